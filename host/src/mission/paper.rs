//! The paper's chain for one sensor against a reference, as the demo runs it: the error
//! signals of Section II with the calibration's convergence as the drive lengthens (Fig. 3)
//! and the errors themselves (Fig. 4), the dynamics regression of Section III (Tables II and
//! III, Fig. 5), and the GMWM of Section IV on the errors in motion, against the same
//! sensor's errors at rest where there is a static recording (Table I, Figs. 6 and 7).

use super::{stage, MissionError};
use crate::calibration::{build_error_signals, CalibrationSummary, ErrorOptions};
use crate::error_signal::ErrorSignals;
use crate::gmwm::compare::{compare, ComparisonRow};
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, ChannelFit, ModelChoice};
use crate::interchange::{ImuRecording, CHANNELS};
use crate::regress::{backward_elimination, RegressionOptions, RegressionReport};
use crate::report::charts::{panels_svg, Axes, Panel, Series, Shape, GREY, PALETTE};
use crate::report::{Cell, Section, Table};
use crate::wv::{haar_wv, WvOptions};

const DEG_PER_RAD: f64 = 180.0 / std::f64::consts::PI;

/// Shares of the drive the calibration is repeated on for its convergence (Fig. 3).
const CONVERGENCE_SHARES: [f64; 8] = [0.1, 0.15, 0.2, 0.3, 0.4, 0.55, 0.75, 1.0];

/// The boresight estimated on the drive's first `t_s` seconds, rad, with its 1-sigma.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvergencePoint {
    pub t_s: f64,
    pub boresight_rad: [f64; 3],
    pub sigma_rad: [f64; 3],
}

/// One channel's error model at rest and in motion, and the paper's Table I rows.
#[derive(Debug, Clone)]
pub struct StaticDynamic {
    pub channel: &'static str,
    pub at_rest: ChannelFit,
    pub in_motion: ChannelFit,
    pub rows: Vec<ComparisonRow>,
}

/// The chain's results for one sensor.
#[derive(Debug, Clone)]
pub struct PaperChain {
    pub sensor: String,
    pub calibration: CalibrationSummary,
    pub convergence: Vec<ConvergencePoint>,
    pub signals: ErrorSignals,
    /// Per channel with an error, the backward elimination on the 15 dynamics regressors.
    pub regressions: Vec<(&'static str, RegressionReport)>,
    /// Per channel, the error model in motion (with `at_rest` where a static recording was
    /// given, fitted with the same structure).
    pub fits: Vec<StaticDynamic>,
    /// Per channel, the automatic (WIC) fit of the error in motion when there is no static
    /// recording to compare with.
    pub motion_only: Vec<ChannelFit>,
}

/// What to do at rest: the sensor's and the reference's static recordings, and the
/// structure both fits of Table I share.
pub struct AtRest<'a> {
    pub sensor: &'a ImuRecording,
    pub reference: &'a ImuRecording,
    pub structure: &'a ModelChoice,
}

fn convergence(
    sensor: &ImuRecording,
    reference: &ImuRecording,
) -> Result<Vec<ConvergencePoint>, MissionError> {
    let t0 = sensor.t_s.first().copied().unwrap_or(0.0);
    let span = sensor.t_s.last().copied().unwrap_or(0.0) - t0;
    let mut points = Vec::new();
    for share in CONVERGENCE_SHARES {
        let to = t0 + share * span + 1e-9;
        let (_, cal) = build_error_signals(
            &sensor.between(f64::NEG_INFINITY, to),
            &reference.between(f64::NEG_INFINITY, to + 1.0),
            &ErrorOptions::default(),
        )
        .map_err(stage("the calibration's convergence"))?;
        points.push(ConvergencePoint {
            t_s: share * span,
            boresight_rad: cal.boresight_rad.value,
            sigma_rad: cal.boresight_rad.sigma,
        });
    }
    Ok(points)
}

fn error_fit(
    signals: &ErrorSignals,
    channel: &'static str,
    dt_s: f64,
    choice: &ModelChoice,
) -> Result<Option<ChannelFit>, MissionError> {
    let Some(y) = signals.error(channel) else {
        return Ok(None);
    };
    let wv = haar_wv(y, dt_s, &WvOptions::default()).map_err(stage("the wavelet variance"))?;
    let input = FitInput::from_wv(&wv).map_err(stage("the GMWM input"))?;
    let unit = if channel.starts_with('g') {
        "rad/s"
    } else {
        "m/s^2"
    };
    analyze(channel, unit, &input, choice, None, &FitOptions::default())
        .map(Some)
        .map_err(stage("the GMWM fit"))
}

/// Runs the chain on `sensor` against `reference` (and at rest, when given).
pub fn run_chain(
    name: &str,
    sensor: &ImuRecording,
    reference: &ImuRecording,
    at_rest: Option<AtRest<'_>>,
) -> Result<PaperChain, MissionError> {
    let (signals, calibration) = build_error_signals(sensor, reference, &ErrorOptions::default())
        .map_err(stage("the error signals"))?;
    let convergence = convergence(sensor, reference)?;
    let regressors = signals.regressors();
    let mut regressions = Vec::new();
    for channel in CHANNELS {
        if let Some(y) = signals.error(channel) {
            let r = backward_elimination(y, &regressors, &RegressionOptions::default())
                .map_err(stage("the dynamics regression"))?;
            regressions.push((channel, r));
        }
    }
    let dt_s = calibration.epoch_dt_s;
    let (mut fits, mut motion_only) = (Vec::new(), Vec::new());
    match at_rest {
        Some(rest) => {
            let still = ErrorOptions {
                estimate_lever_arm: false,
                estimate_time_offset: false,
                ..Default::default()
            };
            let (rest_signals, rest_cal) = build_error_signals(rest.sensor, rest.reference, &still)
                .map_err(stage("the error signals at rest"))?;
            for channel in CHANNELS {
                let moving = error_fit(&signals, channel, dt_s, rest.structure)?;
                let still = error_fit(&rest_signals, channel, rest_cal.epoch_dt_s, rest.structure)?;
                if let (Some(in_motion), Some(at_rest)) = (moving, still) {
                    let rows = compare(&at_rest, &in_motion).map_err(stage("Table I"))?;
                    fits.push(StaticDynamic {
                        channel,
                        at_rest,
                        in_motion,
                        rows,
                    });
                }
            }
        }
        None => {
            for channel in CHANNELS {
                if let Some(f) = error_fit(&signals, channel, dt_s, &ModelChoice::Auto)? {
                    motion_only.push(f);
                }
            }
        }
    }
    Ok(PaperChain {
        sensor: name.to_string(),
        calibration,
        convergence,
        signals,
        regressions,
        fits,
        motion_only,
    })
}

/// Fig. 3: the boresight's three angles with their ±3-sigma band as the drive lengthens.
pub fn convergence_svg(chain: &PaperChain) -> Result<Option<String>, MissionError> {
    let panels: Vec<Panel> = ["roll (x)", "pitch (y)", "yaw (z)"]
        .iter()
        .enumerate()
        .map(|(k, axis)| Panel {
            title: format!("{}: boresight {axis}", chain.sensor),
            x_label: "drive used (s)".into(),
            y_label: "angle (deg)".into(),
            axes: Axes::Linear,
            series: vec![
                Series::new(
                    "±3 sigma",
                    PALETTE[1],
                    Shape::Band(
                        chain
                            .convergence
                            .iter()
                            .map(|p| {
                                let (v, s) = (p.boresight_rad[k], 3.0 * p.sigma_rad[k]);
                                (p.t_s, (v - s) * DEG_PER_RAD, (v + s) * DEG_PER_RAD)
                            })
                            .collect(),
                    ),
                ),
                Series::new(
                    "estimate",
                    PALETTE[1],
                    Shape::Line(
                        chain
                            .convergence
                            .iter()
                            .map(|p| (p.t_s, p.boresight_rad[k] * DEG_PER_RAD))
                            .collect(),
                    ),
                ),
            ],
        })
        .collect();
    panels_svg("Inter-IMU boresight as the drive lengthens", &panels)
        .map_err(stage("drawing Fig. 3"))
}

/// Fig. 4: the error of `gyro` and `accel` channels against time.
pub fn errors_svg(
    chain: &PaperChain,
    gyro: &str,
    accel: &str,
) -> Result<Option<String>, MissionError> {
    let t = &chain.signals.t_s;
    let panel = |channel: &str, unit: &str, colour| Panel {
        title: format!("{}: {channel} error (sensor minus reference)", chain.sensor),
        x_label: "time (s)".into(),
        y_label: format!("error ({unit})"),
        axes: Axes::Linear,
        series: chain
            .signals
            .error(channel)
            .map(|e| {
                vec![Series::new(
                    channel,
                    colour,
                    Shape::Line(t.iter().copied().zip(e.iter().copied()).collect()),
                )]
            })
            .unwrap_or_default(),
    };
    panels_svg(
        "Error signals under dynamics",
        &[
            panel(gyro, "rad/s", PALETTE[0]),
            panel(accel, "m/s^2", PALETTE[1]),
        ],
    )
    .map_err(stage("drawing Fig. 4"))
}

/// The kept regressor with the largest |t| of `channel`'s regression, if any.
fn strongest_regressor<'a>(chain: &'a PaperChain, channel: &str) -> Option<&'a str> {
    let (_, r) = chain.regressions.iter().find(|(c, _)| *c == channel)?;
    r.coefficients
        .iter()
        .filter(|c| c.name != "intercept")
        .max_by(|a, b| a.t.abs().total_cmp(&b.t.abs()))
        .map(|c| c.name.as_str())
}

/// Fig. 5: each of `channels`' error against its strongest kept regressor (or its own
/// axis's angular rate or acceleration when none was kept).
pub fn scatter_svg(chain: &PaperChain, channels: &[&str]) -> Result<Option<String>, MissionError> {
    let regressors = chain.signals.regressors();
    let mut panels = Vec::new();
    for (k, channel) in channels.iter().enumerate() {
        let Some(e) = chain.signals.error(channel) else {
            continue;
        };
        let axis = &channel[1..];
        let fallback = if channel.starts_with('g') {
            format!("omega_{axis}")
        } else {
            format!("a_{axis}")
        };
        let name = strongest_regressor(chain, channel).unwrap_or(&fallback);
        let Some((_, x)) = regressors.iter().find(|(n, _)| *n == name) else {
            continue;
        };
        panels.push(Panel {
            title: format!("{}: {channel} error against {name}", chain.sensor),
            x_label: name.to_string(),
            y_label: format!(
                "{channel} error ({})",
                if channel.starts_with('g') {
                    "rad/s"
                } else {
                    "m/s^2"
                }
            ),
            axes: Axes::Linear,
            series: vec![Series::new(
                "",
                PALETTE[k % PALETTE.len()],
                Shape::Points(x.iter().copied().zip(e.iter().copied()).collect()),
            )],
        });
    }
    panels_svg("Errors against the dynamics", &panels).map_err(stage("drawing Fig. 5"))
}

/// Figs. 6 and 7: the error's wavelet variance in motion (and at rest) with the fitted
/// models' wavelet variance, for `channels`.
pub fn wv_svg(chain: &PaperChain, channels: &[&str]) -> Result<Option<String>, MissionError> {
    let curve = |f: &ChannelFit| -> Vec<(f64, f64)> {
        f.scales_s
            .iter()
            .copied()
            .zip(f.wv.iter().copied())
            .collect()
    };
    let model = |f: &ChannelFit| -> Vec<(f64, f64)> {
        f.scales_s
            .iter()
            .copied()
            .zip(f.model_wv.iter().copied())
            .collect()
    };
    let mut panels = Vec::new();
    for channel in channels {
        let unit = if channel.starts_with('g') {
            "(rad/s)^2"
        } else {
            "(m/s^2)^2"
        };
        let mut series = Vec::new();
        if let Some(sd) = chain.fits.iter().find(|f| f.channel == *channel) {
            series.push(Series::new(
                "in motion",
                PALETTE[0],
                Shape::Points(curve(&sd.in_motion)),
            ));
            series.push(Series::new(
                format!("{} fitted in motion", sd.in_motion.model),
                PALETTE[0],
                Shape::Line(model(&sd.in_motion)),
            ));
            series.push(Series::new(
                "at rest",
                GREY,
                Shape::Points(curve(&sd.at_rest)),
            ));
            series.push(Series::new(
                "fitted at rest",
                GREY,
                Shape::Dashed(model(&sd.at_rest)),
            ));
        } else if let Some(f) = chain.motion_only.iter().find(|f| f.channel == *channel) {
            series.push(Series::new(
                "in motion",
                PALETTE[0],
                Shape::Points(curve(f)),
            ));
            series.push(Series::new(
                format!("{} (WIC)", f.model),
                PALETTE[1],
                Shape::Line(model(f)),
            ));
        }
        panels.push(Panel {
            title: format!("{}: {channel} error wavelet variance", chain.sensor),
            x_label: "scale (s)".into(),
            y_label: format!("wavelet variance {unit}"),
            axes: Axes::LogLog,
            series,
        });
    }
    panels_svg(
        "Wavelet variance of the errors and the fitted models",
        &panels,
    )
    .map_err(stage("drawing Figs. 6-7"))
}

/// The calibration as a table (boresight in deg, lever arm in mm, biases in SI).
pub fn calibration_table(chain: &PaperChain) -> Table {
    let c = &chain.calibration;
    let v3 = |v: [f64; 3], s: [f64; 3], k: usize, f: f64| Cell::PlusMinus(v[k] * f, s[k] * f);
    let rows = (0..3)
        .map(|k| {
            let mut row = vec![
                Cell::from(["x", "y", "z"][k]),
                v3(c.boresight_rad.value, c.boresight_rad.sigma, k, DEG_PER_RAD),
            ];
            for e in [
                c.lever_arm_m.as_ref().map(|l| (l, 1e3)),
                c.gyro_bias_rad_s.as_ref().map(|g| (g, 1.0)),
                c.accel_bias_m_s2.as_ref().map(|a| (a, 1.0)),
            ] {
                row.push(e.map_or("-".into(), |(e, f)| v3(e.value, e.sigma, k, f)));
            }
            row
        })
        .collect();
    let offset = c.time_offset_s.map_or("not estimated".into(), |t| {
        format!(
            "{} ± {} ms",
            crate::report::html::significant(t.value * 1e3, 4),
            crate::report::html::significant(t.sigma * 1e3, 2)
        )
    });
    Table {
        caption: format!(
            "{}: calibration against the reference ({} epochs; 1-sigma, Newey-West); time offset {offset}",
            chain.sensor, c.epochs
        ),
        header: vec![
            "axis".into(),
            "boresight (deg)".into(),
            "lever arm (mm)".into(),
            "gyro bias (rad/s)".into(),
            "accel bias (m/s^2)".into(),
        ],
        rows,
    }
}

/// Tables II and III: each channel's kept dynamics terms with their estimates and t
/// statistics, R^2 and the overall Wald test.
pub fn regression_table(chain: &PaperChain) -> Table {
    let rows = chain
        .regressions
        .iter()
        .map(|(channel, r)| {
            let terms: Vec<String> = r
                .coefficients
                .iter()
                .filter(|c| c.name != "intercept")
                .map(|c| {
                    format!(
                        "{} {} (t {}){}",
                        c.name,
                        crate::report::html::significant(c.estimate, 3),
                        crate::report::html::significant(c.t, 3),
                        c.stars
                    )
                })
                .collect();
            vec![
                Cell::from(*channel),
                Cell::from(if terms.is_empty() {
                    "none".to_string()
                } else {
                    terms.join("; ")
                }),
                Cell::Number(r.r2),
                Cell::Number(r.wald_p_value),
            ]
        })
        .collect();
    Table {
        caption: format!(
            "{}: Tables II/III, errors regressed on the 15 dynamics (backward elimination at \
             5%, Newey-West inference; estimates in error units per regressor unit)",
            chain.sensor
        ),
        header: vec![
            "channel".into(),
            "kept terms".into(),
            "R^2".into(),
            "Wald p (all terms zero)".into(),
        ],
        rows,
    }
}

/// Table I: each parameter at rest and in motion with its 95% interval, whether they overlap
/// and the Wald test.
pub fn table_one(chain: &PaperChain) -> Option<Table> {
    if chain.fits.is_empty() {
        return None;
    }
    let mut rows = Vec::new();
    for sd in &chain.fits {
        for r in &sd.rows {
            let ci = |c: Option<[f64; 2]>| c.map_or("-".into(), |c| Cell::Interval(c[0], c[1]));
            rows.push(vec![
                Cell::from(sd.channel),
                Cell::from(format!("{} ({})", r.parameter, r.unit)),
                Cell::Number(r.static_value),
                ci(r.static_ci95),
                Cell::Number(r.dynamic_value),
                ci(r.dynamic_ci95),
                Cell::from(match r.intervals_overlap {
                    Some(true) => "yes",
                    Some(false) => "no",
                    None => "-",
                }),
                r.wald_p_value.map_or("-".into(), Cell::Number),
            ]);
        }
    }
    Some(Table {
        caption: format!(
            "{}: Table I, the same model fitted at rest and in motion",
            chain.sensor
        ),
        header: vec![
            "channel".into(),
            "parameter".into(),
            "at rest".into(),
            "95% interval".into(),
            "in motion".into(),
            "95% interval".into(),
            "intervals overlap".into(),
            "Wald p".into(),
        ],
        rows,
    })
}

/// The fits in motion alone (WIC's choice per channel) as a table.
pub fn motion_table(chain: &PaperChain) -> Option<Table> {
    if chain.motion_only.is_empty() {
        return None;
    }
    let rows = chain
        .motion_only
        .iter()
        .flat_map(|f| {
            f.parameters.iter().map(move |p| {
                vec![
                    Cell::from(f.channel.clone()),
                    Cell::from(f.model.clone()),
                    Cell::from(p.name.clone()),
                    Cell::Number(p.value),
                    p.ci95.map_or("-".into(), |c| Cell::Interval(c[0], c[1])),
                ]
            })
        })
        .collect();
    Some(Table {
        caption: format!(
            "{}: GMWM of the errors in motion (model chosen by WIC)",
            chain.sensor
        ),
        header: vec![
            "channel".into(),
            "model".into(),
            "parameter".into(),
            "value (SI)".into(),
            "95% interval".into(),
        ],
        rows,
    })
}

/// The chain's sections: Section II (calibration, Figs. 3-4), Section III (Tables II/III,
/// Fig. 5) and Section IV (Table I or the fits in motion, Figs. 6-7), on channels `gyro`
/// and `accel` for the figures.
pub fn sections(chain: &PaperChain, gyro: &str, accel: &str) -> Result<Vec<Section>, MissionError> {
    let name = &chain.sensor;
    let errors = Section::new(format!("{name}: error signals (Section II)"))
        .table(calibration_table(chain))
        .figure(
            format!("{name}: boresight to the reference estimated on the first part of the drive, with its ±3-sigma band (paper Fig. 3)"),
            convergence_svg(chain)?,
        )
        .figure(
            format!("{name}: {gyro} and {accel} errors after calibration (paper Fig. 4)"),
            errors_svg(chain, gyro, accel)?,
        );
    let dynamics = Section::new(format!("{name}: errors and the dynamics (Section III)"))
        .table(regression_table(chain))
        .figure(
            format!("{name}: errors against their strongest dynamics term (paper Fig. 5)"),
            scatter_svg(chain, &[gyro, accel])?,
        );
    let mut noise = Section::new(format!("{name}: stochastic model (Section IV)"));
    if let Some(t) = table_one(chain) {
        noise = noise.table(t);
    }
    if let Some(t) = motion_table(chain) {
        noise = noise.table(t);
    }
    noise = noise.figure(
        format!("{name}: wavelet variance of the errors with the fitted models (paper Figs. 6-7)"),
        wv_svg(chain, &[gyro, accel])?,
    );
    Ok(vec![errors, dynamics, noise])
}
