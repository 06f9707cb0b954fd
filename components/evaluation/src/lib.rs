//! Trajectory-tracking evaluation (paper §V): unseen trajectories run through the full
//! multi-process pipeline in lockstep (target → compensator → actuator → plant → camera →
//! estimator) for each controller and repeat, and the paper's Table V (task space) and
//! Table VI (joint space), measured both by the vision estimate (as the paper did) and by the
//! simulator's truth, with plots like Fig. 12/13.

pub mod figures;
pub mod metrics;
pub mod report;
pub mod session;
pub mod tick;

use bowden_interfaces::{services, CompensationMode, JointCommand, JointEstimate, JointTarget, PlantState};
use bowden_kinematics::{JointsDeg, N_JOINTS};
use bowden_runtime::config::{Mode, Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::node::Registry;
use bowden_runtime::session::{LockstepSession, SessionError, SessionOptions};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Controllers compared, by the compensator's mode names.
pub const CONTROLLERS: [&str; 3] = ["uncalibrated", "paper", "newton"];

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("{path}: {message}")]
    Config { path: PathBuf, message: String },
    #[error("{what}: {source}")]
    Session { what: String, source: SessionError },
    #[error("{what}: {message}")]
    Run { what: String, message: String },
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
}

/// What holding one target measured: the newest joint command and plant state of the hold,
/// and the joint estimate of its last tick only (the one frame per held point that sees the
/// settled robot), at the simulated time of that tick.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Held {
    pub command: Option<JointCommand>,
    pub state: Option<PlantState>,
    pub estimate: Option<JointEstimate>,
    pub t_sim_ns: u64,
}

/// Why holding a target failed.
#[derive(Debug, thiserror::Error)]
pub enum HoldError {
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error("a node failed at tick {tick}: {event}")]
    NodeFailed { tick: u64, event: String },
}

/// The one hold-and-measure loop of `collect` and `evaluate`: publishes target `q_deg` for
/// `ticks` ticks (at least one) of a lockstep session that is the targets' source and taps
/// the joint commands, plant states and joint estimates, and returns what the hold measured.
/// A node that fails during the hold ends it with [`HoldError::NodeFailed`].
pub fn hold(s: &mut LockstepSession, q_deg: &[f64], ticks: u32) -> Result<Held, HoldError> {
    let mut held = Held::default();
    for _ in 0..ticks.max(1) {
        let out = s.step_with(JointTarget::from_deg(q_deg))?;
        if let Some(e) = out.events.first() {
            return Err(HoldError::NodeFailed {
                tick: out.tick,
                event: e.clone(),
            });
        }
        held.command = out.get::<JointCommand>(services::JOINT_COMMAND).or(held.command);
        held.state = out.get::<PlantState>(services::PLANT_STATE).or(held.state);
        held.estimate = out.get::<JointEstimate>(services::JOINT_ESTIMATE);
        held.t_sim_ns = out.t_sim_ns;
    }
    Ok(held)
}

/// What one trajectory point produced.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PointRecord {
    pub q_desired_deg: JointsDeg,
    /// The command the compensator sent for it.
    pub q_cmd_deg: JointsDeg,
    /// The plant's true configuration at the end of the point (simulation truth).
    pub q_true_deg: JointsDeg,
    /// The vision estimate at the end of the point, when the estimator produced a valid one.
    pub q_est_deg: Option<JointsDeg>,
    /// The estimator's end-effector pose in the base frame: position mm and quaternion w, x, y, z.
    pub ee_est: Option<([f64; 3], [f64; 4])>,
    /// The forward model's prediction for the command sent (absent in `uncalibrated` mode and
    /// without a forward model): against `q_true_deg` it separates model error from what
    /// the refinement left.
    pub q_predicted_deg: Option<JointsDeg>,
    pub refine_iterations: u32,
    /// The plant's simulated time at the measurement, ns (the session's clock; not written to
    /// `bowden evaluate`'s report.json, whose points are indexed by their position).
    #[serde(skip)]
    pub t_sim_ns: u64,
}

/// One run: a trajectory, a controller, a repeat.
#[derive(Debug, Clone, Serialize)]
pub struct RunRecord {
    pub trajectory: String,
    pub controller: String,
    pub repeat: u32,
    pub seed: u64,
    pub points: Vec<PointRecord>,
    pub invalid_estimates: usize,
    pub ticks: u64,
}

/// How runs are made.
#[derive(Debug, Clone)]
pub struct EvalSettings {
    /// Ticks each trajectory point is held (the paper paused 0.5 s): the last tick is measured.
    pub settle_ticks: u32,
    pub repeats: u32,
    /// Seed of repeat r is `seed0 + r`: the plant's and the camera's noise differ per repeat.
    pub seed0: u64,
    /// Working directory for per-controller pipeline files.
    pub work_dir: PathBuf,
    /// iceoryx2 prefix stem; each run gets its own prefix.
    pub prefix_stem: String,
    pub launch: LaunchOptions,
    /// The node kinds of the program `launch` starts (the `bowden` binary's registry): the
    /// pipeline files are validated against them.
    pub kinds: Registry,
}

/// Writes a copy of the pipeline file with the compensator's `mode` set to `controller`.
pub fn pipeline_for_controller(template: &Path, controller: &str, work_dir: &Path) -> Result<PathBuf, EvalError> {
    pipeline_variant(
        template,
        &[("compensator", "mode", toml::Value::String(controller.to_string()))],
        &work_dir.join(format!("pipeline-{controller}.toml")),
    )
}

/// Writes a copy of the pipeline file `template` to `out` with node parameters replaced:
/// each `(node name, parameter, value)` sets `[node.params] parameter = value` of that node.
/// Relative file paths of the template are made absolute so the copy names the same files.
/// Appends a `[[node]]` (`name`, `kind`, `params`) to a pipeline file written by
/// [`pipeline_variant`] (`bowden evaluate --adapt` adds the `adapt` node this way).
pub fn pipeline_add_node(file: &Path, name: &str, kind: &str, params: toml::Table) -> Result<(), EvalError> {
    let text = std::fs::read_to_string(file).map_err(|source| EvalError::Io {
        path: file.to_path_buf(),
        source,
    })?;
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| EvalError::Config {
        path: file.to_path_buf(),
        message: e.to_string().replace('\n', " "),
    })?;
    let mut node = toml::Table::new();
    node.insert("name".into(), toml::Value::String(name.into()));
    if kind != name {
        node.insert("kind".into(), toml::Value::String(kind.into()));
    }
    node.insert("params".into(), toml::Value::Table(params));
    match table.get_mut("node").and_then(|n| n.as_array_mut()) {
        Some(nodes) => nodes.push(toml::Value::Table(node)),
        None => {
            table.insert("node".into(), toml::Value::Array(vec![toml::Value::Table(node)]));
        }
    }
    let text = toml::to_string(&table).map_err(|e| EvalError::Config {
        path: file.to_path_buf(),
        message: e.to_string(),
    })?;
    std::fs::write(file, text).map_err(|source| EvalError::Io {
        path: file.to_path_buf(),
        source,
    })
}

pub fn pipeline_variant(template: &Path, set: &[(&str, &str, toml::Value)], out: &Path) -> Result<PathBuf, EvalError> {
    let text = std::fs::read_to_string(template).map_err(|source| EvalError::Io {
        path: template.to_path_buf(),
        source,
    })?;
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| EvalError::Config {
        path: template.to_path_buf(),
        message: e.to_string().replace('\n', " "),
    })?;
    let nodes = table
        .get_mut("node")
        .and_then(|n| n.as_array_mut())
        .ok_or_else(|| EvalError::Config {
            path: template.to_path_buf(),
            message: "no [[node]] entries".into(),
        })?;
    for (node, key, value) in set {
        let entry = nodes
            .iter_mut()
            .filter_map(|n| n.as_table_mut())
            .find(|n| n.get("name").and_then(|v| v.as_str()) == Some(node))
            .ok_or_else(|| EvalError::Config {
                path: template.to_path_buf(),
                message: format!("no node named `{node}`"),
            })?;
        let params = entry
            .entry("params")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| EvalError::Config {
                path: template.to_path_buf(),
                message: format!("{node}: params is not a table"),
            })?;
        params.insert((*key).to_string(), value.clone());
    }
    // The copy lives elsewhere: make the template's relative file paths absolute so they
    // still name the same files.
    let base = template
        .parent()
        .map(|b| std::fs::canonicalize(if b.as_os_str().is_empty() { Path::new(".") } else { b }))
        .transpose()
        .map_err(|source| EvalError::Io {
            path: template.to_path_buf(),
            source,
        })?
        .unwrap_or_default();
    absolutize_paths(&mut table, &base);
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir).map_err(|source| EvalError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    let text = toml::to_string(&table).map_err(|e| EvalError::Config {
        path: out.to_path_buf(),
        message: e.to_string(),
    })?;
    std::fs::write(out, text).map_err(|source| EvalError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    Ok(out.to_path_buf())
}

/// The camera frame rate that gives one frame per held point (the paper measured each
/// command once, after its 0.5 s pause): 1 / (settle ticks × tick).
pub fn camera_fps_for(settle_ticks: u32, tick_ns: u64) -> f64 {
    1e9 / (f64::from(settle_ticks.max(1)) * tick_ns.max(1) as f64)
}

/// Keys whose string values are file paths in pipeline files.
const PATH_KEYS: [&str; 6] = ["robot", "config", "markers", "file", "path", "models_dir"];

fn absolutize_paths(v: &mut toml::Table, base: &Path) {
    for (k, val) in v.iter_mut() {
        match val {
            toml::Value::String(s) if PATH_KEYS.contains(&k.as_str()) && Path::new(s.as_str()).is_relative() => {
                *s = base.join(s.as_str()).display().to_string();
            }
            toml::Value::Table(t) => absolutize_paths(t, base),
            toml::Value::Array(a) => {
                for item in a.iter_mut() {
                    if let toml::Value::Table(t) = item {
                        absolutize_paths(t, base);
                    }
                }
            }
            _ => {}
        }
    }
}

/// One run to make: which pipeline (controller), trajectory and repeat.
#[derive(Debug, Clone, Copy)]
pub struct RunSpec<'a> {
    /// The pipeline file for the controller (see [`pipeline_variant`]).
    pub pipeline_file: &'a Path,
    pub name: &'a str,
    pub controller: &'a str,
    pub repeat: u32,
    /// Home → the trajectory's start, held but not measured.
    pub approach: &'a [JointsDeg],
    /// The measured points.
    pub q_path: &'a [JointsDeg],
}

/// Runs one trajectory through the lockstep pipeline `pipeline_file` and records every point.
/// The robot first moves along `approach` (home → the trajectory's start at the model step,
/// held like any point, not measured), so the first measured point does not start with a jump.
/// `on_point` is called after each measured point (progress).
pub fn run_trajectory(
    run: &RunSpec<'_>,
    settings: &EvalSettings,
    on_point: &mut dyn FnMut(),
) -> Result<RunRecord, EvalError> {
    let RunSpec {
        pipeline_file,
        name,
        controller,
        repeat,
        approach,
        q_path,
    } = *run;
    let seed = settings.seed0 + u64::from(repeat);
    let what = format!("{name}/{controller}/repeat {repeat}");
    let ov = Overrides {
        mode: Some(Mode::Lockstep),
        prefix: Some(format!("{}{}_{}_{}_", settings.prefix_stem, name, controller, repeat)),
        seed: Some(seed),
        ..Default::default()
    };
    let cfg = PipelineConfig::load(pipeline_file, &ov, settings.kinds).map_err(|e| EvalError::Config {
        path: pipeline_file.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut opts = SessionOptions::new(settings.launch.clone());
    opts.taps = [services::JOINT_COMMAND, services::PLANT_STATE, services::JOINT_ESTIMATE]
        .map(String::from)
        .to_vec();
    opts.source = Some(services::JOINT_TARGET.into());
    let session_err = |source| EvalError::Session {
        what: what.clone(),
        source,
    };
    let mut s = LockstepSession::start(&cfg, opts).map_err(session_err)?;
    let mut points = Vec::with_capacity(q_path.len());
    let mut invalid = 0usize;
    let result = (|| {
        // One warm-up tick at home puts the camera's frame grid (one frame per held point,
        // see `camera_fps_for`) on the last tick of every point.
        s.step_with(JointTarget::from_deg(&[0.0; N_JOINTS]))
            .map_err(session_err)?;
        let hold_err = |e: HoldError, during: &str| match e {
            HoldError::Session(source) => EvalError::Session {
                what: what.clone(),
                source,
            },
            HoldError::NodeFailed { tick, event } => EvalError::Run {
                what: what.clone(),
                message: format!("a node failed at tick {tick}{during}: {event}"),
            },
        };
        for q in approach {
            hold(&mut s, q, settings.settle_ticks).map_err(|e| hold_err(e, " (approach)"))?;
        }
        for q in q_path {
            let h = hold(&mut s, q, settings.settle_ticks).map_err(|e| hold_err(e, ""))?;
            let last_est = h.estimate;
            let (Some(cmd), Some(state)) = (h.command, h.state) else {
                return Err(EvalError::Run {
                    what: what.clone(),
                    message: "no command or plant state came back: is the pipeline complete?".into(),
                });
            };
            if points.is_empty() && last_est.is_none() {
                return Err(EvalError::Run {
                    what: what.clone(),
                    message: "no camera frame on the last tick of the first point: the camera's fps must be \
                              1 / (settle ticks × tick) (see camera_fps_for)"
                        .into(),
                });
            }
            let take = |a: &[f64; 8]| -> JointsDeg { core::array::from_fn(|j| a[j]) };
            let (q_est, ee_est) = match last_est {
                Some(e) if e.quality == JointEstimate::QUALITY_VALID => {
                    (Some(take(&e.q_phy_deg)), Some((e.ee_pos_base_mm, e.ee_quat_base_wxyz)))
                }
                _ => {
                    invalid += 1;
                    (None, None)
                }
            };
            points.push(PointRecord {
                q_desired_deg: *q,
                q_cmd_deg: take(&cmd.q_cmd_deg),
                q_true_deg: take(&state.q_phy_deg),
                q_est_deg: q_est,
                ee_est,
                q_predicted_deg: (cmd.mode != CompensationMode::Uncalibrated as u32)
                    .then(|| take(&cmd.q_predicted_deg)),
                refine_iterations: cmd.iterations,
                t_sim_ns: state.t_sim_ns,
            });
            on_point();
        }
        Ok(())
    })();
    let ticks = s.ticks_done();
    let shutdown = s.shutdown();
    result?;
    shutdown.map_err(session_err)?;
    debug_assert!(points.iter().all(|p| p.q_true_deg.len() == N_JOINTS));
    Ok(RunRecord {
        trajectory: name.into(),
        controller: controller.into(),
        repeat,
        seed,
        points,
        invalid_estimates: invalid,
        ticks,
    })
}
