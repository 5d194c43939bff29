//! Steered motion: generated motions asked, at every frame, to follow a
//! path ([`crate::model::Parts::control`], `motion_steer::Follower`).

use crate::data::{Stats, Windows};
use crate::generate::{Rollout, PACE_EVERY};
use crate::model::MotionModel;
use crate::rng::noise;
use candle_core::{Device, Tensor};
use mocap_ingest::features::{ANG_VEL_Y, VEL_X, VEL_Z};
use motion_steer::{Follower, Frame2, Path, CONTROL};

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
        // Each new frame is asked from where the root of the frame before
        // it is, and that root joins the track; the context is read as it is.
        let mut tracks: Vec<&mut Vec<Frame2>> = out.iter_mut().map(|s| &mut s.track).collect();
        let mut control = |step: usize, so_far: &[Tensor]| -> candle_core::Result<Option<Tensor>> {
            if step < k {
                return Ok(None);
            }
            if step > k {
                let last = so_far[step - 1].to_vec2::<f32>()?;
                for (track, row) in tracks.iter_mut().zip(&last) {
                    let next = track[track.len() - 1].advanced(root_of(row, stats));
                    track.push(next);
                }
            }
            let rows: Vec<f32> = followers
                .iter_mut()
                .zip(&tracks)
                .flat_map(|(fo, track)| fo.control(&track[track.len() - 1]))
                .collect();
            Tensor::from_vec(rows, (n, CONTROL), device).map(Some)
        };
        let x = model
            .steer(&eps, Some(&context), cond.as_ref(), &mut control)?
            .narrow(1, k - 1, new + 1)?;
        let v = x.flatten_all()?.to_vec1::<f32>()?;
        // The run's last frame was never asked from: its root ends the track.
        for (m, s) in v.chunks((new + 1) * f).zip(out.iter_mut()) {
            let fresh = if made == 0 { m } else { &m[f..] };
            s.frames.extend_from_slice(fresh);
            if new > 0 {
                let next = s.track[s.track.len() - 1].advanced(root_of(&m[new * f..], stats));
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
