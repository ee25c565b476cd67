//! Series of one run's length that a stage needs together, a block of epochs at a time
//! ([`SeriesBank`]): a diagnosis's error signals and the dynamics its calibration design is
//! made of, a dozen candidate terms' filtered signatures, or the calibration's filtered
//! columns on a channel, against each of which every baseline simulation is multiplied. On
//! a short run they are held; on a long one they are written to a temporary file (whole
//! series as they are made, or a block of every series at a time as a calibration forms
//! them) and read back a block at a time, so a stage holds a block of each rather than a
//! dozen series of the drive's length (the operating system's file cache, not the process,
//! keeps what it can of the file).

use std::fs::File;
use std::io::Write;
use std::ops::Range;

use std::borrow::Cow;

/// Epochs of each series read at a time from a spilled bank (128 KiB of each).
pub const BANK_BLOCK_EPOCHS: usize = 1 << 14;

/// The consecutive blocks of [`BANK_BLOCK_EPOCHS`] epochs (the last shorter) that cover
/// `epochs`, in order: how a spilled bank, and any loop over a run's epochs that keeps a
/// block at a time, cuts them.
pub fn block_ranges(epochs: Range<usize>) -> impl Iterator<Item = Range<usize>> {
    let end = epochs.end;
    epochs
        .step_by(BANK_BLOCK_EPOCHS)
        .map(move |start| start..(start + BANK_BLOCK_EPOCHS).min(end))
}

/// What visits a bank's blocks: the block's epochs, and every series over them.
pub type BlockVisit<'v> = dyn FnMut(Range<usize>, &[&[f64]]) + 'v;

/// A bank's temporary file could not be made, written or read back.
#[derive(Debug, thiserror::Error)]
#[error("the temporary file of a long run's series: {0}")]
pub struct SpillError(#[from] pub std::io::Error);

/// See the module documentation.
pub struct SeriesBank {
    /// Epochs of every series.
    n: usize,
    store: Store,
}

enum Store {
    Held(Vec<Vec<f64>>),
    /// Series after series, each `n` little-endian f64.
    Spilled {
        file: File,
        count: usize,
    },
}

fn spill_error(source: std::io::Error) -> SpillError {
    SpillError(source)
}

impl SeriesBank {
    /// An empty bank of series of `n` epochs, spilled to a temporary file when `spill`.
    pub fn new(n: usize, spill: bool) -> Result<Self, SpillError> {
        let store = if spill {
            Store::Spilled {
                file: tempfile::tempfile().map_err(spill_error)?,
                count: 0,
            }
        } else {
            Store::Held(Vec::new())
        };
        Ok(Self { n, store })
    }

    /// A bank of `count` series of `n` epochs, each written a block at a time in order
    /// ([`SeriesBank::write`]), spilled to a temporary file when `spill`.
    pub fn columns(n: usize, count: usize, spill: bool) -> Result<Self, SpillError> {
        let store = if spill {
            let file = tempfile::tempfile().map_err(spill_error)?;
            file.set_len(8 * (n * count) as u64).map_err(spill_error)?;
            Store::Spilled { file, count }
        } else {
            Store::Held((0..count).map(|_| Vec::with_capacity(n)).collect())
        };
        Ok(Self { n, store })
    }

    /// Adds `series` (of the bank's length) as the next one.
    pub fn push(&mut self, series: Vec<f64>) -> Result<(), SpillError> {
        assert_eq!(series.len(), self.n, "a bank's series share one length");
        match &mut self.store {
            Store::Held(held) => held.push(series),
            Store::Spilled { file, count } => {
                let mut bytes = Vec::with_capacity(8 * BANK_BLOCK_EPOCHS);
                for chunk in series.chunks(BANK_BLOCK_EPOCHS) {
                    bytes.clear();
                    chunk.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
                    file.write_all(&bytes).map_err(spill_error)?;
                }
                *count += 1;
            }
        }
        Ok(())
    }

    /// Adds every series of `other` (of the bank's length) after this bank's, a block at a
    /// time: a series made a block at a time in a bank of its own (a task of a parallel
    /// batch each) joins the batch's bank without being held whole.
    pub fn append(&mut self, other: SeriesBank) -> Result<(), SpillError> {
        assert_eq!(other.n, self.n, "a bank's series share one length");
        match (&mut self.store, other.store) {
            (Store::Held(held), Store::Held(series)) => held.extend(series),
            (Store::Spilled { file, count }, store) => {
                let other = SeriesBank { n: other.n, store };
                let mut bytes = Vec::with_capacity(8 * BANK_BLOCK_EPOCHS);
                for k in 0..other.len() {
                    let mut failed = None;
                    other.for_each_block_of(&[k], &mut |_, series| {
                        if failed.is_some() {
                            return;
                        }
                        for chunk in series[0].chunks(BANK_BLOCK_EPOCHS) {
                            bytes.clear();
                            chunk.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
                            if let Err(e) = file.write_all(&bytes) {
                                failed = Some(e);
                                return;
                            }
                        }
                    })?;
                    if let Some(e) = failed {
                        return Err(spill_error(e));
                    }
                    *count += 1;
                }
            }
            (Store::Held(held), store) => {
                let other = SeriesBank { n: other.n, store };
                for k in 0..other.len() {
                    held.push(other.series(k)?.into_owned());
                }
            }
        }
        Ok(())
    }

    /// Writes `values` as epochs `start..` of series `k` of a bank made by
    /// [`SeriesBank::columns`]: each series is written in order, from its first epoch on.
    pub fn write(&mut self, k: usize, start: usize, values: &[f64]) -> Result<(), SpillError> {
        assert!(start + values.len() <= self.n, "past the bank's epochs");
        match &mut self.store {
            Store::Held(held) => {
                assert_eq!(held[k].len(), start, "a held series is written in order");
                held[k].extend_from_slice(values);
            }
            Store::Spilled { file, .. } => {
                write_values(file, values, 8 * (k * self.n + start) as u64)?;
            }
        }
        Ok(())
    }

    /// Number of series.
    pub fn len(&self) -> usize {
        match &self.store {
            Store::Held(held) => held.len(),
            Store::Spilled { count, .. } => *count,
        }
    }

    /// Whether the bank has no series.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Epochs of every series.
    pub fn epochs(&self) -> usize {
        self.n
    }

    /// Whether the series are in a temporary file rather than held.
    /// Changes series `k` of a bank whose series are all written, a block of
    /// [`block_ranges`] at a time in order: `change(epochs, values)` over each (read back and
    /// written again when spilled).
    pub fn update(
        &mut self,
        k: usize,
        change: &mut dyn FnMut(Range<usize>, &mut [f64]),
    ) -> Result<(), SpillError> {
        match &mut self.store {
            Store::Held(held) => {
                let series = &mut held[k];
                assert_eq!(series.len(), self.n, "a series written whole");
                for range in block_ranges(0..self.n) {
                    change(range.clone(), &mut series[range]);
                }
            }
            Store::Spilled { file, .. } => {
                let mut values = Vec::with_capacity(BANK_BLOCK_EPOCHS);
                for range in block_ranges(0..self.n) {
                    let offset = 8 * (k * self.n + range.start) as u64;
                    values.clear();
                    read_values(file, offset, range.len(), &mut values)?;
                    change(range, &mut values);
                    write_values(file, &values, offset)?;
                }
            }
        }
        Ok(())
    }

    pub fn is_spilled(&self) -> bool {
        matches!(self.store, Store::Spilled { .. })
    }

    /// Epochs `range` of series `k`: borrowed when held, read back when spilled.
    pub fn range(&self, k: usize, range: Range<usize>) -> Result<Cow<'_, [f64]>, SpillError> {
        match &self.store {
            Store::Held(held) => Ok(Cow::Borrowed(&held[k][range])),
            Store::Spilled { file, .. } => {
                let mut values = Vec::with_capacity(range.len());
                read_values(
                    file,
                    8 * (k * self.n + range.start) as u64,
                    range.len(),
                    &mut values,
                )?;
                Ok(Cow::Owned(values))
            }
        }
    }

    /// Series `k` whole.
    pub fn series(&self, k: usize) -> Result<Cow<'_, [f64]>, SpillError> {
        self.range(k, 0..self.n)
    }

    /// Calls `visit` with each block of epochs in order (its range, and every series over
    /// it, in the order they were pushed).
    pub fn for_each_block(&self, visit: &mut BlockVisit<'_>) -> Result<(), SpillError> {
        let all: Vec<usize> = (0..self.len()).collect();
        self.for_each_block_of(&all, visit)
    }

    /// Calls `visit` with each block of epochs in order (its range, and the series `which`
    /// over it, in that order). A held bank is one block.
    pub fn for_each_block_of(
        &self,
        which: &[usize],
        visit: &mut BlockVisit<'_>,
    ) -> Result<(), SpillError> {
        self.for_each_block_in(which, 0..self.n, visit)
    }

    /// [`SeriesBank::for_each_block_of`] over the epochs `epochs` only.
    pub fn for_each_block_in(
        &self,
        which: &[usize],
        epochs: Range<usize>,
        visit: &mut BlockVisit<'_>,
    ) -> Result<(), SpillError> {
        assert!(epochs.end <= self.n, "past the bank's epochs");
        match &self.store {
            Store::Held(held) => {
                let all: Vec<&[f64]> = which.iter().map(|&k| &held[k][epochs.clone()]).collect();
                visit(epochs, &all);
                Ok(())
            }
            Store::Spilled { file, .. } => {
                let mut blocks = vec![Vec::with_capacity(BANK_BLOCK_EPOCHS); which.len()];
                for range in block_ranges(epochs) {
                    for (&k, block) in which.iter().zip(blocks.iter_mut()) {
                        block.clear();
                        let offset = 8 * (k * self.n + range.start) as u64;
                        read_values(file, offset, range.len(), block)?;
                    }
                    let views: Vec<&[f64]> = blocks.iter().map(Vec::as_slice).collect();
                    visit(range, &views);
                }
                Ok(())
            }
        }
    }

    /// Each series' inner product with the one series of `other` (a bank of the same
    /// length), read a block at a time: the figures of [`SeriesBank::dots`] of it held.
    pub fn dots_with(&self, other: &SeriesBank) -> Result<Vec<f64>, SpillError> {
        let mut sums = vec![0.0; self.len()];
        let mut failed = None;
        self.for_each_block(&mut |range, series| {
            let y = match other.range(0, range) {
                Ok(y) => y,
                Err(e) => {
                    failed.get_or_insert(e);
                    return;
                }
            };
            for (sum, x) in sums.iter_mut().zip(series) {
                *sum += x.iter().zip(y.iter()).map(|(a, b)| a * b).sum::<f64>();
            }
        })?;
        match failed {
            Some(e) => Err(e),
            None => Ok(sums),
        }
    }

    /// Each series' inner product with `y` (of the bank's length).
    pub fn dots(&self, y: &[f64]) -> Result<Vec<f64>, SpillError> {
        let mut sums = vec![0.0; self.len()];
        self.add_dots_in(0..self.n, y, &mut sums)?;
        Ok(sums)
    }

    /// Adds each series' inner product with `y` over the epochs `epochs` (`y` given over
    /// them) to `sums`: [`SeriesBank::dots`] of a series fed a block at a time, with its
    /// figures when the blocks are the bank's.
    pub fn add_dots_in(
        &self,
        epochs: Range<usize>,
        y: &[f64],
        sums: &mut [f64],
    ) -> Result<(), SpillError> {
        let all: Vec<usize> = (0..self.len()).collect();
        let first = epochs.start;
        self.for_each_block_in(&all, epochs, &mut |range, series| {
            let y = &y[range.start - first..range.end - first];
            for (sum, x) in sums.iter_mut().zip(series) {
                *sum += x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
            }
        })
    }
}

/// Appends `count` values read at byte `offset` of `file` to `values`.
fn read_values(
    file: &File,
    offset: u64,
    count: usize,
    values: &mut Vec<f64>,
) -> Result<(), SpillError> {
    // Read straight into the values' own memory: a buffer of bytes per read was most of a
    // long diagnosis's allocations (millions of 128 KiB blocks).
    let start = values.len();
    values.resize(start + count, 0.0);
    let read = read_exact_at(file, bytemuck::cast_slice_mut(&mut values[start..]), offset);
    if let Err(e) = read {
        values.truncate(start);
        return Err(spill_error(e));
    }
    if cfg!(target_endian = "big") {
        for v in &mut values[start..] {
            *v = f64::from_bits(u64::from_le(v.to_bits()));
        }
    }
    Ok(())
}

/// Writes `values` into `file` at `offset`, little-endian as [`read_values`] reads them.
fn write_values(file: &File, values: &[f64], offset: u64) -> Result<(), SpillError> {
    let written = if cfg!(target_endian = "little") {
        write_all_at(file, bytemuck::cast_slice(values), offset)
    } else {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        write_all_at(file, &bytes, offset)
    };
    written.map_err(spill_error)
}

/// Writes all of `buf` into `file` at `offset`.
#[cfg(unix)]
fn write_all_at(file: &File, buf: &[u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::write_all_at(file, buf, offset)
}

#[cfg(windows)]
fn write_all_at(file: &File, mut buf: &[u8], mut offset: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_write(buf, offset)? {
            0 => return Err(std::io::ErrorKind::WriteZero.into()),
            written => {
                buf = &buf[written..];
                offset += written as u64;
            }
        }
    }
    Ok(())
}

/// Reads `buf.len()` bytes of `file` at `offset`, without moving a shared cursor (so
/// several threads read one bank at once).
#[cfg(unix)]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

#[cfg(windows)]
fn read_exact_at(file: &File, mut buf: &mut [u8], mut offset: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_read(buf, offset)? {
            0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            read => {
                buf = &mut buf[read..];
                offset += read as u64;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_series_updated_block_by_block_is_changed_there_alone_held_or_spilled() {
        let n = 2 * BANK_BLOCK_EPOCHS + 5;
        let series = |k: usize| -> Vec<f64> { (0..n).map(|t| (t + 10 * k) as f64).collect() };
        for spill in [false, true] {
            let mut bank = SeriesBank::new(n, spill).unwrap();
            (0..3).for_each(|k| bank.push(series(k)).unwrap());
            let mut seen = Vec::new();
            bank.update(1, &mut |epochs, values| {
                seen.push(epochs.clone());
                values
                    .iter_mut()
                    .zip(epochs)
                    .for_each(|(v, t)| *v -= 2.0 * t as f64);
            })
            .unwrap();
            assert_eq!(seen, block_ranges(0..n).collect::<Vec<_>>());
            let changed: Vec<f64> = (0..n).map(|t| 10.0 - t as f64).collect();
            assert_eq!(bank.series(0).unwrap(), series(0));
            assert_eq!(bank.series(1).unwrap(), changed);
            assert_eq!(bank.series(2).unwrap(), series(2));
        }
    }

    #[test]
    fn a_bank_appended_to_another_follows_its_series_held_or_spilled() {
        let n = BANK_BLOCK_EPOCHS + 77;
        let series = |k: usize| -> Vec<f64> { (0..n).map(|t| (t * (k + 2)) as f64).collect() };
        for spill in [false, true] {
            let mut bank = SeriesBank::new(n, spill).unwrap();
            bank.push(series(0)).unwrap();
            let mut other = SeriesBank::columns(n, 1, spill).unwrap();
            // Written a block at a time, as a term's signature is made.
            for start in (0..n).step_by(1000) {
                let end = (start + 1000).min(n);
                other.write(0, start, &series(1)[start..end]).unwrap();
            }
            let y = series(2);
            let mut held_y = SeriesBank::new(n, spill).unwrap();
            held_y.push(y.clone()).unwrap();
            assert_eq!(other.dots_with(&held_y).unwrap(), other.dots(&y).unwrap());
            bank.append(other).unwrap();
            assert_eq!(bank.len(), 2);
            assert_eq!(
                bank.series(0).unwrap().as_ref(),
                &series(0)[..],
                "spill {spill}"
            );
            assert_eq!(
                bank.series(1).unwrap().as_ref(),
                &series(1)[..],
                "spill {spill}"
            );
        }
    }

    #[test]
    fn a_spilled_bank_reads_back_what_a_held_one_holds_block_by_block() {
        let n = 2 * BANK_BLOCK_EPOCHS + 123;
        let series: Vec<Vec<f64>> = (0..3)
            .map(|k| (0..n).map(|t| (t as f64 * 0.37 + k as f64).sin()).collect())
            .collect();
        let y: Vec<f64> = (0..n).map(|t| (t as f64 * 0.11).cos()).collect();
        let banks: Vec<SeriesBank> = [false, true]
            .into_iter()
            .map(|spill| {
                let mut bank = SeriesBank::new(n, spill).unwrap();
                series.iter().for_each(|s| bank.push(s.clone()).unwrap());
                bank
            })
            .collect();
        for bank in &banks {
            assert_eq!(bank.len(), 3);
            let mut seen = vec![Vec::new(); 3];
            let mut blocks = 0;
            bank.for_each_block(&mut |range, block| {
                blocks += 1;
                for (s, b) in seen.iter_mut().zip(block) {
                    assert_eq!(b.len(), range.len());
                    s.extend_from_slice(b);
                }
            })
            .unwrap();
            assert_eq!(seen, series);
            let dots = bank.dots(&y).unwrap();
            for (d, s) in dots.iter().zip(&series) {
                let whole: f64 = s.iter().zip(&y).map(|(a, b)| a * b).sum();
                assert!(
                    (d - whole).abs() <= 1e-9 * whole.abs().max(1.0),
                    "{d} {whole}"
                );
            }
        }
        let mut spilled_blocks = 0;
        banks[1]
            .for_each_block(&mut |_, _| spilled_blocks += 1)
            .unwrap();
        assert_eq!(spilled_blocks, 3);
    }

    #[test]
    fn series_written_a_block_at_a_time_read_back_whole_in_ranges_and_in_blocks() {
        let n = BANK_BLOCK_EPOCHS + 1000;
        let series: Vec<Vec<f64>> = (0..4)
            .map(|k| (0..n).map(|t| t as f64 * 0.5 - k as f64).collect())
            .collect();
        for spill in [false, true] {
            let mut bank = SeriesBank::columns(n, 4, spill).unwrap();
            assert_eq!(bank.is_spilled(), spill);
            for start in (0..n).step_by(700) {
                let end = (start + 700).min(n);
                for (k, s) in series.iter().enumerate() {
                    bank.write(k, start, &s[start..end]).unwrap();
                }
            }
            assert_eq!(bank.len(), 4);
            assert_eq!(bank.epochs(), n);
            for (k, s) in series.iter().enumerate() {
                assert_eq!(&bank.series(k).unwrap()[..], &s[..]);
                assert_eq!(
                    &bank.range(k, 5..BANK_BLOCK_EPOCHS + 9).unwrap()[..],
                    &s[5..BANK_BLOCK_EPOCHS + 9]
                );
            }
            let mut seen = [Vec::new(), Vec::new()];
            bank.for_each_block_of(&[3, 1], &mut |range, block| {
                assert_eq!(block[0].len(), range.len());
                seen[0].extend_from_slice(block[0]);
                seen[1].extend_from_slice(block[1]);
            })
            .unwrap();
            assert_eq!(seen, [series[3].clone(), series[1].clone()]);
        }
    }
}
