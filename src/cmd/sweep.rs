//! `bowden sweep`: a thin wrapper over `bowden_learning::sweep`.

use anyhow::{Context, Result};
use bowden_learning::sweep::{execute_runs, merge_sweep, plan_sweep, run_sweep, Selection, SweepConfig, SweepPlan};
use bowden_learning::{Architecture, Direction, TcnBlock};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct SweepArgs {
    /// Architectures (comma-separated).
    #[arg(long, default_value = "fnn,lstm,tcn,tcn-lstm", value_delimiter = ',',
          value_parser = super::typed::<Architecture>(), ignore_case = true)]
    archs: Vec<Architecture>,
    /// Comma-separated sequence lengths.
    #[arg(long, default_value = "10,50,65,80,100,120")]
    seq_lens: String,
    /// Seeds per configuration (0, 1, ... N−1).
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// Directions (comma-separated).
    #[arg(long, default_value = "forward,inverse", value_delimiter = ',',
          value_parser = super::typed::<Direction>(), ignore_case = true)]
    directions: Vec<Direction>,
    /// TCN block variants for tcn and tcn-lstm (comma-separated).
    #[arg(long, default_value = "relu-linear,relu-relu", value_delimiter = ',',
          value_parser = super::typed::<TcnBlock>(), ignore_case = true)]
    tcn_blocks: Vec<TcnBlock>,
    /// Training epochs of every run.
    #[arg(long, default_value_t = 30)]
    epochs: usize,
    /// Stop a run after N epochs without a better validation RMSE.
    #[arg(long)]
    early_stop: Option<usize>,
    /// Dataset directory (dataset.csv + manifest.json).
    #[arg(long)]
    data: PathBuf,
    /// Output directory (runs/ holds one JSON per finished run: rerunning resumes).
    #[arg(long)]
    out: PathBuf,
    /// Configurations trained at once (one per thread).
    #[arg(long)]
    jobs: Option<usize>,
    #[command(flatten)]
    split: super::learning::SplitArgs,
    /// Print the runs instead of training: index, key, fingerprint (data hash + code version
    /// + these settings) and status in --out; --json for JSON.
    #[arg(long, conflicts_with_all = ["shard", "run", "merge"])]
    plan: bool,
    /// Train only shard I of N: the runs whose index ≡ I (mod N), e.g. a Slurm array task's
    /// "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT" or a Kubernetes Indexed Job's
    /// "$JOB_COMPLETION_INDEX/N"; no summary is written (see --merge).
    #[arg(long, value_name = "I/N", conflicts_with_all = ["run", "merge"])]
    shard: Option<String>,
    /// Train only the run of index K (from --plan); no summary is written (see --merge).
    #[arg(long, value_name = "K", conflicts_with = "merge")]
    run: Option<usize>,
    /// Train nothing: check every run file in --out/runs against the plan (same data, code and
    /// settings; none missing) and write sweep.md, sweep.json and sweep.svg.
    #[arg(long)]
    merge: bool,
    /// Use the portable training kernels instead of AVX-512 where the CPU has it: the same
    /// bits on every x86-64 CPU, for shards on nodes that differ (slower).
    #[arg(long)]
    portable_kernels: bool,
    /// With --plan: print the plan as JSON on stdout instead of the table.
    #[arg(long, requires = "plan")]
    json: bool,
    /// With --plan: also write the plan JSON to FILE.
    #[arg(long, value_name = "FILE", requires = "plan")]
    json_out: Option<PathBuf>,
    /// Overwrite --json-out if it exists.
    #[arg(long)]
    force: bool,
}

pub fn sweep(a: SweepArgs) -> Result<()> {
    let (split, phy) = a.split.parse()?;
    super::dataset_dir("--data", &a.data)?;
    if a.portable_kernels {
        // Before any kernel runs: the choice is made once per process.
        bowden_learning::kernels::simd::force_portable(true);
    }
    let cfg = SweepConfig {
        archs: a.archs.clone(),
        seq_lens: super::learning::parse_usizes(&a.seq_lens, "seq-lens")?,
        seeds: a.seeds,
        directions: a.directions.clone(),
        tcn_blocks: a.tcn_blocks.clone(),
        epochs: a.epochs,
        early_stop: a.early_stop,
        split,
        phy_source: phy,
        jobs: a
            .jobs
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
    };
    let into = || format!("sweep into {}", a.out.display());
    let selection = match (&a.shard, a.run) {
        (Some(s), _) => Some(s.parse::<Selection>().map_err(anyhow::Error::msg)?),
        (None, Some(k)) => Some(Selection::Run(k)),
        (None, None) => None,
    };
    if !(a.plan || a.merge || selection.is_some()) {
        let summary = run_sweep(&a.data, &a.out, &cfg, true).with_context(into)?;
        println!("{}", summary.markdown);
        println!(
            "wrote {0}/sweep.md, {0}/sweep.json, {0}/sweep.svg ({1} runs, {2} reused from an earlier sweep)",
            a.out.display(),
            summary.runs,
            summary.reused
        );
        return Ok(());
    }
    let (mut plan, ds) = plan_sweep(&a.data, &cfg).with_context(into)?;
    if a.plan {
        super::refuse_overwrite(a.json_out.as_slice(), a.force, "--json-out")?;
        plan.check_status(&a.out);
        let json = serde_json::to_string_pretty(&plan)?;
        if let Some(j) = &a.json_out {
            std::fs::write(j, format!("{json}\n")).with_context(|| format!("{}", j.display()))?;
        }
        if a.json {
            println!("{json}");
        } else {
            print_plan(&plan, &a.out);
        }
        return Ok(());
    }
    if let Some(selection) = selection {
        println!(
            "sweep plan {}: {} runs ({}, data {} FNV-1a {}); {selection}",
            plan.fingerprint,
            plan.runs.len(),
            plan.code_version,
            plan.data,
            plan.data_fnv1a64
        );
        let report = execute_runs(&plan, &ds, &a.out, selection, cfg.jobs, true).with_context(into)?;
        for (i, why) in &report.redone {
            println!("run {i}: redone, its file was unusable: {why}");
        }
        for r in &report.runs {
            println!(
                "run {} {}: {:.3}° ({})",
                r.index,
                r.key.name(),
                r.best_val_rmse_deg,
                if r.trained {
                    "trained"
                } else {
                    "kept from an earlier process"
                }
            );
        }
        println!(
            "{}/runs: {} of {} runs written or kept ({} trained, {} kept); when every shard has finished: \
             bowden sweep ... --merge",
            a.out.display(),
            report.runs.len(),
            plan.runs.len(),
            report.trained,
            report.reused
        );
        return Ok(());
    }
    let summary = merge_sweep(&plan, &a.out).with_context(into)?;
    println!("{}", summary.markdown);
    println!(
        "wrote {0}/sweep.md, {0}/sweep.json, {0}/sweep.svg ({1} runs merged from {0}/runs, plan {2})",
        a.out.display(),
        summary.runs,
        plan.fingerprint
    );
    Ok(())
}

fn print_plan(plan: &SweepPlan, out: &std::path::Path) {
    println!(
        "sweep plan {}: {} runs; {}; data {} (FNV-1a {}); sharding {}",
        plan.fingerprint,
        plan.runs.len(),
        plan.code_version,
        plan.data,
        plan.data_fnv1a64,
        plan.sharding
    );
    let width = plan.runs.iter().map(|r| r.key.name().len()).max().unwrap_or(0);
    println!(
        "{:>5}  {:width$}  {:16}  status in {}",
        "index",
        "key",
        "fingerprint",
        out.display()
    );
    for r in &plan.runs {
        println!(
            "{:>5}  {:width$}  {:16}  {}",
            r.index,
            r.key.name(),
            r.fingerprint,
            r.status.as_deref().unwrap_or("")
        );
    }
}
