//! The ULog message walk: the header, then one message at a time read from the file, each
//! checked whole before it is used; every error names the message's byte offset, index and
//! type. Only one message is in memory at a time, so a walk holds what it keeps, not the file.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use super::{
    corrupt, flatten, hex, parse_format, BasicType, DefaultParameter, Dropout, FieldDecl,
    ImportError, InfoValue, Layout, LoggedString, Sample, Topic, ULog, FLAG_BITS_LEN, HEADER_LEN,
    INCOMPAT_DATA_APPENDED, MAGIC, MAX_VERSION, MESSAGE_HEADER_LEN, SYNC_MAGIC,
};
use crate::import::read_up_to;

/// Where a message is: byte offset, 0-based index, type byte.
#[derive(Debug, Clone, Copy)]
struct At {
    offset: usize,
    index: usize,
    kind: u8,
}

/// The state of a parse.
pub(super) struct Parser<'v, R> {
    reader: R,
    log: ULog,
    layouts: BTreeMap<String, Layout>,
    /// Active subscriptions: msg_id -> index into `log.topics`.
    active: BTreeMap<u16, usize>,
    /// Offsets of appended data (`B`), checked to fall on message starts, and whether a
    /// message started there.
    appended: Vec<(u64, bool)>,
    /// Which topics hold their samples.
    keep: &'v dyn Fn(&str) -> bool,
    /// Sees every sample.
    visit: &'v mut dyn FnMut(Sample) -> Result<(), ImportError>,
    /// A data payload padded to its format's size.
    padded: Vec<u8>,
}

/// A key `type name` and its value: the payload of `I`, `P` (after `skip` bytes: `M` has
/// `is_continued`, `Q` its `default_types` first).
fn split_key(payload: &[u8], skip: usize) -> Result<(FieldDecl, &[u8]), String> {
    let key_len = usize::from(
        *payload
            .get(skip)
            .ok_or_else(|| format!("payload of {} bytes has no key length", payload.len()))?,
    );
    let key_end = skip + 1 + key_len;
    let key = payload.get(skip + 1..key_end).ok_or_else(|| {
        format!(
            "key of {key_len} bytes overruns the payload of {} bytes",
            payload.len()
        )
    })?;
    let key = std::str::from_utf8(key).map_err(|_| format!("key {:02X?} is not UTF-8", key))?;
    let decl = FieldDecl::parse(key).map_err(|e| format!("key: {e}"))?;
    Ok((decl, &payload[key_end..]))
}

/// The value of key `decl`: its basic type and array length must account for every byte.
fn info_value(decl: &FieldDecl, value: &[u8]) -> Result<InfoValue, String> {
    let kind = BasicType::from_name(&decl.type_name).ok_or_else(|| {
        format!(
            "key `{}` has the type `{}`, not a basic type",
            decl.name, decl.type_name
        )
    })?;
    let count = decl.array_len.unwrap_or(1);
    if value.len() != count * kind.size() {
        return Err(format!(
            "key `{}`: value of {} bytes, its type needs {}",
            decl.name,
            value.len(),
            count * kind.size()
        ));
    }
    Ok(match kind {
        BasicType::Char => InfoValue::Text(String::from_utf8_lossy(value).into_owned()),
        _ => InfoValue::Numbers(
            value
                .chunks_exact(kind.size())
                .filter_map(|c| kind.decode(c))
                .collect(),
        ),
    })
}

/// The single number a parameter holds.
fn parameter_value(decl: &FieldDecl, value: &[u8]) -> Result<f64, String> {
    match info_value(decl, value)? {
        InfoValue::Numbers(v) if v.len() == 1 => Ok(v[0]),
        _ => Err(format!(
            "parameter `{}` of type `{}` is not one number",
            decl.name, decl.type_name
        )),
    }
}

/// Little-endian u16 / u64 at `at` (the caller has checked the length).
fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

/// Checks a payload has at least `min` bytes.
fn at_least(payload: &[u8], min: usize, what: &str) -> Result<(), String> {
    if payload.len() < min {
        return Err(format!(
            "payload of {} bytes, {what} needs at least {min}",
            payload.len()
        ));
    }
    Ok(())
}

impl<'v, R: Read> Parser<'v, R> {
    /// Reads and checks the header and starts a parse of `reader`.
    pub(super) fn new(
        path: &Path,
        mut reader: R,
        keep: &'v dyn Fn(&str) -> bool,
        visit: &'v mut dyn FnMut(Sample) -> Result<(), ImportError>,
    ) -> Result<Self, ImportError> {
        let mut header = [0u8; HEADER_LEN];
        let got = read_up_to(&mut reader, &mut header).map_err(|e| ImportError::io(path, e))?;
        let head = &header[..got.min(MAGIC.len())];
        if head != &MAGIC[..head.len()] {
            return Err(corrupt(
                path,
                0,
                format!(
                    "not a ULog file: magic {}, expected {}",
                    hex(head),
                    hex(&MAGIC)
                ),
            ));
        }
        if got < HEADER_LEN {
            return Err(corrupt(
                path,
                0,
                format!("the file ends {got} byte(s) into the {HEADER_LEN}-byte ULog header"),
            ));
        }
        let version = header[7];
        if version > MAX_VERSION {
            return Err(corrupt(
                path,
                7,
                format!("ULog version {version}: this reader knows versions 0 to {MAX_VERSION}"),
            ));
        }
        Ok(Parser {
            reader,
            log: ULog {
                path: path.to_path_buf(),
                version,
                start_time_us: u64_at(&header, 8),
                compat_flags: [0; 8],
                incompat_flags: [0; 8],
                formats: BTreeMap::new(),
                topics: Vec::new(),
                info: BTreeMap::new(),
                multi_info: BTreeMap::new(),
                parameters: BTreeMap::new(),
                parameter_offsets: BTreeMap::new(),
                default_parameters: Vec::new(),
                logged: Vec::new(),
                dropouts: Vec::new(),
                sync_count: 0,
                message_count: 0,
            },
            layouts: BTreeMap::new(),
            active: BTreeMap::new(),
            appended: Vec::new(),
            keep,
            visit,
            padded: Vec::new(),
        })
    }

    fn error(&self, at: At, message: impl std::fmt::Display) -> ImportError {
        corrupt(
            &self.log.path,
            at.offset as u64,
            format!(
                "message {} ('{}'): {message}",
                at.index,
                char::from(at.kind).escape_default()
            ),
        )
    }

    /// Walks every message, then checks every format resolves and the appended-data
    /// offsets fall on message starts.
    pub(super) fn run(mut self) -> Result<ULog, ImportError> {
        let mut offset = HEADER_LEN;
        let mut payload = Vec::new();
        let io = |path: &Path, e| ImportError::io(path, e);
        loop {
            let index = self.log.message_count;
            let mut head = [0u8; MESSAGE_HEADER_LEN];
            let got = read_up_to(&mut self.reader, &mut head).map_err(|e| io(&self.log.path, e))?;
            if got == 0 {
                break;
            }
            if got < MESSAGE_HEADER_LEN {
                return Err(corrupt(
                    &self.log.path,
                    offset as u64,
                    format!("message {index}: the file ends {got} byte(s) into a message header"),
                ));
            }
            let size = usize::from(u16_at(&head, 0));
            let at = At {
                offset,
                index,
                kind: head[2],
            };
            payload.resize(size, 0);
            let got =
                read_up_to(&mut self.reader, &mut payload).map_err(|e| io(&self.log.path, e))?;
            if got < size {
                return Err(self.error(
                    at,
                    format!("truncated: a payload of {size} bytes, but the file ends after {got}"),
                ));
            }
            self.message(at, &payload)?;
            for (start, found) in &mut self.appended {
                *found |= *start == offset as u64;
            }
            self.log.message_count += 1;
            offset += MESSAGE_HEADER_LEN + size;
        }
        let names: Vec<String> = self.log.formats.keys().cloned().collect();
        for name in names {
            self.layout(&name)?;
        }
        for &(a, found) in &self.appended {
            if a != offset as u64 && !found {
                return Err(corrupt(
                    &self.log.path,
                    a,
                    "the flag bits' appended-data offset is not the start of a message",
                ));
            }
        }
        Ok(self.log)
    }

    /// Handles one message of type `at.kind` and payload `p`.
    fn message(&mut self, at: At, p: &[u8]) -> Result<(), ImportError> {
        let result = match at.kind {
            b'B' => self.flag_bits(at, p),
            b'F' => self.format(at, p),
            b'I' => self.info(p),
            b'M' => self.multi_info(p),
            b'P' => self.parameter(at, p),
            b'Q' => self.default_parameter(p),
            b'A' => return self.subscribe(at, p),
            b'R' => self.unsubscribe(p),
            b'D' => return self.data(at, p),
            b'L' => self.logged(at, p, false),
            b'C' => self.logged(at, p, true),
            b'S' => {
                self.log.sync_count += 1;
                (p == SYNC_MAGIC)
                    .then_some(())
                    .ok_or_else(|| format!("sync marker {}, expected {}", hex(p), hex(&SYNC_MAGIC)))
            }
            b'O' => {
                if p.len() == 2 {
                    self.log.dropouts.push(Dropout {
                        offset: at.offset as u64,
                        duration_ms: u16_at(p, 0),
                    });
                    Ok(())
                } else {
                    Err(format!("dropout payload of {} bytes, expected 2", p.len()))
                }
            }
            other => Err(format!(
                "unknown message type 0x{other:02X} with a payload of {} bytes",
                p.len()
            )),
        };
        result.map_err(|e| self.error(at, e))
    }

    fn flag_bits(&mut self, at: At, p: &[u8]) -> Result<(), String> {
        if at.index != 0 {
            return Err("flag bits after the first message".into());
        }
        at_least(p, FLAG_BITS_LEN, "the flag bits")?;
        self.log.compat_flags.copy_from_slice(&p[..8]);
        self.log.incompat_flags.copy_from_slice(&p[8..16]);
        let unknown: Vec<String> = self
            .log
            .incompat_flags
            .iter()
            .enumerate()
            .filter_map(|(i, b)| {
                let b = if i == 0 {
                    b & !INCOMPAT_DATA_APPENDED
                } else {
                    *b
                };
                (b != 0).then(|| format!("byte {i} = 0x{b:02X}"))
            })
            .collect();
        if !unknown.is_empty() {
            return Err(format!(
                "unknown incompatible flags ({}): the log needs a newer reader",
                unknown.join(", ")
            ));
        }
        if self.log.incompat_flags[0] & INCOMPAT_DATA_APPENDED != 0 {
            self.appended = (0..3)
                .map(|k| u64_at(p, 16 + 8 * k))
                .filter(|o| *o != 0)
                .map(|o| (o, false))
                .collect();
        }
        Ok(())
    }

    fn format(&mut self, at: At, p: &[u8]) -> Result<(), String> {
        let text =
            std::str::from_utf8(p).map_err(|_| format!("format text {:02X?} is not UTF-8", p))?;
        let format = parse_format(text, at.offset as u64)?;
        if let Some(old) = self.log.formats.get(&format.name) {
            if old.fields != format.fields {
                return Err(format!(
                    "format `{}` redefined differently (first at byte offset {})",
                    format.name, old.offset
                ));
            }
            return Ok(());
        }
        self.log.formats.insert(format.name.clone(), format);
        Ok(())
    }

    fn info(&mut self, p: &[u8]) -> Result<(), String> {
        let (decl, value) = split_key(p, 0)?;
        let value = info_value(&decl, value)?;
        self.log.info.insert(decl.name, value);
        Ok(())
    }

    fn multi_info(&mut self, p: &[u8]) -> Result<(), String> {
        at_least(p, 2, "a multi information message")?;
        let continued = p[0] != 0;
        let (decl, value) = split_key(p, 1)?;
        let value = info_value(&decl, value)?;
        let values = self.log.multi_info.entry(decl.name.clone()).or_default();
        match (continued, values.last_mut(), value) {
            (false, _, value) => values.push(value),
            (true, Some(InfoValue::Text(text)), InfoValue::Text(more)) => text.push_str(&more),
            (true, Some(InfoValue::Numbers(v)), InfoValue::Numbers(more)) => v.extend(more),
            (true, _, _) => {
                return Err(format!(
                    "continues `{}`, which has no earlier value of its type",
                    decl.name
                ))
            }
        }
        Ok(())
    }

    fn parameter(&mut self, at: At, p: &[u8]) -> Result<(), String> {
        let (decl, value) = split_key(p, 0)?;
        let value = parameter_value(&decl, value)?;
        self.log
            .parameter_offsets
            .entry(decl.name.clone())
            .or_default()
            .push(at.offset as u64);
        self.log
            .parameters
            .entry(decl.name)
            .or_default()
            .push(value);
        Ok(())
    }

    fn default_parameter(&mut self, p: &[u8]) -> Result<(), String> {
        at_least(p, 2, "a default parameter")?;
        let (decl, value) = split_key(p, 1)?;
        let value = parameter_value(&decl, value)?;
        self.log.default_parameters.push(DefaultParameter {
            default_types: p[0],
            name: decl.name,
            value,
        });
        Ok(())
    }

    /// The layout of format `name`, resolved once; errors name the `F` message at fault.
    fn layout(&mut self, name: &str) -> Result<Layout, ImportError> {
        if let Some(layout) = self.layouts.get(name) {
            return Ok(layout.clone());
        }
        let layout = flatten(&self.log.formats, name, &mut Vec::new())
            .map_err(|(offset, e)| corrupt(&self.log.path, offset, format!("format: {e}")))?;
        self.layouts.insert(name.to_string(), layout.clone());
        Ok(layout)
    }

    fn subscribe(&mut self, at: At, p: &[u8]) -> Result<(), ImportError> {
        at_least(p, 4, "a subscription").map_err(|e| self.error(at, e))?;
        let multi_id = p[0];
        let msg_id = u16_at(p, 1);
        let name = std::str::from_utf8(&p[3..])
            .map_err(|_| self.error(at, format!("topic name {:02X?} is not UTF-8", &p[3..])))?;
        if !self.log.formats.contains_key(name) {
            return Err(self.error(
                at,
                format!("msg_id {msg_id} subscribes to `{name}`, which no format defines"),
            ));
        }
        if let Some(&k) = self.active.get(&msg_id) {
            let t = &self.log.topics[k];
            return Err(self.error(
                at,
                format!(
                    "msg_id {msg_id} is already subscribed to `{}` instance {}",
                    t.name, t.multi_id
                ),
            ));
        }
        let layout = self.layout(name)?;
        let existing = self
            .log
            .topics
            .iter()
            .position(|t| t.name == name && t.multi_id == multi_id);
        let k = match existing {
            Some(k) => k,
            None => {
                self.log.topics.push(Topic {
                    name: name.to_string(),
                    multi_id,
                    position: self.log.topics.len(),
                    layout,
                    count: 0,
                    data: Vec::new(),
                    offsets: Vec::new(),
                });
                self.log.topics.len() - 1
            }
        };
        self.active.insert(msg_id, k);
        Ok(())
    }

    fn unsubscribe(&mut self, p: &[u8]) -> Result<(), String> {
        if p.len() != 2 {
            return Err(format!(
                "payload of {} bytes, expected a u16 msg_id",
                p.len()
            ));
        }
        let msg_id = u16_at(p, 0);
        self.active
            .remove(&msg_id)
            .map(|_| ())
            .ok_or_else(|| format!("removes msg_id {msg_id}, which is not subscribed"))
    }

    /// A sample: checked against its format, held if its topic is kept, and visited.
    fn data(&mut self, at: At, p: &[u8]) -> Result<(), ImportError> {
        at_least(p, 2, "a data message's msg_id").map_err(|e| self.error(at, e))?;
        let msg_id = u16_at(p, 0);
        let Some(&k) = self.active.get(&msg_id) else {
            return Err(self.error(
                at,
                format!("data for msg_id {msg_id}, which no subscription ('A') announced"),
            ));
        };
        let topic = &self.log.topics[k];
        let payload = &p[2..];
        let size = topic.layout.size;
        let min = size - topic.layout.trailing_padding;
        if payload.len() < min || payload.len() > size {
            let needs = if min == size {
                format!("{size}")
            } else {
                format!("{min} to {size}")
            };
            let message = format!(
                "`{}` instance {} data of {} bytes, its format needs {needs}",
                topic.name,
                topic.multi_id,
                payload.len()
            );
            return Err(self.error(at, message));
        }
        self.padded.clear();
        self.padded.extend_from_slice(payload);
        self.padded.resize(size, 0);
        let topic = &mut self.log.topics[k];
        if (self.keep)(&topic.name) {
            topic.data.extend_from_slice(&self.padded);
            topic.offsets.push(at.offset as u64);
        }
        topic.count += 1;
        (self.visit)(Sample {
            path: &self.log.path,
            topic: &self.log.topics[k],
            index: self.log.topics[k].count - 1,
            offset: at.offset as u64,
            payload: &self.padded,
        })
    }

    fn logged(&mut self, at: At, p: &[u8], tagged: bool) -> Result<(), String> {
        let head = if tagged { 11 } else { 9 };
        at_least(p, head, "a log string")?;
        let (tag, time_at) = if tagged {
            (Some(u16_at(p, 1)), 3)
        } else {
            (None, 1)
        };
        self.log.logged.push(LoggedString {
            offset: at.offset as u64,
            level: p[0],
            tag,
            timestamp_us: u64_at(p, time_at),
            text: String::from_utf8_lossy(&p[head..]).into_owned(),
        });
        Ok(())
    }
}
