//! Building a sensor's error signals against a reference (paper Section II): put the two
//! recordings on one time base, estimate the inter-IMU boresight, lever arm, biases and
//! residual time offset, bring the sensor into the reference body frame (eq. 9) and subtract.
//!
//! Time base. Each recording is turned into running integrals of its angular rate and
//! specific force (trapezoidal for rate samples), so interval means over any common epoch
//! grid are exact integrals of what each sensor measured, whatever their sample rates. The
//! epochs are the sample intervals of the slower recording. A time offset is applied by
//! evaluating the sensor's integrals at shifted boundaries.
//!
//! Reference kinds. A reference IMU (rate and specific-force columns, plus attitude for the
//! gravity term of the linear acceleration), or only a navigation solution (attitude, NED
//! velocity and position, such as the 10 Hz PSINS FOG INS output): then the reference body
//! rate over an epoch is the rotation between consecutive attitudes plus the Earth and
//! transport rates, and the specific force is the velocity change corrected for Coriolis and
//! gravity, compared at the reference's rate over matching intervals.
//!
//! Estimation. A batch weighted least-squares fit over all epochs of the linearised eqs.
//! 10-11 plus biases and the time-offset term (-dt times the derivative), iterated on the time
//! offset; 1-sigma values come from a Newey-West sandwich over epoch scores, because the
//! residuals are autocorrelated sensor noise. The boresight psi is the small rotation
//! C_b^s = exp(-[psi x]) from the reference body frame b to the sensor frame s; the lever arm
//! r is the sensor's position relative to the reference, in b, metres; the time offset is
//! positive when the sensor lags the reference. The error signals keep the sensor biases:
//! they are part of the error the stochastic model has to describe.

use dynacal_core::nav::{earth_rate_ned_rad_s, gravity_ned_m_s2, transport_rate_ned_rad_s};
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error_signal::ErrorSignals;
use crate::interchange::ImuRecording;
use crate::numeric::{central_difference_3, stencil_derivative};
use crate::regress::{andrews_bartlett_lag_from_scores, newey_west_meat_from_scores};

/// Errors building error signals.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ErrorsError {
    /// The sensor recording has neither gyro nor accelerometer columns.
    #[error("sensor recording has no gyro (gx_rad_s ...) or accelerometer (ax_m_s2 ...) columns")]
    SensorHasNoChannels,
    /// The reference lacks what is needed.
    #[error("reference recording needs {0}")]
    ReferenceIncomplete(&'static str),
    /// The recordings do not overlap in time long enough.
    #[error("the recordings overlap for {overlap_s:.3} s, too short (need at least {needed_s} s)")]
    NoOverlap { overlap_s: f64, needed_s: f64 },
    /// The calibration is not observable from these data.
    #[error("calibration not observable from these data: {0}")]
    Unobservable(String),
}

/// A vector estimate with its 1-sigma uncertainty per component.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate3 {
    pub value: [f64; 3],
    pub sigma: [f64; 3],
}

/// A scalar estimate with its 1-sigma uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate1 {
    pub value: f64,
    pub sigma: f64,
}

/// What was estimated while building the error signals (the `--json` summary).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationSummary {
    /// Boresight psi_b->s (small rotation from reference body to sensor frame), rad.
    pub boresight_rad: Estimate3,
    /// Lever arm r_b->s of the sensor w.r.t. the reference, reference body frame, m.
    /// `None` when the sensor has no accelerometers or the lever arm was not estimated.
    pub lever_arm_m: Option<Estimate3>,
    /// Time offset of the sensor w.r.t. the reference, s (positive: the sensor lags).
    pub time_offset_s: Option<Estimate1>,
    /// Gyro bias in the sensor frame, rad/s.
    pub gyro_bias_rad_s: Option<Estimate3>,
    /// Accelerometer bias in the sensor frame, m/s^2.
    pub accel_bias_m_s2: Option<Estimate3>,
    /// `imu` or `navigation_solution`.
    pub reference_kind: String,
    /// Number of epochs and their median length, s.
    pub epochs: usize,
    pub epoch_dt_s: f64,
    /// Standard deviation of each error channel after calibration (gx .. az; absent = null).
    pub error_std: [Option<f64>; 6],
    /// Newey-West lag (epochs) used for the uncertainties.
    pub hac_lag: usize,
    /// How the estimates were obtained.
    pub method: String,
    /// Anything the user should know (e.g. terms left out as unobservable).
    pub notes: Vec<String>,
}

/// Options for [`build_error_signals`].
#[derive(Debug, Clone, Copy)]
pub struct ErrorOptions {
    /// Estimate the lever arm (needs rotational dynamics; otherwise it is fixed to zero).
    pub estimate_lever_arm: bool,
    /// Estimate the time offset.
    pub estimate_time_offset: bool,
    /// Largest time offset searched, s: also the margin trimmed off the overlap.
    pub max_time_offset_s: f64,
}

impl Default for ErrorOptions {
    fn default() -> Self {
        Self {
            estimate_lever_arm: true,
            estimate_time_offset: true,
            max_time_offset_s: 0.2,
        }
    }
}

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

/// Cubic (4-point Lagrange) interpolation of `x` sampled at `t_s` (increasing), linear in
/// the first and last interval. Linear interpolation of a reference IMU is not good enough
/// once the epochs fall between its samples: at 200 Hz it loses 8% of a 26 Hz vibration at
/// mid-interval, which then shows in the error as a false scale factor; the cubic loses
/// about 1%.
fn cubic_at(t_s: &[f64], x: &[f64], t: f64) -> f64 {
    let n = t_s.len();
    if n < 4 || t <= t_s[1] || t >= t_s[n - 2] {
        return lerp_at(t_s, x, t);
    }
    let i = t_s.partition_point(|&s| s <= t) - 1;
    let idx = [i - 1, i, i + 1, i + 2];
    let mut value = 0.0;
    for (a, &ia) in idx.iter().enumerate() {
        let mut w = 1.0;
        for (b, &ib) in idx.iter().enumerate() {
            if a != b {
                w *= (t - t_s[ib]) / (t_s[ia] - t_s[ib]);
            }
        }
        value += w * x[ia];
    }
    value
}

/// The reference over the epochs: mean body rate and specific force, attitude at mid-epoch.
struct EpochData {
    reference: ReferenceEpochs,
    omega_dot: Vec<Vector3<f64>>,
    f_dot: Vec<Vector3<f64>>,
    gyro: Option<Vec<Vector3<f64>>>,
    accel: Option<Vec<Vector3<f64>>>,
}

struct ReferenceEpochs {
    omega_ib_b_rad_s: Vec<Vector3<f64>>,
    f_b_m_s2: Vec<Vector3<f64>>,
    q_nb_mid: Vec<UnitQuaternion<f64>>,
    g_ned_mid_m_s2: Vec<Vector3<f64>>,
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
    let at = |t: f64, x: &[Vec<f64>; 3]| Vector3::from_fn(|i, _| cubic_at(&rec.t_s, &x[i], t));
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

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Column layout of the unknowns.
/// Most parameters of the linearised model: boresight, two bias triplets, lever arm and six
/// per-channel time offsets.
const MAX_PARAMETERS: usize = 18;

#[derive(Debug, Clone, Copy)]
struct Layout {
    gyro: bool,
    accel: bool,
    lever: bool,
    time: bool,
}

impl Layout {
    fn len(&self) -> usize {
        3 + 3 * usize::from(self.gyro)
            + 3 * usize::from(self.accel)
            + 3 * usize::from(self.lever)
            + 6 * usize::from(self.time)
    }
    fn bg(&self) -> Option<usize> {
        self.gyro.then_some(3)
    }
    fn ba(&self) -> Option<usize> {
        self.accel.then_some(3 + 3 * usize::from(self.gyro))
    }
    fn lever(&self) -> Option<usize> {
        self.lever
            .then_some(3 + 3 * usize::from(self.gyro) + 3 * usize::from(self.accel))
    }
    /// First of the six per-channel time-offset columns (gx gy gz ax ay az).
    fn time(&self) -> Option<usize> {
        self.time.then_some(self.len() - 6)
    }
}

struct Solution {
    theta: DVector<f64>,
    cov: DMatrix<f64>,
    lag: usize,
}

/// The three rows (x, y, z) of the linearised error model of one epoch for the gyros
/// (`accel = false`) or the accelerometers: columns as in [`Layout`].
fn design_rows(
    layout: &Layout,
    omega_rad_s: &Vector3<f64>,
    f_m_s2: &Vector3<f64>,
    omega_dot_rad_s2: &Vector3<f64>,
    f_dot_m_s3: &Vector3<f64>,
    accel: bool,
) -> [[f64; MAX_PARAMETERS]; 3] {
    let mut rows = [[0.0; MAX_PARAMETERS]; 3];
    let s = skew(if accel { f_m_s2 } else { omega_rad_s });
    let ww = skew(omega_rad_s);
    let lever_matrix = skew(omega_dot_rad_s2) + ww * ww;
    for (i, x) in rows.iter_mut().enumerate() {
        for j in 0..3 {
            x[j] = s[(i, j)];
        }
        if accel {
            if let Some(ba) = layout.ba() {
                x[ba + i] = 1.0;
            }
            if let Some(l) = layout.lever() {
                for j in 0..3 {
                    x[l + j] = lever_matrix[(i, j)];
                }
            }
            if let Some(t) = layout.time() {
                x[t + 3 + i] = -f_dot_m_s3[i];
            }
        } else {
            if let Some(bg) = layout.bg() {
                x[bg + i] = 1.0;
            }
            if let Some(t) = layout.time() {
                x[t + i] = -omega_dot_rad_s2[i];
            }
        }
    }
    rows
}

/// The linear model the calibration fitted, at its solution: what it would have absorbed
/// from any other error. The discrepancy engine uses it to estimate per-channel terms
/// jointly with the calibration (Frisch-Waugh: a candidate regressor is first stripped of
/// what the calibration would take from it) and to correct the calibration's estimates for
/// the terms it finds; and it carries the epoch derivatives the calibration used (9-point
/// stencils at the reference's native rate), which are better than differences at the
/// sensor rate.
#[derive(Debug, Clone)]
pub struct CalibrationDesign {
    epochs: usize,
    /// Rows per channel (gx gy gz ax ay az), `epochs` each; empty for a channel not present.
    rows: [Vec<[f64; MAX_PARAMETERS]>; 6],
    weights: [f64; 2],
    /// (X' W X)^-1.
    bread: DMatrix<f64>,
    layout: Layout,
    /// Angular acceleration at the epochs, rad/s^2, body (reference) frame.
    pub omega_dot_b_rad_s2: [Vec<f64>; 3],
    /// Rate of change of specific force at the epochs, m/s^3, body (reference) frame.
    pub f_dot_b_m_s3: [Vec<f64>; 3],
}

impl CalibrationDesign {
    /// Index of the lever arm's x component, if estimated.
    pub fn lever_index(&self) -> Option<usize> {
        self.layout.lever()
    }
    /// Number of parameters.
    pub fn parameters(&self) -> usize {
        self.layout.len()
    }
    /// Number of epochs (rows per channel).
    pub fn epochs(&self) -> usize {
        self.epochs
    }
    /// Weight of a channel's rows (0..6, gx..az) in the calibration's least squares.
    pub fn weight(&self, channel: usize) -> f64 {
        self.weights[channel / 3]
    }
    /// Whether a channel (0..6, gx..az) has rows.
    pub fn has_channel(&self, channel: usize) -> bool {
        !self.rows[channel].is_empty()
    }
    /// (X'WX)^-1 of the calibration's weighted least squares.
    pub fn bread(&self) -> &DMatrix<f64> {
        &self.bread
    }
    /// Moments X_c' W_c y of a series on `channel` with the calibration's columns.
    pub fn moments(&self, channel: usize, y: &[f64]) -> DVector<f64> {
        let p = self.layout.len();
        let w = self.weights[channel / 3];
        let mut xtwy = DVector::<f64>::zeros(p);
        for (x, v) in self.rows[channel].iter().zip(y) {
            for a in 0..p {
                xtwy[a] += w * x[a] * v;
            }
        }
        xtwy
    }
    /// Moments X' W y of series on all channels at once.
    pub fn moments_all(&self, y: &[Option<&[f64]>; 6]) -> DVector<f64> {
        let mut total = DVector::<f64>::zeros(self.layout.len());
        for (ch, series) in y.iter().enumerate() {
            if let Some(series) = series.filter(|_| self.has_channel(ch)) {
                total += self.moments(ch, series);
            }
        }
        total
    }
    /// The calibration parameters the weighted least squares would take from an error
    /// series on `channel` alone (zero on the others).
    pub fn absorbed(&self, channel: usize, y: &[f64]) -> DVector<f64> {
        &self.bread * self.moments(channel, y)
    }
    /// The calibration parameters taken from errors on all channels at once.
    pub fn absorbed_all(&self, y: &[Option<&[f64]>; 6]) -> DVector<f64> {
        &self.bread * self.moments_all(y)
    }
    /// The fitted error on `channel` of a parameter vector.
    pub fn fitted(&self, channel: usize, theta: &DVector<f64>) -> Vec<f64> {
        let p = self.layout.len();
        self.rows[channel]
            .iter()
            .map(|x| (0..p).map(|a| x[a] * theta[a]).sum())
            .collect()
    }
    /// `y` on `channel` minus what the calibration would have absorbed from it.
    pub fn residualize(&self, channel: usize, y: &[f64]) -> Vec<f64> {
        if !self.has_channel(channel) || y.len() != self.epochs {
            return y.to_vec();
        }
        let theta = self.absorbed(channel, y);
        let fit = self.fitted(channel, &theta);
        y.iter().zip(fit).map(|(v, f)| v - f).collect()
    }
}

/// Inverse of a normal matrix X'WX, or None when it is near singular (rather than return
/// meaningless estimates). Columns are scaled first so the inverse is well conditioned
/// (lever-arm columns are ~1e-2 of the boresight ones on a car).
fn normal_matrix_inverse(xtwx: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let p = xtwx.nrows();
    let scale: Vec<f64> = (0..p).map(|a| xtwx[(a, a)].sqrt().max(1e-300)).collect();
    let scaled = DMatrix::from_fn(p, p, |a, b| xtwx[(a, b)] / (scale[a] * scale[b]));
    let eig = scaled.clone().symmetric_eigen();
    let (min_e, max_e) = eig
        .eigenvalues
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &e| {
            (lo.min(e), hi.max(e))
        });
    if !(min_e > 1e-10 * max_e) {
        return None;
    }
    let inv_scaled = scaled.cholesky()?.inverse();
    Some(DMatrix::from_fn(p, p, |a, b| {
        inv_scaled[(a, b)] / (scale[a] * scale[b])
    }))
}

/// One weighted least-squares solve of the linearised error model over all epochs.
#[allow(clippy::too_many_arguments)]
fn solve(
    layout: &Layout,
    reference: &ReferenceEpochs,
    omega_dot: &[Vector3<f64>],
    f_dot: &[Vector3<f64>],
    omega_s: Option<&[Vector3<f64>]>,
    f_s: Option<&[Vector3<f64>]>,
    weights: [f64; 2],
) -> Option<Solution> {
    let n = reference.omega_ib_b_rad_s.len();
    let p = layout.len();
    let mut xtwx = DMatrix::<f64>::zeros(p, p);
    let mut xtwy = DVector::<f64>::zeros(p);
    let mut rows: Vec<(usize, [f64; MAX_PARAMETERS], f64, f64)> = Vec::with_capacity(6 * n);
    for k in 0..n {
        let w = &reference.omega_ib_b_rad_s[k];
        let f = &reference.f_b_m_s2[k];
        if let Some(omega_s) = omega_s.filter(|_| layout.gyro) {
            let e = omega_s[k] - w;
            for (i, x) in design_rows(layout, w, f, &omega_dot[k], &f_dot[k], false)
                .into_iter()
                .enumerate()
            {
                rows.push((k, x, e[i], weights[0]));
            }
        }
        if let Some(f_s) = f_s.filter(|_| layout.accel) {
            let e = f_s[k] - f;
            for (i, x) in design_rows(layout, w, f, &omega_dot[k], &f_dot[k], true)
                .into_iter()
                .enumerate()
            {
                rows.push((k, x, e[i], weights[1]));
            }
        }
    }
    for (_, x, y, w) in &rows {
        for a in 0..p {
            xtwy[a] += w * x[a] * y;
            for b in 0..p {
                xtwx[(a, b)] += w * x[a] * x[b];
            }
        }
    }
    let bread = normal_matrix_inverse(&xtwx)?;
    let theta = &bread * &xtwy;
    // Epoch scores for the sandwich: sum over the epoch's rows of w x e.
    let mut scores = vec![0.0; n * p];
    for (k, x, y, w) in &rows {
        let pred: f64 = (0..p).map(|a| x[a] * theta[a]).sum();
        let e = y - pred;
        for a in 0..p {
            scores[k * p + a] += w * x[a] * e;
        }
    }
    let lag = andrews_bartlett_lag_from_scores(&scores, p);
    let meat = newey_west_meat_from_scores(&scores, p, lag);
    let cov = &bread * meat * &bread;
    Some(Solution { theta, cov, lag })
}

const CHANNEL_NAMES: [&str; 6] = ["gx", "gy", "gz", "ax", "ay", "az"];

/// The time offset common to a sensor's channels, from the per-channel offsets of one solve.
struct CommonTimeOffset {
    /// Step to apply to the current offset, s.
    value: f64,
    /// 1-sigma, s.
    sigma: f64,
    /// Channels left out, with their own offset step, s.
    inconsistent: Vec<(usize, f64)>,
}

/// A sensor time offset delays every channel alike, while a sensitivity to angular
/// acceleration or jerk acts on one channel's own derivative and looks like an offset of that
/// channel alone. So each channel gets its own offset column, and the common offset is the
/// precision-weighted mean over the channels that agree with their median (within 4 sigma
/// plus 0.2 ms, so a Newey-West sigma that is somewhat optimistic does not split a true
/// common offset); the median is not moved by one or two channels with terms of their own.
fn common_time_offset(sol: &Solution, t: usize, gyro: bool, accel: bool) -> CommonTimeOffset {
    let present: Vec<usize> = (0..6)
        .filter(|&ch| if ch < 3 { gyro } else { accel })
        .filter(|&ch| sol.cov[(t + ch, t + ch)] > 0.0)
        .collect();
    let tau = |ch: usize| sol.theta[t + ch];
    let sd = |ch: usize| sol.cov[(t + ch, t + ch)].sqrt();
    if present.is_empty() {
        return CommonTimeOffset {
            value: 0.0,
            sigma: f64::INFINITY,
            inconsistent: Vec::new(),
        };
    }
    let mut sorted: Vec<f64> = present.iter().map(|&ch| tau(ch)).collect();
    sorted.sort_by(f64::total_cmp);
    let m = sorted.len();
    let median = if m % 2 == 1 {
        sorted[m / 2]
    } else {
        0.5 * (sorted[m / 2 - 1] + sorted[m / 2])
    };
    let (kept, inconsistent): (Vec<usize>, Vec<usize>) = present
        .iter()
        .partition(|&&ch| (tau(ch) - median).abs() <= 4.0 * sd(ch) + 2e-4);
    let kept = if kept.is_empty() {
        present.clone()
    } else {
        kept
    };
    let weight_sum: f64 = kept.iter().map(|&ch| 1.0 / sd(ch).powi(2)).sum();
    let value = kept.iter().map(|&ch| tau(ch) / sd(ch).powi(2)).sum::<f64>() / weight_sum;
    CommonTimeOffset {
        value,
        sigma: weight_sum.sqrt().recip(),
        inconsistent: inconsistent.iter().map(|&ch| (ch, tau(ch))).collect(),
    }
}

fn triplet_estimate(sol: &Solution, at: usize) -> Estimate3 {
    Estimate3 {
        value: std::array::from_fn(|i| sol.theta[at + i]),
        sigma: std::array::from_fn(|i| sol.cov[(at + i, at + i)].max(0.0).sqrt()),
    }
}

/// A bias estimated in the (rotated) body frame, expressed back in the sensor frame. The
/// rotation is small, so the per-axis sigmas carry over.
fn to_sensor_frame(e: Estimate3, r_sb: &Rotation3<f64>) -> Estimate3 {
    let v = r_sb.inverse() * Vector3::from(e.value);
    Estimate3 {
        value: v.into(),
        sigma: e.sigma,
    }
}

fn std_dev(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
}

/// Builds the error signals of `sensor` against `reference` and reports the calibration.
pub fn build_error_signals(
    sensor: &ImuRecording,
    reference: &ImuRecording,
    opts: &ErrorOptions,
) -> Result<(ErrorSignals, CalibrationSummary), ErrorsError> {
    build_error_signals_with_design(sensor, reference, opts).map(|(s, c, _)| (s, c))
}

/// [`build_error_signals`], also returning the calibration's linear model at its solution.
pub fn build_error_signals_with_design(
    sensor: &ImuRecording,
    reference: &ImuRecording,
    opts: &ErrorOptions,
) -> Result<(ErrorSignals, CalibrationSummary, CalibrationDesign), ErrorsError> {
    if sensor.gyro_rad_s.is_none() && sensor.accel_m_s2.is_none() {
        return Err(ErrorsError::SensorHasNoChannels);
    }
    let ref_is_imu = reference.gyro_rad_s.is_some() && reference.accel_m_s2.is_some();
    let margin = if opts.estimate_time_offset {
        opts.max_time_offset_s
    } else {
        0.0
    };
    let start = sensor.t_s[0].max(reference.t_s[0]) + margin;
    let end = sensor.t_s[sensor.len() - 1].min(reference.t_s[reference.len() - 1]) - margin;
    let needed_s = 1.0;
    if !(end - start >= needed_s) {
        return Err(ErrorsError::NoOverlap {
            overlap_s: (end - start).max(0.0),
            needed_s,
        });
    }
    // Epochs. Against a reference IMU: the sensor's own samples, untouched (so its noise
    // reaches the error signal unfiltered and a fitted model can be simulated directly),
    // with the smooth reference interpolated to them. Against a navigation solution: the
    // solution's sample intervals, with the sensor integrated over each.
    let (epoch_t, sensor_idx, bounds, bounds_idx): (Vec<f64>, Vec<usize>, Vec<f64>, Vec<usize>) =
        if ref_is_imu {
            let (t, i): (Vec<f64>, Vec<usize>) = sensor
                .t_s
                .iter()
                .enumerate()
                .filter(|(_, &t)| t >= start && t <= end)
                .map(|(i, &t)| (t, i))
                .unzip();
            (t, i, Vec::new(), Vec::new())
        } else {
            let (b, i): (Vec<f64>, Vec<usize>) = reference
                .t_s
                .iter()
                .enumerate()
                .filter(|(_, &t)| t >= start && t <= end)
                .map(|(i, &t)| (t, i))
                .unzip();
            let mid = b.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
            (mid, Vec::new(), b, i)
        };
    if epoch_t.len() < 10 {
        return Err(ErrorsError::NoOverlap {
            overlap_s: end - start,
            needed_s,
        });
    }
    let mid_t = epoch_t.clone();
    let fixed_reference = if ref_is_imu {
        None
    } else {
        Some(reference_from_solution(reference, &bounds_idx)?)
    };
    let gyro_int = sensor
        .gyro_rad_s
        .as_ref()
        .map(|g| integrals(&sensor.t_s, g));
    let accel_int = sensor
        .accel_m_s2
        .as_ref()
        .map(|a| integrals(&sensor.t_s, a));
    // Derivatives of a reference IMU at its own rate, interpolated to the epochs like the
    // rates themselves.
    let reference_derivatives = if ref_is_imu {
        Some((
            native_derivative(
                &reference.t_s,
                reference.gyro_rad_s.as_ref().expect("reference IMU"),
            ),
            native_derivative(
                &reference.t_s,
                reference.accel_m_s2.as_ref().expect("reference IMU"),
            ),
        ))
    } else {
        None
    };
    let raw_at = |x: &[Vec<f64>; 3]| -> Vec<Vector3<f64>> {
        sensor_idx
            .iter()
            .map(|&i| Vector3::new(x[0][i], x[1][i], x[2][i]))
            .collect()
    };
    // Reference and sensor over the epochs for a time offset `shift_s` (positive: the
    // sensor lags, so its epoch k shows the truth at epoch time - shift).
    let epoch_data = |shift_s: f64| -> Result<EpochData, ErrorsError> {
        let (reference_epochs, gyro, accel) = match &fixed_reference {
            None => {
                let shifted: Vec<f64> = epoch_t.iter().map(|t| t - shift_s).collect();
                let r = reference_at_points(
                    reference,
                    reference
                        .gyro_rad_s
                        .as_ref()
                        .expect("reference IMU has gyros"),
                    reference
                        .accel_m_s2
                        .as_ref()
                        .expect("reference IMU has accelerometers"),
                    &shifted,
                )?;
                (
                    r,
                    sensor.gyro_rad_s.as_ref().map(raw_at),
                    sensor.accel_m_s2.as_ref().map(raw_at),
                )
            }
            Some(r) => (
                ReferenceEpochs {
                    omega_ib_b_rad_s: r.omega_ib_b_rad_s.clone(),
                    f_b_m_s2: r.f_b_m_s2.clone(),
                    q_nb_mid: r.q_nb_mid.clone(),
                    g_ned_mid_m_s2: r.g_ned_mid_m_s2.clone(),
                },
                gyro_int
                    .as_ref()
                    .map(|g| interval_means(g, &bounds, shift_s)),
                accel_int
                    .as_ref()
                    .map(|a| interval_means(a, &bounds, shift_s)),
            ),
        };
        let (omega_dot, f_dot) = match &reference_derivatives {
            Some((wd, fd)) => {
                let at = |x: &[Vec<f64>; 3]| -> Vec<Vector3<f64>> {
                    epoch_t
                        .iter()
                        .map(|&t| {
                            Vector3::from_fn(|i, _| cubic_at(&reference.t_s, &x[i], t - shift_s))
                        })
                        .collect()
                };
                (at(wd), at(fd))
            }
            None => (
                central_difference_3(&mid_t, &reference_epochs.omega_ib_b_rad_s),
                central_difference_3(&mid_t, &reference_epochs.f_b_m_s2),
            ),
        };
        Ok(EpochData {
            reference: reference_epochs,
            omega_dot,
            f_dot,
            gyro,
            accel,
        })
    };
    let mut notes = Vec::new();
    let mut layout = Layout {
        gyro: gyro_int.is_some(),
        accel: accel_int.is_some(),
        lever: accel_int.is_some() && opts.estimate_lever_arm,
        time: opts.estimate_time_offset,
    };
    let mut shift_s = 0.0;
    // Gauss-Newton on the rotation: the sensor is rotated by the current boresight estimate
    // and only a small residual rotation is solved for linearly, so the small-angle model
    // of eqs. 10-11 holds at convergence even for boresights of several degrees.
    let mut r_sb = Rotation3::identity();
    let mut weights = [1.0, 1.0];
    let rotate = |v: &Option<Vec<Vector3<f64>>>, r_sb: &Rotation3<f64>| {
        v.as_ref()
            .map(|v| v.iter().map(|x| r_sb * x).collect::<Vec<_>>())
    };
    let mut solution = None;
    let mut common_time: Option<CommonTimeOffset> = None;
    for iteration in 0..12 {
        let data = epoch_data(shift_s)?;
        let (reference_epochs, omega_dot, f_dot) = (&data.reference, &data.omega_dot, &data.f_dot);
        let (omega_s, f_s) = (rotate(&data.gyro, &r_sb), rotate(&data.accel, &r_sb));
        let sol = loop {
            match solve(
                &layout,
                reference_epochs,
                omega_dot,
                f_dot,
                omega_s.as_deref(),
                f_s.as_deref(),
                weights,
            ) {
                Some(s) => break s,
                None if layout.lever => {
                    layout.lever = false;
                    notes
                        .push("lever arm not observable from these dynamics: fixed to zero".into());
                }
                None if layout.time => {
                    layout.time = false;
                    notes.push(
                        "time offset not observable from these dynamics: fixed to zero".into(),
                    );
                }
                None => {
                    return Err(ErrorsError::Unobservable(
                        "boresight and biases are not separable (the reference barely moves)"
                            .into(),
                    ))
                }
            }
        };
        // Reweight gyro and accelerometer rows by their residual variances once, so neither
        // sensor type dominates through its units.
        if iteration == 0 {
            let theta = &sol.theta;
            let (mut sg, mut ng, mut sa, mut na) = (0.0, 0.0, 0.0, 0.0);
            for k in 0..mid_t.len() {
                let w = &reference_epochs.omega_ib_b_rad_s[k];
                let f = &reference_epochs.f_b_m_s2[k];
                let psi = Vector3::new(theta[0], theta[1], theta[2]);
                if let (Some(o), Some(bg)) = (&omega_s, layout.bg()) {
                    let mut pred =
                        skew(w) * psi + Vector3::new(theta[bg], theta[bg + 1], theta[bg + 2]);
                    if let Some(t) = layout.time() {
                        pred -= Vector3::new(theta[t], theta[t + 1], theta[t + 2])
                            .component_mul(&omega_dot[k]);
                    }
                    sg += (o[k] - w - pred).norm_squared();
                    ng += 3.0;
                }
                if let (Some(fs), Some(ba)) = (&f_s, layout.ba()) {
                    let mut pred =
                        skew(f) * psi + Vector3::new(theta[ba], theta[ba + 1], theta[ba + 2]);
                    if let Some(l) = layout.lever() {
                        let ww = skew(w);
                        pred += (skew(&omega_dot[k]) + ww * ww)
                            * Vector3::new(theta[l], theta[l + 1], theta[l + 2]);
                    }
                    if let Some(t) = layout.time() {
                        pred -= Vector3::new(theta[t + 3], theta[t + 4], theta[t + 5])
                            .component_mul(&f_dot[k]);
                    }
                    sa += (fs[k] - f - pred).norm_squared();
                    na += 3.0;
                }
            }
            if ng > 0.0 && sg > 0.0 {
                weights[0] = ng / sg;
            }
            if na > 0.0 && sa > 0.0 {
                weights[1] = na / sa;
            }
            continue;
        }
        // The residual rotation solved for is psi in C_b^s' = exp(-[psi x]) of the rotated
        // sensor, so the sensor-to-body rotation is refined by exp([psi x]).
        let dpsi = Vector3::new(sol.theta[0], sol.theta[1], sol.theta[2]);
        let common = layout
            .time()
            .map(|t| common_time_offset(&sol, t, omega_s.is_some(), f_s.is_some()));
        let step = common.as_ref().map_or(0.0, |c| c.value);
        common_time = common;
        r_sb = Rotation3::new(dpsi) * r_sb;
        shift_s = (shift_s + step).clamp(-opts.max_time_offset_s, opts.max_time_offset_s);
        let done = dpsi.norm() < 1e-9 && step.abs() < 1e-8;
        solution = Some(sol);
        if done {
            break;
        }
    }
    let sol = solution.expect("at least one update iteration");
    let psi_total = r_sb.scaled_axis();
    let lever = layout
        .lever()
        .map(|l| Vector3::new(sol.theta[l], sol.theta[l + 1], sol.theta[l + 2]));

    // Final errors at the estimated boresight and time offset.
    let data = epoch_data(shift_s)?;
    let (reference_epochs, omega_dot, f_dot) = (&data.reference, &data.omega_dot, &data.f_dot);
    let (omega_s, f_s) = (rotate(&data.gyro, &r_sb), rotate(&data.accel, &r_sb));
    let n = mid_t.len();
    // The time offset is the one common to the consistent channels, which a channel-specific
    // term does not move: the design the engine strips candidates with holds it fixed.
    let design_layout = Layout {
        time: false,
        ..layout
    };
    let design = {
        let mut rows: [Vec<[f64; MAX_PARAMETERS]>; 6] = Default::default();
        for k in 0..n {
            let (w, f) = (
                &reference_epochs.omega_ib_b_rad_s[k],
                &reference_epochs.f_b_m_s2[k],
            );
            for (accel, present) in [(false, omega_s.is_some()), (true, f_s.is_some())] {
                if present {
                    let r = design_rows(&design_layout, w, f, &omega_dot[k], &f_dot[k], accel);
                    for i in 0..3 {
                        rows[3 * usize::from(accel) + i].push(r[i]);
                    }
                }
            }
        }
        let p = design_layout.len();
        let mut xtwx = DMatrix::<f64>::zeros(p, p);
        for (ch, rs) in rows.iter().enumerate() {
            let w = weights[ch / 3];
            for x in rs {
                for a in 0..p {
                    for b in 0..p {
                        xtwx[(a, b)] += w * x[a] * x[b];
                    }
                }
            }
        }
        CalibrationDesign {
            epochs: n,
            rows,
            weights,
            // The same design with the time columns left out was solvable above, so this
            // inverse exists; zeros (nothing absorbed) only guard the impossible case.
            bread: normal_matrix_inverse(&xtwx).unwrap_or_else(|| DMatrix::zeros(p, p)),
            layout: design_layout,
            omega_dot_b_rad_s2: std::array::from_fn(|i| omega_dot.iter().map(|v| v[i]).collect()),
            f_dot_b_m_s3: std::array::from_fn(|i| f_dot.iter().map(|v| v[i]).collect()),
        }
    };
    let mut errors: [Option<Vec<f64>>; 6] = Default::default();
    if let Some(o) = &omega_s {
        for i in 0..3 {
            errors[i] = Some(
                (0..n)
                    .map(|k| (o[k] - reference_epochs.omega_ib_b_rad_s[k])[i])
                    .collect(),
            );
        }
    }
    if let Some(fs) = &f_s {
        for i in 0..3 {
            errors[3 + i] = Some(
                (0..n)
                    .map(|k| {
                        let w = &reference_epochs.omega_ib_b_rad_s[k];
                        let ww = skew(w);
                        let lever_term =
                            lever.map_or(Vector3::zeros(), |r| (skew(&omega_dot[k]) + ww * ww) * r);
                        (fs[k] - (reference_epochs.f_b_m_s2[k] + lever_term))[i]
                    })
                    .collect(),
            );
        }
    }
    // Dynamics of Section III at the epochs.
    let omega_ddot = central_difference_3(&mid_t, &omega_dot);
    let a_b: Vec<Vector3<f64>> = (0..n)
        .map(|k| {
            reference_epochs.f_b_m_s2[k]
                + reference_epochs.q_nb_mid[k].inverse() * reference_epochs.g_ned_mid_m_s2[k]
        })
        .collect();
    let a_dot = central_difference_3(&mid_t, &a_b);
    let series = [
        &reference_epochs.omega_ib_b_rad_s,
        &omega_dot,
        &omega_ddot,
        &a_b,
        &a_dot,
    ];
    let dynamics: [Vec<f64>; 15] =
        std::array::from_fn(|q| series[q / 3].iter().map(|v| v[q % 3]).collect());

    let error_std = std::array::from_fn(|i| errors[i].as_ref().map(|e| std_dev(e)));
    let mut dt: Vec<f64> = epoch_t.windows(2).map(|w| w[1] - w[0]).collect();
    let mid = dt.len() / 2;
    let epoch_dt_s = *dt.select_nth_unstable_by(mid, f64::total_cmp).1;
    if let Some(c) = common_time.as_ref().filter(|c| !c.inconsistent.is_empty()) {
        notes.push(format!(
            "time offset: {} not consistent with the offset common to the other channels \
             (a channel-specific derivative term, left in the error signal)",
            c.inconsistent
                .iter()
                .map(|(ch, tau)| format!("{} ({:+.5} s)", CHANNEL_NAMES[*ch], shift_s + tau))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    let summary = CalibrationSummary {
        boresight_rad: Estimate3 {
            value: psi_total.into(),
            sigma: triplet_estimate(&sol, 0).sigma,
        },
        lever_arm_m: layout.lever().map(|l| triplet_estimate(&sol, l)),
        time_offset_s: common_time.as_ref().map(|c| Estimate1 {
            value: shift_s,
            sigma: c.sigma,
        }),
        gyro_bias_rad_s: layout
            .bg()
            .map(|b| to_sensor_frame(triplet_estimate(&sol, b), &r_sb)),
        accel_bias_m_s2: layout
            .ba()
            .map(|b| to_sensor_frame(triplet_estimate(&sol, b), &r_sb)),
        reference_kind: if ref_is_imu {
            "imu"
        } else {
            "navigation_solution"
        }
        .into(),
        epochs: n,
        epoch_dt_s,
        error_std,
        hac_lag: sol.lag,
        method: "batch weighted least squares of the linearised eqs. 10-11 with biases and a \
                 time-offset term, iterated on the time offset; 1-sigma from a Newey-West \
                 sandwich over epoch scores"
            .into(),
        notes,
    };
    Ok((
        ErrorSignals {
            specific_force_b_m_s2: Some(std::array::from_fn(|i| {
                reference_epochs.f_b_m_s2.iter().map(|v| v[i]).collect()
            })),
            t_s: mid_t,
            errors,
            dynamics,
        },
        summary,
        design,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// Smooth, rich body motion: angular rate (rad/s) and its derivative, and specific force
    /// (m/s^2), as sums of sinusoids.
    fn motion(t: f64) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let tone = |a: f64, f: f64, p: f64| {
            let w = 2.0 * std::f64::consts::PI * f;
            (a * (w * t + p).sin(), a * w * (w * t + p).cos())
        };
        let comps = [
            [tone(0.3, 0.11, 0.0), tone(0.1, 0.7, 1.0)],
            [tone(0.25, 0.13, 2.0), tone(0.08, 0.9, 0.5)],
            [tone(0.5, 0.05, 1.0), tone(0.2, 0.6, 3.0)],
        ];
        let omega = Vector3::from_fn(|i, _| comps[i][0].0 + comps[i][1].0);
        let omega_dot = Vector3::from_fn(|i, _| comps[i][0].1 + comps[i][1].1);
        let f = Vector3::new(
            2.0 * (0.2 * t).sin(),
            1.5 * (0.17 * t + 1.0).sin(),
            -9.81 + 0.5 * (0.8 * t).sin(),
        );
        (omega, omega_dot, f)
    }

    #[test]
    fn cubic_interpolation_keeps_a_vibration_between_samples() {
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
        let cubic = worst(&|t| cubic_at(&t_s, &x, t));
        let linear = worst(&|t| lerp_at(&t_s, &x, t));
        assert!(linear > 0.07, "{linear}");
        assert!(cubic < 0.015, "{cubic}");
    }

    #[test]
    fn recovers_boresight_lever_arm_biases_and_time_offset() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let psi_true = Vector3::new(0.02, -0.01, 0.03);
        let r_true = Vector3::new(0.4, -0.25, 0.15);
        let bg = Vector3::new(1e-3, -2e-3, 5e-4);
        let ba = Vector3::new(0.05, -0.03, 0.08);
        let dt_true = 0.012;
        let c_bs = Rotation3::new(-psi_true);
        let dt = 0.01;
        let n = 30_000;
        let t_s: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
        let mut reference = ImuRecording {
            t_s: t_s.clone(),
            ..Default::default()
        };
        let mut sensor = ImuRecording {
            t_s: t_s.clone(),
            ..Default::default()
        };
        let (mut rg, mut ra, mut sg, mut sa): (
            [Vec<f64>; 3],
            [Vec<f64>; 3],
            [Vec<f64>; 3],
            [Vec<f64>; 3],
        ) = Default::default();
        for &t in &t_s {
            let (w, _, f) = motion(t);
            // The sensor lags: its sample at t shows the truth at t - dt_true.
            let (ws, wds, fs0) = motion(t - dt_true);
            let ws_b = ws;
            let fs_b = fs0 + skew(&wds) * r_true + skew(&ws_b) * skew(&ws_b) * r_true;
            let gyro = c_bs * ws_b
                + bg
                + Vector3::from_fn(|_, _| 2e-3 * rng.sample::<f64, _>(StandardNormal));
            let acc = c_bs * fs_b
                + ba
                + Vector3::from_fn(|_, _| 2e-2 * rng.sample::<f64, _>(StandardNormal));
            for i in 0..3 {
                rg[i].push(w[i]);
                ra[i].push(f[i]);
                sg[i].push(gyro[i]);
                sa[i].push(acc[i]);
            }
        }
        reference.gyro_rad_s = Some(rg);
        reference.accel_m_s2 = Some(ra);
        reference.attitude_rad = Some([vec![0.0; n], vec![0.0; n], vec![0.0; n]]);
        sensor.gyro_rad_s = Some(sg);
        sensor.accel_m_s2 = Some(sa);
        let (sig, s) = build_error_signals(&sensor, &reference, &ErrorOptions::default()).unwrap();
        let within = |est: f64, sigma: f64, truth: f64, what: &str| {
            assert!(
                sigma > 0.0 && (est - truth).abs() < 4.0 * sigma,
                "{what}: {est} +- {sigma} vs {truth}"
            );
        };
        for i in 0..3 {
            within(
                s.boresight_rad.value[i],
                s.boresight_rad.sigma[i],
                psi_true[i],
                "psi",
            );
            let l = s.lever_arm_m.unwrap();
            within(l.value[i], l.sigma[i], r_true[i], "lever");
            assert!(
                (l.value[i] - r_true[i]).abs() < 0.02,
                "lever arm within 2 cm"
            );
            within(
                s.gyro_bias_rad_s.unwrap().value[i],
                s.gyro_bias_rad_s.unwrap().sigma[i],
                bg[i],
                "bg",
            );
            within(
                s.accel_bias_m_s2.unwrap().value[i],
                s.accel_bias_m_s2.unwrap().sigma[i],
                ba[i],
                "ba",
            );
        }
        let to = s.time_offset_s.unwrap();
        within(to.value, to.sigma, dt_true, "time offset");
        assert!((to.value - dt_true).abs() < 1e-3);
        // After calibration the gyro error is bias plus white noise: its mean is the bias in
        // the reference frame and its spread the noise averaged over the epoch.
        let gx = sig.error("gx").unwrap();
        let mean = gx.iter().sum::<f64>() / gx.len() as f64;
        assert!((mean - bg[0]).abs() < 2e-4, "{mean}");
        assert!(std_dev(gx) < 3e-3, "{}", std_dev(gx));
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
