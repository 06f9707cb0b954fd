//! Joint-space fit: the configuration whose forward kinematics puts the jaw spheres where
//! they were measured (in the base frame), by Levenberg–Marquardt over all five joints,
//! each centre weighted by its covariance (a partly hidden sphere is uncertain along some
//! directions only; one known only by its outline, along its line of sight), and each
//! joint's standard deviation from the weighted Jacobian.
//!
//! Why beyond the paper's eq. 14 + IK: the IK matches a 6-D pose with four unknowns and
//! an arbitrary weighting of millimetres against radians, then reads q4/q5 from θ alone.
//! The measured quantities are the four centres (12 numbers, isotropic noise), so the
//! least-squares configuration over those is the statistically right estimate; it also
//! handles a hidden sphere (three or two jaw spheres still constrain some or all joints),
//! where eq. 8–14 cannot be evaluated. The IK result is its starting point.

use bowden_kinematics::markers::MarkerGeometry;
use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use nalgebra::{Matrix3, Point3, SMatrix, SVector, SymmetricEigen, Vector3};

/// Jaw spheres in fit order: r2, b1 (left jaw), y0, g0 (right jaw).
pub const N_JAW_MARKERS: usize = 4;

type Residual = SVector<f64, { 3 * N_JAW_MARKERS }>;
type Jacobian = SMatrix<f64, { 3 * N_JAW_MARKERS }, N_JOINTS>;

/// Where the four jaw spheres are for a configuration, base frame, mm.
pub fn jaw_centres(robot: &Robot, geometry: &MarkerGeometry, q_deg: &JointsDeg) -> [Vector3<f64>; N_JAW_MARKERS] {
    let fk = robot.fk(q_deg);
    let p = |t: &nalgebra::Isometry3<f64>, a: [f64; 3]| (t * Point3::from(a)).coords;
    [
        p(&fk.jaw_left, geometry.r2_left_mm),
        p(&fk.jaw_left, geometry.b1_left_mm),
        p(&fk.jaw_right, geometry.y0_right_mm),
        p(&fk.jaw_right, geometry.g0_right_mm),
    ]
}

/// The measured jaw centres (base frame) with their whitening: `whiten[i]ᵀ·(model − measured)`
/// has unit covariance, so the fit weighs each centre by how well it was measured (a
/// partially hidden sphere is uncertain along some directions only).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JawObservations {
    pub centre_mm: [Vector3<f64>; N_JAW_MARKERS],
    pub whiten: [Matrix3<f64>; N_JAW_MARKERS],
    /// Projection onto the directions in which each centre is measured to better than
    /// [`GATE_SD_MM`]: the fit's RMS (the consistency gate) is taken there only, so a sphere
    /// known only along its line of sight does not fail the gate on its loose range.
    pub gate_proj: [Matrix3<f64>; N_JAW_MARKERS],
    /// Bit i: centre i is used.
    pub use_mask: u8,
}

/// See [`JawObservations::gate_proj`].
pub const GATE_SD_MM: f64 = 1.0;

impl JawObservations {
    /// From centres and their covariances (mm²); `floor_mm` is added in quadrature on every
    /// axis (model and calibration error no sphere fit sees). `None` if a used covariance
    /// is not positive definite.
    pub fn new(
        centre_mm: [Vector3<f64>; N_JAW_MARKERS],
        cov_mm2: [Matrix3<f64>; N_JAW_MARKERS],
        use_mask: u8,
        floor_mm: f64,
    ) -> Option<Self> {
        let mut whiten = [Matrix3::zeros(); N_JAW_MARKERS];
        let mut gate_proj = [Matrix3::identity(); N_JAW_MARKERS];
        for i in 0..N_JAW_MARKERS {
            if use_mask & (1 << i) == 0 {
                continue;
            }
            let cov = cov_mm2[i] + Matrix3::identity() * (floor_mm * floor_mm);
            // Σ⁻¹ = L·Lᵀ  ⇒  (Lᵀ r)ᵀ(Lᵀ r) = rᵀ Σ⁻¹ r.
            let l = cov.try_inverse()?.cholesky()?.l();
            whiten[i] = l.transpose();
            let eig = SymmetricEigen::new(cov);
            let mut g = Matrix3::zeros();
            for k in 0..3 {
                if eig.eigenvalues[k] <= GATE_SD_MM * GATE_SD_MM {
                    let v = eig.eigenvectors.column(k);
                    g += v * v.transpose();
                }
            }
            gate_proj[i] = g;
        }
        Some(Self {
            centre_mm,
            whiten,
            gate_proj,
            use_mask,
        })
    }

    /// Equal, isotropic weights `sigma_mm` on every used centre.
    pub fn isotropic(centre_mm: [Vector3<f64>; N_JAW_MARKERS], use_mask: u8, sigma_mm: f64) -> Self {
        Self {
            centre_mm,
            whiten: [Matrix3::identity() / sigma_mm; N_JAW_MARKERS],
            gate_proj: [Matrix3::identity(); N_JAW_MARKERS],
            use_mask,
        }
    }

    pub fn with_mask(&self, use_mask: u8) -> Self {
        Self { use_mask, ..*self }
    }

    fn used(&self, i: usize) -> bool {
        self.use_mask & (1 << i) != 0
    }
}

fn residual(robot: &Robot, geometry: &MarkerGeometry, q: &JointsDeg, obs: &JawObservations) -> (Residual, f64) {
    let pred = jaw_centres(robot, geometry, q);
    let mut r = Residual::zeros();
    let mut ss_mm2 = 0.0;
    for i in 0..N_JAW_MARKERS {
        if obs.used(i) {
            let e = pred[i] - obs.centre_mm[i];
            ss_mm2 += (obs.gate_proj[i] * e).norm_squared();
            r.fixed_rows_mut::<3>(3 * i).copy_from(&(obs.whiten[i] * e));
        }
    }
    (r, ss_mm2)
}

/// Forward differences; 1e-4° keeps truncation (~1e-6 relative) and round-off (~1e-9)
/// far below the measurement noise.
fn jacobian(robot: &Robot, geometry: &MarkerGeometry, q: &JointsDeg, r0: &Residual, obs: &JawObservations) -> Jacobian {
    const H_DEG: f64 = 1e-4;
    let mut j = Jacobian::zeros();
    for k in 0..N_JOINTS {
        let mut qk = *q;
        qk[k] += H_DEG;
        let (rk, _) = residual(robot, geometry, &qk, obs);
        j.set_column(k, &((rk - r0) / H_DEG));
    }
    j
}

/// Result of the joint-space fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointFit {
    pub q_deg: JointsDeg,
    /// RMS distance between the used measured centres and the model's, mm (unweighted,
    /// in the well-measured directions of each centre, see [`JawObservations::gate_proj`]).
    pub rms_mm: f64,
    /// Weighted sum of squares (χ² if the covariances are right).
    pub chi2: f64,
    pub iterations: u32,
    /// Predicted standard deviation of each joint from the centres' covariances; infinite
    /// where the data do not determine the joint.
    pub sigma_deg: [f64; N_JOINTS],
}

/// Levenberg–Marquardt from `q0` on the used centres of `obs`, weighted by their whitening.
pub fn fit_joints(
    robot: &Robot,
    geometry: &MarkerGeometry,
    obs: &JawObservations,
    q0: &JointsDeg,
    max_iterations: u32,
) -> JointFit {
    let n_used = (obs.use_mask & 0x0f).count_ones().max(1) as f64;
    let mut q = *q0;
    let (mut r, mut ss) = residual(robot, geometry, &q, obs);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut j = jacobian(robot, geometry, &q, &r, obs);
    for _ in 0..max_iterations {
        iterations += 1;
        let jtj = j.transpose() * j;
        let jtr = j.transpose() * r;
        let mut accepted = false;
        let mut converged = false;
        for _ in 0..10 {
            let mut a = jtj;
            for d in 0..N_JOINTS {
                // The small absolute term keeps an unobservable joint (a zero column) where it is.
                a[(d, d)] += lambda * jtj[(d, d)] + 1e-9;
            }
            let Some(chol) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let step = -chol.solve(&jtr);
            let mut q2 = q;
            for k in 0..N_JOINTS {
                q2[k] += step[k];
            }
            let (r2, ss2) = residual(robot, geometry, &q2, obs);
            let c2 = r2.norm_squared();
            if c2.is_finite() && c2 <= cost {
                converged = step.amax() < 1e-7 || cost - c2 <= 1e-14 * cost.max(1e-300);
                q = q2;
                r = r2;
                ss = ss2;
                cost = c2;
                lambda = (lambda * 0.3).max(1e-12);
                accepted = true;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted || converged {
            break;
        }
        j = jacobian(robot, geometry, &q, &r, obs);
    }
    let j = jacobian(robot, geometry, &q, &r, obs);
    JointFit {
        q_deg: q,
        rms_mm: (ss / n_used).sqrt(),
        chi2: cost,
        iterations,
        sigma_deg: joint_sigmas(&j, 1.0),
    }
}

/// Eq. (4) carried to convergence on a pose that four joints cannot match exactly (a
/// measured one): Levenberg–Marquardt on the 6-D pose error with the same weighting as
/// `robot.ik` (`rot_weight_mm_per_rad`), stopping when the step, not the residual, is
/// small. `robot.ik` is run with noise-level tolerances to find the basin; this finds the
/// least-squares configuration in it. Returns (q1, q2, q3, q_yaw) in degrees.
pub fn polish_pose_ik(
    robot: &Robot,
    target: &nalgebra::Isometry3<f64>,
    q0_deg: [f64; 4],
    rot_weight_mm_per_rad: f64,
    max_iterations: u32,
) -> [f64; 4] {
    use bowden_kinematics::ik::pose_error;
    use nalgebra::{Matrix4, Vector4, Vector6};
    let w = rot_weight_mm_per_rad;
    let eval = |q: &[f64; 4]| {
        let (pose, mut jac) = robot.ee_jacobian(q);
        let (dp, dr) = pose_error(target, &pose);
        let mut e = Vector6::zeros();
        e.fixed_rows_mut::<3>(0).copy_from(&dp);
        e.fixed_rows_mut::<3>(3).copy_from(&(dr * w));
        for c in 0..4 {
            for r in 3..6 {
                jac[(r, c)] *= w;
            }
        }
        (e, jac)
    };
    let mut q = q0_deg;
    let (mut e, mut jac) = eval(&q);
    let mut cost = e.norm_squared();
    let mut lambda = 1e-4;
    for _ in 0..max_iterations {
        let jtj = jac.transpose() * jac;
        let jte = jac.transpose() * e;
        let mut accepted = false;
        let mut done = false;
        for _ in 0..10 {
            let damped = jtj + Matrix4::from_diagonal(&jtj.diagonal().map(|d| lambda * d + 1e-12));
            let Some(step) = damped.cholesky().map(|c| c.solve(&jte)) else {
                lambda *= 10.0;
                continue;
            };
            let step: Vector4<f64> = step;
            let q2 = [
                q[0] + step[0].to_degrees(),
                q[1] + step[1].to_degrees(),
                q[2] + step[2].to_degrees(),
                q[3] + step[3].to_degrees(),
            ];
            let (e2, j2) = eval(&q2);
            let c2 = e2.norm_squared();
            if c2.is_finite() && c2 <= cost {
                done = step.amax().to_degrees() < 1e-7;
                q = q2;
                e = e2;
                jac = j2;
                cost = c2;
                lambda = (lambda * 0.3).max(1e-12);
                accepted = true;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted || done {
            break;
        }
    }
    q
}

/// Standard deviation of each joint of a linearised least-squares fit with Jacobian `j`
/// (mm per degree) and i.i.d. noise `sigma_mm`: σ_k = σ·√((JᵀJ)⁺_kk). A joint with a
/// component in the null space of J is not determined at all: infinite.
pub fn joint_sigmas(j: &Jacobian, sigma_mm: f64) -> [f64; N_JOINTS] {
    let jtj = j.transpose() * j;
    let eig = SymmetricEigen::new(jtj);
    let lmax = eig.eigenvalues.amax();
    let mut out = [f64::INFINITY; N_JOINTS];
    if !(lmax.is_finite() && lmax > 0.0) {
        return out;
    }
    let tol = 1e-10 * lmax;
    for (k, o) in out.iter_mut().enumerate() {
        let (mut var, mut null) = (0.0, 0.0);
        for e in 0..N_JOINTS {
            let v = eig.eigenvectors[(k, e)];
            let l = eig.eigenvalues[e];
            if l > tol {
                var += v * v / l;
            } else {
                null += v * v;
            }
        }
        *o = if null > 1e-6 {
            f64::INFINITY
        } else {
            sigma_mm * var.sqrt()
        };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_joints_from_exact_centres_and_flags_a_hidden_jaw() {
        let robot = Robot::paper_default();
        let g = MarkerGeometry::paper_default();
        let q_true = [35.0, -20.0, 25.0, -10.0, 30.0];
        let measured = jaw_centres(&robot, &g, &q_true);
        let obs = JawObservations::isotropic(measured, 0b1111, 0.2);
        let fit = fit_joints(&robot, &g, &obs, &[0.0; 5], 50);
        for k in 0..N_JOINTS {
            assert!((fit.q_deg[k] - q_true[k]).abs() < 1e-5, "q{} {:?}", k + 1, fit.q_deg);
            assert!(
                fit.sigma_deg[k].is_finite() && fit.sigma_deg[k] < 3.0,
                "{:?}",
                fit.sigma_deg
            );
        }
        assert!(fit.rms_mm < 1e-6);

        // Right jaw hidden: q5 is not observable, the others still are.
        let start = [30.0, -15.0, 20.0, 0.0, 0.0];
        let fit = fit_joints(&robot, &g, &obs.with_mask(0b0011), &start, 50);
        assert!(fit.sigma_deg[4].is_infinite(), "{:?}", fit.sigma_deg);
        assert_eq!(fit.q_deg[4], 0.0, "an unobservable joint stays at its start");
        for k in 0..4 {
            assert!((fit.q_deg[k] - q_true[k]).abs() < 1e-3, "q{} {:?}", k + 1, fit.q_deg);
        }
        // One sphere: three numbers for five joints.
        let fit = fit_joints(&robot, &g, &obs.with_mask(0b0001), &start, 50);
        assert!(
            fit.sigma_deg.iter().filter(|s| s.is_finite() && **s < 3.0).count() < 5,
            "{:?}",
            fit.sigma_deg
        );
    }
}
