//! The compensation step allocates nothing: a counting global allocator over many steps of
//! every mode, with history shifts, interpolated multi-entry appends, resets and rejected
//! targets, on the TCN fixtures and (newton, forward model only) on the FNN, LSTM and
//! TCN-LSTM fixtures; and with every safeguard of the safe refinement active.

mod common;
use bowden_compensator::bench::random_trajectory;
use bowden_compensator::{Compensator, ControllerConfig, Mode, Model, StepOutput};
use bowden_kinematics::Robot;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);
thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

fn count<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALLOCS.load(Ordering::Relaxed);
    COUNTING.with(|c| c.set(true));
    let r = f();
    COUNTING.with(|c| c.set(false));
    (r, ALLOCS.load(Ordering::Relaxed) - before)
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
    for mode in Mode::ALL {
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
    for mode in [Mode::Paper, Mode::Newton] {
        let mut c = cfg.clone();
        c.mode = mode;
        c.safety = bowden_compensator::SafetyConfig::on();
        let fwd = common::supported("tcn_forward_L80_J5_s0");
        let inv = Model::load(common::fixture("tcn_inverse_L80_J5_s0")).unwrap();
        let mut comp = Compensator::from_models(&c, &robot, Some(fwd), Some(inv)).unwrap();
        assert!(comp.support().is_some());
        let ((evals, _), allocs) = count(|| run_steps(&mut comp, &targets));
        assert_eq!(allocs, 0, "{mode} with safety: {allocs} allocations");
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

#[test]
fn the_counter_counts() {
    let (_, n) = count(|| vec![1u8; 10]);
    assert!(n >= 1, "the counting allocator must see a Vec allocation");
}
