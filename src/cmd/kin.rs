//! `bowden fk`, `bowden ik`, `bowden cables`: the manipulator model from the command line.

use anyhow::{anyhow, bail, Context, Result};
use bowden_kinematics::ik::{pose_error, IkOptions};
use bowden_kinematics::{IkError, JointsDeg, Robot, JOINT_NAMES, N_CABLES, N_JOINTS};
use clap::{Args, Subcommand};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::path::PathBuf;

#[derive(Args)]
pub struct RobotArg {
    /// Robot description (Table I/II geometry, limits, cable routing); found as given, under
    /// $BOWDEN_HOME, or built in (`bowden shipped`).
    #[arg(long, default_value = "configs/robot.toml")]
    pub config: PathBuf,
    /// Print JSON on stdout instead of the text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Subcommand)]
pub enum Command {
    /// Forward kinematics (eq. 1–3): joint angles → end-effector, jaw and segment frames.
    ///
    /// Positions are printed to 1e-6 mm and quaternions to 1e-9, so a printed pose pasted into
    /// `bowden ik` round-trips; the last line is that `ik` command for the end-effector.
    Fk {
        /// Joint angles q1,q2,q3,q4,q5 in degrees.
        #[arg(long, value_name = "Q1,Q2,Q3,Q4,Q5", allow_hyphen_values = true)]
        q: String,
        #[command(flatten)]
        robot: RobotArg,
    },
    /// Inverse kinematics (eq. 4): end-effector pose → (q1, q2, q3, q_yaw) by damped Newton–Raphson.
    ///
    /// The 6-D pose is matched with 4 joints, so a pose typed or pasted with rounded digits is
    /// reachable only approximately: the answer is accepted when its pose is within --tol-mm and
    /// --tol-deg of the target. Otherwise the best configuration found is printed, labelled NOT
    /// converged, with its residual, and the command fails (non-zero exit).
    Ik {
        /// End-effector position x,y,z in the base frame, mm.
        #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
        pos: String,
        /// End-effector orientation as a quaternion w,x,y,z (base frame). A norm within 5 % of 1
        /// is normalised (with a note on stderr when it is off by more than 1e-6); anything
        /// else is refused.
        #[arg(long, value_name = "W,X,Y,Z", allow_hyphen_values = true)]
        quat: String,
        /// Jaw opening θ = q5 − q4 in degrees, to report q4 = q_yaw − θ/2 and q5 = q_yaw + θ/2.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        opening: f64,
        /// Starting configuration q1,q2,q3,q_yaw in degrees (the paper starts from the command).
        #[arg(long, value_name = "Q1,Q2,Q3,QYAW", allow_hyphen_values = true)]
        q0: Option<String>,
        /// Largest accepted position residual of the solution's pose, mm.
        #[arg(long, default_value_t = DEFAULT_TOL_MM)]
        tol_mm: f64,
        /// Largest accepted orientation residual of the solution's pose, deg.
        #[arg(long, default_value_t = DEFAULT_TOL_DEG)]
        tol_deg: f64,
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

/// `ik`'s default acceptance: 1 µm and 0.001°, far below what the robot can resolve and far
/// above the residual of a pose printed by `fk` (≈ 1e-6 mm, 1e-7°).
const DEFAULT_TOL_MM: f64 = 1e-3;
const DEFAULT_TOL_DEG: f64 = 1e-3;
/// `--quat` norms further than this from 1 are refused; within it, normalised.
const QUAT_NORM_REFUSE: f64 = 0.05;
/// `--quat` norms further than this from 1 are normalised with a note (closer: rounding).
const QUAT_NORM_NOTE: f64 = 1e-6;

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Fk { q, robot } => fk(&q, &robot),
        Command::Ik {
            pos,
            quat,
            opening,
            q0,
            tol_mm,
            tol_deg,
            robot,
        } => ik(
            &pos,
            &quat,
            opening,
            q0.as_deref(),
            Tolerance {
                mm: tol_mm,
                deg: tol_deg,
            },
            &robot,
        ),
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
    Ok(Robot::load(crate::home::path(&robot.config)?)?)
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
        "{name:<13} pos [{:12.6} {:12.6} {:12.6}] mm   quat(w,x,y,z) [{:12.9} {:12.9} {:12.9} {:12.9}]   rpy [{:8.3} {:8.3} {:8.3}] deg",
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
        let t = fk.ee.translation.vector;
        let r = fk.ee.rotation;
        println!(
            "back through ik: bowden ik --pos {:.6},{:.6},{:.6} --quat {:.9},{:.9},{:.9},{:.9} --opening {}",
            t.x,
            t.y,
            t.z,
            r.w,
            r.i,
            r.j,
            r.k,
            q[4] - q[3]
        );
    }
    Ok(())
}

/// `ik`'s acceptance of a solution: its pose's residual to the target.
#[derive(Debug, Clone, Copy)]
struct Tolerance {
    mm: f64,
    deg: f64,
}

/// `--quat` as a unit quaternion: normalised when its norm is within 5 % of 1 (a note on
/// stderr names the norm), refused otherwise. Returns the quaternion and the norm given.
fn unit_quaternion(qw: [f64; 4]) -> Result<(UnitQuaternion<f64>, f64)> {
    let norm = qw.iter().map(|v| v * v).sum::<f64>().sqrt();
    if norm == 0.0 {
        bail!("--quat: {qw:?} is the zero quaternion, not an orientation");
    }
    if (norm - 1.0).abs() > QUAT_NORM_REFUSE {
        bail!(
            "--quat: {qw:?} is not a unit quaternion (norm {norm:.6}, more than {:.0} % from 1)",
            QUAT_NORM_REFUSE * 100.0
        );
    }
    if (norm - 1.0).abs() > QUAT_NORM_NOTE {
        eprintln!(
            "note: --quat {qw:?} has norm {norm:.6}; normalised to [{:.9}, {:.9}, {:.9}, {:.9}]",
            qw[0] / norm,
            qw[1] / norm,
            qw[2] / norm,
            qw[3] / norm
        );
    }
    let q = nalgebra::Quaternion::new(qw[0], qw[1], qw[2], qw[3]);
    Ok((UnitQuaternion::from_quaternion(q), norm))
}

/// Residual of (q1, q2, q3, q_yaw)'s end-effector pose to `target`: mm and deg.
fn residual(robot: &Robot, target: &Isometry3<f64>, q4: &[f64; 4]) -> (f64, f64) {
    let (dp, dr) = pose_error(target, &robot.ee_pose_reduced(q4));
    (dp.norm(), dr.norm().to_degrees())
}

fn ik(pos: &str, quat: &str, opening: f64, q0: Option<&str>, tol: Tolerance, robot_arg: &RobotArg) -> Result<()> {
    let robot = load(robot_arg)?;
    let p: [f64; 3] = parse_list(pos, "--pos")?;
    let qw: [f64; 4] = parse_list(quat, "--quat")?;
    if !opening.is_finite() {
        bail!("--opening: {opening} is not a finite number");
    }
    for (v, name) in [(tol.mm, "--tol-mm"), (tol.deg, "--tol-deg")] {
        if !(v.is_finite() && v > 0.0) {
            bail!("{name}: {v} is not a positive number");
        }
    }
    let (rot, quat_norm) = unit_quaternion(qw)?;
    let q0 = q0.map(|s| parse_list::<4>(s, "--q0")).transpose()?;
    let target = Isometry3::from_parts(Translation3::new(p[0], p[1], p[2]), rot);
    let within = |r: (f64, f64)| r.0 <= tol.mm && r.1 <= tol.deg;

    // The solver's own tolerances are tight (1e-9 mm): an exactly reachable pose is solved to
    // machine precision. A pose given with rounded digits is reachable only approximately; the
    // solver then ends at the least-squares configuration, accepted when within `tol`. If its
    // best start ended elsewhere, a run with `tol` as the solver's tolerance tries every start.
    let tight = IkOptions::default();
    let relaxed = IkOptions {
        tol_pos_mm: tol.mm,
        tol_rot_rad: tol.deg.to_radians(),
        ..tight
    };
    let (q4, iterations, converged) = match robot.ik(&target, q0, &tight) {
        Ok(sol) => (sol.q_deg, sol.iterations, true),
        Err(IkError::NotConverged {
            iterations, best_q_deg, ..
        }) if within(residual(&robot, &target, &best_q_deg)) => (best_q_deg, iterations, true),
        Err(IkError::NotConverged {
            iterations, best_q_deg, ..
        }) => match robot.ik(&target, q0, &relaxed) {
            Ok(sol) => (sol.q_deg, iterations + sol.iterations, true),
            Err(IkError::NotConverged { .. }) => (best_q_deg, iterations, false),
            Err(e) => return Err(e).context("ik"),
        },
        Err(e) => return Err(e).context("ik"),
    };
    let (res_mm, res_deg) = residual(&robot, &target, &q4);
    let [q1, q2, q3, q_yaw] = q4;
    let q = [q1, q2, q3, q_yaw - 0.5 * opening, q_yaw + 0.5 * opening];
    // A converged answer must be a valid configuration; the best of a failed solve is shown
    // as it is, with what is wrong with it.
    let limits = robot.check_limits(&q).err().map(|e| e.to_string());
    if let (true, Some(e)) = (converged, &limits) {
        bail!("ik solution with --opening: {e}");
    }
    if robot_arg.json {
        println!(
            "{}",
            serde_json::json!({
                "converged": converged,
                "q_deg": q, "q_yaw_deg": q_yaw, "iterations": iterations,
                "residual_pos_mm": res_mm, "residual_rot_deg": res_deg,
                "residual_rot_rad": res_deg.to_radians(),
                "tol_pos_mm": tol.mm, "tol_rot_deg": tol.deg,
                "within_limits": limits.is_none(),
                "quat_norm": quat_norm,
                "target": pose_json(&target),
            })
        );
    } else {
        if !converged {
            println!("NOT CONVERGED: the best configuration found, which does NOT reach the pose:");
        }
        for (name, v) in JOINT_NAMES.iter().zip(q) {
            println!("{name} = {v:12.6} deg");
        }
        println!("q_yaw = {q_yaw:.6} deg");
        println!(
            "{}: residual {res_mm:.3e} mm, {res_deg:.3e} deg (tolerance {:e} mm, {:e} deg); {iterations} solver iterations",
            if converged { "converged" } else { "NOT CONVERGED" },
            tol.mm,
            tol.deg,
        );
        if let Some(e) = &limits {
            println!("outside the robot's limits: {e}");
        }
    }
    if !converged {
        return Err(anyhow!(
            "did not converge (unreachable pose?): the best configuration found (printed, NOT a solution) \
             misses the target by {res_mm:.3e} mm and {res_deg:.3e} deg, above --tol-mm {} / --tol-deg {}",
            tol.mm,
            tol.deg
        ))
        .context("ik");
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
