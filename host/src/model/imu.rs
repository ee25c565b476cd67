//! One IMU's error model: its mounting against the reference body frame, its sample clock,
//! and the error model of each of its six channels (the GMWM stochastic processes plus every
//! deterministic effect the simulator runs and the diagnosis names). Each effect is defined
//! here once; the simulator (`crate::sim::effects`) implements it and the diagnosis fills it.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::Channel;
use crate::gmwm::model::{ModelSpec, Process};

/// An effect of the model that can be switched off without deleting its parameters (in a
/// `disabled` list of a channel, a sensor or the GNSS receiver, or everywhere with `dynacal
/// simulate --disable`); written as its snake_case name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Effect {
    /// Switches off white noise of the stochastic model.
    WhiteNoise,
    /// Switches off quantization noise of the stochastic model.
    QuantizationNoise,
    /// Switches off random walk of the stochastic model.
    RandomWalk,
    /// Switches off drift of the stochastic model.
    Drift,
    /// Switches off every Gauss-Markov process of the stochastic model.
    GaussMarkov,
    /// Switches off the constant bias.
    Bias,
    /// Switches off the scale-factor error.
    ScaleFactor,
    /// Switches off the cross-axis sensitivity.
    CrossAxis,
    /// Switches off the gyro g-sensitivity.
    GSensitivity,
    /// Switches off the angular-acceleration sensitivity.
    AngularAccelerationSensitivity,
    /// Switches off the jerk sensitivity.
    JerkSensitivity,
    /// Switches off noise following the dynamics.
    DynamicNoise,
    /// Switches off the vibration lines.
    Vibration,
    /// Switches off outliers.
    Outliers,
    /// Switches off the bias steps.
    BiasStep,
    /// Switches off saturation.
    Saturation,
    /// Switches off rounding of the output to its step.
    Quantization,
    /// Switches off the lever arm.
    LeverArm,
    /// Switches off the boresight.
    Boresight,
    /// Switches off the time offset.
    TimeOffset,
    /// Switches off the sample clock's frequency offset and random walk.
    ClockDrift,
    /// Switches off the sample clock's jitter.
    ClockJitter,
    /// Switches off white noise of the GNSS position.
    GnssPositionNoise,
    /// Switches off the correlated GNSS position error.
    GnssPositionBias,
    /// Switches off white noise of the GNSS velocity.
    GnssVelocityNoise,
    /// Switches off the GNSS outages.
    GnssOutages,
    /// Switches off the PPS jitter.
    PpsJitter,
}

impl Effect {
    /// Every effect, in the order the simulator applies them.
    pub const ALL: [Effect; 27] = [
        Effect::WhiteNoise,
        Effect::QuantizationNoise,
        Effect::RandomWalk,
        Effect::Drift,
        Effect::GaussMarkov,
        Effect::Bias,
        Effect::ScaleFactor,
        Effect::CrossAxis,
        Effect::GSensitivity,
        Effect::AngularAccelerationSensitivity,
        Effect::JerkSensitivity,
        Effect::DynamicNoise,
        Effect::Vibration,
        Effect::Outliers,
        Effect::BiasStep,
        Effect::Saturation,
        Effect::Quantization,
        Effect::LeverArm,
        Effect::Boresight,
        Effect::TimeOffset,
        Effect::ClockDrift,
        Effect::ClockJitter,
        Effect::GnssPositionNoise,
        Effect::GnssPositionBias,
        Effect::GnssVelocityNoise,
        Effect::GnssOutages,
        Effect::PpsJitter,
    ];

    /// The name in model files and on the command line.
    pub const fn name(self) -> &'static str {
        match self {
            Effect::WhiteNoise => "white_noise",
            Effect::QuantizationNoise => "quantization_noise",
            Effect::RandomWalk => "random_walk",
            Effect::Drift => "drift",
            Effect::GaussMarkov => "gauss_markov",
            Effect::Bias => "bias",
            Effect::ScaleFactor => "scale_factor",
            Effect::CrossAxis => "cross_axis",
            Effect::GSensitivity => "g_sensitivity",
            Effect::AngularAccelerationSensitivity => "angular_acceleration_sensitivity",
            Effect::JerkSensitivity => "jerk_sensitivity",
            Effect::DynamicNoise => "dynamic_noise",
            Effect::Vibration => "vibration",
            Effect::Outliers => "outliers",
            Effect::BiasStep => "bias_step",
            Effect::Saturation => "saturation",
            Effect::Quantization => "quantization",
            Effect::LeverArm => "lever_arm",
            Effect::Boresight => "boresight",
            Effect::TimeOffset => "time_offset",
            Effect::ClockDrift => "clock_drift",
            Effect::ClockJitter => "clock_jitter",
            Effect::GnssPositionNoise => "gnss_position_noise",
            Effect::GnssPositionBias => "gnss_position_bias",
            Effect::GnssVelocityNoise => "gnss_velocity_noise",
            Effect::GnssOutages => "gnss_outages",
            Effect::PpsJitter => "pps_jitter",
        }
    }

    /// Every name, comma-separated (for messages).
    pub fn all_names() -> String {
        Self::ALL.map(Effect::name).join(", ")
    }
}

impl std::fmt::Display for Effect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Effect {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|e| e.name() == s)
            .ok_or_else(|| format!("unknown effect `{s}` (known: {})", Self::all_names()))
    }
}

/// What makes a channel's noise level depend on the dynamics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DynamicDriver {
    /// |omega_ib^s|, rad/s.
    AngularRateNorm,
    /// |d omega/dt|, rad/s^2.
    AngularAccelerationNorm,
    /// Ground speed, m/s.
    Speed,
    /// |d f^s/dt|, m/s^3.
    JerkNorm,
}

/// White noise whose standard deviation is `sigma_per_unit * driver`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DynamicNoise {
    pub driver: DynamicDriver,
    /// Channel unit (rad/s or m/s^2) per driver unit.
    pub sigma_per_unit: f64,
}

/// A sinusoidal disturbance on the channel, evaluated at the true sampling instants (so a
/// line above the Nyquist frequency aliases as it would in the sensor).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VibrationLine {
    pub frequency_hz: f64,
    /// Amplitude, channel unit.
    pub amplitude: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub phase_rad: f64,
}

/// Rare large errors: with `probability` per sample, an added N(0, sigma^2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Outliers {
    pub probability: f64,
    /// Channel unit.
    pub sigma: f64,
}

/// The error model of one channel (gx ... az); units are SI (rad/s or m/s^2) except inside
/// `stochastic`, which carries its own unit and sample rate.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelModel {
    /// Effects switched off for this channel.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disabled: Vec<Effect>,
    /// Stochastic error processes (white noise, quantization noise, random walk, drift, any
    /// number of Gauss-Markov): a GMWM model object as `dynacal fit` writes it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stochastic: Option<ModelSpec>,
    /// Constant bias, channel unit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bias: Option<f64>,
    /// Scale-factor error (dimensionless: 1e-3 is 1000 ppm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale_factor: Option<f64>,
    /// Cross-axis sensitivity to the true sensor-frame x, y, z inputs (misalignment); the
    /// channel's own entry must be 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cross_axis: Option<[f64; 3]>,
    /// Sensitivity to the sensor-frame specific force (gyro g-sensitivity), unit per m/s^2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub g_sensitivity: Option<[f64; 3]>,
    /// Sensitivity to sensor-frame angular acceleration, unit per rad/s^2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angular_acceleration_sensitivity: Option<[f64; 3]>,
    /// Sensitivity to the rate of change of sensor-frame specific force, unit per m/s^3.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jerk_sensitivity: Option<[f64; 3]>,
    /// Noise whose level follows the dynamics.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dynamic_noise: Option<DynamicNoise>,
    /// Vibration lines.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub vibration_lines: Vec<VibrationLine>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outliers: Option<Outliers>,
    /// Steps of the bias during the run (e.g. after a shock or a thermal event).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub bias_steps: Vec<BiasStep>,
    /// Output clipped to +-saturation, channel unit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saturation: Option<f64>,
    /// Output rounded to multiples of this step (LSB), channel unit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quantization_step: Option<f64>,
}

/// A step of the bias: from true time `at_s` on, the channel's bias is larger by `size`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BiasStep {
    /// True time of the step, s from the start of the run.
    pub at_s: f64,
    /// Size of the step, channel unit (rad/s or m/s^2).
    pub size: f64,
}

/// The sample clock of an IMU: samples are evenly spaced in the IMU's own time, which runs
/// at (1 + frequency error) times true time; each instant also jitters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClockModel {
    /// Constant frequency error, ppm (positive: the clock runs fast).
    pub frequency_offset_ppm: f64,
    /// Random walk of the frequency error, ppm per sqrt(s).
    pub frequency_random_walk_ppm_per_sqrt_s: f64,
    /// White jitter of each sampling instant (standard deviation), s.
    pub jitter_s: f64,
}

/// One IMU: its mounting relative to the reference (b-frame), its clock, and the error model
/// of each of its six channels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuModel {
    /// Name; also the output file stem.
    pub name: String,
    /// Nominal sampling rate, Hz.
    pub rate_hz: f64,
    /// Lever arm from the reference IMU to this IMU, reference body frame, m.
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub lever_arm_b_m: [f64; 3],
    /// Boresight: roll, pitch, yaw (Z-Y-X) of this IMU's frame w.r.t. the reference body
    /// frame, deg (C_s^b = Rz Ry Rx).
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub boresight_rpy_deg: [f64; 3],
    /// The sample stamped t was taken at true time t - time_offset_s.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub time_offset_s: f64,
    #[serde(default, skip_serializing_if = "is_default")]
    pub clock: ClockModel,
    /// Effects switched off for the whole sensor.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disabled: Vec<Effect>,
    /// Default error model of gx, gy, gz.
    #[serde(default, skip_serializing_if = "is_default")]
    pub gyro: ChannelModel,
    /// Default error model of ax, ay, az.
    #[serde(default, skip_serializing_if = "is_default")]
    pub accel: ChannelModel,
    /// Per-channel models replacing the defaults.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub channels: BTreeMap<Channel, ChannelModel>,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}
fn is_zero3(v: &[f64; 3]) -> bool {
    *v == [0.0; 3]
}
fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

impl ImuModel {
    /// The model of channel `i` (0..6 in gx gy gz ax ay az order).
    pub fn channel(&self, i: usize) -> &ChannelModel {
        let channel = Channel::ALL[i];
        self.model_of(channel)
    }

    /// The model of `channel`: its own entry, else the sensor's default.
    pub fn model_of(&self, channel: Channel) -> &ChannelModel {
        self.channels.get(&channel).unwrap_or(if channel.is_gyro() {
            &self.gyro
        } else {
            &self.accel
        })
    }

    /// A MEMS IMU named `name` sampled at `rate_hz`, mounted at the reference with no error
    /// effect: the start of a fitted or diagnosed model.
    pub fn bare(name: &str, rate_hz: f64) -> Self {
        ImuModel {
            name: name.into(),
            rate_hz,
            lever_arm_b_m: [0.0; 3],
            boresight_rpy_deg: [0.0; 3],
            time_offset_s: 0.0,
            clock: ClockModel::default(),
            disabled: Vec::new(),
            gyro: ChannelModel::default(),
            accel: ChannelModel::default(),
            channels: BTreeMap::new(),
        }
    }

    /// A navigation-grade reference IMU (figures of the seed paper's Ixsea Airins: gyro
    /// noise 0.0015 deg/sqrt(h), gyro bias 0.01 deg/h, accelerometer noise 20 ug/sqrt(Hz),
    /// bias 100 ug), sampled at 200 Hz.
    pub fn navigation_grade_reference() -> Self {
        let rate = 200.0;
        let gyro_density = 0.0015f64.to_radians() / 60.0; // rad/s/sqrt(Hz)
        let accel_density = 20e-6 * 9.80665; // m/s^2/sqrt(Hz)
        let wn = |density: f64, unit: &str| ModelSpec {
            model: "WN".into(),
            unit: unit.into(),
            sample_rate_hz: rate,
            processes: vec![Process::WhiteNoise {
                sigma2: density * density * rate,
            }],
        };
        ImuModel {
            name: "reference".into(),
            rate_hz: rate,
            lever_arm_b_m: [0.0; 3],
            boresight_rpy_deg: [0.0; 3],
            time_offset_s: 0.0,
            clock: ClockModel::default(),
            disabled: Vec::new(),
            gyro: ChannelModel {
                stochastic: Some(wn(gyro_density, "rad/s")),
                bias: Some(0.01f64.to_radians() / 3600.0),
                ..Default::default()
            },
            accel: ChannelModel {
                stochastic: Some(wn(accel_density, "m/s2")),
                bias: Some(100e-6 * 9.80665),
                ..Default::default()
            },
            channels: BTreeMap::new(),
        }
    }
}
