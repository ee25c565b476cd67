//! Streaming Haar wavelet variance of one channel of an arbitrarily long float series: one
//! sample at a time, in memory fixed by the number of full levels, for `dynacal wv` on
//! recordings too long to hold (`crate::input::stream`).
//!
//! Levels `1..=full_levels` are the batch estimator ([`super::haar_wv`]) itself: every
//! overlapping (MODWT) coefficient, from a ring of the last 2^full_levels prefix sums, so
//! their variances equal the batch ones (to rounding, ~1e-12 relative) and get the same
//! eta3 intervals. Higher levels are decimated as the board's
//! [`dynacal_core::wavelet::HaarStream`] decimates them: level j uses only the coefficients at
//! sample counts that are multiples of its half-width h = 2^{j-1}, and gets eta =
//! max(2K/9, 1) degrees of freedom from K coefficients (4/9 of what K h overlapping
//! coefficients would give: see `dynacal_core::wavelet` for the measured cost).
//! [`HaarWvStream::oversampled`] takes them every h/2^s samples instead, nearly as steady
//! as the overlapping level for s = 4 in a ring of 2^(s+1) prefix sums a level: for
//! `crate::diagnose`, which compares a level only with the same estimator on simulations.
//!
//! Numerics: prefix sums of 1e8 samples in plain f64 would lose the digits the Haar
//! differences live in, so each sample minus the first is added exactly (TwoSum) into a
//! double-double running sum. For integer counts below 2^53 every prefix sum, and hence every
//! Haar difference, is exact, as in [`super::haar_wv_counts`]; for floats each sample enters
//! exactly and the sums keep about 32 digits; each Haar difference is formed from the sums'
//! parts ([`haar_difference`]), within a rounding or two of its exact value. A full level's
//! squared differences are summed plainly in groups of 4 096 (eight lanes), the groups' sums
//! with a TwoSum compensation, as the batch estimator sums its blocks.

use super::{eta3, two_sum, WaveletVariance, WvError};

/// A double-double number: the unevaluated sum hi + lo, |lo| <= ulp(hi) / 2.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct DoubleDouble {
    hi: f64,
    lo: f64,
}

impl DoubleDouble {
    /// self + (big + small), with |small| <= ulp(big) / 2 (the parts of an exact difference):
    /// `big` added exactly (TwoSum), `small` with the low parts, then renormalised, one
    /// TwoSum on the running sum's chain per sample instead of one per part.
    fn add_parts(self, big: f64, small: f64) -> Self {
        let (s, e) = two_sum(self.hi, big);
        let (hi, lo) = fast_two_sum(s, e + (self.lo + small));
        Self { hi, lo }
    }
}

/// The unscaled Haar difference (S_k - S_{k-h}) - (S_{k-h} - S_{k-2h}) from the three
/// double-double prefix sums `now`, `half` and `whole` (S_k, S_{k-h}, S_{k-2h}). Each window
/// sum is taken part by part: the high parts of neighbouring sums are within a factor of two
/// of each other wherever the window sum is small beside them (where digits are at risk), so
/// their difference is exact (Sterbenz), and each window sum is within a rounding of its
/// exact value; the difference of the two is then rounded once more, as the batch estimator
/// rounds its f64 prefix sums. A fifth of the arithmetic of double-double subtractions, with
/// no dependence between coefficients, so it vectorises.
#[inline(always)]
fn haar_difference(now: DoubleDouble, half: DoubleDouble, whole: DoubleDouble) -> f64 {
    haar_difference_parts([now.hi, half.hi, whole.hi], [now.lo, half.lo, whole.lo])
}

/// [`haar_difference`] of the sums' high parts `hi` and low parts `lo` (S_k, S_{k-h},
/// S_{k-2h} each), as the ring holds them.
#[inline(always)]
fn haar_difference_parts(hi: [f64; 3], lo: [f64; 3]) -> f64 {
    let recent = (hi[0] - hi[1]) + (lo[0] - lo[1]);
    let older = (hi[1] - hi[2]) + (lo[1] - lo[2]);
    recent - older
}

/// Dekker's FastTwoSum, |a| >= |b|: a + b = s + e exactly.
fn fast_two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    (s, b - (s - a))
}

/// A running sum of many positive terms with its compensation (Kahan-Babuska via TwoSum).
#[derive(Debug, Clone, Copy, Default)]
struct CompensatedSum {
    sum: f64,
    compensation: f64,
}

impl CompensatedSum {
    fn add(&mut self, value: f64) {
        let (s, e) = two_sum(self.sum, value);
        self.sum = s;
        self.compensation += e;
    }

    fn value(&self) -> f64 {
        self.sum + self.compensation
    }
}

/// Coefficients computed at a time in [`HaarWvStream::push_block`].
const SEGMENT: usize = 256;

/// The last k' <= `last_k`, at most [`SEGMENT`] - 1 past `k`, such that for every offset
/// `back` the ring slots of k - back .. k' - back do not wrap around (`mask` = ring length - 1).
#[inline(always)]
fn segment_end(k: u64, last_k: u64, backs: &[u64], mask: u64) -> u64 {
    let mut end = last_k.min(k + SEGMENT as u64 - 1);
    for &back in backs {
        let to_wrap = mask - ((k - back) & mask);
        end = end.min(k + to_wrap);
    }
    end
}

/// Coefficients whose squares are summed plainly before their sum joins a level's
/// compensated total, by the sample a coefficient ends at (k / group), as the batch
/// estimator sums a block of positions in plain lanes: a plain addition costs a fraction of
/// a compensated one, and a group's 4 096 squares in eight lanes lose at most 512 roundings.
/// A group is summed once every prefix sum it reads is in the ring, every level over it in
/// turn, so the ring's stretches a group reads stay in the core's cache from one level to
/// the next (each level's older window is the next level's middle one).
const GROUP: u64 = 1 << 12;

/// A full level's sum of squared coefficients over the groups summed so far.
#[derive(Debug, Clone, Copy, Default)]
struct LevelSums {
    finished: CompensatedSum,
    count: u64,
}

impl LevelSums {
    /// Adds one group's sum of squares and its number of coefficients (none: nothing).
    fn add_group(&mut self, (squares, count): (f64, u64)) {
        if count > 0 {
            self.finished.add(squares);
            self.count += count;
        }
    }
}

/// The eight lanes' sum, always in the same order.
fn lanes_total(lanes: &[f64; 8]) -> f64 {
    ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3]))
        + ((lanes[4] + lanes[5]) + (lanes[6] + lanes[7]))
}

/// Adds the squared coefficients of one run (ending at samples `k`, `k + 1`, ...; the
/// runs of S_k, S_{k-h} and S_{k-2h}, high parts in `hi`, low parts in `lo`) to lanes
/// (k + i) mod 8: the same additions as one at a time, eight abreast where the run is
/// aligned, so the squares are formed and added in vector registers.
#[inline(always)]
fn add_run_to_lanes(lanes: &mut [f64; 8], k: u64, hi: [&[f64]; 3], lo: [&[f64]; 3]) {
    let square = |i: usize| {
        let d = haar_difference_parts(
            [hi[0][i], hi[1][i], hi[2][i]],
            [lo[0][i], lo[1][i], lo[2][i]],
        );
        d * d
    };
    let n = hi[0].len();
    let lead = ((k.wrapping_neg() % 8) as usize).min(n);
    for i in 0..lead {
        lanes[((k + i as u64) % 8) as usize] += square(i);
    }
    let octets = (n - lead) / 8;
    let octet = |part: &[f64], first: usize| -> [f64; 8] {
        part[first..first + 8].try_into().expect("eight")
    };
    for o in 0..octets {
        let first = lead + 8 * o;
        let (h, l) = (hi.map(|p| octet(p, first)), lo.map(|p| octet(p, first)));
        for (j, lane) in lanes.iter_mut().enumerate() {
            let d = haar_difference_parts([h[0][j], h[1][j], h[2][j]], [l[0][j], l[1][j], l[2][j]]);
            *lane += d * d;
        }
    }
    let done = lead + 8 * octets;
    for (j, lane) in lanes.iter_mut().enumerate().take(n - done) {
        *lane += square(done + j);
    }
}

/// The sum of squared Haar coefficients of half-width `h` ending at samples `first..=last`,
/// from the prefix-sum ring `ring` (S_k at k mod its length, a power of two). Compiled
/// again for the wider vector units of the machine it runs on (chosen when first called):
/// the same operations in the same order, so the same result to the bit on any of them.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn level_squares<'r>(ring: &'r PrefixRing, h: u64, first: u64, last: u64) -> f64 {
    let mask = ring.hi.len() as u64 - 1;
    let mut lanes = [0.0f64; 8];
    let mut k = first;
    while k <= last {
        // A run of coefficients whose three prefix sums lie in unbroken stretches of the
        // ring: computed independently of each other (vectorised), added in order.
        let end = segment_end(k, last, &[0, h, 2 * h], mask);
        let n = (end - k + 1) as usize;
        let slot = |back: u64| ((k - back) & mask) as usize;
        let run = |part: &'r [f64], back: u64| -> &'r [f64] { &part[slot(back)..slot(back) + n] };
        add_run_to_lanes(
            &mut lanes,
            k,
            [run(&ring.hi, 0), run(&ring.hi, h), run(&ring.hi, 2 * h)],
            [run(&ring.lo, 0), run(&ring.lo, h), run(&ring.lo, 2 * h)],
        );
        k = end + 1;
    }
    lanes_total(&lanes)
}

/// The last prefix sums, S_k at k mod the length (a power of two), their high and low parts
/// in arrays of their own so that a run of coefficients loads each part in whole vectors.
#[derive(Debug, Clone)]
struct PrefixRing {
    hi: Vec<f64>,
    lo: Vec<f64>,
}

impl PrefixRing {
    fn new(len: usize) -> Self {
        Self {
            hi: vec![0.0; len],
            lo: vec![0.0; len],
        }
    }

    fn store(&mut self, slot: usize, sum: DoubleDouble) {
        self.hi[slot] = sum.hi;
        self.lo[slot] = sum.lo;
    }
}

/// One decimated level: its prefix sums at the last 2^(oversampling + 1) multiples of its
/// spacing g = h / 2^oversampling, the two a coefficient at the next multiple reads among them
/// (S_{k-h} and S_{k-2h}).
#[derive(Debug, Clone, Default)]
struct DecimatedLevel {
    /// ring[m mod len] = S_{m g}; zero (S_0) before the multiple m is passed.
    previous: Vec<DoubleDouble>,
    squares: CompensatedSum,
    count: u64,
}

/// The streaming Haar wavelet variance of one channel (see the module documentation).
///
/// Memory: 16 bytes per sample of the ring (2^(full_levels + 1) of them: the widest level
/// reads 2^full_levels back, and a block of up to 2^(full_levels - 1) samples is summed
/// before the levels read it) plus about 64 bytes per level: 8 MiB for the default
/// [`Self::DEFAULT_FULL_LEVELS`] = 18.
#[derive(Debug, Clone)]
pub struct HaarWvStream {
    full_levels: u32,
    /// ring[k mod 2^(full_levels + 1)] = S_k, k = number of samples summed.
    ring: PrefixRing,
    sum: DoubleDouble,
    /// The first sample: subtracted from every sample so the sums stay small (the Haar
    /// filter ignores any constant).
    origin: Option<f64>,
    n: u64,
    full: Vec<LevelSums>,
    /// Coefficients ending at samples 1..=summed_to are in `full`; the rest, fewer than a
    /// group, wait for their group to fill.
    summed_to: u64,
    /// Decimated level j takes its coefficients every h / 2^oversampling samples.
    oversampling: u32,
    decimated: Vec<DecimatedLevel>,
}

impl HaarWvStream {
    /// Full levels 1..=18: every level of a recording under 2^20 samples at the default
    /// maximum level floor(log2 N) - 1, so such recordings get the batch estimator whole.
    pub const DEFAULT_FULL_LEVELS: u32 = 18;

    /// Full levels 1..=16, 2 MiB of ring: for analyses that keep many streams at once (a
    /// long run's pairs and channels, a still stretch's axes).
    pub const COMPACT_FULL_LEVELS: u32 = 16;

    /// Levels the stream can hold: enough for 2^62 samples.
    const MAX_LEVELS: u32 = 62;

    /// A stream with `full_levels` overlapping levels (1..=30) and decimated ones above, up
    /// to level 62.
    pub fn new(full_levels: u32) -> Self {
        Self::oversampled(full_levels, 0)
    }

    /// A stream whose decimated levels take a coefficient every h / 2^`oversampling`
    /// samples (`oversampling` clamped to 0..=min(full_levels, 8); [`Self::new`] is 0, the
    /// board's decimation), from a ring of 2^(oversampling + 1) prefix sums per level. Where the levels are only compared with the same estimator on simulations
    /// (`crate::diagnose`), 4 makes a wide level almost as steady as the overlapping one
    /// (measured in this module's tests) in 0.5 KiB a level, not 2^level samples.
    pub fn oversampled(full_levels: u32, oversampling: u32) -> Self {
        let full_levels = full_levels.clamp(1, 30);
        let oversampling = oversampling.min(full_levels).min(8);
        let level = DecimatedLevel {
            previous: vec![DoubleDouble::default(); 2 << oversampling],
            ..Default::default()
        };
        Self {
            full_levels,
            ring: PrefixRing::new(2 << full_levels),
            sum: DoubleDouble::default(),
            origin: None,
            n: 0,
            full: vec![LevelSums::default(); full_levels as usize],
            summed_to: 0,
            oversampling,
            decimated: vec![level; (Self::MAX_LEVELS - full_levels) as usize],
        }
    }

    /// Samples pushed so far.
    pub fn len(&self) -> u64 {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Adds one sample (any unit; finite, checked by the reader).
    pub fn push(&mut self, value: f64) {
        self.push_block(std::slice::from_ref(&value));
    }

    /// Adds samples in order; the same result, bit for bit, as pushing them one by one, in
    /// a fraction of the time on long blocks: their prefix sums are stored first, then the
    /// groups of coefficients they complete are summed (on every core), each reading the
    /// ring in order rather than at 18 scattered places per sample.
    pub fn push_block(&mut self, values: &[f64]) {
        for chunk in values.chunks(1usize << (self.full_levels - 1)) {
            self.store_prefix_sums(chunk);
            self.add_full_groups();
        }
    }

    /// S_k of each sample into the ring, and the decimated levels at their multiples.
    fn store_prefix_sums(&mut self, values: &[f64]) {
        let ring_mask = self.ring.hi.len() as u64 - 1;
        let period_mask = (1u64 << (self.full_levels - self.oversampling)) - 1;
        for &value in values {
            let origin = *self.origin.get_or_insert(value);
            // value - origin exactly, as a double-double (both parts enter the running sum).
            let (difference, rounding) = two_sum(value, -origin);
            self.sum = self.sum.add_parts(difference, rounding);
            self.n += 1;
            self.ring.store((self.n & ring_mask) as usize, self.sum);
            if self.n & period_mask == 0 {
                self.push_decimated(self.n);
            }
        }
    }

    /// Coefficients a group holds: [`GROUP`], or half the widest full level's reach where
    /// that is less (the ring holds a waiting group beside the block being added).
    fn group(&self) -> u64 {
        GROUP.min(1 << (self.full_levels - 1))
    }

    /// Sums the groups of coefficients the ring now holds whole (on every core when there
    /// are several), each group's level sums added in order.
    fn add_full_groups(&mut self) {
        use rayon::prelude::*;
        let g = self.group();
        let whole_groups = (self.n + 1) / g;
        let first_group = (self.summed_to + 1) / g;
        if whole_groups <= first_group {
            return;
        }
        // Group i holds the coefficients ending at samples i g ..= i g + g - 1 (none ends at 0).
        let group_sums = |i: u64| self.group_squares((i * g).max(1), i * g + g - 1);
        let sums: Vec<Vec<(f64, u64)>> = if whole_groups - first_group > 1 {
            (first_group..whole_groups)
                .into_par_iter()
                .map(group_sums)
                .collect()
        } else {
            (first_group..whole_groups).map(group_sums).collect()
        };
        for group in &sums {
            for (level, &level_group) in self.full.iter_mut().zip(group) {
                level.add_group(level_group);
            }
        }
        self.summed_to = whole_groups * g - 1;
    }

    /// Each full level's sum of squared coefficients ending at samples `first..=last` (one
    /// group or the start of one: their prefix sums and the 2^full_levels before them are
    /// in the ring) and their number.
    fn group_squares(&self, first: u64, last: u64) -> Vec<(f64, u64)> {
        (0..self.full_levels)
            .map(|index| {
                let h = 1u64 << index;
                let start = first.max(2 * h);
                if start > last {
                    return (0.0, 0);
                }
                let squares = level_squares(&self.ring, h, start, last);
                (squares, last - start + 1)
            })
            .collect()
    }

    /// The decimated levels at a multiple k of 2^(full_levels - oversampling): level j takes
    /// the coefficient at k when its spacing g = 2^(j - 1 - oversampling) divides k.
    fn push_decimated(&mut self, k: u64) {
        let first_level = self.full_levels + 1;
        let oversampling = self.oversampling;
        for (index, level) in self.decimated.iter_mut().enumerate() {
            let spacing = 1u64 << (first_level + index as u32 - 1 - oversampling);
            if !k.is_multiple_of(spacing) {
                break;
            }
            let len = level.previous.len() as u64;
            let m = k / spacing;
            // The ring starts as S_0 everywhere: the first coefficient is at k = 2h, m = len.
            if m >= len {
                let half = level.previous[((m - len / 2) % len) as usize];
                let whole = level.previous[(m % len) as usize];
                let d = haar_difference(self.sum, half, whole);
                level.squares.add(d * d);
                level.count += 1;
            }
            level.previous[(m % len) as usize] = self.sum;
        }
    }

    /// The wavelet variance of levels 1..=`max_level` in the square of `unit` (physical units
    /// per input unit) with `dt_s` seconds per sample; `max_level` `None` is the batch
    /// default floor(log2 N) - 1. Levels beyond `full_levels` are the decimated estimates,
    /// with their wider intervals; `n_coefficients` holds the coefficients actually used.
    pub fn wavelet_variance(
        &self,
        max_level: Option<u32>,
        unit: f64,
        dt_s: f64,
    ) -> Result<WaveletVariance, WvError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(WvError::BadInterval { dt_s });
        }
        let n = self.n as usize;
        if n < 4 {
            return Err(WvError::TooShort { n });
        }
        let top = n.ilog2();
        let j_max = match max_level {
            None => super::default_max_level(n),
            Some(j) if (1..=top).contains(&j) => j,
            Some(j) => {
                return Err(WvError::BadLevel {
                    requested: j,
                    max: top,
                    n,
                })
            }
        };
        let waiting = self.group_squares(self.summed_to + 1, self.n);
        let (mut levels, mut variance, mut m, mut eta) = (vec![], vec![], vec![], vec![]);
        for j in 1..=j_max {
            let (squares, count, dof) = if j <= self.full_levels {
                let mut level = self.full[j as usize - 1];
                level.add_group(waiting[j as usize - 1]);
                (level.finished, level.count, eta3(level.count as usize, j))
            } else {
                let level = &self.decimated[(j - self.full_levels - 1) as usize];
                let dof = match self.oversampling {
                    0 => decimated_dof(level.count),
                    // Coefficients h / 2^s apart stand in for the 2^s times as many overlapping
                    // ones (eta3 of those): measured close at s = 4 in the tests.
                    s => eta3((level.count << s) as usize, j),
                };
                (level.squares, level.count, dof)
            };
            if count == 0 {
                // A decimated level wider than half the series has no coefficient yet.
                break;
            }
            let width = (1u64 << j) as f64;
            levels.push(j);
            variance.push(squares.value() / (width * width) / count as f64 * unit * unit);
            m.push(count as usize);
            eta.push(dof);
        }
        Ok(WaveletVariance::from_levels(
            levels, variance, m, eta, n, dt_s, false,
        ))
    }

    /// Number of full (overlapping, batch-equal) levels; higher ones are decimated.
    pub fn full_levels(&self) -> u32 {
        self.full_levels
    }
}

/// Equivalent degrees of freedom of a decimated level's variance from its `count`
/// coefficients: max(2K/9, 1) (see the module's note).
pub fn decimated_dof(count: u64) -> f64 {
    (2.0 * count as f64 / 9.0).max(1.0)
}

#[cfg(test)]
mod tests {
    use super::super::{haar_wv, haar_wv_counts, WvOptions};
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// White noise plus a random walk on a large offset.
    fn drifting(seed: u64, n: usize, offset: f64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 1.0).unwrap();
        let step = Normal::new(0.0, 0.01).unwrap();
        let mut walk = 0.0;
        (0..n)
            .map(|_| {
                walk += step.sample(&mut rng);
                offset + walk + noise.sample(&mut rng)
            })
            .collect()
    }

    #[test]
    fn blocks_of_any_size_give_the_one_by_one_result_to_the_bit() {
        // Few full levels, so blocks span the chunking (2^(full_levels - 1)) and the
        // decimated levels' multiples.
        let x = drifting(13, 70_000, 3e3);
        for full_levels in [5, 12] {
            let mut one_by_one = HaarWvStream::new(full_levels);
            x.iter().for_each(|&v| one_by_one.push(v));
            let mut blocks = HaarWvStream::new(full_levels);
            let mut rng = ChaCha8Rng::seed_from_u64(full_levels as u64);
            let mut rest = x.as_slice();
            while !rest.is_empty() {
                let size = rand::Rng::random_range(&mut rng, 1..9_000).min(rest.len());
                let (block, tail) = rest.split_at(size);
                blocks.push_block(block);
                rest = tail;
            }
            assert_eq!(
                blocks.wavelet_variance(None, 1.0, 0.01).unwrap(),
                one_by_one.wavelet_variance(None, 1.0, 0.01).unwrap()
            );
        }
    }

    #[test]
    fn full_levels_equal_the_batch_estimator_on_floats() {
        let x = drifting(11, 50_000, 1e4);
        let batch = haar_wv(&x, 0.01, &WvOptions::default()).unwrap();
        let mut stream = HaarWvStream::new(20);
        x.iter().for_each(|&v| stream.push(v));
        let streamed = stream.wavelet_variance(None, 1.0, 0.01).unwrap();
        assert_eq!(streamed.levels, batch.levels);
        assert_eq!(streamed.n_coefficients, batch.n_coefficients);
        for i in 0..batch.len() {
            let relative = (streamed.variance[i] / batch.variance[i] - 1.0).abs();
            assert!(relative < 1e-12, "level {}: {relative:e}", i + 1);
            assert!((streamed.ci_low[i] / batch.ci_low[i] - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn a_large_offset_and_a_random_walk_keep_their_digits_when_streamed() {
        // The batch estimator's hard case (`wv::tests`): 1 g of offset, a random-walk bias and
        // 1e-3 of noise in exact counts of 1e-6 g, streamed as floats in blocks that cross
        // the groups, against the exact integer sums; the first sample far from the rest, so
        // the sums relative to it grow by 0.05 g a sample.
        let n = (1 << 20) + 12_345;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 1000.0).unwrap();
        let walk = Normal::new(0.0, 3.0).unwrap();
        let mut bias = 0.0f64;
        let mut counts: Vec<i32> = (0..n)
            .map(|_| {
                bias += walk.sample(&mut rng);
                (1_000_000.0 + bias + noise.sample(&mut rng)).round() as i32
            })
            .collect();
        counts[0] = 950_000;
        let lsb = 1e-6;
        let exact = haar_wv_counts(&counts, lsb, 0.01, &WvOptions::default()).unwrap();
        let mut stream = HaarWvStream::new(HaarWvStream::DEFAULT_FULL_LEVELS);
        let x: Vec<f64> = counts.iter().map(|&c| c as f64 * lsb).collect();
        x.chunks(100_003).for_each(|block| stream.push_block(block));
        let streamed = stream.wavelet_variance(None, 1.0, 0.01).unwrap();
        for i in 0..HaarWvStream::DEFAULT_FULL_LEVELS as usize {
            assert_eq!(streamed.n_coefficients[i], exact.n_coefficients[i]);
            let err = ((streamed.variance[i] - exact.variance[i]) / exact.variance[i]).abs();
            assert!(err < 1e-11, "level {}: {err:e}", i + 1);
        }
    }

    #[test]
    fn integer_counts_equal_the_exact_batch_sums() {
        let counts: Vec<i32> = drifting(12, 40_000, 2e6)
            .iter()
            .map(|v| (v * 100.0).round() as i32)
            .collect();
        let batch = haar_wv_counts(&counts, 1e-3, 0.01, &WvOptions::default()).unwrap();
        let mut stream = HaarWvStream::new(18);
        counts.iter().for_each(|&c| stream.push(c as f64));
        let streamed = stream.wavelet_variance(None, 1e-3, 0.01).unwrap();
        for i in 0..batch.len() {
            let relative = (streamed.variance[i] / batch.variance[i] - 1.0).abs();
            assert!(relative < 1e-13, "level {}: {relative:e}", i + 1);
        }
    }

    #[test]
    fn decimated_levels_match_the_board_stream_and_have_wider_intervals() {
        // The board's integer stream with 4 full levels is the reference for the decimated
        // sums: same coefficients, so the same variance, counts and degrees of freedom.
        let counts: Vec<i32> = drifting(13, 1 << 14, 0.0)
            .iter()
            .map(|v| (v * 1000.0).round() as i32)
            .collect();
        let mut board = dynacal_core::wavelet::HaarStream::<4, 16, 12>::new();
        let mut stream = HaarWvStream::new(4);
        for &c in &counts {
            board.push(c);
            stream.push(c as f64);
        }
        let reference =
            WaveletVariance::from_stream_snapshot(&board.snapshot(), 1.0, 0.01).unwrap();
        let streamed = stream.wavelet_variance(Some(12), 1.0, 0.01).unwrap();
        assert_eq!(streamed.levels, reference.levels[..streamed.len()]);
        for i in 0..streamed.len() {
            assert_eq!(
                streamed.n_coefficients[i],
                reference.n_coefficients[i],
                "level {}",
                i + 1
            );
            let relative = (streamed.variance[i] / reference.variance[i] - 1.0).abs();
            assert!(relative < 1e-12, "level {}: {relative:e}", i + 1);
            assert!((streamed.ci_high[i] / reference.ci_high[i] - 1.0).abs() < 1e-9);
        }
        let batch = haar_wv_counts(
            &counts,
            1.0,
            0.01,
            &WvOptions {
                max_level: Some(12),
                ..Default::default()
            },
        )
        .unwrap();
        let width = |w: &WaveletVariance, i: usize| (w.ci_high[i] - w.ci_low[i]) / w.variance[i];
        assert!(width(&streamed, 6) > 1.3 * width(&batch, 6));
    }

    /// Level j's variance from the Haar coefficients ending at every multiple of `spacing`
    /// from 2h on, straight from the definition (the oracle of the oversampled levels).
    fn variance_every(x: &[f64], level: u32, spacing: usize) -> (f64, usize) {
        let h = 1usize << (level - 1);
        let mut sums = vec![0.0f64];
        for v in x {
            sums.push(sums.last().unwrap() + (v - x[0]));
        }
        let (mut squares, mut count) = (0.0, 0);
        for k in (2 * h..=x.len()).step_by(spacing) {
            let d = (sums[k] - sums[k - h]) - (sums[k - h] - sums[k - 2 * h]);
            squares += d * d;
            count += 1;
        }
        let width = (2 * h) as f64;
        (squares / (width * width) / count as f64, count)
    }

    #[test]
    fn oversampled_levels_take_the_coefficients_every_h_over_2_to_the_s() {
        let x = drifting(14, 60_000, 50.0);
        let (full_levels, oversampling) = (6, 3);
        let mut stream = HaarWvStream::oversampled(full_levels, oversampling);
        for block in x.chunks(7_777) {
            stream.push_block(block);
        }
        let wv = stream.wavelet_variance(Some(13), 1.0, 0.01).unwrap();
        for level in full_levels + 1..=13 {
            let spacing = 1usize << (level - 1 - oversampling);
            let (variance, count) = variance_every(&x, level, spacing);
            let i = level as usize - 1;
            assert_eq!(wv.n_coefficients[i], count, "level {level}");
            let relative = (wv.variance[i] / variance - 1.0).abs();
            assert!(relative < 1e-9, "level {level}: {relative:e}");
        }
    }

    #[test]
    fn oversampled_by_4_a_wide_level_is_almost_as_steady_as_the_overlapping_one() {
        // Level 11 of white noise (2^13 samples): the log variance's spread over 200 seeds,
        // overlapping (batch), decimated to multiples of h, and every h/16, all 4 full levels.
        let spread = |values: &[f64]| {
            let mean = values.iter().sum::<f64>() / values.len() as f64;
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
        };
        let (mut batch, mut decimated, mut oversampled) = (vec![], vec![], vec![]);
        for seed in 0..200 {
            let mut rng = ChaCha8Rng::seed_from_u64(1_000 + seed);
            let x: Vec<f64> = (0..1 << 13)
                .map(|_| Normal::new(0.0, 1.0).unwrap().sample(&mut rng))
                .collect();
            let options = WvOptions {
                max_level: Some(11),
                ..Default::default()
            };
            batch.push(haar_wv(&x, 0.01, &options).unwrap().variance[10].ln());
            for (s, out) in [(0, &mut decimated), (4, &mut oversampled)] {
                let mut stream = HaarWvStream::oversampled(4, s);
                stream.push_block(&x);
                out.push(
                    stream
                        .wavelet_variance(Some(11), 1.0, 0.01)
                        .unwrap()
                        .variance[10]
                        .ln(),
                );
            }
        }
        let (b, d, o) = (spread(&batch), spread(&decimated), spread(&oversampled));
        assert!(o < 1.1 * b, "oversampled {o} against overlapping {b}");
        assert!(d > 1.3 * b, "decimated {d} against overlapping {b}");
    }
}
