//! The TCN's residual blocks, forward and backward, fused and batched.
//!
//! Activations are channels-first per window: `C` rows of `P + T` floats whose first `P`
//! (= twice the largest dilation) are zeros, so a causal dilated tap `t − s` is a plain
//! shifted slice — the left zero padding of PyTorch's `F.pad(x, (2d, 0))` — and every inner
//! loop runs over T contiguous time steps (vectorised across time).

use super::simd::simd_fn;
use crate::arch::{tcn_dilation, TcnBlock, TCN_KERNEL};
use bowden_fastmath::AVec;

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
    dz: AVec<f32>,
    dh1: AVec<f32>,
    /// Gradients at a conv's output, `C` rows of `T + pad` floats (then `LANES` spare), so
    /// the input-gradient loop reads `g[t + shift]` past a row's end without a bounds
    /// branch (those lanes are masked out).
    da: AVec<f32>,
}

impl TcnScratch {
    pub fn new(d: &TcnDims) -> Self {
        Self {
            dz: AVec::from_elem(0.0, d.plane()),
            dh1: AVec::from_elem(0.0, d.plane()),
            // A register block may read up to LANES − 1 floats past the last row (masked).
            da: AVec::from_elem(0.0, d.c * d.s() + LANES),
        }
    }
}

/// Time steps per register block of the convolution loops (one AVX-512 vector).
const LANES: usize = 16;

simd_fn! {
    /// out[co][P+t] = bias[co] + Σ_ci Σ_kk w[co][ci][kk] · inp[ci][P + t − (2−kk)·d]
    ///
    /// Every output starts at the bias and adds the taps one by one in (ci, kk) order — the
    /// same sums in the same order as a pass over the row per tap, so the same bits — but 16
    /// time steps are held in a register through all the taps instead of being loaded and
    /// stored once per tap.
    fn conv_fwd(w: &[f32], bias: &[f32], dil: usize, inp: &[f32], out: &mut [f32], c: usize, pad: usize, t: usize) {
        let s = pad + t;
        let full = t / LANES * LANES;
        for co in 0..c {
            let wrow = &w[co * c * TCN_KERNEL..(co + 1) * c * TCN_KERNEL];
            let o = &mut out[co * s + pad..co * s + pad + t];
            for t0 in (0..full).step_by(LANES) {
                let mut acc = [bias[co]; LANES];
                for ci in 0..c {
                    for kk in 0..TCN_KERNEL {
                        let shift = (TCN_KERNEL - 1 - kk) * dil;
                        let wv = wrow[ci * TCN_KERNEL + kk];
                        let at = ci * s + pad - shift + t0;
                        let src = &inp[at..at + LANES];
                        for l in 0..LANES {
                            acc[l] += wv * src[l];
                        }
                    }
                }
                o[t0..t0 + LANES].copy_from_slice(&acc);
            }
            for tt in full..t {
                let mut acc = bias[co];
                for ci in 0..c {
                    for kk in 0..TCN_KERNEL {
                        let shift = (TCN_KERNEL - 1 - kk) * dil;
                        acc += wrow[ci * TCN_KERNEL + kk] * inp[ci * s + pad - shift + tt];
                    }
                }
                o[tt] = acc;
            }
        }
    }
}

simd_fn! {
    /// Gradients of one conv: dw += dout ⋆ inp, db += Σ dout, din[..] += wᵀ dout (if
    /// `want_din`). `dout` is `C` rows of `T + pad` floats and `LANES` more.
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
            let g = &dout[co * s..co * s + t];
            db[co] += sum16(g);
            for ci in 0..c {
                for kk in 0..TCN_KERNEL {
                    let shift = (TCN_KERNEL - 1 - kk) * dil;
                    let src = &inp[ci * s + pad - shift..ci * s + pad - shift + t];
                    dw[(co * c + ci) * TCN_KERNEL + kk] += dot16(g, src);
                }
            }
        }
        if !want_din {
            return;
        }
        // din[ci][t'] += w[co][ci][kk] · g_co[t' + shift] for t' + shift < t (taps into the
        // zero pad carry no gradient anywhere), added in (co, kk) order: the order of a pass
        // per tap, 16 time steps held in a register. A lane past the end adds −0.0, which
        // leaves every value (±0 included) as it was, so the bits are those of the loop
        // that skips it.
        let full = t / LANES * LANES;
        for ci in 0..c {
            let drow = &mut din[ci * s + pad..ci * s + pad + t];
            for t0 in (0..full).step_by(LANES) {
                let mut acc = [0.0f32; LANES];
                acc.copy_from_slice(&drow[t0..t0 + LANES]);
                for co in 0..c {
                    for kk in 0..TCN_KERNEL {
                        let shift = (TCN_KERNEL - 1 - kk) * dil;
                        if t0 + shift >= t {
                            continue;
                        }
                        let wv = w[(co * c + ci) * TCN_KERNEL + kk];
                        let at = co * s + t0 + shift;
                        let gsrc = &dout[at..at + LANES];
                        let live = t - t0 - shift;
                        for l in 0..LANES {
                            let term = wv * gsrc[l];
                            acc[l] += if l < live { term } else { -0.0 };
                        }
                    }
                }
                drow[t0..t0 + LANES].copy_from_slice(&acc);
            }
            for (tt, dv) in drow.iter_mut().enumerate().skip(full) {
                for co in 0..c {
                    for kk in 0..TCN_KERNEL {
                        let shift = (TCN_KERNEL - 1 - kk) * dil;
                        if tt + shift < t {
                            *dv += w[(co * c + ci) * TCN_KERNEL + kk] * dout[co * s + tt + shift];
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
            let out = &mut da[co * s..co * s + t];
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
            relu_grad(&mut da[co * s..co * s + t], &dh1[r.clone()], &h1[r]);
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The loops before the register blocks: one pass over the row per tap.
    #[allow(clippy::too_many_arguments)]
    fn conv_fwd_per_tap(
        w: &[f32],
        bias: &[f32],
        dil: usize,
        inp: &[f32],
        out: &mut [f32],
        c: usize,
        pad: usize,
        t: usize,
    ) {
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

    #[allow(clippy::too_many_arguments)]
    fn din_per_tap(w: &[f32], dil: usize, dout: &[f32], din: &mut [f32], c: usize, pad: usize, t: usize) {
        let s = pad + t;
        for co in 0..c {
            let g = &dout[co * s..co * s + t];
            for ci in 0..c {
                for kk in 0..TCN_KERNEL {
                    let shift = (TCN_KERNEL - 1 - kk) * dil;
                    if shift < t {
                        let wv = w[(co * c + ci) * TCN_KERNEL + kk];
                        let dst = &mut din[ci * s + pad..ci * s + pad + t - shift];
                        for (dv, gv) in dst.iter_mut().zip(&g[shift..]) {
                            *dv += wv * gv;
                        }
                    }
                }
            }
        }
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The register-blocked convolutions give the per-tap loops' bits: lengths with and
    /// without a partial block, every dilation, signed zeros in the input gradient.
    #[test]
    fn register_blocks_give_the_bits_of_a_pass_per_tap() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for &(c, t, blocks) in &[(5, 80, 5), (3, 33, 3), (5, 20, 3), (2, 7, 2)] {
            let d = TcnDims::new(c, t, blocks, TcnBlock::ReluLinear);
            let (s, pad) = (d.s(), d.pad);
            for k in 0..blocks {
                let dil = tcn_dilation(k);
                let w: Vec<f32> = (0..c * c * TCN_KERNEL).map(|_| rng.random_range(-1.0..1.0)).collect();
                let bias: Vec<f32> = (0..c).map(|_| rng.random_range(-1.0..1.0)).collect();
                let mut inp = vec![0.0f32; c * s];
                for ci in 0..c {
                    for v in &mut inp[ci * s + pad..(ci + 1) * s] {
                        *v = rng.random_range(-1.0..1.0);
                    }
                }
                let (mut a, mut b) = (vec![0.0f32; c * s], vec![0.0f32; c * s]);
                conv_fwd(&w, &bias, dil, &inp, &mut a, c, pad, t);
                conv_fwd_per_tap(&w, &bias, dil, &inp, &mut b, c, pad, t);
                assert_eq!(bits(&a), bits(&b), "forward c={c} t={t} dil={dil}");

                // Output gradients with exact zeros (ReLU) and an input gradient that starts
                // with −0.0 entries, where adding +0.0 instead of nothing would flip a bit.
                let mut dout = vec![0.0f32; c * s + LANES];
                for co in 0..c {
                    for v in &mut dout[co * s..co * s + t] {
                        *v = if rng.random_bool(0.3) {
                            0.0
                        } else {
                            rng.random_range(-1.0..1.0)
                        };
                    }
                }
                let mut din0 = vec![0.0f32; c * s];
                for v in din0.iter_mut() {
                    *v = if rng.random_bool(0.5) {
                        -0.0
                    } else {
                        rng.random_range(-1.0..1.0)
                    };
                }
                let (mut dw_a, mut db_a, mut din_a) = (vec![0.0f32; w.len()], vec![0.0f32; c], din0.clone());
                conv_bwd(&w, dil, &inp, &dout, &mut dw_a, &mut db_a, &mut din_a, true, c, pad, t);
                let mut din_b = din0.clone();
                din_per_tap(&w, dil, &dout, &mut din_b, c, pad, t);
                assert_eq!(bits(&din_a), bits(&din_b), "input gradient c={c} t={t} dil={dil}");
                for co in 0..c {
                    let g = &dout[co * s..co * s + t];
                    assert_eq!(db_a[co].to_bits(), sum16(g).to_bits());
                    for ci in 0..c {
                        for kk in 0..TCN_KERNEL {
                            let shift = (TCN_KERNEL - 1 - kk) * dil;
                            let src = &inp[ci * s + pad - shift..ci * s + pad - shift + t];
                            assert_eq!(dw_a[(co * c + ci) * TCN_KERNEL + kk].to_bits(), dot16(g, src).to_bits());
                        }
                    }
                }
            }
        }
    }
}
