//! FK, IK and cable equation timings (`cargo bench --bench kinematics`).

use bowden_kinematics::ik::IkOptions;
use bowden_kinematics::Robot;
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

fn kinematics(c: &mut Criterion) {
    let robot = Robot::paper_default();
    let q = [23.0, -31.0, 17.0, -12.0, 20.0];
    c.bench_function("fk (5 joints, 30 modules, jaws, ee)", |b| {
        b.iter(|| robot.fk(black_box(&q)))
    });
    let q4 = [q[0], q[1], q[2], 0.5 * (q[3] + q[4])];
    c.bench_function("ee pose + analytic jacobian", |b| {
        b.iter(|| robot.ee_jacobian(black_box(&q4)))
    });
    let target = robot.fk(&q).ee;
    let opts = IkOptions::default();
    c.bench_function("ik from zero (to 1e-9 mm)", |b| {
        b.iter(|| robot.ik(black_box(&target), None, &opts).expect("reachable"))
    });
    let near = [q4[0] + 2.0, q4[1] - 2.0, q4[2] + 2.0, q4[3] - 2.0];
    c.bench_function("ik from a 2-degree-off start", |b| {
        b.iter(|| robot.ik(black_box(&target), Some(near), &opts).expect("reachable"))
    });
    c.bench_function("cable displacements eq. 5 (10 cables)", |b| {
        b.iter(|| robot.cables().displacements_mm(black_box(&q)))
    });
    let w = robot.cables().displacements_mm(&q);
    c.bench_function("cable inverse (joints from 10 cables)", |b| {
        b.iter(|| {
            robot
                .cables()
                .joints_from_displacements(black_box(&w))
                .expect("consistent")
        })
    });
}

criterion_group!(benches, kinematics);
criterion_main!(benches);
