//! A whole collection → the training dataset (see `docs/dataset.md`):
//! `frames.parquet`, `takes.parquet`, `windows.parquet`, `stats.json`,
//! `skipped.json` and `manifest.json`, written atomically into one directory.
//!
//! Determinism: takes are processed in parallel in fixed-size chunks, but
//! results are consumed in take order, so the bytes written never depend on
//! the thread count. The split of a take (or subject) is a hash of the seed
//! and its id, so adding a take never moves another.

use crate::category::{self, Category, CategoryTable};
use crate::features::{feature_names, NUM_FEATURES};
use crate::source::{FileRef, Source, TakeInput};
use crate::{process_take_with, Clip, ErrorKind, IngestError, Options};
use arrow_array::{ArrayRef, Float32Array, RecordBatch, StringArray, UInt32Array};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;
use parquet::schema::types::ColumnPath;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Takes processed per parallel chunk. Fixed, so output never depends on the
/// number of threads; small, so memory holds a few files at a time.
const CHUNK: usize = 16;

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
/// encoded (`bench-dataset --encodings` compares them). The default,
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
    /// Skip files that end inside their motion (code `truncated`), as
    /// format 2 did, instead of keeping their complete frames with a warning.
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

#[derive(Serialize)]
struct InputFile {
    path: String,
    size: u64,
    sha256: String,
}

#[derive(Serialize)]
struct OutputFile {
    path: String,
    size: u64,
    sha256: String,
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

/// One copy of a take: a source's file, with where it comes from.
struct Copy<'a> {
    source: &'a Source,
    /// Index of `source` among the build's sources (selects the reader).
    source_index: usize,
    take: TakeInput,
    /// The motion file's portable name.
    file: String,
}

/// All copies of one take id, the preferred first (ASF/AMC, then path order).
struct Group<'a> {
    copies: Vec<Copy<'a>>,
}

/// One copy read (successfully or not).
struct Attempt {
    result: Result<Clip, IngestError>,
    /// Every file read: portable name, size, SHA-256.
    inputs: Vec<InputFile>,
}

/// A group after reading: the attempts, in the order of the copies (copies
/// after the last attempt were not read), and which one is kept.
struct GroupDone {
    attempts: Vec<Attempt>,
    kept: Option<usize>,
}

/// Open readers of one worker, one per source (opened on first use).
type Readers = Vec<Option<crate::source::SourceReader>>;

fn run_copy(copy: &Copy, readers: &mut Readers, opts: &Options, strict: bool) -> Attempt {
    let mut inputs = Vec::new();
    let slot = &mut readers[copy.source_index];
    let reader = match slot {
        Some(r) => Ok(r),
        None => copy
            .source
            .reader()
            .map(|r| slot.insert(r))
            .map_err(|e| IngestError::new(&copy.file, ErrorKind::Io(std::io::Error::other(e)))),
    };
    let result = reader.and_then(|reader| {
        // Every file read is recorded (size, SHA-256) for the manifest.
        let read = |f: &FileRef| {
            let bytes = reader.read_file(f)?;
            inputs.push(InputFile {
                path: copy.source.portable_file(f),
                size: bytes.len() as u64,
                sha256: sha256_hex(&bytes),
            });
            Ok(bytes)
        };
        process_take_with(&copy.take, |f| copy.source.portable_file(f), read, opts)
    });
    // Strict: a file cut short is refused, as in format 2.
    let result = result.and_then(|clip| match clip.truncation {
        Some(t) if strict => Err(IngestError::new(&copy.file, t.to_error())),
        _ => Ok(clip),
    });
    Attempt { result, inputs }
}

/// Read the copies of a take in order of preference until one succeeds. A
/// copy retargeted onto another figure (Daz-friendly BVH) or cut short (the
/// file ends inside its motion) is kept only if no later copy reads whole
/// with the subject's own skeleton.
fn run_group(
    group: &Group,
    readers: &mut Readers,
    opts: &DatasetOptions,
    progress: &dyn Progress,
) -> GroupDone {
    let mut attempts = Vec::new();
    let mut kept = None;
    for copy in &group.copies {
        let a = run_copy(copy, readers, &opts.ingest, opts.strict);
        progress.file_done(&copy.file, a.result.is_ok());
        let whole = match &a.result {
            Ok(clip) => clip.skeleton != crate::SkeletonKind::Daz && clip.truncation.is_none(),
            Err(_) => false,
        };
        if (a.result.is_ok() && kept.is_none()) || whole {
            kept = Some(attempts.len());
        }
        attempts.push(a);
        if whole {
            break;
        }
    }
    for rest in &group.copies[attempts.len()..] {
        progress.file_done(&rest.file, false);
    }
    GroupDone { attempts, kept }
}

/// Streaming mean/variance (Chan et al. merge), combined in a fixed order.
#[derive(Clone)]
struct Moments {
    n: f64,
    mean: [f64; NUM_FEATURES],
    m2: [f64; NUM_FEATURES],
}

impl Moments {
    fn new() -> Self {
        Moments {
            n: 0.0,
            mean: [0.0; NUM_FEATURES],
            m2: [0.0; NUM_FEATURES],
        }
    }

    fn add(&mut self, x: &[f64; NUM_FEATURES], weight: f64) {
        if weight == 0.0 {
            return;
        }
        let n = self.n + weight;
        for ((&xi, mean), m2) in x.iter().zip(&mut self.mean).zip(&mut self.m2) {
            let d = xi - *mean;
            *mean += d * weight / n;
            *m2 += weight * d * (xi - *mean);
        }
        self.n = n;
    }
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> DatasetError {
    DatasetError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn parquet_writer(
    path: &Path,
    schema: SchemaRef,
    encoding: Encoding,
) -> Result<ArrowWriter<OutWriter>, DatasetError> {
    let file = create_out(path)?;
    let (compression, split_floats) = match encoding {
        Encoding::Snappy => (Compression::SNAPPY, false),
        Encoding::SnappyByteStreamSplit => (Compression::SNAPPY, true),
        Encoding::Zstd => (Compression::ZSTD(ZstdLevel::default()), false),
        Encoding::ZstdByteStreamSplit => (Compression::ZSTD(ZstdLevel::default()), true),
    };
    // Dictionaries only for the repeated id strings; for float features they
    // cost time (interning every value) and save nothing.
    let mut props = WriterProperties::builder()
        .set_compression(compression)
        .set_dictionary_enabled(false)
        .set_column_dictionary_enabled(ColumnPath::from("take"), true)
        .set_column_dictionary_enabled(ColumnPath::from("subject"), true)
        .set_column_dictionary_enabled(ColumnPath::from("split"), true)
        .set_max_row_group_row_count(Some(64 * 1024))
        .set_created_by(format!("mocap-ingest {}", env!("CARGO_PKG_VERSION")));
    if split_floats {
        for f in schema.fields() {
            if f.data_type() == &DataType::Float32 {
                props = props.set_column_encoding(
                    ColumnPath::from(f.name().as_str()),
                    parquet::basic::Encoding::BYTE_STREAM_SPLIT,
                );
            }
        }
    }
    let props = props.build();
    ArrowWriter::try_new(file, schema, Some(props)).map_err(|e| write_err(path, e))
}

fn frames_schema() -> SchemaRef {
    let mut fields = vec![
        Field::new("take", DataType::Utf8, false),
        Field::new("subject", DataType::Utf8, false),
        Field::new("frame", DataType::UInt32, false),
    ];
    for n in feature_names() {
        fields.push(Field::new(n, DataType::Float32, false));
    }
    Arc::new(Schema::new(fields))
}

fn frames_batch(
    schema: &SchemaRef,
    clips: &[(&Clip, &str)],
) -> Result<RecordBatch, arrow_schema::ArrowError> {
    let rows: usize = clips.iter().map(|c| c.0.features.len()).sum();
    let mut take = Vec::with_capacity(rows);
    let mut subject = Vec::with_capacity(rows);
    let mut frame = Vec::with_capacity(rows);
    let mut cols: Vec<Vec<f32>> = (0..NUM_FEATURES)
        .map(|_| Vec::with_capacity(rows))
        .collect();
    for (c, subj) in clips {
        for (t, f) in c.features.iter().enumerate() {
            take.push(c.take_id.as_str());
            subject.push(*subj);
            frame.push(t as u32);
            for (i, col) in cols.iter_mut().enumerate() {
                col.push(f[i] as f32);
            }
        }
    }
    let mut arrays: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from(take)),
        Arc::new(StringArray::from(subject)),
        Arc::new(UInt32Array::from(frame)),
    ];
    arrays.extend(
        cols.into_iter()
            .map(|c| Arc::new(Float32Array::from(c)) as ArrayRef),
    );
    RecordBatch::try_new(schema.clone(), arrays)
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
    let files = copies.len();
    let mut summary = BuildSummary {
        files,
        ..Default::default()
    };
    progress.start(files);

    // Excluded takes are not read.
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

    // Copies of one take (the same id) form a group, the preferred copy
    // first: ASF/AMC (CMU's original), then the first in path order.
    let mut copies = copies;
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
    // The fallback skeleton's file name (one per build in practice).
    let asf: BTreeSet<String> = sources
        .iter()
        .filter_map(|s| {
            s.fallback_asf()
                .map(|p| s.portable_file(&FileRef::External(p.into())))
        })
        .collect();
    let result = write_all(
        &groups,
        asf.into_iter().next(),
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

/// What the build accumulates, group by group in take order.
struct Tally<'o> {
    opts: &'o DatasetOptions,
    summary: &'o mut BuildSummary,
    takes_rows: Vec<TakeRow>,
    windows_rows: Vec<(String, u32, usize)>,
    inputs: BTreeMap<String, InputFile>,
    moments: Moments,
    /// Kept takes by the hashes of the files they were read from: the same
    /// bytes under two ids are one take.
    kept_content: HashMap<Vec<String>, (String, String)>,
}

impl Tally<'_> {
    fn skip(&mut self, file: &str, take: &str, code: &str, message: String, kept: Option<&str>) {
        self.summary.skipped.push(Skipped {
            file: file.to_string(),
            take: take.to_string(),
            code: code.to_string(),
            message,
            kept: kept.map(str::to_string),
        });
    }

    /// Account for one group: every file read, every copy not kept (and
    /// why), duplicates; returns the kept take's clip and subject, if any.
    fn group<'g>(&mut self, group: &'g Group, d: &'g GroupDone) -> Option<(&'g Clip, &'g str)> {
        let id = &group.copies[0].take.take_id;
        let kept = d.kept.map(|i| &group.copies[i]);
        let k = kept.map(|c| c.file.as_str());
        if group.copies.len() > 1 {
            let dup = &mut self.summary.duplicates;
            dup.takes += 1;
            if let (Some(copy), Some(i)) = (kept, d.kept) {
                *dup.kept_by_format
                    .entry(copy.take.format.as_str().to_string())
                    .or_default() += 1;
                dup.fell_back += usize::from(d.attempts[..i].iter().any(|a| a.result.is_err()));
            }
            dup.unread += group.copies.len() - d.attempts.len();
        }
        for (i, (copy, a)) in group.copies.iter().zip(&d.attempts).enumerate() {
            for f in &a.inputs {
                self.inputs.entry(f.path.clone()).or_insert(InputFile {
                    path: f.path.clone(),
                    size: f.size,
                    sha256: f.sha256.clone(),
                });
            }
            let kept_name = k.unwrap_or_default();
            match &a.result {
                _ if d.kept == Some(i) => {}
                Err(e) => {
                    let message = match k {
                        Some(k) => format!("{e} (take {id} was read from {k} instead)"),
                        None => e.to_string(),
                    };
                    self.skip(&e.file, id, e.code(), message, k);
                }
                Ok(clip) => {
                    let kept_clip = d
                        .kept
                        .and_then(|j| d.attempts.get(j))
                        .and_then(|a| a.result.as_ref().ok());
                    let kept_own =
                        kept_clip.is_some_and(|c| c.skeleton != crate::SkeletonKind::Daz);
                    let why = match clip.truncation {
                        Some(t) if !(kept_own && clip.skeleton == crate::SkeletonKind::Daz) => {
                            self.summary.duplicates.truncated_yielded += 1;
                            let other = if kept_clip.is_some_and(|c| c.truncation.is_none()) {
                                "is complete"
                            } else {
                                "was read first"
                            };
                            format!(
                                "it ends inside its motion ({} of {} frames) and \
                                 the copy {kept_name} {other}",
                                t.frames_kept(),
                                t.frames_expected()
                            )
                        }
                        _ => {
                            self.summary.duplicates.superseded += 1;
                            format!("the copy {kept_name} has the subject's own skeleton")
                        }
                    };
                    let message = format!(
                        "{}: duplicate take {id}, read but not kept: {why}",
                        copy.file
                    );
                    self.skip(&copy.file, id, "duplicate_take", message, k);
                }
            }
        }
        for copy in &group.copies[d.attempts.len()..] {
            let message = format!(
                "{}: duplicate take {id}, not read: the copy {} was read",
                copy.file,
                k.unwrap_or_default()
            );
            self.skip(&copy.file, id, "duplicate_take", message, k);
        }
        let i = d.kept?;
        let (copy, attempt) = (&group.copies[i], &d.attempts[i]);
        let clip = attempt.result.as_ref().ok()?;
        let content: Vec<String> = attempt.inputs.iter().map(|f| f.sha256.clone()).collect();
        if let Some((other, other_file)) = self.kept_content.get(&content).cloned() {
            let message = format!(
                "{}: the same bytes as {other_file}, already in the dataset as take {other}",
                copy.file
            );
            self.skip(&copy.file, id, "duplicate_file", message, Some(&other_file));
            return None;
        }
        self.kept_content
            .insert(content, (id.clone(), copy.file.clone()));
        if let Some(t) = &clip.truncation {
            self.summary
                .warnings
                .push(Warning::truncated(&copy.file, &clip.take_id, t));
        }
        self.add_take(copy, clip);
        Some((clip, copy.take.subject.as_str()))
    }

    /// A take goes in: its split, windows, statistics, rows and counts.
    fn add_take(&mut self, copy: &Copy, clip: &Clip) {
        let (opts, summary) = (self.opts, &mut *self.summary);
        let subject = copy.take.subject.as_str();
        let key = match opts.split_by {
            SplitBy::Take => clip.take_id.as_str(),
            SplitBy::Subject => subject,
        };
        let split = split_of(key, opts.seed, opts.fractions);
        let starts = window_starts(clip.features.len(), opts.window, opts.stride);
        if starts.is_empty() {
            summary.short_takes += 1;
        }
        if split == 0 {
            // Multiplicity of each frame in the train windows.
            let mut mult = vec![0u32; clip.features.len()];
            for &s in &starts {
                mult[s..s + opts.window].iter_mut().for_each(|m| *m += 1);
            }
            for (f, &m) in clip.features.iter().zip(&mult) {
                self.moments.add(f, m as f64);
            }
        }
        summary.takes += 1;
        summary.takes_per_split[split] += 1;
        summary.windows_per_split[split] += starts.len();
        summary.frames += clip.features.len();
        summary.native_frames += clip.native_frames;
        let format = copy.take.format.as_str();
        *summary
            .takes_by_skeleton
            .entry((format.to_string(), clip.skeleton.name().to_string()))
            .or_default() += 1;
        for &s in &starts {
            self.windows_rows
                .push((clip.take_id.clone(), s as u32, split));
        }
        let (category, description) =
            category::resolve(&clip.take_id, &opts.categories, CategoryTable::cmu());
        self.takes_rows.push(TakeRow {
            category: category.name(),
            description: description.map(String::from),
            take: clip.take_id.clone(),
            subject: subject.to_string(),
            file: copy.file.clone(),
            format,
            skeleton: clip.skeleton.name(),
            source_fps: clip.source_fps,
            native_frames: clip.native_frames as u32,
            frames: clip.features.len() as u32,
            split,
        });
    }
}

/// Read every group, chunk by chunk in parallel, accounting for each in take
/// order; `frames.parquet` is encoded, compressed and written on its own
/// thread, batch by batch in that order, while the next chunk is read.
fn read_all(
    groups: &[Group],
    num_sources: usize,
    frames_path: &Path,
    tally: &mut Tally,
    progress: &dyn Progress,
) -> Result<OutputFile, DatasetError> {
    let opts = tally.opts;
    let schema = frames_schema();
    std::thread::scope(|scope| {
        let (tx, rx) = std::sync::mpsc::sync_channel::<RecordBatch>(2);
        let writer = {
            let schema = schema.clone();
            scope.spawn(move || -> Result<OutputFile, DatasetError> {
                let mut w = parquet_writer(frames_path, schema, opts.encoding)?;
                for batch in rx {
                    w.write(&batch).map_err(|e| write_err(frames_path, e))?;
                }
                let inner = w.into_inner().map_err(|e| write_err(frames_path, e))?;
                finish_file(inner, frames_path)
            })
        };
        for chunk in groups.chunks(CHUNK) {
            let done: Vec<GroupDone> = chunk
                .par_iter()
                .map_init(
                    || -> Readers { (0..num_sources).map(|_| None).collect() },
                    |readers, group| run_group(group, readers, opts, progress),
                )
                .collect();
            let ok: Vec<(&Clip, &str)> = chunk
                .iter()
                .zip(&done)
                .filter_map(|(g, d)| tally.group(g, d))
                .collect();
            if !ok.is_empty() {
                let batch = frames_batch(&schema, &ok).map_err(|e| write_err(frames_path, e))?;
                if tx.send(batch).is_err() {
                    break; // The writer failed; its error comes from join below.
                }
            }
        }
        drop(tx);
        writer
            .join()
            .map_err(|_| write_err(frames_path, "the Parquet writer thread panicked"))?
    })
}

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
    let mut tally = Tally {
        opts,
        summary,
        takes_rows: Vec::new(),
        windows_rows: Vec::new(),
        inputs: BTreeMap::new(),
        moments: Moments::new(),
        kept_content: HashMap::new(),
    };
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
    let categories: BTreeMap<&str, &str> = (opts.categories.iter())
        .map(|(t, c)| (t.as_str(), c.name()))
        .collect();
    let manifest = serde_json::json!({
        "tool": "mocap-ingest",
        "tool_version": env!("CARGO_PKG_VERSION"),
        "format_version": FORMAT_VERSION,
        "sources": source_labels,
        "options": {
            "fps": opts.ingest.target_fps,
            "window": opts.window,
            "stride": opts.stride,
            "split_fractions": opts.fractions,
            "seed": opts.seed,
            "split_by": opts.split_by,
            "std_floor": opts.std_floor,
            "full_asf_skeleton": opts.ingest.asf.full_skeleton,
            "frame_rate_overrides": frame_rate_overrides(&opts.ingest),
            "exclude": opts.exclude,
            "categories": categories,
            "asf": asf,
            "encoding": opts.encoding.name(),
            "strict": opts.strict,
        },
        "counts": {
            "files": summary.files,
            "takes": summary.takes,
            "skipped": summary.skipped.len(),
            "excluded": summary.excluded,
            "short_takes": summary.short_takes,
            "native_frames": summary.native_frames,
            "frames": summary.frames,
            "takes_per_split": split_map(summary.takes_per_split),
            "windows_per_split": split_map(summary.windows_per_split),
            "warnings": summary.warnings.len(),
        },
        "warnings": summary.warnings,
        "inputs": inputs.values().collect::<Vec<_>>(),
        "outputs": outputs,
    });
    write_json(&dir.join("manifest.json"), &manifest)?;
    Ok(())
}

fn frame_rate_overrides(o: &Options) -> BTreeMap<String, f64> {
    let builtin = crate::fps::FrameRateTable::default();
    o.frame_rates
        .entries()
        .filter(|(k, v)| builtin.get(k) != Some(*v))
        .map(|(k, v)| (k.to_string(), v))
        .collect()
}

fn split_map(v: [usize; 3]) -> serde_json::Value {
    serde_json::json!({ "train": v[0], "val": v[1], "test": v[2] })
}

fn stats_of(m: &Moments, floor: f64) -> Stats {
    let names = feature_names();
    let std_raw: Vec<f64> = m.m2.iter().map(|v| (v / m.n).max(0.0).sqrt()).collect();
    let std: Vec<f64> = std_raw.iter().map(|s| s.max(floor)).collect();
    let floored = names
        .iter()
        .zip(&std_raw)
        .filter(|(_, s)| **s < floor)
        .map(|(n, _)| n.clone())
        .collect();
    Stats {
        features: names,
        mean: m.mean.to_vec(),
        std,
        std_raw,
        std_floor: floor,
        floored,
        count: m.n as u64,
    }
}

/// A writer that hashes (SHA-256) and counts what goes through it, so an
/// output's manifest entry needs no second read of the file.
struct Hashing<W> {
    inner: W,
    hasher: Sha256,
    len: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hasher.update(&buf[..n]);
        self.len += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// An output file being written: buffered, hashed.
type OutWriter = Hashing<BufWriter<File>>;

fn create_out(path: &Path) -> Result<OutWriter, DatasetError> {
    let file = File::create(path).map_err(|e| write_err(path, e))?;
    Ok(Hashing {
        inner: BufWriter::new(file),
        hasher: Sha256::new(),
        len: 0,
    })
}

/// Flush and sync an output; its manifest entry.
fn finish_file(w: OutWriter, path: &Path) -> Result<OutputFile, DatasetError> {
    let f = w
        .inner
        .into_inner()
        .map_err(|e| write_err(path, e.error()))?;
    f.sync_all().map_err(|e| write_err(path, e))?;
    Ok(OutputFile {
        path: path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
        size: w.len,
        sha256: w
            .hasher
            .finalize()
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect(),
    })
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<OutputFile, DatasetError> {
    let mut text = serde_json::to_string_pretty(value).map_err(|e| write_err(path, e))?;
    text.push('\n');
    let mut w = create_out(path)?;
    w.write_all(text.as_bytes())
        .map_err(|e| write_err(path, e))?;
    finish_file(w, path)
}

/// One row of `takes.parquet`.
struct TakeRow {
    take: String,
    subject: String,
    file: String,
    format: &'static str,
    skeleton: &'static str,
    source_fps: f64,
    native_frames: u32,
    frames: u32,
    split: usize,
    category: &'static str,
    description: Option<String>,
}

fn write_takes(
    path: &Path,
    rows: &[TakeRow],
    encoding: Encoding,
) -> Result<OutputFile, DatasetError> {
    let schema = Arc::new(Schema::new(vec![
        Field::new("take", DataType::Utf8, false),
        Field::new("subject", DataType::Utf8, false),
        Field::new("file", DataType::Utf8, false),
        Field::new("format", DataType::Utf8, false),
        Field::new("skeleton", DataType::Utf8, false),
        Field::new("source_fps", DataType::Float32, false),
        Field::new("native_frames", DataType::UInt32, false),
        Field::new("frames", DataType::UInt32, false),
        Field::new("split", DataType::Utf8, false),
        Field::new("category", DataType::Utf8, false),
        Field::new("description", DataType::Utf8, true),
    ]));
    let strings = |f: fn(&TakeRow) -> &str| -> ArrayRef {
        Arc::new(StringArray::from_iter_values(rows.iter().map(f)))
    };
    let counts = |f: fn(&TakeRow) -> u32| -> ArrayRef {
        Arc::new(UInt32Array::from_iter_values(rows.iter().map(f)))
    };
    let cols: Vec<ArrayRef> = vec![
        strings(|r| &r.take),
        strings(|r| &r.subject),
        strings(|r| &r.file),
        strings(|r| r.format),
        strings(|r| r.skeleton),
        Arc::new(Float32Array::from_iter_values(
            rows.iter().map(|r| r.source_fps as f32),
        )),
        counts(|r| r.native_frames),
        counts(|r| r.frames),
        strings(|r| SPLITS[r.split]),
        strings(|r| r.category),
        Arc::new(StringArray::from_iter(
            rows.iter().map(|r| r.description.as_deref()),
        )),
    ];
    write_table(path, schema, cols, encoding)
}

fn write_windows(
    path: &Path,
    rows: &[(String, u32, usize)],
    window: usize,
    encoding: Encoding,
) -> Result<OutputFile, DatasetError> {
    let schema = Arc::new(Schema::new(vec![
        Field::new("take", DataType::Utf8, false),
        Field::new("start", DataType::UInt32, false),
        Field::new("length", DataType::UInt32, false),
        Field::new("split", DataType::Utf8, false),
    ]));
    let cols: Vec<ArrayRef> = vec![
        Arc::new(StringArray::from_iter_values(
            rows.iter().map(|r| r.0.as_str()),
        )),
        Arc::new(UInt32Array::from_iter_values(rows.iter().map(|r| r.1))),
        Arc::new(UInt32Array::from_iter_values(
            rows.iter().map(|_| window as u32),
        )),
        Arc::new(StringArray::from_iter_values(
            rows.iter().map(|r| SPLITS[r.2]),
        )),
    ];
    write_table(path, schema, cols, encoding)
}

fn write_table(
    path: &Path,
    schema: SchemaRef,
    cols: Vec<ArrayRef>,
    encoding: Encoding,
) -> Result<OutputFile, DatasetError> {
    let batch = RecordBatch::try_new(schema.clone(), cols).map_err(|e| write_err(path, e))?;
    let mut w = parquet_writer(path, schema, encoding)?;
    w.write(&batch).map_err(|e| write_err(path, e))?;
    let f = w.into_inner().map_err(|e| write_err(path, e))?;
    finish_file(f, path)
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

impl BuildSummary {
    /// The summary `cargo xtask dataset` prints: counts, skipped files by
    /// reason, copies, warnings, splits, speed (`dir`: where the dataset went;
    /// `rss`: peak resident set size in KiB, if known).
    pub fn report(&self, dir: &Path, seconds: f64, threads: usize, rss: Option<u64>) -> String {
        use std::fmt::Write as _;
        let s = self;
        let out_dir = dir;
        let mut out = String::new();

        let _ = writeln!(out, "dataset written to {}", out_dir.display());
        let _ = writeln!(out, "  files found        {:>10}", s.files);
        let _ = writeln!(out, "  takes written      {:>10}", s.takes);
        for ((format, skeleton), n) in &s.takes_by_skeleton {
            let _ = writeln!(out, "    {format:<4} {skeleton:<33} {n:>6}");
        }
        let _ = writeln!(out, "  files skipped      {:>10}", s.skipped.len());
        let mut by_code: BTreeMap<&str, usize> = BTreeMap::new();
        for k in &s.skipped {
            *by_code.entry(k.code.as_str()).or_default() += 1;
        }
        for (code, n) in &by_code {
            let _ = writeln!(out, "    {code:<16} {n:>10}");
        }
        let d = &s.duplicates;
        if d.takes > 0 {
            let kept: Vec<String> = d
                .kept_by_format
                .iter()
                .map(|(f, n)| format!("{n} {f}"))
                .collect();
            let _ = writeln!(
                out,
                "  takes in several copies {:>5}   kept: {}; {} after the preferred copy failed; \
             {} retargeted (Daz) copies read but yielded to the subject's skeleton; \
             {} copies cut short yielded to another copy; {} copies not read",
                d.takes,
                if kept.is_empty() {
                    "none".into()
                } else {
                    kept.join(", ")
                },
                d.fell_back,
                d.superseded,
                d.truncated_yielded,
                d.unread
            );
        }
        if s.excluded > 0 || !s.exclude_unmatched.is_empty() {
            let _ = writeln!(out, "  excluded files     {:>10}", s.excluded);
        }
        if !s.exclude_unmatched.is_empty() {
            let _ = writeln!(
                out,
                "  exclude-list ids matching no take: {}",
                s.exclude_unmatched.join(", ")
            );
        }
        let _ = writeln!(
            out,
            "  input frames       {:>10}   (native rate)",
            s.native_frames
        );
        let _ = writeln!(out, "  frames written     {:>10}   (30 fps)", s.frames);
        let _ = writeln!(out, "  takes < 1 window   {:>10}", s.short_takes);
        let _ = writeln!(
            out,
            "  takes cut short    {:>10}   (complete frames kept, see warnings)",
            s.warnings.len()
        );
        let _ = writeln!(out, "  {:<8} {:>8} {:>10}", "split", "takes", "windows");
        for (i, split) in SPLITS.iter().enumerate() {
            let _ = writeln!(
                out,
                "  {:<8} {:>8} {:>10}",
                split, s.takes_per_split[i], s.windows_per_split[i]
            );
        }
        let rss = rss.map_or("?".to_string(), |k| format!("{:.0} MiB", k as f64 / 1024.0));
        let _ = writeln!(
            out,
            "  {seconds:.2} s on {threads} threads, {:.0} input frames/s, peak RSS {rss}",
            s.native_frames as f64 / seconds
        );
        // Duplicates that were simply not read and excluded files are routine;
        // list the files that failed.
        let failed: Vec<_> = s
            .skipped
            .iter()
            .filter(|k| !matches!(k.code.as_str(), "duplicate_take" | "excluded"))
            .collect();
        if !s.warnings.is_empty() {
            let _ = writeln!(
                out,
                "warnings: files that end inside their motion, their complete frames kept \
             (all in manifest.json; --strict skips them):"
            );
            for w in s.warnings.iter().take(20) {
                let _ = writeln!(out, "  {}", w.message);
            }
            if s.warnings.len() > 20 {
                let _ = writeln!(out, "  … and {} more", s.warnings.len() - 20);
            }
        }
        if !failed.is_empty() {
            let _ = writeln!(
                out,
                "files that failed (all skipped files are in skipped.json):"
            );
            for k in failed.iter().take(20) {
                let _ = writeln!(out, "  {}", k.message);
            }
            if failed.len() > 20 {
                let _ = writeln!(out, "  … and {} more", failed.len() - 20);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_cover_whole_windows_only() {
        assert_eq!(window_starts(127, 128, 64), Vec::<usize>::new());
        assert_eq!(window_starts(128, 128, 64), vec![0]);
        assert_eq!(window_starts(320, 128, 64), vec![0, 64, 128, 192]);
    }

    #[test]
    fn split_is_stable_and_roughly_proportional() {
        let f = [0.8, 0.1, 0.1];
        assert_eq!(split_of("02_01", 7, f), split_of("02_01", 7, f));
        let mut counts = [0; 3];
        for i in 0..10_000 {
            counts[split_of(&format!("{:02}_{:02}", i / 100, i % 100), 0, f)] += 1;
        }
        assert!((7700..8300).contains(&counts[0]), "{counts:?}");
        assert!((800..1200).contains(&counts[1]), "{counts:?}");
        let all_train = [1.0, 0.0, 0.0];
        assert_eq!(split_of("x", 1, all_train), 0);
    }

    #[test]
    fn moments_match_two_pass_statistics() {
        let mut m = Moments::new();
        let xs = [1.0, 2.0, 4.0, 7.0];
        let ws = [1.0, 2.0, 0.0, 1.0];
        for (x, w) in xs.iter().zip(ws) {
            m.add(&[*x; NUM_FEATURES], w);
        }
        // Weighted: values 1, 2, 2, 7 → mean 3, variance (4+1+1+16)/4 = 5.5.
        assert!((m.mean[0] - 3.0).abs() < 1e-12);
        assert!((m.m2[0] / m.n - 5.5).abs() < 1e-12);
    }
}
