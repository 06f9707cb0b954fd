//! The unit the scheduler runs: a [`Stage`] owns its input and output ports and does one
//! activation per call of [`Stage::step`]. One process hosts one stage (the default: every
//! component is its own OS process) or several in a fixed order (`process = "..."` in the config).
//!
//! A stage is written once for both modes and never names the mode: it reads each input with
//! [`crate::ports::Input::next`], whose declared [`Read`] policy the runtime maps onto the mode
//! (lockstep: the sample of this tick; real time: the newest), stamps outputs with
//! [`StepCx::out_tick`] and [`StepCx::clock_ns`] (lockstep: simulated time, so runs are
//! reproducible) and never blocks.

use crate::config::{PipelineConfig, StageSpec};
use crate::node::{NodeKind, Read};
use crate::ports::{FrameInput, FrameOutput, Input, Message, Output, PortContext, PortError};
use crate::sys::monotonic_ns;

/// `ComponentStatus::state` values.
pub mod state {
    pub const STARTING: u32 = 0;
    pub const RUNNING: u32 = 1;
    pub const DEGRADED: u32 = 2;
    pub const STOPPED: u32 = 3;
    pub const ESTOP: u32 = 4;
    /// Safe hold after a fault the stage detected (robot state not finite, out of range, stale,
    /// missing); latched until it clears as configured or a person releases it.
    pub const FAULT: u32 = 5;

    /// The state a stage's counters report while it runs (e-stop over fault hold over degraded).
    pub fn of(c: &super::StageCounters) -> u32 {
        if c.estop {
            ESTOP
        } else if c.fault_hold {
            FAULT
        } else if c.degraded {
            DEGRADED
        } else {
            RUNNING
        }
    }

    /// A short name for reports.
    pub fn name(s: u32) -> &'static str {
        match s {
            STARTING => "starting",
            RUNNING => "running",
            DEGRADED => "degraded",
            STOPPED => "stopped",
            ESTOP => "e-stop",
            FAULT => "fault hold",
            _ => "?",
        }
    }
}

/// Context of one activation: what a node may ask of the tick it runs in. The scheduling mode
/// stays inside the runtime: inputs are read with their declared [`Read`] policy
/// ([`crate::ports::Input::next`]), outputs are stamped with [`StepCx::out_tick`] and
/// [`StepCx::clock_ns`], a simulation advances by [`StepCx::time_step_ns`]; a node that genuinely
/// needs a policy (a time budget, waiting for a helper thread) asks [`StepCx::reproducible`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepCx {
    reproducible: bool,
    tick: u64,
    t_now_ns: u64,
    dt_ns: u64,
    t_release_ns: u64,
}

impl StepCx {
    /// A lockstep activation: tick `tick` at simulated time `t_sim_ns`, step `dt_ns`.
    pub fn lockstep(tick: u64, t_sim_ns: u64, dt_ns: u64) -> Self {
        Self {
            reproducible: true,
            tick,
            t_now_ns: t_sim_ns,
            dt_ns,
            t_release_ns: t_sim_ns,
        }
    }

    /// A real-time activation number `activation`, woken at monotonic `t_now_ns` for the
    /// release `t_release_ns` of a period `period_ns` (0: event-driven).
    pub fn realtime(activation: u64, t_now_ns: u64, period_ns: u64, t_release_ns: u64) -> Self {
        Self {
            reproducible: false,
            tick: activation,
            t_now_ns,
            dt_ns: period_ns,
            t_release_ns,
        }
    }

    /// Is this run reproducible bit for bit (lockstep)? Then nothing may depend on wall time or
    /// on the machine's speed: no time budget, and a helper thread's answer is waited for.
    #[inline]
    pub fn reproducible(&self) -> bool {
        self.reproducible
    }

    /// The number of this activation: the clock tick in lockstep, the process's activation
    /// count in real time. A source (a node without inputs) stamps its samples with it.
    #[inline]
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// When this activation started: simulated time in lockstep, the monotonic clock at
    /// wake-up in real time.
    #[inline]
    pub fn t_now_ns(&self) -> u64 {
        self.t_now_ns
    }

    /// The nominal time step: the simulated step in lockstep, the period in real time (0 for
    /// an event-driven process).
    #[inline]
    pub fn dt_ns(&self) -> u64 {
        self.dt_ns
    }

    /// Periodic real time: the nominal release of this activation (its deadline origin).
    #[inline]
    pub fn t_release_ns(&self) -> u64 {
        self.t_release_ns
    }

    /// The time to stamp a new sample's `t_origin_ns` with: simulated in lockstep (reproducible),
    /// the monotonic clock now in real time.
    #[inline]
    pub fn clock_ns(&self) -> u64 {
        if self.reproducible {
            self.t_now_ns
        } else {
            monotonic_ns()
        }
    }

    /// The tick an output of this activation carries, given the tick of the newest input it
    /// derives from: in lockstep every output of tick k belongs to k (also a hold sent without
    /// a new input); in real time the input's tick is forwarded, so a sample can be traced to
    /// the target it came from across processes.
    #[inline]
    pub fn out_tick(&self, input_tick: u64) -> u64 {
        if self.reproducible {
            self.tick
        } else {
            input_tick
        }
    }

    /// How far a simulation advances in this activation, at `now_ns` (from [`Self::clock_ns`])
    /// after the previous step at `t_prev_ns`: the tick's step in lockstep; in real time the
    /// time that actually passed (at least 1 ns; the nominal step on the first activation),
    /// so a simulated robot keeps pace with the wall clock even after a late wake-up.
    #[inline]
    pub fn time_step_ns(&self, now_ns: u64, t_prev_ns: Option<u64>) -> u64 {
        if self.reproducible {
            self.dt_ns
        } else {
            t_prev_ns.map(|t| now_ns.saturating_sub(t)).unwrap_or(self.dt_ns).max(1)
        }
    }
}

/// Queue depth of an input whose kind declares none (ports from parameters).
const DEFAULT_INPUT_BUFFER: usize = 64;

/// What one activation did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StepReport {
    /// Something was processed or published.
    pub active: bool,
    /// `t_origin_ns` of the newest sample published, for latency accounting.
    pub t_origin_ns: Option<u64>,
}

impl StepReport {
    pub const IDLE: StepReport = StepReport {
        active: false,
        t_origin_ns: None,
    };

    pub fn published(t_origin_ns: u64) -> Self {
        Self {
            active: true,
            t_origin_ns: Some(t_origin_ns),
        }
    }
}

/// Health counters a stage keeps (published in its `ComponentStatus`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StageCounters {
    /// Input samples rejected as invalid (NaN/inf, out of range, wrong size).
    pub rejected: u64,
    /// Watchdog faults (stale inputs) and other recoverable faults.
    pub faults: u64,
    /// Currently degraded (holding, missing inputs).
    pub degraded: bool,
    /// E-stop latched.
    pub estop: bool,
    /// Holding safely after a fault it detected (`state::FAULT`).
    pub fault_hold: bool,
    /// The last fault detected (`bowden_interfaces::fault` codes, 0 = none).
    pub last_fault: u32,
}

/// A stage failed in a way it cannot recover from (the process exits non-zero; the supervisor
/// reports it and restarts it if configured).
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error(transparent)]
    Port(#[from] PortError),
    #[error("stage `{stage}`: {message}")]
    Fatal { stage: String, message: String },
}

/// One component inside the scheduler.
pub trait Stage {
    /// One activation: read inputs, compute, publish. Must not block; should not allocate.
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError>;

    /// Health counters for status samples.
    fn counters(&self) -> StageCounters {
        StageCounters::default()
    }

    /// Called once before the process exits (flush files, hold actuators).
    fn finish(&mut self) -> Result<(), StageError> {
        Ok(())
    }

    /// A file descriptor that, when readable, means this stage has work that did not arrive on
    /// an iceoryx2 input (a network bridge's receive queue). An event-driven process wakes on
    /// it as on its inputs; the stage resets it in `step`.
    fn wake_fd(&self) -> Option<std::os::fd::RawFd> {
        None
    }

    /// Extra lines for the exit summary.
    fn summary(&self) -> Vec<String> {
        Vec::new()
    }
}

/// What a node kind's constructor gets to build a stage.
pub struct StageEnv<'a> {
    pub spec: &'a StageSpec,
    /// The kind's declaration (ports, schedule).
    pub kind: &'static NodeKind,
    pub pipeline: &'a PipelineConfig,
    pub ports: &'a PortContext,
}

impl StageEnv<'_> {
    /// The stage's input on `service`, read with its declared [`Read`] policy; an undeclared
    /// input is an error (the declaration is what the validator and the scheduler know).
    pub fn input<T: Message>(&self, service: &str) -> Result<Input<T>, StageBuildError> {
        let read = self.read_of(service)?;
        let buffer = self.kind.input(service).map_or(DEFAULT_INPUT_BUFFER, |d| d.buffer);
        Ok(self.ports.input::<T>(service, buffer)?.with_read(read))
    }

    /// The stage's frame input on `service` (always [`Read::Tick`]).
    pub fn frame_input(&self, service: &str) -> Result<FrameInput, StageBuildError> {
        self.read_of(service)?;
        let buffer = self.kind.input(service).map_or(2, |d| d.buffer);
        Ok(self.ports.frame_input(service, buffer)?)
    }

    /// The stage's output on `service`; an undeclared output is an error.
    pub fn output<T: Message>(&self, service: &str) -> Result<Output<T>, StageBuildError> {
        self.check_output(service)?;
        Ok(self.ports.output::<T>(service)?)
    }

    /// The stage's frame output on `service`, for frames of up to `max_len` bytes.
    pub fn frame_output(&self, service: &str, max_len: usize) -> Result<FrameOutput, StageBuildError> {
        self.check_output(service)?;
        Ok(self.ports.frame_output(service, max_len)?)
    }

    fn read_of(&self, service: &str) -> Result<Read, StageBuildError> {
        self.spec
            .reads
            .iter()
            .find(|(s, _)| s == service)
            .map(|(_, r)| *r)
            .ok_or_else(|| {
                self.error(format!(
                    "opens input `{service}`, which kind `{}` does not declare",
                    self.kind.kind
                ))
            })
    }

    fn check_output(&self, service: &str) -> Result<(), StageBuildError> {
        if self.spec.outputs.iter().any(|o| o == service) {
            Ok(())
        } else {
            Err(self.error(format!(
                "opens output `{service}`, which kind `{}` does not declare",
                self.kind.kind
            )))
        }
    }

    /// Is a service of this pipeline produced by some stage? (A consumer may open an optional
    /// path only when its producer exists, e.g. model updates.)
    pub fn produced(&self, service: &str) -> bool {
        self.pipeline.producer_of(service).is_some()
    }

    /// The robot description file of the pipeline (`[runtime] robot = "..."`), resolved
    /// against the config's directory; `None` for the shipped robot.
    pub fn robot_file(&self) -> Option<std::path::PathBuf> {
        self.pipeline.runtime.robot.as_ref().map(|p| self.pipeline.resolve(p))
    }

    /// A path parameter resolved against the pipeline config's directory.
    pub fn resolve(&self, p: impl AsRef<std::path::Path>) -> std::path::PathBuf {
        self.pipeline.resolve(p)
    }

    /// Deserialises the stage's `[node.params]` into `T` (`deny_unknown_fields` recommended),
    /// with errors naming the config, the stage and the field.
    pub fn params<T: serde::de::DeserializeOwned>(&self) -> Result<T, StageBuildError> {
        T::deserialize(toml::Value::Table(self.spec.params.clone())).map_err(|e| StageBuildError {
            stage: self.spec.name.clone(),
            message: format!(
                "{}: [node.params] of `{}`: {}",
                self.pipeline.origin,
                self.spec.name,
                e.to_string().replace('\n', " ")
            ),
        })
    }

    /// Will this stage run reproducibly bit for bit (lockstep)? For choices made once at
    /// build time (no time budget, helper threads that are waited for); per activation, ask
    /// [`StepCx::reproducible`].
    pub fn reproducible(&self) -> bool {
        self.pipeline.lockstep()
    }

    /// Builds a [`StageBuildError`] for this stage.
    pub fn error(&self, message: impl std::fmt::Display) -> StageBuildError {
        StageBuildError {
            stage: self.spec.name.clone(),
            message: message.to_string(),
        }
    }
}

/// A stage could not be built (bad parameters, missing file, port creation failed).
#[derive(Debug, thiserror::Error)]
#[error("stage `{stage}`: {message}")]
pub struct StageBuildError {
    pub stage: String,
    pub message: String,
}

impl From<PortError> for StageBuildError {
    fn from(e: PortError) -> Self {
        StageBuildError {
            stage: String::new(),
            message: e.to_string(),
        }
    }
}
