//! Test support for the binary importers' property tests (`ardupilot_dataflash::tests`,
//! `px4_ulog::tests`, `ros_bag::tests`): a byte mutation proptest can draw, and the judgement of an import
//! through the library's entry points (`detect`, `import_file`): recordings that validate
//! and hold only finite numbers, or an error that names the file and, for damage, a byte
//! offset inside it. The text importers are fuzzed from `host/tests/fuzz_import.rs`.

use proptest::prelude::*;

use super::{detect, import_file, Dataset, ImportError};

/// One change to a log's bytes; positions are taken modulo the current length.
#[derive(Debug, Clone)]
pub(crate) enum Mutation {
    /// XOR a byte with a non-zero mask.
    Flip { at: usize, mask: u8 },
    /// Insert bytes.
    Insert { at: usize, bytes: Vec<u8> },
    /// Remove up to `len` bytes.
    Delete { at: usize, len: usize },
    /// Cut the log.
    Truncate { at: usize },
    /// Insert a copy of up to `len` bytes from `from` at `to` (a message repeated).
    Duplicate { from: usize, len: usize, to: usize },
}

impl Mutation {
    pub(crate) fn apply(&self, bytes: &mut Vec<u8>) {
        let n = bytes.len();
        match self {
            Mutation::Flip { at, mask } if n > 0 => bytes[at % n] ^= (*mask).max(1),
            Mutation::Flip { .. } => {}
            Mutation::Insert { at, bytes: new } => {
                let at = at % (n + 1);
                bytes.splice(at..at, new.iter().copied());
            }
            Mutation::Delete { at, len } => {
                let at = at % (n + 1);
                bytes.drain(at..(at + len).min(n));
            }
            Mutation::Truncate { at } => bytes.truncate(at % (n + 1)),
            Mutation::Duplicate { from, len, to } => {
                let from = from % (n + 1);
                let copy = bytes[from..(from + len).min(n)].to_vec();
                let to = to % (n + 1);
                bytes.splice(to..to, copy);
            }
        }
    }
}

pub(crate) fn arb_mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        3 => (any::<usize>(), 1u8..=255).prop_map(|(at, mask)| Mutation::Flip { at, mask }),
        1 => (any::<usize>(), proptest::collection::vec(any::<u8>(), 1..64))
            .prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        1 => (any::<usize>(), 1usize..64).prop_map(|(at, len)| Mutation::Delete { at, len }),
        1 => any::<usize>().prop_map(|at| Mutation::Truncate { at }),
        1 => (any::<usize>(), 1usize..120, any::<usize>())
            .prop_map(|(from, len, to)| Mutation::Duplicate { from, len, to }),
    ]
}

/// Seeded proptest settings: every failure reproduces.
pub(crate) fn config(cases: u32, seed: u64) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// A clean answer: each recording's sample count, or the error's message and (for damage)
/// its byte offset.
pub(crate) type Clean = Result<Vec<usize>, (String, Option<u64>)>;

/// What importing `bytes` as the file `name` gave: the sample count of each recording, or
/// the error (with its byte offset where it is damage). Fails the case when the answer is not
/// clean: a recording that does not validate or holds a non-finite number, an error that
/// does not name the file, an offset beyond the file's end, or `detect` disagreeing.
pub(crate) fn import_clean(
    name: &str,
    dataset: Dataset,
    bytes: &[u8],
) -> Result<Clean, TestCaseError> {
    let dir = tempfile::tempdir().map_err(|e| TestCaseError::fail(e.to_string()))?;
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).map_err(|e| TestCaseError::fail(e.to_string()))?;
    let named = |e: &ImportError| e.to_string().contains(&path.display().to_string());
    match detect(&path) {
        Ok(found) => prop_assert!(found.is_none() || found == Some(dataset), "{found:?}"),
        Err(e) => prop_assert!(named(&e), "detect: {e}"),
    }
    match import_file(&path, dataset) {
        Ok(sensors) => {
            prop_assert!(!sensors.is_empty());
            let mut lens = Vec::new();
            for s in &sensors {
                let rec = &s.recording;
                prop_assert!(rec.validate(&path).is_ok(), "{}: invalid", s.name);
                prop_assert!(all_finite(rec), "{}: a non-finite value", s.name);
                lens.push(rec.len());
            }
            Ok(Ok(lens))
        }
        Err(e) => {
            prop_assert!(named(&e), "error does not name the file: {e}");
            let offset = match &e {
                ImportError::Corrupt { offset, .. } => Some(*offset),
                _ => None,
            };
            if let Some(offset) = offset {
                prop_assert!(offset <= bytes.len() as u64, "offset {offset}: {e}");
            }
            Ok(Err((e.to_string(), offset)))
        }
    }
}

fn all_finite(rec: &crate::interchange::ImuRecording) -> bool {
    let triplets = [
        &rec.gyro_rad_s,
        &rec.accel_m_s2,
        &rec.attitude_rad,
        &rec.position,
        &rec.velocity_ned_m_s,
    ];
    let finite = |c: &Vec<f64>| c.iter().all(|x| x.is_finite());
    triplets.iter().flat_map(|t| t.iter().flatten()).all(finite)
        && rec.single_axis.iter().all(|s| finite(&s.values))
        && finite(&rec.t_s)
}

/// A name for the importer's file that does not occur in its messages by accident.
pub(crate) fn file_name(dataset: Dataset) -> &'static str {
    match dataset {
        Dataset::ArduPilotDataFlash => "fuzzed-log.bin",
        Dataset::RosBag => "fuzzed-log.bag",
        _ => "fuzzed-log.ulg",
    }
}

/// Shared by both binary importers: damaged logs import cleanly; a log followed by random
/// bytes keeps every sample or is refused at an offset at or after its end.
pub(crate) fn check_damaged(
    dataset: Dataset,
    clean: &[u8],
    mutations: &[Mutation],
) -> Result<(), TestCaseError> {
    let mut bytes = clean.to_vec();
    for m in mutations {
        m.apply(&mut bytes);
    }
    import_clean(file_name(dataset), dataset, &bytes).map(|_| ())
}

pub(crate) fn check_tail(dataset: Dataset, clean: &[u8], tail: &[u8]) -> Result<(), TestCaseError> {
    let whole = match import_clean(file_name(dataset), dataset, clean)? {
        Ok(lens) => lens,
        Err((e, _)) => return Err(TestCaseError::fail(format!("the clean log: {e}"))),
    };
    let followed = [clean, tail].concat();
    match import_clean(file_name(dataset), dataset, &followed)? {
        Ok(lens) => prop_assert!(
            lens.len() >= whole.len() && lens.iter().zip(&whole).all(|(a, b)| a >= b),
            "{lens:?} against {whole:?}"
        ),
        Err((e, offset)) => {
            prop_assert!(offset.is_some_and(|o| o >= clean.len() as u64), "{e}")
        }
    }
    Ok(())
}
