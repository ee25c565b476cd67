//! What `dynacal fit` and `dynacal compare` read: the wavelet variance of each channel of an
//! interchange CSV, of any other CSV with a `t_s` column (e.g. an error-signal file of
//! `dynacal errors`: its channels are the error columns, chosen by name), of any CSV by
//! column name (rate, scale and unit given), or WVs stored as
//! JSON (the output of `dynacal wv`: one WV object, a map of channel -> WV object, or
//! `{"channels": ...}` of either; and the SMAC-Group reference file with its sensor keys).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::error_signal::ERROR_COLUMNS;
use crate::interchange::{
    open_maybe_gz, read_table, ImuRecording, TableError, CHANNELS, CHANNEL_COLUMNS,
};
use crate::wv::{haar_wv, read_smac_golden, WaveletVariance, WvError, WvOptions};

/// Errors reading fit inputs; each names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InputError {
    #[error(transparent)]
    Table(#[from] TableError),
    #[error(transparent)]
    Wv(#[from] WvError),
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

/// One channel's WV and its unit.
#[derive(Debug, Clone)]
pub struct ChannelWv {
    pub channel: String,
    pub unit: String,
    pub wv: WaveletVariance,
}

/// How to read plain CSVs and which channels to keep.
#[derive(Debug, Clone, Default)]
pub struct ReadOptions {
    /// Channels (or column names) to keep; all when empty.
    pub columns: Vec<String>,
    /// Sample rate of a CSV without a `t_s` column, Hz.
    pub rate_hz: Option<f64>,
    /// Multiplier per column of a plain CSV (key "" = every column), e.g. LSB sizes.
    pub scale: BTreeMap<String, f64>,
    /// Unit per column of a plain CSV (key "" = every column).
    pub unit: BTreeMap<String, String>,
    /// WV options for series.
    pub wv: WvOptions,
}

fn lookup<'a, T>(map: &'a BTreeMap<String, T>, key: &str) -> Option<&'a T> {
    map.get(key).or_else(|| map.get(""))
}

fn is_json(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

/// Reads every wanted channel of `path` as a WV.
pub fn load_channels(path: &Path, opts: &ReadOptions) -> Result<Vec<ChannelWv>, InputError> {
    let fmt = |message: String| InputError::Format {
        path: path.to_path_buf(),
        message,
    };
    let mut out = if is_json(path) {
        load_json(path)?
    } else {
        load_series(path, opts)?
    };
    if !opts.columns.is_empty() {
        for c in &opts.columns {
            if !out.iter().any(|x| &x.channel == c) {
                return Err(fmt(format!(
                    "no channel `{c}` (available: {})",
                    out.iter()
                        .map(|x| x.channel.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
        }
        out.retain(|x| opts.columns.contains(&x.channel));
    }
    if out.is_empty() {
        return Err(fmt("no channel to fit".into()));
    }
    Ok(out)
}

fn load_series(path: &Path, opts: &ReadOptions) -> Result<Vec<ChannelWv>, InputError> {
    let fmt = |message: String| InputError::Format {
        path: path.to_path_buf(),
        message,
    };
    let header: Vec<String> = {
        let mut reader = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .from_reader(open_maybe_gz(path)?);
        reader
            .headers()
            .map_err(|e| fmt(format!("line 1: {e}")))?
            .iter()
            .map(str::to_string)
            .collect()
    };
    let is_interchange = header
        .iter()
        .any(|c| CHANNEL_COLUMNS.contains(&c.as_str()) || CHANNELS.contains(&c.as_str()));
    if header.iter().any(|c| c == "t_s") && !is_interchange {
        return load_timed_columns(path, &header, opts);
    }
    if header.iter().any(|c| c == "t_s") {
        let rec = ImuRecording::read(path)?;
        let dt = rec.median_dt_s();
        let mut out = Vec::new();
        for name in rec.channels() {
            if !opts.columns.is_empty() && !opts.columns.iter().any(|c| c == name) {
                continue;
            }
            let x = rec.channel(name).expect("listed channel");
            let unit = if CHANNELS[..3].contains(&name) {
                "rad/s"
            } else {
                "m/s^2"
            };
            out.push(ChannelWv {
                channel: name.to_string(),
                unit: unit.to_string(),
                wv: haar_wv(x, dt, &opts.wv)?,
            });
        }
        return Ok(out);
    }
    let rate = opts
        .rate_hz
        .ok_or_else(|| fmt("no `t_s` column: give the sample rate (--rate-hz)".into()))?;
    if !(rate.is_finite() && rate > 0.0) {
        return Err(fmt(format!("bad sample rate {rate} Hz")));
    }
    let wanted: Vec<&str> = opts.columns.iter().map(|s| s.as_str()).collect();
    let table = read_table(
        path,
        if wanted.is_empty() {
            None
        } else {
            Some(&wanted)
        },
    )?;
    let mut out = Vec::new();
    for name in table.headers.clone() {
        if !wanted.is_empty() && !wanted.contains(&name.as_str()) {
            continue;
        }
        let scale = *lookup(&opts.scale, &name).unwrap_or(&1.0);
        let unit = lookup(&opts.unit, &name)
            .cloned()
            .unwrap_or_else(|| "unit".into());
        let x: Vec<f64> = table
            .column(&name)
            .expect("listed column")
            .iter()
            .map(|v| v * scale)
            .collect();
        out.push(ChannelWv {
            channel: name,
            unit,
            wv: haar_wv(&x, 1.0 / rate, &opts.wv)?,
        });
    }
    Ok(out)
}

/// Unit of a column named with the project's unit suffix (`gy_err_rad_s` -> rad/s).
fn unit_from_suffix(name: &str) -> Option<&'static str> {
    [
        ("_rad_s3", "rad/s^3"),
        ("_rad_s2", "rad/s^2"),
        ("_rad_s", "rad/s"),
        ("_m_s3", "m/s^3"),
        ("_m_s2", "m/s^2"),
        ("_m_s", "m/s"),
    ]
    .iter()
    .find(|(suffix, _)| name.ends_with(suffix))
    .map(|(_, unit)| *unit)
}

/// A CSV with a `t_s` column that is not an interchange recording. The sample interval is the
/// median step of `t_s`. Without `--columns`, an error-signal file contributes its six error
/// columns (the dynamics columns beside them are regressors, not sensor errors) and any
/// other file every column but `t_s`.
fn load_timed_columns(
    path: &Path,
    header: &[String],
    opts: &ReadOptions,
) -> Result<Vec<ChannelWv>, InputError> {
    let fmt = |message: String| InputError::Format {
        path: path.to_path_buf(),
        message,
    };
    let mut wanted: Vec<&str> = if !opts.columns.is_empty() {
        opts.columns.iter().map(String::as_str).collect()
    } else if header.iter().any(|h| ERROR_COLUMNS.contains(&h.as_str())) {
        ERROR_COLUMNS
            .iter()
            .copied()
            .filter(|c| header.iter().any(|h| h == c))
            .collect()
    } else {
        header
            .iter()
            .map(String::as_str)
            .filter(|h| *h != "t_s")
            .collect()
    };
    if let Some(missing) = opts
        .columns
        .iter()
        .find(|c| !header.iter().any(|h| h == *c) || *c == "t_s")
    {
        return Err(fmt(format!(
            "no channel `{missing}` (available: {})",
            header
                .iter()
                .filter(|h| *h != "t_s")
                .map(String::as_str)
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    if wanted.is_empty() {
        return Err(fmt("no column besides `t_s`".into()));
    }
    wanted.push("t_s");
    let table = read_table(path, Some(&wanted))?;
    wanted.pop();
    let t_s = table.column("t_s").expect("t_s is in the header");
    let mut dt: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
    if dt.is_empty() {
        return Err(fmt("fewer than two rows: no sample interval".into()));
    }
    dt.sort_by(f64::total_cmp);
    let dt_s = dt[dt.len() / 2];
    if !(dt_s.is_finite() && dt_s > 0.0) {
        return Err(fmt(format!(
            "`t_s` does not increase (median step {dt_s} s)"
        )));
    }
    wanted
        .iter()
        .map(|name| {
            let scale = *lookup(&opts.scale, name).unwrap_or(&1.0);
            let unit = lookup(&opts.unit, name)
                .cloned()
                .or_else(|| unit_from_suffix(name).map(str::to_string))
                .unwrap_or_else(|| "unit".into());
            let x: Vec<f64> = table
                .column(name)
                .expect("read column")
                .iter()
                .map(|v| v * scale)
                .collect();
            Ok(ChannelWv {
                channel: (*name).to_string(),
                unit,
                wv: haar_wv(&x, dt_s, &opts.wv)?,
            })
        })
        .collect()
}

fn load_json(path: &Path) -> Result<Vec<ChannelWv>, InputError> {
    let fmt = |message: String| InputError::Format {
        path: path.to_path_buf(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| fmt(e.to_string()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| fmt(format!("not JSON: {e}")))?;
    let obj = value
        .as_object()
        .ok_or_else(|| fmt("expected a JSON object".into()))?;
    // The SMAC-Group reference file: {sensor: {sensor, freq, n, wvar: {...}}}.
    if !obj.is_empty() && obj.values().all(|v| v.get("wvar").is_some()) {
        return Ok(read_smac_golden(path)?
            .into_iter()
            .map(|g| {
                let key = g
                    .channel_key()
                    .map(str::to_string)
                    .unwrap_or(g.channel.clone());
                let gyro = g.channel.starts_with("Gyro");
                // Units: the README of the data gives deg/s and g for ADIS16405; the other
                // sensors' source states none.
                let unit = match (g.sensor_key.as_str(), gyro) {
                    ("adis", true) => "deg/s",
                    ("adis", false) => "g",
                    _ => "unstated",
                };
                ChannelWv {
                    channel: format!("{}/{}", g.sensor_key, key),
                    unit: unit.to_string(),
                    wv: g.wv,
                }
            })
            .collect());
    }
    let single = |name: &str, v: &serde_json::Value| -> Result<ChannelWv, InputError> {
        let wv: WaveletVariance = serde_json::from_value(v.clone())
            .map_err(|e| fmt(format!("channel `{name}`: not a wavelet variance: {e}")))?;
        let channel = v
            .get("channel")
            .and_then(|c| c.as_str())
            .unwrap_or(name)
            .to_string();
        let unit = v
            .get("unit")
            .and_then(|c| c.as_str())
            .unwrap_or("unit")
            .to_string();
        Ok(ChannelWv { channel, unit, wv })
    };
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    if obj.contains_key("variance") && obj.contains_key("levels") {
        return Ok(vec![single(&stem, &value)?]);
    }
    let container = obj.get("channels").unwrap_or(&value);
    match container {
        serde_json::Value::Array(items) => items
            .iter()
            .enumerate()
            .map(|(i, v)| single(&format!("{stem}[{i}]"), v))
            .collect(),
        serde_json::Value::Object(map) => map
            .iter()
            .filter(|(_, v)| v.is_object())
            .map(|(k, v)| single(k, v))
            .collect(),
        _ => Err(fmt("no wavelet variance found".into())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An interchange recording keeps its channel names (gx..az) and SI units: `dynacal
    /// diagnose` looks its baseline models up by those names.
    #[test]
    fn interchange_recording_channels_are_named_gx_to_az() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rec.csv");
        let mut text = String::from("t_s,gx_rad_s,gy_rad_s,gz_rad_s,ax_m_s2,ay_m_s2,az_m_s2\n");
        for k in 0..512 {
            let v = ((k * 7919) % 101) as f64 * 1e-3;
            text.push_str(&format!(
                "{},{v},{v},{v},{v},{v},{}\n",
                k as f64 * 0.01,
                v - 9.8
            ));
        }
        std::fs::write(&path, text).unwrap();
        let chans = load_channels(&path, &ReadOptions::default()).unwrap();
        let names: Vec<&str> = chans.iter().map(|c| c.channel.as_str()).collect();
        assert_eq!(names, CHANNELS.to_vec());
        assert_eq!(chans[0].unit, "rad/s");
        assert_eq!(chans[5].unit, "m/s^2");
    }
}
