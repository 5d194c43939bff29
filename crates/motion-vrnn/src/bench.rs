//! Speed of a training step (forward, backward, Adam) and of sampling, on
//! random windows, for `cargo xtask bench-train`; and PyTorch eager running
//! the paper's model on the same machine (`xtask/py/pytorch_vrnn_step.py`).

use crate::model::Config;
use crate::optim::Adam;
use crate::train::{feed_mask, init_model, named_vars, noise, sharded, TrainError};
use crate::MotionModel;
use candle_core::{Device, Tensor};
use std::path::Path;

/// Frames per window in the benchmark.
pub const FRAMES: usize = 128;

/// The bench's name for what `cargo xtask train --preset standard` trains:
/// `motion` conditioned on the category (every category of the list, each
/// window asking for one, a tenth for none, as
/// [`crate::train::CONDITION_DROPOUT`]).
pub const CONDITIONED: &str = "motion+category";

/// The bench's name for what `cargo xtask train` trains by default (the
/// `minute` preset): [`CONDITIONED`] with the pace as a condition and the
/// feed rounds drawn at the sampling temperature.
pub const DEFAULT: &str = "minute";

/// The models `bench-train` times: every model of [`crate::model::MODELS`],
/// then [`CONDITIONED`] and [`DEFAULT`].
pub fn bench_models() -> Vec<String> {
    let mut v: Vec<String> = crate::model::MODELS
        .iter()
        .map(|m| m.0.to_string())
        .collect();
    v.extend([CONDITIONED.to_string(), DEFAULT.to_string()]);
    v
}

/// `name` if it is one of [`bench_models`], or an error listing them (a
/// command-line parser).
pub fn parse_model(name: &str) -> Result<String, String> {
    crate::model::one_of(name, &bench_models())
}

/// The configuration `name` ([`bench_models`]) stands for.
fn bench_config(name: &str) -> Option<Config> {
    if name == CONDITIONED || name == DEFAULT {
        let mut c = Config::named(crate::model::DEFAULT_MODEL)?;
        if name == DEFAULT {
            c = crate::options::Preset::Minute.for_model(c).model;
        }
        c.categories = mocap_ingest::category::Category::ALL
            .iter()
            .map(|c| c.name().to_string())
            .collect();
        return Some(c);
    }
    Config::named(name)
}

/// Condition weights for `b` windows of a conditioned model (None
/// otherwise): window `k` asks for category row `1 + k % n`, one window in
/// `1 / CONDITION_DROPOUT` (every tenth) for none.
fn bench_condition(
    model: &Config,
    b: usize,
    device: &Device,
) -> candle_core::Result<Option<Tensor>> {
    let n = model.categories.len();
    let period = (1.0 / crate::train::CONDITION_DROPOUT).round() as usize;
    let rows: Vec<Option<usize>> = (0..b)
        .map(|k| (k % period != period - 1).then_some(1 + k % n.max(1)))
        .collect();
    model.condition(&rows, 1.0, device)
}

/// Seconds per training step of one model, path and batch size.
#[derive(Clone, Debug)]
pub struct StepTiming {
    /// Model name.
    pub model: String,
    /// `fused` (the blocks) or `autograd` (their candle-op references).
    pub path: &'static str,
    /// Windows per step.
    pub batch: usize,
    /// Median and fastest step, seconds.
    pub median: f64,
    /// Fastest step, seconds.
    pub min: f64,
    /// Median time to sample 36 motions, seconds.
    pub sample: f64,
}

/// Time `steps` training steps (after 2 warm-up steps) of model `name` at
/// each batch size, on the fused path and, with `reference`, through candle
/// ops and autograd too.
pub fn time_steps(
    name: &str,
    batches: &[usize],
    steps: usize,
    reference: bool,
    device: &Device,
) -> Result<Vec<StepTiming>, TrainError> {
    let t = FRAMES;
    let mut model =
        bench_config(name).ok_or_else(|| TrainError::Invalid(format!("unknown model {name:?}")))?;
    // Synthetic data: the body of the skeleton part from random windows.
    let train = crate::rng::Rng::new(2, 0).normals(64 * t * model.input);
    let mut mean = vec![0.0; model.input];
    mean[0] = 15.0;
    model.fit_to(&mean, &vec![2.0; model.input], &train);
    let paths: &[&'static str] = if reference {
        &["fused", "autograd"]
    } else {
        &["fused"]
    };
    let mut rows = Vec::new();
    for &path in paths {
        for &b in batches {
            let m = init_model(&model, 0, device)?;
            let mut adam = Adam::new(named_vars(&m.varmap), Default::default())?;
            let vars: Vec<_> = adam.vars().iter().map(|v| v.1.clone()).collect();
            let x = Tensor::from_vec(
                crate::rng::Rng::new(1, b as u64).normals(b * t * model.input),
                (b, t, model.input),
                device,
            )?;
            let cond = bench_condition(&model, b, device)?;
            let mut times = Vec::new();
            for step in 0..steps.max(1) + 2 {
                let eps = noise(0, step as u64, t, b, model.latent, device)?;
                let feed = feed_mask(0, step as u64, b, t, model.parts.self_feed, 1, device)?;
                let start = std::time::Instant::now();
                let grads = if path == "fused" {
                    let c = cond.as_ref();
                    sharded(&m.model, &x, &eps, feed.as_ref(), c, Some((1.0, &vars)))?.1
                } else {
                    crate::blocks::reference(|| {
                        let l = m.model.losses(&x, &eps, feed.as_ref(), cond.as_ref())?;
                        ((&l.recon + &l.kl)? + &l.extra)?.backward().map(Some)
                    })?
                };
                let grads = grads.ok_or_else(|| TrainError::Invalid("no gradients".into()))?;
                adam.step(&grads)?;
                if step >= 2 {
                    times.push(start.elapsed().as_secs_f64());
                }
            }
            times.sort_by(f64::total_cmp);
            let mut sample = Vec::new();
            for k in 0..5 {
                let eps = noise(5, k, t, 36, model.latent, device)?;
                let start = std::time::Instant::now();
                let s = if path == "fused" {
                    m.model.sample(&eps, None, None)?
                } else {
                    crate::blocks::reference(|| m.model.sample(&eps, None, None))?
                };
                let _ = s.sum_all()?.to_scalar::<f32>()?;
                sample.push(start.elapsed().as_secs_f64());
            }
            sample.sort_by(f64::total_cmp);
            rows.push(StepTiming {
                model: name.to_string(),
                path,
                batch: b,
                median: times[times.len() / 2],
                min: times[0],
                sample: sample[2],
            });
        }
    }
    Ok(rows)
}

/// Median seconds per step of PyTorch eager on the paper's model, per batch
/// size, from `script` (`xtask/py/pytorch_vrnn_step.py`) run by `python`
/// with `threads` threads, in its `hoisted` form or step by step.
pub fn pytorch_medians(
    python: &Path,
    script: &Path,
    batches: &[usize],
    steps: usize,
    threads: usize,
    hoisted: bool,
) -> Result<Vec<(usize, f64)>, TrainError> {
    let mut cmd = std::process::Command::new(python);
    cmd.arg(script).arg("--batch");
    cmd.args(batches.iter().map(usize::to_string));
    cmd.args(["--steps", &steps.to_string()]);
    cmd.args(["--threads", &threads.to_string()]);
    if hoisted {
        cmd.arg("--hoisted");
    }
    let fail = |message: String| TrainError::Io {
        path: script.to_path_buf(),
        message,
    };
    let out = cmd
        .output()
        .map_err(|e| fail(format!("running it with {}: {e}", python.display())))?;
    if !out.status.success() {
        return Err(fail(format!(
            "{} failed (is PyTorch installed for it?):\n{}",
            python.display(),
            String::from_utf8_lossy(&out.stderr)
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let medians: Vec<(usize, f64)> = text
        .lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            Some((w.next()?.parse().ok()?, w.next()?.parse().ok()?))
        })
        .collect();
    if medians.len() != batches.len() {
        return Err(fail(format!("unexpected output:\n{text}")));
    }
    Ok(medians)
}

/// The speed-up over PyTorch eager running the paper's model that every
/// model should reach (issue 24 §4, the default model included): 1.5× at
/// batch 1,600 and 5× at batch 64.
pub fn speedup_goal(batch: usize) -> f64 {
    if batch >= 1600 {
        1.5
    } else {
        5.0
    }
}

/// The `bench-train` report, line by line to `out`: seconds per training
/// step (forward, backward, Adam) of each model of `models` (every model of
/// [`bench_models`] when empty) at each batch size on random
/// windows, and the sampling time; with `reference`, also through candle
/// ops (autograd); with `pytorch = (python, script)`, every model against
/// PyTorch eager on the paper's model ([`against_pytorch`]).
pub fn report(
    models: &[String],
    batches: &[usize],
    steps: usize,
    reference: bool,
    pytorch: Option<(&Path, &Path)>,
    device: &Device,
    out: &mut dyn FnMut(&str),
) -> Result<(), TrainError> {
    let every = bench_models();
    let models = if models.is_empty() { &every } else { models };
    let steps = steps.max(1);
    out(&format!(
        "training step (T = {FRAMES}, forward + backward + Adam) on {device:?}, {} rayon threads; median and min of {steps} steps after 2 warm-up steps",
        rayon::current_num_threads()
    ));
    out(&format!(
        "{:>9} {:>9} {:>6} {:>10} {:>10} {:>16} {:>12}",
        "model", "path", "batch", "median s", "min s", "windows*frames/s", "sample 36 s"
    ));
    let mut fused = Vec::new();
    for name in models {
        for r in time_steps(name, batches, steps, reference, device)? {
            out(&format!(
                "{:>9} {:>9} {:>6} {:>10.4} {:>10.4} {:>16.0} {:>12.4}",
                r.model,
                r.path,
                r.batch,
                r.median,
                r.min,
                (r.batch * FRAMES) as f64 / r.median,
                r.sample
            ));
            if r.path == "fused" {
                fused.push(r);
            }
        }
    }
    if let Some((python, script)) = pytorch {
        against_pytorch(python, script, &fused, batches, steps, out)?;
    }
    Ok(())
}

/// Every model against PyTorch eager running the paper's model on this
/// machine, in both its forms: *stepwise* (the reference) and
/// *hoisted* (faster at small batches), with the goal of issue 24
/// ([`speedup_goal`]).
fn against_pytorch(
    python: &Path,
    script: &Path,
    rows: &[StepTiming],
    batches: &[usize],
    steps: usize,
    out: &mut dyn FnMut(&str),
) -> Result<(), TrainError> {
    let threads = rayon::current_num_threads();
    let stepwise = pytorch_medians(python, script, batches, steps, threads, false)?;
    let hoisted = pytorch_medians(python, script, batches, steps, threads, true)?;
    out("");
    out("PyTorch eager, paper model (xtask/py/pytorch_vrnn_step.py), median s per step:");
    for ((b, s), (_, h)) in stepwise.iter().zip(&hoisted) {
        out(&format!("  batch {b:>5}: stepwise {s:.4}, hoisted {h:.4}"));
    }
    out("");
    out(&format!(
        "{:>9} {:>6} {:>10} {:>11} {:>10} {:>6} {:>11} {:>10}",
        "model",
        "batch",
        "median s",
        "÷ stepwise",
        "÷ hoisted",
        "goal",
        "met (step)",
        "met (hoist)"
    ));
    let met = |x: f64, goal: f64| if x >= goal { "yes" } else { "no" };
    for r in rows {
        let Some(i) = batches.iter().position(|x| *x == r.batch) else {
            continue;
        };
        let (step, hoist) = (stepwise[i].1 / r.median, hoisted[i].1 / r.median);
        let goal = speedup_goal(r.batch);
        out(&format!(
            "{:>9} {:>6} {:>10.4} {step:>10.2}x {hoist:>9.2}x {goal:>5.1}x {:>11} {:>10}",
            r.model,
            r.batch,
            r.median,
            met(step, goal),
            met(hoist, goal)
        ));
    }
    Ok(())
}
