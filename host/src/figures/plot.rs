//! SVG drawing of Fig. 1 with `plotters` (SVG backend only): one row per extra IMU, lever
//! arm on the left and boresight on the right as in the paper, each axis's estimate with its
//! ±3σ envelope against time and the truth as a dashed line.

use plotters::prelude::*;

use super::fig1::{CalibrationPoint, Fig1Run};

/// Why drawing failed.
#[derive(Debug, thiserror::Error)]
#[error("drawing the figure: {0}")]
pub struct PlotError(String);

fn plot_err<E: std::fmt::Display>(e: E) -> PlotError {
    PlotError(e.to_string())
}

/// Most points drawn per curve; longer traces are decimated evenly (the SVG stays small).
const MAX_POINTS: usize = 600;

const AXIS_COLOURS: [RGBColor; 3] = [RGBColor(200, 30, 30), RGBColor(20, 140, 40), BLUE];
const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

/// One panel's quantity: value and sigma of axis `a` in display units.
struct Quantity {
    title: &'static str,
    unit: &'static str,
    value: fn(&CalibrationPoint, usize) -> f64,
    sigma: fn(&CalibrationPoint, usize) -> f64,
    truth: [f64; 3],
    /// Half-height of the y-range beyond the truth's span, display units.
    margin: f64,
}

/// Renders the run as an SVG document.
pub fn fig1_svg(run: &Fig1Run) -> Result<String, PlotError> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1200, 820)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let (title_area, body) = root.split_vertically(40);
        title_area
            .titled(
                &format!(
                    "Joint inter-IMU lever-arm and boresight estimation (simulated car, {} s, seed {}, \u{00b1}3\u{03c3} envelopes, truth dashed)",
                    run.report.seconds, run.report.seed
                ),
                ("sans-serif", 18),
            )
            .map_err(plot_err)?;
        let panels = body.split_evenly((2, 2));
        let t_end = run.trace.t_s.last().copied().unwrap_or(1.0);
        let step = run.trace.t_s.len().div_ceil(MAX_POINTS).max(1);
        for (imu, truth) in run.truth.iter().enumerate().take(2) {
            let quantities = [
                Quantity {
                    title: "lever arm",
                    unit: "cm",
                    value: |p, a| p.lever_arm_b_m[a] * 100.0,
                    sigma: |p, a| p.lever_arm_sigma_m[a] * 100.0,
                    truth: truth.lever_arm_b_m.map(|x| x * 100.0),
                    margin: 15.0,
                },
                Quantity {
                    title: "boresight",
                    unit: "deg",
                    value: |p, a| p.boresight_rad[a].to_degrees(),
                    sigma: |p, a| p.boresight_sigma_rad[a].to_degrees(),
                    truth: truth.boresight_rad.map(f64::to_degrees),
                    margin: 4.0,
                },
            ];
            let name = &run.report.imus[imu].name;
            for (column, q) in quantities.iter().enumerate() {
                let area = &panels[2 * imu + column];
                let lo = q.truth.iter().copied().fold(f64::INFINITY, f64::min) - q.margin;
                let hi = q.truth.iter().copied().fold(f64::NEG_INFINITY, f64::max) + q.margin;
                let clamp = |y: f64| y.clamp(lo, hi);
                let mut chart = ChartBuilder::on(area)
                    .caption(
                        format!("{name}: {} [{}]", q.title, q.unit),
                        ("sans-serif", 16),
                    )
                    .margin(8)
                    .x_label_area_size(30)
                    .y_label_area_size(45)
                    .build_cartesian_2d(0.0..t_end, lo..hi)
                    .map_err(plot_err)?;
                chart
                    .configure_mesh()
                    .x_desc("time [s]")
                    .y_desc(q.unit)
                    .light_line_style(WHITE.mix(0.0))
                    .draw()
                    .map_err(plot_err)?;
                let points = &run.trace.points[imu];
                let indices: Vec<usize> = (0..points.len())
                    .step_by(step)
                    .chain(std::iter::once(points.len().saturating_sub(1)))
                    .collect();
                for (a, colour) in AXIS_COLOURS.iter().enumerate() {
                    let envelope: Vec<(f64, f64)> = indices
                        .iter()
                        .map(|&k| {
                            let p = &points[k];
                            (
                                run.trace.t_s[k],
                                clamp((q.value)(p, a) + 3.0 * (q.sigma)(p, a)),
                            )
                        })
                        .chain(indices.iter().rev().map(|&k| {
                            let p = &points[k];
                            (
                                run.trace.t_s[k],
                                clamp((q.value)(p, a) - 3.0 * (q.sigma)(p, a)),
                            )
                        }))
                        .collect();
                    chart
                        .draw_series(std::iter::once(Polygon::new(envelope, colour.mix(0.15))))
                        .map_err(plot_err)?;
                    chart
                        .draw_series(LineSeries::new(
                            indices
                                .iter()
                                .map(|&k| (run.trace.t_s[k], clamp((q.value)(&points[k], a)))),
                            colour.stroke_width(2),
                        ))
                        .map_err(plot_err)?
                        .label(format!("{} ({})", AXIS_NAMES[a], q.unit))
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                        });
                    chart
                        .draw_series(DashedLineSeries::new(
                            [(0.0, q.truth[a]), (t_end, q.truth[a])],
                            8,
                            5,
                            colour.mix(0.9).stroke_width(1),
                        ))
                        .map_err(plot_err)?;
                }
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .position(SeriesLabelPosition::UpperRight)
                    .draw()
                    .map_err(plot_err)?;
            }
        }
        root.present().map_err(plot_err)?;
    }
    Ok(svg)
}
