//! The backward of the rollout ([`fed_backward`]): back through every step
//! of [`super::pass`], then each weight's gradient as one product over all
//! rows.

use super::*;
use crate::blocks::kernels::{dsigma, mm, rm, simd_fn, tr};

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
/// rows (laid out as [`Cond::rows`]).
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
    pub cond: Option<Vec<f32>>,
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

/// The sizes [`fed_backward`] reads, and the filters' gains.
#[derive(Clone, Copy)]
struct Dims {
    h: usize,
    z: usize,
    f: usize,
    b: usize,
    tt: usize,
    e1: usize,
    e2: usize,
    z2: usize,
    h4: usize,
    zh: usize,
    width: usize,
    enc_in: usize,
    gin: usize,
    g_in: f32,
    g_out: f32,
    bones: usize,
    /// Width of a row of the op's output and its gradient
    /// ([`RolloutOp::width`]).
    ow: usize,
}

/// What [`fed_backward`] reads and carries from step to step.
struct Back<'a> {
    net: &'a Net,
    sh: &'a Shard<'a>,
    tape: &'a Tape,
    /// The op's output and its gradient, rows [`Dims::ow`] wide.
    fed: &'a [f32],
    dout: &'a [f32],
    dims: Dims,
    gr: Grads,
    /// Carried between steps: d h_t and d c_t, the filters' and the lock's
    /// gradients of the step before.
    dh: Vec<f32>,
    dc: Vec<f32>,
    dhp: Vec<f32>,
    czf: Vec<f32>,
    cof: Vec<f32>,
    cprev: Vec<f32>,
    cnext: Vec<f32>,
    down: Vec<f32>,
    /// Per step, over its rows: the features' and the fed frames' gradients
    /// from the gates (`gx`, `dxs`), and the decoder's input's (`dus`).
    gx: Vec<f32>,
    dxs: Vec<f32>,
    dus: Vec<f32>,
    /// Each layer's output gradient per row (`t·B + s`), and the inputs the
    /// tape does not hold in that order, for the weights' gradients at the
    /// end: the gates (`[n, 4H]`) read the features `xin` (the fed frame's,
    /// or the real one's) and `z_q`, `h`; φ₁, φ₂ the fed frames (`xf`);
    /// the posterior the real features (`fr`) and `h`.
    dgs: Vec<f32>,
    dzq: Vec<f32>,
    xin: Vec<f32>,
    fr: Vec<f32>,
    dq2: Vec<f32>,
    dq1: Vec<f32>,
    xf: Vec<f32>,
    dofs: Vec<f32>,
    da2: Vec<f32>,
    da1: Vec<f32>,
    dps: Vec<f32>,
    des: Vec<f32>,
    /// Every product of a step's backward, its weights packed once.
    gates_x: Rhs<'a>,
    gates_z: Rhs<'a>,
    gates_h: Rhs<'a>,
    phi: [Rhs<'a>; 2],
    dec: [Rhs<'a>; 3],
    prior: Rhs<'a>,
    enc_x: Rhs<'a>,
    enc_h: Rhs<'a>,
}

#[allow(clippy::needless_range_loop)] // several arrays indexed alike
impl<'a> Back<'a> {
    /// Zero gradients and buffers for the backward of `tape`'s pass.
    #[inline(always)]
    fn new(
        net: &'a Net,
        sh: &'a Shard<'a>,
        tape: &'a Tape,
        fed: &'a [f32],
        dout: &'a [f32],
    ) -> Back<'a> {
        let (h, z, f, b, tt) = (net.hidden, net.latent, net.input, sh.b, sh.t);
        let (e1, e2, d) = (net.phi[0].out, net.phi[1].out, &net.decoder);
        let (z2, h4, zh, width) = (2 * z, 4 * h, z + h, d[2].out);
        let (enc_in, gin) = (net.encoder.inp, e2 + z);
        let gain = |rho: f32| (1.0 - rho * rho).max(0.0).sqrt();
        let (g_in, g_out) = (gain(net.rho), gain(net.rho_out));
        let bones = crate::blocks::skeleton::BONES;
        let ow = f + h + 3 * z;
        let gr = Grads {
            feat: vec![0.0; b * tt * e2],
            phi: [DenseGrad::of(&net.phi[0]), DenseGrad::of(&net.phi[1])],
            encoder: DenseGrad::of(&net.encoder),
            prior: DenseGrad::of(&net.prior),
            decoder: [
                DenseGrad::of(&d[0]),
                DenseGrad::of(&d[1]),
                DenseGrad::of(&d[2]),
            ],
            w_ih: vec![0.0; net.w_ih.len()],
            w_hh: vec![0.0; net.w_hh.len()],
            b_gates: vec![0.0; h4],
            cond: sh.cond.as_ref().map(|c| vec![0.0; c.rows.len()]),
        };
        let n = b * tt;
        let rows = |w: usize| vec![0.0f32; n * w];
        Back {
            net,
            sh,
            tape,
            fed,
            dout,
            dims: Dims {
                h,
                z,
                f,
                b,
                tt,
                e1,
                e2,
                z2,
                h4,
                zh,
                width,
                enc_in,
                gin,
                g_in,
                g_out,
                bones,
                ow,
            },
            gr,
            dh: vec![0.0f32; b * h],
            dc: vec![0.0f32; b * h],
            dhp: vec![0.0f32; b * h],
            czf: vec![0.0f32; b * z],
            cof: vec![0.0f32; b * width],
            cprev: vec![0.0f32; b * f],
            cnext: vec![0.0f32; b * f],
            down: vec![0.0f32; f],
            gx: vec![0.0f32; b * e2],
            dxs: vec![0.0f32; b * f],
            dus: vec![0.0f32; b * zh],
            dgs: rows(h4),
            dzq: rows(z),
            xin: rows(e2),
            fr: rows(e2),
            dq2: rows(e2),
            dq1: rows(e1),
            xf: rows(f),
            dofs: rows(width),
            da2: rows(d[1].out),
            da1: rows(d[0].out),
            dps: rows(z2),
            des: rows(z2),
            gates_x: Rhs::back(&net.w_ih, gin, 0, h4, e2),
            gates_z: Rhs::back(&net.w_ih, gin, e2, h4, z),
            gates_h: Rhs::back(&net.w_hh, h, 0, h4, h),
            phi: [Rhs::back_of(&net.phi[0]), Rhs::back_of(&net.phi[1])],
            dec: [
                Rhs::back_of(&d[0]),
                Rhs::back_of(&d[1]),
                Rhs::back_of(&d[2]),
            ],
            prior: Rhs::back_of(&net.prior),
            enc_x: Rhs::back(&net.encoder.w, enc_in, 0, z2, e2),
            enc_h: Rhs::back(&net.encoder.w, enc_in, e2, z2, h),
        }
    }

    /// Step `t` back through the cell into the gates and their inputs
    /// (`z_q`, `h_{t−1}`, the frame's features).
    #[inline(always)]
    fn cell(&mut self, t: usize) {
        let Dims {
            h,
            z,
            f,
            b,
            tt,
            e2,
            z2,
            h4,
            ow,
            ..
        } = self.dims;
        let step = |t: usize, w: usize| t * b * w..(t + 1) * b * w;
        let r0 = t * b;
        let Back {
            sh,
            tape,
            dout,
            gr,
            gates_x,
            gates_z,
            gates_h,
            dh,
            dc,
            dhp,
            cnext,
            gx,
            dgs,
            dzq,
            ..
        } = self;
        dhp.fill(0.0);
        cnext.fill(0.0);
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
                let at = c.at(Part::Pre, b, s, t) + z2;
                add(&mut gc[at..at + h4], dg);
            }
        }
        // The gates' inputs: z_q, h_{t−1}, and the frame's features (the
        // fed frame's own, or the real one's).
        let dg = &dgs[step(t, h4)];
        gates_z.rows(b, &mut dzq[step(t, z)], rm(0, z), false, dg);
        // And what the loss gives `z_t`.
        for s in 0..b {
            let at = (s * tt + t) * ow + f + h + z2;
            add(&mut dzq[(r0 + s) * z..(r0 + s + 1) * z], &dout[at..at + z]);
        }
        if t > 0 {
            gates_h.rows(b, dhp, rm(0, h), true, dg);
        }
        gates_x.rows(b, gx, rm(0, e2), false, dg);
    }

    /// Step `t`'s gradient of the frame's features into the real ones, or
    /// back through φ₂, φ₁ into the fed frames.
    #[inline(always)]
    fn inputs(&mut self, t: usize) {
        let Dims {
            f,
            b,
            tt,
            e1,
            e2,
            ow,
            ..
        } = self.dims;
        let step = |t: usize, w: usize| t * b * w..(t + 1) * b * w;
        let r0 = t * b;
        let Back {
            sh,
            tape,
            fed,
            gr,
            phi,
            gx,
            dxs,
            xin,
            fr,
            dq2,
            dq1,
            xf,
            ..
        } = self;
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
                xf[r * f..(r + 1) * f].copy_from_slice(&fed[q * ow..q * ow + f]);
            } else {
                xin[r * e2..(r + 1) * e2].copy_from_slice(ft);
                add(&mut gr.feat[q * e2..(q + 1) * e2], g);
            }
        }
        // Back through φ₂ and φ₁ into the fed frames (rows not fed are zero).
        phi[1].rows(
            b,
            &mut dq1[step(t, e1)],
            rm(0, e1),
            false,
            &dq2[step(t, e2)],
        );
        for s in 0..b {
            if sh.mask[s * tt + t] != 0.0 {
                let r = r0 + s;
                let g1 = &mut dq1[r * e1..(r + 1) * e1];
                relu_back(g1, &tape.q1[r * e1..(r + 1) * e1]);
                add(&mut gr.phi[0].b, g1);
            }
        }
        phi[0].rows(b, dxs, rm(0, f), false, &dq1[step(t, e1)]);
    }

    /// Step `t` back from the fed frames through the foot lock, the
    /// skeleton and the output filter to the decoder's output.
    #[inline(always)]
    fn frames(&mut self, t: usize) {
        let Dims {
            f,
            b,
            tt,
            width,
            g_out,
            bones,
            ow,
            ..
        } = self.dims;
        let r0 = t * b;
        let Back {
            net,
            sh,
            tape,
            dout,
            gr,
            cof,
            cprev,
            cnext,
            down,
            dxs,
            dofs,
            ..
        } = self;
        for s in 0..b {
            let (r, q) = (r0 + s, s * tt + t);
            let m = sh.mask[q];
            // The fed frame x + m (own − x) → the own frame, plus what the
            // next step's lock gave it.
            for k in 0..f {
                down[k] = m * (dout[q * ow + k] + dxs[s * f + k]) + cprev[s * f + k];
            }
            let mut dlog = [0.0f32; 2];
            if let Some(lock) = &net.lock {
                if let Some(lk) = &tape.lock[r] {
                    lock.lock_row_grad(lk, down, &mut cnext[s * f..(s + 1) * f], &mut dlog);
                }
                lock.ground_row_grad(&tape.ground[r], down, &mut dlog);
            }
            let ofr = &tape.of[r * width..(r + 1) * width];
            if let (Some(p), Some(l)) = (&net.place, sh.lengths) {
                p.row_grad(&ofr[..f], &l[q * bones..(q + 1) * bones], down);
            }
            // The output filter.
            let dof = &mut dofs[r * width..(r + 1) * width];
            dof[..f].copy_from_slice(down);
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
    }

    /// Step `t` back through the decoder's layers to its input `[z, h]`.
    #[inline(always)]
    fn decoder(&mut self, t: usize) {
        let Dims { b, zh, width, .. } = self.dims;
        let step = |t: usize, w: usize| t * b * w..(t + 1) * b * w;
        let r0 = t * b;
        let Back {
            net,
            sh,
            tape,
            gr,
            dec,
            dus,
            dofs,
            da2,
            da1,
            ..
        } = self;
        let d = &net.decoder;
        // The decoder.
        dec[2].rows(
            b,
            &mut da2[step(t, d[1].out)],
            rm(0, d[1].out),
            false,
            &dofs[step(t, width)],
        );
        for s in 0..b {
            let r = r0 + s;
            let g2 = &mut da2[r * d[1].out..(r + 1) * d[1].out];
            relu_back(g2, &tape.a2[r * d[1].out..(r + 1) * d[1].out]);
            add(&mut gr.decoder[1].b, g2);
        }
        dec[1].rows(
            b,
            &mut da1[step(t, d[0].out)],
            rm(0, d[0].out),
            false,
            &da2[step(t, d[1].out)],
        );
        for s in 0..b {
            let r = r0 + s;
            let g1 = &mut da1[r * d[0].out..(r + 1) * d[0].out];
            relu_back(g1, &tape.a1[r * d[0].out..(r + 1) * d[0].out]);
            add(&mut gr.decoder[0].b, g1);
            if let (Some(c), Some(gc)) = (&sh.cond, gr.cond.as_mut()) {
                let at = c.at(Part::Decoder, b, s, t);
                add(&mut gc[at..at + d[0].out], g1);
            }
        }
        dec[0].rows(b, dus, rm(0, zh), false, &da1[step(t, d[0].out)]);
    }

    /// Step `t` back through the latent filter, the prior's and the
    /// posterior's draws into `h_{t−1}` and the real features.
    #[inline(always)]
    fn latents(&mut self, t: usize) {
        let Dims {
            h,
            z,
            f,
            b,
            tt,
            e2,
            z2,
            zh,
            g_in,
            ow,
            ..
        } = self.dims;
        let step = |t: usize, w: usize| t * b * w..(t + 1) * b * w;
        let r0 = t * b;
        let Back {
            net,
            sh,
            tape,
            dout,
            gr,
            prior,
            enc_x,
            enc_h,
            dh,
            dhp,
            czf,
            cprev,
            cnext,
            dus,
            dzq,
            dps,
            des,
            ..
        } = self;
        for s in 0..b {
            let (r, q) = (r0 + s, s * tt + t);
            let du = &dus[s * zh..(s + 1) * zh];
            add(&mut dhp[s * h..(s + 1) * h], &du[z..]);
            // What the loss gives `h_{t−1}`, `μ_t`, `σ_t`.
            let dl = &dout[q * ow + f..q * ow + f + h + z2];
            add(&mut dhp[s * h..(s + 1) * h], &dl[..h]);
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
                    let at = c.at(Part::Prior, b, s, t);
                    add(&mut gc[at..at + z2], dp);
                }
            }
            // The posterior's draw: from the real frame's features and h.
            let de = &mut des[r * z2..(r + 1) * z2];
            for j in 0..z {
                let dz = dzq[r * z + j];
                de[j] = dz + dl[h + j];
                de[z + j] = (dz * sh.eps[q * z + j] + dl[h + z + j]) * dsigma(tape.sq[r * z + j]);
            }
            let de = &des[r * z2..(r + 1) * z2];
            add(&mut gr.encoder.b, de);
            if let (Some(c), Some(gc)) = (&sh.cond, gr.cond.as_mut()) {
                let at = c.at(Part::Pre, b, s, t);
                add(&mut gc[at..at + z2], de);
            }
        }
        if t > 0 {
            prior.rows(b, dhp, rm(0, h), true, &dps[step(t, z2)]);
            enc_h.rows(b, dhp, rm(0, h), true, &des[step(t, z2)]);
        }
        enc_x.rows(
            b,
            &mut gr.feat,
            rm(t * e2, tt * e2),
            true,
            &des[step(t, z2)],
        );
        std::mem::swap(dh, dhp);
        std::mem::swap(cprev, cnext);
    }

    /// The gradients, with the weights' each one product over all rows.
    #[inline(always)]
    fn weights(self) -> Grads {
        let Dims {
            h,
            z,
            f,
            e1,
            e2,
            z2,
            h4,
            zh,
            width,
            enc_in,
            gin,
            ..
        } = self.dims;
        let Back {
            net,
            tape,
            mut gr,
            dgs,
            xin,
            fr,
            dq2,
            dq1,
            xf,
            dofs,
            da2,
            da1,
            dps,
            des,
            ..
        } = self;
        let d = &net.decoder;
        // The weights' gradients, each one product over all rows (`h` is zero
        // at the first step, as are the rows of a part that did not run).
        weight_grad(&mut gr.w_ih, gin, 0, &dgs, h4, &xin, e2);
        weight_grad(&mut gr.w_ih, gin, e2, &dgs, h4, &tape.zq, z);
        weight_grad(&mut gr.w_hh, h, 0, &dgs, h4, &tape.h, h);
        weight_grad(&mut gr.phi[1].w, e1, 0, &dq2, e2, &tape.q1, e1);
        weight_grad(&mut gr.phi[0].w, f, 0, &dq1, e1, &xf, f);
        weight_grad(
            &mut gr.decoder[2].w,
            d[2].inp,
            0,
            &dofs,
            width,
            &tape.a2,
            d[1].out,
        );
        weight_grad(
            &mut gr.decoder[1].w,
            d[1].inp,
            0,
            &da2,
            d[1].out,
            &tape.a1,
            d[0].out,
        );
        weight_grad(&mut gr.decoder[0].w, zh, 0, &da1, d[0].out, &tape.zf, z);
        weight_grad(&mut gr.decoder[0].w, zh, z, &da1, d[0].out, &tape.h, h);
        weight_grad(&mut gr.prior.w, h, 0, &dps, z2, &tape.h, h);
        weight_grad(&mut gr.encoder.w, enc_in, 0, &des, z2, &fr, e2);
        weight_grad(&mut gr.encoder.w, enc_in, e2, &des, z2, &tape.h, h);
        gr
    }
}

simd_fn! {
/// The backward of [`RolloutOp`]: the gradients of everything its output
/// `fed` (each fed frame and the recurrence's `h | μ | σ | z`,
/// [`RolloutOp::width`] wide) was made of, given theirs (`dout`, laid out
/// alike), through every step of the recurrence, the prior's draws, the
/// decoder, the filters, the skeleton and the foot lock (module docs).
pub fn fed_backward(net: &Net, sh: &Shard, tape: &Tape, fed: &[f32], dout: &[f32]) -> Grads {
    let mut k = Back::new(net, sh, tape, fed, dout);
    for t in (0..sh.t).rev() {
        k.cell(t);
        k.inputs(t);
        k.frames(t);
        k.decoder(t);
        k.latents(t);
    }
    k.weights()
}
}
