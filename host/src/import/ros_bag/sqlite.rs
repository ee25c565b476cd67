//! ROS2 bags stored in SQLite (`.db3`, rosbag2's default storage up to ROS 2 Humble), read
//! with `rusqlite` (SQLite itself, built in): the `topics` table names each topic, its type
//! and serialisation format; the `messages` table holds each message's topic, receive time
//! (ns since the Unix epoch) and serialised bytes. Messages are visited in time order, as
//! `ros2 bag play` gives them.

use std::path::Path;

use rusqlite::{Connection, OpenFlags};

use super::messages::Encoding;
use super::{BagVisitor, Location, TopicInfo};
use crate::import::ImportError;

/// The first bytes of an SQLite 3 database.
pub const MAGIC: &[u8] = b"SQLite format 3\0";

/// True when `head` starts an SQLite 3 database.
pub fn is_sqlite(head: &[u8]) -> bool {
    head.starts_with(MAGIC)
}

/// Reads the rosbag2 SQLite database at `path`, giving every message to `visitor`.
pub fn read(path: &Path, visitor: &mut dyn BagVisitor) -> Result<(), ImportError> {
    let corrupt = |message: String| ImportError::Damaged {
        path: path.to_path_buf(),
        message,
    };
    let db = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| corrupt(format!("not a readable SQLite database: {e}")))?;
    let topics = read_topics(&db).map_err(|e| corrupt(format!("table `topics`: {e}")))?;
    let mut statement = db
        .prepare("SELECT id, topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
        .map_err(|e| corrupt(format!("table `messages`: {e}")))?;
    let mut rows = statement
        .query([])
        .map_err(|e| corrupt(format!("table `messages`: {e}")))?;
    let mut last: Option<(i64, i64)> = None;
    loop {
        let row = rows.next().map_err(|e| {
            corrupt(match last {
                Some((id, t)) => format!(
                    "table `messages` damaged after row id {id} (time {} s): {e}",
                    super::seconds(i128::from(t))
                ),
                None => format!("table `messages`: {e}"),
            })
        })?;
        let Some(row) = row else { break };
        let read = |row: &rusqlite::Row<'_>| -> rusqlite::Result<(i64, i64, i64, Vec<u8>)> {
            Ok((row.get(0)?, row.get(1)?, row.get(2)?, row.get(3)?))
        };
        let (id, topic_id, time, data) = read(row).map_err(|e| {
            corrupt(format!(
                "table `messages`, row id {}: {e}",
                last.map_or(0, |l| l.0 + 1)
            ))
        })?;
        last = Some((id, time));
        let topic = topics.get(&topic_id).ok_or_else(|| {
            corrupt(format!(
                "table `messages`, row id {id}: topic id {topic_id} is not in table `topics`"
            ))
        })?;
        visitor.message(topic, i128::from(time), &data, Location::Row(id))?;
    }
    Ok(())
}

fn read_topics(db: &Connection) -> rusqlite::Result<std::collections::BTreeMap<i64, TopicInfo>> {
    let mut statement = db.prepare("SELECT id, name, type, serialization_format FROM topics")?;
    let rows = statement.query_map([], |row| {
        let format: String = row.get(3)?;
        Ok((
            row.get::<_, i64>(0)?,
            TopicInfo {
                name: row.get(1)?,
                msg_type: super::normalise_type(&row.get::<_, String>(2)?),
                encoding: match format.as_str() {
                    "cdr" => Some(Encoding::Cdr),
                    "ros1" => Some(Encoding::Ros1),
                    _ => None,
                },
            },
        ))
    })?;
    rows.collect()
}
