//! `dynacal demo`: the walking skeleton end to end. Builds the replay firmware, runs it in
//! QEMU's emulated STM32F405 on the first minute of ADIS16405 session 1, decodes the log on
//! the host, checks that every sample arrived bit for bit, and prints what it measured.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use dynacal::decode::decode_file;
use dynacal::replay::{
    adis16405_replay, adis16405_session_path, build_replay_firmware, check_log_against_replay,
    qemu_available, run_replay_in_qemu, workspace_root, FIRMWARE_TARGET_DIR,
};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// ADIS16405 session to replay (1 to 6).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=6))]
    pub session: u32,
    /// Seconds of the session to replay, from its start.
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub seconds: u32,
    /// Keep the replay input and the board log in this folder (default: a temporary folder).
    #[arg(long)]
    pub keep: Option<PathBuf>,
    /// Cargo target folder for the firmware build (default: target/firmware).
    #[arg(long)]
    pub target_dir: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let data_dir = dynacal::data_dir();
    let session = adis16405_session_path(&data_dir, args.session);
    if !session.exists() {
        bail!(
            "{}: not found. The demo replays the measured ADIS16405 data: set DYNACAL_DATA to \
             the data folder (default ../shared/data beside the repository); see scripts/setup \
             for the rest of what the demo needs",
            session.display()
        );
    }
    if !qemu_available() {
        bail!("qemu-system-arm not found: run scripts/setup to install it (and the thumbv7em-none-eabihf target)");
    }

    println!(
        "dynacal demo: ADIS16405 session {}, first {} s, through the firmware in QEMU (netduinoplus2, STM32F405)",
        args.session, args.seconds
    );
    let input = adis16405_replay(&session, args.seconds)?;
    let temp = tempfile::tempdir().context("cannot create a temporary folder")?;
    let folder = match &args.keep {
        Some(dir) => {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("{}: cannot create folder", dir.display()))?;
            dir.clone()
        }
        None => temp.path().to_path_buf(),
    };
    let input_path = folder.join(format!(
        "adis16405-session{}-{}s.replay",
        args.session, args.seconds
    ));
    let log_path = folder.join("board.log");
    input.write(&input_path)?;
    let input_bytes = std::fs::metadata(&input_path).map(|m| m.len()).unwrap_or(0);
    println!(
        "  input     {} sample sets, {} PPS edges, {} bytes: {}",
        input.samples().count(),
        input.pps_t_us().count(),
        input_bytes,
        input_path.display()
    );

    let target_dir = args
        .target_dir
        .clone()
        .unwrap_or_else(|| workspace_root().join(FIRMWARE_TARGET_DIR));
    let started = Instant::now();
    let elf = build_replay_firmware(&target_dir)?;
    println!(
        "  firmware  built in {:.1} s: {}",
        started.elapsed().as_secs_f64(),
        elf.display()
    );

    let run = run_replay_in_qemu(&elf, &input_path, &log_path, None)?;
    let report = run.report;
    let log = decode_file(&log_path)?;
    log.validate(&log_path)?;
    let check = check_log_against_replay(&input, &log);
    let kinds: Vec<String> = log
        .frames_by_kind
        .iter()
        .map(|(kind, n)| format!("{n} {kind}"))
        .collect();
    println!(
        "  run       {:.2} s in QEMU (host wall clock), guest exit 0",
        run.wall_time.as_secs_f64()
    );
    println!(
        "  log       {} bytes, {} frames ({}), {} dropped: {}",
        report.bytes_written,
        log.frames_decoded(),
        kinds.join(", "),
        check.frames_dropped,
        log_path.display()
    );
    println!(
        "  check     {}/{} sample sets bit-exact (t_us, counts, counts x scale in f64), {}/{} PPS edges exact",
        check.samples_exact, check.samples_expected, check.pps_exact, check.pps_expected
    );
    let per_sample = |instructions: u64| instructions as f64 / report.imu_sample_sets.max(1) as f64;
    println!(
        "  cost      {:.0} instructions per sample set: {:.0} recording (framing + log sink), {:.0} replay input decoding (QEMU -icount, SysTick)",
        report.total_instructions_per_sample(),
        report.record_instructions_per_sample(),
        per_sample(report.source_instructions)
    );
    if !check.is_exact() {
        bail!(
            "the decoded log differs from the replay input:\n  {}",
            check.mismatches.join("\n  ")
        );
    }
    if args.keep.is_none() {
        println!("  (pass --keep DIR to keep the input and the log)");
    }
    Ok(())
}
