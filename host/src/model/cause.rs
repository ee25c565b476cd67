//! The causes the diagnosis names: the vocabulary of its output contract (`findings[].cause`),
//! each spelled once.

use serde::{Deserialize, Serialize};

/// A cause of a discrepancy between a measured error and its simulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cause {
    /// Error proportional to the channel's own true input.
    ScaleFactor,
    /// Error proportional to the other axes' true inputs of the same sensor (misalignment).
    CrossAxis,
    /// Gyro error proportional to the specific force.
    GSensitivity,
    /// Error proportional to the angular acceleration.
    AngularAcceleration,
    /// Error proportional to the rate of change of specific force.
    Jerk,
    /// A time offset of this channel against the others and the reference.
    TimeOffset,
    /// An accelerometer's lever arm differing from the calibrated one.
    LeverArm,
    /// White noise whose level follows the dynamics.
    NoiseScalesWithDynamics,
    /// Sinusoidal lines in the error spectrum.
    Vibration,
    /// Rare large errors.
    Outliers,
    /// Steps of the bias during the run.
    BiasShift,
    /// Correlated noise (wavelet variance at long scales) differing from the baseline.
    CorrelatedNoiseChange,
    /// Output quantised to a step (LSB).
    Quantization,
    /// White noise (wavelet variance at short scales) differing from the baseline.
    WhiteNoiseChange,
}

impl Cause {
    /// Every cause, in the order the diagnosis reports them.
    pub const ALL: [Cause; 14] = [
        Cause::ScaleFactor,
        Cause::CrossAxis,
        Cause::GSensitivity,
        Cause::AngularAcceleration,
        Cause::Jerk,
        Cause::TimeOffset,
        Cause::LeverArm,
        Cause::NoiseScalesWithDynamics,
        Cause::Vibration,
        Cause::Outliers,
        Cause::BiasShift,
        Cause::CorrelatedNoiseChange,
        Cause::Quantization,
        Cause::WhiteNoiseChange,
    ];

    /// The name in the output contract (`scale_factor`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            Cause::ScaleFactor => "scale_factor",
            Cause::CrossAxis => "cross_axis",
            Cause::GSensitivity => "g_sensitivity",
            Cause::AngularAcceleration => "angular_acceleration",
            Cause::Jerk => "jerk",
            Cause::TimeOffset => "time_offset",
            Cause::LeverArm => "lever_arm",
            Cause::NoiseScalesWithDynamics => "noise_scales_with_dynamics",
            Cause::Vibration => "vibration",
            Cause::Outliers => "outliers",
            Cause::BiasShift => "bias_shift",
            Cause::CorrelatedNoiseChange => "correlated_noise_change",
            Cause::Quantization => "quantization",
            Cause::WhiteNoiseChange => "white_noise_change",
        }
    }

    /// True for the causes the engine estimates as deterministic terms of the error (a
    /// coefficient on a regressor, or a step); the rest are stochastic effects.
    pub const fn is_deterministic(self) -> bool {
        matches!(
            self,
            Cause::ScaleFactor
                | Cause::CrossAxis
                | Cause::GSensitivity
                | Cause::AngularAcceleration
                | Cause::Jerk
                | Cause::TimeOffset
                | Cause::LeverArm
                | Cause::BiasShift
        )
    }
}

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Cause {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| format!("unknown cause `{s}`"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_through_serde_and_from_str() {
        for c in Cause::ALL {
            let json = serde_json::to_string(&c).unwrap();
            assert_eq!(json, format!("\"{}\"", c.name()));
            assert_eq!(c.name().parse::<Cause>(), Ok(c));
        }
        assert_eq!(
            Cause::ALL.iter().filter(|c| c.is_deterministic()).count(),
            8
        );
    }
}
