//! `bowden evaluate`: tracking of unseen task-space trajectories through the full
//! multi-process pipeline in lockstep, for each controller and repeat (paper §V, Tables V–VI).
//! `bowden evaluate --session MINUTES`: the same trajectories looped through one pipeline for
//! MINUTES of simulated time, the error over time (cable slack scenarios, issue #13).

use crate::home::Resolved;
use anyhow::{bail, Context, Result};
use bowden_evaluation::report::{summarise, write_report};
use bowden_evaluation::session::{self, SlackEvents};
use bowden_evaluation::tick;
use bowden_evaluation::{
    camera_fps_for, pipeline_add_node, pipeline_variant, run_trajectory, EvalSettings, RunSpec, CONTROLLERS,
};
use bowden_kinematics::Robot;
use bowden_runtime::config::{Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_trajectory::task_space::TrajectorySpec;
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

#[derive(Args)]
pub struct EvaluateArgs {
    /// Pipeline to run (lockstep; its compensator's mode is set per controller). Config, robot,
    /// plant, controller and trajectory files are found as given, under $BOWDEN_HOME, or built
    /// in (`bowden shipped`).
    #[arg(long, default_value = "configs/evaluate.toml")]
    pub config: PathBuf,
    /// Robot description used for FK of the errors and IK of the trajectories.
    #[arg(long, default_value = "configs/robot.toml")]
    pub robot: PathBuf,
    /// Trajectory names, files `<trajectories-dir>/<name>.toml` (shipped: random, circle, zigzag).
    #[arg(long, value_delimiter = ',', default_value = "random,circle,zigzag")]
    pub trajectories: Vec<String>,
    /// Directory of the trajectory files (configs/trajectories/large: the larger test paths).
    #[arg(long, default_value = "configs/trajectories")]
    pub trajectories_dir: PathBuf,
    /// Controllers (comma-separated): uncalibrated, paper (Algorithm 1), newton.
    #[arg(long, value_delimiter = ',', default_value = "uncalibrated,paper,newton",
          value_parser = super::choice(&CONTROLLERS), ignore_case = true)]
    pub controllers: Vec<String>,
    /// Runs of every (trajectory, controller), each with its own seed (camera noise; with
    /// `--units per-repeat` also the plant unit). Default 5; 1 with `--session`.
    #[arg(long)]
    pub repeats: Option<u32>,
    /// Which manufactured unit of the plant runs: `configured` (the plant file's
    /// `variation.unit`, the robot the models were trained on, as the paper evaluated) or
    /// `per-repeat` (repeat r runs unit seed + r: other units of the same design, a transfer test).
    #[arg(long, value_enum, default_value_t = Units::Configured, ignore_case = true)]
    pub units: Units,
    /// Seed of repeat 0 (repeat r uses seed + r): camera noise, and with `--units per-repeat`
    /// the plant unit.
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
    /// Directory for report.md, report.json and the plots (default out/evaluate; with
    /// `--session`, session.md, session.json and its plots, default out/evaluate-session),
    /// relative to the working directory. An earlier report there is kept unless --force.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Print the summary as JSON on stdout instead of the tables.
    #[arg(long)]
    pub json: bool,
    /// Also write the summary JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub json_out: Option<PathBuf>,
    /// Overwrite an earlier report in --report (and --json-out).
    #[arg(long)]
    pub force: bool,
    /// One long tracking session instead: the trajectories played one after another in a loop
    /// through ONE pipeline (the plant is never restarted: its creep and slips carry over) for
    /// MINUTES of simulated time, per controller; reports the error per `--window-s` window.
    #[arg(long, value_name = "MINUTES")]
    pub session: Option<f64>,
    /// With `--session`: the length of a window of the error-over-time tables, s.
    #[arg(long, default_value_t = 60.0, value_name = "SECONDS")]
    pub window_s: f64,
    /// Online adaptation while tracking: adds an `adapt` node with these settings
    /// (configs/adapt.toml layout) beside the paper and newton controllers' pipelines; each
    /// run starts from the controller's models, its generations go to `<report>/adapt-<controller>`.
    #[arg(long, value_name = "FILE")]
    pub adapt: Option<PathBuf>,
    /// Camera frame rate, fps. Default: one frame per held point, on its last tick (the paper
    /// measured each command once). A multiple of that rate whose frame period divides the
    /// hold (e.g. 10 = a frame every 100 ms tick) gives the compensator's vision feedback
    /// frames to act on during the hold; the point is still measured on its last tick.
    #[arg(long, value_name = "FPS")]
    pub camera_fps: Option<f64>,
    /// Run the pipeline at this tick instead of its own (a divisor of it, ms), keeping the
    /// hold (`--settle-ticks` × the pipeline's tick) and the per-tick rate limits (the
    /// compensator's and the actuator's deg/s scaled by the ratio), so the feed-forward runs as
    /// it does at the pipeline's tick while a faster camera fits in the hold: e.g. `--tick-ms
    /// 10 --camera-fps 50` holds each point 50 ticks with a frame every 2.
    #[arg(long, value_name = "MS")]
    pub tick_ms: Option<f64>,
}

/// The arguments with their files found (`crate::home`); the other fields through `Deref`.
struct Files {
    args: EvaluateArgs,
    config: Resolved,
    robot: Resolved,
    trajectories_dir: Resolved,
    plant: Option<Resolved>,
    controller_config: Option<Resolved>,
    adapt: Option<Resolved>,
}

impl Files {
    fn resolve(args: EvaluateArgs) -> Result<Self> {
        let find = |p: &PathBuf, flag: &str| crate::home::resolve(p).with_context(|| flag.to_string());
        Ok(Files {
            config: find(&args.config, "--config")?,
            robot: find(&args.robot, "--robot")?,
            trajectories_dir: find(&args.trajectories_dir, "--trajectories-dir")?,
            plant: args.plant.as_ref().map(|p| find(p, "--plant")).transpose()?,
            controller_config: args
                .controller_config
                .as_ref()
                .map(|p| find(p, "--controller-config"))
                .transpose()?,
            adapt: args.adapt.as_ref().map(|p| find(p, "--adapt")).transpose()?,
            args,
        })
    }
}

impl std::ops::Deref for Files {
    type Target = EvaluateArgs;
    fn deref(&self) -> &EvaluateArgs {
        &self.args
    }
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
        // Relative to the working directory (or the built-in copy, said so) when inside it, so
        // reports do not name the machine.
        let shown = crate::home::describe(&path);
        Some(format!(
            "controller {} (forward {}, inverse {})",
            shown,
            name(&cfg.model_fwd),
            name(&cfg.model_inv)
        ))
    };
    find().unwrap_or_else(|| "controller config not readable".into())
}

/// What `evaluate` and `evaluate --session` both prepare: the checked arguments, the robot,
/// the trajectories as joint paths, one pipeline file per controller, the run settings.
struct Prepared {
    robot: Robot,
    paths: Vec<bowden_trajectory::task_space::JointTrajectory>,
    pipelines: Vec<PathBuf>,
    settings: EvalSettings,
    repeats: u32,
    report: PathBuf,
    tick_ns: u64,
    /// Ticks each point is held (`--settle-ticks` scaled to `--tick-ms`).
    settle_ticks: u32,
}

// Long: the evaluation's set-up in the order its options interact (repeats, tick, camera rate, controller copies, pipeline variants).
fn prepare(a: &Files, default_repeats: u32, default_report: &str, report_files: [&str; 2]) -> Result<Prepared> {
    let repeats = a.repeats.unwrap_or(default_repeats);
    if repeats == 0 || a.settle_ticks == 0 {
        bail!("--repeats and --settle-ticks must be at least 1");
    }
    let report = a.report.clone().unwrap_or_else(|| PathBuf::from(default_report));
    if report.is_file() {
        bail!(
            "--report {}: expected a directory for the report; this is a file",
            report.display()
        );
    }
    let mut outputs = report_files.map(|f| report.join(f)).to_vec();
    outputs.extend(a.json_out.clone());
    super::refuse_overwrite(&outputs, a.force, "--report")?;
    let robot = Robot::load(&a.robot.path)?;
    let mut paths = Vec::new();
    for name in &a.trajectories {
        let file = a.trajectories_dir.path.join(format!("{name}.toml"));
        let spec = TrajectorySpec::load(&file)?;
        let mut t = spec.to_joint_space(&robot, &file)?;
        if let Some(n) = a.max_points {
            t.q_deg.truncate(n.max(1));
        }
        paths.push(t);
    }
    let work_dir = report.join("pipelines");
    let base_tick_ns =
        PipelineConfig::load(&a.config.path, &Overrides::default(), bowden::registry::REGISTRY)?.period_ns();
    let (tick_ns, tick_scale) = match a.tick_ms {
        None => (base_tick_ns, 1),
        Some(ms) => tick::shorter_tick(ms, base_tick_ns).context("--tick-ms")?,
    };
    let settle_ticks =
        u32::try_from(u64::from(a.settle_ticks) * tick_scale).context("--settle-ticks × the tick ratio")?;
    let per_point = camera_fps_for(settle_ticks, tick_ns);
    let fps = match a.camera_fps {
        None => per_point,
        Some(f) => {
            // Frames must fall on every point's last tick: f = k × (one per point), k | settle ticks.
            let k = (f / per_point).round();
            if !(f.is_finite()
                && k >= 1.0
                && (f - k * per_point).abs() <= 1e-9 * f
                && settle_ticks.is_multiple_of(k as u32))
            {
                bail!(
                    "--camera-fps {f}: must be k × {per_point} fps (one frame per point) with k dividing the {} ticks \
                     a point is held (frames must fall on every point's last tick); e.g. {}",
                    settle_ticks,
                    (1..=settle_ticks)
                        .filter(|k| settle_ticks.is_multiple_of(*k))
                        .map(|k| format!("{}", f64::from(k) * per_point))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
            k * per_point
        }
    };
    // `--tick-ms`: one controller copy with the per-tick rate limit kept, for every pipeline.
    let tick_controller = if tick_scale > 1 {
        let src = match &a.controller_config {
            Some(f) => f.path.clone(),
            None => tick::pipeline_controller(&a.config.path)?,
        };
        let shipped_rate_deg_s = bowden_compensator::ControllerConfig::shipped().output.rate_limit_deg_s;
        let find_model = |p: &std::path::Path| crate::home::path(p).map_err(|e| format!("{e:#}"));
        Some(tick::controller_for_tick(
            &src,
            &work_dir,
            tick_scale,
            shipped_rate_deg_s,
            &find_model,
        )?)
    } else {
        None
    };
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
                let abs = std::fs::canonicalize(&f.path).with_context(|| f.shown())?;
                set.push((node, "config", toml::Value::String(abs.display().to_string())));
            }
        }
        if let Some(ctl) = &tick_controller {
            set.push(("compensator", "config", toml::Value::String(ctl.display().to_string())));
            set.push((
                "actuator",
                "max_rate_deg_s",
                tick::actuator_rate_for_tick(&a.config.path, tick_scale)?,
            ));
        }
        let file = pipeline_variant(&a.config.path, &set, &work_dir.join(format!("pipeline-{c}.toml")))?;
        if tick_scale > 1 {
            tick::set_period(&file, tick_ns)?;
        }
        if let (Some(f), true) = (&a.adapt, c != "uncalibrated") {
            let abs = std::fs::canonicalize(&f.path).with_context(|| f.shown())?;
            let state = std::path::absolute(report.join(format!("adapt-{c}")))?;
            let mut params = toml::Table::new();
            params.insert("config".into(), toml::Value::String(abs.display().to_string()));
            params.insert("state_dir".into(), toml::Value::String(state.display().to_string()));
            // Every run starts from the controller's own models.
            params.insert("resume".into(), toml::Value::Boolean(false));
            pipeline_add_node(&file, "adapt", "adapt", params)?;
        }
        pipelines.push(file);
    }
    let settings = EvalSettings {
        settle_ticks,
        repeats,
        seed0: a.seed,
        work_dir,
        prefix_stem: format!("bev{}_", std::process::id()),
        launch: LaunchOptions {
            quiet_children: true,
            ..LaunchOptions::current_exe().context("locating the bowden executable")?
        },
        kinds: bowden::registry::REGISTRY,
    };
    Ok(Prepared {
        robot,
        paths,
        pipelines,
        settings,
        repeats,
        report,
        tick_ns,
        settle_ticks,
    })
}

fn progress_bar(total: u64) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{msg:32} [{bar:30}] {pos}/{len} points  {per_sec}  eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

/// "plant FILE (unit …)" of the report headers.
fn describe_plant(a: &Files, repeats: u32) -> Result<(bowden_plant::PlantConfig, String)> {
    let plant_cfg = bowden_plant::PlantConfig::load_or_shipped(a.plant.as_ref().map(|p| p.path.as_path()))?;
    let plant_name = a
        .plant
        .as_ref()
        .map(|p| p.shown())
        .unwrap_or_else(|| "configs/plant.toml".into());
    let units = match (a.units, plant_cfg.variation.unit) {
        (Units::Configured, Some(u)) => format!("unit {u}"),
        (Units::Configured, None) | (Units::PerRepeat, _) => {
            format!("units {}..={}, one per repeat", a.seed, a.seed + u64::from(repeats) - 1)
        }
    };
    Ok((plant_cfg, format!("plant {plant_name} ({units})")))
}

fn evaluate(args: EvaluateArgs) -> Result<()> {
    let a = Files::resolve(args)?;
    if let Some(minutes) = a.session {
        return evaluate_session(&a, minutes);
    }
    let Prepared {
        robot,
        paths,
        pipelines,
        settings,
        repeats,
        report,
        tick_ns,
        settle_ticks,
    } = prepare(&a, 5, "out/evaluate", ["report.md", "report.json"])?;
    let total: u64 =
        paths.iter().map(|t| t.q_deg.len() as u64).sum::<u64>() * a.controllers.len() as u64 * u64::from(repeats);
    let bar = progress_bar(total);
    let mut runs = Vec::new();
    for t in &paths {
        for (c, pipeline) in a.controllers.iter().zip(&pipelines) {
            for r in 0..repeats {
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
    let (_, plant) = describe_plant(&a, repeats)?;
    let header = format!(
        "{} trajectories × {} controllers × {} repeats; points held {} ticks of {} ms; pipeline {}; robot {}; {}; {}.",
        a.trajectories.len(),
        a.controllers.len(),
        repeats,
        settle_ticks,
        tick_ns as f64 / 1e6,
        a.config.shown(),
        a.robot.shown(),
        plant,
        pipelines
            .first()
            .map(|p| describe_controller(p))
            .unwrap_or_else(|| "no controller".into())
    );
    let files = write_report(&robot, &runs, &summary, &header, &report)?;
    let json = serde_json::to_string_pretty(&summary)?;
    if let Some(j) = &a.json_out {
        std::fs::write(j, &json).with_context(|| format!("{}", j.display()))?;
    }
    if a.json {
        println!("{json}");
    } else {
        print!("{}", bowden_evaluation::report::markdown(&summary, &header));
    }
    print_files(&files);
    Ok(())
}

fn print_files(files: &[PathBuf]) {
    eprintln!(
        "report: {}",
        files
            .iter()
            .map(|f| f.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
}

/// The plant file's `[drift]` as the session reports it: onset, marks for the plots, one line.
fn slack_events(cfg: &bowden_plant::PlantConfig, robot: &Robot) -> SlackEvents {
    let (marks, description) = cfg.drift.describe(|i| {
        robot
            .config
            .cables
            .get(i)
            .map(|c| c.name.clone())
            .unwrap_or_else(|| format!("w{}", i + 1))
    });
    SlackEvents {
        onset_s: cfg.drift.onset_s(),
        marks,
        description,
    }
}

/// `bowden evaluate --session MINUTES`: the trajectories looped through one lockstep pipeline
/// per controller (and repeat) for MINUTES of simulated time; error over time.
fn evaluate_session(a: &Files, minutes: f64) -> Result<()> {
    if !(minutes.is_finite() && minutes > 0.0 && minutes <= 24.0 * 60.0) {
        bail!("--session: MINUTES must be in (0, 1440], got {minutes}");
    }
    if !(a.window_s.is_finite() && a.window_s > 0.0) {
        bail!("--window-s must be a positive number of seconds, got {}", a.window_s);
    }
    let Prepared {
        robot,
        paths,
        pipelines,
        settings,
        repeats,
        report,
        tick_ns,
        settle_ticks,
    } = prepare(a, 1, "out/evaluate-session", ["session.md", "session.json"])?;
    let trajectories: Vec<(String, Vec<bowden_kinematics::JointsDeg>)> =
        paths.iter().map(|t| (t.name.clone(), t.q_deg.clone())).collect();
    let connect = |x: &bowden_kinematics::JointsDeg, y: &bowden_kinematics::JointsDeg| {
        bowden_trajectory::interpolate_eq16(&[*x, *y])
    };
    let plan = session::plan(&trajectories, minutes * 60.0, settle_ticks, tick_ns, &connect)?;
    let total = plan.q_path.len() as u64 * a.controllers.len() as u64 * u64::from(repeats);
    let bar = progress_bar(total);
    let mut runs = Vec::new();
    for (c, pipeline) in a.controllers.iter().zip(&pipelines) {
        for r in 0..repeats {
            bar.set_message(format!("session / {c} / #{r}"));
            let spec = RunSpec {
                pipeline_file: pipeline,
                name: "session",
                controller: c,
                repeat: r,
                approach: &plan.approach,
                q_path: &plan.q_path,
            };
            runs.push(run_trajectory(&spec, &settings, &mut || bar.inc(1))?);
        }
    }
    bar.finish_and_clear();
    let (plant_cfg, plant) = describe_plant(a, repeats)?;
    let slack = slack_events(&plant_cfg, &robot);
    let summary = session::analyse(&robot, &plan, &runs, a.window_s, &slack)?;
    let header = format!(
        "Session of {:.1} simulated minutes ({} points per run, trajectories {} looped) × {} controllers × {} \
         repeats; points held {} ticks of {} ms; pipeline {}; robot {}; {}; {}.",
        plan.duration_s / 60.0,
        plan.q_path.len(),
        a.trajectories.join(", "),
        a.controllers.len(),
        repeats,
        settle_ticks,
        tick_ns as f64 / 1e6,
        a.config.shown(),
        a.robot.shown(),
        plant,
        pipelines
            .first()
            .map(|p| describe_controller(p))
            .unwrap_or_else(|| "no controller".into())
    );
    let files = session::write(&summary, &plan, &runs, &header, &report)?;
    let json = serde_json::to_string_pretty(&summary)?;
    if let Some(j) = &a.json_out {
        std::fs::write(j, &json).with_context(|| format!("{}", j.display()))?;
    }
    if a.json {
        println!("{json}");
    } else {
        print!("{}", session::markdown(&summary, &header));
    }
    print_files(&files);
    Ok(())
}
