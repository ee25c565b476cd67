//! The sensor error model: one typed home for what `fit` writes, `simulate` runs,
//! `diagnose` reads as its baseline and writes as its extension, and the board's compact
//! form derives from. Channels are [`Channel`]s and the causes the diagnosis names are
//! [`Cause`]s; nothing downstream matches on strings.
//!
//! - [`imu`]: one IMU's mounting, clock and per-channel error effects;
//! - [`gnss`]: the GNSS receiver and PPS of a simulation;
//! - [`file`](mod@file): the whole model file, its version and loading (also of older files);
//! - [`fitted`]: a model file from fitted stochastic models, by series name;
//! - [`units`]: the units a stochastic model may be stated in;
//! - `validate`: range checks naming the field.
//!
//! The stochastic part of a channel is the GMWM process model, [`ModelSpec`].

mod cause;
pub mod file;
pub mod fitted;
pub mod fitting;
pub mod gnss;
pub mod imu;
pub mod units;
mod validate;

pub use crate::gmwm::model::{ModelSpec, Process};
pub use cause::Cause;
pub use dynacal_core::{Channel, SensorKind};
pub use file::{ModelFileError, SimModel, MODEL_FILE_VERSION};
pub use fitted::{imu_channel_of_name, imu_name_from};
pub use fitting::{
    fit_file, fit_file_as, fitted_model, fitted_model_of, fitted_record_samples, FitFileError,
};
pub use gnss::{GnssBias, GnssModel, PpsModel};
pub use imu::{
    BiasStep, ChannelModel, ClockModel, DynamicDriver, DynamicNoise, Effect, ImuModel, Outliers,
    VibrationLine,
};
pub use units::{stochastic_in_si, unit_to_si};
