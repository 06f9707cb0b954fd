//! Fully connected layers (PyTorch `nn.Linear`: `y = x Wᵀ + b`, W is `[out][in]`) and ReLU,
//! forward and backward, on top of the one GEMM.

use super::gemm::{gemm_acc, StridedA};
use super::simd::simd_fn;

/// `y[b×out] = x[b×in] · Wᵀ + bias`, with `wt` = Wᵀ (`[in][out]`).
pub fn forward(x: &[f32], b: usize, n_in: usize, wt: &[f32], bias: &[f32], n_out: usize, y: &mut [f32]) {
    let y = &mut y[..b * n_out];
    for row in y.chunks_exact_mut(n_out) {
        row.copy_from_slice(&bias[..n_out]);
    }
    gemm_acc(
        b,
        n_out,
        n_in,
        StridedA {
            data: &x[..b * n_in],
            rs: n_in,
            cs: 1,
        },
        wt,
        n_out,
        y,
        n_out,
    );
}

/// Accumulates dW (`[out][in]`) += dyᵀ x and db += Σ dy; writes dx = dy · W when given.
#[allow(clippy::too_many_arguments)]
pub fn backward(
    x: &[f32],
    b: usize,
    n_in: usize,
    w: &[f32],
    n_out: usize,
    dy: &[f32],
    dw: &mut [f32],
    db: &mut [f32],
    dx: Option<&mut [f32]>,
) {
    gemm_acc(
        n_out,
        n_in,
        b,
        StridedA {
            data: &dy[..b * n_out],
            rs: 1,
            cs: n_out,
        },
        &x[..b * n_in],
        n_in,
        dw,
        n_in,
    );
    for row in dy[..b * n_out].chunks_exact(n_out) {
        for (d, v) in db.iter_mut().zip(row) {
            *d += v;
        }
    }
    if let Some(dx) = dx {
        let dx = &mut dx[..b * n_in];
        dx.fill(0.0);
        gemm_acc(
            b,
            n_in,
            n_out,
            StridedA {
                data: &dy[..b * n_out],
                rs: n_out,
                cs: 1,
            },
            w,
            n_in,
            dx,
            n_in,
        );
    }
}

simd_fn! {
    pub fn relu(x: &mut [f32]) {
        for v in x.iter_mut() {
            *v = v.max(0.0);
        }
    }
}

simd_fn! {
    /// g ⊙= [act > 0]
    pub fn relu_backward(g: &mut [f32], act: &[f32]) {
        for (gv, a) in g.iter_mut().zip(act) {
            if *a <= 0.0 {
                *gv = 0.0;
            }
        }
    }
}
