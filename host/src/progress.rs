//! How far long work has come, for a progress display. The library draws nothing: it tells
//! the process's observers, if the program installed any (the `dynacal` binary draws on
//! stderr).
//!
//! - Reading: every file the host reads goes through [`crate::interchange::open_maybe_gz`]
//!   (a board log through [`crate::decode::decode_file`], a Parquet file through its column
//!   reader), which counts the bytes taken from the file on disk (compressed bytes for a gzip
//!   file, so the share is right either way) and tells the [`ReadProgress`] observer.
//! - Computing: long computations (a diagnosis, a calibration) name the stage they enter with
//!   [`stage`], told to the [`WorkProgress`] observer: a run of many minutes says what it is
//!   doing rather than only that it runs; work of a known size (a diagnosis's passes over
//!   its channels, a bootstrap's replicates) counts its units with a [`Tally`], so the
//!   display shows how much is done and how long the rest will take.

use std::io::Read;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

/// What is told of a file being read. One file's calls come from one thread, in order:
/// `started`, `advanced` as bytes come, `finished` once (when the reader is dropped).
pub trait ReadProgress: Send + Sync {
    /// Reading of `path` (`size_bytes` on disk) starts; returns the handle its later calls
    /// carry (several files may be open at once).
    fn started(&self, path: &Path, size_bytes: u64) -> u64;
    /// `bytes` more of file `handle` were read.
    fn advanced(&self, handle: u64, bytes: u64);
    /// File `handle` is closed.
    fn finished(&self, handle: u64);
}

static OBSERVER: OnceLock<Box<dyn ReadProgress>> = OnceLock::new();

/// Installs the process's observer of file reading; false if one already was.
pub fn observe_reading(observer: Box<dyn ReadProgress>) -> bool {
    OBSERVER.set(observer).is_ok()
}

/// What is told of long work: the stage it enters (any thread, in the order they come).
pub trait WorkProgress: Send + Sync {
    /// Work enters the stage `what` ("channel gx: measuring the gain").
    fn stage(&self, what: &str);
    /// `done` of the `total` units of work a [`Tally`] counts are finished (`total` may grow
    /// as work finds more to do).
    fn counted(&self, done: u64, total: u64) {
        let _ = (done, total);
    }
}

static WORK_OBSERVER: OnceLock<Box<dyn WorkProgress>> = OnceLock::new();

/// Installs the process's observer of long work; false if one already was.
pub fn observe_work(observer: Box<dyn WorkProgress>) -> bool {
    WORK_OBSERVER.set(observer).is_ok()
}

/// Tells the observer, if any, that work enters the stage `what()` (formatted only then).
pub fn stage(what: impl FnOnce() -> String) {
    if let Some(observer) = WORK_OBSERVER.get() {
        observer.stage(&what());
    }
}

/// Units of work of a known count (any thread), told to the [`WorkProgress`] observer as
/// they are announced and finished.
#[derive(Debug, Default)]
pub struct Tally {
    done: AtomicU64,
    total: AtomicU64,
}

impl Tally {
    /// `units` more units of work are to come.
    pub fn expect(&self, units: u64) {
        let total = self.total.fetch_add(units, Ordering::Relaxed) + units;
        Self::tell(self.done.load(Ordering::Relaxed), total);
    }

    /// One unit of work is finished.
    pub fn finish_one(&self) {
        self.finish(1);
    }

    /// `units` units of work are finished (or found to need nothing).
    pub fn finish(&self, units: u64) {
        let done = self.done.fetch_add(units, Ordering::Relaxed) + units;
        Self::tell(done, self.total.load(Ordering::Relaxed));
    }

    /// Units finished and announced so far.
    pub fn counts(&self) -> (u64, u64) {
        (
            self.done.load(Ordering::Relaxed),
            self.total.load(Ordering::Relaxed),
        )
    }

    fn tell(done: u64, total: u64) {
        if let Some(observer) = WORK_OBSERVER.get() {
            observer.counted(done.min(total), total);
        }
    }
}

/// Bytes between two reports: often enough for a bar, rarely enough to cost nothing.
const REPORT_EVERY_BYTES: u64 = 1 << 20;

/// What one file's reading has reported: the handle the observer gave it and the bytes not
/// yet told. Tells the observer the file is finished when dropped.
pub(crate) struct Reporter {
    handle: Option<u64>,
    unreported: u64,
}

impl Reporter {
    /// Starts reporting the reading of `path` (`size_bytes` on disk); reports nothing when
    /// no observer is installed.
    pub fn new(path: &Path, size_bytes: u64) -> Self {
        Self {
            handle: OBSERVER.get().map(|o| o.started(path, size_bytes)),
            unreported: 0,
        }
    }

    /// `bytes` more were read; told to the observer once a megabyte has gathered.
    pub fn add(&mut self, bytes: u64) {
        self.unreported += bytes;
        if self.unreported >= REPORT_EVERY_BYTES {
            self.report();
        }
    }

    fn report(&mut self) {
        if let (Some(h), Some(o)) = (self.handle, OBSERVER.get()) {
            if self.unreported > 0 {
                o.advanced(h, self.unreported);
            }
        }
        self.unreported = 0;
    }
}

impl Drop for Reporter {
    fn drop(&mut self) {
        self.report();
        if let (Some(h), Some(o)) = (self.handle, OBSERVER.get()) {
            o.finished(h);
        }
    }
}

/// A reader that counts what it takes from `inner` and reports it to the observer.
pub(crate) struct Counted<R> {
    inner: R,
    reporter: Reporter,
}

impl<R: Read> Counted<R> {
    /// `inner` reading `path` of `size_bytes`; reports nothing when no observer is installed.
    pub fn new(inner: R, path: &Path, size_bytes: u64) -> Self {
        Counted {
            inner,
            reporter: Reporter::new(path, size_bytes),
        }
    }
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.reporter.add(n as u64);
        if n == 0 {
            self.reporter.report();
        }
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    /// Records every call, for the process-wide observer of this test binary.
    #[derive(Default)]
    struct Recorder {
        calls: Mutex<Vec<(String, u64, u64)>>,
    }

    impl ReadProgress for &'static Recorder {
        fn started(&self, path: &Path, size_bytes: u64) -> u64 {
            let mut calls = self.calls.lock().unwrap();
            let handle = calls.len() as u64;
            calls.push((path.display().to_string(), handle, size_bytes));
            handle
        }
        fn advanced(&self, handle: u64, bytes: u64) {
            self.calls
                .lock()
                .unwrap()
                .push(("advanced".into(), handle, bytes));
        }
        fn finished(&self, handle: u64) {
            self.calls
                .lock()
                .unwrap()
                .push(("finished".into(), handle, 0));
        }
    }

    /// Stages told with `stage` reach the installed observer, in order, formatted; a
    /// tally's units are counted as announced and finished.
    #[test]
    fn stages_and_counted_work_reach_the_work_observer_in_order() {
        static STAGES: Mutex<Vec<String>> = Mutex::new(Vec::new());
        static COUNTED: Mutex<Vec<(u64, u64)>> = Mutex::new(Vec::new());
        struct Log;
        impl WorkProgress for Log {
            fn stage(&self, what: &str) {
                STAGES.lock().unwrap().push(what.to_string());
            }
            fn counted(&self, done: u64, total: u64) {
                COUNTED.lock().unwrap().push((done, total));
            }
        }
        assert!(observe_work(Box::new(Log)));
        assert!(!observe_work(Box::new(Log)), "one observer a process");
        stage(|| "a first stage".into());
        stage(|| format!("channel {}: a second", "gx"));
        // Other tests of this binary (calibrations) may tell stages of their own meanwhile.
        let seen = STAGES.lock().unwrap().clone();
        let mine: Vec<&str> = seen
            .iter()
            .map(String::as_str)
            .filter(|s| s.starts_with("a first") || s.ends_with("a second"))
            .collect();
        assert_eq!(mine, ["a first stage", "channel gx: a second"]);
        // A total no other test's tally has, so theirs can be told apart.
        let tally = Tally::default();
        tally.expect(7_000);
        tally.expect(919);
        tally.finish_one();
        tally.finish_one();
        assert_eq!(tally.counts(), (2, 7_919));
        let counted: Vec<(u64, u64)> = COUNTED
            .lock()
            .unwrap()
            .iter()
            .copied()
            .filter(|&(_, total)| total == 7_000 || total == 7_919)
            .collect();
        assert_eq!(counted, [(0, 7_000), (0, 7_919), (1, 7_919), (2, 7_919)]);
    }

    /// A gzip file read through `open_maybe_gz` reports its compressed size, bytes adding up
    /// to it, and one `finished`, whether it is read to the end or dropped early.
    #[test]
    fn reading_reports_the_bytes_on_disk_and_one_finish() {
        static RECORDER: OnceLock<Recorder> = OnceLock::new();
        let recorder: &'static Recorder = RECORDER.get_or_init(Recorder::default);
        assert!(observe_reading(Box::new(recorder)));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rows.csv.gz");
        let text: String = (0..200_000).map(|i| format!("{i},{}\n", i * 7)).collect();
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        std::io::Write::write_all(&mut gz, text.as_bytes()).unwrap();
        let bytes = gz.finish().unwrap();
        std::fs::write(&path, &bytes).unwrap();
        let mut whole = String::new();
        crate::interchange::open_maybe_gz(&path)
            .unwrap()
            .read_to_string(&mut whole)
            .unwrap();
        assert_eq!(whole, text);
        let mut first = [0u8; 10];
        crate::interchange::open_maybe_gz(&path)
            .unwrap()
            .read_exact(&mut first)
            .unwrap();
        let calls = recorder.calls.lock().unwrap().clone();
        let of = |h: u64, what: &str| -> Vec<u64> {
            calls
                .iter()
                .filter(|c| c.1 == h && c.0 == what)
                .map(|c| c.2)
                .collect()
        };
        let opened: Vec<&(String, u64, u64)> = calls
            .iter()
            .filter(|c| c.0 == path.display().to_string())
            .collect();
        assert_eq!(opened.len(), 2, "{calls:?}");
        let handles: Vec<u64> = opened.iter().map(|c| c.1).collect();
        for (_, h, size) in &opened {
            assert_eq!(*size, bytes.len() as u64);
            assert_eq!(of(*h, "finished").len(), 1, "{calls:?}");
        }
        let read = |h: u64| of(h, "advanced").iter().sum::<u64>();
        assert_eq!(read(handles[0]), bytes.len() as u64, "read to the end");
        assert!(read(handles[1]) < bytes.len() as u64, "dropped early");
    }
}
