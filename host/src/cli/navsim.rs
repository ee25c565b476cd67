//! `dynacal navsim --scalar f64|f32|fixed --seconds S --seed K --outage-s O --json OUT [--model
//! M.json]`: the board's fusion filter on a simulated car drive with GNSS outages, on the
//! host in the scalar asked, measured against the truth ([`dynacal::navsim`]).

use std::path::PathBuf;

use anyhow::Context;
use dynacal::model::SimModel;
use dynacal::navsim::{run as navsim, three_unit_model, NavSimOptions, Scalar};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The filter's scalar.
    #[arg(long, value_enum, default_value_t = Scalar::F64)]
    pub scalar: Scalar,
    /// Length of the drive, s.
    #[arg(long, default_value_t = 600.0)]
    pub seconds: f64,
    /// Seed of the drive (trajectory, units' noise, fixes).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Length of each GNSS outage, s: one per 300 s of driving (at least one), spread
    /// through the run; 0 for none.
    #[arg(long, default_value_t = 30.0)]
    pub outage_s: f64,
    /// The measured figures (JSON).
    #[arg(long)]
    pub json: PathBuf,
    /// A model file of three units sampled together (the first at the body's origin,
    /// unturned) and a GNSS receiver; default `examples/models/three-units-200hz.json`.
    #[arg(long)]
    pub model: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let model = match &args.model {
        Some(path) => SimModel::load(path)?,
        None => three_unit_model(),
    };
    anyhow::ensure!(
        args.seconds.is_finite() && args.seconds > 0.0,
        "--seconds must be a positive number of seconds, got {}",
        args.seconds
    );
    anyhow::ensure!(
        args.outage_s.is_finite() && args.outage_s >= 0.0 && args.outage_s < args.seconds,
        "--outage-s must be from 0 to the drive's length ({} s), got {}",
        args.seconds,
        args.outage_s
    );
    let options = NavSimOptions {
        seconds: args.seconds,
        seed: args.seed,
        outage_s: args.outage_s,
        scalar: args.scalar,
    };
    let bar = super::working(&format!("navigating {} s of driving", args.seconds));
    let report = navsim(&model, &options);
    bar.finish_and_clear();
    let report = report.with_context(|| match &args.model {
        Some(path) => format!("{}", path.display()),
        None => "the built-in three-unit drive".into(),
    })?;
    dynacal::output::write_json_atomic(&args.json, &report)
        .with_context(|| format!("writing {}", args.json.display()))?;
    println!(
        "{}: position RMS {:.3} m with GNSS, {:.3} m in outages; attitude RMS {:.3} deg; NEES {:.2} in [{:.2}, {:.2}] (its {} samples worth {:.1} independent ones by {}; [{:.2}, {:.2}] if they were independent); calibrations' NEES {:.2} (of 12 states); at most {:.3} m/s taken for a standstill; {} overflow events",
        args.scalar.name(),
        report.position_rms_m,
        report.position_rms_outage_m,
        report.attitude_rms_deg,
        report.nees_mean,
        report.nees_bounds[0],
        report.nees_bounds[1],
        report.nees_samples,
        report.nees_effective_samples,
        report.nees_judged_by,
        report.nees_bounds_independent[0],
        report.nees_bounds_independent[1],
        report.calibration_nees_mean,
        report.still_speed_max_m_s,
        report.overflow_events
    );
    super::wrote(&[&args.json]);
    Ok(())
}
