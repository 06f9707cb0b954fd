//! One small GEMM: `C[m×n] += A(m×k) · B[k×n]`, B and C row-major, A read through
//! arbitrary strides (so `Aᵀ` costs nothing). Every matrix product of the LSTM, FNN and the
//! heads, forward and backward, is this one form.
//!
//! The AVX-512 path is an 8 × 32 register tile (16 zmm accumulators, B rows loaded with
//! masks at the right edge, A broadcast); the sizes here (≤ 512 wide, K ≤ a few thousand)
//! keep B's panel in L1/L2, so no packing. The portable path is a plain loop the compiler
//! vectorises for the baseline target.
//!
//! Why not faer: at the shapes an LSTM step uses (benches/gemm.rs; best of 15 alternating
//! rounds on the 2-core AVX-512 machine of 2026-11-25) this kernel ran at 52–56 G
//! multiply-adds/s per core, and faer 0.24.4's `matmul` (Par::Seq, same buffers) took
//! 4–9 % longer on the recurrent products (16×512×128, 16×128×512: two thirds of the
//! epoch's arithmetic), 8–17 % longer on the head and dW_ihᵀ, and tied (±3 %) on dW_hh and
//! the input projections. So the kernels call only [`gemm_acc`]; the `faer` feature keeps
//! faer's product beside it for the comparison. Re-run on the Zen 5 guest of 2026-11-27
//! (criterion, G multiply-adds/s, hand / faer): recurrent products 130 / 105 and 129 / 114,
//! dW_hh 127 / 119, head 113–130 / 97–110, dW_ihᵀ 68 / 46; faer wins only the input
//! projection (k = 5: 63 / 68), ≈ 1 % of the epoch's arithmetic. The hand kernel runs at
//! ≈ 95 % of that core's FMA peak (≈ 132 G/s with 12 independent accumulators).

/// A strided view of A: element (i, k) is `data[i * rs + k * cs]`.
#[derive(Clone, Copy)]
pub struct StridedA<'a> {
    pub data: &'a [f32],
    pub rs: usize,
    pub cs: usize,
}

/// `C[m×n] += A(m×k)·B[k×n]`, with `B[kk, j] = b[kk * ldb + j]`, `C[i, j] = c[i * ldc + j]`.
///
/// Panics if a slice is too short for the given shape (a caller bug, never data).
#[allow(clippy::too_many_arguments)]
pub fn gemm_acc(m: usize, n: usize, k: usize, a: StridedA<'_>, b: &[f32], ldb: usize, c: &mut [f32], ldc: usize) {
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    check_bounds(m, n, k, a, b, ldb, c, ldc);
    #[cfg(target_arch = "x86_64")]
    {
        if super::simd::has_avx512() {
            // SAFETY: the CPU has AVX-512F (checked); every access is within the slices
            // (checked by `check_bounds` for the extreme indices of each operand).
            unsafe { avx512::gemm(m, n, k, a, b, ldb, c, ldc) };
            return;
        }
    }
    gemm_portable(m, n, k, a, b, ldb, c, ldc);
}

/// C = bias (each row) + A·B, the bits of copying `bias` into every row of C and then
/// [`gemm_acc`], in one pass over C: the LSTM's gates start as b_ih + b_hh + x_t W_ihᵀ every
/// step (K = J = 5), and the copy and the product's read-add-write of C were two passes over
/// a step's gates for five multiply-adds an element.
#[allow(clippy::too_many_arguments)]
pub fn gemm_set_bias(
    m: usize,
    n: usize,
    k: usize,
    a: StridedA<'_>,
    b: &[f32],
    ldb: usize,
    bias: &[f32],
    c: &mut [f32],
    ldc: usize,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(bias.len() >= n, "gemm_set_bias: bias {} < n {n}", bias.len());
    #[cfg(target_arch = "x86_64")]
    {
        if k > 0 && k <= avx512::KC && super::simd::has_avx512() {
            check_bounds(m, n, k, a, b, ldb, c, ldc);
            // SAFETY: the CPU has AVX-512F (checked); every access is within the slices
            // (checked above for the extreme indices of each operand, and bias ≥ n).
            unsafe { avx512::gemm_set_bias(m, n, k, a, b, ldb, bias, c, ldc) };
            return;
        }
    }
    for i in 0..m {
        c[i * ldc..i * ldc + n].copy_from_slice(&bias[..n]);
    }
    gemm_acc(m, n, k, a, b, ldb, c, ldc);
}

#[allow(clippy::too_many_arguments)]
fn check_bounds(m: usize, n: usize, k: usize, a: StridedA<'_>, b: &[f32], ldb: usize, c: &[f32], ldc: usize) {
    let a_last = (m - 1) * a.rs + (k - 1) * a.cs;
    let b_last = (k - 1) * ldb + n - 1;
    let c_last = (m - 1) * ldc + n - 1;
    assert!(
        a_last < a.data.len() && b_last < b.len() && c_last < c.len() && n <= ldb && n <= ldc,
        "gemm {m}×{n}×{k}: operand too short (A {} needs {}, B {} needs {}, C {} needs {})",
        a.data.len(),
        a_last + 1,
        b.len(),
        b_last + 1,
        c.len(),
        c_last + 1
    );
}

/// The same product through faer 0.24's `matmul` (f32, sequential: the caller's shards are
/// the threads, so faer must not start its own). Views are built over the caller's buffers
/// with their real strides; nothing is copied or allocated here. Only for the comparison at
/// the training shapes (`cargo bench -p bowden-learning --features faer --bench gemm`) and
/// its test: the kernels call [`gemm_acc`].
#[cfg(feature = "faer")]
#[allow(clippy::too_many_arguments)]
pub fn gemm_acc_faer(m: usize, n: usize, k: usize, a: StridedA<'_>, b: &[f32], ldb: usize, c: &mut [f32], ldc: usize) {
    use faer::{Accum, MatMut, MatRef, Par};
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    check_bounds(m, n, k, a, b, ldb, c, ldc);
    let lhs = if a.cs == 1 {
        MatRef::from_row_major_slice_with_stride(a.data, m, k, a.rs)
    } else if a.rs == 1 {
        MatRef::from_column_major_slice_with_stride(a.data, m, k, a.cs)
    } else {
        // SAFETY: `check_bounds` proved the last element (m−1, k−1) lies inside `a.data`,
        // and every stride is non-negative, so every element does.
        unsafe { MatRef::from_raw_parts(a.data.as_ptr(), m, k, a.rs as isize, a.cs as isize) }
    };
    let rhs = MatRef::from_row_major_slice_with_stride(b, k, n, ldb);
    // Not `MatMut::from_row_major_slice_with_stride_mut`: in faer 0.24.4 it builds the view
    // with strides (1, row_stride), i.e. column-major, and the product writes out of bounds.
    let dst = MatMut::from_column_major_slice_with_stride_mut(c, n, m, ldc).transpose_mut();
    faer::linalg::matmul::matmul(dst, Accum::Add, lhs, rhs, 1.0f32, Par::Seq);
}

/// The baseline path (also the reference the tests hold the AVX-512 path to).
#[allow(clippy::too_many_arguments)]
pub fn gemm_portable(m: usize, n: usize, k: usize, a: StridedA<'_>, b: &[f32], ldb: usize, c: &mut [f32], ldc: usize) {
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    check_bounds(m, n, k, a, b, ldb, c, ldc);
    for i in 0..m {
        let crow = &mut c[i * ldc..i * ldc + n];
        for kk in 0..k {
            let av = a.data[i * a.rs + kk * a.cs];
            let brow = &b[kk * ldb..kk * ldb + n];
            for (cv, bv) in crow.iter_mut().zip(brow) {
                *cv += av * bv;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod avx512 {
    use super::StridedA;
    use std::arch::x86_64::*;

    /// Rows of C per register tile; 32 columns (two vectors) per tile, so 16 accumulators.
    pub(in crate::kernels) const MR: usize = 8;
    pub(in crate::kernels) const NR: usize = 32;
    pub(super) const KC: usize = 256;

    /// The load/store masks of a tile's two vectors when `nr` (≤ 32) of its columns are live.
    #[inline(always)]
    pub(in crate::kernels) fn edge_masks(nr: usize) -> (__mmask16, __mmask16) {
        let m0: __mmask16 = if nr >= 16 { 0xffff } else { ((1u32 << nr) - 1) as u16 };
        let m1: __mmask16 = if nr >= 32 {
            0xffff
        } else if nr > 16 {
            ((1u32 << (nr - 16)) - 1) as u16
        } else {
            0
        };
        (m0, m1)
    }

    /// Calls `f(i0, j0, mr, m0, m1)` for every register tile of an m × n product: its first
    /// row and column, its live rows (≤ [`MR`]) and the masks of its live columns. Inlined
    /// into the callers' `#[target_feature]` kernels (closures inherit their features).
    #[inline(always)]
    pub(in crate::kernels) fn for_each_tile(
        m: usize,
        n: usize,
        mut f: impl FnMut(usize, usize, usize, __mmask16, __mmask16),
    ) {
        let mut j0 = 0;
        while j0 < n {
            let (m0, m1) = edge_masks((n - j0).min(NR));
            let mut i0 = 0;
            while i0 < m {
                f(i0, j0, (m - i0).min(MR), m0, m1);
                i0 += MR;
            }
            j0 += NR;
        }
    }

    /// `f::<R>(args)` with R = `mr`, a tile's live rows (1 ..= [`MR`]): the accumulators
    /// are arrays of R registers, so R must be a constant.
    macro_rules! by_rows {
        ($mr:expr, $f:ident($($arg:expr),* $(,)?)) => {
            match $mr {
                8 => $f::<8>($($arg),*),
                7 => $f::<7>($($arg),*),
                6 => $f::<6>($($arg),*),
                5 => $f::<5>($($arg),*),
                4 => $f::<4>($($arg),*),
                3 => $f::<3>($($arg),*),
                2 => $f::<2>($($arg),*),
                _ => $f::<1>($($arg),*),
            }
        };
    }
    pub(in crate::kernels) use by_rows;

    /// C's R rows (stride `ldc`) += the tile's accumulators, under the edge masks.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)]
    pub(in crate::kernels) unsafe fn add_to_c<const R: usize>(
        c: *mut f32,
        ldc: usize,
        acc0: &[__m512; R],
        acc1: &[__m512; R],
        m0: __mmask16,
        m1: __mmask16,
    ) {
        for r in 0..R {
            let crow = c.add(r * ldc);
            let c0 = _mm512_maskz_loadu_ps(m0, crow);
            _mm512_mask_storeu_ps(crow, m0, _mm512_add_ps(c0, acc0[r]));
            if m1 != 0 {
                let c1 = _mm512_maskz_loadu_ps(m1, crow.add(16));
                _mm512_mask_storeu_ps(crow.add(16), m1, _mm512_add_ps(c1, acc1[r]));
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn gemm(
        m: usize,
        n: usize,
        k: usize,
        a: StridedA<'_>,
        b: &[f32],
        ldb: usize,
        c: &mut [f32],
        ldc: usize,
    ) {
        // K is cut into panels of KC so that the B panel a column block sweeps (KC × 32
        // floats) stays in L1 while every row tile of C reuses it.
        let mut k0 = 0;
        while k0 < k {
            let kc = (k - k0).min(KC);
            gemm_panel(
                m,
                n,
                kc,
                a.data.as_ptr().add(k0 * a.cs),
                a.rs,
                a.cs,
                b.as_ptr().add(k0 * ldb),
                ldb,
                c.as_mut_ptr(),
                ldc,
            );
            k0 += kc;
        }
    }

    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn gemm_panel(
        m: usize,
        n: usize,
        k: usize,
        ap: *const f32,
        a_rs: usize,
        a_cs: usize,
        bp: *const f32,
        ldb: usize,
        cp: *mut f32,
        ldc: usize,
    ) {
        for_each_tile(m, n, |i0, j0, mr, m0, m1| {
            // SAFETY: the tile lies inside the operands the caller checked.
            unsafe {
                let (a_tile, b_tile, c_tile) = (ap.add(i0 * a_rs), bp.add(j0), cp.add(i0 * ldc + j0));
                by_rows!(mr, tile(k, a_tile, a_rs, a_cs, b_tile, ldb, c_tile, ldc, m0, m1));
            }
        });
    }

    /// [`super::gemm_set_bias`] for k ≤ [`KC`]: [`gemm`]'s tiles in one panel, each ending
    /// with C = bias + acc where [`gemm`] ends with C = C + acc on C holding the bias (the
    /// same operands of the same addition).
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn gemm_set_bias(
        m: usize,
        n: usize,
        k: usize,
        a: StridedA<'_>,
        b: &[f32],
        ldb: usize,
        bias: &[f32],
        c: &mut [f32],
        ldc: usize,
    ) {
        let (ap, bp, biasp, cp) = (a.data.as_ptr(), b.as_ptr(), bias.as_ptr(), c.as_mut_ptr());
        let (a_rs, a_cs) = (a.rs, a.cs);
        for_each_tile(m, n, |i0, j0, mr, m0, m1| {
            // SAFETY: the tile lies inside the operands the caller checked.
            unsafe {
                let (a_tile, b_tile, c_tile) = (ap.add(i0 * a_rs), bp.add(j0), cp.add(i0 * ldc + j0));
                let bias_tile = biasp.add(j0);
                by_rows!(
                    mr,
                    tile_set_bias(k, a_tile, a_rs, a_cs, b_tile, ldb, bias_tile, c_tile, ldc, m0, m1)
                );
            }
        });
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    unsafe fn tile_set_bias<const R: usize>(
        k: usize,
        a: *const f32,
        a_rs: usize,
        a_cs: usize,
        b: *const f32,
        ldb: usize,
        bias: *const f32,
        c: *mut f32,
        ldc: usize,
        m0: __mmask16,
        m1: __mmask16,
    ) {
        let (acc0, acc1) = accumulate::<R>(k, a, a_rs, a_cs, b, ldb, m0, m1);
        let bias0 = _mm512_maskz_loadu_ps(m0, bias);
        let bias1 = _mm512_maskz_loadu_ps(m1, bias.add(16));
        for r in 0..R {
            let crow = c.add(r * ldc);
            _mm512_mask_storeu_ps(crow, m0, _mm512_add_ps(bias0, acc0[r]));
            if m1 != 0 {
                _mm512_mask_storeu_ps(crow.add(16), m1, _mm512_add_ps(bias1, acc1[r]));
            }
        }
    }

    /// A tile's sums: `acc[r]` = Σ_k A[r][k] · B[k][..] by FMA in k order from zero.
    #[inline(always)]
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    unsafe fn accumulate<const R: usize>(
        k: usize,
        a: *const f32,
        a_rs: usize,
        a_cs: usize,
        b: *const f32,
        ldb: usize,
        m0: __mmask16,
        m1: __mmask16,
    ) -> ([__m512; R], [__m512; R]) {
        let mut acc0 = [_mm512_setzero_ps(); R];
        let mut acc1 = [_mm512_setzero_ps(); R];
        if m1 != 0 {
            for kk in 0..k {
                let brow = b.add(kk * ldb);
                let b0 = _mm512_maskz_loadu_ps(m0, brow);
                let b1 = _mm512_maskz_loadu_ps(m1, brow.add(16));
                let acol = a.add(kk * a_cs);
                for r in 0..R {
                    let av = _mm512_set1_ps(*acol.add(r * a_rs));
                    acc0[r] = _mm512_fmadd_ps(av, b0, acc0[r]);
                    acc1[r] = _mm512_fmadd_ps(av, b1, acc1[r]);
                }
            }
        } else {
            for kk in 0..k {
                let b0 = _mm512_maskz_loadu_ps(m0, b.add(kk * ldb));
                let acol = a.add(kk * a_cs);
                for r in 0..R {
                    let av = _mm512_set1_ps(*acol.add(r * a_rs));
                    acc0[r] = _mm512_fmadd_ps(av, b0, acc0[r]);
                }
            }
        }
        (acc0, acc1)
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    unsafe fn tile<const R: usize>(
        k: usize,
        a: *const f32,
        a_rs: usize,
        a_cs: usize,
        b: *const f32,
        ldb: usize,
        c: *mut f32,
        ldc: usize,
        m0: __mmask16,
        m1: __mmask16,
    ) {
        let (acc0, acc1) = accumulate::<R>(k, a, a_rs, a_cs, b, ldb, m0, m1);
        add_to_c(c, ldc, &acc0, &acc1, m0, m1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[allow(clippy::too_many_arguments)]
    fn naive(m: usize, n: usize, k: usize, a: StridedA<'_>, b: &[f32], ldb: usize, c: &mut [f32], ldc: usize) {
        for i in 0..m {
            for j in 0..n {
                let mut s = 0.0f64;
                for kk in 0..k {
                    s += a.data[i * a.rs + kk * a.cs] as f64 * b[kk * ldb + j] as f64;
                }
                c[i * ldc + j] += s as f32;
            }
        }
    }

    /// gemm_set_bias gives the bits of copying the bias into C and then gemm_acc: on this
    /// CPU's path (its own tiles on AVX-512), past one K panel, and with k = 0. (Without
    /// AVX-512 it is the copy and gemm_acc themselves.)
    #[test]
    fn set_bias_is_copy_then_gemm_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        {
            let portable = !super::super::simd::has_avx512();
            for &(m, n, k) in &[(16, 512, 5), (9, 33, 3), (1, 7, 1), (5, 40, 300), (3, 16, 0)] {
                let a: Vec<f32> = (0..m * k.max(1)).map(|_| rng.random_range(-1.0..1.0)).collect();
                let av = StridedA {
                    data: &a,
                    rs: k.max(1),
                    cs: 1,
                };
                let ldb = n + 2;
                let b: Vec<f32> = (0..k.max(1) * ldb).map(|_| rng.random_range(-1.0..1.0)).collect();
                let bias: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
                let ldc = n + 1;
                let c0: Vec<f32> = (0..m * ldc).map(|_| rng.random_range(-1.0..1.0)).collect();
                let mut want = c0.clone();
                for i in 0..m {
                    want[i * ldc..i * ldc + n].copy_from_slice(&bias);
                }
                gemm_acc(m, n, k, av, &b, ldb, &mut want, ldc);
                let mut got = c0.clone();
                gemm_set_bias(m, n, k, av, &b, ldb, &bias, &mut got, ldc);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got), bits(&want), "{m}×{n}×{k} portable {portable}");
            }
        }
    }

    #[test]
    fn matches_naive_on_odd_shapes_and_strides() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for &(m, n, k) in &[
            (1, 1, 1),
            (5, 7, 3),
            (8, 32, 16),
            (9, 33, 17),
            (16, 512, 128),
            (128, 5, 40),
            (3, 64, 1),
        ] {
            for transposed in [false, true] {
                let a: Vec<f32> = (0..m * k).map(|_| rng.random_range(-1.0..1.0)).collect();
                let (rs, cs) = if transposed { (1, m) } else { (k, 1) };
                let ldb = n + 3;
                let b: Vec<f32> = (0..k * ldb).map(|_| rng.random_range(-1.0..1.0)).collect();
                let ldc = n + 1;
                let c0: Vec<f32> = (0..m * ldc).map(|_| rng.random_range(-1.0..1.0)).collect();
                let av = StridedA { data: &a, rs, cs };
                let mut want = c0.clone();
                naive(m, n, k, av, &b, ldb, &mut want, ldc);
                let mut fast = c0.clone();
                gemm_acc(m, n, k, av, &b, ldb, &mut fast, ldc);
                let mut port = c0.clone();
                gemm_portable(m, n, k, av, &b, ldb, &mut port, ldc);
                #[cfg(feature = "faer")]
                let viafaer = {
                    let mut c = c0.clone();
                    gemm_acc_faer(m, n, k, av, &b, ldb, &mut c, ldc);
                    c
                };
                for i in 0..want.len() {
                    let tol = 1e-5 * (1.0 + k as f32).sqrt() * 4.0;
                    assert!((fast[i] - want[i]).abs() < tol, "{m}×{n}×{k} fast[{i}]");
                    assert!((port[i] - want[i]).abs() < tol, "{m}×{n}×{k} portable[{i}]");
                    #[cfg(feature = "faer")]
                    assert!((viafaer[i] - want[i]).abs() < tol, "{m}×{n}×{k} faer[{i}]");
                }
                // Padding columns of C (j ≥ n) are untouched.
                for i in 0..m {
                    assert_eq!(fast[i * ldc + n], c0[i * ldc + n]);
                }
            }
        }
    }
}
