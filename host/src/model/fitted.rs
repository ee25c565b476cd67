//! A model file from fitted stochastic models: which IMU and channel a fitted series is, by
//! its name (`gx`, `gx_rad_s`, `gx_err_rad_s`, or any of them after a `sensor/` prefix, as
//! `dynacal fit` names the channels of multi-sensor inputs and board logs).

use super::file::SimModel;
use super::imu::{ChannelModel, ImuModel};
use super::units::unit_to_si;
use super::Channel;
use crate::gmwm::model::ModelSpec;

/// The IMU (the `sensor/` prefix, if any) and the channel a series name denotes.
pub fn imu_channel_of_name(name: &str) -> Option<(Option<&str>, Channel)> {
    let (prefix, short) = match name.rsplit_once('/') {
        Some((p, s)) => (Some(p), s),
        None => (None, name),
    };
    let short = short.trim();
    let channel = short.parse::<Channel>().ok().or_else(|| {
        // An error-signal column: `gx_err_rad_s`.
        Channel::ALL.into_iter().find(|c| {
            let unit_suffix = &c.column()[c.name().len()..];
            short == format!("{}_err{unit_suffix}", c.name())
        })
    })?;
    Some((prefix, channel))
}

/// An IMU name the model file accepts (letters, digits, `-`, `_`), made from `raw`.
pub fn imu_name_from(raw: &str) -> String {
    let name: String = raw
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    match name.as_str() {
        "" => "imu1".into(),
        "reference" | "gnss" | "pps" | "truth" => format!("imu_{name}"),
        _ => name,
    }
}

impl SimModel {
    /// A model whose MEMS IMUs carry the fitted stochastic models `specs`, each on the
    /// channel its name denotes ([`imu_channel_of_name`]); names without a `sensor/` prefix
    /// belong to the IMU `default_imu`. Returns the model and the names that denote no IMU
    /// channel (left out), except that a lone fitted series of no channel name carries over
    /// to every channel of its dimension, as a bare fitted model does.
    pub fn from_channel_models(
        default_imu: &str,
        specs: &[(String, ModelSpec)],
    ) -> (SimModel, Vec<String>) {
        let mut imus: Vec<ImuModel> = Vec::new();
        let mut unmapped = Vec::new();
        for (name, spec) in specs {
            let Some((prefix, channel)) = imu_channel_of_name(name) else {
                unmapped.push(name.clone());
                continue;
            };
            let imu_name = imu_name_from(prefix.unwrap_or(default_imu));
            let k = match imus.iter().position(|i| i.name == imu_name) {
                Some(k) => k,
                None => {
                    imus.push(ImuModel::bare(&imu_name, spec.sample_rate_hz));
                    imus.len() - 1
                }
            };
            imus[k].channels.insert(
                channel,
                ChannelModel {
                    stochastic: Some(spec.clone()),
                    ..Default::default()
                },
            );
        }
        if imus.is_empty() && specs.len() == 1 {
            if let Some((_, angular)) = unit_to_si(&specs[0].1.unit) {
                let mut imu =
                    ImuModel::bare(&imu_name_from(default_imu), specs[0].1.sample_rate_hz);
                let channel = ChannelModel {
                    stochastic: Some(specs[0].1.clone()),
                    ..Default::default()
                };
                if angular {
                    imu.gyro = channel;
                } else {
                    imu.accel = channel;
                }
                imus.push(imu);
                unmapped.clear();
            }
        }
        let model = SimModel {
            imus,
            ..SimModel::default()
        };
        (model, unmapped)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gmwm::model::Process;

    fn wn(unit: &str) -> ModelSpec {
        ModelSpec {
            model: "WN".into(),
            unit: unit.into(),
            sample_rate_hz: 200.0,
            processes: vec![Process::WhiteNoise { sigma2: 1e-4 }],
        }
    }

    #[test]
    fn series_names_denote_imu_channels() {
        assert_eq!(imu_channel_of_name("gx"), Some((None, Channel::Gx)));
        assert_eq!(imu_channel_of_name("az_m_s2"), Some((None, Channel::Az)));
        assert_eq!(
            imu_channel_of_name("gy_err_rad_s"),
            Some((None, Channel::Gy))
        );
        assert_eq!(
            imu_channel_of_name("imu2/ay"),
            Some((Some("imu2"), Channel::Ay))
        );
        assert_eq!(imu_channel_of_name("gx_err_m_s2"), None);
        assert_eq!(imu_channel_of_name("temperature"), None);
        assert_eq!(imu_name_from("psins mems"), "psins_mems");
        assert_eq!(imu_name_from("reference"), "imu_reference");
    }

    #[test]
    fn fitted_channels_land_on_their_imus() {
        let specs = vec![
            ("imu0/gx".to_string(), wn("rad/s")),
            ("imu1/az".to_string(), wn("m/s^2")),
            ("imu1/temp".to_string(), wn("rad/s")),
        ];
        let (model, unmapped) = SimModel::from_channel_models("x", &specs);
        assert_eq!(unmapped, vec!["imu1/temp".to_string()]);
        let names: Vec<&str> = model.imus.iter().map(|i| i.name.as_str()).collect();
        assert_eq!(names, ["imu0", "imu1"]);
        assert!(model.imus[0].model_of(Channel::Gx).stochastic.is_some());
        assert!(model.imus[0].model_of(Channel::Gy).stochastic.is_none());
        assert!(model.imus[1].model_of(Channel::Az).stochastic.is_some());
        model.validate(std::path::Path::new("m.json")).unwrap();
    }

    #[test]
    fn a_lone_unnamed_series_models_every_channel_of_its_kind() {
        let (model, unmapped) =
            SimModel::from_channel_models("mtig", &[("gyro_x".to_string(), wn("deg/s"))]);
        assert!(unmapped.is_empty());
        assert_eq!(model.imus[0].name, "mtig");
        assert!(model.imus[0].model_of(Channel::Gz).stochastic.is_some());
        assert!(model.imus[0].model_of(Channel::Ax).stochastic.is_none());
    }
}
