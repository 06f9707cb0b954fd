//! No allocation per frame after warm-up: a counting global allocator around `estimate` and
//! `estimate_payload`, over clean, occluded and malformed frames. (A test binary of its own:
//! the allocator counts every allocation of this thread.)

use crate::common;

use bowden_estimator::eval::random_configuration;
use bowden_interfaces::{marker, JointEstimate, MarkerSet};
use rand::SeedableRng;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCS.with(|c| c.get())
}

#[test]
fn estimate_does_not_allocate_after_warm_up() {
    let mut cam = common::camera(9);
    let mut est = common::estimator();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    // Frames prepared up front: workspace configurations, one with hidden markers, one
    // with a wrong depth (leave-one-out path), and payload copies.
    let mut frames = Vec::new();
    for i in 0..12 {
        let q = random_configuration(est.robot(), &mut rng);
        frames.push((q, common::render(&mut cam, &q, i)));
    }
    let mut hidden = common::render(&mut cam, &common::Q_ALL_VISIBLE, 100);
    common::paint_out_marker(&mut hidden, cam.labels(), marker::RIGHT_Y0);
    common::paint_out_marker(&mut hidden, cam.labels(), marker::RIGHT_G0);
    let mut shifted = common::render(&mut cam, &common::Q_ALL_VISIBLE, 101);
    for i in common::marker_pixels(cam.labels(), marker::RIGHT_Y0) {
        shifted.depth[i] = shifted.depth[i].saturating_add(15);
    }
    frames.push((common::Q_ALL_VISIBLE, hidden));
    frames.push((common::Q_ALL_VISIBLE, shifted));
    let mut payload = vec![0u8; cam.payload_len()];
    cam.render_into_payload(&frames[0].0, 0, &mut payload).unwrap();
    let header = frames[0].1.header;
    let (mut ms, mut je) = (MarkerSet::default(), JointEstimate::default());

    est.reserve_frame(640, 480);
    let before = allocations();
    let mut valid = 0;
    for round in 0..2 {
        for (q, f) in &frames {
            let hint = if round == 0 { Some(*q) } else { None };
            est.estimate(&f.header, &f.rgb, &f.depth, hint, &mut ms, &mut je)
                .unwrap();
            valid += (je.quality == JointEstimate::QUALITY_VALID) as u32;
        }
        est.estimate_payload(&header, &payload, None, &mut ms, &mut je).unwrap();
        // Malformed frames: errors, also without allocating.
        assert!(est
            .estimate(
                &header,
                &frames[0].1.rgb[1..],
                &frames[0].1.depth,
                None,
                &mut ms,
                &mut je
            )
            .is_err());
        assert!(est
            .estimate_payload(&header, &payload[..100], None, &mut ms, &mut je)
            .is_err());
    }
    let after = allocations();
    assert_eq!(after - before, 0, "estimate allocated {} times", after - before);
    assert!(
        valid >= 20,
        "the frames exercised the full path ({valid} valid estimates)"
    );
}
