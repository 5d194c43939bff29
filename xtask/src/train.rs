//! `cargo xtask train`.

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use motion_vrnn::bench;
use motion_vrnn::classifier::{self, ClassifierTraining};
use motion_vrnn::model::Config;
use motion_vrnn::options::{ConditionOn, Overrides, Preset, SelectBy};
use motion_vrnn::train::{layout, train, EpochMetrics, TrainProgress};
use std::path::PathBuf;

#[derive(Args)]
pub struct TrainArgs {
    /// Dataset directory written by `cargo xtask dataset`.
    #[arg(long, default_value = "data/datasets/cmu")]
    pub data: PathBuf,
    /// Run directory: checkpoints, metrics, loss curve.
    #[arg(long, default_value = "runs/vrnn")]
    pub out: PathBuf,
    /// The model: `paper`, `smooth`, `skeletal`, `feet`, `fed` or `motion` (docs/training.md).
    #[arg(long, default_value = motion_vrnn::model::DEFAULT_MODEL, value_parser = motion_vrnn::model::parse_name)]
    pub model: String,
    /// The settings the options below replace: `minute` (a minute of motion), `standard`, `quick` or `paper` (docs/training.md).
    #[arg(long, default_value = "minute")]
    pub preset: Preset,
    /// Epochs, in place of the budget (minute: the budget's; standard: 400; quick: 30; paper: 2000).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Training windows seen: the epochs and every count of epochs below scaled to the dataset, the preset's for the shared samples' 776 windows (minute: its epochs × 776, 465,600 with `motion`; the others: none).
    #[arg(long, value_name = "WINDOWS")]
    pub budget: Option<u64>,
    /// Windows per step (paper: 1600; the others: 64).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Adam learning rate (0.001).
    #[arg(long)]
    pub lr: Option<f64>,
    /// Learning rate of the last epoch as a share of --lr, reached along a half cosine over the second half (minute, standard: 0.1; quick, paper: 1, constant).
    #[arg(long)]
    pub lr_final: Option<f64>,
    /// Seed of initialisation, shuffling and noise (0).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Initialisations tried for 20 epochs each, the best on validation kept (minute: 3; the others: 1).
    #[arg(long)]
    pub inits: Option<usize>,
    /// The feature extractor's two layer sizes, `A,B` (minute: 64,32; the others: 48,32).
    #[arg(long, value_parser = motion_vrnn::options::parse_two_sizes)]
    pub extractor: Option<[usize; 2]>,
    /// The decoder's two layer sizes, `A,B` (minute: 64,96; the others: 32,48).
    #[arg(long, value_parser = motion_vrnn::options::parse_two_sizes)]
    pub decoder: Option<[usize; 2]>,
    /// Sampling temperature saved with the model; the judge samples at it, and the minute preset draws its fed-back frames at it (`motion`: 0.7; the others: 1).
    #[arg(long)]
    pub temperature: Option<f64>,
    /// Train the last N epochs with the gradient through the fed-back frames and the fed speed loss (minute with `motion`: 300; else 0, none).
    #[arg(long, value_name = "N")]
    pub rollout_last: Option<usize>,
    /// Weight of the root's motion in the squared error in those last N epochs (minute with `motion`: 8; else 1, the ELBO's).
    #[arg(long, value_name = "W")]
    pub late_root_weight: Option<f64>,
    /// Epochs over which the KL weight rises from 0 to 1 (minute, standard: 20; quick: 5; paper: 0, off).
    #[arg(long)]
    pub kl_warmup: Option<usize>,
    /// Clip the global gradient norm at this (paper: 0, off; the others: 100).
    #[arg(long)]
    pub clip: Option<f64>,
    /// Stop after this many epochs without a lower validation loss (minute with `motion`, paper: 0, off; minute, standard: 60; quick: 10).
    #[arg(long)]
    pub early_stopping: Option<usize>,
    /// How `best` is chosen: `generation` (every --judge-every epochs, 200 motions continuing 16 frames of training windows, one draw at guidance 1, measured on their first and last stretch against the training windows; the validation windows give the Fréchet reference) or `loss` (lowest validation loss; the paper preset's).
    #[arg(long)]
    pub select: Option<SelectBy>,
    /// Epochs between two judgements of generated motion with --select generation (minute: 10; standard: 5).
    #[arg(long)]
    pub judge_every: Option<usize>,
    /// Window-long stretches the judge rolls its motions out for, scoring the first and the last (minute: 14; the others: 1).
    #[arg(long)]
    pub judge_stretches: Option<usize>,
    /// What the model is conditioned on, so `sample --category walk` can ask for one: `category+pace+control` (minute: a model that can be steered), `category+pace`, `category` (standard) or `none` (quick, paper).
    #[arg(long)]
    pub condition: Option<ConditionOn>,
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
    /// A line above the bar, or on stderr when the bar is hidden (no terminal: it would print nothing).
    fn println(&self, line: &str) {
        if self.0.is_hidden() {
            eprintln!("{line}");
        } else {
            self.0.println(line);
        }
    }
}

impl TrainArgs {
    /// The options that replace the preset's values: each option is the
    /// field of [`Overrides`] of the same name, and the fields only a preset
    /// sets are left as they are (a field left out, or one `Overrides`
    /// lacks, does not compile).
    fn overrides(&self) -> Overrides {
        macro_rules! same_names {
            ($($f:ident)*) => {
                Overrides { $($f: self.$f,)* feed_rounds: None, rollouts_at_temperature: false }
            };
        }
        same_names! {
            temperature extractor decoder epochs budget batch lr lr_final seed kl_warmup clip early_stopping
            select judge_every judge_stretches condition inits rollout_last late_root_weight
        }
    }
}

pub fn run(a: TrainArgs) -> Result<()> {
    let model = Config::named(&a.model).context("unknown model")?;
    let mut cfg = a.preset.for_model(model);
    a.overrides().apply(&mut cfg);
    let device = motion_vrnn::model::default_device();
    let data = motion_vrnn::data::load(&a.data, &["train", "val"]).with_context(|| {
        format!(
            "loading the dataset {} (build it with `cargo xtask dataset`)",
            a.data.display()
        )
    })?;
    let n = |s: &str| data.splits.get(s).map_or(0, |w| w.n);
    let cfg = cfg.for_windows(n("train"));
    if !a.quiet {
        let windows = (n("train"), n("val"));
        eprintln!("{}", cfg.announce(&a.model, windows, &a.data, &device));
        if device.is_cuda() {
            eprintln!("note: these small recurrent models train several times faster on the CPU (docs/training.md, \"GPU\"); `CUDA_VISIBLE_DEVICES= cargo xtask train …` runs there");
        }
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

/// `cargo xtask bench-train` ([`motion_vrnn::bench::report`], printed as it goes).
pub fn bench(a: BenchArgs) -> Result<()> {
    let script = crate::workspace_root().join("xtask/py/pytorch_vrnn_step.py");
    let py = a.pytorch.as_deref().map(|p| (p, script.as_path()));
    let device = motion_vrnn::model::default_device();
    let print = &mut |line: &str| println!("{line}");
    let b = bench::Bench {
        models: &a.models,
        batches: &a.batch,
        steps: a.steps,
        reference: a.autograd,
        blocks: a.blocks,
        pytorch: py,
        rounds: a.rounds,
    };
    bench::report(&b, &device, print)?;
    Ok(())
}

#[derive(Args)]
pub struct BenchArgs {
    /// Batch sizes.
    #[arg(long, value_delimiter = ',', default_values_t = [1600, 64])]
    batch: Vec<usize>,
    /// Timed steps per batch size (after 2 warm-up steps).
    #[arg(long, default_value_t = 5)]
    steps: usize,
    /// Models to time (default: every model, then `motion+category` (`--preset standard`) and `minute`, what `train` trains by default).
    #[arg(long = "model", value_parser = bench::parse_model)]
    models: Vec<String>,
    /// Also time each model through candle ops and autograd (the blocks' reference path).
    #[arg(long)]
    autograd: bool,
    /// Also print where each step's time goes, block by block.
    #[arg(long)]
    blocks: bool,
    /// A Python with PyTorch: also time the paper's model in PyTorch eager (`xtask/py/pytorch_vrnn_step.py`) and print every model's speed-up against it.
    #[arg(long, value_name = "PYTHON")]
    pytorch: Option<PathBuf>,
    /// Run the whole bench (PyTorch included) this many times in turn and give each speed-up as the median over the rounds, with its range.
    #[arg(long, default_value_t = 1)]
    rounds: usize,
}

/// `cargo xtask train-classifier` ([`motion_vrnn::classifier`]).
pub fn classifier(a: ClassifierArgs) -> Result<()> {
    let data = motion_vrnn::data::load(&a.data, &["train", "test"])
        .with_context(|| format!("loading the dataset {}", a.data.display()))?;
    let mut t = ClassifierTraining {
        seed: a.seed,
        ..Default::default()
    };
    t.epochs = a.epochs.unwrap_or(t.epochs);
    let device = motion_vrnn::model::default_device();
    let report = classifier::train_and_measure(&data, &a.out, &t, &device)?;
    print!("{report}");
    Ok(())
}

#[derive(Args)]
pub struct ClassifierArgs {
    /// Dataset directory written by `cargo xtask dataset`.
    #[arg(long, default_value = "data/datasets/cmu")]
    data: PathBuf,
    /// Classifier directory (classifier.safetensors, classifier.json).
    #[arg(long, default_value = "runs/classifier")]
    out: PathBuf,
    /// Seed of initialisation, shuffles and the measures' draws.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Epochs (default 30).
    #[arg(long)]
    epochs: Option<usize>,
}
