//! Running a whole pipeline from a library caller: [`LockstepSession`] (tests, `collect`,
//! `evaluate`: step a reproducible multi-process run tick by tick and read its samples back) and
//! [`RealtimeSession`] (`bowden run`: start, supervise, stop on Ctrl-C or after a time).
//!
//! # Lockstep
//!
//! ```no_run
//! use bowden_interfaces::{services, PlantState};
//! use bowden_runtime::config::{Mode, Overrides, PipelineConfig};
//! use bowden_runtime::session::{LockstepSession, SessionOptions};
//! use bowden_runtime::launch::LaunchOptions;
//! # let kinds = bowden_runtime::node::Registry(&[&bowden_runtime::record::KIND]);
//!
//! // `kinds`: the node kinds of the program that runs the children (the `bowden` binary's table).
//! let ov = Overrides { mode: Some(Mode::Lockstep), prefix: Some("eval42_".into()), ..Default::default() };
//! let cfg = PipelineConfig::load_arg("configs/sim.toml", &ov, kinds)?;
//! let mut opts = SessionOptions::new(LaunchOptions::current_exe()?);
//! opts.taps.push(services::PLANT_STATE.into());
//! let mut s = LockstepSession::start(&cfg, opts)?;        // children up, stale resources cleaned
//! for _ in 0..2000 {
//!     let out = s.step()?;                                  // tick k done by every stage
//!     if let Some(p) = out.get::<PlantState>(services::PLANT_STATE) { println!("{:?}", &p.q_phy_deg[..5]); }
//! }
//! let report = s.shutdown()?;                               // children exit, nothing left in /dev/shm
//! println!("{}", report.format_summary());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Each [`LockstepSession::step`] publishes `ClockTick` k and returns once every live stage has
//! reported tick k done; the samples of tick k of the tapped services are in the returned
//! [`TickOutputs`]. A session can also be the source of one service no stage produces
//! ([`SessionOptions::source`], e.g. the targets of a pipeline without a trajectory node): call
//! [`LockstepSession::step_with`] with each tick's sample.
//!
//! A child that dies mid-run is detected (its exit status is in [`TickOutputs::events`]); its
//! stages are declared stopped on its behalf, its iceoryx2 resources are removed, and it is
//! restarted between two ticks if its restart policy says so. A process lost for good (no
//! restart left) or a tick without progress within `[runtime] stall_timeout_ms` halts the run:
//! the launcher sends an e-stop and [`LockstepSession::step`] returns [`SessionError::Halted`];
//! [`LockstepSession::shutdown`] still stops everything and reports.
//!
//! # Faults and outcome
//!
//! The launcher watches every stage's status samples: a rise of its fault counter, a change to
//! degraded, fault hold or e-stop, and back, are [`FaultRecord`]s with their time, and the run's
//! [`Outcome`] (clean, recovered, not recovered, e-stop) follows from them and from the states at
//! the end; `bowden run` exits with [`Outcome::exit_code`].

use crate::cleanup::{self, CleanupReport};
use crate::config::{OnLoss, PipelineConfig};
use crate::launch::{LaunchOptions, SpawnError, Supervisor};
use crate::ports::{visit_payload, Input, Message, Output, PayloadVisitor, PortContext, PortError, Waiter, Wakeup};
use crate::stage::state;
use crate::stats::fmt_ns;
use crate::sys::{self, monotonic_ns, Reactor};
use bowden_interfaces::{fault, services, ClockTick, ComponentStatus, SafetyCommand};
use std::time::{Duration, Instant};

/// Why a session failed.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error(transparent)]
    Port(#[from] PortError),
    #[error(transparent)]
    Spawn(#[from] SpawnError),
    #[error("start-up: {0}")]
    Startup(String),
    #[error("tick {tick}: no progress for {waited_ms} ms, waiting for: {waiting}")]
    Stalled { tick: u64, waited_ms: u64, waiting: String },
    /// The launcher halted the run (a process lost for good, a stall): e-stop sent; call
    /// `shutdown` for the report.
    #[error("run halted at tick {tick}: {reason}")]
    Halted { tick: u64, reason: String },
    #[error("interrupted by signal")]
    Interrupted,
    #[error("{0}")]
    Usage(String),
    #[error("launcher: {0}")]
    Os(String),
    #[error(transparent)]
    ForeignFile(#[from] cleanup::ForeignFile),
}

/// Options of a session.
#[derive(Debug, Clone)]
pub struct SessionOptions {
    pub launch: LaunchOptions,
    /// Lockstep: the services read back per tick (full names, `bowden/...`), in
    /// [`TickOutputs::samples`].
    pub taps: Vec<String>,
    /// Lockstep: a service the session publishes itself, one sample per tick
    /// ([`LockstepSession::step_with`]); no stage of the pipeline may produce it.
    pub source: Option<String>,
    /// Print start-up, events and the summary to stderr.
    pub verbose: bool,
    /// Lockstep: halt after this long without progress in a tick (`None`: the config's
    /// `[runtime] stall_timeout_ms`).
    pub stall_timeout: Option<Duration>,
    /// Remove the prefix's remaining files at the end if no node is left (a per-run prefix).
    pub remove_prefix_files: bool,
    /// Real time: the run lasts until SIGINT/SIGTERM (for the start-up message only).
    pub until_signal: bool,
}

impl SessionOptions {
    pub fn new(launch: LaunchOptions) -> Self {
        Self {
            launch,
            taps: Vec::new(),
            source: None,
            verbose: false,
            stall_timeout: None,
            remove_prefix_files: true,
            until_signal: false,
        }
    }
}

/// Samples of one lockstep tick.
#[derive(Debug, Clone, Default)]
pub struct TickOutputs {
    pub tick: u64,
    pub t_sim_ns: u64,
    /// The tapped services' samples of this tick (service, the sample's bytes), in the order
    /// of [`SessionOptions::taps`]; a service that sent nothing this tick is absent.
    pub samples: Vec<(String, Vec<u8>)>,
    /// Supervision events during this tick (a process exited, was restarted).
    pub events: Vec<String>,
}

impl TickOutputs {
    /// The sample of `service` of this tick, if it was tapped and sent one.
    pub fn get<T: Message>(&self, service: &str) -> Option<T> {
        self.samples
            .iter()
            .find(|(s, _)| s == service)
            .and_then(|(_, b)| T::from_bytes(b))
    }
}

/// What a run did, for the exit summary.
#[derive(Debug, Clone, Default)]
pub struct RunReport {
    pub mode: String,
    /// From spawning to every stage ready.
    pub startup: Duration,
    pub ticks: u64,
    pub elapsed: Duration,
    /// Last status of every stage, in config order.
    pub statuses: Vec<(String, Option<ComponentStatus>)>,
    pub events: Vec<String>,
    pub cleanup_at_start: CleanupReport,
    pub forced_stops: Vec<(String, &'static str)>,
    pub files_removed: usize,
    /// Every fault the launcher saw, in time order (and the recoveries from them).
    pub faults: Vec<FaultRecord>,
    /// Why the launcher halted the run, when it did.
    pub halted: Option<String>,
    /// How the run ended.
    pub outcome: Outcome,
    /// Every status-reporting stage's state at the end of the run, before shutdown.
    pub end_states: Vec<(String, u32)>,
}

/// How a run ended, for its exit code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Outcome {
    /// No fault.
    #[default]
    Clean,
    /// Faults occurred; every stage was running again at the end.
    Recovered,
    /// A fault was still present at the end (a stage holding or degraded), or the launcher
    /// halted the run (a process lost for good, a stall).
    Unrecovered,
    /// An e-stop was latched at the end (and nothing else was unrecovered).
    EStop,
}

impl Outcome {
    /// `bowden run`'s exit code: 0 clean, 3 fault recovered, 4 fault not recovered, 5 e-stop
    /// latched (1 is an error that stopped bowden itself, 2 a usage error).
    pub fn exit_code(self) -> u8 {
        match self {
            Outcome::Clean => 0,
            Outcome::Recovered => 3,
            Outcome::Unrecovered => 4,
            Outcome::EStop => 5,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Clean => "clean",
            Outcome::Recovered => "fault recovered",
            Outcome::Unrecovered => "fault not recovered",
            Outcome::EStop => "e-stop latched",
        }
    }
}

/// One fault (or recovery) the launcher saw.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultRecord {
    /// Run time, s: simulated in lockstep, since the common start in real time.
    pub t_s: f64,
    /// Lockstep tick.
    pub tick: Option<u64>,
    /// Stage or process.
    pub source: String,
    pub what: String,
}

impl std::fmt::Display for FaultRecord {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.tick {
            Some(k) => write!(f, "t {:.3} s (tick {k}): {}: {}", self.t_s, self.source, self.what),
            None => write!(f, "t {:.3} s: {}: {}", self.t_s, self.source, self.what),
        }
    }
}

impl RunReport {
    /// The status of stage `name` at the end.
    pub fn status(&self, name: &str) -> Option<&ComponentStatus> {
        self.statuses
            .iter()
            .find(|(n, _)| n == name)
            .and_then(|(_, s)| s.as_ref())
    }

    /// The table printed at exit: one row per stage, latency since origin (real time).
    pub fn format_summary(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "bowden run ({}): start-up {} ms, {} ticks in {:.2} s",
            self.mode,
            self.startup.as_millis(),
            self.ticks,
            self.elapsed.as_secs_f64()
        );
        let _ = writeln!(
            s,
            "| stage | state | cycles | misses | rejected | faults | p50 | p99 | p99.9 | max |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
        );
        for (name, st) in &self.statuses {
            match st {
                Some(c) => {
                    let lat = |v: u64| if v == 0 { "-".to_string() } else { fmt_ns(v) };
                    // The final state, and what it was at the end of the run when that was
                    // not plain running ("stopped after fault hold").
                    let end = self.end_states.iter().find(|(n, _)| n == name).map(|e| e.1);
                    let shown = match end {
                        Some(e) if e != c.state && e != state::RUNNING => {
                            format!("{} after {}", state::name(c.state), state::name(e))
                        }
                        _ => state::name(c.state).to_string(),
                    };
                    let _ = writeln!(
                        s,
                        "| {name} | {shown} | {} | {} | {} | {} | {} | {} | {} | {} |",
                        c.cycles,
                        c.deadline_misses,
                        c.rejected_samples,
                        c.faults,
                        lat(c.latency_p50_ns),
                        lat(c.latency_p99_ns),
                        lat(c.latency_p999_ns),
                        lat(c.latency_max_ns)
                    );
                }
                None => {
                    let _ = writeln!(s, "| {name} | no status | | | | | | | | |");
                }
            }
        }
        for e in &self.events {
            let _ = writeln!(s, "event: {e}");
        }
        for (p, how) in &self.forced_stops {
            let _ = writeln!(s, "process `{p}` did not exit in time: {how}");
        }
        for f in &self.faults {
            let _ = writeln!(s, "fault: {f}");
        }
        if let Some(h) = &self.halted {
            let _ = writeln!(s, "halted: {h}");
        }
        let _ = writeln!(
            s,
            "outcome: {} (exit code {})",
            self.outcome.as_str(),
            self.outcome.exit_code()
        );
        s
    }

    /// The outcome from the faults seen and the stages' states at the end (before shutdown).
    fn classify(&mut self, states: &[u32]) {
        self.outcome = if self.halted.is_some() || states.iter().any(|&s| s == state::FAULT || s == state::DEGRADED) {
            Outcome::Unrecovered
        } else if states.contains(&state::ESTOP) {
            Outcome::EStop
        } else if !self.faults.is_empty() {
            Outcome::Recovered
        } else {
            Outcome::Clean
        };
    }
}

struct StageView {
    name: String,
    process: usize,
    /// Reports status (built-in, or external with `reports_status`).
    tracked: bool,
    alive: bool,
    started: bool,
    done: Option<u64>,
    last: Option<ComponentStatus>,
    /// The state and fault count last seen while the run was watched (not during shutdown).
    seen_state: u32,
    seen_faults: u64,
    /// Fault counts are reported at most once a second per stage (a camera counts every
    /// skipped frame): the time of the last such record and what was counted since.
    counted_at_s: Option<f64>,
    counted_since: u64,
    last_t_s: f64,
    /// When its last status arrived (real-time liveness).
    seen_at: Instant,
    /// Reads `bowden/safety` (an actuator): confirms an e-stop.
    takes_estop: bool,
    /// Has reported running at least once.
    ever_running: bool,
    /// A fault state was recorded and has not cleared yet.
    fault_open: bool,
}

/// The launcher's iceoryx2 side: clock, statuses, wake-ups.
struct Core {
    stages: Vec<StageView>,
    clock_out: Output<ClockTick>,
    clock_wakeup: Wakeup,
    status_out: Output<ComponentStatus>,
    status_in: Input<ComponentStatus>,
    status_waiter: Waiter,
    /// Per stage, wake-ups of its outputs (to release its consumers when it dies).
    out_wakeups: Vec<Vec<Wakeup>>,
    reactor: Reactor,
    ports: PortContext,
    safety_out: Output<SafetyCommand>,
    safety_wakeup: Wakeup,
    /// Record faults from statuses (off during shutdown: stopping stages are not faults).
    watch: bool,
    /// Subtracted from a status's `t_origin_ns` for the run time (the real-time start).
    t0_ns: u64,
    faults: Vec<FaultRecord>,
}

impl Core {
    fn new(cfg: &PipelineConfig) -> Result<Self, SessionError> {
        let ports = PortContext::new("launcher", &cfg.ipc())?;
        let mut reactor = Reactor::new().map_err(|e| SessionError::Os(format!("epoll: {e}")))?;
        let status_in = ports.input::<ComponentStatus>(services::COMPONENT_STATUS, 256)?;
        let status_waiter = ports.listener(services::COMPONENT_STATUS)?;
        reactor
            .add(status_waiter.fd())
            .map_err(|e| SessionError::Os(format!("epoll: {e}")))?;
        let mut out_wakeups = Vec::new();
        let mut stages = Vec::new();
        for s in &cfg.stages {
            let process = cfg.processes.iter().position(|p| p.name == s.process).unwrap_or(0);
            let mut w = Vec::new();
            for o in &s.outputs {
                w.push(ports.notifier(o)?);
            }
            out_wakeups.push(w);
            stages.push(StageView {
                name: s.name.clone(),
                process,
                tracked: cfg.processes[process].reports_status,
                alive: true,
                started: false,
                done: None,
                last: None,
                seen_state: state::RUNNING,
                seen_faults: 0,
                counted_at_s: None,
                counted_since: 0,
                last_t_s: 0.0,
                seen_at: Instant::now(),
                takes_estop: s.reads.iter().any(|(svc, _)| svc == services::SAFETY),
                ever_running: false,
                fault_open: false,
            });
        }
        Ok(Self {
            stages,
            clock_out: ports.output::<ClockTick>(services::CLOCK)?,
            clock_wakeup: ports.notifier(services::CLOCK)?,
            safety_out: ports.output::<SafetyCommand>(services::SAFETY)?,
            safety_wakeup: ports.notifier(services::SAFETY)?,
            watch: false,
            t0_ns: 0,
            faults: Vec::new(),
            status_out: ports.output::<ComponentStatus>(services::COMPONENT_STATUS)?,
            status_in,
            status_waiter,
            out_wakeups,
            reactor,
            ports,
        })
    }

    fn drain_statuses(&mut self) {
        self.status_waiter.drain();
        while let Some(st) = self.status_in.recv() {
            let name = st.name();
            let Some(v) = self.stages.iter_mut().find(|v| v.name == name) else {
                continue;
            };
            v.seen_at = Instant::now();
            if self.watch && st.state != state::STOPPED && st.state != state::STARTING {
                let t_s = st.header.t_origin_ns.saturating_sub(self.t0_ns) as f64 / 1e9;
                let tick = (self.t0_ns == 0).then_some(st.header.tick);
                let mut record = |what: String| {
                    self.faults.push(FaultRecord {
                        t_s,
                        tick,
                        source: v.name.clone(),
                        what,
                    })
                };
                v.last_t_s = t_s;
                if st.faults > v.seen_faults {
                    v.counted_since += st.faults - v.seen_faults;
                    if v.counted_at_s.is_none_or(|t| t_s - t >= 1.0) {
                        record(format!(
                            "{} fault(s) counted (last: {})",
                            v.counted_since,
                            fault::name(st.last_fault)
                        ));
                        v.counted_at_s = Some(t_s);
                        v.counted_since = 0;
                    }
                }
                if st.state != v.seen_state {
                    // A stage degraded before it ever ran (a camera waiting for the robot's
                    // first state) is starting up, not faulty; it still counts at the end if it
                    // never got going.
                    let starting = st.state == state::DEGRADED && !v.ever_running;
                    let what = match st.state {
                        state::RUNNING if v.fault_open => {
                            Some(format!("running again (was {})", state::name(v.seen_state)))
                        }
                        state::RUNNING => None,
                        state::FAULT => Some(format!("safe hold: {}", fault::name(st.last_fault))),
                        _ if starting => None,
                        s => Some(state::name(s).to_string()),
                    };
                    v.fault_open = st.state != state::RUNNING && !starting;
                    if let Some(what) = what {
                        record(what);
                    }
                }
                v.ever_running |= st.state == state::RUNNING;
                v.seen_faults = v.seen_faults.max(st.faults);
                v.seen_state = st.state;
            }
            // Our own "stopped on behalf of" samples come back too: they agree with our view.
            match st.state {
                state::STOPPED => v.alive = false,
                state::STARTING => {
                    v.alive = true;
                    v.started = true;
                }
                _ => {
                    v.alive = true;
                    v.started = true;
                    v.done = Some(st.header.tick);
                }
            }
            v.last = Some(st);
        }
    }

    fn wait(&self, timeout: Duration) -> Result<bool, SessionError> {
        let w = self
            .reactor
            .wait(Some(monotonic_ns() + timeout.as_nanos() as u64))
            .map_err(|e| SessionError::Os(format!("epoll: {e}")))?;
        Ok(w.terminate)
    }

    fn publish_clock(&mut self, tick: u64, t_sim_ns: u64, dt_ns: u64, shutdown: bool) -> Result<(), SessionError> {
        self.clock_out.publish(
            tick,
            t_sim_ns,
            ClockTick {
                t_sim_ns,
                dt_ns,
                shutdown: shutdown as u32,
                ..Default::default()
            },
        )?;
        self.clock_wakeup.notify()?;
        Ok(())
    }

    /// Declares the stages of a dead process stopped, so their consumers stop waiting for them.
    fn declare_dead(&mut self, process: usize, tick: u64) -> Result<(), SessionError> {
        for i in 0..self.stages.len() {
            if self.stages[i].process != process {
                continue;
            }
            self.stages[i].alive = false;
            let mut s = ComponentStatus {
                state: state::STOPPED,
                ..Default::default()
            };
            s.set_name(&self.stages[i].name);
            self.status_out.publish(tick, 0, s)?;
            for w in &self.out_wakeups[i] {
                w.notify()?;
            }
        }
        Ok(())
    }

    fn statuses(&self) -> Vec<(String, Option<ComponentStatus>)> {
        self.stages.iter().map(|v| (v.name.clone(), v.last)).collect()
    }

    /// Latches the e-stop of every actuator (the launcher's own reaction to a halt).
    fn estop(&mut self, tick: u64, t_ns: u64) -> Result<(), SessionError> {
        self.safety_out.publish(
            tick,
            t_ns,
            SafetyCommand {
                command: SafetyCommand::ESTOP,
                ..Default::default()
            },
        )?;
        self.safety_wakeup.notify()?;
        Ok(())
    }

    fn record(&mut self, t_s: f64, tick: Option<u64>, source: &str, what: String) {
        self.faults.push(FaultRecord {
            t_s,
            tick,
            source: source.to_string(),
            what,
        });
    }

    /// Stops watching (shutdown begins) and hands the faults and end states to the report.
    fn close(&mut self, report: &mut RunReport) {
        self.drain_statuses();
        self.watch = false;
        for v in self.stages.iter_mut().filter(|v| v.counted_since > 0) {
            self.faults.push(FaultRecord {
                t_s: v.last_t_s,
                tick: None,
                source: v.name.clone(),
                what: format!("{} more fault(s) counted by the end", v.counted_since),
            });
            v.counted_since = 0;
        }
        self.faults.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
        report.end_states = self
            .stages
            .iter()
            .filter(|v| v.tracked)
            .map(|v| (v.name.clone(), if v.started { v.seen_state } else { state::STARTING }))
            .collect();
        report.faults = std::mem::take(&mut self.faults);
        let states: Vec<u32> = self
            .stages
            .iter()
            .filter(|v| v.tracked && v.started)
            .map(|v| v.seen_state)
            .collect();
        report.classify(&states);
    }
}

/// Removes what a session leaves in shared memory when it is dropped without `shutdown` (an
/// error or a panic on the caller's side): declared last in a session, so it runs after the
/// supervisor has stopped the children and the launcher's node is gone.
struct CleanupGuard {
    ipc: crate::ports::IpcSettings,
    armed: bool,
    remove_files: bool,
}

impl Drop for CleanupGuard {
    fn drop(&mut self) {
        if self.armed {
            let _ = cleanup::remove_stale_nodes(&self.ipc);
            if self.remove_files {
                let _ = cleanup::remove_prefix_files(&self.ipc);
            }
        }
    }
}

/// Starts the children and waits until every status-reporting stage has announced itself.
fn start_common(
    cfg: &PipelineConfig,
    opts: &SessionOptions,
) -> Result<(Supervisor, Core, CleanupReport, Duration), SessionError> {
    sys::install_termination_handlers().map_err(|e| SessionError::Os(format!("signal handlers: {e}")))?;
    let ipc = cfg.ipc();
    // No file of the prefix may belong to another user (see `secure_prefix_files`).
    cleanup::secure_prefix_files(&ipc)?;
    // Before our own node exists (iceoryx2 would clean silently on node creation): so the
    // report says what a previous, killed run left behind.
    let cleanup_at_start = cleanup::remove_stale_nodes(&ipc)?;
    if opts.verbose && cleanup_at_start.dead_removed + cleanup_at_start.dead_failed > 0 {
        eprintln!(
            "launcher: removed stale iceoryx2 resources of {} dead node(s) under prefix `{}` ({} failed)",
            cleanup_at_start.dead_removed, ipc.prefix, cleanup_at_start.dead_failed
        );
    }
    let mut core = Core::new(cfg)?;
    // Our node created the management file (mode 0666 in iceoryx2 0.10): make it ours alone
    // before any child, estop or client opens it.
    let made_private = cleanup::secure_prefix_files(&ipc)?;
    if opts.verbose && made_private > 0 {
        eprintln!(
            "launcher: {made_private} iceoryx2 file(s) of prefix `{}` made private (mode 0600)",
            ipc.prefix
        );
    }
    let mut sup = Supervisor::new(cfg, opts.launch.clone());
    let t0 = Instant::now();
    // A failed or interrupted start-up stops what was started and leaves nothing behind.
    let guard = CleanupGuard {
        ipc: ipc.clone(),
        armed: true,
        remove_files: opts.remove_prefix_files,
    };
    let startup = wait_ready(cfg, &mut sup, &mut core, t0);
    if let Err(e) = startup {
        // No clock tick was sent yet: ask the others to stop now rather than wait for them.
        sup.signal_all(libc::SIGTERM);
        sup.stop_all(Duration::from_millis(cfg.runtime.shutdown_timeout_ms));
        drop(sup);
        drop(core);
        drop(guard);
        return Err(e);
    }
    let mut guard = guard;
    guard.armed = false;
    let startup = t0.elapsed();
    // Connect the clock to every subscriber now, so tick 0 reaches all.
    core.clock_out.update_connections()?;
    Ok((sup, core, cleanup_at_start, startup))
}

fn wait_ready(cfg: &PipelineConfig, sup: &mut Supervisor, core: &mut Core, t0: Instant) -> Result<(), SessionError> {
    sup.spawn_all()?;
    let deadline = t0 + Duration::from_millis(cfg.runtime.startup_timeout_ms);
    loop {
        core.drain_statuses();
        if core.stages.iter().all(|v| !v.tracked || v.started) {
            break;
        }
        if let Some((i, status, _)) = sup.poll_exits().into_iter().next() {
            return Err(SessionError::Startup(format!(
                "process `{}` exited during start-up ({status})",
                sup.spec(i).name
            )));
        }
        if Instant::now() >= deadline {
            let waiting: Vec<&str> = core
                .stages
                .iter()
                .filter(|v| v.tracked && !v.started)
                .map(|v| v.name.as_str())
                .collect();
            return Err(SessionError::Startup(format!(
                "no status from {} within {} ms",
                waiting.join(", "),
                cfg.runtime.startup_timeout_ms
            )));
        }
        if core.wait(Duration::from_millis(20))? {
            return Err(SessionError::Interrupted);
        }
    }
    Ok(())
}

/// A pipeline stepped tick by tick on a simulated clock. See the module documentation.
pub struct LockstepSession {
    cfg: PipelineConfig,
    opts: SessionOptions,
    tick: u64,
    t0: Instant,
    report: RunReport,
    source: Option<SourceOut>,
    taps: Vec<(String, Box<dyn Tap>)>,
    pending_restarts: Vec<usize>,
    // Field order = drop order: the supervisor stops children before our node goes away.
    sup: Supervisor,
    core: Core,
    guard: CleanupGuard,
}

/// A tapped service: hands out the bytes of the sample of tick k.
trait Tap {
    fn take(&mut self, tick: u64) -> Option<Vec<u8>>;
}

impl<T: Message> Tap for Input<T> {
    fn take(&mut self, tick: u64) -> Option<Vec<u8>> {
        self.take_tick(tick).map(|v| v.as_bytes().to_vec())
    }
}

/// Opens a tap of any sample service.
struct OpenTap<'a> {
    ports: &'a PortContext,
    service: &'a str,
}

impl PayloadVisitor for OpenTap<'_> {
    type Output = Result<Box<dyn Tap>, SessionError>;
    fn sample<T: Message>(self) -> Self::Output {
        Ok(Box::new(self.ports.input::<T>(self.service, 8)?))
    }
    fn frame(self) -> Self::Output {
        Err(SessionError::Usage(format!(
            "`{}` carries frames: a session taps fixed-size samples (record frames with a recorder)",
            self.service
        )))
    }
}

/// Type-erased publisher: (bytes of a sample, tick, t_sim) → publish and wake the consumers.
type PublishBytes = Box<dyn FnMut(&[u8], u64, u64) -> Result<(), SessionError>>;

/// The session's own source: publishes the caller's sample of each tick.
struct SourceOut {
    service: String,
    publish: PublishBytes,
}

struct OpenSource<'a> {
    ports: &'a PortContext,
    service: &'a str,
}

impl PayloadVisitor for OpenSource<'_> {
    type Output = Result<SourceOut, SessionError>;
    fn sample<T: Message>(self) -> Self::Output {
        let mut out = self.ports.output::<T>(self.service)?;
        let wake = self.ports.notifier(self.service)?;
        let service = self.service.to_string();
        let name = service.clone();
        Ok(SourceOut {
            service,
            publish: Box::new(move |bytes, tick, t_sim| {
                let v = T::from_bytes(bytes)
                    .ok_or_else(|| SessionError::Usage(format!("a sample of another type given for `{name}`")))?;
                out.publish(tick, t_sim, v)?;
                wake.notify()?;
                Ok(())
            }),
        })
    }
    fn frame(self) -> Self::Output {
        Err(SessionError::Usage(format!(
            "`{}` carries frames: a session publishes fixed-size samples only",
            self.service
        )))
    }
}

impl LockstepSession {
    /// Cleans stale resources of the prefix, starts every process of `cfg` (which must be in
    /// lockstep mode) and waits until all are ready.
    pub fn start(cfg: &PipelineConfig, opts: SessionOptions) -> Result<Self, SessionError> {
        if !cfg.lockstep() {
            return Err(SessionError::Usage(format!(
                "{}: a lockstep session needs `[runtime] mode = \"lockstep\"` (or the mode override)",
                cfg.origin
            )));
        }
        let (sup, core, cleanup_at_start, startup) = start_common(cfg, &opts)?;
        let p = &core.ports;
        let mut taps: Vec<(String, Box<dyn Tap>)> = Vec::new();
        for service in &opts.taps {
            let tap = visit_payload(service, OpenTap { ports: p, service })
                .unwrap_or_else(|| Err(SessionError::Usage(format!("cannot tap unknown service `{service}`"))))?;
            taps.push((service.clone(), tap));
        }
        let source = match &opts.source {
            Some(service) => {
                if let Some(i) = cfg.producer_of(service) {
                    return Err(SessionError::Usage(format!(
                        "the session cannot publish `{service}`: stage `{}` produces it",
                        cfg.stages[i].name
                    )));
                }
                Some(
                    visit_payload(service, OpenSource { ports: p, service })
                        .unwrap_or_else(|| Err(SessionError::Usage(format!("unknown service `{service}`"))))?,
                )
            }
            None => None,
        };
        let mut core = core;
        core.watch = true;
        if opts.verbose {
            eprintln!(
                "launcher: {} process(es) ready in {} ms (lockstep, prefix `{}`)",
                sup.len(),
                startup.as_millis(),
                cfg.runtime.prefix
            );
        }
        Ok(Self {
            cfg: cfg.clone(),
            tick: 0,
            t0: Instant::now(),
            report: RunReport {
                mode: "lockstep".into(),
                startup,
                cleanup_at_start,
                ..Default::default()
            },
            source,
            taps,
            pending_restarts: Vec::new(),
            guard: CleanupGuard {
                ipc: cfg.ipc(),
                armed: true,
                remove_files: opts.remove_prefix_files,
            },
            opts,
            sup,
            core,
        })
    }

    /// Ticks completed so far.
    pub fn ticks_done(&self) -> u64 {
        self.tick
    }

    /// Simulated time step, ns.
    pub fn dt_ns(&self) -> u64 {
        self.cfg.period_ns()
    }

    /// Process ids of the children, by process name.
    pub fn pids(&self) -> Vec<(String, u32)> {
        self.sup.pids()
    }

    /// The service the session publishes itself ([`SessionOptions::source`]), if any.
    pub fn source(&self) -> Option<&str> {
        self.source.as_ref().map(|s| s.service.as_str())
    }

    /// Runs one tick (a session without a [`SessionOptions::source`]).
    pub fn step(&mut self) -> Result<TickOutputs, SessionError> {
        if let Some(s) = &self.source {
            return Err(SessionError::Usage(format!(
                "the session publishes `{}`: give each tick's sample with step_with",
                s.service
            )));
        }
        self.step_inner(None)
    }

    /// Runs one tick, publishing `sample` (stamped with the tick and its simulated time) on
    /// the session's [`SessionOptions::source`] before the tick starts.
    pub fn step_with<T: Message>(&mut self, sample: T) -> Result<TickOutputs, SessionError> {
        if self.source.is_none() {
            return Err(SessionError::Usage(
                "the session has no source service (SessionOptions::source): use step".into(),
            ));
        }
        self.step_inner(Some(sample.as_bytes()))
    }

    fn step_inner(&mut self, sample: Option<&[u8]>) -> Result<TickOutputs, SessionError> {
        let k = self.tick;
        let dt = self.cfg.period_ns();
        let t_sim = k * dt;
        let mut out = TickOutputs {
            tick: k,
            t_sim_ns: t_sim,
            ..Default::default()
        };
        if let Some(reason) = &self.report.halted {
            return Err(SessionError::Halted {
                tick: k,
                reason: reason.clone(),
            });
        }
        // Restarts happen between ticks, so a new instance joins at a tick boundary.
        for i in std::mem::take(&mut self.pending_restarts) {
            self.restart_process(i, &mut out)?;
        }
        if let (Some(bytes), Some(src)) = (sample, self.source.as_mut()) {
            (src.publish)(bytes, k, t_sim)?;
        }
        self.core.publish_clock(k, t_sim, dt, false)?;
        let mut last_progress = Instant::now();
        let mut last_done = 0usize;
        let stall_timeout = self
            .opts
            .stall_timeout
            .unwrap_or(Duration::from_millis(self.cfg.runtime.stall_timeout_ms));
        loop {
            self.core.drain_statuses();
            let done = self
                .core
                .stages
                .iter()
                .filter(|v| !v.tracked || !v.alive || v.done.is_some_and(|d| d >= k))
                .count();
            if done == self.core.stages.len() {
                break;
            }
            if done != last_done {
                last_done = done;
                last_progress = Instant::now();
            }
            self.supervise(k, &mut out)?;
            if let Some(reason) = &self.report.halted {
                return Err(SessionError::Halted {
                    tick: k,
                    reason: reason.clone(),
                });
            }
            if sys::termination_requested() {
                return Err(SessionError::Interrupted);
            }
            if last_progress.elapsed() > stall_timeout {
                let waiting: Vec<String> = self
                    .core
                    .stages
                    .iter()
                    .filter(|v| v.tracked && v.alive && v.done.is_none_or(|d| d < k))
                    .map(|v| v.name.clone())
                    .collect();
                let e = SessionError::Stalled {
                    tick: k,
                    waited_ms: last_progress.elapsed().as_millis() as u64,
                    waiting: waiting.join(", "),
                };
                self.halt(k, "launcher", format!("{e} (hung?)"), &mut out)?;
                return Err(SessionError::Halted {
                    tick: k,
                    reason: e.to_string(),
                });
            }
            self.core.wait(Duration::from_millis(20))?;
        }
        // One more look: a child that died right at the end of the tick.
        self.supervise(k, &mut out)?;
        for (service, tap) in self.taps.iter_mut() {
            if let Some(b) = tap.take(k) {
                out.samples.push((service.clone(), b));
            }
        }
        self.tick += 1;
        Ok(out)
    }

    fn supervise(&mut self, k: u64, out: &mut TickOutputs) -> Result<(), SessionError> {
        for (i, status, success) in self.sup.poll_exits() {
            let name = self.sup.spec(i).name.clone();
            // Its resources (publisher slots, shared memory) must go before anyone reuses them.
            let cleaned = cleanup::remove_stale_nodes(&self.cfg.ipc())?;
            self.core.declare_dead(i, k)?;
            let restart = self.sup.wants_restart(i, success);
            let ev = format!(
                "tick {k}: process `{name}` exited ({status}); stale resources of {} node(s) removed; {}",
                cleaned.dead_removed,
                if restart {
                    "restarting at the next tick"
                } else if self.sup.spec(i).on_loss == OnLoss::Continue {
                    "not restarted, the others go on (on_loss = \"continue\")"
                } else {
                    "not restarted: e-stop, run halted"
                }
            );
            if self.opts.verbose {
                eprintln!("launcher: {ev}");
            }
            out.events.push(ev.clone());
            self.report.events.push(ev);
            let t_s = k as f64 * self.cfg.period_ns() as f64 / 1e9;
            self.core
                .record(t_s, Some(k), &format!("process {name}"), format!("exited ({status})"));
            if restart {
                self.pending_restarts.push(i);
            } else {
                self.sup.mark_gone(i);
                if self.sup.spec(i).on_loss == OnLoss::Halt {
                    self.halt(k, &format!("process {name}"), format!("lost for good ({status})"), out)?;
                }
            }
        }
        Ok(())
    }

    /// Halts the run: records why, latches the e-stop; `step` refuses from now on.
    fn halt(&mut self, k: u64, source: &str, why: String, out: &mut TickOutputs) -> Result<(), SessionError> {
        if self.report.halted.is_some() {
            return Ok(());
        }
        let t_ns = k * self.cfg.period_ns();
        self.core.record(
            t_ns as f64 / 1e9,
            Some(k),
            source,
            format!("{why}; e-stop sent, run halted"),
        );
        self.core.estop(k, t_ns)?;
        let reason = format!("{source}: {why}");
        if self.opts.verbose {
            eprintln!("launcher: halting: {reason}");
        }
        out.events.push(format!("halted: {reason}"));
        self.report.halted = Some(reason);
        Ok(())
    }

    fn restart_process(&mut self, i: usize, out: &mut TickOutputs) -> Result<(), SessionError> {
        self.sup.restart(i)?;
        for v in self.core.stages.iter_mut().filter(|v| v.process == i) {
            v.started = false;
        }
        let deadline = Instant::now() + Duration::from_millis(self.cfg.runtime.startup_timeout_ms);
        loop {
            self.core.drain_statuses();
            if self.core.stages.iter().filter(|v| v.process == i).all(|v| v.started) {
                break;
            }
            if let Some((_, status, _)) = self.sup.poll_exits().into_iter().find(|e| e.0 == i) {
                self.sup.mark_gone(i);
                let name = self.sup.spec(i).name.clone();
                let ev = format!("process `{name}` exited again during restart ({status})");
                out.events.push(ev.clone());
                self.report.events.push(ev);
                if self.sup.spec(i).on_loss == OnLoss::Continue {
                    return Ok(());
                }
                let k = self.tick;
                self.halt(
                    k,
                    &format!("process {name}"),
                    format!("exited again during restart ({status})"),
                    out,
                )?;
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(SessionError::Startup(format!(
                    "restarted process `{}` sent no status",
                    self.sup.spec(i).name
                )));
            }
            self.core.wait(Duration::from_millis(20))?;
        }
        self.core.clock_out.update_connections()?;
        let ev = format!(
            "tick {}: process `{}` restarted (restart {})",
            self.tick,
            self.sup.spec(i).name,
            self.sup.restarts(i)
        );
        out.events.push(ev.clone());
        self.report.events.push(ev);
        Ok(())
    }

    /// Sends the shutdown tick, waits for the children to exit (signalling stragglers), and
    /// removes what the run leaves in shared memory.
    pub fn shutdown(mut self) -> Result<RunReport, SessionError> {
        let k = self.tick;
        self.core.close(&mut self.report);
        self.core
            .publish_clock(k, k * self.cfg.period_ns(), self.cfg.period_ns(), true)?;
        let grace = Duration::from_millis(self.cfg.runtime.shutdown_timeout_ms);
        self.report.forced_stops = self.sup.stop_all(grace);
        self.core.drain_statuses();
        self.report.ticks = k;
        self.report.elapsed = self.t0.elapsed();
        self.report.statuses = self.core.statuses();
        let ipc = self.cfg.ipc();
        let remove_files = self.opts.remove_prefix_files;
        let report = std::mem::take(&mut self.report);
        self.guard.armed = false;
        drop(self);
        let mut report = report;
        cleanup::remove_stale_nodes(&ipc)?;
        if remove_files {
            report.files_removed = cleanup::remove_prefix_files(&ipc)?;
        }
        Ok(report)
    }
}

/// `bowden run` in real-time mode: start, supervise, stop.
pub struct RealtimeSession {
    cfg: PipelineConfig,
    opts: SessionOptions,
    start_ns: u64,
    report: RunReport,
    sup: Supervisor,
    core: Core,
    guard: CleanupGuard,
}

impl RealtimeSession {
    /// Cleans stale resources, starts every process, waits for them, and sends the common start
    /// time (a short lead ahead, so every periodic process starts on the same grid).
    pub fn start(cfg: &PipelineConfig, opts: SessionOptions) -> Result<Self, SessionError> {
        if cfg.lockstep() {
            return Err(SessionError::Usage(format!(
                "{}: a real-time session needs `[runtime] mode = \"realtime\"`",
                cfg.origin
            )));
        }
        let (sup, mut core, cleanup_at_start, startup) = start_common(cfg, &opts)?;
        let start_ns = monotonic_ns() + 20_000_000;
        core.publish_clock(0, start_ns, cfg.period_ns(), false)?;
        core.t0_ns = start_ns;
        core.watch = true;
        // Silence is measured from the common start: a process that waited long for the others
        // to start up sent no status meanwhile, and is not hung.
        let now = Instant::now();
        for v in core.stages.iter_mut() {
            v.seen_at = now;
        }
        if opts.verbose {
            eprintln!(
                "launcher: {} process(es) ready in {} ms (real time, prefix `{}`); running{}",
                sup.len(),
                startup.as_millis(),
                cfg.runtime.prefix,
                if opts.until_signal { " until Ctrl-C" } else { "" }
            );
        }
        Ok(Self {
            guard: CleanupGuard {
                ipc: cfg.ipc(),
                armed: true,
                remove_files: opts.remove_prefix_files,
            },
            cfg: cfg.clone(),
            opts,
            start_ns,
            report: RunReport {
                mode: "realtime".into(),
                startup,
                cleanup_at_start,
                ..Default::default()
            },
            sup,
            core,
        })
    }

    /// Process ids of the children.
    pub fn pids(&self) -> Vec<(String, u32)> {
        self.sup.pids()
    }

    /// Supervises until `duration` has passed (`None`: until SIGINT/SIGTERM).
    pub fn run_for(&mut self, duration: Option<Duration>) -> Result<(), SessionError> {
        let t0 = Instant::now();
        loop {
            if sys::termination_requested() {
                return Ok(());
            }
            if duration.is_some_and(|d| t0.elapsed() >= d) {
                return Ok(());
            }
            self.core.drain_statuses();
            for (i, status, success) in self.sup.poll_exits() {
                let name = self.sup.spec(i).name.clone();
                let cleaned = cleanup::remove_stale_nodes(&self.cfg.ipc())?;
                let restart = self.sup.wants_restart(i, success);
                let t_s = self.run_time_s();
                let ev = format!(
                    "{t_s:.3} s: process `{name}` exited ({status}); stale resources of {} node(s) removed; {}",
                    cleaned.dead_removed,
                    if restart {
                        "restarting"
                    } else if self.sup.spec(i).on_loss == OnLoss::Continue {
                        "not restarted, the others go on (on_loss = \"continue\")"
                    } else {
                        "not restarted: e-stop, run halted"
                    }
                );
                if self.opts.verbose {
                    eprintln!("launcher: {ev}");
                }
                self.report.events.push(ev);
                self.core
                    .record(t_s, None, &format!("process {name}"), format!("exited ({status})"));
                if restart {
                    self.sup.restart(i)?;
                    self.await_restart(i)?;
                } else {
                    self.sup.mark_gone(i);
                    if self.sup.spec(i).on_loss == OnLoss::Halt {
                        return self.halt(&format!("process {name}"), format!("lost for good ({status})"));
                    }
                }
            }
            if let Some((name, silent_ms)) = self.silent_stage() {
                return self.halt(
                    &format!("stage {name}"),
                    format!("no status for {silent_ms} ms (hung?)"),
                );
            }
            let left = duration
                .map(|d| d.saturating_sub(t0.elapsed()))
                .unwrap_or(Duration::from_millis(100));
            self.core.wait(left.min(Duration::from_millis(100)))?;
        }
    }

    /// Seconds since the common start (the time base of the run's fault records).
    pub fn run_time_s(&self) -> f64 {
        monotonic_ns().saturating_sub(self.start_ns) as f64 / 1e9
    }

    /// A status-reporting stage whose last status is older than `[runtime] liveness_ms`.
    fn silent_stage(&self) -> Option<(String, u64)> {
        let bound = Duration::from_millis(self.cfg.liveness_ms());
        self.core
            .stages
            .iter()
            .filter(|v| v.tracked && v.alive && v.started)
            .find(|v| v.seen_at.elapsed() > bound)
            .map(|v| (v.name.clone(), v.seen_at.elapsed().as_millis() as u64))
    }

    /// Halts the run: records why, latches the e-stop (and waits up to 200 ms for every
    /// stage that takes it to confirm), and ends `run_for`.
    fn halt(&mut self, source: &str, why: String) -> Result<(), SessionError> {
        let t_s = self.run_time_s();
        self.core
            .record(t_s, None, source, format!("{why}; e-stop sent, run halted"));
        let sent = Instant::now();
        self.core.estop(0, monotonic_ns())?;
        let until = sent + Duration::from_millis(200);
        let confirmed = loop {
            self.core.drain_statuses();
            let pending: Vec<&str> = self
                .core
                .stages
                .iter()
                .filter(|v| v.takes_estop && v.alive && v.seen_state != state::ESTOP)
                .map(|v| v.name.as_str())
                .collect();
            if pending.is_empty() {
                break Ok(sent.elapsed());
            }
            if Instant::now() >= until {
                break Err(pending.join(", "));
            }
            self.core.wait(Duration::from_millis(2))?;
        };
        let what = match confirmed {
            Ok(d) => format!("e-stop confirmed in {:.1} ms", d.as_secs_f64() * 1e3),
            Err(p) => format!("e-stop not confirmed within 200 ms by: {p}"),
        };
        let t_s = self.run_time_s();
        self.core.record(t_s, None, "launcher", what);
        let reason = format!("{source}: {why}");
        if self.opts.verbose {
            eprintln!("launcher: halting: {reason}");
        }
        self.report.events.push(format!("halted: {reason}"));
        self.report.halted = Some(reason);
        Ok(())
    }

    fn await_restart(&mut self, i: usize) -> Result<(), SessionError> {
        for v in self.core.stages.iter_mut().filter(|v| v.process == i) {
            v.started = false;
        }
        let deadline = Instant::now() + Duration::from_millis(self.cfg.runtime.startup_timeout_ms);
        while Instant::now() < deadline {
            self.core.drain_statuses();
            if self
                .core
                .stages
                .iter()
                .filter(|v| v.process == i)
                .all(|v| v.started || !v.tracked)
            {
                // The restarted process waits for a start tick: same grid as everyone else.
                let now = Instant::now();
                for v in self.core.stages.iter_mut().filter(|v| v.process == i) {
                    v.seen_at = now;
                }
                self.core.clock_out.update_connections()?;
                self.core.publish_clock(0, self.start_ns, self.cfg.period_ns(), false)?;
                let ev = format!(
                    "process `{}` restarted (restart {})",
                    self.sup.spec(i).name,
                    self.sup.restarts(i)
                );
                if self.opts.verbose {
                    eprintln!("launcher: {ev}");
                }
                self.report.events.push(ev);
                return Ok(());
            }
            self.core.wait(Duration::from_millis(20))?;
        }
        Err(SessionError::Startup(format!(
            "restarted process `{}` sent no status",
            self.sup.spec(i).name
        )))
    }

    /// Stops every process (shutdown tick, then signals if needed) and returns the summary.
    pub fn shutdown(mut self) -> Result<RunReport, SessionError> {
        let elapsed_ns = monotonic_ns().saturating_sub(self.start_ns);
        self.core.close(&mut self.report);
        self.core.publish_clock(0, 0, self.cfg.period_ns(), true)?;
        let grace = Duration::from_millis(self.cfg.runtime.shutdown_timeout_ms);
        self.report.forced_stops = self.sup.stop_all(grace);
        self.core.drain_statuses();
        self.report.ticks = elapsed_ns / self.cfg.period_ns().max(1);
        self.report.elapsed = Duration::from_nanos(elapsed_ns);
        self.report.statuses = self.core.statuses();
        let ipc = self.cfg.ipc();
        let remove_files = self.opts.remove_prefix_files;
        let report = std::mem::take(&mut self.report);
        self.guard.armed = false;
        drop(self);
        let mut report = report;
        cleanup::remove_stale_nodes(&ipc)?;
        if remove_files {
            report.files_removed = cleanup::remove_prefix_files(&ipc)?;
        }
        Ok(report)
    }
}
