//! Compensator hot paths (`cargo bench --bench compensator`): the incremental TCN evaluator
//! (one trial, one trial with the Jacobian — through the compiled narrow plan and through the
//! generic node walk — full and shifted prefix), tract's full evaluation
//! of the same window, and whole compensation steps per mode; on test fixtures and on the
//! shipped models. Percentiles over ≥ 100k steps
//! with the naive loop beside them: `bowden bench compensate`.

use bowden_compensator::bench::random_trajectory;
use bowden_compensator::{Compensator, ControllerConfig, Mode, Model, StepOutput};
use bowden_kinematics::Robot;
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("tests/fixtures/pytorch/{name}.onnx"))
}

fn evaluators(c: &mut Criterion) {
    let robot = Robot::paper_default();
    let traj = random_trajectory(&robot, 200, 3.0 * 5f64.sqrt(), 1);
    let window: Vec<f64> = traj[..80].iter().flatten().copied().collect();
    let last = [10.0, -5.0, 3.0, -8.0, 9.0];
    let shipped = |f: &str| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models").join(f);
    for (name, path) in [
        (
            "tcn-linear2_forward_L80_J5_s0",
            fixture("tcn-linear2_forward_L80_J5_s0"),
        ),
        ("fnn_forward_L80_J5_s0", fixture("fnn_forward_L80_J5_s0")),
        ("lstm_forward_L80_J5_s0", fixture("lstm_forward_L80_J5_s0")),
        // The shipped pairs: controller.toml (TCN both ways), controller-accurate.toml (TCN
        // forward, LSTM inverse: its prefix is the one the prefix worker takes off the cycle).
        ("shipped tcn_forward_L80", shipped("tcn_forward_L80.onnx")),
        ("shipped tcn_inverse_L80", shipped("tcn_inverse_L80.onnx")),
        ("shipped lstm_inverse_L80", shipped("lstm_inverse_L80.onnx")),
    ] {
        let m = Model::load(&path).expect("model loads");
        let mut inc = m.incremental().expect("recognised");
        inc.set_history(&window[..79 * 5]);
        let mut out = [0.0; 5];
        let mut jac = [0.0; 25];
        c.bench_function(&format!("{name}: incremental trial (last column)"), |b| {
            b.iter(|| inc.eval(black_box(&last), &mut out))
        });
        c.bench_function(&format!("{name}: incremental trial + 5x5 jacobian"), |b| {
            b.iter(|| inc.eval_jacobian(black_box(&last), &mut out, &mut jac))
        });
        if inc.is_narrow() {
            // The same trials through the generic node walk: what the compiled plan saves.
            let mut walk = inc.clone().into_generic();
            c.bench_function(&format!("{name}: incremental trial, node walk"), |b| {
                b.iter(|| walk.eval(black_box(&last), &mut out))
            });
            c.bench_function(&format!("{name}: incremental trial + 5x5 jacobian, node walk"), |b| {
                b.iter(|| walk.eval_jacobian(black_box(&last), &mut out, &mut jac))
            });
        }
        c.bench_function(&format!("{name}: prefix, full (79 columns)"), |b| {
            b.iter(|| inc.set_history(black_box(&window[..79 * 5])))
        });
        let mut hist = window[..79 * 5].to_vec();
        let mut k = 80;
        c.bench_function(&format!("{name}: prefix, shifted by one entry"), |b| {
            b.iter(|| {
                hist.copy_within(5.., 0);
                hist[78 * 5..].copy_from_slice(&traj[k % traj.len()]);
                k += 1;
                inc.shift_history(black_box(&hist))
            })
        });
        let w32: Vec<f32> = window.iter().map(|&v| v as f32).collect();
        c.bench_function(&format!("{name}: tract full evaluation (naive trial)"), |b| {
            b.iter(|| m.eval_full(black_box(&w32)).expect("runs"))
        });
    }
}

fn steps(c: &mut Criterion) {
    let robot = Robot::paper_default();
    let mut cfg = ControllerConfig::shipped();
    cfg.budget.budget_ns = 0;
    for (label, spacing) in [("dataset step", 3.0 * 5f64.sqrt()), ("fine 0.06 deg", 0.06)] {
        let targets = random_trajectory(&robot, 20_000, spacing, 2);
        for &mode in Mode::ALL {
            cfg.mode = mode;
            let mut comp = Compensator::from_config(&cfg, &robot).expect("fixtures load");
            let mut out = StepOutput::default();
            let mut i = 0;
            c.bench_function(&format!("compensation step, {mode} mode, {label}"), |b| {
                b.iter(|| {
                    // Targets come from the generator and are always valid.
                    let _ = comp.step(black_box(&targets[i % targets.len()]), &mut out);
                    i += 1;
                })
            });
        }
    }
}

criterion_group!(benches, evaluators, steps);
criterion_main!(benches);
