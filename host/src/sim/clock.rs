//! IMU sample clocks: the true (GPS-time) instants at which an IMU whose oscillator has a
//! frequency error, a frequency random walk and timing jitter takes its evenly spaced
//! (in its own time) samples, and the inverse map used to stamp PPS edges in IMU time.

use rand::Rng;
use rand_distr::StandardNormal;

use crate::model::ClockModel;

/// The realised clock of one IMU over a run.
#[derive(Debug, Clone)]
pub struct ClockRun {
    /// Nominal rate, Hz: sample k is stamped k / rate in the IMU's own time.
    pub rate_hz: f64,
    /// True time of sample k without jitter (the oscillator's k-th tick), s.
    pub tick_t_s: Vec<f64>,
    /// True sampling instant of sample k (tick plus jitter), s.
    pub sample_t_s: Vec<f64>,
}

impl ClockRun {
    /// Realises `n` ticks. With `drift` off the ticks are exactly k / rate; with `jitter`
    /// off the sampling instants are the ticks.
    pub fn realise<R: Rng>(
        model: &ClockModel,
        rate_hz: f64,
        n: usize,
        drift: bool,
        jitter: bool,
        rng: &mut R,
    ) -> Self {
        let dt = 1.0 / rate_hz;
        let drifting = drift
            && (model.frequency_offset_ppm != 0.0
                || model.frequency_random_walk_ppm_per_sqrt_s != 0.0);
        let tick_t_s: Vec<f64> = if drifting {
            let mut t = 0.0;
            let mut ppm = model.frequency_offset_ppm;
            let step = model.frequency_random_walk_ppm_per_sqrt_s * dt.sqrt();
            let mut out = Vec::with_capacity(n);
            for _ in 0..n {
                out.push(t);
                t += dt / (1.0 + ppm * 1e-6);
                if step != 0.0 {
                    let z: f64 = rng.sample(StandardNormal);
                    ppm += step * z;
                }
            }
            out
        } else {
            (0..n).map(|k| k as f64 * dt).collect()
        };
        let sample_t_s = if jitter && model.jitter_s > 0.0 {
            tick_t_s
                .iter()
                .map(|&t| {
                    let z: f64 = rng.sample(StandardNormal);
                    t + model.jitter_s * z
                })
                .collect()
        } else {
            tick_t_s.clone()
        };
        ClockRun {
            rate_hz,
            tick_t_s,
            sample_t_s,
        }
    }

    /// The IMU's own time when true time is `t_s` (linear between ticks; beyond the last
    /// tick at the last tick spacing).
    pub fn local_time_at(&self, t_s: f64) -> f64 {
        let ticks = &self.tick_t_s;
        let dt = 1.0 / self.rate_hz;
        if ticks.len() < 2 {
            return t_s;
        }
        let i = ticks
            .partition_point(|&x| x <= t_s)
            .clamp(1, ticks.len() - 1)
            - 1;
        let span = ticks[i + 1] - ticks[i];
        i as f64 * dt + (t_s - ticks[i]) / span * dt
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn a_fast_clock_takes_its_samples_early_by_the_ppm_offset() {
        let model = ClockModel {
            frequency_offset_ppm: 50.0,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let c = ClockRun::realise(&model, 100.0, 360_001, true, true, &mut rng);
        // after 3600 s of IMU time, true time is 3600 / (1 + 50e-6)
        let last = *c.tick_t_s.last().unwrap();
        assert!((last - 3600.0 / (1.0 + 50e-6)).abs() < 1e-7, "{last}");
        assert!((c.local_time_at(last) - 3600.0).abs() < 1e-9);
        assert!((c.local_time_at(1000.0) - 1000.0 * (1.0 + 50e-6)).abs() < 1e-8);
    }

    #[test]
    fn jitter_has_the_stated_spread_and_switches_off() {
        let model = ClockModel {
            jitter_s: 1e-5,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let c = ClockRun::realise(&model, 1000.0, 100_000, true, true, &mut rng);
        let var: f64 = c
            .sample_t_s
            .iter()
            .zip(&c.tick_t_s)
            .map(|(s, t)| (s - t).powi(2))
            .sum::<f64>()
            / 1e5;
        assert!((var.sqrt() / 1e-5 - 1.0).abs() < 0.02, "{}", var.sqrt());
        let off = ClockRun::realise(&model, 1000.0, 1000, true, false, &mut rng);
        assert_eq!(off.sample_t_s, off.tick_t_s);
    }
}
