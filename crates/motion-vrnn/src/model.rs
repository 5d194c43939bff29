//! The VRNN of Murakami & Ikuzawa (section 4.2), after Chung et al. (2015),
//! and the parts this project adds to it, written once from the fused
//! blocks of [`crate::blocks`].
//!
//! Per time step, with `h` the LSTM state before the step:
//! - features `x'' = relu(W2 relu(W1 x))` (58 → 48 → 32);
//! - prior `N(μp, σp)` from `h` (`σ = sigmoid(·)`), `N(0, I)` at the first step;
//! - posterior `N(μz, σz)` from `[x'', h]`; `z = μz + σz ⊙ ε`;
//! - decoder `x̃ = W5 relu(W4 relu(W3 [z, h]))` (→ 32 → 48 → 58);
//! - LSTM input `[x'', z]`, hidden 32, `h0 = c0 = 0`.
//!
//! Loss per step: `‖x̃ − x‖² + KL(N(μz,σz) ‖ N(μp,σp))`, summed over time and
//! averaged over the batch. Standard deviations are clamped to at least
//! [`SIGMA_MIN`] so the logs stay finite.
//!
//! [`Parts`] switches on what goes beyond the paper (all off is the paper's
//! model, bit for bit the same losses and gradients as before):
//! - `skeleton`: each decoded bone (decoded joint minus decoded parent) is
//!   rescaled to a fixed length by forward kinematics: the window's bone
//!   lengths (training, reconstruction) or the start window's / the
//!   training set's mean skeleton (sampling), so bones cannot stretch;
//! - `latent_filter`: the decoder reads the latent through a causal
//!   low-pass filter over time, so a per-step latent draw cannot make the
//!   pose jump (the paper's "filter over time inside the model");
//! - `self_feed`, `feed_rounds`: scheduled sampling, rolled out over one or
//!   more rounds; `temperature`: the prior's spread when sampling;
//! - the rest (output filter, feet) on [`Parts`].

use crate::blocks::feet::{self, ground, lock, FootLockOp, TOES};
use crate::blocks::scan::ScanDims;
use crate::blocks::skeleton::{bone_lengths, place, row_bone_lengths, PlaceOp, BONES};
use crate::blocks::{
    self, add_rows, filter, gaussian_kl, latent_lstm, linear, lstm_cell, rollout, squared_error,
    Act,
};
use candle_core::{DType, Device, Result, Tensor, D};
use candle_nn::VarBuilder;
use mocap_ingest::category::Category;
use mocap_ingest::features::{ANG_VEL_Y, ROOT_Y, VEL_X, VEL_Z};
use serde::{Deserialize, Serialize};

pub use crate::blocks::SIGMA_MIN;

/// Every size of the model, and the parts beyond the paper.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Config {
    /// Features per frame.
    pub input: usize,
    /// Feature-extractor layer sizes.
    pub extractor: [usize; 2],
    /// LSTM hidden size.
    pub hidden: usize,
    /// Latent size.
    pub latent: usize,
    /// Decoder hidden sizes (ψ, then the next layer).
    pub decoder: [usize; 2],
    /// What the model adds to the paper's (absent in the paper's checkpoints).
    #[serde(default, skip_serializing_if = "Parts::is_paper")]
    pub parts: Parts,
    /// The data the skeleton and feet parts need, filled from the training set by
    /// [`Config::fit_to`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body: Option<Body>,
    /// The categories the model is conditioned on (`walk`, …, in
    /// [`mocap_ingest::category::Category::ALL`] order; those with training
    /// windows), filled by training with `--condition category`; empty: an
    /// unconditioned model (every checkpoint from before conditioning).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub categories: Vec<String>,
}

impl Default for Config {
    /// The paper's sizes.
    fn default() -> Self {
        Config {
            input: 58,
            extractor: [48, 32],
            hidden: 32,
            latent: 8,
            decoder: [32, 48],
            parts: Parts::default(),
            body: None,
            categories: Vec::new(),
        }
    }
}

/// The parts beyond the paper (see the module docs).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Parts {
    /// Joints by forward kinematics from decoded bone directions.
    #[serde(default)]
    pub skeleton: bool,
    /// Pole `ρ ∈ [0, 1)` of the causal filter on the decoder's latent (0: off).
    #[serde(default)]
    pub latent_filter: f64,
    /// Pole `ρ ∈ [0, 1)` of the causal filter on the decoder's output, before
    /// forward kinematics (0: off).
    #[serde(default)]
    pub output_filter: f64,
    /// Foot-locked root motion: the decoder also predicts each foot's contact
    /// (trained on the real toe being below 5 cm), and the root's planar
    /// velocity is the one that keeps the feet in contact where they were
    /// (blended with the decoded velocity by the contact probability).
    #[serde(default)]
    pub foot_lock: bool,
    /// Weight of the foot-contact penalty: the squared horizontal slide of
    /// each decoded toe over the frames where the real toe is on the floor
    /// (CMU units², summed like the reconstruction error; 0: off).
    #[serde(default)]
    pub feet: f64,
    /// Scheduled sampling: the largest share of frames whose recurrence
    /// input is the model's own one-step prediction instead of the real
    /// frame (0: off). Training raises the share from 0 to this over the
    /// first half of its epochs ([`crate::train::TrainConfig::feed_share`]).
    #[serde(default)]
    pub self_feed: f64,
    /// Weight of the KL term once warmed up (None: 1, the ELBO). Below 1
    /// the latent may carry more of each motion (a β-VAE with β < 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kl_weight: Option<f64>,
    /// Rounds of scheduled sampling (None: 1). In round `r + 1` the
    /// recurrence that predicts the fed-back frames reads round `r`'s, so a
    /// run of consecutive fed frames is rolled out up to this many steps
    /// deep on the model's own motion. `Some(0)`: to every depth, in one
    /// pass in time order (each fed frame from a state that read every
    /// earlier one, as sampling makes it; `docs/training.md`, "Fed back to
    /// every depth").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feed_rounds: Option<usize>,
    /// Sampling temperature: the scale of the prior's standard deviation
    /// when generating (None: 1). Training and the ELBO do not use it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temperature: Option<f64>,
    /// The feed rounds draw the prior's latent at [`Parts::temperature`],
    /// as sampling does, so training rolls out the motion generation will
    /// make (false: at 1, the prior as trained; the `minute` preset's).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub rollouts_at_temperature: bool,
    /// The gradient flows through the fed-back frames: fed back to every
    /// depth on the model's own weights by the fused pass with its backward
    /// (`rollout::RolloutOp`; the step loop `Vrnn::fed_in_sequence` off
    /// the CPU) instead of the fused pass on detached ones, so the losses
    /// after a fed frame reach what made it. A training step costs about
    /// 1.4× one without it. Needs `feed_rounds` 0. Set in the late epochs
    /// ([`crate::train::TrainConfig::late_model`]).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub rollout_gradient: bool,
    /// Generation in runs of at most this many new frames: after each, the
    /// recurrence restarts from a fresh state, reading the last frames made
    /// as its context, so it never runs far longer than the windows it was
    /// trained on (None: one run however long the motion). Training and
    /// the ELBO do not use it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restart: Option<usize>,
    /// Sharpness of the foot lock when generating: the contact logits are
    /// multiplied by it before the lock weighs the toes (None: 1, as
    /// trained). Above 1 a toe the model thinks is probably down counts
    /// more, and one probably in the air less, so a swinging foot no
    /// longer pulls the root back. Training and the ELBO do not use it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_sharpness: Option<f64>,
    /// The pace: a conditioned model also reads, at every step, the mean
    /// of [`PACE_FEATURES`] over the sequence ([`pace`]), so a rollout is
    /// told the height, speed and turning to keep. Training reads each
    /// whole window's; generation asks for its context's, never for frames
    /// after it ([`crate::generate::continue_windows_with`],
    /// [`Config::paced`]). Needs [`Config::categories`].
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub pace: bool,
    /// Weight of the fed speed loss (None: off; needs the skeleton's
    /// statistics): over each window's fed frames, the root's mean
    /// horizontal speed must be the real frames', as a ratio
    /// ([`fed_speed_loss`]). A loss on what the rollout does over a window,
    /// not on each frame: through the gradient of [`Parts::rollout_gradient`]
    /// it reaches every step that made a fed frame (without it the fed
    /// frames carry no gradient, nor does the loss). Set, with that, in the
    /// late epochs ([`crate::train::TrainConfig::late_model`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fed_speed: Option<f64>,
    /// Weight of the root's motion ([`ROOT_FEATURES`]) in the squared
    /// error, in place of the ELBO's 1 (None: 1): the term `(w − 1) Σ (x̂ −
    /// x)²` over those features joins the extra losses, so the
    /// reconstruction and the ELBO reported stay the model's. The decoder
    /// spends more of itself on where the root goes. Set in the late
    /// epochs ([`crate::train::TrainConfig::late_root_weight`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub root_weight: Option<f64>,
}

/// The normalised features of the root's motion ([`Parts::root_weight`]):
/// `vel_x`, `vel_z`, `ang_vel_y`, the last three.
pub const ROOT_FEATURES: std::ops::Range<usize> = VEL_X..ANG_VEL_Y + 1;

/// The normalised features whose means make the pace ([`Parts::pace`]):
/// `root_y`, `vel_x`, `vel_z`, `ang_vel_y`.
pub const PACE_FEATURES: [usize; 4] = [ROOT_Y, VEL_X, VEL_Z, ANG_VEL_Y];

/// Category weights `cond: [B, categories + 1]` with the pace `[B,
/// PACE_FEATURES]` as their last columns, weighed like the category (`1 −`
/// the weight of row 0): [`Config::paced`], [`Config::asking_pace`].
fn with_pace(cond: &Tensor, pace: &Tensor) -> Result<Tensor> {
    let asked = cond.narrow(1, 0, 1)?.affine(-1.0, 1.0)?;
    Tensor::cat(&[cond, &pace.broadcast_mul(&asked)?], 1)
}

/// The pace of sequences `x: [B, T, ≥ 58]` (normalised features): the mean
/// over the frames of each of [`PACE_FEATURES`], `[B, 4]`.
pub fn pace(x: &Tensor) -> Result<Tensor> {
    let columns = PACE_FEATURES
        .iter()
        .map(|&f| x.narrow(2, f, 1))
        .collect::<Result<Vec<_>>>()?;
    Tensor::cat(&columns, 2)?.mean(1)
}

/// The root's horizontal speed `√(vx² + vz² + offset)` in each frame of
/// `x: [B, T, ≥ 58]` (normalised features, `body`'s statistics), CMU units
/// a frame: `[B, T, 1]`. The positive `offset` keeps the gradient finite
/// at a standstill.
fn frame_speed(x: &Tensor, body: &feet::Stats, offset: f64) -> Result<Tensor> {
    let squared = |f: usize| feet::raw_col(x, f, body)?.sqr();
    ((squared(VEL_X)? + squared(VEL_Z)?)? + offset)?.sqrt()
}

impl Parts {
    /// Nothing beyond the paper.
    pub fn is_paper(&self) -> bool {
        *self == Parts::default()
    }

    /// Rounds of scheduled sampling ([`Parts::feed_rounds`]; 0: every
    /// depth, in one pass).
    pub fn rounds(&self) -> usize {
        self.feed_rounds.unwrap_or(1)
    }
}

/// Feature statistics and the mean skeleton, for the skeleton and feet parts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Body {
    /// Mean of each feature (`stats.json`).
    pub mean: Vec<f32>,
    /// Standard deviation of each feature (`stats.json`).
    pub std: Vec<f32>,
    /// Mean length of each bone over the training windows (CMU units).
    pub bones: Vec<f32>,
    /// Mean height of a toe in contact with the floor over the training
    /// windows (CMU units; where the foot lock puts a planted toe).
    #[serde(default)]
    pub contact_height: f32,
}

impl Body {
    /// What the foot lock needs of it.
    pub fn stats(&self) -> feet::Stats<'_> {
        feet::Stats {
            mean: &self.mean,
            std: &self.std,
            contact_height: self.contact_height,
        }
    }
}

/// The model `cargo xtask train` trains unless told otherwise.
pub const DEFAULT_MODEL: &str = "motion";

/// The models `cargo xtask train --model NAME` knows, with what each adds.
pub const MODELS: [(&str, &str); 6] = [
    ("paper", "the paper's VRNN"),
    ("smooth", "the paper's VRNN, with causal low-pass filters on the decoder's latent and output"),
    ("skeletal", "the paper's VRNN, each decoded bone rescaled to a fixed length by forward kinematics"),
    ("feet", "skeletal, with foot contacts predicted, the root moved by the planted feet, and a penalty on toes that slide in contact"),
    ("fed", "the paper's VRNN, trained on its own one-step predictions for half its frames (scheduled sampling)"),
    ("motion", "smooth, skeletal, feet and fed together, fed back in two rounds, sampled at temperature 0.7"),
];

/// A model name of [`MODELS`], or an error that lists them.
pub fn parse_name(name: &str) -> std::result::Result<String, String> {
    one_of(name, &MODELS.map(|m| m.0))
}

/// `name` if it is one of `known`, or an error that lists them (the
/// command-line parsers of model names).
pub fn one_of<S: AsRef<str>>(name: &str, known: &[S]) -> std::result::Result<String, String> {
    match known.iter().any(|m| m.as_ref() == name) {
        true => Ok(name.to_string()),
        false => Err(format!(
            "unknown model {name:?}; the models: {}",
            known
                .iter()
                .map(|m| m.as_ref())
                .collect::<Vec<_>>()
                .join(", ")
        )),
    }
}

/// The largest share of frames fed back in the models that do (`fed`,
/// `motion`).
pub const SELF_FEED: f64 = 0.5;

/// The sampling temperature of `motion` ([`Parts::temperature`]).
pub const MOTION_TEMPERATURE: f64 = 0.7;

/// Generated frames over which a motion leaves its real start frames
/// ([`MotionModel::sample`]): a third of a second at 30 fps. The decoder's
/// pose at the last start frame is off the real pose by its reconstruction
/// error, and the generated poses carry that offset (about twice a frame's
/// motion on the default model), so the first generated frame would jump.
/// The offset is added to the decoded poses and faded out over these frames
/// with a raised cosine, before the skeleton and the feet (bones stay rigid,
/// the root moves with the eased feet); nothing changes after the fade
/// (inertialization, as game animation blends one clip into the next).
pub const SEAM_FRAMES: usize = 10;

/// The name of the condition table's variable ([`Config::categories`]);
/// it starts at zero, so a conditioned model starts as the unconditioned
/// one with the same seed ([`crate::train::init_uniform`] leaves it).
pub const COND_WEIGHT: &str = "cond.weight";

/// The weight of the seam's offset `t` frames after the start frames.
fn seam_weight(t: usize) -> f64 {
    if t >= SEAM_FRAMES {
        return 0.0;
    }
    0.5 * (1.0 + (std::f64::consts::PI * t as f64 / SEAM_FRAMES as f64).cos())
}

impl Config {
    /// The model called `name` in [`MODELS`].
    pub fn named(name: &str) -> Option<Config> {
        let smooth = Parts {
            latent_filter: 0.9,
            output_filter: 0.8,
            ..Parts::default()
        };
        let skeletal = Parts {
            skeleton: true,
            ..Parts::default()
        };
        let parts = match name {
            "paper" => Parts::default(),
            "smooth" => smooth,
            "skeletal" => skeletal,
            "feet" => Parts {
                feet: 1.0,
                foot_lock: true,
                ..skeletal
            },
            "fed" => Parts {
                self_feed: SELF_FEED,
                ..Parts::default()
            },
            "motion" => Parts {
                skeleton: true,
                feet: 1.0,
                foot_lock: true,
                self_feed: SELF_FEED,
                feed_rounds: Some(2),
                temperature: Some(MOTION_TEMPERATURE),
                ..smooth
            },
            _ => return None,
        };
        Some(Config {
            parts,
            ..Config::default()
        })
    }

    /// Columns of the condition weights after the categories': the pace's
    /// ([`Parts::pace`]), or none.
    pub fn pace_columns(&self) -> usize {
        if self.parts.pace {
            PACE_FEATURES.len()
        } else {
            0
        }
    }

    /// The pace of sequences `x: [B, T, ≥ 58]` as this model reads it
    /// ([`pace`]), `[B, pace_columns]`.
    pub fn pace_of(&self, x: &Tensor) -> Result<Tensor> {
        pace(x)
    }

    /// `cond` with the pace of `x: [B, T, input]` ([`Parts::pace`]) as its
    /// last columns, weighed like the category (`1 −` the weight of row 0:
    /// zero where no category is asked, `guidance` where one is); `cond`
    /// as it is without the pace part or where it has its pace already
    /// (generation asks for a window's own, [`crate::generate`]). Without
    /// frames (`x` None or empty) the pace is 0, the training set's mean.
    pub fn paced(&self, cond: Option<&Tensor>, x: Option<&Tensor>) -> Result<Option<Tensor>> {
        let n = self.categories.len() + 1;
        let Some(cond) = cond.filter(|c| self.parts.pace && c.dim(1).is_ok_and(|w| w == n)) else {
            return Ok(cond.cloned());
        };
        let pace = match x {
            Some(x) if x.dim(1)? > 0 => self.pace_of(x)?,
            _ => Tensor::zeros(
                (cond.dim(0)?, self.pace_columns()),
                DType::F32,
                cond.device(),
            )?,
        };
        with_pace(cond, &pace).map(Some)
    }

    /// `cond` (paced, [`Config::paced`]) asking for the pace `want`
    /// (`[B, PACE_FEATURES]`) instead of its own, weighed as
    /// [`Config::paced`] weighs it (by the weight of the category asked):
    /// how a motion is held to its pace ([`crate::generate::PACE_GAIN`]).
    pub fn asking_pace(&self, cond: &Tensor, want: &Tensor) -> Result<Tensor> {
        let w = self.categories.len() + 1;
        if !self.parts.pace || cond.dim(1)? != w + self.pace_columns() {
            candle_core::bail!(
                "asking_pace: a paced condition of {} columns, got {:?}",
                w + self.pace_columns(),
                cond.shape()
            );
        }
        with_pace(&cond.narrow(1, 0, w)?, want)
    }

    /// Condition weights `[B, categories + 1]` for sequences asking for
    /// `asked` (rows of [`Config::categories`], counted from 1; None: no
    /// category) at guidance scale `guidance`: a sequence asking for row
    /// `k` weighs row `k` by `guidance` and row 0 by `1 − guidance`, so 1 is
    /// the plain conditional model, 0 the unconditional one, and above 1
    /// pushes away from the unconditional model (classifier-free guidance
    /// on the pre-activations the condition feeds). None for an
    /// unconditioned model.
    pub fn condition(
        &self,
        asked: &[Option<usize>],
        guidance: f64,
        device: &Device,
    ) -> Result<Option<Tensor>> {
        let n = self.categories.len() + 1;
        if n == 1 {
            return Ok(None);
        }
        let mut w = vec![0f32; asked.len() * n];
        for (row, a) in w.chunks_exact_mut(n).zip(asked) {
            match a {
                Some(k) if *k >= 1 && *k < n => {
                    row[0] = (1.0 - guidance) as f32;
                    row[*k] = guidance as f32;
                }
                Some(k) => candle_core::bail!("category row {k} is out of range (1..{n})"),
                None => row[0] = 1.0,
            }
        }
        Tensor::from_vec(w, (asked.len(), n), device).map(Some)
    }

    /// Condition weights for the windows `windows` of a split whose
    /// windows have the categories `categories` (`other` past its end, as
    /// for a dataset without categories), each asking for its own category
    /// at `guidance` ([`Config::condition`]), or for none where
    /// `dropped(k)` (`k`: the position in `windows`) or where the model has
    /// no row for it; None for an unconditioned model.
    pub fn window_condition(
        &self,
        categories: &[Category],
        windows: &[usize],
        guidance: f64,
        dropped: impl Fn(usize) -> bool,
        device: &Device,
    ) -> Result<Option<Tensor>> {
        if self.categories.is_empty() {
            return Ok(None);
        }
        let rows: Vec<Option<usize>> = windows
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let c = categories.get(i).copied().unwrap_or(Category::Other);
                self.row_of(c).filter(|_| !dropped(k))
            })
            .collect();
        self.condition(&rows, guidance, device)
    }

    /// The condition-table row of `category` (counted from 1), if the
    /// model has one.
    fn row_of(&self, category: Category) -> Option<usize> {
        self.categories
            .iter()
            .position(|c| c == category.name())
            .map(|k| k + 1)
    }

    /// The row of the condition table asked for by the category `name`
    /// (counted from 1, [`Config::condition`]), or an error that says what
    /// can be asked: an unknown name lists the known ones, a known one the
    /// model was not trained with lists the model's.
    pub fn category_row(&self, name: &str) -> std::result::Result<usize, String> {
        let category: Category = name.parse()?;
        if self.categories.is_empty() {
            return Err(format!(
                "this model was trained without categories, so it cannot be asked for {category}; train one with `cargo xtask train --condition category`"
            ));
        }
        self.row_of(category).ok_or_else(|| {
                format!(
                    "the model was not trained with {category} (its training set had no {category} windows); it knows: {}",
                    self.categories.join(", ")
                )
            })
    }

    /// The name in [`MODELS`] of this configuration, if it has one: the
    /// same parts, apart from those any model can be trained with: the
    /// pace as a condition ([`Parts::pace`]), how deep and at what
    /// temperature they are fed back ([`Parts::feed_rounds`],
    /// [`Parts::rollouts_at_temperature`]; the `minute` preset's) and the
    /// late epochs' ([`Parts::rollout_gradient`], [`Parts::fed_speed`],
    /// [`Parts::root_weight`]).
    pub fn name(&self) -> Option<&'static str> {
        let plain = |p: &Parts| Parts {
            pace: false,
            feed_rounds: None,
            rollouts_at_temperature: false,
            fed_speed: None,
            root_weight: None,
            rollout_gradient: false,
            ..p.clone()
        };
        MODELS
            .iter()
            .map(|m| m.0)
            .find(|n| Config::named(n).is_some_and(|c| plain(&c.parts) == plain(&self.parts)))
    }

    /// Fill what the model needs from the training data: for the skeleton
    /// and feet parts, the feature statistics and the mean bone lengths of `train`
    /// (normalised windows, `n × T × input`).
    pub fn fit_to(&mut self, mean: &[f64], std: &[f64], train: &[f32]) {
        if !self.parts.skeleton && self.parts.feet <= 0.0 && !self.parts.foot_lock {
            self.body = None;
            return;
        }
        let (mean, std): (Vec<f32>, Vec<f32>) = (
            mean.iter().map(|&v| v as f32).collect(),
            std.iter().map(|&v| v as f32).collect(),
        );
        let f = self.input;
        let rows = train.len() / f.max(1);
        let raw: Vec<f32> = train
            .iter()
            .enumerate()
            .map(|(i, v)| v * std[i % f] + mean[i % f])
            .collect();
        let (y, joints) = split_raw(&raw, f);
        let lengths = bone_lengths(&y, &joints);
        let mut bones = [0.0f64; BONES];
        for r in 0..rows {
            for (b, l) in bones.iter_mut().zip(&lengths[r * BONES..(r + 1) * BONES]) {
                *b += *l as f64;
            }
        }
        // Toe heights in contact (local y = height above the floor).
        let (mut sum, mut count) = (0.0f64, 0usize);
        for r in raw.chunks_exact(f) {
            for toe in TOES {
                let y = r[1 + 3 * (toe - 1) + 1] as f64;
                if y < CONTACT_UNITS {
                    sum += y;
                    count += 1;
                }
            }
        }
        self.body = Some(Body {
            mean,
            std,
            bones: bones
                .iter()
                .map(|b| (b / rows.max(1) as f64) as f32)
                .collect(),
            contact_height: (sum / count.max(1) as f64) as f32,
        });
    }
}

/// Root heights and the 54 joint coordinates of raw feature rows.
fn split_raw(raw: &[f32], f: usize) -> (Vec<f32>, Vec<f32>) {
    let y = raw.chunks_exact(f).map(|r| r[0]).collect();
    let joints = raw
        .chunks_exact(f)
        .flat_map(|r| r[1..1 + 3 * BONES].iter().copied())
        .collect();
    (y, joints)
}

/// Losses of a batch: summed over time, averaged over the batch (scalars).
#[derive(Clone, Debug)]
pub struct Losses {
    /// Squared reconstruction error.
    pub recon: Tensor,
    /// KL(posterior ‖ prior).
    pub kl: Tensor,
    /// Penalties of the parts beyond the paper, already weighted (zero for
    /// the paper's model); training minimises `recon + w·kl + extra`.
    pub extra: Tensor,
}

/// What training, sampling, evaluation and checkpoints ask of a model.
pub trait MotionModel: Send + Sync {
    /// The model's configuration (saved in checkpoints).
    fn config(&self) -> &Config;
    /// Losses of `x: [B, T, input]` with reparameterisation noise
    /// `eps: [T, B, latent]`. With `feed: [B, T]` (0 or 1), the frames
    /// marked 1 reach the recurrence as the model's own prediction
    /// (scheduled sampling); the encoder and the loss still see `x`.
    /// `cond: [B, categories + 1]` weighs the rows of the condition table
    /// per sequence ([`Config::condition`]; None: no category).
    fn losses(
        &self,
        x: &Tensor,
        eps: &Tensor,
        feed: Option<&Tensor>,
        cond: Option<&Tensor>,
    ) -> Result<Losses>;
    /// Reconstructions `[B, T, input]` of real windows: posterior mean,
    /// decoder mean, real frames fed to the recurrence.
    fn reconstruct(&self, x: &Tensor, cond: Option<&Tensor>) -> Result<Tensor>;
    /// `T` frames per sequence from the prior with noise `eps: [T, B, latent]`,
    /// each decoded frame fed back as the next input. `[B, T, input]`.
    /// With `start: [B, K, input]`, the first `K` frames are those real
    /// frames, read through the posterior (so the state and the latent
    /// filter start where real motion would put them); the prior takes over
    /// at frame `K`, leaving the last real frame without a jump
    /// ([`SEAM_FRAMES`]). Prior draws use the noise scaled by the model's
    /// [`Parts::temperature`].
    fn sample(&self, eps: &Tensor, start: Option<&Tensor>, cond: Option<&Tensor>)
        -> Result<Tensor>;
}

/// A dense layer's parameters.
#[derive(Clone, Debug)]
struct Lin {
    w: Tensor,
    b: Tensor,
}

impl Lin {
    fn new(inp: usize, out: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Lin {
            w: vb.get((out, inp), "weight")?,
            b: vb.get(out, "bias")?,
        })
    }

    fn forward(&self, x: &Tensor, act: Act) -> Result<Tensor> {
        linear(x, &self.w, &self.b, act)
    }
}

/// Mean and standard-deviation heads of a Gaussian, applied as one layer
/// (`[μ | logit σ]`).
fn stacked(mean: &Lin, std: &Lin) -> Result<Lin> {
    Ok(Lin {
        w: Tensor::cat(&[&mean.w, &std.w], 0)?,
        b: Tensor::cat(&[&mean.b, &std.b], 0)?,
    })
}

/// The model.
#[derive(Clone, Debug)]
pub struct Vrnn {
    config: Config,
    phi_x: [Lin; 2],
    prior: [Lin; 2],
    encoder: [Lin; 2],
    decoder: [Lin; 3],
    w_ih: Tensor,
    w_hh: Tensor,
    b_ih: Tensor,
    b_hh: Tensor,
    /// The condition table `[categories + 1, 2Z + 4H + 2Z + d1]`: row 0 is
    /// "no category", row `k` the `k`-th of [`Config::categories`]; each row
    /// is added to the pre-activations of the posterior and the LSTM gates,
    /// of the prior and of the decoder's first layer ([`Bias`]). None in an
    /// unconditioned model.
    cond: Option<Tensor>,
}

/// One sequence's row of the condition table, cut into what it is added to
/// (`[B or 1, ·]` each).
struct Bias {
    /// The recurrence's per-row input: posterior `2Z`, then gates `4H`.
    pre: Tensor,
    /// The prior's `[μ | logit σ]`.
    prior: Tensor,
    /// The decoder's first layer, before its ReLU.
    decoder: Tensor,
}

impl Bias {
    /// The same rows detached from the graph (for the feed rounds).
    fn detached(&self) -> Bias {
        Bias {
            pre: self.pre.detach(),
            prior: self.prior.detach(),
            decoder: self.decoder.detach(),
        }
    }

    /// The same rows for sequences `[B, T, ·]`.
    fn over_time(&self) -> Result<Bias> {
        Ok(Bias {
            pre: self.pre.unsqueeze(1)?,
            prior: self.prior.unsqueeze(1)?,
            decoder: self.decoder.unsqueeze(1)?,
        })
    }

    /// Rows made [`Bias::over_time`] back to one per sequence.
    fn per_sequence(&self) -> Result<Bias> {
        Ok(Bias {
            pre: self.pre.squeeze(1)?,
            prior: self.prior.squeeze(1)?,
            decoder: self.decoder.squeeze(1)?,
        })
    }
}

/// `x` plus the bias where there is one.
fn plus(x: Tensor, bias: Option<&Tensor>) -> Result<Tensor> {
    match bias {
        Some(b) => add_rows(&x, b, Act::None),
        None => Ok(x),
    }
}

/// What the recurrence gives per row.
struct Scan {
    /// LSTM state before the step `[B, T, H]`.
    h: Tensor,
    /// Posterior `[μ | σ]`, `[B, T, 2Z]`.
    q: Tensor,
    /// Posterior sample `[B, T, Z]`.
    z: Tensor,
}

impl Vrnn {
    /// Build the model; variables are created through `vb` (the names of
    /// PyTorch's `nn.Linear` and `nn.LSTM`).
    pub fn new(config: &Config, vb: VarBuilder) -> Result<Self> {
        let c = config;
        let [e1, e2] = c.extractor;
        let [d1, d2] = c.decoder;
        let needs_body = c.parts.skeleton || c.parts.feet > 0.0 || c.parts.foot_lock;
        if needs_body && (c.input != 1 + 3 * BONES + 3 || c.body.is_none()) {
            candle_core::bail!("the skeleton and feet parts need the 58 features and the training set's statistics (Config::fit_to)");
        }
        for (what, rho) in [
            ("latent_filter", c.parts.latent_filter),
            ("output_filter", c.parts.output_filter),
        ] {
            if !(0.0..1.0).contains(&rho) {
                candle_core::bail!("{what} must be in [0, 1), got {rho}");
            }
        }
        if !(0.0..=1.0).contains(&c.parts.self_feed) {
            candle_core::bail!("self_feed must be in [0, 1], got {}", c.parts.self_feed);
        }
        if c.parts.pace && (c.categories.is_empty() || PACE_FEATURES.iter().any(|&f| f >= c.input))
        {
            candle_core::bail!(
                "the pace part needs a model conditioned on the category and the 58 features"
            );
        }
        positive("kl_weight", c.parts.kl_weight)?;
        positive("temperature", c.parts.temperature)?;
        positive("fed speed weight", c.parts.fed_speed)?;
        positive("root weight", c.parts.root_weight)?;
        if c.parts.fed_speed.is_some() && c.body.is_none() {
            candle_core::bail!(
                "the fed speed loss needs the skeleton's statistics (a skeletal model)"
            );
        }
        if c.parts.rollout_gradient && c.parts.rounds() != 0 {
            candle_core::bail!(
                "the gradient through the rollout needs feeding back to every depth (feed_rounds 0, the minute preset's)"
            );
        }
        let gaussian = |input: usize, vb: VarBuilder| -> Result<[Lin; 2]> {
            Ok([
                Lin::new(input, c.latent, vb.pp("mean"))?,
                Lin::new(input, c.latent, vb.pp("std"))?,
            ])
        };
        let rnn = vb.pp("rnn");
        let (h4, lstm_in) = (4 * c.hidden, e2 + c.latent);
        Ok(Vrnn {
            config: c.clone(),
            phi_x: [
                Lin::new(c.input, e1, vb.pp("phi_x.0"))?,
                Lin::new(e1, e2, vb.pp("phi_x.1"))?,
            ],
            prior: gaussian(c.hidden, vb.pp("prior"))?,
            encoder: gaussian(e2 + c.hidden, vb.pp("encoder"))?,
            decoder: [
                Lin::new(c.latent + c.hidden, d1, vb.pp("decoder.0"))?,
                Lin::new(d1, d2, vb.pp("decoder.1"))?,
                Lin::new(d2, c.input + contacts(c), vb.pp("decoder.2"))?,
            ],
            w_ih: rnn.get((h4, lstm_in), "weight_ih_l0")?,
            w_hh: rnn.get((h4, c.hidden), "weight_hh_l0")?,
            b_ih: rnn.get(h4, "bias_ih_l0")?,
            b_hh: rnn.get(h4, "bias_hh_l0")?,
            cond: match c.categories.len() {
                0 => None,
                n => Some(vb.get_with_hints(
                    (n + 1 + c.pace_columns(), 4 * c.latent + h4 + d1),
                    COND_WEIGHT,
                    candle_nn::Init::Const(0.0),
                )?),
            },
        })
    }

    /// The condition's bias rows for `cond` ([`Config::condition`]; None: row
    /// 0, "no category"), with the pace of `frames` where the model reads
    /// one ([`Config::paced`]), or None for an unconditioned model.
    fn bias(&self, cond: Option<&Tensor>, frames: Option<&Tensor>) -> Result<Option<Bias>> {
        let c = &self.config;
        let cond = c.paced(cond, frames)?;
        let cond = cond.as_ref();
        let Some(table) = &self.cond else {
            if cond.is_some() {
                candle_core::bail!("this model was trained without categories; train one with --condition category");
            }
            return Ok(None);
        };
        let e = match cond {
            // The fused product: its backward sums over the rows in
            // blocks that do not depend on the CPU (`blocks::kernels::mm`),
            // where candle's `matmul` leaves that to the cache size.
            Some(w) => {
                let none = Tensor::zeros(table.dim(1)?, DType::F32, table.device())?;
                linear(w, &table.t()?, &none, Act::None)?
            }
            None => table.narrow(0, 0, 1)?,
        };
        let (pre, prior) = (2 * c.latent + 4 * c.hidden, 2 * c.latent);
        Ok(Some(Bias {
            pre: e.narrow(1, 0, pre)?,
            prior: e.narrow(1, pre, prior)?,
            decoder: e.narrow(1, pre + prior, c.decoder[0])?,
        }))
    }

    /// The same model with every weight detached from the graph: what runs
    /// through it keeps no graph and no buffers for a backward pass (the
    /// feed rounds, whose output no gradient flows through).
    fn detached(&self) -> Vrnn {
        let lin = |l: &Lin| Lin {
            w: l.w.detach(),
            b: l.b.detach(),
        };
        Vrnn {
            config: self.config.clone(),
            phi_x: self.phi_x.each_ref().map(lin),
            prior: self.prior.each_ref().map(lin),
            encoder: self.encoder.each_ref().map(lin),
            decoder: self.decoder.each_ref().map(lin),
            w_ih: self.w_ih.detach(),
            w_hh: self.w_hh.detach(),
            b_ih: self.b_ih.detach(),
            b_hh: self.b_hh.detach(),
            cond: self.cond.as_ref().map(Tensor::detach),
        }
    }

    fn dims(&self) -> ScanDims {
        ScanDims {
            hidden: self.config.hidden,
            latent: self.config.latent,
        }
    }

    fn features(&self, x: &Tensor) -> Result<Tensor> {
        let a = self.phi_x[0].forward(x, Act::Relu)?;
        self.phi_x[1].forward(&a, Act::Relu)
    }

    /// The recurrence over whole sequences with noise `eps: [B, T, Z]`,
    /// from the features `feat = features(x)` of `x: [B, T, input]`; the LSTM
    /// reads `fed` instead of `x` where given (scheduled sampling), the
    /// posterior always reads `x`.
    fn scan(
        &self,
        feat: &Tensor,
        fed: Option<&Tensor>,
        eps: &Tensor,
        bias: Option<&Bias>,
    ) -> Result<Scan> {
        let c = &self.config;
        let (e2, h, z) = (c.extractor[1], c.hidden, c.latent);
        // What does not depend on the recurrence, for all rows at once: the
        // x'' halves of the posterior and of the LSTM input product.
        let enc = stacked(&self.encoder[0], &self.encoder[1])?;
        let (enc_x, gates_x) = (
            Lin {
                w: enc.w.narrow(1, 0, e2)?,
                b: enc.b.clone(),
            },
            Lin {
                w: self.w_ih.narrow(1, 0, e2)?,
                b: (&self.b_ih + &self.b_hh)?,
            },
        );
        let pre = match fed {
            None => vec![Lin {
                w: Tensor::cat(&[&enc_x.w, &gates_x.w], 0)?,
                b: Tensor::cat(&[&enc_x.b, &gates_x.b], 0)?,
            }
            .forward(feat, Act::None)?],
            Some(f) => vec![
                enc_x.forward(feat, Act::None)?,
                gates_x.forward(&self.features(f)?, Act::None)?,
            ],
        };
        let w = Tensor::cat(
            &[
                enc.w.narrow(1, e2, h)?.flatten_all()?,
                self.w_ih.narrow(1, e2, z)?.flatten_all()?,
                self.w_hh.flatten_all()?,
            ],
            0,
        )?;
        let pre: Vec<&Tensor> = pre.iter().collect();
        let s = latent_lstm(&pre, bias.map(|b| &b.pre), eps, &w, self.dims())?;
        Ok(Scan {
            h: s.narrow(D::Minus1, 0, h)?,
            q: s.narrow(D::Minus1, h, 2 * z)?,
            z: s.narrow(D::Minus1, h + 2 * z, z)?,
        })
    }

    /// The decoder's layers over rows `[…, Z]` and `[…, H]` (before the
    /// output filter and the skeleton).
    fn decode_raw(&self, z: &Tensor, h: &Tensor, bias: Option<&Bias>) -> Result<Tensor> {
        let u = Tensor::cat(&[z, h], D::Minus1)?;
        let a = match bias {
            Some(b) => add_rows(
                &self.decoder[0].forward(&u, Act::None)?,
                &b.decoder,
                Act::Relu,
            )?,
            None => self.decoder[0].forward(&u, Act::Relu)?,
        };
        let b = self.decoder[1].forward(&a, Act::Relu)?;
        self.decoder[2].forward(&b, Act::None)
    }

    /// Decoder output (filtered) → features: through the skeleton when it
    /// is on, with bone lengths `lengths: […, 18]`.
    fn finish(&self, o: &Tensor, lengths: Option<&Tensor>) -> Result<Tensor> {
        let o = o.narrow(D::Minus1, 0, self.config.input)?;
        match (&self.config.body, lengths) {
            (Some(body), Some(l)) if self.config.parts.skeleton => self.place(&o, body, l),
            _ => Ok(o),
        }
    }

    /// The contact logits of decoder outputs (foot-lock part).
    fn contact_logits(&self, o: &Tensor) -> Result<Option<Tensor>> {
        match contacts(&self.config) {
            0 => Ok(None),
            n => o.narrow(D::Minus1, self.config.input, n).map(Some),
        }
    }

    /// Foot-locked root velocity over sequences: frames 1.. of `x_hat`
    /// (normalised `[B, T, input]`) get the velocity that keeps the feet of
    /// frame `t − 1` in place, weighted by the contact probabilities
    /// (`logits: [B, T, 2]`).
    fn lock_sequence(&self, x_hat: &Tensor, logits: &Tensor) -> Result<Tensor> {
        match &self.config.body {
            Some(body) => feet::foot_lock(x_hat, logits, &body.stats()),
            None => Ok(x_hat.clone()),
        }
    }

    /// The whole decoder over sequences `[B, T, ·]`: latent filter, layers,
    /// output filter, skeleton, foot lock. Returns the features and, with the
    /// foot lock, the contact logits.
    fn decode(
        &self,
        z: &Tensor,
        h: &Tensor,
        lengths: Option<&Tensor>,
        bias: Option<&Bias>,
    ) -> Result<(Tensor, Option<Tensor>)> {
        let o = self.decode_raw(&self.filtered(z)?, h, bias)?;
        let rho = self.config.parts.output_filter;
        let o = if rho > 0.0 {
            filter::smooth(&o, rho)?
        } else {
            o
        };
        let x_hat = self.finish(&o, lengths)?;
        match self.contact_logits(&o)? {
            Some(l) => Ok((self.lock_sequence(&x_hat, &l)?, Some(l))),
            None => Ok((x_hat, None)),
        }
    }

    /// Skeleton part: decoder outputs (the 58 normalised features, as in
    /// the paper) → each decoded bone (joint minus parent) rescaled to its
    /// length by forward kinematics → the 58 normalised features
    /// ([`blocks::skeleton::place`]).
    fn place(&self, o: &Tensor, body: &Body, lengths: &Tensor) -> Result<Tensor> {
        place(o, lengths, &body.mean, &body.std)
    }

    /// The decoder's latent: `z` through the causal filter when it is on.
    fn filtered(&self, z: &Tensor) -> Result<Tensor> {
        let rho = self.config.parts.latent_filter;
        if rho > 0.0 {
            filter::smooth(z, rho)
        } else {
            Ok(z.clone())
        }
    }

    /// Generate in runs of at most `frames` new frames ([`Parts::restart`];
    /// None or 0: one run).
    pub fn set_restart(&mut self, frames: Option<usize>) {
        self.config.parts.restart = frames.filter(|&f| f > 0);
    }

    /// Sample at temperature `t` ([`Parts::temperature`]; None: 1) instead
    /// of the one the model was trained with.
    pub fn set_temperature(&mut self, t: Option<f64>) -> Result<()> {
        positive("temperature", t)?;
        self.config.parts.temperature = t;
        Ok(())
    }

    /// Generate with the foot lock's contact logits times `k`
    /// ([`Parts::contact_sharpness`]; None: 1) instead of the model's own.
    pub fn set_contact_sharpness(&mut self, k: Option<f64>) -> Result<()> {
        positive("contact sharpness", k)?;
        self.config.parts.contact_sharpness = k;
        Ok(())
    }

    /// Each window's bone lengths (mean over its frames) for every row:
    /// `[B, T, 18]`, or `None` without the skeleton part.
    fn window_bones(&self, x: &Tensor) -> Result<Option<Tensor>> {
        let Some(body) = self
            .config
            .body
            .as_ref()
            .filter(|_| self.config.parts.skeleton)
        else {
            return Ok(None);
        };
        let (b, t, f) = x.dims3()?;
        let v = x.flatten_all()?.to_vec1::<f32>()?;
        let mut out = vec![0.0f32; b * t * BONES];
        let raw = |row: &[f32], k: usize| row[k] * body.std[k] + body.mean[k];
        let mut joints = [0.0f32; 3 * BONES];
        for (w, window) in v.chunks_exact(t * f).enumerate() {
            let mut mean = [0.0f64; BONES];
            for row in window.chunks_exact(f) {
                for (k, j) in joints.iter_mut().enumerate() {
                    *j = raw(row, 1 + k);
                }
                let lengths = row_bone_lengths(raw(row, 0), &joints);
                for (m, l) in mean.iter_mut().zip(&lengths) {
                    *m += *l as f64;
                }
            }
            for o in out[w * t * BONES..(w + 1) * t * BONES].chunks_exact_mut(BONES) {
                for (o, m) in o.iter_mut().zip(&mean) {
                    *o = (m / t as f64) as f32;
                }
            }
        }
        Tensor::from_vec(out, (b, t, BONES), x.device()).map(Some)
    }

    /// The prior's noise: `eps` at the sampling temperature where rollouts
    /// are drawn at it ([`Parts::rollouts_at_temperature`]), else as is.
    fn prior_noise(&self, eps: &Tensor) -> Result<Tensor> {
        match self.config.parts.temperature {
            Some(tau) if self.config.parts.rollouts_at_temperature => eps * tau,
            _ => Ok(eps.clone()),
        }
    }

    /// Each step's one-step prediction drawn from the prior `p` (given the
    /// recurrence's states `h`) with the noise `e`, and decoded, as sampling
    /// makes a frame; the first step is the noise alone (N(0, I)).
    fn prior_decoded(
        &self,
        p: &Tensor,
        h: &Tensor,
        e: &Tensor,
        lengths: Option<&Tensor>,
        bias: Option<&Bias>,
    ) -> Result<Tensor> {
        let t = e.dim(1)?;
        let z = draw(p, e, self.config.latent)?;
        let z = if t > 1 {
            Tensor::cat(&[&e.narrow(1, 0, 1)?, &z.narrow(1, 1, t - 1)?], 1)?
        } else {
            e.clone()
        };
        Ok(self.decode(&z, h, lengths, bias)?.0)
    }

    /// Scheduled sampling: `x` with the frames where `mask: [B, T]` is 1
    /// replaced by the model's own one-step prediction, as sampling makes
    /// it (latent drawn from the prior, `N(0, I)` at the first step, with
    /// the same noise; the whole decoder). The state comes from the real
    /// frames in the first round, and from the previous round's frames in
    /// each later one ([`Parts::feed_rounds`]; with 0, to every depth in one
    /// pass: [`Vrnn::fed_in_sequence`]). Training calls it on detached
    /// weights, so no gradient flows through the replacement, but with
    /// [`Parts::rollout_gradient`] on its own.
    fn fed_back(&self, i: &Feed) -> Result<Tensor> {
        if self.config.parts.rounds() == 0 {
            // A gradient through the rollout ([`Parts::rollout_gradient`])
            // takes the fused pass with its backward.
            return match (blocks::fused(i.x), self.config.parts.rollout_gradient) {
                (true, false) => self.fed_fused(i),
                (true, true) => self.fed_fused_grad(i),
                (false, _) => self.fed_in_sequence(i),
            };
        }
        let mut fed = self.feed_round(i, None)?.detach();
        for _ in 1..self.config.parts.rounds() {
            fed = self.feed_round(i, Some(&fed))?.detach();
        }
        Ok(fed)
    }

    /// One round of feeding back: the recurrence reads `fed` (the real
    /// frames when None), and each masked frame is replaced by the frame
    /// the prior's draw decodes to from the state before it.
    fn feed_round(&self, i: &Feed, fed: Option<&Tensor>) -> Result<Tensor> {
        let s = self.scan(i.feat, fed, i.eps, i.bias)?;
        let prior = stacked(&self.prior[0], &self.prior[1])?;
        let p = plus(prior.forward(&s.h, Act::None)?, i.bias.map(|b| &b.prior))?;
        let own = self.prior_decoded(&p, &s.h, i.e, i.lengths, i.bias)?;
        let m = i.mask.unsqueeze(D::Minus1)?.broadcast_as(i.x.shape())?;
        i.x + ((own - i.x)? * &m)?
    }

    /// [`Vrnn::fed_back`] to every depth (`feed_rounds` 0): one pass in
    /// time order, each fed frame predicted from a state that read every
    /// earlier fed frame, as sampling would make it. It gives what rounds
    /// give once there are as many rounds as fed frames in a window, at the
    /// cost of one. `eps`: the posterior's noise, `e`: the prior's.
    fn fed_in_sequence(&self, i: &Feed) -> Result<Tensor> {
        let (c, x, lengths) = (&self.config, i.x, i.lengths);
        let t = x.dim(1)?;
        // Everything time-major, so a step's rows are one contiguous slice.
        let steps = |v: &Tensor| v.transpose(0, 1)?.contiguous();
        let (xs, fs, eq, ep) = (steps(x)?, steps(i.feat)?, steps(i.eps)?, steps(i.e)?);
        let ms = steps(&i.mask.unsqueeze(D::Minus1)?)?;
        let ls = lengths.map(steps).transpose()?;
        // The condition's rows, one per sequence.
        let bias = i.bias.map(Bias::per_sequence).transpose()?;
        let st = Steps::new(self, bias.as_ref())?;
        let (rho, rho_out) = (c.parts.latent_filter, c.parts.output_filter);
        let mut h = Tensor::zeros((x.dim(0)?, c.hidden), DType::F32, x.device())?;
        let mut cell = h.clone();
        let (mut zf, mut of, mut prev): (Option<Tensor>, Option<Tensor>, Option<Tensor>) =
            (None, None, None);
        let mut fed = Vec::with_capacity(t);
        for step in 0..t {
            let (xt, ft) = (xs.get(step)?, fs.get(step)?);
            // The posterior reads the real frame; its z goes to the LSTM.
            let zq = draw(&st.posterior(&ft, &h)?, &eq.get(step)?, c.latent)?;
            // The prior's draw makes the own frame (its noise alone at first).
            let zp = st.prior_draw(&h, ep.get(step)?, step == 0)?;
            let zd = step_filter(&zf, zp, rho)?;
            let o = step_filter(&of, self.decode_raw(&zd, &h, st.bias)?, rho_out)?;
            let l = ls.as_ref().map(|l| l.get(step)).transpose()?;
            let mut own = self.finish(&o, l.as_ref())?;
            if let Some(logits) = self.contact_logits(&o)? {
                own = self.lock_step(prev.as_ref(), &own, &logits)?;
            }
            let xf = (&xt + (&own - &xt)?.broadcast_mul(&ms.get(step)?)?)?;
            (h, cell) = st.advance(&self.features(&xf)?, &zq, &h, &cell)?;
            (zf, of, prev) = (Some(zd), Some(o), Some(own));
            fed.push(xf);
        }
        Tensor::stack(&fed, 1)
    }

    /// One frame `x: [B, input]` through the foot lock, given its contact
    /// logits: grounded, then locked against the frame before it where
    /// there is one (`prev`). As it is without a body.
    fn lock_step(&self, prev: Option<&Tensor>, x: &Tensor, logits: &Tensor) -> Result<Tensor> {
        let Some(body) = &self.config.body else {
            return Ok(x.clone());
        };
        let one = |t: &Tensor| t.unsqueeze(1);
        let g = ground(&one(x)?, &one(logits)?, &body.stats())?;
        match prev {
            Some(p) => lock(&one(p)?, &g, &one(logits)?, &body.stats())?,
            None => g,
        }
        .squeeze(1)
    }

    /// The model's weights as [`rollout::fed`] reads them.
    fn rollout_net(&self, lengths: Option<&Tensor>) -> Result<rollout::Net> {
        let c = &self.config;
        let v = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        let dense = |l: &Lin| -> Result<rollout::Dense> {
            let (out, inp) = l.w.dims2()?;
            Ok(rollout::Dense {
                w: v(&l.w)?,
                b: v(&l.b)?,
                inp,
                out,
            })
        };
        let body = c.body.as_ref();
        Ok(rollout::Net {
            hidden: c.hidden,
            latent: c.latent,
            input: c.input,
            phi: [dense(&self.phi_x[0])?, dense(&self.phi_x[1])?],
            encoder: dense(&stacked(&self.encoder[0], &self.encoder[1])?)?,
            prior: dense(&stacked(&self.prior[0], &self.prior[1])?)?,
            decoder: [
                dense(&self.decoder[0])?,
                dense(&self.decoder[1])?,
                dense(&self.decoder[2])?,
            ],
            w_ih: v(&self.w_ih)?,
            w_hh: v(&self.w_hh)?,
            b_gates: v(&(&self.b_ih + &self.b_hh)?)?,
            rho: c.parts.latent_filter as f32,
            rho_out: c.parts.output_filter as f32,
            lock: body
                .filter(|_| contacts(c) > 0)
                .map(|b| FootLockOp::new(&b.stats())),
            place: body
                .filter(|_| c.parts.skeleton && lengths.is_some())
                .map(|b| PlaceOp {
                    mean: b.mean.clone(),
                    std: b.std.clone(),
                }),
        })
    }

    /// The fused pass's inputs ([`rollout::RolloutOp`]) and the
    /// condition's rows packed as it reads them.
    fn rollout_op(&self, i: &Feed) -> Result<(rollout::RolloutOp, Tensor)> {
        let (b, t, _) = i.x.dims3()?;
        let v = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        let (cond, widths) = match i.bias {
            Some(bias) => {
                let parts = [&bias.pre, &bias.prior, &bias.decoder];
                let widths = parts.map(|p| p.dim(D::Minus1).unwrap_or(0));
                (Tensor::cat(&parts, D::Minus1)?, Some(widths))
            }
            None => (Tensor::zeros(1, DType::F32, i.x.device())?, None),
        };
        let op = rollout::RolloutOp {
            net: self.rollout_net(i.lengths)?,
            b,
            t,
            x: v(i.x)?,
            eps: v(i.eps)?,
            e: v(i.e)?,
            mask: v(i.mask)?,
            lengths: i.lengths.map(v).transpose()?,
            cond: widths,
            tape: std::sync::Mutex::new(None),
        };
        Ok((op, cond.contiguous()?))
    }

    /// [`Vrnn::fed_in_sequence`] as one fused block ([`rollout::fed`]).
    fn fed_fused(&self, i: &Feed) -> Result<Tensor> {
        let v = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        let (op, cond) = self.rollout_op(i)?;
        let out = op.fed(&v(i.feat)?, &v(&cond)?);
        Tensor::from_vec(out, i.x.shape(), i.x.device())
    }

    /// [`Vrnn::fed_fused`] with the gradient through the fed frames
    /// ([`rollout::RolloutOp`]): of the real frames' features, every weight
    /// and the condition's rows.
    fn fed_fused_grad(&self, i: &Feed) -> Result<Tensor> {
        let flat = |l: &Lin| -> Result<[Tensor; 2]> { Ok([l.w.flatten_all()?, l.b.clone()]) };
        let mut w = Vec::new();
        for l in [
            &self.phi_x[0],
            &self.phi_x[1],
            &stacked(&self.encoder[0], &self.encoder[1])?,
            &stacked(&self.prior[0], &self.prior[1])?,
            &self.decoder[0],
            &self.decoder[1],
            &self.decoder[2],
        ] {
            w.extend(flat(l)?);
        }
        w.extend([
            self.w_ih.flatten_all()?,
            self.w_hh.flatten_all()?,
            (&self.b_ih + &self.b_hh)?,
        ]);
        let w = Tensor::cat(&w, 0)?;
        let (op, cond) = self.rollout_op(i)?;
        i.feat.contiguous()?.apply_op3(&w, &cond, op)
    }

    /// `x − o` over the pose features of a real frame `x: [B, input]` and
    /// the decoder's output `o: [B, ≥ input]` for it (zero on the root
    /// motion, the last three features, and on what `o` has beyond them).
    fn pose_offset(&self, x: &Tensor, o: &Tensor) -> Result<Tensor> {
        let (b, width) = o.dims2()?;
        let pose = self.config.input.saturating_sub(3);
        let d = (x.narrow(1, 0, pose)? - o.narrow(1, 0, pose)?)?;
        let rest = Tensor::zeros((b, width - pose), DType::F32, o.device())?;
        Tensor::cat(&[&d, &rest], 1)
    }

    /// The mean skeleton for `b` sequences (sampling): `[b, 18]`.
    fn mean_bones(&self, b: usize, device: &Device) -> Result<Option<Tensor>> {
        match self
            .config
            .body
            .as_ref()
            .filter(|_| self.config.parts.skeleton)
        {
            Some(body) => Tensor::new(body.bones.as_slice(), device)?
                .unsqueeze(0)?
                .broadcast_as((b, BONES))?
                .contiguous()
                .map(Some),
            None => Ok(None),
        }
    }
}

impl MotionModel for Vrnn {
    fn config(&self) -> &Config {
        &self.config
    }

    fn losses(
        &self,
        x: &Tensor,
        eps: &Tensor,
        feed: Option<&Tensor>,
        cond: Option<&Tensor>,
    ) -> Result<Losses> {
        let b = x.dim(0)? as f64;
        let eps = eps.transpose(0, 1)?.contiguous()?;
        let lengths = self.window_bones(x)?;
        let feat = self.features(x)?;
        let bias = self
            .bias(cond, Some(x))?
            .map(|b| b.over_time())
            .transpose()?;
        let bias = bias.as_ref();
        let fed = match feed {
            Some(mask) => {
                // The prior's draws at the sampling temperature where asked;
                // the posterior's noise as is.
                let e = self.prior_noise(&eps)?;
                let i = Feed {
                    x,
                    feat: &feat,
                    eps: &eps,
                    e: &e,
                    mask,
                    lengths: lengths.as_ref(),
                    bias,
                };
                if self.config.parts.rollout_gradient {
                    Some(self.fed_back(&i)?)
                } else {
                    let (b, detached) = (bias.map(Bias::detached), feat.detach());
                    Some(self.detached().fed_back(&Feed {
                        feat: &detached,
                        bias: b.as_ref(),
                        ..i
                    })?)
                }
            }
            None => None,
        };
        let s = self.scan(&feat, fed.as_ref(), &eps, bias)?;
        let p = stacked(&self.prior[0], &self.prior[1])?.forward(&s.h, Act::None)?;
        let p = plus(p, bias.map(|b| &b.prior))?;
        let kl = gaussian_kl(&s.q, &p)?;
        let (x_hat, logits) = self.decode(&s.z, &s.h, lengths.as_ref(), bias)?;
        let recon = squared_error(&x_hat, x)?;
        let mut extra = Tensor::zeros((), DType::F32, x.device())?;
        if let (Some(body), w) = (&self.config.body, self.config.parts.feet) {
            if w > 0.0 {
                extra = (extra + (feet::foot_slide(&x_hat, x, &body.stats())? * (w / b))?)?;
            }
        }
        if let (Some(body), Some(l)) = (&self.config.body, &logits) {
            extra = (extra + (feet::contact_loss(l, x, &body.stats())? / b)?)?;
        }
        if let Some(w) = self.config.parts.root_weight {
            let root = |t: &Tensor| t.narrow(2, ROOT_FEATURES.start, ROOT_FEATURES.len());
            extra = (extra + (squared_error(&root(&x_hat)?, &root(x)?)? * ((w - 1.0) / b))?)?;
        }
        if let (Some(w), Some(fed), Some(mask), Some(body)) =
            (self.config.parts.fed_speed, &fed, feed, &self.config.body)
        {
            extra = (extra + (fed_speed_loss(fed, x, mask, &body.stats())? * (w / b))?)?;
        }
        Ok(Losses {
            recon: (recon / b)?,
            kl: (kl / b)?,
            extra,
        })
    }

    fn reconstruct(&self, x: &Tensor, cond: Option<&Tensor>) -> Result<Tensor> {
        let (b, t, _) = x.dims3()?;
        let zero = Tensor::zeros((b, t, self.config.latent), DType::F32, x.device())?;
        let bias = self
            .bias(cond, Some(x))?
            .map(|b| b.over_time())
            .transpose()?;
        // With ε = 0 the posterior sample is its mean.
        let s = self.scan(&self.features(x)?, None, &zero, bias.as_ref())?;
        let lengths = self.window_bones(x)?;
        Ok(self.decode(&s.z, &s.h, lengths.as_ref(), bias.as_ref())?.0)
    }

    fn sample(
        &self,
        eps: &Tensor,
        start: Option<&Tensor>,
        cond: Option<&Tensor>,
    ) -> Result<Tensor> {
        let c = &self.config;
        let (t, b, _) = eps.dims3()?;
        let dev = eps.device();
        let bias = self.bias(cond, start)?;
        let st = Steps::new(self, bias.as_ref())?;
        let k = start.map_or(Ok(0), |s| s.dim(1))?;
        // Bone lengths: the start frames' own skeleton, else the training
        // set's mean skeleton.
        let bones = match start {
            Some(s) if k > 0 => self
                .window_bones(s)?
                .map(|l| l.narrow(1, 0, 1)?.squeeze(1))
                .transpose()?,
            _ => self.mean_bones(b, dev)?,
        };
        let (rho, rho_out) = (c.parts.latent_filter, c.parts.output_filter);
        let mut h = Tensor::zeros((b, c.hidden), DType::F32, dev)?;
        let mut cell = h.clone();
        let (mut zf, mut of): (Option<Tensor>, Option<Tensor>) = (None, None);
        let mut frames = Vec::with_capacity(t);
        // The last start frame's pose minus the decoder's ([`SEAM_FRAMES`]).
        let mut seam: Option<Tensor> = None;
        for step in 0..t {
            let e = eps.get(step)?;
            // A real start frame is read through the posterior; later frames
            // draw z from the prior (N(0, I) at the first step).
            let (real, z) = match start.filter(|_| step < k) {
                Some(s) => {
                    let x = s.narrow(1, step, 1)?.squeeze(1)?;
                    let feat = self.features(&x)?;
                    let z = draw(&st.posterior(&feat, &h)?, &e, c.latent)?;
                    (Some((x, feat)), z)
                }
                None => {
                    let e = match c.parts.temperature {
                        Some(tau) => (e * tau)?,
                        None => e,
                    };
                    (None, st.prior_draw(&h, e, step == 0)?)
                }
            };
            let zd = step_filter(&zf, z.clone(), rho)?;
            // The decoder runs on start frames too, so its output filter has
            // the history it has in training.
            let o = step_filter(&of, self.decode_raw(&zd, &h, st.bias)?, rho_out)?;
            let (x, feat) = match real {
                Some(r) => {
                    if step + 1 == k {
                        seam = Some(self.pose_offset(&r.0, &o)?);
                    }
                    r
                }
                None => {
                    let eased = match &seam {
                        Some(d) if step - k < SEAM_FRAMES => (&o + (d * seam_weight(step - k))?)?,
                        _ => o.clone(),
                    };
                    let mut x = self.finish(&eased, bones.as_ref())?;
                    if let (Some(prev), Some(l)) = (frames.last(), self.contact_logits(&o)?) {
                        let l = match c.parts.contact_sharpness {
                            Some(k) => (l * k)?,
                            None => l,
                        };
                        x = self.lock_step(Some(prev), &x, &l)?;
                    }
                    let feat = self.features(&x)?;
                    (x, feat)
                }
            };
            zf = Some(zd);
            of = Some(o);
            (h, cell) = st.advance(&feat, &z, &h, &cell)?;
            frames.push(x);
        }
        Tensor::stack(&frames, 1)
    }
}

/// What feeding back to every depth reads ([`Vrnn::fed_in_sequence`]): the
/// real frames `[B, T, input]`, their features, the posterior's noise and
/// the prior's (`[B, T, Z]`), the mask `[B, T]`, the bone lengths and the
/// condition's rows (over time).
struct Feed<'a> {
    x: &'a Tensor,
    feat: &'a Tensor,
    eps: &'a Tensor,
    e: &'a Tensor,
    mask: &'a Tensor,
    lengths: Option<&'a Tensor>,
    bias: Option<&'a Bias>,
}

/// One step of the recurrence at a time, for the step loops (sampling,
/// feeding back to every depth): the weights as each step reads them.
struct Steps<'a> {
    /// The condition's rows (`[B or 1, ·]`).
    bias: Option<&'a Bias>,
    /// The condition's share of the posterior and of the gates.
    enc_bias: Option<Tensor>,
    gates_bias: Option<Tensor>,
    prior: Lin,
    encoder: Lin,
    gates_in: Lin,
    w_hh: Tensor,
    no_bias: Tensor,
    latent: usize,
}

impl<'a> Steps<'a> {
    fn new(m: &Vrnn, bias: Option<&'a Bias>) -> Result<Steps<'a>> {
        let (z, h) = (m.config.latent, m.config.hidden);
        let (enc_bias, gates_bias) = match bias {
            Some(b) => (
                Some(b.pre.narrow(1, 0, 2 * z)?),
                Some(b.pre.narrow(1, 2 * z, 4 * h)?),
            ),
            None => (None, None),
        };
        Ok(Steps {
            bias,
            enc_bias,
            gates_bias,
            prior: stacked(&m.prior[0], &m.prior[1])?,
            encoder: stacked(&m.encoder[0], &m.encoder[1])?,
            gates_in: Lin {
                w: m.w_ih.clone(),
                b: (&m.b_ih + &m.b_hh)?,
            },
            w_hh: m.w_hh.clone(),
            no_bias: m.b_hh.zeros_like()?,
            latent: z,
        })
    }

    /// The posterior's `[μ | logit σ]` from features `feat` and state `h`.
    fn posterior(&self, feat: &Tensor, h: &Tensor) -> Result<Tensor> {
        let q = self
            .encoder
            .forward(&Tensor::cat(&[feat, h], 1)?, Act::None)?;
        plus(q, self.enc_bias.as_ref())
    }

    /// The prior's draw from state `h` with noise `e` (`e` itself at the
    /// first step: `N(0, I)`).
    fn prior_draw(&self, h: &Tensor, e: Tensor, first: bool) -> Result<Tensor> {
        if first {
            return Ok(e);
        }
        let p = plus(
            self.prior.forward(h, Act::None)?,
            self.bias.map(|b| &b.prior),
        )?;
        draw(&p, &e, self.latent)
    }

    /// The LSTM's state `(h, c)` after reading `[feat, z]` from `(h, cell)`.
    fn advance(
        &self,
        feat: &Tensor,
        z: &Tensor,
        h: &Tensor,
        cell: &Tensor,
    ) -> Result<(Tensor, Tensor)> {
        let gates = (self
            .gates_in
            .forward(&Tensor::cat(&[feat, z], 1)?, Act::None)?
            + linear(h, &self.w_hh, &self.no_bias, Act::None)?)?;
        lstm_cell(&plus(gates, self.gates_bias.as_ref())?, cell)
    }
}

/// One step of a causal filter with pole `rho` (the first value as is).
fn step_filter(prev: &Option<Tensor>, x: Tensor, rho: f64) -> Result<Tensor> {
    match prev {
        Some(p) if rho > 0.0 => filter::step(p, &x, rho),
        _ => Ok(x),
    }
}

/// An error unless the optional setting `what` is positive and finite.
fn positive(what: &str, v: Option<f64>) -> Result<()> {
    match v {
        Some(w) if !(w.is_finite() && w > 0.0) => {
            candle_core::bail!("{what} must be positive, got {w}")
        }
        _ => Ok(()),
    }
}

/// Added to a window's mean speed before [`fed_speed_loss`] takes its
/// logarithm (CMU units a frame; about 0.008 m/s): standing windows are
/// compared without the logarithm of nothing.
pub const FED_SPEED_FLOOR: f64 = 0.005;

/// The fed speed loss of the frames the recurrence read, `fed: [B, T, F]`
/// (real frames where `mask: [B, T]` is 1 replaced by the model's own),
/// against the real `x` (normalised features, `body`'s statistics): per
/// window, the mean over its fed frames of the root's horizontal speed
/// `√(vx² + vz²)` (CMU units a frame), and the real frames' mean at the
/// same frames; the squared difference of their logarithms (each plus
/// [`FED_SPEED_FLOOR`]), so a standing window a third too fast counts as
/// much as a running one, summed and scaled by `T` (so it weighs like a
/// per-frame error). Zero for a window with no fed frame.
pub fn fed_speed_loss(
    fed: &Tensor,
    x: &Tensor,
    mask: &Tensor,
    body: &feet::Stats,
) -> Result<Tensor> {
    let t = fed.dim(1)?;
    let m = mask.unsqueeze(2)?;
    let count = (m.sum_keepdim(1)? + 1e-6)?;
    let speed = |a: &Tensor| -> Result<Tensor> {
        frame_speed(a, body, 1e-8)?
            .broadcast_mul(&m)?
            .sum_keepdim(1)?
            .broadcast_div(&count)
    };
    let log = |a: &Tensor| (speed(a)? + FED_SPEED_FLOOR)?.log();
    (log(fed)? - log(x)?)?.sqr()?.sum_all()? * t as f64
}

/// A draw from a Gaussian head's `[μ | logit σ]` (last dimension `2Z`)
/// with noise `e`.
fn draw(p: &Tensor, e: &Tensor, latent: usize) -> Result<Tensor> {
    let mu = p.narrow(D::Minus1, 0, latent)?;
    let sigma =
        candle_nn::ops::sigmoid(&p.narrow(D::Minus1, latent, latent)?)?.clamp(SIGMA_MIN, 1.0)?;
    mu + (sigma * e)?
}

pub use crate::blocks::feet::CONTACT_UNITS;

/// Extra decoder outputs: one contact logit per toe with the foot lock.
fn contacts(c: &Config) -> usize {
    if c.parts.foot_lock {
        TOES.len()
    } else {
        0
    }
}

/// `KL(N(μ, σ) ‖ N(0, 1))` summed over the last dimension.
pub use blocks::kl::{kl_gaussians, kl_standard};

/// The device to train on: CUDA when built with `cuda` and one is present.
pub fn default_device() -> Device {
    Device::cuda_if_available(0).unwrap_or(Device::Cpu)
}

/// A device as a user names it: `the CPU`, `CUDA GPU 0`.
pub fn device_name(d: &Device) -> String {
    match d.location() {
        candle_core::DeviceLocation::Cpu => "the CPU".into(),
        candle_core::DeviceLocation::Cuda { gpu_id } => format!("CUDA GPU {gpu_id}"),
        candle_core::DeviceLocation::Metal { gpu_id } => format!("Metal GPU {gpu_id}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mocap_ingest::skeleton::JOINT_PARENTS;

    /// Four frames, 1 and 3 fed: the fed frames' speeds 5 (3, 4) and 0,
    /// the real ones 0, so the means are about 2.5 and 0 and the loss about
    /// ln(2.505 / 0.0051)² · 4 = 153.6 (with velocity stds of 2 and 0.5 as
    /// well: the same raw speeds). Frame 0 is fast but not fed: it does not
    /// count.
    #[test]
    fn the_fed_speed_loss_compares_the_fed_frames_mean_speed() {
        use mocap_ingest::features::{VEL_X, VEL_Z};
        let dev = &Device::Cpu;
        let mut v = vec![0.0f32; 4 * 58];
        (v[VEL_X], v[58 + VEL_X], v[58 + VEL_Z]) = (10.0, 3.0, 4.0);
        let fast = Tensor::from_vec(v, (1, 4, 58), dev).unwrap();
        let mask = Tensor::from_vec(vec![0.0f32, 1.0, 0.0, 1.0], (1, 4), dev).unwrap();
        let still = Tensor::zeros((1, 4, 58), DType::F32, dev).unwrap();
        let value = |body: &Body, fed: &Tensor| {
            fed_speed_loss(fed, &still, &mask, &body.stats())
                .unwrap()
                .to_scalar::<f32>()
                .unwrap() as f64
        };
        // A standstill's speed is the offset's root, 1e-4.
        let mean = |sum: f64| sum / (2.0 + 1e-6) + FED_SPEED_FLOOR;
        let expected = (mean(5.0 + 1e-4) / mean(2e-4)).ln().powi(2) * 4.0;
        assert!((expected - 153.6).abs() < 0.1);
        let body = identity_body();
        assert!((value(&body, &fast) - expected).abs() < 1e-5 * expected);
        // Velocity stds 2 and 0.5: the same raw speeds, the same loss.
        let mut scaled = identity_body();
        (scaled.std[VEL_X], scaled.std[VEL_Z]) = (2.0, 0.5);
        let mut v = vec![0.0f32; 4 * 58];
        (v[VEL_X], v[58 + VEL_X], v[58 + VEL_Z]) = (5.0, 1.5, 8.0);
        let fed = Tensor::from_vec(v, (1, 4, 58), dev).unwrap();
        assert!((value(&scaled, &fed) - expected).abs() < 1e-5 * expected);
        // No fed frame: nothing to compare.
        let none = Tensor::zeros((1, 4), DType::F32, dev).unwrap();
        let loss = fed_speed_loss(&fast, &still, &none, &body.stats()).unwrap();
        assert_eq!(loss.to_scalar::<f32>().unwrap(), 0.0);
    }

    /// Statistics that leave values as they are (mean 0, std 1).
    fn identity_body() -> Body {
        Body {
            mean: vec![0.0; 58],
            std: vec![1.0; 58],
            bones: vec![1.0; BONES],
            contact_height: 0.5,
        }
    }

    fn row(v: &[f32]) -> Tensor {
        Tensor::from_vec(v.to_vec(), (1, 1, 58), &Device::Cpu).unwrap()
    }

    #[test]
    fn a_planted_foot_gives_the_root_velocity_that_keeps_it_in_place() {
        let body = identity_body();
        // Root moves by v = (0.5, 0.3) and turns by θ = 0.2; both toes stay
        // where they were in the world: p_t = R(θ)⁻¹ (p_{t−1} − v).
        let (v, th) = ([0.5f32, 0.3], 0.2f32);
        let (s, c) = th.sin_cos();
        let (mut prev, mut cur) = ([0f32; 58], [0f32; 58]);
        for (toe, p) in [(4usize, [1.0f32, 2.0]), (8, [-1.0, 1.5])] {
            let k = 1 + 3 * (toe - 1);
            prev[k] = p[0];
            prev[k + 2] = p[1];
            let (dx, dz) = (p[0] - v[0], p[1] - v[1]);
            // R(θ)·(x, z) = (c x + s z, −s x + c z); its inverse is R(−θ).
            cur[k] = c * dx - s * dz;
            cur[k + 2] = s * dx + c * dz;
        }
        cur[57] = th;
        cur[55] = 9.0; // the decoded velocity, overruled by the planted feet
        cur[56] = -9.0;
        let logits = Tensor::new(&[[[30f32, 30.0]]], &Device::Cpu).unwrap();
        let out = lock(&row(&prev), &row(&cur), &logits, &body.stats())
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        assert!(
            (out[55] - v[0]).abs() < 1e-5 && (out[56] - v[1]).abs() < 1e-5,
            "{:?}",
            &out[55..]
        );
        // Feet in the air: the decoded velocity stays.
        let up = Tensor::new(&[[[-30f32, -30.0]]], &Device::Cpu).unwrap();
        let out = lock(&row(&prev), &row(&cur), &up, &body.stats())
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        assert!((out[55] - 9.0).abs() < 1e-4 && (out[56] + 9.0).abs() < 1e-4);
    }

    /// A pose of 19 joints (root height 9, joints spread out), as features.
    fn pose() -> Vec<f32> {
        let mut x = vec![0f32; 58];
        x[0] = 9.0;
        for j in 1..=BONES {
            let k = 1 + 3 * (j - 1);
            let f = j as f32;
            x[k] = (0.7 * f).sin() * 3.0;
            x[k + 1] = 9.0 - 0.4 * f;
            x[k + 2] = (0.3 * f).cos() * 2.0;
        }
        x
    }

    #[test]
    fn placing_scales_each_bone_from_its_parent_in_raw_units() {
        // Statistics that are not the identity: raw = 2·n + 1.
        let (mean, std) = (vec![1.0f32; 58], vec![2.0f32; 58]);
        let raw = pose();
        let n: Vec<f32> = raw.iter().map(|v| (v - 1.0) / 2.0).collect();
        let at = |v: &[f32], j: usize, k: usize| match j {
            0 if k == 1 => v[0],
            0 => 0.0,
            _ => v[1 + 3 * (j - 1) + k],
        };
        let bone =
            |v: &[f32], j: usize, k: usize| at(v, j, k) - at(v, JOINT_PARENTS[j].unwrap_or(0), k);
        // Twice each bone's length: each bone doubles along its direction.
        let lengths: Vec<f32> = bone_lengths(&raw[..1], &raw[1..55])
            .iter()
            .map(|l| 2.0 * l)
            .collect();
        let l = Tensor::from_vec(lengths, (1, 1, BONES), &Device::Cpu).unwrap();
        for reference in [false, true] {
            let run = || place(&row(&n), &l, &mean, &std);
            let out = if reference {
                blocks::reference(run)
            } else {
                run()
            };
            let out: Vec<f32> = out
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap()
                .iter()
                .map(|v| 2.0 * v + 1.0)
                .collect();
            for j in 1..=BONES {
                for k in 0..3 {
                    let (got, want) = (bone(&out, j, k), 2.0 * bone(&raw, j, k));
                    assert!(
                        (got - want).abs() < 1e-4,
                        "reference {reference}, bone {j} axis {k}: {got} vs {want}"
                    );
                }
            }
            // Root height, velocity and turn pass through.
            for k in [0, 55, 56, 57] {
                assert!((out[k] - raw[k]).abs() < 1e-5, "feature {k}");
            }
        }
    }

    #[test]
    fn the_skeleton_leaves_a_pose_with_the_right_bones_unchanged() {
        let mut c = Config::named("skeletal").unwrap();
        c.body = Some(identity_body());
        let m = crate::train::init_model(&c, 1, &Device::Cpu).unwrap().model;
        let x = pose();
        let lengths = bone_lengths(&x[..1], &x[1..55]);
        let l = Tensor::from_vec(lengths.clone(), (1, 1, BONES), &Device::Cpu).unwrap();
        let out = m.place(&row(&x), &identity_body(), &l).unwrap();
        let out = out.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        for (k, (a, b)) in out.iter().zip(&x).enumerate() {
            assert!((a - b).abs() < 1e-4, "feature {k}: {a} vs {b}");
        }
        // Longer bones: each joint moves away from its parent along the
        // same direction, so the bone's direction is kept.
        let l2 = (l * 2.0).unwrap();
        let out = m.place(&row(&x), &identity_body(), &l2).unwrap();
        let out = out.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let got = bone_lengths(&out[..1], &out[1..55]);
        for (b, (g, w)) in got.iter().zip(&lengths).enumerate() {
            assert!((g - 2.0 * w).abs() < 1e-3, "bone {b}: {g} vs {}", 2.0 * w);
        }
    }

    #[test]
    fn a_planted_foot_stands_at_the_contact_height() {
        let body = identity_body();
        let mut x = [0f32; 58];
        x[0] = 10.0; // hips height
        x[1 + 3 * 3 + 1] = 3.0; // left toe 3 units up
        x[1 + 3 * 7 + 1] = 7.0; // right toe
        x[1 + 3 * 11 + 1] = 20.0; // head
                                  // Left foot down, right foot up: everything moves by 0.5 − 3.
        let logits = Tensor::new(&[[[30f32, -30.0]]], &Device::Cpu).unwrap();
        let out = ground(&row(&x), &logits, &body.stats())
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        for (k, want) in [
            (0, 7.5f32),
            (1 + 3 * 3 + 1, 0.5),
            (1 + 3 * 7 + 1, 4.5),
            (1 + 3 * 11 + 1, 17.5),
        ] {
            assert!(
                (out[k] - want).abs() < 1e-4,
                "feature {k}: {} vs {want}",
                out[k]
            );
        }
        // x and z stay.
        assert_eq!(out[1 + 3 * 3], 0.0);
    }
}
