//! The bundle of `cargo xtask play`'s page ([`motion_play::Bundle`]): a
//! run's model, a start context per category from its training windows,
//! and the speeds its real walks hold.

use crate::run::Run;
use crate::EvalError;
use mocap_ingest::category::Category;
use motion_play::bundle::{Bundle, Header, Start};
use motion_vrnn::model::PACE_FRAMES;
use motion_vrnn::train::layout;
use std::path::Path;

/// What [`Run::write_play`] wrote.
pub struct PlayPage {
    /// The page's size, bytes.
    pub bytes: usize,
    /// The model's bundle's size, bytes.
    pub model_bytes: usize,
    /// The categories the digit keys pick.
    pub categories: Vec<String>,
}

impl Run {
    /// The page's bundle for this run's checkpoint `checkpoint` (the
    /// directory it was loaded from): its weights as saved, one training
    /// context drawn from `seed` for each category the model knows and the
    /// training set holds (walking first), walking at the real walks' mean
    /// speed and running at the fastest training window's.
    pub fn play_bundle(&self, checkpoint: &Path, seed: u64) -> Result<Bundle, EvalError> {
        let config = self.meta.config.model.clone();
        if !config.parts.control {
            return Err(EvalError::Invalid(
                "this model was trained without the control, so it cannot be steered; train one with `cargo xtask train` (the default, `--condition category+pace+control`)".into(),
            ));
        }
        let file = checkpoint.join(layout::MODEL);
        let weights = std::fs::read(&file).map_err(|cause| EvalError::Io {
            path: file.clone(),
            cause,
        })?;
        let (train, _) = self.labelled("train")?;
        let mut names = config.categories.clone();
        if let Some(w) = names.iter().position(|c| c == Category::Walk.name()) {
            let walk = names.remove(w);
            names.insert(0, walk);
        }
        let mut starts = Vec::new();
        for name in names {
            let category: Category = name.parse().map_err(EvalError::Invalid)?;
            let Ok(pick) = self.training_picks(Some(category), 1, seed) else {
                continue;
            };
            let w = train.length * train.features;
            let window = &train.data[pick[0] * w..(pick[0] + 1) * w];
            starts.push(Start {
                category: name,
                source: format!("training window {}", pick[0]),
                frames: window[..PACE_FRAMES * train.features].to_vec(),
            });
        }
        let walks = self.walks()?;
        Ok(Bundle {
            header: Header {
                config,
                starts,
                speeds: [walks.speed_m_s, walks.fastest_m_s],
            },
            weights,
        })
    }
}

impl Run {
    /// `play.html` at `out` for this run's checkpoint `checkpoint`
    /// ([`Run::play_bundle`] with `seed`), with the player built for
    /// WebAssembly from the workspace at `root` ([`motion_play::module::build`]).
    pub fn write_play(
        &self,
        checkpoint: &Path,
        seed: u64,
        out: &Path,
        root: &Path,
    ) -> Result<PlayPage, EvalError> {
        let bundle = self.play_bundle(checkpoint, seed)?;
        let wasm = motion_play::module::build(root)?;
        let bytes = bundle.to_bytes()?;
        let html = motion_render::play::play_html(&wasm, &bytes, seed);
        motion_render::play::write_play(out, html.as_bytes())?;
        Ok(PlayPage {
            bytes: html.len(),
            model_bytes: bytes.len(),
            categories: bundle
                .header
                .starts
                .into_iter()
                .map(|s| s.category)
                .collect(),
        })
    }
}
