//! Hidden-effect tests of `dynacal diagnose`: a generator picks an effect from the cause
//! vocabulary, a channel and a magnitude from a seed, simulates a car run with it hidden in a
//! MEMS IMU beside a navigation-grade reference, and runs the engine without telling it what
//! was hidden. The engine must name the right cause on the right channel with the true value
//! inside its 95% interval; on runs with nothing beyond the baseline it must name nothing.

use dynacal::diagnose::engine::{diagnose, Baseline, DiagnoseOptions, DiagnoseReport};
use dynacal::gmwm::inference::ModelChoice;
use dynacal::gmwm::model::{ModelSpec, Process};
use dynacal::input::InputArgs;
use dynacal::model::{fit_file, fitted_model};
use dynacal::model::{
    BiasStep, Cause, ChannelModel, DynamicDriver, DynamicNoise, ImuModel, Outliers, VibrationLine,
};
use dynacal::sim::SimOptions;
use dynacal::sim::{simulate, Scenario, SimModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const RATE_HZ: f64 = 100.0;
/// Length of each simulated drive: the 15 minutes of the paper's vehicle test (Section V).
/// On 300 s drives the gyro terms the car's turning drives were found in only 8 of 20 fresh
/// runs: a drive can barely turn (omega_z sd 0.004 rad/s), and with few turns f_y ~ speed *
/// omega_z cannot be told from omega_z (BENCHMARKS.md).
const SECONDS: f64 = 900.0;

fn spec(unit: &str, wn: f64, gm_beta: f64, gm_sigma: f64) -> ModelSpec {
    ModelSpec {
        model: "WN+GM".into(),
        unit: unit.into(),
        sample_rate_hz: RATE_HZ,
        processes: vec![
            Process::WhiteNoise { sigma2: wn * wn },
            Process::GaussMarkov {
                beta_per_s: gm_beta,
                sigma2: gm_sigma * gm_sigma,
            },
        ],
    }
}

fn gyro_spec() -> ModelSpec {
    spec("rad/s", 0.004, 0.05, 0.002)
}
fn accel_spec() -> ModelSpec {
    spec("m/s^2", 0.02, 0.02, 0.01)
}

/// What was hidden, for checking.
#[derive(Debug, Clone)]
struct Hidden {
    cause: &'static str,
    channel: &'static str,
    /// True value to find in the matching estimate (None: check cause and channel only).
    truth: Option<f64>,
    /// Index into a vector estimate (lever arm component).
    component: Option<usize>,
    /// The term as the engine names its regressor (e.g. `f_y`), for failure messages.
    term: String,
}

fn base_imu() -> ImuModel {
    let mut imu = ImuModel::navigation_grade_reference();
    imu.name = "mems".into();
    imu.rate_hz = RATE_HZ;
    imu.boresight_rpy_deg = [0.3, -0.2, 0.5];
    imu.gyro = ChannelModel {
        stochastic: Some(gyro_spec()),
        bias: Some(0.002),
        ..Default::default()
    };
    imu.accel = ChannelModel {
        stochastic: Some(accel_spec()),
        bias: Some(0.03),
        ..Default::default()
    };
    imu
}

/// Builds the model with a seeded hidden effect (`cause = None` for a null run).
fn hide(cause: Option<&'static str>, seed: u64) -> (SimModel, Option<Hidden>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed * 7919 + 17);
    let mut imu = base_imu();
    let pick =
        |rng: &mut ChaCha8Rng, chans: &[&'static str]| chans[rng.random_range(0..chans.len())];
    let ch_index = |c: &str| {
        dynacal::interchange::CHANNELS
            .iter()
            .position(|x| *x == c)
            .unwrap()
    };
    let (gyro_model, accel_model) = (imu.gyro.clone(), imu.accel.clone());
    let channel_model = |c: &str| -> ChannelModel {
        if c.starts_with('g') {
            gyro_model.clone()
        } else {
            accel_model.clone()
        }
    };
    let hidden = cause.map(|cause| {
        let mut h = Hidden {
            cause,
            channel: "gx",
            truth: None,
            component: None,
            term: String::new(),
        };
        let set = |c: &'static str, m: ChannelModel, imu: &mut ImuModel| {
            imu.channels.insert(c.parse().expect("a channel name"), m);
        };
        match cause {
            "scale_factor" => {
                let c = pick(&mut rng, &["gz", "ax", "ay"]);
                let v =
                    rng.random_range(0.01..0.03) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                let mut m = channel_model(c);
                m.scale_factor = Some(v);
                set(c, m, &mut imu);
                h.term = format!(
                    "{}_{}",
                    if c.starts_with('g') { "omega" } else { "f" },
                    &c[1..]
                );
                h.channel = c;
                h.truth = Some(v);
            }
            "cross_axis" => {
                // Gyros only: on a car an accelerometer cross-axis term f_y -> ax cannot be told
                // from a boresight about z (both are ax ~ f_y), so it is absorbed by the
                // calibration; a gyro's ω_z -> gx is pinned by the accelerometers' gravity.
                let (c, j) = [("gx", 2usize), ("gy", 2)][rng.random_range(0..2)];
                let v = rng.random_range(0.01..0.03);
                let mut m = channel_model(c);
                let mut k = [0.0; 3];
                k[j] = v;
                m.cross_axis = Some(k);
                set(c, m, &mut imu);
                h.term = format!("omega_{}", ["x", "y", "z"][j]);
                h.channel = c;
                h.truth = Some(v);
            }
            "g_sensitivity" => {
                let c = pick(&mut rng, &["gx", "gy", "gz"]);
                let j = rng.random_range(0..2);
                let v = rng.random_range(1.5e-3..3e-3);
                let mut m = channel_model(c);
                let mut k = [0.0; 3];
                k[j] = v;
                m.g_sensitivity = Some(k);
                set(c, m, &mut imu);
                h.term = format!("f_{}", ["x", "y", "z"][j]);
                h.channel = c;
                h.truth = Some(v);
            }
            "angular_acceleration" => {
                // Gyros only: on an accelerometer a sensitivity to omega_dot is the tangential
                // term of a lever arm, which the calibration estimates.
                let c = pick(&mut rng, &["gx", "gy", "gz"]);
                let v = rng.random_range(0.01..0.02);
                let mut m = channel_model(c);
                m.angular_acceleration_sensitivity = Some([0.0, 0.0, v]);
                set(c, m, &mut imu);
                h.term = "omega_dot_z".into();
                h.channel = c;
                h.truth = Some(v);
            }
            "jerk" => {
                // On az only: on a car the vertical channel carries the body and wheel-hop
                // vibration whose jerk makes a 2-4 ms sensitivity observable in a drive; the
                // lateral and longitudinal jerk of driving is too weak (measured: 3.1 ms on
                // ay went unseen, see BENCHMARKS.md).
                let c = "az";
                let v = rng.random_range(0.002..0.004);
                let mut m = channel_model(c);
                let mut k = [0.0; 3];
                k[ch_index(c) - 3] = v;
                m.jerk_sensitivity = Some(k);
                set(c, m, &mut imu);
                h.channel = c;
                h.truth = Some(v);
            }
            "time_offset" => {
                let v = rng.random_range(0.005..0.02);
                imu.time_offset_s = v;
                h.channel = "gz";
                h.truth = Some(v);
            }
            "lever_arm" => {
                let r = [
                    rng.random_range(0.2..0.5),
                    rng.random_range(-0.4..-0.1),
                    rng.random_range(0.1..0.3),
                ];
                imu.lever_arm_b_m = r;
                h.channel = "ay";
                h.component = Some(0);
                h.truth = Some(r[0]);
            }
            "noise_scales_with_dynamics" => {
                let c = pick(&mut rng, &["gx", "gy", "gz"]);
                let v = rng.random_range(0.03..0.06);
                let mut m = channel_model(c);
                m.dynamic_noise = Some(DynamicNoise {
                    driver: DynamicDriver::AngularRateNorm,
                    sigma_per_unit: v,
                });
                set(c, m, &mut imu);
                h.channel = c;
                h.truth = Some(v);
            }
            "vibration" => {
                let c = pick(&mut rng, &["gx", "gy", "gz", "ax", "ay", "az"]);
                let a = if c.starts_with('g') {
                    rng.random_range(0.003..0.006)
                } else {
                    rng.random_range(0.03..0.06)
                };
                let f = rng.random_range(60.0..140.0);
                let mut m = channel_model(c);
                m.vibration_lines = vec![VibrationLine {
                    frequency_hz: f,
                    amplitude: a,
                    phase_rad: 0.3,
                }];
                set(c, m, &mut imu);
                h.channel = c;
                h.truth = Some(a);
            }
            "outliers" => {
                let c = pick(&mut rng, &["gx", "gy", "gz", "ax", "ay", "az"]);
                let s = if c.starts_with('g') { 0.2 } else { 1.0 };
                let p = rng.random_range(5e-4..2e-3);
                let mut m = channel_model(c);
                m.outliers = Some(Outliers {
                    probability: p,
                    sigma: s,
                });
                set(c, m, &mut imu);
                h.channel = c;
                h.truth = Some(p);
            }
            "bias_shift" => {
                let c = pick(&mut rng, &["gx", "gy", "gz", "ax", "ay", "az"]);
                let size = if c.starts_with('g') {
                    rng.random_range(0.006..0.01)
                } else {
                    rng.random_range(0.05..0.08)
                };
                let mut m = channel_model(c);
                let at_s = rng.random_range(0.3..0.7) * SECONDS;
                m.bias_steps = vec![BiasStep { at_s, size }];
                set(c, m, &mut imu);
                h.term = format!("step at {at_s:.2} s");
                h.channel = c;
                h.truth = Some(size);
            }
            "correlated_noise_change" => {
                let c = pick(&mut rng, &["gx", "gy", "gz", "ax", "ay", "az"]);
                let mut m = channel_model(c);
                let mut s = m.stochastic.clone().unwrap();
                if let Process::GaussMarkov { sigma2, .. } = &mut s.processes[1] {
                    *sigma2 *= 9.0;
                }
                m.stochastic = Some(s);
                set(c, m, &mut imu);
                h.channel = c;
            }
            "quantization" => {
                let c = pick(&mut rng, &["gx", "gy", "gz", "ax", "ay", "az"]);
                let q = if c.starts_with('g') { 1e-3 } else { 5e-3 };
                let mut m = channel_model(c);
                m.quantization_step = Some(q);
                set(c, m, &mut imu);
                h.channel = c;
                h.truth = Some(q);
            }
            other => panic!("no generator for {other}"),
        }
        h
    });
    let mut model = SimModel::from_fitted(gyro_spec(), std::path::Path::new("hidden")).unwrap();
    model.imus = vec![imu];
    (model, hidden)
}

/// The baseline a user has: `dynacal fit --model auto` on a static recording of the same
/// sensor (without the effect hidden under dynamics), as long as the drive, written as a
/// model file and read back as `dynacal diagnose --baseline` reads it. The static record is
/// simulated with its own seed, so its noise is not the drive's.
fn fitted_baseline(seed: u64, seconds: f64) -> Baseline {
    let (model, _) = hide(None, seed);
    let out = simulate(
        &model,
        &SimOptions {
            scenario: Scenario::Static,
            seconds,
            seed: seed ^ 0x57a7_1c00,
            disabled: vec![],
            keep_ideal: false,
        },
        &|_| {},
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("static-mems.csv");
    out.imus[0].recording.write(&csv).unwrap();
    let fits = fit_file(&csv, &InputArgs::default(), &ModelChoice::Auto, None).unwrap();
    let (file, _) = fitted_model(&csv, "auto", &fits).unwrap();
    let path = dir.path().join("baseline.json");
    std::fs::write(&path, serde_json::to_string(&file).unwrap()).unwrap();
    Baseline::load(&path).unwrap()
}

fn run(cause: Option<&'static str>, seed: u64) -> (DiagnoseReport, Option<Hidden>) {
    let (model, hidden) = hide(cause, seed);
    let out = simulate(
        &model,
        &SimOptions {
            scenario: Scenario::Car,
            seconds: SECONDS,
            seed,
            disabled: vec![],
            keep_ideal: false,
        },
        &|_| {},
    )
    .unwrap();
    let sensor = out.imus[0].recording.clone();
    let report = diagnose(
        &sensor,
        Some(&out.reference.recording),
        Some(fitted_baseline(seed, SECONDS)),
        &DiagnoseOptions {
            seed,
            ..Default::default()
        },
    )
    .unwrap();
    (report, hidden)
}

/// Half-width of a 99.9% normal interval over that of a 95% one (3.2905 / 1.9600).
const WIDEN_95_TO_999: f64 = 3.290_526_731_491_926 / 1.959_963_984_540_054;

/// Whether `truth` lies in the interval `ci` (for a vector estimate: in component
/// `component`, or in any component when none is given), after widening it about its centre
/// by `widen` (1 for the reported 95% interval).
fn contains(ci: &serde_json::Value, truth: f64, component: Option<usize>, widen: f64) -> bool {
    let inside = |v: &serde_json::Value| -> bool {
        let (Some(lo), Some(hi)) = (
            v.get(0).and_then(|x| x.as_f64()),
            v.get(1).and_then(|x| x.as_f64()),
        ) else {
            return false;
        };
        let (mid, half) = (0.5 * (lo + hi), 0.5 * (hi - lo) * widen);
        mid - half <= truth && truth <= mid + half
    };
    if let Some(k) = component {
        return ci.get(k).is_some_and(inside);
    }
    if ci.get(0).is_some_and(|x| x.is_number()) {
        return inside(ci);
    }
    ci.as_array().is_some_and(|a| a.iter().any(inside))
}

/// Every seed: the hidden cause on the hidden channel, with the truth inside the reported
/// interval taken to 99.9%. The 95% interval itself misses the truth in one run of twenty
/// when it is calibrated, so over this suite's 26 checks a few would miss by chance (at
/// 900 s: the step of bias_shift seed 2 by 2.9 sigma of the Gauss-Markov wander); the
/// power harness below measures how often the 95% interval holds the truth.
fn check(cause: &'static str, seeds: &[u64]) {
    for &seed in seeds {
        let (report, hidden) = run(Some(cause), seed);
        let h = hidden.unwrap();
        let named: Vec<String> = report
            .findings
            .iter()
            .map(|f| format!("{}:{}", f.channel, f.cause))
            .collect();
        let hit = report
            .findings
            .iter()
            .find(|f| f.cause.name() == h.cause && f.channel.name() == h.channel);
        let f = hit.unwrap_or_else(|| panic!("seed {seed}: hid {h:?}, named {named:?}"));
        if let Some(t) = h.truth {
            assert!(
                contains(&f.ci95, t, h.component, WIDEN_95_TO_999),
                "seed {seed}: hid {h:?}, found {f:?}; all named: {named:?}"
            );
        }
        // A deterministic term is named only where it was hidden: the calibration shares the
        // boresight and lever arm between channels, and a term one channel shows through
        // them is the joint fit's to take back.
        let sensor_wide = matches!(h.cause, "time_offset" | "lever_arm");
        let elsewhere: Vec<&Cause> = report
            .findings
            .iter()
            .filter(|f| f.cause.is_deterministic())
            .filter(|f| {
                !(f.cause.name() == h.cause && (f.channel.name() == h.channel || sensor_wide))
            })
            .map(|f| &f.cause)
            .collect();
        assert!(
            elsewhere.is_empty(),
            "seed {seed}: hid {h:?}; other deterministic terms named: {named:?}"
        );
    }
}

#[test]
fn null_runs_name_nothing() {
    for seed in [101, 102] {
        let (report, _) = run(None, seed);
        assert!(
            report.findings.is_empty(),
            "seed {seed}: {:?}",
            report.findings
        );
    }
}

#[test]
fn finds_scale_factor() {
    check("scale_factor", &[1, 2]);
}
#[test]
fn finds_cross_axis() {
    check("cross_axis", &[1, 2]);
}
#[test]
fn finds_g_sensitivity() {
    check("g_sensitivity", &[1, 2]);
}
#[test]
fn finds_angular_acceleration() {
    check("angular_acceleration", &[1, 2]);
}
#[test]
fn finds_jerk() {
    check("jerk", &[1, 2]);
}
#[test]
fn finds_time_offset() {
    check("time_offset", &[1, 2]);
}
#[test]
fn finds_lever_arm() {
    check("lever_arm", &[1, 2]);
}
#[test]
fn finds_noise_scaling_with_dynamics() {
    check("noise_scales_with_dynamics", &[1, 2]);
}
#[test]
fn finds_vibration() {
    check("vibration", &[1, 2]);
}
#[test]
fn finds_outliers() {
    check("outliers", &[1, 2]);
}
#[test]
fn finds_bias_shift() {
    check("bias_shift", &[1, 2]);
}
#[test]
fn finds_correlated_noise_change() {
    check("correlated_noise_change", &[1, 2]);
}
#[test]
fn finds_quantization() {
    check("quantization", &[1, 2]);
}

/// Every cause of the vocabulary a generator above can hide (a white-noise change is only
/// ever a by-product).
fn causes_under_test() -> Vec<&'static str> {
    Cause::ALL
        .into_iter()
        .filter(|c| *c != Cause::WhiteNoiseChange)
        .map(Cause::name)
        .collect()
}

/// Outcome of one hidden-effect run.
/// What one hidden-effect run found: the hidden cause on its channel (`named`), with the
/// truth inside the reported interval taken to 99.9% (`hit`, what the tests require) and
/// inside the 95% interval itself (None when there is no value to check), and the number of
/// other (cause, channel) pairs named.
struct Outcome {
    named: bool,
    hit: bool,
    inside_95: Option<bool>,
    others: usize,
}

fn outcome(cause: &'static str, seed: u64) -> Outcome {
    let (report, hidden) = run(Some(cause), seed);
    let h = hidden.expect("a cause was hidden");
    eprintln!(
        "{cause} seed {seed}: hid {} {} {:?}; named {:?}",
        h.channel,
        h.term,
        h.truth,
        report
            .findings
            .iter()
            .map(|f| format!("{}:{}={}", f.channel, f.cause, f.estimate))
            .collect::<Vec<_>>()
    );
    let found = report
        .findings
        .iter()
        .find(|f| f.cause.name() == h.cause && f.channel.name() == h.channel);
    let inside = |widen: f64| {
        found.is_some_and(|f| {
            h.truth
                .is_none_or(|t| contains(&f.ci95, t, h.component, widen))
        })
    };
    // Other causes, and the hidden one on other channels (except a time offset, which names
    // every channel, and a lever arm, every accelerometer).
    let sensor_wide = matches!(h.cause, "time_offset" | "lever_arm");
    let others = report
        .findings
        .iter()
        .filter(|f| f.cause.name() != h.cause || (f.channel.name() != h.channel && !sensor_wide))
        .map(|f| (f.cause, f.channel))
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    Outcome {
        named: found.is_some(),
        hit: inside(WIDEN_95_TO_999),
        inside_95: (found.is_some() && h.truth.is_some()).then(|| inside(1.0)),
        others,
    }
}

/// Detection power and false alarms over fresh seeds (not the ones the tests above use):
/// `cargo test --release -p dynacal-tests --test hidden_effects -- --ignored power --nocapture`.
/// Prints the table of BENCHMARKS.md and asserts a floor on the power of every cause and a
/// ceiling on false alarms in null runs. DYNACAL_POWER_SEEDS sets the seeds per cause (5).
#[test]
#[ignore]
fn power_and_false_alarm_rates() {
    let seeds: u64 = std::env::var("DYNACAL_POWER_SEEDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    // DYNACAL_POWER_CAUSES (comma-separated) restricts the causes, to look into a few.
    let only: Option<Vec<String>> = std::env::var("DYNACAL_POWER_CAUSES")
        .ok()
        .map(|s| s.split(',').map(|c| c.trim().to_string()).collect());
    let causes: Vec<&'static str> = causes_under_test()
        .into_iter()
        .filter(|c| only.as_ref().is_none_or(|o| o.iter().any(|x| x == c)))
        .collect();
    println!("| cause | named on the right channel | and truth inside the 99.9% interval | truth inside the 95% interval | runs naming another cause too |");
    println!("|---|---|---|---|---|");
    let mut detected = 0usize;
    let (mut inside_95, mut checked_95) = (0usize, 0usize);
    for &cause in &causes {
        let results: Vec<Outcome> = (0..seeds).map(|k| outcome(cause, 11 + k)).collect();
        let count = |f: &dyn Fn(&Outcome) -> bool| results.iter().filter(|r| f(r)).count();
        let hits = count(&|r| r.hit);
        let checked = count(&|r| r.inside_95.is_some());
        let inside = count(&|r| r.inside_95 == Some(true));
        let coverage = if checked > 0 {
            format!("{inside} / {checked}")
        } else {
            "(no value)".into()
        };
        println!(
            "| {cause} | {} / {seeds} | {hits} / {seeds} | {coverage} | {} / {seeds} |",
            count(&|r| r.named),
            count(&|r| r.others > 0)
        );
        detected += hits;
        inside_95 += inside;
        checked_95 += checked;
    }
    if checked_95 > 0 {
        println!(
            "| all | | {detected} / {} | {inside_95} / {checked_95} | |",
            causes.len() as u64 * seeds
        );
    }
    let null_runs = match &only {
        Some(o) if !o.iter().any(|x| x == "null") => 0,
        _ => 2 * seeds,
    };
    let alarms: Vec<usize> = (0..null_runs)
        .map(|k| {
            let findings = run(None, 201 + k).0.findings;
            eprintln!(
                "null seed {}: named {:?}",
                201 + k,
                findings
                    .iter()
                    .map(|f| format!("{}:{}={}", f.channel, f.cause, f.estimate))
                    .collect::<Vec<_>>()
            );
            findings.len()
        })
        .collect();
    let runs_with_alarm = alarms.iter().filter(|&&a| a > 0).count();
    println!(
        "| null (nothing hidden) | {runs_with_alarm} of {null_runs} runs named anything | | | |"
    );
    // Guards below the levels measured on 2026-11-22 with 900 s drives (BENCHMARKS.md):
    // 64 of 65 runs detected, the truth inside 55 of 59 95% intervals, no null run naming
    // anything (on 300 s drives: 50 of 65 detected).
    if !causes.is_empty() {
        let power = detected as f64 / (causes.len() as u64 * seeds) as f64;
        assert!(power >= 0.9, "overall power {power:.2}");
    }
    if checked_95 > 0 {
        let coverage = inside_95 as f64 / checked_95 as f64;
        assert!(
            coverage >= 0.85,
            "95% intervals held the truth in {inside_95} of {checked_95}"
        );
    }
    assert!(
        runs_with_alarm as f64 <= 0.1 * null_runs as f64,
        "{runs_with_alarm} of {null_runs} null runs named a cause"
    );
}

/// One hidden-effect run chosen from the environment, to look into a failure the power
/// harness reports: `DYNACAL_CAUSE=g_sensitivity DYNACAL_SEED=12 cargo test -p dynacal-tests
/// --test hidden_effects -- --ignored one_run`.
#[test]
#[ignore]
fn one_run() {
    let cause = std::env::var("DYNACAL_CAUSE").expect("set DYNACAL_CAUSE");
    let seed: u64 = std::env::var("DYNACAL_SEED")
        .expect("set DYNACAL_SEED")
        .parse()
        .expect("DYNACAL_SEED is an integer");
    let cause: &'static str = causes_under_test()
        .into_iter()
        .find(|c| *c == cause)
        .expect("a cause of the vocabulary");
    let (report, hidden) = run(Some(cause), seed);
    eprintln!("hid {hidden:?}");
    for d in &report.discrepancies {
        eprintln!("discrepancy {d:?}");
    }
    for f in &report.findings {
        eprintln!("finding {f:?}");
    }
    check(cause, &[seed]);
}

/// The extended model is a model file the simulator runs, and what it carries is what was
/// found: simulated again from it, the hidden bias step is found again at its size.
#[test]
fn extended_model_runs_in_the_simulator_and_carries_the_found_effect() {
    let (report, hidden) = run(Some("bias_shift"), 1);
    let h = hidden.expect("hidden");
    let first = report
        .findings
        .iter()
        .find(|f| f.cause == Cause::BiasShift && f.channel.name() == h.channel)
        .expect("the step is found")
        .clone();
    let model = SimModel::from_json(
        &serde_json::to_string(&report.extended_model).unwrap(),
        std::path::Path::new("extended-model.json"),
    )
    .expect("the simulator accepts the extended model");
    let out = simulate(
        &model,
        &SimOptions {
            scenario: Scenario::Car,
            seconds: SECONDS,
            seed: 77,
            disabled: vec![],
            keep_ideal: false,
        },
        &|_| {},
    )
    .expect("the extended model simulates");
    let again = diagnose(
        &out.imus[0].recording,
        Some(&out.reference.recording),
        Some(fitted_baseline(77, SECONDS)),
        &DiagnoseOptions {
            seed: 77,
            ..Default::default()
        },
    )
    .unwrap();
    let refound = again
        .findings
        .iter()
        .find(|f| f.cause == Cause::BiasShift && f.channel.name() == h.channel)
        .unwrap_or_else(|| panic!("not found again: {:?}", again.findings));
    // Both are estimates with their own noise: their difference must be within its 95%
    // interval, and the step at the same time.
    let estimate_and_se = |f: &dynacal::diagnose::engine::Finding| -> (f64, f64) {
        let ci: Vec<f64> = serde_json::from_value(f.ci95.clone()).unwrap();
        (f.estimate.as_f64().unwrap(), (ci[1] - ci[0]) / (2.0 * 1.96))
    };
    let ((a, sa), (b, sb)) = (estimate_and_se(&first), estimate_and_se(refound));
    assert!(
        (a - b).abs() <= 1.96 * sa.hypot(sb),
        "found {first:?}, found again {refound:?}"
    );
    assert_eq!(
        first.regressors, refound.regressors,
        "the step at the same time"
    );
}

/// Writes the whole report of every hidden-effect run on seed 1 (and the null run) as JSON
/// into `$DYNACAL_DUMP`, so a refactoring of the engine can be checked to change nothing:
/// `DYNACAL_DUMP=/tmp/reports cargo test -p dynacal-tests --test hidden_effects -- --ignored
/// dump_reports`, once before and once after, then `diff -r`.
#[test]
#[ignore]
fn dump_reports() {
    let dir = std::path::PathBuf::from(std::env::var("DYNACAL_DUMP").expect("set DYNACAL_DUMP"));
    std::fs::create_dir_all(&dir).unwrap();
    let mut runs: Vec<Option<&'static str>> = vec![None];
    runs.extend(causes_under_test().into_iter().map(Some));
    for cause in runs {
        let (report, _) = run(cause, 1);
        let name = format!("{}.json", cause.unwrap_or("null"));
        let text = serde_json::to_string_pretty(&report).unwrap();
        std::fs::write(dir.join(name), text).unwrap();
    }
}
