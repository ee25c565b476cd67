//! The calibration's linear model at its solution ([`CalibrationDesign`]), which the
//! diagnosis strips candidate regressors with and corrects the calibration's estimates by.

use nalgebra::{DMatrix, DVector, Vector3};

use super::epochs::EpochData;
use super::least_squares::{design_row, normal_matrix_inverse, Layout, MAX_PARAMETERS};

/// The linear model the calibration fitted, at its solution: what it would have absorbed
/// from any other error. The discrepancy engine uses it to estimate per-channel terms
/// jointly with the calibration (Frisch-Waugh: a candidate regressor is first stripped of
/// what the calibration would take from it) and to correct the calibration's estimates for
/// the terms it finds; and it carries the epoch derivatives the calibration used (9-point
/// stencils at the reference's native rate), which are better than differences at the
/// sensor rate.
///
/// Its rows are computed when asked for, from the reference's rates and specific force at
/// the epochs: held whole they would take 18 numbers per channel and epoch (864 bytes an
/// epoch), the largest item of a long drive's diagnosis.
#[derive(Debug, Clone)]
pub struct CalibrationDesign {
    epochs: usize,
    /// Whether the gyro and the accelerometer channels have rows.
    present: [bool; 2],
    /// The reference's angular rate and specific force at the epochs (rad/s, m/s^2, body
    /// frame): with the derivatives below, what a row is made of.
    omega_ib_b_rad_s: Vec<Vector3<f64>>,
    f_b_m_s2: Vec<Vector3<f64>>,
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
        self.present[channel / 3]
    }
    /// The rows of `channel` (0..6, gx..az) at every epoch, in order.
    fn rows(&self, channel: usize) -> impl Iterator<Item = [f64; MAX_PARAMETERS]> + '_ {
        let accel = channel >= 3;
        let count = if self.has_channel(channel) {
            self.epochs
        } else {
            0
        };
        (0..count).map(move |k| {
            let at = |v: &[Vec<f64>; 3]| Vector3::new(v[0][k], v[1][k], v[2][k]);
            design_row(
                &self.layout,
                &self.omega_ib_b_rad_s[k],
                &self.f_b_m_s2[k],
                &at(&self.omega_dot_b_rad_s2),
                &at(&self.f_dot_b_m_s3),
                accel,
                channel % 3,
            )
        })
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
        for (x, v) in self.rows(channel).zip(y) {
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
        self.rows(channel)
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

impl CalibrationDesign {
    /// The design of `layout` without its time-offset columns over the epochs of `data`
    /// (the sensor at the final boresight and time offset), weighted by `weights`.
    pub(super) fn new(layout: &Layout, weights: [f64; 2], data: &EpochData) -> Self {
        let n = data.len();
        let reference = &data.reference;
        let (omega_dot, f_dot) = (&data.omega_dot_b_rad_s2, &data.f_dot_b_m_s3);
        // The time offset is the one common to the consistent channels, which a
        // channel-specific term does not move: the design the engine strips candidates with
        // holds it fixed.
        let design_layout = Layout {
            time: false,
            ..*layout
        };
        let p = design_layout.len();
        let mut design = CalibrationDesign {
            epochs: n,
            present: [data.gyro_rad_s.is_some(), data.accel_m_s2.is_some()],
            omega_ib_b_rad_s: reference.omega_ib_b_rad_s.clone(),
            f_b_m_s2: reference.f_b_m_s2.clone(),
            weights,
            bread: DMatrix::zeros(p, p),
            layout: design_layout,
            omega_dot_b_rad_s2: std::array::from_fn(|i| omega_dot.iter().map(|v| v[i]).collect()),
            f_dot_b_m_s3: std::array::from_fn(|i| f_dot.iter().map(|v| v[i]).collect()),
        };
        let mut xtwx = DMatrix::<f64>::zeros(p, p);
        for ch in 0..6 {
            let w = weights[ch / 3];
            for x in design.rows(ch) {
                for a in 0..p {
                    for b in 0..p {
                        xtwx[(a, b)] += w * x[a] * x[b];
                    }
                }
            }
        }
        // The same design with the time columns left out was solvable, so this inverse
        // exists; zeros (nothing absorbed) only guard the impossible case.
        if let Some(bread) = normal_matrix_inverse(&xtwx) {
            design.bread = bread;
        }
        design
    }
}
