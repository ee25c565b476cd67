//! The null distribution every test of a diagnosis is calibrated on, and the p-values read
//! from it.
//!
//! A baseline fitted on a record of finite length is an estimate, not the truth: a
//! Gauss-Markov correlation time of 20 s fitted on 600 s is uncertain by tens of percent.
//! The simulations that calibrate the tests therefore draw each channel's model from its
//! sampling distribution (a parametric bootstrap of the fit: the model refitted on a record
//! of the same length simulated from it, [`sampling_draw`]), so the null spread covers what
//! the user knows, not what the truth would give.
//!
//! The wavelet variance at a level is a scaled chi-square with few degrees of freedom at long
//! scales, far from Gaussian on any scale. Its test reads the p-value from that law, with the
//! equivalent degrees of freedom matched to the spread of the simulated log wavelet variance
//! (which holds both the estimation noise and the baseline's own uncertainty). Levels where
//! even a tenfold change of the variance would not be significant are not tested.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};
use statrs::function::gamma::digamma;

use super::baseline::Baseline;
use crate::gmwm::inference::sampling_draw;
use crate::gmwm::model::ModelSpec;
use crate::model::Channel;

/// Per channel (in the order of `channels`), the model of each baseline simulation: drawn
/// from the fit's sampling distribution where the baseline states the record length, the
/// baseline's model itself otherwise. Returns the models and notes on what was assumed.
pub(super) fn null_models(
    baseline: &Baseline,
    channels: &[Channel],
    replicates: usize,
    seed: u64,
) -> (Vec<Vec<ModelSpec>>, Vec<String>) {
    let mut notes = Vec::new();
    let mut exact = Vec::new();
    let models = channels
        .iter()
        .enumerate()
        .map(|(slot, channel)| {
            let Some(spec) = baseline.channels.get(channel) else {
                return Vec::new();
            };
            let Some(&n) = baseline.record_samples.get(channel) else {
                exact.push(channel.name());
                return vec![spec.clone(); replicates];
            };
            let draws: Vec<Option<ModelSpec>> = (0..replicates)
                .into_par_iter()
                .map(|r| {
                    let mut rng = ChaCha8Rng::seed_from_u64(
                        seed ^ 0xb007_5742 ^ ((slot as u64) << 32) ^ r as u64,
                    );
                    sampling_draw(spec, n, &mut rng)
                })
                .collect();
            let failed = draws.iter().filter(|d| d.is_none()).count();
            if failed > 0 {
                notes.push(format!(
                    "{channel}: {failed} of {replicates} refits of the baseline on simulated records of {n} samples failed; those simulations use the baseline itself"
                ));
            }
            draws
                .into_iter()
                .map(|d| d.unwrap_or_else(|| spec.clone()))
                .collect()
        })
        .collect();
    if !exact.is_empty() {
        notes.push(format!(
            "the baseline states no record length for {} (not a `dynacal fit` output): its model is taken as exact, and its own error is not in the tests' null distribution",
            exact.join(", ")
        ));
    }
    (models, notes)
}

/// The trigamma function psi'(x), x > 0: recurrence up to x >= 10, then the asymptotic
/// series (error below 1e-10 there). statrs has digamma but not trigamma.
fn trigamma(mut x: f64) -> f64 {
    let mut acc = 0.0;
    while x < 10.0 {
        acc += 1.0 / (x * x);
        x += 1.0;
    }
    let x2 = 1.0 / (x * x);
    acc + 1.0 / x + x2 / 2.0 + (1.0 / x) * x2 * (1.0 / 6.0 - x2 * (1.0 / 30.0 - x2 / 42.0))
}

/// Degrees of freedom eta of a scaled chi-square whose log has variance `log_variance`
/// (var ln(chi2_eta / eta) = psi'(eta / 2)); eta in [0.05, 1e8].
fn edof_of_log_variance(log_variance: f64) -> f64 {
    let (mut lo, mut hi) = (0.05f64.ln(), 1e8f64.ln());
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        // psi' decreases: a larger variance needs fewer degrees of freedom.
        if trigamma(0.5 * mid.exp()) > log_variance {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (0.5 * (lo + hi)).exp()
}

/// The test of one wavelet-variance level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct LevelTest {
    /// Mean of the simulated log wavelet variance (the null's centre).
    pub null_log_mean: f64,
    /// Equivalent degrees of freedom of the null law.
    pub edof: f64,
    /// Two-sided p-value of the measured value under that law.
    pub p_value: f64,
    /// Whether a tenfold change of the variance, either way, would be significant at
    /// `alpha_test`: if not, the level has too few degrees of freedom to decide.
    pub decidable: bool,
}

/// Upper 90% bound of a variance estimated from `r` simulations, over the estimate: the
/// null spread is not understated for having few simulations.
fn variance_upper_factor(r: usize) -> f64 {
    let dof = (r.max(3) - 1) as f64;
    let chi = ChiSquared::new(dof).expect("positive dof");
    dof / chi.inverse_cdf(0.1)
}

/// Tests a measured log wavelet variance against the same statistic on `sims_log` (log
/// WVs of the baseline's simulations at one level), at per-test level `alpha_test`. The
/// null's degrees of freedom are at most `max_edof`, those the level's own estimator has
/// (eta3 of its coefficients): simulations of a baseline that puts white noise where the
/// data have correlated noise spread less than the measured level can.
pub(super) fn wv_level_test(
    measured_log: f64,
    sims_log: &[f64],
    max_edof: f64,
    alpha_test: f64,
) -> LevelTest {
    let r = sims_log.len();
    let mean = sims_log.iter().sum::<f64>() / r as f64;
    let var = sims_log.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (r as f64 - 1.0);
    let var = (var * variance_upper_factor(r)).max(trigamma(0.5 * max_edof));
    let edof = edof_of_log_variance(var);
    let chi = ChiSquared::new(edof).expect("positive dof");
    // E ln(chi2_eta / eta), so that the law is centred on the simulations' mean.
    let offset = digamma(0.5 * edof) + (2.0 / edof).ln();
    let p_of = |deviation: f64| {
        let x = edof * (deviation + offset).exp();
        (2.0 * chi.cdf(x).min(chi.sf(x))).min(1.0)
    };
    let ten = 10f64.ln();
    LevelTest {
        null_log_mean: mean,
        edof,
        p_value: p_of(measured_log - mean),
        decidable: p_of(ten) <= alpha_test && p_of(-ten) <= alpha_test,
    }
}

/// Two-sided p-value of a statistic that is standard normal under the null.
pub(super) fn normal_p_value(z: f64) -> f64 {
    let n = Normal::new(0.0, 1.0).expect("normal");
    (2.0 * n.sf(z.abs())).min(1.0)
}

/// P-value of the largest of many |z| (a scan over positions and windows, each |z| standard
/// normal under the null), against `sim_max_z`, the same scan's largest |z| on simulations
/// of the null. The scan is taken as the largest of N independent |z|, N chosen so that the
/// simulations' median is the law's median: P(max <= z) = (1 - 2 Phi(-z))^N. Why not the
/// simulations' ranks: thirty simulations cannot resolve the 1e-4 a family-wise level needs.
/// Without simulations (or a degenerate median) the p-value is that of one |z|.
pub(super) fn scan_p_value(z: f64, sim_max_z: &[f64]) -> f64 {
    let one = |z: f64| normal_p_value(z);
    let mut sims: Vec<f64> = sim_max_z
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    if sims.is_empty() {
        return one(z);
    }
    sims.sort_by(f64::total_cmp);
    let median = sims[sims.len() / 2];
    let q_median = one(median);
    let independent = if q_median > 0.0 && q_median < 1.0 {
        (0.5f64.ln() / (-q_median).ln_1p()).max(1.0)
    } else {
        1.0
    };
    (-(independent * (-one(z)).ln_1p()).exp_m1()).clamp(0.0, 1.0)
}

/// P(N >= k) for N Poisson with mean `mean`.
pub(super) fn poisson_upper_tail(k: usize, mean: f64) -> f64 {
    if k == 0 {
        return 1.0;
    }
    match statrs::distribution::Poisson::new(mean.max(1e-12)) {
        Ok(law) => {
            use statrs::distribution::DiscreteCDF;
            law.sf(k as u64 - 1)
        }
        Err(_) => 1.0,
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_scan_p_value_is_uniform_over_null_scans_and_small_for_a_real_step() {
        use rand::Rng;
        use rand_distr::StandardNormal;
        // Scans of 500 independent |z| (the law the calibration assumes): 30 to calibrate,
        // 2000 fresh ones whose p-values must fall below 0.1 and 0.01 at their rates.
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        let mut scan = || {
            (0..500)
                .map(|_| rng.sample::<f64, _>(StandardNormal).abs())
                .fold(0.0, f64::max)
        };
        let calibration: Vec<f64> = (0..30).map(|_| scan()).collect();
        let p: Vec<f64> = (0..2000)
            .map(|_| super::scan_p_value(scan(), &calibration))
            .collect();
        let below = |a: f64| p.iter().filter(|v| **v < a).count() as f64 / p.len() as f64;
        assert!((0.06..0.14).contains(&below(0.1)), "{}", below(0.1));
        assert!(below(0.01) < 0.025, "{}", below(0.01));
        // A 17-sigma step is far out of any scan's reach.
        assert!(super::scan_p_value(17.0, &calibration) < 1e-50);
        // Without simulations: one |z|.
        assert!((super::scan_p_value(1.96, &[]) - 0.05).abs() < 1e-3);
    }

    use super::*;
    use rand_distr::{ChiSquared as ChiDraw, Distribution};

    #[test]
    fn trigamma_matches_known_values() {
        // psi'(1) = pi^2 / 6, psi'(1/2) = pi^2 / 2.
        let pi2 = std::f64::consts::PI.powi(2);
        assert!((trigamma(1.0) - pi2 / 6.0).abs() < 1e-9);
        assert!((trigamma(0.5) - pi2 / 2.0).abs() < 1e-9);
        for eta in [0.5, 2.0, 7.0, 300.0] {
            let back = edof_of_log_variance(trigamma(eta / 2.0));
            assert!((back / eta - 1.0).abs() < 1e-6, "{eta} -> {back}");
        }
    }

    /// On chi-square levels of 3 degrees of freedom (a long scale), the chi-square test
    /// holds its level where a Gaussian z on the log would not: over 20000 seeded trials
    /// against 30 simulations, the rate of p < 0.01 stays at or below 1%.
    #[test]
    fn the_level_test_holds_its_false_alarm_rate_at_few_degrees_of_freedom() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let law = ChiDraw::new(3.0).unwrap();
        let draw = |rng: &mut ChaCha8Rng| (law.sample(rng) / 3.0f64).ln();
        let trials = 20_000;
        let mut alarms = 0;
        for _ in 0..trials {
            let sims: Vec<f64> = (0..30).map(|_| draw(&mut rng)).collect();
            let measured = draw(&mut rng);
            if wv_level_test(measured, &sims, 1e9, 1e-3).p_value < 0.01 {
                alarms += 1;
            }
        }
        let rate = alarms as f64 / trials as f64;
        assert!(rate <= 0.01, "false-alarm rate {rate}");
        // And it has power: a sixteenfold variance is found at 1% most of the time.
        let mut found = 0;
        for _ in 0..2000 {
            let sims: Vec<f64> = (0..30).map(|_| draw(&mut rng)).collect();
            let measured = draw(&mut rng) + 4f64.ln() * 2.0;
            if wv_level_test(measured, &sims, 1e9, 1e-3).p_value < 0.01 {
                found += 1;
            }
        }
        assert!(found > 1000, "power {found} of 2000 at sixteenfold");
    }

    #[test]
    fn a_level_of_one_degree_of_freedom_is_not_decidable_and_many_are() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let few = ChiDraw::new(1.0).unwrap();
        let many = ChiDraw::new(400.0).unwrap();
        let sims_few: Vec<f64> = (0..30)
            .map(|_| f64::max(few.sample(&mut rng), 1e-300).ln())
            .collect();
        let sims_many: Vec<f64> = (0..30)
            .map(|_| (many.sample(&mut rng) / 400.0f64).ln())
            .collect();
        assert!(!wv_level_test(0.0, &sims_few, 1e9, 1e-4).decidable);
        assert!(wv_level_test(0.0, &sims_many, 1e9, 1e-4).decidable);
    }
}
