//! The evaluation of a run (`eval.json`) and its Markdown (`eval.md`):
//! real, reconstructed and generated windows of a split, measured alike
//! with every measure of `docs/metrics.md`.

use crate::horizon::{Horizon, HorizonOptions};
use crate::run::{Run, RunSpec};
use crate::{mean_of, EvalError};
use mocap_ingest::features::NUM_FEATURES;
use mocap_ingest::skeleton::Pose;
use motion_metrics::{motion_stats, MotionStats, Options};
use motion_vrnn::generate::{self, to_poses};
use motion_vrnn::train::evaluate;
use motion_vrnn::MotionModel;
use serde::{Deserialize, Serialize};

/// Where `eval` takes the real frames its generated motions continue.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Contexts {
    /// Every window of the evaluated split, once each.
    Split,
    /// Random training windows (as `sample`).
    Train,
}

impl std::str::FromStr for Contexts {
    type Err = String;
    fn from_str(s: &str) -> Result<Contexts, String> {
        match s {
            "split" => Ok(Contexts::Split),
            "train" => Ok(Contexts::Train),
            _ => Err(format!("unknown contexts {s:?}: `split` or `train`")),
        }
    }
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
    /// The guidance scale the generated motions asked their category at
    /// (`--guidance`; absent: they asked for none, or a report written
    /// before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guidance: Option<f64>,
    /// The gain the generated motions were held to their asked pace with
    /// ([`motion_vrnn::generate::PACE_GAIN`]; absent: not held, or a report
    /// written before 4-second motions were).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace_gain: Option<f64>,
    /// The draws of noise each run of a held motion was chosen from
    /// ([`motion_vrnn::generate::POSE_DRAWS`]; absent as `pace_gain`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub draws: Option<usize>,
    /// Whether the generated motions' planted toes were pinned before they
    /// were measured (`--pin-feet`; false in reports written before it).
    #[serde(default)]
    pub pin_feet: bool,
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
    /// With `--contexts split`, the same number of motions generated from
    /// random training contexts (as `sample` does), measured alike: the
    /// harder task, beside the continuation of the split's own windows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_training: Option<FromTraining>,
    /// Motions rolled out for a minute, stretch by stretch (`eval --horizon`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizon: Option<Horizon>,
    /// The same minute from the model alone (one draw, pace not held), where
    /// `horizon` was made by a sampler that holds the pace.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizon_alone: Option<Horizon>,
    /// Generated motion seen by a motion classifier (`eval --classifier`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub classifier: Option<crate::recognition::Recognition>,
    /// What the user should know (e.g. the dataset is not the run's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

fn one() -> f64 {
    1.0
}

/// Motions generated from random training contexts, measured against the
/// split's real windows.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FromTraining {
    /// Every measure of the generated set.
    pub generated: MotionStats,
    /// Fréchet distance to the split's real windows.
    pub frechet: f64,
}

/// Within-window spread of each set ([`motion_metrics::mean_spread`]).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Spread {
    pub real: f64,
    pub reconstructed: f64,
    pub generated: f64,
}

/// The evaluation of a run: real, reconstructed and generated windows of
/// the split, measured alike.
/// With `horizon`, also the long-horizon table ([`crate::horizon`]); with
/// `classifier` (a directory of `train-classifier`), what it recognises
/// ([`crate::recognition`]).
pub fn report(
    a: &RunSpec,
    contexts: Contexts,
    horizon: Option<HorizonOptions>,
    classifier: Option<&std::path::Path>,
) -> Result<EvalReport, EvalError> {
    // The long horizon and the classifier measure against the reference
    // splits (never `test` unless it is the split reported): load them once.
    let splits = match horizon.is_some() || classifier.is_some() {
        true => crate::horizon::reference_splits(&a.split).to_vec(),
        false => vec!["train", a.split.as_str()],
    };
    let mut m = Run::load(a, &splits)?;
    let held = m.held_pace();
    let (minute, minute_alone) = match horizon {
        Some(o) => minutes(&mut m, a, o)?,
        None => (None, None),
    };
    let (w, categories) = m.labelled(&a.split)?;
    let (recon, kl) = evaluate(&m.model.model, w, categories, 256, a.seed, &m.device)?;
    let t = w.length as f64;
    let idx: Vec<usize> = (0..w.n).collect();
    let (real, rec) = m.reconstruct(&a.split, &idx)?;
    let gen = match contexts {
        Contexts::Split => {
            m.continue_asked(m.ask, w, categories, &idx, w.length, a.context, a.seed)?
        }
        Contexts::Train => m.sample(w.n, w.length, a.context, a.seed)?,
    };
    let global = |set: &[Vec<f32>]| -> Vec<Vec<Pose>> {
        set.iter().map(|x| to_poses(x, &m.data.stats)).collect()
    };
    let generated =
        |set: &[Vec<f32>]| -> Vec<Vec<Pose>> { set.iter().map(|x| m.generated_poses(x)).collect() };
    let from_training = match contexts {
        Contexts::Split => Some(from_training_contexts(&m, a, w.n, w.length)?),
        Contexts::Train => None,
    };
    let o = Options::default();
    let (sr, sc, sg) = (
        motion_stats(&global(&real), &o),
        motion_stats(&global(&rec), &o),
        motion_stats(&generated(&gen), &o),
    );
    let summaries = |set: &[Vec<f32>]| generate::summaries(set, NUM_FEATURES);
    let train_windows = generate::windows_of(m.split("train")?);
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
        guidance: m.guidance(),
        pace_gain: held.map(|h| h.0),
        draws: held.map(|h| h.1),
        pin_feet: a.pin_feet,
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
        from_training: from_training.map(|(generated, summaries)| FromTraining {
            generated,
            frechet: motion_metrics::frechet(&s_real, &summaries),
        }),
        warnings: m.warnings.clone(),
        horizon: minute,
        horizon_alone: minute_alone,
        classifier: classifier
            .map(|dir| crate::recognition::recognise(&m, a, dir))
            .transpose()?,
    };
    Ok(report)
}

/// `n` motions of `frames` frames from random training contexts (as
/// `sample` makes them): their measures and window summaries.
fn from_training_contexts(
    m: &Run,
    a: &RunSpec,
    n: usize,
    frames: usize,
) -> Result<(MotionStats, Vec<Vec<f64>>), EvalError> {
    let g = m.sample(n, frames, a.context, a.seed)?;
    let poses: Vec<Vec<Pose>> = g.iter().map(|x| m.generated_poses(x)).collect();
    Ok((
        motion_stats(&poses, &Options::default()),
        generate::summaries(&g, NUM_FEATURES),
    ))
}

/// The minute of `m` with its sampler and, where that sampler holds the
/// pace, from the model alone (one draw, no pace held; `m`'s sampler is
/// restored).
fn minutes(
    m: &mut Run,
    a: &RunSpec,
    o: HorizonOptions,
) -> Result<(Option<Horizon>, Option<Horizon>), EvalError> {
    let minute = crate::horizon::horizon(m, a, o)?;
    if m.held_pace().is_none() {
        return Ok((Some(minute), None));
    }
    let alone = m.alone(|m| crate::horizon::horizon(m, a, o))?;
    Ok((Some(minute), Some(alone)))
}

/// `eval.md`: the report as a Markdown page.
pub fn markdown(r: &EvalReport) -> String {
    let mut s = format!(
        "# Evaluation of {} ({}, epoch {})\n\nDataset {}, split `{}`: {} windows of {} frames; {} generated motions of {} frames (seed {}, temperature {}{}), each continuing the first {} frames of {}.{}\n\n",
        r.run, r.checkpoint, r.epoch, r.dataset, r.split, r.windows, r.frames, r.windows, r.frames, r.seed, r.temperature,
        r.guidance.map(|g| format!(", asked at guidance {g}")).unwrap_or_default(),
        r.context,
        match r.contexts {
            Contexts::Split => format!("one `{}` window (every window once)", r.split),
            Contexts::Train => "a random training window".to_string(),
        },
        crate::horizon::held_sentence(r.pace_gain, r.draws)
    );
    if r.pin_feet {
        s += "Generated motions measured with their planted toes pinned in place (`--pin-feet`, docs/export.md).\n\n";
    }
    s += &format!(
        "Per frame on `{}`: negative ELBO **{:.3}** = reconstruction {:.3} + KL {:.3} (normalised units).\n\n",
        r.split, r.neg_elbo_per_frame, r.recon_per_frame, r.kl_per_frame
    );
    s += &measure_table(r);
    if let Some(t) = &r.from_training {
        let g = &t.generated;
        s += &format!(
            "\nGenerated from random training contexts instead (as `sample`; {} motions), ÷ real: APD {}, jerk {}, contact {}, skating in contact {}, hips height {}, hips speed {} (last 32 frames {}), turning {}, stride {}; Fréchet {:.2}.\n",
            g.motions,
            ratio(g.apd_m, r.real.apd_m),
            ratio(g.jerk_m_s3, r.real.jerk_m_s3),
            ratio(g.contact_share, r.real.contact_share),
            ratio(g.skate_in_contact, r.real.skate_in_contact),
            ratio(g.hip_height_m, r.real.hip_height_m),
            ratio(g.root_speed_m_s, r.real.root_speed_m_s),
            ratio(g.root_speed_end_m_s, r.real.root_speed_end_m_s),
            ratio(g.turning_deg_s, r.real.turning_deg_s),
            ratio(g.stride_m, r.real.stride_m),
            t.frechet
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
    if let Some(h) = &r.horizon {
        let title = match r.horizon_alone {
            Some(_) => "Long horizon, the default sampler",
            None => "Long horizon",
        };
        s += &crate::horizon::markdown(h, title);
    }
    if let Some(h) = &r.horizon_alone {
        s +=
            &crate::horizon::markdown(h, "Long horizon, the model alone (one draw, pace not held)");
    }
    if let Some(c) = &r.classifier {
        s += &crate::recognition::markdown(c, &r.split);
        if let Some(a) = &c.asked {
            s += &crate::asked::markdown(a);
        }
    }
    s
}

/// The table of every measure: real, reconstructed and generated, with
/// their ratios to real.
fn measure_table(r: &EvalReport) -> String {
    let mut s = String::new();
    s += "| measure | real | reconstructed | generated | reconstructed / real | generated / real |\n|---|---|---|---|---|---|\n";
    type Row = (&'static str, fn(&MotionStats) -> f64, usize);
    let rows: [Row; 15] = [
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
        (
            "creep of planted toes (contact, not skating), m/s",
            |m| m.creep_m_s,
            3,
        ),
        ("turning rate, °/s", |m| m.turning_deg_s, 1),
        (
            "stride (toes' swing along the facing), m",
            |m| m.stride_m,
            3,
        ),
        (
            "frames in the air (no joint within 5 cm of the floor)",
            |m| m.airborne_share,
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
    for (name, f, p) in rows {
        let (a, b, c) = (f(&r.real), f(&r.reconstructed), f(&r.generated));
        s += &format!(
            "| {name} | {a:.p$} | {b:.p$} | {c:.p$} | {} | {} |\n",
            ratio(b, a),
            ratio(c, a)
        );
    }
    s
}

/// `x ÷ real` to two decimals, `n/a` where real is about 0.
fn ratio(x: f64, real: f64) -> String {
    if real.abs() > 1e-6 {
        format!("{:.2}", x / real)
    } else {
        "n/a (real ≈ 0)".into()
    }
}
