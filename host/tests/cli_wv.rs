//! End-to-end `dynacal wv`: the JSON it writes equals the library's wavelet variance, and bad
//! input fails naming the file, line and column, leaving no output behind.

use std::path::Path;
use std::process::Command;

use dynacal::wv::{haar_wv, haar_wv_counts, WvOptions};

fn dynacal(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .arg("wv")
        .args(args)
        .output()
        .unwrap()
}

fn write(path: &Path, text: &str) {
    std::fs::write(path, text).unwrap();
}

#[test]
fn generic_csv_with_time_column() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("in.csv");
    let (a, b): (Vec<f64>, Vec<i32>) = (0..600)
        .map(|i| (((i * 7919) % 101) as f64 * 0.013 + 2.5, (i * 31) % 17 - 8))
        .unzip();
    let mut text = String::from("t_s,temp,rate,counts\n");
    for i in 0..600 {
        text += &format!("{},{},{},{}\n", i as f64 * 0.02, 21, a[i], b[i]);
    }
    write(&csv, &text);
    let out = dir.path().join("wv.json");
    let o = dynacal(&[
        csv.to_str().unwrap(),
        "--columns",
        "rate,counts",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let channels = json["channels"].as_object().unwrap();
    assert_eq!(channels.len(), 2);
    let expected_rate = haar_wv(&a, 0.02, &WvOptions::default()).unwrap();
    let expected_counts = haar_wv_counts(&b, 1.0, 0.02, &WvOptions::default()).unwrap();
    for (name, expected) in [("rate", expected_rate), ("counts", expected_counts)] {
        let got: dynacal::wv::WaveletVariance =
            serde_json::from_value(channels[name].clone()).unwrap();
        assert_eq!(got.n, 600);
        assert_eq!(got.levels, expected.levels);
        for i in 0..got.len() {
            assert!((got.variance[i] / expected.variance[i] - 1.0).abs() < 1e-12);
            assert!((got.dt_s - 0.02).abs() < 1e-15);
        }
        assert_eq!(got.allan_variance.len(), got.variance.len());
    }
}

#[test]
fn no_time_column_needs_rate_and_errors_name_place() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("adis_like.csv");
    let mut text = String::from("gx,gy\n");
    for i in 0..300 {
        text += &format!("{},{}\n", (i * 13) % 7 - 3, (i * 5) % 11);
    }
    write(&csv, &text);
    let out = dir.path().join("wv.json");
    let o = dynacal(&[csv.to_str().unwrap(), "--json", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--rate"));
    assert!(!out.exists());

    let o = dynacal(&[
        csv.to_str().unwrap(),
        "--rate",
        "100",
        "--max-level",
        "5",
        "--robust",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(
        json["channels"]["gy"]["levels"].as_array().unwrap().len(),
        5
    );
    assert_eq!(json["channels"]["gx"]["robust"], true);
    assert_eq!(json["dt_s"], 0.01);

    // Per-channel scale: variances scale by its square, the other channel is untouched.
    let scaled = dir.path().join("scaled.json");
    let o = dynacal(&[
        csv.to_str().unwrap(),
        "--rate",
        "100",
        "--max-level",
        "5",
        "--robust",
        "--scale",
        "gy=0.5",
        "--json",
        scaled.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(&scaled).unwrap()).unwrap();
    for i in 0..5 {
        let ratio = s["channels"]["gy"]["variance"][i].as_f64().unwrap()
            / json["channels"]["gy"]["variance"][i].as_f64().unwrap();
        assert!((ratio - 0.25).abs() < 1e-12, "{ratio}");
        assert_eq!(
            s["channels"]["gx"]["variance"][i],
            json["channels"]["gx"]["variance"][i]
        );
    }

    // A bad field: the error names file, line and column, and the old output stays intact.
    let before = std::fs::read(&out).unwrap();
    let last_line = text[..text.len() - 1].rfind('\n').unwrap() + 1;
    text.replace_range(last_line.., "x,1\n");
    write(&csv, &text);
    let o = dynacal(&[
        csv.to_str().unwrap(),
        "--rate",
        "100",
        "--json",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success());
    assert!(
        err.contains("line 301") && err.contains("`gx`") && err.contains("adis_like.csv"),
        "{err}"
    );
    assert_eq!(std::fs::read(&out).unwrap(), before);

    let o = dynacal(&[
        csv.to_str().unwrap(),
        "--rate",
        "100",
        "--columns",
        "gz",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("no channel `gz`"));
}

#[test]
fn interchange_file_channels_in_si_units() {
    use dynacal::interchange::ImuRecording;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.csv");
    let n = 512;
    let t_s: Vec<f64> = (0..n).map(|i| i as f64 * 0.005).collect();
    let wave = |k: usize| -> Vec<f64> {
        (0..n)
            .map(|i| ((i * (7 + k)) % 23) as f64 * 1e-3 + 0.1 * k as f64)
            .collect()
    };
    let rec = ImuRecording {
        t_s,
        gyro_rad_s: Some([wave(0), wave(1), wave(2)]),
        accel_m_s2: None,
        attitude_rad: None,
        position: None,
        velocity_ned_m_s: None,
        single_axis: Vec::new(),
        sample_rate_hz: None,
    };
    rec.write(&path).unwrap();
    let out = dir.path().join("wv.json");
    let o = dynacal(&[path.to_str().unwrap(), "--json", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let channels = json["channels"].as_object().unwrap();
    assert_eq!(channels.keys().collect::<Vec<_>>(), ["gx", "gy", "gz"]);
    let reread = ImuRecording::read(&path).unwrap();
    let expected = haar_wv(reread.channel("gy").unwrap(), 0.005, &WvOptions::default()).unwrap();
    let got: dynacal::wv::WaveletVariance = serde_json::from_value(channels["gy"].clone()).unwrap();
    for i in 0..expected.len() {
        assert!((got.variance[i] / expected.variance[i] - 1.0).abs() < 1e-9);
        assert!((got.scales_s[i] / expected.scales_s[i] - 1.0).abs() < 1e-9);
    }
    // Asking for a channel the file lacks names it.
    let o = dynacal(&[
        path.to_str().unwrap(),
        "--columns",
        "ax",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("no channel `ax`"));
}

#[test]
fn adis_session1_through_cli_reproduces_reference() {
    let data = dynacal::data_dir();
    let session = data.join("adis16405/session1.csv.gz");
    let golden = data.join("golden/smac_wavelet_variance.json");
    if !session.exists() || !golden.exists() {
        println!("SKIP: {} or {} absent", session.display(), golden.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("adis.json");
    let o = dynacal(&[
        session.to_str().unwrap(),
        "--raw",
        "--rate",
        "100",
        "--scale",
        "gx=0.05,gy=0.05,gz=0.05,ax=0.00333,ay=0.00333,az=0.00333",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let reference = dynacal::wv::read_smac_golden(&golden).unwrap();
    let mut checked = 0;
    for g in reference.iter().filter(|g| g.sensor_key == "adis") {
        let key = g.channel_key().unwrap();
        let got: dynacal::wv::WaveletVariance =
            serde_json::from_value(json["channels"][key].clone()).unwrap();
        assert_eq!(got.levels, g.wv.levels);
        for (ours, theirs) in [
            (&got.variance, &g.wv.variance),
            (&got.ci_low, &g.wv.ci_low),
            (&got.ci_high, &g.wv.ci_high),
            (&got.scales_s, &g.wv.scales_s),
        ] {
            for (a, b) in ours.iter().zip(theirs) {
                assert!(((a - b) / b).abs() < 1e-9, "{key}: {a} vs {b}");
            }
        }
        checked += 1;
    }
    assert_eq!(checked, 6);
}

#[test]
fn known_dataset_is_imported_in_si_units() {
    let session = dynacal::data_dir().join("adis16405/session1.csv.gz");
    if !session.exists() {
        println!("SKIP: {} absent", session.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (si, raw) = (dir.path().join("si.json"), dir.path().join("raw.json"));
    let o = dynacal(&[
        session.to_str().unwrap(),
        "--columns",
        "gz",
        "--json",
        si.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = dynacal(&[
        session.to_str().unwrap(),
        "--raw",
        "--rate",
        "100",
        "--columns",
        "gz",
        "--json",
        raw.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let si: serde_json::Value = serde_json::from_slice(&std::fs::read(&si).unwrap()).unwrap();
    let raw: serde_json::Value = serde_json::from_slice(&std::fs::read(&raw).unwrap()).unwrap();
    // Imported: rad/s (0.05 deg/s per count) and t = row / 100 s; raw: counts^2.
    let rad_per_count = 0.05f64.to_radians();
    assert!((si["dt_s"].as_f64().unwrap() - 0.01).abs() < 1e-12);
    for i in 0..18 {
        let ratio = si["channels"]["gz"]["variance"][i].as_f64().unwrap()
            / raw["channels"]["gz"]["variance"][i].as_f64().unwrap();
        assert!(
            (ratio / rad_per_count.powi(2) - 1.0).abs() < 1e-9,
            "level {}: {ratio}",
            i + 1
        );
    }
}

/// A binary dataset (the ArduPilot log) is recognised before its bytes are read as CSV: its
/// uneven logger timing is then refused for the wavelet variance, naming the file and the
/// sample, instead of a CSV encoding error.
#[test]
fn a_binary_log_is_recognised_and_its_uneven_timing_named() {
    let log = dynacal::data_dir().join("ardupilot-3imu-copter/log171.bin");
    if !log.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", log.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("wv.json");
    let out = dynacal(&[log.to_str().unwrap(), "--json", json.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("log171.bin") && err.contains("evenly spaced"),
        "{err}"
    );
    assert!(!json.exists());
}
