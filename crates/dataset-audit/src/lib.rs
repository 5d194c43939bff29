//! Audit a dataset directory written by `cargo xtask dataset` (see
//! `docs/audit.md`). Every check yields a [`Check`]; the report fails if any
//! check fails. Data-quality findings are listed per take.

mod integrity;
pub mod markdown;
mod quality;
mod rebuild;
mod splits;
mod statistics;

use polars::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// CMU length units to metres.
pub const METRES_PER_UNIT: f64 = 0.0564;

/// A failure that prevents the audit itself (not a failed check).
#[derive(Debug, thiserror::Error)]
pub enum AuditError {
    /// The directory has no readable manifest.
    #[error("{0}")]
    Manifest(String),
}

/// One check and its outcome.
#[derive(Clone, Debug, Serialize)]
pub struct Check {
    /// `integrity`, `reproducibility`, `split`, `statistics`.
    pub section: String,
    /// What was checked.
    pub name: String,
    /// Whether it passed.
    pub ok: bool,
    /// Numbers or the problem found.
    pub detail: String,
}

/// Data-quality summary of one take.
#[derive(Clone, Debug, Serialize)]
pub struct TakeQuality {
    /// Take id.
    pub take: String,
    /// Duration in seconds.
    pub seconds: f64,
    /// Mean horizontal root speed, m/s.
    pub mean_speed: f64,
    /// Largest horizontal root speed, m/s (a jump in position shows here).
    pub max_speed: f64,
    /// Largest relative std of a bone length over the take.
    pub bone_cv: f64,
    /// Lowest toe height over the take (units above the floor).
    pub min_toe: f64,
    /// Mean of the lower toe's height (units).
    pub mean_toe: f64,
    /// What looks wrong.
    pub flags: Vec<String>,
}

/// Windows of one category per split.
#[derive(Clone, Debug, Serialize)]
pub struct CategoryWindows {
    /// The category's name.
    pub category: String,
    /// Takes of this category.
    pub takes: u64,
    /// Windows in train, val, test.
    pub windows: [u64; 3],
}

/// Thresholds of the data-quality flags.
#[derive(Clone, Debug, Serialize)]
pub struct Thresholds {
    /// Mean speed above this (m/s) suggests a wrong (too low) frame rate.
    pub mean_speed: f64,
    /// Any frame faster than this (m/s) is a jump in position.
    pub max_speed: f64,
    /// Relative bone-length std above this means bones change.
    pub bone_cv: f64,
    /// A take whose lowest toe stays above this (units) never touches the floor.
    pub min_toe: f64,
    /// A take whose lowest toe goes below this (units) stands under the
    /// floor taken from its first frame: it starts raised (on a box, a
    /// climbing frame) or the ground is uneven.
    #[serde(default = "sink_toe")]
    pub sink_toe: f64,
}

fn sink_toe() -> f64 {
    -10.0
}

impl Default for Thresholds {
    fn default() -> Self {
        Thresholds {
            mean_speed: 5.0,
            max_speed: 12.0,
            bone_cv: 0.01,
            min_toe: 2.0,
            sink_toe: sink_toe(),
        }
    }
}

/// The audit's result.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The dataset directory.
    pub dir: String,
    /// Every check.
    pub checks: Vec<Check>,
    /// Per-take data quality.
    pub takes: Vec<TakeQuality>,
    /// Flag thresholds used.
    pub thresholds: Thresholds,
    /// Features whose std hit the floor.
    pub floored_features: Vec<String>,
    /// Windows per category and split (`takes.parquet`'s `category`; empty
    /// for a format 3 dataset, which has no categories).
    pub categories: Vec<CategoryWindows>,
    /// Data-quality notes: worth knowing, not failures (a category with
    /// train windows but no test windows).
    pub notes: Vec<String>,
    /// Horizontal root speed of every frame, m/s (for a histogram).
    #[serde(skip)]
    pub speeds: Vec<f64>,
    /// Lower-toe height of every frame, units (for a histogram).
    #[serde(skip)]
    pub toe_heights: Vec<f64>,
}

impl Report {
    /// Whether every check passed.
    pub fn ok(&self) -> bool {
        self.checks.iter().all(|c| c.ok)
    }

    fn check(&mut self, section: &str, name: &str, ok: bool, detail: impl Into<String>) {
        self.checks.push(Check {
            section: section.into(),
            name: name.into(),
            ok,
            detail: detail.into(),
        });
    }
}

/// The outputs the manifest lists with their hashes.
const OUTPUTS: [&str; 5] = [
    "frames.parquet",
    "takes.parquet",
    "windows.parquet",
    "stats.json",
    "skipped.json",
];

/// A path as polars takes it.
fn path_str(p: &Path) -> PlRefPath {
    PlRefPath::new(p.to_string_lossy().into_owned())
}

/// A lazy scan of a Parquet file.
fn scan(p: &Path) -> PolarsResult<LazyFrame> {
    LazyFrame::scan_parquet(path_str(p), Default::default())
}

/// Rows per value of `key` (a string column).
fn counts_by(lf: &LazyFrame, key: &str) -> PolarsResult<BTreeMap<String, u64>> {
    let df = lf
        .clone()
        .group_by([col(key)])
        .agg([len().alias("n")])
        .collect()?;
    let keys = df.column(key)?.str()?.clone();
    Ok((0..df.height())
        .filter_map(|i| Some((keys.get(i)?.to_string(), u64_of(&df, "n", i).unwrap_or(0))))
        .collect())
}

/// The value of a column at a row, as `u64`.
fn u64_of(df: &DataFrame, col_name: &str, row: usize) -> Option<u64> {
    df.column(col_name).ok()?.get(row).ok()?.extract::<u64>()
}

/// What a rebuild reads: the collections (as given to `dataset`) and the
/// fallback ASF (`--asf`), if the dataset was built with one.
#[derive(Clone, Debug, Default)]
pub struct Rebuild {
    /// The collections; none means no rebuild.
    pub sources: Vec<PathBuf>,
    /// The `--asf` skeleton.
    pub asf: Option<PathBuf>,
}

/// Audit `dir`; with sources in `rebuild`, also rebuild it (with the
/// manifest's options, exclude list included) and compare bytes.
pub fn audit(dir: &Path, rebuild: &Rebuild, thresholds: Thresholds) -> Result<Report, AuditError> {
    let mpath = dir.join("manifest.json");
    let text = std::fs::read_to_string(&mpath)
        .map_err(|e| AuditError::Manifest(format!("{}: {e}", mpath.display())))?;
    let manifest: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| AuditError::Manifest(format!("{}: not JSON: {e}", mpath.display())))?;
    let mut r = Report {
        dir: dir.display().to_string(),
        checks: Vec::new(),
        takes: Vec::new(),
        thresholds,
        floored_features: Vec::new(),
        categories: Vec::new(),
        notes: Vec::new(),
        speeds: Vec::new(),
        toe_heights: Vec::new(),
    };

    // ---- Integrity: hashes.
    if !integrity::hashes(dir, &manifest, &mut r) {
        return Ok(r);
    }
    if let Err(e) = checks_on_tables(dir, &manifest, &mut r) {
        r.check("integrity", "tables readable", false, e.to_string());
        return Ok(r);
    }

    // ---- Reproducibility.
    if !rebuild.sources.is_empty() {
        rebuild::reproduce(dir, rebuild, &manifest, &mut r);
    }
    Ok(r)
}

/// Every check that reads the tables, in order: schemas, values, windows
/// and counts (integrity), split hygiene, windows per category, statistics
/// and data quality. Stops after a schema that is not the documented one.
fn checks_on_tables(dir: &Path, manifest: &serde_json::Value, r: &mut Report) -> PolarsResult<()> {
    if !integrity::schemas(dir, r)? {
        return Ok(());
    }
    let frames = scan(&dir.join("frames.parquet"))?;
    let takes = scan(&dir.join("takes.parquet"))?;
    let windows = scan(&dir.join("windows.parquet"))?;
    integrity::finite_values(&frames, r)?;
    integrity::windows_inside(&windows, &takes, r)?;
    integrity::frames_per_take(&frames, &takes, r)?;
    let got_takes = integrity::counts(&frames, &takes, &windows, manifest, r)?;
    splits::hygiene(&takes, &windows, manifest, got_takes, r)?;
    if takes.clone().collect_schema()?.contains("category") {
        splits::category_windows(&takes, &windows, r)?;
    }
    statistics::statistics(dir, &frames, &windows, r)?;
    quality::quality(
        &frames,
        manifest["options"]["fps"].as_f64().unwrap_or(30.0),
        r,
    )?;
    Ok(())
}
