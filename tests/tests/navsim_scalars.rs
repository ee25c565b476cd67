//! The board's fusion filter in `f32` and in Q32.32 fixed point against `f64` on the same
//! simulated drives (`dynacal::navsim`, what `dynacal navsim` runs): through GNSS outages the
//! single-precision and the fixed-point filters navigate as the double-precision one does,
//! and none meets a number out of its range.

use dynacal::navsim::{
    run, three_unit_model, CovarianceSpread, NavSimOptions, NavSimReport, Scalar,
};
use statrs::distribution::{ChiSquared, ContinuousCDF};

fn navigate(scalar: Scalar, seed: u64) -> NavSimReport {
    let options = NavSimOptions {
        seconds: 300.0,
        seed,
        outage_s: 30.0,
        scalar,
    };
    run(&three_unit_model(), &options).expect("the drive runs")
}

/// The f64 filter's figures and another scalar's, as a table row's cells.
fn cells(r: &NavSimReport) -> String {
    format!(
        "{:.3} / {:.2} | {:.4} | {:.2} ({:.1})",
        r.position_rms_m,
        r.position_rms_outage_m,
        r.attitude_rms_deg,
        r.nees_mean,
        r.calibration_nees_mean
    )
}

/// The largest relative gap of `other`'s position error with GNSS, through outages and its
/// attitude error to `wide`'s (the f64 filter's).
fn worst_gap(wide: &NavSimReport, other: &NavSimReport) -> f64 {
    [
        (wide.position_rms_outage_m, other.position_rms_outage_m),
        (wide.position_rms_m, other.position_rms_m),
        (wide.attitude_rms_deg, other.attitude_rms_deg),
    ]
    .iter()
    .map(|(a, b)| (b - a).abs() / a)
    .fold(0.0, f64::max)
}

/// On three drives with a 30 s outage: the f32 filter's and the fixed-point filter's
/// position error through the outage, with GNSS, and their attitude error are each within
/// 10% of the f64 filter's, and no filter counts an overflow. The f64 filter is no surer of
/// the extra units' calibrations than their errors allow: their NEES (12 states) stays below
/// chi-square's 97.5% point for 12 degrees of freedom (23.3) even taken as one sample, where
/// a filter counting the calibration the running offsets hide as seen gave 36 on seed 1.
/// And no drive-off is taken for a standstill beyond the zero-velocity update's sigma.
#[test]
fn single_precision_and_fixed_point_navigate_as_double_precision_does() {
    let calibration_high = ChiSquared::new(12.0).unwrap().inverse_cdf(0.975);
    for seed in 1..=3 {
        let wide = navigate(Scalar::F64, seed);
        assert!(
            wide.position_rms_outage_m > 0.0 && wide.attitude_rms_deg > 0.0,
            "seed {seed}: {wide:?}"
        );
        assert!(
            wide.calibration_nees_mean > 0.0 && wide.calibration_nees_mean < calibration_high,
            "seed {seed}: calibration NEES {:.2}",
            wide.calibration_nees_mean
        );

        // The standstill ends before a drive-off's speed reaches the zero-velocity update's
        // sigma (with the force's departure alone it held until 0.05-0.09 m/s).
        let zupt_sigma =
            f64::from(dynacal_core::fusion::FusionConfig::at_rate(200.0).zupt_sigma_m_s);
        assert!(
            wide.still_speed_max_m_s < zupt_sigma,
            "seed {seed}: {:.3} m/s taken for a standstill",
            wide.still_speed_max_m_s
        );
        assert_eq!(wide.overflow_events, 0, "seed {seed}");
        assert_eq!(wide.outages_s, [[135.0, 165.0]]);
        for scalar in [Scalar::F32, Scalar::Fixed] {
            let other = navigate(scalar, seed);
            println!(
                "seed {seed}: f64 {}; {} {}",
                cells(&wide),
                scalar.name(),
                cells(&other)
            );
            let gap = worst_gap(&wide, &other);
            assert!(
                gap <= 0.1,
                "seed {seed}: {} strays {gap:.3} from f64",
                scalar.name()
            );
            assert_eq!(other.overflow_events, 0, "seed {seed}: {}", scalar.name());
        }
    }
}

/// The measurement behind BENCHMARKS.md's "The board's filter in each scalar": 20 seeds of
/// 600 s drives with 30 s and with 60 s outages, f64 against f32 and fixed point (a
/// measurement tool): `cargo test --release -p dynacal-tests --test navsim_scalars --
/// --ignored --nocapture`.
#[test]
#[ignore = "measurement tool: cargo test --release -p dynacal-tests --test navsim_scalars -- --ignored --nocapture"]
fn twenty_seeds_in_each_scalar() {
    println!("| outage s | seed | f64: position RMS with GNSS / in outages m, attitude RMS deg, NEES (calibrations' NEES, 12 states) | f32: the same | fixed: the same | NEES bounds | f32, fixed: largest gap to f64 | overflow events f64 / f32 / fixed |");
    println!("|---|---|---|---|---|---|---|---|");
    for outage_s in [30.0, 60.0] {
        let mut worst = [0.0f64; 2];
        let (mut inside, mut inside_independent) = ([0; 3], [0; 3]);
        let (mut spreads, mut held) = (Vec::new(), Vec::new());
        for seed in 1..=20 {
            let run = |scalar| {
                let options = NavSimOptions {
                    seconds: 600.0,
                    seed,
                    outage_s,
                    scalar,
                };
                run(&three_unit_model(), &options).expect("the drive runs")
            };
            let reports = [run(Scalar::F64), run(Scalar::F32), run(Scalar::Fixed)];
            let [wide, narrow, fixed] = &reports;
            spreads.push(wide.covariance.clone());
            held.push(fixed.covariance.clone());
            let gaps = [worst_gap(wide, narrow), worst_gap(wide, fixed)];
            for k in 0..2 {
                worst[k] = worst[k].max(gaps[k]);
            }
            for (k, r) in reports.iter().enumerate() {
                let within = |[low, high]: [f64; 2]| r.nees_mean >= low && r.nees_mean <= high;
                inside[k] += usize::from(within(r.nees_bounds));
                inside_independent[k] += usize::from(within(r.nees_bounds_independent));
            }
            println!(
                "| {outage_s} | {seed} | {} | {} | {} | [{:.2}, {:.2}] | {:.3}, {:.3} | {} / {} / {} |",
                cells(wide),
                cells(narrow),
                cells(fixed),
                wide.nees_bounds[0],
                wide.nees_bounds[1],
                gaps[0],
                gaps[1],
                wide.overflow_events,
                narrow.overflow_events,
                fixed.overflow_events
            );
        }
        println!(
            "outages of {outage_s} s: largest gap to f64 (position with GNSS, in outages, attitude) {:.3} (f32), {:.3} (fixed); NEES inside its bounds (by the filter's error correlation) on {:?} (f64, f32, fixed) of 20 seeds, inside the bounds of independent samples on {:?}",
            worst[0], worst[1], inside, inside_independent
        );
        print_spread(&spreads);
        let fold = |f: &dyn Fn(&CovarianceSpread) -> f64, max: bool| extreme(&held, f, max);
        println!(
            "  held by the fixed-point filter (scaled by each state's power of two): largest element {:.3}, smallest variance {:.3}, {:.2} decades",
            fold(&|s| s.held_largest_element, true),
            fold(&|s| s.held_smallest_variance, false),
            fold(&|s| s.held_decades, true)
        );
    }
}

/// The largest (`max`) or smallest of a figure over runs' covariance spreads.
fn extreme(
    spreads: &[CovarianceSpread],
    figure: &dyn Fn(&CovarianceSpread) -> f64,
    max: bool,
) -> f64 {
    let values = spreads.iter().map(figure);
    if max {
        values.fold(f64::NEG_INFINITY, f64::max)
    } else {
        values.fold(f64::INFINITY, f64::min)
    }
}

/// The covariance's numbers over every run (f64): each group's variances, and the decades
/// a fixed-point format would have to span, as the filter holds the covariance and scaled by
/// the sigmas it started with.
fn print_spread(spreads: &[CovarianceSpread]) {
    let fold = |f: &dyn Fn(&CovarianceSpread) -> f64, max: bool| extreme(spreads, f, max);
    for (k, (name, _)) in spreads[0].variances.iter().enumerate() {
        println!(
            "  {name}: {:.2e} to {:.2e}",
            fold(&|s| s.variances[k].1.min, false),
            fold(&|s| s.variances[k].1.max, true)
        );
    }
    println!(
        "  as held: largest element {:.2e}, smallest variance {:.2e}, {:.1} decades (worst run {:.1}); scaled by the start's sigmas: {:.2e}, {:.2e}, {:.1} decades (worst run {:.1})",
        fold(&|s| s.largest_element, true),
        fold(&|s| s.smallest_variance, false),
        (fold(&|s| s.largest_element, true) / fold(&|s| s.smallest_variance, false)).log10(),
        fold(&|s| s.decades, true),
        fold(&|s| s.scaled_largest_element, true),
        fold(&|s| s.scaled_smallest_variance, false),
        (fold(&|s| s.scaled_largest_element, true) / fold(&|s| s.scaled_smallest_variance, false))
            .log10(),
        fold(&|s| s.scaled_decades, true)
    );
}

/// Issue 25's day: the fixed-point filter over 24 h of simulated driving with a 60 s outage
/// every 300 s meets no overflow or saturation (nor a covariance reset, a failed update or
/// a restart), and navigates as through the shorter drives (a measurement tool, figures in
/// BENCHMARKS.md): `cargo test --release -p dynacal-tests --test navsim_scalars --
/// --ignored --nocapture a_day`.
#[test]
#[ignore = "a day of driving: cargo test --release -p dynacal-tests --test navsim_scalars -- --ignored --nocapture a_day"]
fn a_day_in_fixed_point_meets_no_overflow() {
    let options = NavSimOptions {
        seconds: 86_400.0,
        seed: 1,
        outage_s: 60.0,
        scalar: Scalar::Fixed,
    };
    let day = run(&three_unit_model(), &options).expect("the day runs");
    let held = &day.covariance;
    println!(
        "a day in fixed point: {} outages; {}; held covariance: largest element {:.3}, \
         smallest variance {:.3}; physical: {:.2e} to {:.2e} ({:.1} decades); overflow \
         events {}",
        day.outages_s.len(),
        cells(&day),
        held.held_largest_element,
        held.held_smallest_variance,
        held.smallest_variance,
        held.largest_element,
        held.decades,
        day.overflow_events
    );
    assert_eq!(day.overflow_events, 0);
    assert!(held.held_largest_element < 4.0 && held.held_smallest_variance >= 0.25);
    assert!(
        day.position_rms_m < 1.0 && day.attitude_rms_deg < 2.0,
        "{day:?}"
    );
}
