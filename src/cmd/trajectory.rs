//! `bowden trajectory export`: a task-space trajectory file as the joint path `evaluate` tracks,
//! written as a CSV of targets at any spacing — the dataset's step (what `evaluate` uses) or a
//! fine step for 1 kHz playback (`compensate --period-ns 1000000`, then `plant play`).

use anyhow::{bail, Context, Result};
use bowden_kinematics::Robot;
use bowden_trajectory::task_space::TrajectorySpec;
use bowden_trajectory::DATASET_STEP_DEG;
use clap::{Args, Subcommand};
use std::io::Write;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum Command {
    /// Trajectory files (configs/trajectories/*.toml) as joint paths.
    #[command(subcommand)]
    Trajectory(TrajectoryCommand),
}

#[derive(Subcommand)]
pub enum TrajectoryCommand {
    /// Write a trajectory file's joint path (IK of its tip path, resampled by chord length) as a
    /// target CSV with columns q1..q5 in degrees — the input `bowden compensate` and
    /// `bowden plant play` read. The default spacing is the dataset's step 3·√5° (what
    /// `bowden evaluate` tracks); `--step-deg 0.06` is the 1 kHz-fine version at 60°/s.
    Export(ExportArgs),
}

#[derive(Args)]
pub struct ExportArgs {
    /// Trajectory file (e.g. configs/trajectories/large/circle.toml).
    #[arg(long)]
    file: PathBuf,
    /// Robot description (IK and joint limits).
    #[arg(long, default_value = "configs/robot.toml")]
    robot: PathBuf,
    /// Joint-space distance between consecutive targets, deg (straight-line over q1..q5).
    /// Default: the dataset's step 3·√5 ≈ 6.708°. A 1 kHz stream moving at v °/s needs v/1000.
    #[arg(long)]
    step_deg: Option<f64>,
    /// Output CSV; standard output when absent.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite --out if it exists.
    #[arg(long)]
    force: bool,
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Trajectory(TrajectoryCommand::Export(a)) => export(a),
    }
}

fn export(a: ExportArgs) -> Result<()> {
    let step_deg = a.step_deg.unwrap_or(DATASET_STEP_DEG);
    if !(step_deg.is_finite() && step_deg >= 1e-3) {
        bail!("--step-deg {step_deg}: need a finite spacing of at least 0.001°");
    }
    let robot_file = crate::home::path(&a.robot)?;
    let robot = Robot::load(&robot_file).with_context(|| format!("loading the robot file {}", a.robot.display()))?;
    let file = crate::home::path(&a.file)?;
    let spec = TrajectorySpec::load(&file)?;
    let path = spec.to_joint_space_with_step(&robot, &a.file, step_deg)?;
    let mut text = String::from("q1,q2,q3,q4,q5\n");
    for q in &path.q_deg {
        let row: Vec<String> = q.iter().map(|v| format!("{v:.9}")).collect();
        text.push_str(&row.join(","));
        text.push('\n');
    }
    match &a.out {
        Some(p) => {
            super::refuse_overwrite(std::slice::from_ref(p), a.force, "--out")?;
            std::fs::write(p, &text).with_context(|| format!("writing {}", p.display()))?;
            eprintln!(
                "{}: {} targets {:.4}° apart ({}) -> {}",
                a.file.display(),
                path.q_deg.len(),
                step_deg,
                spec.name,
                p.display()
            );
        }
        None => {
            let mut out = std::io::stdout().lock();
            match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
                r => r.context("writing to stdout")?,
            }
        }
    }
    Ok(())
}
