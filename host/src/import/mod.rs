//! Importers: turn each measured dataset in the data folder (see its README) into
//! interchange recordings ([`ImuRecording`]) in SI units, with the NED navigation frame and
//! the forward-right-down body frame where the source's frames are known.
//!
//! One module per dataset; [`detect`] recognises a file by its first data line (a binary
//! ArduPilot or PX4 log by its first bytes), and [`import_to_dir`] imports a file or folder and
//! writes one interchange file per sensor, all of them or none. `docs/formats.md` states each
//! conversion.

pub mod adis16405;
pub mod ardupilot_dataflash;
pub mod frames;
#[cfg(test)]
mod fuzz;
pub mod interchange;
pub mod mpu9250_tetra;
pub mod mtig;
pub mod psins_fog_mems;
pub mod psins_lasergyro;
pub mod px4_ulog;
pub mod ros_bag;
pub mod rows;
pub mod xsens_dot;

use std::collections::BTreeMap;
use std::io::{BufRead, Read as _};
use std::path::{Path, PathBuf};

use crate::interchange::{
    open_maybe_gz, FileFormat, ImuRecording, RowWriter, TableError, CHANNELS, CHANNEL_COLUMNS,
};
use crate::output::FileSet;
use rows::{CheckUnits, Collect, Named, SensorLayout, SensorRows};

/// Errors while importing. Each names the file, and the line (1-based) where there is one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// Reading a CSV table or writing an interchange file failed.
    #[error(transparent)]
    Table(#[from] TableError),
    /// A line does not have the dataset's format.
    #[error("{path}: line {line}: {message}")]
    Malformed {
        path: PathBuf,
        line: u64,
        message: String,
    },
    /// A binary file is damaged at a byte offset (of the decompressed data).
    #[error("{path}: byte offset {offset}: {message}")]
    Corrupt {
        path: PathBuf,
        offset: u64,
        message: String,
    },
    /// A file is damaged at a place named by other means than a byte offset (a message's
    /// index and time, a table's row).
    #[error("{path}: {message}")]
    Damaged { path: PathBuf, message: String },
    /// An imported IMU's values cannot be in the units the dataset's format states.
    #[error("{path}: {sensor}: {message}")]
    Implausible {
        path: PathBuf,
        sensor: String,
        message: String,
    },
    /// The file (or no file in the folder) is a dataset this importer knows.
    #[error("{path}: not a dataset dynacal can import: {reason}")]
    UnknownDataset { path: PathBuf, reason: String },
    /// A file or folder could not be read, created or moved.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Two inputs would produce the same output file.
    #[error("{first} and {second} would both be written as {name}")]
    OutputCollision {
        name: String,
        first: PathBuf,
        second: PathBuf,
    },
}

impl ImportError {
    pub(crate) fn malformed(path: &Path, line: u64, message: impl Into<String>) -> Self {
        ImportError::Malformed {
            path: path.to_path_buf(),
            line,
            message: message.into(),
        }
    }
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        ImportError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// The datasets dynacal imports (see the data folder's README).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Dataset {
    /// `adis16405/session*.csv.gz`: ADIS16405 integer counts, 100 Hz.
    Adis16405,
    /// `mtig/gyro_x_contaminated.csv.gz`: Xsens MTi-G gyro X, rad/s, 100 Hz.
    MtigGyroX,
    /// `psins-fog-mems/mems_increments.csv.gz`: MEMS angle/velocity increments, ENU/RFU.
    PsinsMems,
    /// `psins-fog-mems/fog_ins_reference.csv.gz`: FOG INS attitude/velocity/position.
    PsinsFog,
    /// `psins-lasergyro/lasergyro.imu.gz`: PSINS SIMU text log of a ring-laser-gyro IMU.
    PsinsLaserGyro,
    /// `mpu9250x4-tetra-static/static.csv.gz`: four MPU9250 sampled together.
    Mpu9250Tetra,
    /// An ArduPilot DataFlash binary log (`ardupilot-3imu-copter/log171.bin`).
    ArduPilotDataFlash,
    /// An Xsens DOT CSV export (`xsens-dot4-quadrotor/dot*.csv.gz`).
    XsensDot,
    /// A PX4 ULog flight log (`px4-ulog/sample_log_small.ulg`).
    Px4ULog,
    /// A ROS bag: ROS1 `.bag`, or a ROS2 bag's MCAP or SQLite storage file
    /// (`ros-bags/`): its Imu, NavSatFix and Odometry topics.
    RosBag,
    /// An interchange recording (CSV, CSV.gz or Parquet), written again in another form.
    Interchange,
}

impl Dataset {
    /// True when its importer hands over its rows as it reads them, in memory that does not
    /// grow with the file (the text formats row by row, the flight logs, a ROS bag and an
    /// Xsens DOT export in two passes); false for an interchange file (read as one).
    pub fn streams_rows(self) -> bool {
        self != Dataset::Interchange
    }

    /// A short human description.
    pub fn describe(self) -> &'static str {
        match self {
            Dataset::Adis16405 => "ADIS16405 session (integer counts, 100 Hz)",
            Dataset::MtigGyroX => "Xsens MTi-G gyro X (rad/s, 100 Hz)",
            Dataset::PsinsMems => "PSINS MEMS increments (ENU / right-forward-up)",
            Dataset::PsinsFog => "PSINS FOG INS reference (ENU attitude, velocity, position)",
            Dataset::PsinsLaserGyro => "PSINS laser-gyro SIMU log (integer increments)",
            Dataset::Mpu9250Tetra => "4 x MPU9250 tetra static rig",
            Dataset::ArduPilotDataFlash => "ArduPilot DataFlash log (IMU instances, GPS + ATT)",
            Dataset::XsensDot => "Xsens DOT CSV export (sensor axes)",
            Dataset::Px4ULog => "PX4 ULog (IMU topics and instances, GPS + attitude)",
            Dataset::RosBag => "ROS bag (Imu topics, NavSatFix and Odometry references)",
            Dataset::Interchange => "interchange recording (written again in the format asked)",
        }
    }
}

/// Splits a CSV header line into trimmed names.
fn header_fields(line: &str) -> Vec<&str> {
    line.split(',').map(str::trim).collect()
}

/// Recognises a dataset from its first bytes (an ArduPilot DataFlash log: `A3 95 80`, a
/// message header and `FMT`; a PX4 ULog: `ULog 01 12 35`; a Parquet file, taken if it is
/// an interchange recording: `PAR1`) or its first data line (the CSV header, or for the PSINS SIMU
/// log its first numeric line; blank lines and `%` comment lines are skipped; an Xsens DOT
/// header may follow a preamble). `Ok(None)` means "not a known dataset"; errors are I/O
/// failures.
pub fn detect(path: &Path) -> Result<Option<Dataset>, ImportError> {
    // The longest magic: SQLite's 16 bytes (a ROS2 bag's `.db3`).
    let mut head = Vec::with_capacity(16);
    open_maybe_gz(path)?
        .take(16)
        .read_to_end(&mut head)
        .map_err(|e| ImportError::io(path, e))?;
    if ardupilot_dataflash::is_dataflash(&head) {
        return Ok(Some(Dataset::ArduPilotDataFlash));
    }
    if px4_ulog::is_ulog(&head) {
        return Ok(Some(Dataset::Px4ULog));
    }
    if ros_bag::is_bag(path, &head) {
        return Ok(Some(Dataset::RosBag));
    }
    if crate::interchange::parquet::is_parquet(path) {
        return Ok(interchange::is_interchange(path).then_some(Dataset::Interchange));
    }
    let Some((_, line)) = first_data_line(path)? else {
        return Ok(None);
    };
    let fields = header_fields(&line);
    let dataset = if fields == adis16405::COLUMNS {
        Some(Dataset::Adis16405)
    } else if fields == mtig::COLUMNS {
        Some(Dataset::MtigGyroX)
    } else if fields == psins_fog_mems::MEMS_COLUMNS {
        Some(Dataset::PsinsMems)
    } else if fields == psins_fog_mems::FOG_COLUMNS {
        Some(Dataset::PsinsFog)
    } else if fields == mpu9250_tetra::columns() {
        Some(Dataset::Mpu9250Tetra)
    } else if psins_lasergyro::parse_numbers(&line).is_some_and(|v| v.len() == 6) {
        Some(Dataset::PsinsLaserGyro)
    } else if xsens_dot::find_header(path)?.is_some() {
        Some(Dataset::XsensDot)
    } else if interchange::is_interchange(path) {
        Some(Dataset::Interchange)
    } else {
        None
    };
    Ok(dataset)
}

/// The first line that is neither blank nor a `%` comment, with its 1-based line number.
/// Reads at most 64 KiB of it, so a binary file costs nothing.
fn first_data_line(path: &Path) -> Result<Option<(u64, String)>, ImportError> {
    let reader = open_maybe_gz(path)?;
    let mut reader = std::io::BufReader::new(reader.take(1 << 20));
    let mut buf = Vec::new();
    let mut line_no = 0;
    loop {
        buf.clear();
        let n = (&mut reader)
            .take(1 << 16)
            .read_until(b'\n', &mut buf)
            .map_err(|e| ImportError::io(path, e))?;
        if n == 0 {
            return Ok(None);
        }
        line_no += 1;
        let text = String::from_utf8_lossy(&buf);
        let text = text.trim();
        if !text.is_empty() && !text.starts_with('%') {
            return Ok(Some((line_no, text.to_string())));
        }
    }
}

/// One sensor's imported recording and the interchange file stem it is written under.
#[derive(Debug, Clone)]
pub struct ImportedSensor {
    /// Output file name without `.csv.gz`, e.g. `adis16405-session1`, `psins-mems`.
    pub name: String,
    pub recording: ImuRecording,
}

/// Imports one dataset file into its sensors' recordings. What the importer found worth
/// telling (a ROS bag's per-topic report) goes to stderr; [`import_file_noted`] returns it.
pub fn import_file(path: &Path, dataset: Dataset) -> Result<Vec<ImportedSensor>, ImportError> {
    let (sensors, notes) = import_file_noted(path, dataset)?;
    for note in notes {
        eprintln!("{}: {note}", path.display());
    }
    Ok(sensors)
}

/// Imports only the topic `topic` of the ROS bag `path` (the others are counted, not
/// decoded), checked as [`import_file_noted`] checks every sensor.
pub fn import_bag_topic(
    path: &Path,
    topic: &str,
) -> Result<(Vec<ImportedSensor>, Vec<String>), ImportError> {
    let mut collect = Collect::new(path);
    let mut checked = CheckUnits::new(path, &mut collect);
    let report = ros_bag::stream(path, Some(topic), &mut checked)?;
    checked.finish()?;
    Ok((collect.into_sensors()?, report.notes))
}

/// Imports one dataset file into its sensors' recordings, with the importer's notes (one
/// line each).
pub fn import_file_noted(
    path: &Path,
    dataset: Dataset,
) -> Result<(Vec<ImportedSensor>, Vec<String>), ImportError> {
    let mut collect = Collect::new(path);
    let mut checked = CheckUnits::new(path, &mut collect);
    let notes = stream_dataset(path, dataset, &mut checked)?;
    checked.finish()?;
    Ok((collect.into_sensors()?, notes))
}

/// Streams the sensors of `path`, as its dataset's importer reads them, into `sink`, each
/// named as its output file is (`adis16405-session1`, `mpu9250-imu0`...). Returns what the
/// importer found worth telling the user (a ROS bag's report per topic), one line each.
pub(crate) fn stream_dataset(
    path: &Path,
    dataset: Dataset,
    sink: &mut dyn SensorRows,
) -> Result<Vec<String>, ImportError> {
    let stem = file_stem(path);
    let prefix = match dataset {
        Dataset::Adis16405 => format!("adis16405-{stem}"),
        Dataset::MtigGyroX => format!("mtig-{stem}"),
        Dataset::PsinsMems => "psins-mems".into(),
        Dataset::PsinsFog => "psins-fog".into(),
        Dataset::PsinsLaserGyro => "psins-lasergyro".into(),
        Dataset::Mpu9250Tetra => "mpu9250".into(),
        Dataset::ArduPilotDataFlash => format!("ardupilot-{stem}"),
        Dataset::XsensDot => format!("xsens-{stem}-imu"),
        Dataset::Px4ULog => format!("px4-{stem}"),
        // Named after their topics alone: a ROS1 bag and its ROS2 conversion give the
        // same files.
        Dataset::RosBag => String::new(),
        Dataset::Interchange => stem,
    };
    let sink = &mut Named {
        inner: sink,
        prefix,
    };
    let streamed = match dataset {
        Dataset::RosBag => return Ok(ros_bag::stream(path, None, sink)?.notes),
        Dataset::Adis16405 => adis16405::stream(path, sink),
        Dataset::MtigGyroX => mtig::stream(path, sink),
        Dataset::PsinsMems => psins_fog_mems::stream_mems(path, sink),
        Dataset::PsinsFog => psins_fog_mems::stream_fog(path, sink),
        Dataset::PsinsLaserGyro => psins_lasergyro::stream(path, sink).map(|_| ()),
        Dataset::Mpu9250Tetra => mpu9250_tetra::stream(path, sink),
        Dataset::ArduPilotDataFlash => ardupilot_dataflash::stream(path, sink),
        Dataset::XsensDot => xsens_dot::stream(path, sink).map(|_| ()),
        Dataset::Px4ULog => px4_ulog::stream(path, sink),
        Dataset::Interchange => interchange::stream(path, sink),
    };
    streamed.map(|()| Vec::new())
}

/// The file name without directory and without `.gz` / `.csv` / `.imu` / `.bin` / `.ulg`
/// suffixes.
pub(crate) fn file_stem(path: &Path) -> String {
    let mut name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    for suffix in [
        ".gz", ".csv", ".imu", ".bin", ".BIN", ".ulg", ".parquet", ".bag", ".mcap", ".db3",
    ] {
        if let Some(s) = name.strip_suffix(suffix) {
            name = s.to_string();
        }
    }
    name
}

/// Dataset files found (path and dataset), and the other files seen.
pub type DatasetFiles = (Vec<(PathBuf, Dataset)>, Vec<PathBuf>);

/// The dataset files under `path`: the file itself (an error if it is not a known dataset),
/// or every known dataset file in the folder and its subfolders, in name order. The second
/// list holds the folder's files that are not datasets (READMEs, JSON...).
pub fn find_datasets(path: &Path) -> Result<DatasetFiles, ImportError> {
    let meta = std::fs::metadata(path).map_err(|e| ImportError::io(path, e))?;
    if !meta.is_dir() {
        return match detect(path)? {
            Some(d) => Ok((vec![(path.to_path_buf(), d)], Vec::new())),
            None => Err(ImportError::UnknownDataset {
                path: path.to_path_buf(),
                reason: match first_data_line(path)? {
                    Some((line, text)) => format!(
                        "line {line} `{}` matches no known dataset header",
                        text.chars().take(80).collect::<String>()
                    ),
                    None => "no data line".into(),
                },
            }),
        };
    }
    let mut found = Vec::new();
    let mut skipped = Vec::new();
    walk(path, &mut found, &mut skipped)?;
    if found.is_empty() {
        return Err(ImportError::UnknownDataset {
            path: path.to_path_buf(),
            reason: "the folder holds no known dataset file".into(),
        });
    }
    Ok((found, skipped))
}

fn walk(
    dir: &Path,
    found: &mut Vec<(PathBuf, Dataset)>,
    skipped: &mut Vec<PathBuf>,
) -> Result<(), ImportError> {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| ImportError::io(dir, e))?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()
        .map_err(|e| ImportError::io(dir, e))?;
    entries.sort();
    for entry in entries {
        if entry.is_dir() {
            walk(&entry, found, skipped)?;
        } else {
            match detect(&entry)? {
                Some(d) => found.push((entry, d)),
                None => skipped.push(entry),
            }
        }
    }
    Ok(())
}

/// One interchange file written by [`import_to_dir`].
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenFile {
    /// The interchange file written.
    pub path: PathBuf,
    /// The dataset file it came from, and its dataset.
    pub source: PathBuf,
    pub dataset: Dataset,
    pub samples: usize,
    /// Last minus first sample time, s.
    pub duration_s: f64,
    /// What the file holds: IMU channel names (`gx` ... `az`) and `attitude`, `position`,
    /// `velocity_ned` where present.
    pub contents: Vec<&'static str>,
    /// Columns of the source not carried into the file (an interchange recording's columns
    /// that are not the format's); empty for the datasets, whose columns are all converted.
    pub left_out: Vec<String>,
}

/// What [`import_to_dir`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportReport {
    pub written: Vec<WrittenFile>,
    /// Files in the input folder that are not datasets, left alone.
    pub skipped: Vec<PathBuf>,
    /// What the importers found worth telling (a ROS bag's per-topic report): the source
    /// file and one line.
    pub notes: Vec<(PathBuf, String)>,
}

/// The contents of a recording, as listed in [`WrittenFile::contents`].
pub fn contents(rec: &ImuRecording) -> Vec<&'static str> {
    let columns: Vec<&str> = rec.named_columns().iter().map(|c| c.0).collect();
    contents_of(&columns)
}

/// What interchange columns hold, as listed in [`WrittenFile::contents`].
pub fn contents_of(columns: &[&str]) -> Vec<&'static str> {
    let mut out: Vec<&'static str> = CHANNELS
        .iter()
        .zip(CHANNEL_COLUMNS)
        .filter(|(_, column)| columns.contains(column))
        .map(|(name, _)| *name)
        .collect();
    for (name, first_column) in [
        ("attitude", "roll_rad"),
        ("velocity_ned", "vn_m_s"),
        ("position", "lat_rad"),
    ] {
        if columns.contains(&first_column) {
            out.push(name);
        }
    }
    out
}

/// Imports the dataset file or folder `input` and writes one `<name>.csv.gz` interchange
/// file per sensor into `out_dir` (created if needed). The text formats are converted row
/// by row, in memory that does not depend on their length (see [`rows`]).
///
/// All or nothing: every file is first written into a private staging folder inside
/// `out_dir`, and moved into place only once every input has imported; on any error the
/// staging folder is removed and `out_dir` is left as it was (or absent, if it was).
pub fn import_to_dir(
    input: &Path,
    out_dir: &Path,
    format: FileFormat,
) -> Result<ImportReport, ImportError> {
    let (datasets, skipped) = find_datasets(input)?;
    // No completion marker: each sensor's file is a recording on its own.
    let mut set = FileSet::create(out_dir, None).map_err(|e| ImportError::io(out_dir, e))?;
    let mut sources: BTreeMap<String, PathBuf> = BTreeMap::new();
    let mut written = Vec::new();
    let mut notes = Vec::new();
    for (source, dataset) in datasets {
        let mut files = WriteFiles {
            set: &mut set,
            sources: &mut sources,
            source: &source,
            format,
            writers: Vec::new(),
        };
        let mut checked = CheckUnits::new(&source, &mut files);
        let found = stream_dataset(&source, dataset, &mut checked)?;
        checked.finish()?;
        notes.extend(found.into_iter().map(|note| (source.clone(), note)));
        for (file_name, columns, writer) in files.writers {
            let rows = writer.finish()?;
            written.push(WrittenFile {
                path: out_dir.join(&file_name),
                source: source.clone(),
                dataset,
                samples: rows.rows as usize,
                duration_s: rows.last_t_s - rows.first_t_s,
                contents: contents_of(&columns),
                left_out: match dataset {
                    Dataset::Interchange => interchange::left_out_columns(&source)?,
                    _ => Vec::new(),
                },
            });
        }
    }
    set.commit().map_err(|e| ImportError::io(out_dir, e))?;
    Ok(ImportReport {
        written,
        skipped,
        notes,
    })
}

/// Writes each sensor of one dataset file into its staged interchange file as rows come.
struct WriteFiles<'a> {
    set: &'a mut FileSet,
    /// The dataset file each output name came from, over the whole import.
    sources: &'a mut BTreeMap<String, PathBuf>,
    source: &'a Path,
    format: FileFormat,
    /// Output file name, columns, writer.
    writers: Vec<(String, Vec<&'static str>, RowWriter)>,
}

impl SensorRows for WriteFiles<'_> {
    fn begin(&mut self, sensors: Vec<SensorLayout>) -> Result<(), ImportError> {
        for sensor in sensors {
            let file_name = format!("{}.{}", sensor.name, self.format.extension());
            if let Some(first) = self.sources.get(&file_name) {
                return Err(ImportError::OutputCollision {
                    name: file_name,
                    first: first.clone(),
                    second: self.source.to_path_buf(),
                });
            }
            self.sources
                .insert(file_name.clone(), self.source.to_path_buf());
            let path = self.set.path(&file_name);
            let writer = RowWriter::create(&path, sensor.columns.clone(), sensor.rate_hz)?;
            self.writers.push((file_name, sensor.columns, writer));
        }
        Ok(())
    }

    fn push(&mut self, sensor: usize, row: &[f64]) -> Result<(), ImportError> {
        Ok(self.writers[sensor].2.push(row)?)
    }
}

/// Reads from `reader` until `buf` is full or the input ends; the number of bytes read.
pub(crate) fn read_up_to(
    reader: &mut impl std::io::Read,
    buf: &mut [u8],
) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match reader.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

/// The time of sample `k` (0-based) of a file with no time column: `k / rate_hz`, s.
pub(crate) fn uniform_time_s(k: u64, rate_hz: f64) -> f64 {
    k as f64 / rate_hz
}

/// Reads a CSV with exactly the header `columns`, giving each data row to `row` with its
/// 1-based line number (header = line 1). Used where fields need checks `read_table` does not
/// make (integer counts).
pub(crate) fn for_each_csv_row(
    path: &Path,
    columns: &[&str],
    mut row: impl FnMut(u64, &csv::StringRecord) -> Result<(), ImportError>,
) -> Result<(), ImportError> {
    let reader = open_maybe_gz(path)?;
    let mut csv = crate::interchange::csv_reader(reader, false);
    let csv_err = |e: csv::Error| {
        let line = e.position().map_or(0, |p| p.line());
        match e.into_kind() {
            csv::ErrorKind::Io(source) => ImportError::io(path, source),
            csv::ErrorKind::UnequalLengths {
                expected_len, len, ..
            } => {
                ImportError::malformed(path, line, format!("{len} fields, expected {expected_len}"))
            }
            other => ImportError::malformed(path, line, format!("{other:?}")),
        }
    };
    let header: Vec<String> = csv
        .headers()
        .map_err(csv_err)?
        .iter()
        .map(str::to_string)
        .collect();
    if header != columns {
        return Err(ImportError::malformed(
            path,
            1,
            format!(
                "header `{}`, expected `{}`",
                header.join(","),
                columns.join(",")
            ),
        ));
    }
    let mut record = csv::StringRecord::new();
    while csv.read_record(&mut record).map_err(csv_err)? {
        let line = record.position().map_or(0, |p| p.line());
        row(line, &record)?;
    }
    Ok(())
}

/// Reads a numeric CSV that must have all of `columns` (others are ignored), giving `row`
/// each data row's 1-based line and values in `columns` order, one row at a time
/// ([`crate::interchange::for_each_row`]'s checks). The importers that use it read text.
pub(crate) fn for_each_column_row(
    path: &Path,
    columns: &[&str],
    mut row: impl FnMut(u64, &[f64]) -> Result<(), ImportError>,
) -> Result<(), ImportError> {
    crate::interchange::for_each_row(path, columns, |place, values| match place {
        crate::interchange::RowPlace::Line(line) | crate::interchange::RowPlace::Row(line) => {
            row(line, values)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn detects_each_dataset_by_its_first_line() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let mpu_header = mpu9250_tetra::columns().join(",");
        let cases = [
            (
                "a.csv",
                "gx,gy,gz,ax,ay,az\n1,2,3,4,5,6\n".to_string(),
                Some(Dataset::Adis16405),
            ),
            ("b.csv", "gx_rad_s\n0.1\n".into(), Some(Dataset::MtigGyroX)),
            (
                "c.csv",
                format!("{}\n", psins_fog_mems::MEMS_COLUMNS.join(",")),
                Some(Dataset::PsinsMems),
            ),
            (
                "d.csv",
                format!("{}\n", psins_fog_mems::FOG_COLUMNS.join(",")),
                Some(Dataset::PsinsFog),
            ),
            (
                "e.imu",
                "% comment\n\n0 0 -90.6 0 0 0\n".into(),
                Some(Dataset::PsinsLaserGyro),
            ),
            (
                "f.csv",
                format!("{mpu_header}\n"),
                Some(Dataset::Mpu9250Tetra),
            ),
            (
                "i.csv",
                "SampleTimeFine,Euler_X,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z,\n".into(),
                Some(Dataset::XsensDot),
            ),
            (
                "j.csv",
                "Xsens DOT export\n\nPacketCounter,SampleTimeFine,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z\n"
                    .into(),
                Some(Dataset::XsensDot),
            ),
            // The DJI flight record beside the DOT files is not imported.
            (
                "airdata.csv",
                "time(millisecond),datetime(utc),latitude,longitude\n".into(),
                None,
            ),
            // An interchange file is taken last, to be written again in another form; a
            // time column alone is not one.
            ("g.csv", "t_s,gx_rad_s\n0,1\n".into(), Some(Dataset::Interchange)),
            ("k.csv", "t_s,temperature_c\n0,1\n".into(), None),
            ("h.txt", "% only comments\n".into(), None),
        ];
        for (name, text, expected) in cases {
            let path = write(d, name, &text);
            assert_eq!(detect(&path).unwrap(), expected, "{name}");
        }
        // A DataFlash log: a message header and the FMT type; binary bytes after a text-like
        // start are not one.
        let bin = d.join("log1.bin");
        std::fs::write(&bin, [0xA3, 0x95, 0x80, 0x80, 89, 0, 0xFF]).unwrap();
        assert_eq!(detect(&bin).unwrap(), Some(Dataset::ArduPilotDataFlash));
        std::fs::write(&bin, [0xA3, 0x95, 0x81, 0x00]).unwrap();
        assert_eq!(detect(&bin).unwrap(), None);
        // A ULog file by its magic; a shorter or different start is not one.
        let ulg = d.join("log.ulg");
        std::fs::write(&ulg, b"ULog\x01\x12\x35\x01").unwrap();
        assert_eq!(detect(&ulg).unwrap(), Some(Dataset::Px4ULog));
        std::fs::write(&ulg, b"ULog\x01\x12").unwrap();
        assert_eq!(detect(&ulg).unwrap(), None);
    }

    #[test]
    fn unknown_file_and_empty_folder_are_errors_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(dir.path(), "notes.csv", "time,value\n0,1\n");
        let msg = find_datasets(&path).unwrap_err().to_string();
        assert!(
            msg.contains("notes.csv") && msg.contains("time,value"),
            "{msg}"
        );
        let msg = find_datasets(dir.path()).unwrap_err().to_string();
        assert!(msg.contains("no known dataset"), "{msg}");
    }

    #[test]
    fn folder_import_writes_all_files_or_none() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in");
        std::fs::create_dir(&input).unwrap();
        write(
            &input,
            "session1.csv",
            "gx,gy,gz,ax,ay,az\n1,2,3,4,5,-300\n2,3,4,5,6,-301\n",
        );
        write(&input, "README.md", "# not data\n");
        let out = dir.path().join("out");
        let report = import_to_dir(&input, &out, FileFormat::CsvGz).unwrap();
        assert_eq!(report.written.len(), 1);
        let w = &report.written[0];
        assert_eq!(w.path, out.join("adis16405-session1.csv.gz"));
        assert_eq!((w.samples, w.duration_s), (2, 0.01));
        assert_eq!(w.contents, vec!["gx", "gy", "gz", "ax", "ay", "az"]);
        assert_eq!(report.skipped, vec![input.join("README.md")]);
        let rec = ImuRecording::read(&w.path).unwrap();
        assert_eq!(
            rec.channel("az").unwrap()[1],
            -301.0 * adis16405::ADIS16405_ACCEL_M_S2_PER_COUNT
        );

        // A second, malformed session: nothing new appears and no staging folder is left.
        write(
            &input,
            "session2.csv",
            "gx,gy,gz,ax,ay,az\n1,2,3,4,5,6\n1,2,x,4,5,6\n",
        );
        let out2 = dir.path().join("out2");
        let msg = import_to_dir(&input, &out2, FileFormat::CsvGz)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("session2.csv") && msg.contains("line 3"),
            "{msg}"
        );
        assert!(
            !out2.exists(),
            "a folder made for a failed import is removed"
        );
    }

    #[test]
    fn a_long_import_streams_as_the_in_memory_reader_reads_and_fails_whole() {
        // Longer than the rows a writer holds back to state a rate: the rows streamed
        // into the file read back to the bits the in-memory importer gives.
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in");
        std::fs::create_dir(&input).unwrap();
        let rows: Vec<String> = (0..70_000)
            .map(|i| format!("{},{},{},{},{},{}", i % 7, -(i % 5), 3, 1, 2, -300 + i % 3))
            .collect();
        let session = write(
            &input,
            "session1.csv",
            &format!("gx,gy,gz,ax,ay,az\n{}\n", rows.join("\n")),
        );
        let out = dir.path().join("out");
        let report = import_to_dir(&input, &out, FileFormat::CsvGz).unwrap();
        let written = ImuRecording::read(&report.written[0].path).unwrap();
        let direct = import_file(&session, Dataset::Adis16405).unwrap().remove(0);
        assert_eq!(written.t_s, direct.recording.t_s);
        assert_eq!(written.gyro_rad_s, direct.recording.gyro_rad_s);
        assert_eq!(written.accel_m_s2, direct.recording.accel_m_s2);
        assert_eq!(written.sample_rate_hz, Some(100.0));
        assert_eq!(report.written[0].samples, 70_000);

        // A bad count near the end, after much has been written: an error naming it, and
        // no output folder.
        let mut bad = rows.clone();
        bad[68_000] = "1,2,3,4,5,six".into();
        write(
            &input,
            "session1.csv",
            &format!("gx,gy,gz,ax,ay,az\n{}\n", bad.join("\n")),
        );
        let out2 = dir.path().join("out2");
        let msg = import_to_dir(&input, &out2, FileFormat::CsvGz)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("session1.csv") && msg.contains("line 68002"),
            "{msg}"
        );
        assert!(!out2.exists());
    }

    #[test]
    fn two_inputs_with_one_output_name_collide() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "x.csv", "gx_rad_s\n0.1\n");
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        write(&dir.path().join("sub"), "x.csv.gz", "gx_rad_s\n0.2\n");
        let msg = import_to_dir(dir.path(), &dir.path().join("out"), FileFormat::CsvGz)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("mtig-x.csv.gz"), "{msg}");
    }
}
