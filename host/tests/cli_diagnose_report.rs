//! End-to-end `dynacal diagnose --report DIR`: on a short simulated MEMS/reference pair the
//! report directory holds report.md, every plot it links (SVG documents with the expected
//! series) and the extended model; a directory that cannot be created fails naming it and
//! writes nothing.

use std::path::Path;
use std::process::{Command, Output};

/// One MEMS IMU at 100 Hz, white noise and Gauss-Markov on every channel, a gyro scale factor.
const MODEL: &str = r#"{"imus": [{"name": "mems", "rate_hz": 100,
  "gyro": {"stochastic": {"model": "WN+GM", "unit": "rad/s", "sample_rate_hz": 100,
     "processes": [{"kind": "white_noise", "sigma2": 1.6e-5},
                   {"kind": "gauss_markov", "beta_per_s": 0.05, "sigma2": 4e-6}]},
     "bias": 0.002, "scale_factor": 0.003},
  "accel": {"stochastic": {"model": "WN+GM", "unit": "m/s^2", "sample_rate_hz": 100,
     "processes": [{"kind": "white_noise", "sigma2": 4e-4},
                   {"kind": "gauss_markov", "beta_per_s": 0.02, "sigma2": 1e-4}]},
     "bias": 0.03}}]}"#;

fn dynacal(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
        .args(args)
        .output()
        .unwrap()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Simulates 60 s of the car run into `dir/sim`; returns (sensor, reference).
fn simulate(dir: &Path) -> (String, String) {
    let model = dir.join("model.json");
    std::fs::write(&model, MODEL).unwrap();
    let sim = dir.join("sim");
    let o = dynacal(&[
        "simulate",
        "--model",
        path(&model),
        "--seconds",
        "60",
        "--seed",
        "3",
        "--out",
        path(&sim),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (
        path(&sim.join("mems.csv")).to_string(),
        path(&sim.join("reference.csv")).to_string(),
    )
}

/// The targets of the Markdown image links `![...](target)`.
fn image_links(md: &str) -> Vec<String> {
    md.split("![")
        .skip(1)
        .filter_map(|rest| {
            let start = rest.find("](")? + 2;
            let end = start + rest[start..].find(')')?;
            Some(rest[start..end].to_string())
        })
        .collect()
}

/// Number of points of each polyline of the given stroke colour.
fn polylines(doc: &roxmltree::Document, stroke: &str) -> Vec<usize> {
    doc.descendants()
        .filter(|n| n.has_tag_name("polyline") && n.attribute("stroke") == Some(stroke))
        .map(|n| n.attribute("points").unwrap().split_whitespace().count())
        .collect()
}

fn count(doc: &roxmltree::Document, tag: &str, fill: &str) -> usize {
    doc.descendants()
        .filter(|n| n.has_tag_name(tag) && n.attribute("fill") == Some(fill))
        .count()
}

#[test]
fn report_directory_holds_the_markdown_and_every_plot_it_links() {
    let tmp = tempfile::tempdir().unwrap();
    let (sensor, reference) = simulate(tmp.path());
    let json = tmp.path().join("diag.json");
    let report = tmp.path().join("out/report");
    let o = dynacal(&[
        "diagnose",
        "--sensor",
        &sensor,
        "--reference",
        &reference,
        "--replicates",
        "5",
        "--json",
        path(&json),
        "--report",
        path(&report),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let diag: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let curves = diag["wv_curves"].as_object().unwrap();
    assert_eq!(curves.len(), 6, "a WV curve per channel");

    let md = std::fs::read_to_string(report.join("report.md")).unwrap();
    // The rule is stated with the run's own count of tests, and every named cause carries a
    // family-wise p-value below alpha (none: a property read without a test).
    let tests = diag["tests"].as_u64().unwrap();
    assert!(tests >= 6 * 20, "{tests} tests counted for six channels");
    assert!(
        md.contains(&format!(
            "times the {tests} tests of the run (Bonferroni), is below alpha = 0.05"
        )),
        "{md}"
    );
    for f in diag["findings"].as_array().unwrap() {
        match f["p_value"].as_f64() {
            Some(p) => assert!(p < 0.05, "{f}"),
            None => assert_eq!(f["cause"], "quantization", "{f}"),
        }
    }
    let links = image_links(&md);
    let mut expected: Vec<String> = curves.keys().map(|c| format!("wv-{c}.svg")).collect();
    expected.push("gain.svg".into());
    for file in &expected {
        assert!(
            links.contains(file),
            "{file} linked in report.md: {links:?}"
        );
    }
    for link in &links {
        let svg = std::fs::read_to_string(report.join(link))
            .unwrap_or_else(|e| panic!("{link} linked but not readable: {e}"));
        let doc = roxmltree::Document::parse(&svg)
            .unwrap_or_else(|e| panic!("{link} is not an XML document: {e}"));
        assert_eq!(doc.root_element().tag_name().name(), "svg", "{link}");
    }

    // Each channel's plot draws the measured WV through all its levels, with a marker on
    // each, and one shaded band per model.
    for (channel, c) in curves {
        let svg = std::fs::read_to_string(report.join(format!("wv-{channel}.svg"))).unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let levels = c["measured"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|v| v.as_f64().is_some_and(|v| v > 0.0))
            .count();
        assert!(levels >= 8, "{channel}: {levels} levels");
        let measured: Vec<usize> = polylines(&doc, "#C81E1E")
            .into_iter()
            .filter(|&n| n > 2)
            .collect();
        assert_eq!(measured, vec![levels], "{channel}");
        assert_eq!(count(&doc, "circle", "#C81E1E"), levels + 1, "{channel}");
        assert_eq!(
            count(&doc, "polygon", "#6E6E6E"),
            1,
            "{channel} baseline band"
        );
        assert_eq!(
            count(&doc, "polygon", "#1E64C8"),
            1,
            "{channel} extended band"
        );
    }

    // The gain plot: four bars per channel (plus the legend's swatches) where misfits are
    // positive numbers.
    let gain = diag["gain"].as_object().unwrap();
    let svg = std::fs::read_to_string(report.join("gain.svg")).unwrap();
    let doc = roxmltree::Document::parse(&svg).unwrap();
    let bars = |fill: &str| count(&doc, "rect", fill) - 1;
    let positive = |key: &str| {
        gain.values()
            .filter(|g| g[key].as_f64().is_some_and(|v| v > 0.0))
            .count()
    };
    assert_eq!(bars("#6E6E6E"), positive("baseline"));
    assert_eq!(bars("#1E64C8"), positive("extended"));
    assert_eq!(bars("#B9B9B9"), positive("held_out_baseline"));
    assert_eq!(bars("#8CB9EB"), positive("held_out_extended"));

    let model: serde_json::Value =
        serde_json::from_slice(&std::fs::read(report.join("extended-model.json")).unwrap())
            .unwrap();
    assert_eq!(model, diag["extended_model"]);
    // Nothing but the report's own files, no temporary file left over.
    let mut names: Vec<String> = std::fs::read_dir(&report)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let mut wanted = links.clone();
    wanted.extend(["extended-model.json", "report.html", "report.md"].map(String::from));
    wanted.sort();
    assert_eq!(names, wanted);
}

#[test]
fn report_directory_that_cannot_be_created_fails_naming_it_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let (sensor, reference) = simulate(tmp.path());
    let blocker = tmp.path().join("a-file");
    std::fs::write(&blocker, "not a directory").unwrap();
    let report = blocker.join("report");
    let json = tmp.path().join("diag.json");
    let o = dynacal(&[
        "diagnose",
        "--sensor",
        &sensor,
        "--reference",
        &reference,
        "--replicates",
        "5",
        "--json",
        path(&json),
        "--report",
        path(&report),
    ]);
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains(path(&report)), "{stderr}");
    assert!(!json.exists(), "no JSON written when the report fails");
    assert_eq!(
        std::fs::read_to_string(&blocker).unwrap(),
        "not a directory"
    );
}

#[test]
fn alpha_outside_zero_to_one_is_refused_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("diag.json");
    let o = dynacal(&[
        "diagnose",
        "--sensor",
        "no-such-sensor.csv",
        "--alpha",
        "1.5",
        "--json",
        path(&json),
    ]);
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("--alpha must lie in (0, 1), got 1.5"),
        "{stderr}"
    );
    assert!(!json.exists());
}
