//! `cargo xtask train`.

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use motion_vrnn::bench::{pytorch_medians, speedup_bound, time_steps, StepTiming};
use motion_vrnn::model::{Config, MODELS};
use motion_vrnn::options::{Overrides, Preset, SelectBy};
use motion_vrnn::train::{layout, train, EpochMetrics, TrainProgress};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct TrainArgs {
    /// Dataset directory written by `cargo xtask dataset`.
    #[arg(long, default_value = "data/datasets/cmu")]
    pub data: PathBuf,
    /// Run directory (checkpoints, metrics, loss curve).
    #[arg(long, default_value = "runs/vrnn")]
    pub out: PathBuf,
    /// The model (`paper`, `smooth`, `skeletal`, `feet`, `fed`, `motion`; see docs/training.md).
    #[arg(long, default_value = motion_vrnn::model::DEFAULT_MODEL, value_parser = parse_model)]
    pub model: String,
    /// Override the model's latent filter pole (0: off).
    #[arg(long)]
    pub latent_filter: Option<f64>,
    /// Override the model's output filter pole (0: off).
    #[arg(long)]
    pub output_filter: Option<f64>,
    /// Override the weight of the model's foot-slide penalty (0: off).
    #[arg(long)]
    pub feet_weight: Option<f64>,
    /// Override the model's KL weight after warm-up (1: the ELBO).
    #[arg(long)]
    pub kl_weight: Option<f64>,
    /// Override the largest share of frames the model is fed back in
    /// training (scheduled sampling; 0: off).
    #[arg(long)]
    pub self_feed: Option<f64>,
    /// Override the model's rounds of feeding back (each round's
    /// predictions are made from the previous round's; 1: one step deep).
    #[arg(long)]
    pub feed_rounds: Option<usize>,
    /// Override the model's sampling temperature (scale of the prior's
    /// std when generating, also for the checkpoint judge; 1: as trained).
    #[arg(long)]
    pub temperature: Option<f64>,
    /// Starting point for every option below.
    /// `standard`: batch 64, 400 epochs, KL warm-up 20, clipping 100, early
    /// stopping 60; `quick`: 30 epochs, warm-up 5, early stopping 10; `paper`:
    /// exactly the paper (Adam 1e-3, batch 1,600, 2,000 epochs, nothing else).
    #[arg(long, default_value = "standard")]
    pub preset: Preset,
    /// Epochs.
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Windows per step.
    #[arg(long)]
    pub batch: Option<usize>,
    /// Adam learning rate.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Learning rate of the last epoch as a share of --lr, reached along a
    /// half cosine over the second half of the epochs (1: constant).
    #[arg(long)]
    pub lr_final: Option<f64>,
    /// Seed of initialisation, shuffling and noise.
    #[arg(long)]
    pub seed: Option<u64>,
    /// KL warm-up epochs (0: off).
    #[arg(long)]
    pub kl_warmup: Option<usize>,
    /// Clip the global gradient norm (0: off).
    #[arg(long)]
    pub clip: Option<f64>,
    /// Early-stopping patience in epochs (0: off).
    #[arg(long)]
    pub early_stopping: Option<usize>,
    /// How `best` is chosen: `generation` (motions generated every
    /// --judge-every epochs, measured against the validation windows) or
    /// `loss` (lowest validation loss; the paper preset's choice).
    #[arg(long)]
    pub select: Option<SelectBy>,
    /// Epochs between two judgements of generated motion (--select generation).
    #[arg(long)]
    pub judge_every: Option<usize>,
    /// Continue the run in --out from its `last` checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// The progress bar, and whether `--quiet` was given.
struct Bar(ProgressBar, bool);

impl TrainProgress for Bar {
    fn step(&self, epoch: usize, step: u64, recon: f32, kl: f32, wps: f64) {
        self.0.set_message(format!(
            "epoch {epoch} step {step} recon {recon:.2} kl {kl:.2} {wps:.0} windows/s"
        ));
    }
    fn epoch(&self, m: &EpochMetrics) {
        self.0.set_position(m.epoch as u64);
        let mut line = format!(
            "epoch {:>4}  train recon {:>9.3} kl {:>7.3}  val recon {:>9.3} kl {:>7.3}  {:>6.0} windows/s  {:.1} s",
            m.epoch, m.train_recon, m.train_kl, m.val_recon, m.val_kl, m.windows_per_s, m.seconds
        );
        if let Some(v) = &m.generated {
            line += &format!(
                "  generated: distance {:.3}, Fréchet {:.1}",
                v.score, v.frechet
            );
        }
        if !self.1 {
            self.println(&line);
        }
    }
    fn note(&self, message: &str) {
        self.println(&format!("note: {message}"));
    }
}

impl Bar {
    /// A line above the bar (or on stderr when the bar is hidden).
    fn println(&self, line: &str) {
        // A hidden bar (no terminal) prints nothing: keep the log readable.
        if self.0.is_hidden() {
            eprintln!("{line}");
        } else {
            self.0.println(line);
        }
    }
}

/// A model name of [`MODELS`], or an error that lists them.
pub fn parse_model(name: &str) -> std::result::Result<String, String> {
    match Config::named(name) {
        Some(_) => Ok(name.to_string()),
        None => Err(format!(
            "unknown model {name:?}; the models: {}",
            MODELS.iter().map(|m| m.0).collect::<Vec<_>>().join(", ")
        )),
    }
}

impl TrainArgs {
    /// The options that replace the preset's values.
    fn overrides(&self) -> Overrides {
        Overrides {
            latent_filter: self.latent_filter,
            output_filter: self.output_filter,
            feet_weight: self.feet_weight,
            kl_weight: self.kl_weight,
            self_feed: self.self_feed,
            feed_rounds: self.feed_rounds,
            temperature: self.temperature,
            epochs: self.epochs,
            batch: self.batch,
            lr: self.lr,
            lr_final: self.lr_final,
            seed: self.seed,
            kl_warmup: self.kl_warmup,
            clip: self.clip,
            early_stopping: self.early_stopping,
            select: self.select,
            judge_every: self.judge_every,
        }
    }
}

pub fn run(a: TrainArgs) -> Result<()> {
    let mut cfg = a.preset.config();
    cfg.model = Config::named(&a.model).context("unknown model")?;
    a.overrides().apply(&mut cfg);
    let device = motion_vrnn::model::default_device();
    let data = motion_vrnn::data::load(&a.data, &["train", "val"]).with_context(|| {
        format!(
            "loading the dataset {} (build it with `cargo xtask dataset`)",
            a.data.display()
        )
    })?;
    let n = |s: &str| data.splits.get(s).map_or(0, |w| w.n);
    if !a.quiet {
        eprintln!(
            "training the {} model on {} train / {} val windows from {} on {:?}; batch {}, {} epochs, lr {}",
            a.model,
            n("train"),
            n("val"),
            a.data.display(),
            device,
            cfg.batch,
            cfg.epochs,
            cfg.adam.lr
        );
    }
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(cfg.epochs as u64)
    };
    bar.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {bar:30} {pos}/{len} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let started = std::time::Instant::now();
    let history = train(
        &data,
        &cfg,
        &a.out,
        a.resume,
        &device,
        &Bar(bar.clone(), a.quiet),
    )
    .with_context(|| format!("training into {}", a.out.display()))?
    .history;
    bar.finish_and_clear();
    let png = a.out.join("loss.png");
    motion_eval::chart::loss_curves(&png, &history)?;
    if let Some(last) = history.last() {
        println!(
            "done: {} epochs in {:.1} s; last epoch: train recon {:.3} kl {:.3}, val recon {:.3} kl {:.3}; {:.0} windows/s ({:.0} frames/s)",
            last.epoch,
            started.elapsed().as_secs_f64(),
            last.train_recon,
            last.train_kl,
            last.val_recon,
            last.val_kl,
            last.windows_per_s,
            last.windows_per_s * data.splits.get("train").map_or(0, |w| w.length) as f64
        );
    }
    println!(
        "checkpoints: {}/{{{},{}}}; metrics: {}; loss curve: {}",
        a.out.display(),
        layout::BEST,
        layout::LAST,
        a.out.join(layout::METRICS).display(),
        png.display()
    );
    Ok(())
}

/// `cargo xtask bench-train`: seconds per training step (forward, backward,
/// Adam) of each model on random windows, and the sampling time, in one
/// table; with `reference`, also through candle ops (autograd); with
/// `pytorch`, every model against PyTorch eager on the paper's model.
pub fn bench(
    models: &[String],
    batches: &[usize],
    steps: usize,
    reference: bool,
    pytorch: Option<&Path>,
) -> Result<()> {
    let device = motion_vrnn::model::default_device();
    println!(
        "training step (T = {}, forward + backward + Adam) on {device:?}, {} rayon threads; median and min of {steps} steps after 2 warm-up steps",
        motion_vrnn::bench::FRAMES,
        rayon::current_num_threads()
    );
    println!(
        "{:>9} {:>9} {:>6} {:>10} {:>10} {:>16} {:>12}",
        "model", "path", "batch", "median s", "min s", "windows*frames/s", "sample 36 s"
    );
    let mut fused = Vec::new();
    for name in models {
        for r in time_steps(name, batches, steps, reference, &device)? {
            println!(
                "{:>9} {:>9} {:>6} {:>10.4} {:>10.4} {:>16.0} {:>12.4}",
                r.model,
                r.path,
                r.batch,
                r.median,
                r.min,
                (r.batch * motion_vrnn::bench::FRAMES) as f64 / r.median,
                r.sample
            );
            if r.path == "fused" {
                fused.push(r);
            }
        }
    }
    if let Some(python) = pytorch {
        against_pytorch(python, &fused, batches, steps)?;
    }
    Ok(())
}

/// Every model against PyTorch eager running the paper's model on this
/// machine (the faster of its two forms at each batch size), with the
/// speed bounds of issue 11 ([`speedup_bound`]).
fn against_pytorch(
    python: &Path,
    rows: &[StepTiming],
    batches: &[usize],
    steps: usize,
) -> Result<()> {
    let script = crate::workspace_root().join("xtask/py/pytorch_vrnn_step.py");
    let threads = rayon::current_num_threads();
    let stepwise = pytorch_medians(python, &script, batches, steps, threads, false)?;
    let hoisted = pytorch_medians(python, &script, batches, steps, threads, true)?;
    println!();
    println!("PyTorch eager, paper model (xtask/py/pytorch_vrnn_step.py), median s per step:");
    for ((b, s), (_, h)) in stepwise.iter().zip(&hoisted) {
        println!("  batch {b:>5}: stepwise {s:.4}, hoisted {h:.4}");
    }
    println!();
    println!(
        "{:>9} {:>6} {:>10} {:>11} {:>9} {:>7} {:>4}",
        "model", "batch", "median s", "PyTorch s", "speed-up", "bound", "met"
    );
    for r in rows {
        let Some(i) = batches.iter().position(|x| *x == r.batch) else {
            continue;
        };
        let torch = stepwise[i].1.min(hoisted[i].1);
        let speedup = torch / r.median;
        let bound = speedup_bound(r.self_feed, r.batch);
        println!(
            "{:>9} {:>6} {:>10.4} {torch:>11.4} {speedup:>8.2}x {bound:>6.1}x {:>4}",
            r.model,
            r.batch,
            r.median,
            if speedup >= bound { "yes" } else { "no" }
        );
    }
    Ok(())
}
