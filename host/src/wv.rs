//! Batch Haar MODWT wavelet variance (WV) of one sensor channel, with 95% chi-square
//! ("eta3") intervals, the equivalent overlapping Allan variance, an optional robust
//! (Tukey biweight M-scale) estimate, and a reader for the reference WVs published by
//! SMAC-Group (`golden/smac_wavelet_variance.json`). The WV is what the GMWM fit consumes.
//!
//! Conventions (Percival & Walden 2000; Guerrier et al. 2013; `wv` R package):
//! - level j = 1..J, Haar filter width tau_j = 2^j samples, scale `scales_s[j-1] = 2^j dt`;
//! - W_{j,t} = 2^-j [ sum_{l<h} X_{t-l} - sum_{h<=l<2h} X_{t-l} ], h = 2^{j-1};
//! - unbiased estimator: the first 2^j - 1 (boundary) coefficients are dropped, leaving
//!   M_j = N - 2^j + 1, and nu2_j = sum W_{j,t}^2 / M_j (no mean removal: the filter sums to 0);
//! - default maximum level J = floor(log2 N) - 1, as the `wv` package (`gmwm` uses floor(log2 N));
//! - interval: eta_j = max(M_j / 2^j, 1), [eta nu / q(0.975; eta), eta nu / q(0.025; eta)];
//! - overlapping Allan variance at averaging time 2^{j-1} dt (= `scales_s / 2`) is 2 nu2_j.
//!
//! Numerics: W is computed from prefix sums, W_{j,t} = 2^-j (S_{t+1} - 2 S_{t+1-h} + S_{t+1-2h}).
//! A plain f64 running sum of raw data loses digits (its magnitude grows like N x mean while W
//! stays at the noise level), so the series is first centred on its (compensated) mean and then
//! summed with Neumaier compensation; integer counts ([`haar_wv_counts`]) are summed exactly in
//! i64. The coefficients of all levels are formed in one cache-friendly pass over blocks of the
//! prefix-sum array, the blocks spread over threads with rayon; memory is one f64 per sample.

use std::path::{Path, PathBuf};

pub mod stream;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, Continuous, ContinuousCDF};

/// The Haar wavelet variance of one channel, level by level (index i is level `levels[i]`).
///
/// Units: `variance`, `ci_low`, `ci_high` and `allan_variance` are in the square of the input
/// unit (e.g. (deg/s)^2); `scales_s` and `dt_s` in seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WaveletVariance {
    /// Haar filter width 2^j dt of each level, seconds.
    pub scales_s: Vec<f64>,
    /// Decomposition level j (1-based).
    pub levels: Vec<u32>,
    /// Wavelet variance nu2_j, input unit squared.
    pub variance: Vec<f64>,
    /// Lower end of the 95% interval of nu2_j.
    pub ci_low: Vec<f64>,
    /// Upper end of the 95% interval of nu2_j.
    pub ci_high: Vec<f64>,
    /// Overlapping Allan variance at averaging time 2^{j-1} dt (see [`Self::allan_tau_s`]):
    /// exactly 2 nu2_j.
    pub allan_variance: Vec<f64>,
    /// Number of samples of the series.
    pub n: usize,
    /// Number of wavelet coefficients averaged at each level (M_j = N - 2^j + 1 for the batch
    /// estimator; fewer for the decimated levels of a streaming snapshot).
    pub n_coefficients: Vec<usize>,
    /// Whether `variance` is the robust (Tukey biweight M-scale) estimate.
    pub robust: bool,
    /// Sampling interval, seconds.
    pub dt_s: f64,
}

/// Options of [`haar_wv`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WvOptions {
    /// Highest level J; `None` means floor(log2 N) - 1 (the `wv` R package's choice).
    pub max_level: Option<u32>,
    /// Robust estimate: Tukey biweight M-estimate of the scale of each level's coefficients.
    pub robust: bool,
    /// Asymptotic efficiency at Gaussian data of the robust scale estimate, in [0.3, 0.99]
    /// (used only when `robust`). 0.6 by default, as the reference implementation.
    pub efficiency: f64,
}

impl Default for WvOptions {
    fn default() -> Self {
        Self {
            max_level: None,
            robust: false,
            efficiency: 0.6,
        }
    }
}

/// Errors of the wavelet-variance computations and readers.
#[derive(Debug, thiserror::Error)]
pub enum WvError {
    #[error("wavelet variance needs at least 4 samples, got {n}")]
    TooShort { n: usize },
    #[error("sample {index} is not a finite number ({value})")]
    NonFinite { index: usize, value: f64 },
    #[error("sampling interval must be positive and finite, got {dt_s} s")]
    BadInterval { dt_s: f64 },
    #[error("max level {requested} is out of range 1..={max} for {n} samples (2^J must be <= N)")]
    BadLevel { requested: u32, max: u32, n: usize },
    #[error("robust efficiency {efficiency} is out of range [0.3, 0.99]")]
    BadEfficiency { efficiency: f64 },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{path}: {what}")]
    Format { path: PathBuf, what: String },
    #[error("streaming snapshot: {what}")]
    Snapshot { what: String },
}

/// Two-sided 95% interval: tail probability on each side.
const ALPHA_OVER_2: f64 = 0.025;

impl WaveletVariance {
    /// Number of levels.
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Averaging time of each `allan_variance` entry: 2^{j-1} dt = `scales_s / 2`, seconds.
    pub fn allan_tau_s(&self) -> Vec<f64> {
        self.scales_s.iter().map(|s| s / 2.0).collect()
    }

    /// Overlapping Allan deviation sqrt(2 nu2_j) at [`Self::allan_tau_s`].
    pub fn allan_deviation(&self) -> Vec<f64> {
        self.allan_variance.iter().map(|v| v.sqrt()).collect()
    }

    /// Variance of each estimate nu2_j, for GMWM weighting Omega = diag(1 / var).
    ///
    /// Taken from the 95% interval: var = ((ci_high - ci_low) / (2 z_0.975))^2. Under the
    /// chi-square model behind the interval (eta nu_hat / nu ~ chi2(eta)) the estimate's variance
    /// is 2 nu^2 / eta, and for large eta the interval width is 2 z sqrt(2 / eta) nu, so both
    /// agree; at the top levels (eta of a few) the interval is skewed and wider, which
    /// down-weights those noisy levels a little more. Using the interval makes this available
    /// for every source of WV (batch, robust, streaming snapshot, published reference values).
    pub fn estimate_variance(&self) -> Vec<f64> {
        let two_z = 2.0 * 1.959_963_984_540_054;
        self.ci_low
            .iter()
            .zip(&self.ci_high)
            .map(|(lo, hi)| ((hi - lo) / two_z).powi(2))
            .collect()
    }

    /// Assembles a WV from per-level sums (the common tail of every estimator): fills scales,
    /// eta3 intervals with `eta_j = dof_factor * max(M_j / 2^j, 1)` degrees of freedom and the
    /// Allan variance.
    fn from_levels(
        levels: Vec<u32>,
        variance: Vec<f64>,
        n_coefficients: Vec<usize>,
        eta: Vec<f64>,
        n: usize,
        dt_s: f64,
        robust: bool,
    ) -> Self {
        let (ci_low, ci_high) = variance
            .iter()
            .zip(&eta)
            .map(|(&nu, &eta)| chi2_interval(nu, eta))
            .unzip();
        Self {
            scales_s: levels.iter().map(|&j| (1u64 << j) as f64 * dt_s).collect(),
            allan_variance: variance.iter().map(|v| 2.0 * v).collect(),
            levels,
            variance,
            ci_low,
            ci_high,
            n,
            n_coefficients,
            robust,
            dt_s,
        }
    }
}

impl WaveletVariance {
    /// The wavelet variance of several separate stretches of one series (a recording's
    /// static stretches): at each level, the coefficients of every stretch long enough for
    /// it pooled, nu_j = sum_k M_jk nu_jk / sum_k M_jk, with eta3 degrees of freedom of the
    /// pooled count, max(sum_k M_jk / 2^j, 1), as one stretch of that many coefficients
    /// would have. No coefficient straddles two stretches, so a jump between them (a bias
    /// that wandered while the sensor moved) adds nothing. Levels run up to the highest any
    /// stretch reaches. `None` when no part is given, or the parts' intervals or robustness
    /// differ.
    pub fn pooled(parts: &[WaveletVariance]) -> Option<Self> {
        let first = parts.first()?;
        if parts
            .iter()
            .any(|p| p.dt_s != first.dt_s || p.robust != first.robust || p.robust)
        {
            return None;
        }
        let top = parts.iter().flat_map(|p| p.levels.iter().copied()).max()?;
        let (mut levels, mut variance, mut m, mut eta) = (vec![], vec![], vec![], vec![]);
        for j in 1..=top {
            let (mut sum, mut count) = (0.0, 0usize);
            for p in parts {
                if let Some(i) = p.levels.iter().position(|&l| l == j) {
                    sum += p.variance[i] * p.n_coefficients[i] as f64;
                    count += p.n_coefficients[i];
                }
            }
            if count > 0 {
                levels.push(j);
                variance.push(sum / count as f64);
                m.push(count);
                eta.push(eta3(count, j));
            }
        }
        let n = parts.iter().map(|p| p.n).sum();
        Some(Self::from_levels(
            levels, variance, m, eta, n, first.dt_s, false,
        ))
    }
}

impl WaveletVariance {
    /// The wavelet variance accumulated on the board ([`dynacal_core::wavelet::HaarStream`]),
    /// in physical units: `lsb` units per count, `dt_s` seconds per sample. Levels without a
    /// coefficient yet are left out; a saturated level is an error.
    ///
    /// Full levels get the batch estimator's eta3 interval (their sums are the batch sums).
    /// Decimated levels use only every h-th coefficient (h = 2^{j-1}); for white noise that
    /// multiplies the estimate's variance by 9/4 (see `dynacal_core::wavelet`), so they get
    /// eta = max((K / 2) / (9/4), 1) = max(2K / 9, 1) degrees of freedom from K coefficients,
    /// K h / 2^j = K / 2 being the batch eta3 of the same stretch of data.
    pub fn from_stream_snapshot(
        snapshot: &dynacal_core::wavelet::WvSnapshot,
        lsb: f64,
        dt_s: f64,
    ) -> Result<Self, WvError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(WvError::BadInterval { dt_s });
        }
        let (mut levels, mut variance, mut m, mut eta) = (vec![], vec![], vec![], vec![]);
        for sums in snapshot.levels.iter() {
            if sums.saturated {
                return Err(WvError::Snapshot {
                    what: format!("level {} saturated", sums.level),
                });
            }
            let Some(nu) = sums.variance_counts2() else {
                break;
            };
            let j = u32::from(sums.level);
            if levels.last().is_some_and(|&prev| prev + 1 != j) {
                return Err(WvError::Snapshot {
                    what: format!("level {j} does not follow level {}", levels.last().unwrap()),
                });
            }
            levels.push(j);
            variance.push(nu * lsb * lsb);
            m.push(sums.count as usize);
            eta.push(if sums.stride_log2 == 0 {
                eta3(sums.count as usize, j)
            } else {
                (2.0 * sums.count as f64 / 9.0).max(1.0)
            });
        }
        Ok(Self::from_levels(
            levels,
            variance,
            m,
            eta,
            snapshot.n_samples as usize,
            dt_s,
            false,
        ))
    }
}

/// M_j, the Haar MODWT coefficients of level `level` over `n` samples: n - 2^j + 1 (none
/// when the level is wider than the series).
pub fn level_coefficients(n: usize, level: u32) -> usize {
    (n + 1).saturating_sub(1 << level)
}

/// The eta3 equivalent degrees of freedom of level j from M_j coefficients: max(M_j / 2^j, 1).
pub fn eta3(m_j: usize, level: u32) -> f64 {
    (m_j as f64 / (1u64 << level) as f64).max(1.0)
}

/// 95% chi-square interval [eta nu / q(0.975), eta nu / q(0.025)] of a variance estimate `nu`
/// with `eta` equivalent degrees of freedom.
pub fn chi2_interval(nu: f64, eta: f64) -> (f64, f64) {
    let q_hi = chi2_quantile(eta, 1.0 - ALPHA_OVER_2);
    let q_lo = chi2_quantile(eta, ALPHA_OVER_2);
    (eta * nu / q_hi, eta * nu / q_lo)
}

/// Chi-square quantile to full double precision: statrs' inverse (bisection then at most four
/// Newton steps, converged to about 1e-9 relative only) polished by Newton steps kept inside a
/// bracket of the root (plain Newton overshoots below 0 for one degree of freedom).
fn chi2_quantile(dof: f64, p: f64) -> f64 {
    let dist = ChiSquared::new(dof).expect("dof >= 1 by construction");
    let start = match dist.inverse_cdf(p) {
        x if x.is_finite() && x > 0.0 => x,
        _ => dof, // statrs gives NaN for some large dof; the mean is a fine start
    };
    let (mut lo, mut hi) = (start, start);
    while lo > f64::MIN_POSITIVE && dist.cdf(lo) > p {
        lo *= 0.5;
    }
    while hi < f64::MAX / 4.0 && dist.cdf(hi) < p {
        hi *= 2.0;
    }
    let mut x = start;
    for _ in 0..100 {
        let error = dist.cdf(x) - p;
        if error == 0.0 {
            break;
        }
        if error > 0.0 {
            hi = x;
        } else {
            lo = x;
        }
        let newton = x - error / dist.pdf(x);
        let next = if newton > lo && newton < hi {
            newton
        } else {
            0.5 * (lo + hi)
        };
        let done = (next - x).abs() <= 1e-15 * x.abs();
        x = next;
        if done {
            break;
        }
    }
    x
}

/// Default maximum level floor(log2 N) - 1 (at least 1).
pub fn default_max_level(n: usize) -> u32 {
    (n.max(2).ilog2()).saturating_sub(1).max(1)
}

fn resolve_max_level(n: usize, opts: &WvOptions) -> Result<u32, WvError> {
    if n < 4 {
        return Err(WvError::TooShort { n });
    }
    let max = n.ilog2();
    match opts.max_level {
        None => Ok(default_max_level(n)),
        Some(j) if (1..=max).contains(&j) => Ok(j),
        Some(j) => Err(WvError::BadLevel {
            requested: j,
            max,
            n,
        }),
    }
}

fn check_common(dt_s: f64, opts: &WvOptions) -> Result<(), WvError> {
    if !(dt_s.is_finite() && dt_s > 0.0) {
        return Err(WvError::BadInterval { dt_s });
    }
    if opts.robust && !(0.3..=0.99).contains(&opts.efficiency) {
        return Err(WvError::BadEfficiency {
            efficiency: opts.efficiency,
        });
    }
    Ok(())
}

/// Samples up to which [`haar_wv_of_blocks`] gathers a series for the batch estimator (8
/// MiB): below 2^20 samples the streamed estimator's levels are all overlapping, the batch's.
pub const GATHERED_SAMPLES: usize = 1 << 20;

/// A visit of a series a block at a time, in order.
pub type BlockFeed<'a> = dyn FnMut(&mut dyn FnMut(&[f64])) + 'a;

/// [`haar_wv`] (levels 1..=`max_level`, all when None) of a series of `len` samples that
/// `feed` gives a block at a time, in memory that does not grow with it: gathered for the
/// batch estimator up to [`GATHERED_SAMPLES`], streamed above ([`stream::HaarWvStream`],
/// overlapping to level [`stream::HaarWvStream::DEFAULT_FULL_LEVELS`], as `dynacal wv`
/// streams a long file). An error when the series is too short or not finite (its first
/// such sample named).
pub fn haar_wv_of_blocks(
    len: usize,
    dt_s: f64,
    max_level: Option<u32>,
    feed: &mut BlockFeed<'_>,
) -> Result<WaveletVariance, WvError> {
    if len <= GATHERED_SAMPLES {
        let mut all = Vec::with_capacity(len);
        feed(&mut |block| all.extend_from_slice(block));
        let opts = WvOptions {
            max_level,
            ..WvOptions::default()
        };
        return haar_wv(&all, dt_s, &opts);
    }
    let mut stream = stream::HaarWvStream::new(stream::HaarWvStream::DEFAULT_FULL_LEVELS);
    let (mut seen, mut not_finite) = (0, None);
    feed(&mut |block| {
        if not_finite.is_none() {
            not_finite = block
                .iter()
                .position(|v| !v.is_finite())
                .map(|k| WvError::NonFinite {
                    index: seen + k,
                    value: block[k],
                });
        }
        seen += block.len();
        stream.push_block(block);
    });
    match not_finite {
        Some(e) => Err(e),
        None => stream.wavelet_variance(max_level, 1.0, dt_s),
    }
}

/// Haar MODWT wavelet variance of `x` (any unit) sampled every `dt_s` seconds, all levels
/// 1..=J. See the module documentation for the estimator and its conventions.
pub fn haar_wv(x: &[f64], dt_s: f64, opts: &WvOptions) -> Result<WaveletVariance, WvError> {
    let mut buf = Vec::with_capacity(x.len() + 1);
    buf.extend_from_slice(x);
    haar_wv_owned(buf, dt_s, opts)
}

/// [`haar_wv`] of a series the caller is done with: its prefix sums are built in the series'
/// own memory, so no second array of its length is allocated (new pages cost more than the
/// summing: at 4e6 samples, 32 MB of first touches), nor the series moved (the sums take one
/// value more, at the end: room for it spares a copy). The same result, to the bit.
pub fn haar_wv_owned(
    mut x: Vec<f64>,
    dt_s: f64,
    opts: &WvOptions,
) -> Result<WaveletVariance, WvError> {
    let n = x.len();
    check_common(dt_s, opts)?;
    let j_max = resolve_max_level(n, opts)?;
    if let Some(index) = crate::numeric::first_non_finite(&x) {
        return Err(WvError::NonFinite {
            index,
            value: x[index],
        });
    }
    centred_prefix_sums_in_place(&mut x);
    Ok(wv_from_prefix(&x, n, j_max, 1.0, dt_s, opts))
}

/// Haar MODWT wavelet variance of integer counts, `lsb` physical units per count: the same
/// estimator as [`haar_wv`] on `counts * lsb`, but with exact integer prefix sums, so the
/// coefficients carry no rounding error at all before they are squared.
pub fn haar_wv_counts(
    counts: &[i32],
    lsb: f64,
    dt_s: f64,
    opts: &WvOptions,
) -> Result<WaveletVariance, WvError> {
    check_common(dt_s, opts)?;
    let j_max = resolve_max_level(counts.len(), opts)?;
    // Centring on an integer keeps the sums small; the Haar filter ignores constants. While
    // |S| < 2^51 (always in practice: centred counts sum like a random walk) every S and every
    // S_a - 2 S_b + S_c is an integer below 2^53, so the f64 kernel forms the Haar differences
    // exactly; beyond, each S is rounded once (still 1e-16 relative).
    let mean = counts.iter().map(|&c| c as i64).sum::<i64>() / counts.len() as i64;
    let mut sum = 0i64;
    let mut prefix = Vec::with_capacity(counts.len() + 1);
    prefix.push(0.0);
    prefix.extend(counts.iter().map(|&c| {
        sum += c as i64 - mean;
        sum as f64
    }));
    Ok(wv_from_prefix(
        &prefix,
        counts.len(),
        j_max,
        lsb,
        dt_s,
        opts,
    ))
}

/// Prefix sums S_k = sum_{i<k} (x_i - m), k = 0..=N, with m the mean of x (any constant
/// would do: the Haar filter ignores it; the mean keeps |S| smallest), the running sum carried
/// with a compensation term (Knuth's branch-free TwoSum), so each stored S_k is within one
/// rounding of the exact value. `buf` holds x on entry and S_0..=S_N on return: S_k is
/// written where x_k was read (then S_N pushed), so nothing moves. Parallel over chunks: the
/// chunks' compensated sums give each chunk its starting value, then every chunk continues
/// the compensated running sum.
fn centred_prefix_sums_in_place(buf: &mut Vec<f64>) {
    const CHUNK: usize = 1 << 16;
    let x = buf.as_slice();
    // Partial sums collected in order (not rayon's `sum`, whose order varies between runs) so
    // results are bit-for-bit reproducible.
    let partial: Vec<f64> = x.par_chunks(CHUNK).map(|c| c.iter().sum()).collect();
    let mean = partial.iter().sum::<f64>() / x.len().max(1) as f64;
    let chunk_sums: Vec<(f64, f64)> = x
        .par_chunks(CHUNK)
        .map(|c| {
            c.iter().fold((0.0, 0.0), |(sum, comp), &v| {
                let (t, e) = two_sum(sum, v - mean);
                (t, comp + e)
            })
        })
        .collect();
    // Starting value (sum, compensation) of each chunk.
    let mut starts = Vec::with_capacity(chunk_sums.len());
    let (mut sum, mut comp) = (0.0f64, 0.0f64);
    for &(s, c) in &chunk_sums {
        starts.push((sum, comp));
        let (t, e) = two_sum(sum, s);
        sum = t;
        comp += e + c;
    }
    // Each chunk's sum after its last value: the next chunk's first S (carried on from the
    // chunk's values, as a serial pass would), and the last chunk's S_N.
    let ends: Vec<f64> = buf
        .par_chunks_mut(CHUNK)
        .zip(starts.par_iter())
        .map(|(chunk, &(mut sum, mut comp))| {
            for slot in chunk {
                let value = *slot;
                *slot = sum + comp;
                let (t, e) = two_sum(sum, value - mean);
                sum = t;
                comp += e;
            }
            sum + comp
        })
        .collect();
    for (k, &end) in ends.iter().enumerate().take(ends.len().saturating_sub(1)) {
        buf[(k + 1) * CHUNK] = end;
    }
    buf.push(ends.last().copied().unwrap_or(0.0));
}

/// Knuth's TwoSum: a + b = s + e exactly, with s = fl(a + b). No branch, so a running sum
/// built on it pipelines.
#[inline(always)]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let b_virtual = s - a;
    let a_virtual = s - b_virtual;
    (s, (a - a_virtual) + (b - b_virtual))
}

/// Compensated (Neumaier) sum.
pub(crate) fn neumaier_sum(values: impl Iterator<Item = f64>) -> f64 {
    let (mut sum, mut comp) = (0.0f64, 0.0f64);
    for v in values {
        let t = sum + v;
        if sum.abs() >= v.abs() {
            comp += (sum - t) + v;
        } else {
            comp += (v - t) + sum;
        }
        sum = t;
    }
    sum + comp
}

/// Block length (in coefficients) of the all-levels pass: three 64 KiB windows per level stay
/// in L2 while every level is swept over the block.
const BLOCK: usize = 8192;

/// Sum over t of (2^j W_{j,t})^2 for every level 1..=j_max, from prefix sums `s` (length N+1).
fn level_square_sums(s: &[f64], j_max: u32) -> Vec<f64> {
    let n = s.len() - 1;
    let blocks: Vec<Vec<f64>> = (1..=n)
        .step_by(BLOCK)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|start| {
            let end = (start + BLOCK).min(n + 1);
            (1..=j_max)
                .map(|j| {
                    let h = 1usize << (j - 1);
                    let first = start.max(2 * h);
                    if first >= end {
                        return 0.0;
                    }
                    squared_haar_sum(
                        &s[first..end],
                        &s[first - h..end - h],
                        &s[first - 2 * h..end - 2 * h],
                    )
                })
                .collect()
        })
        .collect();
    (0..j_max as usize)
        .map(|level| neumaier_sum(blocks.iter().map(|b| b[level])))
        .collect()
}

/// sum_k (a_k - 2 b_k + c_k)^2 with eight independent accumulators so the loop vectorises;
/// compiled again for wider vector units as [`stream`]'s level sums are (the same result to
/// the bit on any of them).
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn squared_haar_sum(a: &[f64], b: &[f64], c: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (a8, b8, c8) = (a.chunks_exact(8), b.chunks_exact(8), c.chunks_exact(8));
    let (ar, br, cr) = (a8.remainder(), b8.remainder(), c8.remainder());
    for ((a, b), c) in a8.zip(b8).zip(c8) {
        for l in 0..8 {
            let d = (a[l] - b[l]) - (b[l] - c[l]);
            acc[l] += d * d;
        }
    }
    let mut tail = 0.0;
    for ((a, b), c) in ar.iter().zip(br).zip(cr) {
        let d = (a - b) - (b - c);
        tail += d * d;
    }
    acc.iter().sum::<f64>() + tail
}

fn wv_from_prefix(
    prefix: &[f64],
    n: usize,
    j_max: u32,
    unit: f64,
    dt_s: f64,
    opts: &WvOptions,
) -> WaveletVariance {
    let levels: Vec<u32> = (1..=j_max).collect();
    let m: Vec<usize> = levels.iter().map(|&j| n + 1 - (1usize << j)).collect();
    let eta: Vec<f64> = levels.iter().zip(&m).map(|(&j, &m)| eta3(m, j)).collect();
    if opts.robust {
        let tuning = BiweightScale::for_efficiency(opts.efficiency)
            .expect("efficiency range checked by check_common");
        let mut coeffs = Vec::with_capacity(n);
        let variance = levels
            .iter()
            .map(|&j| {
                haar_coefficients(prefix, j, &mut coeffs);
                let scale = tuning.scale(&coeffs);
                scale * scale * unit * unit
            })
            .collect();
        let eta = eta.iter().map(|e| e * opts.efficiency).collect();
        WaveletVariance::from_levels(levels, variance, m, eta, n, dt_s, true)
    } else {
        let sums = level_square_sums(prefix, j_max);
        let variance = levels
            .iter()
            .zip(&sums)
            .zip(&m)
            .map(|((&j, &ss), &m)| {
                let width = (1u64 << j) as f64;
                ss / (width * width) / m as f64 * unit * unit
            })
            .collect();
        WaveletVariance::from_levels(levels, variance, m, eta, n, dt_s, false)
    }
}

/// The M_j non-boundary coefficients W_{j,t} (t = 2^j - 1 .. N-1) of level j, into `out`.
fn haar_coefficients(s: &[f64], j: u32, out: &mut Vec<f64>) {
    let h = 1usize << (j - 1);
    let inv_width = 1.0 / (2 * h) as f64;
    let n = s.len() - 1;
    out.clear();
    out.par_extend(
        (2 * h..=n)
            .into_par_iter()
            .map(|k| ((s[k] - s[k - h]) - (s[k - h] - s[k - 2 * h])) * inv_width),
    );
}

/// Tukey biweight M-estimate of scale, made consistent for the standard deviation at Gaussian
/// data: sigma solves mean(rho(w / sigma)) = b, with rho(r) = 1 - (1 - (r/c)^2)^3 for |r| <= c
/// and 1 beyond, b = E[rho(Z)] for Z standard normal. The tuning constant c is chosen for a
/// given asymptotic efficiency relative to the Gaussian maximum-likelihood scale (for 0.6,
/// c = 1.7295 and b = 0.4561, so the breakdown point b is 46%). Unlike the reference implementation (which
/// solves a psi-type equation whose left side is not monotone in sigma), rho is monotone, so
/// the root is unique and found by a bracketed Newton iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiweightScale {
    /// Tuning constant c (in units of sigma).
    pub c: f64,
    /// Consistency constant b = E[rho(Z)], Z ~ N(0, 1).
    pub b: f64,
}

impl BiweightScale {
    /// Tuning for asymptotic efficiency `efficiency` in [0.3, 0.99] at the Gaussian.
    pub fn for_efficiency(efficiency: f64) -> Result<Self, WvError> {
        if !(0.3..=0.99).contains(&efficiency) {
            return Err(WvError::BadEfficiency { efficiency });
        }
        // Efficiency increases with c: bisection.
        let (mut lo, mut hi) = (0.5f64, 60.0f64);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if Self::efficiency_of(mid) < efficiency {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let c = 0.5 * (lo + hi);
        Ok(Self {
            c,
            b: Self::gaussian_mean(c, |r| rho(r, c)),
        })
    }

    /// Asymptotic efficiency of the scale estimate with tuning c: 0.5 / V with
    /// V = E[(rho - b)^2] / E[Z rho'(Z)]^2 (0.5 is the maximum-likelihood value).
    pub fn efficiency_of(c: f64) -> f64 {
        let b = Self::gaussian_mean(c, |r| rho(r, c));
        let var = Self::gaussian_mean(c, |r| (rho(r, c) - b).powi(2));
        let slope = Self::gaussian_mean(c, |r| r * rho_prime(r, c));
        0.5 / (var / (slope * slope))
    }

    /// E[f(Z)] for a function that is constant (= f(c)) for |z| > c: Simpson on [0, c] plus
    /// the Gaussian tail mass.
    fn gaussian_mean(c: f64, f: impl Fn(f64) -> f64) -> f64 {
        let intervals = 4000;
        let h = c / intervals as f64;
        let phi = |z: f64| (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
        let mut acc = f(0.0) * phi(0.0) + f(c) * phi(c);
        for i in 1..intervals {
            let z = i as f64 * h;
            acc += if i % 2 == 1 { 4.0 } else { 2.0 } * f(z) * phi(z);
        }
        let tail = statrs::function::erf::erfc(c / std::f64::consts::SQRT_2);
        2.0 * acc * h / 3.0 + tail * f(c + 1.0)
    }

    /// The M-estimate of scale sigma of `w` (same unit as `w`); 0 if more than a fraction 1-b
    /// of `w` is exactly 0.
    pub fn scale(&self, w: &[f64]) -> f64 {
        if w.is_empty() {
            return 0.0;
        }
        let n = w.len() as f64;
        // Start from the normalised median absolute value (robust, near the answer).
        let mut abs: Vec<f64> = w.par_iter().map(|v| v.abs()).collect();
        let mid = abs.len() / 2;
        let (_, median, _) = abs.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        let mut sigma = *median / 0.674_489_750_196_081_7;
        drop(abs);
        if sigma <= 0.0 {
            let rms = (w.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
            if rms == 0.0 {
                return 0.0;
            }
            sigma = rms;
        }
        // g(log sigma) = mean rho(w / sigma) - b decreases in sigma. Bracket, then Newton in
        // log sigma with bisection fallback.
        let g = |sigma: f64| -> (f64, f64) {
            // Fixed chunks summed in order: reproducible bit for bit whatever the threads do.
            let partial: Vec<(f64, f64)> = w
                .par_chunks(1 << 14)
                .map(|chunk| {
                    chunk.iter().fold((0.0, 0.0), |acc, &v| {
                        let r = v / sigma;
                        (acc.0 + rho(r, self.c), acc.1 + r * rho_prime(r, self.c))
                    })
                })
                .collect();
            let (sr, srp) = partial
                .iter()
                .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            (sr / n - self.b, -srp / n)
        };
        let (mut lo, mut hi) = (sigma, sigma);
        while g(lo).0 < 0.0 && lo > f64::MIN_POSITIVE * 1e10 {
            lo /= 2.0;
        }
        while g(hi).0 > 0.0 && hi < f64::MAX / 4.0 {
            hi *= 2.0;
        }
        let mut log_s = sigma.ln().clamp(lo.ln(), hi.ln());
        for _ in 0..200 {
            let (value, slope) = g(log_s.exp());
            if value > 0.0 {
                lo = log_s.exp();
            } else {
                hi = log_s.exp();
            }
            let newton = log_s - value / slope;
            let next = if slope < 0.0 && newton > lo.ln() && newton < hi.ln() {
                newton
            } else {
                0.5 * (lo.ln() + hi.ln())
            };
            if (next - log_s).abs() < 1e-14 || (hi.ln() - lo.ln()) < 1e-14 {
                log_s = next;
                break;
            }
            log_s = next;
        }
        log_s.exp()
    }
}

fn rho(r: f64, c: f64) -> f64 {
    let u = (r / c) * (r / c);
    if u >= 1.0 {
        1.0
    } else {
        1.0 - (1.0 - u).powi(3)
    }
}

fn rho_prime(r: f64, c: f64) -> f64 {
    let u = (r / c) * (r / c);
    if u >= 1.0 {
        0.0
    } else {
        6.0 * r / (c * c) * (1.0 - u).powi(2)
    }
}

/// One sensor channel of the SMAC-Group reference file.
#[derive(Debug, Clone)]
pub struct GoldenWv {
    /// Key of the sensor in the file (`adis`, `imar`, `kvh1750`, `ln200`, `navchip`).
    pub sensor_key: String,
    /// Human name of the sensor as given in the file.
    pub sensor: String,
    /// Channel name as given in the file (`Gyro. X`, ..., `Accel. Z`).
    pub channel: String,
    /// The WV in the file's units; `n_coefficients` and the Allan variance are derived.
    pub wv: WaveletVariance,
}

impl GoldenWv {
    /// dynacal's channel key (`gx` .. `az`) for the file's channel name, if it is one of them.
    pub fn channel_key(&self) -> Option<&'static str> {
        let axis = match self.channel.chars().last()? {
            'X' => 0,
            'Y' => 1,
            'Z' => 2,
            _ => return None,
        };
        if self.channel.starts_with("Gyro") {
            Some(crate::interchange::CHANNELS[axis])
        } else if self.channel.starts_with("Accel") {
            Some(crate::interchange::CHANNELS[3 + axis])
        } else {
            None
        }
    }
}

#[derive(Deserialize)]
struct GoldenSensorJson {
    sensor: String,
    freq: f64,
    n: usize,
    wvar: serde_json::Map<String, serde_json::Value>,
}

#[derive(Deserialize)]
struct GoldenChannelJson {
    scales: Vec<f64>,
    variance: Vec<f64>,
    ci_low: Vec<f64>,
    ci_high: Vec<f64>,
}

/// Reads `golden/smac_wavelet_variance.json` (`{sensor: {sensor, freq, n, wvar: {channel:
/// {scales, variance, ci_low, ci_high}}}}`) into one [`GoldenWv`] per sensor channel, sorted
/// by sensor key then channel name. Checks that every scale is 2^j / freq for j = 1, 2, ... and that the arrays agree in
/// length; errors name the sensor and channel.
pub fn read_smac_golden(path: &Path) -> Result<Vec<GoldenWv>, WvError> {
    let text = std::fs::read_to_string(path).map_err(|source| WvError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let sensors: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(&text).map_err(|source| WvError::Json {
            path: path.to_path_buf(),
            source,
        })?;
    let format = |what: String| WvError::Format {
        path: path.to_path_buf(),
        what,
    };
    let mut out = Vec::new();
    for (key, value) in sensors {
        let sensor: GoldenSensorJson =
            serde_json::from_value(value).map_err(|e| format(format!("sensor `{key}`: {e}")))?;
        if !(sensor.freq.is_finite() && sensor.freq > 0.0) {
            return Err(format(format!("sensor `{key}`: bad freq {}", sensor.freq)));
        }
        let dt_s = 1.0 / sensor.freq;
        for (channel, value) in sensor.wvar {
            let at = format!("sensor `{key}` channel `{channel}`");
            let ch: GoldenChannelJson =
                serde_json::from_value(value).map_err(|e| format(format!("{at}: {e}")))?;
            let len = ch.scales.len();
            if ch.variance.len() != len || ch.ci_low.len() != len || ch.ci_high.len() != len {
                return Err(format(format!("{at}: arrays differ in length")));
            }
            let levels: Vec<u32> = (1..=len as u32).collect();
            for (&j, &scale) in levels.iter().zip(&ch.scales) {
                let expected = (1u64 << j) as f64 * dt_s;
                if (scale - expected).abs() > 1e-9 * expected {
                    return Err(format(format!(
                        "{at}: scale {scale} at level {j} is not 2^{j}/freq = {expected}"
                    )));
                }
                if (1usize << j) > sensor.n {
                    return Err(format(format!("{at}: level {j} exceeds n = {}", sensor.n)));
                }
            }
            let n_coefficients = levels
                .iter()
                .map(|&j| level_coefficients(sensor.n, j))
                .collect();
            out.push(GoldenWv {
                sensor_key: key.clone(),
                sensor: sensor.sensor.clone(),
                channel,
                wv: WaveletVariance {
                    scales_s: ch.scales,
                    allan_variance: ch.variance.iter().map(|v| 2.0 * v).collect(),
                    levels,
                    variance: ch.variance,
                    ci_low: ch.ci_low,
                    ci_high: ch.ci_high,
                    n: sensor.n,
                    n_coefficients,
                    robust: false,
                    dt_s,
                },
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn gaussian(seed: u64, n: usize, sigma: f64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let dist = Normal::new(0.0, sigma).unwrap();
        (0..n).map(|_| dist.sample(&mut rng)).collect()
    }

    /// The prefix sums built in the series' own memory are the ones built beside it: same
    /// chunks, same order, so the same bits, at a length of several chunks and a partial one.
    #[test]
    fn a_series_worked_on_in_place_gives_the_borrowed_result_to_the_bit() {
        let n = 3 * (1 << 16) + 12_345;
        let mut walk = 0.0;
        let x: Vec<f64> = gaussian(5, n, 1e-3)
            .into_iter()
            .zip(gaussian(6, n, 1e-6))
            .map(|(white, step)| {
                walk += step;
                0.5 + walk + white
            })
            .collect();
        for opts in [
            WvOptions::default(),
            WvOptions {
                robust: true,
                ..WvOptions::default()
            },
        ] {
            let borrowed = haar_wv(&x, 0.01, &opts).unwrap();
            let owned = haar_wv_owned(x.clone(), 0.01, &opts).unwrap();
            assert_eq!(owned, borrowed);
        }
        let mut bad = x;
        bad[70_000] = f64::NAN;
        let e = haar_wv_owned(bad, 0.01, &WvOptions::default()).unwrap_err();
        assert!(
            matches!(e, WvError::NonFinite { index: 70_000, .. }),
            "{e:?}"
        );
    }

    #[test]
    fn prefix_sums_built_in_place_are_the_serial_compensated_sums() {
        // Three and a bit chunks, so every chunk boundary's sum is carried across.
        let n = 3 * (1 << 16) + 4_321;
        let x: Vec<f64> = gaussian(21, n, 1e-3).iter().map(|v| 0.5 + v).collect();
        let mut sums = x.clone();
        centred_prefix_sums_in_place(&mut sums);
        assert_eq!(sums.len(), n + 1);
        // The serial compensated running sum, in the chunks' order of operations: each
        // chunk's values summed from the same start as the parallel pass.
        let mean = x
            .chunks(1 << 16)
            .map(|c| c.iter().sum::<f64>())
            .sum::<f64>()
            / n as f64;
        let (mut sum, mut comp) = (0.0f64, 0.0f64);
        let mut exact_enough = vec![0.0];
        for &v in &x {
            let (t, e) = two_sum(sum, v - mean);
            sum = t;
            comp += e;
            exact_enough.push(sum + comp);
        }
        for (k, (got, want)) in sums.iter().zip(&exact_enough).enumerate() {
            let ulp = want.abs().max(f64::MIN_POSITIVE) * f64::EPSILON;
            assert!(
                (got - want).abs() <= 2.0 * ulp,
                "S_{k}: {got} against {want}"
            );
        }
        assert_eq!(sums[0], 0.0);
    }

    #[test]
    fn pooled_stretches_ignore_the_jump_between_them() {
        let opts = WvOptions::default();
        let a = gaussian(11, 4096, 0.5);
        let b = gaussian(12, 2048, 0.5);
        let shifted: Vec<f64> = b.iter().map(|x| x + 100.0).collect();
        let wa = haar_wv(&a, 0.01, &opts).unwrap();
        let pooled =
            WaveletVariance::pooled(&[wa.clone(), haar_wv(&b, 0.01, &opts).unwrap()]).unwrap();
        let pooled_shifted =
            WaveletVariance::pooled(&[wa.clone(), haar_wv(&shifted, 0.01, &opts).unwrap()])
                .unwrap();
        assert_eq!(
            pooled.levels, wa.levels,
            "levels up to the longest stretch's"
        );
        assert_eq!(pooled.n, 4096 + 2048);
        for j in 0..pooled.len() {
            let rel = (pooled.variance[j] - pooled_shifted.variance[j]).abs() / pooled.variance[j];
            assert!(rel < 1e-9, "level {}: {rel}", pooled.levels[j]);
        }
        // Level 1: M = 4095 + 2047 coefficients, white noise's 0.25 / 2 within its interval.
        assert_eq!(pooled.n_coefficients[0], 4095 + 2047);
        assert!(pooled.ci_low[0] < 0.125 && 0.125 < pooled.ci_high[0]);
        // Concatenated, the jump dominates every coarse level instead.
        let joined: Vec<f64> = a.iter().chain(&shifted).copied().collect();
        let whole = haar_wv(&joined, 0.01, &opts).unwrap();
        assert!(whole.variance[8] > 100.0 * pooled.variance[8]);
        // One part pools to itself.
        let alone = WaveletVariance::pooled(std::slice::from_ref(&wa)).unwrap();
        assert_eq!(alone.variance, wa.variance);
        assert_eq!(alone.ci_low, wa.ci_low);
    }

    #[test]
    fn chi_square_quantiles_are_accurate_down_to_one_dof() {
        // Reference values: scipy.stats.chi2.ppf.
        let cases = [
            (1.0, 0.025, 0.000_982_069_117_175_255_5),
            (1.0, 0.975, 5.023_886_187_314_888),
            (10.0, 0.025, 3.246_972_780_236_841),
            (3.8, 0.975, 10.794_240_173_527_653),
        ];
        for (dof, p, q) in cases {
            let got = chi2_quantile(dof, p);
            assert!(
                ((got - q) / q).abs() < 1e-9,
                "dof {dof} p {p}: {got} vs {q}"
            );
        }
        let more = [
            (1.004, 0.001_012_498_535_929_695_7, 5.034_817_489_441_242),
            (2.5, 0.118_622_942_100_063_45, 8.392_295_266_912_964),
            (40.0, 24.433_039_170_807_888, 59.341_707_143_173_18),
            (5e5, 498_041.931_008_642_5, 501_961.857_602_028_8),
        ];
        for (dof, q_lo, q_hi) in more {
            for (p, q) in [(0.025, q_lo), (0.975, q_hi)] {
                let got = chi2_quantile(dof, p);
                assert!(
                    ((got - q) / q).abs() < 1e-12,
                    "dof {dof} p {p}: {got} vs {q}"
                );
            }
        }
        // Every interval of a short series is finite and positive (top level has eta = 1).
        let x = gaussian(9, 512, 1.0);
        let wv = haar_wv(&x, 0.01, &WvOptions::default()).unwrap();
        assert!(wv
            .ci_low
            .iter()
            .chain(&wv.ci_high)
            .all(|v| v.is_finite() && *v > 0.0));
    }

    #[test]
    fn default_max_level_follows_wv_package() {
        assert_eq!(default_max_level(1_000_000), 18);
        assert_eq!(default_max_level(1024), 9);
        assert_eq!(default_max_level(1023), 8);
        let x = gaussian(1, 1024, 1.0);
        assert_eq!(haar_wv(&x, 0.01, &WvOptions::default()).unwrap().len(), 9);
        let all = WvOptions {
            max_level: Some(10),
            ..Default::default()
        };
        let wv = haar_wv(&x, 0.01, &all).unwrap();
        assert_eq!((wv.len(), wv.n_coefficients[9]), (10, 1));
        let too_deep = WvOptions {
            max_level: Some(11),
            ..Default::default()
        };
        assert!(matches!(
            haar_wv(&x, 0.01, &too_deep),
            Err(WvError::BadLevel { requested: 11, .. })
        ));
        let mut bad = x.clone();
        bad[17] = f64::NAN;
        assert!(matches!(
            haar_wv(&bad, 0.01, &WvOptions::default()),
            Err(WvError::NonFinite { index: 17, .. })
        ));
    }

    /// Brute force from the definition, summing in f64 over exactly the same coefficients.
    fn direct_wv(x: &[f64], j: u32) -> f64 {
        let h = 1usize << (j - 1);
        let width = (2 * h) as f64;
        let mut sum = 0.0;
        let mut m = 0;
        for t in (2 * h - 1)..x.len() {
            let recent: f64 = x[t + 1 - h..=t].iter().sum();
            let older: f64 = x[t + 1 - 2 * h..=t - h].iter().sum();
            sum += ((recent - older) / width).powi(2);
            m += 1;
        }
        sum / m as f64
    }

    #[test]
    fn matches_definition_and_white_noise_theory() {
        let x = gaussian(2, 5000, 3.0);
        let wv = haar_wv(&x, 0.5, &WvOptions::default()).unwrap();
        for (i, &j) in wv.levels.iter().enumerate() {
            let direct = direct_wv(&x, j);
            assert!(
                ((wv.variance[i] - direct) / direct).abs() < 1e-12,
                "level {j}"
            );
            assert_eq!(wv.scales_s[i], 0.5 * (1u64 << j) as f64);
            assert!(wv.ci_low[i] < wv.variance[i] && wv.variance[i] < wv.ci_high[i]);
        }
        // White noise: nu_j = s2 / 2^j; level 1 has thousands of coefficients.
        assert!((wv.variance[0] / (9.0 / 2.0) - 1.0).abs() < 0.05);
    }

    #[test]
    fn large_offset_and_random_walk_keep_digits() {
        // An accelerometer-like series: 1 g offset, a random-walk bias, 1e-3 noise, as exact
        // integer counts of 1e-6 g; the f64 path must agree with the exact integer path.
        let n = 1 << 20;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 1000.0).unwrap();
        let walk = Normal::new(0.0, 3.0).unwrap();
        let mut bias = 0.0f64;
        let counts: Vec<i32> = (0..n)
            .map(|_| {
                bias += walk.sample(&mut rng);
                (1_000_000.0 + bias + noise.sample(&mut rng)).round() as i32
            })
            .collect();
        let lsb = 1e-6;
        let exact = haar_wv_counts(&counts, lsb, 0.01, &WvOptions::default()).unwrap();
        let x: Vec<f64> = counts.iter().map(|&c| c as f64 * lsb).collect();
        let float = haar_wv(&x, 0.01, &WvOptions::default()).unwrap();
        for i in 0..exact.len() {
            let err = ((float.variance[i] - exact.variance[i]) / exact.variance[i]).abs();
            assert!(err < 1e-11, "level {}: {err:e}", i + 1);
        }
    }

    #[test]
    fn biweight_tuning_reaches_requested_efficiency() {
        let t = BiweightScale::for_efficiency(0.6).unwrap();
        assert!((BiweightScale::efficiency_of(t.c) - 0.6).abs() < 1e-9);
        // Independent check (scipy quad + brentq on the same definitions): c = 1.72947,
        // b = 0.456109.
        assert!((t.c - 1.729_47).abs() < 1e-4, "c = {}", t.c);
        assert!((t.b - 0.456_109).abs() < 1e-5, "b = {}", t.b);
        // Monte Carlo at iid Gaussian data: consistency (mean near sigma) and efficiency
        // (variance of the robust scale over that of the RMS, the Gaussian MLE of the scale of
        // zero-mean data) near 1 / 0.6.
        let (reps, n) = (600, 2000);
        let (mut robust, mut rms) = (vec![], vec![]);
        for r in 0..reps {
            let x = gaussian(100 + r, n, 2.0);
            robust.push(t.scale(&x));
            rms.push((x.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt());
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let var = |v: &[f64]| {
            let m = mean(v);
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64
        };
        assert!(
            (mean(&robust) / 2.0 - 1.0).abs() < 0.005,
            "{}",
            mean(&robust)
        );
        let efficiency = var(&rms) / var(&robust);
        assert!((0.5..0.7).contains(&efficiency), "efficiency {efficiency}");
    }

    #[test]
    fn robust_wv_resists_outliers_and_widens_interval() {
        let mut x = gaussian(4, 1 << 16, 1.0);
        for i in (0..x.len()).step_by(500) {
            x[i] += 80.0; // 0.2% spikes
        }
        let classical = haar_wv(&x, 1.0, &WvOptions::default()).unwrap();
        let opts = WvOptions {
            robust: true,
            ..Default::default()
        };
        let robust = haar_wv(&x, 1.0, &opts).unwrap();
        assert!(robust.robust);
        // Truth at level 1 is 1/2: the spikes inflate the classical estimate many times over.
        assert!(classical.variance[0] > 5.0, "{}", classical.variance[0]);
        assert!(
            (robust.variance[0] / 0.5 - 1.0).abs() < 0.05,
            "{}",
            robust.variance[0]
        );
        // Same data without spikes: the robust interval is the wider one (fewer dof).
        let clean = gaussian(4, 1 << 16, 1.0);
        let c = haar_wv(&clean, 1.0, &WvOptions::default()).unwrap();
        let r = haar_wv(&clean, 1.0, &opts).unwrap();
        let width = |w: &WaveletVariance| (w.ci_high[0] - w.ci_low[0]) / w.variance[0];
        assert!(width(&r) > 1.2 * width(&c));
        assert!((r.variance[0] / c.variance[0] - 1.0).abs() < 0.05);
    }

    #[test]
    fn estimate_variance_agrees_with_chi_square_model() {
        let x = gaussian(5, 1 << 18, 1.0);
        let wv = haar_wv(&x, 1.0, &WvOptions::default()).unwrap();
        let v = wv.estimate_variance();
        // For many degrees of freedom, var = 2 nu^2 / eta.
        let eta = eta3(wv.n_coefficients[0], 1);
        let model = 2.0 * wv.variance[0].powi(2) / eta;
        assert!((v[0] / model - 1.0).abs() < 0.01);
    }

    #[test]
    fn golden_reader_rejects_inconsistent_scales() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.json");
        std::fs::write(
            &path,
            r#"{"s": {"sensor": "S", "freq": 100, "n": 1000, "wvar": {"Gyro. X":
               {"scales": [0.02, 0.05], "variance": [1, 2], "ci_low": [0.5, 1], "ci_high": [2, 3]}}}}"#,
        )
        .unwrap();
        let err = read_smac_golden(&path).unwrap_err().to_string();
        assert!(
            err.contains("channel `Gyro. X`") && err.contains("level 2"),
            "{err}"
        );
    }
}
