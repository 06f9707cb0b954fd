//! Step 3 of §IV-A: frames from sphere centres.
//!
//! * Base frame (eq. 6–7): the rigid transform that maps the three base spheres' known
//!   positions onto their measured centres, by orthogonal Procrustes (Kabsch). With exact
//!   centres it is eq. 7 exactly (ŷ_B = r0→r1, ẑ_B = r1→b0, x̂_B = ŷ_B × ẑ_B, origin at the
//!   r0–r1 midpoint plus L_base); with noisy centres eq. 7's axes are not orthogonal and
//!   x̂_B is not a unit vector, while Procrustes gives the least-squares rotation. L_base of
//!   eq. 7 is a base-frame vector, so it is applied rotated into the camera frame.
//! * Jaw frames (eq. 8–10) and end-effector (eq. 11–13): both jaws share the pivot and the
//!   rotation axis x̂; the left jaw is the bisector frame B rotated by −θ/2 about x̂, the right
//!   one by +θ/2. [`fit_jaw_pair`] fits (pivot, B, θ) to the four jaw centres by least
//!   squares. This is what eq. 8–13 approximate: eq. 9 writes ŷ = x̂ × ẑ (left-handed; the
//!   right-handed frame has ŷ = ẑ × x̂), builds x̂ from a sphere of the other jaw, and corrects
//!   the sideways marker offset with R_x(ψ); eq. 13 places the tip along ẑ_f1 with a
//!   (1 − cos θ/2) term, exact only along the bisector's ẑ. With the marker offsets known
//!   (`MarkerGeometry`) the joint model needs none of those approximations: R_EE = B (eq. 12:
//!   R_f1·R_x(θ/2)), P_EE = pivot + d_fcps·ẑ_B, θ = the angle between ẑ_f1 and ẑ_f2 (eq. 11).

use nalgebra::{Isometry3, Matrix3, Rotation3, SMatrix, SVector, Translation3, UnitQuaternion, Vector3};

/// Least-squares rigid transform `T` with `measured[i] ≈ T · model[i]` (Kabsch). `None` for
/// degenerate input (fewer than 3 non-collinear points, non-finite values).
pub fn kabsch(model: &[Vector3<f64>], measured: &[Vector3<f64>]) -> Option<Isometry3<f64>> {
    let n = model.len();
    if n < 3 || measured.len() != n {
        return None;
    }
    let ma = model.iter().fold(Vector3::zeros(), |s, p| s + p) / n as f64;
    let mc = measured.iter().fold(Vector3::zeros(), |s, p| s + p) / n as f64;
    let mut h = Matrix3::zeros();
    for (a, c) in model.iter().zip(measured) {
        h += (a - ma) * (c - mc).transpose();
    }
    if !h.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = h.svd(true, true);
    // Rank < 2 (collinear points): the rotation about the line is undetermined.
    let sv = svd.singular_values;
    if sv[1] <= 1e-9 * sv[0].max(1e-300) {
        return None;
    }
    let (u, v_t) = (svd.u?, svd.v_t?);
    let v = v_t.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let r = v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = mc - rot * ma;
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

/// RMS distance between `measured[i]` and `T · model[i]`.
pub fn rms_distance(t: &Isometry3<f64>, model: &[Vector3<f64>], measured: &[Vector3<f64>]) -> f64 {
    let ss: f64 = model
        .iter()
        .zip(measured)
        .map(|(a, c)| (t.transform_vector(a) + t.translation.vector - c).norm_squared())
        .sum();
    (ss / model.len().max(1) as f64).sqrt()
}

/// The two jaws as one rigid pair with an opening angle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JawPair {
    /// Bisector frame at the pivot: x̂ = jaw rotation axis, ẑ = along the closed jaws.
    pub bisector: Isometry3<f64>,
    /// θ = q5 − q4, rad (the right jaw is the bisector turned by +θ/2 about x̂).
    pub opening_rad: f64,
    /// RMS distance of the four centres to the model, mm.
    pub rms_mm: f64,
}

impl JawPair {
    pub fn left(&self) -> Isometry3<f64> {
        self.bisector * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -0.5 * self.opening_rad)
    }
    pub fn right(&self) -> Isometry3<f64> {
        self.bisector * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.5 * self.opening_rad)
    }
    /// End-effector pose (eq. 12–13 exact): bisector orientation, origin at the closed-jaw
    /// tip `jaw_length_mm` along ẑ from the pivot.
    pub fn end_effector(&self, jaw_length_mm: f64) -> Isometry3<f64> {
        let tip = self.bisector * nalgebra::Point3::new(0.0, 0.0, jaw_length_mm);
        Isometry3::from_parts(Translation3::from(tip.coords), self.bisector.rotation)
    }
}

fn rx(a: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), a)
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Fits the jaw pair to the measured centres of the left jaw's two spheres (`left`, their
/// jaw-frame positions `left_model`) and the right jaw's two (`right`, `right_model`).
/// Initialised by Procrustes over a grid of openings, then Levenberg–Marquardt on
/// (pivot, bisector rotation, θ). `None` if the input is degenerate.
pub fn fit_jaw_pair(
    left_model: &[Vector3<f64>; 2],
    right_model: &[Vector3<f64>; 2],
    left: &[Vector3<f64>; 2],
    right: &[Vector3<f64>; 2],
) -> Option<JawPair> {
    let measured = [left[0], left[1], right[0], right[1]];
    let model_at = |phi: f64| {
        let (l, r) = (rx(-phi), rx(phi));
        [
            l * left_model[0],
            l * left_model[1],
            r * right_model[0],
            r * right_model[1],
        ]
    };
    // Initial guess: the opening whose rigid Procrustes fit is best (θ/2 from −10° to 70°).
    let mut best: Option<(f64, Isometry3<f64>, f64)> = None;
    for k in 0..=16 {
        let phi = (-10.0 + 5.0 * k as f64).to_radians();
        let model = model_at(phi);
        if let Some(t) = kabsch(&model, &measured) {
            let cost = rms_distance(&t, &model, &measured);
            if best.is_none_or(|b| cost < b.2) {
                best = Some((phi, t, cost));
            }
        }
    }
    let (mut phi, t0, _) = best?;
    let mut rot = t0.rotation.to_rotation_matrix();
    let mut pivot = t0.translation.vector;

    let residuals = |pivot: &Vector3<f64>, rot: &Rotation3<f64>, phi: f64| -> SVector<f64, 12> {
        let model = model_at(phi);
        let mut r = SVector::<f64, 12>::zeros();
        for i in 0..4 {
            let e = pivot + rot * model[i] - measured[i];
            r.fixed_rows_mut::<3>(3 * i).copy_from(&e);
        }
        r
    };
    let mut r = residuals(&pivot, &rot, phi);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..30 {
        // Jacobian w.r.t. (δpivot, δω (left-multiplied rotation), δφ).
        let mut j = SMatrix::<f64, 12, 7>::zeros();
        let (l, rr) = (rx(-phi), rx(phi));
        for i in 0..4 {
            let (a, sign, jaw) = if i < 2 {
                (left_model[i], -1.0, l)
            } else {
                (right_model[i - 2], 1.0, rr)
            };
            let u = rot * (jaw * a);
            let dphi = rot * (jaw * Vector3::x().cross(&a)) * sign;
            j.fixed_view_mut::<3, 3>(3 * i, 0).copy_from(&Matrix3::identity());
            j.fixed_view_mut::<3, 3>(3 * i, 3).copy_from(&(-skew(&u)));
            j.fixed_view_mut::<3, 1>(3 * i, 6).copy_from(&dphi);
        }
        let jtj = j.transpose() * j;
        let jtr = j.transpose() * r;
        let mut accepted = false;
        let mut small_step = false;
        for _ in 0..10 {
            let mut a = jtj;
            for d in 0..7 {
                a[(d, d)] += lambda * jtj[(d, d)] + 1e-12;
            }
            let Some(chol) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let step = -chol.solve(&jtr);
            let p2 = pivot + step.fixed_rows::<3>(0);
            let w = Vector3::new(step[3], step[4], step[5]);
            let rot2 = Rotation3::new(w) * rot;
            let phi2 = phi + step[6];
            let r2 = residuals(&p2, &rot2, phi2);
            let c2 = r2.norm_squared();
            if c2 <= cost {
                small_step = step.norm() < 1e-10;
                pivot = p2;
                rot = rot2;
                phi = phi2;
                r = r2;
                cost = c2;
                lambda = (lambda * 0.3).max(1e-12);
                accepted = true;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted || small_step {
            break;
        }
    }
    if !(cost.is_finite() && phi.is_finite()) {
        return None;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&rot);
    Some(JawPair {
        bisector: Isometry3::from_parts(Translation3::from(pivot), rot),
        opening_rad: 2.0 * phi,
        rms_mm: (cost / 4.0).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kabsch_recovers_a_rigid_transform() {
        let t = Isometry3::from_parts(
            Translation3::new(10.0, -20.0, 300.0),
            UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
        );
        let model = [
            Vector3::new(-25.0, -16.0, 0.0),
            Vector3::new(-25.0, 16.0, 0.0),
            Vector3::new(-25.0, 16.0, 22.0),
        ];
        let measured = model.map(|a| t.transform_vector(&a) + t.translation.vector);
        let est = kabsch(&model, &measured).unwrap();
        assert!((est.translation.vector - t.translation.vector).norm() < 1e-9);
        assert!(est.rotation.angle_to(&t.rotation) < 1e-9);
        // Collinear points leave the rotation about the line free.
        let line = [Vector3::zeros(), Vector3::x(), Vector3::x() * 2.0];
        assert!(kabsch(&line, &line).is_none());
    }

    #[test]
    fn jaw_pair_recovers_pose_and_opening() {
        let lm = [Vector3::new(3.0, 0.0, 8.5), Vector3::new(3.0, 0.0, 2.5)];
        let rm = [Vector3::new(-3.0, 0.0, 8.5), Vector3::new(-3.0, 0.0, 2.5)];
        for (k, opening_deg) in [0.0, 3.0, 25.0, 60.0, 99.0].iter().enumerate() {
            let bis = Isometry3::from_parts(
                Translation3::new(50.0, 5.0 * k as f64, -3.0),
                UnitQuaternion::from_euler_angles(0.2 * k as f64, 1.0 - 0.3 * k as f64, 0.5),
            );
            let truth = JawPair {
                bisector: bis,
                opening_rad: f64::to_radians(*opening_deg),
                rms_mm: 0.0,
            };
            let (l, r) = (truth.left(), truth.right());
            let left = lm.map(|a| l.transform_vector(&a) + l.translation.vector);
            let right = rm.map(|a| r.transform_vector(&a) + r.translation.vector);
            let fit = fit_jaw_pair(&lm, &rm, &left, &right).unwrap();
            assert!(fit.rms_mm < 1e-8, "opening {opening_deg}: rms {}", fit.rms_mm);
            assert!((fit.opening_rad - truth.opening_rad).abs() < 1e-8);
            assert!(fit.bisector.rotation.angle_to(&bis.rotation) < 1e-8);
            assert!((fit.bisector.translation.vector - bis.translation.vector).norm() < 1e-8);
            let ee = fit.end_effector(9.0);
            let tip = bis * nalgebra::Point3::new(0.0, 0.0, 9.0);
            assert!((ee.translation.vector - tip.coords).norm() < 1e-8);
        }
    }
}
