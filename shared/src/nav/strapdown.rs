//! Strapdown inertial navigation in the local North-East-Down frame: attitude, velocity and
//! geodetic position integrated from gyro and accelerometer increments (or from rate and
//! specific-force samples), with coning and sculling corrections, Earth rate, transport rate,
//! Coriolis and normal gravity.
//!
//! The algorithm follows the classic two-speed structure (Savage, *Strapdown Analytics*,
//! ch. 7; Groves, *Principles of GNSS, Inertial and Multisensor Integrated Navigation*, 5.5):
//! the body rotation over a step is a rotation vector with a coning term, the velocity
//! increment is rotated into NED with rotation-compensation and sculling terms, and the
//! slowly varying terms (gravity, Coriolis, frame rotation) are evaluated at the mid-step
//! state by one predictor-corrector pass, so the scheme is second order in the step length.
//!
//! It is generic over the scalar: `f32` on the board, `f64` on the host. It never panics;
//! numerical trouble is reported as a [`NavFault`] and leaves the state untouched.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::scalar::FilterScalar;

use super::earth::Latitude;

/// How far the position may move before the latitude's trigonometry is recomputed, rad
/// (about 6 m): gravity then errs by 5e-8 m/s^2 at most and Earth rate by 1e-10 rad/s.
const LATITUDE_REFRESH_RAD: f64 = 1e-6;

#[inline]
fn c<T: FilterScalar>(x: f64) -> T {
    nalgebra::convert(x)
}

/// `x` in f64 (exact for `f32` and `f64`; NaN for a scalar f64 cannot hold).
#[inline]
pub fn to_f64<T: FilterScalar>(x: T) -> f64 {
    nalgebra::try_convert::<T, f64>(x).unwrap_or(f64::NAN)
}

/// The angle, rad, that `metres` along a radius of curvature `radius_m` subtends, in f64:
/// how a displacement in the scalar moves the f64 latitude or longitude. A step's 0.1 m is
/// 1.6e-8 rad, 68 units of a Q32.32 fixed-point number, so there the quotient is taken in
/// f64 (a software division per call) rather than rounded to 1% in the scalar; floats take
/// it in the scalar, as they always have.
pub fn arc_angle_rad<T: FilterScalar>(metres: T, radius_m: T) -> f64 {
    if T::SCALED {
        to_f64(metres) / to_f64(radius_m)
    } else {
        to_f64(metres / radius_m)
    }
}

/// Navigation state: attitude, Earth-relative velocity and geodetic position.
///
/// Latitude and longitude are f64 whatever the scalar: in f32 one unit in the last place of
/// a latitude near 0.8 rad is 6e-8 rad, 0.38 m, more than a car moves in one 200 Hz step, so
/// an f32 position would stand still between steps (the remedy PX4 takes too: its f32 filter
/// keeps its position against an f64 origin). Increments are computed in the scalar and
/// added in f64, which costs the board a few software double additions per step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavState<T: FilterScalar> {
    /// Attitude of the body (forward-right-down) w.r.t. NED: rotates body-frame vectors into
    /// NED (the quaternion of C_b^n).
    pub q_nb: UnitQuaternion<T>,
    /// Velocity w.r.t. the Earth, resolved in NED, m/s.
    pub v_ned_m_s: Vector3<T>,
    /// Geodetic latitude (WGS84), rad.
    pub lat_rad: f64,
    /// Longitude, rad.
    pub lon_rad: f64,
    /// Ellipsoidal height, m.
    pub h_m: T,
}

impl<T: FilterScalar> NavState<T> {
    /// A state from Z-Y-X Euler angles (roll, pitch, yaw of body w.r.t. NED, rad).
    pub fn from_euler(
        roll_rad: T,
        pitch_rad: T,
        yaw_rad: T,
        v_ned_m_s: Vector3<T>,
        lat_rad: f64,
        lon_rad: f64,
        h_m: T,
    ) -> Self {
        Self {
            q_nb: crate::scalar::quaternion_from_euler(roll_rad, pitch_rad, yaw_rad),
            v_ned_m_s,
            lat_rad,
            lon_rad,
            h_m,
        }
    }

    /// Latitude in the scalar of the filter, rad (for curvature, gravity, Earth rate).
    pub fn lat(&self) -> T {
        c(self.lat_rad)
    }

    /// C_b^n: the direction cosine matrix taking body-frame vectors into NED.
    pub fn c_bn(&self) -> Matrix3<T> {
        self.q_nb.to_rotation_matrix().into_inner()
    }

    /// Roll, pitch, yaw (Z-Y-X Euler angles of body w.r.t. NED), rad; yaw in (-pi, pi].
    pub fn euler_rad(&self) -> (T, T, T) {
        self.q_nb.euler_angles()
    }
}

/// Why a step was refused. The state is left as it was.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum NavFault {
    /// The step length was not a positive finite number.
    BadTimeStep,
    /// An input or the resulting state was NaN or infinite.
    NonFinite,
    /// The position is within ~6 m of a pole, where longitude rate is undefined.
    NearPole,
}

/// The strapdown integrator: a [`NavState`] plus the previous step's increments, which the
/// two-sample coning and sculling corrections need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Strapdown<T: FilterScalar> {
    state: NavState<T>,
    previous_increments: Option<(Vector3<T>, Vector3<T>)>,
    /// The Earth model's latitude terms, and the latitude (f64) they were computed at.
    latitude: (Latitude<T>, f64),
}

impl<T: FilterScalar> Strapdown<T> {
    /// Starts from `state` with no history (the first increment step gets no coning or
    /// sculling correction).
    pub fn new(state: NavState<T>) -> Self {
        Self {
            latitude: (Latitude::new(state.lat()), state.lat_rad),
            state,
            previous_increments: None,
        }
    }

    /// The latitude terms at the current position (renewed every few metres, see
    /// `LATITUDE_REFRESH_RAD`).
    pub fn latitude(&mut self) -> Latitude<T> {
        if (self.state.lat_rad - self.latitude.1).abs() > LATITUDE_REFRESH_RAD {
            self.latitude = (Latitude::new(self.state.lat()), self.state.lat_rad);
        }
        self.latitude.0
    }

    /// The current navigation state.
    pub fn state(&self) -> &NavState<T> {
        &self.state
    }

    /// Replaces the navigation state (e.g. after a filter correction), keeping the increment
    /// history so coning and sculling stay continuous.
    pub fn set_state(&mut self, state: NavState<T>) {
        self.state = state;
    }

    /// Advances by one step from IMU increments over `dt_s` seconds: `delta_theta_b_rad`,
    /// the integral of the body angular rate w.r.t. inertial space (rad), and `delta_v_b_m_s`,
    /// the integral of specific force (m/s), both in the body frame. Coning and sculling are
    /// corrected with the two-sample algorithm using the previous step's increments (which
    /// assumes steps of equal length).
    pub fn step(
        &mut self,
        delta_theta_b_rad: Vector3<T>,
        delta_v_b_m_s: Vector3<T>,
        dt_s: T,
    ) -> Result<(), NavFault> {
        let twelfth: T = c(1.0 / 12.0);
        let half: T = c(0.5);
        let (coning, sculling) = match self.previous_increments {
            Some((prev_theta, prev_v)) => (
                prev_theta.cross(&delta_theta_b_rad) * twelfth,
                (prev_theta.cross(&delta_v_b_m_s) + prev_v.cross(&delta_theta_b_rad)) * twelfth,
            ),
            None => (Vector3::zeros(), Vector3::zeros()),
        };
        let rotation_vector_b = delta_theta_b_rad + coning;
        let delta_v_sf_b =
            delta_v_b_m_s + delta_theta_b_rad.cross(&delta_v_b_m_s) * half + sculling;
        self.advance(rotation_vector_b, delta_v_sf_b, dt_s)?;
        self.previous_increments = Some((delta_theta_b_rad, delta_v_b_m_s));
        Ok(())
    }

    /// Advances by one step from samples at the start and end of the step: angular rate
    /// `omega_ib_b_rad_s` and specific force `f_b_m_s2`, body frame. Within the step both are
    /// taken as linear in time; the rotation vector and the rotation-compensated velocity
    /// increment are then exact to first order in the body rotation over the step (the
    /// coning term is `dt^2/12 omega0 x omega1`). The increment history is cleared, since
    /// these corrections are already intra-step.
    pub fn step_rates(
        &mut self,
        omega0_ib_b_rad_s: Vector3<T>,
        omega1_ib_b_rad_s: Vector3<T>,
        f0_b_m_s2: Vector3<T>,
        f1_b_m_s2: Vector3<T>,
        dt_s: T,
    ) -> Result<(), NavFault> {
        let half: T = c(0.5);
        let dt2 = dt_s * dt_s;
        let d_omega = omega1_ib_b_rad_s - omega0_ib_b_rad_s;
        let d_f = f1_b_m_s2 - f0_b_m_s2;
        let rotation_vector_b = (omega0_ib_b_rad_s + omega1_ib_b_rad_s) * (half * dt_s)
            + omega0_ib_b_rad_s.cross(&omega1_ib_b_rad_s) * (dt2 * c::<T>(1.0 / 12.0));
        // Integral over the step of alpha(t) x f(t), alpha(t) the rotation since step start.
        let rotation_compensation = (omega0_ib_b_rad_s.cross(&f0_b_m_s2) * half
            + omega0_ib_b_rad_s.cross(&d_f) * c::<T>(1.0 / 3.0)
            + d_omega.cross(&f0_b_m_s2) * c::<T>(1.0 / 6.0)
            + d_omega.cross(&d_f) * c::<T>(1.0 / 8.0))
            * dt2;
        let delta_v_sf_b = (f0_b_m_s2 + f1_b_m_s2) * (half * dt_s) + rotation_compensation;
        self.advance(rotation_vector_b, delta_v_sf_b, dt_s)?;
        self.previous_increments = None;
        Ok(())
    }

    /// One step from the body rotation vector (frame at step start to frame at step end) and
    /// the specific-force velocity increment resolved in the body frame at step start.
    fn advance(
        &mut self,
        rotation_vector_b: Vector3<T>,
        delta_v_sf_b: Vector3<T>,
        dt_s: T,
    ) -> Result<(), NavFault> {
        if dt_s <= T::zero() || !dt_s.is_finite() {
            return Err(NavFault::BadTimeStep);
        }
        if !all_finite(&rotation_vector_b) || !all_finite(&delta_v_sf_b) {
            return Err(NavFault::NonFinite);
        }
        let s = self.state;
        let half: T = c(0.5);
        let c_bn = s.c_bn();
        let delta_v_sf_n0 = c_bn * delta_v_sf_b;
        // A step moves the latitude by 1e-8 rad or so: its terms at the step start serve the
        // whole step.
        let latitude = self.latitude();
        let omega_ie_n = latitude.earth_rate_ned_rad_s();

        // Predictor: slow terms at the step start; corrector: at the predicted mid-step.
        let mut v_new = s.v_ned_m_s;
        let mut mid = (s.h_m, s.v_ned_m_s);
        let mut zeta_n = Vector3::zeros();
        for _ in 0..2 {
            let (h_mid, v_mid) = mid;
            let omega_en_n = latitude.transport_rate_ned_rad_s(h_mid, &v_mid);
            zeta_n = (omega_ie_n + omega_en_n) * dt_s;
            let delta_v_sf_n = delta_v_sf_n0 - zeta_n.cross(&delta_v_sf_n0) * half;
            let coriolis = (omega_ie_n * c::<T>(2.0) + omega_en_n).cross(&v_mid);
            v_new =
                s.v_ned_m_s + delta_v_sf_n + (latitude.gravity_ned_m_s2(h_mid) - coriolis) * dt_s;
            let v_avg = (s.v_ned_m_s + v_new) * half;
            let (_, _, h_rate) = latitude
                .position_rates(s.h_m, &v_avg)
                .ok_or(NavFault::NearPole)?;
            mid = (s.h_m + h_rate * dt_s * half, v_avg);
        }
        let (h_mid, v_avg) = mid;
        let (_, _, h_rate) = latitude
            .position_rates(h_mid, &v_avg)
            .ok_or(NavFault::NearPole)?;
        let radii = latitude.radii;
        let q_body = rotation_of(rotation_vector_b);
        let q_nav = rotation_of(-zeta_n);
        let mut q_nb = q_nav * s.q_nb * q_body;
        q_nb.renormalize();
        let next = NavState {
            q_nb,
            v_ned_m_s: v_new,
            lat_rad: s.lat_rad + arc_angle_rad(v_avg.x * dt_s, radii.meridian_m + h_mid),
            lon_rad: s.lon_rad
                + arc_angle_rad(v_avg.y * dt_s, (radii.transverse_m + h_mid) * latitude.cos),
            h_m: s.h_m + h_rate * dt_s,
        };
        if !all_finite(&next.v_ned_m_s)
            || !next.lat_rad.is_finite()
            || !next.lon_rad.is_finite()
            || !next.h_m.is_finite()
            || !next.q_nb.coords.iter().all(|x| x.is_finite())
        {
            return Err(NavFault::NonFinite);
        }
        self.state = next;
        Ok(())
    }
}

/// The rotation by a rotation vector (axis times angle, rad): `UnitQuaternion::
/// from_scaled_axis`, with one `sin_cos` of the half angle where nalgebra calls `sin` and
/// `cos` apart. On the board each is its own software routine of 1.6 KB of flash, and the
/// filter needs no other plain `sin` or `cos`.
pub fn rotation_of<T: FilterScalar>(rotation_vector: Vector3<T>) -> UnitQuaternion<T> {
    let angle = rotation_vector.norm();
    let half: T = c(0.5);
    if angle <= T::default_epsilon() {
        // sin(a/2)/a -> 1/2 as a -> 0.
        let v = rotation_vector * half;
        return UnitQuaternion::new_normalize(nalgebra::Quaternion::new(T::one(), v.x, v.y, v.z));
    }
    let (sin, cos) = (angle * half).sin_cos_rad();
    let v = rotation_vector * (sin / angle);
    UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(cos, v.x, v.y, v.z))
}

fn all_finite<T: FilterScalar>(v: &Vector3<T>) -> bool {
    v.iter().all(|x| x.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav::earth::{earth_rate_ned_rad_s, gravity_ned_m_s2, normal_gravity_m_s2};
    use approx::assert_relative_eq;

    const LAT: f64 = 0.811_578; // 46.5 deg
    const H: f64 = 400.0;

    fn level_at_rest(yaw: f64) -> NavState<f64> {
        NavState::from_euler(0.0, 0.0, yaw, Vector3::zeros(), LAT, 0.1, H)
    }

    /// What a perfect IMU at rest on the Earth measures: Earth rate and minus gravity,
    /// resolved in the body frame.
    fn at_rest_measurements(state: &NavState<f64>) -> (Vector3<f64>, Vector3<f64>) {
        let c_nb = state.c_bn().transpose();
        (
            c_nb * earth_rate_ned_rad_s(state.lat()),
            -(c_nb * gravity_ned_m_s2(state.lat(), state.h_m)),
        )
    }

    #[test]
    fn stationary_imu_stays_put_for_an_hour() {
        // GIVEN a level, north-east-heading IMU at rest with perfect measurements
        let start = level_at_rest(0.7);
        let (omega, f) = at_rest_measurements(&start);
        let mut nav = Strapdown::new(start);
        // WHEN integrating increments at 100 Hz for an hour
        let dt = 0.01;
        for _ in 0..360_000 {
            nav.step(omega * dt, f * dt, dt).unwrap();
        }
        // THEN position, velocity and attitude are unchanged to numerical precision
        let end = nav.state();
        assert!(end.v_ned_m_s.norm() < 1e-6, "{:?}", end.v_ned_m_s);
        assert!((end.lat_rad - LAT).abs() * 6.4e6 < 1e-3);
        assert!((end.h_m - H).abs() < 1e-3, "{}", end.h_m);
        assert!(end.q_nb.angle_to(&start.q_nb) < 1e-9);
    }

    #[test]
    fn f32_stationary_imu_stays_put_for_a_minute() {
        let start64 = level_at_rest(0.0);
        let (omega, f) = at_rest_measurements(&start64);
        let start =
            NavState::<f32>::from_euler(0.0, 0.0, 0.0, Vector3::zeros(), LAT, 0.1, H as f32);
        let mut nav = Strapdown::new(start);
        let (omega, f) = (omega.cast::<f32>(), f.cast::<f32>());
        for _ in 0..6000 {
            nav.step(omega * 0.01, f * 0.01, 0.01).unwrap();
        }
        assert!(
            nav.state().v_ned_m_s.norm() < 0.02,
            "{:?}",
            nav.state().v_ned_m_s
        );
    }

    #[test]
    fn f32_position_follows_f64_at_speed_where_f32_angles_would_stand_still() {
        // GIVEN a car heading north-east at 30 m/s (0.1 m per 200 Hz step, below a third
        // of an f32 latitude's last place), mechanized in f32 and in f64
        let v = Vector3::new(21.2, 21.2, 0.0);
        let start64 = NavState::<f64>::from_euler(0.0, 0.0, 0.785, v, LAT, 0.1, H);
        let (omega, f) = at_rest_measurements(&start64);
        let start32 = NavState::<f32>::from_euler(0.0, 0.0, 0.785, v.cast(), LAT, 0.1, H as f32);
        let (mut nav64, mut nav32) = (Strapdown::new(start64), Strapdown::new(start32));
        let dt = 0.005;
        for _ in 0..12_000 {
            nav64.step(omega * dt, f * dt, dt).unwrap();
            let (w, a) = (omega.cast::<f32>(), f.cast::<f32>());
            nav32.step(w * dt as f32, a * dt as f32, dt as f32).unwrap();
        }
        // WHEN 60 s have passed THEN both moved about 1.8 km and agree to 0.2 m (f32 angles
        // would have lost up to 0.38 m at every step)
        let (a, b) = (nav64.state(), nav32.state());
        let north_m = (a.lat_rad - LAT) * 6.37e6;
        assert!((north_m - 1272.0).abs() < 20.0, "{north_m}");
        let gap_north_m = (a.lat_rad - b.lat_rad) * 6.37e6;
        let gap_east_m = (a.lon_rad - b.lon_rad) * 6.37e6 * LAT.cos();
        assert!(
            gap_north_m.hypot(gap_east_m) < 0.2,
            "{gap_north_m} {gap_east_m}"
        );
    }

    #[test]
    fn roll_error_leaks_gravity_into_east_velocity_at_g_times_tilt() {
        // GIVEN a level IMU at rest believed rolled right by 1e-4 rad: the measured upward
        // specific force, resolved with the wrong attitude, has an east part g * 1e-4
        // WHEN integrating 1 s THEN east velocity is g * 1e-4 * 1 s
        let truth = level_at_rest(0.0);
        let (omega, f) = at_rest_measurements(&truth);
        let tilted = NavState {
            q_nb: truth.q_nb * UnitQuaternion::from_euler_angles(1e-4, 0.0, 0.0),
            ..truth
        };
        let mut nav = Strapdown::new(tilted);
        for _ in 0..100 {
            nav.step(omega * 0.01, f * 0.01, 0.01).unwrap();
        }
        let g = normal_gravity_m_s2(LAT, H);
        assert_relative_eq!(nav.state().v_ned_m_s.y, g * 1e-4, max_relative = 1e-3);
    }

    #[test]
    fn constant_yaw_rate_turn_gives_exact_heading_change() {
        // GIVEN a vehicle at rest rotating about the local vertical at 0.5 rad/s
        let start = level_at_rest(0.0);
        let mut nav = Strapdown::new(start);
        let yaw_rate = 0.5;
        // WHEN integrating 2 s of rate samples (the body frame turns, so resolve each sample)
        let dt = 0.01;
        let sample = |t: f64| {
            let s = NavState::from_euler(0.0, 0.0, yaw_rate * t, Vector3::zeros(), LAT, 0.1, H);
            let (we, fb) = at_rest_measurements(&s);
            (we + Vector3::new(0.0, 0.0, yaw_rate), fb)
        };
        for k in 0..200 {
            let (w0, f0) = sample(k as f64 * dt);
            let (w1, f1) = sample((k + 1) as f64 * dt);
            nav.step_rates(w0, w1, f0, f1, dt).unwrap();
        }
        // THEN the heading is 1 rad and nothing else moved
        let (roll, pitch, yaw) = nav.state().euler_rad();
        assert_relative_eq!(yaw, 1.0, epsilon = 1e-9);
        assert!(roll.abs() < 1e-9 && pitch.abs() < 1e-9);
        assert!(nav.state().v_ned_m_s.norm() < 1e-7);
    }

    #[test]
    fn coning_correction_removes_most_of_the_coning_attitude_error() {
        // GIVEN a body angular rate omega = a w [-sin wt, cos wt, 0] (two axes oscillating in
        // quadrature: coning, which drives a real rotation about z that increments alone miss)
        let a = 0.02;
        let w = 2.0 * core::f64::consts::PI * 5.0;
        let integrate = |steps: usize, dt: f64, coning: bool| {
            let mut q = UnitQuaternion::identity();
            let mut prev: Option<Vector3<f64>> = None;
            for k in 0..steps {
                let (t0, t1) = (k as f64 * dt, (k + 1) as f64 * dt);
                // the exact integral of omega over the step
                let inc = Vector3::new(
                    a * ((w * t1).cos() - (w * t0).cos()),
                    a * ((w * t1).sin() - (w * t0).sin()),
                    0.0,
                );
                let phi = match (coning, prev) {
                    (true, Some(p)) => inc + p.cross(&inc) / 12.0,
                    _ => inc,
                };
                prev = Some(inc);
                q *= UnitQuaternion::from_scaled_axis(phi);
            }
            q
        };
        // WHEN integrating 10 s at 1 kHz with and without the two-sample correction
        let reference = integrate(1_000_000, 1e-5, false);
        let err_plain = integrate(10_000, 1e-3, false).angle_to(&reference);
        let err_corrected = integrate(10_000, 1e-3, true).angle_to(&reference);
        // THEN the uncorrected error is visible and the correction removes most of it
        assert!(err_plain > 1e-6, "{err_plain}");
        assert!(
            err_corrected < err_plain / 20.0,
            "{err_corrected} vs {err_plain}"
        );
    }

    #[test]
    fn bad_inputs_are_refused_and_leave_the_state_alone() {
        let start = level_at_rest(0.0);
        let mut nav = Strapdown::new(start);
        let z = Vector3::zeros();
        assert_eq!(nav.step(z, z, 0.0), Err(NavFault::BadTimeStep));
        assert_eq!(nav.step(z, z, f64::NAN), Err(NavFault::BadTimeStep));
        assert_eq!(
            nav.step(Vector3::new(f64::NAN, 0.0, 0.0), z, 0.01),
            Err(NavFault::NonFinite)
        );
        assert_eq!(*nav.state(), start);
        let mut polar = Strapdown::new(NavState {
            lat_rad: core::f64::consts::FRAC_PI_2,
            ..start
        });
        assert_eq!(polar.step(z, z, 0.01), Err(NavFault::NearPole));
    }
}
