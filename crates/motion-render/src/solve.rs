//! Joint rotations from joint positions: the pose solver behind BVH export.
//!
//! The exported skeleton is CMU's Motionbuilder-friendly one without fingers
//! ([`SKELETON`]): the 19 kept joints plus six helper joints that CMU's files
//! also have (`LHipJoint`, `RHipJoint`, `LowerBack`, `Neck`, `LeftShoulder`,
//! `RightShoulder`), each at its parent's position. With the helpers, every
//! one of the 18 bones between kept joints belongs to a joint with exactly one
//! child, so its direction can be matched exactly in every frame.
//!
//! Rest pose (all rotations zero): y up, the first frame facing +z. Each
//! bone has the motion's mean length. Its rest direction, relative to its
//! parent, is the bone's mean direction over the motion, except the upper
//! arms, which rest sideways (T-pose); the spine above the pelvis and the
//! chest point up. Each rotation is thus measured from where the bone
//! usually is.
//!
//! Orientation of each joint (global, `G`), frame by frame:
//! - `Hips` (pelvis): aim `Spine − Hips` (+y), twist from the hip line
//!   `LeftUpLeg − RightUpLeg` (+x);
//! - `Spine1` (chest): aim `Neck1 − Spine1`, twist from the shoulder line
//!   `LeftArm − RightArm`;
//! - `Spine`: aim `Spine1 − Spine`, twist from the sum of the unit hip and
//!   shoulder lines (half the torso's twist on each side of it);
//! - every other joint with a child: the shortest rotation, relative to its
//!   parent, from its rest bone direction onto the observed one (no twist of
//!   its own: joint positions carry no information about a limb's twist);
//! - end joints (`Head`, hands, toes): no rotation relative to the parent.
//!
//! Local rotations are `G_parentᵀ · G`. Euler angles: the root's channels are
//! `Z Y X` (CMU's order); every other joint gets, of the six orders, the one
//! whose middle angle stays furthest from ±90° (gimbal lock) over the motion.
//! Angles are unwrapped frame to frame, so channels never jump by 360° or
//! switch between the two equivalent solutions.
//!
//! Exactness: every bone points exactly along the observed bone, so a motion
//! whose bone lengths are constant (real motion) is reproduced exactly (to
//! the written decimals). When bone lengths vary (generated motion), the only
//! error is the difference between each bone's length at a frame and its
//! mean, accumulated from the root along the chain ([`with_mean_bone_lengths`]
//! computes exactly that prediction). Continuity: the shortest rotation is
//! singular only when a bone points opposite its rest direction relative to
//! its parent (opposite its mean: a knee bent backwards; for an upper arm,
//! across the chest to the other side), so rotations follow the bones
//! smoothly; the root's `Z Y X` channels turn fast when the body faces ±x
//! while leaning (gimbal lock of the mandated order).

use crate::{Motion, RenderError};
use mocap_ingest::math::{add, cross, dot, norm, scale, sub, Axis, Mat3, Vec3};
use mocap_ingest::skeleton::{Pose, JOINT_PARENTS, NUM_JOINTS};

/// The vector that fixes a joint's twist (its +x axis, made orthogonal to
/// the aim).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Side {
    /// From kept joint `.1` to kept joint `.0`.
    Line(usize, usize),
    /// The sum of the unit hip line and the unit shoulder line.
    Blend,
}

/// How a joint of the exported skeleton gets its orientation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Orient {
    /// The frame whose +y points from kept joint `from` to kept joint `to`,
    /// twisted by `side`, relative to the same frame in the rest pose.
    Aim {
        /// Kept joint the aim starts at.
        from: usize,
        /// Kept joint the aim points to.
        to: usize,
        /// What fixes the twist.
        side: Side,
    },
    /// Shortest rotation relative to the parent onto the bone to its one child.
    Swing,
    /// No rotation relative to the parent (end joints).
    Fixed,
}

/// One joint of the exported BVH skeleton.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BvhJoint {
    /// Motionbuilder name.
    pub name: &'static str,
    /// Parent in [`SKELETON`] (`None` for the root).
    pub parent: Option<usize>,
    /// The kept joint (index into `JOINT_NAMES`) at whose position it sits.
    pub at: usize,
    /// Whether it is one of the 19 kept joints (false: a helper at its
    /// parent's position).
    pub kept: bool,
    /// How its orientation is solved.
    pub orient: Orient,
}

const fn j(name: &'static str, parent: usize, at: usize, kept: bool, orient: Orient) -> BvhJoint {
    BvhJoint {
        name,
        parent: Some(parent),
        at,
        kept,
        orient,
    }
}

use Orient::{Fixed, Swing};

const fn aim(from: usize, to: usize, side: Side) -> Orient {
    Orient::Aim { from, to, side }
}

/// The exported skeleton, parents before children (depth-first, the order
/// of the BVH hierarchy and of the channels).
pub const SKELETON: [BvhJoint; 25] = [
    BvhJoint {
        name: "Hips",
        parent: None,
        at: 0,
        kept: true,
        orient: aim(0, 9, Side::Line(1, 5)),
    },
    j("LHipJoint", 0, 0, false, Swing),
    j("LeftUpLeg", 1, 1, true, Swing),
    j("LeftLeg", 2, 2, true, Swing),
    j("LeftFoot", 3, 3, true, Swing),
    j("LeftToeBase", 4, 4, true, Fixed),
    j("RHipJoint", 0, 0, false, Swing),
    j("RightUpLeg", 6, 5, true, Swing),
    j("RightLeg", 7, 6, true, Swing),
    j("RightFoot", 8, 7, true, Swing),
    j("RightToeBase", 9, 8, true, Fixed),
    j("LowerBack", 0, 0, false, Swing),
    j("Spine", 11, 9, true, aim(9, 10, Side::Blend)),
    j("Spine1", 12, 10, true, aim(10, 11, Side::Line(13, 16))),
    j("Neck", 13, 10, false, Swing),
    j("Neck1", 14, 11, true, Swing),
    j("Head", 15, 12, true, Fixed),
    j("LeftShoulder", 13, 10, false, Swing),
    j("LeftArm", 17, 13, true, Swing),
    j("LeftForeArm", 18, 14, true, Swing),
    j("LeftHand", 19, 15, true, Fixed),
    j("RightShoulder", 13, 10, false, Swing),
    j("RightArm", 21, 16, true, Swing),
    j("RightForeArm", 22, 17, true, Swing),
    j("RightHand", 23, 18, true, Fixed),
];

/// Number of joints of the exported skeleton.
pub const NUM_BVH_JOINTS: usize = SKELETON.len();

/// The one child of each joint in [`SKELETON`], if it has exactly one.
fn only_child(b: usize) -> Option<usize> {
    let mut kids = (0..NUM_BVH_JOINTS).filter(|&c| SKELETON[c].parent == Some(b));
    match (kids.next(), kids.next()) {
        (Some(c), None) => Some(c),
        _ => None,
    }
}

/// The rest pose: each joint's offset from its parent (the root's is zero),
/// and the end-site offset of each end joint.
#[derive(Clone, Debug, PartialEq)]
pub struct Rest {
    /// Offset of each joint of [`SKELETON`] from its parent, in the parent's
    /// rest frame (the global frame: rest rotations are all zero).
    pub offsets: [Vec3; NUM_BVH_JOINTS],
    /// `End Site` offset of each end joint (zero for others): half the
    /// joint's own bone, along its rest direction (cosmetic).
    pub end_sites: [Vec3; NUM_BVH_JOINTS],
}

/// Solved joint rotations: per frame, the local rotation of every joint of
/// [`SKELETON`] (the root's is global), and the root position.
#[derive(Clone, Debug)]
pub struct Solved {
    /// The rest pose.
    pub rest: Rest,
    /// Hips position per frame.
    pub root: Vec<Vec3>,
    /// Local rotations per frame, one per joint of [`SKELETON`].
    pub local: Vec<[Mat3; NUM_BVH_JOINTS]>,
    /// The rotation channels' order of each joint (listed, outermost first).
    pub orders: [[Axis; 3]; NUM_BVH_JOINTS],
}

fn unit(v: Vec3) -> Option<Vec3> {
    let n = norm(v);
    (n.is_finite() && n > 1e-12).then(|| scale(v, 1.0 / n))
}

/// Rotation with columns `x`, `y`, `z` (maps the unit axes onto them).
fn from_columns(x: Vec3, y: Vec3, z: Vec3) -> Mat3 {
    Mat3([[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]])
}

/// The frame with +y along `aim` and +x along `side` made orthogonal to it.
fn aim_frame(aim: Vec3, side: Vec3) -> Option<Mat3> {
    let y = unit(aim)?;
    let x = unit(sub(side, scale(y, dot(side, y))))?;
    Some(from_columns(x, y, cross(x, y)))
}

/// Rotation by `angle` radians about the unit `axis` (Rodrigues).
fn axis_angle(axis: Vec3, angle: f64) -> Mat3 {
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    let [x, y, z] = axis;
    Mat3([
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ])
}

/// The shortest rotation turning unit `a` onto unit `b`. For opposite
/// vectors (no shortest rotation) it turns by 180° about an axis
/// perpendicular to `a`, chosen from `a` alone.
pub fn swing(a: Vec3, b: Vec3) -> Mat3 {
    let axis = cross(a, b);
    let s = norm(axis);
    let c = dot(a, b);
    if s > 1e-12 {
        return axis_angle(scale(axis, 1.0 / s), s.atan2(c));
    }
    if c > 0.0 {
        return Mat3::IDENTITY;
    }
    // Perpendicular to a: cross with the unit axis a is least aligned with.
    let k = (0..3)
        .min_by(|&i, &j| a[i].abs().total_cmp(&a[j].abs()))
        .unwrap_or(0);
    let mut e = [0.0; 3];
    e[k] = 1.0;
    let p = unit(cross(a, e)).unwrap_or([1.0, 0.0, 0.0]);
    axis_angle(p, std::f64::consts::PI)
}

/// The observed vector from a joint to its one child.
fn bone(pose: &Pose, b: usize) -> Option<Vec3> {
    only_child(b).map(|c| sub(pose[SKELETON[c].at], pose[SKELETON[b].at]))
}

/// The observed frame of an [`Orient::Aim`] joint.
fn aim_orient(pose: &Pose, o: Orient) -> Option<Mat3> {
    let Orient::Aim { from, to, side } = o else {
        return None;
    };
    let side = match side {
        Side::Line(a, b) => sub(pose[a], pose[b]),
        Side::Blend => add(unit(sub(pose[1], pose[5]))?, unit(sub(pose[13], pose[16]))?),
    };
    aim_frame(sub(pose[to], pose[from]), side)
}

/// Canonical rest direction of a bone that is not out of the pelvis or the
/// chest: spine, neck and head up, legs down, feet forward, arms sideways.
fn canonical_direction(child_kept: usize) -> Vec3 {
    match child_kept {
        2 | 3 | 6 | 7 => [0.0, -1.0, 0.0],
        4 | 8 => [0.0, 0.0, 1.0],
        14 | 15 => [1.0, 0.0, 0.0],
        17 | 18 => [-1.0, 0.0, 0.0],
        _ => [0.0, 1.0, 0.0],
    }
}

/// Mean length of each bone (kept joint to its kept parent) over the motion.
pub fn mean_bone_lengths(poses: &[Pose]) -> [f64; NUM_JOINTS] {
    let mut len = [0.0; NUM_JOINTS];
    for pose in poses {
        for (j, p) in JOINT_PARENTS.iter().enumerate() {
            if let Some(p) = p {
                len[j] += norm(sub(pose[j], pose[*p]));
            }
        }
    }
    len.map(|l| l / poses.len().max(1) as f64)
}

/// The motion with every bone at its mean length and its observed direction,
/// rebuilt from the root: what a rigid skeleton can reproduce at best. The
/// distance of these positions from the observed ones is the part of the BVH
/// round-trip error due to bone-length variation.
pub fn with_mean_bone_lengths(poses: &[Pose]) -> Vec<Pose> {
    let len = mean_bone_lengths(poses);
    poses
        .iter()
        .map(|pose| {
            let mut out = *pose;
            for (j, p) in JOINT_PARENTS.iter().enumerate() {
                if let Some(p) = *p {
                    let d = unit(sub(pose[j], pose[p])).unwrap_or([0.0; 3]);
                    out[j] = add(out[p], scale(d, len[j]));
                }
            }
            out
        })
        .collect()
}

/// Solve the rotations of every joint of [`SKELETON`] at every frame of `m`.
pub fn solve(m: &Motion) -> Result<Solved, RenderError> {
    let err = |message: String| RenderError::Motion {
        id: m.id.clone(),
        message,
    };
    if m.poses.is_empty() {
        return Err(err("no frames".into()));
    }
    for (f, pose) in m.poses.iter().enumerate() {
        if pose.iter().flatten().any(|v| !v.is_finite()) {
            return Err(err(format!("non-finite joint position at frame {f}")));
        }
    }
    let len = mean_bone_lengths(&m.poses);
    for joint in SKELETON.iter().filter(|j| j.kept && j.parent.is_some()) {
        let l = len[joint.at];
        if !(l.is_finite() && l > 1e-9) {
            return Err(err(format!("bone {} has no length (mean {l})", joint.name)));
        }
    }
    let n = m.poses.len();
    let mut offsets = [[0.0; 3]; NUM_BVH_JOINTS];
    let mut g = vec![[Mat3::IDENTITY; NUM_BVH_JOINTS]; n];
    let mut local = vec![[Mat3::IDENTITY; NUM_BVH_JOINTS]; n];
    // Joint by joint (parents first), every frame: a Swing joint needs its
    // bone's mean direction over the motion in its parent's frame.
    for (b, joint) in SKELETON.iter().enumerate() {
        let parents: Vec<Mat3> = (0..n)
            .map(|t| joint.parent.map_or(Mat3::IDENTITY, |p| g[t][p]))
            .collect();
        let solved: Vec<Option<Mat3>> = match joint.orient {
            Orient::Aim { to, .. } => {
                // The aim is +y: a kept child at the aimed joint lies along it.
                if let Some(c) = (0..NUM_BVH_JOINTS)
                    .find(|&c| SKELETON[c].parent == Some(b) && SKELETON[c].at == to)
                {
                    offsets[c] = [0.0, len[to], 0.0];
                }
                m.poses
                    .iter()
                    .map(|pose| aim_orient(pose, joint.orient))
                    .collect()
            }
            Orient::Swing => {
                let c = only_child(b).unwrap_or(b);
                let dirs: Vec<Option<Vec3>> = (0..n)
                    .map(|t| Some(parents[t].transpose().apply(unit(bone(&m.poses[t], b)?)?)))
                    .collect();
                // Rest direction: for upper arms the T-pose's (sideways: the
                // shortest rotation from it is singular only for an arm
                // pointing across the chest to the other side, whereas arms
                // go both down and overhead); for the other bones the mean
                // direction relative to the parent, so the singular
                // direction is the one opposite where the bone usually is
                // (a knee or elbow bent backwards, a foot pointing back).
                let at = SKELETON[c].at;
                let mean = if matches!(at, 14 | 17) {
                    canonical_direction(at)
                } else {
                    unit(dirs.iter().flatten().fold([0.0; 3], |a, d| add(a, *d)))
                        .unwrap_or_else(|| canonical_direction(at))
                };
                offsets[c] = scale(mean, len[SKELETON[c].at]);
                dirs.iter()
                    .enumerate()
                    .map(|(t, d)| d.map(|d| parents[t].mul(&swing(mean, d))))
                    .collect()
            }
            Orient::Fixed => parents.iter().map(|p| Some(*p)).collect(),
        };
        for t in 0..n {
            // A degenerate frame (zero-length bone, collinear torso) keeps
            // the previous frame's orientation.
            let previous = t.checked_sub(1).map(|p| g[p][b]);
            g[t][b] = solved[t].or(previous).unwrap_or(parents[t]);
            local[t][b] = parents[t].transpose().mul(&g[t][b]);
        }
    }
    let mut end_sites = [[0.0; 3]; NUM_BVH_JOINTS];
    for (c, e) in end_sites.iter_mut().enumerate() {
        if only_child(c).is_none() && (0..NUM_BVH_JOINTS).all(|k| SKELETON[k].parent != Some(c)) {
            *e = scale(offsets[c], 0.5);
        }
    }
    Ok(Solved {
        rest: Rest { offsets, end_sites },
        root: m.poses.iter().map(|p| p[0]).collect(),
        orders: channel_orders(&local),
        local,
    })
}

/// Forward kinematics of solved rotations: the kept joints' positions at
/// `frame` (what a BVH reader computes from the exported file).
pub fn forward(s: &Solved, frame: usize) -> Pose {
    let mut g = [Mat3::IDENTITY; NUM_BVH_JOINTS];
    let mut pos = [[0.0; 3]; NUM_BVH_JOINTS];
    for (b, joint) in SKELETON.iter().enumerate() {
        match joint.parent {
            None => {
                pos[b] = s.root[frame];
                g[b] = s.local[frame][b];
            }
            Some(p) => {
                pos[b] = add(pos[p], g[p].apply(s.rest.offsets[b]));
                g[b] = g[p].mul(&s.local[frame][b]);
            }
        }
    }
    let mut out = [[0.0; 3]; NUM_JOINTS];
    for (b, joint) in SKELETON.iter().enumerate() {
        if joint.kept {
            out[joint.at] = pos[b];
        }
    }
    out
}

/// The six orders a joint's rotation channels may take.
const ORDERS: [[Axis; 3]; 6] = [
    [Axis::Z, Axis::Y, Axis::X],
    [Axis::Z, Axis::X, Axis::Y],
    [Axis::Y, Axis::Z, Axis::X],
    [Axis::X, Axis::Y, Axis::Z],
    [Axis::Y, Axis::X, Axis::Z],
    [Axis::X, Axis::Z, Axis::Y],
];

/// The channel order of each joint: `Z Y X` for the root (CMU's order) and,
/// for every other joint, of the six orders the one whose middle angle
/// stays furthest from ±90° (gimbal lock) over the motion, so the Euler
/// angles stay well-conditioned; ties go to `Z Y X`.
fn channel_orders(local: &[[Mat3; NUM_BVH_JOINTS]]) -> [[Axis; 3]; NUM_BVH_JOINTS] {
    let mut out = [ORDERS[0]; NUM_BVH_JOINTS];
    for (b, o) in out.iter_mut().enumerate().skip(1) {
        let worst = |order: &[Axis; 3]| {
            let [i, _, k] = order.map(axis_index);
            local.iter().map(|l| l[b].0[i][k].abs()).fold(0.0, f64::max)
        };
        let mut best = (f64::INFINITY, ORDERS[0]);
        for order in ORDERS {
            let w = worst(&order);
            if w < best.0 - 1e-9 {
                best = (w, order);
            }
        }
        *o = best.1;
    }
    out
}

fn axis_index(a: Axis) -> usize {
    match a {
        Axis::X => 0,
        Axis::Y => 1,
        Axis::Z => 2,
    }
}

/// Angle of a rotation about axis `i` alone.
fn angle_about(m: &Mat3, i: usize) -> f64 {
    let (p, q) = ((i + 1) % 3, (i + 2) % 3);
    m.0[q][p].atan2(m.0[p][p])
}

/// Euler angles in degrees, in the listed `order` (`R = R(a0)·R(a1)·R(a2)`,
/// the BVH convention, any three distinct axes), chosen of the two
/// equivalent solutions and the multiples of 360° to be closest to `prev`
/// (continuity over time); without `prev`, the one with `|a1| ≤ 90°`.
pub fn euler(r: &Mat3, order: [Axis; 3], prev: Option<[f64; 3]>) -> [f64; 3] {
    let [i, j, k] = order.map(axis_index);
    // +1 for cyclic orders (X Y Z, Y Z X, Z X Y), −1 otherwise.
    let s = if (j + 3 - i) % 3 == 1 { 1.0 } else { -1.0 };
    let m = &r.0;
    let sb = (s * m[i][k]).clamp(-1.0, 1.0);
    let b = sb.asin();
    let cb = (1.0 - sb * sb).max(0.0).sqrt();
    let (a, c) = if cb > 1e-9 {
        ((-s * m[j][k]).atan2(m[k][k]), (-s * m[i][j]).atan2(m[i][i]))
    } else {
        // Gimbal lock: only a combination of a and c is defined; keep the
        // previous c and find a.
        let c = prev.map_or(0.0, |p| p[2].to_radians());
        let inner = Mat3::rotation(order[1], b).mul(&Mat3::rotation(order[2], c));
        (angle_about(&r.mul(&inner.transpose()), i), c)
    };
    let deg = [a.to_degrees(), b.to_degrees(), c.to_degrees()];
    let Some(p) = prev else { return deg };
    let alt = [deg[0] + 180.0, 180.0 - deg[1], deg[2] + 180.0];
    let near = |c: [f64; 3]| [0, 1, 2].map(|k| p[k] + wrap(c[k] - p[k]));
    let dist = |c: &[f64; 3]| (0..3).map(|k| (c[k] - p[k]).abs()).sum::<f64>();
    let (a, b) = (near(deg), near(alt));
    if dist(&b) < dist(&a) {
        b
    } else {
        a
    }
}

/// `d` wrapped into `(−180°, 180°]`.
fn wrap(d: f64) -> f64 {
    let w = d.rem_euclid(360.0);
    if w > 180.0 {
        w - 360.0
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A hand-built T-pose matching the canonical rest directions: facing
    /// +z, left = +x, hips at height 10.
    fn t_pose() -> Pose {
        let mut p = [[0.0; 3]; NUM_JOINTS];
        p[0] = [0.0, 10.0, 0.0];
        p[1] = [1.5, 9.0, 0.5];
        p[2] = [1.5, 5.0, 0.5];
        p[3] = [1.5, 1.0, 0.5];
        p[4] = [1.5, 1.0, 2.5];
        p[5] = [-1.5, 9.0, 0.5];
        p[6] = [-1.5, 5.0, 0.5];
        p[7] = [-1.5, 1.0, 0.5];
        p[8] = [-1.5, 1.0, 2.5];
        p[9] = [0.0, 12.0, 0.0];
        p[10] = [0.0, 14.0, 0.0];
        p[11] = [0.0, 15.5, 0.0];
        p[12] = [0.0, 17.0, 0.0];
        p[13] = [3.0, 15.0, 0.0];
        p[14] = [7.0, 15.0, 0.0];
        p[15] = [10.0, 15.0, 0.0];
        p[16] = [-3.0, 15.0, 0.0];
        p[17] = [-7.0, 15.0, 0.0];
        p[18] = [-10.0, 15.0, 0.0];
        p
    }

    fn index(name: &str) -> usize {
        SKELETON.iter().position(|j| j.name == name).unwrap()
    }

    fn close(a: &Mat3, b: &Mat3) -> bool {
        (0..3).all(|i| (0..3).all(|k| (a.0[i][k] - b.0[i][k]).abs() < 1e-9))
    }

    fn solve_poses(poses: Vec<Pose>) -> Solved {
        solve(&Motion {
            id: "t".into(),
            poses,
        })
        .unwrap()
    }

    fn max_error(s: &Solved, poses: &[Pose]) -> f64 {
        poses
            .iter()
            .enumerate()
            .flat_map(|(f, p)| {
                let q = forward(s, f);
                (0..NUM_JOINTS)
                    .map(move |k| norm(sub(p[k], q[k])))
                    .collect::<Vec<_>>()
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn the_rest_pose_has_no_rotation() {
        let s = solve_poses(vec![t_pose()]);
        for (b, r) in s.local[0].iter().enumerate() {
            assert!(close(r, &Mat3::IDENTITY), "{}", SKELETON[b].name);
        }
        // Offsets: the motion's bone lengths; legs down, arms sideways.
        assert_eq!(s.rest.offsets[index("LeftLeg")], [0.0, -4.0, 0.0]);
        assert_eq!(s.rest.offsets[index("RightForeArm")], [-4.0, 0.0, 0.0]);
        assert!(max_error(&s, &[t_pose()]) < 1e-12);
    }

    #[test]
    fn a_bent_elbow_is_one_rotation_at_the_elbow() {
        // Left forearm bent 90° forward: the hand goes from +x to +z of the elbow.
        let mut bent = t_pose();
        bent[15] = [7.0, 15.0, 3.0];
        let s = solve_poses(vec![t_pose(), bent]);
        let elbow = index("LeftForeArm");
        // From the first frame to the second, only the elbow turns: 90°
        // about −y (the rest pose, the mean of the two, is half bent).
        for (b, joint) in SKELETON.iter().enumerate() {
            let turn = s.local[1][b].mul(&s.local[0][b].transpose());
            let want = if b == elbow {
                Mat3::rotation(Axis::Y, -std::f64::consts::FRAC_PI_2)
            } else {
                Mat3::IDENTITY
            };
            assert!(close(&turn, &want), "{}: {turn:?}", joint.name);
        }
        // The rest forearm points halfway; each frame turns 45° from it.
        let r = 0.5f64.sqrt() * 3.0;
        assert!(norm(sub(s.rest.offsets[index("LeftHand")], [r, 0.0, r])) < 1e-12);
        let order = s.orders[elbow];
        let e = euler(&s.local[1][elbow], order, None);
        assert!(
            (e.iter().map(|v| v.abs()).sum::<f64>() - 45.0).abs() < 1e-9,
            "{e:?}"
        );
        assert!(max_error(&s, &[t_pose(), bent]) < 1e-12);
    }

    #[test]
    fn a_turned_hip_turns_only_the_root() {
        // The whole body turned 30° about y and moved: only the root rotates.
        let r = Mat3::rotation(Axis::Y, 30f64.to_radians());
        let turned = t_pose().map(|p| add(r.apply(p), [5.0, 0.0, -2.0]));
        let s = solve_poses(vec![t_pose(), turned]);
        assert!(close(&s.local[1][0], &r));
        for (b, l) in s.local[1].iter().enumerate().skip(1) {
            assert!(close(l, &Mat3::IDENTITY), "{}", SKELETON[b].name);
        }
        let e = euler(&s.local[1][0], [Axis::Z, Axis::Y, Axis::X], None);
        assert!(e[0].abs() < 1e-9 && (e[1] - 30.0).abs() < 1e-9 && e[2].abs() < 1e-9);
        assert!(max_error(&s, &[t_pose(), turned]) < 1e-12);
        // Twisting the pelvis alone (hips turned, chest facing forward) puts
        // half the twist below the chest, in Spine, and the rest in Spine1.
        let mut twisted = t_pose();
        for k in [1, 2, 3, 4, 5, 6, 7, 8] {
            twisted[k] = add(r.apply(sub(twisted[k], twisted[0])), twisted[0]);
        }
        let s = solve_poses(vec![twisted]);
        let half = Mat3::rotation(Axis::Y, -15f64.to_radians());
        assert!(close(&s.local[0][index("Spine")], &half));
        assert!(close(&s.local[0][index("Spine1")], &half));
        assert!(max_error(&s, &[twisted]) < 1e-12);
    }

    #[test]
    fn euler_angles_invert_every_order_and_stay_continuous() {
        use Axis::{X, Y, Z};
        let orders = [
            [Z, Y, X],
            [Z, X, Y],
            [Y, Z, X],
            [X, Y, Z],
            [Y, X, Z],
            [X, Z, Y],
        ];
        for order in orders {
            // Two full turns about the middle axis through gimbal lock,
            // with a tilt about the first.
            let mut prev = None;
            for k in 0..=72 {
                let a = (k as f64 * 10.0).to_radians();
                let r = Mat3::rotation(order[0], 0.3)
                    .mul(&Mat3::rotation(order[1], a))
                    .mul(&Mat3::rotation(order[2], -0.2));
                let e = euler(&r, order, prev);
                let back = Mat3::euler_listed(&order, &e.map(f64::to_radians));
                assert!(close(&back, &r), "{order:?} {k}: {e:?}");
                if let Some(p) = prev {
                    let step: f64 = (0..3).map(|i| (e[i] - p[i]).abs()).sum();
                    assert!(step < 25.0, "{order:?} jump at {k}: {p:?} -> {e:?}");
                }
                prev = Some(e);
            }
        }
    }

    #[test]
    fn a_bending_knee_is_a_hinge_all_the_way() {
        // Shin and foot turn together about the knee's x axis, 0° to 175°:
        // only the knee rotates, about x, and its channel follows smoothly.
        let knee = index("LeftLeg");
        let poses: Vec<Pose> = (0..=35)
            .map(|k| {
                let r = Mat3::rotation(Axis::X, (k as f64 * 5.0).to_radians());
                let mut p = t_pose();
                for j in [3, 4] {
                    p[j] = add(p[2], r.apply(sub(t_pose()[j], p[2])));
                }
                p
            })
            .collect();
        let s = solve_poses(poses.clone());
        let order = s.orders[knee];
        let mut prev: Option<[f64; 3]> = None;
        for (k, l) in s.local.iter().enumerate() {
            let want = Mat3::rotation(Axis::X, (k as f64 * 5.0).to_radians());
            assert!(
                close(&l[knee].mul(&s.local[0][knee].transpose()), &want),
                "{k}"
            );
            assert!(close(&l[index("LeftFoot")], &Mat3::IDENTITY), "{k}");
            let e = euler(&l[knee], order, prev);
            // One channel moves, by 5° a frame; the others stay at 0.
            if let Some(p) = prev {
                let steps: Vec<f64> = (0..3).map(|i| (e[i] - p[i]).abs()).collect();
                assert!(
                    (steps.iter().sum::<f64>() - 5.0).abs() < 1e-6,
                    "{k}: {steps:?}"
                );
            }
            prev = Some(e);
        }
        assert!(max_error(&s, &poses) < 1e-12);
        // The knee turns about x: x is not the middle axis (gimbal lock).
        assert_ne!(order[1], Axis::X);
        assert_eq!(s.orders[0], [Axis::Z, Axis::Y, Axis::X]);
    }

    #[test]
    fn varying_bones_give_exactly_the_bone_length_error() {
        // A forearm that stretches: the solver keeps its direction, so the
        // round-trip error is the mean-length prediction's.
        let mut long = t_pose();
        long[15] = [11.0, 15.0, 1.0];
        let poses = vec![t_pose(), long];
        let s = solve_poses(poses.clone());
        let rigid = with_mean_bone_lengths(&poses);
        for (f, p) in rigid.iter().enumerate() {
            let q = forward(&s, f);
            for k in 0..NUM_JOINTS {
                assert!(norm(sub(p[k], q[k])) < 1e-9);
            }
        }
        assert!(max_error(&s, &poses) > 0.1);
    }

    #[test]
    fn degenerate_motions_are_errors_not_panics() {
        let empty = Motion {
            id: "e".into(),
            poses: vec![],
        };
        assert!(solve(&empty).is_err());
        let mut nan = t_pose();
        nan[3][1] = f64::NAN;
        let e = solve(&Motion {
            id: "n".into(),
            poses: vec![nan],
        })
        .unwrap_err();
        assert!(e.to_string().contains("frame 0"), "{e}");
        let flat = Motion {
            id: "z".into(),
            poses: vec![[[1.0; 3]; NUM_JOINTS]],
        };
        assert!(solve(&flat).unwrap_err().to_string().contains("no length"));
    }
}
