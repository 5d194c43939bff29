//! Frame rates of CMU trials and resampling to the target rate.
//!
//! CMU captured most trials at 120 fps and some at 60 fps; the cgspeed BVH
//! files say 120 for all of them, and AMC files say nothing. The project ships
//! its own table of the 60 fps trials (`data/cmu-60fps-takes.txt`); users can
//! add or override entries.
//!
//! Resampling keeps every k-th frame, starting with the first, where
//! `k = source / target` must be a whole number (120 → 30: every 4th, 60 → 30:
//! every 2nd). Any other ratio is refused with
//! [`ErrorKind::UnsupportedFrameRate`]: interpolating joint positions would
//! shorten bones, and CMU has no such rates.

use crate::error::ErrorKind;
use std::collections::HashMap;
use std::path::Path;

/// The project's table of 60 fps CMU takes, one take id per line.
pub const CMU_60FPS_TAKES: &str = include_str!("../../../data/cmu-60fps-takes.txt");

/// The rate CMU used for every trial not listed as 60 fps.
pub const CMU_DEFAULT_FPS: f64 = 120.0;

/// Frame rate of each take, by take id (`SUBJECT_TRIAL`, e.g. `02_01`).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRateTable {
    rates: HashMap<String, f64>,
}

impl Default for FrameRateTable {
    /// The built-in CMU table.
    fn default() -> Self {
        let rates = CMU_60FPS_TAKES
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .map(|l| (l.to_string(), 60.0))
            .collect();
        FrameRateTable { rates }
    }
}

impl FrameRateTable {
    /// A table with no entries.
    pub fn empty() -> Self {
        FrameRateTable {
            rates: HashMap::new(),
        }
    }

    /// Set the rate of one take (overrides the table).
    pub fn set(&mut self, take: &str, fps: f64) {
        self.rates.insert(take.to_string(), fps);
    }

    /// The rate listed for `take`, if any.
    pub fn get(&self, take: &str) -> Option<f64> {
        self.rates.get(take).copied()
    }

    /// All entries (take id, fps), in no particular order.
    pub fn entries(&self) -> impl Iterator<Item = (&str, f64)> {
        self.rates.iter().map(|(k, v)| (k.as_str(), *v))
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.rates.len()
    }

    /// Whether the table has no entries.
    pub fn is_empty(&self) -> bool {
        self.rates.is_empty()
    }

    /// Add entries from CSV text with `take,fps` rows (a header row and `#`
    /// comments are skipped; extra columns are ignored), overriding existing
    /// entries. CMU's `trials.csv` (`take,subject,trial,fps,…`) also works: the
    /// `fps` column is found by its header.
    pub fn merge_csv(&mut self, text: &str) -> Result<usize, String> {
        let mut fps_col = 1;
        let mut added = 0;
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let cols: Vec<&str> = line.split(',').map(str::trim).collect();
            if i == 0 || cols.get(fps_col).is_some_and(|c| c.parse::<f64>().is_err()) {
                if let Some(c) = cols.iter().position(|c| c.eq_ignore_ascii_case("fps")) {
                    fps_col = c;
                    continue;
                }
            }
            let fps: f64 = cols
                .get(fps_col)
                .and_then(|c| c.parse().ok())
                .filter(|f: &f64| f.is_finite() && *f > 0.0)
                .ok_or_else(|| format!("line {}: expected `take,fps`, found {line:?}", i + 1))?;
            self.set(cols[0], fps);
            added += 1;
        }
        Ok(added)
    }

    /// Load overrides from a CSV file (see [`FrameRateTable::merge_csv`]).
    pub fn merge_csv_file(&mut self, path: &Path) -> Result<usize, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        self.merge_csv(&text)
            .map_err(|e| format!("{}: {e}", path.display()))
    }

    /// The rate to use for a take: the table's entry; else, for a CMU take
    /// id, 120 fps; else the rate the file states; else 120 fps.
    pub fn resolve(&self, take: &str, declared: Option<f64>) -> f64 {
        if let Some(f) = self.get(take) {
            return f;
        }
        if is_cmu_take_id(take) {
            return CMU_DEFAULT_FPS;
        }
        declared.unwrap_or(CMU_DEFAULT_FPS)
    }
}

/// Whether `s` looks like a CMU take id (`NN_MM`, digits on both sides).
pub fn is_cmu_take_id(s: &str) -> bool {
    match s.split_once('_') {
        Some((a, b)) => {
            !a.is_empty()
                && !b.is_empty()
                && a.bytes().all(|c| c.is_ascii_digit())
                && b.bytes().all(|c| c.is_ascii_digit())
        }
        None => false,
    }
}

/// The source frames kept when resampling `num_frames` frames from
/// `source_fps` to `target_fps`: `0, k, 2k, …` with `k = source / target`.
pub fn resample_indices(
    num_frames: usize,
    source_fps: f64,
    target_fps: f64,
) -> Result<Vec<usize>, ErrorKind> {
    let ratio = source_fps / target_fps;
    let k = ratio.round();
    let refuse = || ErrorKind::UnsupportedFrameRate {
        source_fps,
        target_fps,
    };
    if !(ratio.is_finite() && k >= 1.0) || (ratio - k).abs() > 1e-3 * k {
        return Err(refuse());
    }
    Ok((0..num_frames).step_by(k as usize).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_keeps_every_kth_frame() {
        assert_eq!(resample_indices(9, 120.0, 30.0).unwrap(), vec![0, 4, 8]);
        assert_eq!(resample_indices(8, 120.0, 30.0).unwrap(), vec![0, 4]);
        assert_eq!(resample_indices(5, 60.0, 30.0).unwrap(), vec![0, 2, 4]);
        assert_eq!(resample_indices(3, 30.0, 30.0).unwrap(), vec![0, 1, 2]);
        // The cgspeed frame time .0083333 s is 120.0005 fps.
        assert_eq!(
            resample_indices(5, 1.0 / 0.0083333, 30.0).unwrap(),
            vec![0, 4]
        );
        assert!(matches!(
            resample_indices(10, 100.0, 30.0),
            Err(ErrorKind::UnsupportedFrameRate { .. })
        ));
        assert!(resample_indices(10, 24.0, 30.0).is_err());
    }

    #[test]
    fn table_knows_cmu_rates_and_takes_overrides() {
        let mut t = FrameRateTable::default();
        assert_eq!(t.resolve("33_01", Some(120.0)), 60.0);
        assert_eq!(t.resolve("02_01", Some(120.0)), 120.0);
        assert_eq!(t.resolve("02_01", None), 120.0);
        assert_eq!(t.resolve("my_walk", Some(24.0)), 24.0);
        assert_eq!(t.resolve("my-walk", None), 120.0);
        t.merge_csv("take,subject,trial,fps,description\n02_01,2,1,60,walk\n")
            .unwrap();
        assert_eq!(t.resolve("02_01", None), 60.0);
        t.merge_csv("02_01,120\n").unwrap();
        assert_eq!(t.resolve("02_01", None), 120.0);
        assert!(t.merge_csv("02_01,fast\n").is_err());
    }
}
