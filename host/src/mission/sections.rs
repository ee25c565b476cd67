//! The demo's report: the summary at the top (what the diagnosis named, what the units say
//! of themselves, what the refitted model does on the board, what was hidden and whether it
//! was found), then the sections of each part in the paper's order, and the PSINS pair.

use std::path::Path;

use super::board::BoardLoop;
use super::paper::{self, PaperChain};
use super::{stage, MissionError};
use crate::diagnose::engine::{diagnose, DiagnoseOptions, DiagnoseReport, Finding};
use crate::diagnose::readable;
use crate::gmwm::model::Process;
use crate::import::psins_fog_mems::{read_fog, read_mems};
use crate::model::SimModel;
use crate::redundancy::RedundancyReport;
use crate::report::charts::{panels_svg, Axes, Panel, Series, Shape, GREY};
use crate::report::html::significant;
use crate::report::{Cell, HtmlReport, Section, Table};
use crate::sim::hidden::{contains, Hidden};
use crate::sim::SimOutput;

/// The real pair's chain and diagnosis.
#[derive(Debug, Clone)]
pub struct PsinsPart {
    pub chain: PaperChain,
    pub diagnosis: DiagnoseReport,
}

/// The PSINS MEMS unit against its FOG INS (100 s of a car): the chain and the diagnosis
/// (no static recording: the baseline is the quietest stretch's fit, as `diagnose` does
/// without `--baseline`). `Ok(Err(why))` when the data are absent.
pub fn psins(
    data_dir: &Path,
    opts: &DiagnoseOptions,
) -> Result<Result<PsinsPart, String>, MissionError> {
    let dir = data_dir.join("psins-fog-mems");
    let (mems_path, fog_path) = (
        dir.join("mems_increments.csv.gz"),
        dir.join("fog_ins_reference.csv.gz"),
    );
    if !mems_path.exists() || !fog_path.exists() {
        return Ok(Err(format!(
            "{}: not found; set DYNACAL_DATA to the data folder for the real PSINS pair",
            dir.display()
        )));
    }
    let mems = read_mems(&mems_path).map_err(stage("reading the PSINS MEMS"))?;
    let fog = read_fog(&fog_path).map_err(stage("reading the PSINS FOG INS"))?;
    let chain = paper::run_chain("PSINS MEMS", &mems, &fog, None)?;
    let diagnosis =
        diagnose(mems, Some(fog), None, opts).map_err(stage("the diagnosis of the PSINS MEMS"))?;
    Ok(Ok(PsinsPart { chain, diagnosis }))
}

/// Everything the report is made of.
pub struct Parts<'a> {
    pub hidden: &'a Hidden,
    pub named: Option<&'a Finding>,
    pub model: &'a SimModel,
    pub chain: &'a PaperChain,
    pub diagnosis: &'a DiagnoseReport,
    pub redundant: &'a RedundancyReport,
    pub board: &'a BoardLoop,
    pub psins: &'a Result<PsinsPart, String>,
    pub drive: &'a SimOutput,
    pub seconds: f64,
}

/// The hidden effect in words: cause, channel, term and size in SI.
pub fn hidden_words(h: &Hidden) -> String {
    let mut s = format!("{} on {}", h.cause, h.channel);
    if !h.term.is_empty() {
        s.push_str(&format!(" ({})", h.term));
    }
    if let Some(t) = h.truth {
        s.push_str(&format!(", true value {} (SI)", significant(t, 4)));
    }
    s
}

/// Whether the named finding's 95% interval holds the hidden truth (None: no value).
pub fn truth_inside_95(h: &Hidden, f: &Finding) -> Option<bool> {
    h.truth.map(|t| contains(&f.ci95, t, h.component, 1.0))
}

/// The verdict line: what was hidden and whether it was found.
pub fn verdict(h: &Hidden, named: Option<&Finding>) -> String {
    match named {
        Some(f) => format!(
            "Hidden in mems0: {}. Found: the diagnosis named {} on {}, {}{}.",
            hidden_words(h),
            f.cause,
            f.channel,
            readable::estimate(f),
            match truth_inside_95(h, f) {
                Some(true) => ", the truth inside its 95% interval",
                Some(false) => ", the truth outside its 95% interval",
                None => "",
            }
        ),
        None => format!(
            "Hidden in mems0: {}. Not found: the diagnosis did not name it.",
            hidden_words(h)
        ),
    }
}

/// The gyro and accelerometer channels the figures show: the hidden channel and the other
/// sensor's channel on the same axis.
fn figure_channels(h: &Hidden) -> (String, String) {
    let axis = h.channel.get(1..).unwrap_or("z");
    (format!("g{axis}"), format!("a{axis}"))
}

fn white_sigma(model: &SimModel, unit: usize, gyro: bool) -> Option<f64> {
    let imu = model.imus.get(unit)?;
    let channel = if gyro { &imu.gyro } else { &imu.accel };
    channel
        .stochastic
        .as_ref()?
        .processes
        .iter()
        .find_map(|p| match p {
            Process::WhiteNoise { sigma2 } => Some(sigma2.sqrt()),
            _ => None,
        })
}

/// Each unit's own white noise from the differences against what the simulation put in.
fn own_noise_truth_table(p: &Parts<'_>) -> Table {
    let rows = p
        .redundant
        .imus
        .iter()
        .enumerate()
        .map(|(k, u)| {
            let own = |c: &str| Cell::Number(u.white_noise_sigma2[c].max(0.0).sqrt());
            let truth = |g| white_sigma(p.model, k, g).map_or("-".into(), Cell::Number);
            vec![
                Cell::from(u.name_short()),
                own("gz"),
                truth(true),
                own("az"),
                truth(false),
            ]
        })
        .collect();
    Table {
        caption: "Own white noise per sample found from the units' differences, against the \
                  simulation's truth"
            .into(),
        header: [
            "unit",
            "gz found (rad/s)",
            "gz truth (rad/s)",
            "az found (m/s^2)",
            "az truth (m/s^2)",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }
}

/// Fig. 8: the first unit's true error (grey) and the live noise level the three units
/// estimated of it (black, ±1 sigma).
fn noise_level_svg(p: &Parts<'_>) -> Result<Option<String>, MissionError> {
    let Some(level) = p.redundant.noise_level.first() else {
        return Ok(None);
    };
    let t = &p.chain.signals.t_s;
    let black = plotters::style::RGBColor(0, 0, 0);
    let panel = |channel: &str, unit: &str, sd: &[f64]| Panel {
        title: format!("mems0: {channel} error against the reference, and the units' own estimate"),
        x_label: "time (s)".into(),
        y_label: format!("{channel} error ({unit})"),
        axes: Axes::Linear,
        series: vec![
            Series::new(
                "error against the reference",
                GREY,
                Shape::Line(
                    p.chain
                        .signals
                        .error(channel)
                        .map(|e| t.iter().copied().zip(e.iter().copied()).collect())
                        .unwrap_or_default(),
                ),
            ),
            Series::new(
                "± own noise level (3 units)",
                black,
                Shape::Line(level.t_s.iter().copied().zip(sd.iter().copied()).collect()),
            ),
            Series::new(
                "",
                black,
                Shape::Line(level.t_s.iter().zip(sd).map(|(&t, &s)| (t, -s)).collect()),
            ),
        ],
    };
    let (g, a) = figure_channels(p.hidden);
    panels_svg(
        "The units' own noise level against the true error",
        &[
            panel(&a, "m/s^2", &level.accel_m_s2),
            panel(&g, "rad/s", &level.gyro_rad_s),
        ],
    )
    .map_err(stage("drawing Fig. 8"))
}

fn board_summary(b: &BoardLoop) -> String {
    let (rms_a, nees_a) = b.built_in.position_summary();
    let (rms_b, nees_b) = b.refitted.position_summary();
    format!(
        "Board (QEMU, three units fused): horizontal position RMS {} m with the built-in model, \
         {} m with the refitted one; mean position NEES {} and {} (3 is consistent). The \
         refitted blob is {}.",
        significant(rms_a, 3),
        significant(rms_b, 3),
        significant(nees_a, 3),
        significant(nees_b, 3),
        b.blob.display()
    )
}

fn drive_section(p: &Parts<'_>) -> Section {
    let names: Vec<&str> = p.drive.imus.iter().map(|u| u.name.as_str()).collect();
    Section::new("The run").paragraph(format!(
        "A simulated car drive of {} s: a navigation-grade reference IMU at {} Hz, three MEMS \
         units ({}) at {} Hz on one board, GNSS and PPS. One effect was hidden in mems0, drawn \
         from the seed and told at the end. A static recording of the same units, as long, \
         gave the baseline, fitted as `dynacal fit --model auto` fits it (static-mems0.csv, \
         baseline.json): the diagnosis never saw the true model.",
        p.seconds,
        p.model.reference.rate_hz,
        names.join(", "),
        p.model.imus.first().map_or(0.0, |i| i.rate_hz)
    ))
}

fn psins_sections(p: &Parts<'_>) -> Result<Vec<Section>, MissionError> {
    match p.psins {
        Ok(part) => {
            let mut s = paper::sections(&part.chain, "gz", "ay")?;
            s.extend(
                crate::diagnose::html::sections(&part.diagnosis, "PSINS MEMS: ")
                    .map_err(stage("the PSINS diagnosis's figures"))?,
            );
            Ok(s)
        }
        Err(why) => Ok(vec![
            Section::new("The real PSINS MEMS/FOG pair").paragraph(format!("Left out: {why}."))
        ]),
    }
}

/// The whole report.
pub fn report(p: &Parts<'_>) -> Result<HtmlReport, MissionError> {
    let mut summary: Vec<String> = crate::diagnose::html::summary(p.diagnosis)
        .into_iter()
        .map(|l| format!("mems0: {l}"))
        .collect();
    summary.extend(crate::redundancy::report::html_summary(p.redundant));
    summary.push(board_summary(p.board));
    if let Ok(part) = p.psins {
        summary.extend(
            crate::diagnose::html::summary(&part.diagnosis)
                .into_iter()
                .map(|l| format!("PSINS MEMS: {l}")),
        );
    }
    summary.push(verdict(p.hidden, p.named));
    let (gyro, accel) = figure_channels(p.hidden);
    let mut sections = vec![drive_section(p)];
    sections.extend(paper::sections(p.chain, &gyro, &accel)?);
    sections.extend(
        crate::diagnose::html::sections(p.diagnosis, "mems0: ")
            .map_err(stage("the diagnosis's figures"))?,
    );
    let mut redundancy = crate::redundancy::report::html_sections(p.redundant)
        .map_err(stage("the redundancy's figures"))?;
    if let Some(first) = redundancy.first_mut() {
        first.tables.push(own_noise_truth_table(p));
        first.figures.insert(
            0,
            crate::report::Figure {
                caption: "mems0's true error (grey) and the noise level the three units \
                          estimated of it from their differences, ±1 sigma (black; paper Fig. 8)"
                    .into(),
                svg: noise_level_svg(p)?.unwrap_or_default(),
            },
        );
        first.figures.retain(|f| !f.svg.is_empty());
    }
    sections.extend(redundancy);
    sections.push(super::board::section(p.board)?);
    sections.extend(psins_sections(p)?);
    sections.push(Section::new("What was hidden").paragraph(verdict(p.hidden, p.named)));
    Ok(HtmlReport {
        title: "dynacal demo: MEMS errors under vehicle dynamics, end to end".into(),
        summary,
        sections,
    })
}
