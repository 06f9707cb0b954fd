//! `bowden node`, `bowden run`, `bowden replay`, `bowden estop`, and `bowden bench ipc|cycle`:
//! thin wrappers over `bowden-runtime`.

use anyhow::{bail, Context};
use bowden_runtime::config::{Mode, Overrides, PipelineConfig, SIM_DEFAULT_NAME};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::ports::{IpcSettings, PortContext};
use bowden_runtime::replay::{self, Pace};
use bowden_runtime::session::{LockstepSession, RealtimeSession, RunReport, SessionOptions};
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
pub(super) fn load(arg: &str, ov: &Overrides) -> anyhow::Result<PipelineConfig> {
    let arg = if arg == SIM_DEFAULT_NAME {
        arg.to_string()
    } else {
        crate::home::path(Path::new(arg))?.display().to_string()
    };
    PipelineConfig::load_arg(&arg, ov, bowden::registry::REGISTRY).context("pipeline config")
}

// Long: the dispatch of the pipeline commands (node, run, replay, estop, clean), each a few lines of argument mapping.
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

pub(super) fn report_json(r: &RunReport) -> String {
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
