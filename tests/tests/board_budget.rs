//! The board's budget (issue 19, "Must show"): the real board's image (STM32F405, the
//! `firmware` profile) fits 128 KiB of flash; three IMUs at 1 kHz with GNSS at 10 Hz, PPS,
//! the accumulators on every channel, the redundancy monitors and the filter running cost
//! under 15% of its 168 MHz Cortex-M4F; and its statics with the deepest stack stay under
//! 64 KiB of RAM.
//!
//! Flash and statics are read from the real board's ELF (its loadable segments: what is
//! flashed, and what is RAM). The cost and the stack come from the replay board under QEMU
//! (`-icount`: instructions are deterministic, so they are asserted) running the same run
//! loop on a simulated drive; its stack is the real board's bound, its own main frame being
//! the larger of the two (BENCHMARKS.md, "The board's fusion").
//!
//! Skips when qemu-system-arm is absent, except in CI, where that fails.

use dynacal::model::SimModel;
use dynacal::replay::{
    build_firmware, run_replay_in_qemu, workspace_root, BOARD_CORE_HZ, FIRMWARE_TARGET_DIR,
};
use dynacal_tests::flash_and_statics;

const FLASH_BUDGET_BYTES: u64 = 128 * 1024;
const RAM_BUDGET_BYTES: u64 = 64 * 1024;
const CORE_SHARE_BUDGET: f64 = 0.15;

#[test]
fn the_real_board_fits_its_flash_and_ram_and_the_fusion_its_core() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let target_dir = workspace_root().join(FIRMWARE_TARGET_DIR);

    // GIVEN the real board's image
    let real = build_firmware(&target_dir, "board-stm32f405").unwrap();
    let (flash, statics) = flash_and_statics(&real);
    println!("real board: {flash} bytes of flash, {statics} bytes of statics");
    // THEN it fits the flash
    assert!(
        flash > 50_000 && flash < FLASH_BUDGET_BYTES,
        "{flash} bytes of flash"
    );

    // GIVEN a 60 s drive of three units at 1 kHz with GNSS and PPS (the filter starts at
    // about 35 s, after a standstill and the drive-off)
    let model_path = workspace_root().join("examples/models/board-three-mems.json");
    let model = SimModel::load(&model_path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (_, input) = dynacal_tests::simulated_drive(&model, 60.0, 5, dir.path());

    // WHEN the replay board runs it
    let replay = build_firmware(&target_dir, "board-replay").unwrap();
    let run = run_replay_in_qemu(&replay, &input, &dir.path().join("drive.log"), None).unwrap();
    let report = run.report;

    // THEN with the filter running the board's work is under 15% of its core
    let sets_per_unit = report.imu_sample_sets / 3;
    assert!(
        report.navigating_sample_sets > sets_per_unit / 4,
        "the filter ran for {} of {sets_per_unit} sample sets",
        report.navigating_sample_sets
    );
    let steady = report.steady_instructions_per_second(60.0, 1000.0).unwrap();
    let share = steady / BOARD_CORE_HZ;
    println!(
        "navigating: {steady:.0} instructions per second, {:.1}% of the core; stack at the \
         deepest {} bytes",
        100.0 * share,
        report.stack_peak_bytes
    );
    assert!(share > 0.02 && share < CORE_SHARE_BUDGET, "{share}");
    // AND the statics with the deepest stack fit the RAM
    let ram = statics + report.stack_peak_bytes;
    assert!(
        report.stack_peak_bytes > 1000 && ram < RAM_BUDGET_BYTES,
        "{statics} bytes of statics + {} of stack",
        report.stack_peak_bytes
    );
}
