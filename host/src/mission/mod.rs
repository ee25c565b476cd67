//! `dynacal demo`: the mission end to end on one machine, as a user would run it.
//!
//! A car drive is simulated with three MEMS IMUs beside a navigation-grade reference, one
//! effect hidden in the first unit (cause, channel and size drawn from the seed by
//! [`crate::sim::hidden`], told only at the end), and a static recording of the same units.
//! On the first unit the paper's chain runs ([`paper`]: error signals, dynamics regression,
//! GMWM at rest against in motion), then the diagnosis against the baseline fitted from the
//! static recording as `dynacal fit --model auto` fits it (never the true model); the three
//! units characterise themselves from their differences ([`crate::redundancy`]); the board's
//! firmware fuses them under QEMU with its built-in model, its log is refitted and the
//! firmware runs again with the refitted blob ([`board`]). The real PSINS MEMS unit against
//! its FOG INS goes through the same chain and diagnosis. Everything lands in one
//! self-contained `report.html`, and the outcome says what was hidden and whether the
//! diagnosis named it.

pub mod board;
pub mod paper;
mod sections;

pub use sections::{hidden_words, verdict};

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::diagnose::engine::{diagnose, Baseline, DiagnoseOptions, DiagnoseReport, Finding};
use crate::gmwm::inference::{BootstrapOptions, ModelChoice};
use crate::gmwm::model::Structure;
use crate::input::InputArgs;
use crate::interchange::ImuRecording;
use crate::model::{fit_file, fitted_model, Cause, GnssModel, SimModel};
use crate::redundancy::{redundancy, RedundancyOptions, RedundancyReport};
use crate::report::HtmlReport;
use crate::sim::hidden::{base_imu, hide, Hidden};
use crate::sim::{simulate, Scenario, SimOptions, SimOutput};

/// A stage of the mission failed: which, and why.
#[derive(Debug, thiserror::Error)]
#[error("{stage}: {message}")]
pub struct MissionError {
    pub stage: String,
    pub message: String,
}

impl MissionError {
    pub fn new(stage: &str, message: impl Into<String>) -> Self {
        Self {
            stage: stage.into(),
            message: message.into(),
        }
    }
}

/// A closure turning any error into a [`MissionError`] of `stage` (for `map_err`).
pub(crate) fn stage<E: std::fmt::Display>(stage: &'static str) -> impl Fn(E) -> MissionError {
    move |e| MissionError::new(stage, e.to_string())
}

/// What the demo runs.
#[derive(Debug, Clone)]
pub struct MissionOptions {
    /// Length of the simulated drive and of the static recording, s.
    pub seconds: f64,
    /// Seed of everything random: the hidden effect, the drive, the noise, the simulations.
    pub seed: u64,
    /// Baseline simulations per channel in the diagnosis.
    pub replicates: usize,
    /// Bootstrap replicates of the board log's refit.
    pub bootstrap: usize,
    /// The measured-data folder (for the PSINS pair); its absence is said in the report.
    pub data_dir: PathBuf,
    /// The replay firmware's ELF, run under QEMU.
    pub firmware_elf: PathBuf,
}

/// The mission's stages, in order (for progress).
pub const STAGES: [&str; 7] = [
    "simulating the drive and the static recording",
    "error signals, dynamics and Table I of the first unit",
    "diagnosing the first unit against a baseline fitted at rest",
    "the three units' own errors from their differences",
    "the board under QEMU: built-in model, refit, refitted model",
    "the PSINS MEMS unit against its FOG INS",
    "writing the report",
];

/// What the mission found, and its report.
#[derive(Debug, Clone)]
pub struct MissionOutcome {
    pub hidden: Hidden,
    /// The finding that names the hidden effect, if the diagnosis named it.
    pub named: Option<Finding>,
    /// Everything the diagnosis named on the first unit.
    pub diagnosis: DiagnoseReport,
    pub report: HtmlReport,
    /// Why the PSINS pair was left out, when it was.
    pub psins_skipped: Option<String>,
}

/// The causes the demo draws from: every cause of the vocabulary a generator can hide.
fn demo_causes() -> Vec<&'static str> {
    Cause::ALL
        .into_iter()
        .filter(|c| *c != Cause::WhiteNoiseChange)
        .map(Cause::name)
        .collect()
}

/// The drive's model: the first unit with the hidden effect (or none), two more units of the
/// same make a few centimetres away and a fraction of a degree off.
fn three_unit_model(
    cause: Option<&'static str>,
    seed: u64,
    seconds: f64,
) -> (SimModel, Vec<Hidden>) {
    let hidden: Vec<(&'static str, Option<&'static str>)> =
        cause.map(|c| vec![(c, None)]).unwrap_or_default();
    let (mut model, found) = hide(&hidden, seed, seconds);
    model.imus[0].name = "mems0".into();
    for (k, (lever_arm_b_m, boresight_rpy_deg)) in [
        ([0.04, 0.03, 0.0], [-0.4, 0.3, -0.2]),
        ([-0.03, 0.05, 0.01], [0.2, 0.5, 0.3]),
    ]
    .into_iter()
    .enumerate()
    {
        let mut imu = base_imu();
        imu.name = format!("mems{}", k + 1);
        imu.lever_arm_b_m = lever_arm_b_m;
        imu.boresight_rpy_deg = boresight_rpy_deg;
        model.imus.push(imu);
    }
    model.comment = Some("dynacal demo: three MEMS units beside the reference".into());
    model.gnss = Some(board_receiver(seconds));
    (model, found)
}

/// The receiver the board fuses: a code solution (0.5 m, 1 m vertical; 0.05 m/s) at 10 Hz,
/// its antenna at the first unit (the board's filter has no antenna lever arm), and a 30 s
/// outage in the middle of the drive, where the board's navigation rests on the units' error
/// model alone.
fn board_receiver(seconds: f64) -> GnssModel {
    let outage_start_s = 0.5 * seconds;
    GnssModel {
        rate_hz: 10.0,
        lever_arm_b_m: [0.0; 3],
        position_sigma_ned_m: [0.5, 0.5, 1.0],
        position_bias: None,
        velocity_sigma_ned_m_s: [0.05, 0.05, 0.1],
        outages: vec![[outage_start_s, outage_start_s + 30.0]],
        disabled: Vec::new(),
    }
}

fn run_sim(
    model: &SimModel,
    scenario: Scenario,
    seconds: f64,
    seed: u64,
) -> Result<SimOutput, MissionError> {
    simulate(model, &SimOptions::run(scenario, seconds, seed), &|_| {}).map_err(stage("simulating"))
}

/// The baseline a user fits: `dynacal fit --model auto` on the static recording written as
/// an interchange file (`dir/static-mems0.csv`), its model file (`dir/baseline.json`)
/// written and read back as `diagnose --baseline` reads it.
pub fn fit_baseline(static_record: &ImuRecording, dir: &Path) -> Result<Baseline, MissionError> {
    let csv = dir.join("static-mems0.csv");
    static_record
        .write(&csv)
        .map_err(stage("writing the static recording"))?;
    let fits = fit_file(&csv, &InputArgs::default(), &ModelChoice::Auto, None)
        .map_err(stage("fitting the baseline at rest"))?;
    let (file, _) = fitted_model(&csv, "auto", &fits).map_err(stage("the baseline model file"))?;
    let path = dir.join("baseline.json");
    crate::output::write_json_atomic(&path, &file).map_err(stage("writing the baseline"))?;
    Baseline::load(&path).map_err(stage("reading the baseline"))
}

fn redundancy_of(drive: &SimOutput) -> Result<RedundancyReport, MissionError> {
    let units: Vec<(String, ImuRecording)> = drive
        .imus
        .iter()
        .map(|u| (u.name.clone(), u.recording.clone()))
        .collect();
    redundancy(&units, &RedundancyOptions::default()).map_err(stage("the redundancy analysis"))
}

/// Runs the whole mission, writing its working files into `dir` (the static recording, the
/// baseline, the board's input, logs and refitted blob); `progress(k)` is called as stage k
/// of [`STAGES`] starts. The report is returned, not written.
pub fn run_mission(
    opts: &MissionOptions,
    dir: &Path,
    progress: &dyn Fn(usize),
) -> Result<MissionOutcome, MissionError> {
    progress(0);
    let causes = demo_causes();
    let cause = causes[ChaCha8Rng::seed_from_u64(opts.seed).random_range(0..causes.len())];
    let (model, hidden) = three_unit_model(Some(cause), opts.seed, opts.seconds);
    let (clean, _) = three_unit_model(None, opts.seed, opts.seconds);
    let drive = run_sim(&model, Scenario::Car, opts.seconds, opts.seed)?;
    let at_rest = run_sim(
        &clean,
        Scenario::Static,
        opts.seconds,
        opts.seed ^ 0x57a7_1c00,
    )?;

    progress(1);
    let structure = Structure::parse("WN+GM").map_err(stage("the Table I model"))?;
    let chain = paper::run_chain(
        "mems0",
        &drive.imus[0].recording,
        &drive.reference.recording,
        Some(paper::AtRest {
            sensor: &at_rest.imus[0].recording,
            reference: &at_rest.reference.recording,
            structure: &ModelChoice::Fixed(structure),
        }),
    )?;

    progress(2);
    let baseline = fit_baseline(&at_rest.imus[0].recording, dir)?;
    let diagnose_opts = DiagnoseOptions {
        replicates: opts.replicates,
        seed: opts.seed,
        ..Default::default()
    };
    let diagnosis = diagnose(
        drive.imus[0].recording.clone(),
        Some(drive.reference.recording.clone()),
        Some(baseline),
        &diagnose_opts,
    )
    .map_err(stage("the diagnosis of mems0"))?;
    crate::output::write_json_atomic(&dir.join("extended-model.json"), &diagnosis.extended_model)
        .map_err(stage("writing the extended model"))?;

    progress(3);
    let redundant = redundancy_of(&drive)?;

    progress(4);
    let board = board::run_board_loop(
        &drive,
        &model,
        &opts.firmware_elf,
        dir,
        BootstrapOptions {
            replicates: opts.bootstrap,
            seed: opts.seed,
        },
    )?;

    progress(5);
    let psins = sections::psins(&opts.data_dir, &diagnose_opts)?;

    progress(6);
    let hidden = hidden.into_iter().next().ok_or_else(|| {
        MissionError::new("hiding the effect", format!("no generator hid {cause}"))
    })?;
    let named = diagnosis
        .findings
        .iter()
        .find(|f| hidden.is_named_by(f))
        .cloned();
    let parts = sections::Parts {
        hidden: &hidden,
        named: named.as_ref(),
        model: &model,
        chain: &chain,
        diagnosis: &diagnosis,
        redundant: &redundant,
        board: &board,
        psins: &psins,
        drive: &drive,
        seconds: opts.seconds,
    };
    let report = sections::report(&parts)?;
    Ok(MissionOutcome {
        hidden,
        named,
        diagnosis,
        report,
        psins_skipped: psins.as_ref().err().cloned(),
    })
}
