//! Board faults under emulation (issue 21, part 3): the replay firmware runs a simulated
//! drive of three MEMS units in QEMU with a fault plan (`dynacal_core::inject`) that makes
//! one unit go quiet, stick, saturate, come late and fail its SPI reads, loses the PPS for a
//! minute, the receiver's fixes for 30 s, corrupts its bytes, and fills the log sink. The
//! run must end normally; each fault must show in the log at its time (the Health frames'
//! episodes, `dynacal::board_log::health_episodes`, and the fusion's Fault frames), with no
//! fault reported outside the plan's windows; no corrupted fix may reach the log; the
//! logged times must hold through the PPS loss; and the fused output must go on to the end.
//! Its navigation error is measured against the truth and printed (BENCHMARKS.md); it is
//! not yet within a bound. A planned hang must be ended by the watchdog.
//!
//! Skips with a message when qemu-system-arm is absent, except in CI.

use dynacal::board_log::{health_episodes, state_error, HealthEpisode};
use dynacal::decode::{decode_file, seconds_of_us, DecodedLog};
use dynacal::replay::{
    build_replay_firmware, run_replay_with_faults_in_qemu, workspace_root, FIRMWARE_TARGET_DIR,
    QEMU_BOARD_ARGS,
};
use dynacal::sim::board::board_recording;
use dynacal::sim::trajectory::Scenario;
use dynacal::sim::{simulate, SimOptions, SimOutput};
use dynacal_core::log::FaultFrame;
use dynacal_core::replay::ReplayRecord;

mod three_units;

const SECONDS: f64 = 240.0;
/// The drives the plan runs on (`DYNACAL_FAULTS_SEEDS=a,b,...` for others). Seed 21 is not
/// among them: on it the filter's start fails with no fault at all (a heading 112 degrees
/// off at 36 s, errors of metres with GNSS; BENCHMARKS.md), which no fault handling can
/// be judged on.
const SEEDS: [u64; 2] = [1, 2];

/// The plan, times in seconds from the replay's first event.
const PLAN: &str = "seed=5
imu-silent    unit=1 from=30  to=40
imu-stuck     unit=2 from=50  to=60
imu-saturated unit=0 from=70  to=72
imu-late      unit=1 from=80  to=100 delay_us=10000
spi-errors    unit=2 from=110 to=130 rate=0.2
pps-lost      from=140 to=200
gnss-absent   from=150 to=180
gnss-corrupt  from=190 to=220 rate=0.003
log-full      from=225 to=228
";

/// Per planned unit fault: unit, window (s), and the fault kinds that explain it.
const UNIT_FAULTS: [(u8, [f64; 2], &[&str]); 5] = [
    (1, [30.0, 40.0], &["dropout"]),
    (2, [50.0, 60.0], &["stuck"]),
    (0, [70.0, 72.0], &["saturation"]),
    (1, [80.0, 100.0], &["dropout", "time_slip"]),
    (2, [110.0, 130.0], &["dropout"]),
];

struct Run {
    sim: SimOutput,
    /// The replay's first event, s (the plan's zero).
    start_s: f64,
    records: Vec<ReplayRecord>,
    log: DecodedLog,
    /// Receiver frames the board refused (the run report's).
    refused: u64,
}

fn faulty_run(dir: &std::path::Path, seed: u64) -> Run {
    let model = three_units::sim_model(&[]);
    let opts = SimOptions {
        scenario: Scenario::Car,
        seconds: SECONDS,
        seed,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    let sim = simulate(&model, &opts, &|_| {}).unwrap();
    let board = board_recording(&sim, &model).unwrap();
    let input = board.to_replay_input().unwrap();
    let input_path = dir.join("drive.replay");
    input.write(&input_path).unwrap();
    let model_path = dir.join("board-model.bin");
    let mut blob = [0u8; dynacal_core::board_model::MAX_BOARD_MODEL_LEN];
    let len = three_units::board_model(true).encode(&mut blob).unwrap();
    std::fs::write(&model_path, &blob[..len]).unwrap();
    let plan_path = dir.join("faults.txt");
    // DYNACAL_FAULTS_PLAN=FILE runs another plan (to look into one fault alone).
    match std::env::var("DYNACAL_FAULTS_PLAN") {
        Ok(other) => std::fs::copy(other, &plan_path).map(|_| ()).unwrap(),
        Err(_) => std::fs::write(&plan_path, PLAN).unwrap(),
    }
    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let log_path = dir.join("board.log");
    let run = run_replay_with_faults_in_qemu(
        &elf,
        &input_path,
        &log_path,
        Some(&model_path),
        Some(&plan_path),
    )
    .unwrap();
    assert!(run.stderr.contains("run-report"), "{}", run.stderr);
    if std::env::var("DYNACAL_FAULTS_TRACE").is_ok() {
        println!("{}", run.stderr);
    }
    let first = input.records.iter().map(record_t_us).min().unwrap();
    Run {
        sim,
        start_s: seconds_of_us(first),
        records: input.records,
        log: decode_file(&log_path).unwrap(),
        refused: run.report.gnss_frames_refused,
    }
}

fn record_t_us(r: &ReplayRecord) -> u64 {
    match *r {
        ReplayRecord::Imu { t_us, .. }
        | ReplayRecord::Pps { t_us }
        | ReplayRecord::Gnss { t_us, .. } => t_us,
        ReplayRecord::End { .. } => u64::MAX,
    }
}

fn episodes<'a>(all: &'a [HealthEpisode], condition: &str) -> Vec<&'a HealthEpisode> {
    all.iter().filter(|e| e.condition == condition).collect()
}

/// The episode's span in plan seconds.
fn span(e: &HealthEpisode, start_s: f64) -> [f64; 2] {
    [
        e.from_t_s - start_s,
        e.to_t_s.map_or(f64::INFINITY, |t| t - start_s),
    ]
}

/// An episode that starts within `lag_s` after `from` and ends within `lag_s` after `to`.
fn flagged(spans: &[[f64; 2]], [from, to]: [f64; 2], lag_s: f64) -> bool {
    spans
        .iter()
        .any(|s| s[0] >= from && s[0] <= from + lag_s && s[1] >= to && s[1] <= to + lag_s)
}

#[test]
fn board_faults_are_flagged_at_their_time_and_the_fused_output_goes_on() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let seeds: Vec<u64> = std::env::var("DYNACAL_FAULTS_SEEDS")
        .ok()
        .and_then(|v| v.split(',').map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| SEEDS.to_vec());
    for seed in seeds {
        println!("seed {seed}");
        let dir = tempfile::tempdir().unwrap();
        check_faulty_run(&faulty_run(dir.path(), seed));
    }
}

/// Every check of one faulted drive.
fn check_faulty_run(run: &Run) {
    let start_s = run.start_s;
    let worst_navigation = navigation_errors(run);
    let health = health_episodes(&run.log.health);
    let spans = |condition: &str| -> Vec<[f64; 2]> {
        episodes(&health, condition)
            .into_iter()
            .map(|e| span(e, start_s))
            .collect()
    };
    for e in &health {
        println!(
            "health {:?}",
            (
                e.condition,
                span(e, start_s),
                e.frames_dropped,
                e.samples_overrun
            )
        );
    }

    // The board's own flags: a Health report each second, so within 2 s of each edge.
    let imu_fault = spans("imu_fault");
    assert!(
        flagged(&imu_fault, [30.0, 40.0], 2.0),
        "silent unit: {imu_fault:?}"
    );
    assert!(
        flagged(&imu_fault, [110.0, 130.0], 2.0),
        "SPI errors: {imu_fault:?}"
    );
    assert_eq!(imu_fault.len(), 2, "{imu_fault:?}");
    let spi = episodes(&health, "imu_fault")[1];
    // Binomial(20 s x 200 Hz, 0.2) reads failed: 800 +- 25.
    assert!((675..=925).contains(&spi.samples_overrun), "{spi:?}");
    let pps = spans("pps_unlocked");
    assert!(flagged(&pps, [140.0, 200.0], 3.0), "PPS: {pps:?}");
    assert_eq!(pps.len(), 1, "{pps:?}");
    let fix = spans("no_gnss_fix");
    assert!(flagged(&fix, [150.0, 180.0], 3.0), "GNSS: {fix:?}");
    assert!(fix.iter().all(|s| s[0] > 100.0 || s[1] < 5.0), "{fix:?}");
    let full = episodes(&health, "log_backpressure");
    assert_eq!(full.len(), 1, "{full:?}");
    let full_span = span(full[0], start_s);
    assert!((225.0..=229.5).contains(&full_span[0]), "{full_span:?}");
    // Three seconds of three units' frames and more: all dropped, and counted.
    assert!(full[0].frames_dropped >= 1800, "{full:?}");
    assert!(spans("time_not_gps").iter().all(|s| s[1] < 3.0));

    // The fusion's fault events: each planned unit fault found in its window, and none
    // outside one (readmissions aside).
    let faults: Vec<&FaultFrame> = run.log.faults.iter().collect();
    for f in &faults {
        println!(
            "fault {} {} unit {:?} at {:.2} (detected {:.2})",
            f.sensor_name(),
            f.kind_name(),
            f.unit,
            seconds_of_us(f.t_us) - start_s,
            seconds_of_us(f.detected_t_us) - start_s
        );
    }
    for (unit, [from, to], kinds) in UNIT_FAULTS {
        let found = faults.iter().any(|f| {
            let t = seconds_of_us(f.detected_t_us) - start_s;
            f.unit == Some(unit) && kinds.contains(&f.kind_name()) && t >= from && t <= from + 1.0
        });
        assert!(found, "unit {unit} at {from} s: none of {kinds:?} detected");
        let _ = to;
    }
    for f in faults.iter().filter(|f| f.kind_name() != "readmitted") {
        let t = seconds_of_us(f.detected_t_us) - start_s;
        // With two units left a disagreement is found but not placed (unit None).
        let planned = UNIT_FAULTS.iter().any(|(unit, [from, to], _)| {
            (f.unit == Some(*unit) || f.unit.is_none()) && t >= *from && t <= to + 1.0
        });
        assert!(
            planned,
            "a fault outside the plan: {} {} at {t:.2} s",
            f.sensor_name(),
            f.kind_name()
        );
    }

    check_times_and_fixes(run);
    // The fused output never stops: once aligned, a Filter state at least every 0.5 s to
    // the end, however many units are out (before, overlapping faults left no healthy
    // accelerometer and the navigation ended at 80 s).
    // (The states of the 3 s the log sink was full are lost with every other frame.)
    let times: Vec<f64> = run
        .log
        .filter
        .iter()
        .map(|s| seconds_of_us(s.t_us))
        .collect();
    let gap = times
        .windows(2)
        .filter(|w| !(w[0] - start_s < 225.0 && w[1] - start_s >= 228.0))
        .map(|w| w[1] - w[0])
        .fold(0.0, f64::max);
    assert!(
        times.len() > 1 && gap <= 0.5,
        "a gap of {gap} s in the fused output"
    );
    assert!(times[times.len() - 1] - start_s > SECONDS - 1.0);
    // Its error against the truth is measured, not yet bounded: BENCHMARKS.md ("Board
    // faults under emulation") has the figures, and issue 21 stays open for them.
    let _ = worst_navigation;
}

/// The logged times hold through the PPS loss (holdover), and the corrupted bytes gave no
/// wrong fix: every logged fix is one the receiver sent.
fn check_times_and_fixes(run: &Run) {
    let replay_imu: Vec<(u8, u64)> = run
        .records
        .iter()
        .filter_map(|r| match *r {
            ReplayRecord::Imu { t_us, imu_id, .. } => Some((imu_id, t_us)),
            _ => None,
        })
        .collect();
    let mut worst_us = 0i64;
    for imu in &run.log.imus {
        let id = imu.config.imu_id;
        let sent: std::collections::BTreeSet<u64> = replay_imu
            .iter()
            .filter(|r| r.0 == id)
            .map(|r| r.1)
            .collect();
        for &t in &imu.t_us {
            // Each logged stamp is within the board's clock error of a sent one (late unit
            // samples are sent 10 ms late by the plan).
            let near = sent
                .range(t.saturating_sub(20_000)..=t + 20_000)
                .map(|&s| (s as i64 - t as i64).abs())
                .min()
                .unwrap();
            let off = if near >= 9_000 { near - 10_000 } else { near };
            worst_us = worst_us.max(off.abs());
        }
    }
    println!("worst logged time error {worst_us} us");
    assert!(worst_us <= 50, "{worst_us} us");

    let sent = &run.sim.gnss.as_ref().unwrap();
    let fixes = dynacal::sim::board::gnss_fixes(sent);
    let mut matched = 0;
    for logged in &run.log.gnss {
        let truth = fixes.iter().find(|f| f.t_us == logged.t_us);
        let truth = truth.unwrap_or_else(|| panic!("a fix the receiver never sent: {logged:?}"));
        assert!((logged.lat_rad - truth.lat_rad).abs() < 2e-9, "{logged:?}");
        assert!((logged.h_m - truth.h_m).abs() < 1e-3, "{logged:?}");
        matched += 1;
    }
    let in_window = |t: u64, [a, b]: [f64; 2]| {
        let s = seconds_of_us(t) - run.start_s;
        s >= a && s < b
    };
    let lost_to_corruption = fixes
        .iter()
        .filter(|f| in_window(f.t_us, [190.0, 220.0]))
        .filter(|f| !run.log.gnss.iter().any(|l| l.t_us == f.t_us))
        .count();
    println!("{matched} fixes logged; {lost_to_corruption} of 300 lost to corrupted bytes");
    // A 100-byte frame survives 0.3% corruption per byte with probability 0.74.
    assert!(
        (30..=130).contains(&lost_to_corruption),
        "{lost_to_corruption}"
    );
    // The board counts what it refused: a frame whose checksum or length failed (one hit
    // in its sync bytes is never seen as a frame at all), so about one per fix lost.
    let lost = lost_to_corruption as u64;
    assert!(
        2 * run.refused >= lost && run.refused <= 2 * lost,
        "{} refused",
        run.refused
    );
}

/// The fused navigation's worst horizontal position error against the truth (m), and the
/// worst horizontal position and velocity errors in their stated sigmas.
fn navigation_errors(run: &Run) -> (f64, f64, f64) {
    let reference = &run.sim.reference.recording;
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for s in &run.log.filter {
        let e = state_error(reference, s).unwrap();
        let horizontal = e.position_ned_m.xy().norm();
        let sigma = e.sigma_position_m.xy().norm();
        let v = e.velocity_ned_m_s.xy().norm() / e.sigma_velocity_m_s.xy().norm();
        worst = (
            worst.0.max(horizontal),
            worst.1.max(horizontal / sigma),
            worst.2.max(v),
        );
        if std::env::var("DYNACAL_FAULTS_TRACE").is_ok() && (s.t_us / 100_000) % 20 == 0 {
            println!(
                "t {:6.1} horizontal {horizontal:8.2} m sigma {sigma:6.2} velocity {:6.3} sigma {:6.3}",
                seconds_of_us(s.t_us) - run.start_s,
                e.velocity_ned_m_s.xy().norm(),
                e.sigma_velocity_m_s.xy().norm()
            );
        }
    }
    if std::env::var("DYNACAL_FAULTS_TRACE").is_ok() {
        let still: Vec<String> = run
            .log
            .noise
            .iter()
            .filter(|n| n.still)
            .map(|n| format!("{:.0}", seconds_of_us(n.t_us) - run.start_s))
            .collect();
        println!("still at {}", still.join(" "));
    }
    println!(
        "fused navigation: worst horizontal error {:.2} m, {:.2} sigma; velocity {:.2} sigma",
        worst.0, worst.1, worst.2
    );
    worst
}

/// A main loop that hangs (a transfer that never completes) is ended by the watchdog, with
/// its exit code and the time of the last event, and leaves no log that looks whole.
#[test]
fn a_hung_main_loop_is_caught_by_the_watchdog() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = three_units::sim_model(&[]);
    let opts = SimOptions {
        scenario: Scenario::Car,
        seconds: 6.0,
        seed: SEEDS[0],
        disabled: Vec::new(),
        keep_ideal: false,
    };
    let sim = simulate(&model, &opts, &|_| {}).unwrap();
    let input_path = dir.path().join("drive.replay");
    board_recording(&sim, &model)
        .unwrap()
        .to_replay_input()
        .unwrap()
        .write(&input_path)
        .unwrap();
    let plan_path = dir.path().join("hang.txt");
    std::fs::write(&plan_path, "hang at=3\n").unwrap();
    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let log_path = dir.path().join("board.log");
    let run = std::process::Command::new("timeout")
        .arg("120")
        .arg("qemu-system-arm")
        .args(QEMU_BOARD_ARGS)
        .arg("-semihosting-config")
        .arg(format!(
            "enable=on,target=native,arg=dynacal-firmware,arg={},arg={},arg=--faults,arg={}",
            input_path.display(),
            log_path.display(),
            plan_path.display()
        ))
        .arg("-kernel")
        .arg(&elf)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(103), "{stderr}");
    assert!(
        stderr.contains("watchdog") && stderr.contains("500 ms"),
        "{stderr}"
    );
    // The last event handed on is the one at 3 s from the start.
    let t_ms: u64 = stderr
        .split("t=")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("{stderr}"));
    let start_ms = (sim.reference.recording.t_s[0] * 1e3) as u64;
    assert!(
        (2990..=3010).contains(&(t_ms - start_ms)),
        "{t_ms} {start_ms}"
    );
    assert!(!log_path.exists());

    // The same plan through `dynacal board` is a failed run naming the watchdog.
    let err = run_replay_with_faults_in_qemu(&elf, &input_path, &log_path, None, Some(&plan_path))
        .unwrap_err()
        .to_string();
    assert!(err.contains("watchdog"), "{err}");
}

/// A plan that does not read is refused by the board before it runs, naming its line.
#[test]
fn a_bad_fault_plan_is_a_usage_error_naming_its_line() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let imus = [dynacal::replay::adis16405_imu()];
    let samples: Vec<_> = (0..100)
        .map(|k| dynacal::replay::CountSample {
            t_us: k * 10_000,
            imu_id: 0,
            gyro_counts: [1, 2, 3],
            accel_counts: [3, 4, -305],
        })
        .collect();
    let input_path = dir.path().join("one.replay");
    dynacal::replay::ReplayInput::from_counts(&imus, &samples)
        .unwrap()
        .write(&input_path)
        .unwrap();
    let plan_path = dir.path().join("plan.txt");
    std::fs::write(
        &plan_path,
        "pps-lost from=1 to=2\nimu-stuck unit=1 from=1 to=2\n",
    )
    .unwrap();
    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let err = run_replay_with_faults_in_qemu(
        &elf,
        &input_path,
        &dir.path().join("board.log"),
        None,
        Some(&plan_path),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("exit status: 2"), "{err}");
    assert!(err.contains("plan.txt: line 2: unit 1"), "{err}");
}
