//! Per-channel error effects: what a sensor adds to the true sensor-frame quantity, resolved
//! from the model file with the effects switched off removed, and the lever-arm / boresight
//! transfer of the reference kinematics to a sensor (the seed paper's eq. 9:
//! f^s = C_b^s (f^b + Omega_dot r + Omega Omega r), omega^s = C_b^s omega^b).

use std::collections::BTreeSet;

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde_json::{json, Value};

use super::trajectory::Truth;
use crate::gmwm::model::{ModelSpec, Process, Structure};
use crate::model::{
    stochastic_in_si, BiasStep, ChannelModel, DynamicDriver, DynamicNoise, Effect, ImuModel,
    Outliers, VibrationLine,
};

/// Where a sensor sits on the platform.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mount {
    /// C_b^s: reference body frame to sensor frame.
    pub c_bs: Matrix3<f64>,
    /// Lever arm from the reference IMU to the sensor, body frame, m.
    pub lever_arm_b_m: Vector3<f64>,
}

impl Mount {
    /// The mount of `imu`, with lever arm and boresight switched off as `disabled` says.
    pub fn of(imu: &ImuModel, disabled: &BTreeSet<Effect>) -> Self {
        let [r, p, y] = imu.boresight_rpy_deg.map(f64::to_radians);
        let c_sb = Rotation3::from_euler_angles(r, p, y).into_inner();
        Mount {
            c_bs: if disabled.contains(&Effect::Boresight) {
                Matrix3::identity()
            } else {
                c_sb.transpose()
            },
            lever_arm_b_m: if disabled.contains(&Effect::LeverArm) {
                Vector3::zeros()
            } else {
                Vector3::from(imu.lever_arm_b_m)
            },
        }
    }
}

/// The kinematics a sensor experiences, in its own frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorKinematics {
    /// Angular rate w.r.t. inertial space, rad/s.
    pub omega_rad_s: Vector3<f64>,
    /// Angular acceleration, rad/s^2.
    pub omega_dot_rad_s2: Vector3<f64>,
    /// Specific force at the sensor's location, m/s^2.
    pub f_m_s2: Vector3<f64>,
    /// Rate of change of that specific force, m/s^3.
    pub f_dot_m_s3: Vector3<f64>,
    /// Ground speed of the platform, m/s.
    pub speed_m_s: f64,
}

impl SensorKinematics {
    /// Channel `i` (gx gy gz ax ay az order) of the ideal output.
    pub fn channel(&self, i: usize) -> f64 {
        if i < 3 {
            self.omega_rad_s[i]
        } else {
            self.f_m_s2[i - 3]
        }
    }
}

/// Transfers the reference kinematics to a sensor at `mount` (rigid body): eq. 9 of the seed
/// paper and its time derivative. The gravity gradient over the lever arm (3e-6 s^-2 per m)
/// is neglected.
pub fn sensor_kinematics(truth: &Truth, mount: &Mount) -> SensorKinematics {
    let w = truth.omega_ib_b_rad_s;
    let wd = truth.omega_dot_ib_b_rad_s2;
    let wdd = truth.omega_ddot_ib_b_rad_s3;
    let r = mount.lever_arm_b_m;
    let w_x_r = w.cross(&r);
    let wd_x_r = wd.cross(&r);
    let f_b = truth.f_b_m_s2 + wd_x_r + w.cross(&w_x_r);
    let f_dot_b = truth.f_dot_b_m_s3 + wdd.cross(&r) + wd.cross(&w_x_r) + w.cross(&wd_x_r);
    SensorKinematics {
        omega_rad_s: mount.c_bs * w,
        omega_dot_rad_s2: mount.c_bs * wd,
        f_m_s2: mount.c_bs * f_b,
        f_dot_m_s3: mount.c_bs * f_dot_b,
        speed_m_s: truth.speed_m_s,
    }
}

/// The effects of one channel that are on, with SI parameters at the sensor's rate.
#[derive(Debug, Clone, Default)]
pub struct ChannelEffects {
    /// Channel index 0..6 (gx gy gz ax ay az).
    pub index: usize,
    pub stochastic: Option<ModelSpec>,
    pub bias: f64,
    pub scale_factor: f64,
    pub cross_axis: [f64; 3],
    pub g_sensitivity: [f64; 3],
    pub angular_acceleration_sensitivity: [f64; 3],
    pub jerk_sensitivity: [f64; 3],
    pub dynamic_noise: Option<DynamicNoise>,
    pub vibration_lines: Vec<VibrationLine>,
    pub outliers: Option<Outliers>,
    pub bias_steps: Vec<BiasStep>,
    pub saturation: Option<f64>,
    pub quantization_step: Option<f64>,
    report: Vec<Value>,
}

/// The stochastic model converted to SI and to `rate_hz`, keeping only the processes whose
/// kind is not disabled. White noise keeps its density (sigma2 scales with the rate), random
/// walk its rate of variance growth (sigma2 scales with 1/rate); quantization noise is per
/// sample; Gauss-Markov and drift are in physical time already.
pub fn stochastic_at_rate(
    spec: &ModelSpec,
    rate_hz: f64,
    disabled: &BTreeSet<Effect>,
) -> Option<ModelSpec> {
    let kept: Vec<Process> = spec
        .processes
        .iter()
        .filter(|p| !disabled.contains(&process_effect(p)))
        .cloned()
        .collect();
    if kept.is_empty() {
        return None;
    }
    let si = stochastic_in_si(&ModelSpec {
        model: Structure {
            kinds: kept.iter().map(Process::kind).collect(),
        }
        .name(),
        processes: kept,
        ..spec.clone()
    })?;
    let ratio = rate_hz / spec.sample_rate_hz;
    let processes = si
        .processes
        .into_iter()
        .map(|p| match p {
            Process::WhiteNoise { sigma2 } => Process::WhiteNoise {
                sigma2: sigma2 * ratio,
            },
            Process::RandomWalk { sigma2 } => Process::RandomWalk {
                sigma2: sigma2 / ratio,
            },
            other => other,
        })
        .collect();
    Some(ModelSpec {
        sample_rate_hz: rate_hz,
        processes,
        ..si
    })
}

/// The effect a stochastic process is.
pub fn process_effect(p: &Process) -> Effect {
    match p {
        Process::WhiteNoise { .. } => Effect::WhiteNoise,
        Process::QuantizationNoise { .. } => Effect::QuantizationNoise,
        Process::RandomWalk { .. } => Effect::RandomWalk,
        Process::Drift { .. } => Effect::Drift,
        Process::GaussMarkov { .. } => Effect::GaussMarkov,
    }
}

impl ChannelEffects {
    /// Resolves channel `index` of a model at `rate_hz`; `disabled` holds the names switched
    /// off for this channel (its own list, its sensor's and the global one).
    pub fn resolve(
        model: &ChannelModel,
        index: usize,
        rate_hz: f64,
        disabled: &BTreeSet<Effect>,
    ) -> Self {
        let mut fx = ChannelEffects {
            index,
            ..Default::default()
        };
        let on = |effect: Effect| !disabled.contains(&effect);
        let mut report = Vec::new();
        let mut note = |effect: Effect, enabled: bool, params: Value| {
            report.push(json!({"effect": effect, "enabled": enabled, "parameters": params}));
        };
        if let Some(spec) = &model.stochastic {
            for p in &spec.processes {
                let effect = process_effect(p);
                let params = serde_json::to_value(ModelSpec {
                    model: p.kind().token().into(),
                    unit: spec.unit.clone(),
                    sample_rate_hz: spec.sample_rate_hz,
                    processes: vec![p.clone()],
                })
                .ok()
                .and_then(|v| v.get("processes").and_then(|p| p.get(0)).cloned())
                .unwrap_or(Value::Null);
                note(
                    effect,
                    on(effect),
                    json!({"unit": spec.unit, "sample_rate_hz": spec.sample_rate_hz, "process": params}),
                );
            }
            fx.stochastic = stochastic_at_rate(spec, rate_hz, disabled);
        }
        macro_rules! scalar {
            ($field:ident, $name:expr, $unit:expr) => {
                if let Some(v) = model.$field {
                    note($name, on($name), json!({"value": v, "unit": $unit}));
                    if on($name) {
                        fx.$field = v;
                    }
                }
            };
        }
        let unit = if index < 3 { "rad/s" } else { "m/s^2" };
        scalar!(bias, Effect::Bias, unit);
        scalar!(scale_factor, Effect::ScaleFactor, "1");
        macro_rules! row {
            ($field:ident, $name:expr, $unit:expr) => {
                if let Some(v) = model.$field {
                    note($name, on($name), json!({"row": v, "unit": $unit}));
                    if on($name) {
                        fx.$field = v;
                    }
                }
            };
        }
        row!(cross_axis, Effect::CrossAxis, "1");
        row!(
            g_sensitivity,
            Effect::GSensitivity,
            format!("{unit} per m/s^2")
        );
        row!(
            angular_acceleration_sensitivity,
            Effect::AngularAccelerationSensitivity,
            format!("{unit} per rad/s^2")
        );
        row!(
            jerk_sensitivity,
            Effect::JerkSensitivity,
            format!("{unit} per m/s^3")
        );
        if let Some(d) = model.dynamic_noise {
            note(
                Effect::DynamicNoise,
                on(Effect::DynamicNoise),
                serde_json::to_value(d).unwrap_or(Value::Null),
            );
            fx.dynamic_noise = on(Effect::DynamicNoise).then_some(d);
        }
        if !model.vibration_lines.is_empty() {
            note(
                Effect::Vibration,
                on(Effect::Vibration),
                serde_json::to_value(&model.vibration_lines).unwrap_or(Value::Null),
            );
            if on(Effect::Vibration) {
                fx.vibration_lines = model.vibration_lines.clone();
            }
        }
        if !model.bias_steps.is_empty() {
            note(
                Effect::BiasStep,
                on(Effect::BiasStep),
                serde_json::to_value(&model.bias_steps).unwrap_or(Value::Null),
            );
            if on(Effect::BiasStep) {
                fx.bias_steps = model.bias_steps.clone();
            }
        }
        if let Some(o) = model.outliers {
            note(
                Effect::Outliers,
                on(Effect::Outliers),
                serde_json::to_value(o).unwrap_or(Value::Null),
            );
            fx.outliers = on(Effect::Outliers).then_some(o);
        }
        if let Some(s) = model.saturation {
            note(
                Effect::Saturation,
                on(Effect::Saturation),
                json!({"limit": s, "unit": unit}),
            );
            fx.saturation = on(Effect::Saturation).then_some(s);
        }
        if let Some(q) = model.quantization_step {
            note(
                Effect::Quantization,
                on(Effect::Quantization),
                json!({"step": q, "unit": unit}),
            );
            fx.quantization_step = on(Effect::Quantization).then_some(q);
        }
        fx.report = report;
        fx
    }

    /// Every effect named in the model with its parameters and whether it was on.
    pub fn report(&self) -> &[Value] {
        &self.report
    }

    /// The deterministic error at one sample: scale factor, cross-axis, bias,
    /// sensitivities and vibration lines (at true time `t_true_s`).
    pub fn deterministic(&self, k: &SensorKinematics, t_true_s: f64) -> f64 {
        let i = self.index;
        let input = if i < 3 { &k.omega_rad_s } else { &k.f_m_s2 };
        let dot = |row: &[f64; 3], v: &Vector3<f64>| row[0] * v[0] + row[1] * v[1] + row[2] * v[2];
        let mut e = self.bias + self.scale_factor * input[i % 3] + dot(&self.cross_axis, input);
        e += dot(&self.g_sensitivity, &k.f_m_s2);
        e += dot(&self.angular_acceleration_sensitivity, &k.omega_dot_rad_s2);
        e += dot(&self.jerk_sensitivity, &k.f_dot_m_s3);
        for b in self.bias_steps.iter().filter(|b| t_true_s >= b.at_s) {
            e += b.size;
        }
        for l in &self.vibration_lines {
            e += l.amplitude
                * (2.0 * std::f64::consts::PI * l.frequency_hz * t_true_s + l.phase_rad).sin();
        }
        e
    }

    /// Standard deviation of the dynamics-dependent noise at one sample.
    pub fn dynamic_sigma(&self, k: &SensorKinematics) -> f64 {
        match self.dynamic_noise {
            None => 0.0,
            Some(d) => {
                let driver = match d.driver {
                    DynamicDriver::AngularRateNorm => k.omega_rad_s.norm(),
                    DynamicDriver::AngularAccelerationNorm => k.omega_dot_rad_s2.norm(),
                    DynamicDriver::Speed => k.speed_m_s,
                    DynamicDriver::JerkNorm => k.f_dot_m_s3.norm(),
                };
                d.sigma_per_unit * driver
            }
        }
    }

    /// Saturation then quantization of the sensor output.
    pub fn finish(&self, y: f64) -> f64 {
        let y = match self.saturation {
            Some(s) => y.clamp(-s, s),
            None => y,
        };
        match self.quantization_step {
            // Dividing by an exact integer 1/q (e.g. 1e4) gives the double nearest n q, which
            // prints as the short decimal the sensor would report.
            Some(q) => {
                let n = (y / q).round();
                let inv = 1.0 / q;
                if (inv.round() - inv).abs() <= 1e-9 * inv {
                    n / inv.round()
                } else {
                    n * q
                }
            }
            None => y,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kin() -> SensorKinematics {
        SensorKinematics {
            omega_rad_s: Vector3::new(0.1, -0.2, 0.3),
            omega_dot_rad_s2: Vector3::new(1.0, 2.0, 3.0),
            f_m_s2: Vector3::new(0.5, 0.0, -9.8),
            f_dot_m_s3: Vector3::new(4.0, 5.0, 6.0),
            speed_m_s: 10.0,
        }
    }

    #[test]
    fn each_deterministic_effect_adds_its_term_and_switches_off() {
        let model = ChannelModel {
            bias: Some(0.01),
            scale_factor: Some(1e-3),
            cross_axis: Some([2e-3, 0.0, 0.0]),
            g_sensitivity: Some([0.0, 0.0, 1e-4]),
            angular_acceleration_sensitivity: Some([0.0, 1e-5, 0.0]),
            jerk_sensitivity: Some([1e-6, 0.0, 0.0]),
            ..Default::default()
        };
        let none = BTreeSet::new();
        let fx = ChannelEffects::resolve(&model, 1, 100.0, &none);
        let k = kin();
        let expected = 0.01 + 1e-3 * -0.2 + 2e-3 * 0.1 + 1e-4 * -9.8 + 1e-5 * 2.0 + 1e-6 * 4.0;
        assert!((fx.deterministic(&k, 0.0) - expected).abs() < 1e-15);
        let off: BTreeSet<Effect> = [Effect::Bias, Effect::GSensitivity].into();
        let fx = ChannelEffects::resolve(&model, 1, 100.0, &off);
        assert!((fx.deterministic(&k, 0.0) - (expected - 0.01 - 1e-4 * -9.8)).abs() < 1e-15);
        let report = fx.report();
        assert_eq!(report.len(), 6);
        assert!(report
            .iter()
            .any(|r| r["effect"] == "bias" && r["enabled"] == false));
    }

    #[test]
    fn saturation_clips_before_quantization_rounds() {
        let model = ChannelModel {
            saturation: Some(1.0),
            quantization_step: Some(0.3),
            ..Default::default()
        };
        let fx = ChannelEffects::resolve(&model, 0, 100.0, &BTreeSet::new());
        assert!((fx.finish(5.0) - 0.9).abs() < 1e-15);
        assert!((fx.finish(-0.44) + 0.3).abs() < 1e-15);
        assert!((fx.finish(0.46) - 0.6).abs() < 1e-15);
    }

    #[test]
    fn stochastic_model_converts_units_and_rate() {
        let spec = ModelSpec {
            model: "WN+RW+GM".into(),
            unit: "deg/s".into(),
            sample_rate_hz: 100.0,
            processes: vec![
                Process::WhiteNoise { sigma2: 1.0 },
                Process::RandomWalk { sigma2: 1.0 },
                Process::GaussMarkov {
                    beta_per_s: 0.5,
                    sigma2: 1.0,
                },
            ],
        };
        let d2 = (std::f64::consts::PI / 180.0).powi(2);
        let s = stochastic_at_rate(&spec, 400.0, &BTreeSet::new()).unwrap();
        assert_eq!(s.processes[0], Process::WhiteNoise { sigma2: 4.0 * d2 });
        assert_eq!(s.processes[1], Process::RandomWalk { sigma2: d2 / 4.0 });
        assert_eq!(
            s.processes[2],
            Process::GaussMarkov {
                beta_per_s: 0.5,
                sigma2: d2
            }
        );
        let off: BTreeSet<Effect> = [Effect::RandomWalk].into();
        let s = stochastic_at_rate(&spec, 100.0, &off).unwrap();
        assert_eq!(s.model, "WN+GM");
        s.validate().unwrap();
    }
}
