//! Paper Fig. 1 on simulated data: a low-grade and a tactical-grade IMU ride a simulated car
//! with a navigation-grade reference and 10 Hz GNSS; the 27-state error-state filter with
//! the joint boresight/lever-arm update (eqs. 8-12) must find both mounts from a 20 deg /
//! 20 cm prior within seconds, end inside its 3-sigma, and agree between f32 and f64.

use dynacal::figures::fig1::{
    fig1, fig1_filter, fig1_model, inter_imu_noise, run_calibration, simulate_fig1,
    true_calibrations, CalibrationTrace,
};
use dynacal::figures::plot::fig1_svg;
use dynacal::numeric::AngularAccelerationStencil;
use nalgebra::Vector3;

const SECONDS: f64 = 60.0;
const SEED: u64 = 1;

#[test]
fn both_imus_converge_within_seconds_and_end_inside_three_sigma() {
    // GIVEN a 60 s simulated drive and the paper's 20 deg / 20 cm prior
    // WHEN the filter runs forward and the RTS smoother averages its epochs
    let run = fig1(SECONDS, SEED).unwrap();
    let report = &run.report;
    assert_eq!(report.epochs, (SECONDS * 200.0) as usize);
    assert!(report.inter_imu_updates_rejected * 1000 < report.inter_imu_updates_accepted);
    assert!(report.gnss_updates_accepted > 3000);
    for imu in &report.imus {
        let boresight_s = imu.boresight_converged_after_s.unwrap();
        let lever_s = imu.lever_arm_converged_after_s.unwrap();
        println!(
            "{}: within 1 deg after {boresight_s:.2} s, within 5 cm after {lever_s:.2} s; filtered max |err|/sigma {:.2}, smoothed {:.2}",
            imu.name, imu.filtered.max_error_over_sigma, imu.smoothed.max_error_over_sigma
        );
        // THEN the boresight is within 1 deg and the lever arm within 5 cm in seconds
        // (the car drives off after 2 s; the heading boresight needs that motion)
        assert!(
            boresight_s < 8.0,
            "{}: boresight after {boresight_s} s",
            imu.name
        );
        assert!(lever_s < 2.0, "{}: lever arm after {lever_s} s", imu.name);
        // AND both final estimates lie inside their 3-sigma of the truth
        assert!(imu.filtered.max_error_over_sigma < 3.0, "{imu:?}");
        assert!(imu.smoothed.max_error_over_sigma < 3.0, "{imu:?}");
        // AND they are good to a few hundredths of a degree and a few millimetres
        for a in 0..3 {
            assert!(imu.smoothed.boresight_error_deg[a].abs() < 0.05, "{imu:?}");
            assert!(imu.smoothed.lever_arm_error_m[a].abs() < 0.005, "{imu:?}");
            assert!(imu.filtered.boresight_sigma_deg[a] < 0.05);
            assert!(imu.filtered.lever_arm_sigma_m[a] < 0.002);
        }
    }
    // AND the tactical-grade IMU ends better known than the low-grade one
    let (low, tactical) = (&report.imus[0].filtered, &report.imus[1].filtered);
    for a in 0..3 {
        assert!(tactical.boresight_sigma_deg[a] < low.boresight_sigma_deg[a]);
        assert!(tactical.lever_arm_sigma_m[a] < low.lever_arm_sigma_m[a]);
    }
    // AND the figure is an SVG with all four panels
    let svg = fig1_svg(&run).unwrap();
    assert!(svg.starts_with("<svg"));
    for panel in [
        "low_grade: lever arm [cm]",
        "low_grade: boresight [deg]",
        "tactical_grade: lever arm [cm]",
        "tactical_grade: boresight [deg]",
    ] {
        assert!(svg.contains(panel), "missing panel {panel}");
    }
}

fn largest_divergence(narrow: &CalibrationTrace, wide: &CalibrationTrace) -> (f64, f64, f64) {
    let (mut psi, mut arm, mut in_sigma) = (0.0f64, 0.0f64, 0.0f64);
    for imu in 0..2 {
        for (p32, p64) in narrow.points[imu].iter().zip(&wide.points[imu]) {
            for a in 0..3 {
                let dpsi = (p32.boresight_rad[a] - p64.boresight_rad[a]).abs();
                let darm = (p32.lever_arm_b_m[a] - p64.lever_arm_b_m[a]).abs();
                psi = psi.max(dpsi);
                arm = arm.max(darm);
                in_sigma = in_sigma
                    .max(dpsi / p64.boresight_sigma_rad[a])
                    .max(darm / p64.lever_arm_sigma_m[a]);
            }
        }
    }
    (psi, arm, in_sigma)
}

#[test]
fn f32_filter_follows_f64_filter_on_the_simulated_drive() {
    // GIVEN one simulated drive
    let seconds = 30.0;
    let sim = simulate_fig1(seconds, SEED).unwrap();
    let noise = inter_imu_noise(&fig1_model());
    // WHEN the same filter runs in f32 (the board) and f64 (the host)
    let mut narrow_filter = fig1_filter::<f32>();
    let mut wide_filter = fig1_filter::<f64>();
    let narrow = run_calibration(&sim, &noise, &mut narrow_filter).unwrap();
    let wide = run_calibration(&sim, &noise, &mut wide_filter).unwrap();
    assert_eq!(narrow.t_s.len(), wide.t_s.len());
    // THEN the calibration states never part by more than a small fraction of their sigma
    let (psi, arm, in_sigma) = largest_divergence(&narrow, &wide);
    println!(
        "f32 vs f64 over {seconds} s: largest boresight divergence {:.3e} deg, lever arm {:.3e} mm, {in_sigma:.3} sigma",
        psi.to_degrees(),
        arm * 1e3
    );
    assert!(in_sigma < 0.25, "divergence {in_sigma} sigma");
    assert!(psi.to_degrees() < 0.01 && arm < 1e-3);
    // AND the f32 filter ends inside 3 sigma of the truth as well
    let truth = true_calibrations(&sim);
    for (imu, truth) in truth.iter().enumerate() {
        let last = narrow.points[imu].last().unwrap();
        for a in 0..3 {
            assert!(
                (last.boresight_rad[a] - truth.boresight_rad[a]).abs()
                    < 3.0 * last.boresight_sigma_rad[a]
            );
            assert!(
                (last.lever_arm_b_m[a] - truth.lever_arm_b_m[a]).abs()
                    < 3.0 * last.lever_arm_sigma_m[a]
            );
        }
    }
}

#[test]
fn angular_acceleration_stencil_keeps_engine_vibration_that_a_central_difference_loses() {
    // GIVEN a 26 Hz roll vibration sampled at 200 Hz
    let (rate, freq, amplitude) = (200.0f64, 26.0f64, 2e-5f64);
    let w = 2.0 * std::f64::consts::PI * freq;
    let dt = 1.0 / rate;
    let omega = |t: f64| Vector3::new(amplitude * w * (w * t).cos(), 0.0, 0.0);
    let omega_dot = |t: f64| -amplitude * w * w * (w * t).sin();
    let mut stencil = AngularAccelerationStencil::<f64, usize>::default();
    let (mut worst_stencil, mut worst_central, mut peak) = (0.0f64, 0.0f64, 0.0f64);
    for k in 0..400usize {
        let t = k as f64 * dt;
        if let Some((_, estimate, mid)) = stencil.push(dt, omega(t), k) {
            let t_mid = mid as f64 * dt;
            let central = (omega(t_mid + dt).x - omega(t_mid - dt).x) / (2.0 * dt);
            worst_stencil = worst_stencil.max((estimate.x - omega_dot(t_mid)).abs());
            worst_central = worst_central.max((central - omega_dot(t_mid)).abs());
            peak = peak.max(omega_dot(t_mid).abs());
        }
    }
    // THEN the sixth-order stencil is within 0.3 % of the peak, the central difference 10 % off
    println!(
        "26 Hz at 200 Hz: stencil error {:.3} %, central difference {:.2} %",
        100.0 * worst_stencil / peak,
        100.0 * worst_central / peak
    );
    assert!(worst_stencil < 3e-3 * peak);
    assert!(worst_central > 0.1 * peak);
}
