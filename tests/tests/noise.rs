//! `dynacal noise` as its users chain it: a static run simulated from a model with known
//! white noise and random walk, written as a ROS2 bag (`simulate --ros2`), read back and
//! analysed; the bag's round trip through the importer; the errors a user meets. The model
//! choice over many seeds and lengths is an ignored measurement (`noise_model_choice`, its
//! rates in BENCHMARKS.md).

use std::path::Path;

use dynacal::export::imu_noise;
use dynacal::gmwm::model::ModelSpec;
use dynacal::import::ros_bag;
use dynacal::input::stream::StreamMode;
use dynacal::interchange::ImuRecording;
use dynacal::noise::{analyse, choose_imu, kalibr_yaml, model_of, ImuSource, NoiseOptions};
use dynacal::sim::{self, Scenario, SimModel, SimOptions};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Per-sample variances at 100 Hz: gyro white noise 1e-5 (rad/s)^2 and random walk 4e-11
/// (N = 3.16e-4 rad/s/sqrt(Hz), K = 6.32e-5 rad/s^2/sqrt(Hz)); accelerometer 1e-3 and 4e-9.
const RATE_HZ: f64 = 100.0;
const GYRO: (f64, f64) = (1e-5, 4e-11);
const ACCEL: (f64, f64) = (1e-3, 4e-9);

fn model() -> SimModel {
    let channel = |unit: &str, (wn, rw): (f64, f64)| {
        serde_json::json!({"stochastic": {"model": "WN+RW", "unit": unit, "sample_rate_hz": RATE_HZ,
            "processes": [{"kind": "white_noise", "sigma2": wn}, {"kind": "random_walk", "sigma2": rw}]}})
    };
    serde_json::from_value(serde_json::json!({"imus": [{
        "name": "mems", "rate_hz": RATE_HZ,
        "gyro": channel("rad/s", GYRO), "accel": channel("m/s^2", ACCEL)}]}))
    .unwrap()
}

fn density(sigma2: f64) -> f64 {
    (sigma2 / RATE_HZ).sqrt()
}
fn walk(sigma2: f64) -> f64 {
    (sigma2 * RATE_HZ).sqrt()
}

fn simulate_static_bag(dir: &Path, seconds: f64, seed: u64) -> std::path::PathBuf {
    let opts = SimOptions {
        scenario: Scenario::Static,
        seconds,
        seed,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    let out = sim::simulate(&model(), &opts, &|_| ()).unwrap();
    let bag = dir.join("static-bag");
    sim::ros2::write_ros2_bag(&out, &bag).unwrap();
    bag
}

#[test]
fn noise_of_a_simulated_static_bag_recovers_its_white_noise_and_random_walk() {
    let dir = tempfile::tempdir().unwrap();
    let bag = simulate_static_bag(dir.path(), 1800.0, 7);
    let mut chosen = choose_imu(&bag, Some("/mems/imu"), StreamMode::Auto).unwrap();
    assert_eq!(chosen.name, "mems-imu");
    assert!(
        matches!(chosen.source, ImuSource::Bag(_)),
        "a bag's topic is streamed"
    );
    let report = chosen.analyse(&NoiseOptions::default()).unwrap();
    // The topic streamed from the bag gives what the topic imported whole gives.
    let (recordings, _) = ros_bag::read(&bag.join("static-bag_0.mcap")).unwrap();
    let whole = &recordings.iter().find(|r| r.0 == "mems-imu").unwrap().1;
    let in_memory = analyse("mems-imu", whole, &NoiseOptions::default()).unwrap();
    assert_eq!(report.sampling, in_memory.sampling);
    assert_eq!(report.stillness, in_memory.stillness);
    for (s, m) in report.axes.iter().zip(&in_memory.axes) {
        assert_eq!(s.fit.model, m.fit.model);
        for (a, b) in s.wv.variance.iter().zip(&m.wv.variance) {
            assert!((a / b - 1.0).abs() < 1e-12, "{}: {a} vs {b}", s.channel);
        }
        assert!((s.noise_density.0 / m.noise_density.0 - 1.0).abs() < 1e-9);
    }
    assert_eq!(
        report.stillness.still.len(),
        1,
        "a static run is still throughout"
    );
    assert!(report.stillness.moving.is_empty());
    // What Kalibr gets, per axis (a slow Gauss-Markov bias exported as its random walk).
    let exported = imu_noise(&model_of(&report).unwrap(), None, &bag).unwrap();
    for (sensor, (wn, rw)) in [(&exported.gyro, GYRO), (&exported.accel, ACCEL)] {
        for (axis, (n, k)) in sensor.axes.iter().enumerate() {
            let (n_err, k_err) = (n / density(wn) - 1.0, k / walk(rw) - 1.0);
            assert!(n_err.abs() < 0.05, "axis {axis}: N {n} vs {}", density(wn));
            assert!(k_err.abs() < 0.30, "axis {axis}: K {k} vs {}", walk(rw));
        }
    }
    let yaml = kalibr_yaml(&report, chosen.topic.as_deref(), "bag").unwrap();
    assert!(yaml.contains("rostopic: /mems/imu\n"), "{yaml}");
    assert!(yaml.contains("update_rate: 100.0"), "{yaml}");
}

/// What `simulate --ros2` writes, imported again: the IMU topics equal the interchange
/// recordings (axes turned twice), the odometry gives back the reference's attitude and
/// velocity, and stamps are the simulation's time plus the stated epoch.
#[test]
fn a_simulated_drive_written_as_a_ros2_bag_imports_back() {
    let dir = tempfile::tempdir().unwrap();
    let mut model = model();
    model.imus[0].rate_hz = RATE_HZ;
    let opts = SimOptions {
        scenario: Scenario::Car,
        seconds: 20.0,
        seed: 3,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    let out = sim::simulate(&model, &opts, &|_| ()).unwrap();
    let bag = dir.path().join("drive");
    sim::ros2::write_ros2_bag(&out, &bag).unwrap();
    assert!(bag.join("metadata.yaml").exists());
    let storage = bag.join("drive_0.mcap");
    let (recordings, _) = ros_bag::read(&storage).unwrap();
    let get = |name: &str| &recordings.iter().find(|r| r.0 == name).unwrap().1;
    let epoch = sim::ros2::ROS_EPOCH_S as f64;
    let same_times = |a: &ImuRecording, b: &ImuRecording| {
        a.len() == b.len()
            && a.t_s
                .iter()
                .zip(&b.t_s)
                .all(|(x, y)| (x - epoch - y).abs() < 1e-6)
    };
    let mems = get("mems-imu");
    assert!(same_times(mems, &out.imus[0].recording));
    assert_eq!(mems.gyro_rad_s, out.imus[0].recording.gyro_rad_s);
    assert_eq!(mems.accel_m_s2, out.imus[0].recording.accel_m_s2);
    let reference = &out.reference.recording;
    let odometry = get("reference-odometry");
    assert!(same_times(odometry, reference));
    let (att, vel) = (
        odometry.attitude_rad.as_ref().unwrap(),
        odometry.velocity_ned_m_s.as_ref().unwrap(),
    );
    let (att0, vel0) = (
        reference.attitude_rad.as_ref().unwrap(),
        reference.velocity_ned_m_s.as_ref().unwrap(),
    );
    for k in 0..reference.len() {
        for axis in 0..3 {
            let mut d = att[axis][k] - att0[axis][k];
            d -= (d / std::f64::consts::TAU).round() * std::f64::consts::TAU;
            assert!(d.abs() < 1e-9, "attitude {axis} at {k}: {d}");
            assert!(
                (vel[axis][k] - vel0[axis][k]).abs() < 1e-9,
                "velocity {axis} at {k}"
            );
        }
    }
    let fixes = get("gnss-fix");
    let gnss = out.gnss.as_ref().unwrap();
    assert_eq!(fixes.len(), gnss.t_s.len());
    let position = fixes.position.as_ref().unwrap();
    assert!((position[0][3] - gnss.position[0][3]).abs() < 1e-15);
}

#[test]
fn noise_refuses_what_is_not_an_imu_naming_the_topic() {
    let dir = tempfile::tempdir().unwrap();
    let bag = simulate_static_bag(dir.path(), 5.0, 1);
    let several = choose_imu(&bag, None, StreamMode::Auto)
        .err()
        .unwrap()
        .to_string();
    assert!(
        several.contains("2 IMUs, name one with --topic: /mems/imu, /reference/imu"),
        "{several}"
    );
    let odometry = choose_imu(&bag, Some("/reference/odometry"), StreamMode::Auto)
        .err()
        .unwrap()
        .to_string();
    assert!(
        odometry.contains("topic /reference/odometry holds attitude, velocity_ned, not IMU data"),
        "{odometry}"
    );
    let missing = choose_imu(&bag, Some("/nothing"), StreamMode::Auto)
        .err()
        .unwrap()
        .to_string();
    assert!(
        missing.contains("no topic or sensor /nothing; its IMUs: /mems/imu, /reference/imu"),
        "{missing}"
    );
    // Five seconds at rest: white noise only, and no imu.yaml without a random walk.
    let mut chosen = choose_imu(&bag, Some("/mems/imu"), StreamMode::Auto).unwrap();
    let report = chosen.analyse(&NoiseOptions::default()).unwrap();
    assert!(report
        .axes
        .iter()
        .all(|a| a.fit.model == "WN" && a.random_walk.is_none() && a.bias_instability.is_none()));
    assert!(kalibr_yaml(&report, None, "bag").is_err());
}

/// One axis of one seed: the chosen structure, N within 5%, N's interval holding the
/// truth, K within 30%, K's interval holding the truth's, the truth named among the close
/// alternatives where it was not chosen.
type Outcome = (String, bool, bool, bool, bool, bool);

/// The rates of the model choice of `noise` (BENCHMARKS.md, "Model choice of `dynacal
/// noise`"): static recordings of three axes at 100 Hz whose truth is white noise + random
/// walk, or white noise + a Gauss-Markov bias (tau 30 s) + random walk, 1 h, 3 h and 10 h,
/// 50 seeds each: how often the chosen structure is the truth, and how often the exported
/// noise density and random walk (the Kalibr values; a Gauss-Markov bias as the random walk
/// of its driving noise, for the truth as for the fit) fall within 5% and 30% of the
/// truth's, and the noise density's interval holds it.
#[test]
#[ignore = "a measurement of several minutes in release: cargo test --release -p dynacal-tests --test noise -- --ignored --nocapture"]
fn noise_model_choice() {
    use rayon::prelude::*;
    let (wn, rw) = (1e-5, 4e-11);
    let truths = [
        (
            "WN+RW",
            serde_json::json!([{"kind": "white_noise", "sigma2": wn}, {"kind": "random_walk", "sigma2": rw}]),
        ),
        (
            "WN+RW+GM",
            serde_json::json!([{"kind": "white_noise", "sigma2": wn}, {"kind": "random_walk", "sigma2": rw},
            {"kind": "gauss_markov", "beta_per_s": 1.0 / 30.0, "sigma2": 4e-7}]),
        ),
    ];
    println!("| truth | hours | axes | truth chosen | chosen instead | truth named close where not chosen | N within 5% | N interval holds truth | K within 30% | K interval holds truth |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (name, processes) in &truths {
        let spec: ModelSpec = serde_json::from_value(serde_json::json!({
            "model": name, "unit": "rad/s", "sample_rate_hz": RATE_HZ, "processes": processes}))
        .unwrap();
        for hours in [1.0, 3.0, 10.0] {
            let n = (hours * 3600.0 * RATE_HZ) as usize;
            let results: Vec<Outcome> = (1..=50u64)
                .into_par_iter()
                .flat_map_iter(|seed| {
                    let mut rng = ChaCha8Rng::seed_from_u64(seed * 1000 + hours as u64);
                    let gyro = std::array::from_fn(|_| spec.simulate(n, &mut rng));
                    let rec = ImuRecording {
                        t_s: (0..n).map(|k| k as f64 / RATE_HZ).collect(),
                        gyro_rad_s: Some(gyro),
                        ..Default::default()
                    };
                    let report = analyse("sim", &rec, &NoiseOptions::default()).unwrap();
                    // The random walk Kalibr gets: a Gauss-Markov bias as its driving noise.
                    let exported = gyro_only_walks(&report);
                    let truth_walk = exported_walk_of(&spec);
                    report
                        .axes
                        .iter()
                        .zip(exported)
                        .map(|(a, k)| {
                            let n_ok = (a.noise_density.0 / density(wn) - 1.0).abs() < 0.05;
                            let n_ci = a
                                .noise_density
                                .1
                                .is_some_and(|[lo, hi]| lo <= density(wn) && density(wn) <= hi);
                            let k_ci = a
                                .random_walk
                                .and_then(|r| r.1)
                                .is_some_and(|[lo, hi]| lo <= truth_walk && truth_walk <= hi);
                            let named = a.fit.model == *name
                                || a.close_alternatives.iter().any(|c| c.0 == *name);
                            (
                                a.fit.model.clone(),
                                n_ok,
                                n_ci,
                                (k / truth_walk - 1.0).abs() < 0.30,
                                k_ci,
                                named,
                            )
                        })
                        .collect::<Vec<_>>()
                })
                .collect();
            let total = results.len();
            let share = |f: &dyn Fn(&Outcome) -> bool| {
                results.iter().filter(|r| f(r)).count() as f64 / total as f64
            };
            let mut others: std::collections::BTreeMap<&str, usize> = Default::default();
            for r in results.iter().filter(|r| r.0 != *name) {
                *others.entry(&r.0).or_default() += 1;
            }
            let wrong = results.iter().filter(|r| r.0 != *name).count();
            let named = results.iter().filter(|r| r.0 != *name && r.5).count();
            println!(
                "| {name} | {hours} | {total} | {:.3} | {others:?} | {named} of {wrong} | {:.3} | {:.3} | {:.3} | {:.3} |",
                share(&|r| r.0 == *name),
                share(&|r| r.1),
                share(&|r| r.2),
                share(&|r| r.3),
                share(&|r| r.4)
            );
        }
    }
}

/// The random walk the export gives for `spec` itself (the board's and Kalibr's reduction:
/// a Gauss-Markov bias of a second or more counts as the random walk of its driving noise).
fn exported_walk_of(spec: &ModelSpec) -> f64 {
    let (noise, _) = dynacal::refit::channel_noise(spec);
    let mut psd = f64::from(noise.random_walk_psd);
    if noise.gauss_markov_tau_s > 0.0 {
        psd += 2.0 * f64::from(noise.gauss_markov_sigma2) / f64::from(noise.gauss_markov_tau_s);
    }
    psd.sqrt()
}

/// Each gyro axis' exported random walk, through the same reduction as `export` (the
/// recording has no accelerometer, so the model is completed with the gyro's for the call).
fn gyro_only_walks(report: &dynacal::noise::NoiseReport) -> Vec<f64> {
    let mut model = model_of(report).unwrap();
    let imu = &mut model.imus[0];
    imu.accel = imu.gyro.clone();
    for (k, c) in ["ax", "ay", "az"].iter().enumerate() {
        let gyro = imu
            .channels
            .get(&["gx", "gy", "gz"][k].parse().unwrap())
            .cloned();
        if let Some(g) = gyro {
            imu.channels.insert(c.parse().unwrap(), g);
        }
    }
    imu_noise(&model, None, Path::new("sim"))
        .unwrap()
        .gyro
        .axes
        .iter()
        .map(|a| a.1)
        .collect()
}

/// `dynacal noise` against the tools people use, on the same simulated static recordings in
/// one run (BENCHMARKS.md, "Against the peers"): the Rust crate `imu-calib` (0.3.1, its
/// streaming Allan estimator and Kalibr slope fits), and through `bench/noise_peers.py` the
/// Python package `allan-variance-analyzer` (1.0.4) and `allantools` with the slope lines of
/// `allan_variance_ros`'s analysis. Six axes of white noise + random walk at 100 Hz, 10
/// seeds of 1 h and of 10 h; the error of each exported noise density and random walk
/// against the truth, per tool.
#[test]
#[ignore = "a measurement of a few minutes in release, with Python peers: pip install -r bench/requirements.txt allan-variance-analyzer==1.0.4; cargo test --release -p dynacal-tests --test noise -- --ignored --nocapture noise_against_peers"]
fn noise_against_peers() {
    use imu_calib::allan::{AllanConfig, AllanEstimator, Sensor};
    use std::collections::BTreeMap;
    use std::io::Write as _;
    let dir = tempfile::tempdir().unwrap();
    let spec = |unit: &str, (wn, rw): (f64, f64)| -> ModelSpec {
        serde_json::from_value(serde_json::json!({"model": "WN+RW", "unit": unit, "sample_rate_hz": RATE_HZ,
            "processes": [{"kind": "white_noise", "sigma2": wn}, {"kind": "random_walk", "sigma2": rw}]}))
        .unwrap()
    };
    let (accel, gyro) = (spec("m/s^2", ACCEL), spec("rad/s", GYRO));
    let truth = |axis: usize| {
        if axis < 3 {
            (density(ACCEL.0), walk(ACCEL.1))
        } else {
            (density(GYRO.0), walk(GYRO.1))
        }
    };
    // Per (hours, tool): per recording, per axis [ax ay az gx gy gz] (N, K); None where the
    // tool gave no value.
    type Values = Vec<[(Option<f64>, Option<f64>); 6]>;
    let mut results: BTreeMap<(u32, String), Values> = BTreeMap::new();
    let mut files: Vec<(u32, std::path::PathBuf)> = Vec::new();
    for hours in [1u32, 10] {
        let n = (f64::from(hours) * 3600.0 * RATE_HZ) as usize;
        for seed in 1..=10u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed * 7919 + u64::from(hours));
            let series: [Vec<f64>; 6] = std::array::from_fn(|axis| {
                if axis < 3 {
                    accel.simulate(n, &mut rng)
                } else {
                    gyro.simulate(n, &mut rng)
                }
            });
            let rec = ImuRecording {
                t_s: (0..n).map(|k| k as f64 / RATE_HZ).collect(),
                accel_m_s2: Some([series[0].clone(), series[1].clone(), series[2].clone()]),
                gyro_rad_s: Some([series[3].clone(), series[4].clone(), series[5].clone()]),
                ..Default::default()
            };
            let report = analyse("sim", &rec, &NoiseOptions::default()).unwrap();
            let exported = imu_noise(&model_of(&report).unwrap(), None, Path::new("sim")).unwrap();
            let ours: [(Option<f64>, Option<f64>); 6] = std::array::from_fn(|axis| {
                let (n, k) = if axis < 3 {
                    exported.accel.axes[axis]
                } else {
                    exported.gyro.axes[axis - 3]
                };
                (Some(n), (k > 0.0).then_some(k))
            });
            results
                .entry((hours, "dynacal noise".into()))
                .or_default()
                .push(ours);
            let mut est = AllanEstimator::with_rate(AllanConfig::default(), RATE_HZ).unwrap();
            for (k, t) in rec.t_s.iter().enumerate() {
                let at = |axis: usize| series[axis][k];
                est.push(*t, [at(0), at(1), at(2)], [at(3), at(4), at(5)]);
            }
            let calib = est.finish().ok();
            let per_axis = |sensor: Sensor, walk: bool| -> [Option<f64>; 3] {
                let values = calib.as_ref().and_then(|c| {
                    if walk {
                        c.random_walk_per_axis(sensor).ok()
                    } else {
                        c.noise_density_per_axis(sensor).ok()
                    }
                });
                std::array::from_fn(|a| values.map(|v| v[a]))
            };
            let (an, ak, gn, gk) = (
                per_axis(Sensor::Accel, false),
                per_axis(Sensor::Accel, true),
                per_axis(Sensor::Gyro, false),
                per_axis(Sensor::Gyro, true),
            );
            results
                .entry((hours, "imu-calib 0.3.1".into()))
                .or_default()
                .push(std::array::from_fn(|axis| {
                    if axis < 3 {
                        (an[axis], ak[axis])
                    } else {
                        (gn[axis - 3], gk[axis - 3])
                    }
                }));
            let path = dir.path().join(format!("h{hours}-s{seed}.f64"));
            let mut out = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
            for k in 0..n {
                for s in &series {
                    out.write_all(&s[k].to_le_bytes()).unwrap();
                }
            }
            out.flush().unwrap();
            files.push((hours, path));
        }
    }
    let json_path = dir.path().join("peers.json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/noise_peers.py");
    let status = std::process::Command::new("python3")
        .arg(&script)
        .arg(RATE_HZ.to_string())
        .arg(&json_path)
        .args(files.iter().map(|f| &f.1))
        .status();
    match status {
        Ok(s) if s.success() => {
            let peers: serde_json::Value = serde_json::from_slice(&std::fs::read(&json_path).unwrap()).unwrap();
            for (hours, path) in &files {
                for (tool, values) in peers[path.to_str().unwrap()].as_object().unwrap() {
                    let get = |key: &str, axis: usize| values[key][axis].as_f64().filter(|v| v.is_finite() && *v > 0.0);
                    results.entry((*hours, tool.clone())).or_default().push(std::array::from_fn(|axis| (get("N", axis), get("K", axis))));
                }
            }
        }
        other => eprintln!("SKIP the Python peers ({other:?}): pip install -r bench/requirements.txt allan-variance-analyzer==1.0.4"),
    }
    println!("| hours | tool | gyro N: median / max error | accel N: median / max error | gyro K: median / max error | accel K: median / max error | K not given |");
    println!("|---|---|---|---|---|---|---|");
    for ((hours, tool), values) in &results {
        let column = |gyro: bool, walk: bool| -> String {
            let mut errors: Vec<f64> = values
                .iter()
                .flat_map(|v| {
                    (0..6)
                        .filter(move |a| (*a >= 3) == gyro)
                        .map(move |a| (a, v[a]))
                })
                .filter_map(|(a, (n, k))| {
                    let (tn, tk) = truth(a);
                    if walk {
                        k.map(|k| (k / tk - 1.0).abs())
                    } else {
                        n.map(|n| (n / tn - 1.0).abs())
                    }
                })
                .collect();
            if errors.is_empty() {
                return "-".into();
            }
            errors.sort_by(f64::total_cmp);
            format!(
                "{:.1}% / {:.1}%",
                100.0 * errors[errors.len() / 2],
                100.0 * errors[errors.len() - 1]
            )
        };
        let missing = values
            .iter()
            .flat_map(|v| v.iter())
            .filter(|(_, k)| k.is_none())
            .count();
        println!(
            "| {hours} | {tool} | {} | {} | {} | {} | {missing} of {} |",
            column(true, false),
            column(false, false),
            column(true, true),
            column(false, true),
            values.len() * 6
        );
    }
}
