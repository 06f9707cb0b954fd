//! Hot model swap, off the cycle: the compensator's control thread hands a [`ModelUpdate`]
//! (a `Copy` sample, no allocation) to a loader thread; the loader reads the announced ONNX
//! files, checks their hashes, loads them through tract with the usual load check (the exact
//! incremental evaluator compared with tract), sizes the evaluators and passes them back as one
//! boxed [`PreparedModels`]; the cycle exchanges the evaluators by value at its start
//! ([`crate::Compensator::swap_models`]) and hands the box, now holding the replaced models,
//! back to the loader to be dropped. The cycle thereby neither allocates nor frees, and never
//! waits (real time); all three hand-offs are bounded crossbeam channels, whose `try_send` /
//! `try_recv` allocate nothing. A model that fails any check is refused on the loader thread,
//! which prints why and counts it; the models in use stay.

use crate::compensator::PreparedModels;
use crate::config::EvaluatorChoice;
use crate::model::{Evaluator, LoadOptions, Model, ModelError};
use bowden_interfaces::model::Direction;
use bowden_interfaces::{fnv1a64, ModelUpdate};
use crossbeam::channel::{bounded, select, Receiver, Sender, TrySendError};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// What a swapped-in model must be.
#[derive(Debug, Clone)]
pub struct LoaderSettings {
    pub load: LoadOptions,
    /// Sequence lengths of the running models (0 = that direction is not loaded, and an update
    /// for it is refused).
    pub fwd_l: usize,
    pub inv_l: usize,
    pub joints: usize,
    pub evaluator: EvaluatorChoice,
    /// Prefix of the loader's messages (the stage name).
    pub who: String,
    /// Print a line for every model loaded (refusals are always printed).
    pub verbose: bool,
}

impl LoaderSettings {
    /// What models swapped into `comp` (built from `cfg`) must be, and how they are checked and
    /// evaluated: as `cfg` loaded its own.
    pub fn for_compensator(comp: &crate::Compensator, cfg: &crate::ControllerConfig, who: &str, verbose: bool) -> Self {
        let (fwd_l, inv_l) = comp.seq_lens();
        Self {
            load: cfg.load_check.options(),
            fwd_l,
            inv_l,
            joints: comp.joints(),
            evaluator: cfg.evaluator,
            who: who.to_string(),
            verbose,
        }
    }
}

/// The loader's answer to one update.
pub enum Loaded {
    Ready(Box<PreparedModels>),
    /// Refused (the reason was printed by the loader thread and counted).
    Refused {
        generation: u64,
    },
}

/// Counts kept by the loader thread.
#[derive(Debug, Default)]
pub struct LoaderCounts {
    pub loaded: AtomicU64,
    pub refused: AtomicU64,
}

/// The loader thread and its three channels.
pub struct ModelLoader {
    requests: Option<Sender<ModelUpdate>>,
    ready: Receiver<Loaded>,
    retire: Option<Sender<Box<PreparedModels>>>,
    counts: Arc<LoaderCounts>,
    handle: Option<JoinHandle<()>>,
}

impl ModelLoader {
    /// Starts the loader thread. Channels are sized so that the cycle's `try_send`s only fail
    /// when updates come faster than models load (the extra update is then dropped and counted
    /// as refused: the next one supersedes it anyway).
    pub fn spawn(settings: LoaderSettings) -> std::io::Result<Self> {
        let (req_tx, req_rx) = bounded::<ModelUpdate>(4);
        let (ready_tx, ready_rx) = bounded::<Loaded>(4);
        let (retire_tx, retire_rx) = bounded::<Box<PreparedModels>>(8);
        let counts = Arc::new(LoaderCounts::default());
        let c = counts.clone();
        let handle = std::thread::Builder::new()
            .name("model-loader".into())
            .spawn(move || loader_main(settings, req_rx, ready_tx, retire_rx, c))?;
        Ok(Self {
            requests: Some(req_tx),
            ready: ready_rx,
            retire: Some(retire_tx),
            counts,
            handle: Some(handle),
        })
    }

    /// Hands an update to the loader. Allocation-free; `false` if the loader is busy with
    /// four others (counted as refused).
    pub fn request(&self, u: &ModelUpdate) -> bool {
        let ok = self.requests.as_ref().is_some_and(|t| t.try_send(*u).is_ok());
        if !ok {
            self.counts.refused.fetch_add(1, Ordering::Relaxed);
        }
        ok
    }

    /// A loaded (or refused) update, if one is ready. Allocation-free.
    pub fn try_take(&self) -> Option<Loaded> {
        self.ready.try_recv().ok()
    }

    /// Waits up to `timeout` for the loader's answer (lockstep: the swap happens at the tick
    /// the update was read, whatever the machine's speed).
    /// Polls (with short sleeps, which allocate nothing, unlike a first blocking receive) rather
    /// than blocking on the channel.
    pub fn take_blocking(&self, timeout: Duration) -> Option<Loaded> {
        let t0 = std::time::Instant::now();
        loop {
            if let Ok(l) = self.ready.try_recv() {
                return Some(l);
            }
            if t0.elapsed() >= timeout || self.handle.as_ref().is_none_or(|h| h.is_finished()) {
                return self.ready.try_recv().ok();
            }
            std::thread::sleep(Duration::from_micros(100));
        }
    }

    /// Hands the replaced models back to be dropped on the loader thread. Allocation-free.
    pub fn retire(&self, old: Box<PreparedModels>) {
        if let Some(t) = &self.retire {
            match t.try_send(old) {
                Ok(()) => {}
                // Not reachable while the loader lives (8 slots, one swap per update); dropping
                // here frees memory on the calling thread, which is still correct.
                Err(TrySendError::Full(b)) | Err(TrySendError::Disconnected(b)) => drop(b),
            }
        }
    }

    pub fn loaded(&self) -> u64 {
        self.counts.loaded.load(Ordering::Relaxed)
    }

    pub fn refused(&self) -> u64 {
        self.counts.refused.load(Ordering::Relaxed)
    }
}

impl Drop for ModelLoader {
    fn drop(&mut self) {
        self.requests = None;
        self.retire = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

fn loader_main(
    s: LoaderSettings,
    requests: Receiver<ModelUpdate>,
    ready: Sender<Loaded>,
    retire: Receiver<Box<PreparedModels>>,
    counts: Arc<LoaderCounts>,
) {
    let mut retire = Some(retire);
    loop {
        let u = match &retire {
            Some(r) => select! {
                recv(requests) -> u => match u { Ok(u) => u, Err(_) => break },
                recv(r) -> old => {
                    match old {
                        Ok(old) => drop(old),
                        Err(_) => retire = None,
                    }
                    continue;
                }
            },
            None => match requests.recv() {
                Ok(u) => u,
                Err(_) => break,
            },
        };
        let answer = match prepare(&s, &u) {
            Ok(p) => {
                counts.loaded.fetch_add(1, Ordering::Relaxed);
                if s.verbose {
                    eprintln!(
                    "{}: model generation {} loaded and checked (forward {}, inverse {}), swapping at the next cycle",
                    s.who,
                    u.generation,
                    if p.fwd.is_some() { "new" } else { "kept" },
                    if p.inv.is_some() { "new" } else { "kept" },
                    );
                }
                Loaded::Ready(Box::new(p))
            }
            Err(why) => {
                counts.refused.fetch_add(1, Ordering::Relaxed);
                eprintln!(
                    "{}: model generation {} refused, the models in use stay: {why}",
                    s.who, u.generation
                );
                Loaded::Refused {
                    generation: u.generation,
                }
            }
        };
        if ready.send(answer).is_err() {
            break;
        }
    }
}

/// Why a model update was refused (the models in use stay).
#[derive(Debug, thiserror::Error)]
pub enum SwapError {
    #[error("the update's directory is not UTF-8")]
    DirNotUtf8,
    #[error("the update's directory `{0}` is not absolute")]
    DirNotAbsolute(PathBuf),
    #[error("the update names no model")]
    NoModel,
    #[error("{path}: no {direction} model is running to be replaced")]
    NothingToReplace { path: String, direction: Direction },
    #[error("{path}: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "{path}: content hash {got:016x} is not the announced {announced:016x} (the file changed or was cut short)"
    )]
    Hash { path: String, got: u64, announced: u64 },
    /// Corrupt, off the contract, or refused by the load check.
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(
        "{path}: a {direction} model with {joints} joints and L = {seq_len}, the running {direction} model has {running_joints} joints and L = {running_seq_len}"
    )]
    Mismatch {
        path: String,
        direction: Direction,
        joints: usize,
        seq_len: usize,
        running_joints: usize,
        running_seq_len: usize,
    },
}

/// Reads, checks and prepares the models an update announces.
pub fn prepare(s: &LoaderSettings, u: &ModelUpdate) -> Result<PreparedModels, SwapError> {
    let dir = u.dir().ok_or(SwapError::DirNotUtf8)?;
    let dir = Path::new(dir);
    if !dir.is_absolute() {
        return Err(SwapError::DirNotAbsolute(dir.to_path_buf()));
    }
    if u.fwd_hash == 0 && u.inv_hash == 0 {
        return Err(SwapError::NoModel);
    }
    let one = |file: &str, hash: u64, want: Direction, l: usize| -> Result<Option<Evaluator>, SwapError> {
        if hash == 0 {
            return Ok(None);
        }
        let path = dir.join(file);
        let shown = path.display().to_string();
        if l == 0 {
            return Err(SwapError::NothingToReplace {
                path: shown,
                direction: want,
            });
        }
        let bytes = std::fs::read(&path).map_err(|source| SwapError::Read {
            path: shown.clone(),
            source,
        })?;
        let got = fnv1a64(&bytes);
        if got != hash {
            return Err(SwapError::Hash {
                path: shown,
                got,
                announced: hash,
            });
        }
        let m = Model::from_bytes(&bytes, &shown, Some(dir), &s.load)?;
        if m.metadata().direction != want || m.joints() != s.joints || m.seq_len() != l {
            return Err(SwapError::Mismatch {
                path: shown,
                direction: m.metadata().direction,
                joints: m.joints(),
                seq_len: m.seq_len(),
                running_joints: s.joints,
                running_seq_len: l,
            });
        }
        Ok(Some(match s.evaluator {
            EvaluatorChoice::Auto => m.evaluator(),
            EvaluatorChoice::Tract => Evaluator::Tract(Box::new(m.tract_evaluator())),
        }))
    };
    Ok(PreparedModels {
        generation: u.generation,
        fwd: one("fwd.onnx", u.fwd_hash, Direction::Forward, s.fwd_l)?,
        inv: one("inv.onnx", u.inv_hash, Direction::Inverse, s.inv_l)?,
    })
}
