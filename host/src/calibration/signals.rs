//! What the calibration yields: the error signals (sensor minus reference, in the reference
//! body frame, lever-arm term removed), the dynamics of paper Section III beside them, and
//! the summary of the estimates.

use std::ops::Range;

use nalgebra::{Rotation3, Vector3};

use super::epochs::{EpochData, EpochGrid};
use super::least_squares::{skew, triplet_estimate, Fit};
use super::{CalibrationSummary, Estimate1, Estimate3};
use crate::error_signal::ErrorSignals;
use crate::model::Channel;

/// The error of each channel over the epochs (gx .. az; `None` for a sensor type the sensor
/// lacks): the rotated sensor minus the reference, the accelerometers also minus the lever-arm
/// term of `lever_arm_b_m`.
pub(super) fn error_columns(
    data: &EpochData,
    lever_arm_b_m: Option<Vector3<f64>>,
) -> [Option<Vec<f64>>; 6] {
    let reference = &data.reference;
    let n = data.len();
    let mut errors: [Option<Vec<f64>>; 6] = Default::default();
    if let Some(o) = &data.gyro_rad_s {
        for ch in Channel::GYROS {
            errors[ch.index()] = Some(
                (0..n)
                    .map(|k| (o[k] - reference.omega_ib_b_rad_s[k])[ch.axis()])
                    .collect(),
            );
        }
    }
    if let Some(fs) = &data.accel_m_s2 {
        for ch in Channel::ACCELEROMETERS {
            errors[ch.index()] = Some(
                (0..n)
                    .map(|k| {
                        let w = &reference.omega_ib_b_rad_s[k];
                        let ww = skew(w);
                        let lever_term = lever_arm_b_m.map_or(Vector3::zeros(), |r| {
                            (skew(&data.omega_dot_b_rad_s2[k]) + ww * ww) * r
                        });
                        (fs[k] - (reference.f_b_m_s2[k] + lever_term))[ch.axis()]
                    })
                    .collect(),
            );
        }
    }
    errors
}

/// The dynamics of Section III at the epochs `t_s`, in
/// [`crate::regress::DYNAMICS_REGRESSORS`] order: angular rate, acceleration and jerk, linear
/// acceleration (specific force plus gravity) and jerk, body frame.
pub(super) fn dynamics_columns(t_s: &[f64], data: &EpochData) -> [Vec<f64>; 15] {
    let reference = &data.reference;
    let column = |v: &[Vector3<f64>], axis: usize| v.iter().map(|x| x[axis]).collect::<Vec<_>>();
    let mut columns: [Vec<f64>; 15] = std::array::from_fn(|_| Vec::new());
    for axis in 0..3 {
        columns[axis] = column(&reference.omega_ib_b_rad_s, axis);
        columns[3 + axis] = column(&data.omega_dot_b_rad_s2, axis);
    }
    // Each temporary is dropped once its columns are made: a long drive holds fewer series.
    let omega_ddot = crate::numeric::central_difference_3(t_s, &data.omega_dot_b_rad_s2);
    for axis in 0..3 {
        columns[6 + axis] = column(&omega_ddot, axis);
    }
    drop(omega_ddot);
    let a_b: Vec<Vector3<f64>> = (0..data.len())
        .map(|k| {
            reference.f_b_m_s2[k] + reference.q_nb_mid[k].inverse() * reference.g_ned_mid_m_s2[k]
        })
        .collect();
    let a_dot = crate::numeric::central_difference_3(t_s, &a_b);
    for axis in 0..3 {
        columns[9 + axis] = column(&a_b, axis);
        columns[12 + axis] = column(&a_dot, axis);
    }
    columns
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

/// Sample standard deviation.
pub(super) fn std_dev(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
}

/// The spread of each error channel (gx .. az), summed a block at a time: each block's mean
/// and squared deviations, pooled by Chan, Golub and LeVeque's update, so that one block
/// gives [`std_dev`] to the bit and many agree with it to rounding.
#[derive(Debug, Default)]
pub(super) struct ErrorSpread {
    count: [f64; 6],
    mean: [f64; 6],
    squares: [f64; 6],
}

impl ErrorSpread {
    /// Adds epochs `own` of a block's `errors`.
    pub(super) fn add(&mut self, errors: &[Option<Vec<f64>>; 6], own: Range<usize>) {
        for (c, e) in errors.iter().enumerate() {
            let Some(e) = e else { continue };
            let x = &e[own.clone()];
            let n = x.len() as f64;
            if n == 0.0 {
                continue;
            }
            let m = x.iter().sum::<f64>() / n;
            let q: f64 = x.iter().map(|v| (v - m).powi(2)).sum();
            if self.count[c] == 0.0 {
                (self.count[c], self.mean[c], self.squares[c]) = (n, m, q);
                continue;
            }
            let total = self.count[c] + n;
            let delta = m - self.mean[c];
            self.squares[c] += q + delta * delta * self.count[c] * n / total;
            self.mean[c] += delta * n / total;
            self.count[c] = total;
        }
    }

    /// Sample standard deviation of each channel seen.
    pub(super) fn std_dev(&self) -> [Option<f64>; 6] {
        std::array::from_fn(|c| {
            (self.count[c] > 0.0).then(|| (self.squares[c] / (self.count[c] - 1.0)).sqrt())
        })
    }
}

/// Error signals gathered a block at a time: each block's own epochs of its times, errors,
/// dynamics and the reference's specific force, appended in order.
#[derive(Debug, Default)]
pub(super) struct Gathered {
    /// Epochs in all.
    epochs: usize,
    t_s: Vec<f64>,
    errors: [Option<Vec<f64>>; 6],
    dynamics: [Vec<f64>; 15],
    specific_force_b_m_s2: [Vec<f64>; 3],
}

impl Gathered {
    /// Nothing gathered yet, of `epochs` epochs in all.
    pub(super) fn new(epochs: usize) -> Self {
        Self {
            epochs,
            ..Self::default()
        }
    }

    /// Appends epochs `own` of a block: its times `t_s`, its `errors` and `dynamics` (as
    /// [`error_columns`] and [`dynamics_columns`] formed them) and the reference in `data`.
    /// The first block's columns are taken whole when they are all its own (a held block),
    /// so the epochs held whole are not copied.
    pub(super) fn add(
        &mut self,
        t_s: &[f64],
        errors: [Option<Vec<f64>>; 6],
        dynamics: [Vec<f64>; 15],
        data: &EpochData,
        own: Range<usize>,
    ) {
        let whole = self.t_s.is_empty() && own == (0..t_s.len());
        let epochs = self.epochs;
        // Room for every epoch at the first block: grown block by block, a long drive's
        // series would each hold up to twice their length.
        let room = |gathered: &mut Vec<f64>| {
            if gathered.capacity() == 0 {
                gathered.reserve_exact(epochs);
            }
        };
        let append = |gathered: &mut Vec<f64>, column: Vec<f64>| {
            if whole {
                *gathered = column;
            } else {
                room(gathered);
                gathered.extend_from_slice(&column[own.clone()]);
            }
        };
        for (gathered, e) in self.errors.iter_mut().zip(errors) {
            if let Some(e) = e {
                append(gathered.get_or_insert_with(Vec::new), e);
            }
        }
        for (gathered, d) in self.dynamics.iter_mut().zip(dynamics) {
            append(gathered, d);
        }
        for (i, f) in self.specific_force_b_m_s2.iter_mut().enumerate() {
            room(f);
            f.extend(data.reference.f_b_m_s2[own.clone()].iter().map(|v| v[i]));
        }
        room(&mut self.t_s);
        self.t_s.extend_from_slice(&t_s[own]);
    }

    /// The epochs' times gathered so far, s.
    pub(super) fn t_s(&self) -> &[f64] {
        &self.t_s
    }

    /// The error signals gathered.
    pub(super) fn finish(self) -> ErrorSignals {
        ErrorSignals {
            t_s: self.t_s,
            errors: self.errors,
            dynamics: self.dynamics,
            specific_force_b_m_s2: Some(self.specific_force_b_m_s2),
        }
    }
}

/// The error-signal file's row of epoch `k` of a block, in [`ErrorSignalWriter`] order:
/// time, the errors present, the dynamics, the reference's specific force.
///
/// [`ErrorSignalWriter`]: crate::error_signal::ErrorSignalWriter
pub(super) fn file_row(
    t_s: &[f64],
    errors: &[Option<Vec<f64>>; 6],
    dynamics: &[Vec<f64>; 15],
    data: &EpochData,
    k: usize,
    row: &mut Vec<f64>,
) {
    row.clear();
    row.push(t_s[k]);
    row.extend(errors.iter().flatten().map(|e| e[k]));
    row.extend(dynamics.iter().map(|d| d[k]));
    row.extend(data.reference.f_b_m_s2[k].iter());
}

/// The summary of `fit` over the epochs of `grid`, with each error channel's standard
/// deviation and the epochs' median length, s.
pub(super) fn summary(
    fit: Fit,
    grid: &EpochGrid,
    error_std: [Option<f64>; 6],
    epoch_dt_s: f64,
) -> CalibrationSummary {
    let Fit {
        layout,
        r_sb,
        shift_s,
        solution: sol,
        common_time,
        mut notes,
        ..
    } = fit;
    if let Some(c) = common_time.as_ref().filter(|c| !c.inconsistent.is_empty()) {
        notes.push(format!(
            "time offset: {} not consistent with the offset common to the other channels \
             (a channel-specific derivative term, left in the error signal)",
            c.inconsistent
                .iter()
                .map(|(ch, tau)| format!("{} ({:+.5} s)", ch.name(), shift_s + tau))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    CalibrationSummary {
        boresight_rad: Estimate3 {
            value: r_sb.scaled_axis().into(),
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
        reference_kind: if grid.reference_is_imu() {
            "imu"
        } else {
            "navigation_solution"
        }
        .into(),
        epochs: grid.epochs,
        epoch_dt_s,
        error_std,
        hac_lag: sol.lag,
        method: "batch weighted least squares of the linearised eqs. 10-11 with biases and a \
                 time-offset term, iterated on the time offset; 1-sigma from a Newey-West \
                 sandwich over epoch scores"
            .into(),
        notes,
    }
}
