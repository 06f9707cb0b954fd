//! The hand-written GEMM at the exact shapes an LSTM training step uses, and, with
//! `--features faer`, faer 0.24's `matmul` on the same operands beside it:
//!
//! ```sh
//! cargo bench -p bowden-learning --features faer --bench gemm
//! ```
//!
//! Shapes are per shard: a batch of 32 is cut into 2 shards of 16 windows (one per thread),
//! L = 80, hidden H = 128 (4H = 512 gate columns), J = 5 inputs, head 128 → 64 → 5. Each is
//! `C[m×n] += A(m×k)·B[k×n]` with B and C row-major and A row-major or transposed, as the
//! kernels call it. Throughput is in multiply-adds per second.

use bowden_learning::kernels::gemm::{gemm_acc, StridedA};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

/// One product of a training step: `name`, m, n, k, and whether A is read transposed.
struct Shape {
    name: &'static str,
    m: usize,
    n: usize,
    k: usize,
    a_transposed: bool,
}

const SHAPES: &[Shape] = &[
    // Forward: the input projections of all 80 steps at once (x·W_ihᵀ).
    Shape {
        name: "fwd_x_wih",
        m: 1280,
        n: 512,
        k: 5,
        a_transposed: false,
    },
    // Forward, every step after the first: h·W_hhᵀ (79 per shard and batch).
    Shape {
        name: "fwd_h_whh",
        m: 16,
        n: 512,
        k: 128,
        a_transposed: false,
    },
    // Backward, every step after the first: dh = dg·W_hh (79 per shard and batch).
    Shape {
        name: "bwd_dg_whh",
        m: 16,
        n: 128,
        k: 512,
        a_transposed: false,
    },
    // Backward: dW_hh = Σ_t dg_tᵀ h_{t−1} over 79 steps × 16 rows.
    Shape {
        name: "bwd_dwhh",
        m: 512,
        n: 128,
        k: 1264,
        a_transposed: true,
    },
    // Backward: dW_ihᵀ = Xᵀ·dG over 80 steps × 16 rows.
    Shape {
        name: "bwd_dwih_t",
        m: 5,
        n: 512,
        k: 1280,
        a_transposed: true,
    },
    // TCN-LSTM backward: dX = dG·W_ih, the gradient handed to the TCN.
    Shape {
        name: "bwd_dx",
        m: 1280,
        n: 5,
        k: 512,
        a_transposed: false,
    },
    // Head fc.0 (128 → 64): forward, weight gradient, input gradient.
    Shape {
        name: "head_fwd",
        m: 16,
        n: 64,
        k: 128,
        a_transposed: false,
    },
    Shape {
        name: "head_dw",
        m: 64,
        n: 128,
        k: 16,
        a_transposed: true,
    },
    Shape {
        name: "head_dx",
        m: 16,
        n: 128,
        k: 64,
        a_transposed: false,
    },
];

type Gemm = fn(usize, usize, usize, StridedA<'_>, &[f32], usize, &mut [f32], usize);

fn kernels() -> Vec<(&'static str, Gemm)> {
    #[allow(unused_mut)]
    let mut v: Vec<(&'static str, Gemm)> = vec![("hand", gemm_acc as Gemm)];
    #[cfg(feature = "faer")]
    v.push(("faer", bowden_learning::kernels::gemm::gemm_acc_faer as Gemm));
    v
}

fn gemm_shapes(c: &mut Criterion) {
    let mut group = c.benchmark_group("gemm_lstm_shard16");
    for s in SHAPES {
        let a: Vec<f32> = (0..s.m * s.k).map(|i| ((i % 13) as f32 - 6.0) * 0.01).collect();
        let b: Vec<f32> = (0..s.k * s.n).map(|i| ((i % 7) as f32 - 3.0) * 0.01).collect();
        let mut out = vec![0.0f32; s.m * s.n];
        let (rs, cs) = if s.a_transposed { (1, s.m) } else { (s.k, 1) };
        group.throughput(Throughput::Elements((s.m * s.n * s.k) as u64));
        for (which, f) in kernels() {
            let id = BenchmarkId::new(which, format!("{}_{}x{}x{}", s.name, s.m, s.n, s.k));
            group.bench_function(id, |bch| {
                bch.iter(|| {
                    f(s.m, s.n, s.k, StridedA { data: &a, rs, cs }, &b, s.n, &mut out, s.n);
                })
            });
        }
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(std::time::Duration::from_millis(500))
        .measurement_time(std::time::Duration::from_secs(2));
    targets = gemm_shapes
}
criterion_main!(benches);
