//! The platform's angular acceleration from its measured rate. A spectral derivative of the Wiener-filtered rate: each frequency bin kept by
//! the gain 1 - N / P, N the white noise floor (the median bin power over ln 2, the mean of
//! an exponential law) and P the power of the bins around it, then multiplied by i 2 pi f.
//! Why not differences: a car's or a copter's vibration puts angular acceleration at 10-30
//! Hz, which central differences at 100 Hz lose up to 40% of, and an exact derivative of the
//! raw rate amplifies the gyro noise at every frequency; the filter keeps the vibration
//! lines and the manoeuvres, which stand above the noise, and little of the noise. Why the
//! power of the bins around: one bin's power is one draw of an exponential law, and a gain
//! set by it alone lets a noise bin that comes out high through, and does worse than no
//! filter where the signal is one to ten times the noise.
//!
//! The line through the first and last samples is taken out first and its slope added
//! back: the FFT sees the record as periodic, and a rate that ends where it did not start
//! would otherwise put a jump at the ends, whose derivative spreads over the whole spectrum.
//! The same gains put through other signals ([`SpectralDerivative::apply`]) tell what the
//! derivative makes of the gyros' noise: their pairwise differences hold no motion. On
//! simulated drives this filter left the lever-arm-corrected accelerometers' white noise
//! within 8% of the truth, where a gain set by each bin alone left 25% (BENCHMARKS.md).

use std::cell::RefCell;
use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};

/// The forward and inverse real FFTs of one length.
type Plans = (
    usize,
    Arc<dyn RealToComplex<f64>>,
    Arc<dyn ComplexToReal<f64>>,
);

thread_local! {
    /// The plans of the length last transformed on this thread: a stretch's many series
    /// share one length, and planning it (twiddles, and Bluestein's for a length with a
    /// large prime factor) cost more than the transforms; only one length is kept, so a
    /// long run's stretches of varying lengths do not pile up plans.
    static PLANS: RefCell<Option<Plans>> = const { RefCell::new(None) };
}

/// The plans for length `n`, planned once per length in a row.
fn plans(n: usize) -> (Arc<dyn RealToComplex<f64>>, Arc<dyn ComplexToReal<f64>>) {
    PLANS.with(|cell| {
        let mut cell = cell.borrow_mut();
        if cell.as_ref().is_none_or(|(m, _, _)| *m != n) {
            let mut planner = RealFftPlanner::<f64>::new();
            *cell = Some((n, planner.plan_fft_forward(n), planner.plan_fft_inverse(n)));
        }
        let (_, forward, inverse) = cell.as_ref().expect("set above");
        (forward.clone(), inverse.clone())
    })
}

/// Bins on each side of a bin whose powers set its gain.
const NEIGHBOURS: usize = 8;

/// The filter fitted to one rate signal: a gain per real-FFT bin, applied with the
/// derivative's i 2 pi f.
pub(super) struct SpectralDerivative {
    gains: Vec<f64>,
    dt_s: f64,
}

impl SpectralDerivative {
    /// The filter for `x` (sampled every `dt_s` seconds, at least 4 samples), each bin's
    /// gain set by the bin and `neighbours` bins on each side; None for a signal the FFT
    /// cannot take.
    fn fit_over(x: &[f64], dt_s: f64, neighbours: usize) -> Option<Self> {
        let n = x.len();
        let spectrum = detrended_spectrum(x)?.0;
        let power: Vec<f64> = spectrum.iter().map(|c| c.norm_sqr()).collect();
        let gains = gains(&power, noise_floor(&power), n.is_multiple_of(2), neighbours);
        Some(Self { gains, dt_s })
    }

    /// The filter for `x` (see the module's note).
    pub(super) fn fit(x: &[f64], dt_s: f64) -> Option<Self> {
        Self::fit_over(x, dt_s, NEIGHBOURS)
    }

    /// Rate of change of `y` (as long as the signal the filter was fitted to), input unit
    /// per second, per sample, through this filter's gains.
    pub(super) fn apply(&self, y: &[f64]) -> Vec<f64> {
        let derivative = |omega_rad_s: f64, gain: f64| Complex::new(0.0, omega_rad_s * gain);
        let Some((detrended, slope)) = self.through(y, derivative) else {
            return vec![0.0; y.len()];
        };
        detrended.iter().map(|v| v + slope / self.dt_s).collect()
    }

    /// The motion in `y` (as long as the signal the filter was fitted to), in its unit, per
    /// sample: the bins where the motion's power is at least the noise's (gain 1/2 or more)
    /// whole, the others not at all. Whole bins, not Wiener-weighted ones: what is done to
    /// this part (delayed) then keeps the noise's power, where a partial gain would mix the
    /// noise with a delayed copy of itself and lower it.
    pub(super) fn motion(&self, y: &[f64]) -> Vec<f64> {
        let mask = |_: f64, gain: f64| Complex::new(if gain >= 0.5 { 1.0 } else { 0.0 }, 0.0);
        let Some((detrended, slope)) = self.through(y, mask) else {
            return y.to_vec();
        };
        detrended
            .iter()
            .enumerate()
            .map(|(i, v)| v + y[0] + slope * i as f64)
            .collect()
    }

    /// `y` less its end-to-end line, each bin times `weight(omega, gain)` (omega in rad/s,
    /// the bin's gain), and the line's slope per sample; None where the FFT cannot take it.
    fn through(
        &self,
        y: &[f64],
        weight: impl Fn(f64, f64) -> Complex<f64>,
    ) -> Option<(Vec<f64>, f64)> {
        let n = y.len();
        let (mut spectrum, slope) = detrended_spectrum(y)?;
        for (k, c) in spectrum.iter_mut().enumerate() {
            let omega_rad_s = 2.0 * std::f64::consts::PI * k as f64 / (n as f64 * self.dt_s);
            *c *= weight(omega_rad_s, self.gains.get(k).copied().unwrap_or(0.0));
        }
        let inverse = plans(n).1;
        let mut out = inverse.make_output_vec();
        inverse.process(&mut spectrum, &mut out).ok()?;
        Some((out.iter().map(|v| v / n as f64).collect(), slope))
    }
}

/// Spectrum of `y` less the straight line through its first and last samples, and that
/// line's slope per sample; None for fewer than 4 samples or a failed FFT.
fn detrended_spectrum(y: &[f64]) -> Option<(Vec<Complex<f64>>, f64)> {
    let n = y.len();
    if n < 4 {
        return None;
    }
    let slope = (y[n - 1] - y[0]) / (n - 1) as f64;
    let forward = plans(n).0;
    let mut input: Vec<f64> = y
        .iter()
        .enumerate()
        .map(|(i, v)| v - y[0] - slope * i as f64)
        .collect();
    let mut spectrum = forward.make_output_vec();
    forward.process(&mut input, &mut spectrum).ok()?;
    Some((spectrum, slope))
}

/// White-noise power per bin of an unnormalised spectrum: the median bin power over ln 2,
/// the mean of the exponential law a noise bin's power follows (most bins hold noise only).
fn noise_floor(power: &[f64]) -> f64 {
    let mut sorted = power.to_vec();
    let mid = sorted.len() / 2;
    *sorted.select_nth_unstable_by(mid, f64::total_cmp).1 / std::f64::consts::LN_2
}

/// Each bin's Wiener gain 1 - N / P, P the mean power of the bin and its `neighbours` on
/// each side, 0 where P is under the floor N and at the mean and Nyquist bins.
fn gains(power: &[f64], floor: f64, has_nyquist: bool, neighbours: usize) -> Vec<f64> {
    let top = power.len() - 1 - usize::from(has_nyquist);
    window_means(power, neighbours, top)
        .iter()
        .enumerate()
        .map(|(k, mean)| {
            if k == 0 || k > top || *mean <= 0.0 {
                0.0
            } else {
                (1.0 - floor / mean).max(0.0)
            }
        })
        .collect()
}

/// The mean of each bin of `power` and its `neighbours` on each side, among bins 1 to
/// `top` (the mean bin and a Nyquist bin stay out of every window).
fn window_means(power: &[f64], neighbours: usize, top: usize) -> Vec<f64> {
    let mut prefix = vec![0.0; power.len() + 1];
    for (k, p) in power.iter().enumerate() {
        prefix[k + 1] = prefix[k] + p;
    }
    (0..power.len())
        .map(|k| {
            let k = k.clamp(1, top.max(1));
            let lo = k.saturating_sub(neighbours).max(1);
            let hi = (k + neighbours).min(top).max(lo);
            (prefix[hi + 1] - prefix[lo]) / (hi + 1 - lo) as f64
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A rate of two manoeuvre tones and a 26 Hz vibration line, none a whole number of
    /// cycles over the record, in white gyro noise (2 mrad/s at 100 Hz): the derivative's
    /// error variance against the exact derivative is under 1% of what central differences
    /// leave (they lose 39% of the vibration line's amplitude) and under a third of the
    /// error of the same gain set by each bin's own power (measured 0.0068 against 0.83 and
    /// 0.030 (rad/s^2)^2).
    #[test]
    fn the_derivative_keeps_the_vibration_and_little_noise() {
        let dt_s = 0.01;
        let n = 1 << 15;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 2e-3).unwrap();
        let tones = [(0.05, 0.3), (0.4, 0.1), (26.0, 0.02)];
        let t = |i: usize| i as f64 * dt_s;
        let rate: Vec<f64> = (0..n)
            .map(|i| {
                let clean: f64 = tones
                    .iter()
                    .map(|(f, a)| a * (2.0 * std::f64::consts::PI * f * t(i)).sin())
                    .sum();
                clean + noise.sample(&mut rng)
            })
            .collect();
        let exact = |i: usize| -> f64 {
            tones
                .iter()
                .map(|(f, a)| {
                    let w = 2.0 * std::f64::consts::PI * f;
                    a * w * (w * t(i)).cos()
                })
                .sum()
        };
        let error_variance = |d: &[f64], range: std::ops::Range<usize>| {
            let m = range.len() as f64;
            range.map(|i| (d[i] - exact(i)).powi(2)).sum::<f64>() / m
        };
        let derivative = |neighbours: usize| {
            SpectralDerivative::fit_over(&rate, dt_s, neighbours)
                .unwrap()
                .apply(&rate)
        };
        let ours = error_variance(&derivative(NEIGHBOURS), 0..n);
        let central: Vec<f64> = (0..n)
            .map(|i| {
                let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
                (rate[b] - rate[a]) / ((b - a) as f64 * dt_s)
            })
            .collect();
        let differences = error_variance(&central, 1..n - 1);
        assert!(ours < 0.01 * differences, "{ours} vs {differences}");
        let alone = error_variance(&derivative(0), 0..n);
        assert!(ours < alone / 3.0, "{ours} vs {alone}");
    }
}
