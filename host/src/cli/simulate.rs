//! `dynacal simulate`: a car or static run of the reference IMU, MEMS IMUs, GNSS and PPS
//! from a model file, written to a folder in the interchange format with a truth file.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use dynacal::interchange::FileFormat;
use dynacal::sim::{self, Scenario, SimModel, SimOptions};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Motion: a car in traffic, or the platform at rest.
    #[arg(long, value_enum, default_value = "car")]
    pub scenario: Scenario,
    /// Length of the run, seconds.
    #[arg(long, default_value_t = 600.0)]
    pub seconds: f64,
    /// Seed of every random draw (trajectory script, noises, clocks).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Model file (`docs/formats.md` section 3): the output of `dynacal fit`, the extended
    /// model of `dynacal diagnose`, a hand-written simulator model, or a bare GMWM model;
    /// default: a navigation-grade reference, no MEMS IMU, GNSS and PPS.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Output folder (created if absent).
    #[arg(long)]
    pub out: PathBuf,
    /// Switch effects off everywhere, e.g. `--disable white_noise,vibration`.
    #[arg(long, value_delimiter = ',')]
    pub disable: Vec<dynacal::model::Effect>,
    /// Also write `<imu>-ideal.csv`: error-free sensor outputs at the true sampling instants.
    #[arg(long)]
    pub ideal: bool,
    /// The IMU files' form: CSV text, gzip-compressed CSV, or Parquet (binary columns, the
    /// fastest to read; `gnss` and `pps` stay CSV).
    #[arg(long, value_enum, default_value_t = FileFormat::Csv)]
    pub format: FileFormat,
    /// Write gzip-compressed `.csv.gz` files (the same as `--format csv-gz`).
    #[arg(long, conflicts_with = "format")]
    pub gzip: bool,
    /// Also write the MEMS IMUs (at most 3) as the board records them: `board.replay`, the
    /// firmware replay input, and `board.log`, the board log (raw counts with each IMU's
    /// quantization_step as LSB, or 1e-6 rad/s and 1e-5 m/s^2; GPS-time microsecond
    /// stamps; PPS every second; GNSS fixes in the log).
    #[arg(long)]
    pub replay: bool,
    /// Also write the run as a ROS2 bag folder (MCAP, `metadata.yaml`): each IMU as a
    /// `sensor_msgs/Imu` topic `/<imu>/imu`, the reference's navigation as
    /// `/reference/odometry`, the GNSS fixes as `/gnss/fix` (`docs/formats.md`, "ROS bags").
    #[arg(long, value_name = "DIR")]
    pub ros2: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let model = match &args.model {
        Some(path) => SimModel::load(path)?,
        None => serde_json::from_str::<SimModel>("{}").context("default model")?,
    };
    let opts = SimOptions {
        scenario: args.scenario,
        seconds: args.seconds,
        seed: args.seed,
        disabled: args.disable.clone(),
        keep_ideal: args.ideal,
    };
    let total = sim::total_samples(&model, args.seconds);
    let bar = super::bars().add(ProgressBar::new(total));
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} simulating [{bar:40}] {percent}% {human_pos}/{human_len} samples, eta {eta}",
        )
        .context("progress template")?
        .progress_chars("=> "),
    );
    let started = Instant::now();
    let out = sim::simulate(&model, &opts, &|n| bar.inc(n))?;
    bar.finish_and_clear();
    let simulated = started.elapsed();
    let board = if args.replay {
        Some(sim::board::board_recording(&out, &model)?)
    } else {
        None
    };
    let files = sim::output::write_outputs_with_board(
        &out,
        &args.out,
        if args.gzip {
            FileFormat::CsvGz
        } else {
            args.format
        },
        args.ideal,
        board.as_ref(),
    )?;
    if let Some(bag) = &args.ros2 {
        let written = sim::ros2::write_ros2_bag(&out, bag)?;
        eprintln!(
            "wrote the ROS2 bag {} ({} files)",
            bag.display(),
            written.len()
        );
    }
    eprintln!(
        "simulated {} s ({} IMU samples) in {:.2} s, wrote {} files to {} in {:.2} s",
        args.seconds,
        total,
        simulated.as_secs_f64(),
        files.len(),
        args.out.display(),
        (started.elapsed() - simulated).as_secs_f64()
    );
    Ok(())
}
