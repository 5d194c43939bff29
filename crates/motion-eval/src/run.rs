//! A trained run loaded with its dataset, and the windows it makes: real
//! windows reconstructed, new motions generated from real contexts.

use crate::EvalError;
use candle_core::Device;
use mocap_ingest::Pose;
use motion_render::feet::{Pinned, Planted};
use motion_render::Motion;
use motion_vrnn::data::Category;
use motion_vrnn::data::{Dataset, Stats, Windows};
use motion_vrnn::generate::{self, to_poses, Ask, Rollout};
use motion_vrnn::train::{layout, load_model, CheckpointMeta, Trained};
use motion_vrnn::MotionModel;
use std::path::PathBuf;

/// Which run, checkpoint and data; how motions are generated from it.
#[derive(Clone, Debug)]
pub struct RunSpec {
    /// Run directory written by `cargo xtask train`.
    pub run: PathBuf,
    /// Checkpoint inside the run: `best` or `last`.
    pub checkpoint: String,
    /// Dataset directory (`None`: the one the run was trained on).
    pub data: Option<PathBuf>,
    /// Seed of the sampling noise and of the contexts drawn.
    pub seed: u64,
    /// Split of real windows to reconstruct and compare with.
    pub split: String,
    /// Real frames each generated motion continues.
    pub context: usize,
    /// Sampling temperature instead of the model's own.
    pub temperature: Option<f64>,
    /// Foot-lock sharpness instead of the model's own
    /// (`Parts::contact_sharpness`).
    pub contact_sharpness: Option<f64>,
    /// Frames per run of the recurrence instead of the model's own
    /// (`Some(0)`: one run; see `Parts::restart`).
    pub restart: Option<usize>,
    /// The category to generate (a model trained with `--condition
    /// category`): generated motions are asked for it and continue
    /// training windows of it; [`OWN`]: each motion the category of the
    /// window it continues (the default of a conditioned model); [`NONE`]:
    /// no category.
    pub category: Option<String>,
    /// Guidance scale of the category ([`motion_vrnn::Config::condition`]).
    pub guidance: f64,
    /// How hard a motion is held to its asked pace
    /// ([`generate::PACE_GAIN`]; 0: not at all).
    pub pace_gain: f64,
    /// Draws each run of a held motion is chosen from
    /// ([`generate::POSE_DRAWS`]; at least 1).
    pub draws: usize,
    /// Pin the planted toes of generated motions in place
    /// ([`motion_render::feet::pin_feet`]): what `sample` and `continue`
    /// write and what `eval` measures of them.
    pub pin_feet: bool,
}

impl RunSpec {
    /// The `best` checkpoint of `run` on the `test` split, seed 0, the
    /// standard context, the model's own temperature, the default guidance.
    pub fn best(run: PathBuf, data: Option<PathBuf>) -> RunSpec {
        RunSpec {
            run,
            checkpoint: layout::BEST.into(),
            data,
            seed: 0,
            split: "test".into(),
            context: generate::CONTEXT,
            temperature: None,
            contact_sharpness: None,
            restart: None,
            category: None,
            guidance: generate::GUIDANCE,
            pace_gain: generate::PACE_GAIN,
            draws: generate::POSE_DRAWS,
            pin_feet: false,
        }
    }
}

/// Normalised windows, one `[T × 58]` vector each.
pub type WindowSet = Vec<Vec<f32>>;

/// A loaded run: model, checkpoint metadata, dataset, device.
pub struct Run {
    /// The model and its variables.
    pub model: Trained,
    /// The checkpoint's metadata (epoch, options, dataset hash).
    pub meta: CheckpointMeta,
    /// The dataset's splits that were asked for.
    pub data: Dataset,
    /// Where the model runs.
    pub device: Device,
    /// What the caller should tell the user (e.g. another dataset than the
    /// run's).
    pub warnings: Vec<String>,
    /// What generated motions are asked for ([`RunSpec::category`]).
    pub ask: Asking,
    /// Whether `--category` was given (a clip continued by a conditioned
    /// model asks for no category unless told one).
    pub asked_explicitly: bool,
    /// How hard motions are held to their asked pace
    /// ([`RunSpec::pace_gain`]).
    pub pace_gain: f64,
    /// Draws each run of a held motion is chosen from ([`RunSpec::draws`]).
    pub draws: usize,
    /// Whether generated motions get their planted toes pinned
    /// ([`RunSpec::pin_feet`]).
    pub pin_feet: bool,
}

/// `--category own`: each motion asks for the category of the window it
/// continues (what a conditioned model's motions do unless told otherwise).
pub const OWN: &str = "own";

/// `--category none`: no category (row 0 of a conditioned model).
pub const NONE: &str = "none";

/// What a run's generated motions are asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Asking {
    /// No category (row 0 of a conditioned model; any unconditioned model).
    Nothing,
    /// One category for every motion, each continuing a training window of it.
    One(Category, Ask),
    /// Each motion the category of the window it continues, at this guidance.
    Own(f64),
}

impl Run {
    /// Load the run of `spec` and the `splits` of its dataset.
    pub fn load(spec: &RunSpec, splits: &[&str]) -> Result<Run, EvalError> {
        let device = motion_vrnn::model::default_device();
        let ck = spec.run.join(&spec.checkpoint);
        if !ck.join(layout::META).exists() {
            return Err(EvalError::NoCheckpoint {
                checkpoint: ck,
                run: spec.run.clone(),
            });
        }
        let (mut model, meta) = load_model(&ck, &device)?;
        if let Some(t) = spec.temperature {
            model
                .model
                .set_temperature(Some(t))
                .map_err(|e| EvalError::Invalid(format!("--temperature: {e}")))?;
        }
        if let Some(k) = spec.contact_sharpness {
            model
                .model
                .set_contact_sharpness(Some(k))
                .map_err(|e| EvalError::Invalid(format!("--contact-sharpness: {e}")))?;
        }
        if let Some(r) = spec.restart {
            model.model.set_restart(Some(r));
        }
        if !(spec.guidance.is_finite() && spec.guidance >= 0.0) {
            return Err(EvalError::Invalid(format!(
                "--guidance must be 0 or more, got {}",
                spec.guidance
            )));
        }
        if !(spec.pace_gain.is_finite() && spec.pace_gain >= 0.0) {
            return Err(EvalError::Invalid(format!(
                "--pace-gain must be 0 or more, got {}",
                spec.pace_gain
            )));
        }
        if spec.draws == 0 {
            return Err(EvalError::Invalid(
                "--draws must be 1 or more (1: the one draw of noise)".into(),
            ));
        }
        let invalid = |e: String| EvalError::Invalid(format!("--category: {}: {e}", ck.display()));
        let ask = match spec.category.as_deref() {
            // A conditioned model's motions ask for their contexts' categories
            // unless told otherwise.
            None if !meta.config.model.categories.is_empty() => Asking::Own(spec.guidance),
            None | Some(NONE) => Asking::Nothing,
            Some(OWN) if meta.config.model.categories.is_empty() => {
                return Err(invalid(format!(
                    "`{OWN}` asks each motion for its context's category, and this model was trained without categories; train one with `cargo xtask train --condition category`"
                )))
            }
            Some(OWN) => Asking::Own(spec.guidance),
            Some(name) => {
                let row = meta.config.model.category_row(name).map_err(invalid)?;
                let category = name.parse().map_err(EvalError::Invalid)?;
                Asking::One(
                    category,
                    Ask {
                        row,
                        guidance: spec.guidance,
                    },
                )
            }
        };
        let dir = spec
            .data
            .clone()
            .unwrap_or_else(|| PathBuf::from(&meta.dataset));
        let data = motion_vrnn::data::load(&dir, splits).map_err(|cause| EvalError::Data {
            dir: dir.clone(),
            cause,
        })?;
        let mut warnings = Vec::new();
        if data.manifest_sha256 != meta.dataset_manifest_sha256 {
            warnings.push(format!(
                "{} is not the dataset this run was trained on (manifest hash differs)",
                dir.display()
            ));
        }
        Ok(Run {
            model,
            meta,
            data,
            device,
            warnings,
            ask,
            asked_explicitly: spec.category.is_some(),
            pace_gain: spec.pace_gain,
            draws: spec.draws,
            pin_feet: spec.pin_feet,
        })
    }

    /// `f` of this run sampled by the model alone: one draw, the pace not
    /// held; the run's own sampler is restored afterwards.
    pub fn alone<T>(&mut self, f: impl FnOnce(&Run) -> T) -> T {
        let sampler = (self.pace_gain, self.draws);
        (self.pace_gain, self.draws) = (0.0, 1);
        let out = f(self);
        (self.pace_gain, self.draws) = sampler;
        out
    }

    /// The gain motions are held to their asked pace with, and the draws
    /// each run is chosen from, where they are held ([`generate::held_gain`]).
    pub fn held_pace(&self) -> Option<(f64, usize)> {
        let config = self.model.model.config();
        generate::held_gain(config, self.pace_gain, self.ask != Asking::Nothing)
            .map(|g| (g, self.draws))
    }

    /// The guidance scale generated motions ask their category at (None:
    /// they ask for none).
    pub fn guidance(&self) -> Option<f64> {
        match self.ask {
            Asking::Nothing => None,
            Asking::One(_, ask) => Some(ask.guidance),
            Asking::Own(g) => Some(g),
        }
    }

    /// The windows of split `name`, or an error when it has none.
    pub fn split(&self, name: &str) -> Result<&Windows, EvalError> {
        self.labelled(name).map(|s| s.0)
    }

    /// The windows of split `name` with their categories, or an error when
    /// it has none.
    pub fn labelled(&self, name: &str) -> Result<(&Windows, &[Category]), EvalError> {
        self.data.split(name).ok_or_else(|| EvalError::NoWindows {
            dir: self.data.dir.clone(),
            split: name.to_string(),
        })
    }

    /// `n` motions of `frames` frames sampled from the prior, each
    /// continuing `context` frames of a random training window
    /// ([`generate::sample_windows`]), normalised. With a category asked
    /// for ([`RunSpec::category`]), the motions are asked for it and
    /// continue training windows of it.
    pub fn sample(
        &self,
        n: usize,
        frames: usize,
        context: usize,
        seed: u64,
    ) -> Result<WindowSet, EvalError> {
        self.sample_asked(self.ask, n, frames, context, seed)
    }

    /// [`Run::sample`] asking for `ask` instead of the run's own.
    pub fn sample_asked(
        &self,
        ask: Asking,
        n: usize,
        frames: usize,
        context: usize,
        seed: u64,
    ) -> Result<WindowSet, EvalError> {
        let (train, categories) = self.labelled("train")?;
        let category = match ask {
            Asking::One(c, _) => Some(c),
            _ => None,
        };
        let picks = self.training_picks(category, n, seed)?;
        self.continue_asked(ask, train, categories, &picks, frames, context, seed)
    }

    /// `n` training windows drawn from `seed` ([`generate::picks`]) among
    /// those of `category` (all where None), or an error where there are
    /// none.
    pub fn training_picks(
        &self,
        category: Option<Category>,
        n: usize,
        seed: u64,
    ) -> Result<Vec<usize>, EvalError> {
        let (train, categories) = self.labelled("train")?;
        let pool: Vec<usize> = (0..train.n)
            .filter(|&i| category.is_none_or(|c| categories.get(i) == Some(&c)))
            .collect();
        if pool.is_empty() {
            let what = category.map_or("any category".into(), |c| c.to_string());
            return Err(EvalError::Invalid(format!(
                "{}: no training windows of {what} to start from",
                self.data.dir.display()
            )));
        }
        Ok(generate::picks(seed, n, pool.len())
            .into_iter()
            .map(|i| pool[i])
            .collect())
    }

    /// One motion of `frames` frames per window of `windows` in `picks`
    /// (whose categories are `categories`), each continuing `context` of
    /// its frames and asked for `ask`.
    #[allow(clippy::too_many_arguments)]
    pub fn continue_asked(
        &self,
        ask: Asking,
        windows: &Windows,
        categories: &[Category],
        picks: &[usize],
        frames: usize,
        context: usize,
        seed: u64,
    ) -> Result<WindowSet, EvalError> {
        let model = &self.model.model;
        let o = Rollout {
            frames,
            context,
            seed,
            pace_gain: self.pace_gain,
            draws: self.draws,
            ask: match ask {
                Asking::One(_, a) => Some(a),
                _ => None,
            },
        };
        let Asking::Own(guidance) = ask else {
            return Ok(generate::continue_windows(
                model,
                windows,
                picks,
                &o,
                &self.device,
            )?);
        };
        let cond = model.config().window_condition(
            categories,
            picks,
            guidance,
            |_| false,
            &self.device,
        )?;
        Ok(generate::continue_windows_with(
            model,
            windows,
            picks,
            &o,
            cond,
            &self.device,
        )?)
    }

    /// Real windows `idx` of split `split` and their reconstructions,
    /// normalised (a conditioned model reads each window's category).
    pub fn reconstruct(
        &self,
        split: &str,
        idx: &[usize],
    ) -> Result<(WindowSet, WindowSet), EvalError> {
        let (w, categories) = self.labelled(split)?;
        let per = w.length * w.features;
        let mut real = Vec::new();
        let mut rec = Vec::new();
        for chunk in idx.chunks(256) {
            let x = w.batch(chunk, &self.device)?;
            let cond = self.model.model.config().window_condition(
                categories,
                chunk,
                1.0,
                |_| false,
                &self.device,
            )?;
            let r = self.model.model.reconstruct(&x, cond.as_ref())?;
            for (set, t) in [(&mut real, &x), (&mut rec, &r)] {
                set.extend(
                    t.flatten_all()?
                        .to_vec1::<f32>()?
                        .chunks(per)
                        .map(<[f32]>::to_vec),
                );
            }
        }
        Ok((real, rec))
    }

    /// A generated motion's normalised features `[T × 58]` → its global
    /// poses, the planted toes pinned when the run asks for it.
    pub fn generated_poses(&self, x: &[f32]) -> Vec<Pose> {
        let mut poses = to_poses(x, &self.data.stats);
        if self.pin_feet {
            pin_feet(&mut poses);
        }
        poses
    }

    /// Normalised features `[T × 58]` → a named global motion.
    pub fn motion(&self, id: String, x: &[f32]) -> Motion {
        to_motion(id, x, &self.data.stats)
    }
}

/// Pins the planted toes of `poses` in place
/// ([`motion_render::feet::pin_feet`]), planted meaning what the foot
/// measures of `motion-metrics` count as creeping.
pub fn pin_feet(poses: &mut [Pose]) -> Pinned {
    let o = motion_metrics::Options::default();
    let planted = Planted {
        contact_m: o.contact_m,
        slide_m_s: o.skate_m_s,
    };
    motion_render::feet::pin_feet(poses, &planted)
}

/// Normalised features `[T × 58]` → a named global motion.
pub fn to_motion(id: String, x: &[f32], stats: &Stats) -> Motion {
    Motion {
        id,
        poses: to_poses(x, stats),
    }
}
