//! `build_dataset` on the real CMU samples: byte-identical output whatever the
//! thread count, bad files reported without changing the good output, a
//! failed build leaves the previous dataset in place, and polars reads it all.

use integration_tests::{
    asfamc_zip, bvh_zip, dataset_contents, read_entry, short_takes_options, DATASET_FILES,
};
use mocap_ingest::dataset::{build_dataset, DatasetOptions, NoProgress};
use mocap_ingest::source::Source;
use polars::prelude::*;
use std::path::Path;

fn build(sources: &[&Path], out: &Path, threads: usize) -> mocap_ingest::dataset::BuildSummary {
    build_with(sources, out, threads, &DatasetOptions::default())
}

fn build_with(
    sources: &[&Path],
    out: &Path,
    threads: usize,
    opts: &DatasetOptions,
) -> mocap_ingest::dataset::BuildSummary {
    let srcs: Vec<Source> = sources.iter().map(|p| Source::open(p).unwrap()).collect();
    let labels: Vec<String> = sources.iter().map(|p| p.display().to_string()).collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| build_dataset(&srcs, &labels, out, opts, &NoProgress))
        .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn output_is_byte_identical_with_one_thread_and_all_threads() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let bvh = bvh_zip();
    let mut seen = Vec::new();
    for (i, threads) in [1, 4, 1, 4].iter().enumerate() {
        let out = tmp.path().join(format!("run{i}"));
        let s = build(&[&bvh], &out, *threads);
        assert_eq!(s.takes, 139);
        seen.push(dataset_contents(&out));
    }
    for other in &seen[1..] {
        for f in DATASET_FILES {
            assert!(seen[0][f] == other[f], "{f} differs between runs");
        }
    }
}

#[test]
fn broken_files_are_reported_and_do_not_change_the_good_output() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("good");
    let mixed = tmp.path().join("mixed");
    let take = |n: &str| read_entry(&bvh_zip(), &format!("cmu-bvh-motionbuilder/{n}"));
    for dir in [&good, &mixed] {
        std::fs::create_dir_all(dir.join("02")).unwrap();
        for n in [
            "02/02_01.bvh",
            "02/02_02.bvh",
            "02/02_03.bvh",
            "02/02_04.bvh",
        ] {
            std::fs::write(dir.join(n), take(n)).unwrap();
        }
    }
    let t = take("02/02_05.bvh");
    std::fs::write(mixed.join("02/02_90.bvh"), &t[..t.len() / 2]).unwrap();
    std::fs::write(mixed.join("02/02_91.bvh"), b"").unwrap();
    std::fs::write(mixed.join("02/02_92.bvh"), [0u8, 1, 2, 3, 255]).unwrap();
    std::fs::write(mixed.join("02/02_93.amc"), b"1\nroot 0 0 0 0 0 0\n").unwrap();
    std::fs::write(mixed.join("02/notes.txt"), b"not motion").unwrap();

    // Strict, the file cut short is skipped too (as in format 2).
    let strict = DatasetOptions {
        strict: true,
        ..short_takes_options()
    };
    let a = build_with(&[&good], &tmp.path().join("a"), 2, &short_takes_options());
    let b = build_with(&[&mixed], &tmp.path().join("b"), 2, &strict);
    assert_eq!(a.takes, 4);
    assert_eq!(b.takes, 4);
    assert!(b.warnings.is_empty());
    let codes: Vec<&str> = b.skipped.iter().map(|s| s.code.as_str()).collect();
    assert_eq!(codes, ["truncated", "empty", "not_text", "missing_asf"]);
    assert!(b.skipped[0].message.contains("02_90.bvh"));
    // By default it is kept with its complete frames, and a warning.
    let c = build_with(&[&mixed], &tmp.path().join("c"), 2, &short_takes_options());
    assert_eq!(c.takes, 5);
    let codes: Vec<&str> = c.skipped.iter().map(|s| s.code.as_str()).collect();
    assert_eq!(codes, ["empty", "not_text", "missing_asf"]);
    assert_eq!(c.warnings.len(), 1);
    let w = &c.warnings[0];
    assert_eq!((w.take.as_str(), w.kind.as_str()), ("02_90", "truncated"));
    assert!(w.file.ends_with("02/02_90.bvh"), "{w:?}");
    assert!(
        w.frames_kept > 0 && w.frames_kept < w.frames_expected,
        "{w:?}"
    );
    assert_eq!(c.native_frames, a.native_frames + w.frames_kept);
    let (ca, cb) = (
        dataset_contents(&tmp.path().join("a")),
        dataset_contents(&tmp.path().join("b")),
    );
    for f in ["frames.parquet", "windows.parquet", "stats.json"] {
        assert!(ca[f] == cb[f], "{f} changed because of the broken files");
    }
    let skipped: serde_json_like::Skipped = serde_json_like::parse(&cb["skipped.json"]);
    assert_eq!(skipped.0, 4);
}

/// Tiny helper so the test needs no JSON dependency: count `"code"` keys.
mod serde_json_like {
    pub struct Skipped(pub usize);
    pub fn parse(bytes: &[u8]) -> Skipped {
        Skipped(String::from_utf8_lossy(bytes).matches("\"code\"").count())
    }
}

#[test]
fn a_failed_build_keeps_the_previous_dataset() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let src = tmp.path().join("src");
    std::fs::create_dir_all(&src).unwrap();
    std::fs::write(
        src.join("02_01.bvh"),
        read_entry(&bvh_zip(), "cmu-bvh-motionbuilder/02/02_01.bvh"),
    )
    .unwrap();
    build_with(&[&src], &out, 1, &short_takes_options());
    let before = dataset_contents(&out);
    // Only a broken file now: the build fails (empty dataset) ...
    std::fs::write(src.join("02_01.bvh"), b"HIERARCHY\n").unwrap();
    let s = Source::open(&src).unwrap();
    let err = build_dataset(
        &[s],
        &["src".into()],
        &out,
        &short_takes_options(),
        &NoProgress,
    )
    .unwrap_err();
    assert!(err.to_string().contains("empty dataset"), "{err}");
    // ... and the previous dataset is untouched, with no staging left over.
    assert_eq!(dataset_contents(&out), before);
    let names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
}

#[test]
fn polars_reads_the_dataset_back() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let s = build(&[&bvh_zip(), &asfamc_zip()], &out, 2);
    // 54 takes are in both archives: each is kept once (the ASF/AMC copy).
    for k in s.skipped.iter().filter(|k| k.code != "duplicate_take") {
        eprintln!("{}", k.message);
    }
    assert_eq!(s.files, 139 + 225);
    assert_eq!(s.takes, 139 + 225 - 54);
    assert_eq!(
        s.skipped
            .iter()
            .filter(|k| k.code == "duplicate_take")
            .count(),
        54
    );

    let path = |f: &str| PlRefPath::new(out.join(f).to_str().unwrap().to_string());
    let frames = LazyFrame::scan_parquet(path("frames.parquet"), Default::default()).unwrap();
    let takes = LazyFrame::scan_parquet(path("takes.parquet"), Default::default()).unwrap();
    let windows = LazyFrame::scan_parquet(path("windows.parquet"), Default::default()).unwrap();

    // Frames per take counted from frames.parquet equal takes.parquet's column.
    let per_take = frames
        .clone()
        .group_by([col("take")])
        .agg([len().alias("n"), col("frame").max().alias("last")])
        .join(
            takes.clone(),
            [col("take")],
            [col("take")],
            JoinArgs::new(JoinType::Inner),
        )
        .filter(
            col("n")
                .cast(DataType::UInt32)
                .neq(col("frames"))
                .or((col("last") + lit(1u32)).neq(col("frames"))),
        )
        .collect()
        .unwrap();
    assert_eq!(per_take.height(), 0, "{per_take}");

    // Every window lies inside its take, and windows never leak across splits.
    let bad = windows
        .clone()
        .join(
            takes
                .clone()
                .select([col("take"), col("frames"), col("split").alias("take_split")]),
            [col("take")],
            [col("take")],
            JoinArgs::new(JoinType::Inner),
        )
        .filter(
            (col("start") + col("length"))
                .gt(col("frames"))
                .or(col("split").neq(col("take_split"))),
        )
        .collect()
        .unwrap();
    assert_eq!(bad.height(), 0, "{bad}");

    let counts = windows
        .group_by([col("split")])
        .agg([len().alias("windows")])
        .sort(["split"], Default::default())
        .collect()
        .unwrap();
    eprintln!("{counts}");
    let total: u64 = counts
        .column("windows")
        .unwrap()
        .cast(&DataType::UInt64)
        .unwrap()
        .u64()
        .unwrap()
        .into_no_null_iter()
        .sum();
    assert_eq!(total as usize, s.windows_per_split.iter().sum::<usize>());

    // No NaN anywhere in the features.
    let nan = frames
        .select([all()
            .exclude_cols(["take", "subject", "frame"])
            .as_expr()
            .is_nan()
            .sum()])
        .collect()
        .unwrap();
    for c in nan.columns() {
        assert_eq!(
            c.cast(&DataType::UInt64).unwrap().u64().unwrap().get(0),
            Some(0)
        );
    }
}
