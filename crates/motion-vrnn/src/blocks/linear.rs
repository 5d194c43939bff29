//! Dense layers over all rows at once, and the squared error.

use super::kernels::{mm, mm_rows, rm, simd_fn, tr};
use super::{fused, slice, tensor, with_values};
use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Result, Shape, Tensor, D};
use serde::{Deserialize, Serialize};

/// The activation after a [`linear`] layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Act {
    /// None (a plain affine map).
    None,
    /// `max(0, ·)`.
    Relu,
}

/// `act(x · Wᵀ + b)` over every row of `x` (`[…, in]` → `[…, out]`), with
/// `w: [out, in]`, `b: [out]`.
pub fn linear(x: &Tensor, w: &Tensor, b: &Tensor, act: Act) -> Result<Tensor> {
    if fused(x) {
        return x
            .contiguous()?
            .apply_op3(&w.contiguous()?, &b.contiguous()?, LinearOp { act });
    }
    let dims = x.dims().to_vec();
    let rows = x.elem_count() / dims[dims.len() - 1];
    let y = x
        .reshape((rows, dims[dims.len() - 1]))?
        .matmul(&w.contiguous()?.t()?)?
        .broadcast_add(b)?;
    let y = match act {
        Act::None => y,
        Act::Relu => y.relu()?,
    };
    let mut out = dims;
    let last = out.len() - 1;
    out[last] = w.dim(0)?;
    y.reshape(out)
}

/// The fused [`linear`].
struct LinearOp {
    act: Act,
}

/// `(rows, in, out)` of a linear layer, checked.
fn sizes(x: &Shape, w: &Shape, b: &Shape) -> Result<(usize, usize, usize)> {
    let (out, inp) = w.dims2()?;
    let last = *x.dims().last().unwrap_or(&0);
    if last != inp || b.dims() != [out] {
        candle_core::bail!("linear: x {x:?}, w {w:?}, b {b:?} do not fit");
    }
    Ok((x.elem_count() / inp.max(1), inp, out))
}

impl CustomOp3 for LinearOp {
    fn name(&self) -> &'static str {
        "linear"
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
        let (x, w, b) = (
            slice(s1, l1, "x")?,
            slice(s2, l2, "w")?,
            slice(s3, l3, "b")?,
        );
        let (rows, inp, out) = sizes(l1.shape(), l2.shape(), l3.shape())?;
        let mut y = mm_rows((rows, out, inp), x, w, tr(0, inp), Some(b));
        if self.act == Act::Relu {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        let mut shape = l1.shape().dims().to_vec();
        let last = shape.len() - 1;
        shape[last] = out;
        Ok((CpuStorage::F32(y), Shape::from(shape)))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        b: &Tensor,
        res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let (rows, inp, out) = sizes(x.shape(), w.shape(), b.shape())?;
        // g = grad ⊙ act'(y) and db = Σ_rows g, in one pass (rows in order,
        // so db's sums keep their order).
        let relu = self.act == Act::Relu;
        let (g, db) = with_values(grad, |g| {
            with_values(res, |y| Ok(relu_grad(g, y, out, relu)))
        })?;
        let dw = with_values(x, |xv| Ok(weight_grad(&g, xv, (rows, inp, out))))?;
        // No input gradient where nothing upstream needs it (the real
        // frames, the fed-back ones): for the first layer it costs as much
        // as the weights' gradient.
        let dx = if x.track_op() {
            let dx = with_values(w, |wv| {
                Ok(mm_rows((rows, inp, out), &g, wv, rm(0, inp), None))
            })?;
            Some(tensor(dx, x.dims(), x)?)
        } else {
            None
        };
        Ok((
            dx,
            Some(tensor(dw, w.dims(), w)?),
            Some(tensor(db, b.dims(), b)?),
        ))
    }
}

/// A dense layer's weight gradient `gᵀ · x` (`[out, inp]`) over `rows`
/// rows of the output's gradient `g` (`rows × out`) and the input `x`
/// (`rows × inp`), summed in [`mm`]'s order.
fn weight_grad(g: &[f32], x: &[f32], (rows, inp, out): (usize, usize, usize)) -> Vec<f32> {
    let mut dw = vec![0.0f32; out * inp];
    mm(
        (out, inp, rows),
        &mut dw,
        rm(0, inp),
        false,
        g,
        tr(0, out),
        x,
        rm(0, inp),
    );
    dw
}

simd_fn! {
/// `(g, db)` of a linear layer: the output's gradient `grad` through the
/// activation (`relu`: zero where the output `y` is not positive), and its
/// sum over the rows of width `out`.
fn relu_grad(grad: &[f32], y: &[f32], out: usize, relu: bool) -> (Vec<f32>, Vec<f32>) {
    let mut g = Vec::with_capacity(grad.len());
    let mut db = vec![0.0f32; out];
    for (gr, yr) in grad.chunks_exact(out.max(1)).zip(y.chunks_exact(out.max(1))) {
        let start = g.len();
        if relu {
            g.extend(gr.iter().zip(yr).map(|(&d, &v)| if v > 0.0 { d } else { 0.0 }));
        } else {
            g.extend_from_slice(gr);
        }
        for (d, v) in db.iter_mut().zip(&g[start..]) {
            *d += v;
        }
    }
    (g, db)
}
}

/// `Σ (a − b)²` over every element (a scalar).
pub fn squared_error(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    if a.shape() != b.shape() {
        candle_core::bail!("squared_error: {:?} vs {:?}", a.shape(), b.shape());
    }
    if fused(a) {
        return a.contiguous()?.apply_op2(&b.contiguous()?, SquaredError);
    }
    (a - b)?.sqr()?.flatten_all()?.sum(D::Minus1)
}

/// The fused [`squared_error`].
struct SquaredError;

impl CustomOp2 for SquaredError {
    fn name(&self) -> &'static str {
        "squared-error"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (a, b) = (slice(s1, l1, "a")?, slice(s2, l2, "b")?);
        let sum: f64 = a
            .iter()
            .zip(b)
            .map(|(x, y)| {
                let d = (x - y) as f64;
                d * d
            })
            .sum();
        Ok((CpuStorage::F32(vec![sum as f32]), Shape::from(())))
    }

    fn bwd(
        &self,
        a: &Tensor,
        b: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let g = 2.0 * grad.to_scalar::<f32>()?;
        let da = with_values(a, |av| {
            with_values(b, |bv| {
                Ok(av.iter().zip(bv).map(|(x, y)| g * (x - y)).collect())
            })
        })?;
        let da = tensor(da, a.dims(), a)?;
        // The target (real frames) usually needs no gradient.
        let db = if b.track_op() { Some(da.neg()?) } else { None };
        Ok((Some(da), db))
    }
}

/// `act(y + r)` with one row `r` per sequence: `y: [B, T, n]`, `r: [B, 1, n]`
/// or `[1, 1, n]` (a condition's bias, added to every frame), or one per
/// frame, `r: [B, T, n]` (with the control); or one step, `y: [B, n]` and
/// `r: [B, n]` or `[1, n]`. One pass where candle's `broadcast_add` and
/// `relu` take two forward and five backward.
pub fn add_rows(y: &Tensor, r: &Tensor, act: Act) -> Result<Tensor> {
    if y.rank() == 2 && r.rank() == 2 {
        return add_rows(&y.unsqueeze(1)?, &r.unsqueeze(1)?, act)?.squeeze(1);
    }
    let (b, _, n) = y.dims3()?;
    let (rb, rt, rn) = r.dims3()?;
    let per_frame = rt > 1 && rt == y.dim(1)? && rb == b;
    if (rt != 1 && !per_frame) || rn != n || (rb != b && rb != 1) {
        candle_core::bail!("add_rows: y {:?}, r {:?} do not fit", y.shape(), r.shape());
    }
    if fused(y) {
        return y.contiguous()?.apply_op2(&r.contiguous()?, AddRows { act });
    }
    let s = y.broadcast_add(r)?;
    match act {
        Act::None => Ok(s),
        Act::Relu => s.relu(),
    }
}

/// The fused [`add_rows`].
struct AddRows {
    act: Act,
}

impl CustomOp2 for AddRows {
    fn name(&self) -> &'static str {
        "add-rows"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (y, r) = (slice(s1, l1, "y")?, slice(s2, l2, "r")?);
        let (b, t, n) = l1.shape().dims3()?;
        let rows = Rows::of(l2.shape().dims(), t);
        let relu = self.act == Act::Relu;
        let mut out = Vec::with_capacity(y.len());
        for (s, ys) in y.chunks_exact((t * n).max(1)).enumerate().take(b) {
            for (k, yr) in ys.chunks_exact(n.max(1)).enumerate() {
                let at = rows.at(s, k, t, n);
                let rs = &r[at..at + n];
                out.extend(yr.iter().zip(rs).map(|(a, c)| {
                    let v = a + c;
                    if relu {
                        v.max(0.0)
                    } else {
                        v
                    }
                }));
            }
        }
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    /// The gradients as candle's autograd gives them, to the bit: `y`'s is
    /// the output's (zero where `y + r < 0` under the ReLU), `r`'s the same
    /// per frame, else its sum over the frames (and the sequences, for a
    /// shared row) in row order.
    fn bwd(
        &self,
        y: &Tensor,
        r: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let (b, t, n) = y.dims3()?;
        let rows = Rows::of(r.dims(), t);
        let relu = self.act == Act::Relu;
        let (dy, dr) = with_values(grad, |g| {
            with_values(y, |yv| {
                with_values(r, |rv| Ok(add_rows_grad(g, yv, rv, [b, t, n], rows, relu)))
            })
        })?;
        Ok((
            Some(tensor(dy, y.dims(), y)?),
            Some(tensor(dr, r.dims(), r)?),
        ))
    }
}

simd_fn! {
/// `(dy, dr)` of [`add_rows`] from the output's gradient `g`, rows in order.
fn add_rows_grad(
    g: &[f32],
    y: &[f32],
    r: &[f32],
    dims: [usize; 3],
    rows: Rows,
    relu: bool,
) -> (Vec<f32>, Vec<f32>) {
    let [b, t, n] = dims;
    let mut dy = vec![0.0f32; g.len()];
    for s in 0..b {
        for k in 0..t {
            let ra = rows.at(s, k, t, n);
            let rs = &r[ra..ra + n];
            let at = (s * t + k) * n;
            let (gr, yr, dyr) = (&g[at..at + n], &y[at..at + n], &mut dy[at..at + n]);
            // 0 + g: autograd adds into a zeroed buffer.
            if relu {
                for j in 0..n {
                    dyr[j] = 0.0 + if yr[j] + rs[j] >= 0.0 { gr[j] } else { 0.0 };
                }
            } else {
                for j in 0..n {
                    dyr[j] = 0.0 + gr[j];
                }
            }
        }
    }
    // `0 + dy` is `dy` here, bit for bit: it is `0 + g` already.
    let dr = match rows {
        Rows::Frame => dy.clone(),
        Rows::Shared => row_sums(&dy, dims, true),
        Rows::Sequence => row_sums(&dy, dims, false),
    };
    (dy, dr)
}
}

/// Which rows [`add_rows`] adds: one for all, one per sequence, or one per
/// frame.
#[derive(Clone, Copy)]
enum Rows {
    Shared,
    Sequence,
    Frame,
}

impl Rows {
    /// The layout of rows `r` (`[·, ·, n]`) for sequences of `t` frames.
    fn of(r: &[usize], t: usize) -> Rows {
        match r {
            [1, 1, _] => Rows::Shared,
            [_, rt, _] if *rt == t && t > 1 => Rows::Frame,
            _ => Rows::Sequence,
        }
    }

    /// Where the row for sequence `s`, frame `k` starts.
    #[inline(always)]
    fn at(self, s: usize, k: usize, t: usize, n: usize) -> usize {
        match self {
            Rows::Shared => 0,
            Rows::Sequence => s * n,
            Rows::Frame => (s * t + k) * n,
        }
    }
}

/// The gradient of rows added to every step (as [`add_rows`] adds them):
/// `g: [B, T, n]` summed over the steps of each sequence (and over the
/// sequences when one row is `shared`), in row order from zero, each term
/// `0 + g` as autograd adds into a zeroed buffer.
pub(crate) fn row_sums(g: &[f32], [b, t, n]: [usize; 3], shared: bool) -> Vec<f32> {
    let per = if shared { 0 } else { n };
    let mut dr = vec![0.0f32; if shared { n } else { b * n }];
    for s in 0..b {
        let drs = &mut dr[s * per..s * per + n];
        for k in 0..t {
            let at = (s * t + k) * n;
            for (d, v) in drs.iter_mut().zip(&g[at..at + n]) {
                *d += 0.0 + v;
            }
        }
    }
    dr
}

/// `base + ctl · w` per frame: `ctl: [B, T, C]` (the control, data: it gets
/// no gradient), `w: [C, n]`, `base: [B, n]` or `[1, n]` (a row per
/// sequence, or one for all) → `[B, T, n]`; one step's `ctl: [B, C]` gives
/// `[B, n]`. The bits of [`linear`] (`wᵀ`, a zero bias) plus `base`
/// broadcast over the frames, in one pass each way where those take a
/// product, a broadcast sum and, backward, candle's sum over the frames.
pub fn control_rows(ctl: &Tensor, w: &Tensor, base: &Tensor) -> Result<Tensor> {
    let ctl = ctl.detach();
    if ctl.rank() == 3 && fused(&ctl) {
        let (b, _, c) = ctl.dims3()?;
        let (wc, n) = w.dims2()?;
        let (rb, rn) = base.dims2()?;
        if wc != c || rn != n || (rb != b && rb != 1) {
            candle_core::bail!(
                "control_rows: ctl {:?}, w {:?}, base {:?} do not fit",
                ctl.shape(),
                w.shape(),
                base.shape()
            );
        }
        return ctl
            .contiguous()?
            .apply_op3(&w.contiguous()?, &base.contiguous()?, ControlRows);
    }
    let none = Tensor::zeros(w.dim(1)?, candle_core::DType::F32, w.device())?;
    let r = linear(&ctl, &w.t()?.contiguous()?, &none, Act::None)?;
    let base = if ctl.rank() == 3 {
        base.unsqueeze(1)?
    } else {
        base.clone()
    };
    r.broadcast_add(&base)
}

/// The fused [`control_rows`] over `[B, T, ·]`.
struct ControlRows;

/// `w: [C, n]` transposed (`[n, C]`, row-major), as [`linear`] reads it.
fn transposed(w: &[f32], c: usize, n: usize) -> Vec<f32> {
    (0..n)
        .flat_map(|j| (0..c).map(move |k| w[k * n + j]))
        .collect()
}

impl CustomOp3 for ControlRows {
    fn name(&self) -> &'static str {
        "control-rows"
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
        let (ctl, w, base) = (
            slice(s1, l1, "ctl")?,
            slice(s2, l2, "w")?,
            slice(s3, l3, "base")?,
        );
        let (b, t, c) = l1.shape().dims3()?;
        let n = l2.shape().dims2()?.1;
        let per = if l3.shape().dims()[0] == 1 { 0 } else { n };
        let zeros = vec![0.0f32; n];
        let wt = transposed(w, c, n);
        let mut y = mm_rows((b * t, n, c), ctl, &wt, tr(0, c), Some(&zeros));
        for (s, ys) in y.chunks_exact_mut((t * n).max(1)).enumerate() {
            let rs = &base[s * per..s * per + n];
            for row in ys.chunks_exact_mut(n.max(1)) {
                row.iter_mut().zip(rs).for_each(|(v, r)| *v += r);
            }
        }
        Ok((CpuStorage::F32(y), Shape::from((b, t, n))))
    }

    /// `w`'s gradient as [`linear`]'s backward sums it, `base`'s as
    /// candle's sum over the frames (and the sequences, for one row), rows
    /// in order: the bits of the composition.
    fn bwd(
        &self,
        ctl: &Tensor,
        w: &Tensor,
        base: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let (b, t, c) = ctl.dims3()?;
        let n = w.dim(1)?;
        let shared = base.dim(0)? == 1;
        let (dw, dbase) = with_values(grad, |g| {
            with_values(ctl, |x| {
                let dwt = weight_grad(g, x, (b * t, c, n));
                Ok((transposed(&dwt, n, c), row_sums(g, [b, t, n], shared)))
            })
        })?;
        Ok((
            None,
            Some(tensor(dw, w.dims(), w)?),
            Some(tensor(dbase, base.dims(), base)?),
        ))
    }
}
