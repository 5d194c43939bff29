//! A user's clip continued: its frames, as features, are the context the
//! model reads; what it generates after them is appended, and the whole is
//! one motion continuous at the seam (`cargo xtask continue`).

use crate::run::{Asking, Run, OWN};
use crate::samples::{pin_generated, FeetPinned};
use crate::EvalError;
use mocap_ingest::features::{to_global, FeatureVec};
use mocap_ingest::Pose;
use motion_render::Motion;
use motion_vrnn::data::Windows;
use motion_vrnn::generate::{continue_windows, denormalise, Rollout, CONTEXT};
use motion_vrnn::steer::steer_windows;

/// Frames per second of the features (and of the BVH written).
pub const FPS: f64 = 30.0;

/// The longest continuation, in seconds (an hour: 108,000 frames).
pub const MAX_SECONDS: f64 = 3600.0;

/// How long, how many, from which seed, along which path.
#[derive(Clone, Debug)]
pub struct ContinueOptions {
    /// Seconds of generated motion after the clip.
    pub seconds: f64,
    /// Seed of the first variation; variation `k` uses `seed + k`.
    pub seed: u64,
    /// Variations to generate.
    pub variations: usize,
    /// Last frames of the clip the model reads (all of it when shorter).
    pub context: usize,
    /// A path the continuation follows from the clip's last frame (a
    /// model with the control), or None: free.
    pub path: Option<motion_steer::Path>,
}

impl Default for ContinueOptions {
    fn default() -> Self {
        ContinueOptions {
            seconds: 10.0,
            seed: 0,
            variations: 1,
            context: CONTEXT,
            path: None,
        }
    }
}

impl ContinueOptions {
    /// An error naming the option that cannot work.
    pub fn validate(&self) -> Result<(), EvalError> {
        if !(self.seconds > 0.0 && self.seconds <= MAX_SECONDS) {
            return Err(EvalError::Invalid(format!(
                "--seconds must be positive and at most {MAX_SECONDS}, got {}",
                self.seconds
            )));
        }
        if self.variations == 0 || self.context == 0 {
            return Err(EvalError::Invalid(
                "--variations and --context must be at least 1".into(),
            ));
        }
        Ok(())
    }
}

/// How the motion moves across the seam, against how the clip itself moves
/// (mean joint displacement between consecutive frames, CMU units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seam {
    /// From the clip's last frame to the first generated frame.
    pub jump: f64,
    /// The clip's own displacement per frame, mean over its frames.
    pub clip_mean: f64,
    /// The clip's own displacement per frame, its largest.
    pub clip_max: f64,
    /// The clip's last step (into its last frame).
    pub clip_last: f64,
    /// The generated motion's displacement per frame over its first second
    /// after the seam.
    pub next_second: f64,
}

/// One continuation: the clip's frames then the generated ones.
pub struct Continued {
    /// The whole motion (30 fps, global joint positions).
    pub motion: Motion,
    /// Frames of it that are the clip's.
    pub clip_frames: usize,
    /// The seed it was generated with.
    pub seed: u64,
    /// The seam, measured.
    pub seam: Seam,
    /// With [`crate::run::RunSpec::pin_feet`]: what pinning the feet did
    /// to the generated frames (the clip's are left as they are).
    pub pinned: Option<FeetPinned>,
}

/// Mean joint displacement between two poses.
fn step(a: &Pose, b: &Pose) -> f64 {
    let d: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| {
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        })
        .sum();
    d / a.len().max(1) as f64
}

/// The seam of `poses` whose first `clip` frames are the clip's.
pub fn seam(poses: &[Pose], clip: usize) -> Seam {
    let own: Vec<f64> = poses[..clip]
        .windows(2)
        .map(|w| step(&w[0], &w[1]))
        .collect();
    Seam {
        jump: poses.get(clip).map_or(0.0, |p| step(&poses[clip - 1], p)),
        clip_mean: crate::mean_of(&own),
        clip_max: own.iter().copied().fold(0.0, f64::max),
        clip_last: own.last().copied().unwrap_or(0.0),
        next_second: crate::mean_of(
            &poses[clip..]
                .windows(2)
                .take(FPS as usize)
                .map(|w| step(&w[0], &w[1]))
                .collect::<Vec<_>>(),
        ),
    }
}

/// Continue `clip` (features at 30 fps, as the dataset computes them) with
/// the model of `run`: `o.variations` motions, each the clip followed by
/// `o.seconds` of generated motion. The model reads the clip's last
/// `o.context` frames through its posterior (as `sample` reads a training
/// window's); the root path and facing are integrated over the whole, so
/// position and facing continue across the seam.
pub fn continue_clip(
    run: &Run,
    clip: &[FeatureVec],
    o: &ContinueOptions,
) -> Result<Vec<Continued>, EvalError> {
    if clip.len() < 2 {
        return Err(EvalError::Invalid(format!(
            "the clip has {} frame(s) at 30 fps; continuing needs at least 2",
            clip.len()
        )));
    }
    o.validate()?;
    let stats = &run.data.stats;
    let k = o.context.min(clip.len());
    let generated = (o.seconds * FPS).round().max(1.0) as usize;
    let window = Windows {
        data: clip[clip.len() - k..]
            .iter()
            .flat_map(|f| {
                f.iter()
                    .enumerate()
                    .map(|(i, v)| ((v - stats.mean[i]) / stats.std[i]) as f32)
            })
            .collect(),
        n: 1,
        length: k,
        features: stats.mean.len(),
    };
    (0..o.variations as u64)
        .map(|v| {
            let seed = o.seed + v;
            // The motion's first frame is the clip's last: the rest is new.
            let rollout = Rollout {
                frames: generated + 1,
                context: k,
                seed,
                pace_gain: run.pace_gain,
                draws: run.draws,
                ask: match run.ask {
                    Asking::Nothing => None,
                    Asking::One(_, a) => Some(a),
                    // A clip has no category: none unless one is named.
                    Asking::Own(_) if !run.asked_explicitly => None,
                    Asking::Own(_) => {
                        return Err(EvalError::Invalid(format!(
                            "--category {OWN} asks for the category of a training window; a clip has none: name one"
                        )))
                    }
                },
            };
            let model = &run.model.model;
            let x = match &o.path {
                Some(path) => {
                    let rollout = Rollout {
                        pace_gain: 0.0,
                        draws: 1,
                        ..rollout
                    };
                    steer_windows(model, &window, &[0], &rollout, path, stats, &run.device)?
                        .remove(0)
                        .frames
                }
                None => continue_windows(model, &window, &[0], &rollout, &run.device)?.remove(0),
            };
            let mut frames = clip.to_vec();
            frames.extend(denormalise(&x[window.features..], stats));
            let mut motion = Motion {
                id: format!("continued_{seed}"),
                poses: to_global(&frames),
            };
            let pinned = run
                .pin_feet
                .then(|| pin_generated(std::slice::from_mut(&mut motion), clip.len()));
            Ok(Continued {
                seam: seam(&motion.poses, clip.len()),
                pinned,
                motion,
                clip_frames: clip.len(),
                seed,
            })
        })
        .collect()
}

/// Each continuation of `done` (from [`continue_clip`] with options of
/// `seed`) written as a BVH at `out` (several: `OUT_k.bvh`, k from 0) and
/// read back: a line per file, what `continue` prints.
pub fn write_continued(
    done: &[Continued],
    seed: u64,
    out: &std::path::Path,
) -> Result<String, EvalError> {
    let stem = out.with_extension("");
    let dir = out.parent().unwrap_or(std::path::Path::new("."));
    crate::create_dir(dir)?;
    let mut printed = String::new();
    for c in done {
        let path = match done.len() {
            1 => out.to_path_buf(),
            _ => std::path::PathBuf::from(format!("{}_{}.bvh", stem.display(), c.seed - seed)),
        };
        motion_render::bvh::write_bvh(&path, &c.motion)?;
        let check = motion_render::bvh::read_motion(&path, "check")?;
        printed += &format!(
            "{} <- seed {}: {} + {} frames ({:.1} s); seam step {:.3} ({:.2}x the clip's mean, clip's last {:.3}, next second {:.3}); read back: {} frames\n",
            path.display(), c.seed, c.clip_frames, c.motion.poses.len() - c.clip_frames,
            c.motion.poses.len() as f64 / 30.0, c.seam.jump, c.seam.jump / c.seam.clip_mean.max(1e-9), c.seam.clip_last, c.seam.next_second, check.poses.len()
        );
        c.pinned.iter().for_each(|p| printed += &format!("  {p}\n"));
    }
    Ok(printed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f64) -> Pose {
        let mut p = Pose::default();
        for (j, q) in p.iter_mut().enumerate() {
            *q = [x, j as f64, 0.0];
        }
        p
    }

    #[test]
    fn the_seam_compares_the_jump_with_the_clips_own_steps() {
        // The clip moves 1, then 3 units a frame; the seam jumps 2.
        let poses = [pose(0.0), pose(1.0), pose(4.0), pose(6.0), pose(6.5)];
        let s = seam(&poses, 3);
        assert_eq!(s.jump, 2.0);
        assert_eq!(s.clip_mean, 2.0);
        assert_eq!(s.clip_max, 3.0);
        assert_eq!(s.clip_last, 3.0);
        assert_eq!(s.next_second, 0.5);
    }
}
