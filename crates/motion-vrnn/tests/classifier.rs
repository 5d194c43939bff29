//! The motion classifier on synthetic windows: it learns a separable
//! problem, its training does not depend on the thread count, it saves and
//! loads; its measures against hand-computed values.

use candle_core::Device;
use motion_vrnn::classifier::{
    accuracy, diversity, feature_frechet, multimodality, train, Classifier, ClassifierMeta,
    ClassifierTraining, MIN_FRAMES,
};
use motion_vrnn::data::{Category, Windows};
use motion_vrnn::rng::Rng;

const FEATURES: usize = 6;

/// `n` windows of `MIN_FRAMES` frames around a random pose near 0: even
/// ones still (a little noise), odd ones moving (sinusoids of random phase
/// and frequency); labelled `Floor` and `Walk`.
fn still_or_moving(n: usize, seed: u64) -> (Windows, Vec<Category>) {
    let t = MIN_FRAMES;
    let mut rng = Rng::new(seed, 0);
    let mut data = Vec::with_capacity(n * t * FEATURES);
    let mut labels = Vec::with_capacity(n);
    for i in 0..n {
        let pose: Vec<f64> = (0..FEATURES).map(|_| 0.3 * rng.normal()).collect();
        let phase: Vec<f64> = (0..FEATURES)
            .map(|_| rng.uniform() * std::f64::consts::TAU)
            .collect();
        let freq = 0.2 + 0.3 * rng.uniform();
        for f in 0..t {
            for (j, p) in pose.iter().enumerate() {
                let v = if i % 2 == 0 {
                    p + 0.01 * rng.normal()
                } else {
                    p + 2.0 * (freq * f as f64 + phase[j]).sin()
                };
                data.push(v as f32);
            }
        }
        labels.push(if i % 2 == 0 {
            Category::Floor
        } else {
            Category::Walk
        });
    }
    let w = Windows {
        data,
        n,
        length: t,
        features: FEATURES,
    };
    (w, labels)
}

fn meta(c: &Classifier, training: &ClassifierTraining, loss: Vec<f64>) -> ClassifierMeta {
    ClassifierMeta {
        config: c.config().clone(),
        training: *training,
        dataset: "synthetic".into(),
        dataset_manifest_sha256: String::new(),
        loss,
    }
}

#[test]
fn learns_still_against_moving_and_predicts_only_trained_categories() {
    let dev = Device::Cpu;
    let (w, labels) = still_or_moving(64, 1);
    let training = ClassifierTraining {
        epochs: 25,
        batch: 16,
        ..Default::default()
    };
    let (c, loss) = train(&w, &labels, &training, &dev).unwrap();
    assert_eq!(loss.len(), 25);
    assert!(loss[24] < loss[0], "{loss:?}");
    // Windows it has not seen.
    let (test, truth) = still_or_moving(40, 2);
    let out = c.outputs(&test, &dev).unwrap();
    assert_eq!(out.features.len(), 40);
    assert!(out.features.iter().all(|f| f.len() == c.config().embedding));
    for p in &out.probabilities {
        assert_eq!(p.len(), Category::ALL.len());
        assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        // Categories without training windows get nothing.
        for (k, cat) in Category::ALL.iter().enumerate() {
            if !matches!(cat, Category::Floor | Category::Walk) {
                assert_eq!(p[k], 0.0, "{cat}");
            }
        }
    }
    let a = accuracy(&out.predicted(), &truth);
    assert_eq!(a.correct, 40, "{a:?}");
    assert_eq!(a.overall(), Some(1.0));
    assert_eq!(a.of(Category::Walk), Some(1.0));
    assert_eq!(a.of(Category::Run), None);
}

#[test]
fn training_is_byte_identical_with_1_and_2_threads_and_reloads() {
    let dev = Device::Cpu;
    // 80 windows, batch 64: shards of 32, 32 (and 16, 16 in the last batch).
    let (w, labels) = still_or_moving(80, 3);
    let training = ClassifierTraining {
        seed: 7,
        epochs: 3,
        ..Default::default()
    };
    let tmp = tempfile::tempdir().unwrap();
    let run = |threads: usize| {
        let dir = tmp.path().join(format!("t{threads}"));
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let (c, loss) = train(&w, &labels, &training, &dev).unwrap();
                c.save(&dir, &meta(&c, &training, loss)).unwrap();
                let out = c.outputs(&w, &dev).unwrap();
                (dir, out)
            })
    };
    let (a, out_a) = run(1);
    let (b, out_b) = run(2);
    for f in ["classifier.safetensors", "classifier.json"] {
        let (x, y) = (
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
        );
        assert!(x == y, "{f} differs between 1 and 2 threads");
    }
    assert_eq!(out_a, out_b);
    let (loaded, m) = Classifier::load(&a, &dev).unwrap();
    assert_eq!(m.training, training);
    assert_eq!(loaded.outputs(&w, &dev).unwrap(), out_a);
    // Saving again replaces the directory whole; another directory with
    // other files in it is refused.
    loaded.save(&a, &m).unwrap();
    std::fs::write(tmp.path().join("t2").join("classifier.json"), "{").unwrap();
    assert!(Classifier::load(&b, &dev).is_err());
    let busy = tmp.path().join("busy");
    std::fs::create_dir_all(&busy).unwrap();
    std::fs::write(busy.join("notes.txt"), "mine").unwrap();
    assert!(loaded.save(&busy, &m).is_err());
    assert!(busy.join("notes.txt").is_file());
}

#[test]
fn windows_too_short_or_of_another_shape_are_refused() {
    let dev = Device::Cpu;
    let (mut w, labels) = still_or_moving(4, 4);
    let short = Windows {
        data: w.data[..4 * (MIN_FRAMES - 1) * FEATURES].to_vec(),
        length: MIN_FRAMES - 1,
        ..w.clone()
    };
    assert!(train(&short, &labels, &Default::default(), &dev).is_err());
    assert!(train(&w, &labels[..3], &Default::default(), &dev).is_err());
    let training = ClassifierTraining {
        epochs: 1,
        ..Default::default()
    };
    let (c, _) = train(&w, &labels, &training, &dev).unwrap();
    w.features = 3;
    w.length = 2 * MIN_FRAMES;
    assert!(c.outputs(&w, &dev).is_err());
}

#[test]
fn diversity_and_multimodality_by_hand() {
    let v = |x: &[f32]| x.to_vec();
    // Two vectors: one pair, whatever the draw.
    let two = [v(&[0.0, 0.0]), v(&[3.0, 4.0])];
    assert_eq!(diversity(&two, 200, 0), Some(5.0));
    assert_eq!(diversity(&two[..1], 200, 0), None);
    // Five corners of a regular simplex: every pair √2 apart; S_d = 2.
    let simplex: Vec<Vec<f32>> = (0..5)
        .map(|i| (0..5).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
        .collect();
    for seed in 0..5 {
        let d = diversity(&simplex, 200, seed).unwrap();
        assert!((d - 2f64.sqrt()).abs() < 1e-12, "{d}");
    }
    // Disjoint sets: three equal vectors and a fourth at distance 1; with
    // S_d = 2 every draw pairs the fourth with one of the others (1) and the
    // remaining two (0): 0.5.
    let three_and_one = [v(&[0.0]), v(&[0.0]), v(&[0.0]), v(&[1.0])];
    for seed in 0..8 {
        assert_eq!(diversity(&three_and_one, 200, seed), Some(0.5));
    }
    // S_d = 1 of the simplex: one pair.
    let d = diversity(&simplex, 1, 3).unwrap();
    assert!((d - 2f64.sqrt()).abs() < 1e-12);

    // Multimodality: walk pair 5 apart, run pair 1 apart, one jump (left
    // out): (5 + 1) / 2.
    let f = [
        v(&[0.0, 0.0]),
        v(&[1.0, 1.0]),
        v(&[9.0, 9.0]),
        v(&[3.0, 4.0]),
        v(&[1.0, 2.0]),
    ];
    use Category::*;
    let labels = [Walk, Run, Jump, Walk, Run];
    assert_eq!(multimodality(&f, &labels, 20, 0), Some(3.0));
    assert_eq!(multimodality(&f[..3], &labels[..3], 20, 0), None);
    // Seeded: the same draw for the same seed.
    let many: Vec<Vec<f32>> = (0..50).map(|i| v(&[(i * i % 17) as f32])).collect();
    let cats: Vec<Category> = (0..50).map(|i| Category::ALL[i % 3]).collect();
    assert_eq!(
        multimodality(&many, &cats, 20, 4),
        multimodality(&many, &cats, 20, 4)
    );
    assert_eq!(diversity(&many, 200, 4), diversity(&many, 200, 4));
}

#[test]
fn accuracy_and_frechet_by_hand() {
    use Category::*;
    // Logits and per-category counts are indexed by `category as usize`.
    for (i, c) in Category::ALL.iter().enumerate() {
        assert_eq!(*c as usize, i, "{c}");
    }
    let a = accuracy(&[Walk, Walk, Run, Jump], &[Walk, Run, Run, Dance]);
    assert_eq!((a.windows, a.correct), (4, 2));
    assert_eq!(a.overall(), Some(0.5));
    assert_eq!(a.of(Walk), Some(1.0));
    assert_eq!(a.of(Run), Some(0.5));
    assert_eq!(a.of(Dance), Some(0.0));
    assert_eq!(a.of(Jump), None);
    assert_eq!(accuracy(&[], &[]).overall(), None);
    // Sets that differ by a shift of (3, 4): the means are 5 apart, the
    // covariances equal.
    let a: Vec<Vec<f32>> = vec![vec![0.0, 0.0], vec![1.0, 0.0], vec![0.0, 2.0]];
    let b: Vec<Vec<f32>> = a.iter().map(|x| vec![x[0] + 3.0, x[1] + 4.0]).collect();
    assert!((feature_frechet(&a, &b) - 25.0).abs() < 1e-9);
    assert!(feature_frechet(&a, &a).abs() < 1e-9);
}
