//! `dynacal redundancy`: three or more IMUs sampled together characterise themselves without
//! a reference. Each unit is brought into the first unit's frame (the rotation from the
//! gyros, Wahba's problem solved by SVD, when the motion turns about two axes or more; the
//! lever arm from the accelerometers' differences against angular acceleration and
//! centripetal terms, the seed paper's eq. (9) between two MEMS units), then every pairwise
//! difference of the aligned signals, which cancels the motion, gives its Haar wavelet
//! variance per scale, and the units' own wavelet variances follow per scale by
//! non-negative least squares over the pairs ([`dynacal_core::redundancy::own_variances`]),
//! with each unit's white-noise variance from the finest scale. On the accelerometers the
//! lever-arm correction's own error (the angular acceleration's gyro noise times the lever
//! arms, common to the units) is taken out of the pairs first. The live white-noise level of
//! each unit over time comes from the core's [`LiveNoise`], the same code the board runs.
//!
//! What the units share cancels in every difference (a common temperature drift, the same
//! vibration): the figures are the independent parts of the errors. On static data nothing
//! needs aligning (a constant difference has no wavelet variance) and no rotation or lever
//! arm can be determined; the output says so.

mod align;
mod derivative;
mod faults;
mod grid;
pub mod report;
mod stretches;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynacal_core::redundancy::{own_variances, LiveNoise, MotionThresholds, MAX_UNITS};
use serde::Serialize;

pub use faults::{clipping_level, kind_name, FaultRecord, Ranges};

use crate::interchange::{ImuRecording, RowWriter};
use stretches::{PieceWv, Stretch, Stretches};

pub use stretches::{MARGIN_EPOCHS, STRETCH_EPOCHS};

/// Channel names in interchange order: gyros then accelerometers.
const CHANNELS: [&str; 6] = ["gx", "gy", "gz", "ax", "ay", "az"];

/// Why a set of recordings cannot be analysed together.
#[derive(Debug, thiserror::Error)]
pub enum RedundancyError {
    #[error("{0} recordings given: the analysis needs 3 to {MAX_UNITS} IMUs sampled together")]
    Units(usize),
    #[error("{name}: {message}")]
    Unit { name: String, message: String },
    #[error("{0}")]
    NoOverlap(String),
    #[error("{path}: {message}")]
    Output { path: PathBuf, message: String },
    /// A unit's file could not be read (the message names it).
    #[error("{0}")]
    Input(String),
}

/// How a unit's rotation to the first unit was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RotationBasis {
    /// The first unit itself.
    Reference,
    /// From the gyros: the motion turned about two axes or more.
    Gyros,
    /// Not determined: the motion did not turn about two axes (static data determine no
    /// rotation about gravity); the unit's axes are compared as they are.
    Undetermined,
}

/// A unit's place relative to the first unit.
#[derive(Debug, Clone, Serialize)]
pub struct Alignment {
    pub basis: RotationBasis,
    /// Rotation from the first unit's axes to this unit's (y_k = C y_0), roll-pitch-yaw, deg;
    /// None where the motion does not determine it (then it is not applied).
    pub rotation_rpy_deg: Option<[f64; 3]>,
    /// 1-sigma of the rotation about the axis the motion turned least, deg (None where it is
    /// not determined).
    pub rotation_sigma_deg: Option<f64>,
    /// Lever arm from the first unit to this one, in the first unit's axes, m, with its
    /// 1-sigma; None where it cannot be determined (no angular acceleration to see it). The
    /// sigma is the larger of the least squares' and a block jackknife's, which covers the
    /// angular acceleration's error too: over 40 simulated drives, 96.7% of the errors were
    /// within 1.96 sigma (BENCHMARKS.md).
    pub lever_arm_m: Option<[f64; 3]>,
    pub lever_arm_sigma_m: Option<[f64; 3]>,
}

/// One unit's own error wavelet variance on one channel.
#[derive(Debug, Clone, Serialize)]
pub struct OwnWv {
    pub scales_s: Vec<f64>,
    /// Own wavelet variance per scale, SI unit squared.
    pub variance: Vec<f64>,
    /// Where the least squares gave a negative variance, held at 0.
    pub clamped: Vec<bool>,
    /// 95% interval of the own wavelet variance per scale ([`own_interval`]).
    pub ci_low: Vec<f64>,
    pub ci_high: Vec<f64>,
}

/// What the set says of one unit.
#[derive(Debug, Clone, Serialize)]
pub struct UnitReport {
    pub name: String,
    pub alignment: Alignment,
    /// Own white-noise variance per channel, SI unit squared, at the unit's sample rate:
    /// twice the own wavelet variance at the finest scale (white noise of variance s^2 has
    /// s^2 / 2 there).
    pub white_noise_sigma2: BTreeMap<String, f64>,
    pub wv: BTreeMap<String, OwnWv>,
}

/// A unit's live white-noise standard deviation over time.
#[derive(Debug, Clone, Serialize)]
pub struct NoiseLevel {
    pub t_s: Vec<f64>,
    pub gyro_rad_s: Vec<f64>,
    pub accel_m_s2: Vec<f64>,
}

/// The whole analysis.
#[derive(Debug, Clone, Serialize)]
pub struct RedundancyReport {
    pub imus: Vec<UnitReport>,
    pub noise_level: Vec<NoiseLevel>,
    /// Whether the platform moved, per output time of `noise_level`.
    pub moving: Vec<bool>,
    /// Faults found, in the order they were confirmed.
    pub faults: Vec<FaultRecord>,
    pub notes: Vec<String>,
    /// The fused virtual IMU in the first unit's frame (the accelerometers at the first
    /// unit's place): the weighted mean of the healthy units on the common grid; None where
    /// the motion does not determine the units' rotations (no common frame to fuse in).
    #[serde(skip)]
    pub fused: Option<ImuRecording>,
}

/// Options of the analysis.
#[derive(Debug, Clone)]
pub struct RedundancyOptions {
    /// Time constant of the live noise level, s.
    pub live_time_constant_s: f64,
    /// Spacing of the live noise level's output, s.
    pub live_output_interval_s: f64,
    /// Per-axis range of every unit's gyros (rad/s) and accelerometers (m/s^2), for the
    /// saturation test; where None, each unit's clipping level from its own data
    /// ([`clipping_level`]).
    pub ranges: Ranges,
}

impl Default for RedundancyOptions {
    fn default() -> Self {
        Self {
            live_time_constant_s: 2.0,
            live_output_interval_s: 0.5,
            ranges: [None, None],
        }
    }
}

/// Checks that the recordings are 3 to MAX_UNITS IMUs with both triads and 64 samples or
/// more; whether they were sampled together is [`grid::common_grid`]'s to say.
fn check_units(units: &[(String, ImuRecording)]) -> Result<(), RedundancyError> {
    if !(3..=MAX_UNITS).contains(&units.len()) {
        return Err(RedundancyError::Units(units.len()));
    }
    for (name, r) in units {
        let fail = |message: String| RedundancyError::Unit {
            name: name.clone(),
            message,
        };
        if r.gyro_rad_s.is_none() || r.accel_m_s2.is_none() {
            return Err(fail("needs both a gyro and an accelerometer triad".into()));
        }
        if r.len() < 64 {
            return Err(fail(format!("{} samples: at least 64 are needed", r.len())));
        }
    }
    Ok(())
}

/// Units sampled together ride on one platform: each must show the first unit's motion
/// (a recording at rest among drives, or of another day on the same clock, is refused).
fn check_same_motion(grid: &grid::Grid) -> Result<(), RedundancyError> {
    use crate::calibration::motion::{same_motion, Quantity};
    let vectors = |triad: &Option<[Vec<f64>; 3]>| -> Vec<nalgebra::Vector3<f64>> {
        let [x, y, z] = triad.as_ref().expect("checked: both triads");
        (0..x.len())
            .map(|i| nalgebra::Vector3::new(x[i], y[i], z[i]))
            .collect()
    };
    let (first_name, first) = &grid.filled[0];
    let first_vectors = [vectors(&first.gyro_rad_s), vectors(&first.accel_m_s2)];
    for (name, unit) in &grid.filled[1..] {
        let unit_vectors = [vectors(&unit.gyro_rad_s), vectors(&unit.accel_m_s2)];
        for (q, quantity) in [Quantity::TurnRate, Quantity::SpecificForce]
            .into_iter()
            .enumerate()
        {
            same_motion(
                &grid.t_s,
                &first_vectors[q],
                &unit_vectors[q],
                quantity,
                [first_name, name],
            )
            .map_err(|m| RedundancyError::Unit {
                name: name.clone(),
                message: format!(
                    "did not move with {first_name}: {} ({}'s 1 s averages change by {:.3e} {unit} \
                     in {first_name}, {:.3e} {unit} in {name}); the units must ride on one \
                     platform",
                    m.reason,
                    quantity.name(),
                    m.variations[0],
                    m.variations[1],
                    unit = quantity.unit(),
                ),
            })?;
        }
    }
    Ok(())
}

/// The pairs of `units` units, (k, l) with k < l, in [`pair_index`] order.
fn members(units: usize) -> Vec<(usize, usize)> {
    (0..units)
        .flat_map(|k| (k + 1..units).map(move |l| (k, l)))
        .collect()
}

/// Each unit's own wavelet variance on channel `c` of `signals` (held whole), from the
/// wavelet variances of every pairwise difference, per scale. On the accelerometers, the
/// lever-arm correction's error (`correction`), common to the units, is taken out of each
/// pair first: it is not a unit's.
#[cfg(test)]
fn own_wv(
    signals: &[[Vec<f64>; 6]],
    c: usize,
    dt_s: f64,
    correction: Option<&align::CorrectionError>,
) -> Vec<OwnWv> {
    let series: Vec<&[f64]> = signals.iter().map(|s| s[c].as_slice()).collect();
    hat_of(&pair_wvs(&series, dt_s), series.len(), |level, p, q| {
        channel_common(correction, c, level, p, q, series.len())
    })
}

/// The covariance the lever-arm correction's error puts into the pairs p and q (in
/// [`members`] order) on channel c at a level: none on the gyros.
fn channel_common(
    correction: Option<&align::CorrectionError>,
    c: usize,
    level: usize,
    p: usize,
    q: usize,
    units: usize,
) -> f64 {
    match (correction, c >= 3) {
        (Some(e), true) => {
            let members = members(units);
            e.pair_covariance(c - 3, level, members[p], members[q])
        }
        _ => 0.0,
    }
}

/// Each unit's own wavelet variance from `series`, one per unit, sampled together and
/// already in one frame with nothing common left in them (the N-cornered hat of
/// [`own_variances`] at every scale, with the intervals of [`own_interval`]): what
/// [`redundancy`] computes of a channel, for a caller that simulates the units (the refit's
/// bootstrap).
pub fn own_wv_of(series: &[&[f64]], dt_s: f64) -> Vec<OwnWv> {
    hat_of(&pair_wvs(series, dt_s), series.len(), |_, _, _| 0.0)
}

/// [`own_wv_of`] of `units` series of `n` samples given a block at a time: `next(len)`
/// gives every unit's next `len` samples. In one block (`block >= n`) it is [`own_wv_of`];
/// in several, the pairs' wavelet variances are streamed (levels past 16 decimated), as a
/// long run's are ([`redundancy_of_files`]).
pub fn own_wv_of_blocks(
    units: usize,
    n: usize,
    block: usize,
    dt_s: f64,
    mut next: impl FnMut(usize) -> Vec<Vec<f64>>,
) -> Vec<OwnWv> {
    let block = block.max(1);
    let members = members(units);
    let mut pairs: Vec<PieceWv> = members
        .iter()
        .map(|_| PieceWv::new(n.div_ceil(block), dt_s))
        .collect();
    let mut done = 0;
    while done < n {
        let len = block.min(n - done);
        let series = next(len);
        for (&(k, l), wv) in members.iter().zip(pairs.iter_mut()) {
            let d: Vec<f64> = series[k]
                .iter()
                .zip(&series[l])
                .map(|(a, b)| a - b)
                .collect();
            wv.add(&d);
        }
        done += len;
    }
    hat_of(&pairs, units, |_, _, _| 0.0)
}

/// The wavelet variance of every pairwise difference of `series` held whole, in
/// [`members`] order.
fn pair_wvs(series: &[&[f64]], dt_s: f64) -> Vec<PieceWv> {
    members(series.len())
        .iter()
        .map(|&(k, l)| {
            let d: Vec<f64> = series[k]
                .iter()
                .zip(series[l])
                .map(|(a, b)| a - b)
                .collect();
            let mut wv = PieceWv::new(1, dt_s);
            wv.add(&d);
            wv
        })
        .collect()
}

/// The N-cornered hat per scale from the pairs' wavelet variances (in [`members`] order);
/// `common(level, p, q)` is the covariance the pairs p and q share beyond their units,
/// taken out of every pair.
fn hat_of(
    pairs_wv: &[PieceWv],
    units: usize,
    common: impl Fn(usize, usize, usize) -> f64,
) -> Vec<OwnWv> {
    let members = members(units);
    let results: Vec<_> = pairs_wv
        .iter()
        .map(|p| p.result().expect("at least 64 samples"))
        .collect();
    let (first, eta) = &results[0];
    let scales_s = first.scales_s.clone();
    let pair_wv: Vec<&Vec<f64>> = results.iter().map(|(wv, _)| &wv.variance).collect();
    let mut out: Vec<OwnWv> = (0..units)
        .map(|_| OwnWv {
            scales_s: scales_s.clone(),
            variance: Vec::new(),
            clamped: Vec::new(),
            ci_low: Vec::new(),
            ci_high: Vec::new(),
        })
        .collect();
    for level in 0..scales_s.len() {
        let at_level: Vec<f64> = (0..members.len())
            .map(|p| pair_wv[p][level] - common(level, p, p))
            .collect();
        let own = own_variances(units, &at_level).expect("3..=MAX_UNITS units, variances");
        let covariance: Vec<Vec<f64>> = (0..members.len())
            .map(|p| {
                (0..members.len())
                    .map(|q| {
                        if p == q {
                            pair_wv[p][level]
                        } else {
                            shared(members[p], members[q], &own.value[..units])
                                + common(level, p, q)
                        }
                    })
                    .collect()
            })
            .collect();
        for (k, o) in out.iter_mut().enumerate() {
            let (lo, hi) = own_interval(k, &covariance, &own.value[..units], eta[level]);
            o.variance.push(own.value[k]);
            o.clamped.push(own.clamped[k]);
            o.ci_low.push(lo);
            o.ci_high.push(hi);
        }
    }
    out
}

/// Covariance of the differences k - l and m - o through the unit they share (its own
/// variance `own`, signed by the side it is on), 0 for pairs that share none.
fn shared((k, l): (usize, usize), (m, o): (usize, usize), own: &[f64]) -> f64 {
    let side = |u: usize, (a, b): (usize, usize)| {
        if u == a {
            1.0
        } else if u == b {
            -1.0
        } else {
            0.0
        }
    };
    [k, l]
        .iter()
        .map(|&u| side(u, (k, l)) * side(u, (m, o)) * own[u].max(0.0))
        .sum()
}

/// 95% interval of unit k's own wavelet variance at one scale, from the covariance of the
/// pairs' wavelet coefficients (`covariance[p][q]`, p and q in [`members`] order: on the
/// diagonal each pair's wavelet variance, of eta equivalent degrees of freedom; off it, the
/// shared unit's own variance and any error common to the pairs) and the units' own
/// variances `own`. The least squares gives x_k = sum_p a_p nu_p with a_p = ([k in p] -
/// 1 / (N - 1)) / (N - 2); for Gaussian errors Cov(nu_p, nu_q) = 2 c_pq^2 / eta, so the
/// chi-square law of one wavelet variance does not carry over: the estimate gets the
/// equivalent degrees of freedom 2 x_k^2 / Var(x_k) of its own. A unit held at 0 gets
/// [0, 1.96 sd].
pub fn own_interval(k: usize, covariance: &[Vec<f64>], own: &[f64], eta: f64) -> (f64, f64) {
    let n = own.len();
    let members = members(n);
    let coefficient = |(i, j): (usize, usize)| {
        let inside = if i == k || j == k { 1.0 } else { 0.0 };
        (inside - 1.0 / (n as f64 - 1.0)) / (n as f64 - 2.0)
    };
    let mut variance = 0.0;
    for (p, &a) in members.iter().enumerate() {
        for (q, &b) in members.iter().enumerate() {
            variance += coefficient(a) * coefficient(b) * 2.0 * covariance[p][q].powi(2) / eta;
        }
    }
    let x = own[k];
    if x <= 0.0 || variance <= 0.0 {
        return (0.0, 1.96 * variance.max(0.0).sqrt());
    }
    crate::wv::chi2_interval(x, (2.0 * x * x / variance).max(1.0))
}

/// Each unit's live gyro and accelerometer white-noise level (the core's [`LiveNoise`]) and
/// the motion state, sampled every `opts.live_output_interval_s`, fed stretch by stretch.
trait LiveLevels {
    fn push(&mut self, signals: &[[Vec<f64>; 6]], stretch: &Stretch);
    fn finish(self: Box<Self>) -> (Vec<NoiseLevel>, Vec<bool>);
}

struct Live<const N: usize> {
    gyro: LiveNoise<N>,
    accel: LiveNoise<N>,
    levels: Vec<NoiseLevel>,
    moving: Vec<bool>,
    /// Epochs between outputs.
    every: usize,
}

impl<const N: usize> Live<N> {
    fn new(dt_s: f64, opts: &RedundancyOptions) -> Self {
        let tau = opts.live_time_constant_s as f32;
        Self {
            gyro: LiveNoise::<N>::new(dt_s as f32, tau, MotionThresholds::default()),
            accel: LiveNoise::<N>::new(dt_s as f32, tau, MotionThresholds::default()),
            levels: (0..N)
                .map(|_| NoiseLevel {
                    t_s: Vec::new(),
                    gyro_rad_s: Vec::new(),
                    accel_m_s2: Vec::new(),
                })
                .collect(),
            moving: Vec::new(),
            every: ((opts.live_output_interval_s / dt_s).round() as usize).max(1),
        }
    }
}

impl<const N: usize> LiveLevels for Live<N> {
    fn push(&mut self, signals: &[[Vec<f64>; 6]], stretch: &Stretch) {
        for (e, i) in (stretch.first_epoch..).zip(stretch.own.clone()) {
            let triad = |first: usize| -> [[f32; 3]; N] {
                std::array::from_fn(|k| std::array::from_fn(|a| signals[k][first + a][i] as f32))
            };
            let g = triad(0);
            let rate: [f32; 3] =
                std::array::from_fn(|a| g.iter().map(|u| u[a]).sum::<f32>() / N as f32);
            self.gyro.push(&g, rate);
            self.accel.push(&triad(3), rate);
            if e % self.every == self.every - 1 {
                for (k, level) in self.levels.iter_mut().enumerate() {
                    level.t_s.push(stretch.grid.t_s[i]);
                    level.gyro_rad_s.push(self.gyro.sigma(k) as f64);
                    level.accel_m_s2.push(self.accel.sigma(k) as f64);
                }
                self.moving.push(self.gyro.moving());
            }
        }
    }

    fn finish(self: Box<Self>) -> (Vec<NoiseLevel>, Vec<bool>) {
        (self.levels, self.moving)
    }
}

/// The live levels of `units` units.
fn live_levels(units: usize, dt_s: f64, opts: &RedundancyOptions) -> Box<dyn LiveLevels> {
    match units {
        3 => Box::new(Live::<3>::new(dt_s, opts)),
        4 => Box::new(Live::<4>::new(dt_s, opts)),
        5 => Box::new(Live::<5>::new(dt_s, opts)),
        6 => Box::new(Live::<6>::new(dt_s, opts)),
        7 => Box::new(Live::<7>::new(dt_s, opts)),
        _ => Box::new(Live::<8>::new(dt_s, opts)),
    }
}

/// The analysis of `units` (name, recording), sampled together, held whole.
pub fn redundancy(
    units: &[(String, ImuRecording)],
    opts: &RedundancyOptions,
) -> Result<RedundancyReport, RedundancyError> {
    check_units(units)?;
    let grid = grid::common_grid(units, None)?;
    let mut run = stretches::HeldRun::new(units, grid);
    let mut fused = ImuRecording {
        gyro_rad_s: Some(Default::default()),
        accel_m_s2: Some(Default::default()),
        ..Default::default()
    };
    let (mut report, one_frame) = analyse(&mut run, opts, &mut |t, row| {
        fused.t_s.push(t);
        for (c, v) in row.iter().enumerate() {
            let triad = if c < 3 {
                &mut fused.gyro_rad_s
            } else {
                &mut fused.accel_m_s2
            };
            triad.as_mut().expect("both triads")[c % 3].push(*v);
        }
        Ok(())
    })?;
    if one_frame {
        report.fused = Some(fused);
    }
    Ok(report)
}

/// What [`redundancy_of_files`] wrote besides its report.
pub struct FilesOutcome {
    pub report: RedundancyReport,
    /// Whether the fused output was written (not where the units have no common frame).
    pub fused_written: bool,
}

/// The analysis of the units' interchange files at `paths`, between `from_s` and `to_s`,
/// read stretch by stretch from spill files (memory follows a stretch of
/// `stretch_epochs` shared times, not the run), the fused virtual IMU written to `fused`
/// as it is formed (whole, or not at all).
pub fn redundancy_of_files(
    paths: &[PathBuf],
    window_s: (f64, f64),
    opts: &RedundancyOptions,
    fused: Option<&Path>,
    stretch_epochs: usize,
) -> Result<FilesOutcome, RedundancyError> {
    if !(3..=MAX_UNITS).contains(&paths.len()) {
        return Err(RedundancyError::Units(paths.len()));
    }
    let run = stretches::SpilledRun::open(paths, window_s, stretch_epochs)?;
    analyse_spilled(run, opts, fused)
}

/// The analysis of units already spilled (name, recording), read stretch by stretch as
/// [`redundancy_of_files`] reads its files.
pub fn redundancy_of_spills(
    units: Vec<(String, crate::calibration::SpilledRecording)>,
    opts: &RedundancyOptions,
    fused: Option<&Path>,
    stretch_epochs: usize,
) -> Result<FilesOutcome, RedundancyError> {
    if !(3..=MAX_UNITS).contains(&units.len()) {
        return Err(RedundancyError::Units(units.len()));
    }
    let window = (f64::NEG_INFINITY, f64::INFINITY);
    let run = stretches::SpilledRun::new(units, window, stretch_epochs)?;
    analyse_spilled(run, opts, fused)
}

/// [`analyse`] of a spilled run, the fused output written to `fused` as it is formed.
fn analyse_spilled(
    mut run: stretches::SpilledRun,
    opts: &RedundancyOptions,
    fused: Option<&Path>,
) -> Result<FilesOutcome, RedundancyError> {
    let output = |path: &Path| {
        let path = path.to_path_buf();
        move |e: crate::interchange::TableError| RedundancyError::Output {
            path: path.clone(),
            message: e.to_string(),
        }
    };
    let fused_error = fused.map(output);
    let columns = vec![
        "t_s", "gx_rad_s", "gy_rad_s", "gz_rad_s", "ax_m_s2", "ay_m_s2", "az_m_s2",
    ];
    let mut writer = fused
        .map(|p| RowWriter::create(p, columns, Some(1.0 / run.dt_s())).map_err(output(p)))
        .transpose()?;
    let mut rows = 0u64;
    let (report, one_frame) = analyse(&mut run, opts, &mut |t, row| {
        rows += 1;
        match writer.as_mut() {
            Some(w) => {
                let mut values = [t; 7];
                values[1..].copy_from_slice(&row);
                w.push(&values)
                    .map_err(fused_error.as_ref().expect("a writer has a path"))
            }
            None => Ok(()),
        }
    })?;
    let fused_written = match (writer, fused) {
        (Some(w), Some(p)) if one_frame && rows > 0 => {
            w.finish().map_err(output(p))?;
            true
        }
        _ => false,
    };
    Ok(FilesOutcome {
        report,
        fused_written,
    })
}

/// What the first pass over the run gathers: the rotations' sums and what the notes say of
/// the grid.
struct Survey {
    rotations: align::RotationSums,
    epochs: usize,
    /// Per unit: shared times without its sample.
    missing: Vec<usize>,
    /// Per unit: its rate against the grid's, summed weighted by the stretches' epochs.
    rate_sums: Vec<f64>,
    /// Per unit: the furthest its samples were from their grid times, s.
    furthest_s: Vec<f64>,
    anchor: usize,
    spacing: Spacing,
}

/// The grid's steps against its median step.
#[derive(Default)]
struct Spacing {
    dt_s: Option<f64>,
    steps: usize,
    uneven: usize,
    gaps: usize,
    longest_gap_s: f64,
}

impl Survey {
    fn new(units: usize) -> Self {
        Self {
            rotations: align::RotationSums::new(units),
            epochs: 0,
            missing: vec![0; units],
            rate_sums: vec![0.0; units],
            furthest_s: vec![0.0; units],
            anchor: 0,
            spacing: Spacing::default(),
        }
    }

    fn push(&mut self, stretch: &Stretch, dt_s: f64) -> Result<(), RedundancyError> {
        let grid = &stretch.grid;
        check_same_motion(grid)?;
        let own = stretch.own.clone();
        self.epochs += own.len();
        self.anchor = grid.anchor;
        for k in 0..self.missing.len() {
            self.missing[k] += grid.present[k][own.clone()].iter().filter(|p| !**p).count();
            self.rate_sums[k] += grid.rate_offset[k] * own.len() as f64;
            let furthest = grid.offset_s[k][own.clone()]
                .iter()
                .fold(0.0_f64, |m, o| m.max(o.abs()));
            self.furthest_s[k] = self.furthest_s[k].max(furthest);
        }
        let spacing = &mut self.spacing;
        let dt = *spacing.dt_s.get_or_insert_with(|| {
            crate::interchange::median_step_s(&grid.t_s).unwrap_or(f64::NAN)
        });
        for i in own.filter(|i| *i > 0 && dt.is_finite()) {
            let step = grid.t_s[i] - grid.t_s[i - 1];
            spacing.steps += 1;
            if step > 1.5 * dt {
                spacing.gaps += 1;
                spacing.longest_gap_s = spacing.longest_gap_s.max(step);
            }
            if (step / dt - 1.0).abs() > 0.1 {
                spacing.uneven += 1;
            }
        }
        self.rotations.push(stretch, dt_s);
        Ok(())
    }
}

/// The analysis of a run, stretch by stretch, in three passes: the grid's notes and the
/// rotations; the platform's motion and the lever arms; the aligned signals' wavelet
/// variances, live levels and monitors, with the fused output to `fused`. Also says whether
/// the units are in one frame (else nothing was fused).
fn analyse(
    run: &mut dyn Stretches,
    opts: &RedundancyOptions,
    fused: &mut faults::FusedSink,
) -> Result<(RedundancyReport, bool), RedundancyError> {
    let names = run.names().to_vec();
    let units = names.len();
    let dt_s = run.dt_s();
    let mut survey = Survey::new(units);
    run.for_each(&mut |stretch| survey.push(stretch, dt_s))?;
    let mut notes = vec![
        "what the units share (a common temperature drift, the same vibration) cancels in \
         every difference: these are the independent parts of the units' errors"
            .to_string(),
    ];
    note_dropouts(&names, &survey.missing, survey.epochs, &mut notes);
    note_clocks(&names, &survey, &mut notes);
    note_spacing(&survey.spacing, &mut notes);
    let rotations = survey.rotations.finish();
    let pieces = run.count();
    let mut noise = align::DerivativeNoise::new(align::determined_units(&rotations), pieces, dt_s);
    let mut levers = align::LeverSums::new(units, survey.epochs);
    run.for_each(&mut |stretch| {
        align::push_motion(stretch, &rotations, dt_s, &mut noise, &mut levers);
        Ok(())
    })?;
    let aligned = align::alignments(&names, rotations, &noise, &levers, &mut notes);
    let clipping = run.clipping()?;
    let ranges: Vec<Ranges> = clipping
        .iter()
        .map(|own| [0, 1].map(|sensor| opts.ranges[sensor].or(own[sensor])))
        .collect();
    let setup = faults::MonitorSetup {
        dt_s,
        ranges: &ranges,
        lengths_only: aligned.unobservable,
    };
    let mut monitors = faults::monitors(units, &setup);
    let mut live = live_levels(units, dt_s, opts);
    let members = members(units);
    let mut pair_wv: Vec<Vec<PieceWv>> = (0..6)
        .map(|_| members.iter().map(|_| PieceWv::new(pieces, dt_s)).collect())
        .collect();
    run.for_each(&mut |stretch| {
        let signals = align::aligned_signals(stretch, &aligned, dt_s);
        for (c, channel) in pair_wv.iter_mut().enumerate() {
            for (&(k, l), wv) in members.iter().zip(channel.iter_mut()) {
                let d: Vec<f64> = stretch
                    .own
                    .clone()
                    .map(|i| signals[k][c][i] - signals[l][c][i])
                    .collect();
                wv.add(&d);
            }
        }
        live.push(&signals, stretch);
        let monitored = faults::MonitorStretch {
            signals: &signals,
            raw: &stretch.grid.filled,
            present: &stretch.grid.present,
            t_s: &stretch.grid.t_s,
            own: stretch.own.clone(),
            first_epoch: stretch.first_epoch,
        };
        monitors.push(&monitored, fused)
    })?;
    let per_channel: Vec<Vec<OwnWv>> = (0..6)
        .map(|c| {
            hat_of(&pair_wv[c], units, |level, p, q| {
                channel_common(aligned.correction_error.as_ref(), c, level, p, q, units)
            })
        })
        .collect();
    let imus = names
        .iter()
        .zip(aligned.alignments.clone())
        .enumerate()
        .map(|(k, (name, alignment))| {
            let wv: BTreeMap<String, OwnWv> = CHANNELS
                .iter()
                .zip(&per_channel)
                .map(|(c, own)| (c.to_string(), own[k].clone()))
                .collect();
            UnitReport {
                name: name.clone(),
                alignment,
                white_noise_sigma2: wv
                    .iter()
                    .map(|(c, w)| (c.clone(), 2.0 * w.variance[0]))
                    .collect(),
                wv,
            }
        })
        .collect();
    let (noise_level, moving) = live.finish();
    let monitoring = monitors.finish();
    note_faults(&monitoring, !aligned.unobservable, units, &mut notes);
    Ok((
        RedundancyReport {
            imus,
            noise_level,
            moving,
            faults: monitoring.faults,
            notes,
            fused: None,
        },
        !aligned.unobservable,
    ))
}

/// What the output must say of a grid whose times are not evenly spaced (a logger's pauses
/// and late samples): the analysis takes the samples as evenly spaced.
fn note_spacing(spacing: &Spacing, notes: &mut Vec<String>) {
    let Some(dt) = spacing.dt_s.filter(|dt| dt.is_finite()) else {
        return;
    };
    if spacing.uneven > 0 {
        notes.push(format!(
            "the shared times are not evenly spaced: {} of {} steps differ from the median \
             {dt:.4} s by more than 10%, {} of them gaps (the longest {:.3} s), at the same times \
             in every unit; the samples are analysed as evenly spaced (the units' differences \
             do not depend on the motion's timing, but a wavelet scale's time and the angular \
             acceleration across a gap do)",
            spacing.uneven, spacing.steps, spacing.gaps, spacing.longest_gap_s
        ));
    }
}

/// What the output must say of units on their own clocks: how far their rates and
/// instants are from the grid's.
fn note_clocks(names: &[String], survey: &Survey, notes: &mut Vec<String>) {
    let dt_s = survey
        .spacing
        .dt_s
        .filter(|dt| dt.is_finite())
        .unwrap_or(0.0);
    let anchor = &names[survey.anchor];
    for (k, name) in names.iter().enumerate() {
        let furthest_s = survey.furthest_s[k];
        let rate = survey.rate_sums[k] / survey.epochs.max(1) as f64;
        // Within a quarter interval, units stamped together with some jitter.
        if furthest_s <= 0.25 * dt_s {
            continue;
        }
        notes.push(format!(
            "{name}: sampled on its own clock, {:+.1} ppm against {anchor}'s over the run, its \
             samples up to {:.3} ms from the shared times: each is taken at the shared time \
             nearest, its motion (what stands above the noise) carried to that time, and a \
             shared time its slower clock passed over is filled from its neighbours",
            rate * 1e6,
            furthest_s * 1e3
        ));
    }
}

/// What the output must say of units that missed samples.
fn note_dropouts(names: &[String], missing: &[usize], epochs: usize, notes: &mut Vec<String>) {
    for (name, missing) in names.iter().zip(missing) {
        if *missing > 0 {
            notes.push(format!(
                "{name}: no sample at {missing} of the {epochs} shared times (dropouts): filled by \
                 interpolation for its wavelet variances, left out of the fused output"
            ));
        }
    }
}

/// What the output must say of the fault monitoring.
fn note_faults(
    monitoring: &faults::Monitoring,
    one_frame: bool,
    units: usize,
    notes: &mut Vec<String>,
) {
    if monitoring.faults.iter().any(|f| f.imu.is_none()) {
        notes.push(
            "with only two healthy units left, a disagreement is detected but cannot be placed: \
             such faults have no imu, and neither unit is excluded"
                .into(),
        );
    }
    if monitoring.unfused > 0 {
        notes.push(format!(
            "at {} sensor samples no unit was healthy: the fused output there is the plain mean \
             of the units present",
            monitoring.unfused
        ));
    }
    if !one_frame {
        notes.push(
            "the motion does not show every unit's rotation (static data see only gravity), so \
             the units' axes are not in one frame: faults are sought in the rotation-invariant lengths of the gyro and \
             accelerometer vectors only (a fault along one axis shows little in a length), \
             and there is no fused output"
                .into(),
        );
    }
    if units == 3 {
        notes.push(
            "three units isolate one faulty unit at a time; while one is out, the other two \
             only detect"
                .into(),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// The own wavelet variances' 95% intervals cover the truth at least 93% of the time,
    /// per unit and scale, on three units of white noise of very different levels (where
    /// one unit's own variance is a small difference of the others' large ones), 300 seeds,
    /// levels 1 to 4. Measured 97% to 100%: the intervals are conservative, as the eta3
    /// degrees of freedom of the pairs' wavelet variances are (an interval that ignored the
    /// pairs' covariance, or took one pair's chi-square law, would fall below).
    #[test]
    fn the_own_wavelet_variance_intervals_cover_the_truth() {
        let sd = [0.5, 1.0, 2.0];
        let n = 2048;
        let levels = 4;
        let mut covered = [[0u32; 4]; 3];
        let seeds = 300;
        for seed in 0..seeds {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let signals: Vec<[Vec<f64>; 6]> = sd
                .iter()
                .map(|s| {
                    let d = Normal::new(0.0, *s).unwrap();
                    let mut six: [Vec<f64>; 6] = Default::default();
                    six[0] = (0..n).map(|_| d.sample(&mut rng)).collect();
                    six
                })
                .collect();
            let own = own_wv(&signals, 0, 0.01, None);
            for (k, o) in own.iter().enumerate() {
                for (j, c) in covered[k].iter_mut().enumerate().take(levels) {
                    // Haar WV of white noise at level j + 1: s^2 / 2^(j + 1).
                    let truth = sd[k].powi(2) / f64::from(1u32 << (j + 1));
                    *c += u32::from(o.ci_low[j] <= truth && truth <= o.ci_high[j]);
                }
            }
        }
        for (k, unit) in covered.iter().enumerate() {
            for (j, c) in unit.iter().enumerate() {
                let rate = f64::from(*c) / seeds as f64;
                assert!(rate >= 0.93, "unit {k} level {}: {rate}", j + 1);
            }
        }
    }
}
