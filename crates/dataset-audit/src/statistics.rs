//! The normalisation statistics (`stats.json`) recomputed with polars from
//! the train windows' frames, and compared.

use crate::Report;
use mocap_ingest::dataset::Stats;
use mocap_ingest::features::feature_names;
use polars::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;

/// Recompute the normalisation statistics with polars and compare.
pub(crate) fn statistics(
    dir: &Path,
    frames: &LazyFrame,
    windows: &LazyFrame,
    r: &mut Report,
) -> PolarsResult<()> {
    let p = dir.join("stats.json");
    let parsed = std::fs::read_to_string(&p)
        .map_err(|e| e.to_string())
        .and_then(|t| serde_json::from_str::<Stats>(&t).map_err(|e| e.to_string()));
    let stats = match parsed {
        Ok(s) => s,
        Err(e) => {
            r.check(
                "statistics",
                "stats.json readable",
                false,
                format!("{}: {e}", p.display()),
            );
            return Ok(());
        }
    };
    let names = feature_names();
    let sums = weighted_sums(frames, windows, &names)?;
    let get = |c: &str| {
        sums.column(c)
            .ok()
            .and_then(|c| c.get(0).ok())
            .and_then(|v| v.extract::<f64>())
            .unwrap_or(f64::NAN)
    };
    let n = get("__n");
    let mut worst = (0.0f64, String::new());
    for (i, name) in names.iter().enumerate() {
        let mean = get(&format!("{name}__s1")) / n;
        let var = (get(&format!("{name}__s2")) / n - mean * mean).max(0.0);
        let std = var.sqrt();
        let smean = stats.mean.get(i).copied().unwrap_or(f64::NAN);
        let sstd = stats.std_raw.get(i).copied().unwrap_or(f64::NAN);
        let scale = sstd.max(1e-3);
        for (what, d) in [
            ("mean", (mean - smean).abs() / scale),
            ("std", (std - sstd).abs() / scale),
        ] {
            // NaN (a missing value) counts as the worst difference.
            if d.is_nan() || d > worst.0 {
                worst = (d, format!("{name} {what}"));
            }
        }
    }
    let ok = worst.0 < 1e-3 && n as u64 == stats.count;
    r.check(
        "statistics",
        "stats.json matches the train split recomputed with polars",
        ok,
        format!(
            "{n} weighted frames (stats.json: {}); largest difference {:.2e} of a std ({})",
            stats.count, worst.0, worst.1
        ),
    );
    r.floored_features = stats.floored;
    Ok(())
}

/// One row of sums over the train windows' frames, each frame weighted by
/// the number of train windows it is in: `__n` (the total weight), and for
/// each feature `NAME__s1` (weighted sum) and `NAME__s2` (weighted sum of
/// squares).
fn weighted_sums(
    frames: &LazyFrame,
    windows: &LazyFrame,
    names: &[String],
) -> PolarsResult<DataFrame> {
    let weighted = frames.clone().join(
        train_multiplicity(windows)?.lazy(),
        [col("take"), col("frame")],
        [col("take"), col("frame")],
        JoinArgs::new(JoinType::Inner),
    );
    let mut aggs = vec![col("w").sum().alias("__n")];
    for n in names {
        let x = col(n.as_str()).cast(DataType::Float64);
        aggs.push((x.clone() * col("w")).sum().alias(format!("{n}__s1")));
        aggs.push((x.clone() * x * col("w")).sum().alias(format!("{n}__s2")));
    }
    weighted.select(aggs).collect()
}

/// The multiplicity of each frame in the train windows (`take`, `frame`,
/// `w`), built per take from the windows table.
fn train_multiplicity(windows: &LazyFrame) -> PolarsResult<DataFrame> {
    let w = windows
        .clone()
        .filter(col("split").eq(lit("train")))
        .collect()?;
    let (wt, ws, wl) = (
        w.column("take")?.str()?.clone(),
        w.column("start")?.u32()?.clone(),
        w.column("length")?.u32()?.clone(),
    );
    let mut mult: BTreeMap<(String, u32), u32> = BTreeMap::new();
    for i in 0..w.height() {
        if let (Some(t), Some(s), Some(l)) = (wt.get(i), ws.get(i), wl.get(i)) {
            for f in s..s + l {
                *mult.entry((t.to_string(), f)).or_default() += 1;
            }
        }
    }
    let (mt, (mf, mw)): (Vec<String>, (Vec<u32>, Vec<f64>)) = mult
        .into_iter()
        .map(|((t, f), m)| (t, (f, m as f64)))
        .unzip();
    DataFrame::new_infer_height(vec![
        Column::from(Series::new("take".into(), mt)),
        Column::from(Series::new("frame".into(), mf)),
        Column::from(Series::new("w".into(), mw)),
    ])
}
