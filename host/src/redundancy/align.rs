//! Bringing every unit into the first unit's frame from the redundant data themselves: the
//! rotation from the gyros (Wahba's problem, Markley's SVD solution) when the motion turns
//! about two axes or more, then the lever arm from the accelerometers' differences against
//! the angular acceleration and centripetal terms (the seed paper's eq. (9) between two
//! MEMS units), each with its uncertainty and a note where the motion does not determine it.
//!
//! A run is read in stretches ([`super::stretches`]): one for a recording held whole, many
//! for a long one. Each estimate is summed over the stretches ([`RotationSums`],
//! [`LeverSums`]), so memory follows a stretch, not the run; the signals are then aligned
//! stretch by stretch ([`aligned_signals`]).

use std::ops::Range;

use nalgebra::{Matrix3, Vector3};

use dynacal_core::redundancy::{lever_matrix, LeverArmNormal, RotationAccumulator};

use super::derivative::SpectralDerivative;
use super::stretches::{PieceWv, Stretch};
use super::{members, Alignment, RotationBasis};
use crate::interchange::ImuRecording;

/// Sample k of a triad as a vector.
fn at(triad: &[Vec<f64>; 3], k: usize) -> Vector3<f64> {
    Vector3::new(triad[0][k], triad[1][k], triad[2][k])
}

/// Lag of the differences the rotation is solved on, s.
const LAG_S: f64 = 0.5;

/// Changes of a triad over `lag` samples at the samples `own` (those with `lag` samples
/// before them): a bias does not rotate with the motion, and differences remove it; a
/// unit's bias that steps weighs on `lag` samples only, which the second solution of
/// [`RotationSums::push`] drops (a faulty unit must not be misaligned by its fault).
fn lagged_changes(triad: &[Vec<f64>; 3], lag: usize, own: &Range<usize>) -> Vec<Vector3<f64>> {
    (own.start.max(lag)..own.end)
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

/// A unit's gyro triad.
fn gyro(r: &ImuRecording) -> &[Vec<f64>; 3] {
    r.gyro_rad_s.as_ref().expect("checked: both triads")
}

/// A unit's accelerometer triad.
fn accel(r: &ImuRecording) -> &[Vec<f64>; 3] {
    r.accel_m_s2.as_ref().expect("checked: both triads")
}

/// The rotations C with w_k = C w_0, from the gyros' changes over [`LAG_S`] summed over
/// the run's stretches. Each stretch is solved twice: the second time without the samples
/// whose residual is beyond 5 times the stretch's median (a unit's fault, a clipped peak, a
/// crash must not turn the whole run's rotation); the kept samples of every stretch give
/// the rotation, its 1-sigma ([`RotationAccumulator::sigma_rad`]) and whether the motion
/// determines it.
pub(super) struct RotationSums {
    /// Per unit (the first's unused): every change, and the changes kept.
    all: Vec<RotationAccumulator<f64>>,
    kept: Vec<RotationAccumulator<f64>>,
}

impl RotationSums {
    pub fn new(units: usize) -> Self {
        Self {
            all: vec![RotationAccumulator::default(); units],
            kept: vec![RotationAccumulator::default(); units],
        }
    }

    /// Adds a stretch's own samples.
    pub fn push(&mut self, stretch: &Stretch, dt_s: f64) {
        let n = stretch.grid.t_s.len();
        let lag = ((LAG_S / dt_s).round() as usize).clamp(1, n.saturating_sub(1).max(1));
        let changes = |k: usize| lagged_changes(gyro(&stretch.grid.filled[k].1), lag, &stretch.own);
        let first = changes(0);
        for k in 1..self.all.len() {
            let unit = changes(k);
            let mut stretch_all = RotationAccumulator::default();
            for (w0, wk) in first.iter().zip(&unit) {
                stretch_all.push(w0, wk);
                self.all[k].push(w0, wk);
            }
            let Some(rough) = stretch_all.rotation() else {
                continue;
            };
            let residual: Vec<f64> = first
                .iter()
                .zip(&unit)
                .map(|(w0, wk)| (wk - rough * w0).norm())
                .collect();
            let mut sorted = residual.clone();
            let median = *sorted
                .select_nth_unstable_by(residual.len() / 2, f64::total_cmp)
                .1;
            for ((w0, wk), r) in first.iter().zip(&unit).zip(&residual) {
                if *r <= 5.0 * median {
                    self.kept[k].push(w0, wk);
                }
            }
        }
    }

    /// Each unit's rotation (the first's the identity).
    pub fn finish(&self) -> Vec<Rotation> {
        (0..self.all.len())
            .map(|k| {
                if k == 0 {
                    return Rotation {
                        c: Matrix3::identity(),
                        sigma_rad: 0.0,
                        determined: true,
                    };
                }
                let Some(rough) = self.all[k].rotation() else {
                    return Rotation {
                        c: Matrix3::identity(),
                        sigma_rad: f64::INFINITY,
                        determined: false,
                    };
                };
                let c = self.kept[k].rotation().unwrap_or(rough);
                let sigma = self.kept[k].sigma_rad(&c).unwrap_or(f64::INFINITY);
                // Determined when known to ROTATION_SIGMA_MAX_RAD, or when the rotation
                // stands two sigmas clear of none and is known to ROTATION_SIGMA_LOOSE_RAD
                // (units on a vibrating frame: 1-2 deg apart, known to 0.5-0.7 deg);
                // otherwise none is as good an estimate.
                let angle = nalgebra::Rotation3::from_matrix_unchecked(c).angle();
                let clear = angle > 2.0 * sigma && sigma < ROTATION_SIGMA_LOOSE_RAD;
                Rotation {
                    c,
                    sigma_rad: sigma,
                    determined: sigma < ROTATION_SIGMA_MAX_RAD || clear,
                }
            })
            .collect()
    }
}

/// Roll, pitch, yaw (Z-Y-X) of a rotation matrix, deg.
fn rpy_deg(c: &Matrix3<f64>) -> [f64; 3] {
    let r = nalgebra::Rotation3::from_matrix_unchecked(*c);
    let (roll, pitch, yaw) = r.euler_angles();
    [roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()]
}

/// Per sample of a stretch, the platform's angular rate (the mean of the units whose
/// rotation is known, rad/s) and its rate of change ([`SpectralDerivative`], rad/s^2).
type RateAndAcceleration = Vec<(Vector3<f64>, Vector3<f64>)>;

/// What the derivative lets through of the gyros' noise, summed over the run's stretches.
/// It is measured on the gyros' pairwise differences, which hold no motion: each
/// difference through the same filter has the variance V_j + V_k (V_k unit k's noise
/// through the filter), the sum over the pairs is (M - 1) times the sum of the V_k, and the
/// mean of M units lets through their sum over M^2; the same holds of the wavelet variances
/// per level.
pub(super) struct DerivativeNoise {
    /// Per axis: the sum over the pairs and samples of the filtered differences' squares,
    /// and the samples summed (per pair).
    squares: [f64; 3],
    samples: [usize; 3],
    /// Per axis and pair: the filtered difference's Haar wavelet variance.
    wv: [Vec<PieceWv>; 3],
    /// The units the mean is over.
    units: usize,
}

impl DerivativeNoise {
    pub fn new(units: usize, pieces: usize, dt_s: f64) -> Self {
        let pairs = units * units.saturating_sub(1) / 2;
        Self {
            squares: [0.0; 3],
            samples: [0; 3],
            wv: std::array::from_fn(|_| (0..pairs).map(|_| PieceWv::new(pieces, dt_s)).collect()),
            units,
        }
    }

    fn share(&self) -> f64 {
        1.0 / (self.units.saturating_sub(1) * self.units * self.units).max(1) as f64
    }

    /// Variance of the gyro noise the derivative lets through, per axis, (rad/s^2)^2.
    pub fn variance(&self) -> [f64; 3] {
        std::array::from_fn(|a| self.squares[a] / self.samples[a].max(1) as f64 * self.share())
    }

    /// Its Haar wavelet variance per axis and level (from 1), (rad/s^2)^2.
    pub fn wavelet_variance(&self) -> [Vec<f64>; 3] {
        std::array::from_fn(|a| {
            let mut levels: Vec<f64> = Vec::new();
            for pair in &self.wv[a] {
                let Some((wv, _)) = pair.result() else {
                    continue;
                };
                levels.resize(levels.len().max(wv.variance.len()), 0.0);
                for (sum, v) in levels.iter_mut().zip(&wv.variance) {
                    *sum += v * self.share();
                }
            }
            levels
        })
    }
}

/// The platform's [`RateAndAcceleration`] over a stretch, from the rotated gyros of the
/// units whose rotation is known; `noise`, where given, takes what the derivative lets
/// through of their noise at the stretch's own samples.
fn platform_motion(
    gyros: &[&Series3],
    dt_s: f64,
    own: &Range<usize>,
    mut noise: Option<&mut DerivativeNoise>,
) -> RateAndAcceleration {
    let n = gyros[0].len();
    let units = gyros.len();
    let mean: Vec<Vector3<f64>> = (0..n)
        .map(|i| gyros.iter().map(|g| g[i]).sum::<Vector3<f64>>() / units as f64)
        .collect();
    let mut derivatives: [Vec<f64>; 3] = Default::default();
    for a in 0..3 {
        let axis = |g: &[Vector3<f64>]| -> Vec<f64> { g.iter().map(|w| w[a]).collect() };
        let Some(filter) = SpectralDerivative::fit(&axis(&mean), dt_s) else {
            derivatives[a] = vec![0.0; n];
            continue;
        };
        derivatives[a] = filter.apply(&axis(&mean));
        let Some(noise) = noise.as_deref_mut() else {
            continue;
        };
        for (p, &(j, k)) in members(units).iter().enumerate() {
            let difference: Vec<f64> = (0..n).map(|i| gyros[j][i][a] - gyros[k][i][a]).collect();
            let through = filter.apply(&difference);
            let through = &through[own.clone()];
            noise.squares[a] += through.iter().map(|v| v * v).sum::<f64>();
            noise.wv[a][p].add(through);
        }
        noise.samples[a] += own.len();
    }
    (0..n)
        .map(|i| {
            let d = |a: usize| derivatives[a][i];
            (mean[i], Vector3::new(d(0), d(1), d(2)))
        })
        .collect()
}

/// Largest 1-sigma of a lever-arm component still applied, m: beyond it the motion does not
/// determine the lever arm, and correcting with it would add noise.
const LEVER_ARM_SIGMA_MAX_M: f64 = 0.01;

/// Blocks of the lever arm's jackknife: enough for its variance to have 19 degrees of
/// freedom, few enough that each block holds several manoeuvres of a drive.
const JACKKNIFE_BLOCKS: usize = 20;

/// The lever arms' normal equations, summed over the run's stretches in
/// [`JACKKNIFE_BLOCKS`] stretches of the run each (the core's [`LeverArmNormal`]).
pub(super) struct LeverSums {
    /// Per unit and block.
    blocks: Vec<Vec<LeverArmNormal<f64>>>,
    /// Per unit: the sum of the squared specific-force differences.
    squares: Vec<f64>,
    /// Epochs of the run.
    epochs: usize,
}

impl LeverSums {
    pub fn new(units: usize, epochs: usize) -> Self {
        Self {
            blocks: vec![vec![LeverArmNormal::default(); JACKKNIFE_BLOCKS]; units],
            squares: vec![0.0; units],
            epochs,
        }
    }

    /// The jackknife block of the run's epoch e: b with floor(b n / B) <= e < floor((b + 1)
    /// n / B).
    fn block(&self, e: usize) -> usize {
        let (n, blocks) = (self.epochs.max(1), JACKKNIFE_BLOCKS);
        let mut b = (e * blocks / n).min(blocks - 1);
        while b + 1 < blocks && (b + 1) * n / blocks <= e {
            b += 1;
        }
        b
    }

    /// Adds a stretch's own samples of every unit whose rotation is known.
    fn push(
        &mut self,
        stretch: &Stretch,
        motion: &RateAndAcceleration,
        rotated: &[(Series3, Series3)],
        rotations: &[Rotation],
    ) {
        for k in (1..rotated.len()).filter(|k| rotations[*k].determined) {
            for (e, i) in (stretch.first_epoch..).zip(stretch.own.clone()) {
                let difference = rotated[k].1[i] - rotated[0].1[i];
                let b = self.block(e);
                self.blocks[k][b].push(&motion[i].0, &motion[i].1, &difference);
                self.squares[k] += difference.norm_squared();
            }
        }
    }

    /// Lever arm of unit k from the first, in the first unit's axes (least squares of eq.
    /// (9) with a bias per axis, corrected for the derivative's noise `noise_variance` where
    /// that leaves half the information: the core's [`LeverArmNormal`]), with its 1-sigma;
    /// None when the motion does not determine it. The sigma is the larger of the least
    /// squares' (white residuals) and a delete-one-block jackknife's over
    /// [`JACKKNIFE_BLOCKS`] stretches of the run, which also covers what the least squares
    /// takes as white and is not: the angular acceleration's error, coloured and
    /// multiplying the lever arm, and manoeuvres that differ along the run.
    fn lever_arm(&self, k: usize, noise_variance: &[f64; 3]) -> Option<([f64; 3], [f64; 3])> {
        let blocks = &self.blocks[k];
        let all = blocks
            .iter()
            .fold(LeverArmNormal::default(), |sum, b| sum.plus(b));
        let noise = if all.correctable(noise_variance) {
            *noise_variance
        } else {
            [0.0; 3]
        };
        let (x, inverse) = all.solve(&noise)?;
        let rss = all.residual_sum_of_squares(&x, self.squares[k]).max(0.0);
        let s2 = rss / (3 * self.epochs).saturating_sub(6).max(1) as f64;
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
            .then_some(([x[0], x[1], x[2]], sigma))
    }
}

/// Each unit's place relative to the first, and what the signals' alignment needs.
pub(super) struct Aligned {
    pub alignments: Vec<Alignment>,
    pub rotations: Vec<Rotation>,
    /// Lever arm applied to each unit, m, in the first unit's axes (zero where none).
    pub lever_arms_m: Vec<Vector3<f64>>,
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
pub(super) struct Rotation {
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

/// Every unit's gyros and accelerometers over a stretch in the first unit's axes, where its
/// rotation is determined (as they are otherwise).
fn rotated(stretch: &Stretch, rotations: &[Rotation]) -> Vec<(Series3, Series3)> {
    let n = stretch.grid.t_s.len();
    stretch
        .grid
        .filled
        .iter()
        .zip(rotations)
        .map(|((_, r), rot)| {
            let into_first = |t: &[Vec<f64>; 3]| -> Series3 {
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
            (into_first(gyro(r)), into_first(accel(r)))
        })
        .collect()
}

/// The platform's motion over a stretch from the rotated gyros of the units whose rotation
/// is determined.
fn stretch_motion(
    rotated: &[(Series3, Series3)],
    rotations: &[Rotation],
    dt_s: f64,
    own: &Range<usize>,
    noise: Option<&mut DerivativeNoise>,
) -> RateAndAcceleration {
    let determined: Vec<&Series3> = rotated
        .iter()
        .zip(rotations)
        .filter(|(_, rot)| rot.determined)
        .map(|((g, _), _)| g)
        .collect();
    platform_motion(&determined, dt_s, own, noise)
}

/// The units whose rotation is determined.
pub(super) fn determined_units(rotations: &[Rotation]) -> usize {
    rotations.iter().filter(|r| r.determined).count()
}

/// Adds a stretch to the derivative's noise and the lever arms' sums.
pub(super) fn push_motion(
    stretch: &Stretch,
    rotations: &[Rotation],
    dt_s: f64,
    noise: &mut DerivativeNoise,
    levers: &mut LeverSums,
) {
    let rotated = rotated(stretch, rotations);
    let motion = stretch_motion(&rotated, rotations, dt_s, &stretch.own, Some(noise));
    levers.push(stretch, &motion, &rotated, rotations);
}

/// Every unit's place from the run's sums: its rotation, and the lever arm of each unit
/// whose rotation is determined, with the notes where the motion does not determine them.
pub(super) fn alignments(
    names: &[String],
    rotations: Vec<Rotation>,
    noise: &DerivativeNoise,
    levers: &LeverSums,
    notes: &mut Vec<String>,
) -> Aligned {
    let noise_variance = noise.variance();
    let mut lever_arms_m = Vec::new();
    let mut alignments = Vec::new();
    for (k, (name, rot)) in names.iter().zip(&rotations).enumerate() {
        let lever = (k > 0 && rot.determined)
            .then(|| levers.lever_arm(k, &noise_variance))
            .flatten();
        if k > 0 {
            note_alignment(notes, name, &names[0], rot, lever.is_some());
        }
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
        alignments,
        correction_error: corrected.then(|| CorrectionError {
            lever_arms_m: lever_arms_m.clone(),
            noise_wv: noise.wavelet_variance(),
        }),
        rotations,
        lever_arms_m,
        unobservable,
    }
}

/// Every unit's gyro and accelerometer signals over a stretch in the first unit's frame,
/// per channel (gx..az) and sample: rotated, and the accelerometers corrected for the lever
/// arms.
pub(super) fn aligned_signals(
    stretch: &Stretch,
    aligned: &Aligned,
    dt_s: f64,
) -> Vec<[Vec<f64>; 6]> {
    let rotated = rotated(stretch, &aligned.rotations);
    let levered = aligned.lever_arms_m.iter().any(|r| r.norm() > 0.0);
    let motion =
        levered.then(|| stretch_motion(&rotated, &aligned.rotations, dt_s, &stretch.own, None));
    rotated
        .iter()
        .zip(&aligned.lever_arms_m)
        .map(|((g, f), r)| {
            let mut six: [Vec<f64>; 6] = Default::default();
            for i in 0..g.len() {
                let correction = match &motion {
                    Some(m) if r.norm() > 0.0 => lever_matrix(&m[i].0, &m[i].1) * r,
                    _ => Vector3::zeros(),
                };
                let corrected = f[i] - correction;
                for a in 0..3 {
                    six[a].push(g[i][a]);
                    six[3 + a].push(corrected[a]);
                }
            }
            six
        })
        .collect()
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
