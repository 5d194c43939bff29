//! Tests of the kernels: every product route gives `gemm`'s bits.

use super::*;

/// A deterministic spread of values in [−1.5, 1.5) for the products'
/// operands, `salt` telling operands apart.
fn value(i: usize, salt: usize) -> f32 {
    let x = (i * 2_654_435_761 + salt * 40_503) % 1_000_003;
    (x as f32 / 1_000_003.0 - 0.5) * 3.0
}

/// A width of the kernel, as [`fma_strided`] calls it.
#[cfg(target_arch = "x86_64")]
type Kernel = unsafe fn(
    (usize, usize, usize),
    *mut f32,
    usize,
    *const f32,
    (usize, usize),
    *const f32,
    usize,
    Start,
);

/// Every width of the kernel this CPU runs, named (none without AVX2
/// and FMA; the 16-lane one only with AVX-512F).
#[cfg(target_arch = "x86_64")]
fn widths() -> Vec<(&'static str, Kernel)> {
    let mut k: Vec<(&str, Kernel)> = Vec::new();
    if has_avx2_fma() {
        k.push(("avx2", fma_avx2));
    }
    if has_avx512() {
        k.push(("avx512", fma_avx512));
    } else {
        eprintln!("AVX-512 part skipped: this CPU has no AVX-512F");
    }
    k
}

/// The inner dimension is cut as `gemm` cuts it with 512-long blocks:
/// equal pieces of at most 512, in order, covering it once.
#[test]
fn inner_blocks_are_gemms_512_blocks() {
    let cut = |k: usize| k_blocks(k).collect::<Vec<_>>();
    assert_eq!(cut(100), [(0, 100)]);
    assert_eq!(cut(512), [(0, 512)]);
    assert_eq!(cut(513), [(0, 257), (257, 256)]);
    assert_eq!(cut(1000), [(0, 500), (500, 500)]);
    assert_eq!(
        cut(4096),
        (0..8).map(|i| (512 * i, 512)).collect::<Vec<_>>()
    );
    assert_eq!(cut(1), [(0, 1)]);
    assert_eq!(cut(0), [(0, 0)]);
    assert_eq!(cut(1025), [(0, 342), (342, 342), (684, 341)]);
}

simd_fn! {
    /// The activations and a cell update over a slice, in [`simd_fn!`].
    fn activations(x: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(4 * x.len());
        out.extend(x.iter().map(|&v| exp(v)));
        out.extend(x.iter().map(|&v| tanh(v)));
        out.extend(x.iter().map(|&v| sigma(v)));
        out.extend(x.iter().zip(x.iter().rev()).map(|(&a, &b)| a * b + b * sigmoid(a)));
        out
    }
}

/// The AVX2 instance of a [`simd_fn!`] gives the bits of the baseline
/// build, element by element, over the activations' whole range
/// (this machine runs the AVX2 one where it has the features; the loop
/// below is compiled for the baseline and not vectorised with AVX2).
#[test]
fn the_fast_instance_gives_the_baseline_bits() {
    let x: Vec<f32> = (0..20_011)
        .map(|i| (i as f32 - 10_005.0) * 0.0123 + (i % 7) as f32 * 1e-4)
        .chain([0.0, -0.0, 1e-30, -1e-30, 100.0, -100.0, 88.7, -87.5])
        .collect();
    let got = activations(&x);
    let mut want = Vec::with_capacity(4 * x.len());
    for &v in &x {
        want.push(std::hint::black_box(exp(v)));
    }
    for &v in &x {
        want.push(std::hint::black_box(tanh(v)));
    }
    for &v in &x {
        want.push(std::hint::black_box(sigma(v)));
    }
    for (&a, &b) in x.iter().zip(x.iter().rev()) {
        want.push(std::hint::black_box(a * b + b * sigmoid(a)));
    }
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert_eq!(g.to_bits(), w.to_bits(), "element {i}: {g} against {w}");
    }
}

/// `mm_small` gives `mm`'s bits for the recurrence's products (and the
/// shapes `gemm` routes elsewhere), accumulating or not, on strided rows.
#[test]
fn small_products_give_gemms_bits() {
    // (m, n, k, b transposed): the scan's four products at 32 and at
    // other shard sizes, and odd shapes.
    let shapes = [
        (32, 16, 32, true),
        (32, 128, 40, true),
        (32, 40, 128, false),
        (32, 32, 16, false),
        (5, 16, 32, true),
        (2, 128, 40, true),
        (7, 40, 128, false),
        (9, 32, 16, false),
        (1, 16, 32, true),
        (33, 24, 3, true),
        (6, 8, 2, false),
        (17, 12, 5, true),
        (4096, 60, 48, true),
        (4096, 40, 32, false),
        (101, 20, 33, true),
        // Last columns under a mask: 1, 2 and 7 of them.
        (5, 9, 7, false),
        (13, 58, 48, true),
        (6, 63, 20, false),
    ];
    for (m, n, k, trans) in shapes {
        for acc in [false, true] {
            // Rows of `a` and `c` a few values wider than used, offset.
            let (a_rs, c_rs) = (k + 3, n + 5);
            let a: Vec<f32> = (0..2 + m * a_rs).map(|i| value(i, 1)).collect();
            let b: Vec<f32> = (0..k * n).map(|i| value(i, 2)).collect();
            let bv = if trans { tr(0, k) } else { rm(0, n) };
            let packed = Packed::new(&b, bv, k, n);
            let c0: Vec<f32> = (0..1 + m * c_rs).map(|i| value(i, 3)).collect();
            let (mut want, mut got) = (c0.clone(), c0);
            let (av, cv) = (rm(2, a_rs), rm(1, c_rs));
            mm_with((m, n, k), &mut want, cv, acc, &a, av, &b, bv, false);
            mm_small((m, n, k), &mut got, cv, acc, &a, av, &b, bv, &packed);
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                assert_eq!(
                    g.to_bits(),
                    w.to_bits(),
                    "{m}x{n}x{k} (acc {acc}) element {i}: {g} against {w}"
                );
            }
        }
        // A dense layer's rows into a new buffer, from the bias or zero,
        // against `mm` into the bias repeated (or zeros).
        let a: Vec<f32> = (0..m * k).map(|i| value(i, 4)).collect();
        let b: Vec<f32> = (0..k * n).map(|i| value(i, 5)).collect();
        let bv = if trans { tr(0, k) } else { rm(0, n) };
        let packed = Packed::new(&b, bv, k, n);
        let bias: Vec<f32> = (0..n).map(|i| value(i, 6)).collect();
        for start in [Some(&bias[..]), None] {
            let mut want = match start {
                Some(v) => v.repeat(m),
                None => vec![0.0; m * n],
            };
            mm_with(
                (m, n, k),
                &mut want,
                rm(0, n),
                start.is_some(),
                &a,
                rm(0, k),
                &b,
                bv,
                false,
            );
            // Whichever route it takes, `mm_rows` gives `gemm`'s bits.
            let rows = mm_rows((m, n, k), &a, &b, bv, start);
            for (i, (g, w)) in rows.iter().zip(&want).enumerate() {
                assert_eq!(g.to_bits(), w.to_bits(), "{m}x{n}x{k} mm_rows, element {i}");
            }
            match rows_fma((m, n, k), &a, bv, &packed, start) {
                Some(got) => {
                    assert!(has_avx2_fma() && general_route((m, n, k), rm(0, k), bv));
                    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                        assert_eq!(g.to_bits(), w.to_bits(), "{m}x{n}x{k} rows, element {i}");
                    }
                }
                None => assert!(!has_avx2_fma() || !general_route((m, n, k), rm(0, k), bv)),
            }
        }
    }
}

/// Both widths of [`fma_rows`] give `mm`'s bits on every tile of each
/// (rows 8, 4, 2, 1 and 6; blocks of 32, 16 and 8 columns, every masked
/// width), from zero, the destination and a bias; the 16-lane one only
/// where the CPU has AVX-512 (the 8-lane one runs on such CPUs too).
#[cfg(target_arch = "x86_64")]
#[test]
fn both_widths_give_gemms_bits() {
    if !has_avx2_fma() {
        eprintln!("skipped: this CPU has no AVX2 and FMA");
        return;
    }
    let kernels = widths();
    let (k, m) = (37, 15);
    // From 2 columns: `gemm` sums a single one another way (`general_route`).
    for n in (2..=40).chain([47, 48, 58, 60, 63, 64, 128]) {
        let (a_rs, c_rs) = (k + 2, n + 3);
        let a: Vec<f32> = (0..m * a_rs).map(|i| value(i, 1)).collect();
        let b: Vec<f32> = (0..k * n).map(|i| value(i, 2)).collect();
        let bias: Vec<f32> = (0..n).map(|i| value(i, 3)).collect();
        let c0: Vec<f32> = (0..m * c_rs).map(|i| value(i, 4)).collect();
        for start in [Start::Zero, Start::Dst, Start::Bias(&bias)] {
            // `mm` into the destination, the bias in every row, or zeros.
            let mut want = c0.clone();
            for r in 0..m {
                let row = &mut want[r * c_rs..r * c_rs + n];
                match start {
                    Start::Zero => row.fill(0.0),
                    Start::Bias(v) => row.copy_from_slice(v),
                    Start::Dst => {}
                }
            }
            let acc = !matches!(start, Start::Zero);
            let (av, bv) = (rm(0, a_rs), rm(0, n));
            mm_with(
                (m, n, k),
                &mut want,
                rm(0, c_rs),
                acc,
                &a,
                av,
                &b,
                bv,
                false,
            );
            for (name, kernel) in &kernels {
                let mut got = c0.clone();
                // SAFETY: the CPU has the kernel's features (checked
                // above); `a`, `b` and `got` hold every row it touches.
                unsafe {
                    kernel(
                        (m, n, k),
                        got.as_mut_ptr(),
                        c_rs,
                        a.as_ptr(),
                        (a_rs, 1),
                        b.as_ptr(),
                        n,
                        start,
                    )
                };
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(
                        g.to_bits(),
                        w.to_bits(),
                        "{name} n {n}, element {i}: {g} against {w}"
                    );
                }
            }
        }
    }
}

/// `mm` gives `gemm`'s bits on the weights' gradients (a transposed
/// left side, thousands of rows summed in blocks of [`K_BLOCK`]), from
/// zero and accumulated, into strided rows; so does each width of the
/// kernel alone on one block (the 16-lane one where the CPU has
/// AVX-512; `mm` runs the widest the CPU has).
#[test]
fn weight_gradients_give_gemms_bits() {
    // (out, inp, rows, offset of b's columns, b's row stride): dense
    // layers' `gᵀ · x`, and the scan's, whose `b` starts inside a row.
    let shapes = [
        (16, 32, 4096, 0, 32),
        (128, 40, 4096, 0, 40),
        (48, 58, 1000, 0, 58),
        (60, 48, 300, 0, 48),
        (8, 32, 4096, 0, 32),
        (16, 32, 4096, 8, 40),
        (3, 5, 7, 2, 9),
        (128, 40, 512, 0, 40),
        (16, 32, 512, 8, 40),
    ];
    #[cfg(target_arch = "x86_64")]
    let kernels = widths();
    for (out, inp, rows, off, b_rs) in shapes {
        let g: Vec<f32> = (0..rows * out).map(|i| value(i, 1)).collect();
        let x: Vec<f32> = (0..rows * b_rs).map(|i| value(i, 2)).collect();
        let c0: Vec<f32> = (0..out * (inp + 1)).map(|i| value(i, 3)).collect();
        for acc in [false, true] {
            let run = |fma: bool| {
                let mut c = c0.clone();
                let (av, bv) = (tr(0, out), rm(off, b_rs));
                mm_with(
                    (out, inp, rows),
                    &mut c,
                    rm(0, inp + 1),
                    acc,
                    &g,
                    av,
                    &x,
                    bv,
                    fma,
                );
                c
            };
            let (got, want) = (run(true), run(false));
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                assert_eq!(
                    g.to_bits(),
                    w.to_bits(),
                    "{out}x{inp}x{rows} (acc {acc}) element {i}: {g} against {w}"
                );
            }
            // Each width alone, where one block holds every row and
            // `gemm` takes its general route.
            #[cfg(target_arch = "x86_64")]
            if rows <= K_BLOCK && general_route((out, inp, rows), tr(0, out), rm(off, b_rs)) {
                for (name, kernel) in &kernels {
                    let mut c = c0.clone();
                    let start = if acc { Start::Dst } else { Start::Zero };
                    // SAFETY: the CPU has the kernel's features; `g`
                    // holds `rows × out`, `x` `rows` rows of `b_rs` from
                    // `off`, `c` `out` rows of `inp + 1`.
                    unsafe {
                        kernel(
                            (out, inp, rows),
                            c.as_mut_ptr(),
                            inp + 1,
                            g.as_ptr(),
                            (1, out),
                            x.as_ptr().add(off),
                            b_rs,
                            start,
                        )
                    };
                    for (i, (g, w)) in c.iter().zip(&want).enumerate() {
                        assert_eq!(
                            g.to_bits(),
                            w.to_bits(),
                            "{name} {out}x{inp}x{rows} (acc {acc}) element {i}: {g} against {w}"
                        );
                    }
                }
            }
        }
    }
}

/// A product longer than one block, strided and accumulated, against a
/// sum in f64.
#[test]
fn a_long_product_is_the_product() {
    let (m, n, k) = (3, 5, 1300);
    let a: Vec<f32> = (0..m * k)
        .map(|i| ((i * 7 % 13) as f32 - 6.0) / 7.0)
        .collect();
    let b: Vec<f32> = (0..k * n)
        .map(|i| ((i * 5 % 11) as f32 - 5.0) / 3.0)
        .collect();
    // c = 1 + a · bᵀᵀ with b stored transposed (n × k, row-major).
    let mut c = vec![1.0f32; m * n];
    mm(
        (m, n, k),
        &mut c,
        rm(0, n),
        true,
        &a,
        rm(0, k),
        &b,
        tr(0, k),
    );
    for r in 0..m {
        for q in 0..n {
            let want: f64 = 1.0
                + (0..k)
                    .map(|i| a[r * k + i] as f64 * b[q * k + i] as f64)
                    .sum::<f64>();
            let got = c[r * n + q] as f64;
            assert!(
                (got - want).abs() < 1e-3 * want.abs().max(1.0),
                "{got} vs {want}"
            );
        }
    }
}
