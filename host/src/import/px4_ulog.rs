//! PX4 ULog flight logs (`.ulg`, e.g. `px4-ulog/sample_log_small.ulg`): the logged IMU
//! topics as interchange recordings (`sensor_combined`, every `sensor_gyro`/`sensor_accel`
//! instance, every `vehicle_imu` instance), and a reference recording of GPS fixes with the
//! estimator's attitude.
//!
//! The format (PX4's "ULog file format" spec) is self-describing: a 16-byte header (magic
//! `ULog 01 12 35`, a version byte, the start time in µs), then messages `u16 payload size,
//! u8 type, payload`, little-endian. Definitions come first: flag bits (`B`), formats (`F`,
//! `name:type field;type field;...` with the basic types `int8_t` ... `uint64_t`, `float`,
//! `double`, `bool`, `char`, arrays `type[n]`, other formats nested by name, `_padding*`
//! fields), information (`I`, `M`), parameters (`P`, `Q`). Then data: a subscription (`A`:
//! multi_id, msg_id, format name) binds a msg_id to one instance of a topic, and each `D`
//! message is `msg_id` and the topic's bytes laid out by its format (a trailing padding field
//! is not written); `R` ends a subscription; `L`/`C` are log strings, `S` sync markers, `O`
//! dropouts. [`ULog`] keeps every topic instance apart (`sensor_gyro` 0, 1, 2), with its fields
//! flattened to names like `gyro_rad[0]` or `current.lat` and read as `f64`.
//!
//! The parser is written here rather than taken from the `px4-ulog` crate (0.1.1): that crate
//! merges the multi_id instances of a topic into one stream (three gyros would read as one
//! gyro jumping between them), swallows parse errors (a damaged message ends its iterator as
//! if the log had ended), and decodes only a few field types. Here every byte must belong to a
//! whole, well-formed message: a bad magic, a message overrunning the file (a truncated last
//! message included), data for a msg_id no `A` subscribed, a payload shorter or longer than
//! its format, a format naming an unknown type or nesting itself, an unknown message type, a
//! malformed key or sync marker are errors naming the file, the byte offset and the message
//! index (the spec lets readers skip unknown message types; here one cannot be told from
//! damage, so it is refused).
//!
//! Conversions (`docs/formats.md`, section 2). Every `t_s` is the log's boot clock, µs / 1e6,
//! not rebased; PX4's body frame is forward-right-down and its navigation frame NED, as ours.
//! - `sensor_combined` -> `sensor_combined`: `gyro_rad[3]` rad/s, `accelerometer_m_s2[3]` m/s^2,
//!   calibrated and in the body frame, `t_s` = `timestamp` (the gyro's); the accelerometer's
//!   own `accelerometer_timestamp_relative` is not applied (0 throughout the sample log), and a
//!   sample marked as having no accelerometer value (`0x7fffffff`) is an error.
//! - `sensor_gyro` k and `sensor_accel` k (x, y, z in rad/s, m/s^2) -> `imu{k}`: uncalibrated
//!   (PX4's calibration offsets and scales are not applied) but turned from the sensor's axes
//!   into the body's with the log's board rotation, `v_b = R_b_s v_s`, `R_b_s` = the level
//!   trims `SENS_BOARD_{X,Y,Z}_OFF` times the rotation `SENS_BOARD_ROT` (or an external
//!   sensor's `CAL_*n_ROT`), every value PX4 defines ([`board`] has the convention). A log
//!   without `SENS_BOARD_ROT` keeps the sensor's axes and the output's name ends in
//!   [`BOARD_FRAME_SUFFIX`] (`imu0_board`). `t_s` = `timestamp_sample` (`timestamp` where the
//!   format has none). Gyro and accelerometer of one instance index share a recording when
//!   both carry the same `device_id` (the same chip), identical sample times and the same
//!   frame; otherwise they are written apart as `gyro{k}` and `accel{k}`.
//! - `vehicle_imu` k -> `vehicle_imu{k}`: `delta_angle[3]` / (`delta_angle_dt` µs) rad/s and
//!   `delta_velocity[3]` / (`delta_velocity_dt` µs) m/s^2, the mean over the interval ending at
//!   `timestamp_sample` (= `t_s`), calibrated and in the body frame.
//! - Reference (no IMU channel): one row per measured 3D GPS fix ([`GPS_FIXES_3D`]) with,
//!   where the format has it, `vel_ned_valid`, from instance 0 of the first of [`GPS_TOPICS`]
//!   with samples (`vehicle_gps_position`, else `sensor_gps`); `t_s` =
//!   `timestamp`; lat/lon from `lat`/`lon` (1e-7 deg) or `latitude_deg`/`longitude_deg`
//!   (double deg); `h_m` the ellipsoidal height `alt_ellipsoid` (mm) or
//!   `altitude_ellipsoid_m`; velocity `vel_n_m_s`, `vel_e_m_s`,
//!   `vel_d_m_s`; attitude from `vehicle_attitude` (instance 0) `q[4]` (Hamilton w, x, y, z,
//!   body FRD to NED) as roll, pitch, yaw Z-Y-X, by slerp between the two samples around the
//!   fix (a fix outside their span, or whose neighbours are more than [`MAX_ATTITUDE_GAP_S`]
//!   apart, is left out).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion};

use super::ImportError;
use crate::interchange::{open_maybe_gz, ImuRecording};

/// The first bytes of every ULog file: `ULog` and 01 12 35.
pub const MAGIC: [u8; 7] = [b'U', b'L', b'o', b'g', 0x01, 0x12, 0x35];
/// Length of the file header (magic, version byte, start time as u64 µs), bytes.
pub const HEADER_LEN: usize = 16;
/// Length of a message header (u16 payload size, u8 type), bytes.
pub const MESSAGE_HEADER_LEN: usize = 3;
/// Highest file version byte this parser reads.
pub const MAX_VERSION: u8 = 1;

/// The most bytes a format can describe: a message's payload length is a u16.
pub const MAX_FORMAT_BYTES: usize = u16::MAX as usize;
/// The payload of a sync message (`S`).
pub const SYNC_MAGIC: [u8; 8] = [0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x12];
/// Length of the flag-bits message's (`B`) payload, bytes: 8 compatible and 8 incompatible
/// flag bytes, three u64 offsets of appended data.
pub const FLAG_BITS_LEN: usize = 40;
/// Bit 0 of the first incompatible flag byte: data were appended at the offsets given.
pub const INCOMPAT_DATA_APPENDED: u8 = 1;
/// `sensor_combined.accelerometer_timestamp_relative` when the sample has no accelerometer
/// value (PX4's `RELATIVE_TIMESTAMP_INVALID`).
pub const RELATIVE_TIMESTAMP_INVALID: f64 = 2_147_483_647.0;
/// Largest gap between the two `vehicle_attitude` samples around a GPS fix for the fix to get
/// an interpolated attitude, s.
pub const MAX_ATTITUDE_GAP_S: f64 = 0.5;
/// The `fix_type` values of a measured 3D fix: 3 (3D), 4 (RTCM code differential), 5 (RTK
/// float), 6 (RTK fixed). 0-2 have no 3D position and 8 (extrapolated) is dead reckoning.
pub const GPS_FIXES_3D: [f64; 4] = [3.0, 4.0, 5.0, 6.0];
/// The GPS topics the reference reads, in order of preference (instance 0 of the first one
/// with samples): `vehicle_gps_position`, the receiver PX4's `vehicle_gps_position` module
/// selects (or blends) from the `sensor_gps` instances and the estimator fuses, then
/// `sensor_gps`, the first receiver itself, for logs without the former. Both carry the same
/// message from PX4 v1.14 (`msg/SensorGps.msg`: `# TOPICS sensor_gps vehicle_gps_position`).
pub const GPS_TOPICS: [&str; 2] = ["vehicle_gps_position", "sensor_gps"];
/// Largest departure of a `vehicle_attitude` quaternion's norm from 1 accepted (a float
/// quaternion is unit to about 1e-7; more is not an attitude).
pub const MAX_QUATERNION_NORM_ERROR: f64 = 1e-3;

/// The basic field types of a ULog format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BasicType {
    Int8,
    UInt8,
    Int16,
    UInt16,
    Int32,
    UInt32,
    Int64,
    UInt64,
    Float,
    Double,
    Bool,
    Char,
}

impl BasicType {
    /// The type of a ULog type name (`int8_t` ... `uint64_t`, `float`, `double`, `bool`,
    /// `char`), `None` for any other name (a nested format, or nothing ULog defines).
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "int8_t" => Self::Int8,
            "uint8_t" => Self::UInt8,
            "int16_t" => Self::Int16,
            "uint16_t" => Self::UInt16,
            "int32_t" => Self::Int32,
            "uint32_t" => Self::UInt32,
            "int64_t" => Self::Int64,
            "uint64_t" => Self::UInt64,
            "float" => Self::Float,
            "double" => Self::Double,
            "bool" => Self::Bool,
            "char" => Self::Char,
            _ => return None,
        })
    }

    /// Size of one value, bytes.
    pub fn size(self) -> usize {
        match self {
            Self::Int8 | Self::UInt8 | Self::Bool | Self::Char => 1,
            Self::Int16 | Self::UInt16 => 2,
            Self::Int32 | Self::UInt32 | Self::Float => 4,
            Self::Int64 | Self::UInt64 | Self::Double => 8,
        }
    }

    /// The value of `bytes` (little-endian) as `f64`: integers exactly up to 2^53, `bool` as
    /// 0 or 1 (any non-zero byte is 1), `char` as its byte. `None` for a slice of the wrong
    /// length.
    pub fn decode(self, bytes: &[u8]) -> Option<f64> {
        fn arr<const N: usize>(b: &[u8]) -> Option<[u8; N]> {
            b.try_into().ok()
        }
        Some(match self {
            Self::Int8 => f64::from(i8::from_le_bytes(arr(bytes)?)),
            Self::UInt8 | Self::Char => f64::from(u8::from_le_bytes(arr(bytes)?)),
            Self::Bool => f64::from(u8::from(arr::<1>(bytes)?[0] != 0)),
            Self::Int16 => f64::from(i16::from_le_bytes(arr(bytes)?)),
            Self::UInt16 => f64::from(u16::from_le_bytes(arr(bytes)?)),
            Self::Int32 => f64::from(i32::from_le_bytes(arr(bytes)?)),
            Self::UInt32 => f64::from(u32::from_le_bytes(arr(bytes)?)),
            Self::Int64 => i64::from_le_bytes(arr(bytes)?) as f64,
            Self::UInt64 => u64::from_le_bytes(arr(bytes)?) as f64,
            Self::Float => f64::from(f32::from_le_bytes(arr(bytes)?)),
            Self::Double => f64::from_le_bytes(arr(bytes)?),
        })
    }
}

/// One field as a format (or an information key) declares it: `type[n] name`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FieldDecl {
    /// Type name without the array suffix: a basic type or a nested format's name.
    pub type_name: String,
    /// `n` of `type[n]` (0 allowed); `None` for a single value.
    pub array_len: Option<usize>,
    pub name: String,
}

impl FieldDecl {
    /// Parses `type name` or `type[n] name`.
    fn parse(text: &str) -> Result<Self, String> {
        let (ty, name) = text
            .split_once(' ')
            .ok_or_else(|| format!("field `{text}` is not `type name`"))?;
        if ty.is_empty() || name.is_empty() || name.contains(' ') {
            return Err(format!("field `{text}` is not `type name`"));
        }
        let (type_name, array_len) = match ty.strip_suffix(']') {
            None => (ty, None),
            Some(head) => {
                let (base, n) = head
                    .split_once('[')
                    .ok_or_else(|| format!("field `{text}`: `{ty}` is not `type[n]`"))?;
                // `char[0]` occurs: an empty continued multi information value.
                let n: usize = n
                    .parse()
                    .map_err(|_| format!("field `{text}`: `{ty}` has no array length"))?;
                (base, Some(n))
            }
        };
        Ok(FieldDecl {
            type_name: type_name.to_string(),
            array_len,
            name: name.to_string(),
        })
    }

    /// True for the padding fields a format inserts for alignment (`_padding0`, ...).
    pub fn is_padding(&self) -> bool {
        self.name.starts_with("_padding")
    }
}

/// A format as an `F` message defines it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MessageFormat {
    pub name: String,
    pub fields: Vec<FieldDecl>,
    /// Byte offset of the `F` message that defined it.
    pub offset: u64,
}

/// Parses the text of an `F` message, `name:type field;type field;...`.
fn parse_format(text: &str, offset: u64) -> Result<MessageFormat, String> {
    let (name, body) = text
        .split_once(':')
        .ok_or_else(|| format!("format `{text}` has no `name:`"))?;
    if name.is_empty() || name.contains([' ', ';', '[']) {
        return Err(format!("format name `{name}` is empty or not a name"));
    }
    let pieces: Vec<&str> = body.split(';').collect();
    let mut fields: Vec<FieldDecl> = Vec::with_capacity(pieces.len());
    for (i, piece) in pieces.iter().enumerate() {
        if piece.is_empty() {
            if i + 1 == pieces.len() {
                continue;
            }
            return Err(format!("format `{name}`: empty field {i}"));
        }
        let field = FieldDecl::parse(piece).map_err(|e| format!("format `{name}`: {e}"))?;
        if fields.iter().any(|f| f.name == field.name) {
            return Err(format!("format `{name}`: field `{}` twice", field.name));
        }
        fields.push(field);
    }
    if fields.is_empty() {
        return Err(format!("format `{name}` has no fields"));
    }
    Ok(MessageFormat {
        name: name.to_string(),
        fields,
        offset,
    })
}

/// One basic value of a flattened format.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FlatField {
    /// Flattened name: `x`, `gyro_rad[0]`, `current.lat`, `heartbeats[1].type`.
    pub name: String,
    /// Byte offset in the topic's payload.
    pub offset: usize,
    pub kind: BasicType,
}

/// A format with its nested formats resolved: every basic value's name, offset and type.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Layout {
    /// Size of the whole format, bytes, its padding included.
    pub size: usize,
    /// Size of a trailing `_padding*` field, which data messages leave out, bytes.
    pub trailing_padding: usize,
    /// Every basic value in byte order (padding fields left out).
    pub fields: Vec<FlatField>,
    index: BTreeMap<String, usize>,
}

impl Layout {
    /// The flattened field `name`.
    pub fn field(&self, name: &str) -> Option<&FlatField> {
        self.index.get(name).map(|&i| &self.fields[i])
    }

    fn push(&mut self, name: String, offset: usize, kind: BasicType) {
        self.index.insert(name.clone(), self.fields.len());
        self.fields.push(FlatField { name, offset, kind });
    }
}

/// The layout of format `name` (defined in `formats`), nested formats flattened; `stack`
/// holds the formats being resolved around it. The error is the offset of the `F` message at
/// fault and what is wrong.
fn flatten(
    formats: &BTreeMap<String, MessageFormat>,
    name: &str,
    stack: &mut Vec<String>,
) -> Result<Layout, (u64, String)> {
    let Some(format) = formats.get(name) else {
        let offset = stack
            .last()
            .and_then(|outer| formats.get(outer))
            .map_or(0, |f| f.offset);
        return Err((offset, format!("no format `{name}` is defined")));
    };
    if stack.iter().any(|s| s == name) {
        return Err((
            format.offset,
            format!(
                "format `{name}` contains itself ({} -> {name})",
                stack.join(" -> ")
            ),
        ));
    }
    stack.push(name.to_string());
    let mut layout = Layout::default();
    for decl in &format.fields {
        let count = decl.array_len.unwrap_or(1);
        let item = |i: usize| match decl.array_len {
            Some(_) => format!("{}[{i}]", decl.name),
            None => decl.name.clone(),
        };
        let start = layout.size;
        let (kind, inner) = if let Some(kind) = BasicType::from_name(&decl.type_name) {
            (Some(kind), None)
        } else if formats.contains_key(&decl.type_name) {
            (None, Some(flatten(formats, &decl.type_name, stack)?))
        } else {
            return Err((
                format.offset,
                format!(
                    "format `{name}`: field `{}` has the unknown type `{}`",
                    decl.name, decl.type_name
                ),
            ));
        };
        let item_size = match (&kind, &inner) {
            (Some(kind), _) => kind.size(),
            (_, Some(inner)) => inner.size,
            _ => 0,
        };
        // Checked before the fields are listed: a message holds at most MAX_FORMAT_BYTES, and
        // a damaged array length (`float[2147483648]`) otherwise listed a field per element
        // until memory ran out, or overflowed the size.
        let Some(end) = count
            .checked_mul(item_size)
            .and_then(|n| n.checked_add(start))
            .filter(|&end| end <= MAX_FORMAT_BYTES)
        else {
            return Err((
                format.offset,
                format!(
                    "format `{name}`: field `{}` ({count} x {item_size} bytes from byte {start}) \
                     makes it longer than a message can hold ({MAX_FORMAT_BYTES} bytes)",
                    decl.name
                ),
            ));
        };
        for i in 0..count {
            match (&kind, &inner) {
                (Some(kind), _) if !decl.is_padding() => {
                    layout.push(item(i), start + i * kind.size(), *kind)
                }
                (_, Some(inner)) => {
                    for f in &inner.fields {
                        let at = start + i * inner.size + f.offset;
                        layout.push(format!("{}.{}", item(i), f.name), at, f.kind);
                    }
                }
                _ => {}
            }
        }
        layout.size = end;
    }
    if let Some(last) = format.fields.last().filter(|f| f.is_padding()) {
        if let Some(kind) = BasicType::from_name(&last.type_name) {
            layout.trailing_padding = kind.size() * last.array_len.unwrap_or(1);
        }
    }
    stack.pop();
    Ok(layout)
}

/// One instance of a logged topic (`sensor_gyro` multi_id 1): its layout, and its samples
/// where the log holds them (every topic's when read whole; a walk holds those it keeps).
#[derive(Debug, Clone, PartialEq)]
pub struct Topic {
    /// The format's name, e.g. `sensor_gyro`.
    pub name: String,
    /// The instance (0 for a single-instance topic).
    pub multi_id: u8,
    /// Its place in [`ULog::topics`].
    position: usize,
    layout: Layout,
    /// Number of samples logged, held or not.
    count: usize,
    /// The held samples' payloads, each [`Layout::size`] bytes (a trailing padding left out by
    /// the log is zero here).
    data: Vec<u8>,
    /// Byte offset of each held sample's `D` message in the file.
    offsets: Vec<u64>,
}

impl Topic {
    /// Number of samples logged.
    pub fn len(&self) -> usize {
        self.count
    }
    /// True when the topic was subscribed but never logged.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }
    /// True when the log holds the samples (every topic's when read whole).
    pub fn is_held(&self) -> bool {
        self.offsets.len() == self.count
    }
    /// The flattened layout of its format.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }
    /// Its place in [`ULog::topics`].
    pub fn position(&self) -> usize {
        self.position
    }
    /// Byte offset of held sample `i`'s `D` message in the file.
    pub fn offset(&self, i: usize) -> u64 {
        self.offsets[i]
    }
    /// True when the format has the flattened field `field`.
    pub fn has(&self, field: &str) -> bool {
        self.layout.field(field).is_some()
    }
    /// Field `field` of held sample `i` as `f64` ([`BasicType::decode`]); `None` if the format
    /// has no such field or the log holds no sample `i`.
    pub fn value(&self, i: usize, field: &str) -> Option<f64> {
        field_value(&self.layout, self.payload(i)?, field)
    }
    /// Field `field` of every held sample.
    pub fn column(&self, field: &str) -> Option<Vec<f64>> {
        self.layout.field(field)?;
        (0..self.offsets.len())
            .map(|i| self.value(i, field))
            .collect()
    }
    /// The `timestamp` field of every held sample, µs on the boot clock (exact: read as `u64`).
    pub fn timestamps_us(&self) -> Option<Vec<u64>> {
        let f = self.layout.field("timestamp")?;
        if f.kind != BasicType::UInt64 {
            return None;
        }
        (0..self.offsets.len())
            .map(|i| {
                let bytes: [u8; 8] = self
                    .payload(i)?
                    .get(f.offset..f.offset + 8)?
                    .try_into()
                    .ok()?;
                Some(u64::from_le_bytes(bytes))
            })
            .collect()
    }
    /// The payload of held sample `i`.
    fn payload(&self, i: usize) -> Option<&[u8]> {
        let start = i.checked_mul(self.layout.size)?;
        self.data.get(start..start + self.layout.size)
    }
}

/// Field `field` of a payload laid out as `layout`, as `f64`.
fn field_value(layout: &Layout, payload: &[u8], field: &str) -> Option<f64> {
    let f = layout.field(field)?;
    f.kind
        .decode(payload.get(f.offset..f.offset + f.kind.size())?)
}

/// One sample of a topic instance, as a walk meets it or the log holds it: its fields, where
/// it is.
#[derive(Clone, Copy)]
pub struct Sample<'a> {
    path: &'a Path,
    pub topic: &'a Topic,
    /// Its position among the instance's samples.
    pub index: usize,
    /// Byte offset of its `D` message in the file.
    pub offset: u64,
    /// [`Layout::size`] bytes (a trailing padding left out by the log is zero here).
    payload: &'a [u8],
}

impl Sample<'_> {
    /// Field `field` as `f64` ([`BasicType::decode`]); `None` if the format has no such field.
    pub fn value(&self, field: &str) -> Option<f64> {
        field_value(&self.topic.layout, self.payload, field)
    }

    /// An error about this sample, naming its message's byte offset.
    pub fn error(&self, message: impl std::fmt::Display) -> ImportError {
        corrupt(
            self.path,
            self.offset,
            format!(
                "{} instance {} sample {}: {message}",
                self.topic.name, self.topic.multi_id, self.index
            ),
        )
    }

    /// Field `field`, which must be present and finite.
    pub fn required(&self, field: &str) -> Result<f64, ImportError> {
        match self.value(field) {
            Some(v) if v.is_finite() => Ok(v),
            Some(v) => Err(self.error(format!("`{field}` is {v}, not a finite number"))),
            None => Err(self.error(format!("has no field `{field}`"))),
        }
    }

    /// Field `time_field` (µs) in seconds, checked to follow `previous` (the last time of the
    /// same series).
    pub fn time_s(&self, time_field: &str, previous: Option<f64>) -> Result<f64, ImportError> {
        let t = self.required(time_field)? / 1e6;
        match previous {
            Some(p) if !(t > p) => Err(self.error(format!(
                "`{time_field}` {t} s is {} the previous sample's {p} s",
                if t == p { "a duplicate of" } else { "before" }
            ))),
            _ => Ok(t),
        }
    }
}

/// The value of an information message (`I`, `M`) or a parameter (`P`, `Q`).
#[derive(Debug, Clone, PartialEq)]
pub enum InfoValue {
    /// A `char[n]` value (invalid UTF-8 replaced).
    Text(String),
    /// A numeric value or array.
    Numbers(Vec<f64>),
}

/// A log string (`L`, or `C` with its tag).
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedString {
    /// Byte offset of its message.
    pub offset: u64,
    /// Syslog level, `b'0'` (emergency) to `b'7'` (debug).
    pub level: u8,
    /// The tag of a tagged string (`C`).
    pub tag: Option<u16>,
    /// Boot clock, µs.
    pub timestamp_us: u64,
    pub text: String,
}

/// A dropout (`O`): the logger lost data for a while.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dropout {
    /// Byte offset of its message.
    pub offset: u64,
    pub duration_ms: u16,
}

/// A default parameter value (`Q`).
#[derive(Debug, Clone, PartialEq)]
pub struct DefaultParameter {
    /// Bit 0: the system-wide default, bit 1: the default of the current configuration.
    pub default_types: u8,
    pub name: String,
    pub value: f64,
}

/// A parsed ULog file: header, definitions, every topic instance with its samples.
#[derive(Debug, Clone, PartialEq)]
pub struct ULog {
    path: PathBuf,
    /// The header's version byte.
    pub version: u8,
    /// The header's start time, µs on the boot clock.
    pub start_time_us: u64,
    /// The flag bits (`B`): compatible and incompatible flag bytes (zero without a `B`).
    pub compat_flags: [u8; 8],
    pub incompat_flags: [u8; 8],
    formats: BTreeMap<String, MessageFormat>,
    topics: Vec<Topic>,
    info: BTreeMap<String, InfoValue>,
    multi_info: BTreeMap<String, Vec<InfoValue>>,
    parameters: BTreeMap<String, Vec<f64>>,
    /// Byte offset of each `P` message, by parameter name, in step with `parameters`.
    parameter_offsets: BTreeMap<String, Vec<u64>>,
    default_parameters: Vec<DefaultParameter>,
    logged: Vec<LoggedString>,
    dropouts: Vec<Dropout>,
    sync_count: usize,
    message_count: usize,
}

/// An error at a byte offset of `path`.
fn corrupt(path: &Path, offset: u64, message: impl Into<String>) -> ImportError {
    ImportError::Corrupt {
        path: path.to_path_buf(),
        offset,
        message: message.into(),
    }
}

/// Bytes as upper-case hex pairs separated by spaces.
fn hex(bytes: &[u8]) -> String {
    let pairs: Vec<String> = bytes.iter().map(|b| format!("{b:02X}")).collect();
    pairs.join(" ")
}

/// True when `head` (a file's first bytes) starts a ULog file.
pub fn is_ulog(head: &[u8]) -> bool {
    head.starts_with(&MAGIC)
}

mod parse;

impl ULog {
    /// Reads and parses a log file (gzip-compressed or not), every topic's samples held.
    pub fn read(path: &Path) -> Result<Self, ImportError> {
        Self::walk(path, &|_| true, &mut |_| Ok(()))
    }

    /// Parses a whole log held in memory; `path` is only for messages. Every byte must belong
    /// to the header or to a complete, well-formed message.
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<Self, ImportError> {
        parse::Parser::new(path, bytes, &|_| true, &mut |_| Ok(()))?.run()
    }

    /// Walks the file `path` (gzip-compressed or not) message by message, each checked as
    /// [`ULog::parse`] checks it, in memory that grows only with what is kept: every sample is
    /// handed to `visit`, and only the topics whose name `keep` accepts hold their samples in
    /// the log returned (every other topic's samples are counted). Definitions, information,
    /// parameters and log strings are always held.
    pub fn walk(
        path: &Path,
        keep: &dyn Fn(&str) -> bool,
        visit: &mut dyn FnMut(Sample) -> Result<(), ImportError>,
    ) -> Result<Self, ImportError> {
        let reader = std::io::BufReader::with_capacity(1 << 16, open_maybe_gz(path)?);
        parse::Parser::new(path, reader, keep, visit)?.run()
    }

    /// The held samples of `topic`, in order (every sample of a log read whole; none of a
    /// topic a walk did not keep).
    pub fn held_samples<'a>(&'a self, topic: &'a Topic) -> impl Iterator<Item = Sample<'a>> + 'a {
        (0..topic.offsets.len()).map(move |i| self.sample(topic, i))
    }

    /// Held sample `i` of `topic` (which must be held, as every topic of a log read whole;
    /// panics if `i` is not a held sample).
    pub fn sample<'a>(&'a self, topic: &'a Topic, i: usize) -> Sample<'a> {
        Sample {
            path: &self.path,
            topic,
            index: i,
            offset: topic.offsets[i],
            payload: topic.payload(i).unwrap_or_default(),
        }
    }

    /// The file the log was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }
    /// Every format defined, by name.
    pub fn formats(&self) -> &BTreeMap<String, MessageFormat> {
        &self.formats
    }
    /// Every topic instance subscribed, in the order of their first subscription.
    pub fn topics(&self) -> &[Topic] {
        &self.topics
    }
    /// The instances of topic `name`, by multi_id.
    pub fn instances<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Topic> + 'a {
        let mut found: Vec<&Topic> = self.topics.iter().filter(|t| t.name == name).collect();
        found.sort_by_key(|t| t.multi_id);
        found.into_iter()
    }
    /// Instance `multi_id` of topic `name`.
    pub fn topic(&self, name: &str, multi_id: u8) -> Option<&Topic> {
        self.topics
            .iter()
            .find(|t| t.name == name && t.multi_id == multi_id)
    }
    /// The information messages (`I`), by key name (a repeated key keeps its last value).
    pub fn info(&self) -> &BTreeMap<String, InfoValue> {
        &self.info
    }
    /// The multi information messages (`M`), by key name, continued values joined.
    pub fn multi_info(&self) -> &BTreeMap<String, Vec<InfoValue>> {
        &self.multi_info
    }
    /// Parameter `name`'s first value (the one at the start of the log).
    pub fn parameter(&self, name: &str) -> Option<f64> {
        self.parameters.get(name).and_then(|v| v.first().copied())
    }
    /// Every value parameter `name` took, in log order (the first at start, then changes).
    pub fn parameter_values(&self, name: &str) -> Option<&[f64]> {
        self.parameters.get(name).map(Vec::as_slice)
    }
    /// Byte offsets of the `P` messages that set parameter `name`, in log order (one per
    /// value of [`ULog::parameter_values`]).
    pub fn parameter_offsets(&self, name: &str) -> Option<&[u64]> {
        self.parameter_offsets.get(name).map(Vec::as_slice)
    }
    /// Number of parameters logged.
    pub fn parameter_count(&self) -> usize {
        self.parameters.len()
    }
    /// The default parameter values (`Q`).
    pub fn default_parameters(&self) -> &[DefaultParameter] {
        &self.default_parameters
    }
    /// The log strings (`L`, `C`).
    pub fn logged_strings(&self) -> &[LoggedString] {
        &self.logged
    }
    /// The dropouts (`O`).
    pub fn dropouts(&self) -> &[Dropout] {
        &self.dropouts
    }
    /// Number of sync markers (`S`).
    pub fn sync_count(&self) -> usize {
        self.sync_count
    }
    /// Number of messages after the header.
    pub fn message_count(&self) -> usize {
        self.message_count
    }

    /// An error about held sample `i` of `topic`, naming its message's byte offset.
    pub fn error_at(
        &self,
        topic: &Topic,
        i: usize,
        message: impl std::fmt::Display,
    ) -> ImportError {
        self.sample(topic, i).error(message)
    }

    /// Field `field` of held sample `i`, which must be present and finite.
    pub fn required(&self, topic: &Topic, i: usize, field: &str) -> Result<f64, ImportError> {
        self.sample(topic, i).required(field)
    }
}

pub mod board;
mod convert;

pub use board::{sensor_to_body, SensorKind, SensorToBody};
pub use convert::{
    gps_topic, read, read_reference, read_sensor_combined, read_sensor_imus, read_vehicle_imus,
    reference_topic, stream, NamedRecording, BOARD_FRAME_SUFFIX,
};

#[cfg(test)]
mod tests;
