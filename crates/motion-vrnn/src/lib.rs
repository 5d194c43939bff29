//! The VRNN of *Human Motion Generative Model using Variational Recurrent
//! Neural Network* (Murakami & Ikuzawa) in candle, trained on the Parquet
//! windows written by `cargo xtask dataset`.
//!
//! - [`model`]: `Config` (the paper's sizes and the parts beyond it),
//!   `Vrnn::new(vb)`, and the [`MotionModel`] trait (`losses`,
//!   `reconstruct`, `sample`) that training, sampling and evaluation use.
//! - [`blocks`]: the fused building blocks models are written with (dense
//!   layers over all rows, the recurrence over whole sequences, the Gaussian
//!   KL, forward kinematics, a temporal filter), each with a hand-written
//!   CPU backward tested against autograd.
//! - [`data`]: the dataset through polars, normalised by its `stats.json`,
//!   with each window's category.
//! - [`classifier`]: a motion classifier trained on real windows per
//!   category, and the measures made with it (accuracy, Fréchet distance of
//!   its features, diversity, multimodality).
//! - [`generate`]: motions sampled from a model, back in global positions,
//!   and the [`generate::Judge`] that chooses checkpoints by them.
//! - [`optim`]: Adam with saveable state; gradient-norm clipping.
//! - [`options`]: overrides of a training configuration, one per option.
//! - [`mod@bench`]: the speed of a training step and of sampling.
//! - [`train`]: the training loop, checkpoints, resume, metrics.
//! - [`rng`]: the seeded RNG behind every random number (and the
//!   reparameterisation noise).
//! - [`error`]: [`error::TrainError`], shared by training and generation.

#[cfg(feature = "train")]
pub mod bench;
pub mod blocks;
#[cfg(feature = "train")]
pub mod classifier;
#[cfg(feature = "train")]
pub mod data;
pub mod error;
#[cfg(feature = "train")]
pub mod generate;
pub mod model;
#[cfg(feature = "train")]
pub mod optim;
#[cfg(feature = "train")]
pub mod options;
pub mod rng;
#[cfg(feature = "train")]
pub mod steer;
#[cfg(feature = "train")]
pub mod train;

pub use model::{Config, MotionModel, Vrnn};
