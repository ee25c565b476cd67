//! `dynacal redundancy`: three or more IMUs sampled together, each unit's own error (wavelet
//! variance per scale, white-noise level) and live noise level, without a reference.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::input::load_recording;
use dynacal::redundancy::{redundancy, RedundancyOptions};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The units' recordings (interchange CSV or CSV.gz, gyro and accelerometer triads),
    /// sampled together on one time base: three or more, up to eight. The first is the
    /// frame the others are aligned to.
    #[arg(required = true, num_args = 3..)]
    pub units: Vec<PathBuf>,
    /// Output JSON: per unit its alignment, own white-noise variance and own wavelet
    /// variance per channel; per unit its live noise level over time.
    #[arg(long)]
    pub json: PathBuf,
    /// Time constant of the live noise level, s.
    #[arg(long, default_value_t = 2.0)]
    pub live_time_constant_s: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.live_time_constant_s > 0.0 && args.live_time_constant_s.is_finite(),
        "--live-time-constant-s must be a positive number of seconds, got {}",
        args.live_time_constant_s
    );
    let units = args
        .units
        .iter()
        .map(|p| Ok((p.display().to_string(), load_recording(p, true)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let opts = RedundancyOptions {
        live_time_constant_s: args.live_time_constant_s,
        ..Default::default()
    };
    let report = redundancy(&units, &opts).context("the redundancy analysis")?;
    for (unit, level) in report.imus.iter().zip(&report.noise_level) {
        let s = |c: &str| unit.white_noise_sigma2[c].sqrt();
        eprintln!(
            "{}: own white noise gyro {:.3e} {:.3e} {:.3e} rad/s, accel {:.3e} {:.3e} {:.3e} m/s^2 per sample; live levels at {} times",
            unit.name,
            s("gx"),
            s("gy"),
            s("gz"),
            s("ax"),
            s("ay"),
            s("az"),
            level.t_s.len()
        );
    }
    for note in &report.notes {
        eprintln!("note: {note}");
    }
    dynacal::output::write_json_atomic(&args.json, &report)
        .with_context(|| format!("writing {}", args.json.display()))
}
