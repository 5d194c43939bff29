//! A small seeded RNG (SplitMix64) so every random number of a run follows
//! from explicit seeds, independent of crate versions and thread counts.

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
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
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
                for v in piece {
                    *v = r.normal() as f32;
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
