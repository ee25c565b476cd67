//! What the importer property tests (`fuzz_import.rs`) and the seeded mutation harness
//! (`fuzz_mutation.rs`) share: byte mutations (flips, insertions, deletions, truncation,
//! duplicated chunks, a field replaced by an awkward number), a small valid file of every text
//! dataset, and the one judgement both make of an importer's answer: a clean answer is a set
//! of recordings that validate and hold only finite numbers, or an error that names the file.
//! A panic is never clean; the property tests let proptest report it, the harness counts it.

#![allow(dead_code)]

use std::path::Path;

use dynacal::import::{detect, import_file, Dataset};
use dynacal::interchange::ImuRecording;
use rand::Rng;

/// Every dataset, so each importer sees every input (not only the one `detect` picks).
pub const ALL_DATASETS: [Dataset; 9] = [
    Dataset::Adis16405,
    Dataset::MtigGyroX,
    Dataset::PsinsMems,
    Dataset::PsinsFog,
    Dataset::PsinsLaserGyro,
    Dataset::Mpu9250Tetra,
    Dataset::ArduPilotDataFlash,
    Dataset::XsensDot,
    Dataset::Px4ULog,
];

/// The text datasets, with the file name a synthetic file of each is written under.
pub const TEXT_DATASETS: [(Dataset, &str); 7] = [
    (Dataset::Adis16405, "session9.csv"),
    (Dataset::MtigGyroX, "gyro_x.csv"),
    (Dataset::PsinsMems, "mems_increments.csv"),
    (Dataset::PsinsFog, "fog_ins_reference.csv"),
    (Dataset::PsinsLaserGyro, "lasergyro.imu"),
    (Dataset::Mpu9250Tetra, "static.csv"),
    (Dataset::XsensDot, "dot9.csv"),
];

/// One change to a file's bytes. Positions are taken modulo the current length, so any
/// value applies to any file.
#[derive(Debug, Clone)]
pub enum Mutation {
    /// XOR one byte with a non-zero mask.
    Flip { at: usize, mask: u8 },
    /// Cut the file to `len` bytes (modulo its length + 1).
    Truncate { len: usize },
    /// Insert bytes.
    Insert { at: usize, bytes: Vec<u8> },
    /// Remove up to `len` bytes at `from`.
    Delete { from: usize, len: usize },
    /// Copy up to `len` bytes from `from` and insert the copy at `to`.
    Duplicate { from: usize, len: usize, to: usize },
    /// Replace the `field`-th run of number characters with `text` (an edge of what a
    /// number parser accepts: huge, tiny, signed zero, `inf`, `NaN`, hex...).
    Field { field: usize, text: &'static str },
}

/// Texts a number field is replaced with by [`Mutation::Field`].
pub const AWKWARD_NUMBERS: [&str; 20] = [
    "1e308",
    "-1e308",
    "1.7976931348623157e308",
    "1e-320",
    "4.9e-324",
    "-0",
    "0",
    "inf",
    "-inf",
    "NaN",
    "nan",
    "0x10",
    "+5",
    "1_000",
    "",
    "2147483648",
    "-2147483649",
    "4294967296",
    "18446744073709551616",
    "9223372036854775807",
];

impl Mutation {
    pub fn apply(&self, bytes: &mut Vec<u8>) {
        let n = bytes.len();
        match self {
            Mutation::Flip { at, mask } => {
                if n > 0 {
                    bytes[at % n] ^= (*mask).max(1);
                }
            }
            Mutation::Truncate { len } => bytes.truncate(len % (n + 1)),
            Mutation::Insert { at, bytes: new } => {
                let at = at % (n + 1);
                bytes.splice(at..at, new.iter().copied());
            }
            Mutation::Delete { from, len } => {
                let from = from % (n + 1);
                bytes.drain(from..(from + len).min(n));
            }
            Mutation::Duplicate { from, len, to } => {
                let from = from % (n + 1);
                let copy = bytes[from..(from + len).min(n)].to_vec();
                let to = to % (n + 1);
                bytes.splice(to..to, copy);
            }
            Mutation::Field { field, text } => {
                let runs = number_runs(bytes);
                if !runs.is_empty() {
                    let run = runs[field % runs.len()].clone();
                    bytes.splice(run, text.bytes());
                }
            }
        }
    }
}

/// The byte ranges of runs of characters a number is written with.
fn number_runs(bytes: &[u8]) -> Vec<std::ops::Range<usize>> {
    let is_number = |b: u8| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E');
    let mut runs = Vec::new();
    let mut start = None;
    for (i, &b) in bytes.iter().enumerate() {
        match (is_number(b), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                runs.push(s..i);
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        runs.push(s..bytes.len());
    }
    runs
}

/// A mutation drawn from `rng` for a file of `len` bytes: chunks up to 300 bytes, random
/// insertions half the time of text characters (so they read as lines and fields, not only
/// as binary noise).
pub fn random_mutation(rng: &mut impl Rng, len: usize) -> Mutation {
    let at = rng.random_range(0..=len);
    match rng.random_range(0..6) {
        0 => Mutation::Flip {
            at,
            mask: 1 << rng.random_range(0..8),
        },
        1 => Mutation::Truncate {
            len: rng.random_range(0..=len),
        },
        2 => {
            let n = rng.random_range(1..300);
            let text = rng.random_bool(0.5);
            let bytes = (0..n)
                .map(|_| {
                    if text {
                        b"0123456789.,-e \n"[rng.random_range(0..16)]
                    } else {
                        rng.random()
                    }
                })
                .collect();
            Mutation::Insert { at, bytes }
        }
        3 => Mutation::Delete {
            from: at,
            len: rng.random_range(1..300),
        },
        4 => Mutation::Duplicate {
            from: rng.random_range(0..=len),
            len: rng.random_range(1..300),
            to: at,
        },
        _ => Mutation::Field {
            field: rng.random_range(0..10_000),
            text: AWKWARD_NUMBERS[rng.random_range(0..AWKWARD_NUMBERS.len())],
        },
    }
}

/// The proptest strategy of [`Mutation`]s.
pub fn arb_mutation() -> impl proptest::strategy::Strategy<Value = Mutation> {
    use proptest::prelude::*;
    prop_oneof![
        (any::<usize>(), 1u8..=255).prop_map(|(at, mask)| Mutation::Flip { at, mask }),
        any::<usize>().prop_map(|len| Mutation::Truncate { len }),
        (
            any::<usize>(),
            proptest::collection::vec(any::<u8>(), 1..200)
        )
            .prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        (any::<usize>(), 1usize..200).prop_map(|(from, len)| Mutation::Delete { from, len }),
        (any::<usize>(), 1usize..200, any::<usize>())
            .prop_map(|(from, len, to)| Mutation::Duplicate { from, len, to }),
        (any::<usize>(), 0..AWKWARD_NUMBERS.len()).prop_map(|(field, k)| Mutation::Field {
            field,
            text: AWKWARD_NUMBERS[k],
        }),
    ]
}

/// A valid file of `dataset` with `rows` samples (at least 1), values varied by `seed`.
pub fn valid_text(dataset: Dataset, rows: usize, seed: u64) -> String {
    let v = |k: usize, c: usize| ((seed as usize + 7 * k + 3 * c) % 97) as f64 * 0.013 - 0.6;
    let count = |k: usize, c: usize| ((seed as usize + 11 * k + 5 * c) % 2001) as i64 - 1000;
    let mut out = String::new();
    let line = |out: &mut String, fields: Vec<String>| {
        out.push_str(&fields.join(","));
        out.push('\n');
    };
    match dataset {
        Dataset::Adis16405 => {
            line(&mut out, vec!["gx,gy,gz,ax,ay,az".into()]);
            for k in 0..rows {
                line(&mut out, (0..6).map(|c| count(k, c).to_string()).collect());
            }
        }
        Dataset::MtigGyroX => {
            line(&mut out, vec!["gx_rad_s".into()]);
            for k in 0..rows {
                line(&mut out, vec![format!("{:.6e}", v(k, 0) * 1e-3)]);
            }
        }
        Dataset::PsinsMems => {
            line(
                &mut out,
                vec![dynacal::import::psins_fog_mems::MEMS_COLUMNS.join(",")],
            );
            for k in 0..rows {
                let mut f = vec![format!("{:.10}", 0.01 * (k + 1) as f64)];
                f.extend((0..6).map(|c| format!("{:.12e}", v(k, c) * 1e-3)));
                line(&mut out, f);
            }
        }
        Dataset::PsinsFog => {
            line(
                &mut out,
                vec![dynacal::import::psins_fog_mems::FOG_COLUMNS.join(",")],
            );
            for k in 0..rows {
                let mut f = vec![format!("{:.12e}", 0.1 * (k + 1) as f64)];
                f.extend((0..6).map(|c| format!("{:.12e}", v(k, c))));
                f.extend(["0.6008512", "1.9448941", "172.59"].map(String::from));
                line(&mut out, f);
            }
        }
        Dataset::PsinsLaserGyro => {
            out.push_str("% PSINS SIMU\n0 0 -90.6 0 0 0\n34.246 108.9097 380 0 10 9.780327\n");
            out.push_str("0.1 0.1 0.1 125 125 125\n");
            for k in 0..rows {
                let f: Vec<String> = (0..6).map(|c| count(k, c).to_string()).collect();
                out.push_str(&f.join(" "));
                out.push('\n');
            }
        }
        Dataset::Mpu9250Tetra => {
            line(
                &mut out,
                vec![dynacal::import::mpu9250_tetra::columns().join(",")],
            );
            for k in 0..rows {
                let mut f = vec![format!("{:.6}", 0.023 * k as f64)];
                f.extend((0..24).map(|c| format!("{:.6}", v(k, c))));
                line(&mut out, f);
            }
        }
        Dataset::XsensDot => {
            out.push_str("SampleTimeFine,Euler_X,Euler_Y,Euler_Z,Acc_X,Acc_Y,Acc_Z,");
            out.push_str("Gyr_X,Gyr_Y,Gyr_Z,Mag_X,Mag_Y,Mag_Z,\n");
            for k in 0..rows {
                let mut f = vec![(677_591_333 + 8_333 * k as u64).to_string()];
                f.extend((0..12).map(|c| format!("{:.9}", v(k, c) + 0.5)));
                f.push(" ".into());
                line(&mut out, f);
            }
        }
        _ => unreachable!("{dataset:?} is not a text dataset"),
    }
    out
}

/// Lines before the first sample line in [`valid_text`]'s file of `dataset`.
pub fn header_lines(dataset: Dataset) -> usize {
    if dataset == Dataset::PsinsLaserGyro {
        4
    } else {
        1
    }
}

/// What an importer made of a file.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// Recordings that validate and hold only finite numbers: their sample counts.
    Imported(Vec<usize>),
    /// An error naming the file: its message.
    Refused(String),
    /// Not clean: what is wrong.
    Unclean(String),
}

/// The first non-finite value of a recording, by column name.
fn non_finite(rec: &ImuRecording) -> Option<String> {
    let triplets = [
        ("gyro", &rec.gyro_rad_s),
        ("accel", &rec.accel_m_s2),
        ("attitude", &rec.attitude_rad),
        ("position", &rec.position),
        ("velocity", &rec.velocity_ned_m_s),
    ];
    let columns = triplets
        .iter()
        .filter_map(|(name, t)| t.as_ref().map(|t| (*name, t)))
        .flat_map(|(name, t)| t.iter().map(move |c| (name, c.as_slice())))
        .chain(
            rec.single_axis
                .iter()
                .map(|s| ("single axis", s.values.as_slice())),
        )
        .chain(std::iter::once(("t_s", rec.t_s.as_slice())));
    for (name, column) in columns {
        if let Some(x) = column.iter().find(|x| !x.is_finite()) {
            return Some(format!("{name} holds {x}"));
        }
    }
    None
}

/// Runs `dataset`'s importer on `path` and judges the answer (see the module's note).
pub fn import_outcome(path: &Path, dataset: Dataset) -> Outcome {
    let name = path.display().to_string();
    match import_file(path, dataset) {
        Ok(sensors) => {
            let mut lens = Vec::new();
            for sensor in &sensors {
                let rec = &sensor.recording;
                if let Err(e) = rec.validate(path) {
                    return Outcome::Unclean(format!("{}: imported but invalid: {e}", sensor.name));
                }
                if let Some(what) = non_finite(rec) {
                    return Outcome::Unclean(format!("{}: imported but {what}", sensor.name));
                }
                lens.push(rec.len());
            }
            if lens.is_empty() {
                return Outcome::Unclean("imported nothing without an error".into());
            }
            Outcome::Imported(lens)
        }
        Err(e) => {
            let message = e.to_string();
            if message.contains(&name) {
                Outcome::Refused(message)
            } else {
                Outcome::Unclean(format!("error does not name the file: {message}"))
            }
        }
    }
}

/// `detect` on `path`: the dataset it recognises, or what is unclean about its error.
pub fn detect_outcome(path: &Path) -> Result<Option<Dataset>, String> {
    match detect(path) {
        Ok(found) => Ok(found),
        Err(e) if e.to_string().contains(&path.display().to_string()) => Ok(None),
        Err(e) => Err(format!("detect's error does not name the file: {e}")),
    }
}

/// The line number an error message names (`line N`), if any.
pub fn named_line(message: &str) -> Option<u64> {
    let rest = &message[message.find("line ")? + 5..];
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// `$DYNACAL_DATA` (default: the data folder beside the repository), or None with a
/// printed SKIP when it is absent.
pub fn data_dir_or_skip(test: &str) -> Option<std::path::PathBuf> {
    let dir = dynacal::data_dir();
    if dir.is_dir() {
        Some(dir)
    } else {
        println!("SKIP {test}: no data folder at {}", dir.display());
        None
    }
}

/// The first `lines` lines of a (possibly gzipped) text file, or the first `bytes` bytes of
/// a binary one; None when the file is absent.
pub fn head_of(path: &Path, lines: usize, bytes: usize) -> Option<Vec<u8>> {
    use std::io::{BufRead, Read};
    let file = std::fs::File::open(path).ok()?;
    let reader: Box<dyn Read> = if path.extension().is_some_and(|e| e == "gz") {
        Box::new(flate2::read::MultiGzDecoder::new(file))
    } else {
        Box::new(file)
    };
    let mut reader = std::io::BufReader::new(reader);
    let mut out = Vec::new();
    if lines == 0 {
        reader.take(bytes as u64).read_to_end(&mut out).ok()?;
        return Some(out);
    }
    for _ in 0..lines {
        if reader.read_until(b'\n', &mut out).ok()? == 0 {
            break;
        }
    }
    Some(out)
}

/// What `dynacal decode` does with the board log at `path` after reading it (the library's
/// part of `cli/decode.rs`): `Refused` when the log is refused with an error naming the file,
/// `Imported` (the IMUs' sample counts) when every output is computed and every IMU's
/// recording validates with finite values.
pub fn decode_outcome(path: &Path) -> Outcome {
    use dynacal::board_log::{fault_entries, nav_csv, noise_csv};
    let name = path.display().to_string();
    let log = match dynacal::decode::decode_file(path) {
        Ok(log) => log,
        Err(e) => return Outcome::Unclean(format!("reading failed: {e}")),
    };
    if let Err(e) = log.validate(path) {
        let message = e.to_string();
        return if message.contains(&name) {
            Outcome::Refused(message)
        } else {
            Outcome::Unclean(format!("error does not name the file: {message}"))
        };
    }
    let json = |what: &str, r: serde_json::Result<String>| {
        r.err()
            .map(|e| Outcome::Unclean(format!("{what} does not serialise: {e}")))
    };
    if let Some(bad) = json(
        "summary",
        serde_json::to_string(&log.summary(dynacal::interchange::FileFormat::Csv)),
    ) {
        return bad;
    }
    let mut lens = Vec::new();
    for imu in log.imus.iter().filter(|imu| !imu.is_empty()) {
        let rec = imu.to_recording();
        if let Err(e) = rec.validate(path) {
            return Outcome::Unclean(format!("imu {}: invalid: {e}", imu.config.imu_id));
        }
        if let Some(what) = non_finite(&rec) {
            return Outcome::Unclean(format!("imu {}: {what}", imu.config.imu_id));
        }
        lens.push(rec.len());
    }
    if let Some(bad) = json("wv.json", serde_json::to_string(&log.wavelet_variance_si())) {
        return bad;
    }
    let _ = nav_csv(&log.filter);
    if let Some(header) = &log.header {
        let _ = noise_csv(header, &log.noise);
        let faults = serde_json::to_string(&fault_entries(header, &log.faults));
        if let Some(bad) = json("faults.json", faults) {
            return bad;
        }
    }
    Outcome::Imported(lens)
}
