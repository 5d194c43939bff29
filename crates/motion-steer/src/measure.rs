//! Steering measures: how well a generated root followed what was asked.

use crate::follow::WINDOW_M;
use crate::path::Path;
use crate::{dist, heading_deg, FPS};

/// Share of the path's length the root must have passed (by projection) for
/// reaching the end to count, so a closed path's start is not its end.
pub const REACH_SHARE: f64 = 0.9;

/// Mean over frames of the distance from the root to the path, metres (NaN
/// for no frames).
pub fn path_error(path: &Path, roots: &[[f64; 2]]) -> f64 {
    let sum: f64 = roots.iter().map(|&r| path.distance(r)).sum();
    sum / roots.len() as f64
}

/// Seconds (first frame / FPS) at which the root is within `within_m` of the
/// path's end, having passed [`REACH_SHARE`] of its length; `None` if never.
/// Progress is the root's projection on the path, searched up to
/// [`crate::follow::WINDOW_M`] ahead of the previous frame's, as the follower
/// does.
pub fn reach_seconds(path: &Path, roots: &[[f64; 2]], within_m: f64) -> Option<f64> {
    let end = path.point_at(path.length());
    let mut s = 0.0;
    for (t, &r) in roots.iter().enumerate() {
        s = path.project(r, s, WINDOW_M);
        if s >= REACH_SHARE * path.length() && dist(r, end) <= within_m {
            return Some(t as f64 / FPS);
        }
    }
    None
}

/// Seconds after `from_frame` until the facing (`forward[t]`) is within
/// `tolerance_deg` of `target`; `None` if it never is.
pub fn turn_seconds(
    forward: &[[f64; 2]],
    from_frame: usize,
    target: [f64; 2],
    tolerance_deg: f64,
) -> Option<f64> {
    let t = forward
        .iter()
        .skip(from_frame)
        .position(|&f| heading_deg(f, target).abs() <= tolerance_deg)?;
    Some(t as f64 / FPS)
}
