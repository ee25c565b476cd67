//! The discrepancy engine behind `dynacal diagnose`: compares measured error signals with
//! the baseline stochastic model simulated along the measured dynamics, names the causes of
//! what the baseline cannot explain, builds the extended model and measures the gain.
//!
//! Causes are told apart by their physics:
//! - deterministic sensitivities are per-channel regressions on the regressor that physics
//!   says drives them: the channel's own input (`scale_factor`), another axis' input
//!   (`cross_axis`), specific force on a gyro (`g_sensitivity`), angular acceleration
//!   (`angular_acceleration`), rate of change of specific force (`jerk`);
//! - a time offset is one coefficient common to every channel of the sensor, on each
//!   channel's own derivative, and a lever arm is omega_dot x r + omega x (omega x r) on the
//!   accelerometers: both are estimated jointly by the calibration of
//!   [`crate::calibration::build_error_signals`] and named when significant;
//! - stochastic causes are tested against the same statistic on series simulated from the
//!   baseline: outliers, vibration lines, a shift of the mean, noise growing with the
//!   dynamics, quantization (the raw sensor values lie on a lattice), and a change of the
//!   correlated or white noise (the wavelet variance of what remains).
//!
//! The deterministic terms are found in two stages: per channel, a stepwise selection over
//! the physics candidates (and a bias step), each fitted jointly with the calibration on
//! every channel's rows; then across channels, a joint fit of all kept terms, so a term one
//! channel shows only because another's term moved the calibration drops out.
//!
//! False alarms are controlled by strict per-test levels (Bonferroni over the tests of a
//! run), an effect-size floor for deterministic terms, simulation-calibrated thresholds, and
//! coefficient spreads no smaller than the measured residual's own (so a noise stronger than
//! the baseline's is not read as terms).

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use statrs::distribution::{ContinuousCDF, Normal};

use super::stats::{
    find_outliers, local_step_null_sd, local_step_robust_sd, local_step_scan, noise_vs_dynamics,
    outlier_process, spectral_lines, welch_psd,
};
use crate::calibration::{
    build_error_signals_with_design, CalibrationDesign, CalibrationSummary, ErrorOptions,
};
use crate::error_signal::ErrorSignals;
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, ModelChoice};
use crate::gmwm::model::ModelSpec;
#[cfg(test)]
use crate::gmwm::model::Process;
use crate::interchange::{ImuRecording, CHANNELS};
use crate::numeric::central_difference;
use crate::regress::{backward_elimination, RegressionOptions};
use crate::wv::{haar_wv, WvOptions};

/// The cause vocabulary (exact strings of the output contract).
pub const CAUSES: [&str; 14] = [
    "scale_factor",
    "cross_axis",
    "g_sensitivity",
    "angular_acceleration",
    "jerk",
    "time_offset",
    "lever_arm",
    "noise_scales_with_dynamics",
    "vibration",
    "outliers",
    "bias_shift",
    "correlated_noise_change",
    "quantization",
    "white_noise_change",
];

/// Causes the engine estimates as deterministic terms (the rest are stochastic effects).
pub const DETERMINISTIC_CAUSES: [&str; 8] = [
    "scale_factor",
    "cross_axis",
    "g_sensitivity",
    "angular_acceleration",
    "jerk",
    "time_offset",
    "lever_arm",
    "bias_shift",
];

/// Errors of the engine.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DiagnoseError {
    #[error(transparent)]
    Errors(#[from] crate::calibration::ErrorsError),
    #[error("baseline model {path}: {message}")]
    Baseline { path: String, message: String },
    #[error("channel {channel}: {message}")]
    Channel { channel: String, message: String },
}

/// The baseline stochastic model per channel, in SI units (rad/s, m/s^2).
#[derive(Debug, Clone)]
pub struct Baseline {
    pub channels: BTreeMap<String, ModelSpec>,
    /// Where it came from, in words.
    pub source: String,
}

impl Baseline {
    /// Reads the JSON written by `dynacal fit` (`{"channels": [{"channel": "gx", "model_object": ..}]}`).
    pub fn load(path: &std::path::Path) -> Result<Self, DiagnoseError> {
        let err = |message: String| DiagnoseError::Baseline {
            path: path.display().to_string(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        let v: Value = serde_json::from_str(&text).map_err(|e| err(format!("not JSON: {e}")))?;
        // `dynacal fit` writes a list of channel fits, each naming its channel; a map keyed
        // by channel is accepted too.
        let entries: Vec<(String, &Value)> = match v.get("channels") {
            Some(Value::Array(list)) => list
                .iter()
                .enumerate()
                .map(|(i, ch)| {
                    ch.get("channel")
                        .and_then(Value::as_str)
                        .map(|name| (name.to_string(), ch))
                        .ok_or_else(|| err(format!("channels[{i}]: no `channel` name")))
                })
                .collect::<Result<_, _>>()?,
            Some(Value::Object(map)) => map.iter().map(|(k, ch)| (k.clone(), ch)).collect(),
            _ => {
                return Err(err(
                    "no `channels` list (expected the output of `dynacal fit`)".into(),
                ))
            }
        };
        let mut out = BTreeMap::new();
        for (name, ch) in entries {
            let obj = ch
                .get("model_object")
                .ok_or_else(|| err(format!("channels.{name}: no `model_object`")))?;
            let spec = ModelSpec::from_json(&obj.to_string())
                .map_err(|e| err(format!("channels.{name}.model_object: {e}")))?;
            let si = matches!(
                spec.unit.replace(' ', "").as_str(),
                "rad/s" | "m/s^2" | "m/s2"
            );
            if !si {
                return Err(err(format!(
                    "channels.{name}: unit `{}` is not SI (fit the interchange file, which is in rad/s and m/s^2)",
                    spec.unit
                )));
            }
            out.insert(name, spec);
        }
        Ok(Self {
            channels: out,
            source: format!("file {}", path.display()),
        })
    }
}

/// Options of [`diagnose`].
#[derive(Debug, Clone, Copy)]
pub struct DiagnoseOptions {
    /// Baseline simulations per channel.
    pub replicates: usize,
    pub seed: u64,
    /// Family-wise false-alarm level of a whole run (split over its tests).
    pub alpha: f64,
    /// Fraction of the epochs held out (at the end) for the held-out gain.
    pub holdout_fraction: f64,
    /// Smallest share of a channel's error variance a deterministic term must explain.
    pub min_variance_explained: f64,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            replicates: 30,
            seed: 1,
            alpha: 0.01,
            holdout_fraction: 0.3,
            min_variance_explained: 0.005,
        }
    }
}

/// A named cause (the output contract's `findings` entries).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finding {
    pub channel: String,
    pub cause: String,
    /// The regressors or signal features the estimate refers to, in order.
    pub regressors: Vec<String>,
    /// SI units: a number, or a list aligned with `regressors` (a lever arm: 3 components).
    pub estimate: Value,
    /// [lo, hi], or a list of them aligned with `regressors`.
    pub ci95: Value,
    /// Share of the channel's error variance this term accounts for.
    pub variance_explained: f64,
}

/// Per-channel gain of the extended model over the baseline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gain {
    pub metric: String,
    pub baseline: f64,
    pub extended: f64,
    pub held_out_baseline: f64,
    pub held_out_extended: f64,
    /// Share of the error variance the extended model's deterministic terms explain
    /// (in-sample, and on the held-out part with coefficients from the first part).
    pub variance_explained: f64,
    pub held_out_variance_explained: f64,
}

/// A statistic the baseline fails to reproduce.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Discrepancy {
    pub channel: String,
    pub statistic: String,
    pub measured: f64,
    /// Range of the statistic over the baseline simulations.
    pub simulated_range: [f64; 2],
    pub detail: String,
}

/// Everything `diagnose` found.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DiagnoseReport {
    pub baseline_source: String,
    pub calibration: Option<CalibrationSummary>,
    pub findings: Vec<Finding>,
    pub gain: BTreeMap<String, Gain>,
    pub discrepancies: Vec<Discrepancy>,
    /// Per channel, the measured error's wavelet variance against the simulated bands of the
    /// baseline and the extended model (what the gain's misfit compares; the report plots it).
    pub wv_curves: BTreeMap<String, WvCurves>,
    /// The extended model as a simulator model file (`dynacal simulate --model`).
    pub extended_model: Value,
    /// Notes on what was assumed.
    pub notes: Vec<String>,
}

/// Haar wavelet variance of a channel's measured error and the 95% bands of the same
/// statistic over simulations of the baseline and of the extended model, in the channel's
/// squared SI unit ((rad/s)^2 or (m/s^2)^2), at scales `scale_s` = 2^j dt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WvCurves {
    pub scale_s: Vec<f64>,
    pub measured: Vec<f64>,
    pub baseline_lo: Vec<f64>,
    pub baseline_hi: Vec<f64>,
    pub extended_lo: Vec<f64>,
    pub extended_hi: Vec<f64>,
}

impl WvCurves {
    fn new(dt_s: f64, measured_log: &[f64], base: &[Vec<f64>], ext: &[Vec<f64>]) -> Self {
        let (bm, bs) = level_stats(base);
        let (em, es) = level_stats(ext);
        let j = measured_log.len().min(bm.len()).min(em.len());
        let band = |m: &[f64], s: &[f64], sign: f64| -> Vec<f64> {
            (0..j)
                .map(|k| (m[k] + sign * Z_FLOOR * s[k]).exp())
                .collect()
        };
        Self {
            scale_s: (0..j).map(|k| dt_s * 2f64.powi(k as i32 + 1)).collect(),
            measured: measured_log[..j].iter().map(|v| v.exp()).collect(),
            baseline_lo: band(&bm, &bs, -1.0),
            baseline_hi: band(&bm, &bs, 1.0),
            extended_lo: band(&em, &es, -1.0),
            extended_hi: band(&em, &es, 1.0),
        }
    }
}

/// Model error of the calibration's lever arm, m (1 sigma), added to its statistical
/// uncertainty: on simulated 300 s car runs the estimate missed the truth by 0.85 mm with a
/// statistical sigma of 0.36 mm (the linearised eq. 11 with interpolated reference rates and
/// their derivatives is not exact at the millimetre level).
pub const LEVER_ARM_MODEL_SIGMA_M: f64 = 1e-3;

/// Smallest deviation of a level's log wavelet variance from the baseline's that names a
/// noise change: 0.1 is about 10% in variance, 5% in sigma. On simulated null runs,
/// deviations of 0.03 at level 1 (1.5% in sigma) were significant and named a
/// white-noise change.
pub const WV_MIN_LOG_DEVIATION: f64 = 0.1;

const Z_FLOOR: f64 = 1.959_963_984_540_054;

/// A deterministic term: regressor values and where it goes in the simulator model.
struct Candidate<'a> {
    name: String,
    values: &'a [f64],
    cause: &'static str,
    /// (simulator field, axis index) of the coefficient.
    field: (&'static str, usize),
}

fn variance(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)
}

fn ci(est: f64, se: f64) -> [f64; 2] {
    [est - Z_FLOOR * se, est + Z_FLOOR * se]
}

/// The deterministic part of a channel's error over `range`: the sum of the kept terms.
fn det_terms(
    cands: &[Candidate],
    coeffs: &[(usize, f64, [f64; 2], f64)],
    range: std::ops::Range<usize>,
) -> Vec<f64> {
    range
        .map(|t| {
            coeffs
                .iter()
                .map(|(k, b, _, _)| b * cands[*k].values[t])
                .sum::<f64>()
        })
        .collect()
}

/// What a least-squares fit of per-channel terms jointly with the calibration needs of the
/// calibration: with a reference, the calibration design (weighted least squares over every
/// channel's rows: boresight, lever arm, biases); without one (static data), a mean per
/// channel.
#[derive(Clone, Copy)]
enum Absorber<'a> {
    Design(&'a CalibrationDesign),
    Mean,
}

/// A regressor on one channel seen through the calibration: its moments with the
/// calibration's columns (X_c' W_c x) and the parameters the calibration would take from
/// it, `absorbed` = (X'WX)^-1 X_c' W_c x.
struct Projection {
    moments: nalgebra::DVector<f64>,
    absorbed: nalgebra::DVector<f64>,
}

impl Absorber<'_> {
    fn weight(&self, channel: usize) -> f64 {
        match self {
            Absorber::Design(d) => d.weight(channel),
            Absorber::Mean => 1.0,
        }
    }
    fn project(&self, channel: usize, x: &[f64]) -> Projection {
        match self {
            Absorber::Design(d) => {
                let moments = d.moments(channel, x);
                Projection {
                    absorbed: d.bread() * &moments,
                    moments,
                }
            }
            Absorber::Mean => {
                let sum = x.iter().sum::<f64>();
                Projection {
                    moments: nalgebra::DVector::from_element(1, sum),
                    absorbed: nalgebra::DVector::from_element(1, sum / x.len().max(1) as f64),
                }
            }
        }
    }
    /// `x` on `channel` minus what the calibration takes from it there.
    fn own(&self, channel: usize, x: &[f64], p: &Projection) -> Vec<f64> {
        match self {
            Absorber::Design(d) => x
                .iter()
                .zip(d.fitted(channel, &p.absorbed))
                .map(|(v, f)| v - f)
                .collect(),
            Absorber::Mean => x.iter().map(|v| v - p.absorbed[0]).collect(),
        }
    }
    /// Weighted inner product of two terms after the calibration has taken its part from
    /// both, over every channel's rows: w_c <x, y> [same channel] - x' W X (X'WX)^-1 X' W y.
    fn gram(&self, a: &Term, b: &Term) -> f64 {
        let same = if a.channel == b.channel {
            self.weight(a.channel) * a.raw.iter().zip(&b.raw).map(|(x, y)| x * y).sum::<f64>()
        } else {
            0.0
        };
        same - a.projection.moments.dot(&b.projection.absorbed)
    }
}

/// A deterministic term on one channel (index into [`CHANNELS`]): its regressor as measured
/// (`raw`) and stripped of what the calibration absorbs from it on its own channel (`own`),
/// its moments after the calibration with the error and with each baseline simulation, and
/// its coefficient with the standard error the simulations give it.
struct Term {
    channel: usize,
    name: String,
    cause: &'static str,
    field: (&'static str, usize),
    raw: Vec<f64>,
    own: Vec<f64>,
    projection: Projection,
    on_error: f64,
    on_sims: Vec<f64>,
    coef: f64,
    se: f64,
    /// Smallest standard error the term's coefficient may have: the measured-residual
    /// spread of its own channel's fit, kept for the joint fit across channels.
    sd_floor: f64,
}

impl Term {
    /// `moments_e` and `moments_sims`: the calibration's moments of the error and of each
    /// replicate's simulations (all channels with a design, this one without).
    fn new(
        absorber: &Absorber,
        channel: usize,
        c: &Candidate,
        e: &[f64],
        moments_e: &nalgebra::DVector<f64>,
        sims: &[Vec<f64>],
        moments_sims: &[nalgebra::DVector<f64>],
    ) -> Self {
        let projection = absorber.project(channel, c.values);
        let w = absorber.weight(channel);
        let after = |y: &[f64], m: &nalgebra::DVector<f64>| {
            w * c.values.iter().zip(y).map(|(a, b)| a * b).sum::<f64>() - projection.absorbed.dot(m)
        };
        Term {
            channel,
            name: c.name.clone(),
            cause: c.cause,
            field: c.field,
            raw: c.values.to_vec(),
            own: absorber.own(channel, c.values, &projection),
            on_error: after(e, moments_e),
            on_sims: sims
                .iter()
                .zip(moments_sims)
                .map(|(s, m)| after(s, m))
                .collect(),
            projection,
            coef: 0.0,
            se: f64::NAN,
            sd_floor: 0.0,
        }
    }
}

/// The error left after the terms: `e` minus each term's own-channel regressor times its
/// coefficient, minus the mean of what remains.
fn residual_of(e: &[f64], terms: &[Term]) -> Vec<f64> {
    let mut r = e.to_vec();
    for t in terms {
        r.iter_mut().zip(&t.own).for_each(|(v, x)| *v -= t.coef * x);
    }
    let m = r.iter().sum::<f64>() / r.len().max(1) as f64;
    r.iter_mut().for_each(|v| *v -= m);
    r
}

/// Coefficients, null standard deviations and |z| of a least-squares fit on moments.
struct MomentFit {
    beta: Vec<f64>,
    sd: Vec<f64>,
    z: Vec<f64>,
}

/// The error a fit of terms on one channel leaves, for a spread of its coefficients that
/// does not lean on the baseline model: `e` with `weight`, the calibration's weight of the
/// channel.
#[derive(Clone, Copy)]
struct MeasuredSpread<'a> {
    e: &'a [f64],
    weight: f64,
}

/// Blocks of the batch-means spread: long enough (45 s of a 900 s drive) to hold most of the
/// correlation of a Gauss-Markov wander of 20 s, many enough for a spread within ~16%.
const SPREAD_BLOCKS: usize = 20;

/// Standard deviations of the coefficients from the measured residual itself (batch means:
/// the coefficients' scores summed over SPREAD_BLOCKS consecutive blocks, in a sandwich with
/// the inverse Gram matrix). Why: the simulated spread assumes the baseline's noise; when the
/// channel's correlated noise is stronger than the baseline's (a noise change), that spread
/// is too small and slow wander correlated with slow manoeuvres is named as terms.
fn measured_spread(
    spread: MeasuredSpread,
    terms: &[Term],
    active: &[usize],
    beta: &[f64],
    gram_inv: &nalgebra::DMatrix<f64>,
) -> Vec<f64> {
    let n = spread.e.len();
    let mut u = spread.e.to_vec();
    for (a, &k) in active.iter().enumerate() {
        u.iter_mut()
            .zip(&terms[k].own)
            .for_each(|(v, x)| *v -= beta[a] * x);
    }
    let mean = u.iter().sum::<f64>() / n.max(1) as f64;
    let block = (n / SPREAD_BLOCKS).max(1);
    let scores: Vec<nalgebra::DVector<f64>> = (0..n / block)
        .map(|b| {
            let range = b * block..(b + 1) * block;
            nalgebra::DVector::from_iterator(
                active.len(),
                active.iter().map(|&k| {
                    spread.weight
                        * terms[k].own[range.clone()]
                            .iter()
                            .zip(&u[range.clone()])
                            .map(|(x, v)| x * (v - mean))
                            .sum::<f64>()
                }),
            )
        })
        .collect();
    let blocks = scores.len() as f64;
    let centre = scores
        .iter()
        .fold(nalgebra::DVector::zeros(active.len()), |acc, s| acc + s)
        / blocks;
    let meat = scores.iter().fold(
        nalgebra::DMatrix::zeros(active.len(), active.len()),
        |acc, s| {
            let d = s - &centre;
            acc + &d * d.transpose()
        },
    ) * (blocks / (blocks - 1.0).max(1.0));
    let cov = gram_inv * meat * gram_inv;
    (0..active.len())
        .map(|a| cov[(a, a)].max(0.0).sqrt())
        .collect()
}

/// Fits the `active` terms on their moments (None when they are exactly collinear). The
/// spread of each coefficient is that of the same fit on every baseline simulation, or,
/// when `spread` is given and it is larger, the batch-means spread of the measured
/// residual.
fn fit_on_moments(
    gram: &nalgebra::DMatrix<f64>,
    terms: &[Term],
    active: &[usize],
    spread: Option<MeasuredSpread>,
) -> Option<MomentFit> {
    let g = nalgebra::DMatrix::from_fn(active.len(), active.len(), |a, b| {
        gram[(active[a], active[b])]
    });
    let chol = g.cholesky()?;
    let solve = |rhs: &dyn Fn(usize) -> f64| {
        chol.solve(&nalgebra::DVector::from_iterator(
            active.len(),
            active.iter().map(|&k| rhs(k)),
        ))
    };
    let beta: Vec<f64> = solve(&|k| terms[k].on_error).iter().copied().collect();
    let replicates = terms[active[0]].on_sims.len();
    let null: Vec<nalgebra::DVector<f64>> = (0..replicates)
        .map(|r| solve(&|k| terms[k].on_sims[r]))
        .collect();
    let reps = null.len() as f64;
    let mut sd: Vec<f64> = (0..active.len())
        .map(|a| {
            let m = null.iter().map(|x| x[a]).sum::<f64>() / reps;
            (null.iter().map(|x| (x[a] - m).powi(2)).sum::<f64>() / (reps - 1.0).max(1.0)).sqrt()
        })
        .collect();
    if let Some(spread) = spread {
        let measured = measured_spread(spread, terms, active, &beta, &chol.inverse());
        sd.iter_mut().zip(measured).for_each(|(s, m)| *s = s.max(m));
    }
    for (s, &k) in sd.iter_mut().zip(active) {
        *s = s.max(terms[k].sd_floor);
    }
    let z = (0..active.len())
        .map(|a| {
            if sd[a] > 0.0 {
                (beta[a] / sd[a]).abs()
            } else {
                0.0
            }
        })
        .collect();
    Some(MomentFit { beta, sd, z })
}

/// Stepwise selection on moments. `gram` holds the terms' inner products after the
/// calibration; each term carries its moment with the error and with every baseline
/// simulation. Backward: the least significant term goes while one is below `z_strict` or
/// `small` (too little variance explained at its coefficient). Forward: of the terms left
/// out, the most significant when added to the survivors comes back if it passes, and the
/// backward pass runs again. The forward pass matters when two terms are nearly collinear
/// (omega_z and f_y ~ speed * omega_z on a car): backward elimination drops whichever is
/// slightly weaker in the crowded full model, and the proxy left alone may fall short where
/// the true term alone would not. Each term comes back at most once, so this ends. Returns
/// (term, coefficient, null sd) of the survivors.
fn eliminate_on_moments(
    gram: &nalgebra::DMatrix<f64>,
    terms: &[Term],
    z_strict: f64,
    small: &dyn Fn(usize, f64) -> bool,
    spread: Option<MeasuredSpread>,
) -> Vec<(usize, f64, f64)> {
    let mut active: Vec<usize> = (0..terms.len()).collect();
    let mut brought_back: Vec<usize> = Vec::new();
    loop {
        let fit = loop {
            if active.is_empty() {
                break None;
            }
            let Some(fit) = fit_on_moments(gram, terms, &active, spread) else {
                // Exactly collinear: the term with the weakest marginal fit goes.
                let marginal = |a: usize| {
                    let k = active[a];
                    terms[k].on_error.abs() / gram[(k, k)].max(1e-300).sqrt()
                };
                let weakest = (0..active.len())
                    .min_by(|&a, &b| marginal(a).total_cmp(&marginal(b)))
                    .expect("active is not empty");
                active.remove(weakest);
                continue;
            };
            let failing =
                (0..active.len()).filter(|&a| fit.z[a] < z_strict || small(active[a], fit.beta[a]));
            match failing.min_by(|&a, &b| fit.z[a].total_cmp(&fit.z[b])) {
                Some(a) => {
                    active.remove(a);
                }
                None => break Some(fit),
            }
        };
        let best = (0..terms.len())
            .filter(|k| !active.contains(k) && !brought_back.contains(k))
            .filter_map(|k| {
                let with: Vec<usize> = active.iter().copied().chain([k]).collect();
                let f = fit_on_moments(gram, terms, &with, spread)?;
                let (z, b) = (f.z[with.len() - 1], f.beta[with.len() - 1]);
                (z >= z_strict && !small(k, b)).then_some((k, z))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((k, _)) => {
                brought_back.push(k);
                active.push(k);
            }
            None => {
                return fit.map_or_else(Vec::new, |f| {
                    active
                        .iter()
                        .enumerate()
                        .map(|(a, &k)| (k, f.beta[a], f.sd[a]))
                        .collect()
                });
            }
        }
    }
}

/// What stage 1 found on one channel.
struct ChannelTerms {
    terms: Vec<Term>,
    step_at_s: Option<f64>,
    discrepancies: Vec<Discrepancy>,
}

/// The terms that survive the joint fit, and per channel (gx..az) what the other channels'
/// terms had pushed into it through the calibration (to be taken out of its error).
struct JointTerms {
    terms: Vec<Term>,
    spill: [Option<Vec<f64>>; 6],
}

/// Fits the terms of all channels jointly with the calibration and with each other, and
/// eliminates, one at a time, those no longer significant or too small to matter (`small`
/// at their coefficient).
///
/// Why: a term on one channel moves the calibration (a gyro's omega_z -> gx term pulls the
/// boresight about y), and the moved calibration leaves a copy of the term's pattern on the
/// other channels (f_x on az). Each channel's own fit sees that copy as a term of its own;
/// in the joint fit the copy is explained by the term that caused it.
fn joint_terms(
    design: &CalibrationDesign,
    terms: Vec<Term>,
    z_strict: f64,
    small: &dyn Fn(&Term, f64) -> bool,
) -> JointTerms {
    let absorber = Absorber::Design(design);
    let k = terms.len();
    let gram = nalgebra::DMatrix::from_fn(k, k, |a, b| absorber.gram(&terms[a], &terms[b]));
    let kept = eliminate_on_moments(&gram, &terms, z_strict, &|i, b| small(&terms[i], b), None);
    let mut spill: [Option<Vec<f64>>; 6] =
        std::array::from_fn(|ch| design.has_channel(ch).then(|| vec![0.0; design.epochs()]));
    let mut terms: Vec<Option<Term>> = terms.into_iter().map(Some).collect();
    let mut out = Vec::new();
    for (i, coef, se) in kept {
        let mut t = terms[i].take().expect("each term once");
        // What the calibration took from this term shows on the other channels as
        // -coef * X_ch absorbed.
        for (ch, s) in spill.iter_mut().enumerate() {
            if let Some(s) = s.as_mut().filter(|_| ch != t.channel) {
                let fit = design.fitted(ch, &t.projection.absorbed);
                s.iter_mut().zip(fit).for_each(|(v, x)| *v -= coef * x);
            }
        }
        t.coef = coef;
        t.se = se;
        out.push(t);
    }
    JointTerms { terms: out, spill }
}

/// Log wavelet variance per level of a series (levels 1..=max).
fn log_wv(x: &[f64], dt_s: f64, max_level: u32) -> Vec<f64> {
    match haar_wv(
        x,
        dt_s,
        &WvOptions {
            max_level: Some(max_level),
            ..Default::default()
        },
    ) {
        Ok(w) => w.variance.iter().map(|v| v.max(1e-300).ln()).collect(),
        Err(_) => Vec::new(),
    }
}

/// Mean and standard deviation per level of simulated log-WVs.
fn level_stats(sims: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
    let levels = sims.iter().map(Vec::len).min().unwrap_or(0);
    let r = sims.len() as f64;
    let mean: Vec<f64> = (0..levels)
        .map(|j| sims.iter().map(|s| s[j]).sum::<f64>() / r)
        .collect();
    let sd: Vec<f64> = (0..levels)
        .map(|j| {
            (sims.iter().map(|s| (s[j] - mean[j]).powi(2)).sum::<f64>() / (r - 1.0).max(1.0))
                .sqrt()
                .max(1e-3)
        })
        .collect();
    (mean, sd)
}

/// Mean squared z-score of the measured log-WV against simulated ones: the WV misfit.
fn wv_misfit(measured: &[f64], sims: &[Vec<f64>]) -> f64 {
    let (mean, sd) = level_stats(sims);
    let j = mean.len().min(measured.len());
    if j == 0 {
        return f64::NAN;
    }
    (0..j)
        .map(|k| ((measured[k] - mean[k]) / sd[k]).powi(2))
        .sum::<f64>()
        / j as f64
}

/// Extra stochastic effects found on a channel, applied when simulating the extended model.
#[derive(Debug, Clone, Default)]
struct ChannelEffects {
    dynamic_noise_sigma_per_rad_s: Option<f64>,
    vibration: Vec<(f64, f64)>,
    outliers: Option<(f64, f64)>,
}

fn simulate_channel(
    spec: &ModelSpec,
    effects: &ChannelEffects,
    omega_norm: &[f64],
    dt_s: f64,
    n: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<f64> {
    let mut x = spec.simulate(n, rng);
    if let Some(k) = effects.dynamic_noise_sigma_per_rad_s {
        for (v, w) in x.iter_mut().zip(omega_norm) {
            let z: f64 = StandardNormal.sample(rng);
            *v += k * w * z;
        }
    }
    for &(f, a) in &effects.vibration {
        let phase: f64 = rand::Rng::random_range(rng, 0.0..std::f64::consts::TAU);
        for (i, v) in x.iter_mut().enumerate() {
            *v += a * (std::f64::consts::TAU * f * i as f64 * dt_s + phase).sin();
        }
    }
    if let Some((p, s)) = effects.outliers {
        for v in x.iter_mut() {
            if rand::Rng::random_bool(rng, p.clamp(0.0, 1.0)) {
                let z: f64 = StandardNormal.sample(rng);
                *v += s * z;
            }
        }
    }
    x
}

/// Lattice spacing of a raw sensor channel, if its values lie on one (quantised output).
fn lattice_step(x: &[f64]) -> Option<(f64, f64)> {
    let diffs: Vec<f64> = x
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 0.0)
        .collect();
    if diffs.len() < 100 {
        return None;
    }
    let scale = diffs.iter().fold(0.0f64, |a, b| a.max(*b));
    let q0 = diffs.iter().fold(f64::INFINITY, |a, b| a.min(*b));
    if !(q0 > 1e-9 * scale) {
        return None;
    }
    let on_lattice = diffs
        .iter()
        .filter(|d| ((*d / q0) - (*d / q0).round()).abs() < 1e-3)
        .count();
    if (on_lattice as f64) < 0.999 * diffs.len() as f64 {
        return None;
    }
    // Refine from the many unit steps.
    let unit: Vec<f64> = diffs
        .iter()
        .copied()
        .filter(|d| (d / q0).round() == 1.0)
        .collect();
    let q = unit.iter().sum::<f64>() / unit.len() as f64;
    let sd = variance(&unit).sqrt() / (unit.len() as f64).sqrt();
    Some((q, sd.max(q * 1e-12)))
}

/// Runs the engine on a sensor recording against a reference (or, without one, on static
/// data whose truth is constant).
pub fn diagnose(
    sensor: &ImuRecording,
    reference: Option<&ImuRecording>,
    baseline: Option<Baseline>,
    opts: &DiagnoseOptions,
) -> Result<DiagnoseReport, DiagnoseError> {
    let mut notes = Vec::new();
    let (signals, calibration) = match reference {
        Some(r) => {
            let (s, c, d) = build_error_signals_with_design(sensor, r, &ErrorOptions::default())?;
            (s, Some((c, d)))
        }
        None => {
            notes.push(
                "no reference: static data assumed, the error is each channel minus its mean"
                    .into(),
            );
            (static_signals(sensor), None)
        }
    };
    let n = signals.t_s.len();
    let dt_s = {
        let mut d: Vec<f64> = signals.t_s.windows(2).map(|w| w[1] - w[0]).collect();
        let m = d.len() / 2;
        *d.select_nth_unstable_by(m, f64::total_cmp).1
    };
    let has_dynamics = reference.is_some();
    let omega_norm: Vec<f64> = (0..n)
        .map(|k| {
            (signals.dynamics[0][k].powi(2)
                + signals.dynamics[1][k].powi(2)
                + signals.dynamics[2][k].powi(2))
            .sqrt()
        })
        .collect();
    let channels: Vec<&str> = CHANNELS
        .iter()
        .copied()
        .filter(|c| signals.error(c).is_some())
        .collect();
    let baseline = match baseline {
        Some(b) => b,
        None => {
            let b = fit_quietest(&signals, &channels, &omega_norm, dt_s)?;
            notes.push(format!("no baseline model given: {}", b.source));
            b
        }
    };
    // Tests per channel: 15 regressors + ~8 stochastic statistics; Bonferroni over all.
    let tests = (channels.len() * 24).max(1) as f64;
    let alpha_test = opts.alpha / tests;
    let z_strict = Normal::new(0.0, 1.0)
        .expect("normal")
        .inverse_cdf(1.0 - alpha_test / 2.0);

    let mut findings = Vec::new();
    let mut discrepancies = Vec::new();
    let f = signals
        .specific_force_b_m_s2
        .clone()
        .unwrap_or_else(|| std::array::from_fn(|i| signals.dynamics[9 + i].clone()));
    // The calibration's derivatives (9-point stencils at the reference's native rate) when
    // there is one: differences at the sensor rate lose much of a vibration's jerk.
    let f_dot: [Vec<f64>; 3] = match &calibration {
        Some((_, d)) => d.f_dot_b_m_s3.clone(),
        None => std::array::from_fn(|i| central_difference(&signals.t_s, &f[i])),
    };
    let design: Option<&CalibrationDesign> = calibration.as_ref().map(|(_, d)| d);
    let split = ((1.0 - opts.holdout_fraction) * n as f64) as usize;

    struct ChannelResult {
        findings: Vec<Finding>,
        discrepancies: Vec<Discrepancy>,
        gain: Gain,
        wv_curves: WvCurves,
        model: Value,
        absorbed: Option<nalgebra::DVector<f64>>,
    }
    // Baseline simulation `r` of a channel (index into `channels`): the null distribution of
    // every statistic. Seeded by channel and replicate, so every stage draws the same ones.
    let baseline_sim = |ci_idx: usize, r: usize, spec: &ModelSpec| -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ ((ci_idx as u64) << 32) ^ r as u64);
        spec.simulate(n, &mut rng)
    };
    let baseline_sims = |ci_idx: usize, spec: &ModelSpec| -> Vec<Vec<f64>> {
        (0..opts.replicates)
            .into_par_iter()
            .map(|r| baseline_sim(ci_idx, r, spec))
            .collect()
    };
    let spec_of = |ch: &str| -> Result<&ModelSpec, DiagnoseError> {
        baseline
            .channels
            .get(ch)
            .ok_or_else(|| DiagnoseError::Channel {
                channel: ch.into(),
                message: format!(
                    "the baseline model ({}) has no model for it",
                    baseline.source
                ),
            })
    };
    // Stage 1, per channel: the deterministic terms its error carries (backward elimination
    // over the physics candidates, then a bias step).
    let errors: [Option<&[f64]>; 6] = std::array::from_fn(|i| signals.error(CHANNELS[i]));
    let absorber = match design {
        Some(d) => Absorber::Design(d),
        None => Absorber::Mean,
    };
    // Every channel's baseline simulations of one replicate (the ones stage 1 draws).
    let sims_of = |r: usize| -> [Option<Vec<f64>>; 6] {
        std::array::from_fn(|i| {
            let ci_idx = channels.iter().position(|c| *c == CHANNELS[i])?;
            Some(baseline_sim(ci_idx, r, baseline.channels.get(CHANNELS[i])?))
        })
    };
    // The calibration's moments of the error and of each replicate's simulations over all
    // channels: what a term's joint fit with the calibration needs of the other channels.
    let (moments_e, moments_sims): (nalgebra::DVector<f64>, Vec<nalgebra::DVector<f64>>) =
        match design {
            Some(d) => (
                d.moments_all(&errors),
                (0..opts.replicates)
                    .into_par_iter()
                    .map(|r| {
                        let sims = sims_of(r);
                        d.moments_all(&std::array::from_fn(|i| sims[i].as_deref()))
                    })
                    .collect(),
            ),
            None => (nalgebra::DVector::zeros(0), Vec::new()),
        };
    // Stage 1, per channel: the deterministic terms its error carries (backward elimination
    // over the physics candidates, then a bias step).
    let stage1: Vec<Result<ChannelTerms, DiagnoseError>> = channels
        .par_iter()
        .enumerate()
        .map(|(ci_idx, &ch)| {
            let e = signals.error(ch).expect("channel present");
            let spec = spec_of(ch)?;
            let axis = CHANNELS
                .iter()
                .position(|c| *c == ch)
                .expect("known channel")
                % 3;
            let gyro = ch.starts_with('g');
            let xyz = ["x", "y", "z"];
            let ch_index = CHANNELS
                .iter()
                .position(|c| *c == ch)
                .expect("known channel");
            // Deterministic candidates by physics. Each is fitted jointly with the
            // calibration (boresight, lever arm, biases) on every channel's rows, so its
            // coefficient is the one of a joint fit: a gyro's omega_z -> gx term is otherwise
            // half absorbed by the boresight, and an accelerometer's jerk term by the time
            // offset.
            let mut cands: Vec<Candidate> = Vec::new();
            if has_dynamics {
                for j in 0..3 {
                    let (input, input_name) = if gyro {
                        (&signals.dynamics[j], "omega")
                    } else {
                        (&f[j], "f")
                    };
                    cands.push(Candidate {
                        name: format!("{input_name}_{}", xyz[j]),
                        values: input,
                        cause: if j == axis {
                            "scale_factor"
                        } else {
                            "cross_axis"
                        },
                        field: (
                            if j == axis {
                                "scale_factor"
                            } else {
                                "cross_axis"
                            },
                            j,
                        ),
                    });
                    if gyro {
                        cands.push(Candidate {
                            name: format!("f_{}", xyz[j]),
                            values: &f[j],
                            cause: "g_sensitivity",
                            field: ("g_sensitivity", j),
                        });
                    }
                    cands.push(Candidate {
                        name: format!("omega_dot_{}", xyz[j]),
                        values: &signals.dynamics[3 + j],
                        cause: "angular_acceleration",
                        field: ("angular_acceleration_sensitivity", j),
                    });
                    cands.push(Candidate {
                        name: format!("f_dot_{}", xyz[j]),
                        values: &f_dot[j],
                        cause: "jerk",
                        field: ("jerk_sensitivity", j),
                    });
                }
            }
            // Baseline simulations: the null distribution of every statistic below.
            let sims = baseline_sims(ci_idx, spec);
            let (own_moments_e, own_moments_sims);
            let (m_e, m_sims) = match absorber {
                Absorber::Design(_) => (&moments_e, &moments_sims),
                Absorber::Mean => {
                    own_moments_e = absorber.project(ch_index, e).moments;
                    own_moments_sims = sims
                        .iter()
                        .map(|s| absorber.project(ch_index, s).moments)
                        .collect::<Vec<_>>();
                    (&own_moments_e, &own_moments_sims)
                }
            };
            // Backward elimination with simulation-calibrated standard errors: the baseline
            // noise (slow Gauss-Markov wander included) is regressed on the same measured
            // dynamics, so spurious correlation of slow noise with slow manoeuvres is in the
            // null distribution. HAC alone under-covers for such persistent noise.
            let var_e = variance(e);
            let eliminate = |cands: &[Candidate]| -> Vec<Term> {
                let terms: Vec<Term> = cands
                    .par_iter()
                    .map(|c| Term::new(&absorber, ch_index, c, e, m_e, &sims, m_sims))
                    .collect();
                let gram = nalgebra::DMatrix::from_fn(terms.len(), terms.len(), |a, b| {
                    absorber.gram(&terms[a], &terms[b])
                });
                let small = |k: usize, b: f64| {
                    !(b.powi(2) * variance(&terms[k].own) / var_e >= opts.min_variance_explained)
                };
                let kept = eliminate_on_moments(
                    &gram,
                    &terms,
                    z_strict,
                    &small,
                    Some(MeasuredSpread {
                        e,
                        weight: absorber.weight(ch_index),
                    }),
                );
                let mut terms: Vec<Option<Term>> = terms.into_iter().map(Some).collect();
                kept.into_iter()
                    .map(|(k, b, sd)| {
                        let mut t = terms[k].take().expect("each term once");
                        t.coef = b;
                        t.se = sd;
                        t.sd_floor = sd;
                        t
                    })
                    .collect()
            };
            let mut terms = eliminate(&cands);
            let sim_range = |vals: &[f64]| {
                [
                    vals.iter().copied().fold(f64::INFINITY, f64::min),
                    vals.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                ]
            };
            let mut ch_disc = Vec::new();

            // A step of the bias. It is looked for at short windows (the difference of the
            // means just after and just before each epoch), where slow Gauss-Markov wander
            // barely moves while a step stands whole, on the residual of the kept terms, with
            // the null spread at each window from the baseline simulations. When found, the
            // step joins the candidates and the elimination runs again, so terms that were
            // standing in for it (a scale factor, when the input's level changes during the
            // run) drop out and its size and interval come from the joint fit.
            let mut step_at_s = None;
            let step_values: Vec<f64>;
            {
                let windows: Vec<usize> = (6..20)
                    .map(|j| 1usize << j)
                    .take_while(|&w| w <= n / 8)
                    .collect();
                let null_sd = local_step_null_sd(&sims, &windows);
                let resid0 = residual_of(e, &terms);
                let sim_z: Vec<f64> = sims
                    .par_iter()
                    .filter_map(|s| local_step_scan(s, &windows, &null_sd))
                    .map(|m| m.z)
                    .collect();
                let range = sim_range(&sim_z);
                // The residual is scaled by its own noise where that is larger than the
                // baseline's (a stronger correlated noise wanders in steps the baseline's
                // would not); the threshold on the largest z still comes from the simulations.
                let own_sd = local_step_robust_sd(&resid0, &windows);
                let scale_sd: Vec<f64> = null_sd
                    .iter()
                    .zip(&own_sd)
                    .map(|(a, b)| a.max(*b))
                    .collect();
                if let Some(step) = local_step_scan(&resid0, &windows, &scale_sd) {
                    if step.z > (1.25 * range[1]).max(z_strict) {
                        let at_s = signals.t_s[step.index] - sensor.t_s[0];
                        ch_disc.push(Discrepancy {
                            channel: ch.into(),
                            statistic: "largest local step of the mean (|z| at its window)".into(),
                            measured: step.z,
                            simulated_range: range,
                            detail: format!(
                                "at t = {:.2} s, window {} samples, local size {:.4e}",
                                signals.t_s[step.index], step.window, step.size
                            ),
                        });
                        step_values = (0..n)
                            .map(|t| if t >= step.index { 1.0 } else { 0.0 })
                            .collect();
                        cands.push(Candidate {
                            name: format!("step_at_{at_s:.2}_s"),
                            values: &step_values,
                            cause: "bias_shift",
                            field: ("bias_steps", 0),
                        });
                        step_at_s = Some(at_s);
                        terms = eliminate(&cands);
                    }
                }
            }
            Ok(ChannelTerms {
                terms,
                step_at_s,
                discrepancies: ch_disc,
            })
        })
        .collect();
    let mut stage1_terms: Vec<ChannelTerms> = stage1.into_iter().collect::<Result<_, _>>()?;
    // Stage 2, across channels: the terms kept per channel are fitted jointly with the
    // calibration and each other, so a term one channel shows only because another
    // channel's term pulled the boresight or lever arm drops out.
    let spill: Vec<Vec<f64>> = match design {
        Some(d) => {
            let all: Vec<Term> = stage1_terms
                .iter_mut()
                .flat_map(|c| std::mem::take(&mut c.terms))
                .collect();
            let joint = joint_terms(d, all, z_strict, &|t: &Term, b: f64| {
                let explained =
                    b.powi(2) * variance(&t.own) / errors[t.channel].map_or(f64::NAN, variance);
                !(explained >= opts.min_variance_explained)
            });
            let mut joint_spill = joint.spill;
            for t in joint.terms {
                let ci_idx = channels
                    .iter()
                    .position(|c| *c == CHANNELS[t.channel])
                    .expect("a channel of the run");
                stage1_terms[ci_idx].terms.push(t);
            }
            channels
                .iter()
                .map(|c| {
                    let i = CHANNELS.iter().position(|x| x == c).expect("known channel");
                    joint_spill[i].take().unwrap_or_else(|| vec![0.0; n])
                })
                .collect()
        }
        None => vec![vec![0.0; n]; channels.len()],
    };
    // Stage 3, per channel: the stochastic effects of what remains, the extended model and
    // its gain.
    let results: Vec<Result<ChannelResult, DiagnoseError>> = channels
        .par_iter()
        .zip(stage1_terms)
        .zip(spill)
        .enumerate()
        .map(|(ci_idx, ((&ch, found), spill))| {
            let spec = spec_of(ch)?;
            let measured = signals.error(ch).expect("channel present");
            // The error as the joint calibration leaves it.
            let e_joint: Vec<f64> = measured.iter().zip(&spill).map(|(v, s)| v - s).collect();
            let e = &e_joint[..];
            let axis = CHANNELS.iter().position(|c| *c == ch).expect("known channel") % 3;
            let gyro = ch.starts_with('g');
            let sims = baseline_sims(ci_idx, spec);
            let var_e = variance(e);
            let cands: Vec<Candidate> = found.terms.iter().map(|t| Candidate { name: t.name.clone(), values: &t.own, cause: t.cause, field: t.field }).collect();
            let mut coeffs: Vec<(usize, f64, [f64; 2], f64)> = found.terms.iter().enumerate().map(|(k, t)| (k, t.coef, ci(t.coef, t.se), t.coef.powi(2) * variance(&t.own) / var_e)).collect();
            let intercept = e.iter().sum::<f64>() / n as f64 - found.terms.iter().map(|t| t.coef * t.own.iter().sum::<f64>() / n as f64).sum::<f64>();
            let step_at_s = found.step_at_s;
            let mut ch_disc = found.discrepancies;
            let sim_range = |vals: &[f64]| [vals.iter().copied().fold(f64::INFINITY, f64::min), vals.iter().copied().fold(f64::NEG_INFINITY, f64::max)];
            // A term on the channel's own derivative is measured on data shifted by the common
            // time offset, so that offset's uncertainty is part of the term's.
            if let Some(t) = calibration.as_ref().and_then(|(c, _)| c.time_offset_s) {
                for (k, b, interval, _) in coeffs.iter_mut() {
                    let (field, j) = cands[*k].field;
                    let own = j == axis && ((gyro && field == "angular_acceleration_sensitivity") || (!gyro && field == "jerk_sensitivity"));
                    if own {
                        let se = (interval[1] - interval[0]) / (2.0 * Z_FLOOR);
                        *interval = ci(*b, se.hypot(t.sigma));
                    }
                }
            }
            let det = |range: std::ops::Range<usize>, coeffs: &[(usize, f64, [f64; 2], f64)]| -> Vec<f64> { det_terms(&cands, coeffs, range) };
            let fitted = det(0..n, &coeffs);
            let mut resid: Vec<f64> = (0..n).map(|t| e[t] - intercept - fitted[t]).collect();
            let mut ch_findings = Vec::new();
            for cause in ["scale_factor", "cross_axis", "g_sensitivity", "angular_acceleration", "jerk", "bias_shift"] {
                let terms: Vec<&(usize, f64, [f64; 2], f64)> = coeffs.iter().filter(|(k, ..)| cands[*k].cause == cause).collect();
                if terms.is_empty() {
                    continue;
                }
                let single = terms.len() == 1;
                ch_findings.push(Finding {
                    channel: ch.into(),
                    cause: cause.into(),
                    regressors: terms.iter().map(|(k, ..)| cands[*k].name.clone()).collect(),
                    estimate: if single { json!(terms[0].1) } else { json!(terms.iter().map(|t| t.1).collect::<Vec<_>>()) },
                    ci95: if single { json!(terms[0].2) } else { json!(terms.iter().map(|t| t.2).collect::<Vec<_>>()) },
                    variance_explained: terms.iter().map(|t| t.3).sum(),
                });
            }

            // Baseline simulations of the residual's statistics.
            let mut effects = ChannelEffects::default();
            let max_level = ((n as f64).log2().floor() as u32).saturating_sub(2).max(1);

            // Noise growing with the dynamics, looked at before outliers: the largest samples
            // of a noise that grows in the manoeuvres are not outliers, and the outlier search
            // then runs on the residual scaled back to the quiet noise level.
            let mut noise_scale: Option<(f64, f64)> = None;
            if has_dynamics {
                let window = ((1.0 / dt_s) as usize).max(16);
                let nd = noise_vs_dynamics(&resid, &omega_norm, window);
                let sim_t: Vec<f64> = sims.iter().map(|s| noise_vs_dynamics(s, &omega_norm, window).t).collect();
                let range = sim_range(&sim_t);
                if nd.t > z_strict.max(range[1] * 1.5) && nd.sigma_per_unit > 0.0 {
                    ch_disc.push(Discrepancy { channel: ch.into(), statistic: "noise variance vs |omega|^2 (t)".into(), measured: nd.t, simulated_range: range, detail: String::new() });
                    ch_findings.push(Finding { channel: ch.into(), cause: "noise_scales_with_dynamics".into(), regressors: vec!["|omega| (rad/s)".into()], estimate: json!(nd.sigma_per_unit), ci95: json!(nd.sigma_per_unit_ci95), variance_explained: nd.sigma_per_unit.powi(2) * omega_norm.iter().map(|w| w * w).sum::<f64>() / n as f64 / variance(e) });
                    effects.dynamic_noise_sigma_per_rad_s = Some(nd.sigma_per_unit);
                    noise_scale = Some((nd.intercept.max(0.0), nd.slope));
                }
            }

            // Outliers.
            let outlier_input: Vec<f64> = match noise_scale {
                Some((var0, slope)) if var0 > 0.0 => resid
                    .iter()
                    .zip(&omega_norm)
                    .map(|(r, w)| r * (var0 / (var0 + slope * w * w)).sqrt())
                    .collect(),
                _ => resid.clone(),
            };
            let out = find_outliers(&outlier_input, 11, 6.0);
            let sim_counts: Vec<f64> = sims.iter().map(|s| find_outliers(s, 11, 6.0).indices.len() as f64).collect();
            let range = sim_range(&sim_counts);
            if out.indices.len() >= 5 && out.indices.len() as f64 > range[1] + 3.0 {
                let med: Vec<f64> = {
                    let w = 5usize;
                    out.indices.iter().map(|&i| {
                        let lo = i.saturating_sub(w);
                        let hi = (i + w + 1).min(n);
                        let mut b: Vec<f64> = resid[lo..hi].to_vec();
                        let m = b.len() / 2;
                        *b.select_nth_unstable_by(m, f64::total_cmp).1
                    }).collect()
                };
                let devs: Vec<f64> = out.indices.iter().zip(&med).map(|(&i, m)| resid[i] - m).collect();
                let op = outlier_process(&out.scaled_deviations, 6.0 * out.robust_sigma, out.robust_sigma, n);
                // The simulation misses the tail either way; only a population that stands out
                // of the noise is named `outliers` (a heavier-tailed noise is not outliers).
                let detail = if op.separated {
                    format!("largest |z| {:.1}", out.max_abs_z)
                } else {
                    format!(
                        "largest |z| {:.1}; a heavier-tailed noise, not a separate outlier population: the exceedances fit a scale of {:.2} robust sigma, of which only {:.1e} would show beyond 6 sigma",
                        out.max_abs_z,
                        op.population_sigma / out.robust_sigma,
                        op.detection_probability
                    )
                };
                ch_disc.push(Discrepancy { channel: ch.into(), statistic: "outliers beyond 6 robust sigma".into(), measured: out.indices.len() as f64, simulated_range: range, detail });
                if op.separated {
                    let ve = devs.iter().map(|d| d * d).sum::<f64>() / n as f64 / variance(e);
                    ch_findings.push(Finding { channel: ch.into(), cause: "outliers".into(), regressors: vec!["probability_per_sample".into(), format!("sigma (estimate {:.3e})", op.sigma)], estimate: json!(op.probability_per_sample), ci95: json!(op.probability_ci95), variance_explained: ve });
                    effects.outliers = Some((op.probability_per_sample, op.sigma));
                    for (&i, m) in out.indices.iter().zip(&med) {
                        resid[i] = *m;
                    }
                }
            }

            // Vibration lines.
            let seg = 1usize << ((n as f64 / 16.0).log2().floor() as u32).clamp(6, 12);
            let lines = spectral_lines(&welch_psd(&resid, dt_s, seg), alpha_test);
            let sim_lines: Vec<f64> = sims.iter().take(8).map(|s| spectral_lines(&welch_psd(s, dt_s, seg), alpha_test).iter().filter(|l| l.freq_hz >= (1.0f64).max(16.0 / (seg as f64 * dt_s))).count() as f64).collect();
            let min_line_hz = (1.0f64).max(16.0 / (seg as f64 * dt_s));
            for line in lines.iter().filter(|l| l.freq_hz >= min_line_hz) {
                // Fit the sinusoid by least squares, refining the frequency within the peak
                // bin: over minutes a half-bin error would turn the fit into nothing.
                let fit_at = |f_hz: f64, y: &[f64]| -> (f64, f64) {
                    let w = std::f64::consts::TAU * f_hz;
                    let (mut ss, mut cc, mut sc, mut ys, mut yc) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for (i, v) in y.iter().enumerate() {
                        let (s, c) = (w * i as f64 * dt_s).sin_cos();
                        ss += s * s; cc += c * c; sc += s * c; ys += v * s; yc += v * c;
                    }
                    let d = ss * cc - sc * sc;
                    if d <= 0.0 { return (0.0, 0.0); }
                    ((ys * cc - yc * sc) / d, (yc * ss - ys * sc) / d)
                };
                let df = 1.0 / (seg as f64 * dt_s);
                let mut best = (line.freq_hz, 0.0);
                for k in -40..=40 {
                    let f_hz = line.freq_hz + k as f64 * df / 40.0;
                    let (a, b) = fit_at(f_hz, &resid);
                    if a * a + b * b > best.1 { best = (f_hz, a * a + b * b); }
                }
                let span = df / 40.0;
                let mut best2 = best;
                for k in -20..=20 {
                    let f_hz = best.0 + k as f64 * span / 20.0;
                    let (a, b) = fit_at(f_hz, &resid);
                    if a * a + b * b > best2.1 { best2 = (f_hz, a * a + b * b); }
                }
                let w = std::f64::consts::TAU * best2.0;
                let (a, b) = fit_at(best2.0, &resid);
                let amp = (a * a + b * b).sqrt();
                for (i, y) in resid.iter_mut().enumerate() {
                    let (s, c) = (w * i as f64 * dt_s).sin_cos();
                    *y -= a * s + b * c;
                }
                // Statistical error of a least-squares sinusoid, plus a 3% allowance for what
                // the sampling does to a line near or above Nyquist (clock jitter, the
                // boresight rotation mixing axes), which the statistical part ignores.
                let noise = ((variance(&resid) * 2.0 / n as f64) + (0.015 * amp).powi(2)).sqrt();
                let line = &super::stats::SpectralLine { freq_hz: best2.0, ..line.clone() };
                ch_disc.push(Discrepancy { channel: ch.into(), statistic: format!("spectral line at {:.2} Hz", line.freq_hz), measured: line.power_ratio, simulated_range: sim_range(&sim_lines), detail: format!("lines found in baseline simulations: {:?}", sim_lines) });
                ch_findings.push(Finding { channel: ch.into(), cause: "vibration".into(), regressors: vec![format!("sinusoid at {:.3} Hz (as sampled)", line.freq_hz)], estimate: json!(amp), ci95: json!(ci(amp, noise)), variance_explained: amp * amp / 2.0 / variance(e) });
                effects.vibration.push((line.freq_hz, amp));
            }

            // Quantization: the raw sensor values on a lattice the baseline does not have.
            let raw = sensor.channel(ch).unwrap_or(&[]);
            if let Some((q, q_se)) = lattice_step(raw) {
                ch_disc.push(Discrepancy { channel: ch.into(), statistic: "raw values on a lattice (LSB)".into(), measured: q, simulated_range: [0.0, 0.0], detail: "baseline simulations are continuous".into() });
                ch_findings.push(Finding { channel: ch.into(), cause: "quantization".into(), regressors: vec!["lsb".into()], estimate: json!(q), ci95: json!(ci(q, q_se)), variance_explained: q * q / 12.0 / variance(e) });
            }

            // Wavelet variance of what remains vs the baseline.
            let measured_wv = log_wv(&resid, dt_s, max_level);
            // Against the baseline with the noise growth found above (still in the residual):
            // without it, that growth would read as a change of the correlated noise too.
            let sim_wv: Vec<Vec<f64>> = match effects.dynamic_noise_sigma_per_rad_s {
                None => sims.par_iter().map(|s| log_wv(s, dt_s, max_level)).collect(),
                Some(_) => {
                    let growth = ChannelEffects { dynamic_noise_sigma_per_rad_s: effects.dynamic_noise_sigma_per_rad_s, ..Default::default() };
                    (0..opts.replicates)
                        .into_par_iter()
                        .map(|r| {
                            let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0xd1_0153 ^ ((ci_idx as u64) << 32) ^ r as u64);
                            log_wv(&simulate_channel(spec, &growth, &omega_norm, dt_s, n, &mut rng), dt_s, max_level)
                        })
                        .collect()
                }
            };
            let (mean, sd) = level_stats(&sim_wv);
            let z: Vec<f64> = (0..mean.len().min(measured_wv.len())).map(|j| (measured_wv[j] - mean[j]) / sd[j]).collect();
            // Significant and large enough to matter: at the finest levels the wavelet
            // variance of a long record is so precise that a 1-2% model error (in sigma) is
            // significant; below WV_MIN_LOG_DEVIATION it is not named.
            let bad: Vec<usize> = (0..z.len()).filter(|&j| z[j].abs() > z_strict.max(4.0) && (measured_wv[j] - mean[j]).abs() > WV_MIN_LOG_DEVIATION).collect();
            let mut stochastic = spec.clone();
            if !bad.is_empty() {
                for &j in &bad {
                    ch_disc.push(Discrepancy { channel: ch.into(), statistic: format!("log WV at level {} (scale {:.3} s)", j + 1, dt_s * 2f64.powi(j as i32 + 1)), measured: measured_wv[j], simulated_range: [mean[j] - 3.0 * sd[j], mean[j] + 3.0 * sd[j]], detail: format!("z = {:.1}", z[j]) });
                }
                // Refit the baseline's structure on what remains.
                if let Ok(wv) = haar_wv(&resid, dt_s, &WvOptions::default()) {
                    if let Ok(input) = FitInput::from_wv(&wv) {
                        if let Ok(fit) = analyze(ch, &spec.unit, &input, &ModelChoice::Fixed(spec.structure()), None, &FitOptions::default()) {
                            stochastic = fit.model_object.clone();
                            let only_small = bad.iter().all(|&j| j < 2);
                            let cause = if only_small { "white_noise_change" } else { "correlated_noise_change" };
                            let params: Vec<_> = fit.parameters.iter().filter(|p| if only_small { p.process == "WN" } else { p.process.starts_with("GM") || p.process == "RW" } && p.name != "beta_per_s").collect();
                            if !params.is_empty() {
                                ch_findings.push(Finding {
                                    channel: ch.into(),
                                    cause: cause.into(),
                                    regressors: params.iter().map(|p| format!("{} {} ({})", p.process, p.name, p.unit)).collect(),
                                    estimate: json!(params.iter().map(|p| p.value).collect::<Vec<_>>()),
                                    ci95: json!(params.iter().map(|p| p.ci95.unwrap_or([f64::NAN, f64::NAN])).collect::<Vec<_>>()),
                                    variance_explained: f64::NAN,
                                });
                            }
                        }
                    }
                }
            }

            // Gain: WV misfit of the raw error against simulations of each model along the
            // measured dynamics, in-sample and on the held-out end.
            let sim_model = |det_coeffs: &[(usize, f64, [f64; 2], f64)], stoch: &ModelSpec, eff: &ChannelEffects, range: std::ops::Range<usize>, icpt: f64, salt: u64| -> Vec<Vec<f64>> {
                let len = range.len();
                let om = &omega_norm[range.clone()];
                (0..opts.replicates.min(16))
                    .into_par_iter()
                    .map(|r| {
                        let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ salt ^ ((ci_idx as u64) << 40) ^ (r as u64) << 8);
                        // Each simulation draws the deterministic coefficients from their
                        // sampling distribution: a term every simulation shared exactly would
                        // leave no spread at the scales it dominates, and any small error of
                        // its coefficient would then read as a huge misfit.
                        let drawn: Vec<(usize, f64, [f64; 2], f64)> = det_coeffs
                            .iter()
                            .map(|&(k, b, interval, ve)| {
                                let se = (interval[1] - interval[0]) / (2.0 * Z_FLOOR);
                                let z: f64 = StandardNormal.sample(&mut rng);
                                (k, b + se * z, interval, ve)
                            })
                            .collect();
                        let d = det(range.clone(), &drawn);
                        let mut x = simulate_channel(stoch, eff, om, dt_s, len, &mut rng);
                        for (v, dv) in x.iter_mut().zip(&d) {
                            *v += dv + icpt;
                        }
                        log_wv(&x, dt_s, max_level.min(((len as f64).log2() as u32).saturating_sub(2)))
                    })
                    .collect()
            };
            let max_level_h = max_level.min(((n - split) as f64).log2() as u32).saturating_sub(2);
            let e_wv = log_wv(e, dt_s, max_level);
            let base_sims = sim_model(&[], spec, &ChannelEffects::default(), 0..n, 0.0, 11);
            let ext_sims = sim_model(&coeffs, &stochastic, &effects, 0..n, intercept, 13);
            let base_misfit = wv_misfit(&e_wv, &base_sims);
            let ext_misfit = wv_misfit(&e_wv, &ext_sims);
            let wv_curves = WvCurves::new(dt_s, &e_wv, &base_sims, &ext_sims);
            // Held out: deterministic coefficients refitted on the first part only.
            let first: Vec<(usize, f64, [f64; 2], f64)> = if coeffs.is_empty() {
                Vec::new()
            } else {
                let regs: Vec<(&str, &[f64])> = coeffs.iter().map(|(k, ..)| (cands[*k].name.as_str(), &cands[*k].values[..split])).collect();
                match backward_elimination(&e[..split], &regs, &RegressionOptions { alpha: 1.0, ..Default::default() }) {
                    Ok(rep) => coeffs.iter().map(|(k, _, c, v)| (*k, rep.coefficient(&cands[*k].name).map_or(0.0, |x| x.estimate), *c, *v)).collect(),
                    Err(_) => coeffs.clone(),
                }
            };
            let e_tail = &e[split..];
            let tail_wv = log_wv(e_tail, dt_s, max_level_h);
            let held_base = wv_misfit(&tail_wv, &sim_model(&[], spec, &ChannelEffects::default(), split..n, 0.0, 17));
            let held_ext = wv_misfit(&tail_wv, &sim_model(&first, &stochastic, &effects, split..n, intercept, 19));
            let ve_in = 1.0 - variance(&(0..n).map(|t| e[t] - fitted[t]).collect::<Vec<_>>()) / variance(e);
            let d_tail = det(split..n, &first);
            let ve_out = 1.0 - variance(&e_tail.iter().zip(&d_tail).map(|(a, b)| a - b).collect::<Vec<_>>()) / variance(e_tail);

            let mut model = json!({ "stochastic": serde_json::to_value(&stochastic).unwrap_or(Value::Null), "bias": intercept });
            for (k, b, _, _) in &coeffs {
                let (field, j) = cands[*k].field;
                if field == "bias_steps" {
                    model[field] = json!([{ "at_s": step_at_s, "size": b }]);
                } else if field == "scale_factor" {
                    model[field] = json!(b);
                } else {
                    if model.get(field).is_none() {
                        model[field] = json!([0.0, 0.0, 0.0]);
                    }
                    model[field][j] = json!(b);
                }
            }
            if let Some(k) = effects.dynamic_noise_sigma_per_rad_s {
                model["dynamic_noise"] = json!({"driver": "angular_rate_norm", "sigma_per_unit": k});
            }
            if !effects.vibration.is_empty() {
                model["vibration_lines"] = json!(effects.vibration.iter().map(|(f, a)| json!({"frequency_hz": f, "amplitude": a})).collect::<Vec<_>>());
            }
            if let Some((p, s)) = effects.outliers {
                model["outliers"] = json!({"probability": p, "sigma": s});
            }
            if let Some(q) = ch_findings.iter().find(|f| f.cause == "quantization").and_then(|f| f.estimate.as_f64()) {
                model["quantization_step"] = json!(q);
            }
            // What the calibration took from the terms found here, to correct its estimates.
            let absorbed = design.map(|d| {
                let mut total = nalgebra::DVector::<f64>::zeros(d.parameters());
                for (k, b, _, _) in &coeffs {
                    total += &found.terms[*k].projection.absorbed * *b;
                }
                total
            });
            Ok(ChannelResult {
                absorbed,
                findings: ch_findings,
                discrepancies: ch_disc,
                wv_curves,
                gain: Gain { metric: "wv_misfit (mean squared z of log wavelet variance vs model simulations)".into(), baseline: base_misfit, extended: ext_misfit, held_out_baseline: held_base, held_out_extended: held_ext, variance_explained: ve_in, held_out_variance_explained: ve_out },
                model,
            })
        })
        .collect();
    let mut gain = BTreeMap::new();
    let mut wv_curves = BTreeMap::new();
    let mut channel_models = serde_json::Map::new();
    let mut absorbed_total: Option<nalgebra::DVector<f64>> = None;
    let mut channel_findings = Vec::new();
    for (ch, r) in channels.iter().zip(results) {
        let r = r?;
        if let Some(a) = r.absorbed {
            absorbed_total = Some(match absorbed_total {
                Some(t) => t + a,
                None => a,
            });
        }
        channel_findings.extend(r.findings);
        discrepancies.extend(r.discrepancies);
        gain.insert((*ch).to_string(), r.gain);
        wv_curves.insert((*ch).to_string(), r.wv_curves);
        channel_models.insert((*ch).to_string(), r.model);
    }
    let (calibration, design) = match calibration {
        Some((c, d)) => (Some(c), Some(d)),
        None => (None, None),
    };
    // Sensor-wide calibration terms, corrected for what the per-channel terms found had
    // pushed into them (the joint estimate), with 1-sigma no smaller than the spread the
    // calibration shows on baseline noise simulated for every channel: the Newey-West sigma
    // alone under-covers when the noise wanders slowly.
    let mut joint_time_offset = None;
    let mut joint_lever = None;
    if let (Some(cal), Some(design)) = (&calibration, &design) {
        let p = design.parameters();
        let shift = absorbed_total.unwrap_or_else(|| nalgebra::DVector::zeros(p));
        let reps = opts.replicates.max(8);
        let thetas: Vec<nalgebra::DVector<f64>> = (0..reps)
            .into_par_iter()
            .map(|r| {
                let series: Vec<Option<Vec<f64>>> = CHANNELS
                    .iter()
                    .enumerate()
                    .map(|(i, c)| {
                        let spec = baseline.channels.get(*c)?;
                        design.has_channel(i).then(|| {
                            let mut rng = ChaCha8Rng::seed_from_u64(
                                opts.seed ^ 0x5eed_ca1b ^ ((r as u64) << 8) ^ i as u64,
                            );
                            spec.simulate(n, &mut rng)
                        })
                    })
                    .collect();
                let refs: [Option<&[f64]>; 6] = std::array::from_fn(|i| series[i].as_deref());
                design.absorbed_all(&refs)
            })
            .collect();
        let sim_sd: Vec<f64> = (0..p)
            .map(|a| {
                let m = thetas.iter().map(|t| t[a]).sum::<f64>() / reps as f64;
                (thetas.iter().map(|t| (t[a] - m).powi(2)).sum::<f64>() / (reps as f64 - 1.0))
                    .sqrt()
            })
            .collect();
        // The time offset is the one common to the channels that agree (see
        // `errors::common_time_offset`): a per-channel term does not move it, so it needs no
        // correction here.
        if let Some(t) = cal.time_offset_s {
            let (value, sigma) = (t.value, t.sigma);
            joint_time_offset = Some(value);
            if sigma > 0.0 && (value / sigma).abs() > z_strict && value.abs() > 0.2 * dt_s.min(0.01)
            {
                for ch in &channels {
                    findings.push(Finding {
                        channel: (*ch).into(),
                        cause: "time_offset".into(),
                        regressors: vec![format!("d{ch}/dt")],
                        estimate: json!(value),
                        ci95: json!(ci(value, sigma)),
                        variance_explained: f64::NAN,
                    });
                }
            }
        }
        if let (Some(l), Some(li)) = (cal.lever_arm_m, design.lever_index()) {
            let value: [f64; 3] = std::array::from_fn(|i| l.value[i] - shift[li + i]);
            let sigma: [f64; 3] = std::array::from_fn(|i| {
                l.sigma[i]
                    .max(sim_sd[li + i])
                    .hypot(LEVER_ARM_MODEL_SIGMA_M)
            });
            joint_lever = Some(value);
            let significant = (0..3).any(|i| {
                sigma[i] > 0.0 && (value[i] / sigma[i]).abs() > z_strict && value[i].abs() > 0.005
            });
            if significant {
                for ch in channels.iter().filter(|c| c.starts_with('a')) {
                    findings.push(Finding {
                        channel: (*ch).into(),
                        cause: "lever_arm".into(),
                        regressors: vec!["r_x_m".into(), "r_y_m".into(), "r_z_m".into()],
                        estimate: json!(value),
                        ci95: json!([
                            ci(value[0], sigma[0]),
                            ci(value[1], sigma[1]),
                            ci(value[2], sigma[2])
                        ]),
                        variance_explained: f64::NAN,
                    });
                }
            }
        }
    }
    findings.extend(channel_findings);
    let mut imu = json!({ "name": "diagnosed", "rate_hz": 1.0 / dt_s, "channels": channel_models });
    if let Some(cal) = &calibration {
        if let Some(l) = joint_lever {
            imu["lever_arm_b_m"] = json!(l);
        }
        if let Some(t) = joint_time_offset {
            imu["time_offset_s"] = json!(t);
        }
        let deg = 180.0 / std::f64::consts::PI;
        let b = cal.boresight_rad.value;
        imu["boresight_rpy_deg"] = json!([b[0] * deg, b[1] * deg, b[2] * deg]);
    }
    for f in findings.iter_mut() {
        if f.variance_explained.is_nan() {
            f.variance_explained = 0.0;
        }
    }
    Ok(DiagnoseReport {
        baseline_source: baseline.source.clone(),
        calibration,
        findings,
        gain,
        discrepancies,
        wv_curves,
        extended_model: json!({ "_comment": "extended model written by dynacal diagnose", "imus": [imu] }),
        notes,
    })
}

/// Error signals of static data without a reference: each channel minus its mean, with the
/// dynamics all zero.
fn static_signals(sensor: &ImuRecording) -> ErrorSignals {
    let n = sensor.len();
    let errors = std::array::from_fn(|i| {
        sensor.channel(CHANNELS[i]).map(|x| {
            let m = x.iter().sum::<f64>() / n as f64;
            x.iter().map(|v| v - m).collect()
        })
    });
    ErrorSignals {
        t_s: sensor.t_s.clone(),
        errors,
        dynamics: std::array::from_fn(|_| vec![0.0; n]),
        specific_force_b_m_s2: None,
    }
}

/// Fits a baseline on the quietest stretch (lowest mean |omega|, a quarter of the run).
fn fit_quietest(
    signals: &ErrorSignals,
    channels: &[&str],
    omega_norm: &[f64],
    dt_s: f64,
) -> Result<Baseline, DiagnoseError> {
    let n = signals.t_s.len();
    let w = (n / 4).max(256).min(n);
    let mut best = (0usize, f64::INFINITY);
    let step = (w / 8).max(1);
    let mut start = 0;
    while start + w <= n {
        let m = omega_norm[start..start + w].iter().sum::<f64>() / w as f64;
        if m < best.1 {
            best = (start, m);
        }
        start += step;
    }
    let mut out = BTreeMap::new();
    for ch in channels {
        let e = &signals.error(ch).expect("channel")[best.0..best.0 + w];
        let unit = if ch.starts_with('g') {
            "rad/s"
        } else {
            "m/s^2"
        };
        let err = |m: String| DiagnoseError::Channel {
            channel: (*ch).into(),
            message: m,
        };
        let wv = haar_wv(e, dt_s, &WvOptions::default()).map_err(|x| err(x.to_string()))?;
        let input = FitInput::from_wv(&wv).map_err(|x| err(x.to_string()))?;
        let fit = analyze(
            ch,
            unit,
            &input,
            &ModelChoice::Auto,
            None,
            &FitOptions::default(),
        )
        .map_err(|x| err(x.to_string()))?;
        out.insert((*ch).to_string(), fit.model_object);
    }
    Ok(Baseline {
        channels: out,
        source: format!(
            "fitted (model auto) on the quietest stretch t = {:.1}..{:.1} s (mean |omega| {:.4} rad/s)",
            signals.t_s[best.0],
            signals.t_s[best.0 + w - 1],
            best.1
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn baseline_reads_the_fit_output_and_rejects_non_si_units() {
        let dir = tempfile::tempdir().unwrap();
        let model = |unit: &str| {
            json!({"model": "WN", "unit": unit, "sample_rate_hz": 100.0,
                   "processes": [{"kind": "white_noise", "sigma2": 1e-6}]})
        };
        let good = dir.path().join("fit.json");
        let list = json!({"channels": [{"channel": "gx", "model_object": model("rad/s")},
                                       {"channel": "ax", "model_object": model("m/s^2")}]});
        std::fs::write(&good, list.to_string()).unwrap();
        let b = Baseline::load(&good).unwrap();
        assert_eq!(b.channels.keys().collect::<Vec<_>>(), vec!["ax", "gx"]);
        assert_eq!(
            b.channels["gx"].processes,
            vec![Process::WhiteNoise { sigma2: 1e-6 }]
        );

        let bad = dir.path().join("deg.json");
        std::fs::write(
            &bad,
            json!({"channels": [{"channel": "gx", "model_object": model("deg/s")}]}).to_string(),
        )
        .unwrap();
        let msg = Baseline::load(&bad).unwrap_err().to_string();
        assert!(msg.contains("deg.json") && msg.contains("not SI"), "{msg}");
    }

    /// Candidates on one channel without a calibration design: the true regressor, a proxy
    /// that is the true one modulated (as f_y is speed times omega_z), and an unrelated one.
    fn moment_terms(
        e: &[f64],
        sims: &[Vec<f64>],
        columns: &[(&str, Vec<f64>)],
    ) -> (nalgebra::DMatrix<f64>, Vec<Term>) {
        let absorber = Absorber::Mean;
        let m_e = absorber.project(0, e).moments;
        let m_sims: Vec<_> = sims
            .iter()
            .map(|s| absorber.project(0, s).moments)
            .collect();
        let terms: Vec<Term> = columns
            .iter()
            .map(|(name, values)| {
                let c = Candidate {
                    name: (*name).into(),
                    values,
                    cause: "scale_factor",
                    field: ("scale_factor", 0),
                };
                Term::new(&absorber, 0, &c, e, &m_e, sims, &m_sims)
            })
            .collect();
        let gram = nalgebra::DMatrix::from_fn(terms.len(), terms.len(), |a, b| {
            absorber.gram(&terms[a], &terms[b])
        });
        (gram, terms)
    }

    fn white_series(rng: &mut ChaCha8Rng, n: usize, sigma: f64) -> Vec<f64> {
        (0..n)
            .map(|_| sigma * Distribution::<f64>::sample(&StandardNormal, rng))
            .collect()
    }

    #[test]
    fn stepwise_selection_keeps_the_true_term_over_its_proxy_and_names_nothing_in_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        let n = 20_000;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.01).collect();
        let truth: Vec<f64> = t
            .iter()
            .map(|t| (0.31 * t).sin() + 0.5 * (1.7 * t).sin())
            .collect();
        let proxy: Vec<f64> = truth
            .iter()
            .zip(&t)
            .map(|(x, t)| x * (1.0 + 0.4 * (0.05 * t).sin()))
            .collect();
        let unrelated: Vec<f64> = t.iter().map(|t| (0.9 * t).cos()).collect();
        let sims: Vec<Vec<f64>> = (0..30).map(|_| white_series(&mut rng, n, 0.05)).collect();
        let noise = white_series(&mut rng, n, 0.05);
        let columns = [
            ("truth", truth.clone()),
            ("proxy", proxy),
            ("unrelated", unrelated),
        ];
        let never_small = |_: usize, _: f64| false;

        let e: Vec<f64> = truth
            .iter()
            .zip(&noise)
            .map(|(x, w)| 0.02 * x + w)
            .collect();
        let (gram, terms) = moment_terms(&e, &sims, &columns);
        let kept = eliminate_on_moments(
            &gram,
            &terms,
            4.0,
            &never_small,
            Some(MeasuredSpread { e: &e, weight: 1.0 }),
        );
        assert_eq!(kept.len(), 1, "{kept:?}");
        let (k, b, sd) = kept[0];
        assert_eq!(terms[k].name, "truth");
        assert!((b - 0.02).abs() < 3.0 * sd, "{b} +- {sd}");

        let (gram, terms) = moment_terms(&noise, &sims, &columns);
        let kept = eliminate_on_moments(
            &gram,
            &terms,
            4.0,
            &never_small,
            Some(MeasuredSpread {
                e: &noise,
                weight: 1.0,
            }),
        );
        assert!(kept.is_empty(), "{kept:?}");
    }

    #[test]
    fn the_measured_spread_guards_against_a_noise_stronger_than_the_baseline() {
        // The baseline simulations are white; the measured error is a slow random walk that
        // wanders with a slow regressor. Against the simulations alone the slope is
        // "significant"; with the measured residual's batch-means spread it is not.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 20_000;
        let slow: Vec<f64> = (0..n).map(|k| (k as f64 * 2e-4).sin()).collect();
        let sims: Vec<Vec<f64>> = (0..30).map(|_| white_series(&mut rng, n, 0.05)).collect();
        let mut walk = 0.0;
        let e: Vec<f64> = (0..n)
            .map(|_| {
                walk += 0.01 * Distribution::<f64>::sample(&StandardNormal, &mut rng);
                walk + 0.05 * Distribution::<f64>::sample(&StandardNormal, &mut rng)
            })
            .collect();
        let columns = [("slow", slow)];
        let (gram, terms) = moment_terms(&e, &sims, &columns);
        let never_small = |_: usize, _: f64| false;
        assert_eq!(
            eliminate_on_moments(&gram, &terms, 4.0, &never_small, None).len(),
            1
        );
        assert!(eliminate_on_moments(
            &gram,
            &terms,
            4.0,
            &never_small,
            Some(MeasuredSpread { e: &e, weight: 1.0 })
        )
        .is_empty());
    }
}
