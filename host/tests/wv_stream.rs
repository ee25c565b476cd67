//! `dynacal wv --stream`: a recording read once, row by row, gives the batch estimator's
//! wavelet variance (plain and gzip, floats and integer counts on large offsets), and bad
//! rows fail naming the file and the line, as the whole-file reader does.

use std::io::Write;
use std::path::Path;
use std::process::Command;

use dynacal::input::stream::{stream_wavelet_variances, NotStreamable};
use dynacal::input::InputArgs;
use dynacal::wv::stream::HaarWvStream;
use dynacal::wv::{haar_wv_counts, WaveletVariance, WvOptions};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn dynacal_wv(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .arg("wv")
        .args(args)
        .output()
        .unwrap()
}

/// Three gyro channels at 100 Hz: white noise on a random walk on a large offset as floats
/// (gx), the same as integer counts on a 1e6 offset (gy), and white noise on a 1e3 offset
/// (gz). `n` rows, the rate stated.
fn recording_text(seed: u64, n: usize) -> String {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let white = Normal::new(0.0, 1e-3).unwrap();
    let step = Normal::new(0.0, 1e-5).unwrap();
    let mut walk = 0.0f64;
    let mut text = String::from("# sample_rate_hz: 100\nt_s,gx_rad_s,gy_rad_s,gz_rad_s\n");
    for i in 0..n {
        walk += step.sample(&mut rng);
        let gx = 10.0 + walk + white.sample(&mut rng);
        let gy = 1_000_000 + ((walk + white.sample(&mut rng)) * 1e5).round() as i64;
        let gz = 1e3 + white.sample(&mut rng);
        text += &format!("{},{gx},{gy},{gz}\n", i as f64 * 0.01);
    }
    text
}

fn run_wv(input: &Path, stream: &str, json: &Path) -> serde_json::Value {
    let o = dynacal_wv(&[
        input.to_str().unwrap(),
        "--stream",
        stream,
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap()
}

fn channel(json: &serde_json::Value, name: &str) -> WaveletVariance {
    serde_json::from_value(json["channels"][name].clone()).unwrap()
}

fn assert_close(streamed: &WaveletVariance, batch: &WaveletVariance, tolerance: f64) {
    assert_eq!(streamed.levels, batch.levels);
    assert_eq!(streamed.n_coefficients, batch.n_coefficients);
    assert_eq!(streamed.n, batch.n);
    for i in 0..batch.len() {
        for (s, b) in [
            (streamed.variance[i], batch.variance[i]),
            (streamed.ci_low[i], batch.ci_low[i]),
            (streamed.ci_high[i], batch.ci_high[i]),
        ] {
            let relative = (s / b - 1.0).abs();
            assert!(relative < tolerance, "level {}: {relative:e}", i + 1);
        }
    }
}

#[test]
fn streamed_equals_batch_on_floats_and_counts_plain_and_gzip() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("imu.csv");
    let text = recording_text(21, 200_000);
    std::fs::write(&plain, &text).unwrap();
    let gz = dir.path().join("imu.csv.gz");
    let mut encoder = flate2::write::GzEncoder::new(
        std::fs::File::create(&gz).unwrap(),
        flate2::Compression::fast(),
    );
    encoder.write_all(text.as_bytes()).unwrap();
    encoder.finish().unwrap();

    let batch = run_wv(&plain, "never", &dir.path().join("batch.json"));
    let streamed = run_wv(&plain, "always", &dir.path().join("stream.json"));
    let streamed_gz = run_wv(&gz, "always", &dir.path().join("stream-gz.json"));
    assert!(batch.get("streamed").is_none());
    assert_eq!(streamed["streamed"]["full_levels"], 18);
    assert_eq!(streamed["dt_s"], batch["dt_s"]);
    for name in ["gx", "gy", "gz"] {
        assert_close(&channel(&streamed, name), &channel(&batch, name), 1e-12);
        assert_eq!(channel(&streamed_gz, name), channel(&streamed, name));
    }

    // A comment line near the end, past the fast reader's first blocks: it leaves the file to
    // the csv crate there, which starts again; the result is the same to the bit.
    let mut lines: Vec<&str> = text.lines().collect();
    let near_end = lines.len() - 1000;
    lines.insert(near_end, "# a note among the rows");
    let commented = dir.path().join("commented.csv");
    std::fs::write(&commented, lines.join("\n") + "\n").unwrap();
    let streamed_commented = run_wv(&commented, "always", &dir.path().join("c.json"));
    for name in ["gx", "gy", "gz"] {
        assert_eq!(channel(&streamed_commented, name), channel(&streamed, name));
    }
}

#[test]
fn long_float_series_with_large_mean_keeps_its_digits() {
    // GIVEN 2^21 accelerometer-like samples: 1 g in units of 1e-6 g, a random walk and
    // 1e-3 g of noise, exact integer counts; the floats are the counts times 1e-6.
    let n = 1 << 21;
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let noise = Normal::new(0.0, 1000.0).unwrap();
    let walk = Normal::new(0.0, 3.0).unwrap();
    let mut bias = 0.0f64;
    let counts: Vec<i32> = (0..n)
        .map(|_| {
            bias += walk.sample(&mut rng);
            (1_000_000.0 + bias + noise.sample(&mut rng)).round() as i32
        })
        .collect();
    // WHEN the float series is streamed with every level full
    let mut stream = HaarWvStream::new(20);
    counts.iter().for_each(|&c| stream.push(c as f64 * 1e-6));
    let streamed = stream.wavelet_variance(None, 1.0, 0.01).unwrap();
    // THEN it equals the exact integer estimator to 1e-12 at every level
    let exact = haar_wv_counts(&counts, 1e-6, 0.01, &WvOptions::default()).unwrap();
    assert_close(&streamed, &exact, 1e-12);
}

/// The error `dynacal wv` prints for `text`, streamed and loaded whole.
fn errors(text: &str) -> (String, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.csv");
    std::fs::write(&path, text).unwrap();
    let json = dir.path().join("wv.json");
    let run = |stream: &str| {
        let o = dynacal_wv(&[
            path.to_str().unwrap(),
            "--stream",
            stream,
            "--json",
            json.to_str().unwrap(),
        ]);
        assert!(!o.status.success());
        assert!(!json.exists(), "no output on failure");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    (run("always"), run("never"))
}

#[test]
fn bad_rows_fail_naming_file_and_line_as_the_batch_reader_does() {
    let good = recording_text(23, 40);
    let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
    // Lines are 1-based: the rate is line 1, the header line 2, row i is line i + 3.
    let cases: [(usize, &str, &str); 4] = [
        (9, "0.07,1,x,2", "`x` is not a finite number"),
        (12, "0.08,1,2,3", "does not increase"),
        (15, "0.12,1,2", "fields"),
        (42, "0.5,1,2,3", "evenly spaced"),
    ];
    for (line, row, what) in cases {
        let saved = std::mem::replace(&mut lines[line - 1], row.to_string());
        let text = lines.join("\n") + "\n";
        let (streamed, batch) = errors(&text);
        assert!(
            streamed.contains("bad.csv") && streamed.contains(&format!("line {line}")),
            "{streamed}"
        );
        // The whole-file reader names the same line: its time and gap checks run on the
        // column read whole, which keeps where its rows are (behind the
        // `# sample_rate_hz:` line, not counted from the header).
        assert!(
            batch.contains("bad.csv") && batch.contains(&format!("line {line}")),
            "{batch}"
        );
        assert!(
            streamed.contains(what) && batch.contains(what),
            "{streamed} / {batch}"
        );
        lines[line - 1] = saved;
    }
}

#[test]
fn a_file_without_a_rate_streams_only_with_one_given() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("norate.csv");
    let text = recording_text(24, 5000);
    std::fs::write(&path, text.split_once('\n').unwrap().1).unwrap();
    let json = dir.path().join("wv.json");
    let o = dynacal_wv(&[
        path.to_str().unwrap(),
        "--stream",
        "always",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--rate-hz"));
    let args = InputArgs {
        rate_hz: Some(100.0),
        columns: vec!["gz".into()],
        ..Default::default()
    };
    let streamed = stream_wavelet_variances(&path, &args, &WvOptions::default(), 18)
        .unwrap()
        .unwrap();
    assert_eq!(streamed.channels.len(), 1);
    assert_eq!(streamed.channels[0].channel, "gz");
    assert_eq!(streamed.channels[0].wv.n, 5000);
    let robust = WvOptions {
        robust: true,
        ..Default::default()
    };
    assert_eq!(
        stream_wavelet_variances(&path, &args, &robust, 18)
            .unwrap()
            .unwrap_err(),
        NotStreamable::Robust
    );
}

fn dynacal_fit(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .arg("fit")
        .args(args)
        .output()
        .unwrap()
}

/// The parameter values of the first channel's fit in a `dynacal fit` model file, the first
/// of each process (its variance).
fn fitted_values(json: &Path) -> Vec<(String, f64)> {
    let model: serde_json::Value = serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap();
    model["fit"]["channels"][0]["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            (
                p["process"].as_str().unwrap().to_string(),
                p["value"].as_f64().unwrap(),
            )
        })
        .fold(Vec::new(), |mut first, (process, value)| {
            if !first.iter().any(|(p, _)| *p == process) {
                first.push((process, value));
            }
            first
        })
}

/// `dynacal fit --stream always` on 2^20 + 50 000 rows (its top level decimated) recovers
/// the white noise and random walk the batch fit does, and those simulated: the fit needs
/// only the wavelet variances, which stream in bounded memory. A file that cannot be
/// streamed is refused under `always`, naming it and why.
#[test]
fn a_streamed_fit_recovers_the_batch_fit() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("long.csv");
    let (white_sigma, step_sigma) = (1e-3, 1e-5);
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let white = Normal::new(0.0, white_sigma).unwrap();
    let step = Normal::new(0.0, step_sigma).unwrap();
    let mut file = std::io::BufWriter::new(std::fs::File::create(&input).unwrap());
    writeln!(file, "# sample_rate_hz: 100\nt_s,gx_rad_s").unwrap();
    let mut walk = 0.0f64;
    for i in 0..(1usize << 20) + 50_000 {
        walk += step.sample(&mut rng);
        writeln!(
            file,
            "{:.2},{:.7e}",
            i as f64 * 0.01,
            walk + white.sample(&mut rng)
        )
        .unwrap();
    }
    file.flush().unwrap();
    drop(file);
    let fit = |stream: &str| {
        let json = dir.path().join(format!("{stream}.json"));
        let input = input.to_str().unwrap();
        let o = dynacal_fit(&[
            input,
            "--model",
            "WN+RW",
            "--stream",
            stream,
            "--json",
            json.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        fitted_values(&json)
    };
    let (streamed, batch) = (fit("always"), fit("never"));
    assert_eq!(streamed.len(), 2, "{streamed:?}");
    let truth = [
        ("WN", white_sigma * white_sigma),
        ("RW", step_sigma * step_sigma),
    ];
    for ((process, s), (_, b)) in streamed.iter().zip(&batch) {
        let want = truth.iter().find(|t| t.0 == process).unwrap().1;
        // The white noise is set by the finest levels, which are the batch estimator's.
        let (against_batch, against_truth) = if process == "WN" {
            (1e-3, 0.02)
        } else {
            (0.1, 0.2)
        };
        assert!(
            (s / b - 1.0).abs() < against_batch,
            "{process}: streamed {s:e}, batch {b:e}"
        );
        assert!(
            (s / want - 1.0).abs() < against_truth,
            "{process}: {s:e} against {want:e}"
        );
    }

    let no_rate = dir.path().join("no-rate.csv");
    std::fs::write(
        &no_rate,
        "t_s,gx_rad_s\n0,1\n0.01,2\n0.02,3\n0.03,4\n0.04,5\n",
    )
    .unwrap();
    let json = dir.path().join("refused.json");
    let o = dynacal_fit(&[
        no_rate.to_str().unwrap(),
        "--stream",
        "always",
        "--json",
        json.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("no-rate.csv") && err.contains("cannot stream"),
        "{err}"
    );
    assert!(!json.exists());
}

#[test]
fn parquet_reads_whole_and_streamed_as_its_csv_does() {
    // GIVEN a recording as CSV and the same recording written as Parquet (two row groups)
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("imu.csv");
    std::fs::write(&csv, recording_text(25, 200_000)).unwrap();
    let parquet = dir.path().join("imu.parquet");
    dynacal::interchange::ImuRecording::read(&csv)
        .unwrap()
        .write(&parquet)
        .unwrap();
    // WHEN each is read whole and streamed
    let csv_whole = run_wv(&csv, "never", &dir.path().join("a.json"));
    let csv_streamed = run_wv(&csv, "always", &dir.path().join("b.json"));
    let parquet_whole = run_wv(&parquet, "never", &dir.path().join("c.json"));
    let parquet_streamed = run_wv(&parquet, "always", &dir.path().join("d.json"));
    // THEN the Parquet file gives its CSV's wavelet variances to the bit, either way
    assert_eq!(parquet_streamed["streamed"]["full_levels"], 18);
    for name in ["gx", "gy", "gz"] {
        assert_eq!(channel(&parquet_whole, name), channel(&csv_whole, name));
        assert_eq!(
            channel(&parquet_streamed, name),
            channel(&csv_streamed, name)
        );
    }
}
