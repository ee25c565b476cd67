//! `dynacal._dynacal`, the native module of the `dynacal` Python package: thin functions over
//! the dynacal library. Sample data crosses as numpy arrays (float64, SI units); the
//! structured results (wavelet variances, fits, redundancy reports, simulation truth) cross as
//! the JSON their library types serialise to, which `dynacal/__init__.py` turns into
//! dataclasses, so each result's shape has one home: the library's serde type, also what the
//! command line writes. Every computation runs with the GIL released. Errors raise
//! `dynacal.DynacalError` carrying the library's message as the command line prints it
//! (file, line, field; each cause said once).

use std::path::{Path, PathBuf};

use dynacal::decode::decode_file;
use dynacal::gmwm::fit::{FitInput, FitOptions};
use dynacal::gmwm::inference::{analyze, BootstrapOptions, ModelChoice};
use dynacal::gmwm::model::Structure;
use dynacal::import::{detect, import_file_noted};
use dynacal::input::wavelet_variance_of;
use dynacal::interchange::{ImuRecording, RowLines, Table};
use dynacal::model::fitted::imu_channel_of_name;
use dynacal::model::{fitted_model_of, SimModel};
use dynacal::redundancy::{redundancy as redundancy_of, RedundancyOptions};
use dynacal::sim::{simulate as run_simulation, Scenario, SimOptions};
use dynacal::wv::{WaveletVariance, WvOptions};
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyDict;

create_exception!(
    _dynacal,
    DynacalError,
    PyException,
    "An error of the dynacal library, with its message as the command line prints it."
);

/// The library's error as a `DynacalError`.
fn raise(error: &(dyn std::error::Error + 'static)) -> PyErr {
    DynacalError::new_err(dynacal::error_message(error))
}

/// A message of this module's own as a `DynacalError`.
fn refuse(message: String) -> PyErr {
    DynacalError::new_err(message)
}

fn to_json<T: serde::Serialize>(value: &T) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| raise(&e))
}

/// The samples of a numpy array, copied only when the array is not contiguous.
fn samples<'a>(x: &'a PyReadonlyArray1<'_, f64>) -> std::borrow::Cow<'a, [f64]> {
    match x.as_slice() {
        Ok(s) => std::borrow::Cow::Borrowed(s),
        Err(_) => std::borrow::Cow::Owned(x.as_array().to_vec()),
    }
}

fn wv_options(robust: bool, efficiency: f64, max_level: Option<u32>) -> WvOptions {
    WvOptions {
        max_level,
        robust,
        efficiency,
    }
}

/// Haar wavelet variance of `x` (any unit) sampled every `dt_s` s, as `dynacal wv` computes a
/// column: integer-valued samples are taken as counts and summed exactly. JSON of
/// `dynacal::wv::WaveletVariance`.
#[pyfunction]
#[pyo3(signature = (x, dt_s, robust=false, efficiency=0.6, max_level=None))]
fn wavelet_variance(
    py: Python<'_>,
    x: PyReadonlyArray1<'_, f64>,
    dt_s: f64,
    robust: bool,
    efficiency: f64,
    max_level: Option<u32>,
) -> PyResult<String> {
    let x = samples(&x);
    let opts = wv_options(robust, efficiency, max_level);
    let wv = py
        .detach(|| wavelet_variance_of(x, 1.0, dt_s, &opts))
        .map_err(|e| raise(&e))?;
    to_json(&wv)
}

/// The model choice of a `model` argument: "auto" or a structure such as "WN+RW+GM".
fn model_choice(model: &str) -> PyResult<ModelChoice> {
    if model.trim().eq_ignore_ascii_case("auto") {
        return Ok(ModelChoice::Auto);
    }
    Structure::parse(model)
        .map(ModelChoice::Fixed)
        .map_err(|e| refuse(format!("model {model:?}: {e}")))
}

/// The SI unit of a channel named as the interchange names it (`gx`, `imu2/az`), else
/// "unit".
fn unit_of_channel(channel: &str) -> &'static str {
    imu_channel_of_name(channel).map_or("unit", |(_, c)| c.si_unit())
}

/// GMWM fit of one channel's wavelet variance (the JSON of [`wavelet_variance`] or of a
/// `dynacal wv` channel), as `dynacal fit` fits each channel. Returns the JSON object
/// `{"fit": ChannelFit, "model": model file, "notes": [...]}`.
#[pyfunction]
#[pyo3(signature = (wv_json, model="auto", channel="x", unit=None, bootstrap=0, seed=1))]
fn fit_wavelet_variance(
    py: Python<'_>,
    wv_json: &str,
    model: &str,
    channel: &str,
    unit: Option<&str>,
    bootstrap: usize,
    seed: u64,
) -> PyResult<String> {
    let wv: WaveletVariance = serde_json::from_str(wv_json)
        .map_err(|e| refuse(format!("not a wavelet variance: {e}")))?;
    let choice = model_choice(model)?;
    let unit = unit.unwrap_or_else(|| unit_of_channel(channel)).to_string();
    let boot = (bootstrap > 0).then_some(BootstrapOptions {
        replicates: bootstrap,
        seed,
    });
    let fit = py
        .detach(|| {
            let input = FitInput::from_wv(&wv)?;
            analyze(
                channel,
                &unit,
                &input,
                &choice,
                boot,
                &FitOptions::default(),
            )
        })
        .map_err(|e| refuse(format!("channel {channel}: {}", dynacal::error_message(&e))))?;
    let fits = [fit];
    let (model_file, notes) =
        fitted_model_of("imu1", "a Python array", model, &fits).map_err(|e| raise(&e))?;
    let [fit] = fits;
    to_json(&serde_json::json!({ "fit": fit, "model": model_file, "notes": notes }))
}

/// A recording's interchange columns as numpy arrays, in the order a file holds them.
fn recording_columns<'py>(py: Python<'py>, rec: &ImuRecording) -> PyResult<Bound<'py, PyDict>> {
    let columns = PyDict::new(py);
    for (name, values) in rec.named_columns() {
        columns.set_item(name, PyArray1::from_slice(py, values))?;
    }
    Ok(columns)
}

/// One recording for Python: `(name, columns, sample_rate_hz)`.
type PyRecording<'py> = (String, Bound<'py, PyDict>, Option<f64>);

fn py_recording<'py>(
    py: Python<'py>,
    name: String,
    rec: &ImuRecording,
) -> PyResult<PyRecording<'py>> {
    Ok((name, recording_columns(py, rec)?, rec.sample_rate_hz))
}

/// Every sensor of a file dynacal reads: a dataset `dynacal import` knows (interchange CSV,
/// CSV.gz or Parquet; ROS bags; PX4 ULog; ArduPilot DataFlash; Xsens DOT; the shared
/// datasets), else a board log (`dynacal decode`). The list of `(name, columns, rate)`, and
/// what the importer found worth telling (a ROS bag's topics left out and why), which the
/// command line prints and the Python layer raises as warnings.
#[pyfunction]
fn read(py: Python<'_>, path: PathBuf) -> PyResult<(Vec<PyRecording<'_>>, Vec<String>)> {
    let (sensors, notes) = py.detach(|| read_sensors(&path))?;
    let recordings = sensors
        .into_iter()
        .map(|(name, rec)| py_recording(py, name, &rec))
        .collect::<PyResult<_>>()?;
    Ok((recordings, notes))
}

/// The sensors a file holds, and the importer's notes on it.
type Sensors = (Vec<(String, ImuRecording)>, Vec<String>);

fn read_sensors(path: &Path) -> PyResult<Sensors> {
    if let Some(dataset) = detect(path).map_err(|e| raise(&e))? {
        let (sensors, notes) = import_file_noted(path, dataset).map_err(|e| raise(&e))?;
        let sensors = sensors.into_iter().map(|s| (s.name, s.recording)).collect();
        return Ok((sensors, notes));
    }
    // Not a dataset's file: a board log, or nothing dynacal reads.
    let log = decode_file(path).map_err(|e| raise(&e))?;
    log.validate(path).map_err(|e| {
        refuse(format!(
            "{}: not a file dynacal reads (no known dataset, interchange or flight-log \
             form; as a board log: {})",
            path.display(),
            dynacal::error_message(&e)
        ))
    })?;
    let sensors = log
        .imus
        .iter()
        .filter(|imu| !imu.is_empty())
        .map(|imu| (format!("imu{}", imu.config.imu_id), imu.to_recording()))
        .collect();
    Ok((sensors, Vec::new()))
}

/// A recording from named interchange columns (`t_s`, `gx_rad_s`, ...), checked as a file
/// read is; `name` stands for the file in errors.
fn recording_from_columns(
    name: &str,
    columns: Vec<(String, PyReadonlyArray1<'_, f64>)>,
    sample_rate_hz: Option<f64>,
) -> PyResult<ImuRecording> {
    let (headers, columns): (Vec<String>, Vec<Vec<f64>>) = columns
        .into_iter()
        .map(|(h, c)| (h, samples(&c).into_owned()))
        .unzip();
    let table = Table {
        path: PathBuf::from(name),
        headers,
        columns,
        row_lines: RowLines::Unknown,
    };
    let mut rec = ImuRecording::from_table(table).map_err(|e| raise(&e))?;
    rec.sample_rate_hz = sample_rate_hz;
    Ok(rec)
}

/// The redundancy analysis of `dynacal redundancy` on three or more units sampled together:
/// each `(name, columns, sample_rate_hz)`. JSON of `dynacal::redundancy::RedundancyReport`.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn redundancy(
    py: Python<'_>,
    units: Vec<(
        String,
        Vec<(String, PyReadonlyArray1<'_, f64>)>,
        Option<f64>,
    )>,
) -> PyResult<String> {
    let units: Vec<(String, ImuRecording)> = units
        .into_iter()
        .map(|(name, columns, rate)| {
            Ok((name.clone(), recording_from_columns(&name, columns, rate)?))
        })
        .collect::<PyResult<_>>()?;
    let report = py
        .detach(|| redundancy_of(&units, &RedundancyOptions::default()))
        .map_err(|e| raise(&e))?;
    to_json(&report)
}

/// A simulation as `dynacal simulate` runs it, from model-file text (a model file, `dynacal
/// fit`'s output, a bare GMWM model). Returns `(reference, imus, truth_json)`, each
/// recording as [`read`] gives it.
#[pyfunction]
#[pyo3(signature = (model_json, seconds, seed=1, scenario="car"))]
#[allow(clippy::type_complexity)]
fn simulate<'py>(
    py: Python<'py>,
    model_json: &str,
    seconds: f64,
    seed: u64,
    scenario: &str,
) -> PyResult<(PyRecording<'py>, Vec<PyRecording<'py>>, String)> {
    let model = SimModel::from_json(model_json, Path::new("the model")).map_err(|e| raise(&e))?;
    let scenario = match scenario {
        "car" => Scenario::Car,
        "static" => Scenario::Static,
        other => {
            return Err(refuse(format!(
                "scenario {other:?}: one of \"car\", \"static\""
            )))
        }
    };
    let opts = SimOptions::run(scenario, seconds, seed);
    let out = py
        .detach(|| run_simulation(&model, &opts, &|_| {}))
        .map_err(|e| raise(&e))?;
    let reference = py_recording(py, out.reference.name.clone(), &out.reference.recording)?;
    let imus = out
        .imus
        .iter()
        .map(|imu| py_recording(py, imu.name.clone(), &imu.recording))
        .collect::<PyResult<_>>()?;
    Ok((reference, imus, to_json(&out.truth)?))
}

#[pymodule]
fn _dynacal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("DynacalError", m.py().get_type::<DynacalError>())?;
    m.add_function(wrap_pyfunction!(wavelet_variance, m)?)?;
    m.add_function(wrap_pyfunction!(fit_wavelet_variance, m)?)?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(redundancy, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    Ok(())
}
