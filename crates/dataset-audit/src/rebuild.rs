//! Reproducibility: the dataset rebuilt from its sources with the options
//! its manifest records, and compared byte for byte.

use crate::{scan, Rebuild, Report, OUTPUTS};
use mocap_ingest::dataset::{build_dataset, DatasetOptions, Encoding, NoProgress, SplitBy};
use mocap_ingest::source::Source;
use polars::prelude::*;
use std::path::Path;

/// Rebuild the dataset with the manifest's options and compare bytes.
pub(crate) fn reproduce(
    dir: &Path,
    rebuild: &Rebuild,
    manifest: &serde_json::Value,
    r: &mut Report,
) {
    let tmp = std::env::temp_dir().join(format!("dataset-audit-{}", std::process::id()));
    let out = tmp.join("rebuild");
    match rebuild_into(&out, rebuild, manifest) {
        Err(e) => r.check("reproducibility", "rebuild from --source", false, e),
        Ok(()) => {
            let first_diff = first_difference(dir, &out);
            r.check(
                "reproducibility",
                "rebuild from --source is byte-identical",
                first_diff.is_none(),
                first_diff.unwrap_or_else(|| format!("all {} files identical", OUTPUTS.len() + 1)),
            );
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

/// The build options a manifest records (`options`), defaults for those it
/// lacks.
fn options_of(o: &serde_json::Value) -> DatasetOptions {
    let mut opts = DatasetOptions::default();
    opts.ingest.target_fps = o["fps"].as_f64().unwrap_or(30.0);
    opts.window = o["window"].as_u64().unwrap_or(128) as usize;
    opts.stride = o["stride"].as_u64().unwrap_or(64) as usize;
    if let Some(f) = o["split_fractions"].as_array() {
        for (i, v) in f.iter().take(3).enumerate() {
            opts.fractions[i] = v.as_f64().unwrap_or(opts.fractions[i]);
        }
    }
    opts.seed = o["seed"].as_u64().unwrap_or(0);
    opts.split_by = if o["split_by"].as_str() == Some("subject") {
        SplitBy::Subject
    } else {
        SplitBy::Take
    };
    opts.std_floor = o["std_floor"].as_f64().unwrap_or(1e-3);
    opts.ingest.asf.full_skeleton = o["full_asf_skeleton"].as_bool().unwrap_or(false);
    if let Some(map) = o["frame_rate_overrides"].as_object() {
        for (k, v) in map {
            if let Some(f) = v.as_f64() {
                opts.ingest.frame_rates.set(k, f);
            }
        }
    }
    if let Some(e) = o["encoding"].as_str().and_then(Encoding::from_name) {
        opts.encoding = e;
    }
    // A manifest without `strict` (format 2) comes from a build that always
    // skipped files cut short.
    opts.strict = o["strict"].as_bool().unwrap_or(true);
    if let Some(ids) = o["exclude"].as_array() {
        opts.exclude = ids
            .iter()
            .filter_map(|v| v.as_str().map(String::from))
            .collect();
    }
    if let Some(map) = o["categories"].as_object() {
        for (take, c) in map {
            if let Some(c) = c.as_str().and_then(|c| c.parse().ok()) {
                opts.categories.insert(take.clone(), c);
            }
        }
    }
    opts
}

/// Build the dataset into `out` from the rebuild's sources, with the
/// manifest's options and source labels; a dataset built with `--asf`
/// needs the same `--asf`.
fn rebuild_into(out: &Path, rebuild: &Rebuild, manifest: &serde_json::Value) -> Result<(), String> {
    let o = &manifest["options"];
    let opts = options_of(o);
    if o["asf"].is_string() && rebuild.asf.is_none() {
        return Err(format!(
            "the dataset was built with --asf {}: give the audit the same --asf",
            o["asf"]
        ));
    }
    let srcs = rebuild
        .sources
        .iter()
        .map(|p| {
            Source::open(p)
                .map(|s| s.with_fallback_asf(rebuild.asf.clone()))
                .map_err(|e| e.to_string())
        })
        .collect::<Result<Vec<_>, _>>()?;
    let labels: Vec<String> = manifest["sources"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|v| v.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default();
    build_dataset(&srcs, &labels, out, &opts, &NoProgress).map_err(|e| e.to_string())?;
    Ok(())
}

/// The first of the dataset's files whose bytes differ from the rebuild's
/// (for a table, with the first row and column that differ).
fn first_difference(dir: &Path, out: &Path) -> Option<String> {
    for f in OUTPUTS.iter().chain(std::iter::once(&"manifest.json")) {
        let (a, b) = (
            std::fs::read(dir.join(f)).unwrap_or_default(),
            std::fs::read(out.join(f)).unwrap_or_default(),
        );
        if a != b {
            let row = if f.ends_with(".parquet") {
                first_differing_row(&dir.join(f), &out.join(f))
            } else {
                None
            };
            return Some(match row {
                Some((row, c)) => format!("{f} differs first at row {row}, column {c}"),
                None => format!("{f} differs"),
            });
        }
    }
    None
}

/// The first row and column where two Parquet files differ.
fn first_differing_row(a: &Path, b: &Path) -> Option<(usize, String)> {
    let (da, db) = (scan(a).ok()?.collect().ok()?, scan(b).ok()?.collect().ok()?);
    let mut best: Option<(usize, String)> = None;
    for ca in da.columns() {
        let cb = db.column(ca.name()).ok()?;
        let (sa, sb) = (
            ca.cast(&DataType::String).ok()?,
            cb.cast(&DataType::String).ok()?,
        );
        let (sa, sb) = (sa.str().ok()?.clone(), sb.str().ok()?.clone());
        let n = sa.len().max(sb.len());
        if let Some(i) = (0..n).find(|&i| sa.get(i) != sb.get(i)) {
            if best.as_ref().is_none_or(|b| i < b.0) {
                best = Some((i, ca.name().to_string()));
            }
        }
    }
    best
}
