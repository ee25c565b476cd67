//! The replay board's watchdog. QEMU's netduinoplus2 models no independent watchdog, so the
//! replay board keeps one in software with the real board's timeout: the main loop feeds it
//! each time it asks for an event (as the STM32F405 board feeds its IWDG), and SysTick's
//! wrap interrupt (`cost.rs`, every 2^24 ticks) checks how long ago that was. A loop that
//! stops asking (a hung transfer, a loop gone wrong) ends the run with exit code 103 and
//! the time of the last event it handed on, where the real board would reset. It is armed
//! by the first feed, so start-up and the cost benches, which never feed it, run free.

use core::sync::atomic::{AtomicU32, Ordering};

/// The real board's IWDG timeout (`stm32f405.rs`).
pub const TIMEOUT_MS: u32 = 500;
/// SysTick ticks a second: the 168 MHz core clock it counts.
const TICKS_PER_S: u64 = 168_000_000;
/// Whole SysTick wraps (2^24 ticks, 100 ms at 168 MHz) that cover the timeout.
const TIMEOUT_WRAPS: u32 = ((TIMEOUT_MS as u64 * TICKS_PER_S / 1000).div_ceil(1 << 24)) as u32;
/// The wrap count at the last feed; `u32::MAX` until the first.
static FED_AT_WRAP: AtomicU32 = AtomicU32::new(u32::MAX);
/// The last event's time, ms on the replay's timescale (for the report; the core has no
/// 64-bit atomics).
static LAST_EVENT_T_MS: AtomicU32 = AtomicU32::new(0);
/// The run's exit code when the watchdog ends it.
pub const EXIT_WATCHDOG: i32 = 103;

/// The main loop is alive; `t_us` is the time of the event it last handed on.
#[allow(dead_code)] // the cost benches, which include this module, never feed it
pub fn feed(wraps: u32, t_us: u64) {
    FED_AT_WRAP.store(wraps, Ordering::Relaxed);
    LAST_EVENT_T_MS.store((t_us / 1000) as u32, Ordering::Relaxed);
}

/// Called from SysTick's interrupt at each wrap: ends the run when the loop has not fed the
/// watchdog within the timeout.
pub fn on_wrap(wraps: u32) {
    let fed = FED_AT_WRAP.load(Ordering::Relaxed);
    if fed != u32::MAX && wraps.wrapping_sub(fed) > TIMEOUT_WRAPS {
        semihosting::eprintln!(
            "dynacal-firmware: watchdog: the main loop asked for no event for {TIMEOUT_MS} ms \
             (the last one at t={} ms); the board resets here",
            LAST_EVENT_T_MS.load(Ordering::Relaxed)
        );
        semihosting::process::exit(EXIT_WATCHDOG)
    }
}
