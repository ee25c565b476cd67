//! The discrepancy engine: what the simulation gets wrong, the named cause, the extended
//! model and the measured gain (`dynacal diagnose`).

pub mod engine;
pub mod report;
pub mod stats;
