//! `dynacal export` as a user chains it: a static run simulated, its IMU fitted with
//! `dynacal fit`, the fitted model exported to Kalibr, PX4 and ArduPilot; and a model of
//! several IMUs refused without `--imu`, writing nothing.

use std::path::Path;
use std::process::Command;

fn dynacal(args: &[&str]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .output()
        .unwrap();
    out
}

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The value of `key: value` in a Kalibr file.
fn kalibr_value(text: &str, key: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(&format!("{key}:")))
        .and_then(|v| v.split('#').next())
        .map(|v| v.trim().parse().unwrap())
        .unwrap_or_else(|| panic!("no {key} in\n{text}"))
}

#[test]
fn a_fitted_static_run_exports_its_white_noise_to_each_tool() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name).display().to_string();
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/board-three-mems.json");
    // GIVEN 300 s of the example board's units at rest (gyro white noise 2e-5 (rad/s)^2 per
    // sample at 1 kHz, quantised in steps of 1.0652e-3 rad/s), fitted as a user fits them
    ok(&dynacal(&[
        "simulate",
        "--scenario",
        "static",
        "--seconds",
        "300",
        "--seed",
        "4",
        "--model",
        &model.display().to_string(),
        "--out",
        &d("sim"),
    ]));
    ok(&dynacal(&[
        "fit",
        &d("sim/icm0.csv"),
        "--model",
        "WN+GM",
        "--json",
        &d("fit.json"),
    ]));

    // WHEN the fitted model is exported to Kalibr
    ok(&dynacal(&[
        "export",
        &d("fit.json"),
        "--to",
        "kalibr",
        "--out",
        &d("imu.yaml"),
    ]));
    let yaml = std::fs::read_to_string(d("imu.yaml")).unwrap();

    // THEN its noise density is the truth's, quantisation included: sqrt((2e-5 + q^2/12) dt)
    let truth = ((2e-5 + 1.0652e-3f64.powi(2) / 12.0) / 1000.0).sqrt();
    let density = kalibr_value(&yaml, "gyroscope_noise_density");
    assert!(
        (density / truth - 1.0).abs() < 0.03,
        "{density} against {truth}"
    );
    assert_eq!(kalibr_value(&yaml, "update_rate"), 1000.0);
    // AND PX4's and ArduPilot's are the same density per their filters' steps
    for (format, name, step_s, sep) in [
        ("px4", "EKF2_GYR_NOISE", 0.010f64, '\t'),
        ("ardupilot", "EK3_GYRO_P_NSE", 0.012, ','),
    ] {
        let out = d(&format!("params.{format}"));
        ok(&dynacal(&[
            "export",
            &d("fit.json"),
            "--to",
            format,
            "--out",
            &out,
        ]));
        let text = std::fs::read_to_string(&out).unwrap();
        let value: f64 = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .find(|l| l.contains(name))
            .and_then(|l| {
                l.split(sep)
                    .find_map(|f| f.parse().ok().filter(|_| f.contains('e')))
            })
            .unwrap_or_else(|| panic!("no {name} in\n{text}"));
        assert!(
            (value * step_s.sqrt() / density - 1.0).abs() < 1e-5,
            "{name} {value}"
        );
    }
}

#[test]
fn a_model_of_several_imus_is_refused_without_imu_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/board-three-mems.json");
    let out_path = dir.path().join("imu.yaml");
    let out = dynacal(&[
        "export",
        &model.display().to_string(),
        "--to",
        "kalibr",
        "--out",
        &out_path.display().to_string(),
    ]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("board-three-mems.json") && stderr.contains("icm0, icm1, icm2"),
        "{stderr}"
    );
    assert!(!out_path.exists());
}
