//! `cargo xtask play`: the page in headless Chromium, driven through the
//! DevTools protocol over a pipe with real key presses, its state read back
//! from `window.play`.
//!
//! On a small run trained here (the model knows little): the page starts
//! without a JavaScript error, makes frames in real time, the keys reach the
//! model (the asked heading and speed), and one frame takes under 1/30 s.
//! With `MOCAP_PLAY_RUN` naming a run of the default `train`, the figure
//! itself is checked: holding Up moves it forward (over 0.25 m), holding Left for 2 s
//! turns it at least 60°, Space brings it to a stand within 2 s (under
//! 0.15 m/s over the next half second).

mod common;

use common::{six_takes, small_dataset, xtask};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::os::fd::FromRawFd;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Chromium with its DevTools protocol on fds 3 (commands in) and 4
/// (replies and events out), `\0`-separated JSON.
struct Cdp {
    child: std::process::Child,
    to: std::fs::File,
    from: mpsc::Receiver<Value>,
    id: u64,
    session: Option<String>,
    /// Exceptions the page threw (`Runtime.exceptionThrown`).
    thrown: Vec<String>,
    _profile: tempfile::TempDir,
}

impl Cdp {
    fn start(chromium: &Path) -> Cdp {
        let profile = tempfile::tempdir().unwrap();
        let (mut a, mut b) = ([0; 2], [0; 2]);
        // SAFETY: two fresh pipes; the child's ends are moved to fds 3 and 4
        // between fork and exec, the parent's wrapped in Files it owns.
        unsafe {
            assert_eq!(libc::pipe(a.as_mut_ptr()), 0);
            assert_eq!(libc::pipe(b.as_mut_ptr()), 0);
        }
        let (child_in, child_out) = (a[0], b[1]);
        let mut cmd = std::process::Command::new(chromium);
        cmd.args(motion_render::viewer::CHROMIUM_FLAGS)
            .args(["--remote-debugging-pipe", "--window-size=900,700"])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg("about:blank")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
        // SAFETY: only async-signal-safe calls (fcntl, dup2) in the child.
        unsafe {
            cmd.pre_exec(move || {
                let i = libc::fcntl(child_in, libc::F_DUPFD, 10);
                let o = libc::fcntl(child_out, libc::F_DUPFD, 10);
                if i < 0 || o < 0 || libc::dup2(i, 3) < 0 || libc::dup2(o, 4) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = cmd.spawn().expect("starting chromium");
        // SAFETY: the parent's ends, owned from here on; the child's closed.
        let (to, mut from) = unsafe {
            libc::close(child_in);
            libc::close(child_out);
            (
                std::fs::File::from_raw_fd(a[1]),
                std::fs::File::from_raw_fd(b[0]),
            )
        };
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let (mut buf, mut chunk) = (Vec::new(), [0u8; 65536]);
            while let Ok(n) = from.read(&mut chunk) {
                if n == 0 {
                    break;
                }
                buf.extend_from_slice(&chunk[..n]);
                while let Some(end) = buf.iter().position(|&c| c == 0) {
                    let msg: Vec<u8> = buf.drain(..=end).collect();
                    if let Ok(v) = serde_json::from_slice(&msg[..end]) {
                        if tx.send(v).is_err() {
                            return;
                        }
                    }
                }
            }
        });
        Cdp {
            child,
            to,
            from: rx,
            id: 0,
            session: None,
            thrown: Vec::new(),
            _profile: profile,
        }
    }

    /// Sends `method` (to the page once attached) and waits for its result.
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.id += 1;
        let mut msg = json!({ "id": self.id, "method": method, "params": params });
        if let Some(s) = &self.session {
            msg["sessionId"] = json!(s);
        }
        self.to.write_all(format!("{msg}\0").as_bytes()).unwrap();
        let until = Instant::now() + Duration::from_secs(60);
        loop {
            let left = until.saturating_duration_since(Instant::now());
            let v = self
                .from
                .recv_timeout(left)
                .unwrap_or_else(|_| panic!("no reply to {method}"));
            if v["method"] == "Runtime.exceptionThrown" {
                self.thrown
                    .push(v["params"]["exceptionDetails"].to_string());
            }
            if v["id"] == json!(self.id) {
                assert!(v.get("error").is_none(), "{method}: {v}");
                return v["result"].clone();
            }
        }
    }

    /// The value of a JavaScript expression in the page.
    fn eval(&mut self, expr: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({ "expression": expr, "returnByValue": true }),
        );
        r["result"]["value"].clone()
    }

    /// A key pressed (`down`) or released, as the keyboard sends it.
    fn key(&mut self, code: &str, key: &str, vk: u32, down: bool) {
        let kind = if down { "rawKeyDown" } else { "keyUp" };
        self.call(
            "Input.dispatchKeyEvent",
            json!({ "type": kind, "code": code, "key": key, "windowsVirtualKeyCode": vk }),
        );
    }

    fn hold(&mut self, code: &str, key: &str, vk: u32, secs: f64) {
        self.key(code, key, vk, true);
        std::thread::sleep(Duration::from_secs_f64(secs));
        self.key(code, key, vk, false);
    }

    fn state(&mut self) -> Value {
        self.eval("window.play.state")
    }
}

impl Drop for Cdp {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn angle_deg(a: &Value, b: &Value) -> f64 {
    let v = |x: &Value, i: usize| x[i].as_f64().unwrap();
    let cross = v(a, 1) * v(b, 0) - v(a, 0) * v(b, 1);
    let dot = v(a, 0) * v(b, 0) + v(a, 1) * v(b, 1);
    cross.atan2(dot).to_degrees()
}

fn sub(a: &Value, b: &Value) -> [f64; 2] {
    [0, 1].map(|i| a[i].as_f64().unwrap() - b[i].as_f64().unwrap())
}

/// Whether the page test can run: Chromium and a WebAssembly toolchain
/// (mandatory under CI, which sets `MOCAP_REQUIRE_CHROMIUM`).
fn chromium() -> Option<std::path::PathBuf> {
    let c = motion_render::viewer::find_chromium();
    if c.is_none() {
        assert!(
            std::env::var_os("MOCAP_REQUIRE_CHROMIUM").is_none(),
            "MOCAP_REQUIRE_CHROMIUM is set but no chromium is on PATH (apt-get install chromium)"
        );
        eprintln!("SKIPPED the page test: no chromium on PATH (Debian: apt-get install chromium)");
    }
    c
}

#[test]
fn the_page_steers_the_model_with_the_keys() {
    integration_tests::require_samples!();
    let Some(chromium) = chromium() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let trained = std::env::var_os("MOCAP_PLAY_RUN").map(std::path::PathBuf::from);
    let run = match &trained {
        Some(r) => r.clone(),
        None => {
            let ds = tmp.path().join("ds");
            small_dataset(&six_takes(tmp.path()), &ds);
            let run = tmp.path().join("run");
            let ok = xtask()
                .args([
                    "train",
                    "--quiet",
                    "--batch",
                    "8",
                    "--epochs",
                    "2",
                    "--condition",
                    "category+pace+control",
                    "--data",
                ])
                .arg(&ds)
                .arg("--out")
                .arg(&run)
                .status()
                .unwrap();
            assert!(ok.success());
            run
        }
    };
    let page = tmp.path().join("play.html");
    // From the workspace's root, where a run's relative dataset path points.
    let o = xtask()
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join(".."))
        .args(["play", "--run"])
        .arg(&run)
        .arg("--out")
        .arg(&page)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    if !o.status.success() && err.contains("no Rust toolchain for wasm32") {
        assert!(
            std::env::var_os("MOCAP_REQUIRE_CHROMIUM").is_none(),
            "{err}"
        );
        eprintln!("SKIPPED the page test: {err}");
        return;
    }
    assert!(o.status.success(), "{err}");

    let mut cdp = Cdp::start(&chromium);
    let target = cdp.call(
        "Target.createTarget",
        json!({ "url": format!("file://{}", page.display()) }),
    );
    let attached = cdp.call(
        "Target.attachToTarget",
        json!({ "targetId": target["targetId"], "flatten": true }),
    );
    cdp.session = attached["sessionId"].as_str().map(String::from);
    cdp.call("Runtime.enable", json!({}));
    let until = Instant::now() + Duration::from_secs(60);
    while cdp.eval("!!(window.play && (window.play.ready || window.play.errors.length))")
        != json!(true)
    {
        assert!(Instant::now() < until, "the page did not start in 60 s");
        std::thread::sleep(Duration::from_millis(200));
    }
    std::thread::sleep(Duration::from_secs(2));
    let s0 = cdp.state();
    assert!(s0["frame"].as_f64().unwrap() >= 30.0, "frames in 2 s: {s0}");

    // Up held: walking asked (and, on a trained model, the root moves on).
    cdp.hold("ArrowUp", "ArrowUp", 38, 2.0);
    let s1 = cdp.state();
    let ahead = sub(&s1["root"], &s0["root"]);
    let ahead =
        ahead[0] * s0["facing"][0].as_f64().unwrap() + ahead[1] * s0["facing"][1].as_f64().unwrap();
    assert!(s1["speed"].as_f64().unwrap() > 0.3, "{s1}");

    // Left held 2 s: the asked heading turns 180° to the left; both it and
    // the figure's facing are summed over states read every 0.1 s.
    cdp.key("ArrowLeft", "ArrowLeft", 37, true);
    let (mut asked, mut turned, mut prev) = (0.0, 0.0, s1.clone());
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(2) {
        std::thread::sleep(Duration::from_millis(100));
        let s = cdp.state();
        asked += angle_deg(&prev["heading"], &s["heading"]);
        turned += angle_deg(&prev["facing"], &s["facing"]);
        prev = s;
    }
    cdp.key("ArrowLeft", "ArrowLeft", 37, false);
    assert!(asked < -150.0, "asked heading turned {asked:.0}°");

    // Space: asked to stand; 2 s later, the root's speed over half a second.
    cdp.hold("Space", " ", 32, 0.05);
    std::thread::sleep(Duration::from_secs(2));
    let s3 = cdp.state();
    std::thread::sleep(Duration::from_millis(500));
    let s4 = cdp.state();
    let d = sub(&s4["root"], &s3["root"]);
    let stand = d[0].hypot(d[1]) * 30.0
        / (s4["frame"].as_f64().unwrap() - s3["frame"].as_f64().unwrap()).max(1.0);
    assert_eq!(s3["speed"].as_f64(), Some(0.0), "{s3}");

    let fps = s4["fps"].as_f64().unwrap();
    let errors = cdp.eval("window.play.errors");
    println!(
        "page: {fps:.0} frames/s possible; Up 2 s: {ahead:.2} m ahead; Left 2 s: asked {asked:.0}°, facing {turned:.0}°; 2 s after Space: {stand:.2} m/s"
    );
    assert_eq!(errors, json!([]), "the page's errors");
    assert!(cdp.thrown.is_empty(), "{:?}", cdp.thrown);
    assert!(fps >= 30.0, "{fps:.1} frames/s");
    if trained.is_some() {
        assert!(ahead > 0.25, "Up for 2 s moved the root {ahead:.2} m ahead");
        assert!(
            turned <= -60.0,
            "Left for 2 s turned the figure {turned:.0}°"
        );
        assert!(
            stand < 0.15,
            "2 s after Space the root moves at {stand:.2} m/s"
        );
    }
}
