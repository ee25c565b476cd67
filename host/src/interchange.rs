//! The IMU interchange format: one CSV (optionally gzip-compressed) per sensor, with a header
//! row and SI units. Every dynacal tool reads and writes it; `docs/formats.md` is its spec.
//!
//! Columns: `t_s` (seconds, strictly increasing) is required. Then any of the body-frame
//! (forward-right-down) angular rate `gx_rad_s, gy_rad_s, gz_rad_s` (body w.r.t. inertial
//! space) and specific force `ax_m_s2, ay_m_s2, az_m_s2`; optionally the attitude of the body
//! w.r.t. local North-East-Down `roll_rad, pitch_rad, yaw_rad` (Z-Y-X), the position
//! `lat_rad, lon_rad, h_m` and the NED velocity `vn_m_s, ve_m_s, vd_m_s`. A triplet is all
//! present or all absent, with one exception: a single-axis sensor may give exactly one of the
//! gyro (or accelerometer) columns alone (see [`SingleAxis`]); two of three is still an error,
//! as it is far more often a misspelt column than a two-axis sensor. A file may hold no IMU
//! channel at all (a reference trajectory: attitude, velocity, position). Unknown columns are
//! ignored.

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

use crate::output::AtomicFile;

pub mod fast;
pub mod parquet;
pub mod summary;

/// Errors reading or writing tables. Each names the file and, where there is one, the line
/// (1-based, the header being line 1) and column.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The CSV layer rejected a record (bad quoting, wrong field count, bad UTF-8).
    #[error("{path}: line {line}: {message}")]
    Csv {
        path: PathBuf,
        line: u64,
        message: String,
    },
    /// A column the format requires is absent from the header.
    #[error("{path}: line 1: missing required column `{column}`")]
    MissingColumn { path: PathBuf, column: String },
    /// Only part of a column triplet is present (e.g. `gx_rad_s` and `gy_rad_s` without
    /// `gz_rad_s`, or `roll_rad` alone). A lone gyro or accelerometer column is allowed.
    #[error("{path}: line 1: column `{present}` needs `{missing}` too")]
    IncompleteTriplet {
        path: PathBuf,
        present: String,
        missing: String,
    },
    /// A field is not a finite number.
    #[error("{path}: line {line}, column `{column}`: `{value}` is not a finite number")]
    NotANumber {
        path: PathBuf,
        line: u64,
        column: String,
        value: String,
    },
    /// Time does not strictly increase.
    #[error("{path}: line {line}, column `t_s`: time {t_s} s does not increase (previous {previous_t_s} s)")]
    TimeNotIncreasing {
        path: PathBuf,
        line: u64,
        t_s: f64,
        previous_t_s: f64,
    },
    /// Time does not strictly increase, found where the file's lines are no longer known
    /// (a column read whole, whose comment lines were skipped; a binary log's samples).
    #[error("{path}: sample {sample} (1-based), column `t_s`: time {t_s} s does not increase (previous {previous_t_s} s)")]
    TimeNotIncreasingAtSample {
        path: PathBuf,
        sample: u64,
        t_s: f64,
        previous_t_s: f64,
    },
    /// The file has a header but no data rows.
    #[error("{path}: no data rows")]
    Empty { path: PathBuf },
    /// The sample rate stated in the file (`place`: its line, or a Parquet file's metadata
    /// entry) disagrees with its time column.
    #[error("{path}: {place}: the stated sample rate {stated_hz} Hz disagrees with the time column `t_s` (median step {median_step_s} s, {measured_hz:.6} Hz)")]
    RateMismatch {
        path: PathBuf,
        place: String,
        stated_hz: f64,
        median_step_s: f64,
        measured_hz: f64,
    },
    /// A value outside what its column can hold (a latitude beyond a pole).
    #[error("{path}: column `{column}` at t = {t_s} s: {value} is outside {range} (degrees in a radian column?)")]
    OutOfRange {
        path: PathBuf,
        column: &'static str,
        t_s: f64,
        value: f64,
        range: &'static str,
    },
    /// A Parquet file that cannot be read or written, or a column of it dynacal cannot read.
    #[error("{path}: {message}")]
    Parquet { path: PathBuf, message: String },
    /// A value of a binary table (Parquet) that is not what its column needs; rows are
    /// counted among the data rows, from 1.
    #[error("{path}: row {row}, column `{column}`: {message}")]
    AtRow {
        path: PathBuf,
        row: u64,
        column: String,
        message: String,
    },
    /// Columns of an in-memory recording have different lengths.
    #[error("{path}: column `{column}` has {len} values, expected {expected}")]
    LengthMismatch {
        path: PathBuf,
        column: String,
        len: usize,
        expected: usize,
    },
}

/// A numeric table read from a CSV: the header names and one `Vec<f64>` per column.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub path: PathBuf,
    pub headers: Vec<String>,
    pub columns: Vec<Vec<f64>>,
    /// Where its rows are in the file, for errors found after reading.
    pub row_lines: RowLines,
}

/// The file lines of a column's samples, as far as they are known: where errors found in a
/// column read whole (time going back, a gap) can name the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowLines {
    /// Sample i is on line `first + i` (1-based; no comment line among the rows).
    From(u64),
    /// Not known (comment lines among the rows, or not a text file): errors name the sample.
    Unknown,
}

impl Table {
    /// Index of a column by exact header name.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.headers.iter().position(|h| h == name)
    }
    /// A column by exact header name.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.index(name).map(|i| self.columns[i].as_slice())
    }
    /// Number of data rows.
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }
}

/// Makes room for `additional` more values at the end of `column` and asks the kernel to
/// back the room with transparent huge pages (where it gives them only when asked, as on a
/// default Linux): a long recording's columns are first touched as they are filled, at a
/// page fault per 4 KiB page otherwise (a 4e6-row CSV's two columns: 16 000 faults and a
/// fifth of the read's processor time, BENCHMARKS.md "Ingest", stop 67), where a 2 MiB
/// page costs one. The memory a column holds is the same, but for the last page's rounding.
/// Room that cannot be had (a file stating more rows than memory holds) is not made: the
/// column then grows as it is filled, and fails only if what it holds does not fit. One
/// value more is made room for: the wavelet variance puts its prefix sums in the column's
/// own memory, one longer than the series ([`crate::wv::haar_wv_owned`]), and a column
/// with no room to spare would be copied whole into a new allocation for it.
pub(crate) fn reserve_column(column: &mut Vec<f64>, additional: usize) {
    let capacity = column.capacity();
    if column.try_reserve(additional + 1).is_err() {
        return;
    }
    if column.capacity() != capacity {
        advise_huge_pages(column.spare_capacity_mut());
    }
}

#[cfg(target_os = "linux")]
fn advise_huge_pages<T>(room: &mut [T]) {
    const HUGE_PAGE_BYTES: usize = 2 << 20;
    let start = (room.as_ptr() as usize).next_multiple_of(HUGE_PAGE_BYTES);
    let end =
        (room.as_ptr() as usize + std::mem::size_of_val(room)) / HUGE_PAGE_BYTES * HUGE_PAGE_BYTES;
    if end > start {
        // SAFETY: the range lies inside `room`, memory this process owns, and the advice
        // changes only how the kernel backs it, never its contents. A refusal (a kernel
        // without huge pages) leaves the small pages: nothing to report.
        unsafe {
            libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge_pages<T>(_room: &mut [T]) {}

/// The first two bytes of every gzip member (RFC 1952).
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// Opens a file for reading, transparently decompressing gzip (detected by its magic bytes,
/// so a `.csv` that is really gzip, or a `.gz` that is not, still reads).
pub fn open_maybe_gz(path: &Path) -> Result<Box<dyn Read>, TableError> {
    let io = |source| TableError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = File::open(path).map_err(io)?;
    let mut magic = [0u8; 2];
    let n = file.read(&mut magic).map_err(io)?;
    let file = File::open(path).map_err(io)?;
    let size_bytes = file.metadata().map_err(io)?.len();
    let file = crate::progress::Counted::new(file, path, size_bytes);
    if n == 2 && magic == GZIP_MAGIC {
        Ok(Box::new(BufReader::with_capacity(
            1 << 16,
            GzipText {
                inner: flate2::read::MultiGzDecoder::new(BufReader::with_capacity(1 << 16, file)),
                bytes: 0,
                lines: 0,
            },
        )))
    } else {
        Ok(Box::new(BufReader::with_capacity(1 << 16, file)))
    }
}

/// About how many bytes of text the file at `path` holds, to size what is read from it
/// ahead: a plain file's size; a gzip file's stated length (its last member's, modulo 4 GiB:
/// exact for the usual single member under 4 GiB), and at least its compressed size. `0`
/// when the file cannot be read (its reader will say why).
pub(crate) fn text_bytes_hint(path: &Path) -> u64 {
    let Ok(mut file) = File::open(path) else {
        return 0;
    };
    let size_bytes = file.metadata().map_or(0, |m| m.len());
    let mut magic = [0u8; 2];
    if size_bytes < 18 || file.read_exact(&mut magic).is_err() || magic != GZIP_MAGIC {
        return size_bytes;
    }
    let mut stated = [0u8; 4];
    let read = std::io::Seek::seek(&mut file, std::io::SeekFrom::End(-4))
        .and_then(|_| file.read_exact(&mut stated));
    match read {
        Ok(()) => u64::from(u32::from_le_bytes(stated)).max(size_bytes),
        Err(_) => size_bytes,
    }
}

/// A gzip decoder that says where its stream broke: flate2's "incomplete deflate stream"
/// names neither the line nor the cause a user can act on (a file cut short in a copy or a
/// download), so the error is restated with the line and the decompressed bytes read so far.
struct GzipText<R> {
    inner: R,
    bytes: u64,
    lines: u64,
}

impl<R: Read> Read for GzipText<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self.inner.read(buf) {
            Ok(n) => {
                self.bytes += n as u64;
                self.lines += bytecount::count(&buf[..n], b'\n') as u64;
                Ok(n)
            }
            Err(e) => Err(std::io::Error::new(
                e.kind(),
                format!(
                    "line {}: the gzip data end or break after {} decompressed bytes \
                     (the file is cut short or damaged: {e})",
                    self.lines + 1,
                    self.bytes
                ),
            )),
        }
    }
}

/// Reads a CSV (or CSV.gz) with a header row whose fields are all numbers.
///
/// Only the columns named in `wanted` are parsed (all columns if `wanted` is `None`); other
/// columns may hold anything. Every parsed field must be a finite number.
pub fn read_table(path: &Path, wanted: Option<&[&str]>) -> Result<Table, TableError> {
    if parquet::is_parquet(path) {
        return parquet::read_table(path, wanted);
    }
    if let Some(table) = fast::read_table(path, wanted) {
        return Ok(table);
    }
    read_table_by_rows(path, wanted)
}

/// [`read_table`] with the `csv` crate, one row at a time on one core: what reads the files
/// the fast path leaves, and says what is wrong with a bad one.
pub fn read_table_by_rows(path: &Path, wanted: Option<&[&str]>) -> Result<Table, TableError> {
    let mut rows = TableRows::open(path, wanted)?;
    let mut columns: Vec<Vec<f64>> = vec![Vec::new(); rows.headers().len()];
    let mut row_lines = None;
    let mut count = 0u64;
    while let Some((line, values)) = rows.next_row()? {
        row_lines = match row_lines {
            None => Some(RowLines::From(line)),
            Some(RowLines::From(first)) if first + count != line => Some(RowLines::Unknown),
            known => known,
        };
        count += 1;
        for (column, value) in columns.iter_mut().zip(values) {
            column.push(*value);
        }
    }
    Ok(Table {
        path: path.to_path_buf(),
        headers: rows.headers,
        columns,
        row_lines: row_lines.unwrap_or(RowLines::Unknown),
    })
}

/// The `csv` reader every text table is read with: a header row, fields trimmed, `#` lines
/// skipped when `comments`. Records end at LF only (a CR before it is trimmed with the field):
/// with the crate's default CR/LF/CRLF ending, each row of a CRLF file is reported one line
/// early.
pub fn csv_reader<R: Read>(reader: R, comments: bool) -> csv::Reader<R> {
    csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .terminator(csv::Terminator::Any(b'\n'))
        .comment(comments.then_some(b'#'))
        .from_reader(reader)
}

/// Where a row is in its file: a CSV's 1-based line (the header being line 1), or a Parquet
/// file's 1-based data row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowPlace {
    Line(u64),
    Row(u64),
}

impl std::fmt::Display for RowPlace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Line(line) => write!(f, "line {line}"),
            Self::Row(row) => write!(f, "row {row}"),
        }
    }
}

/// Reads a numeric table (CSV, CSV.gz or Parquet) that must have all of `columns` (others
/// are ignored), giving `row` each data row's place and values in `columns` order, one row
/// at a time, in memory that does not grow with the file. Every field must be a finite
/// number, and a `t_s` among the columns must strictly increase. Errors name the file and
/// the line (CSV) or row (Parquet); a table without data rows is an error.
pub fn for_each_row<E: From<TableError>>(
    path: &Path,
    columns: &[&str],
    mut row: impl FnMut(RowPlace, &[f64]) -> Result<(), E>,
) -> Result<(), E> {
    let time = columns.iter().position(|c| *c == "t_s");
    let mut previous_t_s: Option<f64> = None;
    let mut check_time = |place: RowPlace, values: &[f64]| -> Result<(), TableError> {
        let Some(k) = time else { return Ok(()) };
        let t_s = values[k];
        if let Some(previous_t_s) = previous_t_s.filter(|p| !(t_s > *p)) {
            let path = path.to_path_buf();
            return Err(match place {
                RowPlace::Line(line) => TableError::TimeNotIncreasing {
                    path,
                    line,
                    t_s,
                    previous_t_s,
                },
                RowPlace::Row(sample) => TableError::TimeNotIncreasingAtSample {
                    path,
                    sample,
                    t_s,
                    previous_t_s,
                },
            });
        }
        previous_t_s = Some(t_s);
        Ok(())
    };
    let mut values = vec![0.0; columns.len()];
    let mut any_row = false;
    if parquet::is_parquet(path) {
        let mut reader = parquet::ParquetColumns::open(path, Some(columns))?;
        let order = column_order(path, reader.headers(), columns)?;
        while let Some(block) = reader.next_block()? {
            let rows = block.columns.first().map_or(0, Vec::len);
            for k in 0..rows {
                for (value, &i) in values.iter_mut().zip(&order) {
                    *value = block.columns[i][k];
                }
                let place = RowPlace::Row(block.first_row + k as u64);
                check_time(place, &values)?;
                any_row = true;
                row(place, &values)?;
            }
        }
    } else {
        let mut rows = TableRows::open(path, Some(columns))?;
        let order = column_order(path, rows.headers(), columns)?;
        while let Some((line, parsed)) = rows.next_row()? {
            for (value, &i) in values.iter_mut().zip(&order) {
                *value = parsed[i];
            }
            check_time(RowPlace::Line(line), &values)?;
            any_row = true;
            row(RowPlace::Line(line), &values)?;
        }
    }
    if !any_row {
        return Err(TableError::Empty {
            path: path.to_path_buf(),
        }
        .into());
    }
    Ok(())
}

/// Where each of `columns` is among a reader's `headers`, or the first one missing.
fn column_order(
    path: &Path,
    headers: &[String],
    columns: &[&str],
) -> Result<Vec<usize>, TableError> {
    columns
        .iter()
        .map(|name| {
            headers
                .iter()
                .position(|h| h == name)
                .ok_or_else(|| TableError::MissingColumn {
                    path: path.to_path_buf(),
                    column: (*name).to_string(),
                })
        })
        .collect()
}

/// A numeric CSV (or CSV.gz) read one row at a time, with [`read_table`]'s rules: `#` lines
/// skipped, fields trimmed, only the wanted columns parsed, each a finite number, every error
/// naming the file and line. What a reader whose memory must not grow with the file uses.
pub struct TableRows {
    path: PathBuf,
    csv: csv::Reader<Box<dyn Read>>,
    headers: Vec<String>,
    selected: Vec<usize>,
    record: csv::ByteRecord,
    values: Vec<f64>,
}

impl TableRows {
    /// Opens `path` and reads its header; `wanted` as in [`read_table`].
    pub fn open(path: &Path, wanted: Option<&[&str]>) -> Result<Self, TableError> {
        let mut csv = csv_reader(open_maybe_gz(path)?, true);
        let all_headers: Vec<String> = csv
            .headers()
            .map_err(|e| csv_error(path, e))?
            .iter()
            .map(str::to_string)
            .collect();
        let selected: Vec<usize> = match wanted {
            None => (0..all_headers.len()).collect(),
            Some(names) => all_headers
                .iter()
                .enumerate()
                .filter(|(_, h)| names.contains(&h.as_str()))
                .map(|(i, _)| i)
                .collect(),
        };
        Ok(Self {
            path: path.to_path_buf(),
            csv,
            headers: selected.iter().map(|&i| all_headers[i].clone()).collect(),
            values: vec![0.0; selected.len()],
            selected,
            record: csv::ByteRecord::new(),
        })
    }

    /// The parsed columns' names, in file order.
    pub fn headers(&self) -> &[String] {
        &self.headers
    }

    /// The next data row's 1-based file line and its parsed values (in [`Self::headers`]
    /// order); `None` after the last row.
    pub fn next_row(&mut self) -> Result<Option<(u64, &[f64])>, TableError> {
        match self.csv.read_byte_record(&mut self.record) {
            Ok(false) => return Ok(None),
            Ok(true) => {}
            Err(e) => return Err(csv_error(&self.path, e)),
        }
        let line = self.record.position().map_or(0, |p| p.line());
        for (slot, &i) in self.selected.iter().enumerate() {
            self.values[slot] =
                parse_field(&self.path, &self.record, i, &self.headers[slot], line)?;
        }
        Ok(Some((line, &self.values)))
    }
}

/// Field `index` of a record on file line `line` as a finite number, or an error naming the
/// file, line, column and text.
pub(crate) fn parse_field(
    path: &Path,
    record: &csv::ByteRecord,
    index: usize,
    column: &str,
    line: u64,
) -> Result<f64, TableError> {
    let raw = record.get(index).unwrap_or(b"");
    std::str::from_utf8(raw)
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|v| v.is_finite())
        .ok_or_else(|| TableError::NotANumber {
            path: path.to_path_buf(),
            line,
            column: column.into(),
            value: String::from_utf8_lossy(raw).into_owned(),
        })
}

/// A CSV layer error as a [`TableError`] naming the file and line.
pub(crate) fn csv_error(path: &Path, e: csv::Error) -> TableError {
    let line = e.position().map_or(0, |p| p.line());
    let text = e.to_string();
    match e.into_kind() {
        csv::ErrorKind::Io(source) => TableError::Io {
            path: path.to_path_buf(),
            source,
        },
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => TableError::Csv {
            path: path.to_path_buf(),
            line,
            message: format!("{len} fields, expected {expected_len} as in the header"),
        },
        csv::ErrorKind::Utf8 { err, .. } => TableError::Csv {
            path: path.to_path_buf(),
            line,
            message: format!("field {} is not UTF-8 text", err.field() + 1),
        },
        _ => TableError::Csv {
            path: path.to_path_buf(),
            line,
            message: text,
        },
    }
}

/// The median step of a time column, s: dynacal's one estimate of a sample interval where
/// none is stated (robust to a gap or a late sample). `None` for fewer than two samples.
pub fn median_step_s(t_s: &[f64]) -> Option<f64> {
    let steps = t_s.len().checked_sub(1)?;
    crate::numeric::select_rank(steps, |i| t_s[i + 1] - t_s[i], steps / 2)
}

/// How regular a time column is: the median step, the spread of the steps and the gaps.
/// Commands that need a uniform grid take the samples in order at the median step and say
/// so with this summary; the importers report it per sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct Sampling {
    pub samples: usize,
    /// Last minus first time, s.
    pub span_s: f64,
    pub median_step_s: f64,
    pub min_step_s: f64,
    pub max_step_s: f64,
    /// The 1st and 99th percentiles of the steps, s.
    pub p01_step_s: f64,
    pub p99_step_s: f64,
    /// Steps longer than [`Sampling::GAP_STEPS`] median steps: (start time, length), s.
    pub gaps: Vec<(f64, f64)>,
}

impl Sampling {
    /// A step longer than this many median steps is a gap.
    pub const GAP_STEPS: f64 = 2.0;

    /// The summary of `t_s` (increasing); `None` for fewer than two samples.
    pub fn of(t_s: &[f64]) -> Option<Self> {
        let median = median_step_s(t_s)?;
        let mut steps: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
        let gaps = t_s
            .windows(2)
            .filter(|w| w[1] - w[0] > Self::GAP_STEPS * median)
            .map(|w| (w[0], w[1] - w[0]))
            .collect();
        steps.sort_by(f64::total_cmp);
        let at = |q: f64| steps[((steps.len() - 1) as f64 * q).round() as usize];
        Some(Self {
            samples: t_s.len(),
            span_s: t_s[t_s.len() - 1] - t_s[0],
            median_step_s: median,
            min_step_s: steps[0],
            max_step_s: steps[steps.len() - 1],
            p01_step_s: at(0.01),
            p99_step_s: at(0.99),
            gaps,
        })
    }

    /// True when every step is within 1% of the median: a uniform grid.
    pub fn is_uniform(&self) -> bool {
        self.max_step_s <= 1.01 * self.median_step_s && self.min_step_s >= 0.99 * self.median_step_s
    }
}

impl std::fmt::Display for Sampling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} samples over {:.3} s, median step {:.3} ms ({:.2} Hz), steps from {:.3} to {:.3} ms (1st to 99th percentile {:.3} to {:.3} ms)",
            self.samples,
            self.span_s,
            self.median_step_s * 1e3,
            1.0 / self.median_step_s,
            self.min_step_s * 1e3,
            self.max_step_s * 1e3,
            self.p01_step_s * 1e3,
            self.p99_step_s * 1e3,
        )?;
        match self.gaps.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
            Some((start, length)) => write!(
                f,
                "; {} gaps longer than {} median steps, the longest {:.3} ms from {:.3} s",
                self.gaps.len(),
                Self::GAP_STEPS,
                length * 1e3,
                start
            ),
            None => write!(f, "; no gap longer than {} median steps", Self::GAP_STEPS),
        }
    }
}

/// The steps of a time line counted as they come, for a [`Sampling`] of a recording read in
/// passes (a ROS bag's topic streamed by `dynacal noise`) in memory independent of its
/// length: one count per distinct step. Its percentiles are [`Sampling::of`]'s exactly
/// (the same f64 steps, ranked the same way); the gaps need the median first, so a second
/// pass finds them ([`Sampling::GAP_STEPS`]). Kept apart from [`Sampling::of`], whose sort
/// is several times faster on a series already in memory.
#[derive(Debug, Clone, Default)]
pub struct StepCounts {
    /// Distinct steps by their order-preserving key ([`f64::total_cmp`]'s), and how often
    /// each occurs.
    counts: std::collections::BTreeMap<u64, u64>,
    first_s: Option<f64>,
    last_s: Option<f64>,
    samples: usize,
}

impl StepCounts {
    /// Counts the next time, s.
    pub fn push(&mut self, t_s: f64) {
        if let Some(last) = self.last_s {
            *self.counts.entry(order_key(t_s - last)).or_default() += 1;
        } else {
            self.first_s = Some(t_s);
        }
        self.last_s = Some(t_s);
        self.samples += 1;
    }

    /// True when no time was counted.
    pub fn is_empty(&self) -> bool {
        self.samples == 0
    }

    /// Number of times counted.
    pub fn len(&self) -> usize {
        self.samples
    }

    /// The last time counted, s.
    pub fn last_s(&self) -> Option<f64> {
        self.last_s
    }

    /// The k-th smallest step (0-based).
    fn nth(&self, k: u64) -> f64 {
        let mut seen = 0;
        for (&key, &count) in &self.counts {
            seen += count;
            if k < seen {
                return from_order_key(key);
            }
        }
        unreachable!("k is below the number of steps")
    }

    /// The summary without its gaps; `None` for fewer than two samples.
    pub fn sampling_without_gaps(&self) -> Option<Sampling> {
        let steps = self.samples.checked_sub(1).filter(|&n| n > 0)? as u64;
        let at = |q: f64| self.nth(((steps - 1) as f64 * q).round() as u64);
        Some(Sampling {
            samples: self.samples,
            span_s: self.last_s? - self.first_s?,
            median_step_s: self.nth(steps / 2),
            min_step_s: self.nth(0),
            max_step_s: self.nth(steps - 1),
            p01_step_s: at(0.01),
            p99_step_s: at(0.99),
            gaps: Vec::new(),
        })
    }
}

/// An f64 as a u64 in [`f64::total_cmp`]'s order.
fn order_key(x: f64) -> u64 {
    let bits = x.to_bits();
    if bits >> 63 == 1 {
        !bits
    } else {
        bits | 1 << 63
    }
}

fn from_order_key(key: u64) -> f64 {
    f64::from_bits(if key >> 63 == 1 {
        key & !(1 << 63)
    } else {
        !key
    })
}

/// How an interchange file states its sample rate: a first line `# sample_rate_hz: 100`.
const RATE_LINE_PREFIX: &str = "# sample_rate_hz: ";

/// The sample rate a file states, Hz, with where it is stated (for errors): a CSV's `#`
/// line before the header (`line N`), a Parquet file's metadata entry.
pub(crate) fn read_stated_rate(path: &Path) -> Result<Option<(String, f64)>, TableError> {
    use std::io::BufRead;
    if parquet::is_parquet(path) {
        let place = format!("metadata `{}`", parquet::RATE_KEY);
        return Ok(parquet::stated_rate_hz(path)?.map(|rate| (place, rate)));
    }
    let reader = std::io::BufReader::new(open_maybe_gz(path)?.take(1 << 16));
    for (i, line) in reader.lines().enumerate() {
        let line = line.map_err(|source| TableError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let Some(comment) = line.strip_prefix('#') else {
            break;
        };
        let Some(value) = comment.trim().strip_prefix("sample_rate_hz:") else {
            continue;
        };
        let rate = value
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|r| r.is_finite() && *r > 0.0);
        return match rate {
            Some(rate) => Ok(Some((format!("line {}", i + 1), rate))),
            None => Err(TableError::Csv {
                path: path.to_path_buf(),
                line: i as u64 + 1,
                message: format!(
                    "`sample_rate_hz`: `{}` is not a positive number of Hz",
                    value.trim()
                ),
            }),
        };
    }
    Ok(None)
}

/// A stated rate must agree with the time column's median step to 1% (a clock off by
/// 10000 ppm, or a file whose rate line belongs to another file).
pub(crate) fn check_stated_rate(
    path: &Path,
    place: String,
    stated_hz: f64,
    t_s: &[f64],
) -> Result<(), TableError> {
    check_stated_rate_against(path, place, stated_hz, median_step_s(t_s))
}

/// [`check_stated_rate`] against a median step found otherwise (`None`: fewer than two
/// samples, nothing to check).
pub(crate) fn check_stated_rate_against(
    path: &Path,
    place: String,
    stated_hz: f64,
    median_step_s: Option<f64>,
) -> Result<(), TableError> {
    let Some(step) = median_step_s else {
        return Ok(());
    };
    if (step * stated_hz - 1.0).abs() > 0.01 {
        return Err(TableError::RateMismatch {
            path: path.to_path_buf(),
            place,
            stated_hz,
            median_step_s: step,
            measured_hz: 1.0 / step,
        });
    }
    Ok(())
}

/// `rate_hz` with the fewest significant digits that keep it within 1e-9 of itself: an
/// estimated rate of 100.00000000000213 Hz is stated as 100.
pub fn shortest_rate_hz(rate_hz: f64) -> f64 {
    (1..=17)
        .map(|digits| {
            let text = format!("{rate_hz:.*e}", digits - 1);
            text.parse::<f64>().unwrap_or(rate_hz)
        })
        .find(|r| ((r - rate_hz) / rate_hz).abs() <= 1e-9)
        .unwrap_or(rate_hz)
}

/// Names of the six IMU channels, in the order dynacal reports them.
pub const CHANNELS: [&str; 6] = {
    let all = crate::model::Channel::ALL;
    [
        all[0].name(),
        all[1].name(),
        all[2].name(),
        all[3].name(),
        all[4].name(),
        all[5].name(),
    ]
};

/// Interchange column names of the six IMU channels, in [`CHANNELS`] order.
pub const CHANNEL_COLUMNS: [&str; 6] = {
    let all = crate::model::Channel::ALL;
    [
        all[0].column(),
        all[1].column(),
        all[2].column(),
        all[3].column(),
        all[4].column(),
        all[5].column(),
    ]
};

/// Whether `name` is one of the format's columns other than `t_s` (a channel, attitude,
/// position or velocity): a file with `t_s` and one of them is an interchange recording.
pub fn is_interchange_column(name: &str) -> bool {
    [GYRO, ACCEL, ATTITUDE, POSITION, VELOCITY]
        .iter()
        .any(|triplet| triplet.contains(&name))
}

/// The interchange columns among `headers`, in the order a recording writes them (`t_s`,
/// the gyro and accelerometer triplets or their lone axes, attitude, position, velocity);
/// others are left out. An error, naming `path`, without `t_s` or for a triplet that is
/// neither whole nor (gyro, accelerometer) a lone axis, as a read refuses them.
pub fn interchange_columns(
    path: &Path,
    headers: &[String],
) -> Result<Vec<&'static str>, TableError> {
    let has = |name: &str| headers.iter().any(|h| h == name);
    if !has("t_s") {
        return Err(TableError::MissingColumn {
            path: path.to_path_buf(),
            column: "t_s".into(),
        });
    }
    let mut columns = vec!["t_s"];
    for names in [&GYRO, &ACCEL, &ATTITUDE, &POSITION, &VELOCITY] {
        let present: Vec<&'static str> = names.iter().copied().filter(|n| has(n)).collect();
        let lone_allowed = CHANNEL_COLUMNS.contains(&names[0]);
        match present.len() {
            0 => {}
            1 if lone_allowed => columns.extend(present),
            3 => columns.extend(present),
            _ => {
                return Err(TableError::IncompleteTriplet {
                    path: path.to_path_buf(),
                    present: present[0].to_string(),
                    missing: names.iter().find(|n| !has(n)).copied().unwrap_or("").into(),
                })
            }
        }
    }
    Ok(columns)
}

/// How a file holds one triplet of interchange columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum TripletPresence {
    Absent,
    Full,
    /// One gyro or accelerometer axis alone: that channel (index into [`CHANNEL_COLUMNS`]).
    LoneAxis {
        channel: usize,
    },
}

/// The rule for a triplet `names` of which the columns `present` are in `path`: all three, or
/// none, or one gyro or accelerometer axis alone; any other part of a triplet is an error
/// naming what is there and what is missing.
pub(crate) fn triplet_presence(
    path: &Path,
    names: &[&str; 3],
    present: [bool; 3],
) -> Result<TripletPresence, TableError> {
    let count = present.iter().filter(|p| **p).count();
    let lone_imu_channel = CHANNEL_COLUMNS.iter().position(|c| c == &names[0]);
    match (count, lone_imu_channel) {
        (0, _) => Ok(TripletPresence::Absent),
        (3, _) => Ok(TripletPresence::Full),
        (1, Some(first)) => Ok(TripletPresence::LoneAxis {
            channel: first + present.iter().position(|p| *p).unwrap_or(0),
        }),
        _ => {
            let present_at = present.iter().position(|p| *p).unwrap_or(0);
            let missing_at = present.iter().position(|p| !*p).unwrap_or(0);
            Err(TableError::IncompleteTriplet {
                path: path.to_path_buf(),
                present: names[present_at].to_string(),
                missing: names[missing_at].to_string(),
            })
        }
    }
}

/// The five triplets of interchange columns, in [`ImuRecording`]'s order: gyro,
/// accelerometer, attitude, position, velocity.
pub(crate) const TRIPLETS: [&[&str; 3]; 5] = [&GYRO, &ACCEL, &ATTITUDE, &POSITION, &VELOCITY];

const GYRO: [&str; 3] = ["gx_rad_s", "gy_rad_s", "gz_rad_s"];
const ACCEL: [&str; 3] = ["ax_m_s2", "ay_m_s2", "az_m_s2"];
const ATTITUDE: [&str; 3] = ["roll_rad", "pitch_rad", "yaw_rad"];
const POSITION: [&str; 3] = ["lat_rad", "lon_rad", "h_m"];
const VELOCITY: [&str; 3] = ["vn_m_s", "ve_m_s", "vd_m_s"];

/// Three columns of equal length, one per axis.
pub type Triplet = [Vec<f64>; 3];

/// One axis of a single-axis sensor: a gyro or accelerometer channel whose other two axes
/// do not exist (e.g. a lone gyro X record). At most one per triplet, and only when the
/// triplet itself is absent.
#[derive(Debug, Clone, PartialEq)]
pub struct SingleAxis {
    /// Index into [`CHANNELS`]: 0..3 gyro x, y, z (rad/s); 3..6 accelerometer x, y, z (m/s^2).
    pub channel: usize,
    /// One value per `t_s`, in the channel's unit, body frame (FRD) axis.
    pub values: Vec<f64>,
}

/// One sensor's recording in the interchange format, column by column (SI units).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImuRecording {
    /// Sample times, seconds, strictly increasing.
    pub t_s: Vec<f64>,
    /// Angular rate of the body w.r.t. inertial space, body frame (FRD), rad/s.
    pub gyro_rad_s: Option<Triplet>,
    /// Specific force, body frame (FRD), m/s^2.
    pub accel_m_s2: Option<Triplet>,
    /// Roll, pitch, yaw of the body w.r.t. local NED (Z-Y-X convention), rad.
    pub attitude_rad: Option<Triplet>,
    /// Geodetic latitude (rad), longitude (rad), ellipsoidal height (m).
    pub position: Option<Triplet>,
    /// Velocity w.r.t. Earth in NED, m/s.
    pub velocity_ned_m_s: Option<Triplet>,
    /// Lone channels of single-axis sensors (empty for ordinary three-axis recordings).
    pub single_axis: Vec<SingleAxis>,
    /// The nominal sample rate, Hz, where the source states it (the file's
    /// `# sample_rate_hz:` line, a board log's header, a simulated IMU's model); `None` where
    /// it does not, and [`ImuRecording::rate_hz`] estimates it from the time column.
    pub sample_rate_hz: Option<f64>,
}

/// Where an [`ImuRecording`] holds one of its channels.
enum ChannelSlot {
    Gyro(usize),
    Accel(usize),
    /// An index into [`ImuRecording::single_axis`].
    Single(usize),
}

impl ImuRecording {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }
    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }
    /// Samples `range` (by index), every column alike.
    pub fn rows_in(&self, range: std::ops::Range<usize>) -> ImuRecording {
        self.each_column(|c| c[range.clone()].to_vec())
    }

    /// The samples with `from_s <= t < to_s`, every column alike.
    pub fn between(&self, from_s: f64, to_s: f64) -> ImuRecording {
        let keep: Vec<bool> = self.t_s.iter().map(|t| *t >= from_s && *t < to_s).collect();
        self.each_column(|c| {
            c.iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(v, _)| *v)
                .collect()
        })
    }

    /// The recording with every column (time included) made by `column` of its own.
    fn each_column(&self, column: impl Fn(&Vec<f64>) -> Vec<f64>) -> ImuRecording {
        let triplet = |t: &Option<Triplet>| t.as_ref().map(|t| t.each_ref().map(&column));
        ImuRecording {
            t_s: column(&self.t_s),
            gyro_rad_s: triplet(&self.gyro_rad_s),
            accel_m_s2: triplet(&self.accel_m_s2),
            attitude_rad: triplet(&self.attitude_rad),
            position: triplet(&self.position),
            velocity_ned_m_s: triplet(&self.velocity_ned_m_s),
            single_axis: self
                .single_axis
                .iter()
                .map(|s| SingleAxis {
                    channel: s.channel,
                    values: column(&s.values),
                })
                .collect(),
            sample_rate_hz: self.sample_rate_hz,
        }
    }

    /// Median sampling interval, seconds (0 for fewer than two samples).
    pub fn median_dt_s(&self) -> f64 {
        median_step_s(&self.t_s).unwrap_or(0.0)
    }

    /// The sample rate, Hz: the stated one, else the reciprocal of the median step (0 for
    /// fewer than two samples).
    pub fn rate_hz(&self) -> f64 {
        match self.sample_rate_hz {
            Some(rate) => rate,
            None => median_step_s(&self.t_s)
                .filter(|&step| step > 0.0)
                .map_or(0.0, |step| 1.0 / step),
        }
    }
    /// A channel by its short name (`gx` ... `az`), if the recording has it.
    pub fn channel(&self, name: &str) -> Option<&[f64]> {
        Some(match self.channel_slot(name)? {
            ChannelSlot::Gyro(axis) => &self.gyro_rad_s.as_ref()?[axis],
            ChannelSlot::Accel(axis) => &self.accel_m_s2.as_ref()?[axis],
            ChannelSlot::Single(k) => &self.single_axis[k].values,
        })
    }
    /// A channel's values taken out of the recording (left empty), as
    /// [`ImuRecording::channel`] finds it: for a reader that keeps the series alone.
    pub fn take_channel(&mut self, name: &str) -> Option<Vec<f64>> {
        let values = match self.channel_slot(name)? {
            ChannelSlot::Gyro(axis) => &mut self.gyro_rad_s.as_mut()?[axis],
            ChannelSlot::Accel(axis) => &mut self.accel_m_s2.as_mut()?[axis],
            ChannelSlot::Single(k) => &mut self.single_axis[k].values,
        };
        Some(std::mem::take(values))
    }
    /// Where the channel `name` is held: an axis of a triplet, or a lone channel.
    fn channel_slot(&self, name: &str) -> Option<ChannelSlot> {
        let i = CHANNELS.iter().position(|c| *c == name)?;
        let triplet = if i < 3 {
            &self.gyro_rad_s
        } else {
            &self.accel_m_s2
        };
        match (triplet, i < 3) {
            (Some(_), true) => Some(ChannelSlot::Gyro(i % 3)),
            (Some(_), false) => Some(ChannelSlot::Accel(i % 3)),
            (None, _) => self
                .single_axis
                .iter()
                .position(|s| s.channel == i)
                .map(ChannelSlot::Single),
        }
    }
    /// The short names of the channels this recording has, in [`CHANNELS`] order.
    pub fn channels(&self) -> Vec<&'static str> {
        CHANNELS
            .iter()
            .copied()
            .filter(|c| self.channel(c).is_some())
            .collect()
    }

    fn triplets(&self) -> [(&'static [&'static str; 3], Option<&Triplet>); 5] {
        [
            (&GYRO, self.gyro_rad_s.as_ref()),
            (&ACCEL, self.accel_m_s2.as_ref()),
            (&ATTITUDE, self.attitude_rad.as_ref()),
            (&POSITION, self.position.as_ref()),
            (&VELOCITY, self.velocity_ned_m_s.as_ref()),
        ]
    }

    /// Checks lengths and time order, naming `path` in errors.
    pub fn validate(&self, path: &Path) -> Result<(), TableError> {
        self.validate_all_but_time(path)?;
        check_time_increasing(path, &self.t_s)
    }

    /// [`Self::validate`] but for the time's order, which a table's reader checks first with
    /// the file lines it knows (a second pass over a long time column cost a few ms).
    fn validate_all_but_time(&self, path: &Path) -> Result<(), TableError> {
        if self.t_s.is_empty() {
            return Err(TableError::Empty {
                path: path.to_path_buf(),
            });
        }
        for (names, triplet) in self.triplets() {
            if let Some(t) = triplet {
                for (name, col) in names.iter().zip(t.iter()) {
                    if col.len() != self.t_s.len() {
                        return Err(TableError::LengthMismatch {
                            path: path.to_path_buf(),
                            column: (*name).to_string(),
                            len: col.len(),
                            expected: self.t_s.len(),
                        });
                    }
                }
            }
        }
        let mut lone_in_triplet = [false; 2];
        for single in &self.single_axis {
            let bad = |message: String| TableError::Csv {
                path: path.to_path_buf(),
                line: 1,
                message,
            };
            let Some(column) = CHANNEL_COLUMNS.get(single.channel) else {
                return Err(bad(format!(
                    "single-axis channel index {} is not a channel (0..6)",
                    single.channel
                )));
            };
            let (kind, full) = if single.channel < 3 {
                (0, self.gyro_rad_s.is_some())
            } else {
                (1, self.accel_m_s2.is_some())
            };
            if full || lone_in_triplet[kind] {
                return Err(bad(format!(
                    "single-axis column `{column}` beside another column of its triplet"
                )));
            }
            lone_in_triplet[kind] = true;
            if single.values.len() != self.t_s.len() {
                return Err(TableError::LengthMismatch {
                    path: path.to_path_buf(),
                    column: (*column).to_string(),
                    len: single.values.len(),
                    expected: self.t_s.len(),
                });
            }
        }
        self.check_position_range(path)
    }

    /// Latitude within the poles and longitude within two turns: a position in degrees
    /// stored as radians fails here rather than as a navigation far off the Earth.
    fn check_position_range(&self, path: &Path) -> Result<(), TableError> {
        let Some([lat, lon, _]) = &self.position else {
            return Ok(());
        };
        for ((t_s, lat), lon) in self.t_s.iter().zip(lat).zip(lon) {
            check_lat_lon(path, *t_s, *lat, *lon)?;
        }
        Ok(())
    }

    /// Reads an interchange CSV, CSV.gz or Parquet file.
    pub fn read(path: &Path) -> Result<Self, TableError> {
        Self::read_with_lines(path).map(|(recording, _)| recording)
    }

    /// As [`Self::read`], with where its samples are in the file (for errors found later).
    pub fn read_with_lines(path: &Path) -> Result<(Self, RowLines), TableError> {
        Self::read_with_median(path).map(|(recording, lines, _)| (recording, lines))
    }

    /// As [`Self::read_with_lines`], with the time column's median step where the read found
    /// it ([`median_step_s`]; `None`: not computed), so a caller needing it does not select
    /// it again.
    pub fn read_with_median(path: &Path) -> Result<(Self, RowLines, Option<f64>), TableError> {
        let mut wanted: Vec<&str> = vec!["t_s"];
        for names in [&GYRO, &ACCEL, &ATTITUDE, &POSITION, &VELOCITY] {
            wanted.extend_from_slice(names);
        }
        let table = read_table(path, Some(&wanted))?;
        let row_lines = table.row_lines;
        let recording = Self::from_table(table)?;
        let stated = read_stated_rate(path)?;
        let sample_rate_hz = stated.as_ref().map(|(_, rate)| *rate);
        let median = stated.as_ref().and_then(|_| median_step_s(&recording.t_s));
        if let Some((place, stated_hz)) = stated {
            check_stated_rate_against(path, place, stated_hz, median)?;
        }
        let recording = ImuRecording {
            sample_rate_hz,
            ..recording
        };
        Ok((recording, row_lines, median))
    }

    /// The recording a table's interchange columns hold (others are ignored), checked as a
    /// file read is; no stated rate. Errors name the table's file.
    pub fn from_table(table: Table) -> Result<Self, TableError> {
        let Table {
            path,
            headers,
            columns,
            row_lines,
        } = table;
        let path = path.as_path();
        let mut columns: Vec<Option<Vec<f64>>> = columns.into_iter().map(Some).collect();
        let mut take = |name: &str| {
            let i = headers.iter().position(|h| h == name)?;
            columns[i].take()
        };
        let t_s = take("t_s").ok_or_else(|| TableError::MissingColumn {
            path: path.to_path_buf(),
            column: "t_s".into(),
        })?;
        check_time_increasing_at(path, &t_s, row_lines)?;
        let mut single_axis = Vec::new();
        let mut triplet = |names: &[&str; 3]| -> Result<Option<Triplet>, TableError> {
            let [x, y, z] = names.map(&mut take);
            let present = [x.is_some(), y.is_some(), z.is_some()];
            match triplet_presence(path, names, present)? {
                TripletPresence::Absent => Ok(None),
                TripletPresence::LoneAxis { channel } => {
                    single_axis.push(SingleAxis {
                        channel,
                        values: x.or(y).or(z).unwrap_or_default(),
                    });
                    Ok(None)
                }
                TripletPresence::Full => Ok(x.zip(y).zip(z).map(|((x, y), z)| [x, y, z])),
            }
        };
        let recording = ImuRecording {
            t_s,
            gyro_rad_s: triplet(&GYRO)?,
            accel_m_s2: triplet(&ACCEL)?,
            attitude_rad: triplet(&ATTITUDE)?,
            position: triplet(&POSITION)?,
            velocity_ned_m_s: triplet(&VELOCITY)?,
            single_axis,
            sample_rate_hz: None,
        };
        recording.validate_all_but_time(path)?;
        Ok(recording)
    }

    /// The recording's interchange columns in the order they are written: `t_s`, then the
    /// gyro, accelerometer (or their lone axes), attitude, position and velocity triplets.
    pub fn named_columns(&self) -> Vec<(&'static str, &[f64])> {
        let mut columns: Vec<(&'static str, &[f64])> = vec![("t_s", &self.t_s)];
        for (k, (names, t)) in self.triplets().into_iter().enumerate() {
            match t {
                Some(t) => columns.extend(names.iter().copied().zip(t.iter().map(Vec::as_slice))),
                // Lone gyro / accelerometer axes take their triplet's place.
                None if k < 2 => columns.extend(
                    self.single_axis
                        .iter()
                        .filter(|s| s.channel / 3 == k)
                        .map(|s| (CHANNEL_COLUMNS[s.channel], s.values.as_slice())),
                ),
                None => {}
            }
        }
        columns
    }

    /// Writes the recording as interchange CSV, gzip-compressed when `path` ends in `.gz`,
    /// or as Parquet when it ends in `.parquet`.
    /// The file appears whole or not at all. Values are written in Rust's shortest
    /// round-trip form, so reading them back gives the same `f64` bits.
    pub fn write(&self, path: &Path) -> Result<(), TableError> {
        self.validate(path)?;
        let columns = self.named_columns();
        let rate = self.sample_rate_hz.or_else(|| {
            median_step_s(&self.t_s)
                .filter(|step| *step > 0.0)
                .map(|step| shortest_rate_hz(1.0 / step))
        });
        let names: Vec<&'static str> = columns.iter().map(|c| c.0).collect();
        let mut out = RowWriter::create(path, names, rate)?;
        let mut row = vec![0.0; columns.len()];
        for i in 0..self.t_s.len() {
            for (value, (_, column)) in row.iter_mut().zip(&columns) {
                *value = column[i];
            }
            out.push(&row)?;
        }
        out.finish().map(|_| ())
    }
}

/// Latitude within the poles and longitude within two turns, rad: a position in degrees
/// stored as radians fails here rather than as a navigation far off the Earth.
pub(crate) fn check_lat_lon(
    path: &Path,
    t_s: f64,
    lat_rad: f64,
    lon_rad: f64,
) -> Result<(), TableError> {
    let half_pi = std::f64::consts::FRAC_PI_2;
    let two_pi = std::f64::consts::TAU;
    for (column, value, limit, range) in [
        ("lat_rad", lat_rad, half_pi, "[-pi/2, pi/2]"),
        ("lon_rad", lon_rad, two_pi, "[-2 pi, 2 pi]"),
    ] {
        if value.abs() > limit {
            return Err(TableError::OutOfRange {
                path: path.to_path_buf(),
                column,
                t_s,
                value,
                range,
            });
        }
    }
    Ok(())
}

/// The form an interchange file is written in; a writer chooses it by the file's name
/// ([`RowWriter`]), a command that names its files by this.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum FileFormat {
    /// CSV text.
    Csv,
    /// CSV text, gzip-compressed.
    #[default]
    CsvGz,
    /// Parquet: binary columns, the fastest to read.
    Parquet,
}

impl FileFormat {
    /// The file name ending that selects this form (no leading dot).
    pub fn extension(self) -> &'static str {
        match self {
            Self::Csv => "csv",
            Self::CsvGz => "csv.gz",
            Self::Parquet => "parquet",
        }
    }
}

/// Rows a [`RowWriter`] holds back when no rate is given: the rate it states is the median
/// step's over them (over the whole file, for files no longer than this).
const RATE_PROBE_ROWS: usize = 1 << 16;

/// What a [`RowWriter`] wrote.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowsWritten {
    pub rows: u64,
    /// First and last `t_s`, s.
    pub first_t_s: f64,
    pub last_t_s: f64,
}

/// An interchange file written one row at a time, in memory that does not grow with its
/// length (a long import): CSV text (gzip-compressed when the name ends in `.gz`), or
/// Parquet when it ends in `.parquet`. Each row is checked as [`ImuRecording::validate`]
/// checks a whole recording (time strictly increasing, latitude and longitude in range). The
/// file appears whole on [`RowWriter::finish`], or not at all.
pub struct RowWriter {
    path: PathBuf,
    columns: Vec<&'static str>,
    file: AtomicFile,
    sink: Option<Sink>,
    rate_hz: Option<f64>,
    /// Rows waiting for the rate to be known, flattened.
    held: Vec<f64>,
    written: RowsWritten,
    lat_lon: Option<(usize, usize)>,
}

/// Where a [`RowWriter`]'s rows go.
enum Sink {
    /// CSV lines gathered in `line` and written a block at a time.
    Text {
        out: Box<dyn Write + Send>,
        line: Vec<u8>,
        digits: zmij::Buffer,
    },
    Parquet(parquet::ParquetSink),
}

impl RowWriter {
    /// Starts `path` with `columns` (`t_s` first, then interchange columns). With no
    /// `rate_hz` the stated rate is the median step's over the first rows.
    pub fn create(
        path: &Path,
        columns: Vec<&'static str>,
        rate_hz: Option<f64>,
    ) -> Result<Self, TableError> {
        assert!(
            columns.first() == Some(&"t_s")
                && columns[1..].iter().all(|c| is_interchange_column(c)),
            "interchange columns are `t_s` then known columns: {columns:?}"
        );
        let io = |source| TableError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = AtomicFile::create(path).map_err(io)?;
        let out = file.owned_writer().map_err(io)?;
        let sink = if parquet::writes_parquet(path) {
            Sink::Parquet(parquet::ParquetSink::create(path, out, &columns)?)
        } else {
            Sink::Text {
                out,
                line: Vec::with_capacity(1 << 16),
                digits: zmij::Buffer::new(),
            }
        };
        let at = |name: &str| columns.iter().position(|c| *c == name);
        let lat_lon = at("lat_rad").zip(at("lon_rad"));
        let mut writer = Self {
            path: path.to_path_buf(),
            columns,
            file,
            sink: Some(sink),
            rate_hz,
            held: Vec::new(),
            written: RowsWritten {
                rows: 0,
                first_t_s: f64::NAN,
                last_t_s: f64::NAN,
            },
            lat_lon,
        };
        if rate_hz.is_some() {
            writer.write_header();
        }
        Ok(writer)
    }

    /// Appends one row, one value per column.
    pub fn push(&mut self, row: &[f64]) -> Result<(), TableError> {
        assert_eq!(row.len(), self.columns.len(), "one value per column");
        self.check(row)?;
        let w = &mut self.written;
        if w.rows == 0 {
            w.first_t_s = row[0];
        }
        w.last_t_s = row[0];
        w.rows += 1;
        // Until the rate is known (set when the held rows reach RATE_PROBE_ROWS).
        if self.rate_hz.is_none() {
            self.held.extend_from_slice(row);
            if self.held_rows() == RATE_PROBE_ROWS {
                self.release_held()?;
            }
            return Ok(());
        }
        self.write_row(row)
    }

    /// Writes what is held, moves the file into place and says what it holds; a file with
    /// no row is an error (and is not written).
    pub fn finish(mut self) -> Result<RowsWritten, TableError> {
        if self.written.rows == 0 {
            return Err(TableError::Empty { path: self.path });
        }
        if !self.held.is_empty() || self.rate_hz.is_none() {
            self.release_held()?;
        }
        self.flush_line()?;
        let io = |source| TableError::Io {
            path: self.path.clone(),
            source,
        };
        match self.sink.take() {
            Some(Sink::Text { mut out, .. }) => out.flush().map_err(io)?,
            Some(Sink::Parquet(sink)) => sink.finish(self.rate_hz)?,
            None => {}
        }
        self.file.commit().map_err(io)?;
        Ok(self.written)
    }

    fn held_rows(&self) -> usize {
        self.held.len() / self.columns.len()
    }

    fn check(&self, row: &[f64]) -> Result<(), TableError> {
        let t_s = row[0];
        if self.written.rows > 0 && !(t_s > self.written.last_t_s) {
            return Err(TableError::TimeNotIncreasingAtSample {
                path: self.path.clone(),
                sample: self.written.rows + 1,
                t_s,
                previous_t_s: self.written.last_t_s,
            });
        }
        if let Some((lat, lon)) = self.lat_lon {
            check_lat_lon(&self.path, t_s, row[lat], row[lon])?;
        }
        Ok(())
    }

    /// States the rate (the held rows' median step's if none was given), writes the header
    /// and the held rows.
    fn release_held(&mut self) -> Result<(), TableError> {
        if self.rate_hz.is_none() {
            let t_s: Vec<f64> = self
                .held
                .iter()
                .step_by(self.columns.len())
                .copied()
                .collect();
            self.rate_hz = median_step_s(&t_s)
                .filter(|step| *step > 0.0)
                .map(|step| shortest_rate_hz(1.0 / step))
                .or(Some(f64::NAN));
            self.write_header();
        }
        let held = std::mem::take(&mut self.held);
        for row in held.chunks_exact(self.columns.len()) {
            self.write_row(row)?;
        }
        Ok(())
    }

    /// The CSV form's rate line and header (a Parquet file's schema is written at its
    /// creation, its rate in its footer).
    fn write_header(&mut self) {
        use std::io::Write as _;
        let Some(Sink::Text { line, .. }) = self.sink.as_mut() else {
            return;
        };
        // NaN: fewer than two rows, no rate to state.
        if let Some(rate) = self.rate_hz.filter(|r| r.is_finite()) {
            let _ = writeln!(line, "{RATE_LINE_PREFIX}{rate}");
        }
        let _ = writeln!(line, "{}", self.columns.join(","));
    }

    fn write_row(&mut self, row: &[f64]) -> Result<(), TableError> {
        match self.sink.as_mut() {
            Some(Sink::Text { line, digits, .. }) => {
                for (k, value) in row.iter().enumerate() {
                    if k > 0 {
                        line.push(b',');
                    }
                    push_f64_display(line, *value, digits);
                }
                line.push(b'\n');
                if line.len() >= (1 << 16) - 1024 {
                    self.flush_line()?;
                }
                Ok(())
            }
            Some(Sink::Parquet(sink)) => sink.push(row),
            None => Ok(()),
        }
    }

    fn flush_line(&mut self) -> Result<(), TableError> {
        let Some(Sink::Text { out, line, .. }) = self.sink.as_mut() else {
            return Ok(());
        };
        out.write_all(line).map_err(|source| TableError::Io {
            path: self.path.clone(),
            source,
        })?;
        line.clear();
        Ok(())
    }
}

/// Appends `x` exactly as `format!("{x}")` writes it (shortest digits that read back to
/// the same bits, plain decimal notation, no exponent), about three times faster: `zmij`
/// (the shortest-digits formatter serde_json uses) finds the digits and they are laid out
/// here the way `Display` does. Hand-written layout because `zmij` writes `1.0` for whole
/// numbers and switches to exponent notation for small and large magnitudes, which the
/// files written so far never contain. Both algorithms return the shortest
/// round-tripping digits closest to the exact value, so the bytes are the same
/// (`fast_float_text_equals_display` checks this over millions of values).
pub fn push_f64_display(out: &mut Vec<u8>, x: f64, digits_buf: &mut zmij::Buffer) {
    if !x.is_finite() || shortest_digits_may_tie(x) {
        use std::io::Write as _;
        let _ = write!(out, "{x}");
        return;
    }
    let text = digits_buf.format_finite(x).as_bytes();
    if !text.contains(&b'e') {
        // Plain notation already; `Display` only drops the `.0` of whole numbers.
        out.extend_from_slice(text.strip_suffix(b".0").unwrap_or(text));
        return;
    }
    let (negative, text) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, text),
    };
    let (mantissa, exponent) = match text.iter().position(|&b| b == b'e') {
        Some(i) => {
            let e = std::str::from_utf8(&text[i + 1..])
                .ok()
                .and_then(|e| e.parse::<i32>().ok()) // `e-7`, `e+20`
                .unwrap_or(0);
            (&text[..i], e)
        }
        None => (text, 0),
    };
    // Digits without the point, and where the point goes among them.
    let mut digits = [0u8; 32];
    let mut n = 0usize;
    let mut point = mantissa.len() as i32;
    for (i, &b) in mantissa.iter().enumerate() {
        if b == b'.' {
            point = i as i32;
        } else {
            digits[n] = b;
            n += 1;
        }
    }
    point += exponent;
    let mut start = 0usize;
    while start < n && digits[start] == b'0' {
        start += 1;
        point -= 1;
    }
    while n > start && digits[n - 1] == b'0' {
        n -= 1;
    }
    if negative {
        out.push(b'-');
    }
    let digits = &digits[start..n];
    if digits.is_empty() {
        out.push(b'0');
    } else if point <= 0 {
        out.extend_from_slice(b"0.");
        out.extend(std::iter::repeat_n(b'0', (-point) as usize));
        out.extend_from_slice(digits);
    } else if point as usize >= digits.len() {
        out.extend_from_slice(digits);
        out.extend(std::iter::repeat_n(b'0', point as usize - digits.len()));
    } else {
        out.extend_from_slice(&digits[..point as usize]);
        out.push(b'.');
        out.extend_from_slice(&digits[point as usize..]);
    }
}

/// Whether two shortest decimal strings could be equally close to `x`. Then `zmij` and
/// `Display` may break the tie differently (e.g. 2031695609939685.25 gives `...685.2` and
/// `...685.3`), so [`push_f64_display`] leaves such values to `Display`. A tie between two
/// n-digit strings puts `x` exactly on an (n+1)-digit decimal, n <= 17; the exact decimal
/// expansion of `x = m 2^-k` (m odd) has as many significant digits as `m 5^k`, so when
/// `m 5^k >= 10^18` no tie is possible. Integers (k <= 0) and short dyadic fractions are
/// left to `Display`.
fn shortest_digits_may_tie(x: f64) -> bool {
    let bits = x.to_bits();
    let biased = ((bits >> 52) & 0x7ff) as i32;
    let fraction = bits & ((1u64 << 52) - 1);
    let (mut m, mut e) = if biased == 0 {
        (fraction, -1074)
    } else {
        (fraction | (1u64 << 52), biased - 1075)
    };
    if m == 0 {
        return false;
    }
    let zeros = m.trailing_zeros();
    m >>= zeros;
    e += zeros as i32;
    if e >= 0 {
        return true;
    }
    // log2(m 5^k) >= (bit length - 1) + k log2(5); 10^18 < 2^59.8.
    let log2_lower = (63 - m.leading_zeros()) as f64 + f64::from(-e) * 5f64.log2();
    log2_lower < 60.5
}

/// Checks that `t_s` strictly increases; the error names the sample (1-based) and its time,
/// for a column that no longer knows its file lines (a line counted from the header would
/// miss comment lines such as `# sample_rate_hz:`, and imported logs have none).
pub fn check_time_increasing(path: &Path, t_s: &[f64]) -> Result<(), TableError> {
    check_time_increasing_at(path, t_s, RowLines::Unknown)
}

/// As [`check_time_increasing`], naming the file line where the rows' lines are known.
pub fn check_time_increasing_at(
    path: &Path,
    t_s: &[f64],
    lines: RowLines,
) -> Result<(), TableError> {
    // On every core: a long recording's checks after its parallel read took a tenth of a
    // whole-file `wv` on one (BENCHMARKS.md, "Ingest", stop 67).
    let Some(i) = crate::numeric::first_bad_step(t_s, |previous, t| !(t > previous)) else {
        return Ok(());
    };
    let path = path.to_path_buf();
    let (t_s, previous_t_s) = (t_s[i + 1], t_s[i]);
    Err(match lines {
        RowLines::From(first) => TableError::TimeNotIncreasing {
            path,
            line: first + i as u64 + 1,
            t_s,
            previous_t_s,
        },
        RowLines::Unknown => TableError::TimeNotIncreasingAtSample {
            path,
            sample: i as u64 + 2,
            t_s,
            previous_t_s,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Time going back is named by its file line behind a comment header, and by its
    /// sample and time where a comment among the rows leaves the lines unknown.
    #[test]
    fn time_going_back_names_its_line_or_else_its_sample() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        std::fs::write(
            &path,
            "# sample_rate_hz: 100\nt_s,gx_rad_s\n0,1\n0.01,1\n0.005,1\n",
        )
        .unwrap();
        let e = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(e.contains("t.csv: line 5,") && e.contains("0.005"), "{e}");
        std::fs::write(&path, "t_s,gx_rad_s\n0,1\n# a note\n0.01,1\n0.005,1\n").unwrap();
        let e = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(e.contains("t.csv: sample 3 ") && e.contains("0.005"), "{e}");
    }

    /// The streamed step counts give [`Sampling::of`]'s percentiles exactly, on a jittered
    /// time line with a gap and repeated steps at a ROS stamp's epoch.
    #[test]
    fn step_counts_rank_the_steps_as_the_sort_does() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x57E9);
        let mut t = 1.7e9;
        let t_s: Vec<f64> = (0..20_000)
            .map(|i| {
                t += match i {
                    5000 => 0.5,
                    _ if i % 7 == 0 => 0.01,
                    _ => 0.01 + rng.random_range(-2e-4..2e-4),
                };
                t
            })
            .collect();
        let mut counts = StepCounts::default();
        t_s.iter().for_each(|&t| counts.push(t));
        let streamed = counts.sampling_without_gaps().unwrap();
        let sorted = Sampling::of(&t_s).unwrap();
        assert_eq!(
            streamed,
            Sampling {
                gaps: Vec::new(),
                ..sorted.clone()
            }
        );
        assert_eq!(sorted.gaps.len(), 1);
        let mut one = StepCounts::default();
        one.push(3.0);
        assert!(one.sampling_without_gaps().is_none());
        assert_eq!(from_order_key(order_key(-2.5)), -2.5);
        assert!(order_key(-1.0) < order_key(0.0) && order_key(0.0) < order_key(1e-300));
    }

    fn sample() -> ImuRecording {
        ImuRecording {
            t_s: vec![0.0, 0.01, 0.02],
            gyro_rad_s: Some([
                vec![0.1, 0.2, 1.0 / 3.0],
                vec![0.0; 3],
                vec![-1e-9, 2e-300, 5.0],
            ]),
            accel_m_s2: Some([vec![0.0; 3], vec![1.0; 3], vec![-9.81, -9.8, 9.7]]),
            ..Default::default()
        }
    }

    #[test]
    fn fast_float_text_equals_display() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
        let mut buf = zmij::Buffer::new();
        let mut out = Vec::new();
        let mut check = |x: f64| {
            out.clear();
            push_f64_display(&mut out, x, &mut buf);
            assert_eq!(std::str::from_utf8(&out).unwrap(), format!("{x}"), "{x:e}");
        };
        for x in [
            0.0,
            -0.0,
            1.0,
            -1.5,
            1e-7,
            1.5e-7,
            123456.0,
            1e15,
            1e16,
            1e21,
            1e300,
            -2.5e-300,
            5e-324,
            f64::MAX,
            f64::MIN_POSITIVE,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            0.1 + 0.2,
            2031695609939685.0 + 0.25,
            0.5,
            0.375,
            3.0,
            1e23,
            2f64.powi(53) + 2.0,
        ] {
            check(x);
        }
        for _ in 0..1_000_000 {
            // Random bit patterns (every magnitude), and values like sensor outputs.
            check(f64::from_bits(rng.random::<u64>()));
            let q: i32 = rng.random_range(-60_000..60_000);
            check(q as f64 / 1e4);
            check(rng.random_range(-1.0..1.0) * 10f64.powi(rng.random_range(-12..8)));
            // Few-bit values, where ties live.
            let few_bits: i64 = rng.random_range(-(1 << 20)..(1 << 20));
            check(few_bits as f64 * 2f64.powi(rng.random_range(-80..80)));
        }
    }

    #[test]
    fn rows_written_one_by_one_are_the_whole_write_and_a_bad_row_leaves_no_file() {
        // Longer than the rows held to state a rate, with one gap: the stated rate is the
        // held rows' median step's, the bytes those of a whole recording's write.
        let dir = tempfile::tempdir().unwrap();
        let n = RATE_PROBE_ROWS + 5_000;
        let t_s: Vec<f64> = (0..n)
            .map(|i| i as f64 * 0.02 + if i > 1000 { 0.5 } else { 0.0 })
            .collect();
        let gx: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin() * 1e-3).collect();
        let rec = ImuRecording {
            t_s: t_s.clone(),
            single_axis: vec![SingleAxis {
                channel: 0,
                values: gx.clone(),
            }],
            ..Default::default()
        };
        let whole = dir.path().join("whole.csv");
        rec.write(&whole).unwrap();
        let streamed = dir.path().join("streamed.csv");
        let mut writer = RowWriter::create(&streamed, vec!["t_s", "gx_rad_s"], None).unwrap();
        for (t, g) in t_s.iter().zip(&gx) {
            writer.push(&[*t, *g]).unwrap();
        }
        let written = writer.finish().unwrap();
        assert_eq!(written.rows, n as u64);
        assert_eq!((written.first_t_s, written.last_t_s), (t_s[0], t_s[n - 1]));
        let text = std::fs::read_to_string(&streamed).unwrap();
        assert!(
            text.starts_with("# sample_rate_hz: 50\nt_s,gx_rad_s\n"),
            "{}",
            &text[..40]
        );
        assert_eq!(text, std::fs::read_to_string(&whole).unwrap());

        // Time going back after the held rows were written: the sample is named and neither
        // the file nor a temporary is left.
        let bad = dir.path().join("bad.csv.gz");
        let mut writer = RowWriter::create(&bad, vec!["t_s", "gx_rad_s"], None).unwrap();
        for t in t_s.iter().take(RATE_PROBE_ROWS + 10) {
            writer.push(&[*t, 0.0]).unwrap();
        }
        let err = writer.push(&[1.0, 0.0]).unwrap_err().to_string();
        assert!(
            err.contains(&format!("sample {}", RATE_PROBE_ROWS + 11)),
            "{err}"
        );
        drop(writer);
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert_eq!(left.len(), 2, "{left:?}");
        let empty = RowWriter::create(&bad, vec!["t_s", "gx_rad_s"], Some(10.0)).unwrap();
        assert!(matches!(empty.finish(), Err(TableError::Empty { .. })));
        assert!(!bad.exists());
    }

    #[test]
    fn write_then_read_gives_identical_bits_plain_and_gz() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["a.csv", "a.csv.gz"] {
            let path = dir.path().join(name);
            sample().write(&path).unwrap();
            // The rate the sample does not state is estimated once, written and read back.
            let stated = ImuRecording {
                sample_rate_hz: Some(100.0),
                ..sample()
            };
            assert_eq!(ImuRecording::read(&path).unwrap(), stated);
            stated.write(&path).unwrap();
            assert_eq!(ImuRecording::read(&path).unwrap(), stated);
        }
    }

    #[test]
    fn a_stated_rate_is_checked_against_the_time_column_and_lines_still_count() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.csv");
        std::fs::write(
            &path,
            "# sample_rate_hz: 200\nt_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0.01,1,2,3\n",
        )
        .unwrap();
        let e = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(
            e.contains("r.csv") && e.contains("line 1") && e.contains("200 Hz"),
            "{e}"
        );
        std::fs::write(
            &path,
            "# sample_rate_hz: 100\nt_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0.01,1,x,3\n",
        )
        .unwrap();
        let e = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(e.contains("line 4") && e.contains("gy_rad_s"), "{e}");
        std::fs::write(&path, "# sample_rate_hz: fast\nt_s,gx_rad_s\n0,1\n").unwrap();
        let e = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("`fast`"), "{e}");
        assert_eq!(shortest_rate_hz(100.00000000000213), 100.0);
        let odd = 1.0 / 0.0049999;
        assert_eq!(shortest_rate_hz(odd), 200.004);
        assert!((shortest_rate_hz(odd) / odd - 1.0).abs() <= 1e-9);
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.csv");
        std::fs::write(
            &path,
            "t_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0.1,1,x,3\n",
        )
        .unwrap();
        let msg = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("bad.csv") && msg.contains("line 3") && msg.contains("gy_rad_s"),
            "{msg}"
        );

        std::fs::write(
            &path,
            "t_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0.1,1,2,3\n0.05,1,2,3\n",
        )
        .unwrap();
        let msg = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(msg.contains("line 4") && msg.contains("t_s"), "{msg}");

        std::fs::write(&path, "t_s,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n0.1,1,2\n").unwrap();
        let msg = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(msg.contains("line 3: 3 fields, expected 4"), "{msg}");

        std::fs::write(&path, "time,gx_rad_s,gy_rad_s,gz_rad_s\n0,1,2,3\n").unwrap();
        let msg = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(msg.contains("missing required column `t_s`"), "{msg}");

        std::fs::write(&path, "t_s,gx_rad_s,gy_rad_s\n0,1,2\n").unwrap();
        let msg = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(msg.contains("gz_rad_s"), "{msg}");
    }

    #[test]
    fn unknown_columns_are_ignored_even_if_not_numbers() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.csv");
        std::fs::write(
            &path,
            "note,t_s,ax_m_s2,ay_m_s2,az_m_s2\nhello,0,1,2,3\nworld,1,1,2,3\n",
        )
        .unwrap();
        let rec = ImuRecording::read(&path).unwrap();
        assert_eq!(rec.channels(), vec!["ax", "ay", "az"]);
        assert_eq!(rec.channel("az").unwrap(), &[3.0, 3.0]);
    }

    #[test]
    fn single_axis_gyro_and_reference_only_files_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("gx.csv");
        std::fs::write(&path, "t_s,gx_rad_s\n0,0.5\n0.01,-0.25\n").unwrap();
        let rec = ImuRecording::read(&path).unwrap();
        assert_eq!(rec.channels(), vec!["gx"]);
        assert_eq!(rec.channel("gx").unwrap(), &[0.5, -0.25]);
        assert!(rec.gyro_rad_s.is_none() && rec.channel("gy").is_none());
        let out = dir.path().join("gx-out.csv");
        rec.write(&out).unwrap();
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            "# sample_rate_hz: 100\nt_s,gx_rad_s\n0,0.5\n0.01,-0.25\n"
        );

        // A lone accelerometer axis next to a full gyro triplet is fine too.
        std::fs::write(
            &path,
            "t_s,gx_rad_s,gy_rad_s,gz_rad_s,az_m_s2\n0,1,2,3,-9.8\n",
        )
        .unwrap();
        let rec = ImuRecording::read(&path).unwrap();
        assert_eq!(rec.channels(), vec!["gx", "gy", "gz", "az"]);

        // No IMU channel at all: a reference trajectory (attitude only).
        std::fs::write(&path, "t_s,roll_rad,pitch_rad,yaw_rad\n0,0.1,0.2,0.3\n").unwrap();
        let rec = ImuRecording::read(&path).unwrap();
        assert!(rec.channels().is_empty());
        assert_eq!(rec.attitude_rad.as_ref().unwrap()[2], vec![0.3]);

        // Navigation triplets stay all-or-nothing; a lone channel cannot sit beside its triplet.
        std::fs::write(&path, "t_s,roll_rad\n0,0.1\n").unwrap();
        let msg = ImuRecording::read(&path).unwrap_err().to_string();
        assert!(msg.contains("pitch_rad"), "{msg}");
        let mut both = sample();
        both.single_axis.push(SingleAxis {
            channel: 1,
            values: vec![0.0; 3],
        });
        let msg = both.write(&out).unwrap_err().to_string();
        assert!(msg.contains("gy_rad_s"), "{msg}");
    }

    #[test]
    fn failed_write_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.csv");
        let mut bad = sample();
        bad.t_s[2] = 0.0;
        assert!(bad.write(&path).is_err());
        assert!(!path.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
