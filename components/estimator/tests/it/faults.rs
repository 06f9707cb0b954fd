//! Ground truth from the synthetic camera, then occlusion and bad data injected into the
//! frame: each case gives the documented flags, never a silently wrong number, never a panic.

#![allow(clippy::needless_range_loop)]

use crate::common;

use bowden_estimator::{EstimatorError, FitFailure, MarkerStatus};
use bowden_interfaces::{marker, JointEstimate, MarkerSet};
use common::{fingerprint, marker_pixels, paint_out_marker, render, Frame, Q_ALL_VISIBLE};
use rand::{Rng, SeedableRng};

fn run(est: &mut bowden_estimator::Estimator, f: &Frame, hint: Option<[f64; 5]>) -> (MarkerSet, JointEstimate) {
    let (mut ms, mut je) = (MarkerSet::default(), JointEstimate::default());
    est.estimate(&f.header, &f.rgb, &f.depth, hint, &mut ms, &mut je)
        .expect("usable frame");
    (ms, je)
}

fn centre_error(ms: &MarkerSet, f: &Frame, m: usize) -> f64 {
    let c = ms.centre_cam_mm[m];
    ((c[0] - f.truth[m].x).powi(2) + (c[1] - f.truth[m].y).powi(2) + (c[2] - f.truth[m].z).powi(2)).sqrt()
}

fn assert_joints_within(je: &JointEstimate, q: &[f64; 5], tol_deg: f64) {
    for k in 0..5 {
        if je.joint_valid_mask & (1 << k) != 0 {
            let e = (je.q_phy_deg[k] - q[k]).abs();
            assert!(
                e <= tol_deg,
                "q{} reported {} for truth {} (error {e:.2} deg)",
                k + 1,
                je.q_phy_deg[k],
                q[k]
            );
        } else {
            assert!(
                je.q_phy_deg[k].is_nan(),
                "q{} is not valid but reads {}",
                k + 1,
                je.q_phy_deg[k]
            );
        }
    }
}

#[test]
fn clean_frame_is_fully_valid_and_accurate() {
    let mut cam = common::camera(5);
    let f = render(&mut cam, &Q_ALL_VISIBLE, 0);
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, None);
    assert_eq!(ms.valid_mask, 0x7f, "{:?}", est.diagnostics().marker_status);
    for m in 0..7 {
        assert!(
            centre_error(&ms, &f, m) < 0.3,
            "{}: {} mm",
            marker::NAMES[m],
            centre_error(&ms, &f, m)
        );
        assert!(ms.inliers[m] > 0 && ms.residual_mm[m].is_finite());
    }
    assert_eq!(je.quality, JointEstimate::QUALITY_VALID);
    assert_eq!(je.joint_valid_mask, 0b11111);
    assert_eq!(je.n_joints, 5);
    assert_joints_within(&je, &Q_ALL_VISIBLE, 1.0);
    // The measured end-effector pose is there, and FK of the estimate is near it.
    assert!(je.ee_pos_base_mm.iter().all(|v| v.is_finite()));
    assert!(je.ik_residual_pos_mm < 1.0 && je.ik_residual_rot_deg < 3.0, "{je:?}");
    assert_eq!(je.frame_seq, f.header.header.seq);
    // The same pipeline without the joint-space fit is the paper's (eq. 6–14 + IK).
    let q_paper = est.diagnostics().q_paper_deg;
    for k in 0..5 {
        assert!((q_paper[k] - Q_ALL_VISIBLE[k]).abs() < 3.0, "paper path {q_paper:?}");
    }
}

#[test]
fn one_jaw_marker_hidden_still_gives_every_joint() {
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 1);
    paint_out_marker(&mut f, cam.labels(), marker::RIGHT_G0);
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, Some([5.0, -5.0, 30.0, -10.0, 10.0]));
    assert_eq!(ms.valid_mask, 0x7f & !(1 << marker::RIGHT_G0));
    assert_eq!(
        est.diagnostics().marker_status[marker::RIGHT_G0],
        MarkerStatus::NotFound
    );
    assert!(ms.centre_cam_mm[marker::RIGHT_G0][0].is_nan() && ms.inliers[marker::RIGHT_G0] == 0);
    // Three jaw spheres determine all five joints (y0 sits 8.5 mm out on the right jaw).
    assert_eq!(
        je.quality,
        JointEstimate::QUALITY_VALID,
        "sd {:?}",
        est.diagnostics().joint_sigma_deg
    );
    assert_joints_within(&je, &Q_ALL_VISIBLE, 1.5);
    // Eq. 8–14 need all four jaw spheres: no paper estimate, no measured end-effector.
    assert!(est.diagnostics().q_paper_deg.iter().all(|v| v.is_nan()));
    assert!(je.ee_pos_base_mm.iter().all(|v| v.is_nan()));
}

#[test]
fn hidden_right_jaw_gives_a_partial_estimate() {
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 2);
    paint_out_marker(&mut f, cam.labels(), marker::RIGHT_Y0);
    paint_out_marker(&mut f, cam.labels(), marker::RIGHT_G0);
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    assert_eq!(ms.valid_mask, 0b0011111);
    // Base + left jaw: q1..q3, and the left jaw's q4 unless a second configuration explains
    // the two spheres as well (then it is withheld as ambiguous); q5 is not observable.
    assert_eq!(je.quality, JointEstimate::QUALITY_PARTIAL);
    assert_eq!(je.joint_valid_mask & 0b00111, 0b00111);
    assert_eq!(je.joint_valid_mask & 0b10000, 0);
    let d = est.diagnostics();
    assert!(d.joint_sigma_deg[4].is_infinite());
    assert!(
        je.joint_valid_mask & 0b01000 != 0 || d.ambiguous_joints & 0b01000 != 0,
        "{je:?} {d:?}"
    );
    assert_joints_within(&je, &Q_ALL_VISIBLE, 1.5);
}

#[test]
fn hidden_base_marker_invalidates_every_joint() {
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 3);
    paint_out_marker(&mut f, cam.labels(), marker::BASE_R1);
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    assert_eq!(ms.valid_mask & (1 << marker::BASE_R1), 0);
    // The remaining large red sphere is still identified as r0 (by its distance to b0).
    assert_ne!(ms.valid_mask & (1 << marker::BASE_R0), 0);
    assert!(centre_error(&ms, &f, marker::BASE_R0) < 0.3);
    assert_eq!(je.quality, JointEstimate::QUALITY_INVALID);
    assert_eq!(je.joint_valid_mask, 0);
    assert!(je.q_phy_deg[..5].iter().all(|v| v.is_nan()));
    assert!(est.diagnostics().base_in_camera.is_none());
}

#[test]
fn frame_without_markers() {
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 4);
    for m in 0..7 {
        paint_out_marker(&mut f, cam.labels(), m);
    }
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    assert_eq!(ms.valid_mask, 0);
    assert!(est
        .diagnostics()
        .marker_status
        .iter()
        .all(|s| *s == MarkerStatus::NotFound));
    assert!(ms.centre_cam_mm.iter().flatten().all(|v| v.is_nan()));
    assert_eq!(je.quality, JointEstimate::QUALITY_INVALID);
    assert!(je.q_phy_deg[..5].iter().all(|v| v.is_nan()));
    // An all-black frame (a camera that delivers nothing) is a frame without markers too.
    let blank = Frame {
        rgb: vec![0; f.rgb.len()],
        depth: vec![0; f.depth.len()],
        ..f
    };
    let (ms, je) = run(&mut est, &blank, None);
    assert_eq!((ms.valid_mask, je.quality), (0, JointEstimate::QUALITY_INVALID));
}

#[test]
fn frame_without_depth() {
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 5);
    f.depth.fill(0);
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, None);
    assert_eq!(ms.valid_mask, 0);
    for s in est.diagnostics().marker_status {
        assert_eq!(
            s,
            MarkerStatus::NotFound,
            "a component without depth is not a candidate"
        );
    }
    assert_eq!(je.quality, JointEstimate::QUALITY_INVALID);
}

#[test]
fn garbage_depth_on_a_marker_is_refused() {
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 6);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    for i in marker_pixels(cam.labels(), marker::LEFT_R2) {
        f.depth[i] = rng.random_range(150..400);
    }
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    assert_eq!(ms.valid_mask & (1 << marker::LEFT_R2), 0, "r2 accepted on random depth");
    assert!(ms.centre_cam_mm[marker::LEFT_R2][0].is_nan());
    // No sphere in the depth; the intact colour outline still gives the line of sight
    // (or nothing at all), never a centre.
    assert!(
        matches!(
            est.diagnostics().marker_status[marker::LEFT_R2],
            MarkerStatus::FitFailed(_) | MarkerStatus::DirectionOnly
        ),
        "{:?}",
        est.diagnostics().marker_status[marker::LEFT_R2]
    );
    // Whatever is still reported is right.
    assert_ne!(je.joint_valid_mask, 0);
    assert_joints_within(&je, &Q_ALL_VISIBLE, 2.0);
}

#[test]
fn plausible_but_wrong_depth_is_caught_by_the_robot_model() {
    // y0's depth shifted 15 mm back: a clean sphere, in the wrong place. Its centre alone
    // cannot be refused; the four jaw centres together do not fit the robot, and leaving y0
    // out does.
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 7);
    for i in marker_pixels(cam.labels(), marker::RIGHT_Y0) {
        if f.depth[i] != 0 {
            f.depth[i] += 15;
        }
    }
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    let d = est.diagnostics();
    assert_eq!(d.left_out_marker, Some(marker::RIGHT_Y0), "{:?}", d.marker_status);
    assert_eq!(d.marker_status[marker::RIGHT_Y0], MarkerStatus::Inconsistent);
    assert_eq!(ms.valid_mask & (1 << marker::RIGHT_Y0), 0);
    assert!(ms.centre_cam_mm[marker::RIGHT_Y0][0].is_nan());
    assert_joints_within(&je, &Q_ALL_VISIBLE, 1.5);
}

#[test]
fn a_distractor_blob_is_not_taken_for_a_marker() {
    // A red sticker on the background, larger in the image than r2.
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 8);
    let w = f.header.width as i64;
    let (u0, v0) = (60i64, 400i64);
    for dv in -7..=7i64 {
        for du in -7..=7i64 {
            if du * du + dv * dv <= 49 {
                let i = ((v0 + dv) * w + u0 + du) as usize;
                f.rgb[3 * i..3 * i + 3].copy_from_slice(&[190, 25, 30]);
            }
        }
    }
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, None);
    // The sticker is a component of its own (8 in all), and it was not taken.
    assert_eq!(est.diagnostics().blobs, 8);
    assert_eq!(ms.valid_mask, 0x7f);
    assert!(centre_error(&ms, &f, marker::LEFT_R2) < 0.3);
    assert_eq!(je.quality, JointEstimate::QUALITY_VALID);
    assert_joints_within(&je, &Q_ALL_VISIBLE, 1.0);
}

#[test]
fn unusable_frames_are_errors_and_leave_no_stale_output() {
    let mut cam = common::camera(5);
    let f = render(&mut cam, &Q_ALL_VISIBLE, 9);
    let mut est = common::estimator();
    let (mut ms, mut je) = run(&mut est, &f, None);
    assert_eq!(je.quality, JointEstimate::QUALITY_VALID);

    // RGB plane one row short.
    let short = &f.rgb[..f.rgb.len() - 3 * 640];
    let e = est
        .estimate(&f.header, short, &f.depth, None, &mut ms, &mut je)
        .unwrap_err();
    assert!(matches!(e, EstimatorError::FrameSize { plane: "rgb plane", .. }), "{e}");
    assert!(e.to_string().contains("640x480"), "{e}");
    assert_eq!(
        (ms.valid_mask, je.quality),
        (0, JointEstimate::QUALITY_INVALID),
        "stale outputs after an error"
    );
    assert!(je.q_phy_deg[..5].iter().all(|v| v.is_nan()));
    assert!(est
        .diagnostics()
        .marker_status
        .iter()
        .all(|s| *s == MarkerStatus::BadFrame));

    // Depth plane too long.
    let mut long = f.depth.clone();
    long.push(0);
    let e = est
        .estimate(&f.header, &f.rgb, &long, None, &mut ms, &mut je)
        .unwrap_err();
    assert!(
        matches!(
            e,
            EstimatorError::FrameSize {
                plane: "depth plane",
                ..
            }
        ),
        "{e}"
    );

    // Header fields.
    type Corrupt = fn(&mut bowden_interfaces::RgbdFrameHeader);
    let cases: [(&str, Corrupt); 6] = [
        ("fx", |h| h.fx = f64::NAN),
        ("fy", |h| h.fy = -615.0),
        ("cx", |h| h.cx = f64::INFINITY),
        ("depth_unit_mm", |h| h.depth_unit_mm = 0.0),
        ("width", |h| h.width = 0),
        ("height", |h| h.height = 100_000),
    ];
    for (field, corrupt) in cases {
        let mut h = f.header;
        corrupt(&mut h);
        let e = est.estimate(&h, &f.rgb, &f.depth, None, &mut ms, &mut je).unwrap_err();
        assert!(
            matches!(e, EstimatorError::BadHeader { field: fl, .. } if fl == field),
            "{field}: {e}"
        );
        assert_eq!(je.quality, JointEstimate::QUALITY_INVALID);
    }
    // A header that disagrees with the buffers (a 320x240 claim on a 640x480 frame).
    let mut h = f.header;
    h.width = 320;
    h.height = 240;
    assert!(matches!(
        est.estimate(&h, &f.rgb, &f.depth, None, &mut ms, &mut je),
        Err(EstimatorError::FrameSize { .. })
    ));
    // And the estimator is still fine afterwards.
    let (_, je) = run(&mut est, &f, None);
    assert_eq!(je.quality, JointEstimate::QUALITY_VALID);
}

#[test]
fn payload_layout_checks_and_equivalence() {
    let mut cam = common::camera(5);
    let f = render(&mut cam, &Q_ALL_VISIBLE, 10);
    let mut payload = vec![0u8; cam.payload_len()];
    cam.render_into_payload(&Q_ALL_VISIBLE, 10, &mut payload).unwrap();
    let mut est = common::estimator();
    let (ms_a, je_a) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    let (mut ms_b, mut je_b) = (MarkerSet::default(), JointEstimate::default());
    est.estimate_payload(&f.header, &payload, Some(Q_ALL_VISIBLE), &mut ms_b, &mut je_b)
        .unwrap();
    assert_eq!(fingerprint(&ms_a, &je_a), fingerprint(&ms_b, &je_b));

    let e = est
        .estimate_payload(&f.header, &payload[1..], None, &mut ms_b, &mut je_b)
        .unwrap_err();
    assert!(matches!(e, EstimatorError::FrameSize { plane: "payload", .. }), "{e}");
    let mut h = f.header;
    h.depth_offset += 2;
    let e = est
        .estimate_payload(&h, &payload, None, &mut ms_b, &mut je_b)
        .unwrap_err();
    assert!(
        matches!(
            e,
            EstimatorError::BadHeader {
                field: "depth_offset",
                ..
            }
        ),
        "{e}"
    );
    let mut h = f.header;
    h.payload_len -= 1;
    let e = est
        .estimate_payload(&h, &payload, None, &mut ms_b, &mut je_b)
        .unwrap_err();
    assert!(
        matches!(
            e,
            EstimatorError::BadHeader {
                field: "payload_len",
                ..
            }
        ),
        "{e}"
    );
    assert_eq!(je_b.quality, JointEstimate::QUALITY_INVALID);
}

#[test]
fn deterministic_and_stateless() {
    let mut cam = common::camera(5);
    let a = render(&mut cam, &Q_ALL_VISIBLE, 11);
    let b = render(&mut cam, &[-30.0, 25.0, -15.0, -5.0, 35.0], 12);
    let hint = Some([0.0, 10.0, 0.0, 0.0, 20.0]);
    let mut e1 = common::estimator();
    let (ms1, je1) = run(&mut e1, &a, hint);
    // A second estimator, and the first one after another frame: identical bits.
    let mut e2 = common::estimator();
    let _ = run(&mut e2, &b, None);
    let (ms2, je2) = run(&mut e2, &a, hint);
    let _ = run(&mut e1, &b, hint);
    let (ms3, je3) = run(&mut e1, &a, hint);
    assert_eq!(fingerprint(&ms1, &je1), fingerprint(&ms2, &je2));
    assert_eq!(fingerprint(&ms1, &je1), fingerprint(&ms3, &je3));
    // A non-finite hint is ignored (as no hint).
    let (ms4, je4) = run(&mut e1, &a, Some([f64::NAN, 0.0, 0.0, 0.0, 0.0]));
    let (ms5, je5) = run(&mut e1, &a, None);
    assert_eq!(fingerprint(&ms4, &je4), fingerprint(&ms5, &je5));
}

#[test]
fn a_jaw_sphere_without_depth_contributes_its_line_of_sight() {
    // b1 keeps its colour but loses all depth except two readings.
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 13);
    let px = marker_pixels(cam.labels(), marker::LEFT_B1);
    for &i in &px {
        f.depth[i] = 0;
    }
    for &i in px.iter().skip(px.len() / 2).take(2) {
        f.depth[i] = f.truth[marker::LEFT_B1].z.round() as u16 - 1;
    }
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, None);
    // Not a measured centre…
    assert_eq!(ms.valid_mask, 0x7f & !(1 << marker::LEFT_B1));
    assert!(ms.centre_cam_mm[marker::LEFT_B1][0].is_nan());
    let status = est.diagnostics().marker_status[marker::LEFT_B1];
    assert_eq!(status, MarkerStatus::DirectionOnly);
    assert_eq!(status.label(), "direction only");
    // …but its line of sight, with a loose range, still helps determine every joint.
    let cov = est.diagnostics().centre_cov_cam_mm2[marker::LEFT_B1];
    let ev = cov.symmetric_eigenvalues();
    assert!(
        ev.max().sqrt() > 5.0 && ev.min().sqrt() < 0.2,
        "range and lateral SD {:?}",
        ev.map(f64::sqrt)
    );
    assert_eq!(je.quality, JointEstimate::QUALITY_VALID);
    assert_joints_within(&je, &Q_ALL_VISIBLE, 1.5);
}

#[test]
fn a_base_sphere_without_depth_is_not_guessed() {
    // The base frame needs true centres: b0 with two depth readings fails, naming why.
    let mut cam = common::camera(5);
    let mut f = render(&mut cam, &Q_ALL_VISIBLE, 14);
    let px = marker_pixels(cam.labels(), marker::BASE_B0);
    for &i in &px {
        f.depth[i] = 0;
    }
    for &i in px.iter().skip(px.len() / 2).take(2) {
        f.depth[i] = f.truth[marker::BASE_B0].z.round() as u16 - 4;
    }
    let mut est = common::estimator();
    let (ms, je) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    let status = est.diagnostics().marker_status[marker::BASE_B0];
    assert!(
        matches!(
            status,
            MarkerStatus::FitFailed(FitFailure::TooFewPoints { points: 2, .. })
        ),
        "{status:?}"
    );
    assert_eq!(status.label(), "too few depth points");
    assert_eq!(ms.valid_mask & (1 << marker::BASE_B0), 0);
    // Without b0, r0 and r1 cannot be told apart either.
    assert_eq!(
        est.diagnostics().marker_status[marker::BASE_R0],
        MarkerStatus::Ambiguous
    );
    assert_eq!(je.quality, JointEstimate::QUALITY_INVALID);
    assert!(je.q_phy_deg[..5].iter().all(|v| v.is_nan()));
}

#[test]
fn paper_path_alone_when_refinement_is_off() {
    use bowden_estimator::{Estimator, EstimatorConfig};
    use bowden_kinematics::{markers::MarkerGeometry, Robot};
    let mut cam = common::camera(5);
    let f = render(&mut cam, &Q_ALL_VISIBLE, 15);
    let mut cfg = EstimatorConfig::paper_default();
    cfg.estimator.refine_joints = false;
    let mut est = Estimator::new(Robot::paper_default(), MarkerGeometry::paper_default(), cfg);
    let (_, je) = run(&mut est, &f, Some(Q_ALL_VISIBLE));
    assert_eq!(je.quality, JointEstimate::QUALITY_VALID);
    // What is reported is exactly eq. 6–14 + IK + q4/q5 from θ.
    assert_eq!(&je.q_phy_deg[..5], &est.diagnostics().q_paper_deg[..]);
    assert_joints_within(&je, &Q_ALL_VISIBLE, 3.0);
    // It needs all four jaw spheres: with one hidden, nothing is reported.
    let mut g = render(&mut cam, &Q_ALL_VISIBLE, 16);
    paint_out_marker(&mut g, cam.labels(), marker::RIGHT_G0);
    let (_, je) = run(&mut est, &g, Some(Q_ALL_VISIBLE));
    assert_eq!(je.quality, JointEstimate::QUALITY_INVALID);
}

#[test]
fn two_near_axis_spheres_are_ambiguous_and_withheld() {
    // Only b1 and g0 (each 2.5 mm out along its jaw) are seen: they fix the pivot's position
    // but hardly its orientation, and two splits of the bend between q1 and q3 reach it.
    let q = [-49.8, -55.2, -34.7, -36.7, -31.2];
    let mut cam = common::camera(7);
    let mut f = render(&mut cam, &q, 17);
    paint_out_marker(&mut f, cam.labels(), marker::LEFT_R2);
    paint_out_marker(&mut f, cam.labels(), marker::RIGHT_Y0);
    let mut est = common::estimator();
    for hint in [None, Some(q)] {
        let (ms, je) = run(&mut est, &f, hint);
        assert_eq!(ms.valid_mask & ((1 << marker::LEFT_R2) | (1 << marker::RIGHT_Y0)), 0);
        let d = est.diagnostics();
        assert_ne!(d.ambiguous_joints & 0b101, 0, "q1/q3 not flagged: {je:?}");
        assert_eq!(je.joint_valid_mask & d.ambiguous_joints, 0);
        assert_ne!(je.quality, JointEstimate::QUALITY_VALID);
        assert_joints_within(&je, &q, 2.0);
    }
}
