//! Micro-timings of the GEMM shapes of an LSTM training step (diagnostics).
use bowden_learning::kernels::gemm::{gemm_acc, StridedA};
use std::time::Instant;

fn time(name: &str, m: usize, n: usize, k: usize, rs: usize, cs: usize, reps: usize) {
    let a = vec![0.5f32; m * k];
    let b = vec![0.25f32; k * n];
    let mut c = vec![0.0f32; m * n];
    let av = StridedA { data: &a, rs, cs };
    gemm_acc(m, n, k, av, &b, n, &mut c, n);
    let t0 = Instant::now();
    for _ in 0..reps {
        gemm_acc(m, n, k, av, &b, n, &mut c, n);
    }
    let s = t0.elapsed().as_secs_f64();
    let gmac = (m * n * k * reps) as f64 / s / 1e9;
    println!(
        "{name:24} {m}x{n}x{k}: {:.2} us/call, {gmac:.1} GMAC/s",
        s / reps as f64 * 1e6
    );
}

fn main() {
    time("fwd h·Rt", 16, 512, 128, 128, 1, 20000);
    time("bwd dg·W", 16, 128, 512, 512, 1, 20000);
    time("dRt Hᵀ·dG", 128, 512, 1264, 1, 128, 200);
    time("xproj", 1280, 512, 5, 5, 1, 2000);
    time("dWt Xᵀ·dG", 5, 512, 1280, 1, 5, 2000);
    time("dx dG·W", 1280, 5, 512, 512, 1, 200);
    lstm_parts();
    sigmoid_speed();
}

pub fn lstm_parts() {
    use bowden_learning::arch::{Arch, ModelSpec, TcnBlock};
    use bowden_learning::kernels::lstm::{self, LstmDims, LstmGrads, LstmParamIdx, LstmPrepared, LstmWork};
    let spec = ModelSpec::new(Arch::Lstm, 80, 5, TcnBlock::ReluLinear);
    let layout = spec.layout();
    let params = spec.init_params(1);
    let idx = LstmParamIdx {
        w_ih: layout.range("lstm.weight_ih_l0").start,
        w_hh: layout.range("lstm.weight_hh_l0").start,
        b_ih: layout.range("lstm.bias_ih_l0").start,
        b_hh: layout.range("lstm.bias_hh_l0").start,
    };
    let d = LstmDims { t: 80, j: 5, h: 128 };
    let b = 16;
    let mut prep = LstmPrepared::default();
    prep.prepare(&d, &params, &idx);
    let mut work = LstmWork::new(&d, b);
    for (i, v) in work.xt.iter_mut().enumerate() {
        *v = ((i % 7) as f32 - 3.0) * 0.3;
    }
    let reps = 50;
    let t0 = Instant::now();
    for _ in 0..reps {
        lstm::forward(&d, &prep, b, &mut work);
    }
    println!(
        "lstm forward b=16: {:.3} ms",
        t0.elapsed().as_secs_f64() / reps as f64 * 1e3
    );
    let mut grad = vec![0.0f32; layout.total];
    let dh = vec![0.01f32; b * 128];
    let t0 = Instant::now();
    for _ in 0..reps {
        let (lo, hi) = grad.split_at_mut(idx.w_hh);
        let (w_hh, hi) = hi.split_at_mut(idx.b_ih - idx.w_hh);
        let (b_ih, b_hh) = hi.split_at_mut(idx.b_hh - idx.b_ih);
        lstm::backward(
            &d,
            &params,
            &idx,
            b,
            &dh,
            &mut work,
            LstmGrads {
                w_ih: &mut lo[idx.w_ih..idx.w_ih + 512 * 5],
                w_hh,
                b_ih,
                b_hh: &mut b_hh[..512],
            },
            false,
        );
    }
    println!(
        "lstm backward b=16: {:.3} ms",
        t0.elapsed().as_secs_f64() / reps as f64 * 1e3
    );
}

pub fn sigmoid_speed() {
    use bowden_learning::kernels::simd::sigmoid_f32;
    let mut v: Vec<f32> = (0..2048).map(|i| (i as f32 - 1024.0) * 0.01).collect();
    #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
    unsafe fn run(v: &mut [f32]) {
        for x in v.iter_mut() {
            *x = sigmoid_f32(*x) - 0.5;
        }
    }
    let reps = 20000;
    let t0 = Instant::now();
    for _ in 0..reps {
        unsafe { run(&mut v) };
    }
    let s = t0.elapsed().as_secs_f64();
    println!("sigmoid: {:.3} ns/elem ({})", s / (reps * 2048) as f64 * 1e9, v[7]);
}
