//! The recurrence: what cannot be batched over time.
//!
//! [`latent_lstm`] runs the VRNN's step loop over whole sequences with the
//! inputs that do not depend on the recurrence precomputed for all rows:
//!
//! ```text
//! e_t  = pre_t[..2Z] + W_e · h_{t−1}                 (posterior logits)
//! μ_t  = e_t[..Z],  σ_t = sigmoid(e_t[Z..])  (clamped to [SIGMA_MIN, 1])
//! z_t  = μ_t + σ_t ⊙ ε_t
//! g_t  = pre_t[2Z..] + W_z · z_t + W_h · h_{t−1}     (LSTM gates i, f, g, o)
//! c_t  = sigmoid(f) c_{t−1} + sigmoid(i) tanh(g),  h_t = sigmoid(o) tanh(c_t)
//! ```
//!
//! with `h_{−1} = c_{−1} = 0`. Per row it returns `[h_{t−1} | μ_t | σ_t | z_t]`:
//! the state *before* the step (what the prior and the decoder read) and the
//! posterior sample.

use super::kernels::{dsigma, mm, mm_small, rm, sigma, sigmoid, simd_fn, tanh, tr, Packed};
use super::linear::row_sums;
use super::{fused, slice, tensor, with_values};
use candle_core::{CpuStorage, CustomOp3, Layout, Result, Shape, Tensor, D};
use std::sync::Mutex;

/// Sizes of the recurrence.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScanDims {
    /// LSTM hidden size `H`.
    pub hidden: usize,
    /// Latent size `Z`.
    pub latent: usize,
}

impl ScanDims {
    /// Width of `pre`: `2Z + 4H`.
    pub fn pre(&self) -> usize {
        2 * self.latent + 4 * self.hidden
    }
    /// Width of the output: `H + 3Z`.
    pub fn out(&self) -> usize {
        self.hidden + 3 * self.latent
    }
    /// Length of the flat recurrent weights `[W_e (2Z×H) | W_z (4H×Z) | W_h (4H×H)]`.
    pub fn weights(&self) -> usize {
        let (h, z) = (self.hidden, self.latent);
        2 * z * h + 4 * h * z + 4 * h * h
    }
}

/// The VRNN recurrence over whole sequences (see the module docs).
/// `pre`: `[B, T, 2Z + 4H]` as one block, or as two, its posterior part
/// `[B, T, 2Z]` and its gates' part `[B, T, 4H]` (what two products made:
/// read in place, with no `cat` in the graph); `rows`: `[B, 1, 2Z + 4H]`
/// added to every step of each sequence (`[1, 1, ·]`: the same for all),
/// as [`add_rows`](super::add_rows) would add them, bit for bit, without
/// the sum as a node of the graph; `eps: [B, T, Z]`; `w`: the flat
/// recurrent weights of [`ScanDims::weights`] (row-major, rows of `W_e`
/// are μ then σ, gates in the order i, f, g, o). Returns `[B, T, H + 3Z]`.
pub fn latent_lstm(
    pre: &[&Tensor],
    rows: Option<&Tensor>,
    eps: &Tensor,
    w: &Tensor,
    dims: ScanDims,
) -> Result<Tensor> {
    let (b, t, _) = match pre.first() {
        Some(p) => p.dims3()?,
        None => candle_core::bail!("latent_lstm: no pre"),
    };
    let widths: Vec<usize> = pre
        .iter()
        .map(|p| p.dim(D::Minus1))
        .collect::<Result<_>>()?;
    let fits = match widths[..] {
        [p] => p == dims.pre(),
        [e, g] => e == 2 * dims.latent && g == 4 * dims.hidden,
        _ => false,
    };
    let rows_fit = rows
        .is_none_or(|r| matches!(r.dims(), &[rb, 1, p] if (rb == b || rb == 1) && p == dims.pre()));
    if !fits
        || !rows_fit
        || pre.iter().any(|p| p.dims()[..2] != [b, t])
        || eps.dims() != [b, t, dims.latent]
        || w.dims() != [dims.weights()]
    {
        candle_core::bail!(
            "latent_lstm: pre {:?}, rows {:?}, eps {:?}, w {:?} do not fit {dims:?}",
            pre.iter().map(|p| p.dims()).collect::<Vec<_>>(),
            rows.map(|r| r.dims()),
            eps.shape(),
            w.shape()
        );
    }
    if !fused(pre[0]) {
        let joint = match pre {
            [p] => (*p).clone(),
            _ => Tensor::cat(pre, D::Minus1)?,
        };
        let joint = match rows {
            Some(r) => joint.broadcast_add(r)?,
            None => joint,
        };
        return reference(&joint, eps, w, dims);
    }
    // The rows ride on the weights' input: one tensor, split back in `bwd`.
    let (w, shared) = match rows {
        Some(r) => (
            Tensor::cat(&[w, &r.flatten_all()?], 0)?,
            Some(r.dim(0)? == 1),
        ),
        None => (w.clone(), None),
    };
    let w = w.contiguous()?;
    match pre {
        [p] => {
            let op = ScanOp::new(dims, None, shared);
            p.contiguous()?.apply_op3(&eps.contiguous()?, &w, op)
        }
        [e, g] => {
            let eps = eps.flatten_all()?.to_vec1::<f32>()?;
            let op = ScanOp::new(dims, Some(eps), shared);
            e.contiguous()?.apply_op3(&g.contiguous()?, &w, op)
        }
        _ => candle_core::bail!("latent_lstm: pre in {} blocks", pre.len()),
    }
}

/// [`latent_lstm`] in candle ops.
fn reference(pre: &Tensor, eps: &Tensor, w: &Tensor, d: ScanDims) -> Result<Tensor> {
    let (b, t, _) = pre.dims3()?;
    let (h, z) = (d.hidden, d.latent);
    let we = w.narrow(0, 0, 2 * z * h)?.reshape((2 * z, h))?;
    let wz = w.narrow(0, 2 * z * h, 4 * h * z)?.reshape((4 * h, z))?;
    let wh = w
        .narrow(0, 2 * z * h + 4 * h * z, 4 * h * h)?
        .reshape((4 * h, h))?;
    let mut hs = Tensor::zeros((b, h), pre.dtype(), pre.device())?;
    let mut cs = hs.clone();
    let mut rows = Vec::with_capacity(t);
    for step in 0..t {
        let p = pre.narrow(1, step, 1)?.squeeze(1)?;
        let e = (p.narrow(1, 0, 2 * z)? + hs.matmul(&we.t()?)?)?;
        let mu = e.narrow(1, 0, z)?;
        let sg =
            candle_nn::ops::sigmoid(&e.narrow(1, z, z)?)?.clamp(super::kernels::SIGMA_MIN, 1.0)?;
        let zz = (&mu + (&sg * eps.narrow(1, step, 1)?.squeeze(1)?)?)?;
        let g = ((p.narrow(1, 2 * z, 4 * h)? + zz.matmul(&wz.t()?)?)? + hs.matmul(&wh.t()?)?)?;
        let (hn, cn) = cell_reference(&g, &cs, h)?;
        rows.push(Tensor::cat(&[&hs, &mu, &sg, &zz], D::Minus1)?);
        hs = hn;
        cs = cn;
    }
    Tensor::stack(&rows, 1)
}

/// One LSTM step in candle ops: gate pre-activations `[B, 4H]` (i, f, g, o)
/// and the cell `[B, H]` → `(h, c)`.
fn cell_reference(g: &Tensor, c: &Tensor, h: usize) -> Result<(Tensor, Tensor)> {
    let i = candle_nn::ops::sigmoid(&g.narrow(1, 0, h)?)?;
    let f = candle_nn::ops::sigmoid(&g.narrow(1, h, h)?)?;
    let gg = g.narrow(1, 2 * h, h)?.tanh()?;
    let o = candle_nn::ops::sigmoid(&g.narrow(1, 3 * h, h)?)?;
    let cn = ((f * c)? + (i * gg)?)?;
    Ok(((o * cn.tanh()?)?, cn))
}

/// One LSTM step (free-running generation): gate pre-activations `[B, 4H]`
/// in the order i, f, g, o and the cell `[B, H]` → `(h, c)`. No backward.
pub fn lstm_cell(gates: &Tensor, c: &Tensor) -> Result<(Tensor, Tensor)> {
    let (b, h) = c.dims2()?;
    if gates.dims() != [b, 4 * h] {
        candle_core::bail!("lstm_cell: gates {:?}, cell {:?}", gates.shape(), c.shape());
    }
    if !fused(gates) {
        return cell_reference(gates, c, h);
    }
    let (mut hv, mut cv) = (vec![0.0f32; b * h], vec![0.0f32; b * h]);
    with_values(gates, |g| {
        with_values(c, |c0| {
            for s in 0..b {
                let mut gr = g[s * 4 * h..(s + 1) * 4 * h].to_vec();
                activate(&mut gr, h);
                for k in 0..h {
                    let (cn, tc) = cell(&gr, c0[s * h + k], k, h);
                    cv[s * h + k] = cn;
                    hv[s * h + k] = gr[3 * h + k] * tc;
                }
            }
            Ok(())
        })
    })?;
    Ok((tensor(hv, &[b, h], c)?, tensor(cv, &[b, h], c)?))
}

/// Gate activations in place: sigmoid for i, f, o; tanh for g.
#[inline(always)]
pub(crate) fn activate(g: &mut [f32], h: usize) {
    let (ifg, o) = g.split_at_mut(3 * h);
    let (i_f, gg) = ifg.split_at_mut(2 * h);
    i_f.iter_mut().for_each(|v| *v = sigmoid(*v));
    gg.iter_mut().for_each(|v| *v = tanh(*v));
    o.iter_mut().for_each(|v| *v = sigmoid(*v));
}

/// A row of the cell: `c = f·c_prev + i·g`, `tc = tanh c` from activated
/// gates `[i | f | g | o]`. Two plain loops over equal-length slices, so
/// both vectorise (a zip of five did not, and `tanh` ran one lane at a time).
#[inline(always)]
pub(crate) fn cell_rows(g: &[f32], c_prev: &[f32], c: &mut [f32], tc: &mut [f32], h: usize) {
    let (gi, gf, gg) = (&g[..h], &g[h..2 * h], &g[2 * h..3 * h]);
    let (c, tc, c_prev) = (&mut c[..h], &mut tc[..h], &c_prev[..h]);
    for k in 0..h {
        c[k] = gf[k] * c_prev[k] + gi[k] * gg[k];
    }
    for k in 0..h {
        tc[k] = tanh(c[k]);
    }
}

/// Unit `k` of the cell: `(c, tanh c)` from activated gates and `c_{t−1}`.
#[inline(always)]
fn cell(g: &[f32], c_prev: f32, k: usize, h: usize) -> (f32, f32) {
    let c = g[h + k] * c_prev + g[k] * g[2 * h + k];
    (c, tanh(c))
}

/// What the forward pass keeps for the backward pass.
struct Cache {
    /// Per row: `[z | h_{t−1}]`.
    u: Vec<f32>,
    /// Per row: `[μ | σ]`.
    e: Vec<f32>,
    /// Per row: activated gates.
    g: Vec<f32>,
    /// Per row: `c_t` and `tanh c_t`.
    c: Vec<f32>,
    tc: Vec<f32>,
}

/// The fused [`latent_lstm`].
struct ScanOp {
    dims: ScanDims,
    cache: Mutex<Option<Cache>>,
    /// `H` zeros (the cell before the first step).
    zeros: Vec<f32>,
    /// With `pre` in two blocks (the op's first two inputs), the noise,
    /// which is otherwise the second input.
    eps: Option<Vec<f32>>,
    /// Whether rows follow the weights in the third input, and whether one
    /// row serves every sequence.
    shared: Option<bool>,
}

impl ScanOp {
    fn new(dims: ScanDims, eps: Option<Vec<f32>>, shared: Option<bool>) -> ScanOp {
        ScanOp {
            dims,
            cache: Mutex::new(None),
            zeros: vec![0.0; dims.hidden],
            eps,
            shared,
        }
    }

    /// The op's inputs as slices: `pre`'s blocks, the noise, the weights
    /// and the rows.
    fn inputs<'a>(&'a self, a: &'a [f32], b: &'a [f32], w: &'a [f32]) -> Inputs<'a> {
        let (w, rows) = match self.shared {
            Some(_) => {
                let (w, r) = w.split_at(self.dims.weights());
                (w, Some(r))
            }
            None => (w, None),
        };
        match &self.eps {
            Some(eps) => Inputs {
                pre: Pre::Split(a, b),
                eps,
                w,
                rows,
            },
            None => Inputs {
                pre: Pre::Joint(a),
                eps: b,
                w,
                rows,
            },
        }
    }
}

/// `pre` as [`latent_lstm`] was given it.
#[derive(Clone, Copy)]
enum Pre<'a> {
    Joint(&'a [f32]),
    Split(&'a [f32], &'a [f32]),
}

impl<'a> Pre<'a> {
    /// Row `q` (input order): its posterior part and its gates' part.
    #[inline(always)]
    fn row(&self, q: usize, z2: usize, h4: usize) -> (&'a [f32], &'a [f32]) {
        match *self {
            Pre::Joint(p) => p[q * (z2 + h4)..(q + 1) * (z2 + h4)].split_at(z2),
            Pre::Split(e, g) => (&e[q * z2..(q + 1) * z2], &g[q * h4..(q + 1) * h4]),
        }
    }
}

/// What [`forward`] and [`backward`] read.
struct Inputs<'a> {
    pre: Pre<'a>,
    eps: &'a [f32],
    w: &'a [f32],
    /// `[B or 1, 2Z + 4H]` added to every step.
    rows: Option<&'a [f32]>,
}

/// `[W_z | W_h]` as one `[4H, Z + H]` matrix (applied to `[z | h]`).
fn pack_zh(w: &[f32], d: ScanDims) -> Vec<f32> {
    let (h, z) = (d.hidden, d.latent);
    let (wz, wh) = (
        &w[2 * z * h..2 * z * h + 4 * h * z],
        &w[2 * z * h + 4 * h * z..],
    );
    let zh = z + h;
    let mut out = vec![0.0f32; 4 * h * zh];
    for r in 0..4 * h {
        out[r * zh..r * zh + z].copy_from_slice(&wz[r * z..(r + 1) * z]);
        out[r * zh + z..(r + 1) * zh].copy_from_slice(&wh[r * h..(r + 1) * h]);
    }
    out
}

/// The posterior and gate pre-activations of [`forward`], time-major,
/// before the recurrence adds to them: `pre`'s two parts (filled by
/// copying, not zeroed first), plus the rows where given.
#[inline(always)]
fn start_pre(op: &ScanOp, x: &Inputs, b: usize, tt: usize) -> (Vec<f32>, Vec<f32>) {
    let (p, z2, h4) = (op.dims.pre(), 2 * op.dims.latent, 4 * op.dims.hidden);
    let n = b * tt;
    let (mut e, mut g) = (Vec::with_capacity(n * z2), Vec::with_capacity(n * h4));
    let per = if op.shared == Some(true) { 0 } else { p };
    for t in 0..tt {
        for s in 0..b {
            let (pe, pg) = x.pre.row(s * tt + t, z2, h4);
            match x.rows {
                Some(r) => {
                    let (re, rg) = r[s * per..s * per + p].split_at(z2);
                    e.extend(pe.iter().zip(re).map(|(a, c)| a + c));
                    g.extend(pg.iter().zip(rg).map(|(a, c)| a + c));
                }
                None => {
                    e.extend_from_slice(pe);
                    g.extend_from_slice(pg);
                }
            }
        }
    }
    (e, g)
}

simd_fn! {
/// The recurrence forward over `b` sequences of `tt` rows: the output rows
/// and what the backward pass needs. Inside, rows are time-major (row
/// `t·b + s` is step `t` of sequence `s`), so the `b` rows of one step lie
/// together: in the input's order (`s·tt + t`) they were `tt` rows apart, a
/// power-of-two stride that made every step's rows fight for the same
/// cache sets.
fn forward(op: &ScanOp, x: &Inputs, b: usize, tt: usize) -> (Vec<f32>, Cache) {
    let (eps, w) = (x.eps, x.w);
    let ScanDims {
        hidden: h,
        latent: z,
    } = op.dims;
    let (o, zh, z2, h4) = (op.dims.out(), z + h, 2 * z, 4 * h);
    let n = b * tt;
    let wzh = pack_zh(w, op.dims);
    let (pe, pg) = (
        Packed::new(w, tr(0, h), h, z2),
        Packed::new(&wzh, tr(0, zh), zh, h4),
    );
    let mut u = vec![0.0f32; n * zh];
    let mut c = vec![0.0f32; n * h];
    let mut tc = vec![0.0f32; n * h];
    let (mut e, mut g) = start_pre(op, x, b, tt);
    for t in 0..tt {
        let base = t * b;
        if t > 0 {
            // e += h · W_eᵀ
            mm_small(
                (b, z2, h),
                &mut e,
                rm(base * z2, z2),
                true,
                &u,
                rm(base * zh + z, zh),
                w,
                tr(0, h),
                &pe,
            );
        }
        for s in 0..b {
            let r = base + s;
            let (mu, sg) = e[r * z2..(r + 1) * z2].split_at_mut(z);
            sg.iter_mut().for_each(|v| *v = sigma(*v));
            let ur = &mut u[r * zh..r * zh + z];
            let ep = &eps[(s * tt + t) * z..(s * tt + t + 1) * z];
            for (((o, m), sv), ev) in ur.iter_mut().zip(&*mu).zip(&*sg).zip(ep) {
                *o = m + sv * ev;
            }
        }
        // g += [z | h] · [W_z | W_h]ᵀ
        mm_small(
            (b, h4, zh),
            &mut g,
            rm(base * h4, h4),
            true,
            &u,
            rm(base * zh, zh),
            &wzh,
            tr(0, zh),
            &pg,
        );
        for s in 0..b {
            let r = base + s;
            let gr = &mut g[r * h4..(r + 1) * h4];
            activate(gr, h);
            let (before, now) = c.split_at_mut(r * h);
            let c_prev = if t > 0 {
                &before[(r - b) * h..(r - b + 1) * h]
            } else {
                &op.zeros[..h]
            };
            let (cn, tn) = (&mut now[..h], &mut tc[r * h..(r + 1) * h]);
            cell_rows(gr, c_prev, cn, tn, h);
            if t + 1 < tt {
                let hn = &mut u[(r + b) * zh + z..(r + b + 1) * zh];
                for ((o, og), tv) in hn.iter_mut().zip(&gr[3 * h..]).zip(&*tn) {
                    *o = og * tv;
                }
            }
        }
    }
    // The output in the input's order.
    let mut out = Vec::with_capacity(n * o);
    for s in 0..b {
        for t in 0..tt {
            let r = t * b + s;
            out.extend_from_slice(&u[r * zh + z..(r + 1) * zh]);
            out.extend_from_slice(&e[r * z2..(r + 1) * z2]);
            out.extend_from_slice(&u[r * zh..r * zh + z]);
        }
    }
    (out, Cache { u, e, g, c, tc })
}
}

/// Step `t`'s gate gradients (rows time-major, as in [`backward`]) from
/// the gradient of the state after it (what step `t + 1` left in `du`) and
/// of the cell (`dc`, per sequence, carried back a step).
#[inline(always)]
fn gate_grads(
    op: &ScanOp,
    cache: &Cache,
    du: &[f32],
    dg: &mut [f32],
    dc: &mut [f32],
    (b, tt, t): (usize, usize, usize),
) {
    let (h, z) = (op.dims.hidden, op.dims.latent);
    let (zh, h4) = (z + h, 4 * h);
    let Cache { g, c, tc, .. } = cache;
    let base = t * b;
    for s in 0..b {
        let r = base + s;
        let gr = &g[r * h4..(r + 1) * h4];
        let (gi, rest) = gr.split_at(h);
        let (gf, rest) = rest.split_at(h);
        let (gg, go) = (&rest[..h], &rest[h..2 * h]);
        let (di, rest) = dg[r * h4..(r + 1) * h4].split_at_mut(h);
        let (df, rest) = rest.split_at_mut(h);
        let (dgg, dgo) = rest.split_at_mut(h);
        let dgo = &mut dgo[..h];
        // Gradient of h_t: what step t + 1 saw as h_{t−1}.
        let dh = if t + 1 < tt {
            &du[(r + b) * zh + z..(r + b + 1) * zh]
        } else {
            &op.zeros[..h]
        };
        let c_prev = if t > 0 {
            &c[(r - b) * h..(r - b + 1) * h]
        } else {
            &op.zeros[..h]
        };
        let tcr = &tc[r * h..(r + 1) * h];
        let dcr = &mut dc[s * h..(s + 1) * h];
        for k in 0..h {
            let (ig, fg, gv, og) = (gi[k], gf[k], gg[k], go[k]);
            let tcv = tcr[k];
            let dcv = dcr[k] + dh[k] * og * (1.0 - tcv * tcv);
            dcr[k] = dcv * fg;
            di[k] = dcv * gv * ig * (1.0 - ig);
            df[k] = dcv * c_prev[k] * fg * (1.0 - fg);
            dgg[k] = dcv * ig * (1.0 - gv * gv);
            dgo[k] = dh[k] * tcv * og * (1.0 - og);
        }
    }
}

/// `pre`'s gradient in the input's order and the weights' gradients, from
/// the time-major `de`, `dg` and rows `u` of [`backward`] (the weights'
/// gradients sum the rows in the input's order).
#[inline(always)]
fn weight_grads(
    op: &ScanOp,
    u: &[f32],
    de: &[f32],
    dg: &[f32],
    b: usize,
    tt: usize,
) -> (Vec<f32>, Vec<f32>) {
    let (h, z) = (op.dims.hidden, op.dims.latent);
    let (p, zh, z2, h4) = (op.dims.pre(), z + h, 2 * z, 4 * h);
    let n = b * tt;
    // Back to the input's order: `pre`'s gradient, and the rows the weights'
    // gradients sum over (in that order, so the sums keep their order).
    let (mut dpre, mut ub) = (Vec::with_capacity(n * p), Vec::with_capacity(n * zh));
    for s in 0..b {
        for t in 0..tt {
            let r = t * b + s;
            dpre.extend_from_slice(&de[r * z2..(r + 1) * z2]);
            dpre.extend_from_slice(&dg[r * h4..(r + 1) * h4]);
            ub.extend_from_slice(&u[r * zh..(r + 1) * zh]);
        }
    }
    // Weights, batched over all rows.
    let mut dw = vec![0.0f32; op.dims.weights()];
    mm(
        (z2, h, n),
        &mut dw,
        rm(0, h),
        false,
        &dpre,
        tr(0, p),
        &ub,
        rm(z, zh),
    );
    let mut dwzh = vec![0.0f32; h4 * zh];
    mm(
        (h4, zh, n),
        &mut dwzh,
        rm(0, zh),
        false,
        &dpre,
        tr(z2, p),
        &ub,
        rm(0, zh),
    );
    let (oz, oh) = (2 * z * h, 2 * z * h + 4 * h * z);
    for r in 0..h4 {
        dw[oz + r * z..oz + (r + 1) * z].copy_from_slice(&dwzh[r * zh..r * zh + z]);
        dw[oh + r * h..oh + (r + 1) * h].copy_from_slice(&dwzh[r * zh + z..(r + 1) * zh]);
    }
    (dpre, dw)
}

simd_fn! {
/// Gradients of `pre` and `w` given the output's gradient `dout` (rows
/// time-major inside, as in [`forward`]; the weights' gradients sum the
/// rows in the input's order).
fn backward(
    op: &ScanOp,
    cache: &Cache,
    dout: &[f32],
    x: &Inputs,
    b: usize,
    tt: usize,
) -> (Vec<f32>, Vec<f32>) {
    let (eps, w) = (x.eps, x.w);
    let ScanDims {
        hidden: h,
        latent: z,
    } = op.dims;
    let (o, zh, z2, h4) = (op.dims.out(), z + h, 2 * z, 4 * h);
    let n = b * tt;
    let wzh = pack_zh(w, op.dims);
    let (pg, pe) = (
        Packed::new(&wzh, rm(0, zh), h4, zh),
        Packed::new(w, rm(0, h), z2, h),
    );
    let Cache { u, e, .. } = cache;
    // dU holds, per row, d[z | h_{t−1}]; starts with the output's part.
    let mut du = vec![0.0f32; n * zh];
    for s in 0..b {
        for t in 0..tt {
            let (r, q) = (t * b + s, s * tt + t);
            du[r * zh..r * zh + z].copy_from_slice(&dout[q * o + h + z2..(q + 1) * o]);
            du[r * zh + z..(r + 1) * zh].copy_from_slice(&dout[q * o..q * o + h]);
        }
    }
    let mut de = vec![0.0f32; n * z2];
    let mut dg = vec![0.0f32; n * h4];
    let mut dc = vec![0.0f32; b * h];
    for t in (0..tt).rev() {
        let base = t * b;
        gate_grads(op, cache, &du, &mut dg, &mut dc, (b, tt, t));
        // d[z | h] += dG · [W_z | W_h]
        mm_small(
            (b, zh, h4),
            &mut du,
            rm(base * zh, zh),
            true,
            &dg,
            rm(base * h4, h4),
            &wzh,
            rm(0, zh),
            &pg,
        );
        for s in 0..b {
            let (r, q) = (base + s, s * tt + t);
            for k in 0..z {
                let dz = du[r * zh + k];
                let sv = e[r * z2 + z + k];
                de[r * z2 + k] = dout[q * o + h + k] + dz;
                de[r * z2 + z + k] = (dout[q * o + h + z + k] + dz * eps[q * z + k]) * dsigma(sv);
            }
        }
        if t > 0 {
            // dh_{t−1} += dE · W_e
            mm_small(
                (b, h, z2),
                &mut du,
                rm(base * zh + z, zh),
                true,
                &de,
                rm(base * z2, z2),
                w,
                rm(0, h),
                &pe,
            );
        }
    }
    weight_grads(op, u, &de, &dg, b, tt)
}
}

impl CustomOp3 for ScanOp {
    fn name(&self) -> &'static str {
        "latent-lstm"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (a, b2, w) = (
            slice(s1, l1, "pre")?,
            slice(s2, l2, "eps or pre")?,
            slice(s3, l3, "w")?,
        );
        let (b, t, _) = l1.shape().dims3()?;
        let (out, cache) = forward(self, &self.inputs(a, b2, w), b, t);
        *self.cache.lock().unwrap_or_else(|p| p.into_inner()) = Some(cache);
        Ok((CpuStorage::F32(out), Shape::from((b, t, self.dims.out()))))
    }

    fn bwd(
        &self,
        a: &Tensor,
        b2: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let (b, t, _) = a.dims3()?;
        let cached = self.cache.lock().unwrap_or_else(|p| p.into_inner()).take();
        let (dpre, mut dw) = with_values(a, |av| {
            with_values(b2, |bv| {
                with_values(w, |wv| {
                    let x = self.inputs(av, bv, wv);
                    let cache = match cached {
                        Some(c) => c,
                        None => forward(self, &x, b, t).1,
                    };
                    with_values(grad, |g| Ok(backward(self, &cache, g, &x, b, t)))
                })
            })
        })?;
        // The rows' gradient after the weights', as their input holds them.
        if let Some(shared) = self.shared {
            dw.extend(row_sums(&dpre, [b, t, self.dims.pre()], shared));
        }
        let dw = Some(tensor(dw, w.dims(), w)?);
        if self.eps.is_none() {
            return Ok((Some(tensor(dpre, a.dims(), a)?), None, dw));
        }
        let z2 = 2 * self.dims.latent;
        let (de, dg) = split_columns(&dpre, self.dims.pre(), z2);
        Ok((
            Some(tensor(de, a.dims(), a)?),
            Some(tensor(dg, b2.dims(), b2)?),
            dw,
        ))
    }
}

/// Rows of width `n` cut into their first `left` columns and the rest.
fn split_columns(v: &[f32], n: usize, left: usize) -> (Vec<f32>, Vec<f32>) {
    let rows = v.len() / n.max(1);
    let (mut a, mut b) = (
        Vec::with_capacity(rows * left),
        Vec::with_capacity(rows * (n - left)),
    );
    for r in v.chunks_exact(n.max(1)) {
        a.extend_from_slice(&r[..left]);
        b.extend_from_slice(&r[left..]);
    }
    (a, b)
}
