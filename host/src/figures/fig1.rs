//! Fig. 1: joint inter-IMU boresight and lever-arm estimation on simulated data.
//!
//! [`fig1_model`] builds the simulator model (navigation-grade reference IMU, a low-grade and
//! a tactical-grade MEMS IMU with known mounts, all at [`FIG1_RATE_HZ`] on one ideal clock,
//! and a 10 Hz GNSS receiver at the reference IMU). [`run_calibration`] drives the
//! reference-IMU strapdown and the 27-state error-state filter through a [`CalibrationFilter`]
//! (a bare filter in `f32` or `f64`, or the recording [`SmoothingEkf`]) and traces the
//! nominal calibrations and their sigmas after every epoch. [`fig1`] does the whole run and
//! returns a [`Fig1Report`].
//!
//! The extra IMUs carry white noise only: the 27-state filter has no states for their
//! biases or scale factors (paper Section II), so any such error would be absorbed into the
//! boresight and lever arm, which is not what Fig. 1 is about.

use dynacal_core::scalar::FilterScalar;
use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;

use dynacal_core::nav::ekf::{
    apply_correction, boresight_index, lever_arm_index, position_innovation_ned_m, EkfConfig,
    ErrorStateEkf, InitialSigmas, InterImuSample, NavCorrection, NavEkf2, NavLinearization,
};
use dynacal_core::nav::{NavState, Strapdown};

use crate::gmwm::model::{ModelSpec, Process};
use crate::interchange::Triplet;
use crate::model::{unit_to_si, ChannelModel, ClockModel, GnssModel, ImuModel};
use crate::nav_smoother::{SmootherError, SmoothingEkf};
use crate::numeric::{stencil_gain, AngularAccelerationStencil, STENCIL};
use crate::sim::gnss::GnssFixes;
use crate::sim::trajectory::TrajectoryConfig;
use crate::sim::{simulate, Scenario, SimError, SimModel, SimOptions, SimOutput};

/// Sampling rate of all three IMUs, Hz (the reference default; the car vibrates up to 26 Hz).
pub const FIG1_RATE_HZ: f64 = 200.0;
/// GNSS fix rate, Hz.
pub const FIG1_GNSS_RATE_HZ: f64 = 10.0;
/// Initial one-sigma of every boresight angle, deg (the paper's value).
pub const INITIAL_BORESIGHT_SIGMA_DEG: f64 = 20.0;
/// Initial one-sigma of every lever-arm component, m (the paper's value).
pub const INITIAL_LEVER_ARM_SIGMA_M: f64 = 0.20;
/// Boresight error below which an estimate counts as converged, deg.
pub const CONVERGED_BORESIGHT_DEG: f64 = 1.0;
/// Lever-arm error below which an estimate counts as converged, m.
pub const CONVERGED_LEVER_ARM_M: f64 = 0.05;
/// Time the car stands still before it first drives off, s.
pub const FIG1_INITIAL_STOP_S: f64 = 2.0;

/// One extra IMU of the figure: its grade and mount.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ExtraImuSpec {
    /// File stem and label.
    pub name: &'static str,
    /// Gyroscope white-noise density, deg/s/sqrt(Hz).
    pub gyro_noise_deg_s_sqrt_hz: f64,
    /// Accelerometer white-noise density, m/s^2/sqrt(Hz).
    pub accel_noise_m_s2_sqrt_hz: f64,
    /// Lever arm from the reference IMU, reference body axes, m.
    pub lever_arm_b_m: [f64; 3],
    /// Boresight roll, pitch, yaw (Z-Y-X, `C_s^b = Rz Ry Rx`), deg.
    pub boresight_rpy_deg: [f64; 3],
}

/// The two extra IMUs: a low-grade consumer MEMS (noise of an XSens MTx: 0.05 deg/s/sqrt(Hz),
/// 0.002 m/s^2/sqrt(Hz)) and a tactical-grade IMU (angle random walk 0.07 deg/sqrt(h),
/// velocity random walk 0.05 m/s/sqrt(h)).
pub const FIG1_IMUS: [ExtraImuSpec; 2] = [
    ExtraImuSpec {
        name: "low_grade",
        gyro_noise_deg_s_sqrt_hz: 0.05,
        accel_noise_m_s2_sqrt_hz: 0.002,
        lever_arm_b_m: [0.42, -0.25, 0.15],
        boresight_rpy_deg: [2.0, -3.0, 4.0],
    },
    ExtraImuSpec {
        name: "tactical_grade",
        gyro_noise_deg_s_sqrt_hz: 0.07 / 60.0,
        accel_noise_m_s2_sqrt_hz: 0.05 / 60.0,
        lever_arm_b_m: [-0.30, 0.18, -0.12],
        boresight_rpy_deg: [-1.5, 2.5, -3.5],
    },
];

/// Errors of the Fig. 1 run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Fig1Error {
    #[error("simulation: {0}")]
    Sim(#[from] SimError),
    #[error("--seconds {0} is too short: the figure needs at least 5 s of data")]
    TooShort(f64),
    #[error("simulated sensor `{sensor}` lacks its {what}")]
    Missing { sensor: String, what: &'static str },
    #[error("sample {index} of `{sensor}` is at t = {t_s} s, the reference's at {reference_t_s} s: the IMUs must share one clock")]
    NotSynchronous {
        sensor: String,
        index: usize,
        t_s: f64,
        reference_t_s: f64,
    },
    #[error("strapdown mechanization failed at t = {t_s} s: {fault}")]
    Mechanization { t_s: f64, fault: String },
    #[error("filter prediction refused at t = {t_s} s (non-finite linearisation)")]
    Prediction { t_s: f64 },
    #[error("smoothing: {0}")]
    Smoother(#[from] SmootherError),
}

/// The simulator model of the figure.
pub fn fig1_model() -> SimModel {
    let rate = FIG1_RATE_HZ;
    let white = |density: f64, unit: &str| ChannelModel {
        stochastic: Some(ModelSpec {
            model: "WN".into(),
            unit: unit.into(),
            sample_rate_hz: rate,
            processes: vec![Process::WhiteNoise {
                sigma2: density * density * rate,
            }],
        }),
        ..Default::default()
    };
    let imus = FIG1_IMUS
        .iter()
        .map(|spec| ImuModel {
            name: spec.name.into(),
            rate_hz: rate,
            lever_arm_b_m: spec.lever_arm_b_m,
            boresight_rpy_deg: spec.boresight_rpy_deg,
            time_offset_s: 0.0,
            clock: ClockModel::default(),
            disabled: Vec::new(),
            gyro: white(spec.gyro_noise_deg_s_sqrt_hz.to_radians(), "rad/s"),
            accel: white(spec.accel_noise_m_s2_sqrt_hz, "m/s2"),
            channels: Default::default(),
        })
        .collect();
    let mut reference = ImuModel::navigation_grade_reference();
    reference.rate_hz = rate;
    // The inter-IMU update's Jacobian has no columns for the reference IMU's bias errors, so
    // an uncalibrated reference accelerometer bias b tilts the boresight by b/g (100 ug gives
    // 1e-4 rad, about twice the final 3σ of roll and pitch here) without the filter knowing.
    // The reference of the figure is taken as bias-calibrated; its noise stays.
    reference.disabled = vec![crate::model::Effect::Bias];
    SimModel {
        comment: Some("dynacal fig1: paper Fig. 1 on simulated data".into()),
        trajectory: TrajectoryConfig {
            initial_stop_s: FIG1_INITIAL_STOP_S,
            ..Default::default()
        },
        reference,
        imus,
        gnss: Some(GnssModel {
            rate_hz: FIG1_GNSS_RATE_HZ,
            // The filter's GNSS update has no antenna lever arm: put the antenna on the IMU.
            lever_arm_b_m: [0.0; 3],
            ..Default::default()
        }),
        pps: None,
        ..SimModel::default()
    }
}

/// Runs the simulator on [`fig1_model`] for the car scenario.
pub fn simulate_fig1(seconds: f64, seed: u64) -> Result<SimOutput, Fig1Error> {
    if seconds.is_nan() || seconds < 5.0 {
        return Err(Fig1Error::TooShort(seconds));
    }
    let opts = SimOptions {
        scenario: Scenario::Car,
        seconds,
        seed,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    Ok(simulate(&fig1_model(), &opts, &|_| {})?)
}

/// What the loop needs of a filter: the bare [`ErrorStateEkf`] or the recording
/// [`SmoothingEkf`], which must see every prediction and every epoch.
pub trait CalibrationFilter<T: FilterScalar> {
    /// The filter.
    fn ekf(&self) -> &ErrorStateEkf<T, 2, 27>;
    /// One covariance prediction; `false` if refused.
    fn predict(&mut self, lin: &NavLinearization<T>, dt_s: T) -> bool;
    /// Runs `updates`, then resets and returns the navigation correction.
    fn epoch(
        &mut self,
        t_s: f64,
        updates: impl FnOnce(&mut ErrorStateEkf<T, 2, 27>),
    ) -> NavCorrection<T>;
}

impl<T: FilterScalar> CalibrationFilter<T> for ErrorStateEkf<T, 2, 27> {
    fn ekf(&self) -> &ErrorStateEkf<T, 2, 27> {
        self
    }
    fn predict(&mut self, lin: &NavLinearization<T>, dt_s: T) -> bool {
        ErrorStateEkf::predict(self, lin, dt_s)
    }
    fn epoch(
        &mut self,
        _t_s: f64,
        updates: impl FnOnce(&mut ErrorStateEkf<T, 2, 27>),
    ) -> NavCorrection<T> {
        updates(self);
        self.reset()
    }
}

impl CalibrationFilter<f64> for SmoothingEkf<2, 27> {
    fn ekf(&self) -> &ErrorStateEkf<f64, 2, 27> {
        SmoothingEkf::ekf(self)
    }
    fn predict(&mut self, lin: &NavLinearization<f64>, dt_s: f64) -> bool {
        SmoothingEkf::predict(self, lin, dt_s)
    }
    fn epoch(
        &mut self,
        t_s: f64,
        updates: impl FnOnce(&mut ErrorStateEkf<f64, 2, 27>),
    ) -> NavCorrection<f64> {
        SmoothingEkf::epoch(self, t_s, updates)
    }
}

/// The measurement noise of the inter-IMU update of one extra IMU (one sample), as the
/// filter is told it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InterImuNoise {
    /// One-sigma of `ω_s − C_b^s ω_b`, rad/s (both gyros' white noise).
    pub rate_rad_s: f64,
    /// One-sigma of `f_s − C_b^s (f_b + (Ω̇ + ΩΩ) r)`, m/s^2: both accelerometers' white
    /// noise, the differenced angular acceleration's noise times the lever-arm prior (3σ)
    /// and the central difference's error on the car's vibration lines times the same arm.
    pub force_m_s2: f64,
}

/// Per-sample one-sigma of a channel's white noise, SI units (0 if it has none).
fn white_sigma(channel: &ChannelModel) -> f64 {
    let Some(spec) = &channel.stochastic else {
        return 0.0;
    };
    let factor = unit_to_si(&spec.unit).map_or(1.0, |(f, _)| f);
    let variance: f64 = spec
        .processes
        .iter()
        .map(|p| match p {
            Process::WhiteNoise { sigma2 } => *sigma2,
            _ => 0.0,
        })
        .sum();
    variance.sqrt() * factor
}

/// Amplitude of the error of the [`AngularAccelerationStencil`] on the trajectory's roll and
/// pitch vibration lines at the fastest cruise speed, rad/s^2 (root sum square of the lines'
/// error amplitudes). A line `a sin(wt)` has acceleration amplitude `a w^2`, of which the
/// stencil returns [`stencil_gain`]`(w dt)`.
fn vibration_difference_error_rad_s2(model: &SimModel) -> f64 {
    let Some(vibration) = &model.trajectory.vibration else {
        return 0.0;
    };
    let speed = model.trajectory.cruise_speed_m_s[1];
    let dt = 1.0 / model.reference.rate_hz;
    vibration
        .roll_rad
        .iter()
        .chain(&vibration.pitch_rad)
        .map(|line| {
            let w = 2.0 * std::f64::consts::PI * line.frequency_hz;
            let amplitude = line.amplitude_at_rest + speed * line.amplitude_per_m_s;
            let x = w * dt;
            let e = amplitude * w * w * (1.0 - stencil_gain(x));
            e * e
        })
        .sum::<f64>()
        .sqrt()
}

/// The inter-IMU measurement noise of each extra IMU of `model`.
pub fn inter_imu_noise(model: &SimModel) -> Vec<InterImuNoise> {
    let ref_gyro = white_sigma(&model.reference.gyro);
    let ref_accel = white_sigma(&model.reference.accel);
    // The stencil's white-noise gain: sqrt(2 Σ c_j^2) / dt.
    let stencil_norm = (2.0 * STENCIL.iter().map(|c| c * c).sum::<f64>()).sqrt();
    let omega_dot_noise = ref_gyro * stencil_norm * model.reference.rate_hz;
    let arm = 3.0 * INITIAL_LEVER_ARM_SIGMA_M;
    let vibration = vibration_difference_error_rad_s2(model);
    model
        .imus
        .iter()
        .map(|imu| {
            let gyro = white_sigma(&imu.gyro);
            let accel = white_sigma(&imu.accel);
            InterImuNoise {
                rate_rad_s: gyro.hypot(ref_gyro),
                force_m_s2: (accel * accel
                    + ref_accel * ref_accel
                    + (omega_dot_noise * arm).powi(2)
                    + (vibration * arm).powi(2))
                .sqrt(),
            }
        })
        .collect()
}

/// Filter settings: [`EkfConfig::automotive_mems`] noise for the reference's navigation block
/// (deliberately loose: it also covers the mechanization's error on point-sampled vibration),
/// rigid mounts (constant boresight and lever arm).
pub fn fig1_config<T: FilterScalar>() -> EkfConfig<T> {
    EkfConfig::automotive_mems()
}

/// Initial sigmas: the navigation state starts at the truth (an aligned reference solution),
/// the calibration states at zero with the paper's 20 deg and 20 cm.
pub fn fig1_initial_sigmas<T: FilterScalar>() -> InitialSigmas<T> {
    let c = |x: f64| Vector3::repeat(nalgebra::convert::<f64, T>(x));
    InitialSigmas {
        position_m: c(0.05),
        velocity_m_s: c(0.02),
        attitude_rad: c(0.05f64.to_radians()),
        accel_bias_m_s2: c(2e-3),
        gyro_bias_rad_s: c(1e-6),
        boresight_rad: c(INITIAL_BORESIGHT_SIGMA_DEG.to_radians()),
        lever_arm_m: c(INITIAL_LEVER_ARM_SIGMA_M),
    }
}

/// A fresh 27-state filter with [`fig1_config`] and [`fig1_initial_sigmas`].
pub fn fig1_filter<T: FilterScalar>() -> NavEkf2<T> {
    NavEkf2::new(fig1_config(), fig1_initial_sigmas())
}

/// The nominal calibration of one extra IMU after an epoch, in `f64`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CalibrationPoint {
    /// Boresight rotation vector `ψ_b→s` (`C_s^b = exp([ψ×])`), rad, body axes.
    pub boresight_rad: [f64; 3],
    /// One-sigma, rad.
    pub boresight_sigma_rad: [f64; 3],
    /// Lever arm `r_b→s`, m, body axes.
    pub lever_arm_b_m: [f64; 3],
    /// One-sigma, m.
    pub lever_arm_sigma_m: [f64; 3],
}

/// The calibration trace of a run: one point per IMU per epoch.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CalibrationTrace {
    /// Epoch times, s.
    pub t_s: Vec<f64>,
    /// `points[imu][epoch]`.
    pub points: [Vec<CalibrationPoint>; 2],
    /// Inter-IMU scalar updates accepted and gated, summed over both IMUs and both kinds.
    pub inter_imu_accepted: u32,
    pub inter_imu_rejected: u32,
    /// GNSS position and velocity scalar updates accepted and gated.
    pub gnss_accepted: u32,
    pub gnss_rejected: u32,
}

fn v3<T: FilterScalar>(triplet: &[Vec<f64>; 3], k: usize) -> Vector3<T> {
    Vector3::new(
        nalgebra::convert(triplet[0][k]),
        nalgebra::convert(triplet[1][k]),
        nalgebra::convert(triplet[2][k]),
    )
}

fn to_f64<T: FilterScalar>(v: Vector3<T>) -> [f64; 3]
where
    f64: From<T>,
{
    [f64::from(v.x), f64::from(v.y), f64::from(v.z)]
}

/// What the rate differentiator carries along with the reference rate: the reference
/// specific force and both extra IMUs' rate and specific force at the same sample.
type Payload<T> = (Vector3<T>, [Vector3<T>; 2], [Vector3<T>; 2]);

/// What the differentiator releases: the reference rate and angular acceleration at the
/// middle sample, with its payload.
type InterImuInput<T> = (Vector3<T>, Vector3<T>, Payload<T>);

/// `x` in the filter's precision.
fn c<T: FilterScalar>(x: f64) -> T {
    nalgebra::convert::<f64, T>(x)
}

/// The reference and extra-IMU columns a run reads, checked present and on one clock.
struct RunInputs<'a> {
    /// Reference sample times, s.
    t_s: &'a [f64],
    gyro: &'a Triplet,
    accel: &'a Triplet,
    attitude: &'a Triplet,
    position: &'a Triplet,
    velocity: &'a Triplet,
    /// Each extra IMU's gyros and accelerometers.
    extra: Vec<(&'a Triplet, &'a Triplet)>,
    /// Samples common to the three IMUs.
    n: usize,
}

impl<'a> RunInputs<'a> {
    fn of(sim: &'a SimOutput, noise: &[InterImuNoise]) -> Result<Self, Fig1Error> {
        let reference = &sim.reference.recording;
        let missing = |sensor: &str, what| Fig1Error::Missing {
            sensor: sensor.to_string(),
            what,
        };
        let name = sim.reference.name.as_str();
        let need =
            |column: &'a Option<Triplet>, what| column.as_ref().ok_or_else(|| missing(name, what));
        let gyro = need(&reference.gyro_rad_s, "gyroscopes")?;
        let accel = need(&reference.accel_m_s2, "accelerometers")?;
        let attitude = need(&reference.attitude_rad, "attitude")?;
        let position = need(&reference.position, "position")?;
        let velocity = need(&reference.velocity_ned_m_s, "velocity")?;
        if sim.imus.len() != 2 || noise.len() != 2 {
            return Err(missing("fig1 model", "two extra IMUs"));
        }
        let mut extra = Vec::with_capacity(2);
        for run in &sim.imus {
            let r = &run.recording;
            let g = r
                .gyro_rad_s
                .as_ref()
                .ok_or_else(|| missing(&run.name, "gyroscopes"))?;
            let a = r
                .accel_m_s2
                .as_ref()
                .ok_or_else(|| missing(&run.name, "accelerometers"))?;
            extra.push((g, a));
        }
        let n = sim
            .imus
            .iter()
            .map(|run| run.recording.len())
            .fold(reference.len(), usize::min);
        for run in &sim.imus {
            for k in 0..n {
                let (t, t_ref) = (run.recording.t_s[k], reference.t_s[k]);
                if (t - t_ref).abs() > 1e-9 {
                    return Err(Fig1Error::NotSynchronous {
                        sensor: run.name.clone(),
                        index: k,
                        t_s: t,
                        reference_t_s: t_ref,
                    });
                }
            }
        }
        Ok(Self {
            t_s: &reference.t_s,
            gyro,
            accel,
            attitude,
            position,
            velocity,
            extra,
            n,
        })
    }

    /// The navigation state of the first reference sample.
    fn initial_state<T: FilterScalar>(&self) -> NavState<T> {
        let (attitude, position) = (self.attitude, self.position);
        NavState::<T>::from_euler(
            c(attitude[0][0]),
            c(attitude[1][0]),
            c(attitude[2][0]),
            v3(self.velocity, 0),
            c(position[0][0]),
            c(position[1][0]),
            c(position[2][0]),
        )
    }

    /// Both extra IMUs' rate and specific force at sample `k`.
    fn extra_at<T: FilterScalar>(&self, k: usize) -> ([Vector3<T>; 2], [Vector3<T>; 2]) {
        (
            [0, 1].map(|i| v3::<T>(self.extra[i].0, k)),
            [0, 1].map(|i| v3::<T>(self.extra[i].1, k)),
        )
    }
}

impl CalibrationTrace {
    /// Appends the filter's nominal calibrations and sigmas at `t_s`.
    fn record<T: FilterScalar>(&mut self, t_s: f64, ekf: &ErrorStateEkf<T, 2, 27>)
    where
        f64: From<T>,
    {
        self.t_s.push(t_s);
        for imu in 0..2 {
            let Some(cal) = ekf.calibration(imu) else {
                continue;
            };
            let sigma =
                |start: usize| [0, 1, 2].map(|a| ekf.sigma(start + a).map_or(f64::NAN, f64::from));
            self.points[imu].push(CalibrationPoint {
                boresight_rad: to_f64(cal.boresight_rad()),
                boresight_sigma_rad: sigma(boresight_index(imu)),
                lever_arm_b_m: to_f64(cal.lever_arm_b_m),
                lever_arm_sigma_m: sigma(lever_arm_index(imu)),
            });
        }
    }
}

/// Scalar updates of one epoch: inter-IMU accepted and gated, GNSS accepted and gated.
#[derive(Debug, Clone, Copy, Default)]
struct UpdateCounts {
    inter_imu_accepted: u32,
    inter_imu_rejected: u32,
    gnss_accepted: u32,
    gnss_rejected: u32,
}

impl CalibrationTrace {
    fn add(&mut self, counts: UpdateCounts) {
        self.inter_imu_accepted += counts.inter_imu_accepted;
        self.inter_imu_rejected += counts.inter_imu_rejected;
        self.gnss_accepted += counts.gnss_accepted;
        self.gnss_rejected += counts.gnss_rejected;
    }
}

/// The measurement noise of the updates, in the filter's precision.
struct UpdateSigmas<T: FilterScalar> {
    /// Per extra IMU: inter-IMU rate and specific-force one-sigma.
    rate: [Vector3<T>; 2],
    force: [Vector3<T>; 2],
    /// GNSS position (m) and velocity (m/s) one-sigma per NED axis, when there are fixes.
    gnss: Option<(Vector3<T>, Vector3<T>)>,
}

impl<T: FilterScalar> UpdateSigmas<T> {
    fn new(noise: &[InterImuNoise], gnss: Option<&GnssFixes>) -> Self {
        Self {
            rate: [0, 1].map(|i| Vector3::repeat(c(noise[i].rate_rad_s))),
            force: [0, 1].map(|i| Vector3::repeat(c(noise[i].force_m_s2))),
            gnss: gnss.map(|g| {
                (
                    Vector3::new(
                        c(g.sigma_ned_m[0]),
                        c(g.sigma_ned_m[1]),
                        c(g.sigma_ned_m[2]),
                    ),
                    Vector3::new(
                        c(g.sigma_v_ned_m_s[0]),
                        c(g.sigma_v_ned_m_s[1]),
                        c(g.sigma_v_ned_m_s[2]),
                    ),
                )
            }),
        }
    }
}

/// The GNSS fixes, read in time order.
struct GnssReader<'a> {
    fixes: Option<&'a GnssFixes>,
    next_fix: usize,
}

impl GnssReader<'_> {
    /// Position and velocity innovations against `nominal` of the fix within half a sample
    /// of `t_s`, if there is one.
    fn innovations<T: FilterScalar>(
        &mut self,
        t_s: f64,
        dt_s: f64,
        nominal: &NavState<T>,
    ) -> Option<(Vector3<T>, Vector3<T>)> {
        let gnss = self.fixes;
        while gnss
            .is_some_and(|g| self.next_fix < g.t_s.len() && g.t_s[self.next_fix] < t_s - 0.5 * dt_s)
        {
            self.next_fix += 1;
        }
        gnss.and_then(|g| {
            let j = self.next_fix;
            (j < g.t_s.len() && (g.t_s[j] - t_s).abs() <= 0.5 * dt_s).then(|| {
                let position_innovation = position_innovation_ned_m(
                    g.position[0][j],
                    g.position[1][j],
                    c(g.position[2][j]),
                    nominal,
                );
                let velocity_innovation = v3::<T>(&g.velocity_ned_m_s, j) - nominal.v_ned_m_s;
                (position_innovation, velocity_innovation)
            })
        })
    }
}

/// The updates of one epoch: the joint inter-IMU update of both extra IMUs when the
/// differentiator released a sample, GNSS position and velocity when there is a fix.
fn fuse_updates<T: FilterScalar>(
    ekf: &mut ErrorStateEkf<T, 2, 27>,
    inter_imu: Option<InterImuInput<T>>,
    fix: Option<(Vector3<T>, Vector3<T>)>,
    sigmas: &UpdateSigmas<T>,
) -> UpdateCounts {
    let mut counts = UpdateCounts::default();
    if let Some((omega_mid, omega_dot_mid, (f_mid, omega_s, f_s))) = inter_imu {
        for imu in 0..2 {
            let sample = InterImuSample {
                omega_ib_b_rad_s: omega_mid,
                omega_dot_ib_b_rad_s2: omega_dot_mid,
                f_b_m_s2: f_mid,
                omega_is_s_rad_s: omega_s[imu],
                f_s_m_s2: f_s[imu],
                shares_reference_bias: false,
            };
            if let Some(batch) =
                ekf.fuse_inter_imu(imu, &sample, &sigmas.rate[imu], &sigmas.force[imu])
            {
                counts.inter_imu_accepted += u32::from(batch.accepted);
                counts.inter_imu_rejected += u32::from(batch.rejected + batch.faults);
            }
        }
    }
    if let (Some((dp, dv)), Some((sigma_p, sigma_v))) = (fix, sigmas.gnss) {
        for batch in [
            ekf.fuse_gnss_position(&dp, &sigma_p),
            ekf.fuse_gnss_velocity(&dv, &sigma_v),
        ] {
            counts.gnss_accepted += u32::from(batch.accepted);
            counts.gnss_rejected += u32::from(batch.rejected + batch.faults);
        }
    }
    counts
}

/// One reference sample `k` through the strapdown (bias-corrected rates and specific forces
/// of samples `k - 1` and `k`) and the filter's prediction; returns the corrected rate and
/// specific force at `k`.
fn propagate<T, F>(
    inputs: &RunInputs<'_>,
    k: usize,
    strapdown: &mut Strapdown<T>,
    filter: &mut F,
) -> Result<(Vector3<T>, Vector3<T>), Fig1Error>
where
    T: FilterScalar,
    F: CalibrationFilter<T>,
{
    let t_s = inputs.t_s[k];
    let dt_s = t_s - inputs.t_s[k - 1];
    let gyro_bias = filter.ekf().gyro_bias_b_rad_s();
    let accel_bias = filter.ekf().accel_bias_b_m_s2();
    let omega0 = v3::<T>(inputs.gyro, k - 1) - gyro_bias;
    let omega1 = v3::<T>(inputs.gyro, k) - gyro_bias;
    let f0 = v3::<T>(inputs.accel, k - 1) - accel_bias;
    let f1 = v3::<T>(inputs.accel, k) - accel_bias;
    strapdown
        .step_rates(omega0, omega1, f0, f1, c(dt_s))
        .map_err(|fault| Fig1Error::Mechanization {
            t_s,
            fault: format!("{fault:?}"),
        })?;
    let half: T = c(0.5);
    let lin = NavLinearization::from_state(strapdown.state(), (f0 + f1) * half);
    if !filter.predict(&lin, c(dt_s)) {
        return Err(Fig1Error::Prediction { t_s });
    }
    Ok((omega1, f1))
}

/// Drives the reference-IMU strapdown and `filter` through a simulation of [`fig1_model`]:
/// a prediction per reference sample, the joint inter-IMU update of both extra IMUs at every
/// sample (three samples late, as the angular acceleration is a central difference), GNSS
/// position and velocity at every fix, and a reset after each epoch.
pub fn run_calibration<T, F>(
    sim: &SimOutput,
    noise: &[InterImuNoise],
    filter: &mut F,
) -> Result<CalibrationTrace, Fig1Error>
where
    T: FilterScalar,
    f64: From<T>,
    F: CalibrationFilter<T>,
{
    let inputs = RunInputs::of(sim, noise)?;
    let sigmas = UpdateSigmas::<T>::new(noise, sim.gnss.as_ref());
    let mut strapdown = Strapdown::new(inputs.initial_state::<T>());
    let mut trace = CalibrationTrace::default();
    filter.epoch(inputs.t_s[0], |_| {});
    trace.record(inputs.t_s[0], filter.ekf());

    let mut gnss = GnssReader {
        fixes: sim.gnss.as_ref(),
        next_fix: 0,
    };
    let mut differentiator = AngularAccelerationStencil::<T, Payload<T>>::default();
    for k in 1..inputs.n {
        let t_s = inputs.t_s[k];
        let dt_s = t_s - inputs.t_s[k - 1];
        let (omega1, f1) = propagate(&inputs, k, &mut strapdown, filter)?;
        let (omega_s, f_s) = inputs.extra_at::<T>(k);
        let inter_imu = differentiator.push(c(dt_s), omega1, (f1, omega_s, f_s));
        let fix = gnss.innovations(t_s, dt_s, strapdown.state());
        let mut counts = UpdateCounts::default();
        let correction = filter.epoch(t_s, |ekf| {
            counts = fuse_updates(ekf, inter_imu, fix, &sigmas);
        });
        trace.add(counts);
        let mut state = *strapdown.state();
        apply_correction(&mut state, &correction);
        strapdown.set_state(state);
        trace.record(t_s, filter.ekf());
    }
    Ok(trace)
}

/// The true mount of one extra IMU, in the filter's parametrisation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TrueCalibration {
    /// Boresight rotation vector `ψ_b→s` of the simulated `C_s^b`, rad.
    pub boresight_rad: [f64; 3],
    /// Lever arm, m, body axes.
    pub lever_arm_b_m: [f64; 3],
}

/// The true calibrations of the simulated extra IMUs (from the mounts the simulator used).
pub fn true_calibrations(sim: &SimOutput) -> Vec<TrueCalibration> {
    sim.imus
        .iter()
        .map(|run| {
            let c_sb = run.mount.c_bs.transpose();
            let q = UnitQuaternion::from_matrix(&c_sb);
            let psi = q.scaled_axis();
            TrueCalibration {
                boresight_rad: [psi.x, psi.y, psi.z],
                lever_arm_b_m: run.mount.lever_arm_b_m.into(),
            }
        })
        .collect()
}

/// An estimate with its one-sigma, and its error against the truth, in the figure's units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CalibrationSummary {
    pub boresight_deg: [f64; 3],
    pub boresight_sigma_deg: [f64; 3],
    pub boresight_error_deg: [f64; 3],
    pub lever_arm_m: [f64; 3],
    pub lever_arm_sigma_m: [f64; 3],
    pub lever_arm_error_m: [f64; 3],
    /// Largest |error| / sigma over the six components.
    pub max_error_over_sigma: f64,
}

impl CalibrationSummary {
    fn new(point: &CalibrationPoint, truth: &TrueCalibration) -> Self {
        let deg = |v: [f64; 3]| v.map(f64::to_degrees);
        let error = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let psi_err = error(point.boresight_rad, truth.boresight_rad);
        let arm_err = error(point.lever_arm_b_m, truth.lever_arm_b_m);
        let ratio = (0..3)
            .flat_map(|a| {
                [
                    psi_err[a].abs() / point.boresight_sigma_rad[a],
                    arm_err[a].abs() / point.lever_arm_sigma_m[a],
                ]
            })
            .fold(0.0, f64::max);
        Self {
            boresight_deg: deg(point.boresight_rad),
            boresight_sigma_deg: deg(point.boresight_sigma_rad),
            boresight_error_deg: deg(psi_err),
            lever_arm_m: point.lever_arm_b_m,
            lever_arm_sigma_m: point.lever_arm_sigma_m,
            lever_arm_error_m: arm_err,
            max_error_over_sigma: ratio,
        }
    }
}

/// Time after which every component of a trace stays within `threshold` of the truth: the
/// epoch after the last one outside it (0 if never outside). `None` if it ends outside.
pub fn convergence_time_s(
    t_s: &[f64],
    values: impl Fn(usize) -> [f64; 3],
    truth: [f64; 3],
    threshold: f64,
) -> Option<f64> {
    let outside = |k: usize| {
        let v = values(k);
        (0..3).any(|a| (v[a] - truth[a]).abs() > threshold || !v[a].is_finite())
    };
    match (0..t_s.len()).rev().find(|&k| outside(k)) {
        None => Some(t_s.first().copied().unwrap_or(0.0)),
        Some(last) if last + 1 < t_s.len() => Some(t_s[last + 1]),
        Some(_) => None,
    }
}

/// One extra IMU's results.
#[derive(Debug, Clone, Serialize)]
pub struct ImuReport {
    pub name: String,
    pub spec: ExtraImuSpec,
    pub truth_boresight_deg: [f64; 3],
    pub truth_lever_arm_m: [f64; 3],
    pub noise: InterImuNoise,
    /// The forward filter at the last epoch.
    pub filtered: CalibrationSummary,
    /// The paper's final estimate: variance-weighted mean of the RTS-smoothed epochs.
    pub smoothed: CalibrationSummary,
    /// Time from the start after which the filtered boresight stays within
    /// [`CONVERGED_BORESIGHT_DEG`] of the truth, s.
    pub boresight_converged_after_s: Option<f64>,
    /// Same for the lever arm within [`CONVERGED_LEVER_ARM_M`], s.
    pub lever_arm_converged_after_s: Option<f64>,
}

/// The whole run's results (written as JSON by `dynacal fig1`).
#[derive(Debug, Clone, Serialize)]
pub struct Fig1Report {
    pub seconds: f64,
    pub seed: u64,
    pub imu_rate_hz: f64,
    pub gnss_rate_hz: f64,
    pub initial_stop_s: f64,
    pub initial_boresight_sigma_deg: f64,
    pub initial_lever_arm_sigma_m: f64,
    pub epochs: usize,
    pub inter_imu_updates_accepted: u32,
    pub inter_imu_updates_rejected: u32,
    pub gnss_updates_accepted: u32,
    pub gnss_updates_rejected: u32,
    pub imus: Vec<ImuReport>,
}

/// A finished Fig. 1 run: the report, the filtered trace and the truth (for the plot).
#[derive(Debug, Clone)]
pub struct Fig1Run {
    pub report: Fig1Report,
    pub trace: CalibrationTrace,
    pub truth: Vec<TrueCalibration>,
}

/// Simulates, filters (f64, recording for the smoother), smooths and summarises.
pub fn fig1(seconds: f64, seed: u64) -> Result<Fig1Run, Fig1Error> {
    let sim = simulate_fig1(seconds, seed)?;
    let model = fig1_model();
    let noise = inter_imu_noise(&model);
    let mut filter = SmoothingEkf::new(fig1_filter::<f64>());
    let trace = run_calibration(&sim, &noise, &mut filter)?;
    let smoothed = filter.smooth()?;
    let truth = true_calibrations(&sim);
    let mut imus = Vec::with_capacity(2);
    for (imu, ((spec, truth_i), noise_i)) in FIG1_IMUS.iter().zip(&truth).zip(&noise).enumerate() {
        let points = &trace.points[imu];
        let last = points.last().ok_or(SmootherError::Empty)?;
        let estimate = smoothed
            .calibration_estimate(imu)
            .ok_or(SmootherError::Empty)?;
        let smoothed_point = CalibrationPoint {
            boresight_rad: estimate.boresight_rad.into(),
            boresight_sigma_rad: estimate.boresight_sigma_rad.into(),
            lever_arm_b_m: estimate.lever_arm_b_m.into(),
            lever_arm_sigma_m: estimate.lever_arm_sigma_m.into(),
        };
        imus.push(ImuReport {
            name: spec.name.to_string(),
            spec: *spec,
            truth_boresight_deg: truth_i.boresight_rad.map(f64::to_degrees),
            truth_lever_arm_m: truth_i.lever_arm_b_m,
            noise: *noise_i,
            filtered: CalibrationSummary::new(last, truth_i),
            smoothed: CalibrationSummary::new(&smoothed_point, truth_i),
            boresight_converged_after_s: convergence_time_s(
                &trace.t_s,
                |k| points[k].boresight_rad,
                truth_i.boresight_rad,
                CONVERGED_BORESIGHT_DEG.to_radians(),
            ),
            lever_arm_converged_after_s: convergence_time_s(
                &trace.t_s,
                |k| points[k].lever_arm_b_m,
                truth_i.lever_arm_b_m,
                CONVERGED_LEVER_ARM_M,
            ),
        });
    }
    let report = Fig1Report {
        seconds,
        seed,
        imu_rate_hz: FIG1_RATE_HZ,
        gnss_rate_hz: FIG1_GNSS_RATE_HZ,
        initial_stop_s: FIG1_INITIAL_STOP_S,
        initial_boresight_sigma_deg: INITIAL_BORESIGHT_SIGMA_DEG,
        initial_lever_arm_sigma_m: INITIAL_LEVER_ARM_SIGMA_M,
        epochs: trace.t_s.len(),
        inter_imu_updates_accepted: trace.inter_imu_accepted,
        inter_imu_updates_rejected: trace.inter_imu_rejected,
        gnss_updates_accepted: trace.gnss_accepted,
        gnss_updates_rejected: trace.gnss_rejected,
        imus,
    };
    Ok(Fig1Run {
        report,
        trace,
        truth,
    })
}
