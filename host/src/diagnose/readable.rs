//! Numbers of a diagnosis as a person reads them: 3-4 significant digits, each cause's
//! estimate in the unit its users quote (%, ms, mm, deg/s, mg, (deg/s)/g), and an interval
//! as `value ± half-width`. The report's tables use it; the JSON keeps SI.

use super::engine::Finding;
use crate::model::{Cause, Channel};

/// Standard gravity, m/s^2 (for mg and per-g units).
const G0_M_S2: f64 = 9.806_65;
const DEG_PER_RAD: f64 = 180.0 / std::f64::consts::PI;

pub use crate::report::html::significant;

/// The unit a cause's estimate on `channel` is shown in, and its factor from SI.
fn display_unit(cause: Cause, channel: Channel) -> (&'static str, f64) {
    let gyro = channel.is_gyro();
    match cause {
        Cause::ScaleFactor | Cause::CrossAxis => ("%", 100.0),
        Cause::GSensitivity => ("(deg/s)/g", DEG_PER_RAD * G0_M_S2),
        Cause::AngularAcceleration | Cause::Jerk | Cause::TimeOffset => ("ms", 1e3),
        Cause::LeverArm => ("mm", 1e3),
        Cause::Outliers => ("% of samples", 100.0),
        Cause::Vibration | Cause::BiasShift | Cause::Quantization if gyro => ("deg/s", DEG_PER_RAD),
        Cause::Vibration | Cause::BiasShift | Cause::Quantization => ("mg", 1e3 / G0_M_S2),
        Cause::NoiseScalesWithDynamics if gyro => ("(deg/s)/(deg/s)", 1.0),
        Cause::NoiseScalesWithDynamics => ("(m/s^2)/(rad/s)", 1.0),
        Cause::CorrelatedNoiseChange | Cause::WhiteNoiseChange => ("", 1.0),
    }
}

/// `value ± half-width unit` of an SI estimate and its 95% interval.
fn plus_minus(value: f64, ci95: [f64; 2], unit: &str, factor: f64) -> String {
    let v = value * factor;
    let half = 0.5 * (ci95[1] - ci95[0]).abs() * factor;
    let unit = if unit.is_empty() {
        String::new()
    } else {
        format!(" {unit}")
    };
    format!("{} ± {}{unit}", significant(v, 4), significant(half, 2))
}

/// A finding's estimate with its 95% interval, readable: one `value ± half-width unit` per
/// regressor (a lever arm: x, y, z).
pub fn estimate(f: &Finding) -> String {
    let (unit, factor) = display_unit(f.cause, f.channel);
    let pair = |v: &serde_json::Value, c: &serde_json::Value| -> Option<String> {
        let value = v.as_f64()?;
        let lo = c.get(0)?.as_f64()?;
        let hi = c.get(1)?.as_f64()?;
        Some(plus_minus(value, [lo, hi], unit, factor))
    };
    if let Some(s) = pair(&f.estimate, &f.ci95) {
        return s;
    }
    match (f.estimate.as_array(), f.ci95.as_array()) {
        (Some(values), Some(intervals)) => values
            .iter()
            .zip(intervals)
            .map(|(v, c)| pair(v, c).unwrap_or_else(|| format!("{v}")))
            .collect::<Vec<_>>()
            .join("; "),
        _ => f.estimate.to_string(),
    }
}

/// A p-value: `< 1e-6` below that, else 2 significant digits.
pub fn p_value(p: Option<f64>) -> String {
    match p {
        None => "(no test)".into(),
        Some(p) if p < 1e-6 => "< 1e-6".into(),
        Some(p) => significant(p, 2),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn numbers_have_four_significant_digits_and_no_logs() {
        assert_eq!(significant(-0.010386969759412643, 4), "-0.01039");
        assert_eq!(significant(17.054, 4), "17.05");
        assert_eq!(significant(3.9104e-8, 4), "3.910e-8");
        assert_eq!(significant(123456.0, 3), "1.23e5");
        assert_eq!(significant(0.0, 4), "0");
    }

    #[test]
    fn each_cause_reads_in_its_unit() {
        let finding = |cause, channel, estimate, ci95| Finding {
            channel,
            cause,
            regressors: vec![],
            estimate,
            ci95,
            variance_explained: 0.0,
            p_value: Some(1e-9),
        };
        let t = finding(
            Cause::TimeOffset,
            Channel::Gz,
            json!(-0.01039),
            json!([-0.0106, -0.0102]),
        );
        assert_eq!(estimate(&t), "-10.39 ± 0.20 ms");
        let s = finding(
            Cause::ScaleFactor,
            Channel::Ay,
            json!(-0.0043),
            json!([-0.0053, -0.0033]),
        );
        assert_eq!(estimate(&s), "-0.4300 ± 0.10 %");
        let l = finding(
            Cause::LeverArm,
            Channel::Ax,
            json!([-0.094, 0.0, 0.1359]),
            json!([[-0.1, -0.088], [-0.01, 0.01], [0.13, 0.1418]]),
        );
        assert_eq!(estimate(&l), "-94.00 ± 6.0 mm; 0 ± 10 mm; 135.9 ± 5.9 mm");
        assert_eq!(p_value(Some(3e-9)), "< 1e-6");
        assert_eq!(p_value(Some(0.0123)), "0.012");
    }
}
