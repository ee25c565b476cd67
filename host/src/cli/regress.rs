//! `dynacal regress ERRORS.csv`: the paper's Tables II and III. Regresses each error channel
//! on the 15 dynamics quantities with backward elimination and prints the table. The file is
//! streamed ([`dynacal::regress::stream`]): memory does not grow with its length.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::error_signal::ERROR_COLUMNS;
use dynacal::interchange::CHANNELS;
use dynacal::regress::stream::regress_file;
use dynacal::regress::{Inference, RegressionOptions, RegressionReport, DYNAMICS_REGRESSORS};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Error-signal file written by `dynacal errors`.
    pub errors: PathBuf,
    /// Inference: `hac` (Newey-West, valid under autocorrelation) or `classical` (the paper's).
    #[arg(long, default_value = "hac", value_parser = ["hac", "classical"])]
    pub inference: String,
    /// HAC Bartlett lag in samples (default: Newey & West's 1994 automatic bandwidth).
    #[arg(long)]
    pub hac_lag: Option<usize>,
    /// Do not VAR(1)-prewhiten the scores before the HAC estimate.
    #[arg(long)]
    pub no_prewhite: bool,
    /// Significance level for backward elimination.
    #[arg(long, default_value_t = 0.05)]
    pub alpha: f64,
    /// Write the reports as JSON (keyed by channel).
    #[arg(long)]
    pub json: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.alpha > 0.0 && args.alpha < 1.0,
        "--alpha must lie in (0, 1), got {}",
        args.alpha
    );
    let opts = RegressionOptions {
        alpha: args.alpha,
        inference: if args.inference == "classical" {
            Inference::Classical
        } else {
            Inference::NeweyWest {
                lag: args.hac_lag,
                prewhite: !args.no_prewhite,
            }
        },
        intercept: true,
    };
    let bar = super::working(&format!("regressing {}", args.errors.display()));
    let outcomes = regress_file(&args.errors, &opts);
    bar.finish_and_clear();
    let mut reports: Vec<(&str, RegressionReport)> = Vec::new();
    for (column, outcome) in outcomes? {
        let k = ERROR_COLUMNS
            .iter()
            .position(|c| *c == column)
            .expect("an error column");
        let report = outcome
            .with_context(|| format!("{}: channel {}", args.errors.display(), CHANNELS[k]))?;
        reports.push((CHANNELS[k], report));
    }
    print!("{}", format_table(&reports));
    if let Some(out) = &args.json {
        let map: serde_json::Map<String, serde_json::Value> = reports
            .iter()
            .map(|(ch, r)| Ok(((*ch).to_string(), serde_json::to_value(r)?)))
            .collect::<anyhow::Result<_>>()?;
        dynacal::output::write_json_atomic(out, &map)
            .with_context(|| format!("writing {}", out.display()))?;
        super::wrote(&[out.as_path()]);
    }
    Ok(())
}

/// Renders reports side by side like the paper's Tables II/III.
pub fn format_table(reports: &[(&str, RegressionReport)]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let w = 26;
    let _ = write!(s, "{:<14}", "");
    for (ch, _) in reports {
        let _ = write!(s, "{:>w$}", format!("error {ch}"));
    }
    s.push('\n');
    for name in std::iter::once("intercept").chain(DYNAMICS_REGRESSORS) {
        let _ = write!(s, "{name:<14}");
        for (_, r) in reports {
            let cell = r
                .coefficient(name)
                .map(|c| format!("{:.3e} ({:.2e}){}", c.estimate, c.std_error, c.stars))
                .unwrap_or_default();
            let _ = write!(s, "{cell:>w$}");
        }
        s.push('\n');
    }
    type Row = (&'static str, fn(&RegressionReport) -> String);
    let rows: [Row; 7] = [
        ("R^2", |r| format!("{:.2} %", 100.0 * r.r2)),
        ("Adj. R^2", |r| format!("{:.2} %", 100.0 * r.adj_r2)),
        ("sigma_e^2", |r| format!("{:.3e}", r.residual_variance)),
        ("F-stat", |r| format!("{:.3e}", r.f_statistic)),
        ("p-value (F)", |r| format!("{:.2e}", r.f_p_value)),
        ("p-value (inf.)", |r| format!("{:.2e}", r.wald_p_value)),
        ("HAC lag", |r| match r.hac_bandwidth {
            Some(bw) => format!("{} ({bw:.1})", r.hac_lag),
            None => r.hac_lag.to_string(),
        }),
    ];
    for (label, f) in rows {
        let _ = write!(s, "{label:<14}");
        for (_, r) in reports {
            let _ = write!(s, "{:>w$}", f(r));
        }
        s.push('\n');
    }
    if let Some((_, r)) = reports.first() {
        let _ = writeln!(
            s,
            "inference: {} (first channel; HAC lag (bandwidth) of each in row `HAC lag`); stars: *** <0.001 ** <0.01 * <0.05 . <0.1",
            r.inference
        );
    }
    s
}
