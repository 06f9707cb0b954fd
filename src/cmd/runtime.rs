//! `bowden node`, `bowden run`, `bowden replay`, `bowden estop`, and `bowden bench ipc|cycle`:
//! thin wrappers over `bowden-runtime`.

use anyhow::{bail, Context};
use bowden_runtime::bench::{self, IpcVariant, Load, Peer};
use bowden_runtime::config::{Mode, Overrides, PipelineConfig, SIM_DEFAULT_NAME};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::ports::{IpcSettings, PortContext};
use bowden_runtime::replay::{self, Pace};
use bowden_runtime::rt::Outcome;
use bowden_runtime::session::{LockstepSession, RealtimeSession, RunReport, SessionOptions};
use bowden_runtime::stats::fmt_ns;
use bowden_runtime::{run_process, ProcessOptions};
use clap::{Args, Subcommand};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Overrides every pipeline command accepts (the launcher passes them on to its children).
#[derive(Args, Debug, Clone, Default)]
pub struct OverrideArgs {
    /// Scheduling mode: lockstep (simulated clock, reproducible) or realtime.
    #[arg(long, value_parser = super::typed::<Mode>(), ignore_case = true)]
    mode: Option<Mode>,
    /// iceoryx2 shared-memory prefix (isolates runs on one machine).
    #[arg(long)]
    prefix: Option<String>,
    /// Service namespace prepended to every service name.
    #[arg(long)]
    namespace: Option<String>,
    /// Record the recorder stage's services to this log (enables the recorder).
    #[arg(long)]
    record: Option<PathBuf>,
    /// Seed of every random process of the run.
    #[arg(long)]
    seed: Option<u64>,
}

impl OverrideArgs {
    fn overrides(&self) -> anyhow::Result<Overrides> {
        Ok(Overrides {
            mode: self.mode,
            prefix: self.prefix.clone(),
            namespace: self.namespace.clone(),
            record_path: self.record.clone(),
            seed: self.seed,
        })
    }
}

#[derive(Subcommand)]
pub enum Command {
    /// Run one process of a pipeline (`bowden run` starts these; run one by hand to debug it).
    Node {
        /// Process name from the config (a stage's name unless stages share a `process`).
        name: String,
        /// Pipeline config (found as `run` finds it); `@sim` is the embedded default.
        #[arg(long)]
        config: Option<String>,
        #[command(flatten)]
        ov: OverrideArgs,
        /// Real time: start at once instead of waiting for the launcher's start tick.
        #[arg(long)]
        standalone: bool,
        /// No exit summary.
        #[arg(long)]
        quiet: bool,
    },
    /// Start a pipeline (default: configs/sim.toml): every stage its own process, supervised;
    /// Ctrl-C stops it cleanly and prints the latency summary and the faults seen.
    ///
    /// Exit code: 0 clean run; 3 faults occurred and every stage was running again at the end;
    /// 4 a fault not recovered (a stage still holding or degraded, a process lost for good, a
    /// hung stage: the launcher latched the e-stop and halted); 5 an e-stop latched at the end;
    /// 1 bowden itself failed; 2 usage error.
    Run {
        /// Pipeline config file: found as given, under $BOWDEN_HOME, or built in (`bowden
        /// shipped`); the files it names are found beside it.
        #[arg(default_value = "configs/sim.toml")]
        config: PathBuf,
        #[command(flatten)]
        ov: OverrideArgs,
        /// Stop after this many ticks (lockstep) or control periods (real time).
        #[arg(long)]
        ticks: Option<u64>,
        /// Real time: stop after this many seconds.
        #[arg(long)]
        seconds: Option<f64>,
        /// Children write their output to DIR/<process>.log instead of this terminal.
        #[arg(long)]
        log_dir: Option<PathBuf>,
        /// Children print no exit summaries.
        #[arg(long)]
        quiet: bool,
        /// Print the run summary as JSON on stdout instead of the table.
        #[arg(long)]
        json: bool,
        /// Also write the run summary as JSON to FILE.
        #[arg(long, value_name = "FILE")]
        json_out: Option<PathBuf>,
        /// Overwrite --json-out and --record if they exist.
        #[arg(long)]
        force: bool,
    },
    /// Feed a recorded log back onto its services, or summarise it.
    Replay {
        /// The log (`.blog`; its index `.blog.idx` beside it).
        log: PathBuf,
        /// Only print the summary (Markdown; `--json` for machines).
        #[arg(long)]
        summary: bool,
        /// Print the summary as JSON on stdout instead of Markdown.
        #[arg(long)]
        json: bool,
        /// Also write the summary as JSON to FILE.
        #[arg(long, value_name = "FILE")]
        json_out: Option<PathBuf>,
        /// Overwrite --json-out if it exists.
        #[arg(long)]
        force: bool,
        /// As fast as possible instead of the recorded pace.
        #[arg(long)]
        fast: bool,
        /// Pace factor (2 = twice as fast as recorded).
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Only these services (comma-separated full names).
        #[arg(long, value_delimiter = ',', value_parser = super::choice(&bowden_interfaces::services::ALL))]
        services: Option<Vec<String>>,
        /// iceoryx2 shared-memory prefix to publish under.
        #[arg(long, default_value = "bowden_")]
        prefix: String,
        /// Service namespace prepended to every service name.
        #[arg(long, default_value = "")]
        namespace: String,
    },
    /// Remove what dead bowden processes left in shared memory under a prefix (the launcher does
    /// this at start by itself; for prefixes no run will reuse).
    Clean {
        /// iceoryx2 shared-memory prefix to clean.
        #[arg(long, default_value = "bowden_")]
        prefix: String,
    },
    /// Latch the actuator's e-stop (hold the last safe command), or release it; waits until an
    /// actuator confirms the new state in its status.
    Estop {
        /// Release a latched e-stop instead.
        #[arg(long)]
        release: bool,
        /// Give up (exit code 1) when no actuator confirms within this many milliseconds.
        #[arg(long, default_value_t = 2000)]
        timeout_ms: u64,
        /// The stage whose status confirms (the pipeline's actuator).
        #[arg(long, default_value = "actuator")]
        stage: String,
        /// iceoryx2 shared-memory prefix of the running pipeline.
        #[arg(long, default_value = "bowden_")]
        prefix: String,
        /// Service namespace of the running pipeline.
        #[arg(long, default_value = "")]
        namespace: String,
    },
}

/// Loads a pipeline: `@sim` (the embedded default), or a file found by `crate::home`'s order.
/// Children get the path found, so every process reads the same file.
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

fn load(arg: &str, ov: &Overrides) -> anyhow::Result<PipelineConfig> {
    let arg = if arg == SIM_DEFAULT_NAME {
        arg.to_string()
    } else {
        crate::home::path(Path::new(arg))?.display().to_string()
    };
    PipelineConfig::load_arg(&arg, ov, bowden::registry::REGISTRY).context("pipeline config")
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Node {
            name,
            config,
            ov,
            standalone,
            quiet,
        } => {
            let cfg = load(config.as_deref().unwrap_or("configs/sim.toml"), &ov.overrides()?)?;
            run_process(
                &cfg,
                &name,
                bowden::registry::REGISTRY,
                &ProcessOptions { standalone, quiet },
            )
            .with_context(|| format!("node `{name}`"))?;
            Ok(())
        }
        Command::Run {
            config,
            ov,
            ticks,
            seconds,
            log_dir,
            quiet,
            json,
            json_out,
            force,
        } => {
            let outputs: Vec<PathBuf> = json_out.iter().chain(ov.record.iter()).cloned().collect();
            super::refuse_overwrite(&outputs, force, "file")?;
            let cfg = load(&config.display().to_string(), &ov.overrides()?)?;
            let report = run_pipeline(&cfg, ticks, seconds, log_dir, quiet)?;
            if json {
                println!("{}", report_json(&report));
            } else {
                print!("{}", report.format_summary());
            }
            if let Some(j) = json_out {
                std::fs::write(&j, report_json(&report)).with_context(|| format!("writing {}", j.display()))?;
            }
            match report.outcome.exit_code() {
                0 => Ok(()),
                code => Err(super::ExitCode {
                    code,
                    why: format!("the run ended with outcome: {}", report.outcome.as_str()),
                }
                .into()),
            }
        }
        Command::Replay {
            log,
            summary,
            fast,
            speed,
            services,
            prefix,
            namespace,
            json,
            json_out,
            force,
        } => {
            super::refuse_overwrite(json_out.as_slice(), force, "--json-out")?;
            if !summary {
                if !(speed.is_finite() && speed > 0.0) {
                    bail!("--speed {speed}: must be a positive number");
                }
                bowden_runtime::sys::install_termination_handlers().context("signal handlers")?;
                let ctx = PortContext::new("replay", &IpcSettings { prefix, namespace }).context("iceoryx2")?;
                let pace = if fast { Pace::Fast } else { Pace::Recorded { speed } };
                let st = replay::replay(&log, &ctx, pace, services.as_deref())
                    .with_context(|| format!("replaying {}", log.display()))?;
                println!(
                    "replayed {} samples in {:.3} s{}",
                    st.published,
                    st.seconds,
                    if st.interrupted { " (interrupted)" } else { "" }
                );
            }
            let s = replay::summarize(&log).with_context(|| format!("reading {}", log.display()))?;
            let text = serde_json::to_string_pretty(&s).context("summary JSON")?;
            if json {
                println!("{text}");
            } else {
                print!("{}", s.to_markdown());
            }
            if let Some(j) = json_out {
                std::fs::write(&j, text).with_context(|| format!("writing {}", j.display()))?;
            }
            Ok(())
        }
        Command::Clean { prefix } => {
            let settings = IpcSettings {
                prefix,
                namespace: String::new(),
            };
            bowden_runtime::cleanup::secure_prefix_files(&settings)?;
            let r = bowden_runtime::cleanup::remove_stale_nodes(&settings).context("cleaning stale nodes")?;
            let files = bowden_runtime::cleanup::remove_prefix_files(&settings).context("removing files")?;
            println!(
                "prefix `{}`: removed the resources of {} dead node(s) ({} failed), {} leftover file(s); {} node(s) alive",
                settings.prefix, r.dead_removed, r.dead_failed, files, r.alive
            );
            Ok(())
        }
        Command::Estop {
            release,
            timeout_ms,
            stage,
            prefix,
            namespace,
        } => {
            use bowden_runtime::safety::{SafetyAction, SafetyLink};
            let action = if release {
                SafetyAction::Release
            } else {
                SafetyAction::Estop
            };
            let settings = IpcSettings { prefix, namespace };
            bowden_runtime::cleanup::secure_prefix_files(&settings)?;
            // Everything that talks to the running pipeline runs under one time bound: a
            // damaged iceoryx2 file must give a clear error, never a hang. The worker thread
            // is abandoned on timeout (the process exits).
            let (tx, rx) = std::sync::mpsc::channel();
            let bound = Duration::from_millis(timeout_ms);
            std::thread::spawn(move || {
                let r = (|| -> anyhow::Result<usize> {
                    let mut link = SafetyLink::open("estop", &settings).context("iceoryx2")?;
                    let n = link.send(action)?;
                    println!("{action} sent to {n} subscriber(s)");
                    link.confirm(&stage, action, bound)?;
                    println!("confirmed by `{stage}`");
                    Ok(n)
                })();
                let _ = tx.send(r);
            });
            match rx.recv_timeout(bound + Duration::from_millis(500)) {
                Ok(r) => r.map(|_| ()),
                Err(_) => bail!(
                    "{action}: no answer within {} ms (the prefix's iceoryx2 files may be damaged: `bowden clean --prefix ...` after the pipeline stopped)",
                    bound.as_millis() + 500
                ),
            }
        }
    }
}

fn run_pipeline(
    cfg: &PipelineConfig,
    ticks: Option<u64>,
    seconds: Option<f64>,
    log_dir: Option<PathBuf>,
    quiet: bool,
) -> anyhow::Result<RunReport> {
    let mut launch = LaunchOptions::current_exe().context("locating the bowden executable")?;
    launch.quiet_children = quiet;
    launch.log_dir = log_dir;
    let mut opts = SessionOptions::new(launch);
    opts.verbose = true;
    for line in cfg.describe() {
        eprintln!("launcher: {line}");
    }
    if cfg.lockstep() {
        let n = ticks.or(cfg.runtime.ticks);
        let mut s = LockstepSession::start(cfg, opts).context("starting the pipeline")?;
        let bar = n.map(|n| {
            let b = indicatif::ProgressBar::new(n);
            b.set_style(
                indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} ticks {per_sec} eta {eta}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        let mut interrupted = false;
        loop {
            if n.is_some_and(|n| s.ticks_done() >= n) {
                break;
            }
            if bowden_runtime::sys::termination_requested() {
                interrupted = true;
                break;
            }
            match s.step() {
                Ok(out) => {
                    for e in out.events {
                        if let Some(b) = &bar {
                            b.println(format!("launcher: {e}"));
                        }
                    }
                }
                Err(bowden_runtime::session::SessionError::Interrupted) => {
                    interrupted = true;
                    break;
                }
                // The launcher halted the run (a process lost for good, a stall) and latched
                // the e-stop: stop everything and report; the outcome says it.
                Err(bowden_runtime::session::SessionError::Halted { .. }) => break,
                Err(e) => return Err(e).context("lockstep run"),
            }
            if let Some(b) = &bar {
                b.inc(1);
            }
        }
        if let Some(b) = bar {
            b.finish_and_clear();
        }
        if interrupted {
            eprintln!("launcher: interrupted after {} ticks; stopping", s.ticks_done());
        }
        Ok(s.shutdown().context("stopping the pipeline")?)
    } else {
        let dur = seconds
            .or(ticks.map(|t| t as f64 * cfg.period_ns() as f64 / 1e9))
            .or(cfg.runtime.seconds)
            .map(Duration::from_secs_f64);
        opts.until_signal = dur.is_none();
        let mut s = RealtimeSession::start(cfg, opts).context("starting the pipeline")?;
        s.run_for(dur).context("supervising")?;
        if bowden_runtime::sys::termination_requested() {
            eprintln!("launcher: stopping on signal");
        }
        Ok(s.shutdown().context("stopping the pipeline")?)
    }
}

fn report_json(r: &RunReport) -> String {
    let stages: Vec<serde_json::Value> = r
        .statuses
        .iter()
        .map(|(n, s)| match s {
            Some(c) => serde_json::json!({
                "stage": n, "state": c.state, "last_fault": c.last_fault, "cycles": c.cycles, "deadline_misses": c.deadline_misses,
                "rejected": c.rejected_samples, "faults": c.faults, "latency_p50_ns": c.latency_p50_ns,
                "latency_p99_ns": c.latency_p99_ns, "latency_p999_ns": c.latency_p999_ns,
                "latency_max_ns": c.latency_max_ns,
            }),
            None => serde_json::json!({"stage": n, "state": null}),
        })
        .collect();
    serde_json::to_string_pretty(&serde_json::json!({
        "mode": r.mode, "startup_ms": r.startup.as_secs_f64() * 1e3, "ticks": r.ticks,
        "elapsed_s": r.elapsed.as_secs_f64(), "stages": stages, "events": r.events,
        "faults": r.faults.iter().map(|f| serde_json::json!({
            "t_s": f.t_s, "tick": f.tick, "source": f.source, "what": f.what,
        })).collect::<Vec<_>>(),
        "halted": r.halted, "outcome": r.outcome.as_str(), "exit_code": r.outcome.exit_code(),
        "stale_nodes_removed_at_start": r.cleanup_at_start.dead_removed,
    }))
    .unwrap_or_default()
}

#[derive(Subcommand)]
pub enum BenchCommand {
    /// One IPC hop, one way and round trip, bowden ports side by side with raw iceoryx2, for a
    /// 240-byte sample and 64 B / 640x480 RGBD frames.
    Ipc {
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
    },
    /// The pong side of `bench ipc` (started by it).
    #[command(hide = true)]
    IpcPeer {
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
    },
    /// Robot-side faults injected into the default simulated pipeline (configs/sim.toml) in real
    /// time — the plant publishing NaN, ±900°, nothing; hanging; killed for good — each run
    /// measured from its own fault records: detection time, reaction, exit code.
    Faults {
        /// Runs per fault.
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Only these faults (comma-separated): nan, out-of-range, silent, hung, lost.
        #[arg(long, value_delimiter = ',')]
        cases: Option<Vec<String>>,
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
    },
    /// End-to-end control cycle (target → compensated → motor command) at the config's rate,
    /// with and without CPU load on the other core; deadline misses per stage.
    Cycle {
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
    },
}

pub fn bench(c: BenchCommand) -> anyhow::Result<()> {
    match c {
        BenchCommand::Ipc {
            samples,
            warmup,
            threads,
            rounds,
            fifo,
            variants,
            json,
            json_out,
            force,
        } => {
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
            let rows =
                bench::ipc_bench(&prefix, samples, warmup, rounds, &peer, &variants, fifo).context("ipc bench")?;
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
            println!(
                "IPC hop, {samples} round trips per variant in {rounds} interleaved rounds ({side}{fifo_note}):\n"
            );
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
        BenchCommand::IpcPeer {
            variant,
            prefix,
            warmup,
            expect,
            fifo,
        } => {
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
        BenchCommand::Faults {
            runs,
            cases,
            fault_at_s,
            after_s,
            json,
            json_out,
            force,
        } => {
            use bowden_runtime::faultbench::{self, FaultBenchOptions, FaultCase};
            super::refuse_overwrite(json_out.as_slice(), force, "--json-out")?;
            let cases = match cases {
                None => FaultCase::ALL.to_vec(),
                Some(names) => names
                    .iter()
                    .map(|n| {
                        FaultCase::ALL.into_iter().find(|c| c.name() == n).with_context(|| {
                            format!("--cases: unknown fault `{n}` (nan, out-of-range, silent, hung, lost)")
                        })
                    })
                    .collect::<anyhow::Result<_>>()?,
            };
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
        BenchCommand::Cycle {
            seconds,
            config,
            load,
            sched,
            json,
            json_out,
            force,
            process_summaries,
        } => {
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
                let base = self::load(c, &ov)?;
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
                    let r =
                        bench::cycle_run(cfg, &launch, seconds, l, &label, process_summaries).context("cycle run")?;
                    results.push(r);
                }
            }
            let v: Vec<serde_json::Value> = results
                .iter()
                .map(|r| serde_json::json!({"run": r.label, "report": serde_json::from_str::<serde_json::Value>(&report_json(&r.report)).unwrap_or_default()}))
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
    }
}
