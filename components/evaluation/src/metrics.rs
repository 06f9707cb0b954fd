//! The paper's tracking metrics: Table V (task space: X, Y, Z mean absolute error, total
//! position error mean ± SD, orientation error mean ± SD) and Table VI (per-joint error and SD).

use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::Serialize;

/// Mean and population standard deviation of a sample (0, 0 for an empty one).
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// One row of Table V for one (trajectory, controller).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct TaskErrors {
    pub n: usize,
    pub x_mae_mm: f64,
    pub y_mae_mm: f64,
    pub z_mae_mm: f64,
    pub pos_mean_mm: f64,
    pub pos_sd_mm: f64,
    pub rot_mean_deg: f64,
    pub rot_sd_deg: f64,
}

/// Table VI for one (trajectory, controller): per-joint mean absolute error and SD of it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct JointErrors {
    pub n: usize,
    pub mae_deg: [f64; N_JOINTS],
    pub sd_deg: [f64; N_JOINTS],
}

/// Position (mm) and orientation (deg) distances between a desired and a reached pose.
pub fn pose_distance(desired: &Isometry3<f64>, reached: &Isometry3<f64>) -> (Vector3<f64>, f64, f64) {
    let d = reached.translation.vector - desired.translation.vector;
    let (pos, rot) = bowden_kinematics::pose_distance(desired, reached);
    (d, pos, rot)
}

/// Table V from pairs (desired pose, reached pose).
pub fn task_errors(pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> TaskErrors {
    let mut ax = Vec::with_capacity(pairs.len());
    let mut ay = Vec::with_capacity(pairs.len());
    let mut az = Vec::with_capacity(pairs.len());
    let mut pos = Vec::with_capacity(pairs.len());
    let mut rot = Vec::with_capacity(pairs.len());
    for (des, got) in pairs {
        let (d, p, r) = pose_distance(des, got);
        ax.push(d.x.abs());
        ay.push(d.y.abs());
        az.push(d.z.abs());
        pos.push(p);
        rot.push(r);
    }
    let (pos_mean_mm, pos_sd_mm) = mean_sd(&pos);
    let (rot_mean_deg, rot_sd_deg) = mean_sd(&rot);
    TaskErrors {
        n: pairs.len(),
        x_mae_mm: mean_sd(&ax).0,
        y_mae_mm: mean_sd(&ay).0,
        z_mae_mm: mean_sd(&az).0,
        pos_mean_mm,
        pos_sd_mm,
        rot_mean_deg,
        rot_sd_deg,
    }
}

/// Table VI from pairs (desired joints, reached joints).
pub fn joint_errors(pairs: &[(JointsDeg, JointsDeg)]) -> JointErrors {
    let mut out = JointErrors {
        n: pairs.len(),
        ..Default::default()
    };
    for j in 0..N_JOINTS {
        let e: Vec<f64> = pairs.iter().map(|(d, g)| (g[j] - d[j]).abs()).collect();
        let (m, s) = mean_sd(&e);
        out.mae_deg[j] = m;
        out.sd_deg[j] = s;
    }
    out
}

/// End-effector pose of a joint configuration.
pub fn ee_pose(robot: &Robot, q: &JointsDeg) -> Isometry3<f64> {
    robot.fk(q).ee
}

/// Pose from the estimator's end-effector fields (position mm, quaternion w, x, y, z).
pub fn pose_from_estimate(pos_mm: &[f64; 3], quat_wxyz: &[f64; 4]) -> Option<Isometry3<f64>> {
    if pos_mm.iter().chain(quat_wxyz).any(|v| !v.is_finite()) {
        return None;
    }
    let q = nalgebra::Quaternion::new(quat_wxyz[0], quat_wxyz[1], quat_wxyz[2], quat_wxyz[3]);
    if (q.norm() - 1.0).abs() > 1e-3 {
        return None;
    }
    Some(Isometry3::from_parts(
        nalgebra::Translation3::new(pos_mm[0], pos_mm[1], pos_mm[2]),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// Reduction of `after` relative to `before`, percent (positive = better).
pub fn reduction_pct(before: f64, after: f64) -> f64 {
    if before.abs() < 1e-12 {
        0.0
    } else {
        100.0 * (before - after) / before
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Translation3;

    #[test]
    fn table_v_by_hand() {
        let id = Isometry3::identity();
        let a = Isometry3::from_parts(Translation3::new(3.0, 0.0, 4.0), UnitQuaternion::identity());
        let b = Isometry3::from_parts(
            Translation3::new(0.0, -1.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 10f64.to_radians()),
        );
        let t = task_errors(&[(id, a), (id, b)]);
        assert_eq!(t.n, 2);
        assert!(
            (t.x_mae_mm - 1.5).abs() < 1e-12 && (t.y_mae_mm - 0.5).abs() < 1e-12 && (t.z_mae_mm - 2.0).abs() < 1e-12
        );
        assert!((t.pos_mean_mm - 3.0).abs() < 1e-12 && (t.pos_sd_mm - 2.0).abs() < 1e-12);
        assert!((t.rot_mean_deg - 5.0).abs() < 1e-9 && (t.rot_sd_deg - 5.0).abs() < 1e-9);
    }

    #[test]
    fn table_vi_by_hand() {
        let z = [0.0; N_JOINTS];
        let j = joint_errors(&[(z, [1.0, -2.0, 0.0, 0.0, 4.0]), (z, [3.0, 2.0, 0.0, 0.0, -4.0])]);
        assert_eq!(j.mae_deg, [2.0, 2.0, 0.0, 0.0, 4.0]);
        assert_eq!(j.sd_deg, [1.0, 0.0, 0.0, 0.0, 0.0]);
        assert!((reduction_pct(13.7, 5.29) - 61.386).abs() < 1e-3);
        assert!(pose_from_estimate(&[0.0; 3], &[2.0, 0.0, 0.0, 0.0]).is_none());
        assert!(pose_from_estimate(&[f64::NAN, 0.0, 0.0], &[1.0, 0.0, 0.0, 0.0]).is_none());
    }
}
