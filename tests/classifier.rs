//! Categories of loaded windows and the motion classifier on real CMU
//! takes: every window carries its take's category, a dataset without the
//! `category` column (format 3) gives `other`, and the classifier trains,
//! saves and measures a small real dataset.

use mocap_ingest::category::Category;
use motion_vrnn::classifier::{train_and_measure, Classifier, ClassifierTraining};
use motion_vrnn::data::load;
use polars::prelude::*;
use std::path::Path;

/// Takes 02_01 … 02_06 (walk, walk, run, jump, sport, gesture), windows of
/// 32 frames, half of them train.
fn small_dataset(dir: &Path) -> std::path::PathBuf {
    integration_tests::small_dataset(dir, [0.5, 0.25, 0.25])
}

fn read(path: &Path) -> DataFrame {
    ParquetReader::new(std::fs::File::open(path).unwrap())
        .finish()
        .unwrap()
}

/// The category of every window of `split`, from the two tables.
fn expected(dir: &Path, split: &str) -> Vec<Category> {
    let takes = read(&dir.join("takes.parquet"));
    let cat = |take: &str| -> Category {
        let t = takes.column("take").unwrap().str().unwrap();
        let c = takes.column("category").unwrap().str().unwrap();
        let i = t.iter().position(|x| x == Some(take)).unwrap();
        c.get(i).unwrap().parse().unwrap()
    };
    let w = read(&dir.join("windows.parquet"));
    let (t, s) = (
        w.column("take").unwrap().str().unwrap(),
        w.column("split").unwrap().str().unwrap(),
    );
    t.iter()
        .zip(s.iter())
        .filter(|(_, s)| *s == Some(split))
        .map(|(t, _)| cat(t.unwrap()))
        .collect()
}

#[test]
fn windows_carry_their_takes_category_and_format_3_gives_other() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = small_dataset(tmp.path());
    let data = load(&ds, &["train", "val", "test"]).unwrap();
    let mut seen = std::collections::BTreeSet::new();
    for split in ["train", "val", "test"] {
        let Some((w, c)) = data.split(split) else {
            continue;
        };
        assert_eq!(c.len(), w.n, "{split}");
        assert_eq!(c, expected(&ds, split).as_slice(), "{split}");
        seen.extend(c.iter().copied());
    }
    assert!(seen.len() >= 3, "{seen:?}");
    assert!(!seen.contains(&Category::Other));

    // A format 3 `takes.parquet`: no category (nor description) column.
    let p = ds.join("takes.parquet");
    let mut takes = read(&p).drop_many(["category", "description"]);
    ParquetWriter::new(std::fs::File::create(&p).unwrap())
        .finish(&mut takes)
        .unwrap();
    let old = load(&ds, &["train", "val", "test"]).unwrap();
    for (split, w) in &data.splits {
        assert_eq!(old.splits[split].data, w.data, "{split}");
        assert!(old.categories[split].iter().all(|c| *c == Category::Other));
        assert_eq!(old.categories[split].len(), w.n);
    }
    // An unknown category is an error that names the file.
    let mut takes = read(&p);
    let n = takes.height();
    takes
        .with_column(Column::new("category".into(), vec!["skating"; n]))
        .unwrap();
    ParquetWriter::new(std::fs::File::create(&p).unwrap())
        .finish(&mut takes)
        .unwrap();
    let e = load(&ds, &["train"]).unwrap_err().to_string();
    assert!(e.contains("takes.parquet") && e.contains("skating"), "{e}");
}

#[test]
fn the_classifier_trains_and_measures_real_windows() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = small_dataset(tmp.path());
    let data = load(&ds, &["train", "test"]).unwrap();
    let dev = candle_core::Device::Cpu;
    let out = tmp.path().join("classifier");
    let t = ClassifierTraining {
        epochs: 8,
        batch: 16,
        ..Default::default()
    };
    let r = train_and_measure(&data, &out, &t, &dev).unwrap();
    let (train, test) = (&r.splits[0], &r.splits[1]);
    assert_eq!(train.accuracy.windows, data.splits["train"].n);
    assert_eq!(test.accuracy.windows, data.splits["test"].n);
    assert!(train.diversity.is_some_and(|d| d > 0.0));
    assert!(r.frechet_train_test.is_some_and(|d| d.is_finite()));
    let text = r.to_string();
    assert!(
        text.contains("| walk |") && text.contains("multimodality"),
        "{text}"
    );
    let (c, meta) = Classifier::load(&out, &dev).unwrap();
    assert_eq!(
        (&meta.config, &meta.training),
        (&r.meta.config, &r.meta.training)
    );
    assert_eq!(meta.loss.len(), 8);
    // JSON keeps the losses to within a unit in the last place.
    for (a, b) in meta.loss.iter().zip(&r.meta.loss) {
        assert!((a - b).abs() <= 1e-12 * b.abs(), "{a} {b}");
    }
    let train_windows: usize = c.config().train_windows.iter().sum();
    assert_eq!(train_windows, data.splits["train"].n);
    // The same seed again: the same files.
    let again = tmp.path().join("again");
    train_and_measure(&data, &again, &t, &dev).unwrap();
    for f in ["classifier.safetensors", "classifier.json"] {
        let (a, b) = (std::fs::read(out.join(f)), std::fs::read(again.join(f)));
        assert!(a.unwrap() == b.unwrap(), "{f}");
    }
}
