//! A run's NEES judged against what the filter itself predicts of it. Samples of the
//! estimation error taken seconds apart are far from independent (a heading error lasts the
//! drive, an outage's drift tens of seconds), so bounds that take them as independent are
//! too narrow, and the correlation estimated from one run's few dozen samples is biased low.
//! A consistent filter states the correlation itself. Between two sample times the error
//! evolves as `e(t_b) = Φ e(t_a) + w`, `w` independent of `e(t_a)`, with `Φ` the closed-loop
//! transition: the product over the filter's steps of each prediction's transition `F` and,
//! over each batch of updates, `I - K H`, which for the optimal gains the filter applies
//! equals `P⁺ (P⁻)⁻¹`. So `Cov(e(t_b), e(t_a)) = Φ P(t_a)`, and for jointly Gaussian errors
//! the NEES `q = e_Sᵀ A e_S` of the judged states `S` (`A` the inverse of their block of `P`)
//! has `Cov(q_a, q_b) = 2 tr(A_a C A_b Cᵀ)`, `C` the `S×S` block of the cross-covariance.
//! The mean's variance over the samples gives their worth in independent samples,
//! `2 m / var` for `m` judged states, and with it the bounds of a chi-square matched in mean
//! and variance (Satterthwaite).
//!
//! Taken as linear, as the filter takes them: the attitude reset after each update (its
//! Jacobian is the identity to first order) and the variance floors. A filter restart or two
//! predictions between looks break the chain; the tracker then says it cannot judge.

use nalgebra::DMatrix;

/// Follows a filter's closed-loop error transition from the covariances it exposes, and the
/// error's covariance at sample times.
#[derive(Debug, Clone)]
pub struct ClosedLoop {
    /// Transition since the last sample.
    phi: DMatrix<f64>,
    /// The covariance after the last step seen.
    covariance: DMatrix<f64>,
    /// Predictions the filter had run at the last step seen.
    predictions: u64,
    /// Covariance at each sample and the transition from the sample before.
    samples: Vec<(DMatrix<f64>, DMatrix<f64>)>,
    /// Why the chain broke, if it did.
    broken: Option<&'static str>,
}

impl ClosedLoop {
    /// Starts following a filter whose covariance is `covariance` after `predictions`
    /// predictions.
    pub fn start(covariance: DMatrix<f64>, predictions: u64) -> Self {
        let n = covariance.nrows();
        Self {
            phi: DMatrix::identity(n, n),
            covariance,
            predictions,
            samples: Vec::new(),
            broken: None,
        }
    }

    /// One look at the filter after it worked: its prediction count, the covariance right
    /// after its last prediction and that prediction's transition (`prediction`, asked for
    /// only when a prediction ran), and its covariance now. Between looks the filter may have
    /// run one prediction followed by updates, or updates only.
    pub fn step(
        &mut self,
        predictions: u64,
        prediction: impl FnOnce() -> (DMatrix<f64>, DMatrix<f64>),
        covariance: DMatrix<f64>,
    ) {
        if self.broken.is_some() {
            return;
        }
        let step = match predictions.checked_sub(self.predictions) {
            Some(0) if covariance == self.covariance => None,
            Some(0) => right_divide(&covariance, &self.covariance),
            Some(1) => {
                let (predicted, transition) = prediction();
                right_divide(&covariance, &predicted).map(|u| u * transition)
            }
            _ => {
                self.broken = Some("more than one prediction between two looks");
                return;
            }
        };
        if let Some(u) = step {
            self.phi = u * &self.phi;
        } else if covariance != self.covariance {
            self.broken = Some("a covariance that is not positive definite");
            return;
        }
        self.covariance = covariance;
        self.predictions = predictions;
    }

    /// Stops following: the error before and after `why` are not related by the filter.
    pub fn break_chain(&mut self, why: &'static str) {
        self.broken.get_or_insert(why);
    }

    /// Takes a sample of the error at the filter's present state.
    pub fn sample(&mut self) {
        let n = self.covariance.nrows();
        let phi = std::mem::replace(&mut self.phi, DMatrix::identity(n, n));
        self.samples.push((self.covariance.clone(), phi));
    }

    /// The variance a consistent filter gives the mean NEES of the `judged` states over the
    /// samples taken, or why it cannot be stated.
    pub fn mean_nees_variance(&self, judged: &[usize]) -> Result<f64, &'static str> {
        if let Some(why) = self.broken {
            return Err(why);
        }
        let n = self.samples.len();
        if n == 0 {
            return Err("no samples");
        }
        let block = |m: &DMatrix<f64>| {
            DMatrix::from_fn(judged.len(), judged.len(), |i, j| m[(judged[i], judged[j])])
        };
        let inverses = self
            .samples
            .iter()
            .map(|(p, _)| {
                block(p)
                    .try_inverse()
                    .ok_or("a judged block that is singular")
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut sum = 0.0;
        for (j, (p_j, _)) in self.samples.iter().enumerate() {
            sum += 2.0 * judged.len() as f64;
            // Cov(e_i, e_j) = Φ(t_i, t_j) P_j, built up sample after sample.
            let mut cross = p_j.clone();
            for i in j + 1..n {
                cross = &self.samples[i].1 * cross;
                let c = block(&cross);
                let term = (&inverses[i] * &c * &inverses[j] * c.transpose()).trace();
                sum += 2.0 * 2.0 * term;
            }
        }
        Ok(sum / (n * n) as f64)
    }

    /// Samples taken.
    pub fn samples(&self) -> usize {
        self.samples.len()
    }
}

/// `a b⁻¹` for a symmetric positive definite `b`, through the Cholesky factor of `b` scaled
/// to unit diagonal (its variances span many decades); `None` if `b` is not positive
/// definite.
fn right_divide(a: &DMatrix<f64>, b: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = b.nrows();
    let d: Vec<f64> = (0..n).map(|i| b[(i, i)].sqrt()).collect();
    if d.iter().any(|v| !(*v > 0.0)) {
        return None;
    }
    let scaled = DMatrix::from_fn(n, n, |i, j| b[(i, j)] / (d[i] * d[j]));
    let cholesky = scaled.cholesky()?;
    // a b⁻¹ = (b⁻¹ aᵀ)ᵀ, and b⁻¹ = D⁻¹ R⁻¹ D⁻¹.
    let rhs = DMatrix::from_fn(n, a.nrows(), |i, j| a[(j, i)] / d[i]);
    let x = cholesky.solve(&rhs);
    Some(DMatrix::from_fn(a.nrows(), n, |i, j| x[(j, i)] / d[j]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// A drifting position and velocity (white acceleration noise), the position measured
    /// every `measure_every` steps: the Kalman filter of the true model, run on its own
    /// simulated truth. Returns each run's mean NEES over samples every `sample_every` steps
    /// and the tracker of the last run.
    fn runs(count: usize, seed: u64) -> (Vec<f64>, ClosedLoop) {
        let (dt, q_acc, r_pos): (f64, f64, f64) = (0.1, 1e-4, 1.0);
        let (measure_every, sample_every, steps) = (25, 10, 600);
        let f = DMatrix::from_row_slice(2, 2, &[1.0, dt, 0.0, 1.0]);
        let q =
            DMatrix::from_row_slice(2, 2, &[dt.powi(3) / 3.0, dt * dt / 2.0, dt * dt / 2.0, dt])
                * q_acc;
        let q_chol = q.clone().cholesky().unwrap().l();
        let p0 = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![4.0, 0.04]));
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut normal =
            |n: usize| nalgebra::DVector::from_fn(n, |_, _| StandardNormal.sample(&mut rng));
        let mut means = Vec::new();
        let mut last = None;
        for _ in 0..count {
            let mut p = p0.clone();
            // The estimation error itself: e = truth - estimate.
            let mut e = p0.clone().cholesky().unwrap().l() * normal(2);
            let mut tracker = ClosedLoop::start(p.clone(), 0);
            let mut nees = Vec::new();
            for k in 1..=steps {
                e = &f * e + &q_chol * normal(2);
                p = &f * &p * f.transpose() + &q;
                let predicted = p.clone();
                if k % measure_every == 0 {
                    let s = p[(0, 0)] + r_pos;
                    let gain = p.column(0) / s;
                    let v = r_pos.sqrt() * normal(1)[0];
                    // e⁺ = (I - K H) e⁻ - K v.
                    let h_e = e[0];
                    e -= &gain * (h_e + v);
                    let i_kh = DMatrix::identity(2, 2)
                        - &gain * DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
                    p = &i_kh * &p * i_kh.transpose() + &gain * gain.transpose() * r_pos;
                }
                tracker.step(k as u64, || (predicted, f.clone()), p.clone());
                if k % sample_every == 0 {
                    tracker.sample();
                    nees.push(e.dot(&(p.clone().try_inverse().unwrap() * &e)));
                }
            }
            means.push(nees.iter().sum::<f64>() / nees.len() as f64);
            last = Some(tracker);
        }
        (means, last.unwrap())
    }

    #[test]
    fn the_predicted_variance_of_the_mean_nees_matches_its_spread_over_runs() {
        let (means, tracker) = runs(800, 5);
        let predicted = tracker.mean_nees_variance(&[0, 1]).unwrap();
        let n = means.len() as f64;
        let mean = means.iter().sum::<f64>() / n;
        let spread = means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let samples = tracker.samples() as f64;
        let independent = 2.0 * 2.0 / samples;
        // The samples are strongly correlated: their mean varies several times more than
        // independent samples' would, and the prediction says by how much.
        assert!(spread > 3.0 * independent, "{spread} {independent}");
        assert!((mean - 2.0).abs() < 0.1, "{mean}");
        assert!(
            (predicted / spread - 1.0).abs() < 0.15,
            "predicted {predicted}, over runs {spread}"
        );
    }
}
