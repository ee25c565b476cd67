//! Covariance prediction: the linearised INS error model (paper eqs. 3–6, in NED metres and
//! the `C_b^n = (I + [ε×]) Ĉ_b^n` attitude-error convention), discretised to first order,
//! and propagated block-sparsely.
//!
//! The transition matrix is `Φ = blockdiag(Φ_nav, I)`: only the 15-state navigation block is
//! dynamic and the calibration states are constant (eq. 6). Of `Φ_nav`'s 25 blocks of 3×3
//! only 11 are non-zero and six of those are diagonal, so the prediction multiplies blocks
//! instead of forming a dense `N×N` `Φ P Φᵀ` (3–10× fewer operations on the Cortex-M4F, see
//! BENCHMARKS.md).
//!
//! Neglected, as in most car-grade INS filters: the position-rate terms of order `|v|/R`
//! (below 5·10⁻⁶ /s at road speeds) and the dependence of the Earth rate on latitude error.
//! Kept: Schuler and vertical-channel gravity gradients, Coriolis and transport rate, the
//! transport-rate dependence on velocity error, and Gauss–Markov biases.

// Block indices address Φ, P and δx together; iterator chains would hide that.
#![allow(clippy::needless_range_loop)]

use super::{boresight_index, skew, ErrorStateEkf, ACCEL_BIAS, ATT, GYRO_BIAS, NAV_STATES, VEL};
use crate::nav::earth::Latitude;
use nalgebra::{Matrix3, SMatrix, Vector3};

use crate::scalar::{FilterScalar, Pow2};

/// The nominal quantities the error model is linearised about, for one prediction step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NavLinearization<T> {
    /// Nominal attitude `Ĉ_b^n` (body to NED).
    pub c_b_n: Matrix3<T>,
    /// Bias-corrected specific force over the step, m/s², body axes (`Δv / Δt`).
    pub f_b_m_s2: Vector3<T>,
    /// Nominal velocity, m/s, NED.
    pub v_ned_m_s: Vector3<T>,
    /// Earth rate in the navigation frame, rad/s, NED.
    pub omega_ie_n_rad_s: Vector3<T>,
    /// Transport rate in the navigation frame, rad/s, NED.
    pub omega_en_n_rad_s: Vector3<T>,
    /// Normal gravity magnitude at the nominal position, m/s².
    pub gravity_m_s2: T,
    /// Meridian radius of curvature plus height, `R_N + h`, m.
    pub meridian_radius_plus_h_m: T,
    /// Transverse radius of curvature plus height, `R_E + h`, m.
    pub transverse_radius_plus_h_m: T,
    /// Tangent of the nominal geodetic latitude.
    pub tan_lat: T,
}

impl<T: FilterScalar> NavLinearization<T> {
    /// Builds the linearisation point from a geodetic nominal state: latitude `lat_rad`,
    /// height `h_m` (WGS84), NED velocity, attitude `c_b_n` and bias-corrected specific force
    /// `f_b_m_s2`, with the WGS84 model of [`crate::nav::earth`].
    pub fn from_geodetic(
        lat_rad: T,
        h_m: T,
        v_ned_m_s: Vector3<T>,
        c_b_n: Matrix3<T>,
        f_b_m_s2: Vector3<T>,
    ) -> Self {
        Self::at_latitude(&Latitude::new(lat_rad), h_m, v_ned_m_s, c_b_n, f_b_m_s2)
    }

    /// As [`Self::from_geodetic`], with the latitude's terms already computed (the
    /// mechanization keeps them: see [`crate::nav::strapdown::Strapdown::latitude`]).
    pub fn at_latitude(
        latitude: &Latitude<T>,
        h_m: T,
        v_ned_m_s: Vector3<T>,
        c_b_n: Matrix3<T>,
        f_b_m_s2: Vector3<T>,
    ) -> Self {
        let r = latitude.radii;
        Self {
            c_b_n,
            f_b_m_s2,
            v_ned_m_s,
            omega_ie_n_rad_s: latitude.earth_rate_ned_rad_s(),
            omega_en_n_rad_s: latitude.transport_rate_ned_rad_s(h_m, &v_ned_m_s),
            gravity_m_s2: latitude.normal_gravity_m_s2(h_m),
            meridian_radius_plus_h_m: r.meridian_m + h_m,
            transverse_radius_plus_h_m: r.transverse_m + h_m,
            tan_lat: latitude.sin / latitude.cos,
        }
    }

    fn is_finite(&self) -> bool {
        self.c_b_n.iter().all(|x| x.is_finite())
            && self.f_b_m_s2.iter().all(|x| x.is_finite())
            && self.v_ned_m_s.iter().all(|x| x.is_finite())
            && self.omega_ie_n_rad_s.iter().all(|x| x.is_finite())
            && self.omega_en_n_rad_s.iter().all(|x| x.is_finite())
            && self.gravity_m_s2.is_finite()
            && self.meridian_radius_plus_h_m.is_finite()
            && self.meridian_radius_plus_h_m > T::zero()
            && self.transverse_radius_plus_h_m.is_finite()
            && self.transverse_radius_plus_h_m > T::zero()
            && self.tan_lat.is_finite()
    }
}

/// How the filter's IMU error depends on the extra units' calibration errors when that IMU
/// is the weighted mean of the units, each turned into the body frame by its *estimated*
/// calibration (the board's fusion), rather than an IMU of its own (the paper's setting,
/// where the calibrations do not touch the navigation). A boresight error `δψ_k` of a unit
/// with weight `w_k` puts `w_k [ω×] Ĉ_kᵀ δψ_k` into the fused rate and `w_k [f×] Ĉ_kᵀ δψ_k`
/// into the fused specific force, and a lever-arm error `δr_k` (the centripetal term moved
/// with the estimated arm) `w_k Ω Ω δr_k`: errors that act as the bias errors do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationCoupling<T, const K: usize> {
    /// Bias-corrected angular rate over the step, rad/s, body axes.
    pub omega_b_rad_s: Vector3<T>,
    /// Each extra unit's weight in the fused angular rate (the weights sum to 1 with the
    /// body unit's).
    pub gyro_share: [T; K],
    /// Each extra unit's weight in the fused specific force.
    pub accel_share: [T; K],
}

/// One block of the transition's navigation-from-calibration part: its first row counted
/// from [`VEL`] (0: velocity, 3: attitude), its first column (a calibration state), the
/// block.
type CouplingBlock<T> = (usize, usize, Matrix3<T>);

/// One 3×3 block of the transition matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Block3<T: FilterScalar> {
    Zero,
    Diag(Vector3<T>),
    Full(Matrix3<T>),
}

impl<T: FilterScalar> Block3<T> {
    /// `self · x`.
    fn left_mul(&self, x: &Matrix3<T>) -> Option<Matrix3<T>> {
        match self {
            Block3::Zero => None,
            Block3::Diag(d) => {
                let mut y = *x;
                for r in 0..3 {
                    for c in 0..3 {
                        y[(r, c)] *= d[r];
                    }
                }
                Some(y)
            }
            // nalgebra's product for floats (vectorised on the M4F); written out in fixed point.
            Block3::Full(m) if T::SCALED => Some(product_3x3(m, x, false)),
            Block3::Full(m) => Some(m * x),
        }
    }

    /// `x · selfᵀ`.
    fn right_mul_transpose(&self, x: &Matrix3<T>) -> Option<Matrix3<T>> {
        match self {
            Block3::Zero => None,
            Block3::Diag(d) => {
                let mut y = *x;
                for r in 0..3 {
                    for c in 0..3 {
                        y[(r, c)] *= d[c];
                    }
                }
                Some(y)
            }
            Block3::Full(m) if T::SCALED => Some(product_3x3(x, m, true)),
            Block3::Full(m) => Some(x * m.transpose()),
        }
    }

    /// The block of the scaled transition `Φ_ij 2^(s_j − s_i)` for row states with scales
    /// `rows` and column states with scales `cols` (a diagonal block stays diagonal).
    fn scaled(&self, rows: &[i32], cols: &[i32]) -> Self
    where
        T: FilterScalar,
    {
        match self {
            Block3::Zero => Block3::Zero,
            Block3::Diag(d) => {
                Block3::Diag(Vector3::from_fn(|r, _| d[r].mul_pow2(cols[r] - rows[r])))
            }
            Block3::Full(m) => Block3::Full(Matrix3::from_fn(|r, c| {
                m[(r, c)].mul_pow2(cols[c] - rows[r])
            })),
        }
    }

    /// `self · v` for a 3-vector.
    fn mul_vector(&self, v: &Vector3<T>) -> Vector3<T> {
        match self {
            Block3::Zero => Vector3::zeros(),
            Block3::Diag(d) => d.component_mul(v),
            Block3::Full(m) if T::SCALED => {
                Vector3::from_fn(|r, _| m[(r, 0)] * v[0] + m[(r, 1)] * v[1] + m[(r, 2)] * v[2])
            }
            Block3::Full(m) => m * v,
        }
    }
}

/// `a b` (or `a bᵀ` when `transpose_b`) written out, for fixed point: nalgebra's general
/// product scales each term by its `alpha` and `beta`, a multiplication by one that costs a
/// fixed-point filter on a core without an FPU a third of its prediction.
#[inline(always)]
fn product_3x3<T: FilterScalar>(a: &Matrix3<T>, b: &Matrix3<T>, transpose_b: bool) -> Matrix3<T> {
    let b_at = |k: usize, c: usize| if transpose_b { b[(c, k)] } else { b[(k, c)] };
    Matrix3::from_fn(|r, c| {
        a[(r, 0)] * b_at(0, c) + a[(r, 1)] * b_at(1, c) + a[(r, 2)] * b_at(2, c)
    })
}

/// A Gauss-Markov bias (inverse correlation time `inv_tau_s`, 1/s; driving PSD `psd`,
/// unit²/s) over `dt` seconds, discretised exactly: its decay `exp(-dt/tau)` and the
/// variance it gains, `psd tau (1 - exp(-2 dt/tau)) / 2` (`psd dt` for a random walk,
/// `inv_tau_s = 0`). The first-order `1 - dt/tau` turns unstable past `dt = 2 tau`: a bias
/// model fitted with a correlation time of a millisecond, predicted every 10 ms, made the
/// board's covariance explode within a second.
pub fn gauss_markov_step<T: FilterScalar>(inv_tau_s: T, psd: T, dt: T) -> (T, T) {
    let x = inv_tau_s * dt;
    if x <= nalgebra::convert(1e-4) {
        // exp's series: the exact form loses its digits to the subtraction here.
        return (T::one() - x, psd * dt * (T::one() - x));
    }
    let decay = (-x).exp();
    (
        decay,
        psd * (T::one() - decay * decay) / (inv_tau_s + inv_tau_s),
    )
}

/// `Φ_nav` as 5×5 blocks (position, velocity, attitude, accel bias, gyro bias).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BlockTransition<T: FilterScalar> {
    pub blocks: [[Block3<T>; 5]; 5],
}

impl<T: FilterScalar> BlockTransition<T> {
    pub fn identity() -> Self {
        let mut blocks = [[Block3::Zero; 5]; 5];
        for (i, row) in blocks.iter_mut().enumerate() {
            row[i] = Block3::Diag(Vector3::repeat(T::one()));
        }
        Self { blocks }
    }

    /// `Φ_nav = I + F dt` for the error model in the module documentation.
    fn first_order(lin: &NavLinearization<T>, config: &super::EkfConfig<T>, dt: T) -> Self {
        let one = T::one();
        let two: T = nalgebra::convert(2.0);
        let identity = Matrix3::<T>::identity();
        // Schuler (horizontal) and vertical-channel gravity gradients about a mean radius:
        // the geometric mean, or in fixed point, where the radii's product (4e13 m²) is out
        // of range and a square root costs a long integer loop, the arithmetic mean (9 m
        // longer: the gradient differs by 1.4e-6 of itself).
        let (north, east) = (lin.meridian_radius_plus_h_m, lin.transverse_radius_plus_h_m);
        let radius = if T::SCALED {
            (north + east) * nalgebra::convert::<f64, T>(0.5)
        } else {
            (north * east).sqrt()
        };
        let g_over_r = lin.gravity_m_s2 / radius;
        // ∂ω_en/∂v: transport rate dependence on velocity error.
        let mut d_omega_en_dv = Matrix3::<T>::zeros();
        d_omega_en_dv[(0, 1)] = one / lin.transverse_radius_plus_h_m;
        d_omega_en_dv[(1, 0)] = -one / lin.meridian_radius_plus_h_m;
        d_omega_en_dv[(2, 1)] = -lin.tan_lat / lin.transverse_radius_plus_h_m;
        let f_n = lin.c_b_n * lin.f_b_m_s2;
        let omega_in = lin.omega_ie_n_rad_s + lin.omega_en_n_rad_s;
        let coriolis = lin.omega_ie_n_rad_s * two + lin.omega_en_n_rad_s;

        let f_vv = -skew(&coriolis) + skew(&lin.v_ned_m_s) * d_omega_en_dv;
        let mut blocks = [[Block3::Zero; 5]; 5];
        blocks[0][0] = Block3::Diag(Vector3::repeat(one));
        blocks[0][1] = Block3::Diag(Vector3::repeat(dt));
        blocks[1][0] = Block3::Diag(Vector3::new(-g_over_r, -g_over_r, two * g_over_r) * dt);
        blocks[1][1] = Block3::Full(identity + f_vv * dt);
        blocks[1][2] = Block3::Full(-skew(&f_n) * dt);
        blocks[1][3] = Block3::Full(-lin.c_b_n * dt);
        blocks[2][1] = Block3::Full(-d_omega_en_dv * dt);
        blocks[2][2] = Block3::Full(identity - skew(&omega_in) * dt);
        blocks[2][4] = Block3::Full(-lin.c_b_n * dt);
        let (accel_decay, _) = gauss_markov_step(config.accel_bias_inv_tau_s, T::zero(), dt);
        let (gyro_decay, _) = gauss_markov_step(config.gyro_bias_inv_tau_s, T::zero(), dt);
        blocks[3][3] = Block3::Diag(Vector3::repeat(accel_decay));
        blocks[4][4] = Block3::Diag(Vector3::repeat(gyro_decay));
        Self { blocks }
    }

    /// The transition of the scaled states `x_i 2^(−s_i)`: `Φ_ij 2^(s_j − s_i)`, for the
    /// navigation states' scales `nav_scale`.
    fn scaled(&self, nav_scale: &[i32]) -> Self
    where
        T: FilterScalar,
    {
        let mut blocks = self.blocks;
        for (bi, row) in blocks.iter_mut().enumerate() {
            for (bj, block) in row.iter_mut().enumerate() {
                *block = block.scaled(
                    &nav_scale[3 * bi..3 * bi + 3],
                    &nav_scale[3 * bj..3 * bj + 3],
                );
            }
        }
        Self { blocks }
    }

    /// The dense 15×15 matrix (for the host smoother).
    pub fn to_dense(self) -> SMatrix<T, NAV_STATES, NAV_STATES> {
        let mut dense = SMatrix::<T, NAV_STATES, NAV_STATES>::zeros();
        for (bi, row) in self.blocks.iter().enumerate() {
            for (bj, block) in row.iter().enumerate() {
                if let Some(b) = block.left_mul(&Matrix3::identity()) {
                    dense.fixed_view_mut::<3, 3>(3 * bi, 3 * bj).copy_from(&b);
                }
            }
        }
        dense
    }
}

fn block<T: FilterScalar, const N: usize>(
    p: &SMatrix<T, N, N>,
    bi: usize,
    bj: usize,
) -> Matrix3<T> {
    p.fixed_view::<3, 3>(3 * bi, 3 * bj).into_owned()
}

impl<T: FilterScalar, const K: usize, const N: usize> ErrorStateEkf<T, K, N> {
    /// Propagates the error state and its covariance over `dt_s` seconds about the nominal
    /// trajectory `lin`. Returns `false` (and counts it) if `dt_s` is not positive and finite
    /// or `lin` holds a non-finite value; the filter is then unchanged.
    pub fn predict(&mut self, lin: &NavLinearization<T>, dt_s: T) -> bool {
        self.predict_coupled(lin, None, dt_s)
    }

    /// [`Self::predict`] for a filter whose IMU is the units' fused output turned by the
    /// estimated calibrations: with `coupling`, the transition also carries the calibration
    /// errors into the velocity and attitude errors ([`CalibrationCoupling`]).
    pub fn predict_coupled(
        &mut self,
        lin: &NavLinearization<T>,
        coupling: Option<&CalibrationCoupling<T, K>>,
        dt_s: T,
    ) -> bool {
        if !(dt_s.is_finite() && dt_s > T::zero() && lin.is_finite()) {
            self.stats.rejected_predictions = self.stats.rejected_predictions.saturating_add(1);
            return false;
        }
        let overflows_before = T::overflows();
        let phi = BlockTransition::first_order(lin, &self.config, dt_s);
        // The covariance is propagated in the scaled states (floats have no scales).
        let scaled_phi;
        let blocks = if T::SCALED {
            scaled_phi = phi.scaled(&self.scale[..NAV_STATES]);
            &scaled_phi.blocks
        } else {
            &phi.blocks
        };

        // M = Φ_nav P_nav,nav (block-sparse on the left).
        let mut m = SMatrix::<T, NAV_STATES, NAV_STATES>::zeros();
        for bi in 0..5 {
            for bj in 0..5 {
                let mut acc = Matrix3::<T>::zeros();
                for (bl, phi_block) in blocks[bi].iter().enumerate() {
                    if let Some(prod) = phi_block.left_mul(&block(&self.p, bl, bj)) {
                        acc += prod;
                    }
                }
                m.fixed_view_mut::<3, 3>(3 * bi, 3 * bj).copy_from(&acc);
            }
        }
        // P_nav,nav ← M Φ_navᵀ on the upper block triangle, mirrored.
        let half: T = nalgebra::convert(0.5);
        for bi in 0..5 {
            for bj in bi..5 {
                let mut acc = Matrix3::<T>::zeros();
                for (bl, phi_block) in blocks[bj].iter().enumerate() {
                    if let Some(prod) = phi_block.right_mul_transpose(&block(&m, bi, bl)) {
                        acc += prod;
                    }
                }
                if bi == bj {
                    acc = (acc + acc.transpose()) * half;
                }
                self.p
                    .fixed_view_mut::<3, 3>(3 * bi, 3 * bj)
                    .copy_from(&acc);
                self.p
                    .fixed_view_mut::<3, 3>(3 * bj, 3 * bi)
                    .copy_from(&acc.transpose());
            }
        }
        // Navigation–calibration cross-covariance: P_nav,cal ← Φ_nav P_nav,cal.
        for col in NAV_STATES..N {
            let mut column = [Vector3::<T>::zeros(); 5];
            for (bl, slot) in column.iter_mut().enumerate() {
                *slot = Vector3::new(
                    self.p[(3 * bl, col)],
                    self.p[(3 * bl + 1, col)],
                    self.p[(3 * bl + 2, col)],
                );
            }
            for bi in 0..5 {
                let mut acc = Vector3::<T>::zeros();
                for (bl, phi_block) in blocks[bi].iter().enumerate() {
                    acc += phi_block.mul_vector(&column[bl]);
                }
                for axis in 0..3 {
                    self.p[(3 * bi + axis, col)] = acc[axis];
                    self.p[(col, 3 * bi + axis)] = acc[axis];
                }
            }
        }
        let coupling_blocks = coupling.map(|c| self.coupling_blocks(lin, c, dt_s));
        if let Some(blocks) = &coupling_blocks {
            self.shear_by_calibrations(blocks.as_flattened());
        }
        self.add_process_noise(dt_s);

        // Error mean: δx_nav ← Φ_nav δx_nav (zero right after a reset).
        let mut nav = [Vector3::<T>::zeros(); 5];
        for (bl, slot) in nav.iter_mut().enumerate() {
            *slot = Vector3::new(self.dx[3 * bl], self.dx[3 * bl + 1], self.dx[3 * bl + 2]);
        }
        for bi in 0..5 {
            let mut acc = Vector3::<T>::zeros();
            for (bl, phi_block) in phi.blocks[bi].iter().enumerate() {
                acc += phi_block.mul_vector(&nav[bl]);
            }
            for axis in 0..3 {
                self.dx[3 * bi + axis] = acc[axis];
            }
        }
        // δx_nav += B δx_cal (the mean is held physical).
        for &(row, col, b) in coupling_blocks.iter().flatten().flatten() {
            let moved = b * Vector3::new(self.dx[col], self.dx[col + 1], self.dx[col + 2]);
            for r in 0..3 {
                self.dx[VEL + row + r] += moved[r];
            }
        }
        self.transition = phi;
        #[cfg(feature = "probe")]
        {
            self.probe_coupling = SMatrix::zeros();
            for &(row, col, b) in coupling_blocks.iter().flatten().flatten() {
                for (r, c) in (0..3).flat_map(|r| (0..3).map(move |c| (r, c))) {
                    self.probe_coupling[(row + r, col + c)] =
                        nalgebra::try_convert::<T, f64>(b[(r, c)]).unwrap_or(f64::NAN);
                }
            }
        }
        if T::overflows() != overflows_before {
            // A saturated number went into the covariance: start it over, as a non-finite
            // variance makes the floors do.
            self.stats.covariance_resets = self.stats.covariance_resets.saturating_add(1);
            self.reset_covariance();
            return true;
        }
        self.apply_variance_floors();
        #[cfg(feature = "probe")]
        {
            self.probe = (self.probe.0 + 1, self.covariance_f64());
        }
        true
    }

    /// The blocks of the transition that carry the calibration errors into the velocity and
    /// attitude errors over `dt`, physical units: `−Ĉ_b^n dt` (the bias columns' block)
    /// times each unit's share of its errors. Each is (first row from [`VEL`], first
    /// column, block).
    #[inline(never)]
    fn coupling_blocks(
        &self,
        lin: &NavLinearization<T>,
        coupling: &CalibrationCoupling<T, K>,
        dt: T,
    ) -> [[CouplingBlock<T>; 3]; K] {
        let to_nav = -lin.c_b_n * dt;
        let omega_skew = skew(&coupling.omega_b_rad_s);
        let rate_to_nav = to_nav * omega_skew;
        let force_to_nav = to_nav * skew(&lin.f_b_m_s2);
        let centripetal_to_nav = rate_to_nav * omega_skew;
        let mut blocks = [[(0, 0, Matrix3::zeros()); 3]; K];
        for (k, unit) in blocks.iter_mut().enumerate() {
            let shares = (coupling.accel_share[k], coupling.gyro_share[k]);
            *unit = self.unit_coupling(
                k,
                shares,
                [&force_to_nav, &centripetal_to_nav, &rate_to_nav],
            );
        }
        blocks
    }

    /// Extra unit `k`'s three coupling blocks from the shared factors `[−Ĉ_b^n dt [f×],
    /// −Ĉ_b^n dt Ω Ω, −Ĉ_b^n dt [ω×]]` and its (accelerometer, gyro) shares; out of line, so
    /// the board carries it once.
    #[inline(never)]
    fn unit_coupling(
        &self,
        k: usize,
        (accel, gyro): (T, T),
        [force_to_nav, centripetal_to_nav, rate_to_nav]: [&Matrix3<T>; 3],
    ) -> [CouplingBlock<T>; 3] {
        let c_s_b = self.calibration[k].c_b_s().transpose();
        let (psi, arm) = (boresight_index(k), boresight_index(k) + 3);
        [
            (0, psi, force_to_nav * c_s_b * accel),
            (0, arm, centripetal_to_nav * accel),
            (3, psi, rate_to_nav * c_s_b * gyro),
        ]
    }

    /// `P ← S P Sᵀ` for the shear `S = [[I, B], [0, I]]`, `B` the calibration columns of the
    /// velocity and attitude rows (`blocks`, physical): with the navigation part of the
    /// transition applied before, the whole `Φ = S · diag(Φ_nav, I)`. Only the velocity and
    /// attitude rows and columns change. Kept out of line and over a slice: the board's
    /// flash has no room for these loops unrolled.
    #[inline(never)]
    fn shear_by_calibrations(&mut self, blocks: &[CouplingBlock<T>]) {
        // X = B P (6 × N), B as the covariance is held (scaled in fixed point).
        let mut x = SMatrix::<T, 6, N>::zeros();
        for block in blocks {
            let (row, col, b) = self.held_block(block);
            for j in 0..N {
                for r in 0..3 {
                    let mut acc = x[(row + r, j)];
                    for c in 0..3 {
                        acc += b[(r, c)] * self.p[(col + c, j)];
                    }
                    x[(row + r, j)] = acc;
                }
            }
        }
        // B P Bᵀ = X Bᵀ (6 × 6), before P changes.
        let mut corner = SMatrix::<T, 6, 6>::zeros();
        for block in blocks {
            let (row, col, b) = self.held_block(block);
            for i in 0..6 {
                for r in 0..3 {
                    let mut acc = corner[(i, row + r)];
                    for c in 0..3 {
                        acc += x[(i, col + c)] * b[(r, c)];
                    }
                    corner[(i, row + r)] = acc;
                }
            }
        }
        // P += E X + Xᵀ Eᵀ + E (X Bᵀ) Eᵀ, E placing six rows at the velocity's.
        let half: T = nalgebra::convert(0.5);
        for r in 0..6 {
            for j in 0..N {
                let inner = (VEL..VEL + 6).contains(&j);
                let corner_part = if inner {
                    (corner[(r, j - VEL)] + corner[(j - VEL, r)]) * half + x[(j - VEL, VEL + r)]
                } else {
                    self.p[(j, VEL + r)] += x[(r, j)];
                    T::zero()
                };
                self.p[(VEL + r, j)] += x[(r, j)] + corner_part;
            }
        }
    }

    /// A coupling block as the covariance is held: `B_ij 2^(s_j − s_i)` in fixed point.
    fn held_block(&self, &(row, col, block): &CouplingBlock<T>) -> CouplingBlock<T> {
        if !T::SCALED {
            return (row, col, block);
        }
        let scaled = Matrix3::from_fn(|r, c| {
            block[(r, c)].mul_pow2(self.scale[col + c] - self.scale[VEL + row + r])
        });
        (row, col, scaled)
    }

    /// `Q_d ≈ G Q Gᵀ dt`: white accelerometer and gyro noise (isotropic, so rotating it into
    /// NED leaves it diagonal), bias and calibration driving noise on the diagonal. Each
    /// density is brought to its state's scale before it meets `dt`, so a fixed-point
    /// product never holds a number as small as the physical `psd dt`.
    fn add_process_noise(&mut self, dt: T) {
        let cfg = self.config;
        // The bias variance gained per unit of driving density.
        let (_, accel_bias_per_psd) = gauss_markov_step(cfg.accel_bias_inv_tau_s, T::one(), dt);
        let (_, gyro_bias_per_psd) = gauss_markov_step(cfg.gyro_bias_inv_tau_s, T::one(), dt);
        let mut add = |i: usize, psd: Pow2<T>, per_psd: T| {
            let density = if T::SCALED {
                psd.times_pow2(-2 * self.scale[i])
            } else {
                psd.mantissa
            };
            self.p[(i, i)] += density * per_psd;
        };
        for axis in 0..3 {
            add(VEL + axis, cfg.accel_noise_psd, dt);
            add(ATT + axis, cfg.gyro_noise_psd, dt);
            add(ACCEL_BIAS + axis, cfg.accel_bias_psd, accel_bias_per_psd);
            add(GYRO_BIAS + axis, cfg.gyro_bias_psd, gyro_bias_per_psd);
        }
        for imu in 0..K {
            for axis in 0..6 {
                let psd = if axis < 3 {
                    cfg.boresight_psd
                } else {
                    cfg.lever_arm_psd
                };
                add(boresight_index(imu) + axis, psd, dt);
            }
        }
    }

    /// The calibration columns of the last prediction's transition, rows from the velocity
    /// error on (six; zero without a [`CalibrationCoupling`]), physical units, f64.
    #[cfg(feature = "probe")]
    pub fn last_transition_coupling(&self) -> &SMatrix<f64, 6, N> {
        &self.probe_coupling
    }

    /// The navigation block of the last prediction's transition matrix `Φ_nav` (dense
    /// 15×15; the calibration block is the identity). Identity before the first prediction.
    pub fn last_transition_nav(&self) -> SMatrix<T, NAV_STATES, NAV_STATES> {
        self.transition.to_dense()
    }

    /// The predictions run so far and the physical covariance right after the last one, in
    /// f64: with [`Self::last_transition_nav`] and the covariance after the updates that
    /// followed, what the closed-loop error transition `P⁺ (P⁻)⁻¹ Φ` is made of.
    #[cfg(feature = "probe")]
    pub fn last_prediction(&self) -> (u64, &SMatrix<f64, N, N>) {
        (self.probe.0, &self.probe.1)
    }
}
