//! A whole collection → the training dataset (see `docs/dataset.md`):
//! `frames.parquet`, `takes.parquet`, `windows.parquet`, `stats.json`,
//! `skipped.json` and `manifest.json`, written atomically into one directory.
//!
//! Determinism: takes are processed in parallel in fixed-size chunks, but
//! results are consumed in take order, so the bytes written never depend on
//! the thread count. The split of a take (or subject) is a hash of the seed
//! and its id, so adding a take never moves another.

mod read;
mod report;
#[cfg(test)]
mod tests;
mod write;

use crate::category::Category;
use crate::source::{FileRef, Source};
use crate::Options;
use read::{read_all, stats_of, Copy, Group, Tally};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use write::{manifest, write_err, write_json, write_takes, write_windows};

/// Version of the dataset layout written here (2: take ids from paths for
/// non-CMU names, `take` and `kept` in `skipped.json`, Zstandard; 3: files
/// cut short keep their complete frames, `warnings` and `options.strict` in
/// the manifest; 4: `category` and `description` in `takes.parquet`,
/// `options.categories` in the manifest).
pub const FORMAT_VERSION: u32 = 4;

/// The three splits, in this order everywhere.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];

/// Every file the dataset stage writes into its directory (`docs/dataset.md`).
pub const FILES: [&str; 6] = [
    "frames.parquet",
    "takes.parquet",
    "windows.parquet",
    "stats.json",
    "skipped.json",
    "manifest.json",
];

/// What a split is decided by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SplitBy {
    /// Each take independently.
    Take,
    /// All takes of a subject together.
    Subject,
}

/// How the Parquet tables are compressed and how their float columns are
/// encoded (`dataset --encoding`; docs/dataset.md compares them). The default,
/// Zstandard with byte-stream-split floats, makes `frames.parquet` 25%
/// smaller than Snappy with plain floats (137 vs 182 MB at the size of the
/// full CMU database); pyarrow and polars read both.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    /// Snappy, plain floats (format 1's choice).
    Snappy,
    /// Snappy, floats byte-stream-split.
    SnappyByteStreamSplit,
    /// Zstandard (level 1), plain floats.
    Zstd,
    /// Zstandard (level 1), floats byte-stream-split.
    ZstdByteStreamSplit,
}

impl Encoding {
    /// Every encoding, for the benchmark.
    pub const ALL: [Encoding; 4] = [
        Encoding::Snappy,
        Encoding::SnappyByteStreamSplit,
        Encoding::Zstd,
        Encoding::ZstdByteStreamSplit,
    ];

    /// Its name (as in the manifest).
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Snappy => "snappy",
            Encoding::SnappyByteStreamSplit => "snappy_byte_stream_split",
            Encoding::Zstd => "zstd",
            Encoding::ZstdByteStreamSplit => "zstd_byte_stream_split",
        }
    }

    /// The encoding of a name.
    pub fn from_name(name: &str) -> Option<Encoding> {
        Encoding::ALL.into_iter().find(|e| e.name() == name)
    }
}

/// Options of a dataset build (the paper's values by default).
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetOptions {
    /// Per-take pipeline options (target fps, frame rates, ASF skeleton).
    pub ingest: Options,
    /// Window length in frames (paper: 128).
    pub window: usize,
    /// Window stride in frames (paper: 64).
    pub stride: usize,
    /// Train/val/test fractions (sum 1).
    pub fractions: [f64; 3],
    /// Seed of the split.
    pub seed: u64,
    /// Split by take or by subject.
    pub split_by: SplitBy,
    /// Lower bound applied to every feature's standard deviation.
    pub std_floor: f64,
    /// Take ids left out (see [`parse_exclude_list`]); their files are not read.
    pub exclude: BTreeSet<String>,
    /// The user's categories (`--categories FILE`, see
    /// [`crate::category::parse_user_categories`]): they win over the built-in
    /// CMU table; a take in neither is `other`.
    pub categories: BTreeMap<String, Category>,
    /// Compression and float encoding of the tables.
    pub encoding: Encoding,
    /// Skip files that end inside their motion (code `truncated`) instead
    /// of keeping their complete frames with a warning.
    pub strict: bool,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        DatasetOptions {
            ingest: Options::default(),
            window: 128,
            stride: 64,
            fractions: [0.8, 0.1, 0.1],
            seed: 0,
            split_by: SplitBy::Take,
            std_floor: 1e-3,
            exclude: BTreeSet::new(),
            categories: BTreeMap::new(),
            encoding: Encoding::ZstdByteStreamSplit,
            strict: false,
        }
    }
}

/// Parse an exclude list: one take id per line; `#` starts a comment (a whole
/// line or the rest of one); blank lines are ignored; ids are trimmed.
/// `cargo xtask audit` writes its `flagged.txt` in this format.
pub fn parse_exclude_list(text: &str) -> BTreeSet<String> {
    text.lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty())
        .map(str::to_string)
        .collect()
}

/// A failure that stops the whole build (per-file problems never do).
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// Invalid options.
    #[error("invalid options: {0}")]
    Options(String),
    /// A collection could not be listed.
    #[error(transparent)]
    Source(#[from] crate::source::SourceError),
    /// Writing the output failed.
    #[error("{path}: {message}")]
    Write {
        /// The file or directory.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// Nothing usable came out.
    #[error("empty dataset: none of the {files} motion files gave any frames (see the skipped files above)")]
    Empty {
        /// Motion files seen.
        files: usize,
    },
}

/// A file that did not make it into the dataset.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Skipped {
    /// The file.
    pub file: String,
    /// The take it holds.
    pub take: String,
    /// Short reason code (`truncated`, `missing_asf`, `duplicate_take`,
    /// `duplicate_file`, `excluded`, …).
    pub code: String,
    /// The full message.
    pub message: String,
    /// The copy of the same take that was kept instead, if any.
    pub kept: Option<String>,
}

/// A take in the dataset with something to know about it (`manifest.json`'s
/// `warnings`, in take order).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct Warning {
    /// The file the take was read from.
    pub file: String,
    /// The take.
    pub take: String,
    /// What: `truncated` (the file ends inside its motion; its complete
    /// frames were kept).
    pub kind: String,
    /// Motion frames kept (the take's `native_frames`).
    pub frames_kept: usize,
    /// Motion frames the file was to hold (a BVH's `Frames:`, an AMC's
    /// number of the frame it ends in; a BVH T-pose frame not counted).
    pub frames_expected: usize,
    /// The full message.
    pub message: String,
}

impl Warning {
    /// The warning for a take kept from a file cut short.
    pub fn truncated(file: &str, take: &str, t: &crate::Truncation) -> Warning {
        Warning {
            file: file.to_string(),
            take: take.to_string(),
            kind: "truncated".into(),
            frames_kept: t.frames_kept(),
            frames_expected: t.frames_expected(),
            message: format!(
                "{file}: the file ends inside its motion (line {}): kept its {} complete frames of {}",
                t.line,
                t.frames_kept(),
                t.frames_expected()
            ),
        }
    }
}

/// The `warnings` of a dataset's `manifest.json` (none in a manifest written
/// before they existed, format 2).
pub fn manifest_warnings(manifest: &serde_json::Value) -> Result<Vec<Warning>, String> {
    match manifest.get("warnings") {
        None | Some(serde_json::Value::Null) => Ok(Vec::new()),
        Some(w) => Vec::<Warning>::deserialize(w).map_err(|e| format!("manifest warnings: {e}")),
    }
}

/// Takes that came in more than one copy (the same CMU trial in several
/// files) and which copy was kept.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Duplicates {
    /// Takes with more than one copy.
    pub takes: usize,
    /// Of those, kept copies by format (`amc`, `bvh`).
    pub kept_by_format: BTreeMap<String, usize>,
    /// Takes whose preferred copy failed and a later copy was kept.
    pub fell_back: usize,
    /// Copies that read but were retargeted (Daz-friendly) and yielded to a
    /// later copy with the subject's own skeleton.
    pub superseded: usize,
    /// Copies that read but end inside their motion, and yielded to a
    /// complete copy (or to a copy read before them).
    pub truncated_yielded: usize,
    /// Copies never read because an earlier copy was kept.
    pub unread: usize,
}

/// What a build did.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct BuildSummary {
    /// Motion files found.
    pub files: usize,
    /// Takes written.
    pub takes: usize,
    /// Files skipped, with reasons.
    pub skipped: Vec<Skipped>,
    /// Input frames at the native rate, over the takes written.
    pub native_frames: usize,
    /// Frames written (target rate).
    pub frames: usize,
    /// Takes shorter than one window (written, but they give no windows).
    pub short_takes: usize,
    /// Takes per split.
    pub takes_per_split: [usize; 3],
    /// Windows per split.
    pub windows_per_split: [usize; 3],
    /// Bytes of input read (motion and skeleton files).
    pub input_bytes: u64,
    /// Takes written per format and skeleton (`bvh` / `Daz-friendly BVH`).
    pub takes_by_skeleton: BTreeMap<(String, String), usize>,
    /// Takes in several copies.
    pub duplicates: Duplicates,
    /// Files left out by the exclude list.
    pub excluded: usize,
    /// Ids of the exclude list that matched no take.
    pub exclude_unmatched: Vec<String>,
    /// Takes written with a warning (files cut short), in take order.
    pub warnings: Vec<Warning>,
}

/// Per-feature statistics of the train split.
#[derive(Clone, Debug, Serialize, serde::Deserialize, PartialEq)]
pub struct Stats {
    /// Feature names, in column order.
    pub features: Vec<String>,
    /// Mean of each feature over the train windows' frames.
    pub mean: Vec<f64>,
    /// Standard deviation after the floor (what to divide by).
    pub std: Vec<f64>,
    /// Standard deviation before the floor.
    pub std_raw: Vec<f64>,
    /// The floor applied to `std`.
    pub std_floor: f64,
    /// Features whose std was raised to the floor.
    pub floored: Vec<String>,
    /// Frames counted (with multiplicity: a frame in two windows counts twice).
    pub count: u64,
}

/// Split of a key (take or subject id): a hash of the seed and the key, so it
/// never depends on the other keys.
pub fn split_of(key: &str, seed: u64, fractions: [f64; 3]) -> usize {
    let mut h = Sha256::new();
    h.update(seed.to_le_bytes());
    h.update(key.as_bytes());
    let d = h.finalize();
    let mut b = [0u8; 8];
    b.copy_from_slice(&d[..8]);
    let u = (u64::from_le_bytes(b) >> 11) as f64 / (1u64 << 53) as f64;
    if u < fractions[0] {
        0
    } else if u < fractions[0] + fractions[1] {
        1
    } else {
        2
    }
}

/// Start frames of the windows of a take with `frames` frames.
pub fn window_starts(frames: usize, window: usize, stride: usize) -> Vec<usize> {
    if frames < window {
        return Vec::new();
    }
    (0..=frames - window).step_by(stride).collect()
}

/// Hex SHA-256 of bytes.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Progress events for a caller's progress bar.
pub trait Progress: Sync {
    /// Called once with the number of motion files.
    fn start(&self, files: usize);
    /// Called after each file, in completion order.
    fn file_done(&self, file: &str, ok: bool);
}

/// No progress output.
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _: usize) {}
    fn file_done(&self, _: &str, _: bool) {}
}

/// Build the dataset from `sources` into `out`, atomically: `out` ends up
/// either as it was or as the complete new dataset.
pub fn build_dataset(
    sources: &[Source],
    source_labels: &[String],
    out: &Path,
    opts: &DatasetOptions,
    progress: &dyn Progress,
) -> Result<BuildSummary, DatasetError> {
    validate(opts)?;
    let copies = list_copies(sources)?;
    let files = copies.len();
    let mut summary = BuildSummary {
        files,
        ..Default::default()
    };
    progress.start(files);
    let copies = leave_out_excluded(copies, opts, &mut summary, progress);
    let groups = group_copies(copies);
    let staging = make_staging(out)?;
    let result = write_all(
        &groups,
        fallback_asf_name(sources),
        sources.len(),
        &staging,
        opts,
        progress,
        &mut summary,
        source_labels,
    );
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e);
    }
    swap_into_place(&staging, out)?;
    Ok(summary)
}

/// Every motion file of every source as a copy of its take, colliding
/// non-CMU ids qualified ([`qualify_colliding_ids`]).
fn list_copies(sources: &[Source]) -> Result<Vec<Copy<'_>>, DatasetError> {
    let mut copies: Vec<Copy> = Vec::new();
    for (source_index, source) in sources.iter().enumerate() {
        for take in source.takes()? {
            copies.push(Copy {
                file: source.portable_name(&take.motion.name),
                source,
                source_index,
                take,
            });
        }
    }
    qualify_colliding_ids(&mut copies);
    Ok(copies)
}

/// The copies whose take is not in the exclude list; the others are
/// recorded as skipped (`excluded`, unread) with the list's ids that
/// matched no take.
fn leave_out_excluded<'a>(
    copies: Vec<Copy<'a>>,
    opts: &DatasetOptions,
    summary: &mut BuildSummary,
    progress: &dyn Progress,
) -> Vec<Copy<'a>> {
    let (excluded, copies): (Vec<Copy>, Vec<Copy>) = copies
        .into_iter()
        .partition(|c| opts.exclude.contains(&c.take.take_id));
    let matched: BTreeSet<&str> = excluded.iter().map(|c| c.take.take_id.as_str()).collect();
    summary.exclude_unmatched = opts
        .exclude
        .iter()
        .filter(|id| !matched.contains(id.as_str()))
        .cloned()
        .collect();
    summary.excluded = excluded.len();
    for c in &excluded {
        progress.file_done(&c.file, false);
        summary.skipped.push(Skipped {
            message: format!("{}: take {} is in the exclude list", c.file, c.take.take_id),
            file: c.file.clone(),
            take: c.take.take_id.clone(),
            code: "excluded".into(),
            kept: None,
        });
    }
    copies
}

/// Copies of one take (the same id) as one group, groups in take order, the
/// preferred copy first in each: ASF/AMC (CMU's original), then the first in
/// path order.
fn group_copies(mut copies: Vec<Copy<'_>>) -> Vec<Group<'_>> {
    copies.sort_by(|a, b| {
        (&a.take.take_id, std::cmp::Reverse(a.take.format), &a.file).cmp(&(
            &b.take.take_id,
            std::cmp::Reverse(b.take.format),
            &b.file,
        ))
    });
    let mut groups: Vec<Group> = Vec::new();
    for c in copies {
        match groups.last_mut() {
            Some(g) if g.copies[0].take.take_id == c.take.take_id => g.copies.push(c),
            _ => groups.push(Group { copies: vec![c] }),
        }
    }
    groups
}

/// A fresh, empty staging directory beside `out` (`.NAME.tmp-PID`), those
/// left by killed runs removed.
fn make_staging(out: &Path) -> Result<PathBuf, DatasetError> {
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(|e| write_err(parent, e))?;
    let name = out
        .file_name()
        .ok_or_else(|| DatasetError::Options(format!("{}: not a directory name", out.display())))?
        .to_string_lossy()
        .into_owned();
    let staging = parent.join(format!(".{name}.tmp-{}", std::process::id()));
    remove_stale(parent, &name);
    if staging.exists() {
        std::fs::remove_dir_all(&staging).map_err(|e| write_err(&staging, e))?;
    }
    std::fs::create_dir_all(&staging).map_err(|e| write_err(&staging, e))?;
    Ok(staging)
}

/// The fallback skeleton's file name (`--asf`; one per build in practice).
fn fallback_asf_name(sources: &[Source]) -> Option<String> {
    let asf: BTreeSet<String> = sources
        .iter()
        .filter_map(|s| {
            s.fallback_asf()
                .map(|p| s.portable_file(&FileRef::External(p.into())))
        })
        .collect();
    asf.into_iter().next()
}

/// Non-CMU ids come from paths inside a collection, so two collections can
/// give the same one for different files: such ids are qualified with the
/// collection's name (`dances/salsa/04`), and with its position among the
/// sources when two collections share a name (`dances#2/salsa/04`).
fn qualify_colliding_ids(copies: &mut [Copy]) {
    let mut sources_of: HashMap<&str, BTreeSet<usize>> = HashMap::new();
    for c in copies.iter().filter(|c| !c.take.cmu_trial) {
        sources_of
            .entry(c.take.take_id.as_str())
            .or_default()
            .insert(c.source_index);
    }
    let colliding: BTreeSet<String> = sources_of
        .into_iter()
        .filter(|(_, s)| s.len() > 1)
        .map(|(id, _)| id.to_string())
        .collect();
    if colliding.is_empty() {
        return;
    }
    // How many of the sources share each collection name.
    let sources: BTreeSet<(String, usize)> = copies
        .iter()
        .map(|c| (c.source.collection_name(), c.source_index))
        .collect();
    let mut name_count: HashMap<String, usize> = HashMap::new();
    for (name, _) in sources {
        *name_count.entry(name).or_default() += 1;
    }
    for c in copies.iter_mut() {
        if c.take.cmu_trial || !colliding.contains(&c.take.take_id) {
            continue;
        }
        let name = c.source.collection_name();
        let prefix = if name_count.get(&name).copied().unwrap_or(0) > 1 {
            format!("{name}#{}", c.source_index + 1)
        } else {
            name
        };
        c.take.take_id = format!("{prefix}/{}", c.take.take_id);
    }
}

fn validate(opts: &DatasetOptions) -> Result<(), DatasetError> {
    let bad = |m: String| Err(DatasetError::Options(m));
    if opts.window == 0 || opts.stride == 0 {
        return bad("window and stride must be positive".into());
    }
    let f = opts.fractions;
    if f.iter().any(|x| !(0.0..=1.0).contains(x)) || (f.iter().sum::<f64>() - 1.0).abs() > 1e-9 {
        return bad(format!(
            "split fractions {f:?} must be in [0, 1] and sum to 1"
        ));
    }
    if !(opts.std_floor > 0.0 && opts.std_floor.is_finite()) {
        return bad("std floor must be positive".into());
    }
    if !(opts.ingest.target_fps > 0.0 && opts.ingest.target_fps.is_finite()) {
        return bad("fps must be positive".into());
    }
    Ok(())
}

/// Remove staging directories left by killed runs (`.NAME.tmp-PID`).
fn remove_stale(parent: &Path, name: &str) {
    let prefix = format!(".{name}.tmp-");
    if let Ok(rd) = std::fs::read_dir(parent) {
        for e in rd.flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            if let Some(pid) = n.strip_prefix(&prefix) {
                let alive = pid.parse::<u32>().is_ok_and(|p| {
                    p != std::process::id() && Path::new(&format!("/proc/{p}")).exists()
                });
                if !alive {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
    }
}

/// Read every group and write the dataset's files into `dir`, the manifest
/// last; fails on an empty dataset or a train split without windows.
#[allow(clippy::too_many_arguments)]
fn write_all(
    groups: &[Group],
    asf: Option<String>,
    num_sources: usize,
    dir: &Path,
    opts: &DatasetOptions,
    progress: &dyn Progress,
    summary: &mut BuildSummary,
    source_labels: &[String],
) -> Result<(), DatasetError> {
    let mut tally = Tally::new(opts, summary);
    let frames_out = read_all(
        groups,
        num_sources,
        &dir.join("frames.parquet"),
        &mut tally,
        progress,
    )?;
    let Tally {
        summary,
        takes_rows,
        windows_rows,
        inputs,
        moments,
        ..
    } = tally;
    summary.input_bytes = inputs.values().map(|i| i.size).sum();
    if summary.takes == 0 {
        return Err(DatasetError::Empty {
            files: summary.files,
        });
    }
    let mut outputs = vec![frames_out];
    outputs.push(write_takes(
        &dir.join("takes.parquet"),
        &takes_rows,
        opts.encoding,
    )?);
    outputs.push(write_windows(
        &dir.join("windows.parquet"),
        &windows_rows,
        opts.window,
        opts.encoding,
    )?);
    if moments.n == 0.0 {
        return Err(DatasetError::Options(
            "the train split has no windows: use more data, a shorter --window or other split fractions".into(),
        ));
    }
    let stats = stats_of(&moments, opts.std_floor);
    outputs.push(write_json(&dir.join("stats.json"), &stats)?);
    summary.skipped.sort_by(|a, b| a.file.cmp(&b.file));
    outputs.push(write_json(&dir.join("skipped.json"), &summary.skipped)?);

    // The manifest comes last: it lists every other output with its hash
    // (computed while writing, so no output is read back).
    let manifest = manifest(opts, asf, source_labels, summary, &inputs, &outputs);
    write_json(&dir.join("manifest.json"), &manifest)?;
    Ok(())
}

/// Put the finished staging directory at `out` (see [`crate::atomic`]),
/// refusing to replace a non-empty directory that is not a dataset.
fn swap_into_place(staging: &Path, out: &Path) -> Result<(), DatasetError> {
    let non_empty = std::fs::read_dir(out)
        .map(|mut d| d.next().is_some())
        .unwrap_or(false);
    if non_empty && !out.join("manifest.json").exists() {
        return Err(DatasetError::Write {
            path: out.to_path_buf(),
            message: "exists and is not a dataset (no manifest.json); refusing to replace it"
                .into(),
        });
    }
    crate::atomic::replace_dir(staging, out).map_err(|e| write_err(out, e))
}
