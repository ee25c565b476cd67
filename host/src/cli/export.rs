//! `dynacal export MODEL --to kalibr|px4|ardupilot|board --out FILE [--imu NAME] [--static S.json]`:
//! a fitted model (`fit`, `refit`, `diagnose`) as the noise parameters of the tools people
//! run, or as the board's model blob (`dynacal::export`), written whole or not at all.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::export::{board_blob, board_model_of, imu_noise, render, Format};
use dynacal::model::SimModel;
use dynacal::output::write_atomic;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Model file (docs/formats.md section 3): ideally one measured under motion (from a
    /// reference with `errors` and `fit`, or from three units with `refit`).
    pub model: PathBuf,
    /// Target format.
    #[arg(long = "to", value_enum)]
    pub format: Target,
    /// The file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// The model's IMU to export (needed when it holds several).
    #[arg(long)]
    pub imu: Option<String>,
    /// A static model of the same IMU: its values and the measured inflation factors go in
    /// comments beside the exported (dynamic) values.
    #[arg(long = "static")]
    pub static_model: Option<PathBuf>,
}

/// Where the model goes: a tool's noise parameters, or the board.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Target {
    /// Kalibr `imu.yaml` (Kalibr, OpenVINS, VINS-Mono).
    Kalibr,
    /// PX4 EKF2 parameters (QGroundControl's `.params` file).
    Px4,
    /// ArduPilot EKF3 parameters (a `.parm` file Mission Planner and MAVProxy load).
    Ardupilot,
    /// The board's model blob (`board-model.bin`: `dynacal board --model`, or flashed into
    /// the real board): every IMU of the model, in order.
    Board,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let model = SimModel::load(&args.model)?;
    let format = match args.format {
        Target::Kalibr => Format::Kalibr,
        Target::Px4 => Format::Px4,
        Target::Ardupilot => Format::Ardupilot,
        Target::Board => return export_board(&model, &args),
    };
    let noise = imu_noise(&model, args.imu.as_deref(), &args.model)?;
    let static_noise = match &args.static_model {
        Some(path) => {
            let m = SimModel::load(path)?;
            // The same IMU by name where the static model has it, else its only one.
            let name = args.imu.clone().or_else(|| {
                m.imus
                    .iter()
                    .any(|i| i.name == noise.imu)
                    .then(|| noise.imu.clone())
            });
            Some(imu_noise(&m, name.as_deref(), path)?)
        }
        None => None,
    };
    let text = render(
        &noise,
        static_noise.as_ref(),
        format,
        &args.model.display().to_string(),
    );
    write_atomic(&args.out, text.as_bytes())
        .with_context(|| format!("{}: cannot write", args.out.display()))?;
    println!(
        "IMU `{}`: gyro {:.3e} rad/s/sqrt(Hz) white, {:.3e} rad/s^2/sqrt(Hz) walk; accel {:.3e} m/s^2/sqrt(Hz), {:.3e} m/s^3/sqrt(Hz); wrote {}",
        noise.imu,
        noise.gyro.noise_density,
        noise.gyro.random_walk,
        noise.accel.noise_density,
        noise.accel.random_walk,
        args.out.display()
    );
    Ok(())
}

fn export_board(model: &SimModel, args: &Args) -> anyhow::Result<()> {
    if args.imu.is_some() || args.static_model.is_some() {
        anyhow::bail!(
            "--to board takes every IMU of {} (the board runs them all) and no --static: \
             leave out --imu and --static",
            args.model.display()
        );
    }
    let (board, notes) = board_model_of(model, &args.model)?;
    let blob = board_blob(&board, &args.model)?;
    for note in notes {
        println!("note: {note}");
    }
    write_atomic(&args.out, &blob)
        .with_context(|| format!("{}: cannot write", args.out.display()))?;
    println!(
        "{} units, {} bytes of board model; wrote {}",
        board.units.len(),
        blob.len(),
        args.out.display()
    );
    Ok(())
}
