//! Measures of motion quality, computed the same way on real and generated
//! motion (definitions in `docs/metrics.md`).
//!
//! A motion is a sequence of [`Pose`]s (global joint positions in CMU units,
//! floor at `y = 0`, as [`mocap_ingest::features::to_global`] returns them).
//! Feature windows are `[frames][58]` in normalised units.

// Index loops here read like the formulas they implement.
#![allow(clippy::needless_range_loop)]

pub mod two_sample;

use mocap_ingest::math::{norm, scale, sub};
use mocap_ingest::skeleton::{Pose, JOINT_PARENTS, LEFT_TOE, NUM_JOINTS, RIGHT_TOE};
use serde::{Deserialize, Serialize};

mod distribution;
pub use distribution::{
    frechet, frechet_of_subsets, mean_spread, pose_spread, symmetric_eigen, window_summary,
};

/// Metres per CMU unit (`(1/0.45)` inches).
pub const METRES_PER_UNIT: f64 = 0.0564;
/// Foot joints for skating: LeftToeBase and RightToeBase.
pub const FEET: [usize; 2] = [LEFT_TOE, RIGHT_TOE];

/// Options of the motion measures.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Options {
    /// Frames per second.
    pub fps: f64,
    /// Frequency above which spectral power counts as jitter (Hz).
    pub cutoff_hz: f64,
    /// A foot is in contact when it is this close to the floor (m).
    pub contact_m: f64,
    /// A foot in contact skates when faster than this horizontally (m/s).
    pub skate_m_s: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            fps: 30.0,
            cutoff_hz: 5.0,
            contact_m: 0.05,
            skate_m_s: 0.5,
        }
    }
}

/// Measures of one set of motions.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MotionStats {
    /// Number of motions.
    pub motions: usize,
    /// Average pairwise distance (m).
    pub apd_m: f64,
    /// Mean jerk magnitude (m/s³).
    pub jerk_m_s3: f64,
    /// Share of (root-relative, mean-removed) spectral power above the cutoff.
    pub high_freq_share: f64,
    /// Mean over bones of std(length)/mean(length).
    pub bone_cv: f64,
    /// Share of foot-frames that are in contact yet skate.
    pub skate_share: f64,
    /// Share of foot-frames in contact with the floor.
    pub contact_share: f64,
    /// Among foot-frames in contact, the share that skate.
    #[serde(default)]
    pub skate_in_contact: f64,
    /// Creep: among foot-frames in contact that do not skate, the mean
    /// horizontal toe speed (m/s): planted feet that slide too slowly to
    /// count as skating (0 in reports written before it).
    #[serde(default)]
    pub creep_m_s: f64,
    /// Drift: mean hips height above the floor, over whole motions (m).
    #[serde(default)]
    pub hip_height_m: f64,
    /// Mean hips height over the last [`TAIL`] frames of each motion (m).
    #[serde(default)]
    pub hip_height_end_m: f64,
    /// Drift: mean horizontal speed of the hips, over whole motions (m/s).
    #[serde(default)]
    pub root_speed_m_s: f64,
    /// Mean horizontal hips speed over the last [`TAIL`] frames (m/s).
    #[serde(default)]
    pub root_speed_end_m_s: f64,
    /// Turning rate: mean absolute change of the facing direction, degrees
    /// per second ([`turning_rate`]).
    #[serde(default)]
    pub turning_deg_s: f64,
    /// Share of frames with no joint within [`AIRBORNE_M`] of the floor
    /// ([`airborne_share`]; 0 in reports written before it).
    #[serde(default)]
    pub airborne_share: f64,
    /// Stride: how far the toes swing past each other along the facing
    /// direction, m ([`stride`]; 0 in reports written before it).
    #[serde(default)]
    pub stride_m: f64,
}

/// Height of a frame's lowest joint above which the figure is in the air
/// ([`airborne_share`]): 5 cm, the foot-contact height.
pub const AIRBORNE_M: f64 = 0.05;

/// Share of a motion's frames whose lowest joint is more than
/// [`AIRBORNE_M`] above the floor (`y = 0`): a figure off the ground.
pub fn airborne_share(m: &[Pose]) -> f64 {
    if m.is_empty() {
        return 0.0;
    }
    let up = m
        .iter()
        .filter(|p| p.iter().fold(f64::INFINITY, |a, j| a.min(j[1])) * METRES_PER_UNIT > AIRBORNE_M)
        .count();
    up as f64 / m.len() as f64
}

/// Frames at the end of a motion over which drift is measured.
pub const TAIL: usize = 32;

/// Mean hips height (m) over frames `from..` of a motion.
pub fn hip_height(m: &[Pose], from: usize) -> f64 {
    let f = &m[from.min(m.len())..];
    if f.is_empty() {
        return 0.0;
    }
    f.iter().map(|p| p[0][1]).sum::<f64>() / f.len() as f64 * METRES_PER_UNIT
}

/// Mean horizontal speed of the hips (m/s) over the steps that end in
/// frames `from..` (and after frame 0).
pub fn root_speed(m: &[Pose], from: usize, fps: f64) -> f64 {
    let steps: Vec<f64> = (from.max(1)..m.len())
        .map(|t| {
            let (dx, dz) = (m[t][0][0] - m[t - 1][0][0], m[t][0][2] - m[t - 1][0][2]);
            (dx * dx + dz * dz).sqrt()
        })
        .collect();
    if steps.is_empty() {
        return 0.0;
    }
    steps.iter().sum::<f64>() / steps.len() as f64 * fps * METRES_PER_UNIT
}

/// Average pairwise distance: over all pairs of motions, the mean Euclidean
/// distance between corresponding joints at corresponding frames (m). Motions
/// are compared over their common length.
pub fn apd(motions: &[Vec<Pose>]) -> f64 {
    use rayon::prelude::*;
    // Each pair's mean distance on rayon's threads (pairs of motion `i`
    // together), then summed one after the other in (i, j) order: the same
    // bits as one thread.
    let per_pair: Vec<Vec<f64>> = (0..motions.len())
        .into_par_iter()
        .map(|i| {
            let mut out = Vec::new();
            for j in i + 1..motions.len() {
                let t = motions[i].len().min(motions[j].len());
                if t == 0 {
                    continue;
                }
                let mut d = 0.0;
                for (a, b) in motions[i][..t].iter().zip(&motions[j][..t]) {
                    // A frame's distances first (a loop that vectorises),
                    // then summed joint by joint as before.
                    let mut n = [0.0f64; NUM_JOINTS];
                    for ((n, p), q) in n.iter_mut().zip(a).zip(b) {
                        *n = norm(sub(*p, *q));
                    }
                    for v in n {
                        d += v;
                    }
                }
                out.push(d / (t * NUM_JOINTS) as f64);
            }
            out
        })
        .collect();
    let (mut sum, mut pairs) = (0.0, 0usize);
    for v in per_pair.iter().flatten() {
        sum += v;
        pairs += 1;
    }
    if pairs == 0 {
        0.0
    } else {
        sum / pairs as f64 * METRES_PER_UNIT
    }
}

/// Mean magnitude of the third difference of joint positions times fps³ (m/s³).
pub fn jerk(m: &[Pose], fps: f64) -> f64 {
    if m.len() < 4 {
        return 0.0;
    }
    let mut sum = 0.0;
    for t in 3..m.len() {
        for k in 0..NUM_JOINTS {
            // p(t) − 3p(t−1) + 3p(t−2) − p(t−3)
            let a = sub(m[t][k], m[t - 3][k]);
            let b = sub(m[t - 1][k], m[t - 2][k]);
            sum += norm(sub(a, scale(b, 3.0)));
        }
    }
    sum / ((m.len() - 3) * NUM_JOINTS) as f64 * fps.powi(3) * METRES_PER_UNIT
}

/// Share of spectral power above `cutoff_hz`: for every joint but the root
/// and every axis, the position relative to the root with its mean removed,
/// a Hann window, and the DFT power at `0 < f`; summed over joints and axes.
pub fn high_freq_share(m: &[Pose], fps: f64, cutoff_hz: f64) -> f64 {
    let n = m.len();
    if n < 4 {
        return 0.0;
    }
    let hann: Vec<f64> = (0..n)
        .map(|t| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * t as f64 / (n - 1) as f64).cos())
        .collect();
    // cos/sin of every (time, frequency) pair, computed once.
    let freqs = n / 2;
    let (mut cos, mut sin) = (vec![0.0; freqs * n], vec![0.0; freqs * n]);
    for t in 0..n {
        for f in 1..=freqs {
            let a = -2.0 * std::f64::consts::PI * ((f * t) % n) as f64 / n as f64;
            cos[t * freqs + f - 1] = a.cos();
            sin[t * freqs + f - 1] = a.sin();
        }
    }
    let (mut high, mut total) = (0.0, 0.0);
    let mut x = vec![0.0; n];
    let (mut re, mut im) = (vec![0.0; freqs], vec![0.0; freqs]);
    for k in 1..NUM_JOINTS {
        for c in 0..3 {
            for (t, v) in x.iter_mut().enumerate() {
                *v = m[t][k][c] - m[t][0][c];
            }
            let mean = x.iter().sum::<f64>() / n as f64;
            for (v, w) in x.iter_mut().zip(&hann) {
                *v = (*v - mean) * w;
            }
            // Every frequency's sums at once, each over time in order (as
            // `Iterator::sum`, from −0.0): the frequencies are independent,
            // so the loop over them vectorises.
            re.fill(-0.0);
            im.fill(-0.0);
            for (t, &v) in x.iter().enumerate() {
                let row = t * freqs..(t + 1) * freqs;
                for ((r, i), (cv, sv)) in re
                    .iter_mut()
                    .zip(im.iter_mut())
                    .zip(cos[row.clone()].iter().zip(&sin[row]))
                {
                    *r += v * cv;
                    *i += v * sv;
                }
            }
            for (f, (re, im)) in (1..=freqs).zip(re.iter().zip(&im)) {
                let p = re * re + im * im;
                total += p;
                if f as f64 * fps / n as f64 > cutoff_hz {
                    high += p;
                }
            }
        }
    }
    if total > 0.0 {
        high / total
    } else {
        0.0
    }
}

/// Mean over the 18 bones (joint to parent) of std(length)/mean(length).
pub fn bone_cv(m: &[Pose]) -> f64 {
    if m.is_empty() {
        return 0.0;
    }
    let mut sum = 0.0;
    let mut bones = 0;
    for (k, p) in JOINT_PARENTS.iter().enumerate() {
        let Some(p) = *p else { continue };
        let l: Vec<f64> = m.iter().map(|pose| norm(sub(pose[k], pose[p]))).collect();
        let (mean, std) = mean_std(&l);
        if mean > 0.0 {
            sum += std / mean;
        }
        bones += 1;
    }
    sum / bones as f64
}

/// Foot-frames of a motion (both toe joints, frames `t ≥ 1`), counted by
/// [`foot_skating`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FootFrames {
    /// In contact and skating.
    pub skate: usize,
    /// In contact.
    pub contact: usize,
    /// All foot-frames.
    pub all: usize,
    /// Sum of the horizontal speeds (m/s) of the foot-frames in contact
    /// that do not skate: how fast planted feet creep.
    pub creep_sum_m_s: f64,
}

impl FootFrames {
    /// Share of the foot-frames in contact that skate.
    pub fn skate_in_contact(&self) -> f64 {
        self.skate as f64 / self.contact.max(1) as f64
    }

    /// Mean horizontal speed (m/s) of the foot-frames in contact that do
    /// not skate: the creep of planted toes.
    pub fn creep_m_s(&self) -> f64 {
        self.creep_sum_m_s / (self.contact - self.skate).max(1) as f64
    }
}

impl std::ops::AddAssign for FootFrames {
    fn add_assign(&mut self, o: Self) {
        self.skate += o.skate;
        self.contact += o.contact;
        self.all += o.all;
        self.creep_sum_m_s += o.creep_sum_m_s;
    }
}

/// A motion's foot-frames. A foot (toe joint) is in contact at frame
/// `t ≥ 1` when its height is below `contact_m`, and skates when its
/// horizontal speed from `t − 1` to `t` exceeds `skate_m_s`; a foot in
/// contact that does not skate adds its speed to the creep.
pub fn foot_skating(m: &[Pose], o: &Options) -> FootFrames {
    let mut n = FootFrames::default();
    for t in 1..m.len() {
        for &f in &FEET {
            n.all += 1;
            if m[t][f][1] * METRES_PER_UNIT >= o.contact_m {
                continue;
            }
            n.contact += 1;
            let (dx, dz) = (m[t][f][0] - m[t - 1][f][0], m[t][f][2] - m[t - 1][f][2]);
            let speed = (dx * dx + dz * dz).sqrt() * METRES_PER_UNIT * o.fps;
            if speed > o.skate_m_s {
                n.skate += 1;
            } else {
                n.creep_sum_m_s += speed;
            }
        }
    }
    n
}

/// Every measure over a set of motions (per-motion values averaged; skating
/// pooled over all foot-frames).
pub fn motion_stats(motions: &[Vec<Pose>], o: &Options) -> MotionStats {
    use rayon::prelude::*;
    let n = motions.len().max(1) as f64;
    // Each motion's value on rayon's threads, summed in the motions' order.
    let mean = |f: &(dyn Fn(&[Pose]) -> f64 + Sync)| {
        let each: Vec<f64> = motions.par_iter().map(|m| f(m)).collect();
        each.iter().sum::<f64>() / n
    };
    // Summed in the motions' order: the creep's sum is a float.
    let mut feet = FootFrames::default();
    let each: Vec<_> = motions.par_iter().map(|m| foot_skating(m, o)).collect();
    for n in each {
        feet += n;
    }
    let (s, c) = (feet.skate, feet.contact);
    let a = feet.all.max(1) as f64;
    MotionStats {
        motions: motions.len(),
        apd_m: apd(motions),
        jerk_m_s3: mean(&|m| jerk(m, o.fps)),
        high_freq_share: mean(&|m| high_freq_share(m, o.fps, o.cutoff_hz)),
        bone_cv: mean(&bone_cv),
        skate_share: s as f64 / a,
        contact_share: c as f64 / a,
        skate_in_contact: feet.skate_in_contact(),
        creep_m_s: feet.creep_m_s(),
        hip_height_m: mean(&|m| hip_height(m, 0)),
        hip_height_end_m: mean(&|m| hip_height(m, m.len().saturating_sub(TAIL))),
        root_speed_m_s: mean(&|m| root_speed(m, 0, o.fps)),
        root_speed_end_m_s: mean(&|m| root_speed(m, m.len().saturating_sub(TAIL), o.fps)),
        turning_deg_s: mean(&|m| turning_rate(m, o.fps)),
        airborne_share: mean(&airborne_share),
        stride_m: mean(&stride),
    }
}

/// Stride of a motion (m): the standard deviation over its frames of how
/// far the left toe is ahead of the right along the facing direction (the
/// local frame's +z of `docs/features.md`, as [`turning_rate`] reads it).
/// Walking swings it from one foot ahead to the other; a figure that
/// shuffles or stands keeps it nearly constant. Frames whose facing is
/// undefined are left out; 0 below two frames.
pub fn stride(m: &[Pose]) -> f64 {
    let ahead: Vec<f64> = m
        .iter()
        .filter_map(|p| {
            let f = mocap_ingest::features::LocalFrame::of(p, 0.0)?;
            Some((f.to_local(p[FEET[0]])[2] - f.to_local(p[FEET[1]])[2]) * METRES_PER_UNIT)
        })
        .collect();
    if ahead.len() < 2 {
        return 0.0;
    }
    mean_std(&ahead).1
}

/// Mean and (population) standard deviation of `v` (not empty).
fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// Turning rate of a motion: the mean absolute change, from frame to frame,
/// of its facing direction (the local frame's +z of `docs/features.md`,
/// from the hips and both shoulders), in degrees per second. Frames whose
/// facing is undefined are left out with their neighbours' steps.
pub fn turning_rate(m: &[Pose], fps: f64) -> f64 {
    let facing: Vec<Option<[f64; 3]>> = m
        .iter()
        .map(|p| mocap_ingest::features::LocalFrame::of(p, 0.0).map(|f| f.ez))
        .collect();
    let steps: Vec<f64> = facing
        .windows(2)
        .filter_map(|w| {
            let (a, b) = (w[0]?, w[1]?);
            // Signed angle from a to b about +y, in the floor plane.
            let cross = a[2] * b[0] - a[0] * b[2];
            let dot = a[0] * b[0] + a[2] * b[2];
            Some(cross.atan2(dot).abs())
        })
        .collect();
    if steps.is_empty() {
        return 0.0;
    }
    (steps.iter().sum::<f64>() / steps.len() as f64 * fps).to_degrees()
}

/// The least-squares slope of `y` on `x` over the pairs `(x, y)`: how much
/// of the differences between the `x` come back in the `y` (1: all of
/// them, 0: none). Given per category a real measure and a generated one,
/// it says whether the categories keep the differences real ones have, or
/// are drawn toward one value (`docs/metrics.md`, "Categories kept
/// apart"). None below two pairs or where every `x` is the same.
pub fn slope(pairs: &[(f64, f64)]) -> Option<f64> {
    if pairs.len() < 2 {
        return None;
    }
    let n = pairs.len() as f64;
    let (sx, sy) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0, b + p.1));
    let (mx, my) = (sx / n, sy / n);
    let (sxy, sxx) = pairs.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    (sxx > 0.0).then(|| sxy / sxx)
}

/// Bone-length variation a generated motion may have before
/// [`goal_distance`] counts it (the goal of issue 11: 1 %).
pub const BONE_CV_GOAL: f64 = 0.01;

/// How far generated motion is from real motion on every measure at once,
/// for choosing among checkpoints: the sum of `|ln(generated ÷ real)|` over
/// jerk, foot contact, APD, hips height and hips speed (whole motions and
/// last [`TAIL`] frames), plus the one-sided terms `max(0, ln(·))` of
/// skating in contact ÷ real, bone cv ÷ [`BONE_CV_GOAL`] and Fréchet ÷
/// `frechet_ref`. 0 means every ratio is 1 (or better, for the one-sided
/// terms); a ratio of 0 counts as 1e-3.
pub fn goal_distance(real: &MotionStats, gen: &MotionStats, frechet: f64, frechet_ref: f64) -> f64 {
    let ln = |a: f64, b: f64| (a.max(1e-3 * b.abs()) / b).ln();
    let two_sided = [
        (gen.jerk_m_s3, real.jerk_m_s3),
        (gen.contact_share, real.contact_share),
        (gen.apd_m, real.apd_m),
        (gen.hip_height_m, real.hip_height_m),
        (gen.hip_height_end_m, real.hip_height_end_m),
        (gen.root_speed_m_s, real.root_speed_m_s),
        (gen.root_speed_end_m_s, real.root_speed_end_m_s),
    ];
    let one_sided = [
        (gen.skate_in_contact, real.skate_in_contact),
        (gen.bone_cv, BONE_CV_GOAL),
        (frechet, frechet_ref),
    ];
    let defined = |b: f64| b.is_finite() && b > 0.0;
    two_sided
        .iter()
        .filter(|(_, b)| defined(*b))
        .map(|&(a, b)| ln(a, b).abs())
        .chain(
            one_sided
                .iter()
                .filter(|(_, b)| defined(*b))
                .map(|&(a, b)| ln(a, b).max(0.0)),
        )
        .sum()
}

#[cfg(test)]
mod tests;
