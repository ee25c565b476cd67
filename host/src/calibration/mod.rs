//! The calibration of a sensor against a reference (paper Section II) and the error signals
//! it yields: put the two recordings on one time base, estimate the inter-IMU boresight,
//! lever arm, biases and residual time offset, bring the sensor into the reference body frame
//! (eq. 9) and subtract.
//!
//! Layout: `recordings` is where the two recordings are read (held in memory, or spilled
//! to a binary file and read a block at a time); `epochs` puts sensor and reference on the
//! epoch grid, a block of epochs at a time (running integrals, interpolation, a navigation
//! solution turned into rates and specific force); `passes` passes over the blocks in
//! order (one held block, or streamed blocks formed again on each pass); `least_squares` is
//! the linearised weighted least squares and its iteration; `motion` checks that the two
//! saw one motion; `design` keeps the fitted linear model for the diagnosis
//! ([`CalibrationDesign`]); `signals` turns the fit into the error signals, their dynamics
//! and the summary. Held ([`build_error_signals`]) and streamed
//! ([`write_error_signals_streamed`]) run the same code over different passes.
//!
//! Time base (`epochs`). Against a reference IMU the epochs are the sensor's own samples,
//! with the reference interpolated to them (8-point Lagrange); against a navigation solution they are
//! the solution's sample intervals, over which the sensor's running integrals (trapezoidal)
//! give exact means whatever the sample rates. A time offset is applied by reading the
//! reference, or the sensor's integrals, at shifted times.
//!
//! Reference kinds. A reference IMU (rate and specific-force columns, plus attitude for the
//! gravity term of the linear acceleration), or only a navigation solution (attitude, NED
//! velocity and position, such as the 10 Hz PSINS FOG INS output): then the reference body
//! rate over an epoch is the rotation between consecutive attitudes plus the Earth and
//! transport rates, and the specific force is the velocity change corrected for Coriolis and
//! gravity, compared at the reference's rate over matching intervals.
//!
//! Estimation. A batch weighted least-squares fit over all epochs of the linearised eqs.
//! 10-11 plus biases and the time-offset term (-dt times the derivative), iterated on the time
//! offset; 1-sigma values come from a Newey-West sandwich over epoch scores, because the
//! residuals are autocorrelated sensor noise. The boresight psi is the small rotation
//! C_b^s = exp(-[psi x]) from the reference body frame b to the sensor frame s; the lever arm
//! r is the sensor's position relative to the reference, in b, metres; the time offset is
//! positive when the sensor lags the reference. The error signals keep the sensor biases:
//! they are part of the error the stochastic model has to describe.

use serde::{Deserialize, Serialize};

mod design;
mod epochs;
mod least_squares;
pub(crate) mod motion;
mod passes;
mod recordings;
mod signal_bank;
mod signals;

use design::DesignSums;
pub use design::{CalibrationDesign, DesignRows};
pub(crate) use recordings::Samples;
pub use recordings::{SpillBuilder, SpilledRecording};
pub use signal_bank::SignalBank;

use std::path::Path;

use nalgebra::Rotation3;

use crate::error_signal::{ErrorSignalWriter, ErrorSignals};
use crate::interchange::ImuRecording;
use epochs::{EpochData, EpochGrid, EpochSource};
use passes::{Epochs, View};

/// Errors building error signals.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ErrorsError {
    /// The sensor recording has neither gyro nor accelerometer columns.
    #[error("sensor recording has no gyro (gx_rad_s ...) or accelerometer (ax_m_s2 ...) columns")]
    SensorHasNoChannels,
    /// The reference lacks what is needed.
    #[error("reference recording needs {0}")]
    ReferenceIncomplete(&'static str),
    /// The recordings do not overlap in time long enough.
    #[error("the recordings overlap for {overlap_s:.3} s, too short (need at least {needed_s} s): the sensor covers {:.3} .. {:.3} s, the reference {:.3} .. {:.3} s", sensor_s[0], sensor_s[1], reference_s[0], reference_s[1])]
    NoOverlap {
        overlap_s: f64,
        needed_s: f64,
        sensor_s: [f64; 2],
        reference_s: [f64; 2],
    },
    /// The two did not ride on one vehicle: their motions differ.
    #[error("the sensor and the reference did not see the same motion: {reason} (the {quantity}'s 1 s averages change by {sensor_variation:.3e} {unit} in the sensor, {reference_variation:.3e} {unit} in the reference); were they recorded together on one vehicle?")]
    DifferentMotion {
        quantity: &'static str,
        unit: &'static str,
        sensor_variation: f64,
        reference_variation: f64,
        reason: String,
    },
    /// The calibration is not observable from these data.
    #[error("calibration not observable from these data: {0}")]
    Unobservable(String),
    /// A recording could not be read (streamed).
    #[error(transparent)]
    Read(#[from] crate::interchange::TableError),
    /// A streamed recording's spill file could not be written or read back.
    #[error(
        "the spill file in {dir}: {source} (set TMPDIR to a folder with room for 8 bytes a value)"
    )]
    Spill {
        dir: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl From<crate::series_bank::SpillError> for ErrorsError {
    fn from(e: crate::series_bank::SpillError) -> Self {
        ErrorsError::Spill {
            dir: std::env::temp_dir(),
            source: e.0,
        }
    }
}

/// A vector estimate with its 1-sigma uncertainty per component.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate3 {
    pub value: [f64; 3],
    pub sigma: [f64; 3],
}

/// A scalar estimate with its 1-sigma uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate1 {
    pub value: f64,
    pub sigma: f64,
}

/// What was estimated while building the error signals (the `--json` summary).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationSummary {
    /// Boresight psi_b->s (small rotation from reference body to sensor frame), rad.
    pub boresight_rad: Estimate3,
    /// Lever arm r_b->s of the sensor w.r.t. the reference, reference body frame, m.
    /// `None` when the sensor has no accelerometers or the lever arm was not estimated.
    pub lever_arm_m: Option<Estimate3>,
    /// Time offset of the sensor w.r.t. the reference, s (positive: the sensor lags).
    pub time_offset_s: Option<Estimate1>,
    /// Gyro bias in the sensor frame, rad/s.
    pub gyro_bias_rad_s: Option<Estimate3>,
    /// Accelerometer bias in the sensor frame, m/s^2.
    pub accel_bias_m_s2: Option<Estimate3>,
    /// `imu` or `navigation_solution`.
    pub reference_kind: String,
    /// Number of epochs and their median length, s.
    pub epochs: usize,
    pub epoch_dt_s: f64,
    /// Standard deviation of each error channel after calibration (gx .. az; absent = null).
    pub error_std: [Option<f64>; 6],
    /// Newey-West lag (epochs) used for the uncertainties.
    pub hac_lag: usize,
    /// How the estimates were obtained.
    pub method: String,
    /// Anything the user should know (e.g. terms left out as unobservable).
    pub notes: Vec<String>,
}

/// Options for [`build_error_signals`].
#[derive(Debug, Clone, Copy)]
pub struct ErrorOptions {
    /// Estimate the lever arm (needs rotational dynamics; otherwise it is fixed to zero).
    pub estimate_lever_arm: bool,
    /// Estimate the time offset.
    pub estimate_time_offset: bool,
    /// Largest time offset searched, s: also the margin trimmed off the overlap.
    pub max_time_offset_s: f64,
    /// Epochs a streamed calibration ([`write_error_signals_streamed`]) forms at a time
    /// (about 200 bytes each, a few blocks held at once); the result does not depend on it.
    pub block_epochs: usize,
    /// Most epochs [`build_error_signals`] forms whole (their interpolated reference beside
    /// the recordings, about 330 bytes an epoch at its peak); a longer overlap is formed in
    /// blocks of `block_epochs`, again on each of the fit's passes.
    pub held_epochs: usize,
}

impl Default for ErrorOptions {
    fn default() -> Self {
        Self {
            estimate_lever_arm: true,
            estimate_time_offset: true,
            max_time_offset_s: 0.2,
            block_epochs: passes::BLOCK_EPOCHS,
            held_epochs: usize::MAX,
        }
    }
}

/// Builds the error signals of `sensor` against `reference` and reports the calibration.
pub fn build_error_signals(
    sensor: &ImuRecording,
    reference: &ImuRecording,
    opts: &ErrorOptions,
) -> Result<(ErrorSignals, CalibrationSummary), ErrorsError> {
    build_error_signals_with_design(sensor, reference, opts).map(|(s, c, _)| (s, c))
}

/// [`build_error_signals`], also returning the calibration's linear model at its solution.
/// Up to [`ErrorOptions::held_epochs`] epochs are formed whole, once per time offset and
/// rotation; more are formed in blocks of [`ErrorOptions::block_epochs`] on every pass, so
/// only the recordings and the error signals are held, not the epochs' interpolated
/// reference beside them (the result agrees to rounding).
pub fn build_error_signals_with_design(
    sensor: &ImuRecording,
    reference: &ImuRecording,
    opts: &ErrorOptions,
) -> Result<(ErrorSignals, CalibrationSummary, CalibrationDesign), ErrorsError> {
    let mut gather = Gather::Signals(None);
    let (summary, design) = form_error_signals(sensor, reference, opts, &mut gather)?;
    let Gather::Signals(Some(gathered)) = gather else {
        unreachable!("the final pass gathers the signals")
    };
    Ok((gathered.finish(), summary, design))
}

/// The error signals a diagnosis reads ([`SignalBank`]: the time, the reference's rates,
/// angular acceleration, specific force and its rate, and the errors) with the calibration
/// and its linear model, gathered a block at a time into a bank held, or spilled to a
/// temporary file when `spill`: then the recordings and a few blocks are all that is held.
/// The calibration design reads its rows from the bank ([`CalibrationDesign::over_bank`]).
pub(crate) fn build_signal_bank(
    sensor: &(dyn Samples + Sync),
    reference: &(dyn Samples + Sync),
    opts: &ErrorOptions,
    spill: bool,
) -> Result<(SignalBank, CalibrationSummary, CalibrationDesign), ErrorsError> {
    let mut gather = Gather::Bank(None, spill);
    let (summary, design) = form_error_signals(sensor, reference, opts, &mut gather)?;
    let Gather::Bank(Some(bank), _) = gather else {
        unreachable!("the final pass gathers the signals")
    };
    Ok((bank, summary, design))
}

/// One block of the final pass, at the calibration's solution, for a gatherer: its times,
/// epochs and errors (gx .. az), of which epochs `own` are the block's own.
struct Block<'b> {
    t_s: &'b [f64],
    data: &'b EpochData,
    errors: [Option<Vec<f64>>; 6],
    own: std::ops::Range<usize>,
}

/// What the final pass's blocks are gathered into, made when the epochs' grid is known: the
/// error signals whole, or a bank (spilled when its flag says so).
enum Gather {
    Signals(Option<Box<signals::Gathered>>),
    Bank(Option<SignalBank>, bool),
}

impl Gather {
    /// Makes room for the epochs of `grid`.
    fn start(&mut self, grid: &EpochGrid) -> Result<(), ErrorsError> {
        match self {
            Gather::Signals(gathered) => {
                *gathered = Some(Box::new(signals::Gathered::new(grid.epochs)));
            }
            Gather::Bank(bank, spill) => {
                let present = std::array::from_fn(|ch| {
                    if ch < 3 {
                        grid.has_gyro()
                    } else {
                        grid.has_accel()
                    }
                });
                *bank = Some(SignalBank::gathering(grid.epochs, present, *spill)?);
            }
        }
        Ok(())
    }

    /// Takes a block; the signals also its dynamics.
    fn add(&mut self, block: Block) -> Result<(), ErrorsError> {
        match self {
            Gather::Signals(gathered) => {
                let dynamics = signals::dynamics_columns(block.t_s, block.data);
                let gathered = gathered.as_mut().expect("started");
                gathered.add(block.t_s, block.errors, dynamics, block.data, block.own);
            }
            Gather::Bank(bank, _) => {
                let bank = bank.as_mut().expect("started");
                bank.add(block.t_s, &block.errors, block.data, block.own)?;
            }
        }
        Ok(())
    }

    /// The median interval between the epochs gathered, s (0 with fewer than two).
    fn median_step_s(&self) -> Result<f64, ErrorsError> {
        Ok(match self {
            Gather::Signals(gathered) => {
                let gathered = gathered.as_ref().expect("started");
                crate::interchange::median_step_s(gathered.t_s())
            }
            Gather::Bank(bank, _) => bank.as_ref().expect("started").median_step_s()?,
        }
        .unwrap_or(0.0))
    }
}

/// The calibration of `sensor` against `reference`, then a pass at its solution whose
/// blocks' error signals `gather` takes; the design keeps the specific force's rate unless
/// a bank does.
fn form_error_signals(
    sensor: &(dyn Samples + Sync),
    reference: &(dyn Samples + Sync),
    opts: &ErrorOptions,
    gather: &mut Gather,
) -> Result<(CalibrationSummary, CalibrationDesign), ErrorsError> {
    let [gyro, accel, ..] = sensor.triplets();
    if !gyro && !accel {
        return Err(ErrorsError::SensorHasNoChannels);
    }
    crate::progress::stage(|| "aligning the sensor's samples with the reference".into());
    let grid = EpochGrid::new(sensor, reference, opts)?;
    let block;
    let epochs = if grid.epochs <= opts.held_epochs {
        block = grid.block(sensor, reference, 0..grid.epochs)?;
        Epochs::Held {
            grid: &grid,
            source: EpochSource::new(&block)?,
        }
    } else {
        Epochs::Streamed {
            grid: &grid,
            sensor,
            reference,
            block_epochs: opts.block_epochs.max(1),
        }
    };
    let fit = calibrate(&epochs, opts)?;
    crate::progress::stage(|| "forming the error signals and the dynamics".into());
    // Final errors at the estimated boresight and time offset.
    let view = epochs.at(fit.shift_s, fit.r_sb)?;
    let lever_arm_b_m = fit.lever_arm_b_m();
    let present = [grid.has_gyro(), grid.has_accel()];
    let keep_f_dot = matches!(gather, Gather::Signals(_));
    let mut design = DesignSums::new(&fit.layout, fit.weights, present, grid.epochs, keep_f_dot);
    let mut spread = signals::ErrorSpread::default();
    gather.start(&grid)?;
    view.pass(&mut |block| {
        let errors = signals::error_columns(block.data, lever_arm_b_m);
        spread.add(&errors, block.own.clone());
        design.add(block.data, block.own.clone());
        let block = Block {
            t_s: block.t_s,
            data: block.data,
            errors,
            own: block.own.clone(),
        };
        gather.add(block)
    })?;
    drop(view);
    let epoch_dt_s = gather.median_step_s()?;
    let summary = signals::summary(fit, &grid, spread.std_dev(), epoch_dt_s);
    Ok((summary, design.finish()))
}

/// The motion check and the fit, over epochs held or streamed.
fn calibrate(epochs: &Epochs<'_>, opts: &ErrorOptions) -> Result<least_squares::Fit, ErrorsError> {
    let view = epochs.at(0.0, Rotation3::identity())?;
    motion::check_same_motion(&view, epochs.grid().epochs)?;
    drop(view);
    crate::progress::stage(|| {
        "estimating boresight, lever arm and time offset (searched over shifts)".into()
    });
    least_squares::fit(epochs, opts)
}

/// [`build_error_signals`] for recordings of any length: the interchange files `sensor` and
/// `reference` (CSV, CSV.gz or Parquet) are read once into spill files in the temporary
/// folder, the calibration passes over them a block of epochs at a time, and the error
/// signals (every dynamics column, and the specific force) are written to `out` as they are
/// formed, whole or not at all. Memory holds a few blocks, not the recordings. The result is
/// [`build_error_signals`]' to rounding (the sandwich's sums and the spread are pooled over
/// blocks; against a navigation solution the sensor's running integrals start at each
/// block).
pub fn write_error_signals_streamed(
    sensor: &Path,
    reference: &Path,
    out: &Path,
    opts: &ErrorOptions,
) -> Result<CalibrationSummary, ErrorsError> {
    crate::progress::stage(|| format!("reading {} into a spill file", sensor.display()));
    let sensor = SpilledRecording::read(sensor)?;
    crate::progress::stage(|| format!("reading {} into a spill file", reference.display()));
    let reference = SpilledRecording::read(reference)?;
    calibrate_streamed(&sensor, &reference, out, opts)
}

/// [`write_error_signals_streamed`] over any [`Samples`].
fn calibrate_streamed(
    sensor: &(dyn Samples + Sync),
    reference: &(dyn Samples + Sync),
    out: &Path,
    opts: &ErrorOptions,
) -> Result<CalibrationSummary, ErrorsError> {
    let [gyro, accel, ..] = sensor.triplets();
    if !gyro && !accel {
        return Err(ErrorsError::SensorHasNoChannels);
    }
    crate::progress::stage(|| "aligning the sensor's samples with the reference".into());
    let grid = EpochGrid::new(sensor, reference, opts)?;
    let epochs = Epochs::Streamed {
        grid: &grid,
        sensor,
        reference,
        block_epochs: opts.block_epochs.max(1),
    };
    let fit = calibrate(&epochs, opts)?;
    crate::progress::stage(|| "writing the error signals and the dynamics".into());
    let view = epochs.at(fit.shift_s, fit.r_sb)?;
    let present = [gyro, gyro, gyro, accel, accel, accel];
    let mut writer = ErrorSignalWriter::create(out, present, true)?;
    let mut spread = signals::ErrorSpread::default();
    let lever_arm_b_m = fit.lever_arm_b_m();
    let mut row = Vec::with_capacity(writer.columns().len());
    view.pass(&mut |block| {
        let errors = signals::error_columns(block.data, lever_arm_b_m);
        let dynamics = signals::dynamics_columns(block.t_s, block.data);
        spread.add(&errors, block.own.clone());
        for k in block.own.clone() {
            signals::file_row(block.t_s, &errors, &dynamics, block.data, k, &mut row);
            writer.push(&row)?;
        }
        Ok(())
    })?;
    let epoch_dt_s = median_epoch_step_s(&view, grid.epochs)?;
    writer.finish()?;
    Ok(signals::summary(fit, &grid, spread.std_dev(), epoch_dt_s))
}

/// The median length of the epochs of `view` (`epochs` of them), s, as
/// [`crate::interchange::median_step_s`] gives it of their times held whole.
fn median_epoch_step_s(view: &View, epochs: usize) -> Result<f64, ErrorsError> {
    let steps = epochs.saturating_sub(1) as u64;
    let median = crate::numeric::select_by_passes(steps / 2, |visit| {
        let mut steps = crate::numeric::TimeSteps::new(visit);
        let read = view.pass(&mut |block| {
            block.t_s[block.own.clone()]
                .iter()
                .for_each(|&t| steps.push(t));
            Ok(())
        });
        steps.finish();
        read
    })?;
    Ok(median.unwrap_or(0.0))
}

#[cfg(test)]
mod tests {
    use super::least_squares::skew;
    use super::signals::std_dev;
    use super::*;
    use nalgebra::{Rotation3, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// Smooth, rich body motion: angular rate (rad/s) and its derivative, and specific force
    /// (m/s^2), as sums of sinusoids.
    fn motion(t: f64) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let tone = |a: f64, f: f64, p: f64| {
            let w = 2.0 * std::f64::consts::PI * f;
            (a * (w * t + p).sin(), a * w * (w * t + p).cos())
        };
        let comps = [
            [tone(0.3, 0.11, 0.0), tone(0.1, 0.7, 1.0)],
            [tone(0.25, 0.13, 2.0), tone(0.08, 0.9, 0.5)],
            [tone(0.5, 0.05, 1.0), tone(0.2, 0.6, 3.0)],
        ];
        let omega = Vector3::from_fn(|i, _| comps[i][0].0 + comps[i][1].0);
        let omega_dot = Vector3::from_fn(|i, _| comps[i][0].1 + comps[i][1].1);
        let f = Vector3::new(
            2.0 * (0.2 * t).sin(),
            1.5 * (0.17 * t + 1.0).sin(),
            -9.81 + 0.5 * (0.8 * t).sin(),
        );
        (omega, omega_dot, f)
    }

    /// The truth of [`simulated_pair`]: boresight (rad), lever arm (m), gyro bias (rad/s),
    /// accelerometer bias (m/s^2), time offset (s).
    fn simulated_truth() -> (Vector3<f64>, Vector3<f64>, Vector3<f64>, Vector3<f64>, f64) {
        (
            Vector3::new(0.02, -0.01, 0.03),
            Vector3::new(0.4, -0.25, 0.15),
            Vector3::new(1e-3, -2e-3, 5e-4),
            Vector3::new(0.05, -0.03, 0.08),
            0.012,
        )
    }

    /// A sensor (with white noise) and a reference IMU on one rich motion, `n` samples at
    /// 100 Hz.
    fn simulated_pair(n: usize) -> (ImuRecording, ImuRecording) {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (psi_true, r_true, bg, ba, dt_true) = simulated_truth();
        let c_bs = Rotation3::new(-psi_true);
        let dt = 0.01;
        let t_s: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
        let mut reference = ImuRecording {
            t_s: t_s.clone(),
            ..Default::default()
        };
        let mut sensor = ImuRecording {
            t_s: t_s.clone(),
            ..Default::default()
        };
        let [mut rg, mut ra, mut sg, mut sa]: [crate::interchange::Triplet; 4] = Default::default();
        for &t in &t_s {
            let (w, _, f) = motion(t);
            // The sensor lags: its sample at t shows the truth at t - dt_true.
            let (ws, wds, fs0) = motion(t - dt_true);
            let ws_b = ws;
            let fs_b = fs0 + skew(&wds) * r_true + skew(&ws_b) * skew(&ws_b) * r_true;
            let gyro = c_bs * ws_b
                + bg
                + Vector3::from_fn(|_, _| 2e-3 * rng.sample::<f64, _>(StandardNormal));
            let acc = c_bs * fs_b
                + ba
                + Vector3::from_fn(|_, _| 2e-2 * rng.sample::<f64, _>(StandardNormal));
            for i in 0..3 {
                rg[i].push(w[i]);
                ra[i].push(f[i]);
                sg[i].push(gyro[i]);
                sa[i].push(acc[i]);
            }
        }
        reference.gyro_rad_s = Some(rg);
        reference.accel_m_s2 = Some(ra);
        reference.attitude_rad = Some([vec![0.0; n], vec![0.0; n], vec![0.0; n]]);
        sensor.gyro_rad_s = Some(sg);
        sensor.accel_m_s2 = Some(sa);
        (sensor, reference)
    }

    #[test]
    fn recovers_boresight_lever_arm_biases_and_time_offset() {
        let (psi_true, r_true, bg, ba, dt_true) = simulated_truth();
        let (sensor, reference) = simulated_pair(30_000);
        let (sig, s) = build_error_signals(&sensor, &reference, &ErrorOptions::default()).unwrap();
        let within = |est: f64, sigma: f64, truth: f64, what: &str| {
            assert!(
                sigma > 0.0 && (est - truth).abs() < 4.0 * sigma,
                "{what}: {est} +- {sigma} vs {truth}"
            );
        };
        for i in 0..3 {
            within(
                s.boresight_rad.value[i],
                s.boresight_rad.sigma[i],
                psi_true[i],
                "psi",
            );
            let l = s.lever_arm_m.unwrap();
            within(l.value[i], l.sigma[i], r_true[i], "lever");
            assert!(
                (l.value[i] - r_true[i]).abs() < 0.02,
                "lever arm within 2 cm"
            );
            within(
                s.gyro_bias_rad_s.unwrap().value[i],
                s.gyro_bias_rad_s.unwrap().sigma[i],
                bg[i],
                "bg",
            );
            within(
                s.accel_bias_m_s2.unwrap().value[i],
                s.accel_bias_m_s2.unwrap().sigma[i],
                ba[i],
                "ba",
            );
        }
        let to = s.time_offset_s.unwrap();
        within(to.value, to.sigma, dt_true, "time offset");
        assert!((to.value - dt_true).abs() < 1e-3);
        // After calibration the gyro error is bias plus white noise: its mean is the bias in
        // the reference frame and its spread the noise averaged over the epoch.
        let gx = sig.error("gx").unwrap();
        let mean = gx.iter().sum::<f64>() / gx.len() as f64;
        assert!((mean - bg[0]).abs() < 2e-4, "{mean}");
        assert!(std_dev(gx) < 3e-3, "{}", std_dev(gx));
        assert!(sig.dynamics.iter().all(|d| d.len() == sig.t_s.len()));
    }

    #[test]
    fn streamed_in_blocks_equals_held_whole() {
        let (sensor, reference) = simulated_pair(20_000);
        let dir = tempfile::tempdir().unwrap();
        let (sensor_path, reference_path) = (dir.path().join("s.csv"), dir.path().join("r.csv"));
        sensor.write(&sensor_path).unwrap();
        reference.write(&reference_path).unwrap();
        let (held, held_summary) =
            build_error_signals(&sensor, &reference, &ErrorOptions::default()).unwrap();
        let (sensor, reference) = (
            SpilledRecording::read(&sensor_path).unwrap(),
            SpilledRecording::read(&reference_path).unwrap(),
        );
        for (block_epochs, name) in [(997, "e.csv"), (4096, "e.parquet")] {
            let out = dir.path().join(name);
            let opts = ErrorOptions {
                block_epochs,
                ..Default::default()
            };
            let summary = calibrate_streamed(&sensor, &reference, &out, &opts).unwrap();
            // Every epoch is formed from the same samples and summed in the same order: the
            // fit is the same to the bit; only the pooled spread differs, by rounding.
            let spread = |s: &CalibrationSummary| s.error_std.map(|e| e.unwrap());
            for (a, b) in spread(&summary).iter().zip(spread(&held_summary)) {
                assert!((a - b).abs() <= 1e-12 * b, "{a} {b}");
            }
            let exact = CalibrationSummary {
                error_std: held_summary.error_std,
                ..summary
            };
            assert_eq!(exact, held_summary);
            let streamed = ErrorSignals::read(&out).unwrap();
            assert_eq!(streamed.t_s, held.t_s);
            assert_eq!(streamed.errors, held.errors);
            assert_eq!(streamed.dynamics, held.dynamics);
            assert_eq!(streamed.specific_force_b_m_s2, held.specific_force_b_m_s2);
        }
    }

    #[test]
    fn recordings_formed_in_blocks_give_the_signals_and_design_held_ones_give() {
        let (sensor, reference) = simulated_pair(20_000);
        let whole = ErrorOptions::default();
        let (held, held_summary, held_design) =
            build_error_signals_with_design(&sensor, &reference, &whole).unwrap();
        let blocked_opts = ErrorOptions {
            held_epochs: 5_000,
            block_epochs: 997,
            ..whole
        };
        let (blocked, summary, design) =
            build_error_signals_with_design(&sensor, &reference, &blocked_opts).unwrap();
        // Each epoch is formed from the same samples: the signals are the same to the bit,
        // the pooled spread and the design's normal matrix to rounding.
        assert_eq!(blocked.t_s, held.t_s);
        assert_eq!(blocked.errors, held.errors);
        assert_eq!(blocked.dynamics, held.dynamics);
        assert_eq!(blocked.specific_force_b_m_s2, held.specific_force_b_m_s2);
        assert_eq!(design.f_dot_b_m_s3, held_design.f_dot_b_m_s3);
        let (a, b) = (design.over(&blocked), held_design.over(&held));
        let scale = b.bread().amax();
        assert!((a.bread() - b.bread()).amax() <= 1e-9 * scale);
        assert_eq!(
            CalibrationSummary {
                error_std: held_summary.error_std,
                ..summary
            },
            held_summary
        );
    }

    #[test]
    fn a_bank_held_or_spilled_holds_the_signals_and_gives_the_design_held_signals_give() {
        let (sensor, reference) = simulated_pair(20_000);
        let whole = ErrorOptions::default();
        let (held, held_summary, held_design) =
            build_error_signals_with_design(&sensor, &reference, &whole).unwrap();
        let blocked = ErrorOptions {
            held_epochs: 5_000,
            block_epochs: 997,
            ..whole
        };
        let f = held.specific_force_b_m_s2.as_ref().unwrap();
        let y: Vec<f64> = (0..held.t_s.len())
            .map(|k| (k as f64 * 0.01).sin())
            .collect();
        let theta =
            nalgebra::DVector::from_fn(held_design.over(&held).parameters(), |a, _| 1.0 + a as f64);
        for (opts, spill) in [(&whole, false), (&blocked, true)] {
            let (bank, summary, design) =
                build_signal_bank(&sensor, &reference, opts, spill).unwrap();
            assert_eq!(bank.is_spilled(), spill);
            assert_eq!(bank.epochs(), held.t_s.len());
            assert_eq!(bank.series(SignalBank::TIME).unwrap()[..], held.t_s[..]);
            for (axis, f) in f.iter().enumerate() {
                let series = |k: usize| bank.series(k).unwrap().into_owned();
                let rate = SignalBank::ANGULAR_RATE_RAD_S[axis];
                let acceleration = SignalBank::ANGULAR_ACCELERATION_RAD_S2[axis];
                assert_eq!(series(rate), held.angular_rate_rad_s(axis));
                assert_eq!(series(acceleration), held.angular_acceleration_rad_s2(axis));
                assert_eq!(&series(SignalBank::SPECIFIC_FORCE_M_S2[axis]), f);
                let f_dot = SignalBank::SPECIFIC_FORCE_RATE_M_S3[axis];
                assert_eq!(series(f_dot), held_design.f_dot_b_m_s3[axis]);
            }
            for channel in crate::model::Channel::ALL {
                let k = bank.error_index(channel).unwrap();
                assert_eq!(Some(&bank.series(k).unwrap()[..]), held.error_of(channel));
            }
            assert_eq!(
                CalibrationSummary {
                    error_std: held_summary.error_std,
                    ..summary
                },
                held_summary
            );
            // The rows read from the bank are the rows made from the held signals.
            let (a, b) = (design.over_bank(&bank), held_design.over(&held));
            assert!((a.bread() - b.bread()).amax() <= 1e-9 * b.bread().amax());
            for ch in 0..6 {
                let (ma, mb) = (a.moments(ch, &y).unwrap(), b.moments(ch, &y).unwrap());
                assert!((&ma - &mb).amax() <= 1e-9 * mb.amax(), "{ma} {mb}");
                let part = a.moments_in(ch, 300..7_000, &y[300..7_000]).unwrap();
                let mut masked = vec![0.0; y.len()];
                masked[300..7_000].copy_from_slice(&y[300..7_000]);
                let whole_masked = b.moments(ch, &masked).unwrap();
                assert!((&part - &whole_masked).amax() <= 1e-9 * whole_masked.amax());
                let (fa, fb) = (a.fitted(ch, &theta).unwrap(), b.fitted(ch, &theta).unwrap());
                assert_eq!(fa.len(), fb.len());
                assert!(fa
                    .iter()
                    .zip(&fb)
                    .all(|(x, z)| (x - z).abs() <= 1e-9 * z.abs().max(1.0)));
            }
        }
    }

    #[test]
    fn a_streamed_calibration_refuses_what_the_held_one_refuses_and_writes_nothing() {
        let (sensor, reference) = simulated_pair(3_000);
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("e.csv");
        let opts = ErrorOptions {
            block_epochs: 500,
            ..Default::default()
        };
        let later = ImuRecording {
            t_s: reference.t_s.iter().map(|t| t + 1000.0).collect(),
            ..reference.clone()
        };
        let still = ImuRecording {
            gyro_rad_s: Some(std::array::from_fn(|_| vec![1e-4; sensor.len()])),
            accel_m_s2: None,
            ..sensor.clone()
        };
        for (sensor, reference) in [(&sensor, &later), (&still, &reference)] {
            let held = build_error_signals(sensor, reference, &opts)
                .unwrap_err()
                .to_string();
            let streamed = calibrate_streamed(sensor, reference, &out, &opts)
                .unwrap_err()
                .to_string();
            assert_eq!(streamed, held);
            assert!(!out.exists());
        }
    }
}
