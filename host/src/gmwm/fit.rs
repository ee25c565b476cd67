//! The GMWM fit (Guerrier et al. 2013; Stebler et al. 2015 eq. 16): theta_hat = argmin
//! (nu_hat - nu(theta))' Omega (nu_hat - nu(theta)) over the transformed parameters, with
//! Omega = diag(1 / var(nu_hat_j)).
//!
//! - var(nu_hat_j) is [`WaveletVariance::estimate_variance`]: from the width of the WV's 95%
//!   chi-square interval, ((ci_high - ci_low) / (2 z_0.975))^2, i.e. about 2 nu_j^2 / eta_j
//!   with eta_j = max(M_j / 2^j, 1) (eta3). It needs nothing but the WV, so a fit from a
//!   published WV alone uses exactly the same weights as a fit from raw data (where an
//!   interval end is not finite, 2 nu_j^2 / eta_j itself). Omega is reported so anyone can
//!   recompute the objective.
//! - Solver: Levenberg-Marquardt (Nielsen's damping update, Marquardt scaling kept as the
//!   running maximum of diag(J'J) as in MINPACK), on box bounds wide enough never to bind
//!   for a well-posed model (they only stop a collapsing GM from running to infinity).
//!   Convergence: gradient (largest cosine between the residual and a Jacobian column
//!   <= 1e-10), step (|delta| <= 1e-10 (|theta| + 1e-10)) or objective (actual and
//!   predicted relative reductions <= 1e-14). Hand-written because the `levenberg-marquardt`
//!   crate pins nalgebra 0.34 (a third copy of nalgebra beside statrs' 0.33 and our 0.35),
//!   has no bounds, and we need the stop reason and iteration count in the output anyway.
//! - Starting values (deterministic): every amplitude (WN, QN, RW and GM variances, drift
//!   slope^2) enters nu linearly, so for a fixed set of GM time constants the best amplitudes
//!   are a non-negative least-squares problem. The GM inverse correlation times are tried on
//!   a grid of one per octave of the WV's scales (every other octave from 3 GMs up: a bump
//!   in the WV at filter width tau means beta ~ 1/tau, the slopes -1 / -2 / +1/2 / +1 of WN,
//!   QN, RW and drift are what the NNLS weights pick up), and the best few starts are
//!   polished by LM; the lowest objective wins.

use nalgebra::{DMatrix, DVector};

use super::model::{ModelSpec, ProcessKind, Structure};
use crate::wv::WaveletVariance;

/// Errors of the fit.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum FitError {
    #[error("wavelet variance: level {level}: value {value} is not finite and positive")]
    BadVariance { level: u32, value: f64 },
    #[error("wavelet variance: level {level}: interval [{low}, {high}] gives no usable variance for the weights")]
    BadInterval { level: u32, low: f64, high: f64 },
    #[error("model {model} has {params} parameters but the wavelet variance has only {levels} levels: at least one more level than parameters is needed")]
    TooFewLevels {
        model: String,
        params: usize,
        levels: usize,
    },
    /// Model selection has no candidate: even white noise alone needs three levels (one
    /// parameter, one degree of freedom for the J-test, one to spare).
    #[error("the wavelet variance has only {levels} levels (a series of {n} samples): choosing a model needs at least 3 levels, 16 samples or more")]
    TooFewLevelsToChoose { levels: usize, n: usize },
    #[error("wavelet variance has a bad sampling interval {dt_s} s")]
    BadSamplingInterval { dt_s: f64 },
}

/// What the fit consumes: the WV estimate, its weights and what V needs.
#[derive(Debug, Clone)]
pub struct FitInput {
    pub levels: Vec<u32>,
    /// nu_hat_j, unit^2.
    pub variance: Vec<f64>,
    /// Omega_jj = 1 / var(nu_hat_j), 1/unit^4.
    pub omega: Vec<f64>,
    /// M_j, coefficients behind nu_hat_j.
    pub n_coefficients: Vec<usize>,
    pub dt_s: f64,
    /// Samples of the series.
    pub n: usize,
}

impl FitInput {
    /// From a WV, with Omega from its intervals (see the module doc).
    pub fn from_wv(wv: &WaveletVariance) -> Result<Self, FitError> {
        if !(wv.dt_s.is_finite() && wv.dt_s > 0.0) {
            return Err(FitError::BadSamplingInterval { dt_s: wv.dt_s });
        }
        let mut var_est = wv.estimate_variance();
        for (i, &j) in wv.levels.iter().enumerate() {
            let v = wv.variance[i];
            if !(v.is_finite() && v > 0.0) {
                return Err(FitError::BadVariance { level: j, value: v });
            }
            if !(var_est[i].is_finite() && var_est[i] > 0.0) {
                // An interval end that is not finite (seen at eta = 1 levels) carries no
                // width: fall back to the chi-square variance 2 nu^2 / eta3 it stands for.
                let m = wv.n_coefficients.get(i).copied().unwrap_or(0);
                if m == 0 {
                    return Err(FitError::BadInterval {
                        level: j,
                        low: wv.ci_low[i],
                        high: wv.ci_high[i],
                    });
                }
                var_est[i] = 2.0 * v * v / crate::wv::eta3(m, j);
            }
        }
        Ok(Self {
            levels: wv.levels.clone(),
            variance: wv.variance.clone(),
            omega: var_est.iter().map(|v| 1.0 / v).collect(),
            n_coefficients: wv.n_coefficients.clone(),
            dt_s: wv.dt_s,
            n: wv.n,
        })
    }

    /// The same input restricted to `levels` (those it holds, in its order).
    pub fn at_levels(&self, levels: &[u32]) -> FitInput {
        let idx: Vec<usize> = levels
            .iter()
            .filter_map(|j| self.levels.iter().position(|x| x == j))
            .collect();
        FitInput {
            levels: idx.iter().map(|&i| self.levels[i]).collect(),
            variance: idx.iter().map(|&i| self.variance[i]).collect(),
            omega: idx.iter().map(|&i| self.omega[i]).collect(),
            n_coefficients: idx.iter().map(|&i| self.n_coefficients[i]).collect(),
            dt_s: self.dt_s,
            n: self.n,
        }
    }

    pub fn taus(&self) -> Vec<f64> {
        self.levels.iter().map(|&j| (j as f64).exp2()).collect()
    }

    /// The GMWM objective at `theta`.
    pub fn objective(&self, s: &Structure, theta: &[f64]) -> f64 {
        let mut nu = vec![0.0; self.levels.len()];
        s.wv(theta, self.dt_s, &self.taus(), &mut nu, None);
        self.variance
            .iter()
            .zip(&nu)
            .zip(&self.omega)
            .map(|((a, b), w)| w * (a - b) * (a - b))
            .sum()
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The residual is orthogonal to every Jacobian column (first-order optimality).
    Gradient,
    /// The step became negligible relative to the parameters.
    Step,
    /// Actual and predicted reductions of the objective became negligible.
    Objective,
    /// No step of any damping reduced the objective (at the floating-point floor).
    NoProgress,
    /// The iteration limit was reached first.
    MaxIterations,
}

impl StopReason {
    pub fn converged(self) -> bool {
        !matches!(self, StopReason::MaxIterations)
    }
}

/// Solver settings.
#[derive(Debug, Clone, Copy)]
pub struct FitOptions {
    pub max_iterations: usize,
    /// Starts polished by LM after the NNLS grid.
    pub polished_starts: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            max_iterations: 400,
            polished_starts: 4,
        }
    }
}

/// The outcome of one fit of one structure.
#[derive(Debug, Clone)]
pub struct Fit {
    pub structure: Structure,
    /// Transformed parameters, GM processes ordered by increasing beta.
    pub theta: Vec<f64>,
    pub objective: f64,
    pub iterations: usize,
    pub reason: StopReason,
    /// Model WV at the fitted parameters, unit^2.
    pub model_wv: Vec<f64>,
    /// Identifiability warnings (collapsed or negligible processes).
    pub warnings: Vec<String>,
    /// Objective at each polished start (best first), for the record.
    pub start_objectives: Vec<f64>,
}

impl Fit {
    pub fn converged(&self) -> bool {
        self.reason.converged()
    }
    pub fn model(&self, unit: &str, dt_s: f64) -> ModelSpec {
        ModelSpec::from_theta(&self.structure, &self.theta, unit, 1.0 / dt_s)
    }
}

/// Box bounds on theta (see the module doc).
fn bounds(s: &Structure, input: &FitInput) -> (Vec<f64>, Vec<f64>) {
    let taus = input.taus();
    let tau_max = taus.iter().cloned().fold(1.0, f64::max);
    let dt = input.dt_s;
    let (mut lo, mut hi) = (Vec::new(), Vec::new());
    for &kind in &s.kinds {
        if kind == ProcessKind::GaussMarkov {
            lo.push((1e-3 / (tau_max * dt)).ln());
            hi.push((1e3 / dt).ln());
        }
        let (amp_min, amp_max) = amplitude_range(kind, input);
        lo.push(amp_min.ln() - 30.0);
        hi.push(amp_max.ln() + 10.0);
    }
    (lo, hi)
}

/// Smallest and largest amplitude that makes the process (with unit amplitude shape at the
/// most favourable GM time constant for GM) equal nu_hat at some level.
fn amplitude_range(kind: ProcessKind, input: &FitInput) -> (f64, f64) {
    let taus = input.taus();
    let mut lo = f64::INFINITY;
    let mut hi: f64 = 0.0;
    for (&tau, &nu) in taus.iter().zip(&input.variance) {
        let unit = match kind {
            ProcessKind::WhiteNoise => 1.0 / tau,
            ProcessKind::QuantizationNoise => 6.0 / (tau * tau),
            ProcessKind::RandomWalk => (tau * tau + 2.0) / (12.0 * tau),
            ProcessKind::Drift => tau * tau / 16.0,
            // A GM's WV never exceeds about 0.3 sigma2 / ... : its sigma2 is at least nu.
            ProcessKind::GaussMarkov => 1.0,
        };
        lo = lo.min(nu / unit);
        hi = hi.max(nu / unit);
    }
    (lo, hi)
}

/// Unit-amplitude WV columns for fixed GM betas: one column per amplitude parameter.
fn amplitude_columns(s: &Structure, betas: &[f64], input: &FitInput) -> Vec<Vec<f64>> {
    let taus = input.taus();
    let mut cols = Vec::new();
    let mut g = 0;
    for &kind in &s.kinds {
        let col: Vec<f64> = match kind {
            ProcessKind::GaussMarkov => {
                let a = betas[g] * input.dt_s;
                g += 1;
                taus.iter()
                    .map(|&tau| 2.0 * super::model::gm_shape(a, tau / 2.0).0 / (tau * tau))
                    .collect()
            }
            ProcessKind::WhiteNoise => taus.iter().map(|&t| 1.0 / t).collect(),
            ProcessKind::QuantizationNoise => taus.iter().map(|&t| 6.0 / (t * t)).collect(),
            ProcessKind::RandomWalk => taus.iter().map(|&t| (t * t + 2.0) / (12.0 * t)).collect(),
            ProcessKind::Drift => taus.iter().map(|&t| t * t / 16.0).collect(),
        };
        cols.push(col);
    }
    cols
}

/// Non-negative least squares min |A x - b|, x >= 0 (Lawson & Hanson's active-set method;
/// a handful of columns, so a dense normal-equation solve per step is fine). Columns are
/// scaled to unit norm first. Returns x and the residual sum of squares.
pub(crate) fn nnls(cols: &[Vec<f64>], b: &[f64]) -> (Vec<f64>, f64) {
    let n = cols.len();
    let m = b.len();
    let norms: Vec<f64> = cols
        .iter()
        .map(|c| c.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300))
        .collect();
    let a = DMatrix::from_fn(m, n, |i, k| cols[k][i] / norms[k]);
    let bv = DVector::from_column_slice(b);
    let mut x = DVector::zeros(n);
    let mut passive = vec![false; n];
    let solve_passive = |passive: &[bool]| -> DVector<f64> {
        let idx: Vec<usize> = (0..n).filter(|&k| passive[k]).collect();
        let mut z = DVector::zeros(n);
        if idx.is_empty() {
            return z;
        }
        let sub = DMatrix::from_fn(m, idx.len(), |i, c| a[(i, idx[c])]);
        let sol = sub
            .clone()
            .svd(true, true)
            .solve(&bv, 1e-14)
            .unwrap_or_else(|_| DVector::zeros(idx.len()));
        for (c, &k) in idx.iter().enumerate() {
            z[k] = sol[c];
        }
        z
    };
    for _outer in 0..(3 * n + 10) {
        let w = a.transpose() * (&bv - &a * &x);
        let candidate = (0..n)
            .filter(|&k| !passive[k] && w[k] > 1e-12 * bv.norm())
            .max_by(|&p, &q| w[p].total_cmp(&w[q]));
        let Some(t) = candidate else { break };
        passive[t] = true;
        for _inner in 0..(3 * n + 10) {
            let z = solve_passive(&passive);
            if (0..n).all(|k| !passive[k] || z[k] > 0.0) {
                x = z;
                break;
            }
            let mut alpha = 1.0f64;
            for k in 0..n {
                if passive[k] && z[k] <= 0.0 {
                    let denom = x[k] - z[k];
                    if denom > 0.0 {
                        alpha = alpha.min(x[k] / denom);
                    }
                }
            }
            x = &x + (z - &x) * alpha;
            for k in 0..n {
                if passive[k] && x[k] <= 1e-15 {
                    passive[k] = false;
                    x[k] = 0.0;
                }
            }
        }
    }
    let rss = (&bv - &a * &x).norm_squared();
    let out = (0..n).map(|k| x[k] / norms[k]).collect();
    (out, rss)
}

/// Grid of GM beta values (1/s): one per `step` octaves of filter width, from 2 samples to
/// twice the longest filter.
fn beta_grid(input: &FitInput, step: usize) -> Vec<f64> {
    let j_max = input.levels.iter().copied().max().unwrap_or(1) as usize;
    (0..=j_max + 1)
        .step_by(step)
        .map(|x| 1.0 / ((x as f64).exp2() * input.dt_s))
        .collect()
}

fn combinations(n: usize, k: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    let mut cur = Vec::with_capacity(k);
    fn rec(start: usize, n: usize, k: usize, cur: &mut Vec<usize>, out: &mut Vec<Vec<usize>>) {
        if cur.len() == k {
            out.push(cur.clone());
            return;
        }
        for i in start..n {
            cur.push(i);
            rec(i + 1, n, k, cur, out);
            cur.pop();
        }
    }
    rec(0, n, k, &mut cur, &mut out);
    out
}

/// Deterministic starting values, best first (see the module doc).
pub fn starting_values(s: &Structure, input: &FitInput, count: usize) -> Vec<Vec<f64>> {
    let n_gm = s.n_gm();
    let grid = beta_grid(input, if n_gm >= 3 { 2 } else { 1 });
    let combos = if n_gm == 0 {
        vec![vec![]]
    } else {
        combinations(grid.len(), n_gm)
    };
    let sqrt_w: Vec<f64> = input.omega.iter().map(|w| w.sqrt()).collect();
    let b: Vec<f64> = input
        .variance
        .iter()
        .zip(&sqrt_w)
        .map(|(v, w)| v * w)
        .collect();
    let mut scored: Vec<(f64, Vec<f64>)> = combos
        .iter()
        .map(|combo| {
            let betas: Vec<f64> = combo.iter().map(|&i| grid[i]).collect();
            let cols: Vec<Vec<f64>> = amplitude_columns(s, &betas, input)
                .into_iter()
                .map(|c| c.iter().zip(&sqrt_w).map(|(x, w)| x * w).collect())
                .collect();
            let (amps, rss) = nnls(&cols, &b);
            // Amplitudes NNLS sets to zero start at 1e-3 of their smallest sensible value.
            let mut theta = Vec::with_capacity(s.n_params());
            let mut g = 0;
            for (k, &kind) in s.kinds.iter().enumerate() {
                let floor = amplitude_range(kind, input).0 * 1e-3;
                if kind == ProcessKind::GaussMarkov {
                    theta.push(betas[g].ln());
                    g += 1;
                }
                theta.push(amps[k].max(floor).ln());
            }
            (rss, theta)
        })
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    scored.into_iter().take(count.max(1)).map(|x| x.1).collect()
}

/// Outcome of one LM run.
struct LmOutcome {
    theta: Vec<f64>,
    objective: f64,
    iterations: usize,
    reason: StopReason,
}

/// Residuals r_j = sqrt(Omega_j) (nu_hat_j - nu_j(theta)) and, optionally, their Jacobian.
fn residuals(
    s: &Structure,
    input: &FitInput,
    taus: &[f64],
    theta: &[f64],
    jac: Option<&mut DMatrix<f64>>,
) -> DVector<f64> {
    let m = taus.len();
    let p = s.n_params();
    let mut nu = vec![0.0; m];
    match jac {
        Some(jm) => {
            let mut flat = vec![0.0; m * p];
            s.wv(theta, input.dt_s, taus, &mut nu, Some(&mut flat));
            for j in 0..m {
                let w = input.omega[j].sqrt();
                for k in 0..p {
                    jm[(j, k)] = -w * flat[j * p + k];
                }
            }
        }
        None => s.wv(theta, input.dt_s, taus, &mut nu, None),
    }
    DVector::from_fn(m, |j, _| {
        input.omega[j].sqrt() * (input.variance[j] - nu[j])
    })
}

/// Levenberg-Marquardt from `theta0` within [lo, hi] (see the module doc).
fn levenberg_marquardt(
    s: &Structure,
    input: &FitInput,
    theta0: &[f64],
    lo: &[f64],
    hi: &[f64],
    max_iterations: usize,
) -> LmOutcome {
    let taus = input.taus();
    let m = taus.len();
    let p = s.n_params();
    let clamp = |t: &mut DVector<f64>| {
        for k in 0..p {
            t[k] = t[k].clamp(lo[k], hi[k]);
        }
    };
    let mut theta = DVector::from_column_slice(theta0);
    clamp(&mut theta);
    let mut jac = DMatrix::zeros(m, p);
    let mut r = residuals(s, input, &taus, theta.as_slice(), Some(&mut jac));
    let mut f = r.norm_squared();
    let mut scale: DVector<f64> = DVector::from_element(p, 0.0);
    let mut lambda = 1e-3;
    let mut nu_factor = 2.0;
    let mut iterations = 0;
    let reason = loop {
        if iterations >= max_iterations {
            break StopReason::MaxIterations;
        }
        iterations += 1;
        let g = jac.transpose() * &r; // half-gradient of f
        let a = jac.transpose() * &jac;
        // Gradient test on the projected gradient: a component pushing against its bound
        // cannot be followed and does not count.
        let r_norm = r.norm();
        let mut max_cos: f64 = 0.0;
        for k in 0..p {
            let at_lo = theta[k] <= lo[k] && g[k] > 0.0;
            let at_hi = theta[k] >= hi[k] && g[k] < 0.0;
            if at_lo || at_hi {
                continue;
            }
            let col = jac.column(k).norm();
            if col > 0.0 && r_norm > 0.0 {
                max_cos = max_cos.max(g[k].abs() / (col * r_norm));
            }
        }
        if max_cos <= 1e-10 || f == 0.0 {
            break StopReason::Gradient;
        }
        for k in 0..p {
            scale[k] = scale[k].max(a[(k, k)]).max(1e-300);
        }
        // Inner loop: raise the damping until a step reduces the objective.
        let mut accepted = None;
        while lambda < 1e20 {
            let mut damped = a.clone();
            for k in 0..p {
                damped[(k, k)] += lambda * scale[k];
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= nu_factor;
                nu_factor *= 2.0;
                continue;
            };
            let delta = chol.solve(&(-&g));
            let mut trial = &theta + &delta;
            clamp(&mut trial);
            let step = &trial - &theta;
            let predicted = -(2.0 * step.dot(&g) + (&a * &step).dot(&step));
            let r_trial = residuals(s, input, &taus, trial.as_slice(), None);
            let f_trial = r_trial.norm_squared();
            let actual = f - f_trial;
            let rho = if predicted > 0.0 {
                actual / predicted
            } else {
                -1.0
            };
            if rho > 1e-4 && f_trial.is_finite() {
                lambda *= (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
                nu_factor = 2.0;
                accepted = Some((trial, step, actual, predicted, f_trial));
                break;
            }
            lambda *= nu_factor;
            nu_factor *= 2.0;
        }
        let Some((trial, step, actual, predicted, f_trial)) = accepted else {
            break StopReason::NoProgress;
        };
        let step_small = step.norm() <= 1e-10 * (theta.norm() + 1e-10);
        theta = trial;
        f = f_trial;
        r = residuals(s, input, &taus, theta.as_slice(), Some(&mut jac));
        if step_small {
            break StopReason::Step;
        }
        if actual <= 1e-14 * f.max(1e-300) && predicted <= 1e-14 * f.max(1e-300) {
            break StopReason::Objective;
        }
    };
    LmOutcome {
        theta: theta.as_slice().to_vec(),
        objective: f,
        iterations,
        reason,
    }
}

/// Puts the GM processes of `theta` in order of increasing beta (identifiability: the
/// labels GM1, GM2, ... are otherwise arbitrary).
pub fn order_gm(s: &Structure, theta: &mut [f64]) {
    let mut starts = Vec::new();
    let mut k = 0;
    for &kind in &s.kinds {
        if kind == ProcessKind::GaussMarkov {
            starts.push(k);
        }
        k += kind.n_params();
    }
    let mut pairs: Vec<(f64, f64)> = starts.iter().map(|&i| (theta[i], theta[i + 1])).collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (&i, &(lb, ls)) in starts.iter().zip(&pairs) {
        theta[i] = lb;
        theta[i + 1] = ls;
    }
}

/// Identifiability warnings for a fitted model.
fn collapse_warnings(s: &Structure, theta: &[f64], input: &FitInput) -> Vec<String> {
    let taus = input.taus();
    let tau_max = taus.iter().cloned().fold(1.0, f64::max);
    let dt = input.dt_s;
    let mut warnings = Vec::new();
    let mut k = 0;
    let mut gm_index = 0;
    let mut gm_betas = Vec::new();
    let mut total = vec![0.0; taus.len()];
    s.wv(theta, dt, &taus, &mut total, None);
    for &kind in &s.kinds {
        let label = if kind == ProcessKind::GaussMarkov {
            gm_index += 1;
            format!("GM{gm_index}")
        } else {
            kind.token().to_string()
        };
        // Share of this process in the model WV.
        let single = Structure { kinds: vec![kind] };
        let mut part = vec![0.0; taus.len()];
        single.wv(&theta[k..k + kind.n_params()], dt, &taus, &mut part, None);
        let share = part
            .iter()
            .zip(&total)
            .map(|(a, b)| a / b)
            .fold(0.0f64, f64::max);
        if share < 0.01 {
            warnings.push(format!(
                "{label} is negligible: under 1% of the model wavelet variance at every scale (largest share {share:.2e}); a smaller model describes the data as well"
            ));
        }
        if kind == ProcessKind::GaussMarkov {
            let beta = theta[k].exp();
            gm_betas.push((label.clone(), beta));
            if beta * dt > 2.0 {
                warnings.push(format!(
                    "{label} collapsed into white noise: beta = {beta:.4e} 1/s, correlation time under half a sample"
                ));
            } else if beta * tau_max * dt < 0.1 {
                warnings.push(format!(
                    "{label} collapsed into a random walk: beta = {beta:.4e} 1/s, correlation time over 10 times the longest scale ({:.4e} s); only beta * sigma2 is identified",
                    tau_max * dt
                ));
            }
        }
        k += kind.n_params();
    }
    for w in gm_betas.windows(2) {
        if w[1].1 < 2.0 * w[0].1 {
            warnings.push(format!(
                "{} and {} merge: beta {:.4e} and {:.4e} 1/s differ by less than a factor 2",
                w[0].0, w[1].0, w[0].1, w[1].1
            ));
        }
    }
    warnings
}

/// Fits structure `s` to `input`: NNLS-grid starts, LM polish of the best few, GM ordering
/// and identifiability checks.
pub fn fit_structure(s: &Structure, input: &FitInput, opts: &FitOptions) -> Result<Fit, FitError> {
    if s.n_params() >= input.levels.len() {
        return Err(FitError::TooFewLevels {
            model: s.name(),
            params: s.n_params(),
            levels: input.levels.len(),
        });
    }
    let (lo, hi) = bounds(s, input);
    let starts = starting_values(s, input, opts.polished_starts);
    let mut outcomes: Vec<LmOutcome> = starts
        .iter()
        .map(|t0| levenberg_marquardt(s, input, t0, &lo, &hi, opts.max_iterations))
        .collect();
    outcomes.sort_by(|a, b| a.objective.total_cmp(&b.objective));
    let start_objectives = outcomes.iter().map(|o| o.objective).collect();
    let best = outcomes.swap_remove(0);
    Ok(finish(s, input, best, start_objectives))
}

/// Refits from a given start only (LM, no grid): the parametric bootstrap's refit.
pub fn refit_from(s: &Structure, input: &FitInput, theta0: &[f64], opts: &FitOptions) -> Fit {
    let (lo, hi) = bounds(s, input);
    let out = levenberg_marquardt(s, input, theta0, &lo, &hi, opts.max_iterations);
    let obj = out.objective;
    finish(s, input, out, vec![obj])
}

fn finish(s: &Structure, input: &FitInput, out: LmOutcome, start_objectives: Vec<f64>) -> Fit {
    let mut theta = out.theta;
    order_gm(s, &mut theta);
    let mut model_wv = vec![0.0; input.levels.len()];
    s.wv(&theta, input.dt_s, &input.taus(), &mut model_wv, None);
    let warnings = collapse_warnings(s, &theta, input);
    Fit {
        structure: s.clone(),
        theta,
        objective: out.objective,
        iterations: out.iterations,
        reason: out.reason,
        model_wv,
        warnings,
        start_objectives,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A WV input whose values are exactly the model's (an exact-fit problem).
    fn exact_input(model: &ModelSpec, levels: &[u32], n: usize) -> FitInput {
        let nu = model.wv_at_levels(levels);
        let n_coefficients: Vec<usize> = levels.iter().map(|&j| n + 1 - (1 << j)).collect();
        let omega = nu
            .iter()
            .zip(levels)
            .zip(&n_coefficients)
            .map(|((v, &j), &m)| crate::wv::eta3(m, j) / (2.0 * v * v))
            .collect();
        FitInput {
            levels: levels.to_vec(),
            variance: nu,
            omega,
            n_coefficients,
            dt_s: model.dt_s(),
            n,
        }
    }

    #[test]
    fn nnls_recovers_nonnegative_solution() {
        let cols = vec![
            vec![1.0, 0.0, 1.0],
            vec![0.0, 1.0, 1.0],
            vec![1.0, 1.0, 0.0],
        ];
        let b = vec![2.0, 3.0, 5.0]; // = 2 col0 + 3 col1
        let (x, rss) = nnls(&cols, &b);
        assert!(rss < 1e-20, "{rss}");
        assert!((x[0] - 2.0).abs() < 1e-10 && (x[1] - 3.0).abs() < 1e-10 && x[2].abs() < 1e-10);
        let (x, _) = nnls(&[vec![1.0, 1.0]], &[-1.0, -2.0]);
        assert_eq!(x, vec![0.0]);
    }

    #[test]
    fn recovers_table_i_dynamic_model_from_its_exact_wv() {
        let truth = ModelSpec::from_json(
            r#"{"model":"WN+GM+GM","unit":"deg/s","sample_rate_hz":100,"processes":[
              {"kind":"white_noise","sigma2":0.65382},
              {"kind":"gauss_markov","beta_per_s":0.00155,"sigma2":0.00981},
              {"kind":"gauss_markov","beta_per_s":1.68012,"sigma2":0.00168}]}"#,
        )
        .unwrap();
        let levels: Vec<u32> = (1..=18).collect();
        let input = exact_input(&truth, &levels, 1 << 19);
        let fit = fit_structure(&truth.structure(), &input, &FitOptions::default()).unwrap();
        assert!(fit.converged(), "{:?}", fit.reason);
        assert!(fit.objective < 1e-12, "objective {}", fit.objective);
        for (a, b) in fit.theta.iter().zip(truth.theta()) {
            assert!(
                (a - b).abs() < 1e-5,
                "{:?} vs {:?}",
                fit.theta,
                truth.theta()
            );
        }
        assert!(fit.warnings.is_empty(), "{:?}", fit.warnings);
    }

    #[test]
    fn recovers_every_process_kind_from_exact_wv() {
        let truth = ModelSpec::from_json(
            r#"{"model":"WN+QN+RW+DR+GM","unit":"rad/s","sample_rate_hz":200,"processes":[
              {"kind":"white_noise","sigma2":1e-4},
              {"kind":"quantization_noise","q2":2e-4},
              {"kind":"random_walk","sigma2":1e-12},
              {"kind":"drift","slope_per_s":1e-7},
              {"kind":"gauss_markov","beta_per_s":0.5,"sigma2":1e-7}]}"#,
        )
        .unwrap();
        let levels: Vec<u32> = (1..=22).collect();
        let input = exact_input(&truth, &levels, 1 << 23);
        let fit = fit_structure(&truth.structure(), &input, &FitOptions::default()).unwrap();
        assert!(fit.converged());
        assert!(fit.objective < 1e-10, "objective {}", fit.objective);
        for (a, b) in fit.theta.iter().zip(truth.theta()) {
            assert!(
                (a - b).abs() < 1e-4,
                "{:?} vs {:?}",
                fit.theta,
                truth.theta()
            );
        }
    }

    #[test]
    fn flags_a_superfluous_gm() {
        let truth = ModelSpec::from_json(
            r#"{"model":"WN+GM","unit":"u","sample_rate_hz":100,"processes":[
              {"kind":"white_noise","sigma2":1.0},
              {"kind":"gauss_markov","beta_per_s":1.0,"sigma2":0.01}]}"#,
        )
        .unwrap();
        let levels: Vec<u32> = (1..=16).collect();
        let input = exact_input(&truth, &levels, 1 << 17);
        let s = Structure::parse("WN+GM+GM").unwrap();
        let fit = fit_structure(&s, &input, &FitOptions::default()).unwrap();
        assert!(fit.objective < 1e-8, "{}", fit.objective);
        assert!(
            !fit.warnings.is_empty(),
            "a second GM on a one-GM truth must be flagged"
        );
    }

    #[test]
    fn too_few_levels_is_an_error() {
        let truth = ModelSpec::from_json(
            r#"{"model":"WN","unit":"u","sample_rate_hz":1,"processes":[{"kind":"white_noise","sigma2":1.0}]}"#,
        )
        .unwrap();
        let input = exact_input(&truth, &[1, 2, 3], 100);
        let s = Structure::parse("WN+GM+GM").unwrap();
        assert!(matches!(
            fit_structure(&s, &input, &FitOptions::default()),
            Err(FitError::TooFewLevels {
                params: 5,
                levels: 3,
                ..
            })
        ));
    }
}
