//! `play.html`: one self-contained page (no network, no server) where the
//! model, compiled to WebAssembly (crate `motion-play`), makes a motion
//! frame by frame as the keys say, drawn with three.js (`docs/play.md`).

use crate::viewer::{page, script_safe};
use crate::RenderError;
use mocap_ingest::skeleton::JOINT_PARENTS;
use std::path::Path;

/// The page's own script.
const PLAY_JS: &str = include_str!("play.js");

/// Standard base64 (RFC 4648, padded).
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            out.push(match k <= c.len() {
                true => A[(n >> (18 - 6 * k) & 63) as usize] as char,
                false => '=',
            });
        }
    }
    out
}

/// The page for the player module `wasm` and its model `bundle`
/// (`motion_play::Bundle`'s bytes), its noise drawn from `seed`.
pub fn play_html(wasm: &[u8], bundle: &[u8], seed: u64) -> String {
    let parents: Vec<i64> = JOINT_PARENTS
        .iter()
        .map(|p| p.map_or(-1, |p| p as i64))
        .collect();
    let meta = serde_json::json!({ "fps": 30, "parents": parents, "seed": seed });
    let body = format!(
        r#"<div id="hud">loading the model…</div>
<div id="keys"></div>
<div id="err"></div>
<div id="view"></div>
<p>The model runs in this page, one frame at a time; the orange line is where it is asked to go (its length: the speed asked). Written by <code>cargo xtask play</code>.</p>
<script id="play-meta" type="application/json">{meta}</script>
<script id="play-wasm" type="application/octet-stream">{wasm}</script>
<script id="play-bundle" type="application/octet-stream">{bundle}</script>
"#,
        meta = script_safe(&meta.to_string()),
        wasm = base64(wasm),
        bundle = base64(bundle),
    );
    let css = "#hud { font-weight: bold; margin-bottom: 4px; }\n";
    page("motion player", css, &body, PLAY_JS)
}

/// Write a page ([`play_html`]) at `path` (atomically; its folder made
/// where missing).
pub fn write_play(path: &Path, html: &[u8]) -> Result<(), RenderError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|cause| RenderError::Io {
            path: dir.to_path_buf(),
            cause,
        })?;
    }
    crate::write_file(path, html)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_is_rfc_4648() {
        // RFC 4648 §10's test vectors.
        for (raw, enc) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(raw.as_bytes()), enc);
        }
    }

    #[test]
    fn the_page_is_one_file_with_no_network() {
        let html = play_html(b"\0asm</script>", b"MPLAY1", 3);
        // meta, module, bundle, three.js, the figures, the player.
        assert_eq!(html.matches("</script>").count(), 6);
        assert!(html.contains(&base64(b"\0asm</script>")) && html.contains("\"seed\":3"));
        for needle in ["<script src", "<link", "import(", "fetch("] {
            assert!(!html.contains(needle), "play.html has {needle}");
        }
    }
}
