//! `cargo xtask dataset` and `cargo xtask bench-dataset`.

use crate::{fetch, file_name, shared_samples, workspace_root};
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use mocap_ingest::bench::BenchRun;
use mocap_ingest::category::read_user_categories;
use mocap_ingest::dataset::{
    build_dataset, parse_exclude_list, DatasetOptions, Encoding, Progress, SplitBy,
};
use mocap_ingest::source::Source;
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
    /// Directory, .zip archive or http(s) URL of CMU .bvh / .asf+.amc files (repeat to combine). URLs are downloaded once into --cache.
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
    /// CSV of `take,fps` rows overriding the built-in frame-rate table (CMU's trials.csv works as is).
    #[arg(long)]
    fps_table: Option<PathBuf>,
    /// Keep the ASF thorax length (the full ASF skeleton) instead of the BVH-compatible 0.
    #[arg(long)]
    full_asf_skeleton: bool,
    /// ASF skeleton for AMC files whose own is not found beside them (after NN.asf, the only .asf in the folder, an .asf starting with the subject number). Meant for one collection; applies to every --source.
    #[arg(long)]
    asf: Option<PathBuf>,
    /// File of take ids to leave out, one per line, `#` comments (the audit's flagged.txt works as is). Recorded in the manifest.
    #[arg(long)]
    exclude: Option<PathBuf>,
    /// File of `take,category` lines for takes that are not CMU trials (or to override). Recorded in the manifest.
    #[arg(long)]
    categories: Option<PathBuf>,
    /// Skip files that end inside their motion (reason `truncated`) instead of keeping their complete frames with a warning. Recorded in the manifest.
    #[arg(long)]
    strict: bool,
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
    /// Parquet compression and float encoding: snappy, snappy_byte_stream_split, zstd, zstd_byte_stream_split.
    #[arg(long, hide = true)]
    encoding: Option<String>,
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
        strict: a.strict,
        ..Default::default()
    };
    opts.ingest.target_fps = a.fps;
    opts.ingest.asf.full_skeleton = a.full_asf_skeleton;
    let [tr, va, te] = a.split[..] else {
        bail!("--split takes three fractions: train,val,test");
    };
    opts.fractions = [tr, va, te];
    if let Some(t) = &a.fps_table {
        let rates = &mut opts.ingest.frame_rates;
        let n = rates.merge_csv_file(t).map_err(anyhow::Error::msg)?;
        if !a.quiet {
            eprintln!("frame-rate overrides: {n} rows from {}", t.display());
        }
    }
    if let Some(e) = &a.encoding {
        opts.encoding =
            Encoding::from_name(e).with_context(|| format!("unknown --encoding {e}"))?;
    }
    if let Some(f) = &a.exclude {
        let text = std::fs::read_to_string(resolve(f))
            .with_context(|| format!("reading the exclude list {}", f.display()))?;
        opts.exclude = parse_exclude_list(&text);
    }
    if let Some(f) = &a.categories {
        opts.categories = read_user_categories(&resolve(f)).map_err(anyhow::Error::msg)?;
    }
    let asf = a.asf.as_deref().map(resolve);
    if let Some(p) = asf.as_ref().filter(|p| !p.is_file()) {
        bail!("--asf {}: no such file", p.display());
    }
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
    let rss = mocap_ingest::bench::peak_rss_kib();
    if a.bench_line {
        let run = BenchRun {
            seconds,
            native_frames: summary.native_frames as u64,
            input_bytes: summary.input_bytes,
            rss_kib: rss.unwrap_or(0),
        };
        println!("{}", run.line());
    } else if !a.quiet {
        print!("{}", summary.report(&out, seconds, threads, rss));
    }
    Ok(())
}

/// Run `dataset` on `src` into `out`, `repeat` times; the fastest run.
fn bench_runs(
    exe: &Path,
    src: &Path,
    out: &Path,
    threads: usize,
    extra: &[&str],
    repeat: usize,
) -> Result<BenchRun> {
    let mut best: Option<BenchRun> = None;
    for _ in 0..repeat.max(1) {
        let o = Command::new(exe)
            .args(["dataset", "--bench-line", "--threads", &threads.to_string()])
            .args(extra)
            .arg("--source")
            .arg(src)
            .arg("--out")
            .arg(out)
            .output()
            .context("running dataset")?;
        if !o.status.success() {
            bail!("dataset failed: {}", String::from_utf8_lossy(&o.stderr));
        }
        let r = BenchRun::parse(&String::from_utf8_lossy(&o.stdout)).context("no BENCH line")?;
        if best.as_ref().is_none_or(|b| r.seconds < b.seconds) {
            best = Some(r);
        }
    }
    best.context("no run")
}

/// Copies of the takes per subject for the scaled benchmark.
const SCALE: usize = 10;

/// `cargo xtask bench-dataset`: each source alone with 1 thread and all
/// cores; with the default sources also the ASF/AMC sample at 10× (peak RSS
/// must not grow with the collection).
pub fn bench(sources: Vec<PathBuf>, repeat: usize) -> Result<()> {
    let default = sources.is_empty();
    let sources = if default { shared_samples()? } else { sources };
    let exe = std::env::current_exe().context("locating the xtask binary")?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let tmp = std::env::temp_dir().join(format!("xtask-bench-dataset-{}", std::process::id()));
    let result = (|| -> Result<()> {
        println!("whole `dataset` pipeline (list, read, FK, features, Parquet, stats, manifest), best of {repeat}, each run a fresh process");
        println!(
            "{:<28} {:>7} {:>9} {:>10} {:>8} {:>8} {:>12} {:>9}",
            "source", "threads", "MB", "frames", "seconds", "MB/s", "frames/s", "peak RSS"
        );
        let mut rss_1x = None;
        for src in &sources {
            for threads in [1, cores] {
                let r = bench_runs(&exe, src, &tmp.join("out"), threads, &[], repeat)?;
                println!("{}", r.row(&file_name(src), threads));
                if threads == cores && file_name(src).contains("asfamc") {
                    rss_1x = Some(r.rss_kib);
                }
            }
        }
        let asfamc = sources.iter().find(|s| file_name(s).contains("asfamc"));
        let (Some(asfamc), true) = (asfamc, default) else {
            return Ok(());
        };
        let (big, fps) = mocap_ingest::bench::scaled_collection(asfamc, &tmp, SCALE)?;
        let fps = fps.display().to_string();
        let r = bench_runs(
            &exe,
            &big,
            &tmp.join("out"),
            cores,
            &["--fps-table", &fps],
            repeat,
        )?;
        println!("{}", r.row(&format!("asfamc sample ×{SCALE}"), cores));
        if let Some(one) = rss_1x {
            println!(
                "peak RSS at ×{SCALE} / ×1 (ASF/AMC sample, {cores} threads): {:.0} / {:.0} MiB",
                r.rss_kib as f64 / 1024.0,
                one as f64 / 1024.0
            );
        }
        Ok(())
    })();
    let _ = std::fs::remove_dir_all(&tmp);
    result
}
