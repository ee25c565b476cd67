//! The sensor error model: one typed home for what `fit` writes, `simulate` runs,
//! `diagnose` reads as its baseline and writes as its extension, and the board's compact
//! form derives from. Channels are [`Channel`]s and the causes the diagnosis names are
//! [`Cause`]s; nothing downstream matches on strings.

mod cause;
mod file;

pub use cause::Cause;
pub use file::*;
pub use dynacal_core::{Channel, SensorKind};
