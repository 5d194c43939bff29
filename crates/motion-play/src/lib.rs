//! The default model steered live, one frame at a time: what the page of
//! `cargo xtask play` runs, compiled to WebAssembly (`docs/play.md`).
//!
//! - [`bundle`]: what the page carries: the model's configuration and
//!   weights, the start contexts, the walking and running speeds;
//! - [`player`]: a [`Player`] making one frame per call from the keys held
//!   ([`motion_steer::Stick`]), in runs as the sampler makes them;
//! - [`module`] (not on `wasm32`): this crate built for the page;
//! - `wasm` (on `wasm32` only): the functions the page calls.
//!
//! The model is `motion_vrnn`'s, read through its [`motion_vrnn::model::Generator`]:
//! nothing of it is written again here.

pub mod bundle;
#[cfg(not(target_arch = "wasm32"))]
pub mod module;
pub mod player;
#[cfg(target_arch = "wasm32")]
mod wasm;

pub use bundle::{Bundle, Start};
pub use player::{Frame, Player};

/// Why the player cannot start or go on.
#[derive(Debug, thiserror::Error)]
pub enum PlayError {
    /// The bundle does not parse.
    #[error("the page's model bundle: {0}")]
    Bundle(String),
    /// The model fails (its weights do not fit its configuration, a tensor
    /// error).
    #[error("the model: {0}")]
    Model(#[from] candle_core::Error),
    /// The module for the page could not be built.
    #[error("building the player for WebAssembly: {0}")]
    Build(String),
    /// A category or start that the bundle does not hold.
    #[error("{0}")]
    Invalid(String),
}
