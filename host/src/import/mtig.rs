//! Xsens MTi-G gyro X (`mtig/gyro_x_contaminated.csv.gz`): one column `gx_rad_s` at
//! 100 Hz, no time column. It becomes a single-axis interchange recording (channel `gx`
//! only), t = row / 100 s. The sensor's axis is kept as the body x axis.

use std::path::Path;

use super::rows::{collect_one, SensorLayout, SensorRows};
use super::{for_each_column_row, uniform_time_s, ImportError};
use crate::interchange::ImuRecording;

/// The header of the MTi-G file.
pub const COLUMNS: [&str; 1] = ["gx_rad_s"];

/// Sampling rate, Hz.
pub const RATE_HZ: f64 = 100.0;

/// Reads the single-axis gyro record.
pub fn read(path: &Path) -> Result<ImuRecording, ImportError> {
    collect_one(path, |sink| stream(path, sink))
}

/// Streams the record into `sink`, row by row.
pub(crate) fn stream(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    sink.begin(vec![SensorLayout {
        name: String::new(),
        columns: vec!["t_s", "gx_rad_s"],
        rate_hz: None,
    }])?;
    let mut samples = 0u64;
    for_each_column_row(path, &COLUMNS, |_, values| {
        let row = [uniform_time_s(samples, RATE_HZ), values[0]];
        samples += 1;
        sink.push(0, &row)
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
