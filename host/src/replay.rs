//! Replay inputs for the firmware's `board-replay` board, and the harness that runs that
//! firmware under QEMU.
//!
//! A replay input is a sensor recording in the board's own terms: raw integer counts per
//! IMU sample set, stamped in microseconds, with PPS edges between them, after a header of
//! IMU scale factors. The byte layout is `dynacal_core::replay` (shared with the firmware,
//! documented in `firmware/README.md`); this module builds inputs from raw counts, and from
//! the ADIS16405 recordings in the data folder, writes them whole or not at all, builds the
//! replay firmware with cargo, runs it in `qemu-system-arm`, and reads its run report.
//!
//! ADIS16405 scale factors: the data sheet gives 0.05 deg/s and 0.00333 g per count; they
//! are converted to SI with deg = pi/180 rad and the standard gravity g = 9.80665 m/s^2
//! ([`ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT`], [`ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT`]).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use dynacal_core::replay::{
    encode_header, encode_record, ReplayError, ReplayHeader, ReplayImu, ReplayRecord,
    MAX_RECORD_LEN,
};

use crate::interchange::{open_maybe_gz, CHANNELS};

/// The emulated board and deterministic clock every firmware run uses: an STM32F405
/// (`netduinoplus2`), no display, monitor or serial, and `-icount shift=0` so the virtual
/// clock advances one nanosecond per instruction (instruction counts are reproducible).
pub const QEMU_BOARD_ARGS: [&str; 11] = [
    "-cpu",
    "cortex-m4",
    "-machine",
    "netduinoplus2",
    "-nographic",
    "-monitor",
    "none",
    "-serial",
    "none",
    "-icount",
    "shift=0",
];

/// The board's target (a Cortex-M4F: floats in hardware).
pub const BOARD_TARGET: &str = "thumbv7em-none-eabihf";
/// A core without an FPU (a Cortex-M3), for the fixed-point filter's board.
pub const FPU_LESS_TARGET: &str = "thumbv7m-none-eabi";

/// QEMU's arguments for an image built for `target`: [`QEMU_BOARD_ARGS`], or for
/// [`FPU_LESS_TARGET`] a Cortex-M3 in `netduino2` (an STM32F205: the F405's flash and SRAM
/// addresses, so the firmware's one memory map serves).
pub fn qemu_board_args(target: &str) -> [&'static str; 11] {
    let mut args = QEMU_BOARD_ARGS;
    if target == FPU_LESS_TARGET {
        args[1] = "cortex-m3";
        args[3] = "netduino2";
    }
    args
}

/// The target an image at `elf` was built for, read from its path under the target
/// directory (`.../TARGET/PROFILE/NAME`); the board's when the path does not say.
fn target_of(elf: &Path) -> &'static str {
    let built_for = |target: &str| elf.components().any(|c| c.as_os_str() == target);
    if built_for(FPU_LESS_TARGET) {
        FPU_LESS_TARGET
    } else {
        BOARD_TARGET
    }
}

/// Standard gravity, m/s^2 (the conventional value, as the ADIS16405 "g" is taken to be).
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;
/// ADIS16405 gyro scale: 0.05 deg/s per count, in rad/s per count.
pub const ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT: f64 = 0.05 * std::f64::consts::PI / 180.0;
/// ADIS16405 accelerometer scale: 0.00333 g per count, in m/s^2 per count.
pub const ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT: f64 = 0.00333 * STANDARD_GRAVITY_M_S2;
/// ADIS16405 session sample rate, Hz.
pub const ADIS16405_RATE_HZ: f32 = 100.0;
/// The IMU id given to the ADIS16405 in a replay input.
pub const ADIS16405_IMU_ID: u8 = 0;

/// Errors building, writing or running a replay.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReplayFileError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: line {line}: {message}")]
    Csv {
        path: PathBuf,
        line: u64,
        message: String,
    },
    #[error("{path}: line 1: missing column `{column}`")]
    MissingColumn { path: PathBuf, column: String },
    #[error("{path}: line {line}, column `{column}`: `{value}` is not an integer count")]
    NotACount {
        path: PathBuf,
        line: u64,
        column: String,
        value: String,
    },
    #[error("{path}: holds {available} samples, {wanted} wanted")]
    TooFewSamples {
        path: PathBuf,
        available: usize,
        wanted: usize,
    },
    #[error("replay header: {0}")]
    Header(ReplayError),
    #[error("record {index}: IMU {imu_id} is not declared in the header")]
    UnknownImu { index: usize, imu_id: u8 },
    #[error("record {index}: t_us={t_us} is before the previous record's t_us={previous_t_us}")]
    TimeNotIncreasing {
        index: usize,
        t_us: u64,
        previous_t_us: u64,
    },
    #[error("record {index}: an end record is written by the encoder, not given")]
    EndRecordGiven { index: usize },
    #[error("{0}")]
    Tool(String),
}

/// A complete replay input held in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayInput {
    pub header: ReplayHeader,
    /// IMU, PPS and GNSS records in time order (no end record: [`ReplayInput::encode`] adds
    /// it).
    pub records: Vec<ReplayRecord>,
}

/// One IMU sample set in raw counts, as read from a recording.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CountSample {
    pub t_us: u64,
    pub imu_id: u8,
    pub gyro_counts: [i32; 3],
    pub accel_counts: [i32; 3],
}

impl ReplayInput {
    /// A replay of raw count samples (in time order) with PPS edges at every whole second
    /// of `t_us` from the first sample's second up to the last sample; a PPS edge sorts
    /// before a sample with the same timestamp.
    pub fn from_counts(
        imus: &[ReplayImu],
        samples: &[CountSample],
    ) -> Result<Self, ReplayFileError> {
        let header = ReplayHeader::new(imus).map_err(ReplayFileError::Header)?;
        let mut records = Vec::with_capacity(samples.len() + samples.len() / 50 + 2);
        let mut next_pps_t_us = samples
            .first()
            .map_or(0, |s| s.t_us.div_ceil(1_000_000) * 1_000_000);
        for s in samples {
            while next_pps_t_us <= s.t_us {
                records.push(ReplayRecord::Pps {
                    t_us: next_pps_t_us,
                });
                next_pps_t_us += 1_000_000;
            }
            records.push(ReplayRecord::Imu {
                t_us: s.t_us,
                imu_id: s.imu_id,
                gyro_counts: s.gyro_counts,
                accel_counts: s.accel_counts,
            });
        }
        let input = ReplayInput { header, records };
        input.validate()?;
        Ok(input)
    }

    /// Checks what the firmware would reject: undeclared IMUs, time going backwards, an
    /// explicit end record.
    pub fn validate(&self) -> Result<(), ReplayFileError> {
        let mut buf = [0u8; dynacal_core::replay::MAX_HEADER_LEN];
        encode_header(&self.header, &mut buf).map_err(ReplayFileError::Header)?;
        let mut previous_t_us = 0u64;
        for (index, record) in self.records.iter().enumerate() {
            let t_us = match *record {
                ReplayRecord::Imu { t_us, imu_id, .. } => {
                    if self.header.imu(imu_id).is_none() {
                        return Err(ReplayFileError::UnknownImu { index, imu_id });
                    }
                    t_us
                }
                ReplayRecord::Pps { t_us } | ReplayRecord::Gnss { t_us, .. } => t_us,
                ReplayRecord::End { .. } => return Err(ReplayFileError::EndRecordGiven { index }),
            };
            if t_us < previous_t_us {
                return Err(ReplayFileError::TimeNotIncreasing {
                    index,
                    t_us,
                    previous_t_us,
                });
            }
            previous_t_us = t_us;
        }
        Ok(())
    }

    /// IMU sample sets in the replay, in order.
    pub fn samples(&self) -> impl Iterator<Item = CountSample> + '_ {
        self.records.iter().filter_map(|r| match *r {
            ReplayRecord::Imu {
                t_us,
                imu_id,
                gyro_counts,
                accel_counts,
            } => Some(CountSample {
                t_us,
                imu_id,
                gyro_counts,
                accel_counts,
            }),
            _ => None,
        })
    }

    /// PPS edge times in the replay, microseconds.
    pub fn pps_t_us(&self) -> impl Iterator<Item = u64> + '_ {
        self.records.iter().filter_map(|r| match *r {
            ReplayRecord::Pps { t_us } => Some(t_us),
            _ => None,
        })
    }

    /// The replay file's bytes: header, records, end record.
    pub fn encode(&self) -> Result<Vec<u8>, ReplayFileError> {
        self.validate()?;
        let mut out = vec![0u8; self.header.encoded_len()];
        encode_header(&self.header, &mut out).map_err(ReplayFileError::Header)?;
        out.reserve(self.records.len() * MAX_RECORD_LEN + MAX_RECORD_LEN);
        let mut buf = [0u8; MAX_RECORD_LEN];
        let end = ReplayRecord::End {
            imu_sample_sets: self.samples().count() as u64,
            pps_edges: self.pps_t_us().count() as u64,
        };
        for record in self.records.iter().chain(std::iter::once(&end)) {
            let n = encode_record(record, &mut buf).map_err(ReplayFileError::Header)?;
            out.extend_from_slice(&buf[..n]);
        }
        Ok(out)
    }

    /// Writes the replay file whole or not at all.
    pub fn write(&self, path: &Path) -> Result<(), ReplayFileError> {
        let bytes = self.encode()?;
        crate::output::write_atomic(path, &bytes).map_err(|source| ReplayFileError::Io {
            path: path.to_path_buf(),
            source,
        })
    }
}

/// The ADIS16405 as a replay header entry.
pub fn adis16405_imu() -> ReplayImu {
    ReplayImu {
        imu_id: ADIS16405_IMU_ID,
        model: ReplayImu::model_field("ADIS16405").unwrap_or([0; 16]),
        sample_rate_hz: ADIS16405_RATE_HZ,
        gyro_scale_rad_s_per_count: ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT,
        accel_scale_m_s2_per_count: ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT,
    }
}

/// The ADIS16405 session file `session{n}.csv.gz` under `data_dir`.
pub fn adis16405_session_path(data_dir: &Path, session: u32) -> PathBuf {
    data_dir
        .join("adis16405")
        .join(format!("session{session}.csv.gz"))
}

/// Reads the first `samples` rows of an ADIS16405 session (columns `gx,gy,gz,ax,ay,az`,
/// integer counts, 100 Hz, t = row / 100 s) as count samples of IMU
/// [`ADIS16405_IMU_ID`], stamped `t_us = row * 10_000`.
pub fn read_adis16405_counts(
    path: &Path,
    samples: usize,
) -> Result<Vec<CountSample>, ReplayFileError> {
    let reader = open_maybe_gz(path).map_err(|e| ReplayFileError::Tool(e.to_string()))?;
    let mut csv = crate::interchange::csv_reader(reader, false);
    let csv_err = |e: csv::Error| ReplayFileError::Csv {
        path: path.to_path_buf(),
        line: e.position().map_or(0, |p| p.line()),
        message: e.to_string(),
    };
    let headers = csv.headers().map_err(csv_err)?.clone();
    let mut columns = [0usize; 6];
    for (slot, name) in CHANNELS.iter().enumerate() {
        columns[slot] = headers.iter().position(|h| h == *name).ok_or_else(|| {
            ReplayFileError::MissingColumn {
                path: path.to_path_buf(),
                column: (*name).to_string(),
            }
        })?;
    }
    let period_us = (1e6 / ADIS16405_RATE_HZ as f64) as u64;
    let mut out = Vec::with_capacity(samples);
    let mut record = csv::StringRecord::new();
    while out.len() < samples && csv.read_record(&mut record).map_err(csv_err)? {
        let line = record.position().map_or(0, |p| p.line());
        let mut counts = [0i32; 6];
        for (slot, &column) in columns.iter().enumerate() {
            let raw = record.get(column).unwrap_or("");
            counts[slot] = raw.parse().map_err(|_| ReplayFileError::NotACount {
                path: path.to_path_buf(),
                line,
                column: CHANNELS[slot].to_string(),
                value: raw.to_string(),
            })?;
        }
        out.push(CountSample {
            t_us: out.len() as u64 * period_us,
            imu_id: ADIS16405_IMU_ID,
            gyro_counts: [counts[0], counts[1], counts[2]],
            accel_counts: [counts[3], counts[4], counts[5]],
        });
    }
    if out.len() < samples {
        return Err(ReplayFileError::TooFewSamples {
            path: path.to_path_buf(),
            available: out.len(),
            wanted: samples,
        });
    }
    Ok(out)
}

/// The first `seconds` of an ADIS16405 session as a replay input, PPS once per second.
pub fn adis16405_replay(path: &Path, seconds: u32) -> Result<ReplayInput, ReplayFileError> {
    let samples = read_adis16405_counts(path, seconds as usize * ADIS16405_RATE_HZ as usize)?;
    ReplayInput::from_counts(&[adis16405_imu()], &samples)
}

/// Cargo target folder (under the workspace root) for firmware builds made by tools and
/// tests: separate from `target/` so a build started from inside `cargo test` does not wait
/// on the lock of the build that is running it.
pub const FIRMWARE_TARGET_DIR: &str = "target/firmware";

/// Core clock of the real board's Cortex-M4F (STM32F405), Hz: the budget instruction counts
/// under emulation are a share of.
pub const BOARD_CORE_HZ: f64 = 168e6;

/// Cargo profile of both boards' firmware (`[profile.firmware]` in the workspace's
/// `Cargo.toml`: speed where the samples run, size elsewhere, so the real board's image fits
/// its flash).
pub const FIRMWARE_PROFILE: &str = "firmware";

/// The workspace root (where `Cargo.toml`, `memory.x` and `firmware/` are).
pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
}

/// Whether `qemu-system-arm` can be started.
pub fn qemu_available() -> bool {
    Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Builds the replay firmware ([`FIRMWARE_PROFILE`], `board-replay`) with cargo into
/// `target_dir` and returns the ELF's path. A separate target directory keeps this build
/// from waiting on the lock of the host build that is running it.
pub fn build_replay_firmware(target_dir: &Path) -> Result<PathBuf, ReplayFileError> {
    build_firmware(target_dir, "board-replay")
}

/// The replay board's firmware image built with this crate (`host/build.rs`), empty when it
/// could not be built then.
static EMBEDDED_REPLAY_FIRMWARE: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/replay-firmware.elf"));

/// The replay board's firmware ELF embedded in this binary at build time, if it was.
pub fn embedded_replay_firmware() -> Option<&'static [u8]> {
    (!EMBEDDED_REPLAY_FIRMWARE.is_empty()).then_some(EMBEDDED_REPLAY_FIRMWARE)
}

/// The replay firmware to run under QEMU: the image embedded at build time, written to
/// `dir/dynacal-replay-firmware.elf`; or, in a binary built without it, the firmware built
/// now with cargo into `target_dir` (which needs the source tree and the
/// thumbv7em-none-eabihf target).
pub fn replay_firmware_elf(dir: &Path, target_dir: &Path) -> Result<PathBuf, ReplayFileError> {
    match embedded_replay_firmware() {
        Some(image) => {
            let path = dir.join("dynacal-replay-firmware.elf");
            crate::output::write_atomic(&path, image).map_err(|source| ReplayFileError::Io {
                path: path.clone(),
                source,
            })?;
            Ok(path)
        }
        None => build_replay_firmware(target_dir),
    }
}

/// Builds the firmware for one board (`board_feature`: `board-replay`, the emulated board, or
/// `board-stm32f405`, the real one) with cargo into `target_dir` and returns the ELF's path.
/// Both boards' images land at the same path: read one before building the other.
pub fn build_firmware(target_dir: &Path, board_feature: &str) -> Result<PathBuf, ReplayFileError> {
    build_firmware_for(target_dir, board_feature, BOARD_TARGET)
}

/// As [`build_firmware`], with `features` (comma-separated) for `target` ([`BOARD_TARGET`]
/// or [`FPU_LESS_TARGET`]).
pub fn build_firmware_for(
    target_dir: &Path,
    features: &str,
    target: &str,
) -> Result<PathBuf, ReplayFileError> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let root = workspace_root();
    let output = Command::new(cargo)
        .current_dir(&root)
        .args([
            "build",
            "-p",
            "dynacal-firmware",
            "--profile",
            FIRMWARE_PROFILE,
            "--target",
            target,
            "--features",
            features,
            "--target-dir",
        ])
        .arg(target_dir)
        .output()
        .map_err(|e| ReplayFileError::Tool(format!("cannot run cargo: {e}")))?;
    if !output.status.success() {
        return Err(ReplayFileError::Tool(format!(
            "building the firmware ({features}) failed (is the {target} target \
             installed? run scripts/setup):\n{}",
            String::from_utf8_lossy(&output.stderr)
        )));
    }
    Ok(target_dir
        .join(target)
        .join(FIRMWARE_PROFILE)
        .join("dynacal-firmware"))
}

/// What the firmware reported at the end of a successful run (one `key=value` line on
/// semihosting stderr). Instruction counts come from SysTick under `-icount shift=0`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RunReport {
    pub imu_sample_sets: u64,
    pub pps_edges: u64,
    /// Receiver solutions logged, and receiver frames refused (corrupted bytes).
    pub gnss_fixes: u64,
    pub gnss_frames_refused: u64,
    pub health_reports: u64,
    /// Filter, Noise and Fault frames of the on-board fusion.
    pub filter_states: u64,
    pub noise_reports: u64,
    pub fault_reports: u64,
    pub frames_written: u64,
    pub bytes_written: u64,
    pub frames_dropped: u64,
    /// Instructions spent framing events and handing them to the log sink.
    pub record_instructions: u64,
    /// Instructions spent fetching events from the replay source (decoding the input).
    pub source_instructions: u64,
    /// Instructions from the log header to the final flush.
    pub total_instructions: u64,
    /// Instructions in the fusion (part of `record_instructions`), and of those the ones
    /// while its filter ran, over `navigating_sample_sets` sample sets.
    pub fusion_instructions: u64,
    pub navigating_fusion_instructions: u64,
    pub navigating_sample_sets: u64,
    /// The deepest the stack went (painted at start-up), and the statics, bytes.
    pub stack_peak_bytes: u64,
    pub static_bytes: u64,
}

impl RunReport {
    /// Finds and parses the run-report line in the firmware's stderr.
    pub fn parse(stderr: &str) -> Option<RunReport> {
        let line = stderr
            .lines()
            .find(|l| l.starts_with("dynacal-firmware: run-report "))?;
        let mut report = RunReport::default();
        let mut seen = 0;
        for field in line.split_whitespace() {
            let Some((key, value)) = field.split_once('=') else {
                continue;
            };
            let slot = match key {
                "imu_sample_sets" => &mut report.imu_sample_sets,
                "pps_edges" => &mut report.pps_edges,
                "gnss_fixes" => &mut report.gnss_fixes,
                "gnss_frames_refused" => &mut report.gnss_frames_refused,
                "health_reports" => &mut report.health_reports,
                "filter_states" => &mut report.filter_states,
                "noise_reports" => &mut report.noise_reports,
                "fault_reports" => &mut report.fault_reports,
                "frames_written" => &mut report.frames_written,
                "bytes_written" => &mut report.bytes_written,
                "frames_dropped" => &mut report.frames_dropped,
                "record_instructions" => &mut report.record_instructions,
                "source_instructions" => &mut report.source_instructions,
                "total_instructions" => &mut report.total_instructions,
                "fusion_instructions" => &mut report.fusion_instructions,
                "navigating_fusion_instructions" => &mut report.navigating_fusion_instructions,
                "navigating_sample_sets" => &mut report.navigating_sample_sets,
                "stack_peak_bytes" => &mut report.stack_peak_bytes,
                "static_bytes" => &mut report.static_bytes,
                _ => continue,
            };
            *slot = value.parse().ok()?;
            seen += 1;
        }
        (seen == 19).then_some(report)
    }

    /// Instructions per IMU sample set in the application's own work (framing + sink).
    pub fn record_instructions_per_sample(&self) -> f64 {
        self.record_instructions as f64 / self.imu_sample_sets.max(1) as f64
    }

    /// Instructions per second of data of the board's own work with its filter running:
    /// recording (framing, accumulators, log sink) at its mean over the run, and the
    /// fusion's cost per sample set while navigating, at `sample_rate_hz` sets a second.
    /// None before the filter ever ran.
    pub fn steady_instructions_per_second(&self, span_s: f64, sample_rate_hz: f64) -> Option<f64> {
        if self.navigating_sample_sets == 0 || span_s <= 0.0 {
            return None;
        }
        let recording = self
            .record_instructions
            .saturating_sub(self.fusion_instructions);
        let fusion_per_set =
            self.navigating_fusion_instructions as f64 / self.navigating_sample_sets as f64;
        Some(recording as f64 / span_s + fusion_per_set * sample_rate_hz)
    }

    /// Instructions per IMU sample set over the whole run (source, framing, sink).
    pub fn total_instructions_per_sample(&self) -> f64 {
        self.total_instructions as f64 / self.imu_sample_sets.max(1) as f64
    }
}

/// A completed QEMU run of the replay firmware.
#[derive(Debug, Clone)]
pub struct QemuRun {
    pub report: RunReport,
    /// The firmware's plain-text messages.
    pub stderr: String,
    /// The firmware's defmt frames (binary; decode with `defmt-print -e ELF`).
    pub defmt: Vec<u8>,
    /// Host wall-clock time of the QEMU run.
    pub wall_time: Duration,
}

impl QemuRun {
    /// The firmware's refusal of the board model it was given (it then ran its built-in
    /// one), if it refused it: the line `board model PATH refused: REASON; ...`.
    pub fn model_refusal(&self) -> Option<&str> {
        self.stderr
            .lines()
            .find(|l| l.starts_with("dynacal-firmware: board model ") && l.contains(" refused: "))
    }
}

/// Runs the replay firmware `elf` in QEMU on `input`, writing the log to `log`, the fusion
/// running `model` (a `board-model.bin`; None: the built-in model). Paths must not contain
/// spaces: semihosting joins arguments with them. Fails unless the guest exits 0 and
/// prints its run report.
pub fn run_replay_in_qemu(
    elf: &Path,
    input: &Path,
    log: &Path,
    model: Option<&Path>,
) -> Result<QemuRun, ReplayFileError> {
    run_replay_with_faults_in_qemu(elf, input, log, model, None)
}

/// As [`run_replay_in_qemu`], with the board faults of the plan at `faults`
/// (`dynacal_core::inject`) injected on the board.
pub fn run_replay_with_faults_in_qemu(
    elf: &Path,
    input: &Path,
    log: &Path,
    model: Option<&Path>,
    faults: Option<&Path>,
) -> Result<QemuRun, ReplayFileError> {
    for path in [elf, input, log].into_iter().chain(model).chain(faults) {
        if path.to_string_lossy().contains([' ', '\t']) {
            return Err(ReplayFileError::Tool(format!(
                "{}: semihosting cannot pass a path containing a space",
                path.display()
            )));
        }
    }
    let arg = |p: &Path| p.to_string_lossy().replace(',', ",,");
    let mut semihosting = format!(
        "enable=on,target=native,arg=dynacal-firmware,arg={},arg={}",
        arg(input),
        arg(log)
    );
    if let Some(model) = model {
        semihosting.push_str(&format!(",arg={}", arg(model)));
    }
    if let Some(faults) = faults {
        semihosting.push_str(&format!(",arg=--faults,arg={}", arg(faults)));
    }
    // The firmware writes LOG.part and renames it to LOG after a complete run; a signal
    // or a failed run must not leave the part behind.
    let mut part = log.as_os_str().to_owned();
    part.push(".part");
    let _part = crate::output::PartialPath::register(Path::new(&part));
    let started = Instant::now();
    let output = Command::new("qemu-system-arm")
        .args(qemu_board_args(target_of(elf)))
        .arg("-semihosting-config")
        .arg(semihosting)
        .arg("-kernel")
        .arg(elf)
        .output()
        .map_err(|e| {
            ReplayFileError::Tool(format!(
                "cannot run qemu-system-arm ({e}); run scripts/setup to install it"
            ))
        })?;
    let wall_time = started.elapsed();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    if !output.status.success() {
        return Err(ReplayFileError::Tool(format!(
            "the replay firmware failed ({}):\n{stderr}",
            output.status
        )));
    }
    let report = RunReport::parse(&stderr).ok_or_else(|| {
        ReplayFileError::Tool(format!(
            "the replay firmware printed no run report:\n{stderr}"
        ))
    })?;
    Ok(QemuRun {
        report,
        stderr,
        defmt: output.stdout,
        wall_time,
    })
}

/// How a decoded board log compares with the replay input it was recorded from.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayCheck {
    /// IMU sample sets in the replay input.
    pub samples_expected: usize,
    /// Sample sets in the log whose time and counts equal the input's, in order, and whose
    /// interchange values are bit-for-bit `counts as f64 * scale`.
    pub samples_exact: usize,
    pub pps_expected: usize,
    /// PPS frames in the log with the input's time and the expected sequence number.
    pub pps_exact: usize,
    /// Frames the decoder could not read (CRC, COBS, truncation) plus frames the board
    /// reported dropped in its last Health frame.
    pub frames_dropped: u64,
    /// The first few differences, described.
    pub mismatches: Vec<String>,
}

impl ReplayCheck {
    /// Everything arrived, exactly, with nothing dropped.
    pub fn is_exact(&self) -> bool {
        self.mismatches.is_empty()
            && self.samples_exact == self.samples_expected
            && self.pps_exact == self.pps_expected
            && self.frames_dropped == 0
    }
}

/// Compares a decoded log with the replay input it was recorded from: header scale factors,
/// every sample's time and counts, the interchange values derived from them (bit for bit),
/// PPS times and sequence numbers, and dropped frames.
pub fn check_log_against_replay(
    input: &ReplayInput,
    log: &crate::decode::DecodedLog,
) -> ReplayCheck {
    const MAX_REPORTED: usize = 8;
    let mut check = ReplayCheck {
        samples_expected: input.samples().count(),
        pps_expected: input.pps_t_us().count(),
        frames_dropped: log.stream.frames_dropped
            + log.health.last().map_or(0, |h| u64::from(h.frames_dropped)),
        ..Default::default()
    };
    let mismatch = |check: &mut ReplayCheck, what: String| {
        if check.mismatches.len() < MAX_REPORTED {
            check.mismatches.push(what);
        }
    };
    if log.stream.bytes_dropped > 0 {
        let what = format!(
            "{} log bytes could not be decoded",
            log.stream.bytes_dropped
        );
        mismatch(&mut check, what);
    }
    for imu in &input.header.imus {
        let Some(stream) = log.imus.iter().find(|s| s.config.imu_id == imu.imu_id) else {
            mismatch(
                &mut check,
                format!("IMU {} missing from the log header", imu.imu_id),
            );
            continue;
        };
        let config = &stream.config;
        if config.gyro_scale_rad_s_per_count.to_bits() != imu.gyro_scale_rad_s_per_count.to_bits()
            || config.accel_scale_m_s2_per_count.to_bits()
                != imu.accel_scale_m_s2_per_count.to_bits()
            || config.sample_rate_hz.to_bits() != imu.sample_rate_hz.to_bits()
            || config.model.as_str() != imu.model_str()
        {
            mismatch(
                &mut check,
                format!("IMU {}: header config differs: {config:?}", imu.imu_id),
            );
        }
        let expected: Vec<CountSample> =
            input.samples().filter(|s| s.imu_id == imu.imu_id).collect();
        if stream.len() != expected.len() {
            let what = format!(
                "IMU {}: {} samples in the log, {} in the input",
                imu.imu_id,
                stream.len(),
                expected.len()
            );
            mismatch(&mut check, what);
        }
        let recording = stream.to_recording();
        let (Some(gyro), Some(accel)) = (&recording.gyro_rad_s, &recording.accel_m_s2) else {
            mismatch(
                &mut check,
                format!("IMU {}: no gyro or accel channels", imu.imu_id),
            );
            continue;
        };
        for (i, want) in expected.iter().enumerate().take(stream.len()) {
            let counts_equal = stream.t_us[i] == want.t_us
                && stream.gyro_counts[i] == want.gyro_counts
                && stream.accel_counts[i] == want.accel_counts;
            let si_equal = (0..3).all(|axis| {
                gyro[axis][i].to_bits()
                    == (want.gyro_counts[axis] as f64 * imu.gyro_scale_rad_s_per_count).to_bits()
                    && accel[axis][i].to_bits()
                        == (want.accel_counts[axis] as f64 * imu.accel_scale_m_s2_per_count)
                            .to_bits()
            });
            if counts_equal && si_equal {
                check.samples_exact += 1;
            } else {
                let what = format!(
                    "IMU {} sample {i}: log t_us={} gyro={:?} accel={:?}, input {want:?}",
                    imu.imu_id, stream.t_us[i], stream.gyro_counts[i], stream.accel_counts[i]
                );
                mismatch(&mut check, what);
            }
        }
    }
    let expected_pps: Vec<u64> = input.pps_t_us().collect();
    if log.pps.len() != expected_pps.len() {
        let what = format!(
            "{} PPS frames in the log, {} in the input",
            log.pps.len(),
            expected_pps.len()
        );
        mismatch(&mut check, what);
    }
    for (k, (pps, &t_us)) in log.pps.iter().zip(&expected_pps).enumerate() {
        if pps.t_us == t_us && pps.sequence as usize == k {
            check.pps_exact += 1;
        } else {
            mismatch(
                &mut check,
                format!("PPS {k}: log {pps:?}, input t_us={t_us}"),
            );
        }
    }
    check
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynacal_core::replay::{decode_header, decode_record};

    fn sample(t_us: u64, imu_id: u8, k: i32) -> CountSample {
        CountSample {
            t_us,
            imu_id,
            gyro_counts: [k, -k, i32::MAX - k],
            accel_counts: [i32::MIN + k, 7, -305],
        }
    }

    #[test]
    fn replay_bytes_decode_back_to_the_samples_with_pps_each_second() {
        let samples: Vec<_> = (0..250).map(|k| sample(k as u64 * 10_000, 0, k)).collect();
        let input = ReplayInput::from_counts(&[adis16405_imu()], &samples).unwrap();
        // 0 .. 2.49 s: PPS at 0, 1 and 2 s, each before the sample at the same time.
        assert_eq!(
            input.pps_t_us().collect::<Vec<_>>(),
            [0, 1_000_000, 2_000_000]
        );
        assert_eq!(input.records[0], ReplayRecord::Pps { t_us: 0 });
        assert_eq!(input.records[101], ReplayRecord::Pps { t_us: 1_000_000 });
        let bytes = input.encode().unwrap();
        let (header, mut at) = decode_header(&bytes).unwrap();
        assert_eq!(header, input.header);
        let mut decoded = Vec::new();
        loop {
            let (record, n) = decode_record(&bytes[at..]).unwrap();
            at += n;
            if let ReplayRecord::End {
                imu_sample_sets,
                pps_edges,
            } = record
            {
                assert_eq!((imu_sample_sets, pps_edges), (250, 3));
                break;
            }
            decoded.push(record);
        }
        assert_eq!(at, bytes.len());
        assert_eq!(decoded, input.records);
    }

    #[test]
    fn inputs_the_firmware_would_reject_are_refused_on_the_host() {
        let imus = [adis16405_imu()];
        let unknown = ReplayInput::from_counts(&imus, &[sample(0, 3, 1)]);
        assert!(matches!(
            unknown,
            Err(ReplayFileError::UnknownImu {
                index: 1,
                imu_id: 3
            })
        ));
        let backwards = ReplayInput::from_counts(&imus, &[sample(20, 0, 1), sample(10, 0, 2)]);
        assert!(matches!(
            backwards,
            Err(ReplayFileError::TimeNotIncreasing {
                index: 1,
                t_us: 10,
                ..
            })
        ));
    }

    #[test]
    fn adis16405_scale_factors_are_the_data_sheet_values_in_si() {
        // 20 counts = 1 deg/s; 300.3 counts ~ 1 g.
        assert!((20.0 * ADIS16405_GYRO_SCALE_RAD_S_PER_COUNT - 1f64.to_radians()).abs() < 1e-15);
        assert_eq!(ADIS16405_ACCEL_SCALE_M_S2_PER_COUNT, 0.00333 * 9.80665);
    }

    #[test]
    fn adis16405_counts_are_read_as_integers_with_errors_naming_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.csv");
        std::fs::write(
            &path,
            "gx,gy,gz,ax,ay,az\n1,2,3,4,5,-305\n-1,-2,-3,0,0,-306\n",
        )
        .unwrap();
        let counts = read_adis16405_counts(&path, 2).unwrap();
        assert_eq!(counts[1].t_us, 10_000);
        assert_eq!(counts[1].gyro_counts, [-1, -2, -3]);
        assert_eq!(counts[1].accel_counts, [0, 0, -306]);
        let err = read_adis16405_counts(&path, 3).unwrap_err();
        assert!(matches!(
            err,
            ReplayFileError::TooFewSamples { available: 2, .. }
        ));
        std::fs::write(&path, "gx,gy,gz,ax,ay,az\n1,2,3,4,5,-305\n1,2,3.5,4,5,6\n").unwrap();
        let err = read_adis16405_counts(&path, 2).unwrap_err().to_string();
        assert!(
            err.contains("line 3") && err.contains("`gz`") && err.contains("3.5"),
            "{err}"
        );
    }

    fn empty_header() -> dynacal_core::log::Header {
        dynacal_core::log::Header {
            protocol_version: dynacal_core::log::PROTOCOL_VERSION,
            board: Default::default(),
            imus: Default::default(),
        }
    }

    #[test]
    fn the_log_check_finds_a_changed_count_a_missing_pps_and_dropped_frames() {
        use dynacal_core::log::{Frame, Header, ImuConfig, ImuSampleSet, PpsEvent};
        let samples: Vec<_> = (0..150).map(|k| sample(k as u64 * 10_000, 0, k)).collect();
        let input = ReplayInput::from_counts(&[adis16405_imu()], &samples).unwrap();
        let imu = adis16405_imu();
        let header = Frame::Header(Header {
            protocol_version: dynacal_core::log::PROTOCOL_VERSION,
            board: "test".try_into().unwrap(),
            imus: {
                let mut imus = empty_header().imus;
                imus.push(ImuConfig {
                    imu_id: 0,
                    model: imu.model_str().try_into().unwrap(),
                    sample_rate_hz: imu.sample_rate_hz,
                    gyro_scale_rad_s_per_count: imu.gyro_scale_rad_s_per_count,
                    accel_scale_m_s2_per_count: imu.accel_scale_m_s2_per_count,
                })
                .unwrap();
                imus
            },
        });
        let frames_of = |input: &ReplayInput| -> Vec<Frame> {
            let mut frames = vec![header.clone()];
            let mut sequence = 0;
            for record in &input.records {
                frames.push(match *record {
                    ReplayRecord::Imu {
                        t_us,
                        imu_id,
                        gyro_counts,
                        accel_counts,
                    } => Frame::Imu(ImuSampleSet {
                        t_us,
                        imu_id,
                        gyro_counts,
                        accel_counts,
                    }),
                    ReplayRecord::Pps { t_us } => {
                        sequence += 1;
                        Frame::Pps(PpsEvent {
                            t_us,
                            sequence: sequence - 1,
                        })
                    }
                    ReplayRecord::End { .. } | ReplayRecord::Gnss { .. } => unreachable!(),
                });
            }
            frames
        };
        let exact =
            crate::decode::decode_bytes(&crate::decode::encode_log(&frames_of(&input)).unwrap());
        let check = check_log_against_replay(&input, &exact);
        assert!(check.is_exact(), "{check:?}");
        assert_eq!((check.samples_exact, check.pps_exact), (150, 2));

        let mut frames = frames_of(&input);
        // frames: header, PPS at 0 s, then sample k at index k + 2.
        if let Frame::Imu(s) = &mut frames[61] {
            s.accel_counts[2] += 1;
        }
        frames.retain(|f| !matches!(f, Frame::Pps(p) if p.t_us == 1_000_000));
        let mut bytes = crate::decode::encode_log(&frames).unwrap();
        let last = bytes.len() - 3;
        // Corrupt the last frame (without making a 0x00 delimiter): the decoder drops it.
        bytes[last] = if bytes[last] == 0x55 { 0x56 } else { 0x55 };
        let check = check_log_against_replay(&input, &crate::decode::decode_bytes(&bytes));
        assert!(!check.is_exact());
        assert_eq!(check.samples_exact, 148);
        assert_eq!(check.pps_exact, 1);
        assert_eq!(check.frames_dropped, 1);
        assert!(
            check.mismatches.iter().any(|m| m.contains("sample 59")),
            "{check:?}"
        );
        assert!(
            check.mismatches.iter().any(|m| m.contains("1 PPS frames")),
            "{check:?}"
        );
    }

    #[test]
    fn run_report_parses_only_a_complete_line() {
        let stderr = "noise\ndynacal-firmware: run-report board=x imu_sample_sets=6000 \
            pps_edges=60 gnss_fixes=600 gnss_frames_refused=3 health_reports=60 filter_states=10 noise_reports=2 fault_reports=1 \
            frames_written=6121 bytes_written=200000 frames_dropped=0 \
            record_instructions=1200000 source_instructions=600000 total_instructions=1900000 \
            fusion_instructions=300000 navigating_fusion_instructions=200000 \
            navigating_sample_sets=1000 stack_peak_bytes=40000 static_bytes=50000 \
            calibration_instructions=2000000 \
            calibration_ticks=336000\n";
        let report = RunReport::parse(stderr).unwrap();
        assert_eq!(report.imu_sample_sets, 6000);
        assert_eq!(report.record_instructions_per_sample(), 200.0);
        assert_eq!((report.filter_states, report.fault_reports), (10, 1));
        assert_eq!((report.gnss_fixes, report.gnss_frames_refused), (600, 3));
        // 900 000 recording instructions over 3 s, 200 fusion instructions a set at 1 kHz.
        assert_eq!(
            report.steady_instructions_per_second(3.0, 1000.0),
            Some(500_000.0)
        );
        assert!(RunReport::parse("dynacal-firmware: run-report imu_sample_sets=1").is_none());
    }
}
