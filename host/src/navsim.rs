//! The board's fusion filter on a simulated car drive, on the host, in the scalar asked
//! (`dynacal navsim`): three units and a GNSS receiver from a model file, GNSS outages spread
//! through the run, and the filter measured against the truth (position and attitude error,
//! with GNSS and through the outages, and its consistency: the normalised estimation error
//! squared of position, velocity and attitude). The same source runs in `f64`, `f32` and
//! Q32.32 fixed point (`dynacal_core::fusion::BoardFusion<T>`, `T` a
//! `dynacal_core::scalar::FilterScalar`), so what a scalar costs is measured on one drive.
//!
//! The drive is streamed ([`drive::StreamedDrive`]): the trajectory and the fixes are built
//! for the whole run, and each sample set is made when the filter needs it, so a day of
//! driving fits in memory.

pub mod consistency;
pub mod drive;

use dynacal_core::board_model::BoardModel;
use dynacal_core::scalar::FilterScalar;
use nalgebra::{DMatrix, SMatrix, UnitQuaternion, Vector3};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use crate::model::SimModel;
use crate::progress::Tally;
use crate::sim::trajectory::Truth;
use consistency::ClosedLoop;
use drive::{DriveError, StreamedDrive};
use dynacal_core::fusion::{BoardFusion, FusionConfig, FusionFilter, UNITS};
use dynacal_core::nav::ekf::{
    boresight_index, ACCEL_BIAS, ATT, CALIBRATION_STATES_PER_IMU, GYRO_BIAS, NAV_STATES, POS, VEL,
};
use dynacal_core::nav::radii;

/// The default drive's units and receiver (`examples/models/three-units-200hz.json`).
const THREE_UNIT_MODEL: &str = include_str!("../../examples/models/three-units-200hz.json");

/// Three MEMS units at 200 Hz on one board and a 10 Hz receiver: the default drive.
pub fn three_unit_model() -> SimModel {
    SimModel::from_json(
        THREE_UNIT_MODEL,
        std::path::Path::new("examples/models/three-units-200hz.json"),
    )
    .expect("the built-in model is valid")
}

/// The filter's scalar.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Scalar {
    /// Double precision: the reference.
    F64,
    /// Single precision: what the Cortex-M4F board runs.
    F32,
    /// Fixed point, Q32.32 (`dynacal_core::fixed::I32F32`): for boards without an FPU.
    Fixed,
}

impl Scalar {
    /// The scalar's name, as `--scalar` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Scalar::F64 => "f64",
            Scalar::F32 => "f32",
            Scalar::Fixed => "fixed",
        }
    }
}

/// What to run.
#[derive(Debug, Clone, Copy)]
pub struct NavSimOptions {
    /// Length of the drive, s.
    pub seconds: f64,
    pub seed: u64,
    /// Length of each GNSS outage, s (0: none).
    pub outage_s: f64,
    pub scalar: Scalar,
}

/// Simulated seconds between two NEES samples. The bounds take the samples as independent;
/// errors this far apart are not quite (the position error's memory with GNSS is seconds,
/// an outage's drift tens of seconds), so the bounds are somewhat too narrow, and closer
/// samples would make them narrower still.
pub const NEES_EVERY_S: f64 = 10.0;
/// The navigation counts as "with GNSS" again this long after an outage ends, s.
pub const SETTLE_AFTER_OUTAGE_S: f64 = 30.0;
/// Dimension of the NEES: position, velocity and attitude errors.
const NEES_STATES: usize = 9;

/// The fusion filter's states: its 15 navigation states, then each extra unit's calibration.
const FILTER_STATES: usize = NAV_STATES + CALIBRATION_STATES_PER_IMU * (UNITS - 1);

/// The fusion filter's covariance in f64, taken once at each judged sample.
type Covariance = SMatrix<f64, FILTER_STATES, FILTER_STATES>;
/// States of the board's filter: the navigation states and each extra unit's calibration.
pub const STATES: usize = NAV_STATES + (UNITS - 1) * CALIBRATION_STATES_PER_IMU;

/// The filter's state groups, with their first index and length (variances in the squared
/// units of `dynacal_core::nav::ekf`'s state table).
pub const STATE_GROUPS: [(&str, usize, usize); 8] = [
    ("position, m^2", POS, 3),
    ("velocity, (m/s)^2", VEL, 3),
    ("roll and pitch, rad^2", ATT, 2),
    ("heading, rad^2", ATT + 2, 1),
    ("accel bias, (m/s^2)^2", ACCEL_BIAS, 3),
    ("gyro bias, (rad/s)^2", GYRO_BIAS, 3),
    ("boresights, rad^2", boresight_index(0), 3),
    ("lever arms, m^2", boresight_index(0) + 3, 3),
];

/// What a run measured.
#[derive(Debug, Clone, Serialize)]
pub struct NavSimReport {
    pub scalar: Scalar,
    pub seconds: f64,
    pub seed: u64,
    /// The GNSS outages, [start, end] s.
    pub outages_s: Vec<[f64; 2]>,
    /// When the filter started (alignment done), s.
    pub aligned_after_s: f64,
    /// RMS of the 3-D position error with GNSS (outside outages and
    /// [`SETTLE_AFTER_OUTAGE_S`] after them), m, every second.
    pub position_rms_m: f64,
    /// RMS of the 3-D position error during the outages, m, every second.
    pub position_rms_outage_m: f64,
    /// RMS of the attitude error angle over the run, deg, every second.
    pub attitude_rms_deg: f64,
    /// Mean NEES of position, velocity and attitude (9 states), every [`NEES_EVERY_S`].
    pub nees_mean: f64,
    /// The same of each block alone, position, velocity and attitude (3 states each, so 3
    /// for a consistent filter), at the same samples: which part of the state a NEES off
    /// its dimension comes from.
    pub nees_mean_by_block: [f64; 3],
    /// Two-sided 95% bounds of that mean for a consistent filter: a chi-square matched to
    /// the mean's variance that the filter's own closed-loop error correlation between the
    /// samples predicts ([`consistency::ClosedLoop`]); the independent samples' bounds
    /// where that cannot be stated ([`Self::nees_judged_by`] says which).
    pub nees_bounds: [f64; 2],
    pub nees_samples: u64,
    /// What the samples are worth as independent ones, by that prediction: errors
    /// [`NEES_EVERY_S`] apart are not independent (a heading error lasts the drive, an
    /// outage's drift tens of seconds).
    pub nees_effective_samples: f64,
    /// The bounds if the samples were independent (chi-square with 9 x samples degrees of
    /// freedom, over the samples): too narrow for correlated samples.
    pub nees_bounds_independent: [f64; 2],
    /// How [`Self::nees_bounds`] were found: `the filter's error correlation`, or why not.
    pub nees_judged_by: String,
    /// Mean NEES of the extra units' calibration states (boresight and lever arm of both
    /// units, 12 states) against the mounts the drive built, every [`NEES_EVERY_S`]: a
    /// consistent filter's is near 12, a filter too sure of its calibrations far above.
    pub calibration_nees_mean: f64,
    /// The largest true speed while the fusion took the platform to be at rest (its
    /// zero-velocity updates then claim zero to within their sigma), m/s, every set: a
    /// drive-off the standstill test is slow to see shows here.
    pub still_speed_max_m_s: f64,
    /// How far apart the covariance's numbers lay over the run (every [`NEES_EVERY_S`]).
    pub covariance: CovarianceSpread,
    /// Numbers the filter found out of its scalar's range or invalid (non-finite or
    /// negative variances, failed updates), covariance resets, and in fixed point every
    /// result that saturated or was invalid (`dynacal_core::fixed::overflows`).
    pub overflow_events: u64,
}

/// The smallest and largest of a quantity over a run.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Span {
    pub min: f64,
    pub max: f64,
}

impl Default for Span {
    fn default() -> Self {
        Self {
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }
}

impl Span {
    /// Widens the span to hold `x`.
    pub fn add(&mut self, x: f64) {
        self.min = self.min.min(x);
        self.max = self.max.max(x);
    }
    /// Decades from `min` to `max`.
    pub fn decades(&self) -> f64 {
        (self.max / self.min).log10()
    }
}

/// How far apart the filter covariance's numbers lie: what a fixed-point format must hold.
/// A format's range must hold the largest magnitude of any element and its resolution must
/// be fine against the smallest variance (an element below the resolution rounds to zero,
/// which errs by the resolution against the square root of its two variances' product).
#[derive(Debug, Clone, Serialize)]
pub struct CovarianceSpread {
    /// Each state group's variances ([`STATE_GROUPS`]).
    pub variances: Vec<(String, Span)>,
    /// Largest magnitude of any element, and smallest variance, as the filter holds them.
    pub largest_element: f64,
    pub smallest_variance: f64,
    /// Decades between the two.
    pub decades: f64,
    /// The same of the covariance scaled by the sigmas it started with (after the
    /// alignment): `P_ij / (s_i s_j)`, the states in units of their initial uncertainty.
    pub scaled_largest_element: f64,
    pub scaled_smallest_variance: f64,
    pub scaled_decades: f64,
    /// The same of the numbers the filter holds: in floating point the covariance itself,
    /// in fixed point the covariance scaled by each state's power of two
    /// (`ErrorStateEkf::held_covariance`), whose range the fixed format must cover.
    pub held_largest_element: f64,
    pub held_smallest_variance: f64,
    pub held_decades: f64,
}

/// Gathers a [`CovarianceSpread`] over a run.
struct SpreadGatherer {
    start_sigmas: Option<[f64; STATES]>,
    variances: [Span; STATES],
    elements: Span,
    scaled_variances: Span,
    scaled_elements: Span,
    held_variances: Span,
    held_elements: Span,
}

impl SpreadGatherer {
    fn new() -> Self {
        Self {
            start_sigmas: None,
            variances: [Span::default(); STATES],
            elements: Span::default(),
            scaled_variances: Span::default(),
            scaled_elements: Span::default(),
            held_variances: Span::default(),
            held_elements: Span::default(),
        }
    }

    /// Takes the filter's sigmas as it starts, the scale of [`CovarianceSpread`]'s scaled
    /// figures.
    fn start<T: FilterScalar>(&mut self, filter: &FusionFilter<T>) {
        let p = filter.ekf.covariance_f64();
        self.start_sigmas = Some(core::array::from_fn(|i| p[(i, i)].sqrt()));
    }

    fn add<T: FilterScalar>(&mut self, filter: &FusionFilter<T>, p: &Covariance) {
        let held = filter.ekf.held_covariance().map(to_f64);
        let Some(sigmas) = self.start_sigmas else {
            return;
        };
        for i in 0..STATES {
            self.held_variances.add(held[(i, i)]);
            for j in 0..=i {
                self.held_elements.add(held[(i, j)].abs());
            }
        }
        for i in 0..STATES {
            self.variances[i].add(p[(i, i)]);
            self.scaled_variances
                .add(p[(i, i)] / (sigmas[i] * sigmas[i]));
            for j in 0..=i {
                self.elements.add(p[(i, j)].abs());
                self.scaled_elements
                    .add(p[(i, j)].abs() / (sigmas[i] * sigmas[j]));
            }
        }
    }

    fn spread(&self) -> CovarianceSpread {
        let smallest = self
            .variances
            .iter()
            .map(|v| v.min)
            .fold(f64::INFINITY, f64::min);
        let groups = STATE_GROUPS.iter().map(|(name, first, len)| {
            let mut span = Span::default();
            for v in &self.variances[*first..first + len] {
                span.add(v.min);
                span.add(v.max);
            }
            (name.to_string(), span)
        });
        let whole = Span {
            min: smallest,
            max: self.elements.max,
        };
        let scaled = Span {
            min: self.scaled_variances.min,
            max: self.scaled_elements.max,
        };
        let held = Span {
            min: self.held_variances.min,
            max: self.held_elements.max,
        };
        CovarianceSpread {
            held_largest_element: held.max,
            held_smallest_variance: held.min,
            held_decades: held.decades(),
            variances: groups.collect(),
            largest_element: whole.max,
            smallest_variance: whole.min,
            decades: whole.decades(),
            scaled_largest_element: scaled.max,
            scaled_smallest_variance: scaled.min,
            scaled_decades: scaled.decades(),
        }
    }
}

/// Errors of a simulated navigation run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NavSimError {
    #[error(transparent)]
    Drive(#[from] DriveError),
    #[error("the filter never started: no alignment in {seconds} s")]
    NeverAligned { seconds: f64 },
}

/// `outage_s`-long GNSS outages spread through `seconds` of driving: one per 300 s (at least
/// one), centred on equal divisions of the run.
pub fn spread_outages(seconds: f64, outage_s: f64) -> Vec<[f64; 2]> {
    if outage_s <= 0.0 {
        return Vec::new();
    }
    let count = (seconds / 300.0).round().max(1.0) as usize;
    (1..=count)
        .map(|k| {
            let centre = seconds * k as f64 / (count + 1) as f64;
            [centre - outage_s / 2.0, centre + outage_s / 2.0]
        })
        .collect()
}

/// Runs the board's fusion over the drive `model` and `opts` describe.
pub fn run(model: &SimModel, opts: &NavSimOptions) -> Result<NavSimReport, NavSimError> {
    match opts.scalar {
        Scalar::F64 => run_with::<f64>(model, opts),
        Scalar::F32 => run_with::<f32>(model, opts),
        Scalar::Fixed => run_with::<dynacal_core::fixed::I32F32>(model, opts),
    }
}

/// Root mean square and largest magnitude of what was added.
#[derive(Debug, Default, Clone, Copy)]
pub struct Rms {
    sum2: f64,
    n: u64,
    /// Largest magnitude added.
    pub max_abs: f64,
}

impl Rms {
    pub fn add(&mut self, x: f64) {
        self.sum2 += x * x;
        self.n += 1;
        self.max_abs = self.max_abs.max(x.abs());
    }
    /// The root mean square (0 before anything is added).
    pub fn value(&self) -> f64 {
        (self.sum2 / self.n.max(1) as f64).sqrt()
    }
}

fn run_with<T: FilterScalar>(
    model: &SimModel,
    opts: &NavSimOptions,
) -> Result<NavSimReport, NavSimError> {
    let outages = spread_outages(opts.seconds, opts.outage_s);
    let mut drive = StreamedDrive::new(model, opts.seconds, outages.clone(), opts.seed)?;
    let rate_hz = drive.rate_hz();
    let mut fusion =
        BoardFusion::<T>::new(FusionConfig::at_rate(rate_hz as f32), &drive.board_model());
    let sets = (opts.seconds * rate_hz) as u64;
    let every_second = rate_hz.round() as u64;
    let nees_every = (NEES_EVERY_S * rate_hz).round() as u64;
    let (mut with_gnss, mut in_outage, mut attitude) =
        (Rms::default(), Rms::default(), Rms::default());
    let mut nees_series = Vec::new();
    let (mut block_sum, mut block_samples) = ([0.0; 3], 0usize);
    let mounts = extra_unit_mounts(&drive.board_model());
    let mut calibration_nees = Vec::new();
    let mut still_speed_max_m_s = 0.0f64;
    // The closed-loop error transition, from the alignment on, and the restarts then.
    let mut closed_loop: Option<(ClosedLoop, u32)> = None;
    let mut aligned_after_s = None;
    let mut spread = SpreadGatherer::new();
    let fixed_overflows_before = dynacal_core::fixed::overflows();
    let tally = Tally::default();
    tally.expect(sets / every_second);
    for k in 0..sets {
        if k % every_second == 0 && k > 0 {
            tally.finish_one();
        }
        let (t_us, truth, readings) = drive.next_set();
        for fix in drive.fixes_until(t_us) {
            fusion.push_gnss(t_us, fix);
            follow(&fusion, &mut closed_loop);
        }
        fusion.push_set(t_us, &readings, &mut |_| {});
        follow(&fusion, &mut closed_loop);
        if fusion.still() {
            still_speed_max_m_s = still_speed_max_m_s.max(truth.v_ned_m_s.norm());
        }
        let Some(filter) = fusion.filter() else {
            continue;
        };
        if aligned_after_s.is_none() {
            aligned_after_s = Some(truth.t_s);
            spread.start(filter);
            let (predictions, _) = filter.ekf.last_prediction();
            closed_loop = Some((
                ClosedLoop::start(covariance_of(filter), predictions),
                fusion.counts().restarts,
            ));
        }
        let error = NavError::of(filter, &truth);
        if k % every_second == 0 {
            attitude.add(error.attitude_rad.norm().to_degrees());
            if drive.in_outage(truth.t_s) {
                in_outage.add(error.position_ned_m.norm());
            } else if drive.with_gnss(truth.t_s, SETTLE_AFTER_OUTAGE_S) {
                with_gnss.add(error.position_ned_m.norm());
            }
        }
        if k % nees_every == 0 {
            let p = filter.ekf.covariance_f64();
            spread.add(filter, &p);
            calibration_nees.extend(calibration_nees_of(filter, &p, &mounts));
            if let Some(nees) = error.nees(&p) {
                nees_series.push(nees);
                if let Some(blocks) = error.nees_by_block(&p) {
                    block_sum = core::array::from_fn(|b| block_sum[b] + blocks[b]);
                    block_samples += 1;
                }
                if let Some((tracker, _)) = &mut closed_loop {
                    tracker.sample();
                }
            }
        }
    }
    let aligned_after_s = aligned_after_s.ok_or(NavSimError::NeverAligned {
        seconds: opts.seconds,
    })?;
    let judged = judge_nees(closed_loop.as_ref().map(|(c, _)| c), nees_series.len());
    Ok(NavSimReport {
        scalar: opts.scalar,
        seconds: opts.seconds,
        seed: opts.seed,
        outages_s: outages,
        aligned_after_s,
        position_rms_m: with_gnss.value(),
        position_rms_outage_m: in_outage.value(),
        attitude_rms_deg: attitude.value(),
        nees_mean: nees_series.iter().sum::<f64>() / nees_series.len().max(1) as f64,
        nees_mean_by_block: block_sum.map(|sum| sum / block_samples.max(1) as f64),
        nees_bounds: nees_bounds(judged.0),
        nees_samples: nees_series.len() as u64,
        nees_effective_samples: judged.0,
        nees_bounds_independent: nees_bounds(nees_series.len() as f64),
        nees_judged_by: judged.1,
        calibration_nees_mean: calibration_nees.iter().sum::<f64>()
            / calibration_nees.len().max(1) as f64,
        still_speed_max_m_s,
        covariance: spread.spread(),
        overflow_events: overflow_events(&fusion)
            + (dynacal_core::fixed::overflows() - fixed_overflows_before),
    })
}

/// Each extra unit's true mount as the board model states it: `C_b^s` (body to unit axes,
/// as the fusion turns roll, pitch and yaw into it) and the lever arm (body axes, m).
fn extra_unit_mounts(model: &BoardModel) -> [(UnitQuaternion<f64>, Vector3<f64>); UNITS - 1] {
    core::array::from_fn(|k| {
        let unit = &model.units[k + 1];
        let [roll, pitch, yaw] = unit.rotation_rpy_rad.map(f64::from);
        (
            UnitQuaternion::from_euler_angles(roll, pitch, yaw),
            Vector3::from(unit.lever_arm_m.map(f64::from)),
        )
    })
}

/// The NEES of the filter's calibration states (boresight and lever arm of each extra unit)
/// against the true `mounts`; None if their covariance block is not positive definite.
fn calibration_nees_of<T: FilterScalar>(
    filter: &FusionFilter<T>,
    p: &Covariance,
    mounts: &[(UnitQuaternion<f64>, Vector3<f64>); UNITS - 1],
) -> Option<f64> {
    const STATES: usize = CALIBRATION_STATES_PER_IMU * (UNITS - 1);
    let mut error = nalgebra::SVector::<f64, STATES>::zeros();
    for (k, (q_b_to_s, lever_arm_m)) in mounts.iter().enumerate() {
        let estimate = filter.ekf.calibration(k)?;
        let q_hat = UnitQuaternion::new_normalize(nalgebra::Quaternion::from(
            estimate.q_b_to_s.into_inner().coords.map(to_f64),
        ));
        // C_b^s = (I - [dpsi x]) C_hat: the error angle is the rotation vector of C_hat C^T,
        // taken through quaternions (from a single-precision matrix the trace of a
        // near-identity product can round above 3, and its angle is NaN).
        let boresight_rad = (q_hat * q_b_to_s.inverse()).scaled_axis();
        let lever_m = estimate.lever_arm_b_m.map(to_f64) - lever_arm_m;
        let at = CALIBRATION_STATES_PER_IMU * k;
        error.fixed_rows_mut::<3>(at).copy_from(&boresight_rad);
        error.fixed_rows_mut::<3>(at + 3).copy_from(&lever_m);
    }
    let first = boresight_index(0);
    let block = SMatrix::<f64, STATES, STATES>::from_fn(|i, j| p[(first + i, first + j)]);
    let cholesky = block.cholesky()?;
    Some(error.dot(&cholesky.solve(&error)))
}

/// Two-sided 95% bounds of the mean of `samples` independent NEES values of a consistent
/// filter (chi-square with 9 x samples degrees of freedom over the samples; a fractional
/// count, as a correlated series' worth in independent samples, is allowed).
pub fn nees_bounds(samples: f64) -> [f64; 2] {
    let m = samples.max(1.0);
    let chi2 = ChiSquared::new(NEES_STATES as f64 * m).expect("positive degrees of freedom");
    [chi2.inverse_cdf(0.025) / m, chi2.inverse_cdf(0.975) / m]
}

/// Follows the fusion's closed-loop error transition after one call into it; a restart
/// breaks the chain.
fn follow<T: FilterScalar>(fusion: &BoardFusion<T>, closed_loop: &mut Option<(ClosedLoop, u32)>) {
    let (Some((tracker, restarts)), Some(filter)) = (closed_loop.as_mut(), fusion.filter()) else {
        return;
    };
    if fusion.counts().restarts != *restarts {
        tracker.break_chain("the filter restarted");
        return;
    }
    let (predictions, predicted) = filter.ekf.last_prediction();
    let prediction = || {
        let nav = filter.ekf.last_transition_nav();
        let coupling = filter.ekf.last_transition_coupling();
        let transition = DMatrix::from_fn(STATES, STATES, |i, j| {
            if i < NAV_STATES && j < NAV_STATES {
                to_f64(nav[(i, j)])
            } else if (VEL..VEL + 6).contains(&i) && j >= NAV_STATES {
                coupling[(i - VEL, j)]
            } else if i == j {
                1.0
            } else {
                0.0
            }
        });
        (
            DMatrix::from_fn(STATES, STATES, |i, j| predicted[(i, j)]),
            transition,
        )
    };
    tracker.step(predictions, prediction, covariance_of(filter));
}

/// The filter's physical covariance, f64.
fn covariance_of<T: FilterScalar>(filter: &FusionFilter<T>) -> DMatrix<f64> {
    let p = filter.ekf.covariance_f64();
    DMatrix::from_fn(STATES, STATES, |i, j| p[(i, j)])
}

/// What the NEES samples are worth as independent ones, by the filter's own error
/// correlation, and how that was found (their count where it cannot be).
fn judge_nees(closed_loop: Option<&ClosedLoop>, samples: usize) -> (f64, String) {
    let judged: Vec<usize> = [POS, VEL, ATT]
        .iter()
        .flat_map(|&first| first..first + 3)
        .collect();
    let variance = closed_loop
        .ok_or("the filter never started")
        .and_then(|c| c.mean_nees_variance(&judged));
    match variance {
        Ok(v) if v > 0.0 => (
            2.0 * NEES_STATES as f64 / v,
            "the filter's error correlation".into(),
        ),
        Ok(_) => (samples as f64, "independent samples (no variance)".into()),
        Err(why) => (samples as f64, format!("independent samples ({why})")),
    }
}

/// The filter's count of numbers out of range or invalid, and its restarts.
fn overflow_events<T: FilterScalar>(fusion: &BoardFusion<T>) -> u64 {
    let restarts = u64::from(fusion.counts().restarts);
    let Some(filter) = fusion.filter() else {
        return restarts;
    };
    let stats = filter.ekf.stats();
    restarts + u64::from(stats.numerical_faults()) + u64::from(stats.covariance_resets)
}

/// A filter value in f64.
fn to_f64<T: FilterScalar>(x: T) -> f64 {
    nalgebra::try_convert::<T, f64>(x).unwrap_or(f64::NAN)
}

/// The filter's navigation error against the truth, truth minus estimate: NED position (m)
/// and velocity (m/s), and attitude (rad, NED axes, as the filter's
/// `C_b^n = (I + [eps x]) C_hat`).
pub struct NavError {
    pub position_ned_m: Vector3<f64>,
    pub velocity_ned_m_s: Vector3<f64>,
    pub attitude_rad: Vector3<f64>,
}

impl NavError {
    /// The error of `filter`'s navigation state against `truth`.
    pub fn of<T: FilterScalar>(filter: &FusionFilter<T>, truth: &Truth) -> Self {
        let s = filter.state();
        let r = radii(truth.lat_rad);
        let h_m = to_f64(s.h_m);
        let q_nb = UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(
            s.q_nb.into_inner().coords.map(to_f64),
        ));
        let truth_q = UnitQuaternion::from_rotation_matrix(
            &nalgebra::Rotation3::from_matrix_unchecked(truth.c_bn),
        );
        Self {
            position_ned_m: Vector3::new(
                (truth.lat_rad - s.lat_rad) * (r.meridian_m + h_m),
                (truth.lon_rad - s.lon_rad) * (r.transverse_m + h_m) * truth.lat_rad.cos(),
                h_m - truth.h_m,
            ),
            velocity_ned_m_s: truth.v_ned_m_s - s.v_ned_m_s.map(to_f64),
            // Through quaternions: a rotation's own angle from its trace is NaN when
            // rounding puts the trace of a near-identity product above 3.
            attitude_rad: (truth_q * q_nb.inverse()).scaled_axis(),
        }
    }

    /// The judged blocks: each one's first state in the filter and its error (position,
    /// velocity, attitude).
    fn blocks(&self) -> [(usize, Vector3<f64>); 3] {
        [
            (POS, self.position_ned_m),
            (VEL, self.velocity_ned_m_s),
            (ATT, self.attitude_rad),
        ]
    }

    /// e' P^-1 e over position, velocity and attitude of the filter's covariance `p`; None
    /// if their covariance block is not positive definite.
    fn nees(&self, p: &Covariance) -> Option<f64> {
        let blocks = self.blocks();
        let block = SMatrix::<f64, NEES_STATES, NEES_STATES>::from_fn(|i, j| {
            p[(blocks[i / 3].0 + i % 3, blocks[j / 3].0 + j % 3)]
        });
        let e = nalgebra::SVector::<f64, NEES_STATES>::from_iterator(
            blocks.iter().flat_map(|(_, error)| error.iter().copied()),
        );
        let cholesky = block.cholesky()?;
        Some(e.dot(&cholesky.solve(&e)))
    }

    /// The NEES of position, velocity and attitude each against its own 3 x 3 covariance
    /// block; None if a block is not positive definite.
    fn nees_by_block(&self, p: &Covariance) -> Option<[f64; 3]> {
        let mut out = [0.0; 3];
        for (nees, (first, error)) in out.iter_mut().zip(self.blocks()) {
            let block = nalgebra::Matrix3::<f64>::from_fn(|i, j| p[(first + i, first + j)]);
            *nees = error.dot(&block.cholesky()?.solve(&error));
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outages_are_spread_through_the_run() {
        assert_eq!(spread_outages(300.0, 30.0), [[135.0, 165.0]]);
        assert_eq!(
            spread_outages(600.0, 30.0),
            [[185.0, 215.0], [385.0, 415.0]]
        );
        assert_eq!(
            spread_outages(900.0, 60.0),
            [[195.0, 255.0], [420.0, 480.0], [645.0, 705.0]]
        );
        assert!(spread_outages(600.0, 0.0).is_empty());
    }

    #[test]
    fn each_blocks_nees_is_its_own_error_against_its_own_covariance() {
        use dynacal_core::nav::ekf::{EkfConfig, ErrorStateEkf, InitialSigmas};
        use dynacal_core::nav::strapdown::{NavState, Strapdown};
        // GIVEN a filter whose covariance is its initial sigmas, one per block (position
        // 2 m, velocity 0.5 m/s, attitude 0.01 rad an axis): no block correlated with another
        let initial = InitialSigmas {
            position_m: Vector3::repeat(2.0),
            velocity_m_s: Vector3::repeat(0.5),
            attitude_rad: Vector3::repeat(0.01),
            accel_bias_m_s2: Vector3::repeat(0.1),
            gyro_bias_rad_s: Vector3::repeat(2e-3),
            boresight_rad: Vector3::repeat(0.01),
            lever_arm_m: Vector3::repeat(0.02),
        };
        let state = NavState {
            q_nb: UnitQuaternion::identity(),
            v_ned_m_s: Vector3::zeros(),
            lat_rad: 0.8,
            lon_rad: 0.1,
            h_m: 100.0,
        };
        let filter = FusionFilter::<f64>::new(
            Strapdown::new(state),
            ErrorStateEkf::new(EkfConfig::automotive_mems(), initial),
        );
        // AND errors of one sigma north, two sigmas east in velocity and three in heading
        let error = NavError {
            position_ned_m: Vector3::new(2.0, 0.0, 0.0),
            velocity_ned_m_s: Vector3::new(0.0, 1.0, 0.0),
            attitude_rad: Vector3::new(0.0, 0.0, 0.03),
        };
        // WHEN judged by block and whole
        let p = filter.ekf.covariance_f64();
        let by_block = error.nees_by_block(&p).unwrap();
        let whole = error.nees(&p).unwrap();
        // THEN each block holds its own error squared in its own sigmas (1, 4, 9), the
        // whole their sum
        for (got, want) in by_block.iter().zip([1.0, 4.0, 9.0]) {
            assert!((got - want).abs() < 1e-9, "{by_block:?}");
        }
        assert!((whole - 14.0).abs() < 1e-9, "{whole}");
    }

    #[test]
    fn nees_bounds_narrow_around_the_dimension() {
        let [low, high] = nees_bounds(1.0);
        // chi-square with 9 degrees of freedom: 2.70 and 19.02.
        assert!((low - 2.700).abs() < 1e-3 && (high - 19.023).abs() < 1e-3);
        let [low, high] = nees_bounds(1000.0);
        assert!(low > 8.7 && high < 9.3 && low < 9.0 && high > 9.0);
    }
}
