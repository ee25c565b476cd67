//! Numerical differentiation of sampled series, the one home of the stencils dynacal uses: a
//! nine-point central stencil for signals sampled on their own (nearly even) grid, a plain
//! central difference for derived epoch series (the calibration and the diagnosis), and a
//! streaming sixth-order central difference for filters fed one sample at a time (Fig. 1).
//! Also the median of a sample, used where a check must not move with a few outliers, held
//! whole ([`median`]) or passed over as often as needed ([`select_by_passes`]), and the
//! first bad step of a long series, searched on every core ([`first_bad_step`]).

use nalgebra::{RealField, Vector3};

/// The median of `values` (the upper one of an even count); `None` when empty.
pub fn median(mut values: Vec<f64>) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// Values (or pairs) one core searches at a time in [`first_bad_step`] and
/// [`first_non_finite`]: a search no longer than this stays on one core.
const STRETCH: usize = 1 << 16;

/// The first `i` where `bad(values[i], values[i + 1])`, searched on every core in stretches
/// of consecutive pairs (a long recording's checks of its time column; rayon's own search
/// over `par_windows` pays per pair and took longer than one core). `None`: no such pair.
pub fn first_bad_step(values: &[f64], bad: impl Fn(f64, f64) -> bool + Sync) -> Option<usize> {
    use rayon::prelude::*;
    let pairs = values.len().saturating_sub(1);
    if pairs <= STRETCH {
        return first_bad_pair(values, &bad);
    }
    (0..pairs.div_ceil(STRETCH))
        .into_par_iter()
        .find_map_first(|k| {
            let start = k * STRETCH;
            let end = (start + STRETCH).min(pairs);
            first_bad_pair(&values[start..=end], &bad).map(|i| start + i)
        })
}

/// Values tested together, with no branch among them (so the tests vectorise), before a run
/// that holds a bad one is searched value by value.
const TEST_RUN: usize = 64;

/// The index of the first value that is not finite (a decoded column's check, a series'
/// before its wavelet variance), searched on every core in stretches when long (on one, a
/// 4e6-sample series' test held the other core idle for 4 ms).
pub fn first_non_finite(values: &[f64]) -> Option<usize> {
    use rayon::prelude::*;
    if values.len() <= STRETCH {
        return first_non_finite_on_one_core(values);
    }
    values
        .par_chunks(STRETCH)
        .enumerate()
        .find_map_first(|(k, stretch)| {
            first_non_finite_on_one_core(stretch).map(|i| k * STRETCH + i)
        })
}

/// [`first_non_finite`] on one core, [`TEST_RUN`] values at a time.
fn first_non_finite_on_one_core(values: &[f64]) -> Option<usize> {
    let mut start = 0;
    for run in values.chunks(TEST_RUN) {
        if run.iter().fold(false, |any, v| any | !v.is_finite()) {
            return run.iter().position(|v| !v.is_finite()).map(|i| start + i);
        }
        start += TEST_RUN;
    }
    None
}

/// [`first_bad_step`] on one core, [`TEST_RUN`] pairs at a time.
fn first_bad_pair(values: &[f64], bad: &impl Fn(f64, f64) -> bool) -> Option<usize> {
    let pairs = values.len().saturating_sub(1);
    let (earlier, later) = (&values[..pairs], values.get(1..).unwrap_or_default());
    let mut start = 0;
    for (a, b) in earlier.chunks(TEST_RUN).zip(later.chunks(TEST_RUN)) {
        let any_bad = a.iter().zip(b).fold(false, |any, (&x, &y)| any | bad(x, y));
        if any_bad {
            return a
                .iter()
                .zip(b)
                .position(|(&x, &y)| bad(x, y))
                .map(|i| start + i);
        }
        start += TEST_RUN;
    }
    None
}

/// Bits of a radix digit in [`select_by_passes`]: 2^16 buckets a pass (1.5 MiB of counts and
/// bounds), four passes at most for 64-bit keys after the one that finds their range.
const SELECT_DIGIT_BITS: u32 = 16;

/// `x`'s bits as an unsigned key in the order of [`f64::total_cmp`].
fn total_order_key(x: f64) -> u64 {
    let bits = x.to_bits();
    if bits >> 63 == 1 {
        !bits
    } else {
        bits | (1 << 63)
    }
}

fn from_total_order_key(key: u64) -> f64 {
    f64::from_bits(if key >> 63 == 1 {
        key & !(1 << 63)
    } else {
        !key
    })
}

/// The value of rank `rank` (0-based, in [`f64::total_cmp`] order) among the values each
/// call of `pass` yields, in slices of any length (the same values on every call, in any
/// order; a slice a call keeps the passes' loops tight), in memory that does
/// not grow with their number: what [`median`] gives of a sample held whole, for one that is
/// not (`rank = count / 2`). A first pass finds the values' range; radix selection then runs
/// on the bits below those all the values share, [`SELECT_DIGIT_BITS`] a pass, most
/// significant first, and a pass whose chosen bucket holds one distinct value ends it. So
/// evenly sampled times (steps alike but for their last bits) take two or three passes, and
/// any values five at most. `None` when `rank` is not below the number of values.
pub fn select_by_passes<E>(
    rank: u64,
    mut pass: impl FnMut(&mut dyn FnMut(&[f64])) -> Result<(), E>,
) -> Result<Option<f64>, E> {
    let (mut count, mut least, mut most) = (0u64, u64::MAX, 0u64);
    pass(&mut |values| {
        count += values.len() as u64;
        for &x in values {
            let key = total_order_key(x);
            least = least.min(key);
            most = most.max(key);
        }
    })?;
    if rank >= count {
        return Ok(None);
    }
    // The bits every value shares need no pass (buckets all of one digit would also chain
    // each count on the last).
    let mut known_bits = (least ^ most).leading_zeros();
    if known_bits == 64 {
        return Ok(Some(from_total_order_key(least)));
    }
    let buckets = 1usize << SELECT_DIGIT_BITS;
    let (mut prefix, mut rank) = (least.checked_shr(64 - known_bits).unwrap_or(0), rank);
    let mut counts = vec![0u64; buckets];
    let mut lowest = vec![u64::MAX; buckets];
    let mut highest = vec![0u64; buckets];
    loop {
        counts.fill(0);
        lowest.fill(u64::MAX);
        highest.fill(0);
        let digit_bits = SELECT_DIGIT_BITS.min(64 - known_bits);
        let shift = 64 - known_bits - digit_bits;
        let digit_mask = (1usize << digit_bits) - 1;
        pass(&mut |values| {
            for &x in values {
                let key = total_order_key(x);
                if key.checked_shr(64 - known_bits).unwrap_or(0) != prefix {
                    continue;
                }
                let b = ((key >> shift) as usize) & digit_mask;
                counts[b] += 1;
                lowest[b] = lowest[b].min(key);
                highest[b] = highest[b].max(key);
            }
        })?;
        let Some(b) = (0..buckets).find(|&b| {
            if rank < counts[b] {
                return true;
            }
            rank -= counts[b];
            false
        }) else {
            return Ok(None);
        };
        if lowest[b] == highest[b] {
            return Ok(Some(from_total_order_key(lowest[b])));
        }
        prefix = (prefix << digit_bits) | b as u64;
        known_bits += digit_bits;
    }
}

/// The value of rank `rank` (0-based, in [`f64::total_cmp`] order) among `value(0..n)`:
/// what a copy of the values and [`slice::select_nth_unstable_by`] give, to the bit, without
/// the copy (8 bytes a value of new memory, whose pages cost more than the selection). A
/// sample of the values brackets the rank, one pass (in parallel chunks: the counts and the
/// set of values kept do not depend on their order) counts the values below the bracket and
/// keeps those inside it (a few percent), and the rank is selected among those; where the
/// sample misjudged (the rank falls outside the bracket, or the bracket holds too many) the
/// values are copied after all.
pub fn select_rank(n: usize, value: impl Fn(usize) -> f64 + Sync, rank: usize) -> Option<f64> {
    const SAMPLE: usize = 4096;
    let copied = || {
        let mut all: Vec<u64> = (0..n).map(|i| total_order_key(value(i))).collect();
        from_total_order_key(*all.select_nth_unstable(rank).1)
    };
    if rank >= n {
        return None;
    }
    if n < 16 * SAMPLE {
        return Some(copied());
    }
    let mut sample: Vec<u64> = (0..SAMPLE)
        .map(|k| total_order_key(value(k * (n - 1) / (SAMPLE - 1))))
        .collect();
    sample.sort_unstable();
    // About six standard deviations of the sample's rank either side.
    let at = rank * (SAMPLE - 1) / (n - 1);
    let (lo, hi) = (
        sample[at.saturating_sub(400)],
        sample[(at + 400).min(SAMPLE - 1)],
    );
    let Some(Bracketed {
        below,
        at_lo,
        at_hi,
        mut inside,
    }) = bracket(n, &value, lo, hi)
    else {
        return Some(copied());
    };
    let Some(mut r) = rank.checked_sub(below) else {
        return Some(copied());
    };
    if r < at_lo {
        return Some(from_total_order_key(lo));
    }
    r -= at_lo;
    if r < inside.len() {
        return Some(from_total_order_key(*inside.select_nth_unstable(r).1));
    }
    r -= inside.len();
    if lo != hi && r < at_hi {
        return Some(from_total_order_key(hi));
    }
    Some(copied())
}

/// How `value(0..n)` falls about the total-order keys `lo` <= `hi`: the counts below, at
/// `lo` and at `hi`, and the keys strictly between.
struct Bracketed {
    below: usize,
    at_lo: usize,
    at_hi: usize,
    inside: Vec<u64>,
}

/// [`Bracketed`] of `value(0..n)`, counted in parallel chunks; `None` when more than n / 8
/// fall inside (the sample misjudged the spread: copying is then cheaper).
fn bracket(
    n: usize,
    value: &(impl Fn(usize) -> f64 + Sync),
    lo: u64,
    hi: u64,
) -> Option<Bracketed> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    const CHUNK: usize = 1 << 16;
    let kept = AtomicUsize::new(0);
    let chunks: Option<Vec<Bracketed>> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            if kept.load(Ordering::Relaxed) > n / 8 {
                return None;
            }
            let mut counts = Bracketed {
                below: 0,
                at_lo: 0,
                at_hi: 0,
                inside: Vec::new(),
            };
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let key = total_order_key(value(i));
                if key < lo {
                    counts.below += 1;
                } else if key == lo {
                    counts.at_lo += 1;
                } else if key < hi {
                    counts.inside.push(key);
                } else if key == hi {
                    counts.at_hi += 1;
                }
            }
            kept.fetch_add(counts.inside.len(), Ordering::Relaxed);
            Some(counts)
        })
        .collect();
    if kept.into_inner() > n / 8 {
        return None;
    }
    let chunks = chunks?;
    let mut all = Bracketed {
        below: chunks.iter().map(|c| c.below).sum(),
        at_lo: chunks.iter().map(|c| c.at_lo).sum(),
        at_hi: chunks.iter().map(|c| c.at_hi).sum(),
        inside: Vec::with_capacity(chunks.iter().map(|c| c.inside.len()).sum()),
    };
    for chunk in chunks {
        all.inside.extend(chunk.inside);
    }
    Some(all)
}

/// Values handed to a [`select_by_passes`] visitor a slice at a time, from one at a time.
pub struct Batched<'a> {
    visit: &'a mut dyn FnMut(&[f64]),
    buffer: [f64; 256],
    len: usize,
}

impl<'a> Batched<'a> {
    pub fn new(visit: &'a mut dyn FnMut(&[f64])) -> Self {
        Self {
            visit,
            buffer: [0.0; 256],
            len: 0,
        }
    }

    pub fn push(&mut self, x: f64) {
        self.buffer[self.len] = x;
        self.len += 1;
        if self.len == self.buffer.len() {
            self.flush();
        }
    }

    /// Hands over what is left.
    pub fn finish(mut self) {
        self.flush();
    }

    fn flush(&mut self) {
        (self.visit)(&self.buffer[..self.len]);
        self.len = 0;
    }
}

/// The steps between consecutive times, s, handed to a [`select_by_passes`] visitor: what a
/// median sample interval is selected from.
pub struct TimeSteps<'a> {
    steps: Batched<'a>,
    previous_t_s: Option<f64>,
}

impl<'a> TimeSteps<'a> {
    pub fn new(visit: &'a mut dyn FnMut(&[f64])) -> Self {
        Self {
            steps: Batched::new(visit),
            previous_t_s: None,
        }
    }

    /// The next time, s.
    pub fn push(&mut self, t_s: f64) {
        if let Some(previous) = self.previous_t_s {
            self.steps.push(t_s - previous);
        }
        self.previous_t_s = Some(t_s);
    }

    /// Hands over the steps not yet handed.
    pub fn finish(self) {
        self.steps.finish();
    }
}

/// Derivative of `x` sampled at `t_s` by a nine-point central stencil (exact for polynomials
/// of degree 8; at 200 Hz it keeps a 26 Hz engine vibration's derivative within 0.05%, where
/// a five-point stencil loses 1.3% and a three-point difference on a 100 Hz grid a third,
/// which biases lever arms by as much), falling back to shorter differences at the ends.
/// Units: those of `x` per second.
pub fn stencil_derivative(t_s: &[f64], x: &[f64]) -> Vec<f64> {
    let n = t_s.len();
    (0..n)
        .map(|k| {
            if k >= 4 && k + 4 < n {
                let h = (t_s[k + 4] - t_s[k - 4]) / 8.0;
                let c = [3.0, -32.0, 168.0, -672.0, 0.0, 672.0, -168.0, 32.0, -3.0];
                (0..9).map(|j| c[j] * x[k + j - 4]).sum::<f64>() / (840.0 * h)
            } else if k >= 2 && k + 2 < n {
                let h = (t_s[k + 2] - t_s[k - 2]) / 4.0;
                (x[k - 2] - 8.0 * x[k - 1] + 8.0 * x[k + 1] - x[k + 2]) / (12.0 * h)
            } else if k >= 1 && k + 1 < n {
                (x[k + 1] - x[k - 1]) / (t_s[k + 1] - t_s[k - 1])
            } else if k + 1 < n {
                (x[k + 1] - x[k]) / (t_s[k + 1] - t_s[k])
            } else if k >= 1 {
                (x[k] - x[k - 1]) / (t_s[k] - t_s[k - 1])
            } else {
                0.0
            }
        })
        .collect()
}

/// The two neighbours a central difference at sample `k` of `n` uses (one-sided at the
/// ends); `None` when there are fewer than two samples.
fn central_pair(k: usize, n: usize) -> Option<(usize, usize)> {
    if n < 2 {
        return None;
    }
    Some(if k == 0 {
        (0, 1)
    } else if k == n - 1 {
        (n - 2, n - 1)
    } else {
        (k - 1, k + 1)
    })
}

/// Central-difference derivative of `x` sampled at `t_s` (one-sided at the ends, zero for a
/// single sample). Units: those of `x` per second.
pub fn central_difference(t_s: &[f64], x: &[f64]) -> Vec<f64> {
    let n = x.len();
    (0..n)
        .map(|k| match central_pair(k, n) {
            Some((a, b)) => (x[b] - x[a]) / (t_s[b] - t_s[a]),
            None => 0.0,
        })
        .collect()
}

/// [`central_difference`] of a vector series.
pub fn central_difference_3(t_s: &[f64], x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let n = x.len();
    (0..n)
        .map(|k| match central_pair(k, n) {
            Some((a, b)) => (x[b] - x[a]) / (t_s[b] - t_s[a]),
            None => Vector3::zeros(),
        })
        .collect()
}

/// Weights of the sixth-order central difference [`AngularAccelerationStencil`] applies to
/// `ω[k+j] − ω[k−j]`, j = 1, 2, 3, per `dt`.
pub const STENCIL: [f64; 3] = [45.0 / 60.0, -9.0 / 60.0, 1.0 / 60.0];
/// Half-width of the stencil, samples (also the delay of its output).
pub const STENCIL_HALF: usize = 3;

/// Gain of [`STENCIL`] on a sinusoid of phase step `x = w dt`: its output over the true
/// derivative, `Σ 2 c_j sin(j x) / x`, 1 − O(x^6).
pub fn stencil_gain(x: f64) -> f64 {
    STENCIL
        .iter()
        .enumerate()
        .map(|(j, c)| 2.0 * c * ((j + 1) as f64 * x).sin())
        .sum::<f64>()
        / x
}

/// Angular acceleration by a sixth-order central difference over seven equally spaced
/// samples (the reference's rate in Fig. 1), delayed by three samples: the streaming
/// counterpart of [`stencil_derivative`] for filters that see one sample at a time.
///
/// Why not the core's `RateDifferentiator`: its three-point central difference returns
/// `sin(w dt)/(w dt)` of a vibration line's angular acceleration, 89 % of the car's 26 Hz
/// engine roll and pitch lines at 200 Hz. That scales the modelled `Ω̇ r` down, and the
/// filter answers by scaling the lever arm up: in this simulation both IMUs' lever arms came
/// out 6-7 % too long, ten times their 3σ. This stencil's gain is 0.998 there.
#[derive(Debug, Clone)]
pub struct AngularAccelerationStencil<T, P> {
    window: std::collections::VecDeque<(Vector3<T>, P)>,
}

impl<T: RealField + Copy, P: Copy> Default for AngularAccelerationStencil<T, P> {
    fn default() -> Self {
        Self {
            window: std::collections::VecDeque::with_capacity(2 * STENCIL_HALF + 1),
        }
    }
}

impl<T: RealField + Copy, P: Copy> AngularAccelerationStencil<T, P> {
    /// Pushes the rate `omega_ib_b_rad_s` (rad/s) with its payload; once seven samples are
    /// held, returns the middle one's rate, angular acceleration (rad/s^2) and payload.
    /// `dt_s` is the (constant) sampling interval.
    pub fn push(
        &mut self,
        dt_s: T,
        omega_ib_b_rad_s: Vector3<T>,
        payload: P,
    ) -> Option<(Vector3<T>, Vector3<T>, P)> {
        if self.window.len() == 2 * STENCIL_HALF + 1 {
            self.window.pop_front();
        }
        self.window.push_back((omega_ib_b_rad_s, payload));
        if self.window.len() < 2 * STENCIL_HALF + 1 {
            return None;
        }
        let mid = STENCIL_HALF;
        let mut omega_dot = Vector3::zeros();
        for (j, weight) in STENCIL.iter().enumerate() {
            let w: T = nalgebra::convert(*weight);
            omega_dot += (self.window[mid + j + 1].0 - self.window[mid - j - 1].0) * (w / dt_s);
        }
        let (omega, payload) = self.window[mid];
        Some((omega, omega_dot, payload))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_bad_step_is_found_across_stretches() {
        // A series with steps back at chosen places: the first is found wherever it falls
        // (either side of a stretch's edge, the first and last pair), as a scan finds it.
        let n = 3 * (1 << 16) + 5;
        let increasing = |previous: f64, t: f64| !(t > previous);
        let series: Vec<f64> = (0..n).map(|i| i as f64).collect();
        assert_eq!(first_bad_step(&series, increasing), None);
        assert_eq!(first_bad_step(&[], increasing), None);
        assert_eq!(first_bad_step(&[1.0], increasing), None);
        for bad in [
            &[0][..],
            &[65_534],
            &[65_535],
            &[65_536, 3],
            &[n - 2],
            &[150_000, 70_000],
        ] {
            let mut t = series.clone();
            for &i in bad {
                t[i + 1] = t[i];
            }
            let scanned = t.windows(2).position(|w| increasing(w[0], w[1]));
            assert_eq!(first_bad_step(&t, increasing), scanned, "{bad:?}");
            assert_eq!(scanned, bad.iter().min().copied());
        }
    }

    #[test]
    fn a_short_series_is_searched_run_by_run_as_a_scan_finds_it() {
        // One stretch, searched on one core 64 pairs at a time: a bad pair either side of a
        // run's edge, alone or after another, is the first found.
        let increasing = |previous: f64, t: f64| !(t > previous);
        let series: Vec<f64> = (0..200).map(|i| i as f64).collect();
        for bad in [
            &[0][..],
            &[62],
            &[63],
            &[64],
            &[127, 128],
            &[190, 70],
            &[198],
        ] {
            let mut t = series.clone();
            for &i in bad {
                t[i + 1] = t[i] - 1.0;
            }
            assert_eq!(
                first_bad_step(&t, increasing),
                bad.iter().min().copied(),
                "{bad:?}"
            );
        }
        let mut x = series.clone();
        assert_eq!(first_non_finite(&x), None);
        x[130] = f64::INFINITY;
        x[64] = f64::NAN;
        assert_eq!(first_non_finite(&x), Some(64));
        x[63] = f64::NEG_INFINITY;
        assert_eq!(first_non_finite(&x), Some(63));
        assert_eq!(first_non_finite(&[]), None);
    }

    #[test]
    fn the_first_non_finite_value_is_found_across_stretches() {
        let n = 3 * STRETCH + 777;
        let clean: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
        assert_eq!(first_non_finite(&clean), None);
        for bad in [
            &[0][..],
            &[STRETCH - 1],
            &[STRETCH],
            &[2 * STRETCH + 5, STRETCH + 3],
            &[3 * STRETCH + 1, 2 * STRETCH + 64],
            &[n - 1],
        ] {
            let mut x = clean.clone();
            for &i in bad {
                x[i] = if i % 2 == 0 { f64::NAN } else { f64::INFINITY };
            }
            assert_eq!(first_non_finite(&x), bad.iter().min().copied(), "{bad:?}");
        }
    }

    #[test]
    fn stencil_is_exact_on_an_octic_and_central_on_a_quadratic() {
        let t: Vec<f64> = (0..40)
            .map(|k| 0.01 * k as f64 + 0.003 * (k % 2) as f64 * 0.0)
            .collect();
        let x: Vec<f64> = t.iter().map(|t| t.powi(8) - 3.0 * t.powi(3)).collect();
        let d = stencil_derivative(&t, &x);
        for k in 4..36 {
            let exact = 8.0 * t[k].powi(7) - 9.0 * t[k].powi(2);
            assert!((d[k] - exact).abs() < 1e-9, "k {k}: {} vs {exact}", d[k]);
        }
        let q: Vec<f64> = t.iter().map(|t| 2.0 * t * t).collect();
        let c = central_difference(&t, &q);
        for k in 1..39 {
            assert!((c[k] - 4.0 * t[k]).abs() < 1e-12);
        }
        assert_eq!(central_difference(&[0.0], &[1.0]), vec![0.0]);
    }

    #[test]
    fn rank_selection_without_a_copy_is_the_sorted_value() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let n = 200_000;
        let t_s: Vec<f64> = (0..=n).map(|k| k as f64 * 0.01).collect();
        let cases: Vec<(&str, Vec<f64>)> = vec![
            (
                "random",
                (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
            ),
            ("time steps", t_s.windows(2).map(|w| w[1] - w[0]).collect()),
            // Every value the sample sees is 0, the rest 1: the bracket misjudges.
            ("against the sample", {
                let mut v = vec![1.0; n];
                (0..4096).for_each(|k| v[k * (n - 1) / 4095] = 0.0);
                v
            }),
            ("sorted", (0..n).map(|i| i as f64).collect()),
            ("equal", vec![-0.0; n]),
            (
                "signed zeros",
                (0..n)
                    .map(|i| if i % 3 == 0 { 0.0 } else { -0.0 })
                    .collect(),
            ),
        ];
        for (name, values) in cases {
            let mut sorted = values.clone();
            sorted.sort_by(f64::total_cmp);
            for rank in [0, 1, n / 3, n / 2, n - 1, rng.random_range(0..n)] {
                let got = select_rank(n, |i| values[i], rank).map(f64::to_bits);
                assert_eq!(got, Some(sorted[rank].to_bits()), "{name}, rank {rank}");
            }
            assert_eq!(select_rank(n, |i| values[i], n), None);
        }
    }

    #[test]
    fn selection_by_passes_is_the_sorted_sample_at_its_rank() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut mixed: Vec<f64> = (0..5001)
            .map(|_| rng.random_range(-1e3..1e3) * 10f64.powi(rng.random_range(-12..12)))
            .collect();
        mixed.extend([0.0, -0.0, f64::INFINITY, -1e300, 1e-300, 7.0, 7.0]);
        let steps: Vec<f64> = (0..4000)
            .map(|k| if k % 7 == 0 { 0.011 } else { 0.01 })
            .collect();
        for values in [mixed, steps, vec![3.5]] {
            let mut sorted = values.clone();
            sorted.sort_by(f64::total_cmp);
            let mut passes = 0;
            for rank in [0, sorted.len() / 3, sorted.len() / 2, sorted.len() - 1] {
                let got = select_by_passes::<()>(rank as u64, |visit| {
                    passes += 1;
                    visit(&values);
                    Ok(())
                })
                .unwrap();
                assert_eq!(
                    got.map(f64::to_bits),
                    Some(sorted[rank].to_bits()),
                    "rank {rank}"
                );
            }
            assert!(passes <= 20, "{passes} passes for four ranks");
            assert_eq!(
                median(values.clone()),
                sorted.get(sorted.len() / 2).copied()
            );
        }
        // A time column's steps, alike but for their last bits: the range pass and two.
        let t_s: Vec<f64> = (0..400_000).map(|k| k as f64 * 0.01).collect();
        let mut steps: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
        let mut passes = 0;
        let got = select_by_passes::<()>(steps.len() as u64 / 2, |visit| {
            passes += 1;
            visit(&steps);
            Ok(())
        });
        let mid = steps.len() / 2;
        let want = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
        assert_eq!(got.unwrap().map(f64::to_bits), Some(want.to_bits()));
        assert!(passes <= 3, "{passes} passes over a time column's steps");
        let beyond = select_by_passes::<()>(3, |visit| {
            visit(&[1.0, 2.0]);
            Ok(())
        });
        assert_eq!(beyond, Ok(None));
    }
}
