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
            eprintln!("dynacal: error: {}", error_message(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined by `: `, each cause said once: many errors already carry
/// their cause's text in their own message (`{path}: {source}`), and printing the chain as
/// it is would repeat it.
fn error_message(error: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if message.contains(&text) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&text);
    }
    message
}
