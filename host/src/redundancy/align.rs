//! Bringing every unit into the first unit's frame from the redundant data themselves: the
//! rotation from the gyros (Wahba's problem, Markley's SVD solution) when the motion turns
//! about two axes or more, then the lever arm from the accelerometers' differences against
//! the angular acceleration and centripetal terms (the seed paper's eq. (9) between two
//! MEMS units), each with its uncertainty and a note where the motion does not determine it.

use nalgebra::{Matrix3, Vector3};

use super::{Alignment, RotationBasis};
use crate::interchange::ImuRecording;

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

/// Wahba's problem on the sample pairs `keep` selects: the rotation C with w_k = C w_0
/// (Markley's SVD solution).
fn wahba(first: &[Vector3<f64>], unit: &[Vector3<f64>], keep: &[bool]) -> Matrix3<f64> {
    let b: Matrix3<f64> = first
        .iter()
        .zip(unit)
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|((w0, wk), _)| wk * w0.transpose())
        .sum();
    let svd = b.svd(true, true);
    let (u, v_t) = (svd.u.expect("u"), svd.v_t.expect("v_t"));
    let d = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, (u * v_t).determinant().signum()));
    u * d * v_t
}

/// Rotation C with w_k = C w_0 from the gyros' changes over [`LAG_S`], its 1-sigma and
/// whether the motion determines it. Solved twice: the second time without the samples
/// whose residual is beyond 5 times the median's (a unit's fault, a clipped peak, a crash
/// must not turn the whole run's rotation). The rotation about the least-turned direction
/// has a 1-sigma of sqrt(s^2 / L2), s^2 the per-sample residual variance of an axis and L2
/// the second-largest eigenvalue of the first unit's rate scatter (summed over the kept
/// samples) less the noise's share; a motion about one axis leaves the rotation about it
/// free (infinite sigma).
fn rotation_from_gyros(first: &[Vector3<f64>], unit: &[Vector3<f64>]) -> (Matrix3<f64>, f64, bool) {
    let all = vec![true; first.len()];
    let rough = wahba(first, unit, &all);
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
    let c = wahba(first, unit, &keep);
    let kept = || first.iter().zip(unit).zip(&keep).filter(|(_, k)| **k);
    let n = kept().count().max(1) as f64;
    let scatter: Matrix3<f64> = kept().map(|((w, _), _)| w * w.transpose()).sum();
    let mut eig: Vec<f64> = scatter.symmetric_eigenvalues().iter().copied().collect();
    eig.sort_by(f64::total_cmp);
    let residual_per_sample = kept()
        .map(|((w0, wk), _)| (wk - c * w0).norm_squared())
        .sum::<f64>()
        / (3.0 * n);
    // The scatter holds the first unit's noise too (about n s0^2 on every axis; the
    // residual variance is s0^2 + sk^2, taken as half each): only what stands above it is
    // motion.
    let motion = eig[1] - n * residual_per_sample / 2.0;
    let sigma = if motion > 0.0 {
        (residual_per_sample / motion).sqrt()
    } else {
        f64::INFINITY
    };
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

/// Rate of change of `x` (sampled every `dt_s`) by a spectral derivative of its Wiener-
/// filtered spectrum: each bin kept in proportion to how far its power stands above the
/// white noise floor (the median bin power over ln 2, the mean of an exponential law), then
/// multiplied by i 2 pi f. Why not differences: a car's or a copter's vibration puts
/// angular acceleration at 10-30 Hz, which central differences at 100 Hz lose up to 40% of,
/// and an exact derivative of the raw rate amplifies the gyro noise at every frequency;
/// the filter keeps the vibration lines and the manoeuvres, which stand above the noise,
/// and little of the noise.
fn spectral_derivative(x: &[f64], dt_s: f64) -> Vec<f64> {
    use realfft::RealFftPlanner;
    let n = x.len();
    let mean = x.iter().sum::<f64>() / n as f64;
    let mut planner = RealFftPlanner::<f64>::new();
    let forward = planner.plan_fft_forward(n);
    let inverse = planner.plan_fft_inverse(n);
    let mut input: Vec<f64> = x.iter().map(|v| v - mean).collect();
    let mut spectrum = forward.make_output_vec();
    if forward.process(&mut input, &mut spectrum).is_err() {
        return vec![0.0; n];
    }
    let mut power: Vec<f64> = spectrum.iter().map(|c| c.norm_sqr()).collect();
    let mid = power.len() / 2;
    let floor = *power.select_nth_unstable_by(mid, f64::total_cmp).1 / std::f64::consts::LN_2;
    let last = spectrum.len() - 1;
    for (k, c) in spectrum.iter_mut().enumerate() {
        let p = c.norm_sqr();
        let keep = if p > 0.0 {
            (1.0 - floor / p).max(0.0)
        } else {
            0.0
        };
        let omega = 2.0 * std::f64::consts::PI * k as f64 / (n as f64 * dt_s);
        *c = if k == 0 || (n.is_multiple_of(2) && k == last) {
            realfft::num_complex::Complex::new(0.0, 0.0)
        } else {
            *c * realfft::num_complex::Complex::new(0.0, omega * keep)
        };
    }
    let mut out = inverse.make_output_vec();
    if inverse.process(&mut spectrum, &mut out).is_err() {
        return vec![0.0; n];
    }
    out.iter().map(|v| v / n as f64).collect()
}

/// The platform's angular rate (the mean of the aligned units' gyros, rad/s) and its rate
/// of change ([`spectral_derivative`], rad/s^2), per sample.
fn rate_and_acceleration(
    aligned_gyros: &[Vec<Vector3<f64>>],
    dt_s: f64,
) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let n = aligned_gyros[0].len();
    let units = aligned_gyros.len() as f64;
    let mean: Vec<Vector3<f64>> = (0..n)
        .map(|i| aligned_gyros.iter().map(|g| g[i]).sum::<Vector3<f64>>() / units)
        .collect();
    let derivative: Vec<Vec<f64>> = (0..3)
        .map(|a| {
            let axis: Vec<f64> = mean.iter().map(|w| w[a]).collect();
            spectral_derivative(&axis, dt_s)
        })
        .collect();
    (0..n)
        .map(|i| {
            let w_dot = Vector3::new(derivative[0][i], derivative[1][i], derivative[2][i]);
            (mean[i], w_dot)
        })
        .collect()
}

/// The lever-arm matrix of eq. (9): f_k - f_0 = (Omega_dot + Omega^2) r, Omega the cross
/// product matrix of the angular rate.
fn lever_matrix(w: &Vector3<f64>, w_dot: &Vector3<f64>) -> Matrix3<f64> {
    let o = w.cross_matrix();
    w_dot.cross_matrix() + o * o
}

/// Largest 1-sigma of a lever-arm component still applied, m: beyond it the motion does not
/// determine the lever arm, and correcting with it would add noise.
const LEVER_ARM_SIGMA_MAX_M: f64 = 0.01;

/// Lever arm of a unit from the first, in the first unit's axes (least squares of eq. (9)
/// with a bias per axis), with its 1-sigma; None when the motion does not determine it.
fn lever_arm(
    motion: &[(Vector3<f64>, Vector3<f64>)],
    first_accel: &[Vector3<f64>],
    aligned_accel: &[Vector3<f64>],
) -> Option<([f64; 3], [f64; 3])> {
    let n = motion.len();
    let mut normal = nalgebra::Matrix6::<f64>::zeros();
    let mut rhs = nalgebra::Vector6::<f64>::zeros();
    let rows = |k: usize| {
        let m = lever_matrix(&motion[k].0, &motion[k].1);
        let y = aligned_accel[k] - first_accel[k];
        (m, y)
    };
    for k in 0..n {
        let (m, y) = rows(k);
        for a in 0..3 {
            let row = nalgebra::Vector6::new(m[(a, 0)], m[(a, 1)], m[(a, 2)], 0.0, 0.0, 0.0)
                + nalgebra::Vector6::ith(3 + a, 1.0);
            normal += row * row.transpose();
            rhs += row * y[a];
        }
    }
    let inverse = normal.try_inverse()?;
    let x = inverse * rhs;
    let r = Vector3::new(x[0], x[1], x[2]);
    let b = Vector3::new(x[3], x[4], x[5]);
    let rss: f64 = (0..n)
        .map(|k| {
            let (m, y) = rows(k);
            (y - m * r - b).norm_squared()
        })
        .sum();
    let s2 = rss / (3 * n).saturating_sub(6).max(1) as f64;
    let sigma = [0, 1, 2].map(|i| (inverse[(i, i)] * s2).max(0.0).sqrt());
    sigma
        .iter()
        .all(|s| *s < LEVER_ARM_SIGMA_MAX_M)
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
    let motion = rate_and_acceleration(&determined_gyros, dt_s);
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
            let correction = match &lever {
                Some((r, _)) => lever_matrix(&motion[i].0, &motion[i].1) * Vector3::from(*r),
                None => Vector3::zeros(),
            };
            let corrected = f[i] - correction;
            for a in 0..3 {
                six[a].push(g[i][a]);
                six[3 + a].push(corrected[a]);
            }
        }
        signals.push(six);
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
    Aligned {
        signals,
        alignments,
        unobservable,
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
