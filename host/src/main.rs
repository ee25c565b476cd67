//! The `dynacal` command line: a thin layer over the `dynacal` library. Each subcommand
//! lives in its own module under `cli/`.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    // SIGINT/SIGTERM/SIGHUP remove the partial outputs; without the handler (it could not be
    // installed) they are still never mistaken for outputs, only left behind.
    let _ = dynacal::output::remove_partials_on_signal();
    let args = cli::Cli::parse();
    cli::show_progress();
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dynacal: error: {}", dynacal::error_message(e.as_ref()));
            std::process::ExitCode::FAILURE
        }
    }
}
