//! The passes `dynacal noise` makes over one IMU's samples, in memory that does not grow
//! with the recording's length: a recording already in memory is walked, a ROS bag's topic
//! is decoded anew each pass (as `imu-calib` and `allan_variance_ros` stream a bag), so an
//! hours-long bag costs what a minute costs; a long interchange file is read anew each pass,
//! and one sensor of a long flight log or text recording imported anew each pass.
//!
//! The first pass (the source's own) gives the time line's summary; the window pass finds
//! the still and moving stretches (the module rule of [`super`]) and the gaps; the
//! wavelet pass feeds each stretch's samples into one streaming Haar accumulator per axis
//! ([`HaarWvStream`]), whose levels up to [`FULL_LEVELS`] are the batch estimator's own
//! (the same sums, to rounding) and higher ones decimated with their wider intervals.
//! Memory: the accumulators' rings (16 bytes x 2^(levels + 1) per axis: 12 MiB for six axes
//! at 16 levels), the window standard deviations (56 bytes per window of about a second:
//! 2 MiB for ten hours), the distinct time steps, and a bag topic's samples where they fit
//! in [`BAG_CACHE_BYTES`] (decoding, not arithmetic, is what a pass costs).

use std::ops::Range;

use super::{axes_of, NoiseError, NoiseOptions, Stillness, Stretch};
use crate::import::ros_bag::{stream_imu_topic, StreamedImu};
use crate::import::rows::{CheckUnits, SensorLayout, SensorRows};
use crate::import::ImportError;
use crate::interchange::{ImuRecording, Sampling, StepCounts, CHANNEL_COLUMNS};
use crate::wv::stream::HaarWvStream;
use crate::wv::{default_max_level, WaveletVariance};

/// Full (overlapping, batch-equal) levels of a still stretch's accumulators: every level of
/// a stretch under 2^18 samples (43 minutes at 100 Hz); longer stretches' top levels are
/// decimated (4/9 of the degrees of freedom). 2 MiB per axis.
pub const FULL_LEVELS: u32 = HaarWvStream::COMPACT_FULL_LEVELS;

/// Samples buffered per axis before they enter an accumulator (its block path is several
/// times faster than one sample at a time, bit for bit the same).
const BLOCK: usize = 4096;

/// One IMU's samples, read in passes.
pub trait ImuSamples {
    /// The channels each sample holds (indices into [`crate::interchange::CHANNELS`]).
    fn channels(&self) -> &[usize];
    /// The time line's summary; its gaps may be left empty (the window pass finds them).
    fn sampling(&self) -> Option<Sampling>;
    /// Calls `each(t_s, values)` for every sample in time order, values in
    /// [`Self::channels`]' order (rad/s, m/s^2, forward-right-down).
    fn pass(&mut self, each: &mut dyn FnMut(f64, &[f64])) -> Result<(), NoiseError>;
}

/// A recording in memory.
pub struct RecordingSamples<'a> {
    rec: &'a ImuRecording,
    channels: Vec<usize>,
    columns: Vec<&'a [f64]>,
}

impl<'a> RecordingSamples<'a> {
    pub fn new(rec: &'a ImuRecording) -> Self {
        let (channels, columns) = axes_of(rec).into_iter().unzip();
        Self {
            rec,
            channels,
            columns,
        }
    }
}

impl ImuSamples for RecordingSamples<'_> {
    fn channels(&self) -> &[usize] {
        &self.channels
    }

    fn sampling(&self) -> Option<Sampling> {
        Sampling::of(&self.rec.t_s)
    }

    fn pass(&mut self, each: &mut dyn FnMut(f64, &[f64])) -> Result<(), NoiseError> {
        let mut values = vec![0.0; self.columns.len()];
        for (i, &t) in self.rec.t_s.iter().enumerate() {
            for (v, column) in values.iter_mut().zip(&self.columns) {
                *v = column[i];
            }
            each(t, &values);
        }
        Ok(())
    }
}

/// An interchange file (CSV, CSV.gz or Parquet) read anew each pass: a recording longer than
/// memory. Its first pass checks it as [`ImuRecording::read`] does (finite numbers, strictly
/// increasing time, whole triplets, a stated rate that agrees with the median step; errors
/// name the line) and counts its time steps.
pub struct FileSamples {
    path: std::path::PathBuf,
    /// `t_s`, then the channels' columns.
    columns: Vec<&'static str>,
    channels: Vec<usize>,
    steps: StepCounts,
    /// Whether the fast block reader takes the file (else the `csv` crate, row by row).
    fast: bool,
}

impl FileSamples {
    /// The first pass over the interchange file at `path`.
    pub fn open(path: &std::path::Path) -> Result<Self, ImportError> {
        use crate::interchange::{summary::interchange_columns, CHANNEL_COLUMNS};
        let found = interchange_columns(path)?;
        let mut channels: Vec<usize> = [(found.whole[0], 0..3), (found.whole[1], 3..6)]
            .into_iter()
            .filter(|(whole, _)| *whole)
            .flat_map(|(_, range)| range)
            .collect();
        channels.extend(&found.lone_axes);
        let mut columns = vec!["t_s"];
        columns.extend(channels.iter().map(|&c| CHANNEL_COLUMNS[c]));
        let mut source = Self {
            path: path.to_path_buf(),
            columns,
            channels,
            steps: StepCounts::default(),
            fast: true,
        };
        let mut steps = StepCounts::default();
        if !source.read(&mut |t_s, _| steps.push(t_s))? {
            source.fast = false;
            steps = StepCounts::default();
            source.read(&mut |t_s, _| steps.push(t_s))?;
        }
        if let Some((place, stated_hz)) = crate::interchange::read_stated_rate(path)? {
            let median = steps.sampling_without_gaps().map(|s| s.median_step_s);
            crate::interchange::check_stated_rate_against(path, place, stated_hz, median)?;
        }
        source.steps = steps;
        Ok(source)
    }

    /// One pass over the file; false where the fast reader gave up (what it passed on is
    /// then to be dropped, and the file read again row by row, whose errors name the line).
    fn read(
        &self,
        each: &mut dyn FnMut(f64, &[f64]),
    ) -> Result<bool, crate::interchange::TableError> {
        use crate::interchange::{fast::for_each_fast_row, for_each_row, TableError};
        if self.fast {
            return for_each_fast_row(
                &self.path,
                &self.columns,
                |row| -> Result<bool, TableError> {
                    each(row[0], &row[1..]);
                    Ok(true)
                },
            );
        }
        for_each_row(
            &self.path,
            &self.columns,
            |_, row: &[f64]| -> Result<(), TableError> {
                each(row[0], &row[1..]);
                Ok(())
            },
        )?;
        Ok(true)
    }
}

impl ImuSamples for FileSamples {
    fn channels(&self) -> &[usize] {
        &self.channels
    }

    fn sampling(&self) -> Option<Sampling> {
        self.steps.sampling_without_gaps()
    }

    fn pass(&mut self, each: &mut dyn FnMut(f64, &[f64])) -> Result<(), NoiseError> {
        match self.read(each) {
            Ok(true) => Ok(()),
            Ok(false) => Err(NoiseError::Recording {
                imu: self.path.display().to_string(),
                message: "the file changed between two passes over it".into(),
            }),
            Err(e) => Err(NoiseError::Read(e.into())),
        }
    }
}

/// A topic of at most this many bytes of samples (8 per value and time: 1.2 million samples
/// of six axes, 3.3 h at 100 Hz) is kept in memory by its first analysis pass, so the bag is
/// decoded twice rather than three times; a longer one is decoded anew each pass.
pub const BAG_CACHE_BYTES: usize = 64 << 20;

/// A ROS bag's Imu topic (in one bag, or split over several files read in order), decoded
/// anew each pass ([`stream_imu_topic`]), or held after one when short
/// ([`BAG_CACHE_BYTES`]).
pub struct BagTopicSamples {
    files: Vec<std::path::PathBuf>,
    topic: String,
    streamed: StreamedImu,
    channels: Vec<usize>,
    steps: StepCounts,
    /// The kept samples' times and values (in [`ImuSamples::channels`] order), once read.
    cache: Option<(Vec<f64>, Vec<f64>)>,
}

impl BagTopicSamples {
    /// The first pass over `files`: what the topic holds, its time steps, and the bags'
    /// notes. `None` when the topic is not a sensor's Imu topic in them (no message, another
    /// type, or all values the same: the whole import says what it is).
    pub fn open(
        files: Vec<std::path::PathBuf>,
        topic: &str,
    ) -> Result<Option<(Self, Vec<String>)>, ImportError> {
        let (mut steps, mut notes, mut found) = (StepCounts::default(), Vec::new(), None);
        for file in &files {
            let mut count = |t_s: f64, _: [f64; 3], _: [f64; 3]| steps.push(t_s);
            let (streamed, report) = stream_imu_topic(file, topic, &mut count)?;
            notes.extend(report.notes);
            found = match (found, streamed) {
                (None, s) | (s, None) => s,
                (Some(a), Some(b)) => Some(StreamedImu {
                    varies: a.varies || b.varies,
                    gyro: a.gyro || b.gyro,
                    accel: a.accel || b.accel,
                    kept: a.kept + b.kept,
                }),
            };
        }
        let Some(streamed) = found.filter(|s| s.varies && s.kept > 0 && (s.gyro || s.accel)) else {
            return Ok(None);
        };
        let channels = [(streamed.gyro, 0..3), (streamed.accel, 3..6)]
            .into_iter()
            .filter(|(present, _)| *present)
            .flat_map(|(_, range)| range)
            .collect();
        let source = Self {
            files,
            topic: topic.to_string(),
            streamed,
            channels,
            steps,
            cache: None,
        };
        Ok(Some((source, notes)))
    }
}

impl ImuSamples for BagTopicSamples {
    fn channels(&self) -> &[usize] {
        &self.channels
    }

    fn sampling(&self) -> Option<Sampling> {
        self.steps.sampling_without_gaps()
    }

    fn pass(&mut self, each: &mut dyn FnMut(f64, &[f64])) -> Result<(), NoiseError> {
        let width = self.channels.len();
        if let Some((t_s, values)) = &self.cache {
            for (t, row) in t_s.iter().zip(values.chunks_exact(width)) {
                each(*t, row);
            }
            return Ok(());
        }
        let (gyro, accel) = (self.streamed.gyro, self.streamed.accel);
        let keep = self.streamed.kept * (width + 1) * 8 <= BAG_CACHE_BYTES;
        let (mut kept_t, mut kept_values) = (Vec::new(), Vec::new());
        let mut values = Vec::with_capacity(6);
        for file in &self.files {
            let mut sink = |t_s: f64, g: [f64; 3], a: [f64; 3]| {
                values.clear();
                if gyro {
                    values.extend(g);
                }
                if accel {
                    values.extend(a);
                }
                each(t_s, &values);
                if keep {
                    kept_t.push(t_s);
                    kept_values.extend_from_slice(&values);
                }
            };
            stream_imu_topic(file, &self.topic, &mut sink)?;
        }
        if keep {
            self.cache = Some((kept_t, kept_values));
        }
        Ok(())
    }
}

/// Welford's running mean and variance.
#[derive(Debug, Clone, Copy, Default)]
struct Running {
    n: f64,
    mean: f64,
    m2: f64,
}

impl Running {
    fn add(&mut self, x: f64) {
        self.n += 1.0;
        let delta = x - self.mean;
        self.mean += delta / self.n;
        self.m2 += delta * (x - self.mean);
    }

    fn std_dev(&self) -> f64 {
        (self.m2 / (self.n - 1.0)).sqrt()
    }
}

/// Runs of equal flags as (flag, range of windows).
fn runs(flags: &[bool]) -> Vec<(bool, Range<usize>)> {
    let mut out: Vec<(bool, Range<usize>)> = Vec::new();
    for (w, &f) in flags.iter().enumerate() {
        match out.last_mut() {
            Some((g, r)) if *g == f => r.end = w + 1,
            _ => out.push((f, w..w + 1)),
        }
    }
    out
}

/// The window pass: where the sensor is still and where it moves (or the span given), and
/// the gaps of the time line (steps over [`Sampling::GAP_STEPS`] median steps).
pub fn stillness_and_gaps(
    source: &mut dyn ImuSamples,
    dt_s: f64,
    opts: &NoiseOptions,
) -> Result<(Stillness, Vec<(f64, f64)>), NoiseError> {
    let axes = source.channels().len();
    let per_window = ((opts.window_s / dt_s).round() as usize).max(16);
    let (mut stds, mut bounds_s) = (vec![Vec::new(); axes], Vec::new());
    let mut window = vec![Running::default(); axes];
    let (mut gaps, mut previous, mut n) = (Vec::new(), None::<f64>, 0usize);
    let mut window_start_s = 0.0;
    let mut span: Option<(usize, usize, f64, f64)> = None;
    source.pass(&mut |t, values| {
        if let Some(p) = previous.filter(|p| t - p > Sampling::GAP_STEPS * dt_s) {
            gaps.push((p, t - p));
        }
        previous = Some(t);
        if opts
            .still_span_s
            .is_some_and(|(from, to)| t >= from && t <= to)
        {
            let s = span.get_or_insert((n, n, t, t));
            (s.1, s.3) = (n, t);
        }
        if n % per_window == 0 {
            window_start_s = t;
        }
        for (w, &v) in window.iter_mut().zip(values) {
            w.add(v);
        }
        if n % per_window == per_window - 1 {
            for (s, w) in stds.iter_mut().zip(&mut window) {
                s.push(w.std_dev());
                *w = Running::default();
            }
            bounds_s.push((window_start_s, t));
        }
        n += 1;
    })?;
    let stillness = match opts.still_span_s {
        Some((from, to)) => Stillness {
            still: span
                .map(|(a, b, from_s, to_s)| Stretch {
                    samples: a..b + 1,
                    from_s,
                    to_s,
                })
                .into_iter()
                .collect(),
            moving: Vec::new(),
            rule: format!("the span given, {from} s to {to} s"),
        },
        None => classify(&stds, &bounds_s, per_window, n, dt_s, opts),
    };
    Ok((stillness, gaps))
}

/// Still and moving stretches from the windows' standard deviations (per axis) and times.
fn classify(
    stds: &[Vec<f64>],
    bounds_s: &[(f64, f64)],
    per_window: usize,
    n: usize,
    dt_s: f64,
    opts: &NoiseOptions,
) -> Stillness {
    if bounds_s.is_empty() {
        return Stillness {
            still: Vec::new(),
            moving: Vec::new(),
            rule: format!("{n} samples, shorter than one window of {per_window}"),
        };
    }
    let floors: Vec<f64> = stds
        .iter()
        .map(|s| {
            let mut sorted = s.clone();
            sorted.sort_by(f64::total_cmp);
            sorted[((sorted.len() - 1) as f64 * 0.02) as usize]
        })
        .collect();
    let still: Vec<bool> = (0..bounds_s.len())
        .map(|w| {
            stds.iter()
                .zip(&floors)
                .all(|(s, floor)| s[w] <= opts.floor_factor * floor)
        })
        .collect();
    let min_windows = (opts.min_still_s / opts.window_s).ceil() as usize;
    let (mut still_out, mut moving_out) = (Vec::new(), Vec::new());
    for (flag, r) in runs(&still) {
        let stretch = Stretch {
            samples: r.start * per_window..r.end * per_window,
            from_s: bounds_s[r.start].0,
            to_s: bounds_s[r.end - 1].1,
        };
        if flag && r.len() >= min_windows.max(1) {
            still_out.push(stretch);
        } else if !flag {
            moving_out.push(stretch);
        }
    }
    Stillness {
        still: still_out,
        moving: moving_out,
        rule: format!(
            "windows of {per_window} samples ({:.3} s) whose every axis' standard deviation is at most {} times its floor (the 2nd percentile of the windows'), in stretches of {} s or more",
            per_window as f64 * dt_s,
            opts.floor_factor,
            opts.min_still_s
        ),
    }
}

/// Per axis, the stretches' wavelet variances.
type PerAxis = Vec<Vec<WaveletVariance>>;

/// One stretch's accumulators, one per axis, with their pending blocks.
struct StretchStreams {
    end: usize,
    still: bool,
    streams: Vec<HaarWvStream>,
    pending: Vec<Vec<f64>>,
}

impl StretchStreams {
    fn flush(&mut self) {
        for (stream, block) in self.streams.iter_mut().zip(&mut self.pending) {
            stream.push_block(block);
            block.clear();
        }
    }
}

/// The wavelet pass: per axis, the still stretches' wavelet variances (each to its own
/// default top level) and the moving stretches' finest level, each list to be pooled.
/// Stretches under 4 samples give none.
pub fn stretch_wavelet_variances(
    source: &mut dyn ImuSamples,
    stillness: &Stillness,
    dt_s: f64,
) -> Result<(PerAxis, PerAxis), NoiseError> {
    let axes = source.channels().len();
    let mut stretches: Vec<(&Stretch, bool)> = stillness
        .still
        .iter()
        .map(|s| (s, true))
        .chain(stillness.moving.iter().map(|s| (s, false)))
        .filter(|(s, _)| s.samples.len() >= 4)
        .collect();
    stretches.sort_by_key(|(s, _)| s.samples.start);
    let (mut still, mut moving) = (vec![Vec::new(); axes], vec![Vec::new(); axes]);
    let (mut next, mut active, mut n) = (0usize, None::<StretchStreams>, 0usize);
    source.pass(&mut |_, values| {
        if active.is_none() && next < stretches.len() && stretches[next].0.samples.start == n {
            let (stretch, is_still) = stretches[next];
            let levels = match is_still {
                true => default_max_level(stretch.samples.len()).min(FULL_LEVELS),
                false => 1,
            };
            active = Some(StretchStreams {
                end: stretch.samples.end,
                still: is_still,
                streams: vec![HaarWvStream::new(levels); axes],
                pending: vec![Vec::with_capacity(BLOCK); axes],
            });
            next += 1;
        }
        n += 1;
        let Some(a) = active.as_mut() else {
            return;
        };
        for (block, &v) in a.pending.iter_mut().zip(values) {
            block.push(v);
        }
        if a.pending[0].len() == BLOCK {
            a.flush();
        }
        if n == a.end {
            a.flush();
            let (into, top) = match a.still {
                true => (&mut still, None),
                false => (&mut moving, Some(1)),
            };
            for (list, stream) in into.iter_mut().zip(&a.streams) {
                list.extend(stream.wavelet_variance(top, 1.0, dt_s).ok());
            }
            active = None;
        }
    })?;
    Ok((still, moving))
}

/// One sensor of a dataset file whose importer streams its rows (a flight log walked twice, a
/// text recording row by row), imported anew each pass ([`crate::import::stream_dataset`]):
/// a recording longer than memory.
pub struct DatasetSamples {
    path: std::path::PathBuf,
    dataset: crate::import::Dataset,
    /// The sensor's place among the importer's sensors.
    sensor: usize,
    /// Where each channel's value is in the sensor's rows.
    columns: Vec<usize>,
    channels: Vec<usize>,
    steps: StepCounts,
}

/// What the first pass over a dataset file found ([`DatasetSamples::survey`]).
pub struct DatasetSurvey {
    /// Every sensor the importer gives, in its order.
    pub layouts: Vec<SensorLayout>,
    /// Each sensor's time steps.
    pub steps: Vec<StepCounts>,
    /// What the importer found worth telling, one line each.
    pub notes: Vec<String>,
}

/// The first pass's sink: every sensor's layout and time steps, its times checked to
/// increase.
struct SurveySink {
    path: std::path::PathBuf,
    layouts: Vec<SensorLayout>,
    steps: Vec<StepCounts>,
}

impl SensorRows for SurveySink {
    fn begin(&mut self, sensors: Vec<SensorLayout>) -> Result<(), ImportError> {
        self.steps = vec![StepCounts::default(); sensors.len()];
        self.layouts = sensors;
        Ok(())
    }

    fn push(&mut self, sensor: usize, row: &[f64]) -> Result<(), ImportError> {
        let steps = &mut self.steps[sensor];
        if let Some(previous_t_s) = steps.last_s().filter(|p| !(row[0] > *p)) {
            return Err(crate::interchange::TableError::TimeNotIncreasingAtSample {
                path: self.path.clone(),
                sample: steps.len() as u64 + 1,
                t_s: row[0],
                previous_t_s,
            }
            .into());
        }
        steps.push(row[0]);
        Ok(())
    }
}

/// A pass's sink: one sensor's rows to the pass's callback.
struct OneSensor<'a> {
    sensor: usize,
    columns: &'a [usize],
    values: Vec<f64>,
    each: &'a mut dyn FnMut(f64, &[f64]),
}

impl SensorRows for OneSensor<'_> {
    fn begin(&mut self, _: Vec<SensorLayout>) -> Result<(), ImportError> {
        Ok(())
    }

    fn push(&mut self, sensor: usize, row: &[f64]) -> Result<(), ImportError> {
        if sensor == self.sensor {
            self.values.clear();
            self.values.extend(self.columns.iter().map(|&c| row[c]));
            (self.each)(row[0], &self.values);
        }
        Ok(())
    }
}

/// What one sensor's layout holds: its channels (indices into [`crate::interchange::CHANNELS`])
/// and where each is in its rows.
pub fn channels_of(layout: &SensorLayout) -> (Vec<usize>, Vec<usize>) {
    CHANNEL_COLUMNS
        .iter()
        .enumerate()
        .filter_map(|(c, name)| Some((c, layout.columns.iter().position(|n| n == name)?)))
        .unzip()
}

impl DatasetSamples {
    /// The first pass over the dataset file `path`: every sensor's layout and time steps,
    /// checked as an import checks them (the units, increasing times), and the importer's
    /// notes.
    pub fn survey(
        path: &std::path::Path,
        dataset: crate::import::Dataset,
    ) -> Result<DatasetSurvey, ImportError> {
        let mut survey = SurveySink {
            path: path.to_path_buf(),
            layouts: Vec::new(),
            steps: Vec::new(),
        };
        let mut checked = CheckUnits::new(path, &mut survey);
        let notes = crate::import::stream_dataset(path, dataset, &mut checked)?;
        checked.finish()?;
        Ok(DatasetSurvey {
            layouts: survey.layouts,
            steps: survey.steps,
            notes,
        })
    }

    /// Sensor `sensor` (of layout `layout` and time steps `steps`, from [`Self::survey`]) of
    /// the dataset file `path`.
    pub fn new(
        path: &std::path::Path,
        dataset: crate::import::Dataset,
        sensor: usize,
        layout: &SensorLayout,
        steps: StepCounts,
    ) -> Self {
        let (channels, columns) = channels_of(layout);
        Self {
            path: path.to_path_buf(),
            dataset,
            sensor,
            columns,
            channels,
            steps,
        }
    }
}

impl ImuSamples for DatasetSamples {
    fn channels(&self) -> &[usize] {
        &self.channels
    }

    fn sampling(&self) -> Option<Sampling> {
        self.steps.sampling_without_gaps()
    }

    fn pass(&mut self, each: &mut dyn FnMut(f64, &[f64])) -> Result<(), NoiseError> {
        let mut sink = OneSensor {
            sensor: self.sensor,
            columns: &self.columns,
            values: Vec::with_capacity(self.columns.len()),
            each,
        };
        crate::import::stream_dataset(&self.path, self.dataset, &mut sink)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wv::{haar_wv, WvOptions};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Three axes at 100 Hz: still (0.01 rad/s white noise) for 300 s, shaken (0.5 rad/s)
    /// for 100 s, still again for 300 s.
    fn still_shaken_still() -> ImuRecording {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5711);
        let n = 70_000;
        let t_s: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
        let column = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f64> {
            (0..n)
                .map(|i| {
                    let sd = if (30_000..40_000).contains(&i) {
                        0.5
                    } else {
                        0.01
                    };
                    Normal::new(0.0, sd).unwrap().sample(rng)
                })
                .collect()
        };
        ImuRecording {
            gyro_rad_s: Some([column(&mut rng), column(&mut rng), column(&mut rng)]),
            t_s,
            ..Default::default()
        }
    }

    /// The passes find the shaking, and each still stretch's accumulated wavelet variance
    /// is the batch estimator's on that stretch.
    #[test]
    fn passes_find_the_motion_and_give_the_batch_wavelet_variance() {
        let rec = still_shaken_still();
        let mut source = RecordingSamples::new(&rec);
        let opts = NoiseOptions::default();
        let (stillness, gaps) = stillness_and_gaps(&mut source, 0.01, &opts).unwrap();
        assert!(gaps.is_empty());
        let spans: Vec<Range<usize>> = stillness.still.iter().map(|s| s.samples.clone()).collect();
        assert_eq!(spans, vec![0..30_000, 40_000..70_000]);
        assert_eq!(stillness.moving.len(), 1);
        assert_eq!(stillness.moving[0].samples, 30_000..40_000);
        let last = &stillness.still[1];
        assert!((last.from_s - 400.0).abs() < 1e-9 && (last.to_s - 699.99).abs() < 1e-9);
        let (still, moving) = stretch_wavelet_variances(&mut source, &stillness, 0.01).unwrap();
        for axis in 0..3 {
            let x = &rec.gyro_rad_s.as_ref().unwrap()[axis];
            for (part, span) in still[axis].iter().zip(&spans) {
                let batch = haar_wv(&x[span.clone()], 0.01, &WvOptions::default()).unwrap();
                assert_eq!(part.levels, batch.levels);
                for (a, b) in part.variance.iter().zip(&batch.variance) {
                    assert!((a / b - 1.0).abs() < 1e-12, "axis {axis}: {a} vs {b}");
                }
            }
            let ratio = (moving[axis][0].variance[0] / still[axis][0].variance[0]).sqrt();
            assert!((ratio / 50.0 - 1.0).abs() < 0.05, "axis {axis}: {ratio}");
        }
    }

    /// A file read in passes gives the report the recording held whole gives, in every
    /// form; a file that breaks is refused naming its line.
    #[test]
    fn a_file_read_in_passes_is_analysed_as_the_recording_held_whole() {
        let rec = ImuRecording {
            sample_rate_hz: Some(100.0),
            ..still_shaken_still()
        };
        let dir = tempfile::tempdir().unwrap();
        let opts = NoiseOptions::default();
        let held = format!("{:?}", super::super::analyse("g", &rec, &opts).unwrap());
        for name in ["g.csv", "g.csv.gz", "g.parquet"] {
            let path = dir.path().join(name);
            rec.write(&path).unwrap();
            let mut source = FileSamples::open(&path).unwrap();
            let report = super::super::analyse_samples("g", &mut source, &opts).unwrap();
            assert_eq!(format!("{report:?}"), held, "{name}");
        }
        let bad = dir.path().join("bad.csv");
        std::fs::write(
            &bad,
            "t_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0.01,1,x,3\n",
        )
        .unwrap();
        let message = FileSamples::open(&bad).err().unwrap().to_string();
        assert!(
            message.contains("bad.csv") && message.contains("line 3"),
            "{message}"
        );
    }

    /// Each IMU of a real flight log, imported anew each pass, gives the report its
    /// recording imported whole gives.
    #[test]
    fn a_flight_logs_imu_imported_each_pass_is_analysed_as_held_whole() {
        use crate::import::{import_file, Dataset};
        // The log, and how many of its IMUs give a report (the PX4 sample is too short for
        // its others).
        let logs = [
            (
                "ardupilot-3imu-copter/log171.bin",
                Dataset::ArduPilotDataFlash,
                3,
            ),
            ("px4-ulog/sample_log_small.ulg", Dataset::Px4ULog, 1),
        ];
        let opts = NoiseOptions::default();
        for (file, dataset, reports) in logs {
            let path = crate::data_dir().join(file);
            if !path.exists() {
                eprintln!("SKIP: {} not found (set DYNACAL_DATA)", path.display());
                continue;
            }
            let held = import_file(&path, dataset).unwrap();
            let DatasetSurvey { layouts, steps, .. } =
                DatasetSamples::survey(&path, dataset).unwrap();
            let names: Vec<&str> = layouts.iter().map(|l| l.name.as_str()).collect();
            let held_names: Vec<&str> = held.iter().map(|s| s.name.as_str()).collect();
            assert_eq!(names, held_names);
            let mut analysed = 0;
            for (k, (layout, steps)) in layouts.iter().zip(steps).enumerate() {
                if channels_of(layout).0.is_empty() {
                    continue;
                }
                let whole = super::super::analyse(&layout.name, &held[k].recording, &opts);
                let mut source = DatasetSamples::new(&path, dataset, k, layout, steps);
                let streamed = super::super::analyse_samples(&layout.name, &mut source, &opts);
                assert_eq!(
                    format!("{streamed:?}"),
                    format!("{whole:?}"),
                    "{}",
                    layout.name
                );
                analysed += usize::from(streamed.is_ok());
            }
            assert_eq!(analysed, reports, "{file}: IMUs analysed");
        }
    }

    /// A span given by time is taken whole, and a gap in the time line is found.
    #[test]
    fn a_given_span_and_a_gap() {
        let mut rec = still_shaken_still();
        for t in &mut rec.t_s[50_000..] {
            *t += 2.0;
        }
        let opts = NoiseOptions {
            still_span_s: Some((100.0, 200.0)),
            ..NoiseOptions::default()
        };
        let mut source = RecordingSamples::new(&rec);
        let (stillness, gaps) = stillness_and_gaps(&mut source, 0.01, &opts).unwrap();
        assert_eq!(stillness.still.len(), 1);
        assert_eq!(stillness.still[0].samples, 10_000..20_001);
        assert_eq!(gaps.len(), 1);
        assert!((gaps[0].0 - 499.99).abs() < 1e-9 && (gaps[0].1 - 2.01).abs() < 1e-9);
    }
}
