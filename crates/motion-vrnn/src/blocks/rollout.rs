//! Scheduled sampling to every depth, fused: the recurrence, the prior, the
//! decoder, the skeleton and the foot lock stepping together over one
//! shard, forward only (no gradient flows through fed-back frames).
//!
//! Per step `t`, with `h`, `c` the LSTM state before it:
//!
//! ```text
//! z_q  = posterior([x''_t, h]) with ε_t            (what the LSTM reads)
//! z_p  = prior(h) with e_t (e_0 itself at t = 0)   (what the own frame is made of)
//! own  = foot_lock(place(filter(decoder(filter(z_p), h))))
//! x̃_t  = x_t + m_t (own − x_t)
//! h, c = LSTM([features(x̃_t), z_q], h, c)
//! ```
//!
//! Its reference is the model's own step loop in candle ops
//! (`Vrnn::fed_in_sequence`), which gives what feed rounds give once there
//! are as many rounds as fed frames; tested against it (`tests/models.rs`).

use super::feet::FootLockOp;
use super::kernels::{mm_rows, mm_small, rm, sigma, simd_fn, tr, Packed};
use super::scan::{activate, cell_rows};
use super::skeleton::place_rows;

/// A dense layer as `nn.Linear` keeps it: `w` is `out × in`, row-major.
#[derive(Clone, Debug)]
pub struct Dense {
    pub w: Vec<f32>,
    pub b: Vec<f32>,
    pub inp: usize,
    pub out: usize,
}

/// The model's weights and settings, as the pass reads them.
#[derive(Clone, Debug)]
pub struct Net {
    pub hidden: usize,
    pub latent: usize,
    /// Features per frame (58).
    pub input: usize,
    /// The feature extractor's two layers (ReLU each).
    pub phi: [Dense; 2],
    /// The posterior `[μ | logit σ]` from `[x'', h]`.
    pub encoder: Dense,
    /// The prior `[μ | logit σ]` from `h`.
    pub prior: Dense,
    /// The decoder's three layers (ReLU, ReLU, none); its output is the
    /// `input` features, then the contact logits where the lock is on.
    pub decoder: [Dense; 3],
    /// The LSTM: `W_ih` (`4H × (E2 + Z)`, gates i, f, g, o), `W_hh`, and
    /// `b_ih + b_hh`.
    pub w_ih: Vec<f32>,
    pub w_hh: Vec<f32>,
    pub b_gates: Vec<f32>,
    /// Poles of the latent and output filters (0: off).
    pub rho: f32,
    pub rho_out: f32,
    /// The foot lock (None: off).
    pub lock: Option<FootLockOp>,
    /// Feature statistics for the skeleton (None: off).
    pub place: Option<(Vec<f32>, Vec<f32>)>,
}

/// The condition's rows (`[n, ·]`, `n` = 1 or the batch): added to the
/// posterior and gates, the prior, and the decoder's first layer.
pub struct Cond<'a> {
    pub pre: &'a [f32],
    pub prior: &'a [f32],
    pub decoder: &'a [f32],
}

/// The shard: `b` sequences of `t` frames, each in the input's order
/// (`[B, T, ·]`).
pub struct Shard<'a> {
    pub b: usize,
    pub t: usize,
    pub x: &'a [f32],
    /// `features(x)`.
    pub feat: &'a [f32],
    /// The posterior's noise and the prior's (at the rollout temperature).
    pub eps: &'a [f32],
    pub e: &'a [f32],
    /// `[B, T]`: 1 where the frame is fed back.
    pub mask: &'a [f32],
    /// `[B, T, 18]` bone lengths (with the skeleton).
    pub lengths: Option<&'a [f32]>,
    pub cond: Option<Cond<'a>>,
}

/// `dst` rows (`n` wide) ← `bias` (+ the condition row of each sequence).
#[inline(always)]
fn fill(dst: &mut [f32], bias: &[f32], cond: Option<(&[f32], usize)>, n: usize) {
    for (s, row) in dst.chunks_exact_mut(n).enumerate() {
        row.copy_from_slice(bias);
        if let Some((c, width)) = cond {
            let r = if c.len() == width { 0 } else { s };
            for (v, a) in row.iter_mut().zip(&c[r * width..r * width + n]) {
                *v += a;
            }
        }
    }
}

/// The columns `from..from + k` of an `out × inp` weight matrix as the
/// right-hand side of a product (`k × out`), packed once for every step.
struct Rhs<'a> {
    w: &'a [f32],
    inp: usize,
    from: usize,
    k: usize,
    n: usize,
    packed: Packed,
}

impl<'a> Rhs<'a> {
    fn new(w: &'a [f32], inp: usize, from: usize, k: usize, n: usize) -> Rhs<'a> {
        let packed = Packed::new(w, tr(from, inp), k, n);
        Rhs {
            w,
            inp,
            from,
            k,
            n,
            packed,
        }
    }

    fn of(d: &'a Dense) -> Rhs<'a> {
        Rhs::new(&d.w, d.inp, 0, d.inp, d.out)
    }

    /// `c += a · self` over `m` rows (`a` rows `k` wide, `c` rows `n`).
    #[inline(always)]
    fn acc(&self, m: usize, c: &mut [f32], a: &[f32]) {
        let (k, n) = (self.k, self.n);
        let (bv, p) = (tr(self.from, self.inp), &self.packed);
        mm_small((m, n, k), c, rm(0, n), true, a, rm(0, k), self.w, bv, p);
    }
}

/// A dense layer over `m` rows: `dst ← relu?(bias (+ cond) + a · Wᵀ)`.
#[inline(always)]
fn layer(
    m: usize,
    dst: &mut [f32],
    a: &[f32],
    l: (&Rhs, &[f32]),
    cond: Option<(&[f32], usize)>,
    relu: bool,
) {
    let n = l.0.n;
    fill(&mut dst[..m * n], l.1, cond, n);
    l.0.acc(m, dst, a);
    if relu {
        dst[..m * n].iter_mut().for_each(|v| *v = v.max(0.0));
    }
}

simd_fn! {
/// The fed-back frames `[B, T, input]` (see the module docs).
pub fn fed(net: &Net, sh: &Shard) -> Vec<f32> {
    let (h, z, f, b, tt) = (net.hidden, net.latent, net.input, sh.b, sh.t);
    let (e2, d, bones) = (net.phi[1].out, &net.decoder, super::skeleton::BONES);
    let (z2, h4, zh, width) = (2 * z, 4 * h, z + h, d[2].out);
    let n = b * tt;
    let enc_in = net.encoder.inp;
    // What does not depend on the recurrence, for all rows: the posterior's
    // and the gates' products with the real frames' features.
    let enc_x = mm_rows((n, z2, e2), sh.feat, &net.encoder.w, tr(0, enc_in), None);
    let gates_x = mm_rows((n, h4, e2), sh.feat, &net.w_ih, tr(0, e2 + z), Some(&net.b_gates));
    // Every product of a step, its weights packed once.
    let enc_h = Rhs::new(&net.encoder.w, enc_in, e2, h, z2);
    let prior = Rhs::of(&net.prior);
    let dec = [Rhs::of(&d[0]), Rhs::of(&d[1]), Rhs::of(&d[2])];
    let phi = [Rhs::of(&net.phi[0]), Rhs::of(&net.phi[1])];
    let gates_fx = Rhs::new(&net.w_ih, e2 + z, 0, e2, h4);
    let gates_z = Rhs::new(&net.w_ih, e2 + z, e2, z, h4);
    let gates_h = Rhs::new(&net.w_hh, h, 0, h, h4);
    // The condition's rows with their widths.
    let (c_pre, c_prior, c_dec) = match &sh.cond {
        Some(c) => (
            Some((c.pre, z2 + h4)),
            Some((c.prior, z2)),
            Some((c.decoder, d[0].out)),
        ),
        None => (None, None, None),
    };
    let gain = |rho: f32| (1.0 - rho * rho).max(0.0).sqrt();
    let (g_in, g_out) = (gain(net.rho), gain(net.rho_out));
    let (mut hs, mut cs, mut tc) = (vec![0.0f32; b * h], vec![0.0f32; b * h], vec![0.0f32; h]);
    let mut cp = vec![0.0f32; h];
    let (mut zf, mut of) = (vec![0.0f32; b * z], vec![0.0f32; b * width]);
    let (mut own, mut prev) = (vec![0.0f32; b * f], vec![0.0f32; b * f]);
    let mut out = vec![0.0f32; n * f];
    let (mut e, mut p) = (vec![0.0f32; b * z2], vec![0.0f32; b * z2]);
    let (mut zq, mut u) = (vec![0.0f32; b * z], vec![0.0f32; b * zh]);
    let (mut a1, mut a2) = (vec![0.0f32; b * d[0].out], vec![0.0f32; b * d[1].out]);
    let (mut o, mut g) = (vec![0.0f32; b * width], vec![0.0f32; b * h4]);
    let (mut fed_rows, mut xf) = (Vec::with_capacity(b), Vec::with_capacity(b * f));
    let (mut q1, mut q2) = (vec![0.0f32; b * net.phi[0].out], vec![0.0f32; b * e2]);
    let (mut gx, mut len) = (vec![0.0f32; b * h4], Vec::with_capacity(b * bones));
    for t in 0..tt {
        let at = |s: usize| s * tt + t;
        // The posterior: e = enc_x + b (+ condition) + h · W_eᵀ; the prior:
        // p = b (+ condition) + h · W_pᵀ.
        fill(&mut e, &net.encoder.b, c_pre, z2);
        for s in 0..b {
            let x = &enc_x[at(s) * z2..(at(s) + 1) * z2];
            e[s * z2..(s + 1) * z2].iter_mut().zip(x).for_each(|(v, a)| *v += a);
        }
        fill(&mut p, &net.prior.b, c_prior, z2);
        if t > 0 {
            enc_h.acc(b, &mut e, &hs);
            prior.acc(b, &mut p, &hs);
        }
        for s in 0..b {
            let (ep, ee) = (&sh.eps[at(s) * z..], &sh.e[at(s) * z..]);
            for k in 0..z {
                let (r, v) = (s * z2 + k, &mut zf[s * z + k]);
                zq[s * z + k] = e[r] + sigma(e[r + z]) * ep[k];
                // The own frame's latent: the prior's draw, filtered.
                let zp = if t == 0 { ee[k] } else { p[r] + sigma(p[r + z]) * ee[k] };
                *v = if t > 0 && net.rho > 0.0 { net.rho * *v + g_in * zp } else { zp };
                u[s * zh + k] = *v;
            }
            u[s * zh + z..(s + 1) * zh].copy_from_slice(&hs[s * h..(s + 1) * h]);
        }
        // The decoder, and its output filter.
        layer(b, &mut a1, &u, (&dec[0], &d[0].b), c_dec, true);
        layer(b, &mut a2, &a1, (&dec[1], &d[1].b), None, true);
        layer(b, &mut o, &a2, (&dec[2], &d[2].b), None, false);
        for (v, a) in of.iter_mut().zip(&o) {
            *v = if t > 0 && net.rho_out > 0.0 { net.rho_out * *v + g_out * a } else { *a };
        }
        // The own frame: the skeleton, then the foot lock against the last.
        for s in 0..b {
            own[s * f..(s + 1) * f].copy_from_slice(&of[s * width..s * width + f]);
        }
        if let (Some((mean, std)), Some(l)) = (&net.place, sh.lengths) {
            len.clear();
            for s in 0..b {
                len.extend_from_slice(&l[at(s) * bones..(at(s) + 1) * bones]);
            }
            own = place_rows(&own, &len, mean, std);
        }
        if let Some(lock) = &net.lock {
            for s in 0..b {
                let logits = &of[s * width + f..s * width + f + 2];
                let row = &mut own[s * f..(s + 1) * f];
                lock.ground_row(row, logits);
                if t > 0 {
                    lock.lock_row(&prev[s * f..(s + 1) * f], row, logits);
                }
            }
        }
        // The frame the recurrence reads: the own one where fed.
        fed_rows.clear();
        for s in 0..b {
            let m = sh.mask[at(s)];
            let (x, dst) = (&sh.x[at(s) * f..], &mut out[at(s) * f..(at(s) + 1) * f]);
            for ((d, &xv), &ov) in dst.iter_mut().zip(x).zip(&own[s * f..(s + 1) * f]) {
                *d = xv + (ov - xv) * m;
            }
            g[s * h4..(s + 1) * h4].copy_from_slice(&gates_x[at(s) * h4..(at(s) + 1) * h4]);
            if m != 0.0 {
                fed_rows.push(s);
            }
        }
        // The fed frames' features and their share of the gates.
        let k = fed_rows.len();
        if k > 0 {
            xf.clear();
            for &s in &fed_rows {
                xf.extend_from_slice(&out[at(s) * f..(at(s) + 1) * f]);
            }
            layer(k, &mut q1, &xf, (&phi[0], &net.phi[0].b), None, true);
            layer(k, &mut q2, &q1, (&phi[1], &net.phi[1].b), None, true);
            layer(k, &mut gx, &q2, (&gates_fx, &net.b_gates), None, false);
            for (i, &s) in fed_rows.iter().enumerate() {
                g[s * h4..(s + 1) * h4].copy_from_slice(&gx[i * h4..(i + 1) * h4]);
            }
        }
        // The gates: + condition + z · W_zᵀ + h · W_hᵀ, then the cell.
        if let Some((c, w)) = c_pre {
            for s in 0..b {
                let r = if c.len() == w { 0 } else { s };
                let row = &c[r * w + z2..(r + 1) * w];
                g[s * h4..(s + 1) * h4].iter_mut().zip(row).for_each(|(v, a)| *v += a);
            }
        }
        gates_z.acc(b, &mut g, &zq);
        if t > 0 {
            gates_h.acc(b, &mut g, &hs);
        }
        for s in 0..b {
            let gr = &mut g[s * h4..(s + 1) * h4];
            activate(gr, h);
            cp.copy_from_slice(&cs[s * h..(s + 1) * h]);
            cell_rows(gr, &cp, &mut cs[s * h..(s + 1) * h], &mut tc, h);
            for k in 0..h {
                hs[s * h + k] = gr[3 * h + k] * tc[k];
            }
        }
        std::mem::swap(&mut prev, &mut own);
    }
    out
}
}
