//! Searches camera viewing directions for the one that keeps every marker most visible over a
//! seeded set of workspace configurations (used to choose the default pose in
//! configs/camera.toml). `cargo run --release -p bowden-camera --example camera_pose_search -- [N]`

use bowden_camera::{label, CameraConfig, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, JointsDeg, Robot};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One viewing direction's score over the configurations.
struct Candidate {
    /// Configurations where some marker has fewer than 12 depth pixels.
    bad: usize,
    jaw_mean: f64,
    az: i32,
    el: i32,
    dist: f64,
    min_count: [usize; 7],
    min_all: usize,
    /// Per marker: configurations where it has fewer than 12 depth pixels.
    why: [usize; 7],
}

fn configs(robot: &Robot, n: usize, seed: u64) -> Vec<JointsDeg> {
    let lim = &robot.config.limits;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    // Corners of the joint box first (the extremes of the workspace), then random samples.
    for mask in 0..8u32 {
        for jaw in [[-50.0, -50.0], [-50.0, 50.0], [50.0, 50.0], [0.0, 0.0]] {
            let pick = |j: usize| {
                if mask >> j & 1 == 1 {
                    lim.q_max_deg[j]
                } else {
                    lim.q_min_deg[j]
                }
            };
            out.push([pick(0), pick(1), pick(2), jaw[0], jaw[1]]);
        }
    }
    while out.len() < n {
        let mut q = [0.0; 5];
        for (j, v) in q.iter_mut().enumerate() {
            *v = rng.random_range(lim.q_min_deg[j]..=lim.q_max_deg[j]);
        }
        if q[4] < q[3] {
            q.swap(3, 4);
        }
        out.push(q);
    }
    out
}

fn main() {
    let n: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(300);
    let robot = Robot::paper_default();
    let markers = MarkerGeometry::paper_default();
    let qs = configs(&robot, n, 42);
    let base_cfg = CameraConfig::paper_default();
    // Workspace points (base frame) to frame: marker centres and the body's centre line.
    let mut pts: Vec<Point3<f64>> = Vec::new();
    let mut cl = Vec::new();
    for q in &qs {
        let fk = robot.fk(q);
        pts.extend(markers.centres_base_mm(&fk));
        robot.centerline(q, &mut cl);
        pts.extend(cl.iter().copied());
        pts.extend(fk.jaw_tips(robot.config.forceps.jaw_length_mm));
    }
    let lo = pts.iter().fold(Vector3::repeat(f64::MAX), |a, p| a.inf(&p.coords));
    let hi = pts.iter().fold(Vector3::repeat(f64::MIN), |a, p| a.sup(&p.coords));
    println!("workspace bbox (base, mm): {lo:.1?} .. {hi:.1?}");
    let centre = (lo + hi) * 0.5;
    let k = base_cfg.intrinsics;
    let mut results = Vec::new();
    let fill = 0.92;
    let min_range_mm: f64 = std::env::args().nth(2).and_then(|s| s.parse().ok()).unwrap_or(150.0);
    // Grid of viewing directions (degrees); override with AZ="a,b,.." EL="c,d,..".
    let list = |var: &str, default: Vec<i32>| -> Vec<i32> {
        std::env::var(var).ok().map_or(default, |s| {
            s.split(',').filter_map(|x| x.trim().parse().ok()).collect()
        })
    };
    let azs = list("AZ", (0..360).step_by(15).collect());
    let els = list("EL", vec![20, 30, 40, 50, 60, 70]);
    for &az in &azs {
        for &el in &els {
            let (a, e) = ((az as f64).to_radians(), (el as f64).to_radians());
            let dir = Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
            let mut cfg = base_cfg;
            cfg.pose.look_at_base_mm = centre.into();
            // Distance that fits every workspace point (with marker radius) into `fill` of the frame.
            let mut dist = 250.0;
            for _ in 0..6 {
                cfg.pose.position_base_mm = (centre + dir * dist).into();
                let t = cfg.pose.camera_in_base().inverse();
                let mut worst: f64 = 0.0;
                for p in &pts {
                    let c = t.transform_point(p);
                    let (u, v) = (
                        (c.x + 5.0 * c.x.signum()) / c.z * k.fx_px,
                        (c.y + 5.0 * c.y.signum()) / c.z * k.fy_px,
                    );
                    worst = worst.max(u.abs() / (k.cx_px * fill)).max(v.abs() / (k.cy_px * fill));
                }
                dist *= worst;
            }
            cfg.pose.position_base_mm = (centre + dir * dist).into();
            // Keep everything beyond the sensor's minimum range (with a margin).
            let t = cfg.pose.camera_in_base().inverse();
            let nearest = pts.iter().map(|p| t.transform_point(p).z).fold(f64::MAX, f64::min) - 5.0;
            if nearest < min_range_mm {
                dist += min_range_mm - nearest;
                cfg.pose.position_base_mm = (centre + dir * dist).into();
            }
            let mut cam = SyntheticCamera::new(robot.clone(), markers.clone(), cfg, 1);
            let px = (cam.width() * cam.height()) as usize;
            let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
            let mut min_count = [usize::MAX; 7];
            let mut sum = [0usize; 7];
            let mut bad = 0usize;
            let mut why = [0usize; 7];
            for (f, q) in qs.iter().enumerate() {
                cam.render(q, f as u64, &mut rgb, &mut depth).expect("render");
                let mut c = [0usize; 7];
                for (i, &l) in cam.labels().iter().enumerate() {
                    let m = (l & label::WHAT_MASK) as usize;
                    if (1..=7).contains(&m) && depth[i] > 0 {
                        c[m - 1] += 1;
                    }
                }
                if c.iter().any(|&x| x < 12) {
                    bad += 1;
                }
                for m in 0..7 {
                    why[m] += usize::from(c[m] < 12);
                    min_count[m] = min_count[m].min(c[m]);
                    sum[m] += c[m];
                }
            }
            let jaw_min = *min_count[3..].iter().min().unwrap_or(&0);
            let base_min = *min_count[..3].iter().min().unwrap_or(&0);
            let jaw_mean = sum[3..].iter().sum::<usize>() as f64 / (4 * qs.len()) as f64;
            results.push(Candidate {
                bad,
                jaw_mean,
                az,
                el,
                dist,
                min_count,
                min_all: jaw_min.min(base_min),
                why,
            });
        }
    }
    // Fewest frames with a poorly visible marker first, then the most jaw-marker pixels.
    results.sort_by(|a, b| a.bad.cmp(&b.bad).then(b.jaw_mean.total_cmp(&a.jaw_mean)));
    for r in results.iter().take(15) {
        println!(
            "bad {:4}  min {:4}  jaw mean {:6.1}  az {:3} el {:2} dist {:6.1}  per marker min {:?} <12 {:?}",
            r.bad, r.min_all, r.jaw_mean, r.az, r.el, r.dist, r.min_count, r.why
        );
    }
}
