//! Linear regression of a sensor error on the vehicle dynamics (paper eq. 13), with backward
//! elimination at a significance level, R^2, adjusted R^2, residual variance and the F-test of
//! eq. 14: the paper's Tables II and III.
//!
//! Sensor errors are autocorrelated (Gauss-Markov terms with correlation times of seconds),
//! so the classical OLS standard errors are far too small and nearly every regressor looks
//! significant. The default inference is therefore Newey-West HAC (Bartlett kernel, lag
//! chosen by Andrews' AR(1) plug-in rule), which stays valid under autocorrelation and
//! heteroscedasticity; the classical inference is available to reproduce the paper. The
//! report says which inference was used.
//!
//! Hand-written because no maintained Rust crate offers OLS with HAC covariance and
//! stepwise elimination; the linear algebra is nalgebra's and the distributions statrs'.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor, Normal, StudentsT};

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
    /// Bartlett kernel; `lag: None` chooses it by Andrews' (1991) AR(1) plug-in rule.
    NeweyWest { lag: Option<usize> },
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
            inference: Inference::NeweyWest { lag: None },
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
    /// Inference used, in words (e.g. "Newey-West HAC, Bartlett kernel, lag 37").
    pub inference: String,
    /// HAC lag actually used (0 for classical inference).
    pub hac_lag: usize,
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
    let mut active: Vec<usize> = (0..regressors.len())
        .filter(|&k| regressors[k].1.iter().any(|&v| v != regressors[k].1[0]))
        .collect();
    // Constant columns are collinear with the intercept: they are dropped up front.
    let mut eliminated: Vec<String> = (0..regressors.len())
        .filter(|k| !active.contains(k))
        .map(|k| regressors[k].0.to_string())
        .collect();
    loop {
        let fit = fit_ols(y, regressors, &active, opts)?;
        let offset = usize::from(opts.intercept);
        let worst = (0..active.len())
            .map(|i| (i, fit.p_values[i + offset]))
            .filter(|(_, p)| !(*p <= opts.alpha))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((i, _)) => {
                eliminated.push(regressors[active[i]].0.to_string());
                active.remove(i);
            }
            None => return Ok(fit.into_report(regressors, &active, opts, eliminated)),
        }
    }
}

struct OlsFit {
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
    // Column scaling keeps X'X well conditioned when regressors differ by orders of
    // magnitude (rates ~1 rad/s, jerks ~100 m/s^3).
    let scale: Vec<f64> = (0..p)
        .map(|j| {
            let norm = x.column(j).norm();
            if norm > 0.0 {
                norm
            } else {
                1.0
            }
        })
        .collect();
    let mut xs = x.clone();
    for (j, s) in scale.iter().enumerate() {
        xs.column_mut(j).scale_mut(1.0 / s);
    }
    let xtx = xs.tr_mul(&xs);
    let xtx_inv = xtx
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .or_else(|| xtx.clone().pseudo_inverse(1e-12).ok())
        .unwrap_or_else(|| DMatrix::zeros(p, p));
    let beta_s = &xtx_inv * xs.tr_mul(&yv);
    let fitted = &xs * &beta_s;
    let resid: Vec<f64> = (0..n).map(|i| y[i] - fitted[i]).collect();
    let sse: f64 = resid.iter().map(|e| e * e).sum();
    let mean_y = y.iter().sum::<f64>() / n as f64;
    let sst: f64 = if opts.intercept {
        y.iter().map(|v| (v - mean_y).powi(2)).sum()
    } else {
        y.iter().map(|v| v * v).sum()
    };
    let df_resid = (n - p) as f64;
    let sigma2 = sse / df_resid;
    let r2 = if sst > 0.0 { 1.0 - sse / sst } else { 0.0 };
    let df_model = active.len();
    let adj_r2 = if opts.intercept {
        1.0 - (1.0 - r2) * (n as f64 - 1.0) / df_resid
    } else {
        1.0 - (1.0 - r2) * n as f64 / df_resid
    };

    let (cov_s, lag) = match opts.inference {
        Inference::Classical => (&xtx_inv * sigma2, 0),
        Inference::NeweyWest { lag } => {
            let lag = lag.unwrap_or_else(|| andrews_bartlett_lag(&xs, &resid));
            let meat = newey_west_meat(&xs, &resid, lag);
            let cov = &xtx_inv * meat * &xtx_inv * (n as f64 / df_resid);
            (cov, lag)
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
    Ok(OlsFit {
        beta,
        cov,
        p_values,
        residuals: resid,
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
        t_dist,
    })
}

impl OlsFit {
    fn into_report(
        self,
        regressors: &[(&str, &[f64])],
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
                    regressors[active[j - usize::from(opts.intercept)]]
                        .0
                        .to_string()
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
        let inference = match opts.inference {
            Inference::Classical => "classical OLS (independent homoscedastic errors)".to_string(),
            Inference::NeweyWest { lag: Some(_) } => {
                format!("Newey-West HAC, Bartlett kernel, lag {} (given)", self.lag)
            }
            Inference::NeweyWest { lag: None } => format!(
                "Newey-West HAC, Bartlett kernel, lag {} (Andrews AR(1) plug-in)",
                self.lag
            ),
        };
        RegressionReport {
            inference,
            hac_lag: self.lag,
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

/// Andrews (1991) automatic bandwidth for the Bartlett kernel from AR(1) fits of each score
/// series x_tj e_t: lag = 1.1447 (alpha n)^(1/3), capped at n/4.
fn andrews_bartlett_lag(x: &DMatrix<f64>, resid: &[f64]) -> usize {
    andrews_bartlett_lag_from_scores(&scores(x, resid), x.ncols())
}

fn newey_west_meat(x: &DMatrix<f64>, resid: &[f64], lag: usize) -> DMatrix<f64> {
    newey_west_meat_from_scores(&scores(x, resid), x.ncols(), lag)
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
    let n = scores.len() / p;
    let (mut num, mut den) = (0.0, 0.0);
    for j in 0..p {
        let u = |t: usize| scores[t * p + j];
        let (mut sxy, mut sxx, mut s2) = (0.0, 0.0, 0.0);
        for t in 1..n {
            sxy += u(t) * u(t - 1);
            sxx += u(t - 1) * u(t - 1);
        }
        for t in 0..n {
            s2 += u(t) * u(t);
        }
        if sxx <= 0.0 {
            continue;
        }
        let rho = (sxy / sxx).clamp(-0.99, 0.99);
        let s2 = s2 / n as f64 * (1.0 - rho * rho);
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

/// Newey-West long-run covariance sum_l w_l (Gamma_l + Gamma_l') of score vectors stored
/// row-major (`scores.len() = n * p`), Bartlett weights w_l = 1 - l / (lag + 1). Not divided
/// by n: it is the "meat" of a sandwich (X'X)^-1 S (X'X)^-1.
pub fn newey_west_meat_from_scores(u: &[f64], p: usize, lag: usize) -> DMatrix<f64> {
    if p == 0 {
        return DMatrix::zeros(0, 0);
    }
    let n = u.len() / p;
    let gamma = |l: usize| -> DMatrix<f64> {
        let mut g = DMatrix::<f64>::zeros(p, p);
        for t in l..n {
            let a = &u[t * p..(t + 1) * p];
            let b = &u[(t - l) * p..(t - l + 1) * p];
            for i in 0..p {
                let ai = a[i];
                for k in 0..p {
                    g[(i, k)] += ai * b[k];
                }
            }
        }
        g
    };
    (0..=lag.min(n.saturating_sub(1)))
        .into_par_iter()
        .map(|l| {
            let g = gamma(l);
            if l == 0 {
                g
            } else {
                let w = 1.0 - l as f64 / (lag as f64 + 1.0);
                (&g + g.transpose()) * w
            }
        })
        .reduce(|| DMatrix::zeros(p, p), |a, b| a + b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    fn ar1(rng: &mut ChaCha8Rng, n: usize, phi: f64, sigma: f64) -> Vec<f64> {
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
