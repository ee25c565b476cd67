//! Inter-IMU calibration updates (paper Section II).
//!
//! * [`ErrorStateEkf::fuse_inter_imu`], method II-B (eqs. 8–12): the reference-IMU filter is
//!   fed the extra IMU's angular rate `ω_is^s = C_b^s ω_ib^b` and specific force
//!   `f^s = C_b^s (f^b + Ω̇ r + Ω Ω r)`, which observe the boresight and lever arm jointly
//!   and, as the paper stresses, without any coupling to the attitude error `ε`.
//! * [`ErrorStateEkf::fuse_attitude`], method II-A (eq. 7): a filter mechanising the extra
//!   IMU is fed the reference solution's attitude.
//!
//! Conventions: `C_b^s = (I − [δψ×]) Ĉ_b^s`, so for `Ĉ_b^s = I` the rate model is the
//! paper's eq. (10), `z_ω ≈ ω + Ω ψ`. The Jacobians are the exact first-order ones of
//! eqs. (8)–(9) about the current nominal calibration (checked against finite differences in
//! the tests). They differ from the printed eq. (11)–(12) in two places: the printed
//! `−[f^b×] ψ` has the opposite sign to what eq. (10)'s own convention `C ≈ I − Ψ` gives
//! (`(I − Ψ) f = f + [f×] ψ`), and the printed lever-arm terms `−Ω Ω [r×] ψ − Ω̇ [r×] ψ`
//! are replaced by the exact `[(Ω Ω r + Ω̇ r)×] ψ`; both agree to first order when `r` is
//! small but the exact form keeps the filter consistent at a 20 cm prior.
//!
//! The reference samples enter bias-corrected with the filter's nominal biases, so what is
//! left of the biases (the bias-error states) is in them too, and the rows carry it: both
//! predictions move by `−C_b^s` per unit of bias error. Left out is only the lever-arm term's
//! change with the gyro bias (`2 |ω| |r|` per unit, 1e-4 m/s² at 1 rad/s, 35 cm, 0.01 deg/s of
//! bias error). The extra IMU's own bias is not a state: a caller removes what it knows of
//! it (e.g. the fault monitor's offset of that unit) before the update.

use super::{
    boresight_index, lever_arm_index, skew, small_rotation_vector, tally, BatchOutcome,
    ErrorStateEkf, SparseRow, ACCEL_BIAS, ATT, GYRO_BIAS,
};
use crate::scalar::FilterScalar;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// One synchronised sample of the reference IMU (the filter's body frame `b`) and an extra
/// IMU (frame `s`), for [`ErrorStateEkf::fuse_inter_imu`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InterImuSample<T> {
    /// Reference angular rate `ω_ib^b`, rad/s, bias-corrected.
    pub omega_ib_b_rad_s: Vector3<T>,
    /// Reference angular acceleration `ω̇_ib^b`, rad/s², from differencing the reference
    /// rates (see [`RateDifferentiator`]).
    pub omega_dot_ib_b_rad_s2: Vector3<T>,
    /// Reference specific force `f^b`, m/s², bias-corrected.
    pub f_b_m_s2: Vector3<T>,
    /// Extra IMU's angular rate `ω_is^s`, rad/s, in its own axes.
    pub omega_is_s_rad_s: Vector3<T>,
    /// Extra IMU's specific force `f^s`, m/s², in its own axes.
    pub f_s_m_s2: Vector3<T>,
    /// The extra IMU's readings were de-biased against the reference (its bias relative to
    /// the reference and the filter's nominal biases taken out, as the board's fusion does
    /// with the fault monitor's offsets): the reference's bias error is then on both sides
    /// and cancels, and the rows get no bias columns. False for independent IMUs (the
    /// paper's setting).
    pub shares_reference_bias: bool,
}

/// The reference's running means that a caller's removal of an extra IMU's relative bias
/// took out of the comparison along with it (see [`ErrorStateEkf::fuse_inter_imu_absorbed`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AbsorbedMeans<T> {
    /// Running mean of the reference angular rate `ω̄_ib^b`, rad/s, body axes.
    pub omega_ib_b_rad_s: Vector3<T>,
    /// Running mean of the reference specific force `f̄^b`, m/s², body axes.
    pub f_b_m_s2: Vector3<T>,
}

impl<T: FilterScalar> AbsorbedMeans<T> {
    /// Nothing absorbed: an extra IMU compared with an independent reference (the paper's
    /// setting).
    pub fn nothing() -> Self {
        Self {
            omega_ib_b_rad_s: Vector3::zeros(),
            f_b_m_s2: Vector3::zeros(),
        }
    }
}

impl<T: FilterScalar, const K: usize, const N: usize> ErrorStateEkf<T, K, N> {
    /// Joint boresight and lever-arm update of extra IMU `imu` (paper II-B, eqs. 8–12): three
    /// scalar angular-rate updates then three scalar specific-force updates. `sigma_rate_rad_s`
    /// and `sigma_force_m_s2` are the one-sigma noises of the difference between the extra
    /// IMU's reading and its prediction from the reference (both sensors' noise, and the
    /// noise of the differenced angular acceleration times the lever arm).
    /// Returns `None` if `imu >= K`.
    pub fn fuse_inter_imu(
        &mut self,
        imu: usize,
        sample: &InterImuSample<T>,
        sigma_rate_rad_s: &Vector3<T>,
        sigma_force_m_s2: &Vector3<T>,
    ) -> Option<BatchOutcome> {
        self.fuse_inter_imu_absorbed(
            imu,
            sample,
            &AbsorbedMeans::nothing(),
            sigma_rate_rad_s,
            sigma_force_m_s2,
        )
    }

    /// [`Self::fuse_inter_imu`] where the extra IMU's readings were de-biased by a running
    /// mean of their difference to the reference (the board's fault monitor learns each
    /// unit's offset over about ten seconds): that mean took out, with the relative bias, the
    /// boresight's effect on the reference's own running means `absorbed`, so what the update
    /// sees of a boresight error is its effect on the reference's departure from them. The
    /// rows then carry `[(C_b^s (ω - ω̄))×]` and `[(C_b^s (f + (Ω̇ + Ω Ω) r - f̄))×]`: with the
    /// full rates the filter would count every update as news of the boresight that the
    /// running offsets had already hidden, and grow sure of an angle it cannot see (measured
    /// on simulated drives: the boresight errors' NEES 28 against its 6, the errors set in the
    /// first half minute and held).
    pub fn fuse_inter_imu_absorbed(
        &mut self,
        imu: usize,
        sample: &InterImuSample<T>,
        absorbed: &AbsorbedMeans<T>,
        sigma_rate_rad_s: &Vector3<T>,
        sigma_force_m_s2: &Vector3<T>,
    ) -> Option<BatchOutcome> {
        let cal = *self.calibration.get(imu)?;
        let c_b_s = cal.c_b_s();
        let lever = cal.lever_arm_b_m;
        let omega = sample.omega_ib_b_rad_s;
        let omega_skew = skew(&omega);
        let omega_dot_skew = skew(&sample.omega_dot_ib_b_rad_s2);
        // (Ω̇ + Ω Ω): specific force at the extra IMU minus at the reference, per metre of arm.
        let arm_to_force = omega_dot_skew + omega_skew * omega_skew;

        let predicted_rate_s = c_b_s * omega;
        let predicted_force_s = c_b_s * (sample.f_b_m_s2 + arm_to_force * lever);
        let rate_psi = skew(&(c_b_s * (omega - absorbed.omega_ib_b_rad_s)));
        let force_psi = skew(&(predicted_force_s - c_b_s * absorbed.f_b_m_s2));
        let force_lever = c_b_s * arm_to_force;

        // The reference samples are corrected with the nominal biases; the bias errors
        // (true minus nominal) remain in them: the true rate is ω − δb_g, the true force
        // f − δb_a, so both predictions move by −C_b^s per unit of bias error.
        let bias_jacobian = -c_b_s;
        let (psi, arm) = (boresight_index(imu), lever_arm_index(imu));
        let mut batch = BatchOutcome::default();
        for axis in 0..3 {
            let mut row = SparseRow::from_blocks(psi, row3(&rate_psi, axis), None);
            if !sample.shares_reference_bias {
                row.push_block(GYRO_BIAS, row3(&bias_jacobian, axis));
            }
            let innovation = sample.omega_is_s_rad_s[axis] - predicted_rate_s[axis];
            let outcome = self.fuse_scalar(&row, innovation, sigma_rate_rad_s[axis]);
            tally(outcome, &mut self.stats.inter_imu_rate, &mut batch);
        }
        for axis in 0..3 {
            let mut row = SparseRow::from_blocks(
                psi,
                row3(&force_psi, axis),
                Some((arm, row3(&force_lever, axis))),
            );
            if !sample.shares_reference_bias {
                row.push_block(ACCEL_BIAS, row3(&bias_jacobian, axis));
            }
            let innovation = sample.f_s_m_s2[axis] - predicted_force_s[axis];
            let outcome = self.fuse_scalar(&row, innovation, sigma_force_m_s2[axis]);
            tally(outcome, &mut self.stats.inter_imu_force, &mut batch);
        }
        self.apply_variance_floors();
        Some(batch)
    }

    /// Boresight update through attitude (paper II-A, eq. 7) for a filter that mechanises the
    /// extra IMU: its body frame is the extra IMU's `s`, and calibration slot `imu` holds
    /// `C_b^s` to the reference `b`. `c_b_n_reference` is the reference solution's attitude
    /// (body `b` to NED), `c_s_n_nominal` this filter's nominal attitude, `sigma_rad` the
    /// one-sigma noise of the reference attitude about the NED axes.
    ///
    /// The innovation is the rotation vector of `C_b^n,ref (Ĉ_s^n Ĉ_b^s)ᵀ ≈ I + [(ε − Ĉ_s^n δψ)×]`
    /// rather than roll/pitch/yaw differences: it is the same measurement as eq. (7) without
    /// the Euler-angle singularity, and its Jacobian `[I | −Ĉ_s^n]` is exact to first order
    /// (the printed `H_φ` carries `Ψ` and `[ε×]` second-order terms). The lever arm is not
    /// observed by attitude and keeps its prior. Returns `None` if `imu >= K`.
    pub fn fuse_attitude(
        &mut self,
        imu: usize,
        c_b_n_reference: &Matrix3<T>,
        c_s_n_nominal: &Matrix3<T>,
        sigma_rad: &Vector3<T>,
    ) -> Option<BatchOutcome> {
        let cal = *self.calibration.get(imu)?;
        let predicted_c_b_n = c_s_n_nominal * cal.c_b_s();
        let residual = c_b_n_reference * predicted_c_b_n.transpose();
        let residual_q =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(residual));
        let innovation = small_rotation_vector(&residual_q);
        let psi_jacobian = -c_s_n_nominal;
        let psi = boresight_index(imu);
        let mut batch = BatchOutcome::default();
        for axis in 0..3 {
            let mut unit = [T::zero(); 3];
            unit[axis] = T::one();
            let row = SparseRow::from_blocks(ATT, unit, Some((psi, row3(&psi_jacobian, axis))));
            let outcome = self.fuse_scalar(&row, innovation[axis], sigma_rad[axis]);
            tally(outcome, &mut self.stats.attitude, &mut batch);
        }
        self.apply_variance_floors();
        Some(batch)
    }
}

fn row3<T: FilterScalar>(m: &Matrix3<T>, row: usize) -> [T; 3] {
    [m[(row, 0)], m[(row, 1)], m[(row, 2)]]
}

/// Angular acceleration from differencing reference rates: a central difference, which is
/// second-order accurate and centred on the middle sample, so every output is delayed by one
/// sample and carries the payload (the other signals) of that middle sample.
#[derive(Clone, Copy, Debug)]
pub struct RateDifferentiator<T, P> {
    older: Option<(Vector3<T>, P)>,
    newer: Option<(Vector3<T>, P, T)>,
}

impl<T: FilterScalar, P: Copy> Default for RateDifferentiator<T, P> {
    fn default() -> Self {
        Self {
            older: None,
            newer: None,
        }
    }
}

impl<T: FilterScalar, P: Copy> RateDifferentiator<T, P> {
    /// An empty differentiator.
    pub fn new() -> Self {
        Self::default()
    }

    /// Pushes a reference rate `omega_ib_b_rad_s` measured `dt_s` seconds after the previous
    /// one, with its `payload`. Returns the previous sample's rate, its angular acceleration
    /// (rad/s²) and payload once two intervals are known. A non-positive or non-finite
    /// `dt_s` restarts the differentiator (a gap in the data).
    pub fn push(
        &mut self,
        dt_s: T,
        omega_ib_b_rad_s: Vector3<T>,
        payload: P,
    ) -> Option<(Vector3<T>, Vector3<T>, P)> {
        if !(dt_s.is_finite() && dt_s > T::zero()) {
            self.older = None;
            self.newer = Some((omega_ib_b_rad_s, payload, T::zero()));
            return None;
        }
        let output = match (&self.older, &self.newer) {
            (Some((omega_old, _)), Some((omega_mid, payload_mid, dt_prev))) => {
                let span = *dt_prev + dt_s;
                Some((
                    *omega_mid,
                    (omega_ib_b_rad_s - omega_old) / span,
                    *payload_mid,
                ))
            }
            _ => None,
        };
        self.older = self.newer.map(|(omega, payload, _)| (omega, payload));
        self.newer = Some((omega_ib_b_rad_s, payload, dt_s));
        output
    }
}
