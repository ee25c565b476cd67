//! `dynacal redundancy`: three or more IMUs sampled together characterise themselves without
//! a reference. Each unit is brought into the first unit's frame (the rotation from the
//! gyros, Wahba's problem solved by SVD, when the motion turns about two axes or more; the
//! lever arm from the accelerometers' differences against angular acceleration and
//! centripetal terms, the seed paper's eq. (9) between two MEMS units), then every pairwise
//! difference of the aligned signals, which cancels the motion, gives its Haar wavelet
//! variance per scale, and the units' own wavelet variances follow per scale by
//! non-negative least squares over the pairs ([`dynacal_core::redundancy::own_variances`]),
//! with each unit's white-noise variance from the finest scale. The live white-noise level of
//! each unit over time comes from the core's [`LiveNoise`], the same code the board runs.
//!
//! What the units share cancels in every difference (a common temperature drift, the same
//! vibration): the figures are the independent parts of the errors. On static data nothing
//! needs aligning (a constant difference has no wavelet variance) and no rotation or lever
//! arm can be determined; the output says so.

use std::collections::BTreeMap;

use dynacal_core::redundancy::{
    own_variances, pair_index, pairs, LiveNoise, MotionThresholds, MAX_UNITS,
};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

use crate::interchange::ImuRecording;
use crate::wv::{haar_wv, WvOptions};

/// Channel names in interchange order: gyros then accelerometers.
const CHANNELS: [&str; 6] = ["gx", "gy", "gz", "ax", "ay", "az"];

/// Why a set of recordings cannot be analysed together.
#[derive(Debug, thiserror::Error)]
pub enum RedundancyError {
    #[error("{0} recordings given: the analysis needs 3 to {MAX_UNITS} IMUs sampled together")]
    Units(usize),
    #[error("{name}: {message}")]
    Unit { name: String, message: String },
}

/// How a unit's rotation to the first unit was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RotationBasis {
    /// The first unit itself.
    Reference,
    /// From the gyros: the motion turned about two axes or more.
    Gyros,
    /// Not determined: the motion did not turn about two axes (static data determine no
    /// rotation about gravity); the unit's axes are compared as they are.
    Undetermined,
}

/// A unit's place relative to the first unit.
#[derive(Debug, Clone, Serialize)]
pub struct Alignment {
    pub basis: RotationBasis,
    /// Rotation from the first unit's axes to this unit's (y_k = C y_0), roll-pitch-yaw, deg;
    /// None where the motion does not determine it (then it is not applied).
    pub rotation_rpy_deg: Option<[f64; 3]>,
    /// 1-sigma of the rotation about the axis the motion turned least, deg (None where it is
    /// not determined).
    pub rotation_sigma_deg: Option<f64>,
    /// Lever arm from the first unit to this one, in the first unit's axes, m, with its
    /// 1-sigma; None where it cannot be determined (no angular acceleration to see it). The
    /// sigma covers the accelerometers' noise only, not the error of the angular
    /// acceleration the lever arm multiplies: on a simulated drive the errors were 1-3 mm
    /// against a sigma of 0.2 mm (BENCHMARKS.md).
    pub lever_arm_m: Option<[f64; 3]>,
    pub lever_arm_sigma_m: Option<[f64; 3]>,
}

/// One unit's own error wavelet variance on one channel.
#[derive(Debug, Clone, Serialize)]
pub struct OwnWv {
    pub scales_s: Vec<f64>,
    /// Own wavelet variance per scale, SI unit squared.
    pub variance: Vec<f64>,
    /// Where the least squares gave a negative variance, held at 0.
    pub clamped: Vec<bool>,
}

/// What the set says of one unit.
#[derive(Debug, Clone, Serialize)]
pub struct UnitReport {
    pub name: String,
    pub alignment: Alignment,
    /// Own white-noise variance per channel, SI unit squared, at the unit's sample rate:
    /// twice the own wavelet variance at the finest scale (white noise of variance s^2 has
    /// s^2 / 2 there).
    pub white_noise_sigma2: BTreeMap<String, f64>,
    pub wv: BTreeMap<String, OwnWv>,
}

/// A unit's live white-noise standard deviation over time.
#[derive(Debug, Clone, Serialize)]
pub struct NoiseLevel {
    pub t_s: Vec<f64>,
    pub gyro_rad_s: Vec<f64>,
    pub accel_m_s2: Vec<f64>,
}

/// The whole analysis.
#[derive(Debug, Clone, Serialize)]
pub struct RedundancyReport {
    pub imus: Vec<UnitReport>,
    pub noise_level: Vec<NoiseLevel>,
    /// Whether the platform moved, per output time of `noise_level`.
    pub moving: Vec<bool>,
    pub notes: Vec<String>,
}

/// Options of the analysis.
#[derive(Debug, Clone)]
pub struct RedundancyOptions {
    /// Time constant of the live noise level, s.
    pub live_time_constant_s: f64,
    /// Spacing of the live noise level's output, s.
    pub live_output_interval_s: f64,
}

impl Default for RedundancyOptions {
    fn default() -> Self {
        Self {
            live_time_constant_s: 2.0,
            live_output_interval_s: 0.5,
        }
    }
}

/// Checks that the recordings are 3 to MAX_UNITS IMUs with both triads, sampled together
/// (same length, same times to a tenth of a sample interval).
fn check_together(units: &[(String, ImuRecording)]) -> Result<(), RedundancyError> {
    if !(3..=MAX_UNITS).contains(&units.len()) {
        return Err(RedundancyError::Units(units.len()));
    }
    let (first_name, first) = &units[0];
    let dt = 1.0 / first.rate_hz().max(f64::MIN_POSITIVE);
    for (name, r) in units {
        let fail = |message: String| RedundancyError::Unit {
            name: name.clone(),
            message,
        };
        if r.gyro_rad_s.is_none() || r.accel_m_s2.is_none() {
            return Err(fail("needs both a gyro and an accelerometer triad".into()));
        }
        if r.len() != first.len() {
            return Err(fail(format!(
                "{} samples against {}'s {}: the units must be sampled together",
                r.len(),
                first_name,
                first.len()
            )));
        }
        if let Some(i) = (0..r.len()).find(|&i| (r.t_s[i] - first.t_s[i]).abs() > 0.1 * dt) {
            return Err(fail(format!(
                "sample {} is at t = {} s where {}'s is at {} s: the units must be sampled together",
                i + 1,
                r.t_s[i],
                first_name,
                first.t_s[i]
            )));
        }
    }
    if first.len() < 64 {
        return Err(RedundancyError::Unit {
            name: first_name.clone(),
            message: format!("{} samples: at least 64 are needed", first.len()),
        });
    }
    Ok(())
}

/// Sample k of a triad as a vector.
fn at(triad: &[Vec<f64>; 3], k: usize) -> Vector3<f64> {
    Vector3::new(triad[0][k], triad[1][k], triad[2][k])
}

/// Deviations of a triad from its mean, per sample (a bias does not rotate with the motion).
fn centred(triad: &[Vec<f64>; 3]) -> Vec<Vector3<f64>> {
    let n = triad[0].len();
    let mean = (0..n).map(|k| at(triad, k)).sum::<Vector3<f64>>() / n as f64;
    (0..n).map(|k| at(triad, k) - mean).collect()
}

/// Largest 1-sigma of the rotation about the least-turned axis for which a unit's rotation
/// counts as determined, rad (0.6 deg, the size of the boresights it is there to remove).
/// The axis turned least is also the one whose error leaks least into the gyro difference
/// (a rotation about the rate leaves the rate unchanged), so a loosely determined rotation
/// about it still aligns the gyros; on static data the sigma is far above this.
const ROTATION_SIGMA_MAX_RAD: f64 = 1e-2;

/// Rotation C with w_k = C w_0 from the gyros (Wahba's problem, Markley's SVD solution) on
/// the centred rates, its 1-sigma and whether the motion determines it: the rotation about
/// the least-turned direction has a 1-sigma of sqrt(s^2 / L2), s^2 the per-sample residual
/// variance of an axis and L2 the second-largest eigenvalue of the first unit's rate scatter
/// (summed over samples) less the noise's share; a motion about one axis leaves the
/// rotation about it free (infinite sigma).
fn rotation_from_gyros(first: &[Vector3<f64>], unit: &[Vector3<f64>]) -> (Matrix3<f64>, f64, bool) {
    let b: Matrix3<f64> = first
        .iter()
        .zip(unit)
        .map(|(w0, wk)| wk * w0.transpose())
        .sum();
    let svd = b.svd(true, true);
    let (u, v_t) = (svd.u.expect("u"), svd.v_t.expect("v_t"));
    let d = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, (u * v_t).determinant().signum()));
    let c = u * d * v_t;
    let scatter: Matrix3<f64> = first.iter().map(|w| w * w.transpose()).sum();
    let mut eig: Vec<f64> = scatter.symmetric_eigenvalues().iter().copied().collect();
    eig.sort_by(f64::total_cmp);
    let residual_per_sample = first
        .iter()
        .zip(unit)
        .map(|(w0, wk)| (wk - c * w0).norm_squared())
        .sum::<f64>()
        / (3 * first.len().max(1)) as f64;
    // The scatter holds the first unit's noise too (about n s0^2 on every axis, s0^2 below
    // the residual variance, which is s0^2 + sk^2): only what stands above it is motion.
    let motion = eig[1] - first.len() as f64 * residual_per_sample;
    let sigma = if motion > 0.0 {
        (residual_per_sample / motion).sqrt()
    } else {
        f64::INFINITY
    };
    (c, sigma, sigma < ROTATION_SIGMA_MAX_RAD)
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
struct Aligned {
    signals: Vec<[Vec<f64>; 6]>,
    alignments: Vec<Alignment>,
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

/// Every unit in the first unit's frame: the rotations from the gyros, then the platform's
/// motion from the rotated gyros of the units whose rotation is determined, then the lever
/// arms and the accelerometers corrected for them.
fn align(units: &[(String, ImuRecording)], notes: &mut Vec<String>) -> Aligned {
    let gyro = |r: &ImuRecording| r.gyro_rad_s.clone().expect("checked");
    let accel = |r: &ImuRecording| r.accel_m_s2.clone().expect("checked");
    let first = &units[0].1;
    let dt_s = 1.0 / first.rate_hz();
    let n = first.len();
    let first_centred = centred(&gyro(first));
    let rotations: Vec<Rotation> = units
        .iter()
        .enumerate()
        .map(|(k, (_, r))| {
            let (c, sigma_rad, determined) = if k == 0 {
                (Matrix3::identity(), 0.0, true)
            } else {
                rotation_from_gyros(&first_centred, &centred(&gyro(r)))
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
            note_alignment(notes, name, &units[0].0, rot.determined, lever.is_some());
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
    Aligned {
        signals,
        alignments,
    }
}

/// What the output must say of a unit's alignment when the motion did not determine it.
fn note_alignment(notes: &mut Vec<String>, name: &str, first: &str, rotation: bool, lever: bool) {
    if !rotation {
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

/// Each unit's own wavelet variance on channel `c`, from the wavelet variances of every
/// pairwise difference, per scale.
fn own_wv(signals: &[[Vec<f64>; 6]], c: usize, dt_s: f64) -> Vec<OwnWv> {
    let units = signals.len();
    let mut scales_s = Vec::new();
    let mut pair_wv: Vec<Vec<f64>> = vec![Vec::new(); pairs(units)];
    for k in 0..units {
        for l in k + 1..units {
            let d: Vec<f64> = signals[k][c]
                .iter()
                .zip(&signals[l][c])
                .map(|(a, b)| a - b)
                .collect();
            let wv = haar_wv(&d, dt_s, &WvOptions::default()).expect("at least 64 samples");
            scales_s = wv.scales_s.clone();
            pair_wv[pair_index(units, k, l)] = wv.variance;
        }
    }
    let mut out: Vec<OwnWv> = (0..units)
        .map(|_| OwnWv {
            scales_s: scales_s.clone(),
            variance: Vec::new(),
            clamped: Vec::new(),
        })
        .collect();
    for level in 0..scales_s.len() {
        let at_level: Vec<f64> = pair_wv.iter().map(|p| p[level]).collect();
        let own = own_variances(units, &at_level).expect("3..=MAX_UNITS units, variances");
        for (k, o) in out.iter_mut().enumerate() {
            o.variance.push(own.value[k]);
            o.clamped.push(own.clamped[k]);
        }
    }
    out
}

/// Each unit's live gyro and accelerometer white-noise level (the core's [`LiveNoise`]) and
/// the motion state, sampled every `opts.live_output_interval_s`.
fn live_levels<const N: usize>(
    signals: &[[Vec<f64>; 6]],
    t_s: &[f64],
    dt_s: f64,
    opts: &RedundancyOptions,
) -> (Vec<NoiseLevel>, Vec<bool>) {
    let tau = opts.live_time_constant_s as f32;
    let mut gyro = LiveNoise::<N>::new(dt_s as f32, tau, MotionThresholds::default());
    let mut accel = LiveNoise::<N>::new(dt_s as f32, tau, MotionThresholds::default());
    let mut levels: Vec<NoiseLevel> = (0..N)
        .map(|_| NoiseLevel {
            t_s: Vec::new(),
            gyro_rad_s: Vec::new(),
            accel_m_s2: Vec::new(),
        })
        .collect();
    let mut moving = Vec::new();
    let every = ((opts.live_output_interval_s / dt_s).round() as usize).max(1);
    for i in 0..t_s.len() {
        let triad = |first: usize| -> [[f32; 3]; N] {
            std::array::from_fn(|k| std::array::from_fn(|a| signals[k][first + a][i] as f32))
        };
        let g = triad(0);
        let rate: [f32; 3] =
            std::array::from_fn(|a| g.iter().map(|u| u[a]).sum::<f32>() / N as f32);
        gyro.push(&g, rate);
        accel.push(&triad(3), rate);
        if i % every == every - 1 {
            for (k, level) in levels.iter_mut().enumerate() {
                level.t_s.push(t_s[i]);
                level.gyro_rad_s.push(gyro.sigma(k) as f64);
                level.accel_m_s2.push(accel.sigma(k) as f64);
            }
            moving.push(gyro.moving());
        }
    }
    (levels, moving)
}

/// The analysis of `units` (name, recording), sampled together.
pub fn redundancy(
    units: &[(String, ImuRecording)],
    opts: &RedundancyOptions,
) -> Result<RedundancyReport, RedundancyError> {
    check_together(units)?;
    let mut notes = vec![
        "what the units share (a common temperature drift, the same vibration) cancels in \
         every difference: these are the independent parts of the units' errors"
            .to_string(),
    ];
    let first = &units[0].1;
    let dt_s = 1.0 / first.rate_hz();
    let aligned = align(units, &mut notes);
    let per_channel: Vec<Vec<OwnWv>> = (0..6).map(|c| own_wv(&aligned.signals, c, dt_s)).collect();
    let imus = units
        .iter()
        .zip(aligned.alignments)
        .enumerate()
        .map(|(k, ((name, _), alignment))| {
            let wv: BTreeMap<String, OwnWv> = CHANNELS
                .iter()
                .zip(&per_channel)
                .map(|(c, own)| (c.to_string(), own[k].clone()))
                .collect();
            UnitReport {
                name: name.clone(),
                alignment,
                white_noise_sigma2: wv
                    .iter()
                    .map(|(c, w)| (c.clone(), 2.0 * w.variance[0]))
                    .collect(),
                wv,
            }
        })
        .collect();
    let (noise_level, moving) = match units.len() {
        3 => live_levels::<3>(&aligned.signals, &first.t_s, dt_s, opts),
        4 => live_levels::<4>(&aligned.signals, &first.t_s, dt_s, opts),
        5 => live_levels::<5>(&aligned.signals, &first.t_s, dt_s, opts),
        6 => live_levels::<6>(&aligned.signals, &first.t_s, dt_s, opts),
        7 => live_levels::<7>(&aligned.signals, &first.t_s, dt_s, opts),
        _ => live_levels::<8>(&aligned.signals, &first.t_s, dt_s, opts),
    };
    Ok(RedundancyReport {
        imus,
        noise_level,
        moving,
        notes,
    })
}
