//! Interrupted runs lose nothing (issue 21, part 5): `dynacal` killed while it writes, by
//! SIGKILL, SIGTERM or SIGINT at several points of the write, leaves the previous output
//! as it was, byte for byte, and nothing under an output's name that it did not hold
//! before; on SIGTERM and SIGINT it also removes its temporary files (`.dynacal-partial-*`)
//! and ends as killed by the signal. The policy is `dynacal::output`'s.

use std::collections::BTreeMap;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use dynacal::output::PARTIAL_PREFIX;

/// One MEMS unit at 100 Hz beside the reference (for `errors`).
const MEMS_MODEL: &str = r#"{"imus": [{"name": "mems", "rate_hz": 100, "lever_arm_b_m": [0.2, -0.1, 0.05],
  "gyro": {"stochastic": {"model": "WN", "unit": "rad/s", "sample_rate_hz": 100,
     "processes": [{"kind": "white_noise", "sigma2": 1e-5}]}},
  "accel": {"stochastic": {"model": "WN", "unit": "m/s^2", "sample_rate_hz": 100,
     "processes": [{"kind": "white_noise", "sigma2": 1e-3}]}}}]}"#;

const SIGKILL: i32 = 9;
const SIGINT: i32 = 2;
const SIGTERM: i32 = 15;

fn dynacal(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .output()
        .expect("run dynacal");
    assert!(
        out.status.success(),
        "dynacal {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start dynacal")
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The visible files of `dir` (not starting with '.') and their bytes.
fn outputs(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap())
        .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
        .map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            (name, std::fs::read(e.path()).unwrap())
        })
        .collect()
}

/// The temporary files and staging folders in `dir`.
fn partials(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap())
        .filter(|e| e.file_name().to_string_lossy().starts_with(PARTIAL_PREFIX))
        .map(|e| e.path())
        .collect()
}

/// Size of the largest file in `dir` and in its staging folders, bytes.
fn largest_partial_bytes(dir: &Path) -> u64 {
    let size = |p: &Path| std::fs::metadata(p).map_or(0, |m| m.len());
    partials(dir)
        .iter()
        .flat_map(|p| match std::fs::read_dir(p) {
            Ok(entries) => entries.map(|e| size(&e.unwrap().path())).collect(),
            Err(_) => vec![size(p)],
        })
        .max()
        .unwrap_or(0)
}

/// Where in the write to kill.
#[derive(Debug, Clone, Copy)]
enum KillPoint {
    /// As soon as a temporary file or staging folder appears in the output folder.
    Started,
    /// Once a file being written has grown to this many bytes.
    Grown(u64),
}

/// Waits for `point` in `dir`, sends `signal` and waits for the process to end; panics if
/// it ended on its own first (the point came too late to test anything).
fn kill_at(mut child: Child, dir: &Path, point: KillPoint, signal: i32) {
    let started = Instant::now();
    loop {
        let reached = match point {
            KillPoint::Started => !partials(dir).is_empty(),
            KillPoint::Grown(bytes) => largest_partial_bytes(dir) >= bytes,
        };
        if reached {
            break;
        }
        if let Some(status) = child.try_wait().unwrap() {
            panic!("dynacal ended ({status}) before {point:?}");
        }
        assert!(
            started.elapsed() < Duration::from_secs(300),
            "{point:?} never came"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    let sent = Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let status = child.wait().unwrap();
    assert_eq!(
        status.signal(),
        Some(signal),
        "dynacal was to end by signal {signal} at {point:?}: {status}"
    );
}

/// After a kill: the outputs are what they were, and on a signal the process can catch its
/// temporaries are gone (after SIGKILL they stay, hidden; they are removed for the next
/// round).
fn assert_untouched(dir: &Path, before: &BTreeMap<String, Vec<u8>>, signal: i32, what: &str) {
    let after = outputs(dir);
    assert_eq!(
        after.keys().collect::<Vec<_>>(),
        before.keys().collect::<Vec<_>>(),
        "{what}: the set of files changed"
    );
    for (name, bytes) in before {
        assert!(after[name] == *bytes, "{what}: {name} changed");
    }
    let left = partials(dir);
    if signal == SIGKILL {
        for p in left {
            let _ = std::fs::remove_dir_all(&p).or_else(|_| std::fs::remove_file(&p));
        }
    } else {
        assert!(left.is_empty(), "{what}: temporaries left behind: {left:?}");
    }
}

/// `simulate` writes a set of files into a folder (a reference CSV of about 150 MB for an
/// hour): killed at its start, early in the big file and deep into it, the previous set of
/// a shorter run stays as it was.
#[test]
fn a_simulation_killed_while_it_writes_leaves_the_previous_set_as_it_was() {
    // GIVEN the complete set of a 60 s simulation in a folder
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    dynacal(&["simulate", "--seconds", "60", "--out", path(&out)]);
    let before = outputs(&out);
    assert!(
        before.contains_key("truth.json") && before.len() >= 4,
        "{before:?}"
    );
    let cases = [
        (KillPoint::Started, SIGKILL),
        (KillPoint::Grown(1 << 20), SIGTERM),
        (KillPoint::Grown(20 << 20), SIGINT),
        (KillPoint::Grown(40 << 20), SIGKILL),
    ];
    for (point, signal) in cases {
        // WHEN an hour's simulation into the same folder is killed while it writes
        let child = spawn(&["simulate", "--seconds", "3600", "--out", path(&out)]);
        kill_at(child, &out, point, signal);
        // THEN the previous set is there byte for byte, and nothing else is in view
        assert_untouched(
            &out,
            &before,
            signal,
            &format!("{point:?}, signal {signal}"),
        );
    }
}

/// `errors --out` writes one large CSV (an error signal per sample): killed as its
/// temporary appears, the previous file stays as it was.
#[test]
fn an_error_signal_killed_while_it_is_written_leaves_the_previous_file_as_it_was() {
    // GIVEN a 20-minute simulation with a MEMS unit and its error signals already written
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("m.json"), MEMS_MODEL).unwrap();
    let sim = d.join("sim");
    dynacal(&[
        "simulate",
        "--seconds",
        "1200",
        "--model",
        path(&d.join("m.json")),
        "--out",
        path(&sim),
    ]);
    let out = d.join("errors");
    std::fs::create_dir(&out).unwrap();
    let (sensor, reference, target) = (
        sim.join("mems.csv"),
        sim.join("reference.csv"),
        out.join("e.csv"),
    );
    let args = [
        "errors",
        "--sensor",
        path(&sensor),
        "--reference",
        path(&reference),
        "--out",
        path(&target),
    ];
    dynacal(&args);
    let before = outputs(&out);
    assert_eq!(before.len(), 1);
    for signal in [SIGKILL, SIGTERM] {
        // WHEN the same command is killed as soon as it starts writing
        kill_at(spawn(&args), &out, KillPoint::Started, signal);
        // THEN the previous file is there byte for byte
        assert_untouched(&out, &before, signal, &format!("errors, signal {signal}"));
    }
}
