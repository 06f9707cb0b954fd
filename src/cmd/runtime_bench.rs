//! `bowden bench ipc|cycle|faults`: thin wrappers over `bowden_runtime::bench` and `bowden_runtime::faultbench`.

use anyhow::{bail, Context};
use bowden_runtime::bench::{self, IpcVariant, Load, Peer};
use bowden_runtime::config::{Mode, Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::ports::IpcSettings;
use bowden_runtime::rt::Outcome;
use bowden_runtime::stats::fmt_ns;
use clap::{Args, Subcommand};
use std::path::{Path, PathBuf};

/// `bench cycle --load`: CPU load during the measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LoadChoice {
    /// No load.
    None,
    /// Load on the CPUs the pipeline is not pinned to.
    Other,
    /// Load on every CPU.
    All,
    /// `none`, then `other`.
    Both,
}

/// `bench cycle --sched`: the scheduling policy of the pipeline's processes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SchedChoice {
    /// SCHED_FIFO as configured.
    Fifo,
    /// SCHED_FIFO off in every process.
    Other,
    /// `fifo`, then `other`.
    Both,
}

#[derive(Subcommand)]
pub enum BenchCommand {
    /// One IPC hop, one way and round trip, bowden ports side by side with raw iceoryx2, for a
    /// 240-byte sample and 64 B / 640x480 RGBD frames.
    Ipc(IpcArgs),
    /// The pong side of `bench ipc` (started by it).
    #[command(hide = true)]
    IpcPeer(IpcPeerArgs),
    /// Robot-side faults injected into the default simulated pipeline (configs/sim.toml) in real
    /// time — the plant publishing NaN, ±900°, nothing; hanging; killed for good — each run
    /// measured from its own fault records: detection time, reaction, exit code.
    Faults(FaultsArgs),
    /// End-to-end control cycle (target → compensated → motor command) at the config's rate,
    /// with and without CPU load on the other core; deadline misses per stage.
    Cycle(CycleArgs),
}

#[derive(Args, Debug)]
pub struct IpcArgs {
    /// Round trips measured per variant.
    #[arg(long, default_value_t = 20_000)]
    samples: usize,
    /// Round trips sent first and not measured.
    #[arg(long, default_value_t = 2_000)]
    warmup: usize,
    /// Pong side in a thread of this process instead of a second process.
    #[arg(long)]
    threads: bool,
    /// Rounds: the variants run in turn this many times (a fresh peer each), so raw and
    /// bowden ports see the same machine.
    #[arg(long, default_value_t = 10)]
    rounds: usize,
    /// Run ping and pong under SCHED_FIFO at this priority (when permitted).
    #[arg(long)]
    fifo: Option<u8>,
    /// Only these variants (comma-separated), e.g. raw-sample,ports-sample.
    #[arg(long, value_delimiter = ',', value_parser = clap::builder::PossibleValuesParser::new(<IpcVariant as strum::VariantNames>::VARIANTS),
          ignore_case = true)]
    variants: Option<Vec<String>>,
    /// Print the rows as JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Also write the rows as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    json_out: Option<PathBuf>,
    /// Overwrite --json-out if it exists.
    #[arg(long)]
    force: bool,
}

#[derive(Args, Debug)]
pub struct IpcPeerArgs {
    #[arg(long)]
    variant: String,
    #[arg(long)]
    prefix: String,
    #[arg(long, default_value_t = 0)]
    warmup: usize,
    #[arg(long, default_value_t = 0)]
    expect: usize,
    #[arg(long)]
    fifo: Option<u8>,
}

#[derive(Args, Debug)]
pub struct FaultsArgs {
    /// Runs per fault.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Only these faults (comma-separated).
    #[arg(long, value_delimiter = ',', value_parser = super::typed::<bowden_runtime::faultbench::FaultCase>(), ignore_case = true)]
    cases: Option<Vec<bowden_runtime::faultbench::FaultCase>>,
    /// Seconds of normal running before the fault.
    #[arg(long, default_value_t = 1.0)]
    fault_at_s: f64,
    /// Seconds run after it.
    #[arg(long, default_value_t = 1.0)]
    after_s: f64,
    /// Print the rows as JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Also write the rows as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    json_out: Option<PathBuf>,
    /// Overwrite --json-out if it exists.
    #[arg(long)]
    force: bool,
}

#[derive(Args, Debug)]
pub struct CycleArgs {
    /// Seconds per run.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Pipeline(s) (real time), comma-separated, run one after the other in this invocation
    /// (e.g. configs/cycle-grouped-accurate.toml,configs/cycle-grouped-tcn.toml: the two
    /// controllers side by side). Default: both layouts, configs/cycle.toml (one process
    /// per stage) and configs/cycle-grouped.toml (the control chain in one process).
    #[arg(long, value_delimiter = ',')]
    config: Option<Vec<String>>,
    /// none, other (load on the CPUs the pipeline is not pinned to), all (every CPU), or
    /// both (= none then other).
    #[arg(long, value_enum, default_value_t = LoadChoice::Both, ignore_case = true)]
    load: LoadChoice,
    /// fifo (as configured), other (SCHED_FIFO off in every process), or both.
    #[arg(long, value_enum, default_value_t = SchedChoice::Fifo, ignore_case = true)]
    sched: SchedChoice,
    /// Print the results as JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Also write the results as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    json_out: Option<PathBuf>,
    /// Overwrite --json-out if it exists.
    #[arg(long)]
    force: bool,
    /// Every process prints its report on stderr at the end of a run: per stage the
    /// compute time of its own steps and its budget overruns (`budget_us`), which
    /// attribute a deadline miss to the stage that caused it.
    #[arg(long)]
    process_summaries: bool,
}

pub fn bench(c: BenchCommand) -> anyhow::Result<()> {
    match c {
        BenchCommand::Ipc(a) => ipc(a),
        BenchCommand::IpcPeer(a) => ipc_peer(a),
        BenchCommand::Faults(a) => faults(a),
        BenchCommand::Cycle(a) => cycle(a),
    }
}

fn ipc(a: IpcArgs) -> anyhow::Result<()> {
    let IpcArgs {
        samples,
        warmup,
        threads,
        rounds,
        fifo,
        variants,
        json,
        json_out,
        force,
    } = a;
    super::refuse_overwrite(json_out.as_slice(), force, "--json-out")?;
    let variants: Vec<IpcVariant> = match variants {
        Some(v) => v
            .iter()
            .map(|n| {
                IpcVariant::ALL
                    .iter()
                    .copied()
                    .find(|v| v.as_str().eq_ignore_ascii_case(n))
                    .with_context(|| {
                        format!(
                            "--variants `{n}`: known: {}",
                            IpcVariant::ALL
                                .iter()
                                .map(|v| v.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        )
                    })
            })
            .collect::<anyhow::Result<_>>()?,
        None => IpcVariant::ALL.to_vec(),
    };
    let peer = if threads {
        Peer::Thread
    } else {
        Peer::Process(std::env::current_exe().context("locating the bowden executable")?)
    };
    let prefix = format!("bwbench{}_", std::process::id());
    let fifo_note = match fifo {
        Some(p) => match bench::probe_fifo(p) {
            Outcome::Applied => format!(", SCHED_FIFO {p}"),
            o => format!(", SCHED_FIFO {p} {o}"),
        },
        None => ", normal scheduling".into(),
    };
    let rows = bench::ipc_bench(&prefix, samples, warmup, rounds, &peer, &variants, fifo).context("ipc bench")?;
    let rows_json = serde_json::to_string_pretty(&rows).context("JSON")?;
    if let Some(j) = &json_out {
        std::fs::write(j, &rows_json).with_context(|| format!("writing {}", j.display()))?;
    }
    if json {
        println!("{rows_json}");
        return Ok(());
    }
    let side = if threads {
        "pong in a second thread"
    } else {
        "pong in a second process"
    };
    println!("IPC hop, {samples} round trips per variant in {rounds} interleaved rounds ({side}{fifo_note}):\n");
    println!("| variant | one-way p50 | p99 | p99.9 | max | round-trip p50 | p99 | p99.9 | max | allocs/send (system, pool) |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|");
    for r in &rows {
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2}, {:.2} |",
            r.description,
            fmt_ns(r.one_way.p50_ns),
            fmt_ns(r.one_way.p99_ns),
            fmt_ns(r.one_way.p999_ns),
            fmt_ns(r.one_way.max_ns),
            fmt_ns(r.round_trip.p50_ns),
            fmt_ns(r.round_trip.p99_ns),
            fmt_ns(r.round_trip.p999_ns),
            fmt_ns(r.round_trip.max_ns),
            r.system_allocs_per_send,
            r.pool_allocs_per_send
        );
    }
    for (raw, ports) in [
        ("raw-sample", "ports-sample"),
        ("raw-sample-event", "ports-sample-event"),
        ("raw-frame-640x480", "ports-frame-640x480"),
    ] {
        let a = rows.iter().find(|r| r.variant == raw);
        let b = rows.iter().find(|r| r.variant == ports);
        if let (Some(a), Some(b)) = (a, b) {
            println!(
                "\n{ports} / {raw}: one-way p99 ×{:.2}, round-trip p99 ×{:.2}",
                b.one_way.p99_ns as f64 / a.one_way.p99_ns.max(1) as f64,
                b.round_trip.p99_ns as f64 / a.round_trip.p99_ns.max(1) as f64
            );
        }
    }
    Ok(())
}

fn ipc_peer(a: IpcPeerArgs) -> anyhow::Result<()> {
    let IpcPeerArgs {
        variant,
        prefix,
        warmup,
        expect,
        fifo,
    } = a;
    let v = IpcVariant::parse(&variant).with_context(|| format!("--variant `{variant}`"))?;
    bowden_runtime::alloc::enable_pool();
    if let Some(p) = fifo {
        let _ = bowden_runtime::rt::set_fifo(p);
    }
    let settings = IpcSettings {
        prefix,
        namespace: String::new(),
    };
    let one_way = bench::run_ipc_peer(v, &settings, warmup, expect).map_err(anyhow::Error::msg)?;
    println!("{}", serde_json::to_string(&one_way).context("JSON")?);
    Ok(())
}

fn faults(a: FaultsArgs) -> anyhow::Result<()> {
    let FaultsArgs {
        runs,
        cases,
        fault_at_s,
        after_s,
        json,
        json_out,
        force,
    } = a;
    use bowden_runtime::faultbench::{self, FaultBenchOptions, FaultCase};
    super::refuse_overwrite(json_out.as_slice(), force, "--json-out")?;
    let cases = cases.unwrap_or_else(|| FaultCase::ALL.to_vec());
    if runs == 0 || !(fault_at_s > 0.0 && after_s > 0.0) {
        bail!("--runs must be at least 1, --fault-at-s and --after-s positive");
    }
    let work = std::env::temp_dir().join(format!("bowden-bench-faults-{}", std::process::id()));
    let opts = FaultBenchOptions {
        cases,
        runs,
        fault_at_s,
        after_s,
        launch: LaunchOptions::current_exe().context("locating the bowden executable")?,
        kinds: bowden::registry::REGISTRY,
        work_dir: work.clone(),
    };
    let bar = indicatif::ProgressBar::new((opts.cases.len() * runs) as u64);
    let rows = faultbench::run(&opts, |line| {
        bar.println(line);
        bar.inc(1);
    });
    let _ = std::fs::remove_dir_all(&work);
    let rows = rows?;
    bar.finish_and_clear();
    let text = serde_json::to_string_pretty(&rows).context("JSON")?;
    if json {
        println!("{text}");
    } else {
        print!("{}", faultbench::to_markdown(&rows));
    }
    if let Some(j) = json_out {
        std::fs::write(&j, text).with_context(|| format!("writing {}", j.display()))?;
    }
    Ok(())
}

// Long: the cycle benchmark's load and scheduling combinations and their table, one measured run each.
fn cycle(a: CycleArgs) -> anyhow::Result<()> {
    let CycleArgs {
        seconds,
        config,
        load,
        sched,
        json,
        json_out,
        force,
        process_summaries,
    } = a;
    super::refuse_overwrite(json_out.as_slice(), force, "--json-out")?;
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds {seconds}: must be positive");
    }
    let ov = Overrides {
        mode: Some(Mode::Realtime),
        prefix: Some(format!("bwcycle{}_", std::process::id())),
        ..Default::default()
    };
    let configs: Vec<String> = match config {
        Some(c) => c,
        None => vec!["configs/cycle.toml".into(), "configs/cycle-grouped.toml".into()],
    };
    let scheds: &[bool] = match sched {
        SchedChoice::Fifo => &[true],
        SchedChoice::Other => &[false],
        SchedChoice::Both => &[true, false],
    };
    let mut cfgs: Vec<(String, PipelineConfig)> = Vec::new();
    for c in &configs {
        let base = super::runtime::load(c, &ov)?;
        let layout = Path::new(c)
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or(c)
            .to_string();
        for &fifo in scheds {
            let mut cfg = base.clone();
            if !fifo {
                for p in cfg.processes.iter_mut() {
                    if let Some(rt) = p.rt.as_mut() {
                        rt.sched_fifo = false;
                    }
                }
            }
            cfgs.push((format!("{layout}{}", if fifo { "" } else { " SCHED_OTHER" }), cfg));
        }
    }
    let pinned: Vec<usize> = cfgs
        .iter()
        .flat_map(|(_, c)| c.processes.iter())
        .filter_map(|p| p.rt.as_ref())
        .flat_map(|r| r.cpus.iter().copied())
        .collect::<std::collections::BTreeSet<usize>>()
        .into_iter()
        .collect();
    let n_cpus = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let others: Vec<usize> = (0..n_cpus).filter(|c| !pinned.contains(c)).collect();
    let all: Vec<usize> = (0..n_cpus).collect();
    let loads: Vec<(&str, Load)> = match load {
        LoadChoice::None => vec![("no load", Load::None)],
        LoadChoice::Other => vec![("load other CPU", Load::Cpus(others.clone()))],
        LoadChoice::All => vec![("load every CPU", Load::Cpus(all))],
        LoadChoice::Both => vec![("no load", Load::None), ("load other CPU", Load::Cpus(others.clone()))],
    };
    let fifo = bench::probe_fifo(80);
    let setup = format!(
        "SCHED_FIFO for this user: {}; pipeline pinned to CPU(s) {:?}; load CPUs for `other`: {:?}",
        match &fifo {
            Outcome::Applied => "available".to_string(),
            o => o.to_string(),
        },
        pinned,
        others
    );
    if json {
        eprintln!("{setup}");
    } else {
        println!("{setup}");
    }
    let launch = LaunchOptions::current_exe().context("locating the bowden executable")?;
    let mut results = Vec::new();
    for (layout, cfg) in &cfgs {
        for (label, l) in &loads {
            let label = format!("{layout}, {label}");
            eprintln!("bench cycle: {label}, {seconds} s ...");
            let r = bench::cycle_run(cfg, &launch, seconds, l, &label, process_summaries).context("cycle run")?;
            results.push(r);
        }
    }
    let v: Vec<serde_json::Value> = results
        .iter()
        .map(|r| serde_json::json!({"run": r.label, "report": serde_json::from_str::<serde_json::Value>(&super::runtime::report_json(&r.report)).unwrap_or_default()}))
        .collect();
    let text = serde_json::to_string_pretty(&serde_json::json!({"sched_fifo": fifo.to_string(), "runs": v}))
        .context("JSON")?;
    if let Some(j) = &json_out {
        std::fs::write(j, &text).with_context(|| format!("writing {}", j.display()))?;
    }
    if json {
        println!("{text}");
        return Ok(());
    }
    println!(
        "\nlatency: periodic drivers (trajectory, plant) since their nominal release, including the \
         wake-up; compensator and actuator since the target was created (actuator = end to end, \
         target → motor command sent)\n"
    );
    println!("| run | stage | cycles | misses | latency p50 | p99 | p99.9 | max |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for r in &results {
        for (name, st) in &r.report.statuses {
            if let Some(s) = st {
                println!(
                    "| {} | {} | {} | {} | {} | {} | {} | {} |",
                    r.label,
                    name,
                    s.cycles,
                    s.deadline_misses,
                    fmt_ns(s.latency_p50_ns),
                    fmt_ns(s.latency_p99_ns),
                    fmt_ns(s.latency_p999_ns),
                    fmt_ns(s.latency_max_ns)
                );
            }
        }
        for e in &r.report.events {
            println!("event ({}): {e}", r.label);
        }
    }
    Ok(())
}
