//! Rauch–Tung–Striebel smoothing of a whole recording through the closed-loop error-state
//! filter of `dynacal_core::nav::ekf`, and the paper's final inter-IMU calibration: the
//! variance-weighted mean of the smoothed boresight and lever-arm estimates over all epochs
//! (Stebler et al. 2015, Section V-B).
//!
//! [`SmoothingEkf`] wraps an `f64` filter. It accumulates the navigation-block transition
//! matrix over the predictions between epochs and, at every [`SmoothingEkf::epoch`], stores
//! the predicted and updated covariances, the correction the filter made and the nominal
//! calibration after the reset. [`SmoothingEkf::smooth`] then runs the RTS recursion
//! backwards. Because the filter resets its error state after every epoch, each smoothed
//! error is expressed about that epoch's post-reset nominal:
//!
//! `δ_k|N = G_k s_{k+1}`,  `G_k = P_k|k Φ_kᵀ P_{k+1|k}⁻¹`,
//! `P_k|N = P_k|k + G_k (P_{k+1|N} − P_{k+1|k}) G_kᵀ`,
//!
//! where `s_{k+1}` is the smoothed state at `k+1` minus the prediction made from epoch `k`.
//! For the navigation states it is `c_{k+1} + δ_{k+1|N}` (the filter's correction plus the
//! smoothed residual, additive to first order). For the calibration states, whose nominal is
//! constant between epochs, it is formed exactly on the rotation group (`Ĉ_b^s` boxminus),
//! so the large early corrections of a 20-degree prior do not leave linearisation error in
//! the smoothed early epochs.
//!
//! Memory: two `N×N` covariances per epoch (11.7 kB for 27 states), so record epochs at the
//! update rate, not the IMU rate.

use dynacal_core::nav::ekf::{
    boresight_index, lever_arm_index, small_rotation, small_rotation_vector, ErrorStateEkf,
    InterImuCalibration, NavCorrection, NAV_STATES,
};
use nalgebra::{DMatrix, DVector, SMatrix, Vector3};

/// Why smoothing failed.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum SmootherError {
    /// No epoch was recorded.
    #[error("no filter epochs were recorded, nothing to smooth")]
    Empty,
    /// A predicted covariance could not be inverted.
    #[error("predicted covariance at epoch {epoch} (t = {t_s} s) is not positive definite")]
    NotPositiveDefinite {
        /// Index of the epoch.
        epoch: usize,
        /// Its time, s.
        t_s: f64,
    },
}

#[derive(Clone, Debug)]
struct EpochRecord {
    t_s: f64,
    /// `P_{k|k−1}`, before this epoch's updates.
    p_predicted: DMatrix<f64>,
    /// `P_{k|k}`, after them.
    p_updated: DMatrix<f64>,
    /// Navigation-block transition from the previous epoch to this one.
    phi_nav_from_previous: SMatrix<f64, NAV_STATES, NAV_STATES>,
    /// The filter's error estimate before the reset, `c_k`.
    correction: DVector<f64>,
    /// Nominal calibrations after the reset, one per extra IMU.
    calibration: Vec<InterImuCalibration<f64>>,
}

/// An `f64` error-state filter that records what the RTS smoother needs.
#[derive(Clone, Debug)]
pub struct SmoothingEkf<const K: usize, const N: usize> {
    ekf: ErrorStateEkf<f64, K, N>,
    phi_since_last_epoch: SMatrix<f64, NAV_STATES, NAV_STATES>,
    epochs: Vec<EpochRecord>,
}

/// One smoothed epoch.
#[derive(Clone, Debug, PartialEq)]
pub struct SmoothedEpoch {
    /// Time, s.
    pub t_s: f64,
    /// Smoothed error about this epoch's post-reset nominal (units of the filter's state
    /// table): add the navigation part to the recorded nominal trajectory.
    pub error: DVector<f64>,
    /// Diagonal of the smoothed covariance `P_k|N`.
    pub variance: DVector<f64>,
    /// Smoothed calibration of each extra IMU.
    pub calibration: Vec<SmoothedCalibration>,
}

/// A smoothed inter-IMU calibration at one epoch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SmoothedCalibration {
    /// Boresight angles `ψ_b→s` (rotation vector, `C_s^b = exp([ψ×])`), rad, body axes.
    pub boresight_rad: Vector3<f64>,
    /// One-sigma boresight uncertainty, rad.
    pub boresight_sigma_rad: Vector3<f64>,
    /// Lever arm `r_b→s`, m, body axes.
    pub lever_arm_b_m: Vector3<f64>,
    /// One-sigma lever-arm uncertainty, m.
    pub lever_arm_sigma_m: Vector3<f64>,
}

/// The whole smoothed recording.
#[derive(Clone, Debug, PartialEq)]
pub struct Smoothed {
    /// Every recorded epoch, in time order.
    pub epochs: Vec<SmoothedEpoch>,
}

impl<const K: usize, const N: usize> SmoothingEkf<K, N> {
    /// Wraps `ekf`; record its initial state with an [`epoch`](Self::epoch) call (with no
    /// updates) before the first prediction.
    pub fn new(ekf: ErrorStateEkf<f64, K, N>) -> Self {
        Self {
            ekf,
            phi_since_last_epoch: SMatrix::identity(),
            epochs: Vec::new(),
        }
    }

    /// The filter (read-only; predict and update through this wrapper).
    pub fn ekf(&self) -> &ErrorStateEkf<f64, K, N> {
        &self.ekf
    }

    /// Number of recorded epochs.
    pub fn epoch_count(&self) -> usize {
        self.epochs.len()
    }

    /// Predicts the filter (see `ErrorStateEkf::predict`) and accumulates the transition.
    pub fn predict(
        &mut self,
        lin: &dynacal_core::nav::ekf::NavLinearization<f64>,
        dt_s: f64,
    ) -> bool {
        let ok = self.ekf.predict(lin, dt_s);
        if ok {
            self.phi_since_last_epoch = self.ekf.last_transition_nav() * self.phi_since_last_epoch;
        }
        ok
    }

    /// Runs this epoch's `updates` on the filter, records the epoch at time `t_s`, resets
    /// the filter and returns the navigation correction for the caller's mechanization.
    pub fn epoch(
        &mut self,
        t_s: f64,
        updates: impl FnOnce(&mut ErrorStateEkf<f64, K, N>),
    ) -> NavCorrection<f64> {
        let p_predicted = to_dynamic(&self.ekf.covariance());
        updates(&mut self.ekf);
        let correction = DVector::from_column_slice(self.ekf.error_estimate().as_slice());
        let p_updated = to_dynamic(&self.ekf.covariance());
        let nav = self.ekf.reset();
        let calibration = (0..K)
            .filter_map(|imu| self.ekf.calibration(imu).copied())
            .collect();
        self.epochs.push(EpochRecord {
            t_s,
            p_predicted,
            p_updated,
            phi_nav_from_previous: self.phi_since_last_epoch,
            correction,
            calibration,
        });
        self.phi_since_last_epoch = SMatrix::identity();
        nav
    }

    /// Runs the RTS recursion backwards over all recorded epochs.
    pub fn smooth(&self) -> Result<Smoothed, SmootherError> {
        let last = self
            .epochs
            .len()
            .checked_sub(1)
            .ok_or(SmootherError::Empty)?;
        let mut smoothed_error = vec![DVector::<f64>::zeros(N); self.epochs.len()];
        let mut smoothed_variance = vec![DVector::<f64>::zeros(N); self.epochs.len()];
        let mut p_next = self.epochs[last].p_updated.clone();
        smoothed_variance[last] = p_next.diagonal();
        for k in (0..last).rev() {
            let here = &self.epochs[k];
            let next = &self.epochs[k + 1];
            let mut phi = DMatrix::<f64>::identity(N, N);
            phi.view_mut((0, 0), (NAV_STATES, NAV_STATES))
                .copy_from(&next.phi_nav_from_previous);
            let chol =
                next.p_predicted
                    .clone()
                    .cholesky()
                    .ok_or(SmootherError::NotPositiveDefinite {
                        epoch: k + 1,
                        t_s: next.t_s,
                    })?;
            // Gᵀ = P_{k+1|k}⁻¹ Φ P_k|k (both covariances symmetric).
            let gain = chol.solve(&(&phi * &here.p_updated)).transpose();
            let innovation = self.smoothed_minus_prediction(k, &smoothed_error[k + 1]);
            smoothed_error[k] = &gain * innovation;
            let p_k = &here.p_updated + &gain * (&p_next - &next.p_predicted) * gain.transpose();
            smoothed_variance[k] = p_k.diagonal();
            p_next = p_k;
        }
        let epochs = self
            .epochs
            .iter()
            .zip(smoothed_error)
            .zip(smoothed_variance)
            .map(|((record, error), variance)| {
                let calibration = record
                    .calibration
                    .iter()
                    .enumerate()
                    .map(|(imu, nominal)| smoothed_calibration(nominal, imu, &error, &variance))
                    .collect();
                SmoothedEpoch {
                    t_s: record.t_s,
                    error,
                    variance,
                    calibration,
                }
            })
            .collect();
        Ok(Smoothed { epochs })
    }

    /// `s_{k+1}`: the smoothed state at epoch `k+1` minus the filter's prediction from epoch
    /// `k`, in the error coordinates of that prediction.
    fn smoothed_minus_prediction(&self, k: usize, smoothed_next: &DVector<f64>) -> DVector<f64> {
        let next = &self.epochs[k + 1];
        let mut s = &next.correction + smoothed_next;
        for imu in 0..K {
            let (Some(predicted), Some(after_reset)) = (
                self.epochs[k].calibration.get(imu),
                next.calibration.get(imu),
            ) else {
                continue;
            };
            let absolute = apply_calibration_error(after_reset, imu, smoothed_next);
            // True C_b^s = exp(−δψ) Ĉ_b^s  ⇒  δψ = −log(C_b^s Ĉ_b^sᵀ).
            let delta_psi =
                -small_rotation_vector(&(absolute.q_b_to_s * predicted.q_b_to_s.inverse()));
            let delta_lever = absolute.lever_arm_b_m - predicted.lever_arm_b_m;
            for axis in 0..3 {
                s[boresight_index(imu) + axis] = delta_psi[axis];
                s[lever_arm_index(imu) + axis] = delta_lever[axis];
            }
        }
        s
    }
}

impl Smoothed {
    /// The paper's final calibration of extra IMU `imu`: each boresight and lever-arm
    /// component is the mean of its smoothed values over all epochs, weighted by the inverse
    /// smoothed variances. The reported sigma is the weighted root-mean-square of the smoothed
    /// sigmas, `sqrt(n / Σ σ⁻²)`, not divided by `√n`, because the smoothed epochs of a
    /// constant are fully correlated. `None` if `imu` is out of range or nothing is finite.
    pub fn calibration_estimate(&self, imu: usize) -> Option<SmoothedCalibration> {
        let mut sum = [0.0f64; 6];
        let mut weight = [0.0f64; 6];
        let mut count = [0u32; 6];
        for epoch in &self.epochs {
            let cal = epoch.calibration.get(imu)?;
            for axis in 0..3 {
                let components = [
                    (axis, cal.boresight_rad[axis], cal.boresight_sigma_rad[axis]),
                    (
                        3 + axis,
                        cal.lever_arm_b_m[axis],
                        cal.lever_arm_sigma_m[axis],
                    ),
                ];
                for (j, value, sigma) in components {
                    let w = 1.0 / (sigma * sigma);
                    if value.is_finite() && w.is_finite() && w > 0.0 {
                        sum[j] += w * value;
                        weight[j] += w;
                        count[j] += 1;
                    }
                }
            }
        }
        if count.contains(&0) {
            return None;
        }
        let mean = |j: usize| sum[j] / weight[j];
        let sigma = |j: usize| (f64::from(count[j]) / weight[j]).sqrt();
        Some(SmoothedCalibration {
            boresight_rad: Vector3::new(mean(0), mean(1), mean(2)),
            boresight_sigma_rad: Vector3::new(sigma(0), sigma(1), sigma(2)),
            lever_arm_b_m: Vector3::new(mean(3), mean(4), mean(5)),
            lever_arm_sigma_m: Vector3::new(sigma(3), sigma(4), sigma(5)),
        })
    }
}

fn to_dynamic<const N: usize>(p: &SMatrix<f64, N, N>) -> DMatrix<f64> {
    DMatrix::from_column_slice(N, N, p.as_slice())
}

/// The nominal calibration with the error `error` (full state vector) folded in, as the
/// filter's reset does.
fn apply_calibration_error(
    nominal: &InterImuCalibration<f64>,
    imu: usize,
    error: &DVector<f64>,
) -> InterImuCalibration<f64> {
    let v3 = |start: usize| Vector3::new(error[start], error[start + 1], error[start + 2]);
    // The filter's own reset map, so that smoothing and filtering share one chart.
    let mut q = small_rotation(-v3(boresight_index(imu))) * nominal.q_b_to_s;
    q.renormalize();
    InterImuCalibration {
        q_b_to_s: q,
        lever_arm_b_m: nominal.lever_arm_b_m + v3(lever_arm_index(imu)),
    }
}

fn smoothed_calibration(
    nominal: &InterImuCalibration<f64>,
    imu: usize,
    error: &DVector<f64>,
    variance: &DVector<f64>,
) -> SmoothedCalibration {
    let cal = apply_calibration_error(nominal, imu, error);
    let sigma = |start: usize| {
        Vector3::new(
            variance[start].max(0.0).sqrt(),
            variance[start + 1].max(0.0).sqrt(),
            variance[start + 2].max(0.0).sqrt(),
        )
    };
    SmoothedCalibration {
        boresight_rad: cal.boresight_rad(),
        boresight_sigma_rad: sigma(boresight_index(imu)),
        lever_arm_b_m: cal.lever_arm_b_m,
        lever_arm_sigma_m: sigma(lever_arm_index(imu)),
    }
}

#[cfg(test)]
mod tests;
