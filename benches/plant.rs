//! Simulated plant step timings (`cargo bench --bench plant`).
//!
//! - moving command: every step gets the next eq. (16) command (3° per joint apart), the worst
//!   case (plays move, the fixed point takes several iterations);
//! - 1 kHz tracking: a 0.003°-per-step ramp, what the runtime's plant node sees at 1 kHz;
//! - held command: nothing moves (one fixed-point check per step);
//! - one dataset sample: 0.5 s hold at dt 10 ms (50 steps), the unit of `plant characterize`.

use bowden_kinematics::Robot;
use bowden_plant::{Plant, PlantConfig};
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

fn plant(c: &mut Criterion) {
    let robot = Robot::paper_default();
    let config = PlantConfig::paper_default();
    let commands: Vec<[f64; 10]> = bowden_trajectory::dataset_commands(&robot, 200, 1)
        .iter()
        .map(|q| robot.cables().displacements_mm(q))
        .collect();

    let mut p = Plant::new(&robot, &config, 1);
    let mut k = 0;
    c.bench_function("plant step, new eq. 16 command every step (dt 1 ms)", |b| {
        b.iter(|| {
            k = (k + 1) % commands.len();
            p.step(black_box(&commands[k]), 0.001).expect("valid command");
        })
    });

    let mut p = Plant::new(&robot, &config, 1);
    let ramp: Vec<[f64; 10]> = (0..10_000)
        .map(|i| {
            let t = i as f64 * 0.003;
            let q = [30.0 * (t / 30.0).sin(), 20.0, -10.0 + t % 20.0, -15.0, 15.0];
            robot.cables().displacements_mm(&q)
        })
        .collect();
    let mut k = 0;
    c.bench_function("plant step, 1 kHz tracking (0.003 deg per step)", |b| {
        b.iter(|| {
            k = (k + 1) % ramp.len();
            p.step(black_box(&ramp[k]), 0.001).expect("valid command");
        })
    });

    let mut p = Plant::new(&robot, &config, 1);
    let held = commands[10];
    p.settle(&held, 1.0, 0.001).expect("valid command");
    c.bench_function("plant step, held command (dt 1 ms)", |b| {
        b.iter(|| p.step(black_box(&held), 0.001).expect("valid command"))
    });

    let mut p = Plant::new(&robot, &config, 1);
    let mut k = 0;
    c.bench_function("plant dataset sample: settle 0.5 s at dt 10 ms", |b| {
        b.iter(|| {
            k = (k + 1) % commands.len();
            p.settle(black_box(&commands[k]), 0.5, 0.01).expect("valid command");
        })
    });
}

criterion_group!(benches, plant);
criterion_main!(benches);
