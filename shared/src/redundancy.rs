//! Several IMUs on one platform, sampled together and brought into one frame, see their own
//! errors without a reference: every difference of two units cancels the motion and leaves
//! the difference of their errors. Two pieces live here, both allocation-free for the board:
//! - [`own_variances`]: each unit's own error variance at one scale (a wavelet variance, or a
//!   white-noise level) from the variances of all pairwise differences. For independent
//!   errors Var(e_k - e_l) = V_k + V_l, so three units give the three-cornered hat of clock
//!   metrology (Gray and Allan 1974), V_1 = (V_12 + V_13 - V_23) / 2; N units give a least
//!   squares over the N(N-1)/2 pairs, solved here with V >= 0 (a quiet unit's variance is a
//!   small difference of large numbers and may come out negative: it is clamped, and said).
//! - [`LiveNoise`]: each unit's own white-noise level over the last seconds (the seed paper's
//!   Fig. 8 without its mixing: a residual around the mean of three units has variance
//!   (4 s_k^2 + s_l^2 + s_m^2) / 9), from products of differences that share the unit, with a
//!   moving / not-moving state.
//!
//! - [`align`]: one unit brought into another's frame (the rotation from the gyros, the lever
//!   arm from the specific-force differences) from accumulated sums.
//!
//! What the units share (a common temperature drift, the same vibration on one board) cancels
//! in every difference: these are the independent parts of the errors only.

use nalgebra::ComplexField;

use crate::scalar::FilterScalar;

pub mod align;
pub mod faults;

pub use align::{lever_matrix, LeverArmNormal, RotationAccumulator};
pub use faults::{FaultConfig, FaultEvent, FaultKind, FaultMonitor};

/// Most units a set may hold.
pub const MAX_UNITS: usize = 8;

/// Sorts a few values (at most [`MAX_UNITS`], or a matrix's three eigenvalues) in place,
/// ascending by `less`. Written out because `core`'s sort brings 6 KB of flash to the board
/// for slices this short, where an insertion sort is as fast.
pub fn sort_few<T: Copy>(values: &mut [T], less: impl Fn(&T, &T) -> bool) {
    for i in 1..values.len() {
        let mut j = i;
        while j > 0 && less(&values[j], &values[j - 1]) {
            values.swap(j, j - 1);
            j -= 1;
        }
    }
}

/// Number of pairs (k, l), k < l, of `units` units.
pub const fn pairs(units: usize) -> usize {
    units * units.saturating_sub(1) / 2
}

/// Index of the pair (k, l), k < l < `units`, in the order (0,1), (0,2), ..., (0,n-1), (1,2),
/// ...: the order [`own_variances`] reads its input in.
pub const fn pair_index(units: usize, k: usize, l: usize) -> usize {
    k * units - k * (k + 1) / 2 + (l - k - 1)
}

/// Why a set of pairwise variances cannot be solved for the units' own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RedundancyError {
    /// Fewer than three units (two see only the sum of their variances) or more than
    /// [`MAX_UNITS`].
    Units(usize),
    /// The number of pairwise variances given is not `pairs(units)`.
    Pairs { expected: usize, given: usize },
    /// A pairwise variance is negative or not finite.
    NotAVariance { pair: usize },
}

/// Each unit's own variance at one scale, unit^2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OwnVariances {
    pub units: usize,
    /// `value[k]` for k < units.
    pub value: [f64; MAX_UNITS],
    /// The unconstrained least squares gave unit k a negative variance, so it was held at 0.
    pub clamped: [bool; MAX_UNITS],
    /// Sum of squared misfits of the pairwise variances, unit^4: large against the pairs'
    /// own spread when the errors are not independent (a common-mode part correlates them).
    pub misfit: f64,
}

/// The least-squares own variances with only the units in `free` (a bit mask) allowed to be
/// non-zero, and the misfit. With every pair observed the normal matrix on the free set F is
/// (N - 2) I + J (each unit is in N - 1 pairs, each two units share one), whose inverse is
/// (I - J / (N - 2 + |F|)) / (N - 2): x_k = (S_k - sum_F S / (N - 2 + |F|)) / (N - 2), with
/// S_k the sum of the pair variances that involve unit k.
fn solve_on(units: usize, pair_variance: &[f64], free: u32) -> ([f64; MAX_UNITS], f64) {
    let n = units as f64;
    let mut s = [0.0; MAX_UNITS];
    for k in 0..units {
        for l in k + 1..units {
            let v = pair_variance[pair_index(units, k, l)];
            s[k] += v;
            s[l] += v;
        }
    }
    let free_count = free.count_ones() as f64;
    let free_sum: f64 = (0..units)
        .filter(|k| free >> k & 1 == 1)
        .map(|k| s[k])
        .sum();
    let mut x = [0.0; MAX_UNITS];
    for (k, xk) in x.iter_mut().enumerate().take(units) {
        if free >> k & 1 == 1 {
            *xk = (s[k] - free_sum / (n - 2.0 + free_count)) / (n - 2.0);
        }
    }
    let mut misfit = 0.0;
    for k in 0..units {
        for l in k + 1..units {
            let r = pair_variance[pair_index(units, k, l)] - x[k] - x[l];
            misfit += r * r;
        }
    }
    (x, misfit)
}

/// Each unit's own variance from `pair_variance`, the variances of the differences of every
/// pair of `units` units in [`pair_index`] order: non-negative least squares, exact. With at
/// most [`MAX_UNITS`] units every free set is tried (at most 256 closed-form solves, no
/// iteration to converge): the optimum is the least-squares solution on its own support,
/// and the best feasible one over all supports is it.
pub fn own_variances(units: usize, pair_variance: &[f64]) -> Result<OwnVariances, RedundancyError> {
    if !(3..=MAX_UNITS).contains(&units) {
        return Err(RedundancyError::Units(units));
    }
    if pair_variance.len() != pairs(units) {
        return Err(RedundancyError::Pairs {
            expected: pairs(units),
            given: pair_variance.len(),
        });
    }
    if let Some(pair) = pair_variance
        .iter()
        .position(|v| !(v.is_finite() && *v >= 0.0))
    {
        return Err(RedundancyError::NotAVariance { pair });
    }
    let all = (1u32 << units) - 1;
    let (unconstrained, _) = solve_on(units, pair_variance, all);
    let mut best: Option<([f64; MAX_UNITS], f64)> = None;
    for free in (0..=all).rev() {
        let (x, misfit) = solve_on(units, pair_variance, free);
        let feasible = x.iter().all(|v| *v >= 0.0);
        if feasible && best.is_none_or(|(_, m)| misfit < m) {
            best = Some((x, misfit));
        }
    }
    // The empty free set (all zero) is always feasible, so there is a best.
    let (value, misfit) = best.unwrap_or(([0.0; MAX_UNITS], f64::INFINITY));
    let mut clamped = [false; MAX_UNITS];
    for k in 0..units {
        clamped[k] = unconstrained[k] < 0.0 && value[k] == 0.0;
    }
    Ok(OwnVariances {
        units,
        value,
        clamped,
        misfit,
    })
}

/// Thresholds of the moving / not-moving state, with hysteresis: the platform is moving once
/// its smoothed angular rate exceeds `moving_rad_s`, and still again once it falls below
/// `still_rad_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionThresholds {
    pub moving_rad_s: f32,
    pub still_rad_s: f32,
}

impl Default for MotionThresholds {
    /// 3 deg/s to start moving, 1.5 deg/s to be still again: above a MEMS gyro's noise and
    /// bias at rest, below any deliberate motion.
    fn default() -> Self {
        Self {
            moving_rad_s: 0.052,
            still_rad_s: 0.026,
        }
    }
}

/// Each of N units' own white-noise level of one sensor triad (gyro or accelerometer) over
/// the last seconds, from aligned samples taken together. For unit k and two others l, m,
/// the product (d z_k - d z_l)(d z_k - d z_m) of first differences (which remove the bias
/// and slow drift) has mean Var(d e_k) = 2 s_k^2 when the errors are independent and white;
/// it is averaged over the pairs (l, m), the three axes and, exponentially, over time.
///
/// Generic over the filter's scalar (`f32` on the board by default, `f64`, or Q32.32 fixed
/// point). In fixed point the differences are scaled by a power of two of the triad's own
/// (`2^-scale`, renormalised so the largest weighted product stays in [1/4, 4)): a gyro's
/// products of 1e-6 (rad/s)² would otherwise hold three digits, and their exponential
/// update, a thousandth of that, none.
#[derive(Debug, Clone)]
pub struct LiveNoise<const N: usize, T: FilterScalar = f32> {
    previous: Option<[[T; 3]; N]>,
    /// Exponentially weighted mean of the products, per unit: 2 s_k^2, times `2^(-2 scale)`.
    weighted: [T; N],
    /// Weight of a new sample, 1 - exp(-dt / time constant).
    alpha: T,
    /// Samples seen, for the start-up weight (a plain mean until 1 / alpha samples).
    seen: u32,
    smoothed_rate_rad_s: T,
    moving: bool,
    moving_rad_s: T,
    still_rad_s: T,
    /// The differences' power-of-two scale exponent (0 in floating point).
    scale: i32,
    /// Sets after which the exponential weight is at least twice a plain mean's, so the
    /// plain mean's (a division, bit by bit in fixed point) is no longer formed.
    plain_mean_sets: u32,
    /// Axes times pairs per unit: what a unit's summed products are divided by (in fixed
    /// point multiplied by its reciprocal: a division there is a bit-by-bit loop).
    products_per_unit: T,
    reciprocal_products_per_unit: T,
}

impl<const N: usize, T: FilterScalar> LiveNoise<N, T> {
    /// `sample_interval_s` between sets of samples, `time_constant_s` of the exponential
    /// weighting (a few seconds: Fig. 8's level follows the manoeuvres).
    pub fn new(sample_interval_s: f32, time_constant_s: f32, thresholds: MotionThresholds) -> Self {
        assert!(N >= 3, "a live noise level needs three units or more");
        let c = T::convert_from_f32;
        let products_per_unit = (3 * (N - 1) * (N - 2) / 2) as f64;
        let alpha = 1.0 - (-sample_interval_s / time_constant_s).exp();
        Self {
            previous: None,
            weighted: [T::zero(); N],
            alpha: c(alpha),
            seen: 0,
            smoothed_rate_rad_s: T::zero(),
            moving: false,
            moving_rad_s: c(thresholds.moving_rad_s),
            still_rad_s: c(thresholds.still_rad_s),
            scale: 0,
            plain_mean_sets: (2.0 / alpha).min(u32::MAX as f32) as u32 + 1,
            products_per_unit: nalgebra::convert(products_per_unit),
            reciprocal_products_per_unit: nalgebra::convert(1.0 / products_per_unit),
        }
    }

    /// One set of aligned samples (body frame, one triad per unit), and for the motion state
    /// the platform's angular rate (rad/s, e.g. the mean of the units' gyros).
    pub fn push(&mut self, samples: &[[T; 3]; N], angular_rate_rad_s: [T; 3]) {
        let mut rate2 = T::zero();
        for w in angular_rate_rad_s {
            rate2 += w * w;
        }
        let rate = rate2.sqrt();
        self.smoothed_rate_rad_s += self.alpha * (rate - self.smoothed_rate_rad_s);
        if self.moving && self.smoothed_rate_rad_s < self.still_rad_s {
            self.moving = false;
        } else if !self.moving && self.smoothed_rate_rad_s > self.moving_rad_s {
            self.moving = true;
        }
        let Some(previous) = self.previous.replace(*samples) else {
            return;
        };
        let mut delta = [[T::zero(); 3]; N];
        for (d, (now, before)) in delta.iter_mut().zip(samples.iter().zip(&previous)) {
            for a in 0..3 {
                d[a] = now[a] - before[a];
                if T::SCALED {
                    d[a] = d[a].mul_pow2(-self.scale);
                }
            }
        }
        self.seen = self.seen.saturating_add(1);
        // A plain mean until the exponential weight is the smaller: no start-up bias to zero.
        let weight = if self.seen < self.plain_mean_sets {
            self.alpha
                .max(T::one() / nalgebra::convert::<f64, T>(f64::from(self.seen)))
        } else {
            self.alpha
        };
        for k in 0..N {
            let mut sum = T::zero();
            for l in 0..N {
                for m in l + 1..N {
                    if l == k || m == k {
                        continue;
                    }
                    let mut axes = T::zero();
                    for ((dk, dl), dm) in delta[k].iter().zip(&delta[l]).zip(&delta[m]) {
                        axes += (*dk - *dl) * (*dk - *dm);
                    }
                    sum += axes;
                }
            }
            let product = if T::SCALED {
                sum * self.reciprocal_products_per_unit
            } else {
                sum / self.products_per_unit
            };
            self.weighted[k] += weight * (product - self.weighted[k]);
        }
        if T::SCALED {
            self.renormalise();
        }
    }

    /// Moves the differences' scale so the largest weighted product lies in [1/4, 4) (each
    /// step halves or doubles the differences, so the products move by four).
    fn renormalise(&mut self) {
        let largest = self.weighted.iter().fold(T::zero(), |m, w| m.max(w.abs()));
        let Some(k) = largest.exponent() else {
            return;
        };
        // A product in [2^k, 2^(k+1)) times 2^(-2d) lies in [1/2, 2) for d = (k + 1) div 2.
        if (-2..=1).contains(&k) {
            return;
        }
        let d = (k + 1).div_euclid(2);
        for w in &mut self.weighted {
            *w = w.mul_pow2(-2 * d);
        }
        self.scale += d;
    }

    /// Unit k's own white-noise standard deviation per sample (sensor unit), 0 before two
    /// sets of samples; a negative weighted product (possible over a short window when the
    /// unit is much quieter than the others) reads 0.
    pub fn sigma(&self, unit: usize) -> T {
        let sigma = self.weighted[unit].mul_pow2(-1).max(T::zero()).sqrt();
        if T::SCALED {
            sigma.mul_pow2(self.scale)
        } else {
            sigma
        }
    }

    /// Whether the platform is moving (with hysteresis, see [`MotionThresholds`]).
    pub fn moving(&self) -> bool {
        self.moving
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    #[test]
    fn sort_few_orders_short_slices_with_ties_and_infinities() {
        let mut x = [
            3.0f32,
            -1.0,
            f32::INFINITY,
            3.0,
            -7.5,
            0.0,
            f32::NEG_INFINITY,
        ];
        sort_few(&mut x, |a, b| a.total_cmp(b).is_lt());
        assert_eq!(
            x,
            [f32::NEG_INFINITY, -7.5, -1.0, 0.0, 3.0, 3.0, f32::INFINITY]
        );
        let mut one = [2.0f64];
        sort_few(&mut one, |a, b| a < b);
        assert_eq!(one, [2.0]);
    }

    #[test]
    fn three_units_give_the_three_cornered_hat_exactly() {
        let own = [4.0, 1.0, 9.0];
        let pair = [own[0] + own[1], own[0] + own[2], own[1] + own[2]];
        let v = own_variances(3, &pair).unwrap();
        for (value, truth) in v.value.iter().zip(own) {
            assert!((value - truth).abs() < 1e-12, "{v:?}");
        }
        assert!(v.misfit < 1e-20 && v.clamped.iter().all(|c| !c));
        // The textbook formula, unit 0.
        assert!((v.value[0] - (pair[0] + pair[1] - pair[2]) / 2.0).abs() < 1e-12);
    }

    #[test]
    fn n_units_recover_their_variances_from_noisy_pairs_by_least_squares() {
        let own = [1.0, 2.0, 3.0, 4.0, 5.0, 0.5];
        let units = own.len();
        let mut pair = [0.0; pairs(6)];
        for k in 0..units {
            for l in k + 1..units {
                pair[pair_index(units, k, l)] = own[k] + own[l];
            }
        }
        let exact = own_variances(units, &pair).unwrap();
        for (value, truth) in exact.value.iter().zip(own) {
            assert!((value - truth).abs() < 1e-12);
        }
        // A perturbation of one pair spreads over its two units, mostly.
        pair[pair_index(units, 1, 3)] += 0.6;
        let v = own_variances(units, &pair).unwrap();
        assert!(v.value[1] > own[1] && v.value[3] > own[3]);
        assert!((v.value[0] - own[0]).abs() < 0.1, "{v:?}");
    }

    #[test]
    fn a_quiet_unit_is_clamped_at_zero_and_said_to_be() {
        // Unit 2's variance is tiny; noise on the pairs makes its least-squares value negative.
        let pair = [2.0 + 3.0, 2.0 + 0.001 + 0.2, 3.0 + 0.001 - 0.3];
        let v = own_variances(3, &pair).unwrap();
        assert!(v.clamped[2] && v.value[2] == 0.0, "{v:?}");
        assert!(v.value.iter().all(|x| *x >= 0.0));
        // Brute force over a grid: nothing feasible fits better.
        let mut best = f64::INFINITY;
        for i in 0..300 {
            for j in 0..300 {
                let (a, b) = (i as f64 * 0.02, j as f64 * 0.02);
                let r = (pair[0] - a - b).powi(2) + (pair[1] - a).powi(2) + (pair[2] - b).powi(2);
                best = best.min(r);
            }
        }
        assert!(v.misfit <= best + 1e-9, "{} vs {best}", v.misfit);
    }

    #[test]
    fn bad_input_is_refused() {
        assert_eq!(own_variances(2, &[1.0]), Err(RedundancyError::Units(2)));
        assert_eq!(
            own_variances(3, &[1.0, 2.0]),
            Err(RedundancyError::Pairs {
                expected: 3,
                given: 2
            })
        );
        assert_eq!(
            own_variances(3, &[1.0, f64::NAN, 2.0]),
            Err(RedundancyError::NotAVariance { pair: 1 })
        );
    }

    /// Three units of white noise sd 0.01, 0.02, 0.04 on a common motion.
    fn three_units(rng: &mut ChaCha8Rng, t: usize, sd: [f32; 3]) -> [[f32; 3]; 3] {
        let motion = [
            (t as f32 * 0.01).sin(),
            (t as f32 * 0.003).cos(),
            0.2 * (t as f32 * 0.02).sin(),
        ];
        core::array::from_fn(|k| {
            core::array::from_fn(|a| {
                let z: f32 = StandardNormal.sample(rng);
                motion[a] + sd[k] * z
            })
        })
    }

    #[test]
    fn the_live_level_is_each_units_own_noise_not_a_mix() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let sd = [0.01f32, 0.02, 0.04];
        let mut live = LiveNoise::<3>::new(0.01, 30.0, MotionThresholds::default());
        for t in 0..60_000 {
            live.push(&three_units(&mut rng, t, sd), [0.0; 3]);
        }
        for (k, truth) in sd.iter().enumerate() {
            let ratio = live.sigma(k) / truth;
            // About 6000 effective samples x 3 axes: within ~4% (1 sigma) for the quietest
            // unit, whose product is the noisiest relative to its size.
            assert!((ratio - 1.0).abs() < 0.12, "unit {k}: {ratio}");
        }
        // A residual around the mean would have given unit 0 sqrt((4 + 4 + 16) / 9) = 1.6
        // times its own level.
    }

    #[test]
    fn the_live_level_in_fixed_point_is_the_one_in_floating_point() {
        use crate::fixed::I32F32;
        // GIVEN three gyros of 1, 2 and 4 mrad/s per sample on a common motion (a quiet
        // triad: its products, 1e-6 (rad/s)², are 4 300 units of Q32.32)
        let mut rng = ChaCha8Rng::seed_from_u64(29);
        let sd = [0.001f32, 0.002, 0.004];
        let mut single = LiveNoise::<3>::new(0.005, 5.0, MotionThresholds::default());
        let mut fixed = LiveNoise::<3, I32F32>::new(0.005, 5.0, MotionThresholds::default());
        let before = crate::fixed::overflows();
        let to_fixed = |v: [f32; 3]| v.map(|x| I32F32::from_f64(f64::from(x)));
        // WHEN both estimate the units' levels from the same samples
        for t in 0..20_000 {
            let set = three_units(&mut rng, t, sd);
            let rate = [0.0, 0.0, 0.1];
            single.push(&set, rate);
            fixed.push(&set.map(to_fixed), to_fixed(rate));
        }
        // THEN the fixed-point levels are the f32 ones to 0.1% (the samples' own rounding to
        // 2^-32 rad/s), each near the unit's truth, and nothing overflowed
        for (k, truth) in sd.iter().enumerate() {
            let (a, b) = (f64::from(single.sigma(k)), fixed.sigma(k).to_f64());
            println!("unit {k}: f32 {a:.6e}, fixed {b:.6e}, truth {truth}");
            assert!((b / a - 1.0).abs() < 1e-3, "unit {k}: f32 {a}, fixed {b}");
            assert!((b / f64::from(*truth) - 1.0).abs() < 0.15, "unit {k}: {b}");
        }
        assert!(fixed.moving() && single.moving());
        assert_eq!(crate::fixed::overflows(), before);
    }

    #[test]
    fn the_live_level_follows_a_noise_burst_and_the_motion_state_has_hysteresis() {
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        let mut live = LiveNoise::<3>::new(0.01, 2.0, MotionThresholds::default());
        let mut states = Vec::new();
        for t in 0..6000 {
            let burst = (2000..4000).contains(&t);
            let sd = if burst { [0.01, 0.08, 0.01] } else { [0.01; 3] };
            // Rate 0.04 rad/s (between the thresholds) after a spin of 0.1 rad/s.
            let rate = if t < 3000 { 0.1 } else { 0.04 };
            live.push(&three_units(&mut rng, t, sd), [0.0, 0.0, rate]);
            if t == 1900 || t == 3900 || t == 5900 {
                states.push((live.sigma(1), live.moving()));
            }
        }
        assert!((states[0].0 / 0.01 - 1.0).abs() < 0.25, "{states:?}");
        assert!((states[1].0 / 0.08 - 1.0).abs() < 0.25, "{states:?}");
        assert!((states[2].0 / 0.01 - 1.0).abs() < 0.3, "{states:?}");
        // Moving at 0.1 rad/s; at 0.04 rad/s (below "moving", above "still") it stays moving.
        assert!(states[0].1 && states[1].1 && states[2].1, "{states:?}");
    }
}
