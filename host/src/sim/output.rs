//! Writing a simulation: one interchange CSV per IMU (the reference with attitude, position
//! and velocity columns), `gnss.csv`, `pps.csv` and `truth.json`, optionally the error-free
//! `<name>-ideal.csv` of each IMU, and on request the board's view of the MEMS IMUs
//! (`board.replay`, the firmware replay input, and `board.log`, the board log; see
//! [`super::board`]). Files are staged in a hidden folder inside the output
//! folder and moved into place only when all are written, `truth.json` last, so a failed
//! run leaves no partial set.

use std::io::Write;
use std::path::{Path, PathBuf};

use super::board::{BoardError, BoardRecording};
use super::SimOutput;
use crate::interchange::{ImuRecording, TableError};
use crate::output::{write_json_atomic, AtomicFile};

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

/// Writes `out` into `dir` (created if absent); returns the files written.
pub fn write_outputs(
    out: &SimOutput,
    dir: &Path,
    gzip: bool,
    write_ideal: bool,
) -> Result<Vec<PathBuf>, SimWriteError> {
    write_outputs_with_board(out, dir, gzip, write_ideal, None)
}

/// [`write_outputs`], plus [`REPLAY_FILE`] and [`LOG_FILE`] from `board` when given (never
/// compressed: the firmware and the decoder read them as they are).
pub fn write_outputs_with_board(
    out: &SimOutput,
    dir: &Path,
    gzip: bool,
    write_ideal: bool,
    board: Option<&BoardRecording>,
) -> Result<Vec<PathBuf>, SimWriteError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| SimWriteError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let stage = tempfile::Builder::new()
        .prefix(".dynacal-partial-")
        .tempdir_in(dir)
        .map_err(io(dir))?;
    let ext = if gzip { "csv.gz" } else { "csv" };
    let mut names: Vec<String> = Vec::new();
    let mut jobs: Vec<(String, &ImuRecording)> = Vec::new();
    for run in std::iter::once(&out.reference).chain(&out.imus) {
        jobs.push((format!("{}.{ext}", run.name), &run.recording));
    }
    let ideal_recordings: Vec<(String, ImuRecording)> = if write_ideal {
        std::iter::once(&out.reference)
            .chain(&out.imus)
            .filter_map(|run| {
                run.ideal.as_ref().map(|ideal| {
                    (
                        format!("{}-ideal.{ext}", run.name),
                        ImuRecording {
                            t_s: run.true_t_s.clone(),
                            gyro_rad_s: Some([
                                ideal[0].clone(),
                                ideal[1].clone(),
                                ideal[2].clone(),
                            ]),
                            accel_m_s2: Some([
                                ideal[3].clone(),
                                ideal[4].clone(),
                                ideal[5].clone(),
                            ]),
                            ..Default::default()
                        },
                    )
                })
            })
            .collect()
    } else {
        Vec::new()
    };
    for (name, rec) in &ideal_recordings {
        jobs.push((name.clone(), rec));
    }
    use rayon::prelude::*;
    jobs.par_iter()
        .map(|(name, rec)| rec.write(&stage.path().join(name)))
        .collect::<Result<Vec<()>, _>>()?;
    names.extend(jobs.iter().map(|(n, _)| n.clone()));

    if let Some(g) = &out.gnss {
        let name = format!("gnss.{ext}");
        let path = stage.path().join(&name);
        let mut f = AtomicFile::create(&path).map_err(io(&path))?;
        {
            let mut w = f.writer();
            let mut text = String::from("t_s,lat_rad,lon_rad,h_m,vn_m_s,ve_m_s,vd_m_s,sigma_n_m,sigma_e_m,sigma_d_m,sigma_vn_m_s,sigma_ve_m_s,sigma_vd_m_s\n");
            use std::fmt::Write as _;
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
            w.write_all(text.as_bytes()).map_err(io(&path))?;
            w.flush().map_err(io(&path))?;
        }
        f.commit().map_err(io(&path))?;
        names.push(name);
    }
    if let Some(p) = &out.pps {
        let name = format!("pps.{ext}");
        let path = stage.path().join(&name);
        let mut f = AtomicFile::create(&path).map_err(io(&path))?;
        {
            let mut w = f.writer();
            let mut text = String::from("gps_t_s");
            for (imu, _) in &p.local_t_s {
                text.push_str(&format!(",{imu}_local_t_s"));
            }
            text.push('\n');
            use std::fmt::Write as _;
            for k in 0..p.gps_t_s.len() {
                let _ = write!(text, "{}", p.gps_t_s[k]);
                for (_, col) in &p.local_t_s {
                    let _ = write!(text, ",{}", col[k]);
                }
                text.push('\n');
            }
            w.write_all(text.as_bytes()).map_err(io(&path))?;
            w.flush().map_err(io(&path))?;
        }
        f.commit().map_err(io(&path))?;
        names.push(name);
    }
    if let Some(board) = board {
        type Writer = fn(&BoardRecording, &mut dyn Write) -> Result<(), BoardError>;
        let files: [(&str, Writer); 2] = [
            (REPLAY_FILE, BoardRecording::write_replay),
            (LOG_FILE, BoardRecording::write_log),
        ];
        for (name, write) in files {
            let path = stage.path().join(name);
            let mut f = AtomicFile::create(&path).map_err(io(&path))?;
            {
                let mut w = f.writer();
                write(board, &mut *w).map_err(|source| SimWriteError::Board {
                    path: path.clone(),
                    source,
                })?;
                w.flush().map_err(io(&path))?;
            }
            f.commit().map_err(io(&path))?;
            names.push(name.to_string());
        }
    }
    let truth_path = stage.path().join("truth.json");
    write_json_atomic(&truth_path, &out.truth).map_err(io(&truth_path))?;
    names.push("truth.json".into());

    let mut written = Vec::new();
    for name in &names {
        let from = stage.path().join(name);
        let to = dir.join(name);
        std::fs::rename(&from, &to).map_err(io(&to))?;
        written.push(to);
    }
    Ok(written)
}
