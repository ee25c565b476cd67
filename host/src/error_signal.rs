//! The error-signal file: per-axis sensor errors (sensor minus reference, in the reference
//! body frame) with the dynamics quantities of paper Section III beside them. Written by
//! `dynacal errors`, read by `dynacal regress` and `dynacal diagnose`.
//!
//! Columns (CSV or CSV.gz, header row): `t_s`; errors `gx_err_rad_s gy_err_rad_s
//! gz_err_rad_s ax_err_m_s2 ay_err_m_s2 az_err_m_s2`; dynamics in the body frame (FRD):
//! angular rate `omega_{x,y,z}_rad_s`, angular acceleration `omega_dot_{x,y,z}_rad_s2`,
//! angular jerk `omega_ddot_{x,y,z}_rad_s3`, linear acceleration (specific force plus
//! gravity) `a_{x,y,z}_m_s2` and linear jerk `a_dot_{x,y,z}_m_s3`.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::interchange::{
    check_time_increasing, check_time_increasing_at, read_table, TableError, CHANNELS,
};
use crate::output::AtomicFile;
use crate::regress::DYNAMICS_REGRESSORS;

/// Error column names, in [`CHANNELS`] order.
pub const ERROR_COLUMNS: [&str; 6] = [
    "gx_err_rad_s",
    "gy_err_rad_s",
    "gz_err_rad_s",
    "ax_err_m_s2",
    "ay_err_m_s2",
    "az_err_m_s2",
];

/// Dynamics column names, in [`DYNAMICS_REGRESSORS`] order (the regressor name plus unit).
pub const DYNAMICS_COLUMNS: [&str; 15] = [
    "omega_x_rad_s",
    "omega_y_rad_s",
    "omega_z_rad_s",
    "omega_dot_x_rad_s2",
    "omega_dot_y_rad_s2",
    "omega_dot_z_rad_s2",
    "omega_ddot_x_rad_s3",
    "omega_ddot_y_rad_s3",
    "omega_ddot_z_rad_s3",
    "a_x_m_s2",
    "a_y_m_s2",
    "a_z_m_s2",
    "a_dot_x_m_s3",
    "a_dot_y_m_s3",
    "a_dot_z_m_s3",
];

/// The error of a file at `path` that has none of [`ERROR_COLUMNS`].
pub(crate) fn no_error_column(path: &Path) -> TableError {
    TableError::Csv {
        path: path.to_path_buf(),
        line: 1,
        message: format!(
            "no error column ({} .. {}): not an error-signal file of `dynacal errors`",
            ERROR_COLUMNS[0],
            ERROR_COLUMNS[ERROR_COLUMNS.len() - 1]
        ),
    }
}

/// Sensor errors with the dynamics they occurred under, column by column.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ErrorSignals {
    /// Epoch times, seconds, strictly increasing.
    pub t_s: Vec<f64>,
    /// Errors per channel in [`CHANNELS`] order (rad/s for gyros, m/s^2 for accelerometers);
    /// `None` where the sensor lacks the channel.
    pub errors: [Option<Vec<f64>>; 6],
    /// The 15 dynamics quantities in [`DYNAMICS_REGRESSORS`] order.
    pub dynamics: [Vec<f64>; 15],
    /// Reference specific force in the body frame, m/s^2 (columns `f_{x,y,z}_m_s2`;
    /// optional): what accelerometer scale factors and gyro g-sensitivity act on.
    pub specific_force_b_m_s2: Option<[Vec<f64>; 3]>,
}

/// Specific-force column names.
pub const SPECIFIC_FORCE_COLUMNS: [&str; 3] = ["f_x_m_s2", "f_y_m_s2", "f_z_m_s2"];

impl ErrorSignals {
    /// The error series of a channel (`gx` ... `az`).
    pub fn error(&self, channel: &str) -> Option<&[f64]> {
        let i = CHANNELS.iter().position(|c| *c == channel)?;
        self.errors[i].as_deref()
    }

    /// The error series of `channel`, if the sensor has it.
    pub fn error_of(&self, channel: crate::model::Channel) -> Option<&[f64]> {
        self.errors[channel.index()].as_deref()
    }

    /// Angular rate about body axis `axis` (0 = x, 1 = y, 2 = z), rad/s.
    pub fn angular_rate_rad_s(&self, axis: usize) -> &[f64] {
        &self.dynamics[axis]
    }

    /// Angular acceleration about body axis `axis`, rad/s^2.
    pub fn angular_acceleration_rad_s2(&self, axis: usize) -> &[f64] {
        &self.dynamics[3 + axis]
    }

    /// Angular jerk about body axis `axis`, rad/s^3.
    pub fn angular_jerk_rad_s3(&self, axis: usize) -> &[f64] {
        &self.dynamics[6 + axis]
    }

    /// Linear acceleration (specific force plus gravity) along body axis `axis`, m/s^2.
    pub fn linear_acceleration_m_s2(&self, axis: usize) -> &[f64] {
        &self.dynamics[9 + axis]
    }

    /// Linear jerk along body axis `axis`, m/s^3.
    pub fn linear_jerk_m_s3(&self, axis: usize) -> &[f64] {
        &self.dynamics[12 + axis]
    }

    /// The dynamics regressors as (name, values) pairs, ready for regression.
    pub fn regressors(&self) -> Vec<(&'static str, &[f64])> {
        DYNAMICS_REGRESSORS
            .iter()
            .zip(self.dynamics.iter())
            .map(|(n, v)| (*n, v.as_slice()))
            .collect()
    }

    /// Reads an error-signal file; all dynamics columns and at least one error column are
    /// required.
    pub fn read(path: &Path) -> Result<Self, TableError> {
        let table = read_table(path, None)?;
        let col = |name: &str| -> Result<Vec<f64>, TableError> {
            table
                .column(name)
                .map(<[f64]>::to_vec)
                .ok_or_else(|| TableError::MissingColumn {
                    path: path.to_path_buf(),
                    column: name.to_string(),
                })
        };
        let t_s = col("t_s")?;
        check_time_increasing_at(path, &t_s, table.row_lines)?;
        let errors = ERROR_COLUMNS.map(|c| table.column(c).map(<[f64]>::to_vec));
        if errors.iter().all(Option::is_none) {
            return Err(no_error_column(path));
        }
        let mut dynamics: [Vec<f64>; 15] = Default::default();
        for (slot, name) in dynamics.iter_mut().zip(DYNAMICS_COLUMNS) {
            *slot = col(name)?;
        }
        if t_s.is_empty() {
            return Err(TableError::Empty {
                path: path.to_path_buf(),
            });
        }
        let specific_force_b_m_s2 = if SPECIFIC_FORCE_COLUMNS
            .iter()
            .all(|c| table.index(c).is_some())
        {
            Some(
                SPECIFIC_FORCE_COLUMNS
                    .map(|c| table.column(c).map(<[f64]>::to_vec).unwrap_or_default()),
            )
        } else {
            None
        };
        Ok(Self {
            t_s,
            errors,
            dynamics,
            specific_force_b_m_s2,
        })
    }

    /// Writes the file whole or not at all (gzip when the name ends in `.gz`, Parquet when
    /// it ends in `.parquet`).
    pub fn write(&self, path: &Path) -> Result<(), TableError> {
        let n = self.t_s.len();
        let mut columns: Vec<&[f64]> = vec![&self.t_s];
        let mut names = vec!["t_s"];
        for (name, e) in ERROR_COLUMNS.iter().zip(&self.errors) {
            if let Some(e) = e {
                columns.push(e);
                names.push(name);
            }
        }
        for (name, d) in DYNAMICS_COLUMNS.iter().zip(&self.dynamics) {
            columns.push(d);
            names.push(name);
        }
        if let Some(f) = &self.specific_force_b_m_s2 {
            for (name, d) in SPECIFIC_FORCE_COLUMNS.iter().zip(f) {
                columns.push(d);
                names.push(name);
            }
        }
        for (name, c) in names.iter().zip(&columns) {
            if c.len() != n {
                return Err(TableError::LengthMismatch {
                    path: path.to_path_buf(),
                    column: (*name).to_string(),
                    len: c.len(),
                    expected: n,
                });
            }
        }
        check_time_increasing(path, &self.t_s)?;
        let present = self.errors.each_ref().map(Option::is_some);
        let mut out =
            ErrorSignalWriter::create(path, present, self.specific_force_b_m_s2.is_some())?;
        let mut row = vec![0.0; columns.len()];
        for k in 0..n {
            row.iter_mut().zip(&columns).for_each(|(v, c)| *v = c[k]);
            out.push(&row)?;
        }
        out.finish()
    }
}

/// An error-signal file written one row at a time, in memory that does not grow with it (a
/// streamed calibration, and [`ErrorSignals::write`]): CSV text, gzip-compressed when the
/// name ends in `.gz`, or Parquet when it ends in `.parquet`. Rows are `t_s`, the error
/// columns present, the 15 dynamics, and the specific force when present, in
/// [`ErrorSignalWriter::columns`] order; time must strictly increase. The file appears
/// whole on [`ErrorSignalWriter::finish`], or not at all.
pub struct ErrorSignalWriter {
    path: PathBuf,
    file: AtomicFile,
    sink: SignalSink,
    columns: Vec<&'static str>,
    rows: u64,
    previous_t_s: f64,
}

/// Where an [`ErrorSignalWriter`]'s rows go.
enum SignalSink {
    Text {
        out: Box<dyn Write + Send>,
        line: Vec<u8>,
        digits: zmij::Buffer,
    },
    Parquet(crate::interchange::parquet::ParquetSink),
}

impl ErrorSignalWriter {
    /// Starts `path` with the error columns `errors` says are present (gx .. az) and the
    /// specific force when `specific_force`.
    pub fn create(
        path: &Path,
        errors: [bool; 6],
        specific_force: bool,
    ) -> Result<Self, TableError> {
        let io = |source| TableError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut columns = vec!["t_s"];
        columns.extend(
            ERROR_COLUMNS
                .iter()
                .zip(errors)
                .filter(|e| e.1)
                .map(|e| *e.0),
        );
        columns.extend(DYNAMICS_COLUMNS);
        if specific_force {
            columns.extend(SPECIFIC_FORCE_COLUMNS);
        }
        let file = AtomicFile::create(path).map_err(io)?;
        let mut out = file.owned_writer().map_err(io)?;
        let sink = if crate::interchange::parquet::writes_parquet(path) {
            SignalSink::Parquet(crate::interchange::parquet::ParquetSink::create(
                path, out, &columns,
            )?)
        } else {
            writeln!(out, "{}", columns.join(",")).map_err(io)?;
            SignalSink::Text {
                out,
                line: Vec::with_capacity(1 << 16),
                digits: zmij::Buffer::new(),
            }
        };
        Ok(Self {
            path: path.to_path_buf(),
            file,
            sink,
            columns,
            rows: 0,
            previous_t_s: f64::NEG_INFINITY,
        })
    }

    /// The file's columns, in the order rows give them.
    pub fn columns(&self) -> &[&'static str] {
        &self.columns
    }

    /// Appends one row, one value per column.
    pub fn push(&mut self, row: &[f64]) -> Result<(), TableError> {
        assert_eq!(row.len(), self.columns.len(), "one value per column");
        self.rows += 1;
        if !(row[0] > self.previous_t_s) {
            return Err(TableError::TimeNotIncreasingAtSample {
                path: self.path.clone(),
                sample: self.rows,
                t_s: row[0],
                previous_t_s: self.previous_t_s,
            });
        }
        self.previous_t_s = row[0];
        let io = |source| TableError::Io {
            path: self.path.clone(),
            source,
        };
        match &mut self.sink {
            SignalSink::Parquet(sink) => sink.push(row),
            SignalSink::Text { out, line, digits } => {
                for (k, value) in row.iter().enumerate() {
                    if k > 0 {
                        line.push(b',');
                    }
                    crate::interchange::push_f64_display(line, *value, digits);
                }
                line.push(b'\n');
                if line.len() >= (1 << 16) - 1024 {
                    out.write_all(line).map_err(io)?;
                    line.clear();
                }
                Ok(())
            }
        }
    }

    /// Writes what is held and moves the file into place; a file with no row is an error
    /// (and is not written).
    pub fn finish(self) -> Result<(), TableError> {
        let io = |source| TableError::Io {
            path: self.path.clone(),
            source,
        };
        if self.rows == 0 {
            return Err(TableError::Empty { path: self.path });
        }
        match self.sink {
            SignalSink::Parquet(sink) => sink.finish(None)?,
            SignalSink::Text { mut out, line, .. } => {
                out.write_all(&line).map_err(io)?;
                out.flush().map_err(io)?;
            }
        }
        self.file.commit().map_err(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_missing_dynamics_column_is_named() {
        let n = 4;
        let sig = ErrorSignals {
            t_s: vec![0.0, 0.1, 0.2, 0.3],
            errors: [
                Some(vec![1.0, 2.0, 3.0, 4.5]),
                None,
                None,
                None,
                None,
                Some(vec![0.0; 4]),
            ],
            dynamics: std::array::from_fn(|k| (0..n).map(|i| (k * 10 + i) as f64 / 7.0).collect()),
            specific_force_b_m_s2: Some([vec![0.5; 4], vec![0.25; 4], vec![-9.75; 4]]),
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("e.csv.gz");
        sig.write(&path).unwrap();
        assert_eq!(ErrorSignals::read(&path).unwrap(), sig);

        let bad = dir.path().join("bad.csv");
        std::fs::write(&bad, "t_s,gx_err_rad_s\n0,1\n").unwrap();
        let msg = ErrorSignals::read(&bad).unwrap_err().to_string();
        assert!(
            msg.contains("omega_x_rad_s") && msg.contains("bad.csv"),
            "{msg}"
        );
    }
}
