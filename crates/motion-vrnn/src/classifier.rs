//! A motion classifier, trained on real windows per category, and the
//! measures the field computes with one (`docs/metrics.md`, "Classifier
//! measures"): recognition accuracy, the Fréchet distance between sets of
//! its feature vectors, diversity and multimodality (Guo et al. 2020,
//! ACTOR, MDM).
//!
//! The network: three temporal convolutions (kernel [`KERNEL`], valid
//! padding) over a window's normalised features, each a dense layer over
//! `KERNEL` consecutive frames followed by ReLU, the first two followed by
//! average pooling over pairs of frames; the last one's output averaged
//! over time is the window's feature vector ([`EMBEDDING`] values); a dense
//! layer maps it to one logit per category of [`Category::ALL`]. Categories
//! without training windows are masked out, so they are never predicted.
//!
//! Training is deterministic: initial weights from the seed
//! ([`crate::train::init_uniform`]), mini-batches by a seeded permutation
//! per epoch, each batch cut into shards of [`SHARD`] windows whose losses
//! and gradients are computed in parallel and summed in shard order, Adam
//! ([`crate::optim::Adam`]) with a constant learning rate.

use crate::data::{Category, Dataset, Windows};
use crate::error::{io_err, TrainError};
use crate::optim::{Adam, AdamConfig};
use crate::rng::Rng;
use crate::train::{init_uniform, named_vars, sum_gradients, SHARD};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Linear, Module, VarBuilder, VarMap};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

/// Frames each temporal convolution sees.
pub const KERNEL: usize = 5;
/// Channels of the first two convolutions.
pub const CHANNELS: usize = 32;
/// Values in a window's feature vector (the last convolution's channels).
pub const EMBEDDING: usize = 32;
/// Pairs of windows drawn for [`diversity`] (`S_d` of Guo et al. 2020,
/// as in ACTOR and MDM).
pub const DIVERSITY_SAMPLES: usize = 200;
/// Pairs drawn per category for [`multimodality`] (`S_l`).
pub const MULTIMODALITY_SAMPLES: usize = 20;
/// Files of a classifier directory.
pub const WEIGHTS: &str = "classifier.safetensors";
/// The classifier's JSON ([`ClassifierMeta`]).
pub const META: &str = "classifier.json";

/// Shortest window the network takes (32 frames): the last convolution
/// needs `KERNEL` frames, each pooling halves, each convolution takes
/// `KERNEL − 1` away.
pub const MIN_FRAMES: usize = (2 * KERNEL + KERNEL - 1) * 2 + KERNEL - 1;

/// Sizes of a classifier.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassifierConfig {
    /// Features per frame (58).
    pub features: usize,
    /// Frames per window it was trained on (windows of other lengths are
    /// refused).
    pub frames: usize,
    /// Frames per convolution ([`KERNEL`]).
    pub kernel: usize,
    /// Channels of the first two convolutions ([`CHANNELS`]).
    pub channels: usize,
    /// Values of the feature vector ([`EMBEDDING`]).
    pub embedding: usize,
    /// Category names, in logit order ([`Category::ALL`]).
    pub categories: Vec<String>,
    /// Training windows per category; a category with none is never
    /// predicted.
    pub train_windows: Vec<usize>,
}

/// How a classifier is trained.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassifierTraining {
    /// Seed of the initial weights and the shuffles.
    pub seed: u64,
    /// Passes over the training windows.
    pub epochs: usize,
    /// Windows per optimiser step.
    pub batch: usize,
    /// Optimiser (constant learning rate).
    pub adam: AdamConfig,
}

impl Default for ClassifierTraining {
    /// Seed 0, 30 epochs, batch 64, Adam 1e-3.
    fn default() -> Self {
        ClassifierTraining {
            seed: 0,
            epochs: 30,
            batch: 64,
            adam: AdamConfig::default(),
        }
    }
}

/// What `classifier.json` holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassifierMeta {
    /// The network's sizes and categories.
    pub config: ClassifierConfig,
    /// How it was trained.
    pub training: ClassifierTraining,
    /// The dataset directory it was trained on.
    pub dataset: String,
    /// SHA-256 of that dataset's `manifest.json`.
    pub dataset_manifest_sha256: String,
    /// Mean cross-entropy of each epoch's batches.
    pub loss: Vec<f64>,
}

/// A motion classifier.
pub struct Classifier {
    varmap: VarMap,
    config: ClassifierConfig,
    convs: [Linear; 3],
    head: Linear,
    /// Added to the logits: 0, or −10⁴ for categories without training windows.
    mask: Tensor,
}

/// A temporal convolution with valid padding: `x` `[B, T, C]` → `[B, T −
/// k + 1, out]`, a dense layer over `k` consecutive frames, then ReLU.
fn conv(x: &Tensor, k: usize, layer: &Linear) -> candle_core::Result<Tensor> {
    let n = (x.dim(1)? + 1)
        .checked_sub(k)
        .filter(|n| *n > 0)
        .ok_or_else(|| candle_core::Error::Msg(format!("fewer than {k} frames")))?;
    let frames = (0..k)
        .map(|j| x.narrow(1, j, n))
        .collect::<candle_core::Result<Vec<_>>>()?;
    layer.forward(&Tensor::cat(&frames, 2)?)?.relu()
}

/// Average pooling over pairs of frames: `[B, T, C]` → `[B, ⌊T/2⌋, C]`.
fn pool(x: &Tensor) -> candle_core::Result<Tensor> {
    let (b, t, c) = x.dims3()?;
    x.narrow(1, 0, t / 2 * 2)?
        .reshape((b, t / 2, 2, c))?
        .mean(2)
}

impl Classifier {
    /// A classifier of `config` with weights from `seed`.
    pub fn new(config: ClassifierConfig, seed: u64, device: &Device) -> Result<Self, TrainError> {
        let n = Category::ALL.len();
        let names: Vec<&str> = Category::ALL.iter().map(|c| c.name()).collect();
        if config.categories != names || config.train_windows.len() != n {
            return Err(TrainError::Invalid(format!(
                "the classifier's categories are {:?}; this build knows {names:?}",
                config.categories
            )));
        }
        if config.frames < MIN_FRAMES || config.kernel != KERNEL {
            return Err(TrainError::Invalid(format!(
                "the classifier takes windows of at least {MIN_FRAMES} frames and kernel {KERNEL}, not {} frames and kernel {}",
                config.frames, config.kernel
            )));
        }
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, device);
        let (k, c) = (config.kernel, config.channels);
        let convs = [
            candle_nn::linear(k * config.features, c, vb.pp("conv1"))?,
            candle_nn::linear(k * c, c, vb.pp("conv2"))?,
            candle_nn::linear(k * c, config.embedding, vb.pp("conv3"))?,
        ];
        let head = candle_nn::linear(config.embedding, n, vb.pp("head"))?;
        init_uniform(&varmap, seed, |_| None, device)?;
        let mask: Vec<f32> = config
            .train_windows
            .iter()
            .map(|&w| if w > 0 { 0.0 } else { -1e4 })
            .collect();
        let mask = Tensor::from_vec(mask, (1, n), device)?;
        Ok(Classifier {
            varmap,
            config,
            convs,
            head,
            mask,
        })
    }

    /// Its sizes and categories.
    pub fn config(&self) -> &ClassifierConfig {
        &self.config
    }

    /// Masked logits `[B, categories]` and feature vectors `[B, embedding]`
    /// of windows `x` `[B, T, features]`.
    pub fn logits(&self, x: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let k = self.config.kernel;
        let h = pool(&conv(x, k, &self.convs[0])?)?;
        let h = pool(&conv(&h, k, &self.convs[1])?)?;
        let features = conv(&h, k, &self.convs[2])?.mean(1)?;
        let logits = self.head.forward(&features)?.broadcast_add(&self.mask)?;
        Ok((logits, features))
    }

    /// Class probabilities `[B, categories]` (in [`Category::ALL`] order)
    /// and feature vectors `[B, embedding]` of windows `x` `[B, T, features]`.
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let (logits, features) = self.logits(x)?;
        Ok((candle_nn::ops::softmax_last_dim(&logits)?, features))
    }

    /// Probabilities and feature vectors of every window, in shards of
    /// [`SHARD`] windows run in parallel (the same numbers for any thread
    /// count).
    pub fn outputs(&self, windows: &Windows, device: &Device) -> Result<Outputs, TrainError> {
        self.check(windows)?;
        let idx: Vec<usize> = (0..windows.n).collect();
        let parts = idx
            .par_chunks(SHARD)
            .map(|chunk| {
                let (p, f) = self.forward(&windows.batch(chunk, device)?)?;
                Ok((p.to_vec2::<f32>()?, f.to_vec2::<f32>()?))
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        let mut out = Outputs {
            probabilities: Vec::with_capacity(windows.n),
            features: Vec::with_capacity(windows.n),
        };
        for (p, f) in parts {
            out.probabilities.extend(p);
            out.features.extend(f);
        }
        Ok(out)
    }

    fn check(&self, w: &Windows) -> Result<(), TrainError> {
        if w.features != self.config.features || w.length != self.config.frames {
            return Err(TrainError::Invalid(format!(
                "the classifier takes windows of {} frames × {} features, not {} × {}",
                self.config.frames, self.config.features, w.length, w.features
            )));
        }
        Ok(())
    }

    /// Write `dir` (weights and [`ClassifierMeta`]) whole: a staging
    /// directory beside it is swapped in atomically. An existing `dir` must
    /// be a classifier directory (or empty).
    pub fn save(&self, dir: &Path, meta: &ClassifierMeta) -> Result<(), TrainError> {
        if dir.exists() && !dir.join(META).is_file() {
            let empty = std::fs::read_dir(dir)
                .map_err(|e| io_err(dir, e))?
                .next()
                .is_none();
            if !empty {
                return Err(TrainError::Invalid(format!(
                    "{} exists and holds no {META}: choose another directory for the classifier",
                    dir.display()
                )));
            }
        }
        let name = dir
            .file_name()
            .map_or_else(|| "classifier".into(), |n| n.to_string_lossy().into_owned());
        let parent = dir.parent().filter(|p| !p.as_os_str().is_empty());
        let parent = parent.unwrap_or(Path::new("."));
        std::fs::create_dir_all(parent).map_err(|e| io_err(parent, e))?;
        let staging = parent.join(format!(".{name}.tmp-{}", std::process::id()));
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| io_err(&staging, e))?;
        }
        std::fs::create_dir_all(&staging).map_err(|e| io_err(&staging, e))?;
        let weights: HashMap<String, Tensor> = named_vars(&self.varmap)
            .into_iter()
            .map(|(k, v)| (k, v.as_tensor().clone()))
            .collect();
        let wp = staging.join(WEIGHTS);
        candle_core::safetensors::save(&weights, &wp).map_err(|e| io_err(&wp, e))?;
        let jp = staging.join(META);
        let text = serde_json::to_string_pretty(meta).map_err(|e| io_err(&jp, e))?;
        std::fs::write(&jp, text + "\n").map_err(|e| io_err(&jp, e))?;
        for p in [&wp, &jp] {
            let f = std::fs::File::open(p).map_err(|e| io_err(p, e))?;
            f.sync_all().map_err(|e| io_err(p, e))?;
        }
        mocap_ingest::atomic::replace_dir(&staging, dir).map_err(|e| io_err(dir, e))
    }

    /// Load a classifier directory written by [`Classifier::save`].
    pub fn load(dir: &Path, device: &Device) -> Result<(Classifier, ClassifierMeta), TrainError> {
        let jp = dir.join(META);
        let text = std::fs::read_to_string(&jp).map_err(|e| io_err(&jp, e))?;
        let meta: ClassifierMeta = serde_json::from_str(&text).map_err(|e| io_err(&jp, e))?;
        let mut c = Classifier::new(meta.config.clone(), 0, device)?;
        let wp = dir.join(WEIGHTS);
        c.varmap.load(&wp).map_err(|e| io_err(&wp, e))?;
        Ok((c, meta))
    }
}

/// What a classifier says about a set of windows.
#[derive(Clone, Debug, PartialEq)]
pub struct Outputs {
    /// Per window, the probability of each category of [`Category::ALL`].
    pub probabilities: Vec<Vec<f32>>,
    /// Per window, its feature vector.
    pub features: Vec<Vec<f32>>,
}

impl Outputs {
    /// Per window, the most probable category (the first of equals).
    pub fn predicted(&self) -> Vec<Category> {
        self.probabilities
            .iter()
            .map(|p| {
                let best = p
                    .iter()
                    .enumerate()
                    .fold(0, |b, (i, v)| if *v > p[b] { i } else { b });
                Category::ALL[best]
            })
            .collect()
    }
}

/// Train a classifier on `windows` labelled `labels` (one per window).
/// Returns it with the mean loss of each epoch.
pub fn train(
    windows: &Windows,
    labels: &[Category],
    training: &ClassifierTraining,
    device: &Device,
) -> Result<(Classifier, Vec<f64>), TrainError> {
    if labels.len() != windows.n || windows.n == 0 {
        return Err(TrainError::Invalid(format!(
            "training the classifier needs windows with one category each: {} windows, {} categories",
            windows.n,
            labels.len()
        )));
    }
    if training.batch == 0 || !(training.adam.lr > 0.0 && training.adam.lr.is_finite()) {
        return Err(TrainError::Invalid(
            "the classifier's batch and learning rate must be positive".into(),
        ));
    }
    let mut train_windows = vec![0; Category::ALL.len()];
    for &l in labels {
        train_windows[l as usize] += 1;
    }
    let config = ClassifierConfig {
        features: windows.features,
        frames: windows.length,
        kernel: KERNEL,
        channels: CHANNELS,
        embedding: EMBEDDING,
        categories: Category::ALL.iter().map(|c| c.name().to_string()).collect(),
        train_windows,
    };
    let model = Classifier::new(config, training.seed, device)?;
    let mut adam = Adam::new(named_vars(&model.varmap), training.adam)?;
    let vars: Vec<Var> = adam.vars().iter().map(|(_, v)| v.clone()).collect();
    let mut losses = Vec::with_capacity(training.epochs);
    for epoch in 0..training.epochs {
        let perm = Rng::new(training.seed, 1000 + epoch as u64).permutation(windows.n);
        let mut sum = 0.0;
        for batch in perm.chunks(training.batch) {
            let b = batch.len() as f64;
            let parts = batch
                .par_chunks(SHARD)
                .map(|shard| {
                    let x = windows.batch(shard, device)?;
                    let y: Vec<u32> = shard.iter().map(|&i| labels[i] as u32).collect();
                    let y = Tensor::from_vec(y, shard.len(), device)?;
                    let loss = candle_nn::loss::cross_entropy(&model.logits(&x)?.0, &y)?;
                    let loss = (loss * (shard.len() as f64 / b))?;
                    let store = loss.backward()?;
                    let grads: Vec<Option<Tensor>> =
                        vars.iter().map(|v| store.get(v).cloned()).collect();
                    Ok((loss.to_scalar::<f32>()? as f64, grads))
                })
                .collect::<candle_core::Result<Vec<_>>>()?;
            let loss: f64 = parts.iter().map(|p| p.0).sum();
            if !loss.is_finite() {
                return Err(TrainError::Invalid(format!(
                    "the classifier's loss became {loss} in epoch {}",
                    epoch + 1
                )));
            }
            let shards: Vec<&[Option<Tensor>]> = parts.iter().map(|p| p.1.as_slice()).collect();
            adam.step(&sum_gradients(&vars, &shards)?)?;
            sum += loss * b;
        }
        losses.push(sum / windows.n as f64);
    }
    Ok((model, losses))
}

/// Recognition accuracy of a set of windows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Accuracy {
    /// Windows.
    pub windows: usize,
    /// Windows whose predicted category is their own.
    pub correct: usize,
    /// Per category of [`Category::ALL`]: `(windows, correct)`.
    pub per_category: Vec<(usize, usize)>,
}

impl Accuracy {
    /// Share of windows recognised (None without windows).
    pub fn overall(&self) -> Option<f64> {
        (self.windows > 0).then(|| self.correct as f64 / self.windows as f64)
    }

    /// Share of `category`'s windows recognised (None without windows).
    pub fn of(&self, category: Category) -> Option<f64> {
        let (n, c) = self.per_category[category as usize];
        (n > 0).then(|| c as f64 / n as f64)
    }
}

/// Accuracy of `predicted` categories against the `truth`, overall and per
/// true category.
pub fn accuracy(predicted: &[Category], truth: &[Category]) -> Accuracy {
    let mut per_category = vec![(0, 0); Category::ALL.len()];
    for (p, t) in predicted.iter().zip(truth) {
        let e = &mut per_category[*t as usize];
        e.0 += 1;
        e.1 += usize::from(p == t);
    }
    Accuracy {
        windows: per_category.iter().map(|e| e.0).sum(),
        correct: per_category.iter().map(|e| e.1).sum(),
        per_category,
    }
}

fn distance(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Mean distance between the vectors of two disjoint random sets of
/// `s = min(samples, ⌊n/2⌋)` vectors of `items`, paired in draw order: the
/// first `2s` of a seeded permutation. None when `s` is 0.
fn paired_distance(
    features: &[Vec<f32>],
    items: &[usize],
    samples: usize,
    rng: &mut Rng,
) -> Option<f64> {
    let s = samples.min(items.len() / 2);
    if s == 0 {
        return None;
    }
    let perm = rng.permutation(items.len());
    let sum: f64 = (0..s)
        .map(|i| distance(&features[items[perm[i]]], &features[items[perm[s + i]]]))
        .sum();
    Some(sum / s as f64)
}

/// Diversity (Guo et al. 2020; ACTOR; MDM): two disjoint random sets of
/// `S_d = min(samples, ⌊n/2⌋)` feature vectors, the mean Euclidean distance
/// between their vectors paired in draw order (`samples` is
/// [`DIVERSITY_SAMPLES`] in the field). Seeded; None for fewer than two
/// vectors.
pub fn diversity(features: &[Vec<f32>], samples: usize, seed: u64) -> Option<f64> {
    let items: Vec<usize> = (0..features.len()).collect();
    paired_distance(features, &items, samples, &mut Rng::new(seed, 0xD1CE))
}

/// Multimodality (Guo et al. 2020; ACTOR; MDM): within each category, two
/// disjoint random sets of `S_l = min(samples, ⌊n_c/2⌋)` of its feature
/// vectors, the mean distance between their vectors paired in draw order;
/// then the mean over the categories with at least two vectors (`samples`
/// is [`MULTIMODALITY_SAMPLES`] in the field). Seeded (a stream per
/// category); None when no category has two vectors.
pub fn multimodality(
    features: &[Vec<f32>],
    labels: &[Category],
    samples: usize,
    seed: u64,
) -> Option<f64> {
    let per: Vec<f64> = Category::ALL
        .iter()
        .filter_map(|&c| {
            let items: Vec<usize> = (0..labels.len().min(features.len()))
                .filter(|&i| labels[i] == c)
                .collect();
            let mut rng = Rng::new(seed, 0x33_0000 + c as u64);
            paired_distance(features, &items, samples, &mut rng)
        })
        .collect();
    (!per.is_empty()).then(|| per.iter().sum::<f64>() / per.len() as f64)
}

/// Fréchet distance between Gaussians fitted to two sets of feature vectors
/// ([`motion_metrics::frechet`]).
pub fn feature_frechet(a: &[Vec<f32>], b: &[Vec<f32>]) -> f64 {
    let wide = |v: &[Vec<f32>]| -> Vec<Vec<f64>> {
        v.iter()
            .map(|x| x.iter().map(|&y| y as f64).collect())
            .collect()
    };
    motion_metrics::frechet(&wide(a), &wide(b))
}

/// The classifier measures of one set of real windows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SplitMeasures {
    /// The split.
    pub split: String,
    /// Recognition accuracy.
    pub accuracy: Accuracy,
    /// [`diversity`] of its feature vectors.
    pub diversity: Option<f64>,
    /// [`multimodality`] of its feature vectors by their categories.
    pub multimodality: Option<f64>,
}

/// Measure `windows` of `split` (with their `labels`) with `classifier`;
/// also returns their feature vectors.
pub fn measure(
    classifier: &Classifier,
    split: &str,
    windows: &Windows,
    labels: &[Category],
    seed: u64,
    device: &Device,
) -> Result<(SplitMeasures, Vec<Vec<f32>>), TrainError> {
    let out = classifier.outputs(windows, device)?;
    let m = SplitMeasures {
        split: split.to_string(),
        accuracy: accuracy(&out.predicted(), labels),
        diversity: diversity(&out.features, DIVERSITY_SAMPLES, seed),
        multimodality: multimodality(&out.features, labels, MULTIMODALITY_SAMPLES, seed),
    };
    Ok((m, out.features))
}

/// What `cargo xtask train-classifier` reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassifierReport {
    /// The classifier directory.
    pub out: String,
    /// The classifier's JSON.
    pub meta: ClassifierMeta,
    /// Seconds of training.
    pub seconds: f64,
    /// The measures of each split measured (train, then test).
    pub splits: Vec<SplitMeasures>,
    /// Fréchet distance between the feature vectors of the train and test
    /// windows (None without test windows).
    pub frechet_train_test: Option<f64>,
}

/// Train a classifier on `data`'s train windows, save it to `out`, and
/// measure the train and test windows with it (the measures' draws use
/// `training.seed`).
pub fn train_and_measure(
    data: &Dataset,
    out: &Path,
    training: &ClassifierTraining,
    device: &Device,
) -> Result<ClassifierReport, TrainError> {
    let (windows, labels) = data
        .split("train")
        .ok_or_else(|| TrainError::Invalid(format!("{}: no train windows", data.dir.display())))?;
    let started = std::time::Instant::now();
    let (classifier, loss) = train(windows, labels, training, device)?;
    let seconds = started.elapsed().as_secs_f64();
    let meta = ClassifierMeta {
        config: classifier.config().clone(),
        training: *training,
        dataset: data.dir.display().to_string(),
        dataset_manifest_sha256: data.manifest_sha256.clone(),
        loss,
    };
    classifier.save(out, &meta)?;
    let (train_m, train_f) = measure(&classifier, "train", windows, labels, training.seed, device)?;
    let mut splits = vec![train_m];
    let mut frechet_train_test = None;
    if let Some((w, l)) = data.split("test") {
        let (m, f) = measure(&classifier, "test", w, l, training.seed, device)?;
        splits.push(m);
        frechet_train_test = Some(feature_frechet(&train_f, &f));
    }
    Ok(ClassifierReport {
        out: out.display().to_string(),
        meta,
        seconds,
        splits,
        frechet_train_test,
    })
}

fn share(v: Option<f64>) -> String {
    v.map_or_else(|| "–".into(), |v| format!("{:.1} %", 100.0 * v))
}

fn value(v: Option<f64>) -> String {
    v.map_or_else(|| "–".into(), |v| format!("{v:.3}"))
}

impl std::fmt::Display for ClassifierReport {
    /// The report as Markdown.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let t = &self.meta.training;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "classifier {}: {} epochs (seed {}, batch {}, lr {}) in {:.1} s; loss {} → {}\n",
            self.out,
            t.epochs,
            t.seed,
            t.batch,
            t.adam.lr,
            self.seconds,
            value(self.meta.loss.first().copied()),
            value(self.meta.loss.last().copied()),
        );
        s.push_str("| category |");
        for m in &self.splits {
            let _ = write!(s, " {0} windows | {0} accuracy |", m.split);
        }
        s.push_str("\n|---|");
        for _ in &self.splits {
            s.push_str("---:|---:|");
        }
        for (i, c) in Category::ALL.iter().enumerate() {
            let _ = write!(s, "\n| {c} |");
            for m in &self.splits {
                let n = m.accuracy.per_category[i].0;
                let _ = write!(s, " {n} | {} |", share(m.accuracy.of(*c)));
            }
        }
        s.push_str("\n| **all** |");
        for m in &self.splits {
            let a = &m.accuracy;
            let _ = write!(s, " {} | {} |", a.windows, share(a.overall()));
        }
        s.push_str("\n\n");
        for m in &self.splits {
            let _ = writeln!(
                s,
                "{} windows: diversity {} (S_d ≤ {DIVERSITY_SAMPLES}), multimodality {} (S_l ≤ {MULTIMODALITY_SAMPLES})",
                m.split,
                value(m.diversity),
                value(m.multimodality)
            );
        }
        if let Some(d) = self.frechet_train_test {
            let _ = writeln!(
                s,
                "Fréchet distance of the train and test feature vectors: {d:.3}"
            );
        }
        f.write_str(&s)
    }
}
