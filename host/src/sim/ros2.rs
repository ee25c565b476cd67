//! A simulation as a ROS2 bag (`dynacal simulate ... --ros2 OUT`), for users whose tools
//! read ROS: each IMU (the reference and the MEMS units) as a `sensor_msgs/Imu` topic
//! `/<imu>/imu` in its own frame `<imu>`, the reference's navigation as a `nav_msgs/Odometry`
//! topic `/reference/odometry` (the body `reference` in the world frame `map`), and the GNSS
//! fixes as a `sensor_msgs/NavSatFix` topic `/gnss/fix`, written with
//! [`crate::import::ros_bag::writer`].
//!
//! Conventions, the inverse of the importer's (`docs/formats.md`, "ROS bags"): stamps are
//! [`ROS_EPOCH_S`] plus the simulation's time (ROS takes a zero stamp for "unset"), the log
//! time equals the stamp; body vectors are turned from forward-right-down to ROS's
//! forward-left-up (y and z negated); the orientation is the body's (forward-left-up) in
//! east-north-up; the odometry's position is east-north-up metres from the first reference
//! sample (the local tangent plane through it, with the ellipsoid's radii there); its twist
//! is in the body frame. Covariances are left unknown (zeros); an Imu states no orientation
//! (covariance element 0 = -1, REP 145). The fixes carry the receiver's stated sigmas as a
//! diagonal covariance (east, north, up).

use std::path::{Path, PathBuf};

use super::SimOutput;
use crate::import::ros_bag::frames::{enu_to_ned, flu_to_frd, ros_of_ned_rpy, rotate_by_ros};
use crate::import::ros_bag::messages::{
    encode_imu_cdr, encode_nav_sat_fix_cdr, encode_odometry_cdr, Header, Imu, NavSatFix, Odometry,
};
use crate::import::ros_bag::writer::{BagWriteError, Ros2BagWriter};

/// The stamp of simulation time 0: 2023-11-14 22:13:20 UTC, s since the Unix epoch.
pub const ROS_EPOCH_S: i128 = 1_700_000_000;

fn stamp_ns(t_s: f64) -> i128 {
    ROS_EPOCH_S * 1_000_000_000 + (t_s * 1e9).round() as i128
}

/// One message to write: its stamp (ns), topic index and bytes.
type Pending = (i128, usize, Vec<u8>);

/// Writes `out` as a ROS2 bag folder `dir`; returns the files written.
pub fn write_ros2_bag(out: &SimOutput, dir: &Path) -> Result<Vec<PathBuf>, BagWriteError> {
    let mut bag = Ros2BagWriter::create(dir)?;
    let mut pending: Vec<Pending> = Vec::new();
    for run in std::iter::once(&out.reference).chain(&out.imus) {
        let topic = bag.add_topic(&format!("/{}/imu", run.name), "sensor_msgs/msg/Imu")?;
        let rec = &run.recording;
        let (Some(gyro), Some(accel)) = (&rec.gyro_rad_s, &rec.accel_m_s2) else {
            continue;
        };
        let mut no_orientation = [0.0; 9];
        no_orientation[0] = -1.0;
        for k in 0..rec.len() {
            let msg = Imu {
                header: Header {
                    stamp_ns: stamp_ns(rec.t_s[k]),
                    frame_id: run.name.clone(),
                },
                orientation: [0.0, 0.0, 0.0, 1.0],
                orientation_covariance: no_orientation,
                angular_velocity: flu_to_frd([gyro[0][k], gyro[1][k], gyro[2][k]]),
                angular_velocity_covariance: [0.0; 9],
                linear_acceleration: flu_to_frd([accel[0][k], accel[1][k], accel[2][k]]),
                linear_acceleration_covariance: [0.0; 9],
            };
            pending.push((msg.header.stamp_ns, topic, encode_imu_cdr(&msg)));
        }
    }
    odometry_messages(out, &mut bag, &mut pending)?;
    fix_messages(out, &mut bag, &mut pending)?;
    // In time order, as a recorder logs them; a stable sort keeps each topic's order.
    pending.sort_by_key(|m| m.0);
    for (stamp, topic, data) in pending {
        bag.write(topic, stamp as u64, &data)?;
    }
    bag.finish()
}

fn odometry_messages(
    out: &SimOutput,
    bag: &mut Ros2BagWriter,
    pending: &mut Vec<Pending>,
) -> Result<(), BagWriteError> {
    let rec = &out.reference.recording;
    let (Some(rpy), Some(pos), Some(vel)) =
        (&rec.attitude_rad, &rec.position, &rec.velocity_ned_m_s)
    else {
        return Ok(());
    };
    if rec.is_empty() {
        return Ok(());
    }
    let topic = bag.add_topic("/reference/odometry", "nav_msgs/msg/Odometry")?;
    let (lat0, lon0, h0) = (pos[0][0], pos[1][0], pos[2][0]);
    let radii = dynacal_core::nav::earth::radii(lat0);
    for k in 0..rec.len() {
        let q = ros_of_ned_rpy([rpy[0][k], rpy[1][k], rpy[2][k]]);
        let v_enu = enu_to_ned() * nalgebra::Vector3::new(vel[0][k], vel[1][k], vel[2][k]);
        // World to body: the inverse turn of the orientation.
        let [x, y, z, w] = q;
        let body = rotate_by_ros([-x, -y, -z, w], [v_enu.x, v_enu.y, v_enu.z]);
        let msg = Odometry {
            header: Header {
                stamp_ns: stamp_ns(rec.t_s[k]),
                frame_id: "map".into(),
            },
            child_frame_id: "reference".into(),
            position: [
                (pos[1][k] - lon0) * (radii.transverse_m + h0) * lat0.cos(),
                (pos[0][k] - lat0) * (radii.meridian_m + h0),
                pos[2][k] - h0,
            ],
            orientation: q,
            linear_velocity: body,
            angular_velocity: [0.0; 3],
        };
        pending.push((msg.header.stamp_ns, topic, encode_odometry_cdr(&msg)));
    }
    Ok(())
}

fn fix_messages(
    out: &SimOutput,
    bag: &mut Ros2BagWriter,
    pending: &mut Vec<Pending>,
) -> Result<(), BagWriteError> {
    let Some(g) = &out.gnss else {
        return Ok(());
    };
    let topic = bag.add_topic("/gnss/fix", "sensor_msgs/msg/NavSatFix")?;
    let [sn, se, sd] = g.sigma_ned_m;
    let mut covariance = [0.0; 9];
    (covariance[0], covariance[4], covariance[8]) = (se * se, sn * sn, sd * sd);
    for k in 0..g.t_s.len() {
        let msg = NavSatFix {
            header: Header {
                stamp_ns: stamp_ns(g.t_s[k]),
                frame_id: "gnss".into(),
            },
            status: 0,
            latitude_deg: g.position[0][k].to_degrees(),
            longitude_deg: g.position[1][k].to_degrees(),
            altitude_m: g.position[2][k],
            position_covariance: covariance,
            position_covariance_type: 2,
        };
        pending.push((msg.header.stamp_ns, topic, encode_nav_sat_fix_cdr(&msg)));
    }
    Ok(())
}
