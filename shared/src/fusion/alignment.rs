//! The filter's start: attitude, gyro bias and heading from a standstill and the first
//! drive-off, without knowing how the board is mounted in the vehicle.
//!
//! At rest the mean specific force gives roll and pitch (it points up: `f = -g`), and the
//! mean angular rate the gyro bias (Earth's rate, 7e-5 rad/s, is left in it). Heading is
//! not observable at rest with MEMS gyros, and a course-over-ground heading needs to know
//! where the vehicle's nose is in the board's axes; so heading comes from comparing two
//! velocity changes over the same interval: the GNSS's, in NED, and the IMU's, integrated in
//! a levelled frame of unknown heading (the start attitude with yaw zero, carried by the
//! gyros). The angle between their horizontal parts is the heading. It needs the vehicle
//! to gain a few m/s from a known standstill; its error is about the GNSS velocity noise
//! over the change (0.05 m/s over 3 m/s: 1 degree), plus the gyro drift over the interval.

// Float methods (sqrt, atan2, hypot) without std.
#[allow(unused_imports)]
use nalgebra::{ComplexField, RealField};
use nalgebra::{UnitQuaternion, Vector3};

use crate::log::GnssFix;
use crate::nav::earth::normal_gravity_m_s2;

/// Exponential weight of the standstill means per second of data (a 1 s time constant).
const STILL_TIME_CONSTANT_S: f32 = 1.0;
/// The longest drive-off the heading is integrated over, s (gyro drift grows with it).
const MAX_WINDOW_S: f32 = 40.0;

/// The start found: everything the filter needs besides its settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Start {
    /// Attitude of the body w.r.t. NED.
    pub q_nb: UnitQuaternion<f32>,
    /// The fix the start is taken at (position and velocity).
    pub fix: GnssFix,
    /// Gyro bias from the standstill, rad/s, body.
    pub gyro_bias_rad_s: Vector3<f32>,
    /// One-sigma of the heading, rad.
    pub heading_sigma_rad: f32,
}

/// A drive-off being integrated.
#[derive(Debug, Clone, Copy)]
struct Window {
    /// Velocity at the start (the standstill fix), NED, m/s.
    v_start_ned_m_s: Vector3<f32>,
    /// Body attitude w.r.t. the levelled frame of zero heading at the start.
    q_wb: UnitQuaternion<f32>,
    /// Velocity change integrated in that frame, m/s.
    dv_w_m_s: Vector3<f32>,
    elapsed_s: f32,
}

/// The alignment's state (see the module's note).
#[derive(Debug, Clone)]
pub struct Alignment {
    /// Means over the current standstill: specific force and angular rate, body.
    still_force: Option<Vector3<f32>>,
    still_rate: Vector3<f32>,
    window: Option<Window>,
    /// Gravity magnitude at the last fix, m/s^2.
    gravity_m_s2: f32,
    /// GNSS velocity change needed for a heading, m/s.
    pub min_speed_change_m_s: f32,
}

impl Alignment {
    pub fn new(min_speed_change_m_s: f32) -> Self {
        Self {
            still_force: None,
            still_rate: Vector3::zeros(),
            window: None,
            gravity_m_s2: 9.81,
            min_speed_change_m_s,
        }
    }

    /// One filter interval of mean rate `omega_b_rad_s` and specific force `f_b_m_s2`
    /// (body) over `dt_s`; `still` says whether the platform is at rest.
    pub fn push(
        &mut self,
        omega_b_rad_s: Vector3<f32>,
        f_b_m_s2: Vector3<f32>,
        dt_s: f32,
        still: bool,
    ) {
        if still {
            let alpha = (dt_s / STILL_TIME_CONSTANT_S).min(1.0);
            match &mut self.still_force {
                Some(f) => {
                    *f += (f_b_m_s2 - *f) * alpha;
                    self.still_rate += (omega_b_rad_s - self.still_rate) * alpha;
                }
                None => {
                    self.still_force = Some(f_b_m_s2);
                    self.still_rate = omega_b_rad_s;
                }
            }
        }
        let g = self.gravity_m_s2;
        let bias = self.still_rate;
        if let Some(w) = &mut self.window {
            let rate = omega_b_rad_s - bias;
            w.q_wb *= UnitQuaternion::from_scaled_axis(rate * dt_s);
            w.dv_w_m_s += (w.q_wb * f_b_m_s2 + Vector3::new(0.0, 0.0, g)) * dt_s;
            w.elapsed_s += dt_s;
            if w.elapsed_s > MAX_WINDOW_S {
                self.window = None;
            }
        }
    }

    /// A GNSS fix with a 3-D solution; `still` as for [`Self::push`]. Returns the start
    /// once the heading is known.
    pub fn on_fix(&mut self, fix: &GnssFix, still: bool) -> Option<Start> {
        // In f32: gravity to 1e-7 is far below the accelerometers' noise, and the board then
        // links no f64 trigonometry.
        self.gravity_m_s2 = normal_gravity_m_s2(fix.lat_rad as f32, fix.h_m);
        let v = Vector3::from(fix.vel_ned_m_s);
        let horizontal = |x: &Vector3<f32>| x.x.hypot(x.y);
        if still && horizontal(&v) < 0.5 {
            // A standstill: (re)start the drive-off window here.
            let f = self.still_force?;
            self.window = Some(Window {
                v_start_ned_m_s: v,
                q_wb: levelled(&f),
                dv_w_m_s: Vector3::zeros(),
                elapsed_s: 0.0,
            });
            return None;
        }
        let w = self.window?;
        let dv_gnss = v - w.v_start_ned_m_s;
        if horizontal(&dv_gnss) < self.min_speed_change_m_s
            || horizontal(&w.dv_w_m_s) < 0.5 * self.min_speed_change_m_s
        {
            return None;
        }
        let heading = dv_gnss.y.atan2(dv_gnss.x) - w.dv_w_m_s.y.atan2(w.dv_w_m_s.x);
        let q_nw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading);
        let velocity_noise = 2.0 * fix.vel_sigma_m_s.max(0.02);
        // The gyro's drift over the window: a 1e-3 rad/s bias residual, at most.
        let drift = 1e-3 * w.elapsed_s;
        self.window = None;
        Some(Start {
            q_nb: q_nw * w.q_wb,
            fix: *fix,
            gyro_bias_rad_s: self.still_rate,
            heading_sigma_rad: (velocity_noise / horizontal(&dv_gnss))
                .hypot(drift)
                .max(0.01),
        })
    }
}

/// The attitude of zero heading whose roll and pitch put the mean specific force `f_b` at
/// rest straight up (`f = (0, 0, -g)` in NED).
fn levelled(f_b: &Vector3<f32>) -> UnitQuaternion<f32> {
    let roll = (-f_b.y).atan2(-f_b.z);
    let pitch = f_b.x.atan2(f_b.y.hypot(f_b.z));
    UnitQuaternion::from_euler_angles(roll, pitch, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fix(v_ned: [f32; 3]) -> GnssFix {
        GnssFix {
            t_us: 0,
            lat_rad: 0.8,
            lon_rad: 0.1,
            h_m: 400.0,
            vel_ned_m_s: v_ned,
            pos_sigma_m: 1.0,
            vel_sigma_m_s: 0.05,
            num_sats: 12,
            fix_type: 3,
        }
    }

    /// A board rolled 0.1 rad, pitched -0.05 rad and mounted at heading `heading`, at rest
    /// for 5 s, then accelerating at 1 m/s^2 along the vehicle's nose, which points north-east.
    #[test]
    fn roll_pitch_and_heading_of_a_board_mounted_any_way() {
        for heading in [0.3f32, 2.0, -2.8] {
            let course = core::f32::consts::FRAC_PI_4;
            let q_nb = UnitQuaternion::from_euler_angles(0.1, -0.05, heading);
            let g = normal_gravity_m_s2(0.8f64, 400.0) as f32;
            let bias = Vector3::new(0.004, -0.003, 0.002);
            let mut align = Alignment::new(3.0);
            let dt = 0.005;
            let f_rest = q_nb.inverse() * Vector3::new(0.0, 0.0, -g);
            for _ in 0..1000 {
                align.push(bias, f_rest, dt, true);
            }
            assert_eq!(align.on_fix(&fix([0.0; 3]), true), None);
            let a_ned = Vector3::new(course.cos(), course.sin(), 0.0);
            let f_drive = q_nb.inverse() * (a_ned - Vector3::new(0.0, 0.0, g));
            let mut start = None;
            for step in 1..=1200 {
                align.push(bias, f_drive, dt, false);
                if step % 20 == 0 {
                    let v = a_ned * (step as f32 * dt);
                    start = start.or(align.on_fix(&fix([v.x, v.y, 0.0]), false));
                }
            }
            let start = start.expect("a heading after 3 m/s");
            let error = (start.q_nb * q_nb.inverse()).scaled_axis();
            assert!(error.norm() < 2e-3, "heading {heading}: {error:?}");
            assert!((start.gyro_bias_rad_s - bias).norm() < 1e-6);
            assert!(start.heading_sigma_rad > 0.0 && start.heading_sigma_rad < 0.05);
        }
    }

    #[test]
    fn no_start_without_a_standstill_before_the_drive_off() {
        let mut align = Alignment::new(3.0);
        for _ in 0..1000 {
            align.push(Vector3::zeros(), Vector3::new(1.0, 0.0, -9.8), 0.005, false);
        }
        assert_eq!(align.on_fix(&fix([10.0, 0.0, 0.0]), false), None);
        assert_eq!(align.on_fix(&fix([0.0, 0.0, 0.0]), true), None);
    }
}
