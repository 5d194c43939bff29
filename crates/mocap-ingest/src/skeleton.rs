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
            SkeletonKind::Exported => {
                "BVH exported by this project (Motionbuilder names, no fingers)"
            }
        }
    }

    /// Whether frame 0 is cgspeed's synthetic T-pose, to be dropped.
    pub fn has_tpose_frame(self) -> bool {
        matches!(
            self,
            SkeletonKind::Motionbuilder2010 | SkeletonKind::Motionbuilder2008
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
/// Returns the kind and, for each kept joint, the BVH joint name it maps to;
/// or the closest candidate and the joints it is missing.
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
    if mb.len() <= max.len() {
        Err((SkeletonKind::Motionbuilder2010.name(), mb))
    } else {
        Err((SkeletonKind::Max3ds.name(), max))
    }
}

/// The BVH names of the kept joints for a recognised kind.
pub fn bvh_names(kind: SkeletonKind) -> &'static [&'static str; NUM_JOINTS] {
    match kind {
        SkeletonKind::Max3ds => &MAX3DS_NAMES,
        _ => &MOTIONBUILDER_NAMES,
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
    }
}
