//! The calibration's passes over its epochs. Every statistic of the fit (the normal
//! equations, the residual weights, the scores of the Newey-West sandwich, the error
//! signals and their spread) is summed over the epochs in order, a block at a time, so the
//! same code serves recordings held whole (one block, formed once per time offset and
//! rotation) and recordings streamed from their spill files (blocks of
//! [`BLOCK_EPOCHS`], formed again on every pass, each with the samples either side that
//! its interpolations and differences reach).

use std::ops::Range;

use nalgebra::Rotation3;
use rayon::prelude::*;

use super::epochs::{EpochData, EpochGrid, EpochSource};
use super::recordings::Samples;
use super::ErrorsError;

/// Epochs a streamed block holds (about 13 MiB of formed epochs; one block per core is
/// formed at a time).
pub(super) const BLOCK_EPOCHS: usize = 1 << 16;

/// A streamed block formed: its epoch times, s, its data, and its own epochs among them.
type Formed = (Vec<f64>, EpochData, Range<usize>);

/// A block of epochs formed at one time offset and rotation.
pub(super) struct Block<'b> {
    /// Epoch times, s, of the epochs formed (the block's own and its aprons).
    pub t_s: &'b [f64],
    /// Reference and sensor over them.
    pub data: &'b EpochData,
    /// The block's own epochs among them: statistics sum over these only.
    pub own: Range<usize>,
}

/// Where the epochs come from.
// One per calibration: boxing the larger variant would gain nothing.
#[allow(clippy::large_enum_variant)]
pub(super) enum Epochs<'a> {
    /// Both recordings in memory: one block.
    Held {
        grid: &'a EpochGrid,
        source: EpochSource<'a>,
    },
    /// Recordings read a block at a time.
    Streamed {
        grid: &'a EpochGrid,
        sensor: &'a (dyn Samples + Sync),
        reference: &'a (dyn Samples + Sync),
        block_epochs: usize,
    },
}

impl<'a> Epochs<'a> {
    /// The grid the epochs are on.
    pub(super) fn grid(&self) -> &EpochGrid {
        match self {
            Epochs::Held { grid, .. } | Epochs::Streamed { grid, .. } => grid,
        }
    }

    /// The epochs at time offset `shift_s` (positive: the sensor lags) with the sensor
    /// rotated by `r_sb`, ready to be passed over.
    pub(super) fn at(
        &self,
        shift_s: f64,
        r_sb: Rotation3<f64>,
    ) -> Result<View<'_, 'a>, ErrorsError> {
        Ok(match self {
            Epochs::Held { source, .. } => View::Held {
                t_s: &source.t_s,
                data: source.at(shift_s)?.rotated(&r_sb),
            },
            Epochs::Streamed { .. } => View::Streamed {
                epochs: self,
                shift_s,
                r_sb,
            },
        })
    }
}

/// The epochs at one time offset and rotation.
pub(super) enum View<'s, 'a> {
    Held {
        t_s: &'s [f64],
        data: EpochData,
    },
    Streamed {
        epochs: &'s Epochs<'a>,
        shift_s: f64,
        r_sb: Rotation3<f64>,
    },
}

impl View<'_, '_> {
    /// Calls `visit` with each block in order.
    pub(super) fn pass(
        &self,
        visit: &mut dyn FnMut(&Block) -> Result<(), ErrorsError>,
    ) -> Result<(), ErrorsError> {
        match self {
            View::Held { t_s, data } => visit(&Block {
                t_s,
                data,
                own: 0..data.len(),
            }),
            View::Streamed {
                epochs,
                shift_s,
                r_sb,
            } => {
                let Epochs::Streamed {
                    grid,
                    sensor,
                    reference,
                    block_epochs,
                } = epochs
                else {
                    unreachable!("a streamed view is made of streamed epochs")
                };
                // Blocks are formed on every core a batch at a time (their interpolations
                // are most of a pass), then visited in order.
                let starts: Vec<usize> = (0..grid.epochs).step_by(*block_epochs).collect();
                for batch in starts.chunks(rayon::current_num_threads().max(1)) {
                    let formed: Vec<Result<Formed, ErrorsError>> = batch
                        .par_iter()
                        .map(|&start| {
                            let own = start..(start + block_epochs).min(grid.epochs);
                            let samples = grid.block(*sensor, *reference, own)?;
                            let mut source = EpochSource::new(&samples)?;
                            let data = source.at(*shift_s)?.rotated(r_sb);
                            Ok((std::mem::take(&mut source.t_s), data, samples.own.clone()))
                        })
                        .collect();
                    for block in formed {
                        let (t_s, data, own) = block?;
                        visit(&Block {
                            t_s: &t_s,
                            data: &data,
                            own,
                        })?;
                    }
                }
                Ok(())
            }
        }
    }
}
