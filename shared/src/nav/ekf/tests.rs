//! Unit and property tests of the error-state EKF: Jacobians against finite differences,
//! block-sparse prediction against the dense formula, Joseph update against the textbook
//! update, gating, covariance health in `f32` over long random runs, convergence of the
//! inter-IMU calibration (paper II-B and II-A) and agreement of `f32` with `f64`.

use super::*;
use crate::fixed::I32F32;
use nalgebra::{Matrix3, Rotation3, SMatrix, UnitQuaternion, Vector3};
use proptest::prelude::*;
use proptest::test_runner::{Config as ProptestConfig, FileFailurePersistence, RngSeed};

fn initial_sigmas<T: FilterScalar>() -> InitialSigmas<T> {
    let c = |x: f64| nalgebra::convert::<f64, T>(x);
    InitialSigmas {
        position_m: Vector3::repeat(c(5.0)),
        velocity_m_s: Vector3::repeat(c(0.5)),
        attitude_rad: Vector3::new(c(0.02), c(0.02), c(0.1)),
        accel_bias_m_s2: Vector3::repeat(c(0.1)),
        gyro_bias_rad_s: Vector3::repeat(c(1e-3)),
        boresight_rad: Vector3::repeat(c(20f64.to_radians())),
        lever_arm_m: Vector3::repeat(c(0.2)),
    }
}

/// The priors of a paper II-B calibration: the reference is the tactical-grade IMU of the
/// paper's Table I, so its biases are known far better than a MEMS unit's.
fn reference_grade_sigmas<T: FilterScalar>() -> InitialSigmas<T> {
    let c = |x: f64| nalgebra::convert::<f64, T>(x);
    InitialSigmas {
        accel_bias_m_s2: Vector3::repeat(c(1e-3)),
        gyro_bias_rad_s: Vector3::repeat(c(1e-5)),
        ..initial_sigmas()
    }
}

fn linearization(yaw: f64, v_n: f64) -> NavLinearization<f64> {
    let c_b_n = Rotation3::from_euler_angles(0.05, -0.03, yaw).into_inner();
    NavLinearization::from_geodetic(
        46.5f64.to_radians(),
        400.0,
        Vector3::new(v_n, 3.0, -0.2),
        c_b_n,
        Vector3::new(0.8, -0.4, -9.7),
    )
}

#[test]
fn block_sparse_prediction_equals_dense_phi_p_phi_transpose_plus_q() {
    let mut ekf = NavEkf2::<f64>::new(EkfConfig::automotive_mems(), initial_sigmas());
    // Give P correlations everywhere by running a few updates first.
    let lin = linearization(0.7, 12.0);
    for step in 0..50 {
        ekf.predict(&lin, 0.01);
        if step % 10 == 0 {
            ekf.fuse_gnss_position(&Vector3::new(0.3, -0.2, 0.1), &Vector3::repeat(1.0));
            ekf.fuse_gnss_velocity(&Vector3::new(0.03, -0.02, 0.01), &Vector3::repeat(0.1));
            let sample = InterImuSample {
                omega_ib_b_rad_s: Vector3::new(0.2, -0.3, 0.5),
                omega_dot_ib_b_rad_s2: Vector3::new(1.0, 0.5, -0.7),
                f_b_m_s2: Vector3::new(0.5, 0.2, -9.8),
                omega_is_s_rad_s: Vector3::new(0.21, -0.28, 0.49),
                f_s_m_s2: Vector3::new(0.6, 0.1, -9.7),
                shares_reference_bias: false,
            };
            ekf.fuse_inter_imu(0, &sample, &Vector3::repeat(0.01), &Vector3::repeat(0.05));
            ekf.fuse_inter_imu(1, &sample, &Vector3::repeat(0.01), &Vector3::repeat(0.05));
            ekf.reset();
        }
    }
    let before = ekf.covariance();
    let dt = 0.01;
    assert!(ekf.predict(&lin, dt));
    let mut phi = SMatrix::<f64, 27, 27>::identity();
    phi.fixed_view_mut::<15, 15>(0, 0)
        .copy_from(&ekf.last_transition_nav());
    let cfg = ekf.config();
    let mut q = SMatrix::<f64, 27, 27>::zeros();
    for axis in 0..3 {
        q[(VEL + axis, VEL + axis)] = cfg.accel_noise_psd.value() * dt;
        q[(ATT + axis, ATT + axis)] = cfg.gyro_noise_psd.value() * dt;
        q[(ACCEL_BIAS + axis, ACCEL_BIAS + axis)] = cfg.accel_bias_psd.value() * dt;
        q[(GYRO_BIAS + axis, GYRO_BIAS + axis)] = cfg.gyro_bias_psd.value() * dt;
    }
    let dense = phi * before * phi.transpose() + q;
    let err = (ekf.covariance() - dense).abs().max();
    assert!(
        err < 1e-12 * dense.abs().max(),
        "block-sparse vs dense: {err:e}"
    );
    // The transition carries the model's structure: velocity error grows with attitude error
    // through the specific force, position error through velocity.
    let phi_nav = ekf.last_transition_nav();
    assert!((phi_nav[(POS, VEL)] - dt).abs() < 1e-15);
    let f_n = lin.c_b_n * lin.f_b_m_s2;
    // Φ_vε = −[fⁿ×] dt, whose (north, east) entry is +f_D dt.
    assert!((phi_nav[(VEL, ATT + 1)] - (f_n.z * dt)).abs() < 1e-12);
}

#[test]
fn joseph_scalar_update_equals_textbook_kalman_update() {
    let mut ekf = NavEkf1::<f64>::new(EkfConfig::automotive_mems(), initial_sigmas());
    let lin = linearization(0.2, 5.0);
    for _ in 0..20 {
        ekf.predict(&lin, 0.01);
    }
    let p = &ekf.covariance();
    let row = SparseRow::from_blocks(
        boresight_index(0),
        [0.3, -0.1, 0.7],
        Some((lever_arm_index(0), [0.05, 0.2, -0.4])),
    );
    let mut h = SVector::<f64, 21>::zeros();
    for m in 0..row.len {
        h[row.index[m]] = row.value[m];
    }
    let sigma = 0.02f64.sqrt();
    let r = sigma * sigma;
    let innovation = 0.05;
    let outcome = ekf.fuse_scalar(&row, innovation, sigma);
    assert!(matches!(outcome, ScalarOutcome::Accepted(_)));
    let s = (h.transpose() * p * h)[(0, 0)] + r;
    let k = p * h / s;
    let expected_p = p - k * h.transpose() * p;
    let expected_dx = k * innovation;
    assert!((ekf.covariance() - expected_p).abs().max() < 1e-12);
    assert!((ekf.error_estimate() - expected_dx).abs().max() < 1e-15);
    assert_eq!(ekf.covariance(), ekf.covariance().transpose());
}

#[test]
fn innovation_gate_rejects_outliers_and_counts_them() {
    let mut config = EkfConfig::<f64>::automotive_mems();
    config.innovation_gate = 9.0; // 3 sigma
    let mut ekf = NavEkf::<f64>::new(config, initial_sigmas());
    // Position sigma 5 m prior, 1 m measurement: S = 26 m², 3-sigma gate at 15.3 m.
    let outcome = ekf.fuse_gnss_position(&Vector3::new(100.0, 2.0, -40.0), &Vector3::repeat(1.0));
    assert_eq!(
        (outcome.accepted, outcome.rejected, outcome.faults),
        (1, 2, 0)
    );
    assert_eq!(ekf.stats().gnss_position.rejected, 2);
    assert_eq!(ekf.stats().gnss_position.accepted, 1);
    assert!(ekf.error_estimate()[POS] == 0.0 && ekf.error_estimate()[POS + 2] == 0.0);
    assert!((ekf.error_estimate()[POS + 1] - 2.0 * 25.0 / 26.0).abs() < 1e-12);
    // A negative variance is a numerical fault, not an update.
    let outcome = ekf.fuse_gnss_velocity(&Vector3::new(0.1, 0.1, 0.1), &Vector3::repeat(f64::NAN));
    assert_eq!(outcome.faults, 3);
    // A non-positive step is refused and leaves the covariance alone.
    let p = ekf.covariance();
    assert!(!ekf.predict(&linearization(0.0, 1.0), -0.01));
    assert_eq!(ekf.covariance(), p);
    assert_eq!(ekf.stats().rejected_predictions, 1);
}

/// Calibration error applied as in `reset`: true `C_b^s = exp(−δψ) Ĉ`, `r = r̂ + δr`.
fn perturbed(cal: &InterImuCalibration<f64>, delta: &[f64; 6]) -> InterImuCalibration<f64> {
    let dpsi = Vector3::new(delta[0], delta[1], delta[2]);
    InterImuCalibration {
        q_b_to_s: UnitQuaternion::from_scaled_axis(-dpsi) * cal.q_b_to_s,
        lever_arm_b_m: cal.lever_arm_b_m + Vector3::new(delta[3], delta[4], delta[5]),
    }
}

/// The inter-IMU measurement of eqs. (8)-(9) with the reference's bias errors `db_g`,
/// `db_a` (true minus nominal) left in its bias-corrected samples: the rate and force the
/// extra IMU reads. The lever-arm term keeps the nominal rate (its change with the gyro bias,
/// 2 |ω| |r| per unit of bias, is the one term the filter neglects).
fn inter_imu_model(
    c: &InterImuCalibration<f64>,
    db_g: Vector3<f64>,
    db_a: Vector3<f64>,
    (omega, omega_dot, f_b): (Vector3<f64>, Vector3<f64>, Vector3<f64>),
) -> [Vector3<f64>; 2] {
    let c_b_s = c.c_b_s();
    let r = c.lever_arm_b_m;
    let rate = c_b_s * (omega - db_g);
    let force = c_b_s * (f_b - db_a + omega_dot.cross(&r) + omega.cross(&omega.cross(&r)));
    [rate, force]
}

#[test]
fn inter_imu_jacobian_matches_finite_differences_of_eqs_8_and_9() {
    let cal = InterImuCalibration {
        q_b_to_s: UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        lever_arm_b_m: Vector3::new(0.3, -0.2, 0.1),
    };
    let motion = (
        Vector3::new(0.4, -0.7, 1.1),
        Vector3::new(2.0, 1.0, -1.5),
        Vector3::new(1.0, -0.5, -9.6),
    );
    // The states the measurement depends on: boresight, lever arm, then the reference's
    // gyro and accelerometer biases.
    let states: [usize; 12] = core::array::from_fn(|j| match j {
        0..=5 => boresight_index(0) + j,
        6..=8 => GYRO_BIAS + j - 6,
        _ => ACCEL_BIAS + j - 9,
    });
    let model_at = |delta: &[f64; 12]| {
        let v = |i: usize| Vector3::new(delta[i], delta[i + 1], delta[i + 2]);
        let mut calibration = [0.0; 6];
        calibration.copy_from_slice(&delta[..6]);
        inter_imu_model(&perturbed(&cal, &calibration), v(6), v(9), motion)
    };
    // Read the filter's H rows through its gains: with P = I and a huge R for one scalar
    // (and effectively infinite R for the others), the update is δx = P h ν / S ≈ h ν / R.
    let base = model_at(&[0.0; 12]);
    let p = SMatrix::<f64, 21, 21>::identity();
    for (kind, axis) in (0..2).flat_map(|k| (0..3).map(move |a| (k, a))) {
        let mut fd = [0.0; 12];
        for (j, slot) in fd.iter_mut().enumerate() {
            let eps = 1e-6;
            let mut plus = [0.0; 12];
            plus[j] = eps;
            let mut minus = [0.0; 12];
            minus[j] = -eps;
            *slot = (model_at(&plus)[kind][axis] - model_at(&minus)[kind][axis]) / (2.0 * eps);
        }
        let mut probe = NavEkf1::<f64>::new(EkfConfig::automotive_mems(), initial_sigmas());
        probe.set_calibration(0, cal);
        probe.set_covariance(&p);
        let mut sample = InterImuSample {
            omega_ib_b_rad_s: motion.0,
            omega_dot_ib_b_rad_s2: motion.1,
            f_b_m_s2: motion.2,
            omega_is_s_rad_s: base[0],
            f_s_m_s2: base[1],
            shares_reference_bias: false,
        };
        let big = 1e9;
        let mut sig_rate = Vector3::repeat(1e30);
        let mut sig_force = Vector3::repeat(1e30);
        if kind == 0 {
            sample.omega_is_s_rad_s[axis] += big;
            sig_rate[axis] = 1e12;
        } else {
            sample.f_s_m_s2[axis] += big;
            sig_force[axis] = 1e12;
        }
        probe.fuse_inter_imu(0, &sample, &sig_rate, &sig_force);
        // dx = P h ν / S with S ≈ R: h_j = dx_j R / ν.
        let r = 1e24;
        for (j, expected) in fd.iter().enumerate() {
            let h_j = probe.error_estimate()[states[j]] * r / big;
            assert!(
                (h_j - expected).abs() < 1e-5 * (1.0 + expected.abs()),
                "kind {kind} axis {axis} state {j}: filter {h_j}, finite difference {expected}"
            );
        }
    }
}

#[test]
fn an_extra_imu_debiased_against_the_reference_leaves_the_bias_states_alone() {
    // The reference's bias error is then in both readings, so the update must not learn it.
    let mut ekf = NavEkf1::<f64>::new(EkfConfig::automotive_mems(), initial_sigmas());
    let sample = InterImuSample {
        omega_ib_b_rad_s: Vector3::new(0.3, -0.2, 0.5),
        omega_dot_ib_b_rad_s2: Vector3::new(1.0, 0.0, -1.0),
        f_b_m_s2: Vector3::new(0.5, 0.2, -9.8),
        omega_is_s_rad_s: Vector3::new(0.31, -0.2, 0.49),
        f_s_m_s2: Vector3::new(0.6, 0.1, -9.7),
        shares_reference_bias: true,
    };
    let batch = ekf
        .fuse_inter_imu(0, &sample, &Vector3::repeat(0.01), &Vector3::repeat(0.1))
        .unwrap();
    assert_eq!(batch.accepted, 6);
    let dx = ekf.error_estimate();
    assert!((0..6).all(|i| dx[ACCEL_BIAS + i] == 0.0), "{dx:?}");
    assert!(dx[boresight_index(0)].abs() > 0.0);
}

/// After one coupled prediction from a diagonal covariance, the velocity-, attitude- and
/// lever-arm cross-covariances of the first extra unit's calibration, physical units.
fn coupled_cross_covariances<T: FilterScalar>(dt_s: f64) -> [Matrix3<f64>; 3] {
    let c = |x: f64| nalgebra::convert::<f64, T>(x);
    let mut ekf = NavEkf2::<T>::new(EkfConfig::automotive_mems(), initial_sigmas());
    // A turned unit: the error lands in body axes through its estimated C_s^b.
    let turned = UnitQuaternion::from_euler_angles(c(0.0), c(0.0), c(0.5 * core::f64::consts::PI));
    ekf.set_calibration(
        0,
        InterImuCalibration {
            q_b_to_s: turned,
            lever_arm_b_m: Vector3::zeros(),
        },
    );
    let lin = linearization(0.3, 12.0);
    let lin_t = NavLinearization {
        c_b_n: lin.c_b_n.map(c),
        f_b_m_s2: lin.f_b_m_s2.map(c),
        v_ned_m_s: lin.v_ned_m_s.map(c),
        omega_ie_n_rad_s: lin.omega_ie_n_rad_s.map(c),
        omega_en_n_rad_s: lin.omega_en_n_rad_s.map(c),
        gravity_m_s2: c(lin.gravity_m_s2),
        meridian_radius_plus_h_m: c(lin.meridian_radius_plus_h_m),
        transverse_radius_plus_h_m: c(lin.transverse_radius_plus_h_m),
        tan_lat: c(lin.tan_lat),
    };
    let coupling = CalibrationCoupling {
        omega_b_rad_s: Vector3::new(c(0.1), c(-0.2), c(0.5)),
        gyro_share: [c(0.3), c(0.3)],
        accel_share: [c(0.25), c(0.25)],
    };
    assert!(ekf.predict_coupled(&lin_t, Some(&coupling), c(dt_s)));
    let p = ekf.covariance_f64();
    let (psi, arm) = (boresight_index(0), lever_arm_index(0));
    [
        p.fixed_view::<3, 3>(VEL, psi).into_owned(),
        p.fixed_view::<3, 3>(ATT, psi).into_owned(),
        p.fixed_view::<3, 3>(VEL, arm).into_owned(),
    ]
}

#[test]
fn a_fused_imu_carries_its_units_calibration_errors_into_velocity_and_attitude() {
    // The fused output turns each unit by its estimated calibration: a boresight error tilts
    // the fused rate by w [ω×] C_s^b δψ and force by w [f×] C_s^b δψ, a lever-arm error moves
    // the force by w Ω Ω δr, each entering as a bias error does (−C_b^n dt per unit).
    let dt = 0.01;
    let lin = linearization(0.3, 12.0);
    let c_s_b = Rotation3::from_euler_angles(0.0, 0.0, 0.5 * core::f64::consts::PI)
        .into_inner()
        .transpose();
    let omega = Vector3::new(0.1, -0.2, 0.5);
    let (var_psi, var_arm) = (20f64.to_radians().powi(2), 0.2f64.powi(2));
    let to_nav = -lin.c_b_n * dt;
    let expected = [
        to_nav * skew(&lin.f_b_m_s2) * c_s_b * 0.25 * var_psi,
        to_nav * skew(&omega) * c_s_b * 0.3 * var_psi,
        to_nav * skew(&omega) * skew(&omega) * 0.25 * var_arm,
    ];
    let f64_cross = coupled_cross_covariances::<f64>(dt);
    let fixed_cross = coupled_cross_covariances::<I32F32>(dt);
    for (k, want) in expected.iter().enumerate() {
        let scale = want.abs().max();
        assert!(scale > 0.0);
        assert!(
            (f64_cross[k] - want).abs().max() < 1e-9 * scale,
            "block {k}: {} vs {want}",
            f64_cross[k]
        );
        assert!(
            (fixed_cross[k] - want).abs().max() < 1e-4 * scale,
            "fixed point, block {k}: {} vs {want}",
            fixed_cross[k]
        );
    }
    // Without the coupling the calibrations stay out of the navigation errors.
    let mut plain = NavEkf2::<f64>::new(EkfConfig::automotive_mems(), initial_sigmas());
    assert!(plain.predict(&lin, dt));
    let p = plain.covariance_f64();
    assert_eq!(
        p.fixed_view::<6, 12>(VEL, boresight_index(0)).abs().max(),
        0.0
    );
}

#[test]
fn reset_folds_calibration_error_into_nominal_with_the_documented_convention() {
    let mut ekf = NavEkf1::<f64>::new(EkfConfig::automotive_mems(), reference_grade_sigmas());
    let truth = InterImuCalibration {
        q_b_to_s: UnitQuaternion::from_scaled_axis(-Vector3::new(0.01, -0.02, 0.015)),
        lever_arm_b_m: Vector3::new(0.1, 0.0, -0.05),
    };
    // Noise-free rate and force updates along two different rotations pin the calibration.
    for i in 0..400 {
        let t = i as f64 * 0.05;
        let omega = Vector3::new((1.3 * t).sin(), (0.7 * t).cos(), 0.5 * (2.1 * t).sin());
        let omega_dot = Vector3::new(
            1.3 * (1.3 * t).cos(),
            -0.7 * (0.7 * t).sin(),
            1.05 * (2.1 * t).cos(),
        );
        let f_b = Vector3::new(0.3 * t.sin(), -0.2, -9.8);
        let c = truth.c_b_s();
        let r = truth.lever_arm_b_m;
        // The reference samples are corrected with the filter's nominal biases, as a
        // mechanization does.
        let sample = InterImuSample {
            omega_ib_b_rad_s: omega - ekf.gyro_bias_b_rad_s(),
            omega_dot_ib_b_rad_s2: omega_dot,
            f_b_m_s2: f_b - ekf.accel_bias_b_m_s2(),
            omega_is_s_rad_s: c * omega,
            f_s_m_s2: c * (f_b + omega_dot.cross(&r) + omega.cross(&omega.cross(&r))),
            shares_reference_bias: false,
        };
        ekf.fuse_inter_imu(0, &sample, &Vector3::repeat(1e-4), &Vector3::repeat(1e-3));
        ekf.reset();
    }
    let est = ekf.calibration(0).copied().unwrap();
    assert!((est.boresight_rad() - Vector3::new(0.01, -0.02, 0.015)).norm() < 1e-6);
    // The reference's bias states take part of the force updates' information: 0.05 mm.
    assert!(
        (est.lever_arm_b_m - truth.lever_arm_b_m).norm() < 5e-5,
        "{:?} {:?} {:?}",
        est.lever_arm_b_m,
        ekf.accel_bias_b_m_s2(),
        ekf.gyro_bias_b_rad_s()
    );
}

#[test]
fn rate_differentiator_is_exact_for_quadratic_rates_and_delays_one_sample() {
    let mut diff = RateDifferentiator::<f64, usize>::new();
    let omega = |t: f64| Vector3::new(t * t, 1.0 - 2.0 * t, 0.5 * t * t + t);
    let times = [0.0, 0.01, 0.025, 0.03, 0.05];
    let mut outputs = 0;
    for (i, &t) in times.iter().enumerate() {
        let dt = if i == 0 { 0.01 } else { t - times[i - 1] };
        if let Some((w, w_dot, idx)) = diff.push(dt, omega(t), i) {
            assert_eq!(idx, i - 1);
            let tm = times[i - 1];
            assert!((w - omega(tm)).norm() < 1e-15);
            // Central difference over unequal steps is exact for the mean slope of a quadratic
            // over [t_{i-2}, t_i], i.e. its derivative at the interval midpoint.
            let t_mid = 0.5 * (times[i - 2] + t);
            let exact = Vector3::new(2.0 * t_mid, -2.0, t_mid + 1.0);
            assert!((w_dot - exact).norm() < 1e-9, "{w_dot} vs {exact}");
            outputs += 1;
        }
    }
    assert_eq!(outputs, 3);
    // A gap restarts it.
    assert!(diff.push(0.0, omega(1.0), 9).is_none());
    assert!(diff.push(0.01, omega(1.01), 10).is_none());
    assert!(diff.push(0.01, omega(1.02), 11).is_some());
}

// ---------------------------------------------------------------------------------------
// Synthetic rich motion for the calibration tests: analytic attitude and position, flat
// non-rotating Earth (the inter-IMU relations (8)–(9) are kinematic and hold regardless).

struct Motion {
    t_s: f64,
    c_b_n: Matrix3<f64>,
    v_ned_m_s: Vector3<f64>,
    omega_ib_b_rad_s: Vector3<f64>,
    omega_dot_ib_b_rad_s2: Vector3<f64>,
    f_b_m_s2: Vector3<f64>,
}

fn euler(t: f64) -> (f64, f64, f64) {
    let tau = core::f64::consts::TAU;
    (
        0.25 * (tau * 0.31 * t).sin(),
        0.2 * (tau * 0.17 * t + 0.4).sin(),
        0.4 * t + 0.6 * (tau * 0.09 * t).sin(),
    )
}

fn body_rate(t: f64) -> Vector3<f64> {
    let h = 1e-5;
    let (r0, p0, y0) = euler(t - h);
    let (r1, p1, y1) = euler(t + h);
    let (r, p, _) = euler(t);
    let (dr, dp, dy) = (
        (r1 - r0) / (2.0 * h),
        (p1 - p0) / (2.0 * h),
        (y1 - y0) / (2.0 * h),
    );
    Vector3::new(
        dr - dy * p.sin(),
        dp * r.cos() + dy * r.sin() * p.cos(),
        -dp * r.sin() + dy * r.cos() * p.cos(),
    )
}

fn motion(t: f64) -> Motion {
    let tau = core::f64::consts::TAU;
    let (r, p, y) = euler(t);
    let c_b_n = Rotation3::from_euler_angles(r, p, y).into_inner();
    let h = 1e-4;
    let omega_dot = (body_rate(t + h) - body_rate(t - h)) / (2.0 * h);
    // Position: a weaving, accelerating path; velocity and acceleration analytic.
    let (w1, w2, w3) = (tau * 0.05, tau * 0.13, tau * 0.21);
    let v = Vector3::new(
        10.0 + 4.0 * w1 * (w1 * t).cos(),
        3.0 * w2 * (w2 * t).cos(),
        0.3 * w3 * (w3 * t).cos(),
    );
    let a = Vector3::new(
        -4.0 * w1 * w1 * (w1 * t).sin(),
        -3.0 * w2 * w2 * (w2 * t).sin(),
        -0.3 * w3 * w3 * (w3 * t).sin(),
    );
    let g_n = Vector3::new(0.0, 0.0, 9.81);
    Motion {
        t_s: t,
        c_b_n,
        v_ned_m_s: v,
        omega_ib_b_rad_s: body_rate(t),
        omega_dot_ib_b_rad_s2: omega_dot,
        f_b_m_s2: c_b_n.transpose() * (a - g_n),
    }
}

/// One epoch of synthetic data for the calibration run: reference and extra-IMU readings
/// with seeded Gaussian noise.
#[derive(Clone, Copy)]
struct CalEpoch {
    motion_lin_c_b_n: Matrix3<f64>,
    v_ned_m_s: Vector3<f64>,
    ref_omega: Vector3<f64>,
    ref_f: Vector3<f64>,
    extra_omega: Vector3<f64>,
    extra_f: Vector3<f64>,
}

const TRUE_BORESIGHT_DEG: [f64; 3] = [2.0, -1.0, 3.0];
const TRUE_LEVER_ARM_M: [f64; 3] = [0.3, -0.2, 0.1];
const RATE_HZ: f64 = 100.0;
const SIGMA_EXTRA_GYRO_RAD_S: f64 = 0.01;
const SIGMA_EXTRA_ACCEL_M_S2: f64 = 0.03;
const SIGMA_REF_GYRO_RAD_S: f64 = 1e-4;
const SIGMA_REF_ACCEL_M_S2: f64 = 2e-4;

fn true_calibration() -> InterImuCalibration<f64> {
    let psi = Vector3::from(TRUE_BORESIGHT_DEG.map(f64::to_radians));
    InterImuCalibration {
        // C_s^b = exp([ψ×]) ⇒ C_b^s = exp(−[ψ×]).
        q_b_to_s: UnitQuaternion::from_scaled_axis(-psi),
        lever_arm_b_m: Vector3::from(TRUE_LEVER_ARM_M),
    }
}

fn calibration_data(seconds: f64, seed: u64) -> Vec<CalEpoch> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let unit = Normal::new(0.0, 1.0).unwrap();
    let mut noise = |sigma: f64| {
        Vector3::new(
            sigma * unit.sample(&mut rng),
            sigma * unit.sample(&mut rng),
            sigma * unit.sample(&mut rng),
        )
    };
    let truth = true_calibration();
    let c_b_s = truth.c_b_s();
    let r = truth.lever_arm_b_m;
    let n = (seconds * RATE_HZ) as usize;
    (0..n)
        .map(|i| {
            let m = motion(i as f64 / RATE_HZ);
            let w = m.omega_ib_b_rad_s;
            let f_at_s = m.f_b_m_s2 + m.omega_dot_ib_b_rad_s2.cross(&r) + w.cross(&w.cross(&r));
            CalEpoch {
                motion_lin_c_b_n: m.c_b_n,
                v_ned_m_s: m.v_ned_m_s,
                ref_omega: w + noise(SIGMA_REF_GYRO_RAD_S),
                ref_f: m.f_b_m_s2 + noise(SIGMA_REF_ACCEL_M_S2),
                extra_omega: c_b_s * w + noise(SIGMA_EXTRA_GYRO_RAD_S),
                extra_f: c_b_s * f_at_s + noise(SIGMA_EXTRA_ACCEL_M_S2),
            }
        })
        .collect()
}

/// Per-epoch calibration estimate and sigma: boresight (rad), lever arm (m).
struct CalTrace {
    boresight_rad: Vec<Vector3<f64>>,
    lever_arm_m: Vec<Vector3<f64>>,
    sigma: Vec<[f64; 6]>,
    accepted: u32,
    rejected: u32,
}

/// Runs the reference filter with one extra IMU in scalar type `T` over `data`: prediction at
/// every sample, inter-IMU update at every sample (with the differenced angular acceleration).
fn run_calibration<T: FilterScalar>(data: &[CalEpoch]) -> CalTrace {
    let c = |x: f64| nalgebra::convert::<f64, T>(x);
    let v3 = |v: &Vector3<f64>| Vector3::new(c(v.x), c(v.y), c(v.z));
    let back = |v: Vector3<T>| {
        Vector3::new(
            nalgebra::try_convert::<T, f64>(v.x).unwrap_or(f64::NAN),
            nalgebra::try_convert::<T, f64>(v.y).unwrap_or(f64::NAN),
            nalgebra::try_convert::<T, f64>(v.z).unwrap_or(f64::NAN),
        )
    };
    let mut ekf = NavEkf1::<T>::new(EkfConfig::automotive_mems(), reference_grade_sigmas());
    let dt = c(1.0 / RATE_HZ);
    // Rate noise: both gyros; force noise: both accelerometers plus the differenced
    // reference rate noise (√2 σ / (2 dt)) times the lever arm (≤ 0.4 m).
    let sigma_rate = Vector3::repeat(c((SIGMA_EXTRA_GYRO_RAD_S.powi(2)
        + SIGMA_REF_GYRO_RAD_S.powi(2))
    .sqrt()));
    let omega_dot_noise = SIGMA_REF_GYRO_RAD_S * 2f64.sqrt() / (2.0 / RATE_HZ);
    let sigma_force = Vector3::repeat(c((SIGMA_EXTRA_ACCEL_M_S2.powi(2)
        + SIGMA_REF_ACCEL_M_S2.powi(2)
        + (0.4 * omega_dot_noise).powi(2))
    .sqrt()));
    let mut diff = RateDifferentiator::<T, usize>::new();
    let mut trace = CalTrace {
        boresight_rad: Vec::new(),
        lever_arm_m: Vec::new(),
        sigma: Vec::new(),
        accepted: 0,
        rejected: 0,
    };
    for (i, epoch) in data.iter().enumerate() {
        let lin = NavLinearization::from_geodetic(
            c(46.5f64.to_radians()),
            c(400.0),
            v3(&epoch.v_ned_m_s),
            Matrix3::from_fn(|r, col| c(epoch.motion_lin_c_b_n[(r, col)])),
            v3(&epoch.ref_f),
        );
        ekf.predict(&lin, dt);
        if let Some((omega, omega_dot, mid)) = diff.push(dt, v3(&epoch.ref_omega), i) {
            let m = &data[mid];
            let sample = InterImuSample {
                omega_ib_b_rad_s: omega - ekf.gyro_bias_b_rad_s(),
                omega_dot_ib_b_rad_s2: omega_dot,
                f_b_m_s2: v3(&m.ref_f) - ekf.accel_bias_b_m_s2(),
                omega_is_s_rad_s: v3(&m.extra_omega),
                f_s_m_s2: v3(&m.extra_f),
                shares_reference_bias: false,
            };
            if let Some(batch) = ekf.fuse_inter_imu(0, &sample, &sigma_rate, &sigma_force) {
                trace.accepted += u32::from(batch.accepted);
                trace.rejected += u32::from(batch.rejected);
            }
            ekf.reset();
        }
        let cal = ekf
            .calibration(0)
            .copied()
            .unwrap_or(InterImuCalibration::identity());
        trace.boresight_rad.push(back(cal.boresight_rad()));
        trace.lever_arm_m.push(back(cal.lever_arm_b_m));
        let mut sigma = [0.0; 6];
        for (j, s) in sigma.iter_mut().enumerate() {
            *s = ekf
                .sigma(boresight_index(0) + j)
                .and_then(|x| nalgebra::try_convert::<T, f64>(x))
                .unwrap_or(f64::NAN);
        }
        trace.sigma.push(sigma);
    }
    trace
}

#[test]
fn boresight_and_lever_arm_converge_within_three_sigma_from_20_deg_20_cm_priors() {
    // GIVEN a reference IMU along rich 3-D motion and an extra IMU rotated by (2, −1, 3) deg
    // and displaced by (0.3, −0.2, 0.1) m, with MEMS-level noise
    let data = calibration_data(60.0, 0x5eed_0001);
    // WHEN the reference filter runs the joint boresight/lever-arm update (eqs. 8–12) from
    // identity and zero with 20 deg and 20 cm one-sigma priors
    let trace = run_calibration::<f64>(&data);
    // THEN the estimates end within 3 sigma of the truth, with sigmas far below the priors
    let truth_psi = Vector3::from(TRUE_BORESIGHT_DEG.map(f64::to_radians));
    let truth_arm = Vector3::from(TRUE_LEVER_ARM_M);
    let last = data.len() - 1;
    let sigma = trace.sigma[last];
    for axis in 0..3 {
        let psi_err = trace.boresight_rad[last][axis] - truth_psi[axis];
        let arm_err = trace.lever_arm_m[last][axis] - truth_arm[axis];
        assert!(
            psi_err.abs() < 3.0 * sigma[axis],
            "boresight axis {axis}: error {psi_err:e} rad, sigma {:e}",
            sigma[axis]
        );
        assert!(
            arm_err.abs() < 3.0 * sigma[3 + axis],
            "lever arm axis {axis}: error {arm_err:e} m, sigma {:e}",
            sigma[3 + axis]
        );
        // Useful accuracy, not merely consistency: better than 0.05 deg and 5 mm.
        assert!(psi_err.abs() < 0.05f64.to_radians());
        assert!(arm_err.abs() < 0.005);
    }
    // AND the sigmas shrink: after 1 s well below the priors, and monotonically over the run
    // (no process noise on constant states). Slower than 1/sqrt(t) after 10 s: the
    // reference's gyro bias walks, and the rate updates share what they say between it and
    // the boresight.
    let one_second = RATE_HZ as usize;
    for j in 0..6 {
        let prior = if j < 3 { 20f64.to_radians() } else { 0.2 };
        assert!(
            trace.sigma[one_second][j] < 0.2 * prior,
            "state {j} after 1 s: {}",
            trace.sigma[one_second][j]
        );
        assert!(
            trace.sigma[last][j] < 0.8 * trace.sigma[10 * one_second][j],
            "state {j}: {} after 10 s, {} at the end",
            trace.sigma[10 * one_second][j],
            trace.sigma[last][j]
        );
        for w in trace.sigma.windows(2) {
            assert!(w[1][j] <= w[0][j] * (1.0 + 1e-12), "state {j} sigma grew");
        }
    }
    // The gate (5 sigma) let consistent data through.
    assert!(
        trace.rejected * 1000 < trace.accepted,
        "{} rejected of {}",
        trace.rejected,
        trace.accepted
    );
}

#[test]
fn f32_filter_tracks_f64_filter_on_the_same_calibration_data() {
    // GIVEN the same 60 s of synthetic data
    let data = calibration_data(60.0, 0x5eed_0002);
    // WHEN the filter runs in f32 (board) and f64 (host)
    let wide = run_calibration::<f64>(&data);
    let narrow = run_calibration::<f32>(&data);
    // THEN the estimates agree to well within their uncertainty at every epoch after the
    // first second, and the largest divergence is small in absolute terms.
    let mut worst_psi: f64 = 0.0;
    let mut worst_arm: f64 = 0.0;
    let mut worst_ratio: f64 = 0.0;
    for i in RATE_HZ as usize..data.len() {
        let dpsi = (wide.boresight_rad[i] - narrow.boresight_rad[i]).abs();
        let darm = (wide.lever_arm_m[i] - narrow.lever_arm_m[i]).abs();
        worst_psi = worst_psi.max(dpsi.max());
        worst_arm = worst_arm.max(darm.max());
        for axis in 0..3 {
            worst_ratio = worst_ratio
                .max(dpsi[axis] / wide.sigma[i][axis])
                .max(darm[axis] / wide.sigma[i][3 + axis]);
        }
    }
    println!(
        "f32 vs f64: largest boresight divergence {:.3e} deg, lever arm {:.3e} mm, {:.3} sigma",
        worst_psi.to_degrees(),
        worst_arm * 1e3,
        worst_ratio
    );
    assert!(
        worst_psi < 1e-3f64.to_radians(),
        "boresight f32/f64 divergence {worst_psi:e} rad"
    );
    assert!(
        worst_arm < 1e-4,
        "lever arm f32/f64 divergence {worst_arm:e} m"
    );
    assert!(worst_ratio < 0.1, "divergence {worst_ratio} sigma");
}

// ---------------------------------------------------------------------------------------
// Method II-A: attitude update of a filter mechanising the extra IMU.

#[test]
fn attitude_update_method_recovers_boresight_and_separates_it_from_attitude_error() {
    // GIVEN a filter whose body is the extra IMU s, with a nominal attitude off the truth by
    // a constant NED-frame error ε, and reference attitudes C_b^n = C_s^n C_b^s
    let truth = true_calibration();
    let eps_true = Vector3::new(0.004, -0.003, 0.01);
    let mut ekf = NavEkf1::<f64>::new(EkfConfig::automotive_mems(), initial_sigmas());
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed_0003);
    let noise = Normal::new(0.0, 1e-3).unwrap();
    let sigma_rad = Vector3::repeat(1e-3);
    let mut applied_eps = Vector3::zeros();
    for i in 0..3000 {
        let m = motion(i as f64 / RATE_HZ);
        // True s attitude: C_s^n = C_b^n C_s^b.
        let c_s_n_true = m.c_b_n * truth.c_b_s().transpose();
        // Nominal = (I + [ε×])⁻¹ truth, with the filter's corrections folded in so far.
        let remaining = eps_true - applied_eps;
        let c_s_n_nominal = UnitQuaternion::from_scaled_axis(-remaining)
            .to_rotation_matrix()
            .into_inner()
            * c_s_n_true;
        let lin = NavLinearization::from_geodetic(
            0.8,
            400.0,
            m.v_ned_m_s,
            c_s_n_nominal,
            Vector3::new(0.0, 0.0, -9.81),
        );
        ekf.predict(&lin, 1.0 / RATE_HZ);
        if i % 10 == 0 {
            let n = Vector3::new(
                noise.sample(&mut rng),
                noise.sample(&mut rng),
                noise.sample(&mut rng),
            );
            let c_b_n_ref = UnitQuaternion::from_scaled_axis(n)
                .to_rotation_matrix()
                .into_inner()
                * m.c_b_n;
            ekf.fuse_attitude(0, &c_b_n_ref, &c_s_n_nominal, &sigma_rad);
            let correction = ekf.reset();
            applied_eps += correction.attitude_ned_rad;
        }
        let _ = m.t_s;
    }
    // THEN the boresight is recovered within 3 sigma and the attitude error is absorbed
    let est = ekf.calibration(0).unwrap().boresight_rad();
    let truth_psi = Vector3::from(TRUE_BORESIGHT_DEG.map(f64::to_radians));
    for axis in 0..3 {
        let sigma = ekf.sigma(boresight_index(0) + axis).unwrap();
        let err = est[axis] - truth_psi[axis];
        assert!(
            err.abs() < 3.0 * sigma,
            "axis {axis}: error {err:e}, sigma {sigma:e}"
        );
        assert!(sigma < 1e-3, "axis {axis}: sigma {sigma:e}");
    }
    assert!(
        (applied_eps - eps_true).norm() < 2e-3,
        "attitude error left {:?}",
        eps_true - applied_eps
    );
    assert_eq!(ekf.stats().attitude.rejected, 0);
}

// ---------------------------------------------------------------------------------------
// Covariance health in f32 over long random sequences.

#[derive(Clone, Debug)]
enum Op {
    Predict {
        yaw: f32,
        pitch: f32,
        roll: f32,
        speed: f32,
        f: [f32; 3],
        dt: f32,
    },
    GnssPosition {
        innovation: [f32; 3],
        sigma: f32,
    },
    GnssVelocity {
        innovation: [f32; 3],
        sigma: f32,
    },
    Zupt {
        v: [f32; 3],
        sigma: f32,
    },
    InterImu {
        imu: usize,
        omega: [f32; 3],
        omega_dot: [f32; 3],
        f: [f32; 3],
        dz: [f32; 6],
        sigma_rate: f32,
        sigma_force: f32,
    },
    Attitude {
        imu: usize,
        rot: [f32; 3],
        sigma: f32,
    },
    Reset,
}

fn op_strategy() -> impl Strategy<Value = Op> {
    let v3 = |r: f32| prop::array::uniform3(-r..r);
    prop_oneof![
        6 => (-3.2f32..3.2, -0.5f32..0.5, -0.5f32..0.5, 0.0f32..40.0, v3(12.0), 0.001f32..0.05)
            .prop_map(|(yaw, pitch, roll, speed, f, dt)| Op::Predict { yaw, pitch, roll, speed, f: [f[0], f[1], f[2] - 9.8], dt }),
        1 => (v3(10.0), 0.005f32..20.0).prop_map(|(innovation, sigma)| Op::GnssPosition { innovation, sigma }),
        1 => (v3(1.0), 0.001f32..2.0).prop_map(|(innovation, sigma)| Op::GnssVelocity { innovation, sigma }),
        1 => (v3(0.5), 0.001f32..0.1).prop_map(|(v, sigma)| Op::Zupt { v, sigma }),
        3 => (0usize..2, v3(3.0), v3(20.0), v3(15.0), prop::array::uniform6(-0.5f32..0.5), 1e-4f32..0.05, 1e-3f32..0.5)
            .prop_map(|(imu, omega, omega_dot, f, dz, sigma_rate, sigma_force)| Op::InterImu { imu, omega, omega_dot, f: [f[0], f[1], f[2] - 9.8], dz, sigma_rate, sigma_force }),
        1 => (0usize..2, v3(0.05), 1e-4f32..0.05).prop_map(|(imu, rot, sigma)| Op::Attitude { imu, rot, sigma }),
        2 => Just(Op::Reset),
    ]
}

/// Applies `op` (its numbers given in f32) to a filter in scalar `T`.
fn apply<T: FilterScalar>(ekf: &mut NavEkf2<T>, op: &Op) {
    let c = |x: f32| nalgebra::convert::<f64, T>(f64::from(x));
    let v = |a: &[f32; 3]| Vector3::new(c(a[0]), c(a[1]), c(a[2]));
    match op {
        Op::Predict {
            yaw,
            pitch,
            roll,
            speed,
            f,
            dt,
        } => {
            let c_b_n = Rotation3::from_euler_angles(c(*roll), c(*pitch), c(*yaw)).into_inner();
            let v_ned = Vector3::new(speed * yaw.cos(), speed * yaw.sin(), 0.1).map(c);
            let lin = NavLinearization::from_geodetic(c(0.8), c(500.0), v_ned, c_b_n, v(f));
            ekf.predict(&lin, c(*dt));
        }
        Op::GnssPosition { innovation, sigma } => {
            ekf.fuse_gnss_position(&v(innovation), &Vector3::repeat(c(*sigma)));
        }
        Op::GnssVelocity { innovation, sigma } => {
            ekf.fuse_gnss_velocity(&v(innovation), &Vector3::repeat(c(*sigma)));
        }
        Op::Zupt { v: vel, sigma } => {
            ekf.fuse_zero_velocity(&v(vel), c(*sigma));
        }
        Op::InterImu {
            imu,
            omega,
            omega_dot,
            f,
            dz,
            sigma_rate,
            sigma_force,
        } => {
            let cal = *ekf.calibration(*imu).unwrap();
            let c_b_s = cal.c_b_s();
            let w = v(omega);
            let dz = dz.map(c);
            let sample = InterImuSample {
                omega_ib_b_rad_s: w,
                omega_dot_ib_b_rad_s2: v(omega_dot),
                f_b_m_s2: v(f),
                omega_is_s_rad_s: c_b_s * w + Vector3::new(dz[0], dz[1], dz[2]) * c(*sigma_rate),
                f_s_m_s2: c_b_s * v(f) + Vector3::new(dz[3], dz[4], dz[5]) * c(*sigma_force),
                shares_reference_bias: false,
            };
            ekf.fuse_inter_imu(
                *imu,
                &sample,
                &Vector3::repeat(c(*sigma_rate)),
                &Vector3::repeat(c(*sigma_force)),
            );
        }
        Op::Attitude { imu, rot, sigma } => {
            let c_s_n = Rotation3::from_euler_angles(c(0.1), c(0.2), c(1.0)).into_inner();
            let cal = *ekf.calibration(*imu).unwrap();
            let reference = UnitQuaternion::from_scaled_axis(v(rot))
                .to_rotation_matrix()
                .into_inner()
                * c_s_n
                * cal.c_b_s();
            ekf.fuse_attitude(*imu, &reference, &c_s_n, &Vector3::repeat(c(*sigma)));
        }
        Op::Reset => {
            ekf.reset();
        }
    }
}

/// Positive definiteness of the f32 matrix itself, checked by Cholesky in f64 after scaling
/// to unit diagonal (so the test is about correlations, not units).
fn is_positive_definite(p: &SMatrix<f32, 27, 27>) -> bool {
    let d: Vec<f64> = (0..27).map(|i| f64::from(p[(i, i)]).sqrt()).collect();
    if d.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
        return false;
    }
    let corr = SMatrix::<f64, 27, 27>::from_fn(|i, j| f64::from(p[(i, j)]) / (d[i] * d[j]));
    corr.cholesky().is_some()
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 24,
        rng_seed: RngSeed::Fixed(0x5eed_0004),
        failure_persistence: Some(Box::new(FileFailurePersistence::Off)),
        ..ProptestConfig::default()
    })]

    #[test]
    fn f32_covariance_stays_symmetric_positive_definite_over_long_random_runs(
        ops in prop::collection::vec(op_strategy(), 3000..6000)
    ) {
        let mut ekf = NavEkf2::<f32>::new(EkfConfig::automotive_mems(), initial_sigmas());
        for (i, op) in ops.iter().enumerate() {
            apply(&mut ekf, op);
            if i % 500 == 0 || i + 1 == ops.len() {
                let p = &ekf.covariance();
                prop_assert_eq!(p, &p.transpose(), "asymmetric after op {}", i);
                prop_assert!(is_positive_definite(p), "not positive definite after op {} ({:?})", i, op);
            }
        }
        prop_assert_eq!(ekf.stats().covariance_resets, 0);
    }

    #[test]
    fn fixed_point_filter_follows_the_f64_filter_over_random_runs(
        ops in prop::collection::vec(op_strategy(), 500..1500)
    ) {
        let before = crate::fixed::overflows();
        let mut wide = NavEkf2::<f64>::new(EkfConfig::automotive_mems(), initial_sigmas());
        let mut fixed = NavEkf2::<I32F32>::new(EkfConfig::automotive_mems(), initial_sigmas());
        for (i, op) in ops.iter().enumerate() {
            apply(&mut wide, op);
            apply(&mut fixed, op);
            let (gap_p, gap_dx) = gap_in_sigmas(&wide, &fixed);
            prop_assert!(
                gap_p < 1e-4 && gap_dx < 1e-4,
                "after op {} ({:?}): covariance {:e}, estimate {:e} sigmas apart", i, op, gap_p, gap_dx
            );
        }
        prop_assert_eq!(fixed.stats().covariance_resets, 0);
        prop_assert_eq!(crate::fixed::overflows(), before);
    }
}

/// How far the fixed-point filter lies from the f64 one: the largest covariance difference
/// as a fraction of `sqrt(P_ii P_jj)`, and the largest error-estimate difference in sigmas.
fn gap_in_sigmas(wide: &NavEkf2<f64>, fixed: &NavEkf2<I32F32>) -> (f64, f64) {
    let (p, q) = (wide.covariance(), fixed.covariance_f64());
    let sigma = |i: usize| p[(i, i)].sqrt();
    let mut gap_p = 0.0f64;
    let mut gap_dx = 0.0f64;
    for i in 0..27 {
        for j in 0..27 {
            gap_p = gap_p.max((p[(i, j)] - q[(i, j)]).abs() / (sigma(i) * sigma(j)));
        }
        let dx = fixed.error_estimate()[i].to_f64();
        gap_dx = gap_dx.max((wide.error_estimate()[i] - dx).abs() / sigma(i));
    }
    (gap_p, gap_dx)
}

#[test]
fn a_gauss_markov_bias_keeps_its_stationary_variance_at_any_step() {
    // sigma^2 = psd / (2 beta): 1e-4 for beta = 0.05 /s; also for a bias fitted with a
    // correlation time far below the step (beta = 1800 /s predicted every 10 ms).
    for (beta, dt) in [(0.05f64, 0.01), (0.05, 1.0), (1800.0, 0.01), (3.0, 0.5)] {
        let sigma2: f64 = 1e-4;
        let psd = 2.0 * sigma2 * beta;
        let (decay, q) = gauss_markov_step(beta, psd, dt);
        let mut p: f64 = 0.0;
        for _ in 0..200_000 {
            p = decay * decay * p + q;
        }
        assert!((p / sigma2 - 1.0).abs() < 1e-9, "beta {beta}, dt {dt}: {p}");
        assert!((decay - (-beta * dt).exp()).abs() < 1e-12);
    }
    // A random walk gains psd dt, and the series branch meets the exact form.
    assert_eq!(gauss_markov_step(0.0, 2.0, 0.01), (1.0, 0.02));
    let (series, exact): ((f64, f64), (f64, f64)) = (
        gauss_markov_step(0.999e-4, 1.0, 1.0),
        gauss_markov_step(1.001e-4, 1.0, 1.0),
    );
    assert!((series.0 - exact.0).abs() < 1e-6 && (series.1 - exact.1).abs() < 1e-6);
}

#[test]
fn a_fixed_point_overflow_in_an_update_is_counted_and_refused() {
    let fx = I32F32::from_f64;
    // GIVEN a fixed-point filter
    let mut ekf = NavEkf2::<I32F32>::new(EkfConfig::automotive_mems(), initial_sigmas());
    let before = crate::fixed::overflows();
    let p_before = ekf.covariance_f64();
    // WHEN a velocity arrives with a sigma so small that its whitened innovation (1e4 m/s
    // over 1e-6 m/s) leaves the Q32.32 range
    let outcome = ekf.fuse_gnss_velocity(&Vector3::repeat(fx(1.0e4)), &Vector3::repeat(fx(1.0e-6)));
    // THEN each overflow is counted, each update refused as a numerical fault, and the
    // filter is as it was
    assert!(crate::fixed::overflows() >= before + 3);
    assert_eq!(outcome.faults, 3);
    assert_eq!(ekf.stats().gnss_velocity.numerical_faults, 3);
    assert_eq!(ekf.covariance_f64(), p_before);
    assert!(ekf.error_estimate().iter().all(|x| *x == I32F32::ZERO));
}

#[test]
fn a_fixed_point_outlier_far_out_is_gated_without_overflow() {
    let fx = I32F32::from_f64;
    // GIVEN a fixed-point filter
    let mut ekf = NavEkf2::<I32F32>::new(EkfConfig::automotive_mems(), initial_sigmas());
    let before = crate::fixed::overflows();
    // WHEN a position 1 km off arrives with a 1 cm sigma (10^5 sigmas: its square would
    // leave the range)
    let outcome = ekf.fuse_gnss_position(&Vector3::repeat(fx(1.0e3)), &Vector3::repeat(fx(0.01)));
    // THEN the gate refuses it, as it would in floating point, and nothing overflowed
    assert_eq!(outcome.rejected, 3);
    assert_eq!(crate::fixed::overflows(), before);
}
