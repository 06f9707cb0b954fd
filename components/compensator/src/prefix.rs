//! Window prefixes computed off the cycle, on a worker thread, double-buffered.
//!
//! When the history gains an entry, the first L − 1 columns of every layer (and an LSTM's
//! state after L − 1 steps) must be recomputed before the next trial sees the new window. For
//! the shipped LSTM inverse model that is 79 steps of a 512×133 matrix–vector product plus
//! 640 transcendental functions each: 0.6 ms with the blocked kernel of [`crate::net`]
//! (1.45 ms before it), on a shared 2-core machine up to several ms, the better part of a
//! 1 kHz period or more. With a
//! [`PrefixWorker`] the cycle never computes it. Each model has three evaluators: the
//! *active* one the step runs trials on, a *ready* one (the newest prefix the worker
//! finished) and one the worker computes into. After a history step the cycle posts the new
//! history (a copy of (L − 1)·J numbers into a preallocated buffer); the worker computes the
//! prefix into its own evaluator and publishes it as *ready*; the next step adopts it by
//! exchanging two boxes. Nothing is allocated or freed on the cycle, and in
//! [`PrefixSync::Newest`] (real time) it never blocks: every lock it takes is a `try_lock`,
//! held for a pointer exchange only.
//!
//! **What changes in the function computed.** The prefix bits are those of the in-step
//! computation whichever evaluator computes them (`set_history` and `shift_history` are
//! bit-identical, and both run the same kernels), so:
//! - [`PrefixSync::Wait`] (lockstep, tests): the step waits for the prefix of the current
//!   history; commands are bit-identical to computing it in the step.
//! - [`PrefixSync::Newest`] (real time): the step uses the newest *complete* prefix. For the
//!   few cycles after a history step until the worker finishes, the trials run on the
//!   previous window (the newest history entry missing, the oldest one still present); the
//!   step reports how many entries its prefix lags in [`crate::StepOutput::prefix_lag`].
//!   At construction, after `reset` and after a model swap there is no complete prefix of
//!   the current models and history: it is then computed in place (construction and
//!   `reset` are not cycles; after a swap `Compensator::prepare` computes it, after the
//!   command went out, as without the worker, so a swap costs one in-cycle prefix).

use crate::net::{IncrementalNet, Net};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, TryLockError};
use std::thread::JoinHandle;

/// How the step treats a prefix the worker has not finished yet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PrefixSync {
    /// Block until the worker delivered the prefix of the current history (lockstep: the
    /// commands are bit-identical to an in-step prefix).
    Wait,
    /// Never block: run on the newest complete prefix (real time).
    Newest,
}

/// Settings of [`crate::Compensator::start_prefix_worker`].
pub struct PrefixWorkerOptions {
    pub sync: PrefixSync,
    /// Thread name (shows in `top -H`, `ps -L`).
    pub name: String,
    /// Runs first on the worker thread: where the runtime places it (CPU affinity, policy).
    /// The thread inherits its creator's scheduling; a real-time creator should move it off
    /// the real-time CPUs or below their priority here.
    pub on_start: Option<Box<dyn FnOnce() + Send>>,
}

impl std::fmt::Debug for PrefixWorkerOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PrefixWorkerOptions")
            .field("sync", &self.sync)
            .field("name", &self.name)
            .field("on_start", &self.on_start.is_some())
            .finish()
    }
}

/// A history state: `epoch` changes at every reset, `count` is the number of entries
/// appended since the reset ([`crate::History::appended_total`]). A prefix of key (e, n) is
/// shifted to (e, n + 1); any other change is a full recomputation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Key {
    pub epoch: u64,
    pub count: u64,
}

/// An evaluator, the key of the prefix it holds (`None`: none valid) and the generation of
/// the model it evaluates (one per swap).
struct Held {
    net: Box<IncrementalNet>,
    key: Option<Key>,
    gen: u64,
}

/// One model's hand-over slot.
struct Slot {
    /// A swapped-in model and its generation: the worker replaces its evaluators.
    new_model: Option<(Arc<Net>, u64)>,
    /// The newest history posted, its key and model generation (`None`: nothing to do).
    req_hist: Vec<f64>,
    req: Option<(Key, u64)>,
    /// The newest prefix the worker finished.
    ready: Option<Held>,
    /// Evaluators for the worker's next jobs (the ones the cycle gave back). Three evaluators
    /// circulate per model (active, ready, the worker's), so one entry is always free when
    /// the cycle gives one back; two, because right after a swap the active evaluator is the
    /// swapped-in one and both others are the worker's fresh ones.
    spare: [Option<Held>; 2],
}

struct State {
    slots: [Option<Slot>; 2],
    stop: bool,
    /// The worker thread ended (a panic): the cycle computes prefixes itself.
    dead: bool,
}

struct Shared {
    state: Mutex<State>,
    /// The worker waits here for requests.
    work: Condvar,
    /// A `Wait` step waits here for results.
    done: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // Every update under the lock is a complete assignment of boxes and keys, so a
        // poisoned lock (a panic elsewhere) leaves consistent data.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
    fn try_lock(&self) -> Option<MutexGuard<'_, State>> {
        match self.state.try_lock() {
            Ok(g) => Some(g),
            Err(TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(TryLockError::WouldBlock) => None,
        }
    }
}

/// The cycle's view of one model.
struct Side {
    /// Key of the prefix in the active evaluator (`None`: none valid).
    active: Option<Key>,
    /// Key of the current history.
    wanted: Key,
    /// `wanted` and its history are in the slot.
    posted: bool,
    /// Generation of the active model.
    gen: u64,
    /// A swapped-in model not yet handed to the worker.
    new_model: Option<Arc<Net>>,
}

/// Index of the forward / inverse model in the worker's slots.
pub(crate) const FWD: usize = 0;
pub(crate) const INV: usize = 1;

/// The worker thread and the cycle's bookkeeping (owned by the [`crate::Compensator`]).
pub(crate) struct PrefixWorker {
    shared: Arc<Shared>,
    handle: Option<JoinHandle<()>>,
    sync: PrefixSync,
    sides: [Option<Side>; 2],
    epoch: u64,
}

impl PrefixWorker {
    /// Starts the worker for the models given (`None`: not handled here): each active
    /// evaluator's prefix must be valid for the history of `count` entries; `hist_len` is
    /// (L − 1)·J. Allocates the two other evaluators of each model; not for the cycle.
    pub(crate) fn spawn(
        models: [Option<(&IncrementalNet, usize)>; 2],
        count: u64,
        opts: PrefixWorkerOptions,
    ) -> std::io::Result<Self> {
        let key = Key { epoch: 0, count };
        let mut slots: [Option<Slot>; 2] = [None, None];
        let mut work: [Option<Held>; 2] = [None, None];
        let mut sides = [None, None];
        for (m, model) in models.iter().enumerate() {
            let Some((net, hist_len)) = model else { continue };
            let fresh = || Held {
                net: Box::new(IncrementalNet::new(net.net_arc().clone())),
                key: None,
                gen: 0,
            };
            slots[m] = Some(Slot {
                new_model: None,
                req_hist: vec![0.0; *hist_len],
                req: None,
                ready: None,
                spare: [Some(fresh()), None],
            });
            work[m] = Some(fresh());
            sides[m] = Some(Side {
                active: Some(key),
                wanted: key,
                posted: true,
                gen: 0,
                new_model: None,
            });
        }
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                slots,
                stop: false,
                dead: false,
            }),
            work: Condvar::new(),
            done: Condvar::new(),
        });
        let sh = shared.clone();
        let on_start = opts.on_start;
        let handle = std::thread::Builder::new().name(opts.name).spawn(move || {
            // Whatever ends this thread, a waiting step must learn it.
            struct Dead<'a>(&'a Shared);
            impl Drop for Dead<'_> {
                fn drop(&mut self) {
                    self.0.lock().dead = true;
                    self.0.done.notify_all();
                }
            }
            let _dead = Dead(&sh);
            if let Some(f) = on_start {
                f();
            }
            worker_main(&sh, work);
        })?;
        Ok(Self {
            shared,
            handle: Some(handle),
            sync: opts.sync,
            sides,
            epoch: 0,
        })
    }

    pub(crate) fn sync_mode(&self) -> PrefixSync {
        self.sync
    }

    /// Whether model `m` is handled by the worker.
    pub(crate) fn handles(&self, m: usize) -> bool {
        self.sides[m].is_some()
    }

    /// The history advanced to `count` entries since the reset. Allocation-free.
    pub(crate) fn advanced(&mut self, count: u64) {
        let epoch = self.epoch;
        for s in self.sides.iter_mut().flatten() {
            s.wanted = Key { epoch, count };
            s.posted = false;
        }
    }

    /// The history was reset (to `count` entries, 0) and every handled model's active prefix
    /// recomputed in place by the caller: a new epoch, whose keys no older result matches.
    pub(crate) fn restarted(&mut self, count: u64) {
        self.epoch += 1;
        let key = Key {
            epoch: self.epoch,
            count,
        };
        for s in self.sides.iter_mut().flatten() {
            s.active = Some(key);
            s.wanted = key;
            s.posted = true;
        }
    }

    /// Model `m` was swapped for an evaluator of `net` (without a prefix): results for the
    /// old model are never adopted, and the worker rebuilds its evaluator of the model at the
    /// next post. Allocation-free (an `Arc` clone).
    pub(crate) fn swapped(&mut self, m: usize, net: &Arc<Net>) {
        if let Some(s) = self.sides[m].as_mut() {
            s.gen += 1;
            s.active = None;
            s.posted = false;
            s.new_model = Some(net.clone());
        }
    }

    /// Whether model `m`'s active evaluator holds no prefix of the current model and epoch
    /// (after a swap): the next [`Self::sync`] would compute one in place.
    pub(crate) fn unusable(&self, m: usize) -> bool {
        self.sides[m]
            .as_ref()
            .is_some_and(|s| s.active.is_none_or(|a| a.epoch != s.wanted.epoch))
    }

    /// Model `m` is no longer handled (a swap brought in an evaluator without a prefix split).
    /// The slot's evaluators stay with the worker until it ends.
    pub(crate) fn release(&mut self, m: usize) {
        self.sides[m] = None;
    }

    /// Hands model `m`'s pending model change and history to the worker. `Newest`: only if
    /// the lock is free at once (else it is retried at the next call).
    pub(crate) fn post(&mut self, m: usize, hist: &[f64]) {
        let Some(side) = self.sides[m].as_mut() else { return };
        if side.posted {
            return;
        }
        let mut g = match self.sync {
            PrefixSync::Wait => self.shared.lock(),
            PrefixSync::Newest => match self.shared.try_lock() {
                Some(g) => g,
                None => return,
            },
        };
        post_locked(&mut g, m, side, hist);
        drop(g);
        self.shared.work.notify_one();
    }

    /// Brings model `m`'s active evaluator to the newest prefix available (`Newest`) or to
    /// the prefix of the current history (`Wait`), computing it in place only when the
    /// active evaluator holds no prefix of the current model and epoch, or the worker died.
    /// Returns how many history entries the prefix in use lags. Allocation-free.
    pub(crate) fn sync(&mut self, m: usize, active: &mut Box<IncrementalNet>, hist: &[f64]) -> u32 {
        let Some(side) = self.sides[m].as_mut() else { return 0 };
        let mut dead = false;
        if side.active != Some(side.wanted) {
            let guard = match self.sync {
                PrefixSync::Wait => Some(self.shared.lock()),
                PrefixSync::Newest => self.shared.try_lock(),
            };
            if let Some(mut g) = guard {
                let mut wake = false;
                if !side.posted {
                    post_locked(&mut g, m, side, hist);
                    wake = true;
                }
                loop {
                    if adopt(&mut g, m, side, active) {
                        // The worker may be waiting for the evaluator just given back.
                        wake |= g.slots[m].as_ref().is_some_and(|s| s.req.is_some());
                    }
                    dead = g.dead;
                    if side.active == Some(side.wanted) || self.sync == PrefixSync::Newest || dead {
                        break;
                    }
                    if wake {
                        self.shared.work.notify_one();
                        wake = false;
                    }
                    g = self.shared.done.wait(g).unwrap_or_else(|p| p.into_inner());
                }
                drop(g);
                if wake {
                    self.shared.work.notify_one();
                }
            }
        }
        let usable = side.active.is_some_and(|a| a.epoch == side.wanted.epoch);
        let complete = side.active == Some(side.wanted);
        if !usable || (!complete && (dead || self.sync == PrefixSync::Wait)) {
            // No prefix of this model and epoch (construction, reset, swap), or no worker to
            // deliver one: compute it here.
            active.set_history(hist);
            side.active = Some(side.wanted);
        }
        side.active.map_or(0, |a| {
            side.wanted.count.saturating_sub(a.count).min(u32::MAX as u64) as u32
        })
    }

    /// Blocks until the worker delivered the prefix of the current history for every model
    /// it handles and adopts it (tests, lockstep checks). Not for the cycle.
    pub(crate) fn wait_idle(&mut self, m: usize, active: &mut Box<IncrementalNet>, hist: &[f64]) {
        let sync = self.sync;
        self.sync = PrefixSync::Wait;
        self.post(m, hist);
        self.sync(m, active, hist);
        self.sync = sync;
    }
}

impl Drop for PrefixWorker {
    fn drop(&mut self) {
        self.shared.lock().stop = true;
        self.shared.work.notify_all();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

fn post_locked(g: &mut State, m: usize, side: &mut Side, hist: &[f64]) {
    let Some(slot) = g.slots[m].as_mut() else { return };
    if let Some(net) = side.new_model.take() {
        // Superseding an unprocessed change drops its Arc here: only a reference count, the
        // net itself is still held by the active evaluator or the worker.
        slot.new_model = Some((net, side.gen));
    }
    slot.req_hist.copy_from_slice(hist);
    slot.req = Some((side.wanted, side.gen));
    side.posted = true;
}

/// Adopts the slot's ready prefix if it is of the current model and epoch and newer than the
/// active one: the two boxes are exchanged, the old active evaluator goes back as the spare.
fn adopt(g: &mut State, m: usize, side: &mut Side, active: &mut Box<IncrementalNet>) -> bool {
    let Some(slot) = g.slots[m].as_mut() else { return false };
    let Some(r) = slot.ready.as_ref() else { return false };
    let Some(rk) = r.key else { return false };
    let newer = match side.active {
        Some(a) if a.epoch == rk.epoch => rk.count > a.count,
        _ => true,
    };
    let Some(free) = slot.spare.iter_mut().find(|s| s.is_none()) else {
        return false;
    };
    if r.gen != side.gen || rk.epoch != side.wanted.epoch || !newer {
        return false;
    }
    let mut r = slot.ready.take().expect("checked above");
    std::mem::swap(active, &mut r.net);
    *free = Some(Held {
        net: r.net,
        key: side.active,
        gen: side.gen,
    });
    side.active = Some(rk);
    true
}

/// The worker: model changes first, then the newest request of each model. Its own
/// evaluator per model (`work`) is the one it computes into; a finished one becomes the
/// slot's `ready`, and the worker continues with the evaluator that was ready before (not
/// adopted: superseded) or the spare the cycle gave back.
fn worker_main(sh: &Shared, mut work: [Option<Held>; 2]) {
    enum Job {
        Rebuild(usize, Arc<Net>, u64),
        Compute(usize, Key),
    }
    let mut hist: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    loop {
        let mut g = sh.lock();
        let job = loop {
            if g.stop {
                return;
            }
            let mut job = None;
            for m in 0..2 {
                let Some(slot) = g.slots[m].as_mut() else { continue };
                if let Some((net, gen)) = slot.new_model.take() {
                    job = Some(Job::Rebuild(m, net, gen));
                    break;
                }
            }
            if job.is_none() {
                for m in 0..2 {
                    let Some(slot) = g.slots[m].as_mut() else { continue };
                    let Some((key, gen)) = slot.req else { continue };
                    if work[m].is_none() {
                        work[m] = take_spare(slot);
                    }
                    if work[m].as_ref().is_some_and(|w| w.gen == gen) {
                        slot.req = None;
                        hist[m].clear();
                        hist[m].extend_from_slice(&slot.req_hist);
                        job = Some(Job::Compute(m, key));
                        break;
                    }
                }
            }
            if let Some(j) = job {
                break j;
            }
            g = sh.work.wait(g).unwrap_or_else(|p| p.into_inner());
        };
        drop(g);
        match job {
            Job::Rebuild(m, net, gen) => {
                // Two evaluators of the new model; the third is the swapped-in active one.
                let fresh = || Held {
                    net: Box::new(IncrementalNet::new(net.clone())),
                    key: None,
                    gen,
                };
                let (a, b) = (fresh(), fresh());
                let mut g = sh.lock();
                let Some(slot) = g.slots[m].as_mut() else { continue };
                if slot.new_model.is_some() {
                    // Superseded by another swap meanwhile: that one is next.
                    continue;
                }
                // The old model's evaluators are dropped here, off the cycle, after the lock.
                let old = (slot.ready.take(), std::mem::replace(&mut slot.spare, [Some(b), None]));
                let old_work = work[m].replace(a);
                drop(g);
                drop((old, old_work));
            }
            Job::Compute(m, key) => {
                let w = work[m].as_mut().expect("a job has an evaluator");
                let shift = w.key.is_some_and(|k| k.epoch == key.epoch && k.count + 1 == key.count);
                // shift_history is bit-identical to set_history (a test checks it).
                if shift {
                    w.net.shift_history(&hist[m]);
                } else {
                    w.net.set_history(&hist[m]);
                }
                w.key = Some(key);
                let mut g = sh.lock();
                let slot = g.slots[m].as_mut().expect("a job has a slot");
                let done = work[m].take().expect("computed above");
                if slot.new_model.is_some() {
                    // The model changed meanwhile: the result is of no use.
                    work[m] = Some(done);
                } else {
                    work[m] = slot.ready.replace(done).or_else(|| take_spare(slot));
                }
                drop(g);
                sh.done.notify_all();
            }
        }
    }
}

fn take_spare(slot: &mut Slot) -> Option<Held> {
    slot.spare.iter_mut().find_map(|s| s.take())
}
