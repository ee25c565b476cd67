//! Prewhitening by a channel's noise model, for generalised least squares. A channel's
//! baseline noise (white noise, Gauss-Markov and random-walk processes) is a linear
//! state-space model; the Kalman filter's innovations, each divided by its standard
//! deviation, are white with unit variance when the model holds. The same filter applied to
//! a regressor gives the regressor as that noise sees it, and least squares on filtered
//! series is generalised least squares. Why: a 20 s Gauss-Markov wander projects heavily on
//! slow manoeuvres (a car's turns), so ordinary least squares leaves a turning term's
//! coefficient with the wander's spread; the filter weighs each manoeuvre by what the white
//! noise, not the wander, leaves of it. The filter is linear and fixed by the baseline, not
//! by the data, so estimates stay unbiased when the model is wrong; only their efficiency
//! suffers, and the spreads the engine reports come from simulations through the same filter.

use crate::gmwm::model::{ModelSpec, Process};

/// The Kalman filter of one channel's noise model, its gains precomputed until they settle.
#[derive(Debug, Clone)]
pub(super) struct Whitener {
    /// Per state: transition factor (exp(-beta dt) for a Gauss-Markov, 1 for a random walk).
    phi: Vec<f64>,
    /// Per epoch until the gains settle (the last one holds after): gain per state and
    /// 1 / sqrt(innovation variance).
    gains: Vec<Vec<f64>>,
    inverse_sd: Vec<f64>,
}

/// Relative change of the innovation variance under which the filter counts as settled.
const SETTLED: f64 = 1e-10;

impl Whitener {
    /// The filter of `spec`: states for its Gauss-Markov and random-walk processes (Gauss-
    /// Markov ones start in their stationary law, a random walk with a variance a thousand
    /// times the observation noise, nearly diffuse); white and quantization noise as the
    /// observation noise (quantization noise, an MA(1) with a unit root that no causal filter
    /// inverts, with its variance 2 Q^2). A drift is deterministic and left to the
    /// calibration's bias. Gains are computed for at most `n` epochs.
    pub fn new(spec: &ModelSpec, n: usize) -> Self {
        let dt = spec.dt_s();
        let mut phi = Vec::new();
        let mut q = Vec::new();
        let mut p0 = Vec::new();
        let mut r = 0.0;
        for p in &spec.processes {
            match *p {
                Process::WhiteNoise { sigma2 } => r += sigma2,
                Process::QuantizationNoise { q2 } => r += 2.0 * q2,
                Process::GaussMarkov { beta_per_s, sigma2 } => {
                    phi.push((-beta_per_s * dt).exp());
                    q.push(sigma2 * -(-2.0 * beta_per_s * dt).exp_m1());
                    p0.push(sigma2);
                }
                Process::RandomWalk { sigma2 } => {
                    phi.push(1.0);
                    q.push(sigma2);
                    p0.push(f64::NAN);
                }
                Process::Drift { .. } => {}
            }
        }
        // A model without white noise still needs an observation variance to divide by.
        let total: f64 =
            r + p0.iter().filter(|v| v.is_finite()).sum::<f64>() + q.iter().sum::<f64>();
        let r = r.max(1e-12 * total).max(f64::MIN_POSITIVE);
        p0.iter_mut()
            .filter(|v| v.is_nan())
            .for_each(|v| *v = 1e3 * r);
        let k = phi.len();
        let mut cov = nalgebra::DMatrix::<f64>::from_diagonal(&nalgebra::DVector::from_vec(p0));
        let f = nalgebra::DMatrix::<f64>::from_diagonal(&nalgebra::DVector::from_vec(phi.clone()));
        let qm = nalgebra::DMatrix::<f64>::from_diagonal(&nalgebra::DVector::from_vec(q));
        let mut gains = Vec::new();
        let mut inverse_sd = Vec::new();
        let mut last_s = f64::INFINITY;
        for _ in 0..n.max(1) {
            // Innovation variance S = H P H' + R with H = [1 ... 1]; gain K = P H' / S.
            let ph: Vec<f64> = (0..k).map(|i| cov.row(i).sum()).collect();
            let s = ph.iter().sum::<f64>() + r;
            let gain: Vec<f64> = ph.iter().map(|v| v / s).collect();
            // Update, then predict: P = F (P - K S K') F' + Q.
            let kv = nalgebra::DVector::from_vec(gain.clone());
            cov = &f * (&cov - &kv * kv.transpose() * s) * &f + &qm;
            gains.push(gain);
            inverse_sd.push(1.0 / s.sqrt());
            if ((s - last_s) / s).abs() < SETTLED {
                break;
            }
            last_s = s;
        }
        Self {
            phi,
            gains,
            inverse_sd,
        }
    }

    /// The standardised innovations of `y` under the model: white with unit variance when
    /// `y` is the model's noise.
    #[cfg(test)]
    pub fn apply(&self, y: &[f64]) -> Vec<f64> {
        let mut out = Vec::with_capacity(y.len());
        self.stream().apply(y, &mut out);
        out
    }

    /// The filter run over a series fed a block at a time, its state carried between blocks.
    pub fn stream(&self) -> WhitenerStream<'_> {
        WhitenerStream {
            whitener: self,
            state: vec![0.0; self.phi.len()],
            t: 0,
        }
    }
}

/// A [`Whitener`] run over a series a block at a time ([`Whitener::stream`]): the same
/// innovations as [`Whitener::apply`] on the series whole.
pub(super) struct WhitenerStream<'w> {
    whitener: &'w Whitener,
    state: Vec<f64>,
    /// Epochs filtered so far.
    t: usize,
}

impl WhitenerStream<'_> {
    /// Appends the innovations of the next block `y` to `out`.
    pub fn apply(&mut self, y: &[f64], out: &mut Vec<f64>) {
        out.extend(y.iter().map(|&v| self.innovation(v)));
    }

    /// Replaces the next block `y` by its innovations.
    pub fn apply_in_place(&mut self, y: &mut [f64]) {
        y.iter_mut().for_each(|v| *v = self.innovation(*v));
    }

    /// The standardised innovation of the next sample `v`.
    fn innovation(&mut self, v: f64) -> f64 {
        let w = self.whitener;
        let e = self.t.min(w.gains.len() - 1);
        let nu = v - self.state.iter().sum::<f64>();
        for ((x, g), phi) in self.state.iter_mut().zip(&w.gains[e]).zip(&w.phi) {
            *x = phi * (*x + g * nu);
        }
        self.t += 1;
        nu * w.inverse_sd[e]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn spec(processes: Vec<Process>) -> ModelSpec {
        ModelSpec {
            model: "test".into(),
            unit: "rad/s".into(),
            sample_rate_hz: 100.0,
            processes,
        }
    }

    fn autocorrelation(x: &[f64], lag: usize) -> f64 {
        let n = x.len();
        let m = x.iter().sum::<f64>() / n as f64;
        let v = x.iter().map(|a| (a - m).powi(2)).sum::<f64>();
        (0..n - lag)
            .map(|t| (x[t] - m) * (x[t + lag] - m))
            .sum::<f64>()
            / v
    }

    /// A MEMS gyro's white noise (4 mrad/s per sample) and 20 s Gauss-Markov wander.
    fn car_gyro_noise() -> Vec<Process> {
        vec![
            Process::WhiteNoise {
                sigma2: 0.004f64.powi(2),
            },
            Process::GaussMarkov {
                beta_per_s: 0.05,
                sigma2: 0.002f64.powi(2),
            },
        ]
    }

    #[test]
    fn the_model_noise_comes_out_white_with_unit_variance() {
        // White noise, a 20 s Gauss-Markov wander and a slow random walk.
        let mut processes = car_gyro_noise();
        processes.push(Process::RandomWalk { sigma2: 1e-10 });
        let model = spec(processes);
        let n = 200_000;
        let y = model.simulate(n, &mut ChaCha8Rng::seed_from_u64(4));
        let whitener = Whitener::new(&model, n);
        let w = whitener.apply(&y);
        // Fed in blocks (the first shorter than the gains' settling), the same innovations.
        let mut stream = whitener.stream();
        let mut blocks = Vec::new();
        y.chunks(777).for_each(|b| stream.apply(b, &mut blocks));
        assert_eq!(blocks, w);
        let mut in_place = y.clone();
        let mut stream = whitener.stream();
        in_place
            .chunks_mut(1000)
            .for_each(|b| stream.apply_in_place(b));
        assert_eq!(in_place, w);
        let tail = &w[1000..];
        let var = tail.iter().map(|v| v * v).sum::<f64>() / tail.len() as f64;
        assert!((var - 1.0).abs() < 0.02, "variance {var}");
        // The raw series is correlated at long lags; its innovations are not.
        assert!(autocorrelation(&y, 1000) > 0.1);
        for lag in [1, 10, 100, 1000] {
            let r = autocorrelation(tail, lag);
            assert!(r.abs() < 0.01, "lag {lag}: {r}");
        }
    }

    #[test]
    fn generalised_least_squares_beats_ordinary_on_a_slow_regressor() {
        // A regressor of slow pulses (10 s turns), noise with a 20 s wander: the coefficient's
        // spread over 200 noise draws, by ordinary and by prewhitened least squares.
        let model = spec(car_gyro_noise());
        let n = 30_000;
        let x: Vec<f64> = (0..n)
            .map(|t| if (t / 1000) % 3 == 1 { 0.2 } else { 0.0 })
            .collect();
        let whitener = Whitener::new(&model, n);
        let wx = whitener.apply(&x);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let (mut ols, mut gls) = (Vec::new(), Vec::new());
        for _ in 0..200 {
            let e = model.simulate(n, &mut rng);
            let xm = x.iter().sum::<f64>() / n as f64;
            let em = e.iter().sum::<f64>() / n as f64;
            let sxy: f64 = x.iter().zip(&e).map(|(a, b)| (a - xm) * (b - em)).sum();
            let sxx: f64 = x.iter().map(|a| (a - xm).powi(2)).sum();
            ols.push(sxy / sxx);
            let we = whitener.apply(&e);
            gls.push(
                wx.iter().zip(&we).map(|(a, b)| a * b).sum::<f64>()
                    / wx.iter().map(|a| a * a).sum::<f64>(),
            );
        }
        let sd = |v: &[f64]| (v.iter().map(|a| a * a).sum::<f64>() / v.len() as f64).sqrt();
        assert!(
            sd(&gls) < 0.5 * sd(&ols),
            "GLS {} vs OLS {}",
            sd(&gls),
            sd(&ols)
        );
    }
}
