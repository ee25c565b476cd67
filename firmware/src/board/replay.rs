//! Replay board: the application under QEMU (`-machine netduinoplus2`, an STM32F405), fed
//! from a recording instead of sensors.
//!
//! The semihosting command line names two host files: the replay input
//! (`dynacal_core::replay` format) and the log to write, and optionally a third: the board
//! model (`board-model.bin`, `dynacal_core::board_model`) the fusion runs. A model that does
//! not read (damaged, truncated, another version) is refused with its reason on stderr and
//! the built-in model runs; a model file that cannot be opened at all is a usage error.
//! `--faults PLAN` (anywhere after the two paths) injects the board faults a plan lists
//! (`dynacal_core::inject`): the source and the sink are wrapped in the plan's faults, and a
//! planned hang stops the main loop, which the watchdog (`soft_watchdog`) catches. A plan
//! that does not read is a usage error naming its line.
//! `--panic-self-test` as the only argument panics on purpose, to show the fatal path, and
//! `--stack-overflow-self-test` overflows the stack on purpose, to show it faults. Both are accessed with semihosting
//! file calls; each call is a trap into QEMU, so input is read and output written in large
//! chunks. The log is written to `OUT.part` and renamed to `OUT` only after a complete run,
//! so a failed run never leaves a log that looks whole. The run report (counts and the
//! instruction cost measured with SysTick) is printed on semihosting stderr as one
//! `key=value` line; QEMU's exit status is the guest's exit code:
//! 0 success, 1 run failed (bad input, I/O), 2 usage, 101 panic, 102 HardFault, 103 watchdog.

// Error messages are formatted into fixed buffers (no allocator), so `Result`s carry them
// inline; they are built only on the way to exit.
#![allow(clippy::result_large_err)]

use core::ffi::CStr;
use core::fmt::Write as _;

use dynacal_core::board_model::{BoardModel, MAX_BOARD_MODEL_LEN};
use dynacal_core::inject::{
    FaultPlan, InjectingSink, InjectingSource, InjectionClock, MAX_PLAN_LEN,
};
use dynacal_core::log::ImuSampleSet;
use dynacal_core::log::{Header, ImuConfig, PpsEvent, IMU_MODEL_LEN, MAX_IMUS, PROTOCOL_VERSION};
use dynacal_core::recorder::{
    Accepted, GnssChunk, LogSink, RecorderError, RecorderStats, SampleSource, SourceEvent,
};
use dynacal_core::replay::{
    decode_header, decode_record, ReplayError, ReplayHeader, ReplayRecord, MAX_HEADER_LEN,
};
use heapless::String;
use semihosting::fs::{File, OpenOptions};
use semihosting::io::{Read as _, Write as _};
use static_cell::StaticCell;

use crate::cost::Calibration;
// The defmt global logger: frames go to semihosting stdout (decode with defmt-print).
use defmt_semihosting as _;

/// Board name written in the log header.
pub const NAME: &str = "replay-qemu-netduinoplus2";

/// Bytes read from the input per semihosting call.
const INPUT_CHUNK: usize = 8 * 1024;
/// Bytes of log collected before one semihosting write.
const OUTPUT_CHUNK: usize = 32 * 1024;
/// Longest host path accepted, bytes (NUL excluded).
const MAX_PATH: usize = 255;

const EXIT_RUN_FAILED: i32 = 1;
const EXIT_USAGE: i32 = 2;
const EXIT_PANIC: i32 = 101;
const EXIT_HARD_FAULT: i32 = 102;

type Path = String<MAX_PATH>;

/// The replay's time since its first event, shared by the fault plan's source and sink.
static INJECTION_CLOCK: InjectionClock = InjectionClock::new();

/// The source and the sink with the fault plan applied, in statics: the plan, its held
/// samples and its generator are kilobytes that would otherwise sit in `main`'s frame, whose
/// stack depth is the real board's bound too.
static SOURCE: StaticCell<InjectingSource<'static, ReplaySource>> = StaticCell::new();
static SINK: StaticCell<InjectingSink<'static, SemihostingSink>> = StaticCell::new();

/// What `main` runs the recorder on.
pub struct Parts {
    pub header: Header,
    pub source: &'static mut InjectingSource<'static, ReplaySource>,
    pub sink: &'static mut InjectingSink<'static, SemihostingSink>,
    /// The model the fusion runs.
    pub model: BoardModel,
}

/// The host paths on the command line.
struct CommandLine {
    input: Path,
    output: Path,
    model: Option<Path>,
    faults: Option<Path>,
}

/// Reads the command line, opens both files and reads the replay header; on any failure
/// prints why and exits.
pub fn init() -> Parts {
    let paths = match command_line() {
        Ok(paths) => paths,
        Err(message) => usage(&message),
    };
    let (header, mut source, sink) = match open(paths.input, paths.output) {
        Ok(parts) => parts,
        Err(message) => fail(&message),
    };
    let plan = match paths.faults.map(|path| read_plan(&path, header.imus.len())) {
        Some(Ok(plan)) => plan,
        Some(Err(message)) => usage(&message),
        None => FaultPlan::default(),
    };
    source.hang_after_us = plan.hang_at_s().map(|s| (s * 1e6) as u64);
    let sink = SINK.init(InjectingSink::new(sink, &plan, &INJECTION_CLOCK));
    let source = SOURCE.init(InjectingSource::new(
        source,
        plan,
        &header.imus,
        &INJECTION_CLOCK,
    ));
    let mut parts = Parts {
        header,
        source,
        sink,
        model: BoardModel {
            units: heapless::Vec::new(),
        },
    };
    let blob = paths.model.map(|path| {
        match read_file::<{ MAX_BOARD_MODEL_LEN + 1 }>(&path, "board model") {
            Ok(blob) => (path, blob),
            Err(message) => usage(&message),
        }
    });
    let ids: heapless::Vec<u8, MAX_IMUS> = parts.header.imus.iter().map(|i| i.imu_id).collect();
    let (model, refused) =
        BoardModel::load_or_built_in(blob.as_ref().map(|(_, b)| b.as_slice()), &ids);
    match (&blob, refused) {
        (Some((path, _)), Some(reason)) => {
            semihosting::eprintln!(
                "dynacal-firmware: board model {path} refused: {reason}; running the built-in model"
            );
        }
        (Some((path, _)), None) => defmt::info!("board model {=str} loaded", path.as_str()),
        (None, _) => defmt::info!("no board model given: running the built-in model"),
    }
    parts.model = model;
    parts
}

fn usage(message: &Message) -> ! {
    semihosting::eprintln!("dynacal-firmware: {message}");
    semihosting::eprintln!(
        "usage: dynacal-firmware REPLAY_INPUT LOG_OUTPUT [BOARD_MODEL] [--faults PLAN]"
    );
    semihosting::process::exit(EXIT_USAGE)
}

/// A small file's bytes, up to `N` (one more than the largest a reader takes, so an
/// oversized file is seen as such rather than read short).
fn read_file<const N: usize>(path: &Path, what: &str) -> Result<heapless::Vec<u8, N>, Message> {
    let mut c_path = [0u8; MAX_PATH + 1];
    let mut file = File::open(c_str(path, &mut c_path))
        .map_err(|e| message(format_args!("{path}: cannot open the {what}: {e}")))?;
    let mut buf = [0u8; N];
    let mut len = 0;
    while len < buf.len() {
        match file.read(&mut buf[len..]) {
            Ok(0) => break,
            Ok(n) => len += n,
            Err(e) => return Err(message(format_args!("{path}: read failed: {e}"))),
        }
    }
    Ok(buf[..len].iter().copied().collect())
}

/// The fault plan at `path`, checked against the replay's `units` IMUs.
fn read_plan(path: &Path, units: usize) -> Result<FaultPlan, Message> {
    let text = read_file::<{ MAX_PLAN_LEN + 1 }>(path, "fault plan")?;
    FaultPlan::parse(&text)
        .and_then(|plan| plan.check_units(units).map(|()| plan))
        .map_err(|e| message(format_args!("{path}: {e}")))
}

fn command_line() -> Result<CommandLine, Message> {
    let args = semihosting::experimental::env::args::<1024>().map_err(|e| {
        message(format_args!(
            "cannot read the semihosting command line: {e}"
        ))
    })?;
    let mut words = (&args).skip(1);
    // None: no more words.
    let mut next_path = |what: &str| -> Option<Result<Path, Message>> {
        let word = words.next()?;
        Some(
            word.map_err(|_| message(format_args!("{what} path is not UTF-8")))
                .and_then(|w| {
                    Path::try_from(w).map_err(|_| {
                        message(format_args!("{what} path longer than {MAX_PATH} bytes"))
                    })
                }),
        )
    };
    let missing = |what: &str| message(format_args!("missing {what} path"));
    let input = next_path("replay input").ok_or_else(|| missing("replay input"))??;
    if input == "--panic-self-test" {
        // The one deliberate panic: it shows that a panic ends the run with failure (exit
        // code 101) instead of hanging the board.
        panic!("self-test: a panic ends the run");
    }
    if input == "--stack-overflow-self-test" {
        // Deliberately deep: the stack runs off the bottom of SRAM (memory.x) and faults,
        // which ends the run with exit code 102, instead of overwriting the statics.
        let depth = overflow_the_stack(0);
        return Err(message(format_args!(
            "the stack did not overflow at depth {depth}"
        )));
    }
    let output = next_path("log output").ok_or_else(|| missing("log output"))??;
    let (mut model, mut faults) = (None, None);
    while let Some(word) = next_path("argument").transpose()? {
        if word == "--faults" {
            faults = Some(next_path("fault plan").ok_or_else(|| missing("fault plan"))??);
        } else if model.is_none() {
            model = Some(word);
        } else {
            return Err(message(format_args!("more than three paths given")));
        }
    }
    Ok(CommandLine {
        input,
        output,
        model,
        faults,
    })
}

/// Recurses with a 1 KiB frame until the stack overflows (see `--stack-overflow-self-test`);
/// returns only if it never does.
#[inline(never)]
fn overflow_the_stack(depth: u32) -> u32 {
    let mut frame = [0u8; 1024];
    frame[depth as usize % 1024] = depth as u8;
    let frame = core::hint::black_box(frame);
    if depth > 1_000 {
        return depth;
    }
    overflow_the_stack(depth + 1) + u32::from(frame[0])
}

fn open(
    input_path: Path,
    output_path: Path,
) -> Result<(Header, ReplaySource, SemihostingSink), Message> {
    let mut c_path = [0u8; MAX_PATH + 1];
    let input = File::open(c_str(&input_path, &mut c_path))
        .map_err(|e| message(format_args!("{input_path}: cannot open: {e}")))?;
    let input_buf = cortex_m::singleton!(: [u8; INPUT_CHUNK] = [0; INPUT_CHUNK])
        .ok_or_else(|| message(format_args!("input buffer taken twice")))?;
    let mut source = ReplaySource {
        file: input,
        path: input_path,
        buf: input_buf,
        start: 0,
        end: 0,
        eof: false,
        buf_offset: 0,
        header: ReplayHeader {
            imus: heapless::Vec::new(),
        },
        imu_records: 0,
        pps_records: 0,
        ended: false,
        first_t_us: None,
        hang_after_us: None,
    };
    source.fill()?;
    let (replay_header, used) = loop {
        match decode_header(source.pending()) {
            Ok(done) => break done,
            Err(ReplayError::Incomplete { .. })
                if !source.eof && source.pending().len() < MAX_HEADER_LEN =>
            {
                source.fill()?
            }
            Err(e) => return Err(message(format_args!("{}: header: {e}", source.path))),
        }
    };
    source.consume(used);
    let header = log_header(&replay_header, &source.path)?;
    source.header = replay_header;

    let part_path = part_path(&output_path)?;
    let output = OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .open(c_str(&part_path, &mut c_path))
        .map_err(|e| message(format_args!("{part_path}: cannot create: {e}")))?;
    let output_buf = cortex_m::singleton!(: [u8; OUTPUT_CHUNK] = [0; OUTPUT_CHUNK])
        .ok_or_else(|| message(format_args!("output buffer taken twice")))?;
    defmt::info!(
        "replay: {=usize} IMU(s), log to {=str}",
        header.imus.len(),
        output_path.as_str()
    );
    let sink = SemihostingSink {
        file: Some(output),
        part_path,
        path: output_path,
        buf: output_buf,
        len: 0,
    };
    Ok((header, source, sink))
}

/// The log header for the IMUs a replay file declares.
fn log_header(replay: &ReplayHeader, path: &str) -> Result<Header, Message> {
    let mut imus = heapless::Vec::new();
    for imu in &replay.imus {
        let mut model = String::<IMU_MODEL_LEN>::new();
        // Both fields hold 16 bytes, so an ASCII model name always fits.
        let _ = model.push_str(imu.model_str());
        imus.push(ImuConfig {
            imu_id: imu.imu_id,
            model,
            sample_rate_hz: imu.sample_rate_hz,
            gyro_scale_rad_s_per_count: imu.gyro_scale_rad_s_per_count,
            accel_scale_m_s2_per_count: imu.accel_scale_m_s2_per_count,
        })
        .map_err(|_| {
            message(format_args!(
                "{path}: {} IMUs declared, the log holds at most {MAX_IMUS}",
                replay.imus.len()
            ))
        })?;
    }
    let mut board = String::new();
    let _ = board.push_str(NAME);
    Ok(Header {
        protocol_version: PROTOCOL_VERSION,
        board,
        imus,
    })
}

fn part_path(output_path: &Path) -> Result<Path, Message> {
    let mut part = output_path.clone();
    part.push_str(".part")
        .map_err(|_| message(format_args!("{output_path}: path too long")))?;
    Ok(part)
}

fn c_str<'a>(path: &str, buf: &'a mut [u8; MAX_PATH + 1]) -> &'a CStr {
    let len = path.len().min(MAX_PATH);
    buf[..len].copy_from_slice(&path.as_bytes()[..len]);
    buf[len] = 0;
    // A path holding a NUL is cut there; the open then fails naming the whole path.
    CStr::from_bytes_until_nul(&buf[..=len]).unwrap_or(c"")
}

/// Sample sets and PPS edges read from the replay input.
pub struct ReplaySource {
    file: File,
    path: Path,
    buf: &'static mut [u8; INPUT_CHUNK],
    /// `buf[start..end]` holds input not yet decoded.
    start: usize,
    end: usize,
    eof: bool,
    /// File offset of `buf[start]`, for error messages.
    buf_offset: u64,
    header: ReplayHeader,
    imu_records: u64,
    pps_records: u64,
    ended: bool,
    first_t_us: Option<u64>,
    /// A planned hang: the main loop stops this long after the first event.
    hang_after_us: Option<u64>,
}

impl ReplaySource {
    fn pending(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    fn consume(&mut self, n: usize) {
        self.start += n;
        self.buf_offset += n as u64;
    }

    /// Moves undecoded bytes to the front and reads until the buffer is full or the file
    /// ends.
    fn fill(&mut self) -> Result<(), Message> {
        self.buf.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        while self.end < INPUT_CHUNK && !self.eof {
            match self.file.read(&mut self.buf[self.end..]) {
                Ok(0) => self.eof = true,
                Ok(n) => self.end += n,
                Err(e) => return Err(message(format_args!("{}: read failed: {e}", self.path))),
            }
        }
        Ok(())
    }

    fn error_at(&self, what: core::fmt::Arguments<'_>) -> Message {
        message(format_args!(
            "{}: byte {}: {what}",
            self.path, self.buf_offset
        ))
    }
}

impl SampleSource for ReplaySource {
    type Error = Message;

    /// Feeds the watchdog each time it is asked, as the real board does.
    fn next_event(&mut self) -> Result<Option<SourceEvent>, Message> {
        let event = self.next_record()?;
        if let Some(event) = &event {
            let t_us = event.t_us();
            crate::soft_watchdog::feed(crate::cost::wraps(), t_us);
            let since_first = t_us - *self.first_t_us.get_or_insert(t_us);
            if self.hang_after_us.is_some_and(|at| since_first >= at) {
                hang();
            }
        }
        Ok(event)
    }
}

/// The main loop stuck for good (a transfer that never completes): it neither returns nor
/// feeds the watchdog.
fn hang() -> ! {
    defmt::warn!("fault plan: the main loop hangs here");
    loop {
        cortex_m::asm::nop();
    }
}

impl ReplaySource {
    /// The next record as an event; None after the end record.
    fn next_record(&mut self) -> Result<Option<SourceEvent>, Message> {
        if self.ended {
            return Ok(None);
        }
        loop {
            let record = match decode_record(self.pending()) {
                Ok((record, used)) => {
                    self.consume(used);
                    record
                }
                Err(ReplayError::Incomplete { .. }) if !self.eof => {
                    self.fill()?;
                    continue;
                }
                Err(ReplayError::Incomplete { .. }) => {
                    return Err(self.error_at(format_args!(
                        "input ends without an end record (truncated file?)"
                    )))
                }
                Err(e) => return Err(self.error_at(format_args!("{e}"))),
            };
            return match record {
                ReplayRecord::Imu {
                    t_us,
                    imu_id,
                    gyro_counts,
                    accel_counts,
                } => {
                    if self.header.imu(imu_id).is_none() {
                        return Err(self.error_at(format_args!(
                            "record names IMU {imu_id}, which the header does not declare"
                        )));
                    }
                    self.imu_records += 1;
                    Ok(Some(SourceEvent::Imu(ImuSampleSet {
                        t_us,
                        imu_id,
                        gyro_counts,
                        accel_counts,
                    })))
                }
                ReplayRecord::Pps { t_us } => {
                    let sequence = self.pps_records as u32;
                    self.pps_records += 1;
                    Ok(Some(SourceEvent::Pps(PpsEvent { t_us, sequence })))
                }
                ReplayRecord::Gnss { t_us, len, data } => {
                    Ok(Some(SourceEvent::Gnss(GnssChunk { t_us, len, data })))
                }
                ReplayRecord::End {
                    imu_sample_sets,
                    pps_edges,
                } => {
                    if (imu_sample_sets, pps_edges) != (self.imu_records, self.pps_records) {
                        return Err(self.error_at(format_args!(
                            "end record counts {imu_sample_sets} IMU and {pps_edges} PPS records, \
                             the file holds {} and {}",
                            self.imu_records, self.pps_records
                        )));
                    }
                    if self.start == self.end {
                        self.fill()?;
                    }
                    if self.start != self.end {
                        return Err(self.error_at(format_args!("bytes after the end record")));
                    }
                    self.ended = true;
                    Ok(None)
                }
            };
        }
    }
}

/// The log, collected in large chunks and written to a host file.
pub struct SemihostingSink {
    file: Option<File>,
    part_path: Path,
    path: Path,
    buf: &'static mut [u8; OUTPUT_CHUNK],
    len: usize,
}

impl SemihostingSink {
    fn write_out(&mut self) -> Result<(), Message> {
        let Some(file) = self.file.as_mut() else {
            return Err(message(format_args!(
                "{}: written after close",
                self.part_path
            )));
        };
        file.write_all(&self.buf[..self.len])
            .map_err(|e| message(format_args!("{}: write failed: {e}", self.part_path)))?;
        self.len = 0;
        Ok(())
    }

    /// Closes the log and gives it its final name.
    fn commit(&mut self) -> Result<(), Message> {
        self.write_out()?;
        drop(self.file.take());
        let mut from = [0u8; MAX_PATH + 1];
        let mut to = [0u8; MAX_PATH + 1];
        semihosting::fs::rename(
            c_str(&self.part_path, &mut from),
            c_str(&self.path, &mut to),
        )
        .map_err(|e| {
            message(format_args!(
                "cannot rename {} to {}: {e}",
                self.part_path, self.path
            ))
        })
    }
}

impl LogSink for SemihostingSink {
    type Error = Message;

    fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, Message> {
        if self.len + frame.len() > OUTPUT_CHUNK {
            self.write_out()?;
        }
        // A frame is far shorter than the chunk, so it fits after a write-out.
        self.buf[self.len..self.len + frame.len()].copy_from_slice(frame);
        self.len += frame.len();
        Ok(Accepted::Written)
    }

    fn flush(&mut self) -> Result<(), Message> {
        self.write_out()
    }
}

/// Reports the run and exits with its status.
pub fn finish(
    result: Result<RecorderStats, RecorderError<Message, Message>>,
    calibration: &Calibration,
    sink: &mut InjectingSink<'static, SemihostingSink>,
) -> ! {
    let sink = sink.inner_mut();
    let stats = match result {
        Ok(stats) => stats,
        Err(RecorderError::Source(m)) | Err(RecorderError::Sink(m)) => fail(&m),
        Err(RecorderError::Encode(e)) => fail(&message(format_args!("log encoding failed: {e}"))),
        Err(RecorderError::UnknownImu { imu_id, t_us }) => fail(&message(format_args!(
            "sample at t_us={t_us} names IMU {imu_id}, which the header does not declare"
        ))),
        Err(RecorderError::TimeWentBackwards {
            t_us,
            previous_t_us,
        }) => fail(&message(format_args!(
            "time went backwards: t_us={t_us} after t_us={previous_t_us}"
        ))),
    };
    if let Err(m) = sink.commit() {
        fail(&m)
    }
    // Painted stack worn down to the statics: the run may have overwritten them.
    if crate::stack::low_water() <= crate::stack::floor() {
        fail(&message(format_args!(
            "the stack reached the statics ({} bytes of stack, {} of statics): the run is not to be trusted",
            crate::stack::peak_bytes(),
            crate::stack::static_bytes()
        )))
    }
    let mut line = String::<640>::new();
    let _ = write!(
        line,
        "dynacal-firmware: run-report board={NAME} imu_sample_sets={} pps_edges={} \
         gnss_fixes={} gnss_frames_refused={} \
         health_reports={} filter_states={} noise_reports={} fault_reports={} \
         frames_written={} bytes_written={} frames_dropped={} \
         record_instructions={} source_instructions={} total_instructions={} \
         fusion_instructions={} navigating_fusion_instructions={} navigating_sample_sets={} \
         stack_peak_bytes={} static_bytes={} \
         calibration_instructions={} calibration_ticks={}",
        stats.total_imu_sample_sets(),
        stats.pps_edges,
        stats.gnss_fixes,
        stats.gnss_frames_refused,
        stats.health_reports,
        stats.filter_states,
        stats.noise_reports,
        stats.fault_reports,
        stats.frames_written,
        stats.bytes_written,
        stats.frames_dropped,
        calibration.instructions(stats.record_ticks),
        calibration.instructions(stats.source_ticks),
        calibration.instructions(stats.total_ticks),
        calibration.instructions(stats.fusion_ticks),
        calibration.instructions(stats.navigating_fusion_ticks),
        stats.navigating_sample_sets,
        crate::stack::peak_bytes(),
        crate::stack::static_bytes(),
        calibration.instructions,
        calibration.ticks,
    );
    semihosting::eprintln!("{line}");
    defmt::info!(
        "run complete: {=u64} sample sets",
        stats.total_imu_sample_sets()
    );
    semihosting::process::exit(0)
}

/// Prints `message` on stderr and exits with the run-failed code.
fn fail(message: &Message) -> ! {
    semihosting::eprintln!("dynacal-firmware: error: {message}");
    defmt::error!("run failed");
    semihosting::process::exit(EXIT_RUN_FAILED)
}

pub fn fatal(what: &str) -> ! {
    semihosting::eprintln!("dynacal-firmware: fatal: {what}");
    semihosting::process::exit(EXIT_RUN_FAILED)
}

pub fn fatal_panic(info: &core::panic::PanicInfo) -> ! {
    semihosting::eprintln!("dynacal-firmware: panic: {info}");
    semihosting::process::exit(EXIT_PANIC)
}

pub fn fatal_hard_fault(pc: u32) -> ! {
    semihosting::eprintln!("dynacal-firmware: HardFault at pc=0x{pc:08x}");
    semihosting::process::exit(EXIT_HARD_FAULT)
}

/// An error message, formatted on the board (no allocator).
pub type Message = String<320>;

fn message(args: core::fmt::Arguments<'_>) -> Message {
    let mut m = Message::new();
    // A message longer than the buffer is cut, which still names the file first.
    let _ = m.write_fmt(args);
    m
}
