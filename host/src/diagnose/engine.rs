//! The discrepancy engine behind `dynacal diagnose`: compares measured error signals with
//! the baseline stochastic model simulated along the measured dynamics, names the causes of
//! what the baseline cannot explain, builds the extended model and measures the gain.
//!
//! Causes are told apart by their physics:
//! - deterministic sensitivities are per-channel regressions on the regressor that physics
//!   says drives them: the channel's own input (`scale_factor`), another axis' input
//!   (`cross_axis`), specific force on a gyro (`g_sensitivity`), angular acceleration
//!   (`angular_acceleration`), rate of change of specific force (`jerk`);
//! - a time offset is one coefficient common to every channel of the sensor, on each
//!   channel's own derivative, and a lever arm is omega_dot x r + omega x (omega x r) on the
//!   accelerometers: both are estimated jointly by the calibration of
//!   [`crate::calibration::build_error_signals`] and named when significant;
//! - stochastic causes are tested against the same statistic on series simulated from the
//!   baseline: outliers, vibration lines, a shift of the mean, noise growing with the
//!   dynamics, quantization (the raw sensor values lie on a lattice), and a change of the
//!   correlated or white noise (the wavelet variance of what remains).
//!
//! The stages, each in its own module of `diagnose`, run in this order:
//! - `calibration`: error signals from the calibration against the reference (or static
//!   data), and at the end the sensor-wide terms (time offset, lever arm) as findings;
//! - [`super::baseline`]: the model to compare with, given or fitted on the quietest stretch;
//! - `terms`: the deterministic terms, per channel a stepwise selection over the physics
//!   candidates, each fitted jointly with the calibration on every channel's rows by
//!   generalised least squares (`moments`, in the metric of each channel's baseline noise,
//!   `whiten`), and a bias step found by a local scan and sized from its windows; then
//!   across channels, a joint fit of all kept terms, so a term one channel shows only
//!   because another's term moved the calibration drops out;
//! - `stochastic`: the stochastic effects of what the terms leave;
//! - `gain`: the gain of the extended model over the baseline, in-sample and held out;
//! - `extension`: the extended model, a simulator model file.
//!
//! False alarms are controlled by strict per-test levels (Bonferroni over the tests of a
//! run), an effect-size floor for deterministic terms, simulation-calibrated thresholds, and
//! coefficient spreads no smaller than the measured residual's own (so a noise stronger than
//! the baseline's is not read as terms).

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use statrs::distribution::{ContinuousCDF, Normal};

pub use super::baseline::Baseline;
pub use super::calibration::Recording;
use super::calibration::{calibrate, sensor_wide_terms};
pub(super) use super::draws::ChannelSimulation;
use super::extension::{channel_model, extended_model};
use super::gain::{measure_gain, ChannelModelSims};
use super::generalise::{keeps_noise_model, kept_coefficients, kept_effects, select};
use super::moments::Absorber;
use super::signals::RunSignals;
use super::stats::{Series, SeriesSet, WindowMeanSquares};
use super::stochastic::{find_stochastic_effects, lattice_step_in};
use super::terms::{find_terms, ChannelTerms, FittedTerms};
use crate::calibration::{CalibrationSummary, DesignRows};
use crate::gmwm::model::ModelSpec;
use crate::interchange::ImuRecording;
use crate::model::{Cause, Channel, ChannelModel, SimModel};
use crate::progress::{stage, Tally};
use crate::series_bank::{block_ranges, SeriesBank};

/// Errors of the engine.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DiagnoseError {
    /// The calibration against the reference failed.
    #[error(transparent)]
    Errors(#[from] crate::calibration::ErrorsError),
    /// The baseline model file cannot be used.
    #[error("baseline model {path}: {message}")]
    Baseline { path: String, message: String },
    /// A channel cannot be diagnosed (no baseline model for it, or its baseline fit failed).
    #[error("channel {channel}: {message}")]
    Channel { channel: Channel, message: String },
    /// A long run's series could not be written to, or read back from, their temporary file.
    #[error(
        "the temporary file in {dir} that holds a long run's series: {source} (set TMPDIR to a \
         folder with room for a few dozen series of the drive's length, 8 bytes an epoch each)"
    )]
    Spill {
        dir: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl From<crate::series_bank::SpillError> for DiagnoseError {
    fn from(e: crate::series_bank::SpillError) -> Self {
        DiagnoseError::Spill {
            dir: std::env::temp_dir(),
            source: e.0,
        }
    }
}

/// Options of [`diagnose`].
#[derive(Debug, Clone, Copy)]
pub struct DiagnoseOptions {
    /// Baseline simulations per channel.
    pub replicates: usize,
    pub seed: u64,
    /// Family-wise false-alarm level of a whole run: the probability that a run with
    /// nothing beyond the baseline names anything (Bonferroni over its tests).
    pub alpha: f64,
    /// Smallest share of a channel's error variance a deterministic term must explain.
    pub min_variance_explained: f64,
    /// Most simulated samples (replicates times epochs) of one channel held in memory;
    /// above it, the simulations are drawn again each time a stage needs them (same seeds,
    /// same series, the same report), so a long drive's memory does not grow with the
    /// replicates.
    pub held_samples: usize,
}

/// The default [`DiagnoseOptions::held_samples`]: 2^23 samples, 64 MiB a channel (30
/// replicates of a 280 s drive at 1 kHz).
pub const HELD_SAMPLES: usize = 1 << 23;

impl DiagnoseOptions {
    /// Most epochs a run holds everything of: above it the run is long (one channel's
    /// simulations exceed [`DiagnoseOptions::held_samples`]), its simulations are drawn
    /// again at each stage and its calibration forms the epochs a block at a time.
    pub fn held_epochs(&self) -> usize {
        self.held_samples / self.replicates.max(1)
    }
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            replicates: 30,
            seed: 1,
            alpha: 0.05,
            min_variance_explained: 0.005,
            held_samples: HELD_SAMPLES,
        }
    }
}

/// A named cause (the output contract's `findings` entries).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finding {
    pub channel: Channel,
    pub cause: Cause,
    /// The regressors or signal features the estimate refers to, in order.
    pub regressors: Vec<String>,
    /// SI units: a number, or a list aligned with `regressors` (a lever arm: 3 components).
    pub estimate: Value,
    /// [lo, hi], or a list of them aligned with `regressors`.
    pub ci95: Value,
    /// Share of the channel's error variance this term accounts for.
    pub variance_explained: f64,
    /// Family-wise p-value: the p-value of the test that named the cause times the number
    /// of tests of the run (Bonferroni), at most 1. A cause is named only below the run's
    /// `alpha`. None for a property read without a test (raw values on a lattice).
    #[serde(default)]
    pub p_value: Option<f64>,
}

/// Per-channel gain of the extended model over the baseline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gain {
    pub metric: String,
    pub baseline: f64,
    pub extended: f64,
    pub held_out_baseline: f64,
    pub held_out_extended: f64,
    /// Share of the error variance the extended model's deterministic terms explain
    /// (in-sample, and held out: fitted on the other blocks of the cross-validation).
    pub variance_explained: f64,
    pub held_out_variance_explained: f64,
    /// Causes named on the channel that did not enter the extended model.
    #[serde(default)]
    pub not_kept: Vec<NotKept>,
}

/// A cause named on a channel but left out of the extended model: adding it did not lower
/// the cross-validated misfit (by 1% or more).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NotKept {
    pub cause: Cause,
    /// The cross-validated WV misfit of the model before it, and with it.
    pub held_out_without: f64,
    pub held_out_with: f64,
}

/// A statistic the baseline fails to reproduce.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Discrepancy {
    pub channel: Channel,
    pub statistic: String,
    pub measured: f64,
    /// Range of the statistic over the baseline simulations.
    pub simulated_range: [f64; 2],
    pub detail: String,
}

/// Everything `diagnose` found.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DiagnoseReport {
    pub baseline_source: String,
    /// The family-wise level of the run: the probability that a run with nothing beyond the
    /// baseline names anything.
    #[serde(default)]
    pub alpha: f64,
    /// The number of tests of the run (Bonferroni's m); a cause is named when its test's
    /// p-value is below alpha / tests.
    #[serde(default)]
    pub tests: usize,
    pub calibration: Option<CalibrationSummary>,
    pub findings: Vec<Finding>,
    pub gain: BTreeMap<Channel, Gain>,
    pub discrepancies: Vec<Discrepancy>,
    /// Per channel, the measured error's wavelet variance against the simulated bands of the
    /// baseline and the extended model (what the gain's misfit compares; the report plots it).
    pub wv_curves: BTreeMap<Channel, WvCurves>,
    /// The extended model as a simulator model file (`dynacal simulate --model`).
    pub extended_model: SimModel,
    /// Notes on what was assumed.
    pub notes: Vec<String>,
}

/// Haar wavelet variance of a channel's measured error and the 95% bands of the same
/// statistic over simulations of the baseline and of the extended model, in the channel's
/// squared SI unit ((rad/s)^2 or (m/s^2)^2), at scales `scale_s` = 2^j dt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WvCurves {
    pub scale_s: Vec<f64>,
    pub measured: Vec<f64>,
    pub baseline_lo: Vec<f64>,
    pub baseline_hi: Vec<f64>,
    pub extended_lo: Vec<f64>,
    pub extended_hi: Vec<f64>,
}

/// Model error of the calibration's lever arm, m (1 sigma), added to its statistical
/// uncertainty: on simulated 300 s car runs the estimate missed the truth by 0.85 mm with a
/// statistical sigma of 0.36 mm (the linearised eq. 11 with interpolated reference rates and
/// their derivatives is not exact at the millimetre level).
pub const LEVER_ARM_MODEL_SIGMA_M: f64 = 1e-3;

/// Smallest deviation of a level's log wavelet variance from the baseline's that names a
/// noise change: 0.1 is about 10% in variance, 5% in sigma. On simulated null runs,
/// deviations of 0.03 at level 1 (1.5% in sigma) were significant and named a
/// white-noise change.
pub const WV_MIN_LOG_DEVIATION: f64 = 0.1;

/// The two-sided 95% normal quantile.
pub(super) const Z_FLOOR: f64 = 1.959_963_984_540_054;

/// The 95% interval of an estimate with standard error `se`.
pub(super) fn ci(est: f64, se: f64) -> [f64; 2] {
    [est - Z_FLOOR * se, est + Z_FLOOR * se]
}

/// [min, max] of a statistic over simulations.
pub(super) fn simulated_range(vals: &[f64]) -> [f64; 2] {
    [
        vals.iter().copied().fold(f64::INFINITY, f64::min),
        vals.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    ]
}

/// What every stage of one run shares: the data, the calibration, the baseline, the options
/// and the quantities derived from them once.
pub(super) struct Run<'a> {
    /// The sensor recording's first time, s: findings' times count from it.
    pub sensor_start_s: f64,
    /// Per channel (gx..az) the lattice step of the raw sensor values and its standard
    /// error, where they lie on one (quantised output).
    pub raw_lattice: [Option<(f64, f64)>; 6],
    pub signals: &'a RunSignals,
    pub calibration: Option<&'a CalibrationSummary>,
    pub design: Option<DesignRows<'a>>,
    pub baseline: &'a Baseline,
    pub opts: &'a DiagnoseOptions,
    /// The channels the sensor has, in [`Channel::ALL`] order; a channel's position here
    /// (its slot) seeds its simulations.
    pub channels: Vec<Channel>,
    /// Epochs.
    pub n: usize,
    /// Median sample interval, s.
    pub dt_s: f64,
    /// True with a reference: the dynamics are measured (without one they are zero).
    pub has_dynamics: bool,
    /// The mean of |omega|^2 over each window of a channel's noise-growth regression
    /// ([`super::stochastic::noise_window`], [`super::stats::WindowMeanSquares`]),
    /// (rad/s)^2: what that test needs of the dynamics, without |omega| per epoch.
    pub omega2_windows: Vec<f64>,
    /// The mean of |omega|^2 over the run, (rad/s)^2.
    pub mean_omega2: f64,
    /// Two-sided normal quantile of one test at `alpha_test`.
    pub z_strict: f64,
    /// Number of tests of the run (Bonferroni's m).
    pub tests: usize,
    /// False-alarm level of one test: the run's `alpha` over its tests.
    pub alpha_test: f64,
    /// Per slot, the model of each baseline simulation ([`super::null::null_models`]).
    pub null_models: Vec<Vec<ModelSpec>>,
    /// The passes over the channels done and announced ([`Run::per_channel`] counts a
    /// channel's pass as one unit), for a progress display.
    pub work: Tally,
}

impl Run<'_> {
    /// The position of a channel of the run in [`Run::channels`].
    pub fn slot(&self, channel: Channel) -> usize {
        self.channels
            .iter()
            .position(|c| *c == channel)
            .expect("a channel of the run")
    }

    /// The baseline model of a channel.
    pub fn spec(&self, channel: Channel) -> Result<&ModelSpec, DiagnoseError> {
        self.baseline
            .channels
            .get(&channel)
            .ok_or_else(|| DiagnoseError::Channel {
                channel,
                message: format!(
                    "the baseline model ({}) has no model for it",
                    self.baseline.source
                ),
            })
    }

    /// The model of baseline simulation `r` of the channel at `slot`: the baseline drawn
    /// from its sampling distribution (or the baseline itself when that is not known).
    pub fn null_model(&self, slot: usize, r: usize) -> &ModelSpec {
        let models = &self.null_models[slot];
        &models[r % models.len()]
    }

    /// Baseline simulation `r` of the channel at `slot`: the null distribution of every
    /// statistic. Seeded by slot and replicate, so every stage draws the same ones.
    pub fn baseline_sim(&self, slot: usize, r: usize) -> Vec<f64> {
        let mut series = Vec::with_capacity(self.n);
        self.for_each_baseline_block(slot, r, &mut |block| series.extend_from_slice(block));
        series
    }

    /// [`Run::baseline_sim`] a block at a time: `visit(block)` for each block of the run's
    /// epochs, in order, none of them held after its visit.
    pub fn for_each_baseline_block(&self, slot: usize, r: usize, visit: &mut dyn FnMut(&[f64])) {
        self.baseline_simulation(slot, r)
            .for_each_block(0..self.n, &mut |_, block| {
                visit(block);
                Ok(())
            })
            .expect("a simulation of processes alone reads no signal");
    }

    /// [`Run::baseline_sim`] to draw a block at a time.
    pub fn baseline_simulation(&self, slot: usize, r: usize) -> ChannelSimulation<'_> {
        use rand::SeedableRng;
        let rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            self.opts.seed ^ ((slot as u64) << 32) ^ r as u64,
        );
        ChannelSimulation::of_processes(self, self.null_model(slot, r), rng)
    }

    /// Whether the run is long: one channel's simulations exceed
    /// [`DiagnoseOptions::held_samples`].
    pub fn is_long(&self) -> bool {
        self.n > self.opts.held_epochs()
    }

    /// `f(slot, channel, item)` for each channel of the run with its item, in order: in
    /// parallel on a short run, one channel after the other on a long one, where a channel's
    /// working set is large (the work within a channel is parallel either way).
    pub fn per_channel<I: Send, T: Send>(
        &self,
        items: Vec<I>,
        f: impl Fn(usize, Channel, I) -> T + Sync + Send,
    ) -> Vec<T> {
        let jobs = self.channels.iter().copied().zip(items).enumerate();
        let counted = |(slot, (channel, item)): (usize, (Channel, I))| {
            let out = f(slot, channel, item);
            self.work.finish_one();
            out
        };
        if self.is_long() {
            jobs.map(counted).collect()
        } else {
            jobs.collect::<Vec<_>>()
                .into_par_iter()
                .map(counted)
                .collect()
        }
    }

    /// Every baseline simulation of the channel at `slot`: held when they fit
    /// [`DiagnoseOptions::held_samples`], drawn again at each visit otherwise.
    pub fn baseline_sims(&self, slot: usize) -> BaselineSims<'_> {
        BaselineSims {
            run: self,
            slot,
            held: (!self.is_long()).then(|| {
                (0..self.opts.replicates)
                    .into_par_iter()
                    .map(|r| self.baseline_sim(slot, r))
                    .collect()
            }),
        }
    }

    /// The family-wise p-value of a test whose own p-value is `p` (Bonferroni).
    pub fn family_p(&self, p: f64) -> f64 {
        (p * self.tests as f64).min(1.0)
    }

    /// What a fit of terms jointly with the calibration needs of it.
    pub fn absorber(&self) -> Absorber<'_> {
        match self.design {
            Some(d) => Absorber::Design(d),
            None => Absorber::Mean,
        }
    }

    /// Coarsest wavelet level compared on the whole run (levels 1..=this): the largest
    /// that still averages over four or more blocks.
    pub fn max_wv_level(&self) -> u32 {
        max_wv_level(self.n)
    }
}

/// Coarsest wavelet level compared on a run of `n` epochs (levels 1..=this): the largest
/// that still averages over four or more blocks.
fn max_wv_level(n: usize) -> u32 {
    ((n.max(2) as f64).log2().floor() as u32)
        .saturating_sub(2)
        .max(1)
}

/// The baseline simulations of one channel of a run ([`Run::baseline_sims`]).
pub(super) struct BaselineSims<'r> {
    run: &'r Run<'r>,
    slot: usize,
    held: Option<Vec<Vec<f64>>>,
}

impl SeriesSet for BaselineSims<'_> {
    fn map_first<T: Send>(&self, count: usize, f: &(dyn Fn(&Series) -> T + Sync)) -> Vec<T> {
        match &self.held {
            Some(held) => held.map_first(count, f),
            None => (0..count.min(self.run.opts.replicates))
                .into_par_iter()
                .map(|r| {
                    let draw = |visit: &mut dyn FnMut(&[f64])| {
                        self.run.for_each_baseline_block(self.slot, r, visit)
                    };
                    f(&Series::Drawn {
                        len: self.run.n,
                        draw: &draw,
                    })
                })
                .collect(),
        }
    }
}

/// The number of tests a run makes, the m of its Bonferroni rule: per channel the
/// deterministic candidates (15 regressors and a bias step, with dynamics), noise growth,
/// outliers, vibration lines (one test, already corrected over the spectrum's bins) and one
/// test per wavelet-variance level; and the sensor-wide time offset and lever arm.
fn tests_of_run(channels: usize, n: usize, has_dynamics: bool) -> usize {
    let levels = max_wv_level(n) as usize;
    let deterministic = if has_dynamics { 16 } else { 1 };
    let sensor_wide = if has_dynamics { 4 } else { 0 };
    (channels * (deterministic + 3 + levels) + sensor_wide).max(1)
}

/// The epochs of error signals and what every stage reads of them.
struct Grid {
    n: usize,
    /// Median sample interval, s.
    dt_s: f64,
    /// See [`Run::omega2_windows`].
    omega2_windows: Vec<f64>,
    /// See [`Run::mean_omega2`].
    mean_omega2: f64,
    /// The channels present, in [`Channel::ALL`] order.
    channels: Vec<Channel>,
}

fn grid_of(signals: &RunSignals) -> Result<Grid, DiagnoseError> {
    let channels: Vec<Channel> = Channel::ALL
        .into_iter()
        .filter(|c| signals.has_error(*c))
        .collect();
    let n = signals.epochs();
    let dt_s = signals.median_step_s()?;
    let mut windows = WindowMeanSquares::new(n, super::stochastic::noise_window(dt_s));
    let mut sum_omega2 = 0.0;
    signals.for_each_angular_rate_norm(0..n, &mut |_, norm| {
        windows.add(norm);
        norm.iter().for_each(|w| sum_omega2 += w * w);
    })?;
    Ok(Grid {
        n,
        dt_s,
        omega2_windows: windows.finish(),
        mean_omega2: sum_omega2 / n as f64,
        channels,
    })
}

/// What one channel contributes to the report.
struct ChannelResult {
    findings: Vec<Finding>,
    discrepancies: Vec<Discrepancy>,
    gain: Gain,
    wv_curves: WvCurves,
    model: ChannelModel,
    /// What the calibration took from the channel's terms.
    absorbed: Option<nalgebra::DVector<f64>>,
    /// What was not tested on the channel, and why.
    notes: Vec<String>,
}

/// The stages after the deterministic terms, on one channel (at `slot`): its terms as
/// findings, the stochastic effects of what they leave, the gain and the extended model.
fn diagnose_channel(
    run: &Run,
    slot: usize,
    channel: Channel,
    mut found: ChannelTerms,
) -> Result<ChannelResult, DiagnoseError> {
    let spec = run.spec(channel)?;
    let e = channel_error(run, channel, found.calibration_spill.as_ref())?;
    stage(|| format!("channel {}: stochastic effects", channel.name()));
    let sims = run.baseline_sims(slot);
    let mut discrepancies = std::mem::take(&mut found.discrepancies);
    let terms = FittedTerms::new(run, channel, found, &e)?;
    let mut findings = terms.findings(run, channel);
    let mut resid = terms.residual(&e, run.is_long())?;
    let stochastic =
        find_stochastic_effects(run, slot, channel, spec, terms.var_e, &mut resid, &sims)?;
    drop(resid);
    stage(|| format!("channel {}: selecting what to keep", channel.name()));
    let selection = select(run, slot, spec, &e, &terms, &stochastic)?;
    let coefficients = kept_coefficients(&terms, &selection.kept);
    let effects = kept_effects(&stochastic, &selection.kept);
    let extended = ChannelModelSims {
        coefficients: &coefficients,
        stochastic: keeps_noise_model(&selection.kept).then_some(&stochastic.stochastic),
        effects: &effects,
        intercept: terms.intercept,
    };
    let model = channel_model(&terms, &stochastic, &selection.kept, spec);
    stage(|| format!("channel {}: measuring the gain", channel.name()));
    let (gain, wv_curves) = measure_gain(run, slot, &e, &terms, &extended, selection)?;
    findings.extend(stochastic.findings);
    discrepancies.extend(stochastic.discrepancies);
    let notes = stochastic.notes;
    Ok(ChannelResult {
        notes,
        findings,
        discrepancies,
        gain,
        wv_curves,
        model,
        absorbed: run.design.map(|d| terms.absorbed_by(d)),
    })
}

/// The error on `channel` as the joint calibration leaves it (less the fitted error of the
/// calibration parameters `pushed` a later stage moved, where it did), in a bank of one
/// series: held on a short run, spilled on a long one.
fn channel_error(
    run: &Run,
    channel: Channel,
    pushed: Option<&nalgebra::DVector<f64>>,
) -> Result<SeriesBank, DiagnoseError> {
    let mut bank = SeriesBank::columns(run.n, 1, run.is_long())?;
    for epochs in block_ranges(0..run.n) {
        let mut e = run
            .signals
            .error_range(channel, epochs.clone())?
            .into_owned();
        if let (Some(pushed), Some(design)) = (pushed, run.design) {
            design.add_fitted(channel.index(), pushed, -1.0, epochs.clone(), &mut e)?;
        }
        bank.write(0, epochs.start, &e)?;
    }
    Ok(bank)
}

/// Runs the engine on a sensor recording against a reference (or, without one, on static
/// data whose truth is constant). The recordings are taken, and dropped once the error
/// signals are formed: on a long drive they are a tenth of what the diagnosis holds.
pub fn diagnose(
    sensor: ImuRecording,
    reference: Option<ImuRecording>,
    baseline: Option<Baseline>,
    opts: &DiagnoseOptions,
) -> Result<DiagnoseReport, DiagnoseError> {
    diagnose_recordings(sensor.into(), reference.map(Into::into), baseline, opts)
}

/// [`diagnose`] of recordings held or in spill files (a long interchange file read without
/// being held: [`crate::input::spill_if_long`]).
pub fn diagnose_recordings(
    sensor: Recording,
    reference: Option<Recording>,
    baseline: Option<Baseline>,
    opts: &DiagnoseOptions,
) -> Result<DiagnoseReport, DiagnoseError> {
    let mut notes = Vec::new();
    let has_dynamics = reference.is_some();
    if has_dynamics {
        stage(|| "calibrating against the reference (boresight, lever arm, time offset)".into());
    }
    let sensor_start_s = sensor.first_time_s()?;
    let mut raw_lattice = [None; 6];
    for (ch, lattice) in raw_lattice.iter_mut().enumerate() {
        *lattice = lattice_step_in(|visit| sensor.for_each_value(ch, visit).map(|_| ()))?;
    }
    let calibrated = calibrate(sensor, reference, opts.held_epochs(), &mut notes)?;
    let signals = &calibrated.signals;
    let Grid {
        n,
        dt_s,
        omega2_windows,
        mean_omega2,
        channels,
    } = grid_of(signals)?;
    let baseline = match baseline {
        Some(b) => b,
        None => {
            stage(|| "fitting the baseline model on the quietest stretch".into());
            let b = super::baseline::fit_quietest(signals, &channels, dt_s)?;
            notes.push(format!("no baseline model given: {}", b.source));
            b
        }
    };
    for channel in &channels {
        if !baseline.channels.contains_key(channel) {
            return Err(DiagnoseError::Channel {
                channel: *channel,
                message: format!(
                    "the baseline model ({}) has no model for it",
                    baseline.source
                ),
            });
        }
    }
    let (null_models, null_notes) =
        super::null::null_models(&baseline, &channels, opts.replicates, opts.seed);
    notes.extend(null_notes);
    let tests = tests_of_run(channels.len(), n, has_dynamics);
    let alpha_test = opts.alpha / tests as f64;
    let z_strict = Normal::new(0.0, 1.0)
        .expect("normal")
        .inverse_cdf(1.0 - alpha_test / 2.0);
    let run = Run {
        sensor_start_s,
        raw_lattice,
        signals,
        calibration: calibrated.calibration.as_ref().map(|(c, _)| c),
        design: calibrated
            .calibration
            .as_ref()
            .map(|(_, d)| d.over_bank(signals.bank())),
        baseline: &baseline,
        opts,
        channels,
        n,
        dt_s,
        has_dynamics,
        omega2_windows,
        mean_omega2,
        z_strict,
        tests,
        alpha_test,
        null_models,
        work: Tally::default(),
    };
    // Two passes over the channels: the deterministic terms, then the rest of each.
    run.work.expect(2 * run.channels.len() as u64);
    stage(|| {
        format!(
            "simulating the baseline ({} replicates a channel) and testing deterministic terms",
            opts.replicates
        )
    });
    let found = find_terms(&run)?;
    let results: Vec<Result<ChannelResult, DiagnoseError>> = run
        .per_channel(found, |slot, channel, found| {
            diagnose_channel(&run, slot, channel, found)
        });
    let mut gain = BTreeMap::new();
    let mut wv_curves = BTreeMap::new();
    let mut discrepancies = Vec::new();
    let mut channel_models = BTreeMap::new();
    let mut channel_findings = Vec::new();
    let mut absorbed_total: Option<nalgebra::DVector<f64>> = None;
    for (&channel, r) in run.channels.iter().zip(results) {
        let r = r?;
        if let Some(a) = r.absorbed {
            absorbed_total = Some(match absorbed_total {
                Some(t) => t + a,
                None => a,
            });
        }
        channel_findings.extend(r.findings);
        discrepancies.extend(r.discrepancies);
        notes.extend(r.notes);
        gain.insert(channel, r.gain);
        wv_curves.insert(channel, r.wv_curves);
        channel_models.insert(channel, r.model);
    }
    stage(|| "terms common to the sensor and the extended model".into());
    let sensor_wide = sensor_wide_terms(&run, absorbed_total)?;
    let extended_model = extended_model(1.0 / dt_s, channel_models, run.calibration, &sensor_wide);
    let mut findings = sensor_wide.findings;
    findings.extend(channel_findings);
    for f in findings.iter_mut() {
        if f.variance_explained.is_nan() {
            f.variance_explained = 0.0;
        }
    }
    Ok(DiagnoseReport {
        baseline_source: baseline.source.clone(),
        alpha: opts.alpha,
        tests: run.tests,
        calibration: calibrated.calibration.map(|(c, _)| c),
        findings,
        gain,
        discrepancies,
        wv_curves,
        extended_model,
        notes,
    })
}
