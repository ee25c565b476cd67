//! The Earth model shared by the strapdown mechanization and the simulator: WGS84 constants,
//! radii of curvature, normal gravity (Somigliana with a second-order height correction),
//! Earth rate and transport rate, all resolved in the local North-East-Down (NED) frame.
//!
//! Everything is generic over the scalar (`f32` on the board, `f64` on the host) through
//! nalgebra's [`RealField`]. The simulator computes its "true" sensor outputs with exactly
//! these functions, so an error-free simulated IMU integrated with [`super::Strapdown`]
//! reproduces the simulated trajectory.

use nalgebra::{RealField, Vector3};

/// WGS84 semi-major axis, m.
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// WGS84 semi-minor axis, m.
pub const WGS84_B_M: f64 = WGS84_A_M * (1.0 - WGS84_F);
/// WGS84 first eccentricity squared.
pub const WGS84_E2: f64 = WGS84_F * (2.0 - WGS84_F);
/// WGS84 Earth rotation rate w.r.t. inertial space, rad/s.
pub const WGS84_OMEGA_IE_RAD_S: f64 = 7.292_115e-5;
/// WGS84 gravitational constant (including the atmosphere), m^3/s^2.
pub const WGS84_GM_M3_S2: f64 = 3.986_004_418e14;
/// Normal gravity on the ellipsoid at the equator, m/s^2.
pub const WGS84_GAMMA_EQUATOR_M_S2: f64 = 9.780_325_335_9;
/// Normal gravity on the ellipsoid at the poles, m/s^2.
pub const WGS84_GAMMA_POLE_M_S2: f64 = 9.832_184_937_8;

#[inline]
fn c<T: RealField + Copy>(x: f64) -> T {
    nalgebra::convert(x)
}

/// Principal radii of curvature of the WGS84 ellipsoid at a latitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Radii<T> {
    /// Meridian radius of curvature R_N (north-south), m.
    pub meridian_m: T,
    /// Transverse (prime vertical) radius of curvature R_E (east-west), m.
    pub transverse_m: T,
}

/// One geodetic latitude with its sine, cosine and radii of curvature: what every Earth-model
/// term below is made of. Computed once and reused while the position moves little
/// (`Strapdown` keeps one and renews it every few metres), because `f32` trigonometry runs
/// in software on the Cortex-M4F at thousands of instructions a call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Latitude<T> {
    pub lat_rad: T,
    pub sin: T,
    pub cos: T,
    pub radii: Radii<T>,
}

impl<T: crate::scalar::FilterScalar> Latitude<T> {
    pub fn new(lat_rad: T) -> Self {
        let (sin, cos) = lat_rad.sin_cos_rad();
        let w2 = T::one() - c::<T>(WGS84_E2) * sin * sin;
        let w = w2.sqrt();
        let a: T = c(WGS84_A_M);
        Self {
            lat_rad,
            sin,
            cos,
            radii: Radii {
                meridian_m: a * (T::one() - c::<T>(WGS84_E2)) / (w2 * w),
                transverse_m: a / w,
            },
        }
    }

    /// Normal gravity at height `h_m`: see [`normal_gravity_m_s2`].
    pub fn normal_gravity_m_s2(&self, h_m: T) -> T {
        let s2 = self.sin * self.sin;
        let k = WGS84_B_M * WGS84_GAMMA_POLE_M_S2 / (WGS84_A_M * WGS84_GAMMA_EQUATOR_M_S2) - 1.0;
        let gamma0 = c::<T>(WGS84_GAMMA_EQUATOR_M_S2) * (T::one() + c::<T>(k) * s2)
            / (T::one() - c::<T>(WGS84_E2) * s2).sqrt();
        let m = WGS84_OMEGA_IE_RAD_S * WGS84_OMEGA_IE_RAD_S * WGS84_A_M * WGS84_A_M * WGS84_B_M
            / WGS84_GM_M3_S2;
        // In powers of h/a rather than of h with coefficients 2/a and 3/a²: a² (4e13 m²)
        // is beyond a fixed-point range, and 2/a (3e-7 /m) keeps three digits there.
        let h_over_a = h_m / c::<T>(WGS84_A_M);
        let linear = c::<T>(2.0) * (c::<T>(1.0 + WGS84_F + m) - c::<T>(2.0 * WGS84_F) * s2);
        gamma0 * (T::one() - linear * h_over_a + c::<T>(3.0) * h_over_a * h_over_a)
    }

    /// Gravity vector in NED at height `h_m`: see [`gravity_ned_m_s2`].
    pub fn gravity_ned_m_s2(&self, h_m: T) -> Vector3<T> {
        Vector3::new(T::zero(), T::zero(), self.normal_gravity_m_s2(h_m))
    }

    /// Earth rate in NED: see [`earth_rate_ned_rad_s`].
    pub fn earth_rate_ned_rad_s(&self) -> Vector3<T> {
        let w: T = c(WGS84_OMEGA_IE_RAD_S);
        Vector3::new(w * self.cos, T::zero(), -w * self.sin)
    }

    /// Transport rate at height `h_m`: see [`transport_rate_ned_rad_s`].
    pub fn transport_rate_ned_rad_s(&self, h_m: T, v_ned_m_s: &Vector3<T>) -> Vector3<T> {
        let re_h = self.radii.transverse_m + h_m;
        let rn_h = self.radii.meridian_m + h_m;
        Vector3::new(
            v_ned_m_s.y / re_h,
            -v_ned_m_s.x / rn_h,
            -v_ned_m_s.y * (self.sin / self.cos) / re_h,
        )
    }

    /// Position rates at height `h_m`: see [`position_rates`].
    pub fn position_rates(&self, h_m: T, v_ned_m_s: &Vector3<T>) -> Option<(T, T, T)> {
        if self.cos.abs() < c(1e-6) {
            return None;
        }
        Some((
            v_ned_m_s.x / (self.radii.meridian_m + h_m),
            v_ned_m_s.y / ((self.radii.transverse_m + h_m) * self.cos),
            -v_ned_m_s.z,
        ))
    }
}

/// Radii of curvature at geodetic latitude `lat_rad`.
pub fn radii<T: crate::scalar::FilterScalar>(lat_rad: T) -> Radii<T> {
    Latitude::new(lat_rad).radii
}

/// Magnitude of normal gravity (gravitation plus centrifugal, along the ellipsoid normal),
/// m/s^2, at geodetic latitude `lat_rad` and ellipsoidal height `h_m`: Somigliana's closed
/// form on the ellipsoid with the usual second-order free-air height correction
/// (NIMA TR8350.2 eq. 4-3), good to a few ugal up to aircraft heights.
pub fn normal_gravity_m_s2<T: crate::scalar::FilterScalar>(lat_rad: T, h_m: T) -> T {
    Latitude::new(lat_rad).normal_gravity_m_s2(h_m)
}

/// Gravity vector (plumb-bob: gravitation plus centrifugal) in NED, m/s^2. The model keeps
/// only the component along the ellipsoid normal (the north component at height is below
/// 1e-5 m/s^2 at car heights).
pub fn gravity_ned_m_s2<T: crate::scalar::FilterScalar>(lat_rad: T, h_m: T) -> Vector3<T> {
    Latitude::new(lat_rad).gravity_ned_m_s2(h_m)
}

/// Earth rate w.r.t. inertial space resolved in NED, omega_ie^n, rad/s.
pub fn earth_rate_ned_rad_s<T: crate::scalar::FilterScalar>(lat_rad: T) -> Vector3<T> {
    Latitude::new(lat_rad).earth_rate_ned_rad_s()
}

/// Transport rate (rotation of NED w.r.t. the Earth caused by moving over it), omega_en^n,
/// rad/s, for Earth-relative velocity `v_ned_m_s` at latitude `lat_rad`, height `h_m`.
pub fn transport_rate_ned_rad_s<T: crate::scalar::FilterScalar>(
    lat_rad: T,
    h_m: T,
    v_ned_m_s: &Vector3<T>,
) -> Vector3<T> {
    Latitude::new(lat_rad).transport_rate_ned_rad_s(h_m, v_ned_m_s)
}

/// Rates of change of geodetic position for Earth-relative velocity `v_ned_m_s`:
/// (d lat/dt rad/s, d lon/dt rad/s, d h/dt m/s). `None` at the poles, where longitude rate
/// is undefined.
pub fn position_rates<T: crate::scalar::FilterScalar>(
    lat_rad: T,
    h_m: T,
    v_ned_m_s: &Vector3<T>,
) -> Option<(T, T, T)> {
    Latitude::new(lat_rad).position_rates(h_m, v_ned_m_s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn somigliana_matches_its_defining_values_and_the_1980_series() {
        assert_relative_eq!(
            normal_gravity_m_s2(0.0f64, 0.0),
            9.780_325_335_9,
            epsilon = 1e-10
        );
        let pole = normal_gravity_m_s2(core::f64::consts::FRAC_PI_2, 0.0);
        assert_relative_eq!(pole, 9.832_184_937_8, epsilon = 1e-9);
        // Independent check: the 1980 International Gravity Formula series,
        // 9.780327 (1 + 0.0053024 sin^2 L - 0.0000058 sin^2 2L), good to ~2e-6 m/s^2.
        for lat_deg in [0.0f64, 15.0, 30.0, 45.0, 60.0, 75.0, 89.0] {
            let lat = lat_deg.to_radians();
            let series = 9.780_327
                * (1.0 + 0.005_302_4 * lat.sin().powi(2) - 0.000_005_8 * (2.0 * lat).sin().powi(2));
            let g = normal_gravity_m_s2(lat, 0.0);
            assert!((g - series).abs() < 3e-6, "{lat_deg} deg: {g} vs {series}");
        }
    }

    #[test]
    fn free_air_gradient_is_about_3_086e_minus_6_per_metre() {
        let lat = 46.5f64.to_radians();
        let dg = normal_gravity_m_s2(lat, 0.0) - normal_gravity_m_s2(lat, 100.0);
        assert_relative_eq!(dg / 100.0, 3.086e-6, epsilon = 0.01e-6);
    }

    #[test]
    fn radii_at_equator_and_pole() {
        let eq = radii(0.0f64);
        assert_relative_eq!(eq.transverse_m, WGS84_A_M, epsilon = 1e-6);
        assert_relative_eq!(eq.meridian_m, WGS84_A_M * (1.0 - WGS84_E2), epsilon = 1e-6);
        let pole = radii(core::f64::consts::FRAC_PI_2);
        assert_relative_eq!(pole.meridian_m, pole.transverse_m, epsilon = 1e-6);
        assert_relative_eq!(
            pole.transverse_m,
            WGS84_A_M * WGS84_A_M / WGS84_B_M,
            epsilon = 1e-5
        );
    }

    #[test]
    fn earth_rate_has_wgs84_norm_and_points_up_north() {
        let lat = 0.8f64;
        let w = earth_rate_ned_rad_s(lat);
        assert_relative_eq!(w.norm(), WGS84_OMEGA_IE_RAD_S, epsilon = 1e-18);
        assert!(w.x > 0.0 && w.z < 0.0);
    }

    #[test]
    fn transport_rate_of_an_eastward_car_tilts_the_frame_about_north() {
        let v = Vector3::new(0.0, 20.0, 0.0);
        let w = transport_rate_ned_rad_s(0.0f64, 0.0, &v);
        assert_relative_eq!(w.x, 20.0 / WGS84_A_M, epsilon = 1e-15);
        assert_eq!(w.y, 0.0);
        assert_relative_eq!(w.z, 0.0, epsilon = 1e-20);
    }

    #[test]
    fn f32_and_f64_agree() {
        let g32 = normal_gravity_m_s2(0.7f32, 400.0);
        let g64 = normal_gravity_m_s2(0.7f64, 400.0);
        assert!((g32 as f64 - g64).abs() < 2e-6);
    }
}
