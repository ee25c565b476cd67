//! SVG plots with `plotters` (SVG backend only). The scaffolding every plot of the crate
//! shares lives here once: the document (`render_svg`), a chart's frame (`chart`), its
//! grid (`grey_grid`), log axes over whole decades (`Decades`), category axes
//! (`CategoryAxis`) and the legend panel beside a chart (`titled_with_legend`,
//! `draw_legend`). The diagnosis report's plots use it, and so does Fig. 1 ([`fig1_svg`]):
//! one row per extra IMU, lever arm on the left and boresight on the right as in the paper,
//! each axis's estimate with its ±3σ envelope against time and the truth as a dashed line.

use plotters::chart::MeshStyle;
use plotters::coord::combinators::{LogCoord, WithKeyPoints};
use plotters::coord::ranged1d::{AsRangedCoord, DefaultFormatting, KeyPointHint};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::fig1::{CalibrationPoint, Fig1Run};

/// The font of every plot.
pub const FONT: &str = "sans-serif";

/// What plotters reported when drawing failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DrawError(String);

impl DrawError {
    /// The message.
    pub fn message(&self) -> &str {
        &self.0
    }
}

impl std::fmt::Display for DrawError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for DrawError {}

/// A plotters error as a [`DrawError`].
pub(crate) fn draw_err<E: std::fmt::Display>(e: E) -> DrawError {
    DrawError(e.to_string())
}

/// The drawing area of an SVG document, or a part of it.
pub(crate) type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// An SVG document of `size` pixels on a white background, drawn by `draw`.
pub(crate) fn render_svg<E: From<DrawError>>(
    size: (u32, u32),
    draw: impl FnOnce(&Area<'_>) -> Result<(), E>,
) -> Result<String, E> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        draw(&root)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Margin around a chart and the sizes of its label areas, pixels.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Frame {
    pub margin: u32,
    pub x_labels: u32,
    pub y_labels: u32,
}

/// A chart of an SVG document over the axes `X` and `Y`.
pub(crate) type Chart<'a, 'b, X, Y> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<X, Y>>;

/// A chart on `area` over the coordinates `x` and `y`, with an optional caption (text and
/// font size) above it.
pub(crate) fn chart<'a, 'b, X: AsRangedCoord, Y: AsRangedCoord>(
    area: &'a Area<'b>,
    caption: Option<(&str, u32)>,
    frame: Frame,
    x: X,
    y: Y,
) -> Result<Chart<'a, 'b, X::CoordDescType, Y::CoordDescType>, DrawError> {
    let mut builder = ChartBuilder::on(area);
    if let Some((text, size)) = caption {
        builder.caption(text, (FONT, size));
    }
    builder
        .margin(frame.margin)
        .x_label_area_size(frame.x_labels)
        .y_label_area_size(frame.y_labels)
        .build_cartesian_2d(x, y)
        .map_err(draw_err)
}

/// Grey grid lines (light and bold grey levels, 0-255) and the axis descriptions' font.
pub(crate) fn grey_grid<'m, 'a, 'b, X: Ranged, Y: Ranged, DB: DrawingBackend>(
    mesh: &'m mut MeshStyle<'a, 'b, X, Y, DB>,
    light: u8,
    bold: u8,
) -> &'m mut MeshStyle<'a, 'b, X, Y, DB> {
    mesh.light_line_style(RGBColor(light, light, light))
        .bold_line_style(RGBColor(bold, bold, bold))
        .axis_desc_style((FONT, 16))
}

/// Whether a value can be drawn on a log axis.
pub(crate) fn usable(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

/// Whole decades `[10^lo, 10^hi]` around some positive values, at least one decade wide.
///
/// Log axes carry explicit decade ticks: plotters' own log key points drop every value below
/// f64::EPSILON, which would leave e.g. the wavelet variance of a good gyro ((rad/s)^2, often
/// under 1e-16) without tick labels.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Decades {
    /// Bottom and top of the range.
    pub lo: f64,
    pub hi: f64,
    exponents: Vec<i32>,
}

impl Decades {
    /// The decades around the [`usable`] `values`; `None` when there is none.
    pub(crate) fn around(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values.into_iter().filter(|v| usable(*v)) {
            min = min.min(v);
            max = max.max(v);
        }
        if !min.is_finite() {
            return None;
        }
        // A little room so a value on a decade is not drawn on the frame.
        let lo = (min.log10() - 0.05).floor() as i32;
        let hi = ((max.log10() + 0.05).ceil() as i32).max(lo + 1);
        Some(Self {
            lo: 10f64.powi(lo),
            hi: 10f64.powi(hi),
            exponents: (lo..=hi).collect(),
        })
    }

    /// The log axis over the decades: bold ticks on the decades, light ones at 2..9 times
    /// each decade.
    pub(crate) fn axis(&self) -> WithKeyPoints<LogCoord<f64>> {
        let bold: Vec<f64> = self.exponents.iter().map(|&e| 10f64.powi(e)).collect();
        let light: Vec<f64> = self
            .exponents
            .iter()
            .take(self.exponents.len().saturating_sub(1))
            .flat_map(|&e| (2..10).map(move |m| f64::from(m) * 10f64.powi(e)))
            .collect();
        (self.lo..self.hi)
            .log_scale()
            .with_key_points(bold)
            .with_light_points(light)
    }
}

/// A decade's tick label: plain between 0.01 and 1000, `1e<k>` beyond.
pub(crate) fn decade_label(v: f64) -> String {
    let e = v.log10().round() as i32;
    if (-2..=3).contains(&e) {
        format!("{}", 10f64.powi(e))
    } else {
        format!("1e{e}")
    }
}

/// A categorical axis: categories 0..n at integer positions on -0.5..n-0.5, one tick each.
/// (plotters' `with_key_points` on an f64 axis loses the label formatting the mesh needs,
/// and its segmented axes cannot place several bars side by side within a category.)
pub(crate) struct CategoryAxis {
    n: usize,
}

impl CategoryAxis {
    pub(crate) fn new(n: usize) -> Self {
        Self { n }
    }
}

impl Ranged for CategoryAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let fraction = (value + 0.5) / self.n.max(1) as f64;
        limit.0 + (fraction * f64::from(limit.1 - limit.0)).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            (0..self.n).map(|k| k as f64).collect()
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        -0.5..self.n as f64 - 0.5
    }
}

/// Width of the legend panel to the right of a chart, pixels (a legend inside the plot
/// would hide data wherever it is put).
pub const LEGEND_WIDTH_PX: u32 = 250;

/// A document of `width` pixels split into its chart panel under `title` and the legend
/// panel ([`LEGEND_WIDTH_PX`]) to the right.
pub(crate) fn titled_with_legend<'a>(
    root: &Area<'a>,
    title: &str,
    width: u32,
) -> Result<(Area<'a>, Area<'a>), DrawError> {
    let body = root.titled(title, (FONT, 20)).map_err(draw_err)?;
    Ok(body.split_horizontally(width - LEGEND_WIDTH_PX))
}

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Glyph {
    /// A shaded band with its bounds.
    Band(RGBColor),
    /// A filled bar.
    Bar(RGBColor),
    /// A line with point markers.
    LineWithMarker(RGBColor),
    /// A dashed line.
    Dashed(RGBColor),
}

/// Draws the legend entries top-down into their own panel.
pub(crate) fn draw_legend(area: &Area<'_>, entries: &[(Glyph, String)]) -> Result<(), DrawError> {
    const TOP: i32 = 50;
    const ROW: i32 = 26;
    const X: i32 = 10;
    for (k, (glyph, text)) in entries.iter().enumerate() {
        let y = TOP + ROW * k as i32;
        match *glyph {
            Glyph::Band(c) => {
                area.draw(&Rectangle::new(
                    [(X, y - 7), (X + 26, y + 7)],
                    c.mix(0.3).filled(),
                ))
                .map_err(draw_err)?;
                for edge in [y - 7, y + 7] {
                    area.draw(&PathElement::new(
                        vec![(X, edge), (X + 26, edge)],
                        c.mix(0.8),
                    ))
                    .map_err(draw_err)?;
                }
            }
            Glyph::Bar(c) => area
                .draw(&Rectangle::new([(X, y - 7), (X + 26, y + 7)], c.filled()))
                .map_err(draw_err)?,
            Glyph::LineWithMarker(c) => {
                area.draw(&PathElement::new(
                    vec![(X, y), (X + 26, y)],
                    c.stroke_width(2),
                ))
                .map_err(draw_err)?;
                area.draw(&Circle::new((X + 13, y), 3, c.filled()))
                    .map_err(draw_err)?;
            }
            Glyph::Dashed(c) => {
                for x0 in [X, X + 10, X + 20] {
                    area.draw(&PathElement::new(
                        vec![(x0, y), (x0 + 6, y)],
                        c.stroke_width(1),
                    ))
                    .map_err(draw_err)?;
                }
            }
        }
        area.draw(&Text::new(
            text.clone(),
            (X + 36, y),
            (FONT, 15)
                .into_font()
                .color(&BLACK)
                .pos(Pos::new(HPos::Left, VPos::Center)),
        ))
        .map_err(draw_err)?;
    }
    Ok(())
}

/// Why drawing Fig. 1 failed.
#[derive(Debug, thiserror::Error)]
#[error("drawing the figure: {0}")]
pub struct PlotError(String);

impl From<DrawError> for PlotError {
    fn from(e: DrawError) -> Self {
        PlotError(e.0)
    }
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
    render_svg((1200, 820), |root| {
        let (title_area, body) = root.split_vertically(40);
        title_area
            .titled(
                &format!(
                    "Joint inter-IMU lever-arm and boresight estimation (simulated car, {} s, seed {}, \u{00b1}3\u{03c3} envelopes, truth dashed)",
                    run.report.seconds, run.report.seed
                ),
                (FONT, 18),
            )
            .map_err(draw_err)?;
        let panels = body.split_evenly((2, 2));
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
            for (column, q) in quantities.iter().enumerate() {
                draw_panel(&panels[2 * imu + column], run, imu, q)?;
            }
        }
        Ok(())
    })
}

/// One panel: quantity `q` of extra IMU `imu` against time, per axis its ±3σ envelope, the
/// estimate and the truth (dashed).
fn draw_panel(area: &Area<'_>, run: &Fig1Run, imu: usize, q: &Quantity) -> Result<(), DrawError> {
    let name = &run.report.imus[imu].name;
    let t_end = run.trace.t_s.last().copied().unwrap_or(1.0);
    let step = run.trace.t_s.len().div_ceil(MAX_POINTS).max(1);
    let lo = q.truth.iter().copied().fold(f64::INFINITY, f64::min) - q.margin;
    let hi = q.truth.iter().copied().fold(f64::NEG_INFINITY, f64::max) + q.margin;
    let clamp = |y: f64| y.clamp(lo, hi);
    let caption = format!("{name}: {} [{}]", q.title, q.unit);
    let frame = Frame {
        margin: 8,
        x_labels: 30,
        y_labels: 45,
    };
    let mut chart = chart(area, Some((&caption, 16)), frame, 0.0..t_end, lo..hi)?;
    chart
        .configure_mesh()
        .x_desc("time [s]")
        .y_desc(q.unit)
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(draw_err)?;
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
            .map_err(draw_err)?;
        chart
            .draw_series(LineSeries::new(
                indices
                    .iter()
                    .map(|&k| (run.trace.t_s[k], clamp((q.value)(&points[k], a)))),
                colour.stroke_width(2),
            ))
            .map_err(draw_err)?
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
            .map_err(draw_err)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_err)?;
    Ok(())
}
