//! `cargo xtask dataset` and `cargo xtask bench-dataset`.

use crate::{fetch, file_name, shared_samples, workspace_root};
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use mocap_ingest::dataset::{
    build_dataset, parse_exclude_list, BuildSummary, DatasetOptions, Progress, SplitBy, SPLITS,
};
use mocap_ingest::source::Source;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// CMU's archive of every ASF/AMC file.
pub const CMU_ALLASFAMC_URL: &str = "http://mocap.cs.cmu.edu/allasfamc.zip";

#[derive(Clone, Copy, ValueEnum)]
enum SplitByArg {
    Take,
    Subject,
}

#[derive(Args)]
pub struct DatasetArgs {
    /// Directory, .zip archive or http(s) URL of CMU .bvh / .asf+.amc files
    /// (repeat to combine). URLs are downloaded once into --cache.
    #[arg(long = "source", default_value = CMU_ALLASFAMC_URL)]
    sources: Vec<String>,
    /// Output directory (replaced atomically).
    #[arg(long, default_value = "data/datasets/cmu")]
    out: PathBuf,
    /// Output frame rate.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Window length in frames.
    #[arg(long, default_value_t = 128)]
    window: usize,
    /// Window stride in frames.
    #[arg(long, default_value_t = 64)]
    stride: usize,
    /// Train,val,test fractions.
    #[arg(long, value_delimiter = ',', default_values_t = [0.8, 0.1, 0.1])]
    split: Vec<f64>,
    /// Seed of the split.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Split whole takes or whole subjects.
    #[arg(long, value_enum, default_value_t = SplitByArg::Take)]
    split_by: SplitByArg,
    /// Floor applied to every feature's standard deviation.
    #[arg(long, default_value_t = 1e-3)]
    std_floor: f64,
    /// CSV of `take,fps` rows overriding the built-in frame-rate table
    /// (CMU's trials.csv works as is).
    #[arg(long)]
    fps_table: Option<PathBuf>,
    /// Keep the ASF thorax length (the full ASF skeleton) instead of the BVH-compatible 0.
    #[arg(long)]
    full_asf_skeleton: bool,
    /// ASF skeleton for AMC files whose own is not found beside them (after
    /// NN.asf, the only .asf in the folder, an .asf starting with the subject
    /// number). Meant for one collection; applies to every --source.
    #[arg(long)]
    asf: Option<PathBuf>,
    /// File of take ids to leave out, one per line, `#` comments (the audit's
    /// flagged.txt works as is). Recorded in the manifest.
    #[arg(long)]
    exclude: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Where downloaded archives are kept.
    #[arg(long, default_value = "data/cache")]
    cache: PathBuf,
    /// No progress bar and no summary.
    #[arg(long)]
    quiet: bool,
    /// Print one machine-readable line for bench-dataset.
    #[arg(long, hide = true)]
    bench_line: bool,
}

struct Bar(ProgressBar);

impl Progress for Bar {
    fn start(&self, files: usize) {
        self.0.set_length(files as u64);
    }
    fn file_done(&self, file: &str, ok: bool) {
        if !ok {
            self.0.set_message(format!("skipped {}", short(file)));
        }
        self.0.inc(1);
    }
}

fn short(file: &str) -> &str {
    file.rsplit(['/', '!']).next().unwrap_or(file)
}

/// Relative paths are taken from the current directory.
fn resolve(p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir()
            .unwrap_or_else(|_| workspace_root())
            .join(p)
    }
}

pub fn run(a: DatasetArgs) -> Result<()> {
    let start = Instant::now();
    let mut opts = DatasetOptions {
        window: a.window,
        stride: a.stride,
        seed: a.seed,
        std_floor: a.std_floor,
        split_by: match a.split_by {
            SplitByArg::Take => SplitBy::Take,
            SplitByArg::Subject => SplitBy::Subject,
        },
        ..Default::default()
    };
    opts.ingest.target_fps = a.fps;
    opts.ingest.asf.full_skeleton = a.full_asf_skeleton;
    let [tr, va, te] = a.split[..] else {
        bail!("--split takes three fractions: train,val,test");
    };
    opts.fractions = [tr, va, te];
    if let Some(t) = &a.fps_table {
        let n = opts
            .ingest
            .frame_rates
            .merge_csv_file(t)
            .map_err(anyhow::Error::msg)?;
        if !a.quiet {
            eprintln!("frame-rate overrides: {n} rows from {}", t.display());
        }
    }
    if let Some(f) = &a.exclude {
        let text = std::fs::read_to_string(resolve(f))
            .with_context(|| format!("reading the exclude list {}", f.display()))?;
        opts.exclude = parse_exclude_list(&text);
    }
    let asf = match &a.asf {
        Some(p) => {
            let p = resolve(p);
            if !p.is_file() {
                bail!("--asf {}: no such file", p.display());
            }
            Some(p)
        }
        None => None,
    };
    let mut sources = Vec::new();
    for s in &a.sources {
        let path = if s.starts_with("http://") || s.starts_with("https://") {
            fetch::cached(s, &resolve(&a.cache), a.quiet)?
        } else {
            resolve(Path::new(s))
        };
        let source = Source::open(&path).with_context(|| format!("opening source {s}"))?;
        sources.push(source.with_fallback_asf(asf.clone()));
    }
    let threads = a
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("building the thread pool")?;
    let bar = if a.quiet || a.bench_line {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(0)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} files {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let out = resolve(&a.out);
    let summary = pool
        .install(|| build_dataset(&sources, &a.sources, &out, &opts, &Bar(bar.clone())))
        .with_context(|| format!("building the dataset in {}", out.display()))?;
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let rss = peak_rss_kib();
    if a.bench_line {
        println!(
            "BENCH seconds={seconds} native_frames={} input_bytes={} peak_rss_kib={}",
            summary.native_frames,
            summary.input_bytes,
            rss.unwrap_or(0)
        );
    } else if !a.quiet {
        print_summary(&summary, &out, seconds, threads, rss);
    }
    Ok(())
}

fn print_summary(s: &BuildSummary, out: &Path, seconds: f64, threads: usize, rss: Option<u64>) {
    println!("dataset written to {}", out.display());
    println!("  files found        {:>10}", s.files);
    println!("  takes written      {:>10}", s.takes);
    for ((format, skeleton), n) in &s.takes_by_skeleton {
        println!("    {format:<4} {skeleton:<33} {n:>6}");
    }
    println!("  files skipped      {:>10}", s.skipped.len());
    let mut by_code: BTreeMap<&str, usize> = BTreeMap::new();
    for k in &s.skipped {
        *by_code.entry(k.code.as_str()).or_default() += 1;
    }
    for (code, n) in &by_code {
        println!("    {code:<16} {n:>10}");
    }
    let d = &s.duplicates;
    if d.takes > 0 {
        let kept: Vec<String> = d
            .kept_by_format
            .iter()
            .map(|(f, n)| format!("{n} {f}"))
            .collect();
        println!(
            "  takes in several copies {:>5}   kept: {}; {} after the preferred copy failed; {} copies not read",
            d.takes,
            if kept.is_empty() { "none".into() } else { kept.join(", ") },
            d.fell_back,
            d.unread
        );
    }
    if s.excluded > 0 || !s.exclude_unmatched.is_empty() {
        println!("  excluded files     {:>10}", s.excluded);
    }
    if !s.exclude_unmatched.is_empty() {
        println!(
            "  exclude-list ids matching no take: {}",
            s.exclude_unmatched.join(", ")
        );
    }
    println!(
        "  input frames       {:>10}   (native rate)",
        s.native_frames
    );
    println!("  frames written     {:>10}   (30 fps)", s.frames);
    println!("  takes < 1 window   {:>10}", s.short_takes);
    println!("  {:<8} {:>8} {:>10}", "split", "takes", "windows");
    for (i, split) in SPLITS.iter().enumerate() {
        println!(
            "  {:<8} {:>8} {:>10}",
            split, s.takes_per_split[i], s.windows_per_split[i]
        );
    }
    let rss = rss.map_or("?".to_string(), |k| format!("{:.0} MiB", k as f64 / 1024.0));
    println!(
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
    if !failed.is_empty() {
        println!("files that failed (all skipped files are in skipped.json):");
        for k in failed.iter().take(20) {
            println!("  {}", k.message);
        }
        if failed.len() > 20 {
            println!("  … and {} more", failed.len() - 20);
        }
    }
}

/// Peak resident set size of this process (Linux), in KiB.
fn peak_rss_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

pub fn bench(sources: Vec<PathBuf>, repeat: usize) -> Result<()> {
    let sources = if sources.is_empty() {
        shared_samples()?
    } else {
        sources
    };
    let exe = std::env::current_exe().context("locating the xtask binary")?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let tmp = std::env::temp_dir().join(format!("xtask-bench-dataset-{}", std::process::id()));
    println!("whole `dataset` pipeline (list, read, FK, features, Parquet, stats, manifest), best of {repeat}, each run a fresh process");
    println!(
        "{:<28} {:>7} {:>9} {:>10} {:>8} {:>8} {:>12} {:>9}",
        "source", "threads", "MB", "frames", "seconds", "MB/s", "frames/s", "peak RSS"
    );
    for src in &sources {
        for threads in [1, cores] {
            let mut best: Option<(f64, u64, u64, u64)> = None;
            for _ in 0..repeat.max(1) {
                let out = Command::new(&exe)
                    .args([
                        "dataset",
                        "--bench-line",
                        "--threads",
                        &threads.to_string(),
                        "--source",
                    ])
                    .arg(src)
                    .arg("--out")
                    .arg(tmp.join("out"))
                    .output()
                    .context("running dataset")?;
                if !out.status.success() {
                    bail!("dataset failed: {}", String::from_utf8_lossy(&out.stderr));
                }
                let text = String::from_utf8_lossy(&out.stdout);
                let line = text
                    .lines()
                    .find(|l| l.starts_with("BENCH "))
                    .context("no BENCH line")?;
                let field = |k: &str| -> Option<f64> {
                    line.split_whitespace()
                        .find_map(|f| f.strip_prefix(k)?.strip_prefix('='))
                        .and_then(|v| v.parse().ok())
                };
                let r = (
                    field("seconds").unwrap_or(f64::NAN),
                    field("native_frames").unwrap_or(0.0) as u64,
                    field("input_bytes").unwrap_or(0.0) as u64,
                    field("peak_rss_kib").unwrap_or(0.0) as u64,
                );
                if best.is_none_or(|b| r.0 < b.0) {
                    best = Some(r);
                }
            }
            let Some((secs, frames, bytes, rss)) = best else {
                continue;
            };
            let name = file_name(src);
            println!(
                "{:<28} {:>7} {:>9.1} {:>10} {:>8.3} {:>8.1} {:>12.0} {:>6.0} MiB",
                name,
                threads,
                bytes as f64 / 1e6,
                frames,
                secs,
                bytes as f64 / 1e6 / secs,
                frames as f64 / secs,
                rss as f64 / 1024.0
            );
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);
    Ok(())
}
