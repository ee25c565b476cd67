//! Writing outputs whole or not at all.
//!
//! - **One file** ([`AtomicFile`], [`write_atomic`], [`write_json_atomic`]): the data go to a
//!   temporary file `.dynacal-partial-*` beside the target and are renamed over it only
//!   once everything is written and flushed to disk, so a failure or a kill midway never
//!   leaves a truncated file where a good one is expected: the target holds its previous
//!   contents, or none, until the rename. (The replay firmware under QEMU does the same
//!   with `LOG.part`, [`PartialPath`].)
//! - **A set of files in one folder** ([`FileSet`]: `simulate`, `import`, `decode`,
//!   `refit`, `fig1`, the report folders): every file is staged in a hidden folder
//!   `.dynacal-partial-*` inside the output folder, and moved into place only once all are
//!   written. The folder's set is complete exactly when its *completion marker* is there
//!   (each command names it: `truth.json` for `simulate`, `summary.json` for `decode`,
//!   `refit.json` for `refit`, ...): the previous marker is removed before the first file
//!   is moved in and the new one is moved in last. A kill during the moves (renames within
//!   one folder, microseconds after minutes of writing) can leave new and previous files
//!   side by side, but never with a marker. Files of a previous set that the new one does
//!   not write (a `board.log` from an earlier `simulate --replay`) are left as they are.
//! - **Signals**: on SIGINT, SIGTERM or SIGHUP, [`remove_partials_on_signal`]'s handler
//!   removes every temporary file and staging folder the process has open, waits for a set
//!   being moved into place to be complete, and ends the process as the signal would have.
//!   A SIGKILL cannot be caught: its temporaries stay (hidden, named `.dynacal-partial-*`)
//!   and the outputs are as above.

use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, PoisonError};

/// Temporary files and staging folders this process has open (what a signal removes).
static PARTIALS: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// The list of partial outputs; a panic elsewhere while it was held leaves it usable.
fn partials() -> MutexGuard<'static, Vec<PathBuf>> {
    PARTIALS.lock().unwrap_or_else(PoisonError::into_inner)
}

fn forget_partial(list: &mut Vec<PathBuf>, path: &Path) {
    if let Some(k) = list.iter().rposition(|p| p == path) {
        list.swap_remove(k);
    }
}

/// Prefix of every temporary file and staging folder.
pub const PARTIAL_PREFIX: &str = ".dynacal-partial-";

/// Installs the handler that removes the partial outputs on SIGINT, SIGTERM and SIGHUP and
/// then ends the process as the signal's default action does (a shell sees the signal in
/// the exit status). Call once, at the start of `main`.
///
/// `signal-hook` rather than a handler of our own: its handler only writes to a pipe, and
/// the removal runs on an ordinary thread that may lock and do I/O, which a signal handler
/// may not; and it re-raises the signal with its default action afterwards, which `ctrlc`
/// does not offer.
pub fn remove_partials_on_signal() -> io::Result<()> {
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
        let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])?;
        std::thread::Builder::new()
            .name("dynacal-signals".into())
            .spawn(move || {
                if let Some(signal) = signals.forever().next() {
                    // Held to the end: a set being moved into place (which holds it) is
                    // finished first, and no new temporary can be registered meanwhile.
                    let list = partials();
                    for path in list.iter() {
                        // An error is a path gone already (moved into place): nothing to do.
                        let _ = if path.is_dir() {
                            std::fs::remove_dir_all(path)
                        } else {
                            std::fs::remove_file(path)
                        };
                    }
                    let _ = signal_hook::low_level::emulate_default_handler(signal);
                    std::process::exit(128 + signal);
                }
            })?;
    }
    Ok(())
}

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
        let mut list = partials();
        let temp = tempfile::Builder::new()
            .prefix(PARTIAL_PREFIX)
            .tempfile_in(&dir)?;
        list.push(temp.path().to_path_buf());
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
        encoded(file, self.gzip)
    }

    /// As [`Self::writer`], on its own handle of the temporary file, so that it can be kept
    /// beside the `AtomicFile` (a file written row by row). Flush and drop it before
    /// [`AtomicFile::commit`]; one writer at a time, as they share the file's offset.
    pub fn owned_writer(&self) -> io::Result<Box<dyn Write + Send>> {
        let file = self
            .temp
            .as_ref()
            .expect("writer after commit")
            .as_file()
            .try_clone()?;
        Ok(encoded(file, self.gzip))
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
        let path = temp.path().to_path_buf();
        let persisted = temp.persist(&self.target).map_err(|e| e.error);
        forget_partial(&mut partials(), &path);
        persisted.map(|_| ())
    }
}

impl Drop for AtomicFile {
    /// An uncommitted file: its temporary is removed (by `NamedTempFile`) and forgotten.
    fn drop(&mut self) {
        if let Some(temp) = self.temp.take() {
            let path = temp.path().to_path_buf();
            drop(temp);
            forget_partial(&mut partials(), &path);
        }
    }
}

/// Files written into one folder as a set, whole or not at all (the policy of the module's
/// note): staged in a hidden folder inside it, moved into place by [`FileSet::commit`] with
/// the completion marker last. Dropping it uncommitted removes what was staged.
pub struct FileSet {
    dir: PathBuf,
    /// The folder did not exist before the set: an uncommitted set removes it again.
    created_dir: bool,
    staging: Option<tempfile::TempDir>,
    names: Vec<String>,
    marker: Option<String>,
}

impl FileSet {
    /// Starts a set in `dir` (created if absent, and removed again if the set is dropped
    /// uncommitted) whose completion marker is the file `marker` (None: a set whose files
    /// each stand alone, as `import`'s recordings).
    pub fn create(dir: &Path, marker: Option<&str>) -> io::Result<Self> {
        let created_dir = !dir.exists();
        std::fs::create_dir_all(dir)?;
        let mut list = partials();
        let staging = tempfile::Builder::new()
            .prefix(PARTIAL_PREFIX)
            .tempdir_in(dir)?;
        list.push(staging.path().to_path_buf());
        Ok(Self {
            dir: dir.to_path_buf(),
            created_dir,
            staging: Some(staging),
            names: Vec::new(),
            marker: marker.map(str::to_string),
        })
    }

    /// Where to write the set's file `name` (in the staging folder), which joins the set:
    /// write it whole (e.g. with [`AtomicFile`]) before [`FileSet::commit`].
    pub fn path(&mut self, name: &str) -> PathBuf {
        if !self.names.iter().any(|n| n == name) {
            self.names.push(name.to_string());
        }
        self.staging_dir().join(name)
    }

    /// The staging folder.
    pub fn staging_dir(&self) -> &Path {
        self.staging
            .as_ref()
            .map_or(self.dir.as_path(), tempfile::TempDir::path)
    }

    /// The folder the set goes to.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Moves the staged files into the folder, the marker last after removing the previous
    /// one; returns their paths in the order moved. A signal arriving meanwhile waits for
    /// the moves to finish (see [`remove_partials_on_signal`]).
    pub fn commit(mut self) -> io::Result<Vec<PathBuf>> {
        let Some(staging) = self.staging.take() else {
            return Ok(Vec::new());
        };
        let mut list = partials();
        let moved = self.move_into_place(staging.path());
        forget_partial(&mut list, staging.path());
        drop(list);
        // Removes the staging folder (empty unless a move failed).
        drop(staging);
        moved
    }

    fn move_into_place(&self, staging: &Path) -> io::Result<Vec<PathBuf>> {
        let in_context = |path: &Path| {
            let path = path.display().to_string();
            move |e: io::Error| io::Error::new(e.kind(), format!("{path}: {e}"))
        };
        let marker = self.marker.as_deref();
        if let Some(marker) = marker {
            if !self.names.iter().any(|n| n == marker) {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!("the set has no completion marker {marker}"),
                ));
            }
            let previous = self.dir.join(marker);
            match std::fs::remove_file(&previous) {
                Err(e) if e.kind() != io::ErrorKind::NotFound => {
                    return Err(in_context(&previous)(e));
                }
                _ => {}
            }
        }
        let (last, first): (Vec<&String>, Vec<&String>) =
            self.names.iter().partition(|n| Some(n.as_str()) == marker);
        let mut moved = Vec::with_capacity(self.names.len());
        for name in first.into_iter().chain(last) {
            let target = self.dir.join(name);
            std::fs::rename(staging.join(name), &target).map_err(in_context(&target))?;
            moved.push(target);
        }
        // The renames reach the disk with the folder's entry (best effort: not every
        // platform can open a folder to sync it).
        if let Ok(dir) = std::fs::File::open(&self.dir) {
            let _ = dir.sync_all();
        }
        Ok(moved)
    }
}

impl Drop for FileSet {
    /// An uncommitted set: the staging folder is removed (by `TempDir`) and forgotten, and
    /// the folder too if the set made it (a failed command leaves no empty folder).
    fn drop(&mut self) {
        if let Some(staging) = self.staging.take() {
            let path = staging.path().to_path_buf();
            drop(staging);
            forget_partial(&mut partials(), &path);
            if self.created_dir {
                let _ = std::fs::remove_dir(&self.dir);
            }
        }
    }
}

/// A partial output another process writes (the replay firmware's `LOG.part` under QEMU):
/// removed on SIGINT, SIGTERM or SIGHUP like this process's own temporaries, and on drop if
/// it is still there (the writer failed before moving it into place).
pub struct PartialPath {
    path: PathBuf,
}

impl PartialPath {
    /// Takes `path` as a partial output from now on.
    pub fn register(path: &Path) -> Self {
        partials().push(path.to_path_buf());
        Self {
            path: path.to_path_buf(),
        }
    }
}

impl Drop for PartialPath {
    fn drop(&mut self) {
        let mut list = partials();
        // Absent after a successful run: the writer moved it into place.
        let _ = std::fs::remove_file(&self.path);
        forget_partial(&mut list, &self.path);
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

/// `file` buffered, and gzip-compressed when `gzip` (the stream finished on flush).
fn encoded<'a, W: Write + Send + 'a>(file: W, gzip: bool) -> Box<dyn Write + Send + 'a> {
    let buffered = BufWriter::with_capacity(1 << 16, file);
    if gzip {
        Box::new(GzFinish(Some(flate2::write::GzEncoder::new(
            buffered,
            flate2::Compression::default(),
        ))))
    } else {
        Box::new(buffered)
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn visible(dir: &Path) -> Vec<(String, String)> {
        let mut files: Vec<(String, String)> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap())
            .map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let text = std::fs::read_to_string(e.path()).unwrap_or_default();
                (name, text)
            })
            .collect();
        files.sort();
        files
    }

    fn previous_set(dir: &Path) {
        std::fs::write(dir.join("a.csv"), "old a").unwrap();
        std::fs::write(dir.join("truth.json"), "old truth").unwrap();
    }

    #[test]
    fn a_committed_set_moves_its_marker_in_last_and_leaves_no_staging_folder() {
        let dir = tempfile::tempdir().unwrap();
        previous_set(dir.path());
        let mut set = FileSet::create(dir.path(), Some("truth.json")).unwrap();
        write_atomic(&set.path("truth.json"), b"new truth").unwrap();
        write_atomic(&set.path("a.csv"), b"new a").unwrap();
        write_atomic(&set.path("b.csv"), b"new b").unwrap();
        let moved = set.commit().unwrap();
        let names: Vec<_> = moved.iter().map(|p| p.file_name().unwrap()).collect();
        assert_eq!(names, ["a.csv", "b.csv", "truth.json"]);
        let expected = [
            ("a.csv", "new a"),
            ("b.csv", "new b"),
            ("truth.json", "new truth"),
        ]
        .map(|(n, t)| (n.to_string(), t.to_string()));
        assert_eq!(visible(dir.path()), expected);
        assert!(partials().iter().all(|p| !p.starts_with(dir.path())));
    }

    #[test]
    fn a_set_dropped_before_its_commit_leaves_the_folder_as_it_was() {
        let dir = tempfile::tempdir().unwrap();
        previous_set(dir.path());
        let before = visible(dir.path());
        let mut set = FileSet::create(dir.path(), Some("truth.json")).unwrap();
        write_atomic(&set.path("a.csv"), b"new a").unwrap();
        let mut half = AtomicFile::create(&set.path("truth.json")).unwrap();
        half.writer().write_all(b"new tr").unwrap();
        drop(half);
        drop(set);
        assert_eq!(visible(dir.path()), before);
        assert!(partials().iter().all(|p| !p.starts_with(dir.path())));
    }

    #[test]
    fn a_set_without_its_marker_is_refused_before_anything_moves() {
        let dir = tempfile::tempdir().unwrap();
        previous_set(dir.path());
        let before = visible(dir.path());
        let mut set = FileSet::create(dir.path(), Some("truth.json")).unwrap();
        write_atomic(&set.path("a.csv"), b"new a").unwrap();
        let error = set.commit().unwrap_err();
        assert!(error.to_string().contains("truth.json"), "{error}");
        assert_eq!(visible(dir.path()), before);
    }
}
