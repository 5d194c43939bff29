//! What a user sees when a command fails: the error and its causes, with no
//! stack trace even where `RUST_BACKTRACE=1` is set (as on many
//! development machines); a panic would still get one.

mod common;

use common::xtask;

#[test]
fn a_missing_dataset_is_one_clear_error_without_a_stack_trace() {
    let tmp = tempfile::tempdir().unwrap();
    let o = xtask()
        .env("RUST_BACKTRACE", "1")
        .env_remove("RUST_LIB_BACKTRACE")
        .args(["train", "--epochs", "1", "--data"])
        .arg(tmp.path().join("none"))
        .arg("--out")
        .arg(tmp.path().join("run"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("loading the dataset") && err.contains("build it with `cargo xtask dataset`"),
        "{err}"
    );
    assert!(err.contains("stats.json"), "{err}");
    assert!(!err.contains("Stack backtrace"), "{err}");
}
