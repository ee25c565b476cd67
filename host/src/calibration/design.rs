//! The calibration's linear model at its solution ([`CalibrationDesign`]), which the
//! diagnosis strips candidate regressors with and corrects the calibration's estimates by;
//! its rows are read over the error signals the calibration formed ([`DesignRows`]).

use std::ops::Range;

use nalgebra::{DMatrix, DVector, Vector3};

use super::epochs::EpochData;
use super::least_squares::{design_row, normal_matrix_inverse, Layout, MAX_PARAMETERS};
use super::signal_bank::SignalBank;
use crate::error_signal::ErrorSignals;
use crate::series_bank::{block_ranges, SpillError};

/// The linear model the calibration fitted, at its solution: what it would have absorbed
/// from any other error. The discrepancy engine uses it to estimate per-channel terms
/// jointly with the calibration (Frisch-Waugh: a candidate regressor is first stripped of
/// what the calibration would take from it) and to correct the calibration's estimates for
/// the terms it finds; and it carries the rate of change of specific force the calibration
/// used (9-point stencils at the reference's native rate), which is better than differences
/// at the sensor rate.
///
/// Its rows are computed a block of epochs at a time when asked for
/// ([`CalibrationDesign::over`], [`CalibrationDesign::over_bank`]), from the reference's
/// rates, angular acceleration, specific force and its rate, which the error signals formed
/// with it hold: held whole the rows would take 18 numbers per channel and epoch (864 bytes
/// an epoch).
#[derive(Debug, Clone)]
pub struct CalibrationDesign {
    epochs: usize,
    /// Whether the gyro and the accelerometer channels have rows.
    present: [bool; 2],
    weights: [f64; 2],
    /// (X' W X)^-1.
    bread: DMatrix<f64>,
    layout: Layout,
    /// Rate of change of specific force at the epochs, m/s^3, body (reference) frame; empty
    /// where a [`SignalBank`] holds it.
    pub f_dot_b_m_s3: [Vec<f64>; 3],
}

/// A [`CalibrationDesign`] over the error signals the calibration formed with it: the
/// design's rows, made a block of epochs at a time when asked for from the signals' angular
/// rate (rad/s), angular acceleration (rad/s^2), specific force (m/s^2) and its rate
/// (m/s^3), body (reference) frame, held or read back from a [`SignalBank`].
#[derive(Clone, Copy)]
pub struct DesignRows<'a> {
    design: &'a CalibrationDesign,
    dynamics: RowDynamics<'a>,
}

/// Where a design's rows read the dynamics: angular rate, angular acceleration, specific
/// force and its rate, three axes each.
#[derive(Clone, Copy)]
enum RowDynamics<'a> {
    Held([&'a [f64]; 12]),
    Banked(&'a SignalBank),
}

impl std::fmt::Debug for DesignRows<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DesignRows")
            .field("design", self.design)
            .field("banked", &matches!(self.dynamics, RowDynamics::Banked(_)))
            .finish()
    }
}

/// What visits a design's rows a block at a time: the block's epochs and a row per epoch.
type RowsVisit<'v> = dyn FnMut(Range<usize>, &[[f64; MAX_PARAMETERS]]) + 'v;

/// Appends a series over the epochs given to the vector given.
pub type ReadInto<'r, E> = dyn FnMut(Range<usize>, &mut Vec<f64>) -> Result<(), E> + 'r;

/// The bank's series a design's rows are made of, in [`RowDynamics::Held`]'s order.
const BANKED_ROW_SERIES: [usize; 12] = {
    let [w, d, f, j] = [
        SignalBank::ANGULAR_RATE_RAD_S,
        SignalBank::ANGULAR_ACCELERATION_RAD_S2,
        SignalBank::SPECIFIC_FORCE_M_S2,
        SignalBank::SPECIFIC_FORCE_RATE_M_S3,
    ];
    [
        w[0], w[1], w[2], d[0], d[1], d[2], f[0], f[1], f[2], j[0], j[1], j[2],
    ]
};

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
        let series: [&[f64]; 12] = std::array::from_fn(|k| match k / 3 {
            0 => signals.angular_rate_rad_s(k % 3),
            1 => signals.angular_acceleration_rad_s2(k % 3),
            2 => &f[k % 3][..],
            _ => &self.f_dot_b_m_s3[k % 3][..],
        });
        assert!(
            series.iter().all(|s| s.len() == self.epochs),
            "error signals of another length than the calibration design's"
        );
        DesignRows {
            design: self,
            dynamics: RowDynamics::Held(series),
        }
    }

    /// The design's rows over `bank`, the signals the calibration gathered with it
    /// ([`super::build_signal_bank`]).
    ///
    /// # Panics
    /// If the bank's length is not the design's.
    pub fn over_bank<'a>(&'a self, bank: &'a SignalBank) -> DesignRows<'a> {
        assert_eq!(bank.epochs(), self.epochs, "a bank of another run");
        DesignRows {
            design: self,
            dynamics: RowDynamics::Banked(bank),
        }
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

    /// Calls `visit` with each block of the rows of `channel` (0..6, gx..az) over the epochs
    /// `epochs`, in order: the block's epochs and a row per epoch.
    fn for_each_rows(
        &self,
        channel: usize,
        epochs: Range<usize>,
        visit: &mut RowsVisit<'_>,
    ) -> Result<(), SpillError> {
        if !self.has_channel(channel) {
            return Ok(());
        }
        let mut rows = Vec::new();
        let mut block = |range: Range<usize>, series: &[&[f64]]| {
            let at = |first: usize, k: usize| {
                Vector3::new(series[first][k], series[first + 1][k], series[first + 2][k])
            };
            rows.clear();
            rows.extend((0..range.len()).map(|k| {
                design_row(
                    &self.design.layout,
                    &at(0, k),
                    &at(6, k),
                    &at(3, k),
                    &at(9, k),
                    channel >= 3,
                    channel % 3,
                )
            }));
            visit(range, &rows);
        };
        match self.dynamics {
            RowDynamics::Held(series) => {
                for range in block_ranges(epochs) {
                    let views: [&[f64]; 12] = std::array::from_fn(|k| &series[k][range.clone()]);
                    block(range, &views);
                }
                Ok(())
            }
            RowDynamics::Banked(bank) => {
                bank.for_each_block_in(&BANKED_ROW_SERIES, epochs, &mut block)
            }
        }
    }

    /// Moments X_c' W_c y of a series on `channel` with the calibration's columns.
    pub fn moments(&self, channel: usize, y: &[f64]) -> Result<DVector<f64>, SpillError> {
        self.moments_in(channel, 0..y.len().min(self.epochs()), y)
    }
    /// Moments over the epochs `epochs` alone of a series `y` on `channel` given over them
    /// (a series zero elsewhere).
    pub fn moments_in(
        &self,
        channel: usize,
        epochs: Range<usize>,
        y: &[f64],
    ) -> Result<DVector<f64>, SpillError> {
        let p = self.parameters();
        let w = self.weight(channel);
        let first = epochs.start;
        // Summed in a fixed array, without a vector's checked indexing: the diagnosis takes
        // these moments of every simulated series.
        let mut xtwy = [0.0; MAX_PARAMETERS];
        self.for_each_rows(channel, epochs, &mut |range, rows| {
            for (x, v) in rows.iter().zip(&y[range.start - first..range.end - first]) {
                for (sum, x) in xtwy.iter_mut().zip(x) {
                    *sum += w * x * v;
                }
            }
        })?;
        Ok(DVector::from_column_slice(&xtwy[..p]))
    }
    /// [`DesignRows::moments`] of a series over all epochs read a block at a time:
    /// `read(epochs, values)` appends the series over `epochs` to `values`.
    pub fn moments_of_blocks<E: From<SpillError>>(
        &self,
        channel: usize,
        read: &mut ReadInto<'_, E>,
    ) -> Result<DVector<f64>, E> {
        let p = self.parameters();
        let w = self.weight(channel);
        let mut xtwy = [0.0; MAX_PARAMETERS];
        let (mut y, mut failed) = (Vec::new(), None);
        self.for_each_rows(channel, 0..self.epochs(), &mut |range, rows| {
            y.clear();
            if failed.is_some() {
                return;
            }
            if let Err(e) = read(range, &mut y) {
                failed = Some(e);
                return;
            }
            for (x, v) in rows.iter().zip(&y) {
                for (sum, x) in xtwy.iter_mut().zip(x) {
                    *sum += w * x * v;
                }
            }
        })?;
        match failed {
            Some(e) => Err(e),
            None => Ok(DVector::from_column_slice(&xtwy[..p])),
        }
    }
    /// Moments X' W y of series on all channels at once.
    pub fn moments_all(&self, y: &[Option<&[f64]>; 6]) -> Result<DVector<f64>, SpillError> {
        let mut total = DVector::<f64>::zeros(self.parameters());
        for (ch, series) in y.iter().enumerate() {
            if let Some(series) = series.filter(|_| self.has_channel(ch)) {
                total += self.moments(ch, series)?;
            }
        }
        Ok(total)
    }
    /// The calibration parameters taken from errors on all channels at once.
    pub fn absorbed_all(&self, y: &[Option<&[f64]>; 6]) -> Result<DVector<f64>, SpillError> {
        Ok(self.bread() * self.moments_all(y)?)
    }
    /// The fitted error on `channel` of a parameter vector (empty where the channel has no
    /// rows).
    pub fn fitted(&self, channel: usize, theta: &DVector<f64>) -> Result<Vec<f64>, SpillError> {
        self.fitted_in(channel, theta, 0..self.epochs())
    }

    /// [`DesignRows::fitted`] over the epochs `epochs` alone (empty where the channel has
    /// no rows).
    pub fn fitted_in(
        &self,
        channel: usize,
        theta: &DVector<f64>,
        epochs: Range<usize>,
    ) -> Result<Vec<f64>, SpillError> {
        let mut fitted = Vec::with_capacity(if self.has_channel(channel) {
            epochs.len()
        } else {
            0
        });
        self.for_each_fitted(channel, theta, epochs, &mut |_, block| {
            fitted.extend_from_slice(block)
        })?;
        Ok(fitted)
    }

    /// Adds `scale` times the fitted error on `channel` of a parameter vector to a series
    /// `y` given over the epochs `epochs` (nothing where the channel has no rows): how a
    /// block of an error takes a calibration's pull out (`scale` -1) or puts a term's
    /// pushed share in (its coefficient).
    pub fn add_fitted(
        &self,
        channel: usize,
        theta: &DVector<f64>,
        scale: f64,
        epochs: Range<usize>,
        y: &mut [f64],
    ) -> Result<(), SpillError> {
        debug_assert_eq!(y.len(), epochs.len());
        let first = epochs.start;
        self.for_each_fitted(channel, theta, epochs, &mut |range, fitted| {
            y[range.start - first..range.end - first]
                .iter_mut()
                .zip(fitted)
                .for_each(|(v, f)| *v += scale * f);
        })
    }

    /// `visit(epochs, fitted)` for each block of `epochs` in order: the fitted error on
    /// `channel` of a parameter vector over the block (nothing where the channel has no
    /// rows).
    pub fn for_each_fitted(
        &self,
        channel: usize,
        theta: &DVector<f64>,
        epochs: Range<usize>,
        visit: &mut dyn FnMut(Range<usize>, &[f64]),
    ) -> Result<(), SpillError> {
        let p = self.parameters();
        let mut fitted = Vec::new();
        self.for_each_rows(channel, epochs, &mut |range, rows| {
            fitted.clear();
            fitted.extend(
                rows.iter()
                    .map(|x| (0..p).map(|a| x[a] * theta[a]).sum::<f64>()),
            );
            visit(range, &fitted);
        })
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
    /// Whether the specific force's rate is kept (see [`CalibrationDesign::f_dot_b_m_s3`]).
    keep_f_dot: bool,
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
        keep_f_dot: bool,
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
            keep_f_dot,
            f_dot_b_m_s3: std::array::from_fn(|_| {
                Vec::with_capacity(if keep_f_dot { epochs } else { 0 })
            }),
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
        if self.keep_f_dot {
            for (i, column) in self.f_dot_b_m_s3.iter_mut().enumerate() {
                column.extend(f_dot[own.clone()].iter().map(|v| v[i]));
            }
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
