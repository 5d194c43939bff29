//! `cargo xtask sample` and `cargo xtask eval`: motions from a trained run,
//! back in global coordinates, written as Parquet + JSON, drawn (contact
//! sheet, animated PNGs, an HTML viewer) and measured (`docs/metrics.md`).

use crate::plot::{save_apng, save_png, Canvas};
use anyhow::{bail, Context, Result};
use candle_core::Device;
use clap::Args;
use mocap_ingest::features::{to_global, FeatureVec, NUM_FEATURES};
use mocap_ingest::skeleton::{Pose, JOINT_NAMES, JOINT_PARENTS, NUM_JOINTS};
use motion_metrics::{motion_stats, window_summary, MotionStats, Options};
use motion_vrnn::data::{Dataset, Stats, Windows};
use motion_vrnn::train::{evaluate, layout, load_model, noise, CheckpointMeta, Trained};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Where a run's model and data come from.
#[derive(Args, Debug, Clone)]
pub struct RunArgs {
    /// Run directory written by `cargo xtask train`.
    #[arg(long, default_value = "runs/vrnn")]
    run: PathBuf,
    /// Checkpoint inside the run: `best` or `last`.
    #[arg(long, default_value = layout::BEST)]
    checkpoint: String,
    /// Dataset directory (default: the one the run was trained on).
    #[arg(long)]
    data: Option<PathBuf>,
    /// Seed of the sampling noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Split of real windows to reconstruct and compare with.
    #[arg(long, default_value = "test")]
    split: String,
}

/// `cargo xtask sample` options.
#[derive(Args, Debug)]
pub struct SampleArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Motions to sample from the prior.
    #[arg(long, default_value_t = 36)]
    n: usize,
    /// Frames per motion (30 fps).
    #[arg(long, default_value_t = 128)]
    frames: usize,
    /// Windows of `--split` to reconstruct (encode, decode) beside the real ones.
    #[arg(long, default_value_t = 4)]
    reconstruct: usize,
    /// Output directory (default: RUN/samples).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// `cargo xtask eval` options.
#[derive(Args, Debug)]
pub struct EvalArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Output directory for eval.json and eval.md (default: RUN/eval).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// One motion in global coordinates (CMU units, floor at y = 0, 30 fps).
pub struct Motion {
    /// Identifier (`sample_007`, `test_003`, `recon_003`).
    pub id: String,
    /// Joint positions per frame.
    pub poses: Vec<Pose>,
}

struct Loaded {
    model: Trained,
    meta: CheckpointMeta,
    data: Dataset,
    device: Device,
}

fn load(a: &RunArgs, splits: &[&str]) -> Result<Loaded> {
    let device = motion_vrnn::model::default_device();
    let ck = a.run.join(&a.checkpoint);
    if !ck.join(layout::META).exists() {
        bail!(
            "{}: no checkpoint here; train one with `cargo xtask train --out {}` (or pass --run / --checkpoint)",
            ck.display(),
            a.run.display()
        );
    }
    let (model, meta) =
        load_model(&ck, &device).with_context(|| format!("loading {}", ck.display()))?;
    let dir = a
        .data
        .clone()
        .unwrap_or_else(|| PathBuf::from(&meta.dataset));
    let data = motion_vrnn::data::load(&dir, splits)
        .with_context(|| format!("loading the dataset {} (pass --data DIR)", dir.display()))?;
    if data.manifest_sha256 != meta.dataset_manifest_sha256 {
        eprintln!(
            "warning: {} is not the dataset this run was trained on (manifest hash differs)",
            dir.display()
        );
    }
    Ok(Loaded {
        model,
        meta,
        data,
        device,
    })
}

/// Normalised features `[T × 58]` → global joint positions.
fn to_poses(x: &[f32], stats: &Stats) -> Vec<Pose> {
    let frames: Vec<FeatureVec> = x
        .chunks(NUM_FEATURES)
        .map(|r| {
            let mut f = [0.0; NUM_FEATURES];
            for (k, v) in f.iter_mut().enumerate() {
                *v = r[k] as f64 * stats.std[k] + stats.mean[k];
            }
            f
        })
        .collect();
    to_global(&frames)
}

/// Normalised features `[T × 58]` → a named global motion.
fn to_motion(id: String, x: &[f32], stats: &Stats) -> Motion {
    Motion {
        id,
        poses: to_poses(x, stats),
    }
}

/// `n` windows sampled from the prior, normalised `[n][T × 58]`.
fn sample_windows(m: &Loaded, n: usize, frames: usize, seed: u64) -> Result<Vec<Vec<f32>>> {
    let latent = m.model.model.config().latent;
    let eps = noise(seed ^ 0x5A3F1E, 0, frames, n, latent, &m.device)?;
    let x = m.model.model.sample(&eps)?;
    let v = x.flatten_all()?.to_vec1::<f32>()?;
    Ok(v.chunks(frames * NUM_FEATURES)
        .map(<[f32]>::to_vec)
        .collect())
}

/// Real windows `idx` of a split and their reconstructions, normalised.
/// Normalised windows, one `[T × 58]` vector each.
type WindowSet = Vec<Vec<f32>>;

fn reconstruct(m: &Loaded, w: &Windows, idx: &[usize]) -> Result<(WindowSet, WindowSet)> {
    let per = w.length * w.features;
    let mut real = Vec::new();
    let mut rec = Vec::new();
    for chunk in idx.chunks(256) {
        let x = w.batch(chunk, &m.device)?;
        let r = m.model.model.reconstruct(&x)?;
        real.extend(
            x.flatten_all()?
                .to_vec1::<f32>()?
                .chunks(per)
                .map(<[f32]>::to_vec),
        );
        rec.extend(
            r.flatten_all()?
                .to_vec1::<f32>()?
                .chunks(per)
                .map(<[f32]>::to_vec),
        );
    }
    Ok((real, rec))
}

fn split<'a>(m: &'a Loaded, name: &str) -> Result<&'a Windows> {
    m.data
        .splits
        .get(name)
        .filter(|w| w.n > 0)
        .with_context(|| format!("{}: no {name} windows", m.data.dir.display()))
}

/// `cargo xtask sample`.
pub fn sample(a: SampleArgs) -> Result<()> {
    if a.n == 0 || a.frames == 0 {
        bail!("--n and --frames must be positive");
    }
    let m = load(&a.run, &[&a.run.split])?;
    let out = a.out.clone().unwrap_or_else(|| a.run.run.join("samples"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let started = std::time::Instant::now();
    let gen = sample_windows(&m, a.n, a.frames, a.run.seed)?;
    let motions: Vec<Motion> = gen
        .iter()
        .enumerate()
        .map(|(k, x)| to_motion(format!("sample_{k:03}"), x, &m.data.stats))
        .collect();
    println!(
        "sampled {} motions x {} frames from {} ({} epoch {}) in {:.2} s",
        a.n,
        a.frames,
        a.run.run.join(&a.run.checkpoint).display(),
        a.run.checkpoint,
        m.meta.epoch,
        started.elapsed().as_secs_f64()
    );
    write_motions(&out, "samples", &motions)?;
    contact_sheet(
        &out.join("contact_sheet.png"),
        &motions,
        &[0, 30, 60, 90, 120],
    )?;
    let anim = out.join("anim");
    std::fs::create_dir_all(&anim)?;
    for mo in &motions {
        animation(&anim.join(format!("{}.png", mo.id)), &[mo])?;
    }
    let mut sets = vec![("samples", &motions[..])];
    let mut pairs = Vec::new();
    if a.reconstruct > 0 {
        let w = split(&m, &a.run.split)?;
        let idx: Vec<usize> = (0..w.n.min(a.reconstruct)).collect();
        let (real, rec) = reconstruct(&m, w, &idx)?;
        for (k, (r, x)) in real.iter().zip(&rec).enumerate() {
            pairs.push(to_motion(
                format!("{}_{k:03}", a.run.split),
                r,
                &m.data.stats,
            ));
            pairs.push(to_motion(format!("recon_{k:03}"), x, &m.data.stats));
        }
        write_motions(&out, "reconstructions", &pairs)?;
        for pair in pairs.chunks(2) {
            animation(
                &anim.join(format!("{}_vs_{}.png", pair[0].id, pair[1].id)),
                &[&pair[0], &pair[1]],
            )?;
        }
        sets.push(("real vs reconstruction", &pairs[..]));
    }
    write_viewer(&out.join("viewer.html"), &sets)?;
    println!("wrote {}:", out.display());
    println!(
        "  samples.parquet, samples.json   motions (motion, frame, joint, x, y, z; CMU units)"
    );
    if !pairs.is_empty() {
        println!(
            "  reconstructions.parquet/.json   {} real {} windows and their reconstructions",
            pairs.len() / 2,
            a.run.split
        );
    }
    println!("  contact_sheet.png               stick figures at frames 0, 30, 60, 90, 120");
    println!(
        "  anim/*.png                      animated PNG per motion (and real vs reconstruction)"
    );
    println!("  viewer.html                     open in a browser: play/pause, frame slider");
    Ok(())
}

/// What `eval.json` holds.
#[derive(Serialize)]
struct EvalReport {
    run: String,
    checkpoint: String,
    epoch: usize,
    dataset: String,
    split: String,
    seed: u64,
    windows: usize,
    frames: usize,
    /// Per frame, on the split, with the training noise convention.
    neg_elbo_per_frame: f64,
    recon_per_frame: f64,
    kl_per_frame: f64,
    real: MotionStats,
    reconstructed: MotionStats,
    generated: MotionStats,
    /// Generated over real.
    jerk_ratio: f64,
    high_freq_ratio: f64,
    frechet_generated: f64,
    frechet_reconstructed: f64,
    /// Reference: train windows against the split.
    frechet_train: f64,
    options: Options,
}

/// `cargo xtask eval`.
pub fn eval(a: EvalArgs) -> Result<()> {
    let m = load(&a.run, &["train", &a.run.split])?;
    let w = split(&m, &a.run.split)?;
    let out = a.out.clone().unwrap_or_else(|| a.run.run.join("eval"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let started = std::time::Instant::now();
    let (recon, kl) = evaluate(&m.model.model, w, 256, a.run.seed, &m.device)?;
    let t = w.length as f64;
    let idx: Vec<usize> = (0..w.n).collect();
    let (real, rec) = reconstruct(&m, w, &idx)?;
    let gen = sample_windows(&m, w.n, w.length, a.run.seed)?;
    let global = |set: &[Vec<f32>]| -> Vec<Vec<Pose>> {
        set.iter().map(|x| to_poses(x, &m.data.stats)).collect()
    };
    let o = Options::default();
    let (sr, sc, sg) = (
        motion_stats(&global(&real), &o),
        motion_stats(&global(&rec), &o),
        motion_stats(&global(&gen), &o),
    );
    let summaries = |set: &[Vec<f32>]| -> Vec<Vec<f64>> {
        set.iter()
            .map(|x| {
                let rows: Vec<Vec<f32>> = x.chunks(NUM_FEATURES).map(<[f32]>::to_vec).collect();
                window_summary(&rows)
            })
            .collect()
    };
    let train = split(&m, "train")?;
    let train_windows: Vec<Vec<f32>> = train
        .data
        .chunks(train.length * train.features)
        .map(<[f32]>::to_vec)
        .collect();
    let s_real = summaries(&real);
    let report = EvalReport {
        run: a.run.run.display().to_string(),
        checkpoint: a.run.checkpoint.clone(),
        epoch: m.meta.epoch,
        dataset: m.data.dir.display().to_string(),
        split: a.run.split.clone(),
        seed: a.run.seed,
        windows: w.n,
        frames: w.length,
        neg_elbo_per_frame: (recon + kl) / t,
        recon_per_frame: recon / t,
        kl_per_frame: kl / t,
        jerk_ratio: sg.jerk_m_s3 / sr.jerk_m_s3,
        high_freq_ratio: sg.high_freq_share / sr.high_freq_share,
        frechet_generated: motion_metrics::frechet(&s_real, &summaries(&gen)),
        frechet_reconstructed: motion_metrics::frechet(&s_real, &summaries(&rec)),
        frechet_train: motion_metrics::frechet(&s_real, &summaries(&train_windows)),
        real: sr,
        reconstructed: sc,
        generated: sg,
        options: o,
    };
    let json = serde_json::to_string_pretty(&report)? + "\n";
    write_atomic(&out.join("eval.json"), json.as_bytes())?;
    let md = markdown(&report);
    write_atomic(&out.join("eval.md"), md.as_bytes())?;
    print!("{md}");
    println!(
        "\nwrote {} and {} in {:.1} s",
        out.join("eval.json").display(),
        out.join("eval.md").display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn markdown(r: &EvalReport) -> String {
    let mut s = format!(
        "# Evaluation of {} ({}, epoch {})\n\nDataset {}, split `{}`: {} windows of {} frames; {} generated motions of {} frames (seed {}).\n\n",
        r.run, r.checkpoint, r.epoch, r.dataset, r.split, r.windows, r.frames, r.windows, r.frames, r.seed
    );
    s += &format!(
        "Per frame on `{}`: negative ELBO **{:.3}** = reconstruction {:.3} + KL {:.3} (normalised units).\n\n",
        r.split, r.neg_elbo_per_frame, r.recon_per_frame, r.kl_per_frame
    );
    s += "| measure | real | reconstructed | generated | generated / real |\n|---|---|---|---|---|\n";
    type Row = (&'static str, fn(&MotionStats) -> f64, usize);
    let rows: [Row; 6] = [
        ("APD, m", |m| m.apd_m, 3),
        ("mean jerk, m/s³", |m| m.jerk_m_s3, 1),
        ("power above 5 Hz", |m| m.high_freq_share, 4),
        ("bone length std / mean", |m| m.bone_cv, 4),
        ("foot skating (share of foot-frames)", |m| m.skate_share, 4),
        (
            "foot contact (share of foot-frames)",
            |m| m.contact_share,
            4,
        ),
    ];
    for (name, f, p) in rows {
        let (a, b, c) = (f(&r.real), f(&r.reconstructed), f(&r.generated));
        let ratio = if a.abs() > 1e-6 {
            format!("{:.2}", c / a)
        } else {
            "n/a (real ≈ 0)".into()
        };
        s += &format!("| {name} | {a:.p$} | {b:.p$} | {c:.p$} | {ratio} |\n");
    }
    s += &format!(
        "\nFréchet distance to the real `{}` windows (summaries: per-window mean and std of the 58 normalised features): generated **{:.2}**, reconstructed {:.2}, train windows {:.2} (reference).\n",
        r.split, r.frechet_generated, r.frechet_reconstructed, r.frechet_train
    );
    s
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::write_atomically(path, |mut f| Ok(f.write_all(bytes)?))
}

/// `NAME.parquet` (motion, frame, joint, x, y, z) and `NAME.json` (the
/// viewer's format, `docs/metrics.md`).
fn write_motions(dir: &Path, name: &str, motions: &[Motion]) -> Result<()> {
    use polars::prelude::{Column, DataFrame, NamedFrom, ParquetWriter, Series};
    let rows = motions.iter().map(|m| m.poses.len() * NUM_JOINTS).sum();
    let (mut id, mut frame, mut joint) = (
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
    );
    let (mut x, mut y, mut z) = (
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
    );
    for m in motions {
        for (f, pose) in m.poses.iter().enumerate() {
            for (j, p) in pose.iter().enumerate() {
                id.push(m.id.clone());
                frame.push(f as u32);
                joint.push(JOINT_NAMES[j]);
                x.push(p[0] as f32);
                y.push(p[1] as f32);
                z.push(p[2] as f32);
            }
        }
    }
    let mut df = DataFrame::new_infer_height(vec![
        Column::from(Series::new("motion".into(), id)),
        Column::from(Series::new("frame".into(), frame)),
        Column::from(Series::new("joint".into(), joint)),
        Column::from(Series::new("x".into(), x)),
        Column::from(Series::new("y".into(), y)),
        Column::from(Series::new("z".into(), z)),
    ])?;
    crate::write_atomically(&dir.join(format!("{name}.parquet")), |f| {
        ParquetWriter::new(f).finish(&mut df)?;
        Ok(())
    })?;
    write_atomic(
        &dir.join(format!("{name}.json")),
        motions_json(motions).as_bytes(),
    )
}

/// `{"fps", "units", "joints", "parents", "motions": [{"id", "frames":
/// [[x, y, z] × joints] × frames}]}`, positions rounded to 0.001 unit.
fn motions_json(motions: &[Motion]) -> String {
    let mut s = String::from(
        "{\"fps\":30,\"units\":\"CMU units (x0.0564 = metres), y up, floor at y = 0\",\"joints\":",
    );
    s += &serde_json::to_string(&JOINT_NAMES).unwrap_or_default();
    let parents: Vec<i64> = JOINT_PARENTS
        .iter()
        .map(|p| p.map_or(-1, |v| v as i64))
        .collect();
    s += ",\"parents\":";
    s += &serde_json::to_string(&parents).unwrap_or_default();
    s += ",\"motions\":[";
    for (k, m) in motions.iter().enumerate() {
        if k > 0 {
            s += ",";
        }
        s += &format!("{{\"id\":\"{}\",\"frames\":[", m.id);
        for (f, pose) in m.poses.iter().enumerate() {
            if f > 0 {
                s += ",";
            }
            s += "[";
            for (j, p) in pose.iter().enumerate() {
                if j > 0 {
                    s += ",";
                }
                s += &format!("[{:.3},{:.3},{:.3}]", p[0], p[1], p[2]);
            }
            s += "]";
        }
        s += "]}";
    }
    s += "]}";
    s
}

/// Side colours: left limbs blue, right limbs red, spine dark grey.
fn bone_color(j: usize) -> [u8; 3] {
    match j {
        1..=4 | 13..=15 => [40, 90, 200],
        5..=8 | 16..=18 => [200, 50, 40],
        _ => [60, 60, 60],
    }
}

/// Horizontal screen coordinate of a point seen at three quarters
/// (50° from the front of a character facing +z), relative to `centre`.
fn project(p: [f64; 3], centre: [f64; 3]) -> f64 {
    let (s, c) = 50f64.to_radians().sin_cos();
    (p[0] - centre[0]) * c + (p[2] - centre[2]) * s
}

/// Draw one pose into the box `(x0, y0, w, h)`: feet at the bottom margin,
/// `scale` pixels per unit, horizontally centred on the hips.
fn draw_pose(cv: &mut Canvas, pose: &Pose, (x0, y0, w, h): (f64, f64, f64, f64), scale: f64) {
    let floor_y = y0 + h - 8.0;
    let cx = x0 + w / 2.0;
    let centre = pose[0];
    cv.line(
        (x0 + 4.0, floor_y),
        (x0 + w - 4.0, floor_y),
        [170, 170, 170],
        1,
    );
    // Floor ticks every 10 units in world x + z, so travel shows.
    for k in -20i64..=20 {
        let d = k as f64 * 10.0 - (centre[0] + centre[2]).rem_euclid(10.0);
        let sx = cx + d * scale * 0.7;
        if sx > x0 + 4.0 && sx < x0 + w - 4.0 {
            cv.line((sx, floor_y), (sx, floor_y + 3.0), [170, 170, 170], 1);
        }
    }
    let pt = |p: [f64; 3]| (cx + project(p, centre) * scale, floor_y - p[1] * scale);
    for (j, parent) in JOINT_PARENTS.iter().enumerate() {
        if let Some(pj) = *parent {
            cv.line(pt(pose[pj]), pt(pose[j]), bone_color(j), 2);
        }
    }
    let head = pt(pose[12]);
    for a in 0..24 {
        let t = a as f64 / 24.0 * std::f64::consts::TAU;
        cv.set(
            (head.0 + 3.0 * t.cos()).round() as i64,
            (head.1 + 3.0 * t.sin()).round() as i64,
            [60, 60, 60],
        );
    }
}

/// Pixels per unit so a 40-unit (about 2.3 m) column fits a box `h` high.
fn scale_for(h: f64) -> f64 {
    (h - 14.0) / 40.0
}

/// The paper's figure 6: a grid of motions, each a row of stick figures at
/// the given frames, one scale for all, floor line in each panel.
fn contact_sheet(path: &Path, motions: &[Motion], times: &[usize]) -> Result<()> {
    let (pw, ph) = (64.0, 110.0);
    let cols = 4usize;
    let rows = motions.len().div_ceil(cols);
    let block_w = pw * times.len() as f64 + 16.0;
    let block_h = ph + 14.0;
    let (w, h) = (
        (block_w * cols as f64) as usize + 8,
        (block_h * rows as f64) as usize + 30,
    );
    let mut cv = Canvas::new(w, h);
    cv.text(
        8,
        8,
        &format!(
            "{} motions, frames {} at 30 fps",
            motions.len(),
            times
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
        [0, 0, 0],
    );
    for (k, m) in motions.iter().enumerate() {
        let bx = 8.0 + (k % cols) as f64 * block_w;
        let by = 26.0 + (k / cols) as f64 * block_h;
        cv.text(bx as i64, by as i64, &m.id.replace('_', " "), [80, 80, 80]);
        for (i, &t) in times.iter().enumerate() {
            let Some(pose) = m.poses.get(t) else { continue };
            draw_pose(
                &mut cv,
                pose,
                (bx + i as f64 * pw, by + 10.0, pw, ph),
                scale_for(ph),
            );
        }
    }
    save_png(&cv, path)
}

/// An animated PNG of motions side by side, 30 fps, labelled.
fn animation(path: &Path, motions: &[&Motion]) -> Result<()> {
    let (pw, ph) = (150.0, 190.0);
    let frames = motions.iter().map(|m| m.poses.len()).max().unwrap_or(0);
    let mut out = Vec::with_capacity(frames);
    for f in 0..frames {
        let mut cv = Canvas::new((pw * motions.len() as f64) as usize, ph as usize + 14);
        for (k, m) in motions.iter().enumerate() {
            let x0 = k as f64 * pw;
            cv.text(x0 as i64 + 4, 4, &m.id.replace('_', " "), [80, 80, 80]);
            if let Some(pose) = m.poses.get(f).or(m.poses.last()) {
                draw_pose(&mut cv, pose, (x0, 14.0, pw, ph), scale_for(ph));
            }
        }
        cv.text(4, ph as i64 + 2, &format!("{f}"), [150, 150, 150]);
        out.push(cv);
    }
    save_apng(&out, 30, path)
}

/// One self-contained HTML file (no network) that plays the motion sets.
fn write_viewer(path: &Path, sets: &[(&str, &[Motion])]) -> Result<()> {
    let mut data = String::from("[");
    for (k, (name, motions)) in sets.iter().enumerate() {
        if k > 0 {
            data += ",";
        }
        data += &format!(
            "{{\"name\":{},\"data\":{}}}",
            serde_json::to_string(name)?,
            motions_json(motions)
        );
    }
    data += "]";
    let html = VIEWER.replace("__DATA__", &data.replace("</", "<\\/"));
    write_atomic(path, html.as_bytes())
}

const VIEWER: &str = r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>motion viewer</title>
<style>
body { font: 14px sans-serif; margin: 12px; color: #222; }
#bar { display: flex; gap: 12px; align-items: center; margin-bottom: 8px; }
#slider { width: 420px; }
canvas { border: 1px solid #ddd; }
</style></head><body>
<div id="bar">
  <select id="set"></select>
  <button id="play">pause</button>
  <input id="slider" type="range" min="0" value="0">
  <span id="label"></span>
</div>
<canvas id="view"></canvas>
<p>Stick figures seen at three quarters, each centred on its hips; floor ticks every 10 units show travel.
Left limbs blue, right limbs red. Written by <code>cargo xtask sample</code>.</p>
<script id="motion-data" type="application/json">__DATA__</script>
<script>
const sets = JSON.parse(document.getElementById('motion-data').textContent);
const sel = document.getElementById('set'), play = document.getElementById('play');
const slider = document.getElementById('slider'), label = document.getElementById('label');
const cv = document.getElementById('view'), ctx = cv.getContext('2d');
sets.forEach((s, i) => { const o = document.createElement('option'); o.value = i; o.textContent = s.name + ' (' + s.data.motions.length + ')'; sel.appendChild(o); });
let frame = 0, playing = true, last = 0;
const PW = 150, PH = 190, COLS = 6;
const side = j => (j >= 1 && j <= 4) || (j >= 13 && j <= 15) ? '#285ac8' : (j >= 5 && j <= 8) || (j >= 16 && j <= 18) ? '#c83228' : '#3c3c3c';
const s50 = Math.sin(50 * Math.PI / 180), c50 = Math.cos(50 * Math.PI / 180);
function current() { return sets[sel.value].data; }
function frames() { return Math.max(...current().motions.map(m => m.frames.length)); }
function layout() {
  const n = current().motions.length, cols = Math.min(COLS, n);
  cv.width = cols * PW; cv.height = Math.ceil(n / cols) * (PH + 16);
  slider.max = frames() - 1;
}
function draw() {
  const d = current(), cols = Math.min(COLS, d.motions.length), sc = (PH - 14) / 40;
  ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, cv.width, cv.height);
  d.motions.forEach((m, k) => {
    const x0 = (k % cols) * PW, y0 = Math.floor(k / cols) * (PH + 16);
    const pose = m.frames[Math.min(frame, m.frames.length - 1)], c = pose[0];
    const fy = y0 + 16 + PH - 8, cx = x0 + PW / 2;
    ctx.fillStyle = '#666'; ctx.fillText(m.id, x0 + 4, y0 + 12);
    ctx.strokeStyle = '#aaa'; ctx.lineWidth = 1; ctx.beginPath(); ctx.moveTo(x0 + 4, fy); ctx.lineTo(x0 + PW - 4, fy);
    const off = ((c[0] + c[2]) % 10 + 10) % 10;
    for (let t = -20; t <= 20; t++) { const sx = cx + (t * 10 - off) * sc * 0.7; if (sx > x0 + 4 && sx < x0 + PW - 4) { ctx.moveTo(sx, fy); ctx.lineTo(sx, fy + 3); } }
    ctx.stroke();
    const P = p => [cx + ((p[0] - c[0]) * c50 + (p[2] - c[2]) * s50) * sc, fy - p[1] * sc];
    ctx.lineWidth = 2;
    d.parents.forEach((pj, j) => { if (pj < 0) return; const a = P(pose[pj]), b = P(pose[j]);
      ctx.strokeStyle = side(j); ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke(); });
    const h = P(pose[12]); ctx.strokeStyle = '#3c3c3c'; ctx.beginPath(); ctx.arc(h[0], h[1], 3, 0, 2 * Math.PI); ctx.stroke();
  });
  slider.value = frame; label.textContent = 'frame ' + frame + ' / ' + (frames() - 1) + ' (' + (frame / d.fps).toFixed(2) + ' s)';
}
function tick(ts) {
  if (playing && ts - last >= 1000 / current().fps) { frame = (frame + 1) % frames(); last = ts; draw(); }
  requestAnimationFrame(tick);
}
sel.onchange = () => { frame = 0; layout(); draw(); };
play.onclick = () => { playing = !playing; play.textContent = playing ? 'pause' : 'play'; };
slider.oninput = () => { frame = +slider.value; playing = false; play.textContent = 'play'; draw(); };
const q = new URLSearchParams(location.search);
if (q.has('frame')) { frame = +q.get('frame'); playing = false; play.textContent = 'play'; }
layout(); draw(); requestAnimationFrame(tick);
</script></body></html>
"#;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motions_json_layout() {
        let m = Motion {
            id: "sample_000".into(),
            poses: vec![[[1.0, 2.0, 3.0]; NUM_JOINTS]; 2],
        };
        let v: serde_json::Value = serde_json::from_str(&motions_json(&[m])).unwrap();
        assert_eq!(v["fps"], 30);
        assert_eq!(v["joints"].as_array().unwrap().len(), NUM_JOINTS);
        assert_eq!(v["parents"][0], -1);
        assert_eq!(v["motions"][0]["frames"].as_array().unwrap().len(), 2);
        assert_eq!(
            v["motions"][0]["frames"][1][18],
            serde_json::json!([1.0, 2.0, 3.0])
        );
    }
}
