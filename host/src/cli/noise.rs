//! `dynacal noise INPUT [--topic T] [--kalibr imu.yaml] [--json MODEL] [--report DIR]
//! [--stream auto|always|never]`: the
//! `allan_variance_ros` workflow in one command on one IMU of any importable input
//! (`dynacal::noise`): the still stretches found, each axis' GMWM model chosen by the WIC,
//! the table people copy from, Kalibr's `imu.yaml`, and the noise in motion over at rest.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::input::stream::StreamMode;
use dynacal::noise::{choose_imu, kalibr_yaml, model_of, report_page, table, NoiseOptions};
use dynacal::output::write_atomic;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A ROS bag (ROS1 `.bag`, a ROS2 bag's folder or storage file), a flight log, an
    /// interchange file, or a folder of them.
    pub input: PathBuf,
    /// The IMU: a ROS topic (`/imu/data`) or an imported sensor's name; needed when the input
    /// holds several.
    #[arg(long)]
    pub topic: Option<String>,
    /// Write Kalibr's imu.yaml (rostopic, noise densities and random walks).
    #[arg(long, value_name = "FILE")]
    pub kalibr: Option<PathBuf>,
    /// Write the fitted model file (`simulate --model`, `diagnose --baseline`, `export`).
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write DIR/report.html: the table and each axis' Allan deviation with the model.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// The still stretch, FROM_S TO_S in the recording's time, instead of finding it.
    #[arg(long, num_args = 2, value_names = ["FROM_S", "TO_S"])]
    pub still: Option<Vec<f64>>,
    /// Window of the stillness test, s.
    #[arg(long, default_value_t = 1.0)]
    pub window_s: f64,
    /// Read the IMU's samples anew each pass (in memory that does not grow with the input)
    /// rather than importing them whole: `auto` for a flight log, text recording or
    /// interchange file over 256 MiB, and a ROS bag's `--topic`.
    #[arg(long, value_enum, default_value_t = StreamMode::Auto)]
    pub stream: StreamMode,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut chosen = choose_imu(&args.input, args.topic.as_deref(), args.stream)?;
    for note in &chosen.notes {
        println!("{}: {note}", args.input.display());
    }
    anyhow::ensure!(
        args.window_s.is_finite() && args.window_s > 0.0,
        "--window-s {} must be a positive number of seconds",
        args.window_s
    );
    let options = NoiseOptions {
        window_s: args.window_s,
        still_span_s: args.still.as_ref().map(|v| (v[0], v[1])),
        ..NoiseOptions::default()
    };
    let bar = super::working(&format!("fitting the noise of {}", chosen.name));
    let report = chosen.analyse(&options);
    bar.finish_and_clear();
    let report = report.map_err(|e| anyhow::anyhow!("{}: {e}", args.input.display()))?;
    println!("IMU {}: {}", report.imu, report.sampling);
    for note in &report.notes {
        println!("note: {note}");
    }
    for s in &report.stillness.still {
        println!(
            "still: {:.3} s to {:.3} s ({} samples)",
            s.from_s,
            s.to_s,
            s.samples.len()
        );
    }
    for line in table(&report) {
        println!("{line}");
    }
    println!("N: white-noise density (unit/sqrt(Hz)); K: bias random walk (unit/s/sqrt(Hz)); B: bias instability (unit) at tau_B; motion x: the noise density in motion over at rest");
    let source = args.input.display().to_string();
    if let Some(path) = &args.kalibr {
        let text = kalibr_yaml(&report, chosen.topic.as_deref(), &source)
            .map_err(|e| anyhow::anyhow!("{source}: Kalibr export: {e}"))?;
        write_atomic(path, text.as_bytes())
            .with_context(|| format!("{}: cannot write", path.display()))?;
        println!("wrote {}", path.display());
    }
    let model = model_of(&report)?;
    let page = match &args.report {
        Some(_) => {
            Some(report_page(&report).map_err(|e| anyhow::anyhow!("drawing the report: {e}"))?)
        }
        None => None,
    };
    match &args.json {
        Some(json) => {
            super::write_json_and_report(json, &model, args.report.as_deref(), page.as_ref())
        }
        None => {
            if let (Some(dir), Some(page)) = (&args.report, &page) {
                dynacal::report::write_html(dir, page)
                    .with_context(|| format!("writing the report into {}", dir.display()))?;
                println!("wrote {}", dir.join(dynacal::report::REPORT_HTML).display());
            }
            Ok(())
        }
    }
}
