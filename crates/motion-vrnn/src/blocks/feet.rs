//! The foot lock over whole sequences: grounding (a planted toe stands at
//! the floor height) and root motion from the planted toes, as one fused op
//! with its own backward. [`ground`] and [`lock`] are the reference (and the
//! per-step path of sampling).
//!
//! Per frame `t` of normalised features `x_t` (root height, 18 joints,
//! planar velocity `v`, turn `θ`) with contact probabilities
//! `p = sigmoid(logits_t)` of the two toes:
//!
//! ```text
//! g_t   = ground(x_t)            every height + α·(h_c − Σ p_i y_i / Σ p_i)
//! out_0 = g_0
//! out_t = lock(g_{t−1}, g_t)     v_t = α·v_lock + (1 − α)·v_t,
//!                                v_lock = Σ p_i (q_i,t−1 − R(θ_t) q_i,t) / Σ p_i
//! ```
//!
//! with `α = 1 − Π (1 − p_i)`, `y_i` a toe's height and `q_i` its planar
//! local position (raw CMU units: features times std plus mean).

use super::skeleton::BONES;
use super::{fused, slice, tensor, with_values};
use candle_core::{CpuStorage, CustomOp2, DType, Layout, Result, Shape, Tensor, D};

/// The toes (joint indices) whose contact the foot lock predicts.
pub const TOES: [usize; 2] = [4, 8];

/// Toe height under which a foot is on the floor (CMU units: 5 cm).
pub const CONTACT_UNITS: f64 = 0.05 / 0.0564;

/// Added to `Σ p_i` before dividing by it.
const EPS: f32 = 1e-6;

/// What the foot lock needs to know of the features.
#[derive(Clone, Copy, Debug)]
pub struct Stats<'a> {
    /// Mean of each feature.
    pub mean: &'a [f32],
    /// Standard deviation of each feature.
    pub std: &'a [f32],
    /// Height of a planted toe (CMU units).
    pub contact_height: f32,
}

/// Raw (CMU-unit) value of feature `k` of normalised rows `v: […, input]`.
pub fn raw_col(v: &Tensor, k: usize, body: &Stats) -> Result<Tensor> {
    (v.narrow(D::Minus1, k, 1)? * body.std[k] as f64)? + body.mean[k] as f64
}

/// The foot lock over sequences: `x: [B, T, F]` normalised features,
/// `logits: [B, T, 2]` → `[B, T, F]` (see the module docs).
pub fn foot_lock(x: &Tensor, logits: &Tensor, body: &Stats) -> Result<Tensor> {
    let (_, t, f) = x.dims3()?;
    if body.mean.len() != f || body.std.len() != f || f != 1 + 3 * BONES + 3 {
        candle_core::bail!("foot_lock: {f} features, statistics of {}", body.mean.len());
    }
    if fused(x) {
        return x
            .contiguous()?
            .apply_op2(&logits.contiguous()?, FootLockOp::new(body));
    }
    let g = ground(x, logits, body)?;
    if t < 2 {
        return Ok(g);
    }
    let locked = lock(
        &g.narrow(1, 0, t - 1)?,
        &g.narrow(1, 1, t - 1)?,
        &logits.narrow(1, 1, t - 1)?,
        body,
    )?;
    Tensor::cat(&[&g.narrow(1, 0, 1)?, &locked], 1)
}

/// Vertical half of the foot lock: every height of normalised rows
/// `x: […, input]` (the root's and each joint's local y) moved by
/// `α·(h_c − y_lock)`, where `y_lock` is the toes' height weighted by their
/// contact probabilities, `h_c` the training set's toe height in contact and
/// `α` the probability that some foot is down: a planted foot stands on the
/// floor, so the figure can neither sink nor float while it is planted.
pub fn ground(x: &Tensor, logits: &Tensor, body: &Stats) -> Result<Tensor> {
    let f = x.dim(D::Minus1)?;
    let p = candle_nn::ops::sigmoid(logits)?;
    let mut wy: Option<Tensor> = None;
    for (i, &toe) in TOES.iter().enumerate() {
        let y = raw_col(x, 1 + 3 * (toe - 1) + 1, body)?;
        let term = (p.narrow(D::Minus1, i, 1)? * y)?;
        wy = Some(match wy {
            None => term,
            Some(a) => (a + term)?,
        });
    }
    let wsum = p.sum_keepdim(D::Minus1)?;
    let none = (1.0 - p.narrow(D::Minus1, 0, 1)?)?.mul(&(1.0 - p.narrow(D::Minus1, 1, 1)?)?)?;
    let y_lock = (wy.unwrap_or(wsum.zeros_like()?) / (&wsum + 1e-6)?)?;
    let shift = ((1.0 - none)? * (body.contact_height as f64 - y_lock)?)?;
    x + shift.broadcast_mul(&per_height(f, body, x.device())?)?
}

/// `1/std` on the `f` features' height columns (the root's and each
/// joint's local y), 0 elsewhere: a height shift in CMU units, normalised.
fn per_height(f: usize, body: &Stats, device: &candle_core::Device) -> Result<Tensor> {
    let mut per: Vec<f32> = vec![0.0; f];
    per[0] = 1.0 / body.std[0];
    for j in 0..BONES {
        let k = 1 + 3 * j + 1;
        per[k] = 1.0 / body.std[k];
    }
    Tensor::new(per.as_slice(), device)
}

/// The foot lock: frame `cur` (normalised `[…, n, input]`) with the root's
/// planar velocity replaced by `α·v_lock + (1 − α)·v`, where `v_lock` keeps
/// the toes of `prev` in place (each toe weighted by its contact
/// probability `sigmoid(logits)`), `α = 1 − Π(1 − p)` the probability that
/// some foot is down and `v` the decoded velocity.
pub fn lock(prev: &Tensor, cur: &Tensor, logits: &Tensor, body: &Stats) -> Result<Tensor> {
    let f = cur.dim(D::Minus1)?;
    let (kx, kz, kt) = (f - 3, f - 2, f - 1);
    let th = raw_col(cur, kt, body)?;
    let (c, s) = (th.cos()?, th.sin()?);
    let p = candle_nn::ops::sigmoid(logits)?;
    let (mut wx, mut wz) = (Tensor::zeros_like(&th)?, Tensor::zeros_like(&th)?);
    let mut wsum = Tensor::zeros_like(&th)?;
    let mut none = Tensor::ones_like(&th)?;
    for (i, &toe) in TOES.iter().enumerate() {
        let k = 1 + 3 * (toe - 1);
        let (lx, lz) = (raw_col(cur, k, body)?, raw_col(cur, k + 2, body)?);
        let (px, pz) = (raw_col(prev, k, body)?, raw_col(prev, k + 2, body)?);
        // s = v + R(θ)·p_t − p_{t−1} = 0
        let vx = (px - ((&c * &lx)? + (&s * &lz)?)?)?;
        let vz = (pz - ((&c * &lz)? - (&s * &lx)?)?)?;
        let w = p.narrow(D::Minus1, i, 1)?;
        wx = (wx + (&w * vx)?)?;
        wz = (wz + (&w * vz)?)?;
        wsum = (wsum + &w)?;
        none = (none * (1.0 - &w)?)?;
    }
    let alpha = (1.0 - none)?;
    let blend = |lock: Tensor, k: usize| -> Result<Tensor> {
        let lock = (lock / (&wsum + 1e-6)?)?;
        let free = raw_col(cur, k, body)?;
        let v = ((&alpha * lock)? + ((1.0 - &alpha)? * free)?)?;
        (v - body.mean[k] as f64)? / body.std[k] as f64
    };
    let (vx, vz) = (blend(wx, kx)?, blend(wz, kz)?);
    Tensor::cat(
        &[
            &cur.narrow(D::Minus1, 0, kx)?,
            &vx,
            &vz,
            &cur.narrow(D::Minus1, kt, 1)?,
        ],
        D::Minus1,
    )
}

/// The foot-contact penalty: `Σ` over windows, frames `t ≥ 1` and both toes
/// where the real toe (in `x`) is below [`CONTACT_UNITS`], of the squared
/// horizontal displacement of the decoded toe (in `x_hat`) from frame
/// `t − 1` to `t` in the world, expressed in frame `t − 1`'s axes:
/// `s = v_t + R(θ_t)·p_t − p_{t−1}` with `v` the root's planar velocity,
/// `θ` its turn and `p` the toe's local (x, z) (see `to_global`).
pub fn foot_slide(x_hat: &Tensor, x: &Tensor, body: &Stats) -> Result<Tensor> {
    if fused(x_hat) {
        return x_hat.contiguous()?.apply_op2(
            &x.contiguous()?,
            SlideOp {
                mean: body.mean.to_vec(),
                std: body.std.to_vec(),
            },
        );
    }
    let (_, t, _) = x.dims3()?;
    if t < 2 {
        return Tensor::zeros((), DType::F32, x.device());
    }
    let xr = raw_rows(x, body)?;
    let mut total = Tensor::zeros((), DType::F32, x.device())?;
    for (toe, slide) in TOES.iter().zip(toe_slides(&raw_rows(x_hat, body)?)?) {
        let contact = xr
            .narrow(2, toe_col(*toe) + 1, 1)?
            .narrow(1, 1, t - 1)?
            .lt(CONTACT_UNITS)?
            .to_dtype(DType::F32)?;
        total = (total + (slide * contact)?.sum_all()?)?;
    }
    Ok(total)
}

/// Reference: the raw (CMU-unit) values of normalised rows `v: [B, T, F]`.
fn raw_rows(v: &Tensor, body: &Stats) -> Result<Tensor> {
    let dev = v.device();
    v.broadcast_mul(&Tensor::new(body.std, dev)?)?
        .broadcast_add(&Tensor::new(body.mean, dev)?)
}

/// Reference: for each of [`TOES`], its squared horizontal slide in the
/// world from frame `t − 1` to `t` of raw sequences `v: [B, T, F]`, for
/// frames `1..T` (`[B, T − 1, 1]`): `s = v_t + R(θ_t)·p_t − p_{t−1}`, as
/// [`real_slides`] computes it for one frame.
fn toe_slides(v: &Tensor) -> Result<Vec<Tensor>> {
    let (_, t, f) = v.dims3()?;
    let col = |k: usize, from: usize| v.narrow(2, k, 1)?.narrow(1, from, t - 1);
    let (vx, vz, th) = (col(f - 3, 1)?, col(f - 2, 1)?, col(f - 1, 1)?);
    let (c, s) = (th.cos()?, th.sin()?);
    TOES.iter()
        .map(|&toe| {
            let k = toe_col(toe);
            let (lx, lz) = (col(k, 1)?, col(k + 2, 1)?);
            let sx = (((&vx + (&c * &lx)?)? + (&s * &lz)?)? - col(k, 0)?)?;
            let sz = (((&vz - (&s * &lx)?)? + (&c * &lz)?)? - col(k + 2, 0)?)?;
            sx.sqr()? + sz.sqr()?
        })
        .collect()
}

/// The fused [`foot_lock`] (and its rows for [`super::rollout`]).
#[derive(Clone, Debug)]
pub(crate) struct FootLockOp {
    mean: Vec<f32>,
    std: Vec<f32>,
    contact_height: f32,
}

fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + (-v).exp())
}

/// The height columns: the root's and each joint's local y.
fn heights() -> impl Iterator<Item = usize> {
    std::iter::once(0).chain((0..BONES).map(|j| 1 + 3 * j + 1))
}

/// The column of a toe's local x (its y and z follow).
fn toe_col(toe: usize) -> usize {
    1 + 3 * (toe - 1)
}

/// What grounding computes for one row, kept for its backward.
pub(crate) struct Grounded {
    p: [f32; 2],
    y: [f32; 2],
    w: f32,
    y_lock: f32,
    alpha: f32,
}

/// What the lock computes for one row, kept for its backward.
pub(crate) struct Locked {
    p: [f32; 2],
    c: f32,
    s: f32,
    l: [[f32; 2]; 2],
    v: [[f32; 2]; 2],
    w: f32,
    alpha: f32,
    lock: [f32; 2],
    free: [f32; 2],
}

impl FootLockOp {
    pub(crate) fn new(body: &Stats) -> FootLockOp {
        FootLockOp {
            mean: body.mean.to_vec(),
            std: body.std.to_vec(),
            contact_height: body.contact_height,
        }
    }

    fn raw(&self, row: &[f32], k: usize) -> f32 {
        row[k] * self.std[k] + self.mean[k]
    }

    /// Ground one row in place.
    pub(crate) fn ground_row(&self, row: &mut [f32], logits: &[f32]) -> Grounded {
        let p = [sigmoid(logits[0]), sigmoid(logits[1])];
        let y = TOES.map(|toe| self.raw(row, toe_col(toe) + 1));
        let w = p[0] + p[1];
        let y_lock = (p[0] * y[0] + p[1] * y[1]) / (w + EPS);
        let alpha = 1.0 - (1.0 - p[0]) * (1.0 - p[1]);
        let shift = alpha * (self.contact_height - y_lock);
        for k in heights() {
            row[k] += shift / self.std[k];
        }
        Grounded {
            p,
            y,
            w,
            y_lock,
            alpha,
        }
    }

    /// Lock row `cur` (grounded) against the grounded `prev`, in place.
    pub(crate) fn lock_row(&self, prev: &[f32], cur: &mut [f32], logits: &[f32]) -> Locked {
        let f = cur.len();
        let (kx, kz, kt) = (f - 3, f - 2, f - 1);
        let p = [sigmoid(logits[0]), sigmoid(logits[1])];
        let (s, c) = self.raw(cur, kt).sin_cos();
        let (mut l, mut v) = ([[0.0f32; 2]; 2], [[0.0f32; 2]; 2]);
        let (mut wx, mut wz) = (0.0f32, 0.0f32);
        for (i, &toe) in TOES.iter().enumerate() {
            let k = toe_col(toe);
            let (lx, lz) = (self.raw(cur, k), self.raw(cur, k + 2));
            let (px, pz) = (self.raw(prev, k), self.raw(prev, k + 2));
            l[i] = [lx, lz];
            v[i] = [px - (c * lx + s * lz), pz - (c * lz - s * lx)];
            wx += p[i] * v[i][0];
            wz += p[i] * v[i][1];
        }
        let w = p[0] + p[1];
        let alpha = 1.0 - (1.0 - p[0]) * (1.0 - p[1]);
        let lock = [wx / (w + EPS), wz / (w + EPS)];
        let free = [self.raw(cur, kx), self.raw(cur, kz)];
        for (j, k) in [kx, kz].into_iter().enumerate() {
            let out = alpha * lock[j] + (1.0 - alpha) * free[j];
            cur[k] = (out - self.mean[k]) / self.std[k];
        }
        Locked {
            p,
            c,
            s,
            l,
            v,
            w,
            alpha,
            lock,
            free,
        }
    }

    /// The forward pass over `x: [B·T, F]`, with what the backward needs.
    fn forward(&self, x: &[f32], logits: &[f32], t: usize, f: usize) -> Vec<f32> {
        let mut out = x.to_vec();
        for (w, lw) in out.chunks_exact_mut(t * f).zip(logits.chunks_exact(t * 2)) {
            for (row, l) in w.chunks_exact_mut(f).zip(lw.chunks_exact(2)) {
                self.ground_row(row, l);
            }
            // Lock from the end so every `prev` is still only grounded.
            for s in (1..t).rev() {
                let (before, now) = w.split_at_mut(s * f);
                self.lock_row(&before[(s - 1) * f..], &mut now[..f], &lw[2 * s..2 * s + 2]);
            }
        }
        out
    }

    /// Gradients of `x` and of the logits for the output gradient `go`.
    fn backward(
        &self,
        x: &[f32],
        logits: &[f32],
        go: &[f32],
        t: usize,
        f: usize,
    ) -> (Vec<f32>, Vec<f32>) {
        let mut gx = vec![0.0f32; x.len()];
        let mut gl = vec![0.0f32; logits.len()];
        let mut g = vec![0.0f32; t * f];
        let mut gg = vec![0.0f32; t * f];
        let windows = x
            .chunks_exact(t * f)
            .zip(logits.chunks_exact(t * 2))
            .zip(go.chunks_exact(t * f))
            .zip(gx.chunks_exact_mut(t * f).zip(gl.chunks_exact_mut(t * 2)));
        for (((xw, lw), gow), (gxw, glw)) in windows {
            // Grounded rows, and what grounding computed.
            g.copy_from_slice(xw);
            let ground: Vec<Grounded> = g
                .chunks_exact_mut(f)
                .zip(lw.chunks_exact(2))
                .map(|(row, l)| self.ground_row(row, l))
                .collect();
            // Through the lock: d out_t / d g_t (cur) and d g_{t−1} (prev).
            gg.copy_from_slice(gow);
            for s in 1..t {
                let mut cur = g[s * f..(s + 1) * f].to_vec();
                let k = self.lock_row(&g[(s - 1) * f..s * f], &mut cur, &lw[2 * s..2 * s + 2]);
                let (gcur, gprev) = {
                    let (a, b) = gg.split_at_mut(s * f);
                    (&mut b[..f], &mut a[(s - 1) * f..s * f])
                };
                self.lock_row_grad(&k, gcur, gprev, &mut glw[2 * s..2 * s + 2]);
            }
            // Through grounding.
            for (s, gr) in ground.iter().enumerate() {
                let out = &mut gxw[s * f..(s + 1) * f];
                out.copy_from_slice(&gg[s * f..(s + 1) * f]);
                self.ground_row_grad(gr, out, &mut glw[2 * s..2 * s + 2]);
            }
        }
        (gx, gl)
    }

    /// [`FootLockOp::lock_row`]'s backward for one row: `g` holds the locked
    /// row's gradient and becomes the grounded row's; the gradients of the
    /// row before it and of the two logits are added to `gprev` and `gl`.
    #[inline(always)]
    pub(crate) fn lock_row_grad(
        &self,
        k: &Locked,
        g: &mut [f32],
        gprev: &mut [f32],
        gl: &mut [f32],
    ) {
        let f = g.len();
        let (kx, kz, kt) = (f - 3, f - 2, f - 1);
        let gv = [g[kx] / self.std[kx], g[kz] / self.std[kz]];
        g[kx] *= 1.0 - k.alpha;
        g[kz] *= 1.0 - k.alpha;
        let galpha = gv[0] * (k.lock[0] - k.free[0]) + gv[1] * (k.lock[1] - k.free[1]);
        let gw_xz = [gv[0] * k.alpha / (k.w + EPS), gv[1] * k.alpha / (k.w + EPS)];
        let gw = -(gw_xz[0] * k.lock[0] + gw_xz[1] * k.lock[1]);
        let (mut gc, mut gs) = (0.0f32, 0.0f32);
        for (i, &toe) in TOES.iter().enumerate() {
            let col = toe_col(toe);
            let other = 1.0 - k.p[1 - i];
            let gp = gw_xz[0] * k.v[i][0] + gw_xz[1] * k.v[i][1] + gw + galpha * other;
            gl[i] += gp * k.p[i] * (1.0 - k.p[i]);
            let (gvx, gvz) = (gw_xz[0] * k.p[i], gw_xz[1] * k.p[i]);
            gprev[col] += gvx * self.std[col];
            gprev[col + 2] += gvz * self.std[col + 2];
            let glx = -k.c * gvx + k.s * gvz;
            let glz = -k.s * gvx - k.c * gvz;
            g[col] += glx * self.std[col];
            g[col + 2] += glz * self.std[col + 2];
            let [lx, lz] = k.l[i];
            gc += -lx * gvx - lz * gvz;
            gs += -lz * gvx + lx * gvz;
        }
        g[kt] += (-k.s * gc + k.c * gs) * self.std[kt];
    }

    /// [`FootLockOp::ground_row`]'s backward for one row: `g` holds the
    /// grounded row's gradient and becomes the input row's; the logits'
    /// gradients are added to `gl`.
    #[inline(always)]
    pub(crate) fn ground_row_grad(&self, gr: &Grounded, g: &mut [f32], gl: &mut [f32]) {
        let gshift: f32 = heights().map(|k| g[k] / self.std[k]).sum();
        for (i, &toe) in TOES.iter().enumerate() {
            let col = toe_col(toe) + 1;
            let dy = -gr.alpha * gr.p[i] / (gr.w + EPS);
            g[col] += gshift * dy * self.std[col];
            let dalpha = 1.0 - gr.p[1 - i];
            let dp = dalpha * (self.contact_height - gr.y_lock)
                - gr.alpha * (gr.y[i] - gr.y_lock) / (gr.w + EPS);
            gl[i] += gshift * dp * gr.p[i] * (1.0 - gr.p[i]);
        }
    }
}

impl CustomOp2 for FootLockOp {
    fn name(&self) -> &'static str {
        "foot-lock"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (x, logits) = (slice(s1, l1, "x")?, slice(s2, l2, "logits")?);
        let (b, t, f) = l1.shape().dims3()?;
        if l2.shape().dims() != [b, t, 2] {
            candle_core::bail!("foot_lock: logits {:?} for x {:?}", l2.shape(), l1.shape());
        }
        Ok((
            CpuStorage::F32(self.forward(x, logits, t, f)),
            l1.shape().clone(),
        ))
    }

    fn bwd(
        &self,
        x: &Tensor,
        logits: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let (_, t, f) = x.dims3()?;
        let (gx, gl) = with_values(x, |xv| {
            with_values(logits, |lv| {
                with_values(grad, |gv| Ok(self.backward(xv, lv, gv, t, f)))
            })
        })?;
        Ok((
            Some(tensor(gx, x.dims(), x)?),
            Some(tensor(gl, logits.dims(), logits)?),
        ))
    }
}

/// The fused [`foot_slide`]: inputs `(x_hat, x)`; no gradient for `x`.
struct SlideOp {
    mean: Vec<f32>,
    std: Vec<f32>,
}

impl SlideOp {
    fn raw(&self, row: &[f32], k: usize) -> f32 {
        row[k] * self.std[k] + self.mean[k]
    }

    /// Each contact term `(row, toe, sx, sz)` of window rows `t ≥ 1`, with
    /// `s` the toe's slide in the previous frame's axes.
    fn each(
        &self,
        xh: &[f32],
        x: &[f32],
        t: usize,
        f: usize,
        mut g: impl FnMut(usize, usize, f32, f32),
    ) {
        let (kx, kz, kt) = (f - 3, f - 2, f - 1);
        for w in 0..xh.len() / (t * f).max(1) {
            for s in 1..t {
                let r = w * t + s;
                let (cur, prev) = (&xh[r * f..(r + 1) * f], &xh[(r - 1) * f..r * f]);
                let (sn, c) = self.raw(cur, kt).sin_cos();
                let (vx, vz) = (self.raw(cur, kx), self.raw(cur, kz));
                for (i, &toe) in TOES.iter().enumerate() {
                    let k = toe_col(toe);
                    if self.raw(&x[r * f..(r + 1) * f], k + 1) >= CONTACT_UNITS as f32 {
                        continue;
                    }
                    let (lx, lz) = (self.raw(cur, k), self.raw(cur, k + 2));
                    let sx = vx + c * lx + sn * lz - self.raw(prev, k);
                    let sz = vz - sn * lx + c * lz - self.raw(prev, k + 2);
                    g(r, i, sx, sz);
                }
            }
        }
    }
}

impl CustomOp2 for SlideOp {
    fn name(&self) -> &'static str {
        "foot-slide"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (xh, x) = (slice(s1, l1, "x_hat")?, slice(s2, l2, "x")?);
        let (_, t, f) = l1.shape().dims3()?;
        if l1.shape() != l2.shape() {
            candle_core::bail!("foot_slide: x_hat {:?}, x {:?}", l1.shape(), l2.shape());
        }
        let mut sum = 0.0f64;
        self.each(xh, x, t, f, |_, _, sx, sz| {
            sum += (sx * sx + sz * sz) as f64
        });
        Ok((CpuStorage::F32(vec![sum as f32]), Shape::from(())))
    }

    fn bwd(
        &self,
        xh: &Tensor,
        x: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let (_, t, f) = xh.dims3()?;
        let (kx, kz, kt) = (f - 3, f - 2, f - 1);
        let g = grad.to_dtype(DType::F32)?.to_scalar::<f32>()?;
        let gx = with_values(xh, |hv| {
            with_values(x, |xv| {
                let mut d = vec![0.0f32; hv.len()];
                self.each(hv, xv, t, f, |r, i, sx, sz| {
                    let (gx, gz) = (2.0 * g * sx, 2.0 * g * sz);
                    let cur = &hv[r * f..(r + 1) * f];
                    let (sn, c) = self.raw(cur, kt).sin_cos();
                    let k = toe_col(TOES[i]);
                    let (lx, lz) = (self.raw(cur, k), self.raw(cur, k + 2));
                    let (a, b) = (r * f, (r - 1) * f);
                    d[a + kx] += gx * self.std[kx];
                    d[a + kz] += gz * self.std[kz];
                    d[a + k] += (gx * c - gz * sn) * self.std[k];
                    d[a + k + 2] += (gx * sn + gz * c) * self.std[k + 2];
                    d[b + k] -= gx * self.std[k];
                    d[b + k + 2] -= gz * self.std[k + 2];
                    let dth = gx * (-sn * lx + c * lz) + gz * (-c * lx - sn * lz);
                    d[a + kt] += dth * self.std[kt];
                });
                Ok(d)
            })
        })?;
        Ok((Some(tensor(gx, xh.dims(), xh)?), None))
    }
}

/// The contact loss of the foot lock: binary cross-entropy of the contact
/// logits `[B, T, 2]` against the real contacts of `x: [B, T, F]` (1 where
/// the real toe is below [`CONTACT_UNITS`]), summed over windows, frames
/// and toes. `x` gets no gradient.
pub fn contact_loss(logits: &Tensor, x: &Tensor, body: &Stats) -> Result<Tensor> {
    let (_, _, f) = x.dims3()?;
    if logits.elem_count() != (x.elem_count() / f.max(1)) * TOES.len() || body.mean.len() != f {
        candle_core::bail!(
            "contact_loss: logits {:?}, x {:?}",
            logits.shape(),
            x.shape()
        );
    }
    if fused(logits) {
        return logits.contiguous()?.apply_op2(
            &x.contiguous()?,
            ContactOp {
                mean: body.mean.to_vec(),
                std: body.std.to_vec(),
            },
        );
    }
    let cols: Vec<Tensor> = TOES
        .iter()
        .map(|&toe| {
            raw_col(x, toe_col(toe) + 1, body)?
                .lt(CONTACT_UNITS)?
                .to_dtype(DType::F32)
        })
        .collect::<Result<_>>()?;
    let target = Tensor::cat(&cols, D::Minus1)?;
    // softplus(l) − t·l, written stably: max(l, 0) − t·l + log(1 + e^{−|l|}).
    let soft = (logits.relu()? + (logits.abs()?.neg()?.exp()? + 1.0)?.log()?)?;
    (soft - (logits * target)?)?.sum_all()
}

/// For each of [`TOES`], whether the contact loss counts it planted in row
/// `r` read raw through `raw(row, feature)`: below [`CONTACT_UNITS`].
fn planted(raw: impl Fn(usize, usize) -> f32, r: usize) -> [bool; TOES.len()] {
    std::array::from_fn(|i| raw(r, toe_col(TOES[i]) + 1) < CONTACT_UNITS as f32)
}

/// The fused [`contact_loss`]: inputs `(logits, x)`.
struct ContactOp {
    mean: Vec<f32>,
    std: Vec<f32>,
}

impl ContactOp {
    /// Each `(logit index, logit, target)`.
    fn each(&self, logits: &[f32], x: &[f32], mut g: impl FnMut(usize, f32, f32)) {
        let f = self.mean.len();
        let raw = |r: usize, k: usize| x[r * f + k] * self.std[k] + self.mean[k];
        for r in 0..x.len() / f {
            for (i, down) in planted(raw, r).into_iter().enumerate() {
                let at = r * TOES.len() + i;
                g(at, logits[at], if down { 1.0 } else { 0.0 });
            }
        }
    }
}

impl CustomOp2 for ContactOp {
    fn name(&self) -> &'static str {
        "contact-loss"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (logits, x) = (slice(s1, l1, "logits")?, slice(s2, l2, "x")?);
        let mut sum = 0.0f64;
        self.each(logits, x, |_, l, t| {
            sum += (l.max(0.0) - t * l + (-l.abs()).exp().ln_1p()) as f64
        });
        Ok((CpuStorage::F32(vec![sum as f32]), Shape::from(())))
    }

    fn bwd(
        &self,
        logits: &Tensor,
        x: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let g = grad.to_dtype(DType::F32)?.to_scalar::<f32>()?;
        let gl = with_values(logits, |lv| {
            with_values(x, |xv| {
                let mut d = vec![0.0f32; lv.len()];
                self.each(lv, xv, |at, l, t| d[at] = g * (sigmoid(l) - t));
                Ok(d)
            })
        })?;
        Ok((Some(tensor(gl, logits.dims(), logits)?), None))
    }
}
