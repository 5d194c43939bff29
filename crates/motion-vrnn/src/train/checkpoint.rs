//! A run directory's checkpoints and metrics: writing them, reading them
//! back, and resuming from `last`.

use super::*;

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

pub(super) fn save_checkpoint(
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
    pub(super) fn walk(path: &str, raw: &Value, known: Option<&Value>, out: &mut Vec<String>) {
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
pub(super) fn resumable(run: &Path, progress: &dyn TrainProgress) -> Result<bool, TrainError> {
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

/// Where a run stands before its next epoch: the metrics so far, the first
/// epoch to train, the best validation loss and generated score with their
/// epochs, and the kept initialisation.
pub(super) struct RunState {
    pub(super) history: Vec<EpochMetrics>,
    pub(super) start_epoch: usize,
    pub(super) best: (f64, usize),
    pub(super) best_generated: Option<(f64, usize)>,
    pub(super) init: Option<InitChoice>,
}

/// The state of the run's `last` checkpoint, loaded into `t` and `adam`
/// after checking it was trained with the same options (but the number of
/// epochs) on the same dataset; the metrics file trimmed to its epoch.
pub(super) fn restore(
    e: &Epochs,
    t: &Trained,
    adam: &mut Adam,
    metrics_path: &Path,
) -> Result<RunState, TrainError> {
    let (config, data) = (e.config, e.data);
    let last_dir = e.run.join(layout::LAST);
    let meta = read_meta(&last_dir)?;
    let unknown = unknown_settings(&last_dir)?;
    if !unknown.is_empty() {
        return Err(TrainError::Invalid(format!(
            "{}: the checkpoint was trained with settings this version does not have ({}); it can be sampled and evaluated, not resumed",
            last_dir.display(),
            unknown.join(", ")
        )));
    }
    // Only the number of epochs (or the budget that gave them) may change
    // on resume.
    let same_but_epochs = TrainConfig {
        epochs: meta.config.epochs,
        budget: meta.config.budget,
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
    let state = candle_core::safetensors::load(&op, e.device).map_err(|e| io_err(&op, e))?;
    adam.load_state(&state, meta.step)?;
    let mut history = Vec::new();
    // Keep the metrics of the epochs the checkpoint has seen.
    if let Ok(text) = std::fs::read_to_string(metrics_path) {
        history = text
            .lines()
            .filter_map(|l| serde_json::from_str::<EpochMetrics>(l).ok())
            .filter(|m| m.epoch <= meta.epoch)
            .collect();
    }
    rewrite_metrics(metrics_path, &history)?;
    Ok(RunState {
        history,
        start_epoch: meta.epoch,
        best: (meta.best_val_loss, meta.best_epoch),
        best_generated: meta.best_generated,
        init: meta.init,
    })
}

/// The options (JSON paths, `model.parts.self_feed`) whose values differ
/// between two configurations, as `path: checkpoint → now`.
pub(super) fn differing(was: &TrainConfig, now: &TrainConfig) -> Vec<String> {
    pub(super) fn walk(
        path: &str,
        a: &serde_json::Value,
        b: &serde_json::Value,
        out: &mut Vec<String>,
    ) {
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

pub(super) fn append_metrics(path: &Path, m: &EpochMetrics) -> Result<(), TrainError> {
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)
        .map_err(|e| io_err(path, e))?;
    let line = serde_json::to_string(m).map_err(|e| io_err(path, e))?;
    writeln!(f, "{line}").map_err(|e| io_err(path, e))?;
    f.sync_all().map_err(|e| io_err(path, e))
}

pub(super) fn rewrite_metrics(path: &Path, history: &[EpochMetrics]) -> Result<(), TrainError> {
    let mut text = String::new();
    for m in history {
        text.push_str(&serde_json::to_string(m).map_err(|e| io_err(path, e))?);
        text.push('\n');
    }
    let tmp = path.with_extension("jsonl.tmp");
    std::fs::write(&tmp, text).map_err(|e| io_err(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| io_err(path, e))
}
