//! Error signals of the real PSINS MEMS unit against the FOG INS solution (paper Section II on
//! measured data): the mounting misalignment, lever arm, biases and time offset are estimated
//! with uncertainties, and the calibration must explain most of the raw sensor-minus-reference
//! difference. Skips with a message when the dataset is absent.

use dynacal::calibration::{build_error_signals, ErrorOptions};
use dynacal::import::psins_fog_mems::{read_fog, read_mems};
use dynacal::regress::{backward_elimination, RegressionOptions};

fn variance(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64
}

#[test]
fn psins_mems_against_fog_calibration_and_error_signals() {
    let dir = dynacal_tests::data_dir().join("psins-fog-mems");
    if !dir.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", dir.display());
        return;
    }
    let mems = read_mems(&dir.join("mems_increments.csv.gz")).unwrap();
    let fog = read_fog(&dir.join("fog_ins_reference.csv.gz")).unwrap();

    let (signals, cal) = build_error_signals(&mems, &fog, &ErrorOptions::default()).unwrap();
    assert_eq!(cal.reference_kind, "navigation_solution");
    // Epochs are the FOG's 10 Hz intervals over the overlap (trimmed by the offset margin).
    assert!(
        cal.epochs > 950 && (cal.epoch_dt_s - 0.1).abs() < 1e-9,
        "{cal:?}"
    );
    // Two boxes bolted to one vehicle: the misalignment is a fraction of a degree and known
    // to better than 0.05 deg.
    for i in 0..3 {
        assert!(
            cal.boresight_rad.value[i].abs() < 1.0f64.to_radians(),
            "{cal:?}"
        );
        assert!(cal.boresight_rad.sigma[i] < 0.05f64.to_radians(), "{cal:?}");
    }
    let lever = cal.lever_arm_m.unwrap();
    for i in 0..3 {
        assert!(
            lever.value[i].abs() < 1.0 && lever.sigma[i] < 0.05,
            "{lever:?}"
        );
    }
    let dt = cal.time_offset_s.unwrap();
    assert!(dt.value.abs() < 0.05 && dt.sigma < 0.002, "{dt:?}");

    // The calibration explains the raw difference: the uncalibrated error (no boresight
    // rotation, lever arm or time shift) has far more variance on the axes the vehicle
    // rotates and accelerates on.
    let raw = ErrorOptions {
        estimate_lever_arm: false,
        estimate_time_offset: false,
        ..Default::default()
    };
    let (raw_signals, _) = build_error_signals(&mems, &fog, &raw).unwrap();
    let explained: Vec<f64> = ["ax", "ay", "gz"]
        .iter()
        .map(|ch| variance(signals.error(ch).unwrap()) / variance(raw_signals.error(ch).unwrap()))
        .collect();
    assert!(explained.iter().any(|r| *r < 0.9), "{explained:?}");

    // MEMS gyro errors are well below the vehicle's rates, and the regression on the
    // dynamics runs on all six channels with HAC inference.
    let gz = signals.error("gz").unwrap();
    let rate_z = &signals.dynamics[2];
    assert!(
        variance(gz) < 0.01 * variance(rate_z),
        "{} vs {}",
        variance(gz),
        variance(rate_z)
    );
    for ch in ["gx", "gy", "gz", "ax", "ay", "az"] {
        let rep = backward_elimination(
            signals.error(ch).unwrap(),
            &signals.regressors(),
            &RegressionOptions::default(),
        )
        .unwrap();
        assert!(rep.inference.starts_with("Newey-West"));
        assert!((0.0..=1.0).contains(&rep.r2));
    }
}
