//! Tests of the RTS smoother: equivalence with the textbook smoother on a linear problem,
//! and the paper's smoothed, variance-weighted inter-IMU calibration.

use super::*;
use dynacal_core::nav::ekf::{
    EkfConfig, InitialSigmas, InterImuSample, NavEkf, NavEkf1, NavLinearization,
    RateDifferentiator, POS, VEL,
};
use nalgebra::{Rotation3, SVector, UnitQuaternion};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn sigmas() -> InitialSigmas<f64> {
    InitialSigmas {
        position_m: Vector3::repeat(5.0),
        velocity_m_s: Vector3::repeat(0.5),
        attitude_rad: Vector3::new(0.02, 0.02, 0.1),
        accel_bias_m_s2: Vector3::repeat(0.1),
        gyro_bias_rad_s: Vector3::repeat(1e-3),
        boresight_rad: Vector3::repeat(20f64.to_radians()),
        lever_arm_m: Vector3::repeat(0.2),
    }
}

fn lin() -> NavLinearization<f64> {
    NavLinearization::from_geodetic(
        0.8,
        300.0,
        Vector3::new(12.0, -4.0, 0.1),
        Rotation3::from_euler_angles(0.03, -0.02, 2.0).into_inner(),
        Vector3::new(0.6, 0.3, -9.75),
    )
}

#[test]
fn rts_with_resets_equals_textbook_rts_of_the_open_loop_filter() {
    // GIVEN a linear problem (fixed linearisation, GNSS position and velocity updates), run
    // closed-loop with resets (recorded for smoothing) and open-loop without resets
    let mut config = EkfConfig::<f64>::automotive_mems();
    config.innovation_gate = f64::INFINITY;
    let mut closed = SmoothingEkf::new(NavEkf::<f64>::new(config, sigmas()));
    let mut open = NavEkf::<f64>::new(config, sigmas());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed_0401);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let lin = lin();
    // The closed loop's nominal (all 15 states), propagated by the same Φ and corrected by
    // each reset, as a mechanization would be.
    let mut nominal = SVector::<f64, 15>::zeros();
    let mut nominal_after_reset = Vec::new();
    let mut open_updated = Vec::new();
    let mut open_p_updated = Vec::new();
    let mut open_p_predicted = Vec::new();
    let mut open_phi = Vec::new();
    let mut phi = SMatrix::<f64, 15, 15>::identity();
    let sigma_p = Vector3::new(1.5, 1.5, 3.0);
    let sigma_v = Vector3::repeat(0.1);
    for epoch in 0..40 {
        if epoch > 0 {
            for _ in 0..10 {
                closed.predict(&lin, 0.1);
                open.predict(&lin, 0.1);
                let step = closed.ekf().last_transition_nav();
                nominal = step * nominal;
                phi = step * phi;
            }
        }
        open_p_predicted.push(open.covariance());
        open_phi.push(phi);
        phi = SMatrix::identity();
        let measure = |rng: &mut rand_chacha::ChaCha8Rng, s: &Vector3<f64>| {
            Vector3::new(
                s.x * normal.sample(rng),
                s.y * normal.sample(rng),
                s.z * normal.sample(rng),
            )
        };
        let z_p = measure(&mut rng, &sigma_p) + Vector3::new(3.0, -2.0, 1.0);
        let z_v = measure(&mut rng, &sigma_v) + Vector3::new(0.3, 0.1, -0.1);
        let with_updates = epoch > 0;
        let nominal_p = nominal.fixed_rows::<3>(POS).into_owned();
        let nominal_v = nominal.fixed_rows::<3>(VEL).into_owned();
        let mut correction = SVector::<f64, 15>::zeros();
        closed.epoch(epoch as f64, |ekf| {
            if with_updates {
                ekf.fuse_gnss_position(&(z_p - nominal_p), &sigma_p);
                ekf.fuse_gnss_velocity(&(z_v - nominal_v), &sigma_v);
            }
            correction = *ekf.error_estimate();
        });
        nominal += correction;
        nominal_after_reset.push(nominal);
        if with_updates {
            open.fuse_gnss_position(&z_p, &sigma_p);
            open.fuse_gnss_velocity(&z_v, &sigma_v);
        }
        open_updated.push(*open.error_estimate());
        open_p_updated.push(open.covariance());
    }
    // WHEN both are smoothed (the open loop with the textbook RTS)
    let smoothed = closed.smooth().unwrap();
    let n = open_updated.len();
    let mut x_s = open_updated[n - 1];
    let mut p_s = open_p_updated[n - 1];
    let mut textbook = vec![(x_s, p_s.diagonal())];
    for k in (0..n - 1).rev() {
        let phi = open_phi[k + 1];
        let p_pred = open_p_predicted[k + 1];
        let gain = open_p_updated[k] * phi.transpose() * p_pred.try_inverse().unwrap();
        x_s = open_updated[k] + gain * (x_s - phi * open_updated[k]);
        p_s = open_p_updated[k] + gain * (p_s - p_pred) * gain.transpose();
        textbook.push((x_s, p_s.diagonal()));
    }
    textbook.reverse();
    // THEN nominal + smoothed error equals the textbook smoothed state, with equal variances
    for k in 0..n {
        let total = nominal_after_reset[k]
            + SVector::<f64, 15>::from_column_slice(smoothed.epochs[k].error.as_slice());
        let (x, var) = &textbook[k];
        let state_gap = (total - x).amax();
        let var_gap =
            (SVector::<f64, 15>::from_column_slice(smoothed.epochs[k].variance.as_slice()) - var)
                .amax();
        assert!(
            state_gap < 1e-9,
            "epoch {k}: state differs by {state_gap:e}"
        );
        assert!(
            var_gap < 1e-9 * var.amax(),
            "epoch {k}: variance differs by {var_gap:e}"
        );
    }
    // And smoothing did something: early epochs are far better known than when filtered.
    assert!(smoothed.epochs[1].variance[POS] < 0.5 * open_p_updated[1][(POS, POS)]);
}

const TRUE_BORESIGHT_DEG: [f64; 3] = [2.0, -1.0, 3.0];
const TRUE_LEVER_ARM_M: [f64; 3] = [0.3, -0.2, 0.1];

#[test]
fn smoothed_weighted_mean_calibration_recovers_boresight_and_lever_arm() {
    // GIVEN reference-IMU rates and specific force along a rich rotation, an extra IMU
    // rotated by (2, −1, 3) deg and displaced by (0.3, −0.2, 0.1) m, 50 Hz, 40 s
    let psi_true = Vector3::from(TRUE_BORESIGHT_DEG.map(f64::to_radians));
    let c_b_s = UnitQuaternion::from_scaled_axis(-psi_true)
        .to_rotation_matrix()
        .into_inner();
    let arm = Vector3::from(TRUE_LEVER_ARM_M);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed_0402);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let mut noise = |s: f64| {
        Vector3::new(
            s * normal.sample(&mut rng),
            s * normal.sample(&mut rng),
            s * normal.sample(&mut rng),
        )
    };
    let rate_hz = 50.0;
    let dt = 1.0 / rate_hz;
    let omega = |t: f64| {
        Vector3::new(
            0.6 * (1.1 * t).sin(),
            0.5 * (0.7 * t + 1.0).sin(),
            0.8 * (0.45 * t + 2.0).sin(),
        )
    };
    let force = |t: f64| {
        Vector3::new(
            0.5 * (0.3 * t).sin(),
            0.4 * (0.5 * t).cos(),
            -9.8 + 0.3 * (0.9 * t).sin(),
        )
    };
    let mut filter = SmoothingEkf::new(NavEkf1::<f64>::new(EkfConfig::automotive_mems(), sigmas()));
    let lin = lin();
    let sigma_rate = Vector3::repeat(0.01);
    let sigma_force = Vector3::repeat(0.03);
    let mut diff = RateDifferentiator::<f64, (Vector3<f64>, Vector3<f64>, Vector3<f64>)>::new();
    let mut filtered_sigma_at_1s = 0.0;
    filter.epoch(0.0, |_| {});
    for i in 1..(40.0 * rate_hz) as usize {
        let t = i as f64 * dt;
        let w = omega(t);
        let h = 1e-5;
        let w_dot = (omega(t + h) - omega(t - h)) / (2.0 * h);
        let f = force(t);
        let extra_omega = c_b_s * w + noise(0.01);
        let extra_f = c_b_s * (f + w_dot.cross(&arm) + w.cross(&w.cross(&arm))) + noise(0.03);
        filter.predict(&lin, dt);
        let measured = diff.push(dt, w + noise(1e-4), (f + noise(2e-4), extra_omega, extra_f));
        filter.epoch(t, |ekf| {
            if let Some((w_mid, w_dot_mid, (f_mid, extra_omega_mid, extra_f_mid))) = measured {
                // Bias-corrected with the filter's nominal biases, as a mechanization is.
                let sample = InterImuSample {
                    omega_ib_b_rad_s: w_mid - ekf.gyro_bias_b_rad_s(),
                    omega_dot_ib_b_rad_s2: w_dot_mid,
                    f_b_m_s2: f_mid - ekf.accel_bias_b_m_s2(),
                    omega_is_s_rad_s: extra_omega_mid,
                    f_s_m_s2: extra_f_mid,
                    shares_reference_bias: false,
                };
                ekf.fuse_inter_imu(0, &sample, &sigma_rate, &sigma_force);
            }
        });
        if i == rate_hz as usize {
            filtered_sigma_at_1s = filter.ekf().sigma(boresight_index(0)).unwrap();
        }
    }
    // WHEN the recording is smoothed and the calibration averaged as in the paper
    let smoothed = filter.smooth().unwrap();
    let estimate = smoothed.calibration_estimate(0).unwrap();
    // THEN it lies within 3 sigma of the truth, to better than 0.05 deg and 5 mm
    for axis in 0..3 {
        let psi_err = estimate.boresight_rad[axis] - psi_true[axis];
        let arm_err = estimate.lever_arm_b_m[axis] - arm[axis];
        assert!(
            psi_err.abs() < 3.0 * estimate.boresight_sigma_rad[axis],
            "boresight {axis}: {psi_err:e} vs {:e}",
            estimate.boresight_sigma_rad[axis]
        );
        assert!(
            arm_err.abs() < 3.0 * estimate.lever_arm_sigma_m[axis],
            "lever arm {axis}: {arm_err:e} vs {:e}",
            estimate.lever_arm_sigma_m[axis]
        );
        assert!(psi_err.abs() < 0.05f64.to_radians() && arm_err.abs() < 0.005);
    }
    // AND for a rigid mount (a constant) every smoothed epoch carries the final filtered
    // estimate and sigma, including the first, which the filter only knew to 20 deg.
    let final_cal = filter.ekf().calibration(0).unwrap();
    let first = &smoothed.epochs[0].calibration[0];
    assert!((first.boresight_rad - final_cal.boresight_rad()).amax() < 1e-9);
    assert!((first.lever_arm_b_m - final_cal.lever_arm_b_m).amax() < 1e-9);
    let final_sigma = filter.ekf().sigma(boresight_index(0)).unwrap();
    assert!((first.boresight_sigma_rad.x - final_sigma).abs() < 1e-6 * final_sigma);
    assert!(smoothed.epochs[50].calibration[0].boresight_sigma_rad.x < 0.1 * filtered_sigma_at_1s);
}

#[test]
fn smoothing_nothing_is_an_error() {
    let filter = SmoothingEkf::new(NavEkf::<f64>::new(EkfConfig::automotive_mems(), sigmas()));
    assert_eq!(filter.smooth().unwrap_err(), SmootherError::Empty);
}
