//! The stochastic effects in what a channel's deterministic terms leave, each tested against
//! the same statistic on baseline simulations: noise growing with the dynamics, outliers,
//! vibration lines, quantization of the raw output, and a change of the white or correlated
//! noise (the wavelet variance of what remains). Found effects are taken out of the residual
//! as they are found (outliers replaced by the local median, lines subtracted), so the later
//! tests see what the earlier ones could not explain.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde_json::json;

use super::draws::ChannelSimulation;
use super::engine::{
    ci, simulated_range, DiagnoseError, Discrepancy, Finding, Run, WV_MIN_LOG_DEVIATION,
};
use super::gain::{fit_wv, log_wv, LogWv};
use super::null::{normal_p_value, poisson_upper_tail, wv_level_test, LevelTest};
use super::readable::significant;
use super::stats::{
    find_outliers, find_outliers_in, noise_vs_window_dynamics, outlier_process, series_variance,
    spectral_lines, welch_psd, with_bank_series, with_mapped_bank_series, Series, SeriesSet,
    SpectralLine,
};
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, parameter_values, ModelChoice};
use crate::gmwm::model::ModelSpec;
use crate::model::{
    Cause, Channel, ChannelModel, DynamicDriver, DynamicNoise, Outliers, VibrationLine,
};
use crate::series_bank::SeriesBank;
use crate::wv::{eta3, level_coefficients, WaveletVariance};

/// What the stochastic stage found on one channel.
pub(super) struct StochasticFindings {
    pub findings: Vec<Finding>,
    pub discrepancies: Vec<Discrepancy>,
    /// The effects found beyond the stochastic model, as the simulator's channel model
    /// carries them (dynamic noise, vibration lines with phase 0 as the phase is not
    /// estimated, outliers, quantization step); its other fields are unset.
    pub effects: ChannelModel,
    /// The stochastic model of the extended model: the baseline's, or its structure refitted
    /// on what remains when that departs from the baseline's wavelet variance.
    pub stochastic: ModelSpec,
    /// What was not tested, and why.
    pub notes: Vec<String>,
}

/// Runs the tests in order on `resid` (the one series of a bank: the channel's error less
/// its deterministic terms and bias, changed in place as effects are taken out of it), the
/// error's variance being `var_e` and `sims` the channel's baseline simulations.
pub(super) fn find_stochastic_effects(
    run: &Run,
    slot: usize,
    channel: Channel,
    spec: &ModelSpec,
    var_e: f64,
    resid: &mut SeriesBank,
    sims: &impl SeriesSet,
) -> Result<StochasticFindings, DiagnoseError> {
    let mut found = StochasticFindings {
        findings: Vec::new(),
        discrepancies: Vec::new(),
        effects: ChannelModel::default(),
        stochastic: spec.clone(),
        notes: Vec::new(),
    };
    // Noise growing with the dynamics, looked at before outliers: the largest samples of a
    // noise that grows in the manoeuvres are not outliers, and the outlier search then runs
    // on the residual scaled back to the quiet noise level.
    let noise_scale = if run.has_dynamics {
        noise_growth(run, channel, var_e, resid, sims, &mut found)?
    } else {
        None
    };
    outliers(run, channel, var_e, resid, noise_scale, sims, &mut found)?;
    vibration_lines(run, channel, var_e, resid, sims, &mut found)?;
    quantization(run, channel, var_e, &mut found);
    noise_change(run, slot, channel, spec, resid, sims, &mut found)?;
    Ok(found)
}

/// The window of the noise-growth regression ([`super::stats::noise_vs_dynamics`]) on a run
/// sampled every `dt_s`: a second, at least 16 epochs.
pub(super) fn noise_window(dt_s: f64) -> usize {
    ((1.0 / dt_s) as usize).max(16)
}

/// Noise whose variance grows with |omega|^2. Returns the quiet variance and the slope of
/// the variance on |omega|^2 when found.
fn noise_growth(
    run: &Run,
    channel: Channel,
    var_e: f64,
    resid: &SeriesBank,
    sims: &impl SeriesSet,
    found: &mut StochasticFindings,
) -> Result<Option<(f64, f64)>, DiagnoseError> {
    let window = noise_window(run.dt_s);
    let nd = with_bank_series(resid, 0, |r| {
        noise_vs_window_dynamics(r, &run.omega2_windows, window)
    })?;
    let sim_t: Vec<f64> =
        sims.map_each(&|s| noise_vs_window_dynamics(s, &run.omega2_windows, window).t);
    let range = simulated_range(&sim_t);
    if !(nd.t > run.z_strict.max(range[1] * 1.5)
        && nd.sigma_per_unit > 0.0
        && nd.sigma_per_unit_ci95[0] > 0.0)
    {
        return Ok(None);
    }
    found.discrepancies.push(Discrepancy {
        channel,
        statistic: "noise variance vs |omega|^2 (t)".into(),
        measured: nd.t,
        simulated_range: range,
        detail: String::new(),
    });
    found.findings.push(Finding {
        channel,
        cause: Cause::NoiseScalesWithDynamics,
        regressors: vec!["|omega| (rad/s)".into()],
        estimate: json!(nd.sigma_per_unit),
        ci95: json!(nd.sigma_per_unit_ci95),
        variance_explained: nd.sigma_per_unit.powi(2) * run.mean_omega2 / var_e,
        p_value: Some(run.family_p(normal_p_value(nd.t))),
    });
    found.effects.dynamic_noise = Some(DynamicNoise {
        driver: DynamicDriver::AngularRateNorm,
        sigma_per_unit: nd.sigma_per_unit,
    });
    Ok(Some((nd.intercept.max(0.0), nd.slope)))
}

/// Outliers beyond 6 robust sigma, more than the baseline simulations show. Named only when
/// they stand out of the noise as a population of their own; then each is replaced in
/// `resid` by the local median. The residual is scanned scaled back to the quiet noise
/// level when the noise grows with |omega| (`noise_scale`: the quiet variance and the slope
/// on |omega|^2), a block at a time.
fn outliers(
    run: &Run,
    channel: Channel,
    var_e: f64,
    resid: &mut SeriesBank,
    noise_scale: Option<(f64, f64)>,
    sims: &impl SeriesSet,
    found: &mut StochasticFindings,
) -> Result<(), DiagnoseError> {
    let n = run.n;
    let held: &SeriesBank = resid;
    let scaled = |visit: &mut dyn FnMut(&[f64])| -> Result<(), DiagnoseError> {
        match noise_scale {
            Some((var0, slope)) if var0 > 0.0 => {
                let (mut block, mut failed) = (Vec::new(), None);
                run.signals
                    .for_each_angular_rate_norm(0..n, &mut |epochs, omega| {
                        let r = match held.range(0, epochs) {
                            Ok(r) => r,
                            Err(e) => {
                                failed.get_or_insert(e);
                                return;
                            }
                        };
                        block.clear();
                        block.extend(
                            r.iter()
                                .zip(omega)
                                .map(|(r, w)| r * (var0 / (var0 + slope * w * w)).sqrt()),
                        );
                        visit(&block);
                    })?;
                failed.map_or(Ok(()), |e| Err(e.into()))
            }
            _ => Ok(held.for_each_block_of(&[0], &mut |_, r| visit(r[0]))?),
        }
    };
    let out = find_outliers_in(n, 11, 6.0, &scaled)?;
    let sim_counts: Vec<f64> = sims.map_each(&|s| find_outliers(s, 11, 6.0).indices.len() as f64);
    let range = simulated_range(&sim_counts);
    if !(out.indices.len() >= 5 && out.indices.len() as f64 > range[1] + 3.0) {
        return Ok(());
    }
    let half_window = 5usize;
    // Each outlier's local median, and its deviation from it.
    let (local_median, devs): (Vec<f64>, Vec<f64>) = out
        .indices
        .iter()
        .map(|&i| {
            let lo = i.saturating_sub(half_window);
            let hi = (i + half_window + 1).min(n);
            let mut b: Vec<f64> = resid.range(0, lo..hi)?.into_owned();
            let at = b[i - lo];
            let m = b.len() / 2;
            let median = *b.select_nth_unstable_by(m, f64::total_cmp).1;
            Ok((median, at - median))
        })
        .collect::<Result<Vec<_>, DiagnoseError>>()?
        .into_iter()
        .unzip();
    let op = outlier_process(
        &out.scaled_deviations,
        6.0 * out.robust_sigma,
        out.robust_sigma,
        n,
    );
    // The simulation misses the tail either way; only a population that stands out of the
    // noise is named `outliers` (a heavier-tailed noise is not outliers).
    let detail = if op.separated {
        format!("largest |z| {:.1}", out.max_abs_z)
    } else {
        format!(
            "largest |z| {:.1}; a heavier-tailed noise, not a separate outlier population: the exceedances fit a scale of {:.2} robust sigma, of which only {:.1e} would show beyond 6 sigma",
            out.max_abs_z,
            op.population_sigma / out.robust_sigma,
            op.detection_probability
        )
    };
    found.discrepancies.push(Discrepancy {
        channel,
        statistic: "outliers beyond 6 robust sigma".into(),
        measured: out.indices.len() as f64,
        simulated_range: range,
        detail,
    });
    // Under the null the count is about Poisson with the simulations' mean (one count
    // added, so that no simulation with an outlier does not make the null count zero).
    let null_mean = (sim_counts.iter().sum::<f64>() + 1.0) / sim_counts.len() as f64;
    let p = poisson_upper_tail(out.indices.len(), null_mean);
    if !(op.separated && op.probability_ci95[0] > 0.0 && p < run.alpha_test) {
        return Ok(());
    }
    let ve = devs.iter().map(|d| d * d).sum::<f64>() / n as f64 / var_e;
    found.findings.push(Finding {
        channel,
        cause: Cause::Outliers,
        regressors: vec![
            "probability_per_sample".into(),
            format!("sigma (estimate {:.3e})", op.sigma),
        ],
        estimate: json!(op.probability_per_sample),
        ci95: json!(op.probability_ci95),
        variance_explained: ve,
        p_value: Some(run.family_p(p)),
    });
    found.effects.outliers = Some(Outliers {
        probability: op.probability_per_sample,
        sigma: op.sigma,
    });
    // The indices come in order: each block takes the run of them inside it.
    let mut next = 0;
    resid.update(0, &mut |epochs, values| {
        while next < out.indices.len() && out.indices[next] < epochs.end {
            values[out.indices[next] - epochs.start] = local_median[next];
            next += 1;
        }
    })?;
    Ok(())
}

/// Least-squares sinusoids a sin(w t) + b cos(w t) at each of `freqs_hz` in `y` sampled
/// every `dt_s`, all in one pass over `y`.
fn fit_sinusoids(freqs_hz: &[f64], y: &Series, dt_s: f64) -> Vec<(f64, f64)> {
    let ws: Vec<f64> = freqs_hz.iter().map(|f| std::f64::consts::TAU * f).collect();
    // ss, cc, sc, ys, yc of each frequency.
    let mut sums = vec![[0.0f64; 5]; ws.len()];
    let mut first = 0usize;
    y.for_each_block(&mut |block| {
        for (w, [ss, cc, sc, ys, yc]) in ws.iter().zip(sums.iter_mut()) {
            for (k, v) in block.iter().enumerate() {
                let (s, c) = (w * (first + k) as f64 * dt_s).sin_cos();
                *ss += s * s;
                *cc += c * c;
                *sc += s * c;
                *ys += v * s;
                *yc += v * c;
            }
        }
        first += block.len();
    });
    sums.iter()
        .map(|[ss, cc, sc, ys, yc]| {
            let d = ss * cc - sc * sc;
            if d <= 0.0 {
                return (0.0, 0.0);
            }
            ((ys * cc - yc * sc) / d, (yc * ss - ys * sc) / d)
        })
        .collect()
}

/// The frequency of a line found in a PSD bin of width `bin_hz`, refined within the bin by
/// the power of the fitted sinusoid: over minutes a half-bin error would turn the fit into
/// nothing.
fn refine_line_frequency(freq_hz: f64, bin_hz: f64, y: &Series, dt_s: f64) -> f64 {
    // The frequency of greatest power among `freqs_hz` (the first of equals), from `start`.
    let strongest = |freqs_hz: Vec<f64>, start: (f64, f64)| {
        let fits = fit_sinusoids(&freqs_hz, y, dt_s);
        freqs_hz
            .into_iter()
            .zip(fits)
            .fold(start, |best, (f_hz, (a, b))| {
                let p = a * a + b * b;
                if p > best.1 {
                    (f_hz, p)
                } else {
                    best
                }
            })
    };
    let coarse: Vec<f64> = (-40..=40)
        .map(|k| freq_hz + k as f64 * bin_hz / 40.0)
        .collect();
    let best = strongest(coarse, (freq_hz, 0.0));
    let span = bin_hz / 40.0;
    let fine: Vec<f64> = (-20..=20)
        .map(|k| best.0 + k as f64 * span / 20.0)
        .collect();
    strongest(fine, best).0
}

/// Spectral lines of the residual (from 1 Hz, and at least 16 PSD bins, up): each is fitted
/// as a sinusoid, named, and subtracted from `resid`.
fn vibration_lines(
    run: &Run,
    channel: Channel,
    var_e: f64,
    resid: &mut SeriesBank,
    sims: &impl SeriesSet,
    found: &mut StochasticFindings,
) -> Result<(), DiagnoseError> {
    let (n, dt_s) = (run.n, run.dt_s);
    let seg = 1usize << ((n as f64 / 16.0).log2().floor() as u32).clamp(6, 12);
    let min_line_hz = (1.0f64).max(16.0 / (seg as f64 * dt_s));
    let lines = with_bank_series(resid, 0, |r| {
        spectral_lines(&welch_psd(r, dt_s, seg), run.alpha_test)
    })?;
    let sim_lines: Vec<f64> = sims.map_first(8, &|s| {
        spectral_lines(&welch_psd(s, dt_s, seg), run.alpha_test)
            .iter()
            .filter(|l| l.freq_hz >= min_line_hz)
            .count() as f64
    });
    for line in lines.iter().filter(|l| l.freq_hz >= min_line_hz) {
        let bin_hz = 1.0 / (seg as f64 * dt_s);
        let (freq_hz, (a, b)) = with_bank_series(resid, 0, |r| {
            let freq_hz = refine_line_frequency(line.freq_hz, bin_hz, r, dt_s);
            (freq_hz, fit_sinusoids(&[freq_hz], r, dt_s)[0])
        })?;
        let w = std::f64::consts::TAU * freq_hz;
        let amp = (a * a + b * b).sqrt();
        let sinusoid = |i: usize| {
            let (s, c) = (w * i as f64 * dt_s).sin_cos();
            a * s + b * c
        };
        let less_line = |epochs: std::ops::Range<usize>, block: &[f64], out: &mut Vec<f64>| {
            out.extend(block.iter().zip(epochs).map(|(y, i)| y - sinusoid(i)));
        };
        let var_after = with_mapped_bank_series(resid, 0, 0..n, &less_line, series_variance)?;
        // Statistical error of a least-squares sinusoid, plus a 3% allowance for what the
        // sampling does to a line near or above Nyquist (clock jitter, the boresight
        // rotation mixing axes), which the statistical part ignores.
        let noise = ((var_after * 2.0 / n as f64) + (0.015 * amp).powi(2)).sqrt();
        let interval = ci(amp, noise);
        if interval[0] <= 0.0 {
            continue;
        }
        resid.update(0, &mut |epochs, values| {
            values
                .iter_mut()
                .zip(epochs)
                .for_each(|(y, i)| *y -= sinusoid(i));
        })?;
        let line = SpectralLine {
            freq_hz,
            ..line.clone()
        };
        found.discrepancies.push(Discrepancy {
            channel,
            statistic: format!("spectral line at {:.2} Hz", line.freq_hz),
            measured: line.power_ratio,
            simulated_range: simulated_range(&sim_lines),
            detail: format!("lines found in baseline simulations: {:?}", sim_lines),
        });
        found.findings.push(Finding {
            channel,
            cause: Cause::Vibration,
            regressors: vec![format!("sinusoid at {:.3} Hz (as sampled)", line.freq_hz)],
            estimate: json!(amp),
            ci95: json!(interval),
            variance_explained: amp * amp / 2.0 / var_e,
            p_value: Some(run.family_p(line.p_value)),
        });
        found.effects.vibration_lines.push(VibrationLine {
            frequency_hz: line.freq_hz,
            amplitude: amp,
            phase_rad: 0.0,
        });
    }
    Ok(())
}

/// Quantization: the raw sensor values on a lattice the baseline does not have.
fn quantization(run: &Run, channel: Channel, var_e: f64, found: &mut StochasticFindings) {
    let Some((q, q_se)) = run.raw_lattice[channel.index()] else {
        return;
    };
    found.discrepancies.push(Discrepancy {
        channel,
        statistic: "raw values on a lattice (LSB)".into(),
        measured: q,
        simulated_range: [0.0, 0.0],
        detail: "baseline simulations are continuous".into(),
    });
    found.findings.push(Finding {
        channel,
        cause: Cause::Quantization,
        regressors: vec!["lsb".into()],
        estimate: json!(q),
        ci95: json!(ci(q, q_se)),
        variance_explained: q * q / 12.0 / var_e,
        p_value: None,
    });
    found.effects.quantization_step = Some(q);
}

/// Lattice spacing of a raw sensor channel and its standard error, if its values lie on one
/// (quantised output): the channel is what each call of `pass` yields, in order (three
/// passes, in memory that does not grow with it: the nonzero steps between consecutive
/// values, their smallest (q0) and largest; then the share on multiples of q0 and the unit
/// steps' mean; then their spread).
pub(super) fn lattice_step_in<E>(
    mut pass: impl FnMut(&mut dyn FnMut(f64)) -> Result<(), E>,
) -> Result<Option<(f64, f64)>, E> {
    // `visit(d)` with each nonzero |step| in order.
    let mut steps = |visit: &mut dyn FnMut(f64)| {
        let mut previous: Option<f64> = None;
        pass(&mut |v| {
            if let Some(p) = previous {
                let d = (v - p).abs();
                if d > 0.0 {
                    visit(d);
                }
            }
            previous = Some(v);
        })
    };
    let (mut count, mut scale, mut q0) = (0usize, 0.0f64, f64::INFINITY);
    steps(&mut |d| {
        count += 1;
        scale = scale.max(d);
        q0 = q0.min(d);
    })?;
    // Steps below 1e-9 of the largest are rounding, not a lattice (NaN: no lattice).
    if count < 100 || !(q0 > 1e-9 * scale) {
        return Ok(None);
    }
    let (mut on_lattice, mut unit_count, mut unit_sum) = (0usize, 0usize, 0.0);
    steps(&mut |d| {
        if ((d / q0) - (d / q0).round()).abs() < 1e-3 {
            on_lattice += 1;
        }
        // Refined from the many unit steps.
        if (d / q0).round() == 1.0 {
            unit_count += 1;
            unit_sum += d;
        }
    })?;
    if (on_lattice as f64) < 0.999 * count as f64 {
        return Ok(None);
    }
    let q = unit_sum / unit_count as f64;
    let mut squares = 0.0;
    steps(&mut |d| {
        if (d / q0).round() == 1.0 {
            squares += (d - q).powi(2);
        }
    })?;
    let sd = (squares / (unit_count as f64 - 1.0).max(1.0)).sqrt() / (unit_count as f64).sqrt();
    Ok(Some((q, sd.max(q * 1e-12))))
}

/// A change of the white or correlated noise: levels of the residual's log wavelet variance
/// outside the baseline's (with the noise growth found above, still in the residual: without
/// it, that growth would read as a change of the correlated noise too). When found, the
/// baseline's structure is refitted on the residual and becomes the extended model's.
fn noise_change(
    run: &Run,
    slot: usize,
    channel: Channel,
    spec: &ModelSpec,
    resid: &SeriesBank,
    sims: &impl SeriesSet,
    found: &mut StochasticFindings,
) -> Result<(), DiagnoseError> {
    let (dt_s, max_level) = (run.dt_s, run.max_wv_level());
    let measured_wv = with_bank_series(resid, 0, |r| log_wv(r, dt_s, max_level))?;
    let sim_wv: Vec<Vec<f64>> = match found.effects.dynamic_noise {
        None => sims.map_each(&|s| log_wv(s, dt_s, max_level)),
        Some(_) => {
            let growth = ChannelModel {
                dynamic_noise: found.effects.dynamic_noise,
                ..Default::default()
            };
            (0..run.opts.replicates)
                .into_par_iter()
                .map(|r| {
                    let rng = ChaCha8Rng::seed_from_u64(
                        run.opts.seed ^ 0xd1_0153 ^ ((slot as u64) << 32) ^ r as u64,
                    );
                    let simulation =
                        ChannelSimulation::new(run, run.null_model(slot, r), &growth, channel, rng);
                    let mut wv = LogWv::new(dt_s, max_level);
                    simulation.for_each_block(0..run.n, &mut |_, x| {
                        wv.push(x);
                        Ok(())
                    })?;
                    Ok(wv.finish())
                })
                .collect::<Result<_, DiagnoseError>>()?
        }
    };
    let levels = measured_wv
        .len()
        .min(sim_wv.iter().map(Vec::len).min().unwrap_or(0));
    let tests: Vec<LevelTest> = (0..levels)
        .map(|j| {
            let sims_j: Vec<f64> = sim_wv.iter().map(|s| s[j]).collect();
            let level = j as u32 + 1;
            wv_level_test(
                measured_wv[j],
                &sims_j,
                eta3(level_coefficients(run.n, level), level),
                run.alpha_test,
            )
        })
        .collect();
    let scale_s = |j: usize| dt_s * 2f64.powi(j as i32 + 1);
    let undecided: Vec<usize> = (0..levels).filter(|&j| !tests[j].decidable).collect();
    if let (Some(&first), Some(&last)) = (undecided.first(), undecided.last()) {
        let edof: Vec<f64> = undecided.iter().map(|&j| tests[j].edof).collect();
        let (lo, hi) = (
            edof.iter().copied().fold(f64::INFINITY, f64::min),
            edof.iter().copied().fold(0.0, f64::max),
        );
        let (scales, dof) = if first == last {
            (
                format!("scale {} s", significant(scale_s(first), 3)),
                format!("{lo:.1}"),
            )
        } else {
            (
                format!(
                    "scales {} to {} s",
                    significant(scale_s(first), 3),
                    significant(scale_s(last), 3)
                ),
                format!("{lo:.1} to {hi:.1}"),
            )
        };
        found.notes.push(format!(
            "{channel}: the wavelet variance at {} of {levels} levels ({scales}) has too few degrees of freedom to decide (equivalent dof {dof}): not tested",
            undecided.len(),
        ));
    }
    // Significant and large enough to matter: at the finest levels the wavelet variance of a
    // long record is so precise that a 1-2% model error (in sigma) is significant; below
    // WV_MIN_LOG_DEVIATION it is not named.
    let bad: Vec<usize> = (0..levels)
        .filter(|&j| {
            tests[j].decidable
                && tests[j].p_value < run.alpha_test
                && (measured_wv[j] - tests[j].null_log_mean).abs() > WV_MIN_LOG_DEVIATION
        })
        .collect();
    if bad.is_empty() {
        return Ok(());
    }
    for &j in &bad {
        found.discrepancies.push(Discrepancy {
            channel,
            statistic: format!(
                "wavelet variance (({})^2) at level {} (scale {} s)",
                spec.unit,
                j + 1,
                significant(scale_s(j), 3)
            ),
            measured: measured_wv[j].exp(),
            simulated_range: simulated_range(
                &sim_wv.iter().map(|s| s[j].exp()).collect::<Vec<_>>(),
            ),
            detail: format!(
                "variance x{:.3} the baseline's; p = {:.2e} (chi-square, {:.1} equivalent dof), {:.2e} family-wise",
                (measured_wv[j] - tests[j].null_log_mean).exp(),
                tests[j].p_value,
                tests[j].edof,
                run.family_p(tests[j].p_value)
            ),
        });
    }
    let p = bad.iter().map(|&j| tests[j].p_value).fold(1.0, f64::min);
    let wv = with_bank_series(resid, 0, |r| fit_wv(r, dt_s).ok())?;
    refit_noise(channel, spec, wv, &bad, run.family_p(p), found);
    Ok(())
}

/// Refits the baseline's structure on the wavelet variance `wv` of what remains (none: too
/// short to have one) and names the changed parameters: the white noise when only the two
/// finest levels are off, the correlated processes otherwise.
fn refit_noise(
    channel: Channel,
    spec: &ModelSpec,
    wv: Option<WaveletVariance>,
    bad_levels: &[usize],
    p_value: f64,
    found: &mut StochasticFindings,
) {
    let Some(wv) = wv else {
        return;
    };
    let Ok(input) = FitInput::from_wv(&wv) else {
        return;
    };
    let choice = ModelChoice::Fixed(spec.structure());
    let Ok(fit) = analyze(
        channel.name(),
        &spec.unit,
        &input,
        &choice,
        None,
        &FitOptions::default(),
    ) else {
        return;
    };
    let only_small = bad_levels.iter().all(|&j| j < 2);
    let cause = if only_small {
        Cause::WhiteNoiseChange
    } else {
        Cause::CorrelatedNoiseChange
    };
    let params: Vec<_> = fit
        .parameters
        .iter()
        .filter(|p| {
            if only_small {
                p.process == "WN"
            } else {
                p.process.starts_with("GM") || p.process == "RW"
            }
        } && p.name != "beta_per_s")
        .collect();
    // Named only when a changed parameter's interval excludes the baseline's value.
    let baseline_params = parameter_values(spec);
    let changed = params.iter().any(|p| {
        let before = baseline_params
            .iter()
            .find(|(process, name, _)| *process == p.process && *name == p.name)
            .map(|(_, _, v)| *v);
        match (p.ci95, before) {
            (Some([lo, hi]), Some(v)) => v < lo || v > hi,
            _ => false,
        }
    });
    if params.is_empty() || !changed {
        return;
    }
    found.stochastic = fit.model_object.clone();
    found.findings.push(Finding {
        channel,
        cause,
        regressors: params
            .iter()
            .map(|p| format!("{} {} ({})", p.process, p.name, p.unit))
            .collect(),
        estimate: json!(params.iter().map(|p| p.value).collect::<Vec<_>>()),
        ci95: json!(params
            .iter()
            .map(|p| p.ci95.unwrap_or([f64::NAN, f64::NAN]))
            .collect::<Vec<_>>()),
        variance_explained: f64::NAN,
        p_value: Some(p_value),
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn lattice_of(x: &[f64]) -> Option<(f64, f64)> {
        let pass = |visit: &mut dyn FnMut(f64)| {
            x.iter().for_each(|v| visit(*v));
            Ok::<_, std::convert::Infallible>(())
        };
        lattice_step_in(pass).unwrap_or_else(|never| match never {})
    }

    #[test]
    fn a_quantised_channel_gives_its_lsb_and_a_continuous_one_none() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let lsb = 0.0061;
        let continuous: Vec<f64> = (0..5_000)
            .map(|i| (i as f64 * 0.01).sin() + 0.02 * rng.random::<f64>())
            .collect();
        assert_eq!(lattice_of(&continuous), None);
        let quantised: Vec<f64> = continuous.iter().map(|v| (v / lsb).round() * lsb).collect();
        let (q, se) = lattice_of(&quantised).unwrap();
        assert!((q / lsb - 1.0).abs() < 1e-9, "{q} {se}");
        assert!(se < 1e-9 * lsb.max(q), "{se}");
        // Too few steps to tell, and a constant: none.
        assert_eq!(lattice_of(&quantised[..50]), None);
        assert_eq!(lattice_of(&[1.0; 1_000]), None);
    }
}
