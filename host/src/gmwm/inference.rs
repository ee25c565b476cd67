//! What a fit means: parameter intervals (delta method on the transformed scale, or a
//! seeded parametric bootstrap), the J-test of goodness of fit, the WIC model-selection
//! criterion, and the per-channel result written by `dynacal fit`.
//!
//! With D = d nu / d theta at theta_hat, Omega the weights and V the covariance of nu_hat
//! implied by the fitted model ([`super::covariance`]):
//! - B = (D' Omega D)^-1 D' Omega, cov(theta_hat) = B V B' (sandwich: Omega is not V^-1);
//!   95% interval theta +- 1.96 se, mapped to physical units through exp (so never negative);
//! - J-test: the residual is e ~ (I - D B) eps, T = e' Omega e ~ sum_k lambda_k chi2_1 with
//!   lambda the eigenvalues of Omega^1/2 P V P' Omega^1/2, P = I - D B; p-value from the
//!   Satterthwaite match T ~ c chi2_nu (c = sum l^2 / sum l, nu = (sum l)^2 / sum l^2);
//! - WIC (Guerrier's wavelet information criterion): objective + 2 tr(Omega D B V_full), the
//!   optimism of the in-sample objective, with one V_full (from the largest candidate model)
//!   shared by all candidates so their criteria are comparable.

use nalgebra::{DMatrix, SymmetricEigen};
use rand::SeedableRng;
use rayon::prelude::*;
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::covariance::wv_covariance;
use super::fit::{fit_structure, refit_from, Fit, FitError, FitInput, FitOptions};
use super::model::{ModelSimulation, ModelSpec, ProcessKind, Structure};
use crate::wv::{haar_wv, haar_wv_of_blocks, WvOptions, GATHERED_SAMPLES};

/// z_0.975.
pub const Z95: f64 = 1.959_963_984_540_054;

/// D (J x p) at theta.
fn jacobian(s: &Structure, theta: &[f64], input: &FitInput) -> DMatrix<f64> {
    let taus = input.taus();
    let (m, p) = (taus.len(), s.n_params());
    let mut nu = vec![0.0; m];
    let mut flat = vec![0.0; m * p];
    s.wv(theta, input.dt_s, &taus, &mut nu, Some(&mut flat));
    DMatrix::from_row_slice(m, p, &flat)
}

/// B = (D' Omega D)^-1 D' Omega, or None when D' Omega D is singular (a collapsed model).
fn influence(d: &DMatrix<f64>, omega: &[f64]) -> Option<DMatrix<f64>> {
    let w = DMatrix::from_diagonal(&nalgebra::DVector::from_column_slice(omega));
    let dtw = d.transpose() * &w;
    let info = &dtw * d;
    // Scale to unit diagonal before inverting: the transformed parameters differ widely in
    // how strongly they move nu.
    let scale: Vec<f64> = (0..info.nrows()).map(|k| info[(k, k)].sqrt()).collect();
    if scale.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return None;
    }
    let scaled = DMatrix::from_fn(info.nrows(), info.ncols(), |a, b| {
        info[(a, b)] / (scale[a] * scale[b])
    });
    let inv = scaled.cholesky()?.inverse();
    if inv.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let inv = DMatrix::from_fn(inv.nrows(), inv.ncols(), |a, b| {
        inv[(a, b)] / (scale[a] * scale[b])
    });
    Some(inv * dtw)
}

/// Delta-method covariance of theta_hat (sandwich), None if not identifiable.
pub fn theta_covariance(fit: &Fit, input: &FitInput, v: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let d = jacobian(&fit.structure, &fit.theta, input);
    let b = influence(&d, &input.omega)?;
    Some(&b * v * b.transpose())
}

/// J-test result.
#[derive(Debug, Clone, Serialize)]
pub struct JTest {
    /// T = the objective.
    pub statistic: f64,
    /// Satterthwaite scale c and degrees of freedom nu of T ~ c chi2_nu.
    pub scale: f64,
    pub dof: f64,
    pub p_value: f64,
}

/// The J-test of the fitted model (see the module doc); None if the model is not
/// identifiable at the fit.
pub fn j_test(fit: &Fit, input: &FitInput, v: &DMatrix<f64>) -> Option<JTest> {
    let d = jacobian(&fit.structure, &fit.theta, input);
    let b = influence(&d, &input.omega)?;
    let m = input.levels.len();
    let p = DMatrix::<f64>::identity(m, m) - &d * &b;
    let sw = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
        m,
        input.omega.iter().map(|w| w.sqrt()),
    ));
    let cov = &sw * &p * v * p.transpose() * &sw;
    let sym = (&cov + cov.transpose()) * 0.5;
    let eig = SymmetricEigen::new(sym).eigenvalues;
    let (s1, s2) = eig
        .iter()
        .filter(|l| **l > 0.0)
        .fold((0.0, 0.0), |(a, b), l| (a + l, b + l * l));
    if !(s1 > 0.0 && s2 > 0.0) {
        return None;
    }
    let scale = s2 / s1;
    let dof = s1 * s1 / s2;
    let p_value = ChiSquared::new(dof)
        .map(|c| 1.0 - c.cdf(fit.objective / scale))
        .unwrap_or(f64::NAN);
    Some(JTest {
        statistic: fit.objective,
        scale,
        dof,
        p_value,
    })
}

/// The WIC optimism 2 tr(Omega D B V_full), or None if not identifiable.
pub fn optimism(fit: &Fit, input: &FitInput, v_full: &DMatrix<f64>) -> Option<f64> {
    let d = jacobian(&fit.structure, &fit.theta, input);
    let b = influence(&d, &input.omega)?;
    let h = &d * &b;
    let mut tr = 0.0;
    for j in 0..input.levels.len() {
        tr += input.omega[j] * (h.row(j) * v_full.column(j))[(0, 0)];
    }
    Some(2.0 * tr)
}

/// One reported parameter, physical units.
#[derive(Debug, Clone, Serialize)]
pub struct Parameter {
    /// Process label: WN, QN, RW, DR, GM1, GM2, ...
    pub process: String,
    pub name: String,
    pub unit: String,
    pub value: f64,
    /// 95% interval (bootstrap percentile when a bootstrap ran, else delta method); null
    /// when the model is not identifiable at the fit.
    pub ci95: Option<[f64; 2]>,
    /// The delta-method 95% interval, always reported when available.
    pub ci95_delta: Option<[f64; 2]>,
    /// Index of the transformed parameter this is a monotone function of.
    pub theta_index: usize,
    /// Standard error of that transformed parameter (delta method).
    pub theta_se: Option<f64>,
}

/// A reported parameter: (process label, parameter name, unit, index of its transformed
/// parameter, physical value as a function of that transformed parameter).
type ParameterMap = (
    String,
    String,
    String,
    usize,
    Box<dyn Fn(f64) -> f64 + Send + Sync>,
);

/// Physical value of each reported parameter as a function of its transformed parameter.
fn parameter_map(s: &Structure, unit: &str, dt: f64) -> Vec<ParameterMap> {
    let mut out: Vec<ParameterMap> = Vec::new();
    let u2 = format!("({unit})^2");
    let mut k = 0;
    let mut gm = 0;
    for &kind in &s.kinds {
        match kind {
            ProcessKind::WhiteNoise => {
                out.push((
                    "WN".into(),
                    "sigma2".into(),
                    u2.clone(),
                    k,
                    Box::new(f64::exp),
                ));
                out.push((
                    "WN".into(),
                    "noise_density".into(),
                    format!("{unit}/sqrt(Hz)"),
                    k,
                    Box::new(move |t: f64| (t.exp() * dt).sqrt()),
                ));
            }
            ProcessKind::QuantizationNoise => {
                out.push(("QN".into(), "q2".into(), u2.clone(), k, Box::new(f64::exp)));
            }
            ProcessKind::RandomWalk => {
                out.push((
                    "RW".into(),
                    "sigma2".into(),
                    u2.clone(),
                    k,
                    Box::new(f64::exp),
                ));
                out.push((
                    "RW".into(),
                    "bias_random_walk".into(),
                    format!("{unit}/s/sqrt(Hz)"),
                    k,
                    Box::new(move |t: f64| (t.exp() / dt).sqrt()),
                ));
            }
            ProcessKind::Drift => {
                out.push((
                    "DR".into(),
                    "slope_per_s".into(),
                    format!("{unit}/s"),
                    k,
                    Box::new(move |t: f64| (0.5 * t).exp() / dt),
                ));
            }
            ProcessKind::GaussMarkov => {
                gm += 1;
                let label = format!("GM{gm}");
                out.push((
                    label.clone(),
                    "beta_per_s".into(),
                    "1/s".into(),
                    k,
                    Box::new(f64::exp),
                ));
                out.push((
                    label.clone(),
                    "correlation_time_s".into(),
                    "s".into(),
                    k,
                    Box::new(|t: f64| (-t).exp()),
                ));
                out.push((
                    label,
                    "sigma2".into(),
                    u2.clone(),
                    k + 1,
                    Box::new(f64::exp),
                ));
            }
        }
        k += kind.n_params();
    }
    out
}

fn sorted_interval(a: f64, b: f64) -> [f64; 2] {
    if a <= b {
        [a, b]
    } else {
        [b, a]
    }
}

/// The reported parameters of a model, without intervals: (process, name, value), in the
/// order and the units [`parameters`] reports them.
pub fn parameter_values(model: &ModelSpec) -> Vec<(String, String, f64)> {
    let theta = model.theta();
    parameter_map(&model.structure(), &model.unit, model.dt_s())
        .into_iter()
        .map(|(process, name, _, k, f)| (process, name, f(theta[k])))
        .collect()
}

/// The reported parameters with their intervals. `bootstrap_theta` (replicates of theta)
/// gives percentile intervals on the transformed scale when present.
pub fn parameters(
    fit: &Fit,
    unit: &str,
    dt: f64,
    cov: Option<&DMatrix<f64>>,
    bootstrap_theta: Option<&[Vec<f64>]>,
) -> Vec<Parameter> {
    parameter_map(&fit.structure, unit, dt)
        .into_iter()
        .map(|(process, name, unit, k, f)| {
            let t = fit.theta[k];
            let se = cov
                .map(|c| c[(k, k)].max(0.0).sqrt())
                .filter(|s| s.is_finite());
            let ci_delta = se.map(|s| sorted_interval(f(t - Z95 * s), f(t + Z95 * s)));
            let ci_boot = bootstrap_theta.filter(|b| b.len() >= 10).map(|b| {
                let mut v: Vec<f64> = b.iter().map(|th| th[k]).collect();
                v.sort_by(f64::total_cmp);
                let q = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
                sorted_interval(f(q(0.025)), f(q(0.975)))
            });
            Parameter {
                process,
                name,
                unit,
                value: f(t),
                ci95: ci_boot.or(ci_delta),
                ci95_delta: ci_delta,
                theta_index: k,
                theta_se: se,
            }
        })
        .collect()
}

/// `fit`'s 95% intervals from `replicates` of its transformed parameters drawn by a
/// caller's own parametric bootstrap (one that simulates more than the one series
/// [`bootstrap`] does, as the refit's N-cornered hat does): bias-corrected percentiles
/// (Efron's BC: the quantiles at Phi(2 z0 -+ 1.96), z0 = Phi^-1 of the share of replicates
/// below the estimate), which take out the estimator's median bias where plain percentiles
/// would carry it twice (a Gauss-Markov `beta` fitted high on a short record), and stay
/// inside the replicates' range where basic intervals, on a skewed bootstrap distribution,
/// leave it. Fewer than 10 replicates leave the intervals as they are.
pub fn set_bootstrap_intervals(fit: &mut ChannelFit, replicates: &[Vec<f64>], method: String) {
    let Ok(structure) = Structure::parse(&fit.model) else {
        return;
    };
    if replicates.len() < 10 {
        return;
    }
    let map = parameter_map(&structure, &fit.unit, 1.0 / fit.sample_rate_hz);
    for (p, (_, _, _, k, f)) in fit.parameters.iter_mut().zip(map) {
        let t = fit.theta[k];
        let mut v: Vec<f64> = replicates.iter().map(|th| th[k]).collect();
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        let normal = statrs::distribution::Normal::standard();
        let below = v.iter().filter(|x| **x < t).count() as f64 + 0.5;
        let z0 = normal.inverse_cdf((below / (v.len() as f64 + 1.0)).clamp(1e-6, 1.0 - 1e-6));
        let at = |z: f64| q(normal.cdf(2.0 * z0 + z));
        p.ci95 = Some(sorted_interval(f(at(-Z95)), f(at(Z95))));
    }
    fit.interval_method = method;
}

/// Samples a long record's simulation is drawn in at a time ([`refit_on_simulation`]).
const SIMULATED_BLOCK: usize = 1 << 16;

/// One parametric-bootstrap replicate: `n` samples simulated from `model` with `rng`, their
/// Haar WV at `levels` (all levels up to the largest when a level is missing from the
/// simulation's WV), and an LM refit of `structure` from `theta0`. None when the WV or the
/// refit fails or the refit does not converge.
fn refit_on_simulation<R: rand::Rng + ?Sized>(
    model: &ModelSpec,
    structure: &Structure,
    theta0: &[f64],
    levels: &[u32],
    n: usize,
    rng: &mut R,
    opts: &FitOptions,
) -> Option<Vec<f64>> {
    let max_level = levels.iter().copied().max().unwrap_or(1);
    let wv = if n <= GATHERED_SAMPLES {
        let x = model.simulate(n, rng);
        let opts = WvOptions {
            max_level: Some(max_level),
            ..WvOptions::default()
        };
        haar_wv(&x, model.dt_s(), &opts)
    } else {
        // A long record (a baseline fitted on a quarter of a long drive) is simulated a
        // block at a time into the streamed estimator: held, it was the largest transient
        // of a long diagnosis (8 bytes a sample on each core).
        let mut sim = ModelSimulation::new(model);
        let mut block = Vec::with_capacity(SIMULATED_BLOCK);
        haar_wv_of_blocks(n, model.dt_s(), Some(max_level), &mut |visit| {
            for start in (0..n).step_by(SIMULATED_BLOCK) {
                block.clear();
                block.resize((n - start).min(SIMULATED_BLOCK), 0.0);
                sim.add_next(&mut block, rng);
                visit(&block);
            }
        })
    }
    .ok()?;
    let sub = FitInput::from_wv(&wv).ok()?.at_levels(levels);
    refit_replicate(structure, &sub, theta0, opts)
}

/// One bootstrap replicate's refit of `structure` on `input` from `theta0`: its transformed
/// parameters, or None when the levels cannot support the model or the fit does not
/// converge.
pub fn refit_replicate(
    structure: &Structure,
    input: &FitInput,
    theta0: &[f64],
    opts: &FitOptions,
) -> Option<Vec<f64>> {
    if input.levels.len() <= structure.n_params() {
        return None;
    }
    let refit = refit_from(structure, input, theta0, opts);
    refit.converged().then_some(refit.theta)
}

/// Parametric bootstrap: `replicates` series of `input.n` samples simulated from the fitted
/// model (seeded: ChaCha8 with `seed`, stream = replicate index, so the result does not
/// depend on the thread count), their WV at the same levels, and an LM refit from theta_hat.
/// Replicates whose refit did not converge are dropped. Returns the theta replicates.
pub fn bootstrap(
    fit: &Fit,
    input: &FitInput,
    unit: &str,
    replicates: usize,
    seed: u64,
    opts: &FitOptions,
) -> Vec<Vec<f64>> {
    let model = fit.model(unit, input.dt_s);
    (0..replicates)
        .into_par_iter()
        .filter_map(|b| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(b as u64);
            refit_on_simulation(
                &model,
                &fit.structure,
                &fit.theta,
                &input.levels,
                input.n,
                &mut rng,
                opts,
            )
        })
        .collect()
}

/// A draw from the sampling distribution of a model fitted on a record of `record_samples`
/// samples: the model refitted (same structure, from its own parameters) on a record of
/// that length simulated from it, at every level with four or more averaging blocks. What a
/// fit of the same length could as well have returned; None when the refit fails.
pub fn sampling_draw<R: rand::Rng + ?Sized>(
    model: &ModelSpec,
    record_samples: usize,
    rng: &mut R,
) -> Option<ModelSpec> {
    let structure = model.structure();
    let max_level = ((record_samples as f64).log2().floor() as u32).saturating_sub(2);
    let levels: Vec<u32> = (1..=max_level).collect();
    let theta = refit_on_simulation(
        model,
        &structure,
        &model.theta(),
        &levels,
        record_samples,
        rng,
        &FitOptions::default(),
    )?;
    Some(ModelSpec::from_theta(
        &structure,
        &theta,
        &model.unit,
        model.sample_rate_hz,
    ))
}

/// One candidate of an automatic model selection.
#[derive(Debug, Clone, Serialize)]
pub struct Candidate {
    pub model: String,
    pub objective: f64,
    pub optimism: Option<f64>,
    pub wic: Option<f64>,
    pub converged: bool,
    pub warnings: Vec<String>,
}

/// The fit of one channel, as written by `dynacal fit`.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelFit {
    pub channel: String,
    pub unit: String,
    pub n: usize,
    pub sample_rate_hz: f64,
    /// Model string, e.g. "WN+GM+GM".
    pub model: String,
    /// The fitted model object (the simulator's model file format).
    pub model_object: ModelSpec,
    pub parameters: Vec<Parameter>,
    /// GMWM objective at the fit, (nu_hat - nu)' Omega (nu_hat - nu).
    pub objective: f64,
    pub levels: Vec<u32>,
    pub scales_s: Vec<f64>,
    pub wv: Vec<f64>,
    pub model_wv: Vec<f64>,
    /// Diagonal of Omega (1/unit^4): 1 / var(nu_hat_j) from the WV intervals.
    pub omega: Vec<f64>,
    pub converged: bool,
    pub iterations: usize,
    pub stop_reason: super::fit::StopReason,
    pub j_test: Option<JTest>,
    /// "delta" or "bootstrap(B=.., seed=.., used=..)".
    pub interval_method: String,
    pub warnings: Vec<String>,
    /// Ranked candidates (best first) when the model was chosen automatically.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub candidates: Option<Vec<Candidate>>,
    /// Transformed parameters and their delta-method covariance (row-major), for
    /// comparisons between fits.
    pub theta: Vec<f64>,
    pub theta_covariance: Option<Vec<f64>>,
}

/// Which model to fit.
#[derive(Debug, Clone)]
pub enum ModelChoice {
    Fixed(Structure),
    /// Choose among all combinations of WN, QN, RW, DR (each present or not) and 0..=3 GM
    /// by the WIC.
    Auto,
    /// Choose among these structures by the WIC (those the levels can support).
    Among(Vec<Structure>),
}

/// Bootstrap settings.
#[derive(Debug, Clone, Copy)]
pub struct BootstrapOptions {
    pub replicates: usize,
    pub seed: u64,
}

/// All candidate structures of the automatic selection that `levels` levels can support.
pub fn auto_candidates(levels: usize) -> Vec<Structure> {
    let mut out = Vec::new();
    for mask in 0..16u32 {
        for n_gm in 0..=3 {
            let mut kinds = Vec::new();
            for (bit, kind) in [
                ProcessKind::WhiteNoise,
                ProcessKind::QuantizationNoise,
                ProcessKind::RandomWalk,
                ProcessKind::Drift,
            ]
            .into_iter()
            .enumerate()
            {
                if mask & (1 << bit) != 0 {
                    kinds.push(kind);
                }
            }
            kinds.extend(std::iter::repeat_n(ProcessKind::GaussMarkov, n_gm));
            let s = Structure { kinds };
            if !s.kinds.is_empty() && s.n_params() + 1 < levels {
                out.push(s);
            }
        }
    }
    out
}

/// Fits one channel's WV: the given model or the WIC-best candidate, intervals (delta
/// method, or bootstrap percentile), J-test.
pub fn analyze(
    channel: &str,
    unit: &str,
    input: &FitInput,
    choice: &ModelChoice,
    bootstrap_opts: Option<BootstrapOptions>,
    opts: &FitOptions,
) -> Result<ChannelFit, FitError> {
    let (fit, candidates) = match choice {
        ModelChoice::Fixed(s) => (fit_structure(s, input, opts)?, None),
        ModelChoice::Auto | ModelChoice::Among(_) => {
            let structures: Vec<Structure> = match choice {
                ModelChoice::Among(list) => list
                    .iter()
                    .filter(|s| s.n_params() + 1 < input.levels.len())
                    .cloned()
                    .collect(),
                _ => auto_candidates(input.levels.len()),
            };
            if structures.is_empty() {
                return Err(FitError::TooFewLevelsToChoose {
                    levels: input.levels.len(),
                    n: input.n,
                });
            }
            let fits: Vec<Fit> = structures
                .par_iter()
                .map(|s| fit_structure(s, input, opts))
                .collect::<Result<_, _>>()?;
            // V_full from the largest converged candidate.
            let full = fits
                .iter()
                .filter(|f| f.converged())
                .max_by_key(|f| f.structure.n_params())
                .unwrap_or(&fits[0]);
            let v_full = wv_covariance(
                &full.model(unit, input.dt_s),
                &input.levels,
                &input.n_coefficients,
            );
            let mut ranked: Vec<(Candidate, Fit)> = fits
                .into_par_iter()
                .map(|f| {
                    let opt = optimism(&f, input, &v_full);
                    let c = Candidate {
                        model: f.structure.name(),
                        objective: f.objective,
                        optimism: opt,
                        wic: opt.map(|o| f.objective + o),
                        converged: f.converged(),
                        warnings: f.warnings.clone(),
                    };
                    (c, f)
                })
                .collect();
            ranked.sort_by(|a, b| {
                let key = |c: &Candidate| c.wic.unwrap_or(f64::INFINITY);
                key(&a.0).total_cmp(&key(&b.0))
            });
            // Best WIC among converged candidates free of identifiability warnings; failing
            // that, the best converged one.
            let pick = ranked
                .iter()
                .position(|(c, _)| c.converged && c.wic.is_some() && c.warnings.is_empty())
                .or_else(|| {
                    ranked
                        .iter()
                        .position(|(c, _)| c.converged && c.wic.is_some())
                })
                .unwrap_or(0);
            let chosen = ranked[pick].1.clone();
            (
                chosen,
                Some(ranked.into_iter().map(|x| x.0).collect::<Vec<_>>()),
            )
        }
    };
    let model = fit.model(unit, input.dt_s);
    let v = wv_covariance(&model, &input.levels, &input.n_coefficients);
    let cov = theta_covariance(&fit, input, &v);
    let jt = j_test(&fit, input, &v);
    let (boot, method) = match bootstrap_opts {
        Some(b) if b.replicates > 0 => {
            let reps = bootstrap(&fit, input, unit, b.replicates, b.seed, opts);
            let m = format!(
                "bootstrap percentile (B={}, seed={}, converged replicates={})",
                b.replicates,
                b.seed,
                reps.len()
            );
            (Some(reps), m)
        }
        _ => (None, "delta method on the transformed scale".to_string()),
    };
    let params = parameters(&fit, unit, input.dt_s, cov.as_ref(), boot.as_deref());
    let mut warnings = fit.warnings.clone();
    if cov.is_none() {
        warnings.push(
            "D' Omega D is singular at the fit: the model is not identifiable there, no delta-method intervals".into(),
        );
    }
    Ok(ChannelFit {
        channel: channel.to_string(),
        unit: unit.to_string(),
        n: input.n,
        sample_rate_hz: 1.0 / input.dt_s,
        model: fit.structure.name(),
        model_object: model,
        parameters: params,
        objective: fit.objective,
        scales_s: input.taus().iter().map(|t| t * input.dt_s).collect(),
        levels: input.levels.clone(),
        wv: input.variance.clone(),
        model_wv: fit.model_wv.clone(),
        omega: input.omega.clone(),
        converged: fit.converged(),
        iterations: fit.iterations,
        stop_reason: fit.reason,
        j_test: jt,
        interval_method: method,
        warnings,
        candidates,
        theta: fit.theta.clone(),
        theta_covariance: cov.map(|c| c.transpose().as_slice().to_vec()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gmwm::model::Process;

    #[test]
    fn a_long_records_sampling_draw_is_streamed_and_centred_on_the_model() {
        let model = ModelSpec {
            model: "WN+RW".into(),
            unit: "rad/s".into(),
            sample_rate_hz: 1000.0,
            processes: vec![
                Process::WhiteNoise { sigma2: 1e-6 },
                Process::RandomWalk { sigma2: 1e-12 },
            ],
        };
        // Above GATHERED_SAMPLES the record is simulated a block at a time and streamed.
        let n = GATHERED_SAMPLES + 50_000;
        for seed in 0..2 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let draw = sampling_draw(&model, n, &mut rng).expect("the refit converges");
            let Process::WhiteNoise { sigma2 } = draw.processes[0] else {
                panic!("the structure is kept: {:?}", draw.processes)
            };
            // The white noise's standard error on 1e6 samples is about 0.2%.
            assert!((sigma2 / 1e-6 - 1.0).abs() < 0.02, "seed {seed}: {sigma2}");
        }
    }
}
