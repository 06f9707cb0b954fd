//! The render path allocates nothing after construction: proven with a counting global
//! allocator (this test binary's own). Counting is per thread: libtest's main thread may allocate
//! its own bookkeeping while the test runs, and the render path is single-threaded.

use bowden_camera::{CameraConfig, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;
thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    if COUNTING.try_with(|c| c.get()).unwrap_or(false) {
        let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
    }
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
fn render_allocates_nothing_after_construction() {
    let mut cam = SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        1,
    );
    let px = (cam.width() * cam.height()) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let mut payload = vec![0u8; cam.payload_len()];
    let qs = [
        [0.0; 5],
        [60.0, -60.0, 44.0, -50.0, 50.0],
        [-35.0, 20.0, -10.0, 5.0, 5.0],
    ];
    COUNTING.with(|c| c.set(true));
    for (k, q) in qs.iter().enumerate() {
        cam.render(q, k as u64, &mut rgb, &mut depth).expect("render");
        cam.render_into_payload(q, k as u64, &mut payload).expect("payload");
        let _ = cam.marker_centres_cam_mm(q);
        let _ = cam.header(k as u64, k as u64, 0);
    }
    // Rejections allocate nothing either.
    let _ = cam.render(&[f64::NAN; 5], 0, &mut rgb, &mut depth);
    COUNTING.with(|c| c.set(false));
    assert_eq!(ALLOCS.with(|a| a.get()), 0, "allocations in the render path");
}
