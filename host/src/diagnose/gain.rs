//! The gain of the extended model over the baseline: the wavelet-variance misfit of the
//! measured error against simulations of each model along the measured dynamics (the
//! baseline drawn as the tests' null draws it), with the share of the error variance the
//! deterministic terms explain, and the wavelet-variance curves the report plots. Which
//! found effects enter the extended model, and their held-out figures, are
//! [`super::generalise`]'s.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::draws::ChannelSimulation;
use super::engine::{DiagnoseError, Gain, Run, WvCurves, Z_FLOOR};
use super::generalise::Selection;
use super::stats::{series_variance, with_bank_series, with_bank_series_in, Series};
use super::terms::{Coefficient, FittedTerms};
use crate::gmwm::model::ModelSpec;
use crate::model::ChannelModel;
use crate::series_bank::SeriesBank;
use crate::wv::stream::HaarWvStream;
use crate::wv::{haar_wv, haar_wv_of_blocks, WaveletVariance, WvError, WvOptions};

/// The log wavelet variance per level (1..=max) the engine compares, of a series fed a block
/// at a time: the overlapping Haar estimator up to level [`LogWv::FULL_LEVELS`], above it
/// coefficients every h/16 samples ([`HaarWvStream::oversampled`]), so a level of a long run
/// takes a ring of 0.5 KiB rather than 2^level samples. The measured error and every
/// simulation go through the same estimator.
pub(super) struct LogWv {
    stream: HaarWvStream,
    dt_s: f64,
    max_level: u32,
}

impl LogWv {
    /// Overlapping levels: 2^16 samples back, a ring of 2 MiB.
    const FULL_LEVELS: u32 = 16;
    /// A coefficient every h / 2^4 samples above them.
    const OVERSAMPLING: u32 = 4;

    pub fn new(dt_s: f64, max_level: u32) -> Self {
        Self {
            stream: HaarWvStream::oversampled(
                max_level.clamp(1, Self::FULL_LEVELS),
                Self::OVERSAMPLING,
            ),
            dt_s,
            max_level,
        }
    }

    /// The next samples of the series, in order.
    pub fn push(&mut self, block: &[f64]) {
        self.stream.push_block(block);
    }

    /// The log variances (empty when the series is too short for `max_level`).
    pub fn finish(self) -> Vec<f64> {
        match self
            .stream
            .wavelet_variance(Some(self.max_level), 1.0, self.dt_s)
        {
            Ok(w) => w.variance.iter().map(|v| v.max(1e-300).ln()).collect(),
            Err(_) => Vec::new(),
        }
    }
}

/// [`LogWv`] of a series.
pub(super) fn log_wv(x: &Series, dt_s: f64, max_level: u32) -> Vec<f64> {
    let mut wv = LogWv::new(dt_s, max_level);
    x.for_each_block(&mut |block| wv.push(block));
    wv.finish()
}

/// The wavelet variance a noise model is fitted on (levels 1..=floor(log2 N) - 1) of a
/// series held or drawn: held, the batch estimator; drawn, [`haar_wv_of_blocks`] (gathered
/// for the batch estimator up to [`crate::wv::GATHERED_SAMPLES`], streamed above). An error when the series
/// is too short or not finite (its first such sample named).
pub(super) fn fit_wv(x: &Series, dt_s: f64) -> Result<WaveletVariance, WvError> {
    match x {
        Series::Held(x) => haar_wv(x, dt_s, &WvOptions::default()),
        Series::Drawn { len, .. } => {
            haar_wv_of_blocks(*len, dt_s, None, &mut |visit| x.for_each_block(visit))
        }
    }
}

/// Mean and standard deviation per level of simulated log-WVs.
pub(super) fn level_stats(sims: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
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
pub(super) fn wv_misfit(measured: &[f64], sims: &[Vec<f64>]) -> f64 {
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

/// A model of one channel to simulate: deterministic coefficients (one per term of the
/// channel; zero for a term left out), the stochastic processes (None: the baseline, drawn
/// per simulation as the tests' null draws it), the effects beyond them, and the bias.
pub(super) struct ChannelModelSims<'a> {
    pub coefficients: &'a [Coefficient],
    pub stochastic: Option<&'a ModelSpec>,
    pub effects: &'a ChannelModel,
    pub intercept: f64,
}

/// Log-WVs of simulations of `model` over the epochs `range`, seeded by `salt`, the channel's
/// `slot` and the replicate: models compared on the same `salt` share their random numbers.
pub(super) fn simulate_model(
    run: &Run,
    slot: usize,
    terms: &FittedTerms,
    model: &ChannelModelSims,
    range: std::ops::Range<usize>,
    salt: u64,
) -> Result<Vec<Vec<f64>>, DiagnoseError> {
    let len = range.len();
    let channel = run.channels[slot];
    let max_level = run
        .max_wv_level()
        .min(((len as f64).log2() as u32).saturating_sub(2));
    (0..run.opts.replicates.min(16))
        .into_par_iter()
        .map(|r| {
            let mut rng = ChaCha8Rng::seed_from_u64(
                run.opts.seed ^ salt ^ ((slot as u64) << 40) ^ (r as u64) << 8,
            );
            // Each simulation draws the deterministic coefficients from their sampling
            // distribution: a term every simulation shared exactly would leave no spread at
            // the scales it dominates, and any small error of its coefficient would then
            // read as a huge misfit.
            let drawn: Vec<Coefficient> = model
                .coefficients
                .iter()
                .map(|c| {
                    let se = (c.ci95[1] - c.ci95[0]) / (2.0 * Z_FLOOR);
                    let z: f64 = StandardNormal.sample(&mut rng);
                    Coefficient {
                        value: c.value + se * z,
                        ..*c
                    }
                })
                .collect();
            let stochastic = model.stochastic.unwrap_or_else(|| run.null_model(slot, r));
            let simulation = ChannelSimulation::new(run, stochastic, model.effects, channel, rng);
            let mut wv = LogWv::new(run.dt_s, max_level);
            simulation.for_each_block(range.clone(), &mut |epochs, x| {
                terms.add_deterministic(&drawn, epochs, model.intercept, x)?;
                wv.push(x);
                Ok(())
            })?;
            Ok(wv.finish())
        })
        .collect()
}

/// The WV misfit of the error `e` (the one series of a bank) over `range` against
/// simulations of `model` there.
pub(super) fn misfit_over(
    run: &Run,
    slot: usize,
    terms: &FittedTerms,
    e: &SeriesBank,
    model: &ChannelModelSims,
    range: std::ops::Range<usize>,
    salt: u64,
) -> Result<f64, DiagnoseError> {
    let sims = simulate_model(run, slot, terms, model, range.clone(), salt)?;
    let max_level = sims.iter().map(Vec::len).min().unwrap_or(0) as u32;
    let measured = with_bank_series_in(e, 0, range, |e| log_wv(e, run.dt_s, max_level.max(1)))?;
    Ok(wv_misfit(&measured, &sims))
}

/// Share of the variance of the error `e` (the one series of a bank) over `range` that
/// `coefficients` explain there.
pub(super) fn variance_explained_over(
    terms: &FittedTerms,
    coefficients: &[Coefficient],
    e: &SeriesBank,
    range: std::ops::Range<usize>,
) -> Result<f64, DiagnoseError> {
    let left = terms.with_residual(
        coefficients,
        e,
        std::slice::from_ref(&range),
        series_variance,
    )?;
    let whole = with_bank_series_in(e, 0, range, series_variance)?;
    Ok(1.0 - left / whole)
}

/// The gain of the extended model (`terms` kept as `coefficients`, zero for a term left
/// out, `stochastic` (None: the baseline's) and `effects`) over the baseline on one channel
/// whose error is `e`: in-sample here, held out as the cross-validated `selection` measured
/// it; with the curves behind it.
pub(super) fn measure_gain(
    run: &Run,
    slot: usize,
    e: &SeriesBank,
    terms: &FittedTerms,
    extended: &ChannelModelSims,
    selection: Selection,
) -> Result<(Gain, WvCurves), DiagnoseError> {
    let n = run.n;
    let no_effects = ChannelModel::default();
    let zero: Vec<Coefficient> = vec![Coefficient::ZERO; terms.coefficients.len()];
    let baseline = ChannelModelSims {
        coefficients: &zero,
        stochastic: None,
        effects: &no_effects,
        intercept: 0.0,
    };
    let e_wv = with_bank_series(e, 0, |e| log_wv(e, run.dt_s, run.max_wv_level()))?;
    // The same random numbers for both: an extended model that kept nothing is the
    // baseline, to the digit.
    let base_sims = simulate_model(run, slot, terms, &baseline, 0..n, 11)?;
    let ext_sims = simulate_model(run, slot, terms, extended, 0..n, 11)?;
    let wv_curves = WvCurves::new(run.dt_s, &e_wv, &base_sims, &ext_sims);
    let gain = Gain {
        metric: "wv_misfit (mean squared z of log wavelet variance vs model simulations)".into(),
        baseline: wv_misfit(&e_wv, &base_sims),
        extended: wv_misfit(&e_wv, &ext_sims),
        held_out_baseline: selection.held_out_baseline,
        held_out_extended: selection.held_out_extended,
        variance_explained: variance_explained_over(terms, extended.coefficients, e, 0..n)?,
        held_out_variance_explained: selection.held_out_variance_explained,
        not_kept: selection.not_kept,
    };
    Ok((gain, wv_curves))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A drawn series gets the batch estimator up to 2^20 samples and the streamed one
    /// above, whose overlapping levels are the batch's.
    #[test]
    fn a_noise_models_wavelet_variance_is_the_batch_one_held_or_drawn() {
        let mut rng = ChaCha8Rng::seed_from_u64(61);
        let mut walk = 0.0;
        let x: Vec<f64> = (0..(1 << 20) + 5_000)
            .map(|_| {
                walk += 1e-3 * rng.sample::<f64, _>(StandardNormal);
                walk + rng.sample::<f64, _>(StandardNormal)
            })
            .collect();
        let drawn = |x: &[f64]| {
            let draw = |visit: &mut dyn FnMut(&[f64])| x.chunks(4_096).for_each(&mut *visit);
            fit_wv(
                &Series::Drawn {
                    len: x.len(),
                    draw: &draw,
                },
                0.01,
            )
            .unwrap()
        };
        let short = &x[..200_000];
        let held = fit_wv(&Series::Held(short), 0.01).unwrap();
        assert_eq!(drawn(short).variance, held.variance);
        let batch = fit_wv(&Series::Held(&x), 0.01).unwrap();
        let streamed = drawn(&x);
        assert_eq!(streamed.levels, batch.levels);
        for (j, (s, b)) in streamed.variance.iter().zip(&batch.variance).enumerate() {
            let overlapping = j < HaarWvStream::DEFAULT_FULL_LEVELS as usize;
            let tolerance = if overlapping { 1e-9 } else { 0.5 };
            assert!((s / b - 1.0).abs() < tolerance, "level {}: {s} {b}", j + 1);
        }
        let mut broken = short.to_vec();
        broken[7] = f64::NAN;
        assert!(fit_wv(&Series::Held(&broken), 0.01).is_err());
    }
}
