//! Units of the stochastic models: what a model file may state and its SI factor.

use crate::gmwm::model::{ModelSpec, Process};

/// SI factor and dimension of a stochastic-model unit: (factor to SI, is angular rate).
pub fn unit_to_si(unit: &str) -> Option<(f64, bool)> {
    let u: String = unit.chars().filter(|c| !c.is_whitespace()).collect();
    let deg = std::f64::consts::PI / 180.0;
    Some(match u.as_str() {
        "rad/s" => (1.0, true),
        "mrad/s" => (1e-3, true),
        "deg/s" => (deg, true),
        "deg/h" | "deg/hr" => (deg / 3600.0, true),
        "m/s2" | "m/s^2" => (1.0, false),
        "g" => (9.80665, false),
        "mg" => (9.80665e-3, false),
        "ug" | "µg" => (9.80665e-6, false),
        _ => return None,
    })
}

/// `spec` restated in SI units (rad/s or m/s^2): every variance scales by the unit's factor
/// squared, a drift slope by the factor, correlation times not at all. `None` for a unit
/// [`unit_to_si`] does not know.
pub fn stochastic_in_si(spec: &ModelSpec) -> Option<ModelSpec> {
    let (factor, angular) = unit_to_si(&spec.unit)?;
    let f2 = factor * factor;
    let processes = spec
        .processes
        .iter()
        .map(|p| match *p {
            Process::WhiteNoise { sigma2 } => Process::WhiteNoise {
                sigma2: sigma2 * f2,
            },
            Process::QuantizationNoise { q2 } => Process::QuantizationNoise { q2: q2 * f2 },
            Process::RandomWalk { sigma2 } => Process::RandomWalk {
                sigma2: sigma2 * f2,
            },
            Process::Drift { slope_per_s } => Process::Drift {
                slope_per_s: slope_per_s * factor,
            },
            Process::GaussMarkov { beta_per_s, sigma2 } => Process::GaussMarkov {
                beta_per_s,
                sigma2: sigma2 * f2,
            },
        })
        .collect();
    Some(ModelSpec {
        model: spec.model.clone(),
        unit: if angular { "rad/s" } else { "m/s^2" }.into(),
        sample_rate_hz: spec.sample_rate_hz,
        processes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_convert_to_si() {
        assert_eq!(unit_to_si("deg/s").unwrap().0, std::f64::consts::PI / 180.0);
        assert_eq!(unit_to_si("m/s^2"), Some((1.0, false)));
        assert!(unit_to_si("furlong/fortnight").is_none());
    }

    #[test]
    fn a_model_in_deg_per_s_restated_in_rad_per_s_has_the_same_wavelet_variance_in_si() {
        let spec = ModelSpec {
            model: "WN+RW+DR+GM".into(),
            unit: "deg/s".into(),
            sample_rate_hz: 100.0,
            processes: vec![
                Process::WhiteNoise { sigma2: 0.5 },
                Process::RandomWalk { sigma2: 1e-6 },
                Process::Drift { slope_per_s: 1e-4 },
                Process::GaussMarkov {
                    beta_per_s: 0.1,
                    sigma2: 1e-3,
                },
            ],
        };
        let si = stochastic_in_si(&spec).unwrap();
        assert_eq!(si.unit, "rad/s");
        let f2 = (std::f64::consts::PI / 180.0).powi(2);
        let levels: Vec<u32> = (1..12).collect();
        for (a, b) in spec
            .wv_at_levels(&levels)
            .iter()
            .zip(si.wv_at_levels(&levels))
        {
            assert!((a * f2 - b).abs() <= 1e-12 * b.abs(), "{a} {b}");
        }
    }
}
