//! Quick per-stage timing of one frame (the criterion bench is `cargo bench --bench camera`
//! at the workspace root): `cargo run --release -p bowden-camera --example camera_timing`.

use bowden_camera::{CameraConfig, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use std::time::Instant;

fn main() {
    let mut cam = SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        1,
    );
    let px = (cam.width() * cam.height()) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let q = [35.0, -25.0, 30.0, -20.0, 25.0];
    let n = 1000;
    let mut times = Vec::with_capacity(n);
    for k in 0..n {
        let t = Instant::now();
        cam.render(&q, k as u64, &mut rgb, &mut depth).expect("render");
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(|a, b| a.total_cmp(b));
    println!(
        "render 640x480: min {:.3} ms  p10 {:.3} ms  p50 {:.3} ms  p99 {:.3} ms  max {:.3} ms  ({:.0} fps at p50)",
        times[0],
        times[n / 10],
        times[n / 2],
        times[n * 99 / 100],
        times[n - 1],
        1e3 / times[n / 2]
    );
}
