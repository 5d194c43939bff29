//! The player on a small random model: the bundle's round trip and its
//! errors, the same frames for the same seed and keys, runs after runs, and
//! keys that reach the control.

use candle_core::{Device, Tensor};
use motion_play::bundle::{Bundle, Header, Start};
use motion_play::{PlayError, Player};
use motion_steer::Keys;
use motion_vrnn::model::{Config, PACE_EVERY, PACE_FRAMES};
use motion_vrnn::rng::Rng;
use motion_vrnn::train::init_model;

/// The default model's parts with categories, a body fitted to synthetic
/// statistics and its control's weights drawn at random (so the control
/// changes the frames), as a bundle with two starts.
fn bundle() -> Bundle {
    let mut c = Config::named("motion").unwrap();
    c.categories = vec!["walk".into(), "run".into()];
    c.parts.pace = true;
    c.parts.control = true;
    let mut mean = vec![0.0; 58];
    mean[0] = 15.0;
    let x = Rng::new(3, 1).normals(4 * 8 * 58);
    c.fit_to(&mean, &vec![2.0; 58], &x);
    let t = init_model(&c, 4, &Device::Cpu).unwrap();
    for (name, v) in t.varmap.data().lock().unwrap().iter() {
        if name == motion_vrnn::model::CONTROL_WEIGHT {
            let r: Vec<f32> = Rng::new(9, 9)
                .normals(v.elem_count())
                .iter()
                .map(|x| 0.3 * x)
                .collect();
            v.set(&Tensor::from_vec(r, v.shape(), &Device::Cpu).unwrap())
                .unwrap();
        }
    }
    let file = tempfile::NamedTempFile::new().unwrap();
    t.varmap.save(file.path()).unwrap();
    let start = |category: &str, seed| Start {
        category: category.into(),
        source: format!("synthetic {seed}"),
        frames: Rng::new(seed, 2)
            .normals(PACE_FRAMES * 58)
            .iter()
            .map(|v| 0.3 * v)
            .collect(),
    };
    Bundle {
        header: Header {
            config: c,
            starts: vec![start("walk", 1), start("run", 2)],
            speeds: [0.7, 1.4],
        },
        weights: std::fs::read(file.path()).unwrap(),
    }
}

fn frames(p: &mut Player, keys: &[Keys]) -> Vec<f64> {
    keys.iter()
        .flat_map(|k| {
            let f = p.step(*k).unwrap();
            f.pose
                .iter()
                .flatten()
                .copied()
                .chain(f.root.pos)
                .collect::<Vec<_>>()
        })
        .collect()
}

#[test]
fn the_bundle_reads_back_and_says_what_is_wrong() {
    let b = bundle();
    let bytes = b.to_bytes().unwrap();
    assert_eq!(Bundle::from_bytes(&bytes).unwrap(), b);
    let err = |bytes: &[u8]| match Bundle::from_bytes(bytes) {
        Err(PlayError::Bundle(m)) => m,
        other => panic!("{:?}", other.map(|_| ())),
    };
    assert!(err(b"<html>").contains("MPLAY1"));
    assert!(err(&bytes[..9]).contains("header's length"));
    assert!(err(&bytes[..40]).contains("inside its header"));
    let mut short = b.clone();
    short.header.starts[1].frames.pop();
    assert!(err(&short.to_bytes().unwrap()).contains("928 expected"));
    let mut free = b.clone();
    free.header.config.parts.control = false;
    match Player::new(&free.to_bytes().unwrap(), 0) {
        Err(e) => assert!(e.to_string().contains("without the control"), "{e}"),
        Ok(_) => panic!("a model without the control played"),
    }
}

#[test]
fn the_same_seed_and_keys_make_the_same_frames_and_keys_steer() {
    let bytes = bundle().to_bytes().unwrap();
    let n = PACE_FRAMES + 2 * PACE_EVERY + 10;
    let left = Keys {
        turn: -1.0,
        ..Keys::default()
    };
    let keys: Vec<Keys> = (0..n)
        .map(|t| if t % 50 < 20 { left } else { Keys::default() })
        .collect();
    let mut a = Player::new(&bytes, 7).unwrap();
    let first = frames(&mut a, &keys);
    assert!(first.iter().all(|v| v.is_finite()));
    assert_eq!(first, frames(&mut Player::new(&bytes, 7).unwrap(), &keys));
    assert_ne!(first, frames(&mut Player::new(&bytes, 8).unwrap(), &keys));
    // The keys reach the model: other keys, other frames (after the start).
    let straight = frames(
        &mut Player::new(&bytes, 7).unwrap(),
        &vec![Keys::default(); n],
    );
    let width = first.len() / n;
    assert_eq!(
        first[..PACE_FRAMES * width],
        straight[..PACE_FRAMES * width]
    );
    assert_ne!(
        first[PACE_FRAMES * width..],
        straight[PACE_FRAMES * width..]
    );
    // The start frames are the context, placed at the origin.
    let f = Player::new(&bytes, 7)
        .unwrap()
        .step(Keys::default())
        .unwrap();
    assert_eq!(f.root, motion_steer::Frame2::START);
    assert_eq!([f.pose[0][0], f.pose[0][2]], [0.0, 0.0]);
    // Another category, and a restart from its context.
    a.pick(1).unwrap();
    assert_eq!(a.category(), 1);
    a.step(Keys::default()).unwrap();
    a.restart(1).unwrap();
    assert_eq!(
        a.step(Keys::default()).unwrap().root,
        motion_steer::Frame2::START
    );
    assert!(a.pick(2).unwrap_err().to_string().contains("no category 2"));
}
