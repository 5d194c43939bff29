//! The model's [`Config`]: the paper's sizes, the [`Parts`] beyond the
//! paper, the training set's [`Body`], and the named models.

use super::*;

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
    /// The control: each frame also reads where the root is asked to be
    /// over the next second ([`motion_steer::CONTROL`]: its position and
    /// facing 10, 20 and 30 frames ahead, in the character's own axes),
    /// through its own weights added to the condition's rows. Training
    /// reads it from the frames that follow and leaves it free (zeros) in a
    /// share of the windows ([`crate::train::CONTROL_DROPOUT`]); generation
    /// leaves it free unless a path is asked (`motion_steer::Follower`).
    /// Needs [`Config::categories`] and the skeleton's statistics.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub control: bool,
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
}

impl Config {
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
            control: false,
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
        let p = &self.parts;
        if !p.skeleton && p.feet <= 0.0 && !p.foot_lock && !p.control {
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
pub(super) fn split_raw(raw: &[f32], f: usize) -> (Vec<f32>, Vec<f32>) {
    let y = raw.chunks_exact(f).map(|r| r[0]).collect();
    let joints = raw
        .chunks_exact(f)
        .flat_map(|r| r[1..1 + 3 * BONES].iter().copied())
        .collect();
    (y, joints)
}

/// Extra decoder outputs: one contact logit per toe with the foot lock.
pub(super) fn contacts(c: &Config) -> usize {
    if c.parts.foot_lock {
        TOES.len()
    } else {
        0
    }
}
