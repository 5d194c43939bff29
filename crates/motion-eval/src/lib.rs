//! Trained runs judged: everything between a run directory written by
//! `cargo xtask train` and what a person reads about it.
//!
//! - [`run`]: a run loaded with its dataset ([`run::Run`]), its windows
//!   reconstructed and new motions generated from it.
//! - [`report`]: the evaluation of a run ([`report::EvalReport`], written as
//!   `eval.json`, and its Markdown `eval.md`).
//! - [`horizon`]: motions rolled out for a minute, measured stretch by
//!   stretch against every real window.
//! - [`recognition`]: generated motion seen by the motion classifier.
//! - [`asked`]: a conditioned model asked for each category, measured by
//!   the classifier and per category.
//! - [`samples`]: the files `cargo xtask sample` writes (Parquet, JSON,
//!   BVH, contact sheet, animations, the 3-D viewer).
//! - [`continuation`]: a user's clip continued by a run's model.
//! - [`compare`]: every model trained with several seeds, evaluated, and
//!   the results page (mean ± std over seeds, goals met).
//! - [`chart`]: a run's loss curves as a picture.
//! - [`speed`]: how fast a run generates, its sampler beside the model alone.
//! - [`steering`]: motions asked to follow a path, and how well they do.
//!
//! Above `motion-vrnn`, `motion-metrics` and `motion-render`; below `xtask`,
//! which parses options, shows progress and prints what these return.

pub mod asked;
pub mod chart;
pub mod compare;
pub mod continuation;
pub mod horizon;
pub mod play;
pub mod recognition;
pub mod report;
pub mod run;
pub mod samples;
pub mod speed;
pub mod steering;

use std::path::PathBuf;

/// Why a run could not be evaluated, sampled or compared.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The run directory has no checkpoint of that name.
    #[error("{}: no checkpoint here; train one with `cargo xtask train --out {}` (or pass --run / --checkpoint)", checkpoint.display(), run.display())]
    NoCheckpoint {
        /// The checkpoint directory looked for.
        checkpoint: PathBuf,
        /// The run directory.
        run: PathBuf,
    },
    /// The dataset could not be loaded.
    #[error("loading the dataset {} (pass --data DIR): {cause}", dir.display())]
    Data {
        /// The dataset directory.
        dir: PathBuf,
        /// The cause.
        cause: motion_vrnn::data::DataError,
    },
    /// The dataset has no windows in a split that is needed.
    #[error("{}: no {split} windows", dir.display())]
    NoWindows {
        /// The dataset directory.
        dir: PathBuf,
        /// The split.
        split: String,
    },
    /// Loading or training a model failed.
    #[error(transparent)]
    Train(#[from] motion_vrnn::train::TrainError),
    /// A path to steer along could not be read or asks too much.
    #[error(transparent)]
    Path(#[from] motion_steer::PathError),
    /// The live player's bundle or module.
    #[error(transparent)]
    Play(#[from] motion_play::PlayError),
    /// A tensor operation failed (its message in this one's, not also a
    /// source, so an error chain says it once).
    #[error("tensor error: {0}")]
    Candle(candle_core::Error),
    /// Writing or drawing an output failed.
    #[error(transparent)]
    Render(#[from] motion_render::RenderError),
    /// A report could not be (de)serialised (its message in this one's).
    #[error("report JSON: {0}")]
    Json(serde_json::Error),
    /// Creating a directory or copying a file failed.
    #[error("{}: {cause}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The cause.
        cause: std::io::Error,
    },
    /// Options that cannot work.
    #[error("{0}")]
    Invalid(String),
    /// A failure inside one step of a longer job, with the step named.
    #[error("{what}: {cause}")]
    In {
        /// The step (e.g. "training motion seed 1").
        what: String,
        /// The cause.
        cause: Box<EvalError>,
    },
}

impl From<candle_core::Error> for EvalError {
    fn from(e: candle_core::Error) -> Self {
        EvalError::Candle(e)
    }
}

impl From<serde_json::Error> for EvalError {
    fn from(e: serde_json::Error) -> Self {
        EvalError::Json(e)
    }
}

impl EvalError {
    /// This error inside the step `what`.
    pub fn within(self, what: impl Into<String>) -> EvalError {
        EvalError::In {
            what: what.into(),
            cause: Box::new(self),
        }
    }
}

/// `std::fs::create_dir_all` with the directory named in the error.
pub(crate) fn create_dir(path: &std::path::Path) -> Result<(), EvalError> {
    std::fs::create_dir_all(path).map_err(|cause| EvalError::Io {
        path: path.to_path_buf(),
        cause,
    })
}

/// Mean of `v` (0 when empty).
pub fn mean_of(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Smallest and largest of `xs` (∞ and −∞ when empty).
pub(crate) fn lo_hi(xs: impl Iterator<Item = f64>) -> (f64, f64) {
    xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    })
}

/// Mean and sample standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = mean_of(v);
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (m, var.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error says its cause once: in its own message, with no source
    /// behind it for an error chain (`anyhow`'s "Caused by") to repeat.
    #[test]
    fn an_error_says_its_cause_once() {
        let io = || std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let errors = [
            EvalError::Io {
                path: "out/x.png".into(),
                cause: io(),
            },
            EvalError::Candle(candle_core::Error::Msg("bad shape".into())),
            EvalError::Render(motion_render::RenderError::Io {
                path: "a.bvh".into(),
                cause: io(),
            })
            .within("writing seed 1"),
        ];
        let texts = errors.map(|e| {
            assert!(std::error::Error::source(&e).is_none(), "{e}");
            e.to_string()
        });
        assert_eq!(texts[0], "out/x.png: no such file");
        assert_eq!(texts[1], "tensor error: bad shape");
        assert_eq!(texts[2], "writing seed 1: a.bvh: no such file");
    }
}
