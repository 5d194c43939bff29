//! A classifier two-sample test: how well a small classifier tells two sets
//! of windows apart on held-out windows (0.5: not at all; 1: always).
//!
//! Each window is summarised by [`window_features`] (per feature: mean,
//! standard deviation, mean absolute step and mean absolute second step, so
//! pose, root motion and jitter all show); a logistic regression on the
//! standardised summaries is trained on all folds but one and scored on the
//! one left out, with windows of one group (a take, or a generated motion)
//! always in the same fold, so overlapping windows never sit on both sides
//! (`docs/metrics.md`, "Realism"). The score is the balanced accuracy (the
//! mean of the two classes' recalls), averaged over the folds. Everything
//! runs on one thread in a fixed order: the same inputs give the same bits.

/// Folds of the cross-validation.
pub const FOLDS: usize = 5;

/// Full-batch gradient steps of the logistic regression.
const STEPS: usize = 300;

/// Its learning rate (on standardised summaries, balanced class weights).
const RATE: f64 = 0.5;

/// Its L2 penalty on the weights.
const L2: f64 = 1e-3;

/// Summary of one window `x: [T × features]` (row-major): per feature, its
/// mean, standard deviation, mean absolute step `|x_t − x_{t−1}|` and mean
/// absolute second step `|x_t − 2x_{t−1} + x_{t−2}|`, `4 × features` values.
pub fn window_features(x: &[f32], features: usize) -> Vec<f64> {
    let t = x.len() / features.max(1);
    let at = |i: usize, f: usize| x[i * features + f] as f64;
    let mut out = Vec::with_capacity(4 * features);
    for f in 0..features {
        let mean = (0..t).map(|i| at(i, f)).sum::<f64>() / t.max(1) as f64;
        let var = (0..t).map(|i| (at(i, f) - mean).powi(2)).sum::<f64>() / t.max(1) as f64;
        let step = (1..t).map(|i| (at(i, f) - at(i - 1, f)).abs()).sum::<f64>()
            / t.saturating_sub(1).max(1) as f64;
        let accel = (2..t)
            .map(|i| (at(i, f) - 2.0 * at(i - 1, f) + at(i - 2, f)).abs())
            .sum::<f64>()
            / t.saturating_sub(2).max(1) as f64;
        out.extend([mean, var.sqrt(), step, accel]);
    }
    out
}

/// The fold of group `g` under `seed` (a fixed hash: splitmix64).
fn fold_of(g: u64, seed: u64) -> usize {
    let mut z = g ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) % FOLDS as u64) as usize
}

/// A logistic regression trained on `x` (rows) with labels `y`, each class
/// weighed by the inverse of its size: weights then bias.
fn fit(x: &[&[f64]], y: &[bool]) -> Vec<f64> {
    let d = x.first().map_or(0, |r| r.len());
    let pos = y.iter().filter(|&&v| v).count().max(1) as f64;
    let neg = (y.len() as f64 - pos).max(1.0);
    let weight = |label: bool| if label { 0.5 / pos } else { 0.5 / neg };
    let mut w = vec![0.0; d + 1];
    let mut grad = vec![0.0; d + 1];
    for _ in 0..STEPS {
        grad.iter_mut().for_each(|g| *g = 0.0);
        for (row, &label) in x.iter().zip(y) {
            let z = w[d] + row.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
            let p = 1.0 / (1.0 + (-z).exp());
            let e = weight(label) * (p - f64::from(u8::from(label)));
            for (g, a) in grad.iter_mut().zip(row.iter()) {
                *g += e * a;
            }
            grad[d] += e;
        }
        for k in 0..d {
            w[k] -= RATE * (grad[k] + L2 * w[k]);
        }
        w[d] -= RATE * grad[d];
    }
    w
}

/// The held-out balanced accuracy of telling the windows `a` (summaries,
/// [`window_features`], each with its group in `a_groups`) from `b`,
/// [`FOLDS`]-fold cross-validated by group, folds drawn with `seed`; None
/// when a fold would leave a class out of training or testing.
pub fn accuracy(
    a: &[Vec<f64>],
    a_groups: &[u64],
    b: &[Vec<f64>],
    b_groups: &[u64],
    seed: u64,
) -> Option<f64> {
    // `b`'s groups are told apart from `a`'s by their high bit.
    let rows: Vec<(&[f64], bool, usize)> = a
        .iter()
        .zip(a_groups)
        .map(|(r, &g)| (r.as_slice(), true, fold_of(g, seed)))
        .chain(
            b.iter()
                .zip(b_groups)
                .map(|(r, &g)| (r.as_slice(), false, fold_of(g | 1 << 63, seed))),
        )
        .collect();
    let d = rows.first()?.0.len();
    let mut scores = Vec::with_capacity(FOLDS);
    for k in 0..FOLDS {
        let (train, test): (Vec<_>, Vec<_>) = rows.iter().partition(|r| r.2 != k);
        let has_both =
            |set: &[&(&[f64], bool, usize)]| set.iter().any(|r| r.1) && set.iter().any(|r| !r.1);
        if !has_both(&train) || !has_both(&test) {
            return None;
        }
        // Standardised with the training fold's mean and spread.
        let n = train.len() as f64;
        let mean: Vec<f64> = (0..d)
            .map(|j| train.iter().map(|r| r.0[j]).sum::<f64>() / n)
            .collect();
        let sd: Vec<f64> = (0..d)
            .map(|j| {
                let v = train
                    .iter()
                    .map(|r| (r.0[j] - mean[j]).powi(2))
                    .sum::<f64>()
                    / n;
                v.sqrt().max(1e-9)
            })
            .collect();
        let scale = |r: &[f64]| -> Vec<f64> {
            r.iter()
                .zip(&mean)
                .zip(&sd)
                .map(|((v, m), s)| (v - m) / s)
                .collect()
        };
        let xs: Vec<Vec<f64>> = train.iter().map(|r| scale(r.0)).collect();
        let refs: Vec<&[f64]> = xs.iter().map(Vec::as_slice).collect();
        let ys: Vec<bool> = train.iter().map(|r| r.1).collect();
        let w = fit(&refs, &ys);
        let (mut hit, mut count) = ([0usize; 2], [0usize; 2]);
        for r in &test {
            let x = scale(r.0);
            let z = w[d] + x.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
            let c = usize::from(r.1);
            count[c] += 1;
            hit[c] += usize::from((z > 0.0) == r.1);
        }
        scores.push(0.5 * (hit[0] as f64 / count[0] as f64 + hit[1] as f64 / count[1] as f64));
    }
    Some(scores.iter().sum::<f64>() / scores.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_is_mean_spread_step_and_second_step() {
        // One feature over four frames: 0, 1, 3, 6.
        let s = window_features(&[0.0, 1.0, 3.0, 6.0], 1);
        assert_eq!(s[0], 2.5);
        assert!((s[1] - 5.25f64.sqrt()).abs() < 1e-12);
        assert_eq!(s[2], 2.0); // steps 1, 2, 3
        assert_eq!(s[3], 1.0); // second steps 1, 1
    }

    /// Points on a line, `n` per group, shifted by `shift`.
    fn set(n: usize, groups: u64, shift: f64, seed: u64) -> (Vec<Vec<f64>>, Vec<u64>) {
        let mut state = seed;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        (0..groups * n as u64)
            .map(|i| (vec![next() + shift, next()], i / n as u64))
            .unzip()
    }

    #[test]
    fn apart_sets_are_told_apart_and_alike_sets_are_not() {
        let (a, ga) = set(3, 60, 0.0, 1);
        let (b, gb) = set(3, 60, 2.0, 2);
        assert_eq!(accuracy(&a, &ga, &b, &gb, 0), Some(1.0));
        let (c, gc) = set(3, 60, 0.0, 3);
        let same = accuracy(&a, &ga, &c, &gc, 0).unwrap();
        assert!((0.35..0.65).contains(&same), "{same}");
        // The same inputs, the same bits; too few groups: no answer.
        assert_eq!(accuracy(&a, &ga, &c, &gc, 0), Some(same));
        assert_eq!(accuracy(&a[..3], &ga[..3], &b, &gb, 0), None);
    }
}
