//! Fixtures shared by the xtask integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The xtask binary under test.
pub fn xtask() -> Command {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
}

/// A CMU sample archive from `../shared/cmu` (the test calls
/// `integration_tests::require_samples!()` first).
pub fn shared(name: &str) -> PathBuf {
    integration_tests::sample(name)
}

/// Copy `entry` of a shared sample archive into `dir`, keeping its file name.
pub fn extract(archive: &str, entry: &str, dir: &Path) -> PathBuf {
    let source = mocap_ingest::source::Source::open(&shared(archive)).unwrap();
    let bytes = source.reader().unwrap().read(entry).unwrap();
    std::fs::create_dir_all(dir).unwrap();
    let out = dir.join(Path::new(entry).file_name().unwrap());
    std::fs::write(&out, bytes).unwrap();
    out
}

/// Six short real takes (02_01 … 02_06, BVH) copied into `tmp/src`.
pub fn six_takes(tmp: &Path) -> PathBuf {
    let source = mocap_ingest::source::Source::open(&shared("cmu-bvh-sample.zip")).unwrap();
    let mut r = source.reader().unwrap();
    let src = tmp.join("src");
    std::fs::create_dir_all(&src).unwrap();
    for t in ["02_01", "02_02", "02_03", "02_04", "02_05", "02_06"] {
        let bytes = r
            .read(&format!("cmu-bvh-motionbuilder/02/{t}.bvh"))
            .unwrap();
        std::fs::write(src.join(format!("{t}.bvh")), bytes).unwrap();
    }
    src
}

/// `cargo xtask dataset` with short windows (the takes are ~90 frames) and a
/// train/val split of one half each.
pub fn small_dataset(src: &Path, out: &Path) {
    let ok = xtask()
        .args([
            "dataset",
            "--quiet",
            "--window",
            "32",
            "--stride",
            "16",
            "--split",
            "0.5,0.5,0",
            "--source",
        ])
        .arg(src)
        .arg("--out")
        .arg(out)
        .status()
        .unwrap();
    assert!(ok.success());
}
