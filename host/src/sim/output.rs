//! Writing a simulation: one interchange file per IMU (the reference with attitude, position
//! and velocity columns; CSV, gzip-compressed CSV or Parquet), `gnss.csv`, `pps.csv` and
//! `truth.json`, optionally the error-free `<name>-ideal.csv` of each IMU, and on request the board's view of the MEMS IMUs
//! (`board.replay`, the firmware replay input, and `board.log`, the board log; see
//! [`super::board`]). Files are staged in a hidden folder inside the output
//! folder and moved into place only when all are written, `truth.json` last as the set's
//! completion marker (`crate::output`), so a failed or killed run leaves no partial set.

use std::borrow::Cow;
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::board::{BoardError, BoardRecording};
use super::gnss::{GnssFixes, PpsTable};
use super::SimOutput;
use crate::interchange::{FileFormat, ImuRecording, TableError};
use crate::output::{write_json_atomic, AtomicFile, FileSet};

/// Errors writing a simulation's outputs.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimWriteError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Table(#[from] TableError),
    #[error("{path}: {source}")]
    Board {
        path: PathBuf,
        #[source]
        source: BoardError,
    },
}

/// Name of the firmware replay input written with a board recording.
pub const REPLAY_FILE: &str = "board.replay";
/// Name of the board log written with a board recording.
pub const LOG_FILE: &str = "board.log";
/// Name of the truth file, the completion marker of a simulation's set (written last).
pub const TRUTH_FILE: &str = "truth.json";

/// Writes `out` into `dir` (created if absent); returns the files written.
pub fn write_outputs(
    out: &SimOutput,
    dir: &Path,
    format: FileFormat,
    write_ideal: bool,
) -> Result<Vec<PathBuf>, SimWriteError> {
    write_outputs_with_board(out, dir, format, write_ideal, None)
}

/// Maps an I/O error on `path` to a [`SimWriteError`].
fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> SimWriteError {
    let path = path.to_path_buf();
    move |source| SimWriteError::Io { path, source }
}

/// The set being written (`crate::output::FileSet`, `truth.json` its completion marker).
struct Stage {
    set: FileSet,
}

impl Stage {
    /// Creates `dir` if absent and a staging folder inside it.
    fn new(dir: &Path) -> Result<Self, SimWriteError> {
        let set = FileSet::create(dir, Some(TRUTH_FILE)).map_err(io_error(dir))?;
        Ok(Self { set })
    }

    /// The staged path of `name`, which joins the set.
    fn path(&mut self, name: &str) -> PathBuf {
        self.set.path(name)
    }

    /// Writes the staged file `name` with `write` (compressed when the name ends in `.gz`).
    fn write_file(
        &mut self,
        name: String,
        write: impl FnOnce(&mut dyn Write, &Path) -> Result<(), SimWriteError>,
    ) -> Result<(), SimWriteError> {
        let path = self.path(&name);
        let mut f = AtomicFile::create(&path).map_err(io_error(&path))?;
        {
            let mut w = f.writer();
            write(&mut *w, &path)?;
            w.flush().map_err(io_error(&path))?;
        }
        f.commit().map_err(io_error(&path))
    }

    /// Moves every staged file into the output folder, `truth.json` last; returns their
    /// paths.
    fn commit(self) -> Result<Vec<PathBuf>, SimWriteError> {
        let dir = self.set.dir().to_path_buf();
        self.set.commit().map_err(io_error(&dir))
    }
}

/// Each IMU's recording to write, named `<imu>.<ext>`, then with `write_ideal` each IMU's
/// error-free outputs at the true sampling instants, `<imu>-ideal.<ext>`.
fn imu_files<'a>(
    out: &'a SimOutput,
    ext: &str,
    write_ideal: bool,
) -> Vec<(String, Cow<'a, ImuRecording>)> {
    let runs = || std::iter::once(&out.reference).chain(&out.imus);
    let mut files: Vec<(String, Cow<'a, ImuRecording>)> = runs()
        .map(|run| (format!("{}.{ext}", run.name), Cow::Borrowed(&run.recording)))
        .collect();
    if write_ideal {
        files.extend(runs().filter_map(|run| {
            run.ideal.as_ref().map(|ideal| {
                let recording = ImuRecording {
                    t_s: run.true_t_s.clone(),
                    gyro_rad_s: Some([ideal[0].clone(), ideal[1].clone(), ideal[2].clone()]),
                    accel_m_s2: Some([ideal[3].clone(), ideal[4].clone(), ideal[5].clone()]),
                    ..Default::default()
                };
                (format!("{}-ideal.{ext}", run.name), Cow::Owned(recording))
            })
        }));
    }
    files
}

/// The text of `gnss.csv`: one row per fix with its position and velocity sigmas.
fn gnss_text(g: &GnssFixes) -> String {
    let mut text = String::from("t_s,lat_rad,lon_rad,h_m,vn_m_s,ve_m_s,vd_m_s,sigma_n_m,sigma_e_m,sigma_d_m,sigma_vn_m_s,sigma_ve_m_s,sigma_vd_m_s\n");
    for k in 0..g.t_s.len() {
        let _ = writeln!(
            text,
            "{},{},{},{},{},{},{},{},{},{},{},{},{}",
            g.t_s[k],
            g.position[0][k],
            g.position[1][k],
            g.position[2][k],
            g.velocity_ned_m_s[0][k],
            g.velocity_ned_m_s[1][k],
            g.velocity_ned_m_s[2][k],
            g.sigma_ned_m[0],
            g.sigma_ned_m[1],
            g.sigma_ned_m[2],
            g.sigma_v_ned_m_s[0],
            g.sigma_v_ned_m_s[1],
            g.sigma_v_ned_m_s[2]
        );
    }
    text
}

/// The text of `pps.csv`: GPS time of each edge and every IMU's clock reading there.
fn pps_text(p: &PpsTable) -> String {
    let mut text = String::from("gps_t_s");
    for (imu, _) in &p.local_t_s {
        text.push_str(&format!(",{imu}_local_t_s"));
    }
    text.push('\n');
    for k in 0..p.gps_t_s.len() {
        let _ = write!(text, "{}", p.gps_t_s[k]);
        for (_, col) in &p.local_t_s {
            let _ = write!(text, ",{}", col[k]);
        }
        text.push('\n');
    }
    text
}

/// A writer of `text`, for [`Stage::write_file`].
fn text_writer(text: String) -> impl FnOnce(&mut dyn Write, &Path) -> Result<(), SimWriteError> {
    move |w, path| w.write_all(text.as_bytes()).map_err(io_error(path))
}

/// [`write_outputs`], plus [`REPLAY_FILE`] and [`LOG_FILE`] from `board` when given (never
/// compressed: the firmware and the decoder read them as they are). The IMUs are written in
/// `format`; `gnss` and `pps`, short tables of another shape, as CSV (gzip-compressed with
/// [`FileFormat::CsvGz`]).
pub fn write_outputs_with_board(
    out: &SimOutput,
    dir: &Path,
    format: FileFormat,
    write_ideal: bool,
    board: Option<&BoardRecording>,
) -> Result<Vec<PathBuf>, SimWriteError> {
    let mut stage = Stage::new(dir)?;
    let ext = match format {
        FileFormat::Parquet => FileFormat::Csv,
        text => text,
    }
    .extension();
    let imus = imu_files(out, format.extension(), write_ideal);
    let paths: Vec<PathBuf> = imus.iter().map(|(name, _)| stage.path(name)).collect();
    imus.par_iter()
        .zip(&paths)
        .map(|((_, rec), path)| rec.write(path))
        .collect::<Result<Vec<()>, _>>()?;
    if let Some(g) = &out.gnss {
        stage.write_file(format!("gnss.{ext}"), text_writer(gnss_text(g)))?;
    }
    if let Some(p) = &out.pps {
        stage.write_file(format!("pps.{ext}"), text_writer(pps_text(p)))?;
    }
    if let Some(board) = board {
        type Writer = fn(&BoardRecording, &mut dyn Write) -> Result<(), BoardError>;
        let files: [(&str, Writer); 2] = [
            (REPLAY_FILE, BoardRecording::write_replay),
            (LOG_FILE, BoardRecording::write_log),
        ];
        for (name, write) in files {
            stage.write_file(name.to_string(), |w, path| {
                write(board, w).map_err(|source| SimWriteError::Board {
                    path: path.to_path_buf(),
                    source,
                })
            })?;
        }
    }
    let truth_path = stage.path(TRUTH_FILE);
    write_json_atomic(&truth_path, &out.truth).map_err(io_error(&truth_path))?;
    stage.commit()
}
