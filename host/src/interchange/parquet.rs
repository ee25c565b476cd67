//! Interchange recordings as Parquet files: the same columns, units and rules as the CSV form
//! (`docs/formats.md` section 1), stored column by column in binary, for recordings of hours
//! (a 10-hour 1 kHz log is 2.4 GB of CSV text). A file is Parquet when it starts with the
//! magic `PAR1`, whatever its name; writers write Parquet when the name ends in `.parquet`.
//! The stated sample rate, a `# sample_rate_hz:` line in a CSV, is the key-value metadata
//! entry `sample_rate_hz` here.
//!
//! Read: every flat column of a numeric physical type (double, float, 32- and 64-bit
//! integers, as pandas, polars and pyarrow write them) is read as `f64`; nested columns are
//! ignored as unknown CSV columns are; a wanted column of another type, a list, a null or a
//! value that is not finite is an error naming the file, the column and the row (1-based,
//! among the data rows). Columns are decoded [`BATCH_ROWS`] rows at a time, so the memory a
//! read holds beside its output does not grow with a row group's size; a whole-file read
//! decodes every row group's columns at once on every core, each into its place in the
//! table. Written: required doubles, BYTE_STREAM_SPLIT encoded
//! (a float's bytes grouped by significance, which compresses where raw IEEE bytes do not)
//! and zstd-compressed, in row groups of [`GROUP_ROWS`] rows.
//!
//! The low-level column API of the `parquet` crate is used, not Arrow: dynacal's columns are
//! plain `f64` slices, and Arrow would add its arrays (and a minute of build) for nothing.

use std::fs::File;
use std::io::{Read, Write};
use std::mem::MaybeUninit;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ::parquet::basic::{
    Compression, ConvertedType, Encoding, LogicalType, Repetition, Type as PhysicalType, ZstdLevel,
};
use ::parquet::column::reader::{ColumnReader, ColumnReaderImpl};
use ::parquet::data_type::{DataType, DoubleType, FloatType, Int32Type, Int64Type};
use ::parquet::errors::ParquetError;
use ::parquet::file::metadata::KeyValue;
use ::parquet::file::properties::WriterProperties;
use ::parquet::file::reader::{ChunkReader, FileReader, Length, SerializedFileReader};
use ::parquet::file::writer::SerializedFileWriter;
use ::parquet::schema::types::{ColumnDescriptor, Type as SchemaType};
use rayon::prelude::*;

use super::{RowLines, Table, TableError};
use crate::output::AtomicFile;
use crate::progress::Reporter;

/// The four bytes a Parquet file starts (and ends) with.
pub const MAGIC: &[u8; 4] = b"PAR1";

/// The key-value metadata entry holding the stated sample rate, Hz (as text, as in the CSV
/// form's `# sample_rate_hz:` line).
pub const RATE_KEY: &str = "sample_rate_hz";

/// Rows decoded at a time per column when reading.
pub const BATCH_ROWS: usize = 1 << 16;

/// Rows per row group when writing: 1 MiB of each column, big enough for compression and
/// column reads to run at full speed, small enough that a writer holds little.
pub const GROUP_ROWS: usize = 1 << 17;

/// Whether `path` starts with the Parquet magic (false if it cannot be read).
pub fn is_parquet(path: &Path) -> bool {
    let mut magic = [0u8; 4];
    File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok()
        && &magic == MAGIC
}

/// Whether a file written to `path` is written as Parquet (its name ends in `.parquet`).
pub fn writes_parquet(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("parquet"))
}

fn format_error(path: &Path, message: impl std::fmt::Display) -> TableError {
    TableError::Parquet {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// The file's reader (its footer read and checked) and its size on disk, bytes.
fn open_file(path: &Path) -> Result<(SerializedFileReader<PositionalFile>, u64), TableError> {
    let io = |source| TableError::Io {
        path: path.to_path_buf(),
        source,
    };
    let handle = File::open(path).map_err(io)?;
    let size_bytes = handle.metadata().map_err(io)?.len();
    let source = PositionalFile {
        file: Arc::new(handle),
        len_bytes: size_bytes,
    };
    let file = SerializedFileReader::new(source).map_err(|e| unreadable_file(path, e))?;
    Ok((file, size_bytes))
}

/// A Parquet file read by positional reads (`pread`), which share no file offset: the
/// `parquet` crate's own source for a `File` reads through handles cloned from it, whose
/// clones share one offset, so columns decoded on several threads would read each other's
/// pages (seen: snappy reporting corrupt input).
struct PositionalFile {
    file: Arc<File>,
    /// The file's size when opened.
    len_bytes: u64,
}

impl PositionalFile {
    fn reader_at(&self, start: u64) -> PositionalRead {
        PositionalRead {
            file: Arc::clone(&self.file),
            at_byte: start,
        }
    }
}

/// Reads a [`PositionalFile`] onward from a position of its own.
struct PositionalRead {
    file: Arc<File>,
    at_byte: u64,
}

impl Read for PositionalRead {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let read = read_at(&self.file, buf, self.at_byte)?;
        self.at_byte += read as u64;
        Ok(read)
    }
}

#[cfg(unix)]
fn read_at(file: &File, buf: &mut [u8], at_byte: u64) -> std::io::Result<usize> {
    std::os::unix::fs::FileExt::read_at(file, buf, at_byte)
}

#[cfg(windows)]
fn read_at(file: &File, buf: &mut [u8], at_byte: u64) -> std::io::Result<usize> {
    // Moves the handle's offset too, which no reader here relies on.
    std::os::windows::fs::FileExt::seek_read(file, buf, at_byte)
}

impl Length for PositionalFile {
    fn len(&self) -> u64 {
        self.len_bytes
    }
}

impl ChunkReader for PositionalFile {
    type T = std::io::BufReader<PositionalRead>;

    fn get_read(&self, start: u64) -> ::parquet::errors::Result<Self::T> {
        Ok(std::io::BufReader::new(self.reader_at(start)))
    }

    fn get_bytes(&self, start: u64, length: usize) -> ::parquet::errors::Result<bytes::Bytes> {
        // Read into spare capacity: zeroing the buffer first cost a few percent of a read.
        let mut buffer = Vec::with_capacity(length);
        let read = self
            .reader_at(start)
            .take(length as u64)
            .read_to_end(&mut buffer)?;
        if read != length {
            return Err(ParquetError::EOF(format!(
                "expected {length} bytes at byte {start}, the file has {read}"
            )));
        }
        Ok(buffer.into())
    }
}

fn unreadable_file(path: &Path, e: ParquetError) -> TableError {
    format_error(
        path,
        format!("not a readable Parquet file (cut short or damaged?): {e}"),
    )
}

/// One column's reader of the current row group, by the physical type it holds.
enum NumberReader {
    F64(ColumnReaderImpl<DoubleType>),
    F32(ColumnReaderImpl<FloatType>),
    I32(ColumnReaderImpl<Int32Type>),
    I64(ColumnReaderImpl<Int64Type>),
}

impl NumberReader {
    fn new(reader: ColumnReader) -> Self {
        match reader {
            ColumnReader::DoubleColumnReader(r) => Self::F64(r),
            ColumnReader::FloatColumnReader(r) => Self::F32(r),
            ColumnReader::Int32ColumnReader(r) => Self::I32(r),
            ColumnReader::Int64ColumnReader(r) => Self::I64(r),
            // Types are checked when the file is opened.
            _ => unreachable!("a column of a type checked at open"),
        }
    }

    /// Up to `rows` records into `out` (non-null values only) and, for a nullable column,
    /// their definition levels into `levels`; the number of records read.
    fn read(
        &mut self,
        rows: usize,
        nullable: bool,
        levels: &mut Vec<i16>,
        out: &mut Vec<f64>,
    ) -> Result<usize, ParquetError> {
        fn typed<T: DataType>(
            reader: &mut ColumnReaderImpl<T>,
            rows: usize,
            levels: Option<&mut Vec<i16>>,
            out: &mut Vec<f64>,
            as_f64: impl Fn(&T::T) -> f64,
        ) -> Result<usize, ParquetError>
        where
            T::T: Clone,
        {
            let mut values: Vec<T::T> = Vec::with_capacity(rows);
            let (records, _, _) = reader.read_records(rows, levels, None, &mut values)?;
            out.extend(values.iter().map(as_f64));
            Ok(records)
        }
        let levels = nullable.then_some(levels);
        match self {
            Self::F64(r) => {
                let (records, _, _) = r.read_records(rows, levels, None, out)?;
                Ok(records)
            }
            Self::F32(r) => typed(r, rows, levels, out, |v| f64::from(*v)),
            Self::I32(r) => typed(r, rows, levels, out, |v| f64::from(*v)),
            Self::I64(r) => typed(r, rows, levels, out, |v| *v as f64),
        }
    }
}

/// What one column's read of a block gave: records read, and its first non-finite value's
/// offset, if any.
struct ColumnRead {
    records: usize,
    non_finite: Option<usize>,
}

/// Why a leaf column cannot be read as numbers, if it cannot.
fn unreadable(descr: &ColumnDescriptor) -> Option<String> {
    if descr.max_rep_level() > 0 {
        return Some("is a list, not one number a row".into());
    }
    match descr.physical_type() {
        PhysicalType::DOUBLE | PhysicalType::FLOAT | PhysicalType::INT32 | PhysicalType::INT64 => {}
        PhysicalType::BYTE_ARRAY | PhysicalType::FIXED_LEN_BYTE_ARRAY => {
            return Some("holds text or bytes, not numbers".into())
        }
        other => return Some(format!("holds {other} values, not numbers")),
    }
    // A decimal's, a timestamp's or a date's integers are not the numbers they stand for.
    let stands_for = match descr.logical_type_ref() {
        None | Some(LogicalType::Integer { .. }) => None,
        Some(LogicalType::Timestamp { .. }) => Some("timestamps".to_string()),
        Some(LogicalType::Date) => Some("dates".into()),
        Some(LogicalType::Time { .. }) => Some("times of day".into()),
        Some(LogicalType::Decimal { .. }) => Some("decimals".into()),
        Some(other) => Some(format!("{other:?}")),
    }
    .or_else(|| {
        let converted = descr.converted_type();
        let plain = matches!(
            converted,
            ConvertedType::NONE
                | ConvertedType::INT_8
                | ConvertedType::INT_16
                | ConvertedType::INT_32
                | ConvertedType::INT_64
                | ConvertedType::UINT_8
                | ConvertedType::UINT_16
                | ConvertedType::UINT_32
                | ConvertedType::UINT_64
        );
        (!plain).then(|| converted.to_string())
    })?;
    Some(format!(
        "holds {stands_for}, not plain numbers (interchange columns are SI values: seconds, \
         rad/s, m/s^2)"
    ))
}

/// Rows of a Parquet file's wanted columns.
pub struct Block<'a> {
    /// 1-based index of the block's first row among the file's data rows.
    pub first_row: u64,
    /// One `Vec` per column of [`ParquetColumns::headers`], all of one length, at most
    /// [`BATCH_ROWS`].
    pub columns: &'a [Vec<f64>],
}

/// Rows of a Parquet file's wanted columns, moved out of the reader (see
/// [`ParquetColumns::next_owned`]).
pub struct OwnedBlock {
    /// 1-based index of the block's first row among the file's data rows.
    pub first_row: u64,
    /// As [`Block::columns`].
    pub columns: Vec<Vec<f64>>,
}

/// A Parquet interchange file's wanted columns read in blocks of rows, in memory that does
/// not grow with the file.
pub struct ParquetColumns {
    path: PathBuf,
    file: SerializedFileReader<PositionalFile>,
    /// The wanted columns' names, in file order, and their leaf indices and nullability.
    headers: Vec<String>,
    leaves: Vec<(usize, bool)>,
    next_group: usize,
    /// The current row group's column readers (empty between groups) and rows left in it.
    readers: Vec<NumberReader>,
    group_rows_left: u64,
    group_bytes: u64,
    rows_read: u64,
    block: Vec<Vec<f64>>,
    /// Each column's definition levels of its last read (nullable columns only).
    levels: Vec<Vec<i16>>,
    reporter: Reporter,
}

impl ParquetColumns {
    /// Opens `path` and checks the wanted columns (all flat columns if `wanted` is None);
    /// names in `wanted` that are absent are left out, as a CSV reader does.
    pub fn open(path: &Path, wanted: Option<&[&str]>) -> Result<Self, TableError> {
        let (file, size_bytes) = open_file(path)?;
        let schema = file.metadata().file_metadata().schema_descr_ptr();
        let mut headers = Vec::new();
        let mut leaves = Vec::new();
        for (i, descr) in schema.columns().iter().enumerate() {
            let name = descr.name();
            let flat = descr.path().parts().len() == 1;
            let is_wanted = wanted.is_none_or(|w| w.contains(&name));
            if !flat || !is_wanted || headers.iter().any(|h| h == name) {
                continue;
            }
            if let Some(why) = unreadable(descr) {
                return Err(format_error(path, format!("column `{name}` {why}")));
            }
            headers.push(name.to_string());
            leaves.push((i, descr.max_def_level() > 0));
        }
        Ok(Self {
            path: path.to_path_buf(),
            block: vec![Vec::new(); headers.len()],
            levels: vec![Vec::new(); headers.len()],
            headers,
            leaves,
            next_group: 0,
            readers: Vec::new(),
            group_rows_left: 0,
            group_bytes: 0,
            rows_read: 0,
            reporter: Reporter::new(path, size_bytes),
            file,
        })
    }

    /// The wanted columns present, in file order.
    pub fn headers(&self) -> &[String] {
        &self.headers
    }

    /// The stated sample rate (metadata `sample_rate_hz`), Hz; an error if it is not a
    /// positive number.
    pub fn stated_rate_hz(&self) -> Result<Option<f64>, TableError> {
        let Some(entries) = self.file.metadata().file_metadata().key_value_metadata() else {
            return Ok(None);
        };
        let Some(entry) = entries.iter().find(|kv| kv.key == RATE_KEY) else {
            return Ok(None);
        };
        let text = entry.value.as_deref().unwrap_or("").trim();
        match text.parse::<f64>() {
            Ok(rate) if rate.is_finite() && rate > 0.0 => Ok(Some(rate)),
            _ => Err(format_error(
                &self.path,
                format!("metadata `{RATE_KEY}`: `{text}` is not a positive number of Hz"),
            )),
        }
    }

    /// The next block of rows; None at the end of the file.
    pub fn next_block(&mut self) -> Result<Option<Block<'_>>, TableError> {
        Ok(self.read_next()?.map(|first_row| Block {
            first_row,
            columns: &self.block,
        }))
    }

    /// As [`Self::next_block`], the rows moved out to the caller, `reuse` (a spent block's
    /// buffers) taken for the next read: for a caller that works on one block while the
    /// next is decoded.
    pub fn next_owned(&mut self, reuse: Vec<Vec<f64>>) -> Result<Option<OwnedBlock>, TableError> {
        let Some(first_row) = self.read_next()? else {
            return Ok(None);
        };
        let mut columns = reuse;
        columns.resize_with(self.headers.len(), Vec::new);
        std::mem::swap(&mut columns, &mut self.block);
        Ok(Some(OwnedBlock { first_row, columns }))
    }

    /// The next block of rows read into `self.block`; its first row's index, None at the end.
    fn read_next(&mut self) -> Result<Option<u64>, TableError> {
        while self.group_rows_left == 0 {
            if self.next_group == self.file.num_row_groups() {
                self.reporter.add(self.group_bytes);
                self.group_bytes = 0;
                return Ok(None);
            }
            self.open_group()?;
        }
        let rows = BATCH_ROWS.min(usize::try_from(self.group_rows_left).unwrap_or(BATCH_ROWS));
        let first_row = self.rows_read + 1;
        self.read_columns(rows, first_row)?;
        self.group_rows_left -= rows as u64;
        self.rows_read += rows as u64;
        Ok(Some(first_row))
    }

    fn open_group(&mut self) -> Result<(), TableError> {
        self.reporter.add(self.group_bytes);
        let group = self
            .file
            .get_row_group(self.next_group)
            .map_err(|e| self.damaged(e))?;
        let meta = group.metadata();
        self.group_rows_left = u64::try_from(meta.num_rows()).unwrap_or(0);
        self.group_bytes = u64::try_from(meta.compressed_size()).unwrap_or(0);
        let mut readers = Vec::with_capacity(self.leaves.len());
        for &(leaf, _) in &self.leaves {
            let reader = group.get_column_reader(leaf).map_err(|e| self.damaged(e))?;
            readers.push(NumberReader::new(reader));
        }
        self.readers = readers;
        self.next_group += 1;
        Ok(())
    }

    /// Every column's next `rows` values into the block, checked: no null, every value
    /// finite. The columns are decoded in parallel (each its own pages and decompression);
    /// an error names the first failing column in file order, as a serial read would.
    fn read_columns(&mut self, rows: usize, first_row: u64) -> Result<(), TableError> {
        let outcomes: Vec<Result<ColumnRead, ParquetError>> = self
            .readers
            .par_iter_mut()
            .zip(&mut self.block)
            .zip(&mut self.levels)
            .zip(&self.leaves)
            .map(|(((reader, out), levels), &(_, nullable))| {
                out.clear();
                levels.clear();
                let records = reader.read(rows, nullable, levels, out)?;
                let non_finite = crate::numeric::first_non_finite(out);
                Ok(ColumnRead {
                    records,
                    non_finite,
                })
            })
            .collect();
        for (k, outcome) in outcomes.into_iter().enumerate() {
            let outcome = outcome.map_err(|e| {
                format_error(&self.path, format!("column `{}`: {e}", self.headers[k]))
            })?;
            let column = (self.path.as_path(), self.headers[k].as_str());
            let values = (self.block[k].as_slice(), self.levels[k].as_slice());
            check_read(column, &outcome, values, rows, first_row)?;
        }
        Ok(())
    }

    fn damaged(&self, e: ParquetError) -> TableError {
        damaged_group(&self.path, self.next_group, e)
    }
}

/// Row group `group` (0-based) of `path` could not be opened.
fn damaged_group(path: &Path, group: usize, e: ParquetError) -> TableError {
    format_error(path, format!("row group {}: {e}", group + 1))
}

/// A read's check: `read` of `rows` records from row `first_row` on left these values and
/// definition levels; an error at the first missing, null or non-finite value, naming the
/// file and column `(path, name)`.
fn check_read(
    (path, name): (&Path, &str),
    read: &ColumnRead,
    (out, levels): (&[f64], &[i16]),
    rows: usize,
    first_row: u64,
) -> Result<(), TableError> {
    let error = |offset: usize, message: String| TableError::AtRow {
        path: path.to_path_buf(),
        row: first_row + offset as u64,
        column: name.to_string(),
        message,
    };
    if read.records < rows {
        return Err(error(read.records, "the column ends early".into()));
    }
    if out.len() < rows {
        let null = levels.iter().position(|&l| l == 0).unwrap_or(out.len());
        return Err(error(null, "empty (null), not a number".into()));
    }
    if let Some(i) = read.non_finite {
        let value = out[i];
        return Err(error(i, format!("{value} is not a finite number")));
    }
    Ok(())
}

/// What the decoding tasks of a whole-file read share (the file and its wanted columns).
struct WholeRead<'a> {
    path: &'a Path,
    file: &'a SerializedFileReader<PositionalFile>,
    headers: &'a [String],
    leaves: &'a [(usize, bool)],
}

impl WholeRead<'_> {
    /// Column `k` of row group `group`, whose first row is `first_row` (1-based), decoded
    /// into `stretch` (as many values as the group has rows) [`BATCH_ROWS`] at a time and
    /// checked as a serial read checks it; an error comes with where a serial read would
    /// have met it ([`ReadPlace`]).
    fn decode_group_column(
        &self,
        group: usize,
        k: usize,
        first_row: u64,
        stretch: &mut [MaybeUninit<f64>],
    ) -> Result<(), (ReadPlace, TableError)> {
        let opening = |e| {
            (
                ReadPlace::opening(group, k),
                damaged_group(self.path, group, e),
            )
        };
        let reader = self.file.get_row_group(group).map_err(opening)?;
        let (leaf, nullable) = self.leaves[k];
        let mut column = NumberReader::new(reader.get_column_reader(leaf).map_err(opening)?);
        let (mut out, mut levels) = (Vec::with_capacity(BATCH_ROWS), Vec::new());
        let mut row = first_row;
        for (batch, room) in stretch.chunks_mut(BATCH_ROWS).enumerate() {
            let place = ReadPlace::reading(group, batch, k);
            out.clear();
            levels.clear();
            let records = column
                .read(room.len(), nullable, &mut levels, &mut out)
                .map_err(|e| {
                    let message = format!("column `{}`: {e}", self.headers[k]);
                    (place, format_error(self.path, message))
                })?;
            let read = ColumnRead {
                records,
                non_finite: crate::numeric::first_non_finite(&out),
            };
            check_read(
                (self.path, &self.headers[k]),
                &read,
                (&out, &levels),
                room.len(),
                row,
            )
            .map_err(|e| (place, e))?;
            for (slot, &value) in room.iter_mut().zip(&out) {
                slot.write(value);
            }
            row += room.len() as u64;
        }
        Ok(())
    }
}

/// Where a serial read of a file meets an error, in the order it meets them: by row group,
/// a group's column readers opened before its batches are read, then by batch and column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct ReadPlace {
    group: usize,
    /// 0 while the group's column readers are opened, batch + 1 when reading.
    stage: usize,
    column: usize,
}

impl ReadPlace {
    fn opening(group: usize, column: usize) -> Self {
        Self {
            group,
            stage: 0,
            column,
        }
    }

    fn reading(group: usize, batch: usize, column: usize) -> Self {
        Self {
            group,
            stage: batch + 1,
            column,
        }
    }
}

/// The flat column names of a Parquet file, in file order.
pub fn headers(path: &Path) -> Result<Vec<String>, TableError> {
    let (file, _) = open_file(path)?;
    let schema = file.metadata().file_metadata().schema_descr_ptr();
    Ok(schema
        .columns()
        .iter()
        .filter(|d| d.path().parts().len() == 1)
        .map(|d| d.name().to_string())
        .collect())
}

/// A whole Parquet table (the wanted columns, as [`super::read_table`]): every column of
/// every row group decoded at once on every core, each straight into its stretch of the
/// table's columns (read a block at a time, one core copied what the other decoded). The
/// error is the one a serial read meets first.
pub fn read_table(path: &Path, wanted: Option<&[&str]>) -> Result<Table, TableError> {
    let reader = ParquetColumns::open(path, wanted)?;
    let metadata = reader.file.metadata();
    let groups: Vec<(usize, u64)> = metadata
        .row_groups()
        .iter()
        .map(|g| {
            let rows = usize::try_from(g.num_rows()).unwrap_or(0);
            (rows, u64::try_from(g.compressed_size()).unwrap_or(0))
        })
        .collect();
    let rows: usize = groups.iter().map(|g| g.0).sum();
    let mut columns: Vec<Vec<f64>> = vec![Vec::new(); reader.headers.len()];
    let columns_per_group = columns.len().max(1) as u64;
    let mut tasks = Vec::with_capacity(groups.len() * columns.len());
    for (k, column) in columns.iter_mut().enumerate() {
        super::reserve_column(column, rows);
        let mut room = &mut column.spare_capacity_mut()[..rows];
        let mut first_row = 1;
        for (group, &(group_rows, _)) in groups.iter().enumerate() {
            let (stretch, rest) = std::mem::take(&mut room).split_at_mut(group_rows);
            tasks.push((group, k, first_row, stretch));
            first_row += group_rows as u64;
            room = rest;
        }
    }
    let ParquetColumns {
        file,
        headers,
        leaves,
        reporter,
        ..
    } = reader;
    let reporter = std::sync::Mutex::new(reporter);
    let whole = WholeRead {
        path,
        file: &file,
        headers: &headers,
        leaves: &leaves,
    };
    let first_error = tasks
        .into_par_iter()
        .filter_map(|(group, k, first_row, stretch)| {
            let decoded = whole.decode_group_column(group, k, first_row, stretch);
            if let Ok(mut reporter) = reporter.lock() {
                reporter.add(groups[group].1 / columns_per_group);
            }
            decoded.err()
        })
        .min_by_key(|(place, _)| *place);
    if let Some((_, error)) = first_error {
        return Err(error);
    }
    for column in &mut columns {
        // SAFETY: every task succeeded, and each wrote every value of its stretch (a
        // group's rows of one column); the stretches tile the column's first `rows` slots.
        unsafe { column.set_len(rows) };
    }
    Ok(Table {
        path: path.to_path_buf(),
        headers,
        columns,
        row_lines: RowLines::Unknown,
    })
}

/// The stated sample rate of a Parquet file, Hz (see [`ParquetColumns::stated_rate_hz`]).
pub fn stated_rate_hz(path: &Path) -> Result<Option<f64>, TableError> {
    ParquetColumns::open(path, Some(&[]))?.stated_rate_hz()
}

/// One row group of `columns` (equal lengths, in the schema's order).
fn write_group<'a>(
    writer: &mut SerializedFileWriter<Box<dyn Write + Send>>,
    path: &Path,
    columns: impl Iterator<Item = &'a [f64]>,
) -> Result<(), TableError> {
    let failed = |e: ParquetError| format_error(path, format!("cannot write: {e}"));
    let mut group = writer.next_row_group().map_err(failed)?;
    for values in columns {
        let Some(mut column) = group.next_column().map_err(failed)? else {
            break;
        };
        column
            .typed::<DoubleType>()
            .write_batch(values, None, None)
            .map_err(failed)?;
        column.close().map_err(failed)?;
    }
    group.close().map_err(failed)?;
    Ok(())
}

/// Writes named columns of one length to `path` as Parquet (a table that is not an
/// interchange recording: error signals), whole or not at all.
pub fn write_columns(path: &Path, columns: &[(&str, &[f64])]) -> Result<(), TableError> {
    let io = |source| TableError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = AtomicFile::create(path).map_err(io)?;
    let names: Vec<&str> = columns.iter().map(|c| c.0).collect();
    let mut sink = ParquetSink::create(path, file.owned_writer().map_err(io)?, &names)?;
    let rows = columns.first().map_or(0, |c| c.1.len());
    for start in (0..rows).step_by(GROUP_ROWS) {
        let end = rows.min(start + GROUP_ROWS);
        let group = columns.iter().map(|c| &c.1[start..end]);
        write_group(&mut sink.writer, path, group)?;
    }
    sink.finish(None)?;
    file.commit().map_err(io)
}

/// The rows of an interchange file being written as Parquet: held column by column until a
/// row group is full.
pub(crate) struct ParquetSink {
    path: PathBuf,
    writer: SerializedFileWriter<Box<dyn Write + Send>>,
    pending: Vec<Vec<f64>>,
}

impl ParquetSink {
    /// A file of required double `columns` written to `out` (`path` names it in errors).
    pub fn create(
        path: &Path,
        out: Box<dyn Write + Send>,
        columns: &[&str],
    ) -> Result<Self, TableError> {
        let failed = |e: ParquetError| format_error(path, format!("cannot write: {e}"));
        let fields = columns
            .iter()
            .map(|name| {
                SchemaType::primitive_type_builder(name, PhysicalType::DOUBLE)
                    .with_repetition(Repetition::REQUIRED)
                    .build()
                    .map(Arc::new)
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(failed)?;
        let schema = SchemaType::group_type_builder("interchange")
            .with_fields(fields)
            .build()
            .map_err(failed)?;
        let properties = WriterProperties::builder()
            .set_created_by(format!("dynacal {}", env!("CARGO_PKG_VERSION")))
            .set_dictionary_enabled(false)
            .set_encoding(Encoding::BYTE_STREAM_SPLIT)
            .set_compression(Compression::ZSTD(ZstdLevel::try_new(1).map_err(failed)?))
            .build();
        let writer = SerializedFileWriter::new(out, Arc::new(schema), Arc::new(properties))
            .map_err(failed)?;
        Ok(Self {
            path: path.to_path_buf(),
            writer,
            pending: vec![Vec::with_capacity(GROUP_ROWS); columns.len()],
        })
    }

    /// Appends one row (one value per column).
    pub fn push(&mut self, row: &[f64]) -> Result<(), TableError> {
        for (column, value) in self.pending.iter_mut().zip(row) {
            column.push(*value);
        }
        if self.pending[0].len() == GROUP_ROWS {
            self.write_group()?;
        }
        Ok(())
    }

    fn write_group(&mut self) -> Result<(), TableError> {
        let columns = self.pending.iter().map(Vec::as_slice);
        write_group(&mut self.writer, &self.path, columns)?;
        for column in &mut self.pending {
            column.clear();
        }
        Ok(())
    }

    /// Writes what is held, the stated rate (if any) and the footer, and flushes.
    pub fn finish(mut self, rate_hz: Option<f64>) -> Result<(), TableError> {
        if !self.pending[0].is_empty() {
            self.write_group()?;
        }
        if let Some(rate) = rate_hz.filter(|r| r.is_finite()) {
            self.writer
                .append_key_value_metadata(KeyValue::new(RATE_KEY.into(), rate.to_string()));
        }
        self.writer
            .close()
            .map_err(|e| format_error(&self.path, format!("cannot write: {e}")))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interchange::ImuRecording;

    fn fixture(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/parquet")
            .join(name)
    }

    /// The value `tests/parquet/make.py` wrote for channel `c` (0..6) at row `k`.
    fn made(c: usize, k: usize) -> f64 {
        (((k * (c + 3)) % 17) as f64 - 8.0) * 1e-4
    }

    #[test]
    fn a_file_pandas_wrote_reads_as_its_values_and_rate() {
        // GIVEN the file pandas' writer made (snappy, dictionary pages, nullable columns, a
        // text column, the stated rate in the schema's metadata)
        let path = fixture("pandas-snappy.parquet");
        assert!(is_parquet(&path));
        // WHEN it is read as an interchange recording
        let rec = ImuRecording::read(&path).unwrap();
        // THEN every value and the rate are the ones written; the text column is ignored
        assert_eq!(rec.sample_rate_hz, Some(100.0));
        assert_eq!(rec.len(), 300);
        let gyro = rec.gyro_rad_s.as_ref().unwrap();
        let accel = rec.accel_m_s2.as_ref().unwrap();
        for k in 0..300 {
            assert_eq!(rec.t_s[k], k as f64 * 0.01);
            for c in 0..3 {
                assert_eq!(gyro[c][k], made(c, k), "gyro {c} row {k}");
                assert_eq!(accel[c][k], made(c + 3, k), "accel {c} row {k}");
            }
        }
    }

    #[test]
    fn small_row_groups_floats_and_integers_read_in_order() {
        // GIVEN zstd pages of 64-row groups with a float32 gyro and an int64 counter
        let path = fixture("zstd-small-groups.parquet");
        // WHEN all its columns are read as a table
        let table = read_table(&path, None).unwrap();
        // THEN each is whole, in order, its values widened exactly; no rate is stated
        assert_eq!(table.rows(), 300);
        let count = table.column("count").unwrap();
        let gx = table.column("gx_rad_s").unwrap();
        for k in 0..300 {
            assert_eq!(count[k], k as f64);
            assert_eq!(gx[k], f64::from(made(0, k) as f32));
        }
        assert_eq!(stated_rate_hz(&path).unwrap(), None);
    }

    #[test]
    fn recordings_written_read_back_to_the_bit_across_row_groups() {
        // GIVEN a recording of every interchange triplet, longer than one row group
        let n = GROUP_ROWS + BATCH_ROWS / 2 + 7;
        let wave = |phase: f64| -> Vec<f64> {
            (0..n)
                .map(|k| (k as f64 * 1e-3 + phase).sin() * 0.7)
                .collect()
        };
        let triplet = |p: f64| Some([wave(p), wave(p + 1.0), wave(p + 2.0)]);
        let rec = ImuRecording {
            t_s: (0..n).map(|k| 5.0 + k as f64 / 200.0).collect(),
            gyro_rad_s: triplet(0.0),
            accel_m_s2: triplet(3.0),
            attitude_rad: triplet(6.0),
            position: triplet(9.0),
            velocity_ned_m_s: triplet(12.0),
            single_axis: Vec::new(),
            sample_rate_hz: Some(200.0),
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rec.parquet");
        // WHEN it is written to a `.parquet` name and read back
        rec.write(&path).unwrap();
        // THEN the file is Parquet, in more than one row group, and reads back equal
        assert!(is_parquet(&path));
        let columns = ParquetColumns::open(&path, None).unwrap();
        assert_eq!(columns.file.num_row_groups(), 2);
        assert_eq!(columns.stated_rate_hz().unwrap(), Some(200.0));
        assert_eq!(ImuRecording::read(&path).unwrap(), rec);
    }

    #[test]
    fn a_whole_read_decoded_in_parallel_names_the_error_a_serial_read_meets_first() {
        // GIVEN three columns over three row groups, with values that are not finite
        // planted in several places (by 0-based row)
        let n = 2 * GROUP_ROWS + 100;
        let dir = tempfile::tempdir().unwrap();
        let plant = |bad: &[(usize, usize)]| {
            let mut columns: Vec<Vec<f64>> = (0..3)
                .map(|c| (0..n).map(|k| made(c, k)).collect())
                .collect();
            for &(c, row) in bad {
                columns[c][row] = if row % 2 == 0 {
                    f64::NAN
                } else {
                    f64::INFINITY
                };
            }
            let path = dir.path().join(format!("bad-{}.parquet", bad.len()));
            let named: Vec<(&str, &[f64])> = ["a", "b", "c"]
                .iter()
                .zip(&columns)
                .map(|(h, v)| (*h, v.as_slice()))
                .collect();
            write_columns(&path, &named).unwrap();
            path
        };
        let g = GROUP_ROWS;
        for (bad, (column, row)) in [
            // in the last group and in the second: the second's
            (&[(0, 2 * g + 5), (2, g + 7)][..], ("c", g + 7)),
            // one group, an earlier batch in a later column before a later batch's
            (&[(0, g + BATCH_ROWS + 1), (2, g + 3)], ("c", g + 3)),
            // one batch, two columns: the earlier column's, though its row is later
            (&[(1, 40), (2, 10)], ("b", 40)),
        ] {
            let path = plant(bad);
            // WHEN it is read whole, and block by block
            let whole = read_table(&path, None).unwrap_err().to_string();
            let mut blocks = ParquetColumns::open(&path, None).unwrap();
            let serial = loop {
                match blocks.next_block() {
                    Ok(Some(_)) => {}
                    Ok(None) => panic!("no error read serially"),
                    Err(e) => break e.to_string(),
                }
            };
            // THEN both name the same cell: the one a serial read meets first
            assert_eq!(whole, serial, "{bad:?}");
            let expected = format!("row {}, column `{column}`", row + 1);
            assert!(whole.contains(&expected), "{whole} (expected {expected})");
        }
    }

    /// Writes `columns` (named, one length) as snappy pages of 256 rows: many small pages per
    /// column chunk, read lazily one after another, as in the files pyarrow writes.
    fn write_small_pages(path: &Path, columns: &[(&str, Vec<f64>)]) {
        let fields = columns
            .iter()
            .map(|(name, _)| {
                SchemaType::primitive_type_builder(name, PhysicalType::DOUBLE)
                    .with_repetition(Repetition::REQUIRED)
                    .build()
                    .map(Arc::new)
                    .unwrap()
            })
            .collect();
        let schema = SchemaType::group_type_builder("t")
            .with_fields(fields)
            .build()
            .unwrap();
        let properties = WriterProperties::builder()
            .set_dictionary_enabled(false)
            .set_compression(Compression::SNAPPY)
            .set_write_batch_size(256)
            .set_data_page_row_count_limit(256)
            .build();
        let out: Box<dyn Write + Send> = Box::new(File::create(path).unwrap());
        let mut writer =
            SerializedFileWriter::new(out, Arc::new(schema), Arc::new(properties)).unwrap();
        let rows = columns[0].1.len();
        for start in (0..rows).step_by(50_000) {
            let end = (start + 50_000).min(rows);
            let group = columns.iter().map(|(_, v)| &v[start..end]);
            write_group(&mut writer, path, group).unwrap();
        }
        writer.close().unwrap();
    }

    #[test]
    fn columns_decoded_on_several_threads_read_their_own_pages() {
        // GIVEN three columns of 200 000 rows in snappy pages of 256 rows (the columns of a
        // block are decoded in parallel, each page read lazily from the file)
        let n = 200_000;
        let column = |c: usize| -> Vec<f64> {
            (0..n)
                .map(|k| ((k * (c + 7)) % 1013) as f64 * 1e-3 + c as f64)
                .collect()
        };
        let columns = [
            ("t_s", (0..n).map(|k| k as f64 * 0.01).collect()),
            ("gx_rad_s", column(1)),
            ("gy_rad_s", column(2)),
        ];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pages.parquet");
        write_small_pages(&path, &columns);
        // WHEN the table is read (on every core)
        let table = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(|| read_table(&path, None))
            .unwrap();
        // THEN each column is the one written, to the bit: no column read another's pages
        for (name, values) in &columns {
            assert_eq!(table.column(name).unwrap(), values.as_slice(), "{name}");
        }
    }

    #[test]
    fn a_wanted_column_that_is_not_numbers_is_named_other_columns_are_not_read() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/bad-input/parquet-text-column.parquet");
        let e = read_table(&path, None).unwrap_err().to_string();
        assert!(e.contains("column `gx_rad_s` holds text"), "{e}");
        let t = read_table(&path, Some(&["t_s", "gy_rad_s"])).unwrap();
        assert_eq!(t.headers, ["t_s", "gy_rad_s"]);
        assert_eq!(t.rows(), 300);
    }
}
