//! The board's fusion filter in `f32` against `f64` on the same simulated drives
//! (`dynacal::navsim`, what `dynacal navsim` runs): through GNSS outages the single-precision
//! filter navigates as the double-precision one does, and neither meets a number out of its
//! range.

use dynacal::navsim::{run, three_unit_model, NavSimOptions, NavSimReport, Scalar};

fn navigate(scalar: Scalar, seed: u64) -> NavSimReport {
    let options = NavSimOptions {
        seconds: 300.0,
        seed,
        outage_s: 30.0,
        scalar,
    };
    run(&three_unit_model(), &options).expect("the drive runs")
}

/// On three drives with a 30 s outage: the f32 filter's position error through the outage,
/// with GNSS, and its attitude error are each within 10% of the f64 filter's, and both
/// filters count no overflow.
#[test]
fn single_precision_navigates_as_double_precision_does() {
    for seed in 1..=3 {
        let (wide, narrow) = (navigate(Scalar::F64, seed), navigate(Scalar::F32, seed));
        println!(
            "seed {seed}: f64 {:.3} / {:.3} m, {:.4} deg, NEES {:.2} {:?}; f32 {:.3} / {:.3} m, {:.4} deg, NEES {:.2}",
            wide.position_rms_m,
            wide.position_rms_outage_m,
            wide.attitude_rms_deg,
            wide.nees_mean,
            wide.nees_bounds,
            narrow.position_rms_m,
            narrow.position_rms_outage_m,
            narrow.attitude_rms_deg,
            narrow.nees_mean
        );
        for (what, a, b) in [
            (
                "position in outages",
                wide.position_rms_outage_m,
                narrow.position_rms_outage_m,
            ),
            (
                "position with GNSS",
                wide.position_rms_m,
                narrow.position_rms_m,
            ),
            ("attitude", wide.attitude_rms_deg, narrow.attitude_rms_deg),
        ] {
            assert!(a > 0.0 && a.is_finite(), "seed {seed}: f64 {what} {a}");
            assert!(
                (b - a).abs() <= 0.1 * a,
                "seed {seed}: {what}: f32 {b} against f64 {a}"
            );
        }
        assert_eq!(wide.overflow_events, 0, "seed {seed}");
        assert_eq!(narrow.overflow_events, 0, "seed {seed}");
        assert_eq!(wide.outages_s, [[135.0, 165.0]]);
    }
}

/// The measurement behind BENCHMARKS.md's "The board's filter in each scalar": 20 seeds of
/// 600 s drives with 30 s and with 60 s outages, f64 against f32 (a measurement tool):
/// `cargo test -p dynacal-tests --test navsim_scalars -- --ignored --nocapture` (the dev
/// profile is optimised).
#[test]
#[ignore = "measurement tool: cargo test -p dynacal-tests --test navsim_scalars -- --ignored --nocapture"]
fn twenty_seeds_in_each_scalar() {
    println!("| outage s | seed | f64: position RMS with GNSS / in outages m | f64: attitude RMS deg | f64: NEES [bounds] | f32: position RMS with GNSS / in outages m | f32: attitude RMS deg | f32: NEES | f32 / f64 in outages | overflow events |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for outage_s in [30.0, 60.0] {
        let mut worst_ratio = 1.0f64;
        let mut inside = [0, 0];
        let mut spreads = Vec::new();
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
            let (wide, narrow) = (run(Scalar::F64), run(Scalar::F32));
            spreads.push(wide.covariance.clone());
            let ratio = narrow.position_rms_outage_m / wide.position_rms_outage_m;
            worst_ratio = worst_ratio.max(ratio).max(1.0 / ratio);
            for (k, r) in [&wide, &narrow].into_iter().enumerate() {
                if r.nees_mean >= r.nees_bounds[0] && r.nees_mean <= r.nees_bounds[1] {
                    inside[k] += 1;
                }
            }
            println!(
                "| {outage_s} | {seed} | {:.3} / {:.2} | {:.4} | {:.2} [{:.2}, {:.2}] | {:.3} / {:.2} | {:.4} | {:.2} | {ratio:.3} | {} / {} |",
                wide.position_rms_m,
                wide.position_rms_outage_m,
                wide.attitude_rms_deg,
                wide.nees_mean,
                wide.nees_bounds[0],
                wide.nees_bounds[1],
                narrow.position_rms_m,
                narrow.position_rms_outage_m,
                narrow.attitude_rms_deg,
                narrow.nees_mean,
                wide.overflow_events,
                narrow.overflow_events
            );
        }
        println!(
            "outages of {outage_s} s: f32 / f64 position in outages within a factor {worst_ratio:.3}; NEES inside its bounds on {} (f64) and {} (f32) of 20 seeds",
            inside[0], inside[1]
        );
        print_spread(&spreads);
    }
}

/// The covariance's numbers over every run (f64): each group's variances, and the decades
/// a fixed-point format would have to span, as the filter holds the covariance and scaled by
/// the sigmas it started with.
fn print_spread(spreads: &[dynacal::navsim::CovarianceSpread]) {
    let fold = |f: &dyn Fn(&dynacal::navsim::CovarianceSpread) -> f64, max: bool| {
        spreads.iter().map(f).fold(
            if max {
                f64::NEG_INFINITY
            } else {
                f64::INFINITY
            },
            |a, b| {
                if max {
                    a.max(b)
                } else {
                    a.min(b)
                }
            },
        )
    };
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
