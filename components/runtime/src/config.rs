//! Pipeline configuration (`configs/sim.toml` and friends): which stages run, grouped into which
//! processes, in which scheduling mode, under which shared-memory prefix; validated on load with
//! errors that name the file and the field.
//!
//! ```toml
//! [runtime]
//! mode = "realtime"        # or "lockstep"
//! prefix = "bowden_"       # iceoryx2 shared-memory prefix
//! period_us = 1000         # control period (lockstep: simulated time step)
//!
//! [[node]]
//! name = "compensator"     # also the process name unless `process` groups stages
//! restart = "on-failure"
//! [node.rt]
//! sched_fifo = true
//! priority = 80
//! [node.params]            # read by the node's component crate
//! mode = "uncalibrated"
//! ```

use crate::node::{ParamPorts, Read, Registry};
use crate::ports::{is_service, known_services, IpcSettings};
use crate::rt::RtSettings;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The default simulated pipeline, embedded so `bowden run` works from any directory.
pub const SIM_DEFAULT_TOML: &str = include_str!("../../../configs/sim.toml");
/// Name under which [`SIM_DEFAULT_TOML`] is addressed on command lines (`--config @sim`).
pub const SIM_DEFAULT_NAME: &str = "@sim";

pub use bowden_interfaces::config::ConfigError;

/// Scheduling mode of a run.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Deserialize,
    Serialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "lowercase")]
#[strum(serialize_all = "lowercase")]
pub enum Mode {
    /// Simulated clock advanced by the launcher; bit-for-bit reproducible.
    Lockstep,
    /// Periodic wake-ups at absolute deadlines on the monotonic clock.
    Realtime,
}

impl Mode {
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }

    /// Parses the spelling of [`Mode::as_str`].
    pub fn parse(s: &str) -> Option<Mode> {
        s.parse().ok()
    }
}

/// What the supervisor does when a process exits on its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    /// Report it; the others keep running.
    #[default]
    Never,
    /// Restart after a non-zero exit or a signal.
    OnFailure,
    /// Restart after any exit.
    Always,
}

/// What the launcher does when a process is lost for good (exited with no restart left).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnLoss {
    /// Latch the e-stop and halt the run (not recovered): a pipeline without its driver,
    /// controller or command source must not go on.
    #[default]
    Halt,
    /// Report it and go on: a helper whose loss leaves the robot safe (online adaptation keeps
    /// the last good model; a recorder's file ends early).
    Continue,
}

/// `[runtime]`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RuntimeSection {
    pub mode: Mode,
    #[serde(default = "default_prefix")]
    pub prefix: String,
    #[serde(default)]
    pub namespace: String,
    /// Control period in real time; simulated time step in lockstep, µs.
    pub period_us: u64,
    /// Stop after this many ticks (lockstep) — `bowden run --ticks` overrides.
    #[serde(default)]
    pub ticks: Option<u64>,
    /// Stop after this many seconds (real time) — `bowden run --seconds` overrides.
    #[serde(default)]
    pub seconds: Option<f64>,
    #[serde(default = "default_startup_timeout_ms")]
    pub startup_timeout_ms: u64,
    #[serde(default = "default_shutdown_timeout_ms")]
    pub shutdown_timeout_ms: u64,
    /// Real time: how often every stage publishes its `ComponentStatus`.
    #[serde(default = "default_status_period_ms")]
    pub status_period_ms: u64,
    /// Real time: a stage whose last status is older than this is hung: the launcher latches
    /// the e-stop and halts the run. Default 3 × `status_period_ms`. (The 1 kHz chain's own
    /// bounds are tighter: the actuator's command watchdog and robot-state age.)
    #[serde(default)]
    pub liveness_ms: Option<u64>,
    /// Lockstep: a tick without progress for this long halts the run (a hung process). Wall
    /// time, not simulated: a lockstep tick takes as long as its computation, and a loaded
    /// 2-core machine running many pipelines at once has taken seconds for one.
    #[serde(default = "default_stall_timeout_ms")]
    pub stall_timeout_ms: u64,
    /// Robot description for the stages that need one (relative to this file); the shipped
    /// robot when absent.
    #[serde(default)]
    pub robot: Option<PathBuf>,
    /// Seed of every random process in the run (plant noise, camera noise, generators).
    #[serde(default)]
    pub seed: u64,
}

fn default_prefix() -> String {
    "bowden_".into()
}
fn default_startup_timeout_ms() -> u64 {
    10_000
}
fn default_shutdown_timeout_ms() -> u64 {
    3_000
}
fn default_status_period_ms() -> u64 {
    1_000
}
fn default_stall_timeout_ms() -> u64 {
    10_000
}

/// One `[[node]]`: a stage of the pipeline.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct NodeSection {
    /// Stage name (unique, ≤ 32 bytes, `[a-z0-9_-]`): status samples and logs use it.
    pub name: String,
    /// Component kind (trajectory, compensator, actuator, plant, camera, estimator, recorder);
    /// defaults to `name`.
    #[serde(default)]
    pub kind: Option<String>,
    /// Process that hosts the stage; stages naming the same process run in it in config order.
    /// Defaults to `name` (one process per stage).
    #[serde(default)]
    pub process: Option<String>,
    /// `false` leaves the stage out of the run.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// External executable and arguments replacing the built-in node (hardware-in-the-loop).
    #[serde(default)]
    pub exec: Option<Vec<String>>,
    /// Services read each tick (override; defaults from the kind). Full names, e.g. `bowden/joint_command`.
    #[serde(default)]
    pub inputs: Option<Vec<String>>,
    /// Services written (override; defaults from the kind).
    #[serde(default)]
    pub outputs: Option<Vec<String>>,
    #[serde(default)]
    pub restart: RestartPolicy,
    #[serde(default = "default_max_restarts")]
    pub max_restarts: u32,
    /// What losing this process for good (exited, no restart left) does to the run.
    #[serde(default)]
    pub on_loss: OnLoss,
    /// Real-time placement of the process (first stage of a process decides).
    #[serde(default)]
    pub rt: Option<RtSettings>,
    /// Real time: activation period of a periodic process, µs (default: `[runtime] period_us`
    /// for periodic kinds).
    #[serde(default)]
    pub period_us: Option<u64>,
    /// Real time: offset of this process's releases from the common start, µs.
    #[serde(default)]
    pub phase_us: Option<u64>,
    /// Real time: an event-driven process wakes at least this often even without input (the
    /// actuator's watchdog needs it), µs.
    #[serde(default)]
    pub wake_timeout_us: Option<u64>,
    /// Real time: latest completion after the sample's origin, µs; later is a deadline miss.
    #[serde(default)]
    pub deadline_us: Option<u64>,
    /// Real time: compute-time budget of one step, µs; more is a budget overrun.
    #[serde(default)]
    pub budget_us: Option<u64>,
    /// External nodes: the launcher waits for their `ComponentStatus` before starting.
    #[serde(default)]
    pub reports_status: Option<bool>,
    /// Kind-specific parameters, read by the component.
    #[serde(default)]
    pub params: toml::Table,
}

fn yes() -> bool {
    true
}
fn default_max_restarts() -> u32 {
    3
}

/// The file as written.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PipelineFile {
    pub runtime: RuntimeSection,
    #[serde(rename = "node", default)]
    pub nodes: Vec<NodeSection>,
}

/// How a process is woken in real-time mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// At absolute deadlines `start + phase + k·period`.
    Periodic { period_ns: u64, phase_ns: u64 },
    /// When an input arrives from another process, or after `timeout_ns` without one.
    Event { timeout_ns: Option<u64> },
}

/// One stage after validation.
#[derive(Debug, Clone, PartialEq)]
pub struct StageSpec {
    pub name: String,
    pub kind: String,
    pub process: String,
    /// Dataflow inputs ([`Read::Tick`]): waited for in lockstep, wake an event-driven process.
    pub inputs: Vec<String>,
    /// [`Read::Side`]: wake the process, never waited for.
    pub side_inputs: Vec<String>,
    /// [`Read::Hint`] and [`Read::Feedback`]: neither waited for nor woken by.
    pub passive_inputs: Vec<String>,
    /// Every input with its read policy (the three lists above are views of it).
    pub reads: Vec<(String, Read)>,
    pub outputs: Vec<String>,
    pub deadline_ns: Option<u64>,
    pub budget_ns: Option<u64>,
    pub params: toml::Table,
}

/// One OS process of the pipeline.
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessSpec {
    pub name: String,
    /// Stage indices into [`PipelineConfig::stages`], in execution order.
    pub stages: Vec<usize>,
    pub exec: Option<Vec<String>>,
    pub restart: RestartPolicy,
    pub max_restarts: u32,
    pub on_loss: OnLoss,
    pub rt: Option<RtSettings>,
    pub activation: Activation,
    /// Whether the launcher waits for this process's status samples (always for built-in nodes).
    pub reports_status: bool,
}

/// Where a configuration came from (children are given the same).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConfigOrigin {
    File(PathBuf),
    Embedded(&'static str),
}

impl std::fmt::Display for ConfigOrigin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ConfigOrigin::File(p) => write!(f, "{}", p.display()),
            ConfigOrigin::Embedded(n) => write!(f, "{n} (embedded configs/sim.toml)"),
        }
    }
}

impl ConfigOrigin {
    /// The `--config` argument that designates it.
    pub fn arg(&self) -> String {
        match self {
            ConfigOrigin::File(p) => p.display().to_string(),
            ConfigOrigin::Embedded(n) => n.to_string(),
        }
    }
}

/// Command-line overrides applied identically by the launcher and every child.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overrides {
    pub mode: Option<Mode>,
    pub prefix: Option<String>,
    pub namespace: Option<String>,
    /// Path of the recorder's log (every recorder stage).
    pub record_path: Option<PathBuf>,
    pub seed: Option<u64>,
}

impl Overrides {
    /// Arguments that reproduce these overrides on a `bowden node` command line.
    pub fn to_args(&self) -> Vec<String> {
        let mut a = Vec::new();
        if let Some(m) = self.mode {
            a.extend(["--mode".to_string(), m.as_str().to_string()]);
        }
        if let Some(p) = &self.prefix {
            a.extend(["--prefix".to_string(), p.clone()]);
        }
        if let Some(n) = &self.namespace {
            a.extend(["--namespace".to_string(), n.clone()]);
        }
        if let Some(r) = &self.record_path {
            a.extend(["--record".to_string(), r.display().to_string()]);
        }
        if let Some(s) = self.seed {
            a.extend(["--seed".to_string(), s.to_string()]);
        }
        a
    }
}

/// A validated pipeline.
#[derive(Debug, Clone, PartialEq)]
pub struct PipelineConfig {
    pub origin: ConfigOrigin,
    pub overrides: Overrides,
    /// Directory relative paths are resolved against.
    pub base_dir: PathBuf,
    pub runtime: RuntimeSection,
    pub stages: Vec<StageSpec>,
    pub processes: Vec<ProcessSpec>,
}

fn valid_name(n: &str) -> bool {
    !n.is_empty()
        && n.len() <= 32
        && n.bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

impl PipelineConfig {
    /// Loads `arg`: a file path, or [`SIM_DEFAULT_NAME`] for the embedded default.
    pub fn load_arg(arg: &str, ov: &Overrides, kinds: Registry) -> Result<Self, ConfigError> {
        if arg == SIM_DEFAULT_NAME {
            Self::embedded_sim(ov, kinds)
        } else {
            Self::load(Path::new(arg), ov, kinds)
        }
    }

    /// Loads and validates a pipeline file; `kinds` are the node kinds the program knows.
    pub fn load(path: &Path, ov: &Overrides, kinds: Registry) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            origin: path.display().to_string(),
            source,
        })?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::parse(&text, ConfigOrigin::File(path.to_path_buf()), base, ov, kinds)
    }

    /// The embedded default (`configs/sim.toml`); relative paths resolve against `./configs`.
    pub fn embedded_sim(ov: &Overrides, kinds: Registry) -> Result<Self, ConfigError> {
        Self::parse(
            SIM_DEFAULT_TOML,
            ConfigOrigin::Embedded(SIM_DEFAULT_NAME),
            PathBuf::from("configs"),
            ov,
            kinds,
        )
    }

    /// Parses and validates TOML text.
    pub fn parse(
        text: &str,
        origin: ConfigOrigin,
        base_dir: PathBuf,
        ov: &Overrides,
        kinds: Registry,
    ) -> Result<Self, ConfigError> {
        let o = origin.to_string();
        let mut file: PipelineFile = toml::from_str(text).map_err(|e| ConfigError::Parse {
            origin: o.clone(),
            message: e.to_string().replace('\n', " "),
        })?;
        if let Some(m) = ov.mode {
            file.runtime.mode = m;
        }
        if let Some(p) = &ov.prefix {
            file.runtime.prefix = p.clone();
        }
        if let Some(n) = &ov.namespace {
            file.runtime.namespace = n.clone();
        }
        if let Some(s) = ov.seed {
            file.runtime.seed = s;
        }
        if let Some(r) = &ov.record_path {
            for n in file.nodes.iter_mut() {
                if n.kind.as_deref().unwrap_or(&n.name) == "recorder" {
                    n.enabled = true;
                    n.params
                        .insert("path".into(), toml::Value::String(r.display().to_string()));
                }
            }
        }
        Self::validate(file, origin, base_dir, ov.clone(), kinds)
    }

    /// Long by design (over 120 lines): one check per field, in the file's order, so every
    /// rule of the schema is in one place beside its struct; each check is a few lines and
    /// shares nothing with the next, so helpers would only scatter the schema.
    // Long: one flat list of independent checks, each naming its field; split, they would only be scattered.
    fn validate(
        file: PipelineFile,
        origin: ConfigOrigin,
        base_dir: PathBuf,
        ov: Overrides,
        kinds: Registry,
    ) -> Result<Self, ConfigError> {
        let o = origin.to_string();
        let bad = |field: String, problem: String| ConfigError::Invalid {
            origin: o.clone(),
            field,
            problem,
        };
        let rt = &file.runtime;
        if rt.period_us == 0 || rt.period_us > 10_000_000 {
            return Err(bad(
                "runtime.period_us".into(),
                format!("must be in 1..=10000000, got {}", rt.period_us),
            ));
        }
        if rt.prefix.is_empty()
            || rt.prefix.len() > 40
            || !rt
                .prefix
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
        {
            return Err(bad(
                "runtime.prefix".into(),
                format!("must be 1..=40 characters of [A-Za-z0-9_-], got `{}`", rt.prefix),
            ));
        }
        if !rt.namespace.is_empty()
            && !rt
                .namespace
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"_-/".contains(&b))
        {
            return Err(bad(
                "runtime.namespace".into(),
                format!("invalid characters in `{}`", rt.namespace),
            ));
        }
        if let Some(s) = rt.seconds {
            if !(s.is_finite() && s > 0.0) {
                return Err(bad(
                    "runtime.seconds".into(),
                    format!("must be a positive number, got {s}"),
                ));
            }
        }
        if rt.stall_timeout_ms == 0 {
            return Err(bad("runtime.stall_timeout_ms".into(), "must be positive".into()));
        }
        if let Some(l) = rt.liveness_ms {
            if l <= rt.status_period_ms {
                return Err(bad(
                    "runtime.liveness_ms".into(),
                    format!(
                        "must be longer than runtime.status_period_ms ({}), got {l}",
                        rt.status_period_ms
                    ),
                ));
            }
        }
        if rt.status_period_ms == 0 {
            return Err(bad("runtime.status_period_ms".into(), "must be positive".into()));
        }

        let mut stages: Vec<StageSpec> = Vec::new();
        let mut proc_order: Vec<String> = Vec::new();
        let mut proc_nodes: BTreeMap<String, Vec<usize>> = BTreeMap::new();
        let mut sections: Vec<&NodeSection> = Vec::new();
        for (i, n) in file.nodes.iter().enumerate() {
            let field = |f: &str| format!("node[{i}] ({}).{f}", n.name);
            if !n.enabled {
                continue;
            }
            if !valid_name(&n.name) {
                return Err(bad(
                    format!("node[{i}].name"),
                    format!("`{}` must be 1..=32 characters of [a-z0-9_-]", n.name),
                ));
            }
            if stages.iter().any(|s| s.name == n.name) {
                return Err(bad(field("name"), "duplicate stage name".into()));
            }
            let kind = n.kind.clone().unwrap_or_else(|| n.name.clone());
            let info = kinds.get(&kind);
            if info.is_none() && n.exec.is_none() {
                return Err(bad(
                    field("kind"),
                    format!(
                        "unknown kind `{kind}` (known: {}); an external node needs `exec`",
                        kinds.names().join(", ")
                    ),
                ));
            }
            // The ports: the kind's declaration (or, for a kind whose ports depend on its
            // parameters, what they name), unless the file lists them; an external node of
            // unknown kind must list them.
            let declared: Option<ParamPorts> = match info {
                Some(k) => Some(match k.ports_from_params {
                    Some(f) => f(&n.params).map_err(|p| bad(field("params"), p.to_string()))?,
                    None => ParamPorts {
                        inputs: k.inputs.iter().map(|d| (d.service.to_string(), d.read)).collect(),
                        outputs: k.outputs.iter().map(|s| s.to_string()).collect(),
                    },
                }),
                None => None,
            };
            let reads: Vec<(String, Read)> = match (&n.inputs, &declared) {
                (Some(v), _) => v.iter().map(|s| (s.clone(), Read::Tick)).collect(),
                (None, Some(d)) => d.inputs.clone(),
                (None, None) => {
                    return Err(bad(
                        field("inputs"),
                        "required for an external node of unknown kind".into(),
                    ))
                }
            };
            let outputs: Vec<String> = match (&n.outputs, &declared) {
                (Some(v), _) => v.clone(),
                (None, Some(d)) => d.outputs.clone(),
                (None, None) => {
                    return Err(bad(
                        field("outputs"),
                        "required for an external node of unknown kind".into(),
                    ))
                }
            };
            for s in reads.iter().map(|(s, _)| s).chain(outputs.iter()) {
                if !is_service(s) {
                    return Err(bad(
                        field("inputs/outputs"),
                        format!("unknown service `{s}` (known: {})", known_services().join(", ")),
                    ));
                }
            }
            if let Some(why) = info.and_then(|k| k.lockstep_refusal) {
                if file.runtime.mode == Mode::Lockstep {
                    return Err(bad(field("kind"), why.into()));
                }
            }
            let with = |f: fn(Read) -> bool| -> Vec<String> {
                reads.iter().filter(|(_, r)| f(*r)).map(|(s, _)| s.clone()).collect()
            };
            let inputs = with(|r| r == Read::Tick);
            let side_inputs = with(|r| r == Read::Side);
            let passive_inputs = with(|r| matches!(r, Read::Hint | Read::Feedback));
            let process = n.process.clone().unwrap_or_else(|| n.name.clone());
            if !valid_name(&process) {
                return Err(bad(
                    field("process"),
                    format!("`{process}` must be 1..=32 characters of [a-z0-9_-]"),
                ));
            }
            for (f, v) in [
                ("period_us", n.period_us),
                ("wake_timeout_us", n.wake_timeout_us),
                ("deadline_us", n.deadline_us),
                ("budget_us", n.budget_us),
            ] {
                if v == Some(0) {
                    return Err(bad(field(f), "must be positive".into()));
                }
            }
            if let Some(rt) = &n.rt {
                if rt.sched_fifo && !(1..=99).contains(&rt.priority) {
                    return Err(bad(
                        field("rt.priority"),
                        format!("must be in 1..=99, got {}", rt.priority),
                    ));
                }
            }
            if let Some(e) = &n.exec {
                if e.is_empty() || e[0].is_empty() {
                    return Err(bad(field("exec"), "needs the executable as first element".into()));
                }
            }
            let deadline_us = n.deadline_us.or(info.and_then(|k| k.schedule.deadline_us));
            let idx = stages.len();
            stages.push(StageSpec {
                name: n.name.clone(),
                kind,
                process: process.clone(),
                inputs,
                side_inputs,
                passive_inputs,
                reads,
                outputs,
                deadline_ns: deadline_us.map(|d| d * 1000),
                budget_ns: n.budget_us.map(|d| d * 1000),
                params: n.params.clone(),
            });
            sections.push(n);
            if !proc_nodes.contains_key(&process) {
                proc_order.push(process.clone());
            }
            proc_nodes.entry(process).or_default().push(idx);
        }
        if stages.is_empty() {
            return Err(bad("node".into(), "no enabled [[node]]".into()));
        }

        // One producer per service.
        let mut producer: BTreeMap<&str, usize> = BTreeMap::new();
        for (i, s) in stages.iter().enumerate() {
            for out in &s.outputs {
                if let Some(&j) = producer.get(out.as_str()) {
                    return Err(bad(
                        format!("node `{}`.outputs", s.name),
                        format!("service `{out}` is already produced by `{}`", stages[j].name),
                    ));
                }
                producer.insert(out, i);
            }
        }
        // The dataflow must be acyclic (lockstep would deadlock) and, inside a process, in order.
        let upstream: Vec<BTreeSet<usize>> = stages
            .iter()
            .map(|s| {
                s.inputs
                    .iter()
                    .filter_map(|i| producer.get(i.as_str()).copied())
                    .collect()
            })
            .collect();
        let mut state = vec![0u8; stages.len()];
        fn visit(i: usize, up: &[BTreeSet<usize>], state: &mut [u8]) -> Option<usize> {
            if state[i] == 2 {
                return None;
            }
            if state[i] == 1 {
                return Some(i);
            }
            state[i] = 1;
            for &u in &up[i] {
                if let Some(c) = visit(u, up, state) {
                    return Some(c);
                }
            }
            state[i] = 2;
            None
        }
        for i in 0..stages.len() {
            if let Some(c) = visit(i, &upstream, &mut state) {
                return Err(bad(
                    format!("node `{}`.inputs", stages[c].name),
                    "the dataflow has a cycle through this stage".into(),
                ));
            }
        }
        let mut processes = Vec::new();
        for pname in &proc_order {
            let idxs = proc_nodes[pname].clone();
            for (pos, &i) in idxs.iter().enumerate() {
                for &u in &upstream[i] {
                    if stages[u].process == *pname && !idxs[..pos].contains(&u) {
                        return Err(bad(
                            format!("node `{}`.process", stages[i].name),
                            format!(
                                "stage `{}` runs after its input producer `{}` in process `{pname}`: list `{}` first",
                                stages[i].name, stages[u].name, stages[u].name
                            ),
                        ));
                    }
                }
            }
            let first = sections[idxs[0]];
            if first.exec.is_some() && file.runtime.mode == Mode::Lockstep && first.reports_status != Some(true) {
                return Err(bad(
                    format!("node `{}`.reports_status", stages[idxs[0]].name),
                    "an external node in lockstep must follow the lockstep protocol (docs/deployment.md) and set \
                     `reports_status = true`; its consumers wait for its per-tick status"
                        .into(),
                ));
            }
            if idxs.len() > 1 && idxs.iter().any(|&i| sections[i].exec.is_some()) {
                return Err(bad(
                    format!("node `{}`.exec", stages[idxs[0]].name),
                    format!("an external executable cannot share process `{pname}` with other stages"),
                ));
            }
            let info = kinds.get(&stages[idxs[0]].kind);
            let periodic = first.period_us.is_some() || info.is_some_and(|k| k.schedule.periodic);
            let activation = if periodic {
                let default_period = info.and_then(|k| k.schedule.period_us).unwrap_or(rt.period_us);
                Activation::Periodic {
                    period_ns: first.period_us.unwrap_or(default_period) * 1000,
                    phase_ns: first.phase_us.unwrap_or(0) * 1000,
                }
            } else {
                let timeout = idxs
                    .iter()
                    .filter_map(|&i| {
                        sections[i]
                            .wake_timeout_us
                            .or(kinds.get(&stages[i].kind).and_then(|k| k.schedule.wake_timeout_us))
                    })
                    .min();
                Activation::Event {
                    timeout_ns: timeout.map(|t| t * 1000),
                }
            };
            processes.push(ProcessSpec {
                name: pname.clone(),
                stages: idxs,
                exec: first.exec.clone(),
                restart: first.restart,
                max_restarts: first.max_restarts,
                on_loss: first.on_loss,
                rt: first.rt.clone(),
                activation,
                reports_status: first.exec.is_none() || first.reports_status.unwrap_or(false),
            });
        }
        Ok(Self {
            origin,
            overrides: ov,
            base_dir,
            runtime: file.runtime,
            stages,
            processes,
        })
    }

    pub fn mode(&self) -> Mode {
        self.runtime.mode
    }

    pub fn lockstep(&self) -> bool {
        self.runtime.mode == Mode::Lockstep
    }

    /// The iceoryx2 settings of this run.
    pub fn ipc(&self) -> IpcSettings {
        IpcSettings {
            prefix: self.runtime.prefix.clone(),
            namespace: self.runtime.namespace.clone(),
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.runtime.period_us * 1000
    }

    /// Real time: the launcher's bound on a stage's silence (`[runtime] liveness_ms`).
    pub fn liveness_ms(&self) -> u64 {
        self.runtime.liveness_ms.unwrap_or(3 * self.runtime.status_period_ms)
    }

    /// `p` relative to the config's directory (absolute paths unchanged).
    pub fn resolve(&self, p: impl AsRef<Path>) -> PathBuf {
        let p = p.as_ref();
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.base_dir.join(p)
        }
    }

    pub fn process(&self, name: &str) -> Option<&ProcessSpec> {
        self.processes.iter().find(|p| p.name == name)
    }

    pub fn stage(&self, name: &str) -> Option<&StageSpec> {
        self.stages.iter().find(|s| s.name == name)
    }

    /// Index of the stage producing `service`.
    pub fn producer_of(&self, service: &str) -> Option<usize> {
        self.stages.iter().position(|s| s.outputs.iter().any(|o| o == service))
    }

    /// Stages whose outputs stage `i` reads (its lockstep upstream).
    pub fn upstream_of(&self, i: usize) -> Vec<usize> {
        let mut v: Vec<usize> = self.stages[i]
            .inputs
            .iter()
            .filter_map(|s| self.producer_of(s))
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// A one-line description per process, for `bowden run` start-up output.
    pub fn describe(&self) -> Vec<String> {
        self.processes
            .iter()
            .map(|p| {
                let names: Vec<&str> = p.stages.iter().map(|&i| self.stages[i].name.as_str()).collect();
                let how = match (&p.exec, p.activation) {
                    (Some(e), _) => format!("external `{}`", e.join(" ")),
                    (None, Activation::Periodic { period_ns, .. }) => format!("periodic {} µs", period_ns / 1000),
                    (None, Activation::Event { timeout_ns }) => match timeout_ns {
                        Some(t) => format!("on input (watchdog {} µs)", t / 1000),
                        None => "on input".into(),
                    },
                };
                format!("{} [{}] {}", p.name, names.join(" → "), how)
            })
            .collect()
    }
}
