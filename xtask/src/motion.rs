//! `cargo xtask sample`, `export`, `screenshot` and `eval`: options, and
//! printing what `motion-eval` and `motion-render` return.

use anyhow::{bail, Context, Result};
use clap::Args;
use motion_eval::horizon::HorizonOptions;
use motion_eval::report::{markdown, report, Contexts};
use motion_eval::run::RunSpec;
use motion_eval::samples::{write_samples, SampleOptions};
use motion_render::bvh::round_trip_table;
use motion_vrnn::generate;
use motion_vrnn::train::layout;
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
    /// Real frames each generated motion continues, of a training window (`sample`, `eval --contexts train`) or of its `--split` window (`eval`); read through the posterior, the motion starts at the last.
    #[arg(long, default_value_t = generate::CONTEXT)]
    pub context: usize,
    /// Sampling temperature (the prior's std times this) instead of the model's own (1: as trained).
    #[arg(long)]
    pub temperature: Option<f64>,
    /// Foot-lock sharpness (contact logits times this) instead of the model's own (1: as trained).
    #[arg(long)]
    pub contact_sharpness: Option<f64>,
    /// Generate in runs of this many frames, each restarting on the last --context made (0: one run).
    #[arg(long)]
    pub restart: Option<usize>,
    /// Generate this category (`walk`, `run`, …; a model trained with `--condition category`), from training contexts of it; `own` (a conditioned model's default): each motion the category of the window it continues; `none`: no category.
    #[arg(long)]
    pub category: Option<String>,
    /// Guidance scale of --category (1: as trained; 0: none; above 1: further from the unconditioned).
    #[arg(long, default_value_t = motion_vrnn::generate::GUIDANCE)]
    pub guidance: f64,
    /// How hard a motion is held to its asked pace (a model conditioned on category and pace): each run of at most 128 frames is tried 4 times, the pace it asks for moved by gain × (target − the pace the try made) after each (0: not held).
    #[arg(long, default_value_t = motion_vrnn::generate::PACE_GAIN)]
    pub pace_gain: f64,
    /// Draws of noise each run of a held motion is chosen from: each motion keeps the one whose mean pose is closest to its context's (1: one draw).
    #[arg(long, default_value_t = motion_vrnn::generate::POSE_DRAWS)]
    pub draws: usize,
    /// Pin each planted toe of generated motions in place, the legs bent by IK to reach it (`sample` and `continue` write them so; `eval` measures them so).
    #[arg(long)]
    pub pin_feet: bool,
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
    #[arg(long, default_value = "split")]
    contexts: Contexts,
    /// Also roll motions out for this many seconds and measure every window-long stretch against all real windows (0: off).
    #[arg(long, default_value_t = 60.0)]
    horizon: f64,
    /// Motions rolled out for --horizon.
    #[arg(long, default_value_t = 256)]
    horizon_motions: usize,
    /// A classifier directory (`train-classifier`): also measure generated motion in its feature space.
    #[arg(long)]
    classifier: Option<PathBuf>,
    /// Output directory for eval.json and eval.md (default: RUN/eval).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Measure steering instead: every built-in path at the real walks' speed, followed by 64 motions from training contexts of walking (steer.json, steer.md, a picture per path).
    #[arg(long)]
    steer: bool,
}

/// `cargo xtask continue` options.
#[derive(Args, Debug)]
pub struct ContinueArgs {
    #[command(flatten)]
    run: RunArgs,
    /// The clip: a .bvh (any supported release) or an .amc with its ASF.
    #[arg(long)]
    input: PathBuf,
    /// ASF skeleton for an .amc whose own is not found beside it.
    #[arg(long)]
    asf: Option<PathBuf>,
    /// Seconds of motion generated after the clip.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// The BVH to write (with --variations K > 1: OUT_0.bvh … OUT_{K-1}.bvh).
    #[arg(long)]
    out: PathBuf,
    /// Continuations to write, from seeds --seed, --seed + 1, …
    #[arg(long, default_value_t = 1)]
    variations: usize,
    /// Steer the continuation along a path (see `steer --path`); it starts at the clip's last frame, facing where the clip faces.
    #[command(flatten)]
    path: crate::steer::PathArgs,
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

impl RunArgs {
    /// The run these options name, for `motion-eval`.
    pub fn spec(&self) -> RunSpec {
        RunSpec {
            run: self.run.clone(),
            checkpoint: self.checkpoint.clone(),
            data: self.data.clone(),
            seed: self.seed,
            split: self.split.clone(),
            context: self.context,
            temperature: self.temperature,
            contact_sharpness: self.contact_sharpness,
            restart: self.restart,
            category: self.category.clone(),
            guidance: self.guidance,
            pace_gain: self.pace_gain,
            draws: self.draws,
            pin_feet: self.pin_feet,
        }
    }
}

/// `cargo xtask sample`.
pub fn sample(a: SampleArgs) -> Result<()> {
    let out = a.out.clone().unwrap_or_else(|| a.run.run.join("samples"));
    let o = SampleOptions {
        n: a.n,
        frames: a.frames,
        reconstruct: a.reconstruct,
        sheet_columns: 5,
    };
    let w = write_samples(&a.run.spec(), &o, &out)?;
    w.warnings.iter().for_each(|w| eprintln!("warning: {w}"));
    println!(
        "sampled {} motions x {} frames from {} ({} epoch {}) in {:.2} s",
        a.n,
        a.frames,
        a.run.run.join(&a.run.checkpoint).display(),
        a.run.checkpoint,
        w.epoch,
        w.seconds
    );
    if let Some(c) = &a.run.category {
        println!(
            "asked for {c} (guidance {}), each continuing a {c} training window",
            a.run.guidance
        );
    }
    print!("{}", w.listing(&out, &a.run.split, &o));
    print!("{}", round_trip_table(&w.round_trips));
    Ok(())
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
    let shots = motion_render::viewer::screenshots_of(&html, a.frame)?;
    for (file, query) in shots {
        let png = out.join(file);
        motion_render::viewer::screenshot(&chromium, &html, &query, &png, (1200, 800))?;
        println!("{} -> {} (no JavaScript error)", query, png.display());
    }
    Ok(())
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
    let (printed, errors) = motion_render::bvh::export_files(&files, a.out.as_deref());
    errors.iter().for_each(|e| eprintln!("error: {e}"));
    print!("{printed}");
    if !errors.is_empty() {
        bail!(
            "{} of {} files could not be exported",
            errors.len(),
            files.len()
        );
    }
    Ok(())
}

/// `cargo xtask eval`.
pub fn eval(a: EvalArgs) -> Result<()> {
    let out = a.out.clone().unwrap_or_else(|| a.run.run.join("eval"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let started = std::time::Instant::now();
    let (name, json, md) = if a.steer {
        let (json, md) = crate::steer::eval(&a.run, motion_eval::steering::STEER_MOTIONS, &out)?;
        ("steer", json, md)
    } else {
        let horizon = (a.horizon > 0.0).then_some(HorizonOptions {
            seconds: a.horizon,
            motions: a.horizon_motions,
        });
        let report = report(&a.run.spec(), a.contexts, horizon, a.classifier.as_deref())?;
        report
            .warnings
            .iter()
            .for_each(|w| eprintln!("warning: {w}"));
        let json = serde_json::to_string_pretty(&report)? + "\n";
        ("eval", json, markdown(&report))
    };
    let (json_file, md_file) = (
        out.join(format!("{name}.json")),
        out.join(format!("{name}.md")),
    );
    motion_render::write_file(&json_file, json.as_bytes())?;
    motion_render::write_file(&md_file, md.as_bytes())?;
    print!("{md}");
    println!(
        "\nwrote {} and {} in {:.1} s",
        json_file.display(),
        md_file.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `cargo xtask continue`: a clip and what the model makes of its future, as BVH.
pub fn continue_clip(a: ContinueArgs) -> Result<()> {
    use motion_eval::continuation::{continue_clip, ContinueOptions};
    let o = ContinueOptions {
        seconds: a.seconds,
        seed: a.run.seed,
        variations: a.variations,
        context: a.run.context,
        path: None,
    };
    o.validate()?;
    let (_, _, clip) = mocap_ingest::clip_of_file(&a.input, a.asf.clone(), &Default::default())
        .with_context(|| format!("reading {}", a.input.display()))?;
    // A path's speed is checked against the training windows'.
    let splits = &["train"][..usize::from(a.path.path.is_some())];
    let run = motion_eval::run::Run::load(&a.run.spec(), splits)?;
    run.warnings.iter().for_each(|w| eprintln!("warning: {w}"));
    let o = ContinueOptions {
        path: match a.path.path.as_deref() {
            Some(p) => Some(motion_eval::steering::asked_path(&run, p, a.path.speed)?.0),
            None => None,
        },
        ..o
    };
    let done = continue_clip(&run, &clip.features, &o)
        .with_context(|| format!("continuing {}", a.input.display()))?;
    println!(
        "{}: {} frames at 30 fps; the model reads the last {}",
        a.input.display(),
        clip.features.len(),
        o.context.min(clip.features.len())
    );
    println!(
        "seam (mean joint step, CMU units): the clip moves {:.3} a frame (largest {:.3})",
        done[0].seam.clip_mean, done[0].seam.clip_max
    );
    print!(
        "{}",
        motion_eval::continuation::write_continued(&done, o.seed, &a.out)?
    );
    Ok(())
}

/// `cargo xtask bench-sample` options.
#[derive(Args, Debug)]
pub struct BenchSampleArgs {
    #[command(flatten)]
    pub run: RunArgs,
    /// Motions generated at once.
    #[arg(long, default_value_t = 64)]
    pub n: usize,
    /// Frames per motion (30 fps; 1800: a minute).
    #[arg(long, default_value_t = 1800)]
    pub frames: usize,
    /// Runs of each sampler; the fastest is reported.
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
}

/// `cargo xtask bench-sample`: frames per second of the run's sampler and
/// of the model alone.
pub fn bench_sample(a: BenchSampleArgs) -> Result<()> {
    let spec = a.run.spec();
    let mut run = motion_eval::run::Run::load(&spec, &["train"])
        .with_context(|| format!("loading the run {}", spec.run.display()))?;
    println!(
        "{} motions of {} frames from training contexts, {} thread(s), {}",
        a.n,
        a.frames,
        rayon::current_num_threads(),
        motion_vrnn::bench::cpu_description()
    );
    let (n, frames, context, seed) = (a.n, a.frames, spec.context, spec.seed);
    let t = motion_eval::speed::time_sampling(&mut run, n, frames, context, seed, a.repeat)?;
    print!("{}", motion_eval::speed::markdown(&t));
    Ok(())
}
