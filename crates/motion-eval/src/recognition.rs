//! Generated motion seen by the motion classifier
//! (`motion_vrnn::classifier`, `cargo xtask train-classifier`): the measures
//! of the action-to-motion protocol (ACTOR, MDM) that apply to any model —
//! the Fréchet distance in the classifier's feature space, diversity,
//! multimodality — and the mix of categories the classifier recognises in
//! generated motion beside real motion's (`eval --classifier DIR`).

use crate::asked::as_windows;
pub use crate::asked::{plain, Plain};
use crate::run::{Run, RunSpec};
use crate::EvalError;
use mocap_ingest::category::Category;
use mocap_ingest::Pose;
use motion_vrnn::classifier::{self, Classifier};
use motion_vrnn::generate::to_poses;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Generated motions the classifier sees.
pub const MOTIONS: usize = 256;

/// One category's share of windows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Share {
    /// The category.
    pub category: String,
    /// Share of the real windows (all splits) labelled with it.
    pub real: f64,
    /// Share of the real windows (all splits) the classifier puts in it.
    pub real_recognised: f64,
    /// Share of the generated motions the classifier puts in it.
    pub generated: f64,
    /// The plain measures of the real windows labelled with it.
    pub real_measures: Option<Plain>,
    /// The plain measures of the generated motions recognised in it.
    pub generated_measures: Option<Plain>,
}

/// The classifier's view of a run (`eval.json`'s `classifier`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Recognition {
    /// The classifier directory.
    pub classifier: String,
    /// Generated motions (each continuing a random training window).
    pub motions: usize,
    /// Recognition accuracy on the real windows of the evaluated split.
    pub test_accuracy: Option<f64>,
    /// Fréchet distance of the generated motions' feature vectors to the
    /// evaluated split's windows'.
    pub frechet_generated: f64,
    /// The same for the training windows (the reference).
    pub frechet_train: f64,
    /// Diversity of the real windows (all splits) and of the generated ones.
    pub diversity_real: Option<f64>,
    /// Diversity of the generated motions.
    pub diversity_generated: Option<f64>,
    /// Multimodality of the real windows by their labels.
    pub multimodality_real: Option<f64>,
    /// Multimodality of the generated motions by the category recognised.
    pub multimodality_generated: Option<f64>,
    /// Per category, the shares of real and generated windows.
    pub shares: Vec<Share>,
    /// A conditioned model asked for each of its categories
    /// ([`crate::asked`]); absent for an unconditioned one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub asked: Option<crate::asked::AskedSet>,
}

/// Measure the loaded run `m` (all splits) with the classifier in `dir`.
pub fn recognise(m: &Run, spec: &RunSpec, dir: &Path) -> Result<Recognition, EvalError> {
    let (c, _) = Classifier::load(dir, &m.device)?;
    let train = m.split("train")?;
    let (len, f) = (train.length, train.features);
    let generated = m.sample(MOTIONS, len, spec.context, spec.seed)?;
    let gen = c.outputs(&as_windows(&generated, len, f), &m.device)?;
    let global = |x: &Vec<f32>| to_poses(x, &m.data.stats);
    let gen_poses: Vec<Vec<Pose>> = generated.iter().map(global).collect();
    // The real windows through the classifier, once.
    let seen = crate::asked::RealSeen::of(m, &c, &spec.split)?;
    let (real_poses, labels) = (&seen.poses, &seen.labels);
    let (mut real_f, mut recognised) = (Vec::new(), Vec::new());
    for (_, o, _) in &seen.splits {
        recognised.extend(o.predicted());
        real_f.extend(o.features.iter().cloned());
    }
    let train_f = seen.split("train").map_or(&real_f, |s| &s.1.features);
    let (test_f, test_accuracy) = match seen.split(&spec.split) {
        Some((_, o, l)) => (
            &o.features,
            classifier::accuracy(&o.predicted(), l).overall(),
        ),
        None => (train_f, None),
    };
    let asked = crate::asked::ask_each(m, spec, &c, &seen)?;
    let predicted = gen.predicted();
    let share = |set: &[Category], c: Category| {
        set.iter().filter(|&&x| x == c).count() as f64 / set.len().max(1) as f64
    };
    let (sd, sl) = (
        classifier::DIVERSITY_SAMPLES,
        classifier::MULTIMODALITY_SAMPLES,
    );
    let group = |poses: &[Vec<Pose>], of: &[Category], c: Category| {
        let picked: Vec<Vec<Pose>> = poses
            .iter()
            .zip(of)
            .filter(|(_, &x)| x == c)
            .map(|(p, _)| p.clone())
            .collect();
        plain(&picked)
    };
    Ok(Recognition {
        classifier: dir.display().to_string(),
        motions: MOTIONS,
        test_accuracy,
        frechet_generated: classifier::feature_frechet(&gen.features, test_f),
        frechet_train: classifier::feature_frechet(train_f, test_f),
        diversity_real: classifier::diversity(&real_f, sd, spec.seed),
        diversity_generated: classifier::diversity(&gen.features, sd, spec.seed),
        multimodality_real: classifier::multimodality(&real_f, labels, sl, spec.seed),
        multimodality_generated: classifier::multimodality(
            &gen.features,
            &predicted,
            sl,
            spec.seed,
        ),
        shares: Category::ALL
            .iter()
            .map(|&c| Share {
                category: c.name().to_string(),
                real: share(labels, c),
                real_recognised: share(&recognised, c),
                generated: share(&predicted, c),
                real_measures: group(real_poses, labels, c),
                generated_measures: group(&gen_poses, &predicted, c),
            })
            .collect(),
        asked,
    })
}

/// The classifier section of `eval.md`.
pub fn markdown(r: &Recognition, split: &str) -> String {
    let opt = |v: Option<f64>| v.map_or("n/a".to_string(), |x| format!("{x:.2}"));
    let mut s = format!(
        "\n## Seen by the motion classifier ({})\n\n\
         {} motions from training contexts. Feature-space Fréchet distance to the {split} windows: \
         generated **{:.1}**, train windows {:.1} (reference). Diversity: real {}, generated {}. \
         Multimodality (by label / by recognised category): real {}, generated {}. \
         Accuracy on the real {split} windows: {}. Definitions: [metrics.md](metrics.md).\n\n\
         Per category: the share of real windows labelled with it, recognised in it, and of generated \
         motions recognised in it; hips speed (m/s), contact share, jerk (m/s³) and APD (m) of the real \
         windows labelled with it → of the generated motions recognised in it.\n\n\
         | category | real windows | real, recognised | generated, recognised | hips speed | contact | jerk | APD |\n|---|---|---|---|---|---|---|---|\n",
        r.classifier,
        r.motions,
        r.frechet_generated,
        r.frechet_train,
        opt(r.diversity_real),
        opt(r.diversity_generated),
        opt(r.multimodality_real),
        opt(r.multimodality_generated),
        r.test_accuracy
            .map_or(format!("n/a (no {split} windows)"), |a| format!("{:.1} %", 100.0 * a)),
    );
    for sh in &r.shares {
        let pair = |f: fn(&Plain) -> Option<f64>, p: usize| {
            let v = |m: &Option<Plain>| {
                m.as_ref()
                    .and_then(f)
                    .map_or("–".into(), |x| format!("{x:.p$}"))
            };
            format!("{} → {}", v(&sh.real_measures), v(&sh.generated_measures))
        };
        s += &format!(
            "| {} | {:.1} % | {:.1} % | {:.1} % | {} | {} | {} | {} |\n",
            sh.category,
            100.0 * sh.real,
            100.0 * sh.real_recognised,
            100.0 * sh.generated,
            pair(|m| Some(m.speed_m_s), 2),
            pair(|m| Some(m.contact), 2),
            pair(|m| Some(m.jerk_m_s3), 0),
            pair(|m| m.apd_m, 2)
        );
    }
    s
}
