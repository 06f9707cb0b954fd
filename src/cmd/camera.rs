//! `bowden render`: one synthetic RGBD frame of a configuration, as PNGs a person can look at.

use anyhow::{Context, Result};
use bowden_camera::pngio::{depth_preview, write_depth_png, write_rgb_png};
use bowden_camera::{label, CameraConfig, SyntheticCamera};
use bowden_interfaces::{marker, N_MARKERS};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_kinematics::{JointsDeg, Robot};
use clap::Subcommand;
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum Command {
    /// Renders the synthetic RGBD camera's view of a configuration: colour PNG, 16-bit depth
    /// PNG (`<out>_depth.png`, counts of depth.unit_mm) and a false-colour depth preview
    /// (`<out>_depth_vis.png`).
    Render {
        /// Physical joint angles q1,q2,q3,q4,q5 in degrees.
        #[arg(long, value_name = "Q1,Q2,Q3,Q4,Q5", allow_hyphen_values = true)]
        q: String,
        /// Colour image to write; the depth images go beside it.
        #[arg(long, default_value = "frame.png")]
        out: PathBuf,
        /// Camera (intrinsics, pose, noise, appearance).
        #[arg(long, default_value = "configs/camera.toml")]
        config: PathBuf,
        /// Robot geometry.
        #[arg(long, default_value = "configs/robot.toml")]
        robot: PathBuf,
        /// Marker placement ([geometry] table).
        #[arg(long, default_value = "configs/markers.toml")]
        markers: PathBuf,
        /// Noise seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Frame index (selects the noise of this frame).
        #[arg(long, default_value_t = 0)]
        frame: u64,
        /// Overwrite the images if they exist.
        #[arg(long)]
        force: bool,
    },
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Render {
            q,
            out,
            config,
            robot,
            markers,
            seed,
            frame,
            force,
        } => {
            let outs = [out.clone(), sibling(&out, "_depth"), sibling(&out, "_depth_vis")];
            super::refuse_overwrite(&outs, force, "--out")?;
            let home = crate::home::path;
            render(&q, &out, &home(&config)?, &home(&robot)?, &home(&markers)?, seed, frame)
        }
    }
}

fn sibling(out: &Path, suffix: &str) -> PathBuf {
    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("frame");
    out.with_file_name(format!("{stem}{suffix}.png"))
}

fn render(q: &str, out: &Path, config: &Path, robot: &Path, markers: &Path, seed: u64, frame: u64) -> Result<()> {
    let q: JointsDeg = super::kin::parse_list(q, "--q")?;
    let cfg = CameraConfig::load(config)?;
    let robot = Robot::load(robot)?;
    let markers = MarkerGeometry::load(markers)?;
    if let Err(e) = robot.check_limits(&q) {
        eprintln!("warning: --q: {e}; rendering it anyway");
    }
    let mut cam = SyntheticCamera::new(robot, markers, cfg, seed);
    let (w, h) = (cam.width(), cam.height());
    let px = (w * h) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    cam.render(&q, frame, &mut rgb, &mut depth).context("render")?;
    let depth_path = sibling(out, "_depth");
    let vis_path = sibling(out, "_depth_vis");
    write_rgb_png(out, w, h, &rgb)?;
    write_depth_png(&depth_path, w, h, &depth, &mut Vec::new())?;
    write_rgb_png(&vis_path, w, h, &depth_preview(&depth))?;
    println!(
        "wrote {} (colour), {} (16-bit depth, {} mm/count), {} (false-colour depth)",
        out.display(),
        depth_path.display(),
        cam.depth_unit_mm(),
        vis_path.display()
    );
    let mut seen = [0usize; N_MARKERS];
    let mut with_depth = [0usize; N_MARKERS];
    for (i, &l) in cam.labels().iter().enumerate() {
        let m = (l & label::WHAT_MASK).wrapping_sub(label::MARKER0) as usize;
        if m < N_MARKERS {
            seen[m] += 1;
            with_depth[m] += usize::from(depth[i] > 0);
        }
    }
    println!("marker  centre in camera (mm)            pixel (u, v)      visible px  with depth");
    for (m, c) in cam.marker_centres_cam_mm(&q).iter().enumerate() {
        let uv = cam
            .intrinsics()
            .project(c)
            .map_or("behind camera".to_string(), |(u, v)| format!("({u:6.1}, {v:6.1})"));
        println!(
            "{:<6}  [{:8.2} {:8.2} {:8.2}]   {uv:<16}  {:>10}  {:>10}",
            marker::NAMES[m],
            c.x,
            c.y,
            c.z,
            seen[m],
            with_depth[m]
        );
    }
    Ok(())
}

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Synthetic camera: latency of one 640x480 frame (render + sensor model into an RGBD
    /// payload) over seeded workspace configurations, p50/p99/p99.9/max.
    Camera {
        /// Frames to render.
        #[arg(long, default_value_t = 2000)]
        frames: u64,
        /// Seed of the configurations and the noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Camera (intrinsics, pose, noise, appearance).
        #[arg(long, default_value = "configs/camera.toml")]
        config: PathBuf,
        /// Print JSON instead of the Markdown table.
        #[arg(long)]
        json: bool,
    },
}

// Reached through `bowden bench camera` once cmd/bench.rs lists `Camera(super::camera::BenchCommand)`.
pub fn bench(c: BenchCommand) -> Result<()> {
    let BenchCommand::Camera {
        frames,
        seed,
        config,
        json,
    } = c;
    if frames == 0 {
        anyhow::bail!("--frames must be > 0");
    }
    let cfg = CameraConfig::load(crate::home::path(&config)?)?;
    let mut cam = SyntheticCamera::new(Robot::paper_default(), MarkerGeometry::paper_default(), cfg, seed);
    let qs = bowden_camera::bench::workspace_configurations(&cam, 256, seed);
    let bar = indicatif::ProgressBar::new(frames);
    let report = bowden_camera::bench::render_latency(&mut cam, &qs, frames, &mut |n| bar.inc(n))?;
    bar.finish_and_clear();
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&report).context("serialising the report")?
        );
    } else {
        print!("{}", report.to_markdown());
    }
    Ok(())
}
