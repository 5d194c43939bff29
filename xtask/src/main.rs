//! `cargo xtask <command>`: the project's pipeline stages and benchmarks.
//!
//! A thin binary over the library crates: argument parsing, progress and
//! reports live here; the work lives in the crates.

mod audit;
mod compare;
mod dataset;
mod fetch;
mod motion;
mod train;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use mocap_ingest::source::Source;
use mocap_ingest::{process_take, Options};
use std::path::{Path, PathBuf};

#[derive(Parser)]
#[command(name = "cargo xtask", about = "Motion-capture → VRNN toolchain tasks")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build the training dataset: CMU files → Parquet frames, windows,
    /// split, normalisation statistics and manifest.
    Dataset(dataset::DatasetArgs),
    /// Check a dataset: integrity, reproducibility, split hygiene, statistics, data quality.
    Audit(audit::AuditArgs),
    /// Train a model (default: the project's best; `--model paper` for the
    /// paper's VRNN) on a dataset (checkpoints, metrics, loss curve).
    Train(train::TrainArgs),
    /// Sample motions from a trained run's prior (and reconstruct test
    /// windows): Parquet + JSON, BVH, contact sheet, animations, 3-D viewer.
    Sample(motion::SampleArgs),
    /// Turn motions Parquet files (from `sample`) into BVH files, one per
    /// motion, and check each by reading it back.
    Export(motion::ExportArgs),
    /// Open a run's 3-D viewer in headless Chromium: fail on a JavaScript
    /// error, screenshot the generated set and the real/reconstruction pairs.
    Screenshot(motion::ScreenshotArgs),
    /// Measure a trained run against real windows: ELBO, diversity,
    /// smoothness, bone lengths, foot skating, Fréchet distance.
    Eval(motion::EvalArgs),
    /// Train every model with several seeds, evaluate each run, and write a
    /// results page (mean ± std over seeds, goals met, contact sheets).
    Compare(compare::CompareArgs),
    /// Benchmark a training step at given batch sizes, and sampling.
    BenchTrain {
        /// Batch sizes.
        #[arg(long, value_delimiter = ',', default_values_t = [1600, 64])]
        batch: Vec<usize>,
        /// Timed steps per batch size (after 2 warm-up steps).
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Models to time (default: every model).
        #[arg(long = "model", value_parser = train::parse_model)]
        models: Vec<String>,
        /// Also time each model through candle ops and autograd (the
        /// blocks' reference path).
        #[arg(long)]
        autograd: bool,
        /// A Python with PyTorch: also time the paper's model in PyTorch
        /// eager (`xtask/py/pytorch_vrnn_step.py`) and print every model's
        /// speed-up against it.
        #[arg(long, value_name = "PYTHON")]
        pytorch: Option<PathBuf>,
    },
    /// Benchmark `dataset` end to end on the CMU samples, 1 thread and all
    /// cores, and the ASF/AMC sample at 10×, each in a fresh process
    /// (reports peak RSS).
    BenchDataset {
        /// Directories, .zip archives (default: the two samples in ../shared/cmu, each alone).
        #[arg(long = "source")]
        sources: Vec<PathBuf>,
        /// Repetitions per configuration (the best is reported).
        #[arg(long, default_value_t = 3)]
        repeat: usize,
        /// Also build the ASF/AMC sample at 10× once per Parquet encoding
        /// (snappy/zstd, plain/byte-stream-split floats): sizes and read times.
        #[arg(long)]
        encodings: bool,
    },
    /// Benchmark reading + forward kinematics + features over CMU collections,
    /// single-threaded and with all cores.
    BenchIngest {
        /// Directories or .zip archives (default: the two samples in ../shared/cmu).
        #[arg(long = "source")]
        sources: Vec<PathBuf>,
        /// Repetitions per configuration (the best is reported).
        #[arg(long, default_value_t = 3)]
        repeat: usize,
    },
    /// Read one motion file and print what the pipeline sees.
    Inspect {
        /// A .bvh file, or an .amc file with its ASF beside it.
        file: PathBuf,
        /// Keep the ASF thorax length (the full ASF skeleton).
        #[arg(long)]
        full_asf_skeleton: bool,
        /// ASF skeleton for an .amc whose own is not found beside it.
        #[arg(long)]
        asf: Option<PathBuf>,
    },
    /// Write the category table of CMU's trials.csv (docs/dataset.md) and print trials per category.
    Categories {
        #[arg(long)]
        trials: PathBuf,
        #[arg(long, default_value = "data/cmu-categories.csv")]
        out: PathBuf,
    },
}

fn main() -> Result<()> {
    // Training parallelises over shards of the batch (rayon). candle 0.11's
    // own element-wise thread pool busy-waits between its parallel ops and
    // takes the cores from the shards (0.87 s against 0.39 s a step at
    // batch 1,600 here), so it gets one thread unless the user says
    // otherwise. Set before any candle op, while this is the only thread.
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        std::env::set_var("CANDLE_NUM_THREADS", "1");
    }
    match Cli::parse().command {
        Command::Dataset(args) => dataset::run(args),
        Command::Train(args) => train::run(args),
        Command::Sample(args) => motion::sample(args),
        Command::Export(args) => motion::export(args),
        Command::Screenshot(args) => motion::screenshot(args),
        Command::Eval(args) => motion::eval(args),
        Command::Audit(args) => audit::run(args),
        Command::Compare(args) => compare::run(args),
        Command::BenchTrain {
            batch,
            steps,
            models,
            autograd,
            pytorch,
        } => {
            let models = if models.is_empty() {
                motion_vrnn::model::MODELS
                    .iter()
                    .map(|m| m.0.to_string())
                    .collect()
            } else {
                models
            };
            train::bench(&models, &batch, steps.max(1), autograd, pytorch.as_deref())
        }
        Command::BenchDataset {
            sources,
            repeat,
            encodings,
        } => dataset::bench(sources, repeat, encodings),
        Command::BenchIngest { sources, repeat } => bench_ingest(sources, repeat),
        Command::Inspect {
            file,
            full_asf_skeleton,
            asf,
        } => inspect(&file, full_asf_skeleton, asf),
        Command::Categories { trials, out } => mocap_ingest::category::write_table(&trials, &out)
            .map(|md| print!("{md}"))
            .map_err(anyhow::Error::msg),
    }
}

/// The workspace root (xtask lives one level below it).
pub(crate) fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

/// The last component of a path, for tables.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// The shared CMU samples beside the repository (or in `CMU_SHARED_DIR`).
pub(crate) fn shared_samples() -> Result<Vec<PathBuf>> {
    let dir = std::env::var_os("CMU_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("../shared/cmu"));
    let files = ["cmu-bvh-sample.zip", "cmu-asfamc-sample.zip"].map(|f| dir.join(f));
    if let Some(missing) = files.iter().find(|f| !f.is_file()) {
        bail!(
            "no --source given and the CMU samples are missing: expected {} \
             (pass --source with a directory or .zip of CMU .bvh or .asf/.amc files)",
            missing.display()
        );
    }
    Ok(files.to_vec())
}

fn bench_ingest(sources: Vec<PathBuf>, repeat: usize) -> Result<()> {
    let sources = if sources.is_empty() {
        shared_samples()?
    } else {
        sources
    };
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("read + FK + 58 features, whole collection, best of {repeat} (input = uncompressed motion + skeleton bytes; frames at the native rate)");
    println!(
        "{:<28} {:>7} {:>6} {:>9} {:>10} {:>8} {:>9} {:>13}",
        "source", "threads", "files", "MB", "frames", "seconds", "MB/s", "frames/s"
    );
    for path in &sources {
        let source = Source::open(path)?;
        let takes = source.takes()?;
        if takes.is_empty() {
            bail!("{}: no .bvh or .amc files", path.display());
        }
        let mut thread_counts = vec![1];
        if cores > 1 {
            thread_counts.push(cores);
        }
        for &threads in &thread_counts {
            let t = mocap_ingest::bench::best_throughput(&source, &takes, threads, repeat)?;
            let name = file_name(path);
            println!(
                "{:<28} {:>7} {:>6} {:>9.1} {:>10} {:>8.3} {:>9.1} {:>13.0}",
                name,
                threads,
                t.files,
                t.bytes as f64 / 1e6,
                t.native_frames,
                t.seconds,
                t.bytes as f64 / 1e6 / t.seconds,
                t.native_frames as f64 / t.seconds
            );
            if t.failed > 0 {
                println!(
                    "  ({} files failed; run `cargo xtask inspect FILE` on them)",
                    t.failed
                );
            }
        }
    }
    Ok(())
}

fn inspect(file: &Path, full_asf_skeleton: bool, asf: Option<PathBuf>) -> Result<()> {
    let dir = file.parent().unwrap_or(Path::new("."));
    let name = file.file_name().context("not a file path")?;
    let source = Source::open(dir)?.with_fallback_asf(asf);
    let take = source
        .takes()?
        .into_iter()
        .find(|t| t.motion.name == name.to_string_lossy())
        .with_context(|| format!("{}: not a .bvh or .amc file", file.display()))?;
    let mut opts = Options::default();
    opts.asf.full_skeleton = full_asf_skeleton;
    let mut reader = source.reader()?;
    let clip = process_take(&source, &mut reader, &take, &opts)?;
    println!("file:          {}", file.display());
    println!("take:          {} (subject {})", clip.take_id, take.subject);
    if let Some(asf) = &take.asf {
        println!(
            "asf:           {} ({})",
            source.display_file(asf),
            take.asf_search
        );
    }
    println!("skeleton:      {}", clip.skeleton.name());
    println!(
        "frames:        {} at {} fps → {} at {} fps",
        clip.native_frames,
        clip.source_fps,
        clip.features.len(),
        opts.target_fps
    );
    println!("feature                 min       mean        max");
    let names = mocap_ingest::features::feature_names();
    for (n, [lo, mean, hi]) in names
        .iter()
        .zip(mocap_ingest::features::ranges(&clip.features))
    {
        println!("{n:<16} {lo:>10.4} {mean:>10.4} {hi:>10.4}");
    }
    Ok(())
}
