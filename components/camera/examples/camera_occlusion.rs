//! Why a marker has few depth pixels: for seeded workspace configurations, what covers each
//! marker's silhouette (another marker, the body, a jaw) and how much of what is visible
//! lost its depth (silhouette, edge, stereo shadow).
//! `cargo run --release -p bowden-camera --example camera_occlusion -- [N] [AZ EL DIST]`

use bowden_camera::{label, CameraConfig, SyntheticCamera};
use bowden_interfaces::marker::NAMES;
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn main() {
    let a: Vec<f64> = std::env::args().skip(1).filter_map(|s| s.parse().ok()).collect();
    let n = a.first().copied().unwrap_or(200.0) as usize;
    let robot = Robot::paper_default();
    let markers = MarkerGeometry::paper_default();
    let mut cfg = CameraConfig::paper_default();
    if a.len() >= 4 {
        let (az, el, dist) = (a[1].to_radians(), a[2].to_radians(), a[3]);
        let dir = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let c = Vector3::from(cfg.pose.look_at_base_mm);
        cfg.pose.position_base_mm = (c + dir * dist).into();
    }
    println!(
        "camera at {:?} looking at {:?}",
        cfg.pose.position_base_mm, cfg.pose.look_at_base_mm
    );
    let k = cfg.intrinsics;
    let mut cam = SyntheticCamera::new(robot.clone(), markers.clone(), cfg, 1);
    let px = (cam.width() * cam.height()) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let lim = robot.config.limits.clone();
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let radii = markers.radii_mm();
    let names = [
        "bg", "r0", "r1", "b0", "r2", "b1", "y0", "g0", "body", "jawL", "jawR", "shaft", "void",
    ];
    let mut counts = Vec::with_capacity(n);
    for f in 0..n {
        let mut q = [0.0; 5];
        for (j, v) in q.iter_mut().enumerate() {
            *v = rng.random_range(lim.q_min_deg[j]..=lim.q_max_deg[j]);
        }
        if q[4] < q[3] {
            q.swap(3, 4);
        }
        cam.render(&q, f as u64, &mut rgb, &mut depth).expect("render");
        let centres = cam.marker_centres_cam_mm(&q);
        let mut worst = usize::MAX;
        for m in 0..7 {
            // The marker's own disc: pixels whose ray hits the sphere.
            let c = centres[m];
            let (mut disc, mut own, mut own_depth, mut flagged) = (0, 0, 0, 0);
            let mut cover = [0usize; 13];
            for v in 0..480 {
                for u in 0..640 {
                    let d =
                        Vector3::new((u as f64 - k.cx_px) / k.fx_px, (v as f64 - k.cy_px) / k.fy_px, 1.0).normalize();
                    let t = c.coords.dot(&d);
                    if (c.coords - d * t).norm() > radii[m] {
                        continue;
                    }
                    disc += 1;
                    let i = v * 640 + u;
                    let l = cam.labels()[i];
                    let what = (l & label::WHAT_MASK) as usize;
                    if what == m + 1 {
                        own += 1;
                        own_depth += usize::from(depth[i] > 0);
                        flagged += usize::from(l & label::NO_DEPTH != 0);
                    } else {
                        cover[what] += 1;
                    }
                }
            }
            worst = worst.min(own_depth);
            if own_depth < 12 {
                let covers: Vec<String> = (0..13)
                    .filter(|&w| cover[w] > 0)
                    .map(|w| format!("{}:{}", names[w], cover[w]))
                    .collect();
                println!(
                    "q=[{:6.1} {:6.1} {:6.1} {:6.1} {:6.1}] {}: disc {disc:4} seen {own:4} depth {own_depth:4} flagged {flagged:4} covered by {}",
                    q[0], q[1], q[2], q[3], q[4], NAMES[m], covers.join(" ")
                );
            }
        }
        counts.push(worst);
    }
    counts.sort_unstable();
    println!(
        "worst-marker depth pixels over {n} configs: min {} p1 {} p5 {} p10 {} median {}",
        counts[0],
        counts[n / 100],
        counts[n / 20],
        counts[n / 10],
        counts[n / 2]
    );
}
