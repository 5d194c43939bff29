//! A run's loss curves as a picture.

use crate::EvalError;
use motion_render::chart::{line_chart, Series};
use motion_vrnn::train::EpochMetrics;
use std::path::Path;

/// The loss curves (recon + KL per window, train and validation, and the
/// validation KL) of a run's epochs as a PNG (`loss.png`).
pub fn loss_curves(path: &Path, history: &[EpochMetrics]) -> Result<(), EvalError> {
    let pts =
        |f: fn(&EpochMetrics) -> f64| history.iter().map(|m| (m.epoch as f64, f(m))).collect();
    Ok(line_chart(
        path,
        "VRNN loss per window",
        "epoch",
        "loss per window (normalised units)",
        &[
            Series {
                name: "train (recon + KL)",
                color: [31, 119, 180],
                points: pts(|m| m.train_recon + m.train_kl),
            },
            Series {
                name: "val (recon + KL)",
                color: [255, 127, 14],
                points: pts(|m| m.val_recon + m.val_kl),
            },
            Series {
                name: "val KL",
                color: [44, 160, 44],
                points: pts(|m| m.val_kl),
            },
        ],
    )?)
}
