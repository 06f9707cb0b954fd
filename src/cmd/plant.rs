//! `bowden plant characterize`: the paper's dataset protocol (eq. 16 commands, each held 0.5 s)
//! on the simulated plant, reported like Table IV with Fig. 9b hysteresis loops.

use anyhow::{Context, Result};
use bowden_kinematics::Robot;
use bowden_plant::{characterize, CharacterizeOptions, PlantConfig};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::path::PathBuf;

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
}

#[derive(Args)]
pub struct CharacterizeArgs {
    /// Plant file; the shipped configs/plant.toml when absent.
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
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Plant(PlantCommand::Characterize(a)) => run_characterize(a),
    }
}

fn run_characterize(a: CharacterizeArgs) -> Result<()> {
    let robot = match &a.robot {
        Some(p) => Robot::load(p).context("loading the robot file (--robot)")?,
        None => Robot::paper_default(),
    };
    let config = PlantConfig::load_or_shipped(a.config.as_deref()).context("loading the plant file (--config)")?;
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
