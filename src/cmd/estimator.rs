//! `bowden estimate` (joint configurations from recorded RGBD frames) and `bowden estimator
//! eval` (accuracy and speed of the estimator against the synthetic camera's ground truth).

use anyhow::{bail, Context, Result};
use bowden_camera::{CameraConfig, ReplaySource, SyntheticCamera};
use bowden_estimator::eval::{run_eval, EvalOptions};
use bowden_estimator::record::EstimateRecord;
use bowden_estimator::{Estimator, EstimatorConfig};
use bowden_interfaces::{JointEstimate, MarkerSet};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_kinematics::{JointsDeg, Robot};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

/// Robot and marker files shared by both subcommands.
#[derive(Args)]
pub struct ModelArgs {
    /// Robot geometry.
    #[arg(long, default_value = "configs/robot.toml")]
    pub robot: PathBuf,
    /// Markers file: [geometry] (sphere placement), [hsv] and [estimator] (thresholds, gates).
    #[arg(long, default_value = "configs/markers.toml")]
    pub markers: PathBuf,
}

#[derive(Subcommand)]
pub enum Command {
    /// Estimates the physical joint configuration of every frame of a recording (a directory
    /// with index.json, colour and 16-bit depth PNGs, as `bowden` records them).
    Estimate {
        /// Recording directory.
        #[arg(long)]
        frames: PathBuf,
        /// Print one JSON record per frame (a JSON array) instead of a table.
        #[arg(long)]
        json: bool,
        /// IK start for every frame, q1,q2,q3,q4,q5 in degrees (e.g. the command); none by default.
        #[arg(long, value_name = "Q1,Q2,Q3,Q4,Q5", allow_hyphen_values = true)]
        hint: Option<String>,
        #[command(flatten)]
        model: ModelArgs,
    },
    /// Estimator tools.
    Estimator {
        #[command(subcommand)]
        what: EstimatorCommand,
    },
}

#[derive(Subcommand)]
pub enum EstimatorCommand {
    /// Renders seeded random configurations over the workspace with the synthetic camera,
    /// estimates them and reports sphere-centre error, joint error, detection rate and
    /// per-frame time against the goals.
    Eval {
        /// Number of frames (random configurations).
        #[arg(long, default_value_t = 1000)]
        frames: u32,
        /// Seed of the configurations and hints; the camera noise uses it too.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print the report as JSON instead of Markdown.
        #[arg(long)]
        json: bool,
        /// Also write eval.json, eval.md and eval.svg into this directory.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Overwrite eval.json, eval.md and eval.svg in --out if they exist.
        #[arg(long)]
        force: bool,
        /// The IK hint is the truth plus uniform noise of ± this per joint (the command is off
        /// the physical angle by the hysteresis).
        #[arg(long, default_value_t = 15.0)]
        hint_offset_deg: f64,
        /// Estimate without any hint.
        #[arg(long)]
        no_hint: bool,
        /// Exit with an error when a goal is missed (timing only in a release build).
        #[arg(long)]
        check: bool,
        /// Camera (intrinsics, pose, noise, appearance).
        #[arg(long, default_value = "configs/camera.toml")]
        camera: PathBuf,
        #[command(flatten)]
        model: ModelArgs,
    },
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Estimate {
            frames,
            json,
            hint,
            model,
        } => estimate(&frames, json, hint.as_deref(), &model),
        Command::Estimator {
            what:
                EstimatorCommand::Eval {
                    frames,
                    seed,
                    json,
                    out,
                    force,
                    hint_offset_deg,
                    no_hint,
                    check,
                    camera,
                    model,
                },
        } => {
            if let Some(dir) = &out {
                let files = ["eval.json", "eval.md", "eval.svg"].map(|f| dir.join(f));
                super::refuse_overwrite(&files, force, "--out")?;
            }
            let camera = crate::home::path(&camera)?;
            let hint = if no_hint { None } else { Some(hint_offset_deg) };
            eval(frames, seed, json, out.as_deref(), hint, check, &camera, &model)
        }
    }
}

fn load_model(m: &ModelArgs) -> Result<(Robot, MarkerGeometry, EstimatorConfig)> {
    let robot = Robot::load(crate::home::path(&m.robot)?)?;
    let markers = crate::home::path(&m.markers)?;
    let geometry = MarkerGeometry::load(&markers)?;
    let cfg = EstimatorConfig::load(&markers)?;
    Ok((robot, geometry, cfg))
}

fn progress(n: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(n);
    bar.set_style(
        ProgressStyle::with_template(&format!("{{bar:40}} {{pos}}/{{len}} {what} {{per_sec}} eta {{eta}}"))
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

fn estimate(dir: &Path, json: bool, hint: Option<&str>, model: &ModelArgs) -> Result<()> {
    let hint: Option<JointsDeg> = hint.map(|h| super::kin::parse_list(h, "--hint")).transpose()?;
    let (robot, geometry, cfg) = load_model(model)?;
    let mut replay = ReplaySource::open(dir)?;
    let s = *replay.stream();
    let px = s.pixels();
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let mut est = Estimator::new(robot, geometry, cfg);
    est.reserve_frame(s.width, s.height);
    let (mut ms, mut je) = (MarkerSet::default(), JointEstimate::default());
    let mut records = Vec::with_capacity(replay.len());
    let mut counts = [0usize; 3];
    let bar = progress(replay.len() as u64, "frames");
    for i in 0..replay.len() {
        let header = replay.read(i, &mut rgb, &mut depth)?;
        est.estimate(&header, &rgb, &depth, hint, &mut ms, &mut je)
            .with_context(|| format!("{}: frame {i} (seq {})", dir.display(), header.header.seq))?;
        counts[(je.quality as usize).min(2)] += 1;
        let rec = EstimateRecord::new(&ms, &je, est.diagnostics());
        if !json {
            bar.suspend(|| println!("{}", rec.summary_line()));
        }
        records.push(rec);
        bar.inc(1);
    }
    bar.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string_pretty(&records)?);
    } else {
        println!(
            "{} frames: {} valid, {} partial, {} invalid",
            records.len(),
            counts[0],
            counts[1],
            counts[2]
        );
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn eval(
    frames: u32,
    seed: u64,
    json: bool,
    out: Option<&Path>,
    hint_offset_deg: Option<f64>,
    check: bool,
    camera: &Path,
    model: &ModelArgs,
) -> Result<()> {
    if frames == 0 {
        bail!("--frames must be at least 1");
    }
    if let Some(d) = hint_offset_deg {
        if !(d.is_finite() && d >= 0.0) {
            bail!("--hint-offset-deg must be a non-negative number, got {d}");
        }
    }
    let (robot, geometry, cfg) = load_model(model)?;
    let cam_cfg = CameraConfig::load(camera)?;
    let mut camera = SyntheticCamera::new(robot.clone(), geometry.clone(), cam_cfg, seed);
    let mut est = Estimator::new(robot, geometry, cfg);
    let opts = EvalOptions {
        frames,
        seed,
        hint_offset_deg,
    };
    let bar = progress(frames as u64, "frames");
    let report = run_eval(&mut est, &mut camera, &opts, |_| bar.inc(1))?;
    bar.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.to_markdown());
        if cfg!(debug_assertions) {
            println!("\n(debug build: frame times are not representative; use --release)");
        }
    }
    if let Some(dir) = out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let j = dir.join("eval.json");
        std::fs::write(&j, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", j.display()))?;
        let m = dir.join("eval.md");
        std::fs::write(&m, report.to_markdown()).with_context(|| format!("writing {}", m.display()))?;
        let svg = dir.join("eval.svg");
        report.write_svg(&svg)?;
        eprintln!("wrote {}, {}, {}", j.display(), m.display(), svg.display());
    }
    if check {
        let failures = report.goal_failures(!cfg!(debug_assertions));
        if !failures.is_empty() {
            bail!("goals missed: {}", failures.join("; "));
        }
    }
    Ok(())
}
