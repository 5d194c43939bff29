//! The bundle the page carries: one byte string, `MPLAY1\n`, a header's
//! length (u32, little-endian), the header (JSON: [`Header`]), then the
//! model's weights (safetensors, as in the checkpoint's `model.safetensors`).

use crate::PlayError;
use motion_vrnn::Config;
use serde::{Deserialize, Serialize};

const MAGIC: &[u8] = b"MPLAY1\n";

/// A context the player starts from (and restarts from when a category is
/// picked): real frames of a training window.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Start {
    /// The category shown for it (a name of [`Config::categories`]).
    pub category: String,
    /// Its take and first frame, for the record.
    pub source: String,
    /// Normalised features, [`motion_vrnn::model::PACE_FRAMES`] frames ×
    /// the model's input.
    pub frames: Vec<f32>,
}

/// The bundle's header.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// The model's configuration (the checkpoint's `config.model`).
    pub config: Config,
    /// The contexts, one per category a digit key picks.
    pub starts: Vec<Start>,
    /// Walking and running speeds asked, metres per second.
    pub speeds: [f64; 2],
}

/// The model and what the player needs with it.
#[derive(Clone, Debug, PartialEq)]
pub struct Bundle {
    /// The header.
    pub header: Header,
    /// The weights, safetensors.
    pub weights: Vec<u8>,
}

impl Bundle {
    /// The bundle's bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>, PlayError> {
        let head =
            serde_json::to_vec(&self.header).map_err(|e| PlayError::Bundle(e.to_string()))?;
        let len = u32::try_from(head.len())
            .map_err(|_| PlayError::Bundle("a header over 4 GiB".into()))?;
        let mut out = Vec::with_capacity(MAGIC.len() + 4 + head.len() + self.weights.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(&head);
        out.extend_from_slice(&self.weights);
        Ok(out)
    }

    /// A bundle from its bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Bundle, PlayError> {
        let bad = |m: &str| PlayError::Bundle(m.to_string());
        let rest = bytes
            .strip_prefix(MAGIC)
            .ok_or_else(|| bad("does not start with MPLAY1 (not written by `cargo xtask play`)"))?;
        let (len, rest) = rest
            .split_first_chunk::<4>()
            .ok_or_else(|| bad("cut before its header's length"))?;
        let len = u32::from_le_bytes(*len) as usize;
        if rest.len() < len {
            return Err(bad("cut inside its header"));
        }
        let (head, weights) = rest.split_at(len);
        let header: Header =
            serde_json::from_slice(head).map_err(|e| PlayError::Bundle(format!("header: {e}")))?;
        let width = header.config.input * motion_vrnn::model::PACE_FRAMES;
        if let Some(s) = header.starts.iter().find(|s| s.frames.len() != width) {
            return Err(PlayError::Bundle(format!(
                "start {} has {} values; {width} expected",
                s.source,
                s.frames.len()
            )));
        }
        if header.starts.is_empty() {
            return Err(bad("no start context"));
        }
        Ok(Bundle {
            header,
            weights: weights.to_vec(),
        })
    }
}
