//! The stack's high-water mark, by painting: the free stack (from just above the statics up
//! to the caller's frame) is filled with a pattern at start-up, and the lowest address no
//! longer holding it, read later, is as deep as the stack has been since. Used by the board
//! application (its run report) and the cost benches.

// Each binary (the board application on either board, the benches) uses part of it.
#![allow(dead_code)]

extern "C" {
    // memory.x and cortex-m-rt's link.x: the statics' RAM region and their end, and the
    // stack's region below them (its lowest address and its top).
    static _ram_start: u32;
    static _ram_end: u32;
    static __sheap: u32;
    static _stack_end: u32;
    static _stack_start: u32;
}

const PAINT: u32 = 0xC0DE_5AFE;

/// Lowest address the stack may use (the bottom of SRAM, below the statics: memory.x).
pub fn floor() -> usize {
    core::ptr::addr_of!(_stack_end) as usize
}

/// Start of the statics' RAM.
pub fn ram_start() -> usize {
    core::ptr::addr_of!(_ram_start) as usize
}

/// SRAM in all: the statics' region and the stack's, bytes.
pub fn sram_bytes() -> usize {
    let statics_region = (core::ptr::addr_of!(_ram_end) as usize).saturating_sub(ram_start());
    statics_region + ram_end().saturating_sub(floor())
}

/// The stack's top (it grows down from here).
pub fn ram_end() -> usize {
    core::ptr::addr_of!(_stack_start) as usize
}

/// Fills the free stack, from its lowest address to just below this function's frame, with
/// the pattern.
#[inline(never)]
pub fn paint() {
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = floor();
    while p + 64 < sp {
        // SAFETY: below the stack pointer and within the stack's region: memory no object
        // owns (exception frames pushed there meanwhile are dead once their handler returns).
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// The lowest stack address written since [`paint`].
pub fn low_water() -> usize {
    let top = ram_end();
    let mut p = floor();
    // SAFETY: reads of the stack's region, as words.
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    p
}

/// Bytes of stack used at the deepest since [`paint`].
pub fn peak_bytes() -> usize {
    ram_end().saturating_sub(low_water())
}

/// Bytes of statics (.data, .bss, .uninit).
pub fn static_bytes() -> usize {
    (core::ptr::addr_of!(__sheap) as usize).saturating_sub(ram_start())
}
