//! `dynacal decode LOG --out DIR [--format csv|csv-gz|parquet]`: the board's log as one
//! interchange file per IMU plus a `summary.json` of what was decoded and what was dropped;
//! when the log holds them, `wv.json` (the latest wavelet-variance snapshot of each IMU
//! channel in SI units) and what the board's fusion found: `nav.csv`, `noise.csv` and
//! `faults.json`, and the board's own troubles from its Health frames, `health.json`
//! (`dynacal::board_log`).

use std::path::PathBuf;

use anyhow::Context;
use dynacal::board_log::{fault_entries, health_episodes, nav_csv, noise_csv};
use std::collections::btree_map::Entry;
use std::collections::BTreeMap;

use dynacal::decode::{decode_file_streamed, imu_file_name, sample_si};
use dynacal::interchange::{FileFormat, RowWriter, CHANNEL_COLUMNS};
use dynacal::output::{write_atomic, write_json_atomic, FileSet};

/// The summary, the completion marker of the folder's set (written last).
const SUMMARY: &str = "summary.json";

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Log file written by the board.
    pub log: PathBuf,
    /// Output folder (created if absent): imu<ID>.csv (or the `--format`'s ending) per IMU, summary.json, and wv.json
    /// when the log holds wavelet-variance snapshots.
    #[arg(long)]
    pub out: PathBuf,
    /// The IMU files' form: CSV text, gzip-compressed CSV, or Parquet (binary columns, the
    /// fastest to read: hours of 1 kHz logs).
    #[arg(long, value_enum, default_value_t = FileFormat::Csv)]
    pub format: FileFormat,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // Every file is staged and moved into place only when all are complete, summary.json
    // last as the set's completion marker (`dynacal::output::FileSet`). The IMUs' samples
    // are written as they are decoded, so a log of hours takes no more memory than a minute.
    let mut set = FileSet::create(&args.out, Some(SUMMARY))
        .with_context(|| format!("{}: cannot create output folder", args.out.display()))?;
    let mut writers: BTreeMap<u8, (String, RowWriter)> = BTreeMap::new();
    let log = decode_file_streamed(&args.log, |config, sample| -> anyhow::Result<()> {
        let (_, writer) = match writers.entry(config.imu_id) {
            Entry::Occupied(entry) => entry.into_mut(),
            Entry::Vacant(entry) => {
                let name = imu_file_name(config.imu_id, args.format);
                let rate_hz = f64::from(config.sample_rate_hz);
                let writer = RowWriter::create(
                    &set.path(&name),
                    [&["t_s"][..], &CHANNEL_COLUMNS[..]].concat(),
                    Some(rate_hz),
                )?;
                entry.insert((name, writer))
            }
        };
        writer.push(&sample_si(config, sample))?;
        Ok(())
    })?;
    log.validate(&args.log)?;
    let summary = log.summary(args.format);
    let cannot = |name: &str| format!("{}: cannot write", args.out.join(name).display());
    let mut files = Vec::new();
    for (name, writer) in writers.into_values() {
        writer.finish()?;
        files.push(name);
    }
    let wv = log.wavelet_variance_si();
    if !wv.is_empty() {
        let name = "wv.json".to_string();
        write_json_atomic(&set.path(&name), &wv).with_context(|| cannot(&name))?;
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
            write_atomic(&set.path(name), text.as_bytes()).with_context(|| cannot(name))?;
            files.push(name.to_string());
        }
    }
    if let (Some(header), false) = (&log.header, log.noise.is_empty() && log.faults.is_empty()) {
        let name = "faults.json";
        write_json_atomic(&set.path(name), &fault_entries(header, &log.faults))
            .with_context(|| cannot(name))?;
        files.push(name.to_string());
    }
    if !log.health.is_empty() {
        let name = "health.json";
        write_json_atomic(&set.path(name), &health_episodes(&log.health))
            .with_context(|| cannot(name))?;
        files.push(name.to_string());
    }
    write_json_atomic(&set.path(SUMMARY), &summary).with_context(|| cannot(SUMMARY))?;
    files.push(SUMMARY.to_string());
    set.commit().context("moving the outputs into place")?;

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
