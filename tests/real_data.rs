//! Every real CMU file reads; BVH and ASF/AMC of the same take agree.

use integration_tests::{asfamc_zip, bvh_zip};
use mocap_ingest::skeleton::JOINT_PARENTS;
use mocap_ingest::source::{Format, Source, TakeInput};
use mocap_ingest::{features, math, read_amc, read_bvh, Motion, Options, JOINT_NAMES, NUM_JOINTS};
use rayon::prelude::*;
use std::collections::BTreeMap;

fn load(source: &Source, take: &TakeInput) -> Motion {
    let mut r = source.reader().expect("open archive");
    let file = source.display_name(&take.motion.name);
    let bytes = r.read(&take.motion.name).expect("read entry");
    match take.format {
        Format::Bvh => read_bvh(&file, &bytes),
        Format::Amc => {
            let asf = take.asf.as_ref().expect("ASF beside AMC");
            let asf_bytes = r.read_file(asf).expect("read ASF");
            let asf_file = source.display_file(asf);
            read_amc(&file, &bytes, &asf_file, &asf_bytes, Default::default())
        }
    }
    .unwrap_or_else(|e| panic!("{e}"))
}

/// Max over bones of (max length − min length) over all frames.
fn bone_length_deviation(m: &Motion) -> f64 {
    let mut lo = [f64::INFINITY; NUM_JOINTS];
    let mut hi = [f64::NEG_INFINITY; NUM_JOINTS];
    for f in 0..m.num_frames() {
        let p = m.pose(f);
        for (j, parent) in JOINT_PARENTS.iter().enumerate() {
            assert!(p[j].iter().all(|v| v.is_finite()), "non-finite joint");
            if let Some(q) = parent {
                let l = math::norm(math::sub(p[j], p[*q]));
                lo[j] = lo[j].min(l);
                hi[j] = hi[j].max(l);
            }
        }
    }
    (1..NUM_JOINTS).map(|j| hi[j] - lo[j]).fold(0.0, f64::max)
}

/// Features → global → features gives the features back: a whole take
/// exactly (to 1e-9), and a 128-frame window from its middle up to the floor
/// (re-derived from the window's first frame) and frame 0's velocities (which
/// repeat frame 1's).
fn round_trip(f: &[features::FeatureVec]) {
    use features::{compute_features, floor_height, to_global, NUM_FEATURES, VEL_X};
    let back = compute_features(&to_global(f)).unwrap();
    for (t, (a, b)) in f.iter().zip(&back).enumerate() {
        for k in 0..NUM_FEATURES {
            assert!(
                (a[k] - b[k]).abs() < 1e-9,
                "frame {t}, feature {k}: {} vs {}",
                a[k],
                b[k]
            );
        }
    }
    if f.len() >= 64 + 128 {
        let w = &f[64..64 + 128];
        let g = to_global(w);
        let shift = floor_height(&g[0]);
        let back = compute_features(&g).unwrap();
        for (t, (a, b)) in w.iter().zip(&back).enumerate() {
            for k in 0..NUM_FEATURES {
                if t == 0 && k >= VEL_X {
                    continue;
                }
                // Heights (root and every joint's y) are relative to the floor.
                let y = k == 0 || (k < VEL_X && (k - 1) % 3 == 1);
                let expect = if y { a[k] - shift } else { a[k] };
                assert!(
                    (expect - b[k]).abs() < 1e-9,
                    "window frame {t}, feature {k}"
                );
            }
        }
    }
}

fn check_archive(path: &std::path::Path, format: Format, expect_takes: usize) {
    let source = Source::open(path).unwrap();
    let takes: Vec<TakeInput> = source.takes().unwrap();
    assert_eq!(takes.len(), expect_takes);
    assert!(takes.iter().all(|t| t.format == format));
    let results: Vec<(usize, f64)> = takes
        .par_iter()
        .map(|t| {
            let m = load(&source, t);
            assert!(m.num_frames() > 0);
            let opts = Options::default();
            let clip = mocap_ingest::clip_from_motion(&t.take_id, &t.take_id, &m, &opts)
                .unwrap_or_else(|e| panic!("{e}"));
            assert!(clip
                .features
                .iter()
                .all(|f| f.iter().all(|v| v.is_finite())));
            round_trip(&clip.features);
            (m.num_frames(), bone_length_deviation(&m))
        })
        .collect();
    let frames: usize = results.iter().map(|r| r.0).sum();
    let dev = results.iter().map(|r| r.1).fold(0.0, f64::max);
    eprintln!(
        "{}: {} takes, {frames} frames, max bone-length deviation {dev:.2e} units",
        path.display(),
        takes.len()
    );
    assert!(dev < 1e-9, "bone lengths change over time: {dev}");
}

#[test]
fn every_bvh_file_reads_with_constant_bone_lengths() {
    integration_tests::require_samples!();
    check_archive(&bvh_zip(), Format::Bvh, 139);
}

#[test]
fn every_asfamc_file_reads_with_constant_bone_lengths() {
    integration_tests::require_samples!();
    check_archive(&asfamc_zip(), Format::Amc, 225);
}

#[test]
fn bvh_and_asfamc_of_the_same_take_agree() {
    integration_tests::require_samples!();
    let bvh = Source::open(&bvh_zip()).unwrap();
    let amc = Source::open(&asfamc_zip()).unwrap();
    let bvh_takes: BTreeMap<String, TakeInput> = bvh
        .takes()
        .unwrap()
        .into_iter()
        .map(|t| (t.take_id.clone(), t))
        .collect();
    let pairs: Vec<(TakeInput, TakeInput)> = amc
        .takes()
        .unwrap()
        .into_iter()
        .filter_map(|t| bvh_takes.get(&t.take_id).map(|b| (b.clone(), t)))
        .collect();
    assert_eq!(pairs.len(), 54, "takes present in both archives");

    let per_take: Vec<([f64; NUM_JOINTS], [f64; 2])> = pairs
        .par_iter()
        .map(|(b, a)| {
            let mb = load(&bvh, b);
            let ma = load(&amc, a);
            assert_eq!(mb.num_frames(), ma.num_frames(), "{}", b.take_id);
            let mut dev = [0.0f64; NUM_JOINTS];
            for f in 0..mb.num_frames() {
                let (pb, pa) = (mb.pose(f), ma.pose(f));
                for j in 0..NUM_JOINTS {
                    dev[j] = dev[j].max(math::norm(math::sub(pb[j], pa[j])));
                }
            }
            let opts = Options::default();
            let fb = mocap_ingest::clip_from_motion("bvh", &b.take_id, &mb, &opts).unwrap();
            let fa = mocap_ingest::clip_from_motion("amc", &a.take_id, &ma, &opts).unwrap();
            assert_eq!(fb.features.len(), fa.features.len());
            // [positions and root height, the three root velocities]
            let mut fdev = [0.0f64; 2];
            for (x, y) in fb.features.iter().zip(&fa.features) {
                for (i, (u, v)) in x.iter().zip(y).enumerate() {
                    let g = usize::from(i >= features::VEL_X);
                    fdev[g] = fdev[g].max((u - v).abs());
                }
            }
            (dev, fdev)
        })
        .collect();
    let mut dev = [0.0f64; NUM_JOINTS];
    for (d, _) in &per_take {
        for j in 0..NUM_JOINTS {
            dev[j] = dev[j].max(d[j]);
        }
    }
    let fdev_pos = per_take.iter().map(|p| p.1[0]).fold(0.0, f64::max);
    let fdev_vel = per_take.iter().map(|p| p.1[1]).fold(0.0, f64::max);
    eprintln!("max |BVH − ASF/AMC| joint position over 54 takes, every frame (units):");
    for j in 0..NUM_JOINTS {
        eprintln!("  {:<13} {:.2e}", JOINT_NAMES[j], dev[j]);
    }
    eprintln!(
        "max |feature difference| over 54 takes at 30 fps: local positions {fdev_pos:.2e}, root velocities {fdev_vel:.2e}"
    );
    assert!(
        dev.iter().all(|&d| d < 1e-3),
        "joint positions differ: {dev:?}"
    );
    assert!(
        fdev_pos < 1e-3 && fdev_vel < 1e-3,
        "features differ by {fdev_pos}, {fdev_vel}"
    );
}

/// Rename the `ROOT`/`JOINT` names of a BVH text by `map`.
fn rename_joints(text: &str, map: &[(&str, &str)]) -> String {
    text.lines()
        .map(|l| {
            let t = l.trim_start();
            for kw in ["JOINT ", "ROOT "] {
                if let Some(name) = t.strip_prefix(kw) {
                    if let Some((_, to)) = map.iter().find(|(from, _)| *from == name.trim()) {
                        return format!("{}{kw}{to}", &l[..l.len() - t.len()]);
                    }
                }
            }
            l.to_string()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn other_bvh_releases_are_recognised_by_joint_names() {
    integration_tests::require_samples!();
    let bytes = integration_tests::read_entry(&bvh_zip(), "cmu-bvh-motionbuilder/02/02_01.bvh");
    let text = String::from_utf8(bytes).unwrap();
    let mb = read_bvh("mb", text.as_bytes()).unwrap();
    assert_eq!(mb.skeleton(), mocap_ingest::SkeletonKind::Motionbuilder2010);

    // 2008 release: LFingers/RFingers instead of Left/RightHandIndex1; T-pose dropped too.
    let mb08 = rename_joints(
        &text,
        &[
            ("LeftHandIndex1", "LFingers"),
            ("RightHandIndex1", "RFingers"),
        ],
    );
    let m08 = read_bvh("mb08", mb08.as_bytes()).unwrap();
    assert_eq!(
        m08.skeleton(),
        mocap_ingest::SkeletonKind::Motionbuilder2008
    );
    assert_eq!(m08.num_frames(), mb.num_frames());
    assert_eq!(m08.pose(7), mb.pose(7));

    // 3dsMax names (same geometry here); 3dsMax files have no T-pose frame,
    // so this file's frame k+1 is the Motionbuilder reading's frame k.
    let max = rename_joints(
        &text,
        &[
            ("LeftUpLeg", "LeftHip"),
            ("LeftLeg", "LeftKnee"),
            ("LeftFoot", "LeftAnkle"),
            ("LeftToeBase", "LeftToe"),
            ("RightUpLeg", "RightHip"),
            ("RightLeg", "RightKnee"),
            ("RightFoot", "RightAnkle"),
            ("RightToeBase", "RightToe"),
            ("LowerBack", "lowerback"),
            ("Spine", "Chest"),
            ("Spine1", "Chest2"),
            ("Neck", "lowerneck"),
            ("Neck1", "Neck"),
            ("LeftShoulder", "LeftCollar"),
            ("LeftArm", "LeftShoulder"),
            ("LeftForeArm", "LeftElbow"),
            ("LeftHand", "LeftWrist"),
            ("LeftFingerBase", "lhand"),
            ("LeftHandIndex1", "LFingers"),
            ("RightShoulder", "RightCollar"),
            ("RightArm", "RightShoulder"),
            ("RightForeArm", "RightElbow"),
            ("RightHand", "RightWrist"),
            ("RightFingerBase", "rhand"),
            ("RightHandIndex1", "RFingers"),
        ],
    );
    let m3 = read_bvh("max", max.as_bytes()).unwrap();
    assert_eq!(m3.skeleton(), mocap_ingest::SkeletonKind::Max3ds);
    assert_eq!(m3.num_frames(), mb.num_frames() + 1);
    for k in [0, 100, mb.num_frames() - 1] {
        assert_eq!(m3.pose(k + 1), mb.pose(k));
    }
}

/// Facing direction (radians, about y) of a pose: the horizontal part of
/// `(LeftArm − Hips) × (RightArm − Hips)`, the local frame's `ez`.
fn facing(p: &mocap_ingest::Pose) -> f64 {
    use mocap_ingest::skeleton::{HIPS, LEFT_ARM, RIGHT_ARM};
    let vf = math::cross(
        math::sub(p[LEFT_ARM], p[HIPS]),
        math::sub(p[RIGHT_ARM], p[HIPS]),
    );
    vf[0].atan2(vf[2])
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// Metres per CMU unit, for readable speeds.
const METRES_PER_UNIT: f64 = 0.0564;

#[test]
fn daz_files_read_and_follow_the_same_trajectory_as_cmu_copies() {
    integration_tests::require_samples!();
    use features::{ANG_VEL_Y, VEL_X, VEL_Z};
    let daz = Source::open(&integration_tests::daz_zip()).unwrap();
    let copies: Vec<(Source, BTreeMap<String, TakeInput>)> = [asfamc_zip(), bvh_zip()]
        .iter()
        .map(|p| {
            let s = Source::open(p).unwrap();
            let t = s
                .takes()
                .unwrap()
                .into_iter()
                .map(|t| (t.take_id.clone(), t))
                .collect();
            (s, t)
        })
        .collect();
    let takes = daz.takes().unwrap();
    assert_eq!(takes.len(), 8);
    let opts = Options::default();
    eprintln!(
        "Daz-friendly BVH vs the same take from ASF/AMC (else Motionbuilder BVH), features at 30 fps:\n\
         take   other frames | facing° mean   max | speed m/s  Δvel m/s  Δ 1 s | ang_vel°/frame Δrms  Δmax"
    );
    let mut worst = [0.0f64; 5];
    for t in &takes {
        let m = load(&daz, t);
        assert_eq!(m.skeleton(), mocap_ingest::SkeletonKind::Daz);
        let dev = bone_length_deviation(&m);
        assert!(dev < 1e-9, "{}: bone lengths change by {dev}", t.take_id);
        let (src, other) = copies
            .iter()
            .find_map(|(s, m)| m.get(&t.take_id).map(|o| (s, o)))
            .unwrap_or_else(|| panic!("{} has no CMU-skeleton copy", t.take_id));
        let mo = load(src, other);
        assert_eq!(m.num_frames(), mo.num_frames(), "{}", t.take_id);
        let a = mocap_ingest::clip_from_motion("daz", &t.take_id, &m, &opts).unwrap();
        let b = mocap_ingest::clip_from_motion("cmu", &t.take_id, &mo, &opts).unwrap();
        assert_eq!(a.features.len(), b.features.len());
        assert!(a.features.iter().all(|f| f.iter().all(|v| v.is_finite())));
        round_trip(&a.features);
        // Facing at every native frame.
        let mut fmax = 0.0f64;
        let mut fsum = 0.0;
        for k in 0..m.num_frames() {
            let d = wrap(facing(&m.pose(k)) - facing(&mo.pose(k))).abs();
            fmax = fmax.max(d);
            fsum += d;
        }
        let fmean = (fsum / m.num_frames() as f64).to_degrees();
        // Planar velocity per frame, and summed over one-second windows (the
        // root's displacement, relative to the CMU copy's).
        let n = a.features.len();
        let (mut dv, mut v, mut dw, mut wmax) = (0.0, 0.0, 0.0, 0.0f64);
        for (x, y) in a.features.iter().zip(&b.features) {
            dv += (x[VEL_X] - y[VEL_X]).powi(2) + (x[VEL_Z] - y[VEL_Z]).powi(2);
            v += y[VEL_X].powi(2) + y[VEL_Z].powi(2);
            let w = (x[ANG_VEL_Y] - y[ANG_VEL_Y]).abs();
            dw += w * w;
            wmax = wmax.max(w);
        }
        let (mut dd, mut dn) = (0.0, 0.0);
        for w in 0..n / 30 {
            let sum = |f: &[features::FeatureVec], k: usize| -> f64 {
                f[w * 30..(w + 1) * 30].iter().map(|x| x[k]).sum()
            };
            for k in [VEL_X, VEL_Z] {
                dd += (sum(&a.features, k) - sum(&b.features, k)).powi(2);
                dn += sum(&b.features, k).powi(2);
            }
        }
        let to_ms = 30.0 * METRES_PER_UNIT;
        let speed = (v / n as f64).sqrt() * to_ms;
        let dvel = (dv / n as f64).sqrt() * to_ms;
        let disp = (dd / dn).sqrt();
        let ang_rms = (dw / n as f64).sqrt().to_degrees();
        eprintln!(
            "{}  {:<5} {:>6} | {:>9.2} {:>5.2} | {:>9.2} {:>9.3} {:>5.1}% | {:>19.2} {:>5.2}",
            t.take_id,
            other.format.as_str(),
            m.num_frames(),
            fmean,
            fmax.to_degrees(),
            speed,
            dvel,
            100.0 * disp,
            ang_rms,
            wmax.to_degrees()
        );
        for (w, x) in worst
            .iter_mut()
            .zip([fmean, fmax.to_degrees(), dvel, disp, ang_rms])
        {
            *w = w.max(x);
        }
    }
    eprintln!(
        "worst: facing {:.2}° mean, {:.2}° max; planar velocity {:.3} m/s rms, one-second displacement {:.1}%; angular velocity {:.2}°/frame rms",
        worst[0],
        worst[1],
        worst[2],
        100.0 * worst[3],
        worst[4]
    );
    // The figure differs, so the hips sway differently; the trajectory agrees.
    assert!(worst[0] < 3.0 && worst[1] < 15.0, "facing {worst:?}");
    assert!(
        worst[2] < 0.3 && worst[3] < 0.15,
        "planar velocity {worst:?}"
    );
    assert!(worst[4] < 2.0, "angular velocity {worst:?}");
}
