//! GMWM fit benchmark (run by bench/fit_bench.sh): generates the Table I dynamic model
//! (WN + 2 GM, 100 Hz, seeded) at N samples, writes the raw series (little-endian f64) for the
//! Python peer, and times dynacal's WV + WN+2GM fit + delta-method intervals + J-test.
//! Usage: fit_bench N OUT.f64

use std::io::Write;
use std::time::Instant;

use dynacal::gmwm::fit::{FitInput, FitOptions};
use dynacal::gmwm::inference::{analyze, ModelChoice};
use dynacal::gmwm::model::{ModelSpec, Structure};
use dynacal::wv::{haar_wv, WvOptions};
use rand::SeedableRng;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args[1].parse().expect("N");
    let truth = ModelSpec::from_json(
        r#"{"model":"WN+GM+GM","unit":"deg/s","sample_rate_hz":100,"processes":[
          {"kind":"white_noise","sigma2":0.65382},
          {"kind":"gauss_markov","beta_per_s":0.00155,"sigma2":0.00981},
          {"kind":"gauss_markov","beta_per_s":1.68012,"sigma2":0.00168}]}"#,
    )
    .unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2015);
    let x = truth.simulate(n, &mut rng);
    let mut f = std::io::BufWriter::new(std::fs::File::create(&args[2]).unwrap());
    for v in &x {
        f.write_all(&v.to_le_bytes()).unwrap();
    }
    drop(f);
    let s = Structure::parse("WN+GM+GM").unwrap();
    let t0 = Instant::now();
    let wv = haar_wv(&x, 0.01, &WvOptions::default()).unwrap();
    let t1 = Instant::now();
    let input = FitInput::from_wv(&wv).unwrap();
    let fit = analyze(
        "x",
        "deg/s",
        &input,
        &ModelChoice::Fixed(s),
        None,
        &FitOptions::default(),
    )
    .unwrap();
    let t2 = Instant::now();
    let p: Vec<String> = fit
        .parameters
        .iter()
        .filter(|p| p.name == "beta_per_s" || p.name == "sigma2")
        .map(|p| format!("{}.{}={:.5e}", p.process, p.name, p.value))
        .collect();
    println!(
        "dynacal n={n} wv_s={:.4} fit_with_intervals_s={:.4} objective={:.4e} converged={} {}",
        (t1 - t0).as_secs_f64(),
        (t2 - t1).as_secs_f64(),
        fit.objective,
        fit.converged,
        p.join(" ")
    );
}
