//! Cost of the navigation filter on the Cortex-M4F: instructions per filter stage and per
//! epoch for the 15-state filter and the 27-state filter (two extra IMUs), in `f32`, measured
//! with SysTick under QEMU's `-icount shift=0` (deterministic: 1 ns of virtual time per
//! instruction, calibrated against a loop of known length).
//!
//! Run: `cargo run -p dynacal-firmware --release --target thumbv7em-none-eabihf
//! --features board-replay --bin ekf_cost`. Prints one `key=value` line per measurement on
//! semihosting stderr and exits 0 (a panic or fault exits non-zero, so QEMU never hangs).
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
    use dynacal_core::nav::ekf::{
        EkfConfig, ErrorStateEkf, InitialSigmas, InterImuSample, NavLinearization,
    };
    use dynacal_core::recorder::TickClock;
    use nalgebra::{Rotation3, SMatrix, Vector3};

    use crate::cost::{Calibration, SysTickClock};

    /// Repetitions of each stage; the mean is reported.
    const REPETITIONS: u32 = 200;
    const DT_S: f32 = 0.01;

    fn sigmas() -> InitialSigmas<f32> {
        InitialSigmas {
            position_m: Vector3::repeat(5.0),
            velocity_m_s: Vector3::repeat(0.5),
            attitude_rad: Vector3::new(0.02, 0.02, 0.1),
            accel_bias_m_s2: Vector3::repeat(0.1),
            gyro_bias_rad_s: Vector3::repeat(1e-3),
            boresight_rad: Vector3::repeat(0.35),
            lever_arm_m: Vector3::repeat(0.2),
        }
    }

    /// A linearisation point that changes with `i` so nothing is constant-folded.
    fn linearization(i: u32) -> NavLinearization<f32> {
        let yaw = 0.001 * i as f32;
        NavLinearization::from_geodetic(
            0.8116,
            400.0,
            Vector3::new(12.0, 3.0 + 0.01 * i as f32, -0.1),
            Rotation3::from_euler_angles(0.02, -0.01, yaw).into_inner(),
            Vector3::new(0.4, -0.2, -9.8),
        )
    }

    fn inter_imu_sample(i: u32) -> InterImuSample<f32> {
        let s = 0.001 * i as f32;
        InterImuSample {
            omega_ib_b_rad_s: Vector3::new(0.1 + s, -0.2, 0.3),
            omega_dot_ib_b_rad_s2: Vector3::new(0.5, 0.4 - s, -0.3),
            f_b_m_s2: Vector3::new(0.4, -0.2, -9.8),
            omega_is_s_rad_s: Vector3::new(0.1 + s, -0.19, 0.31),
            f_s_m_s2: Vector3::new(0.45, -0.25, -9.79),
            shares_reference_bias: false,
        }
    }

    struct Stages {
        /// The same prediction as a dense `Φ P Φᵀ` product (nalgebra), for comparison.
        dense_predict: u64,
        linearization: u64,
        predict: u64,
        gnss: u64,
        inter_imu: u64,
        reset: u64,
    }

    /// Mean instructions of each stage over `REPETITIONS` epochs of the `K`-IMU filter.
    fn measure<const K: usize, const N: usize>(
        clock: &mut SysTickClock,
        calibration: &Calibration,
    ) -> Stages {
        let mut ekf = ErrorStateEkf::<f32, K, N>::new(EkfConfig::automotive_mems(), sigmas());
        let mut ticks = [0u64; 5];
        let sigma_p = Vector3::new(1.5f32, 1.5, 3.0);
        let sigma_v = Vector3::repeat(0.1f32);
        let sigma_rate = Vector3::repeat(0.01f32);
        let sigma_force = Vector3::repeat(0.03f32);
        for i in 0..REPETITIONS {
            let t0 = clock.now_ticks();
            let lin = black_box(linearization(black_box(i)));
            let t1 = clock.now_ticks();
            black_box(ekf.predict(&lin, DT_S));
            let t2 = clock.now_ticks();
            let small = 0.01 * (i % 7) as f32;
            black_box(ekf.fuse_gnss_position(&Vector3::new(0.3 + small, -0.2, 0.1), &sigma_p));
            black_box(ekf.fuse_gnss_velocity(&Vector3::new(0.02, small, -0.01), &sigma_v));
            let t3 = clock.now_ticks();
            let sample = black_box(inter_imu_sample(i));
            for imu in 0..K {
                black_box(ekf.fuse_inter_imu(imu, &sample, &sigma_rate, &sigma_force));
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
        // Peer in the same run: the dense N×N prediction a straightforward filter would do.
        let mut phi = SMatrix::<f32, N, N>::identity();
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
        let mean = |t: u64| calibration.instructions(t) / u64::from(REPETITIONS);
        // The SysTick read itself is inside each span; subtract its cost.
        let overhead = clock.read_overhead(calibration, REPETITIONS);
        let net = |t: u64| mean(t).saturating_sub(overhead);
        Stages {
            dense_predict: net(dense_ticks),
            linearization: net(ticks[0]),
            predict: net(ticks[1]),
            gnss: net(ticks[2]),
            inter_imu: net(ticks[3]),
            reset: net(ticks[4]),
        }
    }

    fn report(states: usize, stages: &Stages) {
        semihosting::eprintln!(
            "ekf-cost states={} linearization={} predict={} dense_predict={} gnss_pos_vel={} \
             inter_imu_all={} reset={}",
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
        report(15, &measure::<0, 15>(&mut clock, &calibration));
        report(27, &measure::<2, 27>(&mut clock, &calibration));
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
        "ekf_cost runs on a Cortex-M4F: cargo run -p dynacal-firmware --release \
         --target thumbv7em-none-eabihf --features board-replay --bin ekf_cost"
    );
    std::process::exit(2);
}
