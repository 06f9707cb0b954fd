//! Forward kinematics: eq. (1)–(3) and Table II, with the geometric Jacobian accumulated
//! along the same walk (so it is analytic, not finite differences).

use nalgebra::{Isometry3, Matrix3, Matrix6x4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::FRAC_PI_2;

use crate::{sinc, sinc_derivative, JointsDeg, Robot};

/// Eq. (1): the equivalent prismatic length of one hinge bent by `theta_rad`,
/// Tr = l·cos(θ/2) + (2h/θ)·sin(θ/2), with the exact limit l + h at θ = 0.
#[inline]
pub fn hinge_length_tr(theta_rad: f64, l_mm: f64, h_mm: f64) -> f64 {
    // (2h/θ)·sin(θ/2) = h·sinc(θ/2): no division by zero, no cancellation near 0.
    l_mm * (0.5 * theta_rad).cos() + h_mm * sinc(0.5 * theta_rad)
}

/// d Tr / d θ.
#[inline]
pub fn hinge_length_tr_derivative(theta_rad: f64, l_mm: f64, h_mm: f64) -> f64 {
    -0.5 * l_mm * (0.5 * theta_rad).sin() + 0.5 * h_mm * sinc_derivative(0.5 * theta_rad)
}

/// Eq. (2): the modified Denavit–Hartenberg transform ^{k-1}T_k.
pub fn dh_transform(alpha_prev: f64, a_prev: f64, d: f64, theta: f64) -> nalgebra::Matrix4<f64> {
    let (st, ct) = theta.sin_cos();
    let (sa, ca) = alpha_prev.sin_cos();
    nalgebra::Matrix4::new(
        ct,
        -st,
        0.0,
        a_prev, //
        st * ca,
        ct * ca,
        -sa,
        -d * sa, //
        st * sa,
        ct * sa,
        ca,
        d * ca, //
        0.0,
        0.0,
        0.0,
        1.0,
    )
}

/// A rigid pose in the base frame (mm, rotation): what [`FkResult`]'s frames are.
pub type Pose = Isometry3<f64>;

/// Position (mm) and orientation (deg) distance of `reached` from `desired`: |Δp| and the
/// angle of the relative rotation, the two tip errors of the paper's Table V.
pub fn pose_distance(desired: &Pose, reached: &Pose) -> (f64, f64) {
    let pos = (reached.translation.vector - desired.translation.vector).norm();
    let rot = (desired.rotation.inverse() * reached.rotation).angle().to_degrees();
    (pos, rot)
}

/// Poses of the manipulator's characteristic frames in the base frame, for one configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct FkResult {
    /// End of segment 1 (elbow): x along the axis.
    pub segment1_end: Isometry3<f64>,
    /// End of segment 2 (wrist).
    pub segment2_end: Isometry3<f64>,
    /// Jaw pivot: x along the axis, z = jaw rotation axis.
    pub pivot: Isometry3<f64>,
    /// Left jaw (forceps 1, q4) at the pivot: x = rotation axis, z = along the jaw.
    pub jaw_left: Isometry3<f64>,
    /// Right jaw (forceps 2, q5).
    pub jaw_right: Isometry3<f64>,
    /// End-effector: the jaws' bisector (rotated by q_yaw = (q4+q5)/2), origin at the
    /// closed-jaw tip, jaw_length from the pivot along z.
    pub ee: Isometry3<f64>,
}

impl FkResult {
    /// Jaw tip of the left / right jaw, mm, base frame.
    pub fn jaw_tips(&self, jaw_length_mm: f64) -> [Point3<f64>; 2] {
        let tip = |t: &Isometry3<f64>| t * Point3::new(0.0, 0.0, jaw_length_mm);
        [tip(&self.jaw_left), tip(&self.jaw_right)]
    }
}

/// Maps the pivot's axes to the paper's jaw axes: x_f = pivot z (rotation axis),
/// z_f = pivot x (along the jaw), y_f = z_f × x_f = −pivot y. Determinant +1.
fn jaw_axes() -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, 0.0, 1.0, //
        0.0, -1.0, 0.0, //
        1.0, 0.0, 0.0,
    ))
}

/// Accumulates the geometric Jacobian of a point (the end-effector origin) without storing
/// every joint axis: v = Σ c·ω × (p − o) + Σ c·a = A × p − B + T, w = A.
#[derive(Default)]
struct JacobianAcc {
    a: [Vector3<f64>; 4],
    b: [Vector3<f64>; 4],
    t: [Vector3<f64>; 4],
}

struct Walker<'a> {
    pose: Isometry3<f64>,
    acc: Option<&'a mut JacobianAcc>,
    points: Option<&'a mut Vec<Point3<f64>>>,
}

impl Walker<'_> {
    fn rot_x(&mut self, angle: f64) {
        self.pose *= UnitQuaternion::from_axis_angle(&Vector3::x_axis(), angle);
    }
    /// Rotation about the current z by `angle`; `dep` = (column, d angle / d q).
    fn rot_z(&mut self, angle: f64, dep: Option<(usize, f64)>) {
        if let (Some(acc), Some((col, c))) = (self.acc.as_deref_mut(), dep) {
            let axis = self.pose.rotation * Vector3::z();
            let origin = self.pose.translation.vector;
            acc.a[col] += c * axis;
            acc.b[col] += c * axis.cross(&origin);
        }
        self.pose *= UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle);
    }
    /// Translation along the current x by `dist`; `dep` = (column, d dist / d q).
    fn trans_x(&mut self, dist: f64, dep: Option<(usize, f64)>) {
        if let (Some(acc), Some((col, c))) = (self.acc.as_deref_mut(), dep) {
            acc.t[col] += c * (self.pose.rotation * Vector3::x());
        }
        self.pose *= Translation3::new(dist, 0.0, 0.0);
        if let Some(points) = self.points.as_deref_mut() {
            points.push(Point3::from(self.pose.translation.vector));
        }
    }
}

impl Robot {
    /// The walk of Table II over both segments to the jaw pivot. Columns of the Jacobian:
    /// 0 = q1, 1 = q2, 2 = q3 (rad), 3 = q_yaw (handled by the caller).
    fn walk_to_pivot(&self, q_rad: &[f64; 3], w: &mut Walker<'_>) -> (Isometry3<f64>, Isometry3<f64>) {
        let c = &self.config;
        let (l, h) = (c.hinge.l_mm, c.hinge.h_mm);
        let n1 = c.segment1.modules as f64;
        let n2 = c.segment2.modules as f64;
        // Segment 1: each module is frames 1–8 of Table II (pitch hinge, then yaw hinge).
        let (tp, ty) = (q_rad[0] / n1, q_rad[1] / n1);
        let (trp, try_) = (hinge_length_tr(tp, l, h), hinge_length_tr(ty, l, h));
        let (dtrp, dtry) = (
            hinge_length_tr_derivative(tp, l, h) / n1,
            hinge_length_tr_derivative(ty, l, h) / n1,
        );
        let half1 = 0.5 / n1;
        for _ in 0..c.segment1.modules {
            w.rot_x(FRAC_PI_2); //                       frame 1: α0 = π/2
            w.rot_z(0.5 * tp, Some((0, half1))); //      frame 2: θ = θp/2
            w.trans_x(trp, Some((0, dtrp))); //          frame 3: a = Tr_i
            w.rot_z(0.5 * tp, Some((0, half1))); //      frame 4: θ = θp/2
            w.rot_x(-FRAC_PI_2); //                      frame 5: α4 = −π/2
            w.rot_z(0.5 * ty, Some((1, half1))); //      frame 6: θ = θy/2
            w.trans_x(try_, Some((1, dtry))); //         frame 7: a = Tr_{i+1}
            w.rot_z(0.5 * ty, Some((1, half1))); //      frame 8: θ = θy/2
        }
        let seg1_end = w.pose;
        // Segment 2: frames 2–4 of Table II per module. Table II's frames 2–4 rotate about
        // the z of frame 1, i.e. after α0 = π/2; without it segment 2 would bend in the yaw
        // plane, contradicting Fig. 4 ("segment 2 ... pitch"). So the segment is wrapped in
        // frame 1's and frame 5's α.
        let t3 = q_rad[2] / n2;
        let (tr3, dtr3) = (hinge_length_tr(t3, l, h), hinge_length_tr_derivative(t3, l, h) / n2);
        let half2 = 0.5 / n2;
        w.rot_x(FRAC_PI_2);
        for _ in 0..c.segment2.modules {
            w.rot_z(0.5 * t3, Some((2, half2)));
            w.trans_x(tr3, Some((2, dtr3)));
            w.rot_z(0.5 * t3, Some((2, half2)));
        }
        w.rot_x(-FRAC_PI_2);
        let seg2_end = w.pose;
        w.trans_x(c.forceps.wrist_length_mm, None);
        (seg1_end, seg2_end)
    }

    /// Eq. (3): base → every characteristic frame for `q_deg`.
    pub fn fk(&self, q_deg: &JointsDeg) -> FkResult {
        let q_rad = [q_deg[0].to_radians(), q_deg[1].to_radians(), q_deg[2].to_radians()];
        let mut w = Walker {
            pose: Isometry3::identity(),
            acc: None,
            points: None,
        };
        let (segment1_end, segment2_end) = self.walk_to_pivot(&q_rad, &mut w);
        self.finish(w.pose, segment1_end, segment2_end, q_deg[3], q_deg[4])
    }

    fn finish(
        &self,
        pivot: Isometry3<f64>,
        segment1_end: Isometry3<f64>,
        segment2_end: Isometry3<f64>,
        q4_deg: f64,
        q5_deg: f64,
    ) -> FkResult {
        let axes = UnitQuaternion::from_rotation_matrix(&jaw_axes());
        let jaw = |q_deg: f64| {
            let r = pivot.rotation * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), q_deg.to_radians()) * axes;
            Isometry3::from_parts(pivot.translation, r)
        };
        let jaw_left = jaw(q4_deg);
        let jaw_right = jaw(q5_deg);
        let bis = jaw(0.5 * (q4_deg + q5_deg));
        let tip = bis * Point3::new(0.0, 0.0, self.config.forceps.jaw_length_mm);
        let ee = Isometry3::from_parts(Translation3::from(tip.coords), bis.rotation);
        FkResult {
            segment1_end,
            segment2_end,
            pivot,
            jaw_left,
            jaw_right,
            ee,
        }
    }

    /// End-effector pose from the IK coordinates (q1, q2, q3, q_yaw) in degrees.
    pub fn ee_pose_reduced(&self, q4_deg: &[f64; 4]) -> Isometry3<f64> {
        self.fk(&[q4_deg[0], q4_deg[1], q4_deg[2], q4_deg[3], q4_deg[3]]).ee
    }

    /// End-effector pose and its geometric Jacobian with respect to (q1, q2, q3, q_yaw) in
    /// radians: rows 0–2 linear velocity (mm/rad), rows 3–5 angular velocity, base frame.
    pub fn ee_jacobian(&self, q4_deg: &[f64; 4]) -> (Isometry3<f64>, Matrix6x4<f64>) {
        let q_rad = [q4_deg[0].to_radians(), q4_deg[1].to_radians(), q4_deg[2].to_radians()];
        let mut acc = JacobianAcc::default();
        let mut w = Walker {
            pose: Isometry3::identity(),
            acc: Some(&mut acc),
            points: None,
        };
        let (s1, s2) = self.walk_to_pivot(&q_rad, &mut w);
        let pivot = w.pose;
        let fk = self.finish(pivot, s1, s2, q4_deg[3], q4_deg[3]);
        // q_yaw: rotation about the pivot's z at the pivot.
        let axis = pivot.rotation * Vector3::z();
        acc.a[3] += axis;
        acc.b[3] += axis.cross(&pivot.translation.vector);
        let p = fk.ee.translation.vector;
        let mut jac = Matrix6x4::zeros();
        for col in 0..4 {
            let v = acc.a[col].cross(&p) - acc.b[col] + acc.t[col];
            jac.fixed_view_mut::<3, 1>(0, col).copy_from(&v);
            jac.fixed_view_mut::<3, 1>(3, col).copy_from(&acc.a[col]);
        }
        (fk.ee, jac)
    }

    /// The body's centre line from base to pivot, one point per hinge (for rendering the
    /// manipulator as an occluder). Clears and fills `out`.
    pub fn centerline(&self, q_deg: &JointsDeg, out: &mut Vec<Point3<f64>>) {
        out.clear();
        out.push(Point3::origin());
        let q_rad = [q_deg[0].to_radians(), q_deg[1].to_radians(), q_deg[2].to_radians()];
        let mut w = Walker {
            pose: Isometry3::identity(),
            acc: None,
            points: Some(out),
        };
        self.walk_to_pivot(&q_rad, &mut w);
    }
}
