//! `dynacal redundancy`: three or more IMUs sampled together, each unit's own error (wavelet
//! variance per scale, white-noise level) and live noise level, without a reference.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::input::load_recording;
use dynacal::input::stream::StreamMode;
use dynacal::redundancy::{redundancy, redundancy_of_files, RedundancyOptions, RedundancyReport};

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
    /// Write the fused virtual IMU here (interchange CSV, `.gz` to compress): the weighted
    /// mean of the healthy units in the first unit's frame and at its place.
    #[arg(long)]
    pub fused: Option<PathBuf>,
    /// Per-axis range of every unit's gyros, rad/s, for the saturation test (default: each
    /// unit's clipping level as its data show it, if they show one).
    #[arg(long)]
    pub gyro_range_rad_s: Option<f64>,
    /// Per-axis range of every unit's accelerometers, m/s^2 (default as for the gyros).
    #[arg(long)]
    pub accel_range_m_s2: Option<f64>,
    /// Write plots of each unit's own wavelet variance, the live noise levels and the
    /// faults over time, with report.md, into this folder (created; written whole or not
    /// at all).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Analyse only the samples from this time on (the files' time base), s: a phase of
    /// the run (at rest, in flight) without the rest.
    #[arg(long)]
    pub from_s: Option<f64>,
    /// Analyse only the samples before this time, s.
    #[arg(long)]
    pub to_s: Option<f64>,
    /// Read the units stretch by stretch from spill files instead of loading them whole
    /// (memory that does not grow with the run): `auto` when the files take more than 64
    /// MiB on disk together (held, about 5 bytes of memory a byte of CSV).
    #[arg(long, value_enum, default_value_t = StreamMode::Auto)]
    pub stream: StreamMode,
    /// Shared times a stretch holds when streamed (tests cut a short run into several).
    #[arg(long, hide = true, default_value_t = dynacal::redundancy::STRETCH_EPOCHS)]
    pub stretch_epochs: usize,
}

/// Size of the units' files together above which `--stream auto` streams them: held, the
/// analysis takes about 5 bytes a byte of their CSV (BENCHMARKS.md), stretch by stretch
/// about 200 MiB whatever their length.
const STREAM_UNITS_BYTES: u64 = 64 << 20;

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.live_time_constant_s > 0.0 && args.live_time_constant_s.is_finite(),
        "--live-time-constant-s must be a positive number of seconds, got {}",
        args.live_time_constant_s
    );
    let (from, to) = (
        args.from_s.unwrap_or(f64::NEG_INFINITY),
        args.to_s.unwrap_or(f64::INFINITY),
    );
    anyhow::ensure!(
        from < to && !from.is_nan() && !to.is_nan(),
        "--from-s {from} must come before --to-s {to}"
    );
    for (name, range) in [
        ("--gyro-range-rad-s", args.gyro_range_rad_s),
        ("--accel-range-m-s2", args.accel_range_m_s2),
    ] {
        if let Some(r) = range {
            anyhow::ensure!(
                r > 0.0 && r.is_finite(),
                "{name} must be a positive number, got {r}"
            );
        }
    }
    let opts = RedundancyOptions {
        live_time_constant_s: args.live_time_constant_s,
        ranges: [args.gyro_range_rad_s, args.accel_range_m_s2],
        ..Default::default()
    };
    let streamed = match args.stream {
        StreamMode::Always => true,
        StreamMode::Never => false,
        StreamMode::Auto => {
            let bytes: u64 = args
                .units
                .iter()
                .filter_map(|p| std::fs::metadata(p).ok())
                .map(|m| m.len())
                .sum();
            bytes > STREAM_UNITS_BYTES
        }
    };
    let (report, fused_written) = if streamed {
        analyse_streamed(&args, (from, to), &opts)?
    } else {
        analyse_whole(&args, (from, to), &opts)?
    };
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
    for f in &report.faults {
        let unit = f.imu.map_or("an unplaced unit".to_string(), |k| {
            report.imus[k].name.clone()
        });
        eprintln!(
            "fault: {unit} {} {} at {:.3} s (readmitted: {})",
            f.channel,
            f.kind,
            f.t_detected_s,
            f.t_readmitted_s
                .map_or("never".to_string(), |t| format!("{t:.3} s"))
        );
    }
    for note in &report.notes {
        eprintln!("note: {note}");
    }
    if let Some(path) = &args.fused {
        anyhow::ensure!(
            fused_written || report.fused.is_some(),
            "no fused output for {}: the motion does not determine the units' rotations, so \
             they have no common frame",
            path.display()
        );
        if let Some(fused) = &report.fused {
            fused
                .write(path)
                .with_context(|| format!("writing {}", path.display()))?;
        }
    }
    if let Some(dir) = &args.report {
        dynacal::redundancy::report::write_report(dir, &report)
            .with_context(|| format!("writing the report into {}", dir.display()))?;
    }
    dynacal::output::write_json_atomic(&args.json, &report)
        .with_context(|| format!("writing {}", args.json.display()))?;
    let html = args
        .report
        .as_ref()
        .map(|d| d.join(dynacal::report::REPORT_HTML));
    let mut written = vec![args.json.as_path()];
    written.extend(args.fused.as_deref());
    written.extend(html.as_deref());
    super::wrote(&written);
    Ok(())
}

/// The units loaded whole; the fused output, if any, is in the report.
fn analyse_whole(
    args: &Args,
    (from, to): (f64, f64),
    opts: &RedundancyOptions,
) -> anyhow::Result<(RedundancyReport, bool)> {
    let units = args
        .units
        .iter()
        .map(|p| {
            let recording = load_recording(p, false)?.between(from, to);
            anyhow::ensure!(
                !recording.is_empty(),
                "{}: no samples between {from} s and {to} s",
                p.display()
            );
            Ok((p.display().to_string(), recording))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let bar = super::working(&format!("analysing {} units", units.len()));
    let report = redundancy(&units, opts).context("the redundancy analysis");
    bar.finish_and_clear();
    Ok((report?, false))
}

/// The units read stretch by stretch; the fused output written as it is formed.
fn analyse_streamed(
    args: &Args,
    window_s: (f64, f64),
    opts: &RedundancyOptions,
) -> anyhow::Result<(RedundancyReport, bool)> {
    let bar = super::working(&format!(
        "analysing {} units stretch by stretch",
        args.units.len()
    ));
    let outcome = redundancy_of_files(
        &args.units,
        window_s,
        opts,
        args.fused.as_deref(),
        args.stretch_epochs.max(1024),
    )
    .context("the redundancy analysis");
    bar.finish_and_clear();
    let outcome = outcome?;
    Ok((outcome.report, outcome.fused_written))
}
