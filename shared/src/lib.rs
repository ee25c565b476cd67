//! dynacal-core: the part of dynacal that runs on the board as well as on the host.
//!
//! Everything here is `no_std` and allocation-free so the firmware can carry it; unit tests
//! run on the host under `std`. The core takes plain timestamped samples and knows no
//! hardware: pins, buses and clocks live in the firmware's board layer.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
// `deny`, not `forbid`: the fixed-point scalar implements simba's `SimdValue`, whose
// trait declares two `unsafe fn` accessors (their bodies are safe).
#![deny(unsafe_code)]
pub mod board_model;
pub mod channel;
pub mod clock;
pub mod fixed;
pub mod fusion;
pub mod gnss;
pub mod inject;
pub mod log;
pub mod nav;
pub mod recorder;
pub mod redundancy;
pub mod replay;
pub mod scalar;
pub mod wavelet;

pub use channel::{Channel, SensorKind};
