//! Shared helpers for dynacal's cross-crate and end-to-end tests: where the measured data
//! live, and how to skip cleanly when they are absent.

use std::path::PathBuf;

/// The measured-data folder: `$DYNACAL_DATA`, else `../shared/data` beside the repository.
pub fn data_dir() -> PathBuf {
    dynacal::data_dir()
}

/// Whether qemu-system-arm can run the firmware here. When it cannot, says so and answers
/// false, except in CI (`CI` or `DYNACAL_REQUIRE_QEMU` set), where it panics: a test that
/// needs QEMU skips on a developer's machine and fails where QEMU must be.
pub fn qemu_or_skip() -> bool {
    if dynacal::replay::qemu_available() {
        return true;
    }
    let required =
        std::env::var_os("CI").is_some() || std::env::var_os("DYNACAL_REQUIRE_QEMU").is_some();
    assert!(
        !required,
        "qemu-system-arm is missing but CI/DYNACAL_REQUIRE_QEMU requires it: run scripts/setup"
    );
    eprintln!("SKIPPED: qemu-system-arm not found (run scripts/setup to install it)");
    false
}

/// Builds the firmware cost bench `firmware/src/bin/{bin}.rs` for thumbv7em-none-eabihf
/// (release, `board-replay`, into `target/firmware-e2e`), runs it in QEMU's netduinoplus2
/// with `-icount shift=0` (deterministic instruction counts) and returns what it printed on
/// semihosting stderr; panics when the build or the run fails. None, after saying so, when
/// qemu-system-arm is absent, except in CI (`CI` or `DYNACAL_REQUIRE_QEMU` set), where that
/// panics.
pub fn run_cost_bench(bin: &str) -> Option<String> {
    use dynacal::replay::{workspace_root, QEMU_BOARD_ARGS};
    use std::process::Command;

    if !qemu_or_skip() {
        return None;
    }
    let root = workspace_root();
    let target_dir = root.join("target/firmware-e2e");
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let build = Command::new(cargo)
        .current_dir(&root)
        .args([
            "build",
            "-p",
            "dynacal-firmware",
            "--release",
            "--target",
            "thumbv7em-none-eabihf",
            "--features",
            "board-replay",
            "--bin",
            bin,
            "--target-dir",
        ])
        .arg(&target_dir)
        .output()
        .expect("run cargo");
    assert!(
        build.status.success(),
        "building {bin} failed (thumbv7em-none-eabihf installed? run scripts/setup):\n{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let elf = target_dir.join("thumbv7em-none-eabihf/release").join(bin);
    let run = Command::new("timeout")
        .arg("300")
        .arg("qemu-system-arm")
        .args(QEMU_BOARD_ARGS)
        .arg("-semihosting-config")
        .arg(format!("enable=on,target=native,arg={bin}"))
        .arg("-kernel")
        .arg(&elf)
        .output()
        .expect("run qemu-system-arm");
    let stderr = String::from_utf8_lossy(&run.stderr).into_owned();
    assert!(run.status.success(), "{bin} failed under QEMU: {stderr}");
    eprintln!("{stderr}");
    Some(stderr)
}

/// A simulated car drive of `model` (`seconds` long, seeded) and its replay input, written
/// to `dir/drive.replay`: what the QEMU tests feed the replay board.
pub fn simulated_drive(
    model: &dynacal::model::SimModel,
    seconds: f64,
    seed: u64,
    dir: &std::path::Path,
) -> (dynacal::sim::SimOutput, PathBuf) {
    let options = dynacal::sim::SimOptions {
        scenario: dynacal::sim::trajectory::Scenario::Car,
        seconds,
        seed,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    let sim = dynacal::sim::simulate(model, &options, &|_| {}).expect("simulate");
    let board = dynacal::sim::board::board_recording(&sim, model).expect("board recording");
    let input = dir.join("drive.replay");
    std::fs::write(&input, board.replay_bytes().expect("replay bytes")).expect("write input");
    (sim, input)
}
