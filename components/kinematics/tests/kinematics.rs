//! Foundation tests of the manipulator model (issue: FK, IK, Jacobian, cable equation).

use bowden_kinematics::cables::eq5_hinge_chord_mm;
use bowden_kinematics::fk::{dh_transform, hinge_length_tr};
use bowden_kinematics::ik::{pose_error, IkError, IkOptions};
use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use nalgebra::{Isometry3, Matrix4, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn robot() -> Robot {
    Robot::paper_default()
}

fn random_q(robot: &Robot, rng: &mut ChaCha8Rng) -> JointsDeg {
    let lim = &robot.config.limits;
    loop {
        let q: JointsDeg = core::array::from_fn(|j| rng.random_range(lim.q_min_deg[j]..=lim.q_max_deg[j]));
        if robot.check_limits(&q).is_ok() {
            return q;
        }
    }
}

#[test]
fn eq1_is_exact_and_finite_at_zero() {
    let (l, h) = (0.7, 0.5);
    assert_eq!(hinge_length_tr(0.0, l, h), l + h);
    // Continuous through zero: the series branch and the closed form agree.
    for &t in &[1e-9, 1e-6, 1e-5, 9.9e-5, 1.01e-4, 1e-3] {
        let closed = l * (t / 2.0f64).cos() + (2.0 * h / t) * (t / 2.0f64).sin();
        assert!((hinge_length_tr(t, l, h) - closed).abs() < 1e-12, "t = {t}");
        assert!((hinge_length_tr(-t, l, h) - closed).abs() < 1e-12);
    }
    assert!(hinge_length_tr(0.3, l, h) < l + h, "a bent hinge is shorter");
}

#[test]
fn fk_straight_length_equals_table_sum() {
    let r = robot();
    let fk = r.fk(&[0.0; N_JOINTS]);
    let expected = r.straight_length_mm();
    // 11 modules × 2 hinges × (l + h) + 8 × (l + h) + wrist + jaw, along +x.
    let c = &r.config;
    let by_hand =
        (2.0 * 11.0 + 8.0) * (c.hinge.l_mm + c.hinge.h_mm) + c.forceps.wrist_length_mm + c.forceps.jaw_length_mm;
    assert!((expected - by_hand).abs() < 1e-12);
    let p = fk.ee.translation.vector;
    assert!((p - Vector3::new(expected, 0.0, 0.0)).norm() < 1e-12, "ee at {p:?}");
    assert!(fk.ee.rotation.angle() < 1e-12 || (fk.ee.rotation * Vector3::z() - Vector3::x()).norm() < 1e-12);
}

#[test]
fn pitch_bends_in_xz_and_yaw_in_xy() {
    let r = robot();
    for q1 in [-40.0, -10.0, 25.0, 55.0] {
        let p = r.fk(&[q1, 0.0, 0.0, 0.0, 0.0]).ee.translation.vector;
        assert!(p.y.abs() < 1e-9, "pure pitch left the x-z plane: {p:?}");
        assert!(p.z.signum() == f64::signum(q1), "positive pitch bends toward +z");
    }
    for q3 in [-30.0, 30.0] {
        let p = r.fk(&[0.0, 0.0, q3, 0.0, 0.0]).ee.translation.vector;
        assert!(
            p.y.abs() < 1e-9 && p.z.signum() == f64::signum(q3),
            "segment 2 pitches in x-z: {p:?}"
        );
    }
    for q2 in [-50.0, 20.0] {
        let p = r.fk(&[0.0, q2, 0.0, 0.0, 0.0]).ee.translation.vector;
        assert!(p.z.abs() < 1e-9, "pure yaw left the x-y plane: {p:?}");
        assert!(p.y.signum() == f64::signum(q2));
    }
    // The total bend of a segment is its joint angle: the pivot's axis turns by q1.
    let fk = r.fk(&[37.0, 0.0, 0.0, 0.0, 0.0]);
    let axis = fk.segment1_end.rotation * Vector3::x();
    assert!((axis.z.atan2(axis.x).to_degrees() - 37.0).abs() < 1e-9);
}

#[test]
fn modified_dh_product_matches_the_walk() {
    // One module of segment 1 by eq. (2) and Table II, against the FK walk with n = 1.
    let mut r = robot();
    r.config.segment1.modules = 1;
    r.config.segment2.modules = 1;
    let r = Robot::new(r.config);
    let (tp, ty) = (0.3f64, -0.2f64);
    let (l, h) = (r.config.hinge.l_mm, r.config.hinge.h_mm);
    let rows: [(f64, f64, f64); 8] = [
        (std::f64::consts::FRAC_PI_2, 0.0, 0.0),
        (0.0, 0.0, tp / 2.0),
        (0.0, hinge_length_tr(tp, l, h), 0.0),
        (0.0, 0.0, tp / 2.0),
        (-std::f64::consts::FRAC_PI_2, 0.0, 0.0),
        (0.0, 0.0, ty / 2.0),
        (0.0, hinge_length_tr(ty, l, h), 0.0),
        (0.0, 0.0, ty / 2.0),
    ];
    let mut t = Matrix4::identity();
    for (alpha, a, theta) in rows {
        t *= dh_transform(alpha, a, 0.0, theta);
    }
    let fk = r.fk(&[tp.to_degrees(), ty.to_degrees(), 0.0, 0.0, 0.0]);
    let m = fk.segment1_end.to_homogeneous();
    assert!((m - t).abs().max() < 1e-12, "DH product\n{t}\nwalk\n{m}");
}

#[test]
fn jaws_mirror_at_opposite_angles() {
    let r = robot();
    for (q, a) in [([10.0, -20.0, 15.0], 25.0), ([0.0, 0.0, 0.0], 40.0)] {
        let fk = r.fk(&[q[0], q[1], q[2], -a, a]);
        // Reflect the right jaw across the pivot's x-z plane (the plane the jaws open in
        // is x-y; the mirror plane contains the axis and the rotation axis).
        let to_pivot = fk.pivot.inverse();
        let zl = to_pivot.rotation * (fk.jaw_left.rotation * Vector3::z());
        let zr = to_pivot.rotation * (fk.jaw_right.rotation * Vector3::z());
        assert!(
            (zl - Vector3::new(zr.x, -zr.y, zr.z)).norm() < 1e-12,
            "{zl:?} vs {zr:?}"
        );
        assert!((zl.y + zr.y).abs() < 1e-12 && zl.y.abs() > 0.1);
        // Bisector along the pivot axis when q_yaw = 0.
        let ze = to_pivot.rotation * (fk.ee.rotation * Vector3::z());
        assert!((ze - Vector3::x()).norm() < 1e-12);
        // The opening angle between the jaws is q5 − q4.
        let zl_w = fk.jaw_left.rotation * Vector3::z();
        let zr_w = fk.jaw_right.rotation * Vector3::z();
        assert!((zl_w.dot(&zr_w).clamp(-1.0, 1.0).acos().to_degrees() - 2.0 * a).abs() < 1e-9);
    }
}

#[test]
fn jacobian_matches_finite_differences() {
    let r = robot();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for _ in 0..50 {
        let q = random_q(&r, &mut rng);
        let q4 = [q[0], q[1], q[2], 0.5 * (q[3] + q[4])];
        let (pose, jac) = r.ee_jacobian(&q4);
        assert!((pose.translation.vector - r.ee_pose_reduced(&q4).translation.vector).norm() < 1e-12);
        let h_deg = 1e-5;
        for col in 0..4 {
            let (mut qp, mut qm) = (q4, q4);
            qp[col] += h_deg;
            qm[col] -= h_deg;
            let (pp, pm) = (r.ee_pose_reduced(&qp), r.ee_pose_reduced(&qm));
            let h = 2.0 * h_deg.to_radians();
            let v = (pp.translation.vector - pm.translation.vector) / h;
            let w = (pp.rotation * pm.rotation.inverse()).scaled_axis() / h;
            let jv = jac.fixed_view::<3, 1>(0, col).into_owned();
            let jw = jac.fixed_view::<3, 1>(3, col).into_owned();
            assert!(
                (v - jv).norm() < 1e-5 * (1.0 + v.norm()),
                "col {col}: fd {v:?} vs {jv:?}"
            );
            assert!((w - jw).norm() < 1e-7, "col {col}: fd {w:?} vs {jw:?}");
        }
    }
}

#[test]
fn ik_round_trip_1000_random_configurations() {
    let r = robot();
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let opts = IkOptions::default();
    let mut worst_pos: f64 = 0.0;
    let mut worst_rot: f64 = 0.0;
    for i in 0..1000 {
        let q = random_q(&r, &mut rng);
        let target = r.fk(&q).ee;
        let sol = r
            .ik(&target, None, &opts)
            .unwrap_or_else(|e| panic!("config {i} {q:?}: {e}"));
        let reached = r.ee_pose_reduced(&sol.q_deg);
        let (dp, dr) = pose_error(&target, &reached);
        worst_pos = worst_pos.max(dp.norm());
        worst_rot = worst_rot.max(dr.norm());
        assert!(dp.norm() < 1e-6 && dr.norm() < 1e-6, "config {i}: {dp:?} {dr:?}");
        // The pose determines the configuration: IK recovers q (q_yaw for the jaws).
        let q_yaw = 0.5 * (q[3] + q[4]);
        for (j, want) in [q[0], q[1], q[2], q_yaw].iter().enumerate() {
            assert!(
                (sol.q_deg[j] - want).abs() < 1e-6,
                "config {i} joint {j}: {} vs {want}",
                sol.q_deg[j]
            );
        }
    }
    eprintln!("IK round trip worst: {worst_pos:.3e} mm, {worst_rot:.3e} rad");
}

#[test]
fn ik_reports_unreachable_poses() {
    let r = robot();
    let opts = IkOptions::default();
    // Far beyond the manipulator's length.
    let far = Isometry3::from_parts(Translation3::new(500.0, 0.0, 0.0), UnitQuaternion::identity());
    assert!(matches!(r.ik(&far, None, &opts), Err(IkError::NotConverged { .. })));
    // Right length, impossible orientation (tip pointing back at the base).
    let back = Isometry3::from_parts(
        Translation3::new(r.straight_length_mm(), 0.0, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
    );
    assert!(r.ik(&back, None, &opts).is_err());
    // Reachable only with q1 beyond its limit: refused as outside the limits.
    let mut cfg = r.config.clone();
    cfg.limits.q_max_deg[0] = 70.0;
    cfg.hinge.max_hinge_bend_deg = 10.0;
    let wide = Robot::new(cfg);
    let target = wide.fk(&[68.0, 0.0, 0.0, 0.0, 0.0]).ee;
    assert!(matches!(
        r.ik(&target, None, &opts),
        Err(IkError::OutsideLimits { joint: 1, .. })
    ));
    // NaN in, error out.
    let nan = Isometry3::from_parts(Translation3::new(f64::NAN, 0.0, 0.0), UnitQuaternion::identity());
    assert_eq!(r.ik(&nan, None, &opts).unwrap_err(), IkError::NotFinite);
}

#[test]
fn eq5_zero_at_straight_and_continuous() {
    let (h, n) = (0.5, 11.0);
    assert_eq!(eq5_hinge_chord_mm(0.0, 4.0, h, n), h);
    let r = robot();
    let w0 = r.cables().displacements_mm(&[0.0; N_JOINTS]);
    assert!(w0.iter().all(|w| *w == 0.0), "{w0:?}");
    // Continuity through θ = 0 for every cable and joint.
    for j in 0..N_JOINTS {
        let mut qp = [0.0; N_JOINTS];
        let mut qm = [0.0; N_JOINTS];
        qp[j] = 1e-7;
        qm[j] = -1e-7;
        let (wp, wm) = (r.cables().displacements_mm(&qp), r.cables().displacements_mm(&qm));
        for i in 0..10 {
            assert!((wp[i] - wm[i]).abs() < 1e-7, "cable {i} jumps at q{} = 0", j + 1);
        }
    }
}

#[test]
fn eq5_antagonistic_pairs_and_decoupling() {
    let r = robot();
    let pairs = *r.cables().pairs();
    for (j, (a, b)) in pairs.iter().enumerate() {
        let mut q = [0.0; N_JOINTS];
        q[j] = 20.0;
        let w = r.cables().displacements_mm(&q);
        assert!(
            w[*a] > 0.0 && w[*b] < 0.0,
            "joint {}: pair ({a},{b}) = {} {}",
            j + 1,
            w[*a],
            w[*b]
        );
        q[j] = -20.0;
        let w = r.cables().displacements_mm(&q);
        assert!(w[*a] < 0.0 && w[*b] > 0.0);
    }
    // Segment-1 pitch moves the segment-2 cables w5/w6 (decoupling), opposite ways.
    let w = r.cables().displacements_mm(&[30.0, 0.0, 0.0, 0.0, 0.0]);
    let (w5, w6) = (w[4], w[5]);
    assert!(w5 > 0.1 && w6 < -0.1, "w5 {w5} w6 {w6}");
    // … and a segment-1 bend alone does not move segment 2: inverse gives q3 = 0.
    let q = r.cables().joints_from_displacements(&w).unwrap();
    assert!(q[2].abs() < 1e-9 && (q[0] - 30.0).abs() < 1e-9, "{q:?}");
    // Small-angle check against the first-order lever: Δw ≈ offset · θ, up to the chord's
    // second-order term H·θ²/(24n), about 2e-6 of the lever at 0.1 deg.
    let w = r.cables().displacements_mm(&[0.1, 0.0, 0.0, 0.0, 0.0]);
    let lever = r.config.cables[0].offset_pitch_mm * 0.1f64.to_radians();
    assert!((w[0] - lever).abs() < 1e-5 * lever.abs(), "{} vs {lever}", w[0]);
    assert!((w[0] - lever).abs() > 0.0, "the second-order chord term is there");
}

#[test]
fn cable_inverse_of_forward_is_identity() {
    let r = robot();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for _ in 0..500 {
        let q = random_q(&r, &mut rng);
        let w = r.cables().displacements_mm(&q);
        let back = r.cables().joints_from_displacements(&w).unwrap();
        for j in 0..N_JOINTS {
            assert!((back[j] - q[j]).abs() < 1e-9, "{q:?} -> {back:?}");
        }
    }
    let mut w = r.cables().displacements_mm(&[1.0; N_JOINTS]);
    w[3] = f64::NAN;
    assert!(r.cables().joints_from_displacements(&w).is_err());
}

#[test]
fn limits_and_config_errors_name_the_field() {
    let r = robot();
    let err = r.check_limits(&[0.0, 0.0, 99.0, 0.0, 0.0]).unwrap_err().to_string();
    assert!(err.contains("q3") && err.contains("99"), "{err}");
    let err = r.check_limits(&[0.0, f64::NAN, 0.0, 0.0, 0.0]).unwrap_err().to_string();
    assert!(err.contains("q2"), "{err}");
    assert!(r.check_limits(&[0.0, 0.0, 0.0, 10.0, -10.0]).is_err(), "crossed jaws");
    let text = include_str!("../../../configs/robot.toml");
    let p = std::path::Path::new("robot.toml");
    let broken = text.replace("h_mm = 0.5", "h_mm = -0.5");
    let e = bowden_kinematics::RobotConfig::parse(&broken, p)
        .unwrap_err()
        .to_string();
    assert!(e.contains("robot.toml") && e.contains("hinge.h_mm"), "{e}");
    let e = bowden_kinematics::RobotConfig::parse("name = 3", p)
        .unwrap_err()
        .to_string();
    assert!(e.contains("robot.toml") && e.contains("malformed"), "{e}");
    let broken = text.replace("modules = 11", "modules = 11\nhinges = 3");
    assert!(
        bowden_kinematics::RobotConfig::parse(&broken, p).is_err(),
        "unknown fields are refused"
    );
    let e = bowden_kinematics::RobotConfig::load("/nonexistent/robot.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/robot.toml"), "{e}");
}

#[test]
fn marker_geometry_follows_the_jaws() {
    let r = robot();
    let g = bowden_kinematics::markers::MarkerGeometry::paper_default();
    let fk = r.fk(&[10.0, -5.0, 20.0, -15.0, 15.0]);
    let c = g.centres_base_mm(&fk);
    // Base markers do not move; jaw markers lie on their jaw's axis line, offset along x.
    assert_eq!(c[0], Point3::from(g.r0_base_mm));
    let local = fk.jaw_left.inverse() * c[3];
    assert!((local.coords - Vector3::from(g.r2_left_mm)).norm() < 1e-12);
    // r0→r1 and r1→b0 give the base frame's y and z axes (eq. 7), origin via L_base.
    let y = (c[1] - c[0]).normalize();
    let z = (c[2] - c[1]).normalize();
    assert!((y - Vector3::y()).norm() < 1e-12 && (z - Vector3::z()).norm() < 1e-12);
    let origin = Point3::from((c[0].coords + c[1].coords) * 0.5 + g.l_base_mm());
    assert!(origin.coords.norm() < 1e-12);
}

#[test]
fn position_ik_with_fixed_yaw_recovers_the_configuration() {
    let r = robot();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let opts = IkOptions::default();
    let mut recovered = 0;
    for _ in 0..300 {
        let q = random_q(&r, &mut rng);
        let q_yaw = 0.5 * (q[3] + q[4]);
        let p = Point3::from(r.fk(&q).ee.translation.vector);
        // From a start a few degrees off (as along a path) the point is reached exactly; the
        // pitch pair (q1, q3) can have two nearby roots, so the configuration may differ.
        let start = [q[0] + 3.0, q[1] - 3.0, q[2] + 3.0];
        if let Ok(sol) = r.ik_position(&p, q_yaw, start, &opts) {
            let reached = r.ee_pose_reduced(&sol.q_deg).translation.vector;
            assert!((reached - p.coords).norm() < 1e-6);
            assert_eq!(sol.q_deg[3], q_yaw);
            recovered += usize::from((0..3).all(|j| (sol.q_deg[j] - q[j]).abs() < 1e-6));
        }
        // The true configuration is a fixed point.
        let sol = r.ik_position(&p, q_yaw, [q[0], q[1], q[2]], &opts).expect("reachable");
        for j in 0..3 {
            assert!((sol.q_deg[j] - q[j]).abs() < 1e-9, "{:?} vs {q:?}", sol.q_deg);
        }
    }
    assert!(
        recovered >= 270,
        "only {recovered}/300 recovered from a 3-degree-off start"
    );
    let far = Point3::new(400.0, 0.0, 0.0);
    assert!(r.ik_position(&far, 0.0, [0.0; 3], &opts).is_err());
}

#[test]
fn commands_may_overlap_the_jaws_by_the_command_bound_only() {
    let text = include_str!("../../../configs/robot.toml");
    let p = std::path::Path::new("robot.toml");
    let with = |line: &str| {
        let t = text.replace("min_jaw_command_opening_deg = -30.0", line);
        bowden_kinematics::RobotConfig::parse(&t, p).map(Robot::new)
    };
    let r = with("min_jaw_command_opening_deg = -20.0").unwrap();
    let crossed = [0.0, 0.0, 0.0, 10.0, -5.0]; // opening −15°
    assert!(r.check_limits(&crossed).is_err(), "the jaws themselves may not cross");
    assert!(r.check_command_limits(&crossed).is_ok(), "a command may, down to −20°");
    let e = r
        .check_command_limits(&[0.0, 0.0, 0.0, 15.0, -10.0])
        .unwrap_err()
        .to_string();
    assert!(e.contains("-25") && e.contains("-20"), "{e}");
    // Clamping opens a command symmetrically to the command bound, a configuration to 0.
    let c = r.clamp_command_to_limits(&[0.0, 0.0, 0.0, 15.0, -15.0]);
    assert!(
        (c[4] - c[3] + 20.0).abs() < 1e-12 && (c[3] + c[4]).abs() < 1e-12,
        "{c:?}"
    );
    let c = r.clamp_to_limits(&[0.0, 0.0, 0.0, 15.0, -15.0]);
    assert!((c[4] - c[3]).abs() < 1e-12, "{c:?}");
    assert_eq!(r.clamp_command_to_limits(&crossed), crossed);
    // Without the line a command obeys the physical bound (no overlap).
    let r = with("").unwrap();
    assert!(r.check_command_limits(&crossed).is_err());
    // A command bound above the physical one would forbid configurations the jaws can take.
    let e = with("min_jaw_command_opening_deg = 5.0").err().unwrap().to_string();
    assert!(e.contains("min_jaw_command_opening_deg"), "{e}");
    let e = with("min_jaw_command_opening_deg = nan").err().unwrap().to_string();
    assert!(e.contains("min_jaw_command_opening_deg"), "{e}");
}
