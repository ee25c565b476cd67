//! The model file: one JSON object holding the error models of up to three MEMS IMUs (and,
//! for simulation, the trajectory options, the reference IMU, the GNSS receiver and the PPS).
//! `dynacal fit` writes it (with its fit statistics beside the model), `dynacal simulate`
//! runs it, `dynacal diagnose` reads it as a baseline and writes its extended model as one.
//! Its format is `docs/formats.md` section 3; `version` says which revision a file follows.
//!
//! Also read, for files written before the format had a version: a bare fitted GMWM model
//! object (one MEMS IMU whose matching channels carry it) and the output of `dynacal fit`
//! of that time (`{"channels": [{"channel": "gx", "model_object": ...}]}`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::gnss::{GnssModel, PpsModel};
use super::imu::{ChannelModel, ImuModel};
use super::units::{stochastic_in_si, unit_to_si};
use super::Channel;
use crate::gmwm::model::ModelSpec;
use crate::sim::trajectory::TrajectoryConfig;

/// The revision of the model-file format this dynacal writes (and the newest it reads).
/// Version 1: the first versioned format; files without `version` are read as version 1.
pub const MODEL_FILE_VERSION: u32 = 1;

/// Errors in a model file; each names the file and the field.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelFileError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// JSON syntax or schema error (serde reports line and column).
    #[error("{path}: {message}")]
    Json { path: PathBuf, message: String },
    /// A value is out of range or inconsistent.
    #[error("{path}: field `{field}`: {message}")]
    Invalid {
        path: PathBuf,
        field: String,
        message: String,
    },
}

/// A whole model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimModel {
    /// Revision of the format ([`MODEL_FILE_VERSION`]); 1 when absent.
    #[serde(default = "first_version")]
    pub version: u32,
    /// Free text describing the model.
    #[serde(default, rename = "_comment", skip_serializing_if = "Option::is_none")]
    pub comment: Option<String>,
    #[serde(default, skip_serializing_if = "is_default_trajectory")]
    pub trajectory: TrajectoryConfig,
    /// The reference IMU; it defines the body frame (no lever arm, boresight or clock).
    #[serde(
        default = "ImuModel::navigation_grade_reference",
        skip_serializing_if = "is_default_reference"
    )]
    pub reference: ImuModel,
    /// Up to three MEMS IMUs.
    #[serde(default)]
    pub imus: Vec<ImuModel>,
    #[serde(default = "default_gnss", skip_serializing_if = "is_default_gnss")]
    pub gnss: Option<GnssModel>,
    #[serde(default = "default_pps", skip_serializing_if = "is_default_pps")]
    pub pps: Option<PpsModel>,
    /// The statistics of the fit this model came from (`dynacal fit`: per channel the
    /// parameters with their intervals, the J-test, the wavelet variances and the ranked
    /// candidates), kept with the model for the record; the simulator does not read them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<serde_json::Value>,
}

fn first_version() -> u32 {
    1
}
fn default_gnss() -> Option<GnssModel> {
    Some(GnssModel::default())
}
fn default_pps() -> Option<PpsModel> {
    Some(PpsModel::default())
}
fn is_default_trajectory(t: &TrajectoryConfig) -> bool {
    *t == TrajectoryConfig::default()
}
fn is_default_reference(r: &ImuModel) -> bool {
    *r == ImuModel::navigation_grade_reference()
}
fn is_default_gnss(g: &Option<GnssModel>) -> bool {
    *g == default_gnss()
}
fn is_default_pps(p: &Option<PpsModel>) -> bool {
    *p == default_pps()
}

impl Default for SimModel {
    /// The current version, default trajectory, reference, GNSS and PPS, and no MEMS IMU.
    fn default() -> Self {
        SimModel {
            version: MODEL_FILE_VERSION,
            comment: None,
            trajectory: TrajectoryConfig::default(),
            reference: ImuModel::navigation_grade_reference(),
            imus: Vec::new(),
            gnss: default_gnss(),
            pps: default_pps(),
            fit: None,
        }
    }
}

/// One channel of a `dynacal fit` output written before model files had a version.
#[derive(Deserialize)]
struct LegacyFitChannel {
    channel: String,
    model_object: ModelSpec,
}

/// A `dynacal fit` output written before model files had a version.
#[derive(Deserialize)]
struct LegacyFitOutput {
    channels: Vec<LegacyFitChannel>,
}

impl SimModel {
    /// Reads a model file (or a file written before the format had a version, see the
    /// module doc), validated.
    pub fn load(path: &Path) -> Result<Self, ModelFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| ModelFileError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json(&text, path)
    }

    /// Parses model-file text; `path` is used in error messages.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, ModelFileError> {
        let json_err = |e: serde_json::Error| ModelFileError::Json {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let value: serde_json::Value = serde_json::from_str(text).map_err(json_err)?;
        let legacy_fit = value.get("version").is_none()
            && value.get("imus").is_none()
            && value
                .get("channels")
                .is_some_and(serde_json::Value::is_array);
        let model = if value.get("processes").is_some() {
            let spec: ModelSpec = serde_json::from_str(text).map_err(json_err)?;
            Self::from_fitted(spec, path)?
        } else if legacy_fit {
            let old: LegacyFitOutput = serde_json::from_str(text).map_err(json_err)?;
            let specs = old
                .channels
                .into_iter()
                .map(|c| (c.channel, c.model_object))
                .collect::<Vec<_>>();
            let (mut model, _) = Self::from_channel_models("imu1", &specs);
            model.comment = Some("converted from an unversioned `dynacal fit` output".into());
            model
        } else {
            serde_json::from_str(text).map_err(json_err)?
        };
        model.validate(path)?;
        Ok(model)
    }

    /// A model whose one MEMS IMU (named `imu1`, at the fitted model's rate) carries the
    /// fitted stochastic model on every channel of matching dimension (gyros for an angular
    /// rate unit, accelerometers otherwise).
    pub fn from_fitted(spec: ModelSpec, path: &Path) -> Result<Self, ModelFileError> {
        let (_, angular) = unit_to_si(&spec.unit).ok_or_else(|| ModelFileError::Invalid {
            path: path.to_path_buf(),
            field: "unit".into(),
            message: format!("unknown unit `{}`", spec.unit),
        })?;
        let channel = ChannelModel {
            stochastic: Some(spec.clone()),
            ..Default::default()
        };
        let mut imu = ImuModel::bare("imu1", spec.sample_rate_hz);
        if angular {
            imu.gyro = channel;
        } else {
            imu.accel = channel;
        }
        Ok(SimModel {
            comment: Some(format!(
                "fitted model {} ({}) on imu1",
                spec.model, spec.unit
            )),
            imus: vec![imu],
            ..SimModel::default()
        })
    }

    /// The stochastic model of every channel of the one MEMS IMU this file describes,
    /// restated in SI units (rad/s, m/s^2): what a diagnosis takes as its baseline.
    pub fn stochastic_si(
        &self,
        path: &Path,
    ) -> Result<BTreeMap<Channel, ModelSpec>, ModelFileError> {
        let bad = |field: String, message: String| ModelFileError::Invalid {
            path: path.to_path_buf(),
            field,
            message,
        };
        let imu = match self.imus.as_slice() {
            [imu] => imu,
            imus => {
                let names: Vec<&str> = imus.iter().map(|i| i.name.as_str()).collect();
                return Err(bad(
                    "imus".into(),
                    format!(
                        "a baseline describes one MEMS IMU; this file has {} ({})",
                        imus.len(),
                        names.join(", ")
                    ),
                ));
            }
        };
        let mut out = BTreeMap::new();
        for channel in Channel::ALL {
            let Some(spec) = &imu.model_of(channel).stochastic else {
                continue;
            };
            let si = stochastic_in_si(spec).ok_or_else(|| {
                bad(
                    format!("imus[0].channels.{channel}.stochastic.unit"),
                    format!("unknown unit `{}`", spec.unit),
                )
            })?;
            out.insert(channel, si);
        }
        if out.is_empty() {
            return Err(bad(
                "imus[0]".into(),
                "no channel has a stochastic model".into(),
            ));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bare_fitted_model_becomes_one_imu_with_that_model_on_its_gyros() {
        let text = r#"{"model": "WN+GM", "unit": "deg/s", "sample_rate_hz": 100,
            "processes": [{"kind": "white_noise", "sigma2": 0.5},
                          {"kind": "gauss_markov", "beta_per_s": 0.01, "sigma2": 0.001}]}"#;
        let m = SimModel::from_json(text, Path::new("fit.json")).unwrap();
        assert_eq!(m.imus.len(), 1);
        assert_eq!(m.imus[0].rate_hz, 100.0);
        assert!(m.imus[0].channel(2).stochastic.is_some());
        assert!(m.imus[0].channel(3).stochastic.is_none());
    }

    #[test]
    fn errors_name_the_file_and_field() {
        let p = Path::new("m.json");
        let msg = |t: &str| SimModel::from_json(t, p).unwrap_err().to_string();
        let e = msg(
            r#"{"imus": [{"name": "a", "rate_hz": 100, "channels": {"gx": {"cross_axis": [0.1, 0, 0]}}}]}"#,
        );
        assert!(
            e.contains("m.json") && e.contains("imus[0].channels.gx.cross_axis"),
            "{e}"
        );
        let e =
            msg(r#"{"imus": [{"name": "a", "rate_hz": 100, "gyro": {"disabled": ["noise"]}}]}"#);
        // An effect's name is checked by serde: the message names the line and column and
        // lists the known effects.
        assert!(
            e.contains("m.json")
                && e.contains("`noise`")
                && e.contains("line 1")
                && e.contains("white_noise"),
            "{e}"
        );
        let e = msg(
            r#"{"imus": [{"name": "a", "rate_hz": 100, "gyro": {"stochastic": {"model": "WN", "unit": "m/s2", "sample_rate_hz": 100, "processes": [{"kind": "white_noise", "sigma2": 1}]}}}]}"#,
        );
        assert!(e.contains("does not fit a gyro channel"), "{e}");
        let e = msg(r#"{"imus": [{"name": "a", "rate_hz": 100, "gyro": {"bias_typo": 1}}]}"#);
        assert!(e.contains("bias_typo") && e.contains("line 1"), "{e}");
        let e = msg(r#"{"gnss": {"rate_hz": 5, "outages": [[10, 5]]}}"#);
        assert!(e.contains("gnss.outages[0]"), "{e}");
        let e = msg(r#"{"imus": [{"name": "reference", "rate_hz": 100}]}"#);
        assert!(e.contains("imus[0].name"), "{e}");
    }
}
