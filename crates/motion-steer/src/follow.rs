//! The follower: turns an asked [`Path`] into control rows, frame by frame,
//! from where the generated root actually is.

use crate::path::Path;
use crate::{Frame2, CONTROL, CONTROL_FRAMES, FPS};

/// How far ahead of its progress (metres) the follower looks for the root's
/// closest point on the path, each frame.
pub const WINDOW_M: f64 = 1.5;

/// Progress this close to the end (metres) has finished the path.
pub const REACHED_M: f64 = 0.05;

/// The most the asked speed rises above the path's (m/s) when the root is
/// behind the path's schedule: by as many metres a second as it is
/// behind, up to this.
pub const LEAD_M: f64 = 1.0;

/// Progress this close to a wait's point (metres) starts the wait: wider
/// than [`REACHED_M`], so a root that stops a little short is not left
/// waiting for a wait that never starts.
pub const WAIT_REACHED_M: f64 = 0.25;

/// Turns a path into control rows, keeping a progress along it that only
/// moves forward.
#[derive(Clone, Debug)]
pub struct Follower {
    path: Path,
    /// Progress: arc length, metres.
    s: f64,
    /// Index into the path's waits of the next one not yet held.
    next_wait: usize,
    /// Frames left of the wait being held, if one is.
    holding: Option<usize>,
    /// Arc length the path asks to have reached by now (its speeds, from
    /// the start, stopping at a pending wait's point).
    due: f64,
}

impl Follower {
    /// A follower at the start of `path`.
    pub fn new(path: Path) -> Follower {
        Follower {
            path,
            s: 0.0,
            next_wait: 0,
            holding: None,
            due: 0.0,
        }
    }

    /// The path followed.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Progress along the path, metres of arc length.
    pub fn progress(&self) -> f64 {
        self.s
    }

    /// Whether the path is finished: progress within [`REACHED_M`] of the end
    /// and no wait pending.
    pub fn done(&self) -> bool {
        self.holding.is_none()
            && self.next_wait >= self.path.waits().len()
            && self.path.length() - self.s <= REACHED_M
    }

    /// Arc length of the next wait's point, if a wait is pending.
    fn wait_arc(&self) -> Option<f64> {
        let &(i, _) = self.path.waits().get(self.next_wait)?;
        Some(self.path.arc_at_point(i))
    }

    /// The control row for the frame where the root is at `at`: called once
    /// per generated frame. Progress moves to the root's closest point up to
    /// [`WINDOW_M`] ahead; the target k frames ahead is the path's point
    /// `speed·k/FPS` further on and its tangent there, in `at`'s axes (the
    /// path's speed, plus how far progress is behind its schedule, in m/s,
    /// up to [`LEAD_M`]). Targets
    /// stop at the end and at a pending wait's point; when progress comes
    /// within [`WAIT_REACHED_M`] of that point they stay there for the wait's seconds (one call = 1/FPS s)
    /// facing along the segment into it, then progress resumes.
    pub fn control(&mut self, at: &Frame2) -> [f32; CONTROL] {
        if self.holding.is_none() {
            self.s = self.s.max(self.path.project(at.pos, self.s, WINDOW_M));
            if let Some(w) = self.wait_arc() {
                if w - self.s <= WAIT_REACHED_M {
                    let secs = self.path.waits()[self.next_wait].1;
                    self.holding = Some((secs * FPS).round() as usize);
                }
            }
        }
        if let Some(left) = self.holding {
            if left == 0 {
                self.release();
                return self.control(at);
            }
            self.holding = Some(left - 1);
            let (i, _) = self.path.waits()[self.next_wait];
            let p = self.path.points()[i];
            let f = self.path.segment_tangent(i.saturating_sub(1));
            return row(at, |_| (p, f));
        }
        // Targets stop at the next wait's point or the end, facing along
        // the segment into it.
        let path = &self.path;
        let last = path.points().len() - 1;
        let stop = path.waits().get(self.next_wait).map_or(last, |w| w.0);
        let cap = path.arc_at_point(stop);
        let cap_facing = path.segment_tangent(stop.saturating_sub(1));
        let speed = path.speed_at(self.s);
        self.due = (self.due + path.speed_at(self.due) / FPS).min(cap);
        // Behind the path's schedule, the speed asked rises by as many
        // metres a second (at most LEAD_M), so a slow motion is asked to
        // catch up as a faster walk would, its targets evenly spaced.
        let speed = speed + (self.due - self.s).clamp(0.0, LEAD_M);
        row(at, |k| {
            let s = self.s + speed * k as f64 / FPS;
            if s >= cap {
                (path.points()[stop], cap_facing)
            } else {
                (path.point_at(s), path.tangent_at(s))
            }
        })
    }

    /// Ends the wait being held: progress moves on to its point.
    fn release(&mut self) {
        if let Some(w) = self.wait_arc() {
            self.s = self.s.max(w);
            self.due = self.due.max(w);
        }
        self.holding = None;
        self.next_wait += 1;
    }
}

/// A control row from the target (point, facing) at each offset, in `at`'s
/// axes, flagged as given.
pub(crate) fn row(at: &Frame2, target: impl Fn(usize) -> ([f64; 2], [f64; 2])) -> [f32; CONTROL] {
    let mut out = [0f32; CONTROL];
    for (i, &k) in CONTROL_FRAMES.iter().enumerate() {
        let (p, f) = target(k);
        let (p, f) = (at.local_point(p), at.local_dir(f));
        out[4 * i..4 * i + 4].copy_from_slice(&[p[0], p[1], f[0], f[1]].map(|v| v as f32));
    }
    out[CONTROL - 1] = 1.0;
    out
}
