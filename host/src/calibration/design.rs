//! The calibration's linear model at its solution ([`CalibrationDesign`]), which the
//! diagnosis strips candidate regressors with and corrects the calibration's estimates by;
//! its rows are read over the error signals the calibration formed ([`DesignRows`]).

use nalgebra::{DMatrix, DVector, Vector3};

use super::epochs::EpochData;
use super::least_squares::{design_row, normal_matrix_inverse, Layout, MAX_PARAMETERS};
use crate::error_signal::ErrorSignals;

/// The linear model the calibration fitted, at its solution: what it would have absorbed
/// from any other error. The discrepancy engine uses it to estimate per-channel terms
/// jointly with the calibration (Frisch-Waugh: a candidate regressor is first stripped of
/// what the calibration would take from it) and to correct the calibration's estimates for
/// the terms it finds; and it carries the rate of change of specific force the calibration
/// used (9-point stencils at the reference's native rate), which is better than differences
/// at the sensor rate.
///
/// Its rows are computed when asked for ([`CalibrationDesign::over`]), from the reference's
/// rates, angular acceleration and specific force, which the error signals formed with it
/// hold: held whole the rows would take 18 numbers per channel and epoch (864 bytes an
/// epoch), and a copy of those series 72 bytes an epoch.
#[derive(Debug, Clone)]
pub struct CalibrationDesign {
    epochs: usize,
    /// Whether the gyro and the accelerometer channels have rows.
    present: [bool; 2],
    weights: [f64; 2],
    /// (X' W X)^-1.
    bread: DMatrix<f64>,
    layout: Layout,
    /// Rate of change of specific force at the epochs, m/s^3, body (reference) frame.
    pub f_dot_b_m_s3: [Vec<f64>; 3],
}

/// A [`CalibrationDesign`] over the error signals the calibration formed with it: the
/// design's rows, made when asked for from the signals' angular rate (rad/s), angular
/// acceleration (rad/s^2) and specific force (m/s^2), body (reference) frame.
#[derive(Debug, Clone, Copy)]
pub struct DesignRows<'a> {
    design: &'a CalibrationDesign,
    omega_ib_b_rad_s: [&'a [f64]; 3],
    omega_dot_b_rad_s2: [&'a [f64]; 3],
    f_b_m_s2: [&'a [f64]; 3],
}

impl CalibrationDesign {
    /// The design's rows over `signals`, the error signals the calibration formed with it
    /// ([`super::build_error_signals_with_design`]).
    ///
    /// # Panics
    /// If `signals` lack the specific force or their length is not the design's: they are
    /// not the signals this design was formed with.
    pub fn over<'a>(&'a self, signals: &'a ErrorSignals) -> DesignRows<'a> {
        let f = signals
            .specific_force_b_m_s2
            .as_ref()
            .expect("the calibration's error signals carry the specific force");
        let rows = DesignRows {
            design: self,
            omega_ib_b_rad_s: std::array::from_fn(|i| signals.angular_rate_rad_s(i)),
            omega_dot_b_rad_s2: std::array::from_fn(|i| signals.angular_acceleration_rad_s2(i)),
            f_b_m_s2: std::array::from_fn(|i| &f[i][..]),
        };
        let lengths = rows
            .omega_ib_b_rad_s
            .iter()
            .chain(&rows.omega_dot_b_rad_s2)
            .chain(&rows.f_b_m_s2);
        assert!(
            lengths.map(|s| s.len()).all(|len| len == self.epochs),
            "error signals of another length than the calibration design's"
        );
        rows
    }
}

impl DesignRows<'_> {
    /// Index of the lever arm's x component, if estimated.
    pub fn lever_index(&self) -> Option<usize> {
        self.design.layout.lever()
    }
    /// Number of parameters.
    pub fn parameters(&self) -> usize {
        self.design.layout.len()
    }
    /// Number of epochs (rows per channel).
    pub fn epochs(&self) -> usize {
        self.design.epochs
    }
    /// Weight of a channel's rows (0..6, gx..az) in the calibration's least squares.
    pub fn weight(&self, channel: usize) -> f64 {
        self.design.weights[channel / 3]
    }
    /// Whether a channel (0..6, gx..az) has rows.
    pub fn has_channel(&self, channel: usize) -> bool {
        self.design.present[channel / 3]
    }
    /// (X'WX)^-1 of the calibration's weighted least squares.
    pub fn bread(&self) -> &DMatrix<f64> {
        &self.design.bread
    }
    /// The rows of `channel` (0..6, gx..az) at every epoch, in order.
    fn rows(&self, channel: usize) -> impl Iterator<Item = [f64; MAX_PARAMETERS]> + '_ {
        let accel = channel >= 3;
        let count = if self.has_channel(channel) {
            self.epochs()
        } else {
            0
        };
        let f_dot = &self.design.f_dot_b_m_s3;
        (0..count).map(move |k| {
            let at = |v: [&[f64]; 3]| Vector3::new(v[0][k], v[1][k], v[2][k]);
            design_row(
                &self.design.layout,
                &at(self.omega_ib_b_rad_s),
                &at(self.f_b_m_s2),
                &at(self.omega_dot_b_rad_s2),
                &Vector3::new(f_dot[0][k], f_dot[1][k], f_dot[2][k]),
                accel,
                channel % 3,
            )
        })
    }
    /// Moments X_c' W_c y of a series on `channel` with the calibration's columns.
    pub fn moments(&self, channel: usize, y: &[f64]) -> DVector<f64> {
        let p = self.parameters();
        let w = self.weight(channel);
        // Summed in a fixed array, without a vector's checked indexing: the diagnosis takes
        // these moments of every simulated series.
        let mut xtwy = [0.0; MAX_PARAMETERS];
        for (x, v) in self.rows(channel).zip(y) {
            for (sum, x) in xtwy.iter_mut().zip(&x) {
                *sum += w * x * v;
            }
        }
        DVector::from_column_slice(&xtwy[..p])
    }
    /// Moments X' W y of series on all channels at once.
    pub fn moments_all(&self, y: &[Option<&[f64]>; 6]) -> DVector<f64> {
        let mut total = DVector::<f64>::zeros(self.parameters());
        for (ch, series) in y.iter().enumerate() {
            if let Some(series) = series.filter(|_| self.has_channel(ch)) {
                total += self.moments(ch, series);
            }
        }
        total
    }
    /// The calibration parameters taken from errors on all channels at once.
    pub fn absorbed_all(&self, y: &[Option<&[f64]>; 6]) -> DVector<f64> {
        self.bread() * self.moments_all(y)
    }
    /// The fitted error on `channel` of a parameter vector.
    pub fn fitted(&self, channel: usize, theta: &DVector<f64>) -> Vec<f64> {
        let p = self.parameters();
        self.rows(channel)
            .map(|x| (0..p).map(|a| x[a] * theta[a]).sum())
            .collect()
    }
}

/// The sums a [`CalibrationDesign`] is made of, added a block of epochs at a time (one
/// held block gives the design of all epochs at once; many agree with it to rounding).
pub(super) struct DesignSums {
    present: [bool; 2],
    weights: [f64; 2],
    layout: Layout,
    /// X' W X over the epochs added.
    xtwx: DMatrix<f64>,
    epochs: usize,
    f_dot_b_m_s3: [Vec<f64>; 3],
}

impl DesignSums {
    /// No epochs yet (room for `epochs`), for the design of `layout` without its
    /// time-offset columns over a sensor with the gyro and accelerometer channels `present`,
    /// weighted by `weights`.
    pub(super) fn new(
        layout: &Layout,
        weights: [f64; 2],
        present: [bool; 2],
        epochs: usize,
    ) -> Self {
        // The time offset is the one common to the consistent channels, which a
        // channel-specific term does not move: the design the engine strips candidates with
        // holds it fixed.
        let layout = Layout {
            time: false,
            ..*layout
        };
        let p = layout.len();
        Self {
            present,
            weights,
            layout,
            xtwx: DMatrix::zeros(p, p),
            epochs: 0,
            f_dot_b_m_s3: std::array::from_fn(|_| Vec::with_capacity(epochs)),
        }
    }

    /// Adds epochs `own` of `data` (the sensor at the final boresight and time offset).
    pub(super) fn add(&mut self, data: &EpochData, own: std::ops::Range<usize>) {
        let reference = &data.reference;
        let (omega_dot, f_dot) = (&data.omega_dot_b_rad_s2, &data.f_dot_b_m_s3);
        let p = self.layout.len();
        for ch in (0..6).filter(|ch| self.present[ch / 3]) {
            let w = self.weights[ch / 3];
            for k in own.clone() {
                let x = design_row(
                    &self.layout,
                    &reference.omega_ib_b_rad_s[k],
                    &reference.f_b_m_s2[k],
                    &omega_dot[k],
                    &f_dot[k],
                    ch >= 3,
                    ch % 3,
                );
                for a in 0..p {
                    for b in 0..p {
                        self.xtwx[(a, b)] += w * x[a] * x[b];
                    }
                }
            }
        }
        for (i, column) in self.f_dot_b_m_s3.iter_mut().enumerate() {
            column.extend(f_dot[own.clone()].iter().map(|v| v[i]));
        }
        self.epochs += own.len();
    }

    /// The design of the epochs added.
    pub(super) fn finish(self) -> CalibrationDesign {
        let p = self.layout.len();
        CalibrationDesign {
            epochs: self.epochs,
            present: self.present,
            weights: self.weights,
            // The same design with the time columns left out was solvable, so this inverse
            // exists; zeros (nothing absorbed) only guard the impossible case.
            bread: normal_matrix_inverse(&self.xtwx).unwrap_or_else(|| DMatrix::zeros(p, p)),
            layout: self.layout,
            f_dot_b_m_s3: self.f_dot_b_m_s3,
        }
    }
}
