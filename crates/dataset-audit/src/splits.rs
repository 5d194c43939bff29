//! Split hygiene (no take, or subject, in two splits; the fractions
//! achieved) and the windows of each category per split.

use crate::{counts_by, u64_of, CategoryWindows, Report};
use mocap_ingest::category::Category;
use mocap_ingest::dataset::SPLITS;
use polars::prelude::*;
use std::collections::BTreeMap;

/// Check that no take (or, split by subject, no subject) is in two splits,
/// and report the fractions of takes achieved against those asked
/// (`got_takes`: the takes in the dataset).
pub(crate) fn hygiene(
    takes: &LazyFrame,
    windows: &LazyFrame,
    manifest: &serde_json::Value,
    got_takes: u64,
    r: &mut Report,
) -> PolarsResult<()> {
    let leaks = windows
        .clone()
        .group_by([col("take")])
        .agg([col("split").n_unique().alias("k")])
        .filter(col("k").gt(lit(1u32)))
        .collect()?;
    let leaks2 = windows
        .clone()
        .join(
            takes
                .clone()
                .select([col("take"), col("split").alias("take_split")]),
            [col("take")],
            [col("take")],
            JoinArgs::new(JoinType::Inner),
        )
        .filter(col("split").neq(col("take_split")))
        .collect()?;
    r.check(
        "split",
        "no take in two splits",
        leaks.height() == 0 && leaks2.height() == 0,
        format!("{} takes with windows in several splits, {} windows whose split differs from their take's", leaks.height(), leaks2.height()),
    );
    if manifest["options"]["split_by"].as_str() == Some("subject") {
        let subj = takes
            .clone()
            .group_by([col("subject")])
            .agg([col("split").n_unique().alias("k")])
            .filter(col("k").gt(lit(1u32)))
            .collect()?;
        r.check(
            "split",
            "no subject in two splits",
            subj.height() == 0,
            format!("{} subjects in several splits", subj.height()),
        );
    }
    let achieved: BTreeMap<String, f64> = counts_by(takes, "split")?
        .into_iter()
        .map(|(k, n)| (k, n as f64 / got_takes.max(1) as f64))
        .collect();
    let asked = &manifest["options"]["split_fractions"];
    r.check(
        "split",
        "split fractions (takes) achieved vs asked",
        true,
        SPLITS
            .iter()
            .enumerate()
            .map(|(i, s)| {
                format!(
                    "{s} {:.3} (asked {})",
                    achieved.get(*s).copied().unwrap_or(0.0),
                    asked[i]
                )
            })
            .collect::<Vec<_>>()
            .join(", "),
    );
    Ok(())
}

/// Windows per category and split, every known category listed (then any
/// other name found); a category with train windows but no test windows gets
/// a note (the test set cannot tell how the model does on it).
pub(crate) fn category_windows(
    takes: &LazyFrame,
    windows: &LazyFrame,
    r: &mut Report,
) -> PolarsResult<()> {
    let mut rows: BTreeMap<String, CategoryWindows> = BTreeMap::new();
    let empty = |c: &str| CategoryWindows {
        category: c.to_string(),
        takes: 0,
        windows: [0; 3],
    };
    for (c, n) in counts_by(takes, "category")? {
        rows.entry(c.clone()).or_insert_with(|| empty(&c)).takes = n;
    }
    let df = windows
        .clone()
        .join(
            takes.clone().select([col("take"), col("category")]),
            [col("take")],
            [col("take")],
            JoinArgs::new(JoinType::Inner),
        )
        .group_by([col("category"), col("split")])
        .agg([len().alias("n")])
        .collect()?;
    let (cats, splits) = (df.column("category")?.str()?, df.column("split")?.str()?);
    for i in 0..df.height() {
        let (Some(c), Some(s)) = (cats.get(i), splits.get(i)) else {
            continue;
        };
        let Some(k) = SPLITS.iter().position(|x| *x == s) else {
            continue;
        };
        rows.entry(c.to_string())
            .or_insert_with(|| empty(c))
            .windows[k] = u64_of(&df, "n", i).unwrap_or(0);
    }
    let known = Category::ALL.map(Category::name);
    let mut list: Vec<CategoryWindows> = known
        .iter()
        .map(|k| rows.remove(*k).unwrap_or_else(|| empty(k)))
        .collect();
    list.extend(rows.into_values());
    for c in &list {
        if c.windows[0] > 0 && c.windows[2] == 0 {
            r.notes.push(format!(
                "category {} has {} train windows but no test windows",
                c.category, c.windows[0]
            ));
        }
    }
    r.categories = list;
    Ok(())
}
