//! ROS1 bags (format 2.0, `#ROSBAG V2.0`), read front to back: the bag header, then chunks
//! (uncompressed, `bz2` or `lz4`) holding connection and message-data records, then the
//! index section (connections again, chunk infos, index data), which is not needed.
//!
//! A record is `u32 header length, header, u32 data length, data`; a header is a list of
//! `u32 length, name=value` fields, among them `op`, the record's kind. Reading the chunks
//! in file order (not through the index) also reads a bag whose recording was not closed
//! (its header's `index_pos` still 0), the common case `rosbag reindex` exists for.
//!
//! Written here rather than through the `rosbag` crate (0.6): it panics on a truncated bag
//! and on an unindexed one (it slices the file up to `index_pos`), reads the index it does
//! not need to, and reports no offsets. Decompression is the `bzip2` and `lz4_flex` crates'.

use std::io::Read as _;
use std::path::Path;

use super::messages::Encoding;
use super::{BagVisitor, Location, TopicInfo};
use crate::import::ImportError;

/// The first bytes of a ROS1 bag of format 2.0.
pub const MAGIC: &[u8] = b"#ROSBAG V2.0\n";

const OP_MESSAGE_DATA: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_INDEX_DATA: u8 = 0x04;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;

/// The largest chunk taken: ROS writes 768 KiB chunks by default; a stated size beyond this
/// is damage, not data.
const MAX_CHUNK_BYTES: u64 = 1 << 31;

/// True when `head` starts a ROS1 bag (any version: the reader refuses the old 1.2 itself).
pub fn is_ros1_bag(head: &[u8]) -> bool {
    head.starts_with(b"#ROSBAG V")
}

/// One record: its header's fields and its data, both borrowed from a buffer.
struct Record<'a> {
    fields: Vec<(&'a str, &'a [u8])>,
    data: &'a [u8],
    /// Byte offset of the record in its buffer.
    offset: u64,
}

impl Record<'_> {
    fn field(&self, name: &str) -> Option<&[u8]> {
        self.fields.iter().find(|f| f.0 == name).map(|f| f.1)
    }
    fn op(&self) -> Option<u8> {
        self.field("op").and_then(|v| v.first().copied())
    }
}

/// The record at `*pos` of `bytes` (advancing `*pos` past it), or at which byte and why
/// it cannot be read.
fn next_record<'a>(bytes: &'a [u8], pos: &mut usize) -> Result<Record<'a>, (u64, String)> {
    let take = |pos: &mut usize, what: &str| -> Result<&'a [u8], (u64, String)> {
        let at = *pos;
        let len = bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")) as usize)
            .ok_or_else(|| {
                (
                    at as u64,
                    format!("the data ends inside a record's {what} length"),
                )
            })?;
        let body = bytes.get(at + 4..at + 4 + len).ok_or_else(|| {
            (
                at as u64,
                format!(
                    "a record's {what} of {len} bytes runs past the end ({} bytes left): \
                     the bag is cut short or damaged",
                    bytes.len() - at - 4
                ),
            )
        })?;
        *pos = at + 4 + len;
        Ok(body)
    };
    let offset = *pos as u64;
    let header = take(pos, "header")?;
    let fields = header_fields(header).map_err(|m| (offset, m))?;
    let data = take(pos, "data")?;
    Ok(Record {
        fields,
        data,
        offset,
    })
}

/// Every record of `bytes`, in order, read as they are asked for.
fn records(bytes: &[u8]) -> impl Iterator<Item = Result<Record<'_>, (u64, String)>> {
    let mut pos = 0usize;
    let mut failed = false;
    std::iter::from_fn(move || {
        if pos >= bytes.len() || failed {
            return None;
        }
        let record = next_record(bytes, &mut pos);
        failed = record.is_err();
        Some(record)
    })
}

/// The `name=value` fields of a record header.
fn header_fields(mut header: &[u8]) -> Result<Vec<(&str, &[u8])>, String> {
    let mut fields = Vec::new();
    while !header.is_empty() {
        let len = header
            .get(..4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")) as usize)
            .ok_or("a header field's length is cut short")?;
        let field = header
            .get(4..4 + len)
            .ok_or_else(|| format!("a header field of {len} bytes runs past its header"))?;
        let eq = field
            .iter()
            .position(|&b| b == b'=')
            .ok_or("a header field without `=`")?;
        let name =
            std::str::from_utf8(&field[..eq]).map_err(|_| "a header field's name is not text")?;
        fields.push((name, &field[eq + 1..]));
        header = &header[4 + len..];
    }
    Ok(fields)
}

fn u32_field(record: &Record<'_>, name: &str) -> Result<u32, String> {
    match record.field(name) {
        Some(v) if v.len() == 4 => Ok(u32::from_le_bytes(v.try_into().expect("4 bytes"))),
        Some(v) => Err(format!("field `{name}` has {} bytes, not 4", v.len())),
        None => Err(format!("no field `{name}`")),
    }
}

fn text_field<'a>(fields: &[(&'a str, &'a [u8])], name: &str) -> Result<&'a str, String> {
    let value = fields
        .iter()
        .find(|f| f.0 == name)
        .ok_or_else(|| format!("no field `{name}`"))?
        .1;
    std::str::from_utf8(value).map_err(|_| format!("field `{name}` is not text"))
}

/// Reads the bag at `path`, giving every message to `visitor` in file order.
pub fn read(path: &Path, visitor: &mut dyn BagVisitor) -> Result<(), ImportError> {
    let map = super::map_file(path)?;
    let bytes: &[u8] = &map;
    let mut release = super::PageRelease::new(Some(&map));
    let corrupt = |offset: u64, message: String| ImportError::Corrupt {
        path: path.to_path_buf(),
        offset,
        message,
    };
    if !bytes.starts_with(MAGIC) {
        let version = bytes.split(|&b| b == b'\n').next().unwrap_or_default();
        return Err(corrupt(
            0,
            format!(
                "`{}` is not a ROS bag of format 2.0 (the only one read)",
                String::from_utf8_lossy(version)
            ),
        ));
    }
    let base = MAGIC.len() as u64;
    let mut top = records(&bytes[MAGIC.len()..]);
    match top.next() {
        Some(Ok(header)) if header.op() == Some(OP_BAG_HEADER) => {}
        Some(Err((at, m))) => return Err(corrupt(base + at, m)),
        _ => {
            return Err(corrupt(
                base,
                "the first record is not the bag header".into(),
            ))
        }
    }
    let mut connections = Connections::default();
    for record in top {
        let record = record.map_err(|(at, m)| corrupt(base + at, m))?;
        let record = &record;
        let at = base + record.offset;
        release.advance(record.data.len());
        match record.op() {
            Some(OP_CHUNK) => read_chunk(path, record, at, &mut connections, visitor)?,
            Some(OP_CONNECTION) => connections
                .add(record)
                .map_err(|m| corrupt(at, format!("connection record: {m}")))?,
            Some(OP_MESSAGE_DATA) => connections
                .visit(record, Location::File(at), visitor)
                .map_err(|e| e.unwrap_or_else(|m| corrupt(at, m)))?,
            Some(OP_INDEX_DATA | OP_CHUNK_INFO) => {}
            Some(op) => return Err(corrupt(at, format!("unknown record op 0x{op:02x}"))),
            None => return Err(corrupt(at, "a record without `op`".into())),
        }
    }
    Ok(())
}

/// Decompresses one chunk and visits its records.
fn read_chunk(
    path: &Path,
    chunk: &Record<'_>,
    at: u64,
    connections: &mut Connections,
    visitor: &mut dyn BagVisitor,
) -> Result<(), ImportError> {
    let corrupt = |message: String| ImportError::Corrupt {
        path: path.to_path_buf(),
        offset: at,
        message: format!("chunk: {message}"),
    };
    let size = u64::from(u32_field(chunk, "size").map_err(corrupt)?);
    if size > MAX_CHUNK_BYTES {
        return Err(corrupt(format!(
            "states {size} bytes, more than any ROS chunk"
        )));
    }
    let compression = text_field(&chunk.fields, "compression").map_err(corrupt)?;
    let data: std::borrow::Cow<'_, [u8]> = match compression {
        "none" => chunk.data.into(),
        "bz2" => decompress(bzip2::read::BzDecoder::new(chunk.data), size).map_err(corrupt)?,
        "lz4" => {
            decompress(lz4_flex::frame::FrameDecoder::new(chunk.data), size).map_err(corrupt)?
        }
        other => {
            return Err(corrupt(format!(
                "compression `{other}` is none of `none`, `bz2`, `lz4`"
            )))
        }
    };
    if data.len() as u64 != size {
        return Err(corrupt(format!(
            "{} bytes after decompression, the header states {size}",
            data.len()
        )));
    }
    for record in records(&data) {
        let record = &record.map_err(|(inner, m)| {
            corrupt(format!("byte {inner} of its {compression} data: {m}"))
        })?;
        let location = Location::Chunk {
            chunk_offset: at,
            inner: record.offset,
        };
        match record.op() {
            Some(OP_CONNECTION) => connections
                .add(record)
                .map_err(|m| corrupt(format!("{location}: connection record: {m}")))?,
            Some(OP_MESSAGE_DATA) => connections
                .visit(record, location, visitor)
                .map_err(|e| e.unwrap_or_else(|m| corrupt(format!("{location}: {m}"))))?,
            Some(op) => {
                return Err(corrupt(format!(
                    "{location}: record op 0x{op:02x} inside a chunk"
                )))
            }
            None => return Err(corrupt(format!("{location}: a record without `op`"))),
        }
    }
    Ok(())
}

/// Reads a decoder to its end, at most `size` bytes and one more (so a longer output shows).
fn decompress(
    decoder: impl std::io::Read,
    size: u64,
) -> Result<std::borrow::Cow<'static, [u8]>, String> {
    // A damaged header may state gigabytes: grow past 64 MiB only as data come.
    let mut out = Vec::with_capacity(size.min(1 << 26) as usize);
    decoder
        .take(size + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("cannot be decompressed: {e}"))?;
    Ok(out.into())
}

/// The connections seen so far: id -> topic.
#[derive(Default)]
struct Connections {
    topics: std::collections::BTreeMap<u32, TopicInfo>,
}

impl Connections {
    fn add(&mut self, record: &Record<'_>) -> Result<(), String> {
        let id = u32_field(record, "conn")?;
        let topic = text_field(&record.fields, "topic")?.to_string();
        let fields = header_fields(record.data)?;
        let msg_type = text_field(&fields, "type")?;
        self.topics.insert(
            id,
            TopicInfo {
                name: topic,
                msg_type: super::normalise_type(msg_type),
                encoding: Some(Encoding::Ros1),
            },
        );
        Ok(())
    }

    /// Gives a message-data record to the visitor. `Err(Ok(e))` is the visitor's error,
    /// `Err(Err(m))` a malformed record.
    fn visit(
        &self,
        record: &Record<'_>,
        location: Location,
        visitor: &mut dyn BagVisitor,
    ) -> Result<(), Result<ImportError, String>> {
        let id = u32_field(record, "conn").map_err(Err)?;
        let time = match record.field("time") {
            Some(v) if v.len() == 8 => {
                let sec = u32::from_le_bytes(v[..4].try_into().expect("4 bytes"));
                let nsec = u32::from_le_bytes(v[4..].try_into().expect("4 bytes"));
                i128::from(sec) * 1_000_000_000 + i128::from(nsec)
            }
            _ => return Err(Err("message data without an 8-byte `time`".into())),
        };
        let topic = self.topics.get(&id).ok_or_else(|| {
            Err(format!(
                "message data on connection {id}, which no record defined"
            ))
        })?;
        visitor
            .message(topic, time, record.data, location)
            .map_err(Ok)
    }
}
