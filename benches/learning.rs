//! Training-step throughput of the fused kernels: one batch of 32 windows (L = 80, J = 5)
//! forward + backward + Adam, for the TCN and the LSTM, on 1 and 2 threads. An epoch of the
//! paper's 24,565 windows is 768 such batches (`bowden bench train` times whole epochs).

use bowden_learning::bench::bench_windows;
use bowden_learning::train::{Stepper, TrainConfig};
use bowden_learning::{Architecture, Direction};
use criterion::{criterion_group, criterion_main, Criterion};

fn train_step(c: &mut Criterion) {
    let data = bench_windows(80, 4096).expect("synthetic windows");
    let mut group = c.benchmark_group("train_step_batch32_L80");
    for arch in [
        Architecture::Tcn,
        Architecture::Lstm,
        Architecture::Fnn,
        Architecture::TcnLstm,
    ] {
        for threads in [1, 2] {
            let mut cfg = TrainConfig::paper(arch, Direction::Forward, 80, 1, 0);
            cfg.threads = threads;
            let mut stepper = Stepper::new(5, &cfg).expect("model");
            let mut batch = 0usize;
            let n_batches = data.train.len() / 32;
            group.bench_function(format!("{}_{}t", arch.as_str(), threads), |b| {
                b.iter(|| {
                    let ids = &data.train[batch * 32..(batch + 1) * 32];
                    batch = (batch + 1) % n_batches;
                    stepper.step(&data, ids).expect("step")
                })
            });
        }
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(std::time::Duration::from_secs(4));
    targets = train_step
}
criterion_main!(benches);
