//! Links the firmware with cortex-m-rt's and defmt's linker scripts, against the
//! STM32F405 memory map in the workspace root's `memory.x`.
//!
//! Done here rather than as target rustflags in `.cargo/config.toml` so the arguments
//! reach this binary only (not host builds, not other crates) and a build from any
//! directory finds `memory.x`.

use std::path::PathBuf;

fn main() {
    let target = std::env::var("TARGET").unwrap_or_default();
    let workspace_root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap())
        .parent()
        .expect("firmware/ sits inside the workspace")
        .to_path_buf();
    println!("cargo:rerun-if-changed=build.rs");
    println!(
        "cargo:rerun-if-changed={}",
        workspace_root.join("memory.x").display()
    );
    if target.starts_with("thumb") {
        println!("cargo:rustc-link-search={}", workspace_root.display());
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
