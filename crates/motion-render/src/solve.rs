//! Joint rotations from joint positions: the pose solver behind BVH export.
//!
//! The exported skeleton is CMU's Motionbuilder-friendly one without fingers
//! ([`SKELETON`]): the 19 kept joints plus six helper joints that CMU's files
//! also have (`LHipJoint`, `RHipJoint`, `LowerBack`, `Neck`, `LeftShoulder`,
//! `RightShoulder`), each at its parent's position. With the helpers, every
//! one of the 18 bones between kept joints belongs to a joint with exactly one
//! child, so its direction can be matched exactly in every frame.
//!
//! Rest pose (all rotations zero): facing +z, y up, left = +x. Bones out of
//! the pelvis and the chest keep their mean direction in the pelvis or chest
//! frame (so the rest pose has the motion's own hips and shoulders); the spine,
//! neck and head point up, legs down, feet forward, arms sideways. Lengths are
//! the motion's mean bone lengths.
//!
//! Orientation of each joint (global, `G`), frame by frame:
//! - `Hips` (pelvis): aim `Spine − Hips` (+y), twist from the hip line
//!   `LeftUpLeg − RightUpLeg` (+x);
//! - `Spine1` (chest): aim `Neck1 − Spine1`, twist from the shoulder line
//!   `LeftArm − RightArm`;
//! - `Spine`: aim `Spine1 − Spine`, twist from the sum of the unit hip and
//!   shoulder lines (half the torso's twist on each side of it);
//! - every other joint with a child: the shortest rotation, relative to its
//!   parent, that turns its rest bone direction onto the observed one (no
//!   twist of its own: positions carry no information about a limb's twist);
//! - end joints (`Head`, hands, toes): no rotation relative to the parent.
//!
//! Local rotations are `G_parentᵀ · G`; Euler angles (`Z Y X` as listed, the
//! BVH convention) are unwrapped frame to frame so channels never jump by
//! 360° or flip between the two equivalent solutions.
//!
//! Exactness: every bone points exactly along the observed bone, so a motion
//! whose bone lengths are constant (real motion) is reproduced exactly (to
//! the written decimals). When bone lengths vary (generated motion), the only
//! error is the difference between each bone's length at a frame and its
//! mean, accumulated from the root along the chain ([`with_mean_bone_lengths`]
//! computes exactly that prediction). The shortest rotation is singular only
//! when a bone points exactly opposite its rest direction relative to its
//! parent (a knee or elbow folded by 180°, a thigh along the spine), which the
//! human body does not reach.

use crate::{Motion, RenderError};
use mocap_ingest::math::{add, cross, dot, norm, scale, sub, Mat3, Vec3};
use mocap_ingest::skeleton::{Pose, JOINT_PARENTS, NUM_JOINTS};

/// How a joint of the exported skeleton gets its orientation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Orient {
    /// Aim (+y) at kept joint `aim` from kept joint `from`; twist (+x) from the
    /// line between kept joints `side.0` and `side.1`.
    Frame {
        /// Kept joint the frame starts at.
        from: usize,
        /// Kept joint the +y axis points to.
        aim: usize,
        /// Kept joints whose difference gives the +x axis.
        side: (usize, usize),
    },
    /// Aim at `Spine1` from `Spine`, twist from the sum of the unit hip and
    /// shoulder lines.
    SpineBlend,
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

/// The exported skeleton, parents before children (depth-first, the order
/// of the BVH hierarchy and of the channels).
pub const SKELETON: [BvhJoint; 25] = [
    BvhJoint {
        name: "Hips",
        parent: None,
        at: 0,
        kept: true,
        orient: Orient::Frame {
            from: 0,
            aim: 9,
            side: (1, 5),
        },
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
    j("Spine", 11, 9, true, Orient::SpineBlend),
    j(
        "Spine1",
        12,
        10,
        true,
        Orient::Frame {
            from: 10,
            aim: 11,
            side: (13, 16),
        },
    ),
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

/// The frame of an [`Orient::Frame`] or [`Orient::SpineBlend`] joint.
fn torso_frame(pose: &Pose, o: Orient) -> Option<Mat3> {
    match o {
        Orient::Frame { from, aim, side } => {
            aim_frame(sub(pose[aim], pose[from]), sub(pose[side.0], pose[side.1]))
        }
        Orient::SpineBlend => {
            let hips = unit(sub(pose[1], pose[5]))?;
            let shoulders = unit(sub(pose[13], pose[16]))?;
            aim_frame(sub(pose[10], pose[9]), add(hips, shoulders))
        }
        _ => None,
    }
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

/// Rest offsets from the motion's mean bone lengths and mean pelvis and chest
/// geometry.
fn rest_pose(m: &Motion) -> Result<Rest, RenderError> {
    let err = |message: String| RenderError::Motion {
        id: m.id.clone(),
        message,
    };
    let len = mean_bone_lengths(&m.poses);
    // Mean direction of the bones out of the pelvis and chest, in their frame.
    let mut local_sum = [[0.0; 3]; NUM_BVH_JOINTS];
    for pose in &m.poses {
        for (b, joint) in SKELETON.iter().enumerate() {
            let Some(parent) = joint.parent else { continue };
            let frame_joint = &SKELETON[parent];
            if joint.kept || !matches!(frame_joint.orient, Orient::Frame { .. }) {
                continue;
            }
            // A helper out of a torso frame: its child's bone in that frame.
            if let (Some(f), Some(v)) = (torso_frame(pose, frame_joint.orient), bone(pose, b)) {
                if let Some(u) = unit(f.transpose().apply(v)) {
                    local_sum[b] = add(local_sum[b], u);
                }
            }
        }
    }
    let mut offsets = [[0.0; 3]; NUM_BVH_JOINTS];
    let mut end_sites = [[0.0; 3]; NUM_BVH_JOINTS];
    for (c, joint) in SKELETON.iter().enumerate() {
        let Some(parent) = joint.parent else { continue };
        if !joint.kept {
            continue; // helpers sit at their parent's position
        }
        let l = len[joint.at];
        if !(l.is_finite() && l > 1e-9) {
            return Err(err(format!("bone {} has no length (mean {l})", joint.name)));
        }
        let dir = if SKELETON[parent].kept {
            canonical_direction(joint.at)
        } else {
            unit(local_sum[parent]).unwrap_or_else(|| canonical_direction(joint.at))
        };
        offsets[c] = scale(dir, l);
        if only_child(c).is_none() {
            end_sites[c] = scale(offsets[c], 0.5);
        }
    }
    Ok(Rest { offsets, end_sites })
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
    let rest = rest_pose(m)?;
    let mut local = Vec::with_capacity(m.poses.len());
    let mut prev_global: Option<[Mat3; NUM_BVH_JOINTS]> = None;
    for pose in &m.poses {
        let mut g = [Mat3::IDENTITY; NUM_BVH_JOINTS];
        let mut l = [Mat3::IDENTITY; NUM_BVH_JOINTS];
        for (b, joint) in SKELETON.iter().enumerate() {
            let parent_g = joint.parent.map_or(Mat3::IDENTITY, |p| g[p]);
            let previous = prev_global.map(|pg| pg[b]);
            g[b] = match joint.orient {
                Orient::Frame { .. } | Orient::SpineBlend => torso_frame(pose, joint.orient),
                Orient::Swing => bone(pose, b).and_then(unit).and_then(|d| {
                    let rest_dir = only_child(b).and_then(|c| unit(rest.offsets[c]))?;
                    Some(parent_g.mul(&swing(rest_dir, parent_g.transpose().apply(d))))
                }),
                Orient::Fixed => Some(parent_g),
            }
            // A degenerate frame (zero-length bone, collinear torso) keeps
            // the previous frame's orientation.
            .or(previous)
            .unwrap_or(parent_g);
            l[b] = parent_g.transpose().mul(&g[b]);
        }
        prev_global = Some(g);
        local.push(l);
    }
    Ok(Solved {
        rest,
        root: m.poses.iter().map(|p| p[0]).collect(),
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

/// Euler angles in degrees `(z, y, x)` with `R = Rz · Ry · Rx`, chosen of
/// the two equivalent solutions and the multiples of 360° to be closest to
/// `prev` (continuity over time); without `prev`, the one with `|y| ≤ 90°`.
pub fn euler_zyx(r: &Mat3, prev: Option<[f64; 3]>) -> [f64; 3] {
    let m = &r.0;
    let sy = (-m[2][0]).clamp(-1.0, 1.0);
    let y = sy.asin();
    let cy = (m[2][1].powi(2) + m[2][2].powi(2)).sqrt();
    let (z, x) = if cy > 1e-9 {
        (m[1][0].atan2(m[0][0]), m[2][1].atan2(m[2][2]))
    } else {
        // Gimbal lock: only z ∓ x is defined; keep the previous x.
        let x = prev.map_or(0.0, |p| p[2].to_radians());
        let z = if sy > 0.0 {
            x - m[0][1].atan2(m[1][1])
        } else {
            (-m[0][1]).atan2(m[1][1]) - x
        };
        (z, x)
    };
    let deg = [z.to_degrees(), y.to_degrees(), x.to_degrees()];
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
    use mocap_ingest::math::Axis;

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
        for (b, r) in s.local[1].iter().enumerate() {
            let want = if b == elbow {
                Mat3::rotation(Axis::Y, -std::f64::consts::FRAC_PI_2)
            } else {
                Mat3::IDENTITY
            };
            assert!(close(r, &want), "{}: {r:?}", SKELETON[b].name);
        }
        let e = euler_zyx(&s.local[1][elbow], None);
        assert!((e[0]).abs() < 1e-9 && (e[1] + 90.0).abs() < 1e-9 && e[2].abs() < 1e-9);
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
        let e = euler_zyx(&s.local[1][0], None);
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
    fn euler_angles_stay_continuous_through_a_full_turn() {
        let mut prev = None;
        for k in 0..=72 {
            let a = (k as f64 * 10.0).to_radians();
            let r = Mat3::rotation(Axis::Y, a).mul(&Mat3::rotation(Axis::X, 0.3));
            let e = euler_zyx(&r, prev);
            let back = Mat3::euler_listed(&[Axis::Z, Axis::Y, Axis::X], &e.map(f64::to_radians));
            assert!(close(&back, &r), "{k}: {e:?}");
            if let Some(p) = prev {
                let step: f64 = e
                    .iter()
                    .zip(&p)
                    .map(|(x, y): (&f64, &f64)| (x - y).abs())
                    .sum();
                assert!(step < 25.0, "jump at {k}: {p:?} -> {e:?}");
            }
            prev = Some(e);
        }
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
