//! [`TrainConfig`]: the training options, their presets and schedules, and
//! the scheduled-sampling mask.

use super::*;

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
    /// Training windows seen that set the schedule (`--budget`): the
    /// epochs and every schedule counted in epochs are scaled to the
    /// dataset before the first epoch ([`TrainConfig::for_windows`]; a
    /// checkpoint holds them scaled); None: the epochs as given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget: Option<u64>,
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

/// Share of the training windows whose control is left free at each step
/// ([`crate::model::Parts::control`]), drawn apart from the category's
/// dropout, so the model learns both to follow a path and to choose its
/// own way.
pub const CONTROL_DROPOUT: f64 = 0.1;

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
            budget: None,
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

    /// `self` for a dataset of `windows` training windows. With a
    /// [`TrainConfig::budget`] of `B` windows seen, `E = B / windows`
    /// epochs (rounded to the nearest, at least 1), and every schedule
    /// counted in epochs multiplied by `E / epochs` (rounded to the
    /// nearest, at least 1): the KL warm-up, the early-stopping patience,
    /// the judge's period, the epochs of each initialisation and the late
    /// epochs; the learning rate's annealing and the feed ramp follow the
    /// epochs (their halves). Where `B / windows` is `epochs`, `self`
    /// unchanged; without a budget too. The result scales to itself again.
    pub fn for_windows(&self, windows: usize) -> TrainConfig {
        let mut c = self.clone();
        let Some(budget) = self.budget.filter(|_| windows > 0) else {
            return c;
        };
        let n = windows as u64;
        let epochs = ((budget + n / 2) / n).max(1) as usize;
        let was = self.epochs.max(1);
        let scale = |m: usize| ((m * epochs + was / 2) / was).max(1);
        c.epochs = epochs;
        if c.kl_warmup_epochs > 0 {
            c.kl_warmup_epochs = scale(c.kl_warmup_epochs);
        }
        c.early_stopping = c.early_stopping.map(scale);
        if let Select::Generation { every } = c.select {
            c.select = Select::Generation {
                every: scale(every),
            };
        }
        if let Some(i) = &mut c.inits {
            i.epochs = scale(i.epochs);
        }
        c.rollout_last = c.rollout_last.map(scale);
        c
    }

    /// The line `train` opens with: the model named `model` and what the
    /// run adds ([`TrainConfig::extras`]), the `(train, val)` windows of
    /// `data` and the device, the batch, the epochs (with the budget they
    /// come from) and the learning rate.
    pub fn announce(
        &self,
        model: &str,
        (train, val): (usize, usize),
        data: &Path,
        device: &Device,
    ) -> String {
        let budget = self.budget.map_or(String::new(), |b| {
            format!(" (a budget of {b} windows seen; --epochs N: N epochs)")
        });
        format!(
            "training the {model} model{} on {train} train / {val} val windows from {} on {}; batch {}, {} epochs{budget}, lr {}",
            self.extras(),
            data.display(),
            crate::model::device_name(device),
            self.batch,
            self.epochs,
            self.adam.lr
        )
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
            let p = &self.model.parts;
            s += match (p.pace, p.control) {
                (true, true) => " conditioned on the category, its pace and a path to follow (--condition none: none of them)",
                (true, false) => " conditioned on the category and its pace (--condition none: neither)",
                _ => " conditioned on the category (--condition none: without)",
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
