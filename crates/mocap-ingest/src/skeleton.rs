//! The 19 joints the paper keeps, and how each CMU skeleton names them.

use crate::math::Vec3;

/// Number of joints kept (the paper's 19).
pub const NUM_JOINTS: usize = 19;

/// The kept joints, in feature order, with Motionbuilder names. Index 0 is the root.
pub const JOINT_NAMES: [&str; NUM_JOINTS] = [
    "Hips",
    "LeftUpLeg",
    "LeftLeg",
    "LeftFoot",
    "LeftToeBase",
    "RightUpLeg",
    "RightLeg",
    "RightFoot",
    "RightToeBase",
    "Spine",
    "Spine1",
    "Neck1",
    "Head",
    "LeftArm",
    "LeftForeArm",
    "LeftHand",
    "RightArm",
    "RightForeArm",
    "RightHand",
];

/// Index of `Hips` in [`JOINT_NAMES`].
pub const HIPS: usize = 0;
/// Index of `LeftUpLeg` (the left hip joint) in [`JOINT_NAMES`].
pub const LEFT_UP_LEG: usize = 1;
/// Index of `RightUpLeg` (the right hip joint) in [`JOINT_NAMES`].
pub const RIGHT_UP_LEG: usize = 5;
/// Index of `LeftLeg` (the left knee) in [`JOINT_NAMES`].
pub const LEFT_LEG: usize = 2;
/// Index of `LeftFoot` (the left ankle) in [`JOINT_NAMES`].
pub const LEFT_FOOT: usize = 3;
/// Index of `RightLeg` (the right knee) in [`JOINT_NAMES`].
pub const RIGHT_LEG: usize = 6;
/// Index of `RightFoot` (the right ankle) in [`JOINT_NAMES`].
pub const RIGHT_FOOT: usize = 7;
/// Index of `LeftToeBase` (the left toe) in [`JOINT_NAMES`].
pub const LEFT_TOE: usize = 4;
/// Index of `RightToeBase` (the right toe) in [`JOINT_NAMES`].
pub const RIGHT_TOE: usize = 8;
/// Index of `LeftArm` (the left shoulder point) in [`JOINT_NAMES`].
pub const LEFT_ARM: usize = 13;
/// Index of `RightArm` (the right shoulder point) in [`JOINT_NAMES`].
pub const RIGHT_ARM: usize = 16;

/// Parent of each kept joint within the kept set (`None` for the root); the
/// "bones" whose lengths stay constant over time.
pub const JOINT_PARENTS: [Option<usize>; NUM_JOINTS] = [
    None,
    Some(0),
    Some(1),
    Some(2),
    Some(3),
    Some(0),
    Some(5),
    Some(6),
    Some(7),
    Some(0),
    Some(9),
    Some(10),
    Some(11),
    Some(10),
    Some(13),
    Some(14),
    Some(10),
    Some(16),
    Some(17),
];

/// Global positions of the 19 kept joints at one time step.
pub type Pose = [Vec3; NUM_JOINTS];

/// Which skeleton a file uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SkeletonKind {
    /// cgspeed's Motionbuilder-friendly BVH, 2010 release (`LeftHandIndex1`).
    Motionbuilder2010,
    /// cgspeed's Motionbuilder-friendly BVH, 2008 release (`LFingers`).
    Motionbuilder2008,
    /// cgspeed's 3dsMax-friendly BVH.
    Max3ds,
    /// CMU's original Acclaim ASF/AMC.
    AsfAmc,
    /// cgspeed's Daz-friendly BVH: the motion retargeted onto a 43-joint Daz
    /// figure (`hip`, `abdomen`, `lThigh`, …) in the figure's own unit; read
    /// through [`DAZ_JOINTS`] and scaled to CMU units (see `docs/features.md`).
    Daz,
    /// Motionbuilder names without any finger joints: this project's BVH
    /// export (`motion-render`), which has no T-pose frame. cgspeed's
    /// Motionbuilder files always carry finger joints.
    Exported,
}

impl SkeletonKind {
    /// A human-readable name.
    pub fn name(self) -> &'static str {
        match self {
            SkeletonKind::Motionbuilder2010 => "Motionbuilder-friendly BVH (2010)",
            SkeletonKind::Motionbuilder2008 => "Motionbuilder-friendly BVH (2008)",
            SkeletonKind::Max3ds => "3dsMax-friendly BVH",
            SkeletonKind::AsfAmc => "ASF/AMC",
            SkeletonKind::Daz => "Daz-friendly BVH",
            SkeletonKind::Exported => {
                "BVH exported by this project (Motionbuilder names, no fingers)"
            }
        }
    }

    /// Whether frame 0 is cgspeed's synthetic T-pose (or, for Daz, rest
    /// pose), to be dropped.
    pub fn has_tpose_frame(self) -> bool {
        matches!(
            self,
            SkeletonKind::Motionbuilder2010 | SkeletonKind::Motionbuilder2008 | SkeletonKind::Daz
        )
    }
}

/// BVH joint names of the kept joints in the Motionbuilder-friendly releases.
pub const MOTIONBUILDER_NAMES: [&str; NUM_JOINTS] = JOINT_NAMES;

/// BVH joint names of the kept joints in the 3dsMax-friendly release. Note
/// that `LeftShoulder` and `Neck` here are Motionbuilder's `LeftArm` and `Neck1`.
pub const MAX3DS_NAMES: [&str; NUM_JOINTS] = [
    "Hips",
    "LeftHip",
    "LeftKnee",
    "LeftAnkle",
    "LeftToe",
    "RightHip",
    "RightKnee",
    "RightAnkle",
    "RightToe",
    "Chest",
    "Chest2",
    "Neck",
    "Head",
    "LeftShoulder",
    "LeftElbow",
    "LeftWrist",
    "RightShoulder",
    "RightElbow",
    "RightWrist",
];

/// Where a kept joint is in a BVH skeleton.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BvhJoint {
    /// The joint of that name.
    Named(&'static str),
    /// The End Site of the joint of that name.
    EndSiteOf(&'static str),
}

impl BvhJoint {
    /// The BVH joint name (for an End Site, its joint's).
    pub fn name(self) -> &'static str {
        match self {
            BvhJoint::Named(n) | BvhJoint::EndSiteOf(n) => n,
        }
    }
}

/// The kept joints in cgspeed's Daz-friendly BVH. The figure has no toe
/// joint: the End Site of each foot stands for the toe. `Hips` is not the
/// figure's `hip` joint itself but a point fixed to it (see
/// [`CMU_ROOT_FROM_HIP_JOINTS`]). Approximations (the figure is Daz's, not
/// the subject's): `abdomen`, `chest`, `neck` and `head` sit at other heights
/// along the spine than CMU's `Spine`, `Spine1`, `Neck1` and `Head`, and the
/// foot's End Site lies near, not at, the ball of the foot. Legs and arms are
/// the same anatomical joints.
pub const DAZ_JOINTS: [BvhJoint; NUM_JOINTS] = [
    BvhJoint::Named("hip"),
    BvhJoint::Named("lThigh"),
    BvhJoint::Named("lShin"),
    BvhJoint::Named("lFoot"),
    BvhJoint::EndSiteOf("lFoot"),
    BvhJoint::Named("rThigh"),
    BvhJoint::Named("rShin"),
    BvhJoint::Named("rFoot"),
    BvhJoint::EndSiteOf("rFoot"),
    BvhJoint::Named("abdomen"),
    BvhJoint::Named("chest"),
    BvhJoint::Named("neck"),
    BvhJoint::Named("head"),
    BvhJoint::Named("lShldr"),
    BvhJoint::Named("lForeArm"),
    BvhJoint::Named("lHand"),
    BvhJoint::Named("rShldr"),
    BvhJoint::Named("rForeArm"),
    BvhJoint::Named("rHand"),
];

/// Joints (besides the kept ones) that the Daz-friendly figure has and the
/// other releases lack.
const DAZ_MARKERS: [&str; 4] = ["lButtock", "rButtock", "lCollar", "rCollar"];

/// Leg length (hip joint to ankle: femur + tibia) of a CMU subject, in CMU
/// units: the mean over both legs of the 11 subjects of the shared ASF/AMC
/// sample (14.52 … 15.28). A Daz-friendly file is scaled so that its figure's
/// legs have this length.
pub const CMU_REFERENCE_LEG: f64 = 14.937;

/// Where a CMU subject's root (`Hips`) sits relative to the middle of its two
/// hip joints, in its rest frame (y up, z forward), CMU units: the mean of
/// the `lhipjoint`/`rhipjoint` bones of the same 11 subjects (1.71 … 1.86
/// units up, 0.62 … 0.85 back). A Daz-friendly file's `Hips` is this point,
/// fixed in the frame of the figure's `hip`.
pub const CMU_ROOT_FROM_HIP_JOINTS: crate::math::Vec3 = [0.0, 1.80, -0.72];

/// The ASF bone whose *end* is each kept joint (`root` is the root position).
pub const ASF_BONES: [&str; NUM_JOINTS] = [
    "root",
    "lhipjoint",
    "lfemur",
    "ltibia",
    "lfoot",
    "rhipjoint",
    "rfemur",
    "rtibia",
    "rfoot",
    "lowerback",
    "upperback",
    "lowerneck",
    "upperneck",
    "lclavicle",
    "lhumerus",
    "lradius",
    "rclavicle",
    "rhumerus",
    "rradius",
];

/// Joints (besides the kept ones) whose presence tells the releases apart.
const MB2010_MARKERS: [&str; 2] = ["LeftHandIndex1", "RightHandIndex1"];
const MB2008_MARKERS: [&str; 2] = ["LFingers", "RFingers"];

/// Recognise a BVH skeleton from its joint names.
///
/// Returns the kind, or the closest candidate and the joints it is missing.
pub fn recognise_bvh(names: &[&str]) -> Result<SkeletonKind, (&'static str, Vec<String>)> {
    let has = |n: &str| names.contains(&n);
    let missing = |set: &[&str]| -> Vec<String> {
        set.iter()
            .filter(|n| !has(n))
            .map(|n| n.to_string())
            .collect()
    };
    let mb = missing(&MOTIONBUILDER_NAMES);
    let max = missing(&MAX3DS_NAMES);
    let daz_names: Vec<&str> = DAZ_JOINTS
        .iter()
        .map(|j| j.name())
        .chain(DAZ_MARKERS)
        .collect();
    let mut daz = missing(&daz_names);
    daz.dedup();
    if mb.is_empty() {
        if MB2010_MARKERS.iter().all(|n| has(n)) {
            return Ok(SkeletonKind::Motionbuilder2010);
        }
        if MB2008_MARKERS.iter().all(|n| has(n)) {
            return Ok(SkeletonKind::Motionbuilder2008);
        }
        if MB2010_MARKERS
            .iter()
            .chain(&MB2008_MARKERS)
            .all(|n| !has(n))
        {
            return Ok(SkeletonKind::Exported);
        }
        let mut m = missing(&MB2010_MARKERS);
        m.push("(or LFingers, RFingers)".into());
        return Err((SkeletonKind::Motionbuilder2010.name(), m));
    }
    // 3dsMax shares `Hips`, `Head`, `Neck`, `LeftShoulder`, … with Motionbuilder,
    // so it is told apart by its leg and spine names.
    if max.is_empty() {
        return Ok(SkeletonKind::Max3ds);
    }
    if daz.is_empty() {
        return Ok(SkeletonKind::Daz);
    }
    let closest = [
        (SkeletonKind::Motionbuilder2010, mb),
        (SkeletonKind::Max3ds, max),
        (SkeletonKind::Daz, daz),
    ]
    .into_iter()
    .min_by_key(|(_, m)| m.len());
    match closest {
        Some((kind, m)) => Err((kind.name(), m)),
        None => Err(("none", Vec::new())),
    }
}

/// Where each kept joint is in a recognised BVH skeleton.
pub fn bvh_joints(kind: SkeletonKind) -> [BvhJoint; NUM_JOINTS] {
    match kind {
        SkeletonKind::Max3ds => MAX3DS_NAMES.map(BvhJoint::Named),
        SkeletonKind::Daz => DAZ_JOINTS,
        _ => MOTIONBUILDER_NAMES.map(BvhJoint::Named),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parents_come_first() {
        for (j, p) in JOINT_PARENTS.iter().enumerate() {
            if let Some(p) = p {
                assert!(*p < j);
            }
        }
        assert_eq!(JOINT_NAMES[LEFT_ARM], "LeftArm");
        assert_eq!(JOINT_NAMES[RIGHT_ARM], "RightArm");
    }

    #[test]
    fn recognises_each_release_and_reports_missing_joints() {
        let mut mb: Vec<&str> = MOTIONBUILDER_NAMES.to_vec();
        mb.extend(MB2010_MARKERS);
        assert_eq!(recognise_bvh(&mb), Ok(SkeletonKind::Motionbuilder2010));
        let mut mb08: Vec<&str> = MOTIONBUILDER_NAMES.to_vec();
        mb08.extend(MB2008_MARKERS);
        assert_eq!(recognise_bvh(&mb08), Ok(SkeletonKind::Motionbuilder2008));
        assert_eq!(recognise_bvh(&MAX3DS_NAMES), Ok(SkeletonKind::Max3ds));
        // No finger joints at all: the project's own export, no T-pose.
        assert_eq!(
            recognise_bvh(&MOTIONBUILDER_NAMES),
            Ok(SkeletonKind::Exported)
        );
        assert!(!SkeletonKind::Exported.has_tpose_frame());
        // One finger marker of a release but not the other: still an error.
        let mut half: Vec<&str> = MOTIONBUILDER_NAMES.to_vec();
        half.push("LeftHandIndex1");
        assert!(recognise_bvh(&half).is_err());
        let partial: Vec<&str> = mb.iter().copied().filter(|n| *n != "LeftForeArm").collect();
        let (closest, missing) = recognise_bvh(&partial).unwrap_err();
        assert_eq!(closest, SkeletonKind::Motionbuilder2010.name());
        assert_eq!(missing, vec!["LeftForeArm".to_string()]);
        let mut daz: Vec<&str> = DAZ_JOINTS.iter().map(|j| j.name()).collect();
        daz.extend(DAZ_MARKERS);
        assert_eq!(recognise_bvh(&daz), Ok(SkeletonKind::Daz));
        daz.retain(|n| *n != "lButtock");
        let (closest, missing) = recognise_bvh(&daz).unwrap_err();
        assert_eq!(closest, SkeletonKind::Daz.name());
        assert_eq!(missing, vec!["lButtock".to_string()]);
    }
}
