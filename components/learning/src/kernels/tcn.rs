//! The TCN's residual blocks, forward and backward, fused and batched.
//!
//! Activations are channels-first per window: `C` rows of `P + T` floats whose first `P`
//! (= twice the largest dilation) are zeros, so a causal dilated tap `t − s` is a plain
//! shifted slice — the left zero padding of PyTorch's `F.pad(x, (2d, 0))` — and every inner
//! loop runs over T contiguous time steps (vectorised across time).

use super::simd::simd_fn;
use crate::arch::{tcn_dilation, TcnBlock, TCN_KERNEL};

/// Shapes of one TCN.
#[derive(Debug, Clone, Copy)]
pub struct TcnDims {
    /// Channels = joints.
    pub c: usize,
    /// Sequence length L.
    pub t: usize,
    pub blocks: usize,
    /// Left zero pad of every row: 2 · largest dilation.
    pub pad: usize,
    pub block_kind: TcnBlock,
}

impl TcnDims {
    pub fn new(c: usize, t: usize, blocks: usize, block_kind: TcnBlock) -> Self {
        Self {
            c,
            t,
            blocks,
            pad: (TCN_KERNEL - 1) * tcn_dilation(blocks.saturating_sub(1)),
            block_kind,
        }
    }

    /// Row stride: pad + T.
    pub fn s(&self) -> usize {
        self.pad + self.t
    }

    /// One C × S activation plane.
    pub fn plane(&self) -> usize {
        self.c * self.s()
    }

    /// Floats cached per window: z_0..z_B, h1 per block, h2 per block.
    pub fn cache_per_window(&self) -> usize {
        (3 * self.blocks + 1) * self.plane()
    }

    fn z_off(&self, k: usize) -> usize {
        k * self.plane()
    }

    fn h1_off(&self, k: usize) -> usize {
        (self.blocks + 1 + k) * self.plane()
    }

    fn h2_off(&self, k: usize) -> usize {
        (2 * self.blocks + 1 + k) * self.plane()
    }
}

/// Offsets of each block's tensors in the flat parameter vector.
#[derive(Debug, Clone)]
pub struct TcnParamIdx {
    /// Per block: (c1.weight, c1.bias, c2.weight, c2.bias) offsets.
    pub blocks: Vec<[usize; 4]>,
}

/// Per-thread scratch for the backward pass.
#[derive(Debug, Clone)]
pub struct TcnScratch {
    dz: Vec<f32>,
    dh1: Vec<f32>,
    da: Vec<f32>,
}

impl TcnScratch {
    pub fn new(d: &TcnDims) -> Self {
        Self {
            dz: vec![0.0; d.plane()],
            dh1: vec![0.0; d.plane()],
            da: vec![0.0; d.c * d.t],
        }
    }
}

simd_fn! {
    /// out[co][P+t] = bias[co] + Σ_ci Σ_kk w[co][ci][kk] · inp[ci][P + t − (2−kk)·d]
    fn conv_fwd(w: &[f32], bias: &[f32], dil: usize, inp: &[f32], out: &mut [f32], c: usize, pad: usize, t: usize) {
        let s = pad + t;
        for co in 0..c {
            let o = &mut out[co * s + pad..co * s + pad + t];
            o.fill(bias[co]);
            for ci in 0..c {
                for kk in 0..TCN_KERNEL {
                    let shift = (TCN_KERNEL - 1 - kk) * dil;
                    let wv = w[(co * c + ci) * TCN_KERNEL + kk];
                    let src = &inp[ci * s + pad - shift..ci * s + pad - shift + t];
                    for (ov, sv) in o.iter_mut().zip(src) {
                        *ov += wv * sv;
                    }
                }
            }
        }
    }
}

simd_fn! {
    /// Gradients of one conv: dw += dout ⋆ inp, db += Σ dout, din[..] += wᵀ dout (if `want_din`).
    fn conv_bwd(
        w: &[f32],
        dil: usize,
        inp: &[f32],
        dout: &[f32],
        dw: &mut [f32],
        db: &mut [f32],
        din: &mut [f32],
        want_din: bool,
        c: usize,
        pad: usize,
        t: usize,
    ) {
        let s = pad + t;
        for co in 0..c {
            let g = &dout[co * t..co * t + t];
            db[co] += sum16(g);
            for ci in 0..c {
                for kk in 0..TCN_KERNEL {
                    let shift = (TCN_KERNEL - 1 - kk) * dil;
                    let src = &inp[ci * s + pad - shift..ci * s + pad - shift + t];
                    let widx = (co * c + ci) * TCN_KERNEL + kk;
                    dw[widx] += dot16(g, src);
                    if want_din && shift < t {
                        // din[ci][t' ] += w · g[t' + shift] for t' in 0..t−shift (taps into the
                        // zero pad carry no gradient anywhere).
                        let wv = w[widx];
                        let dst = &mut din[ci * s + pad..ci * s + pad + t - shift];
                        for (dv, gv) in dst.iter_mut().zip(&g[shift..]) {
                            *dv += wv * gv;
                        }
                    }
                }
            }
        }
    }
}

/// Σ a·b with 16 independent partial sums (vectorises without reassociating a single
/// accumulator; the order is fixed, so results are reproducible).
#[inline(always)]
fn dot16(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 16];
    let n = a.len().min(b.len());
    let chunks = n / 16;
    for ch in 0..chunks {
        let (x, y) = (&a[ch * 16..ch * 16 + 16], &b[ch * 16..ch * 16 + 16]);
        for l in 0..16 {
            acc[l] += x[l] * y[l];
        }
    }
    let mut tail = 0.0f32;
    for i in chunks * 16..n {
        tail += a[i] * b[i];
    }
    acc.iter().sum::<f32>() + tail
}

#[inline(always)]
fn sum16(a: &[f32]) -> f32 {
    let mut acc = [0.0f32; 16];
    let chunks = a.len() / 16;
    for ch in 0..chunks {
        let x = &a[ch * 16..ch * 16 + 16];
        for l in 0..16 {
            acc[l] += x[l];
        }
    }
    let mut tail = 0.0f32;
    for v in &a[chunks * 16..] {
        tail += v;
    }
    acc.iter().sum::<f32>() + tail
}

simd_fn! {
    fn relu_inplace(x: &mut [f32]) {
        for v in x.iter_mut() {
            *v = v.max(0.0);
        }
    }
}

simd_fn! {
    fn add_into(dst: &mut [f32], a: &[f32], b: &[f32]) {
        for ((d, x), y) in dst.iter_mut().zip(a).zip(b) {
            *d = x + y;
        }
    }
}

simd_fn! {
    /// out = g ⊙ [act > 0]
    fn relu_grad(out: &mut [f32], g: &[f32], act: &[f32]) {
        for ((o, gv), a) in out.iter_mut().zip(g).zip(act) {
            *o = if *a > 0.0 { *gv } else { 0.0 };
        }
    }
}

/// Forward pass of `b` windows. `x` is `[b][T][C]` (time-major, normalised); `cache` holds
/// `b × cache_per_window` floats whose pad regions are zero (they are never written).
pub fn forward(d: &TcnDims, params: &[f32], idx: &TcnParamIdx, x: &[f32], b: usize, cache: &mut [f32]) {
    let (c, t, pad, s) = (d.c, d.t, d.pad, d.s());
    let per = d.cache_per_window();
    for row in 0..b {
        let win = &mut cache[row * per..(row + 1) * per];
        let xw = &x[row * t * c..(row + 1) * t * c];
        {
            let z0 = &mut win[d.z_off(0)..d.z_off(0) + d.plane()];
            for tt in 0..t {
                for ci in 0..c {
                    z0[ci * s + pad + tt] = xw[tt * c + ci];
                }
            }
        }
        for k in 0..d.blocks {
            let [w1, b1, w2, b2] = idx.blocks[k];
            let dil = tcn_dilation(k);
            let cc = c * c * TCN_KERNEL;
            // h1 = relu(conv1(z_k))
            let (lo, hi) = win.split_at_mut(d.h1_off(k));
            let zk = &lo[d.z_off(k)..d.z_off(k) + d.plane()];
            let h1 = &mut hi[..d.plane()];
            conv_fwd(&params[w1..w1 + cc], &params[b1..b1 + c], dil, zk, h1, c, pad, t);
            for co in 0..c {
                relu_inplace(&mut h1[co * s + pad..co * s + pad + t]);
            }
            // a2 = conv2(h1) into the h2 slot; relu-relu keeps relu(a2) there.
            let (lo, hi) = win.split_at_mut(d.h2_off(k));
            let h1 = &lo[d.h1_off(k)..d.h1_off(k) + d.plane()];
            let h2 = &mut hi[..d.plane()];
            conv_fwd(&params[w2..w2 + cc], &params[b2..b2 + c], dil, h1, h2, c, pad, t);
            if d.block_kind == TcnBlock::ReluRelu {
                for co in 0..c {
                    relu_inplace(&mut h2[co * s + pad..co * s + pad + t]);
                }
            }
            // z_{k+1} = z_k + h2
            let (lo, hi) = win.split_at_mut(d.h1_off(0));
            let (zs, znext) = lo.split_at_mut(d.z_off(k + 1));
            let zk = &zs[d.z_off(k)..];
            let h2 = &hi[d.h2_off(k) - d.h1_off(0)..d.h2_off(k) - d.h1_off(0) + d.plane()];
            for co in 0..c {
                let r = co * s + pad..co * s + pad + t;
                add_into(&mut znext[r.clone()], &zk[r.clone()], &h2[r]);
            }
        }
    }
}

/// The TCN output z_B of window `row`: channel `ch`, time `tt`.
#[inline]
pub fn output(d: &TcnDims, cache: &[f32], row: usize, ch: usize, tt: usize) -> f32 {
    cache[row * d.cache_per_window() + d.z_off(d.blocks) + ch * d.s() + d.pad + tt]
}

/// Backward pass of one window. `dz_out` is dL/dz_B as `[C][T]`; parameter gradients are
/// accumulated into `grad` (same layout as `params`). The input gradient is not needed (the
/// input is data), so block 0's conv1 skips it.
#[allow(clippy::too_many_arguments)]
pub fn backward_window(
    d: &TcnDims,
    params: &[f32],
    idx: &TcnParamIdx,
    cache: &[f32],
    row: usize,
    dz_out: &[f32],
    scratch: &mut TcnScratch,
    grad: &mut [f32],
) {
    let (c, t, pad, s) = (d.c, d.t, d.pad, d.s());
    let per = d.cache_per_window();
    let win = &cache[row * per..(row + 1) * per];
    let cc = c * c * TCN_KERNEL;
    let TcnScratch { dz, dh1, da } = scratch;
    dz.fill(0.0);
    for co in 0..c {
        dz[co * s + pad..co * s + pad + t].copy_from_slice(&dz_out[co * t..(co + 1) * t]);
    }
    for k in (0..d.blocks).rev() {
        let [w1, b1, w2, b2] = idx.blocks[k];
        let dil = tcn_dilation(k);
        let zk = &win[d.z_off(k)..d.z_off(k) + d.plane()];
        let h1 = &win[d.h1_off(k)..d.h1_off(k) + d.plane()];
        let h2 = &win[d.h2_off(k)..d.h2_off(k) + d.plane()];
        // da2 = dz ⊙ relu'(a2) (relu-relu) or dz (relu-linear)
        for co in 0..c {
            let g = &dz[co * s + pad..co * s + pad + t];
            let out = &mut da[co * t..(co + 1) * t];
            match d.block_kind {
                TcnBlock::ReluRelu => relu_grad(out, g, &h2[co * s + pad..co * s + pad + t]),
                TcnBlock::ReluLinear => out.copy_from_slice(g),
            }
        }
        dh1.fill(0.0);
        {
            let (gw, rest) = grad.split_at_mut(b2);
            conv_bwd(
                &params[w2..w2 + cc],
                dil,
                h1,
                da,
                &mut gw[w2..w2 + cc],
                &mut rest[..c],
                dh1,
                true,
                c,
                pad,
                t,
            );
        }
        for co in 0..c {
            let r = co * s + pad..co * s + pad + t;
            relu_grad(&mut da[co * t..(co + 1) * t], &dh1[r.clone()], &h1[r]);
        }
        // dz_k = dz_{k+1} (residual) + conv1's input gradient, accumulated in place.
        let (gw, rest) = grad.split_at_mut(b1);
        conv_bwd(
            &params[w1..w1 + cc],
            dil,
            zk,
            da,
            &mut gw[w1..w1 + cc],
            &mut rest[..c],
            dz,
            k > 0,
            c,
            pad,
            t,
        );
    }
}
