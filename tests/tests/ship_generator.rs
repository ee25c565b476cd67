//! Tests of the independent ship-motion generator (`ship`): its reference is kinematically
//! exact (a strapdown integration of its rates and specific force reproduces its attitude
//! and velocity), the project's calibration recovers the mount it was given, the error
//! signal of a run with nothing hidden carries the white noise that was put in, each hidden
//! effect adds exactly its defining term, and the static record reads Earth rate and gravity
//! through the boresight.

mod ship;

use std::sync::OnceLock;

use dynacal::calibration::{build_error_signals, CalibrationSummary, ErrorOptions};
use dynacal::error_signal::ErrorSignals;
use dynacal::interchange::ImuRecording;
use dynacal_core::nav::{earth_rate_ned_rad_s, normal_gravity_m_s2, NavState, Strapdown};
use nalgebra::{UnitQuaternion, Vector3};
use ship::{levels, ship_run, static_record, Hidden, Mount, ShipRun};

/// The mount of the calibration tests: the boresight of the project's hidden-effect tests,
/// a lever arm of a few decimetres and a 10 ms sensor lag.
const MOUNT: Mount = Mount {
    boresight_rpy_deg: [0.3, -0.2, 0.5],
    lever_arm_b_m: [0.3, -0.2, 0.15],
    time_offset_s: 0.01,
};

/// Channel `i` (gx gy gz ax ay az) of a recording.
fn channel(rec: &ImuRecording, i: usize) -> &[f64] {
    if i < 3 {
        &rec.gyro_rad_s.as_ref().expect("gyro columns")[i]
    } else {
        &rec.accel_m_s2.as_ref().expect("accel columns")[i - 3]
    }
}

fn triplet_at(t: &[Vec<f64>; 3], k: usize) -> Vector3<f64> {
    Vector3::new(t[0][k], t[1][k], t[2][k])
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

fn std_dev(x: &[f64]) -> f64 {
    let m = mean(x);
    (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
}

/// Standard deviation of the first difference: twice the white-noise variance plus what the
/// slow processes change in one sample.
fn first_difference_std(x: &[f64]) -> f64 {
    let d: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
    std_dev(&d)
}

/// Largest attitude (deg), velocity (m/s) and position (m) differences between the seeded
/// 60 s reference and the project's strapdown integration of its own rates and specific
/// force, and the peak body rate (rad/s) as a sign that the platform really moves.
fn strapdown_errors(seed: u64) -> [f64; 4] {
    let run = ship_run(60.0, seed, &MOUNT, &[]);
    let r = &run.reference;
    let (gyro, accel) = (
        r.gyro_rad_s.as_ref().unwrap(),
        r.accel_m_s2.as_ref().unwrap(),
    );
    let (att, pos, vel) = (
        r.attitude_rad.as_ref().unwrap(),
        r.position.as_ref().unwrap(),
        r.velocity_ned_m_s.as_ref().unwrap(),
    );
    let state = |k: usize| {
        NavState::from_euler(
            att[0][k],
            att[1][k],
            att[2][k],
            triplet_at(vel, k),
            pos[0][k],
            pos[1][k],
            pos[2][k],
        )
    };
    let mut nav = Strapdown::new(state(0));
    let mut worst = [0.0f64; 4];
    for k in 1..r.len() {
        let dt_s = r.t_s[k] - r.t_s[k - 1];
        nav.step_rates(
            triplet_at(gyro, k - 1),
            triplet_at(gyro, k),
            triplet_at(accel, k - 1),
            triplet_at(accel, k),
            dt_s,
        )
        .unwrap();
        let (got, want) = (nav.state(), state(k));
        // Position differences to metres with a round Earth radius: only their size matters.
        let north_m = (got.lat_rad - want.lat_rad) * 6.37e6;
        let east_m = (got.lon_rad - want.lon_rad) * 6.39e6 * want.lat_rad.cos();
        let now = [
            got.q_nb.angle_to(&want.q_nb).to_degrees(),
            (got.v_ned_m_s - want.v_ned_m_s).norm(),
            Vector3::new(north_m, east_m, got.h_m - want.h_m).norm(),
            triplet_at(gyro, k).norm(),
        ];
        for (w, n) in worst.iter_mut().zip(now) {
            *w = w.max(n);
        }
    }
    worst
}

#[test]
fn strapdown_integration_of_the_reference_reproduces_its_attitude_and_velocity() {
    for seed in [11, 12, 13] {
        // GIVEN 60 s of the exact 200 Hz reference
        // WHEN integrating its rates and specific force with the project's mechanization
        let [att_deg, vel_m_s, pos_m, rate_rad_s] = strapdown_errors(seed);
        println!(
            "seed {seed}: attitude {att_deg:.2e} deg, velocity {vel_m_s:.2e} m/s, \
             position {pos_m:.2e} m (peak body rate {rate_rad_s:.3} rad/s)"
        );
        // THEN the platform really moves, and attitude, velocity and position agree with the
        // generated ones (an Earth-rate or Coriolis slip would show at 1e-3 deg or m/s)
        assert!(rate_rad_s > 0.05, "seed {seed}: {rate_rad_s}");
        assert!(att_deg < 1e-3, "seed {seed}: attitude error {att_deg} deg");
        assert!(vel_m_s < 1e-3, "seed {seed}: velocity error {vel_m_s} m/s");
        assert!(pos_m < 0.02, "seed {seed}: position error {pos_m} m");
    }
}

/// The 300 s run with nothing hidden and its calibration, shared by the tests that need it.
fn null_run() -> &'static (ShipRun, ErrorSignals, CalibrationSummary) {
    static RUN: OnceLock<(ShipRun, ErrorSignals, CalibrationSummary)> = OnceLock::new();
    RUN.get_or_init(|| {
        let run = ship_run(300.0, 5, &MOUNT, &[]);
        let (signals, summary) =
            build_error_signals(&run.sensor, &run.reference, &ErrorOptions::default())
                .expect("calibration of the ship run");
        (run, signals, summary)
    })
}

#[test]
fn calibration_recovers_boresight_lever_arm_and_time_offset() {
    // GIVEN a 300 s ship run with a known mount and nothing hidden
    // WHEN the project's calibration builds the error signals
    let (_, _, s) = null_run();
    // THEN each estimate is within 4 of its sigmas (plus a small absolute allowance) of truth
    // (all are printed before any is judged, so a failure shows the whole calibration).
    // Without noise the same run gives the mount to 1e-6, so the conventions agree; with it,
    // over seeds 1-40 the errors are unbiased but spread 1.05-1.47 reported sigmas (likely
    // because a Newey-West lag of ~17 epochs, 0.17 s, cannot see the 20-50 s Gauss-Markov
    // correlation), and seed 18 puts the lever arm x at 4.4 sigmas: the bound holds for this
    // seed, not for every one.
    let mut failures = Vec::new();
    let mut check = |what: String, est: f64, sigma: f64, truth: f64, allowance: f64| {
        let z = (est - truth) / sigma;
        println!("{what}: {est:.6} +- {sigma:.6} (truth {truth:.6}, z {z:+.2})");
        if !(sigma > 0.0 && (est - truth).abs() <= 4.0 * sigma + allowance) {
            failures.push(format!("{what}: {est} +- {sigma} vs truth {truth}"));
        }
    };
    let psi = MOUNT.boresight_rotation_vector_rad();
    let b = &s.boresight_rad;
    let l = s.lever_arm_m.expect("a lever-arm estimate");
    for i in 0..3 {
        check(
            format!("boresight[{i}] deg"),
            b.value[i].to_degrees(),
            b.sigma[i].to_degrees(),
            psi[i].to_degrees(),
            0.01,
        );
        check(
            format!("lever arm[{i}] m"),
            l.value[i],
            l.sigma[i],
            MOUNT.lever_arm_b_m[i],
            0.005,
        );
    }
    let dt = s.time_offset_s.expect("a time-offset estimate");
    check(
        "time offset s".into(),
        dt.value,
        dt.sigma,
        MOUNT.time_offset_s,
        0.001,
    );
    println!("epochs {}, Newey-West lag {}", s.epochs, s.hac_lag);
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn null_run_error_signal_carries_the_white_noise_put_in() {
    // GIVEN the calibrated error signal of the 300 s run with nothing hidden
    let (_, signals, _) = null_run();
    // THEN per channel the first difference's spread over sqrt(2) is the white-noise sigma:
    // the bias cancels, the Gauss-Markov moves by ~sigma sqrt(2 beta dt) (3% of white at
    // most) and the calibration leaves no visible motion-correlated residual
    for (i, name) in dynacal::interchange::CHANNELS.iter().enumerate() {
        let e = signals.errors[i].as_deref().expect("every channel");
        let white = first_difference_std(e) / 2f64.sqrt();
        let put_in = levels(i).white_sigma;
        println!(
            "{name}: white noise {white:.5} vs {put_in:.5} ({:+.2}%)",
            100.0 * (white / put_in - 1.0)
        );
        assert!(
            (white / put_in - 1.0).abs() < 0.1,
            "{name}: {white} vs {put_in}"
        );
    }
}

/// Slope of the no-intercept least-squares fit y ~ slope x.
fn slope(y: &[f64], x: &[f64]) -> f64 {
    let xy: f64 = y.iter().zip(x).map(|(a, b)| a * b).sum();
    let xx: f64 = x.iter().map(|b| b * b).sum();
    xy / xx
}

#[test]
fn each_hidden_effect_adds_exactly_its_defining_term() {
    // GIVEN the same seeded run without and with one hidden effect on each of five channels
    let hidden = [
        Hidden::GSensitivity {
            gyro_channel: 0,
            accel_axis: 2,
            value: 2e-3,
        },
        Hidden::Vibration {
            channel: 1,
            frequency_hz: 73.0,
            amplitude: 0.01,
        },
        Hidden::ScaleFactor {
            channel: 2,
            value: 0.02,
        },
        Hidden::BiasStep {
            channel: 3,
            at_s: 30.0,
            size: 0.05,
        },
        Hidden::NoiseChange {
            channel: 4,
            gm_variance_factor: 4.0,
        },
    ];
    let null = ship_run(60.0, 23, &MOUNT, &[]).sensor;
    let with = ship_run(60.0, 23, &MOUNT, &hidden).sensor;
    let diff = |i: usize| -> Vec<f64> {
        channel(&with, i)
            .iter()
            .zip(channel(&null, i))
            .map(|(a, b)| a - b)
            .collect()
    };
    let names: Vec<&str> = hidden.iter().map(Hidden::channel).collect();
    assert_eq!(names, ["gx", "gy", "gz", "ax", "ay"]);
    // THEN g-sensitivity and scale factor are proportional to the true input (read here off
    // the null run, whose own errors blur the slope by well under 1%)
    let g = slope(&diff(0), channel(&null, 5));
    assert!((g / 2e-3 - 1.0).abs() < 0.01, "g-sensitivity slope {g}");
    let sf = slope(&diff(2), channel(&null, 2));
    assert!((sf / 0.02 - 1.0).abs() < 0.01, "scale-factor slope {sf}");
    // AND the vibration is the stated sinusoid at the true sampling time, aliased or not
    for (k, d) in diff(1).iter().enumerate() {
        let t = null.t_s[k] - MOUNT.time_offset_s;
        let want = 0.01 * (std::f64::consts::TAU * 73.0 * t + 0.3).sin();
        assert!(
            (d - want).abs() < 1e-12,
            "vibration at {t} s: {d} vs {want}"
        );
    }
    // AND the bias step switches on at its stamp time
    for (k, d) in diff(3).iter().enumerate() {
        let want = if null.t_s[k] >= 30.0 { 0.05 } else { 0.0 };
        assert!((d - want).abs() < 1e-12, "step at {} s: {d}", null.t_s[k]);
    }
    // AND doubling the Gauss-Markov sigma adds one more copy of the same GM path: a smooth
    // signal whose one-sample change has the GM's spread sigma sqrt(2 (1 - phi))
    let ay = levels(4);
    let phi = (-ay.gm_beta_per_s / 100.0).exp();
    let want = ay.gm_sigma * (2.0 * (1.0 - phi)).sqrt();
    let got = first_difference_std(&diff(4));
    assert!(
        (got / want - 1.0).abs() < 0.05,
        "GM step spread {got} vs {want}"
    );
    // AND the channel with nothing hidden is untouched
    assert!(diff(5).iter().all(|d| *d == 0.0));
}

#[test]
fn static_record_reads_earth_rate_and_gravity_through_the_boresight() {
    // GIVEN a 600 s static record (level, heading north, at the mean position)
    let seconds = 600.0;
    let rec = static_record(seconds, 7, &MOUNT);
    assert_eq!(rec.len(), 60_000);
    assert!(rec.attitude_rad.is_none() && rec.position.is_none());
    // WHEN comparing each channel's mean with the sensor-frame Earth rate and minus gravity
    let (lat, h) = (ship::LAT0_DEG.to_radians(), ship::H0_M);
    let c_bs = MOUNT.c_bs();
    let omega_s = c_bs * earth_rate_ned_rad_s(lat);
    let f_s = c_bs * Vector3::new(0.0, 0.0, -normal_gravity_m_s2(lat, h));
    for i in 0..6 {
        let x = channel(&rec, i);
        let l = levels(i);
        let truth = if i < 3 { omega_s[i] } else { f_s[i - 3] } + l.bias;
        // The mean of a GM over T has variance ~2 sigma^2 / (beta T).
        let sd = (2.0 * l.gm_sigma.powi(2) / (l.gm_beta_per_s * seconds)
            + l.white_sigma.powi(2) / x.len() as f64)
            .sqrt();
        // THEN it is that plus the bias, within the noise
        assert!(
            (mean(x) - truth).abs() < 4.0 * sd,
            "channel {i}: mean {} vs {truth} (sd {sd})",
            mean(x)
        );
        // AND its white noise is the stated level
        let white = first_difference_std(x) / 2f64.sqrt();
        assert!((white / l.white_sigma - 1.0).abs() < 0.03, "{i}: {white}");
    }
    // AND the record is reproducible from its seed and differs for another seed
    assert_eq!(
        static_record(10.0, 7, &MOUNT),
        static_record(10.0, 7, &MOUNT)
    );
    assert_ne!(
        static_record(10.0, 7, &MOUNT),
        static_record(10.0, 8, &MOUNT)
    );
    // AND the boresight tilts gravity into x and y by about the boresight pitch and roll
    let tilt = UnitQuaternion::rotation_between(&Vector3::z(), &-f_s)
        .unwrap()
        .angle();
    assert!(
        (tilt.to_degrees() - 0.36).abs() < 0.01,
        "{}",
        tilt.to_degrees()
    );
}
