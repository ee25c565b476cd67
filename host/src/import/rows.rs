//! Imported sensors as rows. Every importer hands its sensors to a [`SensorRows`] one row at
//! a time, so one reading code either collects recordings in memory ([`Collect`]: what
//! `import_file`, and so every command given a dataset file, uses) or writes interchange
//! files as it reads (`dynacal import`), in memory that does not grow with the file.
//! The text formats read row by row (ADIS16405, MTi-G, PSINS MEMS and FOG, the laser-gyro
//! log, the MPU-9250 rig); the flight logs (ULog, DataFlash) are walked twice, the first walk
//! deciding the outputs and counting the reference's rows, the second handing over each IMU
//! sample and each fix given its attitude; a ROS bag and an Xsens DOT export in two passes
//! likewise. [`replay`] hands over recordings already in memory.
//!
//! The units check ([`CheckUnits`]) judges a sensor by the medians of its first
//! [`UNITS_PROBE_SAMPLES`] samples, the same way on both paths.

use std::path::{Path, PathBuf};

use super::{ImportError, ImportedSensor};
use crate::interchange::{ImuRecording, Table, CHANNEL_COLUMNS};

/// One imported sensor's name and the interchange columns of its rows.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorLayout {
    /// The importer's part of the output name (`imu0`, a log's instance); empty for a
    /// file's only sensor.
    pub name: String,
    /// `t_s` then interchange columns, in the order written.
    pub columns: Vec<&'static str>,
    /// The rate the source states, Hz; `None` lets the written file state its median step's.
    pub rate_hz: Option<f64>,
}

impl SensorLayout {
    /// A three-axis IMU: `t_s`, gyro (rad/s) and accelerometer (m/s^2), body frame.
    pub fn imu(name: impl Into<String>) -> Self {
        let mut columns = vec!["t_s"];
        columns.extend(CHANNEL_COLUMNS);
        Self {
            name: name.into(),
            columns,
            rate_hz: None,
        }
    }
}

/// Where an importer's rows go.
pub trait SensorRows {
    /// The file's sensors, before any row.
    fn begin(&mut self, sensors: Vec<SensorLayout>) -> Result<(), ImportError>;
    /// One row of sensor `sensor` (an index into `begin`'s list), one value per column.
    fn push(&mut self, sensor: usize, row: &[f64]) -> Result<(), ImportError>;
}

/// Gives the sensors their output names: `prefix`, and `prefix-part` for a named part.
pub struct Named<'a> {
    pub inner: &'a mut dyn SensorRows,
    pub prefix: String,
}

impl SensorRows for Named<'_> {
    fn begin(&mut self, sensors: Vec<SensorLayout>) -> Result<(), ImportError> {
        let sensors = sensors
            .into_iter()
            .map(|s| SensorLayout {
                name: match (self.prefix.as_str(), s.name.as_str()) {
                    (prefix, "") => prefix.to_string(),
                    ("", part) => part.to_string(),
                    (prefix, part) => format!("{prefix}-{part}"),
                },
                ..s
            })
            .collect();
        self.inner.begin(sensors)
    }
    fn push(&mut self, sensor: usize, row: &[f64]) -> Result<(), ImportError> {
        self.inner.push(sensor, row)
    }
}

/// Collects the rows into recordings, checked as an interchange file read is.
pub struct Collect {
    path: PathBuf,
    layouts: Vec<SensorLayout>,
    columns: Vec<Vec<Vec<f64>>>,
}

impl Collect {
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            layouts: Vec::new(),
            columns: Vec::new(),
        }
    }

    /// The recordings, in `begin`'s order.
    pub fn into_sensors(self) -> Result<Vec<ImportedSensor>, ImportError> {
        let path = self.path;
        self.layouts
            .into_iter()
            .zip(self.columns)
            .map(|(layout, mut columns)| {
                // Grown a row at a time, a column may hold up to twice its length; a long
                // recording is held for the whole command, so the slack goes back.
                columns.iter_mut().for_each(Vec::shrink_to_fit);
                let table = Table {
                    path: path.clone(),
                    headers: layout.columns.iter().map(|c| c.to_string()).collect(),
                    columns,
                    row_lines: crate::interchange::RowLines::Unknown,
                };
                let recording = ImuRecording {
                    sample_rate_hz: layout.rate_hz,
                    ..ImuRecording::from_table(table)?
                };
                Ok(ImportedSensor {
                    name: layout.name,
                    recording,
                })
            })
            .collect()
    }
}

impl SensorRows for Collect {
    fn begin(&mut self, sensors: Vec<SensorLayout>) -> Result<(), ImportError> {
        self.columns = sensors
            .iter()
            .map(|s| vec![Vec::new(); s.columns.len()])
            .collect();
        self.layouts = sensors;
        Ok(())
    }
    fn push(&mut self, sensor: usize, row: &[f64]) -> Result<(), ImportError> {
        for (column, value) in self.columns[sensor].iter_mut().zip(row) {
            column.push(*value);
        }
        Ok(())
    }
}

/// The recordings an importer streams into `stream`, named by their importer's part, and
/// what the stream returned.
pub fn collect_named<T>(
    path: &Path,
    stream: impl FnOnce(&mut dyn SensorRows) -> Result<T, ImportError>,
) -> Result<(Vec<(String, ImuRecording)>, T), ImportError> {
    let mut collect = Collect::new(path);
    let returned = stream(&mut collect)?;
    let recordings = collect
        .into_sensors()?
        .into_iter()
        .map(|s| (s.name, s.recording))
        .collect();
    Ok((recordings, returned))
}

/// The one recording an importer of one sensor streams into `stream`.
pub fn collect_one(
    path: &Path,
    stream: impl FnOnce(&mut dyn SensorRows) -> Result<(), ImportError>,
) -> Result<ImuRecording, ImportError> {
    let mut collect = Collect::new(path);
    stream(&mut collect)?;
    let mut sensors = collect.into_sensors()?;
    match sensors.len() {
        1 => Ok(sensors.remove(0).recording),
        n => unreachable!("one sensor expected, the importer gave {n}"),
    }
}

/// The layout of a recording read whole, under the importer's part `name`.
pub fn layout(name: impl Into<String>, recording: &ImuRecording) -> SensorLayout {
    SensorLayout {
        name: name.into(),
        columns: recording.named_columns().iter().map(|c| c.0).collect(),
        rate_hz: recording.sample_rate_hz,
    }
}

/// Hands every row of `recording` to `sink` as sensor `sensor` (whose layout is
/// [`layout`]'s).
pub fn push_recording(
    sink: &mut dyn SensorRows,
    sensor: usize,
    recording: &ImuRecording,
) -> Result<(), ImportError> {
    let columns = recording.named_columns();
    let mut row = vec![0.0; columns.len()];
    for i in 0..recording.len() {
        for (value, (_, column)) in row.iter_mut().zip(&columns) {
            *value = column[i];
        }
        sink.push(sensor, &row)?;
    }
    Ok(())
}

/// Hands recordings read whole (named by their importer's part) to `sink`, row by row.
pub fn replay(
    sensors: &[(String, ImuRecording)],
    sink: &mut dyn SensorRows,
) -> Result<(), ImportError> {
    sink.begin(
        sensors
            .iter()
            .map(|(name, r)| layout(name.clone(), r))
            .collect(),
    )?;
    for (k, (_, recording)) in sensors.iter().enumerate() {
        push_recording(sink, k, recording)?;
    }
    Ok(())
}

/// Samples of each sensor the units check looks at: the first 2^18 (44 minutes at 100 Hz),
/// plenty for a median, and a bound on what a long import holds.
pub const UNITS_PROBE_SAMPLES: usize = 1 << 18;

/// Fewest samples the units check judges: a median of fewer says little of a unit.
const MIN_SAMPLES_FOR_UNITS: usize = 100;

/// Largest median |angular rate| an IMU's import is believed in, rad/s: 2000 deg/s, a MEMS
/// gyro's widest range; more is a unit slip (deg/s or counts taken as rad/s).
const MAX_MEDIAN_TURN_RATE_RAD_S: f64 = 35.0;
/// The median |specific force| of a vehicle on Earth is about g whatever it does; outside
/// this band, m/s^2 are not what the file holds (g, or counts).
const MEDIAN_SPECIFIC_FORCE_M_S2: [f64; 2] = [2.0, 50.0];

/// One sensor's norms seen so far by the units check.
struct UnitsProbe {
    name: String,
    gyro_at: Option<usize>,
    accel_at: Option<usize>,
    gyro_norms: Vec<f64>,
    accel_norms: Vec<f64>,
    judged: bool,
}

/// Passes rows on to `inner`, refusing an imported IMU whose values cannot be in the units
/// its importer states (a median angular rate beyond any MEMS gyro, a median specific force
/// far from g). [`CheckUnits::finish`] judges what the probe did not fill.
pub struct CheckUnits<'a> {
    pub inner: &'a mut dyn SensorRows,
    path: PathBuf,
    probes: Vec<UnitsProbe>,
}

impl<'a> CheckUnits<'a> {
    pub fn new(path: &Path, inner: &'a mut dyn SensorRows) -> Self {
        Self {
            inner,
            path: path.to_path_buf(),
            probes: Vec::new(),
        }
    }

    /// Judges the sensors whose probe is not full (those of fewer samples).
    pub fn finish(&mut self) -> Result<(), ImportError> {
        for k in 0..self.probes.len() {
            self.judge(k)?;
        }
        Ok(())
    }

    fn judge(&mut self, k: usize) -> Result<(), ImportError> {
        let probe = &mut self.probes[k];
        if probe.judged {
            return Ok(());
        }
        probe.judged = true;
        let implausible = |message: String| ImportError::Implausible {
            path: self.path.clone(),
            sensor: probe.name.clone(),
            message,
        };
        let median = |norms: &mut Vec<f64>| {
            (norms.len() >= MIN_SAMPLES_FOR_UNITS)
                .then(|| crate::numeric::median(std::mem::take(norms)))
                .flatten()
        };
        if let Some(w) = median(&mut probe.gyro_norms) {
            if w > MAX_MEDIAN_TURN_RATE_RAD_S {
                return Err(implausible(format!(
                    "the median angular rate is {w:.4} rad/s, beyond any MEMS gyro's range: \
                     the file's values are not in the units this dataset's format states"
                )));
            }
        }
        if let Some(f) = median(&mut probe.accel_norms) {
            let [low, high] = MEDIAN_SPECIFIC_FORCE_M_S2;
            if !(low..=high).contains(&f) {
                return Err(implausible(format!(
                    "the median specific force is {f:.4} m/s^2, not about g (9.81): the file's \
                     values are not in the units this dataset's format states"
                )));
            }
        }
        Ok(())
    }
}

impl SensorRows for CheckUnits<'_> {
    fn begin(&mut self, sensors: Vec<SensorLayout>) -> Result<(), ImportError> {
        let triplet_at = |s: &SensorLayout, first: &str| {
            let at = s.columns.iter().position(|c| *c == first)?;
            let whole = s.columns.get(at..at + 3)?;
            let start = CHANNEL_COLUMNS.iter().position(|c| *c == first)?;
            (whole == &CHANNEL_COLUMNS[start..start + 3]).then_some(at)
        };
        self.probes = sensors
            .iter()
            .map(|s| UnitsProbe {
                name: s.name.clone(),
                gyro_at: triplet_at(s, CHANNEL_COLUMNS[0]),
                accel_at: triplet_at(s, CHANNEL_COLUMNS[3]),
                gyro_norms: Vec::new(),
                accel_norms: Vec::new(),
                judged: false,
            })
            .collect();
        self.inner.begin(sensors)
    }

    fn push(&mut self, sensor: usize, row: &[f64]) -> Result<(), ImportError> {
        let probe = &mut self.probes[sensor];
        if !probe.judged {
            let norm = |at: usize| row[at..at + 3].iter().map(|v| v * v).sum::<f64>().sqrt();
            if let Some(at) = probe.gyro_at {
                probe.gyro_norms.push(norm(at));
            }
            if let Some(at) = probe.accel_at {
                probe.accel_norms.push(norm(at));
            }
            if probe.gyro_norms.len().max(probe.accel_norms.len()) >= UNITS_PROBE_SAMPLES {
                self.judge(sensor)?;
            }
        }
        self.inner.push(sensor, row)
    }
}
