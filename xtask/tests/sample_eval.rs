//! `cargo xtask sample` and `cargo xtask eval` on a small trained run.

mod common;

use common::{extract, six_takes, small_dataset, xtask};
use std::path::Path;

fn train(ds: &Path, run: &Path, extra: &[&str]) {
    let ok = xtask()
        .args([
            "train", "--quiet", "--batch", "8", "--epochs", "2", "--data",
        ])
        .arg(ds)
        .arg("--out")
        .arg(run)
        .args(extra)
        .status()
        .unwrap();
    assert!(ok.success());
}

/// A small dataset of six real takes and a run trained on it for 2 epochs.
fn trained_run() -> (tempfile::TempDir, std::path::PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let ds = tmp.path().join("ds");
    small_dataset(&six_takes(tmp.path()), &ds);
    let run = tmp.path().join("run");
    train(&ds, &run, &[]);
    (tmp, run)
}

fn apng_frames(path: &Path) -> (u32, u32, u32) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let r = dec.read_info().unwrap();
    let info = r.info();
    let frames = info.animation_control().map_or(1, |a| a.num_frames);
    (info.width, info.height, frames)
}

/// The 3-D viewer in headless Chromium: screenshots of both sets, and a
/// page with a JavaScript error fails. Chromium is mandatory under CI
/// (`.ci/run` sets MOCAP_REQUIRE_CHROMIUM=1); elsewhere the check is skipped
/// with a message when it is missing.
fn viewer_in_chromium(samples: &Path, tmp: &Path) {
    if motion_render::viewer::find_chromium().is_none() {
        assert!(
            std::env::var_os("MOCAP_REQUIRE_CHROMIUM").is_none(),
            "MOCAP_REQUIRE_CHROMIUM is set but no chromium is on PATH (apt-get install chromium)"
        );
        eprintln!(
            "SKIPPED the viewer check: no chromium on PATH (Debian: apt-get install chromium)"
        );
        return;
    }
    let shots = tmp.join("shots");
    let o = xtask()
        .args(["screenshot", "--frame", "20", "--html"])
        .arg(samples.join("viewer.html"))
        .arg("--out")
        .arg(&shots)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["viewer_samples.png", "viewer_pairs.png", "viewer_bvh.png"] {
        let (w, h, _) = apng_frames(&shots.join(f));
        assert_eq!((w, h), (1200, 800), "{f}");
    }
    // A page that throws is a failure.
    let broken = tmp.join("broken");
    std::fs::create_dir_all(&broken).unwrap();
    let html = std::fs::read_to_string(samples.join("viewer.html")).unwrap();
    std::fs::write(
        broken.join("viewer.html"),
        html.replace("status('ok');", "noSuchFunction(); status('ok');"),
    )
    .unwrap();
    let o = xtask()
        .args(["screenshot", "--html"])
        .arg(broken.join("viewer.html"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("noSuchFunction"), "{err}");
}

#[test]
fn sample_and_eval_write_what_they_promise() {
    integration_tests::require_samples!();
    let (tmp, run) = trained_run();

    let sample = |out: &Path| {
        let o = xtask()
            .args([
                "sample",
                "--n",
                "3",
                "--frames",
                "40",
                "--split",
                "val",
                "--reconstruct",
                "2",
                "--run",
            ])
            .arg(&run)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let s = tmp.path().join("s");
    sample(&s);

    // Parquet: one row per motion, frame and joint.
    use polars::prelude::*;
    let df = LazyFrame::scan_parquet(
        PlRefPath::new(s.join("samples.parquet").to_string_lossy().into_owned()),
        Default::default(),
    )
    .unwrap()
    .collect()
    .unwrap();
    assert_eq!(df.height(), 3 * 40 * 19);
    let names: Vec<String> = df
        .get_column_names()
        .iter()
        .map(|c| c.to_string())
        .collect();
    assert_eq!(names, ["motion", "frame", "joint", "x", "y", "z"]);
    assert_eq!(df.column("motion").unwrap().n_unique().unwrap(), 3);

    // JSON for the viewer.
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s.join("samples.json")).unwrap()).unwrap();
    let motions = j["motions"].as_array().unwrap();
    assert_eq!(motions.len(), 3);
    assert_eq!(motions[2]["frames"].as_array().unwrap().len(), 40);
    assert_eq!(motions[2]["frames"][39].as_array().unwrap().len(), 19);
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s.join("reconstructions.json")).unwrap())
            .unwrap();
    let ids: Vec<&str> = r["motions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, ["val_000", "recon_000", "val_001", "recon_001"]);

    // Pictures: the contact sheet (one row of 3 motions × 5 time points)
    // and animations with one frame per motion frame.
    assert_eq!(apng_frames(&s.join("contact_sheet.png")), (1352, 154, 1));
    assert_eq!(apng_frames(&s.join("anim/sample_000.png")), (150, 204, 40));
    assert_eq!(
        apng_frames(&s.join("anim/val_000_vs_recon_000.png")),
        (300, 204, 32)
    );

    // The viewer is one file with its data, three.js inline, no network access.
    let html = std::fs::read_to_string(s.join("viewer.html")).unwrap();
    assert!(html.contains("\"id\":\"sample_002\"") && html.contains("\"id\":\"recon_001\""));
    assert!(html.contains("OrbitControls") && html.contains("Three.js Authors"));
    // Generated motions beside their BVH files read back.
    assert!(html.contains("\"id\":\"sample_002_bvh\""));
    for needle in ["<script src", "<link", "<img", "<iframe"] {
        assert!(!html.contains(needle), "viewer.html loads {needle}");
    }

    viewer_in_chromium(&s, tmp.path());

    // Every motion as BVH, named by its id, read back by the project's reader.
    for id in ["sample_000", "sample_002", "val_000", "recon_001"] {
        let bvh = std::fs::read(s.join("bvh").join(format!("{id}.bvh"))).unwrap();
        let m = mocap_ingest::read_bvh(id, &bvh).unwrap();
        assert_eq!(m.skeleton(), mocap_ingest::SkeletonKind::Exported);
        assert_eq!(
            m.num_frames(),
            if id.starts_with("sample") { 40 } else { 32 }
        );
    }

    // `export` turns a motions Parquet back into the same BVH files.
    let ex = tmp.path().join("ex");
    let o = xtask()
        .args(["export", "--parquet"])
        .arg(s.join("reconstructions.parquet"))
        .arg("--out")
        .arg(&ex)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("reconstructions.parquet"), "{table}");
    // Float32 positions in the Parquet: the same motions to 1e-4 units, so
    // the same BVH up to the last decimals; compare the hierarchies.
    let head = |p: &Path| {
        let t = std::fs::read_to_string(p).unwrap();
        t[..t.find("MOTION").unwrap()].lines().count()
    };
    assert_eq!(
        head(&ex.join("val_001.bvh")),
        head(&s.join("bvh/val_001.bvh"))
    );
    let bad = tmp.path().join("bad.parquet");
    std::fs::write(&bad, b"not parquet").unwrap();
    let o = xtask()
        .args(["export", "--parquet"])
        .arg(&bad)
        .arg("--parquet")
        .arg(s.join("samples.parquet"))
        .arg("--out")
        .arg(&ex)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.parquet") && err.contains("1 of 2 files"),
        "{err}"
    );
    assert!(
        ex.join("sample_002.bvh").is_file(),
        "the good file still went through"
    );

    // Same run, same seed: the same motions.
    let s2 = tmp.path().join("s2");
    sample(&s2);
    for f in [
        "samples.json",
        "bvh/sample_001.bvh",
        "bvh/recon_001.bvh",
        "viewer.html",
    ] {
        assert_eq!(
            std::fs::read(s.join(f)).unwrap(),
            std::fs::read(s2.join(f)).unwrap(),
            "{f}"
        );
    }

    // Evaluation against the val windows.
    let e = tmp.path().join("e");
    let v = eval_val(&run, &e, &[]);
    let f = |k: &str| v[k].as_f64().unwrap_or_else(|| panic!("{k} missing"));
    assert!(v["windows"].as_u64().unwrap() > 0);
    assert!((f("recon_per_frame") + f("kl_per_frame") - f("neg_elbo_per_frame")).abs() < 1e-9);
    // Real motion is rigid: its bones keep their length.
    assert!(v["real"]["bone_cv"].as_f64().unwrap() < 1e-6);
    for set in ["real", "reconstructed", "generated"] {
        for (k, x) in v[set].as_object().unwrap() {
            assert!(x.as_f64().unwrap().is_finite(), "{set}.{k}");
        }
    }
    assert!(f("frechet_generated") >= 0.0 && f("frechet_train") >= 0.0);
    // The test-sized reference: train windows drawn as many as val has.
    let subsets = v["frechet_train_subsets"].as_array().unwrap();
    assert!(!subsets.is_empty());
    assert!(subsets.iter().all(|d| d.as_f64().unwrap() >= 0.0));
    // Within-window spread of each set: real windows move, and so do the
    // reconstructed and generated ones.
    for set in ["real", "reconstructed", "generated"] {
        assert!(v["spread"][set].as_f64().unwrap() > 0.0, "spread {set}");
    }
    // The default model places joints by forward kinematics: generated bones
    // keep the lengths of the window each motion started from.
    assert!(v["generated"]["bone_cv"].as_f64().unwrap() < 1e-4);
    for k in [
        "skate_in_contact",
        "hip_height_m",
        "hip_height_end_m",
        "root_speed_m_s",
        "root_speed_end_m_s",
    ] {
        assert!(v["real"][k].as_f64().unwrap() > 0.0, "real.{k}");
    }
    let md = std::fs::read_to_string(e.join("eval.md")).unwrap();
    assert!(md.contains(
        "| measure | real | reconstructed | generated | reconstructed / real | generated / real |"
    ));
    assert!(md.contains("| hips horizontal speed, last 32 frames, m/s |"));
    // The same motions with their planted toes pinned: the feet measured
    // after it, the hips as before, and the report says so.
    let pinned = eval_val(&run, &tmp.path().join("e-pinned"), &["--pin-feet"]);
    assert_eq!(pinned["pin_feet"], true);
    assert_eq!(v["pin_feet"], false);
    let (g, p) = (&v["generated"], &pinned["generated"]);
    for k in ["root_speed_m_s", "hip_height_m", "contact_share"] {
        assert_eq!(g[k], p[k], "{k}");
    }
    let creep = |s: &serde_json::Value| s["creep_m_s"].as_f64().unwrap();
    assert!(creep(p) <= creep(g), "{} > {}", creep(p), creep(g));
    assert_eq!(v["real"], pinned["real"]);
    let md = std::fs::read_to_string(tmp.path().join("e-pinned/eval.md")).unwrap();
    assert!(md.contains("planted toes pinned in place"), "{md}");
    let o = xtask()
        .args(["sample", "--n", "3", "--frames", "40", "--reconstruct", "0"])
        .args(["--pin-feet", "--run"])
        .arg(&run)
        .arg("--out")
        .arg(tmp.path().join("s-pinned"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("feet pinned:"), "{stdout}");

    // Generated motions start from different real frames, not one mean pose.
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s.join("samples.json")).unwrap()).unwrap();
    let firsts: std::collections::BTreeSet<String> = j["motions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["frames"][0].to_string())
        .collect();
    assert!(firsts.len() > 1, "every motion starts from the same pose");
}

/// `cargo xtask eval --split val` of `run` into `out` (with `extra`
/// options): its `eval.json`.
fn eval_val(run: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let o = xtask()
        .args(["eval", "--split", "val", "--horizon", "0"])
        .args(extra)
        .arg("--run")
        .arg(run)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).unwrap()).unwrap()
}

/// Every named model trains (one epoch), records itself in its checkpoint,
/// and goes through `sample` and `eval`; models with the skeleton part
/// generate rigid bones.
#[test]
fn every_model_trains_samples_and_evaluates() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = tmp.path().join("ds");
    small_dataset(&six_takes(tmp.path()), &ds);
    for (name, _) in motion_vrnn::model::MODELS {
        let run = tmp.path().join(name);
        let ok = xtask()
            .args(["train", "--quiet", "--batch", "8", "--epochs", "1"])
            .args(["--model", name, "--data"])
            .arg(&ds)
            .arg("--out")
            .arg(&run)
            .status()
            .unwrap();
        assert!(ok.success(), "{name}: train");
        let meta: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(run.join("last/checkpoint.json")).unwrap(),
        )
        .unwrap();
        let config: motion_vrnn::Config =
            serde_json::from_value(meta["config"]["model"].clone()).unwrap();
        assert_eq!(config.name(), Some(name), "{name}: checkpoint");
        for cmd in [
            vec!["sample", "--n", "2", "--frames", "24", "--split", "val"],
            vec!["eval", "--split", "val"]
                .into_iter()
                .chain(["--horizon", "8", "--horizon-motions", "8"])
                .collect(),
        ] {
            let o = xtask().args(&cmd).arg("--run").arg(&run).output().unwrap();
            assert!(
                o.status.success(),
                "{name} {}: {}",
                cmd[0],
                String::from_utf8_lossy(&o.stderr)
            );
        }
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("eval/eval.json")).unwrap())
                .unwrap();
        let cv = v["generated"]["bone_cv"].as_f64().unwrap();
        assert!(cv.is_finite(), "{name}");
        // Beside continuing the split's windows, as many motions from
        // training contexts, measured alike.
        let from_training = &v["from_training"]["generated"];
        assert_eq!(
            from_training["motions"], v["generated"]["motions"],
            "{name}"
        );
        assert!(v["from_training"]["frechet"].as_f64().unwrap().is_finite());
        // The long horizon: 8 s of 32-frame windows is 7 stretches, each of
        // the 8 motions, against every real window (train and val here).
        let h = &v["horizon"];
        let stretches = h["stretches"].as_array().unwrap();
        assert_eq!(stretches.len(), 7, "{name}");
        assert!(stretches.iter().all(|s| s["generated"]["motions"] == 8));
        let second = stretches[1]["start_s"].as_f64().unwrap();
        assert!((second - 32.0 / 30.0).abs() < 1e-9, "{second}");
        assert_eq!(h["real_spread"].as_array().unwrap().len(), 9);
        assert!(h["real_windows"].as_u64().unwrap() >= 2);
        if config.parts.skeleton {
            let last = stretches[6]["generated"]["bone_cv"].as_f64().unwrap();
            assert!(
                last < 1e-4,
                "{name}: bones stretch late in the rollout: {last}"
            );
        }
        if config.parts.skeleton {
            assert!(cv < 1e-4, "{name}: bone cv {cv}");
        } else {
            assert!(cv > 1e-4, "{name}: bone cv {cv}");
        }
        assert!(run.join("samples/contact_sheet.png").exists(), "{name}");
        // The report says at which temperature it sampled: the model's, or
        // the one asked for.
        let own = config.parts.temperature.unwrap_or(1.0);
        assert_eq!(v["temperature"].as_f64(), Some(own), "{name}");
        if name == "motion" {
            let t1 = eval_val(&run, &run.join("eval-t1"), &["--temperature", "1"]);
            assert_eq!(t1["temperature"].as_f64(), Some(1.0));
            assert_ne!(
                t1["generated"], v["generated"],
                "the temperature changed nothing"
            );
            let bad = xtask()
                .args(["eval", "--split", "val", "--temperature", "0", "--run"])
                .arg(&run)
                .output()
                .unwrap();
            assert!(!bad.status.success());
            assert!(String::from_utf8_lossy(&bad.stderr).contains("temperature must be positive"));
        }
    }
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

#[test]
fn continue_extends_real_clips_and_its_own_bvh_without_a_jump() {
    integration_tests::require_samples!();
    let (tmp, run) = trained_run();
    let inputs = tmp.path().join("in");
    let mb = extract(
        "cmu-bvh-sample.zip",
        "cmu-bvh-motionbuilder/02/02_01.bvh",
        &inputs,
    );
    extract(
        "cmu-asfamc-sample.zip",
        "all_asfamc/subjects/01/01.asf",
        &inputs,
    );
    let amc = extract(
        "cmu-asfamc-sample.zip",
        "all_asfamc/subjects/01/01_01.amc",
        &inputs,
    );
    let daz = extract(
        "cmu-bvh-daz-sample.zip",
        "cmu-bvh-daz/08/08_11.bvh",
        &inputs,
    );
    let cont = |input: &Path, out: &Path, extra: &[&str]| {
        xtask()
            .arg("continue")
            .arg("--run")
            .arg(&run)
            .arg("--input")
            .arg(input)
            .arg("--out")
            .arg(out)
            .args(extra)
            .output()
            .unwrap()
    };
    let outs = tmp.path().join("out");
    let mine = outs.join("mb.bvh");
    for (input, out) in [
        (&mb, mine.clone()),
        (&amc, outs.join("amc.bvh")),
        (&daz, outs.join("daz.bvh")),
        (&mine, outs.join("again.bvh")),
    ] {
        let o = cont(input, &out, &["--seconds", "2"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(stdout.contains("seam step"), "{stdout}");
        // The clip as the pipeline sees it, then 2 s (60 frames) more.
        let (_, _, clip) = mocap_ingest::clip_of_file(input, None, &Default::default()).unwrap();
        let n = clip.features.len();
        let expected = mocap_ingest::features::to_global(&clip.features);
        let back = motion_render::bvh::read_motion(&out, "back").unwrap();
        assert_eq!(back.poses.len(), n + 60, "{}", out.display());
        let text = std::fs::read(&out).unwrap();
        let b = bvh_anim::from_bytes(&text[..]).unwrap();
        assert_eq!(b.frames().len(), n + 60);
        // The clip's frames are the clip's, up to the one skeleton a BVH
        // file has: the mean bone lengths of clip and generated frames
        // (the model takes its bones from the context: a few mm apart).
        let worst = (0..n)
            .flat_map(|f| (0..19).map(move |j| (f, j)))
            .map(|(f, j)| dist(&back.poses[f][j], &expected[f][j]))
            .fold(0.0, f64::max);
        eprintln!("{}: clip frames within {worst:.4} units", out.display());
        assert!(
            worst < 0.25,
            "{}: clip frames moved by {worst}",
            out.display()
        );
        // No jump at the seam: joints step no further there than the clip's
        // largest step or the generated motion's next steps, give or take a
        // quarter (without the easing in the model, 4.7 times that here).
        let step = |f: usize| -> f64 {
            (0..19)
                .map(|j| dist(&back.poses[f][j], &back.poses[f - 1][j]))
                .sum::<f64>()
                / 19.0
        };
        let clip_max = (1..n).map(step).fold(0.0, f64::max);
        let next: Vec<f64> = (n + 1..n + 6).map(step).collect();
        let around = next.iter().copied().fold(clip_max, f64::max);
        assert!(
            step(n) <= 1.25 * around,
            "{}: the seam steps {} (clip's largest step {clip_max}, next frames {next:?})",
            out.display(),
            step(n)
        );
    }
    // Variations: one file per seed, the same clip, different futures;
    // the same seed gives the same bytes.
    let o = cont(
        &mb,
        &outs.join("v.bvh"),
        &["--seconds", "1", "--variations", "2", "--seed", "5"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Vec<Vec<u8>> = ["v_0.bvh", "v_1.bvh"]
        .iter()
        .map(|f| std::fs::read(outs.join(f)).unwrap())
        .collect();
    assert_ne!(v[0], v[1]);
    let o = cont(&mb, &outs.join("w.bvh"), &["--seconds", "1", "--seed", "5"]);
    assert!(o.status.success());
    assert_eq!(std::fs::read(outs.join("w.bvh")).unwrap(), v[0]);
    // Feet pinned: the clip's frames as they were (up to the BVH's one
    // skeleton, which the legs bent by IK move a little), the same length.
    let o = cont(
        &mb,
        &outs.join("p.bvh"),
        &["--seconds", "1", "--seed", "5", "--pin-feet"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("feet pinned:"), "{stdout}");
    let read = |f: &str| motion_render::bvh::read_motion(&outs.join(f), f).unwrap();
    let (p, w) = (read("p.bvh"), read("w.bvh"));
    assert_eq!(p.poses.len(), w.poses.len());
    let n = mocap_ingest::clip_of_file(&mb, None, &Default::default())
        .unwrap()
        .2
        .features
        .len();
    let worst = (0..n)
        .flat_map(|f| (0..19).map(move |j| (f, j)))
        .map(|(f, j)| dist(&p.poses[f][j], &w.poses[f][j]))
        .fold(0.0, f64::max);
    assert!(worst < 0.25, "pinning moved the clip's frames by {worst}");
    // Clear errors.
    let err = |o: std::process::Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    for bad in ["0", "-1", "NaN", "1e9"] {
        let e = err(cont(
            &mb,
            &outs.join("x.bvh"),
            &[&format!("--seconds={bad}")],
        ));
        assert!(e.contains("--seconds must be positive"), "{bad}: {e}");
    }
    let e = err(cont(&tmp.path().join("none.bvh"), &outs.join("x.bvh"), &[]));
    assert!(e.contains("none.bvh") && e.contains("no such file"), "{e}");
    let bad = inputs.join("bad.bvh");
    std::fs::write(&bad, "HIERARCHY\nROOT Hips {\n").unwrap();
    let e = err(cont(&bad, &outs.join("x.bvh"), &[]));
    assert!(e.contains("bad.bvh"), "{e}");
    // One frame: the T-pose line and a single frame of 02_01.
    let text = std::fs::read_to_string(&mb).unwrap();
    let (head, motion) = text.split_once("MOTION").unwrap();
    let lines: Vec<&str> = motion.lines().collect();
    let frame_time = lines.iter().find(|l| l.starts_with("Frame Time")).unwrap();
    let body: Vec<&str> = lines
        .iter()
        .skip_while(|l| !l.starts_with("Frame Time"))
        .skip(1)
        .take(2)
        .copied()
        .collect();
    let short = inputs.join("short.bvh");
    std::fs::write(
        &short,
        format!(
            "{head}MOTION\nFrames: 2\n{frame_time}\n{}\n",
            body.join("\n")
        ),
    )
    .unwrap();
    let e = err(cont(&short, &outs.join("x.bvh"), &[]));
    assert!(e.contains("short.bvh") || e.contains("at least 2"), "{e}");
    let o = xtask()
        .args(["continue", "--run"])
        .arg(tmp.path().join("no-run"))
        .arg("--input")
        .arg(&mb)
        .arg("--out")
        .arg(outs.join("x.bvh"))
        .output()
        .unwrap();
    let e = err(o);
    assert!(e.contains("no checkpoint"), "{e}");
}

#[test]
fn eval_measures_generated_motion_with_the_classifier() {
    integration_tests::require_samples!();
    let (tmp, run) = trained_run();
    let (ds, clf) = (tmp.path().join("ds"), tmp.path().join("clf"));
    let o = xtask()
        .args(["train-classifier", "--epochs", "2", "--data"])
        .arg(&ds)
        .arg("--out")
        .arg(&clf)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eval = |out: &Path| {
        let o = xtask()
            .args(["eval", "--horizon", "0", "--split", "val", "--run"])
            .arg(&run)
            .arg("--classifier")
            .arg(&clf)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(out.join("eval.json")).unwrap()
    };
    let text = eval(&tmp.path().join("e1"));
    let j: serde_json::Value = serde_json::from_str(&text).unwrap();
    let c = &j["classifier"];
    assert_eq!(c["motions"], 256);
    for key in ["frechet_generated", "frechet_train"] {
        assert!(c[key].as_f64().is_some_and(f64::is_finite), "{key}: {c}");
    }
    // Every window, real or generated, lands in one category.
    for key in ["real", "real_recognised", "generated"] {
        let sum: f64 = c["shares"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s[key].as_f64().unwrap())
            .sum();
        assert!((sum - 1.0).abs() < 1e-9, "{key}: {sum}");
    }
    let md = std::fs::read_to_string(tmp.path().join("e1/eval.md")).unwrap();
    assert!(md.contains("Seen by the motion classifier"), "{md}");
    // The same run, classifier and seed: the same report.
    assert_eq!(eval(&tmp.path().join("e2")), text);
}

/// A run trained on the small dataset with `--condition condition` under
/// `dir`: the dataset, the run and its `best` checkpoint's metadata.
fn conditioned_run(
    dir: &Path,
    condition: &str,
) -> (std::path::PathBuf, std::path::PathBuf, serde_json::Value) {
    let ds = dir.join("ds");
    small_dataset(&six_takes(dir), &ds);
    let run = dir.join("cond");
    train(&ds, &run, &["--condition", condition]);
    let meta = std::fs::read_to_string(run.join("best/checkpoint.json")).unwrap();
    (ds, run, serde_json::from_str(&meta).unwrap())
}

/// `train --condition category` records the categories of its training
/// windows; `sample --category` asks for one of them; an unknown name, a
/// category the model has not seen and an unconditioned run each say what
/// can be asked instead.
#[test]
fn a_conditioned_run_samples_the_category_asked_for() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let (ds, run, meta) = conditioned_run(tmp.path(), "category");
    let known: Vec<String> = meta["config"]["model"]["categories"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap().to_string())
        .collect();
    assert!(!known.is_empty());
    // `sample` with these options (none: as a user would call it).
    let sample_with = |run: &Path, options: &[&str], out: &str| {
        xtask()
            .args(["sample", "--n", "2", "--frames", "20", "--split", "val"])
            .args(options)
            .arg("--run")
            .arg(run)
            .arg("--out")
            .arg(tmp.path().join(out))
            .output()
            .unwrap()
    };
    let sample =
        |run: &Path, category: &str, out: &str| sample_with(run, &["--category", category], out);
    let o = sample(&run, &known[0], "asked");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(tmp.path().join("asked/samples.parquet").is_file());
    let err = |o: std::process::Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let e = err(sample(&run, "salsa", "bad"));
    assert!(
        e.contains("unknown category") && e.contains("gesture"),
        "{e}"
    );
    let absent = [
        "walk", "run", "jump", "dance", "sport", "play", "floor", "gesture", "other",
    ]
    .into_iter()
    .find(|c| !known.iter().any(|k| k == c))
    .unwrap();
    let e = err(sample(&run, absent, "bad"));
    assert!(
        e.contains("not trained with") && e.contains(&known[0]),
        "{e}"
    );
    // An unconditioned run cannot be asked.
    let plain = tmp.path().join("plain");
    train(&ds, &plain, &["--condition", "none"]);
    let e = err(sample(&plain, &known[0], "bad"));
    assert!(e.contains("--condition category"), "{e}");
    // Without --category both sample as before; the conditioned run also
    // draws one row per category.
    for (r, out, conditioned) in [(&run, "free", true), (&plain, "free_plain", false)] {
        let o = sample_with(r, &[], out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let sheet = tmp.path().join(out).join("category_sheet.png");
        assert_eq!(sheet.is_file(), conditioned, "{}", sheet.display());
    }
    // `continue --category` asks too, and differs from the same seed unasked.
    let clip = extract(
        "cmu-bvh-sample.zip",
        "cmu-bvh-motionbuilder/02/02_01.bvh",
        &tmp.path().join("in"),
    );
    let cont = |extra: &[&str], out: &str| {
        let o = xtask()
            .args(["continue", "--seconds", "1", "--run"])
            .arg(&run)
            .arg("--input")
            .arg(&clip)
            .arg("--out")
            .arg(tmp.path().join(out))
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(tmp.path().join(out)).unwrap()
    };
    let asked = cont(&["--category", &known[0]], "asked.bvh");
    assert_ne!(asked, cont(&[], "free.bvh"));
    assert_eq!(asked, cont(&["--category", &known[0]], "again.bvh"));
    // A clip has no category to take as its own.
    let o = xtask()
        .args(["continue", "--seconds", "1", "--category", "own", "--run"])
        .arg(&run)
        .arg("--input")
        .arg(&clip)
        .arg("--out")
        .arg(tmp.path().join("own.bvh"))
        .output()
        .unwrap();
    assert!(err(o).contains("a clip has none"));
    // Without --category a conditioned run's motions ask for their
    // contexts' own categories; `none` asks for none.
    let parquet = |out: &str| std::fs::read(tmp.path().join(out).join("samples.parquet")).unwrap();
    assert!(sample(&run, "own", "own").status.success());
    assert!(sample(&run, "none", "none").status.success());
    assert_eq!(parquet("own"), parquet("free"));
    assert_ne!(parquet("none"), parquet("free"));
    // They ask at guidance 1.4 (`generate::GUIDANCE`, chosen on `val`);
    // 1 is the model as trained, another motion.
    for (g, out) in [("1.4", "g14"), ("1", "g1")] {
        let o = sample_with(&run, &["--guidance", g], out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert_eq!(parquet("g14"), parquet("free"));
    assert_ne!(parquet("g1"), parquet("free"));
    let (_, h, _) = apng_frames(&tmp.path().join("free/category_sheet.png"));
    let (_, h1, _) = apng_frames(&tmp.path().join("free/contact_sheet.png"));
    assert!(
        known.len() < 2 || h > h1,
        "one row per category: {h} vs {h1}"
    );
}

/// `train --condition category+pace` records the pace part; such a run
/// samples, is evaluated and continues a clip through the same commands.
#[test]
fn a_paced_run_samples_evaluates_and_continues() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let (_, run, meta) = conditioned_run(tmp.path(), "category+pace");
    assert_eq!(meta["config"]["model"]["parts"]["pace"], true);
    let ok = |args: &[&str], out: &str| {
        let o = xtask()
            .args(args)
            .arg("--run")
            .arg(&run)
            .arg("--out")
            .arg(tmp.path().join(out))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    ok(
        &["sample", "--n", "2", "--frames", "20", "--split", "val"],
        "s",
    );
    ok(&["eval", "--horizon", "0", "--split", "val"], "e");
    // The report says what guidance its motions asked at; none where they
    // asked for no category.
    let report = |out: &str| -> serde_json::Value {
        let text = std::fs::read_to_string(tmp.path().join(out).join("eval.json")).unwrap();
        serde_json::from_str(&text).unwrap()
    };
    assert_eq!(report("e")["guidance"], 1.4);
    let md = std::fs::read_to_string(tmp.path().join("e/eval.md")).unwrap();
    assert!(md.contains("asked at guidance 1.4"), "{md}");
    ok(
        &[
            "eval",
            "--horizon",
            "0",
            "--split",
            "val",
            "--category",
            "none",
        ],
        "e-none",
    );
    assert!(report("e-none").get("guidance").is_none());
    let clip = extract(
        "cmu-bvh-sample.zip",
        "cmu-bvh-motionbuilder/02/02_01.bvh",
        &tmp.path().join("in"),
    );
    let clip = clip.to_str().unwrap();
    ok(&["continue", "--seconds", "1", "--input", clip], "c.bvh");
    let e = xtask()
        .args(["train", "--condition", "pace"])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&e.stderr);
    assert!(e.contains("category+pace"), "{e}");
}

/// Choices made on `val` never read `test`: `eval --split val` measures its
/// minute against the train and val windows alone, `--split test` (the
/// report) against every split.
#[test]
fn val_references_never_read_a_test_window() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let ds = tmp.path().join("ds");
    let ok = xtask()
        .args(["dataset", "--quiet", "--window", "32", "--stride", "16"])
        .args(["--split", "0.4,0.3,0.3", "--source"])
        .arg(six_takes(tmp.path()))
        .arg("--out")
        .arg(&ds)
        .status()
        .unwrap();
    assert!(ok.success());
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ds.join("manifest.json")).unwrap()).unwrap();
    let windows = |s: &str| manifest["counts"]["windows_per_split"][s].as_u64().unwrap();
    let (train_n, val_n, test_n) = (windows("train"), windows("val"), windows("test"));
    assert!(train_n > 0 && val_n > 0 && test_n > 0, "{manifest}");
    let run = tmp.path().join("run");
    train(&ds, &run, &[]);
    let real_windows = |split: &str| {
        let out = tmp.path().join(format!("e-{split}"));
        let o = xtask()
            .args([
                "eval",
                "--split",
                split,
                "--horizon",
                "3",
                "--horizon-motions",
                "4",
            ])
            .arg("--run")
            .arg(&run)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).unwrap()).unwrap();
        j["horizon"]["real_windows"].as_u64().unwrap()
    };
    assert_eq!(real_windows("val"), train_n + val_n);
    assert_eq!(real_windows("test"), train_n + val_n + test_n);
}

/// The default run reads the control: `steer` follows a built-in path and
/// writes its BVH, Parquet and picture; `continue --path` steers a clip;
/// `eval --steer` measures every built-in path; a path file that does not
/// parse, a speed the data does not hold and a run without the control are
/// refused with what to do.
#[test]
fn a_run_with_the_control_steers_and_says_what_it_cannot() {
    integration_tests::require_samples!();
    let tmp = tempfile::tempdir().unwrap();
    let (_, run, meta) = conditioned_run(tmp.path(), "category+pace+control");
    assert_eq!(meta["config"]["model"]["parts"]["control"], true);
    let steer = |extra: &[&str]| {
        xtask()
            .arg("steer")
            .arg("--run")
            .arg(&run)
            .args(extra)
            .output()
            .unwrap()
    };
    let out = tmp.path().join("s").join("line.bvh");
    let o = steer(&[
        "--path",
        "line:3",
        "--n",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("path error"));
    for f in ["line_0.bvh", "line_1.bvh", "line.parquet", "line.png"] {
        assert!(tmp.path().join("s").join(f).is_file(), "{f}");
    }
    let bad = tmp.path().join("bad.csv");
    std::fs::write(&bad, "x,z\n0,0\n1,abc\n").unwrap();
    let refused = |args: &[&str], expected: &str| {
        let o = steer(&[args, &["--out", out.to_str().unwrap()]].concat());
        assert!(!o.status.success());
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(expected), "{e}");
    };
    refused(&["--path", bad.to_str().unwrap()], "bad.csv:3: expected");
    refused(&["--path", "line:3", "--speed", "50"], "ask at most");
    refused(&["--path", "spiral:3"], "the built-ins are");
    let clip = extract(
        "cmu-bvh-sample.zip",
        "cmu-bvh-motionbuilder/02/02_01.bvh",
        &tmp.path().join("in"),
    );
    let o = xtask()
        .args(["continue", "--seconds", "2", "--path", "line:1", "--input"])
        .arg(&clip)
        .arg("--run")
        .arg(&run)
        .arg("--out")
        .arg(tmp.path().join("c.bvh"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let e = tmp.path().join("e");
    let o = xtask()
        .args(["eval", "--steer", "--run"])
        .arg(&run)
        .arg("--out")
        .arg(&e)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(e.join("steer.json")).unwrap()).unwrap();
    assert_eq!(report["paths"].as_array().unwrap().len(), 4);
    assert!(e.join("steer-zigzag-4.png").is_file());
    // A run without the control cannot follow a path.
    let (_, paced, _) = conditioned_run(&tmp.path().join("p"), "category+pace");
    let o = xtask()
        .args(["steer", "--path", "line:3", "--out", "x.bvh", "--run"])
        .arg(&paced)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("trained without the control"),
        "{e}"
    );
}
