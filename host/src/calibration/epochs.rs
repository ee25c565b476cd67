//! The common time base of a sensor and its reference, and both read over it.
//!
//! Each recording is turned into running integrals of its angular rate and specific force
//! (trapezoidal for rate samples), so interval means over any epoch grid are exact integrals
//! of what each sensor measured, whatever their sample rates. Against a reference IMU the
//! epochs are the sensor's own samples, with the smooth reference interpolated to them (8-point Lagrange);
//! against a navigation solution they are the solution's sample intervals, with the sensor
//! integrated over each. A time offset is applied by reading the reference (or the sensor's
//! integrals) at shifted times.

use dynacal_core::nav::{earth_rate_ned_rad_s, gravity_ned_m_s2, transport_rate_ned_rad_s};
use nalgebra::{Rotation3, UnitQuaternion, Vector3};

use super::{ErrorOptions, ErrorsError};
use crate::interchange::{ImuRecording, Triplet};
use crate::numeric::{central_difference_3, stencil_derivative};

/// Running trapezoidal integral of a sampled signal, evaluable at any time inside its span.
struct RunningIntegral<'a> {
    t_s: &'a [f64],
    x: &'a [f64],
    cumulative: Vec<f64>,
}

impl<'a> RunningIntegral<'a> {
    fn new(t_s: &'a [f64], x: &'a [f64]) -> Self {
        let mut cumulative = Vec::with_capacity(t_s.len());
        let mut acc = 0.0;
        cumulative.push(0.0);
        for i in 1..t_s.len() {
            acc += 0.5 * (x[i] + x[i - 1]) * (t_s[i] - t_s[i - 1]);
            cumulative.push(acc);
        }
        Self { t_s, x, cumulative }
    }

    /// Integral from the first sample to `t` (clamped to the recorded span).
    fn at(&self, t: f64) -> f64 {
        let n = self.t_s.len();
        if t <= self.t_s[0] {
            return 0.0;
        }
        if t >= self.t_s[n - 1] {
            return self.cumulative[n - 1];
        }
        let i = self.t_s.partition_point(|&s| s <= t) - 1;
        let dt = t - self.t_s[i];
        let slope = (self.x[i + 1] - self.x[i]) / (self.t_s[i + 1] - self.t_s[i]);
        let xt = self.x[i] + slope * dt;
        self.cumulative[i] + 0.5 * (self.x[i] + xt) * dt
    }

    fn mean(&self, a: f64, b: f64) -> f64 {
        (self.at(b) - self.at(a)) / (b - a)
    }
}

/// Interval means of a triplet over consecutive boundaries, each shifted by `shift_s`.
fn interval_means(
    integrals: &[RunningIntegral<'_>; 3],
    bounds: &[f64],
    shift_s: f64,
) -> Vec<Vector3<f64>> {
    bounds
        .windows(2)
        .map(|w| Vector3::from_fn(|i, _| integrals[i].mean(w[0] + shift_s, w[1] + shift_s)))
        .collect()
}

fn integrals<'a>(t_s: &'a [f64], triplet: &'a [Vec<f64>; 3]) -> [RunningIntegral<'a>; 3] {
    std::array::from_fn(|i| RunningIntegral::new(t_s, &triplet[i]))
}

/// Attitude C_b^n at time `t` by slerp between the recording's samples.
fn attitude_at(rec: &ImuRecording, att: &[Vec<f64>; 3], t: f64) -> UnitQuaternion<f64> {
    let n = rec.t_s.len();
    let q = |i: usize| UnitQuaternion::from_euler_angles(att[0][i], att[1][i], att[2][i]);
    if t <= rec.t_s[0] {
        return q(0);
    }
    if t >= rec.t_s[n - 1] {
        return q(n - 1);
    }
    let i = rec.t_s.partition_point(|&s| s <= t) - 1;
    let frac = (t - rec.t_s[i]) / (rec.t_s[i + 1] - rec.t_s[i]);
    q(i).slerp(&q(i + 1), frac)
}

fn lerp_at(t_s: &[f64], x: &[f64], t: f64) -> f64 {
    let n = t_s.len();
    if t <= t_s[0] {
        return x[0];
    }
    if t >= t_s[n - 1] {
        return x[n - 1];
    }
    let i = t_s.partition_point(|&s| s <= t) - 1;
    let frac = (t - t_s[i]) / (t_s[i + 1] - t_s[i]);
    x[i] + frac * (x[i + 1] - x[i])
}

/// Points of [`lagrange_at`]: an 8-point (7th-degree) Lagrange interpolation.
const LAGRANGE_POINTS: usize = 8;

/// Lagrange interpolation of `x` sampled at `t_s` (increasing) on the [`LAGRANGE_POINTS`]
/// samples around `t`, linear where the series has too few samples on one side. Linear
/// interpolation of a reference IMU is not good enough once the epochs fall between its
/// samples: at 200 Hz it loses 8% of a 26 Hz vibration at mid-interval, which then shows in
/// the error as a false scale factor; a cubic loses about 1%, which with a time offset of
/// 5-20 ms (every epoch between reference samples) leaves a 1-2 mm/s^2 line of a car's
/// vertical vibration in the error that the diagnosis names; eight points lose about 0.02%.
fn lagrange_at(t_s: &[f64], x: &[f64], t: f64) -> f64 {
    let n = t_s.len();
    let half = LAGRANGE_POINTS / 2;
    if n < LAGRANGE_POINTS || t <= t_s[half - 1] || t >= t_s[n - half] {
        return lerp_at(t_s, x, t);
    }
    let i = t_s.partition_point(|&s| s <= t) - 1;
    let idx = i + 1 - half..i + 1 + half;
    let mut value = 0.0;
    for ia in idx.clone() {
        let mut w = 1.0;
        for ib in idx.clone() {
            if ia != ib {
                w *= (t - t_s[ib]) / (t_s[ia] - t_s[ib]);
            }
        }
        value += w * x[ia];
    }
    value
}

/// The reference over the epochs: mean body rate and specific force, attitude and gravity at
/// mid-epoch.
#[derive(Debug, Clone)]
pub(super) struct ReferenceEpochs {
    /// Angular rate of the body w.r.t. inertial space, body frame, rad/s.
    pub omega_ib_b_rad_s: Vec<Vector3<f64>>,
    /// Specific force, body frame, m/s^2.
    pub f_b_m_s2: Vec<Vector3<f64>>,
    /// Attitude C_b^n at mid-epoch.
    pub q_nb_mid: Vec<UnitQuaternion<f64>>,
    /// Gravity at mid-epoch, NED, m/s^2.
    pub g_ned_mid_m_s2: Vec<Vector3<f64>>,
}

fn reference_at_points(
    rec: &ImuRecording,
    gyro: &[Vec<f64>; 3],
    accel: &[Vec<f64>; 3],
    times_s: &[f64],
) -> Result<ReferenceEpochs, ErrorsError> {
    let att = rec
        .attitude_rad
        .as_ref()
        .ok_or(ErrorsError::ReferenceIncomplete(
            "roll_rad, pitch_rad, yaw_rad columns to express gravity in the body frame",
        ))?;
    let at = |t: f64, x: &[Vec<f64>; 3]| Vector3::from_fn(|i, _| lagrange_at(&rec.t_s, &x[i], t));
    Ok(ReferenceEpochs {
        omega_ib_b_rad_s: times_s.iter().map(|&t| at(t, gyro)).collect(),
        f_b_m_s2: times_s.iter().map(|&t| at(t, accel)).collect(),
        q_nb_mid: times_s.iter().map(|&t| attitude_at(rec, att, t)).collect(),
        g_ned_mid_m_s2: times_s
            .iter()
            .map(|&t| match &rec.position {
                Some(p) => {
                    gravity_ned_m_s2(lerp_at(&rec.t_s, &p[0], t), lerp_at(&rec.t_s, &p[2], t))
                }
                None => gravity_ned_m_s2(0.0, 0.0),
            })
            .collect(),
    })
}

/// Reference rates and specific force derived from a navigation solution sampled at the
/// epoch boundaries (the boundaries are the solution's own sample times).
fn reference_from_solution(
    rec: &ImuRecording,
    bounds_idx: &[usize],
) -> Result<ReferenceEpochs, ErrorsError> {
    let att = rec
        .attitude_rad
        .as_ref()
        .ok_or(ErrorsError::ReferenceIncomplete(
            "either rate and specific-force columns, or attitude (roll_rad, pitch_rad, yaw_rad)",
        ))?;
    let vel = rec
        .velocity_ned_m_s
        .as_ref()
        .ok_or(ErrorsError::ReferenceIncomplete(
            "vn_m_s, ve_m_s, vd_m_s columns to derive specific force from a navigation solution",
        ))?;
    let pos = rec
        .position
        .as_ref()
        .ok_or(ErrorsError::ReferenceIncomplete(
            "lat_rad, lon_rad, h_m columns to derive Earth and transport rate",
        ))?;
    let q = |i: usize| UnitQuaternion::from_euler_angles(att[0][i], att[1][i], att[2][i]);
    let v = |i: usize| Vector3::new(vel[0][i], vel[1][i], vel[2][i]);
    let n = bounds_idx.len() - 1;
    let mut out = ReferenceEpochs {
        omega_ib_b_rad_s: Vec::with_capacity(n),
        f_b_m_s2: Vec::with_capacity(n),
        q_nb_mid: Vec::with_capacity(n),
        g_ned_mid_m_s2: Vec::with_capacity(n),
    };
    for w in bounds_idx.windows(2) {
        let (a, b) = (w[0], w[1]);
        let dt = rec.t_s[b] - rec.t_s[a];
        let (qa, qb) = (q(a), q(b));
        // Body rotation over the epoch, in the body frame at its start: C_b(a)^T C_b(b).
        let omega_nb_b = (qa.inverse() * qb).scaled_axis() / dt;
        let q_mid = qa.slerp(&qb, 0.5);
        let lat = 0.5 * (pos[0][a] + pos[0][b]);
        let h = 0.5 * (pos[2][a] + pos[2][b]);
        let v_mid = 0.5 * (v(a) + v(b));
        let w_ie = earth_rate_ned_rad_s(lat);
        let w_en = transport_rate_ned_rad_s(lat, h, &v_mid);
        let c_bn_mid = q_mid.to_rotation_matrix();
        let omega_ib_b = omega_nb_b + c_bn_mid.inverse() * (w_ie + w_en);
        let g = gravity_ned_m_s2(lat, h);
        // v_dot = C_b^n f - (2 w_ie + w_en) x v + g
        let f_ned = (v(b) - v(a)) / dt + (2.0 * w_ie + w_en).cross(&v_mid) - g;
        out.omega_ib_b_rad_s.push(omega_ib_b);
        out.f_b_m_s2.push(c_bn_mid.inverse() * f_ned);
        out.q_nb_mid.push(q_mid);
        out.g_ned_mid_m_s2.push(g);
    }
    Ok(out)
}

/// [`stencil_derivative`] of each axis of a triplet.
fn native_derivative(t_s: &[f64], x: &[Vec<f64>; 3]) -> [Vec<f64>; 3] {
    std::array::from_fn(|i| stencil_derivative(t_s, &x[i]))
}

/// Shortest overlap of the two recordings, s.
const MIN_OVERLAP_S: f64 = 1.0;
/// Fewest epochs a calibration is attempted on.
const MIN_EPOCHS: usize = 10;

/// The span both recordings cover, less the largest time offset searched at either end, s.
fn overlap_s(
    sensor: &ImuRecording,
    reference: &ImuRecording,
    opts: &ErrorOptions,
) -> Result<(f64, f64), ErrorsError> {
    let margin = if opts.estimate_time_offset {
        opts.max_time_offset_s
    } else {
        0.0
    };
    let start = sensor.t_s[0].max(reference.t_s[0]) + margin;
    let end = sensor.t_s[sensor.len() - 1].min(reference.t_s[reference.len() - 1]) - margin;
    if !(end - start >= MIN_OVERLAP_S) {
        return Err(no_overlap(sensor, reference, (end - start).max(0.0)));
    }
    Ok((start, end))
}

fn no_overlap(sensor: &ImuRecording, reference: &ImuRecording, overlap_s: f64) -> ErrorsError {
    let span = |r: &ImuRecording| [r.t_s[0], r.t_s[r.len() - 1]];
    ErrorsError::NoOverlap {
        overlap_s,
        needed_s: MIN_OVERLAP_S,
        sensor_s: span(sensor),
        reference_s: span(reference),
    }
}

/// The samples of `t_s` inside `[start, end]`: their times and indices.
fn samples_within(t_s: &[f64], start: f64, end: f64) -> (Vec<f64>, Vec<usize>) {
    t_s.iter()
        .enumerate()
        .filter(|(_, &t)| t >= start && t <= end)
        .map(|(i, &t)| (t, i))
        .unzip()
}

/// How the reference and the sensor are read over the epochs.
// One per calibration: boxing the larger variant would gain nothing.
#[allow(clippy::large_enum_variant)]
enum EpochKind<'a> {
    /// A reference IMU: the epochs are the sensor's own samples, untouched (so its noise
    /// reaches the error signal unfiltered and a fitted model can be simulated directly),
    /// with the smooth reference interpolated to them.
    ReferenceImu {
        /// Sensor sample of each epoch.
        sensor_idx: Vec<usize>,
        gyro_rad_s: &'a Triplet,
        accel_m_s2: &'a Triplet,
        /// Derivatives of the reference at its own rate (nine-point stencils), interpolated
        /// to the epochs like the rates themselves.
        omega_dot_rad_s2: Triplet,
        f_dot_m_s3: Triplet,
    },
    /// A navigation solution: the epochs are its sample intervals, with the sensor
    /// integrated over each.
    NavigationSolution {
        /// Epoch boundaries (the solution's sample times), s.
        bounds_s: Vec<f64>,
        /// The reference over the epochs (independent of the time offset).
        reference: ReferenceEpochs,
        gyro: Option<[RunningIntegral<'a>; 3]>,
        accel: Option<[RunningIntegral<'a>; 3]>,
    },
}

/// A sensor and its reference on one epoch grid, readable at any time offset.
pub(super) struct EpochSource<'a> {
    sensor: &'a ImuRecording,
    reference: &'a ImuRecording,
    /// Epoch times (mid-epoch), s.
    pub t_s: Vec<f64>,
    kind: EpochKind<'a>,
}

/// Reference and sensor over the epochs at one time offset.
pub(super) struct EpochData {
    pub reference: ReferenceEpochs,
    /// Angular acceleration of the reference, body frame, rad/s^2.
    pub omega_dot_b_rad_s2: Vec<Vector3<f64>>,
    /// Rate of change of the reference's specific force, body frame, m/s^3.
    pub f_dot_b_m_s3: Vec<Vector3<f64>>,
    /// The sensor's angular rate, rad/s, when it has gyros.
    pub gyro_rad_s: Option<Vec<Vector3<f64>>>,
    /// The sensor's specific force, m/s^2, when it has accelerometers.
    pub accel_m_s2: Option<Vec<Vector3<f64>>>,
}

impl EpochData {
    /// The same epochs with the sensor rotated by `r_sb` (sensor to reference body frame).
    pub(super) fn rotated(self, r_sb: &Rotation3<f64>) -> EpochData {
        // In place: a copy would hold both for a moment, six series of the drive's length.
        let rotate = |v: Option<Vec<Vector3<f64>>>| {
            v.map(|mut v| {
                v.iter_mut().for_each(|x| *x = r_sb * *x);
                v
            })
        };
        EpochData {
            gyro_rad_s: rotate(self.gyro_rad_s),
            accel_m_s2: rotate(self.accel_m_s2),
            ..self
        }
    }

    /// Number of epochs.
    pub(super) fn len(&self) -> usize {
        self.reference.omega_ib_b_rad_s.len()
    }
}

impl<'a> EpochSource<'a> {
    /// The epoch grid over the overlap of `sensor` and `reference` (less the time-offset
    /// margin), and what is needed to read both over it.
    pub(super) fn new(
        sensor: &'a ImuRecording,
        reference: &'a ImuRecording,
        opts: &ErrorOptions,
    ) -> Result<Self, ErrorsError> {
        let (start, end) = overlap_s(sensor, reference, opts)?;
        let too_few = |t_s: &[f64]| {
            if t_s.len() < MIN_EPOCHS {
                Err(no_overlap(sensor, reference, end - start))
            } else {
                Ok(())
            }
        };
        let (t_s, kind) = match (&reference.gyro_rad_s, &reference.accel_m_s2) {
            (Some(gyro_rad_s), Some(accel_m_s2)) => {
                let (t_s, sensor_idx) = samples_within(&sensor.t_s, start, end);
                too_few(&t_s)?;
                let kind = EpochKind::ReferenceImu {
                    sensor_idx,
                    gyro_rad_s,
                    accel_m_s2,
                    omega_dot_rad_s2: native_derivative(&reference.t_s, gyro_rad_s),
                    f_dot_m_s3: native_derivative(&reference.t_s, accel_m_s2),
                };
                (t_s, kind)
            }
            _ => {
                let (bounds_s, bounds_idx) = samples_within(&reference.t_s, start, end);
                let t_s: Vec<f64> = bounds_s.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
                too_few(&t_s)?;
                let kind = EpochKind::NavigationSolution {
                    reference: reference_from_solution(reference, &bounds_idx)?,
                    bounds_s,
                    gyro: sensor
                        .gyro_rad_s
                        .as_ref()
                        .map(|g| integrals(&sensor.t_s, g)),
                    accel: sensor
                        .accel_m_s2
                        .as_ref()
                        .map(|a| integrals(&sensor.t_s, a)),
                };
                (t_s, kind)
            }
        };
        Ok(Self {
            sensor,
            reference,
            t_s,
            kind,
        })
    }

    /// Whether the reference is an IMU (else a navigation solution).
    pub(super) fn reference_is_imu(&self) -> bool {
        matches!(self.kind, EpochKind::ReferenceImu { .. })
    }

    /// Whether the sensor has gyros.
    pub(super) fn has_gyro(&self) -> bool {
        self.sensor.gyro_rad_s.is_some()
    }

    /// Whether the sensor has accelerometers.
    pub(super) fn has_accel(&self) -> bool {
        self.sensor.accel_m_s2.is_some()
    }

    /// Reference and sensor over the epochs for a time offset `shift_s` (positive: the
    /// sensor lags, so its epoch k shows the truth at epoch time - shift).
    pub(super) fn at(&self, shift_s: f64) -> Result<EpochData, ErrorsError> {
        match &self.kind {
            EpochKind::ReferenceImu {
                sensor_idx,
                gyro_rad_s,
                accel_m_s2,
                omega_dot_rad_s2,
                f_dot_m_s3,
            } => {
                let shifted: Vec<f64> = self.t_s.iter().map(|t| t - shift_s).collect();
                let reference =
                    reference_at_points(self.reference, gyro_rad_s, accel_m_s2, &shifted)?;
                let raw_at = |x: &Triplet| -> Vec<Vector3<f64>> {
                    sensor_idx
                        .iter()
                        .map(|&i| Vector3::new(x[0][i], x[1][i], x[2][i]))
                        .collect()
                };
                let interpolated = |x: &Triplet| -> Vec<Vector3<f64>> {
                    self.t_s
                        .iter()
                        .map(|&t| {
                            Vector3::from_fn(|i, _| {
                                lagrange_at(&self.reference.t_s, &x[i], t - shift_s)
                            })
                        })
                        .collect()
                };
                Ok(EpochData {
                    reference,
                    omega_dot_b_rad_s2: interpolated(omega_dot_rad_s2),
                    f_dot_b_m_s3: interpolated(f_dot_m_s3),
                    gyro_rad_s: self.sensor.gyro_rad_s.as_ref().map(raw_at),
                    accel_m_s2: self.sensor.accel_m_s2.as_ref().map(raw_at),
                })
            }
            EpochKind::NavigationSolution {
                bounds_s,
                reference,
                gyro,
                accel,
            } => Ok(EpochData {
                omega_dot_b_rad_s2: central_difference_3(&self.t_s, &reference.omega_ib_b_rad_s),
                f_dot_b_m_s3: central_difference_3(&self.t_s, &reference.f_b_m_s2),
                reference: reference.clone(),
                gyro_rad_s: gyro.as_ref().map(|g| interval_means(g, bounds_s, shift_s)),
                accel_m_s2: accel.as_ref().map(|a| interval_means(a, bounds_s, shift_s)),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lagrange_interpolation_keeps_a_vibration_between_samples() {
        // 26 Hz sampled at 200 Hz, read back at mid-interval.
        let t_s: Vec<f64> = (0..400).map(|k| k as f64 * 0.005).collect();
        let w = 2.0 * std::f64::consts::PI * 26.0;
        let x: Vec<f64> = t_s.iter().map(|t| (w * t).sin()).collect();
        let worst = |f: &dyn Fn(f64) -> f64| {
            (10..390)
                .map(|k| {
                    let t = (k as f64 + 0.5) * 0.005;
                    (f(t) - (w * t).sin()).abs()
                })
                .fold(0.0f64, f64::max)
        };
        let lagrange = worst(&|t| lagrange_at(&t_s, &x, t));
        let linear = worst(&|t| lerp_at(&t_s, &x, t));
        assert!(linear > 0.07, "{linear}");
        assert!(lagrange < 5e-4, "{lagrange}");
    }

    #[test]
    fn running_integral_means_are_exact_for_linear_signals() {
        let t: Vec<f64> = (0..50)
            .map(|i| i as f64 * 0.013 + 0.001 * (i % 3) as f64)
            .collect();
        let x: Vec<f64> = t.iter().map(|t| 2.0 + 3.0 * t).collect();
        let r = RunningIntegral::new(&t, &x);
        let (a, b) = (0.1234, 0.4567);
        let exact = 2.0 + 3.0 * 0.5 * (a + b);
        assert!((r.mean(a, b) - exact).abs() < 1e-12);
    }
}
