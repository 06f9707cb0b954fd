//! `bowden bench train`: a thin wrapper over `bowden_learning::bench`.

use anyhow::{Context, Result};
use bowden_learning::bench::{bench_train, BenchOptions};
use bowden_learning::{Architecture, Backend, Precision};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Seconds per training epoch: 24,565 windows of L = 80, batch 32, J = 5 (synthetic
    /// data), against PyTorch's epoch timed in the same run (--pytorch PYTHON) or else a
    /// reference figure from another machine, marked as such (docs/results/train-speed).
    Train(BenchTrainArgs),
}

#[derive(Args, Debug)]
pub struct BenchTrainArgs {
    /// Architectures (comma-separated); default: tcn and lstm.
    #[arg(long, value_delimiter = ',', value_parser = super::typed::<Architecture>(), ignore_case = true)]
    arch: Vec<Architecture>,
    /// Epochs timed (the median is reported).
    #[arg(long, default_value_t = 3)]
    epochs: usize,
    /// Worker threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// fused (hand-written kernels) or candle (autograd reference).
    #[arg(long, default_value = "fused", value_parser = super::typed::<Backend>(), ignore_case = true)]
    backend: Backend,
    /// Windows per epoch (default: the paper's 24,565).
    #[arg(long, default_value_t = bowden_learning::bench::PAPER_TRAIN_WINDOWS)]
    windows: usize,
    /// Input sequence length L.
    #[arg(long, default_value_t = 80)]
    seq_len: usize,
    /// f32, or bf16 (mixed precision for the LSTM's recurrent products).
    #[arg(long, default_value = "f32", value_parser = super::typed::<Precision>(), ignore_case = true)]
    precision: Precision,
    /// A Python interpreter with torch: times PyTorch's epoch of the same networks and
    /// shapes in this run, just before bowden's (with bf16 also under autocast(bfloat16)).
    #[arg(long)]
    pytorch: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

pub fn bench(c: BenchCommand) -> Result<()> {
    match c {
        BenchCommand::Train(a) => {
            let archs: Vec<Architecture> = match a.arch.as_slice() {
                [] => vec![Architecture::Tcn, Architecture::Lstm],
                some => some.to_vec(),
            };
            let (backend, precision) = (a.backend, a.precision);
            let mut results = Vec::new();
            for arch in archs {
                let mut o = BenchOptions::paper(arch);
                o.epochs = a.epochs;
                o.threads = a.threads;
                o.backend = backend;
                o.windows = a.windows;
                o.seq_len = a.seq_len;
                o.precision = precision;
                // PyTorch first, then bowden, back to back on the same machine.
                let torch = match &a.pytorch {
                    Some(python) => {
                        let bf16 = precision == Precision::Bf16;
                        let f = bowden_learning::bench::pytorch_epoch_seconds(python, &o, false)
                            .with_context(|| format!("--pytorch: timing PyTorch's {arch} epoch"))?;
                        let b = if bf16 {
                            Some(
                                bowden_learning::bench::pytorch_epoch_seconds(python, &o, true)
                                    .with_context(|| format!("--pytorch: timing PyTorch's bf16 {arch} epoch"))?,
                            )
                        } else {
                            None
                        };
                        Some((f, b))
                    }
                    None => None,
                };
                let mut r = bench_train(&o).with_context(|| format!("bench train --arch {arch}"))?;
                if let Some((f, b)) = torch {
                    r.set_pytorch_measured(f, b);
                }
                if !a.json {
                    let round = |v: &[f64]| v.iter().map(|s| (s * 1000.0).round() / 1000.0).collect::<Vec<_>>();
                    println!(
                        "{:8} {:6} {} L={} {} windows, batch {}, {} thread(s), {}: {:.3} s/epoch median, {:.3} min, \
                         wall {:?} s, CPU {:?} s, load avg {}{}{}",
                        arch.as_str(),
                        format!("{backend:?}").to_lowercase(),
                        precision,
                        o.seq_len,
                        o.windows,
                        o.batch_size,
                        o.threads,
                        r.simd,
                        r.median_seconds,
                        r.min_seconds,
                        round(&r.epoch_seconds),
                        round(&r.epoch_cpu_seconds),
                        r.load_average_1min.map_or("?".into(), |l| format!("{l:.2}")),
                        match (r.pytorch_seconds, r.speedup_vs_pytorch) {
                            (Some(p), Some(s)) if r.pytorch_measured => format!(
                                "; PyTorch f32 ({} threads, measured in this run) {p:.3} s/epoch → {s:.2}× its speed",
                                o.threads
                            ),
                            (Some(p), Some(s)) => format!(
                                "; PyTorch f32 (2 threads, the issue's machine; --pytorch measures here) {p} s/epoch → \
                                 {s:.2}× its speed"
                            ),
                            _ => String::new(),
                        },
                        match (r.pytorch_bf16_seconds, r.speedup_vs_pytorch_bf16) {
                            (Some(p), Some(s)) => format!("; PyTorch autocast bf16 {p:.3} s/epoch → {s:.2}×"),
                            _ => String::new(),
                        }
                    );
                }
                results.push(r);
            }
            if a.json {
                println!("{}", serde_json::to_string_pretty(&results)?);
            }
            Ok(())
        }
    }
}
