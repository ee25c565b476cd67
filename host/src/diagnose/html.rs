//! The diagnosis in the HTML report (`report.html` of `dynacal diagnose --report DIR`, and a
//! part of `dynacal demo`'s): the summary a person acts on (what is wrong, where, how sure,
//! and what the extended model gains), then the calibration, the discrepancies, the named
//! causes and the gain, each table in readable units with 3-4 significant digits, with the
//! wavelet-variance, findings and gain figures of [`super::report`].

use super::engine::DiagnoseReport;
use super::generalise::FOLDS;
use super::readable::{self, significant};
use super::report::{causes_on, findings_svg, gain_svg, wv_svg, ReportError};
use crate::report::{Cell, Section, Table};

const DEG_PER_RAD: f64 = 180.0 / std::f64::consts::PI;

/// One line per named cause (a cause of the whole sensor, a time offset or a lever arm,
/// named alike on several channels, once with its channels), and one line of what the
/// extended model gains held out; or that nothing beyond the baseline was found.
pub fn summary(r: &DiagnoseReport) -> Vec<String> {
    if r.findings.is_empty() {
        return vec![format!(
            "Nothing beyond the baseline: no test of {} named a cause at the family-wise level {} \
             (the baseline model explains this recording).",
            r.tests, r.alpha
        )];
    }
    // (cause, estimate, p) -> channels, in the findings' order.
    let mut grouped: Vec<(String, Vec<String>, f64)> = Vec::new();
    for f in &r.findings {
        let what = format!(
            "{} {} (family-wise p {})",
            f.cause,
            readable::estimate(f),
            readable::p_value(f.p_value)
        );
        match grouped.iter_mut().find(|(w, ..)| *w == what) {
            Some((_, channels, share)) => {
                channels.push(f.channel.to_string());
                *share = share.max(f.variance_explained);
            }
            None => grouped.push((what, vec![f.channel.to_string()], f.variance_explained)),
        }
    }
    let mut lines: Vec<String> = grouped
        .into_iter()
        .map(|(what, channels, share)| {
            let share = if share > 0.0 {
                format!(", {}% of the error variance", significant(100.0 * share, 3))
            } else {
                String::new()
            };
            format!("{}: {what}{share}.", channels.join(", "))
        })
        .collect();
    let gains: Vec<String> = r
        .gain
        .iter()
        .filter(|(_, g)| g.held_out_extended < g.held_out_baseline)
        .map(|(channel, g)| {
            format!(
                "{channel} {} to {}",
                significant(g.held_out_baseline, 3),
                significant(g.held_out_extended, 3)
            )
        })
        .collect();
    if !gains.is_empty() {
        lines.push(format!(
            "The extended model (extended-model.json) lowers the held-out WV misfit (about 1 \
             for a model that fits): {}.",
            gains.join("; ")
        ));
    }
    lines
}

fn calibration_table(r: &DiagnoseReport) -> Option<Table> {
    let c = r.calibration.as_ref()?;
    let mut rows = vec![];
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        let mut row: Vec<Cell> = vec![
            axis.to_string().into(),
            Cell::PlusMinus(
                c.boresight_rad.value[k] * DEG_PER_RAD,
                c.boresight_rad.sigma[k] * DEG_PER_RAD,
            ),
        ];
        row.push(match c.lever_arm_m {
            Some(l) => Cell::PlusMinus(l.value[k] * 1e3, l.sigma[k] * 1e3),
            None => "not estimated".into(),
        });
        rows.push(row);
    }
    let offset = c.time_offset_s.map_or("not estimated".to_string(), |t| {
        format!(
            "{} ± {} ms",
            significant(t.value * 1e3, 4),
            significant(t.sigma * 1e3, 2)
        )
    });
    Some(Table {
        caption: format!(
            "Calibration against the {} ({} epochs of {} s; 1-sigma); time offset {offset}",
            c.reference_kind,
            c.epochs,
            significant(c.epoch_dt_s, 3)
        ),
        header: vec![
            "axis".into(),
            "boresight (deg)".into(),
            "lever arm (mm)".into(),
        ],
        rows,
    })
}

fn discrepancy_table(r: &DiagnoseReport) -> Table {
    Table {
        caption: "What the simulation of the baseline gets wrong".into(),
        header: vec![
            "channel".into(),
            "statistic".into(),
            "measured".into(),
            "baseline simulations".into(),
            "detail".into(),
        ],
        rows: r
            .discrepancies
            .iter()
            .map(|d| {
                vec![
                    d.channel.name().into(),
                    d.statistic.clone().into(),
                    Cell::Number(d.measured),
                    Cell::Interval(d.simulated_range[0], d.simulated_range[1]),
                    d.detail.clone().into(),
                ]
            })
            .collect(),
    }
}

fn findings_table(r: &DiagnoseReport) -> Table {
    let rows = r
        .findings
        .iter()
        .map(|f| {
            let kept = r
                .gain
                .get(&f.channel)
                .is_none_or(|g| g.not_kept.iter().all(|n| n.cause != f.cause));
            vec![
                f.channel.name().into(),
                f.cause.name().into(),
                f.regressors.join(", ").into(),
                readable::estimate(f).into(),
                readable::p_value(f.p_value).into(),
                Cell::Number(100.0 * f.variance_explained),
                if kept { "yes" } else { "no" }.into(),
            ]
        })
        .collect();
    Table {
        caption: format!(
            "Named causes: family-wise p-value below alpha = {} over {} tests (Bonferroni)",
            r.alpha, r.tests
        ),
        header: vec![
            "channel".into(),
            "cause".into(),
            "regressors".into(),
            "estimate ± 95% half-width".into(),
            "family-wise p".into(),
            "variance explained (%)".into(),
            "in the extended model".into(),
        ],
        rows,
    }
}

fn gain_table(r: &DiagnoseReport) -> Table {
    Table {
        caption: format!(
            "Gain of the extended model: WV misfit (mean squared z of the log wavelet variance; \
             about 1 for a model that fits), in-sample and held out over {FOLDS} time blocks"
        ),
        header: vec![
            "channel".into(),
            "baseline".into(),
            "extended".into(),
            "held-out baseline".into(),
            "held-out extended".into(),
            "held-out variance explained (%)".into(),
        ],
        rows: r
            .gain
            .iter()
            .map(|(ch, g)| {
                vec![
                    ch.name().into(),
                    Cell::Number(g.baseline),
                    Cell::Number(g.extended),
                    Cell::Number(g.held_out_baseline),
                    Cell::Number(g.held_out_extended),
                    Cell::Number(100.0 * g.held_out_variance_explained),
                ]
            })
            .collect(),
    }
}

/// The diagnosis's sections, their headings prefixed by `label` (e.g. the sensor's name in a
/// report of several). The wavelet-variance figures are those of the channels where a cause
/// was named, or every channel when none was.
pub fn sections(r: &DiagnoseReport, label: &str) -> Result<Vec<Section>, ReportError> {
    let mut wrong = Section::new(format!("{label}What the simulation gets wrong"))
        .paragraph(format!("Baseline: {}.", r.baseline_source));
    for n in &r.notes {
        wrong = wrong.paragraph(format!("Note: {n}"));
    }
    if let Some(t) = calibration_table(r) {
        wrong = wrong.table(t);
    }
    wrong = wrong.table(discrepancy_table(r));
    let named: Vec<_> = r.findings.iter().map(|f| f.channel).collect();
    for (channel, curves) in &r.wv_curves {
        if !named.is_empty() && !named.contains(channel) {
            continue;
        }
        let causes = causes_on(&r.findings, *channel);
        let file = format!("wv-{channel}.svg");
        let svg = wv_svg(channel.name(), curves, &causes).map_err(|e| e.on(&file))?;
        wrong = wrong.figure(
            format!(
                "{label}{channel}: Haar wavelet variance of the measured error (red) against the \
                 95% bands of simulations of the baseline (grey) and the extended model (blue)"
            ),
            svg,
        );
    }
    let causes = Section::new(format!("{label}Named causes"))
        .table(findings_table(r))
        .figure(
            format!("{label}Share of each channel's error variance the named causes explain"),
            findings_svg(&r.findings).map_err(|e| e.on("findings.svg"))?,
        );
    let gain = Section::new(format!("{label}The extended model and its gain"))
        .table(gain_table(r))
        .figure(
            format!("{label}WV misfit of the baseline and the extended model per channel"),
            gain_svg(&r.gain).map_err(|e| e.on("gain.svg"))?,
        );
    Ok(vec![wrong, causes, gain])
}
