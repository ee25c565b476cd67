//! ROS bags: ROS1 `.bag` files and ROS2 bags (a folder with `metadata.yaml`, or its storage
//! file alone: MCAP or SQLite `.db3`, either one possibly compressed whole with zstd, its
//! messages possibly compressed one by one with zstd), turned into interchange recordings.
//!
//! Every `sensor_msgs/Imu` topic becomes one IMU recording named after its topic
//! (`/xsens/imu_data` -> `xsens-imu_data`); `sensor_msgs/NavSatFix` topics become position
//! references, `nav_msgs/Odometry` topics attitude and velocity references. Conversions
//! (`docs/formats.md`, "ROS bags"):
//! - time: the header stamp, s since the Unix epoch as the bag has it, not rebased; the
//!   bag's receive time only where the stamp is zero, and said so;
//! - axes: ROS's body frames are forward-left-up (REP 103), the interchange's
//!   forward-right-down: y and z are negated, so the specific force of a level sensor at rest
//!   reads -g on z. The sensor's own `frame_id` and any mounting are left as they are and
//!   stated (a sensor on its side has gravity on another axis);
//! - an Imu whose covariance element 0 is -1 has no such data (REP 145): that triplet is
//!   left out;
//! - NavSatFix: latitude and longitude deg -> rad, `altitude` (above the WGS 84 ellipsoid)
//!   -> `h_m`; fixes with status -1 (no fix) are left out, and counted;
//! - Odometry: the child frame's orientation in the world frame, the world frame taken as
//!   east-north-up (REP 103), as roll, pitch, yaw of forward-right-down in north-east-down;
//!   the twist (in the child frame) turned into north-east-down velocity. Positions, in
//!   metres of an odometry frame, are not carried.
//!
//! Real bags are messy, and nothing is fixed silently: per topic the report
//! ([`BagReport`]) counts stamps that repeat or go back (those messages are left out: the
//! interchange's time increases strictly), zero stamps, the median rate, the jitter and the
//! gaps, and how the covariances are set; a topic that cannot be a sensor (every rate and
//! acceleration the same, the zeros of an Imu derived from odometry) is skipped with a note
//! naming it.

pub mod frames;
pub mod mcap_file;
pub mod messages;
pub mod ros1;
pub mod sqlite;
pub mod writer;

use std::path::Path;

use messages::Encoding;

use super::ImportError;
use crate::interchange::ImuRecording;

/// A topic as its storage describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicInfo {
    pub name: String,
    /// `package/Type` (ROS2's `package/msg/Type` shortened to it).
    pub msg_type: String,
    /// `None` for a serialisation dynacal does not read (its messages are counted only).
    pub encoding: Option<Encoding>,
}

/// Where a message is, for errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Location {
    /// A record at a byte offset of the file.
    File(u64),
    /// A record inside a ROS1 chunk: the chunk's byte offset in the file and the record's
    /// byte offset in the chunk's decompressed data.
    Chunk { chunk_offset: u64, inner: u64 },
    /// The n-th message (0-based) of an MCAP file.
    Message(u64),
    /// A row id of an SQLite bag's `messages` table.
    Row(i64),
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Location::File(offset) => write!(f, "record at byte {offset}"),
            Location::Chunk {
                chunk_offset,
                inner,
            } => write!(
                f,
                "record at byte {inner} of the chunk at byte {chunk_offset}"
            ),
            Location::Message(n) => write!(f, "message {n}"),
            Location::Row(id) => write!(f, "messages row id {id}"),
        }
    }
}

/// Receives a bag's messages in storage order.
pub trait BagVisitor {
    /// One message: its topic, the bag's receive (log) time in ns since the Unix epoch, and
    /// its serialised bytes.
    fn message(
        &mut self,
        topic: &TopicInfo,
        receive_ns: i128,
        data: &[u8],
        at: Location,
    ) -> Result<(), ImportError>;
}

/// `sensor_msgs/msg/Imu` -> `sensor_msgs/Imu`.
pub fn normalise_type(name: &str) -> String {
    name.replace("/msg/", "/")
}

/// ns since the Unix epoch as seconds with 9 decimals, for messages.
pub(crate) fn seconds(ns: i128) -> String {
    let sign = if ns < 0 { "-" } else { "" };
    let ns = ns.unsigned_abs();
    format!("{sign}{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

/// Drops a mapped bag's pages from this process's resident memory every
/// [`PageRelease::EVERY_BYTES`] read, so a bag read front to back holds about that much of
/// itself, not all of it (the pages stay in the OS's cache and fault back in if touched).
pub(crate) struct PageRelease<'a> {
    map: Option<&'a memmap2::Mmap>,
    since: usize,
}

impl<'a> PageRelease<'a> {
    const EVERY_BYTES: usize = 64 << 20;

    pub(crate) fn new(map: Option<&'a memmap2::Mmap>) -> Self {
        Self { map, since: 0 }
    }

    /// `bytes` more of the map read.
    pub(crate) fn advance(&mut self, bytes: usize) {
        self.since += bytes;
        if self.since < Self::EVERY_BYTES {
            return;
        }
        self.since = 0;
        if let Some(map) = self.map {
            // SAFETY: a read-only private map of a file nothing writes (`map_file`'s
            // contract): MADV_DONTNEED discards clean copies of file pages only, and the next
            // access reads the same bytes from the file again. Failing is harmless (the
            // pages just stay resident).
            let _ = unsafe { map.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) };
        }
    }
}

/// Maps a file into memory. The bag must not change while it is read (the usual contract of
/// a mapped file); a bag still being recorded is read through its size at opening.
pub(crate) fn map_file(path: &Path) -> Result<memmap2::Mmap, ImportError> {
    let file = std::fs::File::open(path).map_err(|e| ImportError::io(path, e))?;
    // SAFETY: read-only map of a file this process does not write; see the doc comment.
    unsafe { memmap2::Mmap::map(&file) }.map_err(|e| ImportError::io(path, e))
}

/// The first bytes of a zstd frame (a bag compressed whole, or one of its messages).
const ZSTD_MAGIC: &[u8] = &[0x28, 0xb5, 0x2f, 0xfd];

/// The storage of a bag file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Storage {
    Ros1,
    Mcap,
    Sqlite,
}

fn storage_of(head: &[u8]) -> Option<Storage> {
    if ros1::is_ros1_bag(head) {
        Some(Storage::Ros1)
    } else if mcap_file::is_mcap(head) {
        Some(Storage::Mcap)
    } else if sqlite::is_sqlite(head) {
        Some(Storage::Sqlite)
    } else {
        None
    }
}

/// True when `path`, whose first bytes are `head`, is a bag: a ROS1 bag, an MCAP file, a
/// rosbag2 SQLite file, or one of the last two compressed whole with zstd (`.mcap.zstd`,
/// `.db3.zstd`, as rosbag2's file compression names them).
pub fn is_bag(path: &Path, head: &[u8]) -> bool {
    let name = path.to_string_lossy();
    storage_of(head).is_some()
        || (head.starts_with(ZSTD_MAGIC)
            && (name.ends_with(".mcap.zstd") || name.ends_with(".db3.zstd")))
}

/// Reads every message of the bag file at `path` into `visitor`.
fn visit(path: &Path, visitor: &mut dyn BagVisitor) -> Result<(), ImportError> {
    let head = {
        let mut head = [0u8; 16];
        let mut file = std::fs::File::open(path).map_err(|e| ImportError::io(path, e))?;
        let n = std::io::Read::read(&mut file, &mut head).map_err(|e| ImportError::io(path, e))?;
        head[..n].to_vec()
    };
    match storage_of(&head) {
        Some(Storage::Ros1) => ros1::read(path, visitor),
        Some(Storage::Mcap) => mcap_file::read(path, visitor),
        Some(Storage::Sqlite) => sqlite::read(path, visitor),
        None if head.starts_with(ZSTD_MAGIC) => visit_zstd_file(path, visitor),
        None => Err(ImportError::UnknownDataset {
            path: path.to_path_buf(),
            reason: "not a ROS1 bag, an MCAP file nor an SQLite database".into(),
        }),
    }
}

/// A bag compressed whole (rosbag2's `compression_mode: file`): decompressed into a
/// temporary file (SQLite reads files), then read as its storage.
fn visit_zstd_file(path: &Path, visitor: &mut dyn BagVisitor) -> Result<(), ImportError> {
    let file = std::fs::File::open(path).map_err(|e| ImportError::io(path, e))?;
    let mut decoder =
        zstd::stream::read::Decoder::new(file).map_err(|e| ImportError::io(path, e))?;
    let mut plain = tempfile::NamedTempFile::new().map_err(|e| ImportError::io(path, e))?;
    std::io::copy(&mut decoder, &mut plain).map_err(|e| ImportError::Damaged {
        path: path.to_path_buf(),
        message: format!("zstd-compressed bag cannot be decompressed: {e}"),
    })?;
    let mut head = [0u8; 16];
    let plain_path = plain.path().to_path_buf();
    let n = std::io::Read::read(
        &mut std::fs::File::open(&plain_path).map_err(|e| ImportError::io(path, e))?,
        &mut head,
    )
    .map_err(|e| ImportError::io(path, e))?;
    // Errors name the compressed file, not the temporary one.
    let rename = |e: ImportError| match e {
        ImportError::Corrupt {
            offset, message, ..
        } => ImportError::Corrupt {
            path: path.to_path_buf(),
            offset,
            message: format!("(after zstd decompression) {message}"),
        },
        ImportError::Damaged { message, .. } => ImportError::Damaged {
            path: path.to_path_buf(),
            message: format!("(after zstd decompression) {message}"),
        },
        other => other,
    };
    match storage_of(&head[..n]) {
        Some(Storage::Mcap) => {
            let bytes = std::fs::read(&plain_path).map_err(|e| ImportError::io(path, e))?;
            mcap_file::read_bytes(path, &bytes, None, visitor).map_err(rename)
        }
        Some(Storage::Sqlite) => sqlite::read(&plain_path, visitor).map_err(rename),
        _ => Err(ImportError::Damaged {
            path: path.to_path_buf(),
            message: "decompressed, it is neither an MCAP file nor an SQLite database".into(),
        }),
    }
}

/// What the import of one bag found, topic by topic: one line per fact, for the user.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BagReport {
    pub notes: Vec<String>,
}

/// Reads the bag at `path` into recordings named after their topics, and the report.
pub fn read(path: &Path) -> Result<(Vec<(String, ImuRecording)>, BagReport), ImportError> {
    read_only(path, None)
}

/// As [`read`], decoding only the topic `only` (its name, `/imu/data`, or its file name,
/// `imu-data`) where given: the other topics' messages are counted, not kept, so a long
/// bag's other sensors cost no memory.
pub fn read_only(
    path: &Path,
    only: Option<&str>,
) -> Result<(Vec<(String, ImuRecording)>, BagReport), ImportError> {
    crate::import::rows::collect_named(path, |sink| stream(path, only, sink))
}

/// Streams the bag at `path` into `sink`, one sensor per recording it gives (named after its
/// topic, in topic name order; only the topic `only` where given, as [`read_only`]), in two
/// passes over the bag and memory that does not grow with it (`collect`'s documentation);
/// the report.
pub fn stream(
    path: &Path,
    only: Option<&str>,
    sink: &mut dyn crate::import::rows::SensorRows,
) -> Result<BagReport, ImportError> {
    let only = only.map(file_name_of_topic);
    let mut survey = collect::Collector::new(path, collect::Out::Count);
    survey.only = only.clone();
    visit(path, &mut survey).map_err(|e| survey.with_last_message(e))?;
    let (layouts, outputs) = survey.plan()?;
    sink.begin(layouts)?;
    let mut writer = collect::Collector::new(path, collect::Out::Rows { sink, outputs });
    writer.only = only;
    visit(path, &mut writer).map_err(|e| writer.with_last_message(e))?;
    Ok(survey.report(Some(&writer.gaps())))
}

/// Streams the Imu topic `topic` of the bag at `path`: its kept samples (time s, angular
/// velocity rad/s, specific force m/s^2, forward-right-down; the same as an import keeps) go
/// to `sink` as they are read, nothing is stored, so memory does not grow with the bag.
/// Returns what the topic held (`None` when it is not an Imu topic of this bag) and the
/// report (the topic's notes but its sampling, which its reader measures; the other
/// topics counted).
pub fn stream_imu_topic(
    path: &Path,
    topic: &str,
    sink: collect::ImuSink<'_>,
) -> Result<(Option<StreamedImu>, BagReport), ImportError> {
    let mut collector = collect::Collector::new(path, collect::Out::Imu(sink));
    collector.only = Some(file_name_of_topic(topic));
    visit(path, &mut collector).map_err(|e| collector.with_last_message(e))?;
    Ok((collector.streamed_imu(), collector.report(None)))
}

mod collect;
pub use collect::{file_name_of_topic, StreamedImu};

#[cfg(test)]
mod tests {
    //! Damaged bags of every storage import cleanly (`crate::import::fuzz` says what a clean
    //! answer is): the bags `tests/ros/make.py` wrote with the `rosbags` package.

    use crate::import::fuzz::{arb_mutation, check_damaged, config};
    use crate::import::Dataset;
    use proptest::prelude::*;

    const BAGS: [&[u8]; 5] = [
        include_bytes!("../../../tests/ros/ros1-plain.bag"),
        include_bytes!("../../../tests/ros/ros1-bz2.bag"),
        include_bytes!("../../../tests/ros/ros1-lz4.bag"),
        include_bytes!("../../../tests/ros/ros2-mcap/ros2-mcap.mcap"),
        include_bytes!("../../../tests/ros/ros2-sqlite3/ros2-sqlite3.db3"),
    ];

    proptest! {
        #![proptest_config(config(160, 0x5BA6_2026))]

        #[test]
        fn damaged_bags_are_read_or_refused_cleanly(
            bag in 0..BAGS.len(),
            mutations in proptest::collection::vec(arb_mutation(), 1..4),
        ) {
            check_damaged(Dataset::RosBag, BAGS[bag], &mutations)?;
        }
    }
}
