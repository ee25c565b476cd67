//! The board layer: everything that differs between boards. Each board module provides the
//! same items, used by `main`:
//!
//! - `NAME`: the board name written in the log header;
//! - `init() -> Parts`: clocks, pins and peripherals set up, the log header built, and the
//!   sample source and log sink ready (a board that cannot start reports why and stops);
//! - `finish(result, calibration) -> !`: what to do when the recorder returns;
//! - `fatal(message)`, `fatal_panic(info)`, `fatal_hard_fault(pc)`: stop on an
//!   unrecoverable error in a way the board's operator sees (under QEMU: a non-zero
//!   semihosting exit code, since QEMU would otherwise hang).

#[cfg(all(feature = "board-replay", feature = "board-stm32f405"))]
compile_error!("select exactly one board feature: board-replay or board-stm32f405");
#[cfg(not(any(feature = "board-replay", feature = "board-stm32f405")))]
compile_error!(
    "select a board: --features board-replay (QEMU) or --features board-stm32f405 (hardware)"
);

#[cfg(feature = "board-replay")]
mod replay;
#[cfg(feature = "board-replay")]
pub use replay::*;

#[cfg(feature = "board-stm32f405")]
mod icm42688;
#[cfg(feature = "board-stm32f405")]
mod stm32f405;
#[cfg(feature = "board-stm32f405")]
pub use stm32f405::*;
