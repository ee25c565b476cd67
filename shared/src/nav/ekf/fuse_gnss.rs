//! GNSS position and velocity fusion, and zero-velocity updates (ZUPT), each as three
//! sequential scalar updates on the NED position or velocity error states.

use super::{tally, BatchOutcome, ErrorStateEkf, SparseRow, POS, VEL};
use crate::nav::earth::Latitude;
use crate::nav::strapdown::{to_f64, NavState};
use crate::scalar::FilterScalar;
use nalgebra::Vector3;

/// Position innovation `measured − nominal`, NED metres, of a measured geodetic position
/// (latitude, longitude in rad, WGS84 height in m) against a navigation state: the formula
/// of [`geodetic_difference_ned_m`] with the angles differenced in f64 before they are
/// scaled in the filter's scalar (an f32 angle difference would lose the position).
pub fn position_innovation_ned_m<T: FilterScalar>(
    measured_lat_rad: f64,
    measured_lon_rad: f64,
    measured_h_m: T,
    nominal: &NavState<T>,
) -> Vector3<T> {
    let c = |x: f64| nalgebra::convert::<f64, T>(x);
    let latitude = Latitude::new(nominal.lat());
    let r = latitude.radii;
    let (d_lat, d_lon) = (
        measured_lat_rad - nominal.lat_rad,
        measured_lon_rad - nominal.lon_rad,
    );
    let (north_radius, east_radius) = (r.meridian_m + nominal.h_m, r.transverse_m + nominal.h_m);
    // In fixed point an angle of a metre (1.6e-7 rad) holds only 680 units: the product is
    // formed in f64 there.
    let (north, east) = if T::SCALED {
        let east_radius = east_radius * latitude.cos;
        (
            c(d_lat * to_f64(north_radius)),
            c(d_lon * to_f64(east_radius)),
        )
    } else {
        (
            c(d_lat) * north_radius,
            c(d_lon) * east_radius * latitude.cos,
        )
    };
    Vector3::new(north, east, nominal.h_m - measured_h_m)
}

/// Position innovation `measured − nominal` in NED metres from two geodetic positions
/// (latitude, longitude in rad; WGS84 height in m), using the curvature radii plus height
/// at the nominal position (see [`super::NavLinearization`]). Valid for differences of a few
/// kilometres, far beyond any sensible innovation.
pub fn geodetic_difference_ned_m<T: FilterScalar>(
    measured_lat_lon_h: [T; 3],
    nominal_lat_lon_h: [T; 3],
    meridian_radius_plus_h_m: T,
    transverse_radius_plus_h_m: T,
) -> Vector3<T> {
    let [lat_m, lon_m, h_m] = measured_lat_lon_h;
    let [lat_n, lon_n, h_n] = nominal_lat_lon_h;
    Vector3::new(
        (lat_m - lat_n) * meridian_radius_plus_h_m,
        (lon_m - lon_n) * transverse_radius_plus_h_m * lat_n.sin_cos_rad().1,
        h_n - h_m,
    )
}

impl<T: FilterScalar, const K: usize, const N: usize> ErrorStateEkf<T, K, N> {
    /// Fuses a GNSS position: `innovation_ned_m` is measured minus nominal position (NED, m;
    /// see [`geodetic_difference_ned_m`]), `sigma_ned_m` the one-sigma measurement noise.
    pub fn fuse_gnss_position(
        &mut self,
        innovation_ned_m: &Vector3<T>,
        sigma_ned_m: &Vector3<T>,
    ) -> BatchOutcome {
        let mut batch = BatchOutcome::default();
        for axis in 0..3 {
            let outcome = self.fuse_scalar(
                &SparseRow::unit(POS + axis),
                innovation_ned_m[axis],
                sigma_ned_m[axis],
            );
            tally(outcome, &mut self.stats.gnss_position, &mut batch);
        }
        self.apply_variance_floors();
        batch
    }

    /// Fuses a GNSS velocity: `innovation_ned_m_s` is measured minus nominal velocity (NED,
    /// m/s), `sigma_ned_m_s` the one-sigma measurement noise.
    pub fn fuse_gnss_velocity(
        &mut self,
        innovation_ned_m_s: &Vector3<T>,
        sigma_ned_m_s: &Vector3<T>,
    ) -> BatchOutcome {
        let mut batch = BatchOutcome::default();
        for axis in 0..3 {
            let outcome = self.fuse_scalar(
                &SparseRow::unit(VEL + axis),
                innovation_ned_m_s[axis],
                sigma_ned_m_s[axis],
            );
            tally(outcome, &mut self.stats.gnss_velocity, &mut batch);
        }
        self.apply_variance_floors();
        batch
    }

    /// Zero-velocity update while the vehicle is known to stand still: the true velocity is
    /// zero, so the innovation is minus the nominal velocity `v_ned_m_s` (NED, m/s).
    /// `sigma_m_s` covers residual motion (engine vibration, a rocking body).
    pub fn fuse_zero_velocity(&mut self, v_ned_m_s: &Vector3<T>, sigma_m_s: T) -> BatchOutcome {
        let mut batch = BatchOutcome::default();
        for axis in 0..3 {
            let outcome =
                self.fuse_scalar(&SparseRow::unit(VEL + axis), -v_ned_m_s[axis], sigma_m_s);
            tally(outcome, &mut self.stats.zero_velocity, &mut batch);
        }
        self.apply_variance_floors();
        batch
    }
}
