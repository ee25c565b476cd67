//! Inertial navigation core: the WGS84 Earth model and a strapdown mechanization in the
//! local North-East-Down frame, generic over the scalar (`f32` on the board, `f64` on the
//! host), allocation-free and panic-free. The simulator produces its reference IMU with the
//! same Earth model, and a navigation filter is built on [`Strapdown`].

pub mod earth;
pub mod ekf;
pub mod strapdown;

pub use earth::{
    earth_rate_ned_rad_s, gravity_ned_m_s2, normal_gravity_m_s2, position_rates, radii,
    transport_rate_ned_rad_s, Radii,
};
pub use strapdown::{rotation_of, NavFault, NavState, Strapdown};
