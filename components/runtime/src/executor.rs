//! The scheduler of one process: runs its stages in their fixed order, in lockstep or in real
//! time, keeps their latency statistics and publishes their health.
//!
//! **Lockstep** (a BSP superstep per tick): the launcher publishes `ClockTick` k on
//! `bowden/clock`. A stage handles tick k once every upstream stage (the producers of its
//! inputs) has reported "done with k" — a `ComponentStatus` whose `header.tick` is k — or is known
//! dead; at that point every input sample of tick k is already in its queues, because a stage
//! sends its outputs before its status. It then steps, publishes its status for k, and wakes
//! its consumers through the event services of its outputs. The launcher publishes k+1 when
//! every live stage is done with k. Nothing depends on wall time, so a run is the same bit for
//! bit on any machine and under any load.
//!
//! **Real time**: a periodic process sleeps until absolute deadlines `start + phase + k·period`
//! (timerfd, TIMER_ABSTIME; `start` is common to all processes, sent by the launcher) and runs
//! its stages in order; an event-driven process wakes when an input arrives from another process
//! (or after its watchdog timeout). Each step's compute time and each output's latency since its
//! origin go to HdrHistograms; a latency above the stage's deadline, a compute time above its
//! budget, and a skipped release are counted.
//!
//! The loop allocates nothing (see `tests/it/runtime_alloc.rs`) apart from iceoryx2's per-loan `Rc`,
//! served by [`crate::alloc::RtAlloc`]'s pool.

use crate::alloc;
use crate::config::{Activation, PipelineConfig};
use crate::node::Registry;
use crate::ports::{Input, Output, PortContext, PortError, Waiter, Wakeup};
use crate::rt::{self, RtReport};
use crate::stage::{state, Stage, StageBuildError, StageEnv, StepCx};
use crate::stats::{fmt_ns, LatencyHistogram, Percentiles};
use crate::sys::{self, monotonic_ns, Reactor};
use bowden_interfaces::{services, ClockTick, ComponentStatus};

/// Why a process could not run.
#[derive(Debug, thiserror::Error)]
pub enum ExecError {
    #[error("process `{0}` is not in the pipeline config")]
    UnknownProcess(String),
    #[error("process `{0}` is an external executable: the launcher starts it, not `bowden node`")]
    External(String),
    #[error(transparent)]
    Build(#[from] StageBuildError),
    #[error(transparent)]
    Port(#[from] PortError),
    #[error(transparent)]
    Stage(#[from] crate::stage::StageError),
    #[error("process `{process}`: {message}")]
    Os { process: String, message: String },
}

/// Options of [`run_process`].
#[derive(Debug, Clone, Copy, Default)]
pub struct ProcessOptions {
    /// Real time: start at once instead of waiting for the launcher's start tick.
    pub standalone: bool,
    /// Do not print the exit summary.
    pub quiet: bool,
}

/// Statistics of one stage over the run.
#[derive(Debug, Clone)]
pub struct StageStats {
    pub name: String,
    /// Activations (lockstep: ticks handled).
    pub cycles: u64,
    /// Activations that processed or published something.
    pub active: u64,
    /// Compute time of active steps.
    pub compute: LatencyHistogram,
    /// Latency of published samples since their origin (real time).
    pub latency: LatencyHistogram,
    /// Periodic processes: completion since the nominal release (includes wake-up lateness).
    pub response: LatencyHistogram,
    /// First stage of a periodic process: its status reports the response time.
    pub driver: bool,
    pub deadline_misses: u64,
    pub budget_overruns: u64,
    /// Real time, periodic: releases skipped because the process woke a whole period late.
    pub release_misses: u64,
    pub rejected: u64,
    pub faults: u64,
}

impl StageStats {
    fn new(name: &str) -> Self {
        Self {
            name: name.to_string(),
            cycles: 0,
            active: 0,
            compute: LatencyHistogram::new(),
            latency: LatencyHistogram::new(),
            response: LatencyHistogram::new(),
            driver: false,
            deadline_misses: 0,
            budget_overruns: 0,
            release_misses: 0,
            rejected: 0,
            faults: 0,
        }
    }

    /// The distribution status samples report: the response time since release for the stage
    /// that drives a periodic process (it shows the wake-up jitter), else the latency since the
    /// origin of what the stage published, else its compute time.
    pub fn reported(&self) -> Percentiles {
        if self.driver && self.response.count() > 0 {
            self.response.percentiles()
        } else if self.latency.count() > 0 {
            self.latency.percentiles()
        } else {
            self.compute.percentiles()
        }
    }
}

/// Heap allocations of the cycle, measured on the cycle thread with [`alloc::thread_counts`]
/// (meaningful when [`alloc::RtAlloc`] is the global allocator, as in the `bowden` binary).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AllocAudit {
    /// Cycles ignored at the start (first-use buffers, lazy initialisation).
    pub warmup: u64,
    pub seen: u64,
    /// Cycles measured after the warm-up.
    pub cycles: u64,
    /// Of those, cycles that called the system allocator.
    pub cycles_with_system: u64,
    pub system_allocs: u64,
    /// Pool blocks taken (iceoryx2's per-loan `Rc`: one per published sample).
    pub pool_allocs: u64,
}

impl AllocAudit {
    pub const WARMUP_CYCLES: u64 = 100;

    fn record(&mut self, d: alloc::AllocCounts) {
        self.seen += 1;
        if self.seen <= self.warmup {
            return;
        }
        self.cycles += 1;
        self.system_allocs += d.system_allocs;
        self.pool_allocs += d.pool_allocs;
        if d.system_allocs > 0 {
            self.cycles_with_system += 1;
        }
    }
}

/// What a process did, returned when it exits.
#[derive(Debug, Clone)]
pub struct ProcessReport {
    pub process: String,
    pub rt: Option<RtReport>,
    /// Real time, periodic: wake-up lateness after each release.
    pub wake_latency: LatencyHistogram,
    pub stages: Vec<StageStats>,
    pub extra: Vec<String>,
    pub alloc: AllocAudit,
}

struct Upstream {
    name: String,
    /// Hosted by this process (ran before, in order): never waited for.
    local: bool,
    alive: bool,
    done: Option<u64>,
}

struct Slot {
    name: String,
    stage: Box<dyn Stage>,
    stats: StageStats,
    wakeups: Vec<Wakeup>,
    upstream: Vec<Upstream>,
    deadline_ns: Option<u64>,
    budget_ns: Option<u64>,
    /// State in the last status published (a change is published at once).
    published_state: u32,
}

struct Executor {
    process: String,
    lockstep: bool,
    activation: Activation,
    status_period_ns: u64,
    slots: Vec<Slot>,
    status_out: Output<ComponentStatus>,
    status_wakeup: Wakeup,
    status_in: Option<Input<ComponentStatus>>,
    clock_in: Input<ClockTick>,
    clock_waiter: Waiter,
    waiters: Vec<Waiter>,
    reactor: Reactor,
    wake_latency: LatencyHistogram,
    audit: AllocAudit,
    // Declared last: dropped after every port created from it.
    _ports: PortContext,
}

fn os_err(process: &str, what: &str, e: std::io::Error) -> ExecError {
    ExecError::Os {
        process: process.to_string(),
        message: format!("{what}: {e}"),
    }
}

/// Runs process `process` of `cfg` until the launcher's shutdown tick or SIGINT/SIGTERM,
/// building each of its stages with its kind's constructor from `kinds`.
// Long: one process's life in order (set-up, real-time settings, the loop, status, shutdown); the loop is `Scheduler`'s.
pub fn run_process(
    cfg: &PipelineConfig,
    process: &str,
    kinds: Registry,
    opts: &ProcessOptions,
) -> Result<ProcessReport, ExecError> {
    let pspec = cfg
        .process(process)
        .ok_or_else(|| ExecError::UnknownProcess(process.to_string()))?
        .clone();
    if pspec.exec.is_some() {
        return Err(ExecError::External(process.to_string()));
    }
    sys::install_termination_handlers().map_err(|e| os_err(process, "signal handlers", e))?;
    let lockstep = cfg.lockstep();

    let ports = PortContext::new(process, &cfg.ipc())?;
    let mut slots = Vec::new();
    let local_stages: Vec<&str> = pspec.stages.iter().map(|&i| cfg.stages[i].name.as_str()).collect();
    for &i in &pspec.stages {
        let spec = &cfg.stages[i];
        let kind = kinds.get(&spec.kind).ok_or_else(|| StageBuildError {
            stage: spec.name.clone(),
            message: format!(
                "no built-in node of kind `{}` (known: {})",
                spec.kind,
                kinds.names().join(", ")
            ),
        })?;
        let env = StageEnv {
            spec,
            kind,
            pipeline: cfg,
            ports: &ports,
        };
        let stage: Box<dyn Stage> = (kind.build)(&env)?;
        let mut wakeups = Vec::new();
        for out in &spec.outputs {
            wakeups.push(ports.notifier(out)?);
        }
        let upstream = cfg
            .upstream_of(i)
            .into_iter()
            .map(|u| {
                let name = cfg.stages[u].name.clone();
                Upstream {
                    local: local_stages.contains(&name.as_str()),
                    name,
                    alive: true,
                    done: None,
                }
            })
            .collect();
        let mut stats = StageStats::new(&spec.name);
        stats.driver = slots.is_empty() && !lockstep && matches!(pspec.activation, Activation::Periodic { .. });
        slots.push(Slot {
            name: spec.name.clone(),
            stage,
            stats,
            wakeups,
            upstream,
            deadline_ns: spec.deadline_ns,
            budget_ns: spec.budget_ns,
            published_state: state::STARTING,
        });
    }

    // Wake on inputs produced by other processes. A periodic real-time process wakes on its
    // timer only: it creates no listeners (nobody would drain them between its releases).
    let mut reactor = Reactor::new().map_err(|e| os_err(process, "epoll", e))?;
    let mut waiters = Vec::new();
    let mut seen: Vec<&str> = Vec::new();
    let event_driven = lockstep || matches!(pspec.activation, Activation::Event { .. });
    for &i in pspec.stages.iter().filter(|_| event_driven) {
        for inp in cfg.stages[i].inputs.iter().chain(cfg.stages[i].side_inputs.iter()) {
            let produced_here = pspec.stages.iter().any(|&j| cfg.stages[j].outputs.contains(inp));
            if produced_here || seen.contains(&inp.as_str()) {
                continue;
            }
            seen.push(inp);
            let w = ports.listener(inp)?;
            reactor.add(w.fd()).map_err(|e| os_err(process, "epoll add", e))?;
            waiters.push(w);
        }
    }
    // Work arriving from outside iceoryx2 (the bridge's network queue) wakes the process too.
    if event_driven {
        for slot in &slots {
            if let Some(fd) = slot.stage.wake_fd() {
                reactor.add(fd).map_err(|e| os_err(process, "epoll add", e))?;
            }
        }
    }
    let clock_in = ports.input::<ClockTick>(services::CLOCK, 8)?;
    let clock_waiter = ports.listener(services::CLOCK)?;
    reactor
        .add(clock_waiter.fd())
        .map_err(|e| os_err(process, "epoll add", e))?;
    let status_in = if lockstep {
        Some(ports.input::<ComponentStatus>(services::COMPONENT_STATUS, 256)?)
    } else {
        None
    };
    let status_out = ports.output::<ComponentStatus>(services::COMPONENT_STATUS)?;
    let status_wakeup = ports.notifier(services::COMPONENT_STATUS)?;

    // Real-time placement, then the allocation pool (resident after mlockall).
    let rt_report = match (&pspec.rt, lockstep) {
        (Some(s), false) => {
            let r = rt::apply(s);
            if !opts.quiet {
                for w in r.warnings() {
                    eprintln!("[{process}] warning: {w}");
                }
            }
            Some(r)
        }
        _ => None,
    };
    alloc::enable_pool();

    let mut ex = Executor {
        process: process.to_string(),
        lockstep,
        activation: pspec.activation,
        status_period_ns: cfg.runtime.status_period_ms * 1_000_000,
        slots,
        status_out,
        status_wakeup,
        status_in,
        clock_in,
        clock_waiter,
        waiters,
        reactor,
        wake_latency: LatencyHistogram::new(),
        audit: AllocAudit {
            warmup: AllocAudit::WARMUP_CYCLES,
            ..Default::default()
        },
        _ports: ports,
    };
    // Ports are up: tell the launcher (the ready handshake).
    for i in 0..ex.slots.len() {
        ex.publish_status(i, 0, 0, state::STARTING)?;
    }
    ex.status_wakeup.notify()?;

    let run = if lockstep {
        ex.run_lockstep()
    } else {
        ex.run_realtime(opts.standalone)
    };
    let mut extra = Vec::new();
    let mut finish_err = None;
    for s in ex.slots.iter_mut() {
        if let Err(e) = s.stage.finish() {
            finish_err.get_or_insert(e);
        }
        extra.extend(s.stage.summary());
    }
    for i in 0..ex.slots.len() {
        let _ = ex.publish_status(i, u64::MAX, 0, state::STOPPED);
    }
    let _ = ex.status_wakeup.notify();
    for s in &ex.slots {
        for w in &s.wakeups {
            let _ = w.notify();
        }
    }
    let report = ProcessReport {
        process: ex.process.clone(),
        rt: rt_report,
        wake_latency: ex.wake_latency.clone(),
        stages: ex.slots.iter().map(|s| s.stats.clone()).collect(),
        extra,
        alloc: ex.audit,
    };
    if !opts.quiet {
        eprint!("{}", format_report(&report, lockstep));
    }
    run?;
    if let Some(e) = finish_err {
        return Err(e.into());
    }
    Ok(report)
}

impl Executor {
    fn publish_status(&mut self, i: usize, tick: u64, t_origin_ns: u64, st: u32) -> Result<(), PortError> {
        let slot = &mut self.slots[i];
        let c = slot.stage.counters();
        slot.stats.rejected = c.rejected;
        slot.stats.faults = c.faults;
        let p = slot.stats.reported();
        let state = if st == state::RUNNING { state::of(&c) } else { st };
        let mut s = ComponentStatus {
            state,
            last_fault: c.last_fault,
            cycles: slot.stats.cycles,
            deadline_misses: slot.stats.deadline_misses + slot.stats.release_misses,
            rejected_samples: c.rejected,
            faults: c.faults,
            ..Default::default()
        };
        // Lockstep statuses are part of the simulated run: wall-clock figures stay out of them.
        if !self.lockstep {
            s.latency_p50_ns = p.p50_ns;
            s.latency_p99_ns = p.p99_ns;
            s.latency_p999_ns = p.p999_ns;
            s.latency_max_ns = p.max_ns;
        }
        s.set_name(&slot.name);
        slot.published_state = state;
        self.status_out.publish(tick, t_origin_ns, s)?;
        Ok(())
    }

    fn drain_waiters(&self) {
        for w in &self.waiters {
            w.drain();
        }
        self.clock_waiter.drain();
    }

    /// Applies the status samples received so far to every slot's upstream view.
    fn refresh_upstreams(&mut self) {
        let Some(si) = self.status_in.as_mut() else { return };
        while let Some(st) = si.recv() {
            let name = st.name();
            for slot in self.slots.iter_mut() {
                for u in slot.upstream.iter_mut() {
                    if u.name != name {
                        continue;
                    }
                    match st.state {
                        state::STOPPED => u.alive = false,
                        state::STARTING => u.alive = true,
                        _ => {
                            u.alive = true;
                            u.done = Some(st.header.tick);
                        }
                    }
                }
            }
        }
    }

    fn ready(&self, i: usize, tick: u64) -> bool {
        self.slots[i]
            .upstream
            .iter()
            .all(|u| u.local || !u.alive || u.done.is_some_and(|d| d >= tick))
    }

    fn run_lockstep(&mut self) -> Result<(), ExecError> {
        loop {
            // The next tick from the launcher.
            let tick = loop {
                if let Some(t) = self.clock_in.recv() {
                    break t;
                }
                let wake = self
                    .reactor
                    .wait(Some(monotonic_ns() + 200_000_000))
                    .map_err(|e| os_err(&self.process, "epoll wait", e))?;
                self.drain_waiters();
                if wake.terminate {
                    return Ok(());
                }
            };
            if tick.shutdown != 0 {
                return Ok(());
            }
            let a0 = alloc::thread_counts();
            let k = tick.header.tick;
            let cx = StepCx::lockstep(k, tick.t_sim_ns, tick.dt_ns);
            for i in 0..self.slots.len() {
                loop {
                    self.refresh_upstreams();
                    if self.ready(i, k) {
                        break;
                    }
                    let wake = self
                        .reactor
                        .wait(Some(monotonic_ns() + 200_000_000))
                        .map_err(|e| os_err(&self.process, "epoll wait", e))?;
                    self.drain_waiters();
                    if wake.terminate {
                        return Ok(());
                    }
                }
                let t0 = monotonic_ns();
                let rep = self.slots[i].stage.step(&cx)?;
                let t1 = monotonic_ns();
                let slot = &mut self.slots[i];
                slot.stats.cycles += 1;
                if rep.active {
                    slot.stats.active += 1;
                    slot.stats.compute.record(t1 - t0);
                }
                self.publish_status(i, k, cx.t_now_ns(), state::RUNNING)?;
                for w in &self.slots[i].wakeups {
                    w.notify()?;
                }
                self.status_wakeup.notify()?;
            }
            self.audit.record(alloc::thread_counts().since(&a0));
        }
    }

    /// Real time: waits for the launcher's start tick; returns the common start time, or `None`
    /// on shutdown/termination.
    fn wait_for_start(&mut self) -> Result<Option<u64>, ExecError> {
        loop {
            if let Some(t) = self.clock_in.latest() {
                if t.shutdown != 0 {
                    return Ok(None);
                }
                return Ok(Some(if t.t_sim_ns > 0 { t.t_sim_ns } else { monotonic_ns() }));
            }
            let wake = self
                .reactor
                .wait(Some(monotonic_ns() + 200_000_000))
                .map_err(|e| os_err(&self.process, "epoll wait", e))?;
            self.drain_waiters();
            if wake.terminate {
                return Ok(None);
            }
        }
    }

    fn shutdown_requested(&mut self) -> bool {
        if sys::termination_requested() {
            return true;
        }
        matches!(self.clock_in.latest(), Some(t) if t.shutdown != 0)
    }

    fn step_all(&mut self, cx: &StepCx) -> Result<(), ExecError> {
        let periodic = matches!(self.activation, Activation::Periodic { .. });
        for i in 0..self.slots.len() {
            let t0 = monotonic_ns();
            let rep = self.slots[i].stage.step(cx)?;
            let t1 = monotonic_ns();
            let slot = &mut self.slots[i];
            slot.stats.cycles += 1;
            if !rep.active {
                continue;
            }
            slot.stats.active += 1;
            let compute = t1 - t0;
            slot.stats.compute.record(compute);
            if slot.budget_ns.is_some_and(|b| compute > b) {
                slot.stats.budget_overruns += 1;
            }
            if let Some(origin) = rep.t_origin_ns {
                slot.stats.latency.record(t1.saturating_sub(origin));
            }
            // Periodic: the deadline counts from the nominal release (classic response time);
            // event-driven: from the origin of the sample that triggered the work.
            let since = if periodic {
                Some(cx.t_release_ns())
            } else {
                rep.t_origin_ns
            };
            if let Some(t) = since {
                let lat = t1.saturating_sub(t);
                if periodic {
                    slot.stats.response.record(lat);
                }
                if slot.deadline_ns.is_some_and(|d| lat > d) {
                    slot.stats.deadline_misses += 1;
                }
            }
            for w in &slot.wakeups {
                w.notify()?;
            }
        }
        Ok(())
    }

    /// Publishes every stage's status each status period, and a stage's at once when its state
    /// changed (e-stop latched or released, hold entered or left): operators and tools such as
    /// `bowden estop` see transitions within a cycle, not a status period later.
    fn maybe_status(&mut self, now: u64, next_status: &mut u64, tick: u64) -> Result<(), ExecError> {
        if now < *next_status {
            let mut changed = false;
            for i in 0..self.slots.len() {
                let st = state::of(&self.slots[i].stage.counters());
                if st != self.slots[i].published_state {
                    self.publish_status(i, tick, now, state::RUNNING)?;
                    changed = true;
                }
            }
            if changed {
                self.status_wakeup.notify()?;
            }
            return Ok(());
        }
        *next_status = now + self.status_period_ns;
        for i in 0..self.slots.len() {
            self.publish_status(i, tick, now, state::RUNNING)?;
        }
        self.status_wakeup.notify()?;
        Ok(())
    }

    fn run_realtime(&mut self, standalone: bool) -> Result<(), ExecError> {
        let start = if standalone {
            monotonic_ns()
        } else {
            match self.wait_for_start()? {
                Some(t) => t,
                None => return Ok(()),
            }
        };
        let mut next_status = monotonic_ns() + self.status_period_ns;
        let mut cycle: u64 = 0;
        match self.activation {
            Activation::Periodic { period_ns, phase_ns } => {
                let mut release = start + phase_ns;
                // A late start (the launcher's lead time already passed) joins the grid.
                let now = monotonic_ns();
                if now > release {
                    let behind = (now - release) / period_ns + 1;
                    release += behind * period_ns;
                    cycle += behind;
                }
                loop {
                    // clock_nanosleep(TIMER_ABSTIME): the release grid never drifts. A signal
                    // interrupts it; the shutdown tick is polled once per period.
                    sys::sleep_until_ns(release);
                    if self.shutdown_requested() {
                        return Ok(());
                    }
                    let now = monotonic_ns();
                    if now < release {
                        continue; // interrupted early by a signal that did not terminate
                    }
                    let a0 = alloc::thread_counts();
                    self.wake_latency.record(now - release);
                    let cx = StepCx::realtime(cycle, now, period_ns, release);
                    self.step_all(&cx)?;
                    let done = monotonic_ns();
                    self.maybe_status(done, &mut next_status, cycle)?;
                    self.audit.record(alloc::thread_counts().since(&a0));
                    cycle += 1;
                    release += period_ns;
                    if done > release {
                        // Overran into the next period(s): skip them rather than burst to catch up.
                        let missed = (done - release) / period_ns + 1;
                        if let Some(s) = self.slots.first_mut() {
                            s.stats.release_misses += missed;
                        }
                        release += missed * period_ns;
                        cycle += missed;
                    }
                }
            }
            Activation::Event { timeout_ns } => {
                // The stage's own watchdog deadline, re-armed after each step.
                let mut step_deadline = timeout_ns.map(|t| monotonic_ns() + t);
                loop {
                    let a0 = alloc::thread_counts();
                    // Also wake for the status period: a process whose inputs went quiet still
                    // reports, so the launcher can tell a quiet stage from a hung one.
                    let deadline = step_deadline.map_or(next_status, |d| d.min(next_status));
                    let wake = self
                        .reactor
                        .wait(Some(deadline))
                        .map_err(|e| os_err(&self.process, "epoll wait", e))?;
                    self.drain_waiters();
                    if wake.terminate || self.shutdown_requested() {
                        return Ok(());
                    }
                    let now = monotonic_ns();
                    let status_only = wake.ready_mask == 0 && step_deadline.is_none_or(|d| now < d);
                    if !status_only {
                        let cx = StepCx::realtime(cycle, now, 0, now);
                        self.step_all(&cx)?;
                        cycle += 1;
                        step_deadline = timeout_ns.map(|t| monotonic_ns() + t);
                    }
                    self.maybe_status(monotonic_ns(), &mut next_status, cycle)?;
                    self.audit.record(alloc::thread_counts().since(&a0));
                }
            }
        }
    }
}

/// The exit summary of a process, as printed to stderr.
pub fn format_report(r: &ProcessReport, lockstep: bool) -> String {
    let mut s = String::new();
    use std::fmt::Write;
    let _ = writeln!(
        s,
        "[{}] exit summary ({}):",
        r.process,
        if lockstep { "lockstep" } else { "realtime" }
    );
    if let Some(rt) = &r.rt {
        let _ = writeln!(s, "  rt: {rt}");
    }
    if r.wake_latency.count() > 0 {
        let _ = writeln!(s, "  wake-up lateness: {}", r.wake_latency.percentiles());
    }
    for st in &r.stages {
        let _ = writeln!(
            s,
            "  {}: cycles={} active={} misses={} overruns={} skipped-releases={} rejected={} faults={}",
            st.name,
            st.cycles,
            st.active,
            st.deadline_misses,
            st.budget_overruns,
            st.release_misses,
            st.rejected,
            st.faults
        );
        if st.compute.count() > 0 {
            let _ = writeln!(s, "    compute: {}", st.compute.percentiles());
        }
        if st.response.count() > 0 {
            let _ = writeln!(s, "    response since release: {}", st.response.percentiles());
        }
        if st.latency.count() > 0 {
            let p = st.latency.percentiles();
            let _ = writeln!(
                s,
                "    latency since origin: n={} p50={} p99={} p99.9={} max={}",
                p.count,
                fmt_ns(p.p50_ns),
                fmt_ns(p.p99_ns),
                fmt_ns(p.p999_ns),
                fmt_ns(p.max_ns)
            );
        }
    }
    if r.alloc.seen > 0 {
        let a = &r.alloc;
        let _ = writeln!(
            s,
            "  allocations after {} warm-up cycles: system {} in {} cycles ({} cycles allocated), pool blocks {} ({:.2}/cycle)",
            a.warmup,
            a.system_allocs,
            a.cycles,
            a.cycles_with_system,
            a.pool_allocs,
            a.pool_allocs as f64 / a.cycles.max(1) as f64
        );
    }
    for line in &r.extra {
        let _ = writeln!(s, "  {line}");
    }
    s
}
