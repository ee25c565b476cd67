//! A fitted model in the units and conventions of the tools its users feed noise parameters
//! into (`dynacal export MODEL --to FORMAT`): Kalibr's `imu.yaml` (read by Kalibr, OpenVINS
//! and VINS-Mono), PX4 EKF2 and ArduPilot EKF3 parameter files. Each target holds one white
//! noise and one bias random walk per sensor, so every fitted channel is first reduced to
//! what a filter runs ([`crate::refit::channel_noise`], the same reduction the board's model
//! gets): white noise and quantization noise as a white-noise PSD, a Gauss-Markov bias of a
//! second or longer by its driving PSD `2 sigma^2 / tau` as a random walk (the same
//! short-term wander, unbounded beyond `tau`: said in the file), faster Gauss-Markov terms
//! into the white noise, a drift left out (said). The three axes of a sensor give one value:
//! the root of their mean PSD, each axis's listed in a comment. Conversions, in SI:
//! - Kalibr: noise density `N = sqrt(PSD_white)` (unit/s^0.5 = unit/sqrt(Hz)), random walk
//!   `K = sqrt(PSD_walk)` (unit/s/sqrt(Hz));
//! - PX4 (`EKF2_GYR_NOISE`, ...) and ArduPilot (`EK3_GYRO_P_NSE`, ...): both add
//!   `(dt sigma)^2` of angle or velocity per prediction step of `dt` and `(dt p)^2` of bias
//!   (EKF3 keeps its biases as increments: `(dt^2 p)^2`, the same `p`), so
//!   `sigma = N / sqrt(dt)` and `p = K / sqrt(dt)`, with EKF2's `dt` = `EKF2_PREDICT_US`
//!   (10 ms by default) and EKF3's its 12 ms target step (`EKF_TARGET_DT`).
//!
//! With a static model beside (`--static`), the file carries the static values in comments
//! and the measured inflation factor of each value (dynamic over static), which users of
//! these tools otherwise guess ("multiply by 10 to 20").

use std::fmt::Write as _;
use std::path::Path;

use dynacal_core::board_model::BoardModel;
use dynacal_core::Channel;

use crate::model::{stochastic_in_si, ImuModel, SimModel};
use crate::refit::channel_noise;

/// What a target tool takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Kalibr `imu.yaml` (Kalibr, OpenVINS, VINS-Mono).
    Kalibr,
    /// PX4 EKF2 parameters (QGroundControl's `.params` file).
    Px4,
    /// ArduPilot EKF3 parameters (a `.parm` file Mission Planner and MAVProxy load).
    Ardupilot,
}

/// EKF2's default prediction interval (`EKF2_PREDICT_US` = 10 000 us), s.
pub const PX4_PREDICT_S: f64 = 0.010;
/// EKF3's target prediction step (`EKF_TARGET_DT`), s.
pub const ARDUPILOT_PREDICT_S: f64 = 0.012;

/// Why a model cannot be exported.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExportError {
    #[error("{path}: the model holds IMUs {names}: name one with --imu")]
    WhichImu { path: String, names: String },
    #[error("{path}: no IMU named `{name}` (it holds {names})")]
    NoImu {
        path: String,
        name: String,
        names: String,
    },
    #[error("{path}: IMU `{imu}` has no stochastic model on {channel}: nothing to export")]
    NoModel {
        path: String,
        imu: String,
        channel: Channel,
    },
    #[error("{path}: {message}")]
    Board { path: String, message: String },
}

/// One sensor's (three axes') noise as the targets hold it, SI.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorNoise {
    /// White-noise density, unit/sqrt(Hz) (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)).
    pub noise_density: f64,
    /// Bias random-walk density, unit/s/sqrt(Hz).
    pub random_walk: f64,
    /// Each axis's (noise density, random walk).
    pub axes: [(f64, f64); 3],
    /// What was approximated or left out, per axis.
    pub approximations: Vec<String>,
}

/// The gyro and accelerometer noise of one IMU of a model.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuNoise {
    pub imu: String,
    /// The ROS topic Kalibr's `rostopic` names; `/imu0` when None.
    pub rostopic: Option<String>,
    pub rate_hz: f64,
    pub gyro: SensorNoise,
    pub accel: SensorNoise,
}

/// The IMU `name` of `model` (the only one when None), read from `path`.
pub fn imu_noise(
    model: &SimModel,
    name: Option<&str>,
    path: &Path,
) -> Result<ImuNoise, ExportError> {
    let names = model
        .imus
        .iter()
        .map(|i| i.name.as_str())
        .collect::<Vec<_>>()
        .join(", ");
    let p = path.display().to_string();
    let imu = match name {
        Some(n) => model
            .imus
            .iter()
            .find(|i| i.name == n)
            .ok_or(ExportError::NoImu {
                path: p.clone(),
                name: n.to_string(),
                names: names.clone(),
            })?,
        None if model.imus.len() == 1 => &model.imus[0],
        None => return Err(ExportError::WhichImu { path: p, names }),
    };
    Ok(ImuNoise {
        imu: imu.name.clone(),
        rostopic: None,
        rate_hz: imu.rate_hz,
        gyro: sensor_noise(imu, [Channel::Gx, Channel::Gy, Channel::Gz], &p)?,
        accel: sensor_noise(imu, [Channel::Ax, Channel::Ay, Channel::Az], &p)?,
    })
}

fn sensor_noise(
    imu: &ImuModel,
    channels: [Channel; 3],
    path: &str,
) -> Result<SensorNoise, ExportError> {
    let mut axes = [(0.0, 0.0); 3];
    let mut approximations = Vec::new();
    let (mut white_sum, mut walk_sum) = (0.0, 0.0);
    for (axis, channel) in axes.iter_mut().zip(channels) {
        let spec = imu
            .model_of(channel)
            .stochastic
            .as_ref()
            .and_then(stochastic_in_si)
            .ok_or(ExportError::NoModel {
                path: path.to_string(),
                imu: imu.name.clone(),
                channel,
            })?;
        let (noise, left_out) = channel_noise(&spec);
        let white = f64::from(noise.white_psd);
        let mut walk = f64::from(noise.random_walk_psd);
        if noise.gauss_markov_sigma2 > 0.0 && noise.gauss_markov_tau_s > 0.0 {
            let (sigma2, tau) = (
                f64::from(noise.gauss_markov_sigma2),
                f64::from(noise.gauss_markov_tau_s),
            );
            walk += 2.0 * sigma2 / tau;
            approximations.push(format!(
                "{channel}: Gauss-Markov bias (tau {tau:.3} s, sigma {:.3e}) given as a random walk of its driving noise: the same wander over seconds, unbounded beyond tau",
                sigma2.sqrt()
            ));
        }
        for what in left_out {
            approximations.push(format!(
                "{channel}: the fitted {what} has no slot and is left out"
            ));
        }
        *axis = (white.sqrt(), walk.sqrt());
        white_sum += white;
        walk_sum += walk;
    }
    Ok(SensorNoise {
        noise_density: (white_sum / 3.0).sqrt(),
        random_walk: (walk_sum / 3.0).sqrt(),
        axes,
        approximations,
    })
}

/// One exported value: its name in the target, its value, its unit, and how it was formed.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    pub name: &'static str,
    pub value: f64,
    pub unit: &'static str,
}

/// The target's four values from an IMU's noise.
pub fn entries(noise: &ImuNoise, format: Format) -> Vec<Entry> {
    let (g, a) = (&noise.gyro, &noise.accel);
    let per_step = |x: f64, dt: f64| x / dt.sqrt();
    match format {
        Format::Kalibr => vec![
            Entry {
                name: "accelerometer_noise_density",
                value: a.noise_density,
                unit: "m/s^2/sqrt(Hz)",
            },
            Entry {
                name: "accelerometer_random_walk",
                value: a.random_walk,
                unit: "m/s^3/sqrt(Hz)",
            },
            Entry {
                name: "gyroscope_noise_density",
                value: g.noise_density,
                unit: "rad/s/sqrt(Hz)",
            },
            Entry {
                name: "gyroscope_random_walk",
                value: g.random_walk,
                unit: "rad/s^2/sqrt(Hz)",
            },
        ],
        Format::Px4 => vec![
            Entry {
                name: "EKF2_GYR_NOISE",
                value: per_step(g.noise_density, PX4_PREDICT_S),
                unit: "rad/s",
            },
            Entry {
                name: "EKF2_ACC_NOISE",
                value: per_step(a.noise_density, PX4_PREDICT_S),
                unit: "m/s^2",
            },
            Entry {
                name: "EKF2_GYR_B_NOISE",
                value: per_step(g.random_walk, PX4_PREDICT_S),
                unit: "rad/s^2",
            },
            Entry {
                name: "EKF2_ACC_B_NOISE",
                value: per_step(a.random_walk, PX4_PREDICT_S),
                unit: "m/s^3",
            },
        ],
        Format::Ardupilot => vec![
            Entry {
                name: "EK3_GYRO_P_NSE",
                value: per_step(g.noise_density, ARDUPILOT_PREDICT_S),
                unit: "rad/s",
            },
            Entry {
                name: "EK3_ACC_P_NSE",
                value: per_step(a.noise_density, ARDUPILOT_PREDICT_S),
                unit: "m/s^2",
            },
            Entry {
                name: "EK3_GBIAS_P_NSE",
                value: per_step(g.random_walk, ARDUPILOT_PREDICT_S),
                unit: "rad/s^2",
            },
            Entry {
                name: "EK3_ABIAS_P_NSE",
                value: per_step(a.random_walk, ARDUPILOT_PREDICT_S),
                unit: "m/s^3",
            },
        ],
    }
}

/// The range a target clamps a value to (PX4 constrains to [0, 1]; EKF3's bias noises to
/// [1e-7, 1e-5] and [1e-5, 1e-3]), where a value outside runs as the bound.
fn target_range(name: &str) -> Option<(f64, f64)> {
    match name {
        "EKF2_GYR_NOISE" | "EKF2_ACC_NOISE" | "EKF2_GYR_B_NOISE" | "EKF2_ACC_B_NOISE" => {
            Some((0.0, 1.0))
        }
        "EK3_GBIAS_P_NSE" => Some((1e-7, 1e-5)),
        "EK3_ABIAS_P_NSE" => Some((1e-5, 1e-3)),
        _ => None,
    }
}

/// The file the target reads: its values from `dynamic` (the model measured under motion,
/// or the only one), with `static_noise`'s values and the inflation factors in comments.
pub fn render(
    dynamic: &ImuNoise,
    static_noise: Option<&ImuNoise>,
    format: Format,
    source: &str,
) -> String {
    // Every target's comments start with `#`.
    let comment = "#";
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{comment} IMU `{}` of {source}, exported by dynacal (docs/formats.md, section 5)",
        dynamic.imu
    );
    let statics = static_noise.map(|s| entries(s, format));
    for (sensor, n) in [("gyro", &dynamic.gyro), ("accel", &dynamic.accel)] {
        for (axis, (density, walk)) in ["x", "y", "z"].iter().zip(n.axes) {
            let _ = writeln!(out, "{comment} {sensor} {axis}: noise density {density:.4e}, random walk {walk:.4e} (SI, per sqrt(Hz))");
        }
        for a in &n.approximations {
            let _ = writeln!(out, "{comment} {a}");
        }
    }
    let dynamic_entries = entries(dynamic, format);
    for (i, e) in dynamic_entries.iter().enumerate() {
        if let Some(s) = statics.as_ref().map(|s| &s[i]) {
            let factor = if s.value > 0.0 {
                e.value / s.value
            } else {
                f64::INFINITY
            };
            let _ = writeln!(out, "{comment} {}: static {:.4e} {}, measured under motion {:.4e}: inflation x{factor:.2}", e.name, s.value, e.unit, e.value);
        }
        if let Some((low, high)) = target_range(e.name) {
            if e.value < low || e.value > high {
                let _ = writeln!(out, "{comment} {} = {:.4e} is outside [{low:e}, {high:e}]: the filter runs the bound", e.name, e.value);
            }
        }
    }
    match format {
        Format::Kalibr => {
            for e in &dynamic_entries {
                let _ = writeln!(out, "{}: {:.6e}  # [{}]", e.name, e.value, e.unit);
            }
            let topic = dynamic.rostopic.as_deref().unwrap_or("/imu0");
            let _ = writeln!(out, "rostopic: {topic}");
            let _ = writeln!(out, "update_rate: {:.1}  # [Hz]", dynamic.rate_hz);
        }
        Format::Px4 => {
            let _ = writeln!(out, "# Vehicle-Id Component-Id Name Value Type (QGroundControl); type 9 is a 32-bit float");
            for e in &dynamic_entries {
                let _ = writeln!(out, "1\t1\t{}\t{:.6e}\t9", e.name, e.value);
            }
        }
        Format::Ardupilot => {
            for e in &dynamic_entries {
                let _ = writeln!(out, "{},{:.6e}", e.name, e.value);
            }
        }
    }
    out
}

/// A model file's IMUs as the board's model blob (`board-model.bin`, what `dynacal board
/// --model` runs and the real board is flashed with): each IMU in order as unit 0, 1, ...,
/// each channel's stochastic model reduced as the refit reduces it
/// ([`crate::refit::channel_noise`]), each unit's mount relative to the first IMU (the
/// board's body frame): its rotation `C_k C_0^T` from the models' boresights and its lever
/// arm `C_0 (l_k - l_0)` in the first unit's axes. A channel without a stochastic model
/// keeps the board's built-in noise, and what was left out is said in the notes.
pub fn board_model_of(
    model: &SimModel,
    path: &Path,
) -> Result<(BoardModel, Vec<String>), ExportError> {
    if model.imus.is_empty() || model.imus.len() > dynacal_core::log::MAX_IMUS {
        return Err(ExportError::Board {
            path: path.display().to_string(),
            message: format!(
                "{} IMUs: the board runs 1 to {}",
                model.imus.len(),
                dynacal_core::log::MAX_IMUS
            ),
        });
    }
    let ids: Vec<u8> = (0..model.imus.len() as u8).collect();
    let mut board = BoardModel::built_in(&ids);
    let mut notes = Vec::new();
    let mount = |rpy_deg: [f64; 3]| {
        // The model's boresight angles are those of the unit's axes to the body's (C^T).
        nalgebra::Rotation3::from_euler_angles(
            rpy_deg[0].to_radians(),
            rpy_deg[1].to_radians(),
            rpy_deg[2].to_radians(),
        )
        .transpose()
    };
    let first = &model.imus[0];
    let c0 = mount(first.boresight_rpy_deg);
    let l0 = nalgebra::Vector3::from(first.lever_arm_b_m);
    for (imu, unit) in model.imus.iter().zip(board.units.iter_mut()) {
        for channel in Channel::ALL {
            match &imu.model_of(channel).stochastic {
                Some(spec) => {
                    let (noise, left_out) = channel_noise(spec);
                    for what in left_out {
                        notes.push(format!(
                            "{}/{channel}: the {what} is not run on the board",
                            imu.name
                        ));
                    }
                    unit.channels[channel.index()] = noise;
                }
                None => notes.push(format!(
                    "{}/{channel}: no stochastic model; the board keeps its built-in noise",
                    imu.name
                )),
            }
        }
        let relative = mount(imu.boresight_rpy_deg) * c0.transpose();
        let (r, p, y) = relative.euler_angles();
        unit.rotation_rpy_rad = [r as f32, p as f32, y as f32];
        let arm = c0 * (nalgebra::Vector3::from(imu.lever_arm_b_m) - l0);
        unit.lever_arm_m = [arm.x as f32, arm.y as f32, arm.z as f32];
    }
    Ok((board, notes))
}

/// The board model blob's bytes.
pub fn board_blob(board: &BoardModel, path: &Path) -> Result<Vec<u8>, ExportError> {
    let mut blob = [0u8; dynacal_core::board_model::MAX_BOARD_MODEL_LEN];
    let len = board.encode(&mut blob).map_err(|e| ExportError::Board {
        path: path.display().to_string(),
        message: format!("the board refuses this model: {e:?}"),
    })?;
    Ok(blob[..len].to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gmwm::model::Process;

    #[test]
    fn a_model_file_becomes_the_boards_blob_relative_to_its_first_imu() {
        // GIVEN two IMUs at 200 Hz: gyro WN 1e-5 (rad/s)^2 per sample + GM(0.1/s, 4e-6),
        // accel WN 1e-3 (m/s^2)^2; the first mounted at (0.1, 0, 0) m, the second 5 cm to
        // its right and 10 deg off in yaw.
        let spec = |unit: &str, processes| crate::gmwm::model::ModelSpec {
            model: String::new(),
            unit: unit.into(),
            sample_rate_hz: 200.0,
            processes,
        };
        let mut model = SimModel::default();
        for (k, (arm, yaw)) in [([0.1, 0.0, 0.0], 0.0), ([0.1, 0.05, 0.0], 10.0)]
            .into_iter()
            .enumerate()
        {
            let mut imu = ImuModel::bare(&format!("u{k}"), 200.0);
            imu.gyro.stochastic = Some(spec(
                "rad/s",
                vec![
                    Process::WhiteNoise { sigma2: 1e-5 },
                    Process::GaussMarkov {
                        beta_per_s: 0.1,
                        sigma2: 4e-6,
                    },
                ],
            ));
            imu.accel.stochastic = Some(spec("m/s^2", vec![Process::WhiteNoise { sigma2: 1e-3 }]));
            imu.lever_arm_b_m = arm;
            imu.boresight_rpy_deg = [0.0, 0.0, yaw];
            model.imus.push(imu);
        }
        // WHEN it is exported to the board and the blob read back as the board reads it
        let (board, notes) = board_model_of(&model, Path::new("m.json")).unwrap();
        let blob = board_blob(&board, Path::new("m.json")).unwrap();
        let read = BoardModel::decode(&blob).unwrap();
        // THEN each channel's noise is the hand-computed PSD, the GM is the bias, and the
        // second unit sits 5 cm along the first's y axis, turned -10 deg in yaw (y_k = C y_0
        // with C the transpose of the unit's mount)
        assert!(notes.is_empty(), "{notes:?}");
        assert_eq!(read.units.len(), 2);
        let close = |a: f32, b: f64| (f64::from(a) - b).abs() <= 1e-6 * b.abs().max(1e-9);
        for u in &read.units {
            assert!(close(u.channels[0].white_psd, 1e-5 / 200.0));
            assert!(close(u.channels[0].gauss_markov_sigma2, 4e-6));
            assert!(close(u.channels[0].gauss_markov_tau_s, 10.0));
            assert!(close(u.channels[5].white_psd, 1e-3 / 200.0));
            assert_eq!(u.channels[5].gauss_markov_sigma2, 0.0);
        }
        assert_eq!(read.units[0].rotation_rpy_rad, [0.0; 3]);
        assert_eq!(read.units[0].lever_arm_m, [0.0; 3]);
        let yaw = read.units[1].rotation_rpy_rad[2];
        assert!((f64::from(yaw) + 10f64.to_radians()).abs() < 1e-6, "{yaw}");
        let arm = read.units[1].lever_arm_m;
        assert!(
            arm[0].abs() < 1e-7 && (arm[1] - 0.05).abs() < 1e-7 && arm[2].abs() < 1e-7,
            "{arm:?}"
        );
    }

    /// One IMU at 200 Hz: gyro white noise 2e-6 (rad/s)^2 per sample and a random walk of
    /// 5e-13 (rad/s)^2 per sample; accelerometer white noise 4e-4 (m/s^2)^2 and a
    /// Gauss-Markov bias of 1e-6 (m/s^2)^2 with a 20 s correlation time. `scale` multiplies
    /// every variance (a static model's noise is the dynamic one's over `scale`).
    fn model(scale: f64) -> SimModel {
        let channel = |model: &str, unit: &str, processes: String| {
            format!(
                r#"{{"stochastic": {{"model": "{model}", "unit": "{unit}", "sample_rate_hz": 200, "processes": [{processes}]}}}}"#
            )
        };
        let json = format!(
            r#"{{"imus": [{{"name": "u", "rate_hz": 200, "gyro": {}, "accel": {}}}]}}"#,
            channel(
                "WN+RW",
                "rad/s",
                format!(
                    r#"{{"kind": "white_noise", "sigma2": {}}}, {{"kind": "random_walk", "sigma2": {}}}"#,
                    2e-6 * scale,
                    5e-13 * scale
                )
            ),
            channel(
                "WN+GM",
                "m/s^2",
                format!(
                    r#"{{"kind": "white_noise", "sigma2": {}}}, {{"kind": "gauss_markov", "beta_per_s": 0.05, "sigma2": {}}}"#,
                    4e-4 * scale,
                    1e-6 * scale
                )
            )
        );
        SimModel::from_json(&json, Path::new("m.json")).unwrap()
    }

    fn close(a: f64, b: f64) -> bool {
        ((a - b) / b).abs() < 1e-5
    }

    #[test]
    fn each_target_gets_the_hand_computed_conversion_of_a_known_model() {
        let noise = imu_noise(&model(1.0), None, Path::new("m.json")).unwrap();
        // Densities: N = sqrt(sigma2 dt), K = sqrt(sigma2_rw / dt), and a Gauss-Markov bias's
        // driving PSD 2 sigma^2 / tau as a walk.
        let (n_g, k_g) = ((2e-6f64 / 200.0).sqrt(), (5e-13f64 * 200.0).sqrt());
        let (n_a, k_a) = ((4e-4f64 / 200.0).sqrt(), (2.0 * 1e-6f64 / 20.0).sqrt());
        assert!(close(n_g, 1e-4) && close(k_g, 1e-5));
        let value = |format, name| {
            entries(&noise, format)
                .into_iter()
                .find(|e| e.name == name)
                .unwrap()
                .value
        };
        assert!(close(value(Format::Kalibr, "gyroscope_noise_density"), n_g));
        assert!(close(value(Format::Kalibr, "gyroscope_random_walk"), k_g));
        assert!(close(
            value(Format::Kalibr, "accelerometer_noise_density"),
            n_a
        ));
        assert!(close(
            value(Format::Kalibr, "accelerometer_random_walk"),
            k_a
        ));
        // EKF2 predicts every 10 ms: sigma = N / sqrt(0.01) = 10 N.
        assert!(close(value(Format::Px4, "EKF2_GYR_NOISE"), 1e-3));
        assert!(close(value(Format::Px4, "EKF2_GYR_B_NOISE"), 1e-4));
        assert!(close(value(Format::Px4, "EKF2_ACC_NOISE"), 10.0 * n_a));
        assert!(close(value(Format::Px4, "EKF2_ACC_B_NOISE"), 10.0 * k_a));
        // EKF3 every 12 ms.
        let per_step = 1.0 / 0.012f64.sqrt();
        assert!(close(
            value(Format::Ardupilot, "EK3_GYRO_P_NSE"),
            per_step * n_g
        ));
        assert!(close(
            value(Format::Ardupilot, "EK3_ABIAS_P_NSE"),
            per_step * k_a
        ));
        // The Gauss-Markov approximation is said.
        assert!(noise
            .accel
            .approximations
            .iter()
            .any(|a| a.contains("Gauss-Markov")));
        assert!(noise.gyro.approximations.is_empty());
    }

    #[test]
    fn the_files_read_as_their_tools_read_them_with_the_inflation_beside() {
        let dynamic = imu_noise(&model(16.0), None, Path::new("d.json")).unwrap();
        let static_noise = imu_noise(&model(1.0), None, Path::new("s.json")).unwrap();
        // Kalibr: `key: value` lines, the four values and the rate.
        let yaml = render(&dynamic, Some(&static_noise), Format::Kalibr, "d.json");
        let keys: Vec<(&str, f64)> = yaml
            .lines()
            .filter(|l| !l.starts_with('#'))
            .filter_map(|l| {
                let (k, v) = l.split_once(':')?;
                Some((k, v.split('#').next()?.trim().parse().ok()?))
            })
            .collect();
        assert_eq!(keys.len(), 5, "{yaml}");
        assert!(keys.contains(&("update_rate", 200.0)));
        let density = keys
            .iter()
            .find(|k| k.0 == "gyroscope_noise_density")
            .unwrap()
            .1;
        assert!(close(density, 4e-4), "{density}");
        // Variances 16 times the static ones: densities inflated 4 times, and said.
        assert_eq!(yaml.matches("inflation x4.00").count(), 4, "{yaml}");
        // PX4: tab-separated `1 1 NAME VALUE 9` lines.
        let params = render(&dynamic, None, Format::Px4, "d.json");
        let rows: Vec<Vec<&str>> = params
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| l.split('\t').collect())
            .collect();
        assert_eq!(rows.len(), 4);
        assert!(rows
            .iter()
            .all(|r| r.len() == 5 && r[0] == "1" && r[4] == "9"));
        assert!(rows
            .iter()
            .any(|r| r[2] == "EKF2_GYR_NOISE" && close(r[3].parse().unwrap(), 4e-3)));
        // ArduPilot: `NAME,VALUE`, and a value EKF3 clamps is named with its bound.
        let parm = render(&dynamic, None, Format::Ardupilot, "d.json");
        let names: Vec<&str> = parm
            .lines()
            .filter(|l| !l.starts_with('#'))
            .filter_map(|l| l.split_once(',').map(|(n, _)| n))
            .collect();
        assert_eq!(
            names,
            [
                "EK3_GYRO_P_NSE",
                "EK3_ACC_P_NSE",
                "EK3_GBIAS_P_NSE",
                "EK3_ABIAS_P_NSE"
            ]
        );
        assert!(parm.contains("EK3_GBIAS_P_NSE = ") && parm.contains("the filter runs the bound"));
    }

    #[test]
    fn a_model_of_several_imus_needs_one_named() {
        let mut m = model(1.0);
        let mut second = m.imus[0].clone();
        second.name = "v".into();
        m.imus.push(second);
        let err = imu_noise(&m, None, Path::new("m.json"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("m.json") && err.contains("u, v") && err.contains("--imu"),
            "{err}"
        );
        let err = imu_noise(&m, Some("w"), Path::new("m.json"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("no IMU named `w`"), "{err}");
        assert_eq!(
            imu_noise(&m, Some("v"), Path::new("m.json")).unwrap().imu,
            "v"
        );
    }
}
