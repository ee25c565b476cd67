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

/// What an Imu topic's messages say, counted as they come (for the report and the
/// "not a sensor" test), with its kept samples: stored for an import, handed to the
/// collector's sink when streamed.
#[derive(Debug, Default)]
struct ImuTopic {
    frames: BTreeSet<String>,
    line: StampLine,
    /// The first message's (angular velocity, linear acceleration), ROS axes, and whether a
    /// later one differs: a topic whose every value is the same is no sensor.
    first: Option<([f64; 3], [f64; 3])>,
    varies: bool,
    gyro_covariance: CovarianceSeen,
    accel_covariance: CovarianceSeen,
    /// Sum of the kept specific forces, m/s^2 forward-right-down (their mean is reported).
    kept_accel_sum: [f64; 3],
    /// Kept samples (time increasing), s; forward-right-down rad/s and m/s^2. Empty when
    /// streamed.
    t_s: Vec<f64>,
    gyro: Vec<[f64; 3]>,
    accel: Vec<[f64; 3]>,
}

impl ImuTopic {
    /// Counts `m`; its kept sample as (time s, gyro and accelerometer forward-right-down).
    fn add(&mut self, m: &messages::Imu, receive_ns: i128) -> Option<(f64, [f64; 3], [f64; 3])> {
        let values = (m.angular_velocity, m.linear_acceleration);
        match self.first {
            None => self.first = Some(values),
            Some(first) => self.varies |= first != values,
        }
        self.frames.insert(m.header.frame_id.clone());
        self.gyro_covariance.add(&m.angular_velocity_covariance);
        self.accel_covariance.add(&m.linear_acceleration_covariance);
        let stamp = Stamp::of(&m.header, receive_ns);
        if !self.line.push(stamp) {
            return None;
        }
        let (gyro, accel) = (flu_to_frd(values.0), flu_to_frd(values.1));
        for (sum, a) in self.kept_accel_sum.iter_mut().zip(accel) {
            *sum += a;
        }
        Some((stamp_seconds(stamp.ns), gyro, accel))
    }

    fn has_gyro(&self) -> bool {
        self.gyro_covariance.absent < self.line.messages
    }

    fn has_accel(&self) -> bool {
        self.accel_covariance.absent < self.line.messages
    }
}

/// A streamed Imu topic: which of its vectors hold data, and how many samples were kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamedImu {
    /// False when every message holds the same values: no sensor.
    pub varies: bool,
    pub gyro: bool,
    pub accel: bool,
    pub kept: usize,
}

/// Where a streamed topic's kept samples go: (time s, angular velocity rad/s, specific force
/// m/s^2), both forward-right-down.
pub type ImuSink<'a> = &'a mut dyn FnMut(f64, [f64; 3], [f64; 3]);

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
    Imu(Box<ImuTopic>),
    Fix(FixTopic),
    Odometry(OdometryTopic),
    /// A type dynacal does not read: its message count.
    Other {
        msg_type: String,
        count: usize,
    },
}

/// Collects the messages of one bag.
pub struct Collector<'a> {
    path: PathBuf,
    /// Per topic name, in name order.
    topics: BTreeMap<String, TopicData>,
    /// The topic and receive time of the last message read whole.
    last: Option<(String, i128)>,
    /// Only this topic (by its file name) is decoded; the others are counted.
    pub only: Option<String>,
    /// Whether a topic is the one asked, by name (a topic's file name made once, not per
    /// message).
    asked: BTreeMap<String, bool>,
    /// Where the asked Imu topic's samples go instead of being stored (memory then
    /// independent of the bag's length).
    pub sink: Option<ImuSink<'a>>,
}

impl<'a> Collector<'a> {
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            topics: BTreeMap::new(),
            last: None,
            only: None,
            asked: BTreeMap::new(),
            sink: None,
        }
    }

    /// The streamed Imu topic (the asked one, when a sink is set and it is an Imu topic).
    pub fn streamed_imu(&self) -> Option<StreamedImu> {
        self.topics.values().find_map(|data| match data {
            TopicData::Imu(t) if self.sink.is_some() => Some(StreamedImu {
                varies: t.varies,
                gyro: t.has_gyro(),
                accel: t.has_accel(),
                kept: t.line.kept,
            }),
            _ => None,
        })
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

impl BagVisitor for Collector<'_> {
    fn message(
        &mut self,
        topic: &TopicInfo,
        receive_ns: i128,
        data: &[u8],
        at: Location,
    ) -> Result<(), ImportError> {
        let asked = match (&self.only, self.asked.get(&topic.name)) {
            (None, _) => true,
            (Some(_), Some(&asked)) => asked,
            (Some(only), None) => {
                let asked = *only == file_name_of_topic(&topic.name);
                self.asked.insert(topic.name.clone(), asked);
                asked
            }
        };
        let known = asked && [IMU, NAV_SAT_FIX, ODOMETRY].contains(&topic.msg_type.as_str());
        let Some(encoding) = topic.encoding.filter(|_| known) else {
            if !self.topics.contains_key(&topic.name) {
                self.topics.insert(
                    topic.name.clone(),
                    TopicData::Other {
                        msg_type: topic.msg_type.clone(),
                        count: 0,
                    },
                );
            }
            if let Some(TopicData::Other { count, .. }) = self.topics.get_mut(&topic.name) {
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
        if !self.topics.contains_key(&topic.name) {
            let data = match topic.msg_type.as_str() {
                IMU => TopicData::Imu(Box::default()),
                NAV_SAT_FIX => TopicData::Fix(FixTopic::default()),
                _ => TopicData::Odometry(OdometryTopic::default()),
            };
            self.topics.insert(topic.name.clone(), data);
        }
        let entry = self.topics.get_mut(&topic.name).expect("inserted");
        let sink = &mut self.sink;
        let error = |e: messages::DecodeError| (topic, at, receive_ns, e);
        let result = match entry {
            TopicData::Imu(t) => messages::imu(data, encoding).map(|m| {
                if let Some((t_s, gyro, accel)) = t.add(&m, receive_ns) {
                    match sink {
                        Some(sink) => sink(t_s, gyro, accel),
                        None => {
                            t.t_s.push(t_s);
                            t.gyro.push(gyro);
                            t.accel.push(accel);
                        }
                    }
                }
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

/// A topic's stamps counted as they come: a stamp is kept when it is after every earlier
/// one (an interchange file's time increases strictly); stamps that repeat or go back
/// against the previous message, and zero stamps replaced by the receive time, are counted
/// for the report, never fixed silently.
#[derive(Debug, Default)]
struct StampLine {
    messages: usize,
    kept: usize,
    previous: Option<i128>,
    latest: Option<i128>,
    repeated: usize,
    first_repeated: Option<i128>,
    back: usize,
    /// The first stamp that went back, and the previous message's.
    first_back: Option<(i128, i128)>,
    from_receive: usize,
    first_from_receive: Option<i128>,
}

impl StampLine {
    /// Counts `stamp`; true when it is kept.
    fn push(&mut self, stamp: Stamp) -> bool {
        self.messages += 1;
        if stamp.from_receive_time {
            self.from_receive += 1;
            self.first_from_receive.get_or_insert(stamp.ns);
        }
        match self.previous {
            Some(p) if stamp.ns == p => {
                self.repeated += 1;
                self.first_repeated.get_or_insert(stamp.ns);
            }
            Some(p) if stamp.ns < p => {
                self.back += 1;
                self.first_back.get_or_insert((stamp.ns, p));
            }
            _ => {}
        }
        self.previous = Some(stamp.ns);
        let keep = self.latest.is_none_or(|l| stamp.ns > l);
        if keep {
            self.latest = Some(stamp.ns);
            self.kept += 1;
        }
        keep
    }

    fn notes(&self, topic: &str) -> Vec<String> {
        let mut notes = Vec::new();
        if let Some(first) = self.first_from_receive {
            notes.push(format!(
                "{topic}: {} header stamps are zero: the bag's receive time is used for them (the first at {} s)",
                self.from_receive,
                seconds(first)
            ));
        }
        if let Some(first) = self.first_repeated {
            notes.push(format!(
                "{topic}: {} stamps repeat the previous message's (the first at {} s)",
                self.repeated,
                seconds(first)
            ));
        }
        if let Some((first, after)) = self.first_back {
            notes.push(format!(
                "{topic}: {} stamps go back from the previous message's (the first to {} s after {} s)",
                self.back,
                seconds(first),
                seconds(after)
            ));
        }
        let left_out = self.messages - self.kept;
        if left_out > 0 {
            notes.push(format!(
                "{topic}: {left_out} messages whose stamp is not after every earlier one are left out (an interchange file's time increases strictly)"
            ));
        }
        notes
    }
}

/// The kept samples of a stored topic ([`StampLine`]): their indices and times, with the
/// report.
struct Timeline {
    keep: Vec<usize>,
    t_s: Vec<f64>,
    notes: Vec<String>,
}

fn timeline(topic: &str, stamps: &[Stamp]) -> Timeline {
    let mut line = StampLine::default();
    let keep: Vec<usize> = (0..stamps.len())
        .filter(|&i| line.push(stamps[i]))
        .collect();
    let t_s = keep.iter().map(|&i| stamp_seconds(stamps[i].ns)).collect();
    Timeline {
        keep,
        t_s,
        notes: line.notes(topic),
    }
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

impl Collector<'_> {
    /// The recordings and the report.
    pub fn finish(self) -> Result<(Vec<(String, ImuRecording)>, BagReport), ImportError> {
        let mut recordings = Vec::new();
        let mut report = BagReport::default();
        let mut names: BTreeMap<String, String> = BTreeMap::new();
        let streamed = self.sink.is_some();
        for (topic, data) in self.topics {
            let converted = match data {
                TopicData::Imu(t) => imu_recording(&topic, *t, streamed, &mut report.notes),
                TopicData::Fix(t) => fix_recording(&topic, &t, &mut report.notes),
                TopicData::Odometry(t) => odometry_recording(&topic, &t, &mut report.notes),
                TopicData::Other { msg_type, count } => {
                    report.notes.push(match &self.only {
                        Some(only) if *only != file_name_of_topic(&topic) => format!(
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
                let name = file_name_of_topic(&topic);
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

fn imu_recording(
    topic: &str,
    t: ImuTopic,
    streamed: bool,
    notes: &mut Vec<String>,
) -> Option<ImuRecording> {
    let count = t.line.messages;
    let first = t.first?;
    notes.extend(t.line.notes(topic));
    if !t.varies {
        notes.push(format!(
            "{topic}: skipped, not a sensor: its {count} angular velocities are all {:?} and its linear accelerations all {:?}",
            first.0, first.1
        ));
        return None;
    }
    let partly = |absent: usize| absent > 0 && absent < count;
    if partly(t.gyro_covariance.absent) || partly(t.accel_covariance.absent) {
        notes.push(format!(
            "{topic}: some messages state no angular velocity or no acceleration (covariance -1) and others do: kept as data"
        ));
    }
    // A streamed topic's time line is summarised by its reader (`dynacal noise`).
    if !streamed {
        notes.extend(sampling_note(topic, &t.t_s));
    }
    let frames: Vec<&str> = t.frames.iter().map(String::as_str).collect();
    let mean_f = t.kept_accel_sum.map(|sum| match t.has_accel() {
        true => sum / t.line.kept as f64,
        false => f64::NAN,
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
    if streamed {
        return None;
    }
    let column = |values: &[[f64; 3]]| -> [Vec<f64>; 3] {
        std::array::from_fn(|axis| values.iter().map(|v| v[axis]).collect())
    };
    Some(ImuRecording {
        gyro_rad_s: t.has_gyro().then(|| column(&t.gyro)),
        accel_m_s2: t.has_accel().then(|| column(&t.accel)),
        t_s: t.t_s,
        ..Default::default()
    })
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
