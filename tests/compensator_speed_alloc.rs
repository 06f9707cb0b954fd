//! The step allocates nothing with the window prefixes on the worker thread, in both modes
//! (`Wait`, `Newest`), on both shipped controllers, through history steps, `prepare`, a
//! reset, a rejected target and a hot model swap: a counting global allocator, per thread
//! (the worker's own allocations, at start-up and when it rebuilds its evaluators after a
//! swap, are off the cycle and not counted).

use bowden_compensator::bench::random_trajectory;
use bowden_compensator::{
    Compensator, ControllerConfig, Mode, Model, PrefixSync, PrefixWorkerOptions, PreparedModels, StepOutput,
};
use bowden_kinematics::Robot;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

struct Counting;
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

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn the_counter_counts() {
    let (_, n) = count(|| vec![1u8; 10]);
    assert!(n >= 1);
}

#[test]
fn steps_with_the_prefix_worker_do_not_allocate() {
    let robot = Robot::paper_default();
    let step = 3.0 * 5f64.sqrt();
    let mut targets = random_trajectory(&robot, 100, step, 3);
    targets.extend(random_trajectory(&robot, 30, 3.5 * step, 4));
    targets.extend(random_trajectory(&robot, 400, 0.06, 5));
    for name in ["controller.toml", "controller-accurate.toml"] {
        let base = ControllerConfig::load(root().join("configs").join(name)).unwrap();
        let load = |field: &'static str, p: &Option<std::path::PathBuf>| {
            Model::load(base.resolve_model_path(field, p.as_ref().unwrap()).unwrap()).unwrap()
        };
        let (fwd, inv) = (load("model_fwd", &base.model_fwd), load("model_inv", &base.model_inv));
        let other_inv = Model::load(root().join("models/tcn_inverse_L80.onnx")).unwrap();
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
