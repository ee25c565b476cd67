//! The simulator's physics and error effects, end to end through `dynacal::sim`: exact
//! kinematics (a strapdown integration of the error-free reference IMU reproduces the
//! trajectory), the Haar WV of simulated processes against their closed forms, and each
//! deterministic effect against its defining formula.

use std::path::Path;

use dynacal::gmwm::model::{ModelSpec, Process};
use dynacal::interchange::FileFormat;
use dynacal::model::Channel;
use dynacal::model::{ChannelModel, ImuModel};
use dynacal::sim::effects::sensor_kinematics;
use dynacal::sim::sensors::ImuRun;
use dynacal::sim::{simulate, Scenario, SimModel, SimOptions, SimOutput};
use dynacal::wv::{haar_wv, WvOptions};
use dynacal_core::nav::{radii, NavState, Strapdown};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use statrs::distribution::{ChiSquared, ContinuousCDF};

fn error_free(name: &str, rate_hz: f64) -> ImuModel {
    let mut m: ImuModel =
        serde_json::from_value(serde_json::json!({"name": name, "rate_hz": rate_hz})).unwrap();
    m.gyro = ChannelModel::default();
    m.accel = ChannelModel::default();
    m
}

/// A model with an error-free reference at `ref_rate_hz`, the given IMUs, no GNSS, no PPS.
fn model_with(ref_rate_hz: f64, imus: Vec<ImuModel>) -> SimModel {
    let mut m: SimModel = serde_json::from_str(r#"{"gnss": null, "pps": null}"#).unwrap();
    m.reference = error_free("reference", ref_rate_hz);
    m.imus = imus;
    m
}

fn run(model: &SimModel, scenario: Scenario, seconds: f64, seed: u64) -> SimOutput {
    let opts = SimOptions {
        scenario,
        seconds,
        seed,
        disabled: Vec::new(),
        keep_ideal: true,
    };
    simulate(model, &opts, &|_| {}).unwrap()
}

fn channel(run: &ImuRun, i: usize) -> &[f64] {
    let rec = &run.recording;
    if i < 3 {
        &rec.gyro_rad_s.as_ref().unwrap()[i]
    } else {
        &rec.accel_m_s2.as_ref().unwrap()[i - 3]
    }
}

fn error(run: &ImuRun, i: usize) -> Vec<f64> {
    let ideal = &run.ideal.as_ref().unwrap()[i];
    channel(run, i)
        .iter()
        .zip(ideal)
        .map(|(y, t)| y - t)
        .collect()
}

/// Integrates the reference IMU with the strapdown and returns the largest position (m),
/// velocity (m/s) and attitude (rad) errors against the recording's own truth columns.
fn strapdown_errors(run: &ImuRun) -> (f64, f64, f64) {
    let rec = &run.recording;
    let (g, a) = (
        rec.gyro_rad_s.as_ref().unwrap(),
        rec.accel_m_s2.as_ref().unwrap(),
    );
    let (att, pos, vel) = (
        rec.attitude_rad.as_ref().unwrap(),
        rec.position.as_ref().unwrap(),
        rec.velocity_ned_m_s.as_ref().unwrap(),
    );
    let v3 = |c: &[Vec<f64>; 3], k: usize| Vector3::new(c[0][k], c[1][k], c[2][k]);
    let mut nav = Strapdown::new(NavState::from_euler(
        att[0][0],
        att[1][0],
        att[2][0],
        v3(vel, 0),
        pos[0][0],
        pos[1][0],
        pos[2][0],
    ));
    let (mut e_pos, mut e_vel, mut e_att) = (0.0f64, 0.0f64, 0.0f64);
    for k in 1..rec.len() {
        let dt = rec.t_s[k] - rec.t_s[k - 1];
        nav.step_rates(v3(g, k - 1), v3(g, k), v3(a, k - 1), v3(a, k), dt)
            .unwrap();
        let s = nav.state();
        let r = radii(pos[0][k]);
        let dn = (s.lat_rad - pos[0][k]) * (r.meridian_m + pos[2][k]);
        let de = (s.lon_rad - pos[1][k]) * (r.transverse_m + pos[2][k]) * pos[0][k].cos();
        let dd = s.h_m - pos[2][k];
        e_pos = e_pos.max((dn * dn + de * de + dd * dd).sqrt());
        e_vel = e_vel.max((s.v_ned_m_s - v3(vel, k)).norm());
        e_att = e_att.max(s.q_nb.angle_to(&UnitQuaternion::from_euler_angles(
            att[0][k], att[1][k], att[2][k],
        )));
    }
    (e_pos, e_vel, e_att)
}

#[test]
fn error_free_reference_imu_integrated_by_the_strapdown_reproduces_ten_minutes_of_driving() {
    // GIVEN ten minutes of car motion (stops, turns, hills, lane changes, road and engine
    // vibration) and an error-free 1 kHz reference IMU
    let out = run(&model_with(1000.0, vec![]), Scenario::Car, 600.0, 21);
    // WHEN its rates and specific forces are integrated by the NED strapdown mechanization
    let (e_pos, e_vel, e_att) = strapdown_errors(&out.reference);
    println!(
        "1 kHz, 600 s: position {e_pos:.3e} m, velocity {e_vel:.3e} m/s, attitude {e_att:.3e} rad"
    );
    // THEN position, velocity and attitude follow the simulated truth (the residual is the
    // mechanization's second-order discretisation error on 26 Hz vibration)
    assert!(e_pos < 0.2, "position error {e_pos} m");
    assert!(e_vel < 1e-3, "velocity error {e_vel} m/s");
    assert!(e_att < 1e-6, "attitude error {e_att} rad");
}

#[test]
fn strapdown_error_shrinks_with_the_square_of_the_sample_interval() {
    // Exact kinematics means the only error left is the integrator's: O(dt^2). Any
    // inconsistency (a missing transport rate, a wrong gravity) would leave a floor instead.
    let mut errors = Vec::new();
    for rate in [200.0, 800.0] {
        let out = run(&model_with(rate, vec![]), Scenario::Car, 240.0, 5);
        errors.push(strapdown_errors(&out.reference));
    }
    println!("200 Hz {:?}, 800 Hz {:?}", errors[0], errors[1]);
    assert!(
        errors[0].0 / errors[1].0 > 10.0,
        "position error ratio {}",
        errors[0].0 / errors[1].0
    );
    assert!(
        errors[0].2 / errors[1].2 > 10.0,
        "attitude error ratio {}",
        errors[0].2 / errors[1].2
    );
}

/// Chi-square quantile by bisection on the CDF (statrs' inverse gives NaN far in the lower
/// tail at one degree of freedom).
fn quantile(chi: &ChiSquared, p: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 10.0 * chi.freedom() + 100.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi.cdf(mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Asserts the empirical Haar WV of `x` matches `theory` at every level within the 99.9%
/// chi-square interval, and within the 95% interval at 80% of the levels or more.
fn assert_wv_matches(x: &[f64], dt_s: f64, spec: &ModelSpec, what: &str) {
    let wv = haar_wv(x, dt_s, &WvOptions::default()).unwrap();
    let theory = spec.wv_at_levels(&wv.levels);
    let mut inside95 = 0;
    for (i, &nu) in wv.variance.iter().enumerate() {
        let eta = (wv.n_coefficients[i] as f64 / 2f64.powi(wv.levels[i] as i32)).max(1.0);
        let chi = ChiSquared::new(eta).unwrap();
        let (lo, hi) = (
            eta * nu / quantile(&chi, 0.9995),
            eta * nu / quantile(&chi, 0.0005),
        );
        assert!(
            theory[i] >= lo && theory[i] <= hi,
            "{what}: level {} theory {} outside 99.9% [{lo}, {hi}] (estimate {nu})",
            wv.levels[i],
            theory[i]
        );
        if theory[i] >= wv.ci_low[i] && theory[i] <= wv.ci_high[i] {
            inside95 += 1;
        }
    }
    assert!(
        inside95 as f64 >= 0.8 * wv.len() as f64,
        "{what}: only {inside95} of {} levels inside the 95% interval",
        wv.len()
    );
}

fn stochastic_imu(name: &str, spec: ModelSpec) -> ImuModel {
    let mut imu = error_free(name, spec.sample_rate_hz);
    imu.channels.insert(
        Channel::Gz,
        ChannelModel {
            stochastic: Some(spec),
            ..Default::default()
        },
    );
    imu
}

#[test]
fn haar_wv_of_simulated_white_noise_random_walk_and_gauss_markov_matches_closed_forms() {
    let spec = |model: &str, p: Process| ModelSpec {
        model: model.into(),
        unit: "rad/s".into(),
        sample_rate_hz: 100.0,
        processes: vec![p],
    };
    let wn = spec("WN", Process::WhiteNoise { sigma2: 2.5e-5 });
    let rw = spec("RW", Process::RandomWalk { sigma2: 1e-9 });
    let gm = spec(
        "GM",
        Process::GaussMarkov {
            beta_per_s: 0.5,
            sigma2: 4e-6,
        },
    );
    let imus = vec![
        stochastic_imu("wn", wn.clone()),
        stochastic_imu("rw", rw.clone()),
        stochastic_imu("gm", gm.clone()),
    ];
    let out = run(
        &model_with(100.0, imus),
        Scenario::Static,
        2f64.powi(17) / 100.0,
        77,
    );
    for (imu, spec) in out.imus.iter().zip([&wn, &rw, &gm]) {
        let e = error(imu, 2);
        assert_wv_matches(&e, 0.01, spec, &imu.name);
        // and the other channels carry no error at all
        assert!(error(imu, 0).iter().all(|v| *v == 0.0));
    }
}

fn example(name: &str) -> SimModel {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/models")
        .join(name);
    SimModel::load(&path).unwrap()
}

#[test]
fn table_one_example_models_carry_the_papers_parameters_and_simulate_them() {
    let deg2 = (std::f64::consts::PI / 180.0).powi(2);
    for (file, wn, gm1, gm2) in [
        (
            "table1-static.json",
            0.50552,
            (0.00492, 0.00142),
            (113.51523, 0.05528),
        ),
        (
            "table1-dynamic.json",
            0.65382,
            (0.00155, 0.00981),
            (1.68012, 0.00168),
        ),
    ] {
        let m = example(file);
        assert_eq!(m.imus.len(), 3);
        for imu in &m.imus {
            for i in 0..3 {
                let s = imu.channel(i).stochastic.as_ref().unwrap();
                assert_eq!((s.unit.as_str(), s.sample_rate_hz), ("deg/s", 100.0));
                assert_eq!(
                    s.processes,
                    vec![
                        Process::WhiteNoise { sigma2: wn },
                        Process::GaussMarkov {
                            beta_per_s: gm1.0,
                            sigma2: gm1.1
                        },
                        Process::GaussMarkov {
                            beta_per_s: gm2.0,
                            sigma2: gm2.1
                        }
                    ],
                    "{file}"
                );
            }
        }
        // The static model, simulated at rest: the gyro error's WV is the model's, in rad/s.
        if file == "table1-static.json" {
            let opts = SimOptions {
                scenario: Scenario::Static,
                seconds: 2f64.powi(18) / 100.0,
                seed: 9,
                disabled: vec![dynacal::model::Effect::Quantization],
                keep_ideal: true,
            };
            let out = simulate(&m, &opts, &|_| {}).unwrap();
            let mut spec = m.imus[0].channel(0).stochastic.clone().unwrap();
            spec.unit = "rad/s".into();
            for p in spec.processes.iter_mut() {
                match p {
                    Process::WhiteNoise { sigma2 } | Process::GaussMarkov { sigma2, .. } => {
                        *sigma2 *= deg2
                    }
                    _ => unreachable!(),
                }
            }
            assert_wv_matches(
                &error(&out.imus[0], 0),
                0.01,
                &spec,
                "Table I static, mtx1 gx",
            );
        }
    }
}

fn sf_imu() -> ImuModel {
    let mut imu = error_free("sf", 100.0);
    let sf = |s| ChannelModel {
        scale_factor: Some(s),
        ..Default::default()
    };
    imu.channels.insert(Channel::Gz, sf(3e-3));
    imu.channels.insert(Channel::Ax, sf(-5e-3));
    imu
}

#[test]
fn scale_factor_error_is_proportional_to_the_rate() {
    let mut imu = error_free("sf", 100.0);
    imu.channels.insert(
        Channel::Gz,
        ChannelModel {
            scale_factor: Some(3e-3),
            ..Default::default()
        },
    );
    imu.channels.insert(
        Channel::Ax,
        ChannelModel {
            scale_factor: Some(-5e-3),
            ..Default::default()
        },
    );
    let out = run(&model_with(100.0, vec![imu]), Scenario::Car, 300.0, 4);
    let r = &out.imus[0];
    for (i, s) in [(2usize, 3e-3), (3, -5e-3)] {
        let e = error(r, i);
        let ideal = &r.ideal.as_ref().unwrap()[i];
        let worst = e
            .iter()
            .zip(ideal)
            .map(|(e, y)| (e - s * y).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-14, "channel {i}: {worst}");
        let largest = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(
            largest > 1e-3 * s.abs(),
            "channel {i}: the car must turn/accelerate ({largest})"
        );
    }
    // switched off globally, the same model gives no error
    let opts = SimOptions {
        scenario: Scenario::Car,
        seconds: 60.0,
        seed: 4,
        disabled: vec![dynacal::model::Effect::ScaleFactor],
        keep_ideal: true,
    };
    let m = model_with(100.0, vec![sf_imu()]);
    let off = simulate(&m, &opts, &|_| {}).unwrap();
    assert!(error(&off.imus[0], 2).iter().all(|v| *v == 0.0));
}

#[test]
fn time_offset_error_is_minus_the_offset_times_the_derivative() {
    let delta = 5e-4;
    let mut imu = error_free("late", 200.0);
    imu.time_offset_s = delta;
    let out = run(&model_with(100.0, vec![imu]), Scenario::Car, 300.0, 8);
    let r = &out.imus[0];
    // error against the truth at the stamped time, and the derivative there
    let (mut sxy, mut sxx, mut syy, mut sres) = ([0.0; 6], [0.0; 6], [0.0; 6], [0.0; 6]);
    for (k, &t) in r.recording.t_s.iter().enumerate() {
        let kin = sensor_kinematics(&out.trajectory.truth(t), &r.mount);
        for i in 0..6 {
            let err = channel(r, i)[k] - kin.channel(i);
            let deriv = if i < 3 {
                kin.omega_dot_rad_s2[i]
            } else {
                kin.f_dot_m_s3[i - 3]
            };
            sxy[i] += err * deriv;
            sxx[i] += deriv * deriv;
            syy[i] += err * err;
            sres[i] += (err + delta * deriv).powi(2);
        }
    }
    for i in 0..6 {
        let slope = sxy[i] / sxx[i];
        println!(
            "channel {i}: slope {slope:.6e}, residual/error rms {:.3e}",
            (sres[i] / syy[i]).sqrt()
        );
        assert!(
            (slope / -delta - 1.0).abs() < 0.01,
            "channel {i}: slope {slope}"
        );
        assert!((sres[i] / syy[i]).sqrt() < 0.05, "channel {i}");
    }
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

#[test]
fn lever_arm_adds_the_tangential_and_centripetal_terms_of_eq_9() {
    let r = Vector3::new(1.2, -0.4, 0.3);
    let mut imu = error_free("arm", 100.0);
    imu.lever_arm_b_m = [r.x, r.y, r.z];
    imu.boresight_rpy_deg = [2.0, -3.0, 90.0];
    let out = run(&model_with(100.0, vec![imu]), Scenario::Car, 300.0, 12);
    let s = &out.imus[0];
    let c_bs = s.mount.c_bs;
    let (mut max_tangential, mut max_centripetal) = (0.0f64, 0.0f64);
    for (k, &t) in s.true_t_s.iter().enumerate() {
        let truth = out.trajectory.truth(t);
        let omega = skew(&truth.omega_ib_b_rad_s);
        let omega_dot = skew(&truth.omega_dot_ib_b_rad_s2);
        let expected = c_bs * (truth.f_b_m_s2 + omega_dot * r + omega * omega * r);
        let got = Vector3::new(channel(s, 3)[k], channel(s, 4)[k], channel(s, 5)[k]);
        assert!(
            (got - expected).norm() < 1e-12,
            "t {t}: {got} vs {expected}"
        );
        let w = Vector3::new(channel(s, 0)[k], channel(s, 1)[k], channel(s, 2)[k]);
        assert!((w - c_bs * truth.omega_ib_b_rad_s).norm() < 1e-15);
        max_tangential = max_tangential.max((omega_dot * r).norm());
        max_centripetal = max_centripetal.max((omega * omega * r).norm());
    }
    // both terms are exercised by the drive
    assert!(
        max_tangential > 0.05 && max_centripetal > 0.05,
        "{max_tangential} {max_centripetal}"
    );
}

#[test]
fn a_lever_armed_boresighted_imu_integrates_to_the_path_of_its_own_mounting_point() {
    // Independent check of eq. 9: the strapdown knows nothing of lever arms; integrating the
    // error-free MEMS IMU must follow the point p_b + C_b^n r with attitude C_b^n C_s^b.
    let r = Vector3::new(1.2, -0.4, 0.3);
    let mut imu = error_free("arm", 1000.0);
    imu.lever_arm_b_m = [r.x, r.y, r.z];
    imu.boresight_rpy_deg = [2.0, -3.0, 90.0];
    let out = run(&model_with(100.0, vec![imu]), Scenario::Car, 120.0, 12);
    let s = &out.imus[0];
    let c_sb = s.mount.c_bs.transpose();
    let point = |t: f64| {
        let tr = out.trajectory.truth(t);
        let d = tr.c_bn * r;
        let rr = radii(tr.lat_rad);
        let lat = tr.lat_rad + d.x / (rr.meridian_m + tr.h_m);
        let lon = tr.lon_rad + d.y / ((rr.transverse_m + tr.h_m) * tr.lat_rad.cos());
        let v = tr.v_ned_m_s
            + tr.c_bn
                * (tr.omega_ib_b_rad_s
                    - tr.c_bn.transpose() * dynacal_core::nav::earth_rate_ned_rad_s(tr.lat_rad))
                .cross(&r);
        (lat, lon, tr.h_m - d.z, v, tr.c_bn * c_sb)
    };
    let (lat, lon, h, v, c_sn) = point(0.0);
    let mut nav = Strapdown::new(NavState {
        q_nb: UnitQuaternion::from_matrix(&c_sn),
        v_ned_m_s: v,
        lat_rad: lat,
        lon_rad: lon,
        h_m: h,
    });
    let v3 = |k: usize, o: usize| {
        Vector3::new(channel(s, o)[k], channel(s, o + 1)[k], channel(s, o + 2)[k])
    };
    let mut worst = 0.0f64;
    for k in 1..s.recording.len() {
        nav.step_rates(v3(k - 1, 0), v3(k, 0), v3(k - 1, 3), v3(k, 3), 1e-3)
            .unwrap();
        let (lat, lon, h, _, _) = point(s.true_t_s[k]);
        let st = nav.state();
        let rr = radii(lat);
        let e = Vector3::new(
            (st.lat_rad - lat) * rr.meridian_m,
            (st.lon_rad - lon) * rr.transverse_m * lat.cos(),
            st.h_m - h,
        );
        worst = worst.max(e.norm());
    }
    println!("lever-arm point tracked to {worst:.3e} m over 120 s");
    assert!(worst < 0.02, "{worst} m");
}

#[test]
fn a_vibration_line_above_nyquist_aliases_to_its_folded_frequency() {
    let mut imu = error_free("vib", 100.0);
    imu.channels.insert(
        Channel::Gx,
        serde_json::from_value(serde_json::json!({"vibration_lines": [{"frequency_hz": 130.0, "amplitude": 0.01, "phase_rad": 0.4}]})).unwrap(),
    );
    let out = run(&model_with(100.0, vec![imu]), Scenario::Static, 20.0, 1);
    let e = error(&out.imus[0], 0);
    for (k, v) in e.iter().enumerate() {
        let t = k as f64 / 100.0;
        let folded = 0.01 * (2.0 * std::f64::consts::PI * 30.0 * t + 0.4).sin();
        assert!((v - folded).abs() < 1e-9, "sample {k}: {v} vs {folded}");
    }
}

#[test]
fn g_sensitivity_dynamic_noise_and_outliers_behave_as_specified() {
    let mut imu = error_free("dyn", 100.0);
    imu.channels.insert(
        Channel::Gx,
        ChannelModel {
            g_sensitivity: Some([1e-3, 0.0, 2e-3]),
            ..Default::default()
        },
    );
    imu.channels.insert(
        Channel::Gz,
        serde_json::from_value(serde_json::json!({"dynamic_noise": {"driver": "angular_rate_norm", "sigma_per_unit": 0.05}})).unwrap(),
    );
    imu.channels.insert(
        Channel::Ay,
        serde_json::from_value(
            serde_json::json!({"outliers": {"probability": 0.01, "sigma": 1.0}}),
        )
        .unwrap(),
    );
    let out = run(&model_with(100.0, vec![imu]), Scenario::Car, 600.0, 2);
    let s = &out.imus[0];
    let ideal = s.ideal.as_ref().unwrap();
    // g-sensitivity: the error is the row times the sensor-frame specific force
    for (k, e) in error(s, 0).iter().enumerate() {
        let expected = 1e-3 * ideal[3][k] + 2e-3 * ideal[5][k];
        assert!((e - expected).abs() < 1e-15, "{e} vs {expected}");
    }
    // dynamic noise: E[e^2] = 0.05^2 E[|omega|^2]
    let e = error(s, 2);
    let w2: f64 = (0..e.len())
        .map(|k| ideal[0][k].powi(2) + ideal[1][k].powi(2) + ideal[2][k].powi(2))
        .sum();
    let e2: f64 = e.iter().map(|v| v * v).sum();
    let k_hat = (e2 / w2).sqrt();
    assert!((k_hat / 0.05 - 1.0).abs() < 0.03, "{k_hat}");
    // outliers: about 1% of the samples, zero elsewhere
    let n_out = error(s, 4).iter().filter(|v| **v != 0.0).count();
    let n = s.recording.len() as f64;
    assert!(
        ((n_out as f64) - 0.01 * n).abs() < 4.0 * (0.01 * 0.99 * n).sqrt(),
        "{n_out} of {n}"
    );
}

#[test]
fn gnss_outages_pps_and_clock_drift_follow_the_model() {
    let mut m = model_with(100.0, vec![]);
    let mut imu = error_free("clk", 100.0);
    imu.clock.frequency_offset_ppm = 40.0;
    m.imus = vec![imu];
    m.gnss = Some(serde_json::from_value(serde_json::json!({"rate_hz": 5, "outages": [[100.0, 130.0]], "position_sigma_ned_m": [0.5, 0.5, 1.0]})).unwrap());
    m.pps = Some(Default::default());
    let out = run(&m, Scenario::Car, 300.0, 6);
    let g = out.gnss.as_ref().unwrap();
    assert_eq!(g.t_s.len(), 300 * 5 - 30 * 5);
    assert!(!g.t_s.iter().any(|t| (100.0..130.0).contains(t)));
    // white position noise: north error spread 0.5 m (antenna lever arm and bias absent)
    let north: Vec<f64> = g
        .t_s
        .iter()
        .zip(&g.position[0])
        .map(|(&t, lat)| {
            let tr = out.trajectory.truth(t);
            (lat - tr.lat_rad) * radii(tr.lat_rad).meridian_m
                - (tr.c_bn * Vector3::new(0.0, 0.0, -1.2)).x
        })
        .collect();
    let sd = (north.iter().map(|v| v * v).sum::<f64>() / north.len() as f64).sqrt();
    assert!(sd > 0.45 && sd < 0.56, "{sd}");
    // PPS: the fast clock reads 40 ppm ahead at each GPS second (to its 1 us resolution)
    let pps = out.pps.as_ref().unwrap();
    for (s, local) in pps.gps_t_s.iter().zip(&pps.local_t_s[0].1) {
        assert!((local - s * (1.0 + 40e-6)).abs() < 1.5e-6, "{s}: {local}");
    }
}

#[test]
fn written_outputs_read_back_list_every_effect_and_repeat_bit_for_bit_for_a_seed() {
    let model = example("table1-dynamic.json");
    let opts = SimOptions {
        scenario: Scenario::Car,
        seconds: 30.0,
        seed: 17,
        disabled: vec![dynacal::model::Effect::Outliers],
        keep_ideal: false,
    };
    let dirs = [tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap()];
    for d in &dirs {
        let out = simulate(&model, &opts, &|_| {}).unwrap();
        dynacal::sim::output::write_outputs(&out, d.path(), FileFormat::Csv, false).unwrap();
    }
    let names = [
        "reference.csv",
        "mtx1.csv",
        "mtx2.csv",
        "mtx3.csv",
        "gnss.csv",
        "pps.csv",
        "truth.json",
    ];
    for name in names {
        let a = std::fs::read(dirs[0].path().join(name)).unwrap();
        let b = std::fs::read(dirs[1].path().join(name)).unwrap();
        assert!(a == b, "{name} differs between two runs with the same seed");
    }
    let reference =
        dynacal::interchange::ImuRecording::read(&dirs[0].path().join("reference.csv")).unwrap();
    assert!(
        reference.attitude_rad.is_some()
            && reference.position.is_some()
            && reference.velocity_ned_m_s.is_some()
    );
    assert_eq!(reference.len(), 30 * 200);
    let mtx = dynacal::interchange::ImuRecording::read(&dirs[0].path().join("mtx2.csv")).unwrap();
    assert_eq!(mtx.channels().len(), 6);
    assert!(mtx.position.is_none());
    let truth: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dirs[0].path().join("truth.json")).unwrap()).unwrap();
    let gx = truth["imus"][1]["channels"]["gx"].as_array().unwrap();
    let effects: Vec<(&str, bool)> = gx
        .iter()
        .map(|e| {
            (
                e["effect"].as_str().unwrap(),
                e["enabled"].as_bool().unwrap(),
            )
        })
        .collect();
    for name in [
        "white_noise",
        "gauss_markov",
        "bias",
        "scale_factor",
        "saturation",
        "quantization",
    ] {
        assert!(
            effects.contains(&(name, true)),
            "{name} missing from {effects:?}"
        );
    }
    let sensor = truth["imus"][1]["sensor_effects"].as_array().unwrap();
    assert!(sensor
        .iter()
        .any(|e| e["effect"] == "time_offset" && e["parameters"]["time_offset_s"] == 0.002));
    assert!(!truth["trajectory"]["segments"]
        .as_array()
        .unwrap()
        .is_empty());
    // no staging folder is left behind
    let leftovers = std::fs::read_dir(dirs[0].path())
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with('.')
        })
        .count();
    assert_eq!(leftovers, 0);
}

#[test]
fn every_example_model_loads() {
    for file in [
        "table1-static.json",
        "table1-dynamic.json",
        "three-mems-1khz.json",
    ] {
        let m = example(file);
        assert_eq!(m.imus.len(), 3, "{file}");
    }
}

#[test]
fn an_output_folder_that_cannot_be_created_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let out = run(&model_with(100.0, vec![]), Scenario::Static, 1.0, 1);
    let err =
        dynacal::sim::output::write_outputs(&out, &blocker.join("out"), FileFormat::Csv, false)
            .unwrap_err();
    assert!(
        err.to_string().contains("file/out") || err.to_string().contains("file"),
        "{err}"
    );
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}
