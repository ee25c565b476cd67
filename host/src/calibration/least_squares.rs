//! The linearised least squares of the calibration (eqs. 10-11 plus biases and per-channel
//! time-offset terms): the design rows of an epoch, one weighted solve with its Newey-West
//! sandwich covariance, the time offset common to the channels, and the Gauss-Newton
//! iteration on the boresight and the time offset.

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};

use super::epochs::EpochData;
use super::passes::{Epochs, View};
use super::{ErrorOptions, ErrorsError, Estimate3};
use crate::model::Channel;
use crate::regress::stream::{BartlettSums, Whitener};
use crate::regress::AndrewsSums;

pub(super) fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Most parameters of the linearised model: boresight, two bias triplets, lever arm and six
/// per-channel time offsets.
pub(super) const MAX_PARAMETERS: usize = 18;

/// Column layout of the unknowns: boresight (always), then the gyro biases, accelerometer
/// biases, lever arm and per-channel time offsets of those estimated.
#[derive(Debug, Clone, Copy)]
pub(super) struct Layout {
    pub gyro: bool,
    pub accel: bool,
    pub lever: bool,
    pub time: bool,
}

impl Layout {
    pub(super) fn len(&self) -> usize {
        3 + 3 * usize::from(self.gyro)
            + 3 * usize::from(self.accel)
            + 3 * usize::from(self.lever)
            + 6 * usize::from(self.time)
    }
    pub(super) fn bg(&self) -> Option<usize> {
        self.gyro.then_some(3)
    }
    pub(super) fn ba(&self) -> Option<usize> {
        self.accel.then_some(3 + 3 * usize::from(self.gyro))
    }
    pub(super) fn lever(&self) -> Option<usize> {
        self.lever
            .then_some(3 + 3 * usize::from(self.gyro) + 3 * usize::from(self.accel))
    }
    /// First of the six per-channel time-offset columns (gx gy gz ax ay az).
    pub(super) fn time(&self) -> Option<usize> {
        self.time.then_some(self.len() - 6)
    }
}

/// One weighted least-squares solution.
pub(super) struct Solution {
    /// Parameters, columns as in [`Layout`].
    pub theta: DVector<f64>,
    /// Their Newey-West sandwich covariance.
    pub cov: DMatrix<f64>,
    /// Newey-West lag, epochs.
    pub lag: usize,
}

/// Row `i` of [`skew`]`(v)`.
#[inline]
fn skew_row(v: &Vector3<f64>, i: usize) -> [f64; 3] {
    match i {
        0 => [0.0, -v.z, v.y],
        1 => [v.z, 0.0, -v.x],
        _ => [-v.y, v.x, 0.0],
    }
}

/// Row `i` (axis x, y, z = 0, 1, 2) of the linearised error model of one epoch for the
/// gyros (`accel = false`) or the accelerometers, columns as in [`Layout`]: the diagnosis
/// asks for one channel's rows at a time, and the calibration's normal equations for every
/// epoch's, many times over, so it is written out in scalars (the lever arm's skew(omega_dot) +
/// skew(omega)^2 row is skew(omega_dot)'s row plus omega_i omega_j - |omega|^2 delta_ij).
/// Inlined into its loops, where most of the row is known zeros.
#[inline]
pub(super) fn design_row(
    layout: &Layout,
    omega_rad_s: &Vector3<f64>,
    f_m_s2: &Vector3<f64>,
    omega_dot_rad_s2: &Vector3<f64>,
    f_dot_m_s3: &Vector3<f64>,
    accel: bool,
    i: usize,
) -> [f64; MAX_PARAMETERS] {
    let mut x = [0.0; MAX_PARAMETERS];
    x[..3].copy_from_slice(&skew_row(if accel { f_m_s2 } else { omega_rad_s }, i));
    if accel {
        if let Some(ba) = layout.ba() {
            x[ba + i] = 1.0;
        }
        if let Some(l) = layout.lever() {
            let w = omega_rad_s;
            let w2 = w.norm_squared();
            let dot_row = skew_row(omega_dot_rad_s2, i);
            for j in 0..3 {
                let delta = if i == j { w2 } else { 0.0 };
                x[l + j] = dot_row[j] + w[i] * w[j] - delta;
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
    x
}

/// Inverse of a normal matrix X'WX, or None when it is near singular (rather than return
/// meaningless estimates). Columns are scaled first so the inverse is well conditioned
/// (lever-arm columns are ~1e-2 of the boresight ones on a car).
pub(super) fn normal_matrix_inverse(xtwx: &DMatrix<f64>) -> Option<DMatrix<f64>> {
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

/// Calls `visit(row, error, weight)` for each design row of epoch `k` of `data`: three for
/// the gyros, three for the accelerometers, of those the layout estimates.
fn epoch_rows(
    layout: &Layout,
    weights: [f64; 2],
    data: &EpochData,
    k: usize,
    visit: &mut dyn FnMut(&[f64; MAX_PARAMETERS], f64, f64),
) {
    let reference = &data.reference;
    let w = &reference.omega_ib_b_rad_s[k];
    let f = &reference.f_b_m_s2[k];
    let sensed = [
        (
            data.gyro_rad_s.as_deref().filter(|_| layout.gyro),
            w,
            false,
            weights[0],
        ),
        (
            data.accel_m_s2.as_deref().filter(|_| layout.accel),
            f,
            true,
            weights[1],
        ),
    ];
    for (samples, truth, accel, weight) in sensed {
        let Some(samples) = samples else { continue };
        let e = samples[k] - truth;
        for i in 0..3 {
            // Each epoch's rows are made again on each pass rather than held: six rows of
            // MAX_PARAMETERS numbers an epoch would be the largest item of a long drive.
            let x = design_row(
                layout,
                w,
                f,
                &data.omega_dot_b_rad_s2[k],
                &data.f_dot_b_m_s3[k],
                accel,
                i,
            );
            visit(&x, e[i], weight);
        }
    }
}

/// Calls `score` with each epoch's score (the sum over its rows of w x e, e the residual of
/// `theta`), in epoch order.
fn score_pass(
    layout: &Layout,
    view: &View,
    weights: [f64; 2],
    theta: &DVector<f64>,
    score: &mut dyn FnMut(&[f64]),
) -> Result<(), ErrorsError> {
    let p = layout.len();
    let mut u = vec![0.0; p];
    view.pass(&mut |block| {
        for k in block.own.clone() {
            u.fill(0.0);
            epoch_rows(layout, weights, block.data, k, &mut |x, y, w| {
                let pred: f64 = (0..p).map(|a| x[a] * theta[a]).sum();
                let e = y - pred;
                for a in 0..p {
                    u[a] += w * x[a] * e;
                }
            });
            score(&u);
        }
        Ok(())
    })
}

/// One weighted least-squares solve of the linearised error model over all epochs: the
/// normal equations in one pass, the Newey-West lag's sums in a second, its Bartlett meat in
/// a third. `None` when the normal matrix is near singular.
fn solve(layout: &Layout, view: &View, weights: [f64; 2]) -> Result<Option<Solution>, ErrorsError> {
    let p = layout.len();
    let mut xtwx = DMatrix::<f64>::zeros(p, p);
    let mut xtwy = DVector::<f64>::zeros(p);
    view.pass(&mut |block| {
        for k in block.own.clone() {
            epoch_rows(layout, weights, block.data, k, &mut |x, y, w| {
                // The rows are sparse and the matrix symmetric: the upper triangle's nonzero
                // products, each summed in epoch order (so the same to the bit as all of them).
                for a in (0..p).filter(|&a| x[a] != 0.0) {
                    xtwy[a] += w * x[a] * y;
                    for b in (a..p).filter(|&b| x[b] != 0.0) {
                        xtwx[(a, b)] += w * x[a] * x[b];
                    }
                }
            });
        }
        Ok(())
    })?;
    xtwx.fill_lower_triangle_with_upper_triangle();
    let Some(bread) = normal_matrix_inverse(&xtwx) else {
        return Ok(None);
    };
    let theta = &bread * &xtwy;
    let (mut andrews, mut n) = (AndrewsSums::new(p), 0usize);
    score_pass(layout, view, weights, &theta, &mut |u| {
        andrews.push(u);
        n += 1;
    })?;
    let lag = andrews.lag().min(n.saturating_sub(1));
    let mut bartlett = BartlettSums::new(Whitener::none(p), p, lag, n);
    score_pass(layout, view, weights, &theta, &mut |u| bartlett.push(u))?;
    let cov = &bread * bartlett.finish() * &bread;
    Ok(Some(Solution { theta, cov, lag }))
}

/// The time offset common to a sensor's channels, from the per-channel offsets of one solve.
pub(super) struct CommonTimeOffset {
    /// Step to apply to the current offset, s.
    pub value: f64,
    /// 1-sigma, s.
    pub sigma: f64,
    /// Channels left out, with their own offset step, s.
    pub inconsistent: Vec<(Channel, f64)>,
}

/// A sensor time offset delays every channel alike, while a sensitivity to angular
/// acceleration or jerk acts on one channel's own derivative and looks like an offset of that
/// channel alone. So each channel gets its own offset column, and the common offset is the
/// precision-weighted mean over the channels that agree with their median (within 4 sigma
/// plus 0.2 ms, so a Newey-West sigma that is somewhat optimistic does not split a true
/// common offset); the median is not moved by one or two channels with terms of their own.
fn common_time_offset(sol: &Solution, t: usize, gyro: bool, accel: bool) -> CommonTimeOffset {
    let present: Vec<Channel> = Channel::ALL
        .into_iter()
        .filter(|ch| if ch.is_gyro() { gyro } else { accel })
        .filter(|ch| sol.cov[(t + ch.index(), t + ch.index())] > 0.0)
        .collect();
    let tau = |ch: Channel| sol.theta[t + ch.index()];
    let sd = |ch: Channel| sol.cov[(t + ch.index(), t + ch.index())].sqrt();
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
    let (kept, inconsistent): (Vec<Channel>, Vec<Channel>) = present
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

pub(super) fn triplet_estimate(sol: &Solution, at: usize) -> Estimate3 {
    Estimate3 {
        value: std::array::from_fn(|i| sol.theta[at + i]),
        sigma: std::array::from_fn(|i| sol.cov[(at + i, at + i)].max(0.0).sqrt()),
    }
}

/// The calibration the iterations settled on.
pub(super) struct Fit {
    /// The unknowns left in (lever arm and time offset drop out when unobservable).
    pub layout: Layout,
    /// Weights of the gyro and accelerometer rows.
    pub weights: [f64; 2],
    /// Sensor-to-body rotation applied to the sensor: the boresight estimate.
    pub r_sb: Rotation3<f64>,
    /// Time offset applied, s (positive: the sensor lags).
    pub shift_s: f64,
    /// The last solve, at `r_sb` and `shift_s`.
    pub solution: Solution,
    /// The time offset common to the channels, from the last solve (when estimated).
    pub common_time: Option<CommonTimeOffset>,
    /// Terms left out as unobservable.
    pub notes: Vec<String>,
}

impl Fit {
    /// The estimated lever arm, reference body frame, m.
    pub(super) fn lever_arm_b_m(&self) -> Option<Vector3<f64>> {
        let theta = &self.solution.theta;
        self.layout
            .lever()
            .map(|l| Vector3::new(theta[l], theta[l + 1], theta[l + 2]))
    }
}

/// Most iterations of the fit (the first only sets the weights).
const MAX_ITERATIONS: usize = 12;

/// Gauss-Newton on the rotation and the time offset: the sensor is rotated by the current
/// boresight estimate and only a small residual rotation is solved for linearly, so the
/// small-angle model of eqs. 10-11 holds at convergence even for boresights of several
/// degrees; the time offset moves by the common offset of each solve.
pub(super) fn fit(epochs: &Epochs<'_>, opts: &ErrorOptions) -> Result<Fit, ErrorsError> {
    let grid = epochs.grid();
    let mut notes = Vec::new();
    let mut layout = Layout {
        gyro: grid.has_gyro(),
        accel: grid.has_accel(),
        lever: grid.has_accel() && opts.estimate_lever_arm,
        time: opts.estimate_time_offset,
    };
    let mut shift_s = 0.0;
    let mut r_sb = Rotation3::identity();
    let mut weights = [1.0, 1.0];
    let mut solution = None;
    let mut common_time: Option<CommonTimeOffset> = None;
    for iteration in 0..MAX_ITERATIONS {
        let view = epochs.at(shift_s, r_sb)?;
        let sol = solve_observable(&mut layout, &view, weights, &mut notes)?;
        // Reweight gyro and accelerometer rows by their residual variances once, so neither
        // sensor type dominates through its units.
        if iteration == 0 {
            weights = residual_weights(&layout, &view, &sol, weights)?;
            continue;
        }
        // The residual rotation solved for is psi in C_b^s' = exp(-[psi x]) of the rotated
        // sensor, so the sensor-to-body rotation is refined by exp([psi x]).
        let dpsi = Vector3::new(sol.theta[0], sol.theta[1], sol.theta[2]);
        let common = layout
            .time()
            .map(|t| common_time_offset(&sol, t, grid.has_gyro(), grid.has_accel()));
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
    Ok(Fit {
        layout,
        weights,
        r_sb,
        shift_s,
        solution: solution.expect("at least one update iteration"),
        common_time,
        notes,
    })
}

/// [`solve`], leaving out the lever arm and then the time offset (with a note each) while
/// the normal matrix is singular.
fn solve_observable(
    layout: &mut Layout,
    view: &View,
    weights: [f64; 2],
    notes: &mut Vec<String>,
) -> Result<Solution, ErrorsError> {
    loop {
        match solve(layout, view, weights)? {
            Some(s) => return Ok(s),
            None if layout.lever => {
                layout.lever = false;
                notes.push("lever arm not observable from these dynamics: fixed to zero".into());
            }
            None if layout.time => {
                layout.time = false;
                notes.push("time offset not observable from these dynamics: fixed to zero".into());
            }
            None => {
                return Err(ErrorsError::Unobservable(
                    "boresight and biases are not separable (the reference barely moves)".into(),
                ))
            }
        }
    }
}

/// Row weights that give the gyro and the accelerometer residuals of `sol` unit variance
/// (a sensor type without residuals keeps its weight from `weights`).
fn residual_weights(
    layout: &Layout,
    view: &View,
    sol: &Solution,
    mut weights: [f64; 2],
) -> Result<[f64; 2], ErrorsError> {
    let theta = &sol.theta;
    let (mut sg, mut ng, mut sa, mut na) = (0.0, 0.0, 0.0, 0.0);
    view.pass(&mut |block| {
        let data = block.data;
        let reference = &data.reference;
        let (omega_dot, f_dot) = (&data.omega_dot_b_rad_s2, &data.f_dot_b_m_s3);
        for k in block.own.clone() {
            let w = &reference.omega_ib_b_rad_s[k];
            let f = &reference.f_b_m_s2[k];
            let psi = Vector3::new(theta[0], theta[1], theta[2]);
            if let (Some(o), Some(bg)) = (&data.gyro_rad_s, layout.bg()) {
                let mut pred =
                    skew(w) * psi + Vector3::new(theta[bg], theta[bg + 1], theta[bg + 2]);
                if let Some(t) = layout.time() {
                    pred -= Vector3::new(theta[t], theta[t + 1], theta[t + 2])
                        .component_mul(&omega_dot[k]);
                }
                sg += (o[k] - w - pred).norm_squared();
                ng += 3.0;
            }
            if let (Some(fs), Some(ba)) = (&data.accel_m_s2, layout.ba()) {
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
        Ok(())
    })?;
    if ng > 0.0 && sg > 0.0 {
        weights[0] = ng / sg;
    }
    if na > 0.0 && sa > 0.0 {
        weights[1] = na / sa;
    }
    Ok(weights)
}
