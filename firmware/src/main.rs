//! dynacal firmware entry point (filled in by the firmware work).
#![no_std]
#![no_main]
