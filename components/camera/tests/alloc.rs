//! The render path allocates nothing after construction: proven with a counting global
//! allocator (this test binary's own).

use bowden_camera::{CameraConfig, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

struct Counting;
static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::SeqCst) {
            ALLOCS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::SeqCst) {
            ALLOCS.fetch_add(1, Ordering::SeqCst);
        }
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
    // The only test in this binary, so no other thread allocates while counting.
    COUNTING.store(true, Ordering::SeqCst);
    for (k, q) in qs.iter().enumerate() {
        cam.render(q, k as u64, &mut rgb, &mut depth).expect("render");
        cam.render_into_payload(q, k as u64, &mut payload).expect("payload");
        let _ = cam.marker_centres_cam_mm(q);
        let _ = cam.header(k as u64, k as u64, 0);
    }
    // Rejections allocate nothing either.
    let _ = cam.render(&[f64::NAN; 5], 0, &mut rgb, &mut depth);
    COUNTING.store(false, Ordering::SeqCst);
    assert_eq!(ALLOCS.load(Ordering::SeqCst), 0, "allocations in the render path");
}
