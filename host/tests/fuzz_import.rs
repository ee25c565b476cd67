//! Property tests of every importer through the library's entry points (`import::detect`,
//! `import::import_file`): arbitrary bytes, small valid files of each text dataset damaged by
//! random mutations, a valid file cut at a line end or followed by random bytes, a gzip file
//! cut short, and the damaged first lines (or kilobytes) of the real files in `$DYNACAL_DATA`.
//! No input may panic; every answer is recordings that validate and hold only finite
//! numbers, or an error that names the file (`fuzz_common::import_outcome`). The binary
//! logs' importers get the same treatment on hand-built logs in their unit tests
//! (`import::ardupilot_dataflash::tests`, `import::px4_ulog::tests`).
//!
//! Seeded (`RngSeed::Fixed`), so every failure reproduces; a few hundred cases each keep the
//! whole file to a few seconds.

mod fuzz_common;

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use dynacal::import::Dataset;
use fuzz_common::{
    arb_mutation, detect_outcome, header_lines, import_outcome, named_line, valid_text, Mutation,
    Outcome, ALL_DATASETS, TEXT_DATASETS,
};
use proptest::prelude::*;
use proptest::test_runner::{FileFailurePersistence, RngSeed};

fn config(cases: u32, seed: u64) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: RngSeed::Fixed(seed),
        // Failures are reported with their seed and shrunk input; regressions worth keeping
        // become named unit tests.
        failure_persistence: Some(Box::new(FileFailurePersistence::Off)),
        ..ProptestConfig::default()
    }
}

/// Writes `bytes` as `name` in a fresh folder (kept alive by the returned guard).
fn write(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    (dir, path)
}

/// Every importer, and `detect`, on `path`: a failure message for the first unclean answer.
fn all_clean(path: &Path) -> Result<(), TestCaseError> {
    detect_outcome(path).map_err(TestCaseError::fail)?;
    for dataset in ALL_DATASETS {
        if let Outcome::Unclean(what) = import_outcome(path, dataset) {
            return Err(TestCaseError::fail(format!("{dataset:?}: {what}")));
        }
    }
    Ok(())
}

/// File names that send a file down each importer's path (extensions matter for the file
/// stem only; detection reads the bytes).
const NAMES: [&str; 5] = ["f.csv", "f.bin", "f.ulg", "f.imu", "f.csv.gz"];

proptest! {
    #![proptest_config(config(256, 0xF0220001))]

    /// Arbitrary bytes, and arbitrary bytes behind each binary format's magic (so the
    /// parsers get past their first check), are refused cleanly by every importer.
    #[test]
    fn arbitrary_bytes_are_refused_cleanly(
        bytes in proptest::collection::vec(any::<u8>(), 0..1500),
        magic in 0usize..3,
        name in 0..NAMES.len(),
    ) {
        let prefix: &[u8] = match magic {
            0 => &[],
            1 => &[0xA3, 0x95, 0x80],
            _ => b"ULog\x01\x12\x35\x01",
        };
        let (_dir, path) = write(NAMES[name], &[prefix, &bytes].concat());
        all_clean(&path)?;
    }
}

proptest! {
    #![proptest_config(config(1024, 0xF0220002))]

    /// A small valid file of each text dataset with a few random changes is read or refused
    /// cleanly by every importer, the one `detect` picks among them.
    #[test]
    fn damaged_valid_text_files_are_read_or_refused_cleanly(
        which in 0..TEXT_DATASETS.len(),
        rows in 1usize..40,
        seed in any::<u64>(),
        mutations in proptest::collection::vec(arb_mutation(), 1..5),
    ) {
        let (dataset, name) = TEXT_DATASETS[which];
        let mut bytes = valid_text(dataset, rows, seed).into_bytes();
        for m in &mutations {
            m.apply(&mut bytes);
        }
        let (_dir, path) = write(name, &bytes);
        all_clean(&path)?;
    }
}

proptest! {
    #![proptest_config(config(512, 0xF0220003))]

    /// A valid file cut at the end of a line keeps exactly its whole rows; followed by
    /// random bytes, it keeps at least them, or the error names a line after them (the
    /// damage is not blamed on an intact record).
    #[test]
    fn intact_rows_survive_a_cut_or_a_damaged_tail(
        which in 0..TEXT_DATASETS.len(),
        rows in 2usize..30,
        keep in 1usize..30,
        tail in proptest::collection::vec(any::<u8>(), 1..120),
    ) {
        let (dataset, name) = TEXT_DATASETS[which];
        let keep = keep.min(rows);
        let text = valid_text(dataset, rows, 7);
        let cut: String = text
            .split_inclusive('\n')
            .take(header_lines(dataset) + keep)
            .collect();
        let (_dir, path) = write(name, cut.as_bytes());
        let sensors = if dataset == Dataset::Mpu9250Tetra { 4 } else { 1 };
        prop_assert_eq!(import_outcome(&path, dataset), Outcome::Imported(vec![keep; sensors]));

        let (_dir, path) = write(name, &[cut.as_bytes(), &tail].concat());
        match import_outcome(&path, dataset) {
            Outcome::Imported(lens) => prop_assert!(lens.iter().all(|&n| n >= keep), "{lens:?}"),
            Outcome::Refused(message) => {
                let first_damaged = (header_lines(dataset) + keep + 1) as u64;
                if let Some(line) = named_line(&message) {
                    prop_assert!(line >= first_damaged, "{message}");
                }
            }
            Outcome::Unclean(what) => return Err(TestCaseError::fail(what)),
        }
    }
}

proptest! {
    #![proptest_config(config(256, 0xF0220004))]

    /// A gzip file cut short is read (what it holds whole) or refused naming the file.
    #[test]
    fn a_gzip_file_cut_short_is_refused_cleanly(
        which in 0..TEXT_DATASETS.len(),
        rows in 1usize..60,
        cut in any::<usize>(),
    ) {
        let (dataset, name) = TEXT_DATASETS[which];
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(valid_text(dataset, rows, 3).as_bytes()).unwrap();
        let mut bytes = gz.finish().unwrap();
        let whole = bytes.len();
        bytes.truncate(cut % whole);
        let (_dir, path) = write(&format!("{name}.gz"), &bytes);
        all_clean(&path)?;
    }
}

/// The first lines (text) or kilobytes (binary logs) of each real dataset file, with its
/// name; empty with a printed SKIP when the data folder is absent.
fn real_heads() -> &'static [(String, Vec<u8>)] {
    static HEADS: OnceLock<Vec<(String, Vec<u8>)>> = OnceLock::new();
    HEADS.get_or_init(|| {
        let Some(data) = fuzz_common::data_dir_or_skip("fuzz_import real-file heads") else {
            return Vec::new();
        };
        let files = [
            ("adis16405/session1.csv.gz", 60, 0),
            ("mtig/gyro_x_contaminated.csv.gz", 60, 0),
            ("psins-fog-mems/mems_increments.csv.gz", 60, 0),
            ("psins-fog-mems/fog_ins_reference.csv.gz", 60, 0),
            ("psins-lasergyro/lasergyro.imu.gz", 60, 0),
            ("mpu9250x4-tetra-static/static.csv.gz", 30, 0),
            ("xsens-dot4-quadrotor/dot7.csv.gz", 60, 0),
            ("ardupilot-3imu-copter/log171.bin", 0, 16 << 10),
            ("px4-ulog/sample_log_small.ulg", 0, 16 << 10),
        ];
        files
            .iter()
            .filter_map(|&(rel, lines, bytes)| {
                let head = fuzz_common::head_of(&data.join(rel), lines, bytes);
                if head.is_none() {
                    println!("SKIP {rel}: absent from {}", data.display());
                }
                let name = Path::new(rel).file_name()?.to_string_lossy();
                Some((name.trim_end_matches(".gz").to_string(), head?))
            })
            .collect()
    })
}

proptest! {
    #![proptest_config(config(512, 0xF0220005))]

    /// The head of each real file, damaged, is read or refused cleanly by every importer.
    #[test]
    fn damaged_heads_of_the_real_files_are_read_or_refused_cleanly(
        which in any::<usize>(),
        mutations in proptest::collection::vec(arb_mutation(), 1..6),
    ) {
        let heads = real_heads();
        if heads.is_empty() {
            return Ok(());
        }
        let (name, head) = &heads[which % heads.len()];
        let mut bytes = head.clone();
        for m in &mutations {
            m.apply(&mut bytes);
        }
        let (_dir, path) = write(name, &bytes);
        all_clean(&path)?;
    }
}

/// The undamaged synthetic files read whole: the mutations above start from valid input.
#[test]
fn the_synthetic_files_are_valid() {
    for (dataset, name) in TEXT_DATASETS {
        for rows in [1, 2, 39] {
            let (_dir, path) = write(name, valid_text(dataset, rows, 11).as_bytes());
            assert_eq!(detect_outcome(&path), Ok(Some(dataset)), "{name}");
            let sensors = if dataset == Dataset::Mpu9250Tetra {
                4
            } else {
                1
            };
            assert_eq!(
                import_outcome(&path, dataset),
                Outcome::Imported(vec![rows; sensors]),
                "{name}, {rows} rows"
            );
        }
    }
}

/// A number field replaced by each awkward number is read or refused cleanly, in every
/// text dataset and every field position of the header and first row (a deterministic
/// sweep of what the random field mutation samples).
#[test]
fn every_awkward_number_in_every_field_is_read_or_refused_cleanly() {
    let mut unclean = Vec::new();
    let dir = tempfile::tempdir().unwrap();
    for (dataset, name) in TEXT_DATASETS {
        let path = dir.path().join(name);
        let text = valid_text(dataset, 1, 5);
        let fields = text.split(['\n', ',', ' ']).count();
        for field in 0..fields {
            for awkward in fuzz_common::AWKWARD_NUMBERS {
                let mut bytes = text.clone().into_bytes();
                Mutation::Field {
                    field,
                    text: awkward,
                }
                .apply(&mut bytes);
                std::fs::write(&path, &bytes).unwrap();
                if let Outcome::Unclean(what) = import_outcome(&path, dataset) {
                    unclean.push(format!("{name}: field {field} = `{awkward}`: {what}"));
                }
            }
        }
    }
    assert!(unclean.is_empty(), "{}", unclean.join("\n"));
}
