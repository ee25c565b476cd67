//! What the board model says the fused virtual IMU's filter needs: the noise of the
//! inverse-variance weighted mean of the units, per sensor type.
//!
//! The fusion weights unit k by `1 / white_k` (its white-noise PSD), so the fused white noise
//! is `1 / sum(1 / white_k)` and any other independent error of the units enters with the
//! squared weights: `sum(w_k^2 q_k)`. A unit's bias is a Gauss-Markov process of stationary
//! variance `sigma2` and correlation time `tau` (driving PSD `2 sigma2 / tau`) plus a random
//! walk; the filter's bias state is one first-order process per sensor type, so it takes the
//! weighted correlation rate of the units that have one and the sum of the driving PSDs.
//! Triad axes are averaged: the filter has one PSD per sensor type.

// Float methods without std.
#[allow(unused_imports)]
use nalgebra::ComplexField;

use crate::board_model::{ChannelNoise, UnitModel};

/// Noise of one sensor type (gyro or accelerometer) of the fused output, SI units of the
/// sensor (rad/s or m/s^2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusedNoise {
    /// White-noise PSD, unit^2 s.
    pub white_psd: f32,
    /// Driving PSD of the bias state, unit^2 / s.
    pub bias_psd: f32,
    /// Inverse correlation time of the bias state, 1/s (0: a random walk).
    pub bias_inv_tau_s: f32,
    /// Stationary standard deviation of the bias where it is Gauss-Markov (0: a walk), unit.
    pub bias_sigma: f32,
}

/// One unit's triad of `channels` (three consecutive channels of the model), axis-averaged.
fn triad_mean(channels: &[ChannelNoise]) -> ChannelNoise {
    let n = channels.len().max(1) as f32;
    let mean = |f: fn(&ChannelNoise) -> f32| channels.iter().map(f).sum::<f32>() / n;
    ChannelNoise {
        white_psd: mean(|c| c.white_psd),
        gauss_markov_sigma2: mean(|c| c.gauss_markov_sigma2),
        gauss_markov_tau_s: mean(|c| c.gauss_markov_tau_s),
        random_walk_psd: mean(|c| c.random_walk_psd),
    }
}

/// The fused noise of the units' gyros (`accelerometer` false: channels 0..3) or
/// accelerometers (channels 3..6). Units whose white PSD is zero get equal weights.
pub fn fused_noise(units: &[UnitModel], accelerometer: bool) -> FusedNoise {
    let first = if accelerometer { 3 } else { 0 };
    let triads = units
        .iter()
        .map(|u| triad_mean(&u.channels[first..first + 3]));
    let all_weighted = units
        .iter()
        .all(|u| triad_mean(&u.channels[first..first + 3]).white_psd > 0.0);
    let weight = |c: &ChannelNoise| {
        if all_weighted {
            1.0 / c.white_psd
        } else {
            1.0
        }
    };
    let total: f32 = triads.clone().map(|c| weight(&c)).sum();
    let mut fused = FusedNoise {
        white_psd: 0.0,
        bias_psd: 0.0,
        bias_inv_tau_s: 0.0,
        bias_sigma: 0.0,
    };
    if total <= 0.0 {
        return fused;
    }
    let (mut beta_weight, mut beta_sum, mut gm_variance) = (0.0f32, 0.0f32, 0.0f32);
    for c in triads {
        let w = weight(&c) / total;
        fused.white_psd += w * w * c.white_psd;
        fused.bias_psd += w * w * c.random_walk_psd;
        if c.gauss_markov_sigma2 > 0.0 && c.gauss_markov_tau_s > 0.0 {
            let beta = 1.0 / c.gauss_markov_tau_s;
            fused.bias_psd += w * w * 2.0 * c.gauss_markov_sigma2 * beta;
            gm_variance += w * w * c.gauss_markov_sigma2;
            beta_sum += w * beta;
            beta_weight += w;
        }
    }
    if beta_weight > 0.0 {
        fused.bias_inv_tau_s = beta_sum / beta_weight;
        fused.bias_sigma = gm_variance.sqrt();
    }
    fused
}

/// The variance (sensor unit², per axis) of the error with which a running mean of time
/// constant `time_constant_s` (the fault monitor's offsets) follows extra unit `unit`'s bias
/// relative to the fused output (gyros, or `accelerometer`s): that bias is the unit's own
/// less the weighted mean's, `(1 − w_k) b_k − Σ_{j≠k} w_j b_j`, and a running mean of rate
/// `a = 1 / time_constant_s` lags a Gauss-Markov process of variance `s²` and rate `β` by a
/// variance `β s² / (a + β)`, a random walk of PSD `q` by `q / (2a)`, and averages the
/// relative white noise of PSD `q_w` down to `q_w a / 2`.
pub fn offset_tracking_variance(
    units: &[UnitModel],
    accelerometer: bool,
    unit: usize,
    time_constant_s: f32,
) -> f32 {
    let first = if accelerometer { 3 } else { 0 };
    let mut triads = [None; crate::log::MAX_IMUS];
    for (slot, u) in triads.iter_mut().zip(units) {
        *slot = Some(triad_mean(&u.channels[first..first + 3]));
    }
    let all_weighted = triads.iter().flatten().all(|c| c.white_psd > 0.0);
    let weight = |c: &ChannelNoise| if all_weighted { 1.0 / c.white_psd } else { 1.0 };
    let total: f32 = triads.iter().flatten().map(weight).sum();
    if total <= 0.0 || unit >= units.len() || !(time_constant_s > 0.0) {
        return 0.0;
    }
    let a = 1.0 / time_constant_s;
    let mut variance = 0.0;
    for (j, c) in triads.iter().flatten().enumerate() {
        let w = weight(c) / total;
        // The unit's coefficient in its relative bias: 1 − w_k for itself, −w_j for the others.
        let coefficient = if j == unit { 1.0 - w } else { w };
        let mut own = c.random_walk_psd / (2.0 * a) + c.white_psd * a / 2.0;
        if c.gauss_markov_sigma2 > 0.0 && c.gauss_markov_tau_s > 0.0 {
            let beta = 1.0 / c.gauss_markov_tau_s;
            own += c.gauss_markov_sigma2 * beta / (a + beta);
        }
        variance += coefficient * coefficient * own;
    }
    variance
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board_model::BoardModel;

    #[test]
    fn a_running_offset_lags_a_fast_relative_bias_more_than_a_slow_one() {
        let mut model = BoardModel::built_in(&[0, 1, 2]);
        let mut with_tau = |tau_s: f32| {
            for unit in model.units.iter_mut() {
                for c in &mut unit.channels[3..6] {
                    c.white_psd = 0.0;
                    c.gauss_markov_sigma2 = 1e-4;
                    c.gauss_markov_tau_s = tau_s;
                    c.random_walk_psd = 0.0;
                }
            }
            offset_tracking_variance(&model.units, true, 1, 10.0)
        };
        // Equal units: the relative bias has variance (4/9 + 1/9 + 1/9) 1e-4; a 10 s mean
        // lags a 20 s process by beta / (a + beta) = 1/3 of it, a 300 s one by 1/31.
        let relative = 6.0 / 9.0 * 1e-4;
        assert!((with_tau(20.0) - relative / 3.0).abs() < 1e-3 * relative);
        assert!((with_tau(300.0) - relative / 31.0).abs() < 1e-3 * relative);
    }

    #[test]
    fn equal_units_average_their_white_noise_down_by_their_number() {
        let model = BoardModel::built_in(&[0, 1, 2]);
        let one = model.units[0].channels[0];
        let fused = fused_noise(&model.units, false);
        assert!((fused.white_psd - one.white_psd / 3.0).abs() < 1e-6 * one.white_psd);
        assert!((fused.bias_psd - one.random_walk_psd / 3.0).abs() < 1e-6 * one.random_walk_psd);
        assert_eq!(fused.bias_inv_tau_s, 0.0);
    }

    #[test]
    fn a_noisy_unit_is_weighted_down_and_gauss_markov_biases_set_the_correlation_time() {
        let mut model = BoardModel::built_in(&[0, 1, 2]);
        for (k, unit) in model.units.iter_mut().enumerate() {
            for c in &mut unit.channels[3..6] {
                c.white_psd = if k == 2 { 4e-4 } else { 1e-4 };
                c.gauss_markov_sigma2 = 1e-4;
                c.gauss_markov_tau_s = 100.0;
                c.random_walk_psd = 0.0;
            }
        }
        let fused = fused_noise(&model.units, true);
        // Weights 4:4:1 of 9; white 1 / (1e4 + 1e4 + 2.5e3).
        assert!((fused.white_psd - 1.0 / 22_500.0).abs() < 1e-9);
        let w2: f32 = [4.0f32 / 9.0, 4.0 / 9.0, 1.0 / 9.0]
            .iter()
            .map(|w| w * w)
            .sum();
        assert!((fused.bias_psd - w2 * 2.0 * 1e-4 / 100.0).abs() < 1e-9);
        assert!((fused.bias_inv_tau_s - 0.01).abs() < 1e-7);
        assert!((fused.bias_sigma - (w2 * 1e-4).sqrt()).abs() < 1e-6);
    }
}
