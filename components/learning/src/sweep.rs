//! `bowden sweep`: the paper's study of architectures × sequence lengths × directions over
//! several seeds (their Fig. 10): one training per configuration, run in parallel (one
//! configuration per thread), each finished run saved as its own JSON so an interrupted
//! sweep resumes where it stopped; then mean ± SD of the best validation RMSE per
//! (architecture, TCN block, L, direction) as Markdown, JSON and SVG.
//!
//! A sweep also runs in pieces on a cluster scheduler (Slurm job array, Kubernetes Indexed
//! Job) without bowden managing the cluster: [`plan_sweep`] numbers the runs and fingerprints
//! them, [`execute_runs`] does one [`Selection`] of them (a shard `I/N`: the indices ≡ I mod N,
//! or one run) into a shared `runs/` directory, each result written atomically, and
//! [`merge_sweep`] checks every run file against the plan and writes the same sweep.md,
//! sweep.json and sweep.svg as a local run. [`run_sweep`] is the three at once.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use crate::arch::{Architecture, Direction, ModelSpec, TcnBlock};
use crate::dataset::{fnv1a64_hex, Dataset};
use crate::report::LearnError;
use crate::train::{train, TrainConfig};
use crate::windows::{overall_rmse, PhySource, SplitConfig, WindowSet};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepConfig {
    pub archs: Vec<Architecture>,
    pub seq_lens: Vec<usize>,
    /// Seeds 0 .. seeds−1.
    pub seeds: u64,
    pub directions: Vec<Direction>,
    /// Variants run for the TCN-based architectures.
    pub tcn_blocks: Vec<TcnBlock>,
    pub epochs: usize,
    pub early_stop: Option<usize>,
    pub split: SplitConfig,
    pub phy_source: PhySource,
    /// Configurations trained at once. Not recorded in sweep.json nor in the fingerprints: no
    /// result depends on it, and a sweep run as shards with other `--jobs` must merge into the
    /// same bytes as a local one.
    #[serde(skip)]
    pub jobs: usize,
}

/// One configuration of the sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct RunKey {
    pub arch: Architecture,
    /// `None` for architectures without a TCN.
    pub tcn_block: Option<TcnBlock>,
    pub direction: Direction,
    pub seq_len: usize,
    pub seed: u64,
}

impl RunKey {
    pub fn model_label(&self) -> String {
        match self.tcn_block {
            Some(b) => format!("{} ({})", self.arch, b),
            None => self.arch.to_string(),
        }
    }

    /// `tcn-relu-linear_forward_L80_s2`: the run file's name without `.json`.
    pub fn name(&self) -> String {
        let model = match self.tcn_block {
            Some(b) => format!("{}-{}", self.arch, b),
            None => self.arch.to_string(),
        };
        format!("{model}_{}_L{}_s{}", self.direction, self.seq_len, self.seed)
    }

    pub fn file_name(&self) -> String {
        format!("{}.json", self.name())
    }
}

/// The saved result of one run (`runs/<key>.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunResult {
    pub key: RunKey,
    /// What makes the result reusable: same code, data, epochs, stopping, split and source;
    /// [`RunResult::fingerprint`] hashes them with the key.
    pub code_version: String,
    pub data_fnv1a64: String,
    pub epochs: usize,
    pub early_stop: Option<usize>,
    pub split: SplitConfig,
    pub phy_source: PhySource,
    /// FNV-1a 64 of the above and the key ([`run_fingerprint`]), hex.
    pub fingerprint: String,
    pub params: usize,
    pub best_epoch: usize,
    pub epochs_run: usize,
    pub best_val_rmse_deg: f64,
    pub best_val_rmse_per_joint_deg: Vec<f64>,
    pub identity_val_rmse_deg: f64,
    pub val_rmse_curve_deg: Vec<f64>,
    /// Wall time of the training; only in the run file (never in sweep.json, which must not
    /// depend on where and when the runs were made).
    pub seconds: f64,
}

/// Mean ± SD over seeds of one (model, direction, L).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupStats {
    pub model: String,
    pub arch: Architecture,
    pub tcn_block: Option<TcnBlock>,
    pub direction: Direction,
    pub seq_len: usize,
    pub params: usize,
    pub n: usize,
    pub mean_rmse_deg: f64,
    /// Sample SD (n − 1); 0 for a single seed.
    pub sd_rmse_deg: f64,
    pub runs_rmse_deg: Vec<f64>,
    pub identity_rmse_deg: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepSummary {
    pub format: String,
    pub config: SweepConfig,
    pub data: String,
    pub runs: usize,
    /// Runs taken from an earlier sweep's files by this invocation: printed, never written to
    /// sweep.json (a resumed, sharded or merged sweep writes the same bytes as a fresh one).
    #[serde(skip)]
    pub reused: usize,
    pub groups: Vec<GroupStats>,
    /// Per direction, the models ordered by mean RMSE at each L (best first).
    pub ranking: BTreeMap<String, BTreeMap<usize, Vec<String>>>,
    pub markdown: String,
}

/// Why a sweep could not be planned, run or merged.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error(transparent)]
    Learn(#[from] LearnError),
    #[error("{0}")]
    Selection(String),
    #[error("{}", incomplete_message(.runs_dir, .total, .missing, .bad))]
    Incomplete {
        runs_dir: PathBuf,
        total: usize,
        /// (index, file name) of the runs without a file.
        missing: Vec<(usize, String)>,
        /// One line per file that is there but cannot be merged: its path and why.
        bad: Vec<String>,
    },
}

fn incomplete_message(runs_dir: &Path, total: &usize, missing: &[(usize, String)], bad: &[String]) -> String {
    let mut s = format!("cannot merge {}: ", runs_dir.display());
    let mut parts = Vec::new();
    if !missing.is_empty() {
        let idx: Vec<String> = missing.iter().map(|(i, _)| i.to_string()).collect();
        parts.push(format!(
            "{} of {total} runs missing (indices {}; run them with --run K or rerun their shards)",
            missing.len(),
            idx.join(", ")
        ));
    }
    if !bad.is_empty() {
        parts.push(format!(
            "{} run file(s) not from this sweep (rerun each with --run K, which replaces it):\n  {}",
            bad.len(),
            bad.join("\n  ")
        ));
    }
    s.push_str(&parts.join("; "));
    s
}

/// The code that makes a run's numbers: the crate version and the kernel path (the AVX-512
/// GEMM rounds its FMAs differently from the portable one, so runs made on CPUs with and
/// without AVX-512 differ in the last bits and must not be merged). It is the version, not the
/// commit: after changing training code without a version bump, use a fresh `--out`.
pub fn code_version() -> String {
    let kernels = if crate::kernels::simd::has_avx512() {
        "avx512"
    } else {
        "portable"
    };
    format!("bowden-learning {} ({kernels} kernels)", env!("CARGO_PKG_VERSION"))
}

/// Everything a run's result depends on, hashed into its fingerprint.
#[derive(Serialize)]
struct RunIdentity<'a> {
    code_version: &'a str,
    data_fnv1a64: &'a str,
    key: &'a RunKey,
    epochs: usize,
    early_stop: Option<usize>,
    split: &'a SplitConfig,
    phy_source: PhySource,
}

fn hash_json<T: Serialize>(value: &T) -> String {
    // Plain structs of numbers, strings and enums: serialising them cannot fail.
    fnv1a64_hex(&serde_json::to_vec(value).expect("a plain struct serialises"))
}

/// FNV-1a 64 (hex) of the code version, the data hash, the run's key and the sweep settings
/// that change its result (epochs, early stop, split, source of the physical angles).
pub fn run_fingerprint(key: &RunKey, cfg: &SweepConfig, data_fnv1a64: &str, code_version: &str) -> String {
    hash_json(&RunIdentity {
        code_version,
        data_fnv1a64,
        key,
        epochs: cfg.epochs,
        early_stop: cfg.early_stop,
        split: &cfg.split,
        phy_source: cfg.phy_source,
    })
}

/// How `--shard I/N` divides the plan; written into the plan so a reader need not guess.
pub const SHARDING: &str = "round-robin: shard I of N runs the indices i with i mod N = I";

/// One run of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannedRun {
    /// Position in the plan: what `--run K` and `--shard I/N` select.
    pub index: usize,
    pub key: RunKey,
    /// The result's file under the output directory.
    pub file: String,
    /// [`run_fingerprint`]: the run file must carry the same.
    pub fingerprint: String,
    /// `done`, `pending`, or `redo: <why>` against an output directory
    /// ([`SweepPlan::check_status`]); absent when not checked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<String>,
}

/// Every run of a sweep, numbered, with what the runs are checked against.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepPlan {
    pub format: String,
    pub code_version: String,
    /// The dataset directory as given.
    pub data: String,
    pub data_fnv1a64: String,
    pub config: SweepConfig,
    /// FNV-1a 64 (hex) of the code version, data hash and config (not `jobs`): shards whose
    /// logs print the same fingerprint are pieces of one sweep.
    pub fingerprint: String,
    pub sharding: String,
    pub runs: Vec<PlannedRun>,
}

/// Which runs of a plan one process executes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    All,
    /// Indices ≡ `index` (mod `count`): round-robin, so every shard gets every kind of run
    /// (the plan is ordered architecture-major, and long-L runs take longest) and the shards
    /// finish at about the same time.
    Shard {
        index: usize,
        count: usize,
    },
    /// One run by its index.
    Run(usize),
}

impl std::str::FromStr for Selection {
    type Err = String;
    /// `I/N` (a shard; 0 ≤ I < N).
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("--shard {s:?}: expected I/N with 0 ≤ I < N, e.g. 0/4 (shard 0 of 4)");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index: usize = i.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Selection::Shard { index, count })
    }
}

impl std::fmt::Display for Selection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Selection::All => write!(f, "every run"),
            Selection::Shard { index, count } => write!(f, "shard {index}/{count} (indices ≡ {index} mod {count})"),
            Selection::Run(k) => write!(f, "run {k}"),
        }
    }
}

impl Selection {
    /// The plan indices selected out of `runs`. A shard beyond the runs is empty (a job array
    /// larger than the plan wastes a slot, nothing more); a run index beyond them is an error.
    pub fn indices(&self, runs: usize) -> Result<Vec<usize>, SweepError> {
        match *self {
            Selection::All => Ok((0..runs).collect()),
            Selection::Shard { index, count } => Ok((index..runs).step_by(count.max(1)).collect()),
            Selection::Run(k) if k < runs => Ok(vec![k]),
            Selection::Run(k) => Err(SweepError::Selection(format!(
                "--run {k}: the plan has {runs} runs (indices 0..={})",
                runs.saturating_sub(1)
            ))),
        }
    }
}

pub fn sweep_keys(cfg: &SweepConfig) -> Vec<RunKey> {
    let mut keys = Vec::new();
    for &arch in &cfg.archs {
        let blocks: Vec<Option<TcnBlock>> = if arch.has_tcn() {
            cfg.tcn_blocks.iter().map(|&b| Some(b)).collect()
        } else {
            vec![None]
        };
        for &direction in &cfg.directions {
            for &seq_len in &cfg.seq_lens {
                for &tcn_block in &blocks {
                    for seed in 0..cfg.seeds {
                        keys.push(RunKey {
                            arch,
                            tcn_block,
                            direction,
                            seq_len,
                            seed,
                        });
                    }
                }
            }
        }
    }
    keys
}

/// The plan of a sweep over a dataset of hash `data_fnv1a64` (named `data`), made by
/// `code_version`.
pub fn plan_for(cfg: &SweepConfig, data: &str, data_fnv1a64: &str, code_version: &str) -> SweepPlan {
    #[derive(Serialize)]
    struct PlanIdentity<'a> {
        code_version: &'a str,
        data_fnv1a64: &'a str,
        config: &'a SweepConfig,
    }
    let runs = sweep_keys(cfg)
        .into_iter()
        .enumerate()
        .map(|(index, key)| PlannedRun {
            index,
            key,
            file: format!("runs/{}", key.file_name()),
            fingerprint: run_fingerprint(&key, cfg, data_fnv1a64, code_version),
            status: None,
        })
        .collect();
    SweepPlan {
        format: "bowden-sweep-plan/1".into(),
        code_version: code_version.into(),
        data: data.into(),
        data_fnv1a64: data_fnv1a64.into(),
        config: cfg.clone(),
        fingerprint: hash_json(&PlanIdentity {
            code_version,
            data_fnv1a64,
            config: cfg,
        }),
        sharding: SHARDING.into(),
        runs,
    }
}

/// Reads the dataset in `data_dir` (its hash checked against its manifest) and plans the sweep
/// over it with this build's [`code_version`].
pub fn plan_sweep(data_dir: &Path, cfg: &SweepConfig) -> Result<(SweepPlan, Dataset), SweepError> {
    let (ds, manifest) = Dataset::read_dir(data_dir).map_err(LearnError::from)?;
    let plan = plan_for(
        cfg,
        &data_dir.display().to_string(),
        &manifest.csv_fnv1a64,
        &code_version(),
    );
    Ok((plan, ds))
}

/// What a run's file in `runs/` says about the run.
#[derive(Debug, Clone, PartialEq)]
pub enum RunFileState {
    /// A complete result of this run, made from the same data, settings and code.
    Done(Box<RunResult>),
    Missing,
    /// Not a complete run file (a truncated write, garbage, an older format): why.
    Unreadable(String),
    /// A complete run file of another sweep: why (what differs).
    Mismatch(String),
}

/// Checks the file of `run` in `runs_dir` against the plan.
pub fn check_run_file(runs_dir: &Path, run: &PlannedRun, plan: &SweepPlan) -> RunFileState {
    let path = runs_dir.join(run.key.file_name());
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return RunFileState::Missing,
        Err(e) => return RunFileState::Unreadable(format!("cannot read: {e}")),
    };
    let r: RunResult = match serde_json::from_str(&text) {
        Ok(r) => r,
        Err(e) => return RunFileState::Unreadable(format!("not a complete run file ({e})")),
    };
    let cfg = &plan.config;
    let why = if r.key != run.key {
        Some(format!("holds the run {}, not {}", r.key.name(), run.key.name()))
    } else if r.data_fnv1a64 != plan.data_fnv1a64 {
        Some(format!(
            "made from different data: dataset FNV-1a {}, this sweep's data {} has {}",
            r.data_fnv1a64, plan.data, plan.data_fnv1a64
        ))
    } else if r.code_version != plan.code_version {
        Some(format!("made by {}, this is {}", r.code_version, plan.code_version))
    } else if (r.epochs, r.early_stop) != (cfg.epochs, cfg.early_stop) {
        Some(format!(
            "made with a different config: epochs {} early stop {:?}, this sweep {} and {:?}",
            r.epochs, r.early_stop, cfg.epochs, cfg.early_stop
        ))
    } else if (r.split, r.phy_source) != (cfg.split, cfg.phy_source) {
        Some(format!(
            "made with a different config: split {:?} from {:?}, this sweep {:?} from {:?}",
            r.split, r.phy_source, cfg.split, cfg.phy_source
        ))
    } else if r.fingerprint != run.fingerprint {
        Some(format!(
            "fingerprint {} ≠ the plan's {} (edited by hand?)",
            r.fingerprint, run.fingerprint
        ))
    } else {
        None
    };
    match why {
        Some(w) => RunFileState::Mismatch(w),
        None => RunFileState::Done(Box::new(r)),
    }
}

impl SweepPlan {
    /// Fills every run's `status` against `out_dir`.
    pub fn check_status(&mut self, out_dir: &Path) {
        let runs_dir = out_dir.join("runs");
        let states: Vec<String> = self
            .runs
            .iter()
            .map(|run| match check_run_file(&runs_dir, run, self) {
                RunFileState::Done(_) => "done".to_string(),
                RunFileState::Missing => "pending".to_string(),
                RunFileState::Unreadable(w) | RunFileState::Mismatch(w) => format!("redo: {w}"),
            })
            .collect();
        for (run, s) in self.runs.iter_mut().zip(states) {
            run.status = Some(s);
        }
    }
}

/// Writes `bytes` to `path` so that a reader sees the old file or the whole new one, never a
/// part: into a temporary file beside it (same directory, so the rename stays on one file
/// system), flushed to disk, then renamed over `path`. A process killed before the rename
/// leaves only a `.NAME.tmp-PID` file, which readers ignore.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), LearnError> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy()).unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |source| LearnError::Io { path: p, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let written = std::fs::File::create(&tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    if let Err(e) = written.and_then(|_| std::fs::rename(&tmp, path)) {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(path)(e));
    }
    Ok(())
}

/// Removes what killed writers of `path` left (`.NAME.tmp-*`), once `path` is complete.
fn remove_stale_temps(path: &Path) {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
        return;
    };
    let prefix = format!(".{}.tmp-", name.to_string_lossy());
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

fn json_bytes<T: Serialize>(path: &Path, value: &T) -> Result<Vec<u8>, LearnError> {
    let mut text = serde_json::to_string_pretty(value).map_err(|source| LearnError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    text.push('\n');
    Ok(text.into_bytes())
}

/// One run an [`execute_runs`] call accounted for.
#[derive(Debug, Clone, PartialEq)]
pub struct RunDone {
    pub index: usize,
    pub key: RunKey,
    pub best_val_rmse_deg: f64,
    /// False when its file from an earlier process was kept.
    pub trained: bool,
}

/// What [`execute_runs`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct ExecReport {
    pub selection: Selection,
    /// Every selected run, by index.
    pub runs: Vec<RunDone>,
    pub trained: usize,
    pub reused: usize,
    /// Selected runs whose file was there but unusable (truncated, another sweep's), redone.
    pub redone: Vec<(usize, String)>,
}

/// Trains the runs of `selection` that `out_dir/runs` lacks (or holds only half-written or
/// from another sweep), `jobs` at once, each result written atomically; keeps the others.
// Long: the sweep's runs with their resume checks, progress and run files in one loop.
pub fn execute_runs(
    plan: &SweepPlan,
    ds: &Dataset,
    out_dir: &Path,
    selection: Selection,
    jobs: usize,
    progress: bool,
) -> Result<ExecReport, SweepError> {
    let selected = selection.indices(plan.runs.len())?;
    let cfg = &plan.config;
    let runs_dir = out_dir.join("runs");
    std::fs::create_dir_all(&runs_dir).map_err(|source| LearnError::Io {
        path: runs_dir.clone(),
        source,
    })?;
    let mut done: Vec<RunDone> = Vec::new();
    let mut pending: Vec<&PlannedRun> = Vec::new();
    let mut redone = Vec::new();
    for &i in &selected {
        let run = &plan.runs[i];
        match check_run_file(&runs_dir, run, plan) {
            RunFileState::Done(r) => done.push(RunDone {
                index: i,
                key: run.key,
                best_val_rmse_deg: r.best_val_rmse_deg,
                trained: false,
            }),
            RunFileState::Missing => pending.push(run),
            RunFileState::Unreadable(w) | RunFileState::Mismatch(w) => {
                redone.push((i, format!("{}: {w}", runs_dir.join(run.key.file_name()).display())));
                pending.push(run);
            }
        }
    }
    let reused = done.len();
    // Windows per (direction, L), shared read-only by the workers.
    let mut windows: BTreeMap<(Direction, usize), WindowSet> = BTreeMap::new();
    for run in &pending {
        let k = run.key;
        if let std::collections::btree_map::Entry::Vacant(e) = windows.entry((k.direction, k.seq_len)) {
            let w = WindowSet::build(ds, k.direction, k.seq_len, cfg.split, cfg.phy_source).map_err(|source| {
                LearnError::Window {
                    dir: PathBuf::from(&plan.data),
                    source,
                }
            })?;
            e.insert(w);
        }
    }
    let pb = if progress {
        let pb = ProgressBar::new(selected.len() as u64);
        pb.set_style(
            ProgressStyle::with_template("sweep [{bar:30}] {pos}/{len} runs {elapsed_precise} ETA {eta} {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        pb
    } else {
        ProgressBar::hidden()
    };
    pb.set_position(reused as u64);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<RunDone>> = Mutex::new(Vec::new());
    let first_error: Mutex<Option<LearnError>> = Mutex::new(None);
    let jobs = jobs.clamp(1, pending.len().max(1));
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(run) = pending.get(i).copied() else { break };
                if first_error.lock().map(|e| e.is_some()).unwrap_or(true) {
                    break;
                }
                let k = run.key;
                let path = runs_dir.join(k.file_name());
                let res = run_one(
                    &k,
                    cfg,
                    &windows[&(k.direction, k.seq_len)],
                    &plan.data_fnv1a64,
                    &plan.code_version,
                    &run.fingerprint,
                )
                .and_then(|r| json_bytes(&path, &r).map(|b| (r, b)))
                .and_then(|(r, b)| write_atomic(&path, &b).map(|_| r));
                match res {
                    Ok(r) => {
                        remove_stale_temps(&path);
                        pb.set_message(format!(
                            "{} {} L={} s{}: {:.3}°",
                            k.model_label(),
                            k.direction,
                            k.seq_len,
                            k.seed,
                            r.best_val_rmse_deg
                        ));
                        pb.inc(1);
                        if let Ok(mut v) = results.lock() {
                            v.push(RunDone {
                                index: run.index,
                                key: k,
                                best_val_rmse_deg: r.best_val_rmse_deg,
                                trained: true,
                            });
                        }
                    }
                    Err(e) => {
                        if let Ok(mut slot) = first_error.lock() {
                            slot.get_or_insert(e);
                        }
                    }
                }
            });
        }
    });
    pb.finish();
    if let Some(e) = first_error.into_inner().ok().flatten() {
        return Err(e.into());
    }
    let trained_runs = results.into_inner().unwrap_or_default();
    let trained = trained_runs.len();
    done.extend(trained_runs);
    done.sort_by_key(|r| r.index);
    Ok(ExecReport {
        selection,
        runs: done,
        trained,
        reused,
        redone,
    })
}

/// Reads every run of the plan from `out_dir/runs` and writes sweep.json, sweep.md and
/// sweep.svg into `out_dir`. Refuses, naming each, runs missing and files that are not
/// complete results of this plan (other data, settings or code; truncated); files of runs
/// outside the plan (a larger earlier sweep) and leftover temporary files are ignored.
pub fn merge_sweep(plan: &SweepPlan, out_dir: &Path) -> Result<SweepSummary, SweepError> {
    let runs_dir = out_dir.join("runs");
    let mut done: BTreeMap<RunKey, RunResult> = BTreeMap::new();
    let mut missing = Vec::new();
    let mut bad = Vec::new();
    for run in &plan.runs {
        match check_run_file(&runs_dir, run, plan) {
            RunFileState::Done(r) => {
                done.insert(run.key, *r);
            }
            RunFileState::Missing => missing.push((run.index, run.key.file_name())),
            RunFileState::Unreadable(w) | RunFileState::Mismatch(w) => bad.push(format!(
                "{} (run {}): {w}",
                runs_dir.join(run.key.file_name()).display(),
                run.index
            )),
        }
    }
    if !missing.is_empty() || !bad.is_empty() {
        return Err(SweepError::Incomplete {
            runs_dir,
            total: plan.runs.len(),
            missing,
            bad,
        });
    }
    let summary = summarise(&plan.config, &plan.data, &done, 0);
    let json_path = out_dir.join("sweep.json");
    write_atomic(&json_path, &json_bytes(&json_path, &summary)?)?;
    let md_path = out_dir.join("sweep.md");
    write_atomic(&md_path, summary.markdown.as_bytes())?;
    plot_sweep(&out_dir.join("sweep.svg"), &summary)?;
    Ok(summary)
}

/// Runs (or resumes) a whole sweep over the dataset in `data_dir`, writing into `out_dir`:
/// [`plan_sweep`], [`execute_runs`] of every run, [`merge_sweep`].
pub fn run_sweep(
    data_dir: &Path,
    out_dir: &Path,
    cfg: &SweepConfig,
    progress: bool,
) -> Result<SweepSummary, SweepError> {
    let (plan, ds) = plan_sweep(data_dir, cfg)?;
    let report = execute_runs(&plan, &ds, out_dir, Selection::All, cfg.jobs, progress)?;
    let mut summary = merge_sweep(&plan, out_dir)?;
    summary.reused = report.reused;
    Ok(summary)
}

fn run_one(
    k: &RunKey,
    cfg: &SweepConfig,
    data: &WindowSet,
    data_hash: &str,
    code_version: &str,
    fingerprint: &str,
) -> Result<RunResult, LearnError> {
    let mut tc = TrainConfig::paper(k.arch, k.direction, k.seq_len, cfg.epochs, k.seed);
    tc.tcn_block = k.tcn_block.unwrap_or_default();
    tc.early_stop = cfg.early_stop;
    tc.threads = 1; // one configuration per core
    let t0 = Instant::now();
    let out = train(data, &tc, None)?;
    let best = out.best();
    Ok(RunResult {
        key: *k,
        code_version: code_version.to_string(),
        data_fnv1a64: data_hash.to_string(),
        epochs: cfg.epochs,
        early_stop: cfg.early_stop,
        split: cfg.split,
        phy_source: cfg.phy_source,
        fingerprint: fingerprint.to_string(),
        params: ModelSpec::new(k.arch, k.seq_len, data.joints, tc.tcn_block).param_count(),
        best_epoch: out.best_epoch,
        epochs_run: out.epochs.len(),
        best_val_rmse_deg: best.val_rmse_deg,
        best_val_rmse_per_joint_deg: best.val_rmse_per_joint_deg.clone(),
        identity_val_rmse_deg: overall_rmse(&data.identity_rmse_deg(&data.val)),
        val_rmse_curve_deg: out.epochs.iter().map(|e| e.val_rmse_deg).collect(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Mean and sample SD.
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (mean, sd)
}

pub fn summarise(cfg: &SweepConfig, data: &str, done: &BTreeMap<RunKey, RunResult>, reused: usize) -> SweepSummary {
    let mut groups: BTreeMap<(Direction, String, usize), Vec<&RunResult>> = BTreeMap::new();
    for (k, r) in done {
        groups
            .entry((k.direction, k.model_label(), k.seq_len))
            .or_default()
            .push(r);
    }
    let stats: Vec<GroupStats> = groups
        .iter()
        .map(|((direction, model, seq_len), rs)| {
            let v: Vec<f64> = rs.iter().map(|r| r.best_val_rmse_deg).collect();
            let (mean, sd) = mean_sd(&v);
            GroupStats {
                model: model.clone(),
                arch: rs[0].key.arch,
                tcn_block: rs[0].key.tcn_block,
                direction: *direction,
                seq_len: *seq_len,
                params: rs[0].params,
                n: v.len(),
                mean_rmse_deg: mean,
                sd_rmse_deg: sd,
                runs_rmse_deg: v,
                identity_rmse_deg: rs[0].identity_val_rmse_deg,
            }
        })
        .collect();
    let mut ranking: BTreeMap<String, BTreeMap<usize, Vec<String>>> = BTreeMap::new();
    for d in &cfg.directions {
        for &l in &cfg.seq_lens {
            let mut at: Vec<&GroupStats> = stats.iter().filter(|g| g.direction == *d && g.seq_len == l).collect();
            at.sort_by(|a, b| a.mean_rmse_deg.total_cmp(&b.mean_rmse_deg));
            ranking
                .entry(d.to_string())
                .or_default()
                .insert(l, at.iter().map(|g| g.model.clone()).collect());
        }
    }
    let markdown = markdown_table(cfg, data, &stats);
    SweepSummary {
        format: "bowden-sweep/1".into(),
        config: cfg.clone(),
        data: data.into(),
        runs: done.len(),
        reused,
        groups: stats,
        ranking,
        markdown,
    }
}

fn markdown_table(cfg: &SweepConfig, data: &str, stats: &[GroupStats]) -> String {
    let mut s = format!(
        "# Sweep: best validation RMSE (deg), mean ± SD over {} seed(s)\n\n\
         Data `{data}`, {} epochs{}, split {:.0}/{:.0} in {} contiguous block(s), physical angles from {:?}.\n\
         Identity = the raw hysteresis (predicting the target by the newest input).\n",
        cfg.seeds,
        cfg.epochs,
        cfg.early_stop.map_or(String::new(), |p| format!(" (early stop {p})")),
        (1.0 - cfg.split.val_fraction) * 100.0,
        cfg.split.val_fraction * 100.0,
        cfg.split.val_blocks,
        cfg.phy_source
    );
    let lens = &cfg.seq_lens;
    for d in &cfg.directions {
        s.push_str(&format!(
            "\n## {d}\n\n| model | params @ L={} |",
            lens.last().copied().unwrap_or(0)
        ));
        for l in lens {
            s.push_str(&format!(" L = {l} |"));
        }
        s.push_str("\n|---|---:|");
        for _ in lens {
            s.push_str("---:|");
        }
        s.push('\n');
        let mut models: Vec<String> = stats
            .iter()
            .filter(|g| g.direction == *d)
            .map(|g| g.model.clone())
            .collect();
        models.dedup();
        let mut seen = std::collections::BTreeSet::new();
        models.retain(|m| seen.insert(m.clone()));
        for m in &models {
            let params = stats
                .iter()
                .filter(|g| g.direction == *d && &g.model == m)
                .max_by_key(|g| g.seq_len)
                .map_or(0, |g| g.params);
            s.push_str(&format!("| {m} | {params} |"));
            for &l in lens {
                let best_here = stats
                    .iter()
                    .filter(|g| g.direction == *d && g.seq_len == l)
                    .map(|g| g.mean_rmse_deg)
                    .fold(f64::INFINITY, f64::min);
                match stats
                    .iter()
                    .find(|g| g.direction == *d && &g.model == m && g.seq_len == l)
                {
                    Some(g) if g.mean_rmse_deg == best_here => {
                        s.push_str(&format!(" **{:.2} ± {:.2}** |", g.mean_rmse_deg, g.sd_rmse_deg))
                    }
                    Some(g) => s.push_str(&format!(" {:.2} ± {:.2} |", g.mean_rmse_deg, g.sd_rmse_deg)),
                    None => s.push_str(" – |"),
                }
            }
            s.push('\n');
        }
        s.push_str("| identity | 0 |");
        for &l in lens {
            match stats.iter().find(|g| g.direction == *d && g.seq_len == l) {
                Some(g) => s.push_str(&format!(" {:.2} |", g.identity_rmse_deg)),
                None => s.push_str(" – |"),
            }
        }
        s.push('\n');
    }
    s
}

/// One panel per direction: mean RMSE against L per model, with ±SD bars; one colour per model
/// in every panel, the legend a strip above the panels.
pub fn plot_sweep(path: &Path, summary: &SweepSummary) -> Result<(), LearnError> {
    use crate::report::{legend_strip, LegendMark, LEGEND_STRIP_PX};
    let err = |e: String| LearnError::Plot {
        path: PathBuf::from(path),
        what: e,
    };
    let dirs = &summary.config.directions;
    let width = 560 * dirs.len().max(1) as u32;
    let root = SVGBackend::new(path, (width, 440 + LEGEND_STRIP_PX)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (legend, root) = root.split_vertically(LEGEND_STRIP_PX);
    let panels = root.split_evenly((1, dirs.len().max(1)));
    let lens = &summary.config.seq_lens;
    let (lmin, lmax) = (
        lens.iter().copied().min().unwrap_or(0) as f64,
        lens.iter().copied().max().unwrap_or(1) as f64,
    );
    let palette = [
        BLUE,
        RED,
        GREEN,
        MAGENTA,
        CYAN,
        BLACK,
        RGBColor(230, 140, 0),
        RGBColor(120, 60, 20),
    ];
    // Models in order of appearance over every direction: the same colour in every panel.
    let mut models: Vec<String> = Vec::new();
    for g in &summary.groups {
        if !models.contains(&g.model) {
            models.push(g.model.clone());
        }
    }
    let colour = |m: &str| palette[models.iter().position(|x| x == m).unwrap_or(0) % palette.len()];
    let mut items: Vec<(String, LegendMark)> = models
        .iter()
        .map(|m| (m.clone(), LegendMark::Line(colour(m), 2)))
        .collect();
    items.push(("identity (raw hysteresis)".into(), LegendMark::Line(BLACK, 1)));
    legend_strip(&legend, &items).map_err(err)?;
    for (panel, d) in panels.iter().zip(dirs) {
        let gs: Vec<&GroupStats> = summary.groups.iter().filter(|g| g.direction == *d).collect();
        let ymax = gs
            .iter()
            .map(|g| (g.mean_rmse_deg + g.sd_rmse_deg).max(g.identity_rmse_deg))
            .fold(0.0, f64::max)
            * 1.1;
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{d} model: validation RMSE"), ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(32)
            .y_label_area_size(50)
            .build_cartesian_2d((lmin - 5.0)..(lmax + 5.0), 0.0..ymax.max(1e-6))
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("sequence length L")
            .y_desc("deg")
            .draw()
            .map_err(|e| err(e.to_string()))?;
        for m in &models {
            let color = colour(m);
            let mut pts: Vec<&GroupStats> = gs.iter().copied().filter(|g| &g.model == m).collect();
            if pts.is_empty() {
                continue;
            }
            pts.sort_by_key(|g| g.seq_len);
            chart
                .draw_series(LineSeries::new(
                    pts.iter().map(|g| (g.seq_len as f64, g.mean_rmse_deg)),
                    color.stroke_width(2),
                ))
                .map_err(|e| err(e.to_string()))?;
            chart
                .draw_series(pts.iter().map(|g| {
                    let x = g.seq_len as f64;
                    PathElement::new(
                        vec![
                            (x, g.mean_rmse_deg - g.sd_rmse_deg),
                            (x, g.mean_rmse_deg + g.sd_rmse_deg),
                        ],
                        color.stroke_width(1),
                    )
                }))
                .map_err(|e| err(e.to_string()))?;
            chart
                .draw_series(
                    pts.iter()
                        .map(|g| Circle::new((g.seq_len as f64, g.mean_rmse_deg), 3, color.filled())),
                )
                .map_err(|e| err(e.to_string()))?;
        }
        let mut ident: Vec<(f64, f64)> = gs.iter().map(|g| (g.seq_len as f64, g.identity_rmse_deg)).collect();
        ident.sort_by(|a, b| a.0.total_cmp(&b.0));
        ident.dedup_by(|a, b| a.0 == b.0);
        chart
            .draw_series(LineSeries::new(ident, BLACK.stroke_width(1)))
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> SweepConfig {
        SweepConfig {
            archs: vec![Architecture::Tcn, Architecture::Fnn],
            seq_lens: vec![8, 12],
            seeds: 2,
            directions: vec![Direction::Forward],
            tcn_blocks: vec![TcnBlock::ReluLinear],
            epochs: 2,
            early_stop: None,
            split: SplitConfig::default(),
            phy_source: PhySource::Truth,
            jobs: 2,
        }
    }

    fn result_of(plan: &SweepPlan, run: &PlannedRun) -> RunResult {
        RunResult {
            key: run.key,
            code_version: plan.code_version.clone(),
            data_fnv1a64: plan.data_fnv1a64.clone(),
            epochs: plan.config.epochs,
            early_stop: plan.config.early_stop,
            split: plan.config.split,
            phy_source: plan.config.phy_source,
            fingerprint: run.fingerprint.clone(),
            params: 10,
            best_epoch: 1,
            epochs_run: 2,
            best_val_rmse_deg: 1.5 + run.index as f64,
            best_val_rmse_per_joint_deg: vec![1.5; 5],
            identity_val_rmse_deg: 9.0,
            val_rmse_curve_deg: vec![2.0, 1.5],
            seconds: 0.25,
        }
    }

    #[test]
    fn shards_partition_the_plan_and_bad_selections_are_refused() {
        for n in [1usize, 3, 4, 9] {
            let mut seen = vec![0; 8];
            for i in 0..n {
                let sel: Selection = format!("{i}/{n}").parse().unwrap();
                for k in sel.indices(8).unwrap() {
                    assert_eq!(k % n, i);
                    seen[k] += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "{n} shards: {seen:?}");
        }
        for bad in ["4/4", "1", "a/2", "0/0", "-1/3"] {
            let e = bad.parse::<Selection>().unwrap_err();
            assert!(e.contains("I/N"), "{bad}: {e}");
        }
        assert_eq!(Selection::Run(7).indices(8).unwrap(), vec![7]);
        let e = Selection::Run(8).indices(8).unwrap_err().to_string();
        assert!(e.contains("--run 8") && e.contains("8 runs"), "{e}");
    }

    #[test]
    fn fingerprints_follow_what_changes_results_and_not_jobs() {
        let base = plan_for(&cfg(), "d", "00aa", "v1");
        assert_eq!(base.runs.len(), 8);
        assert_eq!(base.runs[3].index, 3);
        let mut other_jobs = cfg();
        other_jobs.jobs = 7;
        assert_eq!(plan_for(&other_jobs, "elsewhere", "00aa", "v1"), {
            let mut p = base.clone();
            p.data = "elsewhere".into();
            p.config.jobs = 7;
            p
        });
        let mut more_epochs = cfg();
        more_epochs.epochs = 3;
        for other in [
            plan_for(&cfg(), "d", "00ab", "v1"),
            plan_for(&cfg(), "d", "00aa", "v2"),
            plan_for(&more_epochs, "d", "00aa", "v1"),
        ] {
            assert_ne!(other.fingerprint, base.fingerprint);
            assert_ne!(other.runs[0].fingerprint, base.runs[0].fingerprint);
        }
        // More seeds: a new plan, but the runs both have keep their fingerprints (resumable).
        let mut more_seeds = cfg();
        more_seeds.seeds = 3;
        let bigger = plan_for(&more_seeds, "d", "00aa", "v1");
        assert_ne!(bigger.fingerprint, base.fingerprint);
        let fp = |p: &SweepPlan, k: &RunKey| p.runs.iter().find(|r| r.key == *k).map(|r| r.fingerprint.clone());
        for r in &base.runs {
            assert_eq!(fp(&bigger, &r.key), Some(r.fingerprint.clone()));
        }
        // jobs never reaches sweep.json.
        let json = serde_json::to_string(&base.config).unwrap();
        assert!(!json.contains("jobs"), "{json}");
    }

    #[test]
    fn run_files_are_checked_and_merge_names_what_is_wrong() {
        let dir = tempfile::tempdir().unwrap();
        let runs_dir = dir.path().join("runs");
        let plan = plan_for(&cfg(), "d", "00aa", "v1");
        let write = |run: &PlannedRun, r: &RunResult| {
            let p = runs_dir.join(run.key.file_name());
            write_atomic(&p, &json_bytes(&p, r).unwrap()).unwrap();
        };
        for run in &plan.runs {
            write(run, &result_of(&plan, run));
        }
        let leftovers: Vec<_> = std::fs::read_dir(&runs_dir)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
            .collect();
        assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
        let full = merge_sweep(&plan, dir.path()).unwrap();
        assert_eq!(full.runs, 8);
        let json = std::fs::read(dir.path().join("sweep.json")).unwrap();

        // Truncated, other data, other epochs, missing: each named.
        let (r1, r2, r3) = (&plan.runs[1], &plan.runs[2], &plan.runs[3]);
        let p1 = runs_dir.join(r1.key.file_name());
        let text = std::fs::read_to_string(&p1).unwrap();
        std::fs::write(&p1, &text[..text.len() / 2]).unwrap();
        assert!(matches!(
            check_run_file(&runs_dir, r1, &plan),
            RunFileState::Unreadable(_)
        ));
        let mut other_data = result_of(&plan, r2);
        other_data.data_fnv1a64 = "00ff".into();
        write(r2, &other_data);
        let mut other_epochs = result_of(&plan, r3);
        other_epochs.epochs = 5;
        write(r3, &other_epochs);
        std::fs::remove_file(runs_dir.join(plan.runs[6].key.file_name())).unwrap();
        let e = merge_sweep(&plan, dir.path()).unwrap_err().to_string();
        for needle in [
            "1 of 8 runs missing (indices 6;".to_string(),
            format!("{} (run 1): not a complete run file", p1.display()),
            format!(
                "{} (run 2): made from different data: dataset FNV-1a 00ff",
                runs_dir.join(r2.key.file_name()).display()
            ),
            "(run 3): made with a different config: epochs 5".to_string(),
        ] {
            assert!(e.contains(&needle), "{needle:?} not in {e}");
        }
        // A hand-edited result with its key and settings intact is caught by the fingerprint.
        let mut edited = result_of(&plan, r2);
        edited.fingerprint = "0123".into();
        write(r2, &edited);
        assert!(matches!(check_run_file(&runs_dir, r2, &plan), RunFileState::Mismatch(w) if w.contains("fingerprint")));
        // Repaired: the same bytes as before, whatever the file times or order.
        for run in [r1, r2, r3, &plan.runs[6]] {
            write(run, &result_of(&plan, run));
        }
        let mut plan_status = plan.clone();
        plan_status.check_status(dir.path());
        assert!(plan_status.runs.iter().all(|r| r.status.as_deref() == Some("done")));
        merge_sweep(&plan, dir.path()).unwrap();
        assert_eq!(std::fs::read(dir.path().join("sweep.json")).unwrap(), json);
    }

    #[test]
    fn a_stale_temporary_file_is_removed_once_its_run_is_complete() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.json");
        let stale = dir.path().join(".x.json.tmp-999999");
        std::fs::write(&stale, "{\"key\":").unwrap();
        write_atomic(&path, b"{}\n").unwrap();
        assert!(stale.exists(), "write_atomic leaves others' files alone");
        remove_stale_temps(&path);
        assert!(!stale.exists());
        assert_eq!(std::fs::read(&path).unwrap(), b"{}\n");
    }
}
