//! Which of a channel's found effects generalise: cross-validation over [`FOLDS`]
//! contiguous blocks of the run in time. Each candidate extended model is fitted on the
//! other blocks (its deterministic coefficients, and the refitted noise model) and scored on
//! the held-out block by the WV misfit against its simulations there; the score is the mean
//! over the blocks. Blocks rather than halves: an event such as a bias step at 30-70% of the
//! run has data on both sides of it in every training set, so its size can be fitted there. Effects enter the extended model one at a time, in the order they were found, and
//! only if they lower that score by at least [`MIN_RELATIVE_IMPROVEMENT`]; the others are
//! listed with both scores. An effect is thus kept for what it predicts on data it was not
//! fitted on, not for what it explains in-sample.
//!
//! Fitted per training set: the deterministic coefficients (ordinary least squares of its
//! error on the kept terms' regressors) and a refitted noise model (the baseline's structure
//! refitted on its residual, the blocks joined). Taken from the whole run: the stochastic effects'
//! parameters (noise growth, vibration lines, outliers), each already tested significant.
//! The sensor-wide terms (time offset, lever arm) belong to the calibration and are not
//! selected here.

use super::engine::{DiagnoseError, NotKept, Run};
use super::gain::{misfit_over, variance_explained_over, ChannelModelSims};
use super::stochastic::StochasticFindings;
use super::terms::{Coefficient, FittedTerms};
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, ModelChoice};
use crate::gmwm::model::ModelSpec;
use crate::model::{Cause, ChannelModel};
use crate::regress::{backward_elimination, RegressionOptions};
use crate::wv::{haar_wv, WvOptions};

/// Smallest relative decrease of the cross-validated misfit that lets an effect in: below
/// it, the difference is within what the simulations' own noise moves the score.
pub const MIN_RELATIVE_IMPROVEMENT: f64 = 0.01;

/// Blocks of the cross-validation.
pub const FOLDS: usize = 4;

/// A part of a channel's extended model that must earn its place held out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Component {
    /// The channel's deterministic terms of one cause.
    Terms(Cause),
    DynamicNoise,
    Vibration,
    Outliers,
    /// The stochastic model refitted on the residual (named as the cause it carries).
    NoiseModel(Cause),
}

impl Component {
    pub fn cause(self) -> Cause {
        match self {
            Component::Terms(c) | Component::NoiseModel(c) => c,
            Component::DynamicNoise => Cause::NoiseScalesWithDynamics,
            Component::Vibration => Cause::Vibration,
            Component::Outliers => Cause::Outliers,
        }
    }
}

/// What the selection decided on one channel.
pub(super) struct Selection {
    pub kept: Vec<Component>,
    pub not_kept: Vec<NotKept>,
    /// Cross-validated misfit of the baseline and of the kept model.
    pub held_out_baseline: f64,
    pub held_out_extended: f64,
    /// Share of the held-out error variance the kept terms (fitted on the other blocks)
    /// explain, mean over the blocks.
    pub held_out_variance_explained: f64,
}

/// The candidate components of a channel, in the order they were found.
pub(super) fn components(terms: &FittedTerms, found: &StochasticFindings) -> Vec<Component> {
    let mut out: Vec<Component> = Vec::new();
    for t in &terms.terms {
        if !out.contains(&Component::Terms(t.cause)) {
            out.push(Component::Terms(t.cause));
        }
    }
    if found.effects.dynamic_noise.is_some() {
        out.push(Component::DynamicNoise);
    }
    if !found.effects.vibration_lines.is_empty() {
        out.push(Component::Vibration);
    }
    if found.effects.outliers.is_some() {
        out.push(Component::Outliers);
    }
    if let Some(f) = found.findings.iter().find(|f| {
        matches!(
            f.cause,
            Cause::CorrelatedNoiseChange | Cause::WhiteNoiseChange
        )
    }) {
        out.push(Component::NoiseModel(f.cause));
    }
    out
}

/// The effects of `found` that `kept` includes.
pub(super) fn kept_effects(found: &StochasticFindings, kept: &[Component]) -> ChannelModel {
    let has = |c: Component| kept.contains(&c);
    ChannelModel {
        dynamic_noise: found
            .effects
            .dynamic_noise
            .filter(|_| has(Component::DynamicNoise)),
        vibration_lines: if has(Component::Vibration) {
            found.effects.vibration_lines.clone()
        } else {
            Vec::new()
        },
        outliers: found.effects.outliers.filter(|_| has(Component::Outliers)),
        ..Default::default()
    }
}

/// Whether `kept` includes the refitted noise model.
pub(super) fn keeps_noise_model(kept: &[Component]) -> bool {
    kept.iter().any(|c| matches!(c, Component::NoiseModel(_)))
}

/// The coefficients of `terms` with only the causes in `kept`, the others zero.
pub(super) fn kept_coefficients(terms: &FittedTerms, kept: &[Component]) -> Vec<Coefficient> {
    terms
        .coefficients
        .iter()
        .zip(&terms.terms)
        .map(|(c, t)| {
            if kept.contains(&Component::Terms(t.cause)) {
                *c
            } else {
                Coefficient::ZERO
            }
        })
        .collect()
}

/// `x` over the epochs of `ranges`, joined.
fn gather(x: &[f64], ranges: &[std::ops::Range<usize>]) -> Vec<f64> {
    ranges
        .iter()
        .flat_map(|r| x[r.clone()].iter().copied())
        .collect()
}

/// The kept terms' coefficients refitted on `e` over the epochs of `train` alone (ordinary
/// least squares with an intercept); intervals and shares stay those of the whole run.
fn coefficients_on(
    terms: &FittedTerms,
    kept: &[Component],
    e: &[f64],
    train: &[std::ops::Range<usize>],
) -> Vec<Coefficient> {
    let all = kept_coefficients(terms, kept);
    let columns: Vec<(&str, Vec<f64>)> = terms
        .terms
        .iter()
        .zip(terms.own())
        .filter(|(t, _)| kept.contains(&Component::Terms(t.cause)))
        .map(|(t, own)| (t.name.as_str(), gather(own, train)))
        .collect();
    if columns.is_empty() {
        return all;
    }
    let regressors: Vec<(&str, &[f64])> = columns.iter().map(|(n, v)| (*n, &v[..])).collect();
    let opts = RegressionOptions {
        alpha: 1.0,
        ..Default::default()
    };
    match backward_elimination(&gather(e, train), &regressors, &opts) {
        Ok(rep) => all
            .iter()
            .zip(&terms.terms)
            .map(|(c, t)| match rep.coefficient(&t.name) {
                Some(x) if kept.contains(&Component::Terms(t.cause)) => Coefficient {
                    value: x.estimate,
                    ..*c
                },
                _ => *c,
            })
            .collect(),
        Err(_) => all,
    }
}

/// The baseline's structure refitted on `residual`: the noise model of a training set.
fn noise_model_on(spec: &ModelSpec, residual: &[f64], dt_s: f64) -> Option<ModelSpec> {
    let wv = haar_wv(residual, dt_s, &WvOptions::default()).ok()?;
    let input = FitInput::from_wv(&wv).ok()?;
    let fit = analyze(
        "residual",
        &spec.unit,
        &input,
        &ModelChoice::Fixed(spec.structure()),
        None,
        &FitOptions::default(),
    )
    .ok()?;
    Some(fit.model_object)
}

/// One channel's data and what was found on it: what every candidate model is scored on.
struct Scoring<'a> {
    run: &'a Run<'a>,
    slot: usize,
    spec: &'a ModelSpec,
    e: &'a [f64],
    terms: &'a FittedTerms<'a>,
    found: &'a StochasticFindings,
}

impl Scoring<'_> {
    /// The cross-validated misfit of the model with `kept` (mean over the blocks), and the
    /// held-out share of variance its terms explain.
    fn cross_validated(&self, kept: &[Component]) -> Result<(f64, f64), DiagnoseError> {
        let Scoring {
            run,
            slot,
            spec,
            e,
            terms,
            found,
        } = *self;
        let n = run.n;
        let edge = |k: usize| k * n / FOLDS;
        let effects = kept_effects(found, kept);
        let (mut misfit, mut explained) = (0.0, 0.0);
        for k in 0..FOLDS {
            let test = edge(k)..edge(k + 1);
            let train = [0..edge(k), edge(k + 1)..n];
            let coefficients = coefficients_on(terms, kept, e, &train);
            let noise = keeps_noise_model(kept).then(|| {
                let d: Vec<f64> = train
                    .iter()
                    .flat_map(|r| terms.deterministic(&coefficients, r.clone()))
                    .collect();
                let residual: Vec<f64> = gather(e, &train)
                    .iter()
                    .zip(&d)
                    .map(|(a, b)| a - b)
                    .collect();
                noise_model_on(spec, &residual, run.dt_s)
                    .unwrap_or_else(|| found.stochastic.clone())
            });
            let model = ChannelModelSims {
                coefficients: &coefficients,
                stochastic: noise.as_ref(),
                effects: &effects,
                intercept: 0.0,
            };
            let salt = 23 + k as u64;
            misfit += misfit_over(run, slot, terms, e, &model, test.clone(), salt)?;
            explained += variance_explained_over(terms, &coefficients, e, test);
        }
        Ok((misfit / FOLDS as f64, explained / FOLDS as f64))
    }
}

/// Forward selection of the channel's found effects by their cross-validated misfit.
pub(super) fn select(
    run: &Run,
    slot: usize,
    spec: &ModelSpec,
    e: &[f64],
    terms: &FittedTerms,
    found: &StochasticFindings,
) -> Result<Selection, DiagnoseError> {
    let scoring = Scoring {
        run,
        slot,
        spec,
        e,
        terms,
        found,
    };
    let score = |kept: &[Component]| scoring.cross_validated(kept);
    let (held_out_baseline, _) = score(&[])?;
    let mut kept: Vec<Component> = Vec::new();
    let (mut current, mut explained) = (held_out_baseline, 0.0);
    let mut not_kept = Vec::new();
    for component in components(terms, found) {
        let mut trial = kept.clone();
        trial.push(component);
        let (with, trial_explained) = score(&trial)?;
        if with < current * (1.0 - MIN_RELATIVE_IMPROVEMENT) {
            kept = trial;
            current = with;
            explained = trial_explained;
        } else {
            not_kept.push(NotKept {
                cause: component.cause(),
                held_out_without: current,
                held_out_with: with,
            });
        }
    }
    Ok(Selection {
        kept,
        not_kept,
        held_out_baseline,
        held_out_extended: current,
        held_out_variance_explained: explained,
    })
}
