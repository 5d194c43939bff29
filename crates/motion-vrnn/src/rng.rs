//! A small seeded RNG (SplitMix64) so every random number of a run follows
//! from explicit seeds, independent of crate versions and thread counts.

use crate::blocks::kernels::simd_fn;

/// SplitMix64.
#[derive(Clone, Debug)]
pub struct Rng(u64);

/// SplitMix64's increment: after `k` draws the state has moved by `k·GAMMA`.
const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// Normals per piece of [`Rng::normals`].
const NORMALS_PIECE: usize = 1 << 13;

impl Rng {
    /// A generator for `seed` and a `stream` (e.g. epoch or step number).
    pub fn new(seed: u64, stream: u64) -> Rng {
        let mut r = Rng(seed ^ stream.wrapping_mul(GAMMA));
        r.next_u64();
        r
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GAMMA);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        box_muller(u1, u2)
    }

    /// `n` standard normals as `f32`: the next `n` values of [`Rng::normal`],
    /// computed in pieces on rayon's threads. Each normal takes two draws
    /// and SplitMix64's state after `k` draws is the start plus `k·GAMMA`,
    /// so every piece starts where the sequence would be: the same numbers
    /// as one after the other (tested), and the generator ends where they
    /// would leave it.
    pub fn normals(&mut self, n: usize) -> Vec<f32> {
        use rayon::prelude::*;
        let start = self.0;
        let mut out = vec![0.0f32; n];
        out.par_chunks_mut(NORMALS_PIECE)
            .enumerate()
            .for_each(|(i, piece)| {
                let draws = 2 * (i * NORMALS_PIECE) as u64;
                let mut r = Rng(start.wrapping_add(GAMMA.wrapping_mul(draws)));
                let (mut u1, mut u2) = ([0.0; LANES], [0.0; LANES]);
                for block in piece.chunks_mut(LANES) {
                    let k = block.len();
                    for (a, b) in u1[..k].iter_mut().zip(&mut u2[..k]) {
                        *a = 1.0 - r.uniform();
                        *b = r.uniform();
                    }
                    box_muller_f32(&u1[..k], &u2[..k], block);
                }
            });
        self.0 = start.wrapping_add(GAMMA.wrapping_mul(2 * n as u64));
        out
    }

    /// A uniformly random permutation of `0..n` (Fisher–Yates).
    pub fn permutation(&mut self, n: usize) -> Vec<usize> {
        let mut p: Vec<usize> = (0..n).collect();
        for i in (1..n).rev() {
            let j = (self.next_u64() % (i as u64 + 1)) as usize;
            p.swap(i, j);
        }
        p
    }
}

/// Normals per block of [`box_muller_f32`].
const LANES: usize = 64;

/// The Box–Muller normal of `u1 ∈ (0, 1]` and `u2 ∈ [0, 1)` as libm computes
/// it: the definition every faster path must match to the bit.
#[inline]
fn box_muller(u1: f64, u2: f64) -> f64 {
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

simd_fn! {
/// `box_muller(u1[i], u2[i]) as f32` for every `i`, the same bits, without a
/// libm call for almost all of them, so the loop vectorises.
///
/// `ln` and `cos` come from polynomials ([`ln_near`], [`cos_near`]), each
/// within about 2⁻⁵⁰ of libm's result (libm's own error is under one ulp,
/// 2⁻⁵³). Their product `y` is then within `e = (r + |y|)·2⁻⁴⁶` of libm's
/// product, a bound over twenty times the error. Where `y − e` and
/// `y + e` round to the same `f32`, so does libm's product (rounding is
/// monotonic) and `y` is used; elsewhere, about 4 values in a million
/// (within `e` of the midpoint between two `f32`s, or `y = 0`, whose sign
/// matters), libm's `box_muller` computes it. Tested against `box_muller`
/// on 2²⁴ draws and on the edges of both ranges.
fn box_muller_f32(u1: &[f64], u2: &[f64], out: &mut [f32]) -> () {
    let (mut a, mut b) = ([1.0; LANES], [0.0; LANES]);
    let (mut y, mut ok) = ([0.0f32; LANES], [false; LANES]);
    for ((out, u1), u2) in out.chunks_mut(LANES).zip(u1.chunks(LANES)).zip(u2.chunks(LANES)) {
        // Whole blocks, so the loop below has a fixed length and
        // vectorises; lanes past the slices' end are computed and dropped.
        a[..u1.len()].copy_from_slice(u1);
        b[..u2.len()].copy_from_slice(u2);
        for i in 0..LANES {
            let r = (-2.0 * ln_near(a[i])).sqrt();
            let v = r * cos_near(std::f64::consts::TAU * b[i]);
            let e = (r + v.abs()) * f64::from_bits(0x3D10_0000_0000_0000); // 2⁻⁴⁶
            let (lo, hi) = ((v - e) as f32, (v + e) as f32);
            ok[i] = lo.to_bits() == hi.to_bits() && v != 0.0;
            y[i] = v as f32;
        }
        for (i, o) in out.iter_mut().enumerate() {
            *o = if ok[i] { y[i] } else { box_muller(u1[i], u2[i]) as f32 };
        }
    }
}
}

/// `ln u` for a normal positive `u`, within a few ulps: `u = m·2ᵉ` with
/// `m ∈ [√½, √2)`, `ln m = 2·atanh s`, `s = (m − 1)/(m + 1)`, `|s| ≤ 0.172`,
/// the series to `s²¹` (the next term is under 2⁻⁵⁶ of the sum), and `e·ln 2`
/// in two parts so that `e·ln2_hi` is exact (fdlibm's split).
#[inline(always)]
fn ln_near(u: f64) -> f64 {
    const LN2_HI: f64 = f64::from_bits(0x3FE6_2E42_FEE0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3DEA_39EF_3579_3C76);
    let bits = u.to_bits();
    let m = f64::from_bits((bits & 0x000F_FFFF_FFFF_FFFF) | 0x3FF0_0000_0000_0000);
    let big = m > std::f64::consts::SQRT_2;
    let m = if big { 0.5 * m } else { m };
    // The exponent as a float without an integer conversion: its biased
    // field in the low bits of 2⁵², minus 2⁵² and the bias.
    let field = (bits >> 52) + big as u64;
    let e = f64::from_bits(0x4330_0000_0000_0000 | field) - (4_503_599_627_370_496.0 + 1023.0);
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    const P: [f64; 10] = [
        1.0 / 3.0,
        1.0 / 5.0,
        1.0 / 7.0,
        1.0 / 9.0,
        1.0 / 11.0,
        1.0 / 13.0,
        1.0 / 15.0,
        1.0 / 17.0,
        1.0 / 19.0,
        1.0 / 21.0,
    ];
    let mut p = P[9];
    for k in (0..9).rev() {
        p = p * s2 + P[k];
    }
    let p = p * s2 + 1.0;
    e * LN2_HI + (e * LN2_LO + 2.0 * s * p)
}

/// `cos x` for `x ∈ [0, 2π]`, within about 2⁻⁵¹: `x = q·π/2 + y` with
/// `|y| ≤ π/4` (π/2 in two parts, fdlibm's `pio2_1` and `pio2_1t`, so that
/// `q·pio2_1` is exact), then the Taylor series of `cos y` to `y¹⁶` or of
/// `sin y` to `y¹⁷` (the next terms are under 2⁻⁵⁸) by the quadrant `q mod 4`.
#[inline(always)]
fn cos_near(x: f64) -> f64 {
    const PIO2_1: f64 = f64::from_bits(0x3FF9_21FB_5440_0000);
    const PIO2_1T: f64 = f64::from_bits(0x3DD0_B461_1A62_6331);
    // Round to the nearest integer with 1.5·2⁵²; the quadrant is in the
    // low bits of the sum.
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    let t = x * std::f64::consts::FRAC_2_PI + MAGIC;
    let quadrant = t.to_bits() & 3;
    let q = t - MAGIC;
    let y = (x - q * PIO2_1) - q * PIO2_1T;
    let y2 = y * y;
    // 1/k! for the even and the odd k.
    const C: [f64; 8] = [
        -1.0 / 2.0,
        1.0 / 24.0,
        -1.0 / 720.0,
        1.0 / 40_320.0,
        -1.0 / 3_628_800.0,
        1.0 / 479_001_600.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 20_922_789_888_000.0,
    ];
    const S: [f64; 8] = [
        -1.0 / 6.0,
        1.0 / 120.0,
        -1.0 / 5_040.0,
        1.0 / 362_880.0,
        -1.0 / 39_916_800.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 1_307_674_368_000.0,
        1.0 / 355_687_428_096_000.0,
    ];
    let (mut c, mut s) = (C[7], S[7]);
    for k in (0..7).rev() {
        c = c * y2 + C[k];
        s = s * y2 + S[k];
    }
    let c = c * y2 + 1.0;
    let s = y + y * (s * y2);
    // Quadrants 0 to 3: cos y, −sin y, −cos y, sin y.
    let v = if quadrant & 1 == 0 { c } else { s };
    if (quadrant + 1) & 2 == 0 {
        v
    } else {
        -v
    }
}

/// Reparameterisation noise of global step `step`: `[T, B, latent]`.
pub fn noise(
    seed: u64,
    step: u64,
    t: usize,
    b: usize,
    latent: usize,
    device: &candle_core::Device,
) -> candle_core::Result<candle_core::Tensor> {
    let v = Rng::new(seed ^ 0x5EED_0000_0000, step).normals(t * b * latent);
    candle_core::Tensor::from_vec(v, (t, b, latent), device)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The normals computed in pieces are those of one `normal()` after
    /// another, and leave the generator where those leave it.
    #[test]
    fn normals_in_pieces_are_the_sequence() {
        for n in [
            0,
            1,
            5,
            NORMALS_PIECE - 1,
            NORMALS_PIECE,
            3 * NORMALS_PIECE + 17,
        ] {
            let (mut a, mut b) = (Rng::new(3, 4), Rng::new(3, 4));
            let got = a.normals(n);
            let want: Vec<f32> = (0..n).map(|_| b.normal() as f32).collect();
            assert!(got
                .iter()
                .zip(&want)
                .all(|(g, w)| g.to_bits() == w.to_bits()));
            assert_eq!(got.len(), want.len());
            assert_eq!(a.next_u64(), b.next_u64(), "state after {n} normals");
        }
    }

    /// The vectorised Box–Muller gives libm's bits: on 2²⁴ draws, and on the
    /// edges of both uniforms' ranges (1 and 2⁻⁵³ for `u1`, where `ln` is 0
    /// and largest; the quadrants' edges for `u2`, where `cos` is 0 or ±1).
    #[test]
    fn vectorised_box_muller_gives_libms_bits() {
        let ulp = f64::EPSILON / 2.0;
        let mut u1s = vec![1.0, 1.0 - ulp, ulp, 2.0 * ulp, 0.5, 0.25, 1e-300];
        let mut u2s = vec![0.0, 1.0 - ulp, 0.5, 1.0 / 3.0];
        for q in [0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875] {
            let x: f64 = q;
            u2s.extend([
                x,
                f64::from_bits(x.to_bits() - 1),
                f64::from_bits(x.to_bits() + 1),
            ]);
        }
        for m in [
            std::f64::consts::FRAC_1_SQRT_2,
            0.5 * std::f64::consts::SQRT_2,
            0.999,
            0.7,
        ] {
            u1s.extend([
                m,
                f64::from_bits(m.to_bits() - 1),
                f64::from_bits(m.to_bits() + 1),
            ]);
        }
        let mut r = Rng::new(11, 0);
        u1s.extend((0..200).map(|_| 1.0 - r.uniform()));
        u2s.extend((0..200).map(|_| r.uniform()));
        for &a in &u1s {
            let u1 = vec![a; u2s.len()];
            let mut got = vec![0.0f32; u2s.len()];
            box_muller_f32(&u1, &u2s, &mut got);
            for (&b, g) in u2s.iter().zip(&got) {
                let want = box_muller(a, b) as f32;
                assert_eq!(
                    g.to_bits(),
                    want.to_bits(),
                    "u1 {a:e}, u2 {b:e}: {g} vs {want}"
                );
            }
        }
        let (mut a, mut b) = (Rng::new(5, 9), Rng::new(5, 9));
        let got = a.normals(1 << 24);
        let bad = got
            .iter()
            .filter(|g| g.to_bits() != (b.normal() as f32).to_bits())
            .count();
        assert_eq!(bad, 0);
    }

    /// The polynomials are within 2⁻⁴⁹ of libm (`ln` relative, `cos`
    /// absolute), eight times inside the bound `box_muller_f32` relies on.
    #[test]
    fn polynomials_are_near_libm() {
        let mut r = Rng::new(2, 3);
        let (mut worst_ln, mut worst_cos) = (0.0f64, 0.0f64);
        for i in 0..1_000_000 {
            // u1 over many octaves: uniform, and 2^-k·uniform.
            let u = (1.0 - r.uniform()) * 0.5f64.powi(i % 60);
            worst_ln = worst_ln.max(((ln_near(u) - u.ln()) / u.ln()).abs());
            let x = std::f64::consts::TAU * r.uniform();
            worst_cos = worst_cos.max((cos_near(x) - x.cos()).abs());
        }
        let bound = 0.5f64.powi(49);
        assert!(
            worst_ln < bound && worst_cos < bound,
            "ln {worst_ln:e}, cos {worst_cos:e}"
        );
    }

    #[test]
    fn streams_are_reproducible_and_distinct() {
        assert_eq!(Rng::new(1, 2).next_u64(), Rng::new(1, 2).next_u64());
        assert_ne!(Rng::new(1, 2).next_u64(), Rng::new(1, 3).next_u64());
        let mut r = Rng::new(7, 0);
        let xs = r.normals(20_000);
        let mean = xs.iter().map(|&x| x as f64).sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(
            mean.abs() < 0.03 && (var - 1.0).abs() < 0.05,
            "{mean} {var}"
        );
        let mut p = Rng::new(3, 0).permutation(100);
        p.sort();
        assert_eq!(p, (0..100).collect::<Vec<_>>());
    }
}
