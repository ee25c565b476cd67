//! End-to-end `dynacal compare` on error-signal files written by `dynacal errors` (the
//! paper's Table I): the error columns are channels chosen by name, the dynamics columns
//! beside them are not, and a wrong name fails naming the file and the channels there are.

use std::path::Path;
use std::process::Command;

use dynacal::error_signal::ErrorSignals;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

fn dynacal(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .arg("compare")
        .args(args)
        .output()
        .unwrap()
}

/// An error-signal file at 100 Hz whose gyro errors are white noise of `gyro_sigma_rad_s`.
fn write_errors(path: &Path, seed: u64, gyro_sigma_rad_s: f64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = 20_000;
    let mut noise = |sigma: f64| -> Vec<f64> {
        (0..n)
            .map(|_| sigma * rng.sample::<f64, _>(StandardNormal))
            .collect()
    };
    let errors = [
        Some(noise(gyro_sigma_rad_s)),
        Some(noise(gyro_sigma_rad_s)),
        Some(noise(gyro_sigma_rad_s)),
        Some(noise(0.02)),
        Some(noise(0.02)),
        Some(noise(0.02)),
    ];
    let dynamics = std::array::from_fn(|_| noise(1.0));
    ErrorSignals {
        t_s: (0..n).map(|i| i as f64 * 0.01).collect(),
        errors,
        dynamics,
        specific_force_b_m_s2: None,
    }
    .write(path)
    .unwrap();
}

#[test]
fn compares_a_chosen_error_channel_of_two_error_signal_files() {
    let dir = tempfile::tempdir().unwrap();
    let (stat, dyna) = (dir.path().join("static.csv"), dir.path().join("car.csv"));
    write_errors(&stat, 1, 1.0e-3);
    write_errors(&dyna, 2, 1.3e-3);
    let json = dir.path().join("table1.json");
    let o = dynacal(&[
        stat.to_str().unwrap(),
        dyna.to_str().unwrap(),
        "--model",
        "WN",
        "--columns",
        "gy_err_rad_s",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("channel gy_err_rad_s (WN)"), "{stdout}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let channels = v["channels"].as_array().unwrap();
    assert_eq!(channels.len(), 1, "{v}");
    assert_eq!(channels[0]["channel"], "gy_err_rad_s");
    let wn = &channels[0]["rows"][0];
    assert_eq!(wn["process"], "WN");
    assert_eq!(wn["unit"], "(rad/s)^2");
    // The white-noise variances are recovered (1e-6 and 1.69e-6 (rad/s)^2) and differ.
    let (s, d) = (
        wn["static_value"].as_f64().unwrap(),
        wn["dynamic_value"].as_f64().unwrap(),
    );
    assert!((s / 1.0e-6 - 1.0).abs() < 0.05, "{wn}");
    assert!((d / 1.69e-6 - 1.0).abs() < 0.05, "{wn}");
    assert_eq!(wn["intervals_overlap"], false, "{wn}");
}

#[test]
fn without_columns_the_six_error_channels_are_compared_and_not_the_dynamics() {
    let dir = tempfile::tempdir().unwrap();
    let (stat, dyna) = (dir.path().join("static.csv"), dir.path().join("car.csv"));
    write_errors(&stat, 3, 1.0e-3);
    write_errors(&dyna, 4, 1.0e-3);
    let json = dir.path().join("table1.json");
    let o = dynacal(&[
        stat.to_str().unwrap(),
        dyna.to_str().unwrap(),
        "--model",
        "WN",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let names: Vec<&str> = v["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["channel"].as_str().unwrap())
        .collect();
    assert_eq!(names, dynacal::error_signal::ERROR_COLUMNS);
    let units: Vec<&str> = v["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["rows"][0]["unit"].as_str().unwrap())
        .collect();
    assert_eq!(units[0], "(rad/s)^2");
    assert_eq!(units[3], "(m/s^2)^2");
}

#[test]
fn an_unknown_channel_is_named_with_the_available_ones() {
    let dir = tempfile::tempdir().unwrap();
    let (stat, dyna) = (dir.path().join("static.csv"), dir.path().join("car.csv"));
    write_errors(&stat, 5, 1.0e-3);
    write_errors(&dyna, 6, 1.0e-3);
    let json = dir.path().join("table1.json");
    let o = dynacal(&[
        stat.to_str().unwrap(),
        dyna.to_str().unwrap(),
        "--model",
        "WN",
        "--columns",
        "gy",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("static.csv") && stderr.contains("no channel `gy`"),
        "{stderr}"
    );
    assert!(stderr.contains("gy_err_rad_s"), "{stderr}");
    assert!(!json.exists(), "no output on failure");
}
