//! `cargo xtask train`.

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use motion_render::chart::{line_chart, Series};
use motion_vrnn::model::{Config, MODELS};
use motion_vrnn::train::{layout, train, EpochMetrics, Select, TrainConfig, TrainProgress};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, ValueEnum)]
pub enum Preset {
    /// The default schedule: batch 64, 400 epochs, KL warm-up 20, clipping
    /// 100, early stopping after 60 epochs without improvement.
    Standard,
    /// A quick look: batch 64, 30 epochs, KL warm-up 5, clipping 100, early stopping 10.
    Quick,
    /// Exactly the paper: Adam 1e-3, batch 1,600, 2,000 epochs, nothing else.
    Paper,
}

/// How the `best` checkpoint is chosen.
#[derive(Clone, Copy, ValueEnum)]
pub enum SelectBy {
    /// The epoch whose generated motion is closest to the validation windows.
    Generation,
    /// The epoch with the lowest validation loss.
    Loss,
}

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
    #[arg(long, value_enum, default_value_t = Preset::Standard)]
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
    #[arg(long, value_enum)]
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
        // A hidden bar (no terminal) prints nothing: keep the log readable.
        if self.0.is_hidden() {
            if !self.1 {
                eprintln!("{line}");
            }
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

pub fn run(a: TrainArgs) -> Result<()> {
    let mut cfg = match a.preset {
        Preset::Standard => TrainConfig::standard(),
        Preset::Quick => TrainConfig::quick(),
        Preset::Paper => TrainConfig::paper(),
    };
    cfg.model = Config::named(&a.model).context("unknown model")?;
    let parts = &mut cfg.model.parts;
    if let Some(v) = a.latent_filter {
        parts.latent_filter = v;
    }
    if let Some(v) = a.output_filter {
        parts.output_filter = v;
    }
    if let Some(v) = a.feet_weight {
        parts.feet = v;
    }
    if let Some(v) = a.self_feed {
        parts.self_feed = v;
    }
    if let Some(v) = a.kl_weight {
        parts.kl_weight = (v != 1.0).then_some(v);
    }
    if let Some(v) = a.feed_rounds {
        parts.feed_rounds = (v != 1).then_some(v);
    }
    if let Some(v) = a.temperature {
        parts.temperature = (v != 1.0).then_some(v);
    }
    if let Some(v) = a.epochs {
        cfg.epochs = v;
    }
    if let Some(v) = a.batch {
        cfg.batch = v;
    }
    if let Some(v) = a.lr {
        cfg.adam.lr = v;
    }
    if let Some(v) = a.lr_final {
        cfg.lr_final = (v != 1.0).then_some(v);
    }
    if let Some(v) = a.seed {
        cfg.seed = v;
    }
    if let Some(v) = a.kl_warmup {
        cfg.kl_warmup_epochs = v;
    }
    if let Some(v) = a.clip {
        cfg.clip_grad_norm = (v > 0.0).then_some(v);
    }
    if let Some(v) = a.early_stopping {
        cfg.early_stopping = (v > 0).then_some(v);
    }
    let every = match cfg.select {
        Select::Generation { every } => every,
        Select::Loss => 5,
    };
    cfg.select = match (a.select, a.judge_every) {
        (Some(SelectBy::Loss), _) => Select::Loss,
        (Some(SelectBy::Generation), n) => Select::Generation {
            every: n.unwrap_or(every),
        },
        (None, Some(n)) if !cfg.select.is_loss() => Select::Generation { every: n },
        (None, _) => cfg.select,
    };
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
    plot_history(&png, &history)?;
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

/// The loss curves (recon + KL per window, train and validation) as a PNG.
pub fn plot_history(path: &Path, history: &[EpochMetrics]) -> Result<()> {
    let pts =
        |f: fn(&EpochMetrics) -> f64| history.iter().map(|m| (m.epoch as f64, f(m))).collect();
    Ok(line_chart(
        path,
        "VRNN loss per window",
        "epoch",
        "loss per window (normalised units)",
        &[
            Series {
                name: "train (recon + KL)",
                color: [31, 119, 180],
                points: pts(|m| m.train_recon + m.train_kl),
            },
            Series {
                name: "val (recon + KL)",
                color: [255, 127, 14],
                points: pts(|m| m.val_recon + m.val_kl),
            },
            Series {
                name: "val KL",
                color: [44, 160, 44],
                points: pts(|m| m.val_kl),
            },
        ],
    )?)
}

/// `cargo xtask bench-train`: seconds per training step (forward, backward,
/// Adam) of each model on random windows, and the sampling time, in one
/// table. With `reference`, also the same models through candle ops
/// (autograd), the oracle of the fused blocks.
pub fn bench(
    models: &[String],
    batches: &[usize],
    steps: usize,
    reference: bool,
    pytorch: Option<&Path>,
) -> Result<()> {
    use motion_vrnn::optim::Adam;
    use motion_vrnn::train::{feed_mask, init_model, named_vars, noise, sharded};
    use motion_vrnn::MotionModel;
    let device = motion_vrnn::model::default_device();
    let t = 128;
    println!(
        "training step (T = {t}, forward + backward + Adam) on {device:?}, {} rayon threads; median and min of {steps} steps after 2 warm-up steps",
        rayon::current_num_threads()
    );
    println!(
        "{:>9} {:>9} {:>6} {:>10} {:>10} {:>16} {:>12}",
        "model", "path", "batch", "median s", "min s", "windows*frames/s", "sample 36 s"
    );
    let paths: &[&str] = if reference {
        &["fused", "autograd"]
    } else {
        &["fused"]
    };
    let mut rows: Vec<(String, f64, usize, f64)> = Vec::new();
    for name in models {
        let mut model = Config::named(name).context("unknown model")?;
        // Synthetic data: the body of the skeleton part from random windows.
        let n = 64 * t * model.input;
        let train = motion_vrnn::rng::Rng::new(2, 0).normals(n);
        let mut mean = vec![0.0; model.input];
        mean[0] = 15.0;
        model.fit_to(&mean, &vec![2.0; model.input], &train);
        for &path in paths {
            for &b in batches {
                let m = init_model(&model, 0, &device)?;
                let mut adam = Adam::new(named_vars(&m.varmap), Default::default())?;
                let vars: Vec<_> = adam.vars().iter().map(|v| v.1.clone()).collect();
                let x = candle_core::Tensor::from_vec(
                    motion_vrnn::rng::Rng::new(1, b as u64).normals(b * t * model.input),
                    (b, t, model.input),
                    &device,
                )?;
                let mut times = Vec::new();
                for step in 0..steps + 2 {
                    let eps = noise(0, step as u64, t, b, model.latent, &device)?;
                    // Models that feed back their own frames are timed at
                    // their full share.
                    let feed = feed_mask(0, step as u64, b, t, model.parts.self_feed, &device)?;
                    let start = std::time::Instant::now();
                    let grads = if path == "fused" {
                        sharded(&m.model, &x, &eps, feed.as_ref(), Some((1.0, &vars)))?.1
                    } else {
                        motion_vrnn::blocks::reference(|| {
                            let l = m.model.losses(&x, &eps, feed.as_ref())?;
                            ((&l.recon + &l.kl)? + &l.extra)?.backward().map(Some)
                        })?
                    };
                    adam.step(&grads.context("no gradients")?)?;
                    if step >= 2 {
                        times.push(start.elapsed().as_secs_f64());
                    }
                }
                times.sort_by(f64::total_cmp);
                let median = times[times.len() / 2];
                let mut sample = Vec::new();
                for k in 0..5 {
                    let eps = noise(5, k, t, 36, model.latent, &device)?;
                    let start = std::time::Instant::now();
                    let s = if path == "fused" {
                        m.model.sample(&eps, None)?
                    } else {
                        motion_vrnn::blocks::reference(|| m.model.sample(&eps, None))?
                    };
                    let _ = s.sum_all()?.to_scalar::<f32>()?;
                    sample.push(start.elapsed().as_secs_f64());
                }
                sample.sort_by(f64::total_cmp);
                println!(
                    "{name:>9} {path:>9} {b:>6} {median:>10.4} {:>10.4} {:>16.0} {:>12.4}",
                    times[0],
                    (b * t) as f64 / median,
                    sample[2]
                );
                if path == "fused" {
                    rows.push((name.clone(), model.parts.self_feed, b, median));
                }
            }
        }
    }
    if let Some(python) = pytorch {
        against_pytorch(python, &rows, batches, steps)?;
    }
    Ok(())
}

/// Median seconds per step of PyTorch eager on the paper's model, per batch
/// size, in one form of `xtask/py/pytorch_vrnn_step.py` (`hoisted` or not).
fn pytorch_medians(
    python: &Path,
    batches: &[usize],
    steps: usize,
    hoisted: bool,
) -> Result<Vec<(usize, f64)>> {
    let script = crate::workspace_root().join("xtask/py/pytorch_vrnn_step.py");
    let mut cmd = std::process::Command::new(python);
    cmd.arg(&script).arg("--batch");
    cmd.args(batches.iter().map(usize::to_string));
    cmd.args(["--steps", &steps.to_string()]);
    cmd.args(["--threads", &rayon::current_num_threads().to_string()]);
    if hoisted {
        cmd.arg("--hoisted");
    }
    let out = cmd
        .output()
        .with_context(|| format!("running {} {}", python.display(), script.display()))?;
    if !out.status.success() {
        anyhow::bail!(
            "{} {} failed (is PyTorch installed for it?):\n{}",
            python.display(),
            script.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let medians: Vec<(usize, f64)> = text
        .lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            Some((w.next()?.parse().ok()?, w.next()?.parse().ok()?))
        })
        .collect();
    if medians.len() != batches.len() {
        anyhow::bail!("unexpected output of {}:\n{text}", script.display());
    }
    Ok(medians)
}

/// Every model against PyTorch eager running the paper's model on this
/// machine (the faster of its two forms at each batch size), with the
/// speed bounds of issue 11: at least 1.5× faster at batch 1,600 and 5× at
/// batch 64; a model that trains on its own predictions at least 1× and 3×.
fn against_pytorch(
    python: &Path,
    rows: &[(String, f64, usize, f64)],
    batches: &[usize],
    steps: usize,
) -> Result<()> {
    let stepwise = pytorch_medians(python, batches, steps, false)?;
    let hoisted = pytorch_medians(python, batches, steps, true)?;
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
    for (name, feed, b, median) in rows {
        let Some(i) = batches.iter().position(|x| x == b) else {
            continue;
        };
        let torch = stepwise[i].1.min(hoisted[i].1);
        let speedup = torch / median;
        let bound = match (*feed > 0.0, *b >= 1600) {
            (false, true) => 1.5,
            (false, false) => 5.0,
            (true, true) => 1.0,
            (true, false) => 3.0,
        };
        println!(
            "{name:>9} {b:>6} {median:>10.4} {torch:>11.4} {speedup:>8.2}x {bound:>6.1}x {:>4}",
            if speedup >= bound { "yes" } else { "no" }
        );
    }
    Ok(())
}
