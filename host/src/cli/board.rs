//! `dynacal board INPUT.replay --out LOG [--model board-model.bin] [--faults PLAN]`: the
//! board's firmware
//! run in QEMU's emulated STM32F405 on a replay input (a simulation's `board.replay`, or
//! one made from measured data), writing the log the board would write, with the fusion
//! running the given model (the built-in one without `--model`). Prints what the board did
//! and its cost: instructions under `-icount`, per second of data and as a share of a
//! 168 MHz Cortex-M4F. With `--faults` the board meets the faults the plan lists
//! (`dynacal_core::inject`: IMUs silent, stuck, saturated or late, SPI errors, PPS or GNSS
//! lost or corrupted, the log sink full, a hang the watchdog catches), and the command
//! prints what the board flagged and when.

use std::path::PathBuf;

use anyhow::{bail, Context};
use dynacal::board_log::{fault_entries, health_episodes};
use dynacal::decode::{decode_file, DecodedLog};
use dynacal::replay::{
    build_replay_firmware, qemu_available, replay_firmware_elf, run_replay_with_faults_in_qemu,
    workspace_root, BOARD_CORE_HZ as CORE_HZ, FIRMWARE_TARGET_DIR,
};
use dynacal_core::inject::FaultPlan;
use dynacal_core::replay::{decode_header, MAX_HEADER_LEN};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Replay input (`dynacal simulate` writes board.replay beside its CSVs).
    pub input: PathBuf,
    /// The log to write (written whole or not at all).
    #[arg(long)]
    pub out: PathBuf,
    /// Board model for the fusion (`dynacal refit` writes board-model.bin); a blob the
    /// board would refuse (and fall back to its built-in model) is an error here, named with
    /// its reason, before anything runs.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Board faults to inject, one a line (`dynacal_core::inject`: `imu-silent unit=1
    /// from=40 to=70`, `pps-lost from=240 to=420`, `hang at=400`, ...); times are seconds
    /// from the replay's first event, units 0-based in the replay's order.
    #[arg(long)]
    pub faults: Option<PathBuf>,
    /// Build the replay firmware with cargo into this target folder instead of running the
    /// image built into this binary.
    #[arg(long)]
    pub target_dir: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    for (what, path) in [
        ("replay input", Some(&args.input)),
        ("board model", args.model.as_ref()),
        ("fault plan", args.faults.as_ref()),
    ] {
        if let Some(path) = path {
            if !path.is_file() {
                bail!("{}: {what} not found", path.display());
            }
        }
    }
    if let Some(path) = &args.model {
        let blob =
            std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
        if let Err(reason) = dynacal_core::board_model::BoardModel::decode(&blob) {
            bail!(
                "{}: the board refuses this model ({reason}; the board itself would run its \
                 built-in model instead); `dynacal refit` or `dynacal export --to board` \
                 write one",
                path.display()
            );
        }
    }
    if let Some(path) = &args.faults {
        check_plan(path, &args.input)?;
    }
    if !qemu_available() {
        bail!("qemu-system-arm not found: run scripts/setup to install it (and the thumbv7em-none-eabihf target)");
    }
    if let Some(parent) = args.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("{}: cannot create folder", parent.display()))?;
    }
    let scratch = tempfile::tempdir().context("cannot create a temporary folder")?;
    let elf = match &args.target_dir {
        Some(target_dir) => build_replay_firmware(target_dir)?,
        None => replay_firmware_elf(scratch.path(), &workspace_root().join(FIRMWARE_TARGET_DIR))?,
    };
    let bar = super::working(&format!(
        "running {} on the board in QEMU",
        args.input.display()
    ));
    let run = run_replay_with_faults_in_qemu(
        &elf,
        &args.input,
        &args.out,
        args.model.as_deref(),
        args.faults.as_deref(),
    );
    bar.finish_and_clear();
    let run = run?;
    for line in run.stderr.lines().filter(|l| l.contains("board model")) {
        println!("  {line}");
    }
    let report = run.report;
    let log = decode_file(&args.out)?;
    let span_s = log.span_s();
    println!(
        "{}: {} sample sets, {} PPS edges, {} GNSS fixes ({} receiver frames refused); fusion: {} states, {} noise reports, {} fault events; \
         {} frames ({} bytes, {} dropped) to {}",
        args.input.display(),
        report.imu_sample_sets,
        report.pps_edges,
        report.gnss_fixes,
        report.gnss_frames_refused,
        report.filter_states,
        report.noise_reports,
        report.fault_reports,
        report.frames_written,
        report.bytes_written,
        report.frames_dropped,
        args.out.display()
    );
    if span_s > 0.0 {
        let per_second = report.record_instructions as f64 / span_s;
        println!(
            "  cost      {:.0} instructions per second of data, the run's mean of the board's own \
             work (recording, accumulators, fusion, log framing; QEMU -icount, SysTick): \
             {:.1}% of a 168 MHz Cortex-M4F",
            per_second,
            100.0 * per_second / CORE_HZ
        );
    }
    println!(
        "  memory    {} bytes of stack at the deepest (painted), {} of statics (the replay \
         board's 40 KiB of semihosting buffers among them)",
        report.stack_peak_bytes, report.static_bytes
    );
    let rate_hz = log
        .header
        .as_ref()
        .and_then(|h| h.imus.first())
        .map_or(0.0, |i| f64::from(i.sample_rate_hz));
    if let Some(steady) = report.steady_instructions_per_second(span_s, rate_hz) {
        println!(
            "  navigating {:.0} instructions per second with the filter running ({} of {} sample \
             sets): {:.1}% of a 168 MHz Cortex-M4F",
            steady,
            report.navigating_sample_sets,
            report.imu_sample_sets / log.imus.len().max(1) as u64,
            100.0 * steady / CORE_HZ
        );
    }
    if args.faults.is_some() {
        print_flagged(&log);
    }
    super::wrote(&[args.out.as_path()]);
    Ok(())
}

/// Reads the fault plan as the board will, against the replay's IMUs, so a bad plan is
/// named with its line before anything runs.
fn check_plan(path: &std::path::Path, input: &std::path::Path) -> anyhow::Result<()> {
    let text = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let plan = FaultPlan::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let mut head = Vec::with_capacity(MAX_HEADER_LEN);
    std::io::Read::read_to_end(
        &mut std::io::Read::take(
            std::fs::File::open(input)
                .with_context(|| format!("{}: cannot open", input.display()))?,
            MAX_HEADER_LEN as u64,
        ),
        &mut head,
    )
    .with_context(|| format!("{}: cannot read", input.display()))?;
    let (header, _) = decode_header(&head)
        .map_err(|e| anyhow::anyhow!("{}: not a replay input: {e}", input.display()))?;
    plan.check_units(header.imus.len())
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// What the board flagged: its Health episodes and the fusion's fault events.
fn print_flagged(log: &DecodedLog) {
    // Seconds from the first sample, as the plan counts them (from the replay's first event).
    let start_s = log.first_sample_s().unwrap_or(0.0);
    for e in health_episodes(&log.health) {
        let to = e.to_t_s.map_or_else(
            || "the end".to_string(),
            |t| format!("{:.1} s", t - start_s),
        );
        println!(
            "  flagged   {} from {:.1} s to {to} ({} reports; {} frames dropped, {} samples lost)",
            e.condition,
            e.from_t_s - start_s,
            e.reports,
            e.frames_dropped,
            e.samples_overrun
        );
    }
    if let Some(header) = &log.header {
        for f in fault_entries(header, &log.faults) {
            let unit = f
                .imu_id
                .map_or_else(|| "?".to_string(), |id| id.to_string());
            println!(
                "  fusion    {} {} of IMU {unit} at {:.2} s (detected {:.2} s)",
                f.sensor,
                f.kind,
                f.t_s - start_s,
                f.detected_t_s - start_s
            );
        }
    }
}
