//! Every output is an input where a user chains commands: `fit --json` runs in `simulate
//! --model` and refits to the same wavelet variance; the board's own wavelet variances
//! (`decode`'s `wv.json`) refit on the host into a model file the simulator runs.

mod common;

use std::path::Path;
use std::process::Command;

use dynacal::decode::encode_log;
use dynacal::model::{Channel, SimModel};
use dynacal_core::log::{Frame, Header, ImuConfig, ImuSampleSet, WvFrame, PROTOCOL_VERSION};
use dynacal_core::recorder::RecorderWv;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn dynacal(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .output()
        .expect("run dynacal");
    assert!(
        out.status.success(),
        "dynacal {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// A MEMS IMU with a white-noise-plus-Gauss-Markov gyro and a white-noise-plus-random-walk
/// accelerometer, at 100 Hz.
const MEMS_MODEL: &str = r#"{"imus": [{"name": "mems", "rate_hz": 100,
  "gyro": {"stochastic": {"model": "WN+GM", "unit": "rad/s", "sample_rate_hz": 100,
     "processes": [{"kind": "white_noise", "sigma2": 1e-5},
                   {"kind": "gauss_markov", "beta_per_s": 0.05, "sigma2": 1e-7}]}},
  "accel": {"stochastic": {"model": "WN+RW", "unit": "m/s^2", "sample_rate_hz": 100,
     "processes": [{"kind": "white_noise", "sigma2": 1e-3},
                   {"kind": "random_walk", "sigma2": 1e-9}]}}}]}"#;

/// Per channel and level: (wavelet variance, its variance) from a fit's statistics.
fn fitted_wv(fit: &serde_json::Value) -> Vec<(String, Vec<(f64, f64)>)> {
    fit["fit"]["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let wv = c["wv"].as_array().unwrap();
            let omega = c["omega"].as_array().unwrap();
            let levels = wv
                .iter()
                .zip(omega)
                .map(|(v, o)| (v.as_f64().unwrap(), 1.0 / o.as_f64().unwrap()))
                .collect();
            (c["channel"].as_str().unwrap().to_string(), levels)
        })
        .collect()
}

/// fit -> simulate -> fit: the refit's wavelet variance agrees with the first level by level
/// within their intervals. Over 6 channels and about 15 levels each, every difference must
/// be within 3.5 standard errors of the difference (a family-wise 95% bound for ~90 tests).
#[test]
fn a_fitted_model_simulates_and_refits_to_the_same_wavelet_variance() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("m.json"), MEMS_MODEL).unwrap();
    let sim = |model: &Path, seed: &str, out: &Path, format: &str| {
        dynacal(&[
            "simulate",
            "--scenario",
            "static",
            "--seconds",
            "1200",
            "--seed",
            seed,
            "--model",
            path(model),
            "--out",
            path(out),
            "--format",
            format,
        ]);
    };
    sim(&d.join("m.json"), "3", &d.join("s1"), "csv");
    dynacal(&[
        "fit",
        path(&d.join("s1/mems.csv")),
        "--json",
        path(&d.join("f1.json")),
    ]);
    // The fit output is a model file: the simulator runs it as it is.
    let model = SimModel::load(&d.join("f1.json")).unwrap();
    assert_eq!(model.imus.len(), 1);
    assert_eq!(model.imus[0].name, "mems");
    for c in Channel::ALL {
        assert!(model.imus[0].model_of(c).stochastic.is_some(), "{c}");
    }
    // The second round goes through Parquet: what `simulate` writes in it, `fit` reads.
    sim(&d.join("f1.json"), "4", &d.join("s2"), "parquet");
    dynacal(&[
        "fit",
        path(&d.join("s2/mems.parquet")),
        "--json",
        path(&d.join("f2.json")),
    ]);
    let (first, second) = (
        fitted_wv(&read_json(&d.join("f1.json"))),
        fitted_wv(&read_json(&d.join("f2.json"))),
    );
    assert_eq!(first.len(), 6);
    let mut compared = 0;
    for ((name, a), (name2, b)) in first.iter().zip(&second) {
        assert_eq!(name, name2);
        for (j, ((wa, va), (wb, vb))) in a.iter().zip(b).enumerate() {
            let z = (wa - wb) / (va + vb).sqrt();
            assert!(
                z.abs() < 3.5,
                "{name} level {}: {wa:e} vs {wb:e}, z = {z:.2}",
                j + 1
            );
            compared += 1;
        }
    }
    assert!(compared >= 80, "{compared} levels compared");
}

/// One IMU at 200 Hz whose counts are white noise of 40 counts on every channel, with the
/// board's streaming wavelet variance of each channel at the end, as the firmware logs it.
fn board_log_with_wavelet_variances(seconds: u64) -> (Vec<Frame>, f64) {
    let rate_hz = 200.0f32;
    let lsb_gyro = 1e-4;
    let header = Header {
        protocol_version: PROTOCOL_VERSION,
        board: "chain test".try_into().unwrap(),
        imus: [ImuConfig {
            imu_id: 0,
            model: "ICM-42688-P".try_into().unwrap(),
            sample_rate_hz: rate_hz,
            gyro_scale_rad_s_per_count: lsb_gyro,
            accel_scale_m_s2_per_count: 1e-3,
        }]
        .into_iter()
        .collect(),
    };
    let mut frames = vec![Frame::Header(header)];
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let noise = Normal::new(0.0f64, 40.0).unwrap();
    let mut streams: Vec<RecorderWv> = (0..6).map(|_| RecorderWv::new()).collect();
    let n = seconds * rate_hz as u64;
    let mut t_us = common::T0_US;
    for k in 0..n {
        t_us = common::T0_US + k * 5_000;
        let counts: [i32; 6] = std::array::from_fn(|_| noise.sample(&mut rng).round() as i32);
        for (s, c) in streams.iter_mut().zip(counts) {
            s.push(c);
        }
        frames.push(Frame::Imu(ImuSampleSet {
            t_us,
            imu_id: 0,
            gyro_counts: [counts[0], counts[1], counts[2]],
            accel_counts: [counts[3], counts[4], counts[5]],
        }));
    }
    for (channel, s) in streams.iter().enumerate() {
        frames.push(Frame::WaveletVariance(WvFrame {
            t_us,
            imu_id: 0,
            channel: channel as u8,
            snapshot: s.snapshot(),
        }));
    }
    // White noise of 40 counts: sigma2 in (rad/s)^2 on the gyros.
    (frames, (40.0 * lsb_gyro) * (40.0 * lsb_gyro))
}

/// decode -> fit -> simulate: the board's own wavelet variances refit on the host, and the
/// model recovers the white noise the counts carried.
#[test]
fn the_boards_wavelet_variances_refit_into_a_model_the_simulator_runs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (frames, gyro_sigma2) = board_log_with_wavelet_variances(600);
    std::fs::write(d.join("board.log"), encode_log(&frames).unwrap()).unwrap();
    dynacal(&[
        "decode",
        path(&d.join("board.log")),
        "--out",
        path(&d.join("dec")),
    ]);
    let fit_out = d.join("fit.json");
    dynacal(&[
        "fit",
        path(&d.join("dec/wv.json")),
        "--model",
        "WN",
        "--json",
        path(&fit_out),
    ]);
    let model = SimModel::load(&fit_out).unwrap();
    let spec = model.imus[0]
        .model_of(Channel::Gy)
        .stochastic
        .clone()
        .unwrap();
    let dynacal::model::Process::WhiteNoise { sigma2 } = spec.processes[0] else {
        panic!("{spec:?}");
    };
    // 120000 samples: the white-noise variance is known to about 1%.
    assert!(
        (sigma2 / gyro_sigma2 - 1.0).abs() < 0.05,
        "{sigma2:e} vs {gyro_sigma2:e}"
    );
    let fit = read_json(&fit_out);
    let parameter = &fit["fit"]["channels"][1]["parameters"][0];
    let ci = parameter["ci95"].as_array().unwrap();
    assert!(ci[0].as_f64().unwrap() <= gyro_sigma2 && gyro_sigma2 <= ci[1].as_f64().unwrap());
    dynacal(&[
        "simulate",
        "--scenario",
        "static",
        "--seconds",
        "30",
        "--model",
        path(&fit_out),
        "--out",
        path(&d.join("sim")),
    ]);
    assert!(d.join("sim/imu0.csv").exists());
}

/// diagnose -> simulate and diagnose -> diagnose --baseline: the extended model of one
/// diagnosis is a model file the simulator runs (with the mounting the calibration found)
/// and the baseline of the next diagnosis.
#[test]
fn the_extended_model_simulates_and_serves_as_the_next_baseline() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("m.json"), MEMS_MODEL).unwrap();
    dynacal(&[
        "simulate",
        "--model",
        path(&d.join("m.json")),
        "--seconds",
        "120",
        "--seed",
        "5",
        "--out",
        path(&d.join("run")),
    ]);
    let (sensor, reference) = (d.join("run/mems.csv"), d.join("run/reference.csv"));
    dynacal(&[
        "diagnose",
        "--sensor",
        path(&sensor),
        "--reference",
        path(&reference),
        "--json",
        path(&d.join("d1.json")),
        "--report",
        path(&d.join("rep")),
    ]);
    let extended = d.join("rep/extended-model.json");
    let model = SimModel::load(&extended).unwrap();
    let first = read_json(&d.join("d1.json"));
    let boresight = first["calibration"]["boresight_rad"]["value"]
        .as_array()
        .unwrap();
    for (axis, b) in boresight.iter().enumerate() {
        let deg = b.as_f64().unwrap().to_degrees();
        assert!((model.imus[0].boresight_rpy_deg[axis] - deg).abs() < 1e-12);
    }
    for c in Channel::ALL {
        assert!(model.imus[0].model_of(c).stochastic.is_some(), "{c}");
    }

    dynacal(&[
        "simulate",
        "--model",
        path(&extended),
        "--seconds",
        "30",
        "--out",
        path(&d.join("again")),
    ]);
    let again = dynacal::interchange::ImuRecording::read(&d.join("again/diagnosed.csv")).unwrap();
    assert_eq!(again.channels().len(), 6);
    assert_eq!(again.sample_rate_hz, Some(100.0));

    dynacal(&[
        "diagnose",
        "--sensor",
        path(&sensor),
        "--reference",
        path(&reference),
        "--baseline",
        path(&extended),
        "--json",
        path(&d.join("d2.json")),
    ]);
    let second = read_json(&d.join("d2.json"));
    let source = second["baseline_source"].as_str().unwrap();
    assert!(source.contains("extended-model.json"), "{source}");
}
