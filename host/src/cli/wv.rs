//! `dynacal wv FILE --json OUT`: Haar wavelet variance (and overlapping Allan variance) of each
//! channel of a recording, with 95% intervals, written as one JSON file.
//!
//! Inputs: an interchange CSV (channels `gx` .. `az`, SI units, time from `t_s`); a dataset
//! file that `dynacal::import` recognises (imported to SI units first; with several sensors in
//! one file, channels are named `sensor/gx` ...); or any CSV with a header (channels are its
//! columns, `--columns` to choose; time from a `t_s` column or `--rate`). `--raw` reads a known
//! dataset as a plain CSV, e.g. the ADIS16405 sessions as integer counts (100 Hz, no time
//! column): `--raw --rate 100 --scale gx=0.05,gy=0.05,gz=0.05,ax=0.00333,ay=0.00333,az=0.00333`
//! gives deg/s and g, the reference WV's units. Columns holding only integers are processed
//! exactly as counts. Values keep the input's unit times `--scale`; variances are in its
//! square.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use dynacal::interchange::{read_table, ImuRecording, CHANNEL_COLUMNS};
use dynacal::wv::{haar_wv, haar_wv_counts, WaveletVariance, WvOptions};
use serde::Serialize;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Interchange CSV(.gz), or any CSV(.gz) with a header row.
    pub file: PathBuf,
    /// Comma-separated channels (interchange: gx,gy,gz,ax,ay,az; other CSV: column names).
    /// Default: every channel (every column except `t_s`).
    #[arg(long, value_delimiter = ',')]
    pub columns: Option<Vec<String>>,
    /// Sampling rate in Hz, for files without a `t_s` column (overrides `t_s` if both).
    #[arg(long)]
    pub rate: Option<f64>,
    /// Robust wavelet variance (Tukey biweight M-scale, efficiency `--efficiency`).
    #[arg(long)]
    pub robust: bool,
    /// Asymptotic efficiency of the robust estimate at Gaussian data.
    #[arg(long, default_value_t = 0.6)]
    pub efficiency: f64,
    /// Highest level J (default floor(log2 N) - 1, as the `wv` R package).
    #[arg(long)]
    pub max_level: Option<u32>,
    /// Physical units per input unit (e.g. per count), one factor for every channel (`0.05`)
    /// or per channel (`gx=0.05,ax=0.00333`); variances scale by its square.
    #[arg(long, value_delimiter = ',')]
    pub scale: Vec<String>,
    /// Read a known dataset file (see the data README) as a plain CSV instead of importing it
    /// into SI units with `dynacal::import` (e.g. to keep ADIS16405 integer counts exact).
    #[arg(long)]
    pub raw: bool,
    /// Output JSON file (written whole or not at all).
    #[arg(long)]
    pub json: PathBuf,
}

/// The JSON document written by `dynacal wv`.
#[derive(Debug, Serialize)]
struct Report {
    file: String,
    dt_s: f64,
    /// How the maximum level was chosen.
    max_level_rule: String,
    /// One wavelet variance per channel, keyed by channel name.
    channels: BTreeMap<String, WaveletVariance>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (dt_s, channels) = read_channels(&args)?;
    let scales = parse_scales(&args, &channels)?;
    let opts = WvOptions {
        max_level: args.max_level,
        robust: args.robust,
        efficiency: args.efficiency,
    };
    let mut out = BTreeMap::new();
    for ((name, values), scale) in channels.into_iter().zip(scales) {
        let wv = if let Some(counts) = as_counts(&values) {
            haar_wv_counts(&counts, scale, dt_s, &opts)
        } else {
            let scaled: Vec<f64> = values.iter().map(|v| v * scale).collect();
            haar_wv(&scaled, dt_s, &opts)
        }
        .with_context(|| format!("{}: column `{name}`", args.file.display()))?;
        out.insert(name, wv);
    }
    let report = Report {
        file: args.file.display().to_string(),
        dt_s,
        max_level_rule: match args.max_level {
            Some(j) => format!("--max-level {j}"),
            None => "floor(log2 N) - 1".into(),
        },
        channels: out,
    };
    dynacal::output::write_json_atomic(&args.json, &report)
        .with_context(|| format!("writing {}", args.json.display()))?;
    for (name, wv) in &report.channels {
        println!(
            "{name}: N = {}, {} levels, scales {:.4} .. {:.1} s",
            wv.n,
            wv.len(),
            wv.scales_s.first().copied().unwrap_or(0.0),
            wv.scales_s.last().copied().unwrap_or(0.0)
        );
    }
    println!("wrote {}", args.json.display());
    Ok(())
}

/// The `--scale` factor of each channel (1 where none is given).
fn parse_scales(args: &Args, channels: &Channels) -> anyhow::Result<Vec<f64>> {
    let mut scales = vec![1.0; channels.len()];
    for item in &args.scale {
        let (target, text) = match item.split_once('=') {
            Some((name, factor)) => (Some(name.trim()), factor),
            None => (None, item.as_str()),
        };
        let factor: f64 = text
            .trim()
            .parse()
            .ok()
            .filter(|f: &f64| f.is_finite() && *f != 0.0)
            .with_context(|| format!("--scale `{item}`: not a finite non-zero number"))?;
        match target {
            None => scales.iter_mut().for_each(|s| *s = factor),
            Some(name) => {
                let Some(i) = channels.iter().position(|(n, _)| n == name) else {
                    bail!("--scale `{item}`: no selected channel `{name}`");
                };
                scales[i] = factor;
            }
        }
    }
    Ok(scales)
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

fn header(path: &Path) -> anyhow::Result<Vec<String>> {
    let reader = dynacal::interchange::open_maybe_gz(path)?;
    let mut csv = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(reader);
    let headers = csv
        .headers()
        .with_context(|| format!("{}: line 1: cannot read the header", path.display()))?;
    Ok(headers.iter().map(str::to_string).collect())
}

fn rate_dt(path: &Path, rate: f64) -> anyhow::Result<f64> {
    if !(rate.is_finite() && rate > 0.0) {
        bail!(
            "{}: --rate must be a positive number of Hz, got {rate}",
            path.display()
        );
    }
    Ok(1.0 / rate)
}

/// Selected channels as (name, values), in the order asked for.
type Channels = Vec<(String, Vec<f64>)>;

/// Sampling interval and the selected channels.
fn read_channels(args: &Args) -> anyhow::Result<(f64, Channels)> {
    let path = &args.file;
    let headers = header(path)?;
    let interchange = headers.iter().any(|h| h == "t_s")
        && headers
            .iter()
            .any(|h| CHANNEL_COLUMNS.contains(&h.as_str()));
    if interchange {
        let rec = ImuRecording::read(path)?;
        return from_recordings(args, &[(String::new(), rec)]);
    }
    if !args.raw {
        if let Some(dataset) = dynacal::import::detect(path)? {
            let sensors = dynacal::import::import_file(path, dataset)?;
            let prefixed = sensors.len() > 1;
            let recordings: Vec<(String, ImuRecording)> = sensors
                .into_iter()
                .map(|s| {
                    (
                        if prefixed {
                            s.name + "/"
                        } else {
                            String::new()
                        },
                        s.recording,
                    )
                })
                .collect();
            return from_recordings(args, &recordings);
        }
    }
    let names: Vec<String> = match &args.columns {
        Some(c) => c.clone(),
        None => headers.iter().filter(|h| *h != "t_s").cloned().collect(),
    };
    for name in &names {
        if !headers.contains(name) {
            bail!(
                "{}: line 1: no column `{name}` (columns: {})",
                path.display(),
                headers.join(",")
            );
        }
    }
    if names.is_empty() {
        bail!("{}: line 1: no data column", path.display());
    }
    let mut wanted: Vec<&str> = names.iter().map(String::as_str).collect();
    let has_time = headers.iter().any(|h| h == "t_s");
    if has_time && args.rate.is_none() {
        wanted.push("t_s");
    }
    let table = read_table(path, Some(&wanted))?;
    if table.rows() == 0 {
        bail!("{}: no data rows", path.display());
    }
    let dt_s = match (args.rate, table.column("t_s")) {
        (Some(rate), _) => rate_dt(path, rate)?,
        (None, Some(t_s)) => {
            dynacal::interchange::check_time_increasing(path, t_s)?;
            uniform_dt(path, t_s)?
        }
        (None, None) => bail!(
            "{}: line 1: no `t_s` column; give the sampling rate with --rate HZ",
            path.display()
        ),
    };
    let channels = names
        .into_iter()
        .map(|name| {
            let values = table.column(&name).expect("checked above").to_vec();
            (name, values)
        })
        .collect();
    Ok((dt_s, channels))
}

/// Channels of interchange recordings (imported datasets give one per sensor; with several,
/// channel names are prefixed `sensor/`), and their common sampling interval.
fn from_recordings(
    args: &Args,
    recordings: &[(String, ImuRecording)],
) -> anyhow::Result<(f64, Channels)> {
    let path = &args.file;
    let mut available = Vec::new();
    for (prefix, rec) in recordings {
        available.extend(rec.channels().iter().map(|c| format!("{prefix}{c}")));
    }
    let names: Vec<String> = args.columns.clone().unwrap_or_else(|| available.clone());
    let mut channels = Vec::new();
    let mut dt_s = None;
    for name in names {
        let found = recordings.iter().find_map(|(prefix, rec)| {
            let short = name.strip_prefix(prefix.as_str())?;
            rec.channel(short).map(|values| (values.to_vec(), rec))
        });
        let Some((values, rec)) = found else {
            bail!(
                "{}: line 1: no channel `{name}` (this file has: {})",
                path.display(),
                available.join(",")
            );
        };
        let dt = match args.rate {
            Some(rate) => rate_dt(path, rate)?,
            None => uniform_dt(path, &rec.t_s)?,
        };
        if dt_s.is_some_and(|d: f64| (d - dt).abs() > 1e-9 * d) {
            bail!(
                "{}: channel `{name}` has another sampling interval",
                path.display()
            );
        }
        dt_s = Some(dt);
        channels.push((name, values));
    }
    let Some(dt_s) = dt_s else {
        bail!("{}: no channel selected", path.display());
    };
    Ok((dt_s, channels))
}

/// The sampling interval of a time column, which must be uniform: the wavelet variance assumes
/// equally spaced samples, so a gap (any step beyond 1.5 x the median) is an error naming its
/// line.
fn uniform_dt(path: &Path, t_s: &[f64]) -> anyhow::Result<f64> {
    if t_s.len() < 2 {
        bail!("{}: fewer than two samples", path.display());
    }
    let mut steps: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
    let mid = steps.len() / 2;
    let median = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
    if let Some(i) = t_s
        .windows(2)
        .position(|w| (w[1] - w[0] - median).abs() > 0.5 * median)
    {
        bail!(
            "{}: line {}, column `t_s`: step {} s differs from the median interval {median} s \
             (the wavelet variance needs evenly spaced samples)",
            path.display(),
            i + 3,
            t_s[i + 1] - t_s[i]
        );
    }
    // The mean step over the whole record is the best estimate of a uniform interval.
    Ok((t_s[t_s.len() - 1] - t_s[0]) / (t_s.len() - 1) as f64)
}
