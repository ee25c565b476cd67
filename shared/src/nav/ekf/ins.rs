//! The closed loop: a [`Strapdown`] mechanization corrected by the [`ErrorStateEkf`].
//!
//! [`InsEkf::propagate`] removes the estimated biases from the IMU increments, advances the
//! mechanization and predicts the filter about the new nominal state; the `fuse_*` methods
//! form innovations from the nominal state; [`InsEkf::correct`] folds the error estimate back
//! into the mechanization (and the filter's own biases and calibrations) and zeroes it. Call
//! `correct` after the updates of each epoch.

use super::{
    position_innovation_ned_m, small_rotation, AbsorbedMeans, BatchOutcome, CalibrationCoupling,
    ErrorStateEkf, InterImuSample, NavCorrection, NavLinearization,
};
use crate::nav::earth::Latitude;
use crate::nav::strapdown::{arc_angle_rad, NavFault, NavState, Strapdown};
use crate::scalar::FilterScalar;
use nalgebra::Vector3;

impl<T: FilterScalar> NavLinearization<T> {
    /// The linearisation point at a mechanization state, with bias-corrected specific force
    /// `f_b_m_s2` (body, m/s²).
    pub fn from_state(state: &NavState<T>, f_b_m_s2: Vector3<T>) -> Self {
        Self::from_geodetic(
            state.lat(),
            state.h_m,
            state.v_ned_m_s,
            state.c_bn(),
            f_b_m_s2,
        )
    }
}

/// Applies a filter correction to a mechanization state: position via the curvature radii,
/// velocity additively, attitude as `C_b^n ← exp([ε×]) C_b^n`.
pub fn apply_correction<T: FilterScalar>(state: &mut NavState<T>, correction: &NavCorrection<T>) {
    let latitude = Latitude::new(state.lat());
    let (r, cos_lat) = (latitude.radii, latitude.cos);
    let d = correction.position_ned_m;
    state.lat_rad += arc_angle_rad(d.x, r.meridian_m + state.h_m);
    if cos_lat.abs() > nalgebra::convert(1e-9) {
        state.lon_rad += arc_angle_rad(d.y, (r.transverse_m + state.h_m) * cos_lat);
    }
    state.h_m -= d.z;
    state.v_ned_m_s += correction.velocity_ned_m_s;
    state.q_nb = small_rotation(correction.attitude_ned_rad) * state.q_nb;
    state.q_nb.renormalize();
}

/// Strapdown INS with its error-state filter.
#[derive(Clone, Debug)]
pub struct InsEkf<T: FilterScalar, const K: usize, const N: usize> {
    /// The mechanization (nominal navigation state).
    pub strapdown: Strapdown<T>,
    /// The error-state filter.
    pub ekf: ErrorStateEkf<T, K, N>,
}

impl<T: FilterScalar, const K: usize, const N: usize> InsEkf<T, K, N> {
    /// Pairs a mechanization with a filter.
    pub fn new(strapdown: Strapdown<T>, ekf: ErrorStateEkf<T, K, N>) -> Self {
        Self { strapdown, ekf }
    }

    /// The nominal navigation state.
    pub fn state(&self) -> &NavState<T> {
        self.strapdown.state()
    }

    /// One IMU step from raw increments over `dt_s`: `delta_theta_b_rad` (rad) and
    /// `delta_v_b_m_s` (m/s), body axes, before bias removal. On a mechanization fault the
    /// filter is not predicted and the fault is returned.
    pub fn propagate(
        &mut self,
        delta_theta_b_rad: Vector3<T>,
        delta_v_b_m_s: Vector3<T>,
        dt_s: T,
    ) -> Result<(), NavFault> {
        let delta_v = self.mechanize(delta_theta_b_rad, delta_v_b_m_s, dt_s)?;
        self.predict_covariance(delta_v / dt_s, dt_s)
    }

    /// The mechanization's step alone (as [`Self::propagate`], without the covariance):
    /// returns the bias-corrected velocity increment (body, m/s), which a caller predicting
    /// the covariance less often sums for [`Self::predict_covariance`].
    pub fn mechanize(
        &mut self,
        delta_theta_b_rad: Vector3<T>,
        delta_v_b_m_s: Vector3<T>,
        dt_s: T,
    ) -> Result<Vector3<T>, NavFault> {
        let delta_theta = delta_theta_b_rad - self.ekf.gyro_bias_b_rad_s() * dt_s;
        let delta_v = delta_v_b_m_s - self.ekf.accel_bias_b_m_s2() * dt_s;
        self.strapdown.step(delta_theta, delta_v, dt_s)?;
        Ok(delta_v)
    }

    /// The covariance carried `dt_s` forward about the current mechanization state, with the
    /// mean bias-corrected specific force `f_b_m_s2` (body) over that time.
    pub fn predict_covariance(&mut self, f_b_m_s2: Vector3<T>, dt_s: T) -> Result<(), NavFault> {
        self.predict_covariance_coupled(f_b_m_s2, None, dt_s)
    }

    /// [`Self::predict_covariance`] for a fused IMU turned by the estimated calibrations
    /// (see [`ErrorStateEkf::predict_coupled`]).
    pub fn predict_covariance_coupled(
        &mut self,
        f_b_m_s2: Vector3<T>,
        coupling: Option<&CalibrationCoupling<T, K>>,
        dt_s: T,
    ) -> Result<(), NavFault> {
        let latitude = self.strapdown.latitude();
        let s = self.strapdown.state();
        let lin = NavLinearization::at_latitude(&latitude, s.h_m, s.v_ned_m_s, s.c_bn(), f_b_m_s2);
        if self.ekf.predict_coupled(&lin, coupling, dt_s) {
            Ok(())
        } else {
            Err(NavFault::NonFinite)
        }
    }

    /// Fuses a GNSS position (WGS84 latitude, longitude in rad, height in m) with one-sigma
    /// noise `sigma_ned_m` (NED, m). The angles are differenced in f64 before the
    /// difference is scaled in the filter's scalar.
    pub fn fuse_gnss_position(
        &mut self,
        lat_rad: f64,
        lon_rad: f64,
        h_m: T,
        sigma_ned_m: &Vector3<T>,
    ) -> BatchOutcome {
        let innovation = position_innovation_ned_m(lat_rad, lon_rad, h_m, self.strapdown.state());
        self.ekf.fuse_gnss_position(&innovation, sigma_ned_m)
    }

    /// Fuses a GNSS velocity (NED, m/s) with one-sigma noise `sigma_ned_m_s`.
    pub fn fuse_gnss_velocity(
        &mut self,
        v_ned_m_s: &Vector3<T>,
        sigma_ned_m_s: &Vector3<T>,
    ) -> BatchOutcome {
        let innovation = v_ned_m_s - self.strapdown.state().v_ned_m_s;
        self.ekf.fuse_gnss_velocity(&innovation, sigma_ned_m_s)
    }

    /// Zero-velocity update with one-sigma residual motion `sigma_m_s`.
    pub fn fuse_zero_velocity(&mut self, sigma_m_s: T) -> BatchOutcome {
        let v = self.strapdown.state().v_ned_m_s;
        self.ekf.fuse_zero_velocity(&v, sigma_m_s)
    }

    /// Joint boresight/lever-arm update of extra IMU `imu` (see
    /// [`ErrorStateEkf::fuse_inter_imu`]); `None` if `imu >= K`.
    pub fn fuse_inter_imu(
        &mut self,
        imu: usize,
        sample: &InterImuSample<T>,
        sigma_rate_rad_s: &Vector3<T>,
        sigma_force_m_s2: &Vector3<T>,
    ) -> Option<BatchOutcome> {
        self.ekf
            .fuse_inter_imu(imu, sample, sigma_rate_rad_s, sigma_force_m_s2)
    }

    /// [`ErrorStateEkf::fuse_inter_imu_absorbed`]: the update of a unit de-biased by a running
    /// mean against the reference; `None` if `imu >= K`.
    pub fn fuse_inter_imu_absorbed(
        &mut self,
        imu: usize,
        sample: &InterImuSample<T>,
        absorbed: &AbsorbedMeans<T>,
        sigma_rate_rad_s: &Vector3<T>,
        sigma_force_m_s2: &Vector3<T>,
    ) -> Option<BatchOutcome> {
        self.ekf
            .fuse_inter_imu_absorbed(imu, sample, absorbed, sigma_rate_rad_s, sigma_force_m_s2)
    }

    /// Puts the position and velocity at a measurement's (WGS84 latitude, longitude in rad,
    /// height in m; NED velocity in m/s) with its sigmas, forgetting what the filter knew of
    /// them (see [`ErrorStateEkf::forget_block`]); attitude, biases and calibrations stay.
    pub fn reset_position_velocity(
        &mut self,
        (lat_rad, lon_rad, h_m): (f64, f64, T),
        v_ned_m_s: Vector3<T>,
        sigma_ned_m: &Vector3<T>,
        sigma_ned_m_s: &Vector3<T>,
    ) {
        let mut state = *self.strapdown.state();
        state.lat_rad = lat_rad;
        state.lon_rad = lon_rad;
        state.h_m = h_m;
        state.v_ned_m_s = v_ned_m_s;
        self.strapdown.set_state(state);
        self.ekf.forget_block(super::POS, sigma_ned_m);
        self.ekf.forget_block(super::VEL, sigma_ned_m_s);
    }

    /// Folds the error estimate into the mechanization and the filter's nominal values.
    pub fn correct(&mut self) -> NavCorrection<T> {
        let correction = self.ekf.reset();
        let mut state = *self.strapdown.state();
        apply_correction(&mut state, &correction);
        self.strapdown.set_state(state);
        correction
    }
}
