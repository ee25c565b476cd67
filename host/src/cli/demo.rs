//! `dynacal demo`: the mission end to end (`dynacal::mission`): a simulated three-IMU car
//! run beside a navigation-grade reference with one effect hidden, the paper's chain and the
//! diagnosis on it against a baseline fitted at rest, the units' own errors, the board's
//! firmware under QEMU with its built-in and its refitted model, and the real PSINS pair;
//! one `report.html`, and at the end what was hidden and whether it was found.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use dynacal::diagnose::report::write_files;
use dynacal::mission::{run_mission, MissionOptions, STAGES};
use dynacal::replay::{
    build_replay_firmware, qemu_available, replay_firmware_elf, workspace_root, FIRMWARE_TARGET_DIR,
};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder for the report (report.html) and the run's files.
    #[arg(long, default_value = "dynacal-demo")]
    pub report: PathBuf,
    /// Seconds of the simulated drive (and of the static recording).
    #[arg(long, default_value_t = 300.0)]
    pub seconds: f64,
    /// Seed of the hidden effect, the drive and every simulation.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Baseline simulations per channel in the diagnosis.
    #[arg(long, default_value_t = 30)]
    pub replicates: usize,
    /// Bootstrap replicates of the board log's refit.
    #[arg(long, default_value_t = 50)]
    pub bootstrap: usize,
    /// Build the replay firmware with cargo into this target folder instead of running the
    /// image built into this binary.
    #[arg(long)]
    pub target_dir: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.seconds.is_finite() && (60.0..=3600.0).contains(&args.seconds)) {
        bail!("--seconds must lie in [60, 3600], got {}", args.seconds);
    }
    if args.replicates < 5 {
        bail!("--replicates must be at least 5, got {}", args.replicates);
    }
    if !qemu_available() {
        bail!("qemu-system-arm not found: run scripts/setup to install it (and the thumbv7em-none-eabihf target)");
    }
    let started = Instant::now();
    std::fs::create_dir_all(&args.report)
        .with_context(|| format!("{}: cannot create folder", args.report.display()))?;
    // report.html is the folder's completion marker (`dynacal::output`): the run replaces
    // the other files one by one over minutes, so the previous report goes first, and a run
    // stopped midway leaves a folder that says it is incomplete.
    let previous = args.report.join(dynacal::report::REPORT_HTML);
    match std::fs::remove_file(&previous) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("{}: cannot remove", previous.display()));
        }
        _ => {}
    }
    let elf = match &args.target_dir {
        Some(target_dir) => build_replay_firmware(target_dir)?,
        None => replay_firmware_elf(&args.report, &workspace_root().join(FIRMWARE_TARGET_DIR))?,
    };
    let options = MissionOptions {
        seconds: args.seconds,
        seed: args.seed,
        replicates: args.replicates,
        bootstrap: args.bootstrap,
        data_dir: dynacal::data_dir(),
        firmware_elf: elf,
    };
    let bar = super::bars().add(ProgressBar::new(STAGES.len() as u64));
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{bar:30}] {pos}/{len} {msg} ({elapsed})")
            .context("progress template")?
            .progress_chars("=> "),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let outcome = run_mission(&options, &args.report, &|k| {
        bar.set_position(k as u64);
        bar.set_message(STAGES[k]);
    })?;
    bar.finish_and_clear();
    let figures = outcome.report.figure_count();
    write_files(&args.report, &[dynacal::report::html_file(&outcome.report)])
        .with_context(|| format!("writing the report into {}", args.report.display()))?;
    for line in &outcome.report.summary {
        println!("- {line}");
    }
    if let Some(why) = &outcome.psins_skipped {
        println!("note: the real PSINS pair was left out: {why}");
    }
    println!(
        "hidden: {}; found: {}",
        dynacal::mission::hidden_words(&outcome.hidden),
        if outcome.named.is_some() { "yes" } else { "no" }
    );
    println!(
        "wrote {} ({figures} figures) in {:.0} s",
        args.report.join(dynacal::report::REPORT_HTML).display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
