//! The error signals a diagnosis reads, in a [`SeriesBank`] ([`SignalBank`]): the epochs'
//! times, the reference's angular rate, angular acceleration, specific force and its rate
//! (what the calibration design's rows are made of) and each channel's error, gathered a
//! block of epochs at a time as the calibration forms them. Held on a short run; on a long
//! one in a temporary file, so the calibration and every later stage hold a block of each
//! series at a time, or the few series a stage works on, rather than all of them.

use std::borrow::Cow;
use std::ops::Range;

use nalgebra::Vector3;

use super::epochs::EpochData;
use crate::model::Channel;
use crate::series_bank::{BlockVisit, SeriesBank, SpillError};

/// See the module documentation.
pub struct SignalBank {
    bank: SeriesBank,
    /// Where each channel's error is (gx .. az), `None` for a channel the sensor lacks.
    errors: [Option<usize>; 6],
    /// Whether the dynamics series are there (a reference was calibrated against).
    dynamics: bool,
    /// Epochs gathered so far.
    written: usize,
}

/// Three series of a body-frame vector, x, y, z.
type Axes = [usize; 3];

impl SignalBank {
    /// Epoch times, s.
    pub const TIME: usize = 0;
    /// The reference's angular rate, rad/s, body frame.
    pub const ANGULAR_RATE_RAD_S: Axes = [1, 2, 3];
    /// The reference's angular acceleration, rad/s^2, body frame.
    pub const ANGULAR_ACCELERATION_RAD_S2: Axes = [4, 5, 6];
    /// The reference's specific force, m/s^2, body frame.
    pub const SPECIFIC_FORCE_M_S2: Axes = [7, 8, 9];
    /// The rate of change of the reference's specific force, m/s^3, body frame (9-point
    /// stencils at the reference's native rate).
    pub const SPECIFIC_FORCE_RATE_M_S3: Axes = [10, 11, 12];
    /// Series before the errors on a run with dynamics.
    const DYNAMIC_SERIES: usize = 13;

    /// An empty bank of `epochs` epochs for a sensor whose error channels `present` (gx ..
    /// az) will be gathered with the dynamics, spilled to a temporary file when `spill`.
    pub(super) fn gathering(
        epochs: usize,
        present: [bool; 6],
        spill: bool,
    ) -> Result<Self, SpillError> {
        let errors = error_slots(present, Self::DYNAMIC_SERIES);
        let count = Self::DYNAMIC_SERIES + present.iter().filter(|p| **p).count();
        Ok(Self {
            bank: SeriesBank::columns(epochs, count, spill)?,
            errors,
            dynamics: true,
            written: 0,
        })
    }

    /// The error signals of a run of `n` epochs without dynamics (static data): room for
    /// its times and the errors of the channels `present` (gx .. az), each written in
    /// order a block at a time ([`SignalBank::write_time`], [`SignalBank::write_error`]);
    /// spilled to a temporary file when `spill`.
    pub fn static_run(n: usize, present: [bool; 6], spill: bool) -> Result<Self, SpillError> {
        let slots = error_slots(present, 1);
        let count = 1 + slots.iter().flatten().count();
        Ok(Self {
            bank: SeriesBank::columns(n, count, spill)?,
            errors: slots,
            dynamics: false,
            written: n,
        })
    }

    /// Writes the times (s) of a static run's epochs `start..`.
    pub fn write_time(&mut self, start: usize, t_s: &[f64]) -> Result<(), SpillError> {
        self.bank.write(Self::TIME, start, t_s)
    }

    /// Writes the error of channel `channel` (0..6, gx .. az) of a static run over its
    /// epochs `start..`.
    pub fn write_error(
        &mut self,
        channel: usize,
        start: usize,
        values: &[f64],
    ) -> Result<(), SpillError> {
        let k = self.errors[channel].expect("a channel the run has");
        self.bank.write(k, start, values)
    }

    /// Appends epochs `own` of a block: its times `t_s`, its `errors` (as
    /// [`super::signals::error_columns`] formed them) and the reference's dynamics in `data`.
    pub(super) fn add(
        &mut self,
        t_s: &[f64],
        errors: &[Option<Vec<f64>>; 6],
        data: &EpochData,
        own: Range<usize>,
    ) -> Result<(), SpillError> {
        let start = self.written;
        self.bank.write(Self::TIME, start, &t_s[own.clone()])?;
        let reference = &data.reference;
        let vectors: [(&Axes, &[Vector3<f64>]); 4] = [
            (&Self::ANGULAR_RATE_RAD_S, &reference.omega_ib_b_rad_s),
            (&Self::ANGULAR_ACCELERATION_RAD_S2, &data.omega_dot_b_rad_s2),
            (&Self::SPECIFIC_FORCE_M_S2, &reference.f_b_m_s2),
            (&Self::SPECIFIC_FORCE_RATE_M_S3, &data.f_dot_b_m_s3),
        ];
        let mut column = Vec::with_capacity(own.len());
        for (slots, v) in vectors {
            for (axis, &k) in slots.iter().enumerate() {
                column.clear();
                column.extend(v[own.clone()].iter().map(|x| x[axis]));
                self.bank.write(k, start, &column)?;
            }
        }
        for (slot, e) in self.errors.iter().zip(errors) {
            if let (Some(k), Some(e)) = (slot, e) {
                self.bank.write(*k, start, &e[own.clone()])?;
            }
        }
        self.written += own.len();
        Ok(())
    }

    /// Epochs of every series.
    pub fn epochs(&self) -> usize {
        self.bank.epochs()
    }

    /// The median interval between epochs, s (None with fewer than two), found in passes
    /// over the times rather than from a copy of them.
    pub fn median_step_s(&self) -> Result<Option<f64>, SpillError> {
        let steps = self.epochs().saturating_sub(1) as u64;
        crate::numeric::select_by_passes(steps / 2, |visit| {
            let mut steps = crate::numeric::TimeSteps::new(visit);
            let read = self
                .bank
                .for_each_block_in(&[Self::TIME], 0..self.epochs(), &mut |_, t| {
                    t[0].iter().for_each(|&t| steps.push(t));
                });
            steps.finish();
            read
        })
    }

    /// Whether the series are in a temporary file rather than held.
    pub fn is_spilled(&self) -> bool {
        self.bank.is_spilled()
    }

    /// Whether the reference's dynamics are there (not on static data).
    pub fn has_dynamics(&self) -> bool {
        self.dynamics
    }

    /// Where `channel`'s error is, if the sensor has the channel.
    pub fn error_index(&self, channel: Channel) -> Option<usize> {
        self.errors[channel.index()]
    }

    /// Series `k` whole: borrowed when held, read back when spilled.
    pub fn series(&self, k: usize) -> Result<Cow<'_, [f64]>, SpillError> {
        self.bank.series(k)
    }

    /// The bank of every series.
    pub fn series_bank(&self) -> &SeriesBank {
        &self.bank
    }

    /// Epochs `range` of series `k`.
    pub fn range(&self, k: usize, range: Range<usize>) -> Result<Cow<'_, [f64]>, SpillError> {
        self.bank.range(k, range)
    }

    /// Calls `visit` with each block of the epochs `epochs` in order, and the series
    /// `which` over it.
    pub fn for_each_block_in(
        &self,
        which: &[usize],
        epochs: Range<usize>,
        visit: &mut BlockVisit<'_>,
    ) -> Result<(), SpillError> {
        self.bank.for_each_block_in(which, epochs, visit)
    }
}

/// Slots for the errors `present` (gx .. az), numbered in order from `first`.
fn error_slots(present: [bool; 6], first: usize) -> [Option<usize>; 6] {
    let mut next = first;
    std::array::from_fn(|ch| {
        present[ch].then(|| {
            next += 1;
            next - 1
        })
    })
}
