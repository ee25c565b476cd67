//! `dynacal import` end to end: the binary on the real PSINS FOG/MEMS folder, the ArduPilot
//! log, the PX4 ULog and the Xsens DOT folder, and on an unknown file and a damaged log (skips the
//! real-data parts when the data folder is absent).

use std::process::Command;

use dynacal::interchange::ImuRecording;

fn dynacal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
}

#[test]
fn import_psins_folder_writes_mems_and_fog_files_and_reports_them() {
    let input = dynacal::data_dir().join("psins-fog-mems");
    if !input.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", input.display());
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let result = dynacal()
        .arg("import")
        .arg(&input)
        .arg("--out")
        .arg(out.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(
        result.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&result.stderr)
    );
    assert!(
        stdout
            .contains("psins-fog.csv.gz: 1000 samples, 99.900 s, [attitude velocity_ned position]"),
        "{stdout}"
    );
    assert!(
        stdout.contains("psins-mems.csv.gz: 10001 samples, 100.000 s, [gx gy gz ax ay az]"),
        "{stdout}"
    );
    // The written file reads back to exactly what the library produced, and states the rate
    // estimated once from its time column.
    let written = ImuRecording::read(&out.path().join("psins-mems.csv.gz")).unwrap();
    let direct =
        dynacal::import::psins_fog_mems::read_mems(&input.join("mems_increments.csv.gz")).unwrap();
    assert_eq!(
        written,
        ImuRecording {
            sample_rate_hz: Some(100.0),
            ..direct
        }
    );
    let mut names: Vec<String> = std::fs::read_dir(out.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["psins-fog.csv.gz", "psins-mems.csv.gz"]);
}

#[test]
fn unknown_dataset_fails_with_nonzero_exit_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mystery.csv");
    std::fs::write(&path, "time,value\n0,1\n").unwrap();
    let out = dir.path().join("out");
    let result = dynacal()
        .arg("import")
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!result.status.success());
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        stderr.contains("mystery.csv") && stderr.contains("not a dataset"),
        "{stderr}"
    );
    assert!(!out.exists(), "no output folder for a failed detection");
}

/// Runs `dynacal import INPUT --out OUT`, returning success, stdout and stderr.
fn import(input: &std::path::Path, out: &std::path::Path) -> (bool, String, String) {
    let result = dynacal()
        .arg("import")
        .arg(input)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    (
        result.status.success(),
        String::from_utf8_lossy(&result.stdout).into_owned(),
        String::from_utf8_lossy(&result.stderr).into_owned(),
    )
}

/// The file names in `dir`, sorted.
fn names_in(dir: &std::path::Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn import_ardupilot_log_writes_one_file_per_imu_and_the_reference() {
    let input = dynacal::data_dir().join("ardupilot-3imu-copter/log171.bin");
    if !input.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", input.display());
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr) = import(&input, out.path());
    assert!(ok, "{stdout}{stderr}");
    assert_eq!(
        names_in(out.path()),
        [
            "ardupilot-log171-imu0.csv.gz",
            "ardupilot-log171-imu1.csv.gz",
            "ardupilot-log171-imu2.csv.gz",
            "ardupilot-log171-reference.csv.gz"
        ]
    );
    for k in 0..3 {
        let line = format!(
            "ardupilot-log171-imu{k}.csv.gz: 11916 samples, 242.601 s, [gx gy gz ax ay az]"
        );
        assert!(stdout.contains(&line), "{stdout}");
    }
    assert!(
        stdout.contains(
            "ardupilot-log171-reference.csv.gz: 1034 samples, 208.733 s, [attitude velocity_ned position]"
        ),
        "{stdout}"
    );
    let imu1 = ImuRecording::read(&out.path().join("ardupilot-log171-imu1.csv.gz")).unwrap();
    assert_eq!(imu1.sample_rate_hz, Some(50.0));
    assert_eq!((imu1.t_s[0], imu1.len()), (11.46, 11_916));
}

#[test]
fn import_px4_ulog_writes_each_imu_topic_instance_and_the_reference() {
    let input = dynacal::data_dir().join("px4-ulog/sample_log_small.ulg");
    if !input.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", input.display());
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr) = import(&input, out.path());
    assert!(ok, "{stdout}{stderr}");
    assert_eq!(
        names_in(out.path()),
        [
            "px4-sample_log_small-imu0.csv.gz",
            "px4-sample_log_small-imu1.csv.gz",
            "px4-sample_log_small-imu2.csv.gz",
            "px4-sample_log_small-reference.csv.gz",
            "px4-sample_log_small-sensor_combined.csv.gz",
            "px4-sample_log_small-vehicle_imu0.csv.gz",
            "px4-sample_log_small-vehicle_imu1.csv.gz",
            "px4-sample_log_small-vehicle_imu2.csv.gz",
        ]
    );
    for line in [
        "px4-sample_log_small-sensor_combined.csv.gz: 1298 samples, 6.496 s, [gx gy gz ax ay az]",
        "px4-sample_log_small-imu1.csv.gz: 6 samples, 5.000 s, [gx gy gz ax ay az]",
        "px4-sample_log_small-vehicle_imu2.csv.gz: 12 samples, 5.494 s, [gx gy gz ax ay az]",
        "px4-sample_log_small-reference.csv.gz: 32 samples, 6.187 s, [attitude velocity_ned position]",
    ] {
        assert!(stdout.contains(line), "{line}\n{stdout}");
    }
    // The written file reads back to what the library produced.
    let written = ImuRecording::read(
        &out.path()
            .join("px4-sample_log_small-sensor_combined.csv.gz"),
    )
    .unwrap();
    let direct = dynacal::import::px4_ulog::read(&input).unwrap().remove(0);
    assert_eq!(direct.0, "sensor_combined");
    assert_eq!(written.t_s, direct.1.t_s);
    assert_eq!(written.accel_m_s2, direct.1.accel_m_s2);
    assert_eq!(written.gyro_rad_s, direct.1.gyro_rad_s);
}

#[test]
fn damaged_ulog_fails_with_nonzero_exit_naming_the_file_and_offset() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("flight.ulg");
    // A ULog header, then a format message whose size runs past the end of the file.
    let mut bytes = b"ULog\x01\x12\x35\x01".to_vec();
    bytes.extend(0u64.to_le_bytes());
    bytes.extend([200, 0, b'F']);
    bytes.extend(b"t:uint64_t timestamp;");
    std::fs::write(&path, &bytes).unwrap();
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = import(&path, &out);
    assert!(!ok, "{stdout}");
    assert!(
        stderr.contains("flight.ulg")
            && stderr.contains(
                "byte offset 16: message 0 ('F'): truncated: a payload of 200 bytes, but the file ends after 21"
            ),
        "{stderr}"
    );
    assert!(
        !out.exists() || names_in(&out).is_empty(),
        "nothing written"
    );
}

#[test]
fn import_xsens_folder_writes_one_file_per_unit_and_skips_the_dji_record() {
    let input = dynacal::data_dir().join("xsens-dot4-quadrotor");
    if !input.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", input.display());
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr) = import(&input, out.path());
    assert!(ok, "{stdout}{stderr}");
    assert_eq!(
        names_in(out.path()),
        [
            "xsens-dot1-imu.csv.gz",
            "xsens-dot2-imu.csv.gz",
            "xsens-dot4-imu.csv.gz",
            "xsens-dot7-imu.csv.gz"
        ]
    );
    assert!(
        stdout.contains("xsens-dot7-imu.csv.gz: 22867 samples, 190.559 s, [gx gy gz ax ay az]"),
        "{stdout}"
    );
    assert!(
        stdout.contains("airdata.csv.gz (not a dataset)"),
        "{stdout}"
    );
    let dot4 = ImuRecording::read(&out.path().join("xsens-dot4-imu.csv.gz")).unwrap();
    assert_eq!((dot4.sample_rate_hz, dot4.len()), (Some(120.0), 22_859));
}

#[test]
fn damaged_log_fails_with_nonzero_exit_naming_the_file_and_offset() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crash.bin");
    // A DataFlash start (header, FMT) cut after 13 of the FMT message's 89 bytes.
    let mut bytes = vec![0xA3, 0x95, 0x80, 0x80, 89];
    bytes.extend(b"FMT\0BBnN");
    std::fs::write(&path, &bytes).unwrap();
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = import(&path, &out);
    assert!(!ok, "{stdout}");
    assert!(
        stderr.contains("crash.bin")
            && stderr.contains("byte offset 0: message 0 (FMT, 89 bytes) is truncated"),
        "{stderr}"
    );
    assert!(
        !out.exists() || names_in(&out).is_empty(),
        "nothing written"
    );
}
