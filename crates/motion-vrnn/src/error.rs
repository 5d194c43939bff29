//! The error of training and generation (below both, so neither imports the other for it).

use std::path::PathBuf;

/// A failure that stops training.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A tensor operation failed. Its message is in this error's own, so it
    /// is not also given as the source (a chain would print it twice).
    #[error("tensor error: {0}")]
    Candle(candle_core::Error),
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

impl From<candle_core::Error> for TrainError {
    fn from(e: candle_core::Error) -> Self {
        TrainError::Candle(e)
    }
}

#[cfg(feature = "train")]
pub(crate) fn io_err(path: &std::path::Path, e: impl std::fmt::Display) -> TrainError {
    TrainError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tensor error says what failed once: in its message, with no source
    /// behind it for an error chain to print again.
    #[test]
    fn a_tensor_error_is_said_once() {
        let e = TrainError::from(candle_core::Error::Msg(
            "float limit must be positive".into(),
        ));
        assert_eq!(e.to_string(), "tensor error: float limit must be positive");
        assert!(std::error::Error::source(&e).is_none());
    }
}
