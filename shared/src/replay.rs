//! Replay input format: a sensor recording fed to the firmware's `board-replay` board.
//!
//! The replay board runs the real application under QEMU and takes its "sensor" data from a
//! host file (through semihosting) instead of SPI buses and timer captures. This module is
//! the one definition of that file's bytes: the host writes it (`dynacal::replay`) and the
//! firmware reads it, both through these functions, so the two cannot drift apart.
//!
//! Layout, all integers and floats little-endian (see `firmware/README.md`):
//!
//! ```text
//! header   magic "DCREPLAY" (8 bytes), format version u16 (= 2; 1 is read too: it has no
//!          GNSS records), IMU count u16 (1..=8),
//!          then per IMU (40 bytes): imu_id u8, 3 reserved zero bytes,
//!          model [u8; 16] ASCII NUL-padded, sample_rate_hz f32,
//!          gyro_scale_rad_s_per_count f64, accel_scale_m_s2_per_count f64
//! records  tag u8, then
//!          0x01 IMU sample set: t_us u64, imu_id u8, gyro counts [i32; 3], accel counts [i32; 3]
//!          0x02 PPS edge:       t_us u64
//!          0x03 GNSS bytes:     t_us u64, length u8 (1..=100), the receiver's bytes as its
//!                               UART delivered them (u-blox UBX), t_us when the last arrived
//!          0xFF end:            IMU sample-set count u64, PPS count u64 (must be the last bytes)
//! ```
//!
//! Timestamps are microseconds on the board's time base (the timer that captures data-ready
//! and PPS edges); counts are the sensor's raw integer outputs. The end record carries the
//! totals so a truncated file is detected instead of silently replayed short.

use heapless::Vec;

/// First bytes of every replay file.
pub const REPLAY_MAGIC: [u8; 8] = *b"DCREPLAY";
/// Version of the layout described in the module documentation.
pub const REPLAY_FORMAT_VERSION: u16 = 2;
/// Most IMUs one replay file may describe.
pub const MAX_REPLAY_IMUS: usize = 8;
/// Bytes of the fixed part of the header (magic, version, IMU count).
pub const HEADER_FIXED_LEN: usize = 12;
/// Bytes of one IMU description in the header.
pub const IMU_CONFIG_LEN: usize = 40;
/// Bytes of the longest header.
pub const MAX_HEADER_LEN: usize = HEADER_FIXED_LEN + MAX_REPLAY_IMUS * IMU_CONFIG_LEN;
/// Bytes of an IMU sample-set record, tag included.
pub const IMU_RECORD_LEN: usize = 34;
/// Bytes of a PPS record, tag included.
pub const PPS_RECORD_LEN: usize = 9;
/// Bytes of the end record, tag included.
pub const END_RECORD_LEN: usize = 17;
/// Most receiver bytes one GNSS record carries (a whole NAV-PVT frame).
pub const GNSS_CHUNK_MAX: usize = 100;
/// Bytes of a GNSS record before its data: tag, t_us, length.
pub const GNSS_RECORD_HEAD_LEN: usize = 10;
/// Bytes of the longest record.
pub const MAX_RECORD_LEN: usize = GNSS_RECORD_HEAD_LEN + GNSS_CHUNK_MAX;

const TAG_IMU: u8 = 0x01;
const TAG_PPS: u8 = 0x02;
const TAG_GNSS: u8 = 0x03;
const TAG_END: u8 = 0xFF;

/// One IMU as the replay file describes it: identity, rate and the scale factors that turn
/// its integer counts into SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayImu {
    pub imu_id: u8,
    /// Model name, ASCII, NUL-padded.
    pub model: [u8; 16],
    pub sample_rate_hz: f32,
    pub gyro_scale_rad_s_per_count: f64,
    pub accel_scale_m_s2_per_count: f64,
}

impl ReplayImu {
    /// The model name without its NUL padding (empty if it is not valid ASCII).
    pub fn model_str(&self) -> &str {
        let len = self.model.iter().position(|&b| b == 0).unwrap_or(16);
        match core::str::from_utf8(&self.model[..len]) {
            Ok(s) if s.is_ascii() => s,
            _ => "",
        }
    }

    /// Packs an ASCII model name into the fixed 16-byte field; `None` if it does not fit or
    /// is not ASCII.
    pub fn model_field(name: &str) -> Option<[u8; 16]> {
        if name.len() > 16 || !name.is_ascii() || name.bytes().any(|b| b == 0) {
            return None;
        }
        let mut field = [0u8; 16];
        field[..name.len()].copy_from_slice(name.as_bytes());
        Some(field)
    }
}

/// The replay file's header: the IMUs whose records follow.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayHeader {
    pub imus: Vec<ReplayImu, MAX_REPLAY_IMUS>,
}

impl ReplayHeader {
    /// A header declaring `imus` (1 to `MAX_REPLAY_IMUS`, unique ids, finite positive
    /// rates and scale factors).
    pub fn new(imus: &[ReplayImu]) -> Result<Self, ReplayError> {
        validate_imus(imus)?;
        let mut header = ReplayHeader { imus: Vec::new() };
        for imu in imus {
            header
                .imus
                .push(*imu)
                .map_err(|_| ReplayError::BadImuCount(imus.len() as u16))?;
        }
        Ok(header)
    }

    /// The description of IMU `imu_id`, if the header declares it.
    pub fn imu(&self, imu_id: u8) -> Option<&ReplayImu> {
        self.imus.iter().find(|imu| imu.imu_id == imu_id)
    }

    /// Bytes this header occupies in the file.
    pub fn encoded_len(&self) -> usize {
        HEADER_FIXED_LEN + self.imus.len() * IMU_CONFIG_LEN
    }
}

/// One record of the replay stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplayRecord {
    /// One sample set of one IMU, stamped at its data-ready edge.
    Imu {
        t_us: u64,
        imu_id: u8,
        gyro_counts: [i32; 3],
        accel_counts: [i32; 3],
    },
    /// A PPS edge captured at `t_us`.
    Pps { t_us: u64 },
    /// Bytes from the GNSS receiver's UART, the last received at `t_us`: `data[..len]`.
    Gnss {
        t_us: u64,
        len: u8,
        data: [u8; GNSS_CHUNK_MAX],
    },
    /// End of the stream, with the totals of the records before it.
    End {
        imu_sample_sets: u64,
        pps_edges: u64,
    },
}

impl ReplayRecord {
    /// Bytes this record occupies in the file.
    pub fn encoded_len(&self) -> usize {
        match self {
            ReplayRecord::Imu { .. } => IMU_RECORD_LEN,
            ReplayRecord::Pps { .. } => PPS_RECORD_LEN,
            ReplayRecord::Gnss { len, .. } => GNSS_RECORD_HEAD_LEN + usize::from(*len),
            ReplayRecord::End { .. } => END_RECORD_LEN,
        }
    }

    /// A GNSS record of `bytes` (1 to [`GNSS_CHUNK_MAX`]) received by `t_us`.
    pub fn gnss(t_us: u64, bytes: &[u8]) -> Result<Self, ReplayError> {
        if bytes.is_empty() || bytes.len() > GNSS_CHUNK_MAX {
            return Err(ReplayError::BadGnssLength(bytes.len().min(255) as u8));
        }
        let mut data = [0u8; GNSS_CHUNK_MAX];
        data[..bytes.len()].copy_from_slice(bytes);
        Ok(ReplayRecord::Gnss {
            t_us,
            len: bytes.len() as u8,
            data,
        })
    }
}

/// Why replay bytes could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplayError {
    /// More bytes are needed to finish the item (`needed` in total, from its start).
    Incomplete { needed: usize },
    /// The output buffer is too small for the item.
    BufferTooSmall { needed: usize },
    /// The file does not start with `REPLAY_MAGIC`.
    BadMagic,
    /// The header declares a format version this code does not read.
    UnsupportedVersion(u16),
    /// The header declares no IMU or more than `MAX_REPLAY_IMUS`.
    BadImuCount(u16),
    /// Two IMUs in the header share one id.
    DuplicateImuId(u8),
    /// A scale factor or rate is not finite and positive.
    BadImuConfig(u8),
    /// A record starts with an unknown tag byte.
    UnknownTag(u8),
    /// A GNSS record's length is 0 or more than [`GNSS_CHUNK_MAX`].
    BadGnssLength(u8),
}

impl core::fmt::Display for ReplayError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ReplayError::Incomplete { needed } => write!(f, "truncated: {needed} bytes needed"),
            ReplayError::BufferTooSmall { needed } => {
                write!(f, "output buffer too small: {needed} bytes needed")
            }
            ReplayError::BadMagic => write!(f, "not a dynacal replay file (bad magic)"),
            ReplayError::UnsupportedVersion(v) => {
                write!(f, "unsupported replay format version {v}")
            }
            ReplayError::BadImuCount(n) => {
                write!(f, "IMU count {n} outside 1..={MAX_REPLAY_IMUS}")
            }
            ReplayError::DuplicateImuId(id) => write!(f, "IMU id {id} declared twice"),
            ReplayError::BadImuConfig(id) => {
                write!(
                    f,
                    "IMU {id}: rate and scale factors must be finite and positive"
                )
            }
            ReplayError::UnknownTag(tag) => write!(f, "unknown record tag 0x{tag:02x}"),
            ReplayError::BadGnssLength(n) => {
                write!(
                    f,
                    "GNSS record of {n} bytes: 1 to {GNSS_CHUNK_MAX} are allowed"
                )
            }
        }
    }
}

// Fixed-width little-endian field access: the layout is a handful of plain fields, so a
// serialisation crate would add a second description of it without removing this one.
fn le_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn le_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}
fn le_u64(b: &[u8], at: usize) -> u64 {
    let mut raw = [0u8; 8];
    raw.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(raw)
}
fn le_i32x3(b: &[u8], at: usize) -> [i32; 3] {
    [
        le_u32(b, at) as i32,
        le_u32(b, at + 4) as i32,
        le_u32(b, at + 8) as i32,
    ]
}
fn put(out: &mut [u8], at: usize, bytes: &[u8]) {
    out[at..at + bytes.len()].copy_from_slice(bytes);
}
fn put_i32x3(out: &mut [u8], at: usize, v: &[i32; 3]) {
    for (k, x) in v.iter().enumerate() {
        put(out, at + 4 * k, &x.to_le_bytes());
    }
}

/// Writes `header` to the start of `out`; returns the bytes written.
pub fn encode_header(header: &ReplayHeader, out: &mut [u8]) -> Result<usize, ReplayError> {
    let len = header.encoded_len();
    if out.len() < len {
        return Err(ReplayError::BufferTooSmall { needed: len });
    }
    validate_imus(&header.imus)?;
    put(out, 0, &REPLAY_MAGIC);
    put(out, 8, &REPLAY_FORMAT_VERSION.to_le_bytes());
    put(out, 10, &(header.imus.len() as u16).to_le_bytes());
    for (k, imu) in header.imus.iter().enumerate() {
        let at = HEADER_FIXED_LEN + k * IMU_CONFIG_LEN;
        out[at] = imu.imu_id;
        put(out, at + 1, &[0, 0, 0]);
        put(out, at + 4, &imu.model);
        put(out, at + 20, &imu.sample_rate_hz.to_le_bytes());
        put(out, at + 24, &imu.gyro_scale_rad_s_per_count.to_le_bytes());
        put(out, at + 32, &imu.accel_scale_m_s2_per_count.to_le_bytes());
    }
    Ok(len)
}

fn validate_imus(imus: &[ReplayImu]) -> Result<(), ReplayError> {
    if imus.is_empty() || imus.len() > MAX_REPLAY_IMUS {
        return Err(ReplayError::BadImuCount(imus.len() as u16));
    }
    for (k, imu) in imus.iter().enumerate() {
        if imus[..k].iter().any(|other| other.imu_id == imu.imu_id) {
            return Err(ReplayError::DuplicateImuId(imu.imu_id));
        }
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(imu.sample_rate_hz as f64)
            || !positive(imu.gyro_scale_rad_s_per_count)
            || !positive(imu.accel_scale_m_s2_per_count)
        {
            return Err(ReplayError::BadImuConfig(imu.imu_id));
        }
    }
    Ok(())
}

/// Reads the header at the start of `bytes`; returns it and the bytes it occupied.
pub fn decode_header(bytes: &[u8]) -> Result<(ReplayHeader, usize), ReplayError> {
    if bytes.len() < HEADER_FIXED_LEN {
        return Err(ReplayError::Incomplete {
            needed: HEADER_FIXED_LEN,
        });
    }
    if bytes[..8] != REPLAY_MAGIC {
        return Err(ReplayError::BadMagic);
    }
    let version = le_u16(bytes, 8);
    if !(1..=REPLAY_FORMAT_VERSION).contains(&version) {
        return Err(ReplayError::UnsupportedVersion(version));
    }
    let count = le_u16(bytes, 10);
    if count == 0 || count as usize > MAX_REPLAY_IMUS {
        return Err(ReplayError::BadImuCount(count));
    }
    let len = HEADER_FIXED_LEN + count as usize * IMU_CONFIG_LEN;
    if bytes.len() < len {
        return Err(ReplayError::Incomplete { needed: len });
    }
    let mut imus = Vec::new();
    for k in 0..count as usize {
        let at = HEADER_FIXED_LEN + k * IMU_CONFIG_LEN;
        let mut model = [0u8; 16];
        model.copy_from_slice(&bytes[at + 4..at + 20]);
        let imu = ReplayImu {
            imu_id: bytes[at],
            model,
            sample_rate_hz: f32::from_bits(le_u32(bytes, at + 20)),
            gyro_scale_rad_s_per_count: f64::from_bits(le_u64(bytes, at + 24)),
            accel_scale_m_s2_per_count: f64::from_bits(le_u64(bytes, at + 32)),
        };
        // Capacity is MAX_REPLAY_IMUS and count was checked against it above.
        imus.push(imu)
            .map_err(|_| ReplayError::BadImuCount(count))?;
    }
    validate_imus(&imus)?;
    Ok((ReplayHeader { imus }, len))
}

/// Writes one record to the start of `out`; returns the bytes written.
pub fn encode_record(record: &ReplayRecord, out: &mut [u8]) -> Result<usize, ReplayError> {
    let len = record.encoded_len();
    if out.len() < len {
        return Err(ReplayError::BufferTooSmall { needed: len });
    }
    match record {
        ReplayRecord::Imu {
            t_us,
            imu_id,
            gyro_counts,
            accel_counts,
        } => {
            out[0] = TAG_IMU;
            put(out, 1, &t_us.to_le_bytes());
            out[9] = *imu_id;
            put_i32x3(out, 10, gyro_counts);
            put_i32x3(out, 22, accel_counts);
        }
        ReplayRecord::Pps { t_us } => {
            out[0] = TAG_PPS;
            put(out, 1, &t_us.to_le_bytes());
        }
        ReplayRecord::Gnss { t_us, len, data } => {
            let n = usize::from(*len);
            if n == 0 || n > GNSS_CHUNK_MAX {
                return Err(ReplayError::BadGnssLength(*len));
            }
            out[0] = TAG_GNSS;
            put(out, 1, &t_us.to_le_bytes());
            out[9] = *len;
            put(out, GNSS_RECORD_HEAD_LEN, &data[..n]);
        }
        ReplayRecord::End {
            imu_sample_sets,
            pps_edges,
        } => {
            out[0] = TAG_END;
            put(out, 1, &imu_sample_sets.to_le_bytes());
            put(out, 9, &pps_edges.to_le_bytes());
        }
    }
    Ok(len)
}

/// Reads the record at the start of `bytes`; returns it and the bytes it occupied.
/// `Incomplete` means `bytes` ends inside the record (or is empty).
pub fn decode_record(bytes: &[u8]) -> Result<(ReplayRecord, usize), ReplayError> {
    let Some(&tag) = bytes.first() else {
        return Err(ReplayError::Incomplete { needed: 1 });
    };
    let len = match tag {
        TAG_IMU => IMU_RECORD_LEN,
        TAG_PPS => PPS_RECORD_LEN,
        TAG_END => END_RECORD_LEN,
        TAG_GNSS => {
            let Some(&n) = bytes.get(GNSS_RECORD_HEAD_LEN - 1) else {
                return Err(ReplayError::Incomplete {
                    needed: GNSS_RECORD_HEAD_LEN,
                });
            };
            if n == 0 || usize::from(n) > GNSS_CHUNK_MAX {
                return Err(ReplayError::BadGnssLength(n));
            }
            GNSS_RECORD_HEAD_LEN + usize::from(n)
        }
        other => return Err(ReplayError::UnknownTag(other)),
    };
    if bytes.len() < len {
        return Err(ReplayError::Incomplete { needed: len });
    }
    let record = match tag {
        TAG_IMU => ReplayRecord::Imu {
            t_us: le_u64(bytes, 1),
            imu_id: bytes[9],
            gyro_counts: le_i32x3(bytes, 10),
            accel_counts: le_i32x3(bytes, 22),
        },
        TAG_PPS => ReplayRecord::Pps {
            t_us: le_u64(bytes, 1),
        },
        TAG_GNSS => ReplayRecord::gnss(le_u64(bytes, 1), &bytes[GNSS_RECORD_HEAD_LEN..len])?,
        _ => ReplayRecord::End {
            imu_sample_sets: le_u64(bytes, 1),
            pps_edges: le_u64(bytes, 9),
        },
    };
    Ok((record, len))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn imu(id: u8) -> ReplayImu {
        ReplayImu {
            imu_id: id,
            model: ReplayImu::model_field("ADIS16405").unwrap(),
            sample_rate_hz: 100.0,
            gyro_scale_rad_s_per_count: 0.05 * core::f64::consts::PI / 180.0,
            accel_scale_m_s2_per_count: 0.00333 * 9.80665,
        }
    }

    #[test]
    fn header_round_trips_bit_exact_and_rejects_bad_fields() {
        let mut header = ReplayHeader { imus: Vec::new() };
        header.imus.push(imu(0)).unwrap();
        header.imus.push(imu(2)).unwrap();
        let mut buf = [0u8; MAX_HEADER_LEN];
        let n = encode_header(&header, &mut buf).unwrap();
        assert_eq!(n, HEADER_FIXED_LEN + 2 * IMU_CONFIG_LEN);
        let (back, used) = decode_header(&buf[..n]).unwrap();
        assert_eq!(used, n);
        assert_eq!(back, header);
        assert_eq!(back.imus[1].model_str(), "ADIS16405");
        assert_eq!(
            back.imus[0].gyro_scale_rad_s_per_count.to_bits(),
            header.imus[0].gyro_scale_rad_s_per_count.to_bits()
        );
        // Every shorter prefix asks for more bytes instead of misreading.
        for cut in 0..n {
            assert!(matches!(
                decode_header(&buf[..cut]),
                Err(ReplayError::Incomplete { .. })
            ));
        }
        let mut bad = buf;
        bad[0] = b'X';
        assert_eq!(decode_header(&bad[..n]), Err(ReplayError::BadMagic));
        let mut bad = buf;
        bad[8] = 9;
        assert_eq!(
            decode_header(&bad[..n]),
            Err(ReplayError::UnsupportedVersion(9))
        );
        let mut bad = buf;
        bad[HEADER_FIXED_LEN + IMU_CONFIG_LEN] = 0; // second IMU reuses id 0
        assert_eq!(
            decode_header(&bad[..n]),
            Err(ReplayError::DuplicateImuId(0))
        );
        let mut zero_scale = header.clone();
        zero_scale.imus[0].accel_scale_m_s2_per_count = 0.0;
        assert_eq!(
            encode_header(&zero_scale, &mut buf),
            Err(ReplayError::BadImuConfig(0))
        );
    }

    #[test]
    fn records_round_trip_and_truncation_is_detected() {
        let records = [
            ReplayRecord::Pps { t_us: 1_000_000 },
            ReplayRecord::Imu {
                t_us: 1_000_000,
                imu_id: 2,
                gyro_counts: [i32::MIN, -1, i32::MAX],
                accel_counts: [0, 305, -305],
            },
            ReplayRecord::End {
                imu_sample_sets: 1,
                pps_edges: 1,
            },
        ];
        let mut stream = [0u8; 64];
        let mut at = 0;
        for r in &records {
            at += encode_record(r, &mut stream[at..]).unwrap();
        }
        assert_eq!(at, PPS_RECORD_LEN + IMU_RECORD_LEN + END_RECORD_LEN);
        let mut read = 0;
        for r in &records {
            let (back, used) = decode_record(&stream[read..at]).unwrap();
            assert_eq!(back, *r);
            for cut in read..read + used {
                assert!(matches!(
                    decode_record(&stream[read..cut]),
                    Err(ReplayError::Incomplete { .. })
                ));
            }
            read += used;
        }
        assert_eq!(decode_record(&[0x42]), Err(ReplayError::UnknownTag(0x42)));
        assert_eq!(
            encode_record(&records[1], &mut [0u8; 10]),
            Err(ReplayError::BufferTooSmall {
                needed: IMU_RECORD_LEN
            })
        );
    }
}
