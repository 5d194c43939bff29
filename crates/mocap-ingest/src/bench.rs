//! What the ingest benchmarks measure (`cargo xtask bench-ingest`,
//! `bench-dataset`): the per-take pipeline's throughput over a collection,
//! and a collection scaled up by copies of its takes.

use crate::dataset::DatasetError;
use crate::source::{FileRef, Source, TakeInput};
use crate::{process_take, Options};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// One pass of read + FK + features over a collection.
#[derive(Clone, Debug)]
pub struct Throughput {
    /// Motion files.
    pub files: usize,
    /// Uncompressed motion and skeleton bytes.
    pub bytes: u64,
    /// Frames read, at the native rates.
    pub native_frames: usize,
    /// Files that failed.
    pub failed: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Every take of `source` through [`process_take`] on a pool of `threads`.
pub fn throughput(
    source: &Source,
    takes: &[TakeInput],
    threads: usize,
) -> Result<Throughput, DatasetError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| DatasetError::Options(format!("building the thread pool: {e}")))?;
    let opts = Options::default();
    let start = std::time::Instant::now();
    let results: Vec<Option<usize>> = pool.install(|| {
        takes
            .par_iter()
            .map_init(
                || source.reader().ok(),
                |reader, take| {
                    let reader = reader.as_mut()?;
                    process_take(source, reader, take, &opts)
                        .ok()
                        .map(|c| c.native_frames)
                },
            )
            .collect()
    });
    let seconds = start.elapsed().as_secs_f64();
    let bytes = takes
        .iter()
        .map(|t| {
            t.motion.size
                + match &t.asf {
                    Some(FileRef::Entry(a)) => a.size,
                    _ => 0,
                }
        })
        .sum();
    Ok(Throughput {
        files: takes.len(),
        bytes,
        native_frames: results.iter().flatten().sum(),
        failed: results.iter().filter(|r| r.is_none()).count(),
        seconds,
    })
}

/// The `cargo xtask bench-ingest` table: each collection of `sources`
/// through [`best_throughput`] on one thread and on `cores` (when more than
/// one), one line per pass, the files that failed named by count.
pub fn ingest_report(
    sources: &[PathBuf],
    cores: usize,
    repeat: usize,
) -> Result<String, DatasetError> {
    use std::fmt::Write;
    let mut out = format!(
        "read + FK + 58 features, whole collection, best of {repeat} (input = uncompressed motion + skeleton bytes; frames at the native rate)\n{:<28} {:>7} {:>6} {:>9} {:>10} {:>8} {:>9} {:>13}\n",
        "source", "threads", "files", "MB", "frames", "seconds", "MB/s", "frames/s"
    );
    for path in sources {
        let source = Source::open(path)?;
        let takes = source.takes()?;
        if takes.is_empty() {
            return Err(DatasetError::Options(format!(
                "{}: no .bvh or .amc files",
                path.display()
            )));
        }
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into(),
        );
        for threads in [1, cores].into_iter().filter(|&t| t == 1 || cores > 1) {
            let t = best_throughput(&source, &takes, threads, repeat)?;
            let mb = t.bytes as f64 / 1e6;
            let _ = writeln!(
                out,
                "{name:<28} {threads:>7} {:>6} {mb:>9.1} {:>10} {:>8.3} {:>9.1} {:>13.0}",
                t.files,
                t.native_frames,
                t.seconds,
                mb / t.seconds,
                t.native_frames as f64 / t.seconds
            );
            if t.failed > 0 {
                let _ = writeln!(
                    out,
                    "  ({} files failed; run `cargo xtask inspect FILE` on them)",
                    t.failed
                );
            }
        }
    }
    Ok(out)
}

/// The fastest of `repeat` passes of [`throughput`].
pub fn best_throughput(
    source: &Source,
    takes: &[TakeInput],
    threads: usize,
    repeat: usize,
) -> Result<Throughput, DatasetError> {
    let mut best = throughput(source, takes, threads)?;
    for _ in 1..repeat {
        let t = throughput(source, takes, threads)?;
        if t.seconds < best.seconds {
            best = t;
        }
    }
    Ok(best)
}

/// `scale` copies of the ASF/AMC collection `src` in `dir`, each subject
/// under a new three-digit number (145 and up, past CMU's last subject),
/// with a frame-rate table giving each copy its original's rate. AMC files
/// are written once and hard-linked for the other copies; each copy's ASF
/// ends with its own `#` comment, so no two copies are the same bytes (the
/// dataset keeps one take per content). Returns the folder and the
/// frame-rate CSV.
pub fn scaled_collection(
    src: &Path,
    dir: &Path,
    scale: usize,
) -> Result<(PathBuf, PathBuf), DatasetError> {
    let write_err = |path: &Path, e: std::io::Error| DatasetError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let source = Source::open(src)?;
    let mut reader = source.reader()?;
    let takes = source.takes()?;
    let subjects: BTreeSet<&str> = takes.iter().map(|t| t.subject.as_str()).collect();
    let index: BTreeMap<&str, usize> = subjects.iter().enumerate().map(|(i, s)| (*s, i)).collect();
    if 145 + scale * subjects.len() > 999 {
        return Err(DatasetError::Options(format!(
            "too many subjects to scale {}",
            src.display()
        )));
    }
    let root = dir.join(format!("asfamc-x{scale}"));
    let table = dir.join(format!("asfamc-x{scale}-fps.csv"));
    let builtin = crate::fps::FrameRateTable::default();
    let mut csv = String::from("take,fps\n");
    for t in &takes {
        let (Some(asf), Some((_, trial))) = (&t.asf, t.take_id.split_once('_')) else {
            return Err(DatasetError::Options(format!(
                "{}: not a CMU ASF/AMC take",
                t.motion.name
            )));
        };
        let rate = builtin.resolve(&t.take_id, None);
        let mut first_amc: Option<PathBuf> = None;
        for k in 0..scale {
            let n = 145 + k * subjects.len() + index[t.subject.as_str()];
            let sub = root.join(n.to_string());
            std::fs::create_dir_all(&sub).map_err(|e| write_err(&sub, e))?;
            csv.push_str(&format!("{n}_{trial},{rate}\n"));
            let amc = sub.join(format!("{n}_{trial}.amc"));
            match &first_amc {
                Some(orig) if std::fs::hard_link(orig, &amc).is_ok() => {}
                _ => {
                    let bytes = reader
                        .read_file(&FileRef::Entry(t.motion.clone()))
                        .map_err(|e| write_err(Path::new(&t.motion.name), e))?;
                    std::fs::write(&amc, bytes).map_err(|e| write_err(&amc, e))?;
                    first_amc.get_or_insert(amc);
                }
            }
            let asf_path = sub.join(format!("{n}.asf"));
            if !asf_path.exists() {
                let mut bytes = reader.read_file(asf).map_err(|e| write_err(&asf_path, e))?;
                bytes.extend_from_slice(format!("\n# bench copy {k} as subject {n}\n").as_bytes());
                std::fs::write(&asf_path, bytes).map_err(|e| write_err(&asf_path, e))?;
            }
        }
    }
    std::fs::write(&table, csv).map_err(|e| write_err(&table, e))?;
    Ok((root, table))
}

/// Peak resident set size of this process (Linux), in KiB.
pub fn peak_rss_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// One dataset build measured in its own process (`cargo xtask dataset
/// --bench-line` prints [`BenchRun::line`], `bench-dataset` parses it).
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRun {
    /// Wall-clock seconds of the build.
    pub seconds: f64,
    /// Frames read, at the native rates.
    pub native_frames: u64,
    /// Uncompressed input bytes.
    pub input_bytes: u64,
    /// Peak resident set size, KiB (0: unknown).
    pub rss_kib: u64,
}

impl BenchRun {
    /// A row of `bench-dataset`'s table: source, threads, MB, frames,
    /// seconds, MB/s, frames/s, peak RSS.
    pub fn row(&self, name: &str, threads: usize) -> String {
        format!(
            "{:<28} {:>7} {:>9.1} {:>10} {:>8.3} {:>8.1} {:>12.0} {:>6.0} MiB",
            name,
            threads,
            self.input_bytes as f64 / 1e6,
            self.native_frames,
            self.seconds,
            self.input_bytes as f64 / 1e6 / self.seconds,
            self.native_frames as f64 / self.seconds,
            self.rss_kib as f64 / 1024.0
        )
    }

    /// The one-line form: `BENCH seconds=… native_frames=… input_bytes=… peak_rss_kib=…`.
    pub fn line(&self) -> String {
        format!(
            "BENCH seconds={} native_frames={} input_bytes={} peak_rss_kib={}",
            self.seconds, self.native_frames, self.input_bytes, self.rss_kib
        )
    }

    /// The run on the first `BENCH` line of `text` (missing fields are 0).
    pub fn parse(text: &str) -> Option<BenchRun> {
        let line = text.lines().find(|l| l.starts_with("BENCH "))?;
        let field = |k: &str| -> f64 {
            line.split_whitespace()
                .find_map(|f| f.strip_prefix(k)?.strip_prefix('='))
                .and_then(|v| v.parse().ok())
                .unwrap_or(0.0)
        };
        Some(BenchRun {
            seconds: field("seconds"),
            native_frames: field("native_frames") as u64,
            input_bytes: field("input_bytes") as u64,
            rss_kib: field("peak_rss_kib") as u64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::BenchRun;

    #[test]
    fn bench_line_reads_back() {
        let r = BenchRun {
            seconds: 1.25,
            native_frames: 1000,
            input_bytes: 123_456,
            rss_kib: 93_000,
        };
        let out = format!("some output\n{}\n", r.line());
        assert_eq!(BenchRun::parse(&out), Some(r));
        assert_eq!(BenchRun::parse("no such line"), None);
    }
}
