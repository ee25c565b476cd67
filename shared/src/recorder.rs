//! The board application: turns a stream of timestamped raw IMU sample sets, PPS edges and
//! GNSS receiver bytes into the log (`crate::log`), with periodic health reports. The
//! receiver's bytes go through [`crate::gnss::UbxReceiver`], and each solution it finds is
//! logged as a `Gnss` frame at its own (GPS) time of validity.
//!
//! It knows no hardware. A board supplies a [`SampleSource`] (SPI IMUs and timer captures on
//! the STM32F405, a recording read through semihosting under QEMU), a [`LogSink`] (UART, SD
//! card, a host file) and a [`TickClock`] for measuring its own cost; the same code then runs
//! on every board and on the host in tests. It writes one `Header` frame, then every event
//! as it arrives (an `Imu` or `Pps` frame), a `Health` frame each time log time crosses a
//! whole [`Recorder::health_period_us`] after the first event, and a last `Health` frame when
//! the source ends.
//!
//! With exactly three IMUs and a board model ([`Recorder::with_fusion`]) it also runs the
//! on-board fusion ([`crate::fusion`]): each sample set of the three units and each GNSS
//! solution go to it, and what it reports is logged as `Filter`, `Noise` and `Fault` frames.
//!
//! Each IMU's six channels (gyro x y z, accelerometer x y z, raw counts) also feed a streaming
//! Haar wavelet-variance accumulator ([`RecorderWv`]); their snapshots go out as one
//! `WaveletVariance` frame per declared IMU and channel each time log time crosses a whole
//! [`Recorder::wv_period_us`] after the first event, and once more when the source ends.

use crate::board_model::BoardModel;
use crate::clock::{ClockConfig, TimeTagger};
use crate::fusion::sets::SetAssembler;
use crate::fusion::{BoardFusion, FusionConfig, FusionOutput, UnitReading, UNITS};
use crate::gnss::{UbxReceiver, LEAP_SECONDS_2017};
use crate::log::GnssFix;
use crate::log::{
    encode_frame, Frame, Header, Health, ImuConfig, ImuSampleSet, LogError, PpsEvent, WvFrame,
    MAX_FRAME_LEN, MAX_IMUS,
};
use crate::replay::GNSS_CHUNK_MAX;
use crate::wavelet::HaarStream;

/// The recorder's wavelet-variance accumulator of one channel: 4 full (overlapping) levels
/// from a 16-sample ring, then 16 decimated levels, i.e. levels 1..=20 (up to 2^20 samples,
/// 87 min at 200 Hz). Depths are small because the board keeps 3 IMUs x 6 channels of them:
/// about 1.2 KiB each, 21 KiB in all, and the cost per sample grows with the full levels.
pub type RecorderWv = HaarStream<4, 16, 16>;

/// Channels accumulated per IMU, in [`crate::Channel::ALL`] order.
const WV_CHANNELS: usize = 6;

/// Bytes from the GNSS receiver's UART, as they arrived: `data[..len]`, the last at `t_us`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GnssChunk {
    pub t_us: u64,
    pub len: u8,
    pub data: [u8; GNSS_CHUNK_MAX],
}

impl GnssChunk {
    /// The bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..usize::from(self.len).min(GNSS_CHUNK_MAX)]
    }
}

/// One event from the sensors, stamped on the log timescale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SourceEvent {
    Imu(ImuSampleSet),
    Pps(PpsEvent),
    Gnss(GnssChunk),
}

impl SourceEvent {
    /// The event's time, microseconds on the log timescale.
    pub fn t_us(&self) -> u64 {
        match self {
            SourceEvent::Imu(s) => s.t_us,
            SourceEvent::Pps(p) => p.t_us,
            SourceEvent::Gnss(g) => g.t_us,
        }
    }
}

/// Where sample sets and PPS edges come from.
pub trait SampleSource {
    type Error;
    /// The next event in time order; blocks until one is ready. `Ok(None)` when the source
    /// has ended (a recording's last record; a live board never ends).
    fn next_event(&mut self) -> Result<Option<SourceEvent>, Self::Error>;
    /// Sample sets lost to FIFO or driver overrun since start.
    fn samples_overrun(&self) -> u32 {
        0
    }
    /// Whether any IMU read failed since the previous call (asked once per health report).
    fn imu_fault(&mut self) -> bool {
        false
    }
    /// Die temperature of each IMU in header order, degrees Celsius; NaN when not measured.
    fn imu_temperatures_deg_c(&mut self) -> [f32; MAX_IMUS] {
        [f32::NAN; MAX_IMUS]
    }
}

/// A source borrowed (a board that keeps its source in a static hands the recorder this).
impl<S: SampleSource + ?Sized> SampleSource for &mut S {
    type Error = S::Error;
    fn next_event(&mut self) -> Result<Option<SourceEvent>, Self::Error> {
        (**self).next_event()
    }
    fn samples_overrun(&self) -> u32 {
        (**self).samples_overrun()
    }
    fn imu_fault(&mut self) -> bool {
        (**self).imu_fault()
    }
    fn imu_temperatures_deg_c(&mut self) -> [f32; MAX_IMUS] {
        (**self).imu_temperatures_deg_c()
    }
}

/// What a sink did with one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accepted {
    /// The whole frame is queued or written.
    Written,
    /// No room: the frame was discarded whole (never cut), and is counted as dropped.
    Dropped,
}

/// Where the log's bytes go.
pub trait LogSink {
    type Error;
    /// Takes one complete wire frame.
    fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, Self::Error>;
    /// Pushes out everything taken so far.
    fn flush(&mut self) -> Result<(), Self::Error>;
}

/// A sink borrowed (see the [`SampleSource`] impl for `&mut S`).
impl<K: LogSink + ?Sized> LogSink for &mut K {
    type Error = K::Error;
    fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, Self::Error> {
        (**self).write_frame(frame)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        (**self).flush()
    }
}

/// A free-running tick counter used to measure the recorder's own cost.
pub trait TickClock {
    /// Ticks since an arbitrary origin; never decreases.
    fn now_ticks(&mut self) -> u64;
}

/// What a run did and what it cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecorderStats {
    /// IMU sample sets received, per IMU in header order.
    pub imu_sample_sets: [u64; MAX_IMUS],
    /// PPS edges received.
    pub pps_edges: u64,
    /// GNSS solutions found in the receiver's bytes and logged.
    pub gnss_fixes: u64,
    /// Receiver frames refused (bad checksum, bad length, malformed): corrupted bytes.
    pub gnss_frames_refused: u32,
    /// Health frames produced (written or dropped).
    pub health_reports: u64,
    /// WaveletVariance frames produced (written or dropped).
    pub wv_frames: u64,
    /// Filter, Noise and Fault frames of the fusion produced (written or dropped).
    pub filter_states: u64,
    pub noise_reports: u64,
    pub fault_reports: u64,
    /// Ticks spent in the fusion (part of `record_ticks`).
    pub fusion_ticks: u64,
    /// Of those, ticks while its filter was running, and the sample sets fused meanwhile:
    /// the fusion's cost in its steady state.
    pub navigating_fusion_ticks: u64,
    pub navigating_sample_sets: u64,
    /// Frames the sink took.
    pub frames_written: u64,
    /// Bytes of the frames the sink took.
    pub bytes_written: u64,
    /// Frames the sink had no room for.
    pub frames_dropped: u32,
    /// Ticks spent waiting for and fetching events from the source.
    pub source_ticks: u64,
    /// Ticks spent framing events and handing them to the sink (the application's own work).
    pub record_ticks: u64,
    /// Ticks from the header to the final flush.
    pub total_ticks: u64,
}

impl RecorderStats {
    /// Nothing yet.
    pub const ZERO: Self = Self {
        imu_sample_sets: [0; MAX_IMUS],
        pps_edges: 0,
        gnss_fixes: 0,
        gnss_frames_refused: 0,
        health_reports: 0,
        wv_frames: 0,
        filter_states: 0,
        noise_reports: 0,
        fault_reports: 0,
        fusion_ticks: 0,
        navigating_fusion_ticks: 0,
        navigating_sample_sets: 0,
        frames_written: 0,
        bytes_written: 0,
        frames_dropped: 0,
        source_ticks: 0,
        record_ticks: 0,
        total_ticks: 0,
    };

    /// All IMU sample sets received.
    pub fn total_imu_sample_sets(&self) -> u64 {
        self.imu_sample_sets.iter().sum()
    }
}

/// Why a run stopped early.
#[derive(Debug, Clone, PartialEq)]
pub enum RecorderError<S, K> {
    /// The sample source failed.
    Source(S),
    /// The log sink failed.
    Sink(K),
    /// A frame could not be encoded.
    Encode(LogError),
    /// A sample set names an IMU the header does not declare.
    UnknownImu { imu_id: u8, t_us: u64 },
    /// An event is older than the one before it.
    TimeWentBackwards { t_us: u64, previous_t_us: u64 },
}

/// The board application; see the module documentation.
pub struct Recorder {
    header: Header,
    /// Log time between two periodic health reports, microseconds.
    pub health_period_us: u64,
    /// A PPS edge seen within this long before a health report sets `FLAG_PPS_LOCKED`, and a
    /// 3-D GNSS fix `FLAG_GNSS_FIX`.
    pub pps_lock_window_us: u64,
    /// An IMU with no sample for this many of its sample intervals before a health report
    /// has gone quiet (its data-ready line, its clock): the report sets `FLAG_IMU_FAULT`.
    pub imu_silent_intervals: u32,
    /// Log time between two periodic rounds of WaveletVariance frames, microseconds (a live
    /// board never reaches the end-of-run round).
    pub wv_period_us: u64,
    /// The model the fusion runs, when it runs.
    fusion_model: Option<BoardModel>,
}

impl Recorder {
    /// A recorder writing `header` first; health once per second of log time.
    pub fn new(header: Header) -> Self {
        Recorder {
            header,
            health_period_us: 1_000_000,
            pps_lock_window_us: 2_000_000,
            imu_silent_intervals: 10,
            wv_period_us: 60_000_000,
            fusion_model: None,
        }
    }

    /// Runs the on-board fusion with `model` when the header declares exactly three IMUs
    /// (with another count the recorder only records).
    pub fn with_fusion(mut self, model: BoardModel) -> Self {
        self.fusion_model = Some(model);
        self
    }

    /// Puts the fusion for this header into `slot`, if it runs.
    #[inline(never)]
    fn install_fusion(&self, slot: &mut heapless::Vec<Fusion, 1>) {
        slot.clear();
        if let Some(fusion) = self.fusion() {
            let _ = slot.push(fusion);
        }
    }

    /// The fusion and its set assembler for this header, if it runs.
    fn fusion(&self) -> Option<Fusion> {
        let model = self.fusion_model.as_ref()?;
        if self.header.imus.len() != UNITS {
            return None;
        }
        let rate_hz = self.header.imus.first()?.sample_rate_hz;
        let config = FusionConfig::at_rate(rate_hz);
        let interval_us = (f64::from(config.sample_interval_s) * 1e6) as u64;
        Some(Fusion {
            fusion: BoardFusion::new(config, model),
            sets: SetAssembler::new(interval_us),
        })
    }

    /// The header this recorder writes.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Records until the source ends (or, for a live source, forever); flushes the sink and
    /// returns what happened.
    pub fn run<Src: SampleSource, Snk: LogSink, C: TickClock>(
        &self,
        source: &mut Src,
        sink: &mut Snk,
        clock: &mut C,
    ) -> Result<RecorderStats, RecorderError<Src::Error, Snk::Error>> {
        let mut state = RunState::new();
        self.run_in(&mut state, source, sink, clock)
    }

    /// As [`Self::run`], in a state the caller keeps (a board's static, so that the run's
    /// 35 KiB never sit on its stack); the state is reset first.
    pub fn run_in<Src: SampleSource, Snk: LogSink, C: TickClock>(
        &self,
        state: &mut RunState,
        source: &mut Src,
        sink: &mut Snk,
        clock: &mut C,
    ) -> Result<RecorderStats, RecorderError<Src::Error, Snk::Error>> {
        state.reset();
        let mut run = Run { state, sink };
        // Built in a callee's frame: a fusion is 10 KiB, and the board's stack is measured
        // (firmware/src/stack.rs).
        self.install_fusion(&mut run.fusion);
        let start = clock.now_ticks();
        run.emit_with(|| Frame::Header(self.header.clone()))?;
        run.stats.record_ticks += clock.now_ticks().saturating_sub(start);

        let mut previous_t_us: Option<u64> = None;
        let mut next_health_t_us: Option<u64> = None;
        let mut next_wv_t_us: Option<u64> = None;
        let mut last_pps_t_us: Option<u64> = None;
        let mut last_fix_t_us: Option<u64> = None;
        // Each IMU's latest sample (raw time), from the first event on: a unit that never
        // answers goes quiet as one that stops.
        let mut last_imu_t_us: [Option<u64>; MAX_IMUS] = [None; MAX_IMUS];
        let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
        let mut tagger = TimeTagger::new(ClockConfig::microsecond_timer());
        // Whether the latest event's logged time is GPS time.
        let mut time_gps = false;
        let mut dropped_at_last_health = 0u32;
        let mut ticks_at_last_health = start;
        let mut record_ticks_at_last_health = 0u64;
        loop {
            let fetch_start = clock.now_ticks();
            let event = source.next_event().map_err(RecorderError::Source)?;
            let fetched = clock.now_ticks();
            run.stats.source_ticks += fetched.saturating_sub(fetch_start);
            let Some(event) = event else { break };

            let t_us = event.t_us();
            if let Some(previous) = previous_t_us {
                if t_us < previous {
                    return Err(RecorderError::TimeWentBackwards {
                        t_us,
                        previous_t_us: previous,
                    });
                }
            }
            previous_t_us = Some(t_us);
            for last in last_imu_t_us.iter_mut() {
                last.get_or_insert(t_us);
            }
            if let SourceEvent::Pps(_) = event {
                tagger.on_pps(t_us);
            }
            let (log_t_us, clock_status) = tagger.time_of(t_us);
            time_gps = clock_status.is_some();
            let due = *next_health_t_us.get_or_insert(t_us.saturating_add(self.health_period_us));
            if t_us >= due {
                let now = clock.now_ticks();
                let health = self.health(
                    (t_us, log_t_us, time_gps),
                    source,
                    &run.stats,
                    (
                        last_pps_t_us,
                        last_fix_t_us,
                        self.imu_silent(t_us, &last_imu_t_us),
                    ),
                    dropped_at_last_health,
                    load_permille(
                        run.stats
                            .record_ticks
                            .saturating_sub(record_ticks_at_last_health),
                        now.saturating_sub(ticks_at_last_health),
                    ),
                );
                dropped_at_last_health = run.stats.frames_dropped;
                ticks_at_last_health = now;
                record_ticks_at_last_health = run.stats.record_ticks;
                run.emit_with(|| Frame::Health(health))?;
                run.stats.health_reports += 1;
                // Skip whole periods with no events rather than reporting them in a burst.
                let periods_late = (t_us - due) / self.health_period_us.max(1) + 1;
                next_health_t_us =
                    Some(due.saturating_add(periods_late * self.health_period_us.max(1)));
            }
            let wv_period_us = self.wv_period_us.max(1);
            let wv_due = *next_wv_t_us.get_or_insert(t_us.saturating_add(wv_period_us));
            if t_us >= wv_due {
                run.emit_wv(&self.header)?;
                let periods_late = (t_us - wv_due) / wv_period_us + 1;
                next_wv_t_us = Some(wv_due.saturating_add(periods_late * wv_period_us));
            }

            match event {
                SourceEvent::Imu(sample) => {
                    let Some(index) = self
                        .header
                        .imus
                        .iter()
                        .position(|imu| imu.imu_id == sample.imu_id)
                    else {
                        return Err(RecorderError::UnknownImu {
                            imu_id: sample.imu_id,
                            t_us,
                        });
                    };
                    let sample = ImuSampleSet {
                        t_us: log_t_us,
                        ..sample
                    };
                    last_imu_t_us[index] = Some(t_us);
                    run.emit_with(|| Frame::Imu(sample))?;
                    run.stats.imu_sample_sets[index] += 1;
                    if let Some(channels) = run.wv.get_mut(index) {
                        let counts = sample.gyro_counts.iter().chain(&sample.accel_counts);
                        for (stream, &c) in channels.iter_mut().zip(counts) {
                            stream.push(c);
                        }
                    }
                    if let Some(last) = run.wv_last_t_us.get_mut(index) {
                        *last = sample.t_us;
                    }
                    if let Some(imu) = self.header.imus.get(index) {
                        run.fuse_sample(index, &sample, imu, clock)?;
                    }
                }
                SourceEvent::Pps(pps) => {
                    run.emit_with(|| {
                        Frame::Pps(PpsEvent {
                            t_us: log_t_us,
                            ..pps
                        })
                    })?;
                    run.stats.pps_edges += 1;
                    last_pps_t_us = Some(pps.t_us);
                }
                SourceEvent::Gnss(chunk) => {
                    // A chunk of at most GNSS_CHUNK_MAX (100) bytes completes at most one
                    // 100-byte solution; room is kept for two.
                    let mut fixes: heapless::Vec<GnssFix, 2> = heapless::Vec::new();
                    receiver.push(chunk.bytes(), |fix| {
                        let _ = fixes.push(fix);
                    });
                    for fix in fixes {
                        tagger.on_fix(fix.t_us, t_us);
                        run.emit_with(|| Frame::Gnss(fix))?;
                        run.stats.gnss_fixes += 1;
                        // Without GPS time the fix's age is unknown: taken as fresh.
                        let now_us = if time_gps { log_t_us } else { fix.t_us };
                        run.fuse_gnss(now_us, &fix, clock);
                        if fix.fix_type == 3 || fix.fix_type == 4 {
                            last_fix_t_us = Some(t_us);
                        }
                    }
                }
            }
            run.stats.record_ticks += clock.now_ticks().saturating_sub(fetched);
        }

        run.stats.gnss_frames_refused = receiver.counts().malformed;
        let final_start = clock.now_ticks();
        if let Some(set) = run.fusion.first_mut().and_then(|f| f.sets.finish()) {
            run.fuse_set(set, clock)?;
        }
        run.emit_wv(&self.header)?;
        let last_t_us = previous_t_us.unwrap_or(0);
        let health = self.health(
            (last_t_us, tagger.time_of(last_t_us).0, time_gps),
            source,
            &run.stats,
            (
                last_pps_t_us,
                last_fix_t_us,
                self.imu_silent(last_t_us, &last_imu_t_us),
            ),
            dropped_at_last_health,
            load_permille(
                run.stats
                    .record_ticks
                    .saturating_sub(record_ticks_at_last_health),
                final_start.saturating_sub(ticks_at_last_health),
            ),
        );
        run.emit_with(|| Frame::Health(health))?;
        run.stats.health_reports += 1;
        run.sink.flush().map_err(RecorderError::Sink)?;
        let end = clock.now_ticks();
        run.stats.record_ticks += end.saturating_sub(final_start);
        run.stats.total_ticks = end.saturating_sub(start);
        Ok(run.stats)
    }

    /// The health report at an event of raw time `t_us` (the source's), logged at
    /// `log_t_us` (GPS time when `time_gps`).
    fn health<Src: SampleSource>(
        &self,
        (t_us, log_t_us, time_gps): (u64, u64, bool),
        source: &mut Src,
        stats: &RecorderStats,
        (last_pps_t_us, last_fix_t_us, imu_silent): (Option<u64>, Option<u64>, bool),
        dropped_at_last_health: u32,
        cpu_load_permille: u16,
    ) -> Health {
        let mut flags = 0;
        if time_gps {
            flags |= Health::FLAG_TIME_GPS;
        }
        let recent =
            |t: Option<u64>| t.is_some_and(|t| t_us.saturating_sub(t) <= self.pps_lock_window_us);
        if recent(last_pps_t_us) {
            flags |= Health::FLAG_PPS_LOCKED;
        }
        if recent(last_fix_t_us) {
            flags |= Health::FLAG_GNSS_FIX;
        }
        if source.imu_fault() || imu_silent {
            flags |= Health::FLAG_IMU_FAULT;
        }
        if stats.frames_dropped > dropped_at_last_health {
            flags |= Health::FLAG_LOG_BACKPRESSURE;
        }
        Health {
            t_us: log_t_us,
            frames_dropped: stats.frames_dropped,
            samples_overrun: source.samples_overrun(),
            flags,
            cpu_load_permille,
            imu_temperature_deg_c: source.imu_temperatures_deg_c(),
        }
    }
}

impl Recorder {
    /// Whether a declared IMU has had no sample for [`Self::imu_silent_intervals`] of its
    /// intervals at raw time `t_us`.
    fn imu_silent(&self, t_us: u64, last_imu_t_us: &[Option<u64>; MAX_IMUS]) -> bool {
        self.header
            .imus
            .iter()
            .zip(last_imu_t_us)
            .any(|(imu, last)| {
                let interval_us = 1e6 / f64::from(imu.sample_rate_hz).max(1e-3);
                let limit_us = (f64::from(self.imu_silent_intervals) * interval_us) as u64;
                last.is_some_and(|last| t_us.saturating_sub(last) > limit_us)
            })
    }
}

/// Share of `interval_ticks` spent in the recorder's own work, per mille.
fn load_permille(busy_ticks: u64, interval_ticks: u64) -> u16 {
    if interval_ticks == 0 {
        return 0;
    }
    (busy_ticks.min(interval_ticks) * 1000 / interval_ticks) as u16
}

/// What a run keeps from event to event: 35 KiB, most of it the 18 wavelet-variance
/// accumulators and the fusion. A board that measures its stack keeps it in a static
/// ([`Recorder::run_in`]; it is `const`-constructed, so it never passes through the stack).
pub struct RunState {
    stats: RecorderStats,
    frame_buf: [u8; MAX_FRAME_LEN],
    /// Wavelet-variance accumulators per IMU (header order) and channel.
    wv: [[RecorderWv; WV_CHANNELS]; MAX_IMUS],
    /// Time of the last sample accumulated per IMU, microseconds.
    wv_last_t_us: [u64; MAX_IMUS],
    /// The fusion when it runs. A `heapless::Vec` of one rather than an `Option`: empty, it
    /// is all zero bytes (an `Option`'s `None` is a niche value), so a board's static state
    /// sits in .bss and costs no flash image.
    fusion: heapless::Vec<Fusion, 1>,
}

impl RunState {
    /// A fresh state.
    pub const fn new() -> Self {
        Self {
            stats: RecorderStats::ZERO,
            frame_buf: [0u8; MAX_FRAME_LEN],
            wv: [const { [const { RecorderWv::new() }; WV_CHANNELS] }; MAX_IMUS],
            wv_last_t_us: [0; MAX_IMUS],
            fusion: heapless::Vec::new(),
        }
    }

    /// Back to fresh, field by field in place.
    fn reset(&mut self) {
        self.stats = RecorderStats::ZERO;
        for stream in self.wv.iter_mut().flatten() {
            *stream = RecorderWv::new();
        }
        self.wv_last_t_us = [0; MAX_IMUS];
        self.fusion.clear();
    }
}

impl Default for RunState {
    fn default() -> Self {
        Self::new()
    }
}

struct Run<'a, K> {
    state: &'a mut RunState,
    sink: &'a mut K,
}

impl<K> core::ops::Deref for Run<'_, K> {
    type Target = RunState;
    fn deref(&self) -> &RunState {
        self.state
    }
}

impl<K> core::ops::DerefMut for Run<'_, K> {
    fn deref_mut(&mut self) -> &mut RunState {
        self.state
    }
}

/// The on-board fusion and the sets it is fed.
struct Fusion {
    fusion: BoardFusion,
    sets: SetAssembler,
}

/// A sample's counts in SI units, by its IMU's scale factors. In f32: the fusion's own
/// precision, and f64 arithmetic runs in software on the Cortex-M4F.
fn reading_of(sample: &ImuSampleSet, imu: &ImuConfig) -> UnitReading {
    let si = |counts: &[i32; 3], scale: f64| {
        let scale = scale as f32;
        counts.map(|c| c as f32 * scale)
    };
    UnitReading {
        gyro_rad_s: si(&sample.gyro_counts, imu.gyro_scale_rad_s_per_count),
        accel_m_s2: si(&sample.accel_counts, imu.accel_scale_m_s2_per_count),
    }
}

impl<K: LogSink> Run<'_, K> {
    /// Gives unit `index`'s sample to the fusion, and fuses the set it completes.
    fn fuse_sample<S>(
        &mut self,
        index: usize,
        sample: &ImuSampleSet,
        imu: &ImuConfig,
        clock: &mut impl TickClock,
    ) -> Result<(), RecorderError<S, K::Error>> {
        let Some(f) = self.fusion.first_mut() else {
            return Ok(());
        };
        match f.sets.push(index, sample.t_us, reading_of(sample, imu)) {
            Some(set) => self.fuse_set(set, clock),
            None => Ok(()),
        }
    }

    /// Gives a receiver solution to the fusion (out of line: the run loop's frame stays
    /// small).
    #[inline(never)]
    fn fuse_gnss(&mut self, now_us: u64, fix: &GnssFix, clock: &mut impl TickClock) {
        let Some(f) = self.fusion.first_mut() else {
            return;
        };
        let start = clock.now_ticks();
        let navigating = f.fusion.filter().is_some();
        f.fusion.push_gnss(now_us, fix);
        let ticks = clock.now_ticks().saturating_sub(start);
        self.stats.fusion_ticks += ticks;
        if navigating {
            self.stats.navigating_fusion_ticks += ticks;
        }
    }

    /// Fuses one sample set and logs what the fusion reports, each output framed as it
    /// comes (no list of outputs, no frame kept: the board's stack is measured).
    #[inline(never)]
    fn fuse_set<S>(
        &mut self,
        (t_us, readings): crate::fusion::sets::SampleSet,
        clock: &mut impl TickClock,
    ) -> Result<(), RecorderError<S, K::Error>> {
        let Run { state, sink } = self;
        let RunState {
            stats,
            frame_buf,
            fusion,
            ..
        } = &mut **state;
        let Some(f) = fusion.first_mut() else {
            return Ok(());
        };
        let start = clock.now_ticks();
        let navigating = f.fusion.filter().is_some();
        let mut failed = None;
        f.fusion.push_set(t_us, &readings, &mut |output| {
            if failed.is_some() {
                return;
            }
            let frame = match output {
                FusionOutput::State(s) => {
                    stats.filter_states += 1;
                    Frame::Filter(s)
                }
                FusionOutput::Noise(n) => {
                    stats.noise_reports += 1;
                    Frame::Noise(n)
                }
                FusionOutput::Fault(fault) => {
                    stats.fault_reports += 1;
                    Frame::Fault(fault)
                }
            };
            if let Err(e) = emit_to(&mut **sink, frame_buf, stats, &frame) {
                failed = Some(e);
            }
        });
        let ticks = clock.now_ticks().saturating_sub(start);
        self.stats.fusion_ticks += ticks;
        if navigating {
            self.stats.navigating_fusion_ticks += ticks;
            self.stats.navigating_sample_sets += 1;
        }
        failed.map_or(Ok(()), Err)
    }

    /// One WaveletVariance frame per declared IMU and channel.
    fn emit_wv<S>(&mut self, header: &Header) -> Result<(), RecorderError<S, K::Error>> {
        for (index, imu) in header.imus.iter().enumerate() {
            let Some(&t_us) = self.wv_last_t_us.get(index) else {
                continue;
            };
            for channel in 0..WV_CHANNELS {
                let Some(stream) = self.wv.get(index).and_then(|c| c.get(channel)) else {
                    continue;
                };
                let frame = Frame::WaveletVariance(WvFrame {
                    t_us,
                    imu_id: imu.imu_id,
                    channel: channel as u8,
                    snapshot: stream.snapshot(),
                });
                self.emit(&frame)?;
                self.stats.wv_frames += 1;
            }
        }
        Ok(())
    }

    fn emit<S>(&mut self, frame: &Frame) -> Result<(), RecorderError<S, K::Error>> {
        let Run { state, sink } = self;
        emit_to(&mut **sink, &mut state.frame_buf, &mut state.stats, frame)
    }

    /// Emits the frame `make` builds, in this function's frame rather than the caller's (a
    /// `Frame` is 1 KiB: the large run loop keeps none of them).
    #[inline(never)]
    fn emit_with<S>(
        &mut self,
        make: impl FnOnce() -> Frame,
    ) -> Result<(), RecorderError<S, K::Error>> {
        let frame = make();
        self.emit(&frame)
    }
}

/// Encodes `frame` into `frame_buf` and hands it to `sink`, counting it in `stats`.
fn emit_to<S, K: LogSink>(
    sink: &mut K,
    frame_buf: &mut [u8; MAX_FRAME_LEN],
    stats: &mut RecorderStats,
    frame: &Frame,
) -> Result<(), RecorderError<S, K::Error>> {
    let len = encode_frame(frame, frame_buf).map_err(RecorderError::Encode)?;
    let bytes = frame_buf
        .get(..len)
        .ok_or(RecorderError::Encode(LogError::BufferTooSmall))?;
    match sink.write_frame(bytes).map_err(RecorderError::Sink)? {
        Accepted::Written => {
            stats.frames_written += 1;
            stats.bytes_written += len as u64;
        }
        Accepted::Dropped => stats.frames_dropped = stats.frames_dropped.saturating_add(1),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::log::{ImuConfig, LogAccumulator, PROTOCOL_VERSION};

    fn header(ids: &[u8]) -> Header {
        let mut imus = heapless::Vec::new();
        for &imu_id in ids {
            imus.push(ImuConfig {
                imu_id,
                model: heapless::String::try_from("ICM-42688-P").unwrap(),
                sample_rate_hz: 200.0,
                gyro_scale_rad_s_per_count: 1e-3,
                accel_scale_m_s2_per_count: 4e-3,
            })
            .unwrap();
        }
        Header {
            protocol_version: PROTOCOL_VERSION,
            board: heapless::String::try_from("test").unwrap(),
            imus,
        }
    }

    struct VecSource(std::vec::IntoIter<SourceEvent>);
    impl SampleSource for VecSource {
        type Error = ();
        fn next_event(&mut self) -> Result<Option<SourceEvent>, ()> {
            Ok(self.0.next())
        }
    }

    /// A sink with room for `capacity` bytes in total, like a transmit queue never drained.
    struct BoundedSink {
        bytes: std::vec::Vec<u8>,
        capacity: usize,
        flushed: bool,
    }
    impl BoundedSink {
        fn with_capacity(capacity: usize) -> Self {
            Self {
                bytes: std::vec::Vec::new(),
                capacity,
                flushed: false,
            }
        }
    }
    impl LogSink for BoundedSink {
        type Error = ();
        fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, ()> {
            if self.bytes.len() + frame.len() > self.capacity {
                return Ok(Accepted::Dropped);
            }
            self.bytes.extend_from_slice(frame);
            Ok(Accepted::Written)
        }
        fn flush(&mut self) -> Result<(), ()> {
            self.flushed = true;
            Ok(())
        }
    }

    /// Advances 10 ticks per reading.
    struct StepClock(u64);
    impl TickClock for StepClock {
        fn now_ticks(&mut self) -> u64 {
            self.0 += 10;
            self.0
        }
    }

    fn imu(t_us: u64, imu_id: u8, k: i32) -> SourceEvent {
        SourceEvent::Imu(ImuSampleSet {
            t_us,
            imu_id,
            gyro_counts: [k, -k, 3 * k],
            accel_counts: [i32::MAX - k.abs(), 0, -k],
        })
    }

    fn decode(bytes: &[u8]) -> std::vec::Vec<Frame> {
        let mut acc = LogAccumulator::default();
        let frames: std::vec::Vec<_> = acc.feed(bytes).map(|f| f.unwrap()).collect();
        assert_eq!(acc.stats().frames_dropped, 0);
        frames
    }

    /// Receiver bytes split across chunks anywhere are logged as the fixes they hold, and
    /// health reports the 3-D fix while it is recent.
    #[test]
    fn logs_the_fixes_in_the_receivers_bytes_and_reports_the_fix() {
        let fix = |k: u64| GnssFix {
            t_us: k * 100_000,
            lat_rad: 0.8,
            lon_rad: 0.1 + k as f64 * 1e-7,
            h_m: 400.0,
            vel_ned_m_s: [10.0, 0.0, 0.0],
            pos_sigma_m: 0.3,
            vel_sigma_m_s: 0.05,
            num_sats: 12,
            fix_type: 3,
        };
        let bytes: std::vec::Vec<u8> = (0..15)
            .flat_map(|k| crate::gnss::encode_nav_pvt(&fix(k), LEAP_SECONDS_2017))
            .collect();
        let mut events = std::vec::Vec::new();
        for (k, piece) in bytes.chunks(37).enumerate() {
            let mut data = [0u8; GNSS_CHUNK_MAX];
            data[..piece.len()].copy_from_slice(piece);
            let t_us = k as u64 * 37_000;
            events.push(imu(t_us, 4, k as i32));
            events.push(SourceEvent::Gnss(GnssChunk {
                t_us,
                len: piece.len() as u8,
                data,
            }));
        }
        let recorder = Recorder::new(header(&[4]));
        let mut sink = BoundedSink::with_capacity(usize::MAX);
        let stats = recorder
            .run(
                &mut VecSource(events.into_iter()),
                &mut sink,
                &mut StepClock(0),
            )
            .unwrap();
        assert_eq!(stats.gnss_fixes, 15);
        let frames = decode(&sink.bytes);
        let logged: std::vec::Vec<&GnssFix> = frames
            .iter()
            .filter_map(|f| match f {
                Frame::Gnss(g) => Some(g),
                _ => None,
            })
            .collect();
        assert_eq!(logged.len(), 15);
        for (k, g) in logged.iter().enumerate() {
            assert_eq!(g.t_us, k as u64 * 100_000);
            assert!((g.lon_rad - fix(k as u64).lon_rad).abs() < 2e-9);
        }
        let last_health = frames.iter().rev().find_map(|f| match f {
            Frame::Health(h) => Some(h),
            _ => None,
        });
        assert!(last_health.is_some_and(|h| h.flags & Health::FLAG_GNSS_FIX != 0));
    }

    /// The board's timer counts microseconds since boot, 40 ppm fast; the receiver's fixes
    /// (NAV-PVT every 100 ms, 50 ms late) and PPS edges make the log GPS time: samples
    /// are logged within 10 us of their GPS time once a fix has labelled a pulse and a second
    /// pulse has given the rate, and Health says so (FLAG_TIME_GPS).
    #[test]
    fn samples_are_logged_in_gps_time_once_pulses_and_fixes_discipline_the_timer() {
        let gps0_s = 1_400_000_000.0f64;
        let boot_us = |gps_s: f64| ((gps_s - gps0_s + 500.25) * (1.0 + 40e-6) * 1e6).round() as u64;
        let fix = |valid_s: f64| GnssFix {
            t_us: (valid_s * 1e6).round() as u64,
            lat_rad: 0.8,
            lon_rad: 0.1,
            h_m: 400.0,
            vel_ned_m_s: [0.0; 3],
            pos_sigma_m: 0.3,
            vel_sigma_m_s: 0.05,
            num_sats: 12,
            fix_type: 3,
        };
        let mut events = std::vec::Vec::new();
        let mut truth = std::vec::Vec::new();
        for ms in 0..6000u32 {
            let gps_s = gps0_s + 0.5 + f64::from(ms) * 1e-3;
            if ms % 1000 == 500 {
                events.push(SourceEvent::Pps(PpsEvent {
                    t_us: boot_us(gps_s),
                    sequence: ms / 1000,
                }));
            }
            if ms % 100 == 50 {
                let frame = crate::gnss::encode_nav_pvt(&fix(gps_s - 0.05), LEAP_SECONDS_2017);
                let mut data = [0u8; GNSS_CHUNK_MAX];
                data[..frame.len()].copy_from_slice(&frame);
                events.push(SourceEvent::Gnss(GnssChunk {
                    t_us: boot_us(gps_s),
                    len: frame.len() as u8,
                    data,
                }));
            }
            events.push(imu(boot_us(gps_s + 0.0003), 0, ms as i32));
            truth.push(gps_s + 0.0003);
        }
        let mut sink = BoundedSink::with_capacity(usize::MAX);
        Recorder::new(header(&[0]))
            .run(
                &mut VecSource(events.into_iter()),
                &mut sink,
                &mut StepClock(0),
            )
            .unwrap();
        let frames = decode(&sink.bytes);
        let samples: std::vec::Vec<u64> = frames
            .iter()
            .filter_map(|f| match f {
                Frame::Imu(s) => Some(s.t_us),
                _ => None,
            })
            .collect();
        assert_eq!(samples.len(), truth.len());
        // Before the second pulse: boot time; from the third second on: GPS time.
        assert_eq!(samples[0], boot_us(truth[0]));
        let worst_us = samples[2000..]
            .iter()
            .zip(&truth[2000..])
            .map(|(&logged, &t)| (logged as f64 - t * 1e6).abs())
            .fold(0.0, f64::max);
        assert!(worst_us < 10.0, "worst {worst_us} us");
        let health: std::vec::Vec<&Health> = frames
            .iter()
            .filter_map(|f| match f {
                Frame::Health(h) => Some(h),
                _ => None,
            })
            .collect();
        assert_eq!(health[0].flags & Health::FLAG_TIME_GPS, 0);
        assert!(health[3..]
            .iter()
            .all(|h| h.flags & Health::FLAG_TIME_GPS != 0));
    }

    /// An IMU that stops delivering (its data-ready line quiet) is flagged in the health
    /// reports while it is quiet, and no longer once it is back.
    #[test]
    fn a_silent_imu_is_flagged_in_the_health_reports_while_it_is_quiet() {
        // Two IMUs at 100 Hz for 5 s; IMU 7 gives nothing from 1.5 s to 3.2 s.
        let mut events = std::vec::Vec::new();
        for k in 0..500u64 {
            if k % 100 == 0 {
                events.push(SourceEvent::Pps(PpsEvent {
                    t_us: k * 10_000,
                    sequence: (k / 100) as u32,
                }));
            }
            events.push(imu(k * 10_000, 4, k as i32));
            if !(150..320).contains(&k) {
                events.push(imu(k * 10_000 + 3, 7, -(k as i32)));
            }
        }
        let recorder = Recorder::new(header(&[4, 7]));
        let mut sink = BoundedSink::with_capacity(usize::MAX);
        recorder
            .run(
                &mut VecSource(events.into_iter()),
                &mut sink,
                &mut StepClock(0),
            )
            .unwrap();
        let flagged: std::vec::Vec<(u64, bool)> = decode(&sink.bytes)
            .iter()
            .filter_map(|f| match f {
                Frame::Health(h) => Some((h.t_us, h.flags & Health::FLAG_IMU_FAULT != 0)),
                _ => None,
            })
            .collect();
        // Quiet for more than 10 intervals (100 ms) at the reports of 2 s and 3 s only.
        assert_eq!(
            flagged,
            [
                (1_000_000, false),
                (2_000_000, true),
                (3_000_000, true),
                (4_000_000, false),
                (4_990_003, false)
            ]
        );
    }

    #[test]
    fn writes_header_events_in_order_and_health_each_second() {
        // Two IMUs at 100 Hz for 2.5 s, PPS at 0, 1 and 2 s.
        let mut events = std::vec::Vec::new();
        for k in 0..250u64 {
            if k % 100 == 0 {
                events.push(SourceEvent::Pps(PpsEvent {
                    t_us: k * 10_000,
                    sequence: (k / 100) as u32,
                }));
            }
            events.push(imu(k * 10_000, 4, k as i32));
            events.push(imu(k * 10_000 + 3, 7, -(k as i32)));
        }
        let recorder = Recorder::new(header(&[4, 7]));
        let mut sink = BoundedSink::with_capacity(usize::MAX);
        let stats = recorder
            .run(
                &mut VecSource(events.clone().into_iter()),
                &mut sink,
                &mut StepClock(0),
            )
            .unwrap();
        assert!(sink.flushed);
        assert_eq!(stats.imu_sample_sets[..2], [250, 250]);
        assert_eq!(stats.wv_frames, 12);
        assert_eq!(stats.pps_edges, 3);
        assert_eq!(stats.frames_dropped, 0);
        assert_eq!(stats.bytes_written, sink.bytes.len() as u64);

        let frames = decode(&sink.bytes);
        assert_eq!(stats.frames_written, frames.len() as u64);
        assert_eq!(frames[0], Frame::Header(recorder.header().clone()));
        // Health at 1 s and 2 s (before the events stamped then) and at the end.
        let health: std::vec::Vec<&Health> = frames
            .iter()
            .filter_map(|f| match f {
                Frame::Health(h) => Some(h),
                _ => None,
            })
            .collect();
        assert_eq!(stats.health_reports, 3);
        assert_eq!(
            health.iter().map(|h| h.t_us).collect::<std::vec::Vec<_>>(),
            [1_000_000, 2_000_000, 2_490_003]
        );
        assert!(health
            .iter()
            .all(|h| h.flags == Health::FLAG_PPS_LOCKED && h.frames_dropped == 0));
        assert!(health.iter().all(|h| h.cpu_load_permille <= 1000));
        // Every event comes out unchanged and in order.
        let replayed: std::vec::Vec<SourceEvent> = frames
            .iter()
            .filter_map(|f| match f {
                Frame::Imu(s) => Some(SourceEvent::Imu(*s)),
                Frame::Pps(p) => Some(SourceEvent::Pps(*p)),
                _ => None,
            })
            .collect();
        assert_eq!(replayed, events);
    }

    #[test]
    fn a_full_sink_drops_whole_frames_counts_them_and_flags_backpressure() {
        let events: std::vec::Vec<_> = (0..300u64).map(|k| imu(k * 10_000, 1, k as i32)).collect();
        let recorder = Recorder::new(header(&[1]));
        let mut sink = BoundedSink::with_capacity(1000);
        let stats = recorder
            .run(
                &mut VecSource(events.into_iter()),
                &mut sink,
                &mut StepClock(0),
            )
            .unwrap();
        let frames = decode(&sink.bytes);
        let written = frames.len() as u64;
        assert_eq!(stats.frames_written, written);
        // 300 samples + header + health at 1 s and 2 s + final health + 6 WV frames.
        assert_eq!(written + stats.frames_dropped as u64, 300 + 1 + 3 + 6);
        assert!(stats.frames_dropped > 250);
        // No PPS was ever seen: not locked.
        assert!(frames
            .iter()
            .all(|f| !matches!(f, Frame::Health(h) if h.flags & Health::FLAG_PPS_LOCKED != 0)));
        assert!(matches!(frames.last(), Some(Frame::Imu(_))));
    }

    #[test]
    fn wavelet_variance_snapshots_match_direct_accumulation_periodically_and_at_the_end() {
        // Two IMUs at 100 Hz for 25 s; snapshots every 10 s (at 10 s and 20 s) and at the end.
        let events: std::vec::Vec<_> = (0..2500u64)
            .flat_map(|k| {
                let c = ((k * 7919) % 263) as i32 - 131;
                [imu(k * 10_000, 4, c), imu(k * 10_000 + 3, 7, -3 * c + 5)]
            })
            .collect();
        let mut recorder = Recorder::new(header(&[4, 7]));
        recorder.wv_period_us = 10_000_000;
        let mut sink = BoundedSink::with_capacity(usize::MAX);
        let stats = recorder
            .run(
                &mut VecSource(events.clone().into_iter()),
                &mut sink,
                &mut StepClock(0),
            )
            .unwrap();
        assert_eq!(stats.wv_frames, 3 * 2 * 6);
        let frames = decode(&sink.bytes);
        // Replays the log: each WV frame must equal an accumulator fed the samples of its
        // IMU logged before it.
        let mut direct: std::vec::Vec<[RecorderWv; 6]> = std::vec![
            core::array::from_fn(|_| RecorderWv::new()),
            core::array::from_fn(|_| RecorderWv::new())
        ];
        let mut last_t_us = [0u64; 2];
        let mut seen = std::vec::Vec::new();
        for frame in &frames {
            match frame {
                Frame::Imu(s) => {
                    let i = if s.imu_id == 4 { 0 } else { 1 };
                    for (ch, &c) in s.gyro_counts.iter().chain(&s.accel_counts).enumerate() {
                        direct[i][ch].push(c);
                    }
                    last_t_us[i] = s.t_us;
                }
                Frame::WaveletVariance(wv) => {
                    let i = if wv.imu_id == 4 { 0 } else { 1 };
                    assert_eq!(wv.snapshot, direct[i][wv.channel as usize].snapshot());
                    assert_eq!(wv.t_us, last_t_us[i]);
                    assert_eq!(wv.snapshot.levels.len(), 20);
                    seen.push((wv.imu_id, wv.channel, wv.snapshot.n_samples));
                }
                _ => {}
            }
        }
        let mut expected = std::vec::Vec::new();
        // The round at 10 s comes before the 10 s sample of IMU 4 (1000 samples each); the
        // one at 20 s likewise; the last after all 2500.
        for n in [1000u64, 2000, 2500] {
            for imu_id in [4u8, 7] {
                for channel in 0..6u8 {
                    expected.push((imu_id, channel, n));
                }
            }
        }
        assert_eq!(seen, expected);
        // The accumulated sums are not trivially zero.
        assert!(direct[1][0].level(3).unwrap().sum_sq > 0);
        // The final round comes just before the final health report.
        assert!(matches!(frames[frames.len() - 1], Frame::Health(_)));
        assert!(matches!(
            frames[frames.len() - 2],
            Frame::WaveletVariance(_)
        ));
    }

    #[test]
    fn undeclared_imus_and_time_going_backwards_stop_the_run() {
        let recorder = Recorder::new(header(&[1]));
        let sink = || BoundedSink::with_capacity(usize::MAX);
        let unknown = recorder.run(
            &mut VecSource(vec![imu(5, 1, 0), imu(6, 2, 0)].into_iter()),
            &mut sink(),
            &mut StepClock(0),
        );
        assert_eq!(
            unknown,
            Err(RecorderError::UnknownImu { imu_id: 2, t_us: 6 })
        );
        let backwards = recorder.run(
            &mut VecSource(vec![imu(5, 1, 0), imu(4, 1, 0)].into_iter()),
            &mut sink(),
            &mut StepClock(0),
        );
        assert_eq!(
            backwards,
            Err(RecorderError::TimeWentBackwards {
                t_us: 4,
                previous_t_us: 5
            })
        );
    }
}
