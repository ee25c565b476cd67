//! The four-MPU9250 static rig (`mpu9250x4-tetra-static/static.csv.gz`): one `t_s` column
//! and, for k = 0..3, `imu{k}_g{x,y,z}_rad_s` and `imu{k}_a{x,y,z}_m_s2`, about 43 Hz.
//!
//! Each IMU becomes its own interchange recording on the shared time column, values as given
//! (already rad/s and m/s^2; the source used g = 9.81 for its conversion). The values stay in
//! each IMU's own sensor axes: the four IMUs are **not aligned** with each other (imu0 has z
//! roughly up, imu1..3 have gravity mostly along -x, tilted 20-24 degrees), and their
//! orientations on the rig are not documented, so no rotation to a common body frame is made.

use std::path::Path;

use super::rows::{Collect, SensorLayout, SensorRows};
use super::{for_each_column_row, ImportError};
use crate::interchange::ImuRecording;

/// Number of IMUs on the rig.
pub const IMUS: usize = 4;

/// The file's header: `t_s` then six columns per IMU.
pub fn columns() -> Vec<String> {
    let mut out = vec!["t_s".to_string()];
    for k in 0..IMUS {
        for axis in [
            "gx_rad_s", "gy_rad_s", "gz_rad_s", "ax_m_s2", "ay_m_s2", "az_m_s2",
        ] {
            out.push(format!("imu{k}_{axis}"));
        }
    }
    out
}

/// Reads the file into one recording per IMU, in order imu0..imu3.
pub fn read(path: &Path) -> Result<Vec<ImuRecording>, ImportError> {
    let mut collect = Collect::new(path);
    stream(path, &mut collect)?;
    Ok(collect
        .into_sensors()?
        .into_iter()
        .map(|s| s.recording)
        .collect())
}

/// Streams the four IMUs (`imu0`..`imu3`) into `sink`, row by row.
pub(crate) fn stream(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    let names = columns();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    sink.begin(
        (0..IMUS)
            .map(|k| SensorLayout::imu(format!("imu{k}")))
            .collect(),
    )?;
    let mut row = [0.0; 7];
    for_each_column_row(path, &names, |_, values| {
        row[0] = values[0];
        for k in 0..IMUS {
            row[1..].copy_from_slice(&values[1 + 6 * k..7 + 6 * k]);
            sink.push(k, &row)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_into_four_recordings_on_one_time_base() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.csv");
        let row = |t: f64| {
            let mut v = vec![t.to_string()];
            v.extend((0..24).map(|i| (i as f64 + t).to_string()));
            v.join(",")
        };
        std::fs::write(
            &path,
            format!("{}\n{}\n{}\n", columns().join(","), row(0.0), row(0.023)),
        )
        .unwrap();
        let recs = read(&path).unwrap();
        assert_eq!(recs.len(), 4);
        for (k, rec) in recs.iter().enumerate() {
            assert_eq!(rec.t_s, vec![0.0, 0.023]);
            assert_eq!(rec.channel("gx").unwrap()[0], (6 * k) as f64);
            assert_eq!(rec.channel("az").unwrap()[1], (6 * k + 5) as f64 + 0.023);
        }
        std::fs::write(
            &path,
            format!("{}\n{}\n{}\n", columns().join(","), row(0.1), row(0.05)),
        )
        .unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("s.csv: line 3") && msg.contains("t_s"),
            "{msg}"
        );
    }
}
