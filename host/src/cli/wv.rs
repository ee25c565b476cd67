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

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{bail, Context};
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
    /// One wavelet variance per channel, keyed by channel name.
    channels: BTreeMap<String, WaveletVariance>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let series = load_series(&args.file, &args.input)?;
    let opts = WvOptions {
        max_level: args.max_level,
        robust: args.robust,
        efficiency: args.efficiency,
    };
    let dt_s = series[0].dt_s;
    let mut channels = BTreeMap::new();
    for s in &series {
        if (s.dt_s - dt_s).abs() > 1e-9 * dt_s {
            bail!(
                "{}: channel `{}` has another sample interval ({} s, not {dt_s} s)",
                args.file.display(),
                s.name,
                s.dt_s
            );
        }
        let wv = s
            .wavelet_variance(&opts)
            .with_context(|| format!("{}: column `{}`", args.file.display(), s.name))?;
        channels.insert(s.name.clone(), wv);
    }
    let report = Report {
        file: args.file.display().to_string(),
        dt_s,
        max_level_rule: match args.max_level {
            Some(j) => format!("--max-level {j}"),
            None => "floor(log2 N) - 1".into(),
        },
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
