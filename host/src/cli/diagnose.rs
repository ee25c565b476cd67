//! `dynacal diagnose`: what the simulation gets wrong, the named causes, the extended model
//! and the measured gain, for one sensor against a reference (or static data alone).

use std::path::PathBuf;

use anyhow::Context;
use dynacal::diagnose::engine::{diagnose_recordings, Baseline, DiagnoseOptions, Recording};
use dynacal::diagnose::report;
use dynacal::input::{load_recording, spill_if_long};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The sensor under test (interchange CSV or CSV.gz, or a one-sensor dataset file that
    /// `dynacal import` knows), evenly sampled.
    #[arg(long)]
    pub sensor: PathBuf,
    /// The reference IMU or navigation solution; without it the data are taken as static.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Baseline error model: a model file (`docs/formats.md` section 3) with one MEMS IMU,
    /// e.g. the output of `dynacal fit` on a static recording or the extended model of an
    /// earlier `diagnose`. Without it, one is fitted on the quietest stretch of the data,
    /// and the output says so.
    #[arg(long)]
    pub baseline: Option<PathBuf>,
    /// Output JSON (findings, gain, discrepancies, extended model).
    #[arg(long)]
    pub json: PathBuf,
    /// Also write a readable report into DIR: report.md with its plots (wavelet variance per
    /// channel, gain, findings; SVG) and the extended model file, whole or not at all.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Baseline simulations per channel.
    #[arg(long, default_value_t = 30)]
    pub replicates: usize,
    /// Seed of the simulations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Family-wise false-alarm level: the probability that a run with nothing beyond the
    /// baseline names any cause (Bonferroni over the run's tests).
    #[arg(long, default_value_t = 0.05)]
    pub alpha: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.replicates >= 5,
        "--replicates must be at least 5, got {}",
        args.replicates
    );
    anyhow::ensure!(
        args.alpha > 0.0 && args.alpha < 1.0,
        "--alpha must lie in (0, 1), got {}",
        args.alpha
    );
    super::map_long_series_alone();
    // A long interchange file is read into a spill file, never held whole.
    let read = |path: &std::path::Path, evenly_sampled: bool| -> anyhow::Result<Recording> {
        Ok(match spill_if_long(path, evenly_sampled)? {
            Some(spilled) => Recording::Spilled(spilled),
            None => Recording::Held(load_recording(path, evenly_sampled)?),
        })
    };
    let sensor = read(&args.sensor, true)?;
    let reference = args
        .reference
        .as_deref()
        .map(|r| read(r, false))
        .transpose()?;
    let baseline = args.baseline.as_deref().map(Baseline::load).transpose()?;
    let opts = DiagnoseOptions {
        replicates: args.replicates,
        seed: args.seed,
        alpha: args.alpha,
        ..Default::default()
    };
    let bar = super::working(&format!(
        "diagnosing {} ({} simulations per channel)",
        args.sensor.display(),
        args.replicates
    ));
    let report = diagnose_recordings(sensor, reference, baseline, &opts)
        .with_context(|| format!("diagnosing {}", args.sensor.display()));
    bar.finish_and_clear();
    let report = report?;
    let html = args
        .report
        .as_ref()
        .map(|d| d.join(dynacal::report::REPORT_HTML));
    if let Some(dir) = &args.report {
        report::write_report(dir, &report)
            .with_context(|| format!("writing the report into {}", dir.display()))?;
    }
    dynacal::output::write_json_atomic(&args.json, &report)
        .with_context(|| format!("writing {}", args.json.display()))?;
    print!("{}", report::markdown(&report, &report::Figures::default()));
    let mut written = vec![args.json.as_path()];
    written.extend(html.as_deref());
    super::wrote(&written);
    Ok(())
}
