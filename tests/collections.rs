//! CMU collections laid out as their owners keep them, built from the real
//! shared files: renamed ASFs, `NN.bvh` stems in several folders, a broken
//! AMC copy beside a working BVH copy, the Daz-friendly release, a skeleton
//! given with `--asf`, exclude lists. Every take must arrive with the right
//! id, subject and skeleton.

use integration_tests::{
    asfamc_zip, bvh_zip, dataset_contents, daz_zip, read_entry, short_takes_options, DATASET_FILES,
};
use mocap_ingest::dataset::{build_dataset, BuildSummary, DatasetOptions, NoProgress, Skipped};
use mocap_ingest::source::{FileRef, Format, Source};
use mocap_ingest::{process_take, Options};
use polars::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn amc(entry: &str) -> Vec<u8> {
    read_entry(&asfamc_zip(), &format!("all_asfamc/subjects/{entry}"))
}

fn bvh(entry: &str) -> Vec<u8> {
    read_entry(&bvh_zip(), &format!("cmu-bvh-motionbuilder/{entry}"))
}

/// Write `files` (path → bytes) under `root`.
fn lay_out(root: &Path, files: &[(&str, Vec<u8>)]) -> PathBuf {
    for (name, bytes) in files {
        let p = root.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
    root.to_path_buf()
}

fn build(sources: Vec<Source>, out: &Path, opts: &DatasetOptions) -> BuildSummary {
    let labels: Vec<String> = sources
        .iter()
        .map(|s| s.root().display().to_string())
        .collect();
    build_dataset(&sources, &labels, out, opts, &NoProgress).unwrap_or_else(|e| panic!("{e}"))
}

/// `takes.parquet` as (take → (subject, format, skeleton, file)).
fn takes_table(out: &Path) -> BTreeMap<String, [String; 4]> {
    let df = LazyFrame::scan_parquet(
        PlRefPath::new(out.join("takes.parquet").to_str().unwrap().to_string()),
        Default::default(),
    )
    .unwrap()
    .collect()
    .unwrap();
    let col = |n: &str| -> Vec<String> {
        df.column(n)
            .unwrap()
            .str()
            .unwrap()
            .iter()
            .map(|v| v.unwrap_or_default().to_string())
            .collect()
    };
    let (t, s, f, k, p) = (
        col("take"),
        col("subject"),
        col("format"),
        col("skeleton"),
        col("file"),
    );
    (0..t.len())
        .map(|i| {
            (
                t[i].clone(),
                [s[i].clone(), f[i].clone(), k[i].clone(), p[i].clone()],
            )
        })
        .collect()
}

fn row<'a>(takes: &'a BTreeMap<String, [String; 4]>, id: &str) -> &'a [String; 4] {
    takes
        .get(id)
        .unwrap_or_else(|| panic!("take {id} missing; takes: {:?}", takes.keys()))
}

fn skipped_of<'a>(s: &'a BuildSummary, file_end: &str) -> &'a Skipped {
    s.skipped
        .iter()
        .find(|k| k.file.ends_with(file_end))
        .unwrap_or_else(|| panic!("{file_end} not in skipped: {:?}", s.skipped))
}

#[test]
fn skeletons_not_named_nn_asf_are_found() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let fallback = tmp.path().join("skeletons/49.asf");
    lay_out(tmp.path(), &[("skeletons/49.asf", amc("49/49.asf"))]);
    let src = lay_out(
        &tmp.path().join("course"),
        &[
            // A viewer project: one skeleton under another name.
            ("viewer/mjackson.asf", amc("02/02.asf")),
            ("viewer/02_01.amc", amc("02/02_01.amc")),
            ("viewer/02_02.amc", amc("02/02_02.amc")),
            // Course copies: skeletons named after the motion, two in a folder.
            ("class/16-walk.asf", amc("16/16.asf")),
            ("class/29-run.asf", amc("29/29.asf")),
            ("class/16_15-walk.amc", amc("16/16_15.amc")),
            ("class/29_01-run.amc", amc("29/29_01.amc")),
            // No skeleton anywhere near: the --asf fallback.
            ("loose/49_02.amc", amc("49/49_02.amc")),
        ],
    );
    let source = Source::open(&src)
        .unwrap()
        .with_fallback_asf(Some(fallback.clone()));
    let takes = source.takes().unwrap();
    let asf_of: BTreeMap<&str, (String, &str)> = takes
        .iter()
        .map(|t| {
            let asf = match t.asf.as_ref().expect("an ASF") {
                FileRef::Entry(e) => e.name.clone(),
                FileRef::External(p) => p.display().to_string(),
            };
            (t.take_id.as_str(), (asf, t.asf_search.as_str()))
        })
        .collect();
    assert_eq!(asf_of["02_01"].0, "viewer/mjackson.asf");
    assert_eq!(asf_of["02_02"].1, "the only .asf in its folder");
    assert_eq!(asf_of["16_15"].0, "class/16-walk.asf");
    assert_eq!(asf_of["29_01"].0, "class/29-run.asf");
    assert_eq!(
        asf_of["29_01"].1,
        "the .asf starting with its subject number"
    );
    assert_eq!(asf_of["49_02"], (fallback.display().to_string(), "--asf"));

    let out = tmp.path().join("ds");
    let s = build(vec![source], &out, &short_takes_options());
    assert!(s.skipped.is_empty(), "{:?}", s.skipped);
    let t = takes_table(&out);
    assert_eq!(t.len(), 5);
    for (id, subject) in [
        ("02_01", "02"),
        ("02_02", "02"),
        ("16_15", "16"),
        ("29_01", "29"),
        ("49_02", "49"),
    ] {
        let r = row(&t, id);
        assert_eq!(
            (r[0].as_str(), r[1].as_str(), r[2].as_str()),
            (subject, "amc", "ASF/AMC"),
            "{id}"
        );
    }
    // The features are those of the same take in CMU's own layout.
    let archive = Source::open(&asfamc_zip()).unwrap();
    let original = archive
        .takes()
        .unwrap()
        .into_iter()
        .find(|t| t.take_id == "16_15")
        .unwrap();
    let mut reader = archive.reader().unwrap();
    let want = process_take(&archive, &mut reader, &original, &Options::default()).unwrap();
    let renamed = Source::open(&src).unwrap();
    let take = renamed
        .takes()
        .unwrap()
        .into_iter()
        .find(|t| t.take_id == "16_15")
        .unwrap();
    let got = process_take(
        &renamed,
        &mut renamed.reader().unwrap(),
        &take,
        &Options::default(),
    )
    .unwrap();
    assert_eq!(got.features, want.features);
    // The manifest records the fallback skeleton by name, and hashes it.
    let manifest = std::fs::read_to_string(out.join("manifest.json")).unwrap();
    assert!(manifest.contains("\"asf\": \"49.asf\""), "{manifest}");
}

#[test]
fn a_missing_asf_lists_what_was_tried() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let src = lay_out(
        tmp.path(),
        &[
            ("a/07_05-walk.amc", amc("02/02_01.amc")),
            ("a/01-jump.asf", amc("01/01.asf")),
            ("a/03-run.asf", amc("03/03.asf")),
            ("b/walk.amc", amc("02/02_01.amc")),
        ],
    );
    let source = Source::open(&src).unwrap();
    let takes = source.takes().unwrap();
    assert!(takes.iter().all(|t| t.asf.is_none()));
    let tried: BTreeMap<&str, &str> = takes
        .iter()
        .map(|t| (t.take_id.as_str(), t.asf_search.as_str()))
        .collect();
    let a = format!("{}", src.join("a").display());
    assert_eq!(
        tried["07_05"],
        format!(
            "07.asf beside it (absent); the only .asf in {a} (found 2: 01-jump.asf, 03-run.asf); \
             one .asf starting with 07 (found none); --asf (not given)"
        )
    );
    assert_eq!(
        tried["b/walk"],
        format!(
            "NN.asf beside it (the name has no CMU subject number); the only .asf in {} (found none); \
             --asf (not given)",
            src.join("b").display()
        )
    );
    let e = process_take(
        &source,
        &mut source.reader().unwrap(),
        &takes[0],
        &Options::default(),
    )
    .unwrap_err();
    assert_eq!(e.code(), "missing_asf");
    assert!(
        e.to_string()
            .contains("07_05-walk.amc: missing skeleton file"),
        "{e}"
    );
}

#[test]
fn same_stems_in_several_folders_are_different_takes() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let files = [
        ("salsa/04.bvh", bvh("02/02_01.bvh")),
        ("indian/04.bvh", bvh("02/02_02.bvh")),
        ("martial/04.bvh", bvh("02/02_03.bvh")),
        ("martial/deep/04.bvh", bvh("02/02_04.bvh")),
        ("walk.bvh", bvh("02/02_05.bvh")),
    ];
    let a = lay_out(&tmp.path().join("dances"), &files);
    let out = tmp.path().join("ds");
    let s = build(
        vec![Source::open(&a).unwrap()],
        &out,
        &short_takes_options(),
    );
    assert!(s.skipped.is_empty(), "{:?}", s.skipped);
    let t = takes_table(&out);
    let got: Vec<(&str, &str)> = t
        .iter()
        .map(|(id, r)| (id.as_str(), r[0].as_str()))
        .collect();
    assert_eq!(
        got,
        [
            ("indian/04", "indian"),
            ("martial/04", "martial"),
            ("martial/deep/04", "deep"),
            ("salsa/04", "salsa"),
            ("walk", "dances"),
        ]
    );
    assert!(t
        .values()
        .all(|r| r[1] == "bvh" && r[2] == "Motionbuilder-friendly BVH (2010)"));

    // Another collection with the same paths but other motions: the ids are
    // qualified by collection; a byte-identical copy is one take.
    let b = lay_out(
        &tmp.path().join("more"),
        &[
            ("salsa/04.bvh", bvh("02/02_06.bvh")),
            ("indian/04.bvh", bvh("02/02_02.bvh")),
        ],
    );
    let out2 = tmp.path().join("ds2");
    let s = build(
        vec![Source::open(&a).unwrap(), Source::open(&b).unwrap()],
        &out2,
        &short_takes_options(),
    );
    let t = takes_table(&out2);
    assert!(
        t.contains_key("dances/salsa/04") && t.contains_key("more/salsa/04"),
        "{:?}",
        t.keys()
    );
    assert!(t.contains_key("martial/04") && t.contains_key("walk"));
    assert_eq!(t.len(), 6);
    let dup = skipped_of(&s, "more/indian/04.bvh");
    assert_eq!(dup.code, "duplicate_file");
    assert_eq!(dup.kept.as_deref(), Some("dances/indian/04.bvh"));

    // Two collections of the same name: qualified by their position too.
    let c = lay_out(
        &tmp.path().join("elsewhere/dances"),
        &[("salsa/04.bvh", bvh("02/02_07.bvh"))],
    );
    let out3 = tmp.path().join("ds3");
    build(
        vec![Source::open(&a).unwrap(), Source::open(&c).unwrap()],
        &out3,
        &short_takes_options(),
    );
    let t = takes_table(&out3);
    assert_eq!(row(&t, "dances#1/salsa/04")[0], "salsa");
    assert_eq!(row(&t, "dances#2/salsa/04")[3], "dances/salsa/04.bvh");
}

#[test]
fn a_failing_preferred_copy_falls_back_to_the_next() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let src = lay_out(
        tmp.path(),
        &[
            // 02_02: the AMC has no ASF; its BVH copy works.
            ("mixed/amc/02_02.amc", amc("02/02_02.amc")),
            ("mixed/bvh/02_02.bvh", bvh("02/02_02.bvh")),
            // 02_01: both work; the AMC wins and the BVH is not read.
            ("mixed/amc2/02.asf", amc("02/02.asf")),
            ("mixed/amc2/02_01.amc", amc("02/02_01.amc")),
            ("mixed/bvh/02_01.bvh", bvh("02/02_01.bvh")),
            // 02_03: every copy fails.
            ("mixed/amc/02_03.amc", amc("02/02_03.amc")),
            ("mixed/bvh/02_03.bvh", b"HIERARCHY\n".to_vec()),
        ],
    );
    let out = tmp.path().join("ds");
    let s = build(
        vec![Source::open(&src.join("mixed")).unwrap()],
        &out,
        &short_takes_options(),
    );
    let t = takes_table(&out);
    assert_eq!(row(&t, "02_02")[1], "bvh");
    assert_eq!(row(&t, "02_02")[3], "mixed/bvh/02_02.bvh");
    assert_eq!(row(&t, "02_01")[1], "amc");
    assert_eq!(t.len(), 2);

    let failed = skipped_of(&s, "amc/02_02.amc");
    assert_eq!(failed.code, "missing_asf");
    assert_eq!(failed.kept.as_deref(), Some("mixed/bvh/02_02.bvh"));
    assert!(failed
        .message
        .contains("was read from mixed/bvh/02_02.bvh instead"));
    let unread = skipped_of(&s, "bvh/02_01.bvh");
    assert_eq!(unread.code, "duplicate_take");
    assert_eq!(unread.kept.as_deref(), Some("mixed/amc2/02_01.amc"));
    assert_eq!(skipped_of(&s, "amc/02_03.amc").kept, None);
    assert_eq!(skipped_of(&s, "bvh/02_03.bvh").code, "syntax");
    assert_eq!(s.duplicates.takes, 3);
    assert_eq!(s.duplicates.fell_back, 1);
    assert_eq!(s.duplicates.unread, 1);
    assert_eq!(
        s.duplicates.kept_by_format,
        BTreeMap::from([("amc".into(), 1), ("bvh".into(), 1)])
    );
    // skipped.json says the same.
    let json = std::fs::read_to_string(out.join("skipped.json")).unwrap();
    assert!(json.contains("\"kept\": \"mixed/bvh/02_02.bvh\""), "{json}");
    assert_eq!(json.matches("\"code\"").count(), 4);
}

#[test]
fn daz_files_arrive_as_daz_takes_in_a_mixed_collection() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let sources = [daz_zip(), bvh_zip(), asfamc_zip()].map(|p| Source::open(&p).unwrap());
    let daz_alone = tmp.path().join("daz");
    let s = build(
        vec![Source::open(&daz_zip()).unwrap()],
        &daz_alone,
        &short_takes_options(),
    );
    assert_eq!(s.takes, 8);
    let t = takes_table(&daz_alone);
    for (id, r) in &t {
        assert_eq!(r[2], "Daz-friendly BVH", "{id}");
        assert_eq!(r[0], id[..2], "{id}");
        assert_eq!(
            r[3],
            format!("cmu-bvh-daz-sample.zip!/cmu-bvh-daz/{}/{id}.bvh", &id[..2])
        );
    }

    // With the other two samples, every Daz take has another copy: 02_02,
    // 02_08, 03_01 and 05_10 in ASF/AMC (preferred, and read first), 05_03,
    // 06_02, 07_06 and 08_11 in Motionbuilder BVH. The Daz copies of the
    // last three sort first by path and read, but a copy with the subject's
    // own skeleton is kept over a retargeted one.
    let s = build(sources.to_vec(), &out, &DatasetOptions::default());
    let t = takes_table(&out);
    let daz: Vec<&str> = t
        .iter()
        .filter(|(_, r)| r[2] == "Daz-friendly BVH")
        .map(|(id, _)| id.as_str())
        .collect();
    assert!(daz.is_empty(), "{daz:?}");
    let superseded: Vec<&str> = s
        .skipped
        .iter()
        .filter(|k| k.message.contains("read but not kept"))
        .map(|k| k.take.as_str())
        .collect();
    assert_eq!(superseded, ["05_03", "06_02", "07_06", "08_11"]);
    // The same bytes with one thread (duplicates are decided per take, in
    // take order).
    let one = tmp.path().join("one-thread");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(|| build(sources.to_vec(), &one, &DatasetOptions::default()));
    let (a, b) = (dataset_contents(&out), dataset_contents(&one));
    for f in DATASET_FILES {
        assert!(a[f] == b[f], "{f} depends on the thread count");
    }
    assert_eq!(s.files, 8 + 139 + 225);
    assert_eq!(s.takes, 139 + 225 - 54);
    let by: BTreeMap<String, usize> = s
        .takes_by_skeleton
        .iter()
        .map(|((f, k), n)| (format!("{f} {k}"), *n))
        .collect();
    assert_eq!(
        by,
        BTreeMap::from([
            ("amc ASF/AMC".into(), 225),
            ("bvh Motionbuilder-friendly BVH (2010)".into(), 139 - 54),
        ])
    );
}

#[test]
fn excluded_takes_are_left_out_and_recorded() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let src = lay_out(
        tmp.path(),
        &[
            ("s/02_01.bvh", bvh("02/02_01.bvh")),
            ("s/02_02.bvh", bvh("02/02_02.bvh")),
            ("s/02_03.bvh", bvh("02/02_03.bvh")),
        ],
    );
    let mut o = short_takes_options();
    o.exclude = mocap_ingest::dataset::parse_exclude_list(
        "# flagged by the audit\n02_02  # root jumps: 60 m/s\n\n99_99\n",
    );
    let out = tmp.path().join("ds");
    let s = build(vec![Source::open(&src.join("s")).unwrap()], &out, &o);
    let t = takes_table(&out);
    assert_eq!(t.keys().collect::<Vec<_>>(), ["02_01", "02_03"]);
    assert_eq!(s.excluded, 1);
    assert_eq!(skipped_of(&s, "02_02.bvh").code, "excluded");
    assert_eq!(s.exclude_unmatched, ["99_99"]);
    let manifest = std::fs::read_to_string(out.join("manifest.json")).unwrap();
    let m: serde_like::Exclude = serde_like::exclude(&manifest);
    assert_eq!(m.0, ["02_02", "99_99"]);
    assert!(Format::of("x.BVH") == Some(Format::Bvh));
}

/// The manifest's `options.exclude`, without a JSON dependency.
mod serde_like {
    pub struct Exclude(pub Vec<String>);
    pub fn exclude(manifest: &str) -> Exclude {
        let start = manifest
            .find("\"exclude\": [")
            .expect("exclude in manifest")
            + 12;
        let end = start + manifest[start..].find(']').unwrap();
        Exclude(
            manifest[start..end]
                .split(',')
                .map(|s| s.trim().trim_matches('"').to_string())
                .filter(|s| !s.is_empty())
                .collect(),
        )
    }
}
