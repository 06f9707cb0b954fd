//! A single-layer LSTM (PyTorch semantics: gates i, f, g, o; h₀ = c₀ = 0), forward and
//! backward through time, batched: every step is one GEMM of the batch's hidden states
//! against the recurrent weights plus one fused elementwise cell; the weight gradients of
//! all steps are one GEMM each after the backward sweep.

use super::bf16::{
    gemm_bf16_acc, pack_cols, pack_rows, pack_rows_into, pack_rows_into_ld, pack_transposed, pairs, PackedA,
};
use super::gemm::{gemm_acc, gemm_set_bias, StridedA};
use super::simd::{sigmoid_f32, simd_fn, tanh_f32};
use bowden_fastmath::AVec;

/// Shapes: batch rows `b`, steps `t`, input `j`, hidden `h`.
#[derive(Debug, Clone, Copy)]
pub struct LstmDims {
    pub t: usize,
    pub j: usize,
    pub h: usize,
}

/// Offsets of the LSTM tensors in the flat parameter vector.
#[derive(Debug, Clone, Copy)]
pub struct LstmParamIdx {
    pub w_ih: usize,
    pub w_hh: usize,
    pub b_ih: usize,
    pub b_hh: usize,
}

/// Per-thread buffers for `cap` batch rows.
#[derive(Debug, Clone)]
pub struct LstmWork {
    pub cap: usize,
    /// Inputs, `[T][b][J]`.
    pub xt: AVec<f32>,
    /// Gate activations i, f, g, o after their nonlinearity, `[T][b][4H]`.
    g: AVec<f32>,
    /// Cell states c_t, `[T][b][H]`.
    cs: AVec<f32>,
    /// tanh(c_t), `[T][b][H]`.
    tc: AVec<f32>,
    /// Hidden states, `[T+1][b][H]`, `hs[0] = 0`, `hs[t+1] = h_t`.
    pub hs: AVec<f32>,
    /// Pre-activation gate gradients, `[T][b][4H]`.
    dg: AVec<f32>,
    dh: AVec<f32>,
    dc: AVec<f32>,
    /// Input gradients, `[T][b][J]`.
    pub dxt: AVec<f32>,
    dwt: AVec<f32>,
    colsum: AVec<f32>,
    zeros: AVec<f32>,
    /// Mixed precision only: the A and B operands of one product packed as bf16 pairs
    /// (sized on first use, then reused).
    pack_a: AVec<u32>,
    pack_b: AVec<u32>,
    /// Mixed precision only: dg[1..T] packed for dW_hh step by step during the backward
    /// sweep (while each step's rows are in L1), instead of in one pass afterwards.
    pack_dg: AVec<u32>,
    /// Mixed precision, even b: whether the last forward pass already packed h_0..h_{T−2} into
    /// `pack_b` (dW_hh's B operand) step by step, while each h_t was in L1.
    hs_packed: bool,
}

impl LstmWork {
    pub fn new(d: &LstmDims, cap: usize) -> Self {
        let (t, j, h) = (d.t, d.j, d.h);
        Self {
            cap,
            xt: AVec::from_elem(0.0, t * cap * j),
            g: AVec::from_elem(0.0, t * cap * 4 * h),
            cs: AVec::from_elem(0.0, t * cap * h),
            tc: AVec::from_elem(0.0, t * cap * h),
            hs: AVec::from_elem(0.0, (t + 1) * cap * h),
            dg: AVec::from_elem(0.0, t * cap * 4 * h),
            dh: AVec::from_elem(0.0, cap * h),
            dc: AVec::from_elem(0.0, cap * h),
            dxt: AVec::from_elem(0.0, t * cap * j),
            dwt: AVec::from_elem(0.0, j * 4 * h),
            colsum: AVec::from_elem(0.0, 4 * h),
            zeros: AVec::from_elem(0.0, cap * h),
            pack_a: AVec::new(),
            pack_b: AVec::new(),
            pack_dg: AVec::new(),
            hs_packed: false,
        }
    }

    /// h_T of the last forward pass, `[b][H]`.
    pub fn h_last(&self, d: &LstmDims, b: usize) -> &[f32] {
        &self.hs[d.t * b * d.h..(d.t + 1) * b * d.h]
    }
}

/// Transposed copies of the weights the GEMMs want row-major in the other orientation,
/// refreshed once per optimiser step and shared by all threads.
#[derive(Debug, Clone, Default)]
pub struct LstmPrepared {
    /// W_ihᵀ, `[J][4H]`.
    pub wt_ih: AVec<f32>,
    /// W_hhᵀ, `[H][4H]`.
    pub rt: AVec<f32>,
    /// b_ih + b_hh, `[4H]`.
    pub bias: AVec<f32>,
    /// Mixed precision: W_hhᵀ and W_hh as the B operands of the recurrent products, packed
    /// as bf16 pairs ([`super::bf16`]); empty in f32.
    pub rt_bf16: AVec<u32>,
    pub r_bf16: AVec<u32>,
    /// Whether `rt` matches the weights (see [`LstmPrepared::prepare_for_mixed_step`]).
    pub rt_fresh: bool,
}

/// `dst` (`[cols][rows]`) = `src` (`[rows][cols]`)ᵀ.
pub fn transpose(src: &[f32], rows: usize, cols: usize, dst: &mut AVec<f32>) {
    // In 16 × 16 blocks: row by row, the writes run down a column of `dst` with a stride of
    // `rows` floats (2 KiB for W_hh), whose lines all fall in the same few L1 sets and evict
    // each other before the next row fills them.
    const BS: usize = 16;
    dst.resize(rows * cols, 0.0);
    for r0 in (0..rows).step_by(BS) {
        for c0 in (0..cols).step_by(BS) {
            for r in r0..(r0 + BS).min(rows) {
                for c in c0..(c0 + BS).min(cols) {
                    dst[c * rows + r] = src[r * cols + c];
                }
            }
        }
    }
}

impl LstmPrepared {
    /// Refreshes the copies from `params`; `mixed` also packs the bf16 operands.
    pub fn prepare(&mut self, d: &LstmDims, params: &[f32], idx: &LstmParamIdx, mixed: bool) {
        self.prepare_inner(d, params, idx, mixed, true);
    }

    /// What a mixed-precision training step needs: as [`LstmPrepared::prepare`] without the
    /// f32 W_hhᵀ, which only an f32 forward pass (validation) reads and which the step would
    /// otherwise transpose for nothing after every optimiser step (it ran serially, with the
    /// helper thread waiting). An f32 forward pass on these copies panics (a caller bug):
    /// prepare them in full first.
    pub fn prepare_for_mixed_step(&mut self, d: &LstmDims, params: &[f32], idx: &LstmParamIdx) {
        self.prepare_inner(d, params, idx, true, false);
    }

    fn prepare_inner(&mut self, d: &LstmDims, params: &[f32], idx: &LstmParamIdx, mixed: bool, f32_rt: bool) {
        let g = 4 * d.h;
        let w_hh = &params[idx.w_hh..idx.w_hh + g * d.h];
        transpose(&params[idx.w_ih..idx.w_ih + g * d.j], g, d.j, &mut self.wt_ih);
        if f32_rt {
            transpose(w_hh, g, d.h, &mut self.rt);
        }
        self.rt_fresh = f32_rt;
        self.bias.resize(g, 0.0);
        for i in 0..g {
            self.bias[i] = params[idx.b_ih + i] + params[idx.b_hh + i];
        }
        if mixed {
            pack_transposed(g, d.h, w_hh, &mut self.rt_bf16);
            pack_rows(g, d.h, w_hh, d.h, &mut self.r_bf16);
        } else {
            self.rt_bf16.clear();
            self.r_bf16.clear();
        }
    }
}

simd_fn! {
    /// One cell step for `b` rows: gates (pre-activations in, activations out), c, tanh c, h.
    /// Written as slice iterators so the compiler sees no bounds checks and vectorises.
    fn cell_fwd(g: &mut [f32], c_prev: &[f32], c: &mut [f32], tc: &mut [f32], h_out: &mut [f32], b: usize, hd: usize) {
        for r in 0..b {
            let gr = &mut g[r * 4 * hd..(r + 1) * 4 * hd];
            let (ifg, go) = gr.split_at_mut(3 * hd);
            let (i_f, gg) = ifg.split_at_mut(2 * hd);
            for v in i_f.iter_mut() {
                *v = sigmoid_f32(*v);
            }
            for v in gg.iter_mut() {
                *v = tanh_f32(*v);
            }
            for v in go.iter_mut() {
                *v = sigmoid_f32(*v);
            }
            let (gi, gf) = i_f.split_at(hd);
            let cp = &c_prev[r * hd..(r + 1) * hd];
            let cr = &mut c[r * hd..(r + 1) * hd];
            let tr = &mut tc[r * hd..(r + 1) * hd];
            let hr = &mut h_out[r * hd..(r + 1) * hd];
            for (((((((i, f), gv), o), cpv), cv), tv), hv) in gi
                .iter()
                .zip(gf.iter())
                .zip(gg.iter())
                .zip(go.iter())
                .zip(cp.iter())
                .zip(cr.iter_mut())
                .zip(tr.iter_mut())
                .zip(hr.iter_mut())
            {
                let cn = f * cpv + i * gv;
                let t = tanh_f32(cn);
                *cv = cn;
                *tv = t;
                *hv = o * t;
            }
        }
    }
}

simd_fn! {
    /// One cell step backward: dh (in), dc (in/out: carried to t−1), dg (pre-activation
    /// gate gradients out).
    fn cell_bwd(g: &[f32], tc: &[f32], c_prev: &[f32], dh: &[f32], dc: &mut [f32], dg: &mut [f32], b: usize, hd: usize) {
        for r in 0..b {
            let gr = &g[r * 4 * hd..(r + 1) * 4 * hd];
            let (gi, rest) = gr.split_at(hd);
            let (gf, rest) = rest.split_at(hd);
            let (gg, go) = rest.split_at(hd);
            let dgr = &mut dg[r * 4 * hd..(r + 1) * 4 * hd];
            let (dgi, rest) = dgr.split_at_mut(hd);
            let (dgf, rest) = rest.split_at_mut(hd);
            let (dgg, dgo) = rest.split_at_mut(hd);
            let tr = &tc[r * hd..(r + 1) * hd];
            let cp = &c_prev[r * hd..(r + 1) * hd];
            let dhr = &dh[r * hd..(r + 1) * hd];
            let dcr = &mut dc[r * hd..(r + 1) * hd];
            for u in 0..hd.min(go.len()).min(dgo.len()) {
                let i = gi[u];
                let f = gf[u];
                let gv = gg[u];
                let o = go[u];
                let t = tr[u];
                let dhv = dhr[u];
                let dcv = dcr[u] + dhv * o * (1.0 - t * t);
                dgi[u] = dcv * gv * i * (1.0 - i);
                dgf[u] = dcv * cp[u] * f * (1.0 - f);
                dgg[u] = dcv * i * (1.0 - gv * gv);
                dgo[u] = dhv * t * o * (1.0 - o);
                dcr[u] = dcv * f;
            }
        }
    }
}

/// Forward over `b` rows whose inputs are already in `work.xt` (`[T][b][J]`). `mixed`: the
/// recurrent products in bf16 with f32 sums (`prep` must have been prepared with it).
pub fn forward(d: &LstmDims, prep: &LstmPrepared, b: usize, work: &mut LstmWork, mixed: bool) {
    let (t, j, h) = (d.t, d.j, d.h);
    let g4 = 4 * h;
    work.hs[..b * h].fill(0.0);
    // dW_hh's B operand is h_0..h_{T−2} packed as bf16 row pairs; with b even no pair straddles
    // two steps, so each step's rows are packed here, right after the cell wrote them, into the
    // place the backward pass's one packing of all of them would put them: the same elements.
    let pack_hs = mixed && b.is_multiple_of(2) && t > 1;
    work.hs_packed = pack_hs;
    if pack_hs {
        work.pack_b.resize(pairs((t - 1) * b) * h, 0);
    }
    for step in 0..t {
        let gs = &mut work.g[step * b * g4..(step + 1) * b * g4];
        // The bias and the input projection step by step, not for all T steps up front: a
        // step's gates (b × 4H floats) then stay in L1 from here to the cell, where the whole
        // `[T][b][4H]` buffer (2.6 MB for a shard of 16) would be written twice through the
        // caches first. Each element sums the same terms in the same order either way (a
        // GEMM's element does not depend on how many rows share its call): the same bits.
        gemm_set_bias(
            b,
            g4,
            j,
            StridedA {
                data: &work.xt[step * b * j..(step + 1) * b * j],
                rs: j,
                cs: 1,
            },
            &prep.wt_ih,
            g4,
            &prep.bias,
            gs,
            g4,
        );
        if step > 0 && mixed {
            pack_cols(b, h, &work.hs[step * b * h..(step + 1) * b * h], h, &mut work.pack_a);
            let a = PackedA {
                data: &work.pack_a,
                rs: pairs(h),
                ps: 1,
            };
            gemm_bf16_acc(b, g4, pairs(h), a, &prep.rt_bf16, gs, g4);
        } else if step > 0 {
            assert!(
                prep.rt_fresh,
                "an f32 LSTM pass on weights prepared for a mixed step only"
            );
            gemm_acc(
                b,
                g4,
                h,
                StridedA {
                    data: &work.hs[step * b * h..(step + 1) * b * h],
                    rs: h,
                    cs: 1,
                },
                &prep.rt,
                g4,
                gs,
                g4,
            );
        }
        // cs[step] is written while cs[step−1] is read: split the buffer.
        let (cs_lo, cs_hi) = work.cs.split_at_mut(step * b * h);
        let c_prev: &[f32] = if step == 0 {
            &work.zeros[..b * h]
        } else {
            &cs_lo[(step - 1) * b * h..]
        };
        let (c_out, tc_out, h_out) = (
            &mut cs_hi[..b * h],
            &mut work.tc[step * b * h..(step + 1) * b * h],
            &mut work.hs[(step + 1) * b * h..(step + 2) * b * h],
        );
        if !(mixed && mixed_cell::forward(gs, c_prev, c_out, tc_out, h_out, b, h)) {
            cell_fwd(gs, c_prev, c_out, tc_out, h_out, b, h);
        }
        if pack_hs && step + 1 < t {
            // h_out is h_step: rows step·b.. of the operand, pair rows step·b/2..
            let at = step * (b / 2) * h;
            pack_rows_into(b, h, h_out, h, &mut work.pack_b[at..at + (b / 2) * h]);
        }
    }
}

/// The cell of mixed-precision training, with the gate activations in AVX-512 FMA and the
/// hardware reciprocal.
///
/// Why: in an f32 cell the activations are [`bowden_fastmath`]'s, the very functions the
/// real-time evaluators run, built without FMA and with a true division so that every CPU
/// gives the same bits; on the bf16 epoch that cell was 12 % of the CPU time, the division
/// and the unfused polynomial most of it. Mixed precision already trains through products
/// whose operands are rounded to 8 bits, so its activations need not be bit-exact: here
/// e^x is the same Cody–Waite reduction and Cephes polynomial in fused multiply-adds with
/// `vscalefps` for 2ⁿ, and 1 / (1 + e^−x) is `vrcp14ps` refined by one Newton step (≈ 2⁻²⁷
/// relative). Test: `mixed_cell_matches_the_shared_activations` (within 4e-7 of the f32
/// cell). The exported model and validation run the f32 cell as before.
mod mixed_cell {
    /// Runs the cell if the CPU has AVX-512 and `hd` is a multiple of 16; returns false
    /// (having done nothing) otherwise.
    pub fn forward(
        g: &mut [f32],
        c_prev: &[f32],
        c: &mut [f32],
        tc: &mut [f32],
        h_out: &mut [f32],
        b: usize,
        hd: usize,
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if hd.is_multiple_of(16) && super::super::simd::has_avx512() {
                assert!(g.len() >= b * 4 * hd && c_prev.len() >= b * hd && c.len() >= b * hd);
                assert!(tc.len() >= b * hd && h_out.len() >= b * hd);
                // SAFETY: the CPU has AVX-512F (checked); every access is within the slices
                // (lengths checked above, hd a multiple of the 16 lanes).
                unsafe { avx512::forward(g, c_prev, c, tc, h_out, b, hd) };
                return true;
            }
        }
        let _ = (g, c_prev, c, tc, h_out, b, hd);
        false
    }

    #[cfg(target_arch = "x86_64")]
    mod avx512 {
        use std::arch::x86_64::*;

        #[inline(always)]
        unsafe fn exp(x: __m512) -> __m512 {
            // NaN stays NaN: `max`/`min` return their second operand when one is NaN.
            let x = _mm512_min_ps(_mm512_set1_ps(88.0), _mm512_max_ps(_mm512_set1_ps(-87.0), x));
            let n = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(_mm512_mul_ps(
                x,
                _mm512_set1_ps(std::f32::consts::LOG2_E),
            ));
            let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(0.693_359_4), x);
            let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(-2.121_944_4e-4), r);
            let mut p = _mm512_set1_ps(1.987_569_1e-4);
            p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.398_199_9e-3));
            p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(8.333_452e-3));
            p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(4.166_579_6e-2));
            p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.666_666_5e-1));
            p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(0.5));
            let e = _mm512_fmadd_ps(p, _mm512_mul_ps(r, r), _mm512_add_ps(r, _mm512_set1_ps(1.0)));
            _mm512_scalef_ps(e, n)
        }

        /// 1 / (1 + e^−x).
        #[inline(always)]
        unsafe fn sigmoid(x: __m512) -> __m512 {
            let one = _mm512_set1_ps(1.0);
            let d = _mm512_add_ps(one, exp(_mm512_sub_ps(_mm512_setzero_ps(), x)));
            let y = _mm512_rcp14_ps(d);
            // One Newton step: y ← y + y(1 − d·y).
            _mm512_fmadd_ps(y, _mm512_fnmadd_ps(d, y, one), y)
        }

        /// 2σ(2x) − 1.
        #[inline(always)]
        unsafe fn tanh(x: __m512) -> __m512 {
            let two = _mm512_set1_ps(2.0);
            _mm512_fmsub_ps(two, sigmoid(_mm512_mul_ps(two, x)), _mm512_set1_ps(1.0))
        }

        #[target_feature(enable = "avx512f")]
        pub unsafe fn forward(
            g: &mut [f32],
            c_prev: &[f32],
            c: &mut [f32],
            tc: &mut [f32],
            h_out: &mut [f32],
            b: usize,
            hd: usize,
        ) {
            let (g, cp, c, tc, h) = (
                g.as_mut_ptr(),
                c_prev.as_ptr(),
                c.as_mut_ptr(),
                tc.as_mut_ptr(),
                h_out.as_mut_ptr(),
            );
            for r in 0..b {
                let gr = g.add(r * 4 * hd);
                let o = r * hd;
                for u in (0..hd).step_by(16) {
                    let i = sigmoid(_mm512_loadu_ps(gr.add(u)));
                    let f = sigmoid(_mm512_loadu_ps(gr.add(hd + u)));
                    let gg = tanh(_mm512_loadu_ps(gr.add(2 * hd + u)));
                    let og = sigmoid(_mm512_loadu_ps(gr.add(3 * hd + u)));
                    _mm512_storeu_ps(gr.add(u), i);
                    _mm512_storeu_ps(gr.add(hd + u), f);
                    _mm512_storeu_ps(gr.add(2 * hd + u), gg);
                    _mm512_storeu_ps(gr.add(3 * hd + u), og);
                    // c = f·c_prev + i·g, as the f32 cell computes it (product, product, sum).
                    let cn = _mm512_add_ps(_mm512_mul_ps(f, _mm512_loadu_ps(cp.add(o + u))), _mm512_mul_ps(i, gg));
                    _mm512_storeu_ps(c.add(o + u), cn);
                }
            }
            // tanh(c) in a second pass rather than at the end of the loop above, where it hung
            // a second activation chain off the first: measured ≈ 1.5 % faster per epoch in
            // interleaved runs (most likely more independent iterations in flight). The same
            // operations on every element, so the same bits.
            for r in 0..b {
                let gr = g.add(r * 4 * hd);
                let o = r * hd;
                for u in (0..hd).step_by(16) {
                    let t = tanh(_mm512_loadu_ps(c.add(o + u)));
                    _mm512_storeu_ps(tc.add(o + u), t);
                    _mm512_storeu_ps(h.add(o + u), _mm512_mul_ps(_mm512_loadu_ps(gr.add(3 * hd + u)), t));
                }
            }
        }
    }
}

/// Parameter gradients of the LSTM tensors, accumulated.
pub struct LstmGrads<'a> {
    pub w_ih: &'a mut [f32],
    pub w_hh: &'a mut [f32],
    pub b_ih: &'a mut [f32],
    pub b_hh: &'a mut [f32],
}

#[allow(clippy::too_many_arguments)]
/// Backward through time from dL/dh_T (`[b][H]`). Accumulates the parameter gradients;
/// writes dL/dx into `work.dxt` when `want_dx`.
// Long: the LSTM's backward pass through time as one kernel: gates, cell and hidden gradients of a step share registers and buffers.
pub fn backward(
    d: &LstmDims,
    params: &[f32],
    idx: &LstmParamIdx,
    prep: &LstmPrepared,
    b: usize,
    dh_last: &[f32],
    work: &mut LstmWork,
    grads: LstmGrads<'_>,
    want_dx: bool,
    mixed: bool,
) {
    let (t, j, h) = (d.t, d.j, d.h);
    let g4 = 4 * h;
    let w_hh = &params[idx.w_hh..idx.w_hh + g4 * h];
    let w_ih = &params[idx.w_ih..idx.w_ih + g4 * j];
    work.dh[..b * h].copy_from_slice(&dh_last[..b * h]);
    work.dc[..b * h].fill(0.0);
    // Mixed precision: the products that read every step's dg (dW_ihᵀ, the bias sums and
    // dW_hh's packing) are done step by step while dg_t is in L1, not in passes over the
    // whole `[T][b][4H]` buffer afterwards. That sums over the steps in the other order (T−1
    // down to 0), so f32 training keeps the passes and its bits; mixed precision's sums
    // differ from f32's anyway. dg's packing is per step only when b is even, so that no
    // pair straddles two steps (then it is the whole pass's packing, element for element).
    let per_step = mixed;
    let pack_per_step = mixed && b.is_multiple_of(2) && t > 1;
    if per_step {
        work.dwt.fill(0.0);
        work.colsum.fill(0.0);
    }
    // dW_hh's A operand (dg packed k-major) with its pair rows 4H + 32 apart, not 4H: at 2 KiB
    // apart the product's walk down k kept missing L1 (165–182 against 233 G MAC/s alone on
    // this machine at [512 × 128 × 1280]). The padding is never read.
    let lda = g4 + 32;
    if pack_per_step {
        work.pack_dg.resize(pairs((t - 1) * b) * lda, 0);
    }
    // When every use of dg_t is inside its step (mixed precision, packed step by step, no
    // dL/dx wanted), the steps share one `[b][4H]` slice that stays in L1, instead of a
    // `[T][b][4H]` buffer (2.6 MB for a shard of 16) written through the caches and never read
    // again. The same values: the same bits.
    let dg_in_l1 = per_step && pack_per_step && !want_dx;
    let dg_at = |step: usize| if dg_in_l1 { 0 } else { step * b * g4 };
    for step in (0..t).rev() {
        let c_prev: &[f32] = if step == 0 {
            &work.zeros[..b * h]
        } else {
            &work.cs[(step - 1) * b * h..step * b * h]
        };
        cell_bwd(
            &work.g[step * b * g4..(step + 1) * b * g4],
            &work.tc[step * b * h..(step + 1) * b * h],
            c_prev,
            &work.dh[..b * h],
            &mut work.dc[..b * h],
            &mut work.dg[dg_at(step)..dg_at(step) + b * g4],
            b,
            h,
        );
        if per_step {
            let dg_t = &work.dg[dg_at(step)..dg_at(step) + b * g4];
            gemm_acc(
                j,
                g4,
                b,
                StridedA {
                    data: &work.xt[step * b * j..(step + 1) * b * j],
                    rs: 1,
                    cs: j,
                },
                dg_t,
                g4,
                &mut work.dwt,
                g4,
            );
            add_rows(dg_t, g4, &mut work.colsum);
            if pack_per_step && step > 0 {
                let at = (step - 1) * (b / 2) * lda;
                pack_rows_into_ld(b, g4, dg_t, g4, &mut work.pack_dg[at..at + (b / 2) * lda], lda);
            }
        }
        if step > 0 && mixed {
            pack_cols(b, g4, &work.dg[dg_at(step)..dg_at(step) + b * g4], g4, &mut work.pack_a);
            let a = PackedA {
                data: &work.pack_a,
                rs: pairs(g4),
                ps: 1,
            };
            let dh = &mut work.dh[..b * h];
            dh.fill(0.0);
            gemm_bf16_acc(b, h, pairs(g4), a, &prep.r_bf16, dh, h);
        } else if step > 0 {
            let dh = &mut work.dh[..b * h];
            dh.fill(0.0);
            gemm_acc(
                b,
                h,
                g4,
                StridedA {
                    data: &work.dg[dg_at(step)..dg_at(step) + b * g4],
                    rs: g4,
                    cs: 1,
                },
                w_hh,
                h,
                dh,
                h,
            );
        }
    }
    // dW_hh (`[4H][H]`, the parameter's own layout) = Σ_{t≥1} dg_tᵀ h_{t−1}: rows (t, r) of
    // dg[1..T] pair with hs[1..T]. Accumulated straight into the gradient, so no transposed
    // copy to add back; each element sums the same products in the same order as
    // h_{t−1}ᵀ dg_t would, and the gradient arrives zeroed, so the bits do not change.
    if t > 1 && mixed {
        // A = dg[1..T]ᵀ: packed k-major straight from dg's rows, so nothing is transposed.
        let k = (t - 1) * b;
        if !pack_per_step {
            work.pack_dg.resize(pairs(k) * lda, 0);
            pack_rows_into_ld(k, g4, &work.dg[b * g4..t * b * g4], g4, &mut work.pack_dg, lda);
        }
        if !work.hs_packed {
            pack_rows(k, h, &work.hs[b * h..t * b * h], h, &mut work.pack_b);
        }
        let a = PackedA {
            data: &work.pack_dg,
            rs: 1,
            ps: lda,
        };
        gemm_bf16_acc(g4, h, pairs(k), a, &work.pack_b, grads.w_hh, h);
    } else if t > 1 {
        gemm_acc(
            g4,
            h,
            (t - 1) * b,
            StridedA {
                data: &work.dg[b * g4..t * b * g4],
                rs: 1,
                cs: g4,
            },
            &work.hs[b * h..t * b * h],
            h,
            grads.w_hh,
            h,
        );
    }
    // dW_ihᵀ (`[J][4H]`) then added transposed: with J = 5 columns the `[4H][J]` product
    // would use 5 of every 16 vector lanes.
    let dwt = &mut work.dwt;
    if !per_step {
        dwt.fill(0.0);
        gemm_acc(
            j,
            g4,
            t * b,
            StridedA {
                data: &work.xt[..t * b * j],
                rs: 1,
                cs: j,
            },
            &work.dg[..t * b * g4],
            g4,
            dwt,
            g4,
        );
        work.colsum.fill(0.0);
        add_rows(&work.dg[..t * b * g4], g4, &mut work.colsum);
    }
    for r in 0..g4 {
        for c in 0..j {
            grads.w_ih[r * j + c] += dwt[c * g4 + r];
        }
    }
    for ((a, bb), s) in grads.b_ih[..g4]
        .iter_mut()
        .zip(grads.b_hh[..g4].iter_mut())
        .zip(&work.colsum)
    {
        *a += s;
        *bb += s;
    }
    if want_dx {
        let dx = &mut work.dxt[..t * b * j];
        dx.fill(0.0);
        gemm_acc(
            t * b,
            j,
            g4,
            StridedA {
                data: &work.dg[..t * b * g4],
                rs: g4,
                cs: 1,
            },
            w_ih,
            j,
            dx,
            j,
        );
    }
}

simd_fn! {
    /// acc[c] += Σ_rows m[row][c], rows in order.
    fn add_rows(m: &[f32], cols: usize, acc: &mut [f32]) {
        let acc = &mut acc[..cols];
        for row in m.chunks_exact(cols) {
            for (s, v) in acc.iter_mut().zip(row) {
                *s += v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The mixed-precision cell (FMA, hardware reciprocal) against the f32 cell (the shared
    /// activations) on gates over the range training meets, saturated ones and a NaN: within
    /// 4e-7 (absolute, gates and h) and 4e-7 relative (c), NaN kept.
    #[test]
    fn mixed_cell_matches_the_shared_activations() {
        let (b, hd) = (3, 32);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut g: Vec<f32> = (0..b * 4 * hd).map(|_| rng.random_range(-12.0..12.0)).collect();
        g[5] = 95.0;
        g[6] = -95.0;
        g[4 * hd + 7] = f32::NAN;
        let c_prev: Vec<f32> = (0..b * hd).map(|_| rng.random_range(-6.0..6.0)).collect();
        let run = |mixed: bool| {
            let mut g = g.clone();
            let (mut c, mut tc, mut h) = (vec![0.0; b * hd], vec![0.0; b * hd], vec![0.0; b * hd]);
            if mixed {
                if !mixed_cell::forward(&mut g, &c_prev, &mut c, &mut tc, &mut h, b, hd) {
                    return None;
                }
            } else {
                cell_fwd(&mut g, &c_prev, &mut c, &mut tc, &mut h, b, hd);
            }
            Some((g, c, tc, h))
        };
        let want = run(false).unwrap();
        let Some(got) = run(true) else {
            eprintln!("no AVX-512 here: the mixed cell is not used, nothing to compare");
            return;
        };
        let close = |name: &str, a: &[f32], w: &[f32], rel: bool| {
            for (i, (x, y)) in a.iter().zip(w).enumerate() {
                if y.is_nan() {
                    assert!(x.is_nan(), "{name}[{i}]: NaN lost ({x})");
                    continue;
                }
                let tol = if rel { 4e-7 * y.abs().max(1.0) } else { 4e-7 };
                assert!((x - y).abs() <= tol, "{name}[{i}]: {x} vs the f32 cell's {y}");
            }
        };
        close("gates", &got.0, &want.0, false);
        close("c", &got.1, &want.1, true);
        close("tanh c", &got.2, &want.2, false);
        close("h", &got.3, &want.3, false);
        assert_ne!(got.0, want.0, "the mixed cell gave the f32 cell's bits: did it run?");
    }

    /// The mixed-precision sweep's two memory savings compute the same bits as the buffers
    /// they replace: dg_t kept in one L1 slice (no dL/dx wanted) against the `[T][b][4H]`
    /// buffer (dL/dx wanted), and h_t packed for dW_hh by the forward pass step by step against
    /// one packing of all of them in the backward pass. Every parameter gradient, bit for bit.
    #[test]
    fn mixed_sweep_buffers_give_the_same_gradient_bits() {
        let d = LstmDims { t: 9, j: 5, h: 32 };
        let (g4, b) = (4 * d.h, 6);
        let idx = LstmParamIdx {
            w_ih: 0,
            w_hh: g4 * d.j,
            b_ih: g4 * d.j + g4 * d.h,
            b_hh: g4 * d.j + g4 * d.h + g4,
        };
        let n = idx.b_hh + g4;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let params: Vec<f32> = (0..n).map(|_| rng.random_range(-0.3..0.3)).collect();
        let xt: Vec<f32> = (0..d.t * b * d.j).map(|_| rng.random_range(-2.0..2.0)).collect();
        let dh_last: Vec<f32> = (0..b * d.h).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut prep = LstmPrepared::default();
        prep.prepare(&d, &params, &idx, true);
        // (dL/dx wanted, h packed by the backward pass) → the four parameter gradients.
        let run = |want_dx: bool, pack_in_backward: bool| {
            let mut work = LstmWork::new(&d, b);
            work.xt.copy_from_slice(&xt);
            forward(&d, &prep, b, &mut work, true);
            assert!(work.hs_packed, "an even b packs h in the forward pass");
            if pack_in_backward {
                work.pack_b.iter_mut().for_each(|v| *v = 0);
                work.hs_packed = false;
            }
            let (mut w_ih, mut w_hh, mut b_ih, mut b_hh) =
                (vec![0.0; g4 * d.j], vec![0.0; g4 * d.h], vec![0.0; g4], vec![0.0; g4]);
            let grads = LstmGrads {
                w_ih: &mut w_ih,
                w_hh: &mut w_hh,
                b_ih: &mut b_ih,
                b_hh: &mut b_hh,
            };
            backward(&d, &params, &idx, &prep, b, &dh_last, &mut work, grads, want_dx, true);
            [w_ih, w_hh, b_ih, b_hh]
        };
        let reference = run(true, true);
        assert!(reference[1].iter().any(|&v| v != 0.0));
        for (want_dx, in_backward) in [(false, false), (false, true), (true, false)] {
            let got = run(want_dx, in_backward);
            for (name, (a, w)) in ["w_ih", "w_hh", "b_ih", "b_hh"].iter().zip(got.iter().zip(&reference)) {
                let same = a.iter().zip(w).all(|(x, y)| x.to_bits() == y.to_bits());
                assert!(
                    same,
                    "{name}: want_dx {want_dx}, h packed in the backward pass {in_backward}"
                );
            }
        }
    }
}
