//! `dynacal export` as a user chains it: a static run simulated, its IMU fitted with
//! `dynacal fit`, the fitted model exported to Kalibr, PX4 and ArduPilot; and a model of
//! several IMUs refused without `--imu`, writing nothing.

mod kalibr_yaml;

use std::path::Path;
use std::process::Command;

use kalibr_yaml::kalibr_value;

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

/// The board's example model (three units at 1 kHz, mounted apart) exported as the board's
/// blob: it decodes to the model's noise and mounts, and the board's firmware under QEMU
/// runs it on a drive of that model instead of refusing it. `--imu` is refused with it.
#[test]
fn a_model_file_exports_to_the_board_blob_the_firmware_runs() {
    let dir = tempfile::tempdir().unwrap();
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/board-three-mems.json");
    let blob = dir.path().join("board-model.bin");
    let out = dynacal(&[
        "export",
        model.to_str().unwrap(),
        "--to",
        "board",
        "--out",
        blob.to_str().unwrap(),
    ]);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("3 units"));
    let read =
        dynacal_core::board_model::BoardModel::decode(&std::fs::read(&blob).unwrap()).unwrap();
    assert_eq!(read.units.len(), 3);
    // icm1: gyro WN 2e-5 (rad/s)^2 at 1 kHz, GM 2.5e-7 (rad/s)^2 over 1/0.0033 s; 3 cm
    // forward, 2 cm right of icm0.
    let u = &read.units[1];
    assert!((f64::from(u.channels[0].white_psd) - 2e-8).abs() < 1e-13);
    assert!((f64::from(u.channels[0].gauss_markov_sigma2) - 2.5e-7).abs() < 1e-12);
    assert!((f64::from(u.channels[0].gauss_markov_tau_s) - 1.0 / 0.0033).abs() < 1e-2);
    assert!((u.lever_arm_m[0] - 0.03).abs() < 1e-6 && (u.lever_arm_m[1] - 0.02).abs() < 1e-6);
    let refused = dynacal(&[
        "export",
        model.to_str().unwrap(),
        "--to",
        "board",
        "--imu",
        "icm1",
        "--out",
        dir.path().join("x.bin").to_str().unwrap(),
    ]);
    assert!(!refused.status.success() && !dir.path().join("x.bin").exists());

    if !dynacal::replay::qemu_available() {
        assert!(
            std::env::var_os("CI").is_none(),
            "qemu-system-arm is missing in CI"
        );
        eprintln!("SKIPPED the board run: qemu-system-arm not found");
        return;
    }
    let sim = dir.path().join("sim");
    ok(&dynacal(&[
        "simulate",
        "--model",
        model.to_str().unwrap(),
        "--seconds",
        "20",
        "--seed",
        "2",
        "--replay",
        "--out",
        sim.to_str().unwrap(),
    ]));
    let run = dynacal(&[
        "board",
        sim.join("board.replay").to_str().unwrap(),
        "--out",
        dir.path().join("board.log").to_str().unwrap(),
        "--model",
        blob.to_str().unwrap(),
    ]);
    ok(&run);
    let said = String::from_utf8_lossy(&run.stdout);
    let refusal = said
        .lines()
        .find(|l| l.contains("board model") && l.contains("refused"));
    assert_eq!(refusal, None, "{said}");
}
