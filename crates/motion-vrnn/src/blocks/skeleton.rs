//! Forward kinematics over the 19-joint tree of `docs/features.md`: joint
//! positions from bone directions and bone lengths, so a decoded pose keeps
//! its bones by construction.
//!
//! Per row, with `d_j` the raw direction of bone `j` (joint `j` from its
//! parent, `j = 1 … 18`) and `L_j` its length:
//!
//! ```text
//! p_0 = (0, y, 0)                       (Hips above the local origin)
//! p_j = p_parent(j) + L_j · d_j / ‖d_j‖  (‖d‖ = √(d·d + 1e-8))
//! ```
//!
//! Parents precede their children in the feature order, so one pass from
//! the root places every joint and one pass back from the leaves gives the
//! gradients.

use super::kernels::simd_fn;
use super::{fused, slice, tensor, with_values};
use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Result, Shape, Tensor, D};
use mocap_ingest::skeleton::{JOINT_PARENTS, NUM_JOINTS};

/// Bones of the tree (every joint but the root).
pub const BONES: usize = NUM_JOINTS - 1;

/// Added to `‖d‖²` before the square root (keeps a zero direction finite).
const EPS: f32 = 1e-8;

/// Parent of joint `j ≥ 1`.
fn parent(j: usize) -> usize {
    JOINT_PARENTS[j].unwrap_or(0)
}

/// One row's 18 xyz triples (joints or bones 1 … 18) as an array indexed
/// by joint, index 0 (the root) zero.
fn bones_of(v: &[f32]) -> [[f32; 3]; NUM_JOINTS] {
    let mut a = [[0.0f32; 3]; NUM_JOINTS];
    for (j, aj) in a.iter_mut().enumerate().skip(1) {
        aj.copy_from_slice(&v[(j - 1) * 3..][..3]);
    }
    a
}

/// Forward kinematics of one row: joint positions (index 0 the root at
/// `(0, y, 0)`) from bone vectors `d` (index `j` from joint `j`'s parent)
/// and lengths `l` (bone `j` at `l[j − 1]`).
fn fk_row(y: f32, d: &[[f32; 3]; NUM_JOINTS], l: &[f32]) -> [[f32; 3]; NUM_JOINTS] {
    let mut p = [[0.0f32; 3]; NUM_JOINTS];
    p[0][1] = y;
    for j in 1..NUM_JOINTS {
        let dj = d[j];
        let n = (dj[0] * dj[0] + dj[1] * dj[1] + dj[2] * dj[2] + EPS).sqrt();
        let s = l[j - 1] / n;
        let q = p[parent(j)];
        p[j] = [q[0] + s * dj[0], q[1] + s * dj[1], q[2] + s * dj[2]];
    }
    p
}

/// The backward of [`fk_row`]: from the gradient of each joint's position
/// `gp` (children are added into their parents in place, so `gp[0][1]`
/// ends as the root height's gradient), the gradient of each bone vector.
fn fk_row_backward(
    d: &[[f32; 3]; NUM_JOINTS],
    l: &[f32],
    gp: &mut [[f32; 3]; NUM_JOINTS],
) -> [[f32; 3]; NUM_JOINTS] {
    let mut gd = [[0.0f32; 3]; NUM_JOINTS];
    for j in (1..NUM_JOINTS).rev() {
        let gj = gp[j];
        let q = &mut gp[parent(j)];
        for k in 0..3 {
            q[k] += gj[k];
        }
        let dj = d[j];
        let n = (dj[0] * dj[0] + dj[1] * dj[1] + dj[2] * dj[2] + EPS).sqrt();
        // ∂(L d/n)/∂d = L/n (I − d dᵀ/n²)
        let dot = (gj[0] * dj[0] + gj[1] * dj[1] + gj[2] * dj[2]) / (n * n);
        for k in 0..3 {
            gd[j][k] = l[j - 1] / n * (gj[k] - dj[k] * dot);
        }
    }
    gd
}

/// Joint positions `[…, 54]` (joints 1 … 18, xyz) from the root height
/// `y: […, 1]`, raw bone directions `dirs: […, 54]` and bone lengths
/// `lengths: […, 18]`. The lengths get no gradient (they are data).
pub fn forward_kinematics(y: &Tensor, dirs: &Tensor, lengths: &Tensor) -> Result<Tensor> {
    let rows = dirs.elem_count() / (3 * BONES);
    if dirs.dims().last() != Some(&(3 * BONES))
        || y.elem_count() != rows
        || lengths.elem_count() != rows * BONES
    {
        candle_core::bail!(
            "forward_kinematics: y {:?}, dirs {:?}, lengths {:?}",
            y.shape(),
            dirs.shape(),
            lengths.shape()
        );
    }
    if fused(dirs) {
        return dirs
            .contiguous()?
            .apply_op3(&y.contiguous()?, &lengths.contiguous()?, FkOp);
    }
    reference(y, dirs, lengths)
}

/// [`forward_kinematics`] in candle ops.
fn reference(y: &Tensor, dirs: &Tensor, lengths: &Tensor) -> Result<Tensor> {
    let zero = y.zeros_like()?;
    let mut p = vec![Tensor::cat(&[&zero, y, &zero], D::Minus1)?];
    for j in 1..NUM_JOINTS {
        let d = dirs.narrow(D::Minus1, 3 * (j - 1), 3)?;
        let n = (d.sqr()?.sum_keepdim(D::Minus1)? + EPS as f64)?.sqrt()?;
        let l = lengths.narrow(D::Minus1, j - 1, 1)?.detach();
        let bone = d.broadcast_div(&n)?.broadcast_mul(&l)?;
        p.push((&p[parent(j)] + bone)?);
    }
    Tensor::cat(&p[1..], D::Minus1)
}

/// The fused [`forward_kinematics`]: inputs `(dirs, y, lengths)`.
struct FkOp;

impl CustomOp3 for FkOp {
    fn name(&self) -> &'static str {
        "forward-kinematics"
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
        let (d, y, len) = (
            slice(s1, l1, "dirs")?,
            slice(s2, l2, "y")?,
            slice(s3, l3, "lengths")?,
        );
        let rows = y.len();
        let mut out = vec![0.0f32; rows * 3 * BONES];
        for r in 0..rows {
            let p = fk_row(y[r], &bones_of(&d[r * 3 * BONES..]), &len[r * BONES..]);
            for (j, pj) in p.iter().enumerate().skip(1) {
                out[(r * BONES + j - 1) * 3..][..3].copy_from_slice(pj);
            }
        }
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        dirs: &Tensor,
        y: &Tensor,
        lengths: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let rows = y.elem_count();
        let mut dd = vec![0.0f32; rows * 3 * BONES];
        let mut dy = vec![0.0f32; rows];
        with_values(dirs, |d| {
            with_values(lengths, |len| {
                with_values(grad, |g| {
                    for r in 0..rows {
                        let mut gp = bones_of(&g[r * 3 * BONES..]);
                        let gd = fk_row_backward(
                            &bones_of(&d[r * 3 * BONES..]),
                            &len[r * BONES..],
                            &mut gp,
                        );
                        for (j, gj) in gd.iter().enumerate().skip(1) {
                            dd[(r * BONES + j - 1) * 3..][..3].copy_from_slice(gj);
                        }
                        dy[r] = gp[0][1];
                    }
                    Ok(())
                })
            })
        })?;
        Ok((
            Some(tensor(dd, dirs.dims(), dirs)?),
            Some(tensor(dy, y.dims(), y)?),
            None,
        ))
    }
}

/// Bone lengths `[…, 18]` of joint positions `[…, 54]` with root height
/// `y: […, 1]` (no gradient: a measurement of data).
pub fn bone_lengths(y: &[f32], joints: &[f32]) -> Vec<f32> {
    (0..y.len())
        .flat_map(|r| row_bone_lengths(y[r], &joints[r * 3 * BONES..][..3 * BONES]))
        .collect()
}

/// [`bone_lengths`] of one row: root height `y`, joints `[54]`.
pub fn row_bone_lengths(y: f32, joints: &[f32]) -> [f32; BONES] {
    let at = |j: usize| -> [f32; 3] {
        if j == 0 {
            [0.0, y, 0.0]
        } else {
            let p = &joints[(j - 1) * 3..][..3];
            [p[0], p[1], p[2]]
        }
    };
    let mut out = [0.0f32; BONES];
    for (j, o) in out.iter_mut().enumerate().map(|(i, o)| (i + 1, o)) {
        let (a, b) = (at(j), at(parent(j)));
        let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        *o = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    }
    out
}

/// The skeleton part as one block: normalised decoder outputs `o: […, F]`
/// (root height, the 18 joints' local xyz, then the other features) → the
/// same features with every bone rescaled to its length by forward
/// kinematics. With `raw(v, k) = v·std_k + mean_k`, per row:
///
/// ```text
/// d_j  = raw(joint j) − raw(parent j)       (the root at (0, raw(o_0), 0))
/// p    = forward_kinematics(raw(o_0), d, lengths)
/// out  = [o_0 | (p − mean) / std | o_55…]
/// ```
///
/// so a pose whose bones already have the right lengths comes out
/// unchanged, and a bone only ever changes length, never direction.
/// `lengths` get no gradient (they are data).
pub fn place(o: &Tensor, lengths: &Tensor, mean: &[f32], std: &[f32]) -> Result<Tensor> {
    let f = o.dim(D::Minus1)?;
    let rows = o.elem_count() / f.max(1);
    if f < 1 + 3 * BONES
        || mean.len() != f
        || std.len() != f
        || lengths.elem_count() != rows * BONES
    {
        candle_core::bail!(
            "place: o {:?}, lengths {:?}, statistics of {}",
            o.shape(),
            lengths.shape(),
            mean.len()
        );
    }
    if fused(o) {
        return o.contiguous()?.apply_op2(
            &lengths.contiguous()?,
            PlaceOp {
                mean: mean.to_vec(),
                std: std.to_vec(),
            },
        );
    }
    place_reference(o, lengths, mean, std)
}

/// [`place`] in candle ops.
fn place_reference(o: &Tensor, lengths: &Tensor, mean: &[f32], std: &[f32]) -> Result<Tensor> {
    let (f, j) = (o.dim(D::Minus1)?, 3 * BONES);
    let dev = o.device();
    let raw = o
        .broadcast_mul(&Tensor::new(std, dev)?)?
        .broadcast_add(&Tensor::new(mean, dev)?)?;
    let y = raw.narrow(D::Minus1, 0, 1)?;
    let zero = y.zeros_like()?;
    let root = Tensor::cat(&[&zero, &y, &zero], D::Minus1)?;
    let at = |k: usize| -> Result<Tensor> {
        match k {
            0 => Ok(root.clone()),
            _ => raw.narrow(D::Minus1, 1 + 3 * (k - 1), 3),
        }
    };
    let dirs: Vec<Tensor> = (1..NUM_JOINTS)
        .map(|k| at(k)? - at(parent(k))?)
        .collect::<Result<_>>()?;
    let p = reference(&y, &Tensor::cat(&dirs, D::Minus1)?, lengths)?;
    let pn = p
        .broadcast_sub(&Tensor::new(&mean[1..1 + j], dev)?)?
        .broadcast_div(&Tensor::new(&std[1..1 + j], dev)?)?;
    Tensor::cat(
        &[
            &o.narrow(D::Minus1, 0, 1)?,
            &pn,
            &o.narrow(D::Minus1, 1 + j, f - 1 - j)?,
        ],
        D::Minus1,
    )
}

/// Rows [`place_rows`] places side by side, one per vector lane.
const LANES: usize = 8;

simd_fn! {
/// [`PlaceOp`]'s forward over every row of `o` (width `mean.len()`) with
/// the bone lengths `len` (`BONES` per row): the rows go [`LANES`] at a
/// time, each quantity an array over the rows, so the square roots and
/// divisions run on whole vectors. Per row it is [`PlaceOp::bones`],
/// [`fk_row`] and the renormalisation, operation for operation (the same
/// bits; tested against them).
#[allow(clippy::needless_range_loop)] // lane loops index several arrays alike
pub(crate) fn place_rows(o: &[f32], len: &[f32], mean: &[f32], std: &[f32]) -> Vec<f32> {
    let f = mean.len();
    let mut out = o.to_vec();
    let rows = o.len() / f.max(1);
    for g0 in (0..rows).step_by(LANES) {
        let n = LANES.min(rows - g0);
        // Raw root height and joints, lane by lane.
        let mut r = [[[0.0f32; LANES]; 3]; NUM_JOINTS];
        for l in 0..n {
            r[0][1][l] = o[(g0 + l) * f] * std[0] + mean[0];
        }
        for j in 1..NUM_JOINTS {
            for k in 0..3 {
                let c = 1 + 3 * (j - 1) + k;
                for l in 0..n {
                    r[j][k][l] = o[(g0 + l) * f + c] * std[c] + mean[c];
                }
            }
        }
        // Forward kinematics from the bone vectors (joint minus parent).
        let mut p = [[[0.0f32; LANES]; 3]; NUM_JOINTS];
        p[0][1] = r[0][1];
        for j in 1..NUM_JOINTS {
            let q = parent(j);
            let mut d = [[0.0f32; LANES]; 3];
            for k in 0..3 {
                for l in 0..LANES {
                    d[k][l] = r[j][k][l] - r[q][k][l];
                }
            }
            let mut s = [0.0f32; LANES];
            for l in 0..n {
                let nrm = (d[0][l] * d[0][l] + d[1][l] * d[1][l] + d[2][l] * d[2][l] + EPS).sqrt();
                s[l] = len[(g0 + l) * BONES + j - 1] / nrm;
            }
            for k in 0..3 {
                for l in 0..LANES {
                    p[j][k][l] = p[q][k][l] + s[l] * d[k][l];
                }
            }
        }
        for j in 1..NUM_JOINTS {
            for k in 0..3 {
                let c = 1 + 3 * (j - 1) + k;
                for l in 0..n {
                    out[(g0 + l) * f + c] = (p[j][k][l] - mean[c]) / std[c];
                }
            }
        }
    }
    out
}
}

/// The fused [`place`]: inputs `(o, lengths)`.
#[derive(Clone, Debug)]
pub(crate) struct PlaceOp {
    pub(crate) mean: Vec<f32>,
    pub(crate) std: Vec<f32>,
}

impl PlaceOp {
    /// The raw root height and bone vectors of one row.
    fn bones(&self, o: &[f32]) -> (f32, [[f32; 3]; NUM_JOINTS]) {
        let y = o[0] * self.std[0] + self.mean[0];
        let mut r = [[0.0f32; 3]; NUM_JOINTS];
        r[0][1] = y;
        for (j, rj) in r.iter_mut().enumerate().skip(1) {
            for (k, v) in rj.iter_mut().enumerate() {
                let c = 1 + 3 * (j - 1) + k;
                *v = o[c] * self.std[c] + self.mean[c];
            }
        }
        let mut d = [[0.0f32; 3]; NUM_JOINTS];
        for j in 1..NUM_JOINTS {
            let (a, b) = (r[j], r[parent(j)]);
            d[j] = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        }
        (y, d)
    }

    /// The backward of one row `o` with bone lengths `l`: `gr` holds the
    /// placed row's gradient and becomes `o`'s.
    #[inline(always)]
    pub(crate) fn row_grad(&self, o: &[f32], l: &[f32], gr: &mut [f32]) {
        let (_, d) = self.bones(o);
        // Gradient of each placed joint, children added in.
        let mut gp = [[0.0f32; 3]; NUM_JOINTS];
        for (j, gj) in gp.iter_mut().enumerate().skip(1) {
            for (k, v) in gj.iter_mut().enumerate() {
                let c = 1 + 3 * (j - 1) + k;
                *v = gr[c] / self.std[c];
            }
        }
        // Through forward kinematics to the bone vectors.
        let gd = fk_row_backward(&d, l, &mut gp);
        // Bone vectors → raw joints (a joint minus its parent).
        let mut graw = [[0.0f32; 3]; NUM_JOINTS];
        for j in 1..NUM_JOINTS {
            for k in 0..3 {
                graw[j][k] += gd[j][k];
                graw[parent(j)][k] -= gd[j][k];
            }
        }
        // The root height moves every placed joint (gp[0]) and is the
        // parent of the bones from the root (graw[0]).
        gr[0] += (gp[0][1] + graw[0][1]) * self.std[0];
        for (j, gj) in graw.iter().enumerate().skip(1) {
            for (k, v) in gj.iter().enumerate() {
                let c = 1 + 3 * (j - 1) + k;
                gr[c] = v * self.std[c];
            }
        }
    }
}

impl CustomOp2 for PlaceOp {
    fn name(&self) -> &'static str {
        "skeleton-place"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let _time = crate::blocks::timing::span(self.name(), false);
        let (o, len) = (slice(s1, l1, "o")?, slice(s2, l2, "lengths")?);
        let out = place_rows(o, len, &self.mean, &self.std);
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        o: &Tensor,
        lengths: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let _time = crate::blocks::timing::span(self.name(), true);
        let f = self.mean.len();
        let go = with_values(o, |ov| {
            with_values(lengths, |len| {
                with_values(grad, |g| {
                    let mut go = g.to_vec();
                    let rows = ov
                        .chunks_exact(f)
                        .zip(len.chunks_exact(BONES))
                        .zip(go.chunks_exact_mut(f));
                    for ((row, l), gr) in rows {
                        self.row_grad(row, l, gr);
                    }
                    Ok(go)
                })
            })
        })?;
        Ok((Some(tensor(go, o.dims(), o)?), None))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`place_rows`] (rows side by side in lanes) gives, bit for bit, what
    /// the row-by-row path ([`PlaceOp::bones`], [`fk_row`], renormalised)
    /// gives, over a number of rows that is not a multiple of the lanes.
    #[test]
    fn rows_in_lanes_are_the_row_by_row_bits() {
        let f = 1 + 3 * BONES + 3;
        let rows = 3 * LANES + 5;
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 4.0 - 2.0
        };
        let mean: Vec<f32> = (0..f).map(|_| next() * 10.0).collect();
        let std: Vec<f32> = (0..f).map(|_| 0.5 + next().abs() * 3.0).collect();
        let o: Vec<f32> = (0..rows * f).map(|_| next()).collect();
        let len: Vec<f32> = (0..rows * BONES)
            .map(|_| 1.0 + next().abs() * 5.0)
            .collect();
        let op = PlaceOp {
            mean: mean.clone(),
            std: std.clone(),
        };
        let got = place_rows(&o, &len, &mean, &std);
        let mut want = o.clone();
        for (row, l) in want.chunks_exact_mut(f).zip(len.chunks_exact(BONES)) {
            let (y, d) = op.bones(row);
            let p = fk_row(y, &d, l);
            for (j, pj) in p.iter().enumerate().skip(1) {
                for (k, v) in pj.iter().enumerate() {
                    let c = 1 + 3 * (j - 1) + k;
                    row[c] = (v - mean[c]) / std[c];
                }
            }
        }
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(g.to_bits(), w.to_bits(), "element {i}: {g} against {w}");
        }
    }
}
