//! dynacal-core: the part of dynacal that runs on the board as well as on the host.
//!
//! Everything here is `no_std` and allocation-free so the firmware can carry it; unit tests
//! run on the host under `std`. The core takes plain timestamped samples and knows no
//! hardware: pins, buses and clocks live in the firmware's board layer.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![forbid(unsafe_code)]
pub mod board_model;
pub mod channel;
pub mod clock;
pub mod fusion;
pub mod gnss;
pub mod inject;
pub mod log;
pub mod nav;
pub mod recorder;
pub mod redundancy;
pub mod replay;
pub mod wavelet;

pub use channel::{Channel, SensorKind};
