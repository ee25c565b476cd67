//! Cost measurement with SysTick: a free-running 64-bit tick count and its calibration
//! against a loop of known instruction count.
//!
//! Under QEMU with `-icount shift=0` the virtual clock advances 1 ns per instruction, so
//! SysTick ticks are a fixed number of instructions and the run is deterministic; the
//! calibration measures that ratio instead of assuming QEMU's SysTick clock. On the real
//! board the same count is core clock cycles (SysTick runs from the 168 MHz core clock).

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::{syst::SystClkSource, SYST};
use cortex_m_rt::exception;
use dynacal_core::recorder::TickClock;

/// SysTick is a 24-bit down-counter: it reloads from this value and interrupts at zero.
const RELOAD: u32 = 0x00FF_FFFF;

/// Times SysTick has wrapped (counted by its exception).
static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    let wraps = WRAPS.fetch_add(1, Ordering::Relaxed).wrapping_add(1);
    #[cfg(feature = "board-replay")]
    crate::soft_watchdog::on_wrap(wraps);
    #[cfg(not(feature = "board-replay"))]
    let _ = wraps;
}

/// Times SysTick has wrapped so far.
#[allow(dead_code)] // the replay board's watchdog reads it; the cost benches do not
pub fn wraps() -> u32 {
    WRAPS.load(Ordering::Relaxed)
}

/// Iterations of the calibration loop.
const CALIBRATION_ITERATIONS: u32 = 1_000_000;
/// Instructions per calibration iteration (`subs` + `bne`).
const INSTRUCTIONS_PER_ITERATION: u64 = 2;

/// Ticks measured over a known number of instructions.
#[derive(Debug, Clone, Copy)]
pub struct Calibration {
    pub instructions: u64,
    pub ticks: u64,
}

impl Calibration {
    /// `ticks` converted to instructions (exact under QEMU -icount up to one tick).
    #[cfg_attr(not(feature = "board-replay"), allow(dead_code))]
    pub fn instructions(&self, ticks: u64) -> u64 {
        if self.ticks == 0 {
            return 0;
        }
        ((ticks as u128 * self.instructions as u128) / self.ticks as u128) as u64
    }
}

/// SysTick extended to 64 bits by counting its wraps.
pub struct SysTickClock {
    _syst: SYST,
}

impl SysTickClock {
    /// Starts SysTick from the core clock, free-running, interrupting on each wrap.
    pub fn start(mut syst: SYST) -> Self {
        syst.disable_counter();
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(RELOAD);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
        SysTickClock { _syst: syst }
    }

    /// Starts SysTick as [`Self::start`], lets it reload once and calibrates it: what a cost
    /// bench does first. Right after `start` SysTick's current value reads 0 until its first
    /// reload, which [`TickClock::now_ticks`] counts as a full period: a calibration that
    /// began there would come out negative.
    pub fn start_calibrated(syst: SYST) -> (Self, Calibration) {
        let mut clock = Self::start(syst);
        let first = clock.now_ticks();
        while clock.now_ticks() == first {}
        let calibration = clock.calibrate();
        (clock, calibration)
    }

    /// Instructions of one back-to-back pair of clock reads, the mean over `repetitions`:
    /// what every measured span holds besides its work.
    #[allow(dead_code)] // the cost benches' (src/bin/*_cost.rs), not the application's
    pub fn read_overhead(&mut self, calibration: &Calibration, repetitions: u32) -> u64 {
        let mut total = 0;
        for _ in 0..repetitions {
            let a = self.now_ticks();
            let b = self.now_ticks();
            total += b - a;
        }
        calibration.instructions(total) / u64::from(repetitions.max(1))
    }

    /// Measures ticks per instruction on a loop of exactly known length.
    pub fn calibrate(&mut self) -> Calibration {
        let start = self.now_ticks();
        spin(CALIBRATION_ITERATIONS);
        let ticks = self.now_ticks() - start;
        Calibration {
            instructions: CALIBRATION_ITERATIONS as u64 * INSTRUCTIONS_PER_ITERATION,
            ticks,
        }
    }
}

impl TickClock for SysTickClock {
    fn now_ticks(&mut self) -> u64 {
        loop {
            let wraps_before = WRAPS.load(Ordering::Acquire);
            let current = SYST::get_current();
            // A wrap between the two loads shows as a changed count: its exception has
            // been taken by then, so read again.
            if WRAPS.load(Ordering::Acquire) == wraps_before {
                return ((wraps_before as u64) << 24) + u64::from(RELOAD - current);
            }
        }
    }
}

/// Runs `iterations` of a two-instruction loop; hand-written in assembly so the compiler
/// cannot change the instruction count.
fn spin(iterations: u32) {
    // SAFETY: the loop only decrements its own register and touches no memory.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {n}, {n}, #1",
            "bne 2b",
            n = inout(reg) iterations => _,
            options(nomem, nostack),
        );
    }
}
