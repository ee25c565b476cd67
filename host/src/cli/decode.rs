//! `dynacal decode LOG --out DIR`: the board's log as one interchange CSV per IMU plus a
//! `summary.json` of what was decoded and what was dropped; when the log holds them,
//! `wv.json` (the latest wavelet-variance snapshot of each IMU channel in SI units) and what
//! the board's fusion found: `nav.csv`, `noise.csv` and `faults.json` (`dynacal::board_log`).

use std::path::PathBuf;

use anyhow::Context;
use dynacal::board_log::{fault_entries, nav_csv, noise_csv};
use dynacal::decode::{decode_file, imu_file_name};
use dynacal::output::{write_atomic, write_json_atomic};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Log file written by the board.
    pub log: PathBuf,
    /// Output folder (created if absent): imu<ID>.csv per IMU, summary.json, and wv.json
    /// when the log holds wavelet-variance snapshots.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let log = decode_file(&args.log)?;
    log.validate(&args.log)?;
    let summary = log.summary();

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create output folder", args.out.display()))?;
    // Everything is written into a staging folder first and moved into place only when all
    // files are complete, so a failure leaves no partial set of outputs.
    let staging = tempfile::Builder::new()
        .prefix(".dynacal-decode-")
        .tempdir_in(&args.out)
        .with_context(|| format!("{}: cannot create staging folder", args.out.display()))?;
    let mut files = Vec::new();
    for imu in log.imus.iter().filter(|imu| !imu.is_empty()) {
        let name = imu_file_name(imu.config.imu_id);
        imu.to_recording().write(&staging.path().join(&name))?;
        files.push(name);
    }
    let wv = log.wavelet_variance_si();
    if !wv.is_empty() {
        let name = "wv.json".to_string();
        write_json_atomic(&staging.path().join(&name), &wv)
            .with_context(|| format!("{}: cannot write", args.out.join(&name).display()))?;
        files.push(name);
    }
    let texts = [
        ("nav.csv", nav_csv(&log.filter)),
        (
            "noise.csv",
            log.header.as_ref().and_then(|h| noise_csv(h, &log.noise)),
        ),
    ];
    for (name, text) in texts {
        if let Some(text) = text {
            write_atomic(&staging.path().join(name), text.as_bytes())
                .with_context(|| format!("{}: cannot write", args.out.join(name).display()))?;
            files.push(name.to_string());
        }
    }
    if let (Some(header), false) = (&log.header, log.noise.is_empty() && log.faults.is_empty()) {
        let name = "faults.json";
        write_json_atomic(
            &staging.path().join(name),
            &fault_entries(header, &log.faults),
        )
        .with_context(|| format!("{}: cannot write", args.out.join(name).display()))?;
        files.push(name.to_string());
    }
    let name = "summary.json".to_string();
    write_json_atomic(&staging.path().join(&name), &summary)
        .with_context(|| format!("{}: cannot write", args.out.join(&name).display()))?;
    files.push(name);
    for name in &files {
        let target = args.out.join(name);
        std::fs::rename(staging.path().join(name), &target)
            .with_context(|| format!("{}: cannot move into place", target.display()))?;
    }

    println!(
        "{}: {} frames decoded ({}), {} frames dropped, {} of {} bytes dropped; wrote {} to {}",
        args.log.display(),
        summary.frames_decoded_total,
        summary
            .frames_decoded
            .iter()
            .map(|(kind, n)| format!("{kind} {n}"))
            .collect::<Vec<_>>()
            .join(", "),
        summary.frames_dropped,
        summary.bytes_dropped,
        summary.bytes_total,
        files.join(", "),
        args.out.display()
    );
    Ok(())
}
