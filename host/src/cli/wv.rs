//! `dynacal wv FILE --json OUT`: Haar wavelet variance (and overlapping Allan variance) of each
//! channel of a recording, with 95% intervals, written as one JSON file.
//!
//! Inputs are read by [`dynacal::input`]: an interchange CSV (channels `gx` .. `az`, SI
//! units); a dataset file that `dynacal import` recognises (imported to SI units first; with
//! several sensors in one file, channels are named `sensor/gx` ...); or any CSV with a header
//! (channels are its columns, `--columns` to choose; time from a `t_s` column or `--rate-hz`).
//! `--raw` reads a known dataset as a plain CSV, e.g. the ADIS16405 sessions as integer counts
//! (100 Hz, no time column): `--raw --rate-hz 100 --scale
//! gx=0.05,gy=0.05,gz=0.05,ax=0.00333,ay=0.00333,az=0.00333` gives deg/s and g, the reference
//! WV's units. Columns holding only integers are processed exactly as counts. Values keep the
//! input's unit times `--scale`; variances are in its square.
//!
//! Long recordings are streamed (`--stream auto`, the default: an interchange file larger than
//! 256 MiB on disk, [`dynacal::input::stream::STREAM_THRESHOLD_BYTES`], plain or gzip, whose
//! rate is stated or given): read once, block by block, in memory that does not grow with the
//! length (about 8 MiB per channel). Levels 1..=18 are then the batch estimator's to ~1e-12;
//! higher levels (recordings of 2^20 samples or more) are decimated as on the board, every
//! 2^{j-1}-th coefficient, with intervals 9/4 as wide in variance; the JSON says so in
//! `streamed`. `--stream always` streams any file that allows it (else an error saying why),
//! `--stream never` loads it whole. `--robust` is never streamed.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{bail, Context};
use dynacal::input::stream::{streamed_if_wanted, StreamMode};
use dynacal::input::{load_series, InputArgs};
use dynacal::wv::{WaveletVariance, WvOptions};
use serde::Serialize;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Interchange CSV(.gz), a known dataset file, or any CSV(.gz) with a header row.
    pub file: PathBuf,
    #[command(flatten)]
    pub input: InputArgs,
    /// Robust wavelet variance (Tukey biweight M-scale, efficiency `--efficiency`).
    #[arg(long)]
    pub robust: bool,
    /// Asymptotic efficiency of the robust estimate at Gaussian data.
    #[arg(long, default_value_t = 0.6)]
    pub efficiency: f64,
    /// Highest level J (default floor(log2 N) - 1, as the `wv` R package).
    #[arg(long)]
    pub max_level: Option<u32>,
    /// Read the file once, row by row, in bounded memory: `auto` above 256 MiB on disk,
    /// `always`, or `never` (load it whole).
    #[arg(long, value_enum, default_value_t = StreamMode::Auto)]
    pub stream: StreamMode,
    /// Output JSON file (written whole or not at all).
    #[arg(long)]
    pub json: PathBuf,
    /// Also write DIR/report.html: the figures and tables, one self-contained page.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
}

/// The JSON document written by `dynacal wv`.
#[derive(Debug, Serialize)]
struct Report {
    file: String,
    dt_s: f64,
    /// How the maximum level was chosen.
    max_level_rule: String,
    /// Present when the file was streamed: which levels are decimated.
    #[serde(skip_serializing_if = "Option::is_none")]
    streamed: Option<StreamNote>,
    /// One wavelet variance per channel, keyed by channel name.
    channels: BTreeMap<String, WaveletVariance>,
}

/// What streaming changed in the estimates.
#[derive(Debug, Serialize)]
struct StreamNote {
    /// Levels 1..=full_levels use every (overlapping) coefficient: the batch estimator.
    full_levels: u32,
    /// What the levels above are.
    decimated_levels: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let opts = WvOptions {
        max_level: args.max_level,
        robust: args.robust,
        efficiency: args.efficiency,
    };
    let (dt_s, channels, streamed) =
        match streamed_if_wanted(&args.file, &args.input, &opts, args.stream)? {
            Some(s) => {
                let channels = s.channels.into_iter().map(|c| (c.channel, c.wv)).collect();
                let note = StreamNote {
                    full_levels: s.full_levels,
                    decimated_levels: format!(
                        "levels above {} use every 2^(j-1)-th coefficient (as the board's \
                     streaming accumulator); their intervals have 4/9 of the degrees of \
                     freedom of that many overlapping coefficients",
                        s.full_levels
                    ),
                };
                (s.dt_s, channels, Some(note))
            }
            None => {
                let (dt_s, channels) = batch(&args, &opts)?;
                (dt_s, channels, None)
            }
        };
    let report = Report {
        file: args.file.display().to_string(),
        dt_s,
        max_level_rule: match args.max_level {
            Some(j) => format!("--max-level {j}"),
            None => "floor(log2 N) - 1".into(),
        },
        streamed,
        channels,
    };
    let page = match &args.report {
        Some(_) => Some(
            dynacal::report::pages::wv_report(&report.file, &report.channels)
                .map_err(|e| anyhow::anyhow!("drawing the report: {e}"))?,
        ),
        None => None,
    };
    for (name, wv) in &report.channels {
        println!(
            "{name}: N = {}, {} levels, scales {:.4} .. {:.1} s",
            wv.n,
            wv.len(),
            wv.scales_s.first().copied().unwrap_or(0.0),
            wv.scales_s.last().copied().unwrap_or(0.0)
        );
    }
    super::write_json_and_report(&args.json, &report, args.report.as_deref(), page.as_ref())
}

/// The whole file loaded and every channel's batch estimate.
fn batch(
    args: &Args,
    opts: &WvOptions,
) -> anyhow::Result<(f64, BTreeMap<String, WaveletVariance>)> {
    let series = load_series(&args.file, &args.input)?;
    let dt_s = series[0].dt_s;
    let mut channels = BTreeMap::new();
    for mut s in series {
        if (s.dt_s - dt_s).abs() > 1e-9 * dt_s {
            bail!(
                "{}: channel `{}` has another sample interval ({} s, not {dt_s} s)",
                args.file.display(),
                s.name,
                s.dt_s
            );
        }
        let name = std::mem::take(&mut s.name);
        let wv = s
            .into_wavelet_variance(opts)
            .with_context(|| format!("{}: column `{name}`", args.file.display()))?;
        channels.insert(name, wv);
    }
    Ok((dt_s, channels))
}
