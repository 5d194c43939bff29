//! Training: Adam over shuffled windows, validation each epoch, metrics log,
//! `best` and `last` checkpoints (safetensors + JSON, written atomically),
//! exact resume, a NaN guard.
//!
//! The files: `config` ([`TrainConfig`], its presets and schedules),
//! `checkpoint` (checkpoints, metrics, resume), `epoch` (the epochs of a
//! run and the probe of several initialisations).

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

mod checkpoint;
mod config;
mod epoch;

pub use checkpoint::{layout, load_model, read_meta, unknown_settings, CheckpointMeta};
pub use config::{
    feed_mask, Conditioning, InitChoice, Inits, Select, TrainConfig, CONDITION_DROPOUT,
    CONTROL_DROPOUT, INIT_EPOCHS, LATE_SPEED_WEIGHT,
};

use checkpoint::{append_metrics, restore, resumable, rewrite_metrics, save_checkpoint, RunState};
use epoch::Epochs;

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
/// overrides both where it returns one. The condition table and the
/// control's weights ([`crate::model::COND_WEIGHT`],
/// [`crate::model::CONTROL_WEIGHT`]) keep their zeros and draw nothing, so
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
    let zero = [crate::model::COND_WEIGHT, crate::model::CONTROL_WEIGHT];
    for (name, var) in vars.iter().filter(|(n, _)| !zero.contains(&n.as_str())) {
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
        let x = model
            .config()
            .with_control(&windows.batch(chunk, device)?, &[])?;
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
    let train = checked(data, config)?;
    let val = data.splits.get("val").filter(|w| w.n > 0);
    if resume && !run.is_dir() {
        return Err(TrainError::Invalid(format!(
            "{}: nothing to resume (no such directory); drop --resume to start a run there",
            run.display()
        )));
    }
    std::fs::create_dir_all(run).map_err(|e| io_err(run, e))?;
    let metrics_path = run.join(layout::METRICS);
    let config = &fitted(data, config, train, device)?;
    let judge = judge_of(data, config)?;
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
    let init = match config.inits {
        Some(inits) if !resume && inits.candidates > 1 => Some(epochs.probe(inits, progress)?),
        _ => None,
    };
    let init_seed = init.as_ref().map_or(config.seed, |i| i.seed);
    let t = init_model(&config.model, init_seed, device)?;
    let mut adam = Adam::new(named_vars(&t.varmap), config.adam)?;
    let state = if resume {
        restore(&epochs, &t, &mut adam, &metrics_path)?
    } else {
        rewrite_metrics(&metrics_path, &[])?;
        RunState {
            history: Vec::new(),
            start_epoch: 0,
            best: (f64::INFINITY, 0),
            best_generated: None,
            init,
        }
    };
    let history = epochs.all(&t, &mut adam, judge.as_ref(), state, progress)?;
    Ok(Outcome { model: t, history })
}

/// The training windows of `data`, or an error where `config` cannot train
/// on them (feature count, batch, learning rate, layer sizes).
fn checked<'a>(data: &'a Dataset, config: &TrainConfig) -> Result<&'a Windows, TrainError> {
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
    Ok(train)
}

/// `config` scaled to the training windows `train`
/// ([`TrainConfig::for_windows`]), its model fitted to them
/// ([`Config::fit_to`]) and given the training set's categories when
/// conditioned; an error where the late epochs cannot train it.
fn fitted(
    data: &Dataset,
    config: &TrainConfig,
    train: &Windows,
    device: &Device,
) -> Result<TrainConfig, TrainError> {
    let mut config = config.for_windows(train.n);
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
    Ok(config)
}

/// The judge of generated motion and its period in epochs, when `config`
/// chooses checkpoints by it ([`Select::Generation`]).
fn judge_of<'a>(
    data: &'a Dataset,
    config: &TrainConfig,
) -> Result<Option<(Judge<'a>, usize)>, TrainError> {
    Ok(match config.select {
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
    })
}

/// What [`train`] returns.
pub struct Outcome {
    /// The model after the last epoch (as saved in `last`).
    pub model: Trained,
    /// Metrics of every epoch, resumed ones included.
    pub history: Vec<EpochMetrics>,
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
