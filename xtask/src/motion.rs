//! `cargo xtask sample`, `export` and `eval`: motions from a trained run,
//! back in global coordinates, handed to `motion-render` (Parquet, JSON, BVH,
//! contact sheet, animated PNGs, the 3-D viewer) and measured
//! (`docs/metrics.md`).

use anyhow::{bail, Context, Result};
use candle_core::Device;
use clap::Args;
use mocap_ingest::features::NUM_FEATURES;
use mocap_ingest::skeleton::Pose;
use motion_metrics::{motion_stats, MotionStats, Options};
use motion_render::bvh::RoundTrip;
use motion_render::figure::{animation, contact_sheet};
use motion_render::io::write_motions;
use motion_render::viewer::{write_viewer, MotionSet};
use motion_render::Motion;
use motion_vrnn::data::{Dataset, Stats, Windows};
use motion_vrnn::generate::{self, to_poses};
use motion_vrnn::train::{evaluate, layout, load_model, CheckpointMeta, Trained};
use motion_vrnn::MotionModel;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Where a run's model and data come from.
#[derive(Args, Debug, Clone)]
pub struct RunArgs {
    /// Run directory written by `cargo xtask train`.
    #[arg(long, default_value = "runs/vrnn")]
    pub run: PathBuf,
    /// Checkpoint inside the run: `best` or `last`.
    #[arg(long, default_value = layout::BEST)]
    pub checkpoint: String,
    /// Dataset directory (default: the one the run was trained on).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Seed of the sampling noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Split of real windows to reconstruct and compare with.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Real frames each generated motion continues, of a training window
    /// (`sample`, `eval --contexts train`) or of its `--split` window
    /// (`eval`); read through the posterior, the motion starts at the last.
    #[arg(long, default_value_t = generate::CONTEXT)]
    pub context: usize,
    /// Sampling temperature (scale of the prior's std), instead of the
    /// model's own (`docs/training.md`; 1: the prior as trained).
    #[arg(long)]
    pub temperature: Option<f64>,
}

/// `cargo xtask sample` options.
#[derive(Args, Debug)]
pub struct SampleArgs {
    #[command(flatten)]
    pub run: RunArgs,
    /// Motions to sample from the prior.
    #[arg(long, default_value_t = 36)]
    pub n: usize,
    /// Frames per motion (30 fps).
    #[arg(long, default_value_t = 128)]
    pub frames: usize,
    /// Windows of `--split` to reconstruct (encode, decode) beside the real ones.
    #[arg(long, default_value_t = 4)]
    pub reconstruct: usize,
    /// Output directory (default: RUN/samples).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// `cargo xtask eval` options.
#[derive(Args, Debug)]
pub struct EvalArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Where the generated motions' contexts come from: `split` continues
    /// every window of --split once (the generated set starts where the real
    /// set does), `train` continues random training windows as `sample` does.
    #[arg(long, value_enum, default_value_t = Contexts::Split)]
    contexts: Contexts,
    /// Output directory for eval.json and eval.md (default: RUN/eval).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// Where `eval` takes the real frames its generated motions continue.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Contexts {
    /// Every window of the evaluated split, once each.
    Split,
    /// Random training windows (as `sample`).
    Train,
}

/// `cargo xtask screenshot` options.
#[derive(Args, Debug)]
pub struct ScreenshotArgs {
    /// A run directory: its RUN/samples/viewer.html.
    #[arg(long, default_value = "runs/vrnn")]
    run: PathBuf,
    /// A viewer.html (instead of --run).
    #[arg(long)]
    html: Option<PathBuf>,
    /// Output directory (default: beside the viewer).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Frame to show.
    #[arg(long, default_value_t = 60)]
    frame: usize,
}

/// `cargo xtask export` options.
#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Motions Parquet files (`motion, frame, joint, x, y, z`) to export.
    #[arg(long = "parquet")]
    parquet: Vec<PathBuf>,
    /// A run directory: export its RUN/samples/{samples,reconstructions}.parquet.
    #[arg(long)]
    run: Option<PathBuf>,
    /// Output directory for ID.bvh (default: `bvh/` beside each Parquet file).
    #[arg(long)]
    out: Option<PathBuf>,
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
    let (mut model, meta) =
        load_model(&ck, &device).with_context(|| format!("loading {}", ck.display()))?;
    if let Some(t) = a.temperature {
        model
            .model
            .set_temperature(Some(t))
            .context("--temperature")?;
    }
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

/// Normalised features `[T × 58]` → a named global motion.
fn to_motion(id: String, x: &[f32], stats: &Stats) -> Motion {
    Motion {
        id,
        poses: to_poses(x, stats),
    }
}

/// `n` windows sampled from the prior, normalised `[n][T × 58]`, each
/// continuing `a.context` frames of a training window
/// ([`motion_vrnn::generate::sample_windows`]).
fn sample_windows(m: &Loaded, a: &RunArgs, n: usize, frames: usize) -> Result<Vec<Vec<f32>>> {
    let train = split(m, "train")?;
    Ok(generate::sample_windows(
        &m.model.model,
        train,
        n,
        frames,
        a.context,
        a.seed,
        &m.device,
    )?)
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
    let m = load(&a.run, &["train", &a.run.split])?;
    let out = a.out.clone().unwrap_or_else(|| a.run.run.join("samples"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let started = std::time::Instant::now();
    let gen = sample_windows(&m, &a.run, a.n, a.frames)?;
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
    let bvh = out.join("bvh");
    std::fs::create_dir_all(&bvh)?;
    let mut trips = vec![("generated", motion_render::bvh::write_all(&bvh, &motions)?)];
    // The first generated motions beside their BVH files read back: what a
    // rigid skeleton makes of the model's stretching bones.
    let mut read_back = Vec::new();
    for m in motions.iter().take(4) {
        read_back.push(m.clone());
        read_back.push(motion_render::bvh::read_motion(
            &bvh.join(format!("{}.bvh", m.id)),
            &format!("{}_bvh", m.id),
        )?);
    }
    let mut sets = vec![MotionSet {
        name: "samples",
        group: 1,
        motions: &motions,
    }];
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
        let t = motion_render::bvh::write_all(&bvh, &pairs)?;
        let (r, c): (Vec<_>, Vec<_>) = t.iter().enumerate().partition(|(k, _)| k % 2 == 0);
        trips.push(("real", r.into_iter().map(|(_, t)| *t).collect()));
        trips.push(("reconstructed", c.into_iter().map(|(_, t)| *t).collect()));
        sets.push(MotionSet {
            name: "real vs reconstruction",
            group: 2,
            motions: &pairs,
        });
    }
    sets.push(MotionSet {
        name: "generated vs its BVH read back",
        group: 2,
        motions: &read_back,
    });
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
    println!("  bvh/ID.bvh                      every motion as BVH (CMU Motionbuilder skeleton, 30 fps)");
    println!("  contact_sheet.png               stick figures at frames 0, 30, 60, 90, 120");
    println!(
        "  anim/*.png                      animated PNG per motion (and real vs reconstruction)"
    );
    println!("  viewer.html                     open in a browser: 3-D, orbit/pan/zoom, play/pause, speed, frame slider");
    print_round_trips(&trips);
    Ok(())
}

/// The BVH round-trip table: per set, the worst and mean joint distance of
/// the file read back, and the part bone-length variation explains.
fn print_round_trips(sets: &[(&str, Vec<RoundTrip>)]) {
    println!(
        "BVH read back with mocap-ingest (joint distance to the motion, CMU units; x0.0564 = m):"
    );
    println!(
        "  {:<14} {:>7} {:>10} {:>10} {:>16} {:>16}",
        "set", "motions", "max", "mean", "bone-length max", "unexplained max"
    );
    for (name, t) in sets {
        let max = |f: fn(&RoundTrip) -> f64| t.iter().map(f).fold(0.0, f64::max);
        let mean = t.iter().map(|r| r.mean).sum::<f64>() / t.len().max(1) as f64;
        println!(
            "  {name:<14} {:>7} {:>10} {:>10} {:>16} {:>16}",
            t.len(),
            dist(max(|r| r.max)),
            dist(mean),
            dist(max(|r| r.bone_max)),
            dist(max(|r| r.residual_max))
        );
    }
}

/// `cargo xtask screenshot`: open the 3-D viewer in headless Chromium, fail
/// on a JavaScript error, and screenshot the generated set and the
/// real-vs-reconstruction pairs (overlaid).
pub fn screenshot(a: ScreenshotArgs) -> Result<()> {
    let html = a
        .html
        .clone()
        .unwrap_or_else(|| a.run.join("samples").join("viewer.html"));
    if !html.is_file() {
        bail!(
            "{}: no viewer; run `cargo xtask sample --run {}` first (or pass --html)",
            html.display(),
            a.run.display()
        );
    }
    let chromium = motion_render::viewer::find_chromium().context(
        "headless Chromium not found: install it (Debian: apt-get install chromium) or set CHROMIUM",
    )?;
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| html.parent().unwrap_or(Path::new(".")).to_path_buf());
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let html_text =
        std::fs::read_to_string(&html).with_context(|| format!("reading {}", html.display()))?;
    // The sets in the file, in order; the overlaid ones `sample` writes get
    // a screenshot each when present.
    let names: Vec<&str> = html_text
        .split("\"name\":\"")
        .skip(1)
        .filter_map(|t| t.split('"').next())
        .collect();
    let mut shots = vec![("viewer_samples.png", format!("?set=0&frame={}", a.frame))];
    for (name, file) in [
        ("real vs reconstruction", "viewer_pairs.png"),
        ("generated vs its BVH read back", "viewer_bvh.png"),
    ] {
        if let Some(k) = names.iter().position(|n| *n == name) {
            shots.push((file, format!("?set={k}&overlay=1&frame={}", a.frame)));
        }
    }
    for (file, query) in shots {
        let png = out.join(file);
        motion_render::viewer::screenshot(&chromium, &html, &query, &png, (1200, 800))?;
        println!("{} -> {} (no JavaScript error)", query, png.display());
    }
    Ok(())
}

/// A distance for the round-trip table: fixed above 0.01, else scientific.
fn dist(v: f64) -> String {
    if v >= 0.01 {
        format!("{v:.3}")
    } else {
        format!("{v:.1e}")
    }
}

/// `cargo xtask export`: motions Parquet files → one BVH per motion.
pub fn export(a: ExportArgs) -> Result<()> {
    let mut files = a.parquet.clone();
    if let Some(run) = &a.run {
        let dir = run.join("samples");
        files.extend(
            ["samples.parquet", "reconstructions.parquet"]
                .map(|f| dir.join(f))
                .into_iter()
                .filter(|p| p.is_file()),
        );
        if files.is_empty() {
            bail!(
                "{}: no samples.parquet or reconstructions.parquet; run `cargo xtask sample --run {}` first",
                dir.display(),
                run.display()
            );
        }
    }
    if files.is_empty() {
        bail!("nothing to export: pass --parquet FILE (repeatable) or --run RUN");
    }
    let mut failed = 0;
    let mut sets = Vec::new();
    for f in &files {
        let out = a
            .out
            .clone()
            .unwrap_or_else(|| f.parent().unwrap_or(Path::new(".")).join("bvh"));
        let done = motion_render::io::read_parquet(f)
            .map_err(anyhow::Error::from)
            .and_then(|motions| {
                std::fs::create_dir_all(&out)
                    .with_context(|| format!("creating {}", out.display()))?;
                Ok(motion_render::bvh::write_all(&out, &motions)?)
            });
        match done {
            Ok(t) => {
                println!(
                    "{} -> {}/ ({} motions)",
                    f.display(),
                    out.display(),
                    t.len()
                );
                sets.push((crate::file_name(f), t));
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                failed += 1;
            }
        }
    }
    let named: Vec<(&str, Vec<RoundTrip>)> =
        sets.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
    print_round_trips(&named);
    if failed > 0 {
        bail!("{failed} of {} files could not be exported", files.len());
    }
    Ok(())
}

/// What `eval.json` holds.
#[derive(Serialize, Deserialize)]
pub struct EvalReport {
    pub run: String,
    pub checkpoint: String,
    pub epoch: usize,
    pub dataset: String,
    pub split: String,
    pub seed: u64,
    /// Real frames each generated motion continues, and whose.
    pub context: usize,
    pub contexts: Contexts,
    /// Sampling temperature of the generated motions (1: the prior as is).
    #[serde(default = "one")]
    pub temperature: f64,
    pub windows: usize,
    pub frames: usize,
    /// Per frame, on the split, with the training noise convention.
    pub neg_elbo_per_frame: f64,
    pub recon_per_frame: f64,
    pub kl_per_frame: f64,
    pub real: MotionStats,
    pub reconstructed: MotionStats,
    pub generated: MotionStats,
    /// Generated over real.
    pub jerk_ratio: f64,
    pub high_freq_ratio: f64,
    pub frechet_generated: f64,
    pub frechet_reconstructed: f64,
    /// Reference: train windows against the split.
    pub frechet_train: f64,
    /// Reference of the generated set's sample size: train windows, as many
    /// as the split has, against the split, for each of the disjoint subsets
    /// of [`motion_metrics::frechet_of_subsets`].
    #[serde(default)]
    pub frechet_train_subsets: Vec<f64>,
    /// Within-window spread ([`motion_metrics::mean_spread`]) of the real,
    /// reconstructed and generated windows, in normalised units.
    #[serde(default)]
    pub spread: Spread,
    pub options: Options,
}

fn one() -> f64 {
    1.0
}

/// Within-window spread of each set ([`motion_metrics::mean_spread`]).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Spread {
    pub real: f64,
    pub reconstructed: f64,
    pub generated: f64,
}

/// `cargo xtask eval`.
pub fn eval(a: EvalArgs) -> Result<()> {
    let out = a.out.clone().unwrap_or_else(|| a.run.run.join("eval"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let started = std::time::Instant::now();
    let report = report(&a.run, a.contexts)?;
    let json = serde_json::to_string_pretty(&report)? + "\n";
    motion_render::write_file(&out.join("eval.json"), json.as_bytes())?;
    let md = markdown(&report);
    motion_render::write_file(&out.join("eval.md"), md.as_bytes())?;
    print!("{md}");
    println!(
        "\nwrote {} and {} in {:.1} s",
        out.join("eval.json").display(),
        out.join("eval.md").display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The evaluation of a run: real, reconstructed and generated windows of
/// the split, measured alike.
pub fn report(a: &RunArgs, contexts: Contexts) -> Result<EvalReport> {
    let m = load(a, &["train", &a.split])?;
    let w = split(&m, &a.split)?;
    let (recon, kl) = evaluate(&m.model.model, w, 256, a.seed, &m.device)?;
    let t = w.length as f64;
    let idx: Vec<usize> = (0..w.n).collect();
    let (real, rec) = reconstruct(&m, w, &idx)?;
    let gen = match contexts {
        Contexts::Split => generate::continue_windows(
            &m.model.model,
            w,
            &idx,
            w.length,
            a.context,
            a.seed,
            &m.device,
        )?,
        Contexts::Train => sample_windows(&m, a, w.n, w.length)?,
    };
    let global = |set: &[Vec<f32>]| -> Vec<Vec<Pose>> {
        set.iter().map(|x| to_poses(x, &m.data.stats)).collect()
    };
    let o = Options::default();
    let (sr, sc, sg) = (
        motion_stats(&global(&real), &o),
        motion_stats(&global(&rec), &o),
        motion_stats(&global(&gen), &o),
    );
    let summaries = |set: &[Vec<f32>]| generate::summaries(set, NUM_FEATURES);
    let train_windows = generate::windows_of(split(&m, "train")?);
    let s_real = summaries(&real);
    let s_train = summaries(&train_windows);
    let (s_rec, s_gen) = (summaries(&rec), summaries(&gen));
    let report = EvalReport {
        run: a.run.display().to_string(),
        checkpoint: a.checkpoint.clone(),
        epoch: m.meta.epoch,
        dataset: m.data.dir.display().to_string(),
        split: a.split.clone(),
        seed: a.seed,
        context: a.context,
        contexts,
        temperature: m.model.model.config().parts.temperature.unwrap_or(1.0),
        windows: w.n,
        frames: w.length,
        neg_elbo_per_frame: (recon + kl) / t,
        recon_per_frame: recon / t,
        kl_per_frame: kl / t,
        jerk_ratio: sg.jerk_m_s3 / sr.jerk_m_s3,
        high_freq_ratio: sg.high_freq_share / sr.high_freq_share,
        frechet_generated: motion_metrics::frechet(&s_real, &s_gen),
        frechet_reconstructed: motion_metrics::frechet(&s_real, &s_rec),
        frechet_train: motion_metrics::frechet(&s_real, &s_train),
        frechet_train_subsets: motion_metrics::frechet_of_subsets(&s_real, &s_train),
        spread: Spread {
            real: motion_metrics::mean_spread(&s_real),
            reconstructed: motion_metrics::mean_spread(&s_rec),
            generated: motion_metrics::mean_spread(&s_gen),
        },
        real: sr,
        reconstructed: sc,
        generated: sg,
        options: o,
    };
    Ok(report)
}

pub fn markdown(r: &EvalReport) -> String {
    let mut s = format!(
        "# Evaluation of {} ({}, epoch {})\n\nDataset {}, split `{}`: {} windows of {} frames; {} generated motions of {} frames (seed {}, temperature {}), each continuing the first {} frames of {}.\n\n",
        r.run, r.checkpoint, r.epoch, r.dataset, r.split, r.windows, r.frames, r.windows, r.frames, r.seed, r.temperature, r.context,
        match r.contexts {
            Contexts::Split => format!("one `{}` window (every window once)", r.split),
            Contexts::Train => "a random training window".to_string(),
        }
    );
    s += &format!(
        "Per frame on `{}`: negative ELBO **{:.3}** = reconstruction {:.3} + KL {:.3} (normalised units).\n\n",
        r.split, r.neg_elbo_per_frame, r.recon_per_frame, r.kl_per_frame
    );
    s += "| measure | real | reconstructed | generated | reconstructed / real | generated / real |\n|---|---|---|---|---|---|\n";
    type Row = (&'static str, fn(&MotionStats) -> f64, usize);
    let rows: [Row; 11] = [
        ("APD, m", |m| m.apd_m, 3),
        ("mean jerk, m/s³", |m| m.jerk_m_s3, 1),
        ("power above 5 Hz", |m| m.high_freq_share, 4),
        ("bone length std / mean", |m| m.bone_cv, 4),
        (
            "foot contact (share of foot-frames)",
            |m| m.contact_share,
            4,
        ),
        ("foot skating (share of foot-frames)", |m| m.skate_share, 4),
        (
            "skating among contact foot-frames",
            |m| m.skate_in_contact,
            4,
        ),
        ("hips height, m", |m| m.hip_height_m, 3),
        ("hips height, last 32 frames, m", |m| m.hip_height_end_m, 3),
        ("hips horizontal speed, m/s", |m| m.root_speed_m_s, 3),
        (
            "hips horizontal speed, last 32 frames, m/s",
            |m| m.root_speed_end_m_s,
            3,
        ),
    ];
    let ratio = |x: f64, real: f64| {
        if real.abs() > 1e-6 {
            format!("{:.2}", x / real)
        } else {
            "n/a (real ≈ 0)".into()
        }
    };
    for (name, f, p) in rows {
        let (a, b, c) = (f(&r.real), f(&r.reconstructed), f(&r.generated));
        s += &format!(
            "| {name} | {a:.p$} | {b:.p$} | {c:.p$} | {} | {} |\n",
            ratio(b, a),
            ratio(c, a)
        );
    }
    s += &format!(
        "\nFréchet distance to the real `{}` windows (summaries: per-window mean and std of the 58 normalised features): generated **{:.2}**, reconstructed {:.2}, train windows {:.2} (reference).\n",
        r.split, r.frechet_generated, r.frechet_reconstructed, r.frechet_train
    );
    let d = &r.frechet_train_subsets;
    if !d.is_empty() {
        let (lo, hi) = d
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        s += &format!(
            "Train windows {} at a time (the generated set's size; {} disjoint draws): mean {:.2}, {:.2}–{:.2}.\n",
            r.windows,
            d.len(),
            mean_of(d),
            lo,
            hi
        );
    }
    let sp = &r.spread;
    s += &format!(
        "Within-window spread (each normalised feature's std over its window, averaged; the std half of the summaries): real {:.3}, reconstructed {:.3} ({}), generated {:.3} ({}).\n",
        sp.real,
        sp.reconstructed,
        ratio(sp.reconstructed, sp.real),
        sp.generated,
        ratio(sp.generated, sp.real)
    );
    s
}

/// Mean of `v` (0 when empty).
pub fn mean_of(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}
