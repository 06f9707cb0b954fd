//! `bowden plant characterize`: the paper's dataset protocol (eq. 16 commands, each held 0.5 s)
//! on the simulated plant, reported like Table IV with Fig. 9b hysteresis loops.

use anyhow::{bail, Context, Result};
use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use bowden_plant::{characterize, CharacterizeOptions, Plant, PlantConfig};
use bowden_tables::{ReadOptions, Table};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum Command {
    /// The simulated tendon-sheath manipulator.
    #[command(subcommand)]
    Plant(PlantCommand),
}

#[derive(Subcommand)]
pub enum PlantCommand {
    /// Runs the paper's dataset protocol on the simulated plant: eq. (16) commands, each held
    /// for the pause, then per-joint MAE and SD of |q_phy − q_cmd| (Table IV) and a
    /// q_cmd-vs-q_phy loop plot of q1 and q3 (Fig. 9b).
    Characterize(CharacterizeArgs),
    /// Play a command file on the simulated robot offline (no camera, no pipeline): each row is
    /// held --period-ns, the physical angles (simulator truth) are read at the end of the hold and
    /// compared with the targets: joint MAE (Table VI) and tip position / orientation error via FK
    /// (Table V). Commands are the columns q_cmd_1..5 when present (`bowden compensate` output,
    /// whose q_des_1..5 are then the targets), else q1..q5 (a target file played uncalibrated).
    Play(PlayArgs),
}

#[derive(Args)]
pub struct PlayArgs {
    /// Command CSV: `bowden compensate` output, or a target file (columns q1..q5, degrees).
    #[arg(long)]
    commands: PathBuf,
    /// Targets CSV (q1..q5 or q_des_1..5); default: the q_des columns of --commands, else its
    /// commands themselves (the uncalibrated robot).
    #[arg(long)]
    targets: Option<PathBuf>,
    /// Plant file (e.g. configs/plant-lugre.toml: found as given, under $BOWDEN_HOME, or built
    /// in); the shipped configs/plant.toml when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Robot file; the shipped configs/robot.toml when absent.
    #[arg(long)]
    robot: Option<PathBuf>,
    /// The plant unit (manufacturing instance); default the plant file's `[variation] unit`.
    #[arg(long)]
    unit: Option<u64>,
    /// Time each row is held, ns (1 000 000 = a 1 kHz command stream).
    #[arg(long, default_value_t = 1_000_000)]
    period_ns: u64,
    /// Before the first row the robot goes from the straight pose to the first command at the
    /// dataset's step, each step held this long, s (as `bowden evaluate` approaches a path).
    #[arg(long, default_value_t = 0.5)]
    approach_hold_s: f64,
    /// Per-row CSV (q_des, q_cmd, q_phy) to write.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite --out if it exists.
    #[arg(long)]
    force: bool,
    /// Print the result as JSON instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct CharacterizeArgs {
    /// Plant file (e.g. configs/plant-lugre.toml: found as given, under $BOWDEN_HOME, or built
    /// in); the shipped configs/plant.toml when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Robot file; the shipped configs/robot.toml when absent.
    #[arg(long)]
    robot: Option<PathBuf>,
    /// Random configurations of eq. (16) (the paper drew 1,802).
    #[arg(long, default_value_t = 1802)]
    samples: usize,
    /// Seed of the eq. (16) commands.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Seed of the plant instance (its cable-to-cable variation); defaults to --seed.
    #[arg(long)]
    plant_seed: Option<u64>,
    /// Hold per command, s (the paper paused 0.5 s for the camera).
    #[arg(long, default_value_t = 0.5)]
    pause: f64,
    /// Simulation step, s.
    #[arg(long, default_value_t = 0.01)]
    dt: f64,
    /// Print the result as JSON instead of the Markdown table.
    #[arg(long)]
    json: bool,
    /// Hysteresis-loop plot to write (SVG).
    #[arg(long, default_value = "plant_loops.svg")]
    plot: PathBuf,
    /// Overwrite --plot if it exists.
    #[arg(long)]
    force: bool,
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Plant(PlantCommand::Characterize(a)) => run_characterize(a),
        Command::Plant(PlantCommand::Play(a)) => run_play(a),
    }
}

fn run_characterize(a: CharacterizeArgs) -> Result<()> {
    let robot = match &a.robot {
        Some(p) => Robot::load(crate::home::path(p)?).context("loading the robot file (--robot)")?,
        None => Robot::paper_default(),
    };
    let config = a.config.as_deref().map(crate::home::path).transpose()?;
    let config = PlantConfig::load_or_shipped(config.as_deref()).context("loading the plant file (--config)")?;
    super::refuse_overwrite(
        &[a.plot.clone(), bowden_plant::characterize::timeseries_path(&a.plot)],
        a.force,
        "--plot",
    )?;
    anyhow::ensure!(
        a.samples >= 2,
        "--samples {}: need at least 2 random configurations",
        a.samples
    );
    anyhow::ensure!(
        a.pause.is_finite() && a.pause > 0.0,
        "--pause {}: need a positive number of seconds",
        a.pause
    );
    anyhow::ensure!(
        a.dt.is_finite() && a.dt > 0.0 && a.dt <= a.pause,
        "--dt {}: need 0 < dt ≤ pause ({})",
        a.dt,
        a.pause
    );
    let options = CharacterizeOptions {
        n_configs: a.samples,
        dataset_seed: a.seed,
        plant_seed: a.plant_seed.unwrap_or(a.seed),
        pause_s: a.pause,
        dt_s: a.dt,
    };
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:40}] {pos}/{len} commands ({eta})")
            .context("progress bar template")?
            .progress_chars("=> "),
    );
    bar.set_prefix("characterize");
    let result = characterize(&robot, &config, &options, &mut |done, total| {
        if done == 1 {
            bar.set_length(total as u64);
        }
        if done % 100 == 0 || done == total {
            bar.set_position(done as u64);
        }
    })
    .context("running the eq. (16) commands through the plant")?;
    bar.finish_and_clear();
    result
        .write_loop_plot(&a.plot)
        .with_context(|| format!("writing the loop plot {}", a.plot.display()))?;
    let text = if a.json {
        serde_json::to_string_pretty(&result).context("serialising the result")? + "\n"
    } else {
        format!(
            "{}Loops (q_cmd vs q_phy, q1 and q3): {}\n",
            result.markdown_table(),
            a.plot.display()
        )
    };
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        // A closed pipe (`| head`) is the reader's choice, not a failure.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
        r => r.context("writing to stdout")?,
    }
    Ok(())
}

/// A command or target file: a CSV with a header (names compared ignoring case, `#` lines
/// skipped).
fn read_table(file: &Path) -> Result<Table> {
    let opts = ReadOptions {
        header: true,
        comments: true,
        ignore_case: true,
    };
    Ok(Table::read(file, opts)?)
}

/// Columns `names` of the table, as rows of 5 finite values; `None` when the header lacks any
/// of them. Errors name the file, line and column.
fn read_columns(table: &Table, names: &[String]) -> Result<Option<Vec<JointsDeg>>> {
    let Ok(cols) = table.columns(names) else {
        return Ok(None);
    };
    table.require_rows("data rows")?;
    let rows = table.finite_rows(&cols)?;
    Ok(Some(rows.iter().map(|r| core::array::from_fn(|j| r[j])).collect()))
}

fn joint_cols(prefix: &str) -> Vec<String> {
    (1..=N_JOINTS).map(|j| format!("{prefix}{j}")).collect()
}

/// Result of `plant play`.
#[derive(serde::Serialize)]
struct PlayResult {
    rows: usize,
    period_ns: u64,
    plant: String,
    unit: u64,
    joint_mae_deg: [f64; N_JOINTS],
    joint_mae_mean_deg: f64,
    tip_position_mean_mm: f64,
    tip_orientation_mean_deg: f64,
    step_errors: u64,
}

// Long: argument checks, set-up and the paced playback loop of one command; the plant itself is a library call per step.
fn run_play(a: PlayArgs) -> Result<()> {
    let robot = match &a.robot {
        Some(p) => Robot::load(crate::home::path(p)?).context("loading the robot file (--robot)")?,
        None => Robot::paper_default(),
    };
    let config = a.config.as_deref().map(crate::home::path).transpose()?;
    let config = PlantConfig::load_or_shipped(config.as_deref()).context("loading the plant file (--config)")?;
    let Some(unit) = a.unit.or(config.variation.unit) else {
        bail!("the plant file has no `[variation] unit`; pass --unit N to choose the robot instance");
    };
    anyhow::ensure!(a.period_ns > 0, "--period-ns must be positive");
    anyhow::ensure!(
        a.approach_hold_s.is_finite() && a.approach_hold_s >= 0.0,
        "--approach-hold-s {}: need a non-negative number of seconds",
        a.approach_hold_s
    );
    let table = read_table(&a.commands)?;
    let (commands, own_targets) = match read_columns(&table, &joint_cols("q_cmd_"))? {
        Some(c) => (c, read_columns(&table, &joint_cols("q_des_"))?),
        None => match read_columns(&table, &joint_cols("q"))? {
            Some(c) => (c, None),
            None => bail!(
                "{}: no command columns: need q_cmd_1..q_cmd_5 (`bowden compensate` output) or q1..q5",
                a.commands.display()
            ),
        },
    };
    let targets = match &a.targets {
        Some(p) => {
            let t = read_table(p)?;
            match read_columns(&t, &joint_cols("q_des_"))? {
                Some(r) => r,
                None => read_columns(&t, &joint_cols("q"))?
                    .with_context(|| format!("{}: no target columns: need q1..q5 or q_des_1..q_des_5", p.display()))?,
            }
        }
        None => own_targets.unwrap_or_else(|| commands.clone()),
    };
    anyhow::ensure!(
        targets.len() == commands.len(),
        "{} targets but {} commands: the files must have one row per step",
        targets.len(),
        commands.len()
    );
    if let Some(p) = &a.out {
        super::refuse_overwrite(std::slice::from_ref(p), a.force, "--out")?;
    }

    let mut plant =
        Plant::try_new(&robot, &config, unit).with_context(|| format!("building unit {unit} of the plant"))?;
    // Simulation sub-step: the row period, at most 1 ms (the families sub-step further inside).
    let period_s = a.period_ns as f64 * 1e-9;
    let dt_s = period_s.min(1e-3);
    let mut step_errors = 0u64;
    let mut approach = bowden_trajectory::interpolate_eq16(&[[0.0; N_JOINTS], commands[0]]);
    approach.retain(|q| *q != commands[0]);
    if a.approach_hold_s > 0.0 {
        for q in &approach {
            if plant
                .settle_joints(
                    &robot.clamp_command_to_limits(q),
                    a.approach_hold_s,
                    a.approach_hold_s.min(0.01),
                )
                .is_err()
            {
                step_errors += 1;
            }
        }
    }
    let bar = ProgressBar::new(commands.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:40}] {pos}/{len} rows ({eta})")
            .context("progress bar template")?
            .progress_chars("=> "),
    );
    bar.set_prefix("play");
    let mut q_phy = Vec::with_capacity(commands.len());
    for (k, q) in commands.iter().enumerate() {
        // An out-of-range command leaves the plant where it was, as the plant node does: count it.
        if plant.settle_joints(q, period_s, dt_s).is_err() {
            step_errors += 1;
        }
        q_phy.push(plant.q_phy_deg());
        if k % 1000 == 0 {
            bar.set_position(k as u64);
        }
    }
    bar.finish_and_clear();

    let joint = bowden_evaluation::metrics::joint_errors(
        &targets.iter().copied().zip(q_phy.iter().copied()).collect::<Vec<_>>(),
    );
    let task = bowden_evaluation::metrics::task_errors(
        &targets
            .iter()
            .zip(&q_phy)
            .map(|(t, p)| (robot.fk(t).ee, robot.fk(p).ee))
            .collect::<Vec<_>>(),
    );
    let result = PlayResult {
        rows: commands.len(),
        period_ns: a.period_ns,
        plant: config.name.clone(),
        unit,
        joint_mae_deg: joint.mae_deg,
        joint_mae_mean_deg: joint.mae_deg.iter().sum::<f64>() / N_JOINTS as f64,
        tip_position_mean_mm: task.pos_mean_mm,
        tip_orientation_mean_deg: task.rot_mean_deg,
        step_errors,
    };
    if let Some(p) = &a.out {
        let mut t = String::new();
        t.push_str(
            &[joint_cols("q_des_"), joint_cols("q_cmd_"), joint_cols("q_phy_")]
                .concat()
                .join(","),
        );
        t.push('\n');
        for ((d, c), f) in targets.iter().zip(&commands).zip(&q_phy) {
            let row: Vec<String> = d.iter().chain(c).chain(f).map(|v| format!("{v:.6}")).collect();
            t.push_str(&row.join(","));
            t.push('\n');
        }
        std::fs::write(p, t).with_context(|| format!("writing {}", p.display()))?;
    }
    let text = if a.json {
        serde_json::to_string_pretty(&result).context("serialising the result")? + "\n"
    } else {
        let mae: Vec<String> = result.joint_mae_deg.iter().map(|v| format!("{v:.2}")).collect();
        format!(
            "{} rows held {} ns on {} unit {}{}\n\
             | joint MAE q1..q5, deg | mean joint MAE, deg | tip position, mm | tip orientation, deg |\n\
             |---|---|---|---|\n| {} | {:.3} | {:.3} | {:.3} |\n",
            result.rows,
            result.period_ns,
            result.plant,
            result.unit,
            if step_errors > 0 {
                format!(" ({step_errors} commands refused by the plant and held the previous one)")
            } else {
                String::new()
            },
            mae.join(" / "),
            result.joint_mae_mean_deg,
            result.tip_position_mean_mm,
            result.tip_orientation_mean_deg
        )
    };
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
        r => r.context("writing to stdout")?,
    }
    Ok(())
}
