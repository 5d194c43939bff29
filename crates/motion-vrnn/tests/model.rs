//! The model against hand-computed values.

use candle_core::{Device, Tensor};
use motion_vrnn::model::{kl_gaussians, kl_standard};
use motion_vrnn::optim::{Adam, AdamConfig};
use motion_vrnn::train::{init_model, named_vars, noise};
use motion_vrnn::{Config, MotionModel};

fn scalar(t: &Tensor) -> f64 {
    t.to_scalar::<f32>().unwrap() as f64
}

#[test]
fn kl_matches_the_closed_form_by_hand() {
    let d = Device::Cpu;
    let t = |v: &[f32]| Tensor::new(v, &d).unwrap();
    // KL(N(1, .5) ‖ N(0, 1)) = ln 2 + (0.25 + 1)/2 − 1/2 = 0.818147
    let k = kl_standard(&t(&[1.0]), &t(&[0.5])).unwrap();
    assert!((scalar(&k) - 0.818_147).abs() < 1e-5);
    // KL(N(0, 1) ‖ N(1, 2)) = ln 2 + (1 + 1)/8 − 1/2 = 0.443147
    let k = kl_gaussians(&t(&[0.0]), &t(&[1.0]), &t(&[1.0]), &t(&[2.0])).unwrap();
    assert!((scalar(&k) - 0.443_147).abs() < 1e-5);
    // Identical Gaussians: 0; dims are summed.
    let k = kl_gaussians(
        &t(&[0.3, -1.0]),
        &t(&[0.2, 0.7]),
        &t(&[0.3, -1.0]),
        &t(&[0.2, 0.7]),
    )
    .unwrap();
    assert!(scalar(&k).abs() < 1e-6);
}

#[test]
fn zero_initialised_model_gives_the_closed_form_loss() {
    let d = Device::Cpu;
    let cfg = Config::default();
    let m = init_model(&cfg, 0, &d).unwrap();
    for (_, v) in named_vars(&m.varmap) {
        v.set(&v.as_tensor().zeros_like().unwrap()).unwrap();
    }
    // With zero weights: decoder output 0, LSTM state 0, posterior N(0, .5),
    // prior N(0, 1) at t = 0 and N(0, .5) after. Loss = Σ x² + 8·(ln 2 − 3/8).
    let x = Tensor::ones((2, 3, 58), candle_core::DType::F32, &d).unwrap();
    let eps = noise(1, 1, 3, 2, 8, &d).unwrap();
    let l = m.model.losses(&x, &eps, None, None).unwrap();
    assert!(
        (scalar(&l.recon) - 174.0).abs() < 1e-4,
        "{}",
        scalar(&l.recon)
    );
    let kl = 8.0 * (std::f64::consts::LN_2 - 0.375);
    assert!(
        (scalar(&l.kl) - kl).abs() < 1e-4,
        "{} vs {kl}",
        scalar(&l.kl)
    );
}

#[test]
fn shapes_of_losses_and_samples() {
    let d = Device::Cpu;
    let cfg = Config::default();
    let m = init_model(&cfg, 3, &d).unwrap();
    let x = Tensor::randn(0f32, 1.0, (4, 5, 58), &d).unwrap();
    let l = m
        .model
        .losses(&x, &noise(0, 0, 5, 4, 8, &d).unwrap(), None, None)
        .unwrap();
    assert_eq!(l.recon.dims(), &[] as &[usize]);
    assert_eq!(l.kl.dims(), &[] as &[usize]);
    let s = m
        .model
        .sample(&noise(0, 1, 7, 3, 8, &d).unwrap(), None, None)
        .unwrap();
    assert_eq!(s.dims(), &[3, 7, 58]);
    // Same seed, same weights.
    let a = init_model(&cfg, 3, &d).unwrap();
    let w = |t: &motion_vrnn::train::Trained| {
        let mut v = named_vars(&t.varmap);
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v.iter()
            .map(|(_, v)| {
                v.as_tensor()
                    .flatten_all()
                    .unwrap()
                    .to_vec1::<f32>()
                    .unwrap()
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(w(&a), w(&m));
}

#[test]
fn one_adam_step_lowers_the_loss_on_a_fixed_batch() {
    let d = Device::Cpu;
    let m = init_model(&Config::default(), 5, &d).unwrap();
    let x = Tensor::from_vec(
        motion_vrnn::rng::Rng::new(9, 0).normals(8 * 16 * 58),
        (8, 16, 58),
        &d,
    )
    .unwrap();
    let eps = noise(2, 0, 16, 8, 8, &d).unwrap();
    let loss = |m: &motion_vrnn::Vrnn| {
        let l = m.losses(&x, &eps, None, None).unwrap();
        (&l.recon + &l.kl).unwrap()
    };
    let before = loss(&m.model);
    let mut adam = Adam::new(named_vars(&m.varmap), AdamConfig::default()).unwrap();
    adam.step(&before.backward().unwrap()).unwrap();
    let after = loss(&m.model);
    assert!(
        scalar(&after) < scalar(&before),
        "{} !< {}",
        scalar(&after),
        scalar(&before)
    );
}
