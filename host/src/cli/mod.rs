//! Subcommand definitions and dispatch for the `dynacal` binary.

use clap::{Parser, Subcommand};

/// dynacal: observe, model and simulate MEMS inertial sensor errors under vehicle dynamics.
#[derive(Debug, Parser)]
#[command(name = "dynacal", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Show the header and size of an interchange file.
    Info(info::Args),
    /// Build a sensor's error signals against a reference IMU or navigation solution.
    Errors(errors::Args),
    /// Regress error signals on the dynamics (paper Tables II/III).
    Regress(regress::Args),
    /// Convert a measured dataset (file or folder) into interchange files, one per sensor.
    Import(import::Args),
    /// GMWM fit of a stochastic error model per channel, with intervals and J-test.
    Fit(fit::Args),
    /// Fit two recordings with one model and compare parameters (the paper's Table I).
    Compare(compare::Args),
    /// Decode a board log into per-IMU interchange CSVs and summary.json.
    Decode(decode::Args),
    /// What the simulation gets wrong: named causes, extended model, measured gain.
    Diagnose(diagnose::Args),
    /// Three or more IMUs sampled together: each unit's own error and live noise level.
    Redundancy(redundancy::Args),
    /// Simulate a car or static run: reference IMU, MEMS IMUs, GNSS and PPS.
    Simulate(simulate::Args),
    /// The mission end to end: a hidden effect found, three IMUs, the board, one report.html.
    Demo(demo::Args),
    /// Run the board's firmware in QEMU on a replay input: its log, and what it cost.
    Board(board::Args),
    /// Refit a board log's units: error models and alignment, as model.json and board-model.bin.
    Refit(refit::Args),
    /// A fitted model as Kalibr imu.yaml, PX4 EKF2 or ArduPilot EKF3 parameters.
    Export(export::Args),
    /// One IMU's noise (bag, log or file): still stretches, GMWM by WIC, Kalibr imu.yaml, motion.
    Noise(noise::Args),
    /// Haar wavelet variance and Allan variance of each channel, with 95% intervals.
    Wv(wv::Args),
    /// Paper Fig. 1 on simulated data: boresight and lever-arm estimates of two IMUs (SVG, JSON).
    Fig1(fig1::Args),
    /// The board's fusion filter on a simulated drive with GNSS outages, in f64, f32 or fixed point.
    Navsim(navsim::Args),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Info(args) => info::run(args),
        Command::Import(args) => import::run(args),
        Command::Decode(args) => decode::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Board(args) => board::run(args),
        Command::Refit(args) => refit::run(args),
        Command::Errors(args) => errors::run(args),
        Command::Diagnose(args) => diagnose::run(args),
        Command::Regress(args) => regress::run(args),
        Command::Redundancy(args) => redundancy::run(args),
        Command::Fit(args) => fit::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Export(args) => export::run(args),
        Command::Noise(args) => noise::run(args),
        Command::Wv(args) => wv::run(args),
        Command::Fig1(args) => fig1::run(args),
        Command::Navsim(args) => navsim::run(args),
    }
}

/// Every bar a command draws, on stderr (hidden when stderr is not a terminal): one
/// MultiProgress, so an input file's read bar and a stage's spinner or bar do not overwrite
/// each other. Add a bar with `bars().add(..)`.
pub(crate) fn bars() -> &'static indicatif::MultiProgress {
    static BARS: std::sync::OnceLock<indicatif::MultiProgress> = std::sync::OnceLock::new();
    BARS.get_or_init(indicatif::MultiProgress::new)
}

/// Smallest input file that gets a read bar: smaller ones are read in a blink.
const READ_BAR_MIN_BYTES: u64 = 8 << 20;

/// Read bars of the input files being read ([`show_progress`]).
#[derive(Default)]
struct ReadBars {
    open: std::sync::Mutex<std::collections::HashMap<u64, indicatif::ProgressBar>>,
    next: std::sync::atomic::AtomicU64,
}

impl dynacal::progress::ReadProgress for ReadBars {
    fn started(&self, path: &std::path::Path, size_bytes: u64) -> u64 {
        let handle = self.next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if size_bytes >= READ_BAR_MIN_BYTES {
            let bar = bars().add(indicatif::ProgressBar::new(size_bytes));
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{spinner} reading {msg} [{bar:30}] {bytes}/{total_bytes}, {bytes_per_sec}, eta {eta}",
            ) {
                bar.set_style(style.progress_chars("=> "));
            }
            let name = path.file_name().unwrap_or(path.as_os_str());
            bar.set_message(name.to_string_lossy().into_owned());
            if let Ok(mut open) = self.open.lock() {
                open.insert(handle, bar);
            }
        }
        handle
    }
    fn advanced(&self, handle: u64, bytes: u64) {
        if let Some(bar) = self.open.lock().ok().and_then(|o| o.get(&handle).cloned()) {
            bar.inc(bytes);
        }
    }
    fn finished(&self, handle: u64) {
        if let Some(bar) = self.open.lock().ok().and_then(|mut o| o.remove(&handle)) {
            bar.finish_and_clear();
        }
    }
}

/// Draws a read bar on stderr for every large input file the command reads, and the stages
/// of long work on the spinner of [`working`].
pub(crate) fn show_progress() {
    dynacal::progress::observe_reading(Box::new(ReadBars::default()));
    dynacal::progress::observe_work(Box::new(StageSpinner));
}

/// The spinner of the work running now and its message before any stage.
static CURRENT_WORK: std::sync::Mutex<Option<(indicatif::ProgressBar, String)>> =
    std::sync::Mutex::new(None);

/// Tells the stages of long work on the current spinner ("diagnosing x: channel gx: ...").
struct StageSpinner;

impl dynacal::progress::WorkProgress for StageSpinner {
    fn stage(&self, what: &str) {
        if let Ok(current) = CURRENT_WORK.lock() {
            if let Some((bar, message)) = current.as_ref() {
                bar.set_message(format!("{message}: {what}"));
            }
        }
    }
    /// The spinner becomes a bar of the units done, with the time the rest will take.
    fn counted(&self, done: u64, total: u64) {
        if let Ok(current) = CURRENT_WORK.lock() {
            if let Some((bar, _)) = current.as_ref() {
                if bar.length() != Some(total) {
                    if let Ok(style) = indicatif::ProgressStyle::with_template(
                        "{spinner} {msg} [{bar:30}] {pos}/{len} ({elapsed}, eta {eta})",
                    ) {
                        bar.set_style(style.progress_chars("=> "));
                    }
                    bar.set_length(total);
                }
                bar.set_position(done);
            }
        }
    }
}

/// A spinner with `message` and the elapsed time on stderr while long work runs (hidden when
/// stderr is not a terminal); finish it with `finish_and_clear`.
pub(crate) fn working(message: &str) -> indicatif::ProgressBar {
    let bar = bars().add(indicatif::ProgressBar::new_spinner());
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        bar.set_style(style);
    }
    bar.set_message(message.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    if let Ok(mut current) = CURRENT_WORK.lock() {
        *current = Some((bar.clone(), message.to_string()));
    }
    bar
}

/// The last line of a command: what it wrote where.
pub(crate) fn wrote(paths: &[&std::path::Path]) {
    let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    match names.split_last() {
        Some((last, [])) => println!("wrote {last}"),
        Some((last, rest)) => println!("wrote {} and {last}", rest.join(", ")),
        None => {}
    }
}

/// Writes `json` (the command's JSON output) and, when `report_dir` is given, the HTML
/// report `page` drew into it, then says what was written where. The page is drawn by the
/// caller before anything is written, so a failure to draw leaves no output behind.
pub(crate) fn write_json_and_report<T: serde::Serialize>(
    json: &std::path::Path,
    value: &T,
    report_dir: Option<&std::path::Path>,
    page: Option<&dynacal::report::HtmlReport>,
) -> anyhow::Result<()> {
    use anyhow::Context as _;
    dynacal::output::write_json_atomic(json, value)
        .with_context(|| format!("writing {}", json.display()))?;
    let mut written = vec![json.to_path_buf()];
    if let (Some(dir), Some(page)) = (report_dir, page) {
        dynacal::report::write_html(dir, page)
            .with_context(|| format!("writing the report into {}", dir.display()))?;
        written.push(dir.join(dynacal::report::REPORT_HTML));
    }
    let paths: Vec<&std::path::Path> = written.iter().map(|p| p.as_path()).collect();
    wrote(&paths);
    Ok(())
}

mod board;
mod compare;
mod decode;
mod demo;
mod diagnose;
mod errors;
mod export;
mod fig1;
mod fit;
mod import;
mod info;
mod navsim;
mod noise;
mod redundancy;
mod refit;
mod regress;
mod simulate;
mod wv;

/// Allocations of 1 MiB or more (a long drive's series: 8 bytes an epoch, 29 MB an hour at
/// 1 kHz; a stretch's series of a long run) are mapped on their own and handed back to the
/// system when freed. glibc's default threshold rises with every such block freed (up to 32
/// MiB), after which a diagnosis's many short-lived series are carved from the heap and
/// their space stays resident: the process held a third more than it used (BENCHMARKS.md,
/// "Diagnosis in bounded memory").
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub(crate) fn map_long_series_alone() {
    // SAFETY: mallopt only sets a parameter of glibc's allocator (thread-safe); it touches
    // no memory of the program's.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub(crate) fn map_long_series_alone() {}
