//! A single-layer LSTM (PyTorch semantics: gates i, f, g, o; h₀ = c₀ = 0), forward and
//! backward through time, batched: every step is one GEMM of the batch's hidden states
//! against the recurrent weights plus one fused elementwise cell; the weight gradients of
//! all steps are one GEMM each after the backward sweep.

use super::bf16::{gemm_bf16_acc, pack_cols, pack_rows, pairs, PackedA};
use super::gemm::{gemm_acc, StridedA};
use super::simd::{sigmoid_f32, simd_fn, tanh_f32};

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
    pub xt: Vec<f32>,
    /// Gate activations i, f, g, o after their nonlinearity, `[T][b][4H]`.
    g: Vec<f32>,
    /// Cell states c_t, `[T][b][H]`.
    cs: Vec<f32>,
    /// tanh(c_t), `[T][b][H]`.
    tc: Vec<f32>,
    /// Hidden states, `[T+1][b][H]`, `hs[0] = 0`, `hs[t+1] = h_t`.
    pub hs: Vec<f32>,
    /// Pre-activation gate gradients, `[T][b][4H]`.
    dg: Vec<f32>,
    dh: Vec<f32>,
    dc: Vec<f32>,
    /// Input gradients, `[T][b][J]`.
    pub dxt: Vec<f32>,
    dwt: Vec<f32>,
    colsum: Vec<f32>,
    zeros: Vec<f32>,
    /// Mixed precision only: the A and B operands of one product packed as bf16 pairs
    /// (sized on first use, then reused).
    pack_a: Vec<u32>,
    pack_b: Vec<u32>,
}

impl LstmWork {
    pub fn new(d: &LstmDims, cap: usize) -> Self {
        let (t, j, h) = (d.t, d.j, d.h);
        Self {
            cap,
            xt: vec![0.0; t * cap * j],
            g: vec![0.0; t * cap * 4 * h],
            cs: vec![0.0; t * cap * h],
            tc: vec![0.0; t * cap * h],
            hs: vec![0.0; (t + 1) * cap * h],
            dg: vec![0.0; t * cap * 4 * h],
            dh: vec![0.0; cap * h],
            dc: vec![0.0; cap * h],
            dxt: vec![0.0; t * cap * j],
            dwt: vec![0.0; j * 4 * h],
            colsum: vec![0.0; 4 * h],
            zeros: vec![0.0; cap * h],
            pack_a: Vec::new(),
            pack_b: Vec::new(),
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
    pub wt_ih: Vec<f32>,
    /// W_hhᵀ, `[H][4H]`.
    pub rt: Vec<f32>,
    /// b_ih + b_hh, `[4H]`.
    pub bias: Vec<f32>,
    /// Mixed precision: W_hhᵀ and W_hh as the B operands of the recurrent products, packed
    /// as bf16 pairs ([`super::bf16`]); empty in f32.
    pub rt_bf16: Vec<u32>,
    pub r_bf16: Vec<u32>,
}

/// `dst` (`[cols][rows]`) = `src` (`[rows][cols]`)ᵀ.
pub fn transpose(src: &[f32], rows: usize, cols: usize, dst: &mut Vec<f32>) {
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
        let g = 4 * d.h;
        transpose(&params[idx.w_ih..idx.w_ih + g * d.j], g, d.j, &mut self.wt_ih);
        transpose(&params[idx.w_hh..idx.w_hh + g * d.h], g, d.h, &mut self.rt);
        self.bias.resize(g, 0.0);
        for i in 0..g {
            self.bias[i] = params[idx.b_ih + i] + params[idx.b_hh + i];
        }
        if mixed {
            pack_rows(d.h, g, &self.rt, g, &mut self.rt_bf16);
            pack_rows(g, d.h, &params[idx.w_hh..idx.w_hh + g * d.h], d.h, &mut self.r_bf16);
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
    let gates = &mut work.g[..t * b * g4];
    for row in gates.chunks_exact_mut(g4) {
        row.copy_from_slice(&prep.bias);
    }
    // Input projections of all steps at once.
    gemm_acc(
        t * b,
        g4,
        j,
        StridedA {
            data: &work.xt[..t * b * j],
            rs: j,
            cs: 1,
        },
        &prep.wt_ih,
        g4,
        gates,
        g4,
    );
    work.hs[..b * h].fill(0.0);
    for step in 0..t {
        let gs = &mut work.g[step * b * g4..(step + 1) * b * g4];
        if step > 0 && mixed {
            pack_cols(b, h, &work.hs[step * b * h..(step + 1) * b * h], h, &mut work.pack_a);
            let a = PackedA {
                data: &work.pack_a,
                rs: pairs(h),
                ps: 1,
            };
            gemm_bf16_acc(b, g4, pairs(h), a, &prep.rt_bf16, gs, g4);
        } else if step > 0 {
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
        cell_fwd(
            gs,
            c_prev,
            &mut cs_hi[..b * h],
            &mut work.tc[step * b * h..(step + 1) * b * h],
            &mut work.hs[(step + 1) * b * h..(step + 2) * b * h],
            b,
            h,
        );
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
            &mut work.dg[step * b * g4..(step + 1) * b * g4],
            b,
            h,
        );
        if step > 0 && mixed {
            pack_cols(
                b,
                g4,
                &work.dg[step * b * g4..(step + 1) * b * g4],
                g4,
                &mut work.pack_a,
            );
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
                    data: &work.dg[step * b * g4..(step + 1) * b * g4],
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
        pack_rows(k, g4, &work.dg[b * g4..t * b * g4], g4, &mut work.pack_a);
        pack_rows(k, h, &work.hs[b * h..t * b * h], h, &mut work.pack_b);
        let a = PackedA {
            data: &work.pack_a,
            rs: 1,
            ps: g4,
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
    for r in 0..g4 {
        for c in 0..j {
            grads.w_ih[r * j + c] += dwt[c * g4 + r];
        }
    }
    column_sums_into(&work.dg[..t * b * g4], g4, &mut work.colsum, grads.b_ih, grads.b_hh);
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
    /// a[c] += Σ_rows m[row][c]; b[c] += the same (`acc`: `cols` floats of scratch).
    fn column_sums_into(m: &[f32], cols: usize, acc: &mut [f32], a: &mut [f32], b: &mut [f32]) {
        let acc = &mut acc[..cols];
        acc.fill(0.0);
        for row in m.chunks_exact(cols) {
            for (s, v) in acc.iter_mut().zip(row) {
                *s += v;
            }
        }
        for c in 0..cols {
            a[c] += acc[c];
            b[c] += acc[c];
        }
    }
}
