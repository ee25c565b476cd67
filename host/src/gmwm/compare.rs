//! Static versus dynamic (the seed paper's Table I): two fits of the same model, parameter by
//! parameter, with whether their 95% intervals overlap and a Wald test of equality.
//!
//! The Wald test works on the transformed scale, where the estimators are close to normal:
//! z = (theta_a - theta_b) / sqrt(se_a^2 + se_b^2) (the two recordings are independent),
//! two-sided p = 2 (1 - Phi(|z|)). A derived parameter (noise density, correlation time) is
//! a monotone function of one transformed parameter and shares its test.

use serde::Serialize;
use statrs::distribution::{ContinuousCDF, Normal};

use super::inference::ChannelFit;

/// One row of the comparison.
#[derive(Debug, Clone, Serialize)]
pub struct ComparisonRow {
    pub process: String,
    pub parameter: String,
    pub unit: String,
    pub static_value: f64,
    pub static_ci95: Option<[f64; 2]>,
    pub dynamic_value: f64,
    pub dynamic_ci95: Option<[f64; 2]>,
    /// Whether the two 95% intervals overlap (None when one is missing).
    pub intervals_overlap: Option<bool>,
    pub wald_z: Option<f64>,
    pub wald_p_value: Option<f64>,
}

/// Errors comparing fits.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CompareError {
    #[error("the fits have different models ({a} vs {b}): compare fits of the same model")]
    DifferentModels { a: String, b: String },
}

/// Compares `a` (static) with `b` (dynamic).
pub fn compare(a: &ChannelFit, b: &ChannelFit) -> Result<Vec<ComparisonRow>, CompareError> {
    if a.model != b.model {
        return Err(CompareError::DifferentModels {
            a: a.model.clone(),
            b: b.model.clone(),
        });
    }
    let normal = Normal::new(0.0, 1.0).expect("standard normal");
    Ok(a.parameters
        .iter()
        .zip(&b.parameters)
        .map(|(pa, pb)| {
            let overlap = match (pa.ci95, pb.ci95) {
                (Some(x), Some(y)) => Some(x[0] <= y[1] && y[0] <= x[1]),
                _ => None,
            };
            let k = pa.theta_index;
            let z = match (pa.theta_se, pb.theta_se) {
                (Some(sa), Some(sb)) if sa > 0.0 || sb > 0.0 => {
                    Some((a.theta[k] - b.theta[k]) / (sa * sa + sb * sb).sqrt())
                }
                _ => None,
            };
            ComparisonRow {
                process: pa.process.clone(),
                parameter: pa.name.clone(),
                unit: pa.unit.clone(),
                static_value: pa.value,
                static_ci95: pa.ci95,
                dynamic_value: pb.value,
                dynamic_ci95: pb.ci95,
                intervals_overlap: overlap,
                wald_z: z,
                wald_p_value: z.map(|z| 2.0 * (1.0 - normal.cdf(z.abs()))),
            }
        })
        .collect())
}

/// Table I as text.
pub fn format_table(rows: &[ComparisonRow]) -> String {
    let ci = |c: Option<[f64; 2]>| match c {
        Some([l, h]) => format!("[{l:.5e}, {h:.5e}]"),
        None => "n/a".to_string(),
    };
    let mut out = format!(
        "{:<5} {:<19} {:<16} {:>12} {:<27} {:>12} {:<27} {:<8} {:>9}\n",
        "proc",
        "parameter",
        "unit",
        "static",
        "static 95% CI",
        "dynamic",
        "dynamic 95% CI",
        "overlap",
        "Wald p"
    );
    for r in rows {
        out.push_str(&format!(
            "{:<5} {:<19} {:<16} {:>12.5e} {:<27} {:>12.5e} {:<27} {:<8} {:>9}\n",
            r.process,
            r.parameter,
            r.unit,
            r.static_value,
            ci(r.static_ci95),
            r.dynamic_value,
            ci(r.dynamic_ci95),
            match r.intervals_overlap {
                Some(true) => "yes",
                Some(false) => "no",
                None => "n/a",
            },
            r.wald_p_value
                .map(|p| format!("{p:.3e}"))
                .unwrap_or_else(|| "n/a".into()),
        ));
    }
    out
}
