//! Simulations of a channel's error drawn a block at a time: the stochastic processes of a
//! model plus the stochastic effects the engine found (a noise that grows with the angular
//! rate, vibration lines, outliers), over the run's epochs in the blocks
//! [`crate::series_bank::block_ranges`] cuts them into. Every statistic of a simulation reads
//! it block by block, so no simulation of a long run is held; the blocks are the same whether
//! a run is held or long, so a simulation is the same draw either way.

use std::ops::Range;

use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::engine::{DiagnoseError, Run};
use crate::gmwm::model::{ModelSimulation, ModelSpec};
use crate::model::{Channel, ChannelModel, Outliers, VibrationLine};
use crate::series_bank::block_ranges;
use crate::sim::effects::{ChannelEffects, SensorKinematics};

/// What reads a simulation's blocks: the block's epochs and its values (to add to).
pub(super) type DrawnBlockVisit<'v> =
    dyn FnMut(Range<usize>, &mut [f64]) -> Result<(), DiagnoseError> + 'v;

/// One simulation of a channel's stochastic error, drawn a block at a time. Its draws come
/// in this order: a uniform phase per vibration line (the phase of a found line is not
/// estimated), then per block the processes (one after the other, as
/// [`ModelSimulation`] draws them), one normal per epoch for the noise that grows with the
/// dynamics, and per epoch an outlier draw. (The simulator draws its per-sample effects
/// inline, sample by sample, in `sim::sensors`; the engine keeps its own order, which its
/// seeded results depend on.)
pub(super) struct ChannelSimulation<'a> {
    run: &'a Run<'a>,
    processes: ModelSimulation<'a>,
    /// The noise that grows with the angular rate, resolved alone.
    growth: Option<ChannelEffects>,
    /// The vibration lines with their drawn phases, resolved alone.
    vibration: Option<ChannelEffects>,
    outliers: Option<Outliers>,
    rng: ChaCha8Rng,
    /// The first epoch simulated (the lines' time zero) and the next one expected.
    first_epoch: Option<usize>,
    next_epoch: Option<usize>,
}

impl<'a> ChannelSimulation<'a> {
    /// A simulation of `spec`'s processes and the stochastic `effects` on `channel` of
    /// `run`, drawn from `rng`. Each effect's level and waveform are the simulator's
    /// ([`ChannelEffects::dynamic_sigma`], [`ChannelEffects::deterministic`]).
    pub fn new(
        run: &'a Run<'a>,
        spec: &'a ModelSpec,
        effects: &ChannelModel,
        channel: Channel,
        mut rng: ChaCha8Rng,
    ) -> Self {
        let no_switches = std::collections::BTreeSet::new();
        let rate_hz = 1.0 / run.dt_s;
        let resolve = |model: &ChannelModel| {
            ChannelEffects::resolve(model, channel.index(), rate_hz, &no_switches)
        };
        let growth = effects.dynamic_noise.is_some().then(|| {
            resolve(&ChannelModel {
                dynamic_noise: effects.dynamic_noise,
                ..Default::default()
            })
        });
        let vibration = (!effects.vibration_lines.is_empty()).then(|| {
            let lines: Vec<VibrationLine> = effects
                .vibration_lines
                .iter()
                .map(|line| VibrationLine {
                    phase_rad: rand::Rng::random_range(&mut rng, 0.0..std::f64::consts::TAU),
                    ..*line
                })
                .collect();
            resolve(&ChannelModel {
                vibration_lines: lines,
                ..Default::default()
            })
        });
        Self {
            run,
            processes: ModelSimulation::new(spec),
            growth,
            vibration,
            outliers: effects.outliers,
            rng,
            first_epoch: None,
            next_epoch: None,
        }
    }

    /// A simulation of `spec`'s processes alone: a baseline simulation (the channel enters
    /// only the effects, of which there are none).
    pub fn of_processes(run: &'a Run<'a>, spec: &'a ModelSpec, rng: ChaCha8Rng) -> Self {
        Self::new(run, spec, &ChannelModel::default(), Channel::Gx, rng)
    }

    /// Appends the simulation over `epochs` to `x`: the block of [`block_ranges`] that
    /// follows the last one drawn, so that a simulation cut the same way is the same draw.
    pub fn next_block(
        &mut self,
        epochs: Range<usize>,
        x: &mut Vec<f64>,
    ) -> Result<(), DiagnoseError> {
        let first = *self.first_epoch.get_or_insert(epochs.start);
        if let Some(expected) = self.next_epoch {
            debug_assert_eq!(epochs.start, expected, "blocks drawn in order");
        }
        self.next_epoch = Some(epochs.end);
        let start = x.len();
        x.resize(start + epochs.len(), 0.0);
        let x = &mut x[start..];
        self.processes.add_next(x, &mut self.rng);
        if let Some(growth) = &self.growth {
            let omega: Vec<_> = (0..3)
                .map(|axis| self.run.signals.angular_rate_rad_s(axis, epochs.clone()))
                .collect::<Result<_, _>>()?;
            for (k, v) in x.iter_mut().enumerate() {
                let z: f64 = StandardNormal.sample(&mut self.rng);
                let omega_rad_s = Vector3::new(omega[0][k], omega[1][k], omega[2][k]);
                *v += growth.dynamic_sigma(&rotating_at(omega_rad_s)) * z;
            }
        }
        if let Some(vibration) = &self.vibration {
            // The lines are the only deterministic effect resolved here: the kinematics do
            // not enter them.
            let at_rest = rotating_at(Vector3::zeros());
            for (epoch, v) in epochs.clone().zip(x.iter_mut()) {
                *v += vibration.deterministic(&at_rest, (epoch - first) as f64 * self.run.dt_s);
            }
        }
        if let Some(o) = self.outliers {
            for v in x.iter_mut() {
                if rand::Rng::random_bool(&mut self.rng, o.probability.clamp(0.0, 1.0)) {
                    let z: f64 = StandardNormal.sample(&mut self.rng);
                    *v += o.sigma * z;
                }
            }
        }
        Ok(())
    }

    /// `visit(block epochs, block)` for each block of `epochs` in order.
    pub fn for_each_block(
        mut self,
        epochs: Range<usize>,
        visit: &mut DrawnBlockVisit<'_>,
    ) -> Result<(), DiagnoseError> {
        let mut x = Vec::new();
        for block in block_ranges(epochs) {
            x.clear();
            self.next_block(block.clone(), &mut x)?;
            visit(block, &mut x)?;
        }
        Ok(())
    }
}

/// The kinematics the engine knows at an epoch for the simulator's effects: the measured
/// angular rate (`omega_rad_s`, body axes, rad/s); the rest is not measured here and zero.
fn rotating_at(omega_rad_s: Vector3<f64>) -> SensorKinematics {
    SensorKinematics {
        omega_rad_s,
        omega_dot_rad_s2: Vector3::zeros(),
        f_m_s2: Vector3::zeros(),
        f_dot_m_s3: Vector3::zeros(),
        speed_m_s: 0.0,
    }
}
