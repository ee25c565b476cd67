//! The filter's start: attitude, gyro bias and heading from a standstill and the first
//! drive-off, without knowing how the board is mounted in the vehicle.
//!
//! At rest the mean specific force gives roll and pitch (it points up: `f = -g`), and the
//! mean angular rate the gyro bias (Earth's rate, 7e-5 rad/s, is left in it). Rest is what
//! the receiver says: the intervals between two fixes both slower than `REST_SPEED_M_S`.
//! The IMU's own standstill test cannot be trusted here: an idling engine shakes a parked
//! car by 0.01 rad/s, so a test strict enough for zero-velocity updates fails at rest, and a
//! smooth drive-off's steady force passes it, which put the drive-off's acceleration into
//! the levelling (tilts of 0.2 rad and headings 100 degrees off on 2 in 24 drives). Heading is
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
use crate::nav::rotation_of;

/// Longest standstill the rest means average over, s: the gyro bias drifts.
const REST_TIME_CONSTANT_S: f32 = 30.0;
/// How long the receiver must go on seeing rest before an interval is taken as rest, s.
const REST_CONFIRM_S: f32 = 0.5;
/// Horizontal GNSS speed below which the vehicle is at rest, m/s; raised to three of the
/// fix's speed sigmas, up to `MAX_REST_SPEED_M_S`, where the receiver is noisier.
const REST_SPEED_M_S: f32 = 0.2;
const MAX_REST_SPEED_M_S: f32 = 0.5;
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
    /// Gyro bias from the standstill, rad/s, body.
    gyro_bias_rad_s: Vector3<f32>,
    elapsed_s: f32,
}

/// Sums over filter intervals: specific force and angular rate times seconds (body), and
/// the seconds.
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    force: Vector3<f32>,
    rate: Vector3<f32>,
    seconds: f32,
}

impl Sums {
    fn add(&mut self, other: &Sums) {
        self.force += other.force;
        self.rate += other.rate;
        self.seconds += other.seconds;
    }
}

/// The alignment's state (see the module's note).
#[derive(Debug, Clone)]
pub struct Alignment {
    /// The intervals since the last fix.
    since_fix: Sums,
    /// Whether the last fix was at rest.
    last_fix_at_rest: bool,
    /// Means over the current standstill: specific force and angular rate, body.
    rest: Option<(Vector3<f32>, Vector3<f32>)>,
    /// Seconds of the current standstill.
    rest_s: f32,
    /// The last intervals at rest at both ends, older and newer, not yet in the rest means.
    unconfirmed: [Sums; 2],
    window: Option<Window>,
    /// Gravity magnitude at the last fix, m/s^2.
    gravity_m_s2: f32,
    /// GNSS velocity change needed for a heading, m/s.
    pub min_speed_change_m_s: f32,
}

impl Alignment {
    pub fn new(min_speed_change_m_s: f32) -> Self {
        Self {
            since_fix: Sums::default(),
            last_fix_at_rest: false,
            rest: None,
            rest_s: 0.0,
            unconfirmed: [Sums::default(); 2],
            window: None,
            gravity_m_s2: 9.81,
            min_speed_change_m_s,
        }
    }

    /// One filter interval of mean rate `omega_b_rad_s` and specific force `f_b_m_s2`
    /// (body) over `dt_s`.
    pub fn push(&mut self, omega_b_rad_s: Vector3<f32>, f_b_m_s2: Vector3<f32>, dt_s: f32) {
        let sums = &mut self.since_fix;
        sums.force += f_b_m_s2 * dt_s;
        sums.rate += omega_b_rad_s * dt_s;
        sums.seconds += dt_s;
        let g = self.gravity_m_s2;
        if let Some(w) = &mut self.window {
            let rate = omega_b_rad_s - w.gyro_bias_rad_s;
            w.q_wb *= rotation_of(rate * dt_s);
            w.dv_w_m_s += (w.q_wb * f_b_m_s2 + Vector3::new(0.0, 0.0, g)) * dt_s;
            w.elapsed_s += dt_s;
            if w.elapsed_s > MAX_WINDOW_S {
                self.window = None;
            }
        }
    }

    /// Ends the interval since the last fix. Intervals at rest at both ends wait
    /// `REST_CONFIRM_S` before they enter the rest means: the receiver still sees rest for a
    /// fix or two after the wheels start to turn, and that acceleration must not tilt the
    /// levelling. A fix in motion ends the standstill.
    fn close_interval(&mut self, at_rest: bool) {
        let sums = core::mem::take(&mut self.since_fix);
        let both_at_rest = at_rest && self.last_fix_at_rest;
        self.last_fix_at_rest = at_rest;
        if !at_rest {
            self.rest = None;
            self.unconfirmed = [Sums::default(); 2];
            return;
        }
        if !both_at_rest {
            return;
        }
        let [older, newer] = &mut self.unconfirmed;
        newer.add(&sums);
        if newer.seconds < REST_CONFIRM_S {
            return;
        }
        let confirmed = core::mem::replace(older, core::mem::take(newer));
        if confirmed.seconds <= 0.0 {
            return;
        }
        let (force, rate) = (
            confirmed.force / confirmed.seconds,
            confirmed.rate / confirmed.seconds,
        );
        // A plain mean over the standstill until it is as long as the time constant.
        self.rest_s = match self.rest {
            Some(_) => self.rest_s + confirmed.seconds,
            None => confirmed.seconds,
        };
        let alpha = (confirmed.seconds / self.rest_s.min(REST_TIME_CONSTANT_S)).min(1.0);
        let (f, r) = self.rest.unwrap_or((force, rate));
        self.rest = Some((f + (force - f) * alpha, r + (rate - r) * alpha));
    }

    /// A GNSS fix with a 3-D solution. Returns the start once the heading is known.
    pub fn on_fix(&mut self, fix: &GnssFix) -> Option<Start> {
        // In f32: gravity to 1e-7 is far below the accelerometers' noise, and the board then
        // links no f64 trigonometry.
        self.gravity_m_s2 = normal_gravity_m_s2(fix.lat_rad as f32, fix.h_m);
        let v = Vector3::from(fix.vel_ned_m_s);
        let horizontal = |x: &Vector3<f32>| x.x.hypot(x.y);
        // (max/min, not clamp: clamp's panic would bring the formatting machinery into the
        // board's flash.)
        #[allow(clippy::manual_clamp)]
        let rest_speed = (3.0 * fix.vel_sigma_m_s)
            .max(REST_SPEED_M_S)
            .min(MAX_REST_SPEED_M_S);
        let at_rest = horizontal(&v) < rest_speed;
        self.close_interval(at_rest);
        if at_rest {
            // A standstill: (re)start the drive-off window here.
            let (f, rate) = self.rest?;
            self.window = Some(Window {
                v_start_ned_m_s: v,
                q_wb: levelled(&f),
                dv_w_m_s: Vector3::zeros(),
                gyro_bias_rad_s: rate,
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
        let q_nw = crate::scalar::quaternion_from_euler(0.0, 0.0, heading);
        let velocity_noise = 2.0 * fix.vel_sigma_m_s.max(0.02);
        // The gyro's drift over the window: a 1e-3 rad/s bias residual, at most.
        let drift = 1e-3 * w.elapsed_s;
        self.window = None;
        Some(Start {
            q_nb: q_nw * w.q_wb,
            fix: *fix,
            gyro_bias_rad_s: w.gyro_bias_rad_s,
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
    crate::scalar::quaternion_from_euler(roll, pitch, 0.0)
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
    /// for 5 s shaken by an idling engine (13 Hz, 0.3 m/s^2 and 0.01 rad/s), then
    /// accelerating at 1 m/s^2 along the vehicle's nose, which points north-east; a fix every
    /// 0.1 s.
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
            for step in 0..1000 {
                let shake = (2.0 * core::f32::consts::PI * 13.0 * step as f32 * dt).sin();
                let rate = bias + Vector3::new(0.01, -0.01, 0.005) * shake;
                align.push(rate, f_rest + Vector3::new(0.1, 0.2, 0.3) * shake, dt);
                if step % 20 == 0 {
                    assert_eq!(align.on_fix(&fix([0.0; 3])), None);
                }
            }
            let a_ned = Vector3::new(course.cos(), course.sin(), 0.0);
            let f_drive = q_nb.inverse() * (a_ned - Vector3::new(0.0, 0.0, g));
            let mut start = None;
            for step in 1..=1200 {
                align.push(bias, f_drive, dt);
                if step % 20 == 0 {
                    let v = a_ned * (step as f32 * dt);
                    start = start.or(align.on_fix(&fix([v.x, v.y, 0.0])));
                }
            }
            let start = start.expect("a heading after 3 m/s");
            let error = (start.q_nb * q_nb.inverse()).scaled_axis();
            assert!(error.norm() < 2e-3, "heading {heading}: {error:?}");
            assert!((start.gyro_bias_rad_s - bias).norm() < 2e-4);
            assert!(start.heading_sigma_rad > 0.0 && start.heading_sigma_rad < 0.05);
        }
    }

    /// A drive-off whose first 0.1 s the receiver still sees as rest (it reaches 0.2 m/s
    /// only at its second fix) and whose steady force an IMU standstill test would take for
    /// rest: the levelling is from the rest before it, so 1 m/s^2 of it (0.1 rad of tilt)
    /// does not reach the start.
    #[test]
    fn the_drive_off_does_not_enter_the_levelling() {
        let g = 9.81f32;
        let mut align = Alignment::new(3.0);
        let dt = 0.005;
        let f_rest = Vector3::new(0.0, 0.0, -g);
        for step in 0..400 {
            align.push(Vector3::zeros(), f_rest, dt);
            if step % 20 == 0 {
                align.on_fix(&fix([0.0; 3]));
            }
        }
        let accel = 1.5f32;
        let f_drive = Vector3::new(accel, 0.0, -g);
        let mut start = None;
        for step in 1..=1000 {
            align.push(Vector3::zeros(), f_drive, dt);
            if step % 20 == 0 {
                let v = accel * step as f32 * dt;
                start = start.or(align.on_fix(&fix([v, 0.0, 0.0])));
            }
        }
        let start = start.expect("a start");
        let (roll, pitch, yaw) = start.q_nb.euler_angles();
        assert!(
            roll.abs() < 1e-3 && pitch.abs() < 1e-2 && yaw.abs() < 1e-2,
            "{roll} {pitch} {yaw}"
        );
    }

    #[test]
    fn no_start_without_a_standstill_before_the_drive_off() {
        let mut align = Alignment::new(3.0);
        for step in 0..1000 {
            align.push(Vector3::zeros(), Vector3::new(1.0, 0.0, -9.8), 0.005);
            if step % 20 == 0 {
                let v = 1.0 + step as f32 * 0.005;
                assert_eq!(align.on_fix(&fix([v, 0.0, 0.0])), None);
            }
        }
        // One fix at rest is no standstill: nothing is known of the rest's force yet.
        assert_eq!(align.on_fix(&fix([0.0, 0.0, 0.0])), None);
        assert!(align.window.is_none());
    }
}
