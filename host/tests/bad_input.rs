//! Every command under bad input: the corpus of `tests/bad-input` (its README says what is
//! in it). Each case must fail with exit status 1 and a message naming the file and the
//! line, field or time, never panic, and leave nothing in its output folder.

use std::path::{Path, PathBuf};
use std::process::Command;

const DYNACAL: &str = env!("CARGO_BIN_EXE_dynacal");

#[derive(serde::Deserialize)]
struct Case {
    name: String,
    why: String,
    args: Vec<String>,
    expect: Vec<String>,
}

fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/bad-input")
}

fn run_ok(args: &[&str]) {
    let o = Command::new(DYNACAL).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "dynacal {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The valid recordings the cases pair broken ones with, and what is derived from them.
struct Inputs {
    _dir: tempfile::TempDir,
    car: PathBuf,
    still: PathBuf,
    work: PathBuf,
}

fn inputs() -> Inputs {
    let dir = tempfile::tempdir().unwrap();
    let (car, still, work) = (
        dir.path().join("car"),
        dir.path().join("static"),
        dir.path().join("work"),
    );
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/board-three-mems.json");
    let model = model.to_str().unwrap();
    run_ok(&[
        "simulate",
        "--model",
        model,
        "--scenario",
        "car",
        "--seconds",
        "60",
        "--seed",
        "3",
        "--replay",
        "--out",
        car.to_str().unwrap(),
    ]);
    run_ok(&[
        "simulate",
        "--model",
        model,
        "--scenario",
        "static",
        "--seconds",
        "120",
        "--seed",
        "4",
        "--out",
        still.to_str().unwrap(),
    ]);
    std::fs::create_dir(&work).unwrap();
    run_ok(&[
        "fit",
        still.join("icm0.csv").to_str().unwrap(),
        "--model",
        "WN+GM",
        "--json",
        work.join("baseline.json").to_str().unwrap(),
    ]);
    let errors = work.join("errors.csv");
    run_ok(&[
        "errors",
        "--sensor",
        car.join("icm0.csv").to_str().unwrap(),
        "--reference",
        car.join("reference.csv").to_str().unwrap(),
        "--out",
        errors.to_str().unwrap(),
    ]);
    let text = std::fs::read_to_string(&errors).unwrap();
    let head: Vec<&str> = text.lines().take(6).collect();
    std::fs::write(work.join("errors-5-rows.csv"), head.join("\n") + "\n").unwrap();
    derive_csv(
        &car.join("reference.csv"),
        &work.join("reference-late.csv"),
        |t, _, v| (Some(t + 1000.0), v),
    );
    derive_csv(
        &car.join("icm2.csv"),
        &work.join("icm2-late.csv"),
        |t, _, v| (Some(t + 500.0), v),
    );
    derive_csv(
        &car.join("icm0.csv"),
        &work.join("icm0-100hz.csv"),
        |t, i, v| ((i % 10 == 0).then_some(t), v),
    );
    derive_csv(
        &car.join("icm0.csv"),
        &work.join("icm0-in-g.csv"),
        |t, _, mut v| {
            for a in &mut v[3..6] {
                *a /= 9.80665;
            }
            (Some(t), v)
        },
    );
    let cut = |from: &Path, to: &Path, bytes: usize| {
        std::fs::write(to, &std::fs::read(from).unwrap()[..bytes]).unwrap();
    };
    cut(&car.join("board.log"), &work.join("board-short.log"), 3000);
    cut(
        &car.join("board.replay"),
        &work.join("replay-cut.replay"),
        5000,
    );
    Inputs {
        _dir: dir,
        car,
        still,
        work,
    }
}

/// Writes the interchange recording `from` (gyro and accelerometer columns) to `to`, each
/// row (time, index, the six values) mapped by `row`; a `None` time drops the row. The rate
/// line is left out, so the reader estimates it from the times.
fn derive_csv(
    from: &Path,
    to: &Path,
    row: impl Fn(f64, usize, Vec<f64>) -> (Option<f64>, Vec<f64>),
) {
    let text = std::fs::read_to_string(from).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let mut out = String::from(lines.next().unwrap());
    out.push('\n');
    for (i, line) in lines.enumerate() {
        let fields: Vec<f64> = line.split(',').map(|f| f.parse().unwrap()).collect();
        if let (Some(t), values) = row(fields[0], i, fields[1..].to_vec()) {
            let values: Vec<String> = values.iter().map(f64::to_string).collect();
            out += &format!("{t},{}\n", values.join(","));
        }
    }
    std::fs::write(to, out).unwrap();
}

/// Every file under `dir`, hidden ones too.
fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            found.extend(files_under(&path));
        } else {
            found.push(path);
        }
    }
    found
}

#[test]
fn every_command_refuses_broken_input_naming_the_place_and_writing_nothing() {
    let cases: Vec<Case> =
        serde_json::from_slice(&std::fs::read(corpus_dir().join("cases.json")).unwrap()).unwrap();
    assert!(cases.len() >= 40, "{} cases", cases.len());
    let inputs = inputs();
    let mut failures = Vec::new();
    // `errors` streams long recordings from spill files: each of its cases is tried loaded
    // whole (the default on small files) and streamed.
    let streamed = cases
        .iter()
        .filter(|c| c.args.first().is_some_and(|a| a == "errors"))
        .map(|c| (c, &["--stream", "always"][..]));
    let tries = cases.iter().map(|c| (c, &[][..])).chain(streamed);
    for (case, extra) in tries {
        let out = tempfile::tempdir().unwrap();
        let mut args: Vec<String> = case
            .args
            .iter()
            .map(|a| {
                a.replace("{corpus}", corpus_dir().to_str().unwrap())
                    .replace("{car}", inputs.car.to_str().unwrap())
                    .replace("{static}", inputs.still.to_str().unwrap())
                    .replace("{work}", inputs.work.to_str().unwrap())
                    .replace("{out}", out.path().to_str().unwrap())
            })
            .collect();
        args.extend(extra.iter().map(|a| a.to_string()));
        let o = Command::new(DYNACAL).args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        let mut wrong = Vec::new();
        if o.status.code() != Some(1) {
            wrong.push(format!("exit status {:?}, not 1", o.status.code()));
        }
        if stderr.contains("panicked") || !stderr.contains("dynacal: error: ") {
            wrong.push("no `dynacal: error:` line, or a panic".to_string());
        }
        for fragment in &case.expect {
            if !stderr.contains(fragment.as_str()) {
                wrong.push(format!("the message does not say `{fragment}`"));
            }
        }
        let left = files_under(out.path());
        if !left.is_empty() {
            wrong.push(format!("left output behind: {left:?}"));
        }
        if !wrong.is_empty() {
            failures.push(format!(
                "{}{} ({}): {}\n  stderr: {}",
                case.name,
                if extra.is_empty() { "" } else { " (streamed)" },
                case.why,
                wrong.join("; "),
                stderr.trim()
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
