//! Synthetic RGBD camera: one 640×480 frame (render + sensor model), into separate buffers
//! and into an interfaces payload (`cargo bench --bench camera`). Goal: ≤ 11 ms (≥ 90 fps,
//! the D435's fastest rate) on one core.

use bowden_camera::{CameraConfig, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

fn camera(c: &mut Criterion) {
    let mut cam = SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        1,
    );
    let px = (cam.width() * cam.height()) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let mut payload = vec![0u8; cam.payload_len()];
    // A bent configuration with open jaws; the frame index advances so each frame draws fresh noise.
    let q = [35.0, -25.0, 30.0, -20.0, 25.0];
    let mut k = 0u64;
    c.bench_function("render 640x480 rgb+depth (buffers)", |b| {
        b.iter(|| {
            k += 1;
            cam.render(black_box(&q), k, &mut rgb, &mut depth).expect("render");
        })
    });
    c.bench_function("render 640x480 rgb+depth (interfaces payload)", |b| {
        b.iter(|| {
            k += 1;
            cam.render_into_payload(black_box(&q), k, &mut payload).expect("render");
        })
    });
    c.bench_function("camera construction (background pre-render)", |b| {
        b.iter(|| {
            SyntheticCamera::new(
                Robot::paper_default(),
                MarkerGeometry::paper_default(),
                CameraConfig::paper_default(),
                black_box(1),
            )
        })
    });
}

criterion_group!(benches, camera);
criterion_main!(benches);
