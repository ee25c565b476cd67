//! A run read in stretches, so that the analysis holds one stretch at a time and not the
//! run: a recording held whole is one stretch ([`HeldRun`]); the units' files of a long
//! run are each read once into a spill file in the temporary folder (the calibration's
//! [`SpilledRecording`]) and cut into stretches of [`STRETCH_EPOCHS`] shared times
//! ([`SpilledRun`]).
//!
//! A stretch is gridded with [`MARGIN_EPOCHS`] of the run on each side: the units' phases
//! settle, the lagged changes of the rotation reach back, and the spectral derivative's
//! ends, where the FFT sees the stretch as periodic, fall outside the stretch's own samples.
//! Every stretch's grid follows the run's anchor unit, so the stretches' own samples join
//! into the run's grid. Each stretch is checked as a run is (the units sampled together,
//! each covering half its times, on one platform).

use std::ops::Range;
use std::path::PathBuf;

use super::grid::{common_grid, Grid};
use super::{clipping_level, Ranges, RedundancyError};
use crate::calibration::{ErrorsError, Samples, SpilledRecording};
use crate::interchange::ImuRecording;
use crate::wv::{haar_wv, stream::HaarWvStream, WaveletVariance, WvOptions};

/// A stretch of the run on its grid.
pub(super) struct Stretch {
    /// The grid of the stretch with its margins.
    pub grid: Grid,
    /// The grid samples that are the stretch's own.
    pub own: Range<usize>,
    /// The run's index of the first of them.
    pub first_epoch: usize,
}

/// The run, stretch by stretch.
pub(super) trait Stretches {
    /// The units' names, in input order.
    fn names(&self) -> &[String];
    /// Stretches in the run.
    fn count(&self) -> usize;
    /// Sampling interval, s.
    fn dt_s(&self) -> f64;
    /// Calls `each` with every stretch in order.
    fn for_each(
        &mut self,
        each: &mut dyn FnMut(&Stretch) -> Result<(), RedundancyError>,
    ) -> Result<(), RedundancyError>;
    /// Each unit's clipping levels (gyro, accel) as its own data show them.
    fn clipping(&mut self) -> Result<Vec<Ranges>, RedundancyError>;
}

/// A unit's clipping levels from its triads.
fn ranges_of(r: &ImuRecording) -> Ranges {
    let own = |triad: &Option<[Vec<f64>; 3]>| triad.as_ref().and_then(clipping_level);
    [own(&r.gyro_rad_s), own(&r.accel_m_s2)]
}

/// A spill file's error, said of unit `name`.
fn unit_error(name: &str) -> impl Fn(ErrorsError) -> RedundancyError + Copy + '_ {
    move |e| RedundancyError::Unit {
        name: name.to_string(),
        message: e.to_string(),
    }
}

/// Units held whole: one stretch.
pub(super) struct HeldRun<'a> {
    names: Vec<String>,
    units: &'a [(String, ImuRecording)],
    stretch: Stretch,
    dt_s: f64,
}

impl<'a> HeldRun<'a> {
    pub fn new(units: &'a [(String, ImuRecording)], grid: Grid) -> Self {
        let n = grid.t_s.len();
        let dt_s = grid.filled[0].1.median_dt_s();
        Self {
            names: units.iter().map(|(name, _)| name.clone()).collect(),
            units,
            stretch: Stretch {
                grid,
                own: 0..n,
                first_epoch: 0,
            },
            dt_s,
        }
    }
}

impl Stretches for HeldRun<'_> {
    fn names(&self) -> &[String] {
        &self.names
    }

    fn count(&self) -> usize {
        1
    }

    fn dt_s(&self) -> f64 {
        self.dt_s
    }

    fn for_each(
        &mut self,
        each: &mut dyn FnMut(&Stretch) -> Result<(), RedundancyError>,
    ) -> Result<(), RedundancyError> {
        each(&self.stretch)
    }

    fn clipping(&mut self) -> Result<Vec<Ranges>, RedundancyError> {
        Ok(self.units.iter().map(|(_, r)| ranges_of(r)).collect())
    }
}

/// Shared times a stretch of a long run holds as its own: 2^17, 131 s at 1 kHz.
pub const STRETCH_EPOCHS: usize = 1 << 17;
/// Samples of the run gridded on each side of a stretch's own.
pub const MARGIN_EPOCHS: usize = 4096;

/// Units read from their files into spill files, cut into stretches.
pub(super) struct SpilledRun {
    names: Vec<String>,
    units: Vec<SpilledRecording>,
    anchor: usize,
    dt_s: f64,
    /// The times analysed, [from, to), s.
    window_s: (f64, f64),
    /// Where each stretch's own times start (the first at minus infinity), s.
    starts_s: Vec<f64>,
    stretch_epochs: usize,
    /// The only stretch of a short run, gridded once.
    only: Option<Stretch>,
    /// The run on its grid, written by the first pass over a run of several stretches.
    gridded: Option<GridSpill>,
}

/// The run's grid in a spill file, each shared time a row: the time, then per unit whether
/// it has a sample there and its six filled values. The passes after the first read their
/// stretches (margins included) from it instead of gridding the units again: on units with
/// their own crystals the grid carries each sample's motion to its shared time, which cost
/// as much as the rest of a pass.
struct GridSpill {
    file: std::fs::File,
    /// Values a row.
    width: usize,
    /// Each stretch's own shared times, as row ranges.
    stretches: Vec<Range<usize>>,
}

/// Writes the stretches' own rows of the grid as the first pass forms them.
struct GridWriter {
    out: std::io::BufWriter<std::fs::File>,
    width: usize,
    stretches: Vec<Range<usize>>,
    bytes: Vec<u8>,
}

impl GridWriter {
    fn new(units: usize) -> Result<Self, RedundancyError> {
        let file = tempfile::tempfile().map_err(spill_error)?;
        Ok(Self {
            out: std::io::BufWriter::with_capacity(1 << 20, file),
            width: 1 + 7 * units,
            stretches: Vec::new(),
            bytes: Vec::new(),
        })
    }

    fn push(&mut self, stretch: &Stretch) -> Result<(), RedundancyError> {
        use std::io::Write;
        let grid = &stretch.grid;
        for i in stretch.own.clone() {
            self.bytes.clear();
            self.bytes.extend(grid.t_s[i].to_le_bytes());
            for ((_, r), present) in grid.filled.iter().zip(&grid.present) {
                self.bytes
                    .extend(f64::from(u8::from(present[i])).to_le_bytes());
                for triad in [&r.gyro_rad_s, &r.accel_m_s2] {
                    let triad = triad.as_ref().expect("checked: both triads");
                    triad
                        .iter()
                        .for_each(|axis| self.bytes.extend(axis[i].to_le_bytes()));
                }
            }
            self.out.write_all(&self.bytes).map_err(spill_error)?;
        }
        let first = stretch.first_epoch;
        self.stretches.push(first..first + stretch.own.len());
        Ok(())
    }

    fn finish(self) -> Result<GridSpill, RedundancyError> {
        let file = self
            .out
            .into_inner()
            .map_err(|e| spill_error(e.into_error()))?;
        Ok(GridSpill {
            file,
            width: self.width,
            stretches: self.stretches,
        })
    }
}

fn spill_error(e: std::io::Error) -> RedundancyError {
    RedundancyError::Input(format!(
        "writing the grid's spill file in {}: {e}",
        std::env::temp_dir().display()
    ))
}

impl GridSpill {
    /// Stretch `s` with [`MARGIN_EPOCHS`] of the run's grid on each side.
    fn stretch(
        &self,
        s: usize,
        names: &[String],
        anchor: usize,
    ) -> Result<Stretch, RedundancyError> {
        use std::os::unix::fs::FileExt;
        let own = self.stretches[s].clone();
        let epochs = self.stretches.last().map_or(0, |r| r.end);
        let rows = own.start.saturating_sub(MARGIN_EPOCHS)..(own.end + MARGIN_EPOCHS).min(epochs);
        let mut bytes = vec![0u8; rows.len() * self.width * 8];
        self.file
            .read_exact_at(&mut bytes, (rows.start * self.width * 8) as u64)
            .map_err(spill_error)?;
        let values: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
            .collect();
        let n = rows.len();
        let column =
            |c: usize| -> Vec<f64> { (0..n).map(|i| values[i * self.width + c]).collect() };
        let t_s = column(0);
        let units = names.len();
        let grid = Grid {
            present: (0..units)
                .map(|k| column(1 + 7 * k).iter().map(|p| *p != 0.0).collect())
                .collect(),
            filled: names
                .iter()
                .enumerate()
                .map(|(k, name)| {
                    let at = 2 + 7 * k;
                    let recording = ImuRecording {
                        t_s: t_s.clone(),
                        gyro_rad_s: Some(std::array::from_fn(|a| column(at + a))),
                        accel_m_s2: Some(std::array::from_fn(|a| column(at + 3 + a))),
                        ..Default::default()
                    };
                    (name.clone(), recording)
                })
                .collect(),
            offset_s: vec![vec![0.0; n]; units],
            anchor,
            rate_offset: vec![0.0; units],
            t_s,
        };
        Ok(Stretch {
            grid,
            own: own.start - rows.start..own.end - rows.start,
            first_epoch: own.start,
        })
    }
}

/// Samples of a unit read to find its interval.
const INTERVAL_PROBE: usize = 1 << 16;

impl SpilledRun {
    /// The units at `paths`, each spilled once, from `window_s.0` to `window_s.1`, in
    /// stretches of `stretch_epochs` shared times (the run is checked stretch by stretch as
    /// it is read).
    pub fn open(
        paths: &[PathBuf],
        window_s: (f64, f64),
        stretch_epochs: usize,
    ) -> Result<Self, RedundancyError> {
        let units = paths
            .iter()
            // The reader's errors name the file and the line.
            .map(|p| {
                let spilled =
                    SpilledRecording::read(p).map_err(|e| RedundancyError::Input(e.to_string()))?;
                Ok((p.display().to_string(), spilled))
            })
            .collect::<Result<Vec<_>, RedundancyError>>()?;
        Self::new(units, window_s, stretch_epochs)
    }

    /// The spilled units (name, recording), as [`Self::open`].
    pub fn new(
        named: Vec<(String, SpilledRecording)>,
        window_s: (f64, f64),
        stretch_epochs: usize,
    ) -> Result<Self, RedundancyError> {
        let fail = |name: &str, message: String| RedundancyError::Unit {
            name: name.to_string(),
            message,
        };
        let (names, units): (Vec<String>, Vec<SpilledRecording>) = named.into_iter().unzip();
        for (unit, name) in units.iter().zip(&names) {
            let [gyro, accel, ..] = unit.triplets();
            if !(gyro && accel) {
                return Err(fail(
                    name,
                    "needs both a gyro and an accelerometer triad".into(),
                ));
            }
            if unit.len() < 64 {
                return Err(fail(
                    name,
                    format!("{} samples: at least 64 are needed", unit.len()),
                ));
            }
        }
        let mut dt_s = f64::INFINITY;
        let (mut start_s, mut end_s) = (f64::NEG_INFINITY, f64::INFINITY);
        for (unit, name) in units.iter().zip(&names) {
            let first = unit
                .count_before(window_s.0, false)
                .map_err(unit_error(name))?;
            let end = unit
                .count_before(window_s.1, false)
                .map_err(unit_error(name))?;
            if end < first + 2 {
                return Err(fail(
                    name,
                    format!("no samples between {} s and {} s", window_s.0, window_s.1),
                ));
            }
            let probe = unit
                .rows(first..end.min(first + INTERVAL_PROBE))
                .map_err(unit_error(name))?
                .0;
            dt_s = dt_s.min(probe.median_dt_s());
            start_s = start_s.max(unit.time_s(first).map_err(unit_error(name))?);
            end_s = end_s.min(unit.time_s(end - 1).map_err(unit_error(name))?);
        }
        let mut anchor = 0;
        let mut most = 0;
        for (k, (unit, name)) in units.iter().zip(&names).enumerate() {
            let inside = unit.count_before(end_s, true).map_err(unit_error(name))?
                - unit
                    .count_before(start_s, false)
                    .map_err(unit_error(name))?;
            if inside > most {
                (anchor, most) = (k, inside);
            }
        }
        let stretches = ((end_s - start_s) / (stretch_epochs as f64 * dt_s))
            .floor()
            .max(1.0) as usize;
        let starts_s = (0..stretches)
            .map(|s| {
                if s == 0 {
                    f64::NEG_INFINITY
                } else {
                    start_s + (s * stretch_epochs) as f64 * dt_s
                }
            })
            .collect();
        Ok(Self {
            names,
            units,
            anchor,
            dt_s,
            window_s,
            starts_s,
            stretch_epochs,
            only: None,
            gridded: None,
        })
    }

    /// The units' samples from `from_s` to `to_s`, with the margins.
    fn units_between(
        &self,
        from_s: f64,
        to_s: f64,
    ) -> Result<Vec<(String, ImuRecording)>, RedundancyError> {
        let margin_s = MARGIN_EPOCHS as f64 * self.dt_s;
        self.units
            .iter()
            .zip(&self.names)
            .map(|(unit, name)| {
                let error = unit_error(name);
                let from_s = (from_s - margin_s).max(self.window_s.0);
                let to_s = (to_s + margin_s).min(self.window_s.1);
                let first = unit.count_before(from_s, false).map_err(error)?;
                let end = unit.count_before(to_s, false).map_err(error)?;
                Ok((
                    name.clone(),
                    unit.rows(first..end).map_err(error)?.0.into_owned(),
                ))
            })
            .collect()
    }
}

impl SpilledRun {
    /// Stretch `s` on its grid, the run's index of its first own sample `first_epoch`; None
    /// where it has no shared time of its own.
    fn stretch(&self, s: usize, first_epoch: usize) -> Result<Option<Stretch>, RedundancyError> {
        let from_s = self.starts_s[s];
        let to_s = self.starts_s.get(s + 1).copied().unwrap_or(f64::INFINITY);
        let units = self.units_between(from_s, to_s)?;
        let (start_s, end_s) = units
            .iter()
            .filter_map(|(_, r)| r.t_s.first().zip(r.t_s.last()))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (f, l)| {
                (a.min(*f), b.max(*l))
            });
        let within = format!("in the stretch of the run from {start_s:.3} s to {end_s:.3} s");
        // A gap of most of a stretch: held whole, the run would interpolate across it.
        let gap_error = |name: String, message: String| RedundancyError::Unit {
            name,
            message: format!(
                "{message} ({within}: read stretch by stretch, a unit may not miss most of a \
                 stretch; read the run whole with --stream never, or analyse the times before \
                 and after the gap apart with --from-s and --to-s)"
            ),
        };
        if let Some((name, _)) = units.iter().find(|(_, r)| r.len() < 2) {
            return Err(gap_error(name.clone(), "no samples".into()));
        }
        let grid = common_grid(&units, Some(self.anchor)).map_err(|e| match e {
            RedundancyError::Unit { name, message } if message.starts_with("has samples at") => {
                gap_error(name, message)
            }
            RedundancyError::Unit { name, message } => RedundancyError::Unit {
                name,
                message: format!("{message} ({within})"),
            },
            other => other,
        })?;
        let own_start = grid.t_s.partition_point(|t| *t < from_s);
        let own_end = grid.t_s.partition_point(|t| *t < to_s);
        Ok((own_start < own_end).then_some(Stretch {
            grid,
            own: own_start..own_end,
            first_epoch,
        }))
    }
}

impl Stretches for SpilledRun {
    fn names(&self) -> &[String] {
        &self.names
    }

    fn count(&self) -> usize {
        self.starts_s.len()
    }

    fn dt_s(&self) -> f64 {
        self.dt_s
    }

    fn for_each(
        &mut self,
        each: &mut dyn FnMut(&Stretch) -> Result<(), RedundancyError>,
    ) -> Result<(), RedundancyError> {
        if self.starts_s.len() == 1 {
            // A run of one stretch is gridded once, not once a pass.
            if self.only.is_none() {
                self.only = self.stretch(0, 0)?;
            }
            return self.only.as_ref().map_or(Ok(()), each);
        }
        if let Some(gridded) = &self.gridded {
            for s in 0..gridded.stretches.len() {
                each(&gridded.stretch(s, &self.names, self.anchor)?)?;
            }
            return Ok(());
        }
        let mut writer = GridWriter::new(self.names.len())?;
        let mut first_epoch = 0;
        for s in 0..self.starts_s.len() {
            let Some(stretch) = self.stretch(s, first_epoch)? else {
                continue;
            };
            first_epoch += stretch.own.len();
            writer.push(&stretch)?;
            each(&stretch)?;
        }
        self.gridded = Some(writer.finish()?);
        Ok(())
    }

    fn clipping(&mut self) -> Result<Vec<Ranges>, RedundancyError> {
        // A unit clips at its largest value: the largest level any stretch of it shows.
        let mut levels: Vec<Ranges> = vec![[None, None]; self.units.len()];
        for (k, (unit, name)) in self.units.iter().zip(&self.names).enumerate() {
            let error = unit_error(name);
            let mut first = unit.count_before(self.window_s.0, false).map_err(error)?;
            let last = unit.count_before(self.window_s.1, false).map_err(error)?;
            while first < last {
                let end = (first + self.stretch_epochs).min(last);
                let block = ranges_of(&unit.rows(first..end).map_err(error)?.0);
                for (level, found) in levels[k].iter_mut().zip(block) {
                    *level = match (*level, found) {
                        (Some(a), Some(b)) => Some(a.max(b)),
                        (a, b) => a.or(b),
                    };
                }
                first = end;
            }
        }
        Ok(levels)
    }
}

/// The Haar wavelet variance of a series given in pieces, in run order: the batch
/// estimator where the run is one piece, the streaming one ([`HaarWvStream`]: levels past
/// [`HaarWvStream::COMPACT_FULL_LEVELS`] decimated) where it is several.
pub(super) struct PieceWv {
    dt_s: f64,
    estimator: PieceEstimator,
}

enum PieceEstimator {
    Batch(Option<WaveletVariance>),
    Stream(Box<HaarWvStream>),
}

impl PieceWv {
    /// For a run of `pieces` pieces sampled every `dt_s` seconds.
    pub fn new(pieces: usize, dt_s: f64) -> Self {
        let estimator = if pieces <= 1 {
            PieceEstimator::Batch(None)
        } else {
            PieceEstimator::Stream(Box::new(HaarWvStream::new(
                HaarWvStream::COMPACT_FULL_LEVELS,
            )))
        };
        Self { dt_s, estimator }
    }

    /// Adds the next piece of the series.
    pub fn add(&mut self, piece: &[f64]) {
        match &mut self.estimator {
            PieceEstimator::Batch(wv) => {
                assert!(wv.is_none(), "a run of one piece is given one piece");
                *wv = haar_wv(piece, self.dt_s, &WvOptions::default()).ok();
            }
            PieceEstimator::Stream(stream) => stream.push_block(piece),
        }
    }

    /// The wavelet variance and each level's equivalent degrees of freedom; None for a
    /// series too short.
    pub fn result(&self) -> Option<(WaveletVariance, Vec<f64>)> {
        let (wv, full) = match &self.estimator {
            PieceEstimator::Batch(wv) => (wv.clone()?, u32::MAX),
            PieceEstimator::Stream(stream) => (
                stream.wavelet_variance(None, 1.0, self.dt_s).ok()?,
                stream.full_levels(),
            ),
        };
        let eta = wv
            .n_coefficients
            .iter()
            .zip(&wv.levels)
            .map(|(m, j)| {
                if *j <= full {
                    crate::wv::eta3(*m, *j)
                } else {
                    crate::wv::stream::decimated_dof(*m as u64)
                }
            })
            .collect();
        Some((wv, eta))
    }
}
