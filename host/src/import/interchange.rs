//! An interchange recording given to `import` (a CSV, CSV.gz or Parquet file with `t_s` and
//! interchange columns, as `simulate`, `decode` or an earlier import wrote it): written again
//! in the form `--format` asks, so a long CSV becomes a Parquet file, or a Parquet file text,
//! without being loaded. Rows pass one at a time, checked as a read checks them (every field a
//! finite number, `t_s` strictly increasing, latitude and longitude in range, triplets
//! whole); the stated rate is carried over after a check against the first steps. Columns
//! that are not the format's (a temperature, a counter) are not carried.

use std::path::Path;

use super::rows::{SensorLayout, SensorRows};
use super::ImportError;
use crate::interchange::parquet;
use crate::interchange::{
    check_lat_lon, check_stated_rate, for_each_row, interchange_columns, is_interchange_column,
    read_stated_rate, TableError, TableRows,
};

/// Steps of time the stated rate is checked on: the median step over them must agree with
/// it to 1%, as a whole-file read requires of every step's median.
const RATE_CHECK_ROWS: usize = 1 << 16;

/// Whether `path` is an interchange recording: `t_s` and at least one other column of the
/// format (a channel, attitude, position, velocity). A text file that cannot be read as a
/// table is not one; a Parquet file whose columns cannot be read (its footer is missing: a
/// file cut short in a copy) is taken as one, so that reading it names that fault rather
/// than calling the file unknown.
pub(crate) fn is_interchange(path: &Path) -> bool {
    match headers(path) {
        Ok(h) => h.iter().any(|c| c == "t_s") && h.iter().any(|c| is_interchange_column(c)),
        Err(_) => parquet::is_parquet(path),
    }
}

/// The columns of the recording at `path` that a conversion does not carry (not the
/// format's), in file order.
pub(crate) fn left_out_columns(path: &Path) -> Result<Vec<String>, TableError> {
    let headers = headers(path)?;
    let carried = interchange_columns(path, &headers)?;
    Ok(headers
        .into_iter()
        .filter(|h| !carried.contains(&h.as_str()))
        .collect())
}

/// The names of the file's columns (a CSV's header, a Parquet file's flat columns).
fn headers(path: &Path) -> Result<Vec<String>, TableError> {
    if parquet::is_parquet(path) {
        parquet::headers(path)
    } else {
        Ok(TableRows::open(path, None)?.headers().to_vec())
    }
}

/// Streams the recording's interchange columns into `sink`, checked row by row.
pub(crate) fn stream(path: &Path, sink: &mut dyn SensorRows) -> Result<(), ImportError> {
    let stated = read_stated_rate(path)?;
    let columns = interchange_columns(path, &headers(path)?)?;
    sink.begin(vec![SensorLayout {
        name: String::new(),
        columns: columns.clone(),
        rate_hz: stated.as_ref().map(|(_, rate)| *rate),
    }])?;
    let mut checks = RowChecks::new(path, &columns);
    for_each_row(path, &columns, |_, row| -> Result<(), ImportError> {
        checks.check(row)?;
        sink.push(0, row)
    })?;
    if let Some((place, stated_hz)) = stated {
        check_stated_rate(path, place, stated_hz, &checks.first_t_s)?;
    }
    Ok(())
}

/// The checks a row passes that the table readers do not make.
struct RowChecks<'a> {
    path: &'a Path,
    /// Where latitude and longitude are in a row, if the recording has a position.
    lat_lon: Option<(usize, usize)>,
    /// The first [`RATE_CHECK_ROWS`] times, s.
    first_t_s: Vec<f64>,
}

impl<'a> RowChecks<'a> {
    fn new(path: &'a Path, columns: &[&str]) -> Self {
        let at = |name: &str| columns.iter().position(|c| *c == name);
        Self {
            path,
            lat_lon: at("lat_rad").zip(at("lon_rad")),
            first_t_s: Vec::new(),
        }
    }

    /// Checks `row` (in the layout's column order, `t_s` first).
    fn check(&mut self, row: &[f64]) -> Result<(), TableError> {
        if self.first_t_s.len() <= RATE_CHECK_ROWS {
            self.first_t_s.push(row[0]);
        }
        match self.lat_lon {
            Some((lat, lon)) => check_lat_lon(self.path, row[0], row[lat], row[lon]),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::import::{detect, import_to_dir, Dataset};
    use crate::interchange::{FileFormat, ImuRecording};

    /// `n` samples at 100 Hz of a unit at rest with a position: gyro (rad/s) and
    /// accelerometer (m/s^2) values with every significant digit used.
    fn recording(n: usize) -> ImuRecording {
        let t_s: Vec<f64> = (0..n).map(|k| k as f64 / 100.0).collect();
        let wave = |scale: f64, phase: f64, offset: f64| -> Vec<f64> {
            (0..n)
                .map(|k| offset + scale * (0.37 * k as f64 + phase).sin())
                .collect()
        };
        ImuRecording {
            gyro_rad_s: Some([
                wave(1e-3, 0.0, 0.0),
                wave(1e-3, 1.0, 0.0),
                wave(1e-3, 2.0, 0.0),
            ]),
            accel_m_s2: Some([
                wave(0.02, 3.0, 0.0),
                wave(0.02, 4.0, 0.0),
                wave(0.02, 5.0, -9.81),
            ]),
            position: Some([
                wave(0.0, 0.0, 0.81),
                wave(0.0, 0.0, 0.12),
                wave(0.1, 0.0, 400.0),
            ]),
            sample_rate_hz: Some(100.0),
            t_s,
            ..Default::default()
        }
    }

    #[test]
    fn a_csv_recording_becomes_parquet_and_back_to_the_bit() {
        let dir = tempfile::tempdir().unwrap();
        let csv = dir.path().join("unit.csv");
        // More rows than the rate check reads and than a Parquet read block holds.
        let original = recording(70_001);
        original.write(&csv).unwrap();
        assert_eq!(detect(&csv).unwrap(), Some(Dataset::Interchange));
        let report = import_to_dir(&csv, &dir.path().join("pq"), FileFormat::Parquet).unwrap();
        let parquet_file = dir.path().join("pq").join("unit.parquet");
        assert_eq!(report.written[0].path, parquet_file);
        assert_eq!(report.written[0].samples, 70_001);
        assert_eq!(ImuRecording::read(&parquet_file).unwrap(), original);
        assert_eq!(detect(&parquet_file).unwrap(), Some(Dataset::Interchange));
        import_to_dir(&parquet_file, &dir.path().join("text"), FileFormat::Csv).unwrap();
        let text = dir.path().join("text").join("unit.csv");
        assert_eq!(ImuRecording::read(&text).unwrap(), original);
        assert_eq!(std::fs::read(&text).unwrap(), std::fs::read(&csv).unwrap());
    }

    #[test]
    fn other_columns_are_left_and_a_bad_row_refused_with_nothing_written() {
        let dir = tempfile::tempdir().unwrap();
        let csv = dir.path().join("unit.csv");
        let mut text = String::from("# sample_rate_hz: 100\nt_s,temp_c,gx_rad_s\n");
        for k in 0..300 {
            text.push_str(&format!(
                "{},{},{}\n",
                k as f64 / 100.0,
                20 + k,
                1e-3 * k as f64
            ));
        }
        std::fs::write(&csv, &text).unwrap();
        let out = dir.path().join("out");
        import_to_dir(&csv, &out, FileFormat::Parquet).unwrap();
        let written = crate::interchange::parquet::headers(&out.join("unit.parquet")).unwrap();
        assert_eq!(written, ["t_s", "gx_rad_s"]);
        let report = import_to_dir(&csv, &dir.path().join("again"), FileFormat::Csv).unwrap();
        assert_eq!(report.written[0].left_out, ["temp_c"]);
        std::fs::write(&csv, text.replace("\n1.5,170,", "\n1.4,170,")).unwrap();
        let bad_out = dir.path().join("bad");
        let message = import_to_dir(&csv, &bad_out, FileFormat::Parquet)
            .unwrap_err()
            .to_string();
        assert!(message.contains("unit.csv: line 153"), "{message}");
        assert!(!bad_out.exists());
        std::fs::write(&csv, "t_s,temp_c\n0,20\n0.01,21\n").unwrap();
        assert_eq!(detect(&csv).unwrap(), None);
    }
}
