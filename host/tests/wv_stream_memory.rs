//! The measurement behind "memory stays bounded on a 1e8-sample input" (issue 21, part 5):
//! seeded single-channel interchange recordings of 1e6, 1e7 and 1e8 rows are written into a
//! temporary folder (the largest about 3 GB, removed afterwards) and the release `dynacal wv`
//! and `dynacal fit --model WN+RW` are run on each under `/usr/bin/time -v`, streamed, and
//! loaded whole at 1e7 rows for comparison; and `dynacal import` is run on seeded ADIS16405
//! count files of the same lengths (the text importers convert row by row); and
//! `dynacal regress` on seeded error-signal files of 1e5, 1e6 and 1e7 rows (each row 15
//! dynamics and 3 gyro error columns; the largest about 2 GB); and `dynacal errors` on
//! seeded sensor and reference-IMU pairs of 1e5, 1e6 and 1e7 rows, streamed and loaded
//! whole. Ignored: it runs for minutes and needs the disk. Run with
//! `cargo test --release -p dynacal --test wv_stream_memory -- --ignored --nocapture`.

use std::io::Write;
use std::path::Path;
use std::process::Command;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A 100 Hz one-axis gyro: 1e-3 rad/s white noise on a random walk on a 0.5 rad/s offset.
fn write_recording(path: &Path, rows: u64) {
    let file = std::fs::File::create(path).unwrap();
    let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
    let mut rng = ChaCha8Rng::seed_from_u64(rows);
    let white = Normal::new(0.0, 1e-3).unwrap();
    let step = Normal::new(0.0, 1e-6).unwrap();
    let mut walk = 0.0;
    writeln!(out, "# sample_rate_hz: 100\nt_s,gx_rad_s").unwrap();
    for i in 0..rows {
        walk += step.sample(&mut rng);
        let gx = 0.5 + walk + white.sample(&mut rng);
        writeln!(out, "{},{gx}", i as f64 * 0.01).unwrap();
    }
    out.flush().unwrap();
}

/// A 100 Hz ADIS16405 session in integer counts (`gx,gy,gz,ax,ay,az`, no time column), at
/// rest with z down: gyro counts about 0, accelerometer z about -300 (-1 g).
fn write_adis_counts(path: &Path, rows: u64) {
    let file = std::fs::File::create(path).unwrap();
    let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
    let mut rng = ChaCha8Rng::seed_from_u64(rows);
    let noise = Normal::new(0.0f64, 3.0).unwrap();
    writeln!(out, "gx,gy,gz,ax,ay,az").unwrap();
    for _ in 0..rows {
        let mut count = || noise.sample(&mut rng).round() as i32;
        let (gx, gy, gz, ax, ay) = (count(), count(), count(), count(), count());
        writeln!(out, "{gx},{gy},{gz},{ax},{ay},{}", -300 + count()).unwrap();
    }
    out.flush().unwrap();
}

/// An error-signal file of `rows` rows at 100 Hz: 15 slowly varying dynamics columns and
/// gyro errors with a bias, one true term each (on omega_x, omega_y, a_z) and white noise,
/// printed to 7 significant digits.
fn write_error_signals(path: &Path, rows: u64) {
    let file = std::fs::File::create(path).unwrap();
    let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
    let mut rng = ChaCha8Rng::seed_from_u64(rows);
    let unit = Normal::new(0.0, 1.0).unwrap();
    let mut dynamics = [0.0f64; 15];
    let names = dynacal::error_signal::DYNAMICS_COLUMNS.join(",");
    writeln!(out, "t_s,{names},gx_err_rad_s,gy_err_rad_s,gz_err_rad_s").unwrap();
    for i in 0..rows {
        for d in &mut dynamics {
            *d = 0.999 * *d + 0.05 * unit.sample(&mut rng);
        }
        write!(out, "{}", i as f64 * 0.01).unwrap();
        for d in &dynamics {
            write!(out, ",{d:.6e}").unwrap();
        }
        let truth = [
            1e-3 + 2e-3 * dynamics[0],
            -1e-3 + 1e-3 * dynamics[1],
            5e-4 + 4e-4 * dynamics[11],
        ];
        for t in truth {
            write!(out, ",{:.6e}", t + 1e-2 * unit.sample(&mut rng)).unwrap();
        }
        writeln!(out).unwrap();
    }
    out.flush().unwrap();
}

/// Peak resident memory (MiB) and wall time (s) of `dynacal COMMAND` on `input`.
fn measure(command: &[&str], input: &Path, stream: &str, json: &Path) -> (f64, f64) {
    let args = [input.to_str().unwrap(), "--stream", stream, "--json"];
    let mut full: Vec<&str> = command.to_vec();
    full.extend(args);
    full.push(json.to_str().unwrap());
    time_dynacal(&full)
}

/// The lengths listed in the environment variable `var` (`1e6,1e7`), else `default`.
fn lengths_from_env(var: &str, default: &[u64]) -> Vec<u64> {
    match std::env::var(var) {
        Ok(list) => list
            .split(',')
            .map(|n| n.parse::<f64>().expect("a length") as u64)
            .collect(),
        Err(_) => default.to_vec(),
    }
}

/// Largest minus smallest of `values`.
fn spread(values: &[f64]) -> f64 {
    values.iter().cloned().fold(f64::MIN, f64::max)
        - values.iter().cloned().fold(f64::MAX, f64::min)
}

/// Peak resident memory (MiB) and wall time (s) of `dynacal ARGS`.
fn time_dynacal(args: &[&str]) -> (f64, f64) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_dynacal"));
    command.args(args);
    timed(command)
}

/// Peak resident memory (MiB) and wall time (s) of `command`, under `/usr/bin/time -v`.
fn timed(command: Command) -> (f64, f64) {
    let o = Command::new("/usr/bin/time")
        .arg("-v")
        .arg(command.get_program())
        .args(command.get_args())
        .envs(
            command
                .get_envs()
                .filter_map(|(k, v)| v.map(|v| (k.to_owned(), v.to_owned()))),
        )
        .output()
        .expect("/usr/bin/time (apt-get install time)");
    let report = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{report}");
    let field = |name: &str| {
        report
            .lines()
            .find_map(|l| l.trim().strip_prefix(name))
            .unwrap_or_else(|| panic!("no `{name}` in {report}"))
            .trim()
            .to_string()
    };
    let rss_mib = field("Maximum resident set size (kbytes):")
        .parse::<f64>()
        .unwrap()
        / 1024.0;
    let wall_s = field("Elapsed (wall clock) time (h:mm:ss or m:ss):")
        .split(':')
        .fold(0.0, |acc, part| acc * 60.0 + part.parse::<f64>().unwrap());
    (rss_mib, wall_s)
}

#[test]
#[ignore = "minutes and ~3 GB of temporary disk; run by hand for the benchmark"]
fn memory_is_flat_from_1e6_to_1e8_rows() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("wv.json");
    println!(
        "| rows | file MB | command | mode | peak RSS MiB | wall s |\n|---|---|---|---|---|---|"
    );
    let mut streamed_rss = vec![];
    for rows in [1_000_000u64, 10_000_000, 100_000_000] {
        let input = dir.path().join(format!("gyro-{rows}.csv"));
        write_recording(&input, rows);
        let mb = std::fs::metadata(&input).unwrap().len() as f64 / 1e6;
        let modes: &[&str] = if rows == 10_000_000 {
            &["always", "never"]
        } else {
            &["always"]
        };
        for command in [&["wv"][..], &["fit", "--model", "WN+RW"]] {
            for &mode in modes {
                let (rss, wall) = measure(command, &input, mode, &json);
                let label = if mode == "always" {
                    "streamed"
                } else {
                    "loaded whole"
                };
                let name = command.join(" ");
                println!("| {rows:.0e} | {mb:.0} | {name} | {label} | {rss:.1} | {wall:.1} |");
                if mode == "always" {
                    streamed_rss.push((name, rss));
                }
            }
        }
        // `info` streams the files over the threshold and loads the others whole.
        let (rss, wall) = time_dynacal(&["info", input.to_str().unwrap()]);
        let streamed = std::fs::metadata(&input).unwrap().len()
            > dynacal::input::stream::STREAM_THRESHOLD_BYTES;
        let label = if streamed { "streamed" } else { "loaded whole" };
        println!("| {rows:.0e} | {mb:.0} | info | {label} | {rss:.1} | {wall:.1} |");
        if streamed {
            streamed_rss.push(("info".to_string(), rss));
        }
        std::fs::remove_file(&input).unwrap();
    }
    for command in ["wv", "fit --model WN+RW", "info"] {
        let rss: Vec<f64> = streamed_rss
            .iter()
            .filter(|(name, _)| name == command)
            .map(|(_, rss)| *rss)
            .collect();
        let spread = spread(&rss);
        println!("`{command}` streamed: peak RSS spread over the streamed sizes {spread:.1} MiB");
        assert!(
            spread < 16.0,
            "`{command}`'s memory grows with the length: {rss:?}"
        );
    }
}

#[test]
#[ignore = "minutes and ~3 GB of temporary disk; run by hand for the benchmark"]
fn import_memory_is_flat_from_1e6_to_1e8_rows() {
    let dir = tempfile::tempdir().unwrap();
    println!("| rows | file MB | peak RSS MiB | wall s |\n|---|---|---|---|");
    let mut rss = vec![];
    for rows in [1_000_000u64, 10_000_000, 100_000_000] {
        let input = dir.path().join(format!("session-{rows}.csv"));
        write_adis_counts(&input, rows);
        let mb = std::fs::metadata(&input).unwrap().len() as f64 / 1e6;
        let out = dir.path().join(format!("imported-{rows}"));
        let (peak, wall) = time_dynacal(&[
            "import",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let written = out.join(format!("adis16405-session-{rows}.csv.gz"));
        assert!(written.exists(), "no {}", written.display());
        println!("| {rows:.0e} | {mb:.0} | {peak:.1} | {wall:.1} |");
        rss.push(peak);
        std::fs::remove_file(&input).unwrap();
        std::fs::remove_dir_all(&out).unwrap();
    }
    let spread = spread(&rss);
    println!("`import` peak RSS spread from 1e6 to 1e8 rows {spread:.1} MiB");
    assert!(
        spread < 16.0,
        "`import`'s memory grows with the length: {rss:?}"
    );
}

/// What `dynacal regress` did before it streamed: the whole file loaded
/// (`ErrorSignals::read`) and each channel's elimination on the loaded columns
/// (`backward_elimination`). Run as a child of [`regress_memory_is_flat_from_1e5_to_1e7_rows`]
/// (the file in `REGRESS_BATCH_INPUT`), so its peak memory is its own.
#[test]
#[ignore = "run by regress_memory_is_flat_from_1e5_to_1e7_rows"]
fn regress_loaded_whole() {
    let Ok(input) = std::env::var("REGRESS_BATCH_INPUT") else {
        return;
    };
    let signals = dynacal::error_signal::ErrorSignals::read(Path::new(&input)).unwrap();
    let regressors = signals.regressors();
    let options = dynacal::regress::RegressionOptions::default();
    for errors in signals.errors.iter().flatten() {
        dynacal::regress::backward_elimination(errors, &regressors, &options).unwrap();
    }
}

/// Peak resident memory (MiB) and wall time (s) of [`regress_loaded_whole`] on `input`.
fn time_loaded_whole(input: &Path) -> (f64, f64) {
    let mut command = Command::new(std::env::current_exe().unwrap());
    command
        .args([
            "--exact",
            "regress_loaded_whole",
            "--ignored",
            "--test-threads=1",
        ])
        .env("REGRESS_BATCH_INPUT", input);
    timed(command)
}

#[test]
#[ignore = "minutes and ~2 GB of temporary disk; run by hand for the benchmark"]
fn regress_memory_is_flat_from_1e5_to_1e7_rows() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("regress.json");
    println!(
        "| rows | file MB | streamed: peak RSS MiB | wall s | loaded whole: peak RSS MiB | wall s |\n|---|---|---|---|---|---|"
    );
    let mut rss = vec![];
    // REGRESS_MEMORY_ROWS=1e8 (say) runs that length alone, streamed only: loaded whole it
    // would need about 90 GB, and the file takes 23 GB of disk and the spill 14 GB more.
    let lengths = lengths_from_env("REGRESS_MEMORY_ROWS", &[100_000, 1_000_000, 10_000_000]);
    for rows in lengths {
        let input = dir.path().join(format!("errors-{rows}.csv"));
        write_error_signals(&input, rows);
        let mb = std::fs::metadata(&input).unwrap().len() as f64 / 1e6;
        let (peak, wall) = time_dynacal(&[
            "regress",
            input.to_str().unwrap(),
            "--json",
            json.to_str().unwrap(),
        ]);
        let (whole_peak, whole_wall) = if rows <= 10_000_000 {
            time_loaded_whole(&input)
        } else {
            (f64::NAN, f64::NAN)
        };
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let kept = |ch: &str, name: &str| {
            report[ch]["coefficients"]
                .as_array()
                .unwrap()
                .iter()
                .any(|c| c["name"] == name)
        };
        assert!(kept("gx", "omega_x") && kept("gy", "omega_y") && kept("gz", "a_z"));
        println!(
            "| {rows:.0e} | {mb:.0} | {peak:.1} | {wall:.1} | {whole_peak:.1} | {whole_wall:.1} |"
        );
        rss.push(peak);
        std::fs::remove_file(&input).unwrap();
    }
    let spread = spread(&rss);
    println!("`regress` peak RSS spread from 1e5 to 1e7 rows {spread:.1} MiB");
    assert!(
        spread < 16.0,
        "`regress`'s memory grows with the length: {rss:?}"
    );
}

/// A 100 Hz reference IMU (rates, specific force, attitude) on a turning, accelerating
/// motion, and a sensor on it: boresight (0.01, -0.02, 0.015) rad, biases, white noise.
fn write_imu_pair(sensor: &Path, reference: &Path, rows: u64) {
    let open =
        |p: &Path| std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(p).unwrap());
    let (mut s, mut r) = (open(sensor), open(reference));
    writeln!(
        s,
        "# sample_rate_hz: 100\nt_s,gx_rad_s,gy_rad_s,gz_rad_s,ax_m_s2,ay_m_s2,az_m_s2"
    )
    .unwrap();
    writeln!(
        r,
        "# sample_rate_hz: 100\nt_s,gx_rad_s,gy_rad_s,gz_rad_s,ax_m_s2,ay_m_s2,az_m_s2,roll_rad,pitch_rad,yaw_rad"
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(rows);
    let (gyro_noise, accel_noise) = (
        Normal::new(0.0, 2e-3).unwrap(),
        Normal::new(0.0, 2e-2).unwrap(),
    );
    let psi = nalgebra::Vector3::new(0.01, -0.02, 0.015);
    let c_sb = nalgebra::Rotation3::new(-psi);
    for i in 0..rows {
        let t = i as f64 * 0.01;
        let w = nalgebra::Vector3::new(
            0.3 * (0.11 * t).sin() + 0.1 * (0.7 * t + 1.0).sin(),
            0.25 * (0.13 * t + 2.0).sin() + 0.08 * (0.9 * t).sin(),
            0.5 * (0.05 * t + 1.0).sin() + 0.2 * (0.6 * t + 3.0).sin(),
        );
        let f = nalgebra::Vector3::new(
            2.0 * (0.2 * t).sin(),
            1.5 * (0.17 * t + 1.0).sin(),
            -9.81 + 0.5 * (0.8 * t).sin(),
        );
        let g = c_sb * w + nalgebra::Vector3::new(1e-3, -2e-3, 5e-4);
        let a = c_sb * f + nalgebra::Vector3::new(0.05, -0.03, 0.08);
        writeln!(
            r,
            "{t},{},{},{},{},{},{},0,0,{}",
            w.x,
            w.y,
            w.z,
            f.x,
            f.y,
            f.z,
            (0.01 * t).sin()
        )
        .unwrap();
        writeln!(
            s,
            "{t},{},{},{},{},{},{}",
            g.x + gyro_noise.sample(&mut rng),
            g.y + gyro_noise.sample(&mut rng),
            g.z + gyro_noise.sample(&mut rng),
            a.x + accel_noise.sample(&mut rng),
            a.y + accel_noise.sample(&mut rng),
            a.z + accel_noise.sample(&mut rng),
        )
        .unwrap();
    }
    s.flush().unwrap();
    r.flush().unwrap();
}

#[test]
#[ignore = "many minutes and ~4 GB of temporary disk; run by hand for the benchmark"]
fn errors_memory_is_flat_from_1e5_to_1e7_rows() {
    let dir = tempfile::tempdir().unwrap();
    let (sensor, reference, out, json) = (
        dir.path().join("sensor.csv"),
        dir.path().join("reference.csv"),
        dir.path().join("errors.csv"),
        dir.path().join("errors.json"),
    );
    println!(
        "| rows | files MB | streamed: peak RSS MiB | wall s | loaded whole: peak RSS MiB | wall s |\n|---|---|---|---|---|---|"
    );
    // ERRORS_MEMORY_ROWS=1e8 (say) runs that length alone, streamed only.
    let lengths = lengths_from_env("ERRORS_MEMORY_ROWS", &[100_000, 1_000_000, 10_000_000]);
    let mut rss = vec![];
    for rows in lengths {
        write_imu_pair(&sensor, &reference, rows);
        let mb = (std::fs::metadata(&sensor).unwrap().len()
            + std::fs::metadata(&reference).unwrap().len()) as f64
            / 1e6;
        let run = |stream: &str| {
            let measured = time_dynacal(&[
                "errors",
                "--sensor",
                sensor.to_str().unwrap(),
                "--reference",
                reference.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--json",
                json.to_str().unwrap(),
                "--stream",
                stream,
            ]);
            let summary: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
            let boresight = &summary["boresight_rad"]["value"];
            for (i, truth) in [0.01, -0.02, 0.015].into_iter().enumerate() {
                let got = boresight[i].as_f64().unwrap();
                assert!(
                    (got - truth).abs() < 1e-4,
                    "{stream}: boresight {boresight}"
                );
            }
            (measured, summary)
        };
        let ((peak, wall), streamed) = run("always");
        let ((whole_peak, whole_wall), whole) = if rows <= 10_000_000 {
            run("never")
        } else {
            ((f64::NAN, f64::NAN), streamed.clone())
        };
        assert_eq!(streamed["hac_lag"], whole["hac_lag"]);
        println!(
            "| {rows:.0e} | {mb:.0} | {peak:.1} | {wall:.1} | {whole_peak:.1} | {whole_wall:.1} |"
        );
        rss.push(peak);
    }
    let spread = spread(&rss);
    println!("`errors` streamed peak RSS spread {spread:.1} MiB");
    assert!(
        spread < 32.0,
        "`errors`'s memory grows with the length: {rss:?}"
    );
}

/// The seconds of a flight log of `samples` IMU samples at 1 kHz, and the sample times, µs
/// on the boot clock (from 10 s).
fn flight_time_us(i: u64) -> u64 {
    10_000_000 + 1_000 * i
}

/// One gyro (rad/s) and accelerometer (m/s^2) sample of a flight log's IMU at rest: white
/// noise on gravity, forward-right-down.
fn imu_at_rest(rng: &mut ChaCha8Rng) -> [f32; 6] {
    let gyro = Normal::new(0.0, 0.01).unwrap();
    let accel = Normal::new(0.0, 0.05).unwrap();
    [
        gyro.sample(rng),
        gyro.sample(rng),
        gyro.sample(rng),
        accel.sample(rng),
        accel.sample(rng),
        -9.81 + accel.sample(rng),
    ]
}

/// Little-endian bytes of a list of values.
macro_rules! le {
    ($($v:expr),* $(,)?) => {{
        let mut b: Vec<u8> = Vec::new();
        $(b.extend_from_slice(&($v).to_le_bytes());)*
        b
    }};
}

/// A seeded PX4 ULog of one IMU (`sensor_gyro` and `sensor_accel` instance 0, one chip) at
/// 1 kHz, `vehicle_attitude` at 50 Hz and 3D fixes at 5 Hz (PX4 v1.11 layouts).
fn write_ulog(path: &Path, samples: u64) {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    out.write_all(b"ULog\x01\x12\x35\x01").unwrap();
    out.write_all(&0u64.to_le_bytes()).unwrap();
    let mut message = |kind: u8, payload: &[u8]| {
        out.write_all(&(payload.len() as u16).to_le_bytes())
            .unwrap();
        out.write_all(&[kind]).unwrap();
        out.write_all(payload).unwrap();
    };
    message(b'B', &[0; 40]);
    for format in [
        "sensor_gyro:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;float temperature;uint32_t error_count;",
        "sensor_accel:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;float temperature;uint32_t error_count;",
        "vehicle_attitude:uint64_t timestamp;float[4] q;",
        "vehicle_gps_position:uint64_t timestamp;int32_t lat;int32_t lon;int32_t alt;int32_t alt_ellipsoid;float vel_n_m_s;float vel_e_m_s;float vel_d_m_s;uint8_t fix_type;bool vel_ned_valid;",
    ] {
        message(b'F', format.as_bytes());
    }
    let key = "int32_t SENS_BOARD_ROT";
    let mut param = vec![key.len() as u8];
    param.extend(key.as_bytes());
    param.extend(0i32.to_le_bytes());
    message(b'P', &param);
    for (msg_id, name) in [
        "sensor_gyro",
        "sensor_accel",
        "vehicle_attitude",
        "vehicle_gps_position",
    ]
    .iter()
    .enumerate()
    {
        message(
            b'A',
            &[&[0u8][..], &(msg_id as u16).to_le_bytes(), name.as_bytes()].concat(),
        );
    }
    let mut rng = ChaCha8Rng::seed_from_u64(samples);
    for i in 0..samples {
        let t = flight_time_us(i);
        let v = imu_at_rest(&mut rng);
        let raw = |msg_id: u16, x: &[f32]| {
            le!(
                msg_id,
                t + 300,
                t,
                0x25000au32,
                x[0],
                x[1],
                x[2],
                40.0f32,
                0u32
            )
        };
        message(b'D', &raw(0, &v[..3]));
        message(b'D', &raw(1, &v[3..]));
        if i % 20 == 0 {
            message(b'D', &le!(2u16, t, 1.0f32, 0.0f32, 0.0f32, 0.0f32));
        }
        if i % 200 == 100 {
            let mut fix = le!(
                3u16,
                t,
                634_170_612i32,
                104_082_151i32,
                50_000i32,
                90_000i32
            );
            fix.extend(le!(0.0f32, 0.0f32, 0.0f32));
            fix.extend([3u8, 1u8]);
            message(b'D', &fix);
        }
    }
    out.flush().unwrap();
}

/// A seeded ArduPilot DataFlash log (4.x layouts) of one IMU at 1 kHz, `ATT` at 10 Hz and 3D
/// fixes at 5 Hz.
fn write_dataflash(path: &Path, samples: u64) {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut fmt = |type_id: u8, name: &str, format: &str, labels: &str| {
        let sizes = format.bytes().map(|c| match c {
            b'B' => 1,
            b'f' | b'L' => 4,
            b'Q' => 8,
            b'n' => 4,
            b'N' => 16,
            b'Z' => 64,
            _ => unreachable!(),
        });
        let length = 3 + sizes.sum::<usize>() as u8;
        let pad = |s: &str, n: usize| {
            let mut b = s.as_bytes().to_vec();
            b.resize(n, 0);
            b
        };
        let mut m = vec![0xA3, 0x95, 0x80, type_id, length];
        m.extend(pad(name, 4));
        m.extend(pad(format, 16));
        m.extend(pad(labels, 64));
        out.write_all(&m).unwrap();
    };
    fmt(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns");
    fmt(
        200,
        "IMU",
        "QBffffff",
        "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
    );
    fmt(201, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw");
    fmt(
        202,
        "GPS",
        "QBLLffff",
        "TimeUS,Status,Lat,Lng,Alt,Spd,GCrs,VZ",
    );
    let mut rng = ChaCha8Rng::seed_from_u64(samples);
    for i in 0..samples {
        let t = flight_time_us(i);
        let v = imu_at_rest(&mut rng);
        let mut m = vec![0xA3, 0x95, 200];
        m.extend(le!(t, 0u8, v[0], v[1], v[2], v[3], v[4], v[5]));
        if i % 100 == 0 {
            m.extend([0xA3, 0x95, 201]);
            m.extend(le!(t, 0.5f32, -1.0f32, 45.0f32));
        }
        if i % 200 == 150 {
            m.extend([0xA3, 0x95, 202]);
            m.extend(le!(
                t,
                3u8,
                -353_640_332i32,
                1_491_647_457i32,
                590.0f32,
                0.0f32,
                0.0f32,
                0.0f32
            ));
        }
        out.write_all(&m).unwrap();
    }
    out.flush().unwrap();
}

/// What `dynacal import` did with a flight log before it walked it twice: the whole log read
/// and parsed (`ULog::read`, `DataFlashLog::read`) and converted into recordings, then written
/// row by row (the writing, whose memory is the streamed path's, left out). Run as a child of
/// [`flight_log_import_memory_is_flat`] (the log in `FLIGHT_LOG_HELD_INPUT`), so its peak
/// memory is its own.
#[test]
#[ignore = "run by flight_log_import_memory_is_flat"]
fn flight_log_held_whole() {
    use dynacal::import::{ardupilot_dataflash as df, px4_ulog};
    let Ok(input) = std::env::var("FLIGHT_LOG_HELD_INPUT") else {
        return;
    };
    let input = Path::new(&input);
    let samples = if input.extension().is_some_and(|e| e == "ulg") {
        let log = px4_ulog::ULog::read(input).unwrap();
        let imus = px4_ulog::read_sensor_imus(&log).unwrap();
        assert!(px4_ulog::read_reference(&log).unwrap().is_some());
        imus[0].1.len()
    } else {
        let log = df::DataFlashLog::read(input).unwrap();
        let imus = df::read_imus(&log).unwrap();
        assert!(df::read_reference(&log).unwrap().is_some());
        imus[&0].len()
    };
    assert!(samples > 0);
}

/// `FLIGHT_LOG_SAMPLES=1e6,1e7,1e8` sets the lengths (1e6 and 1e7 by default; the logs
/// held whole only up to 1e7), `FLIGHT_LOG_FORMAT=csv` the output's form (Parquet by default).
#[test]
#[ignore = "minutes and ~2 GB of temporary disk; run by hand for the benchmark"]
fn flight_log_import_memory_is_flat() {
    let dir = tempfile::tempdir().unwrap();
    println!(
        "| log | IMU samples | file MB | walked twice: peak RSS MiB | wall s | held whole: peak RSS MiB | wall s |\n|---|---|---|---|---|---|---|"
    );
    let lengths = lengths_from_env("FLIGHT_LOG_SAMPLES", &[1_000_000, 10_000_000]);
    let mut rss: Vec<(&str, f64)> = vec![];
    for samples in lengths {
        for (kind, extension) in [("ULog", "ulg"), ("DataFlash", "bin")] {
            let input = dir.path().join(format!("flight-{samples}.{extension}"));
            match kind {
                "ULog" => write_ulog(&input, samples),
                _ => write_dataflash(&input, samples),
            }
            let mb = std::fs::metadata(&input).unwrap().len() as f64 / 1e6;
            let out = dir.path().join(format!("imported-{samples}"));
            let format = std::env::var("FLIGHT_LOG_FORMAT").unwrap_or("parquet".into());
            let (peak, wall) = time_dynacal(&[
                "import",
                input.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--format",
                &format,
            ]);
            let written: Vec<String> = std::fs::read_dir(&out)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            assert_eq!(written.len(), 2, "an IMU and the reference: {written:?}");
            let (held_peak, held_wall) = if samples <= 10_000_000 {
                let mut command = Command::new(std::env::current_exe().unwrap());
                command
                    .args([
                        "--exact",
                        "flight_log_held_whole",
                        "--ignored",
                        "--test-threads=1",
                    ])
                    .env("FLIGHT_LOG_HELD_INPUT", &input);
                timed(command)
            } else {
                (f64::NAN, f64::NAN)
            };
            println!(
                "| {kind} | {samples:.0e} | {mb:.0} | {peak:.1} | {wall:.1} | {held_peak:.1} | {held_wall:.1} |"
            );
            rss.push((kind, peak));
            std::fs::remove_file(&input).unwrap();
            std::fs::remove_dir_all(&out).unwrap();
        }
    }
    for kind in ["ULog", "DataFlash"] {
        let peaks: Vec<f64> = rss.iter().filter(|r| r.0 == kind).map(|r| r.1).collect();
        let range = spread(&peaks);
        println!("`import` of a {kind} log: peak RSS spread {range:.1} MiB");
        assert!(
            range < 64.0,
            "`import`'s memory grows with the {kind} log: {peaks:?}"
        );
    }
}

#[test]
#[ignore = "minutes and ~2 GB of temporary disk; run by hand for the benchmark"]
fn flight_log_noise_memory_is_flat() {
    let dir = tempfile::tempdir().unwrap();
    println!(
        "| log | IMU samples | file MB | read in passes: peak RSS MiB | wall s | imported whole: peak RSS MiB | wall s |\n|---|---|---|---|---|---|---|"
    );
    let lengths = lengths_from_env("FLIGHT_LOG_SAMPLES", &[1_000_000, 10_000_000]);
    let mut rss: Vec<(&str, f64)> = vec![];
    for samples in lengths {
        for (kind, extension, prefix) in [("ULog", "ulg", "px4"), ("DataFlash", "bin", "ardupilot")]
        {
            let input = dir.path().join(format!("flight-{samples}.{extension}"));
            match kind {
                "ULog" => write_ulog(&input, samples),
                _ => write_dataflash(&input, samples),
            }
            let mb = std::fs::metadata(&input).unwrap().len() as f64 / 1e6;
            let topic = format!("{prefix}-flight-{samples}-imu0");
            let run = |mode: &str| {
                let json = dir.path().join(format!("noise-{mode}.json"));
                let measured = time_dynacal(&[
                    "noise",
                    input.to_str().unwrap(),
                    "--topic",
                    &topic,
                    "--stream",
                    mode,
                    "--json",
                    json.to_str().unwrap(),
                ]);
                (measured, std::fs::read_to_string(&json).unwrap())
            };
            let ((peak, wall), passes) = run("always");
            let ((whole_peak, whole_wall), whole) = if samples <= 10_000_000 {
                run("never")
            } else {
                ((f64::NAN, f64::NAN), passes.clone())
            };
            assert_eq!(passes, whole, "{kind} {samples}: the same model both ways");
            println!(
                "| {kind} | {samples:.0e} | {mb:.0} | {peak:.1} | {wall:.1} | {whole_peak:.1} | {whole_wall:.1} |"
            );
            rss.push((kind, peak));
            std::fs::remove_file(&input).unwrap();
        }
    }
    for kind in ["ULog", "DataFlash"] {
        let peaks: Vec<f64> = rss.iter().filter(|r| r.0 == kind).map(|r| r.1).collect();
        let range = spread(&peaks);
        println!("`noise` on a {kind} log: peak RSS spread {range:.1} MiB");
    }
}

/// What a bag's import held before it read the bag in two passes: every topic's samples
/// collected into recordings (`ros_bag::read`). Run as a child of
/// [`bag_import_memory_is_flat`] (the bag's storage file in `BAG_HELD_INPUT`).
#[test]
#[ignore = "run by bag_import_memory_is_flat"]
fn bag_read_whole() {
    let Ok(input) = std::env::var("BAG_HELD_INPUT") else {
        return;
    };
    let (recordings, _) = dynacal::import::ros_bag::read(Path::new(&input)).unwrap();
    assert!(recordings.len() >= 3);
}

/// `dynacal import` of ROS2 bags (MCAP) of static runs of the three-unit 1 kHz example
/// model (`simulate --ros2`: three MEMS IMUs at 1 kHz, the reference IMU and its odometry at
/// 200 Hz, fixes at 10 Hz). `BAG_SECONDS=600,6000` sets the runs' lengths.
#[test]
#[ignore = "minutes and ~10 GB of temporary disk; run by hand for the benchmark"]
fn bag_import_memory_is_flat() {
    let dir = tempfile::tempdir().unwrap();
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/three-mems-1khz.json");
    println!(
        "| run s | IMU samples | bag MB | two passes: peak RSS MiB | wall s | read whole: peak RSS MiB | wall s |\n|---|---|---|---|---|---|---|"
    );
    let lengths = lengths_from_env("BAG_SECONDS", &[300, 3000]);
    let mut rss = vec![];
    for seconds in lengths {
        let (sim, bag) = (dir.path().join("sim"), dir.path().join("bag"));
        time_dynacal(&[
            "simulate",
            "--scenario",
            "static",
            "--seconds",
            &seconds.to_string(),
            "--seed",
            "1",
            "--model",
            model.to_str().unwrap(),
            "--out",
            sim.to_str().unwrap(),
            "--ros2",
            bag.to_str().unwrap(),
        ]);
        std::fs::remove_dir_all(&sim).unwrap();
        let storage = std::fs::read_dir(&bag)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.extension().is_some_and(|e| e == "mcap"))
            .expect("the bag's MCAP file");
        let mb = std::fs::metadata(&storage).unwrap().len() as f64 / 1e6;
        let out = dir.path().join("imported");
        let (peak, wall) = time_dynacal(&[
            "import",
            bag.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--format",
            "parquet",
        ]);
        let mut command = Command::new(std::env::current_exe().unwrap());
        command
            .args(["--exact", "bag_read_whole", "--ignored", "--test-threads=1"])
            .env("BAG_HELD_INPUT", &storage);
        let (held_peak, held_wall) = timed(command);
        let samples = seconds * 3 * 1000;
        println!("| {seconds} | {samples:.1e} | {mb:.0} | {peak:.1} | {wall:.1} | {held_peak:.1} | {held_wall:.1} |");
        rss.push(peak);
        std::fs::remove_dir_all(&bag).unwrap();
        std::fs::remove_dir_all(&out).unwrap();
    }
    println!("`import` of a bag: peak RSS spread {:.1} MiB", spread(&rss));
}
