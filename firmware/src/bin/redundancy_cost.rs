//! Cost of the redundant-IMU estimator per sample set of three IMUs on the Cortex-M4F (its
//! `f32` in hardware) or, built for thumbv7m-none-eabi with `fixed-point`, on a Cortex-M3
//! (the monitors' `f32` in software, the live levels in the board's fixed point), measured
//! with SysTick under QEMU's `-icount shift=0` (deterministic: 1 ns of virtual time per
//! instruction, calibrated against a loop of known length).
//!
//! Each sample set (gyro and accelerometer triads of three units, synthetic: a slow motion
//! with a 26 Hz vibration line, a bias per unit and seeded noise) goes through what the board
//! would run on it: the live noise levels (`LiveNoise` in the board's scalar, gyro and
//! accelerometer), the fault monitors (`FaultMonitor::push`, gyro and accelerometer,
//! configured as the host's `dynacal redundancy` configures them for ±2000 deg/s, ±16 g
//! units) and the fused output (`FaultMonitor::fused`, both). After a warm-up that turns on every test of the monitors
//! (the noise-burst and slip tests wait for `spread_time_constant_s`), sample sets are timed
//! fault-free, then with a bias step on one unit's gyros and accelerometers: while the
//! monitors gather the step's evidence (the confirmation window) and after, with the unit out.
//!
//! Run: `cargo run -p dynacal-firmware --profile firmware --target thumbv7em-none-eabihf
//! --features board-replay --bin redundancy_cost`. Prints `redundancy-cost key=value ...`
//! lines on semihosting stderr and exits 0 (a panic or fault exits non-zero, so QEMU never
//! hangs):
//! - `setup`: the run's rate and phases, and the calibration;
//! - `sizes`: bytes of `LiveNoise<3>` and `FaultMonitor<3>`, of the four the board keeps, of
//!   the stack the sample-set loop used below the frame that holds those four (painted
//!   before, scanned after), of the statics, of the whole run's deepest stack from the top of
//!   RAM, and of the RAM (from the linker's symbols, i.e. memory.x);
//! - `phase=healthy|episode|excluded`: mean instructions per sample set of `live` (both
//!   LiveNoise pushes with the platform rate they need), `monitor_gyro`, `monitor_accel`,
//!   `monitor` (both), `fused` (both) and `total`, and `total_max`, the costliest set (at
//!   sample set `total_max_set`);
//! - `event`: each fault the monitors confirmed.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
#[path = "../cost.rs"]
mod cost;
#[cfg(target_os = "none")]
#[path = "../soft_watchdog.rs"]
mod soft_watchdog;

#[cfg(target_os = "none")]
#[path = "../stack.rs"]
mod stack;

#[cfg(target_os = "none")]
mod bare_metal {
    use core::hint::black_box;

    use cortex_m_rt::{entry, exception, ExceptionFrame};
    use defmt_semihosting as _;
    use dynacal_core::fusion::BoardScalar;
    use dynacal_core::recorder::TickClock;
    use dynacal_core::redundancy::faults::Step;
    use dynacal_core::redundancy::{
        FaultConfig, FaultEvent, FaultMonitor, LiveNoise, MotionThresholds, MAX_UNITS,
    };
    use dynacal_core::scalar::FilterScalar;
    // Float methods without std.
    use nalgebra::ComplexField;

    use crate::cost::{Calibration, SysTickClock};

    const UNITS: usize = 3;
    const RATE_HZ: f32 = 100.0;
    const SAMPLE_INTERVAL_S: f32 = 1.0 / RATE_HZ;
    /// 15 s: three of the monitors' `spread_time_constant_s` (5 s, after which every test is
    /// on), so the spreads the tests divide by have settled.
    const WARM_UP_SETS: u32 = 1500;
    /// Timed fault-free sample sets.
    const HEALTHY_SETS: u32 = 1000;
    /// Unit 1's gyros and accelerometers step at this sample set.
    const ONSET: u32 = WARM_UP_SETS + HEALTHY_SETS;
    /// Sample sets from the onset: detection, the 1 s confirmation window, then the unit out.
    const FAULT_SETS: u32 = 400;
    const FAULTY_UNIT: usize = 1;
    /// About 10 and 12 of the pairs' standard deviations.
    const GYRO_STEP_RAD_S: f32 = 0.03;
    const ACCEL_STEP_M_S2: f32 = 0.3;
    /// The live levels' time constant (`dynacal redundancy`'s default).
    const LIVE_TIME_CONSTANT_S: f32 = 2.0;
    /// ICM-42688-P ranges, as on the board (±2000 deg/s, ±16 g).
    const GYRO_RANGE_RAD_S: f32 = 34.906_586;
    const ACCEL_RANGE_M_S2: f32 = 156.906_5;
    /// Each unit's white noise per sample and bias.
    const GYRO_NOISE_RAD_S: [f32; UNITS] = [0.002, 0.004, 0.003];
    const ACCEL_NOISE_M_S2: [f32; UNITS] = [0.02, 0.04, 0.03];
    const GYRO_BIAS_RAD_S: [f32; UNITS] = [0.01, -0.005, 0.002];
    const ACCEL_BIAS_M_S2: [f32; UNITS] = [0.05, -0.03, 0.08];
    const SEED: u64 = 0x0D1A_CA1C_0057;

    /// SplitMix64: a small seeded generator, so every run is the same.
    struct SplitMix64(u64);

    impl SplitMix64 {
        fn next_u64(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }

        /// Uniform on [0, 1).
        fn uniform(&mut self) -> f32 {
            (self.next_u64() >> 40) as f32 / (1u32 << 24) as f32
        }

        /// Zero mean, unit variance, nearly normal: the sum of four uniforms (Irwin-Hall,
        /// variance 4/12) centred and scaled.
        fn normal(&mut self) -> f32 {
            let sum: f32 = (0..4).map(|_| self.uniform()).sum();
            (sum - 2.0) * 1.732_050_8
        }
    }

    /// Gyro (rad/s) and accelerometer (m/s^2) triads of every unit, one sample set.
    #[derive(Clone, Copy)]
    struct SampleSet {
        gyro_rad_s: [[f32; 3]; UNITS],
        accel_m_s2: [[f32; 3]; UNITS],
    }

    /// The platform's true angular rate (rad/s) and specific force (m/s^2) at sample set i:
    /// slow turns and sway with a 26 Hz vibration line.
    fn motion(i: u32) -> ([f32; 3], [f32; 3]) {
        let t_s = i as f32 * SAMPLE_INTERVAL_S;
        // 26 Hz at 100 Hz: the phase repeats every 50 sets; exact for any i.
        let phase = 2.0 * core::f32::consts::PI * ((26 * i) % 100) as f32 / 100.0;
        let vibration = phase.sin();
        let omega = [
            0.1 * (0.7 * t_s).sin() + 0.05 * vibration,
            0.15 * (0.4 * t_s + 1.0).sin() + 0.025 * vibration,
            0.3 * (0.25 * t_s).sin() + 0.015 * vibration,
        ];
        let force = [
            0.8 * (0.3 * t_s).sin() + 0.2 * vibration,
            0.5 * (0.5 * t_s + 2.0).sin() + 0.1 * vibration,
            -9.81 + 0.3 * vibration,
        ];
        (omega, force)
    }

    /// What the three units read at sample set i: the motion, each unit's bias and noise, and
    /// from ONSET a bias step on FAULTY_UNIT.
    fn sample_set(i: u32, rng: &mut SplitMix64) -> SampleSet {
        let (omega, force) = motion(i);
        let mut set = SampleSet {
            gyro_rad_s: [[0.0; 3]; UNITS],
            accel_m_s2: [[0.0; 3]; UNITS],
        };
        for k in 0..UNITS {
            let step = if k == FAULTY_UNIT && i >= ONSET {
                1.0
            } else {
                0.0
            };
            for a in 0..3 {
                set.gyro_rad_s[k][a] = omega[a]
                    + GYRO_BIAS_RAD_S[k]
                    + step * GYRO_STEP_RAD_S
                    + GYRO_NOISE_RAD_S[k] * rng.normal();
                set.accel_m_s2[k][a] = force[a]
                    + ACCEL_BIAS_M_S2[k]
                    + step * ACCEL_STEP_M_S2
                    + ACCEL_NOISE_M_S2[k] * rng.normal();
            }
        }
        set
    }

    /// The monitors' configuration, as `dynacal redundancy` sets it: the units' clipping
    /// levels less 1%; accelerometer lengths compared to 10%; gyros not held back by a jolt.
    fn monitor_config(gyro: bool) -> FaultConfig {
        let mut c = FaultConfig::new(SAMPLE_INTERVAL_S);
        let range = if gyro {
            GYRO_RANGE_RAD_S
        } else {
            ACCEL_RANGE_M_S2
        };
        c.range = [0.99 * range; MAX_UNITS];
        if gyro {
            c.common_hold_s = 0.0;
        } else {
            c.norm_tolerance = Some(0.1);
        }
        c
    }

    /// Where a timed sample set falls.
    #[derive(Clone, Copy)]
    enum Phase {
        /// Before the onset, every unit healthy.
        Healthy,
        /// Both monitors hold FAULTY_UNIT suspected and gather its evidence (up to and with
        /// the set that decides its kind).
        Episode,
        /// Both monitors have confirmed the fault; the unit is out of the fused output.
        Excluded,
    }

    /// In the order of Phase's discriminants.
    const PHASES: [&str; 3] = ["healthy", "episode", "excluded"];

    /// Timed spans of one phase: live, gyro monitor, accelerometer monitor, fused.
    #[derive(Clone, Copy, Default)]
    struct Spans {
        sets: u32,
        ticks: [u64; 4],
        /// The costliest set's ticks, all four spans, and its index.
        max_ticks: u64,
        max_set: u32,
    }

    /// One monitor's view of FAULTY_UNIT's fault, from its steps.
    #[derive(Clone, Copy, Default)]
    struct Fault {
        confirmed_at: Option<u32>,
    }

    impl Fault {
        /// After the push of set i with result `step`: whether the unit is under
        /// confirmation (Some(false)) or confirmed and out (Some(true)).
        fn state(&mut self, monitor: &FaultMonitor<UNITS>, step: &Step, i: u32) -> Option<bool> {
            let unit = Some(FAULTY_UNIT as u8);
            if step.confirmed.iter().any(|e| e.unit == unit) {
                self.confirmed_at.get_or_insert(i);
            }
            if monitor.healthy(FAULTY_UNIT) {
                return None;
            }
            Some(self.confirmed_at.is_some_and(|at| at < i))
        }
    }

    /// A confirmed fault and the sensor whose monitor confirmed it.
    type Event = (&'static str, FaultEvent);

    /// Keeps the faults one push confirmed (printed after the run, so the printing's stack
    /// is not counted in the loop's); returns how many there were.
    fn keep_events(
        sensor: &'static str,
        step: &Step,
        events: &mut heapless::Vec<Event, 16>,
    ) -> u32 {
        for e in &step.confirmed {
            // More than 16 events means the run went wrong; the count still says so.
            let _ = events.push((sensor, *e));
        }
        step.confirmed.len() as u32
    }

    fn report_event((sensor, e): &Event) {
        match e.unit {
            Some(unit) => semihosting::eprintln!(
                "redundancy-cost event sensor={} unit={} kind={:?} detected_sample={} \
                 confirmed_sample={}",
                sensor,
                unit,
                e.kind,
                e.detected_sample,
                e.confirmed_sample
            ),
            None => semihosting::eprintln!(
                "redundancy-cost event sensor={} unit=none kind={:?} detected_sample={} \
                 confirmed_sample={}",
                sensor,
                e.kind,
                e.detected_sample,
                e.confirmed_sample
            ),
        }
    }

    use crate::stack;
    use stack::{low_water, paint as paint_free_stack};

    fn run(clock: &mut SysTickClock, calibration: &Calibration) {
        let overhead = clock.read_overhead(calibration, 200);
        let mut rng = SplitMix64(SEED);
        let thresholds = MotionThresholds::default();
        // In the board's scalar, as the fusion runs them: fixed point on the core without an
        // FPU, the samples taken into it as the fusion takes its means.
        let mut live_gyro = LiveNoise::<UNITS, BoardScalar>::new(
            SAMPLE_INTERVAL_S,
            LIVE_TIME_CONSTANT_S,
            thresholds,
        );
        let mut live_accel = LiveNoise::<UNITS, BoardScalar>::new(
            SAMPLE_INTERVAL_S,
            LIVE_TIME_CONSTANT_S,
            thresholds,
        );
        let to_board = |v: [f32; 3]| v.map(BoardScalar::convert_from_f32);
        let mut monitor_gyro = FaultMonitor::<UNITS>::new(monitor_config(true));
        let mut monitor_accel = FaultMonitor::<UNITS>::new(monitor_config(false));
        let (mut fault_gyro, mut fault_accel) = (Fault::default(), Fault::default());
        let mut spans = [Spans::default(); 3];
        let mut events = heapless::Vec::<Event, 16>::new();
        let mut events_before_onset = 0;

        let loop_sp = cortex_m::register::msp::read() as usize;
        paint_free_stack();
        for i in 0..ONSET + FAULT_SETS {
            let set = black_box(sample_set(i, &mut rng));
            let gyro: [Option<[f32; 3]>; UNITS] = set.gyro_rad_s.map(Some);
            let accel: [Option<[f32; 3]>; UNITS] = set.accel_m_s2.map(Some);
            let (gyro, accel) = (black_box(gyro), black_box(accel));

            let t0 = clock.now_ticks();
            // The platform's rate for the motion state: the units' mean, as the host's.
            let rate: [f32; 3] = core::array::from_fn(|a| {
                set.gyro_rad_s.iter().map(|u| u[a]).sum::<f32>() / UNITS as f32
            });
            live_gyro.push(&set.gyro_rad_s.map(to_board), to_board(rate));
            live_accel.push(&set.accel_m_s2.map(to_board), to_board(rate));
            black_box((&live_gyro, &live_accel));
            let t1 = clock.now_ticks();
            let step_gyro = monitor_gyro.push(&gyro);
            black_box(&step_gyro);
            let t2 = clock.now_ticks();
            let step_accel = monitor_accel.push(&accel);
            black_box(&step_accel);
            let t3 = clock.now_ticks();
            black_box(monitor_gyro.fused(&gyro));
            black_box(monitor_accel.fused(&accel));
            let t4 = clock.now_ticks();

            let confirmed = keep_events("gyro", &step_gyro, &mut events)
                + keep_events("accel", &step_accel, &mut events);
            if i < ONSET {
                events_before_onset += confirmed;
            }
            let gyro_state = fault_gyro.state(&monitor_gyro, &step_gyro, i);
            let accel_state = fault_accel.state(&monitor_accel, &step_accel, i);
            let phase = match (i, gyro_state, accel_state) {
                (i, _, _) if i < WARM_UP_SETS => None,
                (i, None, None) if i < ONSET => Some(Phase::Healthy),
                (_, Some(false), Some(false)) => Some(Phase::Episode),
                (_, Some(true), Some(true)) => Some(Phase::Excluded),
                _ => None,
            };
            if let Some(phase) = phase {
                let s = &mut spans[phase as usize];
                s.sets += 1;
                for (slot, span) in s.ticks.iter_mut().zip([t1 - t0, t2 - t1, t3 - t2, t4 - t3]) {
                    *slot += span;
                }
                if t4 - t0 > s.max_ticks {
                    s.max_ticks = t4 - t0;
                    s.max_set = i;
                }
            }
        }
        let low = low_water();

        let live_noise = core::mem::size_of::<LiveNoise<UNITS, BoardScalar>>();
        let fault_monitor = core::mem::size_of::<FaultMonitor<UNITS>>();
        let ram_end = stack::ram_end();
        semihosting::eprintln!(
            "redundancy-cost sizes live_noise_3={} fault_monitor_3={} estimator_state={} \
             stack_per_set={} statics={} stack_peak={} ram={}",
            live_noise,
            fault_monitor,
            2 * live_noise + 2 * fault_monitor,
            loop_sp.saturating_sub(low),
            stack::static_bytes(),
            ram_end - low,
            stack::sram_bytes()
        );
        semihosting::eprintln!(
            "redundancy-cost check events={} events_before_onset={} read_overhead={}",
            events.len(),
            events_before_onset,
            overhead
        );
        events.iter().for_each(report_event);
        for (name, s) in PHASES.iter().zip(&spans) {
            let sets = u64::from(s.sets.max(1));
            let mean = |t: u64| (calibration.instructions(t) / sets).saturating_sub(overhead);
            let [live, monitor_gyro, monitor_accel, fused] = s.ticks.map(mean);
            semihosting::eprintln!(
                "redundancy-cost phase={} sets={} live={} monitor_gyro={} monitor_accel={} \
                 monitor={} fused={} total={} total_max={} total_max_set={}",
                name,
                s.sets,
                live,
                monitor_gyro,
                monitor_accel,
                monitor_gyro + monitor_accel,
                fused,
                live + monitor_gyro + monitor_accel + fused,
                calibration
                    .instructions(s.max_ticks)
                    .saturating_sub(4 * overhead),
                s.max_set
            );
        }
    }

    #[entry]
    fn main() -> ! {
        let Some(core) = cortex_m::Peripherals::take() else {
            semihosting::eprintln!("redundancy-cost: fatal: core peripherals taken twice");
            semihosting::process::exit(1)
        };
        let (mut clock, calibration) = SysTickClock::start_calibrated(core.SYST);
        semihosting::eprintln!(
            "redundancy-cost setup units={} rate_hz={} warm_up_sets={} healthy_sets={} \
             onset={} fault_sets={} faulty_unit={} calibration_instructions={} \
             calibration_ticks={}",
            UNITS,
            RATE_HZ as u32,
            WARM_UP_SETS,
            HEALTHY_SETS,
            ONSET,
            FAULT_SETS,
            FAULTY_UNIT,
            calibration.instructions,
            calibration.ticks
        );
        run(&mut clock, &calibration);
        semihosting::process::exit(0)
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        semihosting::eprintln!("redundancy-cost: panic: {}", info);
        semihosting::process::exit(101)
    }

    #[exception]
    unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
        semihosting::eprintln!("redundancy-cost: hard fault at pc={:#010x}", frame.pc());
        semihosting::process::exit(102)
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "redundancy_cost runs on a Cortex-M4F: cargo run -p dynacal-firmware --profile \
         firmware --target thumbv7em-none-eabihf --features board-replay --bin redundancy_cost"
    );
    std::process::exit(2);
}
