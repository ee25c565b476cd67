//! `dynacal fit FILE --model M|auto --json OUT`: GMWM fit of every channel of a recording or
//! of stored wavelet variances, with intervals, J-test and (for auto) ranked candidates. A
//! long interchange recording is read once in bounded memory (`--stream`, as `dynacal wv`):
//! the fit needs only its wavelet variances.

use std::path::PathBuf;

use dynacal::gmwm::inference::{BootstrapOptions, ModelChoice};
use dynacal::gmwm::model::Structure;
use dynacal::input::stream::StreamMode;
use dynacal::input::InputArgs;
use dynacal::model::{fit_file_as, fitted_model};

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
    /// Read the file once, row by row, in bounded memory: `auto` above 256 MiB on disk,
    /// `always`, or `never` (load it whole). Levels above 18 are then decimated, as
    /// `dynacal wv` says.
    #[arg(long, value_enum, default_value_t = StreamMode::Auto)]
    pub stream: StreamMode,
    /// Output: the model file (`docs/formats.md`: loads in `dynacal simulate --model` and
    /// `dynacal diagnose --baseline`) with the fit statistics beside it; written whole or
    /// not at all.
    #[arg(long)]
    pub json: PathBuf,
    /// Also write DIR/report.html: the figures and tables, one self-contained page.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
}

pub fn model_choice(model: &str) -> anyhow::Result<ModelChoice> {
    Ok(if model.trim().eq_ignore_ascii_case("auto") {
        ModelChoice::Auto
    } else {
        ModelChoice::Fixed(Structure::parse(model)?)
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let choice = model_choice(&args.model)?;
    let bootstrap = (args.bootstrap > 0).then_some(BootstrapOptions {
        replicates: args.bootstrap,
        seed: args.seed,
    });
    let bar = super::working(&format!("fitting {}", args.file.display()));
    let fits = fit_file_as(&args.file, &args.input, &choice, bootstrap, args.stream);
    bar.finish_and_clear();
    let fits = fits?;
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
    let (model, notes) = fitted_model(&args.file, &args.model, &fits)?;
    for note in notes {
        println!("note: {note}");
    }
    let file = args.file.display().to_string();
    let page = match &args.report {
        Some(_) => Some(
            dynacal::report::pages::fit_report(&file, &fits)
                .map_err(|e| anyhow::anyhow!("drawing the report: {e}"))?,
        ),
        None => None,
    };
    super::write_json_and_report(&args.json, &model, args.report.as_deref(), page.as_ref())
}
