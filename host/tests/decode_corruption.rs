//! The decoder against damaged logs: random byte flips, truncation, inserted garbage,
//! duplicated and deleted chunks. Every frame whose bytes (and a closing delimiter) survive
//! intact must be decoded exactly, in order, and nothing else; no input may panic. Beyond the
//! frames, the rest of what `dynacal decode` does with a damaged log or arbitrary bytes
//! (validate, summary, recordings, wavelet variances, nav/noise/fault tables) must give a
//! usable result or an error naming the file. Proptest is seeded, so failures reproduce.

mod common;
mod fuzz_common;

use dynacal::decode::{decode_bytes, encode_log};
use dynacal_core::log::{Frame, LogAccumulator};
use fuzz_common::Outcome;
use std::collections::HashMap;

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A byte stream that remembers where each byte came from in the clean log
/// (`None` for bytes that were overwritten or inserted).
#[derive(Clone)]
struct Tracked {
    bytes: Vec<u8>,
    origin: Vec<Option<usize>>,
}

#[derive(Debug, Clone)]
enum Mutation {
    /// XOR one byte with a non-zero mask.
    Flip { at: usize, mask: u8 },
    /// Cut the log to `len` bytes.
    Truncate { len: usize },
    /// Insert random bytes (zeros included).
    Insert { at: usize, garbage: Vec<u8> },
    /// Copy `len` bytes from `from` and insert the copy at `to`.
    Duplicate { from: usize, len: usize, to: usize },
    /// Remove `len` bytes at `from`.
    Delete { from: usize, len: usize },
}

impl Tracked {
    fn new(bytes: Vec<u8>) -> Self {
        let origin = (0..bytes.len()).map(Some).collect();
        Self { bytes, origin }
    }

    /// Applies `m`; positions are taken modulo the current length, so any value is valid.
    fn apply(&mut self, m: &Mutation) {
        let n = self.bytes.len();
        match m {
            Mutation::Flip { at, mask } => {
                if n > 0 && *mask != 0 {
                    self.bytes[at % n] ^= mask;
                    self.origin[at % n] = None;
                }
            }
            Mutation::Truncate { len } => {
                let len = len % (n + 1);
                self.bytes.truncate(len);
                self.origin.truncate(len);
            }
            Mutation::Insert { at, garbage } => {
                let at = at % (n + 1);
                self.bytes.splice(at..at, garbage.iter().copied());
                self.origin.splice(at..at, garbage.iter().map(|_| None));
            }
            Mutation::Duplicate { from, len, to } => {
                let from = from % (n + 1);
                let end = (from + len).min(n);
                let to = to % (n + 1);
                let bytes: Vec<u8> = self.bytes[from..end].to_vec();
                let origin: Vec<Option<usize>> = self.origin[from..end].to_vec();
                self.bytes.splice(to..to, bytes);
                self.origin.splice(to..to, origin);
            }
            Mutation::Delete { from, len } => {
                let from = from % (n + 1);
                let end = (from + len).min(n);
                self.bytes.drain(from..end);
                self.origin.drain(from..end);
            }
        }
    }
}

/// The clean log and each frame's byte range in it (delimiter included).
fn clean_log(seed: u64, seconds: u64) -> (Vec<Frame>, Vec<u8>, Vec<std::ops::Range<usize>>) {
    let frames = common::frames(seed, seconds);
    let mut bytes = Vec::new();
    let mut ranges = Vec::new();
    for frame in &frames {
        let start = bytes.len();
        bytes.extend(encode_log(std::slice::from_ref(frame)).unwrap());
        ranges.push(start..bytes.len());
    }
    (frames, bytes, ranges)
}

/// Indices of the clean frames untouched in `damaged`, in stream order: the frame's COBS
/// bytes come, contiguously and unaltered, from that frame in the clean log, and a 0x00
/// delimiter follows.
fn untouched_frames(ranges: &[std::ops::Range<usize>], damaged: &Tracked) -> Vec<usize> {
    let starts: HashMap<usize, usize> = ranges
        .iter()
        .enumerate()
        .map(|(i, r)| (r.start, i))
        .collect();
    let mut found = Vec::new();
    for p in 0..damaged.bytes.len() {
        let Some(&frame) = damaged.origin[p].and_then(|o| starts.get(&o)) else {
            continue;
        };
        let body = ranges[frame].len() - 1;
        let contiguous = (0..body)
            .all(|k| damaged.origin.get(p + k).copied().flatten() == Some(ranges[frame].start + k));
        if contiguous && damaged.bytes.get(p + body) == Some(&0) {
            found.push(frame);
        }
    }
    found
}

/// Indices of the clean frames whose exact bytes end at a 0x00 in `damaged`, in stream
/// order, wherever those bytes came from. This includes the untouched frames and also a
/// frame rebuilt from equal bytes elsewhere (e.g. a deleted frame start replaced by the
/// identical start of another IMU frame): its bytes are genuine and the decoder must accept
/// it just the same.
fn intact_frames(clean: &[u8], ranges: &[std::ops::Range<usize>], damaged: &Tracked) -> Vec<usize> {
    let bodies: HashMap<&[u8], usize> = ranges
        .iter()
        .enumerate()
        .map(|(i, r)| (&clean[r.start..r.end - 1], i))
        .collect();
    let mut lengths: Vec<usize> = ranges.iter().map(|r| r.len() - 1).collect();
    lengths.sort_unstable();
    lengths.dedup();
    let mut found = Vec::new();
    for (d, _) in damaged.bytes.iter().enumerate().filter(|(_, b)| **b == 0) {
        let matches: Vec<usize> = lengths
            .iter()
            .filter(|&&len| len <= d)
            .filter_map(|&len| bodies.get(&damaged.bytes[d - len..d]).copied())
            .collect();
        assert!(matches.len() <= 1, "ambiguous test log");
        found.extend(matches);
    }
    found
}

/// True when `sub` occurs in `seq` in order (not necessarily adjacent).
fn is_subsequence(sub: &[usize], seq: &[usize]) -> bool {
    let mut it = seq.iter();
    sub.iter().all(|x| it.any(|y| y == x))
}

fn encoded(frame: &Frame) -> Vec<u8> {
    encode_log(std::slice::from_ref(frame)).unwrap()
}

/// Decodes `damaged` in `chunk`-sized pieces and checks the recovered frames and counts.
fn check_recovery(
    frames: &[Frame],
    clean: &[u8],
    ranges: &[std::ops::Range<usize>],
    damaged: &Tracked,
    chunk: usize,
) {
    let expected = intact_frames(clean, ranges, damaged);
    assert!(is_subsequence(
        &untouched_frames(ranges, damaged),
        &expected
    ));
    let mut acc = LogAccumulator::new();
    let mut decoded = Vec::new();
    for piece in damaged.bytes.chunks(chunk.max(1)) {
        decoded.extend(acc.feed(piece).filter_map(Result::ok));
    }
    acc.finish();
    let decoded: Vec<Vec<u8>> = decoded.iter().map(encoded).collect();
    let expected_bytes: Vec<Vec<u8>> = expected.iter().map(|&i| encoded(&frames[i])).collect();
    if decoded != expected_bytes {
        let first = (0..decoded.len().max(expected_bytes.len()))
            .find(|&i| decoded.get(i) != expected_bytes.get(i))
            .unwrap();
        let at = decoded.get(first).and_then(|d| {
            damaged
                .bytes
                .windows(d.len())
                .position(|w| w == d.as_slice())
        });
        let origin = at.map(|p| damaged.origin[p..p + decoded[first].len()].to_vec());
        panic!(
            "decoded {} frames, {} intact; first difference at #{first}: decoded {:02x?} \
             found at damaged offset {at:?} with origins {origin:?}, expected {:02x?}",
            decoded.len(),
            expected_bytes.len(),
            decoded.get(first),
            expected_bytes.get(first),
        );
    }
    let stats = acc.stats();
    assert_eq!(stats.bytes_seen, damaged.bytes.len() as u64);
    assert_eq!(stats.bytes_decoded + stats.bytes_dropped, stats.bytes_seen);
    assert_eq!(stats.frames_decoded, expected.len() as u64);
    let intact_bytes: usize = expected.iter().map(|&i| ranges[i].len()).sum();
    assert_eq!(stats.bytes_decoded, intact_bytes as u64);

    // The host decoder sees the same stream and counts the same frames per kind.
    let log = decode_bytes(&damaged.bytes);
    assert_eq!(log.stream, stats);
    for kind in ["header", "imu", "pps", "gnss", "filter", "health"] {
        let want = expected
            .iter()
            .filter(|&&i| frames[i].kind_name() == kind)
            .count() as u64;
        assert_eq!(
            log.frames_by_kind.get(kind).copied().unwrap_or(0),
            want,
            "{kind}"
        );
    }
    let errors: u64 = log.dropped_by_error.values().sum();
    assert_eq!(errors, log.stream.frames_dropped);
}

fn random_mutation(rng: &mut ChaCha8Rng, len: usize) -> Mutation {
    let at = rng.random_range(0..=len);
    match rng.random_range(0..5) {
        0 => Mutation::Flip {
            at,
            mask: rng.random_range(1..=255),
        },
        1 => Mutation::Truncate {
            len: rng.random_range(len / 2..=len),
        },
        2 => {
            let n = rng.random_range(1..400);
            Mutation::Insert {
                at,
                garbage: (0..n).map(|_| rng.random()).collect(),
            }
        }
        3 => Mutation::Duplicate {
            from: rng.random_range(0..=len),
            len: rng.random_range(1..300),
            to: at,
        },
        _ => Mutation::Delete {
            from: at,
            len: rng.random_range(1..200),
        },
    }
}

#[test]
fn clean_log_decodes_completely() {
    let (frames, bytes, ranges) = clean_log(1, 3);
    let tracked = Tracked::new(bytes.clone());
    assert_eq!(intact_frames(&bytes, &ranges, &tracked).len(), frames.len());
    check_recovery(&frames, &bytes, &ranges, &tracked, 4096);
    let log = decode_bytes(&bytes);
    assert_eq!(log.stream.bytes_dropped, 0);
    assert_eq!(log.stream.frames_dropped, 0);
    assert_eq!(log.frames_by_kind["imu"], 3 * (200 + 100));
}

#[test]
fn random_damage_over_many_seeds_keeps_every_intact_frame() {
    let (frames, bytes, ranges) = clean_log(7, 2);
    let mut total_intact = 0;
    let mut total_frames = 0;
    for seed in 0..300u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut damaged = Tracked::new(bytes.clone());
        for _ in 0..rng.random_range(1..10) {
            let m = random_mutation(&mut rng, damaged.bytes.len());
            damaged.apply(&m);
        }
        let chunk = rng.random_range(1..5000);
        total_intact += intact_frames(&bytes, &ranges, &damaged).len();
        total_frames += frames.len();
        check_recovery(&frames, &bytes, &ranges, &damaged, chunk);
    }
    // The damage is real but leaves most frames: the test exercises both sides.
    assert!(total_intact < total_frames && total_intact > total_frames / 3);
}

#[test]
fn dense_byte_flips_keep_every_untouched_frame() {
    let (frames, bytes, ranges) = clean_log(3, 2);
    for seed in 0..40u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(1000 + seed);
        let mut damaged = Tracked::new(bytes.clone());
        // About one byte in 200: most frames survive, many do not.
        for _ in 0..bytes.len() / 200 {
            let at = rng.random_range(0..bytes.len());
            damaged.apply(&Mutation::Flip {
                at,
                mask: rng.random_range(1..=255),
            });
        }
        check_recovery(&frames, &bytes, &ranges, &damaged, 1 + seed as usize * 37);
    }
}

#[test]
fn garbage_between_frames_without_delimiters_loses_nothing() {
    let (frames, bytes, ranges) = clean_log(4, 1);
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let mut damaged = Tracked::new(bytes.clone());
    // Insert non-zero garbage exactly at frame boundaries, from the back so earlier
    // boundaries keep their positions; no frame is touched.
    for range in ranges.iter().rev().step_by(3) {
        let n = rng.random_range(1..600);
        damaged.apply(&Mutation::Insert {
            at: range.start,
            garbage: (0..n).map(|_| rng.random_range(1..=255)).collect(),
        });
    }
    assert_eq!(intact_frames(&bytes, &ranges, &damaged).len(), frames.len());
    check_recovery(&frames, &bytes, &ranges, &damaged, 333);
}

fn arb_mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), 1u8..=255).prop_map(|(at, mask)| Mutation::Flip { at, mask }),
        any::<usize>().prop_map(|len| Mutation::Truncate { len }),
        (
            any::<usize>(),
            proptest::collection::vec(any::<u8>(), 1..300)
        )
            .prop_map(|(at, garbage)| Mutation::Insert { at, garbage }),
        (any::<usize>(), 1usize..400, any::<usize>())
            .prop_map(|(from, len, to)| Mutation::Duplicate { from, len, to }),
        (any::<usize>(), 1usize..200).prop_map(|(from, len)| Mutation::Delete { from, len }),
    ]
}

/// Seeded proptest settings (the project's rule: every failure reproduces). The regression
/// file beside this test is still read first.
fn seeded(cases: u32, seed: u64) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        ..ProptestConfig::default()
    }
}

/// `bytes` as the board log `fuzzed.log` through what `dynacal decode` does with it
/// (`fuzz_common::decode_outcome`): a usable result or an error naming the file.
fn decode_command_is_clean(bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzzed.log");
    std::fs::write(&path, bytes).unwrap();
    match fuzz_common::decode_outcome(&path) {
        Outcome::Unclean(what) => Err(TestCaseError::fail(what)),
        Outcome::Imported(_) | Outcome::Refused(_) => Ok(()),
    }
}

proptest! {
    #![proptest_config(seeded(128, 0xF0220301))]

    /// Arbitrary bytes are refused naming the file.
    #[test]
    fn arbitrary_bytes_are_refused_cleanly(
        bytes in proptest::collection::vec(any::<u8>(), 0..3000),
    ) {
        decode_command_is_clean(&bytes)?;
    }

    /// A damaged log is decoded into usable outputs or refused naming the file.
    #[test]
    fn damaged_logs_decode_into_usable_outputs(
        seed in 0u64..1000,
        mutations in proptest::collection::vec(arb_mutation(), 1..8),
    ) {
        let (_, bytes, _) = clean_log(seed, 1);
        let mut damaged = Tracked::new(bytes);
        for m in &mutations {
            damaged.apply(m);
        }
        decode_command_is_clean(&damaged.bytes)?;
    }

    /// Random bytes before and after a whole log (a board that logged noise before it
    /// started, a sink that kept writing after it stopped) cost no frame of the log.
    #[test]
    fn garbage_before_and_after_a_log_costs_no_frame(
        seed in 0u64..1000,
        before in proptest::collection::vec(any::<u8>(), 0..400),
        after in proptest::collection::vec(any::<u8>(), 0..400),
        chunk in 1usize..3000,
    ) {
        let (frames, bytes, ranges) = clean_log(seed, 1);
        let mut damaged = Tracked::new(bytes.clone());
        let end = bytes.len();
        damaged.apply(&Mutation::Insert { at: end, garbage: after });
        damaged.apply(&Mutation::Insert { at: 0, garbage: before });
        prop_assert_eq!(untouched_frames(&ranges, &damaged).len(), frames.len());
        check_recovery(&frames, &bytes, &ranges, &damaged, chunk);
    }
}

proptest! {
    #![proptest_config(seeded(64, 0xF0220302))]
    #[test]
    fn proptest_damage_keeps_every_intact_frame(
        seed in 0u64..1000,
        mutations in proptest::collection::vec(arb_mutation(), 1..8),
        chunk in 1usize..3000,
    ) {
        let (frames, bytes, ranges) = clean_log(seed, 1);
        let mut damaged = Tracked::new(bytes.clone());
        for m in &mutations {
            damaged.apply(m);
        }
        check_recovery(&frames, &bytes, &ranges, &damaged, chunk);
    }
}
