//! `bowden train`, `bowden sweep`, `bowden import` and `bowden bench train`: thin wrappers
//! over `bowden-learning`.

use anyhow::{bail, Context, Result};
use bowden_learning::dataset::{import_csv, import_npy, AngleUnit, ImportOptions};
use bowden_learning::report::train_to_files;
use bowden_learning::spacing::DecimationRule;
use bowden_learning::{Architecture, Backend, Direction, PhySource, Precision, SplitConfig, TcnBlock, TrainConfig};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

// The spellings are the model contract's (bowden_interfaces::model), listed from the enums.

#[derive(Subcommand)]
pub enum Command {
    /// Train one model (paper §IV-C: Adam 1e-3, batch 32, MSE, 80/20 contiguous split, best
    /// epoch on validation RMSE) and export it as ONNX with a JSON report and a loss plot.
    Train(TrainArgs),
    /// The paper's Fig. 10 study: every (architecture, L, direction) over several seeds, in
    /// parallel, resumable; mean ± SD of the best validation RMSE as Markdown, JSON and SVG.
    Sweep(super::sweep::SweepArgs),
    /// Import an external log (CSV with named columns, or a pair of .npy arrays) as a
    /// bowden dataset directory.
    Import(ImportArgs),
    /// Record the support of a model's training data (command range, largest step, largest
    /// command-to-physical gap) in its metadata, for models trained before `train` wrote it.
    /// Only metadata changes; the graph and weights stay byte for byte.
    StampSupport(StampSupportArgs),
    /// Score trained models on a dataset: RMSE and MAE per joint and pooled, against identity
    /// (the raw hysteresis), in degrees, on `train`'s validation windows — the split, angle
    /// source and decimation of each model's training report (NAME.report.json) when it has
    /// one, else the flags — so the RMSE is `train`'s figure exactly. A table, JSON and, with
    /// --plots, predicted against measured over time.
    Score(ScoreArgs),
}

#[derive(Args, Debug)]
pub struct ScoreArgs {
    /// Dataset directory (dataset.csv + manifest.json).
    #[arg(long)]
    data: PathBuf,
    /// Model files (ONNX), forward or inverse (their metadata says which windows are theirs).
    #[arg(required = true)]
    models: Vec<PathBuf>,
    /// Use the split flags below even where a model has a training report.
    #[arg(long)]
    ignore_report: bool,
    #[command(flatten)]
    split: SplitArgs,
    /// Largest history decimation of the windows (as `train --decimation`), when no report says.
    #[arg(long, default_value_t = 1)]
    decimation: usize,
    /// Write NAME.score.svg per model into this directory.
    #[arg(long, value_name = "DIR")]
    plots: Option<PathBuf>,
    /// Print the scores as JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Also write the scores as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    json_out: Option<PathBuf>,
    /// Overwrite --json-out and plots if they exist.
    #[arg(long)]
    force: bool,
}

#[derive(Args, Debug)]
pub struct StampSupportArgs {
    /// Dataset directory the models were trained on (dataset.csv + manifest.json).
    #[arg(long)]
    data: PathBuf,
    /// Model files to stamp in place (their direction and L say which windows are theirs).
    #[arg(required = true)]
    models: Vec<PathBuf>,
    #[command(flatten)]
    split: SplitArgs,
}

#[derive(Args, Debug, Clone)]
pub struct SplitArgs {
    /// Fraction of samples in validation.
    #[arg(long, default_value_t = 0.2)]
    val_fraction: f64,
    /// Contiguous validation blocks (1 = the last 20 % of the sequence).
    #[arg(long, default_value_t = 1)]
    val_blocks: usize,
    /// Physical angles from the vision estimate (as the paper) or the simulator's truth.
    #[arg(long, default_value = "vision", value_parser = super::typed::<PhySource>(), ignore_case = true)]
    phy_source: PhySource,
}

impl SplitArgs {
    pub(super) fn parse(&self) -> Result<(SplitConfig, PhySource)> {
        let phy = self.phy_source;
        Ok((
            SplitConfig {
                val_fraction: self.val_fraction,
                val_blocks: self.val_blocks,
            },
            phy,
        ))
    }
}

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// Architecture.
    #[arg(long, value_parser = super::typed::<Architecture>(), ignore_case = true)]
    arch: Architecture,
    /// forward (q_cmd history → q_phy) or inverse (q_phy history → q_cmd).
    #[arg(long, value_parser = super::typed::<Direction>(), ignore_case = true)]
    direction: Direction,
    /// Input sequence length L.
    #[arg(long, default_value_t = 80)]
    seq_len: usize,
    /// Training epochs (the best on validation RMSE is kept).
    #[arg(long, default_value_t = 100)]
    epochs: usize,
    /// Seed of the weights' initialisation and the batch order.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Dataset directory (dataset.csv + manifest.json).
    #[arg(long)]
    data: PathBuf,
    /// Output model; NAME.report.json and NAME.loss.svg are written beside it. Existing files
    /// are kept unless --force.
    #[arg(long)]
    out: PathBuf,
    /// Overwrite the model, its report and plot if they exist.
    #[arg(long)]
    force: bool,
    /// relu-linear (ReLU between the convs only; default) or relu-relu (the paper literally).
    #[arg(long, default_value = "relu-linear", value_parser = super::typed::<TcnBlock>(), ignore_case = true)]
    tcn_block: TcnBlock,
    /// Stop after N epochs without a better validation RMSE.
    #[arg(long)]
    early_stop: Option<usize>,
    /// Mini-batch size.
    #[arg(long, default_value_t = 32)]
    batch_size: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// fused (hand-written kernels) or candle (autograd reference, slow).
    #[arg(long, default_value = "fused", value_parser = super::typed::<Backend>(), ignore_case = true)]
    backend: Backend,
    /// Worker threads (results do not depend on it).
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// f32, or bf16: the LSTM's recurrent products with bf16 operands and f32 sums (about
    /// twice as fast on CPUs with AVX-512 BF16; weights, validation and export stay f32).
    #[arg(long, default_value = "f32", value_parser = super::typed::<Precision>(), ignore_case = true)]
    precision: Precision,
    /// Train on histories decimated by up to N samples per model step as well (each window's
    /// decimation drawn from 1..=N every epoch; a decimated step never skips a reversal of the
    /// commands): the model learns the larger steps a compensator sends, which eq. (16) data
    /// never makes. 1 = consecutive samples only (the paper). auto: 4 when the training
    /// commands hold no step larger than their grid (eq. (16) data), else 1.
    #[arg(long, default_value = "auto")]
    decimation: DecimationRule,
    #[command(flatten)]
    split: SplitArgs,
}

#[derive(Args, Debug)]
pub struct ImportArgs {
    /// CSV log with a header.
    #[arg(long, conflicts_with_all = ["npy_cmd", "npy_phy"])]
    csv: Option<PathBuf>,
    /// Command array (N × J .npy).
    #[arg(long, requires = "npy_phy")]
    npy_cmd: Option<PathBuf>,
    /// Measured array (N × J .npy).
    #[arg(long, requires = "npy_cmd")]
    npy_phy: Option<PathBuf>,
    /// Output dataset directory; an existing dataset there is kept unless --force.
    #[arg(long)]
    out: PathBuf,
    /// Overwrite an existing dataset in --out.
    #[arg(long)]
    force: bool,
    /// Angle unit of the data: deg, or rad (converted to degrees).
    #[arg(long, default_value = "deg", value_parser = super::typed::<AngleUnit>(), ignore_case = true)]
    unit: AngleUnit,
    /// 1-based joints to keep, e.g. 1,2,3.
    #[arg(long)]
    joints: Option<String>,
    /// CSV command columns (default: q_cmd_1, q_cmd_2, ...).
    #[arg(long)]
    cmd_cols: Option<String>,
    /// CSV measured columns (default: q_phy_1, q_phy_2, ...).
    #[arg(long)]
    phy_cols: Option<String>,
    /// CSV timestamp column, ns (default t_ns if present).
    #[arg(long)]
    time_col: Option<String>,
    /// CSV validity column (default valid if present).
    #[arg(long)]
    valid_col: Option<String>,
    /// Sample period when the data has no timestamps, ns.
    #[arg(long, default_value_t = 500_000_000)]
    period_ns: i64,
}

pub(super) fn parse_usizes(s: &str, what: &str) -> Result<Vec<usize>> {
    s.split(',')
        .map(|p| p.trim())
        .filter(|p| !p.is_empty())
        .map(|p| {
            p.parse::<usize>()
                .with_context(|| format!("--{what}: {p:?} is not a positive integer"))
        })
        .collect()
}

fn epoch_bar() -> ProgressBar {
    let pb = ProgressBar::new(0);
    pb.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} epochs {elapsed_precise} ETA {eta} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Train(a) => {
            let (arch, direction) = (a.arch, a.direction);
            let mut cfg = TrainConfig::paper(arch, direction, a.seq_len, a.epochs, a.seed);
            cfg.tcn_block = a.tcn_block;
            cfg.early_stop = a.early_stop;
            cfg.batch_size = a.batch_size;
            cfg.lr = a.lr;
            cfg.backend = a.backend;
            cfg.threads = a.threads;
            cfg.precision = a.precision;
            let (split, phy) = a.split.parse()?;
            let data = super::dataset_dir("--data", &a.data)?;
            let (json, svg) = bowden_learning::report::sidecar_paths(&a.out);
            super::refuse_overwrite(&[a.out.clone(), json.clone(), svg.clone()], a.force, "--out")?;
            let pb = epoch_bar();
            pb.set_prefix(format!("{arch} {direction} L={}", a.seq_len));
            let report = train_to_files(data, &cfg, a.decimation, split, phy, &a.out, Some(&pb))
                .with_context(|| format!("training on {}", a.data.display()))?;
            pb.finish();
            if let Some(choice) = &report.decimation_auto {
                println!("{choice}");
            }
            println!(
                "{} {} L={} ({} params): best epoch {}/{}: validation RMSE {:.3}° (identity {:.3}°), per joint {:?}",
                arch,
                direction,
                a.seq_len,
                report.params,
                report.best_epoch,
                report.epochs_run,
                report.best_val_rmse_deg,
                report.identity_val_rmse_deg,
                report
                    .best_val_rmse_per_joint_deg
                    .iter()
                    .map(|v| (v * 1000.0).round() / 1000.0)
                    .collect::<Vec<_>>()
            );
            if let Some(x) = &report.export {
                println!(
                    "wrote {} (tract check: max |Δ| {:.2e}° over {} windows), {}, {}; {:.2} s/epoch",
                    a.out.display(),
                    x.max_abs_diff_deg,
                    x.windows_checked,
                    json.display(),
                    svg.display(),
                    report.mean_epoch_seconds
                );
            }
            Ok(())
        }
        Command::Sweep(a) => super::sweep::sweep(a),
        Command::Score(a) => score(a),
        Command::StampSupport(a) => {
            let (split, phy) = a.split.parse()?;
            super::dataset_dir("--data", &a.data)?;
            let (ds, _) =
                bowden_learning::Dataset::read_dir(&a.data).with_context(|| format!("--data {}", a.data.display()))?;
            for m in &a.models {
                let file = bowden_learning::ModelFile::load(m)?;
                let w = bowden_learning::WindowSet::build(&ds, file.direction, file.spec.seq_len, split, phy)
                    .with_context(|| format!("{}: windows of {}", m.display(), a.data.display()))?;
                let sup = bowden_learning::DataSupport::from_windows(&w);
                bowden_learning::support::stamp_file(m, &sup)?;
                println!(
                    "{}: command range {:?}..{:?} deg, largest step {:?}, largest gap {:?}",
                    m.display(),
                    sup.cmd_min_deg.iter().map(|v| v.round()).collect::<Vec<_>>(),
                    sup.cmd_max_deg.iter().map(|v| v.round()).collect::<Vec<_>>(),
                    sup.cmd_step_max_deg
                        .iter()
                        .map(|v| (v * 10.0).round() / 10.0)
                        .collect::<Vec<_>>(),
                    sup.gap_max_deg
                        .iter()
                        .map(|v| (v * 10.0).round() / 10.0)
                        .collect::<Vec<_>>()
                );
            }
            Ok(())
        }
        Command::Import(a) => {
            let unit = a.unit;
            super::dataset_out(&a.out, a.force)?;
            let opts = ImportOptions {
                unit,
                joints: a.joints.as_deref().map(|s| parse_usizes(s, "joints")).transpose()?,
                cmd_columns: a.cmd_cols.as_deref().map(split_names),
                phy_columns: a.phy_cols.as_deref().map(split_names),
                time_column: a.time_col.clone(),
                valid_column: a.valid_col.clone(),
                period_ns: a.period_ns,
            };
            let (ds, source, files) = match (&a.csv, &a.npy_cmd, &a.npy_phy) {
                (Some(csv), None, None) => (import_csv(csv, &opts)?, "import-csv", vec![csv.clone()]),
                (None, Some(c), Some(p)) => (import_npy(c, p, &opts)?, "import-npy", vec![c.clone(), p.clone()]),
                _ => bail!("give either --csv FILE or both --npy-cmd and --npy-phy"),
            };
            let provenance = serde_json::json!({
                "files": files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
                "options": opts,
            });
            let manifest = ds
                .write_dir(&a.out, source, None, None, provenance)
                .with_context(|| format!("writing {}", a.out.display()))?;
            println!(
                "wrote {}: {} samples ({} valid), {} joints",
                a.out.display(),
                manifest.samples,
                manifest.valid_samples,
                manifest.joints
            );
            Ok(())
        }
    }
}

fn split_names(s: &str) -> Vec<String> {
    s.split(',')
        .map(|p| p.trim().to_string())
        .filter(|p| !p.is_empty())
        .collect()
}

fn score(a: ScoreArgs) -> Result<()> {
    use bowden_learning::score::{self, ScoreSettings};
    let (split, phy) = a.split.parse()?;
    let data = super::dataset_dir("--data", &a.data)?;
    let plot_of = |m: &Path| -> Option<PathBuf> {
        let dir = a.plots.as_ref()?;
        let stem = m
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default();
        Some(dir.join(format!("{stem}.score.svg")))
    };
    let mut outputs: Vec<PathBuf> = a.models.iter().filter_map(|m| plot_of(m)).collect();
    outputs.extend(a.json_out.iter().cloned());
    super::refuse_overwrite(&outputs, a.force, "--plots / --json-out")?;
    if let Some(dir) = &a.plots {
        std::fs::create_dir_all(dir).with_context(|| format!("--plots {}", dir.display()))?;
    }
    let mut scores = Vec::new();
    for m in &a.models {
        let settings = match ScoreSettings::of_model(m)? {
            Some(s) if !a.ignore_report => s,
            _ => ScoreSettings::given(split, phy, a.decimation),
        };
        let (sc, series) = score::score(m, data, &settings).with_context(|| format!("scoring {}", m.display()))?;
        if let Some(p) = plot_of(m) {
            score::plot(&p, &sc, &series)?;
        }
        scores.push(sc);
    }
    let text = serde_json::to_string_pretty(&scores).context("JSON")?;
    if a.json {
        println!("{text}");
    } else {
        print!("{}", score::to_markdown(&scores));
    }
    if let Some(j) = &a.json_out {
        std::fs::write(j, text + "\n").with_context(|| format!("writing {}", j.display()))?;
    }
    Ok(())
}
