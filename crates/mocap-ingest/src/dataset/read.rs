//! The copies of every take read, group by group (16 groups in parallel at
//! a time), and accounted for in take order ([`Tally`]): which copy is
//! kept, what was skipped and why, splits, windows and the train split's
//! moments; `frames.parquet` written on its own thread meanwhile.

use super::write::{
    finish_file, frames_batch, frames_schema, parquet_writer, write_err, InputFile, OutputFile,
    TakeRow,
};
use super::{
    sha256_hex, split_of, window_starts, BuildSummary, DatasetError, DatasetOptions, Progress,
    Skipped, SplitBy, Stats, Warning,
};
use crate::category::{self, CategoryTable};
use crate::features::{feature_names, NUM_FEATURES};
use crate::source::{FileRef, Source, TakeInput};
use crate::{process_take_with, Clip, ErrorKind, IngestError, Options};
use arrow_array::RecordBatch;
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Takes processed per parallel chunk. Fixed, so output never depends on the
/// number of threads; small, so memory holds a few files at a time.
const CHUNK: usize = 16;

/// One copy of a take: a source's file, with where it comes from.
pub(super) struct Copy<'a> {
    pub(super) source: &'a Source,
    /// Index of `source` among the build's sources (selects the reader).
    pub(super) source_index: usize,
    pub(super) take: TakeInput,
    /// The motion file's portable name.
    pub(super) file: String,
}

/// All copies of one take id, the preferred first (ASF/AMC, then path order).
pub(super) struct Group<'a> {
    pub(super) copies: Vec<Copy<'a>>,
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

/// Read one copy with this worker's reader of its source, recording every
/// file read; with `strict`, a file cut short is an error.
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
pub(super) struct Moments {
    /// Total weight.
    pub(super) n: f64,
    /// Weighted mean of each feature.
    pub(super) mean: [f64; NUM_FEATURES],
    /// Weighted sum of squared deviations of each feature.
    pub(super) m2: [f64; NUM_FEATURES],
}

impl Moments {
    /// No values yet.
    pub(super) fn new() -> Self {
        Moments {
            n: 0.0,
            mean: [0.0; NUM_FEATURES],
            m2: [0.0; NUM_FEATURES],
        }
    }

    /// Add one frame of features with a weight (0 adds nothing).
    pub(super) fn add(&mut self, x: &[f64; NUM_FEATURES], weight: f64) {
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
/// The statistics of the train split from its moments, the std floored.
pub(super) fn stats_of(m: &Moments, floor: f64) -> Stats {
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

/// What the build accumulates, group by group in take order.
pub(super) struct Tally<'o> {
    opts: &'o DatasetOptions,
    pub(super) summary: &'o mut BuildSummary,
    /// Rows of `takes.parquet`.
    pub(super) takes_rows: Vec<TakeRow>,
    /// Rows of `windows.parquet`: take, start, split.
    pub(super) windows_rows: Vec<(String, u32, usize)>,
    /// Every file read, by portable name.
    pub(super) inputs: BTreeMap<String, InputFile>,
    /// Moments of the train windows' frames.
    pub(super) moments: Moments,
    /// Kept takes by the hashes of the files they were read from: the same
    /// bytes under two ids are one take.
    kept_content: HashMap<Vec<String>, (String, String)>,
}

impl<'o> Tally<'o> {
    /// Nothing accounted for yet.
    pub(super) fn new(opts: &'o DatasetOptions, summary: &'o mut BuildSummary) -> Self {
        Tally {
            opts,
            summary,
            takes_rows: Vec::new(),
            windows_rows: Vec::new(),
            inputs: BTreeMap::new(),
            moments: Moments::new(),
            kept_content: HashMap::new(),
        }
    }

    /// Record a file as skipped.
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
        self.count_duplicates(group, d);
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
                    let why = self.why_not_kept(clip, d, kept_name);
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

    /// Count a group of several copies in the duplicates: which format was
    /// kept, whether an earlier copy failed, how many were not read.
    fn count_duplicates(&mut self, group: &Group, d: &GroupDone) {
        if group.copies.len() <= 1 {
            return;
        }
        let dup = &mut self.summary.duplicates;
        dup.takes += 1;
        if let Some(i) = d.kept {
            *dup.kept_by_format
                .entry(group.copies[i].take.format.as_str().to_string())
                .or_default() += 1;
            dup.fell_back += usize::from(d.attempts[..i].iter().any(|a| a.result.is_err()));
        }
        dup.unread += group.copies.len() - d.attempts.len();
    }

    /// Why a copy that read (`clip`) yielded to the kept copy `kept_name`:
    /// it ends inside its motion, or the kept copy has the subject's own
    /// skeleton; counted in the duplicates.
    fn why_not_kept(&mut self, clip: &Clip, d: &GroupDone, kept_name: &str) -> String {
        let kept_clip = d
            .kept
            .and_then(|j| d.attempts.get(j))
            .and_then(|a| a.result.as_ref().ok());
        let kept_own = kept_clip.is_some_and(|c| c.skeleton != crate::SkeletonKind::Daz);
        match clip.truncation {
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
        }
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
pub(super) fn read_all(
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
