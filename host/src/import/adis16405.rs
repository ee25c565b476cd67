//! ADIS16405 sessions (`adis16405/session{1..6}.csv.gz`): integer output counts at 100 Hz,
//! columns `gx,gy,gz,ax,ay,az`, no time column.
//!
//! Conversion: gyro = counts x 0.05 deg/s with deg = pi/180 rad; accelerometer = counts x
//! 0.00333 g with g = 9.80665 m/s^2 (standard gravity; the source gives no local value);
//! t = row / 100 s, the first row at 0. Each value is `count as f64 * SCALE` with the public
//! constants below, so other code reproduces the bits.
//!
//! Frame: the recordings are in the sensor's own axes and the mounting is not documented, so
//! the sensor frame is kept as the body frame, axis for axis, with no sign change. (At rest
//! `az` reads about -1 g, so the sensor z axis pointed down, as in FRD.)

use std::path::Path;

use super::rows::{collect_one, SensorLayout, SensorRows};
use super::{for_each_csv_row, uniform_time_s, ImportError};
use crate::interchange::ImuRecording;

/// The header of an ADIS16405 session file.
pub const COLUMNS: [&str; 6] = ["gx", "gy", "gz", "ax", "ay", "az"];

/// Sampling rate, Hz.
pub const RATE_HZ: f64 = 100.0;

/// Gyro scale: 0.05 deg/s per count, in rad/s per count.
pub const ADIS16405_GYRO_RAD_S_PER_COUNT: f64 = 0.05 * std::f64::consts::PI / 180.0;

/// Standard gravity used to turn g into m/s^2.
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;

/// Accelerometer scale: 0.00333 g per count, in m/s^2 per count.
pub const ADIS16405_ACCEL_M_S2_PER_COUNT: f64 = 0.00333 * STANDARD_GRAVITY_M_S2;

/// Reads one session; each field must be an integer count.
pub fn read(path: &Path) -> Result<ImuRecording, ImportError> {
    collect_one(path, |sink| stream(path, sink))
}

/// Streams one session into `sink`, row by row.
pub(crate) fn stream(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    sink.begin(vec![SensorLayout::imu("")])?;
    let mut row = [0.0; 7];
    let mut samples = 0u64;
    for_each_csv_row(path, &COLUMNS, |line, record| {
        for (k, field) in record.iter().enumerate() {
            let count: i32 = field.parse().map_err(|_| {
                ImportError::malformed(
                    path,
                    line,
                    format!("column `{}`: `{field}` is not an integer count", COLUMNS[k]),
                )
            })?;
            let scale = if k < 3 {
                ADIS16405_GYRO_RAD_S_PER_COUNT
            } else {
                ADIS16405_ACCEL_M_S2_PER_COUNT
            };
            row[1 + k] = count as f64 * scale;
        }
        row[0] = uniform_time_s(samples, RATE_HZ);
        samples += 1;
        sink.push(0, &row)
    })?;
    if samples == 0 {
        return Err(ImportError::malformed(path, 2, "no data rows"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_become_si_with_stated_scales() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.csv");
        std::fs::write(
            &path,
            "gx,gy,gz,ax,ay,az\n-1,-6,14,-2,0,-305\n20,0,0,0,0,300\n",
        )
        .unwrap();
        let rec = read(&path).unwrap();
        assert_eq!(rec.t_s, vec![0.0, 0.01]);
        // 20 counts = 1 deg/s; 300 counts = 0.999 g.
        assert!((rec.channel("gx").unwrap()[1] - 1f64.to_radians()).abs() < 1e-15);
        assert!((rec.channel("az").unwrap()[1] - 0.999 * 9.80665).abs() < 1e-12);
        assert_eq!(
            rec.channel("gz").unwrap()[0],
            14.0 * ADIS16405_GYRO_RAD_S_PER_COUNT
        );
        assert_eq!(
            rec.channel("az").unwrap()[0],
            -305.0 * ADIS16405_ACCEL_M_S2_PER_COUNT
        );
    }

    #[test]
    fn non_integer_and_short_rows_name_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.csv");
        std::fs::write(&path, "gx,gy,gz,ax,ay,az\n1,2,3,4,5,6\n1,2,3.5,4,5,6\n").unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("s.csv: line 3") && msg.contains("`gz`"),
            "{msg}"
        );
        std::fs::write(
            &path,
            "gx,gy,gz,ax,ay,az\n1,2,3,4,5,6\n1,2,3,4,5,6\n1,2,3,4,5\n",
        )
        .unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("s.csv: line 4") && msg.contains("5 fields"),
            "{msg}"
        );
        std::fs::write(&path, "gx,gy,gz,ax,ay\n1,2,3,4,5\n").unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(msg.contains("line 1") && msg.contains("header"), "{msg}");
    }
}
