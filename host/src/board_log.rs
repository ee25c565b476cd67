//! What the board's fusion logged, as files a user reads and the host's tools take:
//! `nav.csv` (the filter's states, with the column names of the simulator's
//! `reference.csv` plus one `sigma_*` column each, then the biases), `noise.csv` (each
//! unit's own noise level and which units the fused output used), `faults.json` (each
//! fault the fusion confirmed and each unit it took back) and `health.json` (the board's
//! own troubles from its Health frames: a failed or silent IMU, the log sink full, the PPS
//! or the GNSS fix lost, each as an episode with its start and end).
//!
//! Times are GPS seconds as the log's microseconds give them (`decode::seconds_of_us`).
//! Attitude sigmas: the filter's are about the north, east and down axes; roll and pitch
//! sigmas are those turned by the heading (first order, near level), yaw's is the down one.
//!
//! [`state_error`] measures a state against a reference solution (the simulator's truth),
//! with the NEES that says whether the filter's sigmas are honest.

use std::fmt::Write as _;

use dynacal_core::fusion::FUSED_LANE_ID;
use dynacal_core::log::{FaultFrame, FilterState, Header, Health, NoiseFrame};
use dynacal_core::nav::ekf::position_innovation_ned_m;
use dynacal_core::nav::strapdown::NavState;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::Serialize;

use crate::decode::seconds_of_us;
use crate::interchange::ImuRecording;

/// Header of `nav.csv`.
pub const NAV_COLUMNS: &str = "t_s,lat_rad,lon_rad,h_m,vn_m_s,ve_m_s,vd_m_s,roll_rad,pitch_rad,yaw_rad,\
sigma_lat_m,sigma_lon_m,sigma_h_m,sigma_vn_m_s,sigma_ve_m_s,sigma_vd_m_s,sigma_roll_rad,sigma_pitch_rad,sigma_yaw_rad,\
gyro_bias_x_rad_s,gyro_bias_y_rad_s,gyro_bias_z_rad_s,accel_bias_x_m_s2,accel_bias_y_m_s2,accel_bias_z_m_s2,\
sigma_gyro_bias_x_rad_s,sigma_gyro_bias_y_rad_s,sigma_gyro_bias_z_rad_s,\
sigma_accel_bias_x_m_s2,sigma_accel_bias_y_m_s2,sigma_accel_bias_z_m_s2";

/// The text of `nav.csv` from the fused lane's states (None when there are none).
pub fn nav_csv(states: &[FilterState]) -> Option<String> {
    let fused: Vec<&FilterState> = states
        .iter()
        .filter(|s| s.imu_id == FUSED_LANE_ID)
        .collect();
    if fused.is_empty() {
        return None;
    }
    let mut text = String::from(NAV_COLUMNS);
    text.push('\n');
    for s in fused {
        let q = UnitQuaternion::from_quaternion(Quaternion::new(
            f64::from(s.q_nb[0]),
            f64::from(s.q_nb[1]),
            f64::from(s.q_nb[2]),
            f64::from(s.q_nb[3]),
        ));
        let (roll, pitch, yaw) = q.euler_angles();
        let [sn, se, sd] = s.attitude_sigma_rad.map(f64::from);
        let (sin_y, cos_y) = yaw.sin_cos();
        let sigma_roll = (cos_y * cos_y * sn * sn + sin_y * sin_y * se * se).sqrt();
        let sigma_pitch = (sin_y * sin_y * sn * sn + cos_y * cos_y * se * se).sqrt();
        let mut row = vec![
            seconds_of_us(s.t_us),
            s.lat_rad,
            s.lon_rad,
            f64::from(s.h_m),
        ];
        row.extend(s.vel_ned_m_s.map(f64::from));
        row.extend([roll, pitch, yaw]);
        row.extend(s.pos_sigma_m.map(f64::from));
        row.extend(s.vel_sigma_m_s.map(f64::from));
        row.extend([sigma_roll, sigma_pitch, sd]);
        row.extend(s.gyro_bias_rad_s.map(f64::from));
        row.extend(s.accel_bias_m_s2.map(f64::from));
        row.extend(s.gyro_bias_sigma_rad_s.map(f64::from));
        row.extend(s.accel_bias_sigma_m_s2.map(f64::from));
        push_row(&mut text, &row);
    }
    Some(text)
}

/// The text of `noise.csv`: per report, each unit's gyro and accelerometer white noise
/// (standard deviation per sample) and whether it was in the fused output, by the header's
/// IMU ids (None when there are no reports).
pub fn noise_csv(header: &Header, reports: &[NoiseFrame]) -> Option<String> {
    if reports.is_empty() {
        return None;
    }
    let ids: Vec<u8> = header.imus.iter().map(|i| i.imu_id).collect();
    let mut text = String::from("t_s");
    for id in &ids {
        let _ = write!(text, ",gyro_sigma_rad_s_imu{id},accel_sigma_m_s2_imu{id}");
    }
    for id in &ids {
        let _ = write!(text, ",gyro_in_use_imu{id},accel_in_use_imu{id}");
    }
    text.push_str(",still\n");
    for r in reports {
        let mut row = vec![seconds_of_us(r.t_us)];
        for k in 0..ids.len() {
            row.push(f64::from(
                r.gyro_sigma_rad_s.get(k).copied().unwrap_or(f32::NAN),
            ));
            row.push(f64::from(
                r.accel_sigma_m_s2.get(k).copied().unwrap_or(f32::NAN),
            ));
        }
        for k in 0..ids.len() {
            row.push(f64::from((r.in_use >> k) & 1));
            row.push(f64::from((r.in_use >> (3 + k)) & 1));
        }
        row.push(f64::from(u8::from(r.still)));
        push_row(&mut text, &row);
    }
    Some(text)
}

/// One entry of `faults.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FaultEntry {
    /// When the kind was decided (or the unit readmitted), GPS s.
    pub t_s: f64,
    /// When the unit was first suspected and left the fused output, GPS s.
    pub detected_t_s: f64,
    /// "gyro" or "accel".
    pub sensor: &'static str,
    /// The unit's IMU id; None when two units disagreed and which is wrong is unknown.
    pub imu_id: Option<u8>,
    pub axis: Option<u8>,
    /// "stuck", "bias_step", ..., or "readmitted".
    pub kind: &'static str,
}

/// The entries of `faults.json`, units named by the header's IMU ids.
pub fn fault_entries(header: &Header, faults: &[FaultFrame]) -> Vec<FaultEntry> {
    faults
        .iter()
        .map(|f| FaultEntry {
            t_s: seconds_of_us(f.t_us),
            detected_t_s: seconds_of_us(f.detected_t_us),
            sensor: f.sensor_name(),
            imu_id: f
                .unit
                .and_then(|k| header.imus.get(usize::from(k)).map(|i| i.imu_id)),
            axis: f.axis,
            kind: f.kind_name(),
        })
        .collect()
}

/// One stretch of Health reports that all show a trouble (`health.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HealthEpisode {
    /// `imu_fault` (a read failed or an IMU went quiet), `log_backpressure` (frames
    /// dropped), `pps_unlocked`, `no_gnss_fix` or `time_not_gps`.
    pub condition: &'static str,
    /// The first report that shows it, s.
    pub from_t_s: f64,
    /// The first report after it that does not; None when it lasts to the last report.
    pub to_t_s: Option<f64>,
    /// Reports that show it.
    pub reports: usize,
    /// Frames dropped and IMU samples lost from the report before it to its end.
    pub frames_dropped: u32,
    pub samples_overrun: u32,
}

/// The troubles the Health reports show, each condition's episodes in time order.
pub fn health_episodes(health: &[Health]) -> Vec<HealthEpisode> {
    type Shows = fn(&Health) -> bool;
    let conditions: [(&'static str, Shows); 5] = [
        ("imu_fault", |h| h.flags & Health::FLAG_IMU_FAULT != 0),
        ("log_backpressure", |h| {
            h.flags & Health::FLAG_LOG_BACKPRESSURE != 0
        }),
        ("pps_unlocked", |h| h.flags & Health::FLAG_PPS_LOCKED == 0),
        ("no_gnss_fix", |h| h.flags & Health::FLAG_GNSS_FIX == 0),
        ("time_not_gps", |h| h.flags & Health::FLAG_TIME_GPS == 0),
    ];
    let mut episodes = Vec::new();
    for (condition, shows) in conditions {
        let mut open: Option<(usize, usize)> = None;
        for i in 0..=health.len() {
            let showing = health.get(i).is_some_and(shows);
            match (open, showing) {
                (None, true) => open = Some((i, i)),
                (Some((first, _)), true) => open = Some((first, i)),
                (Some((first, last)), false) => {
                    let before = first.checked_sub(1).map(|b| &health[b]);
                    let counts = |f: fn(&Health) -> u32| {
                        f(&health[last]).saturating_sub(before.map_or(0, f))
                    };
                    episodes.push(HealthEpisode {
                        condition,
                        from_t_s: seconds_of_us(health[first].t_us),
                        to_t_s: health.get(i).map(|h| seconds_of_us(h.t_us)),
                        reports: last + 1 - first,
                        frames_dropped: counts(|h| h.frames_dropped),
                        samples_overrun: counts(|h| h.samples_overrun),
                    });
                    open = None;
                }
                (None, false) => {}
            }
        }
    }
    episodes
}

/// A filter state's error against a reference solution: true minus estimated position
/// (NED, m), velocity (NED, m/s) and attitude (rotation vector about NED, rad), with the
/// state's own sigmas for each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateError {
    pub t_s: f64,
    pub position_ned_m: Vector3<f64>,
    pub velocity_ned_m_s: Vector3<f64>,
    pub attitude_rad: Vector3<f64>,
    pub sigma_position_m: Vector3<f64>,
    pub sigma_velocity_m_s: Vector3<f64>,
    pub sigma_attitude_rad: Vector3<f64>,
}

impl StateError {
    /// Normalised estimation error squared of position, velocity and attitude (3 degrees
    /// of freedom each; the filter's diagonal sigmas).
    pub fn nees(&self) -> [f64; 3] {
        let n = |e: &Vector3<f64>, s: &Vector3<f64>| (0..3).map(|a| (e[a] / s[a]).powi(2)).sum();
        [
            n(&self.position_ned_m, &self.sigma_position_m),
            n(&self.velocity_ned_m_s, &self.sigma_velocity_m_s),
            n(&self.attitude_rad, &self.sigma_attitude_rad),
        ]
    }
}

/// The error of `state` against `reference` (a recording with attitude, position and
/// velocity, such as the simulator's `reference.csv`) at the reference sample nearest in
/// time; None when the reference has no navigation columns or no samples.
pub fn state_error(reference: &ImuRecording, state: &FilterState) -> Option<StateError> {
    let (att, pos, vel) = (
        reference.attitude_rad.as_ref()?,
        reference.position.as_ref()?,
        reference.velocity_ned_m_s.as_ref()?,
    );
    let t_s = seconds_of_us(state.t_us);
    let after = reference.t_s.partition_point(|t| *t < t_s);
    let i = match after {
        0 => 0,
        k if k >= reference.len() => reference.len().checked_sub(1)?,
        k if (reference.t_s[k] - t_s).abs() < (t_s - reference.t_s[k - 1]).abs() => k,
        k => k - 1,
    };
    let truth = NavState::<f64>::from_euler(
        att[0][i],
        att[1][i],
        att[2][i],
        Vector3::new(vel[0][i], vel[1][i], vel[2][i]),
        pos[0][i],
        pos[1][i],
        pos[2][i],
    );
    let q = UnitQuaternion::from_quaternion(Quaternion::new(
        f64::from(state.q_nb[0]),
        f64::from(state.q_nb[1]),
        f64::from(state.q_nb[2]),
        f64::from(state.q_nb[3]),
    ));
    let estimate = NavState {
        q_nb: q,
        v_ned_m_s: Vector3::from(state.vel_ned_m_s.map(f64::from)),
        lat_rad: state.lat_rad,
        lon_rad: state.lon_rad,
        h_m: f64::from(state.h_m),
    };
    let v3 = |x: [f32; 3]| Vector3::from(x.map(f64::from));
    Some(StateError {
        t_s,
        position_ned_m: position_innovation_ned_m(
            truth.lat_rad,
            truth.lon_rad,
            truth.h_m,
            &estimate,
        ),
        velocity_ned_m_s: truth.v_ned_m_s - estimate.v_ned_m_s,
        attitude_rad: (truth.q_nb * estimate.q_nb.inverse()).scaled_axis(),
        sigma_position_m: v3(state.pos_sigma_m),
        sigma_velocity_m_s: v3(state.vel_sigma_m_s),
        sigma_attitude_rad: v3(state.attitude_sigma_rad),
    })
}

/// Appends `values` as one CSV row (shortest round-trip decimal; NaN as `NaN`).
fn push_row(text: &mut String, values: &[f64]) {
    for (i, v) in values.iter().enumerate() {
        if i > 0 {
            text.push(',');
        }
        let _ = write!(text, "{v}");
    }
    text.push('\n');
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynacal_core::log::{ImuConfig, PROTOCOL_VERSION};

    fn header() -> Header {
        let imu = |imu_id| ImuConfig {
            imu_id,
            model: "ICM-42688-P".try_into().unwrap(),
            sample_rate_hz: 1000.0,
            gyro_scale_rad_s_per_count: 1e-4,
            accel_scale_m_s2_per_count: 1e-3,
        };
        Header {
            protocol_version: PROTOCOL_VERSION,
            board: "test".try_into().unwrap(),
            imus: [imu(4), imu(5), imu(6)].into_iter().collect(),
        }
    }

    fn state(t_us: u64, yaw: f32) -> FilterState {
        let q = UnitQuaternion::from_euler_angles(0.1f32, -0.2, yaw);
        FilterState {
            t_us,
            imu_id: FUSED_LANE_ID,
            q_nb: [q.w, q.i, q.j, q.k],
            vel_ned_m_s: [1.0, 2.0, 3.0],
            lat_rad: 0.8,
            lon_rad: 0.1,
            h_m: 400.0,
            gyro_bias_rad_s: [1e-3; 3],
            accel_bias_m_s2: [2e-2; 3],
            attitude_sigma_rad: [0.01, 0.02, 0.03],
            vel_sigma_m_s: [0.1; 3],
            pos_sigma_m: [1.0; 3],
            gyro_bias_sigma_rad_s: [1e-4; 3],
            accel_bias_sigma_m_s2: [1e-3; 3],
        }
    }

    #[test]
    fn nav_rows_carry_the_reference_columns_and_turn_tilt_sigmas_by_the_heading() {
        let text = nav_csv(&[
            state(1_500_000, 0.0),
            state(1_600_000, core::f32::consts::FRAC_PI_2),
        ])
        .unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert!(lines[0].starts_with(
            "t_s,lat_rad,lon_rad,h_m,vn_m_s,ve_m_s,vd_m_s,roll_rad,pitch_rad,yaw_rad,sigma_"
        ));
        let cell = |line: &str, name: &str| -> f64 {
            let i = lines[0].split(',').position(|c| c == name).unwrap();
            line.split(',').nth(i).unwrap().parse().unwrap()
        };
        assert_eq!(cell(lines[1], "t_s"), 1.5);
        assert!((cell(lines[1], "roll_rad") - 0.1).abs() < 1e-6);
        assert!((cell(lines[1], "pitch_rad") + 0.2).abs() < 1e-6);
        // Heading north: roll is about north; heading east: roll is about east.
        assert!((cell(lines[1], "sigma_roll_rad") - 0.01).abs() < 1e-6);
        assert!((cell(lines[2], "sigma_roll_rad") - 0.02).abs() < 1e-6);
        assert!((cell(lines[2], "sigma_yaw_rad") - 0.03).abs() < 1e-6);
        let mut other = state(2_000_000, 0.0);
        other.imu_id = 4;
        assert_eq!(nav_csv(&[other]), None);
    }

    #[test]
    fn noise_and_fault_files_name_units_by_their_ids() {
        let report = NoiseFrame {
            t_us: 3_000_000,
            gyro_sigma_rad_s: [0.01, 0.02, 0.03],
            accel_sigma_m_s2: [0.1, 0.2, 0.3],
            in_use: 0b11_1011,
            still: true,
        };
        let text = noise_csv(&header(), &[report]).unwrap();
        let mut lines = text.lines();
        assert_eq!(
            lines.next().unwrap(),
            "t_s,gyro_sigma_rad_s_imu4,accel_sigma_m_s2_imu4,gyro_sigma_rad_s_imu5,accel_sigma_m_s2_imu5,\
gyro_sigma_rad_s_imu6,accel_sigma_m_s2_imu6,gyro_in_use_imu4,accel_in_use_imu4,gyro_in_use_imu5,\
accel_in_use_imu5,gyro_in_use_imu6,accel_in_use_imu6,still"
        );
        assert_eq!(
            lines.next().unwrap(),
            "3,0.009999999776482582,0.10000000149011612,0.019999999552965164,0.20000000298023224,\
0.029999999329447746,0.30000001192092896,1,1,1,1,0,1,1"
        );
        let fault = FaultFrame {
            t_us: 4_000_000,
            detected_t_us: 3_900_000,
            sensor: FaultFrame::SENSOR_GYRO,
            unit: Some(2),
            axis: Some(1),
            kind: 2,
        };
        let entries = fault_entries(&header(), &[fault]);
        assert_eq!(entries[0].imu_id, Some(6));
        assert_eq!((entries[0].sensor, entries[0].kind), ("gyro", "stuck"));
        assert_eq!((entries[0].t_s, entries[0].detected_t_s), (4.0, 3.9));
    }
}
