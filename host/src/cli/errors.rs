//! `dynacal errors --sensor S.csv --reference R.csv --out E.csv [--json SUMMARY.json]
//! [--stream auto|always|never]`: estimates boresight, lever arm, biases and time offset of
//! a sensor against a reference, and writes the sensor's error signals with the dynamics
//! beside them.
//!
//! Long recordings are streamed (`--stream auto`, the default: either file larger than
//! 256 MiB on disk, [`dynacal::input::stream::STREAM_THRESHOLD_BYTES`]): both are read once
//! into spill files in `TMPDIR` (8 bytes a value) and the calibration passes over them a
//! block of epochs at a time, writing the error signals as it forms them, so memory does
//! not grow with the recordings ([`dynacal::calibration::write_error_signals_streamed`]; the
//! same estimates and signals as loaded whole, to rounding). `--stream always` streams any
//! size, `--stream never` loads both whole.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::calibration::{
    build_error_signals, write_error_signals_streamed, CalibrationSummary, ErrorOptions,
};
use dynacal::input::stream::{StreamMode, STREAM_THRESHOLD_BYTES};
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
    /// Stream the recordings from spill files instead of loading them whole: `auto` when
    /// either is larger than 256 MiB on disk.
    #[arg(long, value_enum, default_value_t = StreamMode::Auto)]
    pub stream: StreamMode,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let opts = ErrorOptions {
        estimate_lever_arm: !args.no_lever_arm,
        estimate_time_offset: !args.no_time_offset,
        max_time_offset_s: args.max_time_offset,
        ..Default::default()
    };
    let streamed = match args.stream {
        StreamMode::Always => true,
        StreamMode::Never => false,
        StreamMode::Auto => [&args.sensor, &args.reference]
            .iter()
            .any(|p| std::fs::metadata(p).is_ok_and(|m| m.len() > STREAM_THRESHOLD_BYTES)),
    };
    let summary = if streamed {
        calibrate_streamed(&args, &opts)?
    } else {
        calibrate_whole(&args, &opts)?
    };
    if let Some(json) = &args.json {
        dynacal::output::write_json_atomic(json, &summary)
            .with_context(|| format!("writing {}", json.display()))?;
    }
    print_summary(&summary);
    let mut written = vec![args.out.as_path()];
    written.extend(args.json.as_deref());
    super::wrote(&written);
    Ok(())
}

/// Both recordings loaded whole, the error signals written at the end.
fn calibrate_whole(args: &Args, opts: &ErrorOptions) -> anyhow::Result<CalibrationSummary> {
    let sensor = ImuRecording::read(&args.sensor)?;
    let reference = ImuRecording::read(&args.reference)?;
    let bar = super::working(&format!(
        "calibrating {} against {}",
        args.sensor.display(),
        args.reference.display()
    ));
    let built = build_error_signals(&sensor, &reference, opts);
    bar.finish_and_clear();
    let (signals, summary) = built.with_context(|| against(args))?;
    signals.write(&args.out)?;
    Ok(summary)
}

/// Both recordings streamed from spill files, the error signals written as they are formed.
fn calibrate_streamed(args: &Args, opts: &ErrorOptions) -> anyhow::Result<CalibrationSummary> {
    let bar = super::working(&format!(
        "calibrating {} against {} (streamed)",
        args.sensor.display(),
        args.reference.display()
    ));
    let summary = write_error_signals_streamed(&args.sensor, &args.reference, &args.out, opts);
    bar.finish_and_clear();
    summary.with_context(|| against(args))
}

fn against(args: &Args) -> String {
    format!(
        "sensor {} against reference {}",
        args.sensor.display(),
        args.reference.display()
    )
}

fn print_summary(summary: &CalibrationSummary) {
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
}
