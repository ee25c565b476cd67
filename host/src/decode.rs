//! Decoding the board's log (`docs/log-format.md`) into per-IMU recordings and a summary.
//!
//! The whole log streams through [`dynacal_core::log::LogAccumulator`], which resynchronises
//! on the next 0x00 delimiter after corrupted or truncated bytes and recovers a frame that
//! follows garbage within one run, so every frame whose bytes arrived intact is decoded.
//! Decoding never fails on bad bytes: damage is counted, and [`DecodedLog::validate`] decides
//! whether what survived is usable.
//!
//! IMU samples are kept as raw counts, exactly as logged, and converted to SI with the
//! header's scale factors. Policy for samples that cannot be scaled: samples logged before
//! the first header, or for an IMU id the header does not list, are dropped and counted
//! (`imu_samples_before_header`, `imu_samples_unknown_imu`); samples whose time does not
//! increase on their IMU (a duplicated or reordered stretch) are dropped and counted per IMU
//! (`samples_out_of_order`), because recordings need strictly increasing time.
//!
//! WaveletVariance frames (the board's streaming wavelet-variance snapshots) are kept in log
//! order; [`DecodedLog::latest_wavelet_variance`] picks the newest per IMU and channel and
//! [`DecodedLog::wavelet_variance_si`] converts them with the header's scale factors. Frames
//! for an IMU the header does not list, or a channel outside 0..=5, are counted and dropped
//! like IMU samples (`wv_frames_unknown`).

use std::collections::BTreeMap;
use std::io::{self, Read};
use std::path::{Path, PathBuf};

use dynacal_core::log::{
    FaultFrame, FilterState, Frame, GnssFix, Header, Health, ImuConfig, ImuSampleSet,
    LogAccumulator, LogError, NoiseFrame, PpsEvent, StreamStats, WvFrame, PROTOCOL_VERSION,
};
use serde::{Deserialize, Serialize};

use crate::interchange::{FileFormat, ImuRecording};
use crate::wv::WaveletVariance;
use dynacal_core::Channel;

/// Seconds of a log time in microseconds: one correctly rounded division (exact below 2^53
/// us, 285 years), where `t_us as f64 * 1e-6` rounds twice (1e-6 has no exact double) and
/// turns 50 000 us into 0.049999999999999996 s.
pub fn seconds_of_us(t_us: u64) -> f64 {
    t_us as f64 / 1e6
}

/// One count in SI units: `counts as f64 * per_count`, one rounding, so the values are
/// reproducible bit for bit from the raw counts.
fn si(count: i32, per_count: f64) -> f64 {
    count as f64 * per_count
}

/// One sample in SI units as an interchange row (`t_s` by [`seconds_of_us`], then the gyro
/// in rad/s and the accelerometer in m/s^2 by the IMU's scale factors).
pub fn sample_si(config: &ImuConfig, sample: &ImuSampleSet) -> [f64; 7] {
    let g = config.gyro_scale_rad_s_per_count;
    let a = config.accel_scale_m_s2_per_count;
    let [gx, gy, gz] = sample.gyro_counts;
    let [ax, ay, az] = sample.accel_counts;
    [
        seconds_of_us(sample.t_us),
        si(gx, g),
        si(gy, g),
        si(gz, g),
        si(ax, a),
        si(ay, a),
        si(az, a),
    ]
}

/// Why a log cannot be read or used.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("{path}: no frame decoded from {bytes} bytes (not a dynacal log, or all corrupted)")]
    NoFrames { path: PathBuf, bytes: u64 },
    #[error("{path}: no header frame in the log, so IMU counts cannot be scaled")]
    NoHeader { path: PathBuf },
    #[error(
        "{path}: header declares protocol version {found}, this build reads version {supported}"
    )]
    UnsupportedVersion {
        path: PathBuf,
        found: u16,
        supported: u16,
    },
    #[error("{path}: header lists IMU id {imu_id} more than once")]
    DuplicateImu { path: PathBuf, imu_id: u8 },
    #[error(
        "{path}: header ending at byte {offset} differs from the first header; \
         one log must hold one configuration"
    )]
    HeaderChanged { path: PathBuf, offset: u64 },
}

/// One IMU's samples as logged (raw counts), with its configuration from the header.
/// Index `i` of every vector is the same sample; times strictly increase.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuStream {
    pub config: ImuConfig,
    /// Sample times, GPS time, microseconds.
    pub t_us: Vec<u64>,
    /// Gyro x, y, z, counts.
    pub gyro_counts: Vec<[i32; 3]>,
    /// Accelerometer x, y, z, counts.
    pub accel_counts: Vec<[i32; 3]>,
    /// Samples dropped because their time did not exceed the previous sample's.
    pub samples_out_of_order: u64,
    /// The samples kept, counted as they arrive: the same whether they are held above or
    /// written out as they come ([`decode_file_streamed`]).
    kept: KeptSamples,
}

/// How many samples an IMU stream kept, their first and last times and their gaps.
#[derive(Debug, Clone, PartialEq)]
struct KeptSamples {
    count: u64,
    first_t_us: Option<u64>,
    last_t_us: Option<u64>,
    gaps: GapStats,
}

impl ImuStream {
    fn new(config: ImuConfig) -> Self {
        let nominal_dt_us = 1e6 / f64::from(config.sample_rate_hz);
        Self {
            config,
            t_us: Vec::new(),
            gyro_counts: Vec::new(),
            accel_counts: Vec::new(),
            samples_out_of_order: 0,
            kept: KeptSamples {
                count: 0,
                first_t_us: None,
                last_t_us: None,
                gaps: GapStats {
                    nominal_dt_us: nominal_dt_us.is_finite().then_some(nominal_dt_us),
                    ..Default::default()
                },
            },
        }
    }

    /// Counts `t_us` as this stream's next sample; false (and counted out of order) when it
    /// does not come after the last one kept.
    fn keep(&mut self, t_us: u64) -> bool {
        let kept = &mut self.kept;
        if let Some(last) = kept.last_t_us {
            if t_us <= last {
                self.samples_out_of_order += 1;
                return false;
            }
            let dt_us = t_us - last;
            let gaps = &mut kept.gaps;
            gaps.max_dt_us = gaps.max_dt_us.max(dt_us);
            if let Some(nominal) = gaps.nominal_dt_us.filter(|n| *n > 0.0) {
                if dt_us as f64 > 1.5 * nominal {
                    gaps.gaps += 1;
                    gaps.samples_missing += ((dt_us as f64 / nominal).round() as u64).max(1) - 1;
                }
            }
        }
        kept.first_t_us.get_or_insert(t_us);
        kept.last_t_us = Some(t_us);
        kept.count += 1;
        true
    }

    /// Number of samples kept.
    pub fn len(&self) -> usize {
        self.kept.count as usize
    }

    /// True when no sample was kept.
    pub fn is_empty(&self) -> bool {
        self.kept.count == 0
    }

    /// Times of the first and last samples kept, microseconds.
    pub fn span_us(&self) -> Option<(u64, u64)> {
        self.kept.first_t_us.zip(self.kept.last_t_us)
    }

    /// The samples in SI units, each as [`sample_si`] converts it.
    pub fn to_recording(&self) -> ImuRecording {
        let scale = |counts: &[[i32; 3]], per_count: f64| -> [Vec<f64>; 3] {
            [0, 1, 2].map(|axis| counts.iter().map(|c| si(c[axis], per_count)).collect())
        };
        ImuRecording {
            t_s: self.t_us.iter().map(|&t| seconds_of_us(t)).collect(),
            gyro_rad_s: Some(scale(
                &self.gyro_counts,
                self.config.gyro_scale_rad_s_per_count,
            )),
            accel_m_s2: Some(scale(
                &self.accel_counts,
                self.config.accel_scale_m_s2_per_count,
            )),
            sample_rate_hz: Some(f64::from(self.config.sample_rate_hz)),
            ..Default::default()
        }
    }

    /// Gaps in the sample times against the configured rate.
    pub fn gaps(&self) -> GapStats {
        self.kept.gaps
    }
}

/// Timestamp gaps of one IMU stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct GapStats {
    /// Expected interval from the header's sample rate, microseconds (None if the rate is 0).
    pub nominal_dt_us: Option<f64>,
    /// Intervals longer than 1.5 nominal intervals.
    pub gaps: u64,
    /// Samples missing in those gaps (interval / nominal, rounded, minus one, summed).
    pub samples_missing: u64,
    /// Longest interval between consecutive samples, microseconds.
    pub max_dt_us: u64,
}

/// Everything decoded from one log.
#[derive(Debug, Clone, Default)]
pub struct DecodedLog {
    /// Byte and frame counts of the stream (after the end of the log).
    pub stream: StreamStats,
    /// Frames decoded per kind (`Frame::kind_name`).
    pub frames_by_kind: BTreeMap<&'static str, u64>,
    /// Dropped runs per error kind (`crc_mismatch`, `cobs`, `truncated`, ...).
    pub dropped_by_error: BTreeMap<&'static str, u64>,
    /// The first header, which defines the IMUs.
    pub header: Option<Header>,
    /// Header frames seen (boards may repeat the header).
    pub headers_seen: u64,
    /// Stream offsets (end of frame, bytes) of headers that differ from the first.
    pub conflicting_header_offsets: Vec<u64>,
    /// One stream per IMU in the header, in header order.
    pub imus: Vec<ImuStream>,
    /// IMU samples logged before the first header (dropped).
    pub imu_samples_before_header: u64,
    /// IMU samples whose id the header does not list (dropped).
    pub imu_samples_unknown_imu: u64,
    pub pps: Vec<PpsEvent>,
    pub gnss: Vec<GnssFix>,
    pub filter: Vec<FilterState>,
    pub health: Vec<Health>,
    /// The fusion's noise reports and fault events, in log order.
    pub noise: Vec<NoiseFrame>,
    pub faults: Vec<FaultFrame>,
    /// WaveletVariance frames of IMUs and channels the header lists, in log order.
    pub wavelet_variance: Vec<WvFrame>,
    /// WaveletVariance frames before the first header, for an IMU id the header does not
    /// list, or with a channel outside 0..=5 (dropped).
    pub wv_frames_unknown: u64,
    /// When the samples are written out as they come ([`decode_file_streamed`]): those
    /// kept since the writer last took them (IMU index in header order, sample), instead
    /// of the streams holding them.
    passing: Option<Vec<(usize, ImuSampleSet)>>,
}

/// The newest wavelet-variance snapshot of one IMU channel, in SI units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoardChannelWv {
    pub imu_id: u8,
    pub channel: Channel,
    /// Time of the last sample in the snapshot, microseconds.
    pub t_us: u64,
    /// Samples accumulated.
    pub n_samples: u64,
    /// Number of full (overlapping) levels; the following ones are decimated.
    pub full_levels: u8,
    /// The wavelet variance in (rad/s)^2 or (m/s^2)^2; None when the snapshot cannot be
    /// used (see `error`).
    pub wv: Option<WaveletVariance>,
    /// Why the snapshot cannot be used (a saturated level, levels out of order, a bad rate).
    pub error: Option<String>,
}

/// A short snake_case name of an error, as counted in [`DecodedLog::dropped_by_error`].
pub fn error_kind_name(error: &LogError) -> &'static str {
    match error {
        LogError::BufferTooSmall => "buffer_too_small",
        LogError::Serialize => "serialize",
        LogError::EmptyFrame => "empty_frame",
        LogError::Cobs => "cobs",
        LogError::TooShort { .. } => "too_short",
        LogError::CrcMismatch { .. } => "crc_mismatch",
        LogError::UnknownKind { .. } => "unknown_kind",
        LogError::Malformed => "malformed",
        LogError::TrailingBytes { .. } => "trailing_bytes",
        LogError::FrameTooLong => "frame_too_long",
        LogError::Truncated { .. } => "truncated",
        _ => "other",
    }
}

/// Builds a [`DecodedLog`] from bytes fed in any chunking.
pub struct LogDecoder {
    accumulator: Box<LogAccumulator>,
    log: DecodedLog,
}

impl Default for LogDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl LogDecoder {
    pub fn new() -> Self {
        Self {
            accumulator: Box::new(LogAccumulator::new()),
            log: DecodedLog::default(),
        }
    }

    /// Decodes the frames completed by `bytes`.
    pub fn feed(&mut self, mut bytes: &[u8]) {
        while let Some(item) = self.accumulator.next_frame(&mut bytes) {
            let offset = self.accumulator.stats().bytes_seen;
            match item {
                Ok(frame) => self.log.add(frame, offset),
                Err(error) => self.log.count_error(&error),
            }
        }
    }

    /// Ends the log (an unfinished last frame counts as truncated) and returns the result.
    pub fn finish(mut self) -> DecodedLog {
        // A recovered frame may still be waiting behind the last error.
        self.feed(&[]);
        if let Some(error) = self.accumulator.finish() {
            self.log.count_error(&error);
        }
        self.log.stream = self.accumulator.stats();
        self.log
    }
}

impl DecodedLog {
    /// Seconds of data the log spans: the longest of its IMUs' first-to-last sample times.
    pub fn span_s(&self) -> f64 {
        self.imus
            .iter()
            .filter_map(ImuStream::span_us)
            .map(|(first, last)| (last - first) as f64 * 1e-6)
            .fold(0.0, f64::max)
    }

    /// Time of the earliest IMU sample, s (GPS seconds as the log gives them).
    pub fn first_sample_s(&self) -> Option<f64> {
        self.imus
            .iter()
            .filter_map(|imu| imu.span_us().map(|(first, _)| first))
            .min()
            .map(seconds_of_us)
    }

    fn count_error(&mut self, error: &LogError) {
        *self
            .dropped_by_error
            .entry(error_kind_name(error))
            .or_default() += 1;
    }

    fn add(&mut self, frame: Frame, offset: u64) {
        *self.frames_by_kind.entry(frame.kind_name()).or_default() += 1;
        match frame {
            Frame::Header(header) => {
                self.headers_seen += 1;
                match &self.header {
                    None => {
                        self.imus = header.imus.iter().cloned().map(ImuStream::new).collect();
                        self.header = Some(header);
                    }
                    Some(first) if *first != header => self.conflicting_header_offsets.push(offset),
                    Some(_) => {}
                }
            }
            Frame::Imu(sample) => {
                if self.header.is_none() {
                    self.imu_samples_before_header += 1;
                    return;
                }
                let Some(index) = self
                    .imus
                    .iter()
                    .position(|s| s.config.imu_id == sample.imu_id)
                else {
                    self.imu_samples_unknown_imu += 1;
                    return;
                };
                let imu = &mut self.imus[index];
                if !imu.keep(sample.t_us) {
                    return;
                }
                if let Some(passing) = &mut self.passing {
                    passing.push((index, sample));
                } else {
                    imu.t_us.push(sample.t_us);
                    imu.gyro_counts.push(sample.gyro_counts);
                    imu.accel_counts.push(sample.accel_counts);
                }
            }
            Frame::Pps(pps) => self.pps.push(pps),
            Frame::Gnss(fix) => self.gnss.push(fix),
            Frame::Filter(state) => self.filter.push(state),
            Frame::Health(health) => self.health.push(health),
            Frame::Noise(noise) => self.noise.push(noise),
            Frame::Fault(fault) => self.faults.push(fault),
            Frame::WaveletVariance(wv) => {
                let known = self.header.is_some()
                    && wv.channel().is_some()
                    && self.imus.iter().any(|s| s.config.imu_id == wv.imu_id);
                if known {
                    self.wavelet_variance.push(wv);
                } else {
                    self.wv_frames_unknown += 1;
                }
            }
            // Kinds appended to the protocol after this decoder was written are counted
            // above and otherwise kept by nobody yet.
            #[allow(unreachable_patterns)]
            _ => {}
        }
    }

    /// The last WaveletVariance frame of each (IMU id, channel).
    pub fn latest_wavelet_variance(&self) -> BTreeMap<(u8, u8), &WvFrame> {
        let mut latest = BTreeMap::new();
        for frame in &self.wavelet_variance {
            latest.insert((frame.imu_id, frame.channel), frame);
        }
        latest
    }

    /// The latest snapshot of each IMU channel in SI units, IMUs in header order and channels
    /// in `gx gy gz ax ay az` order: variance scaled by the header's gyro or accelerometer
    /// scale factor squared, scales from the IMU's configured sample rate.
    pub fn wavelet_variance_si(&self) -> Vec<BoardChannelWv> {
        let latest = self.latest_wavelet_variance();
        let mut out = Vec::new();
        for imu in &self.imus {
            let config = &imu.config;
            for channel in Channel::ALL {
                let Some(frame) = latest.get(&(config.imu_id, channel.index() as u8)) else {
                    continue;
                };
                let lsb = if channel.is_gyro() {
                    config.gyro_scale_rad_s_per_count
                } else {
                    config.accel_scale_m_s2_per_count
                };
                let dt_s = 1.0 / f64::from(config.sample_rate_hz);
                let (wv, error) =
                    match WaveletVariance::from_stream_snapshot(&frame.snapshot, lsb, dt_s) {
                        Ok(wv) => (Some(wv), None),
                        Err(e) => (None, Some(e.to_string())),
                    };
                out.push(BoardChannelWv {
                    imu_id: config.imu_id,
                    channel,
                    t_us: frame.t_us,
                    n_samples: frame.snapshot.n_samples,
                    full_levels: frame.snapshot.full_levels,
                    wv,
                    error,
                });
            }
        }
        out
    }

    /// Frames decoded, all kinds.
    pub fn frames_decoded(&self) -> u64 {
        self.stream.frames_decoded
    }

    /// Checks that the log can be used: it has frames and one supported header whose IMU
    /// ids are unique. `path` names the log in errors.
    pub fn validate(&self, path: &Path) -> Result<(), DecodeError> {
        let path = path.to_path_buf();
        if self.stream.frames_decoded == 0 {
            return Err(DecodeError::NoFrames {
                path,
                bytes: self.stream.bytes_seen,
            });
        }
        let Some(header) = &self.header else {
            return Err(DecodeError::NoHeader { path });
        };
        if header.protocol_version != PROTOCOL_VERSION {
            return Err(DecodeError::UnsupportedVersion {
                path,
                found: header.protocol_version,
                supported: PROTOCOL_VERSION,
            });
        }
        for (i, imu) in header.imus.iter().enumerate() {
            if header.imus[..i].iter().any(|o| o.imu_id == imu.imu_id) {
                return Err(DecodeError::DuplicateImu {
                    path,
                    imu_id: imu.imu_id,
                });
            }
        }
        if let Some(&offset) = self.conflicting_header_offsets.first() {
            return Err(DecodeError::HeaderChanged { path, offset });
        }
        Ok(())
    }

    /// What the log held, for `summary.json`; its IMUs' files written in `format`.
    pub fn summary(&self, format: FileFormat) -> LogSummary {
        LogSummary {
            bytes_total: self.stream.bytes_seen,
            bytes_decoded: self.stream.bytes_decoded,
            bytes_dropped: self.stream.bytes_dropped,
            frames_decoded_total: self.stream.frames_decoded,
            frames_decoded: self
                .frames_by_kind
                .iter()
                .map(|(k, v)| ((*k).to_string(), *v))
                .collect(),
            frames_dropped: self.stream.frames_dropped,
            frames_dropped_by_error: self
                .dropped_by_error
                .iter()
                .map(|(k, v)| ((*k).to_string(), *v))
                .collect(),
            header_found: self.header.is_some(),
            protocol_version: self.header.as_ref().map(|h| h.protocol_version),
            header: self.header.clone(),
            headers_seen: self.headers_seen,
            imu_samples_before_header: self.imu_samples_before_header,
            imu_samples_unknown_imu: self.imu_samples_unknown_imu,
            imus: self
                .imus
                .iter()
                .map(|imu| ImuSummary {
                    imu_id: imu.config.imu_id,
                    model: imu.config.model.to_string(),
                    samples: imu.len() as u64,
                    samples_out_of_order: imu.samples_out_of_order,
                    first_t_us: imu.span_us().map(|(first, _)| first),
                    last_t_us: imu.span_us().map(|(_, last)| last),
                    gaps: imu.gaps(),
                    file: (!imu.is_empty()).then(|| imu_file_name(imu.config.imu_id, format)),
                })
                .collect(),
            pps_events: self.pps.len() as u64,
            gnss_fixes: self.gnss.len() as u64,
            filter_states: self.filter.len() as u64,
            noise_reports: self.noise.len() as u64,
            fault_events: self.faults.len() as u64,
            health_reports: self.health.len() as u64,
            wavelet_variance_frames: self.wavelet_variance.len() as u64,
            wv_frames_unknown: self.wv_frames_unknown,
        }
    }
}

/// File name of one IMU's interchange file in a decode output folder.
pub fn imu_file_name(imu_id: u8, format: FileFormat) -> String {
    format!("imu{imu_id}.{}", format.extension())
}

/// The decoder's report (`summary.json`).
#[derive(Debug, Clone, Serialize)]
pub struct LogSummary {
    pub bytes_total: u64,
    pub bytes_decoded: u64,
    /// Bytes outside any decoded frame (corruption, garbage, a truncated tail).
    pub bytes_dropped: u64,
    pub frames_decoded_total: u64,
    /// Frames decoded per kind.
    pub frames_decoded: BTreeMap<String, u64>,
    /// Byte runs that held no valid frame (see `StreamStats::frames_dropped`).
    pub frames_dropped: u64,
    pub frames_dropped_by_error: BTreeMap<String, u64>,
    pub header_found: bool,
    pub protocol_version: Option<u16>,
    pub header: Option<Header>,
    pub headers_seen: u64,
    pub imu_samples_before_header: u64,
    pub imu_samples_unknown_imu: u64,
    pub imus: Vec<ImuSummary>,
    pub pps_events: u64,
    pub gnss_fixes: u64,
    pub filter_states: u64,
    pub noise_reports: u64,
    pub fault_events: u64,
    pub health_reports: u64,
    /// WaveletVariance frames kept (the latest per IMU channel goes to `wv.json`).
    pub wavelet_variance_frames: u64,
    /// WaveletVariance frames dropped (no header yet, unknown IMU id or channel).
    pub wv_frames_unknown: u64,
}

/// Per-IMU part of [`LogSummary`].
#[derive(Debug, Clone, Serialize)]
pub struct ImuSummary {
    pub imu_id: u8,
    pub model: String,
    /// Samples kept (written to `file`).
    pub samples: u64,
    pub samples_out_of_order: u64,
    pub first_t_us: Option<u64>,
    pub last_t_us: Option<u64>,
    pub gaps: GapStats,
    /// The interchange CSV written for this IMU (None when it has no samples).
    pub file: Option<String>,
}

/// Decodes a log held in memory.
pub fn decode_bytes(bytes: &[u8]) -> DecodedLog {
    let mut decoder = LogDecoder::new();
    decoder.feed(bytes);
    decoder.finish()
}

/// Decodes a log from a reader, 64 KiB at a time.
pub fn decode_reader(mut reader: impl Read) -> io::Result<DecodedLog> {
    let mut decoder = LogDecoder::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match reader.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => decoder.feed(&buf[..n]),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(decoder.finish())
}

/// Decodes the log file at `path` handing each IMU sample kept to `sample` as it comes
/// (with its IMU's configuration, which the header gave), so that a log of any length is
/// decoded in memory that does not grow with its samples: the returned log's streams count
/// their samples but hold none. What else the log holds (fixes, filter states, reports) is
/// kept as [`decode_file`] keeps it.
pub fn decode_file_streamed<E: From<DecodeError>>(
    path: &Path,
    mut sample: impl FnMut(&ImuConfig, &ImuSampleSet) -> Result<(), E>,
) -> Result<DecodedLog, E> {
    let io = |source| DecodeError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let size_bytes = file.metadata().map_err(io)?.len();
    let mut reader = crate::progress::Counted::new(file, path, size_bytes);
    let mut decoder = LogDecoder::new();
    decoder.log.passing = Some(Vec::new());
    let mut buf = vec![0u8; 1 << 16];
    let mut pass_on = |decoder: &mut LogDecoder| -> Result<(), E> {
        let passing = decoder.log.passing.as_mut().expect("set above");
        for (index, s) in passing.drain(..) {
            sample(&decoder.log.imus[index].config, &s)?;
        }
        Ok(())
    };
    loop {
        match reader.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => decoder.feed(&buf[..n]),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(io(e).into()),
        }
        pass_on(&mut decoder)?;
    }
    decoder.feed(&[]);
    pass_on(&mut decoder)?;
    let mut log = decoder.finish();
    log.passing = None;
    Ok(log)
}

/// Decodes the log file at `path`.
pub fn decode_file(path: &Path) -> Result<DecodedLog, DecodeError> {
    let io = |source| DecodeError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let size_bytes = file.metadata().map_err(io)?.len();
    decode_reader(crate::progress::Counted::new(file, path, size_bytes)).map_err(io)
}

/// Encodes frames into a log (the board's byte stream), e.g. for tests and simulation.
pub fn encode_log(frames: &[Frame]) -> Result<Vec<u8>, LogError> {
    let mut out = Vec::with_capacity(frames.len() * 40);
    let mut buf = [0u8; dynacal_core::log::MAX_FRAME_LEN];
    for frame in frames {
        let n = dynacal_core::log::encode_frame(frame, &mut buf)?;
        out.extend_from_slice(&buf[..n]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynacal_core::log::ImuSampleSet;

    fn header(imu_ids: &[u8]) -> Header {
        Header {
            protocol_version: PROTOCOL_VERSION,
            board: "test".try_into().unwrap(),
            imus: imu_ids
                .iter()
                .map(|&imu_id| ImuConfig {
                    imu_id,
                    model: "BMI088".try_into().unwrap(),
                    sample_rate_hz: 100.0,
                    gyro_scale_rad_s_per_count: 1.0 / 3.0e4,
                    accel_scale_m_s2_per_count: 9.80665 / 1365.0,
                })
                .collect(),
        }
    }

    fn imu(imu_id: u8, t_us: u64, c: i32) -> Frame {
        Frame::Imu(ImuSampleSet {
            t_us,
            imu_id,
            gyro_counts: [c, -c, 7],
            accel_counts: [-c, c, i32::MIN],
        })
    }

    /// Streamed, a log passes on the samples a held decode keeps, in order, each with its
    /// IMU's configuration, and says of them what the held decode says; its streams hold none.
    #[test]
    fn a_streamed_decode_passes_on_what_a_held_one_keeps() {
        let mut frames = vec![imu(0, 5, 1), Frame::Header(header(&[0, 2]))];
        for k in 1..3_000u64 {
            frames.push(imu(0, k * 10_000, k as i32));
            if k % 7 != 0 {
                frames.push(imu(2, k * 10_000 + 3, -(k as i32)));
            }
            if k % 500 == 0 {
                frames.push(imu(0, k * 10_000, 0));
                frames.push(imu(1, k * 10_000, 0));
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.log");
        std::fs::write(&path, encode_log(&frames).unwrap()).unwrap();
        let held = decode_file(&path).unwrap();
        let mut passed: Vec<[f64; 7]> = Vec::new();
        let mut ids = Vec::new();
        let streamed = decode_file_streamed(&path, |config, sample| -> Result<(), DecodeError> {
            ids.push(config.imu_id);
            passed.push(sample_si(config, sample));
            Ok(())
        })
        .unwrap();
        let json = |log: &DecodedLog| serde_json::to_string(&log.summary(FileFormat::Csv)).unwrap();
        assert_eq!(json(&streamed), json(&held));
        assert!(streamed.imus.iter().all(|imu| imu.t_us.is_empty()));
        for (k, imu) in held.imus.iter().enumerate() {
            let id = imu.config.imu_id;
            let mine: Vec<[f64; 7]> = ids
                .iter()
                .zip(&passed)
                .filter(|(i, _)| **i == id)
                .map(|(_, s)| *s)
                .collect();
            let recording = imu.to_recording();
            assert_eq!(mine.len(), recording.len(), "imu {k}");
            for (i, row) in mine.iter().enumerate() {
                assert_eq!(row[0], recording.t_s[i]);
                assert_eq!(row[1], recording.gyro_rad_s.as_ref().unwrap()[0][i]);
                assert_eq!(row[6], recording.accel_m_s2.as_ref().unwrap()[2][i]);
            }
        }
        assert_eq!(held.imus[0].samples_out_of_order, 5);
        assert_eq!(held.imu_samples_unknown_imu, 5);
    }

    #[test]
    fn counts_convert_bit_exactly_and_policy_drops_are_counted() {
        let frames = vec![
            imu(0, 5, 1),
            Frame::Header(header(&[0, 2])),
            imu(0, 10_000, 3),
            imu(2, 10_000, 4),
            imu(1, 10_000, 5),
            imu(0, 20_000, -6),
            imu(0, 20_000, 99),
            imu(0, 50_000, 8),
            Frame::Header(header(&[0, 2])),
        ];
        let log = decode_bytes(&encode_log(&frames).unwrap());
        log.validate(Path::new("x.log")).unwrap();
        assert_eq!(log.imu_samples_before_header, 1);
        assert_eq!(log.imu_samples_unknown_imu, 1);
        assert_eq!(log.headers_seen, 2);
        assert_eq!(log.frames_by_kind["imu"], 7);
        let imu0 = &log.imus[0];
        assert_eq!(imu0.t_us, vec![10_000, 20_000, 50_000]);
        assert_eq!(imu0.samples_out_of_order, 1);
        assert_eq!(imu0.gyro_counts[1], [-6, 6, 7]);
        let rec = imu0.to_recording();
        let g = &rec.gyro_rad_s.as_ref().unwrap();
        let a = &rec.accel_m_s2.as_ref().unwrap();
        // One rounding: 50 000 us is the double nearest 0.05 s (times 1e-6, it is not).
        assert_eq!(rec.t_s[2].to_bits(), 0.05f64.to_bits());
        assert_ne!((50_000.0f64 * 1e-6).to_bits(), 0.05f64.to_bits());
        assert_eq!(g[0][1].to_bits(), (-6.0f64 * (1.0 / 3.0e4)).to_bits());
        assert_eq!(a[2][0], i32::MIN as f64 * (9.80665 / 1365.0));
        let gaps = imu0.gaps();
        assert_eq!(gaps.nominal_dt_us, Some(10_000.0));
        assert_eq!(gaps.gaps, 1);
        assert_eq!(gaps.samples_missing, 2);
        assert_eq!(gaps.max_dt_us, 30_000);
        assert_eq!(log.imus[1].len(), 1);
    }

    #[test]
    fn validate_names_the_file_and_the_problem() {
        let path = Path::new("flight.log");
        let empty = decode_bytes(&[0x13, 0x37]);
        let err = empty.validate(path).unwrap_err().to_string();
        assert!(
            err.contains("flight.log") && err.contains("no frame"),
            "{err}"
        );

        let no_header = decode_bytes(&encode_log(&[imu(0, 1, 1)]).unwrap());
        let err = no_header.validate(path).unwrap_err().to_string();
        assert!(err.contains("no header"), "{err}");

        let mut newer = header(&[0]);
        newer.protocol_version = PROTOCOL_VERSION + 1;
        let log = decode_bytes(&encode_log(&[Frame::Header(newer)]).unwrap());
        assert!(matches!(
            log.validate(path),
            Err(DecodeError::UnsupportedVersion { .. })
        ));

        let log = decode_bytes(&encode_log(&[Frame::Header(header(&[1, 1]))]).unwrap());
        assert!(matches!(
            log.validate(path),
            Err(DecodeError::DuplicateImu { imu_id: 1, .. })
        ));

        let frames = [Frame::Header(header(&[0])), Frame::Header(header(&[0, 1]))];
        let bytes = encode_log(&frames).unwrap();
        let log = decode_bytes(&bytes);
        match log.validate(path) {
            Err(DecodeError::HeaderChanged { offset, .. }) => {
                assert_eq!(offset, bytes.len() as u64)
            }
            other => panic!("{other:?}"),
        }
    }
}
