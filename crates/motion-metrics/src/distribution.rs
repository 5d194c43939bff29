//! Measures of sets of feature windows: each window's summary, the
//! Fréchet distance between two sets (with its own Jacobi
//! eigen-decomposition), and the spreads within and across windows.

/// The per-window summary the Fréchet distance compares: each feature's mean
/// over the window, then each feature's standard deviation over the window.
pub fn window_summary(window: &[Vec<f32>]) -> Vec<f64> {
    let f = window.first().map_or(0, |r| r.len());
    let n = window.len().max(1) as f64;
    let mut mean = vec![0.0; f];
    for r in window {
        for (m, v) in mean.iter_mut().zip(r) {
            *m += *v as f64 / n;
        }
    }
    let mut std = vec![0.0; f];
    for r in window {
        for ((s, v), m) in std.iter_mut().zip(r).zip(&mean) {
            *s += (*v as f64 - m).powi(2) / n;
        }
    }
    mean.extend(std.into_iter().map(f64::sqrt));
    mean
}

/// The mean and the covariance (n − 1) of a set of vectors.
fn mean_cov(x: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let d = x.first().map_or(0, |r| r.len());
    let n = x.len() as f64;
    let mut mu = vec![0.0; d];
    for r in x {
        for (m, v) in mu.iter_mut().zip(r) {
            *m += v / n;
        }
    }
    let mut cov = vec![vec![0.0; d]; d];
    let denom = (n - 1.0).max(1.0);
    for r in x {
        for i in 0..d {
            let a = r[i] - mu[i];
            for j in 0..d {
                cov[i][j] += a * (r[j] - mu[j]) / denom;
            }
        }
    }
    (mu, cov)
}

/// Eigenvalues and eigenvectors (columns of the second result) of a
/// symmetric matrix, by cyclic Jacobi rotations.
pub fn symmetric_eigen(a: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut a: Vec<Vec<f64>> = a.to_vec();
    let mut v = vec![vec![0.0; n]; n];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let scale: f64 = (0..n).map(|i| a[i][i] * a[i][i]).sum::<f64>().max(1e-300);
        if off <= 1e-24 * scale {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i][i]).collect(), v)
}

/// Symmetric square root of a positive semi-definite matrix (negative
/// eigenvalues from rounding are taken as 0).
fn sqrtm_psd(a: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let (w, v) = symmetric_eigen(a);
    let n = a.len();
    let mut out = vec![vec![0.0; n]; n];
    for k in 0..n {
        let s = w[k].max(0.0).sqrt();
        for i in 0..n {
            for j in 0..n {
                out[i][j] += v[i][k] * s * v[j][k];
            }
        }
    }
    out
}

/// The matrix product `a · b`.
fn matmul(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let (n, m, p) = (a.len(), b.len(), b.first().map_or(0, |r| r.len()));
    let mut c = vec![vec![0.0; p]; n];
    for i in 0..n {
        for k in 0..m {
            let x = a[i][k];
            for j in 0..p {
                c[i][j] += x * b[k][j];
            }
        }
    }
    c
}

/// Fréchet distance between Gaussians fitted to two sets of vectors:
/// `‖μa − μb‖² + tr(Σa + Σb − 2 (Σa^½ Σb Σa^½)^½)`. NaN when a set is
/// empty or the two differ in dimension (no Gaussian to fit, nothing to
/// compare).
pub fn frechet(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let dim = |s: &[Vec<f64>]| s.first().map(Vec::len);
    if a.is_empty() || b.is_empty() || dim(a) != dim(b) {
        return f64::NAN;
    }
    let (ma, ca) = mean_cov(a);
    let (mb, cb) = mean_cov(b);
    let d2: f64 = ma.iter().zip(&mb).map(|(x, y)| (x - y).powi(2)).sum();
    let sa = sqrtm_psd(&ca);
    let inner = matmul(&matmul(&sa, &cb), &sa);
    // Symmetrise against rounding before the eigen-decomposition.
    let n = inner.len();
    let inner: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| 0.5 * (inner[i][j] + inner[j][i])).collect())
        .collect();
    let (w, _) = symmetric_eigen(&inner);
    let tr_sqrt: f64 = w.iter().map(|v| v.max(0.0).sqrt()).sum();
    let tr = |c: &[Vec<f64>]| (0..c.len()).map(|i| c[i][i]).sum::<f64>();
    (d2 + tr(&ca) + tr(&cb) - 2.0 * tr_sqrt).max(0.0)
}

/// Within-window spread of a set of [`window_summary`]s: the mean, over
/// windows and features, of each feature's standard deviation over its
/// window (the second half of a summary). How far a motion moves through
/// the feature space within its window; 0 for an empty set.
pub fn mean_spread(summaries: &[Vec<f64>]) -> f64 {
    let (sum, n) = summaries.iter().fold((0.0, 0usize), |(s, n), r| {
        let half = &r[r.len() / 2..];
        (s + half.iter().sum::<f64>(), n + half.len())
    });
    if n == 0 {
        0.0
    } else {
        sum / n as f64
    }
}

/// Pose spread across windows of a set of [`window_summary`]s: the summed
/// variance over windows (n − 1) of each feature's window mean (the first
/// half of a summary), the trace of their covariance and so that half's
/// share of [`frechet`]'s `tr(Σ)`. How widely the windows' average poses
/// differ from one another; 0 below two windows.
pub fn pose_spread(summaries: &[Vec<f64>]) -> f64 {
    let n = summaries.len();
    if n < 2 {
        return 0.0;
    }
    let d = summaries[0].len() / 2;
    (0..d)
        .map(|j| {
            let mean = summaries.iter().map(|r| r[j]).sum::<f64>() / n as f64;
            let ss: f64 = summaries.iter().map(|r| (r[j] - mean).powi(2)).sum();
            ss / (n - 1) as f64
        })
        .sum()
}

/// Fréchet distances of `real` to subsets of `pool` the size of `real`:
/// `k = ⌊|pool| ÷ |real|⌋` disjoint interleaved subsets (subset `j` takes
/// pool items `j, j + k, j + 2k, …`), so each spreads over the whole pool.
/// A reference of the same sample size as a set of `|real|` generated
/// windows: with few windows in many dimensions the distance grows as the
/// sets shrink, so [`frechet`] against the whole pool is the stricter
/// reference. Empty when the pool has fewer items than `real`.
pub fn frechet_of_subsets(real: &[Vec<f64>], pool: &[Vec<f64>]) -> Vec<f64> {
    let n = real.len();
    if n == 0 {
        return Vec::new();
    }
    let k = pool.len() / n;
    use rayon::prelude::*;
    (0..k)
        .into_par_iter()
        .map(|j| {
            let subset: Vec<Vec<f64>> = pool[j..].iter().step_by(k).take(n).cloned().collect();
            frechet(real, &subset)
        })
        .collect()
}
