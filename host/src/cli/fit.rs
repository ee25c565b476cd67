//! `dynacal fit FILE --model M|auto --json OUT`: GMWM fit of every channel of a recording or
//! of stored wavelet variances, with intervals, J-test and (for auto) ranked candidates.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use rayon::prelude::*;

use dynacal::gmwm::fit::{FitInput, FitOptions};
use dynacal::gmwm::inference::{analyze, BootstrapOptions, ChannelFit, ModelChoice};
use dynacal::gmwm::input::{load_channels, ReadOptions};
use dynacal::gmwm::model::Structure;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Interchange CSV(.gz), any CSV(.gz) by column name (with --rate-hz), or a WV JSON
    /// (output of `dynacal wv`, or the SMAC-Group reference file).
    pub file: PathBuf,
    /// Model, e.g. "WN+GM+GM", "WN+RW+QN+DR+GM", or "auto" (chosen by WIC).
    #[arg(long, default_value = "auto")]
    pub model: String,
    /// Channels (interchange: gx..az; CSV: column names; reference file: sensor/channel).
    #[arg(long, value_delimiter = ',')]
    pub columns: Vec<String>,
    /// Sample rate of a CSV without a `t_s` column, Hz.
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Multiplier of plain-CSV columns: "0.05" or "gx=0.05,ax=0.00333".
    #[arg(long)]
    pub scale: Option<String>,
    /// Unit of plain-CSV columns after scaling: "deg/s" or "gx=deg/s,ax=g".
    #[arg(long)]
    pub unit: Option<String>,
    /// Parametric bootstrap replicates for the intervals (0: delta method).
    #[arg(long, default_value_t = 0)]
    pub bootstrap: usize,
    /// Seed of the bootstrap.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output JSON (written whole or not at all).
    #[arg(long)]
    pub json: PathBuf,
}

/// "v" or "k=v,k=v" into a map ("" = every column).
pub fn parse_map<T: std::str::FromStr>(
    text: &str,
    what: &str,
) -> anyhow::Result<BTreeMap<String, T>>
where
    T::Err: std::fmt::Display,
{
    let mut out = BTreeMap::new();
    for item in text.split(',') {
        let (k, v) = match item.split_once('=') {
            Some((k, v)) => (k.trim().to_string(), v.trim()),
            None => (String::new(), item.trim()),
        };
        let parsed = v
            .parse::<T>()
            .map_err(|e| anyhow::anyhow!("--{what}: `{item}`: {e}"))?;
        out.insert(k, parsed);
    }
    Ok(out)
}

pub fn read_options(
    columns: &[String],
    rate_hz: Option<f64>,
    scale: Option<&str>,
    unit: Option<&str>,
) -> anyhow::Result<ReadOptions> {
    Ok(ReadOptions {
        columns: columns.to_vec(),
        rate_hz,
        scale: scale
            .map(|s| parse_map(s, "scale"))
            .transpose()?
            .unwrap_or_default(),
        unit: unit
            .map(|s| parse_map(s, "unit"))
            .transpose()?
            .unwrap_or_default(),
        ..ReadOptions::default()
    })
}

pub fn model_choice(model: &str) -> anyhow::Result<ModelChoice> {
    Ok(if model.trim().eq_ignore_ascii_case("auto") {
        ModelChoice::Auto
    } else {
        ModelChoice::Fixed(Structure::parse(model)?)
    })
}

/// Fits every channel of `file` (channels in parallel).
pub fn fit_file(
    file: &std::path::Path,
    opts: &ReadOptions,
    choice: &ModelChoice,
    bootstrap: Option<BootstrapOptions>,
) -> anyhow::Result<Vec<ChannelFit>> {
    let channels = load_channels(file, opts)?;
    channels
        .par_iter()
        .map(|c| {
            let input = FitInput::from_wv(&c.wv)
                .with_context(|| format!("{}: channel {}", file.display(), c.channel))?;
            analyze(
                &c.channel,
                &c.unit,
                &input,
                choice,
                bootstrap,
                &FitOptions::default(),
            )
            .with_context(|| format!("{}: channel {}", file.display(), c.channel))
        })
        .collect()
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let choice = model_choice(&args.model)?;
    let opts = read_options(
        &args.columns,
        args.rate_hz,
        args.scale.as_deref(),
        args.unit.as_deref(),
    )?;
    let bootstrap = (args.bootstrap > 0).then_some(BootstrapOptions {
        replicates: args.bootstrap,
        seed: args.seed,
    });
    let fits = fit_file(&args.file, &opts, &choice, bootstrap)?;
    for f in &fits {
        println!(
            "{}: {} objective {:.4e}, {} in {} iterations ({:?}), J-test p = {}",
            f.channel,
            f.model,
            f.objective,
            if f.converged {
                "converged"
            } else {
                "NOT converged"
            },
            f.iterations,
            f.stop_reason,
            f.j_test
                .as_ref()
                .map(|j| format!("{:.3e}", j.p_value))
                .unwrap_or_else(|| "n/a".into())
        );
        for p in &f.parameters {
            let ci = p
                .ci95
                .map(|[l, h]| format!("[{l:.5e}, {h:.5e}]"))
                .unwrap_or_else(|| "n/a".into());
            println!(
                "  {:<5} {:<19} {:>13.6e} {ci} {}",
                p.process, p.name, p.value, p.unit
            );
        }
        for w in &f.warnings {
            println!("  warning: {w}");
        }
    }
    let out = serde_json::json!({
        "file": args.file.display().to_string(),
        "requested_model": args.model,
        "channels": fits,
    });
    dynacal::output::write_json_atomic(&args.json, &out)
        .with_context(|| format!("writing {}", args.json.display()))?;
    Ok(())
}
