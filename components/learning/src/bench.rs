//! `bowden bench train`: seconds per training epoch on the paper's training-set size
//! (24,565 windows of L = 80, batch 32, J = 5), on synthetic hysteretic data, so the number
//! compares with PyTorch's on the same machine. `--pytorch PYTHON` times PyTorch's epoch of
//! the same networks and shapes in the same run (the script is `benches/pytorch_epoch.py`
//! of this crate, embedded); without it the figures of the machine are quoted
//! (2 threads: 3.65 s TCN, 6.4 s LSTM), marked as such.
//!
//! The LSTM epoch is bound by arithmetic: ≈ 16 M multiply-adds per window (h·W_hhᵀ, dg·W_hh
//! and dW_hh at 79 steps × 128 × 512 each, plus the input projections and the head), 3.9·10¹¹
//! per epoch. On the Zen 5 guest of 2026-11-27 (f32 FMA peak 132 G/s per core measured with
//! 12 independent accumulators; the GEMM runs at 122–126 G/s at these shapes) two cores need
//! ≈ 1.55 s for the products alone, against 1.97 s for 3× PyTorch's 5.9 s there: f32 cannot
//! get there with the cells, the head and Adam on top. `precision = bf16` runs those three
//! products with bf16 operands and f32 sums ([`crate::kernels::bf16`], 2× the f32 rate).

use serde::{Deserialize, Serialize};

use crate::arch::{Architecture, Direction, ModelSpec, TcnBlock};
use crate::kernels::Precision;
use crate::synthetic::hysteretic_dataset;
use crate::train::{time_epoch, Backend, TrainConfig, TrainError};
use crate::windows::{PhySource, SplitConfig, WindowSet};

/// The paper's training windows (80 % of 30,707).
pub const PAPER_TRAIN_WINDOWS: usize = 24_565;

/// PyTorch 2.15, 2 threads, seconds per epoch on the machine issue #15 was measured on (not
/// this one necessarily: `--pytorch` measures here).
pub fn pytorch_reference_seconds(arch: Architecture) -> Option<f64> {
    match arch {
        Architecture::Tcn => Some(3.65),
        Architecture::Lstm => Some(6.4),
        _ => None,
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchOptions {
    pub arch: Architecture,
    pub seq_len: usize,
    pub windows: usize,
    pub batch_size: usize,
    pub epochs: usize,
    pub threads: usize,
    pub backend: Backend,
    pub tcn_block: TcnBlock,
    #[serde(default)]
    pub precision: Precision,
}

impl BenchOptions {
    pub fn paper(arch: Architecture) -> Self {
        Self {
            arch,
            seq_len: 80,
            windows: PAPER_TRAIN_WINDOWS,
            batch_size: 32,
            epochs: 3,
            threads: 2,
            backend: Backend::Fused,
            tcn_block: TcnBlock::ReluLinear,
            precision: Precision::F32,
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
    /// PyTorch's f32 epoch: measured in this run (`pytorch_measured`) or the figure.
    pub pytorch_seconds: Option<f64>,
    #[serde(default)]
    pub pytorch_measured: bool,
    /// PyTorch's time / ours (> 1 = faster than PyTorch).
    pub speedup_vs_pytorch: Option<f64>,
    /// With `precision = bf16` and `--pytorch`: PyTorch's epoch under
    /// `autocast(bfloat16)`, measured in this run, and its time / ours.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pytorch_bf16_seconds: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub speedup_vs_pytorch_bf16: Option<f64>,
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
    cfg.precision = opts.precision;
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
        pytorch_measured: false,
        speedup_vs_pytorch: pytorch.map(|p| p / median),
        pytorch_bf16_seconds: None,
        speedup_vs_pytorch_bf16: None,
        simd: {
            let base = if crate::kernels::simd::has_avx512() {
                "avx512"
            } else {
                "portable"
            };
            match opts.precision {
                Precision::F32 => base.into(),
                // Without the instruction the bf16 products run the (slow) portable loop.
                Precision::Bf16 if crate::kernels::bf16::has_avx512_bf16() => format!("{base}+bf16"),
                Precision::Bf16 => format!("{base}, bf16 products portable (no AVX-512 BF16)"),
            }
        },
    })
}

/// PyTorch's side of the comparison, as a Python script (`benches/pytorch_epoch.py`).
pub const PYTORCH_EPOCH_SCRIPT: &str = include_str!("../benches/pytorch_epoch.py");

/// Why PyTorch's epoch could not be timed.
#[derive(Debug, thiserror::Error)]
pub enum PytorchError {
    #[error("{python}: {source}")]
    Spawn { python: String, source: std::io::Error },
    #[error("{python} {script} exited with {status}: {stderr}")]
    Failed {
        python: String,
        script: String,
        status: std::process::ExitStatus,
        stderr: String,
    },
    #[error("{script} printed no JSON result line with median_seconds: {stdout}")]
    NoResult { script: String, stdout: String },
    #[error("writing the script to {path}: {source}")]
    Write { path: String, source: std::io::Error },
}

/// Times PyTorch's epoch for `opts` (f32, or autocast bf16 when `bf16`) with the Python
/// interpreter `python`, which must have torch: median seconds of `opts.epochs` epochs.
pub fn pytorch_epoch_seconds(python: &std::path::Path, opts: &BenchOptions, bf16: bool) -> Result<f64, PytorchError> {
    let arch = match opts.arch {
        Architecture::Lstm => "lstm",
        Architecture::Tcn => "tcn",
        other => {
            return Err(PytorchError::NoResult {
                script: "pytorch_epoch.py".into(),
                stdout: format!("no PyTorch twin for {other}"),
            })
        }
    };
    let dir = std::env::temp_dir().join(format!("bowden-pytorch-{}", std::process::id()));
    let script = dir.join("pytorch_epoch.py");
    let write = std::fs::create_dir_all(&dir).and_then(|_| std::fs::write(&script, PYTORCH_EPOCH_SCRIPT));
    write.map_err(|source| PytorchError::Write {
        path: script.display().to_string(),
        source,
    })?;
    let mut cmd = std::process::Command::new(python);
    cmd.arg(&script)
        .args(["--arch", arch])
        .args(["--threads", &opts.threads.to_string()])
        .args(["--windows", &opts.windows.to_string()])
        .args(["--seq-len", &opts.seq_len.to_string()])
        .args(["--batch", &opts.batch_size.to_string()])
        .args(["--epochs", &opts.epochs.max(1).to_string()]);
    if bf16 {
        cmd.arg("--bf16");
    }
    let out = cmd.output();
    let _ = std::fs::remove_dir_all(&dir);
    let out = out.map_err(|source| PytorchError::Spawn {
        python: python.display().to_string(),
        source,
    })?;
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(3).collect();
        return Err(PytorchError::Failed {
            python: python.display().to_string(),
            script: "pytorch_epoch.py".into(),
            status: out.status,
            stderr: tail.into_iter().rev().collect::<Vec<_>>().join(" | "),
        });
    }
    stdout
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .and_then(|v| v.get("median_seconds")?.as_f64())
        .ok_or(PytorchError::NoResult {
            script: "pytorch_epoch.py".into(),
            stdout,
        })
}

impl BenchResult {
    /// Replaces the quoted PyTorch figure by one measured in this run (and, for a bf16 run,
    /// adds PyTorch's own bf16 epoch).
    pub fn set_pytorch_measured(&mut self, f32_seconds: f64, bf16_seconds: Option<f64>) {
        self.pytorch_seconds = Some(f32_seconds);
        self.pytorch_measured = true;
        self.speedup_vs_pytorch = Some(f32_seconds / self.median_seconds);
        self.pytorch_bf16_seconds = bf16_seconds;
        self.speedup_vs_pytorch_bf16 = bf16_seconds.map(|p| p / self.median_seconds);
    }
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
