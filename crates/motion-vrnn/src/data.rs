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

/// Where each feature of the left–right mirror image of a frame comes
/// from: `(source, sign)` per feature, by name (`docs/features.md`,
/// "Mirrored windows"). A joint's mirror is its other side's (`Left*` ↔
/// `Right*`, the others themselves) with its local x negated, since the
/// mirrored figure's local frame is the original's reflected; `vel_x` and
/// `ang_vel_y` change sign, `root_y` and `vel_z` stay. `None` when a
/// feature has no mirror among `features` (an unknown name, or a side
/// without its other).
pub fn mirror_map(features: &[String]) -> Option<Vec<(usize, f32)>> {
    features
        .iter()
        .map(|name| {
            let sign = if name.ends_with("_x") || name == "ang_vel_y" {
                -1.0
            } else {
                1.0
            };
            let other = if let Some(rest) = name.strip_prefix("Left") {
                format!("Right{rest}")
            } else if let Some(rest) = name.strip_prefix("Right") {
                format!("Left{rest}")
            } else {
                name.clone()
            };
            // Every feature is a coordinate (`root_y`, `vel_x`, … too).
            let known = ["_x", "_y", "_z"].iter().any(|c| name.ends_with(c));
            let source = features.iter().position(|f| *f == other)?;
            known.then_some((source, sign))
        })
        .collect()
}

impl Windows {
    /// The windows' left–right mirror images ([`mirror_map`]), normalised
    /// with the same `stats`: a mirrored walk is a walk with the other foot
    /// first, turning the other way.
    pub fn mirrored(&self, stats: &Stats) -> Result<Windows, DataError> {
        let map = mirror_map(&stats.features)
            .filter(|m| m.len() == self.features)
            .ok_or_else(|| {
                DataError::Invalid(
                    "the dataset's features have no left-right mirror (docs/features.md)".into(),
                )
            })?;
        let (mean, std): (Vec<f32>, Vec<f32>) = (
            stats.mean.iter().map(|&v| v as f32).collect(),
            stats.std.iter().map(|&v| v as f32).collect(),
        );
        let data = self
            .data
            .chunks_exact(self.features)
            .flat_map(|row| {
                map.iter()
                    .enumerate()
                    .map(|(i, &(j, sign))| (sign * (row[j] * std[j] + mean[j]) - mean[i]) / std[i])
            })
            .collect();
        Ok(Windows { data, ..*self })
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

    // Row offset of each take's frame 0 (frames are stored by take, then frame).
    let takes = column(&frames, "take", &fpath, |c| c.str().cloned())?;
    let frame_idx = column(&frames, "frame", &fpath, |c| c.u32().cloned())?;
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
    let nf = stats.features.len();
    let mut cols: Vec<Vec<f32>> = Vec::with_capacity(nf);
    for (i, name) in stats.features.iter().enumerate() {
        let c = column(&frames, name, &fpath, |c| c.f32().cloned())?;
        let (m, s) = (stats.mean[i] as f32, stats.std[i] as f32);
        cols.push(c.iter().map(|v| (v.unwrap_or(f32::NAN) - m) / s).collect());
    }

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

#[cfg(test)]
mod tests {
    use super::*;
    use mocap_ingest::features::{compute_features, feature_names};
    use mocap_ingest::{Pose, JOINT_NAMES};

    /// A figure whose sides differ (arms raised unevenly, one knee bent),
    /// turning and walking: frame `t` of 12.
    fn pose(t: usize) -> Pose {
        let rest: [[f64; 3]; 19] = [
            [0.0, 17.0, 0.0],
            [-1.8, 16.0, 0.2],
            [-2.0, 9.0, 1.5],
            [-2.1, 1.5, 0.0],
            [-2.2, 0.2, 2.0],
            [1.9, 16.1, -0.1],
            [2.2, 9.2, -0.4],
            [2.0, 1.4, -0.8],
            [2.3, 0.3, 1.2],
            [0.1, 20.0, -0.2],
            [0.0, 23.0, 0.1],
            [0.2, 27.0, 0.3],
            [0.3, 29.5, 0.9],
            [-3.0, 26.0, 0.0],
            [-5.5, 27.5, 2.0],
            [-6.0, 30.0, 4.0],
            [3.1, 25.8, 0.2],
            [5.0, 22.0, -0.5],
            [5.2, 18.5, 1.0],
        ];
        let (a, t) = (0.1 + 0.07 * t as f64, t as f64);
        let (c, s) = (a.cos(), a.sin());
        rest.map(|[x, y, z]| {
            [
                c * x + s * z + 0.4 * t,
                y + 0.05 * t,
                -s * x + c * z + 0.9 * t,
            ]
        })
    }

    /// The world reflected in x, each side's joint in its other's place.
    fn reflected(p: &Pose) -> Pose {
        let other = |j: usize| {
            let name = JOINT_NAMES[j];
            let swapped = match name.strip_prefix("Left") {
                Some(rest) => format!("Right{rest}"),
                None => name.replacen("Right", "Left", 1),
            };
            JOINT_NAMES.iter().position(|n| **n == swapped).unwrap()
        };
        std::array::from_fn(|j| {
            let [x, y, z] = p[other(j)];
            [-x, y, z]
        })
    }

    #[test]
    fn the_mirror_map_is_the_features_of_the_reflected_figure() {
        let names = feature_names();
        let map = mirror_map(&names).expect("the 58 features have a mirror");
        assert_eq!(map[0], (0, 1.0), "root_y");
        assert_eq!(map[1], (13, -1.0), "LeftUpLeg_x from RightUpLeg_x");
        assert_eq!(map[14], (2, 1.0), "RightUpLeg_y from LeftUpLeg_y");
        assert_eq!(map[25], (25, -1.0), "Spine_x");
        assert_eq!(map[55..], [(55, -1.0), (56, 1.0), (57, -1.0)]);
        let poses: Vec<Pose> = (0..12).map(pose).collect();
        let mirrored: Vec<Pose> = poses.iter().map(reflected).collect();
        let (f, g) = (
            compute_features(&poses).unwrap(),
            compute_features(&mirrored).unwrap(),
        );
        for (a, b) in f.iter().zip(&g) {
            for (i, &(j, sign)) in map.iter().enumerate() {
                let want = sign as f64 * a[j];
                assert!(
                    (b[i] - want).abs() < 1e-9,
                    "{}: {} vs {want}",
                    names[i],
                    b[i]
                );
            }
        }
        // The figure turns, so the turn's sign is tested on non-zero values.
        assert!(f[3][57].abs() > 0.05);
    }

    #[test]
    fn mirrored_windows_are_normalised_and_twice_mirrored_is_the_same() {
        let features = feature_names();
        let n = features.len();
        let stats = Stats {
            mean: (0..n).map(|i| 0.5 + i as f64 * 0.1).collect(),
            std: (0..n).map(|i| 1.0 + i as f64 * 0.05).collect(),
            std_raw: vec![1.0; n],
            std_floor: 0.0,
            floored: Vec::new(),
            count: 6,
            features,
        };
        let w = Windows {
            data: (0..2 * 3 * n)
                .map(|i| ((i * 37) % 11) as f32 * 0.3 - 1.5)
                .collect(),
            n: 2,
            length: 3,
            features: n,
        };
        let m = w.mirrored(&stats).unwrap();
        // Hand-computed: LeftUpLeg_x (1) from RightUpLeg_x (13), negated.
        let raw13 = w.data[13] * stats.std[13] as f32 + stats.mean[13] as f32;
        let want = (-raw13 - stats.mean[1] as f32) / stats.std[1] as f32;
        assert!((m.data[1] - want).abs() < 1e-5);
        let back = m.mirrored(&stats).unwrap();
        for (a, b) in w.data.iter().zip(&back.data) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
        let unknown = Stats {
            features: vec!["a".into(); n],
            ..stats
        };
        assert!(w.mirrored(&unknown).is_err());
    }
}
