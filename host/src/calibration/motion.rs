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
use super::passes::View;
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

/// Checks that the sensor and the reference (over the `epochs` epochs of `view`, at no time
/// offset and no rotation) show the same motion in turn rate and in specific force, where
/// either moved: one pass for the windowed means, a few for the median specific forces.
pub(super) fn check_same_motion(view: &View, epochs: usize) -> Result<(), ErrorsError> {
    // Sensor and reference windows of the turn rate, then of the specific force.
    let mut windows: [WindowMeans; 4] = Default::default();
    let mut present = [false; 2];
    view.pass(&mut |block| {
        let data = block.data;
        let pairs = [
            (&data.gyro_rad_s, &data.reference.omega_ib_b_rad_s),
            (&data.accel_m_s2, &data.reference.f_b_m_s2),
        ];
        for (q, (sensor, reference)) in pairs.into_iter().enumerate() {
            let Some(sensor) = sensor else { continue };
            present[q] = true;
            for k in block.own.clone() {
                windows[2 * q].push(block.t_s[k], sensor[k].norm());
                windows[2 * q + 1].push(block.t_s[k], reference[k].norm());
            }
        }
        Ok(())
    })?;
    let [wa, ra, wf, rf] = windows;
    let quantities = [
        (Quantity::TurnRate, [wa, ra]),
        (Quantity::SpecificForce, [wf, rf]),
    ];
    for (q, (quantity, [sensor, reference])) in quantities.into_iter().enumerate() {
        if !present[q] {
            continue;
        }
        let medians = match quantity {
            Quantity::SpecificForce => Some([
                median_norm_by_passes(view, epochs, |d| d.accel_m_s2.as_deref())?,
                median_norm_by_passes(view, epochs, |d| Some(&d.reference.f_b_m_s2[..]))?,
            ]),
            Quantity::TurnRate => None,
        };
        let series = [sensor.changes(), reference.changes()];
        same_motion_of(&series, medians, quantity, ["the sensor", "the reference"]).map_err(
            |m| ErrorsError::DifferentMotion {
                quantity: quantity.name(),
                unit: quantity.unit(),
                sensor_variation: m.variations[0],
                reference_variation: m.variations[1],
                reason: m.reason,
            },
        )?;
    }
    Ok(())
}

/// The median of |v| over the `epochs` epochs of `view`, v chosen from each block's data by
/// `of` (present in every block).
fn median_norm_by_passes(
    view: &View,
    epochs: usize,
    of: impl Fn(&EpochData) -> Option<&[Vector3<f64>]>,
) -> Result<f64, ErrorsError> {
    let median = crate::numeric::select_by_passes(epochs as u64 / 2, |visit| {
        let mut norms = crate::numeric::Batched::new(visit);
        let read = view.pass(&mut |block| {
            if let Some(v) = of(block.data) {
                v[block.own.clone()]
                    .iter()
                    .for_each(|x| norms.push(x.norm()));
            }
            Ok(())
        });
        norms.finish();
        read
    })?;
    Ok(median.unwrap_or(0.0))
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
    let changes = |v: &[Vector3<f64>]| {
        let mut windows = WindowMeans::default();
        t_s.iter()
            .zip(v)
            .for_each(|(t, x)| windows.push(*t, x.norm()));
        windows.changes()
    };
    let medians = (quantity == Quantity::SpecificForce).then(|| [median_norm(a), median_norm(b)]);
    same_motion_of(&[changes(a), changes(b)], medians, quantity, names)
}

/// [`same_motion`] of the two units' window-to-window changes of their windowed magnitudes,
/// with their median magnitudes where the quantity's unit slip is read from them (the
/// specific force: gravity is always there).
fn same_motion_of(
    changes: &[Vec<f64>; 2],
    medians: Option<[f64; 2]>,
    quantity: Quantity,
    names: [&str; 2],
) -> Result<(), MotionMismatch> {
    let [ma, mb] = changes;
    if ma.len() < MIN_WINDOWS {
        return Ok(());
    }
    let variations = [std_dev(ma), std_dev(mb)];
    let [sa, sb] = variations;
    let moved = sa.max(sb) > quantity.moving();
    let mismatch = |reason: String| MotionMismatch {
        quantity,
        reason,
        variations,
    };
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
    let r = correlation(ma, mb);
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
    medians: Option<[f64; 2]>,
    variations: [f64; 2],
    moved: bool,
) -> Option<String> {
    let (factor, slip, slipped_reads_larger) = quantity.unit_slip();
    let ratio = match (quantity, medians) {
        (Quantity::SpecificForce, Some(medians)) => medians[0] / medians[1],
        (Quantity::SpecificForce, None) => return None,
        (Quantity::TurnRate, _) if moved => variations[0] / variations[1],
        (Quantity::TurnRate, _) => return None,
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

/// Means of |v| over consecutive windows of [`WINDOW_S`] from the first time (the last,
/// partial one dropped), a sample at a time.
#[derive(Debug, Default)]
struct WindowMeans {
    t0_s: Option<f64>,
    window: u64,
    sum: f64,
    count: usize,
    means: Vec<f64>,
}

impl WindowMeans {
    /// Adds |v| = `norm` at time `t_s`.
    fn push(&mut self, t_s: f64, norm: f64) {
        let t0 = *self.t0_s.get_or_insert(t_s);
        let this = ((t_s - t0) / WINDOW_S) as u64;
        if this != self.window {
            if self.count > 0 {
                self.means.push(self.sum / self.count as f64);
            }
            (self.window, self.sum, self.count) = (this, 0.0, 0);
        }
        self.sum += norm;
        self.count += 1;
    }

    /// Changes of the means from each window to the next.
    fn changes(self) -> Vec<f64> {
        self.means.windows(2).map(|w| w[1] - w[0]).collect()
    }
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
