//! `viewer.html`: one self-contained file (no network) that plays motion
//! sets in 3-D with three.js: orbit, pan and zoom with the mouse, a floor
//! grid, each root's path as a trace, motions side by side or overlaid per
//! group (a real window with its reconstruction), play/pause, speed, a frame
//! slider; `?frame=N` opens paused at frame N, `?set=K` picks a set and
//! `?overlay=1` overlays groups.
//!
//! three.js is vendored: `viewer/vendor/three.bundle.js` is built from the
//! npm packages pinned in `viewer/package.json` (`viewer/build.sh`), licence
//! in `viewer/vendor/three.LICENSE`, and embedded in every file written.

use crate::io::motions_json;
use crate::{Motion, RenderError};
use std::path::Path;

/// three.js (and OrbitControls) as one classic script defining `THREE`.
pub const THREE_BUNDLE: &str = include_str!("../viewer/vendor/three.bundle.js");
/// three.js's licence, kept in every viewer file.
pub const THREE_LICENSE: &str = include_str!("../viewer/vendor/three.LICENSE");
/// The viewer's own script.
const VIEWER_JS: &str = include_str!("viewer.js");

/// A named set of motions; `group` consecutive motions form a group that can
/// be overlaid (2 for real/reconstruction pairs, 1 otherwise).
pub struct MotionSet<'a> {
    /// Shown in the set selector.
    pub name: &'a str,
    /// Motions per group.
    pub group: usize,
    /// The motions.
    pub motions: &'a [Motion],
}

/// Text safe inside a `<script>` element.
fn script_safe(s: &str) -> String {
    s.replace("</", "<\\/")
}

/// The viewer's HTML for `sets`.
pub fn viewer_html(sets: &[MotionSet]) -> String {
    let data: Vec<String> = sets
        .iter()
        .map(|s| {
            format!(
                "{{\"name\":{},\"group\":{},\"data\":{}}}",
                serde_json::Value::from(s.name),
                s.group.max(1),
                motions_json(s.motions)
            )
        })
        .collect();
    let licence = THREE_LICENSE.replace("-->", "- ->");
    format!(
        r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>motion viewer</title>
<!-- three.js, vendored (crates/motion-render/viewer/):
{licence}-->
<style>
body {{ font: 14px sans-serif; margin: 12px; color: #222; }}
#bar {{ display: flex; gap: 12px; align-items: center; margin-bottom: 8px; flex-wrap: wrap; }}
#slider {{ width: 360px; }}
#err {{ color: #b00; }}
#view canvas {{ border: 1px solid #ddd; display: block; }}
</style></head><body>
<div id="bar">
  <select id="set"></select>
  <label><input id="overlay" type="checkbox"> overlay pairs</label>
  <button id="play">pause</button>
  <label>speed <select id="speed"><option>0.25</option><option>0.5</option><option selected>1</option><option>2</option></select></label>
  <input id="slider" type="range" min="0" value="0">
  <span id="label"></span>
  <span id="err"></span>
</div>
<div id="view"></div>
<p><span id="legend"></span> Drag to orbit, right-drag to pan, wheel to zoom. Grid: 10 units (0.56 m). Written by <code>cargo xtask sample</code>.</p>
<script id="motion-data" type="application/json">{data}</script>
<script>{three}</script>
<script>{js}</script>
</body></html>
"#,
        data = script_safe(&format!("[{}]", data.join(","))),
        three = script_safe(THREE_BUNDLE),
        js = script_safe(VIEWER_JS),
    )
}

/// Write `viewer.html` (atomically).
pub fn write_viewer(path: &Path, sets: &[MotionSet]) -> Result<(), RenderError> {
    crate::write_file(path, viewer_html(sets).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_viewer_is_one_file_with_its_data_and_no_network() {
        let m = Motion {
            id: "x</script>".into(),
            poses: vec![[[0.0; 3]; mocap_ingest::NUM_JOINTS]],
        };
        let html = viewer_html(&[MotionSet {
            name: "s",
            group: 1,
            motions: std::slice::from_ref(&m),
        }]);
        assert_eq!(html.matches("</script>").count(), 3);
        assert!(html.contains("Copyright © 2010-"));
        for needle in ["<script src", "<link", "import(", "fetch("] {
            assert!(!html.contains(needle), "viewer.html has {needle}");
        }
    }
}
