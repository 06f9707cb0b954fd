//! Eq. (4): Newton–Raphson inverse kinematics on (q1, q2, q3, q_yaw), damped
//! (Levenberg–Marquardt) because the 6-D pose is matched with 4 unknowns.

use nalgebra::{Isometry3, Matrix4, Vector4, Vector6};

use crate::Robot;

/// Settings of the solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkOptions {
    pub max_iterations: u32,
    /// Converged when the position error is below this, mm …
    pub tol_pos_mm: f64,
    /// … and the orientation error below this, rad.
    pub tol_rot_rad: f64,
    /// Weight of orientation against position in the least squares, mm per rad.
    pub rot_weight_mm_per_rad: f64,
    /// Refuse solutions further than this outside the joint limits (deg); `None` = no check.
    pub limit_margin_deg: Option<f64>,
}

impl Default for IkOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            tol_pos_mm: 1e-9,
            tol_rot_rad: 1e-10,
            rot_weight_mm_per_rad: 20.0,
            limit_margin_deg: Some(0.0),
        }
    }
}

/// A converged solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkSolution {
    /// (q1, q2, q3, q_yaw) in degrees.
    pub q_deg: [f64; 4],
    pub iterations: u32,
    pub residual_pos_mm: f64,
    pub residual_rot_rad: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IkError {
    #[error("IK did not converge (unreachable pose?): after {iterations} iterations the error is {residual_pos_mm:.3e} mm, {residual_rot_deg:.3e} deg")]
    NotConverged {
        iterations: u32,
        residual_pos_mm: f64,
        residual_rot_deg: f64,
        /// The best configuration found, for diagnostics only.
        best_q_deg: [f64; 4],
    },
    #[error("IK solution q{joint} = {value_deg:.2} deg lies outside the joint limits (unreachable pose)")]
    OutsideLimits {
        joint: usize,
        value_deg: f64,
        q_deg: [f64; 4],
    },
    #[error("IK input is not finite")]
    NotFinite,
}

/// Pose error target − current: position (mm) and rotation vector (rad), base frame.
pub fn pose_error(
    target: &Isometry3<f64>,
    current: &Isometry3<f64>,
) -> (nalgebra::Vector3<f64>, nalgebra::Vector3<f64>) {
    let dp = target.translation.vector - current.translation.vector;
    let dr = (target.rotation * current.rotation.inverse()).scaled_axis();
    (dp, dr)
}

impl Robot {
    /// Solves for (q1, q2, q3, q_yaw) whose end-effector pose is `target`, starting from
    /// `q0_deg` (the paper starts from the command; zeros when `None`). Restarts from a few
    /// fixed seeds if the first start does not converge, so the answer is deterministic.
    pub fn ik(
        &self,
        target: &Isometry3<f64>,
        q0_deg: Option<[f64; 4]>,
        opts: &IkOptions,
    ) -> Result<IkSolution, IkError> {
        let finite = target.translation.vector.iter().all(|v| v.is_finite())
            && target.rotation.coords.iter().all(|v| v.is_finite());
        if !finite || q0_deg.is_some_and(|q| q.iter().any(|v| !v.is_finite())) {
            return Err(IkError::NotFinite);
        }
        let seeds: [[f64; 4]; 5] = [
            q0_deg.unwrap_or([0.0; 4]),
            [0.0; 4],
            [30.0, 30.0, 20.0, 0.0],
            [-30.0, -30.0, -20.0, 0.0],
            [30.0, -30.0, -20.0, 0.0],
        ];
        let mut best: Option<IkError> = None;
        let mut total_iterations = 0;
        for seed in seeds.iter() {
            match self.ik_from(target, *seed, opts) {
                Ok(mut sol) => {
                    sol.iterations += total_iterations;
                    return self.check_ik_limits(sol, opts);
                }
                Err(e) => {
                    if let IkError::NotConverged { iterations, .. } = e {
                        total_iterations += iterations;
                    }
                    let better = match (&best, &e) {
                        (
                            Some(IkError::NotConverged { residual_pos_mm: a, .. }),
                            IkError::NotConverged { residual_pos_mm: b, .. },
                        ) => b < a,
                        _ => true,
                    };
                    if better {
                        best = Some(e);
                    }
                }
            }
        }
        match best {
            Some(IkError::NotConverged {
                residual_pos_mm,
                residual_rot_deg,
                best_q_deg,
                ..
            }) => Err(IkError::NotConverged {
                iterations: total_iterations,
                residual_pos_mm,
                residual_rot_deg,
                best_q_deg,
            }),
            Some(e) => Err(e),
            None => Err(IkError::NotFinite),
        }
    }

    fn check_ik_limits(&self, sol: IkSolution, opts: &IkOptions) -> Result<IkSolution, IkError> {
        if let Some(margin) = opts.limit_margin_deg {
            let lim = &self.config.limits;
            // q_yaw is bounded by the jaw limits.
            let lo = [
                lim.q_min_deg[0],
                lim.q_min_deg[1],
                lim.q_min_deg[2],
                lim.q_min_deg[3].max(lim.q_min_deg[4]),
            ];
            let hi = [
                lim.q_max_deg[0],
                lim.q_max_deg[1],
                lim.q_max_deg[2],
                lim.q_max_deg[3].min(lim.q_max_deg[4]),
            ];
            for j in 0..4 {
                if sol.q_deg[j] < lo[j] - margin || sol.q_deg[j] > hi[j] + margin {
                    return Err(IkError::OutsideLimits {
                        joint: if j == 3 { 4 } else { j + 1 },
                        value_deg: sol.q_deg[j],
                        q_deg: sol.q_deg,
                    });
                }
            }
        }
        Ok(sol)
    }

    fn ik_from(&self, target: &Isometry3<f64>, q0_deg: [f64; 4], opts: &IkOptions) -> Result<IkSolution, IkError> {
        let w = opts.rot_weight_mm_per_rad;
        let mut q = Vector4::from_iterator(q0_deg.iter().map(|v| v.to_radians()));
        let deg = |q: &Vector4<f64>| {
            [
                q[0].to_degrees(),
                q[1].to_degrees(),
                q[2].to_degrees(),
                q[3].to_degrees(),
            ]
        };
        let eval = |q: &Vector4<f64>| {
            let (pose, jac) = self.ee_jacobian(&deg(q));
            let (dp, dr) = pose_error(target, &pose);
            let mut e = Vector6::zeros();
            e.fixed_rows_mut::<3>(0).copy_from(&dp);
            e.fixed_rows_mut::<3>(3).copy_from(&(dr * w));
            let mut jw = jac;
            for c in 0..4 {
                for r in 3..6 {
                    jw[(r, c)] *= w;
                }
            }
            (e, jw, dp.norm(), dr.norm())
        };
        let (mut e, mut jac, mut ep, mut er) = eval(&q);
        let mut lambda = 1e-3;
        for it in 0..opts.max_iterations {
            if ep < opts.tol_pos_mm && er < opts.tol_rot_rad {
                return Ok(IkSolution {
                    q_deg: deg(&q),
                    iterations: it,
                    residual_pos_mm: ep,
                    residual_rot_rad: er,
                });
            }
            let jtj = jac.transpose() * jac;
            let jte = jac.transpose() * e;
            let cost = e.norm_squared();
            // Levenberg–Marquardt: grow the damping until the step lowers the error.
            let mut accepted = false;
            for _ in 0..12 {
                let damped = jtj + Matrix4::from_diagonal(&jtj.diagonal().map(|d| lambda * (d + 1e-9)));
                let Some(step) = damped.lu().solve(&jte) else {
                    lambda *= 10.0;
                    continue;
                };
                let q_new = q + step;
                let (e2, j2, ep2, er2) = eval(&q_new);
                if e2.norm_squared() < cost {
                    q = q_new;
                    (e, jac, ep, er) = (e2, j2, ep2, er2);
                    lambda = (lambda * 0.3).max(1e-12);
                    accepted = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !accepted {
                // No step lowers the error: a local minimum away from the target.
                break;
            }
        }
        if ep < opts.tol_pos_mm && er < opts.tol_rot_rad {
            return Ok(IkSolution {
                q_deg: deg(&q),
                iterations: opts.max_iterations,
                residual_pos_mm: ep,
                residual_rot_rad: er,
            });
        }
        Err(IkError::NotConverged {
            iterations: opts.max_iterations,
            residual_pos_mm: ep,
            residual_rot_deg: er.to_degrees(),
            best_q_deg: deg(&q),
        })
    }
}

/// A solution of [`Robot::ik_position`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkPositionSolution {
    /// (q1, q2, q3, q_yaw) in degrees.
    pub q_deg: [f64; 4],
    pub iterations: u32,
    pub residual_pos_mm: f64,
}

impl Robot {
    /// Position-only inverse kinematics with a given jaw direction: (q1, q2, q3) whose
    /// end-effector reaches `target_mm` with q_yaw fixed at `q_yaw_deg`, by damped Newton on
    /// the square 3×3 position system, starting from `q_start_deg`. The manipulator has 4 DOF
    /// for the tip (q1, q2, q3, q_yaw), so a tip path alone leaves one free; fixing q_yaw along
    /// the path (a profile) and starting each point from the previous solution gives a
    /// continuous joint path. Refuses solutions outside the limits.
    pub fn ik_position(
        &self,
        target_mm: &nalgebra::Point3<f64>,
        q_yaw_deg: f64,
        q_start_deg: [f64; 3],
        opts: &IkOptions,
    ) -> Result<IkPositionSolution, IkError> {
        if !target_mm.coords.iter().all(|v| v.is_finite())
            || !q_yaw_deg.is_finite()
            || q_start_deg.iter().any(|v| !v.is_finite())
        {
            return Err(IkError::NotFinite);
        }
        let mut q = nalgebra::Vector3::from_iterator(q_start_deg.iter().map(|v| v.to_radians()));
        let full = |q: &nalgebra::Vector3<f64>| [q[0].to_degrees(), q[1].to_degrees(), q[2].to_degrees(), q_yaw_deg];
        let mut last_err = f64::INFINITY;
        let mut lambda = 1e-6;
        for it in 0..opts.max_iterations {
            let (pose, jac) = self.ee_jacobian(&full(&q));
            let e = target_mm.coords - pose.translation.vector;
            last_err = e.norm();
            if last_err < opts.tol_pos_mm.max(1e-9) {
                let sol = IkSolution {
                    q_deg: full(&q),
                    iterations: it,
                    residual_pos_mm: last_err,
                    residual_rot_rad: 0.0,
                };
                let sol = self.check_ik_limits(sol, opts)?;
                return Ok(IkPositionSolution {
                    q_deg: sol.q_deg,
                    iterations: it,
                    residual_pos_mm: last_err,
                });
            }
            let jv = jac.fixed_view::<3, 3>(0, 0).into_owned();
            let jtj = jv.transpose() * jv;
            let mut accepted = false;
            for _ in 0..10 {
                let Some(step) = (jtj + nalgebra::Matrix3::identity() * lambda)
                    .lu()
                    .solve(&(jv.transpose() * e))
                else {
                    lambda *= 10.0;
                    continue;
                };
                let n = step.norm();
                let step = if n > 0.3 { step * (0.3 / n) } else { step };
                let trial = q + step;
                let reached = self.ee_pose_reduced(&full(&trial)).translation.vector;
                if (target_mm.coords - reached).norm() < last_err {
                    q = trial;
                    lambda = (lambda * 0.3).max(1e-12);
                    accepted = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !accepted {
                break;
            }
        }
        Err(IkError::NotConverged {
            iterations: opts.max_iterations,
            residual_pos_mm: last_err,
            residual_rot_deg: 0.0,
            best_q_deg: full(&q),
        })
    }
}
