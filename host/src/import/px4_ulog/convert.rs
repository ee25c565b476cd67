//! From ULog topics to interchange rows (the conversions the parent module's documentation
//! lists): `sensor_combined`, the raw `sensor_gyro`/`sensor_accel` instances, the
//! `vehicle_imu` instances, and the GPS + attitude reference.
//!
//! A log file is imported in two walks ([`stream`]), in memory that does not grow with its IMU
//! samples. The first checks every message, counts the reference's rows as its samples come
//! ([`Reference`]: a fix and a short stretch of attitude at a time) and learns of the IMU
//! topics what decides their outputs ([`Survey`]: which instances have samples, each raw sensor's device ids,
//! whether an instance's gyro and accelerometer were sampled at the same times); the outputs
//! are then known ([`Plan`]), and the second walk turns each IMU sample into a row of its
//! output as it comes ([`Rows`]), and each fix given its attitude into a row of the reference. A log held whole goes through the same survey, plan and rows
//! ([`read_sensor_imus`] and its siblings).

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::Path;

use super::board::{sensor_to_body, SensorKind, SensorToBody};
use super::{
    corrupt, ImportError, ImuRecording, Quaternion, Sample, Topic, ULog, UnitQuaternion,
    GPS_FIXES_3D, GPS_TOPICS, MAX_ATTITUDE_GAP_S, MAX_QUATERNION_NORM_ERROR,
    RELATIVE_TIMESTAMP_INVALID,
};
use crate::import::frames::{reference_layout, reference_recording, ReferenceRow, ReferenceRows};
use crate::import::rows::{Collect, SensorLayout, SensorRows};
use crate::interchange::CHANNEL_COLUMNS;
use nalgebra::Vector3;

/// The end of a raw IMU output's name when the log gives no board rotation and its data stay
/// in the sensor's axes (`imu0_board`): not the body frame the interchange format expects.
pub const BOARD_FRAME_SUFFIX: &str = "_board";

/// One output of [`read`]: `sensor_combined`, `imu0`, `vehicle_imu0`, `reference`... and its
/// recording.
pub type NamedRecording = (String, ImuRecording);

/// The topic of the attitude the reference interpolates (instance 0).
const ATTITUDE_TOPIC: &str = "vehicle_attitude";

/// The three fields `names` of a sample, each present and finite.
fn vector(s: &Sample, names: [&str; 3]) -> Result<[f64; 3], ImportError> {
    Ok([
        s.required(names[0])?,
        s.required(names[1])?,
        s.required(names[2])?,
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

/// The sample-time field of a raw sensor or `vehicle_imu` topic: `timestamp_sample`, else
/// `timestamp`.
fn sample_clock(topic: &Topic) -> &'static str {
    if topic.has("timestamp_sample") {
        "timestamp_sample"
    } else {
        "timestamp"
    }
}

/// The raw sensor a topic is, by its name.
fn raw_kind(name: &str) -> Option<SensorKind> {
    match name {
        "sensor_gyro" => Some(SensorKind::Gyro),
        "sensor_accel" => Some(SensorKind::Accel),
        _ => None,
    }
}

/// The device ids one raw sensor topic's samples carry.
#[derive(Debug, Default)]
struct DeviceIds {
    /// The first sample's, where the format has the field.
    first: Option<f64>,
    /// The distinct ids seen, at most two (two already say the samples are not one chip's).
    seen: BTreeSet<u64>,
}

/// Whether the gyro and accelerometer of one instance were sampled at the same times, one
/// for one, judged as their samples come: the times of whichever is ahead wait for the other's.
#[derive(Debug)]
struct TimesAgree {
    waiting: VecDeque<f64>,
    waiting_are_gyro: bool,
    agree: bool,
}

impl Default for TimesAgree {
    fn default() -> Self {
        Self {
            waiting: VecDeque::new(),
            waiting_are_gyro: false,
            agree: true,
        }
    }
}

impl TimesAgree {
    fn observe(&mut self, is_gyro: bool, t: Option<f64>) {
        if !self.agree {
            return;
        }
        match t {
            Some(t) if !self.waiting.is_empty() && self.waiting_are_gyro != is_gyro => {
                if self.waiting.pop_front() != Some(t) {
                    self.disagree();
                }
            }
            Some(t) => {
                self.waiting_are_gyro = is_gyro;
                self.waiting.push_back(t);
            }
            None => self.disagree(),
        }
    }

    fn disagree(&mut self) {
        self.agree = false;
        self.waiting = VecDeque::new();
    }

    fn agreed(&self) -> bool {
        self.agree && self.waiting.is_empty()
    }
}

/// What the first walk learns of the raw sensors' samples.
#[derive(Debug, Default)]
pub(super) struct Survey {
    /// By topic position.
    device_ids: BTreeMap<usize, DeviceIds>,
    /// By instance.
    times: BTreeMap<u8, TimesAgree>,
}

impl Survey {
    fn observe(&mut self, s: &Sample) {
        let Some(kind) = raw_kind(&s.topic.name) else {
            return;
        };
        let ids = self.device_ids.entry(s.topic.position()).or_default();
        let id = s.value("device_id");
        if s.index == 0 {
            ids.first = id;
        }
        if let Some(id) = id.filter(|_| ids.seen.len() < 2) {
            ids.seen.insert(id as u64);
        }
        let t = s.value(sample_clock(s.topic)).filter(|t| t.is_finite());
        self.times
            .entry(s.topic.multi_id)
            .or_default()
            .observe(kind == SensorKind::Gyro, t);
    }

    /// The first sample's device id of raw topic `topic`.
    fn first_device_id(&self, topic: &Topic) -> Option<f64> {
        self.device_ids.get(&topic.position())?.first
    }

    /// True when instance `k`'s gyro and accelerometer come from one chip sampled together:
    /// the same single `device_id` throughout (where both formats have one) and the same
    /// sample times, one for one.
    fn same_device(&self, gyro: &Topic, accel: &Topic) -> bool {
        let ids = |t: &Topic| {
            t.has("device_id")
                .then(|| self.device_ids.get(&t.position()).map(|d| &d.seen))
                .flatten()
        };
        let ids_agree = match (ids(gyro), ids(accel)) {
            (Some(g), Some(a)) => g.len() == 1 && g == a,
            _ => true,
        };
        ids_agree
            && self
                .times
                .get(&gyro.multi_id)
                .is_some_and(TimesAgree::agreed)
    }
}

/// Where one IMU topic's samples go.
#[derive(Debug, Clone)]
enum Source {
    /// `sensor_combined`: gyro and accelerometer, body frame, on `timestamp`.
    Combined,
    /// `vehicle_imu`: integrated angle and velocity as mean rates.
    VehicleImu,
    /// `sensor_gyro` or `sensor_accel`, turned into the body's axes where the log says how;
    /// `joined` when the instance's gyro and accelerometer share one output.
    Raw {
        kind: SensorKind,
        to_body: Option<SensorToBody>,
        joined: bool,
    },
}

/// The output (an index into [`Plan::sensors`]) and conversion of one IMU topic.
#[derive(Debug, Clone)]
struct Route {
    sensor: usize,
    source: Source,
}

/// The IMU outputs of a log, decided from its survey: their layouts, in the order written,
/// and the route of each topic's samples.
#[derive(Debug)]
pub(super) struct Plan {
    sensors: Vec<SensorLayout>,
    /// By topic position; `None` for a topic no output reads.
    routes: Vec<Option<Route>>,
}

/// The layout of a raw sensor written alone: `t_s` and its triplet.
fn raw_layout(name: String, kind: SensorKind) -> SensorLayout {
    let triplet = match kind {
        SensorKind::Gyro => &CHANNEL_COLUMNS[..3],
        SensorKind::Accel => &CHANNEL_COLUMNS[3..],
    };
    let mut columns = vec!["t_s"];
    columns.extend(triplet);
    SensorLayout {
        name,
        columns,
        rate_hz: None,
    }
}

impl Plan {
    /// The outputs of the IMU topics `wanted` accepts (see the parent module's documentation):
    /// every `sensor_combined` instance, then each raw instance (`imu{k}`, or `gyro{k}` and
    /// `accel{k}`), then every `vehicle_imu` instance.
    fn new(
        log: &ULog,
        survey: &Survey,
        wanted: &dyn Fn(&str) -> bool,
    ) -> Result<Self, ImportError> {
        let mut plan = Plan {
            sensors: Vec::new(),
            routes: vec![None; log.topics().len()],
        };
        let logged = |name: &'static str| {
            log.instances(name)
                .filter(move |t| !t.is_empty() && wanted(name))
        };
        for topic in logged("sensor_combined") {
            let name = format!("sensor_combined{}", instance_suffix(topic.multi_id));
            plan.add(topic, SensorLayout::imu(name), Source::Combined);
        }
        let raw_ids: BTreeSet<u8> = logged("sensor_gyro")
            .chain(logged("sensor_accel"))
            .map(|t| t.multi_id)
            .collect();
        for k in raw_ids {
            plan.add_raw(log, survey, k)?;
        }
        for topic in logged("vehicle_imu") {
            let name = format!("vehicle_imu{}", topic.multi_id);
            plan.add(topic, SensorLayout::imu(name), Source::VehicleImu);
        }
        Ok(plan)
    }

    fn add(&mut self, topic: &Topic, layout: SensorLayout, source: Source) {
        self.routes[topic.position()] = Some(Route {
            sensor: self.sensors.len(),
            source,
        });
        self.sensors.push(layout);
    }

    /// Raw instance `k`: one output when its gyro and accelerometer are one chip sampled
    /// together ([`Survey::same_device`]) in the same frame, else one for each.
    fn add_raw(&mut self, log: &ULog, survey: &Survey, k: u8) -> Result<(), ImportError> {
        let mut raw = Vec::new();
        for kind in [SensorKind::Gyro, SensorKind::Accel] {
            let name = match kind {
                SensorKind::Gyro => "sensor_gyro",
                SensorKind::Accel => "sensor_accel",
            };
            if let Some(topic) = log.topic(name, k).filter(|t| !t.is_empty()) {
                let to_body = sensor_to_body(log, kind, survey.first_device_id(topic))?;
                raw.push((kind, topic, to_body));
            }
        }
        let suffix = |to_body: &Option<SensorToBody>| {
            if to_body.is_some() {
                ""
            } else {
                BOARD_FRAME_SUFFIX
            }
        };
        let joined = matches!(&raw[..], [(_, g, gb), (_, a, ab)]
            if survey.same_device(g, a) && suffix(gb) == suffix(ab));
        if joined {
            let layout = SensorLayout::imu(format!("imu{k}{}", suffix(&raw[1].2)));
            self.sensors.push(layout);
        }
        for (kind, topic, to_body) in raw {
            if !joined {
                let prefix = match kind {
                    SensorKind::Gyro => "gyro",
                    SensorKind::Accel => "accel",
                };
                let name = format!("{prefix}{k}{}", suffix(&to_body));
                self.sensors.push(raw_layout(name, kind));
            }
            self.routes[topic.position()] = Some(Route {
                sensor: self.sensors.len() - 1,
                source: Source::Raw {
                    kind,
                    to_body,
                    joined,
                },
            });
        }
        Ok(())
    }
}

/// `value / (dt_us / 1e6)` for the three axes of `delta`, `dt_us` checked positive.
fn per_second(s: &Sample, delta: &str, dt_field: &str) -> Result<[f64; 3], ImportError> {
    let dt_us = s.required(dt_field)?;
    if dt_us <= 0.0 {
        return Err(s.error(format!("`{dt_field}` is {dt_us} µs")));
    }
    let names = [0, 1, 2].map(|a| format!("{delta}[{a}]"));
    let v = vector(s, [&names[0], &names[1], &names[2]])?;
    Ok(v.map(|x| x / (dt_us * 1e-6)))
}

/// The gyro and accelerometer samples of a joined raw instance waiting for their partner:
/// time (s) and axes in the body frame.
#[derive(Debug, Default)]
struct Join {
    gyro: VecDeque<(f64, [f64; 3])>,
    accel: VecDeque<(f64, [f64; 3])>,
}

/// Turns IMU samples into rows of their outputs as a [`Plan`] routes them.
struct Rows<'p> {
    plan: &'p Plan,
    /// The last sample time of each topic, s, by topic position.
    previous: Vec<Option<f64>>,
    /// By output.
    joins: BTreeMap<usize, Join>,
}

impl<'p> Rows<'p> {
    fn new(plan: &'p Plan) -> Self {
        Self {
            plan,
            previous: vec![None; plan.routes.len()],
            joins: BTreeMap::new(),
        }
    }

    /// The row of sample `s` to `sink`, if an output reads its topic (a joined raw sample
    /// waits for its partner's).
    fn sample(&mut self, s: &Sample, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
        let position = s.topic.position();
        let Some(route) = self.plan.routes.get(position).and_then(Option::as_ref) else {
            return Ok(());
        };
        let previous = self.previous[position];
        let (t, first, second) = match &route.source {
            Source::Combined => {
                let t = s.time_s("timestamp", previous)?;
                if s.value("accelerometer_timestamp_relative") == Some(RELATIVE_TIMESTAMP_INVALID) {
                    return Err(s.error("the sample has no accelerometer value"));
                }
                let gyro = vector(s, ["gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"])?;
                let accel = [
                    "accelerometer_m_s2[0]",
                    "accelerometer_m_s2[1]",
                    "accelerometer_m_s2[2]",
                ];
                (t, gyro, Some(vector(s, accel)?))
            }
            Source::VehicleImu => {
                let t = s.time_s(sample_clock(s.topic), previous)?;
                let omega = per_second(s, "delta_angle", "delta_angle_dt")?;
                (
                    t,
                    omega,
                    Some(per_second(s, "delta_velocity", "delta_velocity_dt")?),
                )
            }
            Source::Raw {
                kind,
                to_body,
                joined,
            } => {
                let t = s.time_s(sample_clock(s.topic), previous)?;
                let v = vector(s, ["x", "y", "z"])?;
                let v = match to_body {
                    Some(to_body) => (to_body.r_b_s * Vector3::from(v)).into(),
                    None => v,
                };
                self.previous[position] = Some(t);
                if *joined {
                    return self.join(route.sensor, *kind, t, v, sink);
                }
                (t, v, None)
            }
        };
        self.previous[position] = Some(t);
        let mut row = [t; 7];
        row[1..4].copy_from_slice(&first);
        match second {
            Some(second) => {
                row[4..].copy_from_slice(&second);
                sink.push(route.sensor, &row)
            }
            None => sink.push(route.sensor, &row[..4]),
        }
    }

    /// A joined raw sample: its row once the partner with the same place in its series has
    /// come (the survey found their times equal one for one).
    fn join(
        &mut self,
        sensor: usize,
        kind: SensorKind,
        t: f64,
        v: [f64; 3],
        sink: &mut dyn SensorRows,
    ) -> Result<(), ImportError> {
        let join = self.joins.entry(sensor).or_default();
        let (mine, theirs) = match kind {
            SensorKind::Gyro => (&mut join.gyro, &mut join.accel),
            SensorKind::Accel => (&mut join.accel, &mut join.gyro),
        };
        let Some((_, other)) = theirs.pop_front() else {
            mine.push_back((t, v));
            return Ok(());
        };
        let (gyro, accel) = match kind {
            SensorKind::Gyro => (v, other),
            SensorKind::Accel => (other, v),
        };
        let mut row = [t; 7];
        row[1..4].copy_from_slice(&gyro);
        row[4..].copy_from_slice(&accel);
        sink.push(sensor, &row)
    }

    /// Checks no joined sample was left without its partner (the file changed between the
    /// walks).
    fn finish(&self, path: &Path) -> Result<(), ImportError> {
        for (sensor, join) in &self.joins {
            if !join.gyro.is_empty() || !join.accel.is_empty() {
                return Err(corrupt(
                    path,
                    0,
                    format!(
                        "`{}`: its gyro and accelerometer samples no longer pair one for one \
                         (did the file change while it was read?)",
                        self.plan.sensors[*sensor].name
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The IMU outputs of the topics `wanted` accepts, from a log held whole.
fn read_held(
    log: &ULog,
    wanted: &dyn Fn(&str) -> bool,
) -> Result<Vec<NamedRecording>, ImportError> {
    let samples = || {
        log.topics()
            .iter()
            .filter(|t| wanted(&t.name))
            .flat_map(|t| log.held_samples(t))
    };
    let mut survey = Survey::default();
    samples().for_each(|s| survey.observe(&s));
    let plan = Plan::new(log, &survey, wanted)?;
    let mut collect = Collect::new(log.path());
    collect.begin(plan.sensors.clone())?;
    let mut rows = Rows::new(&plan);
    for s in samples() {
        rows.sample(&s, &mut collect)?;
    }
    rows.finish(log.path())?;
    Ok(collect
        .into_sensors()?
        .into_iter()
        .map(|s| (s.name, s.recording))
        .collect())
}

/// Every `sensor_combined` instance (normally one) of a log held whole: gyro and
/// accelerometer in the body frame, calibrated, on `timestamp`.
pub fn read_sensor_combined(log: &ULog) -> Result<Vec<NamedRecording>, ImportError> {
    read_held(log, &|name| name == "sensor_combined")
}

/// Every `sensor_gyro` / `sensor_accel` instance of a log held whole, on `timestamp_sample`,
/// uncalibrated, turned into the body's axes with the log's board rotation
/// ([`sensor_to_body`]). Instance k's gyro and accelerometer share `imu{k}` when they are one
/// chip sampled together in the same frame, else they are `gyro{k}` and `accel{k}`. Without a
/// rotation in the log the data stay in the sensor's axes and the name ends in
/// [`BOARD_FRAME_SUFFIX`].
pub fn read_sensor_imus(log: &ULog) -> Result<Vec<NamedRecording>, ImportError> {
    read_held(log, &|name| raw_kind(name).is_some())
}

/// Every `vehicle_imu` instance of a log held whole: the integrated angle and velocity over
/// their intervals as mean rates (rad/s, m/s^2), calibrated and in the body frame, on
/// `timestamp_sample`.
pub fn read_vehicle_imus(log: &ULog) -> Result<Vec<NamedRecording>, ImportError> {
    read_held(log, &|name| name == "vehicle_imu")
}

/// Latitude, longitude (rad) and ellipsoidal height (m) of a GPS sample, from the
/// integer fields (1e-7 deg, mm) or the newer float ones (deg, m).
fn gps_position(s: &Sample) -> Result<[f64; 3], ImportError> {
    let (lat_deg, lon_deg) = if s.topic.has("lat") {
        (s.required("lat")? * 1e-7, s.required("lon")? * 1e-7)
    } else {
        (s.required("latitude_deg")?, s.required("longitude_deg")?)
    };
    let h_m = if s.topic.has("alt_ellipsoid") {
        s.required("alt_ellipsoid")? * 1e-3
    } else {
        s.required("altitude_ellipsoid_m")?
    };
    if lat_deg.abs() > 90.0 || lon_deg.abs() > 180.0 {
        return Err(s.error(format!(
            "position {lat_deg} deg, {lon_deg} deg is not on Earth"
        )));
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

/// The place in [`GPS_TOPICS`] of the topic the reference reads ([`gps_topic`]).
fn gps_topic_index(log: &ULog) -> Option<usize> {
    let topic = gps_topic(log)?;
    GPS_TOPICS.iter().position(|n| *n == topic.name)
}

/// The reference as a log's samples come (see the parent module's documentation): the
/// attitude of `vehicle_attitude` 0 interpolated to the 3D fixes of the GPS topics (instance
/// 0) it follows ([`ReferenceRows`]). A first walk follows every one of [`GPS_TOPICS`], counting
/// their rows, as which of them the reference reads ([`gps_topic`]), and so which errors
/// count, is known at the end ([`Reference::chosen`]); a walk that writes the rows follows
/// that one.
pub(super) struct Reference {
    attitude_previous_s: Option<f64>,
    attitude_error: Option<ImportError>,
    /// In [`GPS_TOPICS`]' order; `None` for a topic not followed.
    gps: Vec<Option<ReferenceRows>>,
}

impl Reference {
    /// Following every GPS topic, counting its rows.
    pub(super) fn counting() -> Self {
        Self::following(|_| Some(ReferenceRows::new(MAX_ATTITUDE_GAP_S, false)))
    }

    /// Following the GPS topic `k` of [`GPS_TOPICS`], keeping its rows until taken.
    pub(super) fn writing(k: usize) -> Self {
        Self::following(|i| (i == k).then(|| ReferenceRows::new(MAX_ATTITUDE_GAP_S, true)))
    }

    fn following(rows: impl Fn(usize) -> Option<ReferenceRows>) -> Self {
        Self {
            attitude_previous_s: None,
            attitude_error: None,
            gps: (0..GPS_TOPICS.len()).map(rows).collect(),
        }
    }

    /// Sample `s`, if it is one the reference reads.
    pub(super) fn observe(&mut self, s: &Sample) {
        if s.topic.multi_id != 0 {
            return;
        }
        if s.topic.name == ATTITUDE_TOPIC && self.attitude_error.is_none() {
            match attitude(s, self.attitude_previous_s) {
                Ok((t, q)) => {
                    self.attitude_previous_s = Some(t);
                    for rows in self.gps.iter_mut().flatten() {
                        rows.attitude(t, q);
                    }
                }
                Err(e) => self.attitude_error = Some(e),
            }
        } else if let Some(k) = GPS_TOPICS.iter().position(|n| *n == s.topic.name) {
            let Some(rows) = self.gps[k].as_mut().filter(|r| r.error.is_none()) else {
                return;
            };
            match fix_time(s, rows.previous_fix_s) {
                Ok(Some(t)) => {
                    let velocity = ["vel_n_m_s", "vel_e_m_s", "vel_d_m_s"];
                    let values = gps_position(s).and_then(|p| {
                        let v = vector(s, velocity)?;
                        Ok([p[0], p[1], p[2], v[0], v[1], v[2]])
                    });
                    rows.fix(t, values);
                }
                Ok(None) => {}
                Err(e) => rows.error = Some(e),
            }
        }
    }

    /// The place in [`GPS_TOPICS`] of the topic the reference of `log` (whose samples these
    /// were) reads, if it has rows; the error that fails the reference.
    pub(super) fn chosen(&mut self, log: &ULog) -> Result<Option<usize>, ImportError> {
        let Some(k) = gps_topic_index(log) else {
            return Ok(None);
        };
        if let Some(e) = self.failed(k) {
            return Err(e);
        }
        Ok(self.gps[k].as_ref().filter(|r| r.count > 0).map(|_| k))
    }

    /// The error that fails the reference read from GPS topic `k`, taken.
    pub(super) fn failed(&mut self, k: usize) -> Option<ImportError> {
        self.attitude_error
            .take()
            .or_else(|| self.gps[k].as_mut()?.error.take())
    }

    /// The rows formed since the last call, of the GPS topic followed to write them.
    pub(super) fn take_rows(&mut self) -> impl Iterator<Item = ReferenceRow> + '_ {
        self.gps.iter_mut().flatten().flat_map(|r| r.take())
    }
}

/// A `vehicle_attitude` sample: time (s, boot clock, after `previous_s`) and attitude (body
/// FRD to NED).
fn attitude(
    s: &Sample,
    previous_s: Option<f64>,
) -> Result<(f64, UnitQuaternion<f64>), ImportError> {
    let t = s.time_s("timestamp", previous_s)?;
    let mut q = [0.0; 4];
    for (a, v) in q.iter_mut().enumerate() {
        *v = s.required(&format!("q[{a}]"))?;
    }
    let q = Quaternion::new(q[0], q[1], q[2], q[3]);
    if (q.norm() - 1.0).abs() > MAX_QUATERNION_NORM_ERROR {
        return Err(s.error(format!("quaternion `q` has the norm {}, not 1", q.norm())));
    }
    Ok((t, UnitQuaternion::from_quaternion(q)))
}

/// The time (s, boot clock, after `previous_s`) of a GPS sample that is a measured 3D fix
/// with its velocity; `None` for another sample.
fn fix_time(s: &Sample, previous_s: Option<f64>) -> Result<Option<f64>, ImportError> {
    if !GPS_FIXES_3D.contains(&s.required("fix_type")?) || s.value("vel_ned_valid") == Some(0.0) {
        return Ok(None);
    }
    s.time_s("timestamp", previous_s).map(Some)
}

/// The reference recording of a log held whole: 3D GPS fixes with NED velocity and the
/// interpolated `vehicle_attitude` (see the parent module's documentation), the samples in
/// file order as a walk meets them ([`Reference`]). `None` when the log has no GPS fix inside
/// the attitude's span.
pub fn read_reference(log: &ULog) -> Result<Option<ImuRecording>, ImportError> {
    let Some(k) = gps_topic_index(log) else {
        return Ok(None);
    };
    let mut samples: Vec<Sample> = log
        .topics()
        .iter()
        .filter(|t| reference_topic(&t.name) && t.multi_id == 0)
        .flat_map(|t| log.held_samples(t))
        .collect();
    samples.sort_by_key(|s| s.offset);
    let mut reference = Reference::writing(k);
    let mut rows = Vec::new();
    for s in &samples {
        reference.observe(s);
        rows.extend(reference.take_rows());
    }
    if let Some(e) = reference.failed(k) {
        return Err(e);
    }
    if rows.is_empty() {
        return Ok(None);
    }
    let rec = reference_recording(&rows);
    rec.validate(log.path())?;
    Ok(Some(rec))
}

/// True for the topics the reference reads.
pub fn reference_topic(name: &str) -> bool {
    name == ATTITUDE_TOPIC || GPS_TOPICS.contains(&name)
}

/// Streams a log into `sink` as its IMU outputs (`sensor_combined`, `imu{k}` or
/// `gyro{k}`/`accel{k}`, `vehicle_imu{k}`) and, where it has 3D GPS fixes and
/// `vehicle_attitude`, a `reference`, in two walks over the file (the module's documentation).
/// A log with none of the IMU topics is an error.
pub fn stream(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    let (mut survey, mut counting) = (Survey::default(), Reference::counting());
    let log = ULog::walk(path, &|_| false, &mut |s| {
        survey.observe(&s);
        counting.observe(&s);
        Ok(())
    })?;
    let plan = Plan::new(&log, &survey, &|_| true)?;
    if plan.sensors.is_empty() {
        return Err(corrupt(
            path,
            0,
            format!(
                "no samples of sensor_combined, sensor_gyro, sensor_accel or vehicle_imu among its {} topic instances",
                log.topics().len()
            ),
        ));
    }
    let chosen = counting.chosen(&log)?;
    drop(log);
    let mut sensors = plan.sensors.clone();
    sensors.extend(chosen.map(|_| reference_layout("reference")));
    sink.begin(sensors)?;
    let mut rows = Rows::new(&plan);
    let mut reference = chosen.map(Reference::writing);
    ULog::walk(path, &|_| false, &mut |s| {
        rows.sample(&s, sink)?;
        if let Some((reference, k)) = reference.as_mut().zip(chosen) {
            reference.observe(&s);
            if let Some(e) = reference.failed(k) {
                return Err(e);
            }
            for row in reference.take_rows() {
                sink.push(plan.sensors.len(), &row)?;
            }
        }
        Ok(())
    })?;
    rows.finish(path)
}

/// Reads a log into its IMU recordings and reference ([`stream`] collected).
pub fn read(path: &Path) -> Result<Vec<NamedRecording>, ImportError> {
    Ok(crate::import::rows::collect_named(path, |sink| stream(path, sink))?.0)
}
