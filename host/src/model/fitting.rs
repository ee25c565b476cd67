//! A model file fitted from a recording: the GMWM fit of every channel of a file (what
//! `dynacal fit` does) and the model file it writes, each channel's model on the IMU channel
//! its name denotes, with the fit statistics beside it (`fit.channels`). Those statistics
//! also say how long a record each model was fitted on, which a diagnosis needs to know how
//! uncertain the model is ([`fitted_record_samples`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::file::SimModel;
use super::fitted::imu_channel_of_name;
use super::Channel;
use crate::gmwm::fit::{FitError, FitInput, FitOptions};
use crate::gmwm::inference::{analyze, BootstrapOptions, ChannelFit, ModelChoice};
use crate::gmwm::model::ModelSpec;
use crate::input::stream::{streamed_if_wanted, StreamMode};
use crate::input::{load_wavelet_variances, InputArgs, InputError};
use crate::wv::WvOptions;

/// Errors of fitting a file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FitFileError {
    #[error(transparent)]
    Input(#[from] InputError),
    #[error("{path}: channel {channel}: {source}")]
    Channel {
        path: PathBuf,
        channel: String,
        source: FitError,
    },
}

/// Fits every channel of `file` (channels in parallel): the given structure or the
/// WIC-best one ([`ModelChoice`]), with intervals and the J-test.
pub fn fit_file(
    file: &Path,
    input: &InputArgs,
    choice: &ModelChoice,
    bootstrap: Option<BootstrapOptions>,
) -> Result<Vec<ChannelFit>, FitFileError> {
    fit_file_as(file, input, choice, bootstrap, StreamMode::Auto)
}

/// As [`fit_file`], the wavelet variances streamed as `mode` says
/// ([`crate::input::stream::streamed_if_wanted`]): in memory that does not grow with the
/// recording's length, the fit needing only them.
pub fn fit_file_as(
    file: &Path,
    input: &InputArgs,
    choice: &ModelChoice,
    bootstrap: Option<BootstrapOptions>,
    mode: StreamMode,
) -> Result<Vec<ChannelFit>, FitFileError> {
    let opts = WvOptions::default();
    let channels = match streamed_if_wanted(file, input, &opts, mode)? {
        Some(streamed) => streamed.channels,
        None => load_wavelet_variances(file, input, &opts)?,
    };
    // Collected in full before the first error is taken, so that the error named is the
    // first channel's in file order, whichever thread finished first.
    let fits: Vec<Result<ChannelFit, FitFileError>> = channels
        .par_iter()
        .map(|c| {
            let err = |source| FitFileError::Channel {
                path: file.to_path_buf(),
                channel: c.channel.clone(),
                source,
            };
            let fit_input = FitInput::from_wv(&c.wv).map_err(err)?;
            analyze(
                &c.channel,
                &c.unit,
                &fit_input,
                choice,
                bootstrap,
                &FitOptions::default(),
            )
            .map_err(err)
        })
        .collect();
    fits.into_iter().collect()
}

/// What `dynacal fit` writes beside the model: the statistics of every channel's fit.
#[derive(serde::Serialize)]
struct FitRecord<'a> {
    file: String,
    requested_model: &'a str,
    channels: &'a [ChannelFit],
}

/// The model file of `fits` of `file`: each channel's fitted model on the IMU channel its
/// name denotes (the IMU named after the file), with the fit statistics beside it. Returns
/// the model and notes for the user: channels that name no IMU channel (kept in `fit`
/// only), and a model the simulator would refuse.
pub fn fitted_model(
    file: &Path,
    requested_model: &str,
    fits: &[ChannelFit],
) -> Result<(SimModel, Vec<String>), serde_json::Error> {
    fitted_model_of(
        &recording_stem(file),
        &file.display().to_string(),
        requested_model,
        fits,
    )
}

/// As [`fitted_model`], for fits of series that came from `source` (a file's name, or a
/// description where there is no file), their IMU named `imu`.
pub fn fitted_model_of(
    imu: &str,
    source: &str,
    requested_model: &str,
    fits: &[ChannelFit],
) -> Result<(SimModel, Vec<String>), serde_json::Error> {
    let specs: Vec<(String, ModelSpec)> = fits
        .iter()
        .map(|f| (f.channel.clone(), f.model_object.clone()))
        .collect();
    let (mut model, unmapped) = SimModel::from_channel_models(imu, &specs);
    let mut notes = Vec::new();
    if !unmapped.is_empty() {
        notes.push(format!(
            "{} name no IMU channel (gx..az): kept in `fit` only, not in the model",
            unmapped.join(", ")
        ));
    }
    model.comment = Some(format!(
        "fitted by dynacal fit on {source} (model {requested_model})"
    ));
    model.fit = Some(serde_json::to_value(FitRecord {
        file: source.to_string(),
        requested_model,
        channels: fits,
    })?);
    if let Err(e) = model.validate(Path::new(source)) {
        notes.push(format!(
            "the fitted model will not load in `dynacal simulate`: {e}"
        ));
    }
    Ok((model, notes))
}

/// A file's name without its directory and its extensions (`in/psins-mems.csv.gz` ->
/// `psins-mems`): the name of the IMU a fit describes.
fn recording_stem(file: &Path) -> String {
    let name = file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    name.split('.').next().unwrap_or_default().to_string()
}

/// Per channel, the number of samples of the record its model was fitted on, as the fit
/// statistics of a model file written by `dynacal fit` state it (`fit.channels[].n`).
/// Empty for a model file without them (a hand-written or simulator model, or an extended
/// model of `dynacal diagnose`).
pub fn fitted_record_samples(model: &SimModel) -> BTreeMap<Channel, usize> {
    let Some(channels) = model
        .fit
        .as_ref()
        .and_then(|f| f.get("channels"))
        .and_then(|c| c.as_array())
    else {
        return BTreeMap::new();
    };
    channels
        .iter()
        .filter_map(|c| {
            let (_, channel) = imu_channel_of_name(c.get("channel")?.as_str()?)?;
            let n = usize::try_from(c.get("n")?.as_u64()?).ok()?;
            Some((channel, n))
        })
        .collect()
}
