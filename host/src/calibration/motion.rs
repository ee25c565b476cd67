//! Whether a sensor and its reference saw the same motion. Error signals are the sensor
//! minus the reference; when the two were not on one vehicle (a static recording paired
//! with a drive, two drives on one clock, files of different days), every "error" is the
//! motion itself and the calibration still converges to something. The check compares what
//! any frame and mounting leave unchanged: the magnitudes of the angular rate and of the
//! specific force, each averaged over one-second windows so that sensor noise averages out
//! and the vehicle's manoeuvres remain, then differenced from window to window so that a
//! slow drift (a warming sensor at rest) does not pass for motion.

use nalgebra::Vector3;

use super::epochs::EpochData;
use super::signals::std_dev;
use super::ErrorsError;

/// Window of the averages, s: long against sensor noise, short against a manoeuvre.
const WINDOW_S: f64 = 1.0;
/// Fewest windows the check is made on; a shorter overlap is not judged.
const MIN_WINDOWS: usize = 10;
/// A unit "moves" when its windowed turn rate changes from one second to the next by more
/// than this (standard deviation), rad/s: a car pulling away on a straight road stays
/// below, a turning one is far above; a MEMS gyro at rest (0.01 deg/s/sqrt(Hz)) changes
/// by 2.5e-4.
const MOVING_TURN_RATE_RAD_S: f64 = 3e-3;
/// As [`MOVING_TURN_RATE_RAD_S`] for the specific force, m/s^2: a car pulling away changes
/// it by 0.07; a MEMS accelerometer at rest (300 ug/sqrt(Hz)) by 4e-3.
const MOVING_SPECIFIC_FORCE_M_S2: f64 = 0.03;
/// One unit's variation below this share of the other's: one of them was not moving.
const STILL_RATIO: f64 = 0.2;
/// Below this correlation of the windowed magnitudes' changes, two units that both moved
/// moved differently (two independent drives: 0 within 1/sqrt(windows); one drive seen by
/// a noisy sensor: above 0.7 until its noise exceeds the motion).
const MIN_CORRELATION: f64 = 0.3;

/// What a motion is compared in: quantities no frame or mounting changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Quantity {
    /// |angular rate|, rad/s.
    TurnRate,
    /// |specific force|, m/s^2.
    SpecificForce,
}

impl Quantity {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Quantity::TurnRate => "turn rate",
            Quantity::SpecificForce => "specific force",
        }
    }

    pub(crate) fn unit(self) -> &'static str {
        match self {
            Quantity::TurnRate => "rad/s",
            Quantity::SpecificForce => "m/s^2",
        }
    }

    /// The factor a unit slip multiplies the quantity by, and the slip: degrees read as
    /// radians, g as m/s^2.
    /// Whether the slipped one reads larger (degrees) or smaller (g).
    fn unit_slip(self) -> (f64, &'static str, bool) {
        match self {
            Quantity::TurnRate => (180.0 / std::f64::consts::PI, "deg/s instead of rad/s", true),
            Quantity::SpecificForce => (9.80665, "g instead of m/s^2", false),
        }
    }

    fn moving(self) -> f64 {
        match self {
            Quantity::TurnRate => MOVING_TURN_RATE_RAD_S,
            Quantity::SpecificForce => MOVING_SPECIFIC_FORCE_M_S2,
        }
    }
}

/// Two recordings' motions differ.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct MotionMismatch {
    pub quantity: Quantity,
    /// Why, naming the one at rest when one was.
    pub reason: String,
    /// Standard deviation of each one's windowed magnitude, in the quantity's unit.
    pub variations: [f64; 2],
}

/// Checks that the sensor and the reference (over the epochs `t_s`, s, at no time offset)
/// show the same motion in turn rate and in specific force, where either moved.
pub(super) fn check_same_motion(t_s: &[f64], data: &EpochData) -> Result<(), ErrorsError> {
    let pairs = [
        (
            Quantity::TurnRate,
            &data.gyro_rad_s,
            &data.reference.omega_ib_b_rad_s,
        ),
        (
            Quantity::SpecificForce,
            &data.accel_m_s2,
            &data.reference.f_b_m_s2,
        ),
    ];
    for (quantity, sensor, reference) in pairs {
        if let Some(sensor) = sensor {
            same_motion(
                t_s,
                sensor,
                reference,
                quantity,
                ["the sensor", "the reference"],
            )
            .map_err(|m| ErrorsError::DifferentMotion {
                quantity: quantity.name(),
                unit: quantity.unit(),
                sensor_variation: m.variations[0],
                reference_variation: m.variations[1],
                reason: m.reason,
            })?;
        }
    }
    Ok(())
}

/// Whether `a` and `b` (vectors at the times `t_s`, s) moved alike: where either changes its
/// windowed magnitude by more than a moving vehicle does, the other must change by at least
/// a fifth as much, and where both moved the changes must be correlated. `names` name them
/// in the reason.
pub(crate) fn same_motion(
    t_s: &[f64],
    a: &[Vector3<f64>],
    b: &[Vector3<f64>],
    quantity: Quantity,
    names: [&str; 2],
) -> Result<(), MotionMismatch> {
    let (ma, mb) = (window_changes(t_s, a), window_changes(t_s, b));
    if ma.len() < MIN_WINDOWS {
        return Ok(());
    }
    let variations = [std_dev(&ma), std_dev(&mb)];
    let [sa, sb] = variations;
    let moved = sa.max(sb) > quantity.moving();
    let mismatch = |reason: String| MotionMismatch {
        quantity,
        reason,
        variations,
    };
    let medians = [median_norm(a), median_norm(b)];
    if let Some(reason) = unit_slip(quantity, names, medians, variations, moved) {
        return Err(mismatch(reason));
    }
    if !moved {
        return Ok(());
    }
    if sa.min(sb) < STILL_RATIO * sa.max(sb) {
        let (still, moved) = if sa < sb {
            (names[0], names[1])
        } else {
            (names[1], names[0])
        };
        return Err(mismatch(format!("{still} was at rest while {moved} moved")));
    }
    let r = correlation(&ma, &mb);
    if sa.min(sb) > quantity.moving() && r < MIN_CORRELATION {
        return Err(mismatch(format!(
            "both moved, but differently (correlation {r:.2} of the changes of their {WINDOW_S} s \
             averages)"
        )));
    }
    Ok(())
}

/// A unit slip between `a` and `b`: their specific forces' magnitudes (gravity, always
/// there) or, where they moved, their turn rates' changes, in the ratio of
/// [`Quantity::unit_slip`].
fn unit_slip(
    quantity: Quantity,
    names: [&str; 2],
    medians: [f64; 2],
    variations: [f64; 2],
    moved: bool,
) -> Option<String> {
    let (factor, slip, slipped_reads_larger) = quantity.unit_slip();
    let ratio = match quantity {
        Quantity::SpecificForce => medians[0] / medians[1],
        Quantity::TurnRate if moved => variations[0] / variations[1],
        Quantity::TurnRate => return None,
    };
    let near = |r: f64| (r / factor - 1.0).abs() < 0.2;
    let (large, small) = if near(ratio) {
        (names[0], names[1])
    } else if near(1.0 / ratio) {
        (names[1], names[0])
    } else {
        return None;
    };
    let slipped = if slipped_reads_larger { large } else { small };
    Some(format!(
        "{large} reads {:.3} times what {small} reads: is {slipped} in {slip}?",
        ratio.max(1.0 / ratio)
    ))
}

fn median_norm(v: &[Vector3<f64>]) -> f64 {
    crate::numeric::median(v.iter().map(|x| x.norm()).collect()).unwrap_or(0.0)
}

/// Changes of the means of |v| from each window of [`WINDOW_S`] to the next.
fn window_changes(t_s: &[f64], v: &[Vector3<f64>]) -> Vec<f64> {
    window_means(t_s, v)
        .windows(2)
        .map(|w| w[1] - w[0])
        .collect()
}

/// Means of |v| over consecutive windows of [`WINDOW_S`] from the first time (the last,
/// partial one dropped).
fn window_means(t_s: &[f64], v: &[Vector3<f64>]) -> Vec<f64> {
    let Some(&t0) = t_s.first() else {
        return Vec::new();
    };
    let mut means = Vec::new();
    let (mut window, mut sum, mut count) = (0u64, 0.0, 0usize);
    for (t, x) in t_s.iter().zip(v) {
        let this = ((t - t0) / WINDOW_S) as u64;
        if this != window {
            if count > 0 {
                means.push(sum / count as f64);
            }
            (window, sum, count) = (this, 0.0, 0);
        }
        sum += x.norm();
        count += 1;
    }
    means
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let (ma, mb) = (mean(a), mean(b));
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(n: usize, f: impl Fn(f64) -> f64) -> (Vec<f64>, Vec<Vector3<f64>>) {
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
        let v = t.iter().map(|&t| Vector3::new(f(t), 0.0, 0.0)).collect();
        (t, v)
    }

    #[test]
    fn a_unit_at_rest_beside_a_turning_one_is_refused() {
        let (t, turning) = series(6000, |t| 0.3 * (0.2 * t).sin().abs());
        let (_, still) = series(6000, |_| 1e-3);
        let check = |a: &[Vector3<f64>], b: &[Vector3<f64>]| {
            same_motion(&t, a, b, Quantity::TurnRate, ["a", "b"])
        };
        assert_eq!(
            check(&still, &turning).unwrap_err().reason,
            "a was at rest while b moved"
        );
        assert_eq!(
            check(&turning, &still).unwrap_err().reason,
            "b was at rest while a moved"
        );
        assert!(check(&turning, &turning).is_ok());
        assert!(check(&still, &still).is_ok());
    }

    #[test]
    fn a_unit_slip_is_named() {
        let (t, turning) = series(6000, |t| 0.3 * (0.2 * t).sin().abs());
        let in_degrees: Vec<Vector3<f64>> = turning.iter().map(|v| v * 57.29578).collect();
        let e = same_motion(&t, &in_degrees, &turning, Quantity::TurnRate, ["a", "b"]);
        assert!(e
            .unwrap_err()
            .reason
            .contains("is a in deg/s instead of rad/s?"));
        let (_, gravity) = series(6000, |_| 9.81);
        let (_, in_g) = series(6000, |_| 1.0);
        let e = same_motion(&t, &gravity, &in_g, Quantity::SpecificForce, ["a", "b"]);
        assert!(e
            .unwrap_err()
            .reason
            .contains("is b in g instead of m/s^2?"));
    }

    #[test]
    fn two_different_drives_are_refused() {
        let (t, a) = series(6000, |t| 0.3 * (0.21 * t).sin().abs());
        let (_, b) = series(6000, |t| 0.3 * (0.37 * t + 1.0).cos().abs());
        let e = same_motion(&t, &a, &b, Quantity::TurnRate, ["a", "b"]).unwrap_err();
        assert!(e.reason.contains("differently"), "{}", e.reason);
    }
}
