//! `dynacal diagnose`: what the simulation gets wrong, the named causes, the extended model
//! and the measured gain, for one sensor against a reference (or static data alone).

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use dynacal::diagnose::engine::{diagnose, Baseline, DiagnoseOptions, DiagnoseReport};
use dynacal::interchange::ImuRecording;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The sensor under test (interchange CSV or CSV.gz).
    #[arg(long)]
    pub sensor: PathBuf,
    /// The reference IMU or navigation solution; without it the data are taken as static.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Baseline error model: the JSON written by `dynacal fit` (SI units). Without it, one is
    /// fitted on the quietest stretch of the data, and the output says so.
    #[arg(long)]
    pub baseline: Option<PathBuf>,
    /// Output JSON (findings, gain, discrepancies, extended model).
    #[arg(long)]
    pub json: PathBuf,
    /// Also write a readable report (report.md) and the extended model file into DIR.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Baseline simulations per channel.
    #[arg(long, default_value_t = 30)]
    pub replicates: usize,
    /// Seed of the simulations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.replicates >= 5,
        "--replicates must be at least 5, got {}",
        args.replicates
    );
    let sensor = ImuRecording::read(&args.sensor)?;
    let reference = args
        .reference
        .as_deref()
        .map(ImuRecording::read)
        .transpose()?;
    let baseline = args.baseline.as_deref().map(Baseline::load).transpose()?;
    let opts = DiagnoseOptions {
        replicates: args.replicates,
        seed: args.seed,
        ..Default::default()
    };
    let report = diagnose(&sensor, reference.as_ref(), baseline, &opts)
        .with_context(|| format!("diagnosing {}", args.sensor.display()))?;
    let text = render(&report);
    if let Some(dir) = &args.report {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        dynacal::output::write_atomic(&dir.join("report.md"), text.as_bytes())
            .with_context(|| format!("writing {}", dir.join("report.md").display()))?;
        dynacal::output::write_json_atomic(
            &dir.join("extended-model.json"),
            &report.extended_model,
        )
        .with_context(|| format!("writing {}", dir.join("extended-model.json").display()))?;
    }
    dynacal::output::write_json_atomic(&args.json, &report)
        .with_context(|| format!("writing {}", args.json.display()))?;
    print!("{text}");
    Ok(())
}

/// The report as Markdown.
pub fn render(r: &DiagnoseReport) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# dynacal diagnose\n\nbaseline: {}\n", r.baseline_source);
    for n in &r.notes {
        let _ = writeln!(s, "- note: {n}");
    }
    if let Some(c) = &r.calibration {
        let deg = 180.0 / std::f64::consts::PI;
        let b = c.boresight_rad;
        let _ = writeln!(s, "\n## Calibration against the reference\n\nboresight (deg) {:+.4} {:+.4} {:+.4} (1-sigma {:.4} {:.4} {:.4})", b.value[0] * deg, b.value[1] * deg, b.value[2] * deg, b.sigma[0] * deg, b.sigma[1] * deg, b.sigma[2] * deg);
        if let Some(l) = c.lever_arm_m {
            let _ = writeln!(
                s,
                "lever arm (m) {:+.4} {:+.4} {:+.4} (1-sigma {:.4} {:.4} {:.4})",
                l.value[0], l.value[1], l.value[2], l.sigma[0], l.sigma[1], l.sigma[2]
            );
        }
        if let Some(t) = c.time_offset_s {
            let _ = writeln!(
                s,
                "time offset (s) {:+.5} (1-sigma {:.5})",
                t.value, t.sigma
            );
        }
    }
    let _ = writeln!(s, "\n## What the simulation gets wrong\n\n| channel | statistic | measured | baseline simulations | detail |\n|---|---|---|---|---|");
    for d in &r.discrepancies {
        let _ = writeln!(
            s,
            "| {} | {} | {:.4e} | [{:.4e}, {:.4e}] | {} |",
            d.channel,
            d.statistic,
            d.measured,
            d.simulated_range[0],
            d.simulated_range[1],
            d.detail
        );
    }
    let _ = writeln!(s, "\n## Named causes\n\n| channel | cause | regressors | estimate (SI) | 95% interval | variance explained |\n|---|---|---|---|---|---|");
    for f in &r.findings {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {:.2} % |",
            f.channel,
            f.cause,
            f.regressors.join(", "),
            f.estimate,
            f.ci95,
            100.0 * f.variance_explained
        );
    }
    if r.findings.is_empty() {
        let _ = writeln!(s, "| - | nothing beyond the baseline | | | | |");
    }
    let _ = writeln!(s, "\n## Gain of the extended model\n\nmetric: WV misfit (mean squared z of the log wavelet variance against model simulations; about 1 for a model that fits)\n\n| channel | baseline | extended | held-out baseline | held-out extended | variance explained | held-out variance explained |\n|---|---|---|---|---|---|---|");
    for (ch, g) in &r.gain {
        let _ = writeln!(
            s,
            "| {ch} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} % | {:.2} % |",
            g.baseline,
            g.extended,
            g.held_out_baseline,
            g.held_out_extended,
            100.0 * g.variance_explained,
            100.0 * g.held_out_variance_explained
        );
    }
    s
}
