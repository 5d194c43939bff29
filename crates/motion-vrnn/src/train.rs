//! Training: Adam over shuffled windows, validation each epoch, metrics log,
//! `best` and `last` checkpoints (safetensors + JSON, written atomically),
//! exact resume, a NaN guard.

use crate::data::{Category, Dataset, Windows};
use crate::error::io_err;
pub use crate::error::TrainError;
use crate::generate::{Judge, Verdict};
use crate::model::{Config, Losses, MotionModel, Vrnn};
use crate::optim::{clip_grad_norm, Adam, AdamConfig};
pub use crate::rng::noise;
use crate::rng::Rng;
use candle_core::backprop::GradStore;
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// Training options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Model sizes.
    pub model: Config,
    /// Optimiser.
    pub adam: AdamConfig,
    /// Windows per step.
    pub batch: usize,
    /// Epochs to run.
    pub epochs: usize,
    /// Seed of initialisation, shuffling and noise.
    pub seed: u64,
    /// Epochs over which the KL weight rises linearly from 0 to 1 (0: off).
    pub kl_warmup_epochs: usize,
    /// Clip the global gradient norm to this (None: off).
    pub clip_grad_norm: Option<f64>,
    /// Stop after this many epochs without a better validation loss (None: off).
    pub early_stopping: Option<usize>,
    /// How the `best` checkpoint is chosen.
    #[serde(default, skip_serializing_if = "Select::is_loss")]
    pub select: Select,
    /// Learning rate of the last epoch as a share of `adam.lr`: the rate
    /// stays at `adam.lr` over the first half of the epochs and falls along a
    /// half cosine to this share over the second half (None: constant).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lr_final: Option<f64>,
    /// Window-long stretches the judge rolls its motions out for (None or
    /// 1: one window); with more it scores the first and the last stretch
    /// ([`crate::generate::Judge`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_stretches: Option<usize>,
    /// Condition the model on each window's category (`--condition
    /// category`); None: an unconditioned model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub condition: Option<Conditioning>,
    /// Start from the best of several initialisations ([`Inits`]; None:
    /// from the seed's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inits: Option<Inits>,
    /// Train the last this many epochs with the gradient through the
    /// fed-back frames and the fed speed loss (`--rollout-last`;
    /// [`TrainConfig::late_model`]); None: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rollout_last: Option<usize>,
    /// The root's weight in the squared error in those last epochs only
    /// (`--late-root-weight`; [`crate::model::Parts::root_weight`]); None:
    /// the model's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub late_root_weight: Option<f64>,
}

/// Weight of the fed speed loss in the epochs of
/// [`TrainConfig::rollout_last`].
pub const LATE_SPEED_WEIGHT: f64 = 1.0;

/// Epochs each initialisation is trained before they are compared
/// (`--inits`): by epoch 20 the weak initialisations of the default have
/// fallen behind for good (`docs/training.md`, "The best of several
/// initialisations").
pub const INIT_EPOCHS: usize = 20;

/// Several initialisations, each trained for a few epochs (nothing
/// written), the one with the lowest validation loss kept: the run then
/// trains from it as if it were the seed's. Candidate `k` draws its weights
/// from `seed + k·2³²` (candidate 0 is the seed's own); shuffles, noise
/// and masks come from the seed for every candidate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Inits {
    /// Initialisations tried.
    pub candidates: usize,
    /// Epochs each is trained before they are compared.
    pub epochs: usize,
}

impl Inits {
    /// The seed of candidate `k`'s weights.
    pub fn seed(&self, seed: u64, k: usize) -> u64 {
        seed.wrapping_add((k as u64) << 32)
    }
}

/// The initialisation a run with [`TrainConfig::inits`] kept.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InitChoice {
    /// The seed its weights were drawn from.
    pub seed: u64,
    /// Every candidate's validation loss after [`Inits::epochs`], in order.
    pub val_losses: Vec<f64>,
}

/// Training conditioned on the category of each window's take.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Conditioning {
    /// Share of training windows shown with no category (drawn per window
    /// and step from the seed), so the same model also generates without
    /// one (row 0 of the condition table).
    pub dropout: f64,
}

/// The default share of windows trained without their category (MDM's).
pub const CONDITION_DROPOUT: f64 = 0.1;

/// How training chooses its `best` checkpoint.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Select {
    /// The epoch with the lowest validation loss (recon + KL).
    #[default]
    Loss,
    /// Every `every` epochs once the schedule is in full
    /// ([`TrainConfig::schedule_end`]), and at the last one, motions are
    /// generated and measured against the training windows
    /// ([`crate::generate::Judge`]); the epoch whose motion is closest to
    /// real motion on every measure at once is kept.
    Generation {
        /// Epochs between two judgements.
        every: usize,
    },
}

impl Select {
    /// The paper's choice (by validation loss).
    pub fn is_loss(&self) -> bool {
        *self == Select::Loss
    }
}

impl TrainConfig {
    /// The paper's settings: Adam 1e-3, batch 1,600, 2,000 epochs, no warm-up,
    /// no clipping, no early stopping.
    pub fn paper() -> Self {
        TrainConfig {
            model: Config::default(),
            adam: AdamConfig::default(),
            batch: 1600,
            epochs: 2000,
            seed: 0,
            kl_warmup_epochs: 0,
            clip_grad_norm: None,
            early_stopping: None,
            select: Select::Loss,
            lr_final: None,
            judge_stretches: None,
            condition: None,
            inits: None,
            rollout_last: None,
            late_root_weight: None,
        }
    }

    /// The default schedule (converges on the shared CMU samples in
    /// minutes): the default model conditioned on the category, batch 64,
    /// 400 epochs, KL warm-up over 20 epochs, clipping at 100, early
    /// stopping after 60 epochs without improvement, `best` chosen by
    /// generated motion every 5 epochs, the learning rate annealed to a
    /// tenth over the second half.
    pub fn standard() -> Self {
        TrainConfig {
            model: Config::named(crate::model::DEFAULT_MODEL).unwrap_or_default(),
            batch: 64,
            epochs: 400,
            kl_warmup_epochs: 20,
            clip_grad_norm: Some(100.0),
            early_stopping: Some(60),
            select: Select::Generation { every: 5 },
            lr_final: Some(0.1),
            condition: Some(Conditioning {
                dropout: CONDITION_DROPOUT,
            }),
            ..Self::paper()
        }
    }

    /// A quick look: batch 64, 30 epochs, KL warm-up over 5 epochs, clipping
    /// at 100, early stopping after 10 epochs without improvement.
    pub fn quick() -> Self {
        TrainConfig {
            batch: 64,
            epochs: 30,
            kl_warmup_epochs: 5,
            clip_grad_norm: Some(100.0),
            early_stopping: Some(10),
            ..Self::paper()
        }
    }

    /// KL weight in `epoch` (0-based).
    pub fn kl_weight(&self, epoch: usize) -> f64 {
        let full = self.model.parts.kl_weight.unwrap_or(1.0);
        if self.kl_warmup_epochs == 0 {
            full
        } else {
            full * ((epoch + 1) as f64 / self.kl_warmup_epochs as f64).min(1.0)
        }
    }

    /// What the run adds to its model, as `train` announces it: the
    /// condition, feed rounds at the sampling temperature, the late epochs,
    /// a judge over several stretches, several initialisations (empty for
    /// none).
    pub fn extras(&self) -> String {
        let mut s = String::new();
        if self.condition.is_some() {
            s += match self.model.parts.pace {
                true => " conditioned on the category and its pace (--condition none: neither)",
                false => " conditioned on the category (--condition none: without)",
            };
        }
        let every_depth = self.model.parts.self_feed > 0.0 && self.model.parts.rounds() == 0;
        s += match (every_depth, self.model.parts.rollouts_at_temperature) {
            (true, true) => ", fed back to every depth at the sampling temperature",
            (true, false) => ", fed back to every depth",
            (false, true) => ", fed back at the sampling temperature",
            (false, false) => "",
        };
        if let Some(n) = self.rollout_last {
            s += &format!(", the last {n} epochs through the rollout with the fed speed loss");
            if let Some(w) = self.late_root_weight {
                s += &format!(" and the root's motion weighed {w}");
            }
        }
        if let Some(n) = self.judge_stretches {
            s += &format!(", judged over {n} stretches");
        }
        if let Some(i) = self.inits {
            s += &format!(
                ", from the best of {} initialisations after {} epochs",
                i.candidates, i.epochs
            );
        }
        s
    }

    /// The first epoch (1-based, as in the metrics) trained with the
    /// schedule in full: the KL weight warmed up and the share of frames fed
    /// back at its maximum. [`Select::Generation`] judges no epoch before it
    /// (an earlier model is not the model as trained: on `motion` the judge
    /// otherwise once kept epoch 35 of 400, whose reconstructions were half
    /// as jerky as real motion).
    pub fn schedule_end(&self) -> usize {
        let feed = if self.model.parts.self_feed > 0.0 {
            (self.epochs / 2).max(1)
        } else {
            0
        };
        self.kl_warmup_epochs.max(feed).min(self.epochs)
    }

    /// Learning rate in `epoch` (0-based): `adam.lr` over the first half of
    /// the epochs, then a half cosine down to `adam.lr × lr_final` at the
    /// last epoch.
    pub fn lr(&self, epoch: usize) -> f64 {
        let Some(last) = self.lr_final else {
            return self.adam.lr;
        };
        let half = self.epochs / 2;
        let span = self.epochs.saturating_sub(half).max(1);
        let p = ((epoch + 1).saturating_sub(half) as f64 / span as f64).min(1.0);
        let share = last + (1.0 - last) * 0.5 * (1.0 + (std::f64::consts::PI * p).cos());
        self.adam.lr * share
    }

    /// The model's configuration in `epoch` (0-based) where it differs
    /// from [`TrainConfig::model`]: in the last [`TrainConfig::rollout_last`]
    /// epochs, with [`crate::model::Parts::rollout_gradient`], the fed speed
    /// loss weighed [`LATE_SPEED_WEIGHT`], and the root's weight
    /// [`TrainConfig::late_root_weight`] where given.
    pub fn late_model(&self, epoch: usize) -> Option<Config> {
        let n = self.rollout_last?;
        (epoch + n >= self.epochs).then(|| {
            let mut c = self.model.clone();
            c.parts.rollout_gradient = true;
            c.parts.fed_speed = Some(LATE_SPEED_WEIGHT);
            if let Some(w) = self.late_root_weight {
                c.parts.root_weight = Some(w);
            }
            c
        })
    }

    /// Share of frames fed back in `epoch` (0-based; scheduled sampling):
    /// rises linearly from 0 to the model's `self_feed` over the first half
    /// of the epochs.
    pub fn feed_share(&self, epoch: usize) -> f64 {
        let ramp = (self.epochs / 2).max(1);
        self.model.parts.self_feed * ((epoch + 1) as f64 / ramp as f64).min(1.0)
    }
}

/// The scheduled-sampling mask of a step: `[B, T]`, each frame fed with
/// probability `share`, from the run's seed and the step, so it is the same
/// for any thread count and after a resume (None when `share` is 0).
pub fn feed_mask(
    seed: u64,
    step: u64,
    b: usize,
    t: usize,
    share: f64,
    device: &Device,
) -> candle_core::Result<Option<Tensor>> {
    if share <= 0.0 {
        return Ok(None);
    }
    let mut rng = Rng::new(seed ^ 0xFEED_0000_0000, step);
    let v: Vec<f32> = (0..b * t)
        .map(|_| if rng.uniform() < share { 1.0 } else { 0.0 })
        .collect();
    Tensor::from_vec(v, (b, t), device).map(Some)
}

/// One epoch's metrics (a line of `metrics.jsonl`). Losses are summed over
/// the frames of a window and averaged over windows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochMetrics {
    /// Epoch (1-based).
    pub epoch: usize,
    /// Global step at the end of the epoch.
    pub step: u64,
    /// Train reconstruction loss (mean over the epoch's batches).
    pub train_recon: f64,
    /// Train KL.
    pub train_kl: f64,
    /// Validation reconstruction loss.
    pub val_recon: f64,
    /// Validation KL.
    pub val_kl: f64,
    /// KL weight used.
    pub kl_weight: f64,
    /// Learning rate used ([`TrainConfig::lr`]; absent in runs from before
    /// the schedule existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lr: Option<f64>,
    /// Training throughput, windows per second.
    pub windows_per_s: f64,
    /// Seconds of this epoch (judging included).
    pub seconds: f64,
    /// The generated motion, measured, in the epochs that were judged
    /// ([`Select::Generation`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generated: Option<Verdict>,
}

impl EpochMetrics {
    /// Validation loss (recon + KL, unweighted): what `best` minimises.
    pub fn val_loss(&self) -> f64 {
        self.val_recon + self.val_kl
    }
}

/// What a checkpoint's JSON says.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointMeta {
    /// Training options.
    pub config: TrainConfig,
    /// SHA-256 of the dataset's manifest.json.
    pub dataset_manifest_sha256: String,
    /// The dataset directory.
    pub dataset: String,
    /// Epochs completed.
    pub epoch: usize,
    /// Optimiser steps completed.
    pub step: u64,
    /// Best validation loss so far and its epoch.
    pub best_val_loss: f64,
    /// Epoch of the best validation loss.
    pub best_epoch: usize,
    /// With [`Select::Generation`]: the best judged score so far and its
    /// epoch (the `best` checkpoint).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_generated: Option<(f64, usize)>,
    /// With [`TrainConfig::inits`]: the initialisation kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<InitChoice>,
    /// Metrics of the last epoch.
    pub metrics: Option<EpochMetrics>,
}

/// Progress callbacks for a caller's progress bar.
pub trait TrainProgress {
    /// After each optimiser step.
    fn step(&self, epoch: usize, step: u64, recon: f32, kl: f32, windows_per_s: f64);
    /// After each epoch.
    fn epoch(&self, metrics: &EpochMetrics);
    /// Something the user should know that does not stop training (e.g. a
    /// resume that found no checkpoint and started from scratch).
    fn note(&self, _message: &str) {}
}

/// No progress output.
pub struct Quiet;

impl TrainProgress for Quiet {
    fn step(&self, _: usize, _: u64, _: f32, _: f32, _: f64) {}
    fn epoch(&self, _: &EpochMetrics) {}
}

/// A model with its variables.
pub struct Trained {
    /// The variables.
    pub varmap: VarMap,
    /// The model.
    pub model: Vrnn,
}

/// Build a model with deterministic initial weights from `seed`:
/// `U(−1/√fan_in, 1/√fan_in)` for every weight and bias (PyTorch's default
/// for linear and LSTM layers), filled in name order.
pub fn init_model(config: &Config, seed: u64, device: &Device) -> Result<Trained, TrainError> {
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, device);
    let model = Vrnn::new(config, vb)?;
    init_uniform(
        &varmap,
        seed,
        |name| name.starts_with("rnn.").then_some(config.hidden),
        device,
    )?;
    Ok(Trained { varmap, model })
}

/// Fill every variable of `varmap`, in name order, with
/// `U(−1/√fan_in, 1/√fan_in)` drawn from `seed`: a `….weight`'s fan-in is
/// its second dimension, a `….bias` takes its weight's, and `fixed(name)`
/// overrides both where it returns one. The condition table
/// ([`crate::model::COND_WEIGHT`]) keeps its zeros and draws nothing, so
/// the other variables get the values they get without it.
pub fn init_uniform(
    varmap: &VarMap,
    seed: u64,
    fixed: impl Fn(&str) -> Option<usize>,
    device: &Device,
) -> candle_core::Result<()> {
    let mut vars = named_vars(varmap);
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    let fan_in: HashMap<String, usize> = vars
        .iter()
        .filter(|(n, _)| n.contains("weight"))
        .map(|(n, v)| (n.clone(), v.dims().get(1).copied().unwrap_or(1)))
        .collect();
    let mut rng = Rng::new(seed, 0x1417);
    for (name, var) in vars.iter().filter(|(n, _)| n != crate::model::COND_WEIGHT) {
        let fan = fixed(name).unwrap_or_else(|| {
            let w = name.replace(".bias", ".weight");
            fan_in.get(&w).copied().unwrap_or(1)
        });
        let bound = 1.0 / (fan as f64).sqrt();
        let n = var.elem_count();
        let vals: Vec<f32> = (0..n)
            .map(|_| ((rng.uniform() * 2.0 - 1.0) * bound) as f32)
            .collect();
        var.set(&Tensor::from_vec(vals, var.shape(), device)?)?;
    }
    Ok(())
}

/// The variables of a var map with their names.
pub fn named_vars(varmap: &VarMap) -> Vec<(String, Var)> {
    let data = varmap.data().lock().unwrap_or_else(|p| p.into_inner());
    data.iter().map(|(k, v)| (k.clone(), v.clone())).collect()
}

/// Tells glibc's allocator to keep freed buffers in the process. A step
/// allocates and frees the same few MiB per shard many times (every block's
/// output, candle's gradients); by default glibc hands such buffers to the
/// kernel and back (`mmap`, `munmap`, zeroed pages): a sixth of the CPU
/// time of a `motion` step at batch 64 (`perf stat`: 5.36 against 4.42 s
/// for 60 steps). With the thresholds raised, they
/// are reused. Call once at start-up, before other threads allocate; it
/// changes no result. Elsewhere (not glibc) it does nothing.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // glibc's `mallopt` parameters (malloc.h).
        const M_TRIM_THRESHOLD: i32 = -1;
        const M_MMAP_THRESHOLD: i32 = -3;
        extern "C" {
            fn mallopt(param: i32, value: i32) -> i32;
        }
        // SAFETY: `mallopt` only sets allocator parameters; both values are
        // within glibc's limits (the mmap threshold's is 32 MiB).
        unsafe {
            mallopt(M_MMAP_THRESHOLD, 32 << 20);
            mallopt(M_TRIM_THRESHOLD, 512 << 20);
        }
    }
}

/// Windows per shard: a batch is cut into shards of this many windows, run
/// in parallel, and their results summed in shard order, so every number
/// is the same for any thread count.
pub const SHARD: usize = 32;

/// The losses of a batch `(recon, kl)` (means over its windows) and, with
/// `grad = Some((kl_weight, vars))`, the gradients of `recon + kl_weight · kl`
/// for `vars`: shard by shard on the CPU (in parallel, summed in shard
/// order), whole elsewhere.
pub fn sharded(
    model: &dyn MotionModel,
    x: &Tensor,
    eps: &Tensor,
    feed: Option<&Tensor>,
    cond: Option<&Tensor>,
    grad: Option<(f64, &[Var])>,
) -> candle_core::Result<((f32, f32), Option<GradStore>)> {
    let b = x.dim(0)?;
    type Part = ((f64, f64), Vec<Option<Tensor>>);
    let run = |x: &Tensor,
               eps: &Tensor,
               feed: Option<&Tensor>,
               cond: Option<&Tensor>|
     -> candle_core::Result<Part> {
        let l: Losses = model.losses(x, eps, feed, cond)?;
        let n = x.dim(0)? as f64;
        let scale = n / b as f64;
        let grads = match grad {
            Some((w, vars)) => {
                let store = (((&l.recon + (&l.kl * w)?)? + &l.extra)? * scale)?.backward()?;
                vars.iter().map(|v| store.get(v).cloned()).collect()
            }
            None => Vec::new(),
        };
        let (r, k) = (l.recon.to_scalar::<f32>()?, l.kl.to_scalar::<f32>()?);
        Ok(((r as f64 * scale, k as f64 * scale), grads))
    };
    let parts: Vec<Part> = if !x.device().is_cpu() || b <= SHARD {
        vec![run(x, eps, feed, cond)?]
    } else {
        let starts: Vec<usize> = (0..b).step_by(SHARD).collect();
        starts
            .par_iter()
            .map(|&s| {
                let n = SHARD.min(b - s);
                let feed = feed.map(|f| f.narrow(0, s, n)).transpose()?;
                let cond = cond.map(|c| c.narrow(0, s, n)).transpose()?;
                run(
                    &x.narrow(0, s, n)?,
                    &eps.narrow(1, s, n)?,
                    feed.as_ref(),
                    cond.as_ref(),
                )
            })
            .collect::<candle_core::Result<_>>()?
    };
    let (recon, kl) = parts
        .iter()
        .fold((0.0, 0.0), |(r, k), p| (r + p.0 .0, k + p.0 .1));
    let grads = match grad {
        None => None,
        Some((_, vars)) => Some(sum_gradients(
            vars,
            &parts.iter().map(|p| p.1.as_slice()).collect::<Vec<_>>(),
        )?),
    };
    Ok(((recon as f32, kl as f32), grads))
}

/// The gradients of shards summed in shard order into one store:
/// `shards[s][i]` is shard `s`'s gradient of `vars[i]` (None: it has none).
pub fn sum_gradients(vars: &[Var], shards: &[&[Option<Tensor>]]) -> candle_core::Result<GradStore> {
    let mut store = GradStore::default();
    for (i, v) in vars.iter().enumerate() {
        let mut sum: Option<Tensor> = None;
        for p in shards {
            if let Some(g) = &p[i] {
                sum = Some(match sum {
                    None => g.clone(),
                    Some(s) => (s + g)?,
                });
            }
        }
        if let Some(s) = sum {
            store.insert(v, s);
        }
    }
    Ok(store)
}

/// Mean losses over all windows of a split, in batches, with fixed noise
/// (a conditioned model reads each window's category of `categories`).
pub fn evaluate(
    model: &dyn MotionModel,
    windows: &Windows,
    categories: &[Category],
    batch: usize,
    seed: u64,
    device: &Device,
) -> Result<(f64, f64), TrainError> {
    let mut recon = 0.0;
    let mut kl = 0.0;
    let idx: Vec<usize> = (0..windows.n).collect();
    for (k, chunk) in idx.chunks(batch.max(1)).enumerate() {
        let x = windows.batch(chunk, device)?;
        let eps = noise(
            seed ^ 0xE7A1,
            k as u64,
            windows.length,
            chunk.len(),
            model.config().latent,
            device,
        )?;
        let cond = model
            .config()
            .window_condition(categories, chunk, 1.0, |_| false, device)?;
        let (r, k) = sharded(model, &x, &eps, None, cond.as_ref(), None)?.0;
        let w = chunk.len() as f64;
        recon += r as f64 * w;
        kl += k as f64 * w;
    }
    let n = windows.n.max(1) as f64;
    Ok((recon / n, kl / n))
}

/// Files of a run directory.
pub mod layout {
    /// Metrics log, one JSON object per epoch.
    pub const METRICS: &str = "metrics.jsonl";
    /// Latest checkpoint (with optimiser state).
    pub const LAST: &str = "last";
    /// The chosen checkpoint: lowest validation loss, or best generated
    /// motion ([`super::Select`]).
    pub const BEST: &str = "best";
    /// Model weights inside a checkpoint directory.
    pub const MODEL: &str = "model.safetensors";
    /// Optimiser moments inside a checkpoint directory.
    pub const OPTIMIZER: &str = "optimizer.safetensors";
    /// Checkpoint metadata inside a checkpoint directory.
    pub const META: &str = "checkpoint.json";
}

fn save_checkpoint(
    run: &Path,
    name: &str,
    varmap: &VarMap,
    adam: Option<&Adam>,
    meta: &CheckpointMeta,
) -> Result<(), TrainError> {
    let staging = run.join(format!(".{name}.tmp-{}", std::process::id()));
    if staging.exists() {
        std::fs::remove_dir_all(&staging).map_err(|e| io_err(&staging, e))?;
    }
    std::fs::create_dir_all(&staging).map_err(|e| io_err(&staging, e))?;
    let weights: HashMap<String, Tensor> = named_vars(varmap)
        .into_iter()
        .map(|(k, v)| (k, v.as_tensor().clone()))
        .collect();
    let mp = staging.join(layout::MODEL);
    candle_core::safetensors::save(&weights, &mp).map_err(|e| io_err(&mp, e))?;
    if let Some(adam) = adam {
        let op = staging.join(layout::OPTIMIZER);
        candle_core::safetensors::save(&adam.state(), &op).map_err(|e| io_err(&op, e))?;
    }
    let jp = staging.join(layout::META);
    let text = serde_json::to_string_pretty(meta).map_err(|e| io_err(&jp, e))?;
    std::fs::write(&jp, text + "\n").map_err(|e| io_err(&jp, e))?;
    for f in [layout::MODEL, layout::OPTIMIZER, layout::META] {
        if let Ok(file) = std::fs::File::open(staging.join(f)) {
            file.sync_all().map_err(|e| io_err(&staging.join(f), e))?;
        }
    }
    mocap_ingest::atomic::replace_dir(&staging, &run.join(name))
        .map_err(|e| io_err(&run.join(name), e))
}

/// Read a checkpoint's metadata.
pub fn read_meta(dir: &Path) -> Result<CheckpointMeta, TrainError> {
    let p = dir.join(layout::META);
    let text = std::fs::read_to_string(&p).map_err(|e| io_err(&p, e))?;
    serde_json::from_str(&text).map_err(|e| io_err(&p, e))
}

/// The settings in the configuration of the checkpoint in `dir` that
/// [`TrainConfig`] does not read, as JSON paths (`model.parts.swing`):
/// options of an older version. [`read_meta`] ignores them; a resume
/// refuses them.
pub fn unknown_settings(dir: &Path) -> Result<Vec<String>, TrainError> {
    use serde_json::Value;
    /// The paths of `raw` that `known` lacks; under an object `known`
    /// lacks altogether (one serialised only when not all default), those
    /// whose values are not defaults (`false`, 0, null).
    fn walk(path: &str, raw: &Value, known: Option<&Value>, out: &mut Vec<String>) {
        let Some(raw) = raw.as_object() else {
            return;
        };
        for (k, v) in raw {
            let p = if path.is_empty() {
                k.clone()
            } else {
                format!("{path}.{k}")
            };
            match known.map(|w| w.get(k)) {
                Some(Some(w)) => walk(&p, v, Some(w), out),
                _ if v.is_object() => walk(&p, v, None, out),
                Some(None) => out.push(p),
                None if !(v.is_null() || v == false || v.as_f64() == Some(0.0)) => out.push(p),
                None => {}
            }
        }
    }
    let p = dir.join(layout::META);
    let text = std::fs::read_to_string(&p).map_err(|e| io_err(&p, e))?;
    let raw: serde_json::Value = serde_json::from_str(&text).map_err(|e| io_err(&p, e))?;
    let meta: CheckpointMeta = serde_json::from_value(raw.clone()).map_err(|e| io_err(&p, e))?;
    let known = serde_json::to_value(&meta.config).map_err(|e| io_err(&p, e))?;
    let mut out = Vec::new();
    walk("", &raw["config"], Some(&known), &mut out);
    Ok(out)
}

/// Load a checkpoint's model (for sampling, evaluation, tests).
pub fn load_model(dir: &Path, device: &Device) -> Result<(Trained, CheckpointMeta), TrainError> {
    let meta = read_meta(dir)?;
    let mut t = init_model(&meta.config.model, 0, device)?;
    let mp = dir.join(layout::MODEL);
    t.varmap.load(&mp).map_err(|e| {
        let unknown = unknown_settings(dir).unwrap_or_default();
        match unknown.is_empty() {
            true => io_err(&mp, e),
            false => io_err(
                &mp,
                format!(
                    "{e} (the checkpoint has settings this version does not read: {})",
                    unknown.join(", ")
                ),
            ),
        }
    })?;
    Ok((t, meta))
}

/// Whether the existing run directory `run` has a `last` checkpoint to
/// resume from. A run killed in its first epoch has none (its `last/` is
/// written atomically at the end of each epoch): then training starts from
/// scratch, the progress is told so, and whatever metrics the run holds are
/// replaced.
fn resumable(run: &Path, progress: &dyn TrainProgress) -> Result<bool, TrainError> {
    let last = run.join(layout::LAST);
    if last.join(layout::META).is_file() {
        return Ok(true);
    }
    if last.exists() {
        return Err(TrainError::Invalid(format!(
            "{}: a checkpoint directory without {}; move it away and train again",
            last.display(),
            layout::META
        )));
    }
    progress.note(&format!(
        "{}: no checkpoint to resume from yet (the run stopped before its first epoch ended); starting from scratch",
        run.display()
    ));
    Ok(false)
}

/// Train on `data` into the run directory `run`. With `resume`, continue from
/// `run/last` (weights, optimiser, epoch, best), or start from scratch when
/// the run has no checkpoint yet ([`TrainProgress::note`] says so);
/// otherwise `run` must not hold a checkpoint yet.
pub fn train(
    data: &Dataset,
    config: &TrainConfig,
    run: &Path,
    resume: bool,
    device: &Device,
    progress: &dyn TrainProgress,
) -> Result<Outcome, TrainError> {
    let train = data
        .splits
        .get("train")
        .filter(|w| w.n > 0)
        .ok_or_else(|| TrainError::Invalid(format!("{}: no train windows", data.dir.display())))?;
    if train.features != config.model.input {
        return Err(TrainError::Invalid(format!(
            "the dataset has {} features per frame, the model expects {}",
            train.features, config.model.input
        )));
    }
    if config.batch == 0 {
        return Err(TrainError::Invalid("batch must be positive".into()));
    }
    let lr = config.adam.lr;
    if !(lr.is_finite() && lr > 0.0) {
        return Err(TrainError::Invalid(format!(
            "the learning rate must be positive and finite, got {lr}"
        )));
    }
    if let Some(f) = config.lr_final.filter(|f| !(*f > 0.0 && *f <= 1.0)) {
        return Err(TrainError::Invalid(format!(
            "the final learning rate share (--lr-final) must be in (0, 1], got {f}"
        )));
    }
    let m = &config.model;
    for (what, size) in [
        ("latent size", m.latent),
        ("LSTM hidden size", m.hidden),
        (
            "feature extractor's layer sizes (--extractor)",
            m.extractor[0].min(m.extractor[1]),
        ),
        (
            "decoder's layer sizes (--decoder)",
            m.decoder[0].min(m.decoder[1]),
        ),
    ] {
        if size == 0 {
            return Err(TrainError::Invalid(format!(
                "the {what} must be at least 1"
            )));
        }
    }
    let val = data.splits.get("val").filter(|w| w.n > 0);
    if resume && !run.is_dir() {
        return Err(TrainError::Invalid(format!(
            "{}: nothing to resume (no such directory); drop --resume to start a run there",
            run.display()
        )));
    }
    std::fs::create_dir_all(run).map_err(|e| io_err(run, e))?;
    let metrics_path = run.join(layout::METRICS);

    let mut config = config.clone();
    let stats = &data.stats;
    config.model.fit_to(&stats.mean, &stats.std, &train.data);
    let train_categories = data.categories_of("train");
    config.model.categories = match config.condition {
        Some(c) if !(0.0..1.0).contains(&c.dropout) => {
            return Err(TrainError::Invalid(format!(
                "the share of windows trained without their category must be in [0, 1), got {}",
                c.dropout
            )))
        }
        Some(_) => Category::ALL
            .iter()
            .filter(|c| train_categories.contains(c))
            .map(|c| c.name().to_string())
            .collect(),
        None => Vec::new(),
    };
    let config = &config;
    if config.late_root_weight.is_some() && config.rollout_last.is_none() {
        return Err(TrainError::Invalid(
            "--late-root-weight weighs the root in the last epochs: it needs --rollout-last N"
                .into(),
        ));
    }
    if let Some(late) = config.late_model(config.epochs.saturating_sub(1)) {
        // Refuse a model the late epochs cannot train before the first epoch.
        Vrnn::new(
            &late,
            VarBuilder::from_varmap(&VarMap::new(), DType::F32, device),
        )
        .map_err(|e| TrainError::Invalid(format!("--rollout-last: {e}")))?;
    }
    let judge = match config.select {
        Select::Loss => None,
        Select::Generation { every: 0 } => {
            return Err(TrainError::Invalid(
                "choosing by generated motion needs a positive period".into(),
            ))
        }
        Select::Generation { every } => Some((
            Judge::new(data)?.stretches(config.judge_stretches.unwrap_or(1)),
            every,
        )),
    };
    let last_dir = run.join(layout::LAST);
    let resume = resume && resumable(run, progress)?;
    if !resume && last_dir.exists() {
        return Err(TrainError::Invalid(format!(
            "{} already holds a run: pass --resume to continue it, or choose another --out",
            run.display()
        )));
    }
    let epochs = Epochs {
        data,
        train,
        val,
        config,
        run,
        device,
    };
    let mut init = match config.inits {
        Some(inits) if !resume && inits.candidates > 1 => Some(epochs.probe(inits, progress)?),
        _ => None,
    };
    let init_seed = init.as_ref().map_or(config.seed, |i| i.seed);
    let t = init_model(&config.model, init_seed, device)?;
    let mut adam = Adam::new(named_vars(&t.varmap), config.adam)?;
    let mut history: Vec<EpochMetrics> = Vec::new();
    let mut start_epoch = 0;
    let mut best = (f64::INFINITY, 0usize);
    let mut best_generated: Option<(f64, usize)> = None;
    if resume {
        let meta = read_meta(&last_dir)?;
        let unknown = unknown_settings(&last_dir)?;
        if !unknown.is_empty() {
            return Err(TrainError::Invalid(format!(
                "{}: the checkpoint was trained with settings this version does not have ({}); it can be sampled and evaluated, not resumed",
                last_dir.display(),
                unknown.join(", ")
            )));
        }
        // Only the number of epochs may change on resume.
        let same_but_epochs = TrainConfig {
            epochs: meta.config.epochs,
            ..config.clone()
        };
        if meta.config != same_but_epochs {
            return Err(TrainError::Invalid(format!(
                "{}: the checkpoint was trained with other options ({}); resume with the same ones (only --epochs may change)",
                last_dir.display(),
                differing(&meta.config, &same_but_epochs).join(", ")
            )));
        }
        if meta.dataset_manifest_sha256 != data.manifest_sha256 {
            return Err(TrainError::Invalid(format!(
                "{}: the checkpoint was trained on another dataset (manifest hash differs)",
                last_dir.display()
            )));
        }
        let mut vm = t.varmap.clone();
        let mp = last_dir.join(layout::MODEL);
        vm.load(&mp).map_err(|e| io_err(&mp, e))?;
        // `vm` shares its variables with `t.varmap`: the model now has the weights.
        let op = last_dir.join(layout::OPTIMIZER);
        let state = candle_core::safetensors::load(&op, device).map_err(|e| io_err(&op, e))?;
        adam.load_state(&state, meta.step)?;
        start_epoch = meta.epoch;
        best = (meta.best_val_loss, meta.best_epoch);
        best_generated = meta.best_generated;
        init = meta.init;
        // Keep the metrics of the epochs the checkpoint has seen.
        if let Ok(text) = std::fs::read_to_string(&metrics_path) {
            history = text
                .lines()
                .filter_map(|l| serde_json::from_str::<EpochMetrics>(l).ok())
                .filter(|m| m.epoch <= meta.epoch)
                .collect();
        }
        rewrite_metrics(&metrics_path, &history)?;
    } else {
        rewrite_metrics(&metrics_path, &[])?;
    }

    let mut stale = history.len().saturating_sub(best.1);
    for epoch in start_epoch..config.epochs {
        if config.early_stopping.is_some_and(|p| stale >= p) {
            break;
        }
        let started = std::time::Instant::now();
        let mut m = epochs.run(&t, &mut adam, epoch, progress)?;
        let improved = m.val_loss() < best.0;
        if improved {
            best = (m.val_loss(), m.epoch);
            stale = 0;
        } else {
            stale += 1;
        }
        // Judge every `every` epochs, at the last epoch, and before early
        // stopping ends the run.
        let last = m.epoch == config.epochs || config.early_stopping.is_some_and(|p| stale >= p);
        let chosen = match &judge {
            None => improved,
            Some((j, every))
                if (m.epoch % every == 0 && m.epoch >= config.schedule_end()) || last =>
            {
                let v = j.judge(&t.model, device)?;
                let better = best_generated.is_none_or(|(s, _)| v.score < s);
                if better {
                    best_generated = Some((v.score, m.epoch));
                }
                m.generated = Some(v);
                better
            }
            Some(_) => false,
        };
        m.seconds = started.elapsed().as_secs_f64();
        let meta = CheckpointMeta {
            config: config.clone(),
            dataset_manifest_sha256: data.manifest_sha256.clone(),
            dataset: data.dir.display().to_string(),
            epoch: m.epoch,
            step: adam.step,
            best_val_loss: best.0,
            best_epoch: best.1,
            best_generated,
            init: init.clone(),
            metrics: Some(m.clone()),
        };
        // Metrics first, then the checkpoint: a resume trims metrics to the
        // checkpoint's epoch, so a kill in between loses nothing.
        append_metrics(&metrics_path, &m)?;
        if chosen {
            save_checkpoint(run, layout::BEST, &t.varmap, None, &meta)?;
        }
        save_checkpoint(run, layout::LAST, &t.varmap, Some(&adam), &meta)?;
        progress.epoch(&m);
        history.push(m);
    }
    Ok(Outcome { model: t, history })
}

/// What every epoch of a run reads.
struct Epochs<'a> {
    data: &'a Dataset,
    train: &'a Windows,
    val: Option<&'a Windows>,
    config: &'a TrainConfig,
    run: &'a Path,
    device: &'a Device,
}

impl Epochs<'_> {
    /// Epoch `epoch` (0-based) of `t`: Adam steps over the shuffled training
    /// windows, then the validation loss; the metrics, not yet judged.
    fn run(
        &self,
        t: &Trained,
        adam: &mut Adam,
        epoch: usize,
        progress: &dyn TrainProgress,
    ) -> Result<EpochMetrics, TrainError> {
        let (config, train, device) = (self.config, self.train, self.device);
        let vars = adam.vars().to_vec();
        let var_list: Vec<Var> = vars.iter().map(|(_, v)| v.clone()).collect();
        let started = std::time::Instant::now();
        let kl_w = config.kl_weight(epoch);
        let lr = config.lr(epoch);
        adam.set_lr(lr);
        let perm = Rng::new(config.seed, 1000 + epoch as u64).permutation(train.n);
        // The late epochs' model shares `t`'s variables.
        let late = match config.late_model(epoch) {
            Some(c) => Some(Vrnn::new(
                &c,
                VarBuilder::from_varmap(&t.varmap, DType::F32, device),
            )?),
            None => None,
        };
        let step_model = late.as_ref().unwrap_or(&t.model);
        let (mut sum_r, mut sum_k, mut seen) = (0.0f64, 0.0f64, 0usize);
        for chunk in perm.chunks(config.batch) {
            let step = adam.step + 1;
            let x = train.batch(chunk, device)?;
            let eps = noise(
                config.seed,
                step,
                train.length,
                chunk.len(),
                config.model.latent,
                device,
            )?;
            let feed = feed_mask(
                config.seed,
                step,
                chunk.len(),
                train.length,
                config.feed_share(epoch),
                device,
            )?;
            let cond = match config.condition {
                Some(c) => {
                    let mut rng = Rng::new(config.seed ^ 0xC0DE_0000_0000, step);
                    let drop: Vec<bool> = chunk.iter().map(|_| rng.uniform() < c.dropout).collect();
                    let model = &config.model;
                    model.window_condition(
                        self.data.categories_of("train"),
                        chunk,
                        1.0,
                        |k| drop[k],
                        device,
                    )?
                }
                None => None,
            };
            let ((r, k), grads) = sharded(
                step_model,
                &x,
                &eps,
                feed.as_ref(),
                cond.as_ref(),
                Some((kl_w, &var_list)),
            )?;
            if !(r.is_finite() && k.is_finite()) {
                return Err(TrainError::NonFinite {
                    step,
                    epoch: epoch + 1,
                    recon: r,
                    kl: k,
                    dir: self.run.to_path_buf(),
                });
            }
            let mut grads = grads.ok_or_else(|| TrainError::Invalid("no gradients".into()))?;
            if let Some(max) = config.clip_grad_norm {
                clip_grad_norm(&vars, &mut grads, max)?;
            }
            adam.step(&grads)?;
            sum_r += r as f64 * chunk.len() as f64;
            sum_k += k as f64 * chunk.len() as f64;
            seen += chunk.len();
            let wps = seen as f64 / started.elapsed().as_secs_f64().max(1e-9);
            progress.step(epoch + 1, adam.step, r, k, wps);
        }
        let train_secs = started.elapsed().as_secs_f64();
        let (val_recon, val_kl) = match self.val {
            Some(v) => evaluate(
                &t.model,
                v,
                self.data.categories_of("val"),
                config.batch,
                config.seed,
                device,
            )?,
            None => (sum_r / seen as f64, sum_k / seen as f64),
        };
        let m = EpochMetrics {
            epoch: epoch + 1,
            step: adam.step,
            train_recon: sum_r / seen as f64,
            train_kl: sum_k / seen as f64,
            val_recon,
            val_kl,
            kl_weight: kl_w,
            lr: Some(lr),
            windows_per_s: seen as f64 / train_secs.max(1e-9),
            seconds: 0.0,
            generated: None,
        };
        if !m.val_loss().is_finite() {
            return Err(TrainError::NonFinite {
                step: adam.step,
                epoch: epoch + 1,
                recon: val_recon as f32,
                kl: val_kl as f32,
                dir: self.run.to_path_buf(),
            });
        }
        Ok(m)
    }

    /// [`TrainConfig::inits`]: each candidate trained for `inits.epochs`
    /// epochs, the one with the lowest validation loss kept (the first of
    /// equals; a candidate whose loss leaves the finite numbers loses).
    fn probe(&self, inits: Inits, progress: &dyn TrainProgress) -> Result<InitChoice, TrainError> {
        // A run shorter than the probe is probed over its whole length.
        let epochs = inits.epochs.min(self.config.epochs);
        let mut val_losses = Vec::with_capacity(inits.candidates);
        for k in 0..inits.candidates {
            let seed = inits.seed(self.config.seed, k);
            progress.note(&format!(
                "initialisation {} of {} (weights from seed {seed}): {epochs} epochs",
                k + 1,
                inits.candidates,
            ));
            let t = init_model(&self.config.model, seed, self.device)?;
            let mut adam = Adam::new(named_vars(&t.varmap), self.config.adam)?;
            let mut loss = f64::INFINITY;
            for epoch in 0..epochs {
                match self.run(&t, &mut adam, epoch, progress) {
                    Ok(m) => loss = m.val_loss(),
                    Err(TrainError::NonFinite { .. }) => {
                        loss = f64::INFINITY;
                        break;
                    }
                    Err(e) => return Err(e),
                }
            }
            val_losses.push(loss);
        }
        let kept =
            (0..val_losses.len()).fold(0, |b, k| if val_losses[k] < val_losses[b] { k } else { b });
        let shown: Vec<String> = val_losses.iter().map(|l| format!("{l:.1}")).collect();
        progress.note(&format!(
            "kept initialisation {} of {} (validation loss after {epochs} epochs: {})",
            kept + 1,
            inits.candidates,
            shown.join(", ")
        ));
        Ok(InitChoice {
            seed: inits.seed(self.config.seed, kept),
            val_losses,
        })
    }
}

/// The options (JSON paths, `model.parts.self_feed`) whose values differ
/// between two configurations, as `path: checkpoint → now`.
fn differing(was: &TrainConfig, now: &TrainConfig) -> Vec<String> {
    fn walk(path: &str, a: &serde_json::Value, b: &serde_json::Value, out: &mut Vec<String>) {
        use serde_json::Value;
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => {
                let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
                keys.sort();
                keys.dedup();
                for k in keys {
                    let p = if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    };
                    walk(
                        &p,
                        x.get(k).unwrap_or(&Value::Null),
                        y.get(k).unwrap_or(&Value::Null),
                        out,
                    );
                }
            }
            _ if a != b => {
                let short = |v: &Value| {
                    let t = v.to_string();
                    if t.len() > 40 {
                        "…".to_string()
                    } else {
                        t
                    }
                };
                out.push(format!("{path}: {} → {}", short(a), short(b)));
            }
            _ => {}
        }
    }
    let mut out = Vec::new();
    if let (Ok(a), Ok(b)) = (serde_json::to_value(was), serde_json::to_value(now)) {
        walk("", &a, &b, &mut out);
    }
    out
}

/// What [`train`] returns.
pub struct Outcome {
    /// The model after the last epoch (as saved in `last`).
    pub model: Trained,
    /// Metrics of every epoch, resumed ones included.
    pub history: Vec<EpochMetrics>,
}

fn append_metrics(path: &Path, m: &EpochMetrics) -> Result<(), TrainError> {
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)
        .map_err(|e| io_err(path, e))?;
    let line = serde_json::to_string(m).map_err(|e| io_err(path, e))?;
    writeln!(f, "{line}").map_err(|e| io_err(path, e))?;
    f.sync_all().map_err(|e| io_err(path, e))
}

fn rewrite_metrics(path: &Path, history: &[EpochMetrics]) -> Result<(), TrainError> {
    let mut text = String::new();
    for m in history {
        text.push_str(&serde_json::to_string(m).map_err(|e| io_err(path, e))?);
        text.push('\n');
    }
    let tmp = path.with_extension("jsonl.tmp");
    std::fs::write(&tmp, text).map_err(|e| io_err(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| io_err(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--resume` reads the kept epochs' metrics back and writes them again:
    /// the same bytes, also for a float serde_json's default parser reads
    /// an ulp off (`val_kl` here, from a real run).
    #[test]
    fn metrics_read_back_are_written_as_they_were() {
        let line = r#"{"epoch":4,"step":52,"train_recon":5659.49596287049,"train_kl":111.88167343926185,"val_recon":4792.006690932765,"val_kl":118.91529591878255,"kl_weight":0.2,"lr":0.001,"windows_per_s":1013.0384100719328,"seconds":0.814032788}"#;
        let m: EpochMetrics = serde_json::from_str(line).unwrap();
        assert_eq!(serde_json::to_string(&m).unwrap(), line);
    }
}
