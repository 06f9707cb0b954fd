//! Mixed-precision products for training: `C[m×n] += A·B` with A and B rounded to bfloat16
//! and every sum kept in f32 — what PyTorch's `autocast(bfloat16)` does for a matrix product.
//!
//! Why: the LSTM epoch is three products (h·W_hhᵀ, dg·W_hh, dW_hh) of ≈ 3.9·10¹¹
//! multiply-adds, and in f32 they alone hold it at ≈ 1.5 s on two cores running at the FMA
//! peak. AVX-512 BF16's `vdpbf16ps` does two multiply-adds per f32 lane per instruction, so
//! the same products take about half as long. Only training uses it, and only when asked
//! (`precision = "bf16"`); the master weights, Adam, the validation and everything exported
//! stay f32.
//!
//! Operands are packed as *pairs along k*: one `u32` holds `bf16(X[.., 2p])` in its low half
//! and `bf16(X[.., 2p + 1])` in its high half (the layout `vdpbf16ps` multiplies lane by
//! lane); an odd k is padded with a zero. B is packed `[k/2][n]` ([`pack_rows`]); A either
//! row-major `[m][k/2]` ([`pack_cols`], for an A stored row-major) or k-major `[k/2][m]`
//! ([`pack_rows`] again, for an A that is the transpose of a row-major matrix), so no pack
//! ever transposes. The portable path computes the same products (a bf16 × bf16 product is
//! exact in f32) summed pair by pair, so the two paths agree to f32 rounding, not bit for
//! bit.

use super::simd::simd_fn;
use bowden_fastmath::AVec;

/// f32 → bfloat16 bits, round to nearest, ties to even; a NaN stays a NaN (quieted); an f32
/// denormal becomes a zero of its sign. That is `vcvtneps2bf16`'s conversion exactly, so the
/// packing gives the same bits with the instruction ([`has_avx512_bf16`]) and without.
/// Branch-free, so the packing loops vectorise.
#[inline(always)]
pub fn to_bf16(x: f32) -> u16 {
    let bits = x.to_bits();
    let rounded = bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) >> 16;
    let quiet_nan = (bits >> 16) | 0x40;
    let signed_zero = (bits >> 16) & 0x8000;
    (if (bits & 0x7fff_ffff) > 0x7f80_0000 {
        quiet_nan
    } else if bits & 0x7f80_0000 == 0 {
        signed_zero
    } else {
        rounded
    }) as u16
}

/// bfloat16 bits → f32 (exact).
#[inline(always)]
pub fn from_bf16(b: u16) -> f32 {
    f32::from_bits((b as u32) << 16)
}

#[inline(always)]
fn pair(lo: f32, hi: f32) -> u32 {
    to_bf16(lo) as u32 | ((to_bf16(hi) as u32) << 16)
}

/// Pairs along k of a k-row count: `ceil(k / 2)`.
pub fn pairs(k: usize) -> usize {
    k.div_ceil(2)
}

simd_fn! {
    fn pair_rows_sw(lo: &[f32], hi: &[f32], out: &mut [u32]) {
        for ((o, l), h) in out.iter_mut().zip(lo).zip(hi) {
            *o = pair(*l, *h);
        }
    }
}

simd_fn! {
    fn pair_row_with_zero(lo: &[f32], out: &mut [u32]) {
        for (o, l) in out.iter_mut().zip(lo) {
            *o = to_bf16(*l) as u32;
        }
    }
}

simd_fn! {
    fn pair_consecutive_sw(src: &[f32], out: &mut [u32]) {
        for (o, v) in out.iter_mut().zip(src.chunks_exact(2)) {
            *o = pair(v[0], v[1]);
        }
    }
}

/// `out[j]` = pair(lo[j], hi[j]) over the shortest of the three.
fn pair_rows(lo: &[f32], hi: &[f32], out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx512_bf16() {
            let n = out.len().min(lo.len()).min(hi.len());
            // SAFETY: the CPU has AVX-512F and AVX-512 BF16 (checked); n bounds all three.
            let done = unsafe { convert::pair_rows(&lo[..n], &hi[..n], &mut out[..n]) };
            pair_rows_sw(&lo[done..n], &hi[done..n], &mut out[done..n]);
            return;
        }
    }
    pair_rows_sw(lo, hi, out);
}

/// `out[q]` = pair(src[2q], src[2q + 1]) over the shorter of `out` and `src`'s pairs.
fn pair_consecutive(src: &[f32], out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx512_bf16() {
            let n = out.len().min(src.len() / 2);
            // SAFETY: the CPU has AVX-512F and AVX-512 BF16 (checked); n bounds both.
            let done = unsafe { convert::pair_consecutive(&src[..2 * n], &mut out[..n]) };
            pair_consecutive_sw(&src[2 * done..2 * n], &mut out[done..n]);
            return;
        }
    }
    pair_consecutive_sw(src, out);
}

/// The packing's conversions with `vcvtneps2bf16` (the same rounding as [`to_bf16`]): a
/// third of the integer work of the rounding written out, which the packing spent once per
/// element per step.
#[cfg(target_arch = "x86_64")]
mod convert {
    use std::arch::x86_64::*;

    /// Whole blocks of 16 pairs; returns how many pairs were written.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub unsafe fn pair_rows(lo: &[f32], hi: &[f32], out: &mut [u32]) -> usize {
        let n = out.len() / 16 * 16;
        for q in (0..n).step_by(16) {
            // SAFETY: q + 16 ≤ n ≤ every slice's length.
            unsafe {
                let l: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(_mm512_loadu_ps(lo.as_ptr().add(q))));
                let h: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(_mm512_loadu_ps(hi.as_ptr().add(q))));
                let v = _mm512_or_si512(
                    _mm512_cvtepu16_epi32(l),
                    _mm512_slli_epi32::<16>(_mm512_cvtepu16_epi32(h)),
                );
                _mm512_storeu_si512(out.as_mut_ptr().add(q) as *mut __m512i, v);
            }
        }
        n
    }

    /// Whole blocks of 16 pairs (32 values); returns how many pairs were written. A pair of
    /// consecutive values is their two bf16 in memory order, so the conversion is stored as it
    /// comes.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub unsafe fn pair_consecutive(src: &[f32], out: &mut [u32]) -> usize {
        let n = out.len() / 16 * 16;
        for q in (0..n).step_by(16) {
            // SAFETY: 2q + 32 ≤ 2n ≤ src.len() and q + 16 ≤ out.len().
            unsafe {
                let a = _mm512_loadu_ps(src.as_ptr().add(2 * q));
                let b = _mm512_loadu_ps(src.as_ptr().add(2 * q + 16));
                // Words 0..16 from the second operand, 16..32 from the first.
                let v: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(b, a));
                _mm512_storeu_si512(out.as_mut_ptr().add(q) as *mut __m512i, v);
            }
        }
        n
    }
}

/// Packs the `k` rows of a row-major matrix (`n` columns, leading dimension `ld`) as
/// `[pairs(k)][n]`: element `(p, j)` pairs rows 2p and 2p + 1 of column j. This is B's
/// packing, and k-major A's when A = Xᵀ (then `n` = A's m).
pub fn pack_rows(k: usize, n: usize, x: &[f32], ld: usize, out: &mut AVec<u32>) {
    out.resize(pairs(k) * n, 0);
    pack_rows_into(k, n, x, ld, out);
}

/// [`pack_rows`] into the first `pairs(k) · n` elements of `out` (which must hold them):
/// packing a matrix a block of rows at a time, each block written where the whole
/// matrix's packing would put it, gives the same elements when every block but the last
/// has an even number of rows.
pub fn pack_rows_into(k: usize, n: usize, x: &[f32], ld: usize, out: &mut [u32]) {
    pack_rows_into_ld(k, n, x, ld, out, n);
}

/// [`pack_rows_into`] with pair-row `p` at `out[p · ldo ..]` (`ldo` ≥ `n`): a k-major A
/// operand whose pair rows are a power of two apart (2 KiB for 4H = 512 gates) puts every
/// pair row's line in the same few L1 sets, and a tile's walk down k evicts its own lines.
pub fn pack_rows_into_ld(k: usize, n: usize, x: &[f32], ld: usize, out: &mut [u32], ldo: usize) {
    assert!(ldo >= n, "pack_rows_into_ld: ldo {ldo} < n {n}");
    let kp = pairs(k);
    for p in 0..kp {
        let lo = &x[2 * p * ld..2 * p * ld + n];
        let dst = &mut out[p * ldo..p * ldo + n];
        if 2 * p + 1 < k {
            pair_rows(lo, &x[(2 * p + 1) * ld..(2 * p + 1) * ld + n], dst);
        } else {
            pair_row_with_zero(lo, dst);
        }
    }
}

/// Packs Xᵀ as B for a row-major X (`rows × k`, contiguous): element `(p, r)` of the
/// `[pairs(k)][rows]` result pairs X[r][2p] and X[r][2p + 1], so it equals [`pack_rows`] of
/// the transposed copy of X, element for element, without making that copy.
pub fn pack_transposed(rows: usize, k: usize, x: &[f32], out: &mut AVec<u32>) {
    const BS: usize = 16;
    let kp = pairs(k);
    out.resize(kp * rows, 0);
    let mut block = [0u32; 64 * BS];
    if kp > 64 {
        // Wider rows than the block holds: element by element.
        for r in 0..rows {
            for p in 0..kp {
                let lo = x[r * k + 2 * p];
                out[p * rows + r] = if 2 * p + 1 < k {
                    pair(lo, x[r * k + 2 * p + 1])
                } else {
                    to_bf16(lo) as u32
                };
            }
        }
        return;
    }
    // 16 rows at a time: pair each row (contiguous, vectorised), then write the block out a
    // pair-row at a time (16 consecutive u32 per pair index).
    for r0 in (0..rows).step_by(BS) {
        let nr = (rows - r0).min(BS);
        for i in 0..nr {
            let src = &x[(r0 + i) * k..(r0 + i + 1) * k];
            let dst = &mut block[i * kp..(i + 1) * kp];
            pair_consecutive(src, dst);
            if k % 2 == 1 {
                dst[kp - 1] = to_bf16(src[k - 1]) as u32;
            }
        }
        for p in 0..kp {
            let row = &mut out[p * rows + r0..p * rows + r0 + nr];
            for (i, o) in row.iter_mut().enumerate() {
                *o = block[i * kp + p];
            }
        }
    }
}

/// Packs a row-major A (`m × k`, leading dimension `ld`) as `[m][pairs(k)]`.
pub fn pack_cols(m: usize, k: usize, a: &[f32], ld: usize, out: &mut AVec<u32>) {
    let kp = pairs(k);
    out.resize(m * kp, 0);
    for i in 0..m {
        let src = &a[i * ld..i * ld + k];
        let dst = &mut out[i * kp..(i + 1) * kp];
        pair_consecutive(src, dst);
        if k % 2 == 1 {
            dst[kp - 1] = to_bf16(src[k - 1]) as u32;
        }
    }
}

/// A packed A operand: pair `p` of row `i` is `data[i * rs + p * ps]` (row-major from
/// [`pack_cols`]: rs = pairs(k), ps = 1; k-major from [`pack_rows`]: rs = 1, ps = m).
#[derive(Clone, Copy)]
pub struct PackedA<'a> {
    pub data: &'a [u32],
    pub rs: usize,
    pub ps: usize,
}

/// True when the CPU has AVX-512 BF16 (and the AVX-512 kernels are in use).
pub fn has_avx512_bf16() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        super::simd::has_avx512() && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `C[m×n] += A·B` from packed operands over `kp` pairs: `a` as [`PackedA`], `b` is
/// `[kp][n]` ([`pack_rows`]), `C[i, j] = c[i * ldc + j]`.
///
/// Panics if a slice is too short for the given shape (a caller bug, never data).
pub fn gemm_bf16_acc(m: usize, n: usize, kp: usize, a: PackedA<'_>, b: &[u32], c: &mut [f32], ldc: usize) {
    if m == 0 || n == 0 || kp == 0 {
        return;
    }
    assert!(
        (m - 1) * a.rs + (kp - 1) * a.ps < a.data.len()
            && b.len() >= kp * n
            && c.len() > (m - 1) * ldc + n - 1
            && n <= ldc,
        "bf16 gemm {m}×{n}×{kp} pairs: operand too short (A {}, B {}, C {})",
        a.data.len(),
        b.len(),
        c.len()
    );
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx512_bf16() {
            // SAFETY: the CPU has AVX-512F and AVX-512 BF16 (checked); every access is
            // within the slices (checked above for the extreme indices of each operand).
            unsafe { avx512::gemm(m, n, kp, a, b, c, ldc) };
            return;
        }
    }
    gemm_bf16_portable(m, n, kp, a, b, c, ldc);
}

/// The same products without the instruction: each pair's two products (exact in f32) added
/// to the running sum in turn.
pub fn gemm_bf16_portable(m: usize, n: usize, kp: usize, a: PackedA<'_>, b: &[u32], c: &mut [f32], ldc: usize) {
    for i in 0..m {
        let crow = &mut c[i * ldc..i * ldc + n];
        for p in 0..kp {
            let av = a.data[i * a.rs + p * a.ps];
            let (a0, a1) = (from_bf16(av as u16), from_bf16((av >> 16) as u16));
            let brow = &b[p * n..(p + 1) * n];
            for (cv, bv) in crow.iter_mut().zip(brow) {
                let (b0, b1) = (from_bf16(*bv as u16), from_bf16((*bv >> 16) as u16));
                *cv += a0 * b0 + a1 * b1;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use crate::kernels::gemm::avx512::{add_to_c, by_rows, for_each_tile};
    use std::arch::x86_64::*;

    #[target_feature(enable = "avx512f,avx512bf16")]
    pub unsafe fn gemm(m: usize, n: usize, kp: usize, a: super::PackedA<'_>, b: &[u32], c: &mut [f32], ldc: usize) {
        let (ap, bp, cp) = (a.data.as_ptr(), b.as_ptr(), c.as_mut_ptr());
        let (rs, ps) = (a.rs, a.ps);
        for_each_tile(m, n, |i0, j0, mr, m0, m1| {
            // SAFETY: the tile lies inside the operands the caller checked.
            unsafe {
                let (a_tile, b_tile, c_tile) = (ap.add(i0 * rs), bp.add(j0), cp.add(i0 * ldc + j0));
                by_rows!(mr, tile(kp, n, a_tile, rs, ps, b_tile, c_tile, ldc, m0, m1));
            }
        });
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    unsafe fn tile<const R: usize>(
        kp: usize,
        ldb: usize,
        a: *const u32,
        rs: usize,
        ps: usize,
        b: *const u32,
        c: *mut f32,
        ldc: usize,
        m0: __mmask16,
        m1: __mmask16,
    ) {
        let mut acc0 = [_mm512_setzero_ps(); R];
        let mut acc1 = [_mm512_setzero_ps(); R];
        if m1 != 0 {
            for p in 0..kp {
                let brow = b.add(p * ldb) as *const i32;
                let b0: __m512bh = std::mem::transmute(_mm512_maskz_loadu_epi32(m0, brow));
                let b1: __m512bh = std::mem::transmute(_mm512_maskz_loadu_epi32(m1, brow.add(16)));
                for r in 0..R {
                    let av: __m512bh = std::mem::transmute(_mm512_set1_epi32(*a.add(r * rs + p * ps) as i32));
                    acc0[r] = _mm512_dpbf16_ps(acc0[r], av, b0);
                    acc1[r] = _mm512_dpbf16_ps(acc1[r], av, b1);
                }
            }
        } else {
            for p in 0..kp {
                let b0: __m512bh = std::mem::transmute(_mm512_maskz_loadu_epi32(m0, b.add(p * ldb) as *const i32));
                for r in 0..R {
                    let av: __m512bh = std::mem::transmute(_mm512_set1_epi32(*a.add(r * rs + p * ps) as i32));
                    acc0[r] = _mm512_dpbf16_ps(acc0[r], av, b0);
                }
            }
        }
        add_to_c(c, ldc, &acc0, &acc1, m0, m1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn rounding_is_to_nearest_even() {
        assert_eq!(from_bf16(to_bf16(1.0)), 1.0);
        // 1 + 2⁻⁸ is halfway between 1 and 1 + 2⁻⁷: ties to the even mantissa (1.0).
        assert_eq!(from_bf16(to_bf16(1.0 + 1.0 / 256.0)), 1.0);
        // 1 + 3·2⁻⁸ is halfway between 1 + 2⁻⁷ and 1 + 2⁻⁶: ties up to the even one.
        assert_eq!(from_bf16(to_bf16(1.0 + 3.0 / 256.0)), 1.0 + 4.0 / 256.0);
        assert_eq!(from_bf16(to_bf16(-2.5)), -2.5);
        assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
        let x = 0.123_456_79f32;
        assert!((from_bf16(to_bf16(x)) - x).abs() <= x * 2f32.powi(-9));
    }

    /// The instruction's conversion and the written-out one agree bit for bit, on random
    /// values and on ties, NaNs, infinities, zeros and denormals (which become signed zeros).
    #[test]
    fn packing_converts_like_to_bf16_on_every_path() {
        assert_eq!(to_bf16(f32::from_bits(0x0000_0001)), 0);
        assert_eq!(to_bf16(-f32::from_bits(0x007f_ffff)), 0x8000);
        assert_eq!(to_bf16(f32::MIN_POSITIVE), 0x0080);
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let special = [
            0.0f32,
            -0.0,
            1.0 + 1.0 / 256.0,
            1.0 + 3.0 / 256.0,
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0x7f80_0001),
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::from_bits(0x0000_0001),
            f32::from_bits(0x807f_ffff),
            f32::MIN_POSITIVE,
        ];
        let x: Vec<f32> = (0..203)
            .map(|i| {
                if i % 7 == 0 {
                    special[(i / 7) % special.len()]
                } else {
                    f32::from_bits(rng.random::<u32>())
                }
            })
            .collect();
        let want_pairs: Vec<u32> = x.chunks_exact(2).map(|v| pair(v[0], v[1])).collect();
        let mut got = vec![0u32; want_pairs.len()];
        pair_consecutive(&x, &mut got);
        assert_eq!(got, want_pairs);
        let (lo, hi) = x.split_at(101);
        let want_rows: Vec<u32> = lo.iter().zip(hi).map(|(l, h)| pair(*l, *h)).collect();
        let mut got = vec![0u32; 101];
        pair_rows(lo, &hi[..101], &mut got);
        assert_eq!(got, want_rows);
        eprintln!("AVX-512 BF16 conversion in use: {}", has_avx512_bf16());
    }

    /// A padded leading dimension moves each pair row and nothing else: the elements are
    /// [`pack_rows`]'s, the padding is left as it was, and the product reads the same sums.
    #[test]
    fn padded_pair_rows_hold_pack_rows_elements_and_give_the_same_product() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for &(k, n, pad) in &[(32usize, 512usize, 32usize), (9, 40, 16), (1, 7, 1)] {
            let x: Vec<f32> = (0..k * n).map(|_| rng.random_range(-3.0..3.0)).collect();
            let mut want = AVec::new();
            pack_rows(k, n, &x, n, &mut want);
            let ldo = n + pad;
            let mut got = vec![0xdead_beefu32; pairs(k) * ldo];
            pack_rows_into_ld(k, n, &x, n, &mut got, ldo);
            for p in 0..pairs(k) {
                assert_eq!(
                    &got[p * ldo..p * ldo + n],
                    &want[p * n..(p + 1) * n],
                    "k {k} n {n} pair {p}"
                );
                assert!(got[p * ldo + n..(p + 1) * ldo].iter().all(|&v| v == 0xdead_beef));
            }
            // As a k-major A (m = n rows of C) against a B of 24 columns.
            let bm: Vec<f32> = (0..k * 24).map(|_| rng.random_range(-3.0..3.0)).collect();
            let mut bp = AVec::new();
            pack_rows(k, 24, &bm, 24, &mut bp);
            let (mut c0, mut c1) = (vec![0.0f32; n * 24], vec![0.0f32; n * 24]);
            let a0 = PackedA {
                data: &want,
                rs: 1,
                ps: n,
            };
            let a1 = PackedA {
                data: &got,
                rs: 1,
                ps: ldo,
            };
            gemm_bf16_acc(n, 24, pairs(k), a0, &bp, &mut c0, 24);
            gemm_bf16_acc(n, 24, pairs(k), a1, &bp, &mut c1, 24);
            assert_eq!(
                c0.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                c1.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
        }
    }

    /// Packing Xᵀ straight from X gives the elements of [`pack_rows`] on a transposed copy,
    /// on the block path (k ≤ 128), the element-wise path (k > 128), odd k and a partial
    /// block of rows.
    #[test]
    fn pack_transposed_equals_packing_a_transposed_copy() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for &(rows, k) in &[(512, 128), (37, 9), (16, 1), (5, 131), (40, 200)] {
            let x: Vec<f32> = (0..rows * k).map(|_| rng.random_range(-3.0..3.0)).collect();
            let mut xt = vec![0.0f32; rows * k];
            for r in 0..rows {
                for c in 0..k {
                    xt[c * rows + r] = x[r * k + c];
                }
            }
            let (mut want, mut got) = (AVec::new(), AVec::new());
            pack_rows(k, rows, &xt, rows, &mut want);
            pack_transposed(rows, k, &x, &mut got);
            assert_eq!(got, want, "{rows} rows × k = {k}");
        }
    }

    /// Both paths, with A packed row-major and k-major, against the f64 product of the
    /// *rounded* operands (so the only difference is f32 summation), and against the
    /// unrounded product within bf16's precision.
    #[test]
    fn packed_products_match_the_rounded_operands_on_odd_shapes() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for &(m, n, k) in &[
            (1, 1, 1),
            (5, 7, 3),
            (8, 32, 16),
            (9, 33, 17),
            (16, 512, 128),
            (16, 128, 512),
            (3, 64, 1),
        ] {
            for k_major in [false, true] {
                // A row-major `[m][k]`, or A = Xᵀ with X row-major `[k][m]`.
                let x: Vec<f32> = (0..m * k).map(|_| rng.random_range(-1.0..1.0)).collect();
                let a_at = |i: usize, kk: usize| if k_major { x[kk * m + i] } else { x[i * k + kk] };
                let ldb = n + 3;
                let b: Vec<f32> = (0..k * ldb).map(|_| rng.random_range(-1.0..1.0)).collect();
                let ldc = n + 1;
                let c0: Vec<f32> = (0..m * ldc).map(|_| rng.random_range(-1.0..1.0)).collect();
                let (mut pa, mut pb) = (AVec::new(), AVec::new());
                let kp = pairs(k);
                let (rs, ps) = if k_major {
                    pack_rows(k, m, &x, m, &mut pa);
                    (1, m)
                } else {
                    pack_cols(m, k, &x, k, &mut pa);
                    (kp, 1)
                };
                let av = PackedA { data: &pa, rs, ps };
                pack_rows(k, n, &b, ldb, &mut pb);
                let mut fast = c0.clone();
                gemm_bf16_acc(m, n, kp, av, &pb, &mut fast, ldc);
                let mut port = c0.clone();
                gemm_bf16_portable(m, n, kp, av, &pb, &mut port, ldc);
                for i in 0..m {
                    for j in 0..n {
                        let (mut rounded, mut exact) = (c0[i * ldc + j] as f64, c0[i * ldc + j] as f64);
                        for kk in 0..k {
                            let (av, bv) = (a_at(i, kk), b[kk * ldb + j]);
                            rounded += from_bf16(to_bf16(av)) as f64 * from_bf16(to_bf16(bv)) as f64;
                            exact += av as f64 * bv as f64;
                        }
                        let tol = 1e-5 * (1.0 + k as f64).sqrt() * 4.0;
                        let idx = i * ldc + j;
                        assert!((fast[idx] as f64 - rounded).abs() < tol, "{m}×{n}×{k} fast[{i},{j}]");
                        assert!(
                            (port[idx] as f64 - rounded).abs() < tol,
                            "{m}×{n}×{k} portable[{i},{j}]"
                        );
                        // Each operand is within 2⁻⁹ relative of its value: each product
                        // within ≈ 2⁻⁸ of its magnitude (≤ 1 here).
                        assert!((fast[idx] as f64 - exact).abs() < 4e-3 * k as f64 + tol);
                    }
                    // Padding columns of C (j ≥ n) are untouched.
                    assert_eq!(fast[i * ldc + n], c0[i * ldc + n]);
                }
            }
        }
    }
}
