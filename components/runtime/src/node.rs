//! The node contract: what a node declares about its ports, and what the runtime derives from
//! it. A node is a pure step over declared ports ([`crate::stage::Stage::step`]); it never sees
//! the transport or the scheduling mode. Each input carries a [`Read`] policy that says what the
//! node wants of it; the runtime maps the policy onto lockstep or real time
//! ([`crate::ports::Input::next`]) and onto the dataflow (which producers a lockstep tick waits
//! for, which inputs wake an event-driven process).

use crate::stage::{Stage, StageBuildError, StageEnv};

/// How a node reads one input, and what the input means for the schedule.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Read {
    /// The dataflow input of the tick: lockstep reads the sample of this tick and waits for
    /// its producer; real time reads the newest and an arrival wakes an event-driven process.
    Tick,
    /// Read like [`Read::Tick`] when present, but neither waited for nor woken by: a hint from
    /// upstream (the estimator's IK start from the motor command).
    Hint,
    /// Every sample of earlier ticks, oldest first; neither waited for nor woken by: a feedback
    /// path from downstream (joint estimates into the compensator) or an announcement (model
    /// updates). Lockstep reads only ticks before this one, so the result does not depend on
    /// which process happened to run first.
    Feedback,
    /// Every sample as it arrives; wakes the process, never waited for (the e-stop).
    Side,
}

impl Read {
    /// Does a lockstep tick wait for this input's producer?
    pub fn waited_for(self) -> bool {
        self == Read::Tick
    }

    /// Does an arrival wake an event-driven process?
    pub fn wakes(self) -> bool {
        matches!(self, Read::Tick | Read::Side)
    }
}

/// One input a node kind declares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputDecl {
    /// Service name without namespace (`bowden/...`).
    pub service: &'static str,
    pub read: Read,
    /// Queue depth of the subscriber.
    pub buffer: usize,
}

impl InputDecl {
    pub const fn new(service: &'static str, read: Read, buffer: usize) -> Self {
        Self { service, read, buffer }
    }
}

/// How a kind runs in real time unless its `[[node]]` says otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Schedule {
    /// Woken at absolute deadlines (else when an input arrives).
    pub periodic: bool,
    /// A periodic kind's own period, when it is not the pipeline's (`runtime.period_us`).
    pub period_us: Option<u64>,
    /// Event-driven: wake after this long without an input (a watchdog).
    pub wake_timeout_us: Option<u64>,
    /// Latency bound of what it publishes, counted as deadline misses.
    pub deadline_us: Option<u64>,
}

impl Schedule {
    /// Woken at the pipeline's period; no deadline.
    pub const PERIODIC: Schedule = Schedule {
        periodic: true,
        period_us: None,
        wake_timeout_us: None,
        deadline_us: None,
    };
    /// Woken by its inputs; no watchdog, no deadline.
    pub const EVENT: Schedule = Schedule {
        periodic: false,
        period_us: None,
        wake_timeout_us: None,
        deadline_us: None,
    };
}

/// Ports of a kind that depend on its parameters (a bridge's export/import lists, a
/// recorder's services).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ParamPorts {
    pub inputs: Vec<(String, Read)>,
    pub outputs: Vec<String>,
}

/// Reads a kind's ports from its `[node.params]`; the error says what is wrong with them.
pub type PortsFromParams = fn(&toml::Table) -> Result<ParamPorts, ParamPortsError>;

/// What is wrong with the service lists of a node's `[node.params]` (a bridge's `export` and
/// `import`, a recorder's `services`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParamPortsError {
    #[error("{what}")]
    Missing { what: &'static str },
    #[error("`{key}` must be an array of service names")]
    NotAnArray { key: &'static str },
    #[error("`{key}` must be an array of strings")]
    NotStrings { key: &'static str },
    #[error("`{key}`: unknown service `{service}` (known: {})", crate::ports::known_services().join(", "))]
    UnknownService { key: &'static str, service: String },
    #[error("`{key}`: service `{service}` listed twice")]
    Twice { key: &'static str, service: String },
    #[error("`{key}`: `{service}` {why}")]
    Refused {
        key: &'static str,
        service: String,
        why: &'static str,
    },
    #[error("service `{service}` is both exported and imported")]
    BothWays { service: String },
}

/// The service names of list `key` in `params` (empty when absent): known services, each once,
/// none that `refuse` gives a reason against.
pub fn service_list(
    params: &toml::Table,
    key: &'static str,
    refuse: impl Fn(&str) -> Option<&'static str>,
) -> Result<Vec<String>, ParamPortsError> {
    let Some(v) = params.get(key) else {
        return Ok(Vec::new());
    };
    let arr = v.as_array().ok_or(ParamPortsError::NotAnArray { key })?;
    let mut out: Vec<String> = Vec::new();
    for s in arr {
        let s = s.as_str().ok_or(ParamPortsError::NotStrings { key })?;
        let service = s.to_string();
        if !crate::ports::is_service(s) {
            return Err(ParamPortsError::UnknownService { key, service });
        }
        if let Some(why) = refuse(s) {
            return Err(ParamPortsError::Refused { key, service, why });
        }
        if out.contains(&service) {
            return Err(ParamPortsError::Twice { key, service });
        }
        out.push(service);
    }
    Ok(out)
}

/// Builds a node of one kind from its `[[node]]` (parameters, pipeline, ports).
pub type BuildFn = fn(&StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError>;

/// A kind of node: its declared ports, schedule and constructor. The pipeline validator, the
/// lockstep dataflow, the wake-up sets and the session taps are all derived from these
/// declarations; the runtime knows no kind by name but its own recorder.
#[derive(Debug, Clone, Copy)]
pub struct NodeKind {
    /// `kind = "..."` in a pipeline file.
    pub kind: &'static str,
    /// One line for `bowden nodes` and error messages.
    pub summary: &'static str,
    pub inputs: &'static [InputDecl],
    pub outputs: &'static [&'static str],
    pub schedule: Schedule,
    /// The kind's ports depend on its `[node.params]`: they replace `inputs`/`outputs`.
    pub ports_from_params: Option<PortsFromParams>,
    /// Why this kind cannot run in lockstep, if it cannot (a bridge joins two machines'
    /// clocks).
    pub lockstep_refusal: Option<&'static str>,
    pub build: BuildFn,
}

impl NodeKind {
    /// The declared input on `service`, if any.
    pub fn input(&self, service: &str) -> Option<&'static InputDecl> {
        self.inputs.iter().find(|d| d.service == service)
    }
}

/// The node kinds a program knows, by name: the one table that maps `kind` to constructor.
#[derive(Debug, Clone, Copy)]
pub struct Registry(pub &'static [&'static NodeKind]);

impl Registry {
    pub fn get(&self, kind: &str) -> Option<&'static NodeKind> {
        self.0.iter().copied().find(|k| k.kind == kind)
    }

    /// The kinds' names, in table order.
    pub fn names(&self) -> Vec<&'static str> {
        self.0.iter().map(|k| k.kind).collect()
    }

    pub fn kinds(&self) -> impl Iterator<Item = &'static NodeKind> {
        self.0.iter().copied()
    }
}
