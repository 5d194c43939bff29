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
    /// Run directory (checkpoints, metrics, loss curve).
    #[arg(long, default_value = "runs/vrnn")]
    pub out: PathBuf,
    /// The model (`paper`, `smooth`, `skeletal`, `feet`, `fed`, `motion`; see docs/training.md).
    #[arg(long, default_value = motion_vrnn::model::DEFAULT_MODEL, value_parser = motion_vrnn::model::parse_name)]
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
    /// Override the largest share of frames fed back in training (scheduled sampling; 0: off).
    #[arg(long)]
    pub self_feed: Option<f64>,
    /// Override the model's rounds of feeding back (each from the previous round's; 1: one step deep; 0: every depth, one pass in time order).
    #[arg(long)]
    pub feed_rounds: Option<usize>,
    /// Override the sampling temperature (the prior's std × this, also for the judge; 1: as trained).
    #[arg(long)]
    pub temperature: Option<f64>,
    /// Feed back in training at that temperature, as sampling draws (docs/training.md).
    #[arg(long)]
    pub rollouts_at_temperature: bool,
    /// Keep generated figures' lowest joint at most this high above the floor (CMU units; 0: no limit).
    #[arg(long)]
    pub float_limit: Option<f64>,
    /// Planted toes (contact loss) must also move slower than this, m/s (0: height alone; docs/training.md).
    #[arg(long)]
    pub contact_speed: Option<f64>,
    /// Weight of the swing loss: the prior's one-step predictions must swing as far as real frames (0: off; docs/training.md).
    #[arg(long)]
    pub swing_weight: Option<f64>,
    /// Weight of the fed jerk loss: the frames fed back must jerk as much as real ones (0: off; needs --rollout-gradient; docs/training.md).
    #[arg(long)]
    pub fed_jerk_weight: Option<f64>,
    /// Weight of the fed speed loss: each window's fed frames must move the root as fast as real ones (0: off; through the whole rollout with --rollout-gradient, else one step deep; docs/training.md).
    #[arg(long)]
    pub fed_speed_weight: Option<f64>,
    /// Weight of the root's motion (vel_x, vel_z, ang_vel_y) in the squared error (1: the ELBO's; measured, not adopted; docs/training.md).
    #[arg(long)]
    pub root_weight: Option<f64>,
    /// Let the gradient flow through the fed-back frames (a step costs about 1.4× the default; needs --feed-rounds 0; docs/training.md).
    #[arg(long)]
    pub rollout_gradient: bool,
    /// After feeding back, one more round with the gradient: the rollout's gradient one level deep (docs/training.md).
    #[arg(long, conflicts_with = "rollout_gradient")]
    pub last_round_gradient: bool,
    /// Override the model's latent size (the paper's 8; docs/training.md, "Wider").
    #[arg(long)]
    pub latent: Option<usize>,
    /// Override the model's LSTM hidden size (the paper's 32).
    #[arg(long, value_parser = motion_vrnn::options::parse_size)]
    pub hidden: Option<usize>,
    /// Override the feature extractor's two layer sizes, `A,B` (the paper's 48,32; the `minute` preset's 64,32).
    #[arg(long, value_parser = motion_vrnn::options::parse_two_sizes)]
    pub extractor: Option<[usize; 2]>,
    /// Override the decoder's two layer sizes, `A,B` (the paper's 32,48; the `minute` preset's 64,96).
    #[arg(long, value_parser = motion_vrnn::options::parse_two_sizes)]
    pub decoder: Option<[usize; 2]>,
    /// Starting point for every option below (docs/training.md, "Presets").
    /// `minute`: `standard` with --feed-rounds 0 --rollouts-at-temperature
    /// --condition category+pace --judge-stretches 14 --judge-every 10 --inits 3
    /// --extractor 64,32 --decoder 64,96 --epochs 600 --early-stopping 0
    /// --rollout-last 300 --late-root-weight 8 (the last four for `motion`);
    /// `standard`: batch 64, 400 epochs, KL warm-up 20, clipping 100, early
    /// stopping 60; `quick`: 30 epochs; `paper`: the paper (batch 1,600).
    #[arg(long, default_value = "minute")]
    pub preset: Preset,
    /// Epochs (`minute`: 600 for `motion`, 400 for the others; `standard`: 400).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Windows per step.
    #[arg(long)]
    pub batch: Option<usize>,
    /// Adam learning rate.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Learning rate of the last epoch as a share of --lr, reached along a half cosine over the second half of the epochs (1: constant).
    #[arg(long)]
    pub lr_final: Option<f64>,
    /// Seed of initialisation, shuffling and noise.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Initialisations tried for 20 epochs each, the best on validation kept (1: the seed's alone; `minute`: 3; docs/training.md).
    #[arg(long)]
    pub inits: Option<usize>,
    /// Fed-back frames in runs of this many consecutive frames (1: each on its own).
    #[arg(long)]
    pub feed_run: Option<usize>,
    /// Judge and keep as `best` a moving average of the weights with this decay per step, e.g. 0.95 (0: off; needs --select generation; docs/training.md).
    #[arg(long)]
    pub average: Option<f64>,
    /// Also train on the windows' left-right mirror images, each window mirrored every other epoch (measured, not adopted; docs/training.md).
    #[arg(long)]
    pub mirror: bool,
    /// Train the last N epochs with the gradient through the fed-back frames and the fed speed loss (weight 1 unless --fed-speed-weight; `minute`: 300, every epoch when there are fewer; 0: none; a late step costs 1.4–1.6× an early one; docs/training.md).
    #[arg(long, value_name = "N")]
    pub rollout_last: Option<usize>,
    /// Weight of the root's motion in the squared error in those last N epochs only (`minute`: 8; 1: the ELBO's; needs late epochs; docs/training.md).
    #[arg(long, value_name = "W")]
    pub late_root_weight: Option<f64>,
    /// KL warm-up epochs (0: off).
    #[arg(long)]
    pub kl_warmup: Option<usize>,
    /// Clip the global gradient norm (0: off).
    #[arg(long)]
    pub clip: Option<f64>,
    /// Early-stopping patience in epochs (0: off).
    #[arg(long)]
    pub early_stopping: Option<usize>,
    /// How `best` is chosen: `generation` (every --judge-every epochs, 200 motions continuing 16 frames of training windows, one draw at guidance 1, measured on their first and last stretch against the training windows; the validation windows give the Fréchet reference) or `loss` (lowest validation loss; the paper preset's).
    #[arg(long)]
    pub select: Option<SelectBy>,
    /// Epochs between two judgements of generated motion (--select generation).
    #[arg(long)]
    pub judge_every: Option<usize>,
    /// Window-long stretches the judge rolls its motions out for (scores the first and the last; 1: one window).
    #[arg(long)]
    pub judge_stretches: Option<usize>,
    /// `category` (the `standard` preset's): condition on each window's category, so `sample --category walk` can ask for one; `category+pace` (`minute`'s): and on its pace; `category+pace+speed`: the pace with the root's mean speed (measured, not adopted); `none`: neither (`quick`, `paper`).
    #[arg(long)]
    pub condition: Option<ConditionOn>,
    /// Share of windows trained without their category (--condition category).
    #[arg(long)]
    pub condition_dropout: Option<f64>,
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
    /// field of [`Overrides`] of the same name (a field left out, or one
    /// `Overrides` lacks, does not compile).
    fn overrides(&self) -> Overrides {
        macro_rules! same_names {
            ($($f:ident)*) => { Overrides { $($f: self.$f),* } };
        }
        same_names! {
            latent_filter output_filter feet_weight kl_weight self_feed feed_rounds temperature
            latent hidden extractor decoder epochs batch lr lr_final seed kl_warmup clip early_stopping select judge_every
            judge_stretches condition condition_dropout rollouts_at_temperature float_limit
            contact_speed swing_weight fed_jerk_weight fed_speed_weight root_weight rollout_gradient last_round_gradient inits
            feed_run average mirror rollout_last late_root_weight
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
    if !a.quiet {
        eprintln!(
            "training the {} model{} on {} train / {} val windows from {} on {}; batch {}, {} epochs, lr {}",
            a.model,
            cfg.extras(),
            n("train"),
            n("val"),
            a.data.display(),
            motion_vrnn::model::device_name(&device),
            cfg.batch,
            cfg.epochs,
            cfg.adam.lr
        );
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
