//! `dynacal errors --sensor S.csv --reference R.csv --out E.csv [--json SUMMARY.json]`:
//! estimates boresight, lever arm, biases and time offset of a sensor against a reference,
//! and writes the sensor's error signals with the dynamics beside them.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::calibration::{build_error_signals, ErrorOptions};
use dynacal::interchange::{ImuRecording, CHANNELS};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The sensor under test (interchange CSV or CSV.gz).
    #[arg(long)]
    pub sensor: PathBuf,
    /// The reference: an IMU with attitude columns, or a navigation solution
    /// (attitude, NED velocity, position).
    #[arg(long)]
    pub reference: PathBuf,
    /// Error-signal file to write (CSV, or CSV.gz when it ends in .gz).
    #[arg(long)]
    pub out: PathBuf,
    /// Calibration summary (boresight, lever arm, time offset with 1-sigma) as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Do not estimate the lever arm (fix it to zero).
    #[arg(long)]
    pub no_lever_arm: bool,
    /// Do not estimate a time offset.
    #[arg(long)]
    pub no_time_offset: bool,
    /// Largest time offset searched, seconds.
    #[arg(long, default_value_t = 0.2)]
    pub max_time_offset: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let sensor = ImuRecording::read(&args.sensor)?;
    let reference = ImuRecording::read(&args.reference)?;
    let opts = ErrorOptions {
        estimate_lever_arm: !args.no_lever_arm,
        estimate_time_offset: !args.no_time_offset,
        max_time_offset_s: args.max_time_offset,
        rates_only: false,
    };
    let bar = super::working(&format!(
        "calibrating {} against {}",
        args.sensor.display(),
        args.reference.display()
    ));
    let built = build_error_signals(&sensor, &reference, &opts);
    bar.finish_and_clear();
    let (signals, summary) = built.with_context(|| {
        format!(
            "sensor {} against reference {}",
            args.sensor.display(),
            args.reference.display()
        )
    })?;
    signals.write(&args.out)?;
    if let Some(json) = &args.json {
        dynacal::output::write_json_atomic(json, &summary)
            .with_context(|| format!("writing {}", json.display()))?;
    }
    let b = &summary.boresight_rad;
    println!(
        "{} epochs of {:.4} s against a reference {}",
        summary.epochs, summary.epoch_dt_s, summary.reference_kind
    );
    let deg = 180.0 / std::f64::consts::PI;
    println!(
        "boresight (deg): {:+.4} {:+.4} {:+.4}  (1-sigma {:.4} {:.4} {:.4})",
        b.value[0] * deg,
        b.value[1] * deg,
        b.value[2] * deg,
        b.sigma[0] * deg,
        b.sigma[1] * deg,
        b.sigma[2] * deg
    );
    if let Some(l) = &summary.lever_arm_m {
        println!(
            "lever arm (m):   {:+.4} {:+.4} {:+.4}  (1-sigma {:.4} {:.4} {:.4})",
            l.value[0], l.value[1], l.value[2], l.sigma[0], l.sigma[1], l.sigma[2]
        );
    }
    if let Some(t) = &summary.time_offset_s {
        println!(
            "time offset (s): {:+.5} (1-sigma {:.5}), positive = sensor lags",
            t.value, t.sigma
        );
    }
    for note in &summary.notes {
        println!("note: {note}");
    }
    for (ch, sd) in CHANNELS.iter().zip(summary.error_std) {
        if let Some(sd) = sd {
            print!("{ch} error std {sd:.3e}  ");
        }
    }
    println!();
    let mut written = vec![args.out.as_path()];
    written.extend(args.json.as_deref());
    super::wrote(&written);
    Ok(())
}
