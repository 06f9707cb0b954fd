//! `bowden bench train`: seconds per training epoch on the paper's training-set size
//! (24,565 windows of L = 80, batch 32, J = 5), on synthetic hysteretic data, so the number
//! compares with PyTorch's on the same machine (2 threads: 3.65 s TCN, 6.4 s LSTM).
//!
//! The LSTM epoch is bound by arithmetic: ≈ 16 M multiply-adds per window (h·W_hhᵀ, dg·W_hh
//! and dW_hh at 79 steps × 128 × 512 each, plus the input projections and the head), 3.9·10¹¹
//! per epoch. At this CPU's measured f32 FMA peak (≈ 58 G/s per core) two cores need 3.4 s for
//! the products alone, so 3× PyTorch (2.13 s) is out of reach in f32; the GEMM already runs
//! at ≈ 90 % of that peak ([`crate::kernels::gemm`]).

use serde::{Deserialize, Serialize};

use crate::arch::{Arch, Direction, ModelSpec, TcnBlock};
use crate::synthetic::hysteretic_dataset;
use crate::train::{time_epoch, Backend, TrainConfig, TrainError};
use crate::windows::{PhySource, SplitConfig, WindowSet};

/// The paper's training windows (80 % of 30,707).
pub const PAPER_TRAIN_WINDOWS: usize = 24_565;

/// PyTorch 2.15 on this CPU, 2 threads, seconds per epoch (the reference).
pub fn pytorch_reference_seconds(arch: Arch) -> Option<f64> {
    match arch {
        Arch::Tcn => Some(3.65),
        Arch::Lstm => Some(6.4),
        _ => None,
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchOptions {
    pub arch: Arch,
    pub seq_len: usize,
    pub windows: usize,
    pub batch_size: usize,
    pub epochs: usize,
    pub threads: usize,
    pub backend: Backend,
    pub tcn_block: TcnBlock,
}

impl BenchOptions {
    pub fn paper(arch: Arch) -> Self {
        Self {
            arch,
            seq_len: 80,
            windows: PAPER_TRAIN_WINDOWS,
            batch_size: 32,
            epochs: 3,
            threads: 2,
            backend: Backend::Fused,
            tcn_block: TcnBlock::ReluLinear,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchResult {
    pub options: BenchOptions,
    pub params: usize,
    pub batches_per_epoch: usize,
    /// Wall-clock seconds, one entry per measured epoch.
    pub epoch_seconds: Vec<f64>,
    /// Process CPU seconds (all threads) per epoch: on a machine shared with other work,
    /// CPU / threads is what the epoch would take with the cores to itself.
    pub epoch_cpu_seconds: Vec<f64>,
    /// 1-minute load average when the benchmark ended (other work competing for the cores).
    pub load_average_1min: Option<f64>,
    pub min_seconds: f64,
    pub median_seconds: f64,
    pub pytorch_seconds: Option<f64>,
    /// PyTorch's time / ours (> 1 = faster than PyTorch).
    pub speedup_vs_pytorch: Option<f64>,
    pub simd: String,
}

/// The synthetic training windows of a benchmark: `windows` windows of length `seq_len`,
/// J = 5.
pub fn bench_windows(seq_len: usize, windows: usize) -> Result<WindowSet, TrainError> {
    let n = (windows as f64 / 0.78) as usize + seq_len;
    let ds = hysteretic_dataset(n, 5, 1);
    let mut data = WindowSet::build(
        &ds,
        Direction::Forward,
        seq_len,
        SplitConfig::default(),
        PhySource::Vision,
    )
    .map_err(|e| TrainError::Config(e.to_string()))?;
    if data.train.len() < windows {
        return Err(TrainError::Config(format!(
            "synthetic data gave {} windows, {windows} wanted",
            data.train.len()
        )));
    }
    data.train.truncate(windows);
    Ok(data)
}

/// Times `epochs` training epochs (each over `windows` windows, after a warm-up of a few
/// batches).
pub fn bench_train(opts: &BenchOptions) -> Result<BenchResult, TrainError> {
    let j = 5;
    let data = bench_windows(opts.seq_len, opts.windows)?;
    let mut cfg = TrainConfig::paper(opts.arch, Direction::Forward, opts.seq_len, 1, 1);
    cfg.batch_size = opts.batch_size;
    cfg.threads = opts.threads;
    cfg.backend = opts.backend;
    cfg.tcn_block = opts.tcn_block;
    let mut secs = Vec::with_capacity(opts.epochs);
    let mut cpu = Vec::with_capacity(opts.epochs);
    for e in 0..opts.epochs.max(1) {
        let (w, c) = time_epoch(&data, &cfg, if e == 0 { 8 } else { 0 })?;
        secs.push(w);
        cpu.push(c);
    }
    let mut sorted = secs.clone();
    sorted.sort_by(f64::total_cmp);
    let min = sorted[0];
    let median = sorted[sorted.len() / 2];
    let pytorch = if opts.seq_len == 80 && opts.batch_size == 32 {
        pytorch_reference_seconds(opts.arch)
    } else {
        None
    };
    Ok(BenchResult {
        options: opts.clone(),
        params: ModelSpec::new(opts.arch, opts.seq_len, j, opts.tcn_block).param_count(),
        batches_per_epoch: opts.windows.div_ceil(opts.batch_size),
        epoch_seconds: secs,
        epoch_cpu_seconds: cpu,
        load_average_1min: load_average(),
        min_seconds: min,
        median_seconds: median,
        pytorch_seconds: pytorch,
        speedup_vs_pytorch: pytorch.map(|p| p / median),
        simd: if crate::kernels::simd::has_avx512() {
            "avx512".into()
        } else {
            "portable".into()
        },
    })
}

/// The 1-minute load average (Linux), if readable.
pub fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}
