//! The readable report of `dynacal diagnose --report DIR`: `report.md` (the tables) with the
//! plots it embeds, drawn as SVG with `plotters`, and the extended model file.
//!
//! Plots: per channel `wv-<channel>.svg`, the Haar wavelet variance of the measured error
//! against the 95% bands of the same statistic over simulations of the baseline and of the
//! extended model (log-log, squared SI units); `gain.svg`, the WV misfit of both models per
//! channel, in-sample and held-out (log scale); `findings.svg`, the share of each channel's
//! error variance the named causes account for. Everything is rendered in memory first and
//! then written whole or not at all ([`write_files`]).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::engine::{DiagnoseReport, Finding, Gain, NotKept, WvCurves};
use super::generalise::FOLDS;
use super::readable::{self, significant};
use crate::figures::plot::{
    chart, decade_label, draw_err, draw_legend, grey_grid, render_svg, titled_with_legend, usable,
    CategoryAxis, Decades, DrawError, Frame, Glyph, FONT, LEGEND_WIDTH_PX,
};
use crate::model::Channel;
use crate::output::{AtomicFile, FileSet};

/// Why the report could not be produced.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    #[error("drawing {file}: {message}")]
    Plot { file: String, message: String },
    #[error("serialising the extended model: {0}")]
    Json(#[from] serde_json::Error),
    #[error("cannot create report directory {}: {source}", path.display())]
    CreateDir {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {}: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// One output file of the report: its name inside the report directory and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReportFile {
    pub name: String,
    pub bytes: Vec<u8>,
}

/// The plot files report.md links to (an empty set: the Markdown without plots, as printed).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Figures {
    /// Channel -> file name of its wavelet-variance plot.
    pub wv: BTreeMap<Channel, String>,
    pub gain: Option<String>,
    pub findings: Option<String>,
}

/// Colour of the measured wavelet variance (line and markers).
pub const MEASURED_COLOUR: RGBColor = RGBColor(200, 30, 30);
/// Colour of the baseline model's band.
pub const BASELINE_COLOUR: RGBColor = RGBColor(110, 110, 110);
/// Colour of the extended model's band.
pub const EXTENDED_COLOUR: RGBColor = RGBColor(30, 100, 200);
/// Gain bars: baseline in-sample, extended in-sample, baseline held-out, extended held-out.
pub const GAIN_COLOURS: [RGBColor; 4] = [
    RGBColor(110, 110, 110),
    RGBColor(30, 100, 200),
    RGBColor(185, 185, 185),
    RGBColor(140, 185, 235),
];
/// Findings bars: deterministic terms and stochastic effects.
pub const DETERMINISTIC_COLOUR: RGBColor = RGBColor(30, 100, 200);
pub const STOCHASTIC_COLOUR: RGBColor = RGBColor(220, 120, 20);

/// Renders every file of the report: the plots, `extended-model.json` and, last, `report.md`
/// (written last so that a report whose index exists is complete).
pub fn report_files(r: &DiagnoseReport) -> Result<Vec<ReportFile>, ReportError> {
    let mut files = Vec::new();
    let mut figures = Figures::default();
    for (channel, curves) in &r.wv_curves {
        let causes = causes_on(&r.findings, *channel);
        let name = format!("wv-{channel}.svg");
        if let Some(svg) = wv_svg(channel.name(), curves, &causes).map_err(|e| e.on(&name))? {
            figures.wv.insert(*channel, name.clone());
            files.push(ReportFile {
                name,
                bytes: svg.into_bytes(),
            });
        }
    }
    let name = "gain.svg".to_string();
    if let Some(svg) = gain_svg(&r.gain).map_err(|e| e.on(&name))? {
        figures.gain = Some(name.clone());
        files.push(ReportFile {
            name,
            bytes: svg.into_bytes(),
        });
    }
    let name = "findings.svg".to_string();
    if let Some(svg) = findings_svg(&r.findings).map_err(|e| e.on(&name))? {
        figures.findings = Some(name.clone());
        files.push(ReportFile {
            name,
            bytes: svg.into_bytes(),
        });
    }
    let mut model = serde_json::to_vec_pretty(&r.extended_model)?;
    model.push(b'\n');
    files.push(ReportFile {
        name: "extended-model.json".into(),
        bytes: model,
    });
    let page = crate::report::HtmlReport {
        title: "dynacal diagnose".into(),
        summary: super::html::summary(r),
        sections: super::html::sections(r, "")?,
    };
    files.push(crate::report::html_file(&page));
    files.push(ReportFile {
        name: "report.md".into(),
        bytes: markdown(r, &figures).into_bytes(),
    });
    Ok(files)
}

/// Renders the report and writes it into `dir`, whole or not at all.
pub fn write_report(dir: &Path, r: &DiagnoseReport) -> Result<Vec<ReportFile>, ReportError> {
    let files = report_files(r)?;
    write_files(dir, &files)?;
    Ok(files)
}

/// Writes `files` into `dir` (created if absent) whole or not at all, as a set
/// (`crate::output::FileSet`) whose completion marker is the last file (the index: the
/// caller puts report.md or report.html last): every file is staged, and only once all are
/// are they moved into place, the previous marker removed first and the new one moved in
/// last. A failure while staging leaves `dir` as it was (and removes it again if this call
/// created it).
pub fn write_files(dir: &Path, files: &[ReportFile]) -> Result<(), ReportError> {
    let created = !dir.exists();
    let result = stage_and_commit(dir, files);
    if result.is_err() && created {
        // Only removes the directory if nothing is in it (the staging folder is gone).
        let _ = std::fs::remove_dir(dir);
    }
    result
}

fn stage_and_commit(dir: &Path, files: &[ReportFile]) -> Result<(), ReportError> {
    let marker = files.last().map(|f| f.name.as_str());
    let mut set = FileSet::create(dir, marker).map_err(|source| ReportError::CreateDir {
        path: dir.to_path_buf(),
        source,
    })?;
    for f in files {
        let write_err = |source| ReportError::Write {
            path: dir.join(&f.name),
            source,
        };
        let mut atomic = AtomicFile::create(&set.path(&f.name)).map_err(write_err)?;
        {
            let mut w = atomic.writer();
            w.write_all(&f.bytes).map_err(write_err)?;
            w.flush().map_err(write_err)?;
        }
        atomic.commit().map_err(write_err)?;
    }
    set.commit().map_err(|source| ReportError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    Ok(())
}

/// The report as Markdown, embedding the plots in `figures` next to their tables.
pub fn markdown(r: &DiagnoseReport, figures: &Figures) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# dynacal diagnose\n\nbaseline: {}\n", r.baseline_source);
    for n in &r.notes {
        let _ = writeln!(s, "- note: {n}");
    }
    if let Some(c) = &r.calibration {
        let deg = 180.0 / std::f64::consts::PI;
        let b = c.boresight_rad;
        let _ = writeln!(
            s,
            "\n## Calibration against the reference\n\nboresight (deg) {:+.4} {:+.4} {:+.4} (1-sigma {:.4} {:.4} {:.4})",
            b.value[0] * deg,
            b.value[1] * deg,
            b.value[2] * deg,
            b.sigma[0] * deg,
            b.sigma[1] * deg,
            b.sigma[2] * deg
        );
        if let Some(l) = c.lever_arm_m {
            let _ = writeln!(
                s,
                "lever arm (m) {:+.4} {:+.4} {:+.4} (1-sigma {:.4} {:.4} {:.4})",
                l.value[0], l.value[1], l.value[2], l.sigma[0], l.sigma[1], l.sigma[2]
            );
        }
        if let Some(t) = c.time_offset_s {
            let _ = writeln!(
                s,
                "time offset (s) {:+.5} (1-sigma {:.5})",
                t.value, t.sigma
            );
        }
    }
    let _ = writeln!(s, "\n## What the simulation gets wrong\n\n| channel | statistic | measured | baseline simulations | detail |\n|---|---|---|---|---|");
    for d in &r.discrepancies {
        let _ = writeln!(
            s,
            "| {} | {} | {} | [{}, {}] | {} |",
            d.channel,
            table_cell(&d.statistic),
            significant(d.measured, 4),
            significant(d.simulated_range[0], 4),
            significant(d.simulated_range[1], 4),
            table_cell(&d.detail)
        );
    }
    if !figures.wv.is_empty() {
        let _ = writeln!(
            s,
            "\nHaar wavelet variance of each channel's measured error (red) against the 95% bands of the same statistic over simulations of the baseline (grey) and of the extended model (blue):\n"
        );
        for (channel, file) in &figures.wv {
            let _ = writeln!(
                s,
                "![{channel}: wavelet variance of the error, measured and simulated]({file})\n"
            );
        }
    }
    let _ = writeln!(
        s,
        "\n## Named causes\n\nA cause is named when the p-value of its test, times the {} tests of the run (Bonferroni), is below alpha = {}: a run with nothing beyond the baseline names anything with probability at most alpha. Its 95% interval excludes the no-effect value.\n\n| channel | cause | regressors | estimate ± 95% half-width | family-wise p | variance explained | in the extended model |\n|---|---|---|---|---|---|---|",
        r.tests, r.alpha
    );
    for f in &r.findings {
        let kept = r
            .gain
            .get(&f.channel)
            .is_none_or(|g| g.not_kept.iter().all(|n| n.cause != f.cause));
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {}% | {} |",
            f.channel,
            f.cause,
            table_cell(&f.regressors.join(", ")),
            readable::estimate(f),
            readable::p_value(f.p_value),
            significant(100.0 * f.variance_explained, 3),
            if kept { "yes" } else { "no (see below)" }
        );
    }
    if r.findings.is_empty() {
        let _ = writeln!(s, "| - | nothing beyond the baseline | | | | | |");
    }
    if let Some(file) = &figures.findings {
        let without = r.findings.iter().filter(|f| !has_variance_share(f)).count();
        let _ = writeln!(
            s,
            "\n![share of each channel's error variance the named causes explain]({file})\n"
        );
        if without > 0 {
            let _ = writeln!(
                s,
                "({without} of {} findings carry no variance share (estimated in the calibration, or a change of the noise model) and are in the table only.)",
                r.findings.len()
            );
        }
    }
    let _ = writeln!(s, "\n## Gain of the extended model\n\nmetric: WV misfit (mean squared z of the log wavelet variance against model simulations; about 1 for a model that fits). Held out: cross-validation over {} contiguous blocks of the run (fitted on the others, scored on each block in turn); a named cause enters the extended model only if it lowers that misfit by 1% or more.\n\n| channel | baseline | extended | held-out baseline | held-out extended | variance explained | held-out variance explained |\n|---|---|---|---|---|---|---|", FOLDS);
    for (ch, g) in &r.gain {
        let _ = writeln!(
            s,
            "| {ch} | {} | {} | {} | {} | {}% | {}% |",
            significant(g.baseline, 4),
            significant(g.extended, 4),
            significant(g.held_out_baseline, 4),
            significant(g.held_out_extended, 4),
            significant(100.0 * g.variance_explained, 3),
            significant(100.0 * g.held_out_variance_explained, 3)
        );
    }
    let not_kept: Vec<(Channel, &NotKept)> = r
        .gain
        .iter()
        .flat_map(|(ch, g)| g.not_kept.iter().map(move |n| (*ch, n)))
        .collect();
    if !not_kept.is_empty() {
        let _ = writeln!(s, "\nNamed but not kept in the extended model (held out, they did not improve the misfit):\n\n| channel | cause | held-out misfit without | with |\n|---|---|---|---|");
        for (ch, n) in not_kept {
            let _ = writeln!(
                s,
                "| {ch} | {} | {} | {} |",
                n.cause,
                significant(n.held_out_without, 4),
                significant(n.held_out_with, 4)
            );
        }
    }
    if let Some(file) = &figures.gain {
        let _ = writeln!(
            s,
            "\n![WV misfit of the baseline and the extended model per channel, in-sample and held-out]({file})"
        );
    }
    s
}

/// Why a plot could not be drawn (the file name is added by [`report_files`]).
#[derive(Debug)]
pub struct PlotError(String);

impl PlotError {
    pub(crate) fn on(self, file: &str) -> ReportError {
        ReportError::Plot {
            file: file.to_string(),
            message: self.0,
        }
    }
}

impl std::fmt::Display for PlotError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl From<DrawError> for PlotError {
    fn from(e: DrawError) -> Self {
        PlotError(e.message().to_string())
    }
}

/// The distinct causes named on `channel`, in the order of the findings.
pub(crate) fn causes_on(findings: &[Finding], channel: Channel) -> Vec<&'static str> {
    let mut causes: Vec<&str> = Vec::new();
    for f in findings.iter().filter(|f| f.channel == channel) {
        if !causes.contains(&f.cause.name()) {
            causes.push(f.cause.name());
        }
    }
    causes
}

/// The squared SI unit of a channel's wavelet variance (gyros `g*`, accelerometers `a*`).
pub fn wv_unit(channel: &str) -> &'static str {
    match channel.as_bytes().first() {
        Some(b'g') => "(rad/s)\u{00b2}",
        Some(b'a') => "(m/s\u{00b2})\u{00b2}",
        _ => "SI unit\u{00b2}",
    }
}

/// Log-log plot of a channel's measured wavelet variance and the simulated bands. `None` when
/// the curves hold no positive value to draw. The log axes carry explicit decade ticks
/// (`Decades` in `crate::figures::plot`).
pub fn wv_svg(
    channel: &str,
    curves: &WvCurves,
    causes: &[&str],
) -> Result<Option<String>, PlotError> {
    let n = curves
        .scale_s
        .len()
        .min(curves.measured.len())
        .min(curves.baseline_lo.len())
        .min(curves.baseline_hi.len())
        .min(curves.extended_lo.len())
        .min(curves.extended_hi.len());
    let scales = &curves.scale_s[..n];
    let measured: Vec<(f64, f64)> = (0..n)
        .filter(|&k| usable(scales[k]) && usable(curves.measured[k]))
        .map(|k| (scales[k], curves.measured[k]))
        .collect();
    let band = |lo: &[f64], hi: &[f64]| -> Vec<(f64, f64, f64)> {
        (0..n)
            .filter(|&k| usable(scales[k]) && usable(lo[k]) && usable(hi[k]))
            .map(|k| (scales[k], lo[k], hi[k]))
            .collect()
    };
    let baseline = band(&curves.baseline_lo, &curves.baseline_hi);
    let extended = band(&curves.extended_lo, &curves.extended_hi);
    let x_values = measured
        .iter()
        .map(|p| p.0)
        .chain(baseline.iter().map(|b| b.0))
        .chain(extended.iter().map(|b| b.0));
    let y_values = measured
        .iter()
        .map(|p| p.1)
        .chain(baseline.iter().flat_map(|b| [b.1, b.2]))
        .chain(extended.iter().flat_map(|b| [b.1, b.2]));
    let (Some(x_decades), Some(y_decades)) = (Decades::around(x_values), Decades::around(y_values))
    else {
        return Ok(None);
    };
    let unit = wv_unit(channel);
    let title = if causes.is_empty() {
        format!("{channel}: wavelet variance of the error \u{2014} no named cause")
    } else {
        format!(
            "{channel}: wavelet variance of the error \u{2014} causes: {}",
            causes.join(", ")
        )
    };
    let label = |v: &f64| decade_label(*v);
    const WIDTH: u32 = 1000;
    render_svg((WIDTH, 600), |root| {
        let (plot_area, legend_area) = titled_with_legend(root, &title, WIDTH)?;
        let mut legend = Vec::new();
        let frame = Frame {
            margin: 12,
            x_labels: 45,
            y_labels: 70,
        };
        let mut chart = chart(&plot_area, None, frame, x_decades.axis(), y_decades.axis())?;
        grey_grid(&mut chart.configure_mesh(), 235, 200)
            .x_desc("scale \u{03c4} [s]")
            .y_desc(format!("wavelet variance [{unit}]"))
            .x_label_formatter(&label)
            .y_label_formatter(&label)
            .draw()
            .map_err(draw_err)?;
        for (points, colour, name) in [
            (&baseline, BASELINE_COLOUR, "baseline model"),
            (&extended, EXTENDED_COLOUR, "extended model"),
        ] {
            if points.is_empty() {
                continue;
            }
            let outline: Vec<(f64, f64)> = points
                .iter()
                .map(|b| (b.0, b.2))
                .chain(points.iter().rev().map(|b| (b.0, b.1)))
                .collect();
            chart
                .draw_series(std::iter::once(Polygon::new(outline, colour.mix(0.22))))
                .map_err(draw_err)?;
            legend.push((Glyph::Band(colour), format!("{name}, 95% band")));
            for bound in [
                points.iter().map(|b| (b.0, b.1)).collect::<Vec<_>>(),
                points.iter().map(|b| (b.0, b.2)).collect(),
            ] {
                chart
                    .draw_series(LineSeries::new(bound, colour.mix(0.8).stroke_width(1)))
                    .map_err(draw_err)?;
            }
        }
        if !measured.is_empty() {
            chart
                .draw_series(LineSeries::new(
                    measured.iter().copied(),
                    MEASURED_COLOUR.stroke_width(2),
                ))
                .map_err(draw_err)?;
            legend.push((
                Glyph::LineWithMarker(MEASURED_COLOUR),
                "measured error".into(),
            ));
            chart
                .draw_series(
                    measured
                        .iter()
                        .map(|&p| Circle::new(p, 3, MEASURED_COLOUR.filled())),
                )
                .map_err(draw_err)?;
        }
        draw_legend(&legend_area, &legend)?;
        Ok(())
    })
    .map(Some)
}

/// One of a channel's four misfits.
type GainValue = fn(&Gain) -> f64;

/// Bar chart of the WV misfit per channel, baseline against extended, in-sample and held-out,
/// on a log scale with the line a fitting model sits on (misfit 1). `None` without any
/// positive misfit to draw.
pub fn gain_svg(gain: &BTreeMap<Channel, Gain>) -> Result<Option<String>, PlotError> {
    let series: [(&str, GainValue); 4] = [
        ("baseline, in-sample", |g| g.baseline),
        ("extended, in-sample", |g| g.extended),
        ("baseline, held-out", |g| g.held_out_baseline),
        ("extended, held-out", |g| g.held_out_extended),
    ];
    let channels: Vec<Channel> = gain.keys().copied().collect();
    let values = gain
        .values()
        .flat_map(|g| series.iter().map(move |(_, f)| f(g)))
        .chain(std::iter::once(1.0));
    let Some(y_decades) = Decades::around(values) else {
        return Ok(None);
    };
    if !gain
        .values()
        .any(|g| series.iter().any(|(_, f)| usable(f(g))))
    {
        return Ok(None);
    }
    let n = channels.len();
    let x_label = |v: &f64| {
        let k = v.round();
        if (v - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < n {
            channels[k as usize].name().to_string()
        } else {
            String::new()
        }
    };
    let y_label = |v: &f64| decade_label(*v);
    let width = (260 + 110 * n as u32).max(700) + LEGEND_WIDTH_PX;
    let title = "WV misfit of the baseline and the extended model (about 1: the model fits)";
    render_svg((width, 560), |root| {
        let (plot_area, legend_area) = titled_with_legend(root, title, width)?;
        let mut legend = Vec::new();
        let frame = Frame {
            margin: 12,
            x_labels: 40,
            y_labels: 70,
        };
        let mut chart = chart(
            &plot_area,
            None,
            frame,
            CategoryAxis::new(n),
            y_decades.axis(),
        )?;
        grey_grid(&mut chart.configure_mesh(), 235, 200)
            .disable_x_mesh()
            .x_desc("channel")
            .label_style((FONT, 14))
            .y_desc("WV misfit (mean squared z)")
            .x_label_formatter(&x_label)
            .y_label_formatter(&y_label)
            .draw()
            .map_err(draw_err)?;
        const BAR_WIDTH: f64 = 0.19;
        for (s, ((name, value), colour)) in series.iter().zip(GAIN_COLOURS).enumerate() {
            let offset = (s as f64 - 1.5) * (BAR_WIDTH + 0.01);
            let bars: Vec<Rectangle<(f64, f64)>> = gain
                .values()
                .enumerate()
                .filter(|(_, g)| usable(value(g)))
                .map(|(k, g)| {
                    let x = k as f64 + offset;
                    Rectangle::new(
                        [
                            (x - BAR_WIDTH / 2.0, y_decades.lo),
                            (x + BAR_WIDTH / 2.0, value(g)),
                        ],
                        colour.filled(),
                    )
                })
                .collect();
            chart.draw_series(bars).map_err(draw_err)?;
            legend.push((Glyph::Bar(colour), (*name).to_string()));
        }
        chart
            .draw_series(DashedLineSeries::new(
                [(-0.5, 1.0), (n as f64 - 0.5, 1.0)],
                8,
                5,
                BLACK.stroke_width(1),
            ))
            .map_err(draw_err)?;
        legend.push((Glyph::Dashed(BLACK), "misfit 1: the model fits".into()));
        draw_legend(&legend_area, &legend)?;
        Ok(())
    })
    .map(Some)
}

fn has_variance_share(f: &Finding) -> bool {
    usable(f.variance_explained)
}

/// Horizontal bars: the share of its channel's error variance each named cause accounts for,
/// deterministic terms and stochastic effects told apart by colour. Findings without a
/// variance share (calibration terms, noise-model changes) are left to the table. `None` when
/// no finding has one.
pub fn findings_svg(findings: &[Finding]) -> Result<Option<String>, PlotError> {
    let rows: Vec<&Finding> = findings.iter().filter(|f| has_variance_share(f)).collect();
    if rows.is_empty() {
        return Ok(None);
    }
    let n = rows.len();
    let max_percent = rows
        .iter()
        .map(|f| 100.0 * f.variance_explained)
        .fold(0.0, f64::max);
    // The first finding at the top: row k sits at y = n - 1 - k.
    let y_label = |v: &f64| {
        let k = v.round();
        if (v - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < n {
            let f = rows[n - 1 - k as usize];
            format!("{} {}", f.channel, f.cause)
        } else {
            String::new()
        }
    };
    let x_label = |v: &f64| format!("{v}");
    let height = 130 + 30 * n as u32;
    let width = 900 + LEGEND_WIDTH_PX;
    let title = "Share of each channel's error variance explained by the named causes";
    render_svg((width, height), |root| {
        let (plot_area, legend_area) = titled_with_legend(root, title, width)?;
        let mut legend = Vec::new();
        let frame = Frame {
            margin: 12,
            x_labels: 40,
            y_labels: 230,
        };
        let mut chart = chart(
            &plot_area,
            None,
            frame,
            0.0..max_percent * 1.18,
            CategoryAxis::new(n),
        )?;
        grey_grid(&mut chart.configure_mesh(), 240, 210)
            .disable_y_mesh()
            .x_desc("variance explained [%]")
            .x_label_formatter(&x_label)
            .y_label_formatter(&y_label)
            .label_style((FONT, 14))
            .draw()
            .map_err(draw_err)?;
        for (deterministic, colour, name) in [
            (true, DETERMINISTIC_COLOUR, "deterministic term"),
            (false, STOCHASTIC_COLOUR, "stochastic effect"),
        ] {
            let bars: Vec<(f64, f64)> = rows
                .iter()
                .enumerate()
                .filter(|(_, f)| f.cause.is_deterministic() == deterministic)
                .map(|(k, f)| ((n - 1 - k) as f64, 100.0 * f.variance_explained))
                .collect();
            if bars.is_empty() {
                continue;
            }
            chart
                .draw_series(bars.iter().map(|&(y, x)| {
                    Rectangle::new([(0.0, y - 0.35), (x, y + 0.35)], colour.filled())
                }))
                .map_err(draw_err)?;
            legend.push((Glyph::Bar(colour), name.to_string()));
            chart
                .draw_series(bars.iter().map(|&(y, x)| {
                    Text::new(
                        format!("{x:.2} %"),
                        (x + 0.01 * max_percent, y),
                        (FONT, 13)
                            .into_font()
                            .color(&BLACK)
                            .pos(Pos::new(HPos::Left, VPos::Center)),
                    )
                }))
                .map_err(draw_err)?;
        }
        draw_legend(&legend_area, &legend)?;
        Ok(())
    })
    .map(Some)
}

/// Text for a Markdown table cell: a `|` inside it (as in `|omega|`) would end the cell.
fn table_cell(text: &str) -> String {
    text.replace('|', "\\|")
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn hex(c: RGBColor) -> String {
        format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
    }

    /// Pixel points of an SVG `points` attribute.
    fn points(attr: &str) -> Vec<(i32, i32)> {
        attr.split_whitespace()
            .map(|p| {
                let (x, y) = p.split_once(',').unwrap();
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect()
    }

    fn elements<'a>(
        doc: &'a roxmltree::Document,
        tag: &str,
        attr: &str,
        value: &str,
    ) -> Vec<roxmltree::Node<'a, 'a>> {
        doc.descendants()
            .filter(|n| n.has_tag_name(tag) && n.attribute(attr) == Some(value))
            .collect()
    }

    fn texts(doc: &roxmltree::Document) -> Vec<String> {
        doc.descendants()
            .filter(|n| n.has_tag_name("text"))
            .filter_map(|n| n.text().map(|t| t.trim().to_string()))
            .collect()
    }

    /// Eight scales 0.02..2.56 s (factor 2), measured WV falling half a decade per level from
    /// 1e-13 to about 3e-17 (below f64::EPSILON, like a good gyro), bands around it.
    fn curves() -> WvCurves {
        let scale_s: Vec<f64> = (0..8).map(|k| 0.01 * 2f64.powi(k + 1)).collect();
        let measured: Vec<f64> = (0..8)
            .map(|k| 1e-13 * 10f64.powf(-0.5 * k as f64))
            .collect();
        WvCurves {
            baseline_lo: measured.iter().map(|v| v * 0.5).collect(),
            baseline_hi: measured.iter().map(|v| v * 2.0).collect(),
            extended_lo: measured.iter().map(|v| v * 0.8).collect(),
            extended_hi: measured.iter().map(|v| v * 1.25).collect(),
            scale_s,
            measured,
        }
    }

    fn finding(channel: &str, cause: &str, variance_explained: f64) -> Finding {
        Finding {
            channel: channel.parse().unwrap(),
            cause: cause.parse().unwrap(),
            regressors: vec!["omega_x".into()],
            estimate: json!(0.003),
            ci95: json!([0.002, 0.004]),
            variance_explained,
            p_value: Some(1e-4),
        }
    }

    fn gain(baseline: f64, extended: f64, held_out_baseline: f64, held_out_extended: f64) -> Gain {
        Gain {
            metric: "wv_misfit".into(),
            baseline,
            extended,
            held_out_baseline,
            held_out_extended,
            variance_explained: 0.02,
            held_out_variance_explained: 0.01,
            not_kept: vec![],
        }
    }

    fn report() -> DiagnoseReport {
        DiagnoseReport {
            baseline_source: "test baseline".into(),
            alpha: 0.05,
            tests: 120,
            calibration: None,
            findings: vec![
                finding("gx", "scale_factor", 0.04),
                finding("gx", "time_offset", 0.0),
                finding("ax", "vibration", 0.12),
            ],
            gain: [
                (Channel::Ax, gain(40.0, 1.2, 3.0, 1.1)),
                (Channel::Gx, gain(12.0, 0.9, 2.0, 1.3)),
            ]
            .into_iter()
            .collect(),
            discrepancies: vec![],
            wv_curves: [(Channel::Ax, curves()), (Channel::Gx, curves())]
                .into_iter()
                .collect(),
            extended_model: serde_json::from_value(json!({"imus": []})).unwrap(),
            notes: vec![],
        }
    }

    #[test]
    fn wv_plot_draws_measured_curve_and_both_bands_on_log_log_axes() {
        let svg = wv_svg("gx", &curves(), &["scale_factor", "jerk"])
            .unwrap()
            .unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        assert_eq!(doc.root_element().tag_name().name(), "svg");

        // The measured curve: one polyline through all 8 levels, and a marker on each
        // (plus the legend's).
        let lines: Vec<Vec<(i32, i32)>> =
            elements(&doc, "polyline", "stroke", &hex(MEASURED_COLOUR))
                .iter()
                .map(|n| points(n.attribute("points").unwrap()))
                .filter(|p| p.len() > 2)
                .collect();
        assert_eq!(lines.len(), 1);
        let line = &lines[0];
        assert_eq!(line.len(), 8);
        assert_eq!(
            elements(&doc, "circle", "fill", &hex(MEASURED_COLOUR)).len(),
            9
        );
        // Both axes logarithmic: a factor 2 in scale and sqrt(10) in WV per level are equal
        // pixel steps (to rounding), and the WV falls (pixels grow downwards).
        for w in line.windows(3) {
            let (dx0, dx1) = (w[1].0 - w[0].0, w[2].0 - w[1].0);
            let (dy0, dy1) = (w[1].1 - w[0].1, w[2].1 - w[1].1);
            assert!(dx0 > 0 && (dx0 - dx1).abs() <= 1, "x steps {dx0} {dx1}");
            assert!(dy0 > 0 && (dy0 - dy1).abs() <= 1, "y steps {dy0} {dy1}");
        }

        // Each band is one shaded polygon along the upper then the lower bound (2 x 8 points);
        // the wider baseline band encloses the extended one.
        let band = |c: RGBColor| -> Vec<(i32, i32)> {
            let polys = elements(&doc, "polygon", "fill", &hex(c));
            assert_eq!(polys.len(), 1, "one band of colour {}", hex(c));
            points(polys[0].attribute("points").unwrap())
        };
        let (base, ext) = (band(BASELINE_COLOUR), band(EXTENDED_COLOUR));
        assert_eq!(base.len(), 16);
        assert_eq!(ext.len(), 16);
        for k in 0..8 {
            assert!(
                base[k].1 < ext[k].1 && ext[k].1 < line[k].1,
                "upper bounds at {k}"
            );
            assert!(base[15 - k].1 > ext[15 - k].1 && ext[15 - k].1 > line[k].1);
        }

        // The y decades span the data (1e-13 down to 3.2e-17), labelled although they lie
        // below f64::EPSILON; x spans 0.02..2.56 s. Title and units name what is plotted.
        let texts = texts(&doc);
        for label in [
            "1e-17", "1e-16", "1e-15", "1e-14", "1e-13", "1e-12", "0.01", "0.1", "1", "10",
        ] {
            assert!(
                texts.iter().any(|t| t == label),
                "tick {label} in {texts:?}"
            );
        }
        assert!(!texts
            .iter()
            .any(|t| t == "1e-18" || t == "1e-11" || t == "100"));
        assert!(texts
            .iter()
            .any(|t| t.starts_with("gx:") && t.contains("scale_factor, jerk")));
        assert!(texts
            .iter()
            .any(|t| t == "wavelet variance [(rad/s)\u{00b2}]"));
        assert!(texts.iter().any(|t| t == "scale \u{03c4} [s]"));
    }

    #[test]
    fn wv_plot_leaves_out_values_a_log_axis_cannot_show() {
        let mut c = curves();
        c.measured[2] = 0.0;
        c.measured[5] = f64::NAN;
        c.baseline_lo[7] = -1.0;
        let svg = wv_svg("ay", &c, &[]).unwrap().unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let measured: Vec<usize> = elements(&doc, "polyline", "stroke", &hex(MEASURED_COLOUR))
            .iter()
            .map(|n| points(n.attribute("points").unwrap()).len())
            .filter(|&n| n > 2)
            .collect();
        assert_eq!(measured, vec![6]);
        let base = elements(&doc, "polygon", "fill", &hex(BASELINE_COLOUR));
        assert_eq!(points(base[0].attribute("points").unwrap()).len(), 14);
        let texts = texts(&doc);
        assert!(texts.iter().any(|t| t.contains("no named cause")));
        assert!(texts
            .iter()
            .any(|t| t == "wavelet variance [(m/s\u{00b2})\u{00b2}]"));

        let zero = WvCurves {
            measured: vec![0.0; 8],
            baseline_lo: vec![f64::NAN; 8],
            baseline_hi: vec![0.0; 8],
            extended_lo: vec![0.0; 8],
            extended_hi: vec![0.0; 8],
            ..curves()
        };
        assert!(wv_svg("ay", &zero, &[]).unwrap().is_none());
    }

    #[test]
    fn gain_plot_draws_a_log_scaled_bar_per_channel_and_series() {
        let g: BTreeMap<Channel, Gain> = [
            (Channel::Ax, gain(100.0, 10.0, 1.0, f64::NAN)),
            (Channel::Gx, gain(1000.0, 0.0, 5.0, 2.0)),
            (Channel::Gz, gain(3.0, 2.0, 4.0, 1.5)),
        ]
        .into_iter()
        .collect();
        let svg = gain_svg(&g).unwrap().unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let bars = |c: RGBColor| -> Vec<(i32, i32)> {
            // (x, height) of each bar, the legend's swatch (26 px wide) left out.
            elements(&doc, "rect", "fill", &hex(c))
                .iter()
                .filter(|n| n.attribute("width") != Some("26"))
                .map(|n| {
                    (
                        n.attribute("x").unwrap().parse().unwrap(),
                        n.attribute("height").unwrap().parse().unwrap(),
                    )
                })
                .collect()
        };
        let baseline = bars(GAIN_COLOURS[0]);
        assert_eq!(baseline.len(), 3);
        // A misfit that is zero or not a number has no bar.
        assert_eq!(bars(GAIN_COLOURS[1]).len(), 2);
        assert_eq!(bars(GAIN_COLOURS[3]).len(), 2);
        // Log scale: 1000, 100 and 3 sit at heights whose differences are decades.
        // Channels in their order (gyros first): gx, gz, ax.
        let held_out_ax = bars(GAIN_COLOURS[2])[2].1; // misfit 1
        let decade = baseline[2].1 - bars(GAIN_COLOURS[1])[1].1; // 100 vs 10
        assert!(decade > 20);
        assert!((baseline[2].1 - held_out_ax - 2 * decade).abs() <= 2);
        assert!((baseline[0].1 - held_out_ax - 3 * decade).abs() <= 2);
        // Channels left to right in order, labelled.
        assert!(baseline[0].0 < baseline[1].0 && baseline[1].0 < baseline[2].0);
        let texts = texts(&doc);
        for label in [
            "ax",
            "gx",
            "gz",
            "misfit 1: the model fits",
            "extended, held-out",
        ] {
            assert!(texts.iter().any(|t| t == label), "{label}");
        }
    }

    #[test]
    fn findings_plot_shows_only_findings_with_a_variance_share() {
        let findings = vec![
            finding("gx", "scale_factor", 0.04),
            finding("gx", "time_offset", 0.0),
            finding("ay", "correlated_noise_change", f64::NAN),
            finding("ax", "vibration", 0.12),
        ];
        let svg = findings_svg(&findings).unwrap().unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let widths = |c: RGBColor| -> Vec<i32> {
            elements(&doc, "rect", "fill", &hex(c))
                .iter()
                .filter(|n| n.attribute("width") != Some("26"))
                .map(|n| n.attribute("width").unwrap().parse().unwrap())
                .collect()
        };
        let (det, sto) = (widths(DETERMINISTIC_COLOUR), widths(STOCHASTIC_COLOUR));
        assert_eq!((det.len(), sto.len()), (1, 1));
        // Linear in the share: 12 % is three times 4 %.
        assert!((sto[0] - 3 * det[0]).abs() <= 2, "{det:?} {sto:?}");
        let texts = texts(&doc);
        for label in ["gx scale_factor", "ax vibration", "4.00 %", "12.00 %"] {
            assert!(texts.iter().any(|t| t == label), "{label} in {texts:?}");
        }
        assert!(!texts.iter().any(|t| t.contains("time_offset")));
        assert!(findings_svg(&findings[1..3]).unwrap().is_none());
    }

    #[test]
    fn report_links_every_plot_it_writes_next_to_its_table() {
        let files = report_files(&report()).unwrap();
        let names: Vec<&str> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "wv-gx.svg",
                "wv-ax.svg",
                "gain.svg",
                "findings.svg",
                "extended-model.json",
                "report.html",
                "report.md"
            ]
        );
        let md = String::from_utf8(files.last().unwrap().bytes.clone()).unwrap();
        let at = |needle: &str| {
            md.find(needle)
                .unwrap_or_else(|| panic!("{needle} in\n{md}"))
        };
        for svg in names.iter().filter(|n| n.ends_with(".svg")) {
            at(&format!("]({svg})"));
            assert_eq!(md.matches(&format!("]({svg})")).count(), 1);
        }
        assert!(at("## What the simulation gets wrong") < at("](wv-ax.svg)"));
        assert!(at("](wv-gx.svg)") < at("## Named causes"));
        assert!(at("## Named causes") < at("](findings.svg)"));
        assert!(at("](findings.svg)") < at("## Gain of the extended model"));
        assert!(at("| gx | 12.00 | 0.9000 |") < at("](gain.svg)"));
        assert!(md.contains("1 of 3 findings carry no variance share"));
        // Without figures (the text printed on stdout) nothing is linked.
        assert!(!markdown(&report(), &Figures::default()).contains("]("));
        // The model file is the report's extended model, as the simulator reads it.
        let text = std::str::from_utf8(&files[4].bytes).unwrap();
        let path = std::path::Path::new("extended-model.json");
        let model = crate::model::SimModel::from_json(text, path).unwrap();
        assert_eq!(model, report().extended_model);
    }

    fn file(name: &str, text: &str) -> ReportFile {
        ReportFile {
            name: name.into(),
            bytes: text.as_bytes().to_vec(),
        }
    }

    #[test]
    fn report_directory_is_written_whole_or_not_at_all() {
        let tmp = tempfile::tempdir().unwrap();
        let listing = |dir: &Path| -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(dir)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        };

        // Success: every file, with its bytes, and no temporary file left.
        let dir = tmp.path().join("a/b/report");
        let good = [file("wv-gx.svg", "<svg/>"), file("report.md", "# r\n")];
        write_files(&dir, &good).unwrap();
        assert_eq!(listing(&dir), ["report.md", "wv-gx.svg"]);
        assert_eq!(
            std::fs::read_to_string(dir.join("report.md")).unwrap(),
            "# r\n"
        );

        // A file that cannot be staged: the earlier report stays as it was, nothing new
        // appears, and the error names the file.
        let bad = [
            file("wv-gx.svg", "<svg>new</svg>"),
            file("no-such-dir/gain.svg", "<svg/>"),
            file("report.md", "# new\n"),
        ];
        let e = write_files(&dir, &bad).unwrap_err();
        assert!(e.to_string().contains("no-such-dir/gain.svg"), "{e}");
        assert_eq!(listing(&dir), ["report.md", "wv-gx.svg"]);
        assert_eq!(
            std::fs::read_to_string(dir.join("wv-gx.svg")).unwrap(),
            "<svg/>"
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("report.md")).unwrap(),
            "# r\n"
        );

        // The same into a directory that did not exist: it is not left behind.
        let fresh = tmp.path().join("fresh");
        assert!(write_files(&fresh, &bad).is_err());
        assert!(!fresh.exists());

        // A directory that cannot be created: the error names it.
        let blocker = tmp.path().join("plain-file");
        std::fs::write(&blocker, "x").unwrap();
        let e = write_files(&blocker.join("report"), &good).unwrap_err();
        assert!(matches!(e, ReportError::CreateDir { .. }));
        assert!(
            e.to_string()
                .contains(&*blocker.join("report").to_string_lossy()),
            "{e}"
        );
    }

    #[test]
    fn a_pipe_in_a_statistic_does_not_split_its_table_row() {
        let mut r = report();
        r.discrepancies.push(crate::diagnose::engine::Discrepancy {
            channel: Channel::Gx,
            statistic: "noise variance vs |omega|^2 (t)".into(),
            measured: 5.0,
            simulated_range: [-1.0, 1.0],
            detail: "largest |z| 7".into(),
        });
        let md = markdown(&r, &Figures::default());
        let row = md
            .lines()
            .find(|l| l.contains("noise variance vs"))
            .expect("row");
        let unescaped = row
            .char_indices()
            .filter(|&(i, c)| c == '|' && (i == 0 || &row[i - 1..i] != "\\"))
            .count();
        assert_eq!(unescaped, 6, "{row}");
    }
}
