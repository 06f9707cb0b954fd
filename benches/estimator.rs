//! Marker estimator: the whole 640×480 RGBD frame → joints path (HSV, components, sphere
//! fits, frames, IK, joint-space fit) on synthetic frames of seeded workspace
//! configurations (`cargo bench --bench estimator`). Goal: ≤ 3 ms per frame at p99 on one
//! core (`bowden estimator eval` prints the percentiles). Frames are rendered up front and
//! cycled, so the time includes reading a cold frame, as a real pipeline does.

use bowden_camera::{CameraConfig, SyntheticCamera};
use bowden_estimator::eval::random_configuration;
use bowden_estimator::segment::Segmenter;
use bowden_estimator::{Estimator, EstimatorConfig};
use bowden_interfaces::{JointEstimate, MarkerSet, RgbdFrameHeader};
use bowden_kinematics::{markers::MarkerGeometry, JointsDeg, Robot};
use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

const FRAMES: usize = 32;

struct Frame {
    header: RgbdFrameHeader,
    payload: Vec<u8>,
    rgb: Vec<u8>,
    depth: Vec<u16>,
    /// The truth plus up to ±15° per joint: the command, as the runtime passes it.
    hint: JointsDeg,
}

fn frames() -> Vec<Frame> {
    let robot = Robot::paper_default();
    let mut cam = SyntheticCamera::new(
        robot.clone(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        1,
    );
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let px = (cam.width() * cam.height()) as usize;
    (0..FRAMES)
        .map(|i| {
            let q = random_configuration(&robot, &mut rng);
            let hint = core::array::from_fn(|k| q[k] + rng.random_range(-15.0..=15.0));
            let mut payload = vec![0u8; cam.payload_len()];
            cam.render_into_payload(&q, i as u64, &mut payload).expect("render");
            let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
            cam.render(&q, i as u64, &mut rgb, &mut depth).expect("render");
            Frame {
                header: cam.header(i as u64, i as u64, 0),
                payload,
                rgb,
                depth,
                hint,
            }
        })
        .collect()
}

fn estimator(c: &mut Criterion) {
    let frames = frames();
    let mut est = Estimator::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        EstimatorConfig::paper_default(),
    );
    est.reserve_frame(640, 480);
    let (mut ms, mut je) = (MarkerSet::default(), JointEstimate::default());
    let mut i = 0usize;
    c.bench_function("estimate 640x480 frame -> joints (payload, command as hint)", |b| {
        b.iter(|| {
            let f = &frames[i % FRAMES];
            i += 1;
            est.estimate_payload(black_box(&f.header), &f.payload, Some(f.hint), &mut ms, &mut je)
                .expect("usable frame");
            black_box(&je);
        })
    });
    c.bench_function("estimate 640x480 frame -> joints (payload, no hint)", |b| {
        b.iter(|| {
            let f = &frames[i % FRAMES];
            i += 1;
            est.estimate_payload(black_box(&f.header), &f.payload, None, &mut ms, &mut je)
                .expect("usable frame");
            black_box(&je);
        })
    });
    c.bench_function("estimate 640x480 frame -> joints (separate planes, hint)", |b| {
        b.iter(|| {
            let f = &frames[i % FRAMES];
            i += 1;
            est.estimate(black_box(&f.header), &f.rgb, &f.depth, Some(f.hint), &mut ms, &mut je)
                .expect("usable frame");
            black_box(&je);
        })
    });
    let cfg = EstimatorConfig::paper_default();
    let ranges = cfg.hsv.ranges();
    let mut seg = Segmenter::default();
    c.bench_function("segment 640x480 frame (HSV + connected components only)", |b| {
        b.iter(|| {
            let f = &frames[i % FRAMES];
            i += 1;
            seg.run(&f.rgb, f.depth.as_slice(), 640, 480, &ranges, 8, (30, 3000), 1.0);
            black_box(seg.blobs.len());
        })
    });
}

criterion_group!(benches, estimator);
criterion_main!(benches);
