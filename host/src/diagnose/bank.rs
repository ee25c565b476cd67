//! Series of one run's length that a stage needs together, a block of epochs at a time
//! ([`SeriesBank`]): a dozen candidate terms' filtered signatures, or the calibration's
//! filtered columns on a channel, against each of which every baseline simulation is
//! multiplied. On a short run they are held; on a long one they are written to a temporary
//! file as they are made and read back a block at a time, so a stage holds a block of each
//! rather than a dozen series of the drive's length (the operating system's file cache,
//! not the process, keeps what it can of the file).

use std::fs::File;
use std::io::Write;
use std::ops::Range;

use super::engine::DiagnoseError;

/// Epochs of each series read at a time from a spilled bank (128 KiB of each).
pub(super) const BANK_BLOCK_EPOCHS: usize = 1 << 14;

/// What visits a bank's blocks: the block's epochs, and every series over them.
pub(super) type BlockVisit<'v> = dyn FnMut(Range<usize>, &[&[f64]]) + 'v;

/// See the module documentation.
pub(super) struct SeriesBank {
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

fn spill_error(source: std::io::Error) -> DiagnoseError {
    DiagnoseError::Spill {
        dir: std::env::temp_dir(),
        source,
    }
}

impl SeriesBank {
    /// An empty bank of series of `n` epochs, spilled to a temporary file when `spill`.
    pub fn new(n: usize, spill: bool) -> Result<Self, DiagnoseError> {
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

    /// Adds `series` (of the bank's length) as the next one.
    pub fn push(&mut self, series: Vec<f64>) -> Result<(), DiagnoseError> {
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

    /// Number of series.
    pub fn len(&self) -> usize {
        match &self.store {
            Store::Held(held) => held.len(),
            Store::Spilled { count, .. } => *count,
        }
    }

    /// Calls `visit` with each block of epochs in order (its range, and every series over
    /// it, in the order they were pushed).
    pub fn for_each_block(&self, visit: &mut BlockVisit<'_>) -> Result<(), DiagnoseError> {
        match &self.store {
            Store::Held(held) => {
                let all: Vec<&[f64]> = held.iter().map(Vec::as_slice).collect();
                visit(0..self.n, &all);
                Ok(())
            }
            Store::Spilled { file, count } => {
                let mut bytes = vec![0u8; 8 * BANK_BLOCK_EPOCHS];
                let mut blocks = vec![Vec::with_capacity(BANK_BLOCK_EPOCHS); *count];
                for start in (0..self.n).step_by(BANK_BLOCK_EPOCHS) {
                    let end = (start + BANK_BLOCK_EPOCHS).min(self.n);
                    for (k, block) in blocks.iter_mut().enumerate() {
                        let bytes = &mut bytes[..8 * (end - start)];
                        read_exact_at(file, bytes, 8 * (k * self.n + start) as u64)
                            .map_err(spill_error)?;
                        block.clear();
                        block.extend(
                            bytes
                                .chunks_exact(8)
                                .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))),
                        );
                    }
                    let views: Vec<&[f64]> = blocks.iter().map(Vec::as_slice).collect();
                    visit(start..end, &views);
                }
                Ok(())
            }
        }
    }

    /// Each series' inner product with `y` (of the bank's length).
    pub fn dots(&self, y: &[f64]) -> Result<Vec<f64>, DiagnoseError> {
        let mut sums = vec![0.0; self.len()];
        self.for_each_block(&mut |range, series| {
            let y = &y[range];
            for (sum, x) in sums.iter_mut().zip(series) {
                *sum += x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
            }
        })?;
        Ok(sums)
    }
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
}
