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

use nalgebra::{DMatrix, DVector};

use super::engine::{DiagnoseError, NotKept, Run};
use super::gain::{fit_wv, misfit_over, variance_explained_over, ChannelModelSims};
use super::stats::Series;
use super::stochastic::StochasticFindings;
use super::terms::{Coefficient, FittedTerms};
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, ModelChoice};
use crate::gmwm::model::ModelSpec;
use crate::model::{Cause, ChannelModel};
use crate::regress::{column_scale, solve_scaled};
use crate::series_bank::{BlockVisit, SeriesBank};

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

/// The kept terms' coefficients refitted on the error `e` (the one series of a bank) over
/// the epochs of `train` alone
/// ([`slopes_over`]); intervals and shares stay those of the whole run. A term constant over
/// `train` (collinear with the intercept), or too few epochs, keeps its whole-run
/// coefficient.
fn coefficients_on(
    terms: &FittedTerms,
    kept: &[Component],
    e: &SeriesBank,
    train: &[std::ops::Range<usize>],
) -> Result<Vec<Coefficient>, DiagnoseError> {
    let mut all = kept_coefficients(terms, kept);
    let chosen: Vec<usize> = (0..terms.terms.len())
        .filter(|&i| kept.contains(&Component::Terms(terms.terms[i].cause)))
        .collect();
    // Each chosen term's value at the first training epoch, and whether it moves from it.
    let mut first: Vec<Option<f64>> = vec![None; terms.terms.len()];
    let mut varies = vec![false; terms.terms.len()];
    for r in train {
        terms.for_each_own_block(r.clone(), &mut |_, own| {
            for &i in &chosen {
                let Some(&start) = own[i].first() else {
                    continue;
                };
                let at_first = *first[i].get_or_insert(start);
                varies[i] = varies[i] || own[i].iter().any(|v| *v != at_first);
            }
        })?;
    }
    let fitted: Vec<usize> = chosen.into_iter().filter(|&i| varies[i]).collect();
    let blocks = |range: std::ops::Range<usize>, visit: &mut BlockVisit<'_>| {
        terms.for_each_own_block(range, visit)
    };
    if let Some(slopes) = slopes_over(e, &fitted, train, &blocks)? {
        for (&i, value) in fitted.iter().zip(slopes) {
            if value.is_finite() {
                all[i].value = value;
            }
        }
    }
    Ok(all)
}

/// Columns read over a range of epochs a block at a time, each block's series in order.
type ColumnBlocks<'c> =
    dyn Fn(std::ops::Range<usize>, &mut BlockVisit<'_>) -> Result<(), DiagnoseError> + 'c;

/// The slopes of an ordinary least-squares fit of `y` (the one series of a bank) on an
/// intercept and the series
/// `columns` of `blocks` over the epochs `ranges`, from the column-scaled normal equations
/// as [`crate::regress::backward_elimination`] solves them, summed over the epochs rather
/// than made from a design matrix of them (memory in the columns, not the epochs). None
/// without a column, or with no more epochs than parameters plus one.
fn slopes_over(
    y: &SeriesBank,
    columns: &[usize],
    ranges: &[std::ops::Range<usize>],
    blocks: &ColumnBlocks<'_>,
) -> Result<Option<Vec<f64>>, DiagnoseError> {
    let p = 1 + columns.len();
    let n = ranges.iter().map(|r| r.len()).sum::<usize>();
    if columns.is_empty() || n <= p + 1 {
        return Ok(None);
    }
    let mut xtx = DMatrix::<f64>::zeros(p, p);
    let mut xty = DVector::<f64>::zeros(p);
    let mut row = vec![1.0; p];
    let mut failed = None;
    for range in ranges {
        blocks(range.clone(), &mut |block, series| {
            let y = match y.range(0, block) {
                Ok(y) => y,
                Err(e) => {
                    failed.get_or_insert(e);
                    return;
                }
            };
            for (t, y) in y.iter().enumerate() {
                for (slot, &c) in row[1..].iter_mut().zip(columns) {
                    *slot = series[c][t];
                }
                for a in 0..p {
                    xty[a] += row[a] * y;
                    for b in a..p {
                        xtx[(a, b)] += row[a] * row[b];
                    }
                }
            }
        })?;
    }
    if let Some(e) = failed {
        return Err(e.into());
    }
    let scale: Vec<f64> = (0..p).map(|a| column_scale(xtx[(a, a)].sqrt())).collect();
    let scaled = DMatrix::from_fn(p, p, |a, b| {
        let (lo, hi) = (a.min(b), a.max(b));
        xtx[(lo, hi)] / (scale[a] * scale[b])
    });
    let (_, beta_s) = solve_scaled(&scaled, &DVector::from_fn(p, |a, _| xty[a] / scale[a]));
    Ok(Some((1..p).map(|j| beta_s[j] / scale[j]).collect()))
}

/// The baseline's structure refitted on `residual`: the noise model of a training set.
fn noise_model_on(spec: &ModelSpec, residual: &Series, dt_s: f64) -> Option<ModelSpec> {
    let wv = fit_wv(residual, dt_s).ok()?;
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
    e: &'a SeriesBank,
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
            let coefficients = coefficients_on(terms, kept, e, &train)?;
            let noise = keeps_noise_model(kept).then(|| {
                Ok::<_, DiagnoseError>(
                    terms
                        .with_residual(&coefficients, e, &train, |residual| {
                            noise_model_on(spec, residual, run.dt_s)
                        })?
                        .unwrap_or_else(|| found.stochastic.clone()),
                )
            });
            let noise = noise.transpose()?;
            let model = ChannelModelSims {
                coefficients: &coefficients,
                stochastic: noise.as_ref(),
                effects: &effects,
                intercept: 0.0,
            };
            let salt = 23 + k as u64;
            misfit += misfit_over(run, slot, terms, e, &model, test.clone(), salt)?;
            explained += variance_explained_over(terms, &coefficients, e, test)?;
        }
        Ok((misfit / FOLDS as f64, explained / FOLDS as f64))
    }
}

/// Forward selection of the channel's found effects by their cross-validated misfit.
pub(super) fn select(
    run: &Run,
    slot: usize,
    spec: &ModelSpec,
    e: &SeriesBank,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::regress::{backward_elimination, RegressionOptions};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn slopes_summed_over_the_epochs_are_the_regression_of_the_epochs_gathered() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let n = 5_000;
        let columns: Vec<Vec<f64>> = (0..3)
            .map(|k| {
                (0..n)
                    .map(|t| (t as f64 * 0.01 * (k + 1) as f64).sin() + rng.random::<f64>())
                    .collect()
            })
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|t| 0.3 + 2.0 * columns[0][t] - 0.5 * columns[2][t] + rng.random::<f64>() - 0.5)
            .collect();
        let ranges = [0..1_200, 2_500..n];
        let gather =
            |x: &[f64]| -> Vec<f64> { ranges.iter().flat_map(|r| x[r.clone()].to_vec()).collect() };
        let blocks = |range: std::ops::Range<usize>, visit: &mut BlockVisit<'_>| {
            // Blocks of 333 epochs, as a spilled bank reads them.
            for start in range.clone().step_by(333) {
                let block = start..(start + 333).min(range.end);
                let views: Vec<&[f64]> = columns.iter().map(|c| &c[block.clone()]).collect();
                visit(block, &views);
            }
            Ok(())
        };
        let mut y_bank = SeriesBank::new(n, false).unwrap();
        y_bank.push(y.clone()).unwrap();
        let slopes = slopes_over(&y_bank, &[0, 1, 2], &ranges, &blocks)
            .unwrap()
            .unwrap();
        let gathered: Vec<Vec<f64>> = columns.iter().map(|c| gather(c)).collect();
        let names = ["a", "b", "c"];
        let regressors: Vec<(&str, &[f64])> = names
            .iter()
            .zip(&gathered)
            .map(|(n, c)| (*n, &c[..]))
            .collect();
        let opts = RegressionOptions {
            alpha: 1.0,
            ..Default::default()
        };
        let report = backward_elimination(&gather(&y), &regressors, &opts).unwrap();
        for (name, slope) in names.iter().zip(&slopes) {
            let want = report.coefficient(name).unwrap().estimate;
            assert!(
                (slope - want).abs() <= 1e-10 * want.abs().max(1.0),
                "{name}: {slope} {want}"
            );
        }
        assert!((slopes[0] - 2.0).abs() < 0.05 && (slopes[2] + 0.5).abs() < 0.05);
        assert_eq!(slopes_over(&y_bank, &[], &ranges, &blocks).unwrap(), None);
        let four = [0..2, 2..4];
        assert_eq!(
            slopes_over(&y_bank, &[0, 1, 2], &four, &blocks).unwrap(),
            None
        );
    }
}
