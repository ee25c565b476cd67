//! The HTML reports of `dynacal wv --report DIR` and `dynacal fit --report DIR`: each
//! channel's Haar wavelet variance with its 95% interval (and the fitted model's), the
//! tables behind the figures, and a summary of what the numbers say in the units people
//! quote (white-noise density, the fitted model and whether it passes its J-test).

use std::collections::BTreeMap;

use super::charts::{panels_svg, Axes, Panel, Series, Shape, PALETTE};
use super::html::significant;
use super::{Cell, HtmlReport, Section, Table};
use crate::figures::plot::DrawError;
use crate::gmwm::inference::ChannelFit;
use crate::wv::WaveletVariance;

/// The unit of a channel's values from its name's first letter (`g*` gyros, `a*`
/// accelerometers), or the SI unit the caller gives.
fn unit_of(channel: &str, fallback: &str) -> String {
    match channel.as_bytes().first() {
        Some(b'g') => "rad/s".into(),
        Some(b'a') => "m/s^2".into(),
        _ => fallback.into(),
    }
}

/// White-noise density read off the finest scale, unit/sqrt(Hz): white noise of variance
/// s^2 per sample has wavelet variance s^2/2 at scale dt, and density s sqrt(dt). An upper
/// bound where other processes add to the finest scale.
pub fn finest_scale_density(wv: &WaveletVariance) -> Option<f64> {
    let nu1 = *wv.variance.first()?;
    (nu1 > 0.0).then(|| (2.0 * nu1).sqrt() * wv.dt_s.sqrt())
}

fn wv_points(wv: &WaveletVariance) -> Vec<(f64, f64, f64, f64)> {
    (0..wv.len())
        .map(|k| (wv.scales_s[k], wv.variance[k], wv.ci_low[k], wv.ci_high[k]))
        .collect()
}

/// `dynacal wv`'s report: one panel per channel, the levels' table, and the summary.
pub fn wv_report(
    file: &str,
    channels: &BTreeMap<String, WaveletVariance>,
) -> Result<HtmlReport, DrawError> {
    let mut summary = Vec::new();
    let mut panels = Vec::new();
    let mut rows = Vec::new();
    for (k, (name, wv)) in channels.iter().enumerate() {
        let unit = unit_of(name, "unit");
        if let Some(d) = finest_scale_density(wv) {
            summary.push(format!(
                "{name}: {} samples; white-noise density at most {} {unit}/sqrt(Hz) (from the \
                 finest scale, {} s).",
                wv.n,
                significant(d, 3),
                significant(wv.dt_s, 3)
            ));
        }
        panels.push(Panel {
            title: format!("{name}: Haar wavelet variance, 95% interval"),
            x_label: "scale (s)".into(),
            y_label: format!("wavelet variance ({unit})^2"),
            axes: Axes::LogLog,
            series: vec![Series::new(
                name.clone(),
                PALETTE[k % PALETTE.len()],
                Shape::PointsWithBars(wv_points(wv)),
            )],
        });
        for (j, (s, v, lo, hi)) in wv_points(wv).into_iter().enumerate() {
            rows.push(vec![
                Cell::from(name.clone()),
                Cell::Number(f64::from(wv.levels[j])),
                Cell::Number(s),
                Cell::Number(v),
                Cell::Interval(lo, hi),
                Cell::Number(wv.allan_deviation().get(j).copied().unwrap_or(f64::NAN)),
            ]);
        }
    }
    let svg = panels_svg("Haar wavelet variance of each channel", &panels)?;
    let section = Section::new("Wavelet variance")
        .paragraph(format!("Recording: {file}."))
        .figure(
            "Haar wavelet variance of each channel with its 95% interval (chi-square, \
             equivalent degrees of freedom eta3)",
            svg,
        )
        .table(Table {
            caption: "Each level's wavelet variance (squared unit of the channel) and the Allan \
                      deviation at the same scale (unit of the channel)"
                .into(),
            header: [
                "channel",
                "level",
                "scale (s)",
                "wavelet variance",
                "95% interval",
                "Allan deviation",
            ]
            .map(String::from)
            .to_vec(),
            rows,
        });
    Ok(HtmlReport {
        title: format!("dynacal wv: {file}"),
        summary,
        sections: vec![section],
    })
}

fn fit_summary(f: &ChannelFit) -> String {
    let j = f.j_test.as_ref().map_or(String::new(), |j| {
        format!(
            "; J-test p {} ({})",
            significant(j.p_value, 2),
            if j.p_value < 0.05 {
                "the model misses structure in the data"
            } else {
                "the model is not rejected"
            }
        )
    });
    let converged = if f.converged { "" } else { " NOT converged;" };
    format!(
        "{}: {} fitted on {} samples;{converged} objective {}{j}.",
        f.channel,
        f.model,
        f.n,
        significant(f.objective, 3)
    )
}

/// `dynacal fit`'s report: each channel's wavelet variance with the fitted model's, the
/// parameters with their 95% intervals, and a summary per channel.
pub fn fit_report(file: &str, fits: &[ChannelFit]) -> Result<HtmlReport, DrawError> {
    let mut panels = Vec::new();
    let mut rows = Vec::new();
    for (k, f) in fits.iter().enumerate() {
        let pairs = |values: &[f64]| -> Vec<(f64, f64)> {
            f.scales_s
                .iter()
                .copied()
                .zip(values.iter().copied())
                .collect()
        };
        panels.push(Panel {
            title: format!("{}: wavelet variance and the fitted {}", f.channel, f.model),
            x_label: "scale (s)".into(),
            y_label: format!("wavelet variance ({})^2", unit_of(&f.channel, &f.unit)),
            axes: Axes::LogLog,
            series: vec![
                Series::new(
                    "measured",
                    PALETTE[k % PALETTE.len()],
                    Shape::Points(pairs(&f.wv)),
                ),
                Series::new(
                    format!("{} fitted", f.model),
                    PALETTE[(k + 1) % PALETTE.len()],
                    Shape::Line(pairs(&f.model_wv)),
                ),
            ],
        });
        for p in &f.parameters {
            rows.push(vec![
                Cell::from(f.channel.clone()),
                Cell::from(p.process.clone()),
                Cell::from(format!("{} ({})", p.name, p.unit)),
                Cell::Number(p.value),
                p.ci95.map_or("-".into(), |c| Cell::Interval(c[0], c[1])),
            ]);
        }
    }
    let svg = panels_svg("Wavelet variance and the fitted models", &panels)?;
    let section = Section::new("GMWM fit")
        .paragraph(format!("Recording: {file}."))
        .table(Table {
            caption: "Fitted parameters with their 95% intervals".into(),
            header: ["channel", "process", "parameter", "value", "95% interval"]
                .map(String::from)
                .to_vec(),
            rows,
        })
        .figure(
            "Each channel's wavelet variance (points) and the fitted model's (line)",
            svg,
        );
    Ok(HtmlReport {
        title: format!("dynacal fit: {file}"),
        summary: fits.iter().map(fit_summary).collect(),
        sections: vec![section],
    })
}
