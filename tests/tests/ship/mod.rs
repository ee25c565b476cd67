//! An independent trajectory and IMU-error generator, written apart from the project's
//! simulator (`dynacal::sim`) so `dynacal errors` and `dynacal diagnose` can be tested on data
//! they did not make themselves. The platform is a ship (or a motion table) at sea near
//! lat 46.5 deg, lon 6.6 deg, h 400 m: roll, pitch and yaw are seeded sums of sinusoids (yaw
//! with a slow drift), the North-East-Down (NED) displacement is heave, surge and sway
//! sinusoids plus a constant forward speed, all closed-form in time so velocity,
//! acceleration and Euler rates are exact derivatives. The body frame is forward-right-down
//! (FRD); every quantity is SI.
//!
//! Physics: C_b^n from Z-Y-X Euler angles; the body rate is the Euler-rate part plus the
//! navigation frame's rate, omega_ib^b = omega_nb^b + C_n^b (omega_ie^n + omega_en^n); the
//! specific force is f^b = C_n^b (v_dot^n + (2 omega_ie^n + omega_en^n) x v^n - g^n); both
//! with the project's WGS84 Earth model (`dynacal_core::nav::earth`), so a strapdown
//! integration of the error-free reference reproduces the trajectory.
//!
//! Two recordings per run: an exact 200 Hz reference (rates, specific force, attitude,
//! position, velocity) and a 100 Hz MEMS sensor (rates and specific force only) mounted with
//! the project's conventions (`host/src/calibration/mod.rs`, `host/src/sim/effects.rs`):
//! C_s^b = Rotation3::from_euler_angles(boresight roll, pitch, yaw) and C_b^s its transpose,
//! so the calibration's psi (C_b^s = exp(-[psi x])) is the rotation vector of C_s^b; the
//! lever arm is the sensor's position w.r.t. the reference in the reference body frame; a
//! positive time offset means the sensor lags: its sample stamped t shows the kinematics at
//! t - time_offset_s. The sensor errors (bias, white noise, first-order Gauss-Markov, and
//! optional hidden effects) are generated here too, not by `ModelSpec::simulate`.

// Each test file that includes the generator uses a part of it.
#![allow(dead_code)]

use dynacal::interchange::{ImuRecording, Triplet, CHANNELS};
use dynacal_core::nav::{earth_rate_ned_rad_s, gravity_ned_m_s2, radii, transport_rate_ned_rad_s};
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::{PI, TAU};

/// Latitude of the platform's mean position, deg.
pub const LAT0_DEG: f64 = 46.5;
/// Longitude of the platform's mean position, deg.
pub const LON0_DEG: f64 = 6.6;
/// Ellipsoidal height of the platform's mean position, m.
pub const H0_M: f64 = 400.0;
/// Sample rate of the exact reference IMU, Hz.
pub const REFERENCE_RATE_HZ: f64 = 200.0;
/// Sample rate of the MEMS sensor, Hz.
pub const SENSOR_RATE_HZ: f64 = 100.0;

/// Step of the central difference that turns the closed-form omega_ib^b into the angular
/// acceleration, s: truncation ~h^2 |omega'''| / 6 and rounding ~1e-16 |omega| / h both stay
/// near 1e-9 rad/s^2 for ship motion.
const OMEGA_DOT_STEP_S: f64 = 1e-4;
/// Phase of a hidden vibration line at t = 0, rad (fixed, so the hidden effect is exactly
/// reproducible from its parameters).
const VIBRATION_PHASE_RAD: f64 = 0.3;

/// The baseline error levels of one channel kind, SI, at the sensor's 100 Hz.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseLevels {
    /// Constant bias (rad/s or m/s^2).
    pub bias: f64,
    /// White noise, 1-sigma per sample.
    pub white_sigma: f64,
    /// Gauss-Markov correlation rate, 1/s.
    pub gm_beta_per_s: f64,
    /// Gauss-Markov stationary 1-sigma.
    pub gm_sigma: f64,
}

/// Gyro levels (rad/s): those of the project's hidden-effect tests.
pub const GYRO_LEVELS: NoiseLevels = NoiseLevels {
    bias: 0.002,
    white_sigma: 0.004,
    gm_beta_per_s: 0.05,
    gm_sigma: 0.002,
};
/// Accelerometer levels (m/s^2): those of the project's hidden-effect tests.
pub const ACCEL_LEVELS: NoiseLevels = NoiseLevels {
    bias: 0.03,
    white_sigma: 0.02,
    gm_beta_per_s: 0.02,
    gm_sigma: 0.01,
};

/// The levels of channel `index` (gx gy gz ax ay az).
pub fn levels(index: usize) -> NoiseLevels {
    if index < 3 {
        GYRO_LEVELS
    } else {
        ACCEL_LEVELS
    }
}

/// Where the sensor sits on the platform, in the project's conventions (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mount {
    /// Boresight roll, pitch, yaw, deg: C_s^b = Rotation3::from_euler_angles of these.
    pub boresight_rpy_deg: [f64; 3],
    /// Position of the sensor w.r.t. the reference, reference body frame (FRD), m.
    pub lever_arm_b_m: [f64; 3],
    /// Sensor lag, s: the sample stamped t shows the kinematics at t - time_offset_s.
    pub time_offset_s: f64,
}

impl Mount {
    /// C_b^s: reference body frame to sensor frame.
    pub fn c_bs(&self) -> Matrix3<f64> {
        let [r, p, y] = self.boresight_rpy_deg.map(f64::to_radians);
        Rotation3::from_euler_angles(r, p, y)
            .into_inner()
            .transpose()
    }

    /// The boresight as the calibration reports it: psi with C_b^s = exp(-[psi x]), rad.
    pub fn boresight_rotation_vector_rad(&self) -> Vector3<f64> {
        let [r, p, y] = self.boresight_rpy_deg.map(f64::to_radians);
        Rotation3::from_euler_angles(r, p, y).scaled_axis()
    }
}

/// A hidden effect on one sensor channel (indices in gx gy gz ax ay az order, sensor frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Hidden {
    /// Error += value * the channel's true input.
    ScaleFactor { channel: usize, value: f64 },
    /// Gyro error += value (rad/s per m/s^2) * true specific force on `accel_axis` (0..3).
    GSensitivity {
        gyro_channel: usize,
        accel_axis: usize,
        value: f64,
    },
    /// Error += size from the first sample stamped at or after `at_s`.
    BiasStep {
        channel: usize,
        at_s: f64,
        size: f64,
    },
    /// Error += amplitude sin(2 pi frequency_hz t + 0.3), t the true sampling time; a
    /// frequency above the 50 Hz Nyquist aliases, as a real vibration would.
    Vibration {
        channel: usize,
        frequency_hz: f64,
        amplitude: f64,
    },
    /// The channel's Gauss-Markov variance multiplied by `gm_variance_factor`.
    NoiseChange {
        channel: usize,
        gm_variance_factor: f64,
    },
}

impl Hidden {
    /// Index of the channel the effect is on.
    pub fn index(&self) -> usize {
        match *self {
            Hidden::ScaleFactor { channel, .. }
            | Hidden::BiasStep { channel, .. }
            | Hidden::Vibration { channel, .. }
            | Hidden::NoiseChange { channel, .. } => channel,
            Hidden::GSensitivity { gyro_channel, .. } => gyro_channel,
        }
    }

    /// Name of the channel the effect is on (`gx` ... `az`).
    pub fn channel(&self) -> &'static str {
        CHANNELS[self.index()]
    }
}

/// The two recordings of a ship run.
#[derive(Debug, Clone)]
pub struct ShipRun {
    /// Exact 200 Hz reference: gyro, accel, attitude, position, velocity.
    pub reference: ImuRecording,
    /// The 100 Hz MEMS sensor: gyro and accel with errors, in its own frame.
    pub sensor: ImuRecording,
}

/// A seeded ship run of `seconds` with the sensor at `mount` and the `hidden` effects on top
/// of the baseline errors. The trajectory and the errors draw from separate streams of the
/// seed, and hidden effects draw nothing, so a run with and without them differs by exactly
/// the hidden terms.
pub fn ship_run(seconds: f64, seed: u64, mount: &Mount, hidden: &[Hidden]) -> ShipRun {
    let motion = ShipMotion::random(&mut ChaCha8Rng::seed_from_u64(seed));
    let mut error_rng = ChaCha8Rng::seed_from_u64(seed);
    error_rng.set_stream(1);
    ShipRun {
        reference: reference_recording(&motion, seconds),
        sensor: sensor_recording(&motion, seconds, mount, hidden, &mut error_rng),
    }
}

/// A static record of the same sensor (same mount and baseline errors, no hidden effect):
/// the platform at rest and level, heading north, so the gyros read Earth rate and the
/// accelerometers minus gravity, both through the boresight. What a user fits the sensor's
/// baseline noise model on. Its errors draw from another stream than a ship run's, so even
/// a caller passing one seed to both gets independent noise, as two recordings would have.
pub fn static_record(seconds: f64, seed: u64, mount: &Mount) -> ImuRecording {
    let mut error_rng = ChaCha8Rng::seed_from_u64(seed);
    error_rng.set_stream(2);
    sensor_recording(&ShipMotion::at_rest(), seconds, mount, &[], &mut error_rng)
}

/// A sum of sinusoids a_i sin(w_i t + phi_i), differentiable in closed form.
#[derive(Debug, Clone, Default)]
struct Sines {
    /// (amplitude, angular frequency rad/s, phase rad) per term.
    terms: Vec<(f64, f64, f64)>,
}

impl Sines {
    /// `count` terms with amplitudes uniform in `amplitude` and periods (s) in `period_s`.
    fn random(rng: &mut ChaCha8Rng, count: usize, amplitude: [f64; 2], period_s: [f64; 2]) -> Self {
        let terms = (0..count)
            .map(|_| {
                let a = rng.random_range(amplitude[0]..amplitude[1]);
                let w = TAU / rng.random_range(period_s[0]..period_s[1]);
                (a, w, rng.random_range(0.0..TAU))
            })
            .collect();
        Self { terms }
    }

    /// The `order`-th time derivative at `t_s`: d^n/dt^n sin(x) = sin(x + n pi/2).
    fn derivative(&self, t_s: f64, order: i32) -> f64 {
        let shift = f64::from(order) * PI / 2.0;
        self.terms
            .iter()
            .map(|&(a, w, phi)| a * w.powi(order) * (w * t_s + phi + shift).sin())
            .sum()
    }

    fn value(&self, t_s: f64) -> f64 {
        self.derivative(t_s, 0)
    }
    fn d1(&self, t_s: f64) -> f64 {
        self.derivative(t_s, 1)
    }
    fn d2(&self, t_s: f64) -> f64 {
        self.derivative(t_s, 2)
    }
}

/// The platform's motion: Euler angles and NED displacement as closed-form functions of time.
#[derive(Debug, Clone, Default)]
struct ShipMotion {
    roll_rad: Sines,
    pitch_rad: Sines,
    yaw_sines_rad: Sines,
    yaw0_rad: f64,
    yaw_drift_rad_s: f64,
    /// North, east, down displacement about the mean track, m.
    displacement_ned_m: [Sines; 3],
    /// Constant forward speed along the mean course, NED, m/s.
    cruise_ned_m_s: Vector3<f64>,
}

/// The exact kinematics of the platform at one time.
#[derive(Debug, Clone, Copy)]
struct Kinematics {
    roll_pitch_yaw_rad: [f64; 3],
    lat_lon_rad_h_m: [f64; 3],
    v_ned_m_s: Vector3<f64>,
    omega_ib_b_rad_s: Vector3<f64>,
    f_b_m_s2: Vector3<f64>,
}

impl ShipMotion {
    /// A random sea state and course from `rng` (ranges in the module docs).
    fn random(rng: &mut ChaCha8Rng) -> Self {
        let deg = f64::to_radians;
        let roll_terms = rng.random_range(2..=3);
        let pitch_terms = rng.random_range(2..=3);
        let roll_rad = Sines::random(rng, roll_terms, [deg(3.0), deg(10.0)], [6.0, 15.0]);
        let pitch_rad = Sines::random(rng, pitch_terms, [deg(2.0), deg(5.0)], [5.0, 12.0]);
        let yaw_sines_rad = Sines::random(rng, 2, [deg(5.0), deg(20.0)], [10.0, 40.0]);
        let yaw0_rad = rng.random_range(-PI..PI);
        let drift_deg_min =
            rng.random_range(1.0..5.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        // Surge and sway are drawn along north and east: the calibration and diagnosis see
        // only their accelerations, whose direction in the body turns with the yaw anyway.
        let surge_sway_m = [1.0, 3.0];
        let displacement_ned_m = [
            Sines::random(rng, 2, surge_sway_m, [15.0, 60.0]),
            Sines::random(rng, 2, surge_sway_m, [15.0, 60.0]),
            Sines::random(rng, 2, [0.5, 1.5], [6.0, 12.0]),
        ];
        let speed_m_s = rng.random_range(0.0..3.0);
        let course_rad = rng.random_range(-PI..PI);
        Self {
            roll_rad,
            pitch_rad,
            yaw_sines_rad,
            yaw0_rad,
            yaw_drift_rad_s: deg(drift_deg_min) / 60.0,
            displacement_ned_m,
            cruise_ned_m_s: Vector3::new(course_rad.cos(), course_rad.sin(), 0.0) * speed_m_s,
        }
    }

    /// At rest, level, heading north, at the mean position.
    fn at_rest() -> Self {
        Self::default()
    }

    /// Exact kinematics at `t_s`.
    fn kinematics(&self, t_s: f64) -> Kinematics {
        let (roll, pitch) = (self.roll_rad.value(t_s), self.pitch_rad.value(t_s));
        let yaw = self.yaw0_rad + self.yaw_drift_rad_s * t_s + self.yaw_sines_rad.value(t_s);
        let (roll_dot, pitch_dot) = (self.roll_rad.d1(t_s), self.pitch_rad.d1(t_s));
        let yaw_dot = self.yaw_drift_rad_s + self.yaw_sines_rad.d1(t_s);
        // Body rate w.r.t. NED from the Z-Y-X Euler rates.
        let omega_nb_b = Vector3::new(
            roll_dot - yaw_dot * pitch.sin(),
            pitch_dot * roll.cos() + yaw_dot * roll.sin() * pitch.cos(),
            -pitch_dot * roll.sin() + yaw_dot * roll.cos() * pitch.cos(),
        );
        let c_bn = Rotation3::from_euler_angles(roll, pitch, yaw).into_inner();
        let d = &self.displacement_ned_m;
        let ned_m = Vector3::from_fn(|i, _| d[i].value(t_s)) + self.cruise_ned_m_s * t_s;
        let v_ned_m_s = Vector3::from_fn(|i, _| d[i].d1(t_s)) + self.cruise_ned_m_s;
        let a_ned_m_s2 = Vector3::from_fn(|i, _| d[i].d2(t_s));
        // Geodetic position from the displacement with the radii at the mean position, so
        // d lat/dt = v_N / (R_N + h) as the strapdown mechanization has it.
        let (lat0, lon0) = (LAT0_DEG.to_radians(), LON0_DEG.to_radians());
        let r0 = radii(lat0);
        let lat = lat0 + ned_m.x / (r0.meridian_m + H0_M);
        let lon = lon0 + ned_m.y / ((r0.transverse_m + H0_M) * lat0.cos());
        let h = H0_M - ned_m.z;
        let omega_ie_n = earth_rate_ned_rad_s(lat);
        let omega_en_n = transport_rate_ned_rad_s(lat, h, &v_ned_m_s);
        let c_nb = c_bn.transpose();
        let coriolis_n = (omega_ie_n * 2.0 + omega_en_n).cross(&v_ned_m_s);
        Kinematics {
            roll_pitch_yaw_rad: [roll, pitch, wrap_pi(yaw)],
            lat_lon_rad_h_m: [lat, lon, h],
            v_ned_m_s,
            omega_ib_b_rad_s: omega_nb_b + c_nb * (omega_ie_n + omega_en_n),
            f_b_m_s2: c_nb * (a_ned_m_s2 + coriolis_n - gravity_ned_m_s2(lat, h)),
        }
    }

    /// Angular acceleration of the body w.r.t. inertial space, body frame, rad/s^2: a
    /// central difference of the closed-form omega_ib^b (accurate to ~1e-9 rad/s^2).
    fn omega_dot_ib_b_rad_s2(&self, t_s: f64) -> Vector3<f64> {
        let h = OMEGA_DOT_STEP_S;
        (self.kinematics(t_s + h).omega_ib_b_rad_s - self.kinematics(t_s - h).omega_ib_b_rad_s)
            / (2.0 * h)
    }
}

/// An angle brought into (-pi, pi], as a navigation system reports yaw.
fn wrap_pi(angle_rad: f64) -> f64 {
    let wrapped = (angle_rad + PI).rem_euclid(TAU) - PI;
    if wrapped == -PI {
        PI
    } else {
        wrapped
    }
}

/// Sample times k / rate_hz covering [0, seconds).
fn sample_times_s(seconds: f64, rate_hz: f64) -> Vec<f64> {
    let n = (seconds * rate_hz).round() as usize;
    (0..n).map(|k| k as f64 / rate_hz).collect()
}

fn empty_triplet(n: usize) -> Triplet {
    std::array::from_fn(|_| Vec::with_capacity(n))
}

fn push3(triplet: &mut Triplet, values: [f64; 3]) {
    for (column, value) in triplet.iter_mut().zip(values) {
        column.push(value);
    }
}

/// The exact reference at 200 Hz.
fn reference_recording(motion: &ShipMotion, seconds: f64) -> ImuRecording {
    let t_s = sample_times_s(seconds, REFERENCE_RATE_HZ);
    let n = t_s.len();
    let [mut gyro, mut accel, mut attitude, mut position, mut velocity] =
        std::array::from_fn(|_| empty_triplet(n));
    for &t in &t_s {
        let k = motion.kinematics(t);
        push3(&mut gyro, k.omega_ib_b_rad_s.into());
        push3(&mut accel, k.f_b_m_s2.into());
        push3(&mut attitude, k.roll_pitch_yaw_rad);
        push3(&mut position, k.lat_lon_rad_h_m);
        push3(&mut velocity, k.v_ned_m_s.into());
    }
    ImuRecording {
        t_s,
        gyro_rad_s: Some(gyro),
        accel_m_s2: Some(accel),
        attitude_rad: Some(attitude),
        position: Some(position),
        velocity_ned_m_s: Some(velocity),
        single_axis: vec![],
        sample_rate_hz: Some(REFERENCE_RATE_HZ),
    }
}

/// The true sensor-frame inputs (gx gy gz ax ay az) at `true_t_s`: the reference kinematics
/// carried over the lever arm and through the boresight (rigid body; the gravity gradient
/// over the lever arm, 3e-6 s^-2 per m, is neglected as the project does).
fn sensor_inputs(motion: &ShipMotion, true_t_s: f64, mount: &Mount) -> [f64; 6] {
    let k = motion.kinematics(true_t_s);
    let w = k.omega_ib_b_rad_s;
    let r = Vector3::from(mount.lever_arm_b_m);
    let f_at_sensor_b =
        k.f_b_m_s2 + motion.omega_dot_ib_b_rad_s2(true_t_s).cross(&r) + w.cross(&w.cross(&r));
    let c_bs = mount.c_bs();
    let (omega_s, f_s) = (c_bs * w, c_bs * f_at_sensor_b);
    [omega_s.x, omega_s.y, omega_s.z, f_s.x, f_s.y, f_s.z]
}

/// Bias, white noise and a stationary first-order Gauss-Markov process, `n` samples at
/// `dt_s`, the GM variance scaled by `gm_variance_factor`. The GM uses the exact
/// discretisation, so its variance and correlation are right at any beta dt.
fn baseline_errors(
    rng: &mut ChaCha8Rng,
    n: usize,
    dt_s: f64,
    levels: &NoiseLevels,
    gm_variance_factor: f64,
) -> Vec<f64> {
    let mut normal = || rng.sample::<f64, _>(StandardNormal);
    let gm_sigma = levels.gm_sigma * gm_variance_factor.sqrt();
    let phi = (-levels.gm_beta_per_s * dt_s).exp();
    let drive_sigma = gm_sigma * (1.0 - phi * phi).sqrt();
    let mut gm = gm_sigma * normal();
    (0..n)
        .map(|_| {
            let e = levels.bias + levels.white_sigma * normal() + gm;
            gm = phi * gm + drive_sigma * normal();
            e
        })
        .collect()
}

/// The deterministic part of the hidden effects on channel `index` at one sample.
fn hidden_error(
    hidden: &[Hidden],
    index: usize,
    stamp_t_s: f64,
    true_t_s: f64,
    inputs: &[f64; 6],
) -> f64 {
    hidden
        .iter()
        .filter(|h| h.index() == index)
        .map(|h| match *h {
            Hidden::ScaleFactor { value, .. } => value * inputs[index],
            Hidden::GSensitivity {
                accel_axis, value, ..
            } => value * inputs[3 + accel_axis],
            Hidden::BiasStep { at_s, size, .. } => {
                if stamp_t_s >= at_s {
                    size
                } else {
                    0.0
                }
            }
            Hidden::Vibration {
                frequency_hz,
                amplitude,
                ..
            } => amplitude * (TAU * frequency_hz * true_t_s + VIBRATION_PHASE_RAD).sin(),
            Hidden::NoiseChange { .. } => 0.0,
        })
        .sum()
}

/// The 100 Hz sensor on `motion`: true inputs at the lagged times plus its errors.
fn sensor_recording(
    motion: &ShipMotion,
    seconds: f64,
    mount: &Mount,
    hidden: &[Hidden],
    error_rng: &mut ChaCha8Rng,
) -> ImuRecording {
    for h in hidden {
        assert!(
            h.index() < 6,
            "hidden effect on a channel outside gx..az: {h:?}"
        );
        if let Hidden::GSensitivity {
            gyro_channel,
            accel_axis,
            ..
        } = *h
        {
            assert!(
                gyro_channel < 3 && accel_axis < 3,
                "g-sensitivity is gyro on accel: {h:?}"
            );
        }
    }
    let t_s = sample_times_s(seconds, SENSOR_RATE_HZ);
    let n = t_s.len();
    let dt_s = 1.0 / SENSOR_RATE_HZ;
    // Channel by channel, in a fixed order, so the draws do not depend on the hidden effects.
    let errors: [Vec<f64>; 6] = std::array::from_fn(|i| {
        let factor = hidden
            .iter()
            .filter(|h| h.index() == i)
            .map(|h| match *h {
                Hidden::NoiseChange {
                    gm_variance_factor, ..
                } => gm_variance_factor,
                _ => 1.0,
            })
            .product();
        baseline_errors(error_rng, n, dt_s, &levels(i), factor)
    });
    let mut channels: [Vec<f64>; 6] = std::array::from_fn(|_| Vec::with_capacity(n));
    for (k, &stamp_t_s) in t_s.iter().enumerate() {
        // The sensor lags: what it stamps t it sensed at t - time_offset_s.
        let true_t_s = stamp_t_s - mount.time_offset_s;
        let inputs = sensor_inputs(motion, true_t_s, mount);
        for (i, column) in channels.iter_mut().enumerate() {
            let hidden_i = hidden_error(hidden, i, stamp_t_s, true_t_s, &inputs);
            column.push(inputs[i] + errors[i][k] + hidden_i);
        }
    }
    let [gx, gy, gz, ax, ay, az] = channels;
    ImuRecording {
        t_s,
        gyro_rad_s: Some([gx, gy, gz]),
        accel_m_s2: Some([ax, ay, az]),
        attitude_rad: None,
        position: None,
        velocity_ned_m_s: None,
        single_axis: vec![],
        sample_rate_hz: Some(SENSOR_RATE_HZ),
    }
}
