//! `dynacal redundancy --report DIR`: each unit's own error wavelet variance (gyros and
//! accelerometers, the mean over each triad's axes, with the 95% interval), the live noise
//! levels over time with the faults marked where they were detected, the faults' timeline
//! (from detection to readmission), and `report.md` with the figures, the units' white
//! noise, alignments, faults and notes. Written whole or not at all.

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;

use super::{FaultRecord, RedundancyReport};
use crate::diagnose::report::{write_files, ReportError, ReportFile};
use crate::figures::plot::{
    chart, decade_label, draw_err, draw_legend, grey_grid, render_svg, titled_with_legend, usable,
    Area, Decades, DrawError, Frame, Glyph, FONT,
};
use crate::report::{Cell, HtmlReport, Section, Table};

/// One colour per unit (up to eight), and grey for faults no unit could be given.
const UNIT_COLOURS: [RGBColor; 8] = [
    RGBColor(200, 30, 30),
    RGBColor(30, 100, 200),
    RGBColor(20, 140, 40),
    RGBColor(220, 120, 20),
    RGBColor(130, 50, 170),
    RGBColor(0, 150, 150),
    RGBColor(150, 100, 40),
    RGBColor(90, 90, 90),
];
const UNPLACED_COLOUR: RGBColor = RGBColor(150, 150, 150);
const WIDTH: u32 = 1100;

/// The two sensors: name, channels, unit of the level, unit of the wavelet variance.
const SENSORS: [(&str, [&str; 3], &str, &str); 2] = [
    ("gyro", ["gx", "gy", "gz"], "rad/s", "(rad/s)^2"),
    ("accel", ["ax", "ay", "az"], "m/s^2", "(m/s^2)^2"),
];

fn plot_error(file: &str, e: DrawError) -> ReportError {
    ReportError::Plot {
        file: file.to_string(),
        message: e.message().to_string(),
    }
}

fn colour(unit: Option<usize>) -> RGBColor {
    unit.map_or(UNPLACED_COLOUR, |k| UNIT_COLOURS[k % UNIT_COLOURS.len()])
}

/// Renders and writes the report into `dir`, whole or not at all; the files written.
pub fn write_report(dir: &Path, r: &RedundancyReport) -> Result<Vec<ReportFile>, ReportError> {
    let mut files = Vec::new();
    for (sensor, (name, ..)) in SENSORS.iter().enumerate() {
        let file = format!("own-wv-{name}.svg");
        if let Some(svg) = own_wv_svg(r, sensor).map_err(|e| plot_error(&file, e))? {
            files.push(ReportFile {
                name: file,
                bytes: svg.into_bytes(),
            });
        }
    }
    for (file, svg) in [
        ("noise-levels.svg", levels_svg(r)),
        ("faults.svg", faults_svg(r)),
    ] {
        let svg = svg.map_err(|e| plot_error(file, e))?;
        files.push(ReportFile {
            name: file.into(),
            bytes: svg.into_bytes(),
        });
    }
    let names: Vec<String> = files.iter().map(|f| f.name.clone()).collect();
    let page = HtmlReport {
        title: "dynacal redundancy".into(),
        summary: html_summary(r),
        sections: html_sections(r)?,
    };
    files.push(crate::report::html_file(&page));
    files.push(ReportFile {
        name: "report.md".into(),
        bytes: markdown(r, &names).into_bytes(),
    });
    write_files(dir, &files)?;
    Ok(files)
}

/// Unit k's own wavelet variance on `sensor`, the mean over its three axes: (scale, value,
/// low, high) where all are drawable.
fn mean_wv(r: &RedundancyReport, k: usize, sensor: usize) -> Vec<(f64, f64, f64, f64)> {
    let wv: Vec<_> = SENSORS[sensor]
        .1
        .iter()
        .map(|c| &r.imus[k].wv[*c])
        .collect();
    (0..wv[0].scales_s.len())
        .map(|j| {
            let mean =
                |f: fn(&super::OwnWv, usize) -> f64| wv.iter().map(|w| f(w, j)).sum::<f64>() / 3.0;
            (
                wv[0].scales_s[j],
                mean(|w, j| w.variance[j]),
                mean(|w, j| w.ci_low[j]),
                mean(|w, j| w.ci_high[j]),
            )
        })
        .filter(|p| usable(p.0) && usable(p.1))
        .collect()
}

/// Every unit's own wavelet variance on one sensor, log-log, with its 95% interval.
fn own_wv_svg(r: &RedundancyReport, sensor: usize) -> Result<Option<String>, DrawError> {
    let (name, _, _, wv_unit) = SENSORS[sensor];
    let curves: Vec<_> = (0..r.imus.len()).map(|k| mean_wv(r, k, sensor)).collect();
    let xs = curves.iter().flatten().map(|p| p.0);
    let ys = curves
        .iter()
        .flatten()
        .flat_map(|p| [p.1, p.3, p.2.max(p.1 / 10.0)]);
    let (Some(x), Some(y)) = (Decades::around(xs), Decades::around(ys)) else {
        return Ok(None);
    };
    let title =
        format!("{name}: each unit's own error wavelet variance (mean of its axes), 95% interval");
    let label = |v: &f64| decade_label(*v);
    render_svg((WIDTH, 600), |root| {
        let (plot_area, legend_area) = titled_with_legend(root, &title, WIDTH)?;
        let frame = Frame {
            margin: 12,
            x_labels: 45,
            y_labels: 70,
        };
        let mut c = chart(&plot_area, None, frame, x.axis(), y.axis())?;
        grey_grid(&mut c.configure_mesh(), 235, 200)
            .x_desc("scale \u{03c4} [s]")
            .y_desc(format!("wavelet variance [{wv_unit}]"))
            .x_label_formatter(&label)
            .y_label_formatter(&label)
            .draw()
            .map_err(draw_err)?;
        let mut legend = Vec::new();
        for (k, points) in curves.iter().enumerate() {
            let col = colour(Some(k));
            let band: Vec<(f64, f64)> = points
                .iter()
                .map(|p| (p.0, p.3))
                .chain(points.iter().rev().map(|p| (p.0, p.2.max(y.lo))))
                .collect();
            c.draw_series(std::iter::once(Polygon::new(band, col.mix(0.15))))
                .map_err(draw_err)?;
            c.draw_series(LineSeries::new(
                points.iter().map(|p| (p.0, p.1)),
                col.stroke_width(2),
            ))
            .map_err(draw_err)?;
            legend.push((Glyph::LineWithMarker(col), r.imus[k].name_short()));
        }
        draw_legend(&legend_area, &legend)?;
        Ok(())
    })
    .map(Some)
}

/// One panel of live levels: every unit's level of `sensor` against time, and a vertical
/// line at each of that sensor's faults, in the faulty unit's colour.
fn levels_panel(area: &Area<'_>, r: &RedundancyReport, sensor: usize) -> Result<(), DrawError> {
    let (name, _, unit, _) = SENSORS[sensor];
    let series = |k: usize| -> Vec<(f64, f64)> {
        let l = &r.noise_level[k];
        let v = if sensor == 0 {
            &l.gyro_rad_s
        } else {
            &l.accel_m_s2
        };
        l.t_s
            .iter()
            .copied()
            .zip(v.iter().copied())
            .filter(|p| usable(p.1))
            .collect()
    };
    let all: Vec<Vec<(f64, f64)>> = (0..r.noise_level.len()).map(series).collect();
    let (t0, t1) = all
        .iter()
        .flatten()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.0), b.max(p.0))
        });
    let Some(y) = Decades::around(all.iter().flatten().map(|p| p.1)) else {
        return Ok(());
    };
    if !(t0 < t1) {
        return Ok(());
    }
    let frame = Frame {
        margin: 12,
        x_labels: 40,
        y_labels: 70,
    };
    let mut c = chart(
        area,
        Some((&format!("{name}: live white-noise level"), 16)),
        frame,
        t0..t1,
        y.axis(),
    )?;
    let label = |v: &f64| decade_label(*v);
    grey_grid(&mut c.configure_mesh(), 235, 200)
        .x_desc("t [s]")
        .y_desc(format!("noise sd per sample [{unit}]"))
        .y_label_formatter(&label)
        .draw()
        .map_err(draw_err)?;
    for (k, points) in all.iter().enumerate() {
        c.draw_series(LineSeries::new(
            points.iter().copied(),
            colour(Some(k)).stroke_width(1),
        ))
        .map_err(draw_err)?;
    }
    for f in r.faults.iter().filter(|f| sensor_of(f) == sensor) {
        c.draw_series(std::iter::once(PathElement::new(
            vec![(f.t_detected_s, y.lo), (f.t_detected_s, y.hi)],
            colour(f.imu).mix(0.7).stroke_width(1),
        )))
        .map_err(draw_err)?;
    }
    Ok(())
}

/// The sensor (0 gyro, 1 accel) a fault record belongs to.
fn sensor_of(f: &FaultRecord) -> usize {
    usize::from(f.channel.starts_with('a'))
}

/// Both sensors' live levels, one above the other.
fn levels_svg(r: &RedundancyReport) -> Result<String, DrawError> {
    render_svg((WIDTH, 800), |root| {
        let (plot_area, legend_area) = titled_with_legend(
            root,
            "each unit's own live noise level; vertical lines: faults detected",
            WIDTH,
        )?;
        let panels = plot_area.split_evenly((2, 1));
        for (sensor, panel) in panels.iter().enumerate() {
            levels_panel(panel, r, sensor)?;
        }
        let mut legend: Vec<(Glyph, String)> = (0..r.imus.len())
            .map(|k| {
                (
                    Glyph::LineWithMarker(colour(Some(k))),
                    r.imus[k].name_short(),
                )
            })
            .collect();
        legend.push((Glyph::Bar(UNPLACED_COLOUR), "fault, no unit placed".into()));
        draw_legend(&legend_area, &legend)
    })
}

/// The faults' timeline: one row per unit (and one for faults no unit could be given), a
/// bar from detection to readmission (or the end), labelled with the kind and channel.
fn faults_svg(r: &RedundancyReport) -> Result<String, DrawError> {
    let t_end = r
        .noise_level
        .first()
        .and_then(|l| l.t_s.last().copied())
        .unwrap_or(1.0);
    let t_start = r
        .noise_level
        .first()
        .and_then(|l| l.t_s.first().copied())
        .unwrap_or(0.0)
        .min(t_end - 1.0);
    let rows = r.imus.len() + 1;
    let height = 160 + 50 * rows as u32;
    render_svg((WIDTH, height), |root| {
        let (plot_area, legend_area) =
            titled_with_legend(root, "faults: from detection to readmission", WIDTH)?;
        let frame = Frame {
            margin: 12,
            x_labels: 40,
            y_labels: 150,
        };
        let mut c = chart(
            &plot_area,
            None,
            frame,
            t_start..t_end,
            -0.5..rows as f64 - 0.5,
        )?;
        let row_name = |v: &f64| {
            let k = v.round() as usize;
            if (v - v.round()).abs() > 1e-6 {
                String::new()
            } else if k < r.imus.len() {
                r.imus[k].name_short()
            } else {
                "no unit placed".into()
            }
        };
        grey_grid(&mut c.configure_mesh(), 235, 200)
            .x_desc("t [s]")
            .y_labels(rows)
            .y_label_formatter(&row_name)
            .draw()
            .map_err(draw_err)?;
        for f in &r.faults {
            let row = f.imu.unwrap_or(r.imus.len()) as f64;
            let end = f
                .t_readmitted_s
                .unwrap_or(t_end)
                .max(f.t_detected_s + (t_end - t_start) / 500.0);
            c.draw_series(std::iter::once(Rectangle::new(
                [(f.t_detected_s, row - 0.3), (end, row + 0.3)],
                colour(f.imu).mix(0.6).filled(),
            )))
            .map_err(draw_err)?;
            c.draw_series(std::iter::once(Text::new(
                format!("{} {}", f.kind, f.channel),
                (f.t_detected_s, row + 0.42),
                (FONT, 12),
            )))
            .map_err(draw_err)?;
        }
        let legend: Vec<(Glyph, String)> = (0..r.imus.len())
            .map(|k| (Glyph::Bar(colour(Some(k))), r.imus[k].name_short()))
            .collect();
        draw_legend(&legend_area, &legend)
    })
}

/// The report's Markdown: figures, each unit's own white noise and alignment, the faults
/// and the notes.
fn markdown(r: &RedundancyReport, figures: &[String]) -> String {
    let mut s = String::from("# Redundant IMUs: each unit's own error, from the set\n\n");
    s.push_str("## Own white noise (standard deviation per sample, SI units)\n\n");
    s.push_str("| unit | gx | gy | gz | ax | ay | az | rotation to the first (roll, pitch, yaw, deg) | lever arm (m) |\n|---|---|---|---|---|---|---|---|---|\n");
    for u in &r.imus {
        let sd = |c: &str| format!("{:.3e}", u.white_noise_sigma2[c].max(0.0).sqrt());
        let rotation = u
            .alignment
            .rotation_rpy_deg
            .map_or("not determined".to_string(), |a| {
                format!("{:.2}, {:.2}, {:.2}", a[0], a[1], a[2])
            });
        let lever = u.alignment.lever_arm_m.map_or("-".to_string(), |l| {
            format!("{:.3}, {:.3}, {:.3}", l[0], l[1], l[2])
        });
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {rotation} | {lever} |",
            u.name,
            sd("gx"),
            sd("gy"),
            sd("gz"),
            sd("ax"),
            sd("ay"),
            sd("az")
        );
    }
    for f in figures {
        let _ = writeln!(s, "\n![{f}]({f})");
    }
    s.push_str("\n## Faults\n\n");
    if r.faults.is_empty() {
        s.push_str("None found.\n");
    } else {
        s.push_str(
            "| unit | channel | kind | detected (s) | readmitted (s) |\n|---|---|---|---|---|\n",
        );
        for f in &r.faults {
            let unit = f
                .imu
                .map_or("not placed".to_string(), |k| r.imus[k].name_short());
            // An alarm no unit could be given excluded nothing, so nothing is readmitted.
            let back = match (f.imu, f.t_readmitted_s) {
                (None, _) => "-".to_string(),
                (Some(_), Some(t)) => format!("{t:.2}"),
                (Some(_), None) => "never".to_string(),
            };
            let _ = writeln!(
                s,
                "| {unit} | {} | {} | {:.2} | {back} |",
                f.channel, f.kind, f.t_detected_s
            );
        }
    }
    s.push_str("\n## Notes\n\n");
    for n in &r.notes {
        let _ = writeln!(s, "- {n}");
    }
    s
}

/// What a reader acts on: each unit's own white noise against the set's quietest, and the
/// faults found.
pub fn html_summary(r: &RedundancyReport) -> Vec<String> {
    let mut lines = Vec::new();
    for (name, channels, unit, _) in SENSORS {
        let sd: Vec<f64> = r
            .imus
            .iter()
            .map(|u| {
                let mean: f64 = channels
                    .iter()
                    .map(|c| u.white_noise_sigma2[*c].max(0.0))
                    .sum::<f64>()
                    / 3.0;
                mean.sqrt()
            })
            .collect();
        let quietest = sd.iter().copied().fold(f64::INFINITY, f64::min);
        for (u, s) in r.imus.iter().zip(&sd) {
            if *s > 1.5 * quietest {
                lines.push(format!(
                    "{}: {name} white noise {} {unit} per sample, {}x the quietest unit's.",
                    u.name_short(),
                    crate::report::html::significant(*s, 3),
                    crate::report::html::significant(s / quietest, 2)
                ));
            }
        }
    }
    if r.faults.is_empty() {
        lines.push(format!(
            "{} units, no fault found; each unit's own noise is in the table below.",
            r.imus.len()
        ));
    } else {
        lines.push(format!(
            "{} faults found and isolated (table below).",
            r.faults.len()
        ));
    }
    lines
}

/// The units' own white noise and alignment to the first unit as a table.
fn own_noise_table(r: &RedundancyReport) -> Table {
    let rows = r
        .imus
        .iter()
        .map(|u| {
            let mut row = vec![Cell::from(u.name_short())];
            for c in ["gx", "gy", "gz", "ax", "ay", "az"] {
                row.push(Cell::Number(u.white_noise_sigma2[c].max(0.0).sqrt()));
            }
            row.push(
                u.alignment
                    .rotation_rpy_deg
                    .map_or("not determined".into(), |a| {
                        Cell::from(format!(
                            "{}, {}, {}",
                            crate::report::html::significant(a[0], 3),
                            crate::report::html::significant(a[1], 3),
                            crate::report::html::significant(a[2], 3)
                        ))
                    }),
            );
            row
        })
        .collect();
    Table {
        caption: "Each unit's own white noise (standard deviation per sample, from the units' \
                  differences) and its rotation to the first unit"
            .into(),
        header: [
            "unit",
            "gx (rad/s)",
            "gy (rad/s)",
            "gz (rad/s)",
            "ax (m/s^2)",
            "ay (m/s^2)",
            "az (m/s^2)",
            "rotation to the first (roll, pitch, yaw; deg)",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }
}

fn faults_table(r: &RedundancyReport) -> Table {
    let rows = r
        .faults
        .iter()
        .map(|f| {
            let unit = f
                .imu
                .map_or("not placed".to_string(), |k| r.imus[k].name_short());
            vec![
                Cell::from(unit),
                Cell::from(f.channel.to_string()),
                Cell::from(f.kind.to_string()),
                Cell::Number(f.t_detected_s),
                match (f.imu, f.t_readmitted_s) {
                    (None, _) => "-".into(),
                    (Some(_), Some(t)) => Cell::Number(t),
                    (Some(_), None) => "never".into(),
                },
            ]
        })
        .collect();
    Table {
        caption: "Faults found and isolated".into(),
        header: ["unit", "channel", "kind", "detected (s)", "readmitted (s)"]
            .map(String::from)
            .to_vec(),
        rows,
    }
}

/// The redundancy's sections of an HTML report: own noise and alignment, the own wavelet
/// variances, the live noise levels, the faults, the notes.
pub fn html_sections(r: &RedundancyReport) -> Result<Vec<Section>, ReportError> {
    let mut own = Section::new("Redundant IMUs: each unit's own error").table(own_noise_table(r));
    for (sensor, (name, ..)) in SENSORS.iter().enumerate() {
        let file = format!("own-wv-{name}.svg");
        let svg = own_wv_svg(r, sensor).map_err(|e| plot_error(&file, e))?;
        own = own.figure(
            format!(
                "Each unit's own {name} wavelet variance (mean of the axes) with its 95% interval"
            ),
            svg,
        );
    }
    let levels = levels_svg(r).map_err(|e| plot_error("noise-levels.svg", e))?;
    let mut live = Section::new("Redundant IMUs: live noise levels and faults").figure(
        "Each unit's live white-noise level over time, faults marked where detected",
        Some(levels),
    );
    if r.faults.is_empty() {
        live = live.paragraph("No fault found.");
    } else {
        let faults = faults_svg(r).map_err(|e| plot_error("faults.svg", e))?;
        live = live
            .table(faults_table(r))
            .figure("Faults from detection to readmission", Some(faults));
    }
    for n in &r.notes {
        live = live.paragraph(format!("Note: {n}"));
    }
    Ok(vec![own, live])
}

impl super::UnitReport {
    /// The unit's file name without its folders.
    pub fn name_short(&self) -> String {
        Path::new(&self.name)
            .file_name()
            .map_or(self.name.clone(), |f| f.to_string_lossy().into_owned())
    }
}
