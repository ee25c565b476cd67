//! The calibration against the reference (boresight, lever arm, time offset, biases; see
//! [`crate::calibration::build_signal_bank`]) that turns the sensor into error signals (a
//! [`SignalBank`], in a temporary file on a long run), or, without a reference, the error of
//! static data; and after the per-channel
//! stages, the sensor-wide terms of that calibration named as findings (time offset, lever
//! arm), corrected for what the per-channel terms had pushed into them.

use std::ops::Range;
use std::path::Path;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde_json::json;

use super::draws::ChannelSimulation;
use super::engine::{ci, DiagnoseError, Finding, Run, LEVER_ARM_MODEL_SIGMA_M};
use super::null::normal_p_value;
use super::signals::RunSignals;
use crate::calibration::Samples;
use crate::calibration::{
    build_signal_bank, CalibrationDesign, CalibrationSummary, DesignRows, ErrorOptions, SignalBank,
    SpilledRecording,
};
use crate::interchange::ImuRecording;
use crate::model::{Cause, Channel};
use crate::series_bank::{block_ranges, BANK_BLOCK_EPOCHS};

/// Epochs a long run's calibration forms at a time: a quarter of the calibration's own
/// default, so that the blocks it holds (about 3 MiB each, one per core) stay below what the
/// later stages hold.
const CALIBRATION_BLOCK_EPOCHS: usize = 1 << 14;

/// The error signals of a run and, with a reference, the calibration that made them.
pub(super) struct Calibrated {
    pub signals: RunSignals,
    pub calibration: Option<(CalibrationSummary, CalibrationDesign)>,
}

/// A recording the diagnosis reads: held whole, or in a spill file (a long interchange file
/// read without being held, [`SpilledRecording::read`]).
// One or two per run: boxing the held one would gain nothing.
#[allow(clippy::large_enum_variant)]
pub enum Recording {
    Held(ImuRecording),
    Spilled(SpilledRecording),
}

impl From<ImuRecording> for Recording {
    fn from(recording: ImuRecording) -> Self {
        Recording::Held(recording)
    }
}

impl Recording {
    fn samples(&self) -> &(dyn Samples + Sync) {
        match self {
            Recording::Held(r) => r,
            Recording::Spilled(r) => r,
        }
    }

    /// Number of samples.
    pub(super) fn len(&self) -> usize {
        self.samples().len()
    }

    /// The time of the first sample, s (0 without samples).
    pub(super) fn first_time_s(&self) -> Result<f64, DiagnoseError> {
        Ok(if self.len() == 0 {
            0.0
        } else {
            self.samples().time_s(0)?
        })
    }

    /// Calls `visit` with every value of channel `ch` (0..6, gx..az) in order, read a block
    /// at a time where spilled; false (nothing visited) where the recording lacks it.
    pub(super) fn for_each_value(
        &self,
        ch: usize,
        mut visit: impl FnMut(f64),
    ) -> Result<bool, DiagnoseError> {
        Ok(match self {
            Recording::Held(r) => match r.channel(Channel::ALL[ch].name()) {
                Some(x) => {
                    x.iter().for_each(|v| visit(*v));
                    true
                }
                None => false,
            },
            Recording::Spilled(r) => r.for_each_channel_value(ch, visit)?,
        })
    }

    /// The recording in a spill file: written there and dropped if held.
    fn spilled(self, name: &str) -> Result<SpilledRecording, DiagnoseError> {
        Ok(match self {
            Recording::Held(r) => SpilledRecording::from_recording(Path::new(name), &r)?,
            Recording::Spilled(r) => r,
        })
    }
}

/// Calibrates `sensor` against `reference` (forming more than `held_epochs` epochs a block
/// at a time); without one, the data are taken as static (a note says so) and the error is
/// each channel minus its mean. On a run of more than `held_epochs` epochs the recordings
/// are in spill files (written there and dropped if held), and the error signals gathered
/// into a temporary file: what is held is a few blocks of epochs.
pub(super) fn calibrate(
    sensor: Recording,
    reference: Option<Recording>,
    held_epochs: usize,
    notes: &mut Vec<String>,
) -> Result<Calibrated, DiagnoseError> {
    let spill = sensor.len() > held_epochs;
    let Some(reference) = reference else {
        notes.push(
            "no reference: static data assumed, the error is each channel minus its mean".into(),
        );
        return Ok(Calibrated {
            signals: RunSignals::new(static_signals(&sensor, spill)?),
            calibration: None,
        });
    };
    let opts = ErrorOptions {
        held_epochs,
        block_epochs: CALIBRATION_BLOCK_EPOCHS,
        ..Default::default()
    };
    let (signals, summary, design) = if spill {
        let sensor = sensor.spilled("the sensor recording")?;
        let reference = reference.spilled("the reference recording")?;
        build_signal_bank(&sensor, &reference, &opts, true)?
    } else {
        build_signal_bank(sensor.samples(), reference.samples(), &opts, false)?
    };
    Ok(Calibrated {
        signals: RunSignals::new(signals),
        calibration: Some((summary, design)),
    })
}

/// What visits a block of a recording's epochs: their range, the rows holding them, and
/// where the first of them is among those rows.
type RowsVisit<'v> =
    dyn FnMut(Range<usize>, &ImuRecording, usize) -> Result<(), DiagnoseError> + 'v;

/// Error signals of static data without a reference: each channel minus its mean, without
/// dynamics. Two passes over the recording a block at a time (the means, then the
/// signals), so a long one is never held.
fn static_signals(sensor: &Recording, spill: bool) -> Result<SignalBank, DiagnoseError> {
    let samples = sensor.samples();
    let n = samples.len();
    let names = Channel::ALL.map(|c| c.name());
    let (first, _) = samples.rows(0..n.min(1))?;
    let present = names.map(|name| first.channel(name).is_some());
    let blocks = |visit: &mut RowsVisit<'_>| {
        for range in block_ranges(0..n) {
            let (rows, first) = samples.rows(range.clone())?;
            visit(range.clone(), &rows, range.start - first)?;
        }
        Ok::<_, DiagnoseError>(())
    };
    let mut sums = [0.0f64; 6];
    blocks(&mut |range, rows, at| {
        for (sum, name) in sums.iter_mut().zip(names) {
            if let Some(x) = rows.channel(name) {
                x[at..at + range.len()].iter().for_each(|v| *sum += v);
            }
        }
        Ok(())
    })?;
    let means = sums.map(|s| s / n as f64);
    let mut bank = SignalBank::static_run(n, present, spill)?;
    let mut e = Vec::with_capacity(BANK_BLOCK_EPOCHS);
    blocks(&mut |range, rows, at| {
        let own = at..at + range.len();
        bank.write_time(range.start, &rows.t_s[own.clone()])?;
        for ch in (0..6).filter(|&ch| present[ch]) {
            let x = rows.channel(names[ch]).expect("present in every block");
            e.clear();
            e.extend(x[own.clone()].iter().map(|v| v - means[ch]));
            bank.write_error(ch, range.start, &e)?;
        }
        Ok(())
    })?;
    Ok(bank)
}

/// The sensor-wide calibration terms: the time offset and lever arm as the extended model
/// carries them, and the findings naming them when significant.
#[derive(Default)]
pub(super) struct SensorWideTerms {
    pub findings: Vec<Finding>,
    pub time_offset_s: Option<f64>,
    pub lever_arm_b_m: Option<[f64; 3]>,
}

/// Standard deviation of each calibration parameter over baseline noise simulated for every
/// channel: the Newey-West sigma alone under-covers when the noise wanders slowly.
fn simulated_calibration_sd(run: &Run, design: DesignRows<'_>) -> Result<Vec<f64>, DiagnoseError> {
    let reps = run.opts.replicates.max(8);
    let thetas: Vec<nalgebra::DVector<f64>> = (0..reps)
        .into_par_iter()
        .map(|r| {
            // A channel at a time: the calibration's moments add over channels.
            let mut moments = nalgebra::DVector::zeros(design.parameters());
            for c in &Channel::ALL {
                let (Some(slot), i) = (run.channels.iter().position(|x| x == c), c.index()) else {
                    continue;
                };
                if design.has_channel(i) {
                    let rng = ChaCha8Rng::seed_from_u64(
                        run.opts.seed ^ 0x5eed_ca1b ^ ((r as u64) << 8) ^ i as u64,
                    );
                    let mut simulation =
                        ChannelSimulation::of_processes(run, run.null_model(slot, r), rng);
                    moments += design.moments_of_blocks(i, &mut |epochs, values| {
                        simulation.next_block(epochs, values)
                    })?;
                }
            }
            Ok(design.bread() * moments)
        })
        .collect::<Result<_, DiagnoseError>>()?;
    Ok(parameter_sd(&thetas, design.parameters()))
}

/// Sample standard deviation of each of the `parameters` components over `vectors`.
fn parameter_sd(vectors: &[nalgebra::DVector<f64>], parameters: usize) -> Vec<f64> {
    let r = vectors.len() as f64;
    (0..parameters)
        .map(|a| {
            let m = vectors.iter().map(|t| t[a]).sum::<f64>() / r;
            (vectors.iter().map(|t| (t[a] - m).powi(2)).sum::<f64>() / (r - 1.0)).sqrt()
        })
        .collect()
}

/// Batch-means standard deviation of each calibration parameter from the measured residual:
/// the parameters' error is the sum over time blocks of what each block's residual pushes
/// into them, and with blocks long against the noise's memory their spread is that error's.
/// A spread no smaller than the measured residual's own: on ship motion with a baseline
/// fitted on 300 s, the simulated spread fell short of the lever arm's scatter.
fn batch_calibration_sd(run: &Run, design: DesignRows<'_>) -> Result<Vec<f64>, DiagnoseError> {
    const BLOCKS: usize = 20;
    let n = design.epochs();
    let edge = |b: usize| b * n / BLOCKS;
    let pushes: Vec<nalgebra::DVector<f64>> = (0..BLOCKS)
        .into_par_iter()
        .map(|b| {
            // What the block's residual alone (zero elsewhere) pushes into the parameters.
            let block = edge(b)..edge(b + 1);
            let mut moments = nalgebra::DVector::zeros(design.parameters());
            for c in &run.channels {
                if design.has_channel(c.index()) && run.signals.epochs() == n {
                    let e = run.signals.error_range(*c, block.clone())?;
                    moments += design.moments_in(c.index(), block.clone(), &e)?;
                }
            }
            Ok(design.bread() * moments)
        })
        .collect::<Result<_, DiagnoseError>>()?;
    // The error is the sum of the blocks' pushes: its variance is BLOCKS times theirs.
    Ok(parameter_sd(&pushes, design.parameters())
        .into_iter()
        .map(|sd| sd * (BLOCKS as f64).sqrt())
        .collect())
}

/// Sensor-wide calibration terms, corrected for what the per-channel terms found had pushed
/// into them (`absorbed`, the sum over channels of [`super::terms::FittedTerms::absorbed_by`]),
/// with 1-sigma no smaller than the spread the calibration shows on baseline noise, nor than
/// the batch-means spread of the measured residual (the lever arm).
pub(super) fn sensor_wide_terms(
    run: &Run,
    absorbed: Option<nalgebra::DVector<f64>>,
) -> Result<SensorWideTerms, DiagnoseError> {
    let mut out = SensorWideTerms::default();
    let (Some(cal), Some(design)) = (run.calibration, run.design) else {
        return Ok(out);
    };
    let shift = absorbed.unwrap_or_else(|| nalgebra::DVector::zeros(design.parameters()));
    let sim_sd = simulated_calibration_sd(run, design)?;
    let batch_sd = batch_calibration_sd(run, design)?;
    // The time offset is the one common to the channels that agree (see
    // `errors::common_time_offset`): a per-channel term does not move it, so it needs no
    // correction here.
    if let Some(t) = cal.time_offset_s {
        let (value, sigma) = (t.value, t.sigma);
        out.time_offset_s = Some(value);
        if sigma > 0.0
            && (value / sigma).abs() > run.z_strict
            && value.abs() > 0.2 * run.dt_s.min(0.01)
        {
            for &channel in &run.channels {
                out.findings.push(Finding {
                    channel,
                    cause: Cause::TimeOffset,
                    regressors: vec![format!("d{channel}/dt")],
                    estimate: json!(value),
                    ci95: json!(ci(value, sigma)),
                    variance_explained: f64::NAN,
                    p_value: Some(run.family_p(normal_p_value(value / sigma))),
                });
            }
        }
    }
    if let (Some(l), Some(li)) = (cal.lever_arm_m, design.lever_index()) {
        let value: [f64; 3] = std::array::from_fn(|i| l.value[i] - shift[li + i]);
        let sigma: [f64; 3] = std::array::from_fn(|i| {
            l.sigma[i]
                .max(sim_sd[li + i])
                .max(batch_sd[li + i])
                .hypot(LEVER_ARM_MODEL_SIGMA_M)
        });
        out.lever_arm_b_m = Some(value);
        let significant = (0..3).any(|i| {
            sigma[i] > 0.0 && (value[i] / sigma[i]).abs() > run.z_strict && value[i].abs() > 0.005
        });
        // The most significant component's p-value, over the three components tested.
        let p = (0..3)
            .filter(|&i| sigma[i] > 0.0)
            .map(|i| normal_p_value(value[i] / sigma[i]))
            .fold(1.0, f64::min);
        if significant {
            for &channel in run.channels.iter().filter(|c| !c.is_gyro()) {
                out.findings.push(Finding {
                    channel,
                    cause: Cause::LeverArm,
                    regressors: vec!["r_x_m".into(), "r_y_m".into(), "r_z_m".into()],
                    estimate: json!(value),
                    ci95: json!([
                        ci(value[0], sigma[0]),
                        ci(value[1], sigma[1]),
                        ci(value[2], sigma[2])
                    ]),
                    variance_explained: f64::NAN,
                    p_value: Some(run.family_p(p)),
                });
            }
        }
    }
    Ok(out)
}
