//! The VRNN of *Human Motion Generative Model using Variational Recurrent
//! Neural Network* (Murakami & Ikuzawa) in candle, trained on the Parquet
//! windows written by `cargo xtask dataset`.
//!
//! - [`model`]: `Config`, `Vrnn::new(vb)`, `forward` (losses), `sample`.
//! - [`fused`]: the training loss as one CPU kernel with a hand-written backward.
//! - [`data`]: the dataset through polars, normalised by its `stats.json`.
//! - [`optim`]: Adam with saveable state; gradient-norm clipping.
//! - [`train`]: the training loop, checkpoints, resume, metrics.
//! - [`rng`]: the seeded RNG behind every random number.

pub mod data;
pub mod fused;
pub mod model;
pub mod optim;
pub mod rng;
pub mod train;

pub use model::{Config, Vrnn};
