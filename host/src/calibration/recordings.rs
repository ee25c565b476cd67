//! Where the calibration reads its two recordings: held whole in memory ([`ImuRecording`]),
//! or spilled once into a binary file in the temporary folder and read a block of samples at
//! a time ([`SpilledRecording`]), so that `dynacal errors` calibrates recordings of any
//! length in memory that does not grow with them. Both answer the few questions the epoch
//! grid asks ([`Samples`]): how many samples, the time of one, how many lie before a time,
//! and a recording that holds a given range of them.
//!
//! The spill holds the time and the interchange triplets the file has, 8 bytes a value in
//! rows (`t_s`, then gyro, accelerometer, attitude, position, velocity, those present), with
//! every [`INDEX_STRIDE`]-th time kept in memory to find a time by bisection. A CSV is read
//! by the fast block reader where it can (else, and at any row it refuses, again from its
//! start row by row), with the checks [`ImuRecording::read`] makes: finite numbers, strictly increasing
//! time, whole triplets, latitude and longitude in range, a stated rate that agrees with the
//! median step; errors name the file and the line or row.

use std::borrow::Cow;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use super::ErrorsError;
use crate::interchange::fast::for_each_fast_row;
use crate::interchange::summary::interchange_columns;
use crate::interchange::{
    check_lat_lon, check_stated_rate_against, for_each_row, parquet, read_stated_rate,
    ImuRecording, Triplet,
};

/// What the calibration asks of a recording.
pub(crate) trait Samples {
    /// Number of samples.
    fn len(&self) -> usize;
    /// Time of sample `i`, s.
    fn time_s(&self, i: usize) -> Result<f64, ErrorsError>;
    /// Number of samples before `t_s` (at or before it when `inclusive`).
    fn count_before(&self, t_s: f64, inclusive: bool) -> Result<usize, ErrorsError>;
    /// A recording holding samples `range` (and perhaps others), with the index its first
    /// sample has here.
    fn rows(&self, range: Range<usize>) -> Result<(Cow<'_, ImuRecording>, usize), ErrorsError>;
    /// Which of the triplets (gyro, accelerometer, attitude, position, velocity) it has.
    fn triplets(&self) -> [bool; 5];
}

impl Samples for ImuRecording {
    fn len(&self) -> usize {
        self.t_s.len()
    }

    fn time_s(&self, i: usize) -> Result<f64, ErrorsError> {
        Ok(self.t_s[i])
    }

    fn count_before(&self, t_s: f64, inclusive: bool) -> Result<usize, ErrorsError> {
        Ok(if inclusive {
            self.t_s.partition_point(|&s| s <= t_s)
        } else {
            self.t_s.partition_point(|&s| s < t_s)
        })
    }

    /// The whole recording, read in place, when most of it is asked for (epochs formed
    /// whole); otherwise a copy of the samples asked for, so a block's work (the reference's
    /// derivatives) spans the block and not the recording.
    fn rows(&self, range: Range<usize>) -> Result<(Cow<'_, ImuRecording>, usize), ErrorsError> {
        if 2 * range.len() > self.len() {
            return Ok((Cow::Borrowed(self), 0));
        }
        Ok((Cow::Owned(self.rows_in(range.clone())), range.start))
    }

    fn triplets(&self) -> [bool; 5] {
        [
            self.gyro_rad_s.is_some(),
            self.accel_m_s2.is_some(),
            self.attitude_rad.is_some(),
            self.position.is_some(),
            self.velocity_ned_m_s.is_some(),
        ]
    }
}

/// Samples between the times kept in memory.
const INDEX_STRIDE: usize = 4096;

/// An interchange recording read once into a binary spill file.
pub struct SpilledRecording {
    /// The file it was read from (for errors).
    source: PathBuf,
    spill: File,
    present: [bool; 5],
    /// Values a row: the time and three per triplet present.
    width: usize,
    len: usize,
    /// Time of samples 0, INDEX_STRIDE, 2 INDEX_STRIDE, ..., s.
    index_t_s: Vec<f64>,
}

fn spill_error(source: std::io::Error) -> ErrorsError {
    ErrorsError::Spill {
        dir: std::env::temp_dir(),
        source,
    }
}

/// Rows written to a spill file, with every [`INDEX_STRIDE`]-th time kept.
struct SpillWriter {
    out: BufWriter<File>,
    len: usize,
    index_t_s: Vec<f64>,
    bytes: Vec<u8>,
}

impl SpillWriter {
    fn new() -> Result<Self, ErrorsError> {
        let file = tempfile::tempfile().map_err(spill_error)?;
        Ok(Self {
            out: BufWriter::with_capacity(1 << 20, file),
            len: 0,
            index_t_s: Vec::new(),
            bytes: Vec::new(),
        })
    }

    /// Appends a row (time first).
    fn push(&mut self, values: &[f64]) -> Result<(), ErrorsError> {
        if self.len.is_multiple_of(INDEX_STRIDE) {
            self.index_t_s.push(values[0]);
        }
        self.bytes.clear();
        values
            .iter()
            .for_each(|v| self.bytes.extend(v.to_le_bytes()));
        self.out.write_all(&self.bytes).map_err(spill_error)?;
        self.len += 1;
        Ok(())
    }

    /// The spill file, its rows and its index.
    fn finish(self) -> Result<(File, usize, Vec<f64>), ErrorsError> {
        let spill = self
            .out
            .into_inner()
            .map_err(|e| spill_error(e.into_error()))?;
        Ok((spill, self.len, self.index_t_s))
    }
}

/// The CSV at `path` spilled by the fast block reader; `None` where it gives up, or at a row
/// the checks refuse (time not increasing, latitude or longitude out of range): the row
/// reader then reads the file again and names the line.
fn spill_fast(
    path: &Path,
    wanted: &[&str],
    lat_at: Option<usize>,
) -> Result<Option<SpillWriter>, ErrorsError> {
    let mut spill = SpillWriter::new()?;
    let read = for_each_fast_row(path, wanted, |row| -> Result<bool, ErrorsError> {
        if lat_at.is_some_and(|at| check_lat_lon(path, row[0], row[at], row[at + 1]).is_err()) {
            return Ok(false);
        }
        spill.push(row)?;
        Ok(true)
    })?;
    Ok(read.then_some(spill))
}

/// A spill written row by row by a caller that reads its own format (a board log's
/// decoded samples): rows of `t_s` then the triplets `present` says, times increasing.
pub struct SpillBuilder {
    source: PathBuf,
    present: [bool; 5],
    writer: SpillWriter,
}

impl SpillBuilder {
    /// A spill of the samples of `source` (named in errors) with the triplets `present`
    /// (gyro, accelerometer, attitude, position, velocity).
    pub fn new(source: &Path, present: [bool; 5]) -> Result<Self, ErrorsError> {
        Ok(Self {
            source: source.to_path_buf(),
            present,
            writer: SpillWriter::new()?,
        })
    }

    /// Appends a row: the time, then three values per triplet present.
    pub fn push(&mut self, row: &[f64]) -> Result<(), ErrorsError> {
        debug_assert_eq!(
            row.len(),
            1 + 3 * self.present.iter().filter(|p| **p).count()
        );
        self.writer.push(row)
    }

    /// The spilled recording.
    pub fn finish(self) -> Result<SpilledRecording, ErrorsError> {
        let width = 1 + 3 * self.present.iter().filter(|p| **p).count();
        let (spill, len, index_t_s) = self.writer.finish()?;
        Ok(SpilledRecording {
            source: self.source,
            spill,
            present: self.present,
            width,
            len,
            index_t_s,
        })
    }
}

impl SpilledRecording {
    /// Reads the interchange file at `path` (CSV, CSV.gz or Parquet) into a spill file.
    pub fn read(path: &Path) -> Result<Self, ErrorsError> {
        let columns = interchange_columns(path)?;
        let (present, wanted, lat_at) = (columns.whole, columns.wanted, columns.lat_at);
        let fast = if parquet::is_parquet(path) {
            None
        } else {
            spill_fast(path, &wanted, lat_at)?
        };
        let written = match fast {
            Some(written) => written,
            None => {
                let mut spill = SpillWriter::new()?;
                for_each_row(
                    path,
                    &wanted,
                    |_, values: &[f64]| -> Result<(), ErrorsError> {
                        if let Some(at) = lat_at {
                            check_lat_lon(path, values[0], values[at], values[at + 1])?;
                        }
                        spill.push(values)
                    },
                )?;
                spill
            }
        };
        let (spill, len, index_t_s) = written.finish()?;
        let recording = Self {
            source: path.to_path_buf(),
            spill,
            present,
            width: wanted.len(),
            len,
            index_t_s,
        };
        if let Some((place, stated_hz)) = read_stated_rate(path)? {
            let step = recording.median_step_s()?;
            check_stated_rate_against(path, place, stated_hz, step)?;
        }
        Ok(recording)
    }

    /// A recording held in memory written into a spill file (`source` names it in errors),
    /// so it can be dropped: its time and triplets, not its single-axis columns.
    pub fn from_recording(source: &Path, recording: &ImuRecording) -> Result<Self, ErrorsError> {
        let triplets = [
            &recording.gyro_rad_s,
            &recording.accel_m_s2,
            &recording.attitude_rad,
            &recording.position,
            &recording.velocity_ned_m_s,
        ];
        let mut spill = SpillBuilder::new(source, triplets.map(Option::is_some))?;
        let mut row = Vec::with_capacity(16);
        for (k, t_s) in recording.t_s.iter().enumerate() {
            row.clear();
            row.push(*t_s);
            for triplet in triplets.iter().copied().flatten() {
                row.extend(triplet.iter().map(|axis| axis[k]));
            }
            spill.push(&row)?;
        }
        spill.finish()
    }

    /// The file it was read from.
    pub fn source(&self) -> &Path {
        &self.source
    }

    /// The values of rows `range`, row after row.
    fn values(&self, range: Range<usize>) -> Result<Vec<f64>, ErrorsError> {
        let row_bytes = self.width * 8;
        let mut bytes = vec![0u8; range.len() * row_bytes];
        self.spill
            .read_exact_at(&mut bytes, (range.start * row_bytes) as u64)
            .map_err(spill_error)?;
        Ok(bytes
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
            .collect())
    }

    /// Calls `visit` with column `k` of every row (0: the time; then three per triplet
    /// present), in order, read a block at a time.
    fn for_each_in_column(&self, k: usize, mut visit: impl FnMut(f64)) -> Result<(), ErrorsError> {
        let mut start = 0;
        while start < self.len {
            let end = (start + 16 * INDEX_STRIDE).min(self.len);
            let values = self.values(start..end)?;
            values
                .chunks_exact(self.width)
                .for_each(|row| visit(row[k]));
            start = end;
        }
        Ok(())
    }

    /// Calls `visit` with the time of every sample, in order.
    fn for_each_time(&self, visit: impl FnMut(f64)) -> Result<(), ErrorsError> {
        self.for_each_in_column(0, visit)
    }

    /// Column `k` of the spill's rows whole.
    fn column(&self, k: usize) -> Result<Vec<f64>, ErrorsError> {
        let mut column = Vec::with_capacity(self.len);
        self.for_each_in_column(k, |v| column.push(v))?;
        Ok(column)
    }

    /// The times of every sample, s.
    pub fn times_s(&self) -> Result<Vec<f64>, ErrorsError> {
        self.column(0)
    }

    /// The values of channel `channel` (0..6, gx..az: rad/s or m/s^2), None where its
    /// triplet is absent.
    pub fn channel_values(&self, channel: usize) -> Result<Option<Vec<f64>>, ErrorsError> {
        self.channel_column(channel)
            .map(|k| self.column(k))
            .transpose()
    }

    /// Calls `visit` with every value of channel `channel` (0..6, gx..az: rad/s or m/s^2)
    /// in order, read a block at a time; false (nothing visited) where its triplet is
    /// absent.
    pub fn for_each_channel_value(
        &self,
        channel: usize,
        visit: impl FnMut(f64),
    ) -> Result<bool, ErrorsError> {
        match self.channel_column(channel) {
            Some(k) => self.for_each_in_column(k, visit).map(|()| true),
            None => Ok(false),
        }
    }

    /// The spill's column of channel `channel` (0..6), None where its triplet is absent.
    fn channel_column(&self, channel: usize) -> Option<usize> {
        let triplet = channel / 3;
        let before = self.present[..triplet].iter().filter(|p| **p).count();
        self.present[triplet].then_some(1 + 3 * before + channel % 3)
    }

    /// The first step between consecutive times more than half of `median_s` away from it:
    /// the 0-based index of the sample after it and the step, s.
    pub fn first_uneven_step(&self, median_s: f64) -> Result<Option<(usize, f64)>, ErrorsError> {
        let (mut previous, mut index, mut found) = (None::<f64>, 0usize, None);
        self.for_each_time(|t| {
            if let (Some(p), None) = (previous, found) {
                if (t - p - median_s).abs() > 0.5 * median_s {
                    found = Some((index, t - p));
                }
            }
            previous = Some(t);
            index += 1;
        })?;
        Ok(found)
    }

    /// Median step between consecutive times, s (as [`crate::interchange::median_step_s`]).
    pub fn median_step_s(&self) -> Result<Option<f64>, ErrorsError> {
        let steps = self.len.saturating_sub(1) as u64;
        crate::numeric::select_by_passes(steps / 2, |visit| {
            let mut steps = crate::numeric::TimeSteps::new(visit);
            let read = self.for_each_time(|t| steps.push(t));
            steps.finish();
            read
        })
    }
}

impl Samples for SpilledRecording {
    fn len(&self) -> usize {
        self.len
    }

    fn time_s(&self, i: usize) -> Result<f64, ErrorsError> {
        Ok(self.values(i..i + 1)?[0])
    }

    fn count_before(&self, t_s: f64, inclusive: bool) -> Result<usize, ErrorsError> {
        let before = |s: f64| if inclusive { s <= t_s } else { s < t_s };
        // The stride whose first time is the last one before t_s holds the answer.
        let stride = self.index_t_s.partition_point(|&s| before(s));
        if stride == 0 {
            return Ok(0);
        }
        let start = (stride - 1) * INDEX_STRIDE;
        let end = (start + INDEX_STRIDE).min(self.len);
        let values = self.values(start..end)?;
        let within = values
            .chunks_exact(self.width)
            .take_while(|row| before(row[0]))
            .count();
        Ok(start + within)
    }

    fn rows(&self, range: Range<usize>) -> Result<(Cow<'_, ImuRecording>, usize), ErrorsError> {
        let values = self.values(range.clone())?;
        let rows = range.len();
        let column =
            |c: usize| -> Vec<f64> { (0..rows).map(|r| values[r * self.width + c]).collect() };
        let mut next = 1;
        let mut triplets: [Option<Triplet>; 5] = Default::default();
        for (slot, present) in triplets.iter_mut().zip(self.present) {
            if present {
                *slot = Some(std::array::from_fn(|i| column(next + i)));
                next += 3;
            }
        }
        let [gyro_rad_s, accel_m_s2, attitude_rad, position, velocity_ned_m_s] = triplets;
        let recording = ImuRecording {
            t_s: column(0),
            gyro_rad_s,
            accel_m_s2,
            attitude_rad,
            position,
            velocity_ned_m_s,
            ..Default::default()
        };
        Ok((Cow::Owned(recording), range.start))
    }

    fn triplets(&self) -> [bool; 5] {
        self.present
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spilled_file_answers_as_the_recording_read_whole() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.csv");
        let mut text = String::from("# sample_rate_hz: 100\nt_s,gx_rad_s,gy_rad_s,gz_rad_s,roll_rad,pitch_rad,yaw_rad,lat_rad,lon_rad,h_m,az_m_s2\n");
        for k in 0..10_000 {
            let t = 3.0 + k as f64 * 0.01;
            text += &format!(
                "{t},{},{},{},0.1,0.2,0.3,0.8,0.1,{},{}\n",
                0.1 * t,
                -t,
                t * t,
                k,
                9.8
            );
        }
        std::fs::write(&path, text).unwrap();
        let whole = ImuRecording::read(&path).unwrap();
        let spilled = SpilledRecording::read(&path).unwrap();
        assert_eq!(spilled.len(), whole.len());
        assert_eq!(spilled.triplets(), [true, false, true, true, false]);
        for t in [0.0, 3.0, 3.005, 50.0, 52.99, 103.0] {
            for inclusive in [false, true] {
                assert_eq!(
                    spilled.count_before(t, inclusive).unwrap(),
                    whole.count_before(t, inclusive).unwrap(),
                    "{t} {inclusive}"
                );
            }
        }
        let (rows, first) = spilled.rows(4090..4200).unwrap();
        assert_eq!(first, 4090);
        assert_eq!(rows.t_s, whole.t_s[4090..4200]);
        assert_eq!(
            rows.gyro_rad_s.as_ref().unwrap()[2],
            whole.gyro_rad_s.as_ref().unwrap()[2][4090..4200]
        );
        assert_eq!(
            rows.position.as_ref().unwrap()[2],
            whole.position.as_ref().unwrap()[2][4090..4200]
        );
        assert!(rows.accel_m_s2.is_none());
        assert_eq!(
            spilled.median_step_s().unwrap(),
            crate::interchange::median_step_s(&whole.t_s)
        );
    }

    #[test]
    fn a_bad_file_is_refused_as_the_whole_read_refuses_it() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("t_s,gx_rad_s,gy_rad_s\n0,1,2\n", "gz_rad_s"),
            ("t_s,lat_rad,lon_rad,h_m\n0,0.1,0.1,0\n1,57,0.1,0\n", "lat_rad"),
            ("t_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0,1,2,3\n", "line 3"),
            ("# sample_rate_hz: 50\nt_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0.01,1,2,3\n0.02,1,2,3\n", "50"),
            ("t_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,nan,3\n", "line 2"),
        ];
        for (k, (text, named)) in cases.iter().enumerate() {
            let path = dir.path().join(format!("bad{k}.csv"));
            std::fs::write(&path, text).unwrap();
            let whole = ImuRecording::read(&path).unwrap_err().to_string();
            let spilled = SpilledRecording::read(&path).err().unwrap().to_string();
            assert!(spilled.contains(&*path.to_string_lossy()), "{spilled}");
            assert!(spilled.contains(named), "{spilled}");
            assert!(whole.contains(named), "{whole}");
        }
    }
}
