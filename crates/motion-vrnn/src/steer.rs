//! Steered motion: generated motions asked, at every frame, to follow a
//! path ([`crate::model::Parts::control`], `motion_steer::Follower`).

use crate::data::{Stats, Windows};
use crate::generate::{Rollout, PACE_EVERY};
use crate::model::MotionModel;
use crate::rng::noise;
use candle_core::{Device, Tensor};
use mocap_ingest::features::{ANG_VEL_Y, VEL_X, VEL_Z};
use motion_steer::{root_track, Follower, Frame2, Path, CONTROL};

/// One steered motion.
#[derive(Clone, Debug)]
pub struct Steered {
    /// Normalised features `[frames × features]`; the first frame is the
    /// context's last (where the path starts).
    pub frames: Vec<f32>,
    /// The root at every frame, in the path's frame (metres; the first
    /// frame at the origin facing +z).
    pub track: Vec<Frame2>,
}

/// The root's motion `(vel_x, vel_z, ang_vel_y)` of a normalised frame, in
/// the dataset's units.
fn root_of(frame: &[f32], stats: &Stats) -> [f64; 3] {
    [VEL_X, VEL_Z, ANG_VEL_Y].map(|k| frame[k] as f64 * stats.std[k] + stats.mean[k])
}

/// The root at `at` moved by one frame's root motion `root`
/// ([`motion_steer::root_track`]'s step, in `at`'s axes).
fn advanced(at: &Frame2, root: [f64; 3]) -> Frame2 {
    let d = root_track(&[[0.0; 3], root])[1];
    let to = |v: [f64; 2]| [0, 1].map(|i| at.right[i] * v[0] + at.forward[i] * v[1]);
    let p = to(d.pos);
    Frame2 {
        pos: [at.pos[0] + p[0], at.pos[1] + p[1]],
        right: to(d.right),
        forward: to(d.forward),
    }
}

/// One motion of `o.frames` frames per index in `picks`, each continuing
/// the first `o.context` frames of that window of `starts` (as
/// [`crate::generate::continue_windows`] does, the model alone: one draw,
/// no pace held) and asked at every frame to follow `path`, which starts
/// at the context's last frame, facing where it faces. The motion is made
/// in runs of [`PACE_EVERY`] frames, as the sampler makes it; each frame's
/// control comes from where the root of the frame before it is
/// (`motion_steer::Follower::control`). The same model, options and path
/// give the same motions.
pub fn steer_windows(
    model: &dyn MotionModel,
    starts: &Windows,
    picks: &[usize],
    o: &Rollout,
    path: &Path,
    stats: &Stats,
    device: &Device,
) -> candle_core::Result<Vec<Steered>> {
    let config = model.config();
    if !config.parts.control {
        candle_core::bail!(
            "this model was trained without the control, so it cannot be steered; train the default model (`cargo xtask train`), which reads it"
        );
    }
    let (k, f, n) = (o.context, starts.features, picks.len());
    if picks.iter().any(|&i| i >= starts.n) || k == 0 || k > starts.length {
        candle_core::bail!(
            "steering continues 1 to {} frames of one of {} windows",
            starts.length,
            starts.n
        );
    }
    let mut context = starts.batch(picks, device)?.narrow(1, 0, k)?;
    let cond = match o.ask {
        Some(a) => config.condition(&vec![Some(a.row); n], a.guidance, device)?,
        None => None,
    };
    let cond = config.paced(cond.as_ref(), Some(&context))?;
    let frames = o.frames.max(1);
    let mut followers = vec![Follower::new(path.clone()); n];
    let mut out: Vec<Steered> = vec![
        Steered {
            frames: Vec::with_capacity(frames * f),
            track: vec![Frame2::START],
        };
        n
    ];
    let mut made = 0;
    for run in 0u64.. {
        let new = PACE_EVERY.min(frames - made.max(1));
        let eps = noise(o.seed ^ 0x57EE_2000, run, k + new, n, config.latent, device)?;
        let mut at: Vec<Frame2> = out.iter().map(|s| s.track[s.track.len() - 1]).collect();
        let mut control = |step: usize, so_far: &[Tensor]| -> candle_core::Result<Option<Tensor>> {
            // The context is read as it is; each new frame is asked from
            // where the root of the frame before it is.
            if step < k {
                return Ok(None);
            }
            if step > k {
                let last = so_far[step - 1].to_vec2::<f32>()?;
                for (a, row) in at.iter_mut().zip(&last) {
                    *a = advanced(a, root_of(row, stats));
                }
            }
            let rows: Vec<f32> = followers
                .iter_mut()
                .zip(&at)
                .flat_map(|(fo, a)| fo.control(a))
                .collect();
            Tensor::from_vec(rows, (n, CONTROL), device).map(Some)
        };
        let x = model
            .steer(&eps, Some(&context), cond.as_ref(), &mut control)?
            .narrow(1, k - 1, new + 1)?;
        let v = x.flatten_all()?.to_vec1::<f32>()?;
        for (m, s) in v.chunks((new + 1) * f).zip(out.iter_mut()) {
            let fresh = if made == 0 { m } else { &m[f..] };
            s.frames.extend_from_slice(fresh);
            for row in m[f..].chunks(f) {
                let next = advanced(&s.track[s.track.len() - 1], root_of(row, stats));
                s.track.push(next);
            }
        }
        made = out[0].frames.len() / f;
        if made >= frames {
            break;
        }
        let last: Vec<f32> = out
            .iter()
            .flat_map(|s| s.frames[(made - k) * f..].iter().copied())
            .collect();
        context = Tensor::from_vec(last, (n, k, f), device)?;
    }
    Ok(out)
}
