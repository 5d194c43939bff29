//! Categories: the shipped table is what the rules give for CMU's
//! `trials.csv`, `takes.parquet` carries each take's category and
//! description (a user's `--categories` table for takes that are not CMU
//! trials), the build stays deterministic, and the audit counts windows per
//! category and split.

use integration_tests::{bvh_zip, dataset_contents, read_entry, sample, DATASET_FILES};
use mocap_ingest::category::{
    categories_csv, read_user_categories, Category, CategoryTable, CMU_CATEGORIES,
};
use mocap_ingest::dataset::{build_dataset, DatasetOptions, NoProgress};
use mocap_ingest::source::Source;
use polars::prelude::*;
use std::path::Path;

#[test]
fn the_shipped_table_is_what_the_rules_give_for_trials_csv() {
    integration_tests::require_samples!();
    let trials = std::fs::read_to_string(sample("trials.csv")).unwrap();
    let want = categories_csv(&trials).unwrap();
    assert!(
        want == CMU_CATEGORIES,
        "data/cmu-categories.csv is stale: run `cargo xtask categories --trials ../shared/cmu/trials.csv`"
    );
    let t = CategoryTable::cmu();
    assert_eq!(t.len(), 2435);
    assert_eq!(t.get("02_01"), (Category::Walk, Some("walk")));
    assert_eq!(t.get("02_03"), (Category::Run, Some("run/jog")));
    assert_eq!(t.get("02_05"), (Category::Sport, Some("punch/strike")));
    assert_eq!(
        t.get("01_01"),
        (
            Category::Play,
            Some("playground - forward jumps, turn around")
        )
    );
    assert_eq!(
        t.get("24_01").1,
        Some("nursery rhyme - \"I'm a little teapot...\"")
    );
}

#[test]
fn a_categories_file_with_a_bad_line_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let f = tmp.path().join("cats.csv");
    std::fs::write(&f, "take,category\nmine/a,dance\nmine/b,skating\n").unwrap();
    let e = read_user_categories(&f).unwrap_err();
    assert!(
        e.contains(&f.display().to_string())
            && e.contains("line 3")
            && e.contains("\"skating\"")
            && e.contains("walk, run, jump, dance, sport, play, floor, gesture, other"),
        "{e}"
    );
    std::fs::write(&f, "# mine\nmine/a, dance\nmine/b,floor # sits\n").unwrap();
    let m = read_user_categories(&f).unwrap();
    assert_eq!(m.len(), 2);
    assert_eq!(m["mine/b"], Category::Floor);
    assert!(read_user_categories(&tmp.path().join("absent.csv")).is_err());
}

fn build(src: &Path, out: &Path, opts: &DatasetOptions) {
    let s = Source::open(src).unwrap();
    let labels = vec![src.display().to_string()];
    build_dataset(&[s], &labels, out, opts, &NoProgress).unwrap_or_else(|e| panic!("{e}"));
}

fn strings(df: &DataFrame, c: &str) -> Vec<Option<String>> {
    let col = df.column(c).unwrap().str().unwrap().clone();
    (0..df.height())
        .map(|i| col.get(i).map(String::from))
        .collect()
}

#[test]
fn takes_parquet_has_each_takes_category_and_description() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let coll = tmp.path().join("coll");
    std::fs::create_dir_all(coll.join("mine")).unwrap();
    for t in ["02_01", "02_03", "02_05"] {
        let bytes = read_entry(&bvh_zip(), &format!("cmu-bvh-motionbuilder/02/{t}.bvh"));
        std::fs::write(coll.join(format!("{t}.bvh")), &bytes).unwrap();
    }
    // Two takes that are not CMU trials: one in the user's table, one not.
    let b = read_entry(&bvh_zip(), "cmu-bvh-motionbuilder/02/02_04.bvh");
    std::fs::write(coll.join("mine/hops.bvh"), &b).unwrap();
    let b = read_entry(&bvh_zip(), "cmu-bvh-motionbuilder/02/02_02.bvh");
    std::fs::write(coll.join("mine/stroll.bvh"), &b).unwrap();
    let cats = tmp.path().join("cats.csv");
    std::fs::write(&cats, "take,category\nmine/hops,jump\n").unwrap();
    let opts = DatasetOptions {
        categories: read_user_categories(&cats).unwrap(),
        fractions: [1.0, 0.0, 0.0],
        window: 32,
        stride: 16,
        ..Default::default()
    };
    let out = tmp.path().join("ds");
    build(&coll, &out, &opts);
    let df = LazyFrame::scan_parquet(
        PlRefPath::new(out.join("takes.parquet").display().to_string()),
        Default::default(),
    )
    .unwrap()
    .collect()
    .unwrap();
    let got: Vec<(Option<String>, Option<String>, Option<String>)> = strings(&df, "take")
        .into_iter()
        .zip(strings(&df, "category"))
        .zip(strings(&df, "description"))
        .map(|((a, b), c)| (a, b, c))
        .collect();
    let row = |t: &str, c: &str, d: Option<&str>| {
        (
            Some(t.to_string()),
            Some(c.to_string()),
            d.map(String::from),
        )
    };
    assert_eq!(
        got,
        vec![
            row("02_01", "walk", Some("walk")),
            row("02_03", "run", Some("run/jog")),
            row("02_05", "sport", Some("punch/strike")),
            row("mine/hops", "jump", None),
            row("mine/stroll", "other", None),
        ]
    );
    assert_eq!(df.column("description").unwrap().null_count(), 2);
    // The manifest records the user's table.
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["format_version"], 4);
    assert_eq!(
        m["options"]["categories"],
        serde_json::json!({"mine/hops": "jump"})
    );

    // Deterministic: a second build gives the same bytes.
    let again = tmp.path().join("again");
    build(&coll, &again, &opts);
    let (a, b) = (dataset_contents(&out), dataset_contents(&again));
    for f in DATASET_FILES {
        assert!(a[f] == b[f], "{f} differs between two builds");
    }

    // The audit counts windows per category and split, notes the categories
    // with train windows and no test windows (everything is in train here),
    // and the rebuild from the manifest (categories included) is identical.
    let rebuild = dataset_audit::Rebuild {
        sources: vec![coll.clone()],
        asf: None,
    };
    let r = dataset_audit::audit(&out, &rebuild, Default::default()).unwrap();
    assert!(
        r.ok(),
        "{:#?}",
        r.checks.iter().filter(|c| !c.ok).collect::<Vec<_>>()
    );
    let names: Vec<&str> = r.categories.iter().map(|c| c.category.as_str()).collect();
    assert_eq!(names, Category::ALL.map(Category::name));
    let walk = &r.categories[0];
    assert_eq!((walk.takes, walk.windows[1], walk.windows[2]), (1, 0, 0));
    assert!(walk.windows[0] > 0);
    let windows: u64 = r
        .categories
        .iter()
        .map(|c| c.windows.iter().sum::<u64>())
        .sum();
    assert_eq!(
        windows,
        m["counts"]["windows_per_split"]["train"].as_u64().unwrap()
    );
    let with_train = r.categories.iter().filter(|c| c.windows[0] > 0).count();
    assert_eq!(r.notes.len(), with_train);
    assert!(
        r.notes.iter().any(|n| n.contains("category walk has")),
        "{:?}",
        r.notes
    );
    let md = dataset_audit::markdown::markdown(&r, 0.0);
    assert!(
        md.contains("## Categories") && md.contains("| walk | 1 |"),
        "{md}"
    );
}
