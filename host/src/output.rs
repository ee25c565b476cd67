//! Writing outputs whole or not at all: data go to a temporary file beside the target and are
//! renamed over it only once everything is written and flushed, so a failure midway never
//! leaves a truncated file where a good one is expected.

use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// A file being written; it appears at its final path only on [`AtomicFile::commit`].
/// Dropping it without committing removes the temporary file.
pub struct AtomicFile {
    target: PathBuf,
    temp: Option<tempfile::NamedTempFile>,
    gzip: bool,
}

impl AtomicFile {
    /// Starts writing `target`; gzip-compresses when its name ends in `.gz`.
    pub fn create(target: &Path) -> io::Result<Self> {
        let dir = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let temp = tempfile::Builder::new()
            .prefix(".dynacal-partial-")
            .tempfile_in(&dir)?;
        let gzip = target.extension().is_some_and(|e| e == "gz");
        Ok(Self {
            target: target.to_path_buf(),
            temp: Some(temp),
            gzip,
        })
    }

    /// A buffered writer into the temporary file (compressing if the target is `.gz`).
    /// Drop the writer before calling [`AtomicFile::commit`].
    pub fn writer(&mut self) -> Box<dyn Write + '_> {
        let file = self
            .temp
            .as_mut()
            .expect("writer after commit")
            .as_file_mut();
        let buffered = BufWriter::with_capacity(1 << 16, file);
        if self.gzip {
            Box::new(GzFinish(Some(flate2::write::GzEncoder::new(
                buffered,
                flate2::Compression::default(),
            ))))
        } else {
            Box::new(buffered)
        }
    }

    /// Flushes to disk and moves the file into place.
    pub fn commit(mut self) -> io::Result<()> {
        let temp = self.temp.take().expect("commit twice");
        temp.as_file().sync_all()?;
        // Temporary files are created private (0600); a finished output gets the usual
        // permissions of a new file.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            temp.as_file()
                .set_permissions(std::fs::Permissions::from_mode(0o644))?;
        }
        temp.persist(&self.target).map_err(|e| e.error)?;
        Ok(())
    }
}

/// Writes `bytes` to `target` whole or not at all.
pub fn write_atomic(target: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut f = AtomicFile::create(target)?;
    {
        let mut w = f.writer();
        w.write_all(bytes)?;
        w.flush()?;
    }
    f.commit()
}

/// Serialises `value` as pretty JSON to `target`, whole or not at all.
pub fn write_json_atomic<T: serde::Serialize>(target: &Path, value: &T) -> io::Result<()> {
    let mut bytes = serde_json::to_vec_pretty(value).map_err(io::Error::other)?;
    bytes.push(b'\n');
    write_atomic(target, &bytes)
}

/// A gzip encoder whose flush also finishes the stream, so the caller's usual
/// `flush()` produces a complete gzip member.
struct GzFinish<W: Write>(Option<flate2::write::GzEncoder<W>>);

impl<W: Write> Write for GzFinish<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self.0.as_mut() {
            Some(enc) => enc.write(buf),
            None => Err(io::Error::other("write after gzip stream was finished")),
        }
    }
    fn flush(&mut self) -> io::Result<()> {
        if let Some(enc) = self.0.take() {
            let mut inner = enc.finish()?;
            inner.flush()?;
        }
        Ok(())
    }
}
