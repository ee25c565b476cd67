//! The error signals every stage of a diagnosis reads ([`RunSignals`]): the calibration's
//! [`SignalBank`] (held on a short run, in a temporary file on a long one), read a series, a
//! stretch or a block at a time, so a stage holds the few series it works on rather than
//! every one of the run.

use std::borrow::Cow;
use std::ops::Range;

use super::engine::DiagnoseError;
use super::stats::{with_bank_series, with_bank_series_in, Series};
use crate::calibration::SignalBank;
use crate::model::Channel;

/// See the module documentation.
pub(super) struct RunSignals {
    bank: SignalBank,
}

impl RunSignals {
    pub fn new(bank: SignalBank) -> Self {
        Self { bank }
    }

    /// The bank the signals are read from (what the calibration design's rows read).
    pub fn bank(&self) -> &SignalBank {
        &self.bank
    }

    /// Epochs.
    pub fn epochs(&self) -> usize {
        self.bank.epochs()
    }

    /// Whether the sensor has `channel`.
    pub fn has_error(&self, channel: Channel) -> bool {
        self.bank.error_index(channel).is_some()
    }

    fn error_index(&self, channel: Channel) -> usize {
        self.bank
            .error_index(channel)
            .expect("a channel the sensor has")
    }

    /// `f` of the error of `channel` as a [`Series`]: held, or read a block at a time.
    pub fn with_error<T>(
        &self,
        channel: Channel,
        f: impl FnOnce(&Series) -> T,
    ) -> Result<T, DiagnoseError> {
        Ok(with_bank_series(
            self.bank.series_bank(),
            self.error_index(channel),
            f,
        )?)
    }

    /// `f` of the error of `channel` over the epochs `range` as a [`Series`]: borrowed when
    /// held, read a block at a time when spilled.
    pub fn with_error_in<T>(
        &self,
        channel: Channel,
        range: Range<usize>,
        f: impl FnOnce(&Series) -> T,
    ) -> Result<T, DiagnoseError> {
        Ok(with_bank_series_in(
            self.bank.series_bank(),
            self.error_index(channel),
            range,
            f,
        )?)
    }

    /// The error of `channel` (rad/s or m/s^2, a channel the sensor has) over the epochs
    /// `range`.
    pub fn error_range(
        &self,
        channel: Channel,
        range: Range<usize>,
    ) -> Result<Cow<'_, [f64]>, DiagnoseError> {
        Ok(self.bank.range(self.error_index(channel), range)?)
    }

    /// The time of epoch `k`, s.
    pub fn time_at_s(&self, k: usize) -> Result<f64, DiagnoseError> {
        Ok(self.bank.range(SignalBank::TIME, k..k + 1)?[0])
    }

    /// Series `k` of the bank, or zeros on a run without dynamics (static data).
    fn dynamics(&self, k: usize, range: Range<usize>) -> Result<Cow<'_, [f64]>, DiagnoseError> {
        if self.bank.has_dynamics() {
            Ok(self.bank.range(k, range)?)
        } else {
            Ok(Cow::Owned(vec![0.0; range.len()]))
        }
    }

    /// The reference's angular rate about body axis `axis` over `range`, rad/s (zero on
    /// static data).
    pub fn angular_rate_rad_s(
        &self,
        axis: usize,
        range: Range<usize>,
    ) -> Result<Cow<'_, [f64]>, DiagnoseError> {
        self.dynamics(SignalBank::ANGULAR_RATE_RAD_S[axis], range)
    }

    /// The bank's index of a dynamics series a candidate term reads: the reference's
    /// angular rate, angular acceleration, specific force or its rate about `axis`.
    pub fn dynamics_index(&self, quantity: Dynamics, axis: usize) -> usize {
        assert!(self.bank.has_dynamics(), "a run with a reference");
        match quantity {
            Dynamics::AngularRate => SignalBank::ANGULAR_RATE_RAD_S[axis],
            Dynamics::AngularAcceleration => SignalBank::ANGULAR_ACCELERATION_RAD_S2[axis],
            Dynamics::SpecificForce => SignalBank::SPECIFIC_FORCE_M_S2[axis],
            Dynamics::SpecificForceRate => SignalBank::SPECIFIC_FORCE_RATE_M_S3[axis],
        }
    }

    /// Series `k` of the bank (a dynamics series, by [`RunSignals::dynamics_index`]) over
    /// the epochs `range`.
    pub fn series_in(
        &self,
        k: usize,
        range: Range<usize>,
    ) -> Result<Cow<'_, [f64]>, DiagnoseError> {
        Ok(self.bank.range(k, range)?)
    }

    /// `visit(epochs, |omega| over them)` for each block of `range` in order, rad/s (zero on
    /// static data).
    pub fn for_each_angular_rate_norm(
        &self,
        range: Range<usize>,
        visit: &mut dyn FnMut(Range<usize>, &[f64]),
    ) -> Result<(), DiagnoseError> {
        if !self.bank.has_dynamics() {
            let zeros = vec![0.0; range.len().min(crate::series_bank::BANK_BLOCK_EPOCHS)];
            for block in crate::series_bank::block_ranges(range) {
                let len = block.len();
                visit(block, &zeros[..len]);
            }
            return Ok(());
        }
        let mut norm = Vec::new();
        self.bank
            .for_each_block_in(&SignalBank::ANGULAR_RATE_RAD_S, range, &mut |block, w| {
                norm.clear();
                norm.extend(
                    (0..w[0].len())
                        .map(|k| (w[0][k].powi(2) + w[1][k].powi(2) + w[2][k].powi(2)).sqrt()),
                );
                visit(block, &norm);
            })?;
        Ok(())
    }

    /// The median interval between epochs, s (0 with fewer than two).
    pub fn median_step_s(&self) -> Result<f64, DiagnoseError> {
        Ok(self.bank.median_step_s()?.unwrap_or(0.0))
    }
}

/// The dynamics a candidate term reads, about one body axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Dynamics {
    /// rad/s.
    AngularRate,
    /// rad/s^2.
    AngularAcceleration,
    /// m/s^2.
    SpecificForce,
    /// m/s^3.
    SpecificForceRate,
}
