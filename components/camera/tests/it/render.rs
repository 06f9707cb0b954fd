//! Rendering tests: determinism, geometry against ground truth, visibility of every marker
//! over the workspace, the sensor model, and rejection of bad input.

use bowden_camera::noise::gauss_table_max_sigma;
use bowden_camera::{label, CameraConfig, CameraError, SyntheticCamera};
use bowden_interfaces::{marker, N_MARKERS};
use bowden_kinematics::{markers::MarkerGeometry, JointsDeg, Robot};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn camera(cfg: CameraConfig, seed: u64) -> SyntheticCamera {
    SyntheticCamera::new(Robot::paper_default(), MarkerGeometry::paper_default(), cfg, seed)
}

struct Frame {
    rgb: Vec<u8>,
    depth: Vec<u16>,
}

fn render(cam: &mut SyntheticCamera, q: &JointsDeg, index: u64) -> Frame {
    let px = (cam.width() * cam.height()) as usize;
    let mut f = Frame {
        rgb: vec![0; px * 3],
        depth: vec![0; px],
    };
    cam.render(q, index, &mut f.rgb, &mut f.depth).expect("render");
    f
}

/// Seeded configurations inside the joint limits (jaws never crossed).
fn workspace(n: usize, seed: u64) -> Vec<JointsDeg> {
    let robot = Robot::paper_default();
    let lim = &robot.config.limits;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let mut q = [0.0; 5];
            for (j, v) in q.iter_mut().enumerate() {
                *v = rng.random_range(lim.q_min_deg[j]..=lim.q_max_deg[j]);
            }
            if q[4] < q[3] {
                q.swap(3, 4);
            }
            q
        })
        .collect()
}

const Q_A: JointsDeg = [25.0, -15.0, 30.0, -20.0, 10.0];

#[test]
fn same_seed_and_frame_give_identical_bytes_whatever_was_rendered_before() {
    let cfg = CameraConfig::paper_default();
    let mut a = camera(cfg, 11);
    let mut b = camera(cfg, 11);
    // `a` renders other frames and configurations first: frame 7 must not depend on them.
    for (k, q) in workspace(3, 5).iter().enumerate() {
        render(&mut a, q, k as u64);
    }
    let fa = render(&mut a, &Q_A, 7);
    let fb = render(&mut b, &Q_A, 7);
    assert!(fa.rgb == fb.rgb, "colour differs");
    assert!(fa.depth == fb.depth, "depth differs");
    // The noise really is per frame and per seed.
    let other_frame = render(&mut b, &Q_A, 8);
    assert!(other_frame.rgb != fa.rgb && other_frame.depth != fa.depth);
    let other_seed = render(&mut camera(cfg, 12), &Q_A, 7);
    assert!(other_seed.rgb != fa.rgb && other_seed.depth != fa.depth);
}

#[test]
fn payload_matches_separate_buffers_and_header_describes_it() {
    let mut cam = camera(CameraConfig::paper_default(), 3);
    let f = render(&mut cam, &Q_A, 4);
    let mut payload = vec![0u8; cam.payload_len()];
    cam.render_into_payload(&Q_A, 4, &mut payload).expect("payload");
    let h = cam.header(9, 10, 11);
    assert_eq!((h.header.seq, h.header.tick, h.header.t_origin_ns), (9, 10, 11));
    assert_eq!((h.width, h.height), (640, 480));
    assert_eq!(h.payload_len as usize, payload.len());
    let off = h.depth_offset as usize;
    assert_eq!(&payload[..off], &f.rgb[..]);
    let depth: Vec<u16> = payload[off..]
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    assert_eq!(depth, f.depth);
    assert_eq!(
        (h.fx, h.fy, h.cx, h.cy, h.depth_unit_mm),
        (615.0, 615.0, 320.0, 240.0, 1.0)
    );
}

#[test]
fn ground_truth_pose_agrees_with_eq7_on_the_base_spheres() {
    let cam = camera(CameraConfig::paper_default(), 0);
    let m = MarkerGeometry::paper_default();
    let c = cam.marker_centres_cam_mm(&Q_A);
    let t = cam.base_in_camera();
    // Eq. (7): y_B = r0→r1, z_B = r1→b0, x_B = y_B × z_B, p = (r0 + r1)/2 + R·L_base.
    let y = (c[marker::BASE_R1] - c[marker::BASE_R0]).normalize();
    let z = (c[marker::BASE_B0] - c[marker::BASE_R1]).normalize();
    let x = y.cross(&z);
    let r = t.rotation.to_rotation_matrix();
    for (axis, want) in [(x, r * Vector3::x()), (y, r * Vector3::y()), (z, r * Vector3::z())] {
        assert!((axis - want).norm() < 1e-9, "{axis:?} vs {want:?}");
    }
    let p = (c[marker::BASE_R0].coords + c[marker::BASE_R1].coords) * 0.5 + r * m.l_base_mm();
    assert!((p - t.translation.vector).norm() < 1e-9);
}

/// Every marker pixel with depth back-projects onto its sphere: within the noise bound (the
/// Gaussian table is cut at ±3.49σ) plus half a depth count, stretched along the ray.
#[test]
fn sphere_pixels_back_project_onto_their_sphere_within_noise() {
    let cfg = CameraConfig::paper_default();
    let mut cam = camera(cfg, 21);
    let k = *cam.intrinsics();
    let d = cfg.depth;
    let radii = MarkerGeometry::paper_default().radii_mm();
    let mut checked = [0usize; N_MARKERS];
    for (f, q) in [Q_A, [0.0; 5], [-40.0, 30.0, -20.0, 0.0, 40.0]].iter().enumerate() {
        let frame = render(&mut cam, q, f as u64);
        let centres = cam.marker_centres_cam_mm(q);
        let mut signed_sum = [0.0f64; N_MARKERS];
        let mut n = [0usize; N_MARKERS];
        for (i, &l) in cam.labels().iter().enumerate() {
            let m = (l & label::WHAT_MASK).wrapping_sub(label::MARKER0) as usize;
            if m >= N_MARKERS || frame.depth[i] == 0 {
                continue;
            }
            let (u, v) = ((i % 640) as f64, (i / 640) as f64);
            let z = frame.depth[i] as f64 * d.unit_mm;
            let p = k.back_project(u, v, z);
            let ray_stretch = Vector3::new((u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px, 1.0).norm();
            let sigma = d.noise_floor_mm + d.noise_coeff_per_mm * z * z;
            let bound = (gauss_table_max_sigma() * sigma * 1.01 + 0.5 * d.unit_mm) * ray_stretch + 1e-3;
            let err = (p - centres[m]).norm() - radii[m];
            assert!(
                err.abs() <= bound,
                "{} at ({u}, {v}): {err:.3} mm off the sphere, bound {bound:.3}",
                marker::NAMES[m]
            );
            signed_sum[m] += err;
            n[m] += 1;
        }
        for m in 0..N_MARKERS {
            if n[m] > 10 {
                // No systematic bias (quantisation and noise average out).
                let mean = signed_sum[m] / n[m] as f64;
                assert!(mean.abs() < 0.35, "{} mean error {mean:.3} mm", marker::NAMES[m]);
            }
            checked[m] += n[m];
        }
    }
    assert!(checked.iter().all(|&n| n > 20), "too few pixels checked: {checked:?}");
}

/// The whole workspace and the base spheres stay inside the frame; the base spheres are
/// always well visible; the jaw spheres are visible with enough depth pixels for a sphere
/// fit in the large majority of configurations. Not in all: each jaw's two spheres lie 6 mm
/// apart along the jaw (eq. 9 needs them there), so whenever a jaw points within ~42° of
/// the viewing ray one hides the other, and with large bends the body can hide the jaws.
/// No single camera pose avoids that over the whole joint box (see
/// `examples/camera_pose_search.rs`); the estimator must flag such frames.
#[test]
fn every_marker_is_visible_over_seeded_workspace_configurations() {
    let cfg = CameraConfig::paper_default();
    let mut cam = camera(cfg, 2);
    let k = *cam.intrinsics();
    let radii = MarkerGeometry::paper_default().radii_mm();
    let qs = workspace(150, 77);
    const ENOUGH: usize = 12;
    let mut counts: Vec<[usize; N_MARKERS]> = Vec::new();
    let mut min_diameter_px = f64::MAX;
    for (f, q) in qs.iter().enumerate() {
        for (m, c) in cam.marker_centres_cam_mm(q).iter().enumerate() {
            let (u, v) = k.project(c).expect("marker in front of the camera");
            let r_px = radii[m] * k.fx_px / c.z;
            min_diameter_px = min_diameter_px.min(2.0 * r_px);
            assert!(
                u - r_px >= 0.0 && u + r_px <= 639.0 && v - r_px >= 0.0 && v + r_px <= 479.0,
                "{} leaves the image at q = {q:?}: ({u:.1}, {v:.1})",
                marker::NAMES[m]
            );
            assert!(
                c.z - radii[m] > cfg.depth.min_mm,
                "{} closer than the minimum range",
                marker::NAMES[m]
            );
        }
        let frame = render(&mut cam, q, f as u64);
        let mut count = [0usize; N_MARKERS];
        for (i, &l) in cam.labels().iter().enumerate() {
            let m = (l & label::WHAT_MASK).wrapping_sub(label::MARKER0) as usize;
            if m < N_MARKERS && frame.depth[i] > 0 {
                count[m] += 1;
            }
        }
        counts.push(count);
    }
    let n = qs.len() as f64;
    println!(
        "marker depth pixels over {} seeded configurations (min / p5 / median, share with ≥ {ENOUGH}):",
        qs.len()
    );
    let mut shares = [0.0; N_MARKERS];
    for m in 0..N_MARKERS {
        let mut c: Vec<usize> = counts.iter().map(|x| x[m]).collect();
        c.sort_unstable();
        shares[m] = c.iter().filter(|&&x| x >= ENOUGH).count() as f64 / n;
        println!(
            "  {:<3} {:5} {:5} {:5}   {:5.1} %",
            marker::NAMES[m],
            c[0],
            c[c.len() / 20],
            c[c.len() / 2],
            100.0 * shares[m]
        );
    }
    let all_seven = counts.iter().filter(|x| x.iter().all(|&c| c >= ENOUGH)).count() as f64 / n;
    println!(
        "  all seven ≥ {ENOUGH}: {:.1} %; smallest marker diameter {min_diameter_px:.1} px",
        100.0 * all_seven
    );
    for m in [marker::BASE_R0, marker::BASE_R1, marker::BASE_B0] {
        let min = counts.iter().map(|x| x[m]).min().unwrap_or(0);
        assert!(
            min >= 300,
            "base sphere {} down to {min} depth pixels",
            marker::NAMES[m]
        );
    }
    for m in [marker::LEFT_R2, marker::LEFT_B1, marker::RIGHT_Y0, marker::RIGHT_G0] {
        assert!(
            shares[m] >= 0.90,
            "{} usable in only {:.1} % of frames",
            marker::NAMES[m],
            100.0 * shares[m]
        );
    }
    assert!(
        all_seven >= 0.85,
        "all markers usable in only {:.1} % of frames",
        100.0 * all_seven
    );
    assert!(
        min_diameter_px >= 11.0,
        "jaw spheres only {min_diameter_px:.1} px across"
    );
    // In the neutral pose and moderate bends no marker is hidden at all.
    for (f, q) in [
        [0.0; 5],
        [20.0, 20.0, 20.0, -15.0, 15.0],
        [-20.0, -20.0, -20.0, -15.0, 15.0],
    ]
    .iter()
    .enumerate()
    {
        let frame = render(&mut cam, q, f as u64);
        for m in 0..N_MARKERS {
            let c = cam
                .labels()
                .iter()
                .zip(&frame.depth)
                .filter(|(l, d)| **l & label::WHAT_MASK == label::marker(m) && **d > 0)
                .count();
            assert!(c >= 40, "{} has {c} depth pixels at q = {q:?}", marker::NAMES[m]);
        }
    }
}

#[test]
fn depth_is_missing_on_sphere_silhouettes_and_in_the_stereo_shadow() {
    let cfg = CameraConfig::paper_default();
    let mut cam = camera(cfg, 5);
    let q = [0.0; 5];
    let frame = render(&mut cam, &q, 0);
    let labels = cam.labels().to_vec();
    let what = |i: usize| labels[i] & label::WHAT_MASK;
    // Every marker pixel next to the background (a depth jump) has no depth.
    let mut rim = 0;
    for v in 1..479 {
        for u in 1..639 {
            let i = v * 640 + u;
            let m = what(i).wrapping_sub(label::MARKER0) as usize;
            if m >= N_MARKERS {
                continue;
            }
            if [i - 1, i + 1, i - 640, i + 640]
                .iter()
                .any(|&n| what(n) == label::BACKGROUND)
            {
                rim += 1;
                assert_eq!(
                    frame.depth[i],
                    0,
                    "silhouette pixel ({u}, {v}) of {} has depth",
                    marker::NAMES[m]
                );
            }
        }
    }
    assert!(rim > 50, "only {rim} silhouette pixels");
    // Stereo shadow: left of base sphere r0, along its centre row, the background has no depth
    // over about f·B·(1/z_sphere − 1/z_background) pixels; right of it, it has.
    let c = cam.marker_centres_cam_mm(&q)[marker::BASE_R0];
    let (u0, v0) = cam.intrinsics().project(&c).expect("r0 in view");
    let row = v0.round() as usize * 640;
    let left_edge = (0..640)
        .find(|&u| what(row + u) == label::marker(marker::BASE_R0))
        .expect("r0 on its row");
    let mut shadow = 0;
    let mut u = left_edge;
    while u > 0 && what(row + u - 1) == label::BACKGROUND && frame.depth[row + u - 1] == 0 {
        shadow += 1;
        u -= 1;
    }
    // Background depth just outside the shadow, from the pixel left of it.
    let z_bg = frame.depth[row + u - 1] as f64;
    assert!(z_bg > 0.0, "background left of the shadow has depth");
    let expect = 615.0 * 50.0 * (1.0 / (c.z - 5.0) - 1.0 / z_bg);
    assert!(
        (shadow as f64 - expect).abs() <= 4.0 + 0.1 * expect,
        "shadow {shadow} px, expected ≈ {expect:.1}"
    );
    let right = (u0 + 18.0) as usize;
    assert!(
        what(row + right) == label::BACKGROUND && frame.depth[row + right] > 0,
        "no shadow on the right of r0"
    );
}

/// With a fine depth unit (quantisation negligible) the depth noise divided by σ(Z) =
/// coeff·Z² is standard normal over the frame: it grows with the square of the distance.
#[test]
fn depth_noise_grows_with_distance_squared_and_colour_noise_has_its_sigma() {
    let mut cfg = CameraConfig::paper_default();
    cfg.depth.unit_mm = 0.01;
    cfg.depth.max_mm = 600.0;
    cfg.depth.dropout_prob = 0.0;
    let mut clean_cfg = cfg;
    clean_cfg.depth.noise_coeff_per_mm = 0.0;
    clean_cfg.color.read_noise_dn = 0.0;
    clean_cfg.color.shot_noise_gain_dn = 0.0;
    let noisy = render(&mut camera(cfg, 9), &Q_A, 3);
    let clean = render(&mut camera(clean_cfg, 9), &Q_A, 3);
    let (mut near, mut far) = ((0.0, 0usize), (0.0, 0usize));
    let mut all = (0.0f64, 0.0f64, 0usize);
    for (a, b) in noisy.depth.iter().zip(&clean.depth) {
        if *a == 0 || *b == 0 {
            continue;
        }
        let z = *b as f64 * 0.01;
        let err = (*a as f64 - *b as f64) * 0.01;
        let s = err / (cfg.depth.noise_coeff_per_mm * z * z);
        all = (all.0 + s, all.1 + s * s, all.2 + 1);
        let bucket = if z < 230.0 { &mut near } else { &mut far };
        *bucket = (bucket.0 + err * err, bucket.1 + 1);
    }
    let mean = all.0 / all.2 as f64;
    let sd = (all.1 / all.2 as f64 - mean * mean).sqrt();
    assert!(all.2 > 100_000, "{} depth pixels", all.2);
    assert!(mean.abs() < 0.01, "normalised mean {mean}");
    assert!((sd - 1.0).abs() < 0.03, "normalised sd {sd}");
    let rms = |b: (f64, usize)| (b.0 / b.1 as f64).sqrt();
    assert!(near.1 > 100 && far.1 > 100);
    assert!(rms(far) > rms(near) * 1.2, "far rms {} vs near {}", rms(far), rms(near));
    // Colour: σ² = read² + gain·value.
    let mut z2 = (0.0f64, 0usize);
    for (a, b) in noisy.rgb.iter().zip(&clean.rgb) {
        if *b == 0 || *b == 255 {
            continue;
        }
        let var = cfg.color.read_noise_dn.powi(2) + cfg.color.shot_noise_gain_dn * *b as f64;
        let e = *a as f64 - *b as f64;
        // Rounding to 8 bits adds 1/12 DN² of variance.
        z2 = (z2.0 + e * e / (var + 1.0 / 12.0), z2.1 + 1);
    }
    let ratio = z2.0 / z2.1 as f64;
    assert!((ratio - 1.0).abs() < 0.05, "colour noise variance ratio {ratio}");
}

#[test]
fn markers_have_their_colours() {
    let cfg = CameraConfig::paper_default();
    let mut cam = camera(cfg, 1);
    let f = render(&mut cam, &Q_A, 0);
    // Mean colour of each marker's pixels: the dominant channel is the marker's.
    for m in 0..N_MARKERS {
        let mut sum = [0.0f64; 3];
        let mut n = 0.0;
        for (i, &l) in cam.labels().iter().enumerate() {
            if l & label::WHAT_MASK == label::marker(m) {
                for (c, s) in sum.iter_mut().enumerate() {
                    *s += f.rgb[3 * i + c] as f64;
                }
                n += 1.0;
            }
        }
        assert!(n > 0.0, "{} not visible", marker::NAMES[m]);
        let [r, g, b] = sum.map(|s| s / n);
        let ok = match marker::NAMES[m] {
            "r0" | "r1" | "r2" => r > 2.0 * g && r > 2.0 * b,
            "b0" | "b1" => b > 2.0 * r && b > 1.5 * g,
            "y0" => r > 2.0 * b && g > 2.0 * b,
            "g0" => g > 1.5 * r && g > 1.5 * b,
            _ => false,
        };
        assert!(ok, "{} has mean colour ({r:.0}, {g:.0}, {b:.0})", marker::NAMES[m]);
    }
}

#[test]
fn bad_inputs_are_rejected_with_what_and_where() {
    let mut cam = camera(CameraConfig::paper_default(), 0);
    let px = 640 * 480;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let before = render(&mut cam, &Q_A, 0);
    for (j, bad) in [(1, f64::NAN), (3, f64::INFINITY), (5, f64::NEG_INFINITY)] {
        let mut q = Q_A;
        q[j - 1] = bad;
        match cam.render(&q, 0, &mut rgb, &mut depth) {
            Err(CameraError::NonFiniteJoint { joint, .. }) => assert_eq!(joint, j),
            other => panic!("q{j} = {bad}: {other:?}"),
        }
        let mut payload = vec![0u8; px * 5];
        assert!(matches!(
            cam.render_into_payload(&q, 0, &mut payload),
            Err(CameraError::NonFiniteJoint { .. })
        ));
    }
    let mut short = vec![0u8; px * 3 - 1];
    match cam.render(&Q_A, 0, &mut short, &mut depth) {
        Err(e @ CameraError::BufferSize { buffer: "rgb", .. }) => {
            assert!(e.to_string().contains("921599"), "{e}")
        }
        other => panic!("{other:?}"),
    }
    let mut long_depth = vec![0u16; px + 1];
    assert!(matches!(
        cam.render(&Q_A, 0, &mut rgb, &mut long_depth),
        Err(CameraError::BufferSize { buffer: "depth", .. })
    ));
    let mut payload = vec![0u8; px * 5 + 2];
    assert!(matches!(
        cam.render_into_payload(&Q_A, 0, &mut payload),
        Err(CameraError::BufferSize { buffer: "payload", .. })
    ));
    // A rejected call leaves the camera able to render the same bytes as before.
    assert!(render(&mut cam, &Q_A, 0).rgb == before.rgb);
}

#[test]
fn intrinsics_project_and_back_project_are_inverse() {
    let k = CameraConfig::paper_default().intrinsics;
    let p = Point3::new(12.5, -7.25, 231.0);
    let (u, v) = k.project(&p).expect("in front");
    let back = k.back_project(u, v, p.z);
    assert!((back - p).norm() < 1e-9);
    assert!(k.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
}
