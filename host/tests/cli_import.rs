//! `dynacal import` end to end: the binary on the real PSINS FOG/MEMS folder and on an
//! unknown file (skips the real-data part when the data folder is absent).

use std::process::Command;

use dynacal::interchange::ImuRecording;

fn dynacal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynacal"))
}

#[test]
fn import_psins_folder_writes_mems_and_fog_files_and_reports_them() {
    let input = dynacal::data_dir().join("psins-fog-mems");
    if !input.exists() {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", input.display());
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let result = dynacal()
        .arg("import")
        .arg(&input)
        .arg("--out")
        .arg(out.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(
        result.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&result.stderr)
    );
    assert!(
        stdout
            .contains("psins-fog.csv.gz: 1000 samples, 99.900 s, [attitude velocity_ned position]"),
        "{stdout}"
    );
    assert!(
        stdout.contains("psins-mems.csv.gz: 10001 samples, 100.000 s, [gx gy gz ax ay az]"),
        "{stdout}"
    );
    // The written file reads back to exactly what the library produced, and states the rate
    // estimated once from its time column.
    let written = ImuRecording::read(&out.path().join("psins-mems.csv.gz")).unwrap();
    let direct =
        dynacal::import::psins_fog_mems::read_mems(&input.join("mems_increments.csv.gz")).unwrap();
    assert_eq!(
        written,
        ImuRecording {
            sample_rate_hz: Some(100.0),
            ..direct
        }
    );
    let mut names: Vec<String> = std::fs::read_dir(out.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["psins-fog.csv.gz", "psins-mems.csv.gz"]);
}

#[test]
fn unknown_dataset_fails_with_nonzero_exit_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mystery.csv");
    std::fs::write(&path, "time,value\n0,1\n").unwrap();
    let out = dir.path().join("out");
    let result = dynacal()
        .arg("import")
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!result.status.success());
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        stderr.contains("mystery.csv") && stderr.contains("not a dataset"),
        "{stderr}"
    );
    assert!(!out.exists(), "no output folder for a failed detection");
}
