//! ArduPilot DataFlash binary logs (`.bin`, e.g. `ardupilot-3imu-copter/log171.bin`): every
//! IMU instance as its own interchange recording, and a reference recording of GPS position
//! and velocity with the autopilot's attitude (`ATT`).
//!
//! The format is self-describing: each message is `A3 95 <type>` and a payload whose layout
//! an earlier `FMT` message (type 0x80, 89 bytes, itself of layout `BBnNZ`) defines: type,
//! total length, a 4-character name, up to 16 format letters and comma-separated labels.
//! Letters `c C e E` are integers in hundredths (centidegrees, centimetres, cm/s), `L` is
//! latitude or longitude in 1e-7 degrees; this module returns them scaled ([`decode_number`]),
//! so an `ATT` roll reads in degrees whether the firmware logs `c` (centidegrees, Copter 3.3)
//! or `f` (degrees, 4.x).
//!
//! The parser is written here rather than taken from the `ardupilot-binlog` crate (0.2.0, which
//! would build: edition 2024 needs Rust 1.85, our `rust-version`): that crate resynchronises
//! silently on corrupt bytes, drops a truncated last message without a word, stops after 256
//! consecutive bad messages as if the log had ended, gives no byte offsets, and computes a
//! payload length as `length - 3` unchecked, which overflows on a `FMT` declaring fewer than 3
//! bytes. A damaged log would import with samples missing and nobody told. Here any byte that
//! is not part of a whole message of a defined type is an error naming the file, the byte
//! offset and the message index.
//!
//! Conversions (`docs/formats.md`, section 2):
//! - IMU: `IMU`, `IMU2`, `IMU3` (Copter 3.x) or `IMU` with an instance field `I` (4.x) become
//!   `imu0`, `imu1`, `imu2`. `GyrX/Y/Z` rad/s and `AccX/Y/Z` m/s^2 as logged: ArduPilot's body
//!   frame is forward-right-down, so no rotation. `t_s` is the log's own clock, seconds since
//!   the autopilot booted (`TimeUS` / 1e6, or `TimeMS` / 1e3), not rebased to the first sample.
//! - Reference: one row per `GPS` 3D fix (`Status` >= 3) inside the span of `ATT`; `t_s` is the
//!   fix's arrival on the boot clock (`TimeUS`, or `T` in ms on 3.x firmware, whose `TimeMS` is
//!   GPS time of week); lat/lon from `Lat`/`Lng`, `h_m` = `Alt` (above mean sea level: the log
//!   has no geoid height); NED velocity `(Spd cos GCrs, Spd sin GCrs, VZ)`; attitude = `ATT`
//!   roll, pitch, yaw (body FRD w.r.t. NED, Z-Y-X as ours) interpolated to the fix's time by
//!   slerp between the two `ATT` samples around it (a fix whose `ATT` neighbours are more than
//!   [`MAX_ATT_GAP_S`] apart is left out).

use std::collections::{BTreeMap, BTreeSet};
use std::io::Read;
use std::path::{Path, PathBuf};

use nalgebra::UnitQuaternion;

use super::frames::{reference_layout, reference_recording, FixValues, ReferenceRows};
use super::rows::{SensorLayout, SensorRows};
use super::{read_up_to, ImportError};
use crate::interchange::{open_maybe_gz, ImuRecording};

/// The two bytes every DataFlash message starts with.
pub const MESSAGE_HEADER: [u8; 2] = [0xA3, 0x95];
/// The message type of `FMT`, the message that defines message types.
pub const FMT_TYPE: u8 = 0x80;
/// Total length of a `FMT` message, bytes (3 header + 86 payload).
pub const FMT_LENGTH: usize = 89;

/// Largest gap between the two `ATT` samples around a GPS fix for the fix to get an
/// interpolated attitude, s (`ATT` is logged at 10 Hz).
pub const MAX_ATT_GAP_S: f64 = 0.5;

/// Lowest `GPS.Status` that is a 3D fix (ArduPilot's `GPS_OK_FIX_3D`).
pub const GPS_FIX_3D: f64 = 3.0;

/// Size in bytes of one field of DataFlash format letter `letter`, `None` if the letter is
/// not one ArduPilot defines.
pub fn field_size(letter: u8) -> Option<usize> {
    Some(match letter {
        b'b' | b'B' | b'M' => 1,
        b'h' | b'H' | b'c' | b'C' => 2,
        b'i' | b'I' | b'e' | b'E' | b'f' | b'L' | b'n' => 4,
        b'q' | b'Q' | b'd' => 8,
        b'N' => 16,
        b'Z' | b'a' => 64,
        _ => return None,
    })
}

/// The number a field holds, in the unit its letter implies: `c C e E` (hundredths) divided
/// by 100, `L` (1e-7 degrees) times 1e-7, others as stored. `None` for the text and array
/// letters (`n N Z a`) or a slice of the wrong length.
pub fn decode_number(letter: u8, bytes: &[u8]) -> Option<f64> {
    fn arr<const N: usize>(b: &[u8]) -> Option<[u8; N]> {
        b.try_into().ok()
    }
    Some(match letter {
        b'b' => f64::from(i8::from_le_bytes(arr(bytes)?)),
        b'B' | b'M' => f64::from(u8::from_le_bytes(arr(bytes)?)),
        b'h' => f64::from(i16::from_le_bytes(arr(bytes)?)),
        b'H' => f64::from(u16::from_le_bytes(arr(bytes)?)),
        b'i' => f64::from(i32::from_le_bytes(arr(bytes)?)),
        b'I' => f64::from(u32::from_le_bytes(arr(bytes)?)),
        b'q' => i64::from_le_bytes(arr(bytes)?) as f64,
        b'Q' => u64::from_le_bytes(arr(bytes)?) as f64,
        b'f' => f64::from(f32::from_le_bytes(arr(bytes)?)),
        b'd' => f64::from_le_bytes(arr(bytes)?),
        b'c' => f64::from(i16::from_le_bytes(arr(bytes)?)) / 100.0,
        b'C' => f64::from(u16::from_le_bytes(arr(bytes)?)) / 100.0,
        b'e' => f64::from(i32::from_le_bytes(arr(bytes)?)) / 100.0,
        b'E' => f64::from(u32::from_le_bytes(arr(bytes)?)) / 100.0,
        b'L' => f64::from(i32::from_le_bytes(arr(bytes)?)) * 1e-7,
        _ => return None,
    })
}

/// One message type as a `FMT` message defines it.
#[derive(Debug, Clone, PartialEq)]
pub struct MessageFormat {
    /// Message type byte.
    pub type_id: u8,
    /// Total message length, bytes, the 3-byte header included.
    pub length: usize,
    /// Name, e.g. `IMU2`, `GPS`, `ATT`.
    pub name: String,
    /// Format letters, one per field.
    pub format: String,
    /// Field labels, one per format letter.
    pub labels: Vec<String>,
    /// Byte offset of each field from the start of the message (header included).
    offsets: Vec<usize>,
}

impl MessageFormat {
    /// Checks a definition: known letters, a length equal to 3 plus the fields' sizes, one
    /// label per letter. The error says what is wrong (the caller adds where).
    pub fn new(
        type_id: u8,
        length: usize,
        name: &str,
        format: &str,
        labels: &str,
    ) -> Result<Self, String> {
        if name.is_empty() {
            return Err(format!("type {type_id} has an empty name"));
        }
        let mut offsets = Vec::with_capacity(format.len());
        let mut at = 3;
        for letter in format.bytes() {
            let size = field_size(letter).ok_or_else(|| {
                format!(
                    "{name}: format `{format}` has the unknown letter `{}`",
                    letter as char
                )
            })?;
            offsets.push(at);
            at += size;
        }
        if at != length {
            return Err(format!(
                "{name}: length {length} bytes, but its format `{format}` needs {at}"
            ));
        }
        let labels: Vec<String> = if labels.is_empty() {
            Vec::new()
        } else {
            labels.split(',').map(str::to_string).collect()
        };
        if labels.len() != format.len() {
            return Err(format!(
                "{name}: {} labels for the {} letters of format `{format}`",
                labels.len(),
                format.len()
            ));
        }
        Ok(MessageFormat {
            type_id,
            length,
            name: name.to_string(),
            format: format.to_string(),
            labels,
            offsets,
        })
    }

    /// The index of the field labelled `label`.
    pub fn field(&self, label: &str) -> Option<usize> {
        self.labels.iter().position(|l| l == label)
    }
}

/// The layout of `FMT` itself, which no message defines.
fn fmt_format() -> MessageFormat {
    MessageFormat::new(
        FMT_TYPE,
        FMT_LENGTH,
        "FMT",
        "BBnNZ",
        "Type,Length,Name,Format,Columns",
    )
    .unwrap_or_else(|e| unreachable!("the FMT layout is valid: {e}"))
}

/// One message of a log: where it is and which format it has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Message {
    /// 0-based position among the log's messages.
    pub index: usize,
    /// Byte offset of its `A3 95` header in the (decompressed) file.
    pub offset: usize,
    /// Index into [`DataFlashLog::formats`].
    pub format: usize,
    /// Where its bytes start in the log's held bytes (its `offset` when the log is held whole).
    at: usize,
}

/// A parsed DataFlash log: every format defined, and the messages it holds with their bytes:
/// every message when parsed whole ([`DataFlashLog::parse`]), the kept ones after a walk
/// ([`DataFlashLog::walk`]).
#[derive(Debug, Clone)]
pub struct DataFlashLog {
    path: PathBuf,
    /// The held messages' bytes, one after the other.
    bytes: Vec<u8>,
    formats: Vec<MessageFormat>,
    messages: Vec<Message>,
    /// Every message of the file, held or not.
    message_count: usize,
}

/// One message with its bytes, as a walk meets it or the log holds it: its fields by label.
#[derive(Clone, Copy)]
pub struct Record<'a> {
    path: &'a Path,
    format: &'a MessageFormat,
    pub message: Message,
    /// The whole message, its 3-byte header included.
    bytes: &'a [u8],
}

impl Record<'_> {
    /// The message's format's name (`IMU`, `GPS`...).
    pub fn name(&self) -> &str {
        &self.format.name
    }

    /// The numeric field `label`, scaled by its letter ([`decode_number`]); `None` if the
    /// message has no such numeric field.
    pub fn value(&self, label: &str) -> Option<f64> {
        let i = self.format.field(label)?;
        let letter = self.format.format.as_bytes()[i];
        let start = self.format.offsets[i];
        decode_number(letter, self.bytes.get(start..start + field_size(letter)?)?)
    }

    /// An error about this message, naming its index, name and byte offset.
    pub fn error(&self, message: impl std::fmt::Display) -> ImportError {
        corrupt(
            self.path,
            self.message.offset,
            format!(
                "message {} ({}): {message}",
                self.message.index, self.format.name
            ),
        )
    }

    /// Field `label`, which must be present and finite.
    fn required(&self, label: &str) -> Result<f64, ImportError> {
        match self.value(label) {
            Some(v) if v.is_finite() => Ok(v),
            Some(v) => Err(self.error(format!("`{label}` is {v}, not a finite number"))),
            None => Err(self.error(format!("has no numeric field `{label}`"))),
        }
    }

    /// The first of `clocks` (label, units per second) that the message has, in seconds.
    fn time_s(&self, clocks: &[(&str, f64)]) -> Result<f64, ImportError> {
        for (label, unit_per_s) in clocks {
            if self.value(label).is_some() {
                return Ok(self.required(label)? / unit_per_s);
            }
        }
        let names: Vec<&str> = clocks.iter().map(|c| c.0).collect();
        Err(self.error(format!("has no time field ({})", names.join(" or "))))
    }
}

/// An error at a byte offset of `path`.
fn corrupt(path: &Path, offset: usize, message: impl Into<String>) -> ImportError {
    ImportError::Corrupt {
        path: path.to_path_buf(),
        offset: offset as u64,
        message: message.into(),
    }
}

/// Bytes as upper-case hex pairs separated by spaces (`A3 95`).
fn hex(bytes: &[u8]) -> String {
    let pairs: Vec<String> = bytes.iter().map(|b| format!("{b:02X}")).collect();
    pairs.join(" ")
}

/// A NUL-padded text field: the bytes before the first NUL, which must be printable ASCII.
fn text_field(bytes: &[u8]) -> Result<&str, String> {
    let end = bytes.iter().position(|b| *b == 0).unwrap_or(bytes.len());
    let text = &bytes[..end];
    if text.iter().all(|b| (0x20..0x7f).contains(b)) {
        Ok(std::str::from_utf8(text).unwrap_or_default())
    } else {
        Err(format!("text field {:02X?} is not printable ASCII", text))
    }
}

/// Parses the payload of a `FMT` message (`bytes` is the whole 89-byte message).
fn parse_fmt(bytes: &[u8]) -> Result<MessageFormat, String> {
    let type_id = bytes[3];
    let length = usize::from(bytes[4]);
    let name = text_field(&bytes[5..9])?;
    let format = text_field(&bytes[9..25])?;
    let labels = text_field(&bytes[25..89])?;
    let parsed = MessageFormat::new(type_id, length, name, format, labels)?;
    if type_id == FMT_TYPE && parsed != fmt_format() {
        return Err(format!(
            "redefines FMT (type 0x80) as `{format}`, {length} bytes"
        ));
    }
    Ok(parsed)
}

impl DataFlashLog {
    /// Reads and parses a log file (gzip-compressed or not), every message held.
    pub fn read(path: &Path) -> Result<Self, ImportError> {
        Self::walk(path, &|_| true, &mut |_| Ok(()))
    }

    /// Parses a whole log held in memory; `path` is only for messages. Every byte must
    /// belong to a complete message of a type an earlier `FMT` defined.
    pub fn parse(path: &Path, bytes: Vec<u8>) -> Result<Self, ImportError> {
        Self::walk_reader(path, &mut bytes.as_slice(), &|_| true, &mut |_| Ok(()))
    }

    /// Walks the file `path` (gzip-compressed or not) message by message, each checked as
    /// [`DataFlashLog::parse`] checks it, in memory that does not grow with the file: every
    /// message is handed to `visit`, and only those whose format `keep` accepts are held in
    /// the log returned (with the formats).
    pub fn walk(
        path: &Path,
        keep: &dyn Fn(&MessageFormat) -> bool,
        visit: &mut dyn FnMut(Record) -> Result<(), ImportError>,
    ) -> Result<Self, ImportError> {
        let reader = open_maybe_gz(path)?;
        let mut reader = std::io::BufReader::with_capacity(1 << 16, reader);
        Self::walk_reader(path, &mut reader, keep, visit)
    }

    fn walk_reader(
        path: &Path,
        reader: &mut impl Read,
        keep: &dyn Fn(&MessageFormat) -> bool,
        visit: &mut dyn FnMut(Record) -> Result<(), ImportError>,
    ) -> Result<Self, ImportError> {
        let mut log = DataFlashLog {
            path: path.to_path_buf(),
            bytes: Vec::new(),
            formats: vec![fmt_format()],
            messages: Vec::new(),
            message_count: 0,
        };
        let mut by_type: [Option<usize>; 256] = [None; 256];
        by_type[usize::from(FMT_TYPE)] = Some(0);
        let mut buf = vec![0u8; 256];
        let mut offset = 0;
        let io = |e| ImportError::io(path, e);
        loop {
            let index = log.message_count;
            let head = read_up_to(reader, &mut buf[..3]).map_err(io)?;
            if head == 0 {
                break;
            }
            let start = &buf[..head.min(2)];
            if start != &MESSAGE_HEADER[..start.len()] {
                return Err(corrupt(
                    path,
                    offset,
                    format!(
                        "message {index}: expected the message header A3 95, found {}",
                        hex(start)
                    ),
                ));
            }
            if head < 3 {
                return Err(corrupt(
                    path,
                    offset,
                    format!("message {index}: the file ends {head} byte(s) into a message header"),
                ));
            }
            let type_id = buf[2];
            let Some(format) = by_type[usize::from(type_id)] else {
                return Err(corrupt(
                    path,
                    offset,
                    format!("message {index}: type {type_id} (0x{type_id:02X}) has no FMT definition before it"),
                ));
            };
            let length = log.formats[format].length;
            let got = 3 + read_up_to(reader, &mut buf[3..length]).map_err(io)?;
            if got < length {
                return Err(corrupt(
                    path,
                    offset,
                    format!(
                        "message {index} ({}, {length} bytes) is truncated: the file ends after {got} of its bytes",
                        log.formats[format].name,
                    ),
                ));
            }
            let bytes = &buf[..length];
            if type_id == FMT_TYPE {
                let defined = parse_fmt(bytes)
                    .map_err(|e| corrupt(path, offset, format!("message {index} (FMT): {e}")))?;
                by_type[usize::from(defined.type_id)] = Some(log.formats.len());
                log.formats.push(defined);
            }
            let message = Message {
                index,
                offset,
                format,
                at: log.bytes.len(),
            };
            visit(Record {
                path,
                format: &log.formats[format],
                message,
                bytes,
            })?;
            if keep(&log.formats[format]) {
                log.bytes.extend_from_slice(bytes);
                log.messages.push(message);
            }
            log.message_count += 1;
            offset += length;
        }
        Ok(log)
    }

    /// Every format defined, in the order of their `FMT` messages (the first is `FMT`'s own).
    pub fn formats(&self) -> &[MessageFormat] {
        &self.formats
    }
    /// Every message held, in file order.
    pub fn messages(&self) -> &[Message] {
        &self.messages
    }
    /// Number of messages in the file, held or not.
    pub fn message_count(&self) -> usize {
        self.message_count
    }
    /// The format of a message.
    pub fn format_of(&self, m: &Message) -> &MessageFormat {
        &self.formats[m.format]
    }
    /// The held messages named `name`, in file order.
    pub fn named<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Message> + 'a {
        self.messages
            .iter()
            .filter(move |m| self.formats[m.format].name == name)
    }

    /// A held message with its bytes.
    pub fn record(&self, m: &Message) -> Record<'_> {
        let format = &self.formats[m.format];
        Record {
            path: &self.path,
            format,
            message: *m,
            bytes: &self.bytes[m.at..m.at + format.length],
        }
    }

    /// The numeric field `label` of held message `m` ([`Record::value`]).
    pub fn value(&self, m: &Message, label: &str) -> Option<f64> {
        self.record(m).value(label)
    }

    /// An error about held message `m`, naming its index, name and byte offset.
    pub fn error_at(&self, m: &Message, message: impl std::fmt::Display) -> ImportError {
        self.record(m).error(message)
    }
}

/// The boot-clock time fields of IMU and ATT messages: label and units per second.
const BOOT_CLOCK: [(&str, f64); 2] = [("TimeUS", 1e6), ("TimeMS", 1e3)];
/// The boot-clock time of a GPS message: `TimeUS` (4.x), or `T` in ms (3.x, whose `TimeMS` is
/// GPS time of week).
const GPS_BOOT_CLOCK: [(&str, f64); 2] = [("TimeUS", 1e6), ("T", 1e3)];

/// Checks that `t` follows `previous` (the last time of the same series); the error names
/// the message and both times.
fn check_after(
    record: &Record,
    t: f64,
    previous: Option<f64>,
    series: &str,
) -> Result<(), ImportError> {
    match previous {
        Some(p) if !(t > p) => Err(record.error(format!(
            "time {t} s is {} the previous {series} sample's {p} s",
            if t == p { "a duplicate of" } else { "before" }
        ))),
        _ => Ok(()),
    }
}

/// Which IMU a message is: `IMU` (instance from its field `I` where it has one, else 0),
/// `IMU2` = 1, `IMU3` = 2, ...; `None` for other messages.
fn imu_instance(record: &Record) -> Option<usize> {
    let suffix = record.name().strip_prefix("IMU")?;
    if suffix.is_empty() {
        // A 4.x IMU message names its instance; the value was written as a small integer.
        return Some(record.value("I").map_or(0, |i| i as usize));
    }
    let k: usize = suffix.parse().ok()?;
    (2..=9).contains(&k).then(|| k - 1)
}

/// The interchange row of an IMU message: `t_s` on the boot clock (checked to follow
/// `previous`, the instance's last), gyro rad/s, accelerometer m/s^2.
fn imu_row(record: &Record, k: usize, previous: Option<f64>) -> Result<[f64; 7], ImportError> {
    const FIELDS: [&str; 6] = ["GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"];
    let t = record.time_s(&BOOT_CLOCK)?;
    check_after(record, t, previous, &format!("IMU {k}"))?;
    let mut row = [t; 7];
    for (value, label) in row[1..].iter_mut().zip(FIELDS) {
        *value = record.required(label)?;
    }
    Ok(row)
}

/// Every IMU instance of a log held whole as a recording, by instance number (0, 1, 2...).
pub fn read_imus(log: &DataFlashLog) -> Result<BTreeMap<usize, ImuRecording>, ImportError> {
    let mut out: BTreeMap<usize, ImuRecording> = BTreeMap::new();
    for m in log.messages() {
        let record = log.record(m);
        let Some(k) = imu_instance(&record) else {
            continue;
        };
        let rec = out.entry(k).or_insert_with(|| ImuRecording {
            gyro_rad_s: Some(Default::default()),
            accel_m_s2: Some(Default::default()),
            ..Default::default()
        });
        let row = imu_row(&record, k, rec.t_s.last().copied())?;
        rec.t_s.push(row[0]);
        for (triplet, values) in [
            (&mut rec.gyro_rad_s, &row[1..4]),
            (&mut rec.accel_m_s2, &row[4..]),
        ] {
            let columns = triplet.get_or_insert_with(Default::default);
            for (column, v) in columns.iter_mut().zip(values) {
                column.push(*v);
            }
        }
    }
    for rec in out.values() {
        rec.validate(&log.path)?;
    }
    Ok(out)
}

/// An `ATT` message: time (s, boot clock, after `previous_s`) and attitude (body FRD w.r.t.
/// NED).
fn attitude(
    record: &Record,
    previous_s: Option<f64>,
) -> Result<(f64, UnitQuaternion<f64>), ImportError> {
    let t = record.time_s(&BOOT_CLOCK)?;
    check_after(record, t, previous_s, "ATT")?;
    let mut rpy = [0.0; 3];
    for (v, label) in rpy.iter_mut().zip(["Roll", "Pitch", "Yaw"]) {
        let deg = record.required(label)?;
        // Degrees after the letter's scaling; anything larger is a unit the format letters
        // do not explain.
        if deg.abs() > 720.0 {
            return Err(record.error(format!("`{label}` = {deg} is not in degrees")));
        }
        *v = deg.to_radians();
    }
    Ok((t, UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2])))
}

/// The position and NED velocity `(Spd cos GCrs, Spd sin GCrs, VZ)` of a `GPS` message.
fn fix_values(m: &Record) -> FixValues {
    let speed = m.required("Spd")?;
    let course = m.required("GCrs")?.to_radians();
    Ok([
        m.required("Lat")?.to_radians(),
        m.required("Lng")?.to_radians(),
        m.required("Alt")?,
        speed * course.cos(),
        speed * course.sin(),
        m.required("VZ")?,
    ])
}

/// The reference as a log's messages come (see the module docs): the `ATT` attitude
/// interpolated to the first receiver's 3D fixes ([`ReferenceRows`]: counted by a first walk,
/// kept until taken by one that writes them).
struct Reference {
    attitude_previous_s: Option<f64>,
    rows: ReferenceRows,
}

impl Reference {
    fn new(keeps_rows: bool) -> Self {
        Self {
            attitude_previous_s: None,
            rows: ReferenceRows::new(MAX_ATT_GAP_S, keeps_rows),
        }
    }

    /// Message `m`, if it is one the reference reads; the error that fails the reference.
    fn observe(&mut self, m: &Record) -> Result<(), ImportError> {
        match m.name() {
            "ATT" => {
                let (t, q) = attitude(m, self.attitude_previous_s)?;
                self.attitude_previous_s = Some(t);
                self.rows.attitude(t, q);
            }
            // A 4.x log holds every receiver under `GPS` with an instance field `I`.
            "GPS"
                if m.required("Status")? >= GPS_FIX_3D && m.value("I").is_none_or(|i| i == 0.0) =>
            {
                let t = m.time_s(&GPS_BOOT_CLOCK)?;
                check_after(m, t, self.rows.previous_fix_s, "GPS fix")?;
                self.rows.fix(t, fix_values(m));
            }
            _ => {}
        }
        match self.rows.error.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// The reference recording of a log held whole: GPS 3D fixes with NED velocity and the
/// interpolated `ATT` attitude (see the module docs), its messages in file order as a walk
/// meets them ([`Reference`]). `None` when the log has no `ATT` or no fix inside it.
pub fn read_reference(log: &DataFlashLog) -> Result<Option<ImuRecording>, ImportError> {
    let mut reference = Reference::new(true);
    let mut rows = Vec::new();
    for m in log.messages() {
        reference.observe(&log.record(m))?;
        rows.extend(reference.rows.take());
    }
    if rows.is_empty() {
        return Ok(None);
    }
    let rec = reference_recording(&rows);
    rec.validate(&log.path)?;
    Ok(Some(rec))
}

/// One output of [`read`]: `imu0`, `imu1`, ... or `reference`, and its recording.
pub type NamedRecording = (String, ImuRecording);

/// Streams a log into `sink` as `imu{k}` sensors (one per IMU instance, in instance order)
/// and, where the log has GPS fixes and `ATT`, a `reference`, in two walks over the file, in
/// memory that does not grow with it: the first checks every message, counts the reference's
/// rows as its messages come ([`Reference`]) and finds the IMU instances; the second hands
/// each IMU message and each fix given its attitude to `sink` as a row. A log without IMU
/// messages is an error.
pub fn stream(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    let (mut instances, mut counting) = (BTreeSet::new(), Reference::new(false));
    let survey = DataFlashLog::walk(path, &|_| false, &mut |record| {
        instances.extend(imu_instance(&record));
        counting.observe(&record)
    })?;
    if instances.is_empty() {
        return Err(corrupt(
            path,
            0,
            format!(
                "no IMU messages among its {} messages (IMU, IMU2, IMU3 expected)",
                survey.message_count()
            ),
        ));
    }
    let has_reference = counting.rows.count > 0;
    let mut sensors: Vec<SensorLayout> = instances
        .iter()
        .map(|k| SensorLayout::imu(format!("imu{k}")))
        .collect();
    sensors.extend(has_reference.then(|| reference_layout("reference")));
    sink.begin(sensors)?;
    let sensor_of: BTreeMap<usize, usize> =
        instances.iter().enumerate().map(|(i, k)| (*k, i)).collect();
    let mut previous: Vec<Option<f64>> = vec![None; sensor_of.len()];
    let mut reference = Reference::new(true);
    DataFlashLog::walk(path, &|_| false, &mut |record| {
        if has_reference {
            reference.observe(&record)?;
            for row in reference.rows.take() {
                sink.push(sensor_of.len(), &row)?;
            }
        }
        let Some(k) = imu_instance(&record) else {
            return Ok(());
        };
        // The survey saw every instance the file holds.
        let sensor = sensor_of[&k];
        let row = imu_row(&record, k, previous[sensor])?;
        previous[sensor] = Some(row[0]);
        sink.push(sensor, &row)
    })?;
    Ok(())
}

/// Reads a log into `imu{k}` recordings (one per IMU instance) and, where the log has GPS
/// fixes and `ATT`, a `reference` recording ([`stream`] collected).
pub fn read(path: &Path) -> Result<Vec<NamedRecording>, ImportError> {
    Ok(super::rows::collect_named(path, |sink| stream(path, sink))?.0)
}

/// True when `head` (a file's first bytes) starts a DataFlash log: a message header and the
/// `FMT` type.
pub fn is_dataflash(head: &[u8]) -> bool {
    head.len() >= 3 && head[..2] == MESSAGE_HEADER && head[2] == FMT_TYPE
}

#[cfg(test)]
mod tests;
