//! Unseen task-space trajectories (paper §V, Fig. 12): random, circle and zigzag paths of the
//! end-effector, described in `configs/trajectories/*.toml`, turned into joint space by
//! inverse kinematics and sampled at the model's step.
//!
//! The manipulator has 4 DOF for the end-effector pose (q1, q2, q3, q_yaw), so an arbitrary
//! 6-D pose path is not reachable: a path is a sequence of tip *positions*; position IK
//! (`Robot::ik_position`) with q_yaw fixed by a profile, solved point after point from the
//! previous solution, gives a continuous joint path; the jaw opening follows its own profile. The desired pose (for the orientation error of Table V)
//! is then FK of that joint path.
//!
//! Sampling: the models were trained on commands 3·√5 deg apart in joint space (eq. 16), so
//! the joint path is resampled at that arc-length step (docs/architecture.md §4): every sample is one
//! model step, as in the training data.

use bowden_kinematics::ik::IkOptions;
use bowden_kinematics::{JointsDeg, Robot};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Deserialize;
use std::path::{Path, PathBuf};

use crate::dataset::DATASET_STEP_DEG;

/// A profile along the path parameter s ∈ [0, 1]: mean + amplitude·sin(2π·cycles·s).
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    pub mean_deg: f64,
    #[serde(default)]
    pub amplitude_deg: f64,
    #[serde(default)]
    pub cycles: f64,
}

impl Profile {
    pub fn at(&self, s: f64) -> f64 {
        self.mean_deg + self.amplitude_deg * (std::f64::consts::TAU * self.cycles * s).sin()
    }
}

/// The shape of a path.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum Shape {
    /// A circle of `radius_mm` about `center_mm` in the plane normal to `normal`.
    Circle {
        center_mm: [f64; 3],
        radius_mm: f64,
        normal: [f64; 3],
        #[serde(default = "one")]
        laps: f64,
    },
    /// A zigzag: `teeth` straight strokes across `amplitude_mm` (along `across`) while
    /// advancing `length_mm` along `along`, starting at `start_mm`.
    Zigzag {
        start_mm: [f64; 3],
        along: [f64; 3],
        across: [f64; 3],
        length_mm: f64,
        amplitude_mm: f64,
        teeth: u32,
    },
    /// A smooth random path: the tip trace of a joint-space curve through `waypoints` random
    /// configurations drawn with `seed` (a seed stream the dataset never uses), each of q1..q3
    /// uniform in `limit_fraction` × its joint limits.
    Random {
        waypoints: u32,
        seed: u64,
        /// Fraction of the joint limits the waypoints are drawn in, (0, 1]. 0.3 (the default)
        /// keeps the paths of `configs/trajectories/` as they were measured.
        #[serde(default = "default_limit_fraction")]
        limit_fraction: f64,
    },
}

fn one() -> f64 {
    1.0
}

fn default_limit_fraction() -> f64 {
    0.3
}

/// One trajectory file.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrajectorySpec {
    pub name: String,
    /// The `[path]` table.
    #[serde(rename = "path")]
    pub shape: Shape,
    /// Jaw opening q5 − q4 along the path.
    pub jaw_opening: Profile,
    /// Reference for the redundant q_yaw along the path.
    pub q_yaw: Profile,
    /// Spacing of the dense task-space samples before joint-space resampling, mm.
    #[serde(default = "default_dense_step")]
    pub dense_step_mm: f64,
    /// Draw the path on the surface a single C-shaped bend sweeps: each point keeps its
    /// distance r from the manipulator's axis and its axial coordinate becomes the tip's x for a
    /// C-bend reaching r. A continuum manipulator bends, it hardly shortens: off that surface a
    /// point needs an S-shaped bend, with large opposite angles for a fraction of a millimetre.
    #[serde(default)]
    pub on_bend_surface: bool,
}

fn default_dense_step() -> f64 {
    0.25
}

/// A trajectory that could not be built, naming the file and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    #[error("{path}: cannot read: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: malformed trajectory: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
    #[error("{path}: point {index} ({x:.2}, {y:.2}, {z:.2}) mm is not reachable: {reason}")]
    Unreachable {
        path: PathBuf,
        index: usize,
        x: f64,
        y: f64,
        z: f64,
        reason: String,
    },
}

/// A trajectory in joint space, sampled at the model step, with its desired tip positions.
#[derive(Debug, Clone, PartialEq)]
pub struct JointTrajectory {
    pub name: String,
    /// q_desired, degrees, one entry per model step.
    pub q_deg: Vec<JointsDeg>,
}

impl TrajectorySpec {
    pub fn load(path: impl AsRef<Path>) -> Result<Self, TrajectoryError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| TrajectoryError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, TrajectoryError> {
        let spec: TrajectorySpec = toml::from_str(text).map_err(|e| TrajectoryError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().replace('\n', " "),
        })?;
        let bad = |problem: String| TrajectoryError::Invalid {
            path: path.to_path_buf(),
            problem,
        };
        let finite3 = |v: &[f64; 3]| v.iter().all(|x| x.is_finite());
        match &spec.shape {
            Shape::Circle {
                center_mm,
                radius_mm,
                normal,
                laps,
            } => {
                if !finite3(center_mm) || !finite3(normal) || Vector3::from(*normal).norm() < 1e-9 {
                    return Err(bad("circle: center_mm and a non-zero normal are required".into()));
                }
                if !(radius_mm.is_finite() && *radius_mm > 0.0 && laps.is_finite() && *laps > 0.0) {
                    return Err(bad(format!(
                        "circle: radius_mm {radius_mm} and laps {laps} must be positive"
                    )));
                }
            }
            Shape::Zigzag {
                start_mm,
                along,
                across,
                length_mm,
                amplitude_mm,
                teeth,
            } => {
                if !finite3(start_mm) || Vector3::from(*along).norm() < 1e-9 || Vector3::from(*across).norm() < 1e-9 {
                    return Err(bad(
                        "zigzag: start_mm and non-zero along/across directions are required".into(),
                    ));
                }
                if !(*length_mm > 0.0 && *amplitude_mm > 0.0 && *teeth > 0) {
                    return Err(bad("zigzag: length_mm, amplitude_mm and teeth must be positive".into()));
                }
            }
            Shape::Random {
                waypoints,
                limit_fraction,
                ..
            } => {
                if *waypoints < 2 {
                    return Err(bad(format!("random: need at least 2 waypoints, got {waypoints}")));
                }
                if !(limit_fraction.is_finite() && *limit_fraction > 0.0 && *limit_fraction <= 1.0) {
                    return Err(bad(format!(
                        "random: limit_fraction must be in (0, 1], got {limit_fraction}"
                    )));
                }
            }
        }
        if !(spec.dense_step_mm > 0.0 && spec.dense_step_mm.is_finite()) {
            return Err(bad(format!(
                "dense_step_mm must be positive, got {}",
                spec.dense_step_mm
            )));
        }
        for (name, p) in [("jaw_opening", spec.jaw_opening), ("q_yaw", spec.q_yaw)] {
            if ![p.mean_deg, p.amplitude_deg, p.cycles].iter().all(|v| v.is_finite()) {
                return Err(bad(format!("{name}: values must be finite")));
            }
        }
        Ok(spec)
    }

    /// Dense tip positions along the path (s ∈ [0, 1] for each).
    fn dense_positions(&self, robot: &Robot) -> Vec<Point3<f64>> {
        let polyline = match &self.shape {
            Shape::Circle {
                center_mm,
                radius_mm,
                normal,
                laps,
            } => {
                let n = Vector3::from(*normal).normalize();
                // Any unit vector perpendicular to n, then the third axis.
                let seed = if n.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
                let u = n.cross(&seed).normalize();
                let v = n.cross(&u);
                let c = Point3::from(*center_mm);
                let circumference = std::f64::consts::TAU * radius_mm * laps;
                let count = (circumference / self.dense_step_mm).ceil().max(8.0) as usize;
                return (0..=count)
                    .map(|i| {
                        let a = std::f64::consts::TAU * laps * i as f64 / count as f64;
                        c + (u * a.cos() + v * a.sin()) * *radius_mm
                    })
                    .collect();
            }
            Shape::Zigzag {
                start_mm,
                along,
                across,
                length_mm,
                amplitude_mm,
                teeth,
            } => {
                let (a, b) = (Vector3::from(*along).normalize(), Vector3::from(*across).normalize());
                let p0 = Point3::from(*start_mm);
                (0..=*teeth)
                    .map(|i| {
                        let side = if i % 2 == 0 { -0.5 } else { 0.5 };
                        p0 + a * (length_mm * i as f64 / *teeth as f64) + b * (amplitude_mm * side)
                    })
                    .collect::<Vec<_>>()
            }
            Shape::Random {
                waypoints,
                seed,
                limit_fraction,
            } => {
                // The tip trace of a smooth random joint-space curve (q1..q3 through random
                // waypoints inside `limit_fraction` of the limits, smoothstep-blended), with q_yaw from its
                // profile: a task-space path that is reachable by construction (chords between
                // random tip positions leave this curved workspace).
                let mut rng = ChaCha8Rng::seed_from_u64(*seed);
                let lim = &robot.config.limits;
                let wps: Vec<[f64; 3]> = (0..*waypoints)
                    .map(|_| {
                        core::array::from_fn(|j| {
                            rng.random_range(lim.q_min_deg[j] * limit_fraction..=lim.q_max_deg[j] * limit_fraction)
                        })
                    })
                    .collect();
                let tip = |q: &[f64; 3], s: f64| {
                    let y = self.q_yaw.at(s);
                    Point3::from(robot.fk(&[q[0], q[1], q[2], y, y]).ee.translation.vector)
                };
                // Dense enough in joint space that the tip moves well under dense_step_mm per sample.
                let per_segment = 400usize;
                let total = (per_segment * (wps.len() - 1)) as f64;
                let mut out = Vec::with_capacity(per_segment * wps.len());
                for (k, w) in wps.windows(2).enumerate() {
                    for i in 0..per_segment {
                        let t = i as f64 / per_segment as f64;
                        let b = t * t * (3.0 - 2.0 * t);
                        let q: [f64; 3] = core::array::from_fn(|j| w[0][j] + b * (w[1][j] - w[0][j]));
                        out.push(tip(&q, (k * per_segment + i) as f64 / total));
                    }
                }
                out.push(tip(&wps[wps.len() - 1], 1.0));
                return out;
            }
        };
        // Straight segments between the polyline's corners, densely sampled.
        let mut out = vec![polyline[0]];
        for w in polyline.windows(2) {
            let d = w[1] - w[0];
            let n = (d.norm() / self.dense_step_mm).ceil().max(1.0) as usize;
            out.extend((1..=n).map(|i| w[0] + d * (i as f64 / n as f64)));
        }
        out
    }

    /// Joint-space trajectory: position IK along the dense path, then resampled at the
    /// model step: consecutive points 3·√5 deg apart in joint space (straight-line distance, as
    /// eq. 16 spaced the training data and as the compensator's history rule measures).
    pub fn to_joint_space(&self, robot: &Robot, path: &Path) -> Result<JointTrajectory, TrajectoryError> {
        self.to_joint_space_with_step(robot, path, DATASET_STEP_DEG)
    }

    pub fn to_joint_space_with_step(
        &self,
        robot: &Robot,
        path: &Path,
        step_deg: f64,
    ) -> Result<JointTrajectory, TrajectoryError> {
        let mut dense = self.dense_positions(robot);
        if self.on_bend_surface {
            for p in dense.iter_mut() {
                let r = (p.y * p.y + p.z * p.z).sqrt();
                if let Some(x) = bend_surface_x(robot, r) {
                    p.x = x;
                }
            }
        }
        let opts = IkOptions {
            max_iterations: 300,
            // The desired pose is FK of the joint path, so a residual here only moves the path by
            // micrometres; near the straight pose the position system is singular (no shortening).
            tol_pos_mm: 1e-2,
            ..IkOptions::default()
        };
        let last = (dense.len() - 1).max(1) as f64;
        let mut joints: Vec<JointsDeg> = Vec::with_capacity(dense.len());
        for (i, p) in dense.iter().enumerate() {
            let s = i as f64 / last;
            // q_yaw from its profile; start from the previous point (continuity).
            let sol = robot
                .ik_position(p, self.q_yaw.at(s), c_bend_guess(robot, p), &opts)
                .map_err(|e| TrajectoryError::Unreachable {
                    path: path.to_path_buf(),
                    index: i,
                    x: p.x,
                    y: p.y,
                    z: p.z,
                    reason: e.to_string(),
                })?;
            let half = 0.5 * self.jaw_opening.at(s);
            let q = [
                sol.q_deg[0],
                sol.q_deg[1],
                sol.q_deg[2],
                sol.q_deg[3] - half,
                sol.q_deg[3] + half,
            ];
            robot.check_limits(&q).map_err(|e| TrajectoryError::Unreachable {
                path: path.to_path_buf(),
                index: i,
                x: p.x,
                y: p.y,
                z: p.z,
                reason: e.to_string(),
            })?;
            joints.push(q);
        }
        Ok(JointTrajectory {
            name: self.name.clone(),
            q_deg: resample_by_chord(&joints, step_deg),
        })
    }
}

/// The C-shaped bend (segments 1 and 2 bent the same way in proportion to their hinge
/// counts, jaws straight) whose tip is `r_mm` from the axis: its bend θ (q1 for a pure pitch)
/// and the tip's axial coordinate; `None` beyond the bend's reach.
pub fn c_bend(robot: &Robot, r_mm: f64) -> Option<(f64, f64)> {
    let ratio = robot.config.segment2.modules as f64 / robot.config.segment1.modules as f64;
    let tip = |t: f64| robot.fk(&[t, 0.0, t * ratio, 0.0, 0.0]).ee.translation.vector;
    let (mut lo, mut hi) = (0.0, robot.config.limits.q_max_deg[0]);
    if tip(hi).z < r_mm {
        return None;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if tip(mid).z < r_mm {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let t = 0.5 * (lo + hi);
    Some((t, tip(t).x))
}

/// Axial coordinate of the tip when a C-shaped bend puts it `r_mm` from the axis.
pub fn bend_surface_x(robot: &Robot, r_mm: f64) -> Option<f64> {
    c_bend(robot, r_mm).map(|(_, x)| x)
}

/// IK start for a tip position: the C-bend toward it (pitch toward +z, yaw toward +y), so
/// every point is solved on the same, least-bent branch of the 3×3 position system.
fn c_bend_guess(robot: &Robot, p: &Point3<f64>) -> [f64; 3] {
    let r = (p.y * p.y + p.z * p.z).sqrt();
    let ratio = robot.config.segment2.modules as f64 / robot.config.segment1.modules as f64;
    match c_bend(robot, r) {
        Some((t, _)) if r > 1e-9 => {
            let (c, s) = (p.z / r, p.y / r);
            [t * c, t * s, t * c * ratio]
        }
        _ => [0.0; 3],
    }
}

/// Points every `step_deg` of joint-space arc length along a polyline (first point kept;
/// the last point is added if the remainder is over half a step).
pub fn resample_by_arc_length(q: &[JointsDeg], step_deg: f64) -> Vec<JointsDeg> {
    let Some(first) = q.first() else { return Vec::new() };
    let mut out = vec![*first];
    let mut next_at = step_deg;
    let mut travelled = 0.0;
    for w in q.windows(2) {
        let d: f64 = w[0]
            .iter()
            .zip(&w[1])
            .map(|(a, b)| (b - a) * (b - a))
            .sum::<f64>()
            .sqrt();
        while d > 0.0 && travelled + d >= next_at {
            let t = (next_at - travelled) / d;
            out.push(core::array::from_fn(|j| w[0][j] + t * (w[1][j] - w[0][j])));
            next_at += step_deg;
        }
        travelled += d;
    }
    if travelled - (next_at - step_deg) > 0.5 * step_deg {
        if let Some(last) = q.last() {
            out.push(*last);
        }
    }
    out
}

/// Points exactly `step_deg` apart in straight-line joint-space distance along a polyline
/// (first point kept; the last point is added if it is over half a step from the previous one).
///
/// Arc-length spacing on a curved path puts consecutive points closer than `step_deg` (the
/// chord is shorter than the arc): the compensator's `distance` history rule would then skip
/// some of them, and its history would not be the sequence of held commands the plant saw.
pub fn resample_by_chord(q: &[JointsDeg], step_deg: f64) -> Vec<JointsDeg> {
    let Some(first) = q.first() else { return Vec::new() };
    let dist = |a: &JointsDeg, b: &JointsDeg| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt();
    let mut out = vec![*first];
    for w in q.windows(2) {
        // Every crossing of the sphere of radius `step_deg` around the last output point on
        // this polyline segment: solve |a + t(b − a) − c| = step for the largest t in [0, 1].
        loop {
            let c = *out.last().unwrap_or(first);
            let (a, b) = (&w[0], &w[1]);
            if dist(&c, b) < step_deg {
                break;
            }
            let (mut aa, mut bb, mut cc) = (0.0, 0.0, -step_deg * step_deg);
            for j in 0..a.len() {
                let d = b[j] - a[j];
                let e = a[j] - c[j];
                aa += d * d;
                bb += 2.0 * d * e;
                cc += e * e;
            }
            if aa == 0.0 {
                break;
            }
            let disc = (bb * bb - 4.0 * aa * cc).max(0.0);
            let t = ((-bb + disc.sqrt()) / (2.0 * aa)).clamp(0.0, 1.0);
            out.push(core::array::from_fn(|j| a[j] + t * (b[j] - a[j])));
        }
    }
    if let (Some(last), Some(prev)) = (q.last(), out.last()) {
        if dist(prev, last) > 0.5 * step_deg {
            out.push(*last);
        }
    }
    out
}

/// Loads every `*.toml` trajectory of a directory whose name is in `names` (all if empty),
/// in the order of `names`.
pub fn load_named(dir: &Path, names: &[String]) -> Result<Vec<(PathBuf, TrajectorySpec)>, TrajectoryError> {
    let mut out = Vec::new();
    for n in names {
        let p = dir.join(format!("{n}.toml"));
        out.push((p.clone(), TrajectorySpec::load(&p)?));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_spaces_points_one_step_apart() {
        let q: Vec<JointsDeg> = (0..=100).map(|i| [i as f64 * 0.5, 0.0, 0.0, 0.0, 0.0]).collect();
        let r = resample_by_arc_length(&q, 3.0);
        assert_eq!(r.len(), 17 + 1); // 0, 3, …, 48 and the end 50 (2 deg remainder > 1.5)
        for w in r.windows(2).take(16) {
            assert!((w[1][0] - w[0][0] - 3.0).abs() < 1e-12);
        }
    }

    #[test]
    fn chord_resampling_puts_points_exactly_one_step_apart_on_a_curve() {
        // A circle of radius 20 deg in (q1, q2): arc-length spacing gives shorter chords.
        let q: Vec<JointsDeg> = (0..=720)
            .map(|i| {
                let a = i as f64 * std::f64::consts::PI / 360.0;
                [20.0 * a.cos(), 20.0 * a.sin(), 0.0, 0.0, 0.0]
            })
            .collect();
        let step = DATASET_STEP_DEG;
        let r = resample_by_chord(&q, step);
        let d = |w: &[JointsDeg]| {
            w[0].iter()
                .zip(&w[1])
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt()
        };
        for w in r.windows(2).take(r.len() - 2) {
            assert!((d(w) - step).abs() < 1e-9, "chord {}", d(w));
        }
        let arc = resample_by_arc_length(&q, step);
        assert!(
            d(&arc[0..2]) < step - 0.01,
            "arc spacing makes shorter chords on a curve"
        );
        // Circumference 125.7 deg: about 19 chords of 6.7 deg.
        assert!((18..=21).contains(&r.len()), "{} points", r.len());
    }

    #[test]
    fn shipped_trajectories_convert_and_stay_in_limits() {
        let robot = Robot::paper_default();
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/trajectories");
        for name in ["random", "circle", "zigzag"] {
            let p = dir.join(format!("{name}.toml"));
            let spec = TrajectorySpec::load(&p).unwrap();
            let t = spec.to_joint_space(&robot, &p).unwrap_or_else(|e| panic!("{e}"));
            assert!(t.q_deg.len() > 20, "{name}: {} points", t.q_deg.len());
            for w in t.q_deg.windows(2) {
                let d: f64 = w[0]
                    .iter()
                    .zip(&w[1])
                    .map(|(a, b)| (b - a) * (b - a))
                    .sum::<f64>()
                    .sqrt();
                assert!(d <= DATASET_STEP_DEG + 1e-6, "{name}: step {d}");
            }
            // Inside 80 % of the default plant's physical reach (`bowden plant characterize`:
            // q1/q2 ±31°, q3 ±17°, jaws ±21° for commands inside the limits): a desired path
            // the robot cannot physically reach would measure the plant, not the controller.
            let reach = [31.0, 31.0, 17.0, 21.0, 21.0];
            for q in &t.q_deg {
                robot.check_limits(q).unwrap();
                for j in 0..5 {
                    assert!(
                        q[j].abs() <= 0.8 * reach[j],
                        "{name}: q{} = {:.1} beyond reach",
                        j + 1,
                        q[j]
                    );
                }
            }
        }
    }

    #[test]
    fn bad_trajectory_files_name_the_problem() {
        let p = Path::new("bad.toml");
        let e = TrajectorySpec::parse("name = \"x\"\n[path]\nkind = \"square\"", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.toml") && e.contains("malformed"), "{e}");
        let text = "name='c'\njaw_opening={mean_deg=10}\nq_yaw={mean_deg=0}\n\
                    [path]\nkind='circle'\ncenter_mm=[40,0,0]\nradius_mm=-1\nnormal=[1,0,0]";
        let e = TrajectorySpec::parse(text, p).unwrap_err().to_string();
        assert!(e.contains("radius_mm"), "{e}");
        let text = "name='c'\njaw_opening={mean_deg=10}\nq_yaw={mean_deg=0}\n\
                    [path]\nkind='circle'\ncenter_mm=[400,0,0]\nradius_mm=5\nnormal=[1,0,0]";
        let spec = TrajectorySpec::parse(text, p).unwrap();
        let e = spec.to_joint_space(&Robot::paper_default(), p).unwrap_err().to_string();
        assert!(e.contains("not reachable"), "{e}");
    }

    #[test]
    fn random_limit_fraction_scales_the_path_and_defaults_to_the_measured_paths() {
        let robot = Robot::paper_default();
        let p = Path::new("r.toml");
        let file = |extra: &str| {
            format!(
                "name='r'\njaw_opening={{mean_deg=10}}\nq_yaw={{mean_deg=0}}\n\
                 [path]\nkind='random'\nwaypoints=5\nseed=7\n{extra}"
            )
        };
        let span = |t: &JointTrajectory| {
            (0..3)
                .map(|j| {
                    let (lo, hi) = t
                        .q_deg
                        .iter()
                        .fold((f64::MAX, f64::MIN), |(lo, hi), q| (lo.min(q[j]), hi.max(q[j])));
                    hi - lo
                })
                .sum::<f64>()
        };
        let default = TrajectorySpec::parse(&file(""), p).unwrap();
        let explicit = TrajectorySpec::parse(&file("limit_fraction=0.3"), p).unwrap();
        assert_eq!(
            default, explicit,
            "the default must stay the fraction the shipped paths were measured with"
        );
        let small = explicit.to_joint_space(&robot, p).unwrap();
        let large = TrajectorySpec::parse(&file("limit_fraction=0.5"), p)
            .unwrap()
            .to_joint_space(&robot, p)
            .unwrap();
        assert!(
            span(&large) > 1.3 * span(&small),
            "{} vs {}",
            span(&large),
            span(&small)
        );
        for bad in ["limit_fraction=0", "limit_fraction=1.5", "limit_fraction=nan"] {
            let e = TrajectorySpec::parse(&file(bad), p).unwrap_err().to_string();
            assert!(e.contains("limit_fraction"), "{bad}: {e}");
        }
    }
}
