//! `bowden evaluate`: tracking of unseen task-space trajectories through the full
//! multi-process pipeline in lockstep, for each controller and repeat (paper §V, Tables V–VI).

use anyhow::{bail, Context, Result};
use bowden_evaluation::report::{summarise, write_report};
use bowden_evaluation::{camera_fps_for, pipeline_variant, run_trajectory, EvalSettings, RunSpec, CONTROLLERS};
use bowden_kinematics::Robot;
use bowden_runtime::config::{Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_trajectory::task_space::TrajectorySpec;
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

#[derive(Args)]
pub struct EvaluateArgs {
    /// Pipeline to run (lockstep; its compensator's mode is set per controller).
    #[arg(long, default_value = "configs/evaluate.toml")]
    pub config: PathBuf,
    /// Robot description used for FK of the errors and IK of the trajectories.
    #[arg(long, default_value = "configs/robot.toml")]
    pub robot: PathBuf,
    /// Trajectory names, files `<trajectories-dir>/<name>.toml`.
    #[arg(long, value_delimiter = ',', default_value = "random,circle,zigzag")]
    pub trajectories: Vec<String>,
    #[arg(long, default_value = "configs/trajectories")]
    pub trajectories_dir: PathBuf,
    /// Controllers: uncalibrated, paper (Algorithm 1), newton.
    #[arg(long, value_delimiter = ',', default_value = "uncalibrated,paper,newton")]
    pub controllers: Vec<String>,
    /// Runs of every (trajectory, controller), each with its own seed (camera noise; with
    /// `--units per-repeat` also the plant unit).
    #[arg(long, default_value_t = 5)]
    pub repeats: u32,
    /// Which manufactured unit of the plant runs: `configured` (the plant file's
    /// `variation.unit`, the robot the models were trained on, as the paper evaluated) or
    /// `per-repeat` (repeat r runs unit seed + r: other units of the same design, a transfer test).
    #[arg(long, value_enum, default_value_t = Units::Configured)]
    pub units: Units,
    #[arg(long, default_value_t = 1000)]
    pub seed: u64,
    /// Ticks each point is held; the last is measured (5 × 100 ms = the paper's 0.5 s pause).
    #[arg(long, default_value_t = 5)]
    pub settle_ticks: u32,
    /// Use only the first N points of every trajectory (quick checks).
    #[arg(long)]
    pub max_points: Option<usize>,
    /// Plant file for the simulated robot (a second robot is a second file).
    #[arg(long)]
    pub plant: Option<PathBuf>,
    /// Compensator config (models, refinement settings) replacing the pipeline's.
    #[arg(long)]
    pub controller_config: Option<PathBuf>,
    /// Directory for report.md, report.json and the plots.
    #[arg(long, default_value = "out/evaluate")]
    pub report: PathBuf,
    /// Also write the summary JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Units {
    Configured,
    PerRepeat,
}

#[derive(Subcommand)]
pub enum Command {
    /// Track unseen trajectories (random, circle, zigzag) with each controller; print Table V/VI.
    Evaluate(EvaluateArgs),
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Evaluate(a) => evaluate(a),
    }
}

/// Home (all joints zero) to the trajectory's first point, at the dataset's step (eq. 16),
/// without the first point itself.
fn approach_path(q: &[bowden_kinematics::JointsDeg]) -> Vec<bowden_kinematics::JointsDeg> {
    let Some(first) = q.first() else { return Vec::new() };
    let mut path = bowden_trajectory::interpolate_eq16(&[[0.0; 5], *first]);
    path.retain(|p| p != first);
    path
}

/// "controller FILE (forward MODEL, inverse MODEL)" of a pipeline's compensator node, for the
/// report header: a table is only worth as much as knowing which models produced it.
fn describe_controller(pipeline: &std::path::Path) -> String {
    let find = || -> Option<String> {
        let v: toml::Value = toml::from_str(&std::fs::read_to_string(pipeline).ok()?).ok()?;
        let node = v
            .get("node")?
            .as_array()?
            .iter()
            .find(|n| n.get("name").and_then(|x| x.as_str()) == Some("compensator"))?;
        let file = node.get("params")?.get("config")?.as_str()?;
        let mut path = std::path::PathBuf::from(file);
        if path.is_relative() {
            path = pipeline.parent()?.join(path);
        }
        let cfg = bowden_compensator::ControllerConfig::load(&path).ok()?;
        let name = |m: &Option<std::path::PathBuf>| {
            m.as_ref()
                .and_then(|p| p.file_name())
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_else(|| "none".into())
        };
        // Relative to the working directory when inside it, so reports do not name the machine.
        let shown = std::env::current_dir()
            .ok()
            .and_then(|d| path.strip_prefix(d).ok().map(|p| p.display().to_string()))
            .unwrap_or_else(|| file.to_string());
        Some(format!(
            "controller {} (forward {}, inverse {})",
            shown,
            name(&cfg.model_fwd),
            name(&cfg.model_inv)
        ))
    };
    find().unwrap_or_else(|| "controller config not readable".into())
}

fn evaluate(a: EvaluateArgs) -> Result<()> {
    for c in &a.controllers {
        if !CONTROLLERS.contains(&c.as_str()) {
            bail!(
                "--controllers: unknown controller `{c}` (expected {})",
                CONTROLLERS.join(", ")
            );
        }
    }
    if a.repeats == 0 || a.settle_ticks == 0 {
        bail!("--repeats and --settle-ticks must be at least 1");
    }
    let robot = Robot::load(&a.robot)?;
    let mut paths = Vec::new();
    for name in &a.trajectories {
        let file = a.trajectories_dir.join(format!("{name}.toml"));
        let spec = TrajectorySpec::load(&file)?;
        let mut t = spec.to_joint_space(&robot, &file)?;
        if let Some(n) = a.max_points {
            t.q_deg.truncate(n.max(1));
        }
        paths.push(t);
    }
    let work_dir = a.report.join("pipelines");
    let tick_ns = PipelineConfig::load(&a.config, &Overrides::default())?.period_ns();
    let fps = camera_fps_for(a.settle_ticks, tick_ns);
    let mut pipelines = Vec::new();
    for c in &a.controllers {
        let mut set = vec![
            ("compensator", "mode", toml::Value::String(c.clone())),
            ("camera", "fps", toml::Value::Float(fps)),
        ];
        if a.units == Units::PerRepeat {
            set.push(("plant", "unit", toml::Value::String("run-seed".into())));
        }
        for (node, file) in [("plant", &a.plant), ("compensator", &a.controller_config)] {
            if let Some(f) = file {
                let abs = std::fs::canonicalize(f).with_context(|| format!("{}", f.display()))?;
                set.push((node, "config", toml::Value::String(abs.display().to_string())));
            }
        }
        pipelines.push(pipeline_variant(
            &a.config,
            &set,
            &work_dir.join(format!("pipeline-{c}.toml")),
        )?);
    }
    let settings = EvalSettings {
        settle_ticks: a.settle_ticks,
        repeats: a.repeats,
        seed0: a.seed,
        work_dir,
        prefix_stem: format!("bev{}_", std::process::id()),
        launch: LaunchOptions {
            quiet_children: true,
            ..LaunchOptions::current_exe().context("locating the bowden executable")?
        },
    };
    let total: u64 =
        paths.iter().map(|t| t.q_deg.len() as u64).sum::<u64>() * a.controllers.len() as u64 * u64::from(a.repeats);
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{msg:32} [{bar:30}] {pos}/{len} points  {per_sec}  eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let mut runs = Vec::new();
    for t in &paths {
        for (c, pipeline) in a.controllers.iter().zip(&pipelines) {
            for r in 0..a.repeats {
                bar.set_message(format!("{} / {c} / #{r}", t.name));
                let approach = approach_path(&t.q_deg);
                let spec = RunSpec {
                    pipeline_file: pipeline,
                    name: &t.name,
                    controller: c,
                    repeat: r,
                    approach: &approach,
                    q_path: &t.q_deg,
                };
                let run = run_trajectory(&spec, &settings, &mut || bar.inc(1))?;
                runs.push(run);
            }
        }
    }
    bar.finish_and_clear();
    let summary = summarise(&robot, &runs);
    let plant_cfg = bowden_plant::PlantConfig::load_or_shipped(a.plant.as_deref())?;
    let plant_name = a
        .plant
        .as_ref()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|| "configs/plant.toml".into());
    let units = match (a.units, plant_cfg.variation.unit) {
        (Units::Configured, Some(u)) => format!("unit {u}"),
        (Units::Configured, None) | (Units::PerRepeat, _) => format!(
            "units {}..={}, one per repeat",
            a.seed,
            a.seed + u64::from(a.repeats) - 1
        ),
    };
    let header = format!(
        "{} trajectories × {} controllers × {} repeats; points held {} ticks; pipeline {}; robot {}; plant {} ({}); {}.",
        a.trajectories.len(),
        a.controllers.len(),
        a.repeats,
        a.settle_ticks,
        a.config.display(),
        a.robot.display(),
        plant_name,
        units,
        pipelines
            .first()
            .map(|p| describe_controller(p))
            .unwrap_or_else(|| "no controller".into())
    );
    let files = write_report(&robot, &runs, &summary, &header, &a.report)?;
    if let Some(j) = &a.json {
        std::fs::write(j, serde_json::to_string_pretty(&summary)?).with_context(|| format!("{}", j.display()))?;
    }
    print!("{}", bowden_evaluation::report::markdown(&summary, &header));
    eprintln!(
        "report: {}",
        files
            .iter()
            .map(|f| f.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}
