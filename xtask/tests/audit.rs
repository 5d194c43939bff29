//! `cargo xtask audit` passes on a fresh dataset (rebuild included) and fails,
//! naming the problem, on each kind of tampering.

mod common;

use common::{extract, six_takes, small_dataset, xtask};
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
        "flagged.txt",
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

#[test]
fn flagged_takes_rebuild_out_with_exclude() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let src = six_takes(tmp.path());
    // 07_12 jumps (the audit flags it: the root moves ~60 m/s in one frame).
    extract(
        "cmu-bvh-sample.zip",
        "cmu-bvh-motionbuilder/07/07_12.bvh",
        &src,
    );
    // 01_14 starts on a climbing frame: its floor, taken from its first
    // frame, is far above where it later stands.
    for f in ["01.asf", "01_14.amc"] {
        let entry = format!("all_asfamc/subjects/01/{f}");
        extract("cmu-asfamc-sample.zip", &entry, &src);
    }
    let ds = tmp.path().join("ds");
    small_dataset(&src, &ds);
    let report = tmp.path().join("report");
    let o = audit(&ds, None, &report);
    assert!(o.status.success(), "{}", text(&o));
    let flagged = std::fs::read_to_string(report.join("flagged.txt")).unwrap();
    let ids: Vec<&str> = flagged
        .lines()
        .map(|l| l.split('#').next().unwrap().trim())
        .filter(|l| !l.is_empty())
        .collect();
    assert_eq!(ids, ["01_14", "07_12"], "{flagged}");
    assert!(
        flagged.contains("07_12  # ") && flagged.contains("root jumps: 66"),
        "{flagged}"
    );
    assert!(
        flagged.contains("stands below its first frame's floor: lowest toe 25."),
        "{flagged}"
    );

    // Rebuilt without the flagged take; the manifest says so, and the audit's
    // rebuild from --source (which reads the manifest's exclude list) matches.
    let clean = tmp.path().join("clean");
    let ok = xtask()
        .args(["dataset", "--quiet", "--window", "32", "--stride", "16"])
        .args(["--split", "0.5,0.5,0", "--exclude"])
        .arg(report.join("flagged.txt"))
        .arg("--source")
        .arg(&src)
        .arg("--out")
        .arg(&clean)
        .status()
        .unwrap();
    assert!(ok.success());
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(clean.join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(
        m["options"]["exclude"],
        serde_json::json!(["01_14", "07_12"])
    );
    assert_eq!(m["counts"]["takes"], 6);
    assert_eq!(m["counts"]["excluded"], 2);
    let o = audit(&clean, Some(&src), &tmp.path().join("report2"));
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(
        t.contains("rebuild from --source is byte-identical | ok"),
        "{t}"
    );
    assert!(t.contains("0 flagged"), "{t}");
}

#[test]
fn dataset_categories_file_and_the_categories_command() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let src = six_takes(tmp.path());
    std::fs::rename(src.join("02_06.bvh"), src.join("mine.bvh")).unwrap();
    let cats = tmp.path().join("cats.csv");
    let dataset = |out: &Path| {
        xtask()
            .args(["dataset", "--quiet", "--window", "32", "--stride", "16"])
            .args(["--split", "0.5,0.5,0", "--categories"])
            .arg(&cats)
            .arg("--source")
            .arg(&src)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    // A bad line stops the build, naming the file, the line and the categories.
    std::fs::write(&cats, "take,category\nmine,walk\nmine2,skating\n").unwrap();
    let o = dataset(&tmp.path().join("bad"));
    let t = text(&o);
    assert!(!o.status.success());
    assert!(
        t.contains("cats.csv: line 3")
            && t.contains("\"skating\"")
            && t.contains("walk, run, jump, dance, sport, play, floor, gesture, other"),
        "{t}"
    );
    assert!(!tmp.path().join("bad").exists());
    // A good file: the take gets its category, the audit (with the rebuild,
    // which reads the categories from the manifest) passes and has the table.
    std::fs::write(&cats, "# mine\nmine,dance\n").unwrap();
    let ds = tmp.path().join("ds");
    assert!(dataset(&ds).status.success(), "{}", text(&dataset(&ds)));
    let report = tmp.path().join("report");
    let o = audit(&ds, Some(&src), &report);
    assert!(o.status.success(), "{}", text(&o));
    let md = std::fs::read_to_string(report.join("audit.md")).unwrap();
    assert!(
        md.contains("## Categories") && md.contains("| dance | 1 |"),
        "{md}"
    );
    // The categories command writes the table from a trials.csv.
    let trials = tmp.path().join("trials.csv");
    std::fs::write(
        &trials,
        "take,subject,trial,fps,description\n02_01,2,1,120,walk\n01_01,1,1,120,\"playground - forward jumps, turn around\"\n",
    )
    .unwrap();
    let out = tmp.path().join("cats-out.csv");
    let o = xtask()
        .args(["categories", "--trials"])
        .arg(&trials)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("| `play` | 1 |"), "{}", text(&o));
    assert_eq!(
        std::fs::read_to_string(&out).unwrap(),
        "take,category,description\n01_01,play,\"playground - forward jumps, turn around\"\n02_01,walk,walk\n"
    );
}
