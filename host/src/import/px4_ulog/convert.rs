//! From parsed ULog topics to interchange recordings (the conversions the parent module's
//! documentation lists): `sensor_combined`, the raw `sensor_gyro`/`sensor_accel` instances,
//! the `vehicle_imu` instances, and the GPS + attitude reference.

use std::collections::BTreeSet;
use std::path::Path;

use super::board::{sensor_to_body, SensorKind, SensorToBody};
use super::{
    corrupt, ImportError, ImuRecording, Quaternion, Topic, ULog, UnitQuaternion, GPS_FIXES_3D,
    GPS_TOPICS, MAX_ATTITUDE_GAP_S, MAX_QUATERNION_NORM_ERROR, RELATIVE_TIMESTAMP_INVALID,
};
use crate::interchange::Triplet;
use nalgebra::Vector3;

/// The end of a raw IMU output's name when the log gives no board rotation and its data stay
/// in the sensor's axes (`imu0_board`): not the body frame the interchange format expects.
pub const BOARD_FRAME_SUFFIX: &str = "_board";

/// One output of [`read`]: `sensor_combined`, `imu0`, `vehicle_imu0`, `reference`... and its
/// recording.
pub type NamedRecording = (String, ImuRecording);

/// An empty recording with the triplets `gyro`, `accel` present.
fn imu_recording(gyro: bool, accel: bool) -> ImuRecording {
    ImuRecording {
        gyro_rad_s: gyro.then(Triplet::default),
        accel_m_s2: accel.then(Triplet::default),
        ..Default::default()
    }
}

/// Appends `row` to `triplet` (which must be present).
fn push(triplet: &mut Option<Triplet>, row: [f64; 3]) {
    let columns = triplet.get_or_insert_with(Default::default);
    for (column, v) in columns.iter_mut().zip(row) {
        column.push(v);
    }
}

/// The three fields `names` of sample `i`, each present and finite.
fn vector(log: &ULog, topic: &Topic, i: usize, names: [&str; 3]) -> Result<[f64; 3], ImportError> {
    Ok([
        log.required(topic, i, names[0])?,
        log.required(topic, i, names[1])?,
        log.required(topic, i, names[2])?,
    ])
}

/// The instance suffix of a single-instance topic's output: none for instance 0.
fn instance_suffix(multi_id: u8) -> String {
    if multi_id == 0 {
        String::new()
    } else {
        multi_id.to_string()
    }
}

/// Every `sensor_combined` instance (normally one): gyro and accelerometer in the body frame,
/// calibrated, on `timestamp`.
pub fn read_sensor_combined(log: &ULog) -> Result<Vec<NamedRecording>, ImportError> {
    let mut out = Vec::new();
    for topic in log.instances("sensor_combined").filter(|t| !t.is_empty()) {
        let mut rec = imu_recording(true, true);
        for i in 0..topic.len() {
            let t = log.time_s(topic, i, "timestamp", rec.t_s.last().copied())?;
            if topic.value(i, "accelerometer_timestamp_relative")
                == Some(RELATIVE_TIMESTAMP_INVALID)
            {
                return Err(log.error_at(topic, i, "the sample has no accelerometer value"));
            }
            rec.t_s.push(t);
            push(
                &mut rec.gyro_rad_s,
                vector(log, topic, i, ["gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"])?,
            );
            push(
                &mut rec.accel_m_s2,
                vector(
                    log,
                    topic,
                    i,
                    [
                        "accelerometer_m_s2[0]",
                        "accelerometer_m_s2[1]",
                        "accelerometer_m_s2[2]",
                    ],
                )?,
            );
        }
        rec.validate(log.path())?;
        let name = format!("sensor_combined{}", instance_suffix(topic.multi_id));
        out.push((name, rec));
    }
    Ok(out)
}

/// The sample-time field of a raw sensor topic: `timestamp_sample`, else `timestamp`.
fn sample_clock(topic: &Topic) -> &'static str {
    if topic.has("timestamp_sample") {
        "timestamp_sample"
    } else {
        "timestamp"
    }
}

/// The sample times of a raw sensor topic, s, strictly increasing.
fn sample_times_s(log: &ULog, topic: &Topic) -> Result<Vec<f64>, ImportError> {
    let clock = sample_clock(topic);
    let mut t_s: Vec<f64> = Vec::with_capacity(topic.len());
    for i in 0..topic.len() {
        t_s.push(log.time_s(topic, i, clock, t_s.last().copied())?);
    }
    Ok(t_s)
}

/// The `device_id` of every sample of `topic`, if the format has one.
fn device_ids(topic: &Topic) -> Option<BTreeSet<u64>> {
    Some(
        topic
            .column("device_id")?
            .into_iter()
            .map(|v| v as u64)
            .collect(),
    )
}

/// True when gyro and accelerometer instances come from one chip sampled together: the same
/// single `device_id` throughout (where both formats have one) and identical sample times.
fn same_device(gyro: &Topic, accel: &Topic, gyro_t: &[f64], accel_t: &[f64]) -> bool {
    let ids_agree = match (device_ids(gyro), device_ids(accel)) {
        (Some(g), Some(a)) => g.len() == 1 && g == a,
        _ => true,
    };
    ids_agree && gyro_t == accel_t
}

/// One raw sensor topic: its sample times (s) and its rotation into the body's axes (`None`:
/// the log does not say, the data stay in the sensor's axes).
struct RawSensor<'a> {
    topic: &'a Topic,
    t_s: Vec<f64>,
    to_body: Option<SensorToBody>,
}

impl RawSensor<'_> {
    /// Instance `k` of the raw topic of `kind`, if it has samples.
    fn new(log: &ULog, kind: SensorKind, k: u8) -> Result<Option<RawSensor<'_>>, ImportError> {
        let name = match kind {
            SensorKind::Gyro => "sensor_gyro",
            SensorKind::Accel => "sensor_accel",
        };
        let Some(topic) = log.topic(name, k).filter(|t| !t.is_empty()) else {
            return Ok(None);
        };
        Ok(Some(RawSensor {
            topic,
            t_s: sample_times_s(log, topic)?,
            to_body: sensor_to_body(log, kind, topic.value(0, "device_id"))?,
        }))
    }

    /// Its `x, y, z` into `triplet` (gyro or accelerometer), rotated into the body's axes
    /// where the rotation is known.
    fn axes_into(&self, log: &ULog, triplet: &mut Option<Triplet>) -> Result<(), ImportError> {
        for i in 0..self.topic.len() {
            let v = vector(log, self.topic, i, ["x", "y", "z"])?;
            let v = match &self.to_body {
                Some(to_body) => (to_body.r_b_s * Vector3::from(v)).into(),
                None => v,
            };
            push(triplet, v);
        }
        Ok(())
    }

    /// The suffix of its output's name: none in the body's axes, `_board` in the sensor's.
    fn frame_suffix(&self) -> &'static str {
        if self.to_body.is_some() {
            ""
        } else {
            BOARD_FRAME_SUFFIX
        }
    }
}

/// Every `sensor_gyro` / `sensor_accel` instance on `timestamp_sample`, uncalibrated, turned
/// into the body's axes with the log's board rotation ([`sensor_to_body`]). Instance k's gyro
/// and accelerometer share `imu{k}` when they are one chip sampled together ([`same_device`])
/// in the same frame, else they are `gyro{k}` and `accel{k}`. Without a rotation in the log
/// the data stay in the sensor's axes and the name ends in [`BOARD_FRAME_SUFFIX`].
pub fn read_sensor_imus(log: &ULog) -> Result<Vec<NamedRecording>, ImportError> {
    let ids: BTreeSet<u8> = log
        .instances("sensor_gyro")
        .chain(log.instances("sensor_accel"))
        .filter(|t| !t.is_empty())
        .map(|t| t.multi_id)
        .collect();
    let mut out = Vec::new();
    for k in ids {
        let gyro = RawSensor::new(log, SensorKind::Gyro, k)?;
        let accel = RawSensor::new(log, SensorKind::Accel, k)?;
        let mut pieces: Vec<(String, ImuRecording)> = Vec::new();
        match (gyro, accel) {
            (Some(g), Some(a))
                if same_device(g.topic, a.topic, &g.t_s, &a.t_s)
                    && g.frame_suffix() == a.frame_suffix() =>
            {
                let mut rec = imu_recording(true, true);
                g.axes_into(log, &mut rec.gyro_rad_s)?;
                a.axes_into(log, &mut rec.accel_m_s2)?;
                rec.t_s = g.t_s;
                pieces.push((format!("imu{k}{}", a.frame_suffix()), rec));
            }
            (g, a) => {
                if let Some(g) = g {
                    let mut rec = imu_recording(true, false);
                    g.axes_into(log, &mut rec.gyro_rad_s)?;
                    let name = format!("gyro{k}{}", g.frame_suffix());
                    rec.t_s = g.t_s;
                    pieces.push((name, rec));
                }
                if let Some(a) = a {
                    let mut rec = imu_recording(false, true);
                    a.axes_into(log, &mut rec.accel_m_s2)?;
                    let name = format!("accel{k}{}", a.frame_suffix());
                    rec.t_s = a.t_s;
                    pieces.push((name, rec));
                }
            }
        }
        for (_, rec) in &pieces {
            rec.validate(log.path())?;
        }
        out.extend(pieces);
    }
    Ok(out)
}

/// `value / (dt_us / 1e6)` for the three axes, `dt_us` checked positive.
fn per_second(
    log: &ULog,
    topic: &Topic,
    i: usize,
    delta: &str,
    dt_field: &str,
) -> Result<[f64; 3], ImportError> {
    let dt_us = log.required(topic, i, dt_field)?;
    if dt_us <= 0.0 {
        return Err(log.error_at(topic, i, format!("`{dt_field}` is {dt_us} µs")));
    }
    let names = [0, 1, 2].map(|a| format!("{delta}[{a}]"));
    let v = vector(log, topic, i, [&names[0], &names[1], &names[2]])?;
    Ok(v.map(|x| x / (dt_us * 1e-6)))
}

/// Every `vehicle_imu` instance: the integrated angle and velocity over their intervals as
/// mean rates (rad/s, m/s^2), calibrated and in the body frame, on `timestamp_sample`.
pub fn read_vehicle_imus(log: &ULog) -> Result<Vec<NamedRecording>, ImportError> {
    let mut out = Vec::new();
    for topic in log.instances("vehicle_imu").filter(|t| !t.is_empty()) {
        let mut rec = imu_recording(true, true);
        rec.t_s = sample_times_s(log, topic)?;
        for i in 0..topic.len() {
            let omega = per_second(log, topic, i, "delta_angle", "delta_angle_dt")?;
            let f = per_second(log, topic, i, "delta_velocity", "delta_velocity_dt")?;
            push(&mut rec.gyro_rad_s, omega);
            push(&mut rec.accel_m_s2, f);
        }
        rec.validate(log.path())?;
        out.push((format!("vehicle_imu{}", topic.multi_id), rec));
    }
    Ok(out)
}

/// `vehicle_attitude` instance 0: time (s, boot clock) and attitude (body FRD to NED).
fn read_attitude(log: &ULog) -> Result<Vec<(f64, UnitQuaternion<f64>)>, ImportError> {
    let Some(topic) = log.topic("vehicle_attitude", 0) else {
        return Ok(Vec::new());
    };
    let mut out: Vec<(f64, UnitQuaternion<f64>)> = Vec::with_capacity(topic.len());
    for i in 0..topic.len() {
        let t = log.time_s(topic, i, "timestamp", out.last().map(|s| s.0))?;
        let mut q = [0.0; 4];
        for (a, v) in q.iter_mut().enumerate() {
            *v = log.required(topic, i, &format!("q[{a}]"))?;
        }
        let q = Quaternion::new(q[0], q[1], q[2], q[3]);
        if (q.norm() - 1.0).abs() > MAX_QUATERNION_NORM_ERROR {
            return Err(log.error_at(
                topic,
                i,
                format!("quaternion `q` has the norm {}, not 1", q.norm()),
            ));
        }
        out.push((t, UnitQuaternion::from_quaternion(q)));
    }
    Ok(out)
}

/// Latitude, longitude (rad) and ellipsoidal height (m) of GPS sample `i`, from the
/// integer fields (1e-7 deg, mm) or the newer float ones (deg, m).
fn gps_position(log: &ULog, gps: &Topic, i: usize) -> Result<[f64; 3], ImportError> {
    let (lat_deg, lon_deg) = if gps.has("lat") {
        (
            log.required(gps, i, "lat")? * 1e-7,
            log.required(gps, i, "lon")? * 1e-7,
        )
    } else {
        (
            log.required(gps, i, "latitude_deg")?,
            log.required(gps, i, "longitude_deg")?,
        )
    };
    let h_m = if gps.has("alt_ellipsoid") {
        log.required(gps, i, "alt_ellipsoid")? * 1e-3
    } else {
        log.required(gps, i, "altitude_ellipsoid_m")?
    };
    if lat_deg.abs() > 90.0 || lon_deg.abs() > 180.0 {
        return Err(log.error_at(
            gps,
            i,
            format!("position {lat_deg} deg, {lon_deg} deg is not on Earth"),
        ));
    }
    Ok([lat_deg.to_radians(), lon_deg.to_radians(), h_m])
}

/// The GPS topic the reference reads: instance 0 of the first of [`GPS_TOPICS`] with samples
/// (else of the first subscribed, which gives no fix).
pub fn gps_topic(log: &ULog) -> Option<&Topic> {
    let subscribed = || GPS_TOPICS.iter().filter_map(|name| log.topic(name, 0));
    subscribed()
        .find(|t| !t.is_empty())
        .or_else(|| subscribed().next())
}

/// The reference recording: 3D GPS fixes with NED velocity and the interpolated
/// `vehicle_attitude` (see the parent module's documentation). `None` when the log has no GPS
/// fix inside the attitude's span.
pub fn read_reference(log: &ULog) -> Result<Option<ImuRecording>, ImportError> {
    let Some(gps) = gps_topic(log) else {
        return Ok(None);
    };
    let att = read_attitude(log)?;
    let mut rec = ImuRecording {
        attitude_rad: Some(Default::default()),
        position: Some(Default::default()),
        velocity_ned_m_s: Some(Default::default()),
        ..Default::default()
    };
    let mut previous = None;
    for i in 0..gps.len() {
        if !GPS_FIXES_3D.contains(&log.required(gps, i, "fix_type")?)
            || gps.value(i, "vel_ned_valid") == Some(0.0)
        {
            continue;
        }
        let t = log.time_s(gps, i, "timestamp", previous)?;
        previous = Some(t);
        let Some(q) = crate::import::frames::attitude_at(&att, t, MAX_ATTITUDE_GAP_S) else {
            continue;
        };
        let (roll, pitch, yaw) = q.euler_angles();
        push(&mut rec.attitude_rad, [roll, pitch, yaw]);
        push(&mut rec.position, gps_position(log, gps, i)?);
        push(
            &mut rec.velocity_ned_m_s,
            vector(log, gps, i, ["vel_n_m_s", "vel_e_m_s", "vel_d_m_s"])?,
        );
        rec.t_s.push(t);
    }
    if rec.t_s.is_empty() {
        return Ok(None);
    }
    rec.validate(log.path())?;
    Ok(Some(rec))
}

/// Reads a log into its IMU recordings (`sensor_combined`, `imu{k}` or `gyro{k}`/`accel{k}`,
/// `vehicle_imu{k}`) and, where it has 3D GPS fixes and `vehicle_attitude`, a `reference`. A
/// log with none of the IMU topics is an error.
pub fn read(path: &Path) -> Result<Vec<NamedRecording>, ImportError> {
    let log = ULog::read(path)?;
    let mut out = read_sensor_combined(&log)?;
    out.extend(read_sensor_imus(&log)?);
    out.extend(read_vehicle_imus(&log)?);
    if out.is_empty() {
        return Err(corrupt(
            path,
            0,
            format!(
                "no samples of sensor_combined, sensor_gyro, sensor_accel or vehicle_imu among its {} topic instances",
                log.topics().len()
            ),
        ));
    }
    if let Some(reference) = read_reference(&log)? {
        out.push(("reference".into(), reference));
    }
    Ok(out)
}
