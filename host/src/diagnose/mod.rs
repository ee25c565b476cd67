//! The discrepancy engine: what the simulation gets wrong, the named cause, the extended
//! model and the measured gain (`dynacal diagnose`). [`engine::diagnose`] runs the stages
//! of the sibling modules in order.

pub mod baseline;
mod calibration;
mod draws;
pub mod engine;
mod extension;
mod gain;
mod generalise;
pub mod html;
mod moments;
mod null;
mod order;
pub mod readable;
pub mod report;
mod signals;
pub mod stats;
mod stochastic;
mod terms;
mod white_space;
mod whiten;
