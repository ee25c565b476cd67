//! Subcommand definitions and dispatch for the `dynacal` binary.

use clap::{Parser, Subcommand};

/// dynacal: observe, model and simulate MEMS inertial sensor errors under vehicle dynamics.
#[derive(Debug, Parser)]
#[command(name = "dynacal", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Show the header and size of an interchange file.
    Info(info::Args),
    /// Decode a board log into per-IMU interchange CSVs and summary.json.
    Decode(decode::Args),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Info(args) => info::run(args),
        Command::Decode(args) => decode::run(args),
    }
}

mod decode;
mod info;
