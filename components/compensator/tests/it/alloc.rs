//! The compensation step allocates nothing: a counting global allocator over many steps of
//! every mode, with history shifts, interpolated multi-entry appends, resets and rejected
//! targets, on the TCN fixtures and (newton, forward model only) on the FNN, LSTM and
//! TCN-LSTM fixtures; with every safeguard of the safe refinement active; and on the vision
//! feedback path (estimates valid, NaN, invalid, partial, stale; target shaping and command
//! correction; marker loss and return); and with the window prefixes on the worker thread.

use crate::common;
use bowden_compensator::bench::random_trajectory;
use bowden_compensator::{
    ApplyTo, Compensator, ControllerConfig, Feedback, FeedbackConfig, Mode, Model, PrefixSync, PrefixWorkerOptions,
    PreparedModels, StepOutput,
};
use bowden_interfaces::JointEstimate;
use bowden_kinematics::Robot;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;
// Per thread: the tests of this file run in parallel, and one thread's allocations must not
// show in another's count.
thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

fn note_alloc() {
    if COUNTING.try_with(|c| c.get()).unwrap_or(false) {
        let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        note_alloc();
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        note_alloc();
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

fn count<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALLOCS.with(|a| a.get());
    COUNTING.with(|c| c.set(true));
    let r = f();
    COUNTING.with(|c| c.set(false));
    (r, ALLOCS.with(|a| a.get()) - before)
}

fn run_steps(comp: &mut Compensator, targets: &[[f64; 5]]) -> (u64, u64) {
    let mut out = StepOutput::default();
    let mut evals = 0u64;
    let mut appended = 0u64;
    for (i, t) in targets.iter().enumerate() {
        if i == targets.len() / 2 {
            comp.reset();
            // A rejected target on the way.
            let _ = comp.step(&[f64::NAN, 0.0, 0.0, 0.0, 0.0], &mut out);
            let _ = comp.step(&[0.0; 3], &mut out);
        }
        comp.step(t, &mut out).unwrap();
        evals += out.forward_evals as u64;
        appended += out.history_appended as u64;
    }
    (evals, appended)
}

#[test]
fn step_does_not_allocate() {
    let robot = Robot::paper_default();
    let step = 3.0 * 5f64.sqrt();
    // Dataset-rate steps (a history shift every step), then a coarse path (several entries
    // per step, interpolated), then a fine one.
    let mut targets = random_trajectory(&robot, 150, step, 3);
    targets.extend(random_trajectory(&robot, 60, 3.5 * step, 4));
    targets.extend(random_trajectory(&robot, 150, 0.2, 5));

    let cfg = ControllerConfig::shipped();
    for &mode in Mode::ALL {
        let mut c = cfg.clone();
        c.mode = mode;
        let mut comp = Compensator::from_config(&c, &robot).unwrap();
        assert_eq!(comp.incremental(), (Some(true), Some(true)));
        let ((evals, appended), allocs) = count(|| run_steps(&mut comp, &targets));
        assert_eq!(allocs, 0, "{mode}: {allocs} allocations in {} steps", targets.len());
        assert!(appended > 150, "{mode}: the history moved ({appended} entries)");
        if mode != Mode::Uncalibrated {
            assert!(
                evals > targets.len() as u64,
                "{mode}: the models ran ({evals} evaluations)"
            );
        }
    }

    // Every safeguard active: a forward model with support metadata (support bounds, drift
    // guard) and never-worse, in both refining modes.
    // With and without the tip rating (forward kinematics of three predictions per step).
    for (mode, tip) in [
        (Mode::Paper, false),
        (Mode::Newton, false),
        (Mode::Paper, true),
        (Mode::Newton, true),
    ] {
        let mut c = cfg.clone();
        c.mode = mode;
        c.safety = bowden_compensator::SafetyConfig {
            never_worse_tip: tip,
            ..bowden_compensator::SafetyConfig::on()
        };
        let fwd = common::supported("tcn_forward_L80_J5_s0");
        let inv = Model::load(common::fixture("tcn_inverse_L80_J5_s0")).unwrap();
        let mut comp = Compensator::from_models(&c, &robot, Some(fwd), Some(inv)).unwrap();
        assert!(comp.support().is_some());
        let ((evals, _), allocs) = count(|| run_steps(&mut comp, &targets));
        assert_eq!(allocs, 0, "{mode} with safety (tip rating {tip}): {allocs} allocations");
        assert!(evals > targets.len() as u64);
        assert!(comp.safety_counts().limited > 0, "{mode}: the bounds were active");
    }

    // The other architectures' incremental evaluators, through newton on the forward model.
    for name in [
        "fnn_forward_L80_J5_s0",
        "lstm_forward_L80_J5_s0",
        "tcn-lstm_forward_L80_J5_s0",
    ] {
        let mut c = cfg.clone();
        c.mode = Mode::Newton;
        c.newton.init_from_inverse = false;
        c.newton.max_evals = 3;
        let fwd = Model::load(common::fixture(name)).unwrap();
        let mut comp = Compensator::from_models(&c, &robot, Some(fwd), None).unwrap();
        let short = &targets[..40];
        let ((evals, _), allocs) = count(|| run_steps(&mut comp, short));
        assert_eq!(allocs, 0, "{name}: {allocs} allocations");
        assert!(evals >= short.len() as u64);
    }
}

/// The node's feedback cycle (components/compensator/src/node.rs) over `targets`, one per ms, with a
/// camera frame every 33 ms arriving 66 ms later; frames are valid, NaN, invalid or partial in
/// turn, and none arrive between 30 % and 60 % of the run (markers lost, then back).
fn feedback_cycle(comp: &mut Compensator, fb: &mut Feedback, apply: ApplyTo, targets: &[[f64; 5]]) -> u64 {
    let mut out = StepOutput::default();
    let mut queue = [JointEstimate::default(); 4];
    let (mut head, mut len) = (0usize, 0usize);
    let mut shaped = [0.0f64; 5];
    let mut u = [0.0f64; 5];
    let n = targets.len() as u64;
    for (k, q) in targets.iter().enumerate() {
        let (k, now) = (k as u64, k as u64 * 1_000_000);
        fb.begin(k, q, now);
        while len > 0 && queue[head].header.t_origin_ns + 66_000_000 <= now {
            fb.observe(&queue[head], now);
            head = (head + 1) % queue.len();
            len -= 1;
        }
        u.copy_from_slice(fb.update(now));
        match apply {
            ApplyTo::Target => {
                for (s, (q, u)) in shaped.iter_mut().zip(q.iter().zip(&u)) {
                    *s = q + u;
                }
                comp.step(&shaped, &mut out).unwrap();
            }
            ApplyTo::Command => comp.step_with_correction(q, &u, &mut out).unwrap(),
        }
        fb.note_bounds(out.upper_mask, out.lower_mask);
        let lost = k > 3 * n / 10 && k < 6 * n / 10;
        if k.is_multiple_of(33) && !lost && len < queue.len() {
            let mut e = JointEstimate {
                n_joints: 5,
                quality: JointEstimate::QUALITY_VALID,
                joint_valid_mask: 0b11111,
                ..Default::default()
            };
            e.header.tick = k;
            e.header.t_origin_ns = now;
            for (e, q) in e.q_phy_deg.iter_mut().zip(q) {
                *e = q - 0.5;
            }
            match (k / 33) % 5 {
                1 => e.q_phy_deg[2] = f64::NAN,
                2 => e.quality = JointEstimate::QUALITY_INVALID,
                3 => {
                    e.quality = JointEstimate::QUALITY_PARTIAL;
                    e.joint_valid_mask = 0b00111;
                }
                _ => {}
            }
            queue[(head + len) % queue.len()] = e;
            len += 1;
        }
    }
    fb.counts().updates
}

#[test]
fn feedback_path_does_not_allocate() {
    let robot = Robot::paper_default();
    let targets = random_trajectory(&robot, 6000, 0.06, 7);
    for (mode, apply) in [
        (Mode::Newton, ApplyTo::Target),
        (Mode::Paper, ApplyTo::Command),
        (Mode::Uncalibrated, ApplyTo::Target),
    ] {
        let mut c = ControllerConfig::shipped();
        c.mode = mode;
        c.feedback = FeedbackConfig {
            enabled: true,
            apply,
            use_partial: mode == Mode::Paper,
            // The slow correction's path too (its average and dead band).
            bias_gain: 0.3,
            bias_window: 4,
            bias_deadband_deg: 0.05,
            ..FeedbackConfig::default()
        };
        let mut comp = Compensator::from_config(&c, &robot).unwrap();
        comp.set_budget_ns(0);
        let mut fb = Feedback::new(&c.feedback, comp.joints(), 1_000_000);
        let (updates, allocs) = count(|| feedback_cycle(&mut comp, &mut fb, apply, &targets));
        assert_eq!(
            allocs,
            0,
            "{mode} {apply:?}: {allocs} allocations in {} cycles",
            targets.len()
        );
        let fc = fb.counts();
        assert!(updates > 20, "{mode} {apply:?}: the feedback ran: {fc:?}");
        assert!(fc.not_finite > 5 && fc.invalid > 5 && fc.loss_episodes >= 1, "{fc:?}");
        assert!(fb.u_abs_max() > 0.0);
        // reset keeps the ring: no allocation either.
        let ((), allocs) = count(|| fb.reset());
        assert_eq!(allocs, 0);
    }
}

#[test]
fn the_counter_counts() {
    let (_, n) = count(|| vec![1u8; 10]);
    assert!(n >= 1, "the counting allocator must see a Vec allocation");
}

fn root() -> &'static std::path::Path {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// With the window prefixes on the worker thread, in both modes (`Wait`, `Newest`), on both
/// shipped controllers and on the shape `bench transfer`'s `tune` chooses (the real-time
/// config with an LSTM forward model and an LSTM inverse), through history steps, `prepare`, a
/// reset, a rejected target and a hot model swap (the worker's own allocations are off the
/// cycle and not counted).
#[test]
fn steps_with_the_prefix_worker_do_not_allocate() {
    let robot = Robot::paper_default();
    let step = 3.0 * 5f64.sqrt();
    let mut targets = random_trajectory(&robot, 100, step, 3);
    targets.extend(random_trajectory(&robot, 30, 3.5 * step, 4));
    targets.extend(random_trajectory(&robot, 400, 0.06, 5));
    let models = root().join("../../models");
    let lstm_pair = Some(("lstm_forward_L80.onnx", "lstm_inverse_L80.onnx"));
    for (name, files) in [
        ("controller.toml", None),
        ("controller-accurate.toml", None),
        ("controller.toml", lstm_pair),
    ] {
        let base = ControllerConfig::load(root().join("../../configs").join(name)).unwrap();
        let load = |field: &'static str, p: &Option<std::path::PathBuf>| {
            Model::load(base.resolve_model_path(field, p.as_ref().unwrap()).unwrap()).unwrap()
        };
        let (fwd, inv) = match files {
            None => (load("model_fwd", &base.model_fwd), load("model_inv", &base.model_inv)),
            Some((f, i)) => (
                Model::load(models.join(f)).unwrap(),
                Model::load(models.join(i)).unwrap(),
            ),
        };
        let name = format!("{name} {files:?}");
        let other_inv = Model::load(root().join("../../models/tcn_inverse_L80.onnx")).unwrap();
        for sync in [PrefixSync::Wait, PrefixSync::Newest] {
            for mode in [Mode::Paper, Mode::Newton] {
                let mut c = base.clone();
                c.mode = mode;
                let mut comp = Compensator::from_models(&c, &robot, Some(fwd.clone()), Some(inv.clone())).unwrap();
                assert!(comp
                    .start_prefix_worker(PrefixWorkerOptions {
                        sync,
                        name: "prefix-alloc".into(),
                        on_start: None,
                    })
                    .unwrap());
                let mut next = PreparedModels {
                    generation: 1,
                    fwd: None,
                    inv: Some(comp.evaluator_for(&other_inv)),
                };
                let mut out = StepOutput::default();
                let ((appended, lagged), allocs) = count(|| {
                    let (mut appended, mut lagged) = (0u64, 0u64);
                    for (i, t) in targets.iter().enumerate() {
                        if i == targets.len() / 3 {
                            comp.reset();
                            let _ = comp.step(&[f64::NAN; 5], &mut out);
                        }
                        if i == targets.len() / 2 {
                            comp.swap_models(&mut next).unwrap();
                        }
                        comp.step(t, &mut out).unwrap();
                        appended += out.history_appended as u64;
                        lagged += (out.prefix_lag > 0) as u64;
                        comp.prepare();
                    }
                    (appended, lagged)
                });
                assert_eq!(allocs, 0, "{name} {sync:?} {mode}: {allocs} allocations");
                assert!(appended > 100, "the history moved");
                if sync == PrefixSync::Wait {
                    assert_eq!(lagged, 0, "Wait never runs on an older prefix");
                }
                // The replaced model goes back to be dropped off the cycle.
                drop(next);
            }
        }
    }
}
