//! Error signals of the real PSINS MEMS unit against the FOG INS solution (paper Section II on
//! measured data): the mounting misalignment, lever arm, biases and time offset are estimated
//! with uncertainties, and the calibration must explain most of the raw sensor-minus-reference
//! difference. Skips with a message when the dataset is absent.

use dynacal::calibration::{build_error_signals, write_error_signals_streamed, ErrorOptions};
use dynacal::error_signal::ErrorSignals;
use dynacal::import::psins_fog_mems::{read_fog, read_mems};
use dynacal::interchange::ImuRecording;
use dynacal::regress::{backward_elimination, RegressionOptions};

fn variance(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64
}

/// The real MEMS unit and the FOG INS solution; `None` (with a message) when the dataset is
/// absent.
fn psins_pair() -> Option<(ImuRecording, ImuRecording)> {
    let dir = dynacal_tests::data_dir().join("psins-fog-mems");
    if !dir.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", dir.display());
        return None;
    }
    let mems = read_mems(&dir.join("mems_increments.csv.gz")).unwrap();
    let fog = read_fog(&dir.join("fog_ins_reference.csv.gz")).unwrap();
    Some((mems, fog))
}

#[test]
fn psins_mems_against_fog_calibration_and_error_signals() {
    let Some((mems, fog)) = psins_pair() else {
        return;
    };

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

/// The streamed calibration (`dynacal errors --stream always`) of the real PSINS pair in
/// blocks of 97 epochs gives what the calibration of the pair held whole gives: against a
/// navigation solution only the sensor's running integrals differ (they start at each
/// block), so the estimates agree far inside their uncertainty and the signals to rounding.
#[test]
fn psins_streamed_in_blocks_equals_held_whole() {
    let Some((mems, fog)) = psins_pair() else {
        return;
    };
    let (held, held_cal) = build_error_signals(&mems, &fog, &ErrorOptions::default()).unwrap();
    let work = tempfile::tempdir().unwrap();
    let (sensor, reference, out) = (
        work.path().join("mems.csv"),
        work.path().join("fog.csv.gz"),
        work.path().join("errors.csv"),
    );
    mems.write(&sensor).unwrap();
    fog.write(&reference).unwrap();
    let opts = ErrorOptions {
        block_epochs: 97,
        ..Default::default()
    };
    let cal = write_error_signals_streamed(&sensor, &reference, &out, &opts).unwrap();
    assert_eq!(
        (cal.epochs, cal.epoch_dt_s),
        (held_cal.epochs, held_cal.epoch_dt_s)
    );
    assert_eq!(cal.reference_kind, "navigation_solution");
    let pairs = [
        (cal.boresight_rad, held_cal.boresight_rad),
        (cal.lever_arm_m.unwrap(), held_cal.lever_arm_m.unwrap()),
        (
            cal.gyro_bias_rad_s.unwrap(),
            held_cal.gyro_bias_rad_s.unwrap(),
        ),
        (
            cal.accel_bias_m_s2.unwrap(),
            held_cal.accel_bias_m_s2.unwrap(),
        ),
    ];
    for (a, b) in pairs {
        for i in 0..3 {
            assert!(
                (a.value[i] - b.value[i]).abs() < 1e-6 * b.sigma[i],
                "{a:?} {b:?}"
            );
            assert!((a.sigma[i] / b.sigma[i] - 1.0).abs() < 1e-6, "{a:?} {b:?}");
        }
    }
    let (t, held_t) = (cal.time_offset_s.unwrap(), held_cal.time_offset_s.unwrap());
    assert!(
        (t.value - held_t.value).abs() < 1e-6 * held_t.sigma,
        "{t:?} {held_t:?}"
    );
    assert_eq!(cal.hac_lag, held_cal.hac_lag);
    let streamed = ErrorSignals::read(&out).unwrap();
    assert_eq!(streamed.t_s, held.t_s);
    for (c, (a, b)) in streamed.errors.iter().zip(&held.errors).enumerate() {
        let (a, b) = (a.as_ref().unwrap(), b.as_ref().unwrap());
        let scale = held_cal.error_std[c].unwrap();
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-6 * scale, "channel {c}: {worst} of {scale}");
    }
    for (a, b) in streamed.dynamics.iter().zip(&held.dynamics) {
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        let scale = b.iter().map(|x| x.abs()).fold(0.0, f64::max);
        assert!(worst <= 1e-9 * scale, "{worst} of {scale}");
    }
}
