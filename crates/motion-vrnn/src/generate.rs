//! Generated motion, measured: windows sampled from a model's prior, turned
//! back into global joint positions, and the [`Judge`] that scores a model
//! by how close its generated motion comes to real motion on every measure
//! of `docs/metrics.md` at once (used to choose the `best` checkpoint).

use crate::data::{Dataset, Stats, Windows};
use crate::error::TrainError;
use crate::model::MotionModel;
use crate::rng::noise;
use candle_core::Device;
use mocap_ingest::features::{to_global, FeatureVec, NUM_FEATURES};
use mocap_ingest::skeleton::Pose;
use motion_metrics::{frechet, goal_distance, motion_stats, window_summary, MotionStats, Options};
use serde::{Deserialize, Serialize};

/// Normalised feature rows (`[T × 58]`) → feature vectors in their units.
pub fn denormalise(x: &[f32], stats: &Stats) -> Vec<FeatureVec> {
    x.chunks(NUM_FEATURES)
        .map(|r| {
            let mut f = [0.0; NUM_FEATURES];
            for (k, v) in f.iter_mut().enumerate() {
                *v = r[k] as f64 * stats.std[k] + stats.mean[k];
            }
            f
        })
        .collect()
}

/// Normalised feature rows (`[T × 58]`, one window) → global joint positions.
pub fn to_poses(x: &[f32], stats: &Stats) -> Vec<Pose> {
    to_global(&denormalise(x, stats))
}

/// The per-window summaries the Fréchet distance compares, of normalised
/// windows `[T × features]`.
pub fn summaries(windows: &[Vec<f32>], features: usize) -> Vec<Vec<f64>> {
    windows
        .iter()
        .map(|x| {
            let rows: Vec<Vec<f32>> = x.chunks(features).map(<[f32]>::to_vec).collect();
            window_summary(&rows)
        })
        .collect()
}

/// Every window of a split, one normalised `[T × features]` vector each.
pub fn windows_of(w: &Windows) -> Vec<Vec<f32>> {
    w.data
        .chunks(w.length * w.features)
        .map(<[f32]>::to_vec)
        .collect()
}

/// Real frames a generated motion continues ([`sample_windows`]): 16
/// frames, about half a second at 30 fps; the frames a model's pace is
/// trained on ([`crate::model::PACE_FRAMES`]).
pub const CONTEXT: usize = crate::model::PACE_FRAMES;

/// How generated motions are rolled out ([`sample_windows`],
/// [`continue_windows`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rollout {
    /// Frames per motion (the start frame included).
    pub frames: usize,
    /// Real frames each motion continues.
    pub context: usize,
    /// Seed of the contexts drawn and of the noise.
    pub seed: u64,
    /// The category asked for (a conditioned model only; None: none).
    pub ask: Option<Ask>,
    /// How hard a motion is held to its asked pace (a model with the pace
    /// part, asked for a category; 0: not at all): [`PACE_GAIN`].
    pub pace_gain: f64,
    /// Draws of noise each run of a held motion is chosen from (1: the one
    /// draw): [`POSE_DRAWS`].
    pub draws: usize,
}

/// How hard a motion is held to its asked pace, unless told otherwise
/// (`--pace-gain`). A model with the pace part ([`crate::model::Parts::pace`])
/// is asked, at every frame, for its context's pace. Each run of at most
/// [`PACE_EVERY`] frames is tried on its noise and its ask corrected
/// [`PACE_CORRECTIONS`] times, each correction `gain × (target − made)`,
/// `made` the pace of the frames that try made (an integral controller on
/// the condition, within the run; [`crate::model::Config::asking_pace`]);
/// the try after the last correction is kept. Training and the judge do not
/// use it (`docs/training.md`, "The sampler"; how it was chosen:
/// `docs/experiments.md`).
pub const PACE_GAIN: f64 = 0.5;

/// Corrections of each run's asked pace before it is kept ([`PACE_GAIN`]):
/// a run held to its pace costs `1 +` this many samplings.
pub const PACE_CORRECTIONS: usize = 3;

pub use crate::model::PACE_EVERY;

/// Draws of noise each run of a held motion ([`PACE_GAIN`]) is chosen from,
/// unless told otherwise (`--draws`): each draw is held to its pace, and
/// each motion keeps the draw whose mean pose (the mean of its normalised
/// features over the run's frames) is closest to the mean pose of its
/// context. A draw is four samplings ([`PACE_CORRECTIONS`]), so 8 draws make
/// a held motion 32 times the work of the model alone.
pub const POSE_DRAWS: usize = 8;

/// The gain a motion of `config`'s model is held to its pace with
/// ([`PACE_GAIN`]): `gain` where the model reads a pace, a category is
/// `asked` and `gain` is above 0; None where nothing is held.
pub fn held_gain(config: &crate::Config, gain: f64, asked: bool) -> Option<f64> {
    (config.parts.pace && asked && gain > 0.0).then_some(gain)
}

pub use crate::model::GUIDANCE;

/// A category asked of a conditioned model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ask {
    /// Its row of the condition table ([`crate::model::Config::category_row`]).
    pub row: usize,
    /// Guidance scale ([`crate::model::Config::condition`]; 1: the
    /// conditional model as trained).
    pub guidance: f64,
}

/// `n` picks among `pool` windows (`pool` of them, indices `0..pool`),
/// drawn at random from `seed`, as [`sample_windows`] draws its contexts.
pub fn picks(seed: u64, n: usize, pool: usize) -> Vec<usize> {
    let mut rng = crate::rng::Rng::new(seed, 0x57A7);
    (0..n)
        .map(|_| ((rng.uniform() * pool as f64) as usize).min(pool.max(1) - 1))
        .collect()
}

/// `n` motions of `o.frames` frames sampled from the prior, normalised
/// `[n][frames × features]`. Each continues the first `o.context` frames of a
/// window of `starts` drawn at random (seeded by `o.seed`): the model reads
/// them through its posterior, so its state and filters start where that
/// real motion puts them (standing, walking, turning), and the prior
/// generates every later frame. The motion is the last context frame (the
/// pose it starts from) and the `frames − 1` frames generated after it,
/// joined without a jump ([`crate::model::SEAM_FRAMES`]); the other context
/// frames are not part of it. A model with `Parts::restart` makes a long
/// motion in runs, each continuing the last `context` frames made. The
/// noise comes from the seed too, so the same model and seed give the same
/// motions.
pub fn sample_windows(
    model: &dyn MotionModel,
    starts: &Windows,
    n: usize,
    o: &Rollout,
    device: &Device,
) -> candle_core::Result<Vec<Vec<f32>>> {
    continue_windows(model, starts, &picks(o.seed, n, starts.n), o, device)
}

/// One motion of `o.frames` frames per index in `picks`, each continuing the
/// first `o.context` frames of that window of `windows`, as
/// [`sample_windows`] makes them (`eval` continues every window of the split
/// it measures, once each, so the generated set starts where the real set
/// does).
pub fn continue_windows(
    model: &dyn MotionModel,
    windows: &Windows,
    picks: &[usize],
    o: &Rollout,
    device: &Device,
) -> candle_core::Result<Vec<Vec<f32>>> {
    let (starts, n, context) = (windows, picks.len(), o.context);
    if starts.n == 0 {
        candle_core::bail!("no windows to start generated motions from");
    }
    if picks.iter().any(|&i| i >= starts.n) {
        candle_core::bail!(
            "a window to continue is out of range ({} windows)",
            starts.n
        );
    }
    if context == 0 || context > starts.length {
        candle_core::bail!(
            "the context of a generated motion must be 1 to {} frames (the window length), got {context}",
            starts.length
        );
    }
    let cond = match o.ask {
        Some(a) => model
            .config()
            .condition(&vec![Some(a.row); n], a.guidance, device)?,
        None => None,
    };
    continue_windows_with(model, windows, picks, o, cond, device)
}

/// [`continue_windows`] with the condition weights `cond` (one row per
/// pick, [`crate::model::Config::condition`]) instead of `o.ask`'s.
pub fn continue_windows_with(
    model: &dyn MotionModel,
    starts: &Windows,
    picks: &[usize],
    o: &Rollout,
    cond: Option<candle_core::Tensor>,
    device: &Device,
) -> candle_core::Result<Vec<Vec<f32>>> {
    let (latent, k, f, n) = (
        model.config().latent,
        o.context,
        starts.features,
        picks.len(),
    );
    let config = model.config();
    // Only the context is read: nothing after it reaches the motion.
    let mut context = starts.batch(picks, device)?.narrow(1, 0, k)?;
    // A model with the pace part is asked for its context's pace.
    let cond = config.paced(cond.as_ref(), Some(&context))?;
    let frames = o.frames.max(1);
    // Held to that pace ([`PACE_GAIN`]): the target, the weights asking for
    // it that each run's corrections start from, and the context's mean
    // pose each run's draws are chosen by ([`POSE_DRAWS`]).
    let held = match (held_gain(config, o.pace_gain, cond.is_some()), &cond) {
        (Some(gain), Some(c)) => Some(Pace {
            target: config.pace_of(&context)?,
            asking: c.clone(),
            gain,
            pose: context.mean(1)?,
        }),
        _ => None,
    };
    // One run of the recurrence, or runs of `segment` new frames, each
    // restarting from a fresh state on the last `k` frames made so far.
    let segment = config
        .parts
        .restart
        .filter(|&l| l > 0 && frames > l + 1)
        .unwrap_or(frames - 1)
        .min(if held.is_some() { PACE_EVERY } else { frames });
    let mut out: Vec<Vec<f32>> = vec![Vec::with_capacity(frames * f); n];
    let mut made = 0;
    for run in 0u64.. {
        // New frames of this run; the first run also gives the start frame
        // (its context's last).
        let new = segment.min(frames - made.max(1));
        let draw = |d: u64| {
            noise(
                o.seed ^ 0x5A3F1E ^ (d << 40),
                run,
                k + new,
                n,
                latent,
                device,
            )
        };
        let x = match &held {
            Some(pace) => chosen_run(model, &draw, &context, new, pace, o.draws)?,
            None => model
                .sample(&draw(0)?, Some(&context), cond.as_ref())?
                .narrow(1, k - 1, new + 1)?,
        };
        let v = x.flatten_all()?.to_vec1::<f32>()?;
        for (m, o) in v.chunks((new + 1) * f).zip(out.iter_mut()) {
            o.extend_from_slice(if made == 0 { m } else { &m[f..] });
        }
        made = out[0].len() / f;
        if made >= frames {
            break;
        }
        let last: Vec<f32> = out
            .iter()
            .flat_map(|o| o[(made - k) * f..].iter().copied())
            .collect();
        context = candle_core::Tensor::from_vec(last, (n, k, f), device)?;
    }
    Ok(out)
}

/// A run of a motion: its noise `[k + new, n, latent]`, the `k` frames it
/// continues `[n, k, features]` and the frames it makes after them.
struct Tries<'a> {
    eps: &'a candle_core::Tensor,
    context: &'a candle_core::Tensor,
    new: usize,
}

/// The condition weights a run is kept with, held to `pace.target`
/// (`[n, PACE_FEATURES]`) at `pace.gain` ([`PACE_GAIN`]): from
/// `pace.asking` (the weights asking for the target), [`PACE_CORRECTIONS`]
/// tries, each moving the pace asked for by `gain × (target − made)`,
/// `made` the pace of the try's frames (the context's last and the new
/// ones).
fn held_to_pace(
    model: &dyn MotionModel,
    run: &Tries,
    pace: &Pace,
) -> candle_core::Result<candle_core::Tensor> {
    let (config, k) = (model.config(), run.context.dim(1)?);
    let (mut want, mut cond) = (pace.target.clone(), pace.asking.clone());
    for _ in 0..PACE_CORRECTIONS {
        let x = model.sample(run.eps, Some(run.context), Some(&cond))?;
        let made = config.pace_of(&x.narrow(1, k - 1, run.new + 1)?)?;
        want = (&want + ((&pace.target - &made)? * pace.gain)?)?;
        cond = config.asking_pace(&pace.asking, &want)?;
    }
    Ok(cond)
}

/// What a held motion's runs are held to: the pace `target`, the weights
/// `asking` for it, the `gain` ([`held_to_pace`]) and the mean `pose`
/// (`[n, features]`) its draws are chosen by ([`POSE_DRAWS`]).
struct Pace {
    target: candle_core::Tensor,
    asking: candle_core::Tensor,
    gain: f64,
    pose: candle_core::Tensor,
}

/// The frames `[n, new + 1, features]` of a held run after `context`: of
/// `draws` draws of noise (`draw(d)`), each held to its pace
/// ([`held_to_pace`]), each motion keeps the one whose mean pose is closest
/// to `pace.pose` (the earlier on a tie).
fn chosen_run(
    model: &dyn MotionModel,
    draw: &dyn Fn(u64) -> candle_core::Result<candle_core::Tensor>,
    context: &candle_core::Tensor,
    new: usize,
    pace: &Pace,
    draws: usize,
) -> candle_core::Result<candle_core::Tensor> {
    let k = context.dim(1)?;
    let one = |d: u64| -> candle_core::Result<(Vec<f32>, candle_core::Tensor)> {
        let eps = draw(d)?;
        let tries = Tries {
            eps: &eps,
            context,
            new,
        };
        let c = held_to_pace(model, &tries, pace)?;
        let x = model.sample(&eps, Some(context), Some(&c))?;
        let x = x.narrow(1, k - 1, new + 1)?;
        Ok(((x.mean(1)? - &pace.pose)?.sqr()?.sum(1)?.to_vec1()?, x))
    };
    let (mut off, mut x) = one(0)?;
    for d in 1..draws.max(1) as u64 {
        let (o, y) = one(d)?;
        let closer: Vec<u8> = o.iter().zip(&off).map(|(a, b)| u8::from(a < b)).collect();
        let mask = candle_core::Tensor::from_vec(closer, (o.len(), 1, 1), x.device())?;
        x = mask.broadcast_as(y.shape())?.where_cond(&y, &x)?;
        off = o.iter().zip(&off).map(|(a, b)| a.min(*b)).collect();
    }
    Ok(x)
}

/// Sampling seed of the judge: apart from the seeds `cargo xtask eval` and
/// `sample` use by default, so the checkpoint is not chosen on the motions
/// it is then reported with.
pub const JUDGE_SEED: u64 = 0x1D6E;

/// Motions the judge generates.
pub const JUDGE_MOTIONS: usize = 200;

/// Training windows the judge measures real motion on, at most (evenly
/// spaced through the split, so APD over all pairs stays cheap on the whole
/// database).
pub const JUDGE_REFERENCE: usize = 800;

/// A model's generated motion, measured against the training windows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// [`goal_distance`] of the generated motion (lower is better; with a
    /// longer rollout, the first stretch's plus the last's).
    pub score: f64,
    /// Fréchet distance of the generated windows to the training windows.
    pub frechet: f64,
    /// The generated motion's measures.
    pub generated: MotionStats,
    /// With a longer rollout ([`Judge::stretches`]): the last stretch's
    /// measures and Fréchet distance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last: Option<(MotionStats, f64)>,
}

/// Scores models by their generated motion: [`JUDGE_MOTIONS`] motions, each
/// continuing the first [`CONTEXT`] frames of a training window (a
/// conditioned model asked for that window's category and its context's
/// pace at guidance 1; one draw, the pace not held), measured against the
/// training windows (at most [`JUDGE_REFERENCE`]), the distribution they start from and the model is fit
/// to. The Fréchet reference is the validation windows' distance to the
/// training windows: generated windows should come as close to the training
/// set as held-out real windows do.
pub struct Judge<'a> {
    starts: &'a Windows,
    categories: &'a [crate::data::Category],
    stats: &'a Stats,
    real: MotionStats,
    real_summaries: Vec<Vec<f64>>,
    frechet_ref: f64,
    options: Options,
    stretches: usize,
}

impl<'a> Judge<'a> {
    /// A judge on `data`'s `train` windows (and `val` for the Fréchet
    /// reference; without validation windows Fréchet is left out of the score).
    pub fn new(data: &'a Dataset) -> Result<Self, TrainError> {
        let get = |s: &str| data.splits.get(s).filter(|w| w.n > 0);
        let train = get("train").ok_or_else(|| {
            TrainError::Invalid(format!(
                "{}: choosing the checkpoint by generated motion needs train windows",
                data.dir.display()
            ))
        })?;
        let options = Options::default();
        let all = windows_of(train);
        let k = all.len().min(JUDGE_REFERENCE);
        let real: Vec<Vec<f32>> = (0..k).map(|i| all[i * all.len() / k].clone()).collect();
        let poses: Vec<Vec<Pose>> = real.iter().map(|x| to_poses(x, &data.stats)).collect();
        let real_summaries = summaries(&real, train.features);
        let frechet_ref = get("val").map_or(0.0, |val| {
            frechet(&summaries(&windows_of(val), val.features), &real_summaries)
        });
        Ok(Judge {
            starts: train,
            categories: data.categories_of("train"),
            stats: &data.stats,
            real: motion_stats(&poses, &options),
            real_summaries,
            frechet_ref,
            options,
            stretches: 1,
        })
    }

    /// Roll each motion out for `n` window-long stretches (at least 1) and
    /// score the first and the last: the checkpoint whose motion still holds
    /// after `n` windows wins, not only the one that starts best.
    pub fn stretches(mut self, n: usize) -> Self {
        self.stretches = n.max(1);
        self
    }

    /// The measures of the training windows.
    pub fn real(&self) -> &MotionStats {
        &self.real
    }

    /// The Fréchet distance of the validation windows to the training ones
    /// (0 without validation windows).
    pub fn frechet_ref(&self) -> f64 {
        self.frechet_ref
    }

    /// Generate with `model` (sampling seed [`JUDGE_SEED`]) and measure.
    pub fn judge(&self, model: &dyn MotionModel, device: &Device) -> Result<Verdict, TrainError> {
        let (n, len, f) = (JUDGE_MOTIONS, self.starts.length, self.starts.features);
        let rollout = Rollout {
            frames: self.stretches * len,
            context: CONTEXT,
            seed: JUDGE_SEED,
            ask: None,
            pace_gain: 0.0,
            draws: 1,
        };
        // A conditioned model is asked for each context's own category.
        let picks = picks(rollout.seed, n, self.starts.n);
        let cond =
            model
                .config()
                .window_condition(self.categories, &picks, 1.0, |_| false, device)?;
        let gen = continue_windows_with(model, self.starts, &picks, &rollout, cond, device)?;
        // A stretch of every motion, re-based to its own start (its
        // features are local), measured and scored.
        let measure = |k: usize| {
            let w: Vec<Vec<f32>> = gen
                .iter()
                .map(|x| x[k * len * f..(k + 1) * len * f].to_vec())
                .collect();
            let poses: Vec<Vec<Pose>> = w.iter().map(|x| to_poses(x, self.stats)).collect();
            let stats = motion_stats(&poses, &self.options);
            let frechet = frechet(&self.real_summaries, &summaries(&w, f));
            let score = goal_distance(&self.real, &stats, frechet, self.frechet_ref);
            (stats, frechet, score)
        };
        let (generated, frechet, mut score) = measure(0);
        let last = (self.stretches > 1).then(|| measure(self.stretches - 1));
        if let Some((_, _, s)) = &last {
            score += s;
        }
        Ok(Verdict {
            score: if score.is_finite() {
                score
            } else {
                f64::INFINITY
            },
            frechet,
            generated,
            last: last.map(|(m, fr, _)| (m, fr)),
        })
    }
}
