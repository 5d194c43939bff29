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

/// The per-window summary the Fréchet distance compares: each feature's mean
/// over the window, then each feature's standard deviation over the window.
pub fn window_summary(window: &[Vec<f32>]) -> Vec<f64> {
    let f = window.first().map_or(0, |r| r.len());
    let n = window.len().max(1) as f64;
    let mut mean = vec![0.0; f];
    for r in window {
        for (m, v) in mean.iter_mut().zip(r) {
            *m += *v as f64 / n;
        }
    }
    let mut std = vec![0.0; f];
    for r in window {
        for ((s, v), m) in std.iter_mut().zip(r).zip(&mean) {
            *s += (*v as f64 - m).powi(2) / n;
        }
    }
    mean.extend(std.into_iter().map(f64::sqrt));
    mean
}

fn mean_cov(x: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let d = x.first().map_or(0, |r| r.len());
    let n = x.len() as f64;
    let mut mu = vec![0.0; d];
    for r in x {
        for (m, v) in mu.iter_mut().zip(r) {
            *m += v / n;
        }
    }
    let mut cov = vec![vec![0.0; d]; d];
    let denom = (n - 1.0).max(1.0);
    for r in x {
        for i in 0..d {
            let a = r[i] - mu[i];
            for j in 0..d {
                cov[i][j] += a * (r[j] - mu[j]) / denom;
            }
        }
    }
    (mu, cov)
}

/// Eigenvalues and eigenvectors (columns of the second result) of a
/// symmetric matrix, by cyclic Jacobi rotations.
pub fn symmetric_eigen(a: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut a: Vec<Vec<f64>> = a.to_vec();
    let mut v = vec![vec![0.0; n]; n];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let scale: f64 = (0..n).map(|i| a[i][i] * a[i][i]).sum::<f64>().max(1e-300);
        if off <= 1e-24 * scale {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i][i]).collect(), v)
}

/// Symmetric square root of a positive semi-definite matrix (negative
/// eigenvalues from rounding are taken as 0).
fn sqrtm_psd(a: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let (w, v) = symmetric_eigen(a);
    let n = a.len();
    let mut out = vec![vec![0.0; n]; n];
    for k in 0..n {
        let s = w[k].max(0.0).sqrt();
        for i in 0..n {
            for j in 0..n {
                out[i][j] += v[i][k] * s * v[j][k];
            }
        }
    }
    out
}

fn matmul(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let (n, m, p) = (a.len(), b.len(), b.first().map_or(0, |r| r.len()));
    let mut c = vec![vec![0.0; p]; n];
    for i in 0..n {
        for k in 0..m {
            let x = a[i][k];
            for j in 0..p {
                c[i][j] += x * b[k][j];
            }
        }
    }
    c
}

/// Fréchet distance between Gaussians fitted to two sets of vectors:
/// `‖μa − μb‖² + tr(Σa + Σb − 2 (Σa^½ Σb Σa^½)^½)`. NaN when a set is
/// empty or the two differ in dimension (no Gaussian to fit, nothing to
/// compare).
pub fn frechet(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let dim = |s: &[Vec<f64>]| s.first().map(Vec::len);
    if a.is_empty() || b.is_empty() || dim(a) != dim(b) {
        return f64::NAN;
    }
    let (ma, ca) = mean_cov(a);
    let (mb, cb) = mean_cov(b);
    let d2: f64 = ma.iter().zip(&mb).map(|(x, y)| (x - y).powi(2)).sum();
    let sa = sqrtm_psd(&ca);
    let inner = matmul(&matmul(&sa, &cb), &sa);
    // Symmetrise against rounding before the eigen-decomposition.
    let n = inner.len();
    let inner: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| 0.5 * (inner[i][j] + inner[j][i])).collect())
        .collect();
    let (w, _) = symmetric_eigen(&inner);
    let tr_sqrt: f64 = w.iter().map(|v| v.max(0.0).sqrt()).sum();
    let tr = |c: &[Vec<f64>]| (0..c.len()).map(|i| c[i][i]).sum::<f64>();
    (d2 + tr(&ca) + tr(&cb) - 2.0 * tr_sqrt).max(0.0)
}

/// Within-window spread of a set of [`window_summary`]s: the mean, over
/// windows and features, of each feature's standard deviation over its
/// window (the second half of a summary). How far a motion moves through
/// the feature space within its window; 0 for an empty set.
pub fn mean_spread(summaries: &[Vec<f64>]) -> f64 {
    let (sum, n) = summaries.iter().fold((0.0, 0usize), |(s, n), r| {
        let half = &r[r.len() / 2..];
        (s + half.iter().sum::<f64>(), n + half.len())
    });
    if n == 0 {
        0.0
    } else {
        sum / n as f64
    }
}

/// Pose spread across windows of a set of [`window_summary`]s: the summed
/// variance over windows (n − 1) of each feature's window mean (the first
/// half of a summary), the trace of their covariance and so that half's
/// share of [`frechet`]'s `tr(Σ)`. How widely the windows' average poses
/// differ from one another; 0 below two windows.
pub fn pose_spread(summaries: &[Vec<f64>]) -> f64 {
    let n = summaries.len();
    if n < 2 {
        return 0.0;
    }
    let d = summaries[0].len() / 2;
    (0..d)
        .map(|j| {
            let mean = summaries.iter().map(|r| r[j]).sum::<f64>() / n as f64;
            let ss: f64 = summaries.iter().map(|r| (r[j] - mean).powi(2)).sum();
            ss / (n - 1) as f64
        })
        .sum()
}

/// Fréchet distances of `real` to subsets of `pool` the size of `real`:
/// `k = ⌊|pool| ÷ |real|⌋` disjoint interleaved subsets (subset `j` takes
/// pool items `j, j + k, j + 2k, …`), so each spreads over the whole pool.
/// A reference of the same sample size as a set of `|real|` generated
/// windows: with few windows in many dimensions the distance grows as the
/// sets shrink, so [`frechet`] against the whole pool is the stricter
/// reference. Empty when the pool has fewer items than `real`.
pub fn frechet_of_subsets(real: &[Vec<f64>], pool: &[Vec<f64>]) -> Vec<f64> {
    let n = real.len();
    if n == 0 {
        return Vec::new();
    }
    let k = pool.len() / n;
    use rayon::prelude::*;
    (0..k)
        .into_par_iter()
        .map(|j| {
            let subset: Vec<Vec<f64>> = pool[j..].iter().step_by(k).take(n).cloned().collect();
            frechet(real, &subset)
        })
        .collect()
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
mod tests {
    #[test]
    fn frechet_of_an_empty_set_is_nan_not_a_panic() {
        let a = vec![vec![0.0, 1.0], vec![1.0, 0.0]];
        assert!(frechet(&a, &[]).is_nan());
        assert!(frechet(&[], &a).is_nan());
        assert!(frechet(&a, &[vec![1.0]]).is_nan());
        assert!(frechet(&a, &a).abs() < 1e-12);
    }

    use super::*;

    /// The measures over many motions (APD's pairs, each motion's values,
    /// Fréchet's subsets on rayon) are the same bits on one thread as on
    /// several.
    #[test]
    fn measures_do_not_depend_on_the_thread_count() {
        let mut state = 7u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let motions: Vec<Vec<Pose>> = (0..23)
            .map(|_| {
                (0..40)
                    .map(|_| {
                        let mut p = [[0.0; 3]; NUM_JOINTS];
                        for (k, j) in p.iter_mut().enumerate() {
                            *j = [next() * 20.0, 15.0 + k as f64 + next(), next() * 20.0];
                        }
                        p
                    })
                    .collect()
            })
            .collect();
        let real: Vec<Vec<f64>> = (0..5).map(|_| (0..4).map(|_| next()).collect()).collect();
        let pool: Vec<Vec<f64>> = (0..17).map(|_| (0..4).map(|_| next()).collect()).collect();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool")
                .install(|| {
                    let st = motion_stats(&motions, &Options::default());
                    (
                        // Debug prints each f64 so that it reads back exactly.
                        format!("{st:?}"),
                        frechet_of_subsets(&real, &pool)
                            .iter()
                            .map(|v| v.to_bits())
                            .collect::<Vec<_>>(),
                    )
                })
        };
        assert_eq!(run(1), run(3));
    }

    fn still(x: f64) -> Vec<Pose> {
        let mut p: Pose = [[0.0; 3]; NUM_JOINTS];
        for (k, j) in p.iter_mut().enumerate() {
            *j = [x, 1.0 + k as f64, 0.0];
        }
        vec![p; 8]
    }

    /// Hips at 9, shoulders 3 units either side and 5 above, turned by
    /// `yaw` radians about +y.
    fn facing(yaw: f64) -> Pose {
        use mocap_ingest::skeleton::{HIPS, LEFT_ARM, RIGHT_ARM};
        let mut p: Pose = [[0.0, 9.0, 0.0]; NUM_JOINTS];
        let (c, s) = (yaw.cos(), yaw.sin());
        // Local +x to the left shoulder when facing +z.
        p[HIPS] = [0.0, 9.0, 0.0];
        p[LEFT_ARM] = [3.0 * c, 14.0, -3.0 * s];
        p[RIGHT_ARM] = [-3.0 * c, 14.0, 3.0 * s];
        p
    }

    /// Toes `u` units either side of the hips along the facing direction,
    /// the left one ahead, in a figure turned by `yaw`.
    fn stepping(yaw: f64, u: f64) -> Pose {
        let mut p = facing(yaw);
        let (c, s) = (yaw.cos(), yaw.sin());
        // Local +z is (sin yaw, cos yaw) in the floor plane; the toes also
        // stand apart sideways, which the stride does not read.
        p[FEET[0]] = [u * s + 1.0 * c, 0.5, u * c - 1.0 * s];
        p[FEET[1]] = [-u * s - 1.0 * c, 0.5, -u * c + 1.0 * s];
        p
    }

    #[test]
    fn stride_of_steps_at_any_facing_and_of_a_still_stance() {
        // Left toe 2 units ahead, then 2 behind: "ahead" is ±4 units, whose
        // standard deviation is 4 units = 0.2256 m, however the figure faces.
        for yaw in [0.0, 0.7, -2.0] {
            let walk: Vec<Pose> = (0..10)
                .map(|t| stepping(yaw, if t % 2 == 0 { 2.0 } else { -2.0 }))
                .collect();
            assert!((stride(&walk) - 4.0 * METRES_PER_UNIT).abs() < 1e-12);
        }
        // A figure turning on the spot with one foot always 2 units ahead.
        let stance: Vec<Pose> = (0..10).map(|t| stepping(0.3 * t as f64, 2.0)).collect();
        assert!(stride(&stance).abs() < 1e-12);
        assert_eq!(stride(&stance[..1]), 0.0);
        // Three frames ahead by 0, 1 and 2 units (left toe at u/2): std √(2/3).
        let three: Vec<Pose> = (0..3).map(|t| stepping(0.0, t as f64 / 2.0)).collect();
        assert!((stride(&three) - (2.0f64 / 3.0).sqrt() * METRES_PER_UNIT).abs() < 1e-12);
    }

    #[test]
    fn turning_rate_of_a_steady_turn_and_a_swing() {
        // 3° a frame at 30 fps: 90°/s, either way.
        let left: Vec<Pose> = (0..31)
            .map(|t| facing((3.0 * t as f64).to_radians()))
            .collect();
        assert!((turning_rate(&left, 30.0) - 90.0).abs() < 1e-9);
        let right: Vec<Pose> = (0..31)
            .map(|t| facing((-3.0 * t as f64).to_radians()))
            .collect();
        assert!((turning_rate(&right, 30.0) - 90.0).abs() < 1e-9);
        // Across ±180°: the step is 10°, not 350°.
        let wrap = [facing(175f64.to_radians()), facing(-175f64.to_radians())];
        assert!((turning_rate(&wrap, 30.0) - 300.0).abs() < 1e-9);
        // Standing still, and too short to turn.
        assert_eq!(turning_rate(&vec![facing(0.5); 10], 30.0), 0.0);
        assert_eq!(turning_rate(&left[..1], 30.0), 0.0);
    }

    #[test]
    fn airborne_share_counts_frames_whose_lowest_joint_is_off_the_floor() {
        // Every joint at height h units: 0.05 m is 0.887 units.
        let at = |h: f64| -> Pose { [[1.0, h, 2.0]; NUM_JOINTS] };
        let m = [at(0.0), at(0.8), at(0.9), at(5.0), at(-3.0)];
        assert!((airborne_share(&m) - 0.4).abs() < 1e-12);
        // One joint on the floor grounds the frame.
        let mut one = at(5.0);
        one[7][1] = 0.1;
        assert_eq!(airborne_share(&[one]), 0.0);
        assert_eq!(airborne_share(&[]), 0.0);
    }

    #[test]
    fn apd_of_shifted_copies() {
        // Three copies 0, 1 and 3 units apart in x: pair distances 1, 3, 2.
        let m = [still(0.0), still(1.0), still(3.0)];
        assert!((apd(&m) - 2.0 * METRES_PER_UNIT).abs() < 1e-12);
    }

    #[test]
    fn drift_of_a_rising_gliding_root() {
        // Hips at height 1 + t units, moving 3 units in x and 4 in z per
        // frame: 5 units per frame horizontally.
        let m: Vec<Pose> = (0..40)
            .map(|t| {
                let mut p: Pose = [[0.0; 3]; NUM_JOINTS];
                p[0] = [3.0 * t as f64, 1.0 + t as f64, 4.0 * t as f64];
                p
            })
            .collect();
        let u = METRES_PER_UNIT;
        assert!((hip_height(&m, 0) - 20.5 * u).abs() < 1e-12);
        // Last 32 frames: t = 8..39, mean height 1 + 23.5.
        assert!((hip_height(&m, 8) - 24.5 * u).abs() < 1e-12);
        assert!((root_speed(&m, 0, 30.0) - 150.0 * u).abs() < 1e-9);
        assert!((root_speed(&m, 8, 30.0) - 150.0 * u).abs() < 1e-9);
        let s = motion_stats(&[m], &Options::default());
        assert!((s.hip_height_end_m - 24.5 * u).abs() < 1e-12);
    }

    #[test]
    fn jerk_of_a_cubic() {
        // x = t³ (frames): third difference 6 units per frame³ for every joint.
        let m: Vec<Pose> = (0..10)
            .map(|t| [[(t * t * t) as f64, 0.0, 0.0]; NUM_JOINTS])
            .collect();
        assert!((jerk(&m, 30.0) - 6.0 * 27_000.0 * METRES_PER_UNIT).abs() < 1e-6);
        assert_eq!(jerk(&still(0.0), 30.0), 0.0);
    }

    #[test]
    fn high_frequency_share_of_pure_tones() {
        let tone = |hz: f64| -> Vec<Pose> {
            (0..128)
                .map(|t| {
                    let mut p: Pose = [[0.0; 3]; NUM_JOINTS];
                    let y = (2.0 * std::f64::consts::PI * hz * t as f64 / 30.0).sin();
                    for j in p.iter_mut().skip(1) {
                        *j = [0.0, y, 0.0];
                    }
                    p
                })
                .collect()
        };
        assert!(high_freq_share(&tone(1.0), 30.0, 5.0) < 0.01);
        assert!(high_freq_share(&tone(10.0), 30.0, 5.0) > 0.99);
    }

    #[test]
    fn bone_cv_of_a_stretching_bone() {
        let mut m = still(0.0);
        assert_eq!(bone_cv(&m), 0.0);
        // LeftUpLeg (1) sits at y = 2 or 4 (Hips at 1, LeftLeg at 3): the
        // bone to Hips has lengths 1 and 3 (cv 1/2), the bone from LeftLeg
        // lengths 1 and 1 (cv 0); 17 bones stay fixed.
        for (t, p) in m.iter_mut().enumerate() {
            p[1] = [0.0, if t % 2 == 0 { 2.0 } else { 4.0 }, 0.0];
        }
        assert!((bone_cv(&m) - 0.5 / 18.0).abs() < 1e-12);
    }

    /// Five frames of a figure 10 units up but for its toes, placed by
    /// `at(t)` (left, right).
    fn toes(at: impl Fn(f64) -> ([f64; 3], [f64; 3])) -> Vec<Pose> {
        (0..5)
            .map(|t| {
                let mut p: Pose = [[0.0, 10.0, 0.0]; NUM_JOINTS];
                (p[FEET[0]], p[FEET[1]]) = at(t as f64);
                p
            })
            .collect()
    }

    #[test]
    fn foot_skating_counts() {
        let o = Options::default();
        // Toes on the floor; the left toe slides 1 unit per frame
        // (1·0.0564·30 = 1.69 m/s), the right one stays.
        let m = toes(|t| ([t, 0.0, 0.0], [0.0; 3]));
        let n = foot_skating(&m, &o);
        assert_eq!((n.skate, n.contact, n.all, n.creep_sum_m_s), (4, 8, 8, 0.0));
        let s = motion_stats(&[m], &o);
        assert_eq!(
            (s.skate_share, s.contact_share, s.creep_m_s),
            (0.5, 1.0, 0.0)
        );
    }

    #[test]
    fn planted_toes_that_creep() {
        let o = Options::default();
        // Both toes on the floor, the left one creeping 0.1 unit a frame
        // (0.1·0.0564·30 = 0.1692 m/s, under the skating speed), the right
        // one still, then the right toe lifted 10 units for the last frame.
        let m = toes(|t| {
            (
                [0.1 * t, 0.0, 0.0],
                [0.0, if t == 4.0 { 10.0 } else { 0.0 }, 0.0],
            )
        });
        let n = foot_skating(&m, &o);
        // 4 creeping left foot-frames, 3 still right ones, 1 right in the air.
        assert_eq!((n.skate, n.contact, n.all), (0, 7, 8));
        assert!((n.creep_sum_m_s - 4.0 * 0.1692).abs() < 1e-9);
        let s = motion_stats(&[m], &o);
        assert!((s.creep_m_s - 4.0 * 0.1692 / 7.0).abs() < 1e-9);
        assert_eq!(s.skate_in_contact, 0.0);
    }

    #[test]
    fn frechet_of_known_gaussians() {
        // Identical sets: 0. Shifted by (3, 4): 25.
        let a: Vec<Vec<f64>> = vec![
            vec![0.0, 0.0],
            vec![1.0, 0.0],
            vec![0.0, 1.0],
            vec![1.0, 1.0],
        ];
        let b: Vec<Vec<f64>> = a.iter().map(|r| vec![r[0] + 3.0, r[1] + 4.0]).collect();
        assert!(frechet(&a, &a).abs() < 1e-9);
        assert!((frechet(&a, &b) - 25.0).abs() < 1e-9);
        // Scaled by 2 (covariances Σ and 4Σ, Σ = I/3): tr(Σ + 4Σ − 2·2Σ) = tr(Σ) = 2/3.
        let c: Vec<Vec<f64>> = a
            .iter()
            .map(|r| vec![2.0 * r[0] - 0.5, 2.0 * r[1] - 0.5])
            .collect();
        assert!((frechet(&a, &c) - 2.0 / 3.0).abs() < 1e-9);
    }

    #[test]
    fn spread_of_two_windows() {
        // Window 1: feature a goes 0, 2 (std 1), feature b stays (std 0);
        // window 2: a stays, b goes 1, 5 (std 2). Mean of 1, 0, 0, 2.
        let w1 = vec![vec![0.0, 3.0], vec![2.0, 3.0]];
        let w2 = vec![vec![1.0, 1.0], vec![1.0, 5.0]];
        let s = [window_summary(&w1), window_summary(&w2)];
        assert!((mean_spread(&s) - 0.75).abs() < 1e-12);
        assert_eq!(mean_spread(&[]), 0.0);
    }

    #[test]
    fn pose_spread_of_three_windows() {
        // Window means (a, b): (0, 3), (2, 3), (1, 6): a varies 1, b 3 (n − 1).
        let w = |a: f32, b: f32| vec![vec![a, b], vec![a, b]];
        let s = [w(0.0, 3.0), w(2.0, 3.0), w(1.0, 6.0)].map(|x| window_summary(&x));
        assert!((pose_spread(&s) - 4.0).abs() < 1e-12);
        assert_eq!(pose_spread(&s[..1]), 0.0);
    }

    #[test]
    fn frechet_of_interleaved_subsets() {
        // A pool of 5 points for a real set of 2: k = 2 subsets, {0, 2} and
        // {1, 3}; point 4 is left over.
        let real = vec![vec![0.0], vec![2.0]];
        let pool: Vec<Vec<f64>> = [0.0, 10.0, 2.0, 12.0, 99.0].map(|x| vec![x]).to_vec();
        let d = frechet_of_subsets(&real, &pool);
        assert_eq!(d.len(), 2);
        // Same points: 0. Shifted by 10: 100.
        assert!(d[0].abs() < 1e-9 && (d[1] - 100.0).abs() < 1e-9, "{d:?}");
        assert!(frechet_of_subsets(&real, &pool[..1]).is_empty());
    }

    #[test]
    fn slope_is_least_squares() {
        // x 1, 2, 3 (mean 2), y 2, 3, 5 (mean 10/3): Σ(x−x̄)(y−ȳ) = 4/3 + 0 + 5/3
        // = 3, Σ(x−x̄)² = 2, so 1.5.
        let s = slope(&[(1.0, 2.0), (2.0, 3.0), (3.0, 5.0)]).unwrap();
        assert!((s - 1.5).abs() < 1e-12, "{s}");
        // Halfway to one value: y = 0.5 x + 1.
        let half: Vec<(f64, f64)> = [0.1, 0.4, 0.7]
            .iter()
            .map(|&x| (x, 0.5 * x + 1.0))
            .collect();
        assert!((slope(&half).unwrap() - 0.5).abs() < 1e-12);
        // Every category alike: 0.
        assert_eq!(slope(&[(0.2, 0.3), (0.6, 0.3)]), Some(0.0));
        // One pair, or no difference to follow: none.
        assert_eq!(slope(&[(1.0, 2.0)]), None);
        assert_eq!(slope(&[(1.0, 2.0), (1.0, 3.0)]), None);
    }

    #[test]
    fn eigen_of_a_2x2() {
        let (w, _) = symmetric_eigen(&[vec![2.0, 1.0], vec![1.0, 2.0]]);
        let mut w = w;
        w.sort_by(f64::total_cmp);
        assert!((w[0] - 1.0).abs() < 1e-12 && (w[1] - 3.0).abs() < 1e-12);
    }

    #[test]
    fn window_summary_is_mean_then_std() {
        let w = vec![vec![1.0f32, 0.0], vec![3.0, 0.0]];
        assert_eq!(window_summary(&w), vec![2.0, 0.0, 1.0, 0.0]);
    }

    #[test]
    fn goal_distance_sums_log_ratios() {
        let real = MotionStats {
            jerk_m_s3: 10.0,
            contact_share: 0.5,
            apd_m: 1.0,
            hip_height_m: 1.0,
            hip_height_end_m: 1.0,
            root_speed_m_s: 0.4,
            root_speed_end_m_s: 0.4,
            skate_in_contact: 0.1,
            bone_cv: 0.002,
            ..MotionStats::default()
        };
        // Every ratio 1, bones and skating within their goals: distance 0.
        let same = MotionStats {
            bone_cv: 0.0,
            skate_in_contact: 0.05,
            ..real.clone()
        };
        assert!(goal_distance(&real, &same, 50.0, 70.0).abs() < 1e-12);
        // Jerk ×2, speed ÷2 at the end, bones 4 %, skating ×3, Fréchet ×1.5.
        let off = MotionStats {
            jerk_m_s3: 20.0,
            root_speed_end_m_s: 0.2,
            bone_cv: 0.04,
            skate_in_contact: 0.3,
            ..real.clone()
        };
        let want = 2f64.ln() + 2f64.ln() + 4f64.ln() + 3f64.ln() + 1.5f64.ln();
        assert!((goal_distance(&real, &off, 105.0, 70.0) - want).abs() < 1e-12);
        // A frozen motion (APD 0) counts as 1e-3 of real, not infinity.
        let frozen = MotionStats { apd_m: 0.0, ..same };
        assert!((goal_distance(&real, &frozen, 50.0, 70.0) - 1000f64.ln()).abs() < 1e-9);
    }
}
