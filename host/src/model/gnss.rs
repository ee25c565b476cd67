//! The GNSS receiver and its pulse per second, as the simulator runs them.

use serde::{Deserialize, Serialize};

/// First-order Gauss-Markov position error (the slowly wandering part of a GNSS fix).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssBias {
    /// Stationary standard deviation per NED axis, m.
    pub sigma_ned_m: [f64; 3],
    /// Correlation time, s.
    pub tau_s: f64,
}

/// The GNSS receiver: antenna position and velocity fixes on GPS time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssModel {
    /// Fix rate, Hz (1-10 typical).
    pub rate_hz: f64,
    /// Antenna lever arm in the reference body frame, m.
    #[serde(default)]
    pub lever_arm_b_m: [f64; 3],
    /// White position noise per NED axis, m.
    #[serde(default)]
    pub position_sigma_ned_m: [f64; 3],
    /// Correlated position error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_bias: Option<GnssBias>,
    /// White velocity noise per NED axis, m/s.
    #[serde(default)]
    pub velocity_sigma_ned_m_s: [f64; 3],
    /// Intervals [start_s, end_s) without fixes.
    #[serde(default)]
    pub outages: Vec<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disabled: Vec<super::Effect>,
}

impl Default for GnssModel {
    /// A geodetic receiver with a float/fixed carrier-phase solution at 10 Hz.
    fn default() -> Self {
        Self {
            rate_hz: 10.0,
            lever_arm_b_m: [0.0, 0.0, -1.2],
            position_sigma_ned_m: [0.01, 0.01, 0.02],
            position_bias: Some(GnssBias {
                sigma_ned_m: [0.02, 0.02, 0.04],
                tau_s: 60.0,
            }),
            velocity_sigma_ned_m_s: [0.01, 0.01, 0.02],
            outages: Vec::new(),
            disabled: Vec::new(),
        }
    }
}

/// The receiver's pulse per second, captured by each IMU's clock.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PpsModel {
    /// Jitter of the pulse edge w.r.t. the GPS second (standard deviation), s.
    pub jitter_s: f64,
    /// Resolution of the capture by each IMU's timer, s.
    pub capture_resolution_s: f64,
}

impl Default for PpsModel {
    fn default() -> Self {
        Self {
            jitter_s: 20e-9,
            capture_resolution_s: 1e-6,
        }
    }
}
