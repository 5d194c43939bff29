//! The stick: keys held (turn, run, stop, go) turned into control rows,
//! frame by frame, as a game pad steers a character.

use crate::follow::row;
use crate::{Frame2, CONTROL, FPS};

/// The most the targets move ahead of a root behind the asked speed
/// (metres). The path follower asks a faster walk instead
/// ([`crate::follow::LEAD_M`]); live, that kept the default walking after
/// Space (`docs/experiments.md`).
pub const LEAD_M: f64 = 0.5;

/// Frames a stop lets the character settle, the targets on the root
/// itself, before they stay where it settled ([`Stick::control`]).
pub const SETTLE_FRAMES: usize = 30;

/// How fast a held turn key turns the asked heading, degrees per second.
pub const TURN_DEG_PER_S: f64 = 90.0;

/// The keys held at one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Keys {
    /// −1 turn left, +1 turn right, 0 neither.
    pub turn: f64,
    /// Move (forward held): walk, or run with `run`.
    pub go: bool,
    /// Run instead of walk.
    pub run: bool,
    /// Stop and stand (until `go`).
    pub stop: bool,
}

/// Asked heading and speed, kept between frames: the character walks
/// until told to stop, turns while a turn key is held, runs while `run` is
/// held.
#[derive(Clone, Debug)]
pub struct Stick {
    /// The asked heading, a unit vector in the start frame.
    heading: [f64; 2],
    moving: bool,
    /// Walking and running speeds, metres per second.
    speeds: [f64; 2],
    speed: f64,
    /// Where the root was at the last call.
    last: Option<[f64; 2]>,
    /// How far the root is behind the asked speed along the heading
    /// (metres, at most [`LEAD_M`]).
    behind: f64,
    /// Frames since the stop, and where the root was when it had settled.
    stopped: usize,
    anchor: Option<[f64; 2]>,
}

impl Stick {
    /// A stick asking to walk straight ahead of `at` at `walk` m/s (`run`
    /// m/s when running).
    pub fn new(at: &Frame2, walk: f64, run: f64) -> Stick {
        Stick {
            heading: at.forward,
            moving: true,
            speeds: [walk, run],
            speed: walk,
            last: None,
            behind: 0.0,
            stopped: 0,
            anchor: None,
        }
    }

    /// The asked heading (unit vector, start frame).
    pub fn heading(&self) -> [f64; 2] {
        self.heading
    }

    /// The asked speed, metres per second (0 when stopped).
    pub fn speed(&self) -> f64 {
        self.speed
    }

    /// The control row for the frame where the root is at `at`, after the
    /// keys held there: the targets k frames ahead lie on the straight line
    /// from the root along the asked heading at the asked speed, facing the
    /// asked heading (on stopping, the character's own facing); a root
    /// slower than asked is led up to [`LEAD_M`] further on. Stopped, the
    /// targets lie on the root itself for [`SETTLE_FRAMES`], then stay
    /// where it was then, so a root that drifts is asked back.
    pub fn control(&mut self, at: &Frame2, keys: Keys) -> [f32; CONTROL] {
        if keys.stop {
            // Stopping stands facing where the character faces: a turn
            // asked while moving is not finished on the spot.
            if self.moving {
                self.heading = at.forward;
            }
            self.moving = false;
        } else if keys.go {
            self.moving = true;
        }
        match self.moving {
            true => (self.stopped, self.anchor) = (0, None),
            false => {
                self.stopped = self.stopped.saturating_add(1);
                if self.stopped == SETTLE_FRAMES {
                    self.anchor = Some(at.pos);
                }
            }
        }
        let a = (keys.turn.clamp(-1.0, 1.0) * TURN_DEG_PER_S / FPS).to_radians();
        let (s, c) = a.sin_cos();
        // Positive turns right: the forward axis moves towards the right
        // axis, as `Frame2::advanced` turns for a positive angle.
        let [hx, hz] = self.heading;
        let right = [hz, -hx];
        let h = [c * hx + s * right[0], c * hz + s * right[1]];
        let n = h[0].hypot(h[1]);
        self.heading = [h[0] / n, h[1] / n];
        self.speed = match (self.moving, keys.run) {
            (false, _) => 0.0,
            (true, false) => self.speeds[0],
            (true, true) => self.speeds[1],
        };
        let (p, d, v) = (at.pos, self.heading, self.speed);
        // Behind the asked speed, the targets move ahead by as much (at
        // most LEAD_M).
        let moved = self
            .last
            .map_or(v / FPS, |l| (p[0] - l[0]) * d[0] + (p[1] - l[1]) * d[1]);
        self.behind = match v > 0.0 {
            true => (self.behind + v / FPS - moved).clamp(0.0, LEAD_M),
            false => 0.0,
        };
        self.last = Some(p);
        let (lead, p) = (self.behind, self.anchor.unwrap_or(p));
        row(at, |k| {
            let ahead = lead + v * k as f64 / FPS;
            ([p[0] + d[0] * ahead, p[1] + d[1] * ahead], d)
        })
    }
}
