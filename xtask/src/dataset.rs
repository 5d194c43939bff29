//! `cargo xtask dataset` and `cargo xtask bench-dataset`.

use crate::{fetch, file_name, shared_samples, workspace_root};
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use mocap_ingest::dataset::{
    build_dataset, parse_exclude_list, BuildSummary, DatasetOptions, Encoding, Progress, SplitBy,
    SPLITS,
};
use mocap_ingest::source::{FileRef, Source};
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
    /// Parquet compression and float encoding (bench-dataset --encodings
    /// compares them): snappy, snappy_byte_stream_split, zstd, zstd_byte_stream_split.
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
    if let Some(e) = &a.encoding {
        opts.encoding =
            Encoding::from_name(e).with_context(|| format!("unknown --encoding {e}"))?;
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
            "  takes in several copies {:>5}   kept: {}; {} after the preferred copy failed; \
             {} retargeted (Daz) copies read but yielded to the subject's skeleton; {} copies not read",
            d.takes,
            if kept.is_empty() { "none".into() } else { kept.join(", ") },
            d.fell_back,
            d.superseded,
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

/// One `dataset --bench-line` run in a fresh process.
struct BenchRun {
    seconds: f64,
    native_frames: u64,
    input_bytes: u64,
    rss_kib: u64,
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
        let text = String::from_utf8_lossy(&o.stdout);
        let line = text
            .lines()
            .find(|l| l.starts_with("BENCH "))
            .context("no BENCH line")?;
        let field = |k: &str| -> f64 {
            line.split_whitespace()
                .find_map(|f| f.strip_prefix(k)?.strip_prefix('='))
                .and_then(|v| v.parse().ok())
                .unwrap_or(0.0)
        };
        let r = BenchRun {
            seconds: field("seconds"),
            native_frames: field("native_frames") as u64,
            input_bytes: field("input_bytes") as u64,
            rss_kib: field("peak_rss_kib") as u64,
        };
        if best.as_ref().is_none_or(|b| r.seconds < b.seconds) {
            best = Some(r);
        }
    }
    best.context("no run")
}

/// Copies of the takes per subject for the scaled benchmark.
const SCALE: usize = 10;

/// `SCALE` copies of an ASF/AMC collection in `dir`, each subject under a new
/// three-digit number (145 and up, past CMU's last subject), with a
/// frame-rate table giving each copy its original's rate. AMC files are
/// written once and hard-linked for the other copies; each copy's ASF ends
/// with its own `#` comment, so no two copies are the same bytes (the
/// dataset keeps one take per content). Returns the folder and the
/// frame-rate CSV.
fn scaled_collection(src: &Path, dir: &Path) -> Result<(PathBuf, PathBuf)> {
    let source = Source::open(src)?;
    let mut reader = source.reader()?;
    let takes = source.takes()?;
    let subjects: std::collections::BTreeSet<&str> =
        takes.iter().map(|t| t.subject.as_str()).collect();
    let index: BTreeMap<&str, usize> = subjects.iter().enumerate().map(|(i, s)| (*s, i)).collect();
    if 145 + SCALE * subjects.len() > 999 {
        bail!("too many subjects to scale {}", src.display());
    }
    let root = dir.join(format!("asfamc-x{SCALE}"));
    let table = dir.join(format!("asfamc-x{SCALE}-fps.csv"));
    let builtin = mocap_ingest::fps::FrameRateTable::default();
    let mut csv = String::from("take,fps\n");
    for t in &takes {
        let (Some(asf), Some((_, trial))) = (&t.asf, t.take_id.split_once('_')) else {
            bail!("{}: not a CMU ASF/AMC take", t.motion.name);
        };
        let rate = builtin.resolve(&t.take_id, None);
        let mut first_amc: Option<PathBuf> = None;
        for k in 0..SCALE {
            let n = 145 + k * subjects.len() + index[t.subject.as_str()];
            let sub = root.join(n.to_string());
            std::fs::create_dir_all(&sub)?;
            csv.push_str(&format!("{n}_{trial},{rate}\n"));
            let amc = sub.join(format!("{n}_{trial}.amc"));
            match &first_amc {
                Some(orig) if std::fs::hard_link(orig, &amc).is_ok() => {}
                _ => {
                    let bytes = reader.read_file(&FileRef::Entry(t.motion.clone()))?;
                    std::fs::write(&amc, bytes)
                        .with_context(|| format!("writing {}", amc.display()))?;
                    first_amc.get_or_insert(amc);
                }
            }
            let asf_path = sub.join(format!("{n}.asf"));
            if !asf_path.exists() {
                let mut bytes = reader.read_file(asf)?;
                bytes.extend_from_slice(format!("\n# bench copy {k} as subject {n}\n").as_bytes());
                std::fs::write(&asf_path, bytes)
                    .with_context(|| format!("writing {}", asf_path.display()))?;
            }
        }
    }
    std::fs::write(&table, csv)?;
    Ok((root, table))
}

fn print_bench_row(name: &str, threads: usize, r: &BenchRun) {
    println!(
        "{:<28} {:>7} {:>9.1} {:>10} {:>8.3} {:>8.1} {:>12.0} {:>6.0} MiB",
        name,
        threads,
        r.input_bytes as f64 / 1e6,
        r.native_frames,
        r.seconds,
        r.input_bytes as f64 / 1e6 / r.seconds,
        r.native_frames as f64 / r.seconds,
        r.rss_kib as f64 / 1024.0
    );
}

/// `cargo xtask bench-dataset`: each source alone with 1 thread and all
/// cores; with the default sources also the ASF/AMC sample at 10× (peak RSS
/// must not grow with the collection); with `encodings`, the 10× build once
/// per table encoding, with `frames.parquet`'s size and polars' read time.
pub fn bench(sources: Vec<PathBuf>, repeat: usize, encodings: bool) -> Result<()> {
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
                print_bench_row(&file_name(src), threads, &r);
                if threads == cores && file_name(src).contains("asfamc") {
                    rss_1x = Some(r.rss_kib);
                }
            }
        }
        let asfamc = sources.iter().find(|s| file_name(s).contains("asfamc"));
        let (Some(asfamc), true) = (asfamc, default || encodings) else {
            return Ok(());
        };
        let (big, fps) = scaled_collection(asfamc, &tmp)?;
        let fps = fps.display().to_string();
        let r = bench_runs(
            &exe,
            &big,
            &tmp.join("out"),
            cores,
            &["--fps-table", &fps],
            repeat,
        )?;
        print_bench_row(&format!("asfamc sample ×{SCALE}"), cores, &r);
        if let Some(one) = rss_1x {
            println!(
                "peak RSS at ×{SCALE} / ×1 (ASF/AMC sample, {cores} threads): {:.0} / {:.0} MiB",
                r.rss_kib as f64 / 1024.0,
                one as f64 / 1024.0
            );
        }
        if encodings {
            bench_encodings(&exe, &big, &fps, &tmp, cores, repeat)?;
        }
        Ok(())
    })();
    let _ = std::fs::remove_dir_all(&tmp);
    result
}

/// The scaled build once per encoding: size of `frames.parquet`, build time,
/// and the time polars takes to read all of it (best of `repeat`).
fn bench_encodings(
    exe: &Path,
    big: &Path,
    fps: &str,
    tmp: &Path,
    cores: usize,
    repeat: usize,
) -> Result<()> {
    use polars::prelude::{LazyFrame, PlRefPath};
    println!(
        "\nframes.parquet encodings (ASF/AMC sample ×{SCALE}, {cores} threads, best of {repeat}):"
    );
    println!(
        "{:<26} {:>9} {:>13} {:>14} {:>9}",
        "encoding", "MB", "build s", "polars read s", "peak RSS"
    );
    for e in Encoding::ALL {
        let out = tmp.join(format!("out-{}", e.name()));
        let r = bench_runs(
            exe,
            big,
            &out,
            cores,
            &["--fps-table", fps, "--encoding", e.name()],
            repeat,
        )?;
        let frames = out.join("frames.parquet");
        let size = std::fs::metadata(&frames)?.len();
        let mut read = f64::INFINITY;
        for _ in 0..repeat.max(1) {
            let t = Instant::now();
            let df = LazyFrame::scan_parquet(
                PlRefPath::new(frames.display().to_string()),
                Default::default(),
            )?
            .collect()?;
            read = read.min(t.elapsed().as_secs_f64());
            drop(df);
        }
        println!(
            "{:<26} {:>9.1} {:>13.2} {:>14.3} {:>6.0} MiB",
            e.name(),
            size as f64 / 1e6,
            r.seconds,
            read,
            r.rss_kib as f64 / 1024.0
        );
    }
    Ok(())
}
