//! `dynacal noise` as a user chains it: a static run simulated and written as a ROS2 bag
//! (`simulate --ros2`), its noise read off the bag (`noise --kalibr --json --report`), the
//! model file exported again (`export --to kalibr`); and, ignored by default, its speed and
//! memory from bag to `imu.yaml` against the Python pipeline people run (`rosbags` +
//! `allantools`, `bench/noise_bag_peer.py`) in the same run.

mod kalibr_yaml;

use std::path::Path;
use std::process::Command;

use kalibr_yaml::kalibr_value;

fn dynacal(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(out: &std::process::Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `wv` on the shared real bag (an Xsens unit whose stamps jitter and pause): refused with
/// the place in the file, pointing to `noise --topic`, which reads a bag's stamps; nothing
/// written.
#[test]
fn wv_on_a_bags_uneven_stamps_points_to_noise() {
    let bag = dynacal::data_dir().join("ros-bags/xsens-test1.bag");
    if !bag.exists() {
        eprintln!("SKIPPED: {} not found (set DYNACAL_DATA)", bag.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("wv.json");
    let out = dynacal(&[
        "wv",
        bag.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    for expected in [
        "xsens-test1.bag",
        "column `t_s`",
        "dynacal noise",
        "--topic",
    ] {
        assert!(stderr.contains(expected), "{expected} missing: {stderr}");
    }
    assert!(!json.exists());
}

/// A static MEMS unit at 100 Hz: gyro white noise 1e-5 (rad/s)^2 and random walk 4e-11 per
/// sample, accelerometer 1e-3 and 4e-9 (m/s^2)^2.
const MODEL: &str = r#"{"imus": [{"name": "mems", "rate_hz": 100,
  "gyro": {"stochastic": {"model": "WN+RW", "unit": "rad/s", "sample_rate_hz": 100,
    "processes": [{"kind": "white_noise", "sigma2": 1e-5}, {"kind": "random_walk", "sigma2": 4e-11}]}},
  "accel": {"stochastic": {"model": "WN+RW", "unit": "m/s^2", "sample_rate_hz": 100,
    "processes": [{"kind": "white_noise", "sigma2": 1e-3}, {"kind": "random_walk", "sigma2": 4e-9}]}}}]}"#;

fn simulate_bag(dir: &Path, seconds: &str) -> String {
    let d = |name: &str| dir.join(name).display().to_string();
    std::fs::write(dir.join("model.json"), MODEL).unwrap();
    ok(&dynacal(&[
        "simulate",
        "--scenario",
        "static",
        "--seconds",
        seconds,
        "--seed",
        "5",
        "--model",
        &d("model.json"),
        "--out",
        &d("sim"),
        "--ros2",
        &d("bag"),
    ]));
    d("bag")
}

#[test]
fn a_simulated_bag_gives_kalibr_its_noise_and_the_model_exports_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name).display().to_string();
    let bag = simulate_bag(dir.path(), "1200");
    let stdout = ok(&dynacal(&[
        "noise",
        &bag,
        "--topic",
        "/mems/imu",
        "--kalibr",
        &d("imu.yaml"),
        "--json",
        &d("noise.json"),
        "--report",
        &d("report"),
    ]));
    assert!(stdout.contains("still: "), "{stdout}");
    let yaml = std::fs::read_to_string(d("imu.yaml")).unwrap();
    // The truth: N = sqrt(sigma2 / 100 Hz), K = sqrt(sigma2 x 100 Hz).
    let n_gyro = kalibr_value(&yaml, "gyroscope_noise_density");
    let n_accel = kalibr_value(&yaml, "accelerometer_noise_density");
    assert!(
        (n_gyro / 1e-5f64.sqrt() * 10.0 - 1.0).abs() < 0.05,
        "{yaml}"
    );
    assert!(
        (n_accel / 1e-3f64.sqrt() * 10.0 - 1.0).abs() < 0.05,
        "{yaml}"
    );
    let k_gyro = kalibr_value(&yaml, "gyroscope_random_walk");
    assert!(
        (k_gyro / (4e-11f64 * 100.0).sqrt() - 1.0).abs() < 0.30,
        "{yaml}"
    );
    assert!(yaml.contains("rostopic: /mems/imu"));
    let page = std::fs::read_to_string(dir.path().join("report/report.html")).unwrap();
    assert!(page.contains("<svg") && page.contains("Allan deviation"));
    // The summary says per axis what goes into imu.yaml.
    assert!(
        page.contains("s at rest in 1 stretch(es)") && page.contains("gz ("),
        "{page}"
    );
    // The model file chains into `export`, which gives Kalibr the same numbers.
    ok(&dynacal(&[
        "export",
        &d("noise.json"),
        "--to",
        "kalibr",
        "--out",
        &d("again.yaml"),
    ]));
    let again = std::fs::read_to_string(d("again.yaml")).unwrap();
    for key in [
        "gyroscope_noise_density",
        "gyroscope_random_walk",
        "accelerometer_noise_density",
        "accelerometer_random_walk",
    ] {
        assert_eq!(kalibr_value(&again, key), kalibr_value(&yaml, key), "{key}");
    }
}

/// `noise` on one IMU of the real ArduPilot log, its samples imported anew each pass
/// (`--stream always`), says and writes what the log imported whole says and writes;
/// `--stream always` on an input that cannot be read in passes fails saying so.
#[test]
fn a_flight_logs_imu_read_in_passes_gives_the_model_imported_whole() {
    let log = dynacal::data_dir().join("ardupilot-3imu-copter/log171.bin");
    if !log.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", log.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name).display().to_string();
    let log = log.display().to_string();
    let run = |mode: &str| {
        let json = d(&format!("{mode}.json"));
        let stdout = ok(&dynacal(&[
            "noise", &log, "--topic", "imu1", "--stream", mode, "--json", &json,
        ]));
        (
            stdout.replace(&json, "MODEL"),
            std::fs::read_to_string(&json).unwrap(),
        )
    };
    let (passes, passes_json) = run("always");
    let (whole, whole_json) = run("never");
    assert!(passes.contains("IMU ardupilot-log171-imu1"), "{passes}");
    assert_eq!(passes, whole);
    assert_eq!(passes_json, whole_json);

    // A folder of two logs is imported whole.
    let folder = dir.path().join("logs");
    std::fs::create_dir(&folder).unwrap();
    for name in ["a.bin", "b.bin"] {
        std::os::unix::fs::symlink(&log, folder.join(name)).unwrap();
    }
    let out = dynacal(&[
        "noise",
        &folder.display().to_string(),
        "--topic",
        "ardupilot-a-imu1",
        "--stream",
        "always",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("--stream always"),
        "{stderr}"
    );
}

/// `noise` on a bag read in passes (`--stream always`) says and writes what the bag imported
/// whole (`--stream never`) says and writes: without `--topic` (the bag surveyed in a pass of
/// its own) the same choice to make, naming the same topics; with it the same model.
#[test]
fn a_bag_read_in_passes_gives_what_it_gives_imported_whole() {
    let dir = tempfile::tempdir().unwrap();
    let bag = simulate_bag(dir.path(), "300");
    let refused = |mode: &str| {
        let out = dynacal(&["noise", &bag, "--stream", mode]);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let message = refused("always");
    assert!(
        message.contains("2 IMUs, name one with --topic: /mems/imu, /reference/imu"),
        "{message}"
    );
    assert_eq!(message, refused("never"));
    let run = |mode: &str| {
        let json = dir
            .path()
            .join(format!("{mode}.json"))
            .display()
            .to_string();
        let stdout = ok(&dynacal(&[
            "noise", &bag, "--topic", "mems-imu", "--stream", mode, "--json", &json,
        ]));
        (
            stdout.replace(&json, "MODEL"),
            std::fs::read_to_string(&json).unwrap(),
        )
    };
    // The report from the IMU's line on (the streamed topic's importer notes leave its time
    // line to the reader, which states it in that line).
    let report = |out: &str| out[out.find("IMU mems-imu").expect("the IMU's line")..].to_string();
    let (passes, passes_json) = run("always");
    let (whole, whole_json) = run("never");
    assert_eq!(report(&passes), report(&whole));
    assert_eq!(passes_json, whole_json);
}

/// Wall time and peak memory of one command, from GNU time, and whether it succeeded (a
/// peer that finds no random walk fails, after its work).
fn timed(program: &str, args: &[&str]) -> Option<(f64, f64, bool)> {
    let out = Command::new("/usr/bin/time")
        .arg("-v")
        .arg(program)
        .args(args)
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() {
        eprintln!("{program}: {}", text.lines().next().unwrap_or_default());
    }
    let field = |name: &str| {
        text.lines().find_map(|l| {
            l.trim()
                .strip_prefix(name)
                .map(str::trim)
                .map(str::to_string)
        })
    };
    let rss_kib: f64 = field("Maximum resident set size (kbytes):")?.parse().ok()?;
    let wall = field("Elapsed (wall clock) time (h:mm:ss or m:ss):")?;
    let seconds = wall.split(':').fold(0.0, |acc, part| {
        acc * 60.0 + part.parse::<f64>().unwrap_or(0.0)
    });
    Some((seconds, rss_kib / 1024.0, out.status.success()))
}

#[test]
#[ignore = "a measurement of minutes: cargo build --release -p dynacal --example imu_calib_bag && cargo test --release -p dynacal --test cli_noise -- --ignored --nocapture (with pip install -r bench/requirements.txt rosbags==0.11.9)"]
fn noise_from_a_bag_against_rosbags_and_allantools() {
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/noise_bag_peer.py");
    // The imu-calib pipeline, built beside the binary (`cargo build --release -p dynacal
    // --example imu_calib_bag` first: a test filtered to this file builds no example).
    let imu_calib = Path::new(env!("CARGO_BIN_EXE_dynacal"))
        .with_file_name("examples")
        .join("imu_calib_bag");
    println!("| IMU samples | bag MB | dynacal noise s / MiB | imu-calib (mcap crate) s / MiB | rosbags + allantools s / MiB | speed-up vs imu-calib / vs Python | memory ratio vs imu-calib / vs Python |");
    println!("|---|---|---|---|---|---|---|");
    for seconds in ["3600", "36000"] {
        let bag = simulate_bag(dir.path(), seconds);
        let storage = Path::new(&bag).join("bag_0.mcap");
        let mb = std::fs::metadata(&storage).unwrap().len() as f64 / 1e6;
        let ours = timed(
            env!("CARGO_BIN_EXE_dynacal"),
            &[
                "noise",
                &bag,
                "--topic",
                "/mems/imu",
                "--kalibr",
                &dir.path().join("ours.yaml").display().to_string(),
            ],
        )
        .unwrap();
        assert!(ours.2, "dynacal noise failed on {bag}");
        let peer = timed(
            "python3",
            &[
                &script.display().to_string(),
                &bag,
                "/mems/imu",
                &dir.path().join("peer.yaml").display().to_string(),
            ],
        );
        let rust_peer = timed(
            &imu_calib.display().to_string(),
            &[&storage.display().to_string(), "/mems/imu"],
        )
        .unwrap();
        let samples = seconds.parse::<f64>().unwrap() * 100.0;
        let failed = |ok: bool| if ok { "" } else { " (failed: no K)" };
        let (python, speed, memory) = match peer {
            Some(p) => (
                format!("{:.2} / {:.0}{}", p.0, p.1, failed(p.2)),
                format!("{:.1}x", p.0 / ours.0),
                format!("{:.2}", ours.1 / p.1),
            ),
            None => ("(not run)".into(), "-".into(), "-".into()),
        };
        println!(
            "| {samples:.0} | {mb:.0} | {:.2} / {:.0} | {:.2} / {:.0}{} | {python} | {:.1}x / {speed} | {:.2} / {memory} |",
            ours.0,
            ours.1,
            rust_peer.0,
            rust_peer.1,
            failed(rust_peer.2),
            rust_peer.0 / ours.0,
            ours.1 / rust_peer.1
        );
        std::fs::remove_dir_all(&bag).unwrap();
        std::fs::remove_dir_all(dir.path().join("sim")).unwrap();
    }
}
