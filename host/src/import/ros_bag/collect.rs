//! Collects a bag's messages topic by topic and turns each topic into an interchange
//! recording, measuring and reporting what is irregular about it (see the parent module for
//! the conversions).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use super::frames::{enu_to_ned, flu_to_frd, ned_rpy_of_ros, rotate_by_ros};
use super::messages::{self, Encoding};
use super::{seconds, BagReport, BagVisitor, Location, TopicInfo, ZSTD_MAGIC};
use crate::import::ImportError;
use crate::interchange::ImuRecording;

const IMU: &str = "sensor_msgs/Imu";
const NAV_SAT_FIX: &str = "sensor_msgs/NavSatFix";
const ODOMETRY: &str = "nav_msgs/Odometry";

/// The time of a message: its header stamp, or its receive time where the stamp is zero.
#[derive(Debug, Clone, Copy)]
struct Stamp {
    ns: i128,
    from_receive_time: bool,
}

impl Stamp {
    fn of(header: &messages::Header, receive_ns: i128) -> Self {
        match header.stamp_ns {
            0 => Stamp {
                ns: receive_ns,
                from_receive_time: true,
            },
            ns => Stamp {
                ns,
                from_receive_time: false,
            },
        }
    }
}

/// How a covariance diagonal is set over a topic.
#[derive(Debug, Default)]
struct CovarianceSeen {
    /// Messages stating "no data" (element 0 = -1).
    absent: usize,
    /// Messages whose diagonal is all zero ("unknown", REP 145).
    unknown: usize,
    /// The first diagonal that is set, and whether a later one differs.
    first_set: Option<[f64; 3]>,
    varies: bool,
}

impl CovarianceSeen {
    fn add(&mut self, covariance: &[f64; 9]) {
        let diagonal = [covariance[0], covariance[4], covariance[8]];
        if covariance[0] == -1.0 {
            self.absent += 1;
        } else if diagonal == [0.0; 3] {
            self.unknown += 1;
        } else {
            match self.first_set {
                None => self.first_set = Some(diagonal),
                Some(first) => self.varies |= first != diagonal,
            }
        }
    }

    fn describe(&self, name: &str, unit: &str, total: usize) -> String {
        let mut parts = Vec::new();
        if let Some(d) = self.first_set {
            let set = total - self.absent - self.unknown;
            parts.push(format!(
                "set on {set} ({}: first diagonal {:.3e} {:.3e} {:.3e} {unit})",
                if self.varies { "varying" } else { "constant" },
                d[0],
                d[1],
                d[2]
            ));
        }
        if self.unknown > 0 {
            parts.push(format!("zero (unknown) on {}", self.unknown));
        }
        if self.absent > 0 {
            parts.push(format!("-1 (no data) on {}", self.absent));
        }
        format!("{name}: {} of {total} messages", parts.join(", "))
    }
}

#[derive(Debug, Default)]
struct ImuTopic {
    frames: BTreeSet<String>,
    stamps: Vec<Stamp>,
    /// ROS axes (forward-left-up), rad/s and m/s^2, as stored.
    gyro: Vec<[f64; 3]>,
    accel: Vec<[f64; 3]>,
    gyro_covariance: CovarianceSeen,
    accel_covariance: CovarianceSeen,
}

#[derive(Debug, Default)]
struct FixTopic {
    frames: BTreeSet<String>,
    stamps: Vec<Stamp>,
    /// deg, deg, m.
    fixes: Vec<[f64; 3]>,
    no_fix: usize,
}

#[derive(Debug, Default)]
struct OdometryTopic {
    frames: BTreeSet<(String, String)>,
    stamps: Vec<Stamp>,
    orientation: Vec<[f64; 4]>,
    body_velocity: Vec<[f64; 3]>,
}

#[derive(Debug)]
enum TopicData {
    Imu(ImuTopic),
    Fix(FixTopic),
    Odometry(OdometryTopic),
    /// A type dynacal does not read: its message count.
    Other {
        msg_type: String,
        count: usize,
    },
}

/// Collects the messages of one bag.
pub struct Collector {
    path: PathBuf,
    /// Per topic name, in name order.
    topics: BTreeMap<String, TopicData>,
    /// The topic and receive time of the last message read whole.
    last: Option<(String, i128)>,
    /// Only this topic (by its file name) is decoded; the others are counted.
    pub only: Option<String>,
}

impl Collector {
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            topics: BTreeMap::new(),
            last: None,
            only: None,
        }
    }

    /// A storage error, with the last message read whole: where in the recording the
    /// damage lies.
    pub fn with_last_message(&self, e: ImportError) -> ImportError {
        let context = match &self.last {
            Some((topic, t)) => format!(
                "; the last whole message read: topic {topic}, received at {} s",
                seconds(*t)
            ),
            None => "; no message read before it".into(),
        };
        match e {
            ImportError::Corrupt {
                path,
                offset,
                message,
            } if !message.starts_with("topic ") => ImportError::Corrupt {
                path,
                offset,
                message: message + &context,
            },
            ImportError::Damaged { path, message } if !message.starts_with("topic ") => {
                ImportError::Damaged {
                    path,
                    message: message + &context,
                }
            }
            other => other,
        }
    }

    fn decode_error(
        &self,
        topic: &TopicInfo,
        at: Location,
        receive_ns: i128,
        e: impl std::fmt::Display,
    ) -> ImportError {
        let message = format!(
            "topic {} ({}), {at}, received at {} s: {e}",
            topic.name,
            topic.msg_type,
            seconds(receive_ns)
        );
        match at {
            Location::File(offset)
            | Location::Chunk {
                chunk_offset: offset,
                ..
            } => ImportError::Corrupt {
                path: self.path.clone(),
                offset,
                message,
            },
            Location::Message(_) | Location::Row(_) => ImportError::Damaged {
                path: self.path.clone(),
                message,
            },
        }
    }
}

impl BagVisitor for Collector {
    fn message(
        &mut self,
        topic: &TopicInfo,
        receive_ns: i128,
        data: &[u8],
        at: Location,
    ) -> Result<(), ImportError> {
        let asked = self
            .only
            .as_ref()
            .is_none_or(|only| *only == file_name_of_topic(&topic.name));
        let known = asked && [IMU, NAV_SAT_FIX, ODOMETRY].contains(&topic.msg_type.as_str());
        let Some(encoding) = topic.encoding.filter(|_| known) else {
            let entry = self
                .topics
                .entry(topic.name.clone())
                .or_insert_with(|| TopicData::Other {
                    msg_type: topic.msg_type.clone(),
                    count: 0,
                });
            if let TopicData::Other { count, .. } = entry {
                *count += 1;
            }
            return Ok(());
        };
        // rosbag2's per-message compression: a CDR message never starts with zstd's magic.
        let decompressed;
        let data = if encoding == Encoding::Cdr && data.starts_with(ZSTD_MAGIC) {
            decompressed = zstd::stream::decode_all(data)
                .map_err(|e| self.decode_error(topic, at, receive_ns, format!("zstd: {e}")))?;
            &decompressed[..]
        } else {
            data
        };
        let entry = self.topics.entry(topic.name.clone()).or_insert_with(|| {
            match topic.msg_type.as_str() {
                IMU => TopicData::Imu(ImuTopic::default()),
                NAV_SAT_FIX => TopicData::Fix(FixTopic::default()),
                _ => TopicData::Odometry(OdometryTopic::default()),
            }
        });
        let error = |e: messages::DecodeError| (topic, at, receive_ns, e);
        let result = match entry {
            TopicData::Imu(t) => messages::imu(data, encoding).map(|m| {
                t.stamps.push(Stamp::of(&m.header, receive_ns));
                t.frames.insert(m.header.frame_id);
                t.gyro.push(m.angular_velocity);
                t.accel.push(m.linear_acceleration);
                t.gyro_covariance.add(&m.angular_velocity_covariance);
                t.accel_covariance.add(&m.linear_acceleration_covariance);
            }),
            TopicData::Fix(t) => messages::nav_sat_fix(data, encoding).map(|m| {
                if m.status < 0 {
                    t.no_fix += 1;
                } else {
                    t.stamps.push(Stamp::of(&m.header, receive_ns));
                    t.frames.insert(m.header.frame_id);
                    t.fixes
                        .push([m.latitude_deg, m.longitude_deg, m.altitude_m]);
                }
            }),
            TopicData::Odometry(t) => messages::odometry(data, encoding).map(|m| {
                t.stamps.push(Stamp::of(&m.header, receive_ns));
                t.frames.insert((m.header.frame_id, m.child_frame_id));
                t.orientation.push(m.orientation);
                t.body_velocity.push(m.linear_velocity);
            }),
            TopicData::Other { .. } => Ok(()),
        };
        result.map_err(|e| {
            let (topic, at, receive_ns, e) = error(e);
            self.decode_error(topic, at, receive_ns, e)
        })?;
        self.last = Some((topic.name.clone(), receive_ns));
        Ok(())
    }
}

/// `/xsens/imu_data` -> `xsens-imu_data`: a file name made of the topic's name.
pub fn file_name_of_topic(topic: &str) -> String {
    let name: String = topic
        .trim_start_matches('/')
        .chars()
        .map(|c| match c {
            '/' => '-',
            c if c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.' => c,
            _ => '_',
        })
        .collect();
    if name.is_empty() {
        "topic".into()
    } else {
        name
    }
}

/// The kept samples of a topic: indices whose time advances past every earlier one, with
/// the report of those left out and of the zero stamps.
struct Timeline {
    keep: Vec<usize>,
    t_s: Vec<f64>,
    notes: Vec<String>,
}

fn timeline(topic: &str, stamps: &[Stamp]) -> Timeline {
    let mut keep = Vec::with_capacity(stamps.len());
    let mut latest: Option<i128> = None;
    for (i, s) in stamps.iter().enumerate() {
        if latest.is_none_or(|l| s.ns > l) {
            keep.push(i);
            latest = Some(s.ns);
        }
    }
    // Counted against the previous message, as a reader of the bag sees them.
    let repeated: Vec<i128> = stamps
        .windows(2)
        .filter(|w| w[1].ns == w[0].ns)
        .map(|w| w[1].ns)
        .collect();
    let back: Vec<(i128, i128)> = stamps
        .windows(2)
        .filter(|w| w[1].ns < w[0].ns)
        .map(|w| (w[1].ns, w[0].ns))
        .collect();
    let mut notes = Vec::new();
    let from_receive: Vec<i128> = stamps
        .iter()
        .filter(|s| s.from_receive_time)
        .map(|s| s.ns)
        .collect();
    if let Some(first) = from_receive.first() {
        notes.push(format!(
            "{topic}: {} header stamps are zero: the bag's receive time is used for them (the first at {} s)",
            from_receive.len(),
            seconds(*first)
        ));
    }
    if let Some(first) = repeated.first() {
        notes.push(format!(
            "{topic}: {} stamps repeat the previous message's (the first at {} s)",
            repeated.len(),
            seconds(*first)
        ));
    }
    if let Some((first, after)) = back.first() {
        notes.push(format!(
            "{topic}: {} stamps go back from the previous message's (the first to {} s after {} s)",
            back.len(),
            seconds(*first),
            seconds(*after)
        ));
    }
    let left_out = stamps.len() - keep.len();
    if left_out > 0 {
        notes.push(format!(
            "{topic}: {left_out} messages whose stamp is not after every earlier one are left out (an interchange file's time increases strictly)"
        ));
    }
    let t_s = keep.iter().map(|&i| stamp_seconds(stamps[i].ns)).collect();
    Timeline { keep, t_s, notes }
}

/// ns since the Unix epoch -> s, rounded once (the integer seconds are exact in an f64).
fn stamp_seconds(ns: i128) -> f64 {
    let sec = ns.div_euclid(1_000_000_000);
    let nsec = ns.rem_euclid(1_000_000_000);
    sec as f64 + nsec as f64 * 1e-9
}

/// Median rate, jitter and gaps of a kept time line.
fn sampling_note(topic: &str, t_s: &[f64]) -> Option<String> {
    crate::interchange::Sampling::of(t_s).map(|s| format!("{topic}: {s}"))
}

impl Collector {
    /// The recordings and the report.
    pub fn finish(self) -> Result<(Vec<(String, ImuRecording)>, BagReport), ImportError> {
        let mut recordings = Vec::new();
        let mut report = BagReport::default();
        let mut names: BTreeMap<String, String> = BTreeMap::new();
        for (topic, data) in &self.topics {
            let converted = match data {
                TopicData::Imu(t) => imu_recording(topic, t, &mut report.notes),
                TopicData::Fix(t) => fix_recording(topic, t, &mut report.notes),
                TopicData::Odometry(t) => odometry_recording(topic, t, &mut report.notes),
                TopicData::Other { msg_type, count } => {
                    report.notes.push(match &self.only {
                        Some(only) if *only != file_name_of_topic(topic) => format!(
                            "{topic}: {count} messages of {msg_type}, not read (only {only} was asked)"
                        ),
                        _ => format!(
                            "{topic}: {count} messages of {msg_type}, not read (dynacal reads {IMU}, {NAV_SAT_FIX}, {ODOMETRY})"
                        ),
                    });
                    None
                }
            };
            if let Some(recording) = converted {
                let name = file_name_of_topic(topic);
                if let Some(other) = names.insert(name.clone(), topic.clone()) {
                    return Err(ImportError::Implausible {
                        path: self.path.clone(),
                        sensor: topic.clone(),
                        message: format!("topics {other} and {topic} both make the name {name}"),
                    });
                }
                recordings.push((name, recording));
            }
        }
        Ok((recordings, report))
    }
}

fn imu_recording(topic: &str, t: &ImuTopic, notes: &mut Vec<String>) -> Option<ImuRecording> {
    let count = t.stamps.len();
    let first = (t.gyro.first()?, t.accel.first()?);
    let line = timeline(topic, &t.stamps);
    notes.extend(line.notes);
    if t.gyro.iter().all(|g| g == first.0) && t.accel.iter().all(|a| a == first.1) {
        notes.push(format!(
            "{topic}: skipped, not a sensor: its {count} angular velocities are all {:?} and its linear accelerations all {:?}",
            first.0, first.1
        ));
        return None;
    }
    let has_gyro = t.gyro_covariance.absent < count;
    let has_accel = t.accel_covariance.absent < count;
    let partly = |absent: usize| absent > 0 && absent < count;
    if partly(t.gyro_covariance.absent) || partly(t.accel_covariance.absent) {
        notes.push(format!(
            "{topic}: some messages state no angular velocity or no acceleration (covariance -1) and others do: kept as data"
        ));
    }
    notes.extend(sampling_note(topic, &line.t_s));
    let column = |values: &[[f64; 3]]| -> [Vec<f64>; 3] {
        let frd: Vec<[f64; 3]> = line.keep.iter().map(|&i| flu_to_frd(values[i])).collect();
        std::array::from_fn(|axis| frd.iter().map(|v| v[axis]).collect())
    };
    let recording = ImuRecording {
        t_s: line.t_s,
        gyro_rad_s: has_gyro.then(|| column(&t.gyro)),
        accel_m_s2: has_accel.then(|| column(&t.accel)),
        ..Default::default()
    };
    let frames: Vec<&str> = t.frames.iter().map(String::as_str).collect();
    let mean_f: [f64; 3] = std::array::from_fn(|axis| {
        recording.accel_m_s2.as_ref().map_or(f64::NAN, |a| {
            a[axis].iter().sum::<f64>() / a[axis].len() as f64
        })
    });
    notes.push(format!(
        "{topic}: frame_id {}: axes kept as the sensor's, turned from ROS's forward-left-up to forward-right-down (y and z negated); mean specific force ({:.3}, {:.3}, {:.3}) m/s^2",
        frames.join(", "),
        mean_f[0],
        mean_f[1],
        mean_f[2]
    ));
    notes.push(t.gyro_covariance.describe(
        &format!("{topic}: angular_velocity_covariance"),
        "rad^2/s^2",
        count,
    ));
    notes.push(t.accel_covariance.describe(
        &format!("{topic}: linear_acceleration_covariance"),
        "m^2/s^4",
        count,
    ));
    Some(recording)
}

fn fix_recording(topic: &str, t: &FixTopic, notes: &mut Vec<String>) -> Option<ImuRecording> {
    if t.no_fix > 0 {
        notes.push(format!(
            "{topic}: {} messages without a fix (status -1) left out",
            t.no_fix
        ));
    }
    if t.fixes.is_empty() {
        notes.push(format!("{topic}: skipped, no fix"));
        return None;
    }
    let line = timeline(topic, &t.stamps);
    notes.extend(line.notes);
    notes.extend(sampling_note(topic, &line.t_s));
    let position = std::array::from_fn(|axis| {
        line.keep
            .iter()
            .map(|&i| match axis {
                2 => t.fixes[i][2],
                _ => t.fixes[i][axis].to_radians(),
            })
            .collect()
    });
    Some(ImuRecording {
        t_s: line.t_s,
        position: Some(position),
        ..Default::default()
    })
}

fn odometry_recording(
    topic: &str,
    t: &OdometryTopic,
    notes: &mut Vec<String>,
) -> Option<ImuRecording> {
    if let Some(bad) = t.orientation.iter().position(|q| {
        let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        !((norm - 1.0).abs() < 1e-3)
    }) {
        notes.push(format!(
            "{topic}: skipped: orientation {:?} of message {bad} is not a unit quaternion, so neither attitude nor velocity can be told",
            t.orientation[bad]
        ));
        return None;
    }
    let line = timeline(topic, &t.stamps);
    notes.extend(line.notes);
    notes.extend(sampling_note(topic, &line.t_s));
    let (mut attitude, mut velocity) = (Vec::new(), Vec::new());
    for &i in &line.keep {
        attitude.push(ned_rpy_of_ros(t.orientation[i]));
        let v_enu = rotate_by_ros(t.orientation[i], t.body_velocity[i]);
        let v_ned = enu_to_ned() * nalgebra::Vector3::from(v_enu);
        velocity.push([v_ned.x, v_ned.y, v_ned.z]);
    }
    let frames: Vec<String> = t
        .frames
        .iter()
        .map(|(world, child)| match child.as_str() {
            "" => format!("an unnamed child frame in {world}"),
            child => format!("{child} in {world}"),
        })
        .collect();
    notes.push(format!(
        "{topic}: attitude and velocity of {}, the world frame taken as east-north-up (REP 103): yaw is from its x axis, north only if the frame is geo-referenced; positions (m in the odometry frame) not carried",
        frames.join(", ")
    ));
    let split = |rows: &[[f64; 3]]| -> [Vec<f64>; 3] {
        std::array::from_fn(|axis| rows.iter().map(|r| r[axis]).collect())
    };
    Some(ImuRecording {
        t_s: line.t_s,
        attitude_rad: Some(split(&attitude)),
        velocity_ned_m_s: Some(split(&velocity)),
        ..Default::default()
    })
}
