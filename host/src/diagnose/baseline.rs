//! The baseline: the stochastic error model per channel that the measured error is compared
//! with. It is read from a model file (the output of `dynacal fit`, or an earlier extended
//! model), or, without one, fitted on the quietest stretch of the run (where the
//! dynamics-driven terms are smallest).

use std::collections::BTreeMap;

use super::engine::DiagnoseError;
use super::gain::fit_wv;
use super::signals::RunSignals;
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, ModelChoice};
use crate::gmwm::model::ModelSpec;
use crate::model::{fitted_record_samples, Channel, ModelFileError, SimModel};

/// The baseline stochastic model per channel, in SI units (rad/s, m/s^2).
#[derive(Debug, Clone)]
pub struct Baseline {
    pub channels: BTreeMap<Channel, ModelSpec>,
    /// Per channel, the samples of the record its model was fitted on. The simulations that
    /// calibrate the tests then draw the model from its sampling distribution at that
    /// length (a fit is not the truth); a channel missing here is taken as exactly known,
    /// and the report says so.
    pub record_samples: BTreeMap<Channel, usize>,
    /// Where it came from, in words.
    pub source: String,
}

impl Baseline {
    /// Reads a model file (`docs/formats.md` section 3) with one MEMS IMU: the output of
    /// `dynacal fit`, the extended model of an earlier diagnosis, or a simulator model. The
    /// stochastic model of each of its channels, restated in SI units, is the baseline.
    pub fn load(path: &std::path::Path) -> Result<Self, DiagnoseError> {
        let err = |e: ModelFileError| DiagnoseError::Baseline {
            path: path.display().to_string(),
            message: e.to_string(),
        };
        let model = SimModel::load(path).map_err(err)?;
        let channels = model.stochastic_si(path).map_err(err)?;
        let record_samples = fitted_record_samples(&model)
            .into_iter()
            .filter(|(c, _)| channels.contains_key(c))
            .collect();
        Ok(Self {
            channels,
            record_samples,
            source: format!("file {}", path.display()),
        })
    }
}

/// Fits a baseline on the quietest stretch (lowest mean |omega|, a quarter of the run).
/// The stretch's wavelet variance is the noise refits' ([`fit_wv`]: batch up to
/// [`crate::wv::GATHERED_SAMPLES`], streamed above), so a long run's quarter is never held.
pub(super) fn fit_quietest(
    signals: &RunSignals,
    channels: &[Channel],
    dt_s: f64,
) -> Result<Baseline, DiagnoseError> {
    let n = signals.epochs();
    let w = (n / 4).max(256).min(n);
    let best = quietest_window(signals, w)?;
    let mut out = BTreeMap::new();
    for &channel in channels {
        let err = |message: String| DiagnoseError::Channel { channel, message };
        let wv = signals
            .with_error_in(channel, best.0..best.0 + w, |e| fit_wv(e, dt_s))?
            .map_err(|x| err(x.to_string()))?;
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
        record_samples: out.keys().map(|c| (*c, w)).collect(),
        channels: out,
        source: format!(
            "fitted (model auto) on the quietest stretch t = {:.1}..{:.1} s (mean |omega| {:.4} rad/s)",
            signals.time_at_s(best.0)?,
            signals.time_at_s(best.0 + w - 1)?,
            best.1
        ),
    })
}

/// The start of the window of `w` epochs, among those starting every `w / 8`, with the
/// lowest mean |omega| (the first such), and that mean, rad/s; |omega| read a block at a
/// time.
fn quietest_window(signals: &RunSignals, w: usize) -> Result<(usize, f64), DiagnoseError> {
    let mut scan = QuietestWindow::new(signals.epochs(), w);
    signals.for_each_angular_rate_norm(0..signals.epochs(), &mut |epochs, norm| {
        scan.push(epochs.start, norm)
    })?;
    Ok(scan.best)
}

/// The scan of [`quietest_window`] over a series fed a block at a time: each window summed
/// from its start in order as it goes by (at most nine open), so the means are those of
/// the series held whole, to the bit.
struct QuietestWindow {
    n: usize,
    w: usize,
    step: usize,
    /// The windows being summed, oldest first: (start, sum so far).
    open: std::collections::VecDeque<(usize, f64)>,
    /// The first window with the lowest mean so far: (start, mean).
    best: (usize, f64),
}

impl QuietestWindow {
    fn new(n: usize, w: usize) -> Self {
        QuietestWindow {
            n,
            w,
            step: (w / 8).max(1),
            open: Default::default(),
            best: (0, f64::INFINITY),
        }
    }

    /// Feeds the values of epochs `first..first + values.len()` (the next ones).
    fn push(&mut self, first: usize, values: &[f64]) {
        for (p, &v) in (first..).zip(values) {
            if p % self.step == 0 && p + self.w <= self.n {
                self.open.push_back((p, 0.0));
            }
            self.open.iter_mut().for_each(|(_, sum)| *sum += v);
            if let Some(&(start, sum)) = self.open.front() {
                if p + 1 == start + self.w {
                    self.open.pop_front();
                    let mean = sum / self.w as f64;
                    if mean < self.best.1 {
                        self.best = (start, mean);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gmwm::model::Process;
    use rand::{Rng, SeedableRng};
    use serde_json::json;

    /// The scan over the series held whole that the streamed one replaced.
    fn quietest_held(x: &[f64], w: usize) -> (usize, f64) {
        let (n, step) = (x.len(), (w / 8).max(1));
        let mut best = (0usize, f64::INFINITY);
        let mut start = 0;
        while start + w <= n {
            let m = x[start..start + w].iter().sum::<f64>() / w as f64;
            if m < best.1 {
                best = (start, m);
            }
            start += step;
        }
        best
    }

    #[test]
    fn the_quietest_window_fed_in_blocks_is_the_one_held_whole_to_the_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(62);
        for (n, block) in [
            (1_000, 7),
            (5_003, 1_024),
            (40_000, 16_384),
            (300, 300),
            (9, 4),
        ] {
            // |omega| of a drive: quiet stretches among turns, so the choice is not the first.
            let x: Vec<f64> = (0..n)
                .map(|k| {
                    let turning = (k / 250) % 3 != 1;
                    rng.random::<f64>() * if turning { 0.5 } else { 0.01 }
                })
                .collect();
            let w = (n / 4).max(256).min(n);
            let mut scan = QuietestWindow::new(n, w);
            for (i, part) in x.chunks(block).enumerate() {
                scan.push(i * block, part);
            }
            let held = quietest_held(&x, w);
            assert_eq!(scan.best.0, held.0, "n {n}");
            assert_eq!(scan.best.1.to_bits(), held.1.to_bits(), "n {n}");
        }
    }

    #[test]
    fn baseline_reads_model_files_old_fit_outputs_and_restates_units_in_si() {
        let dir = tempfile::tempdir().unwrap();
        let model = |unit: &str| {
            json!({"model": "WN", "unit": unit, "sample_rate_hz": 100.0,
                   "processes": [{"kind": "white_noise", "sigma2": 1e-6}]})
        };
        // A `dynacal fit` output of before the model file had a version.
        let old = dir.path().join("fit.json");
        let list = json!({"channels": [{"channel": "gx", "model_object": model("rad/s")},
                                       {"channel": "ax", "model_object": model("m/s^2")}]});
        std::fs::write(&old, list.to_string()).unwrap();
        let b = Baseline::load(&old).unwrap();
        assert_eq!(
            b.channels.keys().copied().collect::<Vec<_>>(),
            vec![Channel::Gx, Channel::Ax]
        );
        assert_eq!(
            b.channels[&Channel::Gx].processes,
            vec![Process::WhiteNoise { sigma2: 1e-6 }]
        );

        // A model file in deg/s: the baseline is in rad/s.
        let deg = dir.path().join("deg.json");
        let file = json!({"version": 1, "imus": [{"name": "a", "rate_hz": 100,
                          "channels": {"gz": {"stochastic": model("deg/s")}}}]});
        std::fs::write(&deg, file.to_string()).unwrap();
        let b = Baseline::load(&deg).unwrap();
        let gz = &b.channels[&Channel::Gz];
        assert_eq!(gz.unit, "rad/s");
        let Process::WhiteNoise { sigma2 } = gz.processes[0] else {
            panic!("{gz:?}")
        };
        assert!((sigma2 / (1e-6 * (std::f64::consts::PI / 180.0).powi(2)) - 1.0).abs() < 1e-12);

        // Two IMUs: which one is the baseline is not said, so it is an error naming the field.
        let two = dir.path().join("two.json");
        let file = json!({"imus": [{"name": "a", "rate_hz": 100, "gyro": {"stochastic": model("rad/s")}},
                                   {"name": "b", "rate_hz": 100, "gyro": {"stochastic": model("rad/s")}}]});
        std::fs::write(&two, file.to_string()).unwrap();
        let msg = Baseline::load(&two).unwrap_err().to_string();
        assert!(
            msg.contains("two.json") && msg.contains("`imus`") && msg.contains("a, b"),
            "{msg}"
        );
    }
}
