//! Bringing every unit into the first unit's frame from the redundant data themselves: the
//! rotation from the gyros (Wahba's problem, Markley's SVD solution) when the motion turns
//! about two axes or more, then the lever arm from the accelerometers' differences against
//! the angular acceleration and centripetal terms (the seed paper's eq. (9) between two
//! MEMS units), each with its uncertainty and a note where the motion does not determine it.

use nalgebra::{Matrix3, Vector3};

use dynacal_core::redundancy::{lever_matrix, LeverArmNormal, RotationAccumulator};

use super::derivative::SpectralDerivative;
use super::{Alignment, RotationBasis};
use crate::interchange::ImuRecording;
use crate::wv::{haar_wv, WvOptions};

/// Sample k of a triad as a vector.
fn at(triad: &[Vec<f64>; 3], k: usize) -> Vector3<f64> {
    Vector3::new(triad[0][k], triad[1][k], triad[2][k])
}

/// Lag of the differences the rotation is solved on, s.
const LAG_S: f64 = 0.5;

/// Changes of a triad over `lag` samples, per sample (the first `lag` samples give none):
/// a bias does not rotate with the motion, and differences remove it; a unit's bias that
/// steps weighs on `lag` samples only, which the second solution of
/// [`rotation_from_gyros`] drops (a faulty unit must not be misaligned by its fault).
fn lagged_changes(triad: &[Vec<f64>; 3], lag: usize) -> Vec<Vector3<f64>> {
    let n = triad[0].len();
    let lag = lag.clamp(1, n.saturating_sub(1).max(1));
    (lag..n)
        .map(|k| at(triad, k) - at(triad, k - lag))
        .collect()
}

/// Largest 1-sigma of the rotation about the least-turned axis for which a unit's rotation
/// counts as determined, rad (0.6 deg, the size of the boresights it is there to remove).
/// The axis turned least is also the one whose error leaks least into the gyro difference
/// (a rotation about the rate leaves the rate unchanged), so a loosely determined rotation
/// about it still aligns the gyros; on static data the sigma is far above this.
const ROTATION_SIGMA_MAX_RAD: f64 = 1e-2;

/// Largest 1-sigma of a rotation applied because it stands clear of none, rad (1 deg):
/// beyond it the estimate's own error leaves more in the differences (17 mrad/s at 1 rad/s)
/// than a MEMS gyro's noise, and on a static rig known from a few bumps (1-5 deg) it would
/// only mix the units' axes.
const ROTATION_SIGMA_LOOSE_RAD: f64 = 0.0175;

/// Wahba's problem on the sample pairs `keep` selects (the core's
/// [`RotationAccumulator`]).
fn wahba(first: &[Vector3<f64>], unit: &[Vector3<f64>], keep: &[bool]) -> RotationAccumulator<f64> {
    let mut sums = RotationAccumulator::default();
    for ((w0, wk), _) in first.iter().zip(unit).zip(keep).filter(|(_, k)| **k) {
        sums.push(w0, wk);
    }
    sums
}

/// Rotation C with w_k = C w_0 from the gyros' changes over [`LAG_S`], its 1-sigma
/// ([`RotationAccumulator::sigma_rad`]) and whether the motion determines it. Solved
/// twice: the second time without the samples whose residual is beyond 5 times the
/// median's (a unit's fault, a clipped peak, a crash must not turn the whole run's
/// rotation).
fn rotation_from_gyros(first: &[Vector3<f64>], unit: &[Vector3<f64>]) -> (Matrix3<f64>, f64, bool) {
    let all = vec![true; first.len()];
    let Some(rough) = wahba(first, unit, &all).rotation() else {
        return (Matrix3::identity(), f64::INFINITY, false);
    };
    let residual: Vec<f64> = first
        .iter()
        .zip(unit)
        .map(|(w0, wk)| (wk - rough * w0).norm())
        .collect();
    let mut sorted = residual.clone();
    let median = *sorted
        .select_nth_unstable_by(residual.len() / 2, f64::total_cmp)
        .1;
    let keep: Vec<bool> = residual.iter().map(|r| *r <= 5.0 * median).collect();
    let sums = wahba(first, unit, &keep);
    let c = sums.rotation().unwrap_or(rough);
    let sigma = sums.sigma_rad(&c).unwrap_or(f64::INFINITY);
    // Determined when known to ROTATION_SIGMA_MAX_RAD, or when the rotation stands two
    // sigmas clear of none and is known to ROTATION_SIGMA_LOOSE_RAD (units on a vibrating
    // frame: 1-2 deg apart, known to 0.5-0.7 deg); otherwise none is as good an estimate.
    let angle = nalgebra::Rotation3::from_matrix_unchecked(c).angle();
    let clear = angle > 2.0 * sigma && sigma < ROTATION_SIGMA_LOOSE_RAD;
    (c, sigma, sigma < ROTATION_SIGMA_MAX_RAD || clear)
}

/// Roll, pitch, yaw (Z-Y-X) of a rotation matrix, deg.
fn rpy_deg(c: &Matrix3<f64>) -> [f64; 3] {
    let r = nalgebra::Rotation3::from_matrix_unchecked(*c);
    let (roll, pitch, yaw) = r.euler_angles();
    [roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()]
}

/// The platform's motion from the aligned gyros of the units whose rotation is known.
struct Motion {
    /// Per sample, the angular rate (the units' mean, rad/s) and its rate of change
    /// ([`SpectralDerivative`], rad/s^2).
    rate_and_acceleration: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// Variance of the gyro noise the derivative lets through, per axis, (rad/s^2)^2.
    noise_variance: [f64; 3],
    /// Its Haar wavelet variance per axis and level (from 1), (rad/s^2)^2.
    noise_wv: [Vec<f64>; 3],
}

/// The platform's [`Motion`]. The noise the derivative lets through is measured on the
/// gyros' pairwise differences, which hold no motion: each difference through the same
/// filter has the variance V_j + V_k (V_k unit k's noise through the filter), the sum over
/// the pairs is (M - 1) times the sum of the V_k, and the mean of M units lets through
/// their sum over M^2; the same holds of the wavelet variances per level.
fn motion(aligned_gyros: &[Vec<Vector3<f64>>], dt_s: f64) -> Motion {
    let n = aligned_gyros[0].len();
    let units = aligned_gyros.len();
    let axis = |g: &[Vector3<f64>], a: usize| -> Vec<f64> { g.iter().map(|w| w[a]).collect() };
    let mean: Vec<Vector3<f64>> = (0..n)
        .map(|i| aligned_gyros.iter().map(|g| g[i]).sum::<Vector3<f64>>() / units as f64)
        .collect();
    let mut derivatives: [Vec<f64>; 3] = Default::default();
    let mut noise_variance = [0.0; 3];
    let mut noise_wv: [Vec<f64>; 3] = Default::default();
    let share = 1.0 / (units.saturating_sub(1) * units * units).max(1) as f64;
    for a in 0..3 {
        let Some(filter) = SpectralDerivative::fit(&axis(&mean, a), dt_s) else {
            derivatives[a] = vec![0.0; n];
            continue;
        };
        derivatives[a] = filter.apply(&axis(&mean, a));
        let mut pairs_sum = 0.0;
        for j in 0..units {
            for k in j + 1..units {
                let difference: Vec<f64> = (0..n)
                    .map(|i| aligned_gyros[j][i][a] - aligned_gyros[k][i][a])
                    .collect();
                let through = filter.apply(&difference);
                pairs_sum += through.iter().map(|v| v * v).sum::<f64>() / n as f64;
                let wv = haar_wv(&through, dt_s, &WvOptions::default()).expect(">= 64 samples");
                noise_wv[a].resize(wv.variance.len(), 0.0);
                for (sum, v) in noise_wv[a].iter_mut().zip(&wv.variance) {
                    *sum += v * share;
                }
            }
        }
        noise_variance[a] = pairs_sum * share;
    }
    Motion {
        rate_and_acceleration: (0..n)
            .map(|i| {
                let d = |a: usize| derivatives[a][i];
                (mean[i], Vector3::new(d(0), d(1), d(2)))
            })
            .collect(),
        noise_variance,
        noise_wv,
    }
}

/// Largest 1-sigma of a lever-arm component still applied, m: beyond it the motion does not
/// determine the lever arm, and correcting with it would add noise.
const LEVER_ARM_SIGMA_MAX_M: f64 = 0.01;

/// Blocks of the lever arm's jackknife: enough for its variance to have 19 degrees of
/// freedom, few enough that each block holds several manoeuvres of a drive.
const JACKKNIFE_BLOCKS: usize = 20;

/// Lever arm of a unit from the first, in the first unit's axes (least squares of eq. (9)
/// with a bias per axis, corrected for the derivative's noise where that leaves half the
/// information: the core's [`LeverArmNormal`]), with its 1-sigma; None when the motion
/// does not determine it. The sigma is the larger of the least
/// squares' (white residuals) and a delete-one-block jackknife's over
/// [`JACKKNIFE_BLOCKS`] stretches of the run, which also covers what the least squares
/// takes as white and is not: the angular acceleration's error, coloured and multiplying
/// the lever arm, and manoeuvres that differ along the run.
fn lever_arm(
    motion: &Motion,
    first_accel: &[Vector3<f64>],
    aligned_accel: &[Vector3<f64>],
) -> Option<([f64; 3], [f64; 3])> {
    let rows = &motion.rate_and_acceleration;
    let n = rows.len();
    let row = |k: usize| {
        let m = lever_matrix(&rows[k].0, &rows[k].1);
        (m, aligned_accel[k] - first_accel[k])
    };
    let blocks: Vec<LeverArmNormal<f64>> = (0..JACKKNIFE_BLOCKS)
        .map(|b| {
            let mut normal = LeverArmNormal::default();
            for k in b * n / JACKKNIFE_BLOCKS..(b + 1) * n / JACKKNIFE_BLOCKS {
                normal.push(&rows[k].0, &rows[k].1, &(aligned_accel[k] - first_accel[k]));
            }
            normal
        })
        .collect();
    let all = blocks
        .iter()
        .fold(LeverArmNormal::default(), |sum, b| sum.plus(b));
    let noise = if all.correctable(&motion.noise_variance) {
        motion.noise_variance
    } else {
        [0.0; 3]
    };
    let (x, inverse) = all.solve(&noise)?;
    let r = Vector3::new(x[0], x[1], x[2]);
    let bias = Vector3::new(x[3], x[4], x[5]);
    let rss: f64 = (0..n)
        .map(|k| {
            let (m, y) = row(k);
            (y - m * r - bias).norm_squared()
        })
        .sum();
    let s2 = rss / (3 * n).saturating_sub(6).max(1) as f64;
    let deleted: Vec<Vector3<f64>> = blocks
        .iter()
        .filter_map(|b| all.less(b).solve(&noise))
        .map(|(x, _)| Vector3::new(x[0], x[1], x[2]))
        .collect();
    let g = deleted.len() as f64;
    let centre = deleted.iter().sum::<Vector3<f64>>() / g.max(1.0);
    let jackknife = |i: usize| {
        (g - 1.0) / g
            * deleted
                .iter()
                .map(|d| (d[i] - centre[i]).powi(2))
                .sum::<f64>()
    };
    let sigma = [0, 1, 2].map(|i| {
        let least_squares = (inverse[(i, i)] * s2).max(0.0);
        least_squares.max(jackknife(i)).sqrt()
    });
    (deleted.len() == JACKKNIFE_BLOCKS && sigma.iter().all(|s| *s < LEVER_ARM_SIGMA_MAX_M))
        .then_some(([r.x, r.y, r.z], sigma))
}

/// Every unit's gyro and accelerometer signals in the first unit's frame, per channel
/// (gx..az) and sample, with each unit's alignment.
pub(super) struct Aligned {
    pub signals: Vec<[Vec<f64>; 6]>,
    pub alignments: Vec<Alignment>,
    /// Some unit's rotation is not applied though its axes may be far from the first
    /// unit's ([`Rotation::apart`]).
    pub unobservable: bool,
    /// The lever-arm correction's error, common to the units; None where no lever arm is
    /// applied.
    pub correction_error: Option<CorrectionError>,
}

/// The lever-arm correction's error: the angular acceleration's noise e (rad/s^2) times each
/// unit's applied lever arm. Unit k's corrected accelerometers carry -e x r_k, so the
/// difference of units k and l carries (r_k - r_l) x e, the same e in every pair.
pub(super) struct CorrectionError {
    /// Lever arm applied to each unit, m, in the first unit's axes (zero where none).
    pub lever_arms_m: Vec<Vector3<f64>>,
    /// Haar wavelet variance of e per axis and level (from 1), (rad/s^2)^2.
    pub noise_wv: [Vec<f64>; 3],
}

impl CorrectionError {
    /// Covariance, at Haar level index `level` (0 for level 1), of the correction's error in
    /// the differences of the pairs `kl` and `mo` on accelerometer axis `axis` (0 = x),
    /// (m/s^2)^2; the axes of e taken as independent (each comes from its own gyro axis).
    pub fn pair_covariance(
        &self,
        axis: usize,
        level: usize,
        kl: (usize, usize),
        mo: (usize, usize),
    ) -> f64 {
        let arm =
            |(a, b): (usize, usize)| (self.lever_arms_m[a] - self.lever_arms_m[b]).cross_matrix();
        let (p, q) = (arm(kl), arm(mo));
        (0..3)
            .map(|b| {
                let wv = self.noise_wv[b].get(level).copied().unwrap_or(0.0);
                p[(axis, b)] * q[(axis, b)] * wv
            })
            .sum()
    }
}

/// A triad's samples as vectors.
type Series3 = Vec<Vector3<f64>>;

/// A unit's rotation to the first unit's axes: y_k = C y_0, the 1-sigma of the rotation
/// about the least-turned axis (rad), and whether the motion determines it.
struct Rotation {
    c: Matrix3<f64>,
    sigma_rad: f64,
    determined: bool,
}

impl Rotation {
    /// Not applied, though the unit's axes may be far from the first unit's: nothing shows
    /// the rotation (static data), or it stands clear of none but is known too loosely.
    fn apart(&self) -> bool {
        let angle = nalgebra::Rotation3::from_matrix_unchecked(self.c).angle();
        !self.determined && (self.sigma_rad.is_infinite() || angle > 2.0 * self.sigma_rad)
    }
}

/// Every unit in the first unit's frame: the rotations from the gyros, then the platform's
/// motion from the rotated gyros of the units whose rotation is determined, then the lever
/// arms and the accelerometers corrected for them.
pub(super) fn align(units: &[(String, ImuRecording)], notes: &mut Vec<String>) -> Aligned {
    let gyro = |r: &ImuRecording| r.gyro_rad_s.clone().expect("checked");
    let accel = |r: &ImuRecording| r.accel_m_s2.clone().expect("checked");
    let first = &units[0].1;
    let dt_s = 1.0 / first.rate_hz();
    let n = first.len();
    let lag = (LAG_S / dt_s).round() as usize;
    let first_changes = lagged_changes(&gyro(first), lag);
    let rotations: Vec<Rotation> = units
        .iter()
        .enumerate()
        .map(|(k, (_, r))| {
            let (c, sigma_rad, determined) = if k == 0 {
                (Matrix3::identity(), 0.0, true)
            } else {
                rotation_from_gyros(&first_changes, &lagged_changes(&gyro(r), lag))
            };
            Rotation {
                c,
                sigma_rad,
                determined,
            }
        })
        .collect();
    let rotated: Vec<(Series3, Series3)> = units
        .iter()
        .zip(&rotations)
        .map(|((_, r), rot)| {
            let into_first = |t: &[Vec<f64>; 3]| -> Vec<Vector3<f64>> {
                (0..n)
                    .map(|i| {
                        if rot.determined {
                            rot.c.transpose() * at(t, i)
                        } else {
                            at(t, i)
                        }
                    })
                    .collect()
            };
            (into_first(&gyro(r)), into_first(&accel(r)))
        })
        .collect();
    let determined_gyros: Vec<Vec<Vector3<f64>>> = rotated
        .iter()
        .zip(&rotations)
        .filter(|(_, rot)| rot.determined)
        .map(|((g, _), _)| g.clone())
        .collect();
    let motion = motion(&determined_gyros, dt_s);
    let mut lever_arms_m = Vec::new();
    let mut signals = Vec::new();
    let mut alignments = Vec::new();
    for (k, ((name, _), (rot, (g, f)))) in
        units.iter().zip(rotations.iter().zip(&rotated)).enumerate()
    {
        let lever = (k > 0 && rot.determined)
            .then(|| lever_arm(&motion, &rotated[0].1, f))
            .flatten();
        if k > 0 {
            note_alignment(notes, name, &units[0].0, rot, lever.is_some());
        }
        let mut six: [Vec<f64>; 6] = Default::default();
        for i in 0..n {
            let (w, w_dot) = &motion.rate_and_acceleration[i];
            let correction = match &lever {
                Some((r, _)) => lever_matrix(w, w_dot) * Vector3::from(*r),
                None => Vector3::zeros(),
            };
            let corrected = f[i] - correction;
            for a in 0..3 {
                six[a].push(g[i][a]);
                six[3 + a].push(corrected[a]);
            }
        }
        signals.push(six);
        lever_arms_m.push(lever.map_or(Vector3::zeros(), |(r, _)| Vector3::from(r)));
        alignments.push(Alignment {
            basis: match (k, rot.determined) {
                (0, _) => RotationBasis::Reference,
                (_, true) => RotationBasis::Gyros,
                (_, false) => RotationBasis::Undetermined,
            },
            rotation_rpy_deg: rot.determined.then(|| rpy_deg(&rot.c)),
            rotation_sigma_deg: rot.determined.then(|| rot.sigma_rad.to_degrees()),
            lever_arm_m: lever.map(|(r, _)| r),
            lever_arm_sigma_m: lever.map(|(_, s)| s),
        });
    }
    let unobservable = rotations.iter().any(Rotation::apart);
    let corrected = lever_arms_m.iter().any(|r| r.norm() > 0.0);
    Aligned {
        signals,
        alignments,
        unobservable,
        correction_error: corrected.then_some(CorrectionError {
            lever_arms_m,
            noise_wv: motion.noise_wv,
        }),
    }
}

/// What the output must say of a unit's alignment when the motion did not determine it.
fn note_alignment(notes: &mut Vec<String>, name: &str, first: &str, rot: &Rotation, lever: bool) {
    let angle_deg = nalgebra::Rotation3::from_matrix_unchecked(rot.c)
        .angle()
        .to_degrees();
    if !rot.determined && rot.sigma_rad.is_finite() && !rot.apart() {
        notes.push(format!(
            "{name}: its rotation to {first} is within two sigmas ({:.2} deg) of none, so its \
             axes are compared as they are; what misalignment there is stays in its error",
            2.0 * rot.sigma_rad.to_degrees()
        ));
    } else if !rot.determined && rot.sigma_rad.is_finite() {
        notes.push(format!(
            "{name}: its rotation to {first} (about {angle_deg:.0} deg) is known only to {:.1} \
             deg (the motion barely turns it, as a static rig's few bumps), so it is not \
             applied: its axes are compared as they are",
            rot.sigma_rad.to_degrees()
        ));
    } else if !rot.determined {
        notes.push(format!(
            "{name}: the motion does not turn about two axes, so its rotation to {first} is not \
             determined (static data see only gravity: no rotation about it); its axes are \
             compared as they are, which on static data loses nothing (a constant difference \
             has no wavelet variance) and under motion leaves the misalignment in its error"
        ));
    } else if !lever {
        notes.push(format!(
            "{name}: the angular motion does not determine its lever arm to {first} to 1 cm, so \
             its accelerometers are not corrected for one"
        ));
    }
}
