//! Speed of a training step (forward, backward, Adam) and of sampling, on
//! random windows, for `cargo xtask bench-train`; and PyTorch eager running
//! the paper's model on the same machine (`xtask/py/pytorch_vrnn_step.py`).

use crate::blocks::timing::{self, BlockTime};
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
/// `minute` preset): [`CONDITIONED`] with the pace as a condition, the
/// feed rounds drawn at the sampling temperature, and a wider extractor and
/// decoder ([`crate::options::MINUTE_EXTRACTOR`],
/// [`crate::options::MINUTE_DECODER`]).
pub const DEFAULT: &str = "minute";

/// The bench's name for a step of the default training's late epochs
/// ([`crate::options::MINUTE_LATE`] of its
/// [`crate::options::MINUTE_EPOCHS`]): [`DEFAULT`] with the gradient
/// through the fed-back frames, the fed speed loss and the root weighed
/// [`crate::options::MINUTE_LATE_ROOT_WEIGHT`]
/// ([`crate::train::TrainConfig::late_model`]).
pub const LATE: &str = "minute-late";

/// The CPU a bench ran on, for its header: the model name `/proc/cpuinfo`
/// gives (where there is one) and the width of the matrix products'
/// kernel, so that timings from different machines are not confused.
pub fn cpu_description() -> String {
    let name = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| cpu_model_name(&info).map(str::to_owned))
        .unwrap_or_else(|| std::env::consts::ARCH.to_owned());
    let lanes = if crate::blocks::kernels::has_avx512() {
        "16 lanes, AVX-512"
    } else if crate::blocks::kernels::has_avx2_fma() {
        "8 lanes, AVX2 and FMA"
    } else {
        "`gemm`"
    };
    format!("{name}; products in {lanes}")
}

/// The first `model name` of a `/proc/cpuinfo` text.
fn cpu_model_name(info: &str) -> Option<&str> {
    info.lines().find_map(|line| {
        let (key, value) = line.split_once(':')?;
        (key.trim() == "model name").then(|| value.trim())
    })
}

/// The models `bench-train` times: every model of [`crate::model::MODELS`],
/// then [`CONDITIONED`], [`DEFAULT`] and [`LATE`].
pub fn bench_models() -> Vec<String> {
    let mut v: Vec<String> = crate::model::MODELS
        .iter()
        .map(|m| m.0.to_string())
        .collect();
    v.extend([CONDITIONED, DEFAULT, LATE].map(String::from));
    v
}

/// `name` if it is one of [`bench_models`], or an error listing them (a
/// command-line parser).
pub fn parse_model(name: &str) -> Result<String, String> {
    crate::model::one_of(name, &bench_models())
}

/// The configuration `name` ([`bench_models`]) stands for.
fn bench_config(name: &str) -> Option<Config> {
    if name == CONDITIONED || name == DEFAULT || name == LATE {
        let mut c = Config::named(crate::model::DEFAULT_MODEL)?;
        if name != CONDITIONED {
            let minute = crate::options::Preset::Minute.for_model(c);
            c = match name == LATE {
                true => minute.late_model(minute.epochs - 1)?,
                false => minute.model,
            };
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
    /// With [`Bench::blocks`], each fused block's seconds over the timed
    /// steps ([`timing`]), and those steps' wall-clock seconds.
    pub blocks: Option<(Vec<BlockTime>, f64)>,
}

/// Time `steps` training steps (after 2 warm-up steps) of model `name` at
/// each batch size, on the fused path and, with `reference`, through candle
/// ops and autograd too; with `blocks`, each fused block's share as well.
pub fn time_steps(
    name: &str,
    batches: &[usize],
    steps: usize,
    (reference, blocks): (bool, bool),
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
            // A model with the control reads it, as training does.
            let x = model.with_control(&x, &[])?;
            let cond = bench_condition(&model, b, device)?;
            let mut times = Vec::new();
            let timed = blocks && path == "fused";
            for step in 0..steps.max(1) + 2 {
                if timed && step == 2 {
                    timing::start();
                }
                let eps = noise(0, step as u64, t, b, model.latent, device)?;
                let feed = feed_mask(0, step as u64, b, t, model.parts.self_feed, device)?;
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
            let blocks = timed.then(|| (timing::stop(), times.iter().sum()));
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
                blocks,
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

/// What `bench-train` runs ([`report`]).
pub struct Bench<'a> {
    /// Models of [`bench_models`] (all of them when empty).
    pub models: &'a [String],
    /// Batch sizes.
    pub batches: &'a [usize],
    /// Timed steps per model and batch size.
    pub steps: usize,
    /// Also through candle ops (autograd).
    pub reference: bool,
    /// Also each fused block's share of a step ([`timing`]).
    pub blocks: bool,
    /// `(python, script)`: PyTorch eager on the paper's model as well.
    pub pytorch: Option<(&'a Path, &'a Path)>,
    /// Times the whole bench runs, PyTorch included, one after the other
    /// (at least 1): on a noisy machine each speed-up is then the median
    /// over the rounds of one round's models against that round's PyTorch.
    pub rounds: usize,
}

/// One round of the bench: every model's fused timings, and PyTorch's
/// median step per batch size in its stepwise and hoisted forms.
pub struct Round {
    /// The models' fused rows.
    pub rows: Vec<StepTiming>,
    /// `(batch, seconds)`, stepwise.
    pub stepwise: Vec<(usize, f64)>,
    /// `(batch, seconds)`, hoisted.
    pub hoisted: Vec<(usize, f64)>,
}

/// One model at one batch size over the rounds: its median step (seconds)
/// and its speed-ups against each round's PyTorch, in round order.
#[derive(Clone, Debug, PartialEq)]
pub struct SpeedUp {
    /// Model name.
    pub model: String,
    /// Windows per step.
    pub batch: usize,
    /// Median over the rounds of the model's median step, seconds.
    pub seconds: f64,
    /// PyTorch stepwise ÷ the model, one per round.
    pub stepwise: Vec<f64>,
    /// PyTorch hoisted ÷ the model, one per round.
    pub hoisted: Vec<f64>,
}

/// The median of `v` (the mean of the middle two of an even count; NaN
/// when empty).
fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// Rounds in which `ratios` reach `goal`.
fn rounds_met(ratios: &[f64], goal: f64) -> usize {
    ratios.iter().filter(|&&r| r >= goal).count()
}

/// Every model and batch size of the first round, with its speed-ups in
/// each round (each round's model against the same round's PyTorch).
pub fn speedups(rounds: &[Round]) -> Vec<SpeedUp> {
    let Some(first) = rounds.first() else {
        return Vec::new();
    };
    let at = |v: &[(usize, f64)], b: usize| v.iter().find(|x| x.0 == b).map(|x| x.1);
    first
        .rows
        .iter()
        .map(|r0| {
            let mut u = SpeedUp {
                model: r0.model.clone(),
                batch: r0.batch,
                seconds: 0.0,
                stepwise: Vec::new(),
                hoisted: Vec::new(),
            };
            let mut seconds = Vec::new();
            for round in rounds {
                let Some(r) = round
                    .rows
                    .iter()
                    .find(|r| r.model == r0.model && r.batch == r0.batch)
                else {
                    continue;
                };
                seconds.push(r.median);
                if let (Some(s), Some(h)) =
                    (at(&round.stepwise, r.batch), at(&round.hoisted, r.batch))
                {
                    u.stepwise.push(s / r.median);
                    u.hoisted.push(h / r.median);
                }
            }
            u.seconds = median(&seconds);
            u
        })
        .collect()
}

/// The `bench-train` report, line by line to `out`: seconds per training
/// step (forward, backward, Adam) of each model of `b.models` (every model
/// of [`bench_models`] when empty) at each batch size on random windows,
/// and the sampling time; with `b.reference`, also through candle ops
/// (autograd); with `b.pytorch = (python, script)`, every model against
/// PyTorch eager on the paper's model (`against_pytorch`), over
/// `b.rounds` rounds.
pub fn report(b: &Bench, device: &Device, out: &mut dyn FnMut(&str)) -> Result<(), TrainError> {
    let every = bench_models();
    let models = if b.models.is_empty() {
        &every
    } else {
        b.models
    };
    let steps = b.steps.max(1);
    let rounds = b.rounds.max(1);
    let mut done = Vec::new();
    for round in 1..=rounds {
        if rounds > 1 {
            out(&format!("round {round} of {rounds}"));
        }
        out(&format!(
            "training step (T = {FRAMES}, forward + backward + Adam) on {device:?}{}, {} rayon threads; median and min of {steps} steps after 2 warm-up steps",
            match device {
                Device::Cpu => format!(" ({})", cpu_description()),
                _ => String::new(),
            },
            rayon::current_num_threads()
        ));
        out(&format!(
            "{:>9} {:>9} {:>6} {:>10} {:>10} {:>16} {:>12}",
            "model", "path", "batch", "median s", "min s", "windows*frames/s", "sample 36 s"
        ));
        let mut fused = Vec::new();
        for name in models {
            let flags = (b.reference, b.blocks);
            for r in time_steps(name, b.batches, steps, flags, device)? {
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
                if let Some((t, wall)) = &r.blocks {
                    block_table(t, wall * rayon::current_num_threads() as f64, out);
                }
                if r.path == "fused" {
                    fused.push(r);
                }
            }
        }
        let Some((python, script)) = b.pytorch else {
            continue;
        };
        let threads = rayon::current_num_threads();
        let stepwise = pytorch_medians(python, script, b.batches, steps, threads, false)?;
        let hoisted = pytorch_medians(python, script, b.batches, steps, threads, true)?;
        out("");
        out("PyTorch eager, paper model (xtask/py/pytorch_vrnn_step.py), median s per step:");
        for ((batch, s), (_, h)) in stepwise.iter().zip(&hoisted) {
            out(&format!(
                "  batch {batch:>5}: stepwise {s:.4}, hoisted {h:.4}"
            ));
        }
        out("");
        done.push(Round {
            rows: fused,
            stepwise,
            hoisted,
        });
    }
    if !done.is_empty() {
        against_pytorch(&speedups(&done), out);
    }
    Ok(())
}

/// Every model against PyTorch eager running the paper's model on this
/// machine, in both its forms: *stepwise* (the reference) and
/// *hoisted* (faster at small batches), with the goal of issue 24
/// ([`speedup_goal`]). Over several rounds: the median speed-up, its range,
/// and in how many rounds the goal was met.
fn against_pytorch(rows: &[SpeedUp], out: &mut dyn FnMut(&str)) {
    let rounds = rows.first().map_or(0, |r| r.stepwise.len());
    // Several rounds: each ratio's column also holds its range.
    let (suffix, ws, wh) = match rounds > 1 {
        true => (" [range]", 25, 24),
        false => ("", 11, 10),
    };
    if rounds > 1 {
        out(&format!(
            "over {rounds} rounds: the median of the rounds' speed-ups [lowest–highest], each round's models against that round's PyTorch; met: in how many rounds"
        ));
    }
    out(&format!(
        "{:>9} {:>6} {:>10} {:>ws$} {:>wh$} {:>6} {:>11} {:>10}",
        "model",
        "batch",
        "median s",
        format!("÷ stepwise{suffix}"),
        format!("÷ hoisted{suffix}"),
        "goal",
        "met (step)",
        "met (hoist)"
    ));
    for r in rows {
        let goal = speedup_goal(r.batch);
        let (step, hoist) = (median(&r.stepwise), median(&r.hoisted));
        let (ms, mh) = (rounds_met(&r.stepwise, goal), rounds_met(&r.hoisted, goal));
        if rounds > 1 {
            let range = |v: &[f64]| {
                let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                format!("[{lo:.2}–{hi:.2}]")
            };
            out(&format!(
                "{:>9} {:>6} {:>10.4} {step:>10.2}x {:<14} {hoist:>9.2}x {:<14} {goal:>5.1}x {:>11} {:>10}",
                r.model,
                r.batch,
                r.seconds,
                range(&r.stepwise),
                range(&r.hoisted),
                format!("{ms} of {rounds}"),
                format!("{mh} of {rounds}")
            ));
        } else {
            let met = |n: usize| if n > 0 { "yes" } else { "no" };
            out(&format!(
                "{:>9} {:>6} {:>10.4} {step:>10.2}x {hoist:>9.2}x {goal:>5.1}x {:>11} {:>10}",
                r.model,
                r.batch,
                r.seconds,
                met(ms),
                met(mh)
            ));
        }
    }
}

/// Each block's seconds, forward and backward, and its share of the
/// steps' CPU time `cpu` (their wall-clock seconds × the threads), in the
/// order given ([`timing::stop`]'s, slowest first); what is left ran
/// outside the blocks (candle's own ops and copies, Adam, waiting).
fn block_table(t: &[BlockTime], cpu: f64, out: &mut dyn FnMut(&str)) {
    out(&format!(
        "          {:<24} {:>8} {:>8} {:>7}",
        "block (CPU s, all steps)", "forward", "backward", "share"
    ));
    let mut inside = 0.0;
    for b in t {
        let (f, w) = (b.forward, b.backward);
        inside += f + w;
        out(&format!(
            "          {:<24} {f:>8.3} {w:>8.3} {:>6.1}%",
            b.name,
            100.0 * (f + w) / cpu
        ));
    }
    out(&format!(
        "          {:<24} {:>17.3} {:>6.1}%",
        "outside the blocks",
        cpu - inside,
        100.0 * (cpu - inside) / cpu
    ));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_is_named_from_the_first_model_name_line() {
        let info = "processor\t: 0\nvendor_id\t: GenuineIntel\nmodel\t\t: 167\nmodel name\t: Intel(R) Xeon(R) Processor\n\nprocessor\t: 1\nmodel name\t: Other\n";
        assert_eq!(cpu_model_name(info), Some("Intel(R) Xeon(R) Processor"));
        assert_eq!(cpu_model_name("processor : 0\nmodel : 167\n"), None);
        assert!(cpu_description().contains("; products in "));
    }

    #[test]
    fn the_late_epochs_are_timed_as_the_default_training_runs_them() {
        let (d, l) = (bench_config(DEFAULT).unwrap(), bench_config(LATE).unwrap());
        assert!(bench_models().ends_with(&[DEFAULT.to_string(), LATE.to_string()]));
        assert!(l.parts.rollout_gradient && !d.parts.rollout_gradient);
        assert_eq!(l.parts.root_weight, Some(8.0));
        assert!(l.parts.fed_speed.is_some());
        let mut back = l.clone();
        back.parts.rollout_gradient = false;
        back.parts.root_weight = None;
        back.parts.fed_speed = None;
        assert_eq!(back, d, "nothing else differs");
    }

    fn row(model: &str, batch: usize, median: f64) -> StepTiming {
        StepTiming {
            model: model.into(),
            path: "fused",
            batch,
            median,
            min: median,
            sample: 0.0,
            blocks: None,
        }
    }

    #[test]
    fn the_block_table_gives_each_block_its_share_of_the_cpu_time() {
        let b = |name, forward, backward| BlockTime {
            name,
            forward,
            backward,
            calls: 1,
        };
        let t = [b("linear", 1.0, 2.0), b("kl", 0.5, 0.0)];
        let mut lines = Vec::new();
        block_table(&t, 10.0, &mut |l| lines.push(l.trim().to_string()));
        let words = |l: &str| l.split_whitespace().map(String::from).collect::<Vec<_>>();
        assert_eq!(lines.len(), 4);
        assert_eq!(words(&lines[1]), ["linear", "1.000", "2.000", "30.0%"]);
        assert_eq!(words(&lines[2]), ["kl", "0.500", "0.000", "5.0%"]);
        assert_eq!(
            words(&lines[3]),
            ["outside", "the", "blocks", "6.500", "65.0%"]
        );
    }

    /// Each round's model against the same round's PyTorch; the median over
    /// the rounds; the goal counted round by round.
    #[test]
    fn speed_ups_are_taken_round_by_round() {
        let round = |m: f64, s: f64, h: f64| Round {
            rows: vec![row("minute", 64, m)],
            stepwise: vec![(64, s)],
            hoisted: vec![(64, h)],
        };
        let u = speedups(&[
            round(0.02, 0.10, 0.05),
            round(0.03, 0.18, 0.06),
            round(0.025, 0.10, 0.05),
        ]);
        assert_eq!(u.len(), 1);
        assert_eq!(u[0].seconds, 0.025);
        assert_eq!(u[0].stepwise, vec![0.10 / 0.02, 0.18 / 0.03, 0.10 / 0.025]);
        assert_eq!(median(&u[0].stepwise), 5.0);
        assert_eq!(rounds_met(&u[0].stepwise, speedup_goal(64)), 2);
        assert_eq!(u[0].hoisted, vec![2.5, 2.0, 2.0]);
        assert!(speedups(&[]).is_empty());
    }

    /// One round prints the table as it always did; several print each
    /// ratio's range and the rounds that met the goal.
    #[test]
    fn the_table_shows_the_range_over_several_rounds() {
        let u = |stepwise: Vec<f64>, hoisted: Vec<f64>| SpeedUp {
            model: "minute".into(),
            batch: 64,
            seconds: 0.025,
            stepwise,
            hoisted,
        };
        let mut lines = Vec::new();
        against_pytorch(&[u(vec![5.2], vec![2.9])], &mut |l| {
            lines.push(l.to_string())
        });
        assert!(lines[1].contains("5.20x") && lines[1].contains("yes") && lines[1].contains("no"));
        lines.clear();
        against_pytorch(&[u(vec![5.2, 4.8, 6.0], vec![2.9, 3.0, 2.8])], &mut |l| {
            lines.push(l.to_string())
        });
        assert!(lines[0].starts_with("over 3 rounds"));
        assert_eq!(median(&[4.0, 1.0]), 2.5);
        assert!(lines[2].contains("5.20x [4.80–6.00]"), "{}", lines[2]);
        assert!(lines[2].contains("2 of 3") && lines[2].contains("0 of 3"));
    }
}
