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
        let spread = rss.iter().cloned().fold(f64::MIN, f64::max)
            - rss.iter().cloned().fold(f64::MAX, f64::min);
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
    let spread =
        rss.iter().cloned().fold(f64::MIN, f64::max) - rss.iter().cloned().fold(f64::MAX, f64::min);
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
    let lengths: Vec<u64> = match std::env::var("REGRESS_MEMORY_ROWS") {
        Ok(rows) => vec![rows.parse::<f64>().expect("a row count") as u64],
        Err(_) => vec![100_000, 1_000_000, 10_000_000],
    };
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
    let spread =
        rss.iter().cloned().fold(f64::MIN, f64::max) - rss.iter().cloned().fold(f64::MAX, f64::min);
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
    let lengths: Vec<u64> = match std::env::var("ERRORS_MEMORY_ROWS") {
        Ok(rows) => vec![rows.parse::<f64>().expect("a row count") as u64],
        Err(_) => vec![100_000, 1_000_000, 10_000_000],
    };
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
    let spread =
        rss.iter().cloned().fold(f64::MIN, f64::max) - rss.iter().cloned().fold(f64::MAX, f64::min);
    println!("`errors` streamed peak RSS spread {spread:.1} MiB");
    assert!(
        spread < 32.0,
        "`errors`'s memory grows with the length: {rss:?}"
    );
}
