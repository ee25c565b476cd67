//! The car generator of the hidden-effect tests: a MEMS IMU model with effects hidden in it
//! (cause, channel and magnitude drawn from a seed), a drive simulated with it beside the
//! navigation-grade reference, the baseline a user would fit (`dynacal fit --model auto` on
//! a static recording of the same sensor, through the model file), and the scoring of what
//! `dynacal diagnose` named against what was hidden.
// Each test file that includes the generator uses a part of it.
#![allow(dead_code)]

use dynacal::diagnose::engine::{diagnose, Baseline, DiagnoseOptions, DiagnoseReport, Finding};
use dynacal::interchange::ImuRecording;
use dynacal::model::Cause;
use dynacal::sim::SimOptions;
use dynacal::sim::{simulate, Scenario, SimModel, SimOutput};

pub use dynacal::sim::hidden::*;

/// Length of each simulated drive: the 15 minutes of the paper's vehicle test (Section V).
/// On 300 s drives the gyro terms the car's turning drives were found in only 8 of 20 fresh
/// runs: a drive can barely turn (omega_z sd 0.004 rad/s), and with few turns f_y ~ speed *
/// omega_z cannot be told from omega_z (BENCHMARKS.md).
pub const SECONDS: f64 = 900.0;

/// The baseline a user has: `dynacal fit --model auto` on a static recording of the same
/// sensor (without the effect hidden under dynamics), as long as the drive, written as a
/// model file and read back as `dynacal diagnose --baseline` reads it. The static record is
/// simulated with its own seed, so its noise is not the drive's.
pub fn fitted_baseline(seed: u64, seconds: f64) -> Baseline {
    let (model, _) = hide(&[], seed, seconds);
    let out = simulate_run(&model, Scenario::Static, seconds, seed ^ 0x57a7_1c00);
    baseline_fitted_on(&out.imus[0].recording)
}

/// `dynacal fit --model auto` on `static_record` written as an interchange CSV, its model
/// file written and read back as `dynacal diagnose --baseline` reads it.
pub fn baseline_fitted_on(static_record: &ImuRecording) -> Baseline {
    let dir = tempfile::tempdir().unwrap();
    dynacal::mission::fit_baseline(static_record, dir.path()).unwrap()
}

/// `model` simulated in `scenario` for `seconds` from `seed`, every effect on.
pub fn simulate_run(model: &SimModel, scenario: Scenario, seconds: f64, seed: u64) -> SimOutput {
    simulate(model, &SimOptions::run(scenario, seconds, seed), &|_| {}).unwrap()
}

/// A simulated car drive of `seconds` with the effects `hidden` (see [`hide`]), diagnosed
/// against the navigation-grade reference with a baseline fitted as a user would
/// ([`fitted_baseline`]).
pub fn run(
    hidden: &[(&'static str, Option<&'static str>)],
    seed: u64,
    seconds: f64,
) -> (DiagnoseReport, Vec<Hidden>) {
    let (model, hidden) = hide(hidden, seed, seconds);
    let out = simulate_run(&model, Scenario::Car, seconds, seed);
    let report = diagnose(
        out.imus[0].recording.clone(),
        Some(out.reference.recording.clone()),
        Some(fitted_baseline(seed, seconds)),
        &DiagnoseOptions {
            seed,
            ..Default::default()
        },
    )
    .unwrap();
    (report, hidden)
}

/// Every cause of the vocabulary a generator can hide (a white-noise change is only ever a
/// by-product).
pub fn causes_under_test() -> Vec<&'static str> {
    Cause::ALL
        .into_iter()
        .filter(|c| *c != Cause::WhiteNoiseChange)
        .map(Cause::name)
        .collect()
}

/// The finding that names hidden effect `h`: its cause on its channel.
pub fn finding_of<'a>(findings: &'a [Finding], h: &Hidden) -> Option<&'a Finding> {
    findings
        .iter()
        .find(|f| f.cause.name() == h.cause && f.channel.name() == h.channel)
}

/// Whether finding `f` belongs to hidden effect `h`: its cause on its channel, or its cause
/// anywhere when the cause is sensor-wide (a time offset names every channel, a lever arm
/// every accelerometer).
#[derive(Debug, Clone, Copy)]
pub struct EffectOutcome {
    pub named: bool,
    pub hit: bool,
    pub inside_95: Option<bool>,
}

/// What one run found: per hidden effect, and the (cause, channel) pairs named that no
/// hidden effect explains (spurious findings).
#[derive(Debug, Clone)]
pub struct Outcome {
    pub effects: Vec<EffectOutcome>,
    pub spurious: usize,
}

/// Scores `report` against `hidden`, and prints the run.
pub fn score(label: &str, report: &DiagnoseReport, hidden: &[Hidden]) -> Outcome {
    eprintln!(
        "{label}: hid {:?}; named {:?}",
        hidden
            .iter()
            .map(|h| format!("{} {} {} {:?}", h.cause, h.channel, h.term, h.truth))
            .collect::<Vec<_>>(),
        report
            .findings
            .iter()
            .map(|f| format!("{}:{}={}", f.channel, f.cause, f.estimate))
            .collect::<Vec<_>>()
    );
    let effects = hidden
        .iter()
        .map(|h| {
            let found = finding_of(&report.findings, h);
            let inside = |widen: f64| {
                found.is_some_and(|f| {
                    h.truth
                        .is_none_or(|t| contains(&f.ci95, t, h.component, widen))
                })
            };
            EffectOutcome {
                named: found.is_some(),
                hit: inside(WIDEN_95_TO_999),
                inside_95: (found.is_some() && h.truth.is_some()).then(|| inside(1.0)),
            }
        })
        .collect();
    let spurious = report
        .findings
        .iter()
        .filter(|f| !hidden.iter().any(|h| h.is_named_by(f)))
        .map(|f| (f.cause, f.channel))
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    Outcome { effects, spurious }
}
