//! The board in the demo: the drive's three units go through the replay firmware in QEMU's
//! STM32F405 with the board's built-in error model, the board's log is refitted as a user
//! would (`dynacal refit`: the units' own errors from their differences, intervals from the
//! N-cornered hat's bootstrap), and the firmware runs the same drive again with the refitted
//! blob. The two runs' navigation errors against the simulator's truth show what the
//! refitted model changes on the board.

use std::path::{Path, PathBuf};

use super::{stage, MissionError};
use crate::board_log::{state_error, StateError};
use crate::decode::{decode_file, DecodedLog};
use crate::gmwm::inference::{BootstrapOptions, ModelChoice};
use crate::interchange::ImuRecording;
use crate::model::SimModel;
use crate::refit::{refit, Refit, RefitOptions};
use crate::replay::run_replay_in_qemu;
use crate::report::charts::{panels_svg, Axes, Panel, Series, Shape, PALETTE};
use crate::report::{Cell, Section, Table};
use crate::sim::SimOutput;
use dynacal_core::board_model::MAX_BOARD_MODEL_LEN;

/// One board run: its log's filter states against the truth.
#[derive(Debug, Clone)]
pub struct BoardRun {
    pub label: &'static str,
    pub errors: Vec<StateError>,
    /// Instructions per second of data of the board's own work (recording, accumulators,
    /// fusion, log framing; QEMU -icount), the run's mean.
    pub instructions_per_s: f64,
}

/// Both runs and the refit between them.
#[derive(Debug, Clone)]
pub struct BoardLoop {
    pub built_in: BoardRun,
    pub refitted: BoardRun,
    pub refit: Refit,
    /// Where the refitted blob was written.
    pub blob: PathBuf,
}

impl BoardRun {
    /// Horizontal position RMS error, m, and mean position NEES (3 degrees of freedom).
    pub fn position_summary(&self) -> (f64, f64) {
        let n = self.errors.len().max(1) as f64;
        let horizontal = self
            .errors
            .iter()
            .map(|e| e.position_ned_m.xy().norm_squared())
            .sum::<f64>()
            / n;
        let nees = self.errors.iter().map(|e| e.nees()[0]).sum::<f64>() / n;
        (horizontal.sqrt(), nees)
    }
}

fn board_run(
    label: &'static str,
    elf: &Path,
    input: &Path,
    log: &Path,
    blob: Option<&Path>,
    reference: &ImuRecording,
) -> Result<(BoardRun, DecodedLog), MissionError> {
    let run = run_replay_in_qemu(elf, input, log, blob).map_err(stage("the board under QEMU"))?;
    if let Some(refusal) = run.model_refusal() {
        return Err(MissionError::new(
            "the board under QEMU",
            format!("the board refused its model: {refusal}"),
        ));
    }
    let decoded = decode_file(log).map_err(stage("decoding the board's log"))?;
    let errors = decoded
        .filter
        .iter()
        .filter_map(|s| state_error(reference, s))
        .collect();
    let seconds = decoded.span_s().max(1e-9);
    Ok((
        BoardRun {
            label,
            errors,
            instructions_per_s: run.report.record_instructions as f64 / seconds,
        },
        decoded,
    ))
}

/// The loop: built-in model, refit of its log, refitted model; files go to `dir`.
pub fn run_board_loop(
    drive: &SimOutput,
    model: &SimModel,
    elf: &Path,
    dir: &Path,
    bootstrap: BootstrapOptions,
) -> Result<BoardLoop, MissionError> {
    let recording = crate::sim::board::board_recording(drive, model)
        .map_err(stage("the board's replay input"))?;
    let input = dir.join("drive.replay");
    let bytes = recording
        .replay_bytes()
        .map_err(stage("the board's replay input"))?;
    crate::output::write_atomic(&input, &bytes).map_err(stage("writing the replay input"))?;
    let reference = &drive.reference.recording;
    let (built_in, log) = board_run(
        "built-in model",
        elf,
        &input,
        &dir.join("board-built-in.log"),
        None,
        reference,
    )?;
    let options = RefitOptions {
        choice: ModelChoice::Auto,
        bootstrap: Some(bootstrap),
    };
    let refit = refit(&log, &options).map_err(stage("the refit of the board's log"))?;
    let mut blob = [0u8; MAX_BOARD_MODEL_LEN];
    let len = refit
        .board_model
        .encode(&mut blob)
        .map_err(|e| MissionError::new("encoding the board model", format!("{e:?}")))?;
    let blob_path = dir.join("board-model.bin");
    crate::output::write_atomic(&blob_path, &blob[..len])
        .map_err(stage("writing the board model"))?;
    let (refitted, _) = board_run(
        "refitted model",
        elf,
        &input,
        &dir.join("board-refitted.log"),
        Some(&blob_path),
        reference,
    )?;
    Ok(BoardLoop {
        built_in,
        refitted,
        refit,
        blob: blob_path,
    })
}

fn error_panel(title: &str, runs: [&BoardRun; 2], pick: fn(&StateError) -> (f64, f64)) -> Panel {
    let mut series = Vec::new();
    for (k, run) in runs.iter().enumerate() {
        let colour = PALETTE[k];
        series.push(Series::new(
            format!("{}: 3 sigma", run.label),
            colour,
            Shape::Band(
                run.errors
                    .iter()
                    .map(|e| {
                        let (_, s) = pick(e);
                        (e.t_s, -3.0 * s, 3.0 * s)
                    })
                    .collect(),
            ),
        ));
        series.push(Series::new(
            format!("{}: error", run.label),
            colour,
            Shape::Line(run.errors.iter().map(|e| (e.t_s, pick(e).0)).collect()),
        ));
    }
    Panel {
        title: title.into(),
        x_label: "time (s)".into(),
        y_label: "north position error (m)".into(),
        axes: Axes::Linear,
        series,
    }
}

/// The board's section: both runs' navigation against the truth, the refitted parameters,
/// and the cost on the board.
pub fn section(b: &BoardLoop) -> Result<Section, MissionError> {
    let rows = [&b.built_in, &b.refitted]
        .iter()
        .map(|r| {
            let (rms, nees) = r.position_summary();
            vec![
                Cell::from(r.label),
                Cell::Number(rms),
                Cell::Number(nees),
                Cell::Number(r.errors.len() as f64),
                Cell::Number(100.0 * r.instructions_per_s / crate::replay::BOARD_CORE_HZ),
            ]
        })
        .collect();
    let runs = Table {
        caption: "The board's filter on the drive (three units fused on GPS time), against the \
                  simulator's truth"
            .into(),
        header: vec![
            "board model".into(),
            "horizontal position RMS (m)".into(),
            "mean position NEES (3 for a consistent filter)".into(),
            "filter states logged".into(),
            "share of a 168 MHz Cortex-M4F (%)".into(),
        ],
        rows,
    };
    let mut fitted = Vec::new();
    for unit in &b.refit.units {
        for f in &unit.fits {
            for p in &f.parameters {
                fitted.push(vec![
                    Cell::from(f.channel.clone()),
                    Cell::from(f.model.clone()),
                    Cell::from(format!("{} ({})", p.name, p.unit)),
                    Cell::Number(p.value),
                    p.ci95.map_or("-".into(), |c| Cell::Interval(c[0], c[1])),
                ]);
            }
        }
    }
    let svg = panels_svg(
        "The board's north position error and its 3-sigma",
        &[error_panel(
            "north position error on the board",
            [&b.built_in, &b.refitted],
            |e| (e.position_ned_m[0], e.sigma_position_m[0]),
        )],
    )
    .map_err(stage("drawing the board's errors"))?;
    Ok(Section::new("The board: fusion under QEMU, refit, and the refitted model")
        .paragraph(format!(
            "The firmware ran the drive twice in QEMU's STM32F405: with its built-in error model, \
             and with the model refitted from its own log ({}), {} bytes.",
            b.blob.display(),
            std::fs::metadata(&b.blob).map(|m| m.len()).unwrap_or(0)
        ))
        .table(runs)
        .table(Table {
            caption: "The units' own errors refitted from the board's log (GMWM, model by WIC, \
                      95% intervals from the N-cornered hat's bootstrap)"
                .into(),
            header: vec![
                "unit/channel".into(),
                "model".into(),
                "parameter".into(),
                "value".into(),
                "95% interval".into(),
            ],
            rows: fitted,
        })
        .figure(
            "North position error of the board's filter with its 3-sigma band, built-in and refitted model",
            svg,
        ))
}
