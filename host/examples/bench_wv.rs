//! Benchmark worker for `bench/wv_bench.py`: times dynacal's Haar wavelet variance on the first
//! N samples of a raw little-endian f64 file (written once by the script, read by every tool),
//! and prints one JSON object on stdout (times, peak memory, the variances, and the numerical
//! error of each prefix-sum strategy against the exact integer computation).
//!
//! It also times `input::wavelet_variance_of`, the call the Python package's `dynacal.wv`
//! makes, so that the script can state what the bindings add.
//!
//! `cargo run --release --example bench_wv -- FILE N REPEATS`
//! The series holds integer counts stored as f64, so `haar_wv_counts` gives the exact answer.

use std::time::Instant;

use dynacal::input::wavelet_variance_of;
use dynacal::wv::{haar_wv, haar_wv_counts, WvOptions};

/// VmHWM / VmRSS of this process, MiB (Linux).
fn rss_mib(field: &str) -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with(field))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// The textbook method: plain f64 cumulative sum of the raw data (no centring, no
/// compensation), then differences. Used only to measure the digits it loses.
fn naive_prefix_wv(x: &[f64], j_max: u32) -> Vec<f64> {
    let mut s = Vec::with_capacity(x.len() + 1);
    s.push(0.0);
    let mut acc = 0.0;
    for &v in x {
        acc += v;
        s.push(acc);
    }
    (1..=j_max)
        .map(|j| {
            let h = 1usize << (j - 1);
            let mut sum = 0.0;
            for k in 2 * h..=x.len() {
                let d = (s[k] - s[k - h]) - (s[k - h] - s[k - 2 * h]);
                sum += d * d;
            }
            sum / ((2 * h) as f64).powi(2) / (x.len() + 1 - 2 * h) as f64
        })
        .collect()
}

fn max_rel(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) / y).abs())
        .fold(0.0, f64::max)
}

fn time_min<T>(repeats: usize, mut f: impl FnMut() -> T) -> (f64, f64, T) {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..repeats {
        let start = Instant::now();
        let out = f();
        times.push(start.elapsed().as_secs_f64());
        last = Some(out);
    }
    times.sort_by(f64::total_cmp);
    (times[0], times[times.len() / 2], last.unwrap())
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 4 {
        eprintln!("usage: bench_wv FILE N REPEATS");
        std::process::exit(2);
    }
    let n: usize = args[2].parse().expect("N");
    let repeats: usize = args[3].parse().expect("REPEATS");
    // Read straight into the sample vector, 64 KiB at a time, so the peak memory measured
    // below is the data plus what the wavelet variance itself allocates.
    let mut file = std::io::BufReader::new(std::fs::File::open(&args[1]).expect("open series"));
    let mut x = Vec::with_capacity(n);
    let mut buf = vec![0u8; 1 << 16];
    while x.len() < n {
        let want = ((n - x.len()) * 8).min(buf.len());
        std::io::Read::read_exact(&mut file, &mut buf[..want]).expect("file shorter than N");
        x.extend(
            buf[..want]
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap())),
        );
    }
    let baseline_mib = rss_mib("VmRSS:");
    let opts = WvOptions::default();
    let dt_s = 0.01;

    let (f64_min, f64_median, wv) = time_min(repeats, || haar_wv(&x, dt_s, &opts).unwrap());
    let peak_after_f64 = rss_mib("VmHWM:");
    let counts: Vec<i32> = x.iter().map(|&v| v as i32).collect();
    let (counts_min, counts_median, exact) = time_min(repeats, || {
        haar_wv_counts(&counts, 1.0, dt_s, &opts).unwrap()
    });
    // The call `dynacal.wv` makes from Python (the counts rule on a borrowed slice): the
    // Rust time the bindings are measured against.
    let (input_min, _, _) = time_min(repeats, || {
        wavelet_variance_of((&x[..]).into(), 1.0, dt_s, &opts).unwrap()
    });
    let naive = naive_prefix_wv(&x, wv.len() as u32);
    println!(
        "{{\"n\": {n}, \"threads\": {}, \"levels\": {}, \
         \"f64_time_min_s\": {f64_min}, \"f64_time_median_s\": {f64_median}, \
         \"counts_time_min_s\": {counts_min}, \"counts_time_median_s\": {counts_median}, \
         \"input_path_time_min_s\": {input_min}, \
         \"baseline_rss_mib\": {baseline_mib}, \"peak_rss_f64_mib\": {peak_after_f64}, \
         \"f64_vs_exact_max_rel\": {}, \"naive_prefix_vs_exact_max_rel\": {}, \
         \"variance\": {:?}, \"exact_variance\": {:?}}}",
        rayon::current_num_threads(),
        wv.len(),
        max_rel(&wv.variance, &exact.variance),
        max_rel(&naive, &exact.variance),
        wv.variance,
        exact.variance,
    );
}
