//! The extended model: the baseline with everything the diagnosis found, as a simulator model
//! (`dynacal simulate --model`) of one MEMS IMU named `diagnosed`. Per channel, the
//! deterministic terms go where the simulator applies them (scale factor, cross-axis row,
//! sensitivities, bias steps), the stochastic effects beside them and the refitted stochastic
//! model in place of the baseline's; the sensor's calibration (boresight, lever arm, time
//! offset) goes on the IMU. Sections the diagnosis does not estimate (trajectory, reference,
//! GNSS, PPS) are the simulator's defaults.

use std::collections::BTreeMap;

use super::calibration::SensorWideTerms;
use super::generalise::{keeps_noise_model, kept_effects, Component};
use super::stochastic::StochasticFindings;
use super::terms::FittedTerms;
use crate::calibration::CalibrationSummary;
use crate::gmwm::model::ModelSpec;
use crate::model::{BiasStep, Cause, Channel, ChannelModel, ImuModel, SimModel};

/// The extended model of one channel: the `baseline` with the found effects that generalise
/// (`kept`, [`super::generalise`]) and the bias; the quantization step, a property of the
/// raw output the misfit of the error cannot score, whenever it was found.
pub(super) fn channel_model(
    terms: &FittedTerms,
    stochastic: &StochasticFindings,
    kept: &[Component],
    baseline: &ModelSpec,
) -> ChannelModel {
    let mut model = ChannelModel {
        stochastic: Some(if keeps_noise_model(kept) {
            stochastic.stochastic.clone()
        } else {
            baseline.clone()
        }),
        bias: Some(terms.intercept),
        quantization_step: stochastic.effects.quantization_step,
        ..kept_effects(stochastic, kept)
    };
    for (c, t) in terms.coefficients.iter().zip(&terms.terms) {
        if !kept.contains(&Component::Terms(t.cause)) {
            continue;
        }
        let row = match t.cause {
            Cause::ScaleFactor => {
                model.scale_factor = Some(c.value);
                continue;
            }
            Cause::BiasShift => {
                model.bias_steps = terms
                    .step_at_s
                    .map(|at_s| BiasStep {
                        at_s,
                        size: c.value,
                    })
                    .into_iter()
                    .collect();
                continue;
            }
            Cause::CrossAxis => &mut model.cross_axis,
            Cause::GSensitivity => &mut model.g_sensitivity,
            Cause::AngularAcceleration => &mut model.angular_acceleration_sensitivity,
            Cause::Jerk => &mut model.jerk_sensitivity,
            other => unreachable!("{other} is not a per-channel term"),
        };
        row.get_or_insert([0.0; 3])[t.axis] = c.value;
    }
    model
}

/// The extended model of the sensor: its channels' models, sampled at `rate_hz`, mounted as
/// the calibration found (nothing without one).
pub(super) fn extended_model(
    rate_hz: f64,
    channels: BTreeMap<Channel, ChannelModel>,
    calibration: Option<&CalibrationSummary>,
    sensor_wide: &SensorWideTerms,
) -> SimModel {
    let deg = 180.0 / std::f64::consts::PI;
    let mut imu = ImuModel {
        channels,
        ..ImuModel::bare("diagnosed", crate::interchange::shortest_rate_hz(rate_hz))
    };
    if let Some(cal) = calibration {
        if let Some(l) = sensor_wide.lever_arm_b_m {
            imu.lever_arm_b_m = l;
        }
        if let Some(t) = sensor_wide.time_offset_s {
            imu.time_offset_s = t;
        }
        let b = cal.boresight_rad.value;
        imu.boresight_rpy_deg = [b[0] * deg, b[1] * deg, b[2] * deg];
    }
    SimModel {
        comment: Some("extended model written by dynacal diagnose".into()),
        imus: vec![imu],
        ..SimModel::default()
    }
}
