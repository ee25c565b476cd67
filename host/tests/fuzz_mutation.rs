//! The seeded mutation harness: the real files in `$DYNACAL_DATA` (the ArduPilot and PX4
//! logs whole, the first lines of each CSV dataset) and a board log written by
//! `dynacal simulate --replay`, damaged thousands of times (bit flips, inserted text or
//! bytes, deleted and duplicated chunks, truncation, a number field replaced by an awkward
//! one) with ChaCha8 seeds, each case through its importer (`import::detect`,
//! `import::import_file`) or what `dynacal decode` does with a log. It counts per target the
//! cases, the clean answers (imported, refused naming the file), the panics (caught) and the
//! unclean answers, prints them as the table in `BENCHMARKS.md` ("Fuzzing"), and fails on
//! any panic or unclean answer, naming the seed that reproduces it.
//!
//! A measurement tool, ignored in the default run:
//! `cargo test --release -p dynacal --test fuzz_mutation -- --ignored --nocapture`
//! (`FUZZ_CASES=N` sets the cases per target; `FUZZ_TARGET=name` runs one target).

mod fuzz_common;

use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use dynacal::import::Dataset;
use fuzz_common::{decode_outcome, detect_outcome, import_outcome, random_mutation, Outcome};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One file to damage: its name in the case's folder, its bytes, and who reads it.
struct Target {
    name: String,
    bytes: Vec<u8>,
    reader: Reader,
    cases: usize,
}

#[derive(Clone, Copy)]
enum Reader {
    Import(Dataset),
    BoardLog,
}

/// What the cases of one target gave.
#[derive(Default)]
struct Tally {
    cases: usize,
    imported: usize,
    refused: usize,
    panics: Vec<(u64, String)>,
    unclean: Vec<(u64, String)>,
    seconds: f64,
}

/// The message of the last panic, with its location (the hook runs before unwinding).
static LAST_PANIC: Mutex<Option<String>> = Mutex::new(None);

fn cases_per_target(default: usize) -> usize {
    std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The targets found in the data folder; a missing file is skipped with a printed SKIP.
/// Text files are cut to their first lines (0: the whole file, for the binary logs).
fn real_targets(data: &Path) -> Vec<Target> {
    use Dataset::*;
    // (file, lines kept (0: all), dataset, cases): about a minute of release run each.
    let files: [(&str, usize, Dataset, usize); 11] = [
        (
            "ardupilot-3imu-copter/log171.bin",
            0,
            ArduPilotDataFlash,
            5000,
        ),
        ("px4-ulog/sample_log_small.ulg", 0, Px4ULog, 10_000),
        ("adis16405/session1.csv.gz", 2000, Adis16405, 10_000),
        ("mtig/gyro_x_contaminated.csv.gz", 2000, MtigGyroX, 10_000),
        (
            "psins-fog-mems/mems_increments.csv.gz",
            2000,
            PsinsMems,
            5000,
        ),
        // Short, so most damage lands near its structure rather than in its values.
        (
            "psins-fog-mems/mems_increments.csv.gz",
            200,
            PsinsMems,
            10_000,
        ),
        (
            "psins-fog-mems/fog_ins_reference.csv.gz",
            2000,
            PsinsFog,
            5000,
        ),
        (
            "psins-lasergyro/lasergyro.imu.gz",
            2000,
            PsinsLaserGyro,
            10_000,
        ),
        (
            "mpu9250x4-tetra-static/static.csv.gz",
            2000,
            Mpu9250Tetra,
            5000,
        ),
        ("xsens-dot4-quadrotor/dot1.csv.gz", 2000, XsensDot, 5000),
        // dot7's line 3909 is the lost sample (NaN and infinities) the importer drops.
        ("xsens-dot4-quadrotor/dot7.csv.gz", 4000, XsensDot, 5000),
    ];
    let mut targets = Vec::new();
    for (rel, lines, dataset, cases) in files {
        let Some(bytes) = fuzz_common::head_of(&data.join(rel), lines, usize::MAX) else {
            println!("SKIP {rel}: absent from {}", data.display());
            continue;
        };
        let file = Path::new(rel).file_name().unwrap().to_string_lossy();
        let file = file.trim_end_matches(".gz");
        targets.push(Target {
            name: match lines {
                0 => file.to_string(),
                n => format!("{file} ({n} lines)"),
            },
            bytes,
            reader: Reader::Import(dataset),
            cases: cases_per_target(cases),
        });
    }
    targets
}

/// A board log from `dynacal simulate --replay` (20 s of the car scenario with the example
/// model's three MEMS IMUs).
fn board_log_target(dir: &Path) -> Target {
    let out = dir.join("sim");
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/board-three-mems.json");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args([
            "simulate",
            "--scenario",
            "car",
            "--seconds",
            "20",
            "--seed",
            "1",
        ])
        .arg("--model")
        .arg(&model)
        .arg("--out")
        .arg(&out)
        .arg("--replay")
        .status()
        .expect("run dynacal simulate");
    assert!(status.success(), "dynacal simulate --replay failed");
    let bytes = std::fs::read(out.join("board.log")).expect("simulate wrote board.log");
    Target {
        name: "board.log (simulate --replay, 20 s, 3 IMUs)".into(),
        bytes,
        reader: Reader::BoardLog,
        cases: cases_per_target(5000),
    }
}

/// The file name a case is written under (the importers read the bytes, not the name, but
/// the outputs are named from it).
fn case_file_name(target: &Target) -> String {
    target
        .name
        .split_whitespace()
        .next()
        .unwrap_or("case")
        .to_string()
}

/// Reads one damaged file as its target's reader does.
fn outcome(reader: Reader, path: &Path) -> Outcome {
    match reader {
        Reader::Import(dataset) => {
            if let Err(what) = detect_outcome(path) {
                return Outcome::Unclean(what);
            }
            import_outcome(path, dataset)
        }
        Reader::BoardLog => decode_outcome(path),
    }
}

/// The seed of case `case` of the target `name`: from the name (FNV-1a), so a target's cases
/// do not change when others are skipped or filtered out.
fn case_seed(name: &str, case: usize) -> u64 {
    let hash = name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    (hash % 1_000_000) * 1_000_000 + case as u64
}

/// The damaged bytes of a case: one to four mutations drawn from its seed.
fn damaged(bytes: &[u8], seed: u64) -> Vec<u8> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = bytes.to_vec();
    for _ in 0..rng.random_range(1..=4) {
        let m = random_mutation(&mut rng, out.len());
        m.apply(&mut out);
    }
    out
}

fn run_target(target: &Target, dir: &Path) -> Tally {
    let path: PathBuf = dir.join(case_file_name(target));
    let started = Instant::now();
    let mut tally = Tally::default();
    for case in 0..target.cases {
        let seed = case_seed(&target.name, case);
        std::fs::write(&path, damaged(&target.bytes, seed)).expect("write the case");
        tally.cases += 1;
        match std::panic::catch_unwind(AssertUnwindSafe(|| outcome(target.reader, &path))) {
            Ok(Outcome::Imported(_)) => tally.imported += 1,
            Ok(Outcome::Refused(_)) => tally.refused += 1,
            Ok(Outcome::Unclean(what)) => tally.unclean.push((seed, what)),
            Err(_) => {
                let what = LAST_PANIC.lock().unwrap().take().unwrap_or_default();
                tally.panics.push((seed, what));
            }
        }
    }
    tally.seconds = started.elapsed().as_secs_f64();
    tally
}

#[test]
#[ignore = "measurement tool: cargo test --release -p dynacal --test fuzz_mutation -- --ignored"]
fn mutation_harness_over_the_real_files() {
    let dir = tempfile::tempdir().unwrap();
    let mut targets = vec![board_log_target(dir.path())];
    if let Some(data) = fuzz_common::data_dir_or_skip("the real files") {
        targets.extend(real_targets(&data));
    }
    if let Ok(only) = std::env::var("FUZZ_TARGET") {
        targets.retain(|t| t.name.contains(&only));
    }
    std::panic::set_hook(Box::new(|info| {
        *LAST_PANIC.lock().unwrap() = Some(info.to_string());
    }));
    println!("| target | bytes | cases | imported / decoded | refused naming the file | panics | unclean | s |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut failures = Vec::new();
    for target in &targets {
        let tally = run_target(target, dir.path());
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.1} |",
            target.name,
            target.bytes.len(),
            tally.cases,
            tally.imported,
            tally.refused,
            tally.panics.len(),
            tally.unclean.len(),
            tally.seconds
        );
        for (kind, list) in [("panic", &tally.panics), ("unclean", &tally.unclean)] {
            for (seed, what) in list.iter().take(3) {
                failures.push(format!("{}: {kind} at seed {seed}: {what}", target.name));
            }
        }
    }
    let _ = std::panic::take_hook();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
