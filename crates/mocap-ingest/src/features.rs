//! The paper's 58 per-frame features (see `docs/features.md`).
//!
//! For each time step `t` (at the target rate):
//! - `floor` = lowest y over the 19 kept joints in the clip's first frame;
//! - local frame: `ey = (0,1,0)`, `vf = (LeftArm − Hips) × (RightArm − Hips)`,
//!   `ex = normalize(vf × ey)`, `ez = ey × ex`, origin `o = (Hips.x, floor, Hips.z)`.
//!   `R = [ex ey ez]` has determinant −1 (a mirror), as in the paper;
//! - features: Hips local y, the 18 other joints' local xyz (`Rᵀ(p − o)`), and from
//!   `ΔM(t) = M_lg(t−1) · M_gl(t)` the x and z translation
//!   `R(t−1)ᵀ (o(t) − o(t−1))` and the angle θ with `R(t−1)ᵀ R(t) = R_y(θ)`.
//! - frame 0 has no predecessor: its three velocity values repeat frame 1's
//!   (zeros for a one-frame clip).

use crate::error::ErrorKind;
use crate::math::{cross, dot, norm, scale, sub, Vec3};
use crate::skeleton::{Pose, HIPS, JOINT_NAMES, LEFT_ARM, NUM_JOINTS, RIGHT_ARM};

/// Number of features per frame.
pub const NUM_FEATURES: usize = 58;

/// Index of the Hips height feature.
pub const ROOT_Y: usize = 0;
/// Index of the planar velocity x (local frame of the previous step).
pub const VEL_X: usize = 55;
/// Index of the planar velocity z.
pub const VEL_Z: usize = 56;
/// Index of the angular velocity about y.
pub const ANG_VEL_Y: usize = 57;

/// One frame's features.
pub type FeatureVec = [f64; NUM_FEATURES];

/// Column names of the 58 features, in order (`root_y`, `LeftUpLeg_x`, …,
/// `vel_x`, `vel_z`, `ang_vel_y`).
pub fn feature_names() -> Vec<String> {
    let mut names = vec!["root_y".to_string()];
    for j in &JOINT_NAMES[1..] {
        for c in ["x", "y", "z"] {
            names.push(format!("{j}_{c}"));
        }
    }
    names.extend(["vel_x", "vel_z", "ang_vel_y"].map(String::from));
    names
}

/// The character-local frame at one time step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalFrame {
    /// Local x axis (character's side; the frame is mirrored).
    pub ex: Vec3,
    /// Local y axis, always `(0, 1, 0)`.
    pub ey: Vec3,
    /// Local z axis (facing direction).
    pub ez: Vec3,
    /// Origin: the root projected onto the floor.
    pub origin: Vec3,
}

impl LocalFrame {
    /// The local frame of `pose` given the clip's floor height; `None` when
    /// the facing direction is undefined (shoulders collinear with the hip,
    /// or the torso plane horizontal).
    pub fn of(pose: &Pose, floor: f64) -> Option<LocalFrame> {
        let ey = [0.0, 1.0, 0.0];
        let h = pose[HIPS];
        let a = sub(pose[LEFT_ARM], h);
        let b = sub(pose[RIGHT_ARM], h);
        let vf = cross(a, b);
        let side = cross(vf, ey);
        let len = norm(side);
        // Relative threshold: |vf × ey| compared with |a|·|b|.
        let usable = len.is_finite() && len > 1e-9 * norm(a) * norm(b);
        if !usable {
            return None;
        }
        let ex = scale(side, 1.0 / len);
        let ez = cross(ey, ex);
        Some(LocalFrame {
            ex,
            ey,
            ez,
            origin: [h[0], floor, h[2]],
        })
    }

    /// Coordinates of global point `p` in this frame.
    pub fn to_local(&self, p: Vec3) -> Vec3 {
        let d = sub(p, self.origin);
        [dot(self.ex, d), dot(self.ey, d), dot(self.ez, d)]
    }
}

/// The floor height of a clip: lowest y of all kept joints in its first frame.
pub fn floor_height(first: &Pose) -> f64 {
    first.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min)
}

/// Compute the 58 features of every frame of a clip (already at the target rate).
pub fn compute_features(poses: &[Pose]) -> Result<Vec<FeatureVec>, ErrorKind> {
    let Some(first) = poses.first() else {
        return Err(ErrorKind::NoFrames);
    };
    for (t, pose) in poses.iter().enumerate() {
        if let Some(j) = pose.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(ErrorKind::NonFinite {
                frame: t,
                what: format!("joint {}", JOINT_NAMES[j]),
            });
        }
    }
    let floor = floor_height(first);
    let frames: Vec<LocalFrame> = poses
        .iter()
        .enumerate()
        .map(|(t, p)| {
            LocalFrame::of(p, floor).ok_or_else(|| ErrorKind::Degenerate {
                frame: t,
                reason: "facing direction undefined: LeftArm and RightArm collinear with Hips, or the torso plane is horizontal".into(),
            })
        })
        .collect::<Result<_, _>>()?;

    let mut out = Vec::with_capacity(poses.len());
    for (t, (pose, lf)) in poses.iter().zip(&frames).enumerate() {
        let mut f = [0.0; NUM_FEATURES];
        f[ROOT_Y] = pose[HIPS][1] - floor;
        for j in 1..NUM_JOINTS {
            let l = lf.to_local(pose[j]);
            f[1 + 3 * (j - 1)..4 + 3 * (j - 1)].copy_from_slice(&l);
        }
        if t > 0 {
            let [vx, vz, w] = root_delta(&frames[t - 1], lf);
            f[VEL_X] = vx;
            f[VEL_Z] = vz;
            f[ANG_VEL_Y] = w;
        }
        out.push(f);
    }
    if out.len() > 1 {
        let (head, tail) = out.split_at_mut(1);
        head[0][VEL_X..].copy_from_slice(&tail[0][VEL_X..]);
    }
    Ok(out)
}

/// `ΔM = M_lg(prev) · M_gl(cur)`: the current frame expressed in the previous
/// one. Returns `[dx, dz, θ]` with `R(prev)ᵀ R(cur) = R_y(θ)`.
pub fn root_delta(prev: &LocalFrame, cur: &LocalFrame) -> [f64; 3] {
    let d = sub(cur.origin, prev.origin);
    // (R_prevᵀ R_cur)[0][0] = ex_prev·ex_cur, [0][2] = ex_prev·ez_cur;
    // for R_y(θ) these are cos θ and sin θ.
    let theta = dot(prev.ex, cur.ez).atan2(dot(prev.ex, cur.ex));
    [dot(prev.ex, d), dot(prev.ez, d), theta]
}

/// Global joint positions of a feature sequence: the inverse of
/// [`compute_features`]. The root starts at the origin facing +z
/// (`ex = (−1, 0, 0)`, `ez = (0, 0, 1)`); each step moves the local frame by
/// the frame's `(vel_x, vel_z)` in the previous frame's axes and turns it by
/// `ang_vel_y` (`R(t) = R(t−1)·R_y(θ)`), then places the joints at their
/// local coordinates. The floor is `y = 0`. Frame 0's velocities are not used.
pub fn to_global(frames: &[FeatureVec]) -> Vec<Pose> {
    let mut placer = Placer::default();
    frames.iter().map(|f| placer.place(f)).collect()
}

/// [`to_global`] one frame at a time: the root's frame between frames.
#[derive(Clone, Debug)]
pub struct Placer {
    ex: Vec3,
    ez: Vec3,
    origin: Vec3,
    started: bool,
}

impl Default for Placer {
    /// At the origin facing +z, before the first frame.
    fn default() -> Self {
        Placer {
            ex: [-1.0, 0.0, 0.0],
            ez: [0.0, 0.0, 1.0],
            origin: [0.0; 3],
            started: false,
        }
    }
}

impl Placer {
    /// The global joint positions of the next frame `f` (its velocities
    /// move the root unless it is the first).
    pub fn place(&mut self, f: &FeatureVec) -> Pose {
        let (ex, ez, origin) = (&mut self.ex, &mut self.ez, &mut self.origin);
        if self.started {
            let (dx, dz, th) = (f[VEL_X], f[VEL_Z], f[ANG_VEL_Y]);
            for k in 0..3 {
                origin[k] += ex[k] * dx + ez[k] * dz;
            }
            let (s, c) = th.sin_cos();
            let (nx, nz) = (
                [c * ex[0] - s * ez[0], 0.0, c * ex[2] - s * ez[2]],
                [s * ex[0] + c * ez[0], 0.0, s * ex[2] + c * ez[2]],
            );
            // Renormalise so long sequences do not drift from orthonormal.
            *ex = scale(nx, 1.0 / norm(nx));
            *ez = scale(nz, 1.0 / norm(nz));
        }
        self.started = true;
        let mut pose: Pose = [[0.0; 3]; NUM_JOINTS];
        pose[HIPS] = [origin[0], f[ROOT_Y], origin[2]];
        for (j, p) in pose.iter_mut().enumerate().skip(1) {
            let l = &f[1 + 3 * (j - 1)..4 + 3 * (j - 1)];
            for k in 0..3 {
                p[k] = origin[k] + ex[k] * l[0] + ez[k] * l[2];
            }
            p[1] += l[1];
        }
        pose
    }
}

/// Minimum, mean and maximum of each feature over `frames` (NaN when empty).
pub fn ranges(frames: &[FeatureVec]) -> Vec<[f64; 3]> {
    (0..NUM_FEATURES)
        .map(|i| {
            let (lo, hi, sum) = frames
                .iter()
                .map(|f| f[i])
                .fold((f64::INFINITY, f64::NEG_INFINITY, 0.0), |(a, b, s), v| {
                    (a.min(v), b.max(v), s + v)
                });
            [lo, sum / frames.len() as f64, hi]
        })
        .collect()
}

#[cfg(test)]
mod tests {

    #[test]
    fn ranges_are_min_mean_max_per_feature() {
        let mut a = [0.0; NUM_FEATURES];
        let mut b = [0.0; NUM_FEATURES];
        a[3] = -1.0;
        b[3] = 4.0;
        let r = super::ranges(&[a, b]);
        assert_eq!(r.len(), NUM_FEATURES);
        assert_eq!(r[3], [-1.0, 1.5, 4.0]);
        assert_eq!(r[0], [0.0, 0.0, 0.0]);
    }
    use super::*;

    /// A T-pose standing at `(x, z)`, facing +z, hips at height 9, rotated by
    /// `yaw` about +y.
    fn pose(x: f64, z: f64, yaw: f64) -> Pose {
        let mut p = [[0.0; 3]; NUM_JOINTS];
        let (s, c) = yaw.sin_cos();
        // Local offsets relative to the hips (character faces +z, left is +x).
        for (j, item) in p.iter_mut().enumerate() {
            let off = [
                j as f64 * 0.1,
                -9.0 + (j as f64 - 1.0) * 0.5,
                j as f64 * 0.01,
            ];
            *item = off;
        }
        p[HIPS] = [0.0, 0.0, 0.0];
        p[LEFT_ARM] = [3.0, 5.0, 0.0];
        p[RIGHT_ARM] = [-3.0, 5.0, 0.0];
        for q in p.iter_mut() {
            let [a, b, cz] = *q;
            *q = [c * a + s * cz + x, b + 9.0, -s * a + c * cz + z];
        }
        p
    }

    #[test]
    fn local_frame_of_a_hand_built_pose() {
        let p = pose(1.0, 2.0, 0.0);
        let floor = floor_height(&p);
        assert_eq!(floor, 0.0); // LeftUpLeg sits 9 below the hips, at y = 0
        let lf = LocalFrame::of(&p, floor).unwrap();
        // vf = (3,5,0)×(−3,5,0) = (0,0,30); ex = normalize(vf×ey) = (−1,0,0).
        assert_eq!(lf.ex, [-1.0, 0.0, 0.0]);
        assert_eq!(lf.ez, [0.0, 0.0, 1.0]);
        assert_eq!(lf.origin, [1.0, 0.0, 2.0]);
        // Mirror: a point 3 units to the character's left has local x = −3.
        assert_eq!(lf.to_local([4.0, 14.0, 2.0]), [-3.0, 14.0, 0.0]);
    }

    #[test]
    fn features_of_a_tiny_clip() {
        // Three frames: stand, step 1 unit forward (+z) while turning 90° left
        // (about +y), then stand still.
        let q = std::f64::consts::FRAC_PI_2;
        let clip = [pose(0.0, 0.0, 0.0), pose(0.0, 1.0, q), pose(0.0, 1.0, q)];
        let f = compute_features(&clip).unwrap();
        assert_eq!(f.len(), 3);
        // Root height: hips at 9 above the floor.
        assert!((f[0][ROOT_Y] - 9.0).abs() < 1e-12);
        // LeftUpLeg (joint 1): offset (0.1, -9, 0.01) from the hips. Local
        // x is mirrored: -0.1; y = 9 - 9 = 0; z = 0.01. Same in every frame.
        for fr in &f {
            assert!((fr[1] + 0.1).abs() < 1e-12);
            assert!(fr[2].abs() < 1e-12);
            assert!((fr[3] - 0.01).abs() < 1e-12);
        }
        // Frame 1: moved 1 forward in frame 0's local z; turning left by 90°
        // is θ = −90° in the mirrored local frame.
        assert!(f[1][VEL_X].abs() < 1e-12);
        assert!((f[1][VEL_Z] - 1.0).abs() < 1e-12);
        assert!((f[1][ANG_VEL_Y] + q).abs() < 1e-12);
        // Frame 0 repeats frame 1's velocities; frame 2 is still.
        assert_eq!(f[0][VEL_X..], f[1][VEL_X..]);
        assert!(f[2][VEL_X..].iter().all(|v| v.abs() < 1e-12));
    }

    #[test]
    fn degenerate_and_non_finite_poses_are_errors() {
        let mut p = pose(0.0, 0.0, 0.0);
        p[LEFT_ARM] = [0.0, 5.0, 0.0];
        p[RIGHT_ARM] = [0.0, 10.0, 0.0];
        assert!(matches!(
            compute_features(&[p]),
            Err(ErrorKind::Degenerate { frame: 0, .. })
        ));
        let mut p = pose(0.0, 0.0, 0.0);
        p[3][1] = f64::NAN;
        assert!(matches!(
            compute_features(&[pose(0.0, 0.0, 0.0), p]),
            Err(ErrorKind::NonFinite { frame: 1, .. })
        ));
    }

    #[test]
    fn there_are_58_named_features() {
        let n = feature_names();
        assert_eq!(n.len(), NUM_FEATURES);
        assert_eq!(n[1], "LeftUpLeg_x");
        assert_eq!(n[54], "RightHand_z");
        assert_eq!(n[VEL_X], "vel_x");
    }

    #[test]
    fn to_global_inverts_compute_features() {
        // Walk forward while turning, over a hand-built pose.
        let poses: Vec<Pose> = (0..12)
            .map(|t| pose(0.3 * t as f64, 0.2 * t as f64, 0.15 * t as f64))
            .collect();
        let f = compute_features(&poses).unwrap();
        let g = to_global(&f);
        let back = compute_features(&g).unwrap();
        for (a, b) in f.iter().zip(&back) {
            for k in 0..NUM_FEATURES {
                assert!(
                    (a[k] - b[k]).abs() < 1e-9,
                    "feature {k}: {} vs {}",
                    a[k],
                    b[k]
                );
            }
        }
        // Same shape, rigidly moved: distances between joints are kept.
        for (p, q) in poses.iter().zip(&g) {
            let d = |x: &Pose, i: usize, j: usize| norm(sub(x[i], x[j]));
            assert!((d(p, 0, 15) - d(q, 0, 15)).abs() < 1e-9);
            assert!((d(p, 4, 18) - d(q, 4, 18)).abs() < 1e-9);
        }
        // Frame 0 starts at the origin, on the floor, facing +z.
        assert_eq!([g[0][HIPS][0], g[0][HIPS][2]], [0.0, 0.0]);
        assert_eq!(g[0][HIPS][1], f[0][ROOT_Y]);
    }
}
