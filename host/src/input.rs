//! One loader for the commands that read sensor series or their wavelet variances (`wv`,
//! `fit`, `compare`), with one set of flags ([`InputArgs`], flattened into each command),
//! one policy on the sample interval and gaps, and one error type ([`InputError`]).
//!
//! What it reads, recognised by content:
//! - an interchange recording (`docs/formats.md` section 1): channels `gx` .. `az` in SI units;
//! - a dataset file `dynacal import` knows (imported to SI units first; with several sensors
//!   in one file, channels are named `sensor/gx`); `--raw` reads it as a plain CSV instead;
//! - any other CSV with a header row: its columns by name (an error-signal file of `dynacal
//!   errors` contributes its six error columns by default, any other its columns named as
//!   channels or with a unit suffix; others by `--columns`), time from a `t_s` column or
//!   from `--rate-hz`;
//! - wavelet variances stored as JSON (only where a command takes them, see
//!   [`load_wavelet_variances`]): the output of `dynacal wv`, the `wv.json` of `dynacal
//!   decode` (channels `imuN/gx` .. `imuN/az`), and the SMAC-Group reference file.
//!
//! The sample interval: the rate given with `--rate-hz` if any, else the rate an interchange
//! file states, else the median step of the time column
//! ([`crate::interchange::median_step_s`]); a given or stated rate must agree with the time
//! column to 1%. The wavelet variance assumes evenly spaced samples, so a step that differs
//! from the median by more than half of it is a gap, and an error naming its line.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

pub mod stream;

use crate::calibration::SpilledRecording;
use crate::decode::BoardChannelWv;
use crate::error_signal::ERROR_COLUMNS;
use crate::import::ImportError;
use crate::interchange::{
    median_step_s, open_maybe_gz, read_table, ImuRecording, RowLines, TableError,
};
use crate::model::Channel;
use crate::wv::{
    haar_wv, haar_wv_counts, haar_wv_owned, read_smac_golden, WaveletVariance, WvError, WvOptions,
};

/// Errors reading inputs; each names the file and, where there is one, the line or field.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InputError {
    #[error(transparent)]
    Table(#[from] TableError),
    #[error(transparent)]
    Import(#[from] ImportError),
    #[error("{path}: channel `{channel}`: {source}")]
    Wv {
        path: PathBuf,
        channel: String,
        #[source]
        source: WvError,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    /// A command-line value is malformed.
    #[error("{flag} `{value}`: {message}")]
    Flag {
        flag: &'static str,
        value: String,
        message: String,
    },
}

/// The flags of every command that reads series: which channels, at which rate, in which
/// unit.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct InputArgs {
    /// Channels to read, comma-separated (interchange: gx..az; other CSV: column names; WV
    /// JSON: its channel keys; several sensors in one file: sensor/gx). Default: all.
    #[arg(long, value_delimiter = ',')]
    pub columns: Vec<String>,
    /// Sample rate, Hz: needed for a CSV without a `t_s` column; with one, it must agree
    /// with the time column.
    #[arg(long = "rate-hz", visible_alias = "rate")]
    pub rate_hz: Option<f64>,
    /// Physical units per input unit (e.g. per count): one factor for every channel
    /// (`0.05`) or per channel (`gx=0.05,ax=0.00333`); variances scale by its square.
    #[arg(long, value_delimiter = ',')]
    pub scale: Vec<String>,
    /// Unit of a plain CSV's values after scaling: `deg/s` or per channel `gx=deg/s,ax=g`.
    #[arg(long, value_delimiter = ',')]
    pub unit: Vec<String>,
    /// Read a known dataset file as a plain CSV instead of importing it into SI units (keeps
    /// e.g. the ADIS16405 integer counts exact).
    #[arg(long)]
    pub raw: bool,
}

/// One channel read from a file, evenly sampled.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Channel name (`gx`, a column name, or `sensor/gx`).
    pub name: String,
    /// Unit of `values() = raw * scale`.
    pub unit: String,
    /// Sample interval, s.
    pub dt_s: f64,
    /// The values as read, before `scale`.
    pub raw: Vec<f64>,
    /// Physical units per raw unit (from `--scale`, else 1).
    pub scale: f64,
}

impl Series {
    /// The values in `unit`.
    pub fn values(&self) -> Vec<f64> {
        self.raw.iter().map(|v| v * self.scale).collect()
    }

    /// The Haar wavelet variance; integer raw values (counts) are processed exactly.
    pub fn wavelet_variance(&self, opts: &WvOptions) -> Result<WaveletVariance, WvError> {
        wavelet_variance_of(Cow::Borrowed(&self.raw), self.scale, self.dt_s, opts)
    }

    /// [`Series::wavelet_variance`] of a series not needed after, computed in its memory.
    pub fn into_wavelet_variance(self, opts: &WvOptions) -> Result<WaveletVariance, WvError> {
        wavelet_variance_of(Cow::Owned(self.raw), self.scale, self.dt_s, opts)
    }
}

/// The Haar wavelet variance of `raw * scale` sampled every `dt_s` s: integer raw values
/// (counts) are processed exactly ([`haar_wv_counts`]), other values as they are.
/// An owned `raw` is worked on in place ([`haar_wv_owned`]).
pub fn wavelet_variance_of(
    raw: Cow<'_, [f64]>,
    scale: f64,
    dt_s: f64,
    opts: &WvOptions,
) -> Result<WaveletVariance, WvError> {
    match as_counts(&raw) {
        Some(counts) => haar_wv_counts(&counts, scale, dt_s, opts),
        // x * 1.0 is x: no copy needed.
        None if scale == 1.0 => match raw {
            Cow::Borrowed(x) => haar_wv(x, dt_s, opts),
            Cow::Owned(x) => haar_wv_owned(x, dt_s, opts),
        },
        None => haar_wv_owned(raw.iter().map(|v| v * scale).collect(), dt_s, opts),
    }
}

/// One channel's wavelet variance and its unit.
#[derive(Debug, Clone)]
pub struct ChannelWv {
    pub channel: String,
    pub unit: String,
    pub wv: WaveletVariance,
}

/// The column as i32 counts if every value is an integer in i32 range.
fn as_counts(values: &[f64]) -> Option<Vec<i32>> {
    values
        .iter()
        .map(|&v| {
            (v.fract() == 0.0 && v >= i32::MIN as f64 && v <= i32::MAX as f64).then_some(v as i32)
        })
        .collect()
}

fn format_error(path: &Path, message: String) -> InputError {
    InputError::Format {
        path: path.to_path_buf(),
        message,
    }
}

/// `"v"` or `["gx=v", "ax=w"]` resolved for channel `name` (a bare value is every
/// channel's); every named channel must be among `names`.
fn per_channel<T: std::str::FromStr>(
    items: &[String],
    flag: &'static str,
    names: &[String],
) -> Result<Vec<Option<T>>, InputError>
where
    T::Err: std::fmt::Display,
{
    let mut out: Vec<Option<T>> = names.iter().map(|_| None).collect();
    for item in items {
        let flag_err = |message: String| InputError::Flag {
            flag,
            value: item.clone(),
            message,
        };
        let (target, text) = match item.split_once('=') {
            Some((name, v)) => (Some(name.trim()), v.trim()),
            None => (None, item.trim()),
        };
        let parse = || text.parse::<T>().map_err(|e| flag_err(e.to_string()));
        match target {
            None => {
                for slot in &mut out {
                    *slot = Some(parse()?);
                }
            }
            Some(name) => {
                let i = names.iter().position(|n| n == name).ok_or_else(|| {
                    flag_err(format!(
                        "no selected channel `{name}` (selected: {})",
                        names.join(",")
                    ))
                })?;
                out[i] = Some(parse()?);
            }
        }
    }
    Ok(out)
}

/// The sample interval of a time column, s: the stated rate's when one is given (it must
/// agree with the column's median step to 1%), else the median step. A step that differs
/// from the median by more than half of it is a gap, reported with its line (the header
/// being line 1).
pub fn sample_interval_s(
    path: &Path,
    t_s: &[f64],
    stated_rate_hz: Option<f64>,
) -> Result<f64, InputError> {
    sample_interval_at(path, t_s, stated_rate_hz, RowLines::Unknown)
}

/// As [`sample_interval_s`], a gap's error naming the file line where the rows' are known.
pub fn sample_interval_at(
    path: &Path,
    t_s: &[f64],
    stated_rate_hz: Option<f64>,
    lines: RowLines,
) -> Result<f64, InputError> {
    sample_interval_from_median(path, t_s, stated_rate_hz, lines, median_step_s(t_s))
}

/// [`sample_interval_at`] given the column's median step ([`median_step_s`] of `t_s`, as
/// [`ImuRecording::read_with_median`] found it: `None` for fewer than two samples).
fn sample_interval_from_median(
    path: &Path,
    t_s: &[f64],
    stated_rate_hz: Option<f64>,
    lines: RowLines,
    median: Option<f64>,
) -> Result<f64, InputError> {
    let median = median
        .ok_or_else(|| format_error(path, "fewer than two samples: no sample interval".into()))?;
    let uneven = |previous: f64, t: f64| (t - previous - median).abs() > 0.5 * median;
    if let Some(i) = crate::numeric::first_bad_step(t_s, uneven) {
        let place = match lines {
            RowLines::From(first) => format!("line {}", first + i as u64 + 1),
            RowLines::Unknown => format!("sample {} (1-based, t_s {} s)", i + 2, t_s[i + 1]),
        };
        return Err(format_error(
            path,
            format!(
                "{place}, column `t_s`: step {} s differs from the median interval {median} s \
                 (the wavelet variance needs evenly spaced samples)",
                t_s[i + 1] - t_s[i]
            ),
        ));
    }
    match stated_rate_hz {
        None => Ok(median),
        Some(rate) => {
            let dt = stated_interval_s(path, rate)?;
            if (median / dt - 1.0).abs() > 0.01 {
                return Err(format_error(
                    path,
                    format!(
                        "the sample rate {rate} Hz disagrees with the time column `t_s` (median \
                         step {median} s, {:.6} Hz)",
                        1.0 / median
                    ),
                ));
            }
            Ok(dt)
        }
    }
}

fn stated_interval_s(path: &Path, rate_hz: f64) -> Result<f64, InputError> {
    if rate_hz.is_finite() && rate_hz > 0.0 {
        Ok(1.0 / rate_hz)
    } else {
        Err(format_error(
            path,
            format!("the sample rate must be a positive number of Hz, got {rate_hz}"),
        ))
    }
}

/// One sensor's whole recording: an interchange file, or a dataset file `dynacal import`
/// knows that holds one sensor (imported to SI units). With `evenly_sampled`, a gap in its
/// time column is an error naming the line, as for the series the wavelet variance reads.
pub fn load_recording(path: &Path, evenly_sampled: bool) -> Result<ImuRecording, InputError> {
    let (recording, lines) = match crate::import::detect(path)? {
        Some(dataset) => {
            let mut sensors = crate::import::import_file(path, dataset)?;
            if sensors.len() != 1 {
                let names: Vec<String> = sensors.into_iter().map(|s| s.name).collect();
                return Err(format_error(
                    path,
                    format!(
                        "holds {} sensors ({}): import it with `dynacal import` and choose one",
                        names.len(),
                        names.join(", ")
                    ),
                ));
            }
            (sensors.remove(0).recording, RowLines::Unknown)
        }
        None => ImuRecording::read_with_lines(path)?,
    };
    if evenly_sampled {
        sample_interval_at(path, &recording.t_s, recording.sample_rate_hz, lines)?;
    }
    Ok(recording)
}

/// Interchange files above this size on disk are read by [`spill_if_long`] into a spill
/// file rather than held: about the rows of a diagnosis's long run (280 000 at its default
/// 30 replicates, 14-20 MB of CSV).
pub const SPILL_ABOVE_BYTES: u64 = 16 << 20;

/// An interchange file of more than [`SPILL_ABOVE_BYTES`] whose gyro and accelerometer come
/// as whole triplets, read into a spill file a block at a time (never held whole), with the
/// checks [`load_recording`] makes (a gap's error names the sample, not the line); None for
/// any other file, which [`load_recording`] reads.
pub fn spill_if_long(
    path: &Path,
    evenly_sampled: bool,
) -> Result<Option<SpilledRecording>, InputError> {
    spill_above(path, evenly_sampled, SPILL_ABOVE_BYTES)
}

/// [`spill_if_long`] with the size above which a file is spilled.
fn spill_above(
    path: &Path,
    evenly_sampled: bool,
    above_bytes: u64,
) -> Result<Option<SpilledRecording>, InputError> {
    let size = std::fs::metadata(path).map_or(0, |m| m.len());
    if size <= above_bytes
        || crate::import::detect(path)? != Some(crate::import::Dataset::Interchange)
        || !crate::interchange::summary::interchange_columns(path)?
            .lone_axes
            .is_empty()
    {
        return Ok(None);
    }
    // A read error names the file and line already; other failures are the spill file's.
    let failed = |e: crate::calibration::ErrorsError| match e {
        crate::calibration::ErrorsError::Read(e) => InputError::Table(e),
        other => format_error(path, other.to_string()),
    };
    let spilled = SpilledRecording::read(path).map_err(failed)?;
    if evenly_sampled {
        let median = spilled.median_step_s().map_err(failed)?.ok_or_else(|| {
            format_error(path, "fewer than two samples: no sample interval".into())
        })?;
        if let Some((i, step)) = spilled.first_uneven_step(median).map_err(failed)? {
            return Err(format_error(
                path,
                format!(
                    "sample {} (1-based), column `t_s`: step {step} s differs from the median \
                     interval {median} s (the wavelet variance needs evenly spaced samples)",
                    i + 1
                ),
            ));
        }
    }
    Ok(Some(spilled))
}

/// Every wanted channel of a series file (not a WV JSON), in file order or the order of
/// `--columns`.
pub fn load_series(path: &Path, args: &InputArgs) -> Result<Vec<Series>, InputError> {
    // A binary dataset (an ArduPilot log) has no CSV header: it is recognised first.
    let header = match column_names(path) {
        Ok(header) => header,
        Err(e) if args.raw || crate::import::detect(path)?.is_none() => return Err(e),
        Err(_) => Vec::new(),
    };
    let has_time = header.iter().any(|h| h == "t_s");
    let interchange = has_time
        && header
            .iter()
            .any(|h| crate::interchange::is_interchange_column(h));
    let mut series = if interchange {
        let (recording, lines, median) = ImuRecording::read_with_median(path)?;
        from_recordings(path, args, vec![(String::new(), recording, lines, median)])?
    } else if let Some(dataset) = (!args.raw)
        .then(|| crate::import::detect(path))
        .transpose()?
        .flatten()
    {
        let sensors = crate::import::import_file(path, dataset)?;
        let prefixed = sensors.len() > 1;
        let recordings = sensors
            .into_iter()
            .map(|s| {
                let prefix = if prefixed {
                    s.name + "/"
                } else {
                    String::new()
                };
                (prefix, s.recording, RowLines::Unknown, None)
            })
            .collect();
        let read = from_recordings(path, args, recordings);
        if dataset == crate::import::Dataset::RosBag {
            read.map_err(|e| bag_hint(path, e))?
        } else {
            read?
        }
    } else {
        from_columns(path, args, &header)?
    };
    let names: Vec<String> = series.iter().map(|s| s.name.clone()).collect();
    let scales = per_channel::<f64>(&args.scale, "--scale", &names)?;
    let units = per_channel::<String>(&args.unit, "--unit", &names)?;
    for ((s, scale), unit) in series.iter_mut().zip(scales).zip(units) {
        if let Some(scale) = scale {
            if !(scale.is_finite() && scale != 0.0) {
                return Err(InputError::Flag {
                    flag: "--scale",
                    value: scale.to_string(),
                    message: "not a finite non-zero number".into(),
                });
            }
            s.scale = scale;
        }
        if let Some(unit) = unit {
            s.unit = unit;
        }
    }
    Ok(series)
}

/// A bag's message stamps jitter and pause, which the wavelet variance of a series cannot
/// take; `dynacal noise` judges them (stillness, gaps, the sampling) and reads the noise of
/// the still stretches, so an error on a bag's sampling points there.
fn bag_hint(path: &Path, error: InputError) -> InputError {
    match error {
        InputError::Format { path: p, message } if message.contains("column `t_s`") => {
            InputError::Format {
                path: p,
                message: format!(
                    "{message}; a bag's stamps are read by `dynacal noise {} --topic TOPIC`, \
                     which finds its still stretches and gaps",
                    path.display()
                ),
            }
        }
        other => other,
    }
}

/// The column names of a CSV's header row or of a Parquet file.
fn column_names(path: &Path) -> Result<Vec<String>, InputError> {
    if crate::interchange::parquet::is_parquet(path) {
        return Ok(crate::interchange::parquet::headers(path)?);
    }
    let mut reader = crate::interchange::csv_reader(open_maybe_gz(path)?, true);
    Ok(reader
        .headers()
        .map_err(|e| match e.kind() {
            csv::ErrorKind::Utf8 { .. } => format_error(
                path,
                "line 1: the header is not UTF-8 text (not a CSV file, or damaged)".into(),
            ),
            _ => format_error(path, format!("line 1: cannot read the header: {e}")),
        })?
        .iter()
        .map(str::to_string)
        .collect())
}

/// The wanted channels of recordings (named with their `sensor/` prefix), each with where
/// its rows are and its median step where the read found it.
fn from_recordings(
    path: &Path,
    args: &InputArgs,
    recordings: Vec<(String, ImuRecording, RowLines, Option<f64>)>,
) -> Result<Vec<Series>, InputError> {
    let mut available = Vec::new();
    for (prefix, mut rec, lines, median) in recordings {
        let rate = args.rate_hz.or(rec.sample_rate_hz);
        let median = median.or_else(|| median_step_s(&rec.t_s));
        let dt_s = sample_interval_from_median(path, &rec.t_s, rate, lines, median)?;
        for c in Channel::ALL {
            if let Some(raw) = rec.take_channel(c.name()) {
                available.push(Series {
                    name: format!("{prefix}{c}"),
                    unit: c.si_unit().into(),
                    dt_s,
                    raw,
                    scale: 1.0,
                });
            }
        }
    }
    select(path, available, &args.columns)
}

/// `available` restricted to `wanted` (in that order), or all of it when none is wanted.
fn select(
    path: &Path,
    available: Vec<Series>,
    wanted: &[String],
) -> Result<Vec<Series>, InputError> {
    if wanted.is_empty() {
        if available.is_empty() {
            return Err(format_error(path, "no sensor channel".into()));
        }
        return Ok(available);
    }
    let names: Vec<String> = available.iter().map(|s| s.name.clone()).collect();
    wanted
        .iter()
        .map(|w| {
            available
                .iter()
                .find(|s| &s.name == w)
                .cloned()
                .ok_or_else(|| {
                    format_error(
                        path,
                        format!("no channel `{w}` (available: {})", names.join(", ")),
                    )
                })
        })
        .collect()
}

/// Whether a plain CSV's column is taken as a sensor channel without `--columns`: named as
/// one (`gx` .. `az`, as the raw dataset files are) or with a unit suffix. Anything else
/// (a temperature, a counter, a status word) is read only when asked for.
fn is_sensor_column(name: &str) -> bool {
    Channel::ALL.iter().any(|c| c.name() == name) || unit_from_suffix(name).is_some()
}

/// Unit of a column named with the project's unit suffix (`gy_err_rad_s` -> rad/s).
fn unit_from_suffix(name: &str) -> Option<&'static str> {
    [
        ("_rad_s3", "rad/s^3"),
        ("_rad_s2", "rad/s^2"),
        ("_rad_s", "rad/s"),
        ("_m_s3", "m/s^3"),
        ("_m_s2", "m/s^2"),
        ("_m_s", "m/s"),
    ]
    .iter()
    .find(|(suffix, _)| name.ends_with(suffix))
    .map(|(_, unit)| *unit)
}

/// The columns of a CSV that is not an interchange recording. Without `--columns`, an
/// error-signal file contributes its six error columns (the dynamics columns beside them
/// are regressors, not sensor errors) and any other file its sensor columns
/// ([`is_sensor_column`]), or every column but `t_s` when `--unit` or `--scale` says what
/// they hold.
fn from_columns(
    path: &Path,
    args: &InputArgs,
    header: &[String],
) -> Result<Vec<Series>, InputError> {
    let data_columns: Vec<&String> = header.iter().filter(|h| *h != "t_s").collect();
    let names: Vec<String> = if !args.columns.is_empty() {
        args.columns.clone()
    } else if header.iter().any(|h| ERROR_COLUMNS.contains(&h.as_str())) {
        ERROR_COLUMNS
            .iter()
            .filter(|c| header.iter().any(|h| h == *c))
            .map(|c| c.to_string())
            .collect()
    } else if !args.unit.is_empty() || !args.scale.is_empty() {
        // The user says what the values are: every column is a channel.
        data_columns.iter().map(|h| h.to_string()).collect()
    } else {
        let sensor: Vec<String> = data_columns
            .iter()
            .filter(|h| is_sensor_column(h))
            .map(|h| h.to_string())
            .collect();
        if sensor.is_empty() && !data_columns.is_empty() {
            let list: Vec<&str> = data_columns.iter().map(|h| h.as_str()).collect();
            return Err(format_error(
                path,
                format!(
                    "line 1: no sensor column (columns: {}): a channel is named gx .. az or \
                     carries a unit suffix (`_rad_s`, `_m_s2`, ..); choose others with \
                     --columns and say their unit with --unit",
                    list.join(", ")
                ),
            ));
        }
        sensor
    };
    if let Some(missing) = names.iter().find(|n| !data_columns.contains(n)) {
        let list: Vec<&str> = data_columns.iter().map(|h| h.as_str()).collect();
        return Err(format_error(
            path,
            format!(
                "line 1: no channel `{missing}` (available: {})",
                list.join(", ")
            ),
        ));
    }
    if names.is_empty() {
        return Err(format_error(path, "line 1: no data column".into()));
    }
    let has_time = header.iter().any(|h| h == "t_s");
    let mut wanted: Vec<&str> = names.iter().map(String::as_str).collect();
    if has_time {
        wanted.push("t_s");
    }
    let table = read_table(path, Some(&wanted))?;
    if table.rows() == 0 {
        return Err(TableError::Empty {
            path: path.to_path_buf(),
        }
        .into());
    }
    let dt_s = match (table.column("t_s"), args.rate_hz) {
        (Some(t_s), rate) => {
            crate::interchange::check_time_increasing_at(path, t_s, table.row_lines)?;
            sample_interval_at(path, t_s, rate, table.row_lines)?
        }
        (None, Some(rate)) => stated_interval_s(path, rate)?,
        (None, None) => {
            return Err(format_error(
                path,
                "line 1: no `t_s` column; give the sample rate with --rate-hz HZ".into(),
            ))
        }
    };
    Ok(names
        .into_iter()
        .map(|name| Series {
            unit: unit_from_suffix(&name).unwrap_or("unit").to_string(),
            dt_s,
            raw: table.column(&name).expect("read column").to_vec(),
            scale: 1.0,
            name,
        })
        .collect())
}

/// Every wanted channel's wavelet variance: read from a WV JSON, or computed from the
/// series of any other file.
pub fn load_wavelet_variances(
    path: &Path,
    args: &InputArgs,
    opts: &WvOptions,
) -> Result<Vec<ChannelWv>, InputError> {
    let is_json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if !is_json {
        return load_series(path, args)?
            .into_iter()
            .map(|mut s| {
                let (channel, unit) = (std::mem::take(&mut s.name), std::mem::take(&mut s.unit));
                let wv = s
                    .into_wavelet_variance(opts)
                    .map_err(|source| InputError::Wv {
                        path: path.to_path_buf(),
                        channel: channel.clone(),
                        source,
                    })?;
                Ok(ChannelWv { channel, unit, wv })
            })
            .collect();
    }
    let all = read_wv_json(path)?;
    let names: Vec<&str> = all.iter().map(|c| c.channel.as_str()).collect();
    if let Some(missing) = args.columns.iter().find(|c| !names.contains(&c.as_str())) {
        return Err(format_error(
            path,
            format!("no channel `{missing}` (available: {})", names.join(", ")),
        ));
    }
    let out: Vec<ChannelWv> = all
        .into_iter()
        .filter(|c| args.columns.is_empty() || args.columns.contains(&c.channel))
        .collect();
    if out.is_empty() {
        return Err(format_error(path, "no wavelet variance found".into()));
    }
    Ok(out)
}

fn read_wv_json(path: &Path) -> Result<Vec<ChannelWv>, InputError> {
    let text = std::fs::read_to_string(path).map_err(|source| TableError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format_error(path, format!("not JSON: {e}")))?;
    let is_board_list = value
        .as_array()
        .and_then(|a| a.first())
        .is_some_and(|first| first.get("imu_id").is_some());
    if is_board_list {
        return board_wvs(path, &text);
    }
    let obj = value.as_object().ok_or_else(|| {
        format_error(
            path,
            "expected a JSON object or the `wv.json` of `dynacal decode`".into(),
        )
    })?;
    if !obj.is_empty() && obj.values().all(|v| v.get("wvar").is_some()) {
        return smac_wvs(path);
    }
    stored_wvs(path, &value)
}

/// The `wv.json` of `dynacal decode`: the board's streaming wavelet variances, per IMU and
/// channel, in SI units. Channels are named `imuN/gx`, N the IMU id, as decode names the
/// IMUs' files (`imuN.csv`).
fn board_wvs(path: &Path, text: &str) -> Result<Vec<ChannelWv>, InputError> {
    let list: Vec<BoardChannelWv> = serde_json::from_str(text)
        .map_err(|e| format_error(path, format!("not a `dynacal decode` wv.json: {e}")))?;
    list.into_iter()
        .enumerate()
        .map(|(i, c)| {
            let name = format!("imu{}/{}", c.imu_id, c.channel);
            let wv = c.wv.ok_or_else(|| {
                format_error(
                    path,
                    format!(
                        "[{i}] ({name}): the board's snapshot is not usable: {}",
                        c.error.as_deref().unwrap_or("no wavelet variance")
                    ),
                )
            })?;
            Ok(ChannelWv {
                channel: name,
                unit: c.channel.si_unit().into(),
                wv,
            })
        })
        .collect()
}

/// The SMAC-Group reference file: {sensor: {sensor, freq, n, wvar: {...}}}.
fn smac_wvs(path: &Path) -> Result<Vec<ChannelWv>, InputError> {
    let golden = read_smac_golden(path).map_err(|source| InputError::Wv {
        path: path.to_path_buf(),
        channel: "*".into(),
        source,
    })?;
    Ok(golden
        .into_iter()
        .map(|g| {
            let key = g
                .channel_key()
                .map(str::to_string)
                .unwrap_or(g.channel.clone());
            let gyro = g.channel.starts_with("Gyro");
            // Units: the README of the data gives deg/s and g for ADIS16405; the other
            // sensors' source states none.
            let unit = match (g.sensor_key.as_str(), gyro) {
                ("adis", true) => "deg/s",
                ("adis", false) => "g",
                _ => "unstated",
            };
            ChannelWv {
                channel: format!("{}/{}", g.sensor_key, key),
                unit: unit.to_string(),
                wv: g.wv,
            }
        })
        .collect())
}

/// The output of `dynacal wv` (`{"channels": {name: WV}}`), one WV object, or a map or list
/// of them.
fn stored_wvs(path: &Path, value: &serde_json::Value) -> Result<Vec<ChannelWv>, InputError> {
    let single = |name: &str, v: &serde_json::Value| -> Result<ChannelWv, InputError> {
        let wv: WaveletVariance = serde_json::from_value(v.clone()).map_err(|e| {
            format_error(
                path,
                format!("channel `{name}`: not a wavelet variance: {e}"),
            )
        })?;
        let text = |key: &str| v.get(key).and_then(|c| c.as_str()).map(str::to_string);
        Ok(ChannelWv {
            channel: text("channel").unwrap_or_else(|| name.to_string()),
            unit: text("unit").unwrap_or_else(|| "unit".into()),
            wv,
        })
    };
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    if value.get("variance").is_some() && value.get("levels").is_some() {
        return Ok(vec![single(&stem, value)?]);
    }
    match value.get("channels").unwrap_or(value) {
        serde_json::Value::Array(items) => items
            .iter()
            .enumerate()
            .map(|(i, v)| single(&format!("{stem}[{i}]"), v))
            .collect(),
        serde_json::Value::Object(map) => map
            .iter()
            .filter(|(_, v)| v.is_object())
            .map(|(k, v)| single(k, v))
            .collect(),
        _ => Err(format_error(path, "no wavelet variance found".into())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A long interchange file is read into a spill file holding what the held read holds;
    /// a gap is refused naming the sample; a short file, or one with an axis alone, is
    /// left to the held read.
    #[test]
    fn a_long_interchange_file_spills_with_the_checks_the_held_read_makes() {
        use crate::calibration::Samples;
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, header: &str, gap_at: Option<usize>| {
            let path = dir.path().join(name);
            let mut text = format!("# sample_rate_hz: 100\n{header}\n");
            let fields = header.split(',').count() - 1;
            for k in 0..600 {
                let t = k as f64 * 0.01
                    + if gap_at.is_some_and(|g| k >= g) {
                        0.5
                    } else {
                        0.0
                    };
                text.push_str(&format!("{t}"));
                for f in 0..fields {
                    text.push_str(&format!(",{}", (k * (f + 3)) as f64 * 1e-3));
                }
                text.push('\n');
            }
            std::fs::write(&path, text).unwrap();
            path
        };
        let whole = "t_s,gx_rad_s,gy_rad_s,gz_rad_s,ax_m_s2,ay_m_s2,az_m_s2";
        let even = write("even.csv", whole, None);
        let spilled = spill_above(&even, true, 0).unwrap().expect("spilled");
        let held = load_recording(&even, true).unwrap();
        assert_eq!(spilled.len(), held.len());
        assert_eq!(spilled.times_s().unwrap(), held.t_s);
        for ch in 0..6 {
            let name = crate::model::Channel::ALL[ch].name();
            assert_eq!(
                spilled.channel_values(ch).unwrap().as_deref(),
                held.channel(name)
            );
        }
        assert!(spill_above(&even, true, SPILL_ABOVE_BYTES)
            .unwrap()
            .is_none());
        let gap = write("gap.csv", whole, Some(300));
        let Err(error) = spill_above(&gap, true, 0) else {
            panic!("a gap is refused");
        };
        let message = error.to_string();
        assert!(
            message.contains("gap.csv") && message.contains("sample 301"),
            "{message}"
        );
        assert!(spill_above(&gap, false, 0).unwrap().is_some());
        let lone = write("lone.csv", "t_s,gx_rad_s", None);
        assert!(spill_above(&lone, true, 0).unwrap().is_none());
    }

    /// An interchange recording keeps its channel names (gx..az) and SI units: `dynacal
    /// diagnose` looks its baseline models up by those names.
    #[test]
    fn interchange_recording_channels_are_named_gx_to_az() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rec.csv");
        let mut text = String::from("t_s,gx_rad_s,gy_rad_s,gz_rad_s,ax_m_s2,ay_m_s2,az_m_s2\n");
        for k in 0..512 {
            let v = ((k * 7919) % 101) as f64 * 1e-3;
            text.push_str(&format!(
                "{},{v},{v},{v},{v},{v},{}\n",
                k as f64 * 0.01,
                v - 9.8
            ));
        }
        std::fs::write(&path, text).unwrap();
        let chans =
            load_wavelet_variances(&path, &InputArgs::default(), &WvOptions::default()).unwrap();
        let names: Vec<&str> = chans.iter().map(|c| c.channel.as_str()).collect();
        assert_eq!(names, ["gx", "gy", "gz", "ax", "ay", "az"]);
        assert_eq!(chans[0].unit, "rad/s");
        assert_eq!(chans[5].unit, "m/s^2");
    }

    #[test]
    fn a_gap_is_named_by_its_line_and_a_stated_rate_must_match_the_time_column() {
        let p = Path::new("x.csv");
        let t: Vec<f64> = (0..10).map(|k| k as f64 * 0.01).collect();
        assert_eq!(
            sample_interval_s(p, &t, None).unwrap(),
            median_step_s(&t).unwrap()
        );
        assert!((sample_interval_s(p, &t, Some(100.0)).unwrap() - 0.01).abs() < 1e-15);
        let e = sample_interval_s(p, &t, Some(50.0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("x.csv") && e.contains("50 Hz") && e.contains("disagrees"),
            "{e}"
        );
        let mut gap = t.clone();
        for v in &mut gap[6..] {
            *v += 0.05;
        }
        // The step from sample 6 to sample 7 (1-based) is the gap: behind a header and a
        // rate line, sample 7 is on line 9; where the lines are not known, it is named.
        let e = sample_interval_at(p, &gap, None, RowLines::From(3))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 9") && e.contains("t_s"), "{e}");
        let e = sample_interval_s(p, &gap, None).unwrap_err().to_string();
        assert!(e.contains("sample 7 ") && e.contains("t_s 0.11"), "{e}");
    }

    #[test]
    fn per_channel_flags_resolve_and_name_unknown_channels() {
        let names = vec!["gx".to_string(), "ax".to_string()];
        let v = per_channel::<f64>(&["0.5".into(), "ax=2".into()], "--scale", &names).unwrap();
        assert_eq!(v, vec![Some(0.5), Some(2.0)]);
        let e = per_channel::<f64>(&["gz=2".into()], "--scale", &names)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--scale") && e.contains("no selected channel `gz`"),
            "{e}"
        );
    }
}
