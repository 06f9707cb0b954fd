//! The training helper: one persistent thread that runs the second half of each fork
//! ([`Helper::fork2`]) and *spins* between forks instead of sleeping.
//!
//! Why not a thread pool: a training step forks more than once per batch (the two shards,
//! then the optimiser's two halves) with gaps of 50–150 µs between forks. A pool's worker
//! (rayon's, which this replaced) goes to sleep in such a gap, and waking it through the
//! kernel made the forked optimiser slower than one thread doing it all (LSTM, 77,701
//! parameters, 2-vCPU guest of 2026-11-28: 122 µs per batch forked on rayon, 53 µs on one
//! thread, 30 µs forked on this helper). This helper spins on an atomic for up to [`SPIN`]
//! after each job, so a fork within that time starts at once; after it, it parks and the
//! next fork wakes it as a pool would.
//!
//! Soundness: [`Helper::fork2`] lends the helper a closure that borrows the caller's stack
//! and does not return until the helper has finished it, also when the caller's own half
//! panics (a guard waits in its `Drop`), exactly as `std::thread::scope` does. A panic in
//! the helper's half is caught there and re-raised in the caller.

use std::any::Any;
use std::cell::UnsafeCell;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

/// How long the helper spins for the next job before it parks.
pub const SPIN: Duration = Duration::from_millis(2);

/// A job lent to the helper: a type-erased pointer to the caller's closure.
type Job = *mut (dyn FnMut() + Send);

struct Shared {
    /// Jobs posted so far; the helper runs job `n` when it sees `posted` reach `n`.
    posted: AtomicU64,
    /// Jobs finished so far.
    finished: AtomicU64,
    /// Set by the helper just before it parks (read by the poster to know it must unpark).
    parked: AtomicBool,
    shutdown: AtomicBool,
    /// The job of the latest post: written by the poster before `posted` is raised, read by
    /// the helper after it saw `posted` raised, never both at once.
    job: UnsafeCell<Option<Job>>,
    /// A panic of the latest job: written by the helper before `finished` is raised, read by
    /// the poster after it saw it raised.
    panic: UnsafeCell<Option<Box<dyn Any + Send>>>,
}

// SAFETY: `job` and `panic` are handed over by the release/acquire pairs on `posted` and
// `finished` (see their docs): one side writes, raises the counter; the other reads after
// seeing it. The job pointer is only dereferenced while its owner waits in `fork2`.
unsafe impl Sync for Shared {}
unsafe impl Send for Shared {}

/// One persistent helper thread (see the module docs).
pub struct Helper {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl Helper {
    /// Starts the helper thread, named `name`.
    pub fn new(name: &str) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            posted: AtomicU64::new(0),
            finished: AtomicU64::new(0),
            parked: AtomicBool::new(false),
            shutdown: AtomicBool::new(false),
            job: UnsafeCell::new(None),
            panic: UnsafeCell::new(None),
        });
        let s = Arc::clone(&shared);
        let thread = thread::Builder::new().name(name.to_string()).spawn(move || run(&s))?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Runs `a` on this thread and `b` on the helper at the same time; returns both results
    /// once both have finished. A panic in either is re-raised here after both stopped.
    pub fn fork2<RA, RB: Send>(&self, a: impl FnOnce() -> RA, b: impl FnOnce() -> RB + Send) -> (RA, RB) {
        let mut b = Some(b);
        let mut rb: Option<RB> = None;
        let mut call = || {
            if let Some(f) = b.take() {
                rb = Some(f());
            }
        };
        let borrowed: &mut (dyn FnMut() + Send + '_) = &mut call;
        // SAFETY: only the lifetime is erased. The helper calls the closure before it raises
        // `finished`, and this function does not return (nor unwind past `wait`) before it
        // saw `finished` reach this job, so the borrow outlives every use.
        let job: Job = unsafe { std::mem::transmute::<*mut (dyn FnMut() + Send + '_), Job>(borrowed) };
        let s = &*self.shared;
        let n = s.posted.load(Ordering::Relaxed) + 1;
        // SAFETY: the helper has finished every earlier job (each fork waits for its own), so
        // it touches neither slot until `posted` is raised below. (A panic left over from a
        // fork whose own half panicked too is dropped here.)
        unsafe {
            *s.job.get() = Some(job);
            *s.panic.get() = None;
        }
        s.posted.store(n, Ordering::SeqCst);
        if s.parked.load(Ordering::SeqCst) {
            if let Some(t) = &self.thread {
                t.thread().unpark();
            }
        }
        let ra = {
            let _wait = WaitFor { s, n };
            a()
        };
        // SAFETY: `finished` reached `n` (WaitFor's drop): the helper wrote `panic` before.
        if let Some(p) = unsafe { (*s.panic.get()).take() } {
            resume_unwind(p);
        }
        (ra, rb.expect("the helper ran its half"))
    }
}

/// Waits (spinning, then yielding) until the helper has finished job `n`; in `Drop`, so a
/// panic in the caller's half still waits before the borrowed closure goes away.
struct WaitFor<'a> {
    s: &'a Shared,
    n: u64,
}

impl Drop for WaitFor<'_> {
    fn drop(&mut self) {
        let mut spins = 0u32;
        while self.s.finished.load(Ordering::Acquire) < self.n {
            if spins < 1 << 14 {
                spins += 1;
                std::hint::spin_loop();
            } else {
                // The helper was descheduled: let it run.
                thread::yield_now();
            }
        }
    }
}

fn run(s: &Shared) {
    let mut seen = 0u64;
    loop {
        // Spin for the next job, then park.
        let t0 = Instant::now();
        let mut spins = 0u32;
        loop {
            if s.posted.load(Ordering::Acquire) > seen || s.shutdown.load(Ordering::Acquire) {
                break;
            }
            spins = spins.wrapping_add(1);
            if spins.is_multiple_of(256) && t0.elapsed() > SPIN {
                s.parked.store(true, Ordering::SeqCst);
                // Re-check after announcing the park: a post between the check above and
                // the store saw `parked` false and did not unpark, so it must be seen here.
                if s.posted.load(Ordering::SeqCst) == seen && !s.shutdown.load(Ordering::SeqCst) {
                    thread::park();
                }
                s.parked.store(false, Ordering::SeqCst);
            } else {
                std::hint::spin_loop();
            }
        }
        if s.shutdown.load(Ordering::Acquire) && s.posted.load(Ordering::Acquire) == seen {
            return;
        }
        seen += 1;
        // SAFETY: `posted` reached `seen` (acquire): the poster wrote `job` before it, and
        // waits for `finished` before touching it or the closure again.
        let job = unsafe { (*s.job.get()).take() };
        if let Some(job) = job {
            // SAFETY: the closure lives until its poster sees `finished` reach `seen`.
            let result = catch_unwind(AssertUnwindSafe(|| unsafe { (*job)() }));
            if let Err(p) = result {
                // SAFETY: the poster reads `panic` only after `finished` is raised below.
                unsafe { *s.panic.get() = Some(p) };
            }
        }
        s.finished.store(seen, Ordering::Release);
    }
}

impl Drop for Helper {
    fn drop(&mut self) {
        self.shared.shutdown.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_halves_run_and_return_their_results() {
        let h = Helper::new("test-helper").unwrap();
        let mut left = vec![0u64; 1000];
        let mut right = vec![0u64; 1000];
        for round in 0..200u64 {
            let (a, b) = h.fork2(
                || {
                    left.iter_mut().for_each(|v| *v += round);
                    left.iter().sum::<u64>()
                },
                || {
                    right.iter_mut().for_each(|v| *v += 2 * round);
                    right.iter().sum::<u64>()
                },
            );
            let tri = round * (round + 1) / 2;
            assert_eq!(a, 1000 * tri);
            assert_eq!(b, 2000 * tri);
        }
    }

    #[test]
    fn a_parked_helper_is_woken_by_the_next_fork() {
        let h = Helper::new("test-helper").unwrap();
        assert_eq!(h.fork2(|| 1, || 2), (1, 2));
        // Longer than the spin: the helper parks, and the next fork must wake it.
        thread::sleep(SPIN * 3);
        assert!(
            h.shared.parked.load(Ordering::SeqCst),
            "the helper parked after its spin"
        );
        assert_eq!(h.fork2(|| 3, || 4), (3, 4));
    }

    #[test]
    fn a_panic_in_the_helpers_half_reaches_the_caller_and_the_helper_survives() {
        let h = Helper::new("test-helper").unwrap();
        let r = catch_unwind(AssertUnwindSafe(|| h.fork2(|| 1, || -> u32 { panic!("helper half") })));
        assert!(r.is_err());
        assert_eq!(h.fork2(|| 5, || 6), (5, 6));
    }
}
