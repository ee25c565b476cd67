//! The fast path of [`super::read_table`]: a numeric CSV read in large blocks on a thread of
//! its own (which also inflates gzip), the blocks' lines parsed on every core (rayon) with
//! `fast-float2`, no allocation per row: a whole file's rows straight into their places in
//! its columns (each block's line ends counted first), a streamed read's into recycled
//! blocks. It takes the files dynacal writes and most that other tools write: `#` lines
//! before the header, one header line, then rows of comma-separated fields with LF or CRLF
//! line ends and spaces around fields. Anything else (a quote anywhere, a `#` or blank line
//! among the rows, a field count unlike the header's, a wanted field that is not a finite
//! number, a read error) gives `None`, and the caller reads the file again with the `csv`
//! crate, whose errors name the line. So the fast path never decides what an error says:
//! both paths give the same table, or the same error.
//!
//! Hand-written because the `csv` crate parses one record at a time on one core (about
//! 100 MB/s here with the float parsing) and no crate splits a CSV into chunks to parse in
//! parallel; the float parsing itself is `fast-float2`'s, which rounds as `str::parse` does.

use std::io::Read;
use std::mem::MaybeUninit;
use std::path::Path;
use std::sync::mpsc;

use rayon::prelude::*;

use super::{open_maybe_gz, RowLines, Table};

/// Bytes read (after inflating) per block: large enough to split among the cores, small
/// enough that a streamed read holds little (measured: 8 MiB blocks took a streamed `wv` to
/// 53 MiB, 2 MiB to 25 MiB, for about a tenth more time).
const BLOCK_BYTES: usize = 2 << 20;

/// Blocks read ahead of the parser.
const BLOCKS_AHEAD: usize = 2;

/// The table of `path` when the fast path can read it; `None`: read it with the `csv` crate.
pub(super) fn read_table(path: &Path, wanted: Option<&[&str]>) -> Option<Table> {
    let mut blocks = FastBlocks::open(path, wanted)?;
    let names = blocks.headers().to_vec();
    let first_line = blocks.next_line;
    // Each block's rows are parsed straight into the columns' ends, so the only memory
    // touched besides the read's blocks is the columns' own.
    let mut columns: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    // The text's length tells the rows ahead, so the columns are made room for once.
    let file_bytes = super::text_bytes_hint(path);
    let (mut rows, mut bytes_parsed) = (0u64, 0u64);
    while let Some(block_rows) = blocks
        .next_lines(|bytes, header| {
            bytes_parsed += bytes.len() as u64;
            let bytes_after = file_bytes.saturating_sub(bytes_parsed);
            append_rows(bytes, header, &mut columns, bytes_after)
        })
        .ok()?
    {
        rows += block_rows;
    }
    Some(Table {
        path: path.to_path_buf(),
        headers: names,
        columns,
        row_lines: if rows > 0 {
            RowLines::From(first_line)
        } else {
            RowLines::Unknown
        },
    })
}

/// Runs `feed` on every block `next` reads, the next block read while the last one is fed:
/// what consumes a block (a stream's serial prefix chain) runs while the next is parsed on
/// the other cores. `next` is handed the block fed last, to reuse its buffers. A block's
/// feed error comes before the read error of the block after it, as in a loop that reads
/// then feeds.
pub(crate) fn pipelined<B: Send + Sync, E: Send>(
    mut next: impl FnMut(Option<B>) -> Result<Option<B>, E> + Send,
    mut feed: impl FnMut(&B) -> Result<(), E> + Send,
) -> Result<(), E> {
    let (mut last, mut spent) = (None, None);
    loop {
        let (read, fed) = rayon::join(
            || next(spent.take()),
            || last.as_ref().map_or(Ok(()), &mut feed),
        );
        fed?;
        spent = last.take();
        match read? {
            Some(block) => last = Some(block),
            None => return Ok(()),
        }
    }
}

/// The fast path gave up: read the file with the `csv` crate, from its start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fallback;

/// Rows parsed from one block of a file, in pieces of consecutive rows.
pub struct ParsedBlock {
    /// The file line (1-based) of the block's first row.
    pub first_line: u64,
    /// Each piece's row count and columns (in [`FastBlocks::headers`] order).
    pieces: Vec<(u64, Vec<Vec<f64>>)>,
}

impl ParsedBlock {
    /// The pieces' columns, in file order.
    pub fn pieces(&self) -> impl Iterator<Item = &[Vec<f64>]> {
        self.pieces.iter().map(|p| p.1.as_slice())
    }
}

/// A numeric CSV read a block of rows at a time by the fast path: what a whole-file read
/// collects and a streamed one consumes as it goes.
pub struct FastBlocks {
    blocks: mpsc::Receiver<Result<Vec<u8>, ()>>,
    /// Where parsed blocks' buffers go back to the reading thread.
    recycle: mpsc::Sender<Vec<u8>>,
    /// Bytes after the header in the blocks that held it, to parse first.
    queued: Option<Vec<u8>>,
    /// A line begun in the previous block.
    carry: Vec<u8>,
    header: Header,
    /// Parsed pieces' column buffers handed back ([`FastBlocks::recycle`]), to parse into.
    spare: Vec<Vec<Vec<f64>>>,
    /// The file line of the next row.
    next_line: u64,
    at_end: bool,
}

impl FastBlocks {
    /// Reads the header of `path` (`wanted` as in [`super::read_table`]); `None` when the
    /// file is not for the fast path.
    pub fn open(path: &Path, wanted: Option<&[&str]>) -> Option<Self> {
        let (blocks, recycle) = read_ahead(path);
        let mut pending: Vec<u8> = Vec::new();
        let mut at_end = false;
        loop {
            match blocks.recv() {
                Ok(Ok(block)) => pending.extend_from_slice(&block),
                Ok(Err(())) => return None,
                Err(mpsc::RecvError) => at_end = true,
            }
            if pending.starts_with(b"\xEF\xBB\xBF") {
                return None; // A byte-order mark: the csv crate's to strip.
            }
            if let Some((header, consumed, lines)) = find_header(&pending, wanted, at_end)? {
                pending.drain(..consumed);
                return Some(Self {
                    blocks,
                    recycle,
                    queued: Some(pending),
                    carry: Vec::new(),
                    header,
                    spare: Vec::new(),
                    next_line: lines + 1,
                    at_end,
                });
            }
            if at_end {
                return None;
            }
        }
    }

    /// The parsed columns' names, in file order.
    pub fn headers(&self) -> &[String] {
        &self.header.names
    }

    /// Hands a consumed block's buffers back to parse later blocks into: a reader that
    /// recycles its blocks touches no new memory after the first (new pages cost more than
    /// the parse of what fills them).
    pub fn recycle(&mut self, block: ParsedBlock) {
        self.spare
            .extend(block.pieces.into_iter().map(|(_, columns)| columns));
    }

    /// The next block of rows; `Ok(None)` after the last.
    pub fn next_block(&mut self) -> Result<Option<ParsedBlock>, Fallback> {
        let first_line = self.next_line;
        let mut spare = std::mem::take(&mut self.spare);
        let mut pieces = Vec::new();
        let rows = self.next_lines(|bytes, header| {
            let parsed = parse_rows(bytes, header, &mut spare)?;
            let rows = parsed.iter().map(|p| p.0).sum();
            pieces.extend(parsed);
            Some(rows)
        });
        self.spare = spare;
        Ok(rows?.map(|_| ParsedBlock { first_line, pieces }))
    }

    /// Hands `parse` the next runs of whole lines (the line begun in the previous block
    /// joined first) and returns the rows it parsed of them; `Ok(None)` after the last.
    fn next_lines(
        &mut self,
        mut parse: impl FnMut(&[u8], &Header) -> Option<u64>,
    ) -> Result<Option<u64>, Fallback> {
        loop {
            let block = match self.queued.take() {
                Some(block) => Some(block),
                None if self.at_end => None,
                None => match self.blocks.recv() {
                    Ok(Ok(block)) => Some(block),
                    Ok(Err(())) => return Err(Fallback),
                    Err(mpsc::RecvError) => {
                        self.at_end = true;
                        None
                    }
                },
            };
            let Some(block) = block else {
                // The end; a last line may lack its line end.
                if self.carry.is_empty() {
                    return Ok(None);
                }
                let last = std::mem::take(&mut self.carry);
                let rows = parse(&last, &self.header).ok_or(Fallback)?;
                return Ok(Some(self.counted(rows)));
            };
            let rows = self.parse_block(&block, &mut parse);
            let _ = self.recycle.send(block);
            if let Some(rows) = rows.ok_or(Fallback)? {
                return Ok(Some(self.counted(rows)));
            }
        }
    }

    /// Parses the whole lines of `block`, the line begun before it first, and keeps its last
    /// partial line for the next; `Some(None)`: no line ends in it.
    fn parse_block(
        &mut self,
        block: &[u8],
        parse: &mut impl FnMut(&[u8], &Header) -> Option<u64>,
    ) -> Option<Option<u64>> {
        let (Some(first_end), Some(last_end)) =
            (memchr::memchr(b'\n', block), memchr::memrchr(b'\n', block))
        else {
            self.carry.extend_from_slice(block);
            return Some(None);
        };
        let mut rows = 0;
        let mut body_start = 0;
        if !self.carry.is_empty() {
            self.carry.extend_from_slice(&block[..=first_end]);
            rows += parse(&self.carry, &self.header)?;
            self.carry.clear();
            body_start = first_end + 1;
        }
        if body_start <= last_end {
            rows += parse(&block[body_start..=last_end], &self.header)?;
        }
        self.carry.extend_from_slice(&block[last_end + 1..]);
        Some(Some(rows))
    }

    fn counted(&mut self, rows: u64) -> u64 {
        self.next_line += rows;
        rows
    }
}

/// Calls `row` with each data row of the CSV at `path`, its values in `wanted` order (the
/// first wanted column a time that must strictly increase), read by the fast block reader:
/// what a streamed reader spills. `Ok(false)` when the reader gives up, a wanted column is
/// missing, the time does not increase, the file has no row, or `row` refuses one (returns
/// `Ok(false)`): the caller then reads the file again row by row, whose errors name the line.
pub(crate) fn for_each_fast_row<E>(
    path: &Path,
    wanted: &[&str],
    mut row: impl FnMut(&[f64]) -> Result<bool, E>,
) -> Result<bool, E> {
    let Some(mut blocks) = FastBlocks::open(path, Some(wanted)) else {
        return Ok(false);
    };
    let order: Option<Vec<usize>> = wanted
        .iter()
        .map(|name| blocks.headers().iter().position(|h| h == name))
        .collect();
    let Some(order) = order else {
        return Ok(false);
    };
    let mut values = vec![0.0; wanted.len()];
    let (mut previous_t_s, mut rows) = (f64::NEG_INFINITY, 0u64);
    loop {
        let block = match blocks.next_block() {
            Ok(Some(block)) => block,
            Ok(None) => break,
            Err(Fallback) => return Ok(false),
        };
        for piece in block.pieces() {
            let columns: Vec<&[f64]> = order.iter().map(|&c| piece[c].as_slice()).collect();
            for k in 0..columns.first().map_or(0, |c| c.len()) {
                values.iter_mut().zip(&columns).for_each(|(v, c)| *v = c[k]);
                if !(values[0] > previous_t_s) || !row(&values)? {
                    return Ok(false);
                }
                previous_t_s = values[0];
                rows += 1;
            }
        }
        blocks.recycle(block);
    }
    Ok(rows > 0)
}

/// The file's decompressed bytes in blocks, read on a thread of their own (a read error is
/// `Err(())`: the `csv` path says what it is), and where to hand the buffers back.
#[allow(clippy::type_complexity)]
fn read_ahead(path: &Path) -> (mpsc::Receiver<Result<Vec<u8>, ()>>, mpsc::Sender<Vec<u8>>) {
    let (send, receive) = mpsc::sync_channel(BLOCKS_AHEAD);
    let (recycle, recycled) = mpsc::channel::<Vec<u8>>();
    let path = path.to_path_buf();
    std::thread::spawn(move || {
        let Ok(mut reader) = open_maybe_gz(&path) else {
            let _ = send.send(Err(()));
            return;
        };
        loop {
            let mut block = recycled.try_recv().unwrap_or_default();
            match fill_block(&mut reader, &mut block) {
                Ok(0) => return,
                Ok(_) => {
                    if send.send(Ok(block)).is_err() {
                        return; // The parser gave up.
                    }
                }
                Err(_) => {
                    let _ = send.send(Err(()));
                    return;
                }
            }
        }
    });
    (receive, recycle)
}

/// Fills `block` with up to [`BLOCK_BYTES`] bytes of `reader` (fewer only at its end) and
/// returns how many. The reader is a `Box<dyn Read>`, whose `read_to_end` zeroes the spare
/// capacity before every read (measured: 3% of a whole `wv`); a recycled block keeps its
/// length instead, so only what the previous fill left short is zeroed.
fn fill_block(reader: &mut impl Read, block: &mut Vec<u8>) -> std::io::Result<usize> {
    block.resize(BLOCK_BYTES, 0);
    let mut filled = 0;
    while filled < BLOCK_BYTES {
        match reader.read(&mut block[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    block.truncate(filled);
    Ok(filled)
}

/// The header: every field's name, and for each field the slot of its parsed column.
struct Header {
    /// Names of the parsed columns, in file order.
    names: Vec<String>,
    /// For each field of a row, the parsed column it goes to, if any.
    slots: Vec<Option<usize>>,
    /// Fields in the header.
    fields: usize,
}

/// The header found in `bytes` (after `#` lines), the bytes up to its line's end and the
/// lines up to it; `Some(None)`: not all here yet; `None`: not for the fast path.
#[allow(clippy::type_complexity)]
fn find_header(
    bytes: &[u8],
    wanted: Option<&[&str]>,
    at_end: bool,
) -> Option<Option<(Header, usize, u64)>> {
    let mut start = 0;
    let mut lines = 0u64;
    loop {
        let end = match bytes[start..].iter().position(|&b| b == b'\n') {
            Some(i) => start + i,
            None if at_end && start < bytes.len() => bytes.len(),
            None if at_end => return None, // No header: the csv path says so.
            None => return Some(None),
        };
        lines += 1;
        let line = strip_cr(&bytes[start..end]);
        let consumed = (end + 1).min(bytes.len());
        if line.first() == Some(&b'#') {
            start = consumed;
            continue;
        }
        if line.is_empty() || line.contains(&b'"') {
            return None;
        }
        let text = std::str::from_utf8(line).ok()?;
        let all: Vec<&str> = text.split(',').map(|f| f.trim_ascii()).collect();
        let mut names = Vec::new();
        let slots = all
            .iter()
            .map(|name| {
                let parsed = wanted.is_none_or(|w| w.contains(name));
                parsed.then(|| {
                    names.push(name.to_string());
                    names.len() - 1
                })
            })
            .collect();
        let header = Header {
            names,
            slots,
            fields: all.len(),
        };
        return Some(Some((header, consumed, lines)));
    }
}

fn strip_cr(line: &[u8]) -> &[u8] {
    line.strip_suffix(b"\r").unwrap_or(line)
}

/// Parses whole lines of rows in parallel over pieces of `bytes` split at line ends: each
/// piece's row count and columns, parsed into buffers from `spare` where it has them;
/// `None` at anything the fast path leaves to the `csv` crate.
fn parse_rows(
    bytes: &[u8],
    header: &Header,
    spare: &mut Vec<Vec<Vec<f64>>>,
) -> Option<Vec<(u64, Vec<Vec<f64>>)>> {
    if bytes.is_empty() {
        return Some(Vec::new());
    }
    let pieces: Vec<(&[u8], Vec<Vec<f64>>)> = pieces_of(bytes)
        .into_iter()
        .map(|piece| (piece, spare.pop().unwrap_or_default()))
        .collect();
    pieces
        .into_par_iter()
        .map(|(piece, buffers)| parse_piece(piece, header, buffers))
        .collect()
}

/// Parses whole lines of rows in parallel, as [`parse_rows`] does, straight onto the ends
/// of `columns` (in [`Header::names`] order): each piece's rows into its own stretch of
/// every column's spare room, counted from its line ends first. Room is made once for about
/// `bytes_after` more bytes of such rows too. Returns the rows appended; `None` (nothing
/// appended) at anything the fast path leaves to the `csv` crate.
fn append_rows(
    bytes: &[u8],
    header: &Header,
    columns: &mut [Vec<f64>],
    bytes_after: u64,
) -> Option<u64> {
    if bytes.is_empty() {
        return Some(0);
    }
    let pieces = pieces_of(bytes);
    let counts: Vec<usize> = pieces
        .par_iter()
        .map(|piece| unquoted(piece).then(|| line_count(piece)))
        .collect::<Option<_>>()?;
    let total: usize = counts.iter().sum();
    let spare_rows = columns.first().map_or(0, |c| c.capacity() - c.len());
    let reserve = if spare_rows < total {
        total + (total as u64 * bytes_after / bytes.len() as u64) as usize
    } else {
        total
    };
    let mut stretches: Vec<Vec<&mut [MaybeUninit<f64>]>> = counts
        .iter()
        .map(|_| Vec::with_capacity(columns.len()))
        .collect();
    for column in columns.iter_mut() {
        super::reserve_column(column, reserve);
        let mut room = &mut column.spare_capacity_mut()[..total];
        for (piece_stretches, &count) in stretches.iter_mut().zip(&counts) {
            let (stretch, rest) = std::mem::take(&mut room).split_at_mut(count);
            piece_stretches.push(stretch);
            room = rest;
        }
    }
    let filled =
        pieces
            .into_par_iter()
            .zip(stretches)
            .zip(&counts)
            .all(|((piece, stretch), &count)| {
                let mut into = Stretches {
                    columns: stretch,
                    row: 0,
                };
                parse_piece_into(piece, header, &mut into) == Some(count as u64)
            });
    if !filled {
        return None;
    }
    for column in columns.iter_mut() {
        // SAFETY: every piece parsed as many rows as it has lines, and each row wrote every
        // column (a header slot per column) at its own index of the piece's stretch, so the
        // `total` values after the column's end are all written.
        unsafe { column.set_len(column.len() + total) };
    }
    Some(total as u64)
}

/// `bytes` cut into pieces to parse on every core.
fn pieces_of(bytes: &[u8]) -> Vec<&[u8]> {
    split_at_lines(bytes, rayon::current_num_threads() * 4)
}

/// No quote in `piece`: a quoted field is the `csv` crate's to read. Searched piece by
/// piece on every core (a search of the whole block first took 3% of a `wv`).
fn unquoted(piece: &[u8]) -> bool {
    memchr::memchr(b'"', piece).is_none()
}

/// The lines of a piece that ends at a line end or at the end of the file.
fn line_count(piece: &[u8]) -> usize {
    // A vector count: a search per line end, or a plain loop, took a sixth of the read.
    let ends = bytecount::count(piece, b'\n');
    ends + usize::from(piece.last().is_some_and(|&b| b != b'\n'))
}

/// `bytes` cut into about `parts` pieces, each ending at a line end (the last at the end).
fn split_at_lines(bytes: &[u8], parts: usize) -> Vec<&[u8]> {
    let target = bytes.len().div_ceil(parts.max(1)).max(1 << 16);
    let mut pieces = Vec::with_capacity(parts);
    let mut rest = bytes;
    while !rest.is_empty() {
        let cut = if rest.len() <= target {
            rest.len()
        } else {
            match memchr::memchr(b'\n', &rest[target..]) {
                Some(i) => target + i + 1,
                None => rest.len(),
            }
        };
        let (piece, tail) = rest.split_at(cut);
        pieces.push(piece);
        rest = tail;
    }
    pieces
}

/// Where a row's parsed values go: [`parse_row`] puts each wanted field's value in its slot
/// (the column's index in [`Header::names`]), then ends the row.
trait RowSink {
    /// `None`: no room for it (the rows outnumber what was counted).
    fn put(&mut self, slot: usize, value: f64) -> Option<()>;
    fn end_row(&mut self) {}
}

/// A piece's own growing columns (the streamed reads' blocks).
impl RowSink for [Vec<f64>] {
    fn put(&mut self, slot: usize, value: f64) -> Option<()> {
        self[slot].push(value);
        Some(())
    }
}

/// A piece's stretch of every column's room, counted before the parse (a whole-file read).
struct Stretches<'a> {
    columns: Vec<&'a mut [MaybeUninit<f64>]>,
    /// The row being parsed, from the stretch's start.
    row: usize,
}

impl RowSink for Stretches<'_> {
    fn put(&mut self, slot: usize, value: f64) -> Option<()> {
        self.columns[slot].get_mut(self.row)?.write(value);
        Some(())
    }

    fn end_row(&mut self) {
        self.row += 1;
    }
}

/// The number of lines in `piece` and their parsed columns, in `buffers` (emptied first;
/// more made if it has too few).
fn parse_piece(
    piece: &[u8],
    header: &Header,
    mut columns: Vec<Vec<f64>>,
) -> Option<(u64, Vec<Vec<f64>>)> {
    if !unquoted(piece) {
        return None;
    }
    let rows_guess = piece.len() / 16 + 1;
    columns.resize_with(header.names.len(), Vec::new);
    for column in &mut columns {
        column.clear();
        column.reserve(rows_guess);
    }
    let rows = parse_piece_into(piece, header, columns.as_mut_slice())?;
    Some((rows, columns))
}

/// Parses every row of `piece` into `sink`; the number of rows.
fn parse_piece_into(
    piece: &[u8],
    header: &Header,
    sink: &mut (impl RowSink + ?Sized),
) -> Option<u64> {
    let mut rows = 0;
    let mut pos = 0;
    while pos < piece.len() {
        pos = parse_row(piece, pos, header, sink)?;
        sink.end_row();
        rows += 1;
    }
    Some(rows)
}

/// Parses the row starting at `bytes[pos]` into `sink`: each wanted field a finite number
/// with only blanks around it, and as many fields as the header has, up to the line's end
/// (LF, CRLF, or the end of `bytes`); returns where the next row starts. A blank line or a
/// `#` line is not a row (the `csv` crate's to skip).
///
/// The fields are parsed from `bytes` as a whole rather than from a line cut out of them:
/// `fast-float2` reads eight digits at a time where eight bytes follow, and a line cut at
/// its end leaves the last digits of every row to a byte-by-byte loop (measured: about a
/// sixth of the parse).
fn parse_row(
    bytes: &[u8],
    mut pos: usize,
    header: &Header,
    sink: &mut (impl RowSink + ?Sized),
) -> Option<usize> {
    match bytes[pos..] {
        [b'\n' | b'#', ..] | [b'\r', b'\n', ..] => return None,
        _ => {}
    }
    let last = header.fields - 1;
    for (k, slot) in header.slots.iter().enumerate() {
        match slot {
            Some(slot) => {
                let at = skip_blanks(bytes, pos);
                // The longest number at the field's start; what follows must be blanks up
                // to the field's end, or the field is not a number (`1e`, `1 2`, `1x`).
                let (value, used) = fast_float2::parse_partial::<f64, _>(&bytes[at..]).ok()?;
                if !value.is_finite() {
                    return None;
                }
                sink.put(*slot, value)?;
                pos = skip_blanks(bytes, at + used);
            }
            None => {
                pos += memchr::memchr2(b',', b'\n', &bytes[pos..]).unwrap_or(bytes.len() - pos);
            }
        }
        match bytes.get(pos) {
            Some(b',') if k < last => pos += 1,
            Some(b'\n') if k == last => return Some(pos + 1),
            None if k == last => return Some(pos),
            _ => return None,
        }
    }
    None
}

/// The position of the first byte from `pos` on that is not whitespace within a line (a
/// line end is not a blank).
fn skip_blanks(bytes: &[u8], mut pos: usize) -> usize {
    while bytes
        .get(pos)
        .is_some_and(|&b| b != b'\n' && b.is_ascii_whitespace())
    {
        pos += 1;
    }
    pos
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `text` as one gzip member.
    fn gzip(text: &[u8]) -> Vec<u8> {
        use std::io::Write as _;
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        enc.write_all(text).unwrap();
        enc.finish().unwrap()
    }

    /// A `t_s,gx_rad_s` table of `n` rows at 100 Hz, the rate `(i % period) * scale`.
    fn two_column_text(n: usize, period: usize, scale: f64) -> String {
        let mut text = String::from("t_s,gx_rad_s\n");
        for i in 0..n {
            text.push_str(&format!(
                "{},{}\n",
                i as f64 * 0.01,
                (i % period) as f64 * scale
            ));
        }
        text
    }

    /// What the fast path reads must be what the `csv` path reads, to the bit.
    fn agrees(text: &[u8], gzip: bool, wanted: Option<&[&str]>) -> Option<Table> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        if gzip {
            std::fs::write(&path, self::gzip(text)).unwrap();
        } else {
            std::fs::write(&path, text).unwrap();
        }
        let fast = read_table(&path, wanted);
        if let Some(table) = &fast {
            let by_rows = super::super::read_table_by_rows(&path, wanted);
            assert_eq!(
                by_rows.as_ref().ok(),
                Some(table),
                "{:?}: {by_rows:?}",
                String::from_utf8_lossy(text)
            );
        }
        fast
    }

    #[test]
    fn reads_what_dynacal_and_common_tools_write_and_leaves_the_rest() {
        let wanted: &[&str] = &["t_s", "gx_rad_s"];
        for (text, taken) in [
            (
                &b"# sample_rate_hz: 100\nt_s,gx_rad_s\n0,1.5\n0.01,-2e-3\n"[..],
                true,
            ),
            (
                b"t_s , gx_rad_s,name\r\n 0 ,1,a b\r\n0.01,+2,\"\"\r\n",
                false,
            ),
            (b"t_s,gx_rad_s,name\r\n 0 ,1,a\r\n0.01,.5,b", true),
            (b"t_s,gx_rad_s\n0,1\n\n0.01,2\n", false),
            (b"t_s,gx_rad_s\n0,1\n# note\n0.01,2\n", false),
            (b"\xEF\xBB\xBFt_s,gx_rad_s\n0,1\n", false),
            (b"t_s,gx_rad_s\n0,1,3\n", false),
            (b"t_s,gx_rad_s\n0,nan\n", false),
            (b"t_s,gx_rad_s\n0,1e400\n", false),
            (b"t_s,gx_rad_s\n0,1.\n1,5E-1\n", true),
            (b"t_s,gx_rad_s\n", true),
            // A field not wanted first: a comment, blank or CR-only line is still no row,
            // and the number parsed from the whole block stops at its line's end.
            (b"name,t_s,gx_rad_s\na,0,1\n# x,1,2\n", false),
            (b"name,t_s,gx_rad_s\na,0,1\n\r\nb,1,2\n", false),
            (b"name,t_s,gx_rad_s\r\na,0,1 \r\n\tb ,1,2\r\n", true),
            (b"name,t_s,gx_rad_s\na,0,1\n2,3\n", false),
            (b"name,t_s,gx_rad_s\na,0,1e\n5,1,2\n", false),
        ] {
            for gzip in [false, true] {
                let fast = agrees(text, gzip, Some(wanted));
                assert_eq!(
                    fast.is_some(),
                    taken,
                    "{:?} (gzip {gzip})",
                    String::from_utf8_lossy(text)
                );
            }
        }
        // The rows' lines are known behind a comment header.
        let t = agrees(b"# a\n# b\nt_s,gx_rad_s\n0,1\n", false, None).unwrap();
        assert_eq!(t.row_lines, RowLines::From(4));
    }

    #[test]
    fn blocks_join_across_their_boundaries() {
        // Rows across several read blocks and parse pieces: every value lands in order.
        let n = 1_200_000;
        let text = two_column_text(n, 977, 1e-4);
        let table = agrees(text.as_bytes(), false, None).expect("fast path");
        assert_eq!(table.rows(), n);
        assert_eq!(table.columns[1][n - 1], ((n - 1) % 977) as f64 * 1e-4);
    }

    #[test]
    fn rows_land_in_place_whatever_the_length_hint_says() {
        // Two gzip members, the last a single row: its stated length is that row's, so the
        // columns are made room for too short and grow block by block.
        let n = 600_000;
        let body = two_column_text(n, 491, 1e-3);
        let last = format!("{},7.5\n", n as f64 * 0.01);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("two-members.csv.gz");
        std::fs::write(
            &path,
            [gzip(body.as_bytes()), gzip(last.as_bytes())].concat(),
        )
        .unwrap();
        assert_eq!(
            super::super::text_bytes_hint(&path),
            std::fs::metadata(&path).unwrap().len()
        );
        let table = read_table(&path, None).expect("fast path");
        assert_eq!(
            Some(&table),
            super::super::read_table_by_rows(&path, None).ok().as_ref()
        );
        assert_eq!(table.rows(), n + 1);
        assert_eq!(table.columns[1][n], 7.5);
        // A plain file's hint is its size; a one-member gzip's, its text's length.
        let plain = dir.path().join("plain.csv");
        std::fs::write(&plain, &body).unwrap();
        assert_eq!(super::super::text_bytes_hint(&plain), body.len() as u64);
        std::fs::write(&path, gzip(body.as_bytes())).unwrap();
        assert_eq!(super::super::text_bytes_hint(&path), body.len() as u64);
    }

    fn field() -> impl Strategy<Value = String> {
        prop_oneof![
            any::<f64>().prop_map(|v| v.to_string()),
            any::<f32>().prop_map(|v| format!("{v:e}")),
            (-1000i64..1000).prop_map(|v| v.to_string()),
            "[0-9+\\-.eE]{0,6}",
            "[ \t]{0,2}[0-9]{1,3}[ \t]{0,2}",
            prop_oneof![
                Just("nan"),
                Just("inf"),
                Just("\"1\""),
                Just("#"),
                Just("x"),
                Just("")
            ]
            .prop_map(str::to_string),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        #[test]
        fn any_text_reads_as_the_csv_path_reads_it(
            rows in proptest::collection::vec(proptest::collection::vec(field(), 1..4), 0..20),
            crlf in any::<bool>(),
            final_end in any::<bool>(),
            gzip in any::<bool>(),
        ) {
            let end = if crlf { "\r\n" } else { "\n" };
            let lines: Vec<String> = rows.iter().map(|r| r.join(",")).collect();
            let mut text = format!("a,b,c{end}{}", lines.join(end));
            if final_end {
                text.push_str(end);
            }
            agrees(text.as_bytes(), gzip, Some(&["a", "c"]));
            agrees(text.as_bytes(), gzip, None);
        }
    }
}
