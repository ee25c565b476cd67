//! The three MEMS units the board's fusion is tested on: their noise (white plus a slow
//! Gauss-Markov bias per channel, at 200 Hz), their mounts (unit 0 defines the body frame,
//! units 1 and 2 are turned and offset from it), the simulator's model of them with a 10 Hz
//! GNSS receiver and the board model that describes them to the fusion.
// Each test file that includes this module uses a part of it.
#![allow(dead_code)]

use dynacal::model::SimModel;
use dynacal_core::board_model::{BoardModel, ChannelNoise};
use nalgebra::Rotation3;

/// Sample rate of every unit, Hz.
pub const RATE_HZ: f64 = 200.0;
/// Units 1 and 2: lever arm (m, body) and boresight (roll, pitch, yaw, deg) from unit 0.
pub const MOUNTS: [([f64; 3], [f64; 3]); 2] = [
    ([0.05, 0.03, 0.0], [0.0, 0.0, 90.0]),
    ([-0.04, 0.06, 0.02], [180.0, 0.0, 20.0]),
];
/// Gyro noise of every channel: white variance per sample, (rad/s)^2, and a Gauss-Markov
/// bias of inverse correlation time 1/s and stationary variance (rad/s)^2.
pub const GYRO_NOISE: Noise = Noise {
    white_sigma2: 2e-6,
    gm_beta_per_s: 0.0033,
    gm_sigma2: 2.5e-7,
};
/// Accelerometer noise of every channel, as [`GYRO_NOISE`] in (m/s^2)^2.
pub const ACCEL_NOISE: Noise = Noise {
    white_sigma2: 4e-4,
    gm_beta_per_s: 0.0033,
    gm_sigma2: 1e-4,
};
/// GNSS white noise per NED axis: position (m) and velocity (m/s).
pub const GNSS_SIGMA_NED: ([f64; 3], [f64; 3]) = ([0.5, 0.5, 1.0], [0.05, 0.05, 0.1]);

/// One channel's noise: white plus a first-order Gauss-Markov bias.
#[derive(Debug, Clone, Copy)]
pub struct Noise {
    /// White-noise variance per sample at [`RATE_HZ`].
    pub white_sigma2: f64,
    /// Inverse correlation time of the bias, 1/s.
    pub gm_beta_per_s: f64,
    /// Stationary variance of the bias.
    pub gm_sigma2: f64,
}

fn stochastic(noise: Noise, unit: &str) -> String {
    format!(
        r#"{{"stochastic": {{"model": "WN+GM", "unit": "{unit}", "sample_rate_hz": {RATE_HZ},
     "processes": [{{"kind": "white_noise", "sigma2": {}}},
                   {{"kind": "gauss_markov", "beta_per_s": {}, "sigma2": {}}}]}}}}"#,
        noise.white_sigma2, noise.gm_beta_per_s, noise.gm_sigma2
    )
}

fn unit(name: &str, lever: [f64; 3], boresight: [f64; 3]) -> String {
    format!(
        r#"{{"name": "{name}", "rate_hz": {RATE_HZ}, "lever_arm_b_m": {lever:?}, "boresight_rpy_deg": {boresight:?},
  "gyro": {}, "accel": {}}}"#,
        stochastic(GYRO_NOISE, "rad/s"),
        stochastic(ACCEL_NOISE, "m/s^2")
    )
}

/// The simulator's model of the three units and a 10 Hz receiver (antenna at the body
/// origin, white errors only) without fixes over `outages` (start, end s).
pub fn sim_model(outages: &[[f64; 2]]) -> SimModel {
    let (p, v) = GNSS_SIGMA_NED;
    let json = format!(
        r#"{{"imus": [{}, {}, {}],
 "gnss": {{"rate_hz": 10, "lever_arm_b_m": [0, 0, 0], "position_sigma_ned_m": {p:?},
   "velocity_sigma_ned_m_s": {v:?}, "outages": {outages:?}}}}}"#,
        unit("u0", [0.0; 3], [0.0; 3]),
        unit("u1", MOUNTS[0].0, MOUNTS[0].1),
        unit("u2", MOUNTS[1].0, MOUNTS[1].1),
    );
    SimModel::from_json(&json, std::path::Path::new("three-units.json")).unwrap()
}

/// The board model of the simulated mounts: unit k's rotation as roll, pitch, yaw of
/// C_b^k (body to unit axes), its lever arm in body axes; the built-in noise, or the
/// simulation's own (`true_noise`).
pub fn board_model(true_noise: bool) -> BoardModel {
    let mut model = BoardModel::built_in(&[0, 1, 2]);
    if true_noise {
        let dt = 1.0 / RATE_HZ;
        let channel = |n: Noise| ChannelNoise {
            white_psd: (n.white_sigma2 * dt) as f32,
            gauss_markov_sigma2: n.gm_sigma2 as f32,
            gauss_markov_tau_s: (1.0 / n.gm_beta_per_s) as f32,
            random_walk_psd: 0.0,
        };
        for unit in model.units.iter_mut() {
            let (g, a) = (channel(GYRO_NOISE), channel(ACCEL_NOISE));
            unit.channels = [g, g, g, a, a, a];
        }
    }
    for (unit, (lever, rpy_deg)) in model.units[1..].iter_mut().zip(MOUNTS) {
        let [r, p, y] = rpy_deg.map(f64::to_radians);
        let c_b_k = Rotation3::from_euler_angles(r, p, y).transpose();
        let (r, p, y) = c_b_k.euler_angles();
        unit.rotation_rpy_rad = [r as f32, p as f32, y as f32];
        unit.lever_arm_m = lever.map(|x| x as f32);
    }
    model
}
