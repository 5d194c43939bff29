//! Unit tests of the measures on hand-built motions and windows.

use super::*;

#[test]
fn frechet_of_an_empty_set_is_nan_not_a_panic() {
    let a = vec![vec![0.0, 1.0], vec![1.0, 0.0]];
    assert!(frechet(&a, &[]).is_nan());
    assert!(frechet(&[], &a).is_nan());
    assert!(frechet(&a, &[vec![1.0]]).is_nan());
    assert!(frechet(&a, &a).abs() < 1e-12);
}

/// The measures over many motions (APD's pairs, each motion's values,
/// Fréchet's subsets on rayon) are the same bits on one thread as on
/// several.
#[test]
fn measures_do_not_depend_on_the_thread_count() {
    let mut state = 7u64;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let motions: Vec<Vec<Pose>> = (0..23)
        .map(|_| {
            (0..40)
                .map(|_| {
                    let mut p = [[0.0; 3]; NUM_JOINTS];
                    for (k, j) in p.iter_mut().enumerate() {
                        *j = [next() * 20.0, 15.0 + k as f64 + next(), next() * 20.0];
                    }
                    p
                })
                .collect()
        })
        .collect();
    let real: Vec<Vec<f64>> = (0..5).map(|_| (0..4).map(|_| next()).collect()).collect();
    let pool: Vec<Vec<f64>> = (0..17).map(|_| (0..4).map(|_| next()).collect()).collect();
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool")
            .install(|| {
                let st = motion_stats(&motions, &Options::default());
                (
                    // Debug prints each f64 so that it reads back exactly.
                    format!("{st:?}"),
                    frechet_of_subsets(&real, &pool)
                        .iter()
                        .map(|v| v.to_bits())
                        .collect::<Vec<_>>(),
                )
            })
    };
    assert_eq!(run(1), run(3));
}

fn still(x: f64) -> Vec<Pose> {
    let mut p: Pose = [[0.0; 3]; NUM_JOINTS];
    for (k, j) in p.iter_mut().enumerate() {
        *j = [x, 1.0 + k as f64, 0.0];
    }
    vec![p; 8]
}

/// Hips at 9, shoulders 3 units either side and 5 above, turned by
/// `yaw` radians about +y.
fn facing(yaw: f64) -> Pose {
    use mocap_ingest::skeleton::{HIPS, LEFT_ARM, RIGHT_ARM};
    let mut p: Pose = [[0.0, 9.0, 0.0]; NUM_JOINTS];
    let (c, s) = (yaw.cos(), yaw.sin());
    // Local +x to the left shoulder when facing +z.
    p[HIPS] = [0.0, 9.0, 0.0];
    p[LEFT_ARM] = [3.0 * c, 14.0, -3.0 * s];
    p[RIGHT_ARM] = [-3.0 * c, 14.0, 3.0 * s];
    p
}

/// Toes `u` units either side of the hips along the facing direction,
/// the left one ahead, in a figure turned by `yaw`.
fn stepping(yaw: f64, u: f64) -> Pose {
    let mut p = facing(yaw);
    let (c, s) = (yaw.cos(), yaw.sin());
    // Local +z is (sin yaw, cos yaw) in the floor plane; the toes also
    // stand apart sideways, which the stride does not read.
    p[FEET[0]] = [u * s + 1.0 * c, 0.5, u * c - 1.0 * s];
    p[FEET[1]] = [-u * s - 1.0 * c, 0.5, -u * c + 1.0 * s];
    p
}

#[test]
fn stride_of_steps_at_any_facing_and_of_a_still_stance() {
    // Left toe 2 units ahead, then 2 behind: "ahead" is ±4 units, whose
    // standard deviation is 4 units = 0.2256 m, however the figure faces.
    for yaw in [0.0, 0.7, -2.0] {
        let walk: Vec<Pose> = (0..10)
            .map(|t| stepping(yaw, if t % 2 == 0 { 2.0 } else { -2.0 }))
            .collect();
        assert!((stride(&walk) - 4.0 * METRES_PER_UNIT).abs() < 1e-12);
    }
    // A figure turning on the spot with one foot always 2 units ahead.
    let stance: Vec<Pose> = (0..10).map(|t| stepping(0.3 * t as f64, 2.0)).collect();
    assert!(stride(&stance).abs() < 1e-12);
    assert_eq!(stride(&stance[..1]), 0.0);
    // Three frames ahead by 0, 1 and 2 units (left toe at u/2): std √(2/3).
    let three: Vec<Pose> = (0..3).map(|t| stepping(0.0, t as f64 / 2.0)).collect();
    assert!((stride(&three) - (2.0f64 / 3.0).sqrt() * METRES_PER_UNIT).abs() < 1e-12);
}

#[test]
fn turning_rate_of_a_steady_turn_and_a_swing() {
    // 3° a frame at 30 fps: 90°/s, either way.
    let left: Vec<Pose> = (0..31)
        .map(|t| facing((3.0 * t as f64).to_radians()))
        .collect();
    assert!((turning_rate(&left, 30.0) - 90.0).abs() < 1e-9);
    let right: Vec<Pose> = (0..31)
        .map(|t| facing((-3.0 * t as f64).to_radians()))
        .collect();
    assert!((turning_rate(&right, 30.0) - 90.0).abs() < 1e-9);
    // Across ±180°: the step is 10°, not 350°.
    let wrap = [facing(175f64.to_radians()), facing(-175f64.to_radians())];
    assert!((turning_rate(&wrap, 30.0) - 300.0).abs() < 1e-9);
    // Standing still, and too short to turn.
    assert_eq!(turning_rate(&vec![facing(0.5); 10], 30.0), 0.0);
    assert_eq!(turning_rate(&left[..1], 30.0), 0.0);
}

#[test]
fn airborne_share_counts_frames_whose_lowest_joint_is_off_the_floor() {
    // Every joint at height h units: 0.05 m is 0.887 units.
    let at = |h: f64| -> Pose { [[1.0, h, 2.0]; NUM_JOINTS] };
    let m = [at(0.0), at(0.8), at(0.9), at(5.0), at(-3.0)];
    assert!((airborne_share(&m) - 0.4).abs() < 1e-12);
    // One joint on the floor grounds the frame.
    let mut one = at(5.0);
    one[7][1] = 0.1;
    assert_eq!(airborne_share(&[one]), 0.0);
    assert_eq!(airborne_share(&[]), 0.0);
}

#[test]
fn apd_of_shifted_copies() {
    // Three copies 0, 1 and 3 units apart in x: pair distances 1, 3, 2.
    let m = [still(0.0), still(1.0), still(3.0)];
    assert!((apd(&m) - 2.0 * METRES_PER_UNIT).abs() < 1e-12);
}

#[test]
fn drift_of_a_rising_gliding_root() {
    // Hips at height 1 + t units, moving 3 units in x and 4 in z per
    // frame: 5 units per frame horizontally.
    let m: Vec<Pose> = (0..40)
        .map(|t| {
            let mut p: Pose = [[0.0; 3]; NUM_JOINTS];
            p[0] = [3.0 * t as f64, 1.0 + t as f64, 4.0 * t as f64];
            p
        })
        .collect();
    let u = METRES_PER_UNIT;
    assert!((hip_height(&m, 0) - 20.5 * u).abs() < 1e-12);
    // Last 32 frames: t = 8..39, mean height 1 + 23.5.
    assert!((hip_height(&m, 8) - 24.5 * u).abs() < 1e-12);
    assert!((root_speed(&m, 0, 30.0) - 150.0 * u).abs() < 1e-9);
    assert!((root_speed(&m, 8, 30.0) - 150.0 * u).abs() < 1e-9);
    let s = motion_stats(&[m], &Options::default());
    assert!((s.hip_height_end_m - 24.5 * u).abs() < 1e-12);
}

#[test]
fn jerk_of_a_cubic() {
    // x = t³ (frames): third difference 6 units per frame³ for every joint.
    let m: Vec<Pose> = (0..10)
        .map(|t| [[(t * t * t) as f64, 0.0, 0.0]; NUM_JOINTS])
        .collect();
    assert!((jerk(&m, 30.0) - 6.0 * 27_000.0 * METRES_PER_UNIT).abs() < 1e-6);
    assert_eq!(jerk(&still(0.0), 30.0), 0.0);
}

#[test]
fn high_frequency_share_of_pure_tones() {
    let tone = |hz: f64| -> Vec<Pose> {
        (0..128)
            .map(|t| {
                let mut p: Pose = [[0.0; 3]; NUM_JOINTS];
                let y = (2.0 * std::f64::consts::PI * hz * t as f64 / 30.0).sin();
                for j in p.iter_mut().skip(1) {
                    *j = [0.0, y, 0.0];
                }
                p
            })
            .collect()
    };
    assert!(high_freq_share(&tone(1.0), 30.0, 5.0) < 0.01);
    assert!(high_freq_share(&tone(10.0), 30.0, 5.0) > 0.99);
}

#[test]
fn bone_cv_of_a_stretching_bone() {
    let mut m = still(0.0);
    assert_eq!(bone_cv(&m), 0.0);
    // LeftUpLeg (1) sits at y = 2 or 4 (Hips at 1, LeftLeg at 3): the
    // bone to Hips has lengths 1 and 3 (cv 1/2), the bone from LeftLeg
    // lengths 1 and 1 (cv 0); 17 bones stay fixed.
    for (t, p) in m.iter_mut().enumerate() {
        p[1] = [0.0, if t % 2 == 0 { 2.0 } else { 4.0 }, 0.0];
    }
    assert!((bone_cv(&m) - 0.5 / 18.0).abs() < 1e-12);
}

/// Five frames of a figure 10 units up but for its toes, placed by
/// `at(t)` (left, right).
fn toes(at: impl Fn(f64) -> ([f64; 3], [f64; 3])) -> Vec<Pose> {
    (0..5)
        .map(|t| {
            let mut p: Pose = [[0.0, 10.0, 0.0]; NUM_JOINTS];
            (p[FEET[0]], p[FEET[1]]) = at(t as f64);
            p
        })
        .collect()
}

#[test]
fn foot_skating_counts() {
    let o = Options::default();
    // Toes on the floor; the left toe slides 1 unit per frame
    // (1·0.0564·30 = 1.69 m/s), the right one stays.
    let m = toes(|t| ([t, 0.0, 0.0], [0.0; 3]));
    let n = foot_skating(&m, &o);
    assert_eq!((n.skate, n.contact, n.all, n.creep_sum_m_s), (4, 8, 8, 0.0));
    let s = motion_stats(&[m], &o);
    assert_eq!(
        (s.skate_share, s.contact_share, s.creep_m_s),
        (0.5, 1.0, 0.0)
    );
}

#[test]
fn planted_toes_that_creep() {
    let o = Options::default();
    // Both toes on the floor, the left one creeping 0.1 unit a frame
    // (0.1·0.0564·30 = 0.1692 m/s, under the skating speed), the right
    // one still, then the right toe lifted 10 units for the last frame.
    let m = toes(|t| {
        (
            [0.1 * t, 0.0, 0.0],
            [0.0, if t == 4.0 { 10.0 } else { 0.0 }, 0.0],
        )
    });
    let n = foot_skating(&m, &o);
    // 4 creeping left foot-frames, 3 still right ones, 1 right in the air.
    assert_eq!((n.skate, n.contact, n.all), (0, 7, 8));
    assert!((n.creep_sum_m_s - 4.0 * 0.1692).abs() < 1e-9);
    let s = motion_stats(&[m], &o);
    assert!((s.creep_m_s - 4.0 * 0.1692 / 7.0).abs() < 1e-9);
    assert_eq!(s.skate_in_contact, 0.0);
}

#[test]
fn frechet_of_known_gaussians() {
    // Identical sets: 0. Shifted by (3, 4): 25.
    let a: Vec<Vec<f64>> = vec![
        vec![0.0, 0.0],
        vec![1.0, 0.0],
        vec![0.0, 1.0],
        vec![1.0, 1.0],
    ];
    let b: Vec<Vec<f64>> = a.iter().map(|r| vec![r[0] + 3.0, r[1] + 4.0]).collect();
    assert!(frechet(&a, &a).abs() < 1e-9);
    assert!((frechet(&a, &b) - 25.0).abs() < 1e-9);
    // Scaled by 2 (covariances Σ and 4Σ, Σ = I/3): tr(Σ + 4Σ − 2·2Σ) = tr(Σ) = 2/3.
    let c: Vec<Vec<f64>> = a
        .iter()
        .map(|r| vec![2.0 * r[0] - 0.5, 2.0 * r[1] - 0.5])
        .collect();
    assert!((frechet(&a, &c) - 2.0 / 3.0).abs() < 1e-9);
}

#[test]
fn spread_of_two_windows() {
    // Window 1: feature a goes 0, 2 (std 1), feature b stays (std 0);
    // window 2: a stays, b goes 1, 5 (std 2). Mean of 1, 0, 0, 2.
    let w1 = vec![vec![0.0, 3.0], vec![2.0, 3.0]];
    let w2 = vec![vec![1.0, 1.0], vec![1.0, 5.0]];
    let s = [window_summary(&w1), window_summary(&w2)];
    assert!((mean_spread(&s) - 0.75).abs() < 1e-12);
    assert_eq!(mean_spread(&[]), 0.0);
}

#[test]
fn pose_spread_of_three_windows() {
    // Window means (a, b): (0, 3), (2, 3), (1, 6): a varies 1, b 3 (n − 1).
    let w = |a: f32, b: f32| vec![vec![a, b], vec![a, b]];
    let s = [w(0.0, 3.0), w(2.0, 3.0), w(1.0, 6.0)].map(|x| window_summary(&x));
    assert!((pose_spread(&s) - 4.0).abs() < 1e-12);
    assert_eq!(pose_spread(&s[..1]), 0.0);
}

#[test]
fn frechet_of_interleaved_subsets() {
    // A pool of 5 points for a real set of 2: k = 2 subsets, {0, 2} and
    // {1, 3}; point 4 is left over.
    let real = vec![vec![0.0], vec![2.0]];
    let pool: Vec<Vec<f64>> = [0.0, 10.0, 2.0, 12.0, 99.0].map(|x| vec![x]).to_vec();
    let d = frechet_of_subsets(&real, &pool);
    assert_eq!(d.len(), 2);
    // Same points: 0. Shifted by 10: 100.
    assert!(d[0].abs() < 1e-9 && (d[1] - 100.0).abs() < 1e-9, "{d:?}");
    assert!(frechet_of_subsets(&real, &pool[..1]).is_empty());
}

#[test]
fn slope_is_least_squares() {
    // x 1, 2, 3 (mean 2), y 2, 3, 5 (mean 10/3): Σ(x−x̄)(y−ȳ) = 4/3 + 0 + 5/3
    // = 3, Σ(x−x̄)² = 2, so 1.5.
    let s = slope(&[(1.0, 2.0), (2.0, 3.0), (3.0, 5.0)]).unwrap();
    assert!((s - 1.5).abs() < 1e-12, "{s}");
    // Halfway to one value: y = 0.5 x + 1.
    let half: Vec<(f64, f64)> = [0.1, 0.4, 0.7]
        .iter()
        .map(|&x| (x, 0.5 * x + 1.0))
        .collect();
    assert!((slope(&half).unwrap() - 0.5).abs() < 1e-12);
    // Every category alike: 0.
    assert_eq!(slope(&[(0.2, 0.3), (0.6, 0.3)]), Some(0.0));
    // One pair, or no difference to follow: none.
    assert_eq!(slope(&[(1.0, 2.0)]), None);
    assert_eq!(slope(&[(1.0, 2.0), (1.0, 3.0)]), None);
}

#[test]
fn eigen_of_a_2x2() {
    let (w, _) = symmetric_eigen(&[vec![2.0, 1.0], vec![1.0, 2.0]]);
    let mut w = w;
    w.sort_by(f64::total_cmp);
    assert!((w[0] - 1.0).abs() < 1e-12 && (w[1] - 3.0).abs() < 1e-12);
}

#[test]
fn window_summary_is_mean_then_std() {
    let w = vec![vec![1.0f32, 0.0], vec![3.0, 0.0]];
    assert_eq!(window_summary(&w), vec![2.0, 0.0, 1.0, 0.0]);
}

#[test]
fn goal_distance_sums_log_ratios() {
    let real = MotionStats {
        jerk_m_s3: 10.0,
        contact_share: 0.5,
        apd_m: 1.0,
        hip_height_m: 1.0,
        hip_height_end_m: 1.0,
        root_speed_m_s: 0.4,
        root_speed_end_m_s: 0.4,
        skate_in_contact: 0.1,
        bone_cv: 0.002,
        ..MotionStats::default()
    };
    // Every ratio 1, bones and skating within their goals: distance 0.
    let same = MotionStats {
        bone_cv: 0.0,
        skate_in_contact: 0.05,
        ..real.clone()
    };
    assert!(goal_distance(&real, &same, 50.0, 70.0).abs() < 1e-12);
    // Jerk ×2, speed ÷2 at the end, bones 4 %, skating ×3, Fréchet ×1.5.
    let off = MotionStats {
        jerk_m_s3: 20.0,
        root_speed_end_m_s: 0.2,
        bone_cv: 0.04,
        skate_in_contact: 0.3,
        ..real.clone()
    };
    let want = 2f64.ln() + 2f64.ln() + 4f64.ln() + 3f64.ln() + 1.5f64.ln();
    assert!((goal_distance(&real, &off, 105.0, 70.0) - want).abs() < 1e-12);
    // A frozen motion (APD 0) counts as 1e-3 of real, not infinity.
    let frozen = MotionStats { apd_m: 0.0, ..same };
    assert!((goal_distance(&real, &frozen, 50.0, 70.0) - 1000f64.ln()).abs() < 1e-9);
}
