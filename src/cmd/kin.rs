//! `bowden fk`, `bowden ik`, `bowden cables`: the manipulator model from the command line.

use anyhow::{bail, Context, Result};
use bowden_kinematics::ik::IkOptions;
use bowden_kinematics::{JointsDeg, Robot, JOINT_NAMES, N_CABLES, N_JOINTS};
use clap::{Args, Subcommand};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::path::PathBuf;

#[derive(Args)]
pub struct RobotArg {
    /// Robot description (Table I/II geometry, limits, cable routing).
    #[arg(long, default_value = "configs/robot.toml")]
    pub config: PathBuf,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

#[derive(Subcommand)]
pub enum Command {
    /// Forward kinematics (eq. 1–3): joint angles → end-effector, jaw and segment frames.
    Fk {
        /// Joint angles q1,q2,q3,q4,q5 in degrees.
        #[arg(long, value_name = "Q1,Q2,Q3,Q4,Q5", allow_hyphen_values = true)]
        q: String,
        #[command(flatten)]
        robot: RobotArg,
    },
    /// Inverse kinematics (eq. 4): end-effector pose → (q1, q2, q3, q_yaw) by damped Newton–Raphson.
    Ik {
        /// End-effector position x,y,z in the base frame, mm.
        #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
        pos: String,
        /// End-effector orientation as a unit quaternion w,x,y,z (base frame).
        #[arg(long, value_name = "W,X,Y,Z", allow_hyphen_values = true)]
        quat: String,
        /// Jaw opening θ = q5 − q4 in degrees, to report q4 = q_yaw − θ/2 and q5 = q_yaw + θ/2.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        opening: f64,
        /// Starting configuration q1,q2,q3,q_yaw in degrees (the paper starts from the command).
        #[arg(long, value_name = "Q1,Q2,Q3,QYAW", allow_hyphen_values = true)]
        q0: Option<String>,
        #[command(flatten)]
        robot: RobotArg,
    },
    /// Cable drive equation (5) with decoupling: joint angles → the 10 cable displacements, or back.
    Cables {
        /// Joint angles q1..q5 in degrees.
        #[arg(long, value_name = "Q1,...,Q5", allow_hyphen_values = true, conflicts_with = "w")]
        q: Option<String>,
        /// Cable displacements w1..w10 in mm (pulled in = positive): solve for the joint angles.
        #[arg(long, value_name = "W1,...,W10", allow_hyphen_values = true)]
        w: Option<String>,
        #[command(flatten)]
        robot: RobotArg,
    },
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Fk { q, robot } => fk(&q, &robot),
        Command::Ik {
            pos,
            quat,
            opening,
            q0,
            robot,
        } => ik(&pos, &quat, opening, q0.as_deref(), &robot),
        Command::Cables { q, w, robot } => cables(q.as_deref(), w.as_deref(), &robot),
    }
}

/// Parses `n` comma-separated finite numbers; `what` names the argument in errors.
pub fn parse_list<const N: usize>(text: &str, what: &str) -> Result<[f64; N]> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != N {
        bail!(
            "{what}: expected {N} comma-separated numbers, got {} in {text:?}",
            parts.len()
        );
    }
    let mut out = [0.0; N];
    for (i, p) in parts.iter().enumerate() {
        let v: f64 = p
            .parse()
            .with_context(|| format!("{what}[{i}]: {p:?} is not a number"))?;
        if !v.is_finite() {
            bail!("{what}[{i}]: {p:?} is not a finite number");
        }
        out[i] = v;
    }
    Ok(out)
}

fn load(robot: &RobotArg) -> Result<Robot> {
    Ok(Robot::load(&robot.config)?)
}

fn joints(robot: &Robot, text: &str) -> Result<JointsDeg> {
    let q: JointsDeg = parse_list(text, "--q")?;
    robot.check_limits(&q).context("--q")?;
    Ok(q)
}

fn pose_json(p: &Isometry3<f64>) -> serde_json::Value {
    let t = p.translation.vector;
    let r = p.rotation;
    serde_json::json!({
        "pos_mm": [t.x, t.y, t.z],
        "quat_wxyz": [r.w, r.i, r.j, r.k],
        "rotation": (0..3).map(|i| (0..3).map(|j| r.to_rotation_matrix()[(i, j)]).collect::<Vec<_>>()).collect::<Vec<_>>(),
    })
}

fn pose_line(name: &str, p: &Isometry3<f64>) -> String {
    let t = p.translation.vector;
    let r = p.rotation;
    let (roll, pitch, yaw) = r.euler_angles();
    format!(
        "{name:<13} pos [{:9.3} {:9.3} {:9.3}] mm   quat(w,x,y,z) [{:8.5} {:8.5} {:8.5} {:8.5}]   rpy [{:8.3} {:8.3} {:8.3}] deg",
        t.x,
        t.y,
        t.z,
        r.w,
        r.i,
        r.j,
        r.k,
        roll.to_degrees(),
        pitch.to_degrees(),
        yaw.to_degrees()
    )
}

fn fk(q: &str, robot_arg: &RobotArg) -> Result<()> {
    let robot = load(robot_arg)?;
    let q = joints(&robot, q)?;
    let fk = robot.fk(&q);
    let frames = [
        ("segment1_end", &fk.segment1_end),
        ("segment2_end", &fk.segment2_end),
        ("pivot", &fk.pivot),
        ("jaw_left", &fk.jaw_left),
        ("jaw_right", &fk.jaw_right),
        ("ee", &fk.ee),
    ];
    if robot_arg.json {
        let mut m = serde_json::Map::new();
        m.insert("q_deg".into(), serde_json::json!(q));
        for (name, p) in frames {
            m.insert(name.into(), pose_json(p));
        }
        println!("{}", serde_json::Value::Object(m));
    } else {
        println!("q = {q:?} deg   (robot {})", robot.config.name);
        for (name, p) in frames {
            println!("{}", pose_line(name, p));
        }
    }
    Ok(())
}

fn ik(pos: &str, quat: &str, opening: f64, q0: Option<&str>, robot_arg: &RobotArg) -> Result<()> {
    let robot = load(robot_arg)?;
    let p: [f64; 3] = parse_list(pos, "--pos")?;
    let qw: [f64; 4] = parse_list(quat, "--quat")?;
    let norm = qw.iter().map(|v| v * v).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > 1e-3 {
        bail!("--quat: {qw:?} is not a unit quaternion (norm {norm:.6})");
    }
    if !opening.is_finite() {
        bail!("--opening: {opening} is not a finite number");
    }
    let q0 = q0.map(|s| parse_list::<4>(s, "--q0")).transpose()?;
    let rot = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(qw[0], qw[1], qw[2], qw[3]));
    let target = Isometry3::from_parts(Translation3::new(p[0], p[1], p[2]), rot);
    let sol = robot.ik(&target, q0, &IkOptions::default()).context("ik")?;
    let [q1, q2, q3, q_yaw] = sol.q_deg;
    let q = [q1, q2, q3, q_yaw - 0.5 * opening, q_yaw + 0.5 * opening];
    robot.check_limits(&q).context("ik solution with --opening")?;
    if robot_arg.json {
        println!(
            "{}",
            serde_json::json!({
                "q_deg": q, "q_yaw_deg": q_yaw, "iterations": sol.iterations,
                "residual_pos_mm": sol.residual_pos_mm, "residual_rot_rad": sol.residual_rot_rad,
            })
        );
    } else {
        for (name, v) in JOINT_NAMES.iter().zip(q) {
            println!("{name} = {v:10.5} deg");
        }
        println!(
            "q_yaw = {q_yaw:.5} deg; {} iterations; residual {:.2e} mm, {:.2e} rad",
            sol.iterations, sol.residual_pos_mm, sol.residual_rot_rad
        );
    }
    Ok(())
}

fn cables(q: Option<&str>, w: Option<&str>, robot_arg: &RobotArg) -> Result<()> {
    let robot = load(robot_arg)?;
    let names = robot.cables().names().clone();
    match (q, w) {
        (Some(q), None) => {
            let q = joints(&robot, q)?;
            let w = robot.cables().displacements_mm(&q);
            if robot_arg.json {
                println!(
                    "{}",
                    serde_json::json!({ "q_deg": q, "cable_disp_mm": w, "cables": names })
                );
            } else {
                println!("cable displacements for q = {q:?} deg (mm, + = pulled in):");
                for (n, v) in names.iter().zip(w) {
                    println!("  {n:<4} {v:+10.5}");
                }
            }
        }
        (None, Some(w)) => {
            let w: [f64; N_CABLES] = parse_list(w, "--w")?;
            let q = robot.cables().joints_from_displacements(&w).context("--w")?;
            if robot_arg.json {
                println!("{}", serde_json::json!({ "cable_disp_mm": w, "q_deg": q }));
            } else {
                for j in 0..N_JOINTS {
                    println!("{} = {:10.5} deg", JOINT_NAMES[j], q[j]);
                }
            }
        }
        _ => bail!("give either --q (joint angles) or --w (cable displacements)"),
    }
    Ok(())
}
