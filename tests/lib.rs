//! Shared helpers for dynacal's cross-crate and end-to-end tests: where the measured data
//! live, and how to skip cleanly when they are absent.

use std::path::PathBuf;

/// The measured-data folder: `$DYNACAL_DATA`, else `../shared/data` beside the repository.
pub fn data_dir() -> PathBuf {
    dynacal::data_dir()
}

/// Whether qemu-system-arm can run the firmware here. When it cannot, says so and answers
/// false, except in CI (`CI` or `DYNACAL_REQUIRE_QEMU` set), where it panics: a test that
/// needs QEMU skips on a developer's machine and fails where QEMU must be.
pub fn qemu_or_skip() -> bool {
    if dynacal::replay::qemu_available() {
        return true;
    }
    let required =
        std::env::var_os("CI").is_some() || std::env::var_os("DYNACAL_REQUIRE_QEMU").is_some();
    assert!(
        !required,
        "qemu-system-arm is missing but CI/DYNACAL_REQUIRE_QEMU requires it: run scripts/setup"
    );
    eprintln!("SKIPPED: qemu-system-arm not found (run scripts/setup to install it)");
    false
}

/// A core a cost bench runs on under QEMU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CostCore {
    /// The Cortex-M4F board (STM32F405, floats in hardware): QEMU's netduinoplus2.
    M4F,
    /// A Cortex-M3 without an FPU: QEMU's netduino2 (an STM32F205, the same flash and SRAM
    /// addresses as the F405, so the firmware's one memory map serves).
    M3,
}

impl CostCore {
    /// The Rust target the bench is built for.
    pub fn target(self) -> &'static str {
        match self {
            CostCore::M4F => dynacal::replay::BOARD_TARGET,
            CostCore::M3 => dynacal::replay::FPU_LESS_TARGET,
        }
    }

    /// The firmware's features for the board: the replay board's, and on the core without an
    /// FPU the fixed-point filter's, as that board is built.
    pub fn features(self) -> &'static str {
        match self {
            CostCore::M4F => "board-replay",
            CostCore::M3 => "board-replay,fixed-point",
        }
    }

    /// QEMU's arguments for the board, `-icount shift=0` included.
    fn qemu_args(self) -> [&'static str; 11] {
        dynacal::replay::qemu_board_args(self.target())
    }
}

/// Builds the firmware cost bench `firmware/src/bin/{bin}.rs` for the Cortex-M4F as its
/// board runs (`board-replay`, the `firmware` profile, into [`FIRMWARE_TARGET_DIR`]: the
/// replay board's build, which builds every bench beside its image), runs it in QEMU with
/// `-icount shift=0` (deterministic instruction counts) and returns what it printed on
/// semihosting stderr; panics when the build or the run fails. None, after saying so, when
/// qemu-system-arm is absent, except in CI (`CI` or `DYNACAL_REQUIRE_QEMU` set), where that
/// panics.
///
/// [`FIRMWARE_TARGET_DIR`]: dynacal::replay::FIRMWARE_TARGET_DIR
pub fn run_cost_bench(bin: &str) -> Option<String> {
    run_cost_bench_on(bin, CostCore::M4F).map(|(stderr, _)| stderr)
}

/// As [`run_cost_bench`], on `core` (the Cortex-M3 bench built as the fixed-point board's
/// firmware is, `board-replay,fixed-point`); also returns the ELF's path.
pub fn run_cost_bench_on(bin: &str, core: CostCore) -> Option<(String, PathBuf)> {
    use dynacal::replay::{build_firmware_for, workspace_root, FIRMWARE_TARGET_DIR};
    use std::process::Command;

    if !qemu_or_skip() {
        return None;
    }
    let image = build_firmware_for(
        &workspace_root().join(FIRMWARE_TARGET_DIR),
        core.features(),
        core.target(),
    )
    .unwrap_or_else(|e| panic!("building {bin} for {}: {e}", core.target()));
    let elf = image.with_file_name(bin);
    let run = Command::new("timeout")
        .arg("300")
        .arg("qemu-system-arm")
        .args(core.qemu_args())
        .arg("-semihosting-config")
        .arg(format!("enable=on,target=native,arg={bin}"))
        .arg("-kernel")
        .arg(&elf)
        .output()
        .expect("run qemu-system-arm");
    let stderr = String::from_utf8_lossy(&run.stderr).into_owned();
    assert!(run.status.success(), "{bin} failed under QEMU: {stderr}");
    eprintln!("{stderr}");
    Some((stderr, elf))
}

/// Where SRAM starts on the boards (STM32F405 and, under QEMU, the F205): loaded segments
/// from here on are RAM.
pub const RAM_START: u64 = 0x2000_0000;

/// Bytes an ELF puts in flash (its loadable segments' file contents: code, constants and the
/// initialised data's load image) and in RAM (the loaded segments placed there, `.bss` and
/// the RTT buffer included).
pub fn flash_and_statics(elf: &std::path::Path) -> (u64, u64) {
    use object::{Object, ObjectSegment};
    let data = std::fs::read(elf).expect("read the ELF");
    let file = object::File::parse(&*data).expect("an ELF");
    let (mut flash, mut ram) = (0, 0);
    for segment in file.segments() {
        flash += segment.file_range().1;
        if segment.address() >= RAM_START {
            ram += segment.size();
        }
    }
    (flash, ram)
}

/// A simulated car drive of `model` (`seconds` long, seeded) and its replay input, written
/// to `dir/drive.replay`: what the QEMU tests feed the replay board.
pub fn simulated_drive(
    model: &dynacal::model::SimModel,
    seconds: f64,
    seed: u64,
    dir: &std::path::Path,
) -> (dynacal::sim::SimOutput, PathBuf) {
    let options = dynacal::sim::SimOptions {
        scenario: dynacal::sim::trajectory::Scenario::Car,
        seconds,
        seed,
        disabled: Vec::new(),
        keep_ideal: false,
    };
    let sim = dynacal::sim::simulate(model, &options, &|_| {}).expect("simulate");
    let board = dynacal::sim::board::board_recording(&sim, model).expect("board recording");
    let input = dir.join("drive.replay");
    std::fs::write(&input, board.replay_bytes().expect("replay bytes")).expect("write input");
    (sim, input)
}

/// The board's recorder with its fusion on (`model`), run natively on replay `records`:
/// the firmware's own code without the emulator, for sweeps over many drives that QEMU
/// would take hours for. A fault plan (`dynacal_core::inject`'s text), when given, wraps
/// the source and the sink as the replay board's `--faults` does. The log's bytes and the
/// run's statistics.
pub fn run_board_natively(
    header: dynacal_core::log::Header,
    records: &[dynacal_core::replay::ReplayRecord],
    model: dynacal_core::board_model::BoardModel,
    plan: Option<&str>,
) -> (Vec<u8>, dynacal_core::recorder::RecorderStats) {
    use dynacal_core::inject::{FaultPlan, InjectingSink, InjectingSource, InjectionClock};
    use dynacal_core::recorder::Recorder;
    let events: Vec<_> = records.iter().filter_map(native::event_of).collect();
    let plan = FaultPlan::parse(plan.unwrap_or("").as_bytes()).expect("a fault plan that reads");
    let clock = InjectionClock::new();
    let mut source = InjectingSource::new(
        native::Events(events.into_iter()),
        plan.clone(),
        &header.imus,
        &clock,
    );
    let mut sink = InjectingSink::new(native::Bytes::default(), &plan, &clock);
    let recorder = Recorder::new(header).with_fusion(model);
    let stats = recorder
        .run(&mut source, &mut sink, &mut native::NoClock)
        .expect("the recorder runs to the end");
    (std::mem::take(&mut sink.inner_mut().0), stats)
}

/// The plain source, sink and clock the native board runs with.
mod native {
    use dynacal_core::log::{ImuSampleSet, PpsEvent};
    use dynacal_core::recorder::{
        Accepted, GnssChunk, LogSink, SampleSource, SourceEvent, TickClock,
    };
    use dynacal_core::replay::ReplayRecord;

    pub struct Events(pub std::vec::IntoIter<SourceEvent>);

    impl SampleSource for Events {
        type Error = ();
        fn next_event(&mut self) -> Result<Option<SourceEvent>, ()> {
            Ok(self.0.next())
        }
    }

    #[derive(Default)]
    pub struct Bytes(pub Vec<u8>);

    impl LogSink for Bytes {
        type Error = ();
        fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, ()> {
            self.0.extend_from_slice(frame);
            Ok(Accepted::Written)
        }
        fn flush(&mut self) -> Result<(), ()> {
            Ok(())
        }
    }

    /// No cycle counter off the board: the run's cost figures are zero.
    pub struct NoClock;

    impl TickClock for NoClock {
        fn now_ticks(&mut self) -> u64 {
            0
        }
    }

    /// The source event of a replay record (none for its end).
    pub fn event_of(record: &ReplayRecord) -> Option<SourceEvent> {
        match *record {
            ReplayRecord::Imu {
                t_us,
                imu_id,
                gyro_counts,
                accel_counts,
            } => Some(SourceEvent::Imu(ImuSampleSet {
                t_us,
                imu_id,
                gyro_counts,
                accel_counts,
            })),
            ReplayRecord::Pps { t_us } => Some(SourceEvent::Pps(PpsEvent { t_us, sequence: 0 })),
            ReplayRecord::Gnss { t_us, len, data } => {
                Some(SourceEvent::Gnss(GnssChunk { t_us, len, data }))
            }
            ReplayRecord::End { .. } => None,
        }
    }
}
