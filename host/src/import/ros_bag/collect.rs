//! Reads a bag's messages topic by topic, measuring and reporting what is irregular about
//! each (see the parent module for the conversions), in memory that does not grow with the
//! bag: a first pass ([`Out::Count`]) counts every topic's messages, kept stamps and time
//! steps and decides which topics become recordings ([`Collector::plan`]); a second pass hands
//! each kept sample to the outputs as a row ([`Out::Rows`]), finding the gaps of each time
//! line on the way; the report is written from both ([`Collector::report`]).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use super::frames::{enu_to_ned, flu_to_frd, ned_rpy_of_ros, rotate_by_ros};
use super::messages::{self, Encoding};
use super::{seconds, BagReport, BagVisitor, Location, TopicInfo, ZSTD_MAGIC};
use crate::import::rows::{self, SensorLayout, SensorRows};
use crate::import::ImportError;
use crate::interchange::{ImuRecording, Sampling, StepCounts, Triplet};

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
/// "not a sensor" test); its kept samples go to the pass's [`Out`].
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

/// A NavSatFix topic, counted as its messages come.
#[derive(Debug, Default)]
struct FixTopic {
    frames: BTreeSet<String>,
    /// The stamps of the messages with a fix.
    line: StampLine,
    no_fix: usize,
}

/// An Odometry topic, counted as its messages come.
#[derive(Debug, Default)]
struct OdometryTopic {
    frames: BTreeSet<(String, String)>,
    line: StampLine,
    /// The first message whose orientation is not a unit quaternion, and it.
    not_unit: Option<(usize, [f64; 4])>,
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

impl TopicData {
    fn line(&self) -> Option<&StampLine> {
        match self {
            TopicData::Imu(t) => Some(&t.line),
            TopicData::Fix(t) => Some(&t.line),
            TopicData::Odometry(t) => Some(&t.line),
            TopicData::Other { .. } => None,
        }
    }
}

/// One recording a bag gives: its topic's row layout and where its rows go.
#[derive(Debug)]
pub struct Output {
    /// Its place among the pass's sensors.
    sensor: usize,
    /// Which of an Imu topic's vectors hold data.
    gyro: bool,
    accel: bool,
    /// A step longer than this is a gap ([`Sampling::GAP_STEPS`] median steps), s.
    gap_s: f64,
    previous_s: Option<f64>,
    /// (start, length) s.
    gaps: Vec<(f64, f64)>,
}

/// What a pass does with the kept samples.
pub enum Out<'a> {
    /// Counts them (a first pass).
    Count,
    /// Hands the asked Imu topic's to a closure (`dynacal noise`).
    Imu(ImuSink<'a>),
    /// Hands every recording's rows to a sink, the topics of [`Collector::plan`] as its
    /// sensors.
    Rows {
        sink: &'a mut dyn SensorRows,
        outputs: BTreeMap<String, Output>,
    },
}

/// One kept sample, as its message gave it.
enum Kept {
    /// Time s; angular velocity rad/s and specific force m/s^2, forward-right-down.
    Imu(f64, [f64; 3], [f64; 3]),
    /// Time s; latitude, longitude deg, altitude m.
    Fix(f64, [f64; 3]),
    /// Time s; orientation (ROS x, y, z, w) and body velocity (ROS axes), m/s.
    Odometry(f64, [f64; 4], [f64; 3]),
}

/// Reads the messages of one bag in one pass.
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
    /// Where the kept samples go.
    out: Out<'a>,
}

impl<'a> Collector<'a> {
    pub fn new(path: &Path, out: Out<'a>) -> Self {
        Self {
            path: path.to_path_buf(),
            topics: BTreeMap::new(),
            last: None,
            only: None,
            asked: BTreeMap::new(),
            out,
        }
    }

    /// The streamed Imu topic (the asked one, when its samples go to a closure and it is an
    /// Imu topic).
    pub fn streamed_imu(&self) -> Option<StreamedImu> {
        self.topics.values().find_map(|data| match data {
            TopicData::Imu(t) if matches!(self.out, Out::Imu(_)) => Some(StreamedImu {
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
        let kept = match entry {
            TopicData::Imu(t) => messages::imu(data, encoding).map(|m| {
                t.add(&m, receive_ns)
                    .map(|(t_s, gyro, accel)| Kept::Imu(t_s, gyro, accel))
            }),
            TopicData::Fix(t) => messages::nav_sat_fix(data, encoding).map(|m| {
                if m.status < 0 {
                    t.no_fix += 1;
                    return None;
                }
                let stamp = Stamp::of(&m.header, receive_ns);
                t.frames.insert(m.header.frame_id);
                t.line.push(stamp).then(|| {
                    let fix = [m.latitude_deg, m.longitude_deg, m.altitude_m];
                    Kept::Fix(stamp_seconds(stamp.ns), fix)
                })
            }),
            TopicData::Odometry(t) => messages::odometry(data, encoding).map(|m| {
                let norm = m.orientation.iter().map(|x| x * x).sum::<f64>().sqrt();
                if !((norm - 1.0).abs() < 1e-3) && t.not_unit.is_none() {
                    t.not_unit = Some((t.line.messages, m.orientation));
                }
                let stamp = Stamp::of(&m.header, receive_ns);
                t.frames.insert((m.header.frame_id, m.child_frame_id));
                t.line.push(stamp).then(|| {
                    Kept::Odometry(stamp_seconds(stamp.ns), m.orientation, m.linear_velocity)
                })
            }),
            TopicData::Other { .. } => Ok(None),
        };
        let kept = kept.map_err(|e| self.decode_error(topic, at, receive_ns, e))?;
        if let Some(kept) = kept {
            self.hand_over(&topic.name, kept)?;
        }
        self.last = Some((topic.name.clone(), receive_ns));
        Ok(())
    }
}

impl Collector<'_> {
    /// A kept sample of `topic` to the pass's [`Out`].
    fn hand_over(&mut self, topic: &str, kept: Kept) -> Result<(), ImportError> {
        let (sink, outputs) = match &mut self.out {
            Out::Count => return Ok(()),
            Out::Imu(sink) => {
                if let Kept::Imu(t_s, gyro, accel) = kept {
                    sink(t_s, gyro, accel);
                }
                return Ok(());
            }
            Out::Rows { sink, outputs } => (sink, outputs),
        };
        let Some(output) = outputs.get_mut(topic) else {
            return Ok(());
        };
        let mut row = Vec::with_capacity(7);
        match kept {
            Kept::Imu(t_s, gyro, accel) => {
                row.push(t_s);
                if output.gyro {
                    row.extend(gyro);
                }
                if output.accel {
                    row.extend(accel);
                }
            }
            Kept::Fix(t_s, [lat_deg, lon_deg, altitude_m]) => {
                row.extend([t_s, lat_deg.to_radians(), lon_deg.to_radians(), altitude_m]);
            }
            Kept::Odometry(t_s, orientation, body_velocity) => {
                let v_enu = rotate_by_ros(orientation, body_velocity);
                let v_ned = enu_to_ned() * nalgebra::Vector3::from(v_enu);
                row.push(t_s);
                row.extend(ned_rpy_of_ros(orientation));
                row.extend([v_ned.x, v_ned.y, v_ned.z]);
            }
        }
        let t_s = row[0];
        if let Some(previous) = output.previous_s.filter(|p| t_s - p > output.gap_s) {
            output.gaps.push((previous, t_s - previous));
        }
        output.previous_s = Some(t_s);
        sink.push(output.sensor, &row)
    }

    /// The recordings this bag gives, in topic name order: their layouts, and where a pass
    /// that writes them sends each topic's rows ([`Out::Rows`]). Two topics making one name
    /// are an error.
    pub fn plan(&self) -> Result<(Vec<SensorLayout>, BTreeMap<String, Output>), ImportError> {
        let (mut layouts, mut outputs) = (Vec::new(), BTreeMap::new());
        let mut names: BTreeMap<String, String> = BTreeMap::new();
        for (topic, data) in &self.topics {
            let (gyro, accel) = match data {
                TopicData::Imu(t) => (t.has_gyro(), t.has_accel()),
                _ => (false, false),
            };
            let holds = |attitude: bool, position: bool, velocity: bool| ImuRecording {
                gyro_rad_s: gyro.then(Triplet::default),
                accel_m_s2: accel.then(Triplet::default),
                attitude_rad: attitude.then(Triplet::default),
                position: position.then(Triplet::default),
                velocity_ned_m_s: velocity.then(Triplet::default),
                ..Default::default()
            };
            let empty = match data {
                TopicData::Imu(t) => {
                    (t.first.is_some() && t.varies).then(|| holds(false, false, false))
                }
                TopicData::Fix(t) => (t.line.messages > 0).then(|| holds(false, true, false)),
                TopicData::Odometry(t) => t.not_unit.is_none().then(|| holds(true, false, true)),
                TopicData::Other { .. } => None,
            };
            let (Some(empty), Some(line)) = (empty, data.line()) else {
                continue;
            };
            let name = file_name_of_topic(topic);
            if let Some(other) = names.insert(name.clone(), topic.clone()) {
                return Err(ImportError::Implausible {
                    path: self.path.clone(),
                    sensor: topic.clone(),
                    message: format!("topics {other} and {topic} both make the name {name}"),
                });
            }
            let median_s = line.steps.sampling_without_gaps().map(|s| s.median_step_s);
            outputs.insert(
                topic.clone(),
                Output {
                    sensor: layouts.len(),
                    gyro,
                    accel,
                    gap_s: median_s.map_or(f64::INFINITY, |m| Sampling::GAP_STEPS * m),
                    previous_s: None,
                    gaps: Vec::new(),
                },
            );
            layouts.push(rows::layout(name, &empty));
        }
        Ok((layouts, outputs))
    }

    /// The gaps a pass that wrote the rows found, by topic.
    pub fn gaps(self) -> BTreeMap<String, Vec<(f64, f64)>> {
        match self.out {
            Out::Rows { outputs, .. } => outputs.into_iter().map(|(t, o)| (t, o.gaps)).collect(),
            _ => BTreeMap::new(),
        }
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
    /// The kept stamps' steps.
    steps: StepCounts,
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
            self.steps.push(stamp_seconds(stamp.ns));
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

/// ns since the Unix epoch -> s, rounded once (the integer seconds are exact in an f64).
fn stamp_seconds(ns: i128) -> f64 {
    let sec = ns.div_euclid(1_000_000_000);
    let nsec = ns.rem_euclid(1_000_000_000);
    sec as f64 + nsec as f64 * 1e-9
}

/// The note on a kept time line: median rate, jitter and, where a pass that wrote the rows
/// found them, its gaps.
fn sampling_note(topic: &str, line: &StampLine, gaps: Option<&[(f64, f64)]>) -> Option<String> {
    let mut sampling = line.steps.sampling_without_gaps()?;
    sampling.gaps = gaps.map(<[_]>::to_vec).unwrap_or_default();
    Some(format!("{topic}: {sampling}"))
}

impl Collector<'_> {
    /// The report: what each topic held and what was done with it, in topic name order.
    /// `gaps` are the time lines' gaps a pass that wrote the rows found ([`Collector::gaps`]);
    /// without them (a streamed Imu topic, whose reader measures its own time line) an Imu
    /// topic's time line is not described.
    pub fn report(&self, gaps: Option<&BTreeMap<String, Vec<(f64, f64)>>>) -> BagReport {
        let mut notes = Vec::new();
        for (topic, data) in &self.topics {
            let gaps = gaps.map(|g| g.get(topic).map_or(&[][..], Vec::as_slice));
            match data {
                TopicData::Imu(t) => imu_notes(topic, t, gaps, &mut notes),
                TopicData::Fix(t) => fix_notes(topic, t, gaps, &mut notes),
                TopicData::Odometry(t) => odometry_notes(topic, t, gaps, &mut notes),
                TopicData::Other { msg_type, count } => notes.push(match &self.only {
                    Some(only) if *only != file_name_of_topic(topic) => format!(
                        "{topic}: {count} messages of {msg_type}, not read (only {only} was asked)"
                    ),
                    _ => format!(
                        "{topic}: {count} messages of {msg_type}, not read (dynacal reads {IMU}, {NAV_SAT_FIX}, {ODOMETRY})"
                    ),
                }),
            }
        }
        BagReport { notes }
    }
}

fn imu_notes(topic: &str, t: &ImuTopic, gaps: Option<&[(f64, f64)]>, notes: &mut Vec<String>) {
    let count = t.line.messages;
    let Some(first) = t.first else {
        return;
    };
    notes.extend(t.line.notes(topic));
    if !t.varies {
        notes.push(format!(
            "{topic}: skipped, not a sensor: its {count} angular velocities are all {:?} and its linear accelerations all {:?}",
            first.0, first.1
        ));
        return;
    }
    let partly = |absent: usize| absent > 0 && absent < count;
    if partly(t.gyro_covariance.absent) || partly(t.accel_covariance.absent) {
        notes.push(format!(
            "{topic}: some messages state no angular velocity or no acceleration (covariance -1) and others do: kept as data"
        ));
    }
    // A streamed topic's time line is summarised by its reader (`dynacal noise`).
    if gaps.is_some() {
        notes.extend(sampling_note(topic, &t.line, gaps));
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
}

fn fix_notes(topic: &str, t: &FixTopic, gaps: Option<&[(f64, f64)]>, notes: &mut Vec<String>) {
    if t.no_fix > 0 {
        notes.push(format!(
            "{topic}: {} messages without a fix (status -1) left out",
            t.no_fix
        ));
    }
    if t.line.messages == 0 {
        notes.push(format!("{topic}: skipped, no fix"));
        return;
    }
    notes.extend(t.line.notes(topic));
    notes.extend(sampling_note(topic, &t.line, gaps));
}

fn odometry_notes(
    topic: &str,
    t: &OdometryTopic,
    gaps: Option<&[(f64, f64)]>,
    notes: &mut Vec<String>,
) {
    if let Some((bad, orientation)) = t.not_unit {
        notes.push(format!(
            "{topic}: skipped: orientation {orientation:?} of message {bad} is not a unit quaternion, so neither attitude nor velocity can be told"
        ));
        return;
    }
    notes.extend(t.line.notes(topic));
    notes.extend(sampling_note(topic, &t.line, gaps));
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
}
