//! The simulator's model file: one JSON object describing the trajectory options, the
//! reference IMU, up to three MEMS IMUs (mounting, clock, per-channel error effects), the
//! GNSS receiver and the PPS. The stochastic part of every channel is the GMWM model object
//! (`dynacal::gmwm::model::ModelSpec`) that `dynacal fit` writes, and a bare fitted model is
//! accepted as a whole model file too (one MEMS IMU whose matching channels carry it).
//!
//! Every effect is on when its parameters are present and can be switched off without
//! deleting them by naming it in a `disabled` list (per channel, per sensor, or globally
//! from the command line); [`EFFECTS`] lists the names.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::sim::trajectory::TrajectoryConfig;
use crate::gmwm::model::{ModelSpec, Process};

/// Errors in a model file; each names the file and the field.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelFileError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// JSON syntax or schema error (serde reports line and column).
    #[error("{path}: {message}")]
    Json { path: PathBuf, message: String },
    /// A value is out of range or inconsistent.
    #[error("{path}: field `{field}`: {message}")]
    Invalid {
        path: PathBuf,
        field: String,
        message: String,
    },
}

/// Names of all switchable effects.
pub const EFFECTS: &[&str] = &[
    // stochastic processes of the GMWM model, by kind
    "white_noise",
    "quantization_noise",
    "random_walk",
    "drift",
    "gauss_markov",
    // deterministic and other per-channel effects
    "bias",
    "scale_factor",
    "cross_axis",
    "g_sensitivity",
    "angular_acceleration_sensitivity",
    "jerk_sensitivity",
    "dynamic_noise",
    "vibration",
    "outliers",
    "bias_step",
    "saturation",
    "quantization",
    // per-sensor effects
    "lever_arm",
    "boresight",
    "time_offset",
    "clock_drift",
    "clock_jitter",
    // GNSS effects
    "gnss_position_noise",
    "gnss_position_bias",
    "gnss_velocity_noise",
    "gnss_outages",
    "pps_jitter",
];

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
    #[serde(default)]
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
    pub disabled: Vec<String>,
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
    #[serde(default)]
    pub lever_arm_b_m: [f64; 3],
    /// Boresight: roll, pitch, yaw (Z-Y-X) of this IMU's frame w.r.t. the reference body
    /// frame, deg (C_s^b = Rz Ry Rx).
    #[serde(default)]
    pub boresight_rpy_deg: [f64; 3],
    /// The sample stamped t was taken at true time t - time_offset_s.
    #[serde(default)]
    pub time_offset_s: f64,
    #[serde(default)]
    pub clock: ClockModel,
    /// Effects switched off for the whole sensor (any name of [`EFFECTS`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disabled: Vec<String>,
    /// Default error model of gx, gy, gz.
    #[serde(default)]
    pub gyro: ChannelModel,
    /// Default error model of ax, ay, az.
    #[serde(default)]
    pub accel: ChannelModel,
    /// Per-channel models (keys gx ... az) replacing the defaults.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub channels: BTreeMap<String, ChannelModel>,
}

impl ImuModel {
    /// The model of channel `i` (0..6 in gx gy gz ax ay az order).
    pub fn channel(&self, i: usize) -> &ChannelModel {
        let name = crate::interchange::CHANNELS[i];
        self.channels
            .get(name)
            .unwrap_or(if i < 3 { &self.gyro } else { &self.accel })
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

/// First-order Gauss-Markov position error (the slowly wandering part of a GNSS fix).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssBias {
    /// Stationary standard deviation per NED axis, m.
    pub sigma_ned_m: [f64; 3],
    /// Correlation time, s.
    pub tau_s: f64,
}

/// The GNSS receiver: antenna position and velocity fixes on GPS time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssModel {
    /// Fix rate, Hz (1-10 typical).
    pub rate_hz: f64,
    /// Antenna lever arm in the reference body frame, m.
    #[serde(default)]
    pub lever_arm_b_m: [f64; 3],
    /// White position noise per NED axis, m.
    #[serde(default)]
    pub position_sigma_ned_m: [f64; 3],
    /// Correlated position error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_bias: Option<GnssBias>,
    /// White velocity noise per NED axis, m/s.
    #[serde(default)]
    pub velocity_sigma_ned_m_s: [f64; 3],
    /// Intervals [start_s, end_s) without fixes.
    #[serde(default)]
    pub outages: Vec<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disabled: Vec<String>,
}

impl Default for GnssModel {
    /// A geodetic receiver with a float/fixed carrier-phase solution at 10 Hz.
    fn default() -> Self {
        Self {
            rate_hz: 10.0,
            lever_arm_b_m: [0.0, 0.0, -1.2],
            position_sigma_ned_m: [0.01, 0.01, 0.02],
            position_bias: Some(GnssBias {
                sigma_ned_m: [0.02, 0.02, 0.04],
                tau_s: 60.0,
            }),
            velocity_sigma_ned_m_s: [0.01, 0.01, 0.02],
            outages: Vec::new(),
            disabled: Vec::new(),
        }
    }
}

/// The receiver's pulse per second, captured by each IMU's clock.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PpsModel {
    /// Jitter of the pulse edge w.r.t. the GPS second (standard deviation), s.
    pub jitter_s: f64,
    /// Resolution of the capture by each IMU's timer, s.
    pub capture_resolution_s: f64,
}

impl Default for PpsModel {
    fn default() -> Self {
        Self {
            jitter_s: 20e-9,
            capture_resolution_s: 1e-6,
        }
    }
}

/// A whole model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimModel {
    /// Free text describing the model.
    #[serde(default, rename = "_comment", skip_serializing_if = "Option::is_none")]
    pub comment: Option<String>,
    #[serde(default)]
    pub trajectory: TrajectoryConfig,
    /// The reference IMU; it defines the body frame (no lever arm, boresight or clock).
    #[serde(default = "ImuModel::navigation_grade_reference")]
    pub reference: ImuModel,
    /// Up to three MEMS IMUs.
    #[serde(default)]
    pub imus: Vec<ImuModel>,
    #[serde(default = "default_gnss")]
    pub gnss: Option<GnssModel>,
    #[serde(default = "default_pps")]
    pub pps: Option<PpsModel>,
}

fn default_gnss() -> Option<GnssModel> {
    Some(GnssModel::default())
}
fn default_pps() -> Option<PpsModel> {
    Some(PpsModel::default())
}

/// SI factor and dimension of a stochastic-model unit: (factor to SI, is angular rate).
pub fn unit_to_si(unit: &str) -> Option<(f64, bool)> {
    let u: String = unit.chars().filter(|c| !c.is_whitespace()).collect();
    let deg = std::f64::consts::PI / 180.0;
    Some(match u.as_str() {
        "rad/s" => (1.0, true),
        "mrad/s" => (1e-3, true),
        "deg/s" => (deg, true),
        "deg/h" | "deg/hr" => (deg / 3600.0, true),
        "m/s2" | "m/s^2" => (1.0, false),
        "g" => (9.80665, false),
        "mg" => (9.80665e-3, false),
        "ug" | "µg" => (9.80665e-6, false),
        _ => return None,
    })
}

impl SimModel {
    /// Reads a model file: a full simulator model or a bare fitted GMWM model.
    pub fn load(path: &Path) -> Result<Self, ModelFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| ModelFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json(&text, path)
    }

    /// Parses model-file text; `path` is used in error messages.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, ModelFileError> {
        let json_err = |e: serde_json::Error| ModelFileError::Json {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let value: serde_json::Value = serde_json::from_str(text).map_err(json_err)?;
        let model = if value.get("processes").is_some() {
            let spec: ModelSpec = serde_json::from_str(text).map_err(json_err)?;
            Self::from_fitted(spec, path)?
        } else {
            serde_json::from_str(text).map_err(json_err)?
        };
        model.validate(path)?;
        Ok(model)
    }

    /// A model whose one MEMS IMU (named `imu1`, at the fitted model's rate) carries the
    /// fitted stochastic model on every channel of matching dimension (gyros for an angular
    /// rate unit, accelerometers otherwise).
    pub fn from_fitted(spec: ModelSpec, path: &Path) -> Result<Self, ModelFileError> {
        let (_, angular) = unit_to_si(&spec.unit).ok_or_else(|| ModelFileError::Invalid {
            path: path.to_path_buf(),
            field: "unit".into(),
            message: format!("unknown unit `{}`", spec.unit),
        })?;
        let channel = ChannelModel {
            stochastic: Some(spec.clone()),
            ..Default::default()
        };
        let imu = ImuModel {
            name: "imu1".into(),
            rate_hz: spec.sample_rate_hz,
            lever_arm_b_m: [0.0; 3],
            boresight_rpy_deg: [0.0; 3],
            time_offset_s: 0.0,
            clock: ClockModel::default(),
            disabled: Vec::new(),
            gyro: if angular {
                channel.clone()
            } else {
                ChannelModel::default()
            },
            accel: if angular {
                ChannelModel::default()
            } else {
                channel
            },
            channels: BTreeMap::new(),
        };
        Ok(SimModel {
            comment: Some(format!(
                "fitted model {} ({}) on imu1",
                spec.model, spec.unit
            )),
            trajectory: TrajectoryConfig::default(),
            reference: ImuModel::navigation_grade_reference(),
            imus: vec![imu],
            gnss: default_gnss(),
            pps: default_pps(),
        })
    }

    /// Checks ranges and names; errors name the field (e.g. `imus[1].channels.gx.bias`).
    pub fn validate(&self, path: &Path) -> Result<(), ModelFileError> {
        let bad = |field: String, message: String| ModelFileError::Invalid {
            path: path.to_path_buf(),
            field,
            message,
        };
        let known: BTreeSet<&str> = EFFECTS.iter().copied().collect();
        let check_names = |field: String, names: &[String]| -> Result<(), ModelFileError> {
            for n in names {
                if !known.contains(n.as_str()) {
                    return Err(bad(
                        field.clone(),
                        format!("unknown effect `{n}` (known: {})", EFFECTS.join(", ")),
                    ));
                }
            }
            Ok(())
        };
        let finite = |field: String, v: f64| -> Result<(), ModelFileError> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(bad(field, format!("{v} is not a finite number")))
            }
        };
        if self.imus.len() > 3 {
            return Err(bad(
                "imus".into(),
                format!("{} IMUs given, at most 3 are supported", self.imus.len()),
            ));
        }
        let mut names = BTreeSet::new();
        for (k, imu) in std::iter::once(&self.reference)
            .chain(&self.imus)
            .enumerate()
        {
            let at = if k == 0 {
                "reference".to_string()
            } else {
                format!("imus[{}]", k - 1)
            };
            if imu.name.is_empty()
                || !imu
                    .name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(bad(
                    format!("{at}.name"),
                    format!("`{}` must be non-empty letters, digits, - or _", imu.name),
                ));
            }
            if imu.name == "gnss"
                || imu.name == "pps"
                || imu.name == "truth"
                || !names.insert(imu.name.clone())
            {
                return Err(bad(
                    format!("{at}.name"),
                    format!("`{}` is reserved or used twice", imu.name),
                ));
            }
            if !(imu.rate_hz.is_finite() && imu.rate_hz > 0.0 && imu.rate_hz <= 100_000.0) {
                return Err(bad(
                    format!("{at}.rate_hz"),
                    format!("{} must be in (0, 100000] Hz", imu.rate_hz),
                ));
            }
            if k == 0
                && (imu.lever_arm_b_m != [0.0; 3]
                    || imu.boresight_rpy_deg != [0.0; 3]
                    || imu.time_offset_s != 0.0
                    || imu.clock != ClockModel::default())
            {
                return Err(bad(at.clone(), "the reference IMU defines the body frame and GPS time: its lever arm, boresight, time offset and clock must be zero".into()));
            }
            for (i, v) in imu
                .lever_arm_b_m
                .iter()
                .chain(&imu.boresight_rpy_deg)
                .enumerate()
            {
                finite(
                    format!(
                        "{at}.{}",
                        if i < 3 {
                            "lever_arm_b_m"
                        } else {
                            "boresight_rpy_deg"
                        }
                    ),
                    *v,
                )?;
            }
            finite(format!("{at}.time_offset_s"), imu.time_offset_s)?;
            let c = imu.clock;
            for (name, v) in [
                ("frequency_offset_ppm", c.frequency_offset_ppm),
                (
                    "frequency_random_walk_ppm_per_sqrt_s",
                    c.frequency_random_walk_ppm_per_sqrt_s,
                ),
                ("jitter_s", c.jitter_s),
            ] {
                finite(format!("{at}.clock.{name}"), v)?;
            }
            if c.frequency_offset_ppm.abs() >= 1e5
                || c.frequency_random_walk_ppm_per_sqrt_s < 0.0
                || c.jitter_s < 0.0
                || c.jitter_s * imu.rate_hz >= 0.1
            {
                return Err(bad(format!("{at}.clock"), "frequency offset must be below 1e5 ppm, random walk and jitter non-negative, jitter below a tenth of the sample interval".into()));
            }
            check_names(format!("{at}.disabled"), &imu.disabled)?;
            for key in imu.channels.keys() {
                if !crate::interchange::CHANNELS.contains(&key.as_str()) {
                    return Err(bad(
                        format!("{at}.channels.{key}"),
                        "unknown channel (expected gx gy gz ax ay az)".into(),
                    ));
                }
            }
            for i in 0..6 {
                let ch = imu.channel(i);
                let name = crate::interchange::CHANNELS[i];
                let f = |x: &str| format!("{at}.channels.{name}.{x}");
                check_names(f("disabled"), &ch.disabled)?;
                if let Some(spec) = &ch.stochastic {
                    let (_, angular) = unit_to_si(&spec.unit).ok_or_else(|| {
                        bad(
                            f("stochastic.unit"),
                            format!(
                                "unknown unit `{}` (rad/s, mrad/s, deg/s, deg/h, m/s2, g, mg, ug)",
                                spec.unit
                            ),
                        )
                    })?;
                    if angular != (i < 3) {
                        return Err(bad(
                            f("stochastic.unit"),
                            format!(
                                "`{}` does not fit a {} channel",
                                spec.unit,
                                if i < 3 { "gyro" } else { "accelerometer" }
                            ),
                        ));
                    }
                    spec.validate()
                        .map_err(|e| bad(f("stochastic"), e.to_string()))?;
                }
                for (x, v) in [
                    ("bias", ch.bias),
                    ("scale_factor", ch.scale_factor),
                    ("saturation", ch.saturation),
                    ("quantization_step", ch.quantization_step),
                ] {
                    if let Some(v) = v {
                        finite(f(x), v)?;
                    }
                }
                if let Some(s) = ch.saturation {
                    if s <= 0.0 {
                        return Err(bad(f("saturation"), format!("{s} must be positive")));
                    }
                }
                if let Some(q) = ch.quantization_step {
                    if q <= 0.0 {
                        return Err(bad(f("quantization_step"), format!("{q} must be positive")));
                    }
                }
                if let Some(row) = ch.cross_axis {
                    if row[i % 3] != 0.0 {
                        return Err(bad(f("cross_axis"), format!("entry {} is the channel's own axis and must be 0 (use scale_factor)", i % 3)));
                    }
                }
                for (x, v) in [
                    ("cross_axis", ch.cross_axis),
                    ("g_sensitivity", ch.g_sensitivity),
                    (
                        "angular_acceleration_sensitivity",
                        ch.angular_acceleration_sensitivity,
                    ),
                    ("jerk_sensitivity", ch.jerk_sensitivity),
                ] {
                    for e in v.iter().flatten() {
                        finite(f(x), *e)?;
                    }
                }
                if let Some(d) = ch.dynamic_noise {
                    if !(d.sigma_per_unit.is_finite() && d.sigma_per_unit >= 0.0) {
                        return Err(bad(
                            f("dynamic_noise.sigma_per_unit"),
                            format!("{} must be finite and non-negative", d.sigma_per_unit),
                        ));
                    }
                }
                for (j, b) in ch.bias_steps.iter().enumerate() {
                    if !(b.at_s.is_finite() && b.at_s >= 0.0 && b.size.is_finite()) {
                        return Err(bad(
                            f(&format!("bias_steps[{j}]")),
                            "at_s must be finite and non-negative, size finite".into(),
                        ));
                    }
                }
                for (j, l) in ch.vibration_lines.iter().enumerate() {
                    if !(l.frequency_hz.is_finite()
                        && l.frequency_hz >= 0.0
                        && l.amplitude.is_finite()
                        && l.phase_rad.is_finite())
                    {
                        return Err(bad(
                            f(&format!("vibration_lines[{j}]")),
                            "frequency must be finite and non-negative, amplitude and phase finite"
                                .into(),
                        ));
                    }
                }
                if let Some(o) = ch.outliers {
                    if !((0.0..=1.0).contains(&o.probability)
                        && o.sigma.is_finite()
                        && o.sigma >= 0.0)
                    {
                        return Err(bad(
                            f("outliers"),
                            "probability must be in [0, 1] and sigma finite and non-negative"
                                .into(),
                        ));
                    }
                }
            }
        }
        if let Some(g) = &self.gnss {
            if !(g.rate_hz.is_finite() && g.rate_hz > 0.0 && g.rate_hz <= 100.0) {
                return Err(bad(
                    "gnss.rate_hz".into(),
                    format!("{} must be in (0, 100] Hz", g.rate_hz),
                ));
            }
            check_names("gnss.disabled".into(), &g.disabled)?;
            for v in g
                .position_sigma_ned_m
                .iter()
                .chain(&g.velocity_sigma_ned_m_s)
            {
                if !(v.is_finite() && *v >= 0.0) {
                    return Err(bad(
                        "gnss".into(),
                        "noise sigmas must be finite and non-negative".into(),
                    ));
                }
            }
            if let Some(b) = g.position_bias {
                if !(b.tau_s.is_finite()
                    && b.tau_s > 0.0
                    && b.sigma_ned_m.iter().all(|s| s.is_finite() && *s >= 0.0))
                {
                    return Err(bad(
                        "gnss.position_bias".into(),
                        "tau_s must be positive, sigmas non-negative".into(),
                    ));
                }
            }
            for (j, o) in g.outages.iter().enumerate() {
                if !(o[0].is_finite() && o[1].is_finite() && o[1] > o[0]) {
                    return Err(bad(
                        format!("gnss.outages[{j}]"),
                        format!("[{}, {}] must be finite with end > start", o[0], o[1]),
                    ));
                }
            }
        }
        if let Some(p) = &self.pps {
            if !(p.jitter_s.is_finite()
                && p.jitter_s >= 0.0
                && p.capture_resolution_s.is_finite()
                && p.capture_resolution_s > 0.0)
            {
                return Err(bad(
                    "pps".into(),
                    "jitter_s must be non-negative and capture_resolution_s positive".into(),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bare_fitted_model_becomes_one_imu_with_that_model_on_its_gyros() {
        let text = r#"{"model": "WN+GM", "unit": "deg/s", "sample_rate_hz": 100,
            "processes": [{"kind": "white_noise", "sigma2": 0.5},
                          {"kind": "gauss_markov", "beta_per_s": 0.01, "sigma2": 0.001}]}"#;
        let m = SimModel::from_json(text, Path::new("fit.json")).unwrap();
        assert_eq!(m.imus.len(), 1);
        assert_eq!(m.imus[0].rate_hz, 100.0);
        assert!(m.imus[0].channel(2).stochastic.is_some());
        assert!(m.imus[0].channel(3).stochastic.is_none());
    }

    #[test]
    fn errors_name_the_file_and_field() {
        let p = Path::new("m.json");
        let msg = |t: &str| SimModel::from_json(t, p).unwrap_err().to_string();
        let e = msg(
            r#"{"imus": [{"name": "a", "rate_hz": 100, "channels": {"gx": {"cross_axis": [0.1, 0, 0]}}}]}"#,
        );
        assert!(
            e.contains("m.json") && e.contains("imus[0].channels.gx.cross_axis"),
            "{e}"
        );
        let e =
            msg(r#"{"imus": [{"name": "a", "rate_hz": 100, "gyro": {"disabled": ["noise"]}}]}"#);
        assert!(
            e.contains("imus[0].channels.gx.disabled") && e.contains("unknown effect `noise`"),
            "{e}"
        );
        let e = msg(
            r#"{"imus": [{"name": "a", "rate_hz": 100, "gyro": {"stochastic": {"model": "WN", "unit": "m/s2", "sample_rate_hz": 100, "processes": [{"kind": "white_noise", "sigma2": 1}]}}}]}"#,
        );
        assert!(e.contains("does not fit a gyro channel"), "{e}");
        let e = msg(r#"{"imus": [{"name": "a", "rate_hz": 100, "gyro": {"bias_typo": 1}}]}"#);
        assert!(e.contains("bias_typo") && e.contains("line 1"), "{e}");
        let e = msg(r#"{"gnss": {"rate_hz": 5, "outages": [[10, 5]]}}"#);
        assert!(e.contains("gnss.outages[0]"), "{e}");
        let e = msg(r#"{"imus": [{"name": "reference", "rate_hz": 100}]}"#);
        assert!(e.contains("imus[0].name"), "{e}");
    }

    #[test]
    fn units_convert_to_si() {
        assert_eq!(unit_to_si("deg/s").unwrap().0, std::f64::consts::PI / 180.0);
        assert_eq!(unit_to_si("m/s^2"), Some((1.0, false)));
        assert!(unit_to_si("furlong/fortnight").is_none());
    }
}
