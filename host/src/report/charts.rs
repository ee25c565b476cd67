//! The report's general charts: one or more panels stacked in one SVG, each plotting series
//! of lines, points, dashed lines and shaded bands against linear or log-log axes, with the
//! legend beside the panel. The paper's figures are all of this kind: estimates converging
//! against time (Fig. 3), error signals (Fig. 4), errors against dynamics (Fig. 5), wavelet
//! variances with a model (Figs. 6, 7), noise levels over time (Fig. 8).
//!
//! Long series are thinned before drawing so a page stays light: a line keeps the minimum and
//! the maximum of each of [`MAX_LINE_BUCKETS`] buckets (its envelope looks as drawn at full
//! length), a point cloud keeps every k-th point up to [`MAX_POINTS`].

use plotters::coord::ranged1d::Ranged;
use plotters::prelude::*;

use super::html::significant;

use crate::figures::plot::{
    chart, decade_label, draw_err, draw_legend, grey_grid, render_svg, titled_with_legend, usable,
    Area, Chart, Decades, DrawError, Frame, Glyph,
};

/// Buckets of a thinned line: two points (minimum, maximum) are kept from each.
pub const MAX_LINE_BUCKETS: usize = 1500;
/// Points kept of a point cloud.
pub const MAX_POINTS: usize = 3000;

/// Width of every chart, pixels.
const WIDTH_PX: u32 = 1100;
/// Height of one panel, pixels.
const PANEL_HEIGHT_PX: u32 = 330;

/// The colours of series in order (a series may name its own).
pub const PALETTE: [RGBColor; 6] = [
    RGBColor(200, 30, 30),
    RGBColor(30, 100, 200),
    RGBColor(20, 140, 40),
    RGBColor(220, 120, 20),
    RGBColor(130, 50, 170),
    RGBColor(90, 90, 90),
];

/// Grey of a truth or reference drawn behind an estimate.
pub const GREY: RGBColor = RGBColor(150, 150, 150);

/// What a series draws.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A line through `(x, y)`.
    Line(Vec<(f64, f64)>),
    /// A dashed line through `(x, y)`.
    Dashed(Vec<(f64, f64)>),
    /// Markers at `(x, y)`.
    Points(Vec<(f64, f64)>),
    /// Markers at `(x, y)` with a vertical bar from `lo` to `hi`: `(x, y, lo, hi)`.
    PointsWithBars(Vec<(f64, f64, f64, f64)>),
    /// A shaded band from `lo` to `hi`: `(x, lo, hi)`.
    Band(Vec<(f64, f64, f64)>),
}

/// One series of a panel.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub label: String,
    pub colour: RGBColor,
    pub shape: Shape,
}

/// Linear or log-log axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axes {
    Linear,
    LogLog,
}

/// One panel: its title, axis labels (with units), axes and series.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub axes: Axes,
    pub series: Vec<Series>,
}

impl Series {
    pub fn new(label: impl Into<String>, colour: RGBColor, shape: Shape) -> Self {
        Self {
            label: label.into(),
            colour,
            shape,
        }
    }

    /// Every `(x, y)` the series spans, bands and bars by both ends.
    fn extent(&self) -> Vec<(f64, f64)> {
        match &self.shape {
            Shape::Line(p) | Shape::Dashed(p) | Shape::Points(p) => p.clone(),
            Shape::PointsWithBars(p) => p
                .iter()
                .flat_map(|&(x, _, lo, hi)| [(x, lo), (x, hi)])
                .collect(),
            Shape::Band(b) => b
                .iter()
                .flat_map(|&(x, lo, hi)| [(x, lo), (x, hi)])
                .collect(),
        }
    }

    fn glyph(&self) -> Glyph {
        match self.shape {
            Shape::Band(_) => Glyph::Band(self.colour),
            Shape::Dashed(_) => Glyph::Dashed(self.colour),
            _ => Glyph::LineWithMarker(self.colour),
        }
    }
}

/// A line thinned to the minimum and maximum of each of `buckets` equal runs of points.
pub fn thin_line(points: &[(f64, f64)], buckets: usize) -> Vec<(f64, f64)> {
    if points.len() <= 2 * buckets.max(1) {
        return points.to_vec();
    }
    let per = points.len().div_ceil(buckets.max(1));
    let mut out = Vec::with_capacity(2 * buckets);
    for run in points.chunks(per) {
        let finite = run.iter().filter(|p| p.1.is_finite());
        let lo = finite.clone().min_by(|a, b| a.1.total_cmp(&b.1));
        let hi = finite.max_by(|a, b| a.1.total_cmp(&b.1));
        if let (Some(&lo), Some(&hi)) = (lo, hi) {
            // In time order, so the line goes through both.
            if lo.0 <= hi.0 {
                out.extend([lo, hi]);
            } else {
                out.extend([hi, lo]);
            }
        }
    }
    out
}

/// Every k-th point, at most `max` of them.
pub fn thin_points<T: Copy>(points: &[T], max: usize) -> Vec<T> {
    let step = points.len().div_ceil(max.max(1)).max(1);
    points.iter().step_by(step).copied().collect()
}

fn drawable(axes: Axes, (x, y): (f64, f64)) -> bool {
    match axes {
        Axes::Linear => x.is_finite() && y.is_finite(),
        Axes::LogLog => usable(x) && usable(y),
    }
}

/// The range of one axis's values, padded by 5% (a constant widened to show it).
fn linear_range(values: impl Iterator<Item = f64>) -> Option<std::ops::Range<f64>> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return None;
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1e-12)
    };
    Some(lo - pad..hi + pad)
}

/// The panels stacked in one SVG under `title`; None when no panel has anything to draw.
pub fn panels_svg(title: &str, panels: &[Panel]) -> Result<Option<String>, DrawError> {
    let drawn: Vec<&Panel> = panels
        .iter()
        .filter(|p| {
            p.series
                .iter()
                .any(|s| s.extent().into_iter().any(|q| drawable(p.axes, q)))
        })
        .collect();
    if drawn.is_empty() {
        return Ok(None);
    }
    let height = 40 + PANEL_HEIGHT_PX * drawn.len() as u32;
    render_svg((WIDTH_PX, height), |root| {
        let (plots, legends) = titled_with_legend(root, title, WIDTH_PX)?;
        let plot_rows = plots.split_evenly((drawn.len(), 1));
        let legend_rows = legends.split_evenly((drawn.len(), 1));
        for ((panel, plot), legend) in drawn.iter().zip(&plot_rows).zip(&legend_rows) {
            draw_panel(plot, panel)?;
            let entries: Vec<(Glyph, String)> = panel
                .series
                .iter()
                .filter(|s| !s.label.is_empty())
                .map(|s| (s.glyph(), s.label.clone()))
                .collect();
            draw_legend(legend, &entries)?;
        }
        Ok(())
    })
    .map(Some)
}

const FRAME: Frame = Frame {
    margin: 12,
    x_labels: 45,
    y_labels: 85,
};

fn draw_panel(area: &Area<'_>, panel: &Panel) -> Result<(), DrawError> {
    let points: Vec<(f64, f64)> = panel
        .series
        .iter()
        .flat_map(Series::extent)
        .filter(|&q| drawable(panel.axes, q))
        .collect();
    let caption = Some((panel.title.as_str(), 16));
    match panel.axes {
        Axes::Linear => {
            let (Some(x), Some(y)) = (
                linear_range(points.iter().map(|p| p.0)),
                linear_range(points.iter().map(|p| p.1)),
            ) else {
                return Ok(());
            };
            // A tick a rounding error away from zero is zero, not `-2.22e-16`.
            let label = |v: f64, span: f64, digits| {
                let v = if v.abs() < 1e-9 * span { 0.0 } else { v };
                significant(v, digits)
            };
            let (x_span, y_span) = (x.end - x.start, y.end - y.start);
            let mut c = chart(area, caption, FRAME, x, y)?;
            grey_grid(&mut c.configure_mesh(), 235, 205)
                .x_desc(panel.x_label.as_str())
                .y_desc(panel.y_label.as_str())
                .y_label_formatter(&|v| label(*v, y_span, 3))
                .x_label_formatter(&|v| label(*v, x_span, 4))
                .draw()
                .map_err(draw_err)?;
            draw_series(&mut c, panel)
        }
        Axes::LogLog => {
            let (Some(x), Some(y)) = (
                Decades::around(points.iter().map(|p| p.0)),
                Decades::around(points.iter().map(|p| p.1)),
            ) else {
                return Ok(());
            };
            let mut c = chart(area, caption, FRAME, x.axis(), y.axis())?;
            grey_grid(&mut c.configure_mesh(), 235, 205)
                .x_desc(panel.x_label.as_str())
                .y_desc(panel.y_label.as_str())
                .x_label_formatter(&|v| decade_label(*v))
                .y_label_formatter(&|v| decade_label(*v))
                .draw()
                .map_err(draw_err)?;
            draw_series(&mut c, panel)
        }
    }
}

fn draw_series<X, Y>(c: &mut Chart<'_, '_, X, Y>, panel: &Panel) -> Result<(), DrawError>
where
    X: Ranged<ValueType = f64>,
    Y: Ranged<ValueType = f64>,
{
    let ok = |q: &(f64, f64)| drawable(panel.axes, *q);
    // Bands first, so lines and points lie on top of them.
    let mut ordered: Vec<&Series> = panel.series.iter().collect();
    ordered.sort_by_key(|s| !matches!(s.shape, Shape::Band(_)));
    for s in ordered {
        let colour = s.colour;
        match &s.shape {
            Shape::Band(band) => {
                let band: Vec<_> = band
                    .iter()
                    .filter(|&&(x, lo, hi)| ok(&(x, lo)) && ok(&(x, hi)))
                    .collect();
                let outline: Vec<(f64, f64)> = band
                    .iter()
                    .map(|b| (b.0, b.2))
                    .chain(band.iter().rev().map(|b| (b.0, b.1)))
                    .collect();
                c.draw_series(std::iter::once(Polygon::new(
                    outline,
                    colour.mix(0.25).filled(),
                )))
                .map_err(draw_err)?;
            }
            Shape::Line(p) => {
                let p: Vec<_> = thin_line(p, MAX_LINE_BUCKETS)
                    .into_iter()
                    .filter(ok)
                    .collect();
                c.draw_series(LineSeries::new(p, colour.stroke_width(1)))
                    .map_err(draw_err)?;
            }
            Shape::Dashed(p) => {
                let p: Vec<_> = p.iter().copied().filter(ok).collect();
                c.draw_series(DashedLineSeries::new(p, 6, 4, colour.stroke_width(2)))
                    .map_err(draw_err)?;
            }
            Shape::Points(p) => {
                let p: Vec<_> = thin_points(p, MAX_POINTS).into_iter().filter(ok).collect();
                c.draw_series(p.into_iter().map(|q| Circle::new(q, 2, colour.filled())))
                    .map_err(draw_err)?;
            }
            Shape::PointsWithBars(p) => {
                for &(x, y, lo, hi) in p {
                    if ok(&(x, lo)) && ok(&(x, hi)) {
                        c.draw_series(std::iter::once(PathElement::new(
                            vec![(x, lo), (x, hi)],
                            colour.stroke_width(1),
                        )))
                        .map_err(draw_err)?;
                    }
                    if ok(&(x, y)) {
                        c.draw_series(std::iter::once(Circle::new((x, y), 3, colour.filled())))
                            .map_err(draw_err)?;
                    }
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thinned_line_keeps_each_buckets_extremes_in_time_order() {
        let points: Vec<(f64, f64)> = (0..10_000)
            .map(|k| (k as f64, if k == 5_123 { 9.0 } else { (k % 7) as f64 }))
            .collect();
        let thin = thin_line(&points, 100);
        assert!(thin.len() <= 200, "{}", thin.len());
        assert!(thin.contains(&(5_123.0, 9.0)));
        assert!(thin.windows(2).all(|w| w[0].0 <= w[1].0));
        assert_eq!(thin_points(&points, 1000).len(), 1000);
    }

    #[test]
    fn panels_draw_what_they_hold_and_nothing_when_empty() {
        let line = Series::new(
            "e",
            PALETTE[0],
            Shape::Line((0..500).map(|k| (k as f64, (k as f64).sin())).collect()),
        );
        let panel = |series| Panel {
            title: "p".into(),
            x_label: "t (s)".into(),
            y_label: "e (rad/s)".into(),
            axes: Axes::Linear,
            series,
        };
        let svg = panels_svg("T", &[panel(vec![line.clone()]), panel(vec![line])])
            .unwrap()
            .unwrap();
        assert!(svg.contains("<polyline") && svg.contains("t (s)"));
        let log = Panel {
            axes: Axes::LogLog,
            series: vec![Series::new(
                "neg",
                PALETTE[1],
                Shape::Points(vec![(-1.0, 2.0), (1.0, -3.0)]),
            )],
            ..panel(vec![])
        };
        assert!(panels_svg("T", &[log]).unwrap().is_none());
    }
}
