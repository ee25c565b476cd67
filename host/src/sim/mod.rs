//! The simulator: car or static trajectories with exact kinematics, a navigation-grade
//! reference IMU, up to three MEMS IMUs with their own mounting, clocks and error effects,
//! a GNSS receiver and a PPS, written in the interchange format with a truth file.
//!
//! Layers: [`trajectory`] (exact kinematics on Taylor [`jet`]s), [`effects`] (lever arm,
//! boresight and per-channel error effects), [`clock`], [`sensors`] (one IMU, in parallel
//! chunks), [`gnss`] (fixes and PPS), [`crate::model`] (the JSON model), [`output`] (files), [`board`] (raw counts for the
//! firmware replay input and the board log).

pub mod board;
pub mod clock;
pub mod effects;
pub mod gnss;
pub mod hidden;
pub mod jet;
pub mod output;
pub mod ros2;
pub mod sensors;
pub mod trajectory;

use std::collections::BTreeSet;

use rayon::prelude::*;
use serde_json::{json, Value};

pub use crate::model::{Effect, ModelFileError, SimModel};
pub use trajectory::{Scenario, Trajectory, Truth};

use gnss::{GnssFixes, PpsTable};
use sensors::{simulate_imu, ImuJob, ImuRun};

/// What to simulate besides the model.
#[derive(Debug, Clone)]
pub struct SimOptions {
    pub scenario: Scenario,
    /// Length of the run, s.
    pub seconds: f64,
    pub seed: u64,
    /// Effects switched off everywhere.
    pub disabled: Vec<Effect>,
    /// Keep the error-free sensor outputs (for `-ideal` files and tests).
    pub keep_ideal: bool,
}

impl SimOptions {
    /// A run of `scenario`, `seconds` long from `seed`, every effect on, no error-free copy.
    pub fn run(scenario: Scenario, seconds: f64, seed: u64) -> Self {
        Self {
            scenario,
            seconds,
            seed,
            disabled: Vec::new(),
            keep_ideal: false,
        }
    }
}

/// Everything a simulation produced.
#[derive(Debug, Clone)]
pub struct SimOutput {
    pub trajectory: Trajectory,
    pub reference: ImuRun,
    pub imus: Vec<ImuRun>,
    pub gnss: Option<GnssFixes>,
    pub pps: Option<PpsTable>,
    /// The truth file: options, realised trajectory script, every effect and parameter.
    pub truth: Value,
}

/// Errors of [`simulate`] before any work is done.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    #[error("--seconds {0} must be positive and finite")]
    BadDuration(f64),
}

/// Runs a simulation. `progress(done_samples)` is called as IMU samples are finished; the
/// total is [`total_samples`].
pub fn simulate(
    model: &SimModel,
    opts: &SimOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<SimOutput, SimError> {
    if !(opts.seconds.is_finite() && opts.seconds > 0.0) {
        return Err(SimError::BadDuration(opts.seconds));
    }
    let disabled: BTreeSet<Effect> = opts.disabled.iter().copied().collect();
    // The truth must exist wherever a sensor samples: allow for time offsets and clocks.
    let margin = model
        .imus
        .iter()
        .map(|m| {
            m.time_offset_s.abs()
                + opts.seconds * (m.clock.frequency_offset_ppm.abs() * 1e-6 + 1e-3)
                + 10.0 * m.clock.jitter_s
        })
        .fold(1.0, f64::max);
    let trajectory = Trajectory::new(
        opts.scenario,
        model.trajectory.clone(),
        opts.seconds,
        opts.seconds + margin,
        opts.seed,
    );

    let sensors: Vec<(&crate::model::ImuModel, u64)> = std::iter::once((&model.reference, 0))
        .chain(model.imus.iter().zip(1..))
        .collect();
    let mut runs: Vec<ImuRun> = sensors
        .par_iter()
        .map(|&(m, index)| {
            let job = ImuJob {
                model: m,
                sensor: index,
                duration_s: opts.seconds,
                seed: opts.seed,
                disabled: &disabled,
                with_navigation: index == 0,
                keep_ideal: opts.keep_ideal,
            };
            simulate_imu(&trajectory, &job, progress)
        })
        .collect();
    let imus = runs.split_off(1);
    let reference = runs.pop().expect("the reference run is always present");
    let gnss = model
        .gnss
        .as_ref()
        .map(|g| gnss::simulate_gnss(&trajectory, g, opts.seconds, opts.seed, &disabled));
    let pps = model
        .pps
        .as_ref()
        .map(|p| gnss::simulate_pps(p, &imus, opts.seconds, opts.seed, &disabled));
    let truth = truth_json(model, opts, &trajectory, &reference, &imus);
    Ok(SimOutput {
        trajectory,
        reference,
        imus,
        gnss,
        pps,
        truth,
    })
}

/// Number of IMU samples a run produces (for a progress bar).
pub fn total_samples(model: &SimModel, seconds: f64) -> u64 {
    std::iter::once(&model.reference)
        .chain(&model.imus)
        .map(|m| (seconds * m.rate_hz).floor().max(1.0) as u64)
        .sum()
}

fn truth_json(
    model: &SimModel,
    opts: &SimOptions,
    traj: &Trajectory,
    reference: &ImuRun,
    imus: &[ImuRun],
) -> Value {
    let sensor = |run: &ImuRun, m: &crate::model::ImuModel| {
        let channels: serde_json::Map<String, Value> = run
            .channels
            .iter()
            .map(|fx| {
                (
                    crate::interchange::CHANNELS[fx.index].to_string(),
                    Value::Array(fx.report().to_vec()),
                )
            })
            .collect();
        let on = |effect: Effect| !run.disabled.contains(&effect);
        let c = m.clock;
        json!({
            "name": run.name,
            "rate_hz": m.rate_hz,
            "samples": run.recording.len(),
            "time_column": if run.name == reference.name { "GPS time" } else { "the IMU's own clock (see pps.csv)" },
            "sensor_effects": [
                {"effect": "lever_arm", "enabled": on(Effect::LeverArm), "parameters": {"lever_arm_b_m": m.lever_arm_b_m}},
                {"effect": "boresight", "enabled": on(Effect::Boresight), "parameters": {"boresight_rpy_deg": m.boresight_rpy_deg, "c_bs_row_major": run.mount.c_bs.transpose().as_slice()}},
                {"effect": "time_offset", "enabled": on(Effect::TimeOffset), "parameters": {"time_offset_s": m.time_offset_s, "meaning": "the sample stamped t was taken at true time t - time_offset_s"}},
                {"effect": "clock_drift", "enabled": on(Effect::ClockDrift), "parameters": {"frequency_offset_ppm": c.frequency_offset_ppm, "frequency_random_walk_ppm_per_sqrt_s": c.frequency_random_walk_ppm_per_sqrt_s, "last_tick_true_t_s": run.clock.tick_t_s.last()}},
                {"effect": "clock_jitter", "enabled": on(Effect::ClockJitter), "parameters": {"jitter_s": c.jitter_s}},
            ],
            "channels": channels,
        })
    };
    json!({
        "generator": {"program": "dynacal simulate", "version": env!("CARGO_PKG_VERSION")},
        "scenario": opts.scenario,
        "seconds": opts.seconds,
        "seed": opts.seed,
        "disabled_globally": opts.disabled,
        "frames": "body = reference IMU, forward-right-down; navigation = NED; angular rates w.r.t. inertial space",
        "trajectory": {
            "config": model.trajectory,
            "segments": traj.segments,
            "hills_grade_rad_wavelength_m_phase_rad": traj.hills(),
            "vibration_lines": {
                "vertical_m": traj.vibration_lines()[0].iter().map(|(l, p)| json!({"line": l, "phase_rad": p})).collect::<Vec<_>>(),
                "roll_rad": traj.vibration_lines()[1].iter().map(|(l, p)| json!({"line": l, "phase_rad": p})).collect::<Vec<_>>(),
                "pitch_rad": traj.vibration_lines()[2].iter().map(|(l, p)| json!({"line": l, "phase_rad": p})).collect::<Vec<_>>(),
            },
        },
        "reference": sensor(reference, &model.reference),
        "imus": imus.iter().zip(&model.imus).map(|(r, m)| sensor(r, m)).collect::<Vec<_>>(),
        "gnss": model.gnss,
        "pps": model.pps,
        "model": model,
    })
}
