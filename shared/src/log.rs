//! The board's log protocol: what the firmware writes and the host decodes.
//!
//! Each [`Frame`] is serialised with postcard, followed by a CRC-32 (IEEE 802.3, the `crc`
//! crate's `CRC_32_ISO_HDLC`, little-endian) over those postcard bytes, and the whole is
//! COBS-encoded and terminated by one 0x00 delimiter. Encoding streams through postcard's
//! `use-crc` and COBS flavors, so no second buffer is needed; decoding COBS-decodes in place
//! (`cobs` crate), checks the CRC, then postcard-decodes. `docs/log-format.md` is the wire
//! specification; the byte-exact tests below pin it.
//!
//! [`FrameAccumulator`] turns an arbitrary byte stream back into frames on the board or the
//! host, resynchronising on the next delimiter after corruption and recovering a frame that
//! follows garbage within the same delimited run.

use core::fmt;

use serde::{Deserialize, Serialize};

use crate::channel::Channel;
use crate::wavelet::{WvSnapshot, SNAPSHOT_MAX_ENCODED_LEN};

/// Version of this wire format, written in [`Header::protocol_version`]. Bump it when a
/// frame's field layout changes; appending a new [`Frame`] variant or a new health flag does
/// not change existing frames and needs no bump (readers count unknown kinds as dropped).
pub const PROTOCOL_VERSION: u16 = 1;

/// Capacity (bytes, UTF-8) of [`Header::board`].
pub const BOARD_NAME_LEN: usize = 32;
/// Capacity (bytes, UTF-8) of [`ImuConfig::model`].
pub const IMU_MODEL_LEN: usize = 16;
/// Most IMUs one board logs.
pub const MAX_IMUS: usize = 3;
/// Bytes of CRC-32 after the postcard payload.
pub const CRC_LEN: usize = 4;

/// CRC-32 used by the log: IEEE 802.3 (poly 0x04C11DB7 reflected, init 0xFFFFFFFF,
/// xorout 0xFFFFFFFF, check value of "123456789" = 0xCBF43926).
pub static LOG_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Largest postcard encoding of any [`Frame`], bytes (variant tag included, CRC excluded).
pub const MAX_POSTCARD_LEN: usize = 1 + max_of(&[
    Header::MAX_POSTCARD_LEN,
    ImuSampleSet::MAX_POSTCARD_LEN,
    PpsEvent::MAX_POSTCARD_LEN,
    GnssFix::MAX_POSTCARD_LEN,
    FilterState::MAX_POSTCARD_LEN,
    Health::MAX_POSTCARD_LEN,
    WvFrame::MAX_POSTCARD_LEN,
    NoiseFrame::MAX_POSTCARD_LEN,
    FaultFrame::MAX_POSTCARD_LEN,
]);

/// Largest COBS-decoded frame (postcard bytes + CRC), bytes.
pub const MAX_DECODED_LEN: usize = MAX_POSTCARD_LEN + CRC_LEN;

/// Largest complete frame on the wire: COBS overhead and the 0x00 delimiter included.
/// Size transmit buffers with this; a [`FrameAccumulator`] needs `MAX_FRAME_LEN - 1`.
///
/// Since tag 6 this is the worst-case [`WvFrame`] (32 levels of maximal varints, 1059 bytes);
/// every other kind fits in [`MAX_REGULAR_FRAME_LEN`]. One bound for all kinds on purpose: a
/// reader sized for regular frames only would drop every snapshot as `FrameTooLong`, and the
/// board holds a single frame buffer, so the extra 0.9 KiB is a small share of the
/// STM32F405's 128 KiB (see `docs/log-format.md`).
pub const MAX_FRAME_LEN: usize = cobs::max_encoding_length(MAX_DECODED_LEN) + 1;

/// Largest wire frame of the kinds other than [`Frame::WaveletVariance`] (a header with three
/// IMUs and full-length strings), delimiter included.
pub const MAX_REGULAR_FRAME_LEN: usize = cobs::max_encoding_length(
    1 + max_of(&[
        Header::MAX_POSTCARD_LEN,
        ImuSampleSet::MAX_POSTCARD_LEN,
        PpsEvent::MAX_POSTCARD_LEN,
        GnssFix::MAX_POSTCARD_LEN,
        FilterState::MAX_POSTCARD_LEN,
        Health::MAX_POSTCARD_LEN,
        NoiseFrame::MAX_POSTCARD_LEN,
        FaultFrame::MAX_POSTCARD_LEN,
    ]) + CRC_LEN,
) + 1;

/// An accumulator large enough for every frame of this protocol.
pub type LogAccumulator = FrameAccumulator<MAX_FRAME_LEN>;

/// One log record.
///
/// Append-only: postcard writes the variant index (0 for `Header`, 1 for `Imu`, ...) as the
/// frame's leading tag, so existing variants must never be reordered, removed or changed.
/// New kinds are appended at the end, their size added to [`MAX_POSTCARD_LEN`], and their
/// kind named in [`Frame::kind_name`].
///
/// A `Frame` is as large as its largest variant (a 32-level [`WvFrame`], about 1.5 KiB): the
/// no-alloc core cannot box it, and frames are built one at a time and passed by reference,
/// so the size costs stack once, not per frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
#[allow(clippy::large_enum_variant)]
pub enum Frame {
    /// Tag 0: what the log holds; written first and may be repeated.
    Header(Header),
    /// Tag 1: one raw sample of one IMU.
    Imu(ImuSampleSet),
    /// Tag 2: a GNSS pulse-per-second edge.
    Pps(PpsEvent),
    /// Tag 3: a GNSS position/velocity solution.
    Gnss(GnssFix),
    /// Tag 4: the on-board navigation filter's state.
    Filter(FilterState),
    /// Tag 5: board health counters.
    Health(Health),
    /// Tag 6: the streaming Haar wavelet-variance sums of one IMU channel.
    WaveletVariance(WvFrame),
    /// Tag 7: each unit's own noise level, as the on-board fusion measures it.
    Noise(NoiseFrame),
    /// Tag 8: a unit's fault confirmed, or a unit readmitted, by the on-board fusion.
    Fault(FaultFrame),
}

/// Number of [`Frame`] variants this build knows; tags at or above it are reported as
/// [`LogError::UnknownKind`].
pub const FRAME_KINDS: u32 = 9;

impl Frame {
    /// The postcard tag (variant index) of this frame.
    pub fn tag(&self) -> u32 {
        match self {
            Frame::Header(_) => 0,
            Frame::Imu(_) => 1,
            Frame::Pps(_) => 2,
            Frame::Gnss(_) => 3,
            Frame::Filter(_) => 4,
            Frame::Health(_) => 5,
            Frame::WaveletVariance(_) => 6,
            Frame::Noise(_) => 7,
            Frame::Fault(_) => 8,
        }
    }

    /// A short lowercase name of this frame's kind, as used in decoder summaries.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Frame::Header(_) => "header",
            Frame::Imu(_) => "imu",
            Frame::Pps(_) => "pps",
            Frame::Gnss(_) => "gnss",
            Frame::Filter(_) => "filter",
            Frame::Health(_) => "health",
            Frame::WaveletVariance(_) => "wavelet_variance",
            Frame::Noise(_) => "noise",
            Frame::Fault(_) => "fault",
        }
    }

    /// The frame's timestamp on the log timescale, microseconds (the header has none).
    pub fn t_us(&self) -> Option<u64> {
        match self {
            Frame::Header(_) => None,
            Frame::Imu(f) => Some(f.t_us),
            Frame::Pps(f) => Some(f.t_us),
            Frame::Gnss(f) => Some(f.t_us),
            Frame::Filter(f) => Some(f.t_us),
            Frame::Health(f) => Some(f.t_us),
            Frame::WaveletVariance(f) => Some(f.t_us),
            Frame::Noise(f) => Some(f.t_us),
            Frame::Fault(f) => Some(f.t_us),
        }
    }
}

/// What the log holds: the protocol version and each IMU's identity and scale factors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// [`PROTOCOL_VERSION`] of the writer.
    pub protocol_version: u16,
    /// Board name and revision, free text.
    pub board: heapless::String<BOARD_NAME_LEN>,
    /// The IMUs whose samples follow; `imu_id`s are unique.
    pub imus: heapless::Vec<ImuConfig, MAX_IMUS>,
}

/// How to turn one IMU's raw counts into SI units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImuConfig {
    /// The id used by this IMU's [`ImuSampleSet`]s.
    pub imu_id: u8,
    /// Part number, e.g. "ICM-42688-P".
    pub model: heapless::String<IMU_MODEL_LEN>,
    /// Configured output data rate, Hz.
    pub sample_rate_hz: f32,
    /// Angular rate per count, rad/s (f64 so counts x scale is bit-exact on the host).
    pub gyro_scale_rad_s_per_count: f64,
    /// Specific force per count, m/s^2 (f64 for the same reason).
    pub accel_scale_m_s2_per_count: f64,
}

/// One sample of one IMU as raw sensor counts in the sensor's body axes (FRD).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ImuSampleSet {
    /// Sample time: GPS time (log timescale, see [`Health::FLAG_TIME_GPS`]), microseconds.
    pub t_us: u64,
    /// Which [`ImuConfig`] this sample belongs to.
    pub imu_id: u8,
    /// Angular rate x, y, z, counts (multiply by `gyro_scale_rad_s_per_count`).
    pub gyro_counts: [i32; 3],
    /// Specific force x, y, z, counts (multiply by `accel_scale_m_s2_per_count`).
    pub accel_counts: [i32; 3],
}

/// A GNSS pulse-per-second edge as captured by the board's timer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PpsEvent {
    /// Capture time of the edge on the log timescale, microseconds. With the clock locked to
    /// GPS this is a whole second; the remainder is the board's synchronisation error.
    pub t_us: u64,
    /// Pulse counter since boot; a jump reveals missed pulses.
    pub sequence: u32,
}

/// A GNSS receiver solution.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GnssFix {
    /// Time of validity, GPS time, microseconds.
    pub t_us: u64,
    /// Geodetic latitude (WGS84), rad.
    pub lat_rad: f64,
    /// Geodetic longitude (WGS84), rad.
    pub lon_rad: f64,
    /// Ellipsoidal height, m.
    pub h_m: f32,
    /// Velocity w.r.t. Earth, north-east-down, m/s.
    pub vel_ned_m_s: [f32; 3],
    /// Horizontal position accuracy (1 sigma), m.
    pub pos_sigma_m: f32,
    /// Speed accuracy (1 sigma), m/s.
    pub vel_sigma_m_s: f32,
    /// Satellites used in the solution.
    pub num_sats: u8,
    /// Fix type: 0 none, 1 dead reckoning, 2 2-D, 3 3-D, 4 GNSS + dead reckoning, 5 time only.
    pub fix_type: u8,
}

/// The navigation filter's state for one IMU lane, SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FilterState {
    /// Time of validity, GPS time, microseconds.
    pub t_us: u64,
    /// The IMU this filter lane runs on.
    pub imu_id: u8,
    /// Attitude: unit quaternion rotating body (FRD) vectors into NED, scalar first (w, x, y, z).
    pub q_nb: [f32; 4],
    /// Velocity w.r.t. Earth, NED, m/s.
    pub vel_ned_m_s: [f32; 3],
    /// Geodetic latitude (WGS84), rad.
    pub lat_rad: f64,
    /// Geodetic longitude (WGS84), rad.
    pub lon_rad: f64,
    /// Ellipsoidal height, m.
    pub h_m: f32,
    /// Estimated gyro bias, body frame, rad/s.
    pub gyro_bias_rad_s: [f32; 3],
    /// Estimated accelerometer bias, body frame, m/s^2.
    pub accel_bias_m_s2: [f32; 3],
    /// Attitude error 1-sigma about north, east, down, rad.
    pub attitude_sigma_rad: [f32; 3],
    /// Velocity 1-sigma, NED, m/s.
    pub vel_sigma_m_s: [f32; 3],
    /// Position 1-sigma, NED, m.
    pub pos_sigma_m: [f32; 3],
    /// Gyro bias 1-sigma, body frame, rad/s.
    pub gyro_bias_sigma_rad_s: [f32; 3],
    /// Accelerometer bias 1-sigma, body frame, m/s^2.
    pub accel_bias_sigma_m_s2: [f32; 3],
}

/// Board health, logged periodically (e.g. at 1 Hz).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Health {
    /// Time of the report, log timescale, microseconds.
    pub t_us: u64,
    /// Frames the board could not write (log buffer full) since boot.
    pub frames_dropped: u32,
    /// IMU samples lost to FIFO or driver overrun since boot.
    pub samples_overrun: u32,
    /// Status bits, see the `FLAG_*` constants; unassigned bits are zero.
    pub flags: u32,
    /// Processor load over the last report interval, per mille.
    pub cpu_load_permille: u16,
    /// Die temperature of each IMU in header order, degrees Celsius; NaN when not measured.
    pub imu_temperature_deg_c: [f32; MAX_IMUS],
}

impl Health {
    /// The log timescale is GPS time (microseconds since 1980-01-06 00:00:00 GPS). When clear,
    /// `t_us` fields count from boot and are not yet aligned to GPS.
    pub const FLAG_TIME_GPS: u32 = 1 << 0;
    /// The board clock is disciplined by PPS (the last pulse was seen within 2 s).
    pub const FLAG_PPS_LOCKED: u32 = 1 << 1;
    /// The GNSS receiver reports a 3-D fix.
    pub const FLAG_GNSS_FIX: u32 = 1 << 2;
    /// At least one IMU failed its last read or self-test.
    pub const FLAG_IMU_FAULT: u32 = 1 << 3;
    /// The log sink could not keep up during the last interval.
    pub const FLAG_LOG_BACKPRESSURE: u32 = 1 << 4;
}

/// A snapshot of the board's streaming Haar wavelet variance of one IMU channel
/// ([`crate::wavelet::HaarStream`] over the raw counts since the start of the run).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct WvFrame {
    /// Time of the last sample included, log timescale, microseconds.
    pub t_us: u64,
    /// The IMU whose counts were accumulated.
    pub imu_id: u8,
    /// The channel: 0..=5 = gyro x, y, z, accelerometer x, y, z ([`Channel::index`]; a
    /// number on the wire, so the frame's encoding is independent of the enum).
    pub channel: u8,
    /// The accumulated sums, in counts^2 (scale with the header's scale factor squared).
    pub snapshot: WvSnapshot,
}

/// Each unit's own white-noise level of one moment, from the units' differences (the
/// fusion's `LiveNoise`), and which units the fused output uses.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoiseFrame {
    /// Time of the last sample set included, log timescale, microseconds.
    pub t_us: u64,
    /// Each unit's own gyro white noise, standard deviation per sample, rad/s, header order
    /// (NaN for a unit the header does not declare).
    pub gyro_sigma_rad_s: [f32; MAX_IMUS],
    /// Each unit's own accelerometer white noise, standard deviation per sample, m/s^2.
    pub accel_sigma_m_s2: [f32; MAX_IMUS],
    /// Bit k: unit k's gyros are in the fused output; bit 3 + k: its accelerometers.
    pub in_use: u8,
    /// The platform was still (zero-velocity updates were running).
    pub still: bool,
}

/// A fault of one unit the fusion confirmed, or a unit it took back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FaultFrame {
    /// When the kind was decided (or the unit readmitted), log timescale, microseconds.
    pub t_us: u64,
    /// When the unit was first suspected and left the fused output, microseconds.
    pub detected_t_us: u64,
    /// [`FaultFrame::SENSOR_GYRO`] or [`FaultFrame::SENSOR_ACCEL`].
    pub sensor: u8,
    /// The unit, by header index; None when only two units were left and which of them is
    /// wrong cannot be told.
    pub unit: Option<u8>,
    /// The axis (0, 1, 2) that showed it most, where the kind has one.
    pub axis: Option<u8>,
    /// One of the `KIND_*` codes.
    pub kind: u8,
}

impl FaultFrame {
    pub const SENSOR_GYRO: u8 = 0;
    pub const SENSOR_ACCEL: u8 = 1;
    /// Kind codes, in the order of the fault monitor's kinds; then readmission.
    pub const KIND_NAMES: [&'static str; 9] = [
        "dropout",
        "saturation",
        "stuck",
        "spike",
        "bias_step",
        "scale_factor",
        "noise_burst",
        "time_slip",
        "readmitted",
    ];
    /// The code of a readmission.
    pub const KIND_READMITTED: u8 = 8;

    /// The kind's name ("unknown" for a code this build does not know).
    pub fn kind_name(&self) -> &'static str {
        Self::KIND_NAMES
            .get(usize::from(self.kind))
            .copied()
            .unwrap_or("unknown")
    }

    /// The sensor's name.
    pub fn sensor_name(&self) -> &'static str {
        match self.sensor {
            Self::SENSOR_GYRO => "gyro",
            Self::SENSOR_ACCEL => "accel",
            _ => "unknown",
        }
    }
}

impl WvFrame {
    /// The channel, if `channel` names one.
    pub fn channel(&self) -> Option<Channel> {
        Channel::from_index(usize::from(self.channel))
    }
}

// Postcard's `MaxSize` derive does not cover heapless 0.9 containers, so the largest
// encodings are written out here; `max_sizes_are_attained_exactly` checks each against the
// encoding of a worst-case value.
const VARINT_U16_MAX: usize = 3;
const VARINT_U32_MAX: usize = 5;
const VARINT_U64_MAX: usize = 10;
const ZIGZAG_I32_MAX: usize = 5;

const fn varint_len(mut value: usize) -> usize {
    let mut n = 1;
    while value >= 0x80 {
        value >>= 7;
        n += 1;
    }
    n
}

const fn max_of(values: &[usize]) -> usize {
    let mut max = 0;
    let mut i = 0;
    while i < values.len() {
        if values[i] > max {
            max = values[i];
        }
        i += 1;
    }
    max
}

impl ImuConfig {
    /// Largest postcard encoding, bytes.
    pub const MAX_POSTCARD_LEN: usize = 1 + varint_len(IMU_MODEL_LEN) + IMU_MODEL_LEN + 4 + 8 + 8;
}
impl Header {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = VARINT_U16_MAX
        + varint_len(BOARD_NAME_LEN)
        + BOARD_NAME_LEN
        + varint_len(MAX_IMUS)
        + MAX_IMUS * ImuConfig::MAX_POSTCARD_LEN;
}
impl ImuSampleSet {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = VARINT_U64_MAX + 1 + 6 * ZIGZAG_I32_MAX;
}
impl PpsEvent {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = VARINT_U64_MAX + VARINT_U32_MAX;
}
impl GnssFix {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = VARINT_U64_MAX + 8 + 8 + 4 + 3 * 4 + 4 + 4 + 1 + 1;
}
impl FilterState {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = VARINT_U64_MAX + 1 + 4 * 4 + 3 * 4 + 8 + 8 + 4 + 7 * 3 * 4;
}
impl Health {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize =
        VARINT_U64_MAX + 3 * VARINT_U32_MAX + VARINT_U16_MAX + MAX_IMUS * 4;
}

impl WvFrame {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = VARINT_U64_MAX + 1 + 1 + SNAPSHOT_MAX_ENCODED_LEN;
}
impl NoiseFrame {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = VARINT_U64_MAX + 2 * MAX_IMUS * 4 + 1 + 1;
}
impl FaultFrame {
    /// Largest postcard encoding (without the frame tag), bytes.
    pub const MAX_POSTCARD_LEN: usize = 2 * VARINT_U64_MAX + 1 + 2 * 2 + 1;
}

/// Why a frame could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum LogError {
    /// The output buffer is smaller than the encoded frame (use [`MAX_FRAME_LEN`]).
    BufferTooSmall,
    /// postcard refused to serialise the frame.
    Serialize,
    /// The run between two delimiters was empty.
    EmptyFrame,
    /// The bytes are not valid COBS (or contain a 0x00 inside the frame).
    Cobs,
    /// The decoded frame is shorter than a tag plus the CRC.
    TooShort {
        /// Decoded length, bytes.
        len: usize,
    },
    /// The CRC stored in the frame differs from the CRC of its payload.
    CrcMismatch {
        /// CRC carried by the frame.
        received: u32,
        /// CRC computed over the received payload.
        computed: u32,
    },
    /// The CRC is valid but the tag names a frame kind this build does not know (newer writer).
    UnknownKind {
        /// The postcard variant index read.
        tag: u32,
    },
    /// The CRC is valid but the payload does not decode as the tagged frame kind.
    Malformed,
    /// The CRC is valid and the frame decodes, but bytes remain after it.
    TrailingBytes {
        /// Bytes left over.
        extra: usize,
    },
    /// More bytes arrived without a delimiter than the accumulator holds.
    FrameTooLong,
    /// The stream ended in the middle of a frame (no closing delimiter).
    Truncated {
        /// Bytes of the unfinished frame.
        len: usize,
    },
}

impl fmt::Display for LogError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LogError::BufferTooSmall => write!(f, "output buffer too small for the frame"),
            LogError::Serialize => write!(f, "frame could not be serialised"),
            LogError::EmptyFrame => write!(f, "empty frame"),
            LogError::Cobs => write!(f, "invalid COBS encoding"),
            LogError::TooShort { len } => {
                write!(f, "frame of {len} bytes is shorter than a tag and a CRC")
            }
            LogError::CrcMismatch { received, computed } => write!(
                f,
                "CRC mismatch: frame carries {received:#010x}, payload gives {computed:#010x}"
            ),
            LogError::UnknownKind { tag } => write!(f, "unknown frame kind (tag {tag})"),
            LogError::Malformed => write!(f, "CRC valid but payload does not decode"),
            LogError::TrailingBytes { extra } => {
                write!(f, "{extra} unexpected bytes after the frame")
            }
            LogError::FrameTooLong => write!(f, "frame longer than the accumulator"),
            LogError::Truncated { len } => {
                write!(f, "stream ended inside a frame ({len} bytes)")
            }
        }
    }
}

impl core::error::Error for LogError {}

fn map_serialize_error(e: postcard::Error) -> LogError {
    match e {
        postcard::Error::SerializeBufferFull => LogError::BufferTooSmall,
        _ => LogError::Serialize,
    }
}

/// Encodes `frame` into `buf` as a complete wire frame (COBS bytes and the trailing 0x00)
/// and returns its length. A buffer of [`MAX_FRAME_LEN`] bytes always suffices.
pub fn encode_frame(frame: &Frame, buf: &mut [u8]) -> Result<usize, LogError> {
    use postcard::ser_flavors::{crc::CrcModifier, Cobs, Slice};
    let cobs = Cobs::try_new(Slice::new(buf)).map_err(map_serialize_error)?;
    let written = postcard::serialize_with_flavor(frame, CrcModifier::new(cobs, LOG_CRC.digest()))
        .map_err(map_serialize_error)?;
    Ok(written.len())
}

/// Decodes one frame from its COBS bytes (delimiter excluded). Decodes COBS in place, so
/// `cobs_bytes` is overwritten.
pub fn decode_frame(cobs_bytes: &mut [u8]) -> Result<Frame, LogError> {
    if cobs_bytes.is_empty() {
        return Err(LogError::EmptyFrame);
    }
    // `cobs` stops at an embedded zero; a zero inside a frame means corruption.
    if cobs_bytes.contains(&0) {
        return Err(LogError::Cobs);
    }
    let len = cobs::decode_in_place(cobs_bytes).map_err(|_| LogError::Cobs)?;
    decode_payload(cobs_bytes.get(..len).ok_or(LogError::Cobs)?)
}

/// Decodes COBS-decoded bytes (postcard payload followed by the CRC).
pub fn decode_payload(decoded: &[u8]) -> Result<Frame, LogError> {
    let Some((payload, crc_bytes)) = decoded.split_last_chunk::<CRC_LEN>() else {
        return Err(LogError::TooShort { len: decoded.len() });
    };
    if payload.is_empty() {
        return Err(LogError::TooShort { len: decoded.len() });
    }
    let received = u32::from_le_bytes(*crc_bytes);
    let computed = LOG_CRC.checksum(payload);
    if received != computed {
        return Err(LogError::CrcMismatch { received, computed });
    }
    let (tag, _) = postcard::take_from_bytes::<u32>(payload).map_err(|_| LogError::Malformed)?;
    if tag >= FRAME_KINDS {
        return Err(LogError::UnknownKind { tag });
    }
    let (frame, rest) =
        postcard::take_from_bytes::<Frame>(payload).map_err(|_| LogError::Malformed)?;
    if !rest.is_empty() {
        return Err(LogError::TrailingBytes { extra: rest.len() });
    }
    Ok(frame)
}

/// Byte and frame counts of a stream fed to a [`FrameAccumulator`].
///
/// After [`FrameAccumulator::finish`], `bytes_decoded + bytes_dropped == bytes_seen`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamStats {
    /// Bytes fed so far.
    pub bytes_seen: u64,
    /// Bytes belonging to decoded frames, delimiters included.
    pub bytes_decoded: u64,
    /// Bytes not belonging to any decoded frame (corrupted runs, garbage, empty-run
    /// delimiters, a truncated tail).
    pub bytes_dropped: u64,
    /// Frames decoded.
    pub frames_decoded: u64,
    /// Byte runs that held no valid frame: each corrupted run between delimiters, each
    /// undecodable prefix in front of a recovered frame, and a truncated tail.
    pub frames_dropped: u64,
}

/// Reassembles frames from a byte stream fed one slice at a time, with a fixed buffer of
/// `N` bytes (at least `MAX_FRAME_LEN - 1`, see [`LogAccumulator`]).
///
/// After a run fails to decode, the accumulator retries every suffix of the run's last `N`
/// bytes, so a frame preceded by garbage or by the remains of a damaged frame (whose
/// delimiter was lost) is still recovered. A retried suffix is accepted only if COBS, the
/// CRC-32 and postcard all agree, so a false frame needs a CRC collision (about 2^-32 per try).
///
/// Hand-written because postcard's `CobsAccumulator` checks no CRC and cannot resynchronise
/// inside a run.
pub struct FrameAccumulator<const N: usize> {
    /// The last `N` bytes of the current run, as a ring starting at `start`.
    ring: [u8; N],
    start: usize,
    held: usize,
    /// Bytes in the current run, which may exceed `N`.
    run_len: u64,
    scratch: [u8; N],
    /// A frame recovered after a dropped prefix, returned after the prefix's error.
    pending: Option<Frame>,
    stats: StreamStats,
}

impl<const N: usize> Default for FrameAccumulator<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameAccumulator<N> {
    const CAPACITY_OK: () = assert!(N > 1 + CRC_LEN, "accumulator too small for any frame");

    /// An empty accumulator.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::CAPACITY_OK;
        Self {
            ring: [0; N],
            start: 0,
            held: 0,
            run_len: 0,
            scratch: [0; N],
            pending: None,
            stats: StreamStats {
                bytes_seen: 0,
                bytes_decoded: 0,
                bytes_dropped: 0,
                frames_decoded: 0,
                frames_dropped: 0,
            },
        }
    }

    /// Counts so far.
    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// Bytes of the unfinished run held since the last delimiter.
    pub fn pending_run_len(&self) -> u64 {
        self.run_len
    }

    /// Consumes bytes from the front of `input` up to the end of the next frame and returns
    /// that frame or the error of the run that failed; `None` once `input` is exhausted
    /// without a complete run. `input` is advanced past the consumed bytes.
    pub fn next_frame(&mut self, input: &mut &[u8]) -> Option<Result<Frame, LogError>> {
        if let Some(frame) = self.pending.take() {
            return Some(Ok(frame));
        }
        while let Some((&byte, rest)) = input.split_first() {
            *input = rest;
            self.stats.bytes_seen += 1;
            if byte != 0 {
                self.push_byte(byte);
                continue;
            }
            if self.run_len == 0 {
                // Two delimiters in a row carry nothing; the spare delimiter is dropped.
                self.stats.bytes_dropped += 1;
                continue;
            }
            return Some(self.close_run());
        }
        None
    }

    /// Iterates over the frames and errors completed by `input`. Iterate to the end: bytes
    /// not reached when the iterator is dropped are lost.
    pub fn feed<'a>(&'a mut self, input: &'a [u8]) -> Feed<'a, N> {
        Feed { acc: self, input }
    }

    /// Ends the stream: an unfinished run is counted as dropped and reported as
    /// [`LogError::Truncated`]. The accumulator is then ready for a new stream (its counts
    /// are kept).
    pub fn finish(&mut self) -> Option<LogError> {
        if self.run_len == 0 {
            return None;
        }
        let len = self.run_len;
        self.stats.bytes_dropped += len;
        self.stats.frames_dropped += 1;
        self.reset_run();
        Some(LogError::Truncated {
            len: usize::try_from(len).unwrap_or(usize::MAX),
        })
    }

    fn push_byte(&mut self, byte: u8) {
        if self.held < N {
            let index = (self.start + self.held) % N;
            self.ring[index] = byte;
            self.held += 1;
        } else {
            self.ring[self.start] = byte;
            self.start = (self.start + 1) % N;
        }
        self.run_len += 1;
    }

    fn reset_run(&mut self) {
        self.start = 0;
        self.held = 0;
        self.run_len = 0;
    }

    /// Decodes the run just closed by a delimiter.
    fn close_run(&mut self) -> Result<Frame, LogError> {
        self.ring.rotate_left(self.start);
        self.start = 0;
        let held = self.held;
        let run_len = self.run_len;
        let overflowed = run_len > held as u64;
        let whole_error = if overflowed {
            LogError::FrameTooLong
        } else {
            match decode_from(&self.ring[..held], &mut self.scratch) {
                Ok(frame) => {
                    self.stats.frames_decoded += 1;
                    self.stats.bytes_decoded += run_len + 1;
                    self.reset_run();
                    return Ok(frame);
                }
                Err(e) => e,
            }
        };
        // The whole run is bad: look for a frame that ends it.
        let first_suffix = if overflowed { 0 } else { 1 };
        let mut recovered = None;
        for skip in first_suffix..held.saturating_sub(CRC_LEN + 1) {
            if let Ok(frame) = decode_from(&self.ring[skip..held], &mut self.scratch) {
                recovered = Some((skip, frame));
                break;
            }
        }
        self.stats.frames_dropped += 1;
        match recovered {
            Some((skip, frame)) => {
                let frame_len = (held - skip) as u64;
                self.stats.bytes_dropped += run_len - frame_len;
                self.stats.bytes_decoded += frame_len + 1;
                self.stats.frames_decoded += 1;
                self.pending = Some(frame);
            }
            None => self.stats.bytes_dropped += run_len + 1,
        }
        self.reset_run();
        Err(whole_error)
    }
}

/// COBS-decodes `encoded` into `scratch` (leaving `encoded` intact) and decodes the frame.
fn decode_from(encoded: &[u8], scratch: &mut [u8]) -> Result<Frame, LogError> {
    let len = cobs::decode(encoded, scratch).map_err(|_| LogError::Cobs)?;
    decode_payload(scratch.get(..len).ok_or(LogError::Cobs)?)
}

/// Iterator returned by [`FrameAccumulator::feed`].
pub struct Feed<'a, const N: usize> {
    acc: &'a mut FrameAccumulator<N>,
    input: &'a [u8],
}

impl<const N: usize> Iterator for Feed<'_, N> {
    type Item = Result<Frame, LogError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.acc.next_frame(&mut self.input)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wavelet::{LevelSums, MAX_SNAPSHOT_LEVELS};
    use proptest::prelude::*;

    fn encode(frame: &Frame) -> std::vec::Vec<u8> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode_frame(frame, &mut buf).unwrap();
        buf[..n].to_vec()
    }

    fn header_example() -> Frame {
        let mut imus = heapless::Vec::new();
        imus.push(ImuConfig {
            imu_id: 0,
            model: heapless::String::try_from("ICM-42688-P").unwrap(),
            sample_rate_hz: 1000.0,
            gyro_scale_rad_s_per_count: 0.5,
            accel_scale_m_s2_per_count: 0.25,
        })
        .unwrap();
        Frame::Header(Header {
            protocol_version: 1,
            board: heapless::String::try_from("dyn1").unwrap(),
            imus,
        })
    }

    fn imu_example() -> Frame {
        Frame::Imu(ImuSampleSet {
            t_us: 1_000_000,
            imu_id: 0,
            gyro_counts: [1, -1, 300],
            accel_counts: [0, -2048, 16384],
        })
    }

    fn pps_example() -> Frame {
        Frame::Pps(PpsEvent {
            t_us: 2_000_000,
            sequence: 7,
        })
    }

    fn gnss_example() -> Frame {
        Frame::Gnss(GnssFix {
            t_us: 3_000_000,
            lat_rad: 0.5,
            lon_rad: -0.125,
            h_m: 400.0,
            vel_ned_m_s: [1.0, -2.0, 0.0],
            pos_sigma_m: 2.5,
            vel_sigma_m_s: 0.25,
            num_sats: 12,
            fix_type: 3,
        })
    }

    fn filter_example() -> Frame {
        Frame::Filter(FilterState {
            t_us: 4_000_000,
            imu_id: 1,
            q_nb: [1.0, 0.0, 0.0, 0.0],
            vel_ned_m_s: [0.5, 0.0, -0.5],
            lat_rad: 0.5,
            lon_rad: 0.25,
            h_m: 10.0,
            gyro_bias_rad_s: [0.0; 3],
            accel_bias_m_s2: [0.0; 3],
            attitude_sigma_rad: [0.0; 3],
            vel_sigma_m_s: [0.0; 3],
            pos_sigma_m: [0.0; 3],
            gyro_bias_sigma_rad_s: [0.0; 3],
            accel_bias_sigma_m_s2: [2.0; 3],
        })
    }

    fn health_example() -> Frame {
        Frame::Health(Health {
            t_us: 5_000_000,
            frames_dropped: 0,
            samples_overrun: 200,
            flags: Health::FLAG_TIME_GPS | Health::FLAG_PPS_LOCKED,
            cpu_load_permille: 125,
            imu_temperature_deg_c: [25.0, -1.5, f32::NAN],
        })
    }

    fn wv_example() -> Frame {
        let levels = [
            (1, 0, 5999, 123_456_789u128, false),
            (2, 1, 2999, (1u128 << 70) + 5, false),
            (3, 2, 0, 0, false),
        ]
        .into_iter()
        .map(|(level, stride_log2, count, sum_sq, saturated)| LevelSums {
            level,
            stride_log2,
            count,
            sum_sq,
            saturated,
        })
        .collect();
        Frame::WaveletVariance(WvFrame {
            t_us: 59_990_000,
            imu_id: 0,
            channel: 2,
            snapshot: WvSnapshot {
                n_samples: 6000,
                full_levels: 1,
                levels,
            },
        })
    }

    /// Decodes one wire frame (delimiter included).
    fn decode_bytes(wire: &[u8]) -> Result<Frame, LogError> {
        let (last, body) = wire.split_last().unwrap();
        assert_eq!(*last, 0);
        decode_frame(&mut body.to_vec())
    }

    fn postcard_bytes(frame: &Frame) -> std::vec::Vec<u8> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        postcard::to_slice(frame, &mut buf).unwrap().to_vec()
    }

    fn examples() -> std::vec::Vec<Frame> {
        std::vec![
            header_example(),
            imu_example(),
            pps_example(),
            gnss_example(),
            filter_example(),
            health_example(),
            wv_example(),
            noise_example(),
            fault_example(),
        ]
    }

    fn noise_example() -> Frame {
        Frame::Noise(NoiseFrame {
            t_us: 6_000_000,
            gyro_sigma_rad_s: [0.01, 0.02, 0.03],
            accel_sigma_m_s2: [0.1, 0.2, f32::NAN],
            in_use: 0b11_1011,
            still: true,
        })
    }

    fn fault_example() -> Frame {
        Frame::Fault(FaultFrame {
            t_us: 7_000_000,
            detected_t_us: 6_500_000,
            sensor: FaultFrame::SENSOR_ACCEL,
            unit: Some(2),
            axis: None,
            kind: 4,
        })
    }

    #[test]
    fn header_encodes_to_exact_bytes() {
        let expected: &[u8] = &[
            0x01, 0x08, 0x01, 0x04, 0x64, 0x79, 0x6E, 0x31, 0x01, 0x0D, 0x0B, 0x49, 0x43, 0x4D,
            0x2D, 0x34, 0x32, 0x36, 0x38, 0x38, 0x2D, 0x50, 0x01, 0x03, 0x7A, 0x44, 0x01, 0x01,
            0x01, 0x01, 0x01, 0x03, 0xE0, 0x3F, 0x01, 0x01, 0x01, 0x01, 0x01, 0x06, 0xD0, 0x3F,
            0x77, 0x99, 0xE3, 0x01, 0x00,
        ];
        assert_eq!(encode(&header_example()), expected);
        assert_eq!(decode_bytes(expected), Ok(header_example()));
    }

    #[test]
    fn imu_encodes_to_exact_bytes() {
        let expected: &[u8] = &[
            0x05, 0x01, 0xC0, 0x84, 0x3D, 0x05, 0x02, 0x01, 0xD8, 0x04, 0x0A, 0xFF, 0x1F, 0x80,
            0x80, 0x02, 0x11, 0x57, 0x28, 0x82, 0x00,
        ];
        assert_eq!(encode(&imu_example()), expected);
        assert_eq!(decode_bytes(expected), Ok(imu_example()));
    }

    #[test]
    fn pps_encodes_to_exact_bytes() {
        let expected: &[u8] = &[
            0x0A, 0x02, 0x80, 0x89, 0x7A, 0x07, 0x96, 0x36, 0xEB, 0xF4, 0x00,
        ];
        assert_eq!(encode(&pps_example()), expected);
        assert_eq!(decode_bytes(expected), Ok(pps_example()));
    }

    #[test]
    fn gnss_encodes_to_exact_bytes() {
        let expected: &[u8] = &[
            0x06, 0x03, 0xC0, 0x8D, 0xB7, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0xE0, 0x3F,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0xC0, 0xBF, 0x01, 0x03, 0xC8, 0x43, 0x01, 0x03,
            0x80, 0x3F, 0x01, 0x01, 0x02, 0xC0, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0x20, 0x40,
            0x01, 0x09, 0x80, 0x3E, 0x0C, 0x03, 0x90, 0x9E, 0x33, 0x2C, 0x00,
        ];
        assert_eq!(encode(&gnss_example()), expected);
        assert_eq!(decode_bytes(expected), Ok(gnss_example()));
    }

    #[test]
    fn filter_encodes_to_exact_bytes() {
        let expected: &[u8] = &[
            0x07, 0x04, 0x80, 0x92, 0xF4, 0x01, 0x01, 0x01, 0x03, 0x80, 0x3F, 0x01, 0x01, 0x01,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x02, 0x3F, 0x01,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x02, 0xBF, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0xE0,
            0x3F, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0xD0, 0x3F, 0x01, 0x03, 0x20, 0x41, 0x01,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
            0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
            0x01, 0x01, 0x01, 0x02, 0x40, 0x01, 0x01, 0x02, 0x40, 0x01, 0x01, 0x06, 0x40, 0xEE,
            0x71, 0xF3, 0x2B, 0x00,
        ];
        assert_eq!(encode(&filter_example()), expected);
        assert_eq!(decode_bytes(expected), Ok(filter_example()));
    }

    #[test]
    fn health_encodes_to_exact_bytes() {
        let expected: &[u8] = &[
            0x06, 0x05, 0xC0, 0x96, 0xB1, 0x02, 0x05, 0xC8, 0x01, 0x03, 0x7D, 0x01, 0x03, 0xC8,
            0x41, 0x01, 0x03, 0xC0, 0xBF, 0x01, 0x07, 0xC0, 0x7F, 0x30, 0x9B, 0x6B, 0x44, 0x00,
        ];
        assert_eq!(encode(&health_example()), expected);
        // NaN != NaN, so compare the decoded frame bit for bit through its encoding.
        assert_eq!(encode(&decode_bytes(expected).unwrap()), expected);
    }

    #[test]
    fn wavelet_variance_encodes_to_exact_bytes() {
        // postcard: 06 | t_us f0 bf cd 1c | imu 00 | channel 02 | n_samples f0 2e | full 01 |
        // 3 levels 03 | 01 00 ef2e 959aef3a 00 | 02 01 b717 85 80x8 01 00 (2^70 + 5) |
        // 03 02 00 00 00; CRC 0x57692293.
        let expected: &[u8] = &[
            0x06, 0x06, 0xF0, 0xBF, 0xCD, 0x1C, 0x07, 0x02, 0xF0, 0x2E, 0x01, 0x03, 0x01, 0x07,
            0xEF, 0x2E, 0x95, 0x9A, 0xEF, 0x3A, 0x10, 0x02, 0x01, 0xB7, 0x17, 0x85, 0x80, 0x80,
            0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x01, 0x03, 0x03, 0x02, 0x01, 0x01, 0x05,
            0x93, 0x22, 0x69, 0x57, 0x00,
        ];
        assert_eq!(encode(&wv_example()), expected);
        assert_eq!(decode_bytes(expected), Ok(wv_example()));
    }

    #[test]
    fn crc_is_ieee_802_3() {
        assert_eq!(LOG_CRC.checksum(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn tags_follow_variant_order() {
        for (expected_tag, frame) in examples().iter().enumerate() {
            assert_eq!(frame.tag(), expected_tag as u32);
            let postcard = postcard_bytes(frame);
            assert_eq!(postcard[0], expected_tag as u8, "{}", frame.kind_name());
        }
        assert_eq!(examples().len() as u32, FRAME_KINDS);
    }

    fn full_string<const N: usize>(c: char) -> heapless::String<N> {
        let mut s = heapless::String::new();
        while s.push(c).is_ok() {}
        s
    }

    /// Largest-encoding value of each kind: maximal varints, full strings and vectors, and
    /// no zero byte anywhere (the worst case for COBS).
    fn worst_case_frames() -> std::vec::Vec<Frame> {
        let imu = ImuConfig {
            imu_id: 0xFF,
            model: full_string('M'),
            sample_rate_hz: f32::MAX,
            gyro_scale_rad_s_per_count: f64::MAX,
            accel_scale_m_s2_per_count: f64::MIN,
        };
        let mut imus = heapless::Vec::new();
        for _ in 0..MAX_IMUS {
            imus.push(imu.clone()).unwrap();
        }
        let f = -1.0f32 / 3.0;
        std::vec![
            Frame::Header(Header {
                protocol_version: u16::MAX,
                board: full_string('B'),
                imus,
            }),
            Frame::Imu(ImuSampleSet {
                t_us: u64::MAX,
                imu_id: 0xFF,
                gyro_counts: [i32::MIN; 3],
                accel_counts: [i32::MAX; 3],
            }),
            Frame::Pps(PpsEvent {
                t_us: u64::MAX,
                sequence: u32::MAX,
            }),
            Frame::Gnss(GnssFix {
                t_us: u64::MAX,
                lat_rad: -1.0 / 3.0,
                lon_rad: -1.0 / 3.0,
                h_m: f,
                vel_ned_m_s: [f; 3],
                pos_sigma_m: f,
                vel_sigma_m_s: f,
                num_sats: 0xFF,
                fix_type: 0xFF,
            }),
            Frame::Filter(FilterState {
                t_us: u64::MAX,
                imu_id: 0xFF,
                q_nb: [f; 4],
                vel_ned_m_s: [f; 3],
                lat_rad: -1.0 / 3.0,
                lon_rad: -1.0 / 3.0,
                h_m: f,
                gyro_bias_rad_s: [f; 3],
                accel_bias_m_s2: [f; 3],
                attitude_sigma_rad: [f; 3],
                vel_sigma_m_s: [f; 3],
                pos_sigma_m: [f; 3],
                gyro_bias_sigma_rad_s: [f; 3],
                accel_bias_sigma_m_s2: [f; 3],
            }),
            Frame::Health(Health {
                t_us: u64::MAX,
                frames_dropped: u32::MAX,
                samples_overrun: u32::MAX,
                flags: u32::MAX,
                cpu_load_permille: u16::MAX,
                imu_temperature_deg_c: [f; MAX_IMUS],
            }),
            Frame::WaveletVariance(WvFrame {
                t_us: u64::MAX,
                imu_id: 0xFF,
                channel: 0xFF,
                snapshot: WvSnapshot {
                    n_samples: u64::MAX,
                    full_levels: 0xFF,
                    levels: (0..MAX_SNAPSHOT_LEVELS)
                        .map(|_| LevelSums {
                            level: 0xFF,
                            stride_log2: 0xFF,
                            count: u64::MAX,
                            sum_sq: u128::MAX,
                            saturated: true,
                        })
                        .collect(),
                },
            }),
            Frame::Noise(NoiseFrame {
                t_us: u64::MAX,
                gyro_sigma_rad_s: [f; MAX_IMUS],
                accel_sigma_m_s2: [f; MAX_IMUS],
                in_use: 0xFF,
                still: true,
            }),
            Frame::Fault(FaultFrame {
                t_us: u64::MAX,
                detected_t_us: u64::MAX,
                sensor: 0xFF,
                unit: Some(0xFF),
                axis: Some(0xFF),
                kind: 0xFF,
            }),
        ]
    }

    #[test]
    fn max_sizes_are_attained_exactly() {
        let kind_max = [
            Header::MAX_POSTCARD_LEN,
            ImuSampleSet::MAX_POSTCARD_LEN,
            PpsEvent::MAX_POSTCARD_LEN,
            GnssFix::MAX_POSTCARD_LEN,
            FilterState::MAX_POSTCARD_LEN,
            Health::MAX_POSTCARD_LEN,
            WvFrame::MAX_POSTCARD_LEN,
            NoiseFrame::MAX_POSTCARD_LEN,
            FaultFrame::MAX_POSTCARD_LEN,
        ];
        let mut largest_wire = 0;
        let mut largest_regular_wire = 0;
        for (frame, max) in worst_case_frames().iter().zip(kind_max) {
            let postcard = postcard_bytes(frame);
            assert_eq!(postcard.len(), 1 + max, "{}", frame.kind_name());
            // Beyond the tag (0 for the header), no zero byte: the most COBS overhead.
            assert!(
                !postcard[1..].contains(&0),
                "{}: {:02x?}",
                frame.kind_name(),
                postcard
            );
            let wire = encode(frame);
            assert!(wire.len() <= MAX_FRAME_LEN, "{}", frame.kind_name());
            largest_wire = largest_wire.max(wire.len());
            if !matches!(frame, Frame::WaveletVariance(_)) {
                largest_regular_wire = largest_regular_wire.max(wire.len());
            }
            assert_eq!(encode(&decode_bytes(&wire).unwrap()), wire);
        }
        // The bound is tight: the largest frame uses all of it.
        assert_eq!(largest_wire, MAX_FRAME_LEN);
        assert_eq!(largest_regular_wire, MAX_REGULAR_FRAME_LEN);
        // The figures quoted in docs/log-format.md.
        assert_eq!(MAX_FRAME_LEN, 1059);
        assert_eq!(MAX_REGULAR_FRAME_LEN, 158);
    }

    #[test]
    fn encode_into_short_buffers_fails_cleanly() {
        for frame in examples().iter().chain(worst_case_frames().iter()) {
            let needed = encode(frame).len();
            for len in 0..needed {
                let mut buf = std::vec![0u8; len];
                assert_eq!(encode_frame(frame, &mut buf), Err(LogError::BufferTooSmall));
            }
        }
    }

    #[test]
    fn decode_reports_each_error_kind() {
        assert_eq!(decode_frame(&mut []), Err(LogError::EmptyFrame));
        assert_eq!(
            decode_frame(&mut [0x05, 0x01, 0x00, 0x02]),
            Err(LogError::Cobs)
        );
        // COBS code byte claims more bytes than follow.
        assert_eq!(decode_frame(&mut [0x09, 0x01, 0x02]), Err(LogError::Cobs));
        assert_eq!(
            decode_frame(&mut [0x04, 0x01, 0x02, 0x03]),
            Err(LogError::TooShort { len: 3 })
        );
        let mut wire = encode(&pps_example());
        wire[3] ^= 0x10;
        assert!(matches!(
            decode_bytes(&wire),
            Err(LogError::CrcMismatch { .. })
        ));

        // Valid CRCs around payloads that are not frames of this build.
        let with_crc = |payload: &[u8]| {
            let mut decoded = payload.to_vec();
            decoded.extend_from_slice(&LOG_CRC.checksum(payload).to_le_bytes());
            decoded
        };
        assert_eq!(
            decode_payload(&with_crc(&[0x09, 0x01])),
            Err(LogError::UnknownKind { tag: 9 })
        );
        // A PPS frame cut short inside its sequence varint.
        assert_eq!(
            decode_payload(&with_crc(&[0x02, 0x80, 0x89, 0x7A, 0x87])),
            Err(LogError::Malformed)
        );
        assert_eq!(
            decode_payload(&with_crc(&[0x02, 0x80, 0x89, 0x7A, 0x07, 0x55])),
            Err(LogError::TrailingBytes { extra: 1 })
        );
        // A string longer than its capacity.
        let mut long_board = std::vec![0x00, 0x01, 33];
        long_board.extend_from_slice(&[b'x'; 33]);
        long_board.push(0);
        assert_eq!(
            decode_payload(&with_crc(&long_board)),
            Err(LogError::Malformed)
        );
    }

    fn stream_of(frames: &[Frame]) -> std::vec::Vec<u8> {
        frames.iter().flat_map(encode).collect()
    }

    fn collect(
        acc: &mut LogAccumulator,
        bytes: &[u8],
        chunk: usize,
    ) -> std::vec::Vec<Result<Frame, LogError>> {
        let mut out = std::vec::Vec::new();
        for piece in bytes.chunks(chunk) {
            out.extend(acc.feed(piece));
        }
        if let Some(e) = acc.finish() {
            out.push(Err(e));
        }
        out
    }

    #[test]
    fn accumulator_reassembles_any_chunking() {
        let frames = examples();
        let stream = stream_of(&frames);
        for chunk in [1, 2, 3, 7, 64, stream.len()] {
            let mut acc = LogAccumulator::new();
            let got = collect(&mut acc, &stream, chunk);
            let got: std::vec::Vec<Frame> = got.into_iter().map(Result::unwrap).collect();
            assert_eq!(got.len(), frames.len());
            for (a, b) in got.iter().zip(&frames) {
                assert_eq!(encode(a), encode(b));
            }
            let stats = acc.stats();
            assert_eq!(stats.bytes_seen, stream.len() as u64);
            assert_eq!(stats.bytes_decoded, stream.len() as u64);
            assert_eq!(stats.bytes_dropped, 0);
            assert_eq!(stats.frames_decoded, frames.len() as u64);
            assert_eq!(stats.frames_dropped, 0);
        }
    }

    #[test]
    fn accumulator_recovers_frame_after_garbage_in_same_run() {
        let mut stream = std::vec![0x13u8, 0x37, 0x99, 0x01, 0x02];
        stream.extend(encode(&imu_example()));
        let mut acc = LogAccumulator::new();
        let got = collect(&mut acc, &stream, 4);
        assert_eq!(got.len(), 2);
        assert!(got[0].is_err());
        assert_eq!(got[1], Ok(imu_example()));
        let stats = acc.stats();
        assert_eq!(stats.bytes_dropped, 5);
        assert_eq!(stats.frames_dropped, 1);
        assert_eq!(stats.bytes_decoded, encode(&imu_example()).len() as u64);
    }

    #[test]
    fn accumulator_recovers_frame_after_overlong_garbage() {
        let garbage = std::vec![0x5Au8; 3 * MAX_FRAME_LEN + 11];
        let mut stream = garbage.clone();
        stream.extend(encode(&pps_example()));
        stream.extend(encode(&imu_example()));
        let mut acc = LogAccumulator::new();
        let got = collect(&mut acc, &stream, 17);
        assert_eq!(
            got,
            std::vec![
                Err(LogError::FrameTooLong),
                Ok(pps_example()),
                Ok(imu_example())
            ]
        );
        assert_eq!(acc.stats().bytes_dropped, garbage.len() as u64);
    }

    #[test]
    fn accumulator_drops_corrupted_and_truncated_frames_only() {
        let frames = [pps_example(), imu_example(), gnss_example(), pps_example()];
        let mut stream = stream_of(&frames);
        let pps_len = encode(&pps_example()).len();
        stream[pps_len + 4] ^= 0x01; // inside the IMU frame
        stream.truncate(stream.len() - 3); // cut the last PPS frame
        let mut acc = LogAccumulator::new();
        let got = collect(&mut acc, &stream, 5);
        assert_eq!(got.len(), 4);
        assert_eq!(got[0], Ok(pps_example()));
        assert!(matches!(got[1], Err(LogError::CrcMismatch { .. })));
        assert_eq!(got[2], Ok(gnss_example()));
        assert_eq!(got[3], Err(LogError::Truncated { len: pps_len - 3 }));
        let stats = acc.stats();
        assert_eq!(stats.frames_dropped, 2);
        assert_eq!(stats.frames_decoded, 2);
        assert_eq!(
            stats.bytes_decoded + stats.bytes_dropped,
            stream.len() as u64
        );
    }

    #[test]
    fn spare_delimiters_are_skipped_and_counted() {
        let mut stream = std::vec![0u8, 0];
        stream.extend(encode(&pps_example()));
        stream.push(0);
        let mut acc = LogAccumulator::new();
        assert_eq!(collect(&mut acc, &stream, 3), std::vec![Ok(pps_example())]);
        assert_eq!(acc.stats().bytes_dropped, 3);
        assert_eq!(acc.stats().frames_dropped, 0);
    }

    fn heapless_string<const N: usize>() -> impl Strategy<Value = heapless::String<N>> {
        proptest::collection::vec(any::<char>(), 0..=N).prop_map(|chars| {
            let mut s = heapless::String::new();
            for c in chars {
                // A char that no longer fits is skipped; a shorter one may still fit.
                let _ = s.push(c);
            }
            s
        })
    }

    fn arb_imu_config() -> impl Strategy<Value = ImuConfig> {
        (
            any::<u8>(),
            heapless_string::<IMU_MODEL_LEN>(),
            any::<f32>(),
            any::<f64>(),
            any::<f64>(),
        )
            .prop_map(|(imu_id, model, rate, g, a)| ImuConfig {
                imu_id,
                model,
                sample_rate_hz: rate,
                gyro_scale_rad_s_per_count: g,
                accel_scale_m_s2_per_count: a,
            })
    }

    fn arb_frame() -> impl Strategy<Value = Frame> {
        let f3 = || any::<[f32; 3]>();
        prop_oneof![
            (
                any::<u16>(),
                heapless_string::<BOARD_NAME_LEN>(),
                proptest::collection::vec(arb_imu_config(), 0..=MAX_IMUS)
            )
                .prop_map(|(v, board, imus)| Frame::Header(Header {
                    protocol_version: v,
                    board,
                    imus: imus.into_iter().collect(),
                })),
            (
                any::<u64>(),
                any::<u8>(),
                any::<[i32; 3]>(),
                any::<[i32; 3]>()
            )
                .prop_map(|(t_us, imu_id, g, a)| Frame::Imu(ImuSampleSet {
                    t_us,
                    imu_id,
                    gyro_counts: g,
                    accel_counts: a,
                })),
            (any::<u64>(), any::<u32>())
                .prop_map(|(t_us, sequence)| Frame::Pps(PpsEvent { t_us, sequence })),
            (
                any::<u64>(),
                any::<(f64, f64, f32)>(),
                f3(),
                any::<(f32, f32, u8, u8)>()
            )
                .prop_map(|(t_us, (lat, lon, h), v, (ps, vs, n, fix))| {
                    Frame::Gnss(GnssFix {
                        t_us,
                        lat_rad: lat,
                        lon_rad: lon,
                        h_m: h,
                        vel_ned_m_s: v,
                        pos_sigma_m: ps,
                        vel_sigma_m_s: vs,
                        num_sats: n,
                        fix_type: fix,
                    })
                }),
            (
                (any::<u64>(), any::<u8>(), any::<[f32; 4]>(), f3()),
                (any::<f64>(), any::<f64>(), any::<f32>()),
                (f3(), f3(), f3(), f3(), f3(), f3(), f3())
            )
                .prop_map(
                    |((t_us, imu_id, q, v), (lat, lon, h), (bg, ba, sa, sv, sp, sbg, sba))| {
                        Frame::Filter(FilterState {
                            t_us,
                            imu_id,
                            q_nb: q,
                            vel_ned_m_s: v,
                            lat_rad: lat,
                            lon_rad: lon,
                            h_m: h,
                            gyro_bias_rad_s: bg,
                            accel_bias_m_s2: ba,
                            attitude_sigma_rad: sa,
                            vel_sigma_m_s: sv,
                            pos_sigma_m: sp,
                            gyro_bias_sigma_rad_s: sbg,
                            accel_bias_sigma_m_s2: sba,
                        })
                    }
                ),
            (any::<(u64, u32, u32, u32, u16)>(), f3()).prop_map(
                |((t_us, fd, so, flags, load), temp)| Frame::Health(Health {
                    t_us,
                    frames_dropped: fd,
                    samples_overrun: so,
                    flags,
                    cpu_load_permille: load,
                    imu_temperature_deg_c: temp,
                })
            ),
            (
                any::<(u64, u8, u8, u64, u8)>(),
                proptest::collection::vec(
                    any::<(u8, u8, u64, u128, bool)>(),
                    0..=MAX_SNAPSHOT_LEVELS
                )
            )
                .prop_map(
                    |((t_us, imu_id, channel, n_samples, full_levels), levels)| {
                        Frame::WaveletVariance(WvFrame {
                            t_us,
                            imu_id,
                            channel,
                            snapshot: WvSnapshot {
                                n_samples,
                                full_levels,
                                levels: levels
                                    .into_iter()
                                    .map(|(level, stride_log2, count, sum_sq, saturated)| {
                                        LevelSums {
                                            level,
                                            stride_log2,
                                            count,
                                            sum_sq,
                                            saturated,
                                        }
                                    })
                                    .collect(),
                            },
                        })
                    }
                ),
        ]
    }

    proptest! {


        // Seeded: every failure reproduces (the project's rule for random generators).


        #![proptest_config(proptest::test_runner::Config {


            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed0a01),


            failure_persistence: Some(std::boxed::Box::new(


                proptest::test_runner::FileFailurePersistence::Off


            )),


            ..proptest::test_runner::Config::default()


        })]
        #[test]
        fn any_frame_round_trips_bit_exactly(frame in arb_frame()) {
            let mut buf = [0u8; MAX_FRAME_LEN];
            let n = encode_frame(&frame, &mut buf).unwrap();
            prop_assert!(n <= MAX_FRAME_LEN);
            prop_assert_eq!(buf[n - 1], 0);
            prop_assert!(!buf[..n - 1].contains(&0));
            let decoded = decode_frame(&mut buf[..n - 1].to_vec()).unwrap();
            // Floats compare by bits (NaN payloads included) through the encoding.
            prop_assert_eq!(encode(&decoded), buf[..n].to_vec());
            prop_assert_eq!(decoded.tag(), frame.tag());
        }

        #[test]
        fn any_frame_stream_round_trips_through_accumulator(
            frames in proptest::collection::vec(arb_frame(), 0..20),
            chunk in 1usize..200,
        ) {
            let stream = stream_of(&frames);
            let mut acc = LogAccumulator::new();
            let got = collect(&mut acc, &stream, chunk);
            prop_assert_eq!(got.len(), frames.len());
            for (got, sent) in got.iter().zip(&frames) {
                prop_assert_eq!(encode(got.as_ref().unwrap()), encode(sent));
            }
        }

        #[test]
        fn arbitrary_bytes_never_panic_and_account_for_every_byte(
            bytes in proptest::collection::vec(
                prop_oneof![3 => any::<u8>(), 1 => Just(0u8)], 0..2000),
            chunk in 1usize..300,
        ) {
            let _ = decode_frame(&mut bytes.clone());
            let mut acc = LogAccumulator::new();
            let _ = collect(&mut acc, &bytes, chunk);
            let stats = acc.stats();
            prop_assert_eq!(stats.bytes_seen, bytes.len() as u64);
            prop_assert_eq!(stats.bytes_decoded + stats.bytes_dropped, stats.bytes_seen);
        }
    }
}
