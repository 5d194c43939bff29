//! `cargo xtask <command>`: the project's pipeline stages and benchmarks.
//!
//! A thin binary over the library crates: argument parsing, progress and
//! reports live here; the work lives in the crates.

mod audit;
mod compare;
mod dataset;
mod fetch;
mod motion;
mod steer;
mod train;

use anyhow::{bail, Result};
use clap::{Parser, Subcommand};
use mocap_ingest::Options;
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
    Train(Box<train::TrainArgs>),
    /// Sample motions from a trained run's prior (and reconstruct test
    /// windows): Parquet + JSON, BVH, contact sheet, animations, 3-D viewer.
    Sample(motion::SampleArgs),
    /// Turn motions Parquet files (from `sample`) into BVH files, one per
    /// motion, and check each by reading it back.
    Export(motion::ExportArgs),
    /// Open a run's 3-D viewer in headless Chromium: fail on a JavaScript
    /// error, screenshot the generated set and the real/reconstruction pairs.
    Screenshot(motion::ScreenshotArgs),
    /// Continue a motion file (BVH, or AMC with its ASF) with a trained
    /// model: a BVH of the clip followed by generated motion.
    Continue(motion::ContinueArgs),
    /// Steer a trained run's model along a path (a CSV of waypoints or a
    /// built-in shape): BVH, Parquet, and the path from above.
    Steer(steer::SteerArgs),
    /// A web page where the model walks where the keys say, live (WebAssembly, no server).
    Play(steer::PlayArgs),
    /// Measure a trained run against real windows: ELBO, diversity,
    /// smoothness, bone lengths, foot skating, Fréchet distance.
    Eval(motion::EvalArgs),
    /// Train every model with several seeds, evaluate each run, and write a
    /// results page (mean ± std over seeds, goals met, contact sheets).
    Compare(compare::CompareArgs),
    /// Benchmark a training step at given batch sizes, and sampling.
    BenchTrain(train::BenchArgs),
    /// Benchmark sampling: frames per second of a run's default sampler and
    /// of the model alone (one draw, the pace not held).
    BenchSample(motion::BenchSampleArgs),
    /// Train the motion classifier on a dataset's train windows and print
    /// its accuracy, diversity, multimodality and Fréchet distance.
    TrainClassifier(train::ClassifierArgs),
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
    // Set while this is the only thread, unless the user set them: candle
    // 0.11's element-wise pool busy-waits and takes the cores from training's
    // shards (0.87 s against 0.39 s a step at batch 1,600), so one thread;
    // errors are for users, so no backtrace under them (panics keep theirs).
    for (var, value) in [("CANDLE_NUM_THREADS", "1"), ("RUST_LIB_BACKTRACE", "0")] {
        if std::env::var_os(var).is_none() {
            std::env::set_var(var, value);
        }
    }
    motion_vrnn::train::keep_freed_memory();
    match Cli::parse().command {
        Command::Dataset(args) => dataset::run(args),
        Command::Train(args) => train::run(*args),
        Command::Sample(args) => motion::sample(args),
        Command::Continue(args) => motion::continue_clip(args),
        Command::Export(args) => motion::export(args),
        Command::Screenshot(args) => motion::screenshot(args),
        Command::Eval(args) => motion::eval(args),
        Command::Steer(args) => steer::steer(args),
        Command::Play(args) => steer::play(args),
        Command::Audit(args) => audit::run(args),
        Command::Compare(args) => compare::run(args),
        Command::BenchTrain(args) => train::bench(args),
        Command::BenchSample(args) => motion::bench_sample(args),
        Command::TrainClassifier(args) => train::classifier(args),
        Command::BenchDataset { sources, repeat } => dataset::bench(sources, repeat),
        Command::BenchIngest { sources, repeat } => {
            let given = Some(sources).filter(|s| !s.is_empty());
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            let report = mocap_ingest::bench::ingest_report(
                &given.map_or_else(shared_samples, Ok)?,
                cores,
                repeat,
            )?;
            print!("{report}");
            Ok(())
        }
        Command::Inspect {
            file,
            full_asf_skeleton,
            asf,
        } => {
            let mut opts = Options::default();
            opts.asf.full_skeleton = full_asf_skeleton;
            print!("{}", mocap_ingest::describe_file(&file, asf, &opts)?);
            Ok(())
        }
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
