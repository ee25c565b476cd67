//! The board without an FPU (issue 25, part 3): the replay firmware built for a Cortex-M3
//! (thumbv7m-none-eabi, run in QEMU's netduino2) with its fusion filter in Q32.32 fixed
//! point (the firmware's `fixed-point` feature), replaying the same simulated drive as the
//! Cortex-M4F board with its `f32` filter: it navigates as that board does, and its image's
//! flash and RAM and the fusion's instructions are reported.
//!
//! Skips when qemu-system-arm is absent, except in CI, where that fails.

use dynacal::decode::decode_file;
use dynacal::model::SimModel;
use dynacal::replay::{
    build_firmware_for, run_replay_in_qemu, workspace_root, FIRMWARE_TARGET_DIR,
};
use dynacal_core::log::FilterState;
use dynacal_tests::CostCore;

/// The angle between two attitude quaternions (scalar first), rad.
fn attitude_gap_rad(a: &FilterState, b: &FilterState) -> f64 {
    let dot: f64 = a
        .q_nb
        .iter()
        .zip(&b.q_nb)
        .map(|(x, y)| f64::from(*x) * f64::from(*y))
        .sum();
    2.0 * dot.abs().min(1.0).acos()
}

/// Horizontal distance between two states' positions, m (local flat Earth).
fn horizontal_gap_m(a: &FilterState, b: &FilterState) -> f64 {
    let radius = 6.371e6;
    let north = (a.lat_rad - b.lat_rad) * radius;
    let east = (a.lon_rad - b.lon_rad) * radius * a.lat_rad.cos();
    north.hypot(east)
}

#[test]
fn the_fixed_point_board_without_an_fpu_navigates_as_the_f32_board_does() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let target_dir = workspace_root().join(FIRMWARE_TARGET_DIR);
    // GIVEN a 60 s drive of three units at 1 kHz with GNSS and PPS (the filter starts at
    // about 35 s, after a standstill and the drive-off)
    let model_path = workspace_root().join("examples/models/board-three-mems.json");
    let model = SimModel::load(&model_path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (_, input) = dynacal_tests::simulated_drive(&model, 60.0, 5, dir.path());

    // WHEN the Cortex-M4F board (f32 filter) and the Cortex-M3 board (fixed-point filter,
    // no FPU) replay it
    let build = |core: CostCore| build_firmware_for(&target_dir, core.features(), core.target());
    let (m4f, m3) = (build(CostCore::M4F).unwrap(), build(CostCore::M3).unwrap());
    let (log_m4f, log_m3) = (dir.path().join("m4f.log"), dir.path().join("m3.log"));
    let run_m4f = run_replay_in_qemu(&m4f, &input, &log_m4f, None).unwrap();
    let run_m3 = run_replay_in_qemu(&m3, &input, &log_m3, None).unwrap();
    let (a, b) = (
        decode_file(&log_m4f).unwrap(),
        decode_file(&log_m3).unwrap(),
    );

    // THEN both boards recorded the same samples and their filters ran from the same time
    assert_eq!(
        run_m4f.report.imu_sample_sets,
        run_m3.report.imu_sample_sets
    );
    assert!(a.filter.len() > 50, "{} filter states", a.filter.len());
    assert_eq!(a.filter.len(), b.filter.len());
    // AND the fixed-point board's navigation follows the f32 board's
    let (mut position, mut attitude, mut speed) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.filter.iter().zip(&b.filter) {
        assert_eq!(x.t_us, y.t_us);
        position = position.max(horizontal_gap_m(x, y));
        attitude = attitude.max(attitude_gap_rad(x, y));
        let dv = x.vel_ned_m_s.iter().zip(&y.vel_ned_m_s);
        speed = speed.max(dv.map(|(p, q)| f64::from(p - q).abs()).fold(0.0, f64::max));
    }
    let (flash, statics) = dynacal_tests::flash_and_statics(&m3);
    let steady = |run: &dynacal::replay::QemuRun| {
        run.report
            .steady_instructions_per_second(60.0, 1000.0)
            .unwrap_or(f64::NAN)
    };
    println!(
        "fixed point on the Cortex-M3 against f32 on the Cortex-M4F over {} states: position \
         {position:.4} m, velocity {speed:.4} m/s, attitude {:.4} deg apart at most; \
         navigating, {:.0} instructions a second on the M3 ({:.0} on the M4F); the M3 image: \
         {flash} bytes of flash, {statics} of statics, stack at the deepest {} bytes",
        a.filter.len(),
        attitude.to_degrees(),
        steady(&run_m3),
        steady(&run_m4f),
        run_m3.report.stack_peak_bytes
    );
    // Measured: 0.0000 m, 0.0001 m/s, 0.036 deg (seed 5); the bounds are a tenth of the
    // navigation's own errors with GNSS (0.1-0.2 m, 0.2-0.7 deg RMS).
    assert!(position < 0.1, "position {position} m apart");
    assert!(speed < 0.05, "velocity {speed} m/s apart");
    assert!(
        attitude < 0.1f64.to_radians(),
        "attitude {attitude} rad apart"
    );
}
