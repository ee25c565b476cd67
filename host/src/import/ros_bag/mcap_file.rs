//! ROS2 bags stored as MCAP (the default storage since ROS 2 Iron; common in Humble), read
//! with the `mcap` crate (Foxglove's, the format's own): chunks uncompressed, `zstd` or
//! `lz4`, checked against their CRCs. Each channel's `message_encoding` says how its
//! messages are serialised (`cdr`, or `ros1` for a ROS1 recording kept in MCAP); its schema's
//! name is the message type. Messages are visited in file order.

use std::path::Path;

use super::messages::Encoding;
use super::{BagVisitor, Location, TopicInfo};
use crate::import::ImportError;

/// The first bytes of an MCAP file.
pub const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// True when `head` starts an MCAP file.
pub fn is_mcap(head: &[u8]) -> bool {
    head.starts_with(MAGIC)
}

/// Reads the MCAP file at `path`, giving every message to `visitor`.
pub fn read(path: &Path, visitor: &mut dyn BagVisitor) -> Result<(), ImportError> {
    let map = super::map_file(path)?;
    read_bytes(path, &map, Some(&map), visitor)
}

/// Reads MCAP bytes (a file's, or a whole-file-compressed bag's after decompression);
/// `map`, where the bytes are a mapped file, has its pages released as they are read.
pub fn read_bytes(
    path: &Path,
    bytes: &[u8],
    map: Option<&memmap2::Mmap>,
    visitor: &mut dyn BagVisitor,
) -> Result<(), ImportError> {
    let mut release = super::PageRelease::new(map);
    let stream = mcap::MessageStream::new(bytes).map_err(|e| ImportError::Damaged {
        path: path.to_path_buf(),
        message: format!("not a readable MCAP file: {e}"),
    })?;
    let mut topics: std::collections::BTreeMap<u16, TopicInfo> = Default::default();
    let mut last_time_ns = None;
    for (index, message) in stream.enumerate() {
        let message = message.map_err(|e| ImportError::Damaged {
            path: path.to_path_buf(),
            message: format!(
                "MCAP damaged after {index} messages{}: {e}",
                match last_time_ns {
                    Some(t) => format!(" (the last logged at {} s)", super::seconds(t)),
                    None => String::new(),
                }
            ),
        })?;
        let channel = &message.channel;
        let topic = topics.entry(channel.id).or_insert_with(|| TopicInfo {
            name: channel.topic.clone(),
            msg_type: channel
                .schema
                .as_ref()
                .map_or_else(String::new, |s| super::normalise_type(&s.name)),
            encoding: match channel.message_encoding.as_str() {
                "cdr" => Some(Encoding::Cdr),
                "ros1" => Some(Encoding::Ros1),
                _ => None,
            },
        });
        let time = i128::from(message.log_time);
        last_time_ns = Some(time);
        visitor.message(topic, time, &message.data, Location::Message(index as u64))?;
        // About the bytes the message took in the file (chunks compress; this only paces
        // the release).
        release.advance(message.data.len() + 32);
    }
    Ok(())
}
