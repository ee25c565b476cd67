//! The PSINS FOG/MEMS pair (`psins-fog-mems/`): a MEMS IMU's angle and velocity increments
//! at 100 Hz, and a FOG-grade INS solution at 10 Hz, on one vehicle and one time base.
//!
//! Source conventions (PSINS toolbox): navigation frame East-North-Up, body frame
//! right-forward-up (X right, Y forward, Z up), attitude `C_b^n = Rz(yaw) Rx(pitch) Ry(roll)`.
//!
//! MEMS: rate = angle increment / dt and specific force = velocity increment / dt, with
//! dt = 0.01 s (the interval the source states; the `t_s` steps agree to 1e-12 s, which is
//! checked), then RFU -> FRD: x = source y, y = source x, z = -source z. The time of each
//! sample is the source's `t_s`; the rate is the mean over the interval the increment covers.
//!
//! FOG: an interchange file with no IMU channel, only attitude (roll, pitch, yaw of the FRD
//! body w.r.t. NED, from `C_frd^ned = P C_rfu^enu P`, see [`super::frames`]), NED velocity
//! (`vn, ve, -vu`) and position (lat, lon, h as given).

use std::path::Path;

use super::frames::{enu_to_ned, psins_attitude_to_ned, rfu_to_frd};
use super::rows::{collect_one, SensorLayout, SensorRows};
use super::{for_each_column_row, ImportError};
use crate::interchange::ImuRecording;

/// The header of `mems_increments.csv.gz`.
pub const MEMS_COLUMNS: [&str; 7] = [
    "t_s",
    "dtheta_x_rad",
    "dtheta_y_rad",
    "dtheta_z_rad",
    "dv_x_m_s",
    "dv_y_m_s",
    "dv_z_m_s",
];

/// The header of `fog_ins_reference.csv.gz`.
pub const FOG_COLUMNS: [&str; 10] = [
    "t_s",
    "pitch_rad",
    "roll_rad",
    "yaw_rad",
    "ve_m_s",
    "vn_m_s",
    "vu_m_s",
    "lat_rad",
    "lon_rad",
    "h_m",
];

/// The MEMS increment interval, s.
pub const MEMS_DT_S: f64 = 0.01;

/// Largest accepted departure of a `t_s` step from [`MEMS_DT_S`], s (the file's time column
/// is printed with 1e-10 s resolution).
const MEMS_DT_TOLERANCE_S: f64 = 1e-6;

/// Reads the MEMS increments as FRD rates (rad/s) and specific force (m/s^2).
pub fn read_mems(path: &Path) -> Result<ImuRecording, ImportError> {
    collect_one(path, |sink| stream_mems(path, sink))
}

/// Streams the MEMS increments into `sink` as FRD rates and specific force, row by row.
pub(crate) fn stream_mems(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    sink.begin(vec![SensorLayout::imu("")])?;
    let mut previous_t_s: Option<f64> = None;
    let mut row = [0.0; 7];
    for_each_column_row(path, &MEMS_COLUMNS, |line, values| {
        let t_s = values[0];
        if let Some(step) = previous_t_s.map(|p| t_s - p) {
            if (step - MEMS_DT_S).abs() > MEMS_DT_TOLERANCE_S {
                return Err(ImportError::malformed(
                    path,
                    line,
                    format!(
                        "column `t_s`: step {step} s, expected {MEMS_DT_S} s (increments are over 0.01 s)"
                    ),
                ));
            }
        }
        previous_t_s = Some(t_s);
        let omega_rfu = [values[1], values[2], values[3]].map(|d| d / MEMS_DT_S);
        let f_rfu = [values[4], values[5], values[6]].map(|d| d / MEMS_DT_S);
        // A finite increment near f64::MAX overflows when divided by dt (found by fuzzing).
        if let Some(k) = omega_rfu.iter().chain(&f_rfu).position(|v| !v.is_finite()) {
            return Err(ImportError::malformed(
                path,
                line,
                format!(
                    "column `{}`: increment {} over {MEMS_DT_S} s is not a finite rate",
                    MEMS_COLUMNS[1 + k],
                    values[1 + k]
                ),
            ));
        }
        row[0] = t_s;
        row[1..4].copy_from_slice(&rfu_to_frd(omega_rfu));
        row[4..7].copy_from_slice(&rfu_to_frd(f_rfu));
        sink.push(0, &row)
    })
}

/// Reads the FOG INS solution as NED attitude, velocity and position (no IMU channel).
pub fn read_fog(path: &Path) -> Result<ImuRecording, ImportError> {
    collect_one(path, |sink| stream_fog(path, sink))
}

/// Streams the FOG INS solution into `sink`: attitude (rad, FRD w.r.t. NED), position (lat,
/// lon rad, h m) and NED velocity (m/s), row by row.
pub(crate) fn stream_fog(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    sink.begin(vec![SensorLayout {
        name: String::new(),
        columns: vec![
            "t_s",
            "roll_rad",
            "pitch_rad",
            "yaw_rad",
            "lat_rad",
            "lon_rad",
            "h_m",
            "vn_m_s",
            "ve_m_s",
            "vd_m_s",
        ],
        rate_hz: None,
    }])?;
    let mut row = [0.0; 10];
    for_each_column_row(path, &FOG_COLUMNS, |_, v| {
        row[0] = v[0];
        row[1..4].copy_from_slice(&psins_attitude_to_ned(v[1], v[2], v[3]));
        row[4..7].copy_from_slice(&v[7..10]);
        row[7..10].copy_from_slice(&enu_to_ned([v[4], v[5], v[6]]));
        sink.push(0, &row)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mems_increments_become_frd_rates_and_specific_force() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.csv");
        let header = MEMS_COLUMNS.join(",");
        // Right-axis increment 1e-3 rad, forward 2e-3, up 3e-3; dv up 0.098 m/s (1 g at rest).
        std::fs::write(
            &path,
            format!("{header}\n0,1e-3,2e-3,3e-3,0.01,0.02,0.098\n0.01,0,0,0,0,0,0\n"),
        )
        .unwrap();
        let rec = read_mems(&path).unwrap();
        let at0 = |c: &str| rec.channel(c).unwrap()[0];
        let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        close(at0("gx"), 0.2); // forward
        close(at0("gy"), 0.1); // right
        close(at0("gz"), -0.3); // down
        close(at0("ax"), 2.0);
        close(at0("ay"), 1.0);
        close(at0("az"), -9.8); // the down axis reads -g at rest
        assert_eq!(rec.t_s, vec![0.0, 0.01]);

        std::fs::write(
            &path,
            format!("{header}\n0,0,0,0,0,0,0\n0.02,0,0,0,0,0,0\n"),
        )
        .unwrap();
        let msg = read_mems(&path).unwrap_err().to_string();
        assert!(
            msg.contains("m.csv: line 3") && msg.contains("t_s"),
            "{msg}"
        );
    }

    /// Regression (fuzzing): a finite increment near f64::MAX became an infinite rate when
    /// divided by dt and was imported without an error.
    #[test]
    fn an_increment_whose_rate_overflows_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.csv");
        let header = MEMS_COLUMNS.join(",");
        std::fs::write(
            &path,
            format!("{header}\n0,0,0,0,0,0,0\n0.01,0,0,0,0,-1e308,0\n"),
        )
        .unwrap();
        let msg = read_mems(&path).unwrap_err().to_string();
        assert!(
            msg.contains("m.csv: line 3") && msg.contains("`dv_y_m_s`") && msg.contains("finite"),
            "{msg}"
        );
    }

    #[test]
    fn fog_solution_becomes_ned() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.csv");
        let header = FOG_COLUMNS.join(",");
        let yaw = std::f64::consts::FRAC_PI_2; // source +90 deg: facing west
        std::fs::write(
            &path,
            format!("{header}\n0.1,0.1,-0.2,{yaw},-5,1,0.5,0.6,1.9,172\n"),
        )
        .unwrap();
        let rec = read_fog(&path).unwrap();
        assert!(rec.channels().is_empty());
        let att = rec.attitude_rad.as_ref().unwrap();
        let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        close(att[0][0], -0.2);
        close(att[1][0], 0.1);
        close(att[2][0], -yaw);
        let v = rec.velocity_ned_m_s.as_ref().unwrap();
        assert_eq!([v[0][0], v[1][0], v[2][0]], [1.0, -5.0, -0.5]);
        let p = rec.position.as_ref().unwrap();
        assert_eq!([p[0][0], p[1][0], p[2][0]], [0.6, 1.9, 172.0]);
    }
}
