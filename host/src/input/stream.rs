//! The wavelet variance of an interchange recording read in one pass, block by block, in
//! memory that does not grow with its length: what `dynacal wv` does with recordings too long
//! to load whole (`--stream`, chosen automatically above [`STREAM_THRESHOLD_BYTES`]). A CSV's
//! blocks come from the fast reader ([`crate::interchange::fast`]); where it gives up, the
//! file is read again from its start with the `csv` crate, one record at a time. A Parquet
//! file's come from its column readers ([`crate::interchange::parquet`]), its rows numbered
//! among the data rows rather than by line.
//!
//! It validates as the whole-file reader does (every parsed field a finite number, the field
//! count, `t_s` strictly increasing, each error naming the file and the line) and applies the
//! same gap policy, with one difference forced by reading once: the sample interval must be
//! known before the first row, so it is the rate the file states (`# sample_rate_hz:`) or
//! `--rate-hz`; a step more than half of it away is a gap, and the mean step must agree with
//! it to 1% (the whole-file reader compares the median step). A file stating no rate, given
//! none, any other input (a plain CSV, a dataset file) and `--robust` (which needs all
//! coefficients of a level at once) are not streamed. Each channel's wavelet variance is
//! accumulated by [`HaarWvStream`]: its full levels equal the batch estimator's.

use std::path::Path;

use super::{format_error, per_channel, ChannelWv, InputArgs, InputError};
use crate::interchange::fast::{pipelined, Fallback, FastBlocks, ParsedBlock};
use crate::interchange::parquet::{is_parquet, OwnedBlock, ParquetColumns};
use crate::interchange::{
    csv_error, csv_reader, is_interchange_column, open_maybe_gz, parse_field, read_stated_rate,
    TableError,
};
use crate::model::Channel;
use crate::wv::stream::HaarWvStream;
use crate::wv::{WaveletVariance, WvOptions};

/// Files larger than this on disk (256 MiB: about ten million rows of a one-channel text
/// interchange file) are streamed by `dynacal wv` unless told otherwise; smaller ones are
/// loaded whole, where every level is the batch estimator's (a stream decimates the levels
/// above 18, with wider intervals). Not for speed: on a 3.6e7-row CSV the stream was the
/// faster (2.34 s in 30 MiB against 2.80 s in 571 MiB, BENCHMARKS.md "Ingest", stop 65).
pub const STREAM_THRESHOLD_BYTES: u64 = 256 << 20;

/// The streamed wavelet variances of a file's channels and their sample interval.
#[derive(Debug, Clone)]
pub struct StreamedWv {
    /// Sample interval, s (the stated or given rate's).
    pub dt_s: f64,
    /// Levels 1..=`full_levels` are the batch estimator's; higher ones are decimated.
    pub full_levels: u32,
    pub channels: Vec<ChannelWv>,
}

/// Why a file is not streamed (it is then loaded whole).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NotStreamable {
    /// Not an interchange recording (no `t_s`, or no interchange column).
    NotInterchange,
    /// Neither a stated `# sample_rate_hz:` nor `--rate-hz`.
    NoRate,
    /// `--robust` needs every coefficient of a level.
    Robust,
}

impl std::fmt::Display for NotStreamable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::NotInterchange => "only an interchange recording is streamed",
            Self::NoRate => {
                "streaming needs the sample rate before the first row: the file states none \
                 (a `# sample_rate_hz:` line, or a Parquet file's `sample_rate_hz` metadata); \
                 give `--rate-hz`"
            }
            Self::Robust => "the robust wavelet variance needs every coefficient at once",
        })
    }
}

/// When a command streams its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum StreamMode {
    /// Stream interchange files larger than 256 MiB on disk whose rate is known.
    #[default]
    Auto,
    /// Stream, or fail saying why the file does not allow it.
    Always,
    /// Load the whole file.
    Never,
}

/// The streamed wavelet variances of `path` when `mode` and the file call for it; None: load
/// it whole. `Always` on a file that cannot be streamed is an error saying why; `Auto` on a
/// large one says on stderr why it is loaded whole.
pub fn streamed_if_wanted(
    path: &Path,
    args: &InputArgs,
    opts: &WvOptions,
    mode: StreamMode,
) -> Result<Option<StreamedWv>, InputError> {
    let wanted = match mode {
        StreamMode::Never => false,
        StreamMode::Always => true,
        StreamMode::Auto => std::fs::metadata(path).is_ok_and(|m| m.len() > STREAM_THRESHOLD_BYTES),
    };
    if !wanted {
        return Ok(None);
    }
    match stream_wavelet_variances(path, args, opts, HaarWvStream::DEFAULT_FULL_LEVELS)? {
        Ok(streamed) => Ok(Some(streamed)),
        Err(reason) if mode == StreamMode::Always => Err(InputError::Format {
            path: path.to_path_buf(),
            message: format!("cannot stream: {reason}"),
        }),
        Err(reason) => {
            eprintln!("{}: loaded whole ({reason})", path.display());
            Ok(None)
        }
    }
}

/// The wavelet variance of every wanted channel of an interchange file, read once, row by
/// row; `Ok(Err(reason))` when the file or the options do not allow streaming.
pub fn stream_wavelet_variances(
    path: &Path,
    args: &InputArgs,
    opts: &WvOptions,
    full_levels: u32,
) -> Result<Result<StreamedWv, NotStreamable>, InputError> {
    if opts.robust {
        return Ok(Err(NotStreamable::Robust));
    }
    let parquet = is_parquet(path);
    let header: Vec<String> = if parquet {
        crate::interchange::parquet::headers(path)?
    } else {
        match csv_reader(open_maybe_gz(path)?, true).headers() {
            Ok(h) => h.iter().map(str::to_string).collect(),
            Err(_) => return Ok(Err(NotStreamable::NotInterchange)),
        }
    };
    let Some(time_column) = header.iter().position(|h| h == "t_s") else {
        return Ok(Err(NotStreamable::NotInterchange));
    };
    if !header.iter().any(|h| is_interchange_column(h)) {
        return Ok(Err(NotStreamable::NotInterchange));
    }
    let Some(rate_hz) = args.rate_hz.or(stated_rate_hz(path)?) else {
        return Ok(Err(NotStreamable::NoRate));
    };
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(format_error(
            path,
            format!("the sample rate must be a positive number of Hz, got {rate_hz}"),
        ));
    }
    let dt_s = 1.0 / rate_hz;
    let columns = imu_columns(path, &header)?;
    let wanted = wanted_channels(path, &columns, &args.columns)?;
    let names: Vec<String> = wanted.iter().map(|&i| columns[i].0.name().into()).collect();
    let scales = per_channel::<f64>(&args.scale, "--scale", &names)?;
    let units = per_channel::<String>(&args.unit, "--unit", &names)?;
    let mut streams: Vec<HaarWvStream> = wanted
        .iter()
        .map(|_| HaarWvStream::new(full_levels))
        .collect();
    let mut rows = RowChecker::new(path, dt_s, !parquet);
    if parquet {
        feed_parquet(path, &columns, &wanted, &mut rows, &mut streams)?;
    } else if !feed_fast(path, &columns, &wanted, &mut rows, &mut streams)? {
        // The fast reader left the file to the csv crate: start again, row by row.
        rows = RowChecker::new(path, dt_s, true);
        for stream in &mut streams {
            *stream = HaarWvStream::new(full_levels);
        }
        feed_by_rows(
            path,
            time_column,
            &columns,
            &wanted,
            &mut rows,
            &mut streams,
        )?;
    }
    rows.finish(rate_hz)?;
    let mut channels = Vec::with_capacity(wanted.len());
    for (((stream, &i), scale), unit) in streams.iter().zip(&wanted).zip(scales).zip(units) {
        let channel = columns[i].0;
        let scale = checked_scale(scale)?;
        let wv: WaveletVariance = stream
            .wavelet_variance(opts.max_level, scale, dt_s)
            .map_err(|source| InputError::Wv {
                path: path.to_path_buf(),
                channel: channel.name().into(),
                source,
            })?;
        channels.push(ChannelWv {
            channel: channel.name().into(),
            unit: unit.unwrap_or_else(|| channel.si_unit().into()),
            wv,
        });
    }
    Ok(Ok(StreamedWv {
        dt_s,
        full_levels,
        channels,
    }))
}

/// Feeds every row's time to `rows` and its wanted channels to `streams` through the fast
/// block reader ([`crate::interchange::fast`]); `Ok(false)` when that reader leaves the file
/// to the `csv` crate (what it fed is then to be dropped).
fn feed_fast(
    path: &Path,
    columns: &[(Channel, usize)],
    wanted: &[usize],
    rows: &mut RowChecker,
    streams: &mut [HaarWvStream],
) -> Result<bool, InputError> {
    let mut names: Vec<&str> = vec!["t_s"];
    names.extend(columns.iter().map(|(c, _)| c.column()));
    let Some(mut blocks) = FastBlocks::open(path, Some(&names)) else {
        return Ok(false);
    };
    let at = |name: &str| blocks.headers().iter().position(|h| h == name);
    let (Some(time), Some(slots)) = (
        at("t_s"),
        wanted
            .iter()
            .map(|&i| at(columns[i].0.column()))
            .collect::<Option<Vec<usize>>>(),
    ) else {
        return Ok(false);
    };
    // The error `None` is the fast reader giving up (the `csv` crate reads the file then).
    let fed = pipelined(
        |spent| {
            if let Some(block) = spent {
                blocks.recycle(block);
            }
            blocks.next_block().map_err(|Fallback| None)
        },
        |block| feed_block(block, time, &slots, rows, streams).map_err(Some),
    );
    match fed {
        Ok(()) => Ok(true),
        Err(None) => Ok(false),
        Err(Some(e)) => Err(e),
    }
}

/// One parsed block's rows checked and its channels (`slots` of its columns, time at
/// `time`) pushed into `streams`.
fn feed_block(
    block: &ParsedBlock,
    time: usize,
    slots: &[usize],
    rows: &mut RowChecker,
    streams: &mut [HaarWvStream],
) -> Result<(), InputError> {
    let mut line = block.first_line;
    for piece in block.pieces() {
        feed_columns(piece, line, time, slots, rows, streams)?;
        line += piece[time].len() as u64;
    }
    Ok(())
}

/// Rows of `columns` (the first at line or row `first`) checked by their times (column
/// `time`) and their channels (`slots`) pushed into `streams`.
fn feed_columns(
    columns: &[Vec<f64>],
    first: u64,
    time: usize,
    slots: &[usize],
    rows: &mut RowChecker,
    streams: &mut [HaarWvStream],
) -> Result<(), InputError> {
    rows.check_run(&columns[time], first)?;
    for (stream, &slot) in streams.iter_mut().zip(slots) {
        stream.push_block(&columns[slot]);
    }
    Ok(())
}

/// As [`feed_fast`], from a Parquet file's column blocks (errors name the row).
fn feed_parquet(
    path: &Path,
    columns: &[(Channel, usize)],
    wanted: &[usize],
    rows: &mut RowChecker,
    streams: &mut [HaarWvStream],
) -> Result<(), InputError> {
    let mut names: Vec<&str> = vec!["t_s"];
    names.extend(wanted.iter().map(|&i| columns[i].0.column()));
    let mut blocks = ParquetColumns::open(path, Some(&names))?;
    let at = |name: &str| blocks.headers().iter().position(|h| h == name);
    let time = at("t_s").expect("the header has `t_s`");
    let slots: Vec<usize> = wanted
        .iter()
        .map(|&i| at(columns[i].0.column()).expect("the header has the channel"))
        .collect();
    pipelined(
        |spent: Option<OwnedBlock>| {
            let reuse = spent.map(|block| block.columns).unwrap_or_default();
            Ok(blocks.next_owned(reuse)?)
        },
        |block| feed_columns(&block.columns, block.first_row, time, &slots, rows, streams),
    )
}

/// As [`feed_fast`], with the `csv` crate, one record at a time (its errors name the line).
fn feed_by_rows(
    path: &Path,
    time_column: usize,
    columns: &[(Channel, usize)],
    wanted: &[usize],
    rows: &mut RowChecker,
    streams: &mut [HaarWvStream],
) -> Result<(), InputError> {
    let mut csv = csv_reader(open_maybe_gz(path)?, true);
    let mut record = csv::ByteRecord::new();
    let mut values = vec![0.0; columns.len()];
    loop {
        match csv.read_byte_record(&mut record) {
            Ok(false) => break,
            Ok(true) => {}
            Err(e) => return Err(csv_error(path, e).into()),
        }
        let line = record.position().map_or(0, |p| p.line());
        let t_s = parse_field(path, &record, time_column, "t_s", line)?;
        for (value, (channel, index)) in values.iter_mut().zip(columns) {
            *value = parse_field(path, &record, *index, channel.column(), line)?;
        }
        rows.check(t_s, line)?;
        for (stream, &i) in streams.iter_mut().zip(wanted) {
            stream.push(values[i]);
        }
    }
    Ok(())
}

fn checked_scale(scale: Option<f64>) -> Result<f64, InputError> {
    match scale {
        None => Ok(1.0),
        Some(s) if s.is_finite() && s != 0.0 => Ok(s),
        Some(s) => Err(InputError::Flag {
            flag: "--scale",
            value: s.to_string(),
            message: "not a finite non-zero number".into(),
        }),
    }
}

/// The IMU channels present, with their column index; two of a triplet's three is an error
/// (a misspelt column far more often than a two-axis sensor), as the whole-file reader says.
fn imu_columns(path: &Path, header: &[String]) -> Result<Vec<(Channel, usize)>, InputError> {
    let columns: Vec<(Channel, usize)> = Channel::ALL
        .iter()
        .filter_map(|&c| header.iter().position(|h| h == c.column()).map(|i| (c, i)))
        .collect();
    for triplet in Channel::ALL.chunks(3) {
        let present: Vec<&Channel> = triplet
            .iter()
            .filter(|c| columns.iter().any(|(p, _)| p == *c))
            .collect();
        if present.len() == 2 {
            let missing = triplet.iter().find(|c| !present.contains(c)).unwrap();
            return Err(TableError::IncompleteTriplet {
                path: path.to_path_buf(),
                present: present[0].column().into(),
                missing: missing.column().into(),
            }
            .into());
        }
    }
    if columns.is_empty() {
        return Err(format_error(path, "no sensor channel".into()));
    }
    Ok(columns)
}

/// Indices into `columns` of the channels named by `--columns` (in that order), or all.
fn wanted_channels(
    path: &Path,
    columns: &[(Channel, usize)],
    wanted: &[String],
) -> Result<Vec<usize>, InputError> {
    if wanted.is_empty() {
        return Ok((0..columns.len()).collect());
    }
    let names: Vec<&str> = columns.iter().map(|(c, _)| c.name()).collect();
    wanted
        .iter()
        .map(|w| {
            names.iter().position(|n| n == w).ok_or_else(|| {
                format_error(
                    path,
                    format!("no channel `{w}` (available: {})", names.join(", ")),
                )
            })
        })
        .collect()
}

/// The time column's checks, one row at a time.
struct RowChecker<'a> {
    path: &'a Path,
    /// Rows are numbered by their file line (text), else among the data rows (Parquet).
    rows_are_lines: bool,
    dt_s: f64,
    first_t_s: f64,
    previous_t_s: f64,
    rows: u64,
}

impl<'a> RowChecker<'a> {
    fn new(path: &'a Path, dt_s: f64, rows_are_lines: bool) -> Self {
        Self {
            path,
            rows_are_lines,
            dt_s,
            first_t_s: 0.0,
            previous_t_s: 0.0,
            rows: 0,
        }
    }

    /// Row `at`'s time (its line, or its 1-based row among the data rows).
    fn check(&mut self, t_s: f64, at: u64) -> Result<(), InputError> {
        if self.rows > 0 {
            let step = t_s - self.previous_t_s;
            if step <= 0.0 {
                let (path, previous_t_s) = (self.path.to_path_buf(), self.previous_t_s);
                return Err(if self.rows_are_lines {
                    TableError::TimeNotIncreasing {
                        path,
                        line: at,
                        t_s,
                        previous_t_s,
                    }
                } else {
                    TableError::TimeNotIncreasingAtSample {
                        path,
                        sample: at,
                        t_s,
                        previous_t_s,
                    }
                }
                .into());
            }
            if (step - self.dt_s).abs() > 0.5 * self.dt_s {
                let place = if self.rows_are_lines { "line" } else { "row" };
                return Err(format_error(
                    self.path,
                    format!(
                        "{place} {at}, column `t_s`: step {step} s differs from the sample \
                         interval {} s (the wavelet variance needs evenly spaced samples)",
                        self.dt_s
                    ),
                ));
            }
        } else {
            self.first_t_s = t_s;
        }
        self.previous_t_s = t_s;
        self.rows += 1;
        Ok(())
    }

    /// A run of consecutive rows' times, the first at line or row `first`: as [`Self::check`]
    /// on each, with the steps inside the run tested together first (most runs have no bad
    /// one, and a row-by-row check was a tenth of a streamed Parquet `wv`).
    fn check_run(&mut self, times: &[f64], first: u64) -> Result<(), InputError> {
        let Some((&head, rest)) = times.split_first() else {
            return Ok(());
        };
        self.check(head, first)?;
        let (dt_s, half_s) = (self.dt_s, 0.5 * self.dt_s);
        let uneven = |previous: f64, t: f64| !((t - previous - dt_s).abs() <= half_s);
        if crate::numeric::first_bad_step(times, uneven).is_none() {
            self.previous_t_s = times[times.len() - 1];
            self.rows += rest.len() as u64;
            return Ok(());
        }
        for (r, &t_s) in rest.iter().enumerate() {
            self.check(t_s, first + 1 + r as u64)?;
        }
        Ok(())
    }

    /// The whole file read: some rows, and a mean step within 1% of the stated interval.
    fn finish(&self, rate_hz: f64) -> Result<(), InputError> {
        if self.rows == 0 {
            return Err(TableError::Empty {
                path: self.path.to_path_buf(),
            }
            .into());
        }
        if self.rows < 2 {
            return Ok(());
        }
        let mean_step_s = (self.previous_t_s - self.first_t_s) / (self.rows - 1) as f64;
        if (mean_step_s / self.dt_s - 1.0).abs() > 0.01 {
            return Err(format_error(
                self.path,
                format!(
                    "the sample rate {rate_hz} Hz disagrees with the time column `t_s` (mean \
                     step {mean_step_s} s, {:.6} Hz)",
                    1.0 / mean_step_s
                ),
            ));
        }
        Ok(())
    }
}

/// The rate stated in the `#` lines before the header (`# sample_rate_hz: 100`).
fn stated_rate_hz(path: &Path) -> Result<Option<f64>, InputError> {
    Ok(read_stated_rate(path)?.map(|(_, rate_hz)| rate_hz))
}
