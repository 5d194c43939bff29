//! Loading the Parquet dataset written by `cargo xtask dataset` (see
//! `docs/dataset.md`) through polars, normalised with its `stats.json`,
//! with the category of every window (from `takes.parquet`).

use candle_core::{Device, Tensor};
pub use mocap_ingest::category::Category;
use polars::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A failure to load the dataset.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A file could not be read.
    #[error("{path}: {message}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The dataset is not what the model expects.
    #[error("{0}")]
    Invalid(String),
}

fn read_err(path: &Path, e: impl std::fmt::Display) -> DataError {
    DataError::Read {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// A typed column of a data frame read from `path`.
fn column<T>(
    df: &DataFrame,
    name: &str,
    path: &Path,
    typed: impl Fn(&Column) -> PolarsResult<T>,
) -> Result<T, DataError> {
    df.column(name)
        .and_then(typed)
        .map_err(|e| read_err(path, e))
}

/// Normalisation statistics (`stats.json`), as the dataset stage writes them.
pub use mocap_ingest::dataset::Stats;

/// The windows of one split, normalised: `n × length × features`, row-major.
#[derive(Clone, Debug)]
pub struct Windows {
    /// Values, `(x − mean) / std`.
    pub data: Vec<f32>,
    /// Number of windows.
    pub n: usize,
    /// Frames per window.
    pub length: usize,
    /// Features per frame.
    pub features: usize,
}

impl Windows {
    /// The windows at `indices` as a `[B, T, F]` tensor.
    pub fn batch(&self, indices: &[usize], device: &Device) -> candle_core::Result<Tensor> {
        let w = self.length * self.features;
        let mut buf = Vec::with_capacity(indices.len() * w);
        for &i in indices {
            buf.extend_from_slice(&self.data[i * w..(i + 1) * w]);
        }
        Tensor::from_vec(buf, (indices.len(), self.length, self.features), device)
    }
}

/// A loaded dataset directory.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The directory.
    pub dir: PathBuf,
    /// Its statistics.
    pub stats: Stats,
    /// SHA-256 of its `manifest.json` (identifies the exact dataset).
    pub manifest_sha256: String,
    /// Per split (`train`, `val`, `test`), the windows.
    pub splits: HashMap<String, Windows>,
    /// Per split, the category of each of its windows (in window order):
    /// its take's `category` in `takes.parquet`. A dataset without that
    /// column (formats before 4) or without `takes.parquet` gives
    /// [`Category::Other`] for every window.
    pub categories: HashMap<String, Vec<Category>>,
    /// Per split, the take id of each of its windows (in window order).
    pub takes: HashMap<String, Vec<String>>,
}

impl Dataset {
    /// The windows of `split` with their categories (None when the split
    /// was not loaded or has no windows).
    pub fn split(&self, split: &str) -> Option<(&Windows, &[Category])> {
        let w = self.splits.get(split).filter(|w| w.n > 0)?;
        Some((w, self.categories_of(split)))
    }

    /// The take of each window of `split` (empty when the split was not
    /// loaded).
    pub fn takes_of(&self, split: &str) -> &[String] {
        self.takes.get(split).map_or(&[], Vec::as_slice)
    }

    /// The category of each window of `split` (empty when the split was
    /// not loaded).
    pub fn categories_of(&self, split: &str) -> &[Category] {
        self.categories.get(split).map_or(&[], Vec::as_slice)
    }
}

/// Read `stats.json` of a dataset directory.
pub fn read_stats(dir: &Path) -> Result<Stats, DataError> {
    let p = dir.join("stats.json");
    let text = std::fs::read_to_string(&p).map_err(|e| read_err(&p, e))?;
    let s: Stats = serde_json::from_str(&text).map_err(|e| read_err(&p, e))?;
    if s.mean.len() != s.features.len() || s.std.len() != s.features.len() {
        return Err(DataError::Invalid(format!(
            "{}: inconsistent lengths",
            p.display()
        )));
    }
    if s.std.iter().any(|v| !(*v > 0.0 && v.is_finite())) {
        return Err(DataError::Invalid(format!(
            "{}: non-positive std",
            p.display()
        )));
    }
    Ok(s)
}

/// SHA-256 (hex) of a dataset's `manifest.json`.
pub fn manifest_sha256(dir: &Path) -> Result<String, DataError> {
    use sha2::{Digest, Sha256};
    let p = dir.join("manifest.json");
    let bytes = std::fs::read(&p).map_err(|e| read_err(&p, e))?;
    Ok(Sha256::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// Take → category from `takes.parquet`; empty when the file or its
/// `category` column is absent (datasets before format 4).
fn take_categories(dir: &Path) -> Result<HashMap<String, Category>, DataError> {
    let p = dir.join("takes.parquet");
    if !p.is_file() {
        return Ok(HashMap::new());
    }
    let lf = LazyFrame::scan_parquet(
        PlRefPath::new(p.to_string_lossy().into_owned()),
        Default::default(),
    )
    .map_err(|e| read_err(&p, e))?;
    let schema = lf.clone().collect_schema().map_err(|e| read_err(&p, e))?;
    if !schema.contains("category") {
        return Ok(HashMap::new());
    }
    let df = lf
        .select([col("take"), col("category")])
        .collect()
        .map_err(|e| read_err(&p, e))?;
    let takes = column(&df, "take", &p, |c| c.str().cloned())?;
    let cats = column(&df, "category", &p, |c| c.str().cloned())?;
    let mut out = HashMap::new();
    for (row, (t, c)) in takes.iter().zip(cats.iter()).enumerate() {
        let (Some(t), Some(c)) = (t, c) else {
            return Err(DataError::Invalid(format!(
                "{}: null take or category at row {row}",
                p.display()
            )));
        };
        let c: Category = c
            .parse()
            .map_err(|e| DataError::Invalid(format!("{}: take {t}: {e}", p.display())))?;
        out.insert(t.to_string(), c);
    }
    Ok(out)
}

/// Each take's row offset of its frame 0 in `frames` and its number of
/// frames (frames are stored by take, then frame); an error where a take's
/// frames are not consecutive from 0.
fn take_offsets(
    frames: &DataFrame,
    fpath: &Path,
) -> Result<HashMap<String, (usize, usize)>, DataError> {
    let takes = column(frames, "take", fpath, |c| c.str().cloned())?;
    let frame_idx = column(frames, "frame", fpath, |c| c.u32().cloned())?;
    let mut offsets: HashMap<String, (usize, usize)> = HashMap::new();
    for (row, (t, f)) in takes.iter().zip(frame_idx.iter()).enumerate() {
        let (Some(t), Some(f)) = (t, f) else {
            return Err(DataError::Invalid(format!(
                "{}: null take or frame at row {row}",
                fpath.display()
            )));
        };
        let e = offsets.entry(t.to_string()).or_insert((row, 0));
        if f as usize != row - e.0 {
            return Err(DataError::Invalid(format!(
                "{}: take {t} is not stored as consecutive frames from 0 (row {row})",
                fpath.display()
            )));
        }
        e.1 += 1;
    }
    Ok(offsets)
}

/// Every feature column of `frames`, normalised by `stats` (a missing value
/// is NaN).
fn normalised_columns(
    frames: &DataFrame,
    stats: &Stats,
    fpath: &Path,
) -> Result<Vec<Vec<f32>>, DataError> {
    let nf = stats.features.len();
    let mut cols: Vec<Vec<f32>> = Vec::with_capacity(nf);
    for (i, name) in stats.features.iter().enumerate() {
        let c = column(frames, name, fpath, |c| c.f32().cloned())?;
        let (m, s) = (stats.mean[i] as f32, stats.std[i] as f32);
        cols.push(c.iter().map(|v| (v.unwrap_or(f32::NAN) - m) / s).collect());
    }
    Ok(cols)
}

/// Load the given splits of a dataset directory, with the category of every
/// window ([`Dataset::categories`]).
pub fn load(dir: &Path, splits: &[&str]) -> Result<Dataset, DataError> {
    let stats = read_stats(dir)?;
    let manifest = manifest_sha256(dir)?;
    let fpath = dir.join("frames.parquet");
    let wpath = dir.join("windows.parquet");
    let pl = |p: &Path| PlRefPath::new(p.to_string_lossy().into_owned());
    let windows = LazyFrame::scan_parquet(pl(&wpath), Default::default())
        .and_then(|lf| lf.collect())
        .map_err(|e| read_err(&wpath, e))?;
    let frames = LazyFrame::scan_parquet(pl(&fpath), Default::default())
        .and_then(|lf| {
            let mut cols = vec![col("take"), col("frame")];
            cols.extend(stats.features.iter().map(|f| col(f.as_str())));
            lf.select(cols).collect()
        })
        .map_err(|e| read_err(&fpath, e))?;

    let offsets = take_offsets(&frames, &fpath)?;
    let nf = stats.features.len();
    let cols = normalised_columns(&frames, &stats, &fpath)?;

    let wt = column(&windows, "take", &wpath, |c| c.str().cloned())?;
    let ws = column(&windows, "start", &wpath, |c| c.u32().cloned())?;
    let wl = column(&windows, "length", &wpath, |c| c.u32().cloned())?;
    let wsplit = column(&windows, "split", &wpath, |c| c.str().cloned())?;
    let take_category = take_categories(dir)?;
    let mut out: HashMap<String, Windows> = HashMap::new();
    let mut categories: HashMap<String, Vec<Category>> = HashMap::new();
    let mut takes: HashMap<String, Vec<String>> = HashMap::new();
    for i in 0..windows.height() {
        let (Some(take), Some(start), Some(len), Some(split)) =
            (wt.get(i), ws.get(i), wl.get(i), wsplit.get(i))
        else {
            return Err(DataError::Invalid(format!(
                "{}: null value in row {i}",
                wpath.display()
            )));
        };
        if !splits.contains(&split) {
            continue;
        }
        let (off, n) = *offsets
            .get(take)
            .ok_or_else(|| DataError::Invalid(format!("window of unknown take {take}")))?;
        let (start, len) = (start as usize, len as usize);
        if start + len > n {
            return Err(DataError::Invalid(format!(
                "window {take}@{start}+{len} exceeds the take ({n} frames)"
            )));
        }
        let w = out.entry(split.to_string()).or_insert(Windows {
            data: Vec::new(),
            n: 0,
            length: len,
            features: nf,
        });
        if w.length != len {
            return Err(DataError::Invalid(
                "windows of different lengths in one split".into(),
            ));
        }
        for r in off + start..off + start + len {
            w.data.extend(cols.iter().map(|c| c[r]));
        }
        w.n += 1;
        let category = if take_category.is_empty() {
            Category::Other
        } else {
            *take_category.get(take).ok_or_else(|| {
                DataError::Invalid(format!("window of take {take}, which takes.parquet lacks"))
            })?
        };
        categories
            .entry(split.to_string())
            .or_default()
            .push(category);
        takes
            .entry(split.to_string())
            .or_default()
            .push(take.to_string());
    }
    if let Some(bad) = out.values().flat_map(|w| &w.data).find(|v| !v.is_finite()) {
        return Err(DataError::Invalid(format!(
            "non-finite feature value {bad} in {}",
            fpath.display()
        )));
    }
    Ok(Dataset {
        dir: dir.to_path_buf(),
        stats,
        manifest_sha256: manifest,
        splits: out,
        categories,
        takes,
    })
}
