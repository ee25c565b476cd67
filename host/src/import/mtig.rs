//! Xsens MTi-G gyro X (`mtig/gyro_x_contaminated.csv.gz`): one column `gx_rad_s` at
//! 100 Hz, no time column. It becomes a single-axis interchange recording (channel `gx`
//! only), t = row / 100 s. The sensor's axis is kept as the body x axis.

use std::path::Path;

use super::{read_columns, uniform_time_s, ImportError};
use crate::interchange::{ImuRecording, SingleAxis};

/// The header of the MTi-G file.
pub const COLUMNS: [&str; 1] = ["gx_rad_s"];

/// Sampling rate, Hz.
pub const RATE_HZ: f64 = 100.0;

/// Reads the single-axis gyro record.
pub fn read(path: &Path) -> Result<ImuRecording, ImportError> {
    let gx = read_columns(path, &COLUMNS)?.remove(0);
    Ok(ImuRecording {
        t_s: uniform_time_s(gx.len(), RATE_HZ),
        single_axis: vec![SingleAxis {
            channel: 0,
            values: gx,
        }],
        ..Default::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn single_column_becomes_gx_at_100_hz() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.csv");
        std::fs::write(&path, "gx_rad_s\n-7.1e-04\n6.3e-04\n1e-3\n").unwrap();
        let rec = read(&path).unwrap();
        assert_eq!(rec.t_s, vec![0.0, 0.01, 0.02]);
        assert_eq!(rec.channels(), vec!["gx"]);
        assert_eq!(rec.channel("gx").unwrap(), &[-7.1e-4, 6.3e-4, 1e-3]);
        std::fs::write(&path, "gx_rad_s\n1\nnan\n").unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(msg.contains("g.csv: line 3"), "{msg}");
    }
}
