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
//! model):
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
//!
//! The files: `config` ([`Config`], [`Parts`], [`Body`], the named models),
//! `condition` (category weights and pace), `vrnn` ([`Vrnn::new`], the
//! recurrence over whole sequences, the decoder), `step` (one step at a
//! time), `fed` (scheduled sampling), `losses` ([`MotionModel`] for
//! [`Vrnn`]), `generate` (sampling).

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

mod condition;
mod config;
mod fed;
mod generate;
mod losses;
mod step;
#[cfg(test)]
mod tests;
mod vrnn;

pub use condition::{pace, PACE_FEATURES, ROOT_FEATURES};
pub use config::{Body, Config, Parts};
pub use fed::{fed_speed_loss, FED_SPEED_FLOOR};
pub use vrnn::Vrnn;

use condition::frame_speed;
use config::contacts;
use fed::Feed;
use step::{step_filter, Steps};
use vrnn::{draw, plus, stacked, Bias, Lin};

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

pub use crate::blocks::feet::CONTACT_UNITS;

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
