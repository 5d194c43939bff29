//! BVH export on real motion: every real sample take, cut into the 128-frame
//! windows the model sees (features → `to_global`, as `cargo xtask sample`
//! does), exported, read back with the project's reader and with `bvh_anim`.

use integration_tests::{asfamc_zip, bvh_zip};
use mocap_ingest::math::{add, dot, norm, scale, sub, Mat3};
use mocap_ingest::skeleton::{Pose, JOINT_PARENTS};
use mocap_ingest::source::Source;
use mocap_ingest::{features::to_global, process_take, Options, SkeletonKind};
use motion_render::bvh::{round_trip, to_bvh};
use motion_render::solve::solve;
use motion_render::solve::{Orient, NUM_BVH_JOINTS, SKELETON};
use motion_render::Motion;
use rayon::prelude::*;

/// Every take of both samples as 128-frame windows (hop 128) of global poses.
fn real_windows() -> Vec<Motion> {
    let mut out = Vec::new();
    for zip in [bvh_zip(), asfamc_zip()] {
        let source = Source::open(&zip).unwrap();
        let takes = source.takes().unwrap();
        let windows: Vec<Vec<Motion>> = takes
            .par_iter()
            .map_init(
                || source.reader().unwrap(),
                |r, take| {
                    let clip = process_take(&source, r, take, &Options::default())
                        .unwrap_or_else(|e| panic!("{e}"));
                    clip.features
                        .chunks_exact(128)
                        .enumerate()
                        .map(|(k, w)| Motion {
                            id: format!("{}_{k}", clip.take_id),
                            poses: to_global(w),
                        })
                        .collect()
                },
            )
            .collect();
        out.extend(windows.into_iter().flatten());
    }
    out
}

/// Angle of a rotation, degrees.
fn angle(r: &Mat3) -> f64 {
    ((r.0[0][0] + r.0[1][1] + r.0[2][2] - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// Over consecutive frames and every joint but the root: the largest step
/// of a rotation channel (degrees) where the joint turns by less than 20°,
/// and the flips: steps where a joint with one bone turns by 20° more than
/// its bone does while the bone moves smoothly (less than 25° in the frame;
/// subject 5's toe markers jump by up to 167° in a frame, which no solver
/// can follow smoothly).
fn channel_steps(m: &Motion, text: &str) -> (f64, usize) {
    let rows: Vec<Vec<f64>> = text
        .lines()
        .skip_while(|l| !l.starts_with("Frame Time"))
        .skip(1)
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    let s = solve(m).unwrap();
    let (mut step, mut flips) = (0.0f64, 0);
    for f in 1..rows.len() {
        for (b, joint) in SKELETON.iter().enumerate().skip(1) {
            let (l0, l1) = (s.local[f - 1][b], s.local[f][b]);
            let turn = angle(&l1.mul(&l0.transpose()));
            if joint.orient == Orient::Swing {
                let c = SKELETON.iter().position(|k| k.parent == Some(b)).unwrap();
                let r = s.rest.offsets[c];
                let (d0, d1) = (l0.apply(r), l1.apply(r));
                let bone = (dot(d0, d1) / norm(d0) / norm(d1))
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees();
                if bone < 25.0 && turn > bone + 20.0 {
                    flips += 1;
                }
            }
            if turn < 20.0 {
                let cols = 3 + 3 * b..6 + 3 * b;
                for (x, y) in rows[f][cols.clone()].iter().zip(&rows[f - 1][cols]) {
                    step = step.max((x - y).abs());
                }
            }
        }
    }
    (step, flips)
}

#[test]
fn real_windows_round_trip_within_a_thousandth_of_the_tolerance() {
    integration_tests::require_samples!();
    let windows = real_windows();
    assert!(windows.len() > 300, "{} windows", windows.len());
    let results: Vec<(String, f64, f64, usize)> = windows
        .par_iter()
        .map(|m| {
            let text = to_bvh(m).unwrap_or_else(|e| panic!("{e}"));
            // The project's reader: recognised as our export, no frame dropped.
            let r = round_trip(m, &text).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(r.frames, 128);
            // bvh_anim, the reader Blender-like tools resemble, parses it too.
            let b = bvh_anim::from_bytes(text.as_bytes())
                .unwrap_or_else(|e| panic!("{}: bvh_anim: {e}", m.id));
            assert_eq!(b.joints().count(), NUM_BVH_JOINTS);
            assert_eq!(b.frames().len(), 128);
            let (step, flips) = channel_steps(m, &text);
            (m.id.clone(), r.max, step, flips)
        })
        .collect();
    let worst = results.iter().fold(0.0, |a: f64, r| a.max(r.1));
    let (step_id, _, step, _) = results.iter().max_by(|a, b| a.2.total_cmp(&b.2)).unwrap();
    let flips: usize = results.iter().map(|r| r.3).sum();
    eprintln!(
        "{} real windows: max joint distance after the round trip {worst:.2e} units; \
         largest channel step where a joint turns < 20° per frame: {step:.1}° ({step_id}); \
         twist flips: {flips}",
        results.len()
    );
    // Real bones are rigid: the only error is the 6 written decimals.
    assert!(worst < 0.05 * 1e-3, "max distance {worst}");
    // Continuous rotations and channels: no joint turns much more than its
    // bone (no twist flip), and where a joint turns smoothly no channel
    // jumps (no 360° wrap, no switch of Euler solution). The data itself
    // has jumps (a toe marker swapping sides within a frame in subject 5).
    assert!(*step < 45.0, "channel jump of {step}° in {step_id}");
    assert_eq!(flips, 0, "twist flips");
}

/// `pose` with every bone scaled by its own factor (parents before children).
fn stretch(pose: &Pose, f: impl Fn(usize) -> f64) -> Pose {
    let mut out = *pose;
    for (j, p) in JOINT_PARENTS.iter().enumerate() {
        if let Some(p) = *p {
            out[j] = add(out[p], scale(sub(pose[j], pose[p]), f(j)));
        }
    }
    out
}

#[test]
fn stretching_bones_errs_by_exactly_the_bone_length_variation() {
    integration_tests::require_samples!();
    // Generated motion's bones change length; the export keeps each bone's
    // direction, so the error is what the mean lengths predict.
    let real = real_windows().into_iter().step_by(25).collect::<Vec<_>>();
    for m in &real {
        let g = Motion {
            id: m.id.clone(),
            poses: m
                .poses
                .iter()
                .enumerate()
                .map(|(t, p)| stretch(p, |j| 1.0 + 0.15 * (0.2 * t as f64 + j as f64).sin()))
                .collect(),
        };
        let r = round_trip(&g, &to_bvh(&g).unwrap()).unwrap();
        assert!(r.max > 0.1, "{}: stretching changed nothing", g.id);
        assert!(r.residual_max < 1e-4, "{}: {r:?}", g.id);
        assert!((r.max - r.bone_max).abs() < 1e-4, "{}: {r:?}", g.id);
    }
    // The reader knows the export by its joints: Motionbuilder names, no fingers.
    let text = to_bvh(&real[0]).unwrap();
    let back = mocap_ingest::read_bvh("x.bvh", text.as_bytes()).unwrap();
    assert_eq!(back.skeleton(), SkeletonKind::Exported);
    assert!(norm(sub(back.pose(0)[0], real[0].poses[0][0])) < 1e-5);
}
