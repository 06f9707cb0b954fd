//! The plant step is a real-time path: no heap allocation. A counting global allocator in a
//! test binary of its own proves it. The count is per thread: libtest's main thread may allocate
//! (its bookkeeping of running tests) while the test thread is inside the measured region, and
//! that must not be charged to the plant.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;
thread_local! {
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
}

fn allocations() -> usize {
    ALLOCS.with(|c| c.get())
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn step_settle_and_errors_do_not_allocate() {
    use bowden_plant::PlantConfig;
    let mut cfg = PlantConfig::paper_default();
    cfg.drift.rate_mm_per_hour = [0.2; 10]; // exercise the creep path too
    real_time_path_does_not_allocate(&cfg);
    // And slack starting mid-run: creep from 0.3 s, a slip at 0.5 s.
    cfg.drift.start_s = 0.3;
    cfg.drift.slip.push(bowden_plant::config::SlipConfig {
        at_s: 0.5,
        cable: 3,
        mm: 0.2,
    });
    real_time_path_does_not_allocate(&cfg);
}

/// The same for the other hysteresis families (configs/plant-boucwen.toml, plant-lugre.toml,
/// plant-preisach.toml).
#[test]
fn every_family_steps_without_allocating() {
    use bowden_plant::PlantConfig;
    for file in ["plant-boucwen.toml", "plant-lugre.toml", "plant-preisach.toml"] {
        let path = format!("{}/../../configs/{file}", env!("CARGO_MANIFEST_DIR"));
        let mut cfg = PlantConfig::load(&path).unwrap();
        cfg.drift.rate_mm_per_hour = [0.2; 10];
        real_time_path_does_not_allocate(&cfg);
    }
}

fn real_time_path_does_not_allocate(cfg: &bowden_plant::PlantConfig) {
    use bowden_kinematics::Robot;
    use bowden_plant::Plant;

    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, cfg, 1);
    let cmds: Vec<[f64; 10]> = bowden_trajectory::dataset_commands(&robot, 20, 4)
        .iter()
        .map(|q| robot.cables().displacements_mm(q))
        .collect();
    let mut bad = cmds[0];
    bad[3] = f64::NAN;
    let mut state = bowden_interfaces::PlantState::default();

    let before = allocations();
    let mut sum = 0.0;
    for w in &cmds {
        plant.step(w, 0.001).unwrap();
        plant.settle(w, 0.05, 0.001).unwrap();
        assert!(plant.step(&bad, 0.001).is_err());
        assert!(plant.step(w, -1.0).is_err());
        plant.fill_state(&mut state);
        sum += state.q_phy_deg[0] + plant.q_cmd_deg()[1] + plant.t_sim_ns() as f64;
    }
    let after = allocations();
    assert!(sum.is_finite());
    assert_eq!(
        after - before,
        0,
        "the plant `{}` allocated {} times in its real-time path",
        cfg.name,
        after - before
    );
}
