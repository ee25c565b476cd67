//! Times the streamed Haar wavelet variance (`HaarWvStream`, 18 full levels, fed in blocks
//! of 2^16 samples) against the batch one (`haar_wv`) on a seeded white noise on a random
//! walk, and prints their largest relative difference over the full levels.
//!
//! `cargo run --release --example bench_stream_wv -- [N]` (default 2^25 samples)

use std::time::Instant;

use dynacal::wv::stream::HaarWvStream;
use dynacal::wv::{haar_wv, WvOptions};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .map_or(1 << 25, |a| a.parse().expect("N"));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let (noise, step) = (
        Normal::new(0.0, 1e-3).unwrap(),
        Normal::new(0.0, 1e-6).unwrap(),
    );
    let mut walk = 0.0;
    let x: Vec<f64> = (0..n)
        .map(|_| {
            walk += step.sample(&mut rng);
            0.5 + walk + noise.sample(&mut rng)
        })
        .collect();
    let start = Instant::now();
    let batch = haar_wv(&x, 0.01, &WvOptions::default()).unwrap();
    let batch_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let mut stream = HaarWvStream::new(HaarWvStream::DEFAULT_FULL_LEVELS);
    x.chunks(1 << 16).for_each(|b| stream.push_block(b));
    let streamed = stream.wavelet_variance(None, 1.0, 0.01).unwrap();
    let stream_s = start.elapsed().as_secs_f64();
    let worst = (0..HaarWvStream::DEFAULT_FULL_LEVELS as usize)
        .map(|i| (streamed.variance[i] / batch.variance[i] - 1.0).abs())
        .fold(0.0f64, f64::max);
    println!("n {n} batch {batch_s:.3} s streamed {stream_s:.3} s worst full-level relative difference {worst:.2e}");
}
