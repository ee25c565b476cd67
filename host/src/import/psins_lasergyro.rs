//! The PSINS SIMU text log of a ring-laser-gyro IMU (`psins-lasergyro/lasergyro.imu.gz`,
//! format documented in `HEADER.txt`).
//!
//! Three header lines of six numbers: (1) initial pitch, roll, yaw (deg, PSINS convention,
//! see [`super::frames`]) and ENU velocity (m/s); (2) initial latitude, longitude (deg),
//! height (m), start time t0 (s), sampling interval (ms) and g (m/s^2); (3) scale factors:
//! gyro arcsec per count and accelerometer micro-g x s per count, per axis. Then one line per
//! sample of six integer increments (gyro x, y, z, accelerometer x, y, z) in the right-
//! forward-up body frame. `%` comment lines and blank lines are skipped.
//!
//! Conversion: rate = count x gf x (pi / 648000) / dt rad/s; specific force = count x af x
//! 1e-6 x g / dt m/s^2, with the header's g (PSINS defines its micro-g from its own g0,
//! 9.7803267714, which the header rounds). Each is `count as f64 * per-axis scale`. Then RFU
//! -> FRD (x = source y, y = source x, z = -source z). Sample k (0-based) is the increment
//! over (t0 + k dt, t0 + (k + 1) dt] and is stamped at its end, as PSINS does.

use std::io::BufRead;
use std::path::Path;

use super::frames::{psins_attitude_to_ned, rfu_to_frd};
use super::rows::{collect_one, SensorLayout, SensorRows};
use super::ImportError;
use crate::interchange::{open_maybe_gz, ImuRecording};

/// One arcsecond in radians.
pub const ARCSEC_RAD: f64 = std::f64::consts::PI / 648_000.0;

/// The three header lines of a PSINS SIMU log, in the source's units and conventions.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserGyroHeader {
    /// Initial pitch, roll, yaw of the RFU body w.r.t. ENU (PSINS convention), rad
    /// (the source says "maybe inaccurate").
    pub initial_pitch_roll_yaw_psins_rad: [f64; 3],
    /// Initial velocity, East-North-Up, m/s.
    pub initial_velocity_enu_m_s: [f64; 3],
    /// Initial latitude, longitude (rad) and height (m).
    pub initial_lat_lon_rad_h_m: [f64; 3],
    /// Time of the start of the first increment, s.
    pub t0_s: f64,
    /// Sampling interval, s.
    pub dt_s: f64,
    /// Gravity stated by the source, m/s^2.
    pub g_m_s2: f64,
    /// Gyro scale factors, arcsec per count, source x, y, z (RFU).
    pub gyro_arcsec_per_count: [f64; 3],
    /// Accelerometer scale factors, micro-g x s per count, source x, y, z (RFU).
    pub accel_ug_s_per_count: [f64; 3],
}

impl LaserGyroHeader {
    /// The initial attitude as roll, pitch, yaw (rad) of the FRD body w.r.t. NED.
    pub fn initial_attitude_ned_rad(&self) -> [f64; 3] {
        let [p, r, y] = self.initial_pitch_roll_yaw_psins_rad;
        psins_attitude_to_ned(p, r, y)
    }
}

/// The log's header and its samples as an FRD interchange recording.
#[derive(Debug, Clone)]
pub struct LaserGyroLog {
    pub header: LaserGyroHeader,
    pub recording: ImuRecording,
}

/// Parses a whitespace-separated line of finite numbers; `None` if any field is not one.
pub fn parse_numbers(line: &str) -> Option<Vec<f64>> {
    line.split_whitespace()
        .map(|f| f.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect()
}

/// Reads a PSINS SIMU log.
pub fn read(path: &Path) -> Result<LaserGyroLog, ImportError> {
    let mut header = None;
    let recording = collect_one(path, |sink| {
        header = Some(stream(path, sink)?);
        Ok(())
    })?;
    let header = header.expect("a log streamed whole has its header");
    Ok(LaserGyroLog { header, recording })
}

/// Streams a PSINS SIMU log's samples into `sink`, row by row; returns its header.
pub(crate) fn stream(
    path: &Path,
    sink: &mut dyn SensorRows,
) -> Result<LaserGyroHeader, ImportError> {
    sink.begin(vec![SensorLayout::imu("")])?;
    let reader = open_maybe_gz(path)?;
    let mut header_lines: Vec<Vec<f64>> = Vec::with_capacity(3);
    let mut header: Option<LaserGyroHeader> = None;
    let mut gyro_scale = [0.0; 3];
    let mut accel_scale = [0.0; 3];
    let mut samples = 0u64;
    let mut row = [0.0; 7];
    let mut line_no = 0u64;
    for line in std::io::BufReader::new(reader).split(b'\n') {
        line_no += 1;
        let line = line.map_err(|e| ImportError::io(path, e))?;
        let line = String::from_utf8(line)
            .map_err(|_| ImportError::malformed(path, line_no, "not UTF-8 text"))?;
        let text = line.trim();
        if text.is_empty() || text.starts_with('%') {
            continue;
        }
        let Some(h) = &header else {
            let values = parse_numbers(text)
                .filter(|v| v.len() == 6)
                .ok_or_else(|| {
                    ImportError::malformed(
                        path,
                        line_no,
                        format!(
                            "header line {} must be six numbers, found `{text}`",
                            header_lines.len() + 1
                        ),
                    )
                })?;
            header_lines.push(values);
            if header_lines.len() == 3 {
                let h = parse_header(path, line_no, &header_lines)?;
                for k in 0..3 {
                    gyro_scale[k] = h.gyro_arcsec_per_count[k] * ARCSEC_RAD / h.dt_s;
                    accel_scale[k] = h.accel_ug_s_per_count[k] * 1e-6 * h.g_m_s2 / h.dt_s;
                }
                header = Some(h);
            }
            continue;
        };
        let mut counts = [0i64; 6];
        let mut n = 0;
        for field in text.split_whitespace() {
            if n == 6 {
                n += 1;
                break;
            }
            counts[n] = field.parse().map_err(|_| {
                ImportError::malformed(
                    path,
                    line_no,
                    format!("field {}: `{field}` is not an integer count", n + 1),
                )
            })?;
            n += 1;
        }
        if n != 6 {
            return Err(ImportError::malformed(
                path,
                line_no,
                format!(
                    "{} fields, expected 6 integer increments",
                    text.split_whitespace().count()
                ),
            ));
        }
        let omega_rfu = [0, 1, 2].map(|k| counts[k] as f64 * gyro_scale[k]);
        let f_rfu = [0, 1, 2].map(|k| counts[3 + k] as f64 * accel_scale[k]);
        // A huge count times a large (finite) scale overflows (found by fuzzing).
        if let Some(k) = omega_rfu.iter().chain(&f_rfu).position(|v| !v.is_finite()) {
            return Err(ImportError::malformed(
                path,
                line_no,
                format!("field {}: count {} is not a finite rate", k + 1, counts[k]),
            ));
        }
        samples += 1;
        row[0] = h.t0_s + samples as f64 * h.dt_s;
        row[1..4].copy_from_slice(&rfu_to_frd(omega_rfu));
        row[4..7].copy_from_slice(&rfu_to_frd(f_rfu));
        sink.push(0, &row)?;
    }
    let Some(header) = header else {
        return Err(ImportError::malformed(
            path,
            line_no,
            format!("ends after {} of 3 header lines", header_lines.len()),
        ));
    };
    if samples == 0 {
        return Err(ImportError::malformed(path, line_no, "no sample lines"));
    }
    Ok(header)
}

fn parse_header(path: &Path, line: u64, l: &[Vec<f64>]) -> Result<LaserGyroHeader, ImportError> {
    let deg = std::f64::consts::PI / 180.0;
    let header = LaserGyroHeader {
        initial_pitch_roll_yaw_psins_rad: [l[0][0] * deg, l[0][1] * deg, l[0][2] * deg],
        initial_velocity_enu_m_s: [l[0][3], l[0][4], l[0][5]],
        initial_lat_lon_rad_h_m: [l[1][0] * deg, l[1][1] * deg, l[1][2]],
        t0_s: l[1][3],
        dt_s: l[1][4] * 1e-3,
        g_m_s2: l[1][5],
        gyro_arcsec_per_count: [l[2][0], l[2][1], l[2][2]],
        accel_ug_s_per_count: [l[2][3], l[2][4], l[2][5]],
    };
    // The fields are finite (checked when parsed). Only values that make the conversion meaningless are rejected; the g bounds span
    // Earth's surface gravity (9.78 at the equator to 9.83 at the poles) with margin.
    let bad = if header.dt_s <= 0.0 {
        Some(format!("sampling interval {} ms is not positive", l[1][4]))
    } else if !(9.7..=9.9).contains(&header.g_m_s2) {
        Some(format!("g = {} m/s^2 is not Earth gravity", header.g_m_s2))
    } else if header
        .gyro_arcsec_per_count
        .iter()
        .chain(&header.accel_ug_s_per_count)
        .any(|s| *s <= 0.0)
    {
        Some("scale factors must be positive".to_string())
    } else if header
        .gyro_arcsec_per_count
        .iter()
        .chain(&header.accel_ug_s_per_count)
        .any(|s| !(s / header.dt_s).is_finite())
    {
        // A subnormal interval passes the sign check but overflows every count's scale,
        // which turned counts of 0 into NaN (found by fuzzing).
        Some(format!(
            "sampling interval {} ms is too small: the scale per count overflows",
            l[1][4]
        ))
    } else {
        None
    };
    match bad {
        Some(message) => Err(ImportError::malformed(path, line, message)),
        None => Ok(header),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str = "% comment\n0 0 -90.6 0 0 0\n34.246 108.9097 380 0 10 9.780327\n\
                        0.1 0.1 0.1 125 125 125\n";

    #[test]
    fn increments_become_frd_rates_and_specific_force() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("l.imu");
        std::fs::write(&path, format!("{HEAD}0 0 2 0 0 80\n-7 9 3 8 -4 80\n")).unwrap();
        let log = read(&path).unwrap();
        let rec = &log.recording;
        assert_eq!(rec.t_s, vec![0.01, 0.02]);
        assert_eq!(log.header.dt_s, 0.01);
        // 80 counts x 125 ug*s over 0.01 s = 1 g up: FRD z = -g.
        let g = 9.780327;
        let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        close(rec.channel("az").unwrap()[0], -g);
        // Source x (right) 8 counts -> FRD y; source y (forward) -4 -> FRD x.
        close(rec.channel("ay").unwrap()[1], 8.0 * 125e-6 * g / 0.01);
        close(rec.channel("ax").unwrap()[1], -4.0 * 125e-6 * g / 0.01);
        // 2 counts x 0.1 arcsec over 0.01 s about up = 20 arcsec/s; FRD z is down.
        close(rec.channel("gz").unwrap()[0], -20.0 * ARCSEC_RAD);
        close(rec.channel("gx").unwrap()[1], 90.0 * ARCSEC_RAD);
        close(rec.channel("gy").unwrap()[1], -70.0 * ARCSEC_RAD);
        // Initial yaw -90.6 deg (PSINS, counter-clockwise) = heading 90.6 deg east in NED.
        close(
            log.header.initial_attitude_ned_rad()[2],
            90.6f64.to_radians(),
        );
    }

    #[test]
    fn bad_lines_name_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("l.imu");
        for (body, line, what) in [
            ("0 0 2 0 0 80\n1 2 3 4 5\n", 6, "5 fields"),
            ("0 0 2 0 0 80\n1 2 3 4 5 6 7\n", 6, "7 fields"),
            ("0 0 2 0 0 80.5\n", 5, "field 6"),
            ("", 4, "no sample lines"),
        ] {
            std::fs::write(&path, format!("{HEAD}{body}")).unwrap();
            let msg = read(&path).unwrap_err().to_string();
            assert!(
                msg.contains(&format!("l.imu: line {line}:")) && msg.contains(what),
                "{msg}"
            );
        }
        std::fs::write(
            &path,
            "0 0 0 0 0 0\n34 108 380 0 0 9.78\n0.1 0.1 0.1 125 125 125\n",
        )
        .unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(msg.contains("line 3") && msg.contains("interval"), "{msg}");
        std::fs::write(&path, "0 0 0 0 0 0\n34 108 x 0 10 9.78\n").unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("line 2") && msg.contains("header line 2"),
            "{msg}"
        );
    }

    /// Regression (fuzzing): a subnormal interval passed the sign check and turned every
    /// count into an infinite rate (0 counts into NaN), imported without an error; a huge
    /// count times a large scale overflowed the same way.
    #[test]
    fn an_interval_or_count_that_overflows_the_rate_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("l.imu");
        std::fs::write(
            &path,
            "0 0 0 0 0 0\n34 108 380 0 1e-320 9.78\n0.1 0.1 0.1 125 125 125\n0 0 0 0 0 0\n",
        )
        .unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("l.imu: line 3") && msg.contains("too small"),
            "{msg}"
        );
        std::fs::write(
            &path,
            "0 0 0 0 0 0\n34 108 380 0 1e-300 9.78\n0.1 0.1 0.1 125 125 125\n\
             0 0 0 0 0 0\n0 9223372036854775807 0 0 0 0\n",
        )
        .unwrap();
        let msg = read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("l.imu: line 5") && msg.contains("field 2") && msg.contains("finite"),
            "{msg}"
        );
    }
}
