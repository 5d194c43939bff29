//! `cargo xtask audit` passes on a fresh dataset (rebuild included) and fails,
//! naming the problem, on each kind of tampering.

mod common;

use common::{six_takes, small_dataset, xtask};
use polars::prelude::{NamedFrom, SerReader};
use std::path::Path;
use std::process::Output;

fn audit(data: &Path, src: Option<&Path>, report: &Path) -> Output {
    let mut c = xtask();
    c.args(["audit", "--data"])
        .arg(data)
        .arg("--report")
        .arg(report);
    if let Some(s) = src {
        c.arg("--source").arg(s);
    }
    c.output().unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn fresh_dataset_passes_and_tampering_fails_by_name() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let src = six_takes(tmp.path());
    let ds = tmp.path().join("ds");
    small_dataset(&src, &ds);
    let report = tmp.path().join("report");

    let o = audit(&ds, Some(&src), &report);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(
        t.contains("**PASS**") && t.contains("rebuild from --source is byte-identical | ok"),
        "{t}"
    );
    for f in [
        "audit.md",
        "audit.json",
        "root_speed.png",
        "take_duration.png",
        "bone_length_variation.png",
        "foot_height.png",
    ] {
        assert!(report.join(f).is_file(), "{f}");
    }

    // One value changed in a Parquet file (rewritten with polars: still valid Parquet).
    let bad = tmp.path().join("bad1");
    small_dataset(&src, &bad);
    let p = bad.join("windows.parquet");
    let mut df = polars::prelude::ParquetReader::new(std::fs::File::open(&p).unwrap())
        .finish()
        .unwrap();
    let starts = df.column("start").unwrap().u32().unwrap().clone();
    let changed: Vec<u32> = starts
        .iter()
        .enumerate()
        .map(|(i, v)| v.unwrap() + u32::from(i == 0))
        .collect();
    df.replace(
        "start",
        polars::prelude::Column::from(polars::prelude::Series::new("start".into(), changed)),
    )
    .unwrap();
    polars::prelude::ParquetWriter::new(std::fs::File::create(&p).unwrap())
        .finish(&mut df)
        .unwrap();
    let o = audit(&bad, None, &report);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(
        t.contains("| windows.parquet hash | **FAIL** | sha256"),
        "{t}"
    );

    // A file removed.
    let bad = tmp.path().join("bad2");
    small_dataset(&src, &bad);
    std::fs::remove_file(bad.join("takes.parquet")).unwrap();
    let o = audit(&bad, None, &report);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("| takes.parquet present | **FAIL**"),
        "{}",
        text(&o)
    );

    // A hash edited in the manifest.
    let bad = tmp.path().join("bad3");
    small_dataset(&src, &bad);
    let m = std::fs::read_to_string(bad.join("manifest.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&m).unwrap();
    let h = v["outputs"][0]["sha256"].as_str().unwrap().to_string();
    let f = v["outputs"][0]["path"].as_str().unwrap().to_string();
    std::fs::write(bad.join("manifest.json"), m.replace(&h, &"0".repeat(64))).unwrap();
    let o = audit(&bad, None, &report);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(
        t.contains(&format!(
            "| {f} hash | **FAIL** | sha256 {h} but manifest.json says {}",
            "0".repeat(64)
        )),
        "{t}"
    );
}
