//! `cargo xtask compare`: every model trained with several seeds on one
//! dataset, each run evaluated, and one results page (mean ± std over the
//! seeds, the goals each model meets, training time, contact sheets).

use anyhow::Result;
use clap::Args;
use motion_eval::compare::{compare, CompareOptions};
use std::path::PathBuf;

/// `cargo xtask compare` options.
#[derive(Args, Debug)]
pub struct CompareArgs {
    /// Dataset directory written by `cargo xtask dataset`.
    #[arg(long, default_value = "data/datasets/cmu")]
    data: PathBuf,
    /// Directory of the runs (`MODEL/seed-N/`); runs already there are reused.
    #[arg(long, default_value = "runs/compare")]
    out: PathBuf,
    /// Models (default: every model).
    #[arg(long = "model", value_parser = motion_vrnn::model::parse_name)]
    models: Vec<String>,
    /// Training seeds per model (0, 1, …).
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// Epochs (default: the standard preset's).
    #[arg(long)]
    epochs: Option<usize>,
    /// The results page (Markdown; contact sheets go to `images/` beside it).
    #[arg(long, default_value = "runs/compare/results.md")]
    page: PathBuf,
    /// Seconds each run's motions are rolled out for (0: no long horizon).
    #[arg(long, default_value_t = 60.0)]
    horizon: f64,
    /// Reuse each run's kept report (RUN/compare-eval.json) instead of evaluating it again.
    #[arg(long)]
    reuse_reports: bool,
    /// A classifier (`train-classifier`): also train `motion` with `--preset
    /// standard` and the default `--preset minute`, each asked for each category.
    #[arg(long)]
    classifier: Option<PathBuf>,
    /// Only the default model (`motion` with `--preset minute`, asked for each category; needs --classifier).
    #[arg(long, requires = "classifier")]
    default_only: bool,
}

/// `cargo xtask compare`.
pub fn run(a: CompareArgs) -> Result<()> {
    let models = if a.default_only {
        Vec::new()
    } else if a.models.is_empty() {
        motion_vrnn::model::MODELS
            .iter()
            .map(|m| m.0.to_string())
            .collect()
    } else {
        a.models
    };
    let o = CompareOptions {
        data: a.data,
        out: a.out,
        models,
        seeds: a.seeds,
        epochs: a.epochs,
        page: a.page,
        horizon: (a.horizon > 0.0).then_some(motion_eval::horizon::HorizonOptions {
            seconds: a.horizon,
            motions: 256,
        }),
        reuse_reports: a.reuse_reports,
        classifier: a.classifier,
        default_only: a.default_only,
    };
    let md = compare(&o, &|line| eprintln!("{line}"))?;
    println!("{md}");
    eprintln!("wrote {}", o.page.display());
    Ok(())
}
