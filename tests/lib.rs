//! Shared helpers for dynacal's cross-crate and end-to-end tests: where the measured data
//! live, and how to skip cleanly when they are absent.

use std::path::PathBuf;

/// The measured-data folder: `$DYNACAL_DATA`, else `../shared/data` beside the repository.
pub fn data_dir() -> PathBuf {
    dynacal::data_dir()
}
