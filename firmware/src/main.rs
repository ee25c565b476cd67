//! dynacal firmware: records three IMUs, GNSS and PPS edges into the dynacal log, and fuses
//! them on the board (`dynacal_core::fusion`) with the board model it is given.
//!
//! The application (`dynacal_core::recorder::Recorder`) is board-agnostic; this crate adds
//! the board layer (`board::*`, one board per cargo feature), start-up, cost measurement
//! and fatal-error handling. See `firmware/README.md` for the boards and how to run them.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod board;
#[cfg(target_os = "none")]
mod cost;
#[cfg(all(target_os = "none", feature = "board-replay"))]
mod soft_watchdog;
#[cfg(target_os = "none")]
mod stack;

#[cfg(target_os = "none")]
mod bare_metal {
    use cortex_m_rt::{entry, exception, ExceptionFrame};
    use dynacal_core::recorder::{Recorder, RunState};
    use static_cell::ConstStaticCell;

    use crate::{board, cost};

    /// The recorder's state between events, in RAM beside the other statics: it is built at
    /// compile time, so it never passes through the stack, whose depth is measured.
    static RUN_STATE: ConstStaticCell<RunState> = ConstStaticCell::new(RunState::new());

    #[entry]
    #[cfg_attr(
        feature = "board-replay",
        allow(
            clippy::needless_borrow,
            reason = "the replay board's sink is a reference already, the real board's a value"
        )
    )]
    fn main() -> ! {
        // Before anything else runs deep: the run report states the deepest the stack went.
        crate::stack::paint();
        let Some(core) = cortex_m::Peripherals::take() else {
            board::fatal("core peripherals taken twice")
        };
        let (mut clock, calibration) = cost::SysTickClock::start_calibrated(core.SYST);
        defmt::info!(
            "dynacal-firmware on {=str}: {=u64} SysTick ticks per {=u64} calibration instructions",
            board::NAME,
            calibration.ticks,
            calibration.instructions
        );
        let mut parts = board::init();
        let recorder = Recorder::new(parts.header).with_fusion(parts.model);
        let Some(state) = RUN_STATE.try_take() else {
            board::fatal("run state taken twice")
        };
        let result = recorder.run_in(state, &mut parts.source, &mut parts.sink, &mut clock);
        board::finish(result, &calibration, &mut parts.sink)
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        board::fatal_panic(info)
    }

    #[exception]
    unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
        board::fatal_hard_fault(frame.pc())
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "dynacal-firmware runs on a Cortex-M4F: build it with --target thumbv7em-none-eabihf \
         and --features board-replay or board-stm32f405 (see firmware/README.md)"
    );
    std::process::exit(2);
}
