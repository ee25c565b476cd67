//! End to end: the first 60 s of ADIS16405 session 1 go through the real firmware
//! (`board-replay`, built for thumbv7em-none-eabihf, run in QEMU's emulated STM32F405) and
//! come back out of the host decoder bit for bit, and the board's streaming wavelet-variance
//! snapshots agree with the host's batch estimator on the same counts.
//!
//! Skips with a message when the data folder or qemu-system-arm is absent, except in CI
//! (`CI` or `DYNACAL_REQUIRE_QEMU` set), where a missing QEMU fails the test.

use std::path::PathBuf;

use dynacal::decode::decode_file;
use dynacal::interchange::ImuRecording;
use dynacal::replay::{
    adis16405_replay, adis16405_session_path, build_replay_firmware, check_log_against_replay,
    run_replay_in_qemu, workspace_root, ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT,
    ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT, FIRMWARE_TARGET_DIR,
};
use dynacal::wv::{haar_wv_counts, WvOptions};

const SECONDS: u32 = 60;
/// Instructions per sample set the firmware may spend framing and queueing the log and
/// accumulating the wavelet variance of the six channels. Measured 3632 with the `firmware`
/// profile (3113 at opt-level 3: the size the real board's flash needs costs 17% here, and
/// 0.6 points of the core's budget with the fusion running, BENCHMARKS.md); the bound catches
/// a regression of about 20%.
const MAX_RECORD_INSTRUCTIONS_PER_SAMPLE: f64 = 4300.0;
/// Instructions per sample set for the whole loop, replay decoding included (measured 4311).
const MAX_TOTAL_INSTRUCTIONS_PER_SAMPLE: f64 = 5100.0;

#[test]
fn adis16405_minute_passes_through_the_firmware_under_qemu_bit_exact() {
    let session = adis16405_session_path(&tests_data_dir(), 1);
    if !session.exists() {
        eprintln!(
            "SKIPPED: {} not found (set DYNACAL_DATA to the measured-data folder)",
            session.display()
        );
        return;
    }
    if !dynacal_tests::qemu_or_skip() {
        return;
    }

    let input = adis16405_replay(&session, SECONDS).unwrap();
    assert_eq!(input.samples().count(), 6000);
    let dir = tempfile::tempdir().unwrap();
    let input_path = dir.path().join("adis16405-session1-60s.replay");
    input.write(&input_path).unwrap();

    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let log_path = dir.path().join("board.log");
    let run = run_replay_in_qemu(&elf, &input_path, &log_path, None).unwrap();
    let report = run.report;
    eprintln!(
        "firmware: {} sample sets, {} frames, {} bytes, {:.1} instructions/sample recording, \
         {:.1} fetching from the source, {:.1} in total, {:.2} s in QEMU",
        report.imu_sample_sets,
        report.frames_written,
        report.bytes_written,
        report.record_instructions_per_sample(),
        report.source_instructions as f64 / report.imu_sample_sets as f64,
        report.total_instructions_per_sample(),
        run.wall_time.as_secs_f64()
    );
    assert!(!dir.path().join("board.log.part").exists());

    let log = decode_file(&log_path).unwrap();
    log.validate(&log_path).unwrap();
    let bytes = std::fs::read(&log_path).unwrap();
    assert_eq!(report.bytes_written, bytes.len() as u64);
    assert_eq!(report.frames_written, log.frames_decoded());
    assert_eq!(report.frames_dropped, 0);
    assert_eq!(log.stream.frames_dropped, 0);
    assert_eq!(log.stream.bytes_dropped, 0);
    assert_eq!(log.headers_seen, 1);

    // Every sample, in order, with exact times and counts.
    assert_eq!(log.imus.len(), 1);
    let stream = &log.imus[0];
    assert_eq!(stream.config.model.as_str(), "ADIS16405");
    assert_eq!(
        stream.config.gyro_scale_rad_s_per_count.to_bits(),
        ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT.to_bits()
    );
    assert_eq!(
        stream.config.accel_scale_m_s2_per_count.to_bits(),
        ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT.to_bits()
    );
    assert_eq!(stream.samples_out_of_order, 0);
    let source: Vec<_> = input.samples().collect();
    assert_eq!(stream.len(), source.len());
    for (i, want) in source.iter().enumerate() {
        assert_eq!(stream.t_us[i], i as u64 * 10_000, "sample {i} time");
        assert_eq!(stream.t_us[i], want.t_us, "sample {i} time");
        assert_eq!(stream.gyro_counts[i], want.gyro_counts, "sample {i} gyro");
        assert_eq!(
            stream.accel_counts[i], want.accel_counts,
            "sample {i} accel"
        );
    }

    // The interchange file holds counts x scale, bit for bit, after a write/read round trip.
    let csv_path = dir.path().join("imu0.csv");
    stream.to_recording().write(&csv_path).unwrap();
    let recording = ImuRecording::read(&csv_path).unwrap();
    let gyro = recording.gyro_rad_s.as_ref().unwrap();
    let accel = recording.accel_m_s2.as_ref().unwrap();
    for (i, want) in source.iter().enumerate() {
        assert_eq!(
            recording.t_s[i].to_bits(),
            dynacal::decode::seconds_of_us(want.t_us).to_bits()
        );
        for axis in 0..3 {
            let gyro_si = want.gyro_counts[axis] as f64 * ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT;
            let accel_si = want.accel_counts[axis] as f64 * ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT;
            assert_eq!(
                gyro[axis][i].to_bits(),
                gyro_si.to_bits(),
                "sample {i} gyro {axis}"
            );
            assert_eq!(
                accel[axis][i].to_bits(),
                accel_si.to_bits(),
                "sample {i} accel {axis}"
            );
        }
    }

    // One PPS per second, in order, numbered from 0.
    assert_eq!(log.pps.len(), 60);
    for (k, pps) in log.pps.iter().enumerate() {
        assert_eq!((pps.t_us, pps.sequence), (k as u64 * 1_000_000, k as u32));
    }
    // Health at each second after the first event and at the end: never a dropped frame,
    // PPS locked throughout.
    assert_eq!(log.health.len(), 60);
    assert_eq!(report.health_reports, 60);
    for health in &log.health {
        assert_eq!(health.frames_dropped, 0);
        assert_eq!(health.samples_overrun, 0);
        assert_ne!(health.flags & dynacal_core::log::Health::FLAG_PPS_LOCKED, 0);
    }

    // One WaveletVariance frame per channel, at the end of the run, on all 6000 samples.
    assert_eq!(report.frames_written, 1 + 6000 + 60 + 60 + 6);
    assert_eq!(log.frames_by_kind["wavelet_variance"], 6);
    assert_eq!(log.wv_frames_unknown, 0);
    let board_wv = log.wavelet_variance_si();
    assert_eq!(board_wv.len(), 6);
    let dt_s = 1.0 / f64::from(stream.config.sample_rate_hz);
    assert_eq!(dt_s, 0.01);
    for channel in &board_wv {
        let axis = channel.channel.axis();
        let (counts, lsb): (Vec<i32>, f64) = if channel.channel.is_gyro() {
            (
                source.iter().map(|s| s.gyro_counts[axis]).collect(),
                ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT,
            )
        } else {
            (
                source.iter().map(|s| s.accel_counts[axis]).collect(),
                ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT,
            )
        };
        assert_eq!(channel.t_us, 59_990_000, "{}", channel.channel);
        assert_eq!(channel.n_samples, 6000, "{}", channel.channel);
        assert_eq!(channel.full_levels, 4, "{}", channel.channel);
        let board = channel.wv.as_ref().unwrap();
        let batch = haar_wv_counts(&counts, lsb, dt_s, &WvOptions::default()).unwrap();
        // The full (overlapping) levels are the batch estimator's sums, so equal it.
        for level in 1..=u32::from(channel.full_levels) {
            let i = board.levels.iter().position(|&j| j == level).unwrap();
            let k = batch.levels.iter().position(|&j| j == level).unwrap();
            assert_eq!(board.n_coefficients[i], batch.n_coefficients[k]);
            assert_eq!(board.scales_s[i], batch.scales_s[k]);
            let (b, h) = (board.variance[i], batch.variance[k]);
            assert!(
                h > 0.0 && ((b - h) / h).abs() <= 1e-12,
                "{} level {level}: board {b:e}, batch {h:e}",
                channel.channel
            );
        }
        // Decimated levels reach as far as 6000 samples allow (level 12 needs 2 x 2048).
        assert_eq!(board.levels.last(), Some(&12), "{}", channel.channel);
    }

    // The library's own comparison agrees.
    let check = check_log_against_replay(&input, &log);
    assert!(check.is_exact(), "{check:?}");

    // Cost, deterministic under -icount.
    assert_eq!(report.imu_sample_sets, 6000);
    assert!(
        report.record_instructions_per_sample() < MAX_RECORD_INSTRUCTIONS_PER_SAMPLE,
        "recording costs {:.1} instructions per sample set",
        report.record_instructions_per_sample()
    );
    assert!(
        report.total_instructions_per_sample() < MAX_TOTAL_INSTRUCTIONS_PER_SAMPLE,
        "the loop costs {:.1} instructions per sample set",
        report.total_instructions_per_sample()
    );

    // A second run is bit-identical: same log, same instruction counts. (The output path
    // has the same length: the firmware prints it at start-up, which shifts SysTick's phase
    // and with it the load figures in the Health frames.)
    let log_again = dir.path().join("board.lo2");
    let again = run_replay_in_qemu(&elf, &input_path, &log_again, None).unwrap();
    assert!(
        std::fs::read(&log_again).unwrap() == bytes,
        "the second run's log differs"
    );
    assert_eq!(again.report, report);
}

#[test]
fn a_truncated_replay_input_fails_the_run_and_leaves_no_log() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let imus = [dynacal::replay::adis16405_imu()];
    let samples: Vec<_> = (0..300)
        .map(|k| dynacal::replay::CountSample {
            t_us: k * 10_000,
            imu_id: 0,
            gyro_counts: [k as i32, 1, 2],
            accel_counts: [3, 4, -305],
        })
        .collect();
    let input = dynacal::replay::ReplayInput::from_counts(&imus, &samples).unwrap();
    let mut bytes = input.encode().unwrap();
    bytes.truncate(bytes.len() - 30);
    let dir = tempfile::tempdir().unwrap();
    let input_path = dir.path().join("cut.replay");
    std::fs::write(&input_path, &bytes).unwrap();

    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let log_path = dir.path().join("board.log");
    let err = run_replay_in_qemu(&elf, &input_path, &log_path, None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("exit status: 1"), "{err}");
    assert!(
        err.contains("cut.replay") && err.contains("truncated"),
        "{err}"
    );
    assert!(!log_path.exists());
}

/// A panic on the board ends the emulated run with failure (exit code 101 and the panic's
/// message) instead of hanging it: the firmware's one deliberate panic,
/// `--panic-self-test`, goes through the same handler as any other.
#[test]
fn a_panic_on_the_board_ends_the_run_with_failure() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let run = std::process::Command::new("timeout")
        .arg("60")
        .arg("qemu-system-arm")
        .args(dynacal::replay::QEMU_BOARD_ARGS)
        .arg("-semihosting-config")
        .arg("enable=on,target=native,arg=dynacal-firmware,arg=--panic-self-test")
        .arg("-kernel")
        .arg(&elf)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(101), "{stderr}");
    assert!(
        stderr.contains("panic") && stderr.contains("self-test"),
        "{stderr}"
    );
}

/// A stack overflow faults instead of overwriting the statics: the stack sits below them at
/// the bottom of SRAM (memory.x, as flip-link arranges it), so running off it reaches
/// unmapped addresses; the core cannot even stack the fault's frame there and locks up,
/// which ends the emulator with failure (on the board, the watchdog then resets it).
#[test]
fn a_stack_overflow_faults_instead_of_overwriting_the_statics() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let run = std::process::Command::new("timeout")
        .arg("60")
        .arg("qemu-system-arm")
        .args(dynacal::replay::QEMU_BOARD_ARGS)
        .arg("-semihosting-config")
        .arg("enable=on,target=native,arg=dynacal-firmware,arg=--stack-overflow-self-test")
        .arg("-kernel")
        .arg(&elf)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "{stderr}");
    assert_ne!(run.status.code(), Some(124), "it hung: {stderr}");
    assert!(stderr.contains("Lockup"), "{stderr}");
    assert!(!stderr.contains("did not overflow"), "{stderr}");
}

/// A simulated car run's receiver bytes (each GNSS fix as the NAV-PVT frame a u-blox
/// receiver sends, in the replay input as its UART delivers them) go through the firmware's
/// receiver: the board logs every fix, equal to the simulation's to the frame's resolution,
/// and its health reports a 3-D fix.
#[test]
fn the_board_logs_the_receivers_fixes_from_its_ubx_bytes() {
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let model = dynacal::sim::SimModel::load(
        &workspace_root().join("examples/models/three-mems-1khz.json"),
    )
    .unwrap();
    let opts = dynacal::sim::SimOptions {
        scenario: dynacal::sim::Scenario::Car,
        seconds: 3.0,
        seed: 4,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    let out = dynacal::sim::simulate(&model, &opts, &|_| {}).unwrap();
    let board = dynacal::sim::board::board_recording(&out, &model).unwrap();
    assert!(board.gnss.len() >= 20, "{} fixes", board.gnss.len());
    let dir = tempfile::tempdir().unwrap();
    let input_path = dir.path().join("car.replay");
    std::fs::write(&input_path, board.replay_bytes().unwrap()).unwrap();
    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let log_path = dir.path().join("board.log");
    run_replay_in_qemu(&elf, &input_path, &log_path, None).unwrap();
    let log = decode_file(&log_path).unwrap();
    assert_eq!(log.gnss.len(), board.gnss.len());
    for (logged, simulated) in log.gnss.iter().zip(&board.gnss) {
        assert_eq!(logged.t_us, simulated.t_us);
        assert!((logged.lat_rad - simulated.lat_rad).abs() < 2e-9);
        assert!((logged.lon_rad - simulated.lon_rad).abs() < 2e-9);
        assert!((logged.h_m - simulated.h_m).abs() < 1e-3);
        assert_eq!(logged.fix_type, simulated.fix_type);
    }
    let fix_flag = dynacal_core::log::Health::FLAG_GNSS_FIX;
    assert!(log.health.iter().skip(1).all(|h| h.flags & fix_flag != 0));
}

fn tests_data_dir() -> PathBuf {
    dynacal_tests::data_dir()
}
