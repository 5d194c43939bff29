//! Shared CPU kernels: strided matrix products and vectorisable activations.

// The x86-64 kernels are compiled out elsewhere (WebAssembly), leaving
// their arguments and helpers unread there.
#![cfg_attr(not(target_arch = "x86_64"), allow(unused, dead_code))]

/// Lower bound on every standard deviation (guards `log σ` and `1/σ²`):
/// every σ is a sigmoid clamped to `[SIGMA_MIN, 1]`.
pub const SIGMA_MIN: f64 = 1e-4;

/// A strided matrix view into a slice: element `(r, c)` is at
/// `off + r·rs + c·cs`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct V {
    pub off: usize,
    pub rs: usize,
    pub cs: usize,
}

/// Row-major view with row stride `rs`, starting at `off`.
pub(crate) fn rm(off: usize, rs: usize) -> V {
    V { off, rs, cs: 1 }
}

/// The transpose of a row-major block with row stride `rs` starting at `off`.
pub(crate) fn tr(off: usize, rs: usize) -> V {
    V { off, rs: 1, cs: rs }
}

/// Longest run of the inner dimension one `gemm` call sums. `gemm` cuts a
/// longer one into blocks whose length it derives from the CPU's L1 cache
/// (512 on a 32 KiB 8-way L1, 1,024 on a 48 KiB 12-way one), and the block
/// length decides the order of the sum: the same product came out different
/// in its last bits on different CPUs, and training diverged from there. So
/// [`mm`] cuts the inner dimension itself, exactly as `gemm` does with
/// 512-long blocks (equal blocks of at most this length, summed in order),
/// and every call `gemm` sees is a single block whatever the cache.
pub(crate) const K_BLOCK: usize = 512;

/// The `(start, length)` pieces [`mm`] cuts an inner dimension of `k`
/// into; an empty one is one empty piece, so `gemm` still writes `c`.
pub(crate) fn k_blocks(k: usize) -> impl Iterator<Item = (usize, usize)> {
    let pieces = k.div_ceil(K_BLOCK).max(1);
    let len = k.div_ceil(pieces);
    (0..pieces).map(move |i| {
        let start = (i * len).min(k);
        (start, len.min(k - start))
    })
}

/// `c (+)= a · b` with `a: m×k`, `b: k×n`, `c: m×n`; single-threaded; the
/// same bits on every CPU that runs `gemm`'s same kernel ([`K_BLOCK`]).
/// Where the CPU has AVX2 and FMA, a block `gemm` would sum on its general
/// route runs through [`fma_strided`] instead ([`block_fma`]; the weights'
/// gradients, whose transposed left side it reads where it lies): the same
/// bits.
#[allow(clippy::too_many_arguments)]
pub(crate) fn mm(
    mnk: (usize, usize, usize),
    c: &mut [f32],
    cv: V,
    acc: bool,
    a: &[f32],
    av: V,
    b: &[f32],
    bv: V,
) {
    mm_with(mnk, c, cv, acc, a, av, b, bv, true)
}

/// [`mm`], through [`block_fma`] where it gives `gemm`'s bits if `fma`,
/// else through `gemm` alone (the tests' reference).
#[allow(clippy::too_many_arguments)]
fn mm_with(
    (m, n, k): (usize, usize, usize),
    c: &mut [f32],
    cv: V,
    acc: bool,
    a: &[f32],
    av: V,
    b: &[f32],
    bv: V,
    fma: bool,
) {
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !acc {
            for r in 0..m {
                for q in 0..n {
                    c[cv.off + r * cv.rs + q * cv.cs] = 0.0;
                }
            }
        }
        return;
    }
    let end = |v: V, r: usize, q: usize| v.off + (r - 1) * v.rs + (q - 1) * v.cs + 1;
    assert!(end(cv, m, n) <= c.len(), "gemm: destination out of bounds");
    assert!(end(av, m, k) <= a.len(), "gemm: lhs out of bounds");
    assert!(end(bv, k, n) <= b.len(), "gemm: rhs out of bounds");
    for (i, (start, len)) in k_blocks(k).enumerate() {
        let a_block = V {
            off: av.off + start * av.cs,
            ..av
        };
        let b_block = V {
            off: bv.off + start * bv.rs,
            ..bv
        };
        if fma && block_fma((m, n, len), c, cv, acc || i > 0, a, a_block, b, b_block) {
            continue;
        }
        // SAFETY: the asserts above keep every access inside the slices
        // (the block's columns of `a` and rows of `b` lie within `k`); `c`
        // is borrowed mutably, so it cannot alias `a` or `b`.
        unsafe {
            gemm::gemm(
                m,
                n,
                len,
                c.as_mut_ptr().add(cv.off),
                cv.cs as isize,
                cv.rs as isize,
                acc || i > 0,
                a.as_ptr().add(av.off + start * av.cs),
                av.cs as isize,
                av.rs as isize,
                b.as_ptr().add(bv.off + start * bv.rs),
                bv.cs as isize,
                bv.rs as isize,
                1.0,
                1.0,
                false,
                false,
                false,
                gemm::Parallelism::None,
            )
        }
    }
}

/// One block of [`mm`] (`k ≤ K_BLOCK`) through [`fma_strided`] (16 lanes
/// where the CPU has AVX-512F, else 8), reading `a` and `b` where they lie:
/// where the CPU has AVX2 and FMA, `gemm` would take its general route (the
/// FMA chain the kernel reproduces), and the rows of `b` and `c` are
/// contiguous; false, with `c` untouched, elsewhere. (An earlier 8-lane
/// kernel read `a` in rows only, and copying a transposed `a` into rows for
/// it cost more than `gemm`'s packing; the kernel now reads it strided.)
#[allow(clippy::too_many_arguments)]
fn block_fma(
    (m, n, k): (usize, usize, usize),
    c: &mut [f32],
    cv: V,
    acc: bool,
    a: &[f32],
    av: V,
    b: &[f32],
    bv: V,
) -> bool {
    if !(has_avx2_fma() && cv.cs == 1 && bv.cs == 1 && general_route((m, n, k), av, bv)) {
        return false;
    }
    let start = if acc { Start::Dst } else { Start::Zero };
    // SAFETY: the CPU has AVX-512F; `mm` asserted that `a`, `b` and `c` hold
    // every element the views reach.
    #[cfg(target_arch = "x86_64")]
    unsafe {
        fma_strided(
            (m, n, k),
            c.as_mut_ptr().add(cv.off),
            cv.rs,
            a.as_ptr().add(av.off),
            (av.rs, av.cs),
            b.as_ptr().add(bv.off),
            bv.rs,
            start,
        )
    };
    true
}

/// A right-hand side of [`mm`] copied once into one row-major `k × n`
/// block, for [`mm_small`]: the recurrence multiplies by the same weights
/// at every step, and `gemm` packed them again at every call.
pub(crate) struct Packed {
    k: usize,
    n: usize,
    v: Vec<f32>,
}

impl Packed {
    /// The `k × n` matrix `b` seen through `bv`.
    pub(crate) fn new(b: &[f32], bv: V, k: usize, n: usize) -> Packed {
        let mut v = Vec::with_capacity(k * n);
        for r in 0..k {
            v.extend((0..n).map(|q| b[bv.off + r * bv.rs + q * bv.cs]));
        }
        Packed { k, n, v }
    }
}

/// Whether `gemm` runs a product of these sizes and strides through its
/// general kernels, which sum each element as one fused multiply-add chain
/// over the inner dimension in order, from zero, then add it to the
/// destination. Its other routes (`k ≤ 2`, a single row or column, and
/// `m·n ≤ 256` with unit-stride rows of `a` and columns of `b`, which sum
/// in vector lanes first) give other bits, so [`mm_small`] leaves them to it.
fn general_route((m, n, k): (usize, usize, usize), av: V, bv: V) -> bool {
    k > 2 && k <= K_BLOCK && m > 1 && n > 1 && !(m * n <= 256 && av.cs == 1 && bv.rs == 1)
}

/// [`mm`] for the recurrence's small per-step products, with `b` also
/// given [`Packed`]: the same bits as `mm` (each element the same chain of
/// fused multiply-adds, in order), without `gemm`'s packing and dispatch at
/// every call. Runs [`fma_rows`] where `gemm` would run its FMA kernel on
/// the same route ([`general_route`]) and the rows of `a` and `c` are
/// contiguous; `mm` everywhere else.
#[allow(clippy::too_many_arguments)]
pub(crate) fn mm_small(
    (m, n, k): (usize, usize, usize),
    c: &mut [f32],
    cv: V,
    acc: bool,
    a: &[f32],
    av: V,
    b: &[f32],
    bv: V,
    packed: &Packed,
) {
    if fast_rows((m, n, k), av, bv, packed) && cv.cs == 1 {
        let end = |v: V, r: usize, q: usize| v.off + (r - 1) * v.rs + q;
        assert!(
            end(cv, m, n) <= c.len(),
            "mm_small: destination out of bounds"
        );
        assert!(end(av, m, k) <= a.len(), "mm_small: lhs out of bounds");
        let start = if acc { Start::Dst } else { Start::Zero };
        // SAFETY: `fast_rows` checked the CPU's features and `packed`'s
        // size; the asserts keep every row of `a` and `c` inside the slices.
        unsafe {
            fma_rows(
                (m, n, k),
                c.as_mut_ptr().add(cv.off),
                cv.rs,
                a.as_ptr().add(av.off),
                av.rs,
                &packed.v,
                start,
            )
        };
        return;
    }
    mm((m, n, k), c, cv, acc, a, av, b, bv)
}

/// `bias + a · b` (or `a · b`) over rows of `a: m × k` (row-major,
/// contiguous) and `b: k × n` seen through `bv`, into a new `m × n` buffer:
/// the bits of `mm` into a buffer holding the bias in every row (or zeros),
/// through [`fma_rows`] where it gives them (`b` packed once, the buffer
/// neither filled nor read first), through `mm` elsewhere.
pub(crate) fn mm_rows(
    (m, n, k): (usize, usize, usize),
    a: &[f32],
    b: &[f32],
    bv: V,
    bias: Option<&[f32]>,
) -> Vec<f32> {
    if has_avx2_fma() && general_route((m, n, k), rm(0, k), bv) {
        let packed = Packed::new(b, bv, k, n);
        if let Some(y) = rows_fma((m, n, k), a, bv, &packed, bias) {
            return y;
        }
    }
    // The bias in every row (`repeat` copies in doubling blocks: one copy
    // call per row cost 4 % of a `motion` step).
    let mut y = bias.map_or_else(|| vec![0.0; m * n], |v| v.repeat(m));
    mm(
        (m, n, k),
        &mut y,
        rm(0, n),
        bias.is_some(),
        a,
        rm(0, k),
        b,
        bv,
    );
    y
}

/// [`mm_rows`] through [`fma_rows`], with `b` already packed; `None` where
/// [`fast_rows`] does not hold.
fn rows_fma(
    (m, n, k): (usize, usize, usize),
    a: &[f32],
    bv: V,
    packed: &Packed,
    bias: Option<&[f32]>,
) -> Option<Vec<f32>> {
    if !fast_rows((m, n, k), rm(0, k), bv, packed)
        || a.len() < m * k
        || bias.is_some_and(|b| b.len() != n)
    {
        return None;
    }
    let mut out = Vec::<f32>::with_capacity(m * n);
    let start = bias.map_or(Start::Zero, Start::Bias);
    // SAFETY: `fast_rows` checked the CPU's features and `packed`'s size;
    // `a` holds `m` rows of `k` and `out` room for `m` rows of `n`, every
    // element of which `fma_rows` writes before the length is set.
    unsafe {
        fma_rows(
            (m, n, k),
            out.as_mut_ptr(),
            n,
            a.as_ptr(),
            k,
            &packed.v,
            start,
        );
        out.set_len(m * n);
    }
    Some(out)
}

/// Whether [`fma_rows`] gives `mm`'s bits for this product: a CPU with AVX2
/// and FMA (where `gemm` runs its FMA kernels), `gemm`'s general route, and
/// `packed` of the product's size.
fn fast_rows((m, n, k): (usize, usize, usize), av: V, bv: V, packed: &Packed) -> bool {
    has_avx2_fma()
        && cfg!(target_arch = "x86_64")
        && general_route((m, n, k), av, bv)
        && (packed.k, packed.n) == (k, n)
        && av.cs == 1
}

/// What an element of [`fma_rows`] starts from: its sum alone, the
/// destination plus its sum, or the bias of its column plus its sum.
#[derive(Clone, Copy)]
enum Start<'a> {
    Zero,
    Dst,
    Bias(&'a [f32]),
}

/// The kernel of [`mm_small`] and [`mm_rows`]: each element summed as
/// `gemm`'s FMA kernel sums it, from zero, one fused multiply-add per step
/// of the inner dimension in order, then added to its start.
///
/// # Safety
/// The CPU has AVX2 and FMA; `a` points at `m` rows of `k` values `a_rs`
/// apart, `c` at `m` rows of `n` writable values `c_rs` apart (readable
/// too with [`Start::Dst`]), `b` holds `k × n` values and a bias `n`.
#[cfg(target_arch = "x86_64")]
unsafe fn fma_rows(
    mnk: (usize, usize, usize),
    c: *mut f32,
    c_rs: usize,
    a: *const f32,
    a_rs: usize,
    b: &[f32],
    start: Start,
) {
    fma_strided(mnk, c, c_rs, a, (a_rs, 1), b.as_ptr(), mnk.1, start)
}

/// [`fma_rows`] with element `(r, i)` of `a` at `r·a_rs + i·a_cs` and row
/// `i` of `b` at `i·b_rs`: 16 lanes at a time where the CPU has AVX-512
/// ([`fma_avx512`]), else 8 ([`fma_avx2`]). A lane's sum is the same chain
/// of correctly rounded operations at either width, so the bits are too.
///
/// # Safety
/// As [`fma_rows`], for those strides.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
unsafe fn fma_strided(
    mnk: (usize, usize, usize),
    c: *mut f32,
    c_rs: usize,
    a: *const f32,
    a_s: (usize, usize),
    b: *const f32,
    b_rs: usize,
    start: Start,
) {
    if has_avx512() {
        fma_avx512(mnk, c, c_rs, a, a_s, b, b_rs, start)
    } else {
        fma_avx2(mnk, c, c_rs, a, a_s, b, b_rs, start)
    }
}

/// [`fma_strided`] in 8 lanes: tiles of 6 rows (12 accumulators of the 16
/// registers, as `gemm`'s kernel) by 16 columns.
///
/// # Safety
/// As [`fma_strided`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn fma_avx2(
    mnk: (usize, usize, usize),
    c: *mut f32,
    c_rs: usize,
    a: *const f32,
    a_s: (usize, usize),
    b: *const f32,
    b_rs: usize,
    start: Start,
) {
    blocks::<std::arch::x86_64::__m256>(mnk, c, c_rs, a, a_s, b, b_rs, start)
}

/// [`fma_strided`] in 16 lanes: tiles of 8 rows (16 accumulators of the 32
/// registers) by 32 columns. On a core with 512-bit multiply-add units
/// (AMD Zen 5, Intel server cores) twice the arithmetic of [`fma_avx2`]
/// per instruction.
///
/// # Safety
/// As [`fma_strided`], and the CPU has AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn fma_avx512(
    mnk: (usize, usize, usize),
    c: *mut f32,
    c_rs: usize,
    a: *const f32,
    a_s: (usize, usize),
    b: *const f32,
    b_rs: usize,
    start: Start,
) {
    blocks::<std::arch::x86_64::__m512>(mnk, c, c_rs, a, a_s, b, b_rs, start)
}

/// Off x86-64 [`fast_rows`] never holds, so nothing calls this.
#[cfg(not(target_arch = "x86_64"))]
unsafe fn fma_rows(
    _: (usize, usize, usize),
    _: *mut f32,
    _: usize,
    _: *const f32,
    _: usize,
    _: &[f32],
    _: Start,
) {
    unreachable!("fma_rows runs only where fast_rows holds (x86-64)")
}

/// A vector of `f32` lanes for [`blocks`]: its width, the rows of a full
/// tile, and the operations the tiles use (each compiled into the
/// `#[target_feature]` function that instantiates [`blocks`] with it).
#[cfg(target_arch = "x86_64")]
trait Lanes: Copy {
    /// Lanes of a vector.
    const N: usize;
    /// Rows of a full tile: two vectors of accumulators each.
    const ROWS: usize;
    /// Which lanes a masked load or store touches.
    type Mask: Copy;
    /// The first `lanes` lanes (1..N).
    unsafe fn mask(lanes: usize) -> Self::Mask;
    unsafe fn zero() -> Self;
    unsafe fn splat(x: f32) -> Self;
    unsafe fn load(p: *const f32, m: Option<Self::Mask>) -> Self;
    unsafe fn store(p: *mut f32, v: Self, m: Option<Self::Mask>);
    /// `a·b + c`, rounded once.
    unsafe fn fma(a: Self, b: Self, c: Self) -> Self;
    unsafe fn add(a: Self, b: Self) -> Self;
}

#[cfg(target_arch = "x86_64")]
impl Lanes for std::arch::x86_64::__m256 {
    const N: usize = 8;
    const ROWS: usize = 6;
    type Mask = std::arch::x86_64::__m256i;
    #[inline(always)]
    unsafe fn mask(lanes: usize) -> Self::Mask {
        use std::arch::x86_64::*;
        _mm256_cmpgt_epi32(
            _mm256_set1_epi32(lanes as i32),
            _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
        )
    }
    #[inline(always)]
    unsafe fn zero() -> Self {
        std::arch::x86_64::_mm256_setzero_ps()
    }
    #[inline(always)]
    unsafe fn splat(x: f32) -> Self {
        std::arch::x86_64::_mm256_set1_ps(x)
    }
    #[inline(always)]
    unsafe fn load(p: *const f32, m: Option<Self::Mask>) -> Self {
        use std::arch::x86_64::*;
        match m {
            Some(m) => _mm256_maskload_ps(p, m),
            None => _mm256_loadu_ps(p),
        }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: Self, m: Option<Self::Mask>) {
        use std::arch::x86_64::*;
        match m {
            Some(m) => _mm256_maskstore_ps(p, m, v),
            None => _mm256_storeu_ps(p, v),
        }
    }
    #[inline(always)]
    unsafe fn fma(a: Self, b: Self, c: Self) -> Self {
        std::arch::x86_64::_mm256_fmadd_ps(a, b, c)
    }
    #[inline(always)]
    unsafe fn add(a: Self, b: Self) -> Self {
        std::arch::x86_64::_mm256_add_ps(a, b)
    }
}

#[cfg(target_arch = "x86_64")]
impl Lanes for std::arch::x86_64::__m512 {
    const N: usize = 16;
    const ROWS: usize = 8;
    type Mask = std::arch::x86_64::__mmask16;
    #[inline(always)]
    unsafe fn mask(lanes: usize) -> Self::Mask {
        ((1u32 << lanes) - 1) as u16
    }
    #[inline(always)]
    unsafe fn zero() -> Self {
        std::arch::x86_64::_mm512_setzero_ps()
    }
    #[inline(always)]
    unsafe fn splat(x: f32) -> Self {
        std::arch::x86_64::_mm512_set1_ps(x)
    }
    #[inline(always)]
    unsafe fn load(p: *const f32, m: Option<Self::Mask>) -> Self {
        use std::arch::x86_64::*;
        match m {
            Some(m) => _mm512_maskz_loadu_ps(m, p),
            None => _mm512_loadu_ps(p),
        }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: Self, m: Option<Self::Mask>) {
        use std::arch::x86_64::*;
        match m {
            Some(m) => _mm512_mask_storeu_ps(p, m, v),
            None => _mm512_storeu_ps(p, v),
        }
    }
    #[inline(always)]
    unsafe fn fma(a: Self, b: Self, c: Self) -> Self {
        std::arch::x86_64::_mm512_fmadd_ps(a, b, c)
    }
    #[inline(always)]
    unsafe fn add(a: Self, b: Self) -> Self {
        std::arch::x86_64::_mm512_add_ps(a, b)
    }
}

/// [`fma_strided`] in vectors `L`: tiles of `L::ROWS` rows (then 4, 2, 1)
/// by two vectors of columns (the last block one or two, its last vector
/// under a mask where the columns run out: one column at a time cost the
/// decoder's 60-wide output twice its time).
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[inline(always)]
unsafe fn blocks<L: Lanes>(
    (m, n, k): (usize, usize, usize),
    c: *mut f32,
    c_rs: usize,
    a: *const f32,
    a_s: (usize, usize),
    b: *const f32,
    b_rs: usize,
    start: Start,
) {
    let mut q = 0;
    while q < n {
        let width = (n - q).min(2 * L::N);
        let mut r = 0;
        while r < m {
            let rows = match m - r {
                x if x >= L::ROWS => L::ROWS,
                4.. => 4,
                2 | 3 => 2,
                _ => 1,
            };
            let (ct, at, bt) = (c.add(r * c_rs + q), a.add(r * a_s.0), b.add(q));
            let st = match start {
                Start::Bias(v) => Start::Bias(&v[q..]),
                s => s,
            };
            let t = Tile {
                k,
                a: at,
                a_s,
                b: bt,
                b_rs,
                c: ct,
                c_rs,
                start: st,
                width,
            };
            match rows {
                8 => tile_of::<L, 8>(t),
                6 => tile_of::<L, 6>(t),
                4 => tile_of::<L, 4>(t),
                2 => tile_of::<L, 2>(t),
                _ => tile_of::<L, 1>(t),
            }
            r += rows;
        }
        q += width;
    }
}

/// One tile of [`blocks`]: `k` steps of the inner dimension, `a` at its
/// first row (strides `a_s`), `b` at its first column (rows `b_rs` apart),
/// `c` at its first element (rows `c_rs` apart), `width` (1 to two
/// vectors) columns.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct Tile<'a> {
    k: usize,
    a: *const f32,
    a_s: (usize, usize),
    b: *const f32,
    b_rs: usize,
    c: *mut f32,
    c_rs: usize,
    start: Start<'a>,
    width: usize,
}

/// `R` rows of a [`Tile`]: two vectors past one vector's width, the last
/// under a mask unless the width fills it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn tile_of<L: Lanes, const R: usize>(t: Tile) {
    match (t.width > L::N, t.width.is_multiple_of(L::N)) {
        (true, true) => tile::<L, R, 2, false>(t),
        (true, false) => tile::<L, R, 2, true>(t),
        (false, true) => tile::<L, R, 1, false>(t),
        (false, false) => tile::<L, R, 1, true>(t),
    }
}

/// `R` rows by `C` vectors of a [`Tile`]; with `MASK`, the last vector's
/// first `width − N·(C − 1)` lanes only: lanes past them are neither read
/// nor written.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn tile<L: Lanes, const R: usize, const C: usize, const MASK: bool>(t: Tile) {
    let Tile {
        k,
        a,
        a_s: (a_rs, a_cs),
        b,
        b_rs,
        c,
        c_rs,
        start,
        width,
    } = t;
    let mask = MASK.then(|| L::mask(width - L::N * (C - 1)));
    let m = |j: usize| if j + 1 == C { mask } else { None };
    let mut sum = [[L::zero(); C]; R];
    for i in 0..k {
        let mut bv = [L::zero(); C];
        for (j, v) in bv.iter_mut().enumerate() {
            *v = L::load(b.add(i * b_rs + L::N * j), m(j));
        }
        for (row, s) in sum.iter_mut().enumerate() {
            let x = L::splat(*a.add(row * a_rs + i * a_cs));
            for (s, v) in s.iter_mut().zip(&bv) {
                *s = L::fma(x, *v, *s);
            }
        }
    }
    for (row, s) in sum.iter().enumerate() {
        for (j, s) in s.iter().enumerate() {
            let p = c.add(row * c_rs + L::N * j);
            let v = match start {
                Start::Zero => *s,
                Start::Dst => L::add(L::load(p, m(j)), *s),
                Start::Bias(v) => L::add(L::load(v.as_ptr().add(L::N * j), m(j)), *s),
            };
            L::store(p, v, m(j));
        }
    }
}

/// Whether this CPU has AVX-512F, for [`fma_rows`].
#[inline]
pub(crate) fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether this CPU runs [`simd_fn!`]'s AVX2 + FMA instance.
#[inline]
pub(crate) fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `fn name(args) -> R { body }`, its body compiled twice: for AVX2 and FMA
/// (run where the CPU has them, detected at run time) and as built. The
/// blocks' element-wise loops live in such functions: the build targets
/// baseline x86-64 (SSE2, four lanes), and eight lanes cut their time. The
/// bits do not change: Rust never contracts `a·b + c` into an FMA and never
/// reorders a float sum, so every element comes from the same IEEE
/// operations in the same order whatever the vector width (`gemm` picks its
/// own kernel either way). Helpers the body calls must be
/// `#[inline(always)]` to be compiled into the fast instance.
macro_rules! simd_fn {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty $body:block) => {
        $(#[$m])*
        $vis fn $name($($arg: $ty),*) -> $ret {
            #[inline(always)]
            fn body($($arg: $ty),*) -> $ret $body
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            unsafe fn fast($($arg: $ty),*) -> $ret {
                body($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            if $crate::blocks::kernels::has_avx2_fma() {
                // SAFETY: the CPU has both features (checked just above).
                return unsafe { fast($($arg),*) };
            }
            body($($arg),*)
        }
    };
}
pub(crate) use simd_fn;

/// `exp(x)` in f32 without a libm call, so loops over it vectorise
/// (Cephes' `expf`: `2ⁿ · p(r)` with `r = x − n·ln 2`; about 1 ulp).
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    // Round x/ln 2 to the nearest integer with the 1.5·2²³ trick; the
    // integer sits in the low mantissa bits of `big`.
    let big = x * std::f32::consts::LOG2_E + 12_582_912.0;
    let n = big - 12_582_912.0;
    let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 0.166_666_65)
        * r
        + 0.5;
    let y = p * r * r + r + 1.0;
    let k = big.to_bits().wrapping_sub(0x4B40_0000);
    y * f32::from_bits(k.wrapping_add(127) << 23)
}

/// `tanh(x)` (Cephes' `tanhf`: an odd polynomial below 0.625, else from
/// [`exp`]); branch-free so loops over it vectorise.
#[inline(always)]
pub(crate) fn tanh(x: f32) -> f32 {
    let a = x.abs();
    let z = x * x;
    let small = ((((-5.704_988_7e-3 * z + 2.063_909e-2) * z - 5.373_971_6e-2) * z + 0.133_314_42)
        * z
        - 0.333_332_8)
        * z
        * x
        + x;
    let big = (1.0 - 2.0 / (exp(2.0 * a) + 1.0)).copysign(x);
    if a < 0.625 {
        small
    } else {
        big
    }
}

/// The logistic function.
#[inline(always)]
pub(crate) fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// `sigmoid` clamped to `[SIGMA_MIN, 1]`, as the models' standard deviations.
#[inline]
pub(crate) fn sigma(x: f32) -> f32 {
    sigmoid(x).clamp(SIGMA_MIN as f32, 1.0)
}

/// `dσ/dx` of [`sigma`] given its value (zero where the clamp holds).
#[inline]
pub(crate) fn dsigma(s: f32) -> f32 {
    if s > SIGMA_MIN as f32 {
        s * (1.0 - s)
    } else {
        0.0
    }
}

#[cfg(test)]
#[path = "kernels_tests.rs"]
mod tests;
