//! Micro-timings of the GEMM shapes of an LSTM training step (diagnostics).
use bowden_learning::kernels::gemm::{gemm_acc, StridedA};
use std::time::Instant;

type Gemm = fn(usize, usize, usize, StridedA<'_>, &[f32], usize, &mut [f32], usize);

/// The hand-written GEMM on one shape, and faer's beside it when built with `--features faer`:
/// rounds alternate between them and the best round of each is kept (other work on a shared
/// machine only ever adds time, so the minimum is what compares).
fn time(name: &str, m: usize, n: usize, k: usize, rs: usize, cs: usize, reps: usize) {
    #[allow(unused_mut)]
    let mut kernels: Vec<(&str, Gemm)> = vec![("hand", gemm_acc as Gemm)];
    #[cfg(feature = "faer")]
    kernels.push(("faer", bowden_learning::kernels::gemm::gemm_acc_faer as Gemm));
    let a: Vec<f32> = (0..m * k).map(|i| ((i % 13) as f32 - 6.0) * 0.01).collect();
    let b: Vec<f32> = (0..k * n).map(|i| ((i % 7) as f32 - 3.0) * 0.01).collect();
    let av = StridedA { data: &a, rs, cs };
    let mut c = vec![0.0f32; m * n];
    let mut best = vec![f64::INFINITY; kernels.len()];
    for _round in 0..15 {
        for (w, (_, f)) in kernels.iter().enumerate() {
            f(m, n, k, av, &b, n, &mut c, n);
            let t0 = Instant::now();
            for _ in 0..reps / 10 {
                f(m, n, k, av, &b, n, &mut c, n);
            }
            best[w] = best[w].min(t0.elapsed().as_secs_f64() / (reps / 10) as f64);
        }
    }
    let mut line = format!("{name:24} {m}x{n}x{k}:");
    for ((which, _), t) in kernels.iter().zip(&best) {
        line += &format!("  {which} {:.2} us {:.1} GMAC/s", t * 1e6, (m * n * k) as f64 / t / 1e9);
    }
    if best.len() == 2 {
        line += &format!("  faer/hand time {:.2}", best[1] / best[0]);
    }
    println!("{line}");
}

fn main() {
    if std::env::args().any(|a| a == "--hash") {
        // Bits of a short LSTM / TCN-LSTM training, to compare kernel versions.
        use bowden_learning::{train, Architecture, Direction, TrainConfig};
        let data = bowden_learning::bench::bench_windows(80, 640).expect("windows");
        for arch in [Architecture::Lstm, Architecture::TcnLstm] {
            let mut cfg = TrainConfig::paper(arch, Direction::Forward, 80, 2, 3);
            cfg.threads = 2;
            let out = train(&data, &cfg, None).expect("train");
            let mut hsh = 0xcbf2_9ce4_8422_2325u64;
            for p in &out.model.params {
                hsh = (hsh ^ p.to_bits() as u64).wrapping_mul(0x100_0000_01b3);
            }
            println!("{arch}: params hash {hsh:016x}, val loss {:e}", out.epochs[1].val_loss);
        }
        return;
    }
    if let Some(arch) = std::env::args().skip_while(|a| a != "--epoch").nth(1) {
        // The function behind `bowden bench train`, for A/B runs of the kernels alone.
        let mut o = bowden_learning::bench::BenchOptions::paper(arch.parse().expect("arch"));
        o.epochs = 3;
        if let Ok(t) = std::env::var("KT_THREADS") {
            o.threads = t.parse().expect("threads");
        }
        let r = bowden_learning::bench::bench_train(&o).expect("bench");
        println!(
            "{arch}: median {:.3} s/epoch, wall {:?}, CPU {:?}, load {:?}",
            r.median_seconds, r.epoch_seconds, r.epoch_cpu_seconds, r.load_average_1min
        );
        return;
    }
    time("fwd h·Rt", 16, 512, 128, 128, 1, 20000);
    time("bwd dg·W", 16, 128, 512, 512, 1, 20000);
    time("dWhh dGᵀ·H", 512, 128, 1264, 1, 512, 200);
    time("xproj", 1280, 512, 5, 5, 1, 2000);
    time("head fc.0", 16, 64, 128, 128, 1, 20000);
    time("head dW fc.0", 64, 128, 16, 1, 64, 20000);
    time("dWt Xᵀ·dG", 5, 512, 1280, 1, 5, 2000);
    time("dx dG·W", 1280, 5, 512, 512, 1, 200);
    lstm_parts();
    sigmoid_speed();
}

pub fn lstm_parts() {
    use bowden_learning::arch::{Architecture, ModelSpec, TcnBlock};
    use bowden_learning::kernels::lstm::{self, LstmDims, LstmGrads, LstmParamIdx, LstmPrepared, LstmWork};
    let spec = ModelSpec::new(Architecture::Lstm, 80, 5, TcnBlock::ReluLinear);
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
    for mixed in [false, true] {
        let mut prep = LstmPrepared::default();
        prep.prepare(&d, &params, &idx, mixed);
        let mut work = LstmWork::new(&d, b);
        for (i, v) in work.xt.iter_mut().enumerate() {
            *v = ((i % 7) as f32 - 3.0) * 0.3;
        }
        // Best of 10 rounds of 5 (a shared machine's noise only ever adds time).
        let mut best_f = f64::INFINITY;
        let mut best_b = f64::INFINITY;
        let mut grad = vec![0.0f32; layout.total];
        let dh = vec![0.01f32; b * 128];
        for _round in 0..10 {
            let t0 = Instant::now();
            for _ in 0..5 {
                lstm::forward(&d, &prep, b, &mut work, mixed);
            }
            best_f = best_f.min(t0.elapsed().as_secs_f64() / 5.0);
            let t0 = Instant::now();
            for _ in 0..5 {
                grad.fill(0.0);
                let (lo, hi) = grad.split_at_mut(idx.w_hh);
                let (w_hh, hi) = hi.split_at_mut(idx.b_ih - idx.w_hh);
                let (b_ih, b_hh) = hi.split_at_mut(idx.b_hh - idx.b_ih);
                lstm::backward(
                    &d,
                    &params,
                    &idx,
                    &prep,
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
                    mixed,
                );
            }
            best_b = best_b.min(t0.elapsed().as_secs_f64() / 5.0);
        }
        println!(
            "lstm {} forward b=16: {:.3} ms, backward {:.3} ms (best of 10)",
            if mixed { "bf16" } else { "f32" },
            best_f * 1e3,
            best_b * 1e3
        );
        let t0 = Instant::now();
        for _ in 0..200 {
            prep.prepare(&d, &params, &idx, mixed);
        }
        println!(
            "prepare (W transposes{}): {:.1} us",
            if mixed { ", bf16 packs" } else { "" },
            t0.elapsed().as_secs_f64() / 200.0 * 1e6
        );
    }
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
