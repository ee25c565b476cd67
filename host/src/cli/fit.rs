//! `dynacal fit FILE --model M|auto --json OUT`: GMWM fit of every channel of a recording or
//! of stored wavelet variances, with intervals, J-test and (for auto) ranked candidates.

use std::path::PathBuf;

use anyhow::Context;
use rayon::prelude::*;

use dynacal::gmwm::fit::{FitInput, FitOptions};
use dynacal::gmwm::inference::{analyze, BootstrapOptions, ChannelFit, ModelChoice};
use dynacal::gmwm::model::{ModelSpec, Structure};
use dynacal::input::{load_wavelet_variances, InputArgs};
use dynacal::model::SimModel;
use dynacal::wv::WvOptions;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Interchange CSV(.gz), a known dataset file, any CSV(.gz) by column name, or stored
    /// wavelet variances (the JSON of `dynacal wv`, the `wv.json` of `dynacal decode`, or the
    /// SMAC-Group reference file).
    pub file: PathBuf,
    #[command(flatten)]
    pub input: InputArgs,
    /// Model, e.g. "WN+GM+GM", "WN+RW+QN+DR+GM", or "auto" (chosen by WIC).
    #[arg(long, default_value = "auto")]
    pub model: String,
    /// Parametric bootstrap replicates for the intervals (0: delta method).
    #[arg(long, default_value_t = 0)]
    pub bootstrap: usize,
    /// Seed of the bootstrap.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output: the model file (`docs/formats.md`: loads in `dynacal simulate --model` and
    /// `dynacal diagnose --baseline`) with the fit statistics beside it; written whole or
    /// not at all.
    #[arg(long)]
    pub json: PathBuf,
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
    input: &InputArgs,
    choice: &ModelChoice,
    bootstrap: Option<BootstrapOptions>,
) -> anyhow::Result<Vec<ChannelFit>> {
    let channels = load_wavelet_variances(file, input, &WvOptions::default())?;
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
    let bootstrap = (args.bootstrap > 0).then_some(BootstrapOptions {
        replicates: args.bootstrap,
        seed: args.seed,
    });
    let fits = fit_file(&args.file, &args.input, &choice, bootstrap)?;
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
    let model = fitted_model(&args.file, &args.model, &fits)?;
    dynacal::output::write_json_atomic(&args.json, &model)
        .with_context(|| format!("writing {}", args.json.display()))?;
    Ok(())
}

/// What `dynacal fit` writes beside the model: the statistics of every channel's fit.
#[derive(serde::Serialize)]
struct FitRecord<'a> {
    file: String,
    requested_model: &'a str,
    channels: &'a [ChannelFit],
}

/// The model file of `fits`: each channel's fitted model on the IMU channel its name
/// denotes (the IMU named after the file), with the fit statistics beside it. Channels that
/// name no IMU channel stay in the statistics only, and the user is told.
fn fitted_model(
    file: &std::path::Path,
    requested_model: &str,
    fits: &[ChannelFit],
) -> anyhow::Result<SimModel> {
    let specs: Vec<(String, ModelSpec)> = fits
        .iter()
        .map(|f| (f.channel.clone(), f.model_object.clone()))
        .collect();
    let (mut model, unmapped) = SimModel::from_channel_models(&recording_stem(file), &specs);
    if !unmapped.is_empty() {
        println!(
            "note: {} name no IMU channel (gx..az): kept in `fit` only, not in the model",
            unmapped.join(", ")
        );
    }
    model.comment = Some(format!(
        "fitted by dynacal fit on {} (model {requested_model})",
        file.display()
    ));
    model.fit = Some(serde_json::to_value(FitRecord {
        file: file.display().to_string(),
        requested_model,
        channels: fits,
    })?);
    if let Err(e) = model.validate(file) {
        println!("note: the fitted model will not load in `dynacal simulate`: {e}");
    }
    Ok(model)
}

/// A file's name without its directory and its extensions (`in/psins-mems.csv.gz` ->
/// `psins-mems`): the name of the IMU a fit describes.
fn recording_stem(file: &std::path::Path) -> String {
    let name = file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    name.split('.').next().unwrap_or_default().to_string()
}
