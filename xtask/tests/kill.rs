//! A `dataset` run killed with SIGKILL midway leaves the previous dataset
//! complete and intact; the next run cleans up and succeeds.

mod common;

use common::{shared, xtask};
use sha2::{Digest, Sha256};
use std::path::Path;
use std::time::Duration;

/// Every output listed in the manifest exists with the listed SHA-256.
fn assert_complete(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("manifest.json")).expect("manifest.json");
    let m: serde_json::Value = serde_json::from_str(&text).expect("manifest is JSON");
    let outputs = m["outputs"].as_array().expect("outputs");
    assert_eq!(outputs.len(), 5);
    for o in outputs {
        let path = dir.join(o["path"].as_str().unwrap());
        let bytes = std::fs::read(&path).unwrap();
        let sha: String = Sha256::digest(&bytes)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        assert_eq!(sha, o["sha256"].as_str().unwrap(), "{}", path.display());
    }
    m
}

#[test]
fn sigkill_midway_keeps_the_previous_dataset() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let bvh = shared("cmu-bvh-sample.zip");
    let amc = shared("cmu-asfamc-sample.zip");
    let ok = xtask()
        .args(["dataset", "--quiet", "--source"])
        .arg(&bvh)
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(ok.success());
    let before = assert_complete(&out);

    // A second, longer build (ASF/AMC, one thread: ~2.5 s) killed after 0.5 s.
    let mut child = xtask()
        .args(["dataset", "--quiet", "--threads", "1", "--source"])
        .arg(&amc)
        .arg("--out")
        .arg(&out)
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    child.kill().unwrap(); // SIGKILL on Unix
    let status = child.wait().unwrap();
    assert!(!status.success(), "the build finished before it was killed");

    let after = assert_complete(&out);
    assert_eq!(before, after, "the previous dataset changed");
    let leftovers: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".ds.tmp-"))
        .collect();
    assert_eq!(leftovers.len(), 1, "the killed run's staging directory");

    // The next run removes the stale staging directory and replaces the dataset.
    let ok = xtask()
        .args(["dataset", "--quiet", "--source"])
        .arg(&amc)
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(ok.success());
    let new = assert_complete(&out);
    assert_ne!(new["sources"], before["sources"]);
    let names: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().collect();
    assert_eq!(names.len(), 1, "only the dataset remains");
}
