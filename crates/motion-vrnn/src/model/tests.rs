use super::*;
use mocap_ingest::skeleton::JOINT_PARENTS;

/// Four frames, 1 and 3 fed: the fed frames' speeds 5 (3, 4) and 0,
/// the real ones 0, so the means are about 2.5 and 0 and the loss about
/// ln(2.505 / 0.0051)² · 4 = 153.6 (with velocity stds of 2 and 0.5 as
/// well: the same raw speeds). Frame 0 is fast but not fed: it does not
/// count.
#[test]
fn the_fed_speed_loss_compares_the_fed_frames_mean_speed() {
    use mocap_ingest::features::{VEL_X, VEL_Z};
    let dev = &Device::Cpu;
    let mut v = vec![0.0f32; 4 * 58];
    (v[VEL_X], v[58 + VEL_X], v[58 + VEL_Z]) = (10.0, 3.0, 4.0);
    let fast = Tensor::from_vec(v, (1, 4, 58), dev).unwrap();
    let mask = Tensor::from_vec(vec![0.0f32, 1.0, 0.0, 1.0], (1, 4), dev).unwrap();
    let still = Tensor::zeros((1, 4, 58), DType::F32, dev).unwrap();
    let value = |body: &Body, fed: &Tensor| {
        fed_speed_loss(fed, &still, &mask, &body.stats())
            .unwrap()
            .to_scalar::<f32>()
            .unwrap() as f64
    };
    // A standstill's speed is the offset's root, 1e-4.
    let mean = |sum: f64| sum / (2.0 + 1e-6) + FED_SPEED_FLOOR;
    let expected = (mean(5.0 + 1e-4) / mean(2e-4)).ln().powi(2) * 4.0;
    assert!((expected - 153.6).abs() < 0.1);
    let body = identity_body();
    assert!((value(&body, &fast) - expected).abs() < 1e-5 * expected);
    // Velocity stds 2 and 0.5: the same raw speeds, the same loss.
    let mut scaled = identity_body();
    (scaled.std[VEL_X], scaled.std[VEL_Z]) = (2.0, 0.5);
    let mut v = vec![0.0f32; 4 * 58];
    (v[VEL_X], v[58 + VEL_X], v[58 + VEL_Z]) = (5.0, 1.5, 8.0);
    let fed = Tensor::from_vec(v, (1, 4, 58), dev).unwrap();
    assert!((value(&scaled, &fed) - expected).abs() < 1e-5 * expected);
    // No fed frame: nothing to compare.
    let none = Tensor::zeros((1, 4), DType::F32, dev).unwrap();
    let loss = fed_speed_loss(&fast, &still, &none, &body.stats()).unwrap();
    assert_eq!(loss.to_scalar::<f32>().unwrap(), 0.0);
}

/// Statistics that leave values as they are (mean 0, std 1).
fn identity_body() -> Body {
    Body {
        mean: vec![0.0; 58],
        std: vec![1.0; 58],
        bones: vec![1.0; BONES],
        contact_height: 0.5,
    }
}

fn row(v: &[f32]) -> Tensor {
    Tensor::from_vec(v.to_vec(), (1, 1, 58), &Device::Cpu).unwrap()
}

#[test]
fn a_planted_foot_gives_the_root_velocity_that_keeps_it_in_place() {
    let body = identity_body();
    // Root moves by v = (0.5, 0.3) and turns by θ = 0.2; both toes stay
    // where they were in the world: p_t = R(θ)⁻¹ (p_{t−1} − v).
    let (v, th) = ([0.5f32, 0.3], 0.2f32);
    let (s, c) = th.sin_cos();
    let (mut prev, mut cur) = ([0f32; 58], [0f32; 58]);
    for (toe, p) in [(4usize, [1.0f32, 2.0]), (8, [-1.0, 1.5])] {
        let k = 1 + 3 * (toe - 1);
        prev[k] = p[0];
        prev[k + 2] = p[1];
        let (dx, dz) = (p[0] - v[0], p[1] - v[1]);
        // R(θ)·(x, z) = (c x + s z, −s x + c z); its inverse is R(−θ).
        cur[k] = c * dx - s * dz;
        cur[k + 2] = s * dx + c * dz;
    }
    cur[57] = th;
    cur[55] = 9.0; // the decoded velocity, overruled by the planted feet
    cur[56] = -9.0;
    let logits = Tensor::new(&[[[30f32, 30.0]]], &Device::Cpu).unwrap();
    let out = lock(&row(&prev), &row(&cur), &logits, &body.stats())
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    assert!(
        (out[55] - v[0]).abs() < 1e-5 && (out[56] - v[1]).abs() < 1e-5,
        "{:?}",
        &out[55..]
    );
    // Feet in the air: the decoded velocity stays.
    let up = Tensor::new(&[[[-30f32, -30.0]]], &Device::Cpu).unwrap();
    let out = lock(&row(&prev), &row(&cur), &up, &body.stats())
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    assert!((out[55] - 9.0).abs() < 1e-4 && (out[56] + 9.0).abs() < 1e-4);
}

/// A pose of 19 joints (root height 9, joints spread out), as features.
fn pose() -> Vec<f32> {
    let mut x = vec![0f32; 58];
    x[0] = 9.0;
    for j in 1..=BONES {
        let k = 1 + 3 * (j - 1);
        let f = j as f32;
        x[k] = (0.7 * f).sin() * 3.0;
        x[k + 1] = 9.0 - 0.4 * f;
        x[k + 2] = (0.3 * f).cos() * 2.0;
    }
    x
}

#[test]
fn placing_scales_each_bone_from_its_parent_in_raw_units() {
    // Statistics that are not the identity: raw = 2·n + 1.
    let (mean, std) = (vec![1.0f32; 58], vec![2.0f32; 58]);
    let raw = pose();
    let n: Vec<f32> = raw.iter().map(|v| (v - 1.0) / 2.0).collect();
    let at = |v: &[f32], j: usize, k: usize| match j {
        0 if k == 1 => v[0],
        0 => 0.0,
        _ => v[1 + 3 * (j - 1) + k],
    };
    let bone =
        |v: &[f32], j: usize, k: usize| at(v, j, k) - at(v, JOINT_PARENTS[j].unwrap_or(0), k);
    // Twice each bone's length: each bone doubles along its direction.
    let lengths: Vec<f32> = bone_lengths(&raw[..1], &raw[1..55])
        .iter()
        .map(|l| 2.0 * l)
        .collect();
    let l = Tensor::from_vec(lengths, (1, 1, BONES), &Device::Cpu).unwrap();
    for reference in [false, true] {
        let run = || place(&row(&n), &l, &mean, &std);
        let out = if reference {
            blocks::reference(run)
        } else {
            run()
        };
        let out: Vec<f32> = out
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap()
            .iter()
            .map(|v| 2.0 * v + 1.0)
            .collect();
        for j in 1..=BONES {
            for k in 0..3 {
                let (got, want) = (bone(&out, j, k), 2.0 * bone(&raw, j, k));
                assert!(
                    (got - want).abs() < 1e-4,
                    "reference {reference}, bone {j} axis {k}: {got} vs {want}"
                );
            }
        }
        // Root height, velocity and turn pass through.
        for k in [0, 55, 56, 57] {
            assert!((out[k] - raw[k]).abs() < 1e-5, "feature {k}");
        }
    }
}

#[test]
fn the_skeleton_leaves_a_pose_with_the_right_bones_unchanged() {
    let mut c = Config::named("skeletal").unwrap();
    c.body = Some(identity_body());
    let m = crate::train::init_model(&c, 1, &Device::Cpu).unwrap().model;
    let x = pose();
    let lengths = bone_lengths(&x[..1], &x[1..55]);
    let l = Tensor::from_vec(lengths.clone(), (1, 1, BONES), &Device::Cpu).unwrap();
    let out = m.place(&row(&x), &identity_body(), &l).unwrap();
    let out = out.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    for (k, (a, b)) in out.iter().zip(&x).enumerate() {
        assert!((a - b).abs() < 1e-4, "feature {k}: {a} vs {b}");
    }
    // Longer bones: each joint moves away from its parent along the
    // same direction, so the bone's direction is kept.
    let l2 = (l * 2.0).unwrap();
    let out = m.place(&row(&x), &identity_body(), &l2).unwrap();
    let out = out.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let got = bone_lengths(&out[..1], &out[1..55]);
    for (b, (g, w)) in got.iter().zip(&lengths).enumerate() {
        assert!((g - 2.0 * w).abs() < 1e-3, "bone {b}: {g} vs {}", 2.0 * w);
    }
}

#[test]
fn a_planted_foot_stands_at_the_contact_height() {
    let body = identity_body();
    let mut x = [0f32; 58];
    x[0] = 10.0; // hips height
    x[1 + 3 * 3 + 1] = 3.0; // left toe 3 units up
    x[1 + 3 * 7 + 1] = 7.0; // right toe
    x[1 + 3 * 11 + 1] = 20.0; // head
                              // Left foot down, right foot up: everything moves by 0.5 − 3.
    let logits = Tensor::new(&[[[30f32, -30.0]]], &Device::Cpu).unwrap();
    let out = ground(&row(&x), &logits, &body.stats())
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    for (k, want) in [
        (0, 7.5f32),
        (1 + 3 * 3 + 1, 0.5),
        (1 + 3 * 7 + 1, 4.5),
        (1 + 3 * 11 + 1, 17.5),
    ] {
        assert!(
            (out[k] - want).abs() < 1e-4,
            "feature {k}: {} vs {want}",
            out[k]
        );
    }
    // x and z stay.
    assert_eq!(out[1 + 3 * 3], 0.0);
}
