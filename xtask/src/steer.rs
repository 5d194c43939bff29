//! `cargo xtask steer` and `eval --steer`: motions that follow a path.

use crate::motion::RunArgs;
use anyhow::{Context, Result};
use clap::Args;
use motion_eval::run::{Run, RunSpec};
use motion_eval::steering::{asked_path, evaluate, markdown, write_steered};
use std::path::{Path as FsPath, PathBuf};

/// The path options `steer` and `continue --path` share.
#[derive(Args, Debug, Clone)]
pub struct PathArgs {
    /// The path to follow: a CSV file of `x,z` or `x,z,speed` lines (metres, m/s; x to the character's right, z ahead of it, from where it stands), or a built-in: `line:L` (L m ahead), `circle:R` (radius R m, once round to the left), `zigzag:N` (N 90° turns), `stop-go` (5 m, stand 3 s, 5 m).
    #[arg(long)]
    pub path: Option<String>,
    /// Speed along the path, m/s (default: the mean speed of the training set's real walks).
    #[arg(long)]
    pub speed: Option<f64>,
}

/// `cargo xtask steer` options.
#[derive(Args, Debug)]
pub struct SteerArgs {
    #[command(flatten)]
    run: RunArgs,
    #[command(flatten)]
    path: PathArgs,
    /// Motions to make, each from another training context of the category.
    #[arg(long, default_value_t = 1)]
    n: usize,
    /// The BVH to write (with --n K > 1: OUT_0.bvh … OUT_{K-1}.bvh); beside it OUT.parquet (the motions) and OUT.png (the asked path and the root's, from above).
    #[arg(long)]
    out: PathBuf,
}

/// The run of `a` loaded to be steered: walking unless a category is named.
fn load(a: &RunArgs) -> Result<Run> {
    let mut spec = a.spec();
    spec.category.get_or_insert_with(|| "walk".into());
    let run = Run::load(&spec, &["train"])
        .with_context(|| format!("loading the run {}", spec.run.display()))?;
    run.warnings.iter().for_each(|w| eprintln!("warning: {w}"));
    Ok(run)
}

/// `cargo xtask steer`.
pub fn steer(a: SteerArgs) -> Result<()> {
    let run = load(&a.run)?;
    let Some(spec) = a.path.path.as_deref() else {
        anyhow::bail!("--path is required: a CSV file of x,z waypoints or a built-in (line:10, circle:2, zigzag:4, stop-go)");
    };
    let (path, walks) = asked_path(&run, spec, a.path.speed)?;
    println!(
        "{spec}: {:.1} m at {:.2} m/s, {:.1} s asked (real walks: {:.2} m/s)",
        path.length(),
        path.speeds()[0],
        path.asked_seconds(),
        walks.speed_m_s
    );
    let w = write_steered(
        &run,
        (spec, &path),
        a.n,
        (a.run.context, a.run.seed),
        &a.out,
    )?;
    print!("{}", w.summary());
    Ok(())
}

/// `cargo xtask eval --steer`: [`evaluate`] with `motions` motions, a
/// picture per path in `out`; the report as JSON and as Markdown.
pub fn eval(a: &RunArgs, motions: usize, out: &FsPath) -> Result<(String, String)> {
    let run = load(a)?;
    let report = evaluate(&run, motions, a.context, a.seed, Some(out), &|m| {
        println!("{m}")
    })?;
    Ok((
        serde_json::to_string_pretty(&report)? + "\n",
        markdown(&report),
    ))
}

/// `cargo xtask play` options.
#[derive(Args, Debug)]
pub struct PlayArgs {
    /// Run directory written by `cargo xtask train` (its `best` checkpoint).
    #[arg(long, default_value = "runs/vrnn")]
    run: PathBuf,
    /// Dataset directory (default: the run's): the start contexts and the walking and running speeds come from its training windows.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Seed of the start contexts and of the page's noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The page to write.
    #[arg(long, default_value = "play.html")]
    out: PathBuf,
}

/// `cargo xtask play`.
pub fn play(a: PlayArgs) -> Result<()> {
    let spec = RunSpec::best(a.run.clone(), a.data.clone());
    let run = Run::load(&spec, &["train"])
        .with_context(|| format!("loading the run {}", a.run.display()))?;
    println!("building the player for WebAssembly into target/wasm (minutes the first time)");
    let root = crate::workspace_root();
    let p = run.write_play(&a.run.join(&spec.checkpoint), a.seed, &a.out, &root)?;
    println!(
        "{}: {:.1} MB (the model {:.0} kB); open it in a browser: arrows or WASD steer, Shift runs, Space stops, digits pick {}",
        a.out.display(),
        p.bytes as f64 / 1e6,
        p.model_bytes as f64 / 1e3,
        p.categories.join(", ")
    );
    Ok(())
}
