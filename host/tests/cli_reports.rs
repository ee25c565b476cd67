//! The HTML reports as a user meets them, chained from `dynacal simulate` (three MEMS units
//! beside the reference on a 60 s drive): `wv`, `fit`, `redundancy` and `diagnose` each
//! with `--report DIR`, every report.html rendered by a real headless browser with all its
//! figures drawn and nothing on its console, and each command ending with one line saying
//! what it wrote where.

mod browser;

use std::path::{Path, PathBuf};
use std::process::Command;

fn dynacal(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "dynacal {args:?}:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The drive's folder.
fn simulate(dir: &Path) -> PathBuf {
    let model =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/three-mems-1khz.json");
    let out = dir.join("sim");
    dynacal(&[
        "simulate",
        "--model",
        path(&model),
        "--seconds",
        "60",
        "--seed",
        "5",
        "--out",
        path(&out),
    ]);
    out
}

#[test]
fn each_commands_report_renders_in_a_browser_with_every_figure() {
    let dir = tempfile::tempdir().unwrap();
    let sim = simulate(dir.path());
    let unit = |k: usize| sim.join(format!("mtx{k}.csv"));
    let report = |name: &str| dir.path().join(name);

    let wv = dynacal(&[
        "wv",
        path(&unit(1)),
        "--json",
        path(&report("wv.json")),
        "--report",
        path(&report("wv")),
    ]);
    let fit = dynacal(&[
        "fit",
        path(&unit(1)),
        "--model",
        "auto",
        "--json",
        path(&report("fit.json")),
        "--report",
        path(&report("fit")),
    ]);
    let redundancy = dynacal(&[
        "redundancy",
        path(&unit(1)),
        path(&unit(2)),
        path(&unit(3)),
        "--json",
        path(&report("redundancy.json")),
        "--report",
        path(&report("redundancy")),
    ]);
    let diagnose = dynacal(&[
        "diagnose",
        "--sensor",
        path(&unit(1)),
        "--reference",
        path(&sim.join("reference.csv")),
        "--json",
        path(&report("diagnose.json")),
        "--report",
        path(&report("diagnose")),
    ]);
    // The last line of each says what it wrote where.
    for (out, name) in [
        (&wv, "wv"),
        (&fit, "fit"),
        (&redundancy, "redundancy"),
        (&diagnose, "diagnose"),
    ] {
        let last = out.lines().last().unwrap();
        assert!(
            last.starts_with("wrote ") && last.contains(&format!("{name}/report.html")),
            "{last}"
        );
    }
    // A fitted channel reads as a person quotes it, in the summary and the tables.
    let fit_html = std::fs::read_to_string(report("fit").join("report.html")).unwrap();
    assert!(
        fit_html.contains("gx: ") && fit_html.contains("J-test p"),
        "fit summary"
    );
    let wv_html = std::fs::read_to_string(report("wv").join("report.html")).unwrap();
    assert!(
        wv_html.contains("white-noise density at most"),
        "wv summary"
    );

    let Some(chromium) = browser::chromium_or_skip() else {
        return;
    };
    // wv and fit: one figure of six panels each; redundancy: own WV of both sensors and the
    // live levels; diagnose: at least a wavelet-variance figure and the gain.
    for (name, figures) in [("wv", 1), ("fit", 1), ("redundancy", 3), ("diagnose", 2)] {
        let r = browser::assert_renders(&chromium, &report(name).join("report.html"), figures);
        eprintln!("{name}: {} figures, ink {:?}", r.figures, r.figure_ink);
    }
}
