//! `dynacal compare STATIC DYNAMIC --model M --json OUT`: fits both recordings with the same
//! model and prints the paper's Table I comparison (interval overlap and Wald test per
//! parameter) for each channel present in both.

use std::path::PathBuf;

use anyhow::Context;

use dynacal::gmwm::compare::{compare, format_table};

use dynacal::input::InputArgs;

use super::fit::model_choice;
use dynacal::model::fit_file;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Recording (or WV JSON) under static conditions.
    pub static_file: PathBuf,
    /// Recording (or WV JSON) under dynamic conditions.
    pub dynamic_file: PathBuf,
    /// The model both are fitted with, e.g. "WN+GM+GM".
    #[arg(long)]
    pub model: String,
    #[command(flatten)]
    pub input: InputArgs,
    /// Output JSON (written whole or not at all).
    #[arg(long)]
    pub json: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let choice = model_choice(&args.model)?;
    if matches!(choice, dynacal::gmwm::inference::ModelChoice::Auto) {
        anyhow::bail!(
            "--model auto: a comparison needs one model for both fits; give it, e.g. \"WN+GM+GM\""
        );
    }
    let bar = super::working(&format!("fitting {}", args.static_file.display()));
    let a = fit_file(&args.static_file, &args.input, &choice, None);
    bar.set_message(format!("fitting {}", args.dynamic_file.display()));
    let b = a.and_then(|a| Ok((a, fit_file(&args.dynamic_file, &args.input, &choice, None)?)));
    bar.finish_and_clear();
    let (a, b) = b?;
    let mut channels = Vec::new();
    for fa in &a {
        let Some(fb) = b.iter().find(|f| f.channel == fa.channel) else {
            continue;
        };
        if (fa.sample_rate_hz / fb.sample_rate_hz - 1.0).abs() > 0.01 {
            anyhow::bail!(
                "channel {}: {} is sampled at {} Hz, {} at {} Hz: one model's per-sample \
                 parameters (white noise, quantization) do not compare across rates; \
                 compare recordings at one rate",
                fa.channel,
                args.static_file.display(),
                dynacal::interchange::shortest_rate_hz(fa.sample_rate_hz),
                args.dynamic_file.display(),
                dynacal::interchange::shortest_rate_hz(fb.sample_rate_hz)
            );
        }
        let rows = compare(fa, fb).with_context(|| format!("channel {}", fa.channel))?;
        println!("channel {} ({}):", fa.channel, fa.model);
        print!("{}", format_table(&rows));
        channels.push(serde_json::json!({
            "channel": fa.channel, "model": fa.model, "rows": rows,
            "static": fa, "dynamic": fb,
        }));
    }
    if channels.is_empty() {
        anyhow::bail!(
            "no channel present in both {} and {}",
            args.static_file.display(),
            args.dynamic_file.display()
        );
    }
    let out = serde_json::json!({
        "static_file": args.static_file.display().to_string(),
        "dynamic_file": args.dynamic_file.display().to_string(),
        "model": args.model,
        "channels": channels,
    });
    dynacal::output::write_json_atomic(&args.json, &out)
        .with_context(|| format!("writing {}", args.json.display()))?;
    super::wrote(&[args.json.as_path()]);
    Ok(())
}
