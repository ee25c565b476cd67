//! Cost of the navigation filter: instructions per filter stage and per epoch for the
//! 15-state filter and the 27-state filter (two extra IMUs), in `f32` and in Q32.32 fixed
//! point (`dynacal_core::fixed::I32F32`), measured with SysTick under QEMU's `-icount
//! shift=0` (deterministic: 1 ns of virtual time per instruction, calibrated against a loop
//! of known length). Built for the Cortex-M4F (`thumbv7em-none-eabihf`, floats in hardware)
//! and for the Cortex-M3 (`thumbv7m-none-eabi`, no FPU: every float operation a library
//! call), so the same run compares fixed point with software floats.
//!
//! Run: `cargo run -p dynacal-firmware --profile firmware --target thumbv7em-none-eabihf
//! --features board-replay --bin ekf_cost` (or `--target thumbv7m-none-eabi --features
//! board-replay,fixed-point`, as the fixed-point board is built). Prints one
//! `key=value` line per measurement on semihosting stderr and exits 0 (a panic or fault
//! exits non-zero, so QEMU never hangs).
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
#[path = "../cost.rs"]
mod cost;
#[cfg(target_os = "none")]
#[path = "../soft_watchdog.rs"]
mod soft_watchdog;

#[cfg(target_os = "none")]
mod bare_metal {
    use core::hint::black_box;

    use cortex_m_rt::{entry, exception, ExceptionFrame};
    use defmt_semihosting as _;
    use dynacal_core::fixed::I32F32;
    use dynacal_core::nav::earth::Latitude;
    use dynacal_core::nav::ekf::{
        EkfConfig, ErrorStateEkf, InitialSigmas, InterImuSample, NavLinearization,
    };
    use dynacal_core::recorder::TickClock;
    use dynacal_core::scalar::FilterScalar;
    use nalgebra::{Matrix3, Rotation3, SMatrix, Vector3};

    use crate::cost::{Calibration, SysTickClock};

    /// Repetitions of each stage; the mean is reported. Fewer on the core without an FPU,
    /// where each float operation is a library call (the counts are deterministic either
    /// way).
    #[cfg(target_abi = "eabihf")]
    const REPETITIONS: u32 = 200;
    #[cfg(not(target_abi = "eabihf"))]
    const REPETITIONS: u32 = 40;
    const DT_S: f32 = 0.01;
    /// Distinct inputs the repetitions cycle through, so nothing is constant-folded.
    const VARIANTS: usize = 8;

    /// A constant in the measured scalar (converted before the clock starts).
    fn c<T: FilterScalar>(x: f32) -> T {
        nalgebra::convert(f64::from(x))
    }

    fn v<T: FilterScalar>(x: f32, y: f32, z: f32) -> Vector3<T> {
        Vector3::new(c(x), c(y), c(z))
    }

    fn sigmas<T: FilterScalar>() -> InitialSigmas<T> {
        InitialSigmas {
            position_m: v(5.0, 5.0, 5.0),
            velocity_m_s: v(0.5, 0.5, 0.5),
            attitude_rad: v(0.02, 0.02, 0.1),
            accel_bias_m_s2: v(0.1, 0.1, 0.1),
            gyro_bias_rad_s: v(1e-3, 1e-3, 1e-3),
            boresight_rad: v(0.35, 0.35, 0.35),
            lever_arm_m: v(0.2, 0.2, 0.2),
        }
    }

    /// What one epoch is given, in the measured scalar: the motion the error model is
    /// linearised about, GNSS innovations and the extra IMUs' samples.
    struct Inputs<T: FilterScalar> {
        latitude: Latitude<T>,
        height_m: T,
        motion: [(Vector3<T>, Matrix3<T>, Vector3<T>); VARIANTS],
        gnss: [(Vector3<T>, Vector3<T>); VARIANTS],
        samples: [InterImuSample<T>; VARIANTS],
    }

    impl<T: FilterScalar> Inputs<T> {
        fn new() -> Self {
            let motion = core::array::from_fn(|i| {
                let i = i as f32;
                let yaw = 0.001 * i;
                (
                    v(12.0, 3.0 + 0.01 * i, -0.1),
                    Rotation3::from_euler_angles(0.02f32, -0.01, yaw)
                        .into_inner()
                        .map(|x| c(x)),
                    v(0.4, -0.2, -9.8),
                )
            });
            let gnss = core::array::from_fn(|i| {
                let small = 0.01 * i as f32;
                (v(0.3 + small, -0.2, 0.1), v(0.02, small, -0.01))
            });
            let samples = core::array::from_fn(|i| {
                let s = 0.001 * i as f32;
                InterImuSample {
                    omega_ib_b_rad_s: v(0.1 + s, -0.2, 0.3),
                    omega_dot_ib_b_rad_s2: v(0.5, 0.4 - s, -0.3),
                    f_b_m_s2: v(0.4, -0.2, -9.8),
                    omega_is_s_rad_s: v(0.1 + s, -0.19, 0.31),
                    f_s_m_s2: v(0.45, -0.25, -9.79),
                    shares_reference_bias: false,
                }
            });
            Self {
                latitude: Latitude::new(c(0.8116)),
                height_m: c(400.0),
                motion,
                gnss,
                samples,
            }
        }
    }

    struct Stages {
        /// The same prediction as a dense `Φ P Φᵀ` product (nalgebra), for comparison (0
        /// when not measured).
        dense_predict: u64,
        linearization: u64,
        predict: u64,
        gnss: u64,
        inter_imu: u64,
        reset: u64,
    }

    /// Mean instructions of each stage over `REPETITIONS` epochs of the `K`-IMU filter in
    /// scalar `T`: the linearisation from the latitude's cached terms (as the board keeps
    /// them), the block-sparse prediction, GNSS position and velocity, each extra IMU's
    /// inter-IMU update, and the reset.
    fn measure<T: FilterScalar, const K: usize, const N: usize>(
        clock: &mut SysTickClock,
        calibration: &Calibration,
        with_dense: bool,
    ) -> Stages {
        let inputs = Inputs::<T>::new();
        let mut ekf = ErrorStateEkf::<T, K, N>::new(EkfConfig::automotive_mems(), sigmas());
        let mut ticks = [0u64; 5];
        let (sigma_p, sigma_v) = (v::<T>(1.5, 1.5, 3.0), v::<T>(0.1, 0.1, 0.1));
        let (sigma_rate, sigma_force) = (v::<T>(0.01, 0.01, 0.01), v::<T>(0.03, 0.03, 0.03));
        let dt: T = c(DT_S);
        for i in 0..REPETITIONS {
            let k = i as usize % VARIANTS;
            let (velocity, c_b_n, force) = &inputs.motion[k];
            let t0 = clock.now_ticks();
            let lin = black_box(NavLinearization::at_latitude(
                black_box(&inputs.latitude),
                inputs.height_m,
                *velocity,
                *c_b_n,
                *force,
            ));
            let t1 = clock.now_ticks();
            black_box(ekf.predict(&lin, dt));
            let t2 = clock.now_ticks();
            let (position, speed) = &inputs.gnss[k];
            black_box(ekf.fuse_gnss_position(black_box(position), &sigma_p));
            black_box(ekf.fuse_gnss_velocity(black_box(speed), &sigma_v));
            let t3 = clock.now_ticks();
            let sample = black_box(&inputs.samples[k]);
            for imu in 0..K {
                black_box(ekf.fuse_inter_imu(imu, sample, &sigma_rate, &sigma_force));
            }
            let t4 = clock.now_ticks();
            black_box(ekf.reset());
            let t5 = clock.now_ticks();
            for (slot, span) in ticks
                .iter_mut()
                .zip([t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4])
            {
                *slot += span;
            }
        }
        let mean = |t: u64| calibration.instructions(t) / u64::from(REPETITIONS);
        // The SysTick read itself is inside each span; subtract its cost.
        let overhead = clock.read_overhead(calibration, REPETITIONS);
        let net = |t: u64| mean(t).saturating_sub(overhead);
        let dense_predict = if with_dense {
            net(dense_prediction(&ekf, clock))
        } else {
            0
        };
        Stages {
            dense_predict,
            linearization: net(ticks[0]),
            predict: net(ticks[1]),
            gnss: net(ticks[2]),
            inter_imu: net(ticks[3]),
            reset: net(ticks[4]),
        }
    }

    /// Ticks of `REPETITIONS` dense N×N predictions `Φ P Φᵀ`: the peer in the same run, what
    /// a straightforward filter would do.
    fn dense_prediction<T: FilterScalar, const K: usize, const N: usize>(
        ekf: &ErrorStateEkf<T, K, N>,
        clock: &mut SysTickClock,
    ) -> u64 {
        let mut phi = SMatrix::<T, N, N>::identity();
        phi.fixed_view_mut::<15, 15>(0, 0)
            .copy_from(&ekf.last_transition_nav());
        let p = ekf.covariance();
        let mut dense_ticks = 0;
        for _ in 0..REPETITIONS {
            let (phi, p) = (black_box(&phi), black_box(&p));
            let t0 = clock.now_ticks();
            let predicted = phi * p * phi.transpose();
            black_box(&predicted);
            dense_ticks += clock.now_ticks() - t0;
        }
        black_box(ekf.held_covariance());
        dense_ticks
    }

    /// Instructions of one multiply-add `acc += a b` in scalar `T`, from a 64-element dot
    /// product repeated: the filter's inner operation (the loop's own load and index
    /// instructions included).
    fn multiply_add<T: FilterScalar>(clock: &mut SysTickClock, calibration: &Calibration) -> u64 {
        let a: [T; 64] = core::array::from_fn(|i| c(0.01 * i as f32 - 0.3));
        let b: [T; 64] = core::array::from_fn(|i| c(1.5 - 0.02 * i as f32));
        let t0 = clock.now_ticks();
        for _ in 0..REPETITIONS {
            let (a, b) = (black_box(&a), black_box(&b));
            let mut acc = T::zero();
            for (x, y) in a.iter().zip(b) {
                acc += *x * *y;
            }
            black_box(acc);
        }
        let ticks = clock.now_ticks() - t0;
        calibration.instructions(ticks) / (u64::from(REPETITIONS) * 64)
    }

    fn report(scalar: &str, states: usize, stages: &Stages) {
        semihosting::eprintln!(
            "ekf-cost scalar={} states={} linearization={} predict={} dense_predict={} \
             gnss_pos_vel={} inter_imu_all={} reset={}",
            scalar,
            states,
            stages.linearization,
            stages.predict,
            stages.dense_predict,
            stages.gnss,
            stages.inter_imu,
            stages.reset
        );
    }

    #[entry]
    fn main() -> ! {
        let Some(core) = cortex_m::Peripherals::take() else {
            semihosting::eprintln!("ekf-cost: fatal: core peripherals taken twice");
            semihosting::process::exit(1)
        };
        let (mut clock, calibration) = SysTickClock::start_calibrated(core.SYST);
        semihosting::eprintln!(
            "ekf-cost calibration_instructions={} calibration_ticks={} repetitions={}",
            calibration.instructions,
            calibration.ticks,
            REPETITIONS
        );
        // The dense peer only where floats are hardware: on the core without an FPU its
        // 20 000 software multiply-adds would take most of the run.
        let dense = cfg!(target_abi = "eabihf");
        semihosting::eprintln!(
            "ekf-cost multiply_add f32={} fixed={}",
            multiply_add::<f32>(&mut clock, &calibration),
            multiply_add::<I32F32>(&mut clock, &calibration)
        );
        report(
            "f32",
            15,
            &measure::<f32, 0, 15>(&mut clock, &calibration, dense),
        );
        report(
            "f32",
            27,
            &measure::<f32, 2, 27>(&mut clock, &calibration, dense),
        );
        report(
            "fixed",
            15,
            &measure::<I32F32, 0, 15>(&mut clock, &calibration, false),
        );
        report(
            "fixed",
            27,
            &measure::<I32F32, 2, 27>(&mut clock, &calibration, false),
        );
        semihosting::process::exit(0)
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        semihosting::eprintln!("ekf-cost: panic: {}", info);
        semihosting::process::exit(101)
    }

    #[exception]
    unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
        semihosting::eprintln!("ekf-cost: hard fault at pc={:#010x}", frame.pc());
        semihosting::process::exit(102)
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "ekf_cost runs on a Cortex-M4F or M3: cargo run -p dynacal-firmware --profile \
         firmware --target thumbv7em-none-eabihf (or thumbv7m-none-eabi) --features board-replay \
         --bin ekf_cost"
    );
    std::process::exit(2);
}
