//! Heap accounting and containment for real-time paths.
//!
//! iceoryx2 0.10 allocates one 48-byte `Rc` per loaned sample (`Publisher::loan_uninit`, upstream
//! issue #101), so a cycle that publishes cannot be allocation-free through the public API. [`RtAlloc`]
//! contains it instead of hiding it: installed as the `#[global_allocator]` of a process (the `bowden`
//! binary, the allocation test, the IPC bench), it serves blocks of at most [`POOL_BLOCK_BYTES`] from a
//! static, pre-faulted arena through a per-thread free list — O(1), no lock, no system call, no page
//! fault — once [`enable_pool`] has been called. Everything else goes to the system allocator.
//!
//! It also counts, per thread, how often each path is taken ([`thread_counts`]), which is what the
//! counting-allocator test of the cycle and `bowden bench ipc` read: the cycle makes zero calls into
//! the system allocator; the number of pool blocks it takes (one per published sample) is measured
//! and reported rather than assumed.

use core::cell::{Cell, UnsafeCell};
use core::ptr::null_mut;
use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::alloc::{GlobalAlloc, Layout, System};

/// Largest allocation (and alignment) the pool serves. Covers iceoryx2's 48-byte per-loan `Rc`.
pub const POOL_BLOCK_BYTES: usize = 64;
/// Blocks in the arena (256 KiB): far more than the samples a process ever has in flight.
pub const POOL_BLOCKS: usize = 4096;

#[repr(C, align(64))]
struct Arena(UnsafeCell<[u8; POOL_BLOCK_BYTES * POOL_BLOCKS]>);

// SAFETY: blocks are handed out exclusively (bump index or free list), never shared.
unsafe impl Sync for Arena {}

static ARENA: Arena = Arena(UnsafeCell::new([0; POOL_BLOCK_BYTES * POOL_BLOCKS]));
/// Index of the next never-used block.
static ARENA_NEXT: AtomicUsize = AtomicUsize::new(0);
static POOL_ENABLED: AtomicBool = AtomicBool::new(false);

struct FreeBlock {
    next: *mut FreeBlock,
}

thread_local! {
    static FREE_LIST: Cell<*mut FreeBlock> = const { Cell::new(null_mut()) };
    static COUNTS: Cell<AllocCounts> = const { Cell::new(AllocCounts::ZERO) };
}

/// Allocation events of one thread since it started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AllocCounts {
    /// Calls that reached the system allocator (`malloc`/`realloc`).
    pub system_allocs: u64,
    /// Frees handed to the system allocator.
    pub system_frees: u64,
    /// Blocks taken from the pre-faulted pool.
    pub pool_allocs: u64,
    /// Blocks returned to the pool.
    pub pool_frees: u64,
    /// Bytes requested from the system allocator.
    pub system_bytes: u64,
}

impl AllocCounts {
    const ZERO: Self = Self {
        system_allocs: 0,
        system_frees: 0,
        pool_allocs: 0,
        pool_frees: 0,
        system_bytes: 0,
    };

    /// Events between `earlier` and `self` (both from the same thread).
    pub fn since(&self, earlier: &AllocCounts) -> AllocCounts {
        AllocCounts {
            system_allocs: self.system_allocs - earlier.system_allocs,
            system_frees: self.system_frees - earlier.system_frees,
            pool_allocs: self.pool_allocs - earlier.pool_allocs,
            pool_frees: self.pool_frees - earlier.pool_frees,
            system_bytes: self.system_bytes - earlier.system_bytes,
        }
    }

    /// Any allocation at all (system or pool).
    pub fn total_allocs(&self) -> u64 {
        self.system_allocs + self.pool_allocs
    }
}

/// The counting, pool-backed global allocator. Install with
/// `#[global_allocator] static A: bowden_runtime::alloc::RtAlloc = bowden_runtime::alloc::RtAlloc;`
pub struct RtAlloc;

/// Counters of the calling thread (all zero if [`RtAlloc`] is not the global allocator).
pub fn thread_counts() -> AllocCounts {
    COUNTS.try_with(|c| c.get()).unwrap_or_default()
}

/// Serve small allocations from the pool from now on (process-wide). Call once at start-up of a
/// real-time process, after [`crate::rt::lock_memory`] so the arena is resident.
pub fn enable_pool() {
    prefault();
    POOL_ENABLED.store(true, Ordering::Release);
}

/// Turns pool service off again (blocks already handed out still return to it). For
/// measurements that compare the pool with the system allocator.
pub fn disable_pool() {
    POOL_ENABLED.store(false, Ordering::Release);
}

/// Whether [`enable_pool`] was called.
pub fn pool_enabled() -> bool {
    POOL_ENABLED.load(Ordering::Acquire)
}

/// Blocks of the arena ever handed out (high-water mark, process-wide).
pub fn pool_high_water() -> usize {
    ARENA_NEXT.load(Ordering::Relaxed).min(POOL_BLOCKS)
}

/// Touches every page of the arena so the first use of a block cannot page-fault.
fn prefault() {
    let base = ARENA.0.get() as *mut u8;
    let mut off = 0;
    while off < POOL_BLOCK_BYTES * POOL_BLOCKS {
        // SAFETY: in bounds; a volatile read of a byte nobody else writes concurrently at start-up
        // (blocks not yet handed out), or of a handed-out block (reading is harmless).
        unsafe { core::ptr::read_volatile(base.add(off)) };
        off += 4096;
    }
}

#[inline]
fn in_arena(ptr: *mut u8) -> bool {
    let base = ARENA.0.get() as usize;
    let p = ptr as usize;
    p >= base && p < base + POOL_BLOCK_BYTES * POOL_BLOCKS
}

#[inline]
fn bump(f: impl FnOnce(&mut AllocCounts)) {
    let _ = COUNTS.try_with(|c| {
        let mut v = c.get();
        f(&mut v);
        c.set(v);
    });
}

#[inline]
fn pool_take() -> *mut u8 {
    let from_list = FREE_LIST
        .try_with(|head| {
            let h = head.get();
            if h.is_null() {
                null_mut()
            } else {
                // SAFETY: `h` is a block of the arena that this thread freed; its first word is the link.
                head.set(unsafe { (*h).next });
                h as *mut u8
            }
        })
        .unwrap_or(null_mut());
    if !from_list.is_null() {
        return from_list;
    }
    let i = ARENA_NEXT.fetch_add(1, Ordering::Relaxed);
    if i < POOL_BLOCKS {
        // SAFETY: block `i` lies within the arena and was never handed out.
        unsafe { (ARENA.0.get() as *mut u8).add(i * POOL_BLOCK_BYTES) }
    } else {
        null_mut()
    }
}

#[inline]
fn pool_give(ptr: *mut u8) {
    let block = ptr as *mut FreeBlock;
    let pushed = FREE_LIST.try_with(|head| {
        // SAFETY: `ptr` is an arena block being freed by its owner; it becomes a list node.
        unsafe { (*block).next = head.get() };
        head.set(block);
    });
    // A thread being torn down cannot take the block back: it is leaked (bounded by the arena).
    let _ = pushed;
}

unsafe impl GlobalAlloc for RtAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() <= POOL_BLOCK_BYTES
            && layout.align() <= POOL_BLOCK_BYTES
            && POOL_ENABLED.load(Ordering::Relaxed)
        {
            let p = pool_take();
            if !p.is_null() {
                bump(|c| c.pool_allocs += 1);
                return p;
            }
        }
        bump(|c| {
            c.system_allocs += 1;
            c.system_bytes += layout.size() as u64;
        });
        // SAFETY: forwarded with the caller's layout.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() <= POOL_BLOCK_BYTES
            && layout.align() <= POOL_BLOCK_BYTES
            && POOL_ENABLED.load(Ordering::Relaxed)
        {
            let p = pool_take();
            if !p.is_null() {
                bump(|c| c.pool_allocs += 1);
                // SAFETY: `p` is a whole block of POOL_BLOCK_BYTES ≥ layout.size().
                unsafe { core::ptr::write_bytes(p, 0, layout.size()) };
                return p;
            }
        }
        bump(|c| {
            c.system_allocs += 1;
            c.system_bytes += layout.size() as u64;
        });
        // SAFETY: forwarded with the caller's layout.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if in_arena(ptr) {
            bump(|c| c.pool_frees += 1);
            pool_give(ptr);
        } else {
            bump(|c| c.system_frees += 1);
            // SAFETY: `ptr` came from System with this layout.
            unsafe { System.dealloc(ptr, layout) }
        }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if in_arena(ptr) {
            if new_size <= POOL_BLOCK_BYTES {
                return ptr;
            }
            // SAFETY: a valid layout (align ≤ 64, size checked by the caller's contract).
            let new_layout = unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) };
            bump(|c| {
                c.system_allocs += 1;
                c.system_bytes += new_size as u64;
            });
            // SAFETY: fresh system block, copy the old contents, give the block back.
            let p = unsafe { System.alloc(new_layout) };
            if !p.is_null() {
                unsafe { core::ptr::copy_nonoverlapping(ptr, p, layout.size()) };
                bump(|c| c.pool_frees += 1);
                pool_give(ptr);
            }
            return p;
        }
        bump(|c| {
            c.system_allocs += 1;
            c.system_bytes += new_size as u64;
        });
        // SAFETY: `ptr` came from System with `layout`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}
