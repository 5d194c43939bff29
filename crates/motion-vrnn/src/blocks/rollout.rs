//! Scheduled sampling to every depth, fused: the recurrence, the prior, the
//! decoder, the skeleton and the foot lock stepping together over one
//! shard. [`fed`] runs it forward only (no gradient flows through the
//! fed-back frames, the default); [`RolloutOp`] keeps a tape ([`pass`]) and
//! has its own backward ([`fed_backward`]: back through every step, the
//! gradients of the real frames' features, every weight and the
//! condition's rows), for `Parts::rollout_gradient`.
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
use super::kernels::{dsigma, mm, mm_rows, mm_small, rm, sigma, simd_fn, tr, Packed, V};
use super::scan::{activate, cell_rows};
use super::skeleton::{place_rows, PlaceOp};

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
    /// `σ` of the posterior and of the prior.
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

simd_fn! {
/// [`fed`], keeping what the backward needs in `tape` where given.
pub fn pass(net: &Net, sh: &Shard, tape: Option<&mut Tape>) -> Vec<f32> {
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
    let mut tape = tape;
    if let Some(k) = tape.as_deref_mut() {
        let sized = |w: usize| vec![0.0f32; n * w];
        *k = Tape {
            h: sized(h),
            c: sized(h),
            sq: sized(z),
            sp: sized(z),
            zq: sized(z),
            zf: sized(z),
            a1: sized(d[0].out),
            a2: sized(d[1].out),
            of: sized(width),
            ground: Vec::with_capacity(n),
            lock: Vec::with_capacity(n),
            q1: sized(net.phi[0].out),
            q2: sized(e2),
            g: sized(h4),
            tc: sized(h),
        };
    }
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
        if let Some(k) = tape.as_deref_mut() {
            let (hw, zw) = (t * b * h..(t + 1) * b * h, t * b * z..(t + 1) * b * z);
            k.h[hw.clone()].copy_from_slice(&hs);
            k.c[hw].copy_from_slice(&cs);
            k.zq[zw.clone()].copy_from_slice(&zq);
            k.zf[zw.clone()].copy_from_slice(&zf);
            for s in 0..b {
                for j in 0..z {
                    k.sq[t * b * z + s * z + j] = sigma(e[s * z2 + z + j]);
                    k.sp[t * b * z + s * z + j] = if t > 0 { sigma(p[s * z2 + z + j]) } else { 0.0 };
                }
            }
            let rows = |w: usize| t * b * w..(t + 1) * b * w;
            k.a1[rows(d[0].out)].copy_from_slice(&a1);
            k.a2[rows(d[1].out)].copy_from_slice(&a2);
            k.of[rows(width)].copy_from_slice(&of);
        }
        // The own frame: the skeleton, then the foot lock against the last.
        for s in 0..b {
            own[s * f..(s + 1) * f].copy_from_slice(&of[s * width..s * width + f]);
        }
        if let (Some(p), Some(l)) = (&net.place, sh.lengths) {
            len.clear();
            for s in 0..b {
                len.extend_from_slice(&l[at(s) * bones..(at(s) + 1) * bones]);
            }
            own = place_rows(&own, &len, &p.mean, &p.std);
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
            if let Some(tp) = tape.as_deref_mut() {
                let (e1, r) = (net.phi[0].out, t * b);
                for (i, &s) in fed_rows.iter().enumerate() {
                    tp.q1[(r + s) * e1..(r + s + 1) * e1].copy_from_slice(&q1[i * e1..(i + 1) * e1]);
                    tp.q2[(r + s) * e2..(r + s + 1) * e2].copy_from_slice(&q2[i * e2..(i + 1) * e2]);
                }
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
            if let Some(tp) = tape.as_deref_mut() {
                let r = t * b + s;
                tp.g[r * h4..(r + 1) * h4].copy_from_slice(gr);
                tp.tc[r * h..(r + 1) * h].copy_from_slice(&tc);
            }
        }
        std::mem::swap(&mut prev, &mut own);
    }
    out
}
}

/// A dense layer's gradients (`w`: `out × in`, as [`Dense`]).
#[derive(Clone, Debug)]
pub struct DenseGrad {
    pub w: Vec<f32>,
    pub b: Vec<f32>,
}

impl DenseGrad {
    fn of(d: &Dense) -> DenseGrad {
        DenseGrad {
            w: vec![0.0; d.w.len()],
            b: vec![0.0; d.b.len()],
        }
    }
}

/// What [`fed_backward`] gives: the gradients of the real frames' features
/// (`[B, T, E2]`), of every weight of the [`Net`], and of the condition's
/// rows (the shapes of [`Cond`]'s).
#[derive(Clone, Debug)]
pub struct Grads {
    pub feat: Vec<f32>,
    pub phi: [DenseGrad; 2],
    pub encoder: DenseGrad,
    pub prior: DenseGrad,
    pub decoder: [DenseGrad; 3],
    pub w_ih: Vec<f32>,
    pub w_hh: Vec<f32>,
    pub b_gates: Vec<f32>,
    pub cond: Option<[Vec<f32>; 3]>,
}

/// `dw[:, from..from + k] += Σ_rows dyᵀ a` over `n` rows (`dy`: `n × out`,
/// `a`: `n × k`, `dw`: `out × inp`), one product.
fn weight_grad(
    dw: &mut [f32],
    inp: usize,
    from: usize,
    dy: &[f32],
    out: usize,
    a: &[f32],
    k: usize,
) {
    let n = a.len() / k.max(1);
    mm(
        (out, k, n),
        dw,
        rm(from, inp),
        true,
        dy,
        tr(0, out),
        a,
        rm(0, k),
    );
}

/// `dst += src`, element by element.
#[inline(always)]
fn add(dst: &mut [f32], src: &[f32]) {
    for (d, &v) in dst.iter_mut().zip(src) {
        *d += v;
    }
}

/// Zero where the layer's output `y` is not positive (a ReLU's backward).
#[inline(always)]
fn relu_back(g: &mut [f32], y: &[f32]) {
    for (d, &v) in g.iter_mut().zip(y) {
        if v <= 0.0 {
            *d = 0.0;
        }
    }
}

simd_fn! {
/// The backward of [`pass`]: the gradients of everything the fed frames
/// `fed` (its output) were made of, given theirs (`dout`, `[B, T, input]`),
/// through every step of the recurrence, the prior's draws, the decoder,
/// the filters, the skeleton and the foot lock (module docs).
#[allow(clippy::needless_range_loop)] // several arrays indexed alike
pub fn fed_backward(net: &Net, sh: &Shard, tape: &Tape, fed: &[f32], dout: &[f32]) -> Grads {
    let (h, z, f, b, tt) = (net.hidden, net.latent, net.input, sh.b, sh.t);
    let (e1, e2, d) = (net.phi[0].out, net.phi[1].out, &net.decoder);
    let (z2, h4, zh, width) = (2 * z, 4 * h, z + h, d[2].out);
    let (enc_in, gin) = (net.encoder.inp, e2 + z);
    let gain = |rho: f32| (1.0 - rho * rho).max(0.0).sqrt();
    let (g_in, g_out) = (gain(net.rho), gain(net.rho_out));
    let bones = super::skeleton::BONES;
    let mut gr = Grads {
        feat: vec![0.0; b * tt * e2],
        phi: [DenseGrad::of(&net.phi[0]), DenseGrad::of(&net.phi[1])],
        encoder: DenseGrad::of(&net.encoder),
        prior: DenseGrad::of(&net.prior),
        decoder: [DenseGrad::of(&d[0]), DenseGrad::of(&d[1]), DenseGrad::of(&d[2])],
        w_ih: vec![0.0; net.w_ih.len()],
        w_hh: vec![0.0; net.w_hh.len()],
        b_gates: vec![0.0; h4],
        cond: sh
            .cond
            .as_ref()
            .map(|c| [vec![0.0; c.pre.len()], vec![0.0; c.prior.len()], vec![0.0; c.decoder.len()]]),
    };
    // Which row of a condition's slice a sequence reads (one shared row, or
    // one per sequence).
    let crow = |len: usize, w: usize, s: usize| if len == w { 0 } else { s * w };
    // Carried between steps: d h_t and d c_t, the filters' and the lock's
    // gradients of the step before.
    let (mut dh, mut dc, mut dhp) = (vec![0.0f32; b * h], vec![0.0f32; b * h], vec![0.0f32; b * h]);
    let (mut czf, mut cof) = (vec![0.0f32; b * z], vec![0.0f32; b * width]);
    let (mut cprev, mut cnext) = (vec![0.0f32; b * f], vec![0.0f32; b * f]);
    let mut down = vec![0.0f32; f];
    // Per step, over its rows: the features' and the fed frames' gradients
    // from the gates (`gx`, `dxs`), and the decoder's input's (`dus`).
    let (mut gx, mut dxs, mut dus) = (vec![0.0f32; b * e2], vec![0.0f32; b * f], vec![0.0f32; b * zh]);
    // Each layer's output gradient per row (`t·B + s`), and the inputs the
    // tape does not hold in that order, for the weights' gradients at the
    // end: the gates (`[n, 4H]`) read the features `xin` (the fed frame's,
    // or the real one's) and `z_q`, `h`; φ₁, φ₂ the fed frames (`xf`);
    // the posterior the real features (`fr`) and `h`.
    let n = b * tt;
    let rows = |w: usize| vec![0.0f32; n * w];
    let (mut dgs, mut dzq, mut xin, mut fr) = (rows(h4), rows(z), rows(e2), rows(e2));
    let (mut dq2, mut dq1, mut xf) = (rows(e2), rows(e1), rows(f));
    let (mut dofs, mut da2, mut da1) = (rows(width), rows(d[1].out), rows(d[0].out));
    let (mut dps, mut des) = (rows(z2), rows(z2));
    // Every product of a step's backward, its weights packed once.
    let (gates_x, gates_z) = (Rhs::back(&net.w_ih, gin, 0, h4, e2), Rhs::back(&net.w_ih, gin, e2, h4, z));
    let gates_h = Rhs::back(&net.w_hh, h, 0, h4, h);
    let phi = [Rhs::back_of(&net.phi[0]), Rhs::back_of(&net.phi[1])];
    let dec = [Rhs::back_of(&d[0]), Rhs::back_of(&d[1]), Rhs::back_of(&d[2])];
    let prior = Rhs::back_of(&net.prior);
    let (enc_x, enc_h) = (Rhs::back(&net.encoder.w, enc_in, 0, z2, e2), Rhs::back(&net.encoder.w, enc_in, e2, z2, h));
    // The rows `t·B..(t + 1)·B` of a per-row array `w` wide.
    let step = |t: usize, w: usize| t * b * w..(t + 1) * b * w;
    for t in (0..tt).rev() {
        dhp.fill(0.0);
        cnext.fill(0.0);
        let r0 = t * b;
        // The cell: d h_t, d c_t → the gates' pre-activations, d c_{t−1}.
        for s in 0..b {
            let r = r0 + s;
            let (gt, tcr) = (&tape.g[r * h4..(r + 1) * h4], &tape.tc[r * h..(r + 1) * h]);
            let c_prev = &tape.c[r * h..(r + 1) * h];
            let dg = &mut dgs[r * h4..(r + 1) * h4];
            for k in 0..h {
                let (ig, fg, gv, og) = (gt[k], gt[h + k], gt[2 * h + k], gt[3 * h + k]);
                let (tcv, dhv) = (tcr[k], dh[s * h + k]);
                let dcv = dc[s * h + k] + dhv * og * (1.0 - tcv * tcv);
                dc[s * h + k] = dcv * fg;
                dg[k] = dcv * gv * ig * (1.0 - ig);
                dg[h + k] = dcv * c_prev[k] * fg * (1.0 - fg);
                dg[2 * h + k] = dcv * ig * (1.0 - gv * gv);
                dg[3 * h + k] = dhv * tcv * og * (1.0 - og);
            }
            let dg = &dgs[r * h4..(r + 1) * h4];
            add(&mut gr.b_gates, dg);
            if let (Some(c), Some(gc)) = (&sh.cond, gr.cond.as_mut()) {
                let at = crow(c.pre.len(), z2 + h4, s);
                add(&mut gc[0][at + z2..at + z2 + h4], dg);
            }
        }
        // The gates' inputs: z_q, h_{t−1}, and the frame's features (the
        // fed frame's own, or the real one's).
        let dg = &dgs[step(t, h4)];
        gates_z.rows(b, &mut dzq[step(t, z)], rm(0, z), false, dg);
        if t > 0 {
            gates_h.rows(b, &mut dhp, rm(0, h), true, dg);
        }
        gates_x.rows(b, &mut gx, rm(0, e2), false, dg);
        for s in 0..b {
            let (r, q) = (r0 + s, s * tt + t);
            let ft = &sh.feat[q * e2..(q + 1) * e2];
            fr[r * e2..(r + 1) * e2].copy_from_slice(ft);
            let g = &gx[s * e2..(s + 1) * e2];
            if sh.mask[q] != 0.0 {
                let q2 = &tape.q2[r * e2..(r + 1) * e2];
                xin[r * e2..(r + 1) * e2].copy_from_slice(q2);
                let g2 = &mut dq2[r * e2..(r + 1) * e2];
                g2.copy_from_slice(g);
                relu_back(g2, q2);
                add(&mut gr.phi[1].b, g2);
                xf[r * f..(r + 1) * f].copy_from_slice(&fed[q * f..(q + 1) * f]);
            } else {
                xin[r * e2..(r + 1) * e2].copy_from_slice(ft);
                add(&mut gr.feat[q * e2..(q + 1) * e2], g);
            }
        }
        // Back through φ₂ and φ₁ into the fed frames (rows not fed are zero).
        phi[1].rows(b, &mut dq1[step(t, e1)], rm(0, e1), false, &dq2[step(t, e2)]);
        for s in 0..b {
            if sh.mask[s * tt + t] != 0.0 {
                let r = r0 + s;
                let g1 = &mut dq1[r * e1..(r + 1) * e1];
                relu_back(g1, &tape.q1[r * e1..(r + 1) * e1]);
                add(&mut gr.phi[0].b, g1);
            }
        }
        phi[0].rows(b, &mut dxs, rm(0, f), false, &dq1[step(t, e1)]);
        for s in 0..b {
            let (r, q) = (r0 + s, s * tt + t);
            let m = sh.mask[q];
            // The fed frame x + m (own − x) → the own frame, plus what the
            // next step's lock gave it.
            for k in 0..f {
                down[k] = m * (dout[q * f + k] + dxs[s * f + k]) + cprev[s * f + k];
            }
            let mut dlog = [0.0f32; 2];
            if let Some(lock) = &net.lock {
                if let Some(lk) = &tape.lock[r] {
                    lock.lock_row_grad(lk, &mut down, &mut cnext[s * f..(s + 1) * f], &mut dlog);
                }
                lock.ground_row_grad(&tape.ground[r], &mut down, &mut dlog);
            }
            let ofr = &tape.of[r * width..(r + 1) * width];
            if let (Some(p), Some(l)) = (&net.place, sh.lengths) {
                p.row_grad(&ofr[..f], &l[q * bones..(q + 1) * bones], &mut down);
            }
            // The output filter.
            let dof = &mut dofs[r * width..(r + 1) * width];
            dof[..f].copy_from_slice(&down);
            if width >= f + 2 && net.lock.is_some() {
                dof[f..f + 2].copy_from_slice(&dlog);
            }
            let filt = t > 0 && net.rho_out > 0.0;
            for j in 0..width {
                let v = dof[j] + cof[s * width + j];
                dof[j] = if filt { g_out * v } else { v };
                cof[s * width + j] = if filt { net.rho_out * v } else { 0.0 };
            }
            add(&mut gr.decoder[2].b, dof);
        }
        // The decoder.
        dec[2].rows(b, &mut da2[step(t, d[1].out)], rm(0, d[1].out), false, &dofs[step(t, width)]);
        for s in 0..b {
            let r = r0 + s;
            let g2 = &mut da2[r * d[1].out..(r + 1) * d[1].out];
            relu_back(g2, &tape.a2[r * d[1].out..(r + 1) * d[1].out]);
            add(&mut gr.decoder[1].b, g2);
        }
        dec[1].rows(b, &mut da1[step(t, d[0].out)], rm(0, d[0].out), false, &da2[step(t, d[1].out)]);
        for s in 0..b {
            let r = r0 + s;
            let g1 = &mut da1[r * d[0].out..(r + 1) * d[0].out];
            relu_back(g1, &tape.a1[r * d[0].out..(r + 1) * d[0].out]);
            add(&mut gr.decoder[0].b, g1);
            if let (Some(c), Some(gc)) = (&sh.cond, gr.cond.as_mut()) {
                let at = crow(c.decoder.len(), d[0].out, s);
                add(&mut gc[2][at..at + d[0].out], g1);
            }
        }
        dec[0].rows(b, &mut dus, rm(0, zh), false, &da1[step(t, d[0].out)]);
        for s in 0..b {
            let (r, q) = (r0 + s, s * tt + t);
            let du = &dus[s * zh..(s + 1) * zh];
            add(&mut dhp[s * h..(s + 1) * h], &du[z..]);
            // The latent filter, then the prior's draw (its noise alone at
            // the first step).
            let filt = t > 0 && net.rho > 0.0;
            let dp = &mut dps[r * z2..(r + 1) * z2];
            for j in 0..z {
                let v = du[j] + czf[s * z + j];
                let dzp = if filt { g_in * v } else { v };
                czf[s * z + j] = if filt { net.rho * v } else { 0.0 };
                if t > 0 {
                    dp[j] = dzp;
                    dp[z + j] = dzp * sh.e[q * z + j] * dsigma(tape.sp[r * z + j]);
                }
            }
            if t > 0 {
                let dp = &dps[r * z2..(r + 1) * z2];
                add(&mut gr.prior.b, dp);
                if let (Some(c), Some(gc)) = (&sh.cond, gr.cond.as_mut()) {
                    let at = crow(c.prior.len(), z2, s);
                    add(&mut gc[1][at..at + z2], dp);
                }
            }
            // The posterior's draw: from the real frame's features and h.
            let de = &mut des[r * z2..(r + 1) * z2];
            for j in 0..z {
                let dz = dzq[r * z + j];
                de[j] = dz;
                de[z + j] = dz * sh.eps[q * z + j] * dsigma(tape.sq[r * z + j]);
            }
            let de = &des[r * z2..(r + 1) * z2];
            add(&mut gr.encoder.b, de);
            if let (Some(c), Some(gc)) = (&sh.cond, gr.cond.as_mut()) {
                let at = crow(c.pre.len(), z2 + h4, s);
                add(&mut gc[0][at..at + z2], de);
            }
        }
        if t > 0 {
            prior.rows(b, &mut dhp, rm(0, h), true, &dps[step(t, z2)]);
            enc_h.rows(b, &mut dhp, rm(0, h), true, &des[step(t, z2)]);
        }
        enc_x.rows(b, &mut gr.feat, rm(t * e2, tt * e2), true, &des[step(t, z2)]);
        std::mem::swap(&mut dh, &mut dhp);
        std::mem::swap(&mut cprev, &mut cnext);
    }
    // The weights' gradients, each one product over all rows (`h` is zero
    // at the first step, as are the rows of a part that did not run).
    weight_grad(&mut gr.w_ih, gin, 0, &dgs, h4, &xin, e2);
    weight_grad(&mut gr.w_ih, gin, e2, &dgs, h4, &tape.zq, z);
    weight_grad(&mut gr.w_hh, h, 0, &dgs, h4, &tape.h, h);
    weight_grad(&mut gr.phi[1].w, e1, 0, &dq2, e2, &tape.q1, e1);
    weight_grad(&mut gr.phi[0].w, f, 0, &dq1, e1, &xf, f);
    weight_grad(&mut gr.decoder[2].w, d[2].inp, 0, &dofs, width, &tape.a2, d[1].out);
    weight_grad(&mut gr.decoder[1].w, d[1].inp, 0, &da2, d[1].out, &tape.a1, d[0].out);
    weight_grad(&mut gr.decoder[0].w, zh, 0, &da1, d[0].out, &tape.zf, z);
    weight_grad(&mut gr.decoder[0].w, zh, z, &da1, d[0].out, &tape.h, h);
    weight_grad(&mut gr.prior.w, h, 0, &dps, z2, &tape.h, h);
    weight_grad(&mut gr.encoder.w, enc_in, 0, &des, z2, &fr, e2);
    weight_grad(&mut gr.encoder.w, enc_in, e2, &des, z2, &tape.h, h);
    gr
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
/// (anything, unused, without a condition).
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
    /// The condition's rows cut into its three parts.
    fn cond_parts(&self, c: &[f32]) -> Option<[Vec<f32>; 3]> {
        let [a, b, d] = self.cond?;
        let w = a + b + d;
        let mut parts = [Vec::new(), Vec::new(), Vec::new()];
        for row in c.chunks_exact(w) {
            parts[0].extend_from_slice(&row[..a]);
            parts[1].extend_from_slice(&row[a..a + b]);
            parts[2].extend_from_slice(&row[a + b..]);
        }
        Some(parts)
    }

    /// The fed-back frames ([`fed`]) of the real frames' features `feat`
    /// and the condition's rows `cond` (as the op's inputs).
    pub fn fed(&self, feat: &[f32], cond: &[f32]) -> Vec<f32> {
        let parts = self.cond_parts(cond);
        fed(&self.net, &self.shard(feat, parts.as_ref()))
    }

    fn shard<'a>(&'a self, feat: &'a [f32], cond: Option<&'a [Vec<f32>; 3]>) -> Shard<'a> {
        Shard {
            b: self.b,
            t: self.t,
            x: &self.x,
            feat,
            eps: &self.eps,
            e: &self.e,
            mask: &self.mask,
            lengths: self.lengths.as_deref(),
            cond: cond.map(|[pre, prior, decoder]| Cond {
                pre,
                prior,
                decoder,
            }),
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
        let feat = super::slice(s1, l1, "feat")?;
        let parts = self.cond_parts(super::slice(s3, l3, "cond")?);
        let mut tape = Tape::default();
        let out = pass(
            &self.net,
            &self.shard(feat, parts.as_ref()),
            Some(&mut tape),
        );
        *self.tape.lock().unwrap_or_else(|p| p.into_inner()) = Some(tape);
        let shape = candle_core::Shape::from((self.b, self.t, self.net.input));
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
        use super::{tensor, with_values};
        let cached = self.tape.lock().unwrap_or_else(|p| p.into_inner()).take();
        let g = with_values(feat, |fv| {
            with_values(cond, |cv| {
                let parts = self.cond_parts(cv);
                let sh = self.shard(fv, parts.as_ref());
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
        let dcond = match (&g.cond, self.cond) {
            (Some([a, b, d]), Some([wa, wb, wd])) => {
                let mut v = Vec::with_capacity(cond.elem_count());
                for ((ra, rb), rd) in a
                    .chunks_exact(wa)
                    .zip(b.chunks_exact(wb))
                    .zip(d.chunks_exact(wd))
                {
                    v.extend_from_slice(ra);
                    v.extend_from_slice(rb);
                    v.extend_from_slice(rd);
                }
                Some(tensor(v, cond.dims(), cond)?)
            }
            _ => None,
        };
        let dw = tensor(g.weights(), w.dims(), w)?;
        Ok((Some(tensor(g.feat, feat.dims(), feat)?), Some(dw), dcond))
    }
}
