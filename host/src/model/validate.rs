//! Range and name checks of a model file, after serde has checked its shape: every error
//! names the file and the field (`imus[1].channels.gx.bias`).

use std::collections::BTreeSet;
use std::path::Path;

use super::file::{ModelFileError, SimModel, MODEL_FILE_VERSION};
use super::gnss::{GnssModel, PpsModel};
use super::imu::{ChannelModel, ClockModel, ImuModel};
use super::units::unit_to_si;
use super::Channel;

/// Names that are output file stems of the simulator and so cannot name an IMU.
const RESERVED_IMU_NAMES: [&str; 3] = ["gnss", "pps", "truth"];

/// The checks of one file: builds errors that name it.
struct Checker<'a> {
    path: &'a Path,
}

type Checked = Result<(), ModelFileError>;

impl Checker<'_> {
    fn bad(&self, field: String, message: String) -> ModelFileError {
        ModelFileError::Invalid {
            path: self.path.to_path_buf(),
            field,
            message,
        }
    }

    fn finite(&self, field: String, v: f64) -> Checked {
        if v.is_finite() {
            Ok(())
        } else {
            Err(self.bad(field, format!("{v} is not a finite number")))
        }
    }

    fn require(&self, ok: bool, field: String, message: impl Into<String>) -> Checked {
        if ok {
            Ok(())
        } else {
            Err(self.bad(field, message.into()))
        }
    }
}

impl SimModel {
    /// Checks ranges and names; errors name the field (e.g. `imus[1].channels.gx.bias`).
    pub fn validate(&self, path: &Path) -> Result<(), ModelFileError> {
        let check = Checker { path };
        check.require(
            (1..=MODEL_FILE_VERSION).contains(&self.version),
            "version".into(),
            format!(
                "version {} is not one this dynacal reads (1 to {MODEL_FILE_VERSION})",
                self.version
            ),
        )?;
        check.require(
            self.imus.len() <= 3,
            "imus".into(),
            format!("{} IMUs given, at most 3 are supported", self.imus.len()),
        )?;
        let mut names = BTreeSet::new();
        for (k, imu) in std::iter::once(&self.reference)
            .chain(&self.imus)
            .enumerate()
        {
            let at = match k {
                0 => "reference".to_string(),
                _ => format!("imus[{}]", k - 1),
            };
            check.require(
                !RESERVED_IMU_NAMES.contains(&imu.name.as_str()) && names.insert(&imu.name),
                format!("{at}.name"),
                format!("`{}` is reserved or used twice", imu.name),
            )?;
            validate_imu(&check, &at, imu, k == 0)?;
        }
        if let Some(g) = &self.gnss {
            validate_gnss(&check, g)?;
        }
        if let Some(p) = &self.pps {
            validate_pps(&check, p)?;
        }
        Ok(())
    }
}

fn validate_imu(check: &Checker, at: &str, imu: &ImuModel, is_reference: bool) -> Checked {
    let name_ok = !imu.name.is_empty()
        && imu
            .name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    check.require(
        name_ok,
        format!("{at}.name"),
        format!("`{}` must be non-empty letters, digits, - or _", imu.name),
    )?;
    check.require(
        imu.rate_hz.is_finite() && imu.rate_hz > 0.0 && imu.rate_hz <= 100_000.0,
        format!("{at}.rate_hz"),
        format!("{} must be in (0, 100000] Hz", imu.rate_hz),
    )?;
    let mounted_at_reference = imu.lever_arm_b_m == [0.0; 3]
        && imu.boresight_rpy_deg == [0.0; 3]
        && imu.time_offset_s == 0.0
        && imu.clock == ClockModel::default();
    check.require(
        !is_reference || mounted_at_reference,
        at.to_string(),
        "the reference IMU defines the body frame and GPS time: its lever arm, boresight, \
         time offset and clock must be zero",
    )?;
    for v in imu.lever_arm_b_m {
        check.finite(format!("{at}.lever_arm_b_m"), v)?;
    }
    for v in imu.boresight_rpy_deg {
        check.finite(format!("{at}.boresight_rpy_deg"), v)?;
    }
    check.finite(format!("{at}.time_offset_s"), imu.time_offset_s)?;
    validate_clock(check, at, &imu.clock, imu.rate_hz)?;
    for channel in Channel::ALL {
        let field = |x: &str| format!("{at}.channels.{channel}.{x}");
        validate_channel(check, &field, channel, imu.model_of(channel))?;
    }
    Ok(())
}

fn validate_clock(check: &Checker, at: &str, c: &ClockModel, rate_hz: f64) -> Checked {
    for (name, v) in [
        ("frequency_offset_ppm", c.frequency_offset_ppm),
        (
            "frequency_random_walk_ppm_per_sqrt_s",
            c.frequency_random_walk_ppm_per_sqrt_s,
        ),
        ("jitter_s", c.jitter_s),
    ] {
        check.finite(format!("{at}.clock.{name}"), v)?;
    }
    check.require(
        c.frequency_offset_ppm.abs() < 1e5
            && c.frequency_random_walk_ppm_per_sqrt_s >= 0.0
            && c.jitter_s >= 0.0
            && c.jitter_s * rate_hz < 0.1,
        format!("{at}.clock"),
        "frequency offset must be below 1e5 ppm, random walk and jitter non-negative, jitter \
         below a tenth of the sample interval",
    )
}

fn validate_stochastic(
    check: &Checker,
    field: &dyn Fn(&str) -> String,
    channel: Channel,
    spec: &crate::gmwm::model::ModelSpec,
) -> Checked {
    let (_, angular) = unit_to_si(&spec.unit).ok_or_else(|| {
        check.bad(
            field("stochastic.unit"),
            format!(
                "unknown unit `{}` (rad/s, mrad/s, deg/s, deg/h, m/s2, g, mg, ug)",
                spec.unit
            ),
        )
    })?;
    check.require(
        angular == channel.is_gyro(),
        field("stochastic.unit"),
        format!(
            "`{}` does not fit a{} channel",
            spec.unit,
            if channel.is_gyro() {
                " gyro"
            } else {
                "n accelerometer"
            }
        ),
    )?;
    spec.validate()
        .map_err(|e| check.bad(field("stochastic"), e.to_string()))
}

fn validate_channel(
    check: &Checker,
    field: &dyn Fn(&str) -> String,
    channel: Channel,
    ch: &ChannelModel,
) -> Checked {
    if let Some(spec) = &ch.stochastic {
        validate_stochastic(check, field, channel, spec)?;
    }
    for (x, v) in [
        ("bias", ch.bias),
        ("scale_factor", ch.scale_factor),
        ("saturation", ch.saturation),
        ("quantization_step", ch.quantization_step),
    ] {
        if let Some(v) = v {
            check.finite(field(x), v)?;
        }
    }
    if let Some(s) = ch.saturation {
        check.require(
            s > 0.0,
            field("saturation"),
            format!("{s} must be positive"),
        )?;
    }
    if let Some(q) = ch.quantization_step {
        check.require(
            q > 0.0,
            field("quantization_step"),
            format!("{q} must be positive"),
        )?;
    }
    if let Some(row) = ch.cross_axis {
        check.require(
            row[channel.axis()] == 0.0,
            field("cross_axis"),
            format!(
                "entry {} is the channel's own axis and must be 0 (use scale_factor)",
                channel.axis()
            ),
        )?;
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
            check.finite(field(x), *e)?;
        }
    }
    validate_random_effects(check, field, ch)
}

/// The effects that add a process or an event to the channel: noise following the
/// dynamics, bias steps, vibration lines and outliers.
fn validate_random_effects(
    check: &Checker,
    field: &dyn Fn(&str) -> String,
    ch: &ChannelModel,
) -> Checked {
    if let Some(d) = ch.dynamic_noise {
        check.require(
            d.sigma_per_unit.is_finite() && d.sigma_per_unit >= 0.0,
            field("dynamic_noise.sigma_per_unit"),
            format!("{} must be finite and non-negative", d.sigma_per_unit),
        )?;
    }
    for (j, b) in ch.bias_steps.iter().enumerate() {
        check.require(
            b.at_s.is_finite() && b.at_s >= 0.0 && b.size.is_finite(),
            field(&format!("bias_steps[{j}]")),
            "at_s must be finite and non-negative, size finite",
        )?;
    }
    for (j, l) in ch.vibration_lines.iter().enumerate() {
        check.require(
            l.frequency_hz.is_finite()
                && l.frequency_hz >= 0.0
                && l.amplitude.is_finite()
                && l.phase_rad.is_finite(),
            field(&format!("vibration_lines[{j}]")),
            "frequency must be finite and non-negative, amplitude and phase finite",
        )?;
    }
    if let Some(o) = ch.outliers {
        check.require(
            (0.0..=1.0).contains(&o.probability) && o.sigma.is_finite() && o.sigma >= 0.0,
            field("outliers"),
            "probability must be in [0, 1] and sigma finite and non-negative",
        )?;
    }
    Ok(())
}

fn validate_gnss(check: &Checker, g: &GnssModel) -> Checked {
    check.require(
        g.rate_hz.is_finite() && g.rate_hz > 0.0 && g.rate_hz <= 100.0,
        "gnss.rate_hz".into(),
        format!("{} must be in (0, 100] Hz", g.rate_hz),
    )?;
    check.require(
        g.position_sigma_ned_m
            .iter()
            .chain(&g.velocity_sigma_ned_m_s)
            .all(|v| v.is_finite() && *v >= 0.0),
        "gnss".into(),
        "noise sigmas must be finite and non-negative",
    )?;
    if let Some(b) = g.position_bias {
        check.require(
            b.tau_s.is_finite()
                && b.tau_s > 0.0
                && b.sigma_ned_m.iter().all(|s| s.is_finite() && *s >= 0.0),
            "gnss.position_bias".into(),
            "tau_s must be positive, sigmas non-negative",
        )?;
    }
    for (j, o) in g.outages.iter().enumerate() {
        check.require(
            o[0].is_finite() && o[1].is_finite() && o[1] > o[0],
            format!("gnss.outages[{j}]"),
            format!("[{}, {}] must be finite with end > start", o[0], o[1]),
        )?;
    }
    Ok(())
}

fn validate_pps(check: &Checker, p: &PpsModel) -> Checked {
    check.require(
        p.jitter_s.is_finite()
            && p.jitter_s >= 0.0
            && p.capture_resolution_s.is_finite()
            && p.capture_resolution_s > 0.0,
        "pps".into(),
        "jitter_s must be non-negative and capture_resolution_s positive",
    )
}
