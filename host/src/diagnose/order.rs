//! Order statistics of a series read in blocks, in memory that does not grow with it: the
//! running median over a centred window, fed one sample at a time ([`RunningMedian`]), and
//! the exact middle of a series' magnitudes by radix passes, each pass reading the series
//! again ([`median_magnitude`]). The outlier detector ([`super::stats::find_outliers_in`])
//! is built on both, so a long run's residual and simulations are scanned without holding
//! their deviations from the running median. Written here: no crate gives a streaming
//! centred median that orders as `f64::total_cmp` does, or a selection over re-readable
//! passes, and the detector's figures must stay those of a selection over held copies.

/// The median over a centred window of `window` samples (odd) at every index of a series
/// fed in order, the window shortened at the ends (the upper median where it holds an even
/// count): exactly what a selection over each window in `f64::total_cmp`'s order gives. A
/// sorted copy of the window is moved one sample at a time (an insertion sort's step, a few
/// swaps on a short window).
pub(super) struct RunningMedian {
    half: usize,
    sorted: Vec<f64>,
    /// The last `2 half + 2` samples fed, sample `i` at `i % recent.len()`: the window's
    /// leaving sample and the sample a median is emitted for are both among them.
    recent: Vec<f64>,
    fed: usize,
}

impl RunningMedian {
    pub fn new(window: usize) -> Self {
        let half = window / 2;
        Self {
            half,
            sorted: Vec::with_capacity(2 * half + 1),
            recent: vec![0.0; 2 * half + 2],
            fed: 0,
        }
    }

    fn sample(&self, i: usize) -> f64 {
        self.recent[i % self.recent.len()]
    }

    fn position(&self, v: f64) -> usize {
        self.sorted.partition_point(|s| s.total_cmp(&v).is_lt())
    }

    /// Feeds the next sample; `emit(i, x_i, median_i)` for the index whose window it
    /// completes (none while the first `window / 2` samples are fed).
    pub fn push(&mut self, x: f64, emit: &mut impl FnMut(usize, f64, f64)) {
        let j = self.fed;
        let len = self.recent.len();
        self.recent[j % len] = x;
        self.fed += 1;
        if j < self.half {
            let at = self.position(x);
            self.sorted.insert(at, x);
            return;
        }
        if j > 2 * self.half {
            // The leaving sample's place takes the entering one, which then moves to its own.
            let mut at = self.position(self.sample(j - 2 * self.half - 1));
            self.sorted[at] = x;
            while at > 0 && self.sorted[at - 1].total_cmp(&x).is_gt() {
                self.sorted.swap(at - 1, at);
                at -= 1;
            }
            while at + 1 < self.sorted.len() && self.sorted[at + 1].total_cmp(&x).is_lt() {
                self.sorted.swap(at, at + 1);
                at += 1;
            }
        } else {
            let at = self.position(x);
            self.sorted.insert(at, x);
        }
        let i = j - self.half;
        emit(i, self.sample(i), self.sorted[self.sorted.len() / 2]);
    }

    /// Emits the medians of the last `window / 2` indices, whose windows the end of the
    /// series shortens.
    pub fn finish(mut self, emit: &mut impl FnMut(usize, f64, f64)) {
        for i in self.fed.saturating_sub(self.half)..self.fed {
            if i > self.half {
                let at = self.position(self.sample(i - self.half - 1));
                self.sorted.remove(at);
            }
            emit(i, self.sample(i), self.sorted[self.sorted.len() / 2]);
        }
    }
}

/// A series read again in full: each call visits every value once, in order.
pub(super) type ValuePass<'p, E> = dyn FnMut(&mut dyn FnMut(f64)) -> Result<(), E> + 'p;

/// Candidates held and selected directly once the radix passes have narrowed them to this
/// many (2 MiB of bits): on a normal-like series of millions of samples two histogram passes
/// get there.
const HELD_CANDIDATES: usize = 1 << 18;

/// The magnitude |v| of rank `count / 2` (0-based, the upper median) among the `count`
/// values each call of `pass` visits, in `f64::total_cmp`'s order: the value a selection over
/// a held copy of the magnitudes gives, bit for bit. A non-negative float's bits order as
/// the float, so each pass counts the candidates' next 16 bits until few enough are left
/// to hold; `pass` is called once (up to 2^18 values) to five times. Zero when `count` is
/// zero.
pub(super) fn median_magnitude<E>(count: usize, pass: &mut ValuePass<'_, E>) -> Result<f64, E> {
    if count == 0 {
        return Ok(0.0);
    }
    let mut rank = count / 2;
    let mut candidates = count;
    let (mut prefix, mut known_bits) = (0u64, 0u32);
    let matches = move |bits: u64, prefix: u64, known_bits: u32| {
        known_bits == 0 || bits >> (64 - known_bits) == prefix >> (64 - known_bits)
    };
    while known_bits < 64 && candidates > HELD_CANDIDATES {
        let shift = 64 - known_bits - 16;
        let mut histogram = vec![0usize; 1 << 16];
        pass(&mut |v| {
            let bits = v.abs().to_bits();
            if matches(bits, prefix, known_bits) {
                histogram[((bits >> shift) & 0xffff) as usize] += 1;
            }
        })?;
        let mut below = 0;
        let bucket = histogram
            .iter()
            .position(|&c| {
                below += c;
                below > rank
            })
            .expect("the rank lies among the candidates");
        rank -= below - histogram[bucket];
        candidates = histogram[bucket];
        prefix |= (bucket as u64) << shift;
        known_bits += 16;
    }
    if known_bits == 64 {
        return Ok(f64::from_bits(prefix));
    }
    let mut held = Vec::with_capacity(candidates);
    pass(&mut |v| {
        let bits = v.abs().to_bits();
        if matches(bits, prefix, known_bits) {
            held.push(bits);
        }
    })?;
    Ok(f64::from_bits(*held.select_nth_unstable(rank).1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    fn medians(x: &[f64], window: usize, block: usize) -> Vec<(usize, f64, f64)> {
        let mut out = Vec::new();
        let mut running = RunningMedian::new(window);
        let mut emit = |i, v, m| out.push((i, v, m));
        for chunk in x.chunks(block.max(1)) {
            for &v in chunk {
                running.push(v, &mut emit);
            }
        }
        running.finish(&mut emit);
        out
    }

    #[test]
    fn the_running_median_is_each_windows_selected_median_in_order() {
        // Rounded values, so windows hold ties (and signed zeros); series shorter than the
        // window too.
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        for n in [0usize, 1, 2, 4, 11, 12, 500] {
            let x: Vec<f64> = (0..n)
                .map(|_| (rng.sample::<f64, _>(StandardNormal) * 3.0).round())
                .collect();
            for window in [1usize, 3, 11, 31] {
                let h = window / 2;
                let selected: Vec<(usize, f64, f64)> = (0..n)
                    .map(|i| {
                        let mut w = x[i.saturating_sub(h)..(i + h + 1).min(n)].to_vec();
                        let mid = w.len() / 2;
                        (i, x[i], *w.select_nth_unstable_by(mid, f64::total_cmp).1)
                    })
                    .collect();
                for block in [1, 7, n] {
                    assert_eq!(
                        medians(&x, window, block),
                        selected,
                        "n {n}, window {window}, block {block}"
                    );
                }
            }
        }
    }

    fn held_median_magnitude(x: &[f64]) -> f64 {
        let mut abs: Vec<f64> = x.iter().map(|v| v.abs()).collect();
        let mid = abs.len() / 2;
        *abs.select_nth_unstable_by(mid, f64::total_cmp).1
    }

    fn passes_for(x: &[f64]) -> (f64, usize) {
        let mut passes = 0;
        let m = median_magnitude::<()>(x.len(), &mut |visit| {
            passes += 1;
            x.iter().for_each(|v| visit(*v));
            Ok(())
        })
        .unwrap();
        (m, passes)
    }

    #[test]
    fn the_median_magnitude_by_passes_is_the_held_selection() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        // Small: held at once. Large and normal: narrowed by histograms first. Ties and
        // constants: every candidate shares its bits to the last.
        let normal: Vec<f64> = (0..700_001)
            .map(|_| rng.sample::<f64, _>(StandardNormal) * 1e-3)
            .collect();
        let (m, passes) = passes_for(&normal);
        assert_eq!(m.to_bits(), held_median_magnitude(&normal).to_bits());
        assert!(passes >= 2, "{passes} passes");
        let rounded: Vec<f64> = normal.iter().map(|v| (v * 1e3).round()).collect();
        assert_eq!(passes_for(&rounded).0, held_median_magnitude(&rounded));
        let constant = vec![-2.5; 300_000];
        assert_eq!(passes_for(&constant).0, 2.5);
        for n in [1usize, 2, 3, 10, 1001] {
            let x = &normal[..n];
            assert_eq!(passes_for(x), (held_median_magnitude(x), 1), "n {n}");
        }
        assert_eq!(passes_for(&[]), (0.0, 0));
    }
}
