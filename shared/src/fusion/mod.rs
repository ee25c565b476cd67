//! On-board fusion of three IMUs sampled together: one virtual IMU from the healthy units,
//! an INS/GNSS error-state filter on it with the units' inter-IMU calibration as states,
//! process noise from the units' live noise level, zero-velocity updates at standstill, and
//! what it finds (states, noise levels, faults) as log frames.
//!
//! The body frame is the first unit's axes at its place. Each unit's samples are summed over
//! `filter_every` sample sets (5 ms at 1 kHz); at the end of each such interval:
//! 1. each unit's mean rate and specific force are brought into the body frame with its
//!    alignment (the board model's at first, the filter's estimate once it runs); the
//!    specific force is also moved to the body origin by the centripetal term `Ω Ω r`
//!    (the `Ω̇ r` term is left: differencing a MEMS rate would add more noise than it
//!    removes, and it averages out);
//! 2. the fault monitors (`crate::redundancy::FaultMonitor`, gyros and accelerometers) test
//!    the units and give the fused virtual IMU, each unit less its bias relative to the set
//!    and weighted by its own noise; `LiveNoise` measures each unit's own noise level;
//! 3. the fused increments drive the strapdown, with the white-noise PSD of the fused output
//!    from the live levels and the bias noise from the board model ([`process_noise`]); the
//!    covariance is predicted every `predict_every` intervals (and before every update).
//!
//! The inter-IMU update (the paper's II-B, eqs. 8-12) of units 2 and 3 against the fused
//! output runs on means over `calibration_every` intervals, where the angular acceleration
//! it needs is a usable central difference; zero-velocity updates run on the same cadence
//! while the platform is still. GNSS fixes are fused when they arrive, moved forward to the
//! filter's time by their velocity. Before the filter can start it aligns ([`alignment`])
//! from a standstill and a drive-off. The filter's scalar is a parameter: f32 on the board,
//! f64 on the host to measure what f32 costs.

//! Nothing here allocates or panics; the outputs go to a caller's closure.

pub mod alignment;
pub mod process_noise;
pub mod sets;

// Float methods without std.
#[allow(unused_imports)]
use crate::scalar::{FilterScalar, Pow2};
// f32's `sqrt` and `round` on the board, without std (elsewhere the inherent methods serve).
#[allow(unused_imports)]
use nalgebra::ComplexField;
use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

use crate::board_model::BoardModel;
use crate::log::{FaultFrame, FilterState, GnssFix, NoiseFrame, MAX_IMUS};
use crate::nav::earth::Latitude;
use crate::nav::ekf::{
    AbsorbedMeans, CalibrationCoupling, EkfConfig, ErrorStateEkf, InitialSigmas, InsEkf,
    InterImuCalibration, InterImuSample, RateDifferentiator, ACCEL_BIAS, ATT, GYRO_BIAS, POS, VEL,
};
use crate::nav::strapdown::{NavState, Strapdown};
use crate::redundancy::faults::Step;
use crate::redundancy::{FaultConfig, FaultEvent, FaultMonitor, LiveNoise, MotionThresholds};

use alignment::{Alignment, Start};
use process_noise::{fused_noise, offset_tracking_variance, FusedNoise};

/// Units the board fuses.
pub const UNITS: usize = 3;
/// The `imu_id` of the fused virtual IMU's filter lane in [`FilterState`].
pub const FUSED_LANE_ID: u8 = 0xFF;
/// The fusion's filter in scalar `T`: two extra units' calibrations, 27 states.
pub type FusionFilter<T> = InsEkf<T, { UNITS - 1 }, 27>;
/// The scalar of the board's filter: `f32` on a board with an FPU; Q32.32 fixed point with
/// the `fixed-point` feature, for boards without one (every float operation is a library
/// call there: `firmware/src/bin/ekf_cost.rs` measures the two on a Cortex-M3).
#[cfg(not(feature = "fixed-point"))]
pub type BoardScalar = f32;
/// The scalar of the board's filter (see the other definition).
#[cfg(feature = "fixed-point")]
pub type BoardScalar = crate::fixed::I32F32;
/// The board's filter.
pub type BoardFilter = FusionFilter<BoardScalar>;

/// `x` in the filter's scalar.
fn t<T: FilterScalar>(x: f32) -> T {
    T::convert_from_f32(x)
}

/// A filter value back in f32 (NaN for a scalar f32 cannot hold).
fn f<T: FilterScalar>(x: T) -> f32 {
    x.convert_to_f32()
}

fn tv<T: FilterScalar>(v: Vector3<f32>) -> Vector3<T> {
    v.map(t)
}

fn fv<T: FilterScalar>(v: Vector3<T>) -> Vector3<f32> {
    v.map(f)
}

/// One unit's sample, in its own axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnitReading {
    /// Angular rate, rad/s.
    pub gyro_rad_s: [f32; 3],
    /// Specific force, m/s^2.
    pub accel_m_s2: [f32; 3],
}

/// What the fusion reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FusionOutput {
    State(FilterState),
    Noise(NoiseFrame),
    Fault(FaultFrame),
}

/// Settings. Rates as counts of the step below them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionConfig {
    /// Time between sample sets, s.
    pub sample_interval_s: f32,
    /// Sample sets per filter step (the monitors and live levels run on the interval's
    /// means, as does the mechanization).
    pub filter_every: u32,
    /// Filter steps per covariance prediction (the mechanization runs at every step; the
    /// covariance is carried over the steps between, as PX4 EKF2 does).
    pub predict_every: u32,
    /// Filter steps per inter-IMU update.
    pub calibration_every: u32,
    /// Filter steps per [`FilterState`] output.
    pub state_every: u32,
    /// Filter steps per [`NoiseFrame`] output.
    pub noise_every: u32,
    /// Time constant of the live noise levels, s.
    pub live_time_constant_s: f32,
    /// One-sigma residual motion of a zero-velocity update, m/s.
    pub zupt_sigma_m_s: f32,
    /// Standstill: the filter's speed below this, m/s ...
    pub still_speed_m_s: f32,
    /// ... the rate's deviation from its slow mean below this, rad/s ...
    pub still_rate_rad_s: f32,
    /// ... and the specific force's below this, m/s^2 (both beyond their noise) ...
    pub still_force_m_s2: f32,
    /// ... and the speed the specific force's departure from where it stood adds up to
    /// (over [`CREEP_S`]) below this, m/s: the most a gentle drive-off moves unseen, kept
    /// under `zupt_sigma_m_s` so a zero-velocity update never claims less.
    pub still_creep_m_s: f32,
    /// GNSS velocity change from a standstill that gives the heading, m/s.
    pub heading_speed_change_m_s: f32,
    /// Fixes older than this at arrival are not fused, s.
    pub gnss_max_age_s: f32,
    /// Vertical position and velocity sigmas as multiples of the horizontal ones (NAV-PVT's
    /// speed accuracy is one number; receivers' vertical errors are about twice).
    pub gnss_vertical_factor: f32,
    /// Consecutive fixes with a position component the gate refused, after which the filter's position
    /// and velocity are reset to the fix (the filter was wrong and too sure of itself, as
    /// after a long outage; without the reset it would refuse GNSS for ever).
    pub gnss_reset_after: u32,
    /// Floor of the rate-difference sigma of the inter-IMU update (timing between units,
    /// unmodelled scale), rad/s.
    pub calibration_rate_floor_rad_s: f32,
    /// Floor of its force-difference sigma (the `Ω̇ r` left in the fused force), m/s^2.
    pub calibration_force_floor_m_s2: f32,
    pub ekf: EkfConfig<f32>,
    pub initial: InitialSigmas<f32>,
    pub gyro_monitor: FaultConfig,
    pub accel_monitor: FaultConfig,
}

impl FusionConfig {
    /// Time between fusion steps (the filter's, and the monitors' and live levels'), s.
    pub fn fusion_interval_s(&self) -> f32 {
        self.sample_interval_s * self.config_filter_every()
    }

    fn config_filter_every(&self) -> f32 {
        self.filter_every.max(1) as f32
    }

    /// Settings for sample sets at `sample_rate_hz`: the filter (mechanization, monitors,
    /// live levels) near 200 Hz, its covariance prediction near 100 Hz, calibration and
    /// zero-velocity updates near 10 Hz, states at 10 Hz, noise at 1 Hz; the automotive
    /// filter's settings.
    pub fn at_rate(sample_rate_hz: f32) -> Self {
        let rate = if sample_rate_hz.is_finite() && sample_rate_hz > 0.0 {
            sample_rate_hz
        } else {
            200.0
        };
        let filter_every = ((rate / 200.0).round() as u32).max(1);
        let filter_hz = rate / filter_every as f32;
        let every = |hz: f32| ((filter_hz / hz).round() as u32).max(1);
        let sample_interval_s = 1.0 / rate;
        // The monitors and the live levels run on the filter interval's means.
        let fusion_interval_s = sample_interval_s * filter_every as f32;
        let mut accel_monitor = FaultConfig::new(fusion_interval_s);
        accel_monitor.norm_tolerance = Some(0.1);
        let mut gyro_monitor = FaultConfig::new(fusion_interval_s);
        gyro_monitor.common_hold_s = 0.0;
        Self {
            sample_interval_s,
            filter_every,
            predict_every: every(100.0),
            calibration_every: every(10.0),
            state_every: every(10.0),
            noise_every: every(1.0),
            live_time_constant_s: 2.0,
            zupt_sigma_m_s: 0.02,
            still_speed_m_s: 0.3,
            still_rate_rad_s: 0.01,
            still_force_m_s2: 0.05,
            still_creep_m_s: 0.01,
            heading_speed_change_m_s: 3.0,
            gnss_max_age_s: 0.5,
            gnss_vertical_factor: 2.0,
            gnss_reset_after: 10,
            calibration_rate_floor_rad_s: 2e-3,
            calibration_force_floor_m_s2: 0.05,
            ekf: EkfConfig::automotive_mems(),
            initial: InitialSigmas {
                position_m: Vector3::repeat(1.0),
                velocity_m_s: Vector3::repeat(0.1),
                attitude_rad: Vector3::new(0.01, 0.01, 0.05),
                accel_bias_m_s2: Vector3::repeat(0.1),
                gyro_bias_rad_s: Vector3::repeat(2e-3),
                boresight_rad: Vector3::repeat(0.01),
                lever_arm_m: Vector3::repeat(0.02),
            },
            gyro_monitor,
            accel_monitor,
        }
    }
}

/// Counters of what the fusion did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FusionCounts {
    pub sample_sets: u64,
    /// Filter intervals (aligning or navigating).
    pub intervals: u64,
    /// Sets without a fused output (no healthy unit present).
    pub sets_without_output: u64,
    pub filter_steps: u64,
    pub gnss_fused: u32,
    /// Fixes not fused: too old, no 3-D solution, or before the filter started.
    pub gnss_skipped: u32,
    pub zero_velocity_updates: u32,
    pub calibration_updates: u32,
    /// The mechanization refused a step, and the filter started over.
    pub restarts: u32,
    /// Position and velocity reset to GNSS after the gate refused it too long.
    pub gnss_resets: u32,
}

/// Each unit's samples summed over one filter interval, in its own axes.
#[derive(Debug, Clone, Copy, Default)]
struct UnitSums {
    rate: [Vector3<f32>; UNITS],
    force: [Vector3<f32>; UNITS],
    /// Samples summed per unit (fewer than `sets` where a unit missed some).
    samples: [u32; UNITS],
    sets: u32,
}

impl UnitSums {
    /// Each unit's mean (None: no sample from it).
    fn means(&self) -> [Option<UnitReading>; UNITS] {
        core::array::from_fn(|k| {
            (self.samples[k] > 0).then(|| {
                let n = self.samples[k] as f32;
                UnitReading {
                    gyro_rad_s: (self.rate[k] / n).into(),
                    accel_m_s2: (self.force[k] / n).into(),
                }
            })
        })
    }
}

/// The fused output over one filter interval.
#[derive(Debug, Clone, Copy, Default)]
struct Interval {
    rate_sum: Vector3<f32>,
    force_sum: Vector3<f32>,
    sets: u32,
}

/// Sums over one calibration interval: the fused reference and each extra unit in its
/// own axes, de-biased against the set.
#[derive(Debug, Clone, Copy, Default)]
struct CalibrationWindow {
    rate_sum: Vector3<f32>,
    force_sum: Vector3<f32>,
    unit_rate_sum: [Vector3<f32>; UNITS - 1],
    unit_force_sum: [Vector3<f32>; UNITS - 1],
    /// Sets in the sums that had every unit.
    sets: u32,
    filter_steps: u32,
}

/// A calibration window's means, carried through the differentiator.
#[derive(Debug, Clone, Copy)]
struct WindowMeans {
    force: Vector3<f32>,
    /// The fused output's running means as the window closed (see [`OffsetMeans`]).
    absorbed: OffsetMeans,
    unit_rate: [Vector3<f32>; UNITS - 1],
    unit_force: [Vector3<f32>; UNITS - 1],
    sets: u32,
}

/// The fused rate's and specific force's running means at the fault monitors' offset time
/// constant (body axes; rad/s, m/s^2): what a unit's offset, learned against the fused
/// output, took away of a boresight error's effect along with its relative bias.
#[derive(Debug, Clone, Copy, Default)]
struct OffsetMeans {
    rate: Vector3<f32>,
    force: Vector3<f32>,
    /// Intervals seen: a plain mean until the exponential weight is the smaller, as the
    /// monitors' offsets learn.
    seen: u32,
}

impl OffsetMeans {
    fn push(&mut self, rate: Vector3<f32>, force: Vector3<f32>, alpha: [f32; 2]) {
        self.seen = self.seen.saturating_add(1);
        let startup = 1.0 / self.seen as f32;
        self.rate += alpha[0].max(startup) * (rate - self.rate);
        self.force += alpha[1].max(startup) * (force - self.force);
    }
}

/// Standstill test on the filter interval's means.
#[derive(Debug, Clone, Copy, Default)]
struct Stillness {
    slow_rate: Vector3<f32>,
    slow_force: Vector3<f32>,
    rate_deviation2: f32,
    force_deviation2: f32,
    /// [`FAST_MEAN_S`] means of the rate and the specific force.
    fast_rate: Vector3<f32>,
    fast_force: Vector3<f32>,
    /// Where the rate and the force stood when the standstill began, following the slow
    /// means over [`ANCHOR_S`] while it lasts; `None` once the vehicle clearly moved.
    anchor: Option<(Vector3<f32>, Vector3<f32>)>,
    /// The fast force's departure from the anchor summed over [`CREEP_S`] (leaky), body
    /// axes, m/s: the velocity a creeping vehicle has gained.
    creep_m_s: Vector3<f32>,
    /// How long the platform has been steady and slow but away from its anchor, s.
    away_s: f32,
    started: bool,
}

/// What the mechanization ran since the last covariance prediction: the bias-corrected
/// velocity increment (body, m/s), the angle increment as measured (body, rad) and the time
/// (s).
struct PendingPrediction<T: FilterScalar> {
    delta_v_b_m_s: Vector3<T>,
    delta_theta_b_rad: Vector3<T>,
    span_s: T,
}

impl<T: FilterScalar> PendingPrediction<T> {
    fn empty() -> Self {
        Self {
            delta_v_b_m_s: Vector3::zeros(),
            delta_theta_b_rad: Vector3::zeros(),
            span_s: T::zero(),
        }
    }
}

/// Time constant of the standstill test's slow means and deviations, s.
const SLOW_MEAN_S: f32 = 0.5;
/// Time constant of the means compared with the standstill's anchor, s.
const FAST_MEAN_S: f32 = 0.1;
/// Time constant over which the anchor follows the slow means during a standstill, s: long
/// against a drive-off's first second, short against a bias's drift.
const ANCHOR_S: f32 = 5.0;
/// Time constant of the creep's sum, s: long against a drive-off's first second (the sum is
/// its speed), short against the slow wander of the anchor's error.
const CREEP_S: f32 = 2.0;

/// The fusion (see the module's note), its filter in scalar `T`: f32 on the board; f64 on
/// the host, to measure what f32 costs; Q32.32 fixed point on a core without an FPU. The
/// live levels (the redundancy estimator) run in `T` too; the monitors and the alignment are
/// f32 either way.
pub struct BoardFusion<T: FilterScalar = BoardScalar> {
    config: FusionConfig,
    /// Board-model alignment of each unit: C_b^k and lever arm (body axes, m).
    model_alignment: [(Matrix3<f32>, Vector3<f32>); UNITS],
    gyro_noise_model: FusedNoise,
    accel_noise_model: FusedNoise,
    gyro_monitor: FaultMonitor<UNITS>,
    accel_monitor: FaultMonitor<UNITS>,
    gyro_live: LiveNoise<UNITS, T>,
    accel_live: LiveNoise<UNITS, T>,
    /// The live levels' standard deviations of an interval mean (gyro rad/s, accelerometer
    /// m/s^2) per unit, as of the last push: read a dozen times an interval, so taken (a
    /// square root each, bit by bit in fixed point) once.
    live_sigmas: [[f32; UNITS]; 2],
    /// The previous interval's per-unit means (for the stuck test).
    previous_means: [Option<UnitReading>; UNITS],
    unit_sums: UnitSums,
    alignment: Alignment,
    filter: Option<FusionFilter<T>>,
    window: CalibrationWindow,
    differentiator: RateDifferentiator<f32, WindowMeans>,
    stillness: Stillness,
    still: bool,
    offset_means: OffsetMeans,
    /// The exponential weights of [`OffsetMeans`] per interval (gyro, accelerometer).
    offset_alpha: [f32; 2],
    /// Each unit's offset-tracking error variance, gyro ((rad/s)^2) and accelerometer
    /// ((m/s^2)^2), from the board model ([`offset_tracking_variance`]).
    offset_error_variance: [[f32; 2]; UNITS],
    /// Consecutive fixes whose position was refused.
    gnss_refused: u32,
    pending_prediction: PendingPrediction<T>,
    /// Each unit's weight in the fused rate and in the fused specific force over the last
    /// interval (zero until the monitors fuse).
    fused_shares: [[f32; UNITS]; 2],
    counts: FusionCounts,
}

impl<T: FilterScalar> BoardFusion<T> {
    /// A fusion of the units of `model` (its first three, in order: the header's IMUs).
    #[inline(always)]
    pub fn new(config: FusionConfig, model: &BoardModel) -> Self {
        let alignment_of = |k: usize| {
            model
                .units
                .get(k)
                .map_or((Matrix3::identity(), Vector3::zeros()), |u| {
                    let [r, p, y] = u.rotation_rpy_rad;
                    let c = crate::scalar::quaternion_from_euler(r, p, y)
                        .to_rotation_matrix()
                        .into_inner();
                    (c, Vector3::from(u.lever_arm_m))
                })
        };
        let thresholds = MotionThresholds::default();
        let units = &model.units[..model.units.len().min(UNITS)];
        Self {
            model_alignment: core::array::from_fn(alignment_of),
            gyro_noise_model: fused_noise(units, false),
            accel_noise_model: fused_noise(units, true),
            gyro_monitor: FaultMonitor::new(config.gyro_monitor),
            accel_monitor: FaultMonitor::new(config.accel_monitor),
            gyro_live: LiveNoise::new(
                config.fusion_interval_s(),
                config.live_time_constant_s,
                thresholds,
            ),
            accel_live: LiveNoise::new(
                config.fusion_interval_s(),
                config.live_time_constant_s,
                thresholds,
            ),
            live_sigmas: [[0.0; UNITS]; 2],
            previous_means: [None; UNITS],
            unit_sums: UnitSums::default(),
            alignment: Alignment::new(config.heading_speed_change_m_s),
            filter: None,
            window: CalibrationWindow::default(),
            differentiator: RateDifferentiator::new(),
            stillness: Stillness::default(),
            still: false,
            offset_means: OffsetMeans::default(),
            offset_alpha: [config.gyro_monitor, config.accel_monitor]
                .map(|m| m.alpha(m.mean_time_constant_s)),
            offset_error_variance: core::array::from_fn(|k| {
                [(false, config.gyro_monitor), (true, config.accel_monitor)].map(|(accel, m)| {
                    offset_tracking_variance(units, accel, k, m.mean_time_constant_s)
                })
            }),
            gnss_refused: 0,
            pending_prediction: PendingPrediction::empty(),
            fused_shares: [[0.0; UNITS]; 2],
            counts: FusionCounts::default(),
            config,
        }
    }

    /// What the fusion did so far.
    pub fn counts(&self) -> &FusionCounts {
        &self.counts
    }

    /// The running filter, once aligned.
    pub fn filter(&self) -> Option<&FusionFilter<T>> {
        self.filter.as_ref()
    }

    /// Whether the platform is taken to be at rest.
    pub fn still(&self) -> bool {
        self.still
    }

    /// Unit k's alignment: C_b^k (body to unit axes) and lever arm (body axes, m).
    fn alignment_of(&self, k: usize) -> (Matrix3<f32>, Vector3<f32>) {
        match (k, &self.filter) {
            (1.., Some(filter)) => filter
                .ekf
                .calibration(k - 1)
                .map_or(self.model_alignment[k], |c| {
                    (c.c_b_s().map(f), fv(c.lever_arm_b_m))
                }),
            _ => self.model_alignment[k],
        }
    }

    /// One sample set taken at `t_us` (None: the unit's sample is missing). Each unit's
    /// samples are summed over the filter interval; at its end the interval is fused.
    pub fn push_set(
        &mut self,
        t_us: u64,
        readings: &[Option<UnitReading>; UNITS],
        out: &mut impl FnMut(FusionOutput),
    ) {
        self.counts.sample_sets += 1;
        let sums = &mut self.unit_sums;
        for (k, reading) in readings.iter().enumerate() {
            if let Some(r) = reading {
                sums.rate[k] += Vector3::from(r.gyro_rad_s);
                sums.force[k] += Vector3::from(r.accel_m_s2);
                sums.samples[k] += 1;
            }
        }
        sums.sets += 1;
        if sums.sets >= self.config.filter_every {
            let sums = core::mem::take(&mut self.unit_sums);
            self.fuse_interval(t_us, &sums, out);
        }
    }

    /// One interval's per-unit means through the monitors and the live levels into the
    /// fused output, and on to the filter.
    fn fuse_interval(&mut self, t_us: u64, sums: &UnitSums, out: &mut impl FnMut(FusionOutput)) {
        let alignment: [(Matrix3<f32>, Vector3<f32>); UNITS] =
            core::array::from_fn(|k| self.alignment_of(k));
        let means = sums.means();
        self.test_units(t_us, &means, &alignment, out);
        let gyro_body = gyro_in_body(&means, &alignment);
        let gyro_fused = self.gyro_monitor.fused_and_shares(&gyro_body);
        let fused_rate = gyro_fused.map(|(rate, _)| Vector3::from(rate));
        let omega = fused_rate.unwrap_or_else(Vector3::zeros);
        let accel_body = accel_in_body(&means, &alignment, &omega);
        let accel_fused = self.accel_monitor.fused_and_shares(&accel_body);
        let fused_force = accel_fused.map(|(force, _)| Vector3::from(force));
        self.fused_shares = [gyro_fused.map(|(_, s)| s), accel_fused.map(|(_, s)| s)]
            .map(|shares| shares.unwrap_or([0.0; UNITS]));
        if let (Some(g), Some(a)) = (all_present(&gyro_body), all_present(&accel_body)) {
            let rate: [T; 3] = tv(omega).into();
            self.gyro_live.push(&g.map(|v| v.map(t)), rate);
            self.accel_live.push(&a.map(|v| v.map(t)), rate);
            self.live_sigmas = [&self.gyro_live, &self.accel_live]
                .map(|live| core::array::from_fn(|k| f(live.sigma(k))));
        }

        let (Some(rate), Some(force)) = (fused_rate, fused_force) else {
            self.counts.sets_without_output += u64::from(sums.sets);
            return;
        };
        self.offset_means.push(rate, force, self.offset_alpha);
        self.add_to_window(&means, &alignment, rate, force);
        let interval = Interval {
            rate_sum: rate * sums.sets as f32,
            force_sum: force * sums.sets as f32,
            sets: sums.sets,
        };
        self.filter_step(t_us, &interval, out);
    }

    /// The fault monitors' step on one interval's per-unit means (own axes).
    fn test_units(
        &mut self,
        t_us: u64,
        means: &[Option<UnitReading>; UNITS],
        alignment: &[(Matrix3<f32>, Vector3<f32>); UNITS],
        out: &mut impl FnMut(FusionOutput),
    ) {
        // A stuck unit is seen in what it put out, per sensor: equal means.
        let previous = self.previous_means;
        let repeated = |triad: fn(&UnitReading) -> [f32; 3]| -> [[bool; 3]; UNITS] {
            core::array::from_fn(|k| match (&means[k], &previous[k]) {
                (Some(a), Some(b)) => core::array::from_fn(|i| triad(a)[i] == triad(b)[i]),
                _ => [false; 3],
            })
        };
        let gyro_repeated = repeated(|r| r.gyro_rad_s);
        let accel_repeated = repeated(|r| r.accel_m_s2);
        self.previous_means = *means;
        let gyro_body = gyro_in_body(means, alignment);
        let gyro_step = self.gyro_monitor.push_marked(&gyro_body, &gyro_repeated);
        let omega = self
            .gyro_monitor
            .fused(&gyro_body)
            .map_or_else(Vector3::zeros, Vector3::from);
        let accel_body = accel_in_body(means, alignment, &omega);
        let accel_step = self.accel_monitor.push_marked(&accel_body, &accel_repeated);
        self.report_faults(t_us, FaultFrame::SENSOR_GYRO, &gyro_step, out);
        self.report_faults(t_us, FaultFrame::SENSOR_ACCEL, &accel_step, out);
    }

    /// Adds a set to the calibration window: the fused output and each extra unit in its
    /// own axes less its bias relative to the set (see `InterImuSample::shares_reference_bias`).
    fn add_to_window(
        &mut self,
        readings: &[Option<UnitReading>; UNITS],
        alignment: &[(Matrix3<f32>, Vector3<f32>); UNITS],
        rate: Vector3<f32>,
        force: Vector3<f32>,
    ) {
        let Some(filter) = &self.filter else { return };
        let all_in = (0..UNITS).all(|k| {
            readings[k].is_some() && self.gyro_monitor.healthy(k) && self.accel_monitor.healthy(k)
        });
        if !all_in {
            return;
        }
        let (gyro_bias, accel_bias) = (
            fv(filter.ekf.gyro_bias_b_rad_s()),
            fv(filter.ekf.accel_bias_b_m_s2()),
        );
        let w = &mut self.window;
        w.rate_sum += rate;
        w.force_sum += force;
        for k in 1..UNITS {
            let Some(u) = readings[k] else { continue };
            let c = alignment[k].0;
            let gyro_offset = Vector3::from(self.gyro_monitor.offset(k)) + gyro_bias;
            let accel_offset = Vector3::from(self.accel_monitor.offset(k)) + accel_bias;
            w.unit_rate_sum[k - 1] += Vector3::from(u.gyro_rad_s) - c * gyro_offset;
            w.unit_force_sum[k - 1] += Vector3::from(u.accel_m_s2) - c * accel_offset;
        }
        w.sets += 1;
    }

    /// One filter interval, which ended at `t_us`: the alignment until the filter runs, then
    /// the filter's step; noise levels on their own cadence either way.
    fn filter_step(&mut self, t_us: u64, interval: &Interval, out: &mut impl FnMut(FusionOutput)) {
        let sets = interval.sets.max(1) as f32;
        let dt_s = self.config.sample_interval_s * sets;
        let mean_rate = interval.rate_sum / sets;
        let mean_force = interval.force_sum / sets;
        self.update_stillness(mean_rate, mean_force, dt_s);
        self.counts.intervals += 1;
        if self.filter.is_some() {
            self.navigate(t_us, interval, dt_s, out);
        } else {
            self.alignment.push(mean_rate, mean_force, dt_s);
        }
        if self
            .counts
            .intervals
            .is_multiple_of(u64::from(self.config.noise_every))
        {
            out(FusionOutput::Noise(self.noise_frame(t_us)));
        }
    }

    /// The running filter's step over `interval` (`dt_s` long, ended at `t_us`).
    fn navigate(
        &mut self,
        t_us: u64,
        interval: &Interval,
        dt_s: f32,
        out: &mut impl FnMut(FusionOutput),
    ) {
        let [gyro_sigmas, accel_sigmas] = &self.live_sigmas;
        let (gyro_psd, accel_psd) = live_psds(
            (gyro_sigmas, &self.gyro_monitor, &self.gyro_noise_model),
            (accel_sigmas, &self.accel_monitor, &self.accel_noise_model),
            self.config.fusion_interval_s(),
        );
        let Some(filter) = &mut self.filter else {
            return;
        };
        self.counts.filter_steps += 1;
        filter
            .ekf
            .set_sensor_noise_psd(Pow2::from_f32(accel_psd), Pow2::from_f32(gyro_psd));
        let interval_s = self.config.sample_interval_s;
        let Ok(delta_v) = filter.mechanize(
            tv(interval.rate_sum * interval_s),
            tv(interval.force_sum * interval_s),
            t(dt_s),
        ) else {
            self.restart();
            return;
        };
        let pending = &mut self.pending_prediction;
        pending.delta_v_b_m_s += delta_v;
        pending.delta_theta_b_rad += tv(interval.rate_sum * interval_s);
        pending.span_s += t::<T>(dt_s);
        let steps = self.counts.filter_steps;
        if steps.is_multiple_of(u64::from(self.config.predict_every)) && !self.flush_prediction() {
            return;
        }
        let zupt_due = steps.is_multiple_of(u64::from(self.config.calibration_every));
        if self.still && zupt_due && self.flush_prediction() {
            let Some(filter) = &mut self.filter else {
                return;
            };
            filter.fuse_zero_velocity(t(self.config.zupt_sigma_m_s));
            filter.correct();
            self.counts.zero_velocity_updates += 1;
        }
        self.window.filter_steps += 1;
        if self.window.filter_steps >= self.config.calibration_every && self.flush_prediction() {
            self.calibrate(dt_s * self.window.filter_steps as f32);
        }
        if steps.is_multiple_of(u64::from(self.config.state_every)) {
            if let Some(state) = self.filter_state(t_us) {
                out(FusionOutput::State(state));
            }
        }
    }

    /// Predicts the covariance over the steps mechanized since the last prediction (before
    /// an update, and every `predict_every` steps). False if the filter had to start over.
    fn flush_prediction(&mut self) -> bool {
        let pending = core::mem::replace(&mut self.pending_prediction, PendingPrediction::empty());
        let span_s = pending.span_s;
        let Some(filter) = &mut self.filter else {
            return false;
        };
        if span_s <= T::zero() {
            return true;
        }
        // The extra units' shares of the fused output carry their calibration errors into it.
        let [gyro, accel] = self.fused_shares;
        let coupling = CalibrationCoupling {
            omega_b_rad_s: pending.delta_theta_b_rad / span_s - filter.ekf.gyro_bias_b_rad_s(),
            gyro_share: core::array::from_fn(|k| t(gyro[k + 1])),
            accel_share: core::array::from_fn(|k| t(accel[k + 1])),
        };
        let f_b_m_s2 = pending.delta_v_b_m_s / span_s;
        if filter
            .predict_covariance_coupled(f_b_m_s2, Some(&coupling), span_s)
            .is_ok()
        {
            return true;
        }
        self.restart();
        false
    }

    /// The mechanization or the filter failed numerically: align again.
    fn restart(&mut self) {
        self.counts.restarts += 1;
        self.filter = None;
        self.pending_prediction = PendingPrediction::empty();
    }

    /// The inter-IMU update on the window just closed, `window_s` long.
    fn calibrate(&mut self, window_s: f32) {
        let w = core::mem::take(&mut self.window);
        let Some(filter) = &mut self.filter else {
            return;
        };
        if w.sets == 0 {
            // A gap: the differentiator starts over.
            self.differentiator
                .push(0.0, Vector3::zeros(), empty_means());
            return;
        }
        let n = w.sets as f32;
        let means = WindowMeans {
            force: w.force_sum / n - fv(filter.ekf.accel_bias_b_m_s2()),
            absorbed: self.offset_means,
            unit_rate: w.unit_rate_sum.map(|s| s / n),
            unit_force: w.unit_force_sum.map(|s| s / n),
            sets: w.sets,
        };
        let rate = w.rate_sum / n - fv(filter.ekf.gyro_bias_b_rad_s());
        let Some((omega, omega_dot, m)) = self.differentiator.push(window_s, rate, means) else {
            return;
        };
        let [gyro_sigmas, accel_sigmas] = self.live_sigmas;
        let per_set = |sigmas: &[f32; UNITS], k: usize| sigmas[k] * sigmas[k];
        let m_sets = m.sets.max(1) as f32;
        let absorbed = AbsorbedMeans {
            omega_ib_b_rad_s: tv(m.absorbed.rate),
            f_b_m_s2: tv(m.absorbed.force),
        };
        // The offsets' tracking error lasts about their time constant: over that time the
        // updates see one error, so each counts it as many times as one independent error's
        // worth (twice the time constant over the window, an AR(1) mean's variance).
        let repeats = |m: &FaultConfig| 2.0 * m.mean_time_constant_s / window_s.max(1e-3);
        let (gyro_repeats, accel_repeats) = (
            repeats(&self.config.gyro_monitor),
            repeats(&self.config.accel_monitor),
        );
        for k in 1..UNITS {
            let [gyro_offset_var, accel_offset_var] = self.offset_error_variance[k];
            let rate_var = (per_set(&gyro_sigmas, k) + per_set(&gyro_sigmas, 0)) / m_sets
                + gyro_repeats * gyro_offset_var;
            let force_var = (per_set(&accel_sigmas, k) + per_set(&accel_sigmas, 0)) / m_sets
                + accel_repeats * accel_offset_var;
            let sigma_rate = rate_var
                .sqrt()
                .max(self.config.calibration_rate_floor_rad_s);
            let sigma_force = force_var
                .sqrt()
                .max(self.config.calibration_force_floor_m_s2);
            let sample = InterImuSample {
                omega_ib_b_rad_s: tv(omega),
                omega_dot_ib_b_rad_s2: tv(omega_dot),
                f_b_m_s2: tv(m.force),
                omega_is_s_rad_s: tv(m.unit_rate[k - 1]),
                f_s_m_s2: tv(m.unit_force[k - 1]),
                shares_reference_bias: true,
            };
            filter.fuse_inter_imu_absorbed(
                k - 1,
                &sample,
                &absorbed,
                &Vector3::repeat(t(sigma_rate)),
                &Vector3::repeat(t(sigma_force)),
            );
        }
        filter.correct();
        self.counts.calibration_updates += 1;
    }

    /// Updates the standstill test with one filter interval's means.
    ///
    /// A car's drive-off ramps its acceleration up from zero, so gently at first that the
    /// deviation from the slow means stays within the noise until the car moves at walking
    /// pace, while zero-velocity updates pin the filter's speed (and so its speed test) to
    /// zero (measured: 3.7 s and 0.3 m/s with the deviation test alone). The standstill
    /// also ends when the fast means leave where the rate and force stood when it began, or
    /// when the force's departure from there adds up to a speed (the creep).
    fn update_stillness(&mut self, rate: Vector3<f32>, force: Vector3<f32>, dt_s: f32) {
        let s = &mut self.stillness;
        if !s.started {
            s.slow_rate = rate;
            s.slow_force = force;
            s.fast_rate = rate;
            s.fast_force = force;
            s.started = true;
        }
        let alpha = (dt_s / SLOW_MEAN_S).min(1.0);
        let fast = (dt_s / FAST_MEAN_S).min(1.0);
        s.slow_rate += (rate - s.slow_rate) * alpha;
        s.slow_force += (force - s.slow_force) * alpha;
        s.fast_rate += (rate - s.fast_rate) * fast;
        s.fast_force += (force - s.fast_force) * fast;
        s.rate_deviation2 += ((rate - s.slow_rate).norm_squared() - s.rate_deviation2) * alpha;
        s.force_deviation2 += ((force - s.slow_force).norm_squared() - s.force_deviation2) * alpha;
        // The means' own noise: three axes of the noisiest unit's level (the live levels are
        // per interval mean already).
        let noise = |sigmas: &[f32; UNITS]| {
            let level = sigmas.iter().copied().fold(0.0f32, f32::max);
            3.0 * level * level
        };
        let [gyro_sigmas, accel_sigmas] = self.live_sigmas;
        let (rate, force) = (self.config.still_rate_rad_s, self.config.still_force_m_s2);
        let rate_limit = rate * rate + noise(&gyro_sigmas);
        let force_limit = force * force + noise(&accel_sigmas);
        let slow = self
            .filter
            .as_ref()
            .is_none_or(|filter| f(filter.state().v_ned_m_s.norm()) < self.config.still_speed_m_s);
        let steady = s.rate_deviation2 < rate_limit && s.force_deviation2 < force_limit;
        // A drive-off's acceleration ramps up from zero: its speed, the departure's sum, ends
        // the standstill sooner than the departure itself does (measured on the navsim
        // drives: 0.05-0.09 m/s pinned to zero by the updates with the departure alone).
        match s.anchor {
            Some((_, f)) => {
                let leak = (dt_s / CREEP_S).min(1.0);
                s.creep_m_s += (s.fast_force - f) * dt_s - s.creep_m_s * leak;
            }
            None => s.creep_m_s = Vector3::zeros(),
        }
        let creep = self.config.still_creep_m_s;
        let creep_limit = creep * creep + noise(&accel_sigmas) * dt_s * CREEP_S / 2.0;
        let anchored = s.anchor.is_none_or(|(r, f)| {
            (s.fast_rate - r).norm_squared() < rate_limit
                && (s.fast_force - f).norm_squared() < force_limit
                && s.creep_m_s.norm_squared() < creep_limit
        });
        self.still = slow && steady && anchored;
        // Left while the filter is slow, the anchor stays where it was: the deviations
        // cannot tell a gentle drive-off from a standstill (a ramp's deviation from its slow
        // mean stays small), so a standstill resumes only where the vehicle stood, or after
        // it clearly moved. A platform steady for ANCHOR_S away from its anchor stands
        // somewhere else (a bump, a load that tilted it): the anchor is let go.
        s.away_s = if !self.still && slow && steady {
            s.away_s + dt_s
        } else {
            0.0
        };
        s.anchor = if self.still {
            let follow = (dt_s / ANCHOR_S).min(1.0);
            Some(s.anchor.map_or((s.slow_rate, s.slow_force), |(r, f)| {
                (
                    r + (s.slow_rate - r) * follow,
                    f + (s.slow_force - f) * follow,
                )
            }))
        } else if slow && s.away_s < ANCHOR_S {
            s.anchor
        } else {
            None
        };
    }

    /// A GNSS solution that arrived at `t_us`.
    pub fn push_gnss(&mut self, t_us: u64, fix: &GnssFix) {
        if !(fix.fix_type == 3 || fix.fix_type == 4) {
            self.counts.gnss_skipped += 1;
            return;
        }
        let age_s = t_us.saturating_sub(fix.t_us) as f32 * 1e-6;
        if age_s > self.config.gnss_max_age_s || fix.t_us > t_us.saturating_add(100_000) {
            self.counts.gnss_skipped += 1;
            return;
        }
        if self.filter.is_some() && !self.flush_prediction() {
            return;
        }
        let Some(filter) = &mut self.filter else {
            if let Some(start) = self.alignment.on_fix(fix) {
                self.start(&start);
            }
            self.counts.gnss_skipped += 1;
            return;
        };
        let (lat_rad, lon_rad, h_m) = moved_forward(fix, age_s);
        let position = (lat_rad, lon_rad, t::<T>(h_m));
        let (sigma_h, sigma_vh) = per_axis_sigmas(fix);
        let sigma_p = tv(Vector3::new(
            sigma_h,
            sigma_h,
            sigma_h * self.config.gnss_vertical_factor,
        ));
        let velocity = tv(Vector3::from(fix.vel_ned_m_s));
        let sigma_v = tv(Vector3::new(
            sigma_vh,
            sigma_vh,
            sigma_vh * self.config.gnss_vertical_factor,
        ));
        let batch = filter.fuse_gnss_position(position.0, position.1, position.2, &sigma_p);
        self.gnss_refused = if batch.rejected > 0 {
            self.gnss_refused + 1
        } else {
            0
        };
        if self.gnss_refused >= self.config.gnss_reset_after {
            filter.reset_position_velocity(position, velocity, &sigma_p, &sigma_v);
            self.gnss_refused = 0;
            self.counts.gnss_resets += 1;
        } else {
            filter.fuse_gnss_velocity(&velocity, &sigma_v);
        }
        filter.correct();
        self.counts.gnss_fused += 1;
    }

    /// Starts the filter at an alignment's result (out of line: its 4 KiB filter is built
    /// once, and the frames of the hot path stay small).
    #[inline(never)]
    fn start(&mut self, start: &Start) {
        let mut config = self.config.ekf;
        config.gyro_bias_psd = Pow2::from_f32(self.gyro_noise_model.bias_psd);
        config.gyro_bias_inv_tau_s = self.gyro_noise_model.bias_inv_tau_s;
        config.accel_bias_psd = Pow2::from_f32(self.accel_noise_model.bias_psd);
        config.accel_bias_inv_tau_s = self.accel_noise_model.bias_inv_tau_s;
        let mut initial = self.config.initial;
        initial.attitude_rad.z = start.heading_sigma_rad;
        let fix = &start.fix;
        let (sigma_h, sigma_vh) = per_axis_sigmas(fix);
        initial.position_m =
            Vector3::new(sigma_h, sigma_h, sigma_h * self.config.gnss_vertical_factor);
        initial.velocity_m_s = Vector3::repeat(sigma_vh);
        if self.accel_noise_model.bias_sigma > 0.0 {
            initial.accel_bias_m_s2 = Vector3::repeat(self.accel_noise_model.bias_sigma);
        }
        let q = start.q_nb.into_inner();
        let state = NavState {
            q_nb: UnitQuaternion::new_normalize(Quaternion::new(t(q.w), t(q.i), t(q.j), t(q.k))),
            v_ned_m_s: tv(Vector3::from(fix.vel_ned_m_s)),
            lat_rad: fix.lat_rad,
            lon_rad: fix.lon_rad,
            h_m: t(fix.h_m),
        };
        let mut ekf = ErrorStateEkf::new(ekf_config_in(&config), initial_sigmas_in(&initial));
        ekf.set_biases(Vector3::zeros(), tv(start.gyro_bias_rad_s));
        for k in 1..UNITS {
            let (c, r) = self.model_alignment[k];
            // Shepperd's direct method: nalgebra's iterative `from_matrix` stops, in fixed
            // point, where its update falls under one unit (4e-6 rad off for a half turn).
            let q =
                UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(c.map(t)));
            ekf.set_calibration(
                k - 1,
                InterImuCalibration {
                    q_b_to_s: q,
                    lever_arm_b_m: tv(r),
                },
            );
        }
        self.filter = Some(InsEkf::new(Strapdown::new(state), ekf));
        self.window = CalibrationWindow::default();
        self.differentiator = RateDifferentiator::new();
        self.pending_prediction = PendingPrediction::empty();
    }

    /// The filter's state for the log.
    fn filter_state(&self, t_us: u64) -> Option<FilterState> {
        let filter = self.filter.as_ref()?;
        let s = filter.state();
        let ekf = &filter.ekf;
        let sigma3 = |first: usize| -> [f32; 3] {
            core::array::from_fn(|a| ekf.sigma(first + a).map_or(f32::NAN, f))
        };
        let q = s.q_nb.quaternion();
        Some(FilterState {
            t_us,
            imu_id: FUSED_LANE_ID,
            q_nb: [f(q.w), f(q.i), f(q.j), f(q.k)],
            vel_ned_m_s: fv(s.v_ned_m_s).into(),
            lat_rad: s.lat_rad,
            lon_rad: s.lon_rad,
            h_m: f(s.h_m),
            gyro_bias_rad_s: fv(ekf.gyro_bias_b_rad_s()).into(),
            accel_bias_m_s2: fv(ekf.accel_bias_b_m_s2()).into(),
            attitude_sigma_rad: sigma3(ATT),
            vel_sigma_m_s: sigma3(VEL),
            pos_sigma_m: sigma3(POS),
            gyro_bias_sigma_rad_s: sigma3(GYRO_BIAS),
            accel_bias_sigma_m_s2: sigma3(ACCEL_BIAS),
        })
    }

    /// Each unit's live noise level and which units are in use.
    fn noise_frame(&self, t_us: u64) -> NoiseFrame {
        let mut frame = NoiseFrame {
            t_us,
            gyro_sigma_rad_s: [f32::NAN; MAX_IMUS],
            accel_sigma_m_s2: [f32::NAN; MAX_IMUS],
            in_use: 0,
            still: self.still,
        };
        // The live levels are of interval means; white noise per IMU sample is sqrt(n) more.
        let per_sample = self.config.config_filter_every().sqrt();
        for k in 0..UNITS.min(MAX_IMUS) {
            frame.gyro_sigma_rad_s[k] = self.live_sigmas[0][k] * per_sample;
            frame.accel_sigma_m_s2[k] = self.live_sigmas[1][k] * per_sample;
            frame.in_use |= u8::from(self.gyro_monitor.healthy(k)) << k;
            frame.in_use |= u8::from(self.accel_monitor.healthy(k)) << (3 + k);
        }
        frame
    }

    /// Fault frames for what a monitor confirmed and readmitted at this set.
    fn report_faults(
        &self,
        t_us: u64,
        sensor: u8,
        step: &Step,
        out: &mut impl FnMut(FusionOutput),
    ) {
        let interval_us = (self.config.fusion_interval_s() * 1e6) as u64;
        for event in &step.confirmed {
            out(FusionOutput::Fault(fault_frame(
                t_us,
                interval_us,
                sensor,
                event,
            )));
        }
        for k in 0..UNITS {
            if step.readmitted & (1 << k) != 0 {
                out(FusionOutput::Fault(FaultFrame {
                    t_us,
                    detected_t_us: t_us,
                    sensor,
                    unit: Some(k as u8),
                    axis: None,
                    kind: FaultFrame::KIND_READMITTED,
                }));
            }
        }
    }
}

/// The monitor's event as a log frame; `interval_us` between sample sets.
fn fault_frame(t_us: u64, interval_us: u64, sensor: u8, event: &FaultEvent) -> FaultFrame {
    let sets_before = u64::from(event.confirmed_sample.saturating_sub(event.detected_sample));
    FaultFrame {
        t_us,
        detected_t_us: t_us.saturating_sub(sets_before * interval_us),
        sensor,
        unit: event.unit,
        axis: event.axis,
        kind: event.kind as u8,
    }
}

/// Each unit's rate in body axes.
fn gyro_in_body(
    means: &[Option<UnitReading>; UNITS],
    alignment: &[(Matrix3<f32>, Vector3<f32>); UNITS],
) -> [Option<[f32; 3]>; UNITS] {
    core::array::from_fn(|k| {
        means[k].map(|u| (alignment[k].0.transpose() * Vector3::from(u.gyro_rad_s)).into())
    })
}

/// Each unit's specific force in body axes, moved to the body origin by the centripetal term
/// of the platform's rate `omega` (body, rad/s).
fn accel_in_body(
    means: &[Option<UnitReading>; UNITS],
    alignment: &[(Matrix3<f32>, Vector3<f32>); UNITS],
    omega: &Vector3<f32>,
) -> [Option<[f32; 3]>; UNITS] {
    core::array::from_fn(|k| {
        means[k].map(|u| {
            let (c, r) = alignment[k];
            let at_origin =
                c.transpose() * Vector3::from(u.accel_m_s2) - omega.cross(&omega.cross(&r));
            at_origin.into()
        })
    })
}

/// The triads when every unit has one.
fn all_present(triads: &[Option<[f32; 3]>; UNITS]) -> Option<[[f32; 3]; UNITS]> {
    let mut all = [[0.0; 3]; UNITS];
    for (slot, t) in all.iter_mut().zip(triads) {
        *slot = (*t)?;
    }
    Some(all)
}

/// The white-noise PSDs (gyro, accelerometer) of the fused output: from the units in use
/// and their live levels (standard deviations of `interval_s` means, so the PSD is the
/// variance times the interval), or the model's where a level is not known yet.
fn live_psds(
    gyro: (&[f32; UNITS], &FaultMonitor<UNITS>, &FusedNoise),
    accel: (&[f32; UNITS], &FaultMonitor<UNITS>, &FusedNoise),
    interval_s: f32,
) -> (f32, f32) {
    let psd = |(sigmas, monitor, model): (&[f32; UNITS], &FaultMonitor<UNITS>, &FusedNoise)| {
        let mut information = 0.0f32;
        for k in (0..UNITS).filter(|&k| monitor.healthy(k)) {
            let variance = sigmas[k] * sigmas[k];
            if variance <= 0.0 {
                return model.white_psd;
            }
            information += 1.0 / variance;
        }
        if information > 0.0 {
            interval_s / information
        } else {
            model.white_psd
        }
    };
    (psd(gyro), psd(accel))
}

/// A fix's position carried `age_s` forward along its velocity: lat, lon (rad), h (m).
///
/// The displacement is metres, so the curvature terms in f32 (1e-7 relative) change it by
/// well under a micrometre, and the board links no f64 trigonometry.
fn moved_forward(fix: &GnssFix, age_s: f32) -> (f64, f64, f32) {
    let latitude = Latitude::new(fix.lat_rad as f32);
    let r = latitude.radii;
    let [vn, ve, vd] = fix.vel_ned_m_s.map(|v| v * age_s);
    let h = fix.h_m;
    (
        fix.lat_rad + f64::from(vn / (r.meridian_m + h)),
        fix.lon_rad + f64::from(ve / ((r.transverse_m + h) * latitude.cos)),
        fix.h_m - vd,
    )
}

/// The one-sigma errors of one horizontal axis of a fix's position (m) and of one axis of
/// its velocity (m/s). A receiver's horizontal accuracy is the horizontal error's RMS radius
/// (u-blox's hAcc; the simulator states `hypot(sigma_n, sigma_e)`), so each axis has
/// `hAcc / √2`; its speed accuracy is the 3-D velocity error's, `sAcc / √3` an axis. Taken
/// whole for each axis, as PX4's EKF2 does, they doubled (and trebled) the variances the
/// filter stated: its NEES sat at 0.6 of its expected value (BENCHMARKS.md).
fn per_axis_sigmas(fix: &GnssFix) -> (f32, f32) {
    const INV_SQRT_3: f32 = 0.577_350_26;
    (
        (fix.pos_sigma_m * core::f32::consts::FRAC_1_SQRT_2).max(0.1),
        (fix.vel_sigma_m_s * INV_SQRT_3).max(0.02),
    )
}

/// A small constant of the board's settings, held to `T`'s precision.
fn small<T: FilterScalar>(x: Pow2<f32>) -> Pow2<T> {
    Pow2::from_f32(x.value())
}

/// The filter's settings in scalar `T`.
fn ekf_config_in<T: FilterScalar>(c: &EkfConfig<f32>) -> EkfConfig<T> {
    EkfConfig {
        accel_noise_psd: small(c.accel_noise_psd),
        gyro_noise_psd: small(c.gyro_noise_psd),
        accel_bias_psd: small(c.accel_bias_psd),
        gyro_bias_psd: small(c.gyro_bias_psd),
        accel_bias_inv_tau_s: t(c.accel_bias_inv_tau_s),
        gyro_bias_inv_tau_s: t(c.gyro_bias_inv_tau_s),
        boresight_psd: small(c.boresight_psd),
        lever_arm_psd: small(c.lever_arm_psd),
        innovation_gate: t(c.innovation_gate),
        variance_floor: c.variance_floor.map(small),
    }
}

/// The filter's initial sigmas in scalar `T`.
fn initial_sigmas_in<T: FilterScalar>(s: &InitialSigmas<f32>) -> InitialSigmas<T> {
    InitialSigmas {
        position_m: tv(s.position_m),
        velocity_m_s: tv(s.velocity_m_s),
        attitude_rad: tv(s.attitude_rad),
        accel_bias_m_s2: tv(s.accel_bias_m_s2),
        gyro_bias_rad_s: tv(s.gyro_bias_rad_s),
        boresight_rad: tv(s.boresight_rad),
        lever_arm_m: tv(s.lever_arm_m),
    }
}

fn empty_means() -> WindowMeans {
    WindowMeans {
        force: Vector3::zeros(),
        absorbed: OffsetMeans::default(),
        unit_rate: [Vector3::zeros(); UNITS - 1],
        unit_force: [Vector3::zeros(); UNITS - 1],
        sets: 0,
    }
}

#[cfg(test)]
mod tests;
