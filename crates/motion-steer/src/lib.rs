//! Where the character is asked to go: paths, the control signal a model is
//! trained and steered with, and the steering measures.
//!
//! All geometry is planar, in metres, in the character's start frame: `x` to
//! the character's right, `z` forward; the character starts at (0, 0) facing
//! +z.
//!
//! - [`control`]: the root's track and the control rows of a recorded motion
//!   (from its `vel_x`, `vel_z`, `ang_vel_y` features);
//! - [`path`]: asked paths (built-ins and CSV files) and their geometry;
//! - [`follow`]: a [`Follower`] turning a path into control rows, frame by
//!   frame, during generation;
//! - [`stick`]: a [`Stick`] turning keys held (turn, run, stop) into control
//!   rows, frame by frame, for live play;
//! - [`measure`]: how well a generated root followed what was asked.

pub mod control;
pub mod follow;
pub mod measure;
pub mod path;
pub mod stick;

pub use control::{asked_root_motion, control_of_motion, root_track};
pub use follow::Follower;
pub use measure::{path_error, reach_seconds, turn_seconds};
pub use path::{parse_path, Path, PathError};
pub use stick::{Keys, Stick};

/// Metres per dataset length unit (CMU units; `docs/features.md`).
pub const METRES_PER_UNIT: f64 = 0.0564;

/// Frames per second of every motion.
pub const FPS: f64 = 30.0;

/// The frame offsets ahead that a control row describes.
pub const CONTROL_FRAMES: [usize; 3] = [10, 20, 30];

/// Values per control row: for each offset in [`CONTROL_FRAMES`], position
/// (x, z) in metres and facing (x, z) as a unit vector, in the current
/// frame's character axes; then 1.0 where the row is given, 0.0 where it is
/// left free (then all values are zero).
pub const CONTROL: usize = 4 * CONTROL_FRAMES.len() + 1;

/// The root on the floor at one frame, in the start frame: position in metres
/// and the character's right and forward unit axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame2 {
    /// Position (x, z) in metres.
    pub pos: [f64; 2],
    /// The character's right axis (local x) as a unit vector.
    pub right: [f64; 2],
    /// The character's facing (local z) as a unit vector.
    pub forward: [f64; 2],
}

impl Frame2 {
    /// The start frame: at the origin, right = +x, forward = +z.
    pub const START: Frame2 = Frame2 {
        pos: [0.0, 0.0],
        right: [1.0, 0.0],
        forward: [0.0, 1.0],
    };

    /// A point of the start frame in this frame's axes (x right, z forward),
    /// relative to its position.
    pub fn local_point(&self, p: [f64; 2]) -> [f64; 2] {
        self.local_dir([p[0] - self.pos[0], p[1] - self.pos[1]])
    }

    /// A direction of the start frame in this frame's axes.
    pub fn local_dir(&self, d: [f64; 2]) -> [f64; 2] {
        [dot(d, self.right), dot(d, self.forward)]
    }
}

/// Signed angle in degrees from direction `a` to direction `b`, in
/// (-180, 180]: positive when `b` is to the right of `a` (clockwise seen from
/// above, like the dataset's `ang_vel_y`). NaN when either is zero.
pub fn heading_deg(a: [f64; 2], b: [f64; 2]) -> f64 {
    if a == [0.0, 0.0] || b == [0.0, 0.0] {
        return f64::NAN;
    }
    let cross = a[1] * b[0] - a[0] * b[1];
    cross.atan2(dot(a, b)).to_degrees()
}

pub(crate) fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

pub(crate) fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[cfg(test)]
mod tests;
