//! Hidden-effect tests of `dynacal diagnose`: a generator picks an effect from the cause
//! vocabulary, a channel and a magnitude from a seed, simulates a car run with it hidden in a
//! MEMS IMU beside a navigation-grade reference, and runs the engine without telling it what
//! was hidden. The engine must name the right cause on the right channel with the true value
//! inside its 95% interval; on runs with nothing beyond the baseline it must name nothing.

use dynacal::diagnose::engine::{diagnose, Baseline, DiagnoseOptions, DiagnoseReport};
use dynacal::gmwm::model::{ModelSpec, Process};
use dynacal::sim::model_file::{
    BiasStep, ChannelModel, DynamicDriver, DynamicNoise, ImuModel, Outliers, VibrationLine,
};
use dynacal::sim::SimOptions;
use dynacal::sim::{simulate, Scenario, SimModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const RATE_HZ: f64 = 100.0;
const SECONDS: f64 = 300.0;

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
        };
        let set = |c: &'static str, m: ChannelModel, imu: &mut ImuModel| {
            imu.channels.insert(c.into(), m);
        };
        match cause {
            "scale_factor" => {
                let c = pick(&mut rng, &["gz", "ax", "ay"]);
                let v =
                    rng.random_range(0.01..0.03) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                let mut m = channel_model(c);
                m.scale_factor = Some(v);
                set(c, m, &mut imu);
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
                h.channel = c;
                h.truth = Some(v);
            }
            "jerk" => {
                // On az only: on a car the vertical channel carries the body and wheel-hop
                // vibration whose jerk makes a 2-4 ms sensitivity observable in 300 s; the
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
                m.bias_steps = vec![BiasStep {
                    at_s: rng.random_range(0.3..0.7) * SECONDS,
                    size,
                }];
                set(c, m, &mut imu);
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

/// The baseline a static calibration would give: the stochastic part only.
fn static_baseline() -> Baseline {
    Baseline {
        channels: dynacal::interchange::CHANNELS
            .iter()
            .map(|c| {
                let spec = if c.starts_with('g') {
                    gyro_spec()
                } else {
                    accel_spec()
                };
                (c.to_string(), spec)
            })
            .collect(),
        source: "test baseline".into(),
    }
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
    let baseline = static_baseline();
    let report = diagnose(
        &sensor,
        Some(&out.reference.recording),
        Some(baseline),
        &DiagnoseOptions {
            seed,
            ..Default::default()
        },
    )
    .unwrap();
    (report, hidden)
}

fn contains(
    ci: &serde_json::Value,
    est: &serde_json::Value,
    truth: f64,
    component: Option<usize>,
) -> bool {
    let pair = |v: &serde_json::Value| -> Option<(f64, f64)> {
        Some((v.get(0)?.as_f64()?, v.get(1)?.as_f64()?))
    };
    if let Some(k) = component {
        return ci
            .get(k)
            .and_then(pair)
            .is_some_and(|(lo, hi)| lo <= truth && truth <= hi);
    }
    if let Some((lo, hi)) = pair(ci) {
        return lo <= truth && truth <= hi;
    }
    // A vector estimate: the truth must be inside one of its components' intervals.
    let _ = est;
    ci.as_array().is_some_and(|a| {
        a.iter()
            .filter_map(pair)
            .any(|(lo, hi)| lo <= truth && truth <= hi)
    })
}

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
            .find(|f| f.cause == h.cause && f.channel == h.channel);
        let f = hit.unwrap_or_else(|| panic!("seed {seed}: hid {h:?}, named {named:?}"));
        if let Some(t) = h.truth {
            assert!(
                contains(&f.ci95, &f.estimate, t, h.component),
                "seed {seed}: hid {h:?}, found {f:?}; all named: {named:?}"
            );
        }
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
    dynacal::diagnose::engine::CAUSES
        .into_iter()
        .filter(|c| *c != "white_noise_change")
        .collect()
}

/// Outcome of one hidden-effect run.
fn outcome(cause: &'static str, seed: u64) -> (bool, usize) {
    let (report, hidden) = run(Some(cause), seed);
    let h = hidden.expect("a cause was hidden");
    eprintln!(
        "{cause} seed {seed}: hid {} {:?}; named {:?}",
        h.channel,
        h.truth,
        report
            .findings
            .iter()
            .map(|f| format!("{}:{}={}", f.channel, f.cause, f.estimate))
            .collect::<Vec<_>>()
    );
    let hit = report.findings.iter().any(|f| {
        f.cause == h.cause
            && f.channel == h.channel
            && h.truth
                .is_none_or(|t| contains(&f.ci95, &f.estimate, t, h.component))
    });
    // Causes named on channels where nothing was hidden (a time offset names every channel,
    // a lever arm every accelerometer: those count once).
    let others = report
        .findings
        .iter()
        .filter(|f| f.cause != h.cause)
        .map(|f| (f.cause.clone(), f.channel.clone()))
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    (hit, others)
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
    let causes = causes_under_test();
    println!("| cause | detected | runs naming another cause too |");
    println!("|---|---|---|");
    let mut detected = 0usize;
    for &cause in &causes {
        let results: Vec<(bool, usize)> = (0..seeds).map(|k| outcome(cause, 11 + k)).collect();
        let hits = results.iter().filter(|r| r.0).count();
        let extra = results.iter().filter(|r| r.1 > 0).count();
        println!("| {cause} | {hits} / {seeds} | {extra} / {seeds} |");
        detected += hits;
    }
    let null_runs = 2 * seeds;
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
    println!("| null (nothing hidden) | {runs_with_alarm} of {null_runs} runs named anything | |");
    // Guards at the levels measured on 2026-11-22 (BENCHMARKS.md): overall power 50 of 65
    // runs, no null run naming anything (2 of 10 before the noise-change effect-size floor).
    let power = detected as f64 / (causes.len() as u64 * seeds) as f64;
    assert!(power >= 0.7, "overall power {power:.2}");
    assert!(
        runs_with_alarm as f64 <= 0.3 * null_runs as f64,
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
        .find(|f| f.cause == "bias_shift" && f.channel == h.channel)
        .expect("the step is found")
        .clone();
    let model = SimModel::from_json(
        &report.extended_model.to_string(),
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
        Some(static_baseline()),
        &DiagnoseOptions {
            seed: 77,
            ..Default::default()
        },
    )
    .unwrap();
    let refound = again
        .findings
        .iter()
        .find(|f| f.cause == "bias_shift" && f.channel == h.channel)
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
