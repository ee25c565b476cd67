//! The covariance matrix V of the wavelet-variance estimates implied by a model: what the
//! delta-method intervals, the J-test and the model-selection criterion need beyond the
//! diagonal weights.
//!
//! Large-sample result for Gaussian processes (Percival & Walden 2000, ch. 8, extended to
//! two levels): cov(nu_i, nu_j) ~= 2 / sqrt(M_i M_j) * int_{-1/2}^{1/2} G_i(f) G_j(f) S(f)^2 df,
//! with S the model's (pseudo-)spectrum per sample and G_j(f) = 4 sin^4(pi f h)/(tau^2
//! sin^2(pi f)) the squared gain of the Haar MODWT filter (tau = 2^j, h = tau/2). Drift is
//! deterministic and contributes nothing; quantization noise is treated as Gaussian with its
//! spectrum 4 q2 sin^2(pi f) (its fourth cumulant is ignored).
//!
//! Why a hand-made quadrature: the integrand oscillates with period 1/h_j (up to 2^21
//! oscillations at the coarsest level of a 1e7-sample series), so a uniform grid would need
//! millions of points per pair of levels. Instead each pair (i <= j) is integrated exactly
//! (fine uniform grid) only where the oscillations are slow (f < 16/h_j, and f < 16/h_i for
//! nearby levels), and where a filter oscillates fast relative to everything else its sin^4
//! factor is replaced by its mean (3/8; 35/128 for sin^8 when i = j; 7/64 for two adjacent
//! levels, whose sin^4(x) sin^4(2x) have a common harmonic; 9/64 otherwise), leaving smooth
//! envelopes integrated on a geometric grid. Checked against Monte Carlo in the tests.

use nalgebra::DMatrix;
use rayon::prelude::*;

use super::model::{ModelSpec, Process};

/// Periods of the slow filter resolved exactly before its oscillation is averaged.
const EXACT_PERIODS: f64 = 16.0;

/// One-sided spectrum (per sample, cycles/sample f in (0, 1/2)) of the stochastic part of a
/// model, unit^2 per cycle/sample.
fn spectrum(model: &ModelSpec, f: f64) -> f64 {
    let dt = model.dt_s();
    let s_pi = (std::f64::consts::PI * f).sin();
    let mut s = 0.0;
    for p in &model.processes {
        s += match *p {
            Process::WhiteNoise { sigma2 } => sigma2,
            Process::QuantizationNoise { q2 } => 4.0 * q2 * s_pi * s_pi,
            Process::RandomWalk { sigma2 } => sigma2 / (4.0 * s_pi * s_pi),
            Process::Drift { .. } => 0.0,
            Process::GaussMarkov { beta_per_s, sigma2 } => {
                let a = beta_per_s * dt;
                let phi = (-a).exp();
                let one_minus_phi = -(-a).exp_m1();
                // 1 - 2 phi cos(2 pi f) + phi^2 = (1 - phi)^2 + 4 phi sin^2(pi f), no cancellation.
                let den = one_minus_phi * one_minus_phi + 4.0 * phi * s_pi * s_pi;
                sigma2 * one_minus_phi * (1.0 + phi) / den
            }
        };
    }
    s
}

/// Squared Haar gain G(f) for half-width h (tau = 2h).
fn gain(h: f64, f: f64) -> f64 {
    let pi = std::f64::consts::PI;
    let s = (pi * f * h).sin();
    let d = (pi * f).sin();
    let tau = 2.0 * h;
    4.0 * s.powi(4) / (tau * tau * d * d)
}

/// The smooth envelope of G without its sin^4 factor.
fn envelope(h: f64, f: f64) -> f64 {
    let d = (std::f64::consts::PI * f).sin();
    let tau = 2.0 * h;
    4.0 / (tau * tau * d * d)
}

/// Midpoint rule of `g` over [a, b] with local step `step(f)`.
fn integrate(a: f64, b: f64, step: impl Fn(f64) -> f64, g: impl Fn(f64) -> f64) -> f64 {
    let mut total = 0.0;
    let mut f0 = a;
    while f0 < b {
        let f1 = (f0 + step(f0)).min(b);
        total += (f1 - f0) * g(0.5 * (f0 + f1));
        f0 = f1;
    }
    total
}

/// int_0^{1/2} G_i G_j S^2 df for half-widths h_i <= h_j.
fn pair_integral(model: &ModelSpec, hi: f64, hj: f64) -> f64 {
    let s2 = |f: f64| {
        let s = spectrum(model, f);
        s * s
    };
    let f_a = (EXACT_PERIODS / hj).min(0.5);
    let f_b = (EXACT_PERIODS / hi).min(0.5);
    let exact = |f: f64| gain(hi, f) * gain(hj, f) * s2(f);
    // Region A: both filters resolved, 32 points per period of the faster oscillation, and
    // geometric near 0 so that narrow spectral peaks (slow GM, RW) are resolved.
    let fine = 1.0 / (32.0 * hj);
    let mut total = integrate(0.0, f_a, |f| fine.min(0.05 * f).max(1e-3 * fine), exact);
    if f_b > f_a {
        let ratio = hj / hi;
        total += if ratio < 8.0 {
            integrate(f_a, f_b, |f| fine.min(0.05 * f), exact)
        } else {
            // The coarse filter oscillates fast: its sin^4 averages to 3/8.
            let fine_i = 1.0 / (32.0 * hi);
            integrate(
                f_a,
                f_b,
                |f| fine_i.min(0.05 * f),
                |f| 0.375 * envelope(hj, f) * gain(hi, f) * s2(f),
            )
        };
    }
    if f_b < 0.5 {
        let mean = if hi == hj {
            35.0 / 128.0
        } else if hj == 2.0 * hi {
            7.0 / 64.0
        } else {
            9.0 / 64.0
        };
        total += integrate(
            f_b,
            0.5,
            |f| 0.02 * f,
            |f| mean * envelope(hi, f) * envelope(hj, f) * s2(f),
        );
    }
    total
}

/// V: cov(nu_hat_i, nu_hat_j) of the WV estimates at `levels` from `n_coefficients[i]`
/// coefficients each, if `model` is the truth (unit^4).
pub fn wv_covariance(model: &ModelSpec, levels: &[u32], n_coefficients: &[usize]) -> DMatrix<f64> {
    let k = levels.len();
    let pairs: Vec<(usize, usize)> = (0..k).flat_map(|a| (a..k).map(move |b| (a, b))).collect();
    let values: Vec<f64> = pairs
        .par_iter()
        .map(|&(a, b)| {
            let (ha, hb) = (
                (levels[a] as f64 - 1.0).exp2(),
                (levels[b] as f64 - 1.0).exp2(),
            );
            let (lo, hi) = if ha <= hb { (ha, hb) } else { (hb, ha) };
            let integral = pair_integral(model, lo, hi);
            // Two-sided integral = 2 x one-sided; times 2 / sqrt(M_a M_b).
            4.0 * integral / ((n_coefficients[a] as f64) * (n_coefficients[b] as f64)).sqrt()
        })
        .collect();
    let mut v = DMatrix::zeros(k, k);
    for (&(a, b), &x) in pairs.iter().zip(&values) {
        v[(a, b)] = x;
        v[(b, a)] = x;
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wv::{haar_wv, WvOptions};
    use rand::SeedableRng;

    #[test]
    fn white_noise_variance_matches_closed_form() {
        // For WN the exact large-sample variance is 2 nu^2 tau (sum R^2)/... : compare with
        // the direct time-domain sum 2/M sum_k (sigma2 R(k)/tau^2)^2.
        let m = ModelSpec::from_json(
            r#"{"model":"WN","unit":"u","sample_rate_hz":1,"processes":[{"kind":"white_noise","sigma2":2.0}]}"#,
        )
        .unwrap();
        let levels: Vec<u32> = (1..=14).collect();
        let mcount = vec![1_000_000usize; levels.len()];
        let v = wv_covariance(&m, &levels, &mcount);
        for (a, &j) in levels.iter().enumerate() {
            let h = 1i64 << (j - 1);
            let tau = (2 * h) as f64;
            let mut sum = (2.0 * h as f64).powi(2);
            for k in 1..2 * h {
                let r = if k <= h { 2 * h - 3 * k } else { -(2 * h - k) } as f64;
                sum += 2.0 * r * r;
            }
            let exact = 2.0 / 1e6 * sum * (2.0 / (tau * tau)).powi(2);
            let rel = v[(a, a)] / exact - 1.0;
            assert!(
                rel.abs() < 0.01,
                "level {j}: {} vs {exact} ({rel})",
                v[(a, a)]
            );
        }
    }

    #[test]
    fn covariance_matches_monte_carlo_for_wn_plus_gm() {
        let m = ModelSpec::from_json(
            r#"{"model":"WN+GM","unit":"u","sample_rate_hz":100,"processes":[
                {"kind":"white_noise","sigma2":1.0},
                {"kind":"gauss_markov","beta_per_s":3.0,"sigma2":0.5}]}"#,
        )
        .unwrap();
        let n = 1 << 14;
        let reps = 600;
        let opts = WvOptions {
            max_level: Some(8),
            ..WvOptions::default()
        };
        let sims: Vec<Vec<f64>> = (0..reps)
            .into_par_iter()
            .map(|r| {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1000 + r as u64);
                let x = m.simulate(n, &mut rng);
                haar_wv(&x, 0.01, &opts).unwrap().variance
            })
            .collect();
        let levels: Vec<u32> = (1..=8).collect();
        let mcount: Vec<usize> = levels.iter().map(|&j| n + 1 - (1 << j)).collect();
        let v = wv_covariance(&m, &levels, &mcount);
        let k = levels.len();
        let mean: Vec<f64> = (0..k)
            .map(|a| sims.iter().map(|s| s[a]).sum::<f64>() / reps as f64)
            .collect();
        let cov = |a: usize, b: usize| {
            sims.iter()
                .map(|s| (s[a] - mean[a]) * (s[b] - mean[b]))
                .sum::<f64>()
                / (reps - 1) as f64
        };
        // Sampling error of a variance from 600 replicates is about sqrt(2/600) = 6%.
        for a in 0..k {
            let emp = cov(a, a);
            assert!(
                (v[(a, a)] / emp - 1.0).abs() < 0.2,
                "var level {}: model {} mc {emp}",
                a + 1,
                v[(a, a)]
            );
        }
        for a in 0..k - 1 {
            let emp = cov(a, a + 1) / (cov(a, a) * cov(a + 1, a + 1)).sqrt();
            let th = v[(a, a + 1)] / (v[(a, a)] * v[(a + 1, a + 1)]).sqrt();
            assert!(
                (emp - th).abs() < 0.12,
                "corr {}-{}: model {th} mc {emp}",
                a + 1,
                a + 2
            );
        }
    }
}
