//! The simulator's board view (`dynacal::sim::board`): a simulated run's MEMS IMUs as raw
//! counts in the firmware replay input and in the board log. The log decodes with
//! `dynacal::decode` to exactly the replay's counts, stamps and PPS edges, and its
//! interchange values are counts x scale within half an LSB of the simulated outputs.

use std::collections::BTreeMap;
use std::path::Path;

use dynacal::decode::{decode_bytes, decode_file};
use dynacal::interchange::FileFormat;
use dynacal::sim::board::{
    board_recording, BoardError, BoardRecording, DEFAULT_ACCEL_LSB_M_S2, DEFAULT_GYRO_LSB_RAD_S,
};
use dynacal::sim::output::{write_outputs_with_board, LOG_FILE, REPLAY_FILE};
use dynacal::sim::{simulate, Scenario, SimModel, SimOptions, SimOutput};
use dynacal_core::gnss::{UbxReceiver, LEAP_SECONDS_2017};
use dynacal_core::log::GnssFix;
use dynacal_core::replay::{decode_header, decode_record, ReplayRecord};

fn example(name: &str) -> SimModel {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/models")
        .join(name);
    SimModel::load(&path).unwrap()
}

fn run(model: &SimModel, seconds: f64) -> SimOutput {
    let opts = SimOptions {
        scenario: Scenario::Car,
        seconds,
        seed: 5,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    simulate(model, &opts, &|_| {}).unwrap()
}

/// Per IMU id: (t_us, gyro counts, accel counts) of every sample; and the PPS stamps.
type Samples = BTreeMap<u8, Vec<(u64, [i32; 3], [i32; 3])>>;

/// The replay's header scales, samples, PPS stamps, and the fixes its GNSS records give
/// through the board's receiver.
type ReplayContents = (Vec<(u8, f64, f64)>, Samples, Vec<u64>, Vec<GnssFix>);

fn read_replay(bytes: &[u8]) -> ReplayContents {
    let (header, mut at) = decode_header(bytes).unwrap();
    let scales = header
        .imus
        .iter()
        .map(|i| {
            (
                i.imu_id,
                i.gyro_scale_rad_s_per_count,
                i.accel_scale_m_s2_per_count,
            )
        })
        .collect();
    let mut samples = Samples::new();
    let mut pps = Vec::new();
    let mut fixes = Vec::new();
    let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
    loop {
        let (record, n) = decode_record(&bytes[at..]).unwrap();
        at += n;
        match record {
            ReplayRecord::Imu {
                t_us,
                imu_id,
                gyro_counts,
                accel_counts,
            } => samples
                .entry(imu_id)
                .or_default()
                .push((t_us, gyro_counts, accel_counts)),
            ReplayRecord::Pps { t_us } => pps.push(t_us),
            ReplayRecord::Gnss { len, data, .. } => {
                receiver.push(&data[..usize::from(len)], |fix| fixes.push(fix))
            }
            ReplayRecord::End {
                imu_sample_sets,
                pps_edges,
            } => {
                let total: usize = samples.values().map(Vec::len).sum();
                assert_eq!(imu_sample_sets as usize, total);
                assert_eq!(pps_edges as usize, pps.len());
                break;
            }
        }
    }
    assert_eq!(at, bytes.len(), "bytes after the end record");
    (scales, samples, pps, fixes)
}

fn check_log_against_replay(log: &[u8], replay: &[u8], out: &SimOutput) {
    let (scales, replay_samples, replay_pps, replay_fixes) = read_replay(replay);
    let decoded = decode_bytes(log);
    // The replay carries each fix as the receiver's NAV-PVT bytes: the same fixes to the
    // frame's resolution (1e-7 deg, 1 mm, 1 mm/s).
    assert_eq!(replay_fixes.len(), decoded.gnss.len());
    for (sent, logged) in replay_fixes.iter().zip(&decoded.gnss) {
        assert_eq!(sent.t_us, logged.t_us);
        assert!((sent.lat_rad - logged.lat_rad).abs() < 2e-9);
        assert!((sent.lon_rad - logged.lon_rad).abs() < 2e-9);
        assert!((sent.h_m - logged.h_m).abs() < 1e-3);
        for k in 0..3 {
            assert!((sent.vel_ned_m_s[k] - logged.vel_ned_m_s[k]).abs() < 1e-3);
        }
    }
    assert!(
        decoded.dropped_by_error.is_empty(),
        "{:?}",
        decoded.dropped_by_error
    );
    assert_eq!(decoded.imus.len(), out.imus.len());
    for (stream, &(id, gyro_scale, accel_scale)) in decoded.imus.iter().zip(&scales) {
        assert_eq!(stream.config.imu_id, id);
        assert_eq!(stream.config.gyro_scale_rad_s_per_count, gyro_scale);
        assert_eq!(stream.config.accel_scale_m_s2_per_count, accel_scale);
        let from_log: Vec<(u64, [i32; 3], [i32; 3])> = (0..stream.len())
            .map(|k| {
                (
                    stream.t_us[k],
                    stream.gyro_counts[k],
                    stream.accel_counts[k],
                )
            })
            .collect();
        assert!(
            from_log == replay_samples[&id],
            "IMU {id}: log and replay counts differ"
        );
        assert_eq!(stream.samples_out_of_order, 0);

        // Interchange values: exactly counts x scale, and within half an LSB of what the
        // simulated IMU reported.
        let rec = stream.to_recording();
        let sim = &out.imus[id as usize].recording;
        assert_eq!(rec.len(), sim.len());
        for axis in 0..3 {
            for (values, counts, scale, simulated) in [
                (
                    &rec.gyro_rad_s.as_ref().unwrap()[axis],
                    &stream.gyro_counts,
                    gyro_scale,
                    &sim.gyro_rad_s.as_ref().unwrap()[axis],
                ),
                (
                    &rec.accel_m_s2.as_ref().unwrap()[axis],
                    &stream.accel_counts,
                    accel_scale,
                    &sim.accel_m_s2.as_ref().unwrap()[axis],
                ),
            ] {
                for k in 0..values.len() {
                    assert_eq!(
                        values[k].to_bits(),
                        (counts[k][axis] as f64 * scale).to_bits()
                    );
                    assert!(
                        (values[k] - simulated[k]).abs() <= 0.5 * scale * (1.0 + 1e-9),
                        "IMU {id} axis {axis} sample {k}: {} vs simulated {}",
                        values[k],
                        simulated[k]
                    );
                }
            }
        }
        // Stamps are the IMU clock's ticks in GPS time, to the microsecond.
        let ticks = &out.imus[id as usize].clock.tick_t_s;
        for (k, &t_us) in stream.t_us.iter().enumerate() {
            assert!((t_us as f64 - ticks[k] * 1e6).abs() <= 0.5 + 1e-6);
        }
    }
    let log_pps: Vec<u64> = decoded.pps.iter().map(|p| p.t_us).collect();
    assert_eq!(log_pps, replay_pps);
    assert!(decoded
        .pps
        .iter()
        .enumerate()
        .all(|(k, p)| p.t_us % 1_000_000 == 0 && p.sequence == k as u32 + 1));
    let gnss = out.gnss.as_ref().unwrap();
    assert_eq!(decoded.gnss.len(), gnss.t_s.len());
    for (fix, k) in decoded.gnss.iter().zip(0..) {
        assert_eq!(fix.lat_rad, gnss.position[0][k]);
        assert_eq!(fix.lon_rad, gnss.position[1][k]);
        assert_eq!(fix.t_us, (gnss.t_s[k] * 1e6).round() as u64);
    }
}

#[test]
fn simulated_log_decodes_to_the_replay_counts_bit_for_bit_and_to_counts_times_scale() {
    let model = example("three-mems-1khz.json");
    let out = run(&model, 4.5);
    let board = board_recording(&out, &model).unwrap();
    // The model's quantization steps are the LSBs: its outputs are whole counts.
    for imu in &board.imus {
        assert_eq!(imu.config.gyro_scale_rad_s_per_count, 1e-4);
        assert_eq!(imu.config.accel_scale_m_s2_per_count, 1e-3);
        assert_eq!(imu.t_us.len(), 4500);
    }
    let replay = board.replay_bytes().unwrap();
    let log = board.log_bytes().unwrap();
    check_log_against_replay(&log, &replay, &out);
    // PPS every whole second from the first tick (at 0 s) to the last sample (4.499 s).
    assert_eq!(
        board.pps_t_us,
        vec![0, 1_000_000, 2_000_000, 3_000_000, 4_000_000]
    );

    // Written through the output stage: the same bytes, readable from disk.
    let dir = tempfile::tempdir().unwrap();
    let files =
        write_outputs_with_board(&out, dir.path(), FileFormat::Csv, false, Some(&board)).unwrap();
    assert!(files.iter().any(|f| f.ends_with(REPLAY_FILE)));
    assert_eq!(std::fs::read(dir.path().join(REPLAY_FILE)).unwrap(), replay);
    assert_eq!(std::fs::read(dir.path().join(LOG_FILE)).unwrap(), log);
    let from_file = decode_file(&dir.path().join(LOG_FILE)).unwrap();
    assert_eq!(from_file.imus, decode_bytes(&log).imus);
}

#[test]
fn without_a_quantization_step_the_default_lsbs_are_used_and_values_stay_within_half_an_lsb() {
    let mut model = example("three-mems-1khz.json");
    model.imus.truncate(2);
    for imu in &mut model.imus {
        imu.gyro.quantization_step = None;
        imu.accel.quantization_step = None;
        for ch in imu.channels.values_mut() {
            ch.quantization_step = None;
        }
    }
    let out = run(&model, 2.0);
    let board: BoardRecording = board_recording(&out, &model).unwrap();
    assert_eq!(board.imus.len(), 2);
    for imu in &board.imus {
        assert_eq!(
            imu.config.gyro_scale_rad_s_per_count,
            DEFAULT_GYRO_LSB_RAD_S
        );
        assert_eq!(
            imu.config.accel_scale_m_s2_per_count,
            DEFAULT_ACCEL_LSB_M_S2
        );
    }
    check_log_against_replay(
        &board.log_bytes().unwrap(),
        &board.replay_bytes().unwrap(),
        &out,
    );
}

#[test]
fn models_the_board_cannot_log_are_refused_with_the_reason() {
    let mut model = example("three-mems-1khz.json");
    let gy = dynacal::model::ChannelModel {
        quantization_step: Some(2e-4),
        ..model.imus[1].gyro.clone()
    };
    model.imus[1]
        .channels
        .insert(dynacal::model::Channel::Gy, gy);
    let out = run(&model, 1.0);
    let e = board_recording(&out, &model).unwrap_err();
    assert!(
        matches!(e, BoardError::MixedSteps { ref imu, kind: "gyro" } if imu == "mtx2"),
        "{e}"
    );

    let mut model = example("three-mems-1khz.json");
    let mut fourth = model.imus[0].clone();
    fourth.name = "mtx4".into();
    model.imus.push(fourth);
    let out = run(&model, 1.0);
    let e = board_recording(&out, &model).unwrap_err();
    assert!(matches!(e, BoardError::TooManyImus(4)), "{e}");
}

/// The simulated replay through the real firmware (`board-replay` under QEMU): the log it
/// writes decodes to exactly the simulated counts. Skips without qemu-system-arm, except in
/// CI (`CI` or `DYNACAL_REQUIRE_QEMU` set).
#[test]
fn a_simulated_replay_passes_through_the_firmware_under_qemu_bit_exact() {
    use dynacal::replay::{
        build_replay_firmware, check_log_against_replay, run_replay_in_qemu, workspace_root,
        FIRMWARE_TARGET_DIR,
    };
    if !dynacal_tests::qemu_or_skip() {
        return;
    }
    let model = example("three-mems-1khz.json");
    let out = run(&model, 3.0);
    let board = board_recording(&out, &model).unwrap();
    let input = board.to_replay_input().unwrap();
    // The streamed writer and the host's canonical replay encoder agree byte for byte.
    assert!(board.replay_bytes().unwrap() == input.encode().unwrap());

    let dir = tempfile::tempdir().unwrap();
    let input_path = dir.path().join("sim.replay");
    input.write(&input_path).unwrap();
    let elf = build_replay_firmware(&workspace_root().join(FIRMWARE_TARGET_DIR)).unwrap();
    let log_path = dir.path().join("board.log");
    let qemu = run_replay_in_qemu(&elf, &input_path, &log_path, None).unwrap();
    assert_eq!(qemu.report.imu_sample_sets, 9000);
    assert_eq!(qemu.report.pps_edges, 3);
    let decoded = decode_file(&log_path).unwrap();
    let check = check_log_against_replay(&input, &decoded);
    assert!(check.is_exact(), "{check:?}");
    assert_eq!(check.samples_exact, 9000);
}
