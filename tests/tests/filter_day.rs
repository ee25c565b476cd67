//! A day on the board's filter (issue 21, part 4): the board's fusion with its f32 filter,
//! the code the firmware runs, over a long simulated car drive with GNSS, checked every
//! [`CHECK_EVERY_S`] simulated seconds: its covariance stays symmetric and positive definite
//! and every variance inside its bounds ([`Bounds`]), and the navigation stays close to the
//! truth.
//!
//! A day of three units at 200 Hz is 52 million samples, too many to simulate whole (the
//! simulator holds every sample of a run in memory). So the drive is streamed sample by
//! sample (`dynacal::navsim::drive::StreamedDrive`, what `dynacal navsim` drives): the
//! simulator's car trajectory (exact kinematics) and GNSS receiver are built for the whole
//! day (a position grid and the fixes, about 0.5 GB), and each unit's reading is made when
//! it is needed. The units tick together on GPS time (the fusion's own tests cover clocks
//! and the replay path).
//!
//! `the_boards_filter_keeps_its_covariance_over_ten_minutes` runs in the default test run;
//! the day is ignored by default (about 2.5 minutes in release, after the build):
//! `cargo test --release -p dynacal-tests --test filter_day -- --ignored --nocapture`.

mod three_units;

use std::time::Instant;

use dynacal::navsim::drive::StreamedDrive;
use dynacal::navsim::{NavError, Rms, Span, SETTLE_AFTER_OUTAGE_S, STATES, STATE_GROUPS};
use dynacal::sim::trajectory::Truth;
use dynacal_core::fusion::{BoardFilter, BoardFusion, FusionConfig};
use dynacal_core::nav::ekf::{ATT, CALIBRATION_STATES_PER_IMU, NAV_STATES, POS, VEL};
use nalgebra::{Cholesky, SMatrix, SymmetricEigen, Vector3};
use three_units::{board_model, RATE_HZ};

/// The covariance is checked this often, simulated s.
const CHECK_EVERY_S: u64 = 10;
/// The navigation error is taken this often, simulated s.
const ERROR_EVERY_S: u64 = 1;

/// The covariance in f64, as the checks read it.
type Covariance = SMatrix<f64, STATES, STATES>;

/// The filter's error against the truth: NED position (m), attitude (rad, NED axes, as the
/// filter's `C_b^n = (I + [eps x]) C_hat`), both truth minus estimate.
fn nav_error(filter: &BoardFilter, truth: &Truth) -> (Vector3<f64>, Vector3<f64>) {
    let error = NavError::of(filter, truth);
    (error.position_ned_m, error.attitude_rad)
}

/// The variance bounds of each state, as the filter states them or as they follow from its
/// model (variances in the squared units of `dynacal_core::nav::ekf`'s state table).
struct Bounds {
    /// The filter's floors (`EkfConfig::variance_floor`, applied after every prediction and
    /// update): nothing may fall below them.
    floor: [f64; STATES],
    /// Ceilings wherever the model gives one, f64::INFINITY elsewhere:
    /// - boresight and lever arm are random constants (no driving noise), so updates can
    ///   only lower their variance below the initial one;
    /// - each bias is a first-order Gauss-Markov state alone in its block of the transition
    ///   (`P <- phi^2 P + q` with `q = sigma^2 (1 - phi^2)` between updates), so its variance
    ///   stays below the larger of its initial and its stationary `psd / (2 beta)` (no
    ///   ceiling for a random walk);
    /// - position, velocity and attitude are not bounded by the model; with GNSS
    ///   ([`StreamedDrive::with_gnss`]) they are held to [`NAV_CEILING_FACTOR`] times their
    ///   variance at the start (the first fix's and the alignment's), which each fix and
    ///   the drive's manoeuvres keep them under.
    ceiling: [f64; STATES],
}

/// Position, velocity and attitude variances with GNSS stay below this multiple of their
/// start (see [`Bounds::ceiling`]).
const NAV_CEILING_FACTOR: f64 = 1.0;
/// Relative slack on the ceilings for f32 rounding of the variances (2^-24 per operation,
/// a few hundred operations per update).
const CEILING_SLACK: f64 = 1e-4;

impl Bounds {
    /// The bounds of `filter` as it starts (its covariance still the initial one).
    fn at_start(filter: &BoardFilter) -> Self {
        let config = filter.ekf.config();
        let p = filter.ekf.covariance();
        let floor = core::array::from_fn(|i| f64::from(config.variance_floor[class_of(i)].value()));
        let stationary = |psd: f32, inv_tau_s: f32| {
            if inv_tau_s > 0.0 {
                f64::from(psd) / (2.0 * f64::from(inv_tau_s))
            } else {
                f64::INFINITY
            }
        };
        let accel = stationary(config.accel_bias_psd.value(), config.accel_bias_inv_tau_s);
        let gyro = stationary(config.gyro_bias_psd.value(), config.gyro_bias_inv_tau_s);
        let ceiling = core::array::from_fn(|i| {
            let initial = f64::from(p[(i, i)]);
            let model = match class_of(i) {
                3 => initial.max(accel),
                4 => initial.max(gyro),
                5 | 6 => initial,
                _ => initial * NAV_CEILING_FACTOR,
            };
            model * (1.0 + CEILING_SLACK)
        });
        Self { floor, ceiling }
    }
}

/// The variance-floor class of state `i` (`EkfConfig::variance_floor`'s order).
fn class_of(i: usize) -> usize {
    if i < NAV_STATES {
        i / 3
    } else if (i - NAV_STATES) % CALIBRATION_STATES_PER_IMU < 3 {
        5
    } else {
        6
    }
}

/// What one covariance check found.
#[derive(Debug, Clone, Copy)]
struct CovarianceCheck {
    /// Largest `|P_ij - P_ji| / sqrt(P_ii P_jj)`.
    asymmetry: f64,
    /// Whether the Cholesky factorisation (f64) of the f32 matrix succeeded.
    cholesky: bool,
    /// Smallest eigenvalue of `P` (mixed units: dominated by the gyro biases).
    min_eigenvalue: f64,
    /// Smallest eigenvalue of the correlation matrix `D^-1/2 P D^-1/2` (dimensionless, in
    /// (0, 1] for a positive definite `P`): how far from singular `P` is whatever the units.
    min_correlation_eigenvalue: f64,
}

fn check_covariance(p: &Covariance) -> CovarianceCheck {
    let mut asymmetry = 0.0f64;
    for i in 0..STATES {
        for j in 0..i {
            let scale = (p[(i, i)] * p[(j, j)]).sqrt();
            asymmetry = asymmetry.max((p[(i, j)] - p[(j, i)]).abs() / scale);
        }
    }
    let scale = Covariance::from_fn(|i, j| 1.0 / (p[(i, i)] * p[(j, j)]).sqrt());
    let correlation = p.component_mul(&scale);
    let smallest = |m: Covariance| SymmetricEigen::new(m).eigenvalues.min();
    CovarianceCheck {
        asymmetry,
        cholesky: Cholesky::new(*p).is_some(),
        min_eigenvalue: smallest(*p),
        min_correlation_eigenvalue: smallest(correlation),
    }
}

/// Everything the run measured.
#[derive(Debug, Default)]
struct DayFigures {
    simulated_s: f64,
    wall_s: f64,
    /// Peak resident memory of the process, MiB (Linux's VmHWM; 0 where unknown).
    peak_rss_mib: f64,
    /// Simulated s before the filter started (alignment).
    aligned_after_s: f64,
    checks: u64,
    max_asymmetry: f64,
    cholesky_failures: u64,
    min_eigenvalue: Span,
    min_correlation_eigenvalue: Span,
    /// Each state's variance over the checks.
    variance: Vec<Span>,
    /// Checks that found a variance outside its bounds, with the first such finding.
    bound_violations: u64,
    first_violation: Option<String>,
    /// With GNSS: horizontal and vertical position error (m), roll/pitch and heading error
    /// (rad), and the largest error over its stated sigma of any position or attitude axis.
    horizontal_m: Rms,
    vertical_m: Rms,
    level_rad: Rms,
    heading_rad: Rms,
    max_error_over_sigma: f64,
    /// Where it was: simulated s, state index, error and sigma.
    worst_error: (f64, usize, f64, f64),
    /// Horizontal error at the end of each outage, m, and its stated sigma.
    outage_end: Vec<(f64, f64)>,
    restarts: u32,
    covariance_resets: u32,
    numerical_faults: u32,
    gnss_resets: u32,
}

/// Runs the board's fusion over `seconds` of driving with GNSS outages `outages` (start,
/// end s) and measures it.
fn run_day(seconds: f64, outages: Vec<[f64; 2]>, seed: u64) -> DayFigures {
    let started = Instant::now();
    let mut drive = StreamedDrive::new(&three_units::sim_model(&[]), seconds, outages, seed)
        .expect("the three units drive");
    let mut fusion =
        BoardFusion::<f32>::new(FusionConfig::at_rate(RATE_HZ as f32), &board_model(true));
    let mut figures = DayFigures {
        simulated_s: seconds,
        variance: vec![Span::default(); STATES],
        outage_end: vec![(0.0, 0.0); drive.outages().len()],
        ..DayFigures::default()
    };
    let mut bounds: Option<Bounds> = None;
    let trace = trace_window();
    let sets = (seconds * RATE_HZ) as u64;
    let (check_every, error_every) = (
        CHECK_EVERY_S * RATE_HZ as u64,
        ERROR_EVERY_S * RATE_HZ as u64,
    );
    for k in 0..sets {
        let (t_us, truth, readings) = drive.next_set();
        for fix in drive.fixes_until(t_us) {
            fusion.push_gnss(t_us, fix);
        }
        if bounds.is_none() {
            if let Some(filter) = fusion.filter() {
                figures.aligned_after_s = truth.t_s;
                bounds = Some(Bounds::at_start(filter));
            }
        }
        fusion.push_set(t_us, &readings, &mut |_| {});
        let (Some(filter), Some(bounds)) = (fusion.filter(), &bounds) else {
            continue;
        };
        if k % error_every == 0 {
            take_error(&mut figures, &drive, filter, &truth);
            if trace.is_some_and(|(from, to)| truth.t_s >= from && truth.t_s <= to) {
                trace_line(filter, &truth, fusion.still());
            }
        }
        if k % check_every == 0 {
            take_check(&mut figures, &drive, filter, bounds, truth.t_s);
        }
    }
    if let Some(filter) = fusion.filter() {
        let stats = filter.ekf.stats();
        figures.covariance_resets = stats.covariance_resets;
        figures.numerical_faults = stats.numerical_faults();
    }
    figures.restarts = fusion.counts().restarts;
    figures.gnss_resets = fusion.counts().gnss_resets;
    figures.wall_s = started.elapsed().as_secs_f64();
    figures.peak_rss_mib = peak_rss_mib();
    figures
}

/// The process's peak resident memory, MiB, from /proc (0 where there is none).
fn peak_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kib| kib / 1024.0)
}

/// Seconds to print each second of (for looking into a run: DYNACAL_DAY_TRACE=FROM,TO).
fn trace_window() -> Option<(f64, f64)> {
    let v = std::env::var("DYNACAL_DAY_TRACE").ok()?;
    let (from, to) = v.split_once(',')?;
    Some((from.trim().parse().ok()?, to.trim().parse().ok()?))
}

fn trace_line(filter: &BoardFilter, truth: &Truth, still: bool) {
    let (position, attitude) = nav_error(filter, truth);
    let sigma = |i: usize| filter.ekf.sigma(i).unwrap_or(f32::NAN);
    let velocity = truth.v_ned_m_s - filter.state().v_ned_m_s.map(f64::from);
    let st = filter.ekf.stats();
    println!(
        "t {:.0} speed {:.1} still {still} pos {:.3} {:.3} {:.3} sigma {:.3} {:.3} vel {:.3} {:.3} sigma {:.4} att {:.4} {:.4} {:.4} gnss pos acc/rej {}/{} vel {}/{} inter-imu rate {}/{} force {}/{} zupt {}/{}",
        truth.t_s, truth.speed_m_s, position.x, position.y, position.z, sigma(POS), sigma(POS + 1),
        velocity.x, velocity.y, sigma(VEL), attitude.x, attitude.y, attitude.z,
        st.gnss_position.accepted, st.gnss_position.rejected, st.gnss_velocity.accepted,
        st.gnss_velocity.rejected, st.inter_imu_rate.accepted, st.inter_imu_rate.rejected,
        st.inter_imu_force.accepted, st.inter_imu_force.rejected, st.zero_velocity.accepted,
        st.zero_velocity.rejected
    );
}

/// The navigation error at one instant into the figures.
fn take_error(
    figures: &mut DayFigures,
    drive: &StreamedDrive,
    filter: &BoardFilter,
    truth: &Truth,
) {
    let (position, attitude) = nav_error(filter, truth);
    let sigma = |i: usize| f64::from(filter.ekf.sigma(i).unwrap_or(f32::NAN));
    for (o, end) in drive.outages().iter().zip(figures.outage_end.iter_mut()) {
        if truth.t_s < o[1] {
            *end = (position.xy().norm(), sigma(POS).hypot(sigma(POS + 1)));
        }
    }
    if !drive.with_gnss(truth.t_s, SETTLE_AFTER_OUTAGE_S) {
        return;
    }
    figures.horizontal_m.add(position.xy().norm());
    figures.vertical_m.add(position.z);
    figures.level_rad.add(attitude.x.hypot(attitude.y));
    figures.heading_rad.add(attitude.z);
    for (first, error) in [(POS, position), (ATT, attitude)] {
        for a in 0..3 {
            let ratio = (error[a] / sigma(first + a)).abs();
            if ratio > figures.max_error_over_sigma {
                figures.max_error_over_sigma = ratio;
                figures.worst_error = (truth.t_s, first + a, error[a], sigma(first + a));
            }
        }
    }
}

/// One covariance check at `t_s` into the figures.
fn take_check(
    figures: &mut DayFigures,
    drive: &StreamedDrive,
    filter: &BoardFilter,
    bounds: &Bounds,
    t_s: f64,
) {
    let p: Covariance = filter.ekf.covariance().map(f64::from);
    let check = check_covariance(&p);
    figures.checks += 1;
    figures.max_asymmetry = figures.max_asymmetry.max(check.asymmetry);
    figures.cholesky_failures += u64::from(!check.cholesky);
    figures.min_eigenvalue.add(check.min_eigenvalue);
    figures
        .min_correlation_eigenvalue
        .add(check.min_correlation_eigenvalue);
    let with_gnss = drive.with_gnss(t_s, SETTLE_AFTER_OUTAGE_S);
    let mut violation = None;
    for i in 0..STATES {
        let v = p[(i, i)];
        figures.variance[i].add(v);
        let ceiling = if i < NAV_STATES - 6 && !with_gnss {
            f64::INFINITY
        } else {
            bounds.ceiling[i]
        };
        if !(v >= bounds.floor[i] && v <= ceiling) && violation.is_none() {
            violation = Some(format!(
                "t {t_s:.0} s: state {i} variance {v:e} outside [{:e}, {ceiling:e}]",
                bounds.floor[i]
            ));
        }
    }
    if let Some(v) = violation {
        figures.bound_violations += 1;
        figures.first_violation.get_or_insert(v);
    }
}

/// The figures as the lines BENCHMARKS.md quotes.
fn report(f: &DayFigures) {
    println!(
        "{:.0} simulated s in {:.1} s wall ({:.0}x real time, peak memory {:.0} MiB); aligned after {:.1} s",
        f.simulated_s,
        f.wall_s,
        f.simulated_s / f.wall_s,
        f.peak_rss_mib,
        f.aligned_after_s
    );
    println!(
        "{} covariance checks: max asymmetry {:e}, Cholesky failures {}, smallest eigenvalue {:e} .. {:e}, smallest correlation eigenvalue {:e} .. {:e}",
        f.checks,
        f.max_asymmetry,
        f.cholesky_failures,
        f.min_eigenvalue.min,
        f.min_eigenvalue.max,
        f.min_correlation_eigenvalue.min,
        f.min_correlation_eigenvalue.max
    );
    for (name, first, len) in STATE_GROUPS {
        let mut r = Span::default();
        for i in first..first + len {
            r.add(f.variance[i].min);
            r.add(f.variance[i].max);
        }
        println!("variance of {name}: {:.3e} .. {:.3e}", r.min, r.max);
    }
    println!(
        "bound violations {} (first: {:?})",
        f.bound_violations, f.first_violation
    );
    println!(
        "with GNSS: horizontal RMS {:.3} max {:.3} m; vertical RMS {:.3} max {:.3} m; roll/pitch RMS {:.2e} max {:.2e} rad; heading RMS {:.2e} max {:.2e} rad; largest |error|/sigma {:.2} (t, state, error, sigma: {:?})",
        f.horizontal_m.value(), f.horizontal_m.max_abs, f.vertical_m.value(), f.vertical_m.max_abs,
        f.level_rad.value(), f.level_rad.max_abs, f.heading_rad.value(), f.heading_rad.max_abs,
        f.max_error_over_sigma, f.worst_error
    );
    println!(
        "outage ends (horizontal error, sigma, m): {:?}",
        f.outage_end
    );
    println!(
        "restarts {}, covariance resets {}, numerical faults {}, GNSS resets {}",
        f.restarts, f.covariance_resets, f.numerical_faults, f.gnss_resets
    );
}

/// The run's figures against the bounds the tests hold.
fn assert_healthy(f: &DayFigures) {
    assert!(f.aligned_after_s < 60.0, "{f:?}");
    assert!(f.checks as f64 >= 0.9 * f.simulated_s / CHECK_EVERY_S as f64);
    assert_eq!(
        (f.restarts, f.covariance_resets, f.numerical_faults),
        (0, 0, 0)
    );
    assert!(f.max_asymmetry <= 1e-6, "{}", f.max_asymmetry);
    assert_eq!(f.cholesky_failures, 0);
    assert!(f.min_eigenvalue.min > 0.0, "{:?}", f.min_eigenvalue);
    assert!(
        f.min_correlation_eigenvalue.min > MIN_CORRELATION_EIGENVALUE,
        "{:?}",
        f.min_correlation_eigenvalue
    );
    assert_eq!(f.bound_violations, 0, "{:?}", f.first_violation);
    assert!(f.horizontal_m.max_abs < 2.0, "{:?}", f.horizontal_m);
    assert!(f.vertical_m.max_abs < 3.0, "{:?}", f.vertical_m);
    assert!(f.level_rad.max_abs < 0.01, "{:?}", f.level_rad);
    assert!(f.heading_rad.max_abs < 0.05, "{:?}", f.heading_rad);
    for (error, sigma) in &f.outage_end {
        assert!(
            *error < OUTAGE_END_BOUND_M && *error < 4.0 * sigma,
            "{:?}",
            f.outage_end
        );
    }
}

/// Horizontal error at the end of an outage of up to 60 s, m (measured up to 50 m over a
/// day's twelve, at 0.1 to 2.3 of their stated sigma).
const OUTAGE_END_BOUND_M: f64 = 100.0;

/// The correlation matrix's smallest eigenvalue must stay above this: f32 holds each
/// entry to 2^-24 relative, so a correlation matrix of 27 states whose smallest eigenvalue
/// is near 27 * 2^-24 = 1.6e-6 could turn indefinite from rounding alone.
const MIN_CORRELATION_EIGENVALUE: f64 = 1.6e-6;

/// Outages of `length_s` every `every_s` seconds from `first_s` within `seconds`.
fn outages(seconds: f64, first_s: f64, every_s: f64, length_s: f64) -> Vec<[f64; 2]> {
    (0..)
        .map(|k| first_s + k as f64 * every_s)
        .take_while(|t| t + length_s < seconds)
        .map(|t| [t, t + length_s])
        .collect()
}

#[test]
fn the_boards_filter_keeps_its_covariance_over_ten_minutes() {
    // GIVEN 10 minutes of car driving with GNSS, and one 30 s outage
    let seconds = 600.0;
    // WHEN the board's fusion runs its f32 filter on it
    let figures = run_day(seconds, outages(seconds, 300.0, 1e9, 30.0), 21);
    report(&figures);
    // THEN the covariance stays symmetric, positive definite and within its bounds, and
    // the navigation close to the truth
    assert_healthy(&figures);
}

#[test]
#[ignore = "a simulated day: about 2.5 minutes in release"]
fn the_boards_filter_keeps_its_covariance_over_a_day() {
    // GIVEN 24 h of car driving with GNSS at 10 Hz, and a 60 s outage every two hours
    let seconds = 86_400.0;
    // WHEN the board's fusion runs its f32 filter on it
    let figures = run_day(seconds, outages(seconds, 3600.0, 7200.0, 60.0), 21);
    report(&figures);
    // THEN the covariance stays symmetric, positive definite and within its bounds, and
    // the navigation close to the truth
    assert_healthy(&figures);
}
