//! Builds the replay board's firmware (`board-replay`, thumbv7em-none-eabihf, the workspace's
//! `firmware` profile) and hands its ELF to the crate through `OUT_DIR`
//! (`replay-firmware.elf`, embedded by `dynacal::replay::embedded_replay_firmware`). An
//! installed or copied `dynacal` then runs the firmware of the tree it was built from,
//! without cargo or that tree at run time.
//!
//! The build goes to the workspace's `target/firmware`, where the tests and `dynacal board
//! --target-dir` build the same image, so it is built once. When it cannot be built (no
//! thumbv7em-none-eabihf target: run `scripts/setup`), or `DYNACAL_EMBED_FIRMWARE=0`, the
//! crate is built without it, cargo warns, and the binary builds the firmware at run time
//! as before.

use std::path::{Path, PathBuf};
use std::process::Command;

/// What the outer cargo sets for its own compilations and the firmware's must not inherit:
/// wrappers (clippy-driver under `cargo clippy`) and flags meant for the host.
const OUTER_ENV: [&str; 6] = [
    "RUSTC_WRAPPER",
    "RUSTC_WORKSPACE_WRAPPER",
    "CLIPPY_ARGS",
    "CARGO_ENCODED_RUSTFLAGS",
    "RUSTFLAGS",
    "CARGO_TARGET_DIR",
];

fn main() {
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"));
    let root = manifest
        .parent()
        .expect("host/ lies in the workspace")
        .to_path_buf();
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("set by cargo"))
        .join("replay-firmware.elf");
    for input in [
        "firmware/src",
        "firmware/build.rs",
        "firmware/Cargo.toml",
        "shared/src",
        "shared/Cargo.toml",
        "memory.x",
        "Cargo.toml",
        "Cargo.lock",
    ] {
        println!("cargo:rerun-if-changed={}", root.join(input).display());
    }
    println!("cargo:rerun-if-env-changed=DYNACAL_EMBED_FIRMWARE");
    let image = if std::env::var_os("DYNACAL_EMBED_FIRMWARE").is_some_and(|v| v == "0") {
        Vec::new()
    } else {
        build_firmware(&root).unwrap_or_else(|why| {
            println!("cargo:warning=dynacal is built without its replay firmware ({why}); it will build it with cargo when it needs it");
            Vec::new()
        })
    };
    std::fs::write(&out, image).expect("write OUT_DIR/replay-firmware.elf");
}

fn build_firmware(root: &Path) -> Result<Vec<u8>, String> {
    if !root.join("firmware/Cargo.toml").exists() {
        return Err(format!("{}: no firmware crate", root.display()));
    }
    let target_dir = root.join("target/firmware");
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut command = Command::new(cargo);
    command.current_dir(root).args([
        "build",
        "-p",
        "dynacal-firmware",
        "--bin",
        "dynacal-firmware",
        "--profile",
        "firmware",
        "--target",
        "thumbv7em-none-eabihf",
        "--features",
        "board-replay",
        "--target-dir",
    ]);
    command.arg(&target_dir);
    for name in OUTER_ENV {
        command.env_remove(name);
    }
    let output = command
        .output()
        .map_err(|e| format!("cannot run cargo: {e}"))?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let last = stderr.lines().rfind(|l| !l.trim().is_empty()).unwrap_or("");
        return Err(format!("cargo build of the firmware failed: {last}"));
    }
    let elf = target_dir.join("thumbv7em-none-eabihf/firmware/dynacal-firmware");
    std::fs::read(&elf).map_err(|e| format!("{}: {e}", elf.display()))
}
