//! The GNSS receiver and the PPS: antenna position and velocity fixes on GPS time with white
//! and Gauss-Markov errors and outages, and the PPS edges as each IMU's clock captures them.

use std::collections::BTreeSet;

use nalgebra::Vector3;
use rand::Rng;
use rand_distr::StandardNormal;

use super::sensors::{stream, ImuRun};
use super::trajectory::Trajectory;
use crate::model::{Effect, GnssModel, PpsModel};
use dynacal_core::nav::{earth_rate_ned_rad_s, radii};

/// GNSS fixes, column by column.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GnssFixes {
    /// GPS time, s.
    pub t_s: Vec<f64>,
    /// Antenna latitude, longitude (rad) and ellipsoidal height (m).
    pub position: [Vec<f64>; 3],
    /// Antenna velocity w.r.t. the Earth, NED, m/s.
    pub velocity_ned_m_s: [Vec<f64>; 3],
    /// The receiver's stated 1-sigma position uncertainty per NED axis, m.
    pub sigma_ned_m: [f64; 3],
    /// The receiver's stated 1-sigma velocity uncertainty per NED axis, m/s.
    pub sigma_v_ned_m_s: [f64; 3],
}

/// Simulates fixes over `[0, duration_s)`.
pub fn simulate_gnss(
    traj: &Trajectory,
    model: &GnssModel,
    duration_s: f64,
    seed: u64,
    global_disabled: &BTreeSet<Effect>,
) -> GnssFixes {
    let mut disabled = global_disabled.clone();
    disabled.extend(model.disabled.iter().copied());
    let on = |effect: Effect| !disabled.contains(&effect);
    let mut rng = stream(seed, 100, 1, 0);
    let dt = 1.0 / model.rate_hz;
    let n = (duration_s * model.rate_hz).floor() as usize;
    let r = Vector3::from(model.lever_arm_b_m);
    let mut fixes = GnssFixes::default();
    let bias_model = model.position_bias.filter(|_| on(Effect::GnssPositionBias));
    let mut bias = Vector3::zeros();
    if let Some(b) = bias_model {
        for k in 0..3 {
            let z: f64 = rng.sample(StandardNormal);
            bias[k] = b.sigma_ned_m[k] * z;
        }
    }
    let white_p = if on(Effect::GnssPositionNoise) {
        model.position_sigma_ned_m
    } else {
        [0.0; 3]
    };
    let white_v = if on(Effect::GnssVelocityNoise) {
        model.velocity_sigma_ned_m_s
    } else {
        [0.0; 3]
    };
    for k in 0..n {
        let t = k as f64 * dt;
        if k > 0 {
            if let Some(b) = bias_model {
                let phi = (-dt / b.tau_s).exp();
                for a in 0..3 {
                    let z: f64 = rng.sample(StandardNormal);
                    bias[a] = phi * bias[a] + b.sigma_ned_m[a] * (1.0 - phi * phi).sqrt() * z;
                }
            }
        }
        let mut noise = [0.0; 6];
        for (a, x) in noise.iter_mut().enumerate() {
            let z: f64 = rng.sample(StandardNormal);
            *x = z * if a < 3 { white_p[a] } else { white_v[a - 3] };
        }
        if on(Effect::GnssOutages) && model.outages.iter().any(|o| t >= o[0] && t < o[1]) {
            continue;
        }
        let tr = traj.truth(t);
        let offset_n = tr.c_bn * r + bias + Vector3::new(noise[0], noise[1], noise[2]);
        let radii = radii(tr.lat_rad);
        let lat = tr.lat_rad + offset_n.x / (radii.meridian_m + tr.h_m);
        let lon = tr.lon_rad + offset_n.y / ((radii.transverse_m + tr.h_m) * tr.lat_rad.cos());
        let h = tr.h_m - offset_n.z;
        let omega_eb_b =
            tr.omega_ib_b_rad_s - tr.c_bn.transpose() * earth_rate_ned_rad_s(tr.lat_rad);
        let v = tr.v_ned_m_s
            + tr.c_bn * omega_eb_b.cross(&r)
            + Vector3::new(noise[3], noise[4], noise[5]);
        fixes.t_s.push(t);
        for (col, x) in fixes.position.iter_mut().zip([lat, lon, h]) {
            col.push(x);
        }
        for (col, x) in fixes.velocity_ned_m_s.iter_mut().zip([v.x, v.y, v.z]) {
            col.push(x);
        }
    }
    let b = bias_model.map_or([0.0; 3], |b| b.sigma_ned_m);
    fixes.sigma_ned_m = [0, 1, 2].map(|a| (white_p[a].powi(2) + b[a].powi(2)).sqrt());
    fixes.sigma_v_ned_m_s = white_v;
    fixes
}

/// PPS edges: GPS second, and each IMU's own time at the edge as its timer captures it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PpsTable {
    pub gps_t_s: Vec<f64>,
    /// (IMU name, its clock reading at each edge, s).
    pub local_t_s: Vec<(String, Vec<f64>)>,
}

/// PPS edges at each whole GPS second in `[1, duration_s)`.
pub fn simulate_pps(
    model: &PpsModel,
    imus: &[ImuRun],
    duration_s: f64,
    seed: u64,
    global_disabled: &BTreeSet<Effect>,
) -> PpsTable {
    let mut rng = stream(seed, 101, 1, 0);
    let jitter = if global_disabled.contains(&Effect::PpsJitter) {
        0.0
    } else {
        model.jitter_s
    };
    let gps_t_s: Vec<f64> = (1..duration_s.ceil() as usize)
        .map(|s| s as f64)
        .filter(|&s| s < duration_s)
        .collect();
    let edges: Vec<f64> = gps_t_s
        .iter()
        .map(|&s| {
            let z: f64 = rng.sample(StandardNormal);
            s + jitter * z
        })
        .collect();
    let q = model.capture_resolution_s;
    let local_t_s = imus
        .iter()
        .map(|imu| {
            (
                imu.name.clone(),
                edges
                    .iter()
                    .map(|&e| (imu.clock.local_time_at(e) / q).floor() * q)
                    .collect(),
            )
        })
        .collect();
    PpsTable { gps_t_s, local_t_s }
}
