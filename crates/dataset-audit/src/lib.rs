//! Audit a dataset directory written by `cargo xtask dataset` (see
//! `docs/audit.md`). Every check yields a [`Check`]; the report fails if any
//! check fails. Data-quality findings are listed per take.

pub mod markdown;

use mocap_ingest::category::Category;
use mocap_ingest::dataset::{
    build_dataset, manifest_warnings, sha256_hex, DatasetOptions, Encoding, NoProgress, SplitBy,
    Stats, SPLITS,
};
use mocap_ingest::features::{feature_names, ANG_VEL_Y, VEL_X, VEL_Z};
use mocap_ingest::skeleton::{JOINT_NAMES, JOINT_PARENTS, NUM_JOINTS};
use mocap_ingest::source::Source;
use polars::prelude::*;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
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

const OUTPUTS: [&str; 5] = [
    "frames.parquet",
    "takes.parquet",
    "windows.parquet",
    "stats.json",
    "skipped.json",
];

fn path_str(p: &Path) -> PlRefPath {
    PlRefPath::new(p.to_string_lossy().into_owned())
}

fn scan(p: &Path) -> PolarsResult<LazyFrame> {
    LazyFrame::scan_parquet(path_str(p), Default::default())
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
    if !readable {
        return Ok(r);
    }
    if let Err(e) = checks_on_tables(dir, &manifest, &mut r) {
        r.check("integrity", "tables readable", false, e.to_string());
        return Ok(r);
    }

    // ---- Reproducibility.
    if !rebuild.sources.is_empty() {
        reproduce(dir, rebuild, &manifest, &mut r);
    }
    Ok(r)
}

fn checks_on_tables(dir: &Path, manifest: &serde_json::Value, r: &mut Report) -> PolarsResult<()> {
    // Schemas.
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
            return Ok(());
        }
    }
    let frames = scan(&dir.join("frames.parquet"))?;
    let takes = scan(&dir.join("takes.parquet"))?;
    let windows = scan(&dir.join("windows.parquet"))?;
    let names = feature_names();

    // No NaN or infinite values.
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

    // Every window inside its take.
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

    // Frames per take agree with takes.parquet.
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

    // Counts against the manifest.
    let counts = &manifest["counts"];
    let n_takes = takes.clone().select([len()]).collect()?;
    let n_frames = frames.clone().select([len()]).collect()?;
    let got_split = counts_by(&windows, "split")?;
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
    // Takes kept from files cut short: each in takes.parquet with the
    // frames the warning says were kept (none in a format 2 manifest).
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

    // ---- Split hygiene.
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
    let achieved: BTreeMap<String, f64> = counts_by(&takes, "split")?
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

    if takes.clone().collect_schema()?.contains("category") {
        category_windows(&takes, &windows, r)?;
    }
    statistics(dir, &frames, &windows, r)?;
    quality(
        &frames,
        manifest["options"]["fps"].as_f64().unwrap_or(30.0),
        r,
    )?;
    Ok(())
}

/// Windows per category and split, every known category listed (then any
/// other name found); a category with train windows but no test windows gets
/// a note (the test set cannot tell how the model does on it).
fn category_windows(takes: &LazyFrame, windows: &LazyFrame, r: &mut Report) -> PolarsResult<()> {
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

/// Recompute the normalisation statistics with polars and compare.
fn statistics(
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
    // Multiplicity of each frame in the train windows: built per take from the
    // windows table, then joined onto the frames table.
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
    let mdf = DataFrame::new_infer_height(vec![
        Column::from(Series::new("take".into(), mt)),
        Column::from(Series::new("frame".into(), mf)),
        Column::from(Series::new("w".into(), mw)),
    ])?;
    let weighted = frames.clone().join(
        mdf.lazy(),
        [col("take"), col("frame")],
        [col("take"), col("frame")],
        JoinArgs::new(JoinType::Inner),
    );
    let mut aggs = vec![col("w").sum().alias("__n")];
    for n in &names {
        let x = col(n.as_str()).cast(DataType::Float64);
        aggs.push((x.clone() * col("w")).sum().alias(format!("{n}__s1")));
        aggs.push((x.clone() * x * col("w")).sum().alias(format!("{n}__s2")));
    }
    let sums = weighted.select(aggs).collect()?;
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

/// Per-take data quality: duration, root speed, bone lengths, foot height.
fn quality(frames: &LazyFrame, fps: f64, r: &mut Report) -> PolarsResult<()> {
    let names = feature_names();
    let joint_col = |j: usize, c: usize| names[1 + 3 * (j - 1) + c].clone();
    // Derived columns with polars expressions: squared speed, squared bone
    // lengths (local frame is rigid, so lengths are those of the global pose),
    // lower toe height.
    let pos = |j: usize, c: usize| -> Expr {
        if j == 0 {
            if c == 1 {
                col("root_y").cast(DataType::Float64)
            } else {
                lit(0.0)
            }
        } else {
            col(joint_col(j, c).as_str()).cast(DataType::Float64)
        }
    };
    let mut exprs = vec![
        col("take"),
        (col(names[VEL_X].as_str()).cast(DataType::Float64).pow(2)
            + col(names[VEL_Z].as_str()).cast(DataType::Float64).pow(2))
        .alias("speed2"),
        col(names[ANG_VEL_Y].as_str()),
    ];
    let toe_l = JOINT_NAMES
        .iter()
        .position(|n| *n == "LeftToeBase")
        .unwrap_or(4);
    let toe_r = JOINT_NAMES
        .iter()
        .position(|n| *n == "RightToeBase")
        .unwrap_or(8);
    exprs.push(pos(toe_l, 1).alias("toe_l"));
    exprs.push(pos(toe_r, 1).alias("toe_r"));
    for (j, parent) in JOINT_PARENTS.iter().enumerate() {
        if let Some(p) = *parent {
            let d2 = (0..3)
                .map(|c| (pos(j, c) - pos(p, c)).pow(2))
                .reduce(|a, b| a + b)
                .unwrap_or(lit(0.0));
            exprs.push(d2.alias(format!("bone{j}")));
        }
    }
    let derived = frames.clone().select(exprs).collect()?;
    // Per-frame vectors for the histograms.
    let to_f = fps * METRES_PER_UNIT;
    let sp = derived.column("speed2")?.f64()?.clone();
    r.speeds = sp
        .iter()
        .map(|v| v.unwrap_or(f64::NAN).sqrt() * to_f)
        .collect();
    let tl = derived.column("toe_l")?.f64()?.clone();
    let tr = derived.column("toe_r")?.f64()?.clone();
    r.toe_heights = tl
        .iter()
        .zip(tr.iter())
        .map(|(a, b)| a.unwrap_or(f64::NAN).min(b.unwrap_or(f64::NAN)))
        .collect();
    // Aggregates per take with polars.
    let mut aggs = vec![
        len().alias("n"),
        col("speed2").mean().alias("speed2_mean"),
        col("speed2").max().alias("speed2_max"),
        col("toe_l").min().alias("toe_l_min"),
        col("toe_r").min().alias("toe_r_min"),
    ];
    let bones: Vec<usize> = (1..NUM_JOINTS)
        .filter(|j| JOINT_PARENTS[*j].is_some())
        .collect();
    for j in &bones {
        let b = col(format!("bone{j}").as_str()).sqrt();
        aggs.push(b.clone().mean().alias(format!("b{j}_mean")));
        aggs.push(b.std(0).alias(format!("b{j}_std")));
    }
    let mut with_lower = derived.lazy().with_column(
        when(col("toe_l").lt(col("toe_r")))
            .then(col("toe_l"))
            .otherwise(col("toe_r"))
            .alias("toe_low"),
    );
    aggs.push(col("toe_low").mean().alias("toe_low_mean"));
    with_lower = with_lower
        .group_by([col("take")])
        .agg(aggs)
        .sort(["take"], Default::default());
    let per = with_lower.collect()?;
    let f = |c: &str, i: usize| {
        per.column(c)
            .ok()
            .and_then(|c| c.get(i).ok())
            .and_then(|v| v.extract::<f64>())
            .unwrap_or(f64::NAN)
    };
    let takes = per.column("take")?.str()?.clone();
    let th = r.thresholds.clone();
    for i in 0..per.height() {
        let bone_cv = bones
            .iter()
            .map(|j| f(&format!("b{j}_std"), i) / f(&format!("b{j}_mean"), i).max(1e-9))
            .fold(0.0, f64::max);
        let q = TakeQuality {
            take: takes.get(i).unwrap_or("?").to_string(),
            seconds: f("n", i) / fps,
            mean_speed: f("speed2_mean", i).sqrt() * to_f,
            max_speed: f("speed2_max", i).sqrt() * to_f,
            bone_cv,
            min_toe: f("toe_l_min", i).min(f("toe_r_min", i)),
            mean_toe: f("toe_low_mean", i),
            flags: Vec::new(),
        };
        let mut flags = Vec::new();
        if q.mean_speed > th.mean_speed {
            flags.push(format!(
                "root speed {:.1} m/s on average: a wrong (too low) frame rate?",
                q.mean_speed
            ));
        }
        if q.max_speed > th.max_speed {
            flags.push(format!(
                "root jumps: {:.1} m/s at its fastest frame",
                q.max_speed
            ));
        }
        if q.bone_cv > th.bone_cv {
            flags.push(format!("bone lengths change by {:.1}%", 100.0 * q.bone_cv));
        }
        if q.min_toe > th.min_toe {
            flags.push(format!(
                "never touches the floor: lowest toe {:.1} units up",
                q.min_toe
            ));
        }
        if q.min_toe < th.sink_toe {
            flags.push(format!(
                "stands below its first frame's floor: lowest toe {:.1} units down \
                 (the take starts raised, or the ground is uneven)",
                -q.min_toe
            ));
        }
        r.takes.push(TakeQuality { flags, ..q });
    }
    Ok(())
}

/// Rebuild the dataset with the manifest's options and compare bytes.
fn reproduce(dir: &Path, rebuild: &Rebuild, manifest: &serde_json::Value, r: &mut Report) {
    let o = &manifest["options"];
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
    let tmp = std::env::temp_dir().join(format!("dataset-audit-{}", std::process::id()));
    let out = tmp.join("rebuild");
    let result = (|| -> Result<(), String> {
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
        build_dataset(&srcs, &labels, &out, &opts, &NoProgress).map_err(|e| e.to_string())?;
        Ok(())
    })();
    match result {
        Err(e) => r.check("reproducibility", "rebuild from --source", false, e),
        Ok(()) => {
            let mut first_diff = None;
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
                    first_diff = Some(match row {
                        Some((row, c)) => format!("{f} differs first at row {row}, column {c}"),
                        None => format!("{f} differs"),
                    });
                    break;
                }
            }
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
