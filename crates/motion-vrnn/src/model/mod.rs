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
    self, add_rows, control_rows, filter, gaussian_kl, latent_lstm, linear, lstm_cell, rollout,
    squared_error, Act,
};
use candle_core::{DType, Device, Result, Tensor, D};
use candle_nn::VarBuilder;
use mocap_ingest::category::Category;
use mocap_ingest::features::{ANG_VEL_Y, ROOT_Y, VEL_X, VEL_Z};
use serde::{Deserialize, Serialize};

pub use crate::blocks::SIGMA_MIN;

mod condition;
mod config;
mod control;
mod fed;
mod generate;
mod losses;
mod step;
mod vrnn;

pub use condition::{
    pace, CONTROL_PACE_MIN_M_S, GUIDANCE, PACE_EVERY, PACE_FEATURES, PACE_FRAMES, ROOT_FEATURES,
};
pub use config::{Body, Config, Parts};
pub use control::{Control, CONTROL_WEIGHT};
pub use fed::{fed_speed_loss, FED_SPEED_FLOOR};
pub use generate::Generator;
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
    /// [`MotionModel::sample`] with the control ([`Parts::control`]) asked
    /// at each step by `control` (None: left free, as `sample` leaves it).
    fn steer(
        &self,
        eps: &Tensor,
        start: Option<&Tensor>,
        cond: Option<&Tensor>,
        control: &mut Control,
    ) -> Result<Tensor>;
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
