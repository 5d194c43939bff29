//! Fused building blocks: the layers every model is made of, each with a
//! fused CPU forward *and* backward pass and a reference made of candle ops.
//!
//! A model calls these functions and nothing else for its heavy work; it is
//! written once. On the CPU each block runs as one candle custom op over
//! plain `f32` slices (the `gemm` crate for products, vectorisable
//! element-wise loops) with a hand-written backward; on any other device, or
//! inside [`fn@reference`], it runs as a composition of candle ops, whose
//! autograd is the oracle the fused backward is tested against
//! (`tests/blocks.rs`: autograd and finite differences, block by block).
//!
//! - [`mod@linear`]: `act(x · Wᵀ + b)` over all rows at once (every layer that does
//!   not depend on the recurrence runs once over `batch × T` rows).
//! - [`latent_lstm`]: the part that cannot be batched: the VRNN recurrence
//!   over a whole sequence (posterior from `h`, reparameterised `z`, LSTM
//!   cell), and [`lstm_cell`] for one step of free-running generation.
//! - [`gaussian_kl`]: `KL(N(μq, σq) ‖ N(μp, σp))` per step, summed.
//! - [`squared_error`]: `Σ (a − b)²`.
//! - [`skeleton`]: bone directions → joint positions (forward kinematics
//!   with per-window bone lengths).
//! - [`feet`]: the foot lock over whole sequences (grounding, root motion
//!   from the planted toes) and the penalty on toes that slide in contact.
//! - [`filter`]: a causal per-channel low-pass filter over time.
//!
//! Blocks do not split their work across threads: training shards the
//! batch ([`crate::train`]) and runs shards in parallel, so every block sees
//! one shard and its results never depend on the thread count.

use candle_core::{CpuStorage, Layout, Result, Storage, Tensor};
use std::cell::Cell;

pub mod feet;
pub mod filter;
pub(crate) mod kernels;
pub mod kl;
pub mod linear;
pub(crate) mod rollout;
pub mod scan;
pub mod skeleton;
pub mod timing;

pub use kernels::SIGMA_MIN;
pub use kl::gaussian_kl;
pub use linear::{add_rows, control_rows, linear, squared_error, Act};
pub use scan::{latent_lstm, lstm_cell};

thread_local! {
    static REFERENCE: Cell<bool> = const { Cell::new(false) };
}

/// Run `f` with every block of this thread computed by candle ops (the
/// reference implementation and its autograd) instead of the fused kernels.
pub fn reference<R>(f: impl FnOnce() -> R) -> R {
    let before = REFERENCE.with(|r| r.replace(true));
    let out = f();
    REFERENCE.with(|r| r.set(before));
    out
}

/// Whether a block over `t` runs its fused CPU kernel.
pub(crate) fn fused(t: &Tensor) -> bool {
    t.device().is_cpu() && !REFERENCE.with(Cell::get)
}

/// The `f32` slice of a contiguous CPU storage.
pub(crate) fn slice<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> Result<&'a [f32]> {
    let CpuStorage::F32(v) = s else {
        candle_core::bail!("{what} must be f32");
    };
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&v[a..b]),
        None => candle_core::bail!("{what} must be contiguous"),
    }
}

/// Call `f` with the values of a CPU tensor (no copy when it is contiguous).
pub(crate) fn with_values<R>(t: &Tensor, f: impl FnOnce(&[f32]) -> Result<R>) -> Result<R> {
    let t = t.contiguous()?;
    let (storage, layout) = t.storage_and_layout();
    match &*storage {
        Storage::Cpu(s) => f(slice(s, layout, "tensor")?),
        _ => candle_core::bail!("a fused block's backward runs on the CPU only"),
    }
}

/// A CPU tensor of `shape` holding `v`.
pub(crate) fn tensor(v: Vec<f32>, shape: &[usize], like: &Tensor) -> Result<Tensor> {
    Tensor::from_vec(v, shape, like.device())
}
