//! Statistics that expose the causes a stochastic baseline model cannot explain: spectral
//! lines, outliers, a shift in the mean, and a noise level that follows the dynamics. Each
//! takes a residual error series (after the deterministic terms are removed) and returns an
//! estimate in physical units plus a test statistic that the discrepancy engine compares
//! with the same statistic on series simulated from the baseline model.

use super::order::{median_magnitude, RunningMedian};
use crate::series_bank::{SeriesBank, SpillError};
use rayon::prelude::*;
use realfft::RealFftPlanner;
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, Normal};

/// One-sided power spectral density by Welch's method (Hann window, 50% overlap).
#[derive(Debug, Clone, PartialEq)]
pub struct Psd {
    /// Bin frequencies, Hz.
    pub freq_hz: Vec<f64>,
    /// Density, unit^2/Hz.
    pub density: Vec<f64>,
    /// Number of averaged segments.
    pub segments: usize,
    /// The segments' worth as independent averages, (sum p)^2 / sum p^2 over their powers
    /// p: the number of segments for stationary noise, fewer when the noise level changes
    /// (a noise that grows in manoeuvres), whose averaged periodogram then has heavier
    /// tails than chi2(2K)/2K.
    pub effective_segments: f64,
    /// Bin width, Hz.
    pub df_hz: f64,
}

/// Draws a series again, visiting its blocks in order.
pub type DrawBlocks<'a> = dyn Fn(&mut dyn FnMut(&[f64])) + Sync + 'a;

/// A series a statistic reads in full, block by block, as often as it needs: held in memory,
/// or drawn again at each reading (a simulation of a long run). Either way in the blocks of
/// [`crate::series_bank::block_ranges`], so a statistic sees the same blocks of a series
/// held or drawn.
#[derive(Clone, Copy)]
pub enum Series<'a> {
    Held(&'a [f64]),
    Drawn {
        len: usize,
        draw: &'a DrawBlocks<'a>,
    },
}

impl Series<'_> {
    /// Samples in the series.
    pub fn len(&self) -> usize {
        match self {
            Series::Held(x) => x.len(),
            Series::Drawn { len, .. } => *len,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `visit(block)` for each block of the series, in order.
    pub fn for_each_block(&self, visit: &mut dyn FnMut(&[f64])) {
        match self {
            Series::Held(x) => {
                for range in crate::series_bank::block_ranges(0..x.len()) {
                    visit(&x[range]);
                }
            }
            Series::Drawn { draw, .. } => draw(visit),
        }
    }

    /// The sum of the samples, added in order.
    pub fn sum(&self) -> f64 {
        let mut sum = 0.0;
        self.for_each_block(&mut |block| block.iter().for_each(|v| sum += v));
        sum
    }
}

/// `f` of series `k` of `bank` as a [`Series`]: held where the bank holds it, read back a
/// block at a time at each reading where the bank is spilled (a read that fails is the
/// error returned, after `f`).
pub fn with_bank_series<T>(
    bank: &SeriesBank,
    k: usize,
    f: impl FnOnce(&Series) -> T,
) -> Result<T, SpillError> {
    with_bank_series_in(bank, k, 0..bank.epochs(), f)
}

/// [`with_bank_series`] of the epochs `epochs` of series `k` alone.
pub fn with_bank_series_in<T>(
    bank: &SeriesBank,
    k: usize,
    epochs: std::ops::Range<usize>,
    f: impl FnOnce(&Series) -> T,
) -> Result<T, SpillError> {
    if !bank.is_spilled() {
        return Ok(f(&Series::Held(&bank.range(k, epochs)?)));
    }
    let draw = |visit: &mut dyn FnMut(&[f64])| {
        bank.for_each_block_in(&[k], epochs.clone(), &mut |_, series| visit(series[0]))
    };
    drawn_from(epochs.len(), &draw, f)
}

/// A block of a series made from the same block of another: `map(epochs, block, out)`
/// fills `out` (cleared) from the source's `block` over `epochs`.
pub type BlockMap<'m> = dyn Fn(std::ops::Range<usize>, &[f64], &mut Vec<f64>) + Sync + 'm;

/// `f` of the series `map` makes of the epochs `epochs` of series `k` of `bank`, a block of
/// [`crate::series_bank::block_ranges`] at a time at each reading (held or spilled alike):
/// a residual less a fitted line, scored without being held.
pub fn with_mapped_bank_series<T>(
    bank: &SeriesBank,
    k: usize,
    epochs: std::ops::Range<usize>,
    map: &BlockMap<'_>,
    f: impl FnOnce(&Series) -> T,
) -> Result<T, SpillError> {
    let draw = |visit: &mut dyn FnMut(&[f64])| {
        let mut out = Vec::with_capacity(crate::series_bank::BANK_BLOCK_EPOCHS);
        for range in crate::series_bank::block_ranges(epochs.clone()) {
            let block = bank.range(k, range.clone())?;
            out.clear();
            map(range, &block, &mut out);
            visit(&out);
        }
        Ok(())
    };
    drawn_from(epochs.len(), &draw, f)
}

/// Blocks drawn by a reader that can fail.
pub type FallibleDraw<'a, E> = dyn Fn(&mut dyn FnMut(&[f64])) -> Result<(), E> + Sync + 'a;

/// `f` of the series of `len` samples `draw` reads at each reading; the first read that
/// failed is the error returned, after `f`.
pub fn drawn_from<T, E: Send>(
    len: usize,
    draw: &FallibleDraw<'_, E>,
    f: impl FnOnce(&Series) -> T,
) -> Result<T, E> {
    let failed = std::sync::Mutex::new(None);
    let draw = |visit: &mut dyn FnMut(&[f64])| {
        if let Err(e) = draw(visit) {
            failed
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner())
                .get_or_insert(e);
        }
    };
    let out = f(&Series::Drawn { len, draw: &draw });
    match failed.into_inner().unwrap_or_else(|p| p.into_inner()) {
        Some(e) => Err(e),
        None => Ok(out),
    }
}

/// The sample variance of a series (n - 1 in the denominator), by its mean first.
pub fn series_variance(x: &Series) -> f64 {
    let n = x.len() as f64;
    let m = x.sum() / n;
    let mut squares = 0.0;
    x.for_each_block(&mut |block| block.iter().for_each(|v| squares += (v - m).powi(2)));
    squares / (n - 1.0).max(1.0)
}

/// A set of series visited one at a time, such as a channel's baseline simulations: held in
/// memory, or drawn again at each visit (a long drive's thirty simulations would not fit).
pub trait SeriesSet: Sync {
    /// `f` of each of the first `count` series (all of them when there are fewer), in order.
    fn map_first<T: Send>(&self, count: usize, f: &(dyn Fn(&Series) -> T + Sync)) -> Vec<T>;

    /// `f` of every series, in order.
    fn map_each<T: Send>(&self, f: &(dyn Fn(&Series) -> T + Sync)) -> Vec<T> {
        self.map_first(usize::MAX, f)
    }
}

impl SeriesSet for Vec<Vec<f64>> {
    fn map_first<T: Send>(&self, count: usize, f: &(dyn Fn(&Series) -> T + Sync)) -> Vec<T> {
        self[..].map_first(count, f)
    }
}

impl SeriesSet for [Vec<f64>] {
    fn map_first<T: Send>(&self, count: usize, f: &(dyn Fn(&Series) -> T + Sync)) -> Vec<T> {
        self[..count.min(self.len())]
            .par_iter()
            .map(|s| f(&Series::Held(s)))
            .collect()
    }
}

/// Welch PSD of `x` sampled every `dt_s`, with segments of `segment_len` samples (a power of
/// two is fastest). The mean of each segment is removed.
pub fn welch_psd(x: &Series, dt_s: f64, segment_len: usize) -> Psd {
    let m = segment_len.min(x.len()).max(8);
    let step = m / 2;
    let window: Vec<f64> = (0..m)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / m as f64).cos())
        .collect();
    let window_power: f64 = window.iter().map(|w| w * w).sum();
    let mut planner = RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(m);
    let mut input = fft.make_input_vec();
    let mut spectrum = fft.make_output_vec();
    let mut acc = vec![0.0; m / 2 + 1];
    let mut segments = 0;
    let mut segment_powers: Vec<f64> = Vec::new();
    // The samples of the segment being filled: segments start every `step` samples.
    let mut seg: Vec<f64> = Vec::with_capacity(m);
    x.for_each_block(&mut |block| {
        for &v in block {
            seg.push(v);
            if seg.len() < m {
                continue;
            }
            let mean = seg.iter().sum::<f64>() / m as f64;
            for i in 0..m {
                input[i] = (seg[i] - mean) * window[i];
            }
            let power: f64 = input.iter().map(|v| v * v).sum();
            if fft.process(&mut input, &mut spectrum).is_ok() {
                for (a, c) in acc.iter_mut().zip(&spectrum) {
                    *a += c.norm_sqr();
                }
                segments += 1;
                segment_powers.push(power);
            }
            seg.drain(..step);
        }
    });
    let fs = 1.0 / dt_s;
    let scale = 1.0 / (fs * window_power * segments.max(1) as f64);
    let density = acc
        .iter()
        .enumerate()
        .map(|(k, a)| {
            let one_sided = if k == 0 || k == m / 2 { 1.0 } else { 2.0 };
            a * scale * one_sided
        })
        .collect();
    let total: f64 = segment_powers.iter().sum();
    let squares: f64 = segment_powers.iter().map(|p| p * p).sum();
    let effective_segments = if squares > 0.0 {
        total * total / squares
    } else {
        segments as f64
    };
    Psd {
        freq_hz: (0..=m / 2).map(|k| k as f64 * fs / m as f64).collect(),
        density,
        segments,
        effective_segments,
        df_hz: fs / m as f64,
    }
}

/// A narrow-band line standing out of the broadband noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpectralLine {
    /// Frequency of the peak bin, Hz (as seen at the series' sample rate, i.e. after any
    /// aliasing).
    pub freq_hz: f64,
    /// Amplitude of the equivalent sinusoid, error units.
    pub amplitude: f64,
    /// Peak density over the local background.
    pub power_ratio: f64,
    /// Bonferroni-corrected p-value of the peak under a smooth-spectrum null.
    pub p_value: f64,
}

/// Finds lines: bins whose density exceeds a running-median background by more than chance
/// allows (each Welch bin is background x chi2(2K)/2K for K effective segments, and the
/// background an estimate of its own, so the ratio is F-distributed), Bonferroni-corrected
/// over the bins, at family-wise level `alpha`. Adjacent significant bins form one line.
pub fn spectral_lines(psd: &Psd, alpha: f64) -> Vec<SpectralLine> {
    let n = psd.density.len();
    if n < 16 || psd.segments == 0 {
        return Vec::new();
    }
    let half = 8usize;
    let dof = 2.0 * psd.effective_segments.max(1.0);
    let background: Vec<f64> = (0..n)
        .map(|k| {
            let lo = k.saturating_sub(half);
            let hi = (k + half + 1).min(n);
            let mut w: Vec<f64> = psd.density[lo..hi].to_vec();
            let mid = w.len() / 2;
            // Median of chi2(2K)/2K is below 1; correct so the background is the mean.
            let med = *w.select_nth_unstable_by(mid, f64::total_cmp).1;
            med / chi2_median_over_dof(dof)
        })
        .collect();
    // The ratio of a bin to the background is F-distributed, not chi-square: the background
    // is itself an estimate, the median of 2 * half neighbouring bins, worth about
    // 0.64 (a median's efficiency) x 2 half / 1.5 (Hann-windowed bins overlap) independent
    // bins. Ignoring its error named a 0.4 mm/s^2 "line" in a null run (power ratio 2.05 at
    // 84 dof, a background estimated 10% low).
    let background_dof = dof * 0.64 * (2 * half) as f64 / 1.5;
    let ratio_law =
        statrs::distribution::FisherSnedecor::new(dof, background_dof).expect("dof > 0");
    use statrs::distribution::ContinuousCDF;
    let bins = (n - 1) as f64;
    let mut lines: Vec<SpectralLine> = Vec::new();
    let mut k = 1;
    while k < n {
        let ratio = psd.density[k] / background[k].max(f64::MIN_POSITIVE);
        let p = (ratio_law.sf(ratio) * bins).min(1.0);
        if p < alpha {
            // Gather the contiguous run of significant bins: a Hann-windowed line spreads
            // over about three bins.
            let start = k;
            let mut end = k;
            while end + 1 < n {
                let r = psd.density[end + 1] / background[end + 1].max(f64::MIN_POSITIVE);
                if (ratio_law.sf(r) * bins).min(1.0) < alpha || r > 3.0 {
                    end += 1;
                } else {
                    break;
                }
            }
            let lo = start.saturating_sub(1);
            let hi = (end + 1).min(n - 1);
            let excess: f64 = (lo..=hi)
                .map(|j| (psd.density[j] - background[j]).max(0.0))
                .sum::<f64>()
                * psd.df_hz;
            // Hann window: a sinusoid's power spreads over bins with an equivalent noise
            // bandwidth of 1.5 bins, and the density sum times df recovers A^2/2.
            let amplitude = (2.0 * excess).sqrt();
            let peak = (start..=end)
                .max_by(|&a, &b| psd.density[a].total_cmp(&psd.density[b]))
                .unwrap_or(start);
            let peak_ratio = psd.density[peak] / background[peak].max(f64::MIN_POSITIVE);
            lines.push(SpectralLine {
                freq_hz: psd.freq_hz[peak],
                amplitude,
                power_ratio: peak_ratio,
                p_value: (ratio_law.sf(peak_ratio) * bins).min(1.0),
            });
            k = end + 2;
        } else {
            k += 1;
        }
    }
    lines
}

fn chi2_median_over_dof(dof: f64) -> f64 {
    // Wilson-Hilferty: median of chi2(k) ~ k (1 - 2/(9k))^3.
    let k = dof;
    (1.0 - 2.0 / (9.0 * k)).powi(3)
}

/// Isolated outliers found against a running median.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Outliers {
    /// Indices of the outlying samples.
    pub indices: Vec<usize>,
    /// Fraction of samples that are outliers.
    pub rate: f64,
    /// Median absolute size of the outliers above the local level, error units.
    pub median_size: f64,
    /// Robust scale of the residual around its running median, error units.
    pub robust_sigma: f64,
    /// Largest |z| seen.
    pub max_abs_z: f64,
    /// Deviations of the flagged samples from the running median, error units.
    pub scaled_deviations: Vec<f64>,
}

/// Flags samples more than `threshold` robust standard deviations from the running median of
/// the series over `window` samples (odd). Slow wander (Gauss-Markov, random walk) is absorbed
/// by the running median, so only isolated spikes stand out.
pub fn find_outliers(x: &Series, window: usize, threshold: f64) -> Outliers {
    let blocks = |visit: &mut dyn FnMut(&[f64])| -> Result<(), std::convert::Infallible> {
        x.for_each_block(visit);
        Ok(())
    };
    match find_outliers_in(x.len(), window, threshold, &blocks) {
        Ok(found) => found,
        Err(never) => match never {},
    }
}

/// A series read again in full, block by block: each call visits every block once, in order.
pub type SeriesBlocks<'b, E> = dyn Fn(&mut dyn FnMut(&[f64])) -> Result<(), E> + Sync + 'b;

/// [`find_outliers`] of a series of `n` samples that `blocks` visits in order, block by
/// block, each time it is called (two to six times): the deviations from the running
/// median are made again at each pass instead of held, so a series of any length is scanned
/// in a few MiB, with the figures of a scan of the series held.
pub fn find_outliers_in<E>(
    n: usize,
    window: usize,
    threshold: f64,
    blocks: &SeriesBlocks<'_, E>,
) -> Result<Outliers, E> {
    let window = (window | 1).max(3);
    // Calls `visit(i, deviation_i)` for every index, in order.
    let deviations = |visit: &mut dyn FnMut(usize, f64)| -> Result<(), E> {
        let mut running = RunningMedian::new(window);
        let mut emit = |i: usize, v: f64, median: f64| visit(i, v - median);
        blocks(&mut |block: &[f64]| {
            for &v in block {
                running.push(v, &mut emit);
            }
        })?;
        running.finish(&mut emit);
        Ok(())
    };
    let mad = median_magnitude(n, &mut |visit| deviations(&mut |_, d| visit(d)))?;
    let sigma = 1.4826 * mad;
    let z = |d: f64| if sigma > 0.0 { d / sigma } else { 0.0 };
    let (mut indices, mut scaled_deviations, mut sizes) = (Vec::new(), Vec::new(), Vec::new());
    let mut max_abs_z = 0.0f64;
    deviations(&mut |i, d| {
        max_abs_z = max_abs_z.max(z(d).abs());
        if z(d).abs() > threshold {
            indices.push(i);
            scaled_deviations.push(z(d) * sigma);
            sizes.push(d.abs());
        }
    })?;
    let median_size = if sizes.is_empty() {
        0.0
    } else {
        let m = sizes.len() / 2;
        *sizes.select_nth_unstable_by(m, f64::total_cmp).1
    };
    Ok(Outliers {
        rate: indices.len() as f64 / n.max(1) as f64,
        scaled_deviations,
        indices,
        median_size,
        robust_sigma: sigma,
        max_abs_z,
    })
}

/// Difference of the means of the `window` samples after and before each index k
/// (k = window..=n - window), error units: a Haar wavelet coefficient at that scale, placed
/// at every k. A step of size s gives s at its own index, while Gauss-Markov wander with a
/// correlation time much longer than the window barely moves it, so at short windows steps
/// stand out from slow noise that a whole-run CUSUM cannot tell them from.
pub fn local_steps(x: &[f64], window: usize) -> Vec<f64> {
    let mut steps = Vec::new();
    for_each_running_sum(&Series::Held(x), 2 * window + 1, &mut |p, sums| {
        if let Some(k) = step_index(p, window) {
            steps.push(sums.step(k, window));
        }
    });
    steps
}

/// The running sums of a series (the sum of its first q samples at q) over the last
/// positions fed ([`for_each_running_sum`]), from which a local step at any window within
/// reach is two subtractions: one pass serves every window, and no series of the input's
/// length is held.
struct RunningSumRing {
    sums: Vec<f64>,
}

impl RunningSumRing {
    /// The running sum at position `q`, one of the last `reach` positions fed.
    fn at(&self, q: usize) -> f64 {
        self.sums[q % self.sums.len()]
    }

    /// The local step at `window` placed at `k` (its after-window ends at the last position
    /// fed, or later ones within reach).
    fn step(&self, k: usize, window: usize) -> f64 {
        ((self.at(k + window) - self.at(k)) - (self.at(k) - self.at(k - window))) / window as f64
    }

    /// The local step at [`sharp_window`] minus the one at `window`, both at `k`.
    fn sharpness(&self, k: usize, window: usize) -> f64 {
        self.step(k, sharp_window(window)) - self.step(k, window)
    }
}

/// `visit(p, sums)` at each position p = 0..=n of `x` in order, `sums` holding the running
/// sums of the last `reach` positions (p included).
fn for_each_running_sum(x: &Series, reach: usize, visit: &mut dyn FnMut(usize, &RunningSumRing)) {
    let mut ring = RunningSumRing {
        sums: vec![0.0; reach.clamp(1, x.len() + 1)],
    };
    let len = ring.sums.len();
    let (mut acc, mut p) = (0.0, 0);
    visit(0, &ring);
    x.for_each_block(&mut |block| {
        for v in block {
            acc += v;
            p += 1;
            ring.sums[p % len] = acc;
            visit(p, &ring);
        }
    });
}

/// The index a local step at `window` is placed at when its after-window ends at position
/// `p`: k = p - window, for k in window..=n - window (none for an empty window).
fn step_index(p: usize, window: usize) -> Option<usize> {
    (window > 0 && p >= 2 * window).then(|| p - window)
}

/// The most significant step of a series over several window lengths.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LocalStep {
    /// Index of the first sample after the step.
    pub index: usize,
    /// Window (samples) at which it is most significant.
    pub window: usize,
    /// Difference of the window means at the step, error units.
    pub size: f64,
    /// |size| over the null standard deviation at that window.
    pub z: f64,
    /// The null standard deviation of a local step at that window, error units: the size's
    /// standard error.
    pub sd: f64,
}

/// Scans `x` for its most significant step: at each window of `windows`, the local step
/// [`local_steps`] divided by its standard deviation, maximised over windows and indices.
/// That deviation is the larger of `null_sd` (the window's spread under the baseline noise,
/// from simulations, slow wander included) and the spread the two windows' own sample
/// variances give the difference, sqrt((s_before^2 + s_after^2) / window). Why the local
/// floor: an outlier, or noise that grows in a manoeuvre, moves a window's mean as a step
/// does, but it also inflates that window's variance, while a step leaves both windows as
/// quiet as the rest of the run.
///
/// The running sums are kept for the last `2 w + 1` positions only (w the longest window
/// scanned), so the scan holds no series of `x`'s length.
pub fn local_step_scan(x: &Series, windows: &[usize], null_sd: &[f64]) -> Option<LocalStep> {
    let n = x.len();
    let scanned: Vec<(usize, f64)> = windows
        .iter()
        .copied()
        .zip(null_sd.iter().copied())
        .filter(|&(w, sd)| w > 0 && sd > 0.0)
        .collect();
    let reach = 2 * scanned.iter().map(|&(w, _)| w).max()? + 1;
    // Centred on the series' mean, so the sums of squares lose no precision to a bias.
    let centre = x.sum() / n.max(1) as f64;
    let mut ring = vec![RunningSums::default(); reach.min(n + 1)];
    let len = ring.len();
    let mut running = RunningSums::default();
    // Each window's best in index order; across windows the first best in window order,
    // as one scan window after window would choose.
    let mut best: Vec<Option<LocalStep>> = vec![None; scanned.len()];
    let mut at_position = |p: usize, ring: &[RunningSums]| {
        for (&(w, sd), best) in scanned.iter().zip(best.iter_mut()) {
            let Some(i) = p.checked_sub(2 * w) else {
                continue;
            };
            let [before, at, after] = [i, i + w, p].map(|q| &ring[q % len]);
            let d = ((after.sum - at.sum) - (at.sum - before.sum)) / w as f64;
            // The local floor only lowers z below |d| / sd: a step that cannot beat the best
            // even so is passed over before its windows' variances are taken (a margin of
            // 1e-12 over the roundings keeps the choice the full computation makes).
            if best
                .as_ref()
                .is_some_and(|b| d.abs() < b.z * sd * (1.0 - 1e-12))
            {
                continue;
            }
            let local_variance = before.window_variance(at, w) + at.window_variance(after, w);
            let sd = sd.max((local_variance / w as f64).sqrt());
            let z = d.abs() / sd;
            if best.as_ref().is_none_or(|b| z > b.z) {
                *best = Some(LocalStep {
                    index: i + w,
                    window: w,
                    size: d,
                    z,
                    sd,
                });
            }
        }
    };
    ring[0] = running;
    at_position(0, &ring);
    let mut p = 0;
    x.for_each_block(&mut |block| {
        for &v in block {
            p += 1;
            running = running.after(v, centre);
            ring[p % len] = running;
            at_position(p, &ring);
        }
    });
    best.into_iter()
        .flatten()
        .fold(None, |acc: Option<LocalStep>, s| match acc {
            Some(a) if !(s.z > a.z) => Some(a),
            _ => Some(s),
        })
}

/// The running sums of a series up to a position: of the samples (for the local steps),
/// and of their deviations from a centre and its squares (for the windows' variances).
#[derive(Debug, Clone, Copy, Default)]
struct RunningSums {
    sum: f64,
    centred: f64,
    centred_sq: f64,
}

impl RunningSums {
    /// The sums one sample `v` further on.
    fn after(self, v: f64, centre: f64) -> Self {
        Self {
            sum: self.sum + v,
            centred: self.centred + (v - centre),
            centred_sq: self.centred_sq + (v - centre).powi(2),
        }
    }

    /// Sample variance (n - 1) of the `w` samples between this position and `end`.
    fn window_variance(&self, end: &Self, w: usize) -> f64 {
        let l = w as f64;
        let m = (end.centred - self.centred) / l;
        ((end.centred_sq - self.centred_sq) / l - m * m).max(0.0) * l / (l - 1.0).max(1.0)
    }
}

/// Window at which [`step_sharpness`] looks again at a step found at `window`: a quarter of
/// it, no shorter than 16 samples.
fn sharp_window(window: usize) -> usize {
    (window / 4).max(16).min(window)
}

/// How far a change of the mean found at `index` (at `window`) is from a step: the local
/// step at a quarter of the window minus the one at the window, over its standard deviation
/// (the larger of its spread over `sims`, the baseline's simulations, and its robust spread
/// over `x` itself). A step is as large at the shorter window, so this is small (standard
/// normal); a change spread over the window (a ramp, slow wander) is smaller at the shorter
/// window and this is large. NaN when it cannot be computed. Every series is read through
/// a ring of its running sums; `x`'s robust spread by passes ([`median_magnitude`]).
pub fn step_sharpness<S: SeriesSet + ?Sized>(
    x: &Series,
    index: usize,
    window: usize,
    sims: &S,
) -> f64 {
    let reach = 2 * window + 1;
    let mut at = None;
    let mut count = 0usize;
    for_each_running_sum(x, reach, &mut |p, sums| {
        if let Some(k) = step_index(p, window) {
            count += 1;
            if k == index {
                at = Some(sums.sharpness(k, window));
            }
        }
    });
    let Some(at) = at else {
        return f64::NAN;
    };
    // Each simulation's sharpness summed as it is made, not held.
    let pooled = sims
        .map_each(&|s| {
            let (mut ss, mut count) = (0.0, 0usize);
            for_each_running_sum(s, reach, &mut |p, sums| {
                if let Some(k) = step_index(p, window) {
                    let d = sums.sharpness(k, window);
                    ss += d * d;
                    count += 1;
                }
            });
            (ss, count)
        })
        .into_iter()
        .fold((0.0, 0), |(ss, n), (a, b)| (ss + a, n + b));
    let simulated = (pooled.0 / pooled.1.max(1) as f64).sqrt();
    let median = median_magnitude::<std::convert::Infallible>(count, &mut |visit| {
        for_each_running_sum(x, reach, &mut |p, sums| {
            if let Some(k) = step_index(p, window) {
                visit(sums.sharpness(k, window));
            }
        });
        Ok(())
    });
    let own = 1.4826 * median.unwrap_or_else(|never| match never {});
    at.abs() / simulated.max(own)
}

/// Standard deviation of [`local_steps`] at each window over a set of series (simulations of
/// the baseline), pooled over indices.
pub fn local_step_null_sd<S: SeriesSet + ?Sized>(series: &S, windows: &[usize]) -> Vec<f64> {
    let reach = 2 * windows.iter().copied().max().unwrap_or(0) + 1;
    // One visit of each series for every window: a drawn series is drawn once.
    let per_series = series.map_each(&|s| {
        let mut sums = vec![(0.0, 0usize); windows.len()];
        for_each_running_sum(s, reach, &mut |p, ring| {
            for (&w, (ss, count)) in windows.iter().zip(sums.iter_mut()) {
                if let Some(k) = step_index(p, w) {
                    let d = ring.step(k, w);
                    *ss += d * d;
                    *count += 1;
                }
            }
        });
        sums
    });
    (0..windows.len())
        .map(|k| {
            let (ss, count) = per_series
                .iter()
                .fold((0.0, 0usize), |(ss, n), s| (ss + s[k].0, n + s[k].1));
            if count == 0 {
                0.0
            } else {
                (ss / count as f64).sqrt()
            }
        })
        .collect()
}

/// Robust standard deviation of [`local_steps`] of `x` itself at each window (1.4826 times
/// the median absolute local step): a step touches only the 2 w positions around it, so
/// this measures the series' own noise at that window even when it holds a step.
pub fn local_step_robust_sd(x: &Series, windows: &[usize]) -> Vec<f64> {
    windows
        .iter()
        .map(|&w| {
            // By passes over a ring of running sums: no series of the steps is held.
            let count = (x.len() + 1).saturating_sub(2 * w) * usize::from(w > 0);
            let median = median_magnitude::<std::convert::Infallible>(count, &mut |visit| {
                for_each_running_sum(x, 2 * w + 1, &mut |p, sums| {
                    if let Some(k) = step_index(p, w) {
                        visit(sums.step(k, w));
                    }
                });
                Ok(())
            });
            1.482_602_218_505_602 * median.unwrap_or_else(|never| match never {})
        })
        .collect()
}

/// How the short-term noise level follows a dynamics magnitude m: the model is a noise
/// variance sigma0^2 + (k m)^2, i.e. white noise whose standard deviation grows as k m on top
/// of the baseline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NoiseVsDynamics {
    /// Slope of the windowed noise variance on m^2, error units^2 per dynamics unit^2.
    pub slope: f64,
    pub slope_std_error: f64,
    /// Noise variance at zero dynamics, error units^2.
    pub intercept: f64,
    /// slope / std_error.
    pub t: f64,
    /// k = sqrt(slope): noise standard deviation per dynamics unit (0 when slope <= 0).
    pub sigma_per_unit: f64,
    /// 95% interval of k (from the slope's interval, clipped at 0).
    pub sigma_per_unit_ci95: [f64; 2],
}

/// Regresses the short-term noise variance (from first differences over windows of `window`
/// samples, which removes slow correlated noise) on the window mean of `magnitude^2` (e.g.
/// |omega| in rad/s). A stationary baseline gives a slope of zero. Windows are treated as
/// independent, which holds for the white-noise-dominated differences.
pub fn noise_vs_dynamics(x: &[f64], magnitude: &[f64], window: usize) -> NoiseVsDynamics {
    let mut mean_squares = WindowMeanSquares::new(magnitude.len(), window);
    mean_squares.add(magnitude);
    noise_vs_window_dynamics(&Series::Held(x), &mean_squares.finish(), window)
}

/// The window mean of a magnitude's square over the windows [`noise_vs_dynamics`] reads (`w`
/// = `window`, at least 4, samples from 0, w, 2 w, ... while a whole window and one more
/// sample fit), summed from blocks fed in order: what the regression needs of the dynamics,
/// a value a window, without holding them.
pub struct WindowMeanSquares {
    w: usize,
    fed: usize,
    sums: Vec<f64>,
}

impl WindowMeanSquares {
    /// For a series of `n` samples.
    pub fn new(n: usize, window: usize) -> Self {
        let w = window.max(4);
        Self {
            w,
            fed: 0,
            sums: vec![0.0; n.saturating_sub(w).div_ceil(w)],
        }
    }

    /// The next block of the magnitude.
    pub fn add(&mut self, block: &[f64]) {
        for m in block {
            if let Some(sum) = self.sums.get_mut(self.fed / self.w) {
                *sum += m * m;
            }
            self.fed += 1;
        }
    }

    /// Each window's mean square.
    pub fn finish(self) -> Vec<f64> {
        let w = self.w as f64;
        self.sums.into_iter().map(|s| s / w).collect()
    }
}

/// [`noise_vs_dynamics`] given each window's mean of the magnitude's square
/// ([`WindowMeanSquares`]).
pub fn noise_vs_window_dynamics(x: &Series, mag2: &[f64], window: usize) -> NoiseVsDynamics {
    let w = window.max(4);
    // Windows start at 0, w, 2w, ... below n - w: their samples end here.
    let covered = x.len().saturating_sub(w).div_ceil(w) * w;
    let (mut var, mut seg, mut fed) = (Vec::new(), Vec::with_capacity(w), 0usize);
    let mut diffs = Vec::with_capacity(w);
    x.for_each_block(&mut |block| {
        for &v in &block[..block.len().min(covered.saturating_sub(fed))] {
            seg.push(v);
            if seg.len() == w {
                diffs.clear();
                diffs.extend(seg.windows(2).map(|p| p[1] - p[0]));
                let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
                let v = diffs.iter().map(|d| (d - mean).powi(2)).sum::<f64>()
                    / (diffs.len() - 1) as f64;
                // A difference of white noise has twice its variance.
                var.push(v / 2.0);
                seg.clear();
            }
        }
        fed += block.len();
    });
    let mag2 = &mag2[..var.len()];
    let none = |intercept: f64| NoiseVsDynamics {
        slope: 0.0,
        slope_std_error: f64::INFINITY,
        intercept,
        t: 0.0,
        sigma_per_unit: 0.0,
        sigma_per_unit_ci95: [0.0, 0.0],
    };
    let n = var.len() as f64;
    if n < 3.0 {
        return none(0.0);
    }
    // Weighted least squares: a window's variance estimate has a spread proportional to the
    // variance itself (chi-square with w - 2 degrees of freedom), so the few windows of hard
    // manoeuvres, which fix the slope, are also the noisiest. Ordinary least squares with its
    // constant-variance standard error gave intervals of +-0.5% on k on 900 s simulated
    // drives, where the estimate missed the truth by 1-5%; weighted, they are +-3% and hold
    // the truth. Weights come from the fit of the previous pass (ordinary least squares
    // first).
    let mut weights = vec![1.0; var.len()];
    let mut fit = None;
    for _pass in 0..3 {
        let sw: f64 = weights.iter().sum();
        let mx = mag2.iter().zip(&weights).map(|(m, w)| w * m).sum::<f64>() / sw;
        let my = var.iter().zip(&weights).map(|(s, w)| w * s).sum::<f64>() / sw;
        let sxx: f64 = mag2
            .iter()
            .zip(&weights)
            .map(|(m, w)| w * (m - mx).powi(2))
            .sum();
        let sxy: f64 = mag2
            .iter()
            .zip(&var)
            .zip(&weights)
            .map(|((m, s), w)| w * (m - mx) * (s - my))
            .sum();
        if sxx <= 0.0 {
            return none(my);
        }
        let slope = sxy / sxx;
        let intercept = my - slope * mx;
        // Residual scale of the weighted fit (1 when the chi-square spread holds exactly).
        let rss: f64 = mag2
            .iter()
            .zip(&var)
            .zip(&weights)
            .map(|((m, s), w)| w * (s - intercept - slope * m).powi(2))
            .sum();
        // The larger of the model-based and the sandwich (HC1) standard error: the window
        // variances are not exactly chi-square (the driver varies within a window), and on 13
        // simulated drives the model-based interval alone held the truth in 11.
        let model_se = (rss / (n - 2.0) / sxx).sqrt();
        let meat: f64 = mag2
            .iter()
            .zip(&var)
            .zip(&weights)
            .map(|((m, s), w)| (w * (m - mx) * (s - intercept - slope * m)).powi(2))
            .sum::<f64>()
            * n
            / (n - 2.0);
        let se = model_se.max(meat.sqrt() / sxx);
        fit = Some((slope, intercept, se));
        let floor = (intercept.abs() + slope.abs() * mx).max(1e-300) * 1e-3;
        weights = mag2
            .iter()
            .map(|m| (intercept + slope * m).max(floor).powi(-2))
            .collect();
    }
    let (slope, intercept, se) = fit.expect("three passes ran");
    let k = |s: f64| s.max(0.0).sqrt();
    NoiseVsDynamics {
        slope,
        slope_std_error: se,
        intercept,
        t: if se > 0.0 { slope / se } else { 0.0 },
        sigma_per_unit: k(slope),
        sigma_per_unit_ci95: [k(slope - 1.96 * se), k(slope + 1.96 * se)],
    }
}

/// Smallest fraction of a fitted outlier population that must lie beyond the detection
/// threshold for the exceedances to be called a separate population. Below it the fitted
/// population is mostly hidden in the noise: its size would be an extrapolation of the tail's
/// shape by more than a factor 20, and the exceedances are better read as the noise's own
/// heavier-than-Gaussian tail (on the ADIS16405 az channel they pile up just above the
/// threshold, the fit puts 99.99% of its population inside the noise, and the corrected
/// count was 0.49 per sample). The bound also caps the hidden-outlier correction at 20x.
pub const MIN_OUTLIER_DETECTION_PROBABILITY: f64 = 0.05;

/// An outlier process estimated from the deviations beyond a detection threshold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutlierProcess {
    /// True when the exceedances form a population separate from the noise (at least
    /// [`MIN_OUTLIER_DETECTION_PROBABILITY`] of the fitted population shows beyond the
    /// threshold); false when they are the tip of a heavier-tailed noise.
    pub separated: bool,
    /// Outlier probability per sample. Separated: corrected for the outliers hidden in the
    /// noise. Not separated: the detected rate only, with no extrapolation.
    pub probability_per_sample: f64,
    /// 95% interval of `probability_per_sample` (Poisson on the count, scaled alike).
    pub probability_ci95: [f64; 2],
    /// Standard deviation of an outlier, error units (population scale minus the noise).
    pub sigma: f64,
    /// Fitted scale of the deviations (outlier plus noise), error units.
    pub population_sigma: f64,
    /// Fraction of the fitted population beyond the threshold.
    pub detection_probability: f64,
}

/// Estimates an outlier process from the detected deviations `devs` (|deviation| > t_abs,
/// error units) of a series of `n` samples whose noise has standard deviation `noise_sigma`.
/// The detected deviations are modelled as a normal N(0, s^2), s^2 = sigma_out^2 + noise^2,
/// truncated to |x| > t_abs; s is solved from their second moment. The count is corrected for
/// the small outliers hidden in the noise (divided by the detection probability) only when the
/// fit shows a population that stands out of the noise (see
/// [`MIN_OUTLIER_DETECTION_PROBABILITY`]); otherwise the process is flagged as not separated
/// and the detected rate is returned as it is.
pub fn outlier_process(devs: &[f64], t_abs: f64, noise_sigma: f64, n: usize) -> OutlierProcess {
    let normal = Normal::new(0.0, 1.0).expect("standard normal");
    let k = devs.len() as f64;
    let n_f = n.max(1) as f64;
    let m2 = if devs.is_empty() {
        0.0
    } else {
        devs.iter().map(|d| d * d).sum::<f64>() / k
    };
    // E[x^2 | |x| > t] = s^2 + t s phi(t/s) / (1 - Phi(t/s)) for x ~ N(0, s^2); solve for s.
    let second_moment = |s: f64| {
        let u = t_abs / s;
        let tail = (1.0 - normal.cdf(u)).max(1e-300);
        let phi = (-0.5 * u * u).exp() / (2.0 * std::f64::consts::PI).sqrt();
        s * s + t_abs * s * phi / tail
    };
    let (mut lo, mut hi) = (
        noise_sigma.max(1e-12),
        (m2.sqrt() * 10.0).max(noise_sigma * 20.0),
    );
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if second_moment(mid) < m2 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let s = 0.5 * (lo + hi);
    let sigma_out = (s * s - noise_sigma * noise_sigma).max(0.0).sqrt();
    let detect = 2.0 * (1.0 - normal.cdf(t_abs / s));
    let separated = !devs.is_empty() && detect >= MIN_OUTLIER_DETECTION_PROBABILITY;
    // Separated: every detected outlier stands for 1/detect outliers. Not separated: the
    // hidden part is not observed, so nothing is extrapolated.
    let scale = if separated { 1.0 / detect } else { 1.0 };
    // Poisson interval on the count (normal approximation with continuity), scaled.
    let half = 1.959_963_984_540_054 * (k + 1.0).sqrt();
    OutlierProcess {
        separated,
        probability_per_sample: k / n_f * scale,
        probability_ci95: [(k - half).max(0.0) / n_f * scale, (k + half) / n_f * scale],
        sigma: sigma_out,
        population_sigma: s,
        detection_probability: detect,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    fn white(rng: &mut ChaCha8Rng, n: usize, sd: f64) -> Vec<f64> {
        (0..n)
            .map(|_| sd * rng.sample::<f64, _>(StandardNormal))
            .collect()
    }

    #[test]
    fn a_series_drawn_in_blocks_of_any_size_gives_the_statistics_of_the_series_held() {
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        let mut x = white(&mut rng, 50_000, 1.0);
        x[20_000..].iter_mut().for_each(|v| *v += 0.3);
        x[7_777] += 12.0;
        let magnitude: Vec<f64> = (0..x.len()).map(|k| (k as f64 * 1e-3).sin()).collect();
        let mut squares = WindowMeanSquares::new(x.len(), 250);
        squares.add(&magnitude);
        let mag2 = squares.finish();
        let held = Series::Held(&x);
        for block in [1, 999, 1 << 14, 60_000] {
            let draw = |visit: &mut dyn FnMut(&[f64])| x.chunks(block).for_each(&mut *visit);
            let drawn = Series::Drawn {
                len: x.len(),
                draw: &draw,
            };
            assert_eq!(welch_psd(&drawn, 0.01, 1024), welch_psd(&held, 0.01, 1024));
            assert_eq!(
                find_outliers(&drawn, 11, 6.0),
                find_outliers(&held, 11, 6.0)
            );
            assert_eq!(
                noise_vs_window_dynamics(&drawn, &mag2, 250),
                noise_vs_window_dynamics(&held, &mag2, 250)
            );
            let windows = [50, 400, 3_000];
            assert_eq!(
                local_step_scan(&drawn, &windows, &[0.1; 3]),
                local_step_scan(&held, &windows, &[0.1; 3])
            );
            assert_eq!(
                local_step_robust_sd(&drawn, &windows),
                local_step_robust_sd(&held, &windows)
            );
        }
        assert_eq!(find_outliers(&held, 11, 6.0).indices, vec![7_777]);
        let step = local_step_scan(&held, &[50, 400, 3_000], &[0.1; 3]).unwrap();
        assert!((step.index as i64 - 20_000).abs() < 50, "{step:?}");
    }

    #[test]
    fn a_series_of_a_spilled_bank_is_read_back_a_block_at_a_time_to_the_same_statistics() {
        let mut rng = ChaCha8Rng::seed_from_u64(32);
        let x = white(&mut rng, 40_000, 2.0);
        let scan = |s: &Series| {
            (
                s.len(),
                series_variance(s),
                find_outliers(s, 11, 6.0),
                local_step_robust_sd(s, &[64, 1024]),
            )
        };
        let mut figures = Vec::new();
        for spill in [false, true] {
            let mut bank = SeriesBank::columns(x.len(), 2, spill).unwrap();
            for (k, values) in [vec![0.0; x.len()], x.clone()].iter().enumerate() {
                for range in crate::series_bank::block_ranges(0..x.len()) {
                    bank.write(k, range.start, &values[range]).unwrap();
                }
            }
            assert_eq!(bank.is_spilled(), spill);
            figures.push(with_bank_series(&bank, 1, scan).unwrap());
            // A part of the series, and a series made from it a block at a time.
            let part = 5_000..33_333;
            let read = with_bank_series_in(&bank, 1, part.clone(), series_variance).unwrap();
            assert_eq!(read, series_variance(&Series::Held(&x[part.clone()])));
            let map = |epochs: std::ops::Range<usize>, block: &[f64], out: &mut Vec<f64>| {
                out.extend(block.iter().zip(epochs).map(|(v, i)| 2.0 * v + i as f64));
            };
            let mapped = with_mapped_bank_series(&bank, 1, part.clone(), &map, |s| {
                let mut all = Vec::new();
                s.for_each_block(&mut |block| all.extend_from_slice(block));
                all
            })
            .unwrap();
            let want: Vec<f64> = part.map(|i| 2.0 * x[i] + i as f64).collect();
            assert_eq!(mapped, want);
        }
        assert_eq!(figures[0], figures[1]);
        assert_eq!(figures[0], scan(&Series::Held(&x)));
        assert!((figures[0].1 / 4.0 - 1.0).abs() < 0.03, "{}", figures[0].1);
    }

    #[test]
    fn finds_a_vibration_line_with_its_amplitude_and_nothing_in_pure_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let dt = 0.01;
        let mut x = white(&mut rng, 60_000, 0.05);
        assert!(spectral_lines(&welch_psd(&Series::Held(&x), dt, 1024), 0.01).is_empty());
        for (i, v) in x.iter_mut().enumerate() {
            *v += 0.02 * (2.0 * std::f64::consts::PI * 17.3 * i as f64 * dt).sin();
        }
        let lines = spectral_lines(&welch_psd(&Series::Held(&x), dt, 1024), 0.01);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!((lines[0].freq_hz - 17.3).abs() < 0.15, "{lines:?}");
        assert!((lines[0].amplitude - 0.02).abs() < 0.004, "{lines:?}");
    }

    /// In white noise the line test holds its family-wise level over the spectrum: at
    /// alpha 0.1, 200 series of 30000 samples show a line in at most 10% of them (plus a
    /// binomial allowance of 3 sigma).
    #[test]
    fn the_line_test_holds_its_level_on_white_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(33);
        let alarms = (0..200)
            .filter(|_| {
                let psd = welch_psd(&Series::Held(&white(&mut rng, 30_000, 1.0)), 0.01, 1024);
                !spectral_lines(&psd, 0.1).is_empty()
            })
            .count();
        assert!(
            alarms <= 20 + 13,
            "{alarms} of 200 white-noise series showed a line"
        );
    }

    /// Noise whose level changes (quiet, then four times louder in "manoeuvres") has no
    /// line: the test counts the segments by their worth, not their number.
    #[test]
    fn a_changing_noise_level_is_not_a_line() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let mut alarms = 0;
        for _ in 0..20 {
            let x: Vec<f64> = white(&mut rng, 30_000, 1.0)
                .into_iter()
                .enumerate()
                .map(|(i, v)| if (i / 2000) % 5 == 0 { 4.0 * v } else { v })
                .collect();
            let psd = welch_psd(&Series::Held(&x), 0.01, 1024);
            assert!(psd.effective_segments < 0.6 * psd.segments as f64);
            alarms += !spectral_lines(&psd, 0.01).is_empty() as usize;
        }
        assert!(alarms <= 1, "{alarms} of 20 series showed a line");
        let steady = welch_psd(&Series::Held(&white(&mut rng, 30_000, 1.0)), 0.01, 1024);
        assert!(steady.effective_segments > 0.95 * steady.segments as f64);
    }

    #[test]
    fn outliers_are_counted_despite_slow_wander() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let n = 50_000;
        let mut gm = 0.0;
        let mut x: Vec<f64> = (0..n)
            .map(|_| {
                gm = 0.999 * gm + 0.01 * rng.sample::<f64, _>(StandardNormal);
                gm + 0.01 * rng.sample::<f64, _>(StandardNormal)
            })
            .collect();
        assert!(find_outliers(&Series::Held(&x), 11, 6.0).indices.is_empty());
        for k in 0..50 {
            x[k * 997 + 13] += 0.2;
        }
        let o = find_outliers(&Series::Held(&x), 11, 6.0);
        assert_eq!(o.indices.len(), 50);
        assert!((o.median_size - 0.2).abs() < 0.02, "{o:?}");
        // Read in blocks (one not dividing the series, the scan's passes each reading
        // again), the scan finds the same, to the bit.
        let blocks = |visit: &mut dyn FnMut(&[f64])| -> Result<(), ()> {
            x.chunks(4_099).for_each(&mut *visit);
            Ok(())
        };
        assert_eq!(find_outliers_in(n, 11, 6.0, &blocks).unwrap(), o);
    }

    #[test]
    fn window_mean_squares_from_blocks_are_those_of_the_series_held() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let m: Vec<f64> = (0..10_007).map(|_| rng.random::<f64>()).collect();
        let mut whole = WindowMeanSquares::new(m.len(), 100);
        whole.add(&m);
        let whole = whole.finish();
        let mut blocks = WindowMeanSquares::new(m.len(), 100);
        m.chunks(37).for_each(|b| blocks.add(b));
        assert_eq!(blocks.finish(), whole);
        // The windows that fit with a sample to spare: starts 0, 100, ..., 9 900.
        assert_eq!(whole.len(), 100);
        let first = m[..100].iter().map(|v| v * v).sum::<f64>() / 100.0;
        assert!((whole[0] - first).abs() < 1e-15);
    }

    /// Deviations of the flagged samples from their local median (the engine's measure).
    fn flagged_deviations(x: &[f64], o: &Outliers) -> Vec<f64> {
        o.indices
            .iter()
            .map(|&i| {
                let mut b = x[i.saturating_sub(5)..(i + 6).min(x.len())].to_vec();
                let m = b.len() / 2;
                x[i] - *b.select_nth_unstable_by(m, f64::total_cmp).1
            })
            .collect()
    }

    #[test]
    fn heavy_tailed_noise_is_not_an_outlier_process() {
        // Laplace noise (scale b): its exceedances beyond 6 robust sigma decay like exp(-x/b),
        // piling up just above the threshold, as on the ADIS16405 az channel. No outlier
        // population exists; the old estimator extrapolated the count by ~50x.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 200_000;
        let b = 0.01;
        let x: Vec<f64> = (0..n)
            .map(|_| {
                let u: f64 = rng.random_range(-0.5..0.5);
                -b * u.signum() * (1.0 - 2.0 * u.abs()).ln()
            })
            .collect();
        let o = find_outliers(&Series::Held(&x), 11, 6.0);
        assert!(o.indices.len() > 50, "{} exceedances", o.indices.len());
        let devs = flagged_deviations(&x, &o);
        let p = outlier_process(&devs, 6.0 * o.robust_sigma, o.robust_sigma, n);
        assert!(!p.separated, "{p:?}");
        assert!(
            p.detection_probability < MIN_OUTLIER_DETECTION_PROBABILITY,
            "{p:?}"
        );
        // No extrapolation: the detected rate, a few per thousand, not a large fraction.
        assert!((p.probability_per_sample - o.rate).abs() < 1e-15, "{p:?}");
        assert!(p.probability_per_sample < 5e-3, "{p:?}");
    }

    #[test]
    fn an_outlier_population_is_counted_with_its_hidden_part() {
        // Gaussian noise with outliers only 5x the noise: a quarter of them show beyond
        // 6 sigma, the rest must be inferred from the spread of those that do.
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let n = 400_000;
        let (p_true, sigma_true) = (1e-3, 0.05);
        let mut x = white(&mut rng, n, 0.01);
        for v in x.iter_mut() {
            if rng.random_bool(p_true) {
                *v += sigma_true * rng.sample::<f64, _>(StandardNormal);
            }
        }
        let o = find_outliers(&Series::Held(&x), 11, 6.0);
        let devs = flagged_deviations(&x, &o);
        let p = outlier_process(&devs, 6.0 * o.robust_sigma, o.robust_sigma, n);
        assert!(p.separated, "{p:?}");
        assert!(
            p.probability_ci95[0] <= p_true && p_true <= p.probability_ci95[1],
            "{p:?}"
        );
        assert!(
            p.probability_per_sample > 2.0 * o.rate,
            "{p:?} vs {}",
            o.rate
        );
        assert!((p.sigma - sigma_true).abs() < 0.3 * sigma_true, "{p:?}");
    }

    /// Every z at every window and index, the first largest kept: what the scan's shortcut
    /// and its ring must give. Windows without a null spread (0) are not scanned.
    fn full_scan(x: &[f64], windows: &[usize], null_sd: &[f64]) -> Option<LocalStep> {
        let mut best: Option<LocalStep> = None;
        for (&w, &sd) in windows.iter().zip(null_sd) {
            if !(sd > 0.0) {
                continue;
            }
            for (i, d) in local_steps(x, w).into_iter().enumerate() {
                let var = |from: usize| {
                    let s = &x[from..from + w];
                    let m = s.iter().sum::<f64>() / w as f64;
                    s.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (w as f64 - 1.0).max(1.0)
                };
                let sd = sd.max(((var(i) + var(i + w)) / w as f64).sqrt());
                let z = d.abs() / sd;
                if best.as_ref().is_none_or(|b| z > b.z) {
                    best = Some(LocalStep {
                        index: i + w,
                        window: w,
                        size: d,
                        z,
                        sd,
                    });
                }
            }
        }
        best
    }

    #[test]
    fn the_step_scan_chooses_as_the_full_computation_does() {
        // Every z at every window and index, the first largest kept: what the scan's
        // shortcut must give, a step and a noise burst among wander.
        let mut rng = ChaCha8Rng::seed_from_u64(32);
        let windows = [16usize, 64, 256];
        for seed in 0..4 {
            let mut x = white(&mut rng, 4_000, 0.1);
            x[1_000 + 500 * seed..].iter_mut().for_each(|v| *v += 0.05);
            x[3_000..3_200].iter_mut().for_each(|v| *v *= 4.0);
            let null_sd = [0.035, 0.018, 0.009];
            let (fast, slow) = (
                local_step_scan(&Series::Held(&x), &windows, &null_sd).unwrap(),
                full_scan(&x, &windows, &null_sd).unwrap(),
            );
            assert_eq!(
                (fast.index, fast.window),
                (slow.index, slow.window),
                "seed {seed}"
            );
            assert!(
                (fast.z - slow.z).abs() < 1e-9 * slow.z,
                "{fast:?} vs {slow:?}"
            );
        }
    }

    #[test]
    fn the_scan_in_a_ring_chooses_what_the_full_computation_does() {
        // White noise with a step, an outlier and a burst, of lengths short and long against
        // the windows (some windows longer than half the series), with null spreads that
        // make the local floor bind or not, and a window left out (sd 0).
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for case in 0..60 {
            let n = [3, 40, 129, 1_000, 5_000][case % 5] + rng.random_range(0..50);
            let mut x = white(&mut rng, n, 0.05);
            if n > 20 {
                let at = rng.random_range(1..n);
                x[at..].iter_mut().for_each(|v| *v += 0.05);
                x[rng.random_range(0..n)] += 1.0;
            }
            let windows: Vec<usize> = [1usize, 4, 16, 64, 256, 1024]
                .into_iter()
                .filter(|_| rng.random_bool(0.7))
                .collect();
            let sd: Vec<f64> = windows
                .iter()
                .map(|&w| match rng.random_range(0..4) {
                    0 => 0.0,
                    1 => 1e-6,
                    _ => 0.07 / (w as f64).sqrt(),
                })
                .collect();
            let (ring, full) = (
                local_step_scan(&Series::Held(&x), &windows, &sd),
                full_scan(&x, &windows, &sd),
            );
            let case = format!("case {case}: n {n}, windows {windows:?}, sd {sd:?}");
            assert_eq!(
                ring.as_ref().map(|s| (s.index, s.window)),
                full.as_ref().map(|s| (s.index, s.window)),
                "{case}"
            );
            if let (Some(ring), Some(full)) = (ring, full) {
                assert!((ring.z - full.z).abs() <= 1e-9 * full.z, "{case}");
                assert!(
                    (ring.size - full.size).abs() <= 1e-9 * full.size.abs(),
                    "{case}"
                );
            }
        }
    }

    #[test]
    fn a_step_stands_out_of_slow_wander_at_a_short_window() {
        // Slow wander (a random walk of the same total excursion as the step) and a step:
        // at a short window only the step is large.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let n = 20_000;
        let windows = [64usize, 256, 1024];
        let noise = |rng: &mut ChaCha8Rng| -> Vec<f64> {
            let w = white(rng, n, 0.1);
            let mut level = 0.0;
            w.iter()
                .map(|v| {
                    let z: f64 = rng.sample(rand_distr::StandardNormal);
                    level += 0.0005 * z;
                    level + v
                })
                .collect()
        };
        let sims: Vec<Vec<f64>> = (0..10).map(|_| noise(&mut rng)).collect();
        let sd = local_step_null_sd(&sims, &windows);
        let null_max = sims
            .iter()
            .map(|s| local_step_scan(&Series::Held(s), &windows, &sd).unwrap().z)
            .fold(0.0f64, f64::max);
        let mut x = noise(&mut rng);
        for v in &mut x[12_000..] {
            *v += 0.08;
        }
        let s = local_step_scan(&Series::Held(&x), &windows, &sd).unwrap();
        assert!((s.index as i64 - 12_000).abs() < 64, "{s:?}");
        assert!((s.size - 0.08).abs() < 0.03, "{s:?}");
        assert!(s.z > 1.5 * null_max, "{s:?} vs null max {null_max}");
    }

    #[test]
    fn an_outlier_or_a_noise_burst_is_not_a_step() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 20_000;
        let windows = [64usize, 256, 1024];
        let sims: Vec<Vec<f64>> = (0..10).map(|_| white(&mut rng, n, 0.02)).collect();
        let sd = local_step_null_sd(&sims, &windows);
        let null_max = sims
            .iter()
            .map(|s| local_step_scan(&Series::Held(s), &windows, &sd).unwrap().z)
            .fold(0.0f64, f64::max);
        // One 2 m/s^2 outlier (100 sigma): its window's mean moves 5 null sds at 64 samples.
        let mut outlier = white(&mut rng, n, 0.02);
        outlier[7_000] += 2.0;
        let z = local_step_scan(&Series::Held(&outlier), &windows, &sd)
            .unwrap()
            .z;
        assert!(z < 1.25 * null_max, "outlier z {z} vs null max {null_max}");
        // Ten seconds of noise eight times stronger.
        let mut burst = white(&mut rng, n, 0.02);
        burst[9_000..10_000].iter_mut().for_each(|v| *v *= 8.0);
        let z = local_step_scan(&Series::Held(&burst), &windows, &sd)
            .unwrap()
            .z;
        assert!(z < 1.25 * null_max, "burst z {z} vs null max {null_max}");
        // A step of 0.02 m/s^2 (one noise sigma) still stands out.
        let mut stepped = white(&mut rng, n, 0.02);
        stepped[12_000..].iter_mut().for_each(|v| *v += 0.02);
        let s = local_step_scan(&Series::Held(&stepped), &windows, &sd).unwrap();
        assert!(
            s.z > 1.25 * null_max && (s.index as i64 - 12_000).abs() < 100,
            "{s:?}"
        );
    }

    #[test]
    fn a_step_is_sharp_and_a_ramp_is_not() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let n = 40_000;
        let sims: Vec<Vec<f64>> = (0..10).map(|_| white(&mut rng, n, 0.02)).collect();
        let window = 2048;
        // A step of 0.03 at 20000, and a ramp of the same size over 3000 samples.
        let mut stepped = white(&mut rng, n, 0.02);
        stepped[20_000..].iter_mut().for_each(|v| *v += 0.03);
        let mut ramp = white(&mut rng, n, 0.02);
        for (k, v) in ramp.iter_mut().enumerate().skip(18_500) {
            *v += 0.03 * ((k - 18_500) as f64 / 3000.0).min(1.0);
        }
        let step_z = step_sharpness(&Series::Held(&stepped), 20_000, window, &sims);
        let ramp_z = step_sharpness(&Series::Held(&ramp), 20_000, window, &sims);
        assert!(step_z < 3.0, "step {step_z}");
        assert!(ramp_z > 3.0, "ramp {ramp_z}");
    }

    #[test]
    fn the_robust_local_step_spread_follows_the_noise_not_a_step() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let windows = [64, 256, 1024];
        let x = white(&mut rng, 200_000, 0.01);
        let base = local_step_robust_sd(&Series::Held(&x), &windows);
        let mut stepped = x.clone();
        stepped[100_000..].iter_mut().for_each(|v| *v += 0.05);
        let tripled: Vec<f64> = x.iter().map(|v| 3.0 * v).collect();
        for (j, &w) in windows.iter().enumerate() {
            // White noise: a local step has sd sigma sqrt(2 / w) (overlapping windows: the
            // median rests on about n / w independent values).
            let expected = 0.01 * (2.0 / w as f64).sqrt();
            assert!(
                (base[j] / expected - 1.0).abs() < 0.12,
                "window {w}: {} vs {expected}",
                base[j]
            );
            assert!(
                (local_step_robust_sd(&Series::Held(&stepped), &windows)[j] / base[j] - 1.0).abs()
                    < 0.05
            );
            assert!(
                (local_step_robust_sd(&Series::Held(&tripled), &windows)[j] / base[j] - 3.0).abs()
                    < 1e-9
            );
        }
    }

    #[test]
    fn noise_growing_with_rate_gives_a_positive_slope() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let n = 60_000;
        let mag: Vec<f64> = (0..n)
            .map(|i| (1.0 + (i as f64 * 0.001).sin()).abs())
            .collect();
        let flat = white(&mut rng, n, 0.01);
        assert!(noise_vs_dynamics(&flat, &mag, 100).t.abs() < 4.0);
        let grow: Vec<f64> = (0..n)
            .map(|i| {
                let sd = (0.01f64.powi(2) + (0.02 * mag[i]).powi(2)).sqrt();
                sd * rng.sample::<f64, _>(StandardNormal)
            })
            .collect();
        let r = noise_vs_dynamics(&grow, &mag, 100);
        assert!(r.t > 10.0, "{r:?}");
        assert!(
            r.sigma_per_unit_ci95[0] < 0.02 && 0.02 < r.sigma_per_unit_ci95[1],
            "{r:?}"
        );
        assert!((r.intercept - 1e-4).abs() < 2e-5, "{r:?}");
    }
}
