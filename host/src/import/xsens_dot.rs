//! Xsens DOT CSV exports (`xsens-dot4-quadrotor/dot{1,2,4,7}.csv.gz`): one file per unit,
//! columns `SampleTimeFine` (µs, the unit's clock, a 32-bit counter), `Acc_X/Y/Z` (m/s^2),
//! `Gyr_X/Y/Z` (deg/s) and others (`Euler_*`, `Mag_*`, `PacketCounter`...) that are not read.
//! Lines before the header (an exporter's preamble, up to [`MAX_PREAMBLE_LINES`]) are skipped.
//!
//! Conversions: gyro deg/s x pi/180 -> rad/s, accelerometer as given (specific force: it reads
//! +g on an axis pointing up at rest). `t_s` = `SampleTimeFine` / 1e6 after unwrapping the
//! counter at 2^32 µs (each step is taken modulo 2^32; a zero step or one of 2^31 µs or more
//! is an error naming the line), so the units of one recording, which share their clock,
//! keep identical stamps for the same sample (the clock is not rebased to zero).
//!
//! Frame: each unit's **own sensor axes** (right-handed, z normal to the top face of the
//! housing). On the quadrotor the units lie with z about up, so they are not the vehicle's
//! forward-right-down axes and their mounting is not documented: no rotation is applied, as
//! for the MPU9250 rig. The DOT's own orientation estimate (`Euler_*`, w.r.t. its East-North-Up
//! frame) and the magnetometer are not imported.
//!
//! Rows dropped (their line numbers are returned): a first row whose six inertial values are
//! exactly 0 (the export's empty first sample); a lost sample, a row whose six inertial values
//! are all `NaN` or `Infinity`, together with any data row that carries the same stamp (which
//! of the two the stamp belongs to is unknown: `dot7.csv.gz` line 3909 repeats line 3908's
//! stamp after a skipped one). Any other non-finite value is an error naming line and column.

use std::io::{BufRead, BufReader, Read as _};
use std::path::Path;

use super::rows::{SensorLayout, SensorRows};
use super::ImportError;
use crate::interchange::{open_maybe_gz, ImuRecording, StepCounts, TableError};

/// The time column: microseconds of the unit's clock, wrapping at 2^32.
pub const TIME_COLUMN: &str = "SampleTimeFine";
/// Accelerometer columns, m/s^2.
pub const ACCEL_COLUMNS: [&str; 3] = ["Acc_X", "Acc_Y", "Acc_Z"];
/// Gyro columns, deg/s.
pub const GYRO_COLUMNS: [&str; 3] = ["Gyr_X", "Gyr_Y", "Gyr_Z"];
/// The output rates a DOT can be set to, Hz; the recording's stated rate is the one within 1%
/// of its median step.
pub const OUTPUT_RATES_HZ: [f64; 9] = [1.0, 4.0, 10.0, 12.0, 15.0, 20.0, 30.0, 60.0, 120.0];
/// Lines searched for the header.
pub const MAX_PREAMBLE_LINES: u64 = 32;

/// True when a header line (split at commas, trimmed) has the columns this importer reads.
pub fn is_header(fields: &[&str]) -> bool {
    std::iter::once(&TIME_COLUMN)
        .chain(&ACCEL_COLUMNS)
        .chain(&GYRO_COLUMNS)
        .all(|c| fields.contains(c))
}

/// Reads line `line_no` (1-based) into `buf`; `Ok(false)` at the end of the file.
fn next_line(
    path: &Path,
    reader: &mut impl BufRead,
    buf: &mut Vec<u8>,
    line_no: u64,
) -> Result<bool, ImportError> {
    buf.clear();
    let n = reader
        .read_until(b'\n', buf)
        .map_err(|e| ImportError::io(path, e))?;
    if std::str::from_utf8(buf).is_err() {
        return Err(ImportError::malformed(path, line_no, "not UTF-8 text"));
    }
    Ok(n > 0)
}

/// The 1-based line of the header among the first [`MAX_PREAMBLE_LINES`] lines, if any.
pub fn find_header(path: &Path) -> Result<Option<u64>, ImportError> {
    let mut reader = BufReader::new(open_maybe_gz(path)?.take(1 << 20));
    let mut buf = Vec::new();
    for line_no in 1..=MAX_PREAMBLE_LINES {
        buf.clear();
        let n = (&mut reader)
            .take(1 << 16)
            .read_until(b'\n', &mut buf)
            .map_err(|e| ImportError::io(path, e))?;
        if n == 0 {
            break;
        }
        let text = String::from_utf8_lossy(&buf);
        if is_header(&split(&text)) {
            return Ok(Some(line_no));
        }
    }
    Ok(None)
}

fn split(line: &str) -> Vec<&str> {
    line.trim_end_matches(['\n', '\r'])
        .split(',')
        .map(str::trim)
        .collect()
}

/// One data row: its line, raw stamp, and gyro (deg/s) then accelerometer (m/s^2) values,
/// `None` for a lost sample.
struct Row {
    line: u64,
    stamp_us: u32,
    values: Option<[f64; 6]>,
}

/// Column indices: time, then gyro x, y, z and accelerometer x, y, z.
struct Columns {
    count: usize,
    time: usize,
    inertial: [usize; 6],
}

fn parse_row(path: &Path, line: u64, fields: &[&str], cols: &Columns) -> Result<Row, ImportError> {
    if fields.len() != cols.count {
        return Err(ImportError::malformed(
            path,
            line,
            format!("{} fields, expected {}", fields.len(), cols.count),
        ));
    }
    let raw = fields[cols.time];
    let stamp_us: u32 = raw.parse().map_err(|_| {
        ImportError::malformed(
            path,
            line,
            format!("column `{TIME_COLUMN}`: `{raw}` is not a whole number of µs in 0..2^32"),
        )
    })?;
    let names = GYRO_COLUMNS.iter().chain(&ACCEL_COLUMNS);
    let mut values = [0.0f64; 6];
    for ((v, &i), name) in values.iter_mut().zip(&cols.inertial).zip(names) {
        *v = fields[i].parse().map_err(|_| {
            ImportError::malformed(
                path,
                line,
                format!("column `{name}`: `{}` is not a number", fields[i]),
            )
        })?;
    }
    if values.iter().all(|v| !v.is_finite()) {
        return Ok(Row {
            line,
            stamp_us,
            values: None,
        });
    }
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        let name = GYRO_COLUMNS
            .iter()
            .chain(&ACCEL_COLUMNS)
            .nth(k)
            .unwrap_or(&"");
        return Err(ImportError::malformed(
            path,
            line,
            format!(
                "column `{name}`: `{}` is not a finite number (only a row with all six Acc and Gyr values non-finite, a lost sample, is dropped)",
                fields[cols.inertial[k]]
            ),
        ));
    }
    Ok(Row {
        line,
        stamp_us,
        values: Some(values),
    })
}

/// Reads the header (after any preamble) and hands every data row to `each`, in file order.
fn for_each_row(
    path: &Path,
    each: &mut dyn FnMut(Row) -> Result<(), ImportError>,
) -> Result<(), ImportError> {
    let mut reader = BufReader::new(open_maybe_gz(path)?);
    let mut buf = Vec::new();
    let mut line_no = 0;
    let cols = loop {
        line_no += 1;
        if line_no > MAX_PREAMBLE_LINES || !next_line(path, &mut reader, &mut buf, line_no)? {
            return Err(ImportError::malformed(
                path,
                line_no.min(MAX_PREAMBLE_LINES),
                format!(
                    "no Xsens DOT header (`{TIME_COLUMN}`, `Acc_X`..`Gyr_Z`) in the first {MAX_PREAMBLE_LINES} lines"
                ),
            ));
        }
        let text = String::from_utf8_lossy(&buf);
        let fields = split(&text);
        if is_header(&fields) {
            let at = |name: &str| fields.iter().position(|f| *f == name).unwrap_or(0);
            let inertial = [
                GYRO_COLUMNS[0],
                GYRO_COLUMNS[1],
                GYRO_COLUMNS[2],
                ACCEL_COLUMNS[0],
                ACCEL_COLUMNS[1],
                ACCEL_COLUMNS[2],
            ]
            .map(at);
            break Columns {
                count: fields.len(),
                time: at(TIME_COLUMN),
                inertial,
            };
        }
    };
    loop {
        line_no += 1;
        if !next_line(path, &mut reader, &mut buf, line_no)? {
            return Ok(());
        }
        let text = String::from_utf8_lossy(&buf);
        if !text.trim().is_empty() {
            each(parse_row(path, line_no, &split(&text), &cols)?)?;
        }
    }
}

/// Which rows are kept (see the module docs), decided as they come: a kept row waits while
/// a lost sample with its stamp may still follow (the kept rows sharing the last kept stamp
/// wait together, as each lost row drops the last one kept).
#[derive(Default)]
struct Keeper {
    rows: usize,
    waiting: Vec<Row>,
    lost_stamp: Option<u32>,
    dropped: Vec<u64>,
}

impl Keeper {
    /// The next row; the rows now certain to be kept go to `kept`.
    fn push(
        &mut self,
        row: Row,
        kept: &mut dyn FnMut(Row) -> Result<(), ImportError>,
    ) -> Result<(), ImportError> {
        let first = self.rows == 0;
        self.rows += 1;
        match row.values {
            None => {
                if self
                    .waiting
                    .last()
                    .is_some_and(|k| k.stamp_us == row.stamp_us)
                {
                    self.dropped.extend(self.waiting.pop().map(|k| k.line));
                }
                self.lost_stamp = Some(row.stamp_us);
                self.dropped.push(row.line);
            }
            Some(v) if first && v.iter().all(|x| *x == 0.0) => self.dropped.push(row.line),
            Some(_) if self.lost_stamp == Some(row.stamp_us) => self.dropped.push(row.line),
            Some(_) => {
                if self
                    .waiting
                    .last()
                    .is_some_and(|k| k.stamp_us != row.stamp_us)
                {
                    for waiting in self.waiting.drain(..) {
                        kept(waiting)?;
                    }
                }
                self.waiting.push(row);
            }
        }
        Ok(())
    }

    /// The rows still waiting to `kept`; the lines dropped, in file order.
    fn finish(
        mut self,
        kept: &mut dyn FnMut(Row) -> Result<(), ImportError>,
    ) -> Result<Vec<u64>, ImportError> {
        for waiting in self.waiting.drain(..) {
            kept(waiting)?;
        }
        self.dropped.sort_unstable();
        Ok(self.dropped)
    }
}

/// The unit's clock unwrapped at 2^32 µs over the kept rows, each step checked.
struct Clock {
    t_us: u64,
    previous: Option<u32>,
}

impl Clock {
    /// The time of `row`, µs since the clock's zero; a zero step or one of 2^31 µs or more is
    /// an error naming the line.
    fn time_us(&mut self, path: &Path, row: &Row) -> Result<u64, ImportError> {
        let Some(previous) = self.previous else {
            self.previous = Some(row.stamp_us);
            self.t_us = u64::from(row.stamp_us);
            return Ok(self.t_us);
        };
        let step = row.stamp_us.wrapping_sub(previous);
        if step == 0 || step >= 1 << 31 {
            return Err(ImportError::malformed(
                path,
                row.line,
                format!(
                    "column `{TIME_COLUMN}`: {} µs {} the previous row's {previous} µs",
                    row.stamp_us,
                    if step == 0 {
                        "repeats"
                    } else {
                        "goes back from"
                    }
                ),
            ));
        }
        self.t_us += u64::from(step);
        self.previous = Some(row.stamp_us);
        Ok(self.t_us)
    }
}

/// Walks the kept rows of the export at `path`: `each(t_s, gyro rad/s and accelerometer
/// m/s^2)` for each, in file order; the lines dropped.
fn for_each_kept(
    path: &Path,
    each: &mut dyn FnMut(f64, [f64; 6]) -> Result<(), ImportError>,
) -> Result<Vec<u64>, ImportError> {
    let mut clock = Clock {
        t_us: 0,
        previous: None,
    };
    let mut kept = |row: Row| {
        let t_s = crate::decode::seconds_of_us(clock.time_us(path, &row)?);
        let v = row.values.unwrap_or_default();
        each(
            t_s,
            [
                v[0].to_radians(),
                v[1].to_radians(),
                v[2].to_radians(),
                v[3],
                v[4],
                v[5],
            ],
        )
    };
    let mut keeper = Keeper::default();
    for_each_row(path, &mut |row| keeper.push(row, &mut kept))?;
    keeper.finish(&mut kept)
}

/// Streams one DOT export into `sink` as one sensor (`t_s`, gyro, accelerometer), in two
/// passes and memory that does not grow with it: the first checks every row and finds the
/// rate ([`OUTPUT_RATES_HZ`]: the one within 1% of the median step), the second writes the
/// kept rows. The lines dropped.
pub fn stream(path: &Path, sink: &mut dyn SensorRows) -> Result<Vec<u64>, ImportError> {
    let mut steps = StepCounts::default();
    for_each_kept(path, &mut |t_s, _| {
        steps.push(t_s);
        Ok(())
    })?;
    if steps.is_empty() {
        return Err(TableError::Empty {
            path: path.to_path_buf(),
        }
        .into());
    }
    let rate_hz = steps.sampling_without_gaps().and_then(|s| {
        OUTPUT_RATES_HZ
            .into_iter()
            .find(|rate| (s.median_step_s * rate - 1.0).abs() < 0.01)
    });
    sink.begin(vec![SensorLayout {
        rate_hz,
        ..SensorLayout::imu("")
    }])?;
    let mut row = [0.0; 7];
    for_each_kept(path, &mut |t_s, values| {
        row[0] = t_s;
        row[1..].copy_from_slice(&values);
        sink.push(0, &row)
    })
}

/// An imported DOT file: the recording and the lines of the rows dropped.
#[derive(Debug, Clone, PartialEq)]
pub struct DotFile {
    /// Gyro rad/s and accelerometer m/s^2 in the unit's sensor axes, `t_s` on its clock.
    pub recording: ImuRecording,
    /// 1-based lines of the rows left out (the empty first sample, lost samples).
    pub dropped_lines: Vec<u64>,
}

/// Reads one DOT export ([`stream`] collected).
pub fn read(path: &Path) -> Result<DotFile, ImportError> {
    let (mut recordings, dropped_lines) =
        super::rows::collect_named(path, |sink| stream(path, sink))?;
    let (_, recording) = recordings.remove(0);
    Ok(DotFile {
        recording,
        dropped_lines,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str =
        "SampleTimeFine,Euler_X,Euler_Y,Euler_Z,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z,Mag_X,Mag_Y,Mag_Z,";

    fn row(stamp: u64, acc: [&str; 3], gyr: [&str; 3]) -> String {
        format!(
            "{stamp},-2.6,5.6,-150.9,{},{},{},{},{},{},-0.43,-0.48,-1.04, ",
            acc[0], acc[1], acc[2], gyr[0], gyr[1], gyr[2]
        )
    }

    fn write(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("dot9.csv");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    #[test]
    fn converts_units_drops_the_empty_first_row_and_states_120_hz() {
        let zero = ["0"; 3];
        let text = [
            HEADER.to_string(),
            row(677_583_000, zero, zero),
            row(677_591_333, ["-0.6", "-0.55", "9.52"], ["180", "-90", "0"]),
            row(677_599_666, ["0", "0", "9.8"], ["1", "2", "3"]),
            row(677_607_999, ["0", "0", "9.8"], ["1", "2", "3"]),
        ]
        .join("\n");
        let (_dir, path) = write(&text);
        let dot = read(&path).unwrap();
        assert_eq!(dot.dropped_lines, vec![2]);
        let rec = &dot.recording;
        assert_eq!(rec.t_s, vec![677.591333, 677.599666, 677.607999]);
        assert_eq!(rec.sample_rate_hz, Some(120.0));
        assert_eq!(rec.channel("gx").unwrap()[0], std::f64::consts::PI);
        assert_eq!(rec.channel("gy").unwrap()[0], -std::f64::consts::FRAC_PI_2);
        assert_eq!(rec.channel("gz").unwrap()[1], 3f64.to_radians());
        assert_eq!(rec.channel("ax").unwrap()[0], -0.6);
        assert_eq!(rec.channel("az").unwrap()[0], 9.52);
    }

    #[test]
    fn skips_a_preamble_and_unwraps_the_32_bit_clock() {
        let g = ["0.1", "0.2", "0.3"];
        let a = ["0", "0", "9.81"];
        let text = [
            "Xsens DOT exporter".to_string(),
            "DeviceTag: dot9".into(),
            String::new(),
            HEADER.into(),
            row(4_294_959_000, a, g),
            row(4_294_967_295, a, g),
            row(8_332, a, g), // wrapped: 2^32 + 8332
        ]
        .join("\n");
        let (_dir, path) = write(&text);
        assert_eq!(find_header(&path).unwrap(), Some(4));
        let rec = read(&path).unwrap().recording;
        assert_eq!(rec.t_s, vec![4294.959, 4294.967295, 4294.975628]);
    }

    #[test]
    fn a_lost_sample_drops_itself_and_the_row_sharing_its_stamp() {
        let g = ["1", "2", "3"];
        let a = ["0", "0", "9.8"];
        let text = [
            HEADER.to_string(),
            row(100, a, g),
            row(16_766, a, g), // a skipped sample before
            row(
                16_766,
                [" NaN", " NaN", " NaN"],
                [" Infinity", " Infinity", " Infinity"],
            ),
            row(25_099, a, g),
        ]
        .join("\n");
        let (_dir, path) = write(&text);
        let dot = read(&path).unwrap();
        assert_eq!(dot.dropped_lines, vec![3, 4]);
        assert_eq!(dot.recording.t_s, vec![0.0001, 0.025099]);
    }

    /// Read as it comes, a row waits while a lost sample with its stamp may follow: each
    /// lost row drops the last row kept with its stamp, however many wait.
    #[test]
    fn rows_sharing_a_stamp_wait_for_the_lost_rows_that_drop_them() {
        let g = ["1", "2", "3"];
        let a = ["0", "0", "9.8"];
        let lost = ([" NaN"; 3], [" NaN"; 3]);
        let text = [
            HEADER.to_string(),
            row(100, a, g),
            row(200, a, g),
            row(200, a, g),
            row(200, lost.0, lost.1),
            row(300, a, g),
            row(300, a, g),
            row(300, lost.0, lost.1),
            row(300, lost.0, lost.1),
            row(400, a, g),
        ]
        .join("\n");
        let (_dir, path) = write(&text);
        let dot = read(&path).unwrap();
        assert_eq!(dot.dropped_lines, vec![4, 5, 6, 7, 8, 9]);
        assert_eq!(dot.recording.t_s, vec![0.0001, 0.0002, 0.0004]);
        // Without a lost row to drop one of them, two rows with one stamp are an error.
        let text = [
            HEADER.to_string(),
            row(100, a, g),
            row(100, a, g),
            row(200, a, g),
        ]
        .join("\n");
        let (_dir, path) = write(&text);
        let msg = read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("line 3") && msg.contains("100 µs repeats"),
            "{msg}"
        );
    }

    #[test]
    fn bad_rows_are_errors_naming_file_line_and_column() {
        let g = ["1", "2", "3"];
        let a = ["0", "0", "9.8"];
        let cases = [
            (
                row(200, ["0", "nan", "9.8"], g),
                "column `Acc_Y`: `nan` is not a finite number",
            ),
            (
                row(200, a, ["1", "x", "3"]),
                "column `Gyr_Y`: `x` is not a number",
            ),
            (row(100, a, g), "column `SampleTimeFine`: 100 µs repeats"),
            (
                row(50, a, g),
                "50 µs goes back from the previous row's 100 µs",
            ),
            ("12.5,1,2".to_string(), "3 fields, expected 14"),
            (
                row(1 << 32, a, g),
                "`4294967296` is not a whole number of µs",
            ),
        ];
        for (bad, expected) in cases {
            let text = [HEADER.to_string(), row(100, a, g), bad].join("\n");
            let (_dir, path) = write(&text);
            let msg = read(&path).unwrap_err().to_string();
            assert!(
                msg.contains("dot9.csv: line 3") && msg.contains(expected),
                "{msg}"
            );
        }
        let (_dir, path) = write("a,b\n1,2\n");
        let msg = read(&path).unwrap_err().to_string();
        assert!(msg.contains("no Xsens DOT header"), "{msg}");
        assert_eq!(find_header(&path).unwrap(), None);
    }
}
