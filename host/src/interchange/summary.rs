//! What an interchange file holds, in memory that does not grow with it: the columns to
//! read (shared with the calibration's spilled reader), and `dynacal info`'s summary, of a
//! long file from one streamed pass and a few more for the median step (radix selection by
//! passes, [`crate::numeric::select_by_passes`]; a short file is read whole, faster). The checks are [`super::ImuRecording::read`]'s:
//! finite numbers, strictly increasing time, whole triplets, latitude and longitude in
//! range, a stated rate that agrees with the median step; errors name the file and the line
//! (CSV) or row (Parquet).

use std::path::Path;

use super::fast::for_each_fast_row;
use super::{
    check_lat_lon, check_stated_rate_against, for_each_row, parquet, read_stated_rate,
    triplet_presence, TableError, TableRows, TripletPresence, CHANNELS, CHANNEL_COLUMNS, TRIPLETS,
};

/// The interchange columns of a file, as read.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Columns {
    /// `t_s`, then each whole triplet's three columns in [`TRIPLETS`] order.
    pub wanted: Vec<&'static str>,
    /// Which triplets (gyro, accelerometer, attitude, position, velocity) are whole.
    pub whole: [bool; 5],
    /// Where `lat_rad` stands among `wanted`, if the position is there.
    pub lat_at: Option<usize>,
    /// Gyro or accelerometer axes present alone (indices into [`CHANNEL_COLUMNS`]).
    pub lone_axes: Vec<usize>,
}

/// The interchange columns of the file at `path` (CSV, CSV.gz or Parquet), from its header:
/// `t_s` must be there, and a triplet whole, absent or (gyro, accelerometer) one axis alone.
pub(crate) fn interchange_columns(path: &Path) -> Result<Columns, TableError> {
    let headers = if parquet::is_parquet(path) {
        parquet::headers(path)?
    } else {
        TableRows::open(path, None)?.headers().to_vec()
    };
    let has = |name: &str| headers.iter().any(|h| h == name);
    if !has("t_s") {
        return Err(TableError::MissingColumn {
            path: path.to_path_buf(),
            column: "t_s".into(),
        });
    }
    let mut columns = Columns {
        wanted: vec!["t_s"],
        whole: [false; 5],
        lat_at: None,
        lone_axes: Vec::new(),
    };
    for (k, names) in TRIPLETS.iter().enumerate() {
        match triplet_presence(path, names, names.map(has))? {
            TripletPresence::Absent => {}
            TripletPresence::LoneAxis { channel } => columns.lone_axes.push(channel),
            TripletPresence::Full => {
                if names[0] == "lat_rad" {
                    columns.lat_at = Some(columns.wanted.len());
                }
                columns.whole[k] = true;
                columns.wanted.extend_from_slice(&names[..]);
            }
        }
    }
    Ok(columns)
}

/// The size and sampling of an interchange file.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Samples (data rows).
    pub samples: u64,
    /// Time of the first and of the last sample, s.
    pub span_t_s: (f64, f64),
    /// The rate the file states (`# sample_rate_hz`, or a Parquet file's metadata), Hz.
    pub stated_rate_hz: Option<f64>,
    /// The median step between successive times, s (None for a single sample).
    pub median_step_s: Option<f64>,
    /// The gyro and accelerometer channels it holds, in [`CHANNELS`] order.
    pub channels: Vec<&'static str>,
}

/// The summary of the interchange file at `path`: a file up to
/// [`crate::input::stream::STREAM_THRESHOLD_BYTES`] on disk read whole (about three times
/// faster: one pass), a larger one streamed ([`summarise_streamed`]).
pub fn summarise(path: &Path) -> Result<Summary, TableError> {
    let large = std::fs::metadata(path)
        .is_ok_and(|m| m.len() > crate::input::stream::STREAM_THRESHOLD_BYTES);
    if large {
        return summarise_streamed(path);
    }
    let whole = super::ImuRecording::read(path)?;
    Ok(Summary {
        samples: whole.len() as u64,
        span_t_s: (whole.t_s[0], whole.t_s[whole.len() - 1]),
        stated_rate_hz: whole.sample_rate_hz,
        median_step_s: super::median_step_s(&whole.t_s),
        channels: whole.channels(),
    })
}

/// The summary of the interchange file at `path`, read as the module's note says.
pub fn summarise_streamed(path: &Path) -> Result<Summary, TableError> {
    let columns = interchange_columns(path)?;
    let mut wanted = columns.wanted.clone();
    wanted.extend(columns.lone_axes.iter().map(|&c| CHANNEL_COLUMNS[c]));
    let mut span = Span::default();
    let lat_ok = |row: &[f64]| {
        columns.lat_at.map_or(Ok(()), |at| {
            check_lat_lon(path, row[0], row[at], row[at + 1])
        })
    };
    let fast = for_each_fast_row(path, &wanted, |row| -> Result<bool, TableError> {
        let ok = lat_ok(row).is_ok();
        if ok {
            span.add(row[0]);
        }
        Ok(ok)
    })?;
    if !fast {
        // The row reader names the line of whatever the fast reader refused.
        span = Span::default();
        for_each_row(path, &wanted, |_, row: &[f64]| -> Result<(), TableError> {
            lat_ok(row)?;
            span.add(row[0]);
            Ok(())
        })?;
    }
    let samples = span.samples;
    let median_step_s = crate::numeric::select_by_passes(samples.saturating_sub(1) / 2, |visit| {
        let mut steps = crate::numeric::TimeSteps::new(visit);
        let read = if fast {
            for_each_fast_row(path, &["t_s"], |row| -> Result<bool, TableError> {
                steps.push(row[0]);
                Ok(true)
            })
            .map(|_| ())
        } else {
            for_each_row(path, &["t_s"], |_, row: &[f64]| -> Result<(), TableError> {
                steps.push(row[0]);
                Ok(())
            })
        };
        steps.finish();
        read
    })?;
    let stated = read_stated_rate(path)?;
    let stated_rate_hz = stated.as_ref().map(|(_, rate)| *rate);
    if let Some((place, stated_hz)) = stated {
        check_stated_rate_against(path, place, stated_hz, median_step_s)?;
    }
    let held = |c: usize| columns.whole[c / 3] || columns.lone_axes.contains(&c);
    Ok(Summary {
        samples,
        span_t_s: (span.first_t_s, span.last_t_s),
        stated_rate_hz,
        median_step_s,
        channels: (0..CHANNELS.len())
            .filter(|&c| held(c))
            .map(|c| CHANNELS[c])
            .collect(),
    })
}

/// How many times a pass saw, and the first and last.
#[derive(Default)]
struct Span {
    samples: u64,
    first_t_s: f64,
    last_t_s: f64,
}

impl Span {
    fn add(&mut self, t_s: f64) {
        if self.samples == 0 {
            self.first_t_s = t_s;
        }
        self.last_t_s = t_s;
        self.samples += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interchange::ImuRecording;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// 2 000 samples of a 100 Hz IMU with a stamp jitter of 0.1 ms, stated at 100 Hz.
    fn recording() -> ImuRecording {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        let noise = Normal::new(0.0, 1.0).unwrap();
        let n = 2_000;
        let t_s: Vec<f64> = (0..n)
            .map(|i| 3.0 + i as f64 * 0.01 + 1e-4 * noise.sample(&mut rng))
            .collect();
        let mut series = || (0..n).map(|_| noise.sample(&mut rng)).collect::<Vec<f64>>();
        ImuRecording {
            gyro_rad_s: Some([series(), series(), series()]),
            accel_m_s2: Some([series(), series(), series()]),
            t_s,
            sample_rate_hz: Some(100.0),
            ..Default::default()
        }
    }

    /// Streamed, a file's summary is what the file read whole says, in every form.
    #[test]
    fn the_summary_is_what_the_whole_file_says() {
        let dir = tempfile::tempdir().unwrap();
        let written = recording();
        for name in ["r.csv", "r.csv.gz", "r.parquet"] {
            let path = dir.path().join(name);
            written.write(&path).unwrap();
            let whole = ImuRecording::read(&path).unwrap();
            let summary = summarise_streamed(&path).unwrap();
            assert_eq!(summarise(&path).unwrap(), summary, "{name}");
            assert_eq!(summary.samples, whole.len() as u64, "{name}");
            assert_eq!(summary.span_t_s, (whole.t_s[0], whole.t_s[whole.len() - 1]));
            assert_eq!(summary.median_step_s, Some(whole.median_dt_s()), "{name}");
            assert_eq!(summary.stated_rate_hz, Some(100.0));
            assert_eq!(summary.channels, whole.channels(), "{name}");
        }
    }

    /// A lone gyro axis is a channel; no stated rate is none.
    #[test]
    fn a_lone_axis_is_a_channel() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("z.csv");
        std::fs::write(&path, "t_s,gz_rad_s\n0,1\n0.5,2\n1.5,3\n2,4\n").unwrap();
        let summary = summarise_streamed(&path).unwrap();
        assert_eq!(summarise(&path).unwrap(), summary);
        assert_eq!(summary.channels, ["gz"]);
        assert_eq!(summary.stated_rate_hz, None);
        assert_eq!(summary.median_step_s, Some(0.5));
        assert_eq!((summary.samples, summary.span_t_s), (4, (0.0, 2.0)));
    }

    /// Bad files are refused as a whole read refuses them, naming the file and the line.
    #[test]
    fn bad_files_are_refused_naming_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("t_s,gx_rad_s\n0,1\n0.01,2\n0.005,3\n", "line 4"),
            ("t_s,gx_rad_s\n0,1\n0.01,x\n", "line 3"),
            ("t_s,gx_rad_s,gy_rad_s\n0,1,2\n", "needs `gz_rad_s`"),
            ("t_s,gx_rad_s\n", "no data rows"),
            ("gx_rad_s\n1\n", "missing required column `t_s`"),
            (
                "# sample_rate_hz: 200\nt_s,gx_rad_s\n0,1\n0.01,2\n0.02,3\n",
                "disagrees",
            ),
            (
                "t_s,lat_rad,lon_rad,h_m\n0,0.5,0.1,0\n1,40.2,0.1,0\n",
                "lat_rad",
            ),
        ];
        for (k, (text, said)) in cases.iter().enumerate() {
            let path = dir.path().join(format!("bad{k}.csv"));
            std::fs::write(&path, text).unwrap();
            for message in [summarise_streamed(&path), summarise(&path)] {
                let message = message.unwrap_err().to_string();
                assert!(message.contains(&format!("bad{k}.csv")), "{message}");
                assert!(message.contains(said), "{said}: {message}");
            }
        }
    }
}
