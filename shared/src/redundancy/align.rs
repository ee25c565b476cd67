//! One unit brought into another's frame from their own signals, streaming and without
//! allocation, so the board and the host share it. The rotation is Wahba's problem on the
//! same motion seen by both units (gyro changes over a lag: a bias does not rotate with the
//! motion), accumulated as the attitude profile matrix B = sum w_k w_0^T and solved by SVD
//! (Markley); its 1-sigma about the least-turned axis says when the motion determines it
//! (static data turn about no axis, so no rotation about gravity can be seen). The lever arm
//! is the seed paper's eq. (9) between two units, f_k - f_0 = (W_dot + W^2) r + b (W the
//! cross-product matrix of the angular rate), accumulated as normal equations in r and a
//! bias b per axis. Generic over the float: f32 on the board, f64 on the host.

use nalgebra::{Matrix3, Matrix6, RealField, Vector3, Vector6};

/// Wahba's problem accumulated pair by pair: the first unit's view `w_0` and another
/// unit's view `w_k` of the same motion, in their own axes.
#[derive(Debug, Clone, Copy)]
pub struct RotationAccumulator<T: RealField + Copy> {
    /// Attitude profile matrix sum w_k w_0^T.
    profile: Matrix3<T>,
    /// Scatter of the first unit's view, sum w_0 w_0^T.
    scatter: Matrix3<T>,
    /// sum |w_k|^2 + |w_0|^2.
    squares: T,
    /// Pairs added.
    pairs: T,
}

impl<T: RealField + Copy> Default for RotationAccumulator<T> {
    fn default() -> Self {
        Self {
            profile: Matrix3::zeros(),
            scatter: Matrix3::zeros(),
            squares: T::zero(),
            pairs: T::zero(),
        }
    }
}

impl<T: RealField + Copy> RotationAccumulator<T> {
    /// Adds one pair of views of the same motion.
    pub fn push(&mut self, first: &Vector3<T>, unit: &Vector3<T>) {
        self.profile += unit * first.transpose();
        self.scatter += first * first.transpose();
        self.squares += unit.norm_squared() + first.norm_squared();
        self.pairs += T::one();
    }

    /// Pairs added.
    pub fn pairs(&self) -> T {
        self.pairs
    }

    /// The rotation C with w_k = C w_0 (a proper rotation: the SVD's smallest direction is
    /// flipped where U V^T would reflect); None before any pair or where the SVD fails.
    pub fn rotation(&self) -> Option<Matrix3<T>> {
        if self.pairs == T::zero() {
            return None;
        }
        let svd = self.profile.svd(true, true);
        let (u, v_t) = (svd.u?, svd.v_t?);
        let sign = if (u * v_t).determinant() < T::zero() {
            -T::one()
        } else {
            T::one()
        };
        let d = Matrix3::from_diagonal(&Vector3::new(T::one(), T::one(), sign));
        Some(u * d * v_t)
    }

    /// Residual variance per axis and pair of the fit with the rotation `c`: sum |w_k -
    /// C w_0|^2 / (3 n), from the sums alone (|C w_0| = |w_0| for a rotation).
    pub fn residual_variance(&self, c: &Matrix3<T>) -> T {
        let n = self.pairs.max(T::one());
        let cross = (c.transpose() * self.profile).trace();
        let three = T::one() + T::one() + T::one();
        ((self.squares - (cross + cross)) / (three * n)).max(T::zero())
    }

    /// 1-sigma (rad) of the rotation `c` about the direction the motion turned least:
    /// sqrt(s^2 / L2), s^2 the [`Self::residual_variance`] and L2 the second-largest
    /// eigenvalue of the first unit's scatter less the noise's share (about n s^2 / 2 on
    /// every axis, the residual being both units' noise); None where the motion turns about
    /// fewer than two axes (nothing determines the rotation about the other).
    pub fn sigma_rad(&self, c: &Matrix3<T>) -> Option<T> {
        let s2 = self.residual_variance(c);
        let mut eig = self.scatter.symmetric_eigenvalues();
        super::sort_few(eig.as_mut_slice(), |a, b| a < b);
        let n = self.pairs;
        let two = T::one() + T::one();
        let motion = eig[1] - n * s2 / two;
        (motion > T::zero()).then(|| (s2 / motion).sqrt())
    }
}

/// The lever-arm matrix of eq. (9): W_dot + W^2, W the cross-product matrix of the angular
/// rate `w` (rad/s) and W_dot of its rate of change `w_dot` (rad/s^2).
pub fn lever_matrix<T: RealField + Copy>(w: &Vector3<T>, w_dot: &Vector3<T>) -> Matrix3<T> {
    let o = w.cross_matrix();
    w_dot.cross_matrix() + o * o
}

/// Normal equations of eq. (9) with a bias per axis: unknowns the lever arm r (m, the first
/// unit's axes) then the bias (m/s^2).
#[derive(Debug, Clone, Copy)]
pub struct LeverArmNormal<T: RealField + Copy> {
    matrix: Matrix6<T>,
    rhs: Vector6<T>,
    samples: T,
}

impl<T: RealField + Copy> Default for LeverArmNormal<T> {
    fn default() -> Self {
        Self {
            matrix: Matrix6::zeros(),
            rhs: Vector6::zeros(),
            samples: T::zero(),
        }
    }
}

impl<T: RealField + Copy> LeverArmNormal<T> {
    /// Adds one sample: the angular rate `w` and its rate of change `w_dot`, and the
    /// specific-force difference `difference` = f_k - f_0 in the first unit's axes.
    pub fn push(&mut self, w: &Vector3<T>, w_dot: &Vector3<T>, difference: &Vector3<T>) {
        let m = lever_matrix(w, w_dot);
        for a in 0..3 {
            let mut row = Vector6::zeros();
            for c in 0..3 {
                row[c] = m[(a, c)];
            }
            row[3 + a] = T::one();
            self.matrix += row * row.transpose();
            self.rhs += row * difference[a];
        }
        self.samples += T::one();
    }

    /// Samples added.
    pub fn samples(&self) -> T {
        self.samples
    }

    /// Both sets of samples.
    pub fn plus(&self, other: &Self) -> Self {
        Self {
            matrix: self.matrix + other.matrix,
            rhs: self.rhs + other.rhs,
            samples: self.samples + other.samples,
        }
    }

    /// These samples without `other`'s (a part of them).
    pub fn less(&self, other: &Self) -> Self {
        Self {
            matrix: self.matrix - other.matrix,
            rhs: self.rhs - other.rhs,
            samples: self.samples - other.samples,
        }
    }

    /// The diagonal the noise in the measured angular acceleration adds per sample, for
    /// its variance per axis `noise_variance` ((rad/s^2)^2): E[[e]x^T [e]x] = diag(Vy + Vz,
    /// Vx + Vz, Vx + Vy).
    fn noise_diagonal(noise_variance: &[T; 3]) -> [T; 3] {
        let [vx, vy, vz] = *noise_variance;
        [vy + vz, vx + vz, vx + vy]
    }

    /// Whether correcting for the angular acceleration's noise leaves at least half of
    /// every lever-arm component's information. Where it does not (units whose gyros
    /// disagree far beyond white noise, as on a flexible copter frame), the correction rests
    /// on a small difference of large numbers, and the uncorrected least squares is better
    /// kept: it shrinks the lever arm, it never enlarges it.
    pub fn correctable(&self, noise_variance: &[T; 3]) -> bool {
        let half = T::one() / (T::one() + T::one());
        Self::noise_diagonal(noise_variance)
            .iter()
            .enumerate()
            .all(|(i, v)| self.samples * *v <= half * self.matrix[(i, i)])
    }

    /// Sum of the squared residuals of the solution `x` (r, then the bias) over the samples
    /// added, from the sums alone: |y|^2 - 2 x^T rhs + x^T A x, `differences_squared` being
    /// the sum of |f_k - f_0|^2 over the same samples (a long record is not read again).
    pub fn residual_sum_of_squares(&self, x: &Vector6<T>, differences_squared: T) -> T {
        let two = T::one() + T::one();
        differences_squared - two * x.dot(&self.rhs) + (x.transpose() * self.matrix * x)[(0, 0)]
    }

    /// The solution (r, then the bias) and the corrected normal matrix's inverse; None
    /// where the motion leaves the lever arm undetermined. The correction is for errors in
    /// the variables: the noise in the measured W_dot adds [`Self::noise_diagonal`] per
    /// sample to the normal matrix, which would shrink the lever arm toward zero.
    pub fn solve(&self, noise_variance: &[T; 3]) -> Option<(Vector6<T>, Matrix6<T>)> {
        let mut matrix = self.matrix;
        for (i, v) in Self::noise_diagonal(noise_variance).iter().enumerate() {
            matrix[(i, i)] -= self.samples * *v;
        }
        let inverse = matrix.try_inverse()?;
        (0..3)
            .all(|i| inverse[(i, i)] > T::zero())
            .then(|| (inverse * self.rhs, inverse))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// The residuals' sum of squares from the sums equals the one summed sample by sample
    /// (a long record's lever-arm sigma is found without reading it again).
    #[test]
    fn the_residual_sum_of_squares_from_the_sums_is_the_summed_one() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let d = Normal::new(0.0f64, 1.0).unwrap();
        let mut normal = LeverArmNormal::<f64>::default();
        let mut rows = Vec::new();
        let mut squares = 0.0;
        for _ in 0..500 {
            let v = |rng: &mut rand_chacha::ChaCha8Rng| {
                Vector3::new(d.sample(rng), d.sample(rng), d.sample(rng))
            };
            let (w, w_dot, y) = (v(&mut rng), v(&mut rng), v(&mut rng) * 0.1);
            normal.push(&w, &w_dot, &y);
            squares += y.norm_squared();
            rows.push((lever_matrix(&w, &w_dot), y));
        }
        let (x, _) = normal.solve(&[0.0; 3]).unwrap();
        let r = Vector3::new(x[0], x[1], x[2]);
        let bias = Vector3::new(x[3], x[4], x[5]);
        let summed: f64 = rows
            .iter()
            .map(|(m, y)| (y - m * r - bias).norm_squared())
            .sum();
        let from_sums = normal.residual_sum_of_squares(&x, squares);
        assert!(
            (from_sums / summed - 1.0).abs() < 1e-10,
            "{from_sums} vs {summed}"
        );
    }

    /// Rates turning about all three axes, seen by a second unit rotated by (0.5, -0.4,
    /// 0.6) deg with 2 mrad/s of noise on each: the rotation is recovered within 3 of its
    /// sigma, in f32 as on the board; a motion about one axis determines none.
    #[test]
    fn the_rotation_between_two_units_is_recovered_with_its_sigma() {
        let truth = nalgebra::Rotation3::from_euler_angles(
            0.5f32.to_radians(),
            -0.4f32.to_radians(),
            0.6f32.to_radians(),
        );
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let noise = Normal::new(0.0f32, 2e-3).unwrap();
        let motion = Normal::new(0.0f32, 0.3).unwrap();
        let mut turning = RotationAccumulator::<f32>::default();
        let mut one_axis = RotationAccumulator::<f32>::default();
        for _ in 0..5000 {
            let w = Vector3::new(
                motion.sample(&mut rng),
                motion.sample(&mut rng),
                motion.sample(&mut rng),
            );
            let e = |rng: &mut rand_chacha::ChaCha8Rng| {
                Vector3::new(noise.sample(rng), noise.sample(rng), noise.sample(rng))
            };
            let (e0, ek) = (e(&mut rng), e(&mut rng));
            turning.push(&(w + e0), &(truth * w + ek));
            let yaw = Vector3::new(0.0, 0.0, w.z);
            one_axis.push(&(yaw + e0), &(truth * yaw + ek));
        }
        let c = turning.rotation().unwrap();
        // The angle between them from the skew part of C T^T (acos of the trace loses it
        // in f32 near zero).
        let d = c * truth.inverse().matrix();
        let off = Vector3::new(
            d[(2, 1)] - d[(1, 2)],
            d[(0, 2)] - d[(2, 0)],
            d[(1, 0)] - d[(0, 1)],
        )
        .norm()
            / 2.0;
        let sigma = turning.sigma_rad(&c).unwrap();
        assert!(off < 3.0 * sigma && sigma < 1e-3, "{off} vs {sigma}");
        let c1 = one_axis.rotation().unwrap();
        assert_eq!(one_axis.sigma_rad(&c1), None);
    }

    /// Specific-force differences of a unit 5 cm away on a platform turning and shaking,
    /// with 10 mm/s^2 of noise and a bias: the lever arm within 0.5 mm.
    #[test]
    fn the_lever_arm_is_recovered_from_the_specific_force_differences() {
        let r = Vector3::new(0.05f64, 0.03, -0.02);
        let bias = Vector3::new(0.02, -0.01, 0.03);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        let noise = Normal::new(0.0, 0.01).unwrap();
        let mut normal = LeverArmNormal::<f64>::default();
        for i in 0..20_000 {
            let t = f64::from(i) * 0.01;
            let w = Vector3::new(
                0.3 * (0.7 * t).sin(),
                0.2 * (1.1 * t).cos(),
                0.4 * (0.3 * t).sin(),
            );
            let w_dot = Vector3::new(
                0.21 * (0.7 * t).cos(),
                -0.22 * (1.1 * t).sin(),
                0.12 * (0.3 * t).cos(),
            ) + Vector3::new(
                2.0 * (60.0 * t).sin(),
                1.5 * (80.0 * t).cos(),
                1.0 * (70.0 * t).sin(),
            );
            let e = Vector3::new(
                noise.sample(&mut rng),
                noise.sample(&mut rng),
                noise.sample(&mut rng),
            );
            normal.push(&w, &w_dot, &(lever_matrix(&w, &w_dot) * r + bias + e));
        }
        let (x, _) = normal.solve(&[0.0; 3]).unwrap();
        for a in 0..3 {
            assert!((x[a] - r[a]).abs() < 5e-4, "{x}");
            assert!((x[3 + a] - bias[a]).abs() < 2e-3, "{x}");
        }
        assert!(normal.correctable(&[1e-4; 3]));
        assert!(!normal.correctable(&[1e3; 3]));
    }
}
