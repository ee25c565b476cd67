//! `dynacal fig1`: reproduces Fig. 1 of the paper on simulated data (joint inter-IMU
//! boresight and lever-arm estimation for a low-grade and a tactical-grade IMU) and writes
//! the figure as SVG and the final estimates as JSON.

use std::path::PathBuf;

use anyhow::Context;

use dynacal::figures::fig1::fig1;
use dynacal::figures::plot::fig1_svg;
use dynacal::output::{write_atomic, write_json_atomic, FileSet};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder (created if missing): fig1-boresight-lever-arm.svg and fig1.json.
    #[arg(long)]
    out: PathBuf,
    /// Length of the simulated drive, s (the smoother keeps ~12 kB per 5 ms epoch).
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// Seed of the simulation.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let bar = super::working("simulating and calibrating the Fig. 1 run");
    let run = fig1(args.seconds, args.seed);
    bar.finish_and_clear();
    let run = run?;
    let svg = fig1_svg(&run)?;
    // fig1.json last: the completion marker of the folder's set (`dynacal::output::FileSet`).
    let mut set = FileSet::create(&args.out, Some("fig1.json"))
        .with_context(|| format!("creating {}", args.out.display()))?;
    let (svg_path, json_path) = (
        args.out.join("fig1-boresight-lever-arm.svg"),
        args.out.join("fig1.json"),
    );
    write_atomic(&set.path("fig1-boresight-lever-arm.svg"), svg.as_bytes())
        .with_context(|| format!("writing {}", svg_path.display()))?;
    write_json_atomic(&set.path("fig1.json"), &run.report)
        .with_context(|| format!("writing {}", json_path.display()))?;
    set.commit().context("moving the outputs into place")?;
    for imu in &run.report.imus {
        let f = &imu.filtered;
        let s = &imu.smoothed;
        println!(
            "{}: converged within {} deg after {} s, within {} m after {} s; final boresight error {:.3?} deg (3 sigma {:.3?}), lever-arm error {:.4?} m (3 sigma {:.4?}); smoothed max |error|/sigma {:.2}",
            imu.name,
            dynacal::figures::fig1::CONVERGED_BORESIGHT_DEG,
            imu.boresight_converged_after_s.map_or("never".into(), |t| format!("{t:.2}")),
            dynacal::figures::fig1::CONVERGED_LEVER_ARM_M,
            imu.lever_arm_converged_after_s.map_or("never".into(), |t| format!("{t:.2}")),
            f.boresight_error_deg,
            f.boresight_sigma_deg.map(|x| 3.0 * x),
            f.lever_arm_error_m,
            f.lever_arm_sigma_m.map(|x| 3.0 * x),
            s.max_error_over_sigma,
        );
    }
    println!("wrote {} and {}", svg_path.display(), json_path.display());
    Ok(())
}
