//! The unit the scheduler runs: a [`Stage`] owns its input and output ports and does one
//! activation per call of [`Stage::step`]. One process hosts one stage (the default: every
//! component is its own OS process) or several in a fixed order (`process = "..."` in the config).
//!
//! A stage is written once for both modes: it reads each input with
//! `input.take(cx.lockstep, cx.tick)` (lockstep: the sample of this tick; real time: the newest),
//! stamps outputs with [`StepCx::clock_ns`] (lockstep: simulated time, so runs are reproducible)
//! and never blocks.

use crate::config::{PipelineConfig, StageSpec};
use crate::ports::{PortContext, PortError};
use crate::sys::monotonic_ns;

/// `ComponentStatus::state` values.
pub mod state {
    pub const STARTING: u32 = 0;
    pub const RUNNING: u32 = 1;
    pub const DEGRADED: u32 = 2;
    pub const STOPPED: u32 = 3;
    pub const ESTOP: u32 = 4;
}

/// Context of one activation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepCx {
    pub lockstep: bool,
    /// Lockstep: the tick being processed. Real time: the process's activation count (stages
    /// forward the tick of the sample they process instead).
    pub tick: u64,
    /// Lockstep: simulated time of the tick. Real time: monotonic time at activation.
    pub t_now_ns: u64,
    /// Lockstep: simulated time step. Real time: the activation period (0 if event-driven).
    pub dt_ns: u64,
    /// Real time, periodic: the nominal release time of this activation (its deadline origin).
    pub t_release_ns: u64,
}

impl StepCx {
    /// The time to stamp a new sample's `t_origin_ns` with: simulated in lockstep (reproducible),
    /// the monotonic clock in real time.
    #[inline]
    pub fn clock_ns(&self) -> u64 {
        if self.lockstep {
            self.t_now_ns
        } else {
            monotonic_ns()
        }
    }
}

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

/// What a stage factory gets to build a stage.
pub struct StageEnv<'a> {
    pub spec: &'a StageSpec,
    pub pipeline: &'a PipelineConfig,
    pub ports: &'a PortContext,
}

impl StageEnv<'_> {
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

    pub fn lockstep(&self) -> bool {
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

/// Builds the stage of a kind. The root binary provides one covering every component crate;
/// the recorder is built by the runtime itself.
pub type StageFactory<'f> = dyn Fn(&StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> + 'f;
