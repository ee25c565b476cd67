//! The baseline: the stochastic error model per channel that the measured error is compared
//! with. It is read from the output of `dynacal fit`, or, without one, fitted on the quietest
//! stretch of the run (where the dynamics-driven terms are smallest).

use std::collections::BTreeMap;

use serde_json::Value;

use super::engine::DiagnoseError;
use crate::error_signal::ErrorSignals;
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, ModelChoice};
use crate::gmwm::model::ModelSpec;
use crate::model::Channel;
use crate::wv::{haar_wv, WvOptions};

/// The baseline stochastic model per channel, in SI units (rad/s, m/s^2).
#[derive(Debug, Clone)]
pub struct Baseline {
    pub channels: BTreeMap<Channel, ModelSpec>,
    /// Where it came from, in words.
    pub source: String,
}

impl Baseline {
    /// Reads the JSON written by `dynacal fit` (`{"channels": [{"channel": "gx", "model_object": ..}]}`).
    pub fn load(path: &std::path::Path) -> Result<Self, DiagnoseError> {
        let err = |message: String| DiagnoseError::Baseline {
            path: path.display().to_string(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        let v: Value = serde_json::from_str(&text).map_err(|e| err(format!("not JSON: {e}")))?;
        // `dynacal fit` writes a list of channel fits, each naming its channel; a map keyed
        // by channel is accepted too.
        let entries: Vec<(String, &Value)> = match v.get("channels") {
            Some(Value::Array(list)) => list
                .iter()
                .enumerate()
                .map(|(i, ch)| {
                    ch.get("channel")
                        .and_then(Value::as_str)
                        .map(|name| (name.to_string(), ch))
                        .ok_or_else(|| err(format!("channels[{i}]: no `channel` name")))
                })
                .collect::<Result<_, _>>()?,
            Some(Value::Object(map)) => map.iter().map(|(k, ch)| (k.clone(), ch)).collect(),
            _ => {
                return Err(err(
                    "no `channels` list (expected the output of `dynacal fit`)".into(),
                ))
            }
        };
        let mut out = BTreeMap::new();
        for (name, ch) in entries {
            let channel: Channel = name
                .parse()
                .map_err(|e| err(format!("channels.{name}: {e}")))?;
            let obj = ch
                .get("model_object")
                .ok_or_else(|| err(format!("channels.{name}: no `model_object`")))?;
            let spec = ModelSpec::from_json(&obj.to_string())
                .map_err(|e| err(format!("channels.{name}.model_object: {e}")))?;
            let si = matches!(
                spec.unit.replace(' ', "").as_str(),
                "rad/s" | "m/s^2" | "m/s2"
            );
            if !si {
                return Err(err(format!(
                    "channels.{name}: unit `{}` is not SI (fit the interchange file, which is in rad/s and m/s^2)",
                    spec.unit
                )));
            }
            out.insert(channel, spec);
        }
        Ok(Self {
            channels: out,
            source: format!("file {}", path.display()),
        })
    }
}

/// Fits a baseline on the quietest stretch (lowest mean |omega|, a quarter of the run).
pub(super) fn fit_quietest(
    signals: &ErrorSignals,
    channels: &[Channel],
    omega_norm: &[f64],
    dt_s: f64,
) -> Result<Baseline, DiagnoseError> {
    let n = signals.t_s.len();
    let w = (n / 4).max(256).min(n);
    let mut best = (0usize, f64::INFINITY);
    let step = (w / 8).max(1);
    let mut start = 0;
    while start + w <= n {
        let m = omega_norm[start..start + w].iter().sum::<f64>() / w as f64;
        if m < best.1 {
            best = (start, m);
        }
        start += step;
    }
    let mut out = BTreeMap::new();
    for &channel in channels {
        let e = &signals.error_of(channel).expect("channel")[best.0..best.0 + w];
        let err = |message: String| DiagnoseError::Channel { channel, message };
        let wv = haar_wv(e, dt_s, &WvOptions::default()).map_err(|x| err(x.to_string()))?;
        let input = FitInput::from_wv(&wv).map_err(|x| err(x.to_string()))?;
        let fit = analyze(
            channel.name(),
            channel.si_unit(),
            &input,
            &ModelChoice::Auto,
            None,
            &FitOptions::default(),
        )
        .map_err(|x| err(x.to_string()))?;
        out.insert(channel, fit.model_object);
    }
    Ok(Baseline {
        channels: out,
        source: format!(
            "fitted (model auto) on the quietest stretch t = {:.1}..{:.1} s (mean |omega| {:.4} rad/s)",
            signals.t_s[best.0],
            signals.t_s[best.0 + w - 1],
            best.1
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gmwm::model::Process;
    use serde_json::json;

    #[test]
    fn baseline_reads_the_fit_output_and_rejects_non_si_units() {
        let dir = tempfile::tempdir().unwrap();
        let model = |unit: &str| {
            json!({"model": "WN", "unit": unit, "sample_rate_hz": 100.0,
                   "processes": [{"kind": "white_noise", "sigma2": 1e-6}]})
        };
        let good = dir.path().join("fit.json");
        let list = json!({"channels": [{"channel": "gx", "model_object": model("rad/s")},
                                       {"channel": "ax", "model_object": model("m/s^2")}]});
        std::fs::write(&good, list.to_string()).unwrap();
        let b = Baseline::load(&good).unwrap();
        assert_eq!(
            b.channels.keys().copied().collect::<Vec<_>>(),
            vec![Channel::Gx, Channel::Ax]
        );
        assert_eq!(
            b.channels[&Channel::Gx].processes,
            vec![Process::WhiteNoise { sigma2: 1e-6 }]
        );

        let bad = dir.path().join("deg.json");
        std::fs::write(
            &bad,
            json!({"channels": [{"channel": "gx", "model_object": model("deg/s")}]}).to_string(),
        )
        .unwrap();
        let msg = Baseline::load(&bad).unwrap_err().to_string();
        assert!(msg.contains("deg.json") && msg.contains("not SI"), "{msg}");
    }
}
