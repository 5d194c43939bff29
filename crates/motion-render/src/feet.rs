//! Planted toes pinned in place, the legs bent to reach them: the foot
//! clean-up an animator does to captured or generated motion.
//!
//! A toe is planted on a frame where it is below [`Planted::contact_m`] and
//! has moved at most [`Planted::slide_m_s`] horizontally since the frame
//! before (`motion-eval` passes the thresholds of `motion-metrics`, 5 cm and
//! 0.5 m/s: the foot-frames it counts as creeping, `docs/metrics.md`). Over each run of
//! planted frames the toe is held at the horizontal place it had (as shown)
//! when the run began, or dragged along at [`MAX_SHIFT_M`] from its decoded
//! place once that is farther; its height is left as it is. The foot moves rigidly
//! with the toe, and the knee is found by two-bone IK from the hip, in the
//! plane the decoded knee bends in, so every bone keeps its length. After a
//! run the shift fades out over [`FADE_FRAMES`] frames, so the foot does
//! not jump when it lifts. Nothing else of the pose changes: the hips, the
//! root motion and the upper body are the motion's own.

use crate::{FPS, METRES_PER_UNIT};
use mocap_ingest::math::{add, dot, norm, scale, sub, Vec3};
use mocap_ingest::skeleton::{
    Pose, LEFT_FOOT, LEFT_LEG, LEFT_TOE, LEFT_UP_LEG, RIGHT_FOOT, RIGHT_LEG, RIGHT_TOE,
    RIGHT_UP_LEG,
};

/// When a toe is planted.
#[derive(Clone, Copy, Debug)]
pub struct Planted {
    /// Toe height under which a foot may be planted (metres).
    pub contact_m: f64,
    /// Horizontal toe speed above which a foot slides rather than stands (m/s).
    pub slide_m_s: f64,
}

/// Frames over which a planted foot's shift fades out once it lifts.
pub const FADE_FRAMES: usize = 4;

/// Farthest a toe is held from where it was decoded (metres): a foot that
/// slides further while planted is dragged along at this distance, so the
/// leg is not stretched after a figure that glides.
pub const MAX_SHIFT_M: f64 = 0.1;

/// Each leg's hip, knee, ankle and toe (indices into the pose).
const LEGS: [[usize; 4]; 2] = [
    [LEFT_UP_LEG, LEFT_LEG, LEFT_FOOT, LEFT_TOE],
    [RIGHT_UP_LEG, RIGHT_LEG, RIGHT_FOOT, RIGHT_TOE],
];

/// What [`pin_feet`] did to one motion.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pinned {
    /// Foot-frames held in place.
    pub planted: usize,
    /// Of those, frames where the leg could not reach the held toe (it is
    /// stretched straight toward it instead).
    pub out_of_reach: usize,
    /// Largest horizontal shift of a toe (CMU units).
    pub max_shift: f64,
}

impl std::ops::AddAssign for Pinned {
    fn add_assign(&mut self, o: Self) {
        self.planted += o.planted;
        self.out_of_reach += o.out_of_reach;
        self.max_shift = self.max_shift.max(o.max_shift);
    }
}

/// Pins each toe of `poses` (CMU units, 30 fps) in place where it is
/// `planted` (see the module docs).
pub fn pin_feet(poses: &mut [Pose], planted: &Planted) -> Pinned {
    let mut done = Pinned::default();
    let contact = planted.contact_m / METRES_PER_UNIT;
    let slide = planted.slide_m_s / METRES_PER_UNIT / FPS;
    let max_shift = MAX_SHIFT_M / METRES_PER_UNIT;
    for leg in LEGS {
        let toe = leg[3];
        // The toe's horizontal place when its run began, and the shift of
        // the last planted frame with the frames since it (for the fade).
        let (mut anchor, mut carry, mut since): (Option<[f64; 2]>, [f64; 2], usize) =
            (None, [0.0; 2], 0);
        let mut prev = poses.first().map(|p| p[toe]);
        for pose in poses.iter_mut() {
            let t = pose[toe];
            let moved = prev.map_or(0.0, |p| (t[0] - p[0]).hypot(t[2] - p[2]));
            prev = Some(t);
            let planted = t[1] < contact && moved <= slide;
            if !planted && anchor.take().is_some() {
                since = 0;
            }
            if anchor.is_none() {
                since += 1;
            }
            // The last run's shift, faded by the frames since it ended.
            let left = 1.0 - since.min(FADE_FRAMES + 1) as f64 / (FADE_FRAMES + 1) as f64;
            let faded = [carry[0] * left, carry[1] * left];
            let shift = match (planted, anchor) {
                (true, Some(a)) => {
                    let s = [a[0] - t[0], a[1] - t[2]];
                    let k = (max_shift / s[0].hypot(s[1])).min(1.0);
                    anchor = Some([t[0] + s[0] * k, t[2] + s[1] * k]);
                    [s[0] * k, s[1] * k]
                }
                (true, None) => {
                    anchor = Some([t[0] + faded[0], t[2] + faded[1]]);
                    faded
                }
                (false, _) => faded,
            };
            if planted {
                carry = shift;
                done.planted += 1;
            }
            done.max_shift = done.max_shift.max(shift[0].hypot(shift[1]));
            if shift != [0.0; 2] && !reach(pose, leg, [shift[0], 0.0, shift[1]]) {
                done.out_of_reach += 1;
            }
        }
    }
    done
}

/// Moves the leg's ankle and toe by `shift` and bends the knee so that the
/// thigh and shin keep their lengths. Returns false when the ankle is out
/// of reach (then it is placed as near as the straightened leg gets).
fn reach(pose: &mut Pose, [hip, knee, ankle, toe]: [usize; 4], shift: Vec3) -> bool {
    let (h, k, a) = (pose[hip], pose[knee], pose[ankle]);
    let foot = sub(pose[toe], a);
    let (l1, l2) = (norm(sub(k, h)), norm(sub(a, k)));
    let (k2, a2, ok) = two_bone(h, k, add(a, shift), l1, l2);
    pose[knee] = k2;
    pose[ankle] = a2;
    pose[toe] = add(a2, foot);
    ok
}

/// Two-bone IK: the knee and ankle for a hip `h`, a target ankle `target`,
/// bone lengths `l1` (thigh) and `l2` (shin), the knee bending toward where
/// `k` is. The ankle is the target when it is within reach (the flag true),
/// else the nearest point the leg reaches.
pub fn two_bone(h: Vec3, k: Vec3, target: Vec3, l1: f64, l2: f64) -> (Vec3, Vec3, bool) {
    let to = sub(target, h);
    let d0 = norm(to);
    let (lo, hi) = ((l1 - l2).abs() * (1.0 + 1e-9), (l1 + l2) * (1.0 - 1e-9));
    let d = d0.max(lo).min(hi);
    let u = if d0 > 1e-12 {
        scale(to, 1.0 / d0)
    } else {
        [0.0, -1.0, 0.0]
    };
    // The bend direction: the decoded knee's offset from the hip-ankle line,
    // or any direction square to it when the leg was straight.
    let kh = sub(k, h);
    let mut p = sub(kh, scale(u, dot(kh, u)));
    if norm(p) < 1e-9 * l1.max(1e-12) {
        p = if u[2].abs() < 0.9 {
            [0.0, 0.0, 1.0]
        } else {
            [1.0, 0.0, 0.0]
        };
        p = sub(p, scale(u, dot(p, u)));
    }
    let v = scale(p, 1.0 / norm(p));
    let cos = match l1 * d > 0.0 {
        true => ((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d)).clamp(-1.0, 1.0),
        false => 1.0,
    };
    let sin = (1.0 - cos * cos).sqrt();
    let knee = add(h, add(scale(u, l1 * cos), scale(v, l1 * sin)));
    (knee, add(h, scale(u, d)), d == d0)
}

#[cfg(test)]
mod tests {
    use super::*;

    const PLANTED: Planted = Planted {
        contact_m: 0.05,
        slide_m_s: 0.5,
    };

    fn close(a: Vec3, b: Vec3) -> bool {
        norm(sub(a, b)) < 1e-12
    }

    #[test]
    fn two_bone_by_hand() {
        // Hip 2 above the ankle, knee halfway: the ankle asked 1 forward and
        // 1 up is √2 from the hip, so the knee bends 45° off the hip-ankle
        // line and lands where it was, (0, 1, 0).
        let (k, a, ok) = two_bone([0.0, 2.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 1.0], 1.0, 1.0);
        assert!(ok && close(k, [0.0, 1.0, 0.0]) && close(a, [0.0, 1.0, 1.0]));
        // Out of reach: straight toward the target, the lengths kept.
        let (k, a, ok) = two_bone([0.0, 2.0, 0.0], [0.0, 1.0, 0.1], [0.0, -5.0, 0.0], 1.0, 1.0);
        assert!(!ok);
        assert!((norm(sub(k, [0.0, 2.0, 0.0])) - 1.0).abs() < 1e-9);
        assert!((norm(sub(a, k)) - 1.0).abs() < 1e-9);
        assert!(a[1] < 0.0 + 1e-6 && a[1] > -1e-6 && k[1] > 0.99);
    }

    /// A figure standing still but for its left toe, which creeps 0.1 unit
    /// (0.17 m/s) a frame along x on the floor for `creep` frames, then
    /// lifts 2 units for the rest.
    fn creeping(frames: usize, creep: usize) -> Vec<Pose> {
        (0..frames)
            .map(|t| {
                let mut p: Pose = [[0.0; 3]; 19];
                let (x, y) = if t < creep {
                    (0.1 * t as f64, 0.0)
                } else {
                    (0.1 * creep as f64, 2.0)
                };
                // Left leg: hip (1, 10, 0), knee (1, 5, 1), ankle and toe.
                p[1] = [1.0, 10.0, 0.0];
                p[2] = [1.0, 5.0, 1.0];
                p[3] = [1.0 + x, 1.0 + y, 0.0];
                p[4] = [1.0 + x, y, 2.0];
                // Right leg still, its toe planted.
                p[5] = [-1.0, 10.0, 0.0];
                p[6] = [-1.0, 5.0, 1.0];
                p[7] = [-1.0, 1.0, 0.0];
                p[8] = [-1.0, 0.0, 2.0];
                p
            })
            .collect()
    }

    fn lengths(p: &Pose) -> [f64; 6] {
        let l = |a: usize, b: usize| norm(sub(p[a], p[b]));
        [l(1, 2), l(2, 3), l(3, 4), l(5, 6), l(6, 7), l(7, 8)]
    }

    #[test]
    fn a_creeping_toe_is_held_and_the_bones_keep_their_lengths() {
        let before = creeping(16, 8);
        let mut after = before.clone();
        let done = pin_feet(&mut after, &PLANTED);
        // 8 planted left foot-frames, 16 right ones.
        assert_eq!((done.planted, done.out_of_reach), (24, 0));
        assert!((done.max_shift - 0.7).abs() < 1e-12);
        for (b, a) in before.iter().zip(&after) {
            for (x, y) in lengths(b).iter().zip(lengths(a)) {
                assert!((x - y).abs() < 1e-9, "{x} {y}");
            }
            assert_eq!(a[1], b[1]);
        }
        // Held where it stood at frame 0 while planted.
        for a in &after[..8] {
            assert!(close(a[4], [1.0, 0.0, 2.0]), "{:?}", a[4]);
        }
        // Lifted: the 0.7 shift of the last planted frame fades over 4
        // frames (4/5, 3/5, … of it), then the toe is where it was decoded.
        for (k, a) in after[8..14].iter().enumerate() {
            let want = 1.8 - 0.7 * (1.0 - ((k + 1).min(5) as f64) / 5.0);
            assert!(
                (a[4][0] - want).abs() < 1e-9,
                "frame {}: {}",
                k + 8,
                a[4][0]
            );
        }
        // The right leg, already still, is untouched.
        for (b, a) in before.iter().zip(&after) {
            assert_eq!(&a[5..9], &b[5..9]);
        }
    }

    #[test]
    fn a_toe_that_glides_is_dragged_at_the_largest_shift() {
        // 0.25 unit a frame (0.42 m/s, still planted) for 20 frames: 4.75
        // units in all, more than the 0.1 m (1.773 units) a toe is held.
        let mut m = creeping(20, 20);
        for (t, p) in m.iter_mut().enumerate() {
            p[3][0] = 1.0 + 0.25 * t as f64;
            p[4][0] = 1.0 + 0.25 * t as f64;
        }
        let before = m.clone();
        let done = pin_feet(&mut m, &PLANTED);
        let cap = MAX_SHIFT_M / METRES_PER_UNIT;
        assert!((done.max_shift - cap).abs() < 1e-9, "{}", done.max_shift);
        let last = m[19][4][0] - before[19][4][0];
        assert!((last + cap).abs() < 1e-9, "{last}");
        for (b, a) in before.iter().zip(&m) {
            for (x, y) in lengths(b).iter().zip(lengths(a)) {
                assert!((x - y).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn feet_in_the_air_are_left_alone_and_nothing_is_not_a_number() {
        let mut m = creeping(6, 0);
        for p in m.iter_mut() {
            p[8][1] = 3.0;
        }
        let before = m.clone();
        assert_eq!(pin_feet(&mut m, &PLANTED), Pinned::default());
        assert_eq!(m, before);
        // A toe planted on a leg of zero length, and an empty motion.
        let mut odd = vec![[[0.0; 3]; 19]; 3];
        odd[2][4] = [0.01, 0.0, 0.0];
        pin_feet(&mut odd, &PLANTED);
        assert!(odd.iter().flatten().flatten().all(|v| v.is_finite()));
        assert_eq!(pin_feet(&mut [], &PLANTED), Pinned::default());
    }
}
