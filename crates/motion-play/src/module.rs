//! The player compiled to WebAssembly (`wasm32-unknown-unknown`), for the
//! page: `cargo build -p motion-play` for that target, with rustup's target
//! where it is installed, else with Debian's `rustc-web` and its standard
//! library's source (`rust-web-src`), built with the crate.

use crate::PlayError;
use std::path::{Path, PathBuf};
use std::process::Command;

const TARGET: &str = "wasm32-unknown-unknown";

/// Debian's `rustc-web` (1.96, built from source: its standard library is
/// built with the crate) and where its source is.
const DEBIAN_RUSTC: &str = "/usr/bin/rustc";
const DEBIAN_SRC: &str = "/usr/lib/rustlib/src/rust/library";

/// What to install where no toolchain for the target is found.
const INSTALL: &str = "no Rust toolchain for wasm32-unknown-unknown: `rustup target add wasm32-unknown-unknown`, or on Debian 12 `apt install rustc-web cargo-web rust-web-src`";

fn run(cmd: &mut Command) -> Result<String, PlayError> {
    let out = cmd
        .output()
        .map_err(|e| PlayError::Build(format!("{cmd:?}: {e}")))?;
    match out.status.success() {
        true => Ok(String::from_utf8_lossy(&out.stdout).trim().to_string()),
        false => Err(PlayError::Build(format!(
            "{cmd:?} failed: {}",
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .filter(|l| l.starts_with("error") || l.contains("-->"))
                .take(12)
                .collect::<Vec<_>>()
                .join("\n")
        ))),
    }
}

/// Whether `rustc` (the one on `PATH`) has the target's standard library.
fn rustup_has_target() -> bool {
    run(Command::new("rustc").args(["--print", "target-libdir", "--target", TARGET]))
        .is_ok_and(|d| Path::new(&d).is_dir())
}

/// The player's module, built from the workspace at `root` into
/// `root/target/wasm` (release, no debug information).
pub fn build(root: &Path) -> Result<Vec<u8>, PlayError> {
    let target_dir = root.join("target").join("wasm");
    let mut cmd = Command::new("cargo");
    if !rustup_has_target() {
        if !(Path::new(DEBIAN_RUSTC).is_file() && Path::new(DEBIAN_SRC).is_dir()) {
            return Err(PlayError::Build(INSTALL.into()));
        }
        // rustup's linker for the target (rust-lld, shipped with every
        // rustup toolchain), else `wasm-ld` on PATH.
        let sysroot = run(Command::new("rustc").args(["--print", "sysroot"]))?;
        let lld = PathBuf::from(sysroot).join("lib/rustlib/x86_64-unknown-linux-gnu/bin/rust-lld");
        let linker = match lld.is_file() {
            true => lld.display().to_string(),
            false => "wasm-ld".into(),
        };
        cmd = Command::new("/usr/bin/cargo");
        cmd.env("RUSTC", DEBIAN_RUSTC)
            .env("RUSTC_BOOTSTRAP", "1")
            .env("CARGO_TARGET_WASM32_UNKNOWN_UNKNOWN_LINKER", linker)
            .args(["-Zbuild-std=std,panic_abort"]);
    }
    cmd.current_dir(root)
        .args([
            "build",
            "--release",
            "--locked",
            "-p",
            "motion-play",
            "--target",
            TARGET,
        ])
        .arg("--target-dir")
        .arg(&target_dir)
        .env("CARGO_PROFILE_RELEASE_DEBUG", "false")
        .env("CARGO_PROFILE_RELEASE_STRIP", "true")
        .env("RUSTFLAGS", "--cfg getrandom_backend=\"wasm_js\"");
    run(&mut cmd)?;
    let wasm = target_dir
        .join(TARGET)
        .join("release")
        .join("motion_play.wasm");
    std::fs::read(&wasm).map_err(|e| PlayError::Build(format!("{}: {e}", wasm.display())))
}
