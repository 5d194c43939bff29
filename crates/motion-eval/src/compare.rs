//! Every model trained with several seeds on one dataset, each run
//! evaluated, and one results page (mean ± std over the seeds, the goals
//! each model meets, training time, contact sheets).

use crate::asked::{AskedModel, STANDARD_ASKED};
use crate::horizon::{
    frechet_draws_range, misses, pose_spread_range, pose_spread_ratio, tally, Horizon,
    HorizonOptions, MEASURES as HORIZON_MEASURES,
};
pub use crate::mean_std;
use crate::report::{report, Contexts, EvalReport};
use crate::run::RunSpec;
use crate::samples::{write_samples, SampleOptions};
use crate::{create_dir, mean_of, EvalError};
use motion_vrnn::model::Config;
use motion_vrnn::options::{ConditionOn, Overrides, Preset};
use motion_vrnn::train::{layout, train, Quiet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What to compare, and where.
#[derive(Clone, Debug)]
pub struct CompareOptions {
    /// Dataset directory.
    pub data: PathBuf,
    /// Directory of the runs (`MODEL/seed-N/`); runs already there are reused.
    pub out: PathBuf,
    /// Models (names of [`motion_vrnn::model::MODELS`]).
    pub models: Vec<String>,
    /// Training seeds per model (0, 1, …).
    pub seeds: u64,
    /// Epochs (`None`: the standard schedule's).
    pub epochs: Option<usize>,
    /// The results page (contact sheets go to `images/results/` beside it).
    pub page: PathBuf,
    /// Also roll each run out for a minute from training contexts and
    /// measure every stretch (`eval --horizon`).
    pub horizon: Option<HorizonOptions>,
    /// Read each run's report from its `compare-eval.json` when there is
    /// one instead of evaluating it again (written on every evaluation; the
    /// caller vouches that evaluation has not changed since).
    pub reuse_reports: bool,
    /// A classifier directory (`train-classifier`): also train the `motion`
    /// model with the `standard` preset ([`CONDITIONED`]) and with the
    /// default `minute` preset ([`MINUTE`]) with every seed, and ask both for
    /// each category ([`crate::asked`]).
    pub classifier: Option<PathBuf>,
    /// Of the conditioned runs, only the default ([`MINUTE`]).
    pub default_only: bool,
}

/// The directory name (under [`CompareOptions::out`]) of the `motion` model
/// trained with `--condition category`.
pub const CONDITIONED: &str = "motion-category";

/// What [`CONDITIONED`] is, on the results page.
const CONDITIONED_WHAT: &str = "`motion` trained with `--preset standard` (conditioned on the category), each generated motion asked for the category of the training window it continues (`--category own`; continuing a test window, that window's category): the default of `cargo xtask train` until the `minute` preset (the `motion` column is the same model without categories, `--condition none`)";

/// The directory name of the default model, `motion` trained with the
/// `minute` preset (what `cargo xtask train` trains with no flags).
pub const MINUTE: &str = "motion-minute";

/// What [`MINUTE`] is, on the results page.
const MINUTE_WHAT: &str = "`motion` trained with `--preset minute` (`standard` fed back to every depth at the sampling temperature, with `--condition category+pace+control --judge-stretches 14 --judge-every 10 --inits 3 --extractor 64,32 --decoder 64,96 --epochs 600 --early-stopping 0 --rollout-last 300 --late-root-weight 8`), asked as `motion-category` is and for its context's pace, held to that pace run by run (`--pace-gain`, 0.5) and each run chosen among 8 draws by its context's mean pose (`--draws`): **the default of `cargo xtask train`** ([training.md](training.md), \"Presets\", \"The sampler\")";

/// The file each conditioned run's [`crate::asked::AskedSet`] is kept in.
pub const ASKED_FILE: &str = "compare-asked.json";

/// The file each evaluated run's report is kept in.
pub const REPORT_FILE: &str = "compare-eval.json";

/// Train (or reuse) and evaluate every model × seed of `o`, then write the
/// results page; returns its Markdown. `log` hears one line per step.
pub fn compare(o: &CompareOptions, log: &dyn Fn(&str)) -> Result<String, EvalError> {
    let page_dir = o.page.parent().unwrap_or(Path::new(".")).to_path_buf();
    let images = page_dir.join("images").join("results");
    create_dir(&images)?;
    let mut data = None;
    let mut table: Vec<(String, Vec<SeedRun>)> = Vec::new();
    // Every model, and with a classifier the conditioned runs of `motion`,
    // each motion asked for its context's category.
    let mut entries: Vec<(&str, &str, bool, Preset)> = o
        .models
        .iter()
        .map(|m| (m.as_str(), m.as_str(), false, Preset::Standard))
        .collect();
    if o.classifier.is_some() {
        for (name, preset, _) in conditioned_runs(o) {
            entries.push((name, motion_vrnn::model::DEFAULT_MODEL, true, preset));
        }
    }
    for (name, model, conditioned, preset) in entries {
        let mut runs = Vec::new();
        for seed in 0..o.seeds {
            let dir = o.out.join(name).join(format!("seed-{seed}"));
            let started = std::time::Instant::now();
            if dir.join(layout::LAST).join(layout::META).exists() {
                log(&format!("{name} seed {seed}: reusing {}", dir.display()));
            } else {
                log(&format!(
                    "{name} seed {seed}: training into {}",
                    dir.display()
                ));
                let d = match data {
                    Some(ref d) => d,
                    None => {
                        data.insert(motion_vrnn::data::load(&o.data, &["train", "val"]).map_err(
                            |cause| EvalError::Data {
                                dir: o.data.clone(),
                                cause,
                            },
                        )?)
                    }
                };
                train_one(d, model, seed, o.epochs, conditioned, preset, &dir)
                    .map_err(|e| e.within(format!("training {name} seed {seed}")))?;
            }
            let seconds = train_seconds(&dir).unwrap_or(started.elapsed().as_secs_f64());
            let report = evaluated(o, name, seed, conditioned, &dir, &images, log)?;
            runs.push(SeedRun {
                seed,
                seconds,
                report,
            });
        }
        table.push((name.to_string(), runs));
    }
    let mut md = page(o, &table)?;
    md += &steering(o, &images, log)?;
    if let Some(classifier) = &o.classifier {
        md += &conditioned(o, classifier, &images, log)?;
    }
    motion_render::write_file(&o.page, md.as_bytes())?;
    Ok(md)
}

/// The report of the run of `name` with `seed` in `dir` (kept in
/// [`REPORT_FILE`], reused with [`CompareOptions::reuse_reports`]), logged;
/// seed 0's contact sheet copied into `images`.
fn evaluated(
    o: &CompareOptions,
    name: &str,
    seed: u64,
    conditioned: bool,
    dir: &Path,
    images: &Path,
    log: &dyn Fn(&str),
) -> Result<EvalReport, EvalError> {
    let mut spec = RunSpec::best(dir.to_path_buf(), Some(o.data.clone()));
    if conditioned {
        spec.category = Some(crate::run::OWN.into());
    }
    let kept = dir.join(REPORT_FILE);
    let report = match std::fs::read_to_string(&kept) {
        Ok(text) if o.reuse_reports => {
            log(&format!("{name} seed {seed}: reusing {}", kept.display()));
            serde_json::from_str(&text)?
        }
        _ => {
            let r = report(&spec, Contexts::Split, o.horizon, None)
                .map_err(|e| e.within(format!("evaluating {}", dir.display())))?;
            let json = serde_json::to_string_pretty(&r)? + "\n";
            motion_render::write_file(&kept, json.as_bytes())?;
            r
        }
    };
    log(&format!(
        "{name} seed {seed}: jerk {:.2}x, bone cv {:.2} %, APD {:.2}x, Fréchet {:.1}",
        report.generated.jerk_m_s3 / report.real.jerk_m_s3,
        100.0 * report.generated.bone_cv,
        report.generated.apd_m / report.real.apd_m,
        report.frechet_generated
    ));
    if let Some(h) = &report.horizon {
        let bad = h.stretches.iter().filter(|st| !misses(h, st).is_empty());
        log(&format!(
            "{name} seed {seed}: {} of {} stretches of the minute miss a band",
            bad.count(),
            h.stretches.len()
        ));
    }
    if seed == 0 {
        let samples = dir.join("samples");
        let sheet = SampleOptions {
            n: 12,
            frames: 128,
            reconstruct: 0,
            sheet_columns: 5,
        };
        write_samples(&spec, &sheet, &samples)?;
        let png = images.join(format!("{name}.png"));
        std::fs::copy(samples.join("contact_sheet.png"), &png)
            .map_err(|cause| EvalError::Io { path: png, cause })?;
    }
    Ok(report)
}

/// Each seed's steering report, kept beside its [`REPORT_FILE`].
pub const STEER_FILE: &str = "compare-steer.json";

/// The steering section of the page: the default's runs ([`MINUTE`], a
/// model with the control) each measured by `eval --steer` (kept in
/// [`STEER_FILE`], reused with [`CompareOptions::reuse_reports`]), mean ±
/// std over the seeds, and seed 0's pictures; empty where the default's
/// runs cannot be steered.
fn steering(o: &CompareOptions, images: &Path, log: &dyn Fn(&str)) -> Result<String, EvalError> {
    use crate::steering::{evaluate, seeds_markdown, SteerReport, BUILT_IN, STEER_MOTIONS};
    let mut reports = Vec::new();
    for seed in 0..o.seeds {
        let dir = o.out.join(MINUTE).join(format!("seed-{seed}"));
        let mut spec = RunSpec::best(dir.clone(), Some(o.data.clone()));
        spec.category = Some("walk".into());
        let Ok(run) = crate::run::Run::load(&spec, &["train"]) else {
            return Ok(String::new());
        };
        if !run.meta.config.model.parts.control {
            return Ok(String::new());
        }
        let kept = dir.join(STEER_FILE);
        let report: SteerReport = match std::fs::read_to_string(&kept) {
            Ok(text) if o.reuse_reports => serde_json::from_str(&text)?,
            _ => {
                let pictures = (seed == 0).then_some(images);
                let r = evaluate(
                    &run,
                    STEER_MOTIONS,
                    spec.context,
                    0,
                    pictures,
                    &|m: &str| log(&format!("{MINUTE} seed {seed}: steering {m}")),
                )?;
                let json = serde_json::to_string_pretty(&r)? + "\n";
                motion_render::write_file(&kept, json.as_bytes())?;
                r
            }
        };
        reports.push((seed, report));
    }
    let mut s = format!(
        "\n## Steering (`{MINUTE}`, `cargo xtask eval --steer`)\n\nEach built-in path at the mean speed of the real walks \
         ({:.2} m/s), followed by {STEER_MOTIONS} motions from training contexts of walking (the model alone, asked for walking); \
         mean ± std over the seeds ([metrics.md](metrics.md), \"Steering\"; \"reached\" is the share of motions).\n\n",
        reports.first().map_or(0.0, |r| r.1.walks.speed_m_s)
    );
    s += &seeds_markdown(&reports);
    s += "\nSeed 0, each path from above (black) with the 64 roots over it:\n\n";
    for p in BUILT_IN {
        let name = p.replace(':', "-");
        let _ = writeln!(s, "![{p}](images/results/steer-{name}.png)");
    }
    Ok(s)
}

/// The results page's heading of the goals met.
const GOALS_HEADING: &str = "## Goals met (issue 11)";

/// The `minute` preset's model, as its section says.
const MINUTE_ASKED: AskedModel = AskedModel {
    title: "the default model (`--preset minute`)",
    about: "`cargo xtask train`, the `minute` preset (the `standard` preset's condition with the pace and the \
            control as well, each motion asked for its context's pace, the control left free; fed back to every depth at the sampling temperature; the \
            judge over the minute; the best of 3 initialisations)",
};

/// The `motion` model's conditioned runs (with a classifier): directory,
/// preset, and the results page's section on asking it for categories.
const CONDITIONED_RUNS: [(&str, Preset, &AskedModel); 2] = [
    (CONDITIONED, Preset::Standard, &STANDARD_ASKED),
    (MINUTE, Preset::Minute, &MINUTE_ASKED),
];

/// The conditioned runs `o` trains: [`CONDITIONED_RUNS`], or only the
/// default's with [`CompareOptions::default_only`].
fn conditioned_runs(o: &CompareOptions) -> Vec<(&'static str, Preset, &'static AskedModel)> {
    CONDITIONED_RUNS
        .into_iter()
        .filter(|r| !o.default_only || r.0 == MINUTE)
        .collect()
}

/// Ask each seed's run of each conditioned model (trained with the other
/// models) for every category, draw seed 0's category sheet; the results
/// page's sections.
fn conditioned(
    o: &CompareOptions,
    classifier: &Path,
    images: &Path,
    log: &dyn Fn(&str),
) -> Result<String, EvalError> {
    let mut md = String::new();
    for (name, _, model) in conditioned_runs(o) {
        md += &asked_runs(o, classifier, images, log, name, model)?;
    }
    Ok(md)
}

/// [`conditioned`] for the runs of `name`.
fn asked_runs(
    o: &CompareOptions,
    classifier: &Path,
    images: &Path,
    log: &dyn Fn(&str),
    name: &str,
    model: &AskedModel,
) -> Result<String, EvalError> {
    let mut runs = Vec::new();
    for seed in 0..o.seeds {
        // Trained (or reused) with the other models.
        let dir = o.out.join(name).join(format!("seed-{seed}"));
        let spec = RunSpec::best(dir.clone(), Some(o.data.clone()));
        let kept = dir.join(ASKED_FILE);
        let asked = match std::fs::read_to_string(&kept) {
            Ok(text) if o.reuse_reports => serde_json::from_str(&text)?,
            _ => {
                let a = crate::asked::evaluate(&spec, classifier)
                    .map_err(|e| e.within(format!("asking {}", dir.display())))?;
                let json = serde_json::to_string_pretty(&a)? + "\n";
                motion_render::write_file(&kept, json.as_bytes())?;
                a
            }
        };
        if seed == 0 {
            let m = crate::run::Run::load(&spec, &["train"])?;
            let png = images.join(format!("{name}-categories.png"));
            crate::samples::category_sheet(&m, &spec, 128, 5, &png)?;
        }
        log(&format!(
            "{name} seed {seed}: {} categories, {} of them miss a goal",
            asked.categories.len(),
            asked
                .categories
                .iter()
                .filter(|c| c.in_goals() && !c.misses().is_empty())
                .count()
        ));
        runs.push((seed, asked));
    }
    Ok(crate::asked::page_section(
        &runs,
        &format!("images/results/{name}-categories.png"),
        model,
    ))
}

/// Train model `name` with `preset` and `seed` into `dir` (checkpoints,
/// metrics, `loss.png`), as `cargo xtask train --model NAME --preset PRESET
/// --seed SEED [--condition none]` does.
fn train_one(
    data: &motion_vrnn::data::Dataset,
    name: &str,
    seed: u64,
    epochs: Option<usize>,
    conditioned: bool,
    preset: Preset,
    dir: &Path,
) -> Result<(), EvalError> {
    let model =
        Config::named(name).ok_or_else(|| EvalError::Invalid(format!("unknown model {name:?}")))?;
    let mut cfg = preset.for_model(model);
    cfg.seed = seed;
    if !conditioned {
        Overrides {
            condition: Some(ConditionOn::None),
            ..Overrides::default()
        }
        .apply(&mut cfg);
    }
    if let Some(e) = epochs {
        (cfg.epochs, cfg.budget) = (e, None);
    }
    let device = motion_vrnn::model::default_device();
    let outcome = train(data, &cfg, dir, false, &device, &Quiet)?;
    crate::chart::loss_curves(&dir.join("loss.png"), &outcome.history)
}

/// One evaluated run.
pub struct SeedRun {
    /// Training seed.
    pub seed: u64,
    /// Training seconds (the sum of its epochs').
    pub seconds: f64,
    /// Its evaluation.
    pub report: EvalReport,
}

/// A measure of the results table: name, value, decimals.
type Measure = (&'static str, fn(&EvalReport) -> f64, usize);

const MEASURES: [Measure; 16] = [
    (
        "jerk ÷ real, generated",
        |r| r.generated.jerk_m_s3 / r.real.jerk_m_s3,
        2,
    ),
    (
        "jerk ÷ real, reconstructed",
        |r| r.reconstructed.jerk_m_s3 / r.real.jerk_m_s3,
        2,
    ),
    (
        "bone length std/mean, generated (%)",
        |r| 100.0 * r.generated.bone_cv,
        2,
    ),
    (
        "foot contact ÷ real",
        |r| r.generated.contact_share / r.real.contact_share,
        2,
    ),
    (
        "skating among contact frames ÷ real",
        |r| r.generated.skate_in_contact / r.real.skate_in_contact,
        2,
    ),
    ("APD ÷ real", |r| r.generated.apd_m / r.real.apd_m, 2),
    (
        "hips height ÷ real",
        |r| r.generated.hip_height_m / r.real.hip_height_m,
        2,
    ),
    (
        "hips height, last 32 ÷ real",
        |r| r.generated.hip_height_end_m / r.real.hip_height_end_m,
        2,
    ),
    (
        "hips speed ÷ real",
        |r| r.generated.root_speed_m_s / r.real.root_speed_m_s,
        2,
    ),
    (
        "hips speed, last 32 ÷ real",
        |r| r.generated.root_speed_end_m_s / r.real.root_speed_end_m_s,
        2,
    ),
    ("Fréchet, generated", |r| r.frechet_generated, 1),
    ("Fréchet, train vs test (reference)", |r| r.frechet_train, 1),
    (
        "Fréchet, train vs test, test-sized draws (mean)",
        |r| mean_of(&r.frechet_train_subsets),
        1,
    ),
    ("Fréchet, reconstructed", |r| r.frechet_reconstructed, 2),
    (
        "within-window spread ÷ real, generated",
        |r| r.spread.generated / r.spread.real,
        2,
    ),
    ("test negative ELBO per frame", |r| r.neg_elbo_per_frame, 3),
];

/// A goal: its name and whether a run meets it.
type Goal = (&'static str, fn(&EvalReport) -> bool);

/// The goals of issue 11.
const GOALS: [Goal; 8] = [
    ("jerk 0.67–1.5× (generated and reconstructed)", |r| {
        let (g, c) = (
            r.generated.jerk_m_s3 / r.real.jerk_m_s3,
            r.reconstructed.jerk_m_s3 / r.real.jerk_m_s3,
        );
        (0.67..=1.5).contains(&g) && (0.67..=1.5).contains(&c)
    }),
    ("bone cv ≤ 1 %", |r| r.generated.bone_cv <= 0.01),
    ("contact 0.75–1.25×", |r| {
        within(r.generated.contact_share / r.real.contact_share)
    }),
    ("skating in contact ≤ 2×", |r| {
        r.generated.skate_in_contact <= 2.0 * r.real.skate_in_contact
    }),
    ("APD 0.75–1.25×", |r| {
        within(r.generated.apd_m / r.real.apd_m)
    }),
    ("hips height 0.75–1.25× (whole, last 32)", |r| {
        within(r.generated.hip_height_m / r.real.hip_height_m)
            && within(r.generated.hip_height_end_m / r.real.hip_height_end_m)
    }),
    ("hips speed 0.75–1.25× (whole, last 32)", |r| {
        within(r.generated.root_speed_m_s / r.real.root_speed_m_s)
            && within(r.generated.root_speed_end_m_s / r.real.root_speed_end_m_s)
    }),
    ("Fréchet ≤ train-vs-test", |r| {
        r.frechet_generated <= r.frechet_train
    }),
];

/// The seeds' reports averaged field by field (numbers that differ are
/// averaged, everything else is the first report's): the goals of issue 11
/// hold for the mean over the seeds. Every run shares the real windows, so
/// a ratio of the mean is the mean of the ratios.
pub fn mean_report(runs: &[SeedRun]) -> Result<EvalReport, EvalError> {
    let values = runs
        .iter()
        .map(|r| serde_json::to_value(&r.report))
        .collect::<Result<Vec<_>, _>>()?;
    if values.is_empty() {
        return Err(EvalError::Invalid("no runs to average".into()));
    }
    Ok(serde_json::from_value(average(&values))?)
}

/// JSON values of one shape averaged: real numbers that differ become their
/// mean; objects, and arrays of objects of one length, are averaged key by
/// key and element by element; anything else (integers, other arrays,
/// strings) is the first's.
fn average(values: &[serde_json::Value]) -> serde_json::Value {
    use serde_json::Value;
    match &values[0] {
        Value::Object(first) => Value::Object(
            first
                .keys()
                .map(|k| {
                    let each: Vec<Value> = values.iter().map(|v| v[k].clone()).collect();
                    (k.clone(), average(&each))
                })
                .collect(),
        ),
        // Arrays of objects of one length (the stretches of a minute):
        // element by element.
        Value::Array(first)
            if first.iter().all(Value::is_object)
                && values
                    .iter()
                    .all(|v| v.as_array().is_some_and(|a| a.len() == first.len())) =>
        {
            Value::Array(
                (0..first.len())
                    .map(|i| {
                        let each: Vec<Value> = values.iter().map(|v| v[i].clone()).collect();
                        average(&each)
                    })
                    .collect(),
            )
        }
        // Real numbers that differ: their mean. Integers (counts, epochs)
        // stay the first's, so they still read back as integers.
        Value::Number(_)
            if values.iter().all(Value::is_f64) && values.iter().any(|v| v != &values[0]) =>
        {
            let xs: Vec<f64> = values.iter().filter_map(Value::as_f64).collect();
            serde_json::json!(mean_of(&xs))
        }
        first => first.clone(),
    }
}

fn within(x: f64) -> bool {
    (0.75..=1.25).contains(&x)
}

/// Training seconds of a run: the sum of its epochs' times.
fn train_seconds(dir: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(dir.join(layout::METRICS)).ok()?;
    let secs = text
        .lines()
        .filter_map(|l| serde_json::from_str::<motion_vrnn::train::EpochMetrics>(l).ok())
        .map(|m| m.seconds)
        .sum();
    Some(secs)
}

/// A table's header row and rule: `first`, then one column per model.
fn header(first: &str, table: &[(String, Vec<SeedRun>)]) -> String {
    let mut s = format!("| {first} |");
    for (name, _) in table {
        let _ = write!(s, " `{name}` |");
    }
    s += "\n|---|";
    for _ in table {
        s += "---|";
    }
    s + "\n"
}

/// The results page (Markdown).
pub fn page(a: &CompareOptions, table: &[(String, Vec<SeedRun>)]) -> Result<String, EvalError> {
    let mut s = String::from(if a.default_only {
        "# Results: the default model, several seeds\n\n"
    } else {
        "# Results: every model, several seeds\n\n"
    });
    let _ = writeln!(
        s,
        "Written by `cargo xtask compare --data {} --page {}{}{}` ({} seeds per model, each with its preset's schedule{}). \
         Each run is evaluated as `cargo xtask eval` does: its `best` checkpoint, the 51-odd real `test` windows, \
         one generated motion of 128 frames per test window (sampling seed 0, at the model's temperature, each continuing the first 16 frames of its window; \
         a conditioned model asked for that window's category at guidance {}), \
         and the reconstructions of the test windows. Every value is the mean ± std over the seeds; \
         measures are defined in [metrics.md](metrics.md).\n",
        a.data.display(),
        a.page.display(),
        a.classifier
            .as_ref()
            .map(|c| format!(" --classifier {}", c.display()))
            .unwrap_or_default(),
        if a.default_only { " --default-only" } else { "" },
        a.seeds,
        a.epochs.map(|e| format!(", {e} epochs")).unwrap_or_default(),
        motion_vrnn::generate::GUIDANCE
    );
    s += "The protocol ([metrics.md](metrics.md), \"The protocol\"): a generated motion reads its context and \
          nothing after it (its category is its window's, its pace its context frames'); an evaluation on `val` \
          compares with `train` and `val` windows only; this page reads `test`, once, to report. Every table \
          reports `test` or, for the minute and the categories, every real window.\n\n\
          Which split chose each adopted setting: the `best` checkpoint, the judge on training windows (`val` \
          gives its Fréchet reference); the parts of the `motion` model and their settings (issue 11), on `test`; \
          the seam easing and restarting, on training contexts and the `test` continuation together; the \
          category and pace conditioning, the guidance scale, the pace gain, the draws and the `minute` preset, \
          on `val` and the minute from training contexts, but with references that pooled `test` windows and \
          the pace of the whole window, the protocol before 2026-12-05 ([experiments.md](experiments.md)); none \
          of them has been chosen again under this protocol yet. Under it: the pace trained on each window's first \
          16 frames, and the control (steering) beside it, on `val` (seed 0, the minute from training contexts); \
          the follower's lead and the pace asked while steering, on the steering measures from training \
          contexts (3 seeds).\n\n";
    s += "Models (each explained, with a diagram of one time step, in [training.md](training.md)):\n\n";
    for (name, _) in table {
        let what = match name.as_str() {
            CONDITIONED => CONDITIONED_WHAT,
            MINUTE => MINUTE_WHAT,
            _ => motion_vrnn::model::MODELS
                .iter()
                .find(|m| m.0 == name)
                .map_or("", |m| m.1),
        };
        let _ = writeln!(s, "- `{name}`: {what}");
    }
    s += "\n";
    s += &header("measure", table);
    let mut rows: Vec<Measure> = MEASURES.to_vec();
    rows.push(("training time, s", |_| f64::NAN, 0));
    for (label, f, p) in rows {
        let _ = write!(s, "| {label} |");
        for (_, runs) in table {
            let v: Vec<f64> = if label.starts_with("training time") {
                runs.iter().map(|r| r.seconds).collect()
            } else {
                runs.iter().map(|r| f(&r.report)).collect()
            };
            let (m, sd) = mean_std(&v);
            let _ = write!(s, " {m:.p$} ± {sd:.p$} |");
        }
        s += "\n";
    }
    s += "\nTraining time is the wall-clock time of a run's epochs as it was trained (`metrics.jsonl`; a probe of \
          several initialisations before them, `--inits`, is not counted), so it depends on what else the machine \
          was doing then; `cargo xtask bench-train` compares speeds.\n";
    s += &format!("\n{GOALS_HEADING}: on the mean over the seeds, and seed by seed\n\n");
    s += &header("goal", table);
    let means = table
        .iter()
        .map(|(name, runs)| {
            mean_report(runs).map_err(|e| e.within(format!("averaging the reports of {name}")))
        })
        .collect::<Result<Vec<EvalReport>, EvalError>>()?;
    let mark = |ok: bool| if ok { "✓" } else { "✗" };
    for (goal, ok) in GOALS {
        let _ = write!(s, "| {goal} |");
        for ((_, runs), mean) in table.iter().zip(&means) {
            let marks: Vec<String> = runs
                .iter()
                .map(|r| format!("{}{}", r.seed, mark(ok(&r.report))))
                .collect();
            let _ = write!(s, " **mean {}** · {} |", mark(ok(mean)), marks.join(" "));
        }
        s += "\n";
    }
    s += &minute(table, &means);
    s += "\n## Contact sheets (seed 0: 12 generated motions of 128 frames, 5 columns from the first frame to the last, labelled in seconds)\n\n";
    for (name, _) in table {
        let _ = writeln!(s, "### `{name}`\n\n![{name}](images/results/{name}.png)\n");
    }
    Ok(s)
}

/// Which minute of a report a row shows: the sampler's or the model alone's.
type Pick = fn(&EvalReport) -> Option<&Horizon>;

/// How a row of the model alone is named (one draw, pace not held).
const ALONE: &str = ", model alone";

/// Per model, the minutes of its seeds from the default sampler, then (where
/// the sampler holds the pace) from the model alone: name, the row's suffix
/// and the horizons.
fn sampled(table: &[(String, Vec<SeedRun>)]) -> Vec<(&str, &'static str, Vec<Horizon>)> {
    let mut out = Vec::new();
    for (name, runs) in table {
        let of = |pick: Pick| -> Vec<Horizon> {
            runs.iter()
                .filter_map(|r| pick(&r.report).cloned())
                .collect()
        };
        out.push((name.as_str(), "", of(|r| r.horizon.as_ref())));
        let alone = of(|r| r.horizon_alone.as_ref());
        if !alone.is_empty() {
            out.push((name.as_str(), ALONE, alone));
        }
    }
    out
}

/// The long-horizon section: per model, its first and last stretch of a
/// minute from training contexts (mean ± std over seeds, as ÷ all real
/// windows), and the goal of issue 24 §2 stretch by stretch.
fn minute(table: &[(String, Vec<SeedRun>)], means: &[EvalReport]) -> String {
    let Some(h0) = means.iter().find_map(|m| m.horizon.as_ref()) else {
        return String::new();
    };
    let mut s = format!(
        "\n## A minute from training contexts (issue 24)\n\n\
         Each run rolls {} motions out for {:.0} s, each continuing the first 16 frames of a random \
         training window (`eval --horizon`, sampling seed 0), cuts them into {}-frame stretches, re-bases \
         each to its own start and measures it against all {} real windows of the dataset (generated ÷ real; \
         Fréchet against the test windows, reference {:.1}). The first stretch is the 4-second motion from \
         training contexts, the last ends the minute. Mean ± std over the seeds; the first row gives the range \
         of each ratio for draws of real windows of the same size, and of the Fréchet distance for draws of as \
         many training windows. Pose spread: how widely the stretches' \
         average poses differ across motions, ÷ real (a diagnostic of the Fréchet distance, \
         [metrics.md](metrics.md)). In the air: the share of frames with no joint within 5 cm of the floor, \
         in % (the real windows' in the first row). A model whose sampler holds the pace ({} samplings \
         per output frame) has rows `…{ALONE}` too: the same contexts and noise seed, one draw, the pace \
         asked but not held (1 sampling per frame).\n\n| model, stretch |",
        h0.motions,
        h0.seconds,
        h0.frames,
        h0.real_windows,
        h0.frechet_reference,
        means
            .iter()
            .filter_map(|m| m.horizon.as_ref())
            .map(|h| h.samplings_per_frame)
            .max()
            .unwrap_or(1)
    );
    for (name, _) in HORIZON_MEASURES {
        let _ = write!(s, " {name} |");
    }
    s += " bone cv % | in the air % | Fréchet | pose spread |\n|---|";
    s += &"---|".repeat(HORIZON_MEASURES.len() + 4);
    s += "\n| real vs real |";
    for sp in &h0.real_spread {
        let _ = write!(s, " {:.2}–{:.2} |", sp.lo, sp.hi);
    }
    let _ = writeln!(
        s,
        " | real {:.1} | {} | {} |",
        100.0 * h0.real.airborne_share,
        frechet_draws_range(h0),
        pose_spread_range(h0)
    );
    for (name, sampler, hs) in sampled(table) {
        let Some(n) = hs.first().map(|h| h.stretches.len()) else {
            continue;
        };
        for k in [0, n - 1] {
            let st = &hs[0].stretches[k];
            let _ = write!(
                s,
                "| `{name}`{sampler} {:.1}–{:.1} s |",
                st.start_s,
                st.start_s + hs[0].frames as f64 / 30.0
            );
            let cell = |v: Vec<f64>, p: usize| {
                let (m, sd) = mean_std(&v);
                format!(" {m:.p$} ± {sd:.p$} |")
            };
            for (_, f) in HORIZON_MEASURES {
                s += &cell(
                    hs.iter()
                        .map(|h| f(&h.stretches[k].generated) / f(&h.real))
                        .collect(),
                    2,
                );
            }
            s += &cell(
                hs.iter()
                    .map(|h| 100.0 * h.stretches[k].generated.bone_cv)
                    .collect(),
                2,
            );
            s += &cell(
                hs.iter()
                    .map(|h| 100.0 * h.stretches[k].generated.airborne_share)
                    .collect(),
                1,
            );
            s += &cell(hs.iter().map(|h| h.stretches[k].frechet).collect(), 1);
            let spread: Option<Vec<f64>> = hs
                .iter()
                .map(|h| pose_spread_ratio(h, &h.stretches[k]))
                .collect();
            s += &spread.map_or(" n/a |".into(), |v| cell(v, 2));
            s += "\n";
        }
    }
    s + &realism_table(table) + &minute_goals(table, means)
}

/// The realism of each model's minute (and the model alone's), mean ± std
/// over the seeds ([`crate::horizon::Realism`]).
fn realism_table(table: &[(String, Vec<SeedRun>)]) -> String {
    let mut s = String::from(
        "\nRealism: a classifier two-sample test (`eval`'s minute; a logistic regression on each window's \
         per-feature mean, spread, step and second step, cross-validated by take and by motion): held-out \
         balanced accuracy at telling the stretch from the real windows, 0.5 when it cannot (goal ≤ 0.65). \
         Mean ± std over the seeds.\n\n| model | first stretch | last stretch | real vs real |\n|---|---|---|---|\n",
    );
    let mut rows = 0;
    for (name, sampler, hs) in sampled(table) {
        let r: Vec<&crate::horizon::Realism> =
            hs.iter().filter_map(|h| h.realism.as_ref()).collect();
        let cell = |f: fn(&crate::horizon::Realism) -> Option<f64>| {
            let v: Option<Vec<f64>> = r.iter().map(|x| f(x)).collect();
            v.filter(|v| !v.is_empty()).map_or("n/a".into(), |v| {
                let (m, sd) = mean_std(&v);
                format!("{m:.2} ± {sd:.2}")
            })
        };
        if r.is_empty() {
            continue;
        }
        rows += 1;
        let _ = writeln!(
            s,
            "| `{name}`{sampler} | {} | {} | {} |",
            cell(|x| x.first),
            cell(|x| x.last),
            cell(|x| x.real_vs_real)
        );
    }
    if rows == 0 {
        return String::new();
    }
    s
}

/// The goal of the minute, model by model (and the model alone where its
/// sampler holds the pace): stretches within every band on the mean of the
/// seeds, the bands missed, and the first stretch seed by seed.
fn minute_goals(table: &[(String, Vec<SeedRun>)], means: &[EvalReport]) -> String {
    let mut s = String::from("\n### Goal of issue 24 §2: every stretch of the minute within the bands\n\n\
          Bands: jerk 0.67–1.5× (generated, and the reconstruction's), bone cv ≤ 1 %, contact 0.75–1.25×, \
          skating in contact ≤ 2×, APD 0.75–1.25×, hips height and speed 0.75–1.25× (whole stretch and \
          last 32 frames), turning 0.67–1.5×, Fréchet ≤ train-vs-test. On the mean over the seeds every \
          stretch must pass; the first stretch must pass on every seed.\n\n\
          | model | stretches passing (mean of seeds) | bands missed, mean of seeds (stretches) | first stretch, seed by seed |\n|---|---|---|---|\n",
    );
    let variants: [(&str, Pick); 2] = [
        ("", |r| r.horizon.as_ref()),
        (ALONE, |r| r.horizon_alone.as_ref()),
    ];
    for ((sampler, pick), ((name, runs), mean)) in variants
        .iter()
        .flat_map(|v| std::iter::repeat(v).zip(table.iter().zip(means)))
    {
        let Some(h) = pick(mean) else { continue };
        let recon_ok =
            |r: &EvalReport| (0.67..=1.5).contains(&(r.reconstructed.jerk_m_s3 / r.real.jerk_m_s3));
        let (clean, mut missed) = tally(h);
        let passing = if recon_ok(mean) { clean } else { 0 };
        if !recon_ok(mean) {
            missed.push(("reconstruction jerk", h.stretches.len()));
        }
        let seeds: Vec<String> = runs
            .iter()
            .filter_map(|r| {
                let h = pick(&r.report)?;
                let m = misses(h, h.stretches.first()?);
                let ok = m.is_empty() && recon_ok(&r.report);
                Some(match ok {
                    true => format!("{}✓", r.seed),
                    false => format!("{}✗ ({})", r.seed, m.join(", ")),
                })
            })
            .collect();
        let missed: Vec<String> = missed.iter().map(|(b, n)| format!("{b} ({n})")).collect();
        let _ = writeln!(
            s,
            "| `{name}`{sampler} | {passing} of {} | {} | {} |",
            h.stretches.len(),
            if missed.is_empty() {
                "none".into()
            } else {
                missed.join("; ")
            },
            seeds.join(" · ")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::average;
    use serde_json::json;

    #[test]
    fn reports_average_field_by_field() {
        let a = json!({"epoch": 250, "split": "test", "generated": {"apd_m": 1.0}, "d": [1.0]});
        let b = json!({"epoch": 330, "split": "test", "generated": {"apd_m": 2.0}, "d": [3.0]});
        let c = json!({"epoch": 245, "split": "test", "generated": {"apd_m": 6.0}, "d": [5.0]});
        // Integers stay the first's (they deserialise into usize); arrays
        // of numbers too.
        assert_eq!(
            average(&[a, b, c]),
            json!({"epoch": 250, "split": "test", "generated": {"apd_m": 3.0}, "d": [1.0]})
        );
        // Arrays of objects of one length average element by element.
        let a = json!({"s": [{"x": 1.0}, {"x": 2.0}]});
        let b = json!({"s": [{"x": 3.0}, {"x": 6.0}]});
        assert_eq!(average(&[a, b]), json!({"s": [{"x": 2.0}, {"x": 4.0}]}));
    }
}
