//! The error of training and generation (below both, so neither imports the other for it).

use std::path::{Path, PathBuf};

/// A failure that stops training.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A tensor operation failed.
    #[error("tensor error: {0}")]
    Candle(#[from] candle_core::Error),
    /// A file could not be read or written.
    #[error("{path}: {message}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The loss became NaN or infinite.
    #[error("non-finite loss at step {step} (epoch {epoch}): recon {recon}, kl {kl}; the last good checkpoint is kept in {dir}")]
    NonFinite {
        /// Global step.
        step: u64,
        /// Epoch.
        epoch: usize,
        /// Reconstruction loss.
        recon: f32,
        /// KL loss.
        kl: f32,
        /// Run directory.
        dir: PathBuf,
    },
    /// Options or inputs that cannot work.
    #[error("{0}")]
    Invalid(String),
}

pub(crate) fn io_err(path: &Path, e: impl std::fmt::Display) -> TrainError {
    TrainError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}
