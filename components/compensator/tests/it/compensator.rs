//! The compensation step end to end on the PyTorch TCN fixtures: modes, bounds, histories,
//! limits, determinism, rejection, and newton vs Algorithm 1.

use crate::common;
use bowden_compensator::bench::random_trajectory;
use bowden_compensator::{
    newton_refine, paper_refine, Compensator, CompensatorError, ControllerConfig, EvaluatorChoice, IncrementalNet,
    Mode, Model, NewtonParams, PaperParams, StepError, StepOutput, StopReason,
};
use bowden_kinematics::Robot;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn cfg(mode: Mode) -> ControllerConfig {
    let mut c = ControllerConfig::shipped();
    c.mode = mode;
    c.budget.budget_ns = 0;
    c
}

fn dataset_targets(n: usize, seed: u64) -> Vec<[f64; 5]> {
    random_trajectory(&Robot::paper_default(), n, 3.0 * 5f64.sqrt(), seed)
}

#[test]
fn uncalibrated_needs_no_model_and_applies_limits() {
    let robot = Robot::paper_default();
    let mut c = cfg(Mode::Uncalibrated);
    c.model_fwd = None;
    c.model_inv = None;
    c.output.rate_limit_deg_s = 1000.0; // 1 deg per 1 ms period
    let mut comp = Compensator::from_config(&c, &robot).unwrap();
    let mut out = StepOutput::default();
    comp.step(&[10.0, -5.0, 3.0, -10.0, 10.0], &mut out).unwrap();
    assert_eq!(
        &out.q_cmd_deg[..5],
        &[10.0, -5.0, 3.0, -10.0, 10.0],
        "first step: no rate reference"
    );
    assert!(!out.has_prediction && out.stop_reason == StopReason::None);
    comp.step(&[12.5, -5.5, 3.0, -10.0, 10.0], &mut out).unwrap();
    assert_eq!(&out.q_cmd_deg[..2], &[11.0, -5.5]);
    assert!(out.rate_limited);
    // Beyond the joint limits (q1 ≤ 60): clamped.
    c.output.rate_limit_deg_s = 0.0;
    let mut comp = Compensator::from_config(&c, &robot).unwrap();
    comp.step(&[75.0, 0.0, 0.0, 0.0, 0.0], &mut out).unwrap();
    assert_eq!(out.q_cmd_deg[0], 60.0);
    assert!(out.joint_limited);
    // Paper and newton refuse to start without models.
    for m in [Mode::Paper, Mode::Newton] {
        assert!(matches!(comp.set_mode(m), Err(CompensatorError::MissingModel { .. })));
        c.mode = m;
        assert!(Compensator::from_config(&c, &robot).is_err());
    }
}

#[test]
fn model_direction_and_paths_are_checked() {
    let robot = Robot::paper_default();
    let mut c = cfg(Mode::Paper);
    std::mem::swap(&mut c.model_fwd, &mut c.model_inv);
    let e = Compensator::from_config(&c, &robot).unwrap_err().to_string();
    assert!(
        e.contains("inverse_L80") && e.contains("must be a forward model"),
        "{e}"
    );
    let mut c = cfg(Mode::Paper);
    c.model_fwd = Some("tests/fixtures/pytorch/nope.onnx".into());
    let e = Compensator::from_config(&c, &robot).unwrap_err().to_string();
    assert!(
        e.contains("model_fwd") && e.contains("nope.onnx") && e.contains("no such file"),
        "{e}"
    );
}

#[test]
fn rejected_targets_hold_the_last_command_and_are_counted() {
    let robot = Robot::paper_default();
    let mut comp = Compensator::from_config(&cfg(Mode::Paper), &robot).unwrap();
    let mut out = StepOutput::default();
    comp.step(&[1.0, 2.0, 3.0, -4.0, 5.0], &mut out).unwrap();
    let last = out.q_cmd_deg;
    let appended = comp.history().appended_total();
    let e = comp.step(&[1.0, f64::INFINITY, 3.0, 4.0, 5.0], &mut out).unwrap_err();
    assert_eq!(
        e,
        StepError::NotFinite {
            joint: 2,
            value: f64::INFINITY
        }
    );
    assert_eq!(out.q_cmd_deg, last);
    assert_eq!(out.stop_reason, StopReason::RejectedInput);
    assert!(matches!(
        comp.step(&[1.0; 4], &mut out),
        Err(StepError::WrongLength { expected: 5, found: 4 })
    ));
    assert_eq!(comp.rejected_inputs(), 2);
    assert_eq!(
        comp.history().appended_total(),
        appended,
        "nothing bad entered the history"
    );
}

#[test]
fn bounds_stop_the_loop() {
    let robot = Robot::paper_default();
    let t = dataset_targets(30, 9);
    let mut out = StepOutput::default();
    // M: with Thr = 0 every iteration updates, so paper mode runs exactly M.
    let mut c = cfg(Mode::Paper);
    c.paper.threshold_deg = 0.0;
    c.paper.iterations = 7;
    let mut comp = Compensator::from_config(&c, &robot).unwrap();
    for q in &t {
        comp.step(q, &mut out).unwrap();
        assert_eq!((out.stop_reason, out.iterations), (StopReason::MaxIterations, 7));
    }
    // Threshold: a huge Thr stops after the first evaluation.
    c.paper.threshold_deg = 1e6;
    let mut comp = Compensator::from_config(&c, &robot).unwrap();
    for q in &t {
        comp.step(q, &mut out).unwrap();
        assert_eq!((out.stop_reason, out.iterations), (StopReason::Threshold, 1));
    }
    // Budget: 1 ns is spent after the first iteration, whatever the machine.
    for mode in [Mode::Paper, Mode::Newton] {
        let mut c = cfg(mode);
        c.paper.threshold_deg = 0.0;
        c.newton.tolerance_deg = 1e-12;
        c.budget.budget_ns = 1;
        let mut comp = Compensator::from_config(&c, &robot).unwrap();
        for q in &t {
            comp.step(q, &mut out).unwrap();
            assert_eq!(out.stop_reason, StopReason::Budget, "{mode}");
            assert!(out.iterations <= 1, "{mode}: {} iterations", out.iterations);
        }
    }
    // Newton's evaluation cap: 3 in the loop + the prediction at q_cmd; never-worse adds at
    // most two ratings (the refinement's start and the target unchanged).
    for (never_worse, cap) in [(false, 4), (true, 6)] {
        let mut c = cfg(Mode::Newton);
        c.newton.tolerance_deg = 1e-12;
        c.newton.max_evals = 3;
        c.safety.never_worse = never_worse;
        let mut comp = Compensator::from_config(&c, &robot).unwrap();
        for q in &t {
            comp.step(q, &mut out).unwrap();
            assert!(out.forward_evals <= cap, "{} evaluations > {cap}", out.forward_evals);
            assert!(matches!(
                out.stop_reason,
                StopReason::MaxIterations | StopReason::Stalled
            ));
        }
    }
}

#[test]
fn lockstep_runs_are_bit_identical() {
    let robot = Robot::paper_default();
    let t = dataset_targets(120, 5);
    for &mode in Mode::ALL {
        let run = || {
            let mut comp = Compensator::from_config(&cfg(mode), &robot).unwrap();
            let mut out = StepOutput::default();
            t.iter()
                .map(|q| {
                    comp.step(q, &mut out).unwrap();
                    (
                        out.q_cmd_deg.map(f64::to_bits),
                        out.q_predicted_deg.map(f64::to_bits),
                        out.iterations,
                    )
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(run(), run(), "{mode}");
    }
}

#[test]
fn incremental_pipeline_equals_the_naive_tract_pipeline() {
    // The whole step (history sampling, prefix shifts, Algorithm 1) with the incremental
    // evaluator and with tract's full evaluation for every trial gives the same commands.
    let robot = Robot::paper_default();
    let mut t = dataset_targets(40, 21);
    t.extend(random_trajectory(&robot, 40, 0.7, 22));
    let run = |ev: EvaluatorChoice| {
        let mut c = cfg(Mode::Paper);
        c.evaluator = ev;
        let mut comp = Compensator::from_config(&c, &robot).unwrap();
        assert_eq!(comp.incremental().0, Some(ev == EvaluatorChoice::Auto));
        let mut out = StepOutput::default();
        t.iter()
            .map(|q| {
                comp.step(q, &mut out).unwrap();
                out
            })
            .collect::<Vec<_>>()
    };
    let (a, b) = (run(EvaluatorChoice::Auto), run(EvaluatorChoice::Tract));
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        for c in 0..5 {
            assert!(
                (x.q_cmd_deg[c] - y.q_cmd_deg[c]).abs() < 1e-3,
                "step {k}: {:?} vs {:?}",
                x.q_cmd_deg,
                y.q_cmd_deg
            );
            assert!((x.q_predicted_deg[c] - y.q_predicted_deg[c]).abs() < 1e-3);
        }
        assert_eq!(x.history_appended, y.history_appended);
    }
}

/// Targets the forward model can reach: q_desired = f(history, q_true) for random q_true.
struct Case {
    hist_cmd: Vec<f64>,
    hist_des: Vec<f64>,
    q_des: [f64; 5],
}

fn reachable_cases(fwd: &mut IncrementalNet, n: usize, seed: u64) -> Vec<Case> {
    let robot = Robot::paper_default();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let traj = random_trajectory(&robot, 80 * n + 200, 3.0 * 5f64.sqrt(), seed);
    (0..n)
        .map(|i| {
            let hist_cmd: Vec<f64> = traj[i * 80..i * 80 + 79].iter().flatten().copied().collect();
            let last = traj[i * 80 + 78];
            let mut q_true = [0.0; 5];
            for c in 0..5 {
                q_true[c] = last[c] + rng.random_range(-6.0..6.0);
            }
            let q_true = robot.clamp_to_limits(&q_true);
            fwd.set_history(&hist_cmd);
            let mut y = [0.0; 5];
            fwd.eval(&q_true, &mut y);
            // The inverse model sees the same path as its (physical) history.
            Case {
                hist_des: hist_cmd.clone(),
                hist_cmd,
                q_des: y,
            }
        })
        .collect()
}

#[test]
fn newton_converges_where_paper_mode_does_not() {
    let fwd_m = Model::load(common::fixture("tcn-linear2_forward_L80_J5_s0")).unwrap();
    let inv_m = Model::load(common::fixture("tcn-linear2_inverse_L80_J5_s0")).unwrap();
    let mut fwd = fwd_m.incremental().unwrap();
    let mut inv = inv_m.incremental().unwrap();
    let robot = Robot::paper_default();
    let cases = reachable_cases(&mut fwd, 40, 77);
    let paper = PaperParams::default();
    let newton = NewtonParams::default();
    let (mut paper_ok, mut newton_ok, mut newton_ok5) = (0, 0, 0);
    let mut evals_hist = [0usize; 10];
    for case in &cases {
        fwd.set_history(&case.hist_cmd);
        inv.set_history(&case.hist_des);
        let mut q0 = [0.0; 5];
        inv.eval(&case.q_des, &mut q0);
        let mut pred = [0.0; 5];
        let mut q = q0;
        let rp = paper_refine(
            &mut fwd,
            &case.q_des,
            &mut q,
            &paper,
            &mut pred,
            &mut |_| {},
            &mut || false,
            &mut |_, _, _| {},
        );
        let mut y = [0.0; 5];
        fwd.eval(&q, &mut y);
        let paper_loss = (0..5).map(|c| (y[c] - case.q_des[c]).abs()).fold(0.0, f64::max);
        paper_ok += (paper_loss < 0.1) as usize;
        assert_eq!(rp.evals, rp.iterations);

        let mut q = q0;
        let rn = newton_refine(
            &mut fwd,
            &case.q_des,
            &mut q,
            &newton,
            &mut pred,
            &mut |v| {
                let a: [f64; 5] = v.try_into().unwrap();
                v.copy_from_slice(&robot.clamp_to_limits(&a));
            },
            &mut || false,
        );
        fwd.eval(&q, &mut y);
        let newton_loss = (0..5).map(|c| (y[c] - case.q_des[c]).abs()).fold(0.0, f64::max);
        if newton_loss < 0.1 {
            newton_ok += 1;
            newton_ok5 += (rn.evals <= 5) as usize;
            evals_hist[rn.evals as usize] += 1;
        }
    }
    eprintln!(
        "reachable targets: paper < 0.1 deg: {paper_ok}/{n}; newton < 0.1 deg: {newton_ok}/{n} ({newton_ok5} within 5 \
         evaluations; evaluations histogram {evals_hist:?})",
        n = cases.len()
    );
    assert!(
        newton_ok * 10 >= cases.len() * 9,
        "newton converged on {newton_ok}/{}",
        cases.len()
    );
    assert!(
        paper_ok * 10 <= cases.len(),
        "paper mode converged on {paper_ok}/{}",
        cases.len()
    );
    assert!(
        newton_ok5 * 10 >= cases.len() * 8,
        "newton within 5 evaluations on {newton_ok5}/{}",
        cases.len()
    );
}

#[test]
fn history_is_sampled_at_the_model_step() {
    // A 1 kHz-like path moving 0.05 deg per step: one entry per 3√5/0.05 ≈ 134 steps.
    let robot = Robot::paper_default();
    let t = random_trajectory(&robot, 2000, 0.05, 8);
    let mut comp = Compensator::from_config(&cfg(Mode::Paper), &robot).unwrap();
    let mut out = StepOutput::default();
    let mut appended = 0;
    for q in &t {
        comp.step(q, &mut out).unwrap();
        appended += out.history_appended;
    }
    let path: f64 = t
        .windows(2)
        .map(|w| (0..5).map(|c| (w[1][c] - w[0][c]).powi(2)).sum::<f64>().sqrt())
        .sum();
    let expected = path / (3.0 * 5f64.sqrt());
    assert!(
        (appended as f64 - expected).abs() <= 0.1 * expected + 3.0,
        "{appended} entries for a path of {path:.1} deg ({expected:.1} steps)"
    );
}

#[test]
fn compensator_can_move_to_a_realtime_thread() {
    fn assert_send<T: Send>() {}
    assert_send::<Compensator>();
    assert_send::<StepOutput>();
}

#[test]
fn newton_step_tolerance_is_validated_and_off_unless_set() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let parse = |text: &str, name: &str| ControllerConfig::parse(text, std::path::Path::new(name));
    // The real-time TCN pair's config does not set it: absent = off.
    let realtime = std::fs::read_to_string(root.join("configs/controller.toml")).unwrap();
    assert_eq!(parse(&realtime, "a.toml").unwrap().newton.step_tolerance_deg, 0.0);
    // The accurate pair ships with it (chosen a priori, checked on the tuning trajectories).
    let accurate = std::fs::read_to_string(root.join("configs/controller-accurate.toml")).unwrap();
    assert_eq!(parse(&accurate, "b.toml").unwrap().newton.step_tolerance_deg, 0.001);
    let with = |v: &str| realtime.replace("[newton]\n", &format!("[newton]\nstep_tolerance_deg = {v}\n"));
    assert_eq!(parse(&with("0.01"), "c.toml").unwrap().newton.step_tolerance_deg, 0.01);
    for bad in ["-0.5", "nan"] {
        let e = parse(&with(bad), "d.toml").unwrap_err().to_string();
        assert!(
            e.contains("d.toml") && e.contains("newton.step_tolerance_deg"),
            "{bad}: {e}"
        );
    }
}
