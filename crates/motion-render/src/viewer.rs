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
use std::path::{Path, PathBuf};

/// three.js (and OrbitControls) as one classic script defining `THREE`.
pub const THREE_BUNDLE: &str = include_str!("../viewer/vendor/three.bundle.js");
/// three.js's licence, kept in every viewer file.
pub const THREE_LICENSE: &str = include_str!("../viewer/vendor/three.LICENSE");
/// The viewer's own script.
const VIEWER_JS: &str = include_str!("viewer.js");
/// The lit scene and the stick figures, shared with the player's page.
pub(crate) const FIGURE_JS: &str = include_str!("figure.js");

/// How the checks start headless Chromium (software WebGL, nothing fetched
/// in the background, timers not throttled).
pub const CHROMIUM_FLAGS: [&str; 9] = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-background-timer-throttling",
    "--disable-renderer-backgrounding",
];

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
pub(crate) fn script_safe(s: &str) -> String {
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
    let css = "#bar { display: flex; gap: 12px; align-items: center; margin-bottom: 8px; flex-wrap: wrap; }
#slider { width: 360px; }
";
    let body = format!(
        r#"<div id="bar">
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
"#,
        data = script_safe(&format!("[{}]", data.join(","))),
    );
    page("motion viewer", css, &body, VIEWER_JS)
}

/// A self-contained page: `title`, three.js's licence in a comment, the
/// styles every page shares (after `css`'s own rules), `body`, then
/// three.js, the shared figure ([`FIGURE_JS`]) and `js`, each inline.
pub(crate) fn page(title: &str, css: &str, body: &str, js: &str) -> String {
    let licence = THREE_LICENSE.replace("-->", "- ->");
    format!(
        r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<!-- three.js, vendored (crates/motion-render/viewer/):
{licence}-->
<style>
body {{ font: 14px sans-serif; margin: 12px; color: #222; }}
{css}#err {{ color: #b00; }}
#view canvas {{ border: 1px solid #ddd; display: block; }}
</style></head><body>
{body}<script>{three}</script>
<script>{figure}</script>
<script>{js}</script>
</body></html>
"#,
        three = script_safe(THREE_BUNDLE),
        figure = script_safe(FIGURE_JS),
        js = script_safe(js),
    )
}

/// Write `viewer.html` (atomically).
pub fn write_viewer(path: &Path, sets: &[MotionSet]) -> Result<(), RenderError> {
    crate::write_file(path, viewer_html(sets).as_bytes())
}

/// A headless Chromium (Debian's `chromium`): `$CHROMIUM` if set, else the
/// first of `chromium`, `chromium-browser`, `google-chrome` on `PATH`.
pub fn find_chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("CHROMIUM").filter(|p| !p.is_empty()) {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .flat_map(|name| std::env::split_paths(&path).map(move |d| d.join(name)))
        .find(|p| p.is_file())
}

/// Run headless Chromium on `url` with `args`, at most 120 s; its stdout
/// and stderr.
fn run_chromium(
    chromium: &Path,
    args: &[String],
    url: &str,
) -> Result<(String, String), RenderError> {
    static RUN: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let err = |message: String| RenderError::Image {
        path: chromium.to_path_buf(),
        message,
    };
    let profile = std::env::temp_dir().join(format!(
        "motion-viewer-{}-{}",
        std::process::id(),
        RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    ));
    let mut child = std::process::Command::new(chromium)
        .args(CHROMIUM_FLAGS)
        .args(["--enable-logging=stderr", "--virtual-time-budget=3000"])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(url)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .map_err(|e| err(format!("cannot start: {e}")))?;
    let (mut out, mut log) = (child.stdout.take(), child.stderr.take());
    let reader = std::thread::spawn(move || {
        use std::io::Read;
        let (mut a, mut b) = (String::new(), String::new());
        if let Some(o) = out.as_mut() {
            let _ = o.read_to_string(&mut a);
        }
        if let Some(l) = log.as_mut() {
            let _ = l.read_to_string(&mut b);
        }
        (a, b)
    });
    let started = std::time::Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break Some(s),
            Ok(None) if started.elapsed().as_secs() < 120 => {
                std::thread::sleep(std::time::Duration::from_millis(50))
            }
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
        }
    };
    let (stdout, stderr) = reader.join().unwrap_or_default();
    let _ = std::fs::remove_dir_all(&profile);
    match status {
        Some(s) if s.success() => Ok((stdout, stderr)),
        Some(s) => Err(err(format!("exited with {s}: {}", stderr.trim()))),
        None => Err(err("did not finish in 120 s".into())),
    }
}

/// Open `html` (with `query`, e.g. `?set=1&overlay=1&frame=60`) in headless
/// Chromium, check that the viewer started without a JavaScript error, and
/// write a `width × height` screenshot to `png`.
pub fn screenshot(
    chromium: &Path,
    html: &Path,
    query: &str,
    png: &Path,
    (width, height): (u32, u32),
) -> Result<(), RenderError> {
    let abs = std::fs::canonicalize(html).map_err(|cause| RenderError::Io {
        path: html.to_path_buf(),
        cause,
    })?;
    let url = format!("file://{}{query}", abs.display());
    let fail = |message: String| RenderError::Image {
        path: html.to_path_buf(),
        message,
    };
    let (dom, log) = run_chromium(chromium, &["--dump-dom".to_string()], &url)?;
    let status = dom
        .split("data-status=\"")
        .nth(1)
        .and_then(|s| s.split('"').next())
        .unwrap_or("missing (the viewer's script did not run)");
    if status != "ok" {
        return Err(fail(format!("viewer status: {status}")));
    }
    if let Some(line) = log.lines().find(|l| l.contains("Uncaught")) {
        return Err(fail(format!("JavaScript error: {line}")));
    }
    let mut name = png.file_name().unwrap_or_default().to_os_string();
    name.push(".tmp.png");
    let tmp = png.with_file_name(name);
    let (_, log) = run_chromium(
        chromium,
        &[
            format!("--window-size={width},{height}"),
            format!("--screenshot={}", tmp.display()),
        ],
        &url,
    )?;
    if let Some(line) = log.lines().find(|l| l.contains("Uncaught")) {
        return Err(fail(format!("JavaScript error: {line}")));
    }
    std::fs::rename(&tmp, png).map_err(|e| fail(format!("no screenshot ({}): {e}", tmp.display())))
}

/// The screenshots worth taking of a viewer file at `frame`: `(PNG name,
/// query)` for the first set, and for each overlaid set that `cargo xtask
/// sample` writes (real vs reconstruction, generated vs its BVH read back)
/// when the file has it.
pub fn screenshots_of(
    html: &Path,
    frame: usize,
) -> Result<Vec<(&'static str, String)>, RenderError> {
    let text = std::fs::read_to_string(html).map_err(|cause| RenderError::Io {
        path: html.to_path_buf(),
        cause,
    })?;
    // The sets in the file, in order.
    let names: Vec<&str> = text
        .split("\"name\":\"")
        .skip(1)
        .filter_map(|t| t.split('"').next())
        .collect();
    let mut shots = vec![("viewer_samples.png", format!("?set=0&frame={frame}"))];
    for (name, file) in [
        ("real vs reconstruction", "viewer_pairs.png"),
        ("generated vs its BVH read back", "viewer_bvh.png"),
    ] {
        if let Some(k) = names.iter().position(|n| *n == name) {
            shots.push((file, format!("?set={k}&overlay=1&frame={frame}")));
        }
    }
    Ok(shots)
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
        // The data, three.js, the figures, the viewer.
        assert_eq!(html.matches("</script>").count(), 4);
        assert!(html.contains("Copyright © 2010-"));
        for needle in ["<script src", "<link", "import(", "fetch("] {
            assert!(!html.contains(needle), "viewer.html has {needle}");
        }
    }
}
