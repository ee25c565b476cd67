//! The common time base of a sensor and its reference, and both read over it.
//!
//! Each recording is turned into running integrals of its angular rate and specific force
//! (trapezoidal for rate samples), so interval means over any epoch grid are exact integrals
//! of what each sensor measured, whatever their sample rates. Against a reference IMU the
//! epochs are the sensor's own samples, with the smooth reference interpolated to them (8-point Lagrange);
//! against a navigation solution they are the solution's sample intervals, with the sensor
//! integrated over each. A time offset is applied by reading the reference (or the sensor's
//! integrals) at shifted times.
//!
//! The grid ([`EpochGrid`]) is found over the whole overlap; the epochs are formed a block
//! at a time ([`EpochGrid::block`], [`EpochSource`]), each block reading its samples plus
//! those its interpolation and derivative stencils reach and the largest time offset
//! searched, and [`APRON_EPOCHS`] epochs either side for the dynamics' differences, so a
//! block's own epochs are those of the whole grid formed at once.

use dynacal_core::nav::{earth_rate_ned_rad_s, gravity_ned_m_s2, transport_rate_ned_rad_s};
use nalgebra::{Rotation3, UnitQuaternion, Vector3};

use std::borrow::Cow;
use std::ops::Range;

use super::recordings::Samples;
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

/// Points of [`Interpolant::new`]: an 8-point (7th-degree) Lagrange interpolation.
const LAGRANGE_POINTS: usize = 8;

/// How a series sampled at given times is read at one time: the weights of the
/// [`LAGRANGE_POINTS`] samples around it, or linear between two where the series has too few
/// samples on one side (held at the ends). Found once per time and applied to every series
/// of the recording, which is most of the cost of forming the epochs.
enum Interpolant {
    Lagrange {
        first: usize,
        weights: [f64; LAGRANGE_POINTS],
    },
    Linear {
        i: usize,
        frac: f64,
    },
    Sample(usize),
}

impl Interpolant {
    /// Lagrange interpolation at `t` of a series sampled at `t_s` (increasing). Linear
    /// interpolation of a reference IMU is not good enough once the epochs fall between its
    /// samples: at 200 Hz it loses 8% of a 26 Hz vibration at mid-interval, which then shows
    /// in the error as a false scale factor; a cubic loses about 1%, which with a time
    /// offset of 5-20 ms (every epoch between reference samples) leaves a 1-2 mm/s^2 line of
    /// a car's vertical vibration in the error that the diagnosis names; eight points lose
    /// about 0.02%.
    fn new(t_s: &[f64], t: f64) -> Self {
        let n = t_s.len();
        let half = LAGRANGE_POINTS / 2;
        if n < LAGRANGE_POINTS || t <= t_s[half - 1] || t >= t_s[n - half] {
            return Self::linear(t_s, t);
        }
        let first = t_s.partition_point(|&s| s <= t) - half;
        let points = first..first + LAGRANGE_POINTS;
        let mut weights = [0.0; LAGRANGE_POINTS];
        for (w, ia) in weights.iter_mut().zip(points.clone()) {
            *w = 1.0;
            for ib in points.clone() {
                if ia != ib {
                    *w *= (t - t_s[ib]) / (t_s[ia] - t_s[ib]);
                }
            }
        }
        Self::Lagrange { first, weights }
    }

    /// Linear interpolation at `t`, held at the ends.
    fn linear(t_s: &[f64], t: f64) -> Self {
        let n = t_s.len();
        if t <= t_s[0] {
            return Self::Sample(0);
        }
        if t >= t_s[n - 1] {
            return Self::Sample(n - 1);
        }
        let i = t_s.partition_point(|&s| s <= t) - 1;
        let frac = (t - t_s[i]) / (t_s[i + 1] - t_s[i]);
        Self::Linear { i, frac }
    }

    /// The series `x` at the interpolant's time.
    fn read(&self, x: &[f64]) -> f64 {
        match *self {
            Self::Lagrange { first, weights } => {
                let mut value = 0.0;
                for (w, x) in weights.iter().zip(&x[first..]) {
                    value += w * x;
                }
                value
            }
            Self::Linear { i, frac } => x[i] + frac * (x[i + 1] - x[i]),
            Self::Sample(i) => x[i],
        }
    }

    fn read_triplet(&self, x: &Triplet) -> Vector3<f64> {
        Vector3::new(self.read(&x[0]), self.read(&x[1]), self.read(&x[2]))
    }
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

/// A reference's angular acceleration (rad/s^2) and rate of change of specific force (m/s^3)
/// over the epochs.
type Derivatives = [Vec<Vector3<f64>>; 2];

/// A reference IMU (rates, specific force and their derivatives at its own rate) read at
/// `times_s`: the reference over the epochs, with its angular acceleration (rad/s^2) and
/// rate of change of specific force (m/s^3) there.
fn reference_at_points(
    rec: &ImuRecording,
    [gyro, accel, omega_dot, f_dot]: [&Triplet; 4],
    times_s: impl ExactSizeIterator<Item = f64>,
) -> Result<(ReferenceEpochs, Derivatives), ErrorsError> {
    let att = rec
        .attitude_rad
        .as_ref()
        .ok_or(ErrorsError::ReferenceIncomplete(
            "roll_rad, pitch_rad, yaw_rad columns to express gravity in the body frame",
        ))?;
    let n = times_s.len();
    let mut out = ReferenceEpochs {
        omega_ib_b_rad_s: Vec::with_capacity(n),
        f_b_m_s2: Vec::with_capacity(n),
        q_nb_mid: Vec::with_capacity(n),
        g_ned_mid_m_s2: Vec::with_capacity(n),
    };
    let mut derivatives = [Vec::with_capacity(n), Vec::with_capacity(n)];
    for t in times_s {
        let at = Interpolant::new(&rec.t_s, t);
        out.omega_ib_b_rad_s.push(at.read_triplet(gyro));
        out.f_b_m_s2.push(at.read_triplet(accel));
        derivatives[0].push(at.read_triplet(omega_dot));
        derivatives[1].push(at.read_triplet(f_dot));
        out.q_nb_mid.push(attitude_at(rec, att, t));
        out.g_ned_mid_m_s2.push(match &rec.position {
            Some(p) => {
                let linear = Interpolant::linear(&rec.t_s, t);
                gravity_ned_m_s2(linear.read(&p[0]), linear.read(&p[2]))
            }
            None => gravity_ned_m_s2(0.0, 0.0),
        });
    }
    Ok((out, derivatives))
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
/// Epochs a block reads beyond its own at either end: the dynamics' central differences
/// over epochs reach two epochs out (a derivative of a derivative).
const APRON_EPOCHS: usize = 2;
/// Samples a block reads beyond its span at either end: an interpolation's eight points
/// of a nine-point derivative reach eight samples out.
const APRON_SAMPLES: usize = 16;

/// First and last time of a recording, s.
fn span_s(r: &dyn Samples) -> Result<[f64; 2], ErrorsError> {
    Ok([r.time_s(0)?, r.time_s(r.len() - 1)?])
}

/// How the epochs are made over the whole overlap.
#[derive(Debug, Clone, Copy)]
enum GridKind {
    /// Against a reference IMU: the epochs are sensor samples `first ..`.
    ReferenceImu { first_sensor: usize },
    /// Against a navigation solution: the intervals between reference samples `first ..`.
    NavigationSolution { first_bound: usize },
}

/// The epochs of a sensor and its reference over their overlap (less the time-offset
/// margin): which samples make them, read a block at a time ([`EpochGrid::block`]).
pub(super) struct EpochGrid {
    kind: GridKind,
    /// Number of epochs.
    pub epochs: usize,
    /// Largest time offset applied, s: a block reads the other recording this far beyond it.
    margin_s: f64,
    /// The sensor's triplets (gyro, accelerometer, ...), as [`Samples::triplets`].
    sensor_triplets: [bool; 5],
}

/// The samples of a block of epochs, and which of their epochs are the block's own.
pub(super) struct BlockSamples<'a> {
    sensor: Cow<'a, ImuRecording>,
    reference: Cow<'a, ImuRecording>,
    /// The epochs read (the block's and its aprons), as sensor rows or reference bounds
    /// of the recordings above.
    local: Range<usize>,
    kind: GridKind,
    /// The block's own epochs among those read.
    pub own: Range<usize>,
}

impl EpochGrid {
    /// The epoch grid over the overlap of `sensor` and `reference` (less the time-offset
    /// margin).
    pub(super) fn new(
        sensor: &dyn Samples,
        reference: &dyn Samples,
        opts: &ErrorOptions,
    ) -> Result<Self, ErrorsError> {
        let spans = [span_s(sensor)?, span_s(reference)?];
        let no_overlap = |overlap_s: f64| ErrorsError::NoOverlap {
            overlap_s,
            needed_s: MIN_OVERLAP_S,
            sensor_s: spans[0],
            reference_s: spans[1],
        };
        let margin_s = if opts.estimate_time_offset {
            opts.max_time_offset_s
        } else {
            0.0
        };
        let start = spans[0][0].max(spans[1][0]) + margin_s;
        let end = spans[0][1].min(spans[1][1]) - margin_s;
        if !(end - start >= MIN_OVERLAP_S) {
            return Err(no_overlap((end - start).max(0.0)));
        }
        let [gyro, accel, ..] = reference.triplets();
        let (kind, epochs) = if gyro && accel {
            let first_sensor = sensor.count_before(start, false)?;
            let epochs = sensor.count_before(end, true)? - first_sensor;
            (GridKind::ReferenceImu { first_sensor }, epochs)
        } else {
            let first_bound = reference.count_before(start, false)?;
            let bounds = reference.count_before(end, true)? - first_bound;
            (
                GridKind::NavigationSolution { first_bound },
                bounds.saturating_sub(1),
            )
        };
        if epochs < MIN_EPOCHS {
            return Err(no_overlap(end - start));
        }
        Ok(Self {
            kind,
            epochs,
            margin_s,
            sensor_triplets: sensor.triplets(),
        })
    }

    /// Whether the reference is an IMU (else a navigation solution).
    pub(super) fn reference_is_imu(&self) -> bool {
        matches!(self.kind, GridKind::ReferenceImu { .. })
    }

    /// Whether the sensor has gyros.
    pub(super) fn has_gyro(&self) -> bool {
        self.sensor_triplets[0]
    }

    /// Whether the sensor has accelerometers.
    pub(super) fn has_accel(&self) -> bool {
        self.sensor_triplets[1]
    }

    /// The samples of epochs `own` and of [`APRON_EPOCHS`] beyond it either side.
    pub(super) fn block<'a>(
        &self,
        sensor: &'a dyn Samples,
        reference: &'a dyn Samples,
        own: Range<usize>,
    ) -> Result<BlockSamples<'a>, ErrorsError> {
        let read =
            own.start.saturating_sub(APRON_EPOCHS)..(own.end + APRON_EPOCHS).min(self.epochs);
        // The recording the epochs are made of, the rows that make them, and the other one.
        let (first, last, epoch_rows, other): (usize, usize, &dyn Samples, &dyn Samples) =
            match self.kind {
                GridKind::ReferenceImu { first_sensor } => (
                    first_sensor + read.start,
                    first_sensor + read.end - 1,
                    sensor,
                    reference,
                ),
                GridKind::NavigationSolution { first_bound } => (
                    first_bound + read.start,
                    first_bound + read.end,
                    reference,
                    sensor,
                ),
            };
        let lo_s = epoch_rows.time_s(first)? - self.margin_s;
        let hi_s = epoch_rows.time_s(last)? + self.margin_s;
        let other_rows = other
            .count_before(lo_s, false)?
            .saturating_sub(APRON_SAMPLES)
            ..(other.count_before(hi_s, true)? + APRON_SAMPLES).min(other.len());
        let (epoch_rec, epoch_at) = epoch_rows.rows(first..last + 1)?;
        let (other_rec, _) = other.rows(other_rows)?;
        let local = first - epoch_at..first - epoch_at + read.len();
        let (sensor, reference) = match self.kind {
            GridKind::ReferenceImu { .. } => (epoch_rec, other_rec),
            GridKind::NavigationSolution { .. } => (other_rec, epoch_rec),
        };
        Ok(BlockSamples {
            sensor,
            reference,
            local,
            kind: self.kind,
            own: own.start - read.start..own.end - read.start,
        })
    }
}

/// How the reference and the sensor are read over the epochs.
// One per calibration: boxing the larger variant would gain nothing.
#[allow(clippy::large_enum_variant)]
enum EpochKind<'a> {
    /// A reference IMU: the epochs are the sensor's own samples, untouched (so its noise
    /// reaches the error signal unfiltered and a fitted model can be simulated directly),
    /// with the smooth reference interpolated to them.
    ReferenceImu {
        /// Sensor samples of the epochs.
        sensor_rows: Range<usize>,
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

/// A block of epochs of a sensor and its reference, readable at any time offset.
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
    /// The epochs of `block`, and what is needed to read both recordings over them.
    pub(super) fn new(block: &'a BlockSamples<'_>) -> Result<Self, ErrorsError> {
        let (sensor, reference): (&ImuRecording, &ImuRecording) = (&block.sensor, &block.reference);
        let (t_s, kind) = match (block.kind, &reference.gyro_rad_s, &reference.accel_m_s2) {
            (GridKind::ReferenceImu { .. }, Some(gyro_rad_s), Some(accel_m_s2)) => {
                let kind = EpochKind::ReferenceImu {
                    sensor_rows: block.local.clone(),
                    gyro_rad_s,
                    accel_m_s2,
                    omega_dot_rad_s2: native_derivative(&reference.t_s, gyro_rad_s),
                    f_dot_m_s3: native_derivative(&reference.t_s, accel_m_s2),
                };
                (sensor.t_s[block.local.clone()].to_vec(), kind)
            }
            _ => {
                let bounds = block.local.start..block.local.end + 1;
                let bounds_s = reference.t_s[bounds.clone()].to_vec();
                let bounds_idx: Vec<usize> = bounds.collect();
                let t_s: Vec<f64> = bounds_s.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
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

    /// Reference and sensor over the epochs for a time offset `shift_s` (positive: the
    /// sensor lags, so its epoch k shows the truth at epoch time - shift).
    pub(super) fn at(&self, shift_s: f64) -> Result<EpochData, ErrorsError> {
        match &self.kind {
            EpochKind::ReferenceImu {
                sensor_rows,
                gyro_rad_s,
                accel_m_s2,
                omega_dot_rad_s2,
                f_dot_m_s3,
            } => {
                let (reference, [omega_dot, f_dot]) = reference_at_points(
                    self.reference,
                    [gyro_rad_s, accel_m_s2, omega_dot_rad_s2, f_dot_m_s3],
                    self.t_s.iter().map(|t| t - shift_s),
                )?;
                let raw_at = |x: &Triplet| -> Vec<Vector3<f64>> {
                    sensor_rows
                        .clone()
                        .map(|i| Vector3::new(x[0][i], x[1][i], x[2][i]))
                        .collect()
                };
                Ok(EpochData {
                    reference,
                    omega_dot_b_rad_s2: omega_dot,
                    f_dot_b_m_s3: f_dot,
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
        let lagrange = worst(&|t| Interpolant::new(&t_s, t).read(&x));
        let linear = worst(&|t| Interpolant::linear(&t_s, t).read(&x));
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
