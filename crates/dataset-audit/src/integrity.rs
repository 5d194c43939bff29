//! Integrity checks: every output's hash against the manifest, the
//! documented schemas, finite values, windows inside their takes, frames and
//! counts as the manifest says.

use crate::{counts_by, scan, u64_of, Report, OUTPUTS};
use mocap_ingest::dataset::{manifest_warnings, sha256_hex, SPLITS};
use mocap_ingest::features::feature_names;
use polars::prelude::*;
use std::collections::HashMap;
use std::path::Path;

/// Check each output's SHA-256 against the manifest's; whether every output
/// could be read.
pub(crate) fn hashes(dir: &Path, manifest: &serde_json::Value, r: &mut Report) -> bool {
    let listed: HashMap<String, String> = manifest["outputs"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|o| {
                    Some((
                        o["path"].as_str()?.to_string(),
                        o["sha256"].as_str()?.to_string(),
                    ))
                })
                .collect()
        })
        .unwrap_or_default();
    let mut readable = true;
    for f in OUTPUTS {
        let p = dir.join(f);
        match (std::fs::read(&p), listed.get(f)) {
            (Err(e), _) => {
                readable = false;
                r.check(
                    "integrity",
                    &format!("{f} present"),
                    false,
                    format!("{}: {e}", p.display()),
                );
            }
            (Ok(_), None) => r.check(
                "integrity",
                &format!("{f} hash"),
                false,
                "not listed in manifest.json",
            ),
            (Ok(bytes), Some(want)) => {
                let got = sha256_hex(&bytes);
                let ok = &got == want;
                let detail = if ok {
                    format!("sha256 {got}")
                } else {
                    format!("sha256 {got} but manifest.json says {want}")
                };
                r.check("integrity", &format!("{f} hash"), ok, detail);
            }
        }
    }
    readable
}

/// The documented schemas (docs/dataset.md).
fn expected_schema(file: &str) -> Vec<(String, DataType)> {
    let s = |n: &str, t: DataType| (n.to_string(), t);
    match file {
        "frames.parquet" => {
            let mut v = vec![
                s("take", DataType::String),
                s("subject", DataType::String),
                s("frame", DataType::UInt32),
            ];
            v.extend(feature_names().into_iter().map(|n| (n, DataType::Float32)));
            v
        }
        "takes.parquet" => vec![
            s("take", DataType::String),
            s("subject", DataType::String),
            s("file", DataType::String),
            s("format", DataType::String),
            s("skeleton", DataType::String),
            s("source_fps", DataType::Float32),
            s("native_frames", DataType::UInt32),
            s("frames", DataType::UInt32),
            s("split", DataType::String),
            s("category", DataType::String),
            s("description", DataType::String),
        ],
        _ => vec![
            s("take", DataType::String),
            s("start", DataType::UInt32),
            s("length", DataType::UInt32),
            s("split", DataType::String),
        ],
    }
}

/// Check the three tables' schemas against the documented ones (format 3's
/// `takes.parquet`, without `category` and `description`, passes); whether
/// they all match.
pub(crate) fn schemas(dir: &Path, r: &mut Report) -> PolarsResult<bool> {
    for f in ["frames.parquet", "takes.parquet", "windows.parquet"] {
        let schema = scan(&dir.join(f))?.collect_schema()?;
        let got: Vec<(String, DataType)> = schema
            .iter()
            .map(|(n, t)| (n.to_string(), t.clone()))
            .collect();
        let want = expected_schema(f);
        // Format 3 (before categories): takes.parquet without its last two columns.
        let format3 =
            f == "takes.parquet" && got.len() + 2 == want.len() && got[..] == want[..got.len()];
        let ok = got == want || format3;
        let detail = if format3 {
            format!(
                "{} columns as documented for format 3 (no category, description)",
                got.len()
            )
        } else if ok {
            format!("{} columns as documented", got.len())
        } else {
            let diff = want
                .iter()
                .zip(got.iter().map(Some).chain(std::iter::repeat(None)))
                .find(|(w, g)| Some(*w) != *g)
                .map(|(w, g)| format!("expected {} {:?}, found {:?}", w.0, w.1, g))
                .unwrap_or_else(|| format!("{} extra columns", got.len() - want.len()));
            diff
        };
        r.check("integrity", &format!("{f} schema"), ok, detail);
        if !ok {
            return Ok(false);
        }
    }
    Ok(true)
}

/// Check that no feature value is NaN or infinite.
pub(crate) fn finite_values(frames: &LazyFrame, r: &mut Report) -> PolarsResult<()> {
    let names = feature_names();
    let bad = frames
        .clone()
        .select(
            names
                .iter()
                .map(|n| col(n.as_str()).is_finite().not().sum().alias(n.as_str()))
                .collect::<Vec<_>>(),
        )
        .collect()?;
    let mut bad_total = 0u64;
    let mut bad_cols = Vec::new();
    for n in &names {
        let v = u64_of(&bad, n, 0).unwrap_or(0);
        if v > 0 {
            bad_cols.push(format!("{n} ({v})"));
        }
        bad_total += v;
    }
    r.check(
        "integrity",
        "no NaN or infinite feature values",
        bad_total == 0,
        if bad_total == 0 {
            "0 non-finite values".to_string()
        } else {
            format!("{bad_total} non-finite values in {}", bad_cols.join(", "))
        },
    );
    Ok(())
}

/// Check that every window lies inside its take.
pub(crate) fn windows_inside(
    windows: &LazyFrame,
    takes: &LazyFrame,
    r: &mut Report,
) -> PolarsResult<()> {
    let outside = windows
        .clone()
        .join(
            takes
                .clone()
                .select([col("take"), col("frames"), col("split").alias("take_split")]),
            [col("take")],
            [col("take")],
            JoinArgs::new(JoinType::Left),
        )
        .filter(
            col("frames")
                .is_null()
                .or((col("start") + col("length")).gt(col("frames"))),
        )
        .collect()?;
    r.check(
        "integrity",
        "every window lies inside its take",
        outside.height() == 0,
        format!("{} windows outside their take", outside.height()),
    );
    Ok(())
}

/// Check that the frames of each take agree with `takes.parquet`.
pub(crate) fn frames_per_take(
    frames: &LazyFrame,
    takes: &LazyFrame,
    r: &mut Report,
) -> PolarsResult<()> {
    let per_take = frames
        .clone()
        .group_by([col("take")])
        .agg([len().alias("n")])
        .join(
            takes.clone(),
            [col("take")],
            [col("take")],
            JoinArgs::new(JoinType::Full),
        )
        .filter(
            col("n")
                .is_null()
                .or(col("frames").is_null())
                .or(col("n").cast(DataType::UInt32).neq(col("frames"))),
        )
        .collect()?;
    r.check(
        "integrity",
        "frames per take match takes.parquet",
        per_take.height() == 0,
        format!("{} takes disagree", per_take.height()),
    );
    Ok(())
}

/// Check takes, frames, windows per split and the warnings' kept frames
/// against the manifest; the number of takes.
pub(crate) fn counts(
    frames: &LazyFrame,
    takes: &LazyFrame,
    windows: &LazyFrame,
    manifest: &serde_json::Value,
    r: &mut Report,
) -> PolarsResult<u64> {
    let counts = &manifest["counts"];
    let n_takes = takes.clone().select([len()]).collect()?;
    let n_frames = frames.clone().select([len()]).collect()?;
    let got_split = counts_by(windows, "split")?;
    let got_takes = n_takes.columns()[0].get(0)?.extract::<u64>().unwrap_or(0);
    let got_frames = n_frames.columns()[0].get(0)?.extract::<u64>().unwrap_or(0);
    let mut mism = Vec::new();
    if counts["takes"].as_u64() != Some(got_takes) {
        mism.push(format!(
            "takes: manifest {} vs {got_takes}",
            counts["takes"]
        ));
    }
    if counts["frames"].as_u64() != Some(got_frames) {
        mism.push(format!(
            "frames: manifest {} vs {got_frames}",
            counts["frames"]
        ));
    }
    for s in SPLITS {
        let want = counts["windows_per_split"][s].as_u64().unwrap_or(0);
        let got = got_split.get(s).copied().unwrap_or(0);
        if want != got {
            mism.push(format!("{s} windows: manifest {want} vs {got}"));
        }
    }
    warnings_kept(takes, manifest, &mut mism)?;
    r.check(
        "integrity",
        "counts match the manifest",
        mism.is_empty(),
        if mism.is_empty() {
            format!("{got_takes} takes, {got_frames} frames, windows {got_split:?}")
        } else {
            mism.join("; ")
        },
    );
    Ok(got_takes)
}

/// Takes kept from files cut short: each must be in `takes.parquet` with
/// the frames its warning says were kept (a format 2 manifest has no
/// warnings); each disagreement is added to `mism`.
fn warnings_kept(
    takes: &LazyFrame,
    manifest: &serde_json::Value,
    mism: &mut Vec<String>,
) -> PolarsResult<()> {
    match manifest_warnings(manifest) {
        Err(e) => mism.push(e),
        Ok(warnings) if !warnings.is_empty() => {
            let t = takes
                .clone()
                .select([col("take"), col("native_frames")])
                .collect()?;
            let ids = t.column("take")?.str()?.clone();
            let native = t.column("native_frames")?.u32()?.clone();
            let kept: HashMap<&str, u32> = (0..t.height())
                .filter_map(|i| Some((ids.get(i)?, native.get(i)?)))
                .collect();
            for w in &warnings {
                let got = kept.get(w.take.as_str()).map(|&n| n as usize);
                if got != Some(w.frames_kept) {
                    mism.push(format!(
                        "warning on take {}: {} frames kept, takes.parquet {}",
                        w.take,
                        w.frames_kept,
                        got.map_or("has no such take".into(), |n| format!("{n} native frames"))
                    ));
                }
            }
        }
        Ok(_) => {}
    }
    Ok(())
}
