//! dynacal: host-side library. Reads and writes sensor recordings, decodes the board's logs,
//! and fits, simulates and diagnoses inertial sensor error models.
//!
//! The `dynacal` binary is a thin command-line layer over this library; errors here are
//! typed (`thiserror`), `anyhow` appears only in the binary.

pub mod board_log;
pub mod calibration;
pub mod decode;
pub mod diagnose;
pub mod error_signal;
pub mod export;
pub mod figures;
pub mod gmwm;
pub mod import;
pub mod input;
pub mod interchange;
pub mod mission;
pub mod model;
pub mod nav_smoother;
pub mod navsim;
pub mod noise;
pub mod numeric;
pub mod output;
pub mod progress;
pub mod redundancy;
pub mod refit;
pub mod regress;
pub mod replay;
pub mod report;
pub mod series_bank;
pub mod sim;
pub mod wv;

use std::path::PathBuf;

/// An error and its causes joined by `: `, each cause said once: many errors already carry
/// their cause's text in their own message (`{path}: {source}`), and printing the chain as
/// it is would repeat it. What the command line prints after `dynacal: error:`, and the
/// message of the Python package's `DynacalError`.
pub fn error_message(error: &(dyn std::error::Error + 'static)) -> String {
    let mut message = String::new();
    let mut cause = Some(error);
    while let Some(e) = cause {
        let text = e.to_string();
        if !message.contains(&text) {
            if !message.is_empty() {
                message.push_str(": ");
            }
            message.push_str(&text);
        }
        cause = e.source();
    }
    message
}

/// The measured-data folder: `$DYNACAL_DATA` if set, else `../shared/data` relative to the
/// workspace root (the repository is checked out with `shared/` beside it).
pub fn data_dir() -> PathBuf {
    match std::env::var_os("DYNACAL_DATA") {
        Some(dir) => PathBuf::from(dir),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"),
    }
}
