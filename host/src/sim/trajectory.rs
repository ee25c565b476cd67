//! Car-like and static trajectories with exact kinematics.
//!
//! A car trajectory is a seeded random script of manoeuvres (stops at lights, accelerations,
//! braking, speed changes, curves, turns at intersections, lane changes) written as smooth
//! closed-form functions of time: the longitudinal acceleration and the yaw rate are
//! raised-cosine pulses, so speed, along-track distance and heading are closed form too. The
//! road grade is a sum of sinusoids of the along-track distance (hills); pitch follows the
//! grade plus squat/dive under acceleration, roll follows the lateral acceleration, and road
//! and engine vibration are sinusoids whose amplitude grows with speed. Everything is
//! evaluated on Taylor [`Jet`]s, so angular rate, angular acceleration, specific force and
//! jerk are exact derivatives. Position is the one integrated quantity: geodetic latitude,
//! longitude and height follow from the NED velocity by RK4 on a 100 Hz grid and cubic
//! Hermite interpolation between grid nodes (error far below a micrometre).
//!
//! The reference IMU output is then consistent with the strapdown navigation equations of
//! [`dynacal_core::nav`] (same Earth model): omega_ib^b = omega_nb^b + C_n^b (omega_ie^n +
//! omega_en^n) and f^b = C_n^b (v_dot^n + (2 omega_ie^n + omega_en^n) x v^n - g^n).

use dynacal_core::nav::{
    earth::{WGS84_A_M, WGS84_E2, WGS84_OMEGA_IE_RAD_S},
    normal_gravity_m_s2, position_rates,
};
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

use super::jet::{cross, mat_t_vec, order, Jet, JetVec3};

/// Which motion to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Scenario {
    /// A car driving in town and country: stops, turns, hills, lane changes, vibration.
    Car,
    /// The platform at rest (on a table): only Earth rate and gravity.
    Static,
}

/// One sinusoidal vibration line of the platform; amplitude grows linearly with speed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionLine {
    /// Frequency, Hz.
    pub frequency_hz: f64,
    /// Amplitude when stopped (engine idle), m or rad.
    pub amplitude_at_rest: f64,
    /// Additional amplitude per m/s of speed (road roughness), m or rad per m/s.
    pub amplitude_per_m_s: f64,
}

/// Platform vibration: displacement along NED down and small roll and pitch oscillations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VibrationConfig {
    /// Vertical (NED down) displacement lines, m.
    pub vertical_m: Vec<MotionLine>,
    /// Roll lines, rad.
    pub roll_rad: Vec<MotionLine>,
    /// Pitch lines, rad.
    pub pitch_rad: Vec<MotionLine>,
}

impl Default for VibrationConfig {
    /// A mid-size car: body bounce near 1.3 Hz, wheel hop near 11-17 Hz, engine second
    /// order at 26 Hz; at 20 m/s this gives vertical accelerations of a few 0.1 m/s^2 and
    /// angular rate vibration of about 0.01 rad/s.
    fn default() -> Self {
        let l = |f, a0, a1| MotionLine {
            frequency_hz: f,
            amplitude_at_rest: a0,
            amplitude_per_m_s: a1,
        };
        Self {
            vertical_m: vec![
                l(1.3, 0.0, 1e-4),
                l(11.0, 0.0, 2e-6),
                l(17.0, 0.0, 1e-6),
                l(26.0, 3e-6, 1e-7),
            ],
            roll_rad: vec![l(1.1, 0.0, 1e-4), l(14.0, 0.0, 5e-6), l(26.0, 2e-5, 0.0)],
            pitch_rad: vec![l(1.4, 0.0, 8e-5), l(12.0, 0.0, 4e-6), l(26.0, 2e-5, 0.0)],
        }
    }
}

/// Trajectory parameters (the model file's optional `trajectory` object).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrajectoryConfig {
    /// Start latitude, deg.
    pub start_lat_deg: f64,
    /// Start longitude, deg.
    pub start_lon_deg: f64,
    /// Start ellipsoidal height, m.
    pub start_h_m: f64,
    /// Start heading (yaw), deg from north.
    pub start_yaw_deg: f64,
    /// Constant roll and pitch of the platform, deg (the table tilt in the static scenario).
    pub mount_roll_pitch_deg: [f64; 2],
    /// Time at rest before the car first moves, s.
    pub initial_stop_s: f64,
    /// Cruise speeds are drawn from this range, m/s.
    pub cruise_speed_m_s: [f64; 2],
    /// Largest forward acceleration, m/s^2.
    pub max_accel_m_s2: f64,
    /// Largest braking deceleration, m/s^2.
    pub max_brake_m_s2: f64,
    /// Largest lateral (centripetal) acceleration, m/s^2.
    pub max_lateral_m_s2: f64,
    /// Road grade amplitudes of the hill components, rad (wavelengths 800, 2300, 5100 m).
    pub hill_grade_rad: [f64; 3],
    /// Pitch per m/s^2 of forward acceleration (squat; dive when braking), rad.
    pub pitch_per_accel_rad: f64,
    /// Roll per m/s^2 of lateral acceleration (body leans out of the turn), rad.
    pub roll_per_lateral_rad: f64,
    /// Platform vibration; `null` for none.
    pub vibration: Option<VibrationConfig>,
}

impl Default for TrajectoryConfig {
    fn default() -> Self {
        Self {
            start_lat_deg: 46.5191,
            start_lon_deg: 6.5668,
            start_h_m: 400.0,
            start_yaw_deg: 30.0,
            mount_roll_pitch_deg: [0.0, 0.0],
            initial_stop_s: 30.0,
            cruise_speed_m_s: [8.0, 25.0],
            max_accel_m_s2: 2.5,
            max_brake_m_s2: 3.5,
            max_lateral_m_s2: 3.0,
            hill_grade_rad: [0.02, 0.03, 0.015],
            pitch_per_accel_rad: 0.004,
            roll_per_lateral_rad: 0.008,
            vibration: Some(VibrationConfig::default()),
        }
    }
}

/// Yaw-rate shape within a segment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum YawPulse {
    None,
    /// Raised-cosine yaw rate `peak sin^2(pi u / T)`: heading changes by `peak T / 2`.
    Turn {
        peak_rate_rad_s: f64,
    },
    /// Yaw rate `peak sin(x) (1 - cos x) / 2`, `x = 2 pi u / T`: one positive and one
    /// negative lobe, so the heading returns and the car shifts sideways. The rate starts and
    /// ends with zero slope, so roll rate (which follows speed times yaw rate) stays
    /// continuous.
    LaneChange {
        peak_rate_rad_s: f64,
    },
}

/// What a segment is, for the truth file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Manoeuvre {
    Stop,
    Accelerate,
    Brake,
    SpeedChange,
    Cruise,
    Curve,
    Turn,
    LaneChange,
}

/// One piece of the script: over `[t0_s, t0_s + duration_s)` the forward acceleration is
/// `accel_peak sin^2(pi u / T)` and the yaw rate follows `yaw`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    pub manoeuvre: Manoeuvre,
    pub t0_s: f64,
    /// Length, s (infinite for the last segment).
    pub duration_s: f64,
    pub speed0_m_s: f64,
    pub distance0_m: f64,
    pub yaw0_rad: f64,
    pub accel_peak_m_s2: f64,
    pub yaw: YawPulse,
}

struct SegmentJets {
    speed: Jet,
    accel: Jet,
    distance: Jet,
    yaw: Jet,
    yaw_rate: Jet,
}

impl Segment {
    fn jets(&self, t: f64) -> SegmentJets {
        let u = Jet::variable(t - self.t0_s);
        let mut speed = Jet::constant(self.speed0_m_s);
        let mut accel = Jet::constant(0.0);
        let mut distance = u * self.speed0_m_s + self.distance0_m;
        let mut yaw = Jet::constant(self.yaw0_rad);
        let mut yaw_rate = Jet::constant(0.0);
        if self.duration_s.is_finite() {
            let w = 2.0 * PI / self.duration_s;
            let (s, c) = (u * w).sin_cos();
            if self.accel_peak_m_s2 != 0.0 {
                let a = self.accel_peak_m_s2;
                accel = (-c + 1.0) * (0.5 * a);
                speed = speed + (u - s * (1.0 / w)) * (0.5 * a);
                distance = distance + (u * u * 0.5 + (c + -1.0) * (1.0 / (w * w))) * (0.5 * a);
            }
            match self.yaw {
                YawPulse::None => {}
                YawPulse::Turn { peak_rate_rad_s: r } => {
                    yaw_rate = (-c + 1.0) * (0.5 * r);
                    yaw = yaw + (u - s * (1.0 / w)) * (0.5 * r);
                }
                YawPulse::LaneChange { peak_rate_rad_s: r } => {
                    let one_minus_c = -c + 1.0;
                    yaw_rate = s * one_minus_c * (0.5 * r);
                    yaw = yaw + (one_minus_c - s * s * 0.5) * (0.5 * r / w);
                }
            }
        }
        SegmentJets {
            speed,
            accel,
            distance,
            yaw,
            yaw_rate,
        }
    }

    /// Speed, distance and heading at the segment's end.
    fn end_state(&self) -> (f64, f64, f64) {
        let j = self.jets(self.t0_s + self.duration_s);
        (j.speed.value(), j.distance.value(), j.yaw.value())
    }
}

/// Everything true about the platform (the reference IMU's b-frame) at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    /// Time, s (GPS time of the simulation).
    pub t_s: f64,
    pub lat_rad: f64,
    pub lon_rad: f64,
    pub h_m: f64,
    /// Velocity w.r.t. the Earth in NED, m/s.
    pub v_ned_m_s: Vector3<f64>,
    /// Time derivative of the NED velocity components, m/s^2.
    pub accel_ned_m_s2: Vector3<f64>,
    /// Jerk: time derivative of `accel_ned_m_s2`, m/s^3.
    pub jerk_ned_m_s3: Vector3<f64>,
    /// Roll, pitch, yaw (Z-Y-X) of body w.r.t. NED, rad; yaw wrapped to (-pi, pi].
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub yaw_rad: f64,
    /// C_b^n, body to NED.
    pub c_bn: Matrix3<f64>,
    /// Angular rate of body w.r.t. inertial space, body frame, rad/s.
    pub omega_ib_b_rad_s: Vector3<f64>,
    /// Its time derivative (angular acceleration), rad/s^2.
    pub omega_dot_ib_b_rad_s2: Vector3<f64>,
    /// Its second time derivative (angular jerk), rad/s^3.
    pub omega_ddot_ib_b_rad_s3: Vector3<f64>,
    /// Specific force, body frame, m/s^2.
    pub f_b_m_s2: Vector3<f64>,
    /// Time derivative of the body-frame specific force components, m/s^3.
    pub f_dot_b_m_s3: Vector3<f64>,
    /// Ground speed along the path, m/s.
    pub speed_m_s: f64,
}

/// A trajectory ready to be evaluated at any time in `[.., end_s]`.
#[derive(Debug, Clone)]
pub struct Trajectory {
    pub scenario: Scenario,
    pub config: TrajectoryConfig,
    pub segments: Vec<Segment>,
    /// Hill components (grade amplitude rad, wavenumber rad/m, phase rad).
    hills: Vec<(f64, f64, f64)>,
    /// Vibration lines with realised frequencies and phases (displacement, roll, pitch).
    vibration: [Vec<(MotionLine, f64)>; 3],
    grid_dt_s: f64,
    /// (lat, lon, h_base) and their time derivatives at grid nodes from t = 0.
    grid: Vec<([f64; 3], [f64; 3])>,
}

const GRID_DT_S: f64 = 0.01;

impl Trajectory {
    /// Builds the scenario's script from `seed` and integrates position up to `end_s`.
    pub fn new(
        scenario: Scenario,
        config: TrajectoryConfig,
        duration_s: f64,
        end_s: f64,
        seed: u64,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7261_6a65_6374_6f72);
        let yaw0 = config.start_yaw_deg.to_radians();
        let (segments, hills, vibration) = match scenario {
            Scenario::Static => (
                vec![Segment {
                    manoeuvre: Manoeuvre::Stop,
                    t0_s: 0.0,
                    duration_s: f64::INFINITY,
                    speed0_m_s: 0.0,
                    distance0_m: 0.0,
                    yaw0_rad: yaw0,
                    accel_peak_m_s2: 0.0,
                    yaw: YawPulse::None,
                }],
                Vec::new(),
                [Vec::new(), Vec::new(), Vec::new()],
            ),
            Scenario::Car => {
                let segments = script(&config, duration_s, &mut rng);
                let wavelengths = [800.0, 2300.0, 5100.0];
                let hills = config
                    .hill_grade_rad
                    .iter()
                    .zip(wavelengths)
                    .map(|(&g, l)| {
                        (
                            g * rng.random_range(0.7..1.3),
                            2.0 * PI / (l * rng.random_range(0.8..1.25)),
                            rng.random_range(0.0..2.0 * PI),
                        )
                    })
                    .collect();
                let mut realise = |lines: &[MotionLine]| -> Vec<(MotionLine, f64)> {
                    lines
                        .iter()
                        .map(|l| {
                            let mut l = *l;
                            l.frequency_hz *= rng.random_range(0.9..1.1);
                            (l, rng.random_range(0.0..2.0 * PI))
                        })
                        .collect()
                };
                let vibration = match &config.vibration {
                    Some(v) => [
                        realise(&v.vertical_m),
                        realise(&v.roll_rad),
                        realise(&v.pitch_rad),
                    ],
                    None => [Vec::new(), Vec::new(), Vec::new()],
                };
                (segments, hills, vibration)
            }
        };
        let mut trajectory = Trajectory {
            scenario,
            config,
            segments,
            hills,
            vibration,
            grid_dt_s: GRID_DT_S,
            grid: Vec::new(),
        };
        trajectory.integrate_position(end_s.max(0.0) + 2.0 * GRID_DT_S);
        trajectory
    }

    /// Last time at which the trajectory is defined, s.
    pub fn end_s(&self) -> f64 {
        (self.grid.len().saturating_sub(1)) as f64 * self.grid_dt_s
    }

    /// Vibration lines as realised (line, phase rad) for the truth file:
    /// [vertical displacement m, roll rad, pitch rad].
    pub fn vibration_lines(&self) -> &[Vec<(MotionLine, f64)>; 3] {
        &self.vibration
    }

    /// Hill components as realised: (grade amplitude rad, wavelength m, phase rad).
    pub fn hills(&self) -> Vec<(f64, f64, f64)> {
        self.hills
            .iter()
            .map(|&(g, k, p)| (g, 2.0 * PI / k, p))
            .collect()
    }

    fn segment(&self, t: f64) -> &Segment {
        let i = self.segments.partition_point(|s| s.t0_s <= t);
        &self.segments[i.saturating_sub(1)]
    }

    fn grade(&self, distance: Jet) -> Jet {
        let mut g = Jet::constant(0.0);
        for &(amp, k, phase) in &self.hills {
            g = g + (distance * k + phase).sin() * amp;
        }
        g
    }

    /// Velocity of the path without vibration (plain values), NED m/s.
    fn base_velocity(&self, t: f64) -> Vector3<f64> {
        let seg = self.segment(t);
        let j = seg.jets(t);
        let grade = self.grade(j.distance).value();
        let v = j.speed.value();
        let (sy, cy) = j.yaw.value().sin_cos();
        let (sg, cg) = grade.sin_cos();
        Vector3::new(v * cg * cy, v * cg * sy, -v * sg)
    }

    fn position_rate(&self, t: f64, y: [f64; 3]) -> [f64; 3] {
        let v = self.base_velocity(t);
        let (lat, lon, h) = position_rates(y[0], y[2], &v).unwrap_or((0.0, 0.0, 0.0));
        [lat, lon, h]
    }

    fn integrate_position(&mut self, end_s: f64) {
        let n = (end_s / self.grid_dt_s).ceil() as usize + 1;
        let dt = self.grid_dt_s;
        let mut y = [
            self.config.start_lat_deg.to_radians(),
            self.config.start_lon_deg.to_radians(),
            self.config.start_h_m,
        ];
        let mut grid = Vec::with_capacity(n);
        let add =
            |y: [f64; 3], k: [f64; 3], s: f64| [y[0] + s * k[0], y[1] + s * k[1], y[2] + s * k[2]];
        for i in 0..n {
            let t = i as f64 * dt;
            let k1 = self.position_rate(t, y);
            grid.push((y, k1));
            let k2 = self.position_rate(t + 0.5 * dt, add(y, k1, 0.5 * dt));
            let k3 = self.position_rate(t + 0.5 * dt, add(y, k2, 0.5 * dt));
            let k4 = self.position_rate(t + dt, add(y, k3, dt));
            for j in 0..3 {
                y[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
            }
        }
        self.grid = grid;
    }

    /// (lat, lon, h without vibration) at `t` by cubic Hermite interpolation of the grid.
    fn base_position(&self, t: f64) -> [f64; 3] {
        if t <= 0.0 {
            // The script starts at rest, so the start position holds for all earlier times.
            return self.grid[0].0;
        }
        let x = t / self.grid_dt_s;
        let i = (x.floor() as usize).min(self.grid.len() - 2);
        let s = x - i as f64;
        let (y0, d0) = self.grid[i];
        let (y1, d1) = self.grid[i + 1];
        let h = self.grid_dt_s;
        let (s2, s3) = (s * s, s * s * s);
        let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
        let h10 = s3 - 2.0 * s2 + s;
        let h01 = -2.0 * s3 + 3.0 * s2;
        let h11 = s3 - s2;
        [0, 1, 2].map(|k| h00 * y0[k] + h10 * h * d0[k] + h01 * y1[k] + h11 * h * d1[k])
    }

    /// Ground speed at `t`, m/s (cheap: no attitude or position).
    pub fn speed_m_s(&self, t: f64) -> f64 {
        self.segment(t).jets(t).speed.value()
    }

    /// The exact kinematic state at time `t` (s). Defined for `t <= end_s()`; before 0 the
    /// platform is at rest in its start state.
    pub fn truth(&self, t: f64) -> Truth {
        let seg = self.segment(t);
        let j = seg.jets(t);
        let grade = self.grade(j.distance);
        let time = Jet::variable(t);

        // Vibration: displacement d (NED down) and its derivative, roll and pitch parts.
        let line = |lines: &[(MotionLine, f64)]| -> (Jet, Jet) {
            let mut x = Jet::constant(0.0);
            let mut dx = Jet::constant(0.0);
            for (l, phase) in lines {
                let w = 2.0 * PI * l.frequency_hz;
                let m = j.speed * l.amplitude_per_m_s + l.amplitude_at_rest;
                let dm = j.accel * l.amplitude_per_m_s;
                let (s, c) = (time * w + *phase).sin_cos();
                x = x + m * s;
                dx = dx + dm * s + m * c * w;
            }
            (x, dx)
        };
        // Roll and pitch need only the displacement itself (their rates come from the jets),
        // so their lines skip the rate terms: the same operations on the same values as
        // `line(..).0`, hence the same bits.
        let line_value = |lines: &[(MotionLine, f64)]| -> Jet {
            let mut x = Jet::constant(0.0);
            for (l, phase) in lines {
                let w = 2.0 * PI * l.frequency_hz;
                let m = j.speed * l.amplitude_per_m_s + l.amplitude_at_rest;
                let (s, _) = (time * w + *phase).sin_cos();
                x = x + m * s;
            }
            x
        };
        let (d_vib, d_vib_rate) = line(&self.vibration[0]);
        let roll_vib = line_value(&self.vibration[1]);
        let pitch_vib = line_value(&self.vibration[2]);

        let cfg = &self.config;
        let lateral = j.speed * j.yaw_rate;
        let roll = -lateral * cfg.roll_per_lateral_rad
            + cfg.mount_roll_pitch_deg[0].to_radians()
            + roll_vib;
        let pitch = grade
            + j.accel * cfg.pitch_per_accel_rad
            + cfg.mount_roll_pitch_deg[1].to_radians()
            + pitch_vib;
        let yaw = j.yaw;

        let (sg, cg) = grade.sin_cos();
        let (sy, cy) = yaw.sin_cos();
        let v: JetVec3 = [
            j.speed * cg * cy,
            j.speed * cg * sy,
            -(j.speed * sg) + d_vib_rate,
        ];
        let v_dot: JetVec3 = v.map(Jet::derivative);

        // Position: the integrated path plus the vibration displacement.
        let [lat, lon, h_base] = self.base_position(t);
        let h = h_base - d_vib.value();
        let (lat_rate, _, _) = position_rates(
            lat,
            h,
            &Vector3::new(v[0].value(), v[1].value(), v[2].value()),
        )
        .unwrap_or((0.0, 0.0, 0.0));
        let lat_j = Jet([lat, lat_rate, 0.0, 0.0]);
        let h_j = Jet::constant(h) + (-v[2]).integral_shift();

        // Earth rate and transport rate in NED, as jets (first derivative exact).
        let (s_lat, c_lat) = lat_j.sin_cos();
        let omega_ie: JetVec3 = [
            c_lat * WGS84_OMEGA_IE_RAD_S,
            Jet::constant(0.0),
            -(s_lat * WGS84_OMEGA_IE_RAD_S),
        ];
        let w2 = (-(s_lat * s_lat) * WGS84_E2 + 1.0).sqrt();
        let r_e = w2.recip() * WGS84_A_M;
        let r_n = (w2 * w2 * w2).recip() * (WGS84_A_M * (1.0 - WGS84_E2));
        let re_h = (r_e + h_j).recip();
        let rn_h = (r_n + h_j).recip();
        let omega_en: JetVec3 = [
            v[1] * re_h,
            -(v[0] * rn_h),
            -(v[1] * (s_lat / c_lat) * re_h),
        ];
        let omega_in: JetVec3 = [0, 1, 2].map(|k| omega_ie[k] + omega_en[k]);

        // C_b^n from Z-Y-X Euler angles, as jets (rows).
        let (sr, cr) = roll.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        let c_bn: [JetVec3; 3] = [
            [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
            [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
            [-sp, sr * cp, cr * cp],
        ];
        let (roll_d, pitch_d, yaw_d) = (roll.derivative(), pitch.derivative(), yaw.derivative());
        let omega_nb_b: JetVec3 = [
            roll_d - yaw_d * sp,
            pitch_d * cr + yaw_d * sr * cp,
            -(pitch_d * sr) + yaw_d * cr * cp,
        ];
        let omega_in_b = mat_t_vec(&c_bn, &omega_in);
        let omega_ib_b: JetVec3 = [0, 1, 2].map(|k| omega_nb_b[k] + omega_in_b[k]);

        let g = normal_gravity_m_s2(lat, h);
        let coriolis_rate: JetVec3 = [0, 1, 2].map(|k| omega_ie[k] * 2.0 + omega_en[k]);
        let cor = cross(&coriolis_rate, &v);
        let f_n: JetVec3 = [v_dot[0] + cor[0], v_dot[1] + cor[1], v_dot[2] + cor[2] + -g];
        let f_b = mat_t_vec(&c_bn, &f_n);

        let vec = |v: &JetVec3, k: usize| Vector3::from(order(v, k));
        let wrap = |a: f64| {
            let w = (a + PI).rem_euclid(2.0 * PI) - PI;
            if w <= -PI {
                w + 2.0 * PI
            } else {
                w
            }
        };
        Truth {
            t_s: t,
            lat_rad: lat,
            lon_rad: lon,
            h_m: h,
            v_ned_m_s: vec(&v, 0),
            accel_ned_m_s2: vec(&v, 1),
            jerk_ned_m_s3: vec(&v, 2),
            roll_rad: roll.value(),
            pitch_rad: pitch.value(),
            yaw_rad: wrap(yaw.value()),
            c_bn: Matrix3::from_fn(|r, c| c_bn[r][c].value()),
            omega_ib_b_rad_s: vec(&omega_ib_b, 0),
            omega_dot_ib_b_rad_s2: vec(&omega_ib_b, 1),
            omega_ddot_ib_b_rad_s3: vec(&omega_ib_b, 2),
            f_b_m_s2: vec(&f_b, 0),
            f_dot_b_m_s3: vec(&f_b, 1),
            speed_m_s: j.speed.value(),
        }
    }
}

impl Jet {
    /// The jet of a function whose derivative is `self` and whose value is 0 here (orders
    /// 1..=3 of the result are `self`'s orders 0..=2).
    fn integral_shift(self) -> Jet {
        Jet([0.0, self.0[0], self.0[1], self.0[2]])
    }
}

/// The car between two segments: speed, along-track distance and heading.
#[derive(Debug, Clone, Copy)]
struct CarState {
    speed_m_s: f64,
    distance_m: f64,
    yaw_rad: f64,
}

/// The driver's limits, from the configuration (accelerations at least 0.5 m/s^2).
struct DrivingLimits {
    /// Cruise speeds drawn from, m/s.
    cruise_lo_m_s: f64,
    cruise_hi_m_s: f64,
    /// Largest forward acceleration, braking and lateral acceleration, m/s^2.
    accel_m_s2: f64,
    brake_m_s2: f64,
    lateral_m_s2: f64,
}

impl DrivingLimits {
    fn of(cfg: &TrajectoryConfig) -> Self {
        let [cruise_lo_m_s, cruise_hi_m_s] = cfg.cruise_speed_m_s;
        Self {
            cruise_lo_m_s,
            cruise_hi_m_s,
            accel_m_s2: cfg.max_accel_m_s2.max(0.5),
            brake_m_s2: cfg.max_brake_m_s2.max(0.5),
            lateral_m_s2: cfg.max_lateral_m_s2.max(0.5),
        }
    }

    fn cruise_speed_m_s(&self, rng: &mut ChaCha8Rng) -> f64 {
        rng.random_range(self.cruise_lo_m_s..=self.cruise_hi_m_s)
    }
}

/// A script being written: the segments so far, the time they reach and the car's state
/// there.
struct ScriptWriter {
    segments: Vec<Segment>,
    t_s: f64,
    state: CarState,
}

impl ScriptWriter {
    fn new(yaw_rad: f64) -> Self {
        Self {
            segments: Vec::new(),
            t_s: 0.0,
            state: CarState {
                speed_m_s: 0.0,
                distance_m: 0.0,
                yaw_rad,
            },
        }
    }

    fn speed_m_s(&self) -> f64 {
        self.state.speed_m_s
    }

    /// Appends a segment starting where the script ends; a brake ends at rest exactly.
    fn push(&mut self, manoeuvre: Manoeuvre, duration_s: f64, accel_peak_m_s2: f64, yaw: YawPulse) {
        let seg = Segment {
            manoeuvre,
            t0_s: self.t_s,
            duration_s,
            speed0_m_s: self.state.speed_m_s,
            distance0_m: self.state.distance_m,
            yaw0_rad: self.state.yaw_rad,
            accel_peak_m_s2,
            yaw,
        };
        let (speed_m_s, distance_m, yaw_rad) = seg.end_state();
        self.state = CarState {
            speed_m_s: if manoeuvre == Manoeuvre::Brake {
                0.0
            } else {
                speed_m_s
            },
            distance_m,
            yaw_rad,
        };
        self.t_s += duration_s;
        self.segments.push(seg);
    }
}

/// The manoeuvre script of a car run: an initial stop, then from rest a drive-off and while
/// moving a random pick of cruise or curve, speed change, stop, intersection turn or lane
/// change, until `duration_s`; the last segment holds speed and heading for ever.
fn script(cfg: &TrajectoryConfig, duration_s: f64, rng: &mut ChaCha8Rng) -> Vec<Segment> {
    let limits = DrivingLimits::of(cfg);
    let mut w = ScriptWriter::new(cfg.start_yaw_deg.to_radians());
    w.push(
        Manoeuvre::Stop,
        cfg.initial_stop_s.max(0.0),
        0.0,
        YawPulse::None,
    );
    while w.t_s < duration_s {
        if w.speed_m_s() <= 0.0 {
            drive_off(&mut w, &limits, rng);
            continue;
        }
        let pick: f64 = rng.random();
        if pick < 0.30 {
            cruise_or_curve(&mut w, &limits, rng);
        } else if pick < 0.45 {
            change_speed(&mut w, &limits, rng);
        } else if pick < 0.65 {
            stop(&mut w, &limits, rng);
        } else if pick < 0.85 {
            turn_at_intersection(&mut w, &limits, rng);
        } else {
            change_lane(&mut w, &limits, rng);
        }
    }
    // Hold the final speed and heading indefinitely, so the truth exists past the end.
    let last = if w.speed_m_s() > 0.0 {
        Manoeuvre::Cruise
    } else {
        Manoeuvre::Stop
    };
    w.push(last, f64::INFINITY, 0.0, YawPulse::None);
    w.segments
}

/// From rest, accelerate to a cruise speed.
fn drive_off(w: &mut ScriptWriter, limits: &DrivingLimits, rng: &mut ChaCha8Rng) {
    let target = limits.cruise_speed_m_s(rng);
    let a = rng.random_range(0.5 * limits.accel_m_s2..=limits.accel_m_s2);
    w.push(Manoeuvre::Accelerate, 2.0 * target / a, a, YawPulse::None);
}

/// Keep the speed for 5 to 25 s, on a straight or through a curve.
fn cruise_or_curve(w: &mut ScriptWriter, limits: &DrivingLimits, rng: &mut ChaCha8Rng) {
    let v = w.speed_m_s();
    let duration = rng.random_range(5.0..25.0);
    if rng.random_bool(0.5) {
        // A curve: heading change limited so the peak lateral acceleration v r stays within
        // half the limit.
        let max_rate = 0.5 * limits.lateral_m_s2 / v;
        let change: f64 = rng.random_range(-0.6..0.6);
        let rate = (2.0 * change / duration).clamp(-max_rate, max_rate);
        w.push(
            Manoeuvre::Curve,
            duration,
            0.0,
            YawPulse::Turn {
                peak_rate_rad_s: rate,
            },
        );
    } else {
        w.push(Manoeuvre::Cruise, duration, 0.0, YawPulse::None);
    }
}

/// Speed up or slow down to a new cruise speed (nothing when it is within 1 m/s).
fn change_speed(w: &mut ScriptWriter, limits: &DrivingLimits, rng: &mut ChaCha8Rng) {
    let target = limits.cruise_speed_m_s(rng);
    let dv = target - w.speed_m_s();
    if dv.abs() < 1.0 {
        return;
    }
    let a = if dv > 0.0 {
        rng.random_range(0.3 * limits.accel_m_s2..=0.7 * limits.accel_m_s2)
    } else {
        -rng.random_range(0.3 * limits.brake_m_s2..=0.6 * limits.brake_m_s2)
    };
    w.push(Manoeuvre::SpeedChange, 2.0 * dv / a, a, YawPulse::None);
}

/// Brake to rest and wait 5 to 45 s (a red light).
fn stop(w: &mut ScriptWriter, limits: &DrivingLimits, rng: &mut ChaCha8Rng) {
    let v = w.speed_m_s();
    let a = rng.random_range(0.4 * limits.brake_m_s2..=limits.brake_m_s2);
    w.push(Manoeuvre::Brake, 2.0 * v / a, -a, YawPulse::None);
    let wait = rng.random_range(5.0..45.0);
    w.push(Manoeuvre::Stop, wait, 0.0, YawPulse::None);
}

/// Slow down for the intersection, then turn 90 deg left or right.
fn turn_at_intersection(w: &mut ScriptWriter, limits: &DrivingLimits, rng: &mut ChaCha8Rng) {
    let v = w.speed_m_s();
    let turn_speed = rng.random_range(5.0..8.0f64).min(v);
    if v - turn_speed > 0.5 {
        let a = rng.random_range(0.3 * limits.brake_m_s2..=0.6 * limits.brake_m_s2);
        w.push(
            Manoeuvre::SpeedChange,
            2.0 * (v - turn_speed) / a,
            -a,
            YawPulse::None,
        );
    }
    let v = w.speed_m_s();
    let change = if rng.random_bool(0.5) {
        PI / 2.0
    } else {
        -PI / 2.0
    };
    let min_duration = 2.0 * change.abs() * v / limits.lateral_m_s2;
    let duration = rng.random_range(4.0..8.0f64).max(min_duration);
    w.push(
        Manoeuvre::Turn,
        duration,
        0.0,
        YawPulse::Turn {
            peak_rate_rad_s: 2.0 * change / duration,
        },
    );
}

/// Change lane by 3.5 m: lateral offset ~ 3 v r T^2 / (16 pi); the yaw-rate shape peaks at
/// 0.65 r.
fn change_lane(w: &mut ScriptWriter, limits: &DrivingLimits, rng: &mut ChaCha8Rng) {
    let v = w.speed_m_s();
    let duration = rng.random_range(3.0..6.0f64);
    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let rate = (16.0 * PI * 3.5 / (3.0 * v * duration * duration))
        .min(limits.lateral_m_s2 / (0.65 * v))
        * side;
    w.push(
        Manoeuvre::LaneChange,
        duration,
        0.0,
        YawPulse::LaneChange {
            peak_rate_rad_s: rate,
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn car(seconds: f64, seed: u64) -> Trajectory {
        Trajectory::new(
            Scenario::Car,
            TrajectoryConfig::default(),
            seconds,
            seconds + 1.0,
            seed,
        )
    }

    #[test]
    fn the_script_is_reproducible_and_seed_dependent() {
        let a = car(600.0, 7);
        let b = car(600.0, 7);
        let c = car(600.0, 8);
        assert_eq!(a.segments, b.segments);
        assert_ne!(a.segments, c.segments);
        assert_eq!(a.truth(321.0), b.truth(321.0));
    }

    #[test]
    fn the_car_does_what_cars_do() {
        let traj = car(1800.0, 3);
        let kinds: std::collections::HashSet<_> =
            traj.segments.iter().map(|s| s.manoeuvre).collect();
        for m in [
            Manoeuvre::Stop,
            Manoeuvre::Accelerate,
            Manoeuvre::Brake,
            Manoeuvre::Turn,
            Manoeuvre::LaneChange,
            Manoeuvre::Curve,
        ] {
            assert!(kinds.contains(&m), "{m:?} missing from {kinds:?}");
        }
        let mut max_speed: f64 = 0.0;
        let mut max_lat: f64 = 0.0;
        let mut h_range = (f64::MAX, f64::MIN);
        let mut t = 0.0;
        while t < 1800.0 {
            let tr = traj.truth(t);
            assert!(
                tr.speed_m_s >= -1e-9,
                "negative speed {} at {t}",
                tr.speed_m_s
            );
            max_speed = max_speed.max(tr.speed_m_s);
            let seg = traj.segment(t).jets(t);
            max_lat = max_lat.max((seg.speed * seg.yaw_rate).value().abs());
            h_range = (h_range.0.min(tr.h_m), h_range.1.max(tr.h_m));
            t += 0.37;
        }
        assert!(max_speed <= 25.0 + 1e-9 && max_speed > 15.0, "{max_speed}");
        assert!(max_lat <= 3.0 + 1e-9, "{max_lat}");
        assert!(h_range.1 - h_range.0 > 5.0, "no hills: {h_range:?}");
    }

    #[test]
    fn derivatives_are_consistent_with_the_values() {
        // omega_dot and f_dot against central differences of omega and f.
        let traj = car(400.0, 11);
        for &t in &[45.3, 77.7, 150.05, 222.2, 310.9] {
            let h = 2e-5;
            let (a, b, m) = (traj.truth(t - h), traj.truth(t + h), traj.truth(t));
            let dw = (b.omega_ib_b_rad_s - a.omega_ib_b_rad_s) / (2.0 * h);
            let df = (b.f_b_m_s2 - a.f_b_m_s2) / (2.0 * h);
            let dv = (b.v_ned_m_s - a.v_ned_m_s) / (2.0 * h);
            assert!(
                (dw - m.omega_dot_ib_b_rad_s2).norm()
                    < 1e-4 * (1.0 + m.omega_dot_ib_b_rad_s2.norm()),
                "t {t}: {dw} vs {}",
                m.omega_dot_ib_b_rad_s2
            );
            assert!(
                (df - m.f_dot_b_m_s3).norm() < 1e-3 * (1.0 + m.f_dot_b_m_s3.norm()),
                "t {t}: {df} vs {}",
                m.f_dot_b_m_s3
            );
            assert!(
                (dv - m.accel_ned_m_s2).norm() < 1e-5,
                "t {t}: {dv} vs {}",
                m.accel_ned_m_s2
            );
            let dlat = (traj.truth(t + 1e-3).lat_rad - traj.truth(t - 1e-3).lat_rad) / 2e-3;
            let (rate, _, _) = position_rates(m.lat_rad, m.h_m, &m.v_ned_m_s).unwrap();
            assert_relative_eq!(dlat, rate, epsilon = 1e-12);
        }
    }

    #[test]
    fn at_rest_the_imu_measures_earth_rate_and_gravity() {
        let traj = Trajectory::new(Scenario::Static, TrajectoryConfig::default(), 10.0, 11.0, 0);
        let tr = traj.truth(5.0);
        let lat = TrajectoryConfig::default().start_lat_deg.to_radians();
        assert_relative_eq!(
            tr.omega_ib_b_rad_s.norm(),
            WGS84_OMEGA_IE_RAD_S,
            epsilon = 1e-15
        );
        assert_relative_eq!(
            tr.f_b_m_s2.norm(),
            normal_gravity_m_s2(lat, 400.0),
            epsilon = 1e-12
        );
        assert!(tr.f_b_m_s2.z < 0.0);
        assert_eq!(tr.v_ned_m_s, Vector3::zeros());
    }
}
