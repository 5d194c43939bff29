//! Motion to order, measured the way the field measures conditioned
//! generation (ACTOR, MDM): a model trained with `--condition category` is
//! asked for each category in turn, and the motion classifier
//! (`train-classifier`) says whether it got that category; the plain
//! measures say whether a `walk` moves at a walking speed.
//!
//! Per category with at least [`MIN_TRAIN_WINDOWS`] training windows,
//! [`PER_CATEGORY`] motions asked for it, each continuing a training window
//! of it, beside the same contexts continued with no category asked (row 0
//! of the condition table): the second shows what the contexts alone give.

use crate::run::{Asking, Run, RunSpec};
use crate::EvalError;
use mocap_ingest::category::Category;
use mocap_ingest::Pose;
use motion_metrics::{motion_stats, MotionStats, Options};
use motion_vrnn::classifier::{self, Classifier, Outputs};
use motion_vrnn::generate::{self, to_poses, Ask};
use motion_vrnn::MotionModel;
use serde::{Deserialize, Serialize};

/// Motions asked for each category.
pub const PER_CATEGORY: usize = 64;

/// Categories with fewer training windows are left out of the goals.
pub const MIN_TRAIN_WINDOWS: usize = 30;

/// Draws of real windows for the real-vs-real spread of a category.
pub const REAL_DRAWS: usize = 20;

/// The plain measures of one group of windows (`docs/metrics.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plain {
    /// Windows in the group.
    pub windows: usize,
    /// Hips horizontal speed, m/s.
    pub speed_m_s: f64,
    /// Share of foot-frames in contact.
    pub contact: f64,
    /// Mean jerk, m/s³.
    pub jerk_m_s3: f64,
    /// APD, m (None below two windows).
    pub apd_m: Option<f64>,
    /// Stride, m (`motion_metrics::stride`; 0 in reports written before it).
    #[serde(default)]
    pub stride_m: f64,
    /// Creep of planted toes, m/s (`MotionStats::creep_m_s`; 0 in reports
    /// written before it).
    #[serde(default)]
    pub creep_m_s: f64,
}

/// The model a results-page section is about: its heading and what it is.
pub struct AskedModel {
    /// Heading, after "Motion to order: ".
    pub title: &'static str,
    /// How it is trained (Markdown).
    pub about: &'static str,
}

/// The `standard` preset's model, conditioned on the category, as its
/// section says.
pub const STANDARD_ASKED: AskedModel = AskedModel {
    title: "`--preset standard`, conditioned on the category",
    about: "`cargo xtask train --preset standard` (the `motion` model with a learned row per category added to \
            the pre-activations of the posterior, the LSTM gates, the prior and the decoder's first layer; 10 % of \
            windows trained without one; the default until the `minute` preset)",
};

/// The plain measures of `poses` (None when empty).
pub fn plain(poses: &[Vec<Pose>]) -> Option<Plain> {
    if poses.is_empty() {
        return None;
    }
    let m = motion_stats(poses, &Options::default());
    Some(Plain {
        windows: poses.len(),
        speed_m_s: m.root_speed_m_s,
        contact: m.contact_share,
        jerk_m_s3: m.jerk_m_s3,
        apd_m: (poses.len() > 1).then_some(m.apd_m),
        stride_m: m.stride_m,
        creep_m_s: m.creep_m_s,
    })
}

/// One category asked for.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Asked {
    /// The category.
    pub category: String,
    /// Its training windows.
    pub train_windows: usize,
    /// Its windows in the evaluated split (`--split`, `test` by default).
    pub split_windows: usize,
    /// Share of its real windows of the evaluated split the classifier
    /// recognises (None without such windows).
    pub real_accuracy: Option<f64>,
    /// Share of the motions asked for it recognised as it.
    pub accuracy: f64,
    /// Share of the same contexts continued without a category recognised
    /// as it.
    pub accuracy_unasked: f64,
    /// Fréchet distance (classifier features) of the motions asked for it
    /// to its real windows of the evaluated split (None below two).
    pub frechet: Option<f64>,
    /// The same for its real training windows (the reference).
    pub frechet_reference: Option<f64>,
    /// Its real windows (every split).
    pub real: Plain,
    /// The motions asked for it.
    pub generated: Plain,
    /// The same contexts continued without a category.
    pub unasked: Plain,
    /// Smallest and largest ratio of hips speed, then of contact share, of
    /// [`REAL_DRAWS`] draws of half its real windows to all of them.
    pub real_spread: [(f64, f64); 2],
    /// The same for the stride (None in reports written before it).
    #[serde(default)]
    pub stride_spread: Option<(f64, f64)>,
    /// What the classifier takes the motions asked for it for when not for
    /// it: each other category it predicts, with its share of the motions,
    /// largest first (empty in reports written before it).
    #[serde(default)]
    pub taken_for: Vec<(String, f64)>,
}

impl Asked {
    /// Whether the category counts for the goals.
    pub fn in_goals(&self) -> bool {
        self.train_windows >= MIN_TRAIN_WINDOWS
    }

    /// The goals of issue 25 it misses: recognised at least 0.9 × as often
    /// as its real test windows, hips speed and contact share 0.75–1.25 ×
    /// its real windows'.
    pub fn misses(&self) -> Vec<&'static str> {
        let mut m = Vec::new();
        if let Some(r) = self.real_accuracy {
            if self.accuracy < 0.9 * r {
                m.push("recognition");
            }
        }
        let band = |g: f64, r: f64| r > 0.0 && (0.75..=1.25).contains(&(g / r));
        if !band(self.generated.speed_m_s, self.real.speed_m_s) {
            m.push("speed");
        }
        if !band(self.generated.contact, self.real.contact) {
            m.push("contact");
        }
        m
    }
}

/// How far the categories asked for keep the differences their real
/// windows have in one measure ([`motion_metrics::slope`] over the
/// categories of the goals, `docs/metrics.md`, "Categories kept apart"):
/// 1, as far apart as real ones; 0, every category alike.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Separation {
    /// Slope of the motions asked for on the real windows, category by
    /// category.
    pub asked: f64,
    /// The same for the contexts continued without a category.
    pub unasked: f64,
    /// Smallest and largest slope of the [`REAL_DRAWS`] draws of half of
    /// each category's real windows on all of them.
    pub real: (f64, f64),
}

/// Every category asked for (`eval.json`'s `classifier.asked`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AskedSet {
    /// The evaluated split (`--split`): the real reference of recognition
    /// and of the Fréchet distances.
    pub split: String,
    /// Guidance scale.
    pub guidance: f64,
    /// Motions per category.
    pub per_category: usize,
    /// Per category of the model.
    pub categories: Vec<Asked>,
    /// Fréchet distance (classifier features) of every motion asked for to
    /// the real windows of the evaluated split (None below two).
    pub frechet: Option<f64>,
    /// Diversity of every motion asked for.
    pub diversity: Option<f64>,
    /// Multimodality by the category asked for.
    pub multimodality: Option<f64>,
    /// Every measure of every motion asked for (the unconditioned goals
    /// hold for the whole set).
    pub generated: MotionStats,
    /// Every measure of every real window.
    pub real: MotionStats,
    /// Fréchet distance (window summaries, `docs/metrics.md`) of every
    /// motion asked for to the test windows, and of the training windows
    /// to them (the reference).
    pub frechet_summaries: (f64, f64),
    /// How far apart the categories' hips speeds are kept (None below two
    /// categories in the goals, and in reports written before it).
    #[serde(default)]
    pub speed_separation: Option<Separation>,
    /// The same for the stride.
    #[serde(default)]
    pub stride_separation: Option<Separation>,
}

/// Every real window of the reference splits of an evaluated split
/// ([`crate::horizon::reference_splits`], in that order) in global positions
/// with its label, and what the classifier made of each split: computed
/// once, read by [`crate::recognition`] and [`ask_each`].
pub struct RealSeen<'a> {
    /// `(split, outputs, labels)`.
    pub splits: Vec<(&'static str, Outputs, &'a [Category])>,
    /// Every real window, in global positions.
    pub poses: Vec<Vec<Pose>>,
    /// The label of each.
    pub labels: Vec<Category>,
}

impl<'a> RealSeen<'a> {
    /// The real windows of `m` that an evaluation of `split` compares with,
    /// seen by the classifier `c`.
    pub fn of(m: &'a Run, c: &Classifier, split: &str) -> Result<Self, EvalError> {
        let mut seen = RealSeen {
            splits: Vec::new(),
            poses: Vec::new(),
            labels: Vec::new(),
        };
        for &split in crate::horizon::reference_splits(split) {
            if let Some((w, labels)) = m.data.split(split) {
                seen.splits.push((split, c.outputs(w, &m.device)?, labels));
                let windows = generate::windows_of(w);
                seen.poses
                    .extend(windows.iter().map(|x| to_poses(x, &m.data.stats)));
                seen.labels.extend_from_slice(labels);
            }
        }
        Ok(seen)
    }
}

impl RealSeen<'_> {
    /// The classifier's outputs of `split`, with its labels.
    pub fn split(&self, split: &str) -> Option<&(&'static str, Outputs, &[Category])> {
        self.splits.iter().find(|s| s.0 == split)
    }

    /// The features of `split`'s windows labelled `c`.
    fn features(&self, split: &str, c: Category) -> Vec<Vec<f32>> {
        self.split(split).map_or(Vec::new(), |(_, o, l)| {
            o.features
                .iter()
                .zip(l.iter())
                .filter(|(_, &x)| x == c)
                .map(|(f, _)| f.clone())
                .collect()
        })
    }
}

/// Ask the conditioned run `m` for each of its categories and measure what
/// comes back with the classifier `c`; None for an unconditioned model.
pub fn ask_each(
    m: &Run,
    spec: &RunSpec,
    c: &Classifier,
    seen: &RealSeen,
) -> Result<Option<AskedSet>, EvalError> {
    let config = m.model.model.config();
    if config.categories.is_empty() {
        return Ok(None);
    }
    let train = m.split("train")?;
    let f = train.features;
    let opts = Options::default();
    let global = |x: &Vec<f32>| m.generated_poses(x);
    let (mut out, mut all_gen, mut all_feat, mut all_labels, mut draws) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (row, name) in config.categories.iter().enumerate() {
        let cat: Category = name.parse().map_err(EvalError::Invalid)?;
        let One {
            asked,
            draws: d,
            generated: gen,
            features,
        } = ask_one(m, spec, c, seen, row + 1, cat)?;
        out.push(asked);
        draws.push(d);
        all_labels.extend(std::iter::repeat_n(cat, gen.len()));
        all_feat.extend(features);
        all_gen.extend(gen);
    }
    let kept: Vec<(&Asked, &Draws)> = out
        .iter()
        .zip(&draws)
        .filter(|(a, _)| a.in_goals())
        .collect();
    let speed_separation = separation(&kept, |p| p.speed_m_s, |s| s.root_speed_m_s);
    let stride_separation = separation(&kept, |p| p.stride_m, |s| s.stride_m);
    let test_all = seen
        .split(&spec.split)
        .map_or(Vec::new(), |s| s.1.features.clone());
    let gen_poses: Vec<Vec<Pose>> = all_gen.iter().map(global).collect();
    let summaries = |set: &[Vec<f32>]| generate::summaries(set, f);
    let test_s = summaries(&generate::windows_of(m.split(&spec.split)?));
    Ok(Some(AskedSet {
        split: spec.split.clone(),
        guidance: spec.guidance,
        per_category: PER_CATEGORY,
        categories: out,
        frechet: (test_all.len() >= 2).then(|| classifier::feature_frechet(&all_feat, &test_all)),
        diversity: classifier::diversity(&all_feat, classifier::DIVERSITY_SAMPLES, spec.seed),
        multimodality: classifier::multimodality(
            &all_feat,
            &all_labels,
            classifier::MULTIMODALITY_SAMPLES,
            spec.seed,
        ),
        generated: motion_stats(&gen_poses, &opts),
        real: motion_stats(&seen.poses, &opts),
        frechet_summaries: (
            motion_metrics::frechet(&test_s, &summaries(&all_gen)),
            motion_metrics::frechet(&test_s, &summaries(&generate::windows_of(train))),
        ),
        speed_separation,
        stride_separation,
    }))
}

/// One category asked of a conditioned run: its measures, the draws of its
/// real windows, the motions asked for it and their classifier features.
struct One {
    asked: Asked,
    draws: Draws,
    generated: Vec<Vec<f32>>,
    features: Vec<Vec<f32>>,
}

/// Ask `m` for the category `cat` (condition-table `row`) from training
/// contexts of it, beside the same contexts and noise asked for none, and
/// measure both with the classifier `c` and against `seen`'s real windows.
fn ask_one(
    m: &Run,
    spec: &RunSpec,
    c: &Classifier,
    seen: &RealSeen,
    row: usize,
    cat: Category,
) -> Result<One, EvalError> {
    let train = m.split("train")?;
    let (len, f) = (train.length, train.features);
    let global = |x: &Vec<f32>| m.generated_poses(x);
    let real_of = |c: Category| -> Vec<Vec<Pose>> {
        seen.poses
            .iter()
            .zip(&seen.labels)
            .filter(|(_, &l)| l == c)
            .map(|(p, _)| p.clone())
            .collect()
    };
    let count = |split: &str, c: Category| {
        m.data
            .categories
            .get(split)
            .map_or(0, |l| l.iter().filter(|&&x| x == c).count())
    };
    // Contexts of the category, asked for it at `guidance` (0: none).
    let asked = |guidance: f64| {
        let ask = Ask { row, guidance };
        let n = PER_CATEGORY;
        m.sample_asked(Asking::One(cat, ask), n, len, spec.context, spec.seed)
    };
    // The same contexts and noise, with the category and without.
    let (gen, unasked) = (asked(spec.guidance)?, asked(0.0)?);
    let seen_by = |set: &[Vec<f32>]| c.outputs(&as_windows(set, len, f), &m.device);
    let (go, uo) = (seen_by(&gen)?, seen_by(&unasked)?);
    let (gp, up) = (go.predicted(), uo.predicted());
    let test_f = seen.features(&spec.split, cat);
    let real_accuracy = seen
        .split(&spec.split)
        .and_then(|(_, o, l)| classifier::accuracy(&o.predicted(), l).of(cat));
    let two = |v: &[Vec<f32>]| (v.len() >= 2).then_some(());
    let real = real_of(cat);
    let gen_poses: Vec<Vec<Pose>> = gen.iter().map(global).collect();
    let un_poses: Vec<Vec<Pose>> = unasked.iter().map(global).collect();
    let missing = || EvalError::Invalid(format!("no windows of {cat}"));
    let d = spread(&real, spec.seed);
    let asked = Asked {
        category: cat.name().to_string(),
        train_windows: count("train", cat),
        split_windows: count(&spec.split, cat),
        real_accuracy,
        accuracy: share_of(&gp, cat),
        accuracy_unasked: share_of(&up, cat),
        frechet: two(&test_f).map(|_| classifier::feature_frechet(&go.features, &test_f)),
        frechet_reference: two(&test_f)
            .map(|_| classifier::feature_frechet(&seen.features("train", cat), &test_f)),
        real: plain(&real).ok_or_else(missing)?,
        generated: plain(&gen_poses).ok_or_else(missing)?,
        unasked: plain(&un_poses).ok_or_else(missing)?,
        real_spread: [d.range(|s| s.root_speed_m_s), d.range(|s| s.contact_share)],
        stride_spread: Some(d.range(|s| s.stride_m)),
        taken_for: taken_for(&gp, cat),
    };
    Ok(One {
        asked,
        draws: d,
        generated: gen,
        features: go.features,
    })
}

/// Share of `predicted` that is `c` (0 when empty).
fn share_of(predicted: &[Category], c: Category) -> f64 {
    predicted.iter().filter(|&&p| p == c).count() as f64 / predicted.len().max(1) as f64
}

/// Each category with its `share`, those above 0, largest first (ties in
/// [`Category::ALL`]'s order).
fn ranked(share: impl Fn(Category) -> f64) -> Vec<(String, f64)> {
    let mut out: Vec<(String, f64)> = Category::ALL
        .iter()
        .map(|&c| (c.name().to_string(), share(c)))
        .filter(|(_, v)| *v > 0.0)
        .collect();
    out.sort_by(|a, b| b.1.total_cmp(&a.1));
    out
}

/// Each category other than `asked` among `predicted`, with its share of
/// them, largest first ([`ranked`]).
fn taken_for(predicted: &[Category], asked: Category) -> Vec<(String, f64)> {
    ranked(|c| match c == asked {
        true => 0.0,
        false => share_of(predicted, c),
    })
}

/// The first `k` of `taken` as `name share`, e.g. `gesture 20 %, play 8 %`
/// ("–" when none).
fn taken_text(taken: &[(String, f64)], k: usize) -> String {
    if taken.is_empty() {
        return "–".into();
    }
    let each: Vec<String> = taken
        .iter()
        .take(k)
        .map(|(c, v)| format!("{c} {:.0} %", 100.0 * v))
        .collect();
    each.join(", ")
}

/// [`Separation`] of the categories `kept` (each with its real windows'
/// draws) in the measure `f`, `of` giving a draw's value of it; None below
/// two categories or where their real values are all the same.
fn separation(
    kept: &[(&Asked, &Draws)],
    f: fn(&Plain) -> f64,
    of: fn(&MotionStats) -> f64,
) -> Option<Separation> {
    use motion_metrics::slope;
    let over = |g: &dyn Fn(&Asked, &Draws) -> f64| {
        slope(
            &kept
                .iter()
                .map(|(a, d)| (f(&a.real), g(a, d)))
                .collect::<Vec<_>>(),
        )
    };
    let draws = kept.iter().map(|(_, d)| d.each.len()).min().unwrap_or(0);
    let real = (0..draws)
        .map(|k| over(&|_, d| of(&d.each[k])))
        .collect::<Option<Vec<f64>>>()?;
    if real.is_empty() {
        return None;
    }
    Some(Separation {
        asked: over(&|a, _| f(&a.generated))?,
        unasked: over(&|a, _| f(&a.unasked))?,
        real: crate::lo_hi(real.into_iter()),
    })
}

/// What [`spread`] draws of a category's real windows: the measures of
/// all of them and of each draw.
struct Draws {
    all: MotionStats,
    each: Vec<MotionStats>,
}

impl Draws {
    /// Smallest and largest ratio of a draw's measure `f` to all windows'.
    fn range(&self, f: fn(&MotionStats) -> f64) -> (f64, f64) {
        let all = f(&self.all).max(1e-12);
        crate::lo_hi(self.each.iter().map(|s| f(s) / all))
    }
}

/// [`REAL_DRAWS`] draws of half of `real`, measured.
fn spread(real: &[Vec<Pose>], seed: u64) -> Draws {
    let opts = Options::default();
    let k = (real.len() / 2).max(1);
    let mut rng = motion_vrnn::rng::Rng::new(seed, 0x5B2E);
    let each = (0..REAL_DRAWS)
        .map(|_| {
            let pick: Vec<Vec<Pose>> = rng
                .permutation(real.len())
                .into_iter()
                .take(k)
                .map(|i| real[i].clone())
                .collect();
            motion_stats(&pick, &opts)
        })
        .collect();
    Draws {
        all: motion_stats(real, &opts),
        each,
    }
}

/// `v` as one set of `length`-frame windows.
pub(crate) fn as_windows(
    v: &[Vec<f32>],
    length: usize,
    features: usize,
) -> motion_vrnn::data::Windows {
    motion_vrnn::data::Windows {
        data: v.concat(),
        n: v.len(),
        length,
        features,
    }
}

/// A real-vs-real range as printed beside a ratio: `[lo–hi]`, or nothing
/// where there is none (the stride's, in reports written before it).
fn bracket(r: Option<(f64, f64)>) -> String {
    r.map_or(String::new(), |(lo, hi)| format!("[{lo:.2}–{hi:.2}]"))
}

/// The sentence on the categories kept apart ([`Separation`]): for the hips
/// speed and the stride, the asked and unasked slopes of the runs `sets`
/// as `text` writes them (one run's value, or the seeds' mean ± std) and
/// the first run's real-vs-real range; empty where a run has none.
fn separation_line(sets: &[&AskedSet], text: &dyn Fn(&[f64]) -> String) -> String {
    type Pick = fn(&AskedSet) -> Option<Separation>;
    let measures: [(&str, Pick); 2] = [
        ("hips speed", |a| a.speed_separation),
        ("stride", |a| a.stride_separation),
    ];
    let mut parts = Vec::new();
    for (name, pick) in measures {
        let Some(each) = sets.iter().map(|a| pick(a)).collect::<Option<Vec<_>>>() else {
            return String::new();
        };
        let Some(first) = each.first() else {
            return String::new();
        };
        let of = |f: fn(&Separation) -> f64| text(&each.iter().map(f).collect::<Vec<_>>());
        parts.push(format!(
            "{name} **{}** (unasked {}) {}",
            of(|s| s.asked),
            of(|s| s.unasked),
            bracket(Some(first.real))
        ));
    }
    format!(
        "\nCategories kept apart (slope of each category's generated value on its real one, over the categories \
         of the goals: 1, as far apart as real categories; 0, all alike; in brackets, draws of half the real \
         windows): {}.\n",
        parts.join(", ")
    )
}

/// The section of `eval.md`.
pub fn markdown(a: &AskedSet) -> String {
    let opt = |v: Option<f64>| v.map_or("n/a".to_string(), |x| format!("{x:.1}"));
    let mut s = format!(
        "\n## Asked for each category (guidance {})\n\n\
         {} motions per category, each continuing a training window of it; beside them (\"unasked\") the \
         same contexts and noise with no category asked. Recognition: the share the classifier puts in the \
         category asked for, against its share on the real {split} windows of it. Speed, contact and stride: real \
         windows of the category (all splits) → asked → unasked, with the ratio of draws of half the real \
         windows to all of them in brackets (stride: a diagnostic, not a goal). Creep: how fast the planted toes \
         slide (contact, not skating), real → asked, a diagnostic. Taken for: the categories the classifier puts \
         the other asked motions in, the two largest shares. Goals (categories with at least {} training windows): \
         recognised ≥ 0.9 × real, speed and contact 0.75–1.25 × real.\n\n\
         | category | train / {split} windows | recognised: real {split} → asked (unasked) | taken for | hips speed m/s | contact | stride m | creep m/s | jerk m/s³ | APD m | feature Fréchet (ref) | misses |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
        a.guidance,
        a.per_category,
        MIN_TRAIN_WINDOWS,
        split = a.split
    );
    for c in &a.categories {
        let pct = |v: f64| format!("{:.0} %", 100.0 * v);
        let misses = match (c.in_goals(), c.misses()) {
            (false, _) => "(too few windows)".to_string(),
            (true, m) if m.is_empty() => "none".to_string(),
            (true, m) => m.join(", "),
        };
        s += &format!(
            "| {} | {} / {} | {} → **{}** ({}) | {} | {:.2} → **{:.2}** ({:.2}) {} | {:.2} → **{:.2}** ({:.2}) {} | {:.2} → **{:.2}** ({:.2}) {} | {:.3} → {:.3} | {:.0} → {:.0} | {} → {} | {} ({}) | {} |\n",
            c.category,
            c.train_windows,
            c.split_windows,
            c.real_accuracy.map_or("n/a".into(), pct),
            pct(c.accuracy),
            pct(c.accuracy_unasked),
            taken_text(&c.taken_for, 2),
            c.real.speed_m_s,
            c.generated.speed_m_s,
            c.unasked.speed_m_s,
            bracket(Some(c.real_spread[0])),
            c.real.contact,
            c.generated.contact,
            c.unasked.contact,
            bracket(Some(c.real_spread[1])),
            c.real.stride_m,
            c.generated.stride_m,
            c.unasked.stride_m,
            bracket(c.stride_spread),
            c.real.creep_m_s,
            c.generated.creep_m_s,
            c.real.jerk_m_s3,
            c.generated.jerk_m_s3,
            c.real.apd_m.map_or("–".into(), |v| format!("{v:.2}")),
            c.generated.apd_m.map_or("–".into(), |v| format!("{v:.2}")),
            opt(c.frechet),
            opt(c.frechet_reference),
            misses
        );
    }
    let (g, r) = (&a.generated, &a.real);
    s += &format!(
        "\nEvery motion asked for, against every real window: jerk {:.2}×, bone cv {:.2} %, skating in contact {:.2}×, \
         creep of planted toes {:.2}×, hips height {:.2}×, hips speed {:.2}×; Fréchet (window summaries) {:.1} (train windows {:.1}); \
         feature Fréchet {}; diversity {}; multimodality {}.\n",
        g.jerk_m_s3 / r.jerk_m_s3,
        100.0 * g.bone_cv,
        g.skate_in_contact / r.skate_in_contact,
        g.creep_m_s / r.creep_m_s,
        g.hip_height_m / r.hip_height_m,
        g.root_speed_m_s / r.root_speed_m_s,
        a.frechet_summaries.0,
        a.frechet_summaries.1,
        opt(a.frechet),
        opt(a.diversity),
        opt(a.multimodality),
    );
    s += &separation_line(&[a], &|v| format!("{:.2}", crate::mean_of(v)));
    s
}

/// Load the run of `spec` with the reference splits of its split
/// ([`crate::horizon::reference_splits`]) and the classifier in `dir`, and
/// ask the run's model for each of its categories.
pub fn evaluate(spec: &RunSpec, dir: &std::path::Path) -> Result<AskedSet, EvalError> {
    let m = Run::load(spec, crate::horizon::reference_splits(&spec.split))?;
    let (c, _) = Classifier::load(dir, &m.device)?;
    let seen = RealSeen::of(&m, &c, &spec.split)?;
    ask_each(&m, spec, &c, &seen)?.ok_or_else(|| {
        EvalError::Invalid(format!(
            "{}: the model was trained without categories (train it with --condition category)",
            spec.run.display()
        ))
    })
}

/// The seeds' `taken_for` averaged by category (a seed without one counts
/// 0), largest first.
fn mean_taken(each: &[&Asked]) -> Vec<(String, f64)> {
    let n = each.len().max(1) as f64;
    ranked(|c| {
        let sum: f64 = each
            .iter()
            .flat_map(|a| &a.taken_for)
            .filter(|(t, _)| t == c.name())
            .map(|(_, v)| v)
            .sum();
        sum / n
    })
}

/// The row of the category `c` (the `k`-th) of the results page's section:
/// mean ± std over the seeds' runs, the goals missed on the mean, the seeds
/// that miss.
fn category_row(runs: &[(u64, AskedSet)], k: usize, c: &Asked) -> String {
    let ms = |v: Vec<f64>, p: usize| {
        let (m, s) = crate::mean_std(&v);
        format!("{m:.p$} ± {s:.p$}")
    };
    let each: Vec<&Asked> = runs.iter().filter_map(|r| r.1.categories.get(k)).collect();
    let pct = |f: fn(&Asked) -> f64| ms(each.iter().map(|a| 100.0 * f(a)).collect(), 0);
    let ratio = |f: fn(&Plain) -> f64| {
        ms(
            each.iter().map(|a| f(&a.generated) / f(&a.real)).collect(),
            2,
        )
    };
    // Reports written before the stride have none: n/a, not NaN.
    let stride = if each.iter().any(|a| a.real.stride_m <= 0.0) {
        "n/a".to_string()
    } else {
        format!("{} {}", ratio(|p| p.stride_m), bracket(c.stride_spread))
    };
    // The goals on the mean over the seeds.
    let mean =
        |f: fn(&Asked) -> f64| crate::mean_of(&each.iter().map(|a| f(a)).collect::<Vec<_>>());
    let mut avg = c.clone();
    avg.accuracy = mean(|a| a.accuracy);
    avg.generated.speed_m_s = mean(|a| a.generated.speed_m_s);
    avg.generated.contact = mean(|a| a.generated.contact);
    let missed = match (c.in_goals(), avg.misses()) {
        (false, _) => "(too few training windows)".to_string(),
        (true, m) if m.is_empty() => "none".into(),
        (true, m) => m.join(", "),
    };
    let seeds: Vec<String> = runs
        .iter()
        .filter_map(|(seed, a)| {
            let m = a.categories.get(k)?.misses();
            (c.in_goals() && !m.is_empty()).then(|| format!("{seed} ({})", m.join(", ")))
        })
        .collect();
    let spread = |i: usize| bracket(Some(c.real_spread[i]));
    format!(
        "| {} | {} / {} | {} | {} | {} | {} | {} {} | {} {} | {} | {} | {} |\n",
        c.category,
        c.train_windows,
        c.split_windows,
        c.real_accuracy
            .map_or("n/a".into(), |a| format!("{:.0} %", 100.0 * a)),
        pct(|a| a.accuracy),
        pct(|a| a.accuracy_unasked),
        taken_text(&mean_taken(&each), 2),
        ratio(|p| p.speed_m_s),
        spread(0),
        ratio(|p| p.contact),
        spread(1),
        stride,
        missed,
        if seeds.is_empty() {
            "–".into()
        } else {
            seeds.join("; ")
        }
    )
}

/// The results page's section: every category asked of the seeds' runs
/// (`(seed, asked)`), mean ± std over the seeds, the goals met on the mean
/// and the seeds that miss.
pub fn page_section(runs: &[(u64, AskedSet)], sheet: &str, model: &AskedModel) -> String {
    let Some((_, first)) = runs.first() else {
        return String::new();
    };
    let split = &first.split;
    let ms = |v: Vec<f64>, p: usize| {
        let (m, s) = crate::mean_std(&v);
        format!("{m:.p$} ± {s:.p$}")
    };
    let mut s = format!(
        "\n## Motion to order: {} (issue 25)\n\n\
         {}, {} seeds. Each run is asked for each of its categories \
         ({} motions each, each continuing a training window of that category, guidance {}) and the motion \
         classifier (`train-classifier`, seed 0) says what it got; \"unasked\" continues the same contexts with \
         the same noise and no category (what the contexts alone give). Speed and contact are generated ÷ the \
         real windows of the category (every split for a report on `test`; `train` and `val` otherwise), with the range of draws of half those real windows in \
         brackets; stride (how far the toes swing past each other, [metrics.md](metrics.md)) is a diagnostic \
         beside them; \"taken for\": the categories the classifier puts the other asked motions in (the \
         two largest shares, mean over the seeds). Goals for categories with at least {} training windows: recognised ≥ 0.9 × the real {split} \
         windows of the category, speed and contact 0.75–1.25×.\n\n\
         | category | train / {split} windows | recognised, real {split} | recognised, asked | recognised, unasked | \
         taken for | hips speed ÷ real | contact ÷ real | stride ÷ real | goals missed (mean) | seeds that miss |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
        model.title,
        model.about,
        runs.len(),
        first.per_category,
        first.guidance,
        MIN_TRAIN_WINDOWS
    );
    for (k, c) in first.categories.iter().enumerate() {
        s += &category_row(runs, k, c);
    }
    let whole = |f: fn(&AskedSet) -> f64, p: usize| ms(runs.iter().map(|r| f(&r.1)).collect(), p);
    s += &format!(
        "\nEvery motion asked for (all categories together) against every real window, mean ± std over the seeds \
         (the unconditioned goals of issue 11): jerk {}×, bone cv {} %, skating in contact {}×, hips height {}×, \
         hips speed {}×, Fréchet (window summaries, to the {split} windows) {} against the train windows' {:.1}; \
         feature Fréchet {}, diversity {}, multimodality (by the category asked) {}.\n",
        whole(|a| a.generated.jerk_m_s3 / a.real.jerk_m_s3, 2),
        whole(|a| 100.0 * a.generated.bone_cv, 2),
        whole(|a| a.generated.skate_in_contact / a.real.skate_in_contact, 2),
        whole(|a| a.generated.hip_height_m / a.real.hip_height_m, 2),
        whole(|a| a.generated.root_speed_m_s / a.real.root_speed_m_s, 2),
        whole(|a| a.frechet_summaries.0, 1),
        first.frechet_summaries.1,
        whole(|a| a.frechet.unwrap_or(f64::NAN), 0),
        whole(|a| a.diversity.unwrap_or(f64::NAN), 1),
        whole(|a| a.multimodality.unwrap_or(f64::NAN), 1),
    );
    let sets: Vec<&AskedSet> = runs.iter().map(|r| &r.1).collect();
    s += &separation_line(&sets, &|v| ms(v.to_vec(), 2));
    s += &format!(
        "\nOne row per category (seed 0, 4 motions each asked for it, 5 columns from the first frame to the last):\n\n\
         ![one row per category]({sheet})\n"
    );
    s
}

#[cfg(test)]
#[path = "asked_tests.rs"]
mod tests;
