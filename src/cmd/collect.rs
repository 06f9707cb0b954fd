//! `bowden collect`: the paper's dataset (§IV-B, eq. 16) recorded through the vision loop:
//! the eq. (16) commands sent uncalibrated through actuator → plant → camera → estimator in
//! the lockstep multi-process pipeline, each held for the paper's 0.5 s pause and measured by
//! the estimator on its last tick.

use anyhow::{bail, Context, Result};
use bowden_evaluation::{camera_fps_for, hold, pipeline_variant};
use bowden_interfaces::{services, JointEstimate, JointTarget};
use bowden_kinematics::{Robot, N_JOINTS};
use bowden_learning::dataset::{fnv1a64_hex, Dataset};
use bowden_runtime::config::{Mode, Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::session::{LockstepSession, SessionOptions};
use bowden_trajectory::ExcitationKind;
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

#[derive(Args)]
pub struct CollectArgs {
    /// Pipeline to run (lockstep; the compensator is forced to `uncalibrated`). Pipeline, robot
    /// and plant files are found as given, under $BOWDEN_HOME, or built in (`bowden shipped`).
    #[arg(long, default_value = "configs/evaluate.toml")]
    pub config: PathBuf,
    /// Robot description (joint limits of the random configurations).
    #[arg(long, default_value = "configs/robot.toml")]
    pub robot: PathBuf,
    /// Plant file for the simulated robot (a second robot is a second file).
    #[arg(long)]
    pub plant: Option<PathBuf>,
    /// Random configurations (eq. 16's endpoints); each becomes several commands. How many a
    /// recipe needs, and what fewer cost in tracking, is measured in docs/results/data-study/.
    #[arg(long, default_value_t = 8000)]
    pub samples: usize,
    /// Seed of the random configurations, the excitation's jumps and dither, and the run's noise.
    #[arg(long, default_value_t = 2024)]
    pub seed: u64,
    /// Ticks each command is held; the last is measured (5 × 100 ms = the paper's 0.5 s).
    #[arg(long, default_value_t = 5)]
    pub settle_ticks: u32,
    /// Output directory: dataset.csv + manifest.json (and the pipeline it ran in pipeline/).
    /// An existing dataset there is kept unless --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Overwrite an existing dataset in --out.
    #[arg(long)]
    pub force: bool,
    /// `mixed` (default): eq. (16) with per-segment step multipliers 1–4 and dither up to ±20°,
    /// so the models also learn the jumps a compensator commands on reversals. `paper`: eq. (16)
    /// exactly. How models trained on each track: docs/results/data-study/.
    #[arg(long, default_value = "mixed", value_parser = super::typed::<ExcitationKind>(), ignore_case = true)]
    pub excitation: ExcitationKind,
    /// Collect under the compensator: the excitation's commands become *targets*, compensated
    /// by this controller (its models, mode and safety), and `q_cmd` records the command it
    /// sent. A model pair trained on a first dataset thus records what a compensator commands
    /// on this robot — the jumps across the dead band on reversals — which is where such a pair
    /// is least accurate (a second collection round, `--extend`; docs/results/data-study/).
    #[arg(long, value_name = "CONTROLLER")]
    pub controller_config: Option<PathBuf>,
    /// Add to the dataset in this directory: the output (`--out`, another directory) holds this
    /// run's rows followed by that dataset's, so its last 20 % — the validation stretch of
    /// `train` and `tune` — stays the earlier dataset's and every new row is trained on. The
    /// histories of the first windows after the seam span both runs: the manifest says where.
    #[arg(long, value_name = "DIR")]
    pub extend: Option<PathBuf>,
}

#[derive(Subcommand)]
pub enum Command {
    /// Record the eq. (16) dataset through the vision loop (CSV + JSON manifest).
    Collect(CollectArgs),
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Collect(a) => collect(a),
    }
}

// Long: argument checks and the collection's set-up in the order the user sees them; the hold-and-measure loop is `bowden_evaluation::hold`.
fn collect(mut a: CollectArgs) -> Result<()> {
    super::dataset_out(&a.out, a.force)?;
    // Found once, here: every later use (and the manifest) names the same files.
    a.config = crate::home::path(&a.config).context("--config")?;
    a.robot = crate::home::path(&a.robot).context("--robot")?;
    if let Some(p) = &a.plant {
        a.plant = Some(crate::home::path(p).context("--plant")?);
    }
    if a.samples < 2 {
        bail!("--samples: need at least 2 random configurations, got {}", a.samples);
    }
    if a.settle_ticks == 0 {
        bail!("--settle-ticks must be at least 1");
    }
    if let Some(c) = &a.controller_config {
        a.controller_config = Some(crate::home::path(c).context("--controller-config")?);
    }
    let before = match &a.extend {
        Some(dir) => {
            if std::fs::canonicalize(dir).ok() == std::fs::canonicalize(&a.out).ok() {
                bail!("--extend {}: must differ from --out", dir.display());
            }
            let (ds, manifest) = Dataset::read_dir(dir).with_context(|| format!("--extend {}", dir.display()))?;
            if ds.joints != N_JOINTS {
                bail!(
                    "--extend {}: {} joints, the robot has {N_JOINTS}",
                    dir.display(),
                    ds.joints
                );
            }
            Some((ds, manifest))
        }
        None => None,
    };
    let robot = Robot::load(&a.robot)?;
    let excitation = a.excitation.excitation();
    let commands = bowden_trajectory::excitation_commands(&robot, a.samples, a.seed, &excitation)
        .map_err(|e| anyhow::anyhow!("--excitation {}: {e}", a.excitation))?;
    let work = a.out.join("pipeline");
    let tick_ns = PipelineConfig::load(&a.config, &Overrides::default(), bowden::registry::REGISTRY)?.period_ns();
    let compensator_mode = match &a.controller_config {
        Some(c) => bowden_compensator::ControllerConfig::load(c)
            .with_context(|| format!("--controller-config {}", c.display()))?
            .mode
            .to_string(),
        None => "uncalibrated".into(),
    };
    let mut set = vec![
        ("compensator", "mode", toml::Value::String(compensator_mode.clone())),
        (
            "camera",
            "fps",
            toml::Value::Float(camera_fps_for(a.settle_ticks, tick_ns)),
        ),
    ];
    if let Some(p) = &a.plant {
        let abs = std::fs::canonicalize(p).with_context(|| format!("--plant {}", p.display()))?;
        set.push(("plant", "config", toml::Value::String(abs.display().to_string())));
    }
    if let Some(c) = &a.controller_config {
        let abs = std::fs::canonicalize(c).with_context(|| format!("--controller-config {}", c.display()))?;
        set.push(("compensator", "config", toml::Value::String(abs.display().to_string())));
    }
    let pipeline = pipeline_variant(&a.config, &set, &work.join("collect.toml"))?;
    let ov = Overrides {
        mode: Some(Mode::Lockstep),
        prefix: Some(format!("bcol{}_", std::process::id())),
        seed: Some(a.seed),
        ..Default::default()
    };
    let cfg = PipelineConfig::load(&pipeline, &ov, bowden::registry::REGISTRY)?;
    let mut opts = SessionOptions::new(LaunchOptions {
        quiet_children: true,
        ..LaunchOptions::current_exe().context("locating the bowden executable")?
    });
    opts.taps = vec![services::PLANT_STATE.into(), services::JOINT_ESTIMATE.into()];
    if a.controller_config.is_some() {
        opts.taps.push(services::JOINT_COMMAND.into());
    }
    opts.source = Some(services::JOINT_TARGET.into());
    let mut session = LockstepSession::start(&cfg, opts)?;
    let bar = ProgressBar::new(commands.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("collect [{bar:40}] {pos}/{len} commands  {per_sec}  eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let n = commands.len();
    let mut data = Dataset {
        joints: N_JOINTS,
        t_ns: Vec::with_capacity(n),
        q_cmd_deg: Vec::with_capacity(n * N_JOINTS),
        q_phy_deg: Vec::with_capacity(n * N_JOINTS),
        q_true_deg: Some(Vec::with_capacity(n * N_JOINTS)),
        valid: Vec::with_capacity(n),
    };
    let run = (|| -> Result<()> {
        // One warm-up tick at home puts the one-frame-per-command grid on each command's last tick.
        session
            .step_with(JointTarget::from_deg(&[0.0; N_JOINTS]))
            .context("warm-up tick")?;
        for (i, q) in commands.iter().enumerate() {
            let held = hold(&mut session, q, a.settle_ticks).with_context(|| format!("command {i}"))?;
            let (state, sent, estimate, t_ns) = (held.state, held.command, held.estimate, held.t_sim_ns);
            let Some(state) = state else {
                bail!("command {i}: no plant state came back (is the plant in the pipeline?)");
            };
            if i == 0 && estimate.is_none() {
                bail!("no camera frame on the last tick of the first command: the camera's frame grid is off");
            }
            let est = estimate.filter(|e| e.quality == JointEstimate::QUALITY_VALID);
            data.t_ns.push(t_ns as i64);
            match (&a.controller_config, sent) {
                (None, _) => data.q_cmd_deg.extend_from_slice(q),
                // What the compensator sent for this target (the last of the hold).
                (Some(_), Some(c)) => data.q_cmd_deg.extend_from_slice(&c.q_cmd_deg[..N_JOINTS]),
                (Some(_), None) => bail!("command {i}: the compensator published no command"),
            }
            match est {
                Some(e) => data.q_phy_deg.extend_from_slice(&e.q_phy_deg[..N_JOINTS]),
                // Kept and flagged, never dropped: the sequence models need the whole history.
                None => data.q_phy_deg.extend_from_slice(&[f64::NAN; N_JOINTS]),
            }
            data.valid.push(est.is_some());
            if let Some(t) = data.q_true_deg.as_mut() {
                t.extend_from_slice(&state.q_phy_deg[..N_JOINTS]);
            }
            bar.inc(1);
        }
        Ok(())
    })();
    bar.finish_and_clear();
    let report = session.shutdown();
    run?;
    report?;
    let new_rows = data.len();
    // --extend: this run's rows first, the earlier dataset's after them, so that the last 20 %
    // (train's and tune's validation stretch) stays that dataset's and every new row trains.
    let extended = match before {
        Some((first, manifest)) => {
            let seam = data.len();
            let t0 = data.t_ns.last().copied().unwrap_or(0);
            data.t_ns.extend(first.t_ns.iter().map(|t| t0 + 1 + t - first.t_ns[0]));
            data.q_cmd_deg.extend_from_slice(&first.q_cmd_deg);
            data.q_phy_deg.extend_from_slice(&first.q_phy_deg);
            data.valid.extend_from_slice(&first.valid);
            data.q_true_deg = match (data.q_true_deg.take(), first.q_true_deg) {
                (Some(mut a), Some(b)) => {
                    a.extend_from_slice(&b);
                    Some(a)
                }
                // Truth of a part only is no truth column.
                _ => None,
            };
            Some(serde_json::json!({
                "dir": a.extend.as_ref().map(|p| p.display().to_string()),
                "first_row": seam,
                "rows": first.t_ns.len(),
                "csv_fnv1a64": manifest.csv_fnv1a64,
                "source": manifest.source,
                "provenance": manifest.provenance,
            }))
        }
        None => None,
    };
    let config_text = std::fs::read_to_string(&pipeline).unwrap_or_default()
        + &std::fs::read_to_string(&a.robot).unwrap_or_default()
        + &a.plant
            .as_ref()
            .and_then(|p| std::fs::read_to_string(p).ok())
            .unwrap_or_default()
        + &a.controller_config
            .as_ref()
            .and_then(|p| std::fs::read_to_string(p).ok())
            .unwrap_or_default();
    let plant_unit = bowden_plant::PlantConfig::load_or_shipped(a.plant.as_deref())?
        .variation
        .unit_for_run(a.seed);
    let mut provenance = serde_json::json!({
        "command": std::env::args().collect::<Vec<_>>(),
        "pipeline": pipeline.display().to_string(),
        "robot": a.robot.display().to_string(),
        "plant": a.plant.as_ref().map(|p| p.display().to_string()),
        // The manufactured unit the data describes (the plant file's, else the run's seed).
        "plant_unit": plant_unit,
        "random_configurations": a.samples,
        "settle_ticks": a.settle_ticks,
        "tick_ns": cfg.period_ns(),
        "step_deg": bowden_trajectory::DATASET_STEP_DEG,
        "excitation": {
            "name": a.excitation.as_str(),
            "step_multipliers": excitation.step_multipliers,
            "dither_deg": excitation.dither_deg,
        },
    });
    // Only when used, so that a plain collection's manifest stays byte for byte what it was.
    if let Some(c) = &a.controller_config {
        // The excitation's commands were targets, compensated by this controller; q_cmd is
        // what it sent.
        provenance["controller_config"] = serde_json::json!(c.display().to_string());
        provenance["compensator_mode"] = serde_json::json!(compensator_mode);
    }
    if let Some(e) = extended {
        // This run's `new_rows` rows come first, that dataset's follow from row `first_row` on.
        provenance["extends"] = e;
        provenance["new_rows"] = serde_json::json!(new_rows);
    }
    let manifest = data.write_dir(
        &a.out,
        "collect",
        Some(a.seed),
        Some(fnv1a64_hex(config_text.as_bytes())),
        provenance,
    )?;
    println!(
        "{}: {} commands from {} random configurations, {} with a valid vision estimate ({:.2} %)",
        a.out.display(),
        manifest.samples,
        a.samples,
        manifest.valid_samples,
        100.0 * manifest.valid_samples as f64 / manifest.samples.max(1) as f64
    );
    Ok(())
}
