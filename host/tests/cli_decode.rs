//! `dynacal decode LOG --out DIR` end to end: the binary on a generated log.

mod common;

use std::path::Path;
use std::process::Command;

use dynacal::decode::encode_log;
use dynacal::interchange::ImuRecording;
use dynacal_core::log::Frame;

fn dynacal(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .output()
        .expect("run dynacal")
}

fn decode(log: &Path, out: &Path) -> std::process::Output {
    dynacal(&[
        "decode".as_ref(),
        log.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ])
}

#[test]
fn decode_writes_bit_exact_csvs_and_summary() {
    let dir = tempfile::tempdir().unwrap();
    let frames = common::frames(11, 2);
    let mut bytes = encode_log(&frames).unwrap();
    // Damage one IMU frame in the middle: it must be counted, the rest decoded.
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x5A;
    let log = dir.path().join("board.log");
    std::fs::write(&log, &bytes).unwrap();
    let out = dir.path().join("decoded");

    let result = decode(&log, &out);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );

    let header = common::header();
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["header_found"], true);
    assert_eq!(summary["protocol_version"], 1);
    assert_eq!(summary["header"]["board"], "dynacal-test rev A");
    assert_eq!(summary["bytes_total"], bytes.len() as u64);
    assert!(summary["frames_dropped"].as_u64().unwrap() >= 1);
    assert!(summary["bytes_dropped"].as_u64().unwrap() >= 2);
    let decoded_total = summary["frames_decoded_total"].as_u64().unwrap();
    assert!(decoded_total < frames.len() as u64 && decoded_total + 2 >= frames.len() as u64);
    assert_eq!(summary["frames_decoded"]["header"], 1);
    assert_eq!(summary["frames_decoded"]["pps"], 2);

    for config in &header.imus {
        let sent: Vec<_> = frames
            .iter()
            .filter_map(|f| match f {
                Frame::Imu(s) if s.imu_id == config.imu_id => Some(*s),
                _ => None,
            })
            .collect();
        let path = out.join(format!("imu{}.csv", config.imu_id));
        let rec = ImuRecording::read(&path).unwrap();
        let imu_summary = summary["imus"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["imu_id"] == config.imu_id)
            .unwrap();
        assert_eq!(imu_summary["samples"], rec.len() as u64);
        assert!(rec.len() + 2 >= sent.len() && rec.len() <= sent.len());
        // Every row is one sent sample, scaled bit-exactly from its counts.
        let gyro = rec.gyro_rad_s.as_ref().unwrap();
        let accel = rec.accel_m_s2.as_ref().unwrap();
        let mut k = 0;
        for (row, &t_s) in rec.t_s.iter().enumerate() {
            while dynacal::decode::seconds_of_us(sent[k].t_us).to_bits() != t_s.to_bits() {
                k += 1;
            }
            for axis in 0..3 {
                let g = sent[k].gyro_counts[axis] as f64 * config.gyro_scale_rad_s_per_count;
                let a = sent[k].accel_counts[axis] as f64 * config.accel_scale_m_s2_per_count;
                assert_eq!(gyro[axis][row].to_bits(), g.to_bits());
                assert_eq!(accel[axis][row].to_bits(), a.to_bits());
            }
        }
        // 2 s at the configured rate, no gap unless the damaged frame was this IMU's.
        let missing = imu_summary["gaps"]["samples_missing"].as_u64().unwrap();
        assert_eq!(missing as usize, sent.len() - rec.len());
    }
    // Nothing but the promised files (the staging folder is gone).
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["health.json", "imu0.csv", "imu2.csv", "summary.json"]
    );
    // The board's troubles from its Health frames: episodes in time order per condition.
    let health: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("health.json")).unwrap()).unwrap();
    for episode in health.as_array().unwrap() {
        let condition = episode["condition"].as_str().unwrap();
        assert!(
            [
                "imu_fault",
                "log_backpressure",
                "pps_unlocked",
                "no_gnss_fix",
                "time_not_gps"
            ]
            .contains(&condition),
            "{episode}"
        );
        let from = episode["from_t_s"].as_f64().unwrap();
        assert!(
            episode["to_t_s"].as_f64().is_none_or(|to| to > from),
            "{episode}"
        );
        assert!(episode["reports"].as_u64().unwrap() >= 1, "{episode}");
    }
}

#[test]
fn decode_fails_without_header_or_frames_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let frames = common::frames(12, 1);
    let cases: [(&str, Vec<u8>, &str); 3] = [
        (
            "garbage.log",
            (1..=255u8).cycle().take(5000).collect(),
            "no frame",
        ),
        (
            "headless.log",
            encode_log(&frames[1..]).unwrap(),
            "no header",
        ),
        ("empty.log", Vec::new(), "no frame"),
    ];
    for (name, bytes, message) in cases {
        let log = dir.path().join(name);
        std::fs::write(&log, bytes).unwrap();
        let out = dir.path().join(format!("{name}.out"));
        let result = decode(&log, &out);
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert!(!result.status.success(), "{name} should fail");
        assert!(
            stderr.contains(name) && stderr.contains(message),
            "{stderr}"
        );
        assert!(!out.exists(), "{name}: output folder created");
    }
    let missing = dir.path().join("missing.log");
    let result = decode(&missing, &dir.path().join("m.out"));
    assert!(!result.status.success());
    assert!(String::from_utf8_lossy(&result.stderr).contains("missing.log"));
}

#[test]
fn decode_writes_the_latest_wavelet_variance_of_each_channel_in_si() {
    use dynacal::wv::{haar_wv_counts, WvOptions};
    use dynacal_core::log::{ImuSampleSet, WvFrame};
    use dynacal_core::recorder::RecorderWv;

    let header = common::header();
    let imu0 = &header.imus[0];
    let mut frames = vec![Frame::Header(header.clone())];
    let mut streams: [RecorderWv; 6] = std::array::from_fn(|_| RecorderWv::new());
    let mut counts: [Vec<i32>; 6] = Default::default();
    let snapshot_round = |streams: &[RecorderWv; 6], t_us: u64| -> Vec<Frame> {
        (0..6u8)
            .map(|channel| {
                Frame::WaveletVariance(WvFrame {
                    t_us,
                    imu_id: 0,
                    channel,
                    snapshot: streams[channel as usize].snapshot(),
                })
            })
            .collect()
    };
    let n = 3000u64;
    for k in 0..n {
        // Deterministic, non-trivial counts: a slow ramp plus a pseudo-random walk.
        let c = |ch: u64| ((k * (7919 + 13 * ch)) % 601) as i32 - 300 + (k / 7) as i32;
        let sample = ImuSampleSet {
            t_us: common::T0_US + k * 5_000,
            imu_id: 0,
            gyro_counts: [c(0), c(1), c(2)],
            accel_counts: [c(3), c(4), c(5)],
        };
        for (ch, &v) in sample
            .gyro_counts
            .iter()
            .chain(&sample.accel_counts)
            .enumerate()
        {
            streams[ch].push(v);
            counts[ch].push(v);
        }
        frames.push(Frame::Imu(sample));
        if k == n / 2 {
            // An earlier round: superseded by the last one.
            frames.extend(snapshot_round(&streams, sample.t_us));
        }
    }
    let t_last = common::T0_US + (n - 1) * 5_000;
    let mut last_round = snapshot_round(&streams, t_last);
    // A saturated level makes that channel's snapshot unusable; it is reported, not fatal.
    if let Frame::WaveletVariance(wv) = &mut last_round[5] {
        wv.snapshot.levels[2].saturated = true;
    }
    frames.extend(last_round);
    // A snapshot for an IMU the header does not list is counted and dropped.
    frames.push(Frame::WaveletVariance(WvFrame {
        t_us: t_last,
        imu_id: 9,
        channel: 0,
        snapshot: streams[0].snapshot(),
    }));

    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("wv.log");
    std::fs::write(&log, encode_log(&frames).unwrap()).unwrap();
    let out = dir.path().join("decoded");
    let result = decode(&log, &out);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["frames_decoded"]["wavelet_variance"], 13);
    assert_eq!(summary["wavelet_variance_frames"], 12);
    assert_eq!(summary["wv_frames_unknown"], 1);

    let wv: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("wv.json")).unwrap()).unwrap();
    let channels = wv.as_array().unwrap();
    assert_eq!(channels.len(), 6);
    let dt_s = 1.0 / f64::from(imu0.sample_rate_hz);
    for (ch, entry) in channels.iter().enumerate() {
        assert_eq!(entry["imu_id"], 0);
        assert_eq!(entry["channel"], ["gx", "gy", "gz", "ax", "ay", "az"][ch]);
        assert_eq!(entry["t_us"], t_last);
        assert_eq!(entry["n_samples"], n);
        if ch == 5 {
            assert!(entry["wv"].is_null());
            assert!(entry["error"].as_str().unwrap().contains("saturated"));
            continue;
        }
        assert!(entry["error"].is_null());
        let lsb = if ch < 3 {
            imu0.gyro_scale_rad_s_per_count
        } else {
            imu0.accel_scale_m_s2_per_count
        };
        let batch = haar_wv_counts(&counts[ch], lsb, dt_s, &WvOptions::default()).unwrap();
        let got = &entry["wv"];
        assert_eq!(got["scales_s"][0].as_f64().unwrap(), 2.0 * dt_s);
        // Full levels 1..=4: the batch estimator's sums, scaled by the channel's lsb^2.
        for level in 0..4 {
            let b = got["variance"][level].as_f64().unwrap();
            let h = batch.variance[level];
            assert!(
                ((b - h) / h).abs() <= 1e-12,
                "channel {ch} level {}: {b:e} vs {h:e}",
                level + 1
            );
        }
        // Decimated levels up to 2 x 2^(j-1) <= 3000 samples: level 11.
        assert_eq!(got["levels"].as_array().unwrap().len(), 11);
    }
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(names, ["imu0.csv", "summary.json", "wv.json"]);
}

/// What the board's fusion logs comes out as `nav.csv` (the simulator's `reference.csv`
/// columns first, then sigmas and biases), `noise.csv` and `faults.json`, units named by
/// their IMU ids; a log without fusion frames gets none of the three.
#[test]
fn decode_writes_the_fusions_states_noise_and_faults() {
    use dynacal_core::fusion::FUSED_LANE_ID;
    use dynacal_core::log::{FaultFrame, FilterState, NoiseFrame};
    let dir = tempfile::tempdir().unwrap();
    let mut frames = vec![Frame::Header(common::header())];
    for k in 0..5u64 {
        frames.push(Frame::Filter(FilterState {
            t_us: 1_000_000 + k * 100_000,
            imu_id: FUSED_LANE_ID,
            q_nb: [1.0, 0.0, 0.0, 0.0],
            vel_ned_m_s: [k as f32, 0.0, 0.0],
            lat_rad: 0.8,
            lon_rad: 0.1,
            h_m: 400.0,
            gyro_bias_rad_s: [1e-3; 3],
            accel_bias_m_s2: [1e-2; 3],
            attitude_sigma_rad: [0.01; 3],
            vel_sigma_m_s: [0.05; 3],
            pos_sigma_m: [0.3; 3],
            gyro_bias_sigma_rad_s: [1e-4; 3],
            accel_bias_sigma_m_s2: [1e-3; 3],
        }));
    }
    frames.push(Frame::Noise(NoiseFrame {
        t_us: 1_500_000,
        gyro_sigma_rad_s: [0.01, 0.02, 0.03],
        accel_sigma_m_s2: [0.1, 0.2, 0.3],
        in_use: 0b11_1111,
        still: false,
    }));
    frames.push(Frame::Fault(FaultFrame {
        t_us: 1_600_000,
        detected_t_us: 1_550_000,
        sensor: FaultFrame::SENSOR_ACCEL,
        unit: Some(1),
        axis: Some(2),
        kind: 4,
    }));
    let log = dir.path().join("board.log");
    std::fs::write(&log, encode_log(&frames).unwrap()).unwrap();
    let out = dir.path().join("decoded");
    let result = decode(&log, &out);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );

    let nav = std::fs::read_to_string(out.join("nav.csv")).unwrap();
    let mut lines = nav.lines();
    assert!(lines.next().unwrap().starts_with(
        "t_s,lat_rad,lon_rad,h_m,vn_m_s,ve_m_s,vd_m_s,roll_rad,pitch_rad,yaw_rad,sigma_"
    ));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 5);
    assert!(rows[3].starts_with("1.3,0.8,0.1,400,3,0,0,"), "{}", rows[3]);
    let noise = std::fs::read_to_string(out.join("noise.csv")).unwrap();
    assert_eq!(noise.lines().count(), 2);
    let header = common::header();
    let id1 = header.imus[1].imu_id;
    assert!(noise
        .lines()
        .next()
        .unwrap()
        .contains(&format!("gyro_sigma_rad_s_imu{id1}")));
    let faults: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("faults.json")).unwrap()).unwrap();
    assert_eq!(faults[0]["kind"], "bias_step");
    assert_eq!(faults[0]["sensor"], "accel");
    assert_eq!(faults[0]["imu_id"], u64::from(id1));
    assert_eq!(faults[0]["detected_t_s"], 1.55);

    // A log without the fusion's frames: none of its files.
    let plain = dir.path().join("plain.log");
    std::fs::write(&plain, encode_log(&common::frames(3, 1)).unwrap()).unwrap();
    let out2 = dir.path().join("plain");
    assert!(decode(&plain, &out2).status.success());
    for name in ["nav.csv", "noise.csv", "faults.json"] {
        assert!(!out2.join(name).exists(), "{name}");
    }
}
