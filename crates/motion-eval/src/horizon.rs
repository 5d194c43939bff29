//! The long horizon: motions rolled out for a minute from training-window
//! contexts, cut into window-long stretches, each re-based to its own start
//! (position and facing: the features are local, so a stretch's poses start
//! at the origin facing +z as real windows do) and measured against every
//! real window of the dataset, beside the spread of real draws of the same
//! size (`docs/metrics.md`, "Long horizon").

use crate::run::{Run, RunSpec};
use crate::{lo_hi, EvalError};
use mocap_ingest::features::NUM_FEATURES;
use mocap_ingest::skeleton::Pose;
use motion_metrics::{motion_stats, MotionStats, Options};
use motion_vrnn::generate::{self, to_poses};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How long and how many.
#[derive(Clone, Copy, Debug)]
pub struct HorizonOptions {
    /// Seconds each motion is rolled out for (30 fps).
    pub seconds: f64,
    /// Motions generated.
    pub motions: usize,
}

/// Draws of real windows that give the real-vs-real spread.
pub const REAL_DRAWS: usize = 8;

/// A measure of the table: name and value (a ratio to real is taken of it).
pub type Measure = (&'static str, fn(&MotionStats) -> f64);

/// The measures of the long-horizon table, each compared as generated ÷ real.
pub const MEASURES: [Measure; 9] = [
    ("jerk", |m| m.jerk_m_s3),
    ("contact", |m| m.contact_share),
    ("skating in contact", |m| m.skate_in_contact),
    ("APD", |m| m.apd_m),
    ("hips height", |m| m.hip_height_m),
    ("hips height, last 32", |m| m.hip_height_end_m),
    ("hips speed", |m| m.root_speed_m_s),
    ("hips speed, last 32", |m| m.root_speed_end_m_s),
    ("turning", |m| m.turning_deg_s),
];

/// One stretch of the rolled-out motions.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Stretch {
    /// Its first frame, seconds from the motions' start.
    pub start_s: f64,
    /// Every measure over the stretch of every motion.
    pub generated: MotionStats,
    /// Fréchet distance of the stretches to the evaluated split's windows.
    pub frechet: f64,
    /// Pose spread across the motions ([`motion_metrics::pose_spread`] of
    /// the stretches' summaries; absent in reports written before it).
    #[serde(default)]
    pub pose_spread: Option<f64>,
}

/// Range of `generated ÷ real` that real windows themselves give.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Spread {
    /// The measure ([`MEASURES`]).
    pub measure: String,
    /// Smallest and largest ratio over [`REAL_DRAWS`] draws.
    pub lo: f64,
    /// Largest ratio.
    pub hi: f64,
}

/// Pose spread across all real windows ([`motion_metrics::pose_spread`]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PoseSpread {
    /// Over all real windows.
    pub all: f64,
    /// Smallest and largest ratio of a draw's to `all`.
    pub lo: f64,
    /// Largest ratio.
    pub hi: f64,
}

/// Fréchet distances to the evaluated split of [`REAL_DRAWS`] draws
/// (without replacement) of as many training windows as there are motions
/// (at most half of them): what real motion scores at the generated set's
/// size, beside [`Horizon::frechet_reference`] (all training windows).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrechetDraws {
    /// Training windows a draw holds.
    pub windows: usize,
    /// Smallest distance over the draws.
    pub lo: f64,
    /// Mean over the draws.
    pub mean: f64,
    /// Largest.
    pub hi: f64,
}

/// The long-horizon evaluation (`eval.json`'s `horizon`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Horizon {
    /// Seconds rolled out.
    pub seconds: f64,
    /// Motions generated (each continuing a random training window).
    pub motions: usize,
    /// Frames per stretch (the dataset's window length).
    pub frames: usize,
    /// Real windows of the reference splits ([`reference_splits`]).
    pub real_windows: usize,
    /// Every measure over those real windows.
    pub real: MotionStats,
    /// Per measure, the ratios of draws of as many real windows as there
    /// are motions (without replacement) to all real windows.
    pub real_spread: Vec<Spread>,
    /// Fréchet distance of the training windows to the test windows (the
    /// reference, as in the 4-second evaluation).
    pub frechet_reference: f64,
    /// Pose spread across all real windows, and the range of the ratio for
    /// the draws of [`Horizon::real_spread`] (absent in reports written
    /// before it).
    #[serde(default)]
    pub real_pose_spread: Option<PoseSpread>,
    /// The Fréchet distance that real training windows give at the
    /// generated set's size (absent in reports written before it).
    #[serde(default)]
    pub frechet_draws: Option<FrechetDraws>,
    /// The gain the motions were held to their asked pace with
    /// ([`motion_vrnn::generate::PACE_GAIN`]; absent: not held, or a
    /// report written before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace_gain: Option<f64>,
    /// The draws of noise each run of a held motion was chosen from
    /// ([`motion_vrnn::generate::POSE_DRAWS`]; absent: not held, or a report
    /// written before draws were).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub draws: Option<usize>,
    /// Samplings of the model per output frame ([`samplings_per_frame`]; 0
    /// in reports written before it was recorded).
    #[serde(default)]
    pub samplings_per_frame: usize,
    /// How well a classifier tells the first and last stretch from the
    /// real windows (absent in reports written before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub realism: Option<Realism>,
    /// The stretches, in order.
    pub stretches: Vec<Stretch>,
}

/// Held-out balanced accuracy of a classifier two-sample test
/// ([`motion_metrics::two_sample::accuracy`]: 0.5, indistinguishable; 1,
/// always told apart), None where a fold lacked a class.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Realism {
    /// The first stretch of every motion against the real windows (each
    /// motion its own group, each take one).
    pub first: Option<f64>,
    /// The last stretch against the real windows.
    pub last: Option<f64>,
    /// The real windows of half the takes against the other half's: what
    /// real motion scores.
    pub real_vs_real: Option<f64>,
}

/// A take's group for the two-sample test: a fixed hash of its id (FNV-1a).
fn group_of(take: &str) -> u64 {
    take.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    })
}

/// The [`Realism`] of the motions `gen` (each `stretches × per` values)
/// against the `real` windows (`per` values each) of the takes `takes`.
fn realism(gen: &[Vec<f32>], real: &[Vec<f32>], takes: &[u64], per: usize, seed: u64) -> Realism {
    use motion_metrics::two_sample::{accuracy, window_features};
    let summary = |x: &[f32]| window_features(x, NUM_FEATURES);
    let real_s: Vec<Vec<f64>> = real.iter().map(|x| summary(x)).collect();
    let stretches = gen.first().map_or(0, |x| x.len() / per.max(1));
    let motions: Vec<u64> = (0..gen.len() as u64).collect();
    let stretch = |k: usize| {
        let s: Vec<Vec<f64>> = gen
            .iter()
            .map(|x| summary(&x[k * per..(k + 1) * per]))
            .collect();
        accuracy(&s, &motions, &real_s, takes, seed)
    };
    let half = |h: u64| -> (Vec<Vec<f64>>, Vec<u64>) {
        real_s
            .iter()
            .zip(takes)
            .filter(|(_, &t)| t % 2 == h)
            .map(|(s, &t)| (s.clone(), t))
            .unzip()
    };
    let ((a, ga), (b, gb)) = (half(0), half(1));
    Realism {
        first: (stretches > 0).then(|| stretch(0)).flatten(),
        last: (stretches > 1).then(|| stretch(stretches - 1)).flatten(),
        real_vs_real: accuracy(&a, &ga, &b, &gb, seed),
    }
}

pub use mocap_ingest::dataset::SPLITS;

/// The splits whose real windows an evaluation of `split` compares with:
/// every split for the report on `test`; `train` and `val` for any other,
/// so that a choice made on `val` never reads a `test` window.
pub fn reference_splits(split: &str) -> &'static [&'static str] {
    match split {
        "test" => &SPLITS,
        _ => &["train", "val"],
    }
}

/// Roll out `o.motions` motions of the loaded run `m` (with
/// [`reference_splits`] of `spec.split`) for
/// `o.seconds`, with `spec`'s context, seed and split, and measure every
/// stretch (see the module documentation).
pub fn horizon(m: &Run, spec: &RunSpec, o: HorizonOptions) -> Result<Horizon, EvalError> {
    let train = m.split("train")?;
    let test = m.split(&spec.split)?;
    let len = train.length;
    let fps = Options::default().fps;
    let stretches = ((o.seconds * fps).round() as usize) / len.max(1);
    if stretches == 0 || o.motions == 0 {
        return Err(EvalError::Invalid(format!(
            "--horizon {} s is shorter than one {len}-frame window, or no motions",
            o.seconds
        )));
    }
    let gen = m.sample(o.motions, stretches * len, spec.context, spec.seed)?;
    let opts = Options::default();
    let test_summaries = generate::summaries(&generate::windows_of(test), NUM_FEATURES);
    let train_summaries = generate::summaries(&generate::windows_of(train), NUM_FEATURES);
    let per = len * NUM_FEATURES;
    // Each stretch alone (on rayon's threads, collected in order).
    let out: Vec<Stretch> = (0..stretches)
        .into_par_iter()
        .map(|k| {
            let windows: Vec<Vec<f32>> = gen
                .iter()
                .map(|x| x[k * per..(k + 1) * per].to_vec())
                .collect();
            let poses: Vec<Vec<Pose>> = windows.iter().map(|x| m.generated_poses(x)).collect();
            let summaries = generate::summaries(&windows, NUM_FEATURES);
            Stretch {
                start_s: (k * len) as f64 / fps,
                generated: motion_stats(&poses, &opts),
                frechet: motion_metrics::frechet(&test_summaries, &summaries),
                pose_spread: Some(motion_metrics::pose_spread(&summaries)),
            }
        })
        .collect();
    // Every real window of the reference splits, and draws of the generated
    // set's size.
    let (mut real, mut real_summaries): (Vec<Vec<Pose>>, Vec<Vec<f64>>) = (Vec::new(), Vec::new());
    let (mut real_windows, mut real_takes) = (Vec::new(), Vec::new());
    for &split in reference_splits(&spec.split) {
        if let Some(w) = m.data.splits.get(split) {
            let windows = generate::windows_of(w);
            real.extend(windows.iter().map(|x| to_poses(x, &m.data.stats)));
            real_summaries.extend(generate::summaries(&windows, NUM_FEATURES));
            real_takes.extend(m.data.takes_of(split).iter().map(|t| group_of(t)));
            real_windows.extend(windows);
        }
    }
    let realism = realism(&gen, &real_windows, &real_takes, per, spec.seed);
    let all = motion_stats(&real, &opts);
    let (real_spread, real_pose_spread) =
        real_draws(&real, &real_summaries, &all, o.motions, spec.seed);
    let held = m.held_pace();
    Ok(Horizon {
        seconds: (stretches * len) as f64 / fps,
        motions: o.motions,
        frames: len,
        real_windows: real.len(),
        real: all,
        real_spread,
        frechet_reference: motion_metrics::frechet(&test_summaries, &train_summaries),
        real_pose_spread: Some(real_pose_spread),
        frechet_draws: frechet_draws(&test_summaries, &train_summaries, o.motions, spec.seed),
        pace_gain: held.map(|h| h.0),
        draws: held.map(|h| h.1),
        samplings_per_frame: samplings_per_frame(held.map(|h| h.1)),
        realism: Some(realism),
        stretches: out,
    })
}

/// The real-vs-real ranges of [`REAL_DRAWS`] draws (seeded by `seed`) of
/// as many of the `real` windows as there are `motions` (at most half of
/// them): each measure's ratio to `all`, and the pose spread's.
fn real_draws(
    real: &[Vec<Pose>],
    real_summaries: &[Vec<f64>],
    all: &MotionStats,
    motions: usize,
    seed: u64,
) -> (Vec<Spread>, PoseSpread) {
    let all_pose_spread = motion_metrics::pose_spread(real_summaries);
    let draw = motions.min(real.len() / 2).max(1);
    let draws: Vec<(MotionStats, f64)> = (0..REAL_DRAWS as u64)
        .into_par_iter()
        .map(|d| {
            let perm = motion_vrnn::rng::Rng::new(seed, 0xD4A7 + d).permutation(real.len());
            let pick: Vec<Vec<Pose>> = perm[..draw].iter().map(|&i| real[i].clone()).collect();
            let summaries: Vec<Vec<f64>> = perm[..draw]
                .iter()
                .map(|&i| real_summaries[i].clone())
                .collect();
            (
                motion_stats(&pick, &Options::default()),
                motion_metrics::pose_spread(&summaries),
            )
        })
        .collect();
    let (lo, hi) = lo_hi(draws.iter().map(|d| d.1 / all_pose_spread));
    let real_pose_spread = PoseSpread {
        all: all_pose_spread,
        lo,
        hi,
    };
    let spread = MEASURES
        .iter()
        .map(|(name, f)| {
            let (lo, hi) = lo_hi(draws.iter().map(|d| f(&d.0) / f(all)));
            Spread {
                measure: name.to_string(),
                lo,
                hi,
            }
        })
        .collect();
    (spread, real_pose_spread)
}

/// [`FrechetDraws`] of `train` summaries against `split`'s, drawn with
/// `seed`; None where there are too few training windows to draw from.
fn frechet_draws(
    split: &[Vec<f64>],
    train: &[Vec<f64>],
    motions: usize,
    seed: u64,
) -> Option<FrechetDraws> {
    let windows = motions.min(train.len() / 2);
    if windows < 2 {
        return None;
    }
    let d: Vec<f64> = (0..REAL_DRAWS as u64)
        .into_par_iter()
        .map(|d| {
            let perm = motion_vrnn::rng::Rng::new(seed, 0xF7EC + d).permutation(train.len());
            let pick: Vec<Vec<f64>> = perm[..windows].iter().map(|&i| train[i].clone()).collect();
            motion_metrics::frechet(split, &pick)
        })
        .collect();
    let (lo, hi) = lo_hi(d.iter().copied());
    Some(FrechetDraws {
        windows,
        lo,
        mean: crate::mean_of(&d),
        hi,
    })
}

/// The real-vs-real cell of the Fréchet column: the range of
/// [`Horizon::frechet_draws`] (empty in a report written before it).
pub fn frechet_draws_range(h: &Horizon) -> String {
    h.frechet_draws.as_ref().map_or(String::new(), |f| {
        format!("{} train: {:.1}–{:.1}", f.windows, f.lo, f.hi)
    })
}

/// A band of the long-horizon goal (issue 24 §2): the measure's name and
/// whether a stretch's `generated ÷ real` (or value) meets it.
pub type Band = (&'static str, fn(&Horizon, &Stretch) -> bool);

/// Ratio of a measure of a stretch to all real windows.
fn ratio(h: &Horizon, st: &Stretch, f: fn(&MotionStats) -> f64) -> f64 {
    f(&st.generated) / f(&h.real)
}

/// The bands every stretch of a minute must meet (`docs/metrics.md`,
/// "Goals"); the reconstruction's jerk is checked once per run, not here.
pub const BANDS: [Band; 9] = [
    ("jerk 0.67–1.5×", |h, s| {
        (0.67..=1.5).contains(&ratio(h, s, |m| m.jerk_m_s3))
    }),
    ("bone cv ≤ 1 %", |_, s| s.generated.bone_cv <= 0.01),
    ("contact 0.75–1.25×", |h, s| {
        near(ratio(h, s, |m| m.contact_share))
    }),
    ("skating ≤ 2×", |h, s| {
        ratio(h, s, |m| m.skate_in_contact) <= 2.0
    }),
    ("APD 0.75–1.25×", |h, s| near(ratio(h, s, |m| m.apd_m))),
    ("hips height 0.75–1.25× (whole, last 32)", |h, s| {
        near(ratio(h, s, |m| m.hip_height_m)) && near(ratio(h, s, |m| m.hip_height_end_m))
    }),
    ("hips speed 0.75–1.25× (whole, last 32)", |h, s| {
        near(ratio(h, s, |m| m.root_speed_m_s)) && near(ratio(h, s, |m| m.root_speed_end_m_s))
    }),
    ("turning 0.67–1.5×", |h, s| {
        (0.67..=1.5).contains(&ratio(h, s, |m| m.turning_deg_s))
    }),
    ("Fréchet ≤ train-vs-test", |h, s| {
        s.frechet <= h.frechet_reference
    }),
];

/// A stretch's pose spread across motions ÷ all real windows' (None in a
/// report written before it was measured).
pub fn pose_spread_ratio(h: &Horizon, st: &Stretch) -> Option<f64> {
    let real = h.real_pose_spread.as_ref()?.all;
    Some(st.pose_spread? / real).filter(|_| real > 0.0)
}

/// The real-vs-real range of [`pose_spread_ratio`] as a table cell.
pub fn pose_spread_range(h: &Horizon) -> String {
    h.real_pose_spread
        .as_ref()
        .map_or(String::new(), |p| format!("{:.2}–{:.2}", p.lo, p.hi))
}

fn near(x: f64) -> bool {
    (0.75..=1.25).contains(&x)
}

/// The bands `st` misses.
pub fn misses(h: &Horizon, st: &Stretch) -> Vec<&'static str> {
    BANDS
        .iter()
        .filter(|(_, ok)| !ok(h, st))
        .map(|b| b.0)
        .collect()
}

/// Samplings of the model per output frame: 1 for the model alone, `draws
/// × (1 + PACE_CORRECTIONS)` for motions held to their pace with `draws`
/// draws per run ([`motion_vrnn::generate::PACE_CORRECTIONS`]).
pub fn samplings_per_frame(held_draws: Option<usize>) -> usize {
    held_draws.map_or(1, |d| {
        d.max(1) * (1 + motion_vrnn::generate::PACE_CORRECTIONS)
    })
}

/// The sentence a report says its motions were held to their asked pace
/// with (`gain`: [`Horizon::pace_gain`]; `draws`: [`Horizon::draws`];
/// None: nothing).
pub fn held_sentence(gain: Option<f64>, draws: Option<usize>) -> String {
    let chosen = match draws {
        Some(d) if d > 1 => format!(
            "; each motion kept, of {d} draws of noise so held, the one whose mean pose is \
             closest to its context's (`--draws`)"
        ),
        _ => String::new(),
    };
    match gain {
        Some(g) => format!(
            " Each motion held to its asked pace: each run of at most {} frames tried {} times \
             on its noise, the pace asked for moved by {g} × (target − the pace the try made) \
             after each (`--pace-gain`){chosen} (`docs/metrics.md`).",
            motion_vrnn::generate::PACE_EVERY,
            motion_vrnn::generate::PACE_CORRECTIONS + 1
        ),
        None => String::new(),
    }
}

/// The long-horizon table in Markdown under the heading `title`: one row
/// per stretch, each measure as generated ÷ all real windows of the
/// reference splits, the real-vs-real range in the header.
pub fn markdown(h: &Horizon, title: &str) -> String {
    let mut s = format!(
        "\n## {title}: {} motions rolled out for {:.0} s from training contexts, {} sampling{} per frame\n\n\
         Each {}-frame stretch re-based to its own start and measured against all {} real windows \
         of the reference splits (generated ÷ real); under each measure, the range of the same ratio for \
         {REAL_DRAWS} draws of {} real windows. Fréchet: against the evaluated split \
         (train-vs-split reference {:.1}; under it, the range for {REAL_DRAWS} draws of as many training \
         windows). Bone cv in %. Pose spread: how widely the stretches' average \
         poses differ across motions (`docs/metrics.md`), a diagnostic of the Fréchet distance, not a \
         band; stride (how far the toes swing past each other, generated ÷ real) a diagnostic too.{held}\n\n| stretch |",
        h.motions,
        h.seconds,
        h.samplings_per_frame,
        if h.samplings_per_frame == 1 { "" } else { "s" },
        h.frames,
        h.real_windows,
        h.motions.min(h.real_windows / 2),
        h.frechet_reference,
        held = held_sentence(h.pace_gain, h.draws)
    );
    for (name, _) in MEASURES {
        s += &format!(" {name} |");
    }
    s += " bone cv | in the air % | stride | Fréchet | pose spread |\n|---|";
    for _ in 0..MEASURES.len() + 5 {
        s += "---|";
    }
    s += "\n| real vs real |";
    for sp in &h.real_spread {
        s += &format!(" {:.2}–{:.2} |", sp.lo, sp.hi);
    }
    s += &format!(
        " | real {:.1} | real {:.2} m | {} | {} |\n",
        100.0 * h.real.airborne_share,
        h.real.stride_m,
        frechet_draws_range(h),
        pose_spread_range(h)
    );
    for st in &h.stretches {
        s += &format!(
            "| {:.1}–{:.1} s |",
            st.start_s,
            st.start_s + h.frames as f64 / 30.0
        );
        // Generated ÷ real, n/a where real is 0 (the stride in old reports).
        let ratio = |f: fn(&MotionStats) -> f64| {
            let real = f(&h.real);
            if real.abs() > 1e-12 {
                format!("{:.2}", f(&st.generated) / real)
            } else {
                "n/a".to_string()
            }
        };
        for (_, f) in MEASURES {
            s += &format!(" {} |", ratio(f));
        }
        s += &format!(
            " {:.2} | {:.1} | {} | {:.1} | {} |\n",
            100.0 * st.generated.bone_cv,
            100.0 * st.generated.airborne_share,
            ratio(|m| m.stride_m),
            st.frechet,
            pose_spread_ratio(h, st).map_or("n/a".into(), |r| format!("{r:.2}"))
        );
    }
    s + &verdict(h) + &realism_line(h)
}

/// One line on [`Horizon::realism`] (empty in a report without it).
pub fn realism_line(h: &Horizon) -> String {
    let Some(r) = &h.realism else {
        return String::new();
    };
    let p = |v: Option<f64>| v.map_or("n/a".into(), |x| format!("{:.2}", x));
    format!(
        "\nRealism (a classifier two-sample test: a logistic regression on each window's per-feature mean, \
         spread, step and second step, {}-fold cross-validated by take and by motion; held-out balanced \
         accuracy, 0.5: indistinguishable, goal ≤ 0.65): first stretch {}, last stretch {}; real windows \
         of half the takes against the other half {}.\n",
        motion_metrics::two_sample::FOLDS,
        p(r.first),
        p(r.last),
        p(r.real_vs_real)
    )
}

/// The stretches of `h` that meet every band, and each band missed with
/// how many stretches miss it (in the order they are first missed).
pub fn tally(h: &Horizon) -> (usize, Vec<(&'static str, usize)>) {
    let (mut clean, mut missed) = (0, Vec::<(&'static str, usize)>::new());
    for st in &h.stretches {
        let m = misses(h, st);
        clean += usize::from(m.is_empty());
        for b in m {
            match missed.iter_mut().find(|x| x.0 == b) {
                Some(x) => x.1 += 1,
                None => missed.push((b, 1)),
            }
        }
    }
    (clean, missed)
}

/// One line on the minute's goal: how many stretches meet every band, and
/// which bands the others miss in how many stretches ([`tally`], in the
/// order of [`BANDS`]).
pub fn verdict(h: &Horizon) -> String {
    let (clean, mut missed) = tally(h);
    missed.sort_by_key(|(b, _)| BANDS.iter().position(|x| x.0 == *b));
    let missed: Vec<String> = missed.iter().map(|(b, n)| format!("{b} in {n}")).collect();
    format!(
        "\nWithin every band of the minute's goal: {} of {} stretches{}.\n",
        clean,
        h.stretches.len(),
        if missed.is_empty() {
            String::new()
        } else {
            format!("; missed: {}", missed.join(", "))
        }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(scale: f64) -> MotionStats {
        MotionStats {
            motions: 4,
            apd_m: 0.6,
            jerk_m_s3: 160.0,
            contact_share: 0.7,
            skate_in_contact: 0.1,
            hip_height_m: 0.9,
            hip_height_end_m: 0.9,
            root_speed_m_s: 0.25 * scale,
            root_speed_end_m_s: 0.25,
            turning_deg_s: 50.0,
            ..MotionStats::default()
        }
    }

    #[test]
    fn val_is_compared_with_train_and_val_only() {
        assert_eq!(reference_splits("val"), ["train", "val"]);
        assert_eq!(reference_splits("train"), ["train", "val"]);
        assert_eq!(reference_splits("test"), ["train", "val", "test"]);
    }

    #[test]
    fn the_default_sampler_costs_32_samplings_a_frame() {
        assert_eq!(samplings_per_frame(None), 1);
        assert_eq!(samplings_per_frame(Some(1)), 4);
        assert_eq!(samplings_per_frame(Some(8)), 32);
    }

    fn horizon(stretch: MotionStats, frechet: f64) -> Horizon {
        Horizon {
            seconds: 4.27,
            motions: 4,
            frames: 128,
            real_windows: 8,
            real: stats(1.0),
            real_spread: Vec::new(),
            frechet_reference: 70.0,
            real_pose_spread: None,
            frechet_draws: None,
            pace_gain: None,
            draws: None,
            samplings_per_frame: 1,
            realism: None,
            stretches: vec![Stretch {
                start_s: 0.0,
                generated: stretch,
                frechet,
                pose_spread: None,
            }],
        }
    }

    #[test]
    fn frechet_draws_are_real_windows_at_the_generated_size() {
        // Constant summaries: every draw is 3-4-5 away (no covariance).
        let split = vec![vec![3.0, 4.0]; 6];
        let train = vec![vec![0.0, 0.0]; 10];
        let f = frechet_draws(&split, &train, 256, 0).expect("10 windows to draw from");
        assert_eq!(f.windows, 5, "at most half the training windows");
        for v in [f.lo, f.mean, f.hi] {
            assert!((v - 25.0).abs() < 1e-9, "{v}");
        }
        assert!(frechet_draws(&split, &train[..3], 256, 0).is_none());
        let mut h = horizon(stats(1.0), 60.0);
        assert_eq!(frechet_draws_range(&h), "");
        h.frechet_draws = Some(f);
        assert_eq!(frechet_draws_range(&h), "5 train: 25.0–25.0");
    }

    #[test]
    fn the_table_says_when_motions_were_held_to_their_pace() {
        let mut h = horizon(stats(1.0), 60.0);
        assert!(!markdown(&h, "Long horizon").contains("held to its asked pace"));
        let json = serde_json::to_value(&h).expect("serialises");
        assert!(json.get("pace_gain").is_none(), "absent when not held");
        h.pace_gain = Some(0.5);
        h.draws = Some(8);
        let md = markdown(&h, "Long horizon");
        assert!(
            md.contains("of 8 draws of noise so held, the one whose mean pose"),
            "{md}"
        );
        assert!(
            md.contains("held to its asked pace: each run of at most 128 frames tried 4 times"),
            "{md}"
        );
        assert!(md.contains("moved by 0.5 × (target − the pace"), "{md}");
        let back: Horizon =
            serde_json::from_value(serde_json::to_value(&h).expect("serialises")).expect("reads");
        assert_eq!((back.pace_gain, back.draws), (Some(0.5), Some(8)));
        // One draw is not a choice.
        h.draws = Some(1);
        assert!(!markdown(&h, "Long horizon").contains("draws of noise"));
    }

    #[test]
    fn pose_spread_is_a_ratio_to_real_and_absent_in_old_reports() {
        let mut h = horizon(stats(1.0), 60.0);
        assert_eq!(pose_spread_ratio(&h, &h.stretches[0]), None);
        assert_eq!(pose_spread_range(&h), "");
        h.real_pose_spread = Some(PoseSpread {
            all: 2.0,
            lo: 0.9,
            hi: 1.05,
        });
        assert_eq!(pose_spread_ratio(&h, &h.stretches[0]), None);
        h.stretches[0].pose_spread = Some(3.0);
        assert_eq!(pose_spread_ratio(&h, &h.stretches[0]), Some(1.5));
        // A set of identical motions spreads 0×, not "unmeasured".
        h.stretches[0].pose_spread = Some(0.0);
        assert_eq!(pose_spread_ratio(&h, &h.stretches[0]), Some(0.0));
        assert_eq!(pose_spread_range(&h), "0.90–1.05");
        // A report written before the pose spread reads back without it.
        let mut old = serde_json::to_value(&h).expect("serialises");
        if let Some(o) = old["stretches"][0].as_object_mut() {
            o.remove("pose_spread");
        }
        if let Some(o) = old.as_object_mut() {
            o.remove("real_pose_spread");
        }
        let back: Horizon = serde_json::from_value(old).expect("reads back");
        assert!(back.real_pose_spread.is_none() && back.stretches[0].pose_spread.is_none());
    }

    #[test]
    fn the_table_shows_the_stride_beside_the_bands_and_n_a_in_old_reports() {
        let mut h = horizon(
            MotionStats {
                stride_m: 0.09,
                ..stats(1.0)
            },
            60.0,
        );
        h.real.stride_m = 0.12;
        let md = markdown(&h, "Long horizon");
        assert!(md.contains("| in the air % | stride | Fréchet |"), "{md}");
        assert!(md.contains("| real 0.12 m |"), "{md}");
        let row = md.lines().find(|l| l.starts_with("| 0.0–4.3 s")).unwrap();
        assert!(row.contains("| 0.75 | 60.0 |"), "{row}");
        h.real.stride_m = 0.0;
        let md = markdown(&h, "Long horizon");
        let row = md.lines().find(|l| l.starts_with("| 0.0–4.3 s")).unwrap();
        assert!(row.contains("| n/a | 60.0 |"), "{row}");
    }

    #[test]
    fn a_stretch_misses_exactly_the_bands_it_leaves() {
        let h = horizon(stats(1.0), 60.0);
        assert!(misses(&h, &h.stretches[0]).is_empty());
        // Hips 1.3× as fast over the whole stretch (not the last 32 frames),
        // uneven bones and a Fréchet distance above the reference.
        let h = horizon(
            MotionStats {
                bone_cv: 0.02,
                ..stats(1.3)
            },
            80.0,
        );
        assert_eq!(
            misses(&h, &h.stretches[0]),
            [
                "bone cv ≤ 1 %",
                "hips speed 0.75–1.25× (whole, last 32)",
                "Fréchet ≤ train-vs-test"
            ]
        );
        assert_eq!(
            verdict(&h),
            "\nWithin every band of the minute's goal: 0 of 1 stretches; missed: bone cv ≤ 1 % in 1, \
             hips speed 0.75–1.25× (whole, last 32) in 1, Fréchet ≤ train-vs-test in 1.\n"
        );
        // The bands' edges are inside: 1.25× speed passes.
        let h = horizon(stats(1.25), 60.0);
        assert!(misses(&h, &h.stretches[0]).is_empty());
        assert_eq!(
            verdict(&h),
            "\nWithin every band of the minute's goal: 1 of 1 stretches.\n"
        );
    }
}
