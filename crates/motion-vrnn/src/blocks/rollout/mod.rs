//! Scheduled sampling to every depth, fused: the recurrence, the prior, the
//! decoder, the skeleton and the foot lock stepping together over one
//! shard. [`fed`] runs it forward only (no gradient flows through the
//! fed-back frames, the default); [`RolloutOp`] keeps a tape ([`pass`]) and
//! has its own backward ([`fed_backward`]: back through every step, the
//! gradients of the real frames' features, every weight and the
//! condition's rows), for `Parts::rollout_gradient`. The op also gives the
//! recurrence that read the fed frames, what the loss reads, so it runs
//! once.
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
//! are as many rounds as fed frames; the pass and its backward are tested
//! against it and candle's autograd through it (`tests/models.rs`).

use super::feet::{FootLockOp, Grounded, Locked};
use super::kernels::{mm_rows, mm_small, rm, sigma, simd_fn, tr, Packed, V};
use super::scan::{activate, cell_rows};
use super::skeleton::{place_rows, PlaceOp};

mod backward;

pub use backward::{fed_backward, Grads};

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
    /// The skeleton, with the feature statistics (None: off).
    pub place: Option<PlaceOp>,
}

/// The condition's rows, each `pre | prior | decoder` (the widths of
/// [`Cond::widths`]): one row for all, one per sequence (`[B, ·]`), or one
/// per sequence and step (`[B, T, ·]`). They are added to the posterior and
/// gates, the prior, and the decoder's first layer.
pub struct Cond<'a> {
    pub rows: &'a [f32],
    pub widths: [usize; 3],
}

/// Which part of a condition row (the order of [`Cond::widths`]).
#[derive(Clone, Copy)]
pub(super) enum Part {
    Pre = 0,
    Prior = 1,
    Decoder = 2,
}

impl Cond<'_> {
    /// Where `part` of the row of sequence `s` (of `b`) at step `t` starts
    /// in [`Cond::rows`] (and in its gradient, laid out alike).
    #[inline(always)]
    pub(super) fn at(&self, part: Part, b: usize, s: usize, t: usize) -> usize {
        let [pre, prior, _] = self.widths;
        let w = self.widths.iter().sum();
        let off = match part {
            Part::Pre => 0,
            Part::Prior => pre,
            Part::Decoder => pre + prior,
        };
        cond_at(self.rows.len(), w, b, s, t) + off
    }
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

/// Where the condition row of sequence `s` (of `b`) at step `t` starts in
/// a slice `len` long of rows `w` wide: one row for all, one per sequence
/// (`[B, ·]`), or one per sequence and step (`[B, T, ·]`, a model with the
/// control).
#[inline(always)]
pub(super) fn cond_at(len: usize, w: usize, b: usize, s: usize, t: usize) -> usize {
    if len == w {
        0
    } else if len == b * w {
        s * w
    } else {
        (s * (len / (b * w)) + t) * w
    }
}

/// `dst` rows (`n` wide, one per sequence) ← `bias` (+ each sequence's
/// condition row's `part` at step `t`).
#[inline(always)]
fn fill(dst: &mut [f32], bias: &[f32], cond: Option<(&Cond, Part)>, n: usize, t: usize) {
    let b = dst.len() / n.max(1);
    for (s, row) in dst.chunks_exact_mut(n).enumerate() {
        row.copy_from_slice(bias);
        if let Some((c, part)) = cond {
            let at = c.at(part, b, s, t);
            for (v, a) in row.iter_mut().zip(&c.rows[at..at + n]) {
                *v += a;
            }
        }
    }
}

/// Columns of an `out × inp` weight matrix `W` as the right-hand side of
/// a product over the rows of a step, packed once for every step: `Wᵀ`'s
/// (a layer's forward, [`Rhs::new`]) or `W`'s own (its backward,
/// [`Rhs::back`]), `k × n` either way.
struct Rhs<'a> {
    w: &'a [f32],
    bv: V,
    k: usize,
    n: usize,
    packed: Packed,
}

impl<'a> Rhs<'a> {
    /// `W[:, from..from + k]ᵀ` (`k × out`, `n = out`): a layer's forward
    /// from `k` of its inputs.
    fn new(w: &'a [f32], inp: usize, from: usize, k: usize, n: usize) -> Rhs<'a> {
        Rhs::view(w, tr(from, inp), k, n)
    }

    /// `W[:, from..from + n]` (`out × n`, `k = out`): a layer's backward
    /// into `n` of its inputs (its weights' gradients are taken over all
    /// rows at the end, [`weight_grad`]).
    fn back(w: &'a [f32], inp: usize, from: usize, out: usize, n: usize) -> Rhs<'a> {
        Rhs::view(w, rm(from, inp), out, n)
    }

    fn view(w: &'a [f32], bv: V, k: usize, n: usize) -> Rhs<'a> {
        let packed = Packed::new(w, bv, k, n);
        Rhs {
            w,
            bv,
            k,
            n,
            packed,
        }
    }

    fn of(d: &'a Dense) -> Rhs<'a> {
        Rhs::new(&d.w, d.inp, 0, d.inp, d.out)
    }

    fn back_of(d: &'a Dense) -> Rhs<'a> {
        Rhs::back(&d.w, d.inp, 0, d.out, d.inp)
    }

    /// `c += a · self` over `m` rows (`a` rows `k` wide, `c` rows `n`).
    #[inline(always)]
    fn acc(&self, m: usize, c: &mut [f32], a: &[f32]) {
        self.rows(m, c, rm(0, self.n), true, a);
    }

    /// `c (+)= a · self` over `m` rows of `a` (`k` wide, contiguous); `c`'s
    /// rows are `cv` (row-major, any stride).
    #[inline(always)]
    fn rows(&self, m: usize, c: &mut [f32], cv: V, acc: bool, a: &[f32]) {
        let (k, n, p) = (self.k, self.n, &self.packed);
        mm_small((m, n, k), c, cv, acc, a, rm(0, k), self.w, self.bv, p);
    }
}

/// A dense layer over `m` rows: `dst ← relu?(bias (+ cond) + a · Wᵀ)`.
#[inline(always)]
fn layer(
    m: usize,
    dst: &mut [f32],
    a: &[f32],
    l: (&Rhs, &[f32]),
    cond: Option<(&Cond, Part, usize)>,
    relu: bool,
) {
    let n = l.0.n;
    match cond {
        Some((c, part, t)) => fill(&mut dst[..m * n], l.1, Some((c, part)), n, t),
        None => fill(&mut dst[..m * n], l.1, None, n, 0),
    }
    l.0.acc(m, dst, a);
    if relu {
        dst[..m * n].iter_mut().for_each(|v| *v = v.max(0.0));
    }
}

/// The fed-back frames `[B, T, input]` (see the module docs).
pub fn fed(net: &Net, sh: &Shard) -> Vec<f32> {
    pass(net, sh, None)
}

/// What [`pass`] keeps for [`fed_backward`], per row `t·B + s` (time-major).
#[derive(Default)]
pub struct Tape {
    /// The state `h`, `c` before the step.
    h: Vec<f32>,
    c: Vec<f32>,
    /// `μ` of the posterior; `σ` of the posterior and of the prior.
    mu: Vec<f32>,
    sq: Vec<f32>,
    sp: Vec<f32>,
    /// The posterior's draw, and the own frame's latent (filtered).
    zq: Vec<f32>,
    zf: Vec<f32>,
    /// The decoder's hidden layers (after the ReLU) and its filtered output.
    a1: Vec<f32>,
    a2: Vec<f32>,
    of: Vec<f32>,
    ground: Vec<Grounded>,
    lock: Vec<Option<Locked>>,
    /// The feature extractor's layers on the fed frames (zero elsewhere).
    q1: Vec<f32>,
    q2: Vec<f32>,
    /// The activated gates and `tanh c` after the step.
    g: Vec<f32>,
    tc: Vec<f32>,
}

impl Tape {
    /// A tape for `n` rows of `net`'s pass, zeroed.
    fn sized(net: &Net, n: usize) -> Tape {
        let (h, z, d) = (net.hidden, net.latent, &net.decoder);
        let sized = |w: usize| vec![0.0f32; n * w];
        Tape {
            h: sized(h),
            c: sized(h),
            mu: sized(z),
            sq: sized(z),
            sp: sized(z),
            zq: sized(z),
            zf: sized(z),
            a1: sized(d[0].out),
            a2: sized(d[1].out),
            of: sized(d[2].out),
            ground: Vec::with_capacity(n),
            lock: Vec::with_capacity(n),
            q1: sized(net.phi[0].out),
            q2: sized(net.phi[1].out),
            g: sized(4 * h),
            tc: sized(h),
        }
    }
}

/// The sizes [`pass`] reads, and the filters' gains.
#[derive(Clone, Copy)]
struct Sizes {
    h: usize,
    z: usize,
    f: usize,
    b: usize,
    tt: usize,
    e2: usize,
    bones: usize,
    z2: usize,
    h4: usize,
    zh: usize,
    width: usize,
    g_in: f32,
    g_out: f32,
}

/// What [`pass`] reads and carries from step to step.
struct Fwd<'a> {
    net: &'a Net,
    sh: &'a Shard<'a>,
    tape: Option<&'a mut Tape>,
    sizes: Sizes,
    /// What does not depend on the recurrence, for all rows: the
    /// posterior's and the gates' products with the real frames' features.
    enc_x: Vec<f32>,
    gates_x: Vec<f32>,
    /// Every product of a step, its weights packed once.
    enc_h: Rhs<'a>,
    prior: Rhs<'a>,
    dec: [Rhs<'a>; 3],
    phi: [Rhs<'a>; 2],
    gates_fx: Rhs<'a>,
    gates_z: Rhs<'a>,
    gates_h: Rhs<'a>,
    /// The state, the filters' last values, the own frame and the last one,
    /// the fed frames, and the step's layers.
    hs: Vec<f32>,
    cs: Vec<f32>,
    tc: Vec<f32>,
    cp: Vec<f32>,
    zf: Vec<f32>,
    of: Vec<f32>,
    own: Vec<f32>,
    prev: Vec<f32>,
    out: Vec<f32>,
    e: Vec<f32>,
    p: Vec<f32>,
    zq: Vec<f32>,
    u: Vec<f32>,
    a1: Vec<f32>,
    a2: Vec<f32>,
    o: Vec<f32>,
    g: Vec<f32>,
    fed_rows: Vec<usize>,
    xf: Vec<f32>,
    q1: Vec<f32>,
    q2: Vec<f32>,
    gx: Vec<f32>,
    len: Vec<f32>,
}

impl<'a> Fwd<'a> {
    /// The products that do not depend on the recurrence, the packed
    /// weights, zeroed buffers, and `tape` sized for every row.
    #[inline(always)]
    fn new(net: &'a Net, sh: &'a Shard<'a>, tape: Option<&'a mut Tape>) -> Fwd<'a> {
        let (h, z, f, b, tt) = (net.hidden, net.latent, net.input, sh.b, sh.t);
        let (e2, d, bones) = (net.phi[1].out, &net.decoder, super::skeleton::BONES);
        let (z2, h4, zh, width) = (2 * z, 4 * h, z + h, d[2].out);
        let n = b * tt;
        let enc_in = net.encoder.inp;
        let enc_x = mm_rows((n, z2, e2), sh.feat, &net.encoder.w, tr(0, enc_in), None);
        let gates_x = mm_rows(
            (n, h4, e2),
            sh.feat,
            &net.w_ih,
            tr(0, e2 + z),
            Some(&net.b_gates),
        );
        let gain = |rho: f32| (1.0 - rho * rho).max(0.0).sqrt();
        let (g_in, g_out) = (gain(net.rho), gain(net.rho_out));
        let mut tape = tape;
        if let Some(k) = tape.as_deref_mut() {
            *k = Tape::sized(net, n);
        }
        Fwd {
            net,
            sh,
            tape,
            sizes: Sizes {
                h,
                z,
                f,
                b,
                tt,
                e2,
                bones,
                z2,
                h4,
                zh,
                width,
                g_in,
                g_out,
            },
            enc_x,
            gates_x,
            enc_h: Rhs::new(&net.encoder.w, enc_in, e2, h, z2),
            prior: Rhs::of(&net.prior),
            dec: [Rhs::of(&d[0]), Rhs::of(&d[1]), Rhs::of(&d[2])],
            phi: [Rhs::of(&net.phi[0]), Rhs::of(&net.phi[1])],
            gates_fx: Rhs::new(&net.w_ih, e2 + z, 0, e2, h4),
            gates_z: Rhs::new(&net.w_ih, e2 + z, e2, z, h4),
            gates_h: Rhs::new(&net.w_hh, h, 0, h, h4),
            hs: vec![0.0f32; b * h],
            cs: vec![0.0f32; b * h],
            tc: vec![0.0f32; h],
            cp: vec![0.0f32; h],
            zf: vec![0.0f32; b * z],
            of: vec![0.0f32; b * width],
            own: vec![0.0f32; b * f],
            prev: vec![0.0f32; b * f],
            out: vec![0.0f32; n * f],
            e: vec![0.0f32; b * z2],
            p: vec![0.0f32; b * z2],
            zq: vec![0.0f32; b * z],
            u: vec![0.0f32; b * zh],
            a1: vec![0.0f32; b * d[0].out],
            a2: vec![0.0f32; b * d[1].out],
            o: vec![0.0f32; b * width],
            g: vec![0.0f32; b * h4],
            fed_rows: Vec::with_capacity(b),
            xf: Vec::with_capacity(b * f),
            q1: vec![0.0f32; b * net.phi[0].out],
            q2: vec![0.0f32; b * e2],
            gx: vec![0.0f32; b * h4],
            len: Vec::with_capacity(b * bones),
        }
    }

    /// Step `t`'s posterior draw `z_q` and the own frame's latent (the prior's
    /// draw, filtered), with `h` the decoder's input.
    #[inline(always)]
    fn latents(&mut self, t: usize) {
        let Sizes {
            h,
            z,
            b,
            z2,
            zh,
            g_in,
            tt,
            ..
        } = self.sizes;
        let at = |s: usize| s * tt + t;
        let Fwd {
            net,
            sh,
            enc_x,
            enc_h,
            prior,
            hs,
            zf,
            e,
            p,
            zq,
            u,
            ..
        } = self;
        // The posterior: e = enc_x + b (+ condition) + h · W_eᵀ; the prior:
        // p = b (+ condition) + h · W_pᵀ.
        let cond = sh.cond.as_ref();
        fill(e, &net.encoder.b, cond.map(|c| (c, Part::Pre)), z2, t);
        for s in 0..b {
            let x = &enc_x[at(s) * z2..(at(s) + 1) * z2];
            e[s * z2..(s + 1) * z2]
                .iter_mut()
                .zip(x)
                .for_each(|(v, a)| *v += a);
        }
        fill(p, &net.prior.b, cond.map(|c| (c, Part::Prior)), z2, t);
        if t > 0 {
            enc_h.acc(b, e, hs);
            prior.acc(b, p, hs);
        }
        for s in 0..b {
            let (ep, ee) = (&sh.eps[at(s) * z..], &sh.e[at(s) * z..]);
            for k in 0..z {
                let (r, v) = (s * z2 + k, &mut zf[s * z + k]);
                zq[s * z + k] = e[r] + sigma(e[r + z]) * ep[k];
                // The own frame's latent: the prior's draw, filtered.
                let zp = if t == 0 {
                    ee[k]
                } else {
                    p[r] + sigma(p[r + z]) * ee[k]
                };
                *v = if t > 0 && net.rho > 0.0 {
                    net.rho * *v + g_in * zp
                } else {
                    zp
                };
                u[s * zh + k] = *v;
            }
            u[s * zh + z..(s + 1) * zh].copy_from_slice(&hs[s * h..(s + 1) * h]);
        }
    }

    /// Step `t`'s decoder and its output filter; the step's state on the
    /// tape where there is one.
    #[inline(always)]
    fn decode(&mut self, t: usize) {
        let Sizes {
            h,
            z,
            b,
            z2,
            width,
            g_out,
            ..
        } = self.sizes;
        let Fwd {
            net,
            sh,
            tape,
            dec,
            hs,
            cs,
            zf,
            of,
            e,
            p,
            zq,
            u,
            a1,
            a2,
            o,
            ..
        } = self;
        let d = &net.decoder;
        // The decoder, and its output filter.
        layer(
            b,
            a1,
            u,
            (&dec[0], &d[0].b),
            sh.cond.as_ref().map(|c| (c, Part::Decoder, t)),
            true,
        );
        layer(b, a2, a1, (&dec[1], &d[1].b), None, true);
        layer(b, o, a2, (&dec[2], &d[2].b), None, false);
        for (v, a) in of.iter_mut().zip(o.iter()) {
            *v = if t > 0 && net.rho_out > 0.0 {
                net.rho_out * *v + g_out * a
            } else {
                *a
            };
        }
        if let Some(k) = tape.as_deref_mut() {
            let (hw, zw) = (t * b * h..(t + 1) * b * h, t * b * z..(t + 1) * b * z);
            k.h[hw.clone()].copy_from_slice(hs);
            k.c[hw].copy_from_slice(cs);
            k.zq[zw.clone()].copy_from_slice(zq);
            k.zf[zw.clone()].copy_from_slice(zf);
            for s in 0..b {
                for j in 0..z {
                    k.mu[t * b * z + s * z + j] = e[s * z2 + j];
                    k.sq[t * b * z + s * z + j] = sigma(e[s * z2 + z + j]);
                    k.sp[t * b * z + s * z + j] =
                        if t > 0 { sigma(p[s * z2 + z + j]) } else { 0.0 };
                }
            }
            let rows = |w: usize| t * b * w..(t + 1) * b * w;
            k.a1[rows(d[0].out)].copy_from_slice(a1);
            k.a2[rows(d[1].out)].copy_from_slice(a2);
            k.of[rows(width)].copy_from_slice(of);
        }
    }

    /// Step `t`'s own frame: the skeleton, then the foot lock against the
    /// last.
    #[inline(always)]
    fn own(&mut self, t: usize) {
        let Sizes {
            f,
            b,
            bones,
            width,
            tt,
            ..
        } = self.sizes;
        let at = |s: usize| s * tt + t;
        let Fwd {
            net,
            sh,
            tape,
            of,
            own,
            prev,
            len,
            ..
        } = self;
        // The own frame: the skeleton, then the foot lock against the last.
        for s in 0..b {
            own[s * f..(s + 1) * f].copy_from_slice(&of[s * width..s * width + f]);
        }
        if let (Some(p), Some(l)) = (&net.place, sh.lengths) {
            len.clear();
            for s in 0..b {
                len.extend_from_slice(&l[at(s) * bones..(at(s) + 1) * bones]);
            }
            *own = place_rows(own, len, &p.mean, &p.std);
        }
        if let Some(lock) = &net.lock {
            for s in 0..b {
                let logits = &of[s * width + f..s * width + f + 2];
                let row = &mut own[s * f..(s + 1) * f];
                let gr = lock.ground_row(row, logits);
                let lk = (t > 0).then(|| lock.lock_row(&prev[s * f..(s + 1) * f], row, logits));
                if let Some(k) = tape.as_deref_mut() {
                    k.ground.push(gr);
                    k.lock.push(lk);
                }
            }
        }
    }

    /// Step `t`'s frame the recurrence reads (the own one where fed), and
    /// the gates' share of its features.
    #[inline(always)]
    fn read(&mut self, t: usize) {
        let Sizes {
            f, b, e2, h4, tt, ..
        } = self.sizes;
        let at = |s: usize| s * tt + t;
        let Fwd {
            net,
            sh,
            tape,
            gates_x,
            phi,
            gates_fx,
            own,
            out,
            g,
            fed_rows,
            xf,
            q1,
            q2,
            gx,
            ..
        } = self;
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
            for &s in fed_rows.iter() {
                xf.extend_from_slice(&out[at(s) * f..(at(s) + 1) * f]);
            }
            layer(k, q1, xf, (&phi[0], &net.phi[0].b), None, true);
            layer(k, q2, q1, (&phi[1], &net.phi[1].b), None, true);
            layer(k, gx, q2, (gates_fx, &net.b_gates), None, false);
            for (i, &s) in fed_rows.iter().enumerate() {
                g[s * h4..(s + 1) * h4].copy_from_slice(&gx[i * h4..(i + 1) * h4]);
            }
            if let Some(tp) = tape.as_deref_mut() {
                let (e1, r) = (net.phi[0].out, t * b);
                for (i, &s) in fed_rows.iter().enumerate() {
                    tp.q1[(r + s) * e1..(r + s + 1) * e1]
                        .copy_from_slice(&q1[i * e1..(i + 1) * e1]);
                    tp.q2[(r + s) * e2..(r + s + 1) * e2]
                        .copy_from_slice(&q2[i * e2..(i + 1) * e2]);
                }
            }
        }
    }

    /// Step `t`'s gates and cell: the state after the step.
    #[inline(always)]
    fn gates(&mut self, t: usize) {
        let Sizes { h, b, z2, h4, .. } = self.sizes;
        let Fwd {
            sh,
            tape,
            gates_z,
            gates_h,
            hs,
            cs,
            tc,
            cp,
            own,
            prev,
            zq,
            g,
            ..
        } = self;
        // The gates: + condition + z · W_zᵀ + h · W_hᵀ, then the cell.
        if let Some(c) = &sh.cond {
            for s in 0..b {
                let at = c.at(Part::Pre, b, s, t) + z2;
                let row = &c.rows[at..at + h4];
                g[s * h4..(s + 1) * h4]
                    .iter_mut()
                    .zip(row)
                    .for_each(|(v, a)| *v += a);
            }
        }
        gates_z.acc(b, g, zq);
        if t > 0 {
            gates_h.acc(b, g, hs);
        }
        for s in 0..b {
            let gr = &mut g[s * h4..(s + 1) * h4];
            activate(gr, h);
            cp.copy_from_slice(&cs[s * h..(s + 1) * h]);
            cell_rows(gr, cp, &mut cs[s * h..(s + 1) * h], tc, h);
            for k in 0..h {
                hs[s * h + k] = gr[3 * h + k] * tc[k];
            }
            if let Some(tp) = tape.as_deref_mut() {
                let r = t * b + s;
                tp.g[r * h4..(r + 1) * h4].copy_from_slice(gr);
                tp.tc[r * h..(r + 1) * h].copy_from_slice(tc);
            }
        }
        std::mem::swap(prev, own);
    }
}

simd_fn! {
/// [`fed`], keeping what the backward needs in `tape` where given.
pub fn pass(net: &Net, sh: &Shard, tape: Option<&mut Tape>) -> Vec<f32> {
    let mut k = Fwd::new(net, sh, tape);
    for t in 0..sh.t {
        k.latents(t);
        k.decode(t);
        k.own(t);
        k.read(t);
        k.gates(t);
    }
    k.out
}
}

impl Grads {
    /// The weights' gradients as one vector, in [`RolloutOp`]'s order.
    fn weights(&self) -> Vec<f32> {
        let mut v = Vec::new();
        let dense = [
            &self.phi[0],
            &self.phi[1],
            &self.encoder,
            &self.prior,
            &self.decoder[0],
            &self.decoder[1],
            &self.decoder[2],
        ];
        for g in dense {
            v.extend_from_slice(&g.w);
            v.extend_from_slice(&g.b);
        }
        v.extend_from_slice(&self.w_ih);
        v.extend_from_slice(&self.w_hh);
        v.extend_from_slice(&self.b_gates);
        v
    }
}

/// [`pass`] with its backward ([`fed_backward`]) as a candle op, so the
/// gradient flows through the fed-back frames. Inputs: the real frames'
/// features `[B, T, E2]`; every weight of the [`Net`] as one vector
/// (`w`, `b` of φ₁, φ₂, the encoder `[μ | logit σ]`, the prior, the
/// decoder's three layers, then `W_ih`, `W_hh`, `b_ih + b_hh`), whose
/// values `net` holds; the condition's rows `[n, 1, pre | prior | decoder]`
/// (`n` = 1 or `B`) or `[B, T, ·]` (a model with the control; anything,
/// unused, without a condition).
///
/// Output `[B, T, input + H + 3Z]`: each fed frame, then what
/// [`latent_lstm`](super::latent_lstm) gives of the recurrence that read
/// them, `[h_{t−1} | μ_t | σ_t | z_t]` (the state before the step and the
/// posterior), so the loss reads the rollout's own recurrence instead of
/// running it again; the backward takes the gradients of both.
pub struct RolloutOp {
    pub net: Net,
    pub b: usize,
    pub t: usize,
    pub x: Vec<f32>,
    pub eps: Vec<f32>,
    pub e: Vec<f32>,
    pub mask: Vec<f32>,
    pub lengths: Option<Vec<f32>>,
    /// The widths of the condition's parts (pre, prior, decoder), if any.
    pub cond: Option<[usize; 3]>,
    pub tape: std::sync::Mutex<Option<Tape>>,
}

impl RolloutOp {
    /// The fed-back frames ([`fed`]) of the real frames' features `feat`
    /// and the condition's rows `cond` (as the op's inputs).
    pub fn fed(&self, feat: &[f32], cond: &[f32]) -> Vec<f32> {
        let _time = crate::blocks::timing::span("rollout, no gradient", false);
        fed(&self.net, &self.shard(feat, cond))
    }

    /// Width of an output row: the frame, then `h | μ | σ | z`.
    pub fn width(&self) -> usize {
        self.net.input + self.net.hidden + 3 * self.net.latent
    }

    /// The op's output rows (`[B, T, width]`) from the fed frames of
    /// [`pass`] and its tape.
    fn rows(&self, fed: &[f32], tape: &Tape) -> Vec<f32> {
        let (f, h, z, w) = (
            self.net.input,
            self.net.hidden,
            self.net.latent,
            self.width(),
        );
        let mut out = vec![0.0f32; self.b * self.t * w];
        for (q, row) in out.chunks_exact_mut(w).enumerate() {
            let r = (q % self.t) * self.b + q / self.t;
            let (frame, rest) = row.split_at_mut(f);
            frame.copy_from_slice(&fed[q * f..(q + 1) * f]);
            let (hr, rest) = rest.split_at_mut(h);
            hr.copy_from_slice(&tape.h[r * h..(r + 1) * h]);
            for (k, part) in rest.chunks_exact_mut(z).enumerate() {
                let from = [&tape.mu, &tape.sq, &tape.zq][k];
                part.copy_from_slice(&from[r * z..(r + 1) * z]);
            }
        }
        out
    }

    fn shard<'a>(&'a self, feat: &'a [f32], cond: &'a [f32]) -> Shard<'a> {
        Shard {
            b: self.b,
            t: self.t,
            x: &self.x,
            feat,
            eps: &self.eps,
            e: &self.e,
            mask: &self.mask,
            lengths: self.lengths.as_deref(),
            cond: self.cond.map(|widths| Cond { rows: cond, widths }),
        }
    }
}

impl candle_core::CustomOp3 for RolloutOp {
    fn name(&self) -> &'static str {
        "rollout"
    }

    fn cpu_fwd(
        &self,
        s1: &candle_core::CpuStorage,
        l1: &candle_core::Layout,
        _s2: &candle_core::CpuStorage,
        _l2: &candle_core::Layout,
        s3: &candle_core::CpuStorage,
        l3: &candle_core::Layout,
    ) -> candle_core::Result<(candle_core::CpuStorage, candle_core::Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let feat = super::slice(s1, l1, "feat")?;
        let cond = super::slice(s3, l3, "cond")?;
        let mut tape = Tape::default();
        let fed = pass(&self.net, &self.shard(feat, cond), Some(&mut tape));
        let out = self.rows(&fed, &tape);
        *self.tape.lock().unwrap_or_else(|p| p.into_inner()) = Some(tape);
        let shape = candle_core::Shape::from((self.b, self.t, self.width()));
        Ok((candle_core::CpuStorage::F32(out), shape))
    }

    fn bwd(
        &self,
        feat: &candle_core::Tensor,
        w: &candle_core::Tensor,
        cond: &candle_core::Tensor,
        res: &candle_core::Tensor,
        grad: &candle_core::Tensor,
    ) -> candle_core::Result<(
        Option<candle_core::Tensor>,
        Option<candle_core::Tensor>,
        Option<candle_core::Tensor>,
    )> {
        let _time = crate::blocks::timing::span(self.name(), true);
        use super::{tensor, with_values};
        let cached = self.tape.lock().unwrap_or_else(|p| p.into_inner()).take();
        let mut g = with_values(feat, |fv| {
            with_values(cond, |cv| {
                let sh = self.shard(fv, cv);
                let tape = match cached {
                    Some(t) => t,
                    None => {
                        let mut t = Tape::default();
                        pass(&self.net, &sh, Some(&mut t));
                        t
                    }
                };
                with_values(res, |out| {
                    with_values(grad, |go| Ok(fed_backward(&self.net, &sh, &tape, out, go)))
                })
            })
        })?;
        let dcond = g
            .cond
            .take()
            .map(|v| tensor(v, cond.dims(), cond))
            .transpose()?;
        let dw = tensor(g.weights(), w.dims(), w)?;
        Ok((Some(tensor(g.feat, feat.dims(), feat)?), Some(dw), dcond))
    }
}
