//! Hidden-effect tests of `dynacal diagnose`: a generator ([`car`]) picks an effect from the
//! cause vocabulary, a channel and a magnitude from a seed, simulates a car run with it
//! hidden in a MEMS IMU beside a navigation-grade reference, and runs the engine without
//! telling it what was hidden, on a baseline fitted as a user would. The engine must name
//! the right cause on the right channel with the true value inside its interval; on runs
//! with nothing beyond the baseline it must name nothing. The rates over many fresh seeds
//! are measured by `diagnosis_rates.rs`.

mod car;

use car::{causes_under_test, contains, fitted_baseline, run, SECONDS, WIDEN_95_TO_999};
use dynacal::calibration::SpilledRecording;
use dynacal::diagnose::engine::{diagnose, diagnose_recordings, DiagnoseOptions, Recording};
use dynacal::model::Cause;
use dynacal::sim::SimOptions;
use dynacal::sim::{simulate, Scenario, SimModel};

/// Every seed: the hidden cause on the hidden channel, with the truth inside the reported
/// interval taken to 99.9%. The 95% interval itself misses the truth in one run of twenty
/// when it is calibrated, so over many checks a few would miss by chance (at 900 s: the step
/// of bias_shift seed 2 by 2.9 sigma of the Gauss-Markov wander); the power harness below
/// measures how often the 95% interval holds the truth. Each cause runs one seed here (1 or
/// 2, alternating, so both drives are exercised) to keep the suite within CI's time; the
/// rates over many fresh seeds per cause are `diagnosis_rates.rs`'s (BENCHMARKS.md).
fn check(cause: &'static str, seeds: &[u64]) {
    for &seed in seeds {
        let (report, hidden) = run(&[(cause, None)], seed, SECONDS);
        let h = &hidden[0];
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
        let (report, _) = run(&[], seed, SECONDS);
        assert!(
            report.findings.is_empty(),
            "seed {seed}: {:?}",
            report.findings
        );
    }
}

#[test]
fn finds_scale_factor() {
    check("scale_factor", &[1]);
}
#[test]
fn finds_cross_axis() {
    check("cross_axis", &[2]);
}
#[test]
fn finds_g_sensitivity() {
    check("g_sensitivity", &[1]);
}
#[test]
fn finds_angular_acceleration() {
    check("angular_acceleration", &[2]);
}
#[test]
fn finds_jerk() {
    check("jerk", &[1]);
}
#[test]
fn finds_time_offset() {
    check("time_offset", &[2]);
}
#[test]
fn finds_lever_arm() {
    check("lever_arm", &[1]);
}
#[test]
fn finds_noise_scaling_with_dynamics() {
    check("noise_scales_with_dynamics", &[2]);
}
#[test]
fn finds_vibration() {
    check("vibration", &[1]);
}
#[test]
fn finds_outliers() {
    check("outliers", &[2]);
}
#[test]
fn finds_bias_shift() {
    check("bias_shift", &[1]);
}
#[test]
fn finds_correlated_noise_change() {
    check("correlated_noise_change", &[2]);
}
#[test]
fn finds_quantization() {
    check("quantization", &[1]);
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
    let (report, hidden) = run(&[(cause, None)], seed, SECONDS);
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
    let (report, hidden) = run(&[("bias_shift", None)], 1, SECONDS);
    let h = &hidden[0];
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
        out.imus[0].recording.clone(),
        Some(out.reference.recording.clone()),
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
        let hidden: Vec<(&'static str, Option<&'static str>)> =
            cause.map(|c| (c, None)).into_iter().collect();
        let (report, _) = run(&hidden, 1, SECONDS);
        let name = format!("{}.json", cause.unwrap_or("null"));
        let text = serde_json::to_string_pretty(&report).unwrap();
        std::fs::write(dir.join(name), text).unwrap();
    }
}

/// Static data (no reference): a bias step hidden in a static record is found by the local
/// scan and sized from its windows, against a baseline fitted on another static record.
#[test]
fn finds_a_bias_step_on_static_data() {
    let seconds = 300.0;
    let (model, _) = car::hide(&[("bias_shift", Some("ax"))], 41, seconds);
    let out = car::simulate_run(&model, Scenario::Static, seconds, 41);
    let step = model.imus[0]
        .model_of("ax".parse().unwrap())
        .bias_steps
        .first()
        .cloned()
        .expect("a hidden step");
    // Held, and as a long run holds it: the errors in a temporary file, the simulations
    // drawn again.
    let mut estimates = Vec::new();
    for held_samples in [usize::MAX, 0] {
        let report = diagnose(
            out.imus[0].recording.clone(),
            None,
            Some(fitted_baseline(41, seconds)),
            &DiagnoseOptions {
                seed: 41,
                held_samples,
                ..Default::default()
            },
        )
        .unwrap();
        let found = report
            .findings
            .iter()
            .find(|f| f.cause == Cause::BiasShift)
            .unwrap_or_else(|| panic!("no step named: {:?}", report.findings));
        assert_eq!(found.channel.name(), "ax");
        assert!(
            contains(&found.ci95, step.size, None, WIDEN_95_TO_999),
            "{found:?} vs {step:?}"
        );
        assert!(
            report.findings.iter().all(|f| f.channel.name() == "ax"),
            "{:?}",
            report.findings
        );
        estimates.push(found.estimate.as_f64().unwrap());
    }
    assert!((estimates[0] - estimates[1]).abs() <= 1e-9 * estimates[0].abs());
}

/// A long drive's simulations are drawn again at each use instead of held, one channel after
/// another, and its error and residual are kept in spill files and changed there (outliers
/// replaced, lines taken out): the same seeds give the same series, so the report is the one
/// a held run gives (to rounding: inner products are summed in another order). Forced here
/// on a short drive by holding nothing; the memory it saves is in BENCHMARKS.md.
#[test]
fn simulations_drawn_again_give_the_report_held_ones_give() {
    let seconds = 300.0;
    let hide = [
        ("bias_shift", None),
        ("vibration", Some("gz")),
        ("outliers", Some("ay")),
    ];
    let (model, hidden) = car::hide(&hide, 5, seconds);
    let out = car::simulate_run(&model, Scenario::Car, seconds, 5);
    let baseline = fitted_baseline(5, seconds);
    let diagnose_holding = |held_samples: usize| {
        diagnose(
            out.imus[0].recording.clone(),
            Some(out.reference.recording.clone()),
            Some(baseline.clone()),
            &DiagnoseOptions {
                seed: 5,
                held_samples,
                ..Default::default()
            },
        )
        .unwrap()
    };
    let held = diagnose_holding(usize::MAX);
    let drawn = diagnose_holding(0);
    // The same run read from spill files (as a long interchange file is read).
    let spilled = |r: &dynacal::interchange::ImuRecording| {
        Recording::Spilled(
            SpilledRecording::from_recording(std::path::Path::new("recording"), r).unwrap(),
        )
    };
    let from_spills = diagnose_recordings(
        spilled(&out.imus[0].recording),
        Some(spilled(&out.reference.recording)),
        Some(baseline.clone()),
        &DiagnoseOptions {
            seed: 5,
            held_samples: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        serde_json::to_string(&from_spills).unwrap(),
        serde_json::to_string(&drawn).unwrap()
    );
    for h in &hidden {
        assert!(
            held.findings
                .iter()
                .any(|f| f.cause.name() == h.cause && f.channel.name() == h.channel),
            "hid {h:?}, named {:?}",
            held.findings
        );
    }
    let named = |r: &dynacal::diagnose::engine::DiagnoseReport| -> Vec<(String, String)> {
        r.findings
            .iter()
            .map(|f| (f.channel.name().to_string(), f.cause.name().to_string()))
            .collect()
    };
    assert_eq!(named(&held), named(&drawn));
    for (a, b) in held.findings.iter().zip(&drawn.findings) {
        let (x, y) = (a.estimate.as_f64(), b.estimate.as_f64());
        if let (Some(x), Some(y)) = (x, y) {
            assert!(
                (x - y).abs() <= 1e-9 * x.abs().max(y.abs()),
                "{a:?} against {b:?}"
            );
        }
    }
    for (channel, g) in &held.gain {
        let d = &drawn.gain[channel];
        assert!(
            (g.held_out_extended - d.held_out_extended).abs()
                <= 1e-9 * g.held_out_extended.abs().max(1e-300),
            "{channel}: {g:?} against {d:?}"
        );
    }
}
