//! Linear regression of a sensor error on the vehicle dynamics (paper eq. 13), with backward
//! elimination at a significance level, R^2, adjusted R^2, residual variance and the F-test of
//! eq. 14: the paper's Tables II and III.
//!
//! Sensor errors are autocorrelated (Gauss-Markov terms with correlation times of seconds),
//! so the classical OLS standard errors are far too small and nearly every regressor looks
//! significant. The default inference is therefore Newey-West HAC as R's
//! `sandwich::NeweyWest` computes it: Bartlett kernel on the score series x_t e_t, VAR(1)
//! prewhitened (Andrews & Monahan 1992) and with the lag chosen by the Newey & West (1994)
//! automatic bandwidth selection on the prewhitened scores. It stays valid under
//! autocorrelation and heteroscedasticity; the classical inference is available to reproduce
//! the paper. The report says which inference and lag were used.
//!
//! Why not Andrews' (1991) AR(1) plug-in: a MEMS error is mostly white noise with a small,
//! very slow Gauss-Markov part, and so are its scores. An AR(1) fitted to such a series sees
//! the white noise (rho near 0) and picks a lag of a few samples, while the slow part
//! dominates the long-run variance: the intervals came out far too narrow on slow, collinear
//! regressors (yaw rate, lateral acceleration). Prewhitening removes the persistent part
//! parametrically and the NW94 rule measures the remaining autocovariances nonparametrically.
//!
//! Hand-written because no maintained Rust crate offers OLS with HAC covariance and
//! stepwise elimination; the linear algebra is nalgebra's and the distributions statrs'.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor, Normal, StudentsT};

pub mod stream;

/// Names of the 15 dynamics regressors of paper eq. 13, in the paper's order: body angular
/// rate (rad/s), angular acceleration (rad/s^2), angular jerk (rad/s^3), linear acceleration
/// (m/s^2, specific force plus gravity, body frame) and linear jerk (m/s^3).
pub const DYNAMICS_REGRESSORS: [&str; 15] = [
    "omega_x",
    "omega_y",
    "omega_z",
    "omega_dot_x",
    "omega_dot_y",
    "omega_dot_z",
    "omega_ddot_x",
    "omega_ddot_y",
    "omega_ddot_z",
    "a_x",
    "a_y",
    "a_z",
    "a_dot_x",
    "a_dot_y",
    "a_dot_z",
];

/// How standard errors, t-tests and the overall test are computed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Inference {
    /// Classical OLS: independent, homoscedastic errors (the paper's Tables II/III).
    Classical,
    /// Newey-West heteroscedasticity- and autocorrelation-consistent covariance with a
    /// Bartlett kernel; `lag: None` chooses it by Newey & West's (1994) automatic bandwidth
    /// selection; `prewhite` first removes a VAR(1) from the scores and recolours the
    /// long-run covariance (Andrews & Monahan 1992).
    NeweyWest {
        lag: Option<usize>,
        #[serde(default = "default_prewhite")]
        prewhite: bool,
    },
}

fn default_prewhite() -> bool {
    true
}

/// Options of [`backward_elimination`].
#[derive(Debug, Clone, Copy)]
pub struct RegressionOptions {
    /// Significance level for keeping a term (the paper uses 0.05).
    pub alpha: f64,
    /// Inference used both for elimination and for the reported tests.
    pub inference: Inference,
    /// Fit an intercept (the sensor bias). It is never eliminated and not part of the
    /// overall test, which concerns the dynamics coefficients only (eq. 14).
    pub intercept: bool,
}

impl Default for RegressionOptions {
    fn default() -> Self {
        Self {
            alpha: 0.05,
            inference: Inference::NeweyWest {
                lag: None,
                prewhite: true,
            },
            intercept: true,
        }
    }
}

/// One fitted coefficient.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Coefficient {
    /// Regressor name (`intercept` for the constant).
    pub name: String,
    /// Estimate, in error units per regressor unit.
    pub estimate: f64,
    /// Standard error under the report's inference.
    pub std_error: f64,
    /// t statistic (estimate / std_error).
    pub t: f64,
    /// Two-sided p-value.
    pub p_value: f64,
    /// R-style significance stars: `***` < 0.001, `**` < 0.01, `*` < 0.05, `.` < 0.1.
    pub stars: String,
    /// 95% confidence interval under the report's inference.
    pub ci95: [f64; 2],
}

/// The outcome of a regression with backward elimination.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegressionReport {
    /// Inference used, in words (e.g. "Newey-West HAC, Bartlett kernel, VAR(1) prewhitened,
    /// lag 37 (Newey-West 1994 bandwidth 37.4)").
    pub inference: String,
    /// HAC lag (samples) actually used (0 for classical inference).
    pub hac_lag: usize,
    /// Newey-West (1994) automatic bandwidth (samples) before truncation to `hac_lag`; absent
    /// when the lag was given or the inference is classical.
    pub hac_bandwidth: Option<f64>,
    /// Whether the scores were VAR(1) prewhitened.
    pub hac_prewhitened: bool,
    /// Kept terms, intercept first if fitted.
    pub coefficients: Vec<Coefficient>,
    /// Eliminated regressors, in the order they were removed.
    pub eliminated: Vec<String>,
    /// Number of observations.
    pub n: usize,
    /// Coefficient of determination of the final model.
    pub r2: f64,
    /// Adjusted R^2.
    pub adj_r2: f64,
    /// Residual variance sigma_e^2 (error units squared), with n - p degrees of freedom.
    pub residual_variance: f64,
    /// Classical F statistic of H0: all dynamics coefficients of the final model are zero.
    pub f_statistic: f64,
    /// Its degrees of freedom (numerator, denominator).
    pub f_df: [usize; 2],
    /// Its p-value (classical; too small under autocorrelation).
    pub f_p_value: f64,
    /// Wald statistic of the same hypothesis under the report's inference, divided by the
    /// number of restrictions (equals `f_statistic` for classical inference).
    pub wald_f_statistic: f64,
    /// Its p-value (chi-square / q reference under HAC, F under classical).
    pub wald_p_value: f64,
    /// Residuals of the final model, one per observation.
    #[serde(skip)]
    pub residuals: Vec<f64>,
}

impl RegressionReport {
    /// The kept coefficient named `name`, if any.
    pub fn coefficient(&self, name: &str) -> Option<&Coefficient> {
        self.coefficients.iter().find(|c| c.name == name)
    }
}

/// Errors of the regression.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RegressError {
    /// A regressor column has a different length from the response.
    #[error("regressor `{name}` has {len} values, the response has {expected}")]
    LengthMismatch {
        name: String,
        len: usize,
        expected: usize,
    },
    /// Too few observations for the number of regressors.
    #[error("{n} observations are too few for {p} parameters")]
    TooFewObservations { n: usize, p: usize },
    /// A value is NaN or infinite.
    #[error("non-finite value in `{name}` at index {index}")]
    NonFinite { name: String, index: usize },
}

/// Significance stars in R's convention.
pub fn stars(p: f64) -> &'static str {
    if p < 0.001 {
        "***"
    } else if p < 0.01 {
        "**"
    } else if p < 0.05 {
        "*"
    } else if p < 0.1 {
        "."
    } else {
        ""
    }
}

/// Regresses `y` on the named regressors, removing at each step the least significant one
/// until all remaining are significant at `opts.alpha` (paper Section III).
pub fn backward_elimination(
    y: &[f64],
    regressors: &[(&str, &[f64])],
    opts: &RegressionOptions,
) -> Result<RegressionReport, RegressError> {
    let n = y.len();
    for (i, v) in y.iter().enumerate() {
        if !v.is_finite() {
            return Err(RegressError::NonFinite {
                name: "response".into(),
                index: i,
            });
        }
    }
    for (name, x) in regressors {
        if x.len() != n {
            return Err(RegressError::LengthMismatch {
                name: (*name).to_string(),
                len: x.len(),
                expected: n,
            });
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(RegressError::NonFinite {
                name: (*name).to_string(),
                index: i,
            });
        }
    }
    let mut active =
        varying_regressors(regressors.iter().map(|(_, x)| x.iter().any(|&v| v != x[0])));
    let mut eliminated: Vec<String> = (0..regressors.len())
        .filter(|k| !active.contains(k))
        .map(|k| regressors[k].0.to_string())
        .collect();
    loop {
        let fit = fit_ols(y, regressors, &active, opts)?;
        match fit.least_significant(opts) {
            Some(i) => {
                eliminated.push(regressors[active[i]].0.to_string());
                active.remove(i);
            }
            None => {
                let names: Vec<&str> = regressors.iter().map(|(name, _)| *name).collect();
                return Ok(fit.into_report(&names, &active, opts, eliminated));
            }
        }
    }
}

/// The regressors (indices into `regressors`) backward elimination starts from: those that
/// vary, given each column's first value and whether any later value differs. A constant
/// column is collinear with the intercept and is dropped up front.
pub(crate) fn varying_regressors(varies: impl Iterator<Item = bool>) -> Vec<usize> {
    varies
        .enumerate()
        .filter_map(|(k, v)| v.then_some(k))
        .collect()
}

pub(crate) struct OlsFit {
    beta: DVector<f64>,
    cov: DMatrix<f64>,
    p_values: Vec<f64>,
    residuals: Vec<f64>,
    n: usize,
    p: usize,
    r2: f64,
    adj_r2: f64,
    sigma2: f64,
    f: f64,
    f_p: f64,
    wald_f: f64,
    wald_p: f64,
    lag: usize,
    bandwidth: Option<f64>,
    t_dist: Option<StudentsT>,
}

fn design(
    regressors: &[(&str, &[f64])],
    active: &[usize],
    intercept: bool,
    n: usize,
) -> DMatrix<f64> {
    let p = active.len() + usize::from(intercept);
    DMatrix::from_fn(n, p, |row, col| {
        if intercept && col == 0 {
            1.0
        } else {
            regressors[active[col - usize::from(intercept)]].1[row]
        }
    })
}

fn fit_ols(
    y: &[f64],
    regressors: &[(&str, &[f64])],
    active: &[usize],
    opts: &RegressionOptions,
) -> Result<OlsFit, RegressError> {
    let n = y.len();
    let p = active.len() + usize::from(opts.intercept);
    if n <= p + 1 {
        return Err(RegressError::TooFewObservations { n, p });
    }
    let x = design(regressors, active, opts.intercept, n);
    let yv = DVector::from_column_slice(y);
    let scale: Vec<f64> = (0..p).map(|j| column_scale(x.column(j).norm())).collect();
    let mut xs = x.clone();
    for (j, s) in scale.iter().enumerate() {
        xs.column_mut(j).scale_mut(1.0 / s);
    }
    let (xtx_inv, beta_s) = solve_scaled(&xs.tr_mul(&xs), &xs.tr_mul(&yv));
    let fitted = &xs * &beta_s;
    let resid: Vec<f64> = (0..n).map(|i| y[i] - fitted[i]).collect();
    let sse: f64 = resid.iter().map(|e| e * e).sum();
    let mean_y = y.iter().sum::<f64>() / n as f64;
    let sst: f64 = if opts.intercept {
        y.iter().map(|v| (v - mean_y).powi(2)).sum()
    } else {
        y.iter().map(|v| v * v).sum()
    };
    let hac = match opts.inference {
        Inference::Classical => None,
        Inference::NeweyWest { lag, prewhite } => Some(hac_long_run_covariance(
            &scores(&xs, &resid),
            &bandwidth_weights(p, opts.intercept),
            lag,
            prewhite,
        )),
    };
    let solution = ScaledSolution {
        n,
        scale,
        xtx_inv,
        beta_s,
        sse,
        sst,
    };
    Ok(solution.conclude(active.len(), hac, resid, opts))
}

/// Column scaling keeps X'X well conditioned when regressors differ by orders of magnitude
/// (rates ~1 rad/s, jerks ~100 m/s^3): each column is divided by its Euclidean norm, an
/// all-zero column by 1.
pub(crate) fn column_scale(norm: f64) -> f64 {
    if norm > 0.0 {
        norm
    } else {
        1.0
    }
}

/// (X'X)^-1 and the coefficients of the column-scaled normal equations; a singular X'X falls
/// back to the pseudo-inverse, then to zeros.
pub(crate) fn solve_scaled(xtx: &DMatrix<f64>, xty: &DVector<f64>) -> (DMatrix<f64>, DVector<f64>) {
    let p = xtx.nrows();
    let xtx_inv = xtx
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .or_else(|| xtx.clone().pseudo_inverse(1e-12).ok())
        .unwrap_or_else(|| DMatrix::zeros(p, p));
    let beta_s = &xtx_inv * xty;
    (xtx_inv, beta_s)
}

/// The weights the NW94 bandwidth rule gives the score columns: the slopes only (NW94 and
/// sandwich do the same), since the intercept's score is the residual itself.
pub(crate) fn bandwidth_weights(p: usize, intercept: bool) -> Vec<f64> {
    (0..p)
        .map(|j| if intercept && j == 0 { 0.0 } else { 1.0 })
        .collect()
}

/// A least-squares fit in column-scaled form with the sums its tests need, however the data
/// were passed over (whole, or streamed by [`stream`]).
pub(crate) struct ScaledSolution {
    /// Observations.
    pub n: usize,
    /// Column scales (norms), one per parameter.
    pub scale: Vec<f64>,
    /// (Xs'Xs)^-1 of the scaled columns.
    pub xtx_inv: DMatrix<f64>,
    /// Coefficients of the scaled columns.
    pub beta_s: DVector<f64>,
    /// Residual sum of squares.
    pub sse: f64,
    /// Total sum of squares (about the mean with an intercept, about zero without).
    pub sst: f64,
}

impl ScaledSolution {
    /// Standard errors, p-values and the overall tests under `opts.inference` (`hac` is
    /// the long-run covariance of the scaled scores for Newey-West, `None` for classical).
    pub(crate) fn conclude(
        self,
        regressors: usize,
        hac: Option<HacEstimate>,
        residuals: Vec<f64>,
        opts: &RegressionOptions,
    ) -> OlsFit {
        let Self {
            n,
            scale,
            xtx_inv,
            beta_s,
            sse,
            sst,
        } = self;
        let p = scale.len();
        let df_resid = (n - p) as f64;
        let sigma2 = sse / df_resid;
        let r2 = if sst > 0.0 { 1.0 - sse / sst } else { 0.0 };
        let df_model = regressors;
        let adj_r2 = if opts.intercept {
            1.0 - (1.0 - r2) * (n as f64 - 1.0) / df_resid
        } else {
            1.0 - (1.0 - r2) * n as f64 / df_resid
        };
        let (cov_s, lag, bandwidth) = match hac {
            None => (&xtx_inv * sigma2, 0, None),
            Some(hac) => {
                let cov = &xtx_inv * hac.meat * &xtx_inv * (n as f64 / df_resid);
                (cov, hac.lag, hac.bandwidth)
            }
        };
        // Undo the column scaling.
        let beta = DVector::from_fn(p, |j, _| beta_s[j] / scale[j]);
        let cov = DMatrix::from_fn(p, p, |i, j| cov_s[(i, j)] / (scale[i] * scale[j]));

        let t_dist = StudentsT::new(0.0, 1.0, df_resid).ok();
        let normal = Normal::new(0.0, 1.0).expect("standard normal");
        let p_values: Vec<f64> = (0..p)
            .map(|j| {
                let se = cov[(j, j)].max(0.0).sqrt();
                let t = if se > 0.0 {
                    beta[j] / se
                } else {
                    f64::INFINITY
                };
                let tail = match (&opts.inference, &t_dist) {
                    (Inference::Classical, Some(d)) => d.cdf(-t.abs()),
                    _ => normal.cdf(-t.abs()),
                };
                (2.0 * tail).clamp(0.0, 1.0)
            })
            .collect();

        let (f, f_p) = if df_model > 0 && sst > 0.0 {
            let f = ((sst - sse) / df_model as f64) / sigma2;
            let p = FisherSnedecor::new(df_model as f64, df_resid)
                .map(|d| d.sf(f))
                .unwrap_or(f64::NAN);
            (f, p)
        } else {
            (0.0, 1.0)
        };
        let (wald_f, wald_p) = if df_model == 0 {
            (0.0, 1.0)
        } else {
            match opts.inference {
                Inference::Classical => (f, f_p),
                Inference::NeweyWest { .. } => {
                    let off = usize::from(opts.intercept);
                    let b = beta.rows(off, df_model).into_owned();
                    let v = cov.view((off, off), (df_model, df_model)).into_owned();
                    let w = v
                        .clone()
                        .cholesky()
                        .map(|c| (b.transpose() * c.inverse() * &b)[(0, 0)])
                        .unwrap_or(f64::INFINITY);
                    let p = ChiSquared::new(df_model as f64)
                        .map(|d| d.sf(w))
                        .unwrap_or(f64::NAN);
                    (w / df_model as f64, p)
                }
            }
        };
        OlsFit {
            beta,
            cov,
            p_values,
            residuals,
            n,
            p,
            r2,
            adj_r2,
            sigma2,
            f,
            f_p,
            wald_f,
            wald_p,
            lag,
            bandwidth,
            t_dist,
        }
    }
}

impl OlsFit {
    /// The position among the active regressors of the least significant one when it is
    /// not significant at `opts.alpha` (the next to eliminate); `None` when all are.
    pub(crate) fn least_significant(&self, opts: &RegressionOptions) -> Option<usize> {
        let offset = usize::from(opts.intercept);
        (0..self.p - offset)
            .map(|i| (i, self.p_values[i + offset]))
            .filter(|(_, p)| !(*p <= opts.alpha))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i)
    }

    pub(crate) fn into_report(
        self,
        names: &[&str],
        active: &[usize],
        opts: &RegressionOptions,
        eliminated: Vec<String>,
    ) -> RegressionReport {
        let critical = match (&opts.inference, &self.t_dist) {
            (Inference::Classical, Some(d)) => d.inverse_cdf(0.975),
            _ => 1.959_963_984_540_054,
        };
        let coefficients = (0..self.p)
            .map(|j| {
                let name = if opts.intercept && j == 0 {
                    "intercept".to_string()
                } else {
                    names[active[j - usize::from(opts.intercept)]].to_string()
                };
                let se = self.cov[(j, j)].max(0.0).sqrt();
                let est = self.beta[j];
                Coefficient {
                    name,
                    estimate: est,
                    std_error: se,
                    t: if se > 0.0 { est / se } else { f64::INFINITY },
                    p_value: self.p_values[j],
                    stars: stars(self.p_values[j]).to_string(),
                    ci95: [est - critical * se, est + critical * se],
                }
            })
            .collect();
        let prewhitened = matches!(opts.inference, Inference::NeweyWest { prewhite: true, .. });
        let inference = match opts.inference {
            Inference::Classical => "classical OLS (independent homoscedastic errors)".to_string(),
            Inference::NeweyWest { .. } => {
                let how = match self.bandwidth {
                    Some(bw) => format!("Newey-West 1994 automatic bandwidth {bw:.1}"),
                    None => "given".to_string(),
                };
                format!(
                    "Newey-West HAC, Bartlett kernel, {}lag {} samples ({how})",
                    if prewhitened {
                        "VAR(1) prewhitened, "
                    } else {
                        ""
                    },
                    self.lag
                )
            }
        };
        RegressionReport {
            inference,
            hac_lag: self.lag,
            hac_bandwidth: self.bandwidth,
            hac_prewhitened: prewhitened,
            coefficients,
            eliminated,
            n: self.n,
            r2: self.r2,
            adj_r2: self.adj_r2,
            residual_variance: self.sigma2,
            f_statistic: self.f,
            f_df: [active.len(), self.n - self.p],
            f_p_value: self.f_p,
            wald_f_statistic: self.wald_f,
            wald_p_value: self.wald_p,
            residuals: self.residuals,
        }
    }
}

/// Score vectors u_t = x_t e_t stored row-major (one p-vector per time), which keeps the
/// lag products cache-friendly.
fn scores(x: &DMatrix<f64>, resid: &[f64]) -> Vec<f64> {
    let p = x.ncols();
    (0..resid.len())
        .flat_map(|t| (0..p).map(move |j| (t, j)))
        .map(|(t, j)| x[(t, j)] * resid[t])
        .collect()
}

/// Andrews (1991) AR(1) plug-in lag for the Bartlett kernel, from score vectors stored
/// row-major (`scores.len() = n * p`): lag = 1.1447 (alpha n)^(1/3), capped at n/4.
pub fn andrews_bartlett_lag_from_scores(scores: &[f64], p: usize) -> usize {
    if p == 0 {
        return 0;
    }
    let mut sums = AndrewsSums::new(p);
    scores.chunks_exact(p).for_each(|u| sums.push(u));
    sums.lag()
}

/// The sums [`andrews_bartlett_lag_from_scores`] takes of its scores (per column: lag-one
/// products, squares), added one score vector at a time, so that the lag of scores never
/// held together is the same to the bit.
pub(crate) struct AndrewsSums {
    /// Per column: sum u_t u_{t-1}, sum u_{t-1}^2 (t >= 1), sum u_t^2.
    sxy: Vec<f64>,
    sxx: Vec<f64>,
    s2: Vec<f64>,
    previous: Vec<f64>,
    n: usize,
}

impl AndrewsSums {
    pub(crate) fn new(p: usize) -> Self {
        Self {
            sxy: vec![0.0; p],
            sxx: vec![0.0; p],
            s2: vec![0.0; p],
            previous: vec![0.0; p],
            n: 0,
        }
    }

    /// Adds the next score vector.
    pub(crate) fn push(&mut self, u: &[f64]) {
        for (j, &x) in u.iter().enumerate() {
            if self.n > 0 {
                self.sxy[j] += x * self.previous[j];
                self.sxx[j] += self.previous[j] * self.previous[j];
            }
            self.s2[j] += x * x;
        }
        self.previous.copy_from_slice(u);
        self.n += 1;
    }

    /// Andrews' (1991) AR(1) plug-in Bartlett lag of the scores added.
    pub(crate) fn lag(&self) -> usize {
        let n = self.n;
        let (mut num, mut den) = (0.0, 0.0);
        for j in 0..self.s2.len() {
            let sxx = self.sxx[j];
            if sxx <= 0.0 {
                continue;
            }
            let rho = (self.sxy[j] / sxx).clamp(-0.99, 0.99);
            let s2 = self.s2[j] / n as f64 * (1.0 - rho * rho);
            let w = s2 * s2;
            num += w * 4.0 * rho * rho / ((1.0 - rho).powi(6) * (1.0 + rho).powi(2));
            den += w / (1.0 - rho).powi(4);
        }
        if den <= 0.0 {
            return 0;
        }
        let alpha = num / den;
        let lag = 1.1447 * (alpha * n as f64).powf(1.0 / 3.0);
        (lag.ceil() as usize).min(n / 4)
    }
}

/// Newey-West long-run covariance sum_l w_l (Gamma_l + Gamma_l') of score vectors stored
/// row-major (`scores.len() = n * p`), Bartlett weights w_l = 1 - l / (lag + 1). Not divided
/// by n: it is the "meat" of a sandwich (X'X)^-1 S (X'X)^-1.
///
/// Computed as (1 / (lag + 1)) sum_t v_t v_t' over the moving sums v_t of lag + 1
/// consecutive scores (clipped at both ends): each pair (s, r) of scores is counted in
/// lag + 1 - |s - r| windows, which is exactly the Bartlett weight. The cost is O(n p^2)
/// whatever the lag, so long lags on 100 Hz records stay cheap.
pub fn newey_west_meat_from_scores(u: &[f64], p: usize, lag: usize) -> DMatrix<f64> {
    if p == 0 {
        return DMatrix::zeros(0, 0);
    }
    let n = u.len() / p;
    if n == 0 {
        return DMatrix::zeros(p, p);
    }
    let lag = lag.min(n - 1);
    // Chunks of windows in parallel; each chunk starts its moving sum afresh, which also
    // bounds the rounding drift of the running update.
    let windows = n + lag;
    let chunk = MEAT_CHUNK;
    let upper: Vec<f64> = (0..windows.div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let (start, end) = (c * chunk, ((c + 1) * chunk).min(windows));
            let mut acc = vec![0.0; p * p];
            let mut v = vec![0.0; p];
            // v for the window ending at `start`: scores max(0, start - lag) ..= min(start, n - 1).
            for s in start.saturating_sub(lag)..=start.min(n - 1) {
                for (vj, uj) in v.iter_mut().zip(&u[s * p..(s + 1) * p]) {
                    *vj += uj;
                }
            }
            for t in start..end {
                if t > start {
                    if t < n {
                        for (vj, uj) in v.iter_mut().zip(&u[t * p..(t + 1) * p]) {
                            *vj += uj;
                        }
                    }
                    if t > lag {
                        let s = t - lag - 1;
                        for (vj, uj) in v.iter_mut().zip(&u[s * p..(s + 1) * p]) {
                            *vj -= uj;
                        }
                    }
                }
                add_outer_upper(&mut acc, &v);
            }
            acc
        })
        .reduce(
            || vec![0.0; p * p],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    meat_from_upper(&upper, p, lag)
}

/// Windows of the Bartlett moving sums that one run of additions and subtractions covers
/// before the sum is formed afresh, which bounds its rounding drift.
pub(crate) const MEAT_CHUNK: usize = 4096;

/// acc += v v', upper triangle only (row-major p x p).
pub(crate) fn add_outer_upper(acc: &mut [f64], v: &[f64]) {
    let p = v.len();
    for i in 0..p {
        let vi = v[i];
        for k in i..p {
            acc[i * p + k] += vi * v[k];
        }
    }
}

/// The symmetric meat (1 / (lag + 1)) sum v v' from its accumulated upper triangle.
pub(crate) fn meat_from_upper(upper: &[f64], p: usize, lag: usize) -> DMatrix<f64> {
    let scale = 1.0 / (lag as f64 + 1.0);
    DMatrix::from_fn(p, p, |i, k| {
        let (a, b) = if i <= k { (i, k) } else { (k, i) };
        upper[a * p + b] * scale
    })
}

/// A HAC long-run covariance and how its lag was chosen.
#[derive(Debug, Clone)]
pub struct HacEstimate {
    /// Long-run covariance of the scores, not divided by n (the meat of the sandwich).
    pub meat: DMatrix<f64>,
    /// Bartlett lag used, samples.
    pub lag: usize,
    /// Newey-West (1994) automatic bandwidth, samples, when the lag was not given.
    pub bandwidth: Option<f64>,
}

/// Newey-West HAC long-run covariance of score vectors stored row-major
/// (`scores.len() = n * p`), as R's `sandwich::NeweyWest` computes it:
///
/// 1. with `prewhite`, fit a VAR(1) u_t = A u_{t-1} + e_t by least squares (no intercept)
///    and work on its residuals e_t (Andrews & Monahan 1992); A's singular values are capped
///    at 0.97 as Andrews & Monahan advise, so (I - A)^-1 cannot blow up;
/// 2. without a given `lag`, choose it by Newey & West's (1994) automatic bandwidth for the
///    Bartlett kernel on h_t = w' e_t: with sigma_j = sum_t h_t h_{t+j} / n over
///    j <= m = floor(c (n/100)^(2/9)) (c = 3 prewhitened, 4 otherwise), s0 = sigma_0 +
///    2 sum sigma_j, s1 = 2 sum j sigma_j, bandwidth = 1.1447 ((s1/s0)^2)^(1/3) n^(1/3);
///    lag = floor(bandwidth);
/// 3. Bartlett-weighted sum of the autocovariances of e_t (see
///    [`newey_west_meat_from_scores`]), recoloured by (I - A)^-1 S (I - A)^-T.
///
/// `weights` (one per column) select the scores the bandwidth rule looks at; NW94 and
/// sandwich give the intercept's score weight 0.
pub fn hac_long_run_covariance(
    scores: &[f64],
    weights: &[f64],
    lag: Option<usize>,
    prewhite: bool,
) -> HacEstimate {
    let p = weights.len();
    if p == 0 || scores.len() < 2 * p {
        return HacEstimate {
            meat: DMatrix::zeros(p, p),
            lag: 0,
            bandwidth: None,
        };
    }
    let n = scores.len() / p;
    let (resid, recolour) = if prewhite {
        var1_prewhiten(scores, p)
    } else {
        (scores.to_vec(), None)
    };
    let n_e = resid.len() / p;
    let (lag, bandwidth) = match lag {
        Some(l) => (l, None),
        None => {
            let all_zero = weights.iter().all(|w| *w == 0.0);
            let h: Vec<f64> = (0..n_e)
                .map(|t| {
                    resid[t * p..(t + 1) * p]
                        .iter()
                        .zip(weights)
                        .map(|(u, w)| if all_zero { *u } else { u * w })
                        .sum()
                })
                .collect();
            let bw = newey_west_1994_bandwidth(&h, n - n_e, prewhite);
            (lag_of_bandwidth(bw, n_e), Some(bw))
        }
    };
    let s = newey_west_meat_from_scores(&resid, p, lag);
    let meat = match recolour {
        Some(d) => &d * s * d.transpose(),
        None => s,
    };
    HacEstimate {
        meat,
        lag,
        bandwidth,
    }
}

/// The Bartlett lag a bandwidth gives over `n` (prewhitened) scores: its floor, at most
/// n - 1.
pub(crate) fn lag_of_bandwidth(bandwidth: f64, n: usize) -> usize {
    (bandwidth.floor().max(0.0) as usize).min(n - 1)
}

/// Newey & West (1994) automatic Bartlett bandwidth of the scalar series `h` (after
/// `dropped` prewhitening samples), Table II C's pre-lag m and the Bartlett constants.
fn newey_west_1994_bandwidth(h: &[f64], dropped: usize, prewhite: bool) -> f64 {
    let n = h.len();
    let m = nw94_prelag(n, prewhite);
    let sums: Vec<f64> = (0..=m)
        .map(|j| {
            h[..n - j]
                .iter()
                .zip(&h[j..])
                .map(|(a, b)| a * b)
                .sum::<f64>()
        })
        .collect();
    nw94_bandwidth(&sums, n, dropped)
}

/// NW94's pre-lag m = floor(c (n/100)^(2/9)), c = 3 prewhitened and 4 otherwise, at most
/// n - 1: the autocovariances the bandwidth rule looks at.
pub(crate) fn nw94_prelag(n: usize, prewhite: bool) -> usize {
    let c = if prewhite { 3.0 } else { 4.0 };
    ((c * (n as f64 / 100.0).powf(2.0 / 9.0)).floor() as usize).min(n.saturating_sub(1))
}

/// The NW94 Bartlett bandwidth from the lag products `sums[j] = sum_t h_t h_{t+j}`
/// (j = 0 ..= m) of `n` values of h, after `dropped` prewhitening samples.
pub(crate) fn nw94_bandwidth(sums: &[f64], n: usize, dropped: usize) -> f64 {
    let sigma: Vec<f64> = sums.iter().map(|s| s / n as f64).collect();
    let s0 = sigma[0] + 2.0 * sigma[1..].iter().sum::<f64>();
    let s1 = 2.0
        * sigma[1..]
            .iter()
            .enumerate()
            .map(|(j, s)| (j + 1) as f64 * s)
            .sum::<f64>();
    if !(s0 > 0.0) {
        return 0.0;
    }
    1.1447 * (s1 / s0).powi(2).powf(1.0 / 3.0) * ((n + dropped) as f64).powf(1.0 / 3.0)
}

/// Residuals e_t = u_t - A u_{t-1} (t = 1 .. n-1) of a least-squares VAR(1) without
/// intercept, and the recolouring matrix (I - A)^-1.
fn var1_prewhiten(u: &[f64], p: usize) -> (Vec<f64>, Option<DMatrix<f64>>) {
    let n = u.len() / p;
    // Sxx = sum u_{t-1} u_{t-1}', Syx = sum u_t u_{t-1}'.
    let mut sxx = DMatrix::<f64>::zeros(p, p);
    let mut syx = DMatrix::<f64>::zeros(p, p);
    for t in 1..n {
        let prev = &u[(t - 1) * p..t * p];
        let cur = &u[t * p..(t + 1) * p];
        add_var1_sums(&mut sxx, &mut syx, prev, cur);
    }
    let Some((a, recolour)) = var1_fit(&sxx, &syx) else {
        return (u.to_vec(), None);
    };
    let mut e = vec![0.0; (n - 1) * p];
    for t in 1..n {
        var1_residual(
            &a,
            &u[(t - 1) * p..t * p],
            &u[t * p..(t + 1) * p],
            &mut e[(t - 1) * p..t * p],
        );
    }
    (e, Some(recolour))
}

/// Adds one step's VAR(1) normal-equation sums: Sxx += prev prev', Syx += cur prev'.
pub(crate) fn add_var1_sums(
    sxx: &mut DMatrix<f64>,
    syx: &mut DMatrix<f64>,
    prev: &[f64],
    cur: &[f64],
) {
    let p = prev.len();
    for i in 0..p {
        for k in 0..p {
            sxx[(i, k)] += prev[i] * prev[k];
            syx[(i, k)] += cur[i] * prev[k];
        }
    }
}

/// e = cur - A prev, the prewhitened score.
pub(crate) fn var1_residual(a: &DMatrix<f64>, prev: &[f64], cur: &[f64], e: &mut [f64]) {
    for (i, ei) in e.iter_mut().enumerate() {
        let pred: f64 = (0..prev.len()).map(|k| a[(i, k)] * prev[k]).sum();
        *ei = cur[i] - pred;
    }
}

/// The least-squares VAR(1) coefficient A = Syx Sxx^-1 with its singular values capped at
/// 0.97 (Andrews & Monahan 1992, so I - A stays invertible) and the recolouring matrix
/// (I - A)^-1; `None` when either inverse fails (then the scores are used as they are).
pub(crate) fn var1_fit(
    sxx: &DMatrix<f64>,
    syx: &DMatrix<f64>,
) -> Option<(DMatrix<f64>, DMatrix<f64>)> {
    let p = sxx.nrows();
    // Scale to unit diagonal: score columns differ by orders of magnitude.
    let d: Vec<f64> = (0..p)
        .map(|i| {
            let v = sxx[(i, i)].sqrt();
            if v > 0.0 {
                v
            } else {
                1.0
            }
        })
        .collect();
    let sxx_s = DMatrix::from_fn(p, p, |i, k| sxx[(i, k)] / (d[i] * d[k]));
    let inv_s = sxx_s
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .or_else(|| sxx_s.pseudo_inverse(1e-12).ok())?;
    let sxx_inv = DMatrix::from_fn(p, p, |i, k| inv_s[(i, k)] / (d[i] * d[k]));
    let mut a = syx * sxx_inv;
    let svd = a.clone().svd(true, true);
    if svd.singular_values.iter().any(|s| *s > 0.97) {
        if let (Some(uu), Some(vt)) = (&svd.u, &svd.v_t) {
            let s = DMatrix::from_diagonal(&svd.singular_values.map(|s| s.min(0.97)));
            a = uu * s * vt;
        }
    }
    let recolour = (DMatrix::<f64>::identity(p, p) - &a).try_inverse()?;
    Some((a, recolour))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// AR(1) series of `n` values, coefficient `phi`, innovation sigma `sigma`.
    pub(super) fn ar1(rng: &mut ChaCha8Rng, n: usize, phi: f64, sigma: f64) -> Vec<f64> {
        let mut x = 0.0;
        (0..n)
            .map(|_| {
                x = phi * x + sigma * rng.sample::<f64, _>(StandardNormal);
                x
            })
            .collect()
    }

    #[test]
    fn recovers_true_terms_and_eliminates_noise_regressors() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = 20_000;
        let cols: Vec<Vec<f64>> = (0..6).map(|_| ar1(&mut rng, n, 0.9, 1.0)).collect();
        let y: Vec<f64> = (0..n)
            .map(|t| {
                0.3 + 0.05 * cols[1][t] - 0.02 * cols[4][t]
                    + 0.1 * rng.sample::<f64, _>(StandardNormal)
            })
            .collect();
        let names = ["c0", "c1", "c2", "c3", "c4", "c5"];
        let regs: Vec<(&str, &[f64])> = names
            .iter()
            .zip(&cols)
            .map(|(n, c)| (*n, c.as_slice()))
            .collect();
        let rep = backward_elimination(&y, &regs, &RegressionOptions::default()).unwrap();
        let kept: Vec<&str> = rep.coefficients.iter().map(|c| c.name.as_str()).collect();
        assert!(kept.contains(&"c1") && kept.contains(&"c4"), "{kept:?}");
        let c1 = rep.coefficient("c1").unwrap();
        assert!(c1.ci95[0] < 0.05 && 0.05 < c1.ci95[1], "{c1:?}");
        assert!((rep.coefficient("intercept").unwrap().estimate - 0.3).abs() < 0.01);
        assert!(rep.wald_p_value < 1e-10 && rep.f_p_value < 1e-10);
        assert!(rep.r2 > 0.1 && rep.adj_r2 <= rep.r2);
    }

    #[test]
    fn classical_f_and_r2_match_textbook_values() {
        // y = 1 + 2 x + e with exact small data: check against hand-computed OLS.
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        let y = [3.1, 4.9, 7.2, 8.8, 11.1];
        let opts = RegressionOptions {
            inference: Inference::Classical,
            ..Default::default()
        };
        let rep = backward_elimination(&y, &[("x", &x)], &opts).unwrap();
        let b = rep.coefficient("x").unwrap();
        // slope = Sxy/Sxx = 19.9/10, intercept = mean(y) - slope*3
        assert!((b.estimate - 1.99).abs() < 1e-12);
        assert!((rep.coefficient("intercept").unwrap().estimate - (7.02 - 5.97)).abs() < 1e-12);
        let sse: f64 = rep.residuals.iter().map(|e| e * e).sum();
        let sst: f64 = y.iter().map(|v| (v - 7.02f64).powi(2)).sum();
        assert!((rep.r2 - (1.0 - sse / sst)).abs() < 1e-12);
        assert!((rep.f_statistic - (sst - sse) / (sse / 3.0)).abs() < 1e-9);
        assert!((b.std_error - (sse / 3.0 / 10.0).sqrt()).abs() < 1e-12);
    }

    /// Under strongly autocorrelated errors and regressors with no true effect, classical
    /// OLS declares spurious significance far more often than 5%; Newey-West stays close.
    #[test]
    fn hac_controls_false_positives_under_autocorrelation() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (mut classical, mut hac) = (0, 0);
        let reps = 60;
        for _ in 0..reps {
            let n = 4000;
            let x = ar1(&mut rng, n, 0.98, 1.0);
            let y = ar1(&mut rng, n, 0.98, 1.0);
            let regs = [("x", x.as_slice())];
            let c = backward_elimination(
                &y,
                &regs,
                &RegressionOptions {
                    inference: Inference::Classical,
                    ..Default::default()
                },
            )
            .unwrap();
            let h = backward_elimination(&y, &regs, &RegressionOptions::default()).unwrap();
            classical += usize::from(c.coefficient("x").is_some());
            hac += usize::from(h.coefficient("x").is_some());
        }
        assert!(
            classical as f64 / reps as f64 > 0.4,
            "classical {classical}/{reps}"
        );
        assert!((hac as f64 / reps as f64) < 0.2, "hac {hac}/{reps}");
    }

    /// A MEMS error is mostly white noise plus a small, slow Gauss-Markov part, and car
    /// dynamics are slow: the scores look white to an AR(1) fit (Andrews' 1991 plug-in picks
    /// a lag of a few samples) while the slow part dominates their long-run variance. The
    /// prewhitened NW94 inference must bring the false-positive rate closer to 5% than the AR(1)
    /// plug-in lag does not as well.
    #[test]
    fn prewhitened_nw94_cuts_the_ar1_plugin_false_positives_under_white_plus_slow_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        let (mut andrews, mut nw94) = (0, 0);
        let reps = 200;
        let n = 6000;
        for _ in 0..reps {
            let x = ar1(&mut rng, n, 0.99, 1.0);
            let slow = ar1(&mut rng, n, 0.999, 0.014);
            let y: Vec<f64> = slow
                .iter()
                .map(|s| s + rng.sample::<f64, _>(StandardNormal))
                .collect();
            let regs = [("x", x.as_slice())];
            // The AR(1) plug-in lag on this model's scores (intercept and x).
            let xs = DMatrix::from_fn(n, 2, |t, j| if j == 0 { 1.0 } else { x[t] });
            let ols = |t: &[f64]| {
                let mean = t.iter().sum::<f64>() / n as f64;
                t.iter().map(|v| v - mean).collect::<Vec<_>>()
            };
            let (xc, yc) = (ols(&x), ols(&y));
            let b = xc.iter().zip(&yc).map(|(a, b)| a * b).sum::<f64>()
                / xc.iter().map(|a| a * a).sum::<f64>();
            let resid: Vec<f64> = (0..n).map(|t| yc[t] - b * xc[t]).collect();
            let lag = andrews_bartlett_lag_from_scores(&scores(&xs, &resid), 2);
            let a = backward_elimination(
                &y,
                &regs,
                &RegressionOptions {
                    inference: Inference::NeweyWest {
                        lag: Some(lag),
                        prewhite: false,
                    },
                    ..Default::default()
                },
            )
            .unwrap();
            let h = backward_elimination(&y, &regs, &RegressionOptions::default()).unwrap();
            andrews += usize::from(a.coefficient("x").is_some());
            nw94 += usize::from(h.coefficient("x").is_some());
        }
        eprintln!(
            "false positives: Andrews AR(1) lag {andrews}/{reps}, NW94 prewhitened {nw94}/{reps}"
        );
        // Measured: 97/200 and 69/200. Neither reaches 5% here (n / correlation time of the
        // scores is only ~60; no consistent HAC does in so short a record), but prewhitened
        // NW94 must cut the AR(1) plug-in's excess clearly.
        assert!(
            andrews as f64 / reps as f64 > 0.4,
            "andrews {andrews}/{reps}"
        );
        assert!(
            (nw94 as f64) < 0.8 * andrews as f64,
            "nw94 {nw94}/{reps}, andrews {andrews}/{reps}"
        );
    }

    #[test]
    fn moving_sum_meat_equals_bartlett_weighted_autocovariances() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (n, p) = (9000, 3);
        let u: Vec<f64> = (0..n * p)
            .map(|_| rng.sample::<f64, _>(StandardNormal))
            .collect();
        for lag in [0, 1, 7, 5000, n - 1, n + 10] {
            let fast = newey_west_meat_from_scores(&u, p, lag);
            let l_max = lag.min(n - 1);
            let mut slow = DMatrix::<f64>::zeros(p, p);
            for l in 0..=l_max {
                let w = if l == 0 {
                    1.0
                } else {
                    1.0 - l as f64 / (l_max as f64 + 1.0)
                };
                for t in l..n {
                    for i in 0..p {
                        for k in 0..p {
                            let g = u[t * p + i] * u[(t - l) * p + k];
                            slow[(i, k)] += w * g;
                            if l > 0 {
                                slow[(k, i)] += w * g;
                            }
                        }
                    }
                }
            }
            let err = (&fast - &slow).abs().max() / slow.abs().max();
            assert!(err < 1e-9, "lag {lag}: relative error {err}");
        }
    }

    /// For an AR(1) series the NW94 bandwidth estimates the same optimum as Andrews'
    /// formula, 1.1447 (alpha n)^(1/3) with alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2).
    #[test]
    fn nw94_bandwidth_of_an_ar1_matches_the_optimal_bartlett_bandwidth() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let n = 200_000;
        for rho in [0.5, 0.8] {
            let h = ar1(&mut rng, n, rho, 1.0);
            let bw = newey_west_1994_bandwidth(&h, 0, false);
            let alpha = 4.0 * rho * rho / ((1.0 - rho) * (1.0 + rho)).powi(2);
            let optimum = 1.1447 * (alpha * n as f64).powf(1.0 / 3.0);
            assert!(
                (bw / optimum - 1.0).abs() < 0.15,
                "rho {rho}: bandwidth {bw}, optimum {optimum}"
            );
        }
    }

    #[test]
    fn bad_input_is_named() {
        let y = [1.0, 2.0, 3.0];
        let e = backward_elimination(&y, &[("w", &[1.0, 2.0])], &RegressionOptions::default())
            .unwrap_err();
        assert!(e.to_string().contains("`w`"));
        let e = backward_elimination(
            &y,
            &[("w", &[1.0, f64::NAN, 2.0])],
            &RegressionOptions::default(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("index 1"));
    }
}
