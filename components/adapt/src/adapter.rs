//! The adaptation logic, free of IPC: gather rows, decide staleness, fine-tune, validate,
//! write generations, keep state. The `adapt` node (components/adapt/src/node.rs) drives it.

use crate::config::AdaptConfig;
use bowden_interfaces::config::ConfigError;
use bowden_interfaces::fnv1a64;
use bowden_learning::{
    fine_tune, mean_residual_deg, rmse_deg, Dataset, Direction, ModelFile, PhySource, TrainConfig, WindowSet,
};
use bowden_tables::{ReadOptions, Table, TableError, TableWriter};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum AdaptError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The saved rows: unreadable, malformed or not numbers (file:line:column).
    #[error(transparent)]
    Table(#[from] TableError),
}

/// A row [`Adapter::push`] refused (counted in `rejected_rows`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RowError {
    #[error("tick {tick}: a row of {cmd} / {phy} joints, the models have {models}")]
    Joints {
        tick: u64,
        cmd: usize,
        phy: usize,
        models: usize,
    },
    #[error("tick {tick}: a non-finite angle in the row")]
    NonFinite { tick: u64 },
}

/// How errors name the settings an adapter was opened with (they may not come from a file).
const SETTINGS: &str = "the [adapt] settings";

fn file_err(path: &Path, e: impl std::fmt::Display) -> AdaptError {
    AdaptError::File {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// JSON has no NaN: serde_json writes it as `null`, which reads back as NaN here.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// One gathered pair: the command in force when a frame was taken, and the vision estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Row {
    pub tick: u64,
    pub q_cmd_deg: Vec<f64>,
    pub q_phy_deg: Vec<f64>,
    /// The compensator's own forward prediction at the command (its exact running window),
    /// when it sent one.
    #[serde(default)]
    pub q_pred_deg: Option<Vec<f64>>,
}

/// What a check decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Decision {
    /// The first check: its error becomes the reference.
    Reference,
    /// Not stale: nothing trained.
    Fresh,
    /// Stale, fine-tuned, at least one model validated better: a new generation.
    Swapped,
    /// Stale, fine-tuned, no model validated better: nothing published.
    Rejected,
    /// Stale, but too few rows measured since the last fresh check to learn from yet.
    Waiting,
    /// Stale, but the fine-tune could not run (training failed).
    Failed,
}

/// One staleness check, as logged in `adapt.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckRecord {
    pub tick: u64,
    pub rows: usize,
    pub generation: u64,
    /// Held-out RMSE of the forward and inverse models in use, deg.
    #[serde(deserialize_with = "nan_if_null")]
    pub fwd_holdout_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub inv_holdout_deg: f64,
    /// RMSE of the compensator's own predictions over the held-out rows, deg (NaN without).
    #[serde(deserialize_with = "nan_if_null")]
    pub fwd_running_deg: f64,
    /// The references (forward, inverse) these are compared with.
    pub reference_deg: Option<(f64, f64)>,
    pub decision: Decision,
    /// Held-out RMSE before/after of each fine-tuned direction, deg (NaN = not tuned).
    #[serde(deserialize_with = "nan_if_null")]
    pub fwd_before_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub fwd_after_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub inv_before_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub inv_after_deg: f64,
    pub message: String,
}

/// One accepted generation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwapRecord {
    pub generation: u64,
    pub tick: u64,
    pub dir: PathBuf,
    pub fwd_hash: u64,
    pub inv_hash: u64,
    #[serde(deserialize_with = "nan_if_null")]
    pub fwd_before_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub fwd_after_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub inv_before_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub inv_after_deg: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct State {
    generation: u64,
    reference_deg: Option<(f64, f64)>,
    fwd_file: PathBuf,
    inv_file: PathBuf,
    swaps: Vec<SwapRecord>,
    checks: u64,
    /// A staleness episode is open: every check fine-tunes until one does not validate better
    /// (the swap that fixed part of the error leaves the rest for the next check).
    #[serde(default)]
    adapting: bool,
    /// Tick of the last check that found the models fresh: the robot changed after it, so a
    /// fine-tune learns only from rows measured later (older rows still serve as history).
    #[serde(default)]
    fresh_tick: u64,
}

/// Online adaptation of one forward/inverse model pair.
pub struct Adapter {
    cfg: AdaptConfig,
    dir: PathBuf,
    fwd: ModelFile,
    inv: ModelFile,
    state: State,
    rows: VecDeque<Row>,
    since_check: usize,
    skipped_rows: u64,
    rejected_rows: u64,
    /// Rows needed before the first check: L − 1 of history, the hold-out, some training.
    min_rows: usize,
}

/// A check to run (off the node's loop in real time: it owns everything it needs).
pub struct Job {
    cfg: AdaptConfig,
    rows: Vec<Row>,
    fwd: ModelFile,
    inv: ModelFile,
    reference_deg: Option<(f64, f64)>,
    generation: u64,
    adapting: bool,
    fresh_tick: u64,
}

/// What [`Job::run`] found.
pub struct JobResult {
    pub record: CheckRecord,
    /// Fine-tuned models that validated better (None = keep the one in use).
    pub new_fwd: Option<ModelFile>,
    pub new_inv: Option<ModelFile>,
}

impl Adapter {
    /// Starts from `state_dir`'s saved state when there is one (`resume`), else from the given
    /// models (a fresh `state_dir`; with `resume = false` an old state there is removed).
    pub fn open(
        cfg: AdaptConfig,
        state_dir: &Path,
        fwd_file: &Path,
        inv_file: &Path,
        resume: bool,
    ) -> Result<Self, AdaptError> {
        cfg.validate(SETTINGS)?;
        let state_path = state_dir.join("state.json");
        if !resume && state_dir.exists() {
            std::fs::remove_dir_all(state_dir).map_err(|e| file_err(state_dir, e))?;
        }
        std::fs::create_dir_all(state_dir).map_err(|e| file_err(state_dir, e))?;
        let state = if resume && state_path.exists() {
            let text = std::fs::read_to_string(&state_path).map_err(|e| file_err(&state_path, e))?;
            serde_json::from_str::<State>(&text)
                .map_err(|e| file_err(&state_path, format!("not an adapt state: {e}")))?
        } else {
            State {
                generation: 0,
                reference_deg: None,
                fwd_file: fwd_file.to_path_buf(),
                inv_file: inv_file.to_path_buf(),
                swaps: Vec::new(),
                checks: 0,
                adapting: false,
                fresh_tick: 0,
            }
        };
        let load = |p: &Path, want: Direction| -> Result<ModelFile, AdaptError> {
            let m = ModelFile::load(p).map_err(|e| file_err(p, e))?;
            if m.direction != want {
                return Err(file_err(
                    p,
                    format!("a {} model where a {want} one is needed", m.direction),
                ));
            }
            Ok(m)
        };
        let fwd = load(&state.fwd_file, Direction::Forward)?;
        let inv = load(&state.inv_file, Direction::Inverse)?;
        if fwd.spec.joints != inv.spec.joints {
            return Err(ConfigError::invalid(
                SETTINGS,
                "models",
                format!(
                    "the forward model has {} joints, the inverse {}",
                    fwd.spec.joints, inv.spec.joints
                ),
            )
            .into());
        }
        let l = fwd.spec.seq_len.max(inv.spec.seq_len);
        let min_rows = (l - 1) + holdout_rows(&cfg) + 20;
        if cfg.window_rows < min_rows {
            return Err(ConfigError::invalid(
                SETTINGS,
                "adapt.window_rows",
                format!(
                    "{} is too small for L = {l}: at least {min_rows} (L − 1 of history, the hold-out and 20 training windows)",
                    cfg.window_rows
                ),
            )
            .into());
        }
        let mut a = Self {
            cfg,
            dir: state_dir.to_path_buf(),
            fwd,
            inv,
            state,
            rows: VecDeque::new(),
            since_check: 0,
            skipped_rows: 0,
            rejected_rows: 0,
            min_rows,
        };
        if resume {
            a.load_rows()?;
        }
        Ok(a)
    }

    pub fn joints(&self) -> usize {
        self.fwd.spec.joints
    }

    /// The files of the models in use (forward, inverse).
    pub fn model_files(&self) -> (PathBuf, PathBuf) {
        (self.state.fwd_file.clone(), self.state.inv_file.clone())
    }

    pub fn state_dir(&self) -> &Path {
        &self.dir
    }

    pub fn generation(&self) -> u64 {
        self.state.generation
    }

    pub fn swaps(&self) -> &[SwapRecord] {
        &self.state.swaps
    }

    pub fn rows(&self) -> usize {
        self.rows.len()
    }

    pub fn reference_deg(&self) -> Option<(f64, f64)> {
        self.state.reference_deg
    }

    /// Rows skipped (no motion) and rejected (non-finite, wrong size).
    pub fn skipped_rows(&self) -> u64 {
        self.skipped_rows
    }

    pub fn rejected_rows(&self) -> u64 {
        self.rejected_rows
    }

    /// The generation in use and its files, when it is not the start models (announced again
    /// after a restart so the compensator uses it).
    pub fn current(&self) -> Option<&SwapRecord> {
        self.state
            .swaps
            .last()
            .filter(|s| s.generation == self.state.generation)
    }

    /// Adds a row; `Err` (counted) for a row that cannot be used.
    pub fn push(
        &mut self,
        tick: u64,
        q_cmd_deg: &[f64],
        q_phy_deg: &[f64],
        q_pred_deg: Option<&[f64]>,
    ) -> Result<(), RowError> {
        let j = self.joints();
        if q_cmd_deg.len() != j || q_phy_deg.len() != j {
            self.rejected_rows += 1;
            return Err(RowError::Joints {
                tick,
                cmd: q_cmd_deg.len(),
                phy: q_phy_deg.len(),
                models: j,
            });
        }
        if !q_cmd_deg.iter().chain(q_phy_deg).all(|v| v.is_finite()) {
            self.rejected_rows += 1;
            return Err(RowError::NonFinite { tick });
        }
        if let Some(last) = self.rows.back() {
            let moved = last
                .q_cmd_deg
                .iter()
                .zip(q_cmd_deg)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            if moved < self.cfg.min_step_deg {
                self.skipped_rows += 1;
                return Ok(());
            }
        }
        self.rows.push_back(Row {
            tick,
            q_cmd_deg: q_cmd_deg.to_vec(),
            q_phy_deg: q_phy_deg.to_vec(),
            q_pred_deg: q_pred_deg
                .filter(|p| p.len() == j && p.iter().all(|v| v.is_finite()))
                .map(|p| p.to_vec()),
        });
        while self.rows.len() > self.cfg.window_rows {
            self.rows.pop_front();
        }
        self.since_check += 1;
        Ok(())
    }

    /// A check is due: enough rows, and `check_every_rows` new ones since the last.
    pub fn due(&self) -> bool {
        self.rows.len() >= self.min_rows && self.since_check >= self.cfg.check_every_rows
    }

    /// The check to run now (resets the count of new rows).
    pub fn job(&mut self) -> Job {
        self.since_check = 0;
        Job {
            cfg: self.cfg.clone(),
            rows: self.rows.iter().cloned().collect(),
            fwd: self.fwd.clone(),
            inv: self.inv.clone(),
            reference_deg: self.state.reference_deg,
            generation: self.state.generation,
            adapting: self.state.adapting,
            fresh_tick: self.state.fresh_tick,
        }
    }

    /// Takes a check's result at `tick`: logs it, writes an accepted generation, saves the
    /// state. `Ok(Some(record))` = a new generation to announce.
    pub fn apply(&mut self, r: JobResult, tick: u64) -> Result<Option<SwapRecord>, AdaptError> {
        let mut record = r.record;
        record.tick = tick;
        self.state.checks += 1;
        if matches!(record.decision, Decision::Reference | Decision::Fresh) {
            self.state.fresh_tick = tick;
        }
        match record.decision {
            Decision::Reference => self.state.reference_deg = Some((record.fwd_holdout_deg, record.inv_holdout_deg)),
            // Too few rows since the change yet: the episode stays open.
            Decision::Waiting => self.state.adapting = true,
            // Improving: the episode goes on at the next check.
            Decision::Swapped => self.state.adapting = true,
            // Converged (nothing validated better), or back under the threshold, or unable.
            Decision::Rejected | Decision::Fresh | Decision::Failed => self.state.adapting = false,
        }
        let mut swap = None;
        if record.decision == Decision::Swapped {
            let generation = self.state.generation + 1;
            let name = format!("gen-{generation:04}");
            let dir = self.dir.join(&name);
            let tmp = self.dir.join(format!(".{name}.partial"));
            if tmp.exists() {
                std::fs::remove_dir_all(&tmp).map_err(|e| file_err(&tmp, e))?;
            }
            std::fs::create_dir_all(&tmp).map_err(|e| file_err(&tmp, e))?;
            // A direction that kept its model carries the one in use into the generation, so a
            // generation directory always holds the complete pair (what a restart loads).
            let fwd = r.new_fwd.as_ref().unwrap_or(&self.fwd);
            let inv = r.new_inv.as_ref().unwrap_or(&self.inv);
            let hash = |m: &ModelFile, file: &str| -> Result<u64, AdaptError> {
                let p = tmp.join(file);
                m.save(&p).map_err(|e| file_err(&p, e))?;
                let bytes = std::fs::read(&p).map_err(|e| file_err(&p, e))?;
                Ok(fnv1a64(&bytes))
            };
            let fwd_hash = hash(fwd, "fwd.onnx")?;
            let inv_hash = hash(inv, "inv.onnx")?;
            if dir.exists() {
                std::fs::remove_dir_all(&dir).map_err(|e| file_err(&dir, e))?;
            }
            std::fs::rename(&tmp, &dir).map_err(|e| file_err(&dir, e))?;
            let s = SwapRecord {
                generation,
                tick,
                dir: dir.clone(),
                // Only the directions that changed are announced: the other stays loaded.
                fwd_hash: if r.new_fwd.is_some() { fwd_hash } else { 0 },
                inv_hash: if r.new_inv.is_some() { inv_hash } else { 0 },
                fwd_before_deg: record.fwd_before_deg,
                fwd_after_deg: record.fwd_after_deg,
                inv_before_deg: record.inv_before_deg,
                inv_after_deg: record.inv_after_deg,
            };
            if let Some(m) = r.new_fwd {
                self.fwd = m;
            }
            if let Some(m) = r.new_inv {
                self.inv = m;
            }
            self.state.generation = generation;
            self.state.fwd_file = dir.join("fwd.onnx");
            self.state.inv_file = dir.join("inv.onnx");
            self.state.swaps.push(s.clone());
            record.generation = generation;
            swap = Some(s);
        }
        self.log(&record)?;
        self.save()?;
        Ok(swap)
    }

    fn log(&self, record: &CheckRecord) -> Result<(), AdaptError> {
        use std::io::Write as _;
        let p = self.dir.join("adapt.jsonl");
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&p)
            .map_err(|e| file_err(&p, e))?;
        let line = serde_json::to_string(record).map_err(|e| file_err(&p, e))?;
        writeln!(f, "{line}").map_err(|e| file_err(&p, e))
    }

    /// Saves `state.json` and `rows.csv` (each written to a temporary file and renamed).
    pub fn save(&self) -> Result<(), AdaptError> {
        let write = |name: &str, text: String| -> Result<(), AdaptError> {
            let p = self.dir.join(name);
            let tmp = self.dir.join(format!(".{name}.tmp"));
            std::fs::write(&tmp, text).map_err(|e| file_err(&tmp, e))?;
            std::fs::rename(&tmp, &p).map_err(|e| file_err(&p, e))
        };
        write(
            "state.json",
            serde_json::to_string_pretty(&self.state).map_err(|e| file_err(&self.dir, e))?,
        )?;
        let mut header = vec!["tick".to_string()];
        for side in ["cmd", "phy"] {
            header.extend((1..=self.joints()).map(|k| format!("q{k}_{side}_deg")));
        }
        let mut csv = TableWriter::new(&header);
        for r in &self.rows {
            // `{:?}` prints the shortest text that reads back to the same f64.
            let angles = r.q_cmd_deg.iter().chain(&r.q_phy_deg).map(|v| format!("{v:?}"));
            csv.row(std::iter::once(r.tick.to_string()).chain(angles));
        }
        write("rows.csv", csv.into_string())
    }

    fn load_rows(&mut self) -> Result<(), AdaptError> {
        let p = self.dir.join("rows.csv");
        if !p.exists() {
            return Ok(());
        }
        let table = Table::read(&p, ReadOptions::default())?;
        let j = self.joints();
        if table.header.len() != 1 + 2 * j {
            return Err(file_err(
                &p,
                format!("{} columns, expected tick and {} angles", table.header.len(), 2 * j),
            ));
        }
        let angle_cols: Vec<usize> = (1..=2 * j).collect();
        let angles = table.finite_rows(&angle_cols)?;
        for (r, q) in angles.into_iter().enumerate() {
            let tick = table
                .i64(r, 0)
                .ok()
                .and_then(|t| u64::try_from(t).ok())
                .ok_or_else(|| {
                    file_err(
                        &p,
                        format!(
                            "line {}: tick {:?} is not a count",
                            table.rows[r].line,
                            table.text(r, 0)
                        ),
                    )
                })?;
            self.rows.push_back(Row {
                tick,
                q_cmd_deg: q[..j].to_vec(),
                q_phy_deg: q[j..].to_vec(),
                q_pred_deg: None,
            });
        }
        while self.rows.len() > self.cfg.window_rows {
            self.rows.pop_front();
        }
        Ok(())
    }
}

/// Rows measured since the change (outside the hold-out) before a fine-tune is tried.
const MIN_NEW_ROWS: usize = 30;

fn holdout_rows(cfg: &AdaptConfig) -> usize {
    ((cfg.window_rows as f64) * cfg.holdout_fraction).round().max(1.0) as usize
}

impl Job {
    /// Rates the forward model in use on the held-out newest rows; when stale, fine-tunes and
    /// validates. Deterministic; heavy (seconds): run it off any real-time loop.
    // Long: the adaptation cycle's states (gather, check staleness, fine-tune, validate, write a generation) in one place so their order is readable.
    pub fn run(self) -> JobResult {
        let n = self.rows.len();
        let j = self.fwd.spec.joints;
        let n_hold = holdout_rows(&self.cfg).min(n / 3).max(1);
        let mut record = CheckRecord {
            tick: 0,
            rows: n,
            generation: self.generation,
            fwd_holdout_deg: f64::NAN,
            inv_holdout_deg: f64::NAN,
            fwd_running_deg: f64::NAN,
            reference_deg: self.reference_deg,
            decision: Decision::Failed,
            fwd_before_deg: f64::NAN,
            fwd_after_deg: f64::NAN,
            inv_before_deg: f64::NAN,
            inv_after_deg: f64::NAN,
            message: String::new(),
        };
        let fail = |mut record: CheckRecord, msg: String| JobResult {
            record: {
                record.decision = Decision::Failed;
                record.message = msg;
                record
            },
            new_fwd: None,
            new_inv: None,
        };
        let dataset = |rows: &[Row]| Dataset {
            joints: j,
            t_ns: rows.iter().map(|r| r.tick as i64).collect(),
            q_cmd_deg: rows.iter().flat_map(|r| r.q_cmd_deg.iter().copied()).collect(),
            q_phy_deg: rows.iter().flat_map(|r| r.q_phy_deg.iter().copied()).collect(),
            q_true_deg: None,
            valid: vec![true; rows.len()],
        };
        // Windows over all rows, rated on the newest n_hold targets (their histories reach
        // back into older rows, which is what the model sees while running).
        let holdout = |m: &ModelFile| -> Result<(WindowSet, Vec<usize>), String> {
            let ws = WindowSet::build_unsplit(&dataset(&self.rows), m.direction, m.spec.seq_len, PhySource::Vision)
                .map_err(|e| e.to_string())?
                .with_normalisers(m.norm_in.clone(), m.norm_out.clone())
                .map_err(|e| e.to_string())?;
            let ids: Vec<usize> = (n - n_hold..n).filter(|&t| t + 1 >= m.spec.seq_len).collect();
            Ok((ws, ids))
        };
        let rate = |m: &ModelFile| -> Result<f64, String> {
            let (ws, ids) = holdout(m)?;
            rmse_deg(m, &ws, &ids).map_err(|e| e.to_string())
        };
        let now = match rate(&self.fwd) {
            Ok(v) => v,
            Err(e) => return fail(record, format!("rating the forward model: {e}")),
        };
        record.fwd_holdout_deg = now;
        let (mut sse, mut cnt) = (0.0, 0usize);
        for r in &self.rows[n - n_hold..] {
            if let Some(p) = &r.q_pred_deg {
                for (a, b) in p.iter().zip(&r.q_phy_deg) {
                    sse += (a - b) * (a - b);
                    cnt += 1;
                }
            }
        }
        record.fwd_running_deg = if cnt > 0 { (sse / cnt as f64).sqrt() } else { f64::NAN };
        let now_inv = match rate(&self.inv) {
            Ok(v) => v,
            Err(e) => return fail(record, format!("rating the inverse model: {e}")),
        };
        record.inv_holdout_deg = now_inv;
        let Some((reference, reference_inv)) = self.reference_deg else {
            record.decision = Decision::Reference;
            record.message = format!("reference held-out errors: forward {now:.3}°, inverse {now_inv:.3}°");
            return JobResult {
                record,
                new_fwd: None,
                new_inv: None,
            };
        };
        let threshold = (reference * self.cfg.stale_factor).max(self.cfg.stale_min_deg);
        let threshold_inv = (reference_inv * self.cfg.stale_factor).max(self.cfg.stale_min_deg);
        let stale = (self.cfg.adapts(true) && now > threshold) || (self.cfg.adapts(false) && now_inv > threshold_inv);
        if !stale && !self.adapting {
            record.decision = Decision::Fresh;
            record.message =
                format!("held-out forward {now:.3}° ≤ {threshold:.3}°, inverse {now_inv:.3}° ≤ {threshold_inv:.3}°");
            return JobResult {
                record,
                new_fwd: None,
                new_inv: None,
            };
        }
        // Stale: fine-tune on the older rows measured since the robot was last found fresh
        // (rows from before the change would teach the old behaviour), early-stop on their
        // last part; rows before that only serve as the windows' history.
        let train_rows = &self.rows[..n - n_hold];
        let first_new = train_rows
            .iter()
            .position(|r| r.tick > self.fresh_tick)
            .unwrap_or(train_rows.len());
        if train_rows.len() - first_new < MIN_NEW_ROWS {
            record.decision = Decision::Waiting;
            record.message = format!(
                "stale (held-out forward {now:.3}°, inverse {now_inv:.3}°): {} rows measured since tick {} outside the hold-out, waiting for {MIN_NEW_ROWS}",
                train_rows.len() - first_new,
                self.fresh_tick
            );
            return JobResult {
                record,
                new_fwd: None,
                new_inv: None,
            };
        }
        let tune = |m: &ModelFile, seed: u64| -> Result<(ModelFile, f64, f64), String> {
            let l = m.spec.seq_len;
            let mut ws = WindowSet::build_unsplit(&dataset(train_rows), m.direction, l, PhySource::Vision)
                .map_err(|e| e.to_string())?
                .with_normalisers(m.norm_in.clone(), m.norm_out.clone())
                .map_err(|e| e.to_string())?;
            let m_rows = train_rows.len();
            let n_new = m_rows - first_new;
            let n_es = ((n_new as f64) * self.cfg.early_stop_fraction).round().max(1.0) as usize;
            ws.train = ((l - 1).max(first_new)..m_rows - n_es).collect();
            ws.val = (m_rows - n_es..m_rows).filter(|&t| t + 1 >= l).collect();
            if ws.train.len() < 10 || ws.val.is_empty() {
                return Err(format!(
                    "{} training and {} early-stopping windows: too few",
                    ws.train.len(),
                    ws.val.len()
                ));
            }
            let cfg = TrainConfig {
                tcn_block: m.spec.tcn_block,
                early_stop: Some(self.cfg.patience),
                batch_size: self.cfg.batch_size,
                lr: self.cfg.lr,
                anchor: self.cfg.anchor,
                ..TrainConfig::paper(m.spec.arch, m.direction, l, self.cfg.epochs, seed)
            };
            // First the output re-centred on the new rows (the offset a slack cable adds is
            // most of what changed, and a mean over many rows sees it through the camera's
            // noise where a gradient step on few windows does not), then every weight
            // fine-tuned from there.
            let shift = mean_residual_deg(m, &ws, &ws.train).map_err(|e| e.to_string())?;
            let mut centred = m.clone();
            for (mean, d) in centred.norm_out.mean.iter_mut().zip(&shift) {
                // f32, as the exported graph stores it.
                *mean = (*mean + d) as f32 as f64;
            }
            let ws = ws
                .with_normalisers(centred.norm_in.clone(), centred.norm_out.clone())
                .map_err(|e| e.to_string())?;
            let mut tuned = fine_tune(&ws, &cfg, &centred, None).map_err(|e| e.to_string())?.model;
            if self.cfg.interpolate < 1.0 {
                interpolate_towards(&mut tuned.params, &centred.params, self.cfg.interpolate as f32);
            }
            let (hws, ids) = holdout(m)?;
            let before = rmse_deg(m, &hws, &ids).map_err(|e| e.to_string())?;
            // The best of the two candidates on the hold-out (each under its own normalisation).
            let mut best = (centred, f64::INFINITY);
            for cand in [best.0.clone(), tuned] {
                let (cws, cids) = holdout(&cand)?;
                let e = rmse_deg(&cand, &cws, &cids).map_err(|e| e.to_string())?;
                if e < best.1 {
                    best = (cand, e);
                }
            }
            Ok((best.0, before, best.1))
        };
        let seed = self.cfg.seed.wrapping_add(self.generation);
        let mut new_fwd = None;
        let mut new_inv = None;
        let mut notes = Vec::new();
        let keep = 1.0 - self.cfg.min_gain;
        for forward in [true, false] {
            if !self.cfg.adapts(forward) {
                continue;
            }
            let m = if forward { &self.fwd } else { &self.inv };
            match tune(m, seed) {
                Ok((new, before, after)) => {
                    let better = after.is_finite() && after < before * keep;
                    if forward {
                        record.fwd_before_deg = before;
                        record.fwd_after_deg = after;
                        new_fwd = better.then_some(new);
                    } else {
                        record.inv_before_deg = before;
                        record.inv_after_deg = after;
                        new_inv = better.then_some(new);
                    }
                    notes.push(format!(
                        "{} {before:.3}° → {after:.3}° {}",
                        if forward { "forward" } else { "inverse" },
                        if better { "accepted" } else { "kept the model in use" }
                    ));
                }
                Err(e) => notes.push(format!("{}: {e}", if forward { "forward" } else { "inverse" })),
            }
        }
        record.decision = if new_fwd.is_some() || new_inv.is_some() {
            Decision::Swapped
        } else if record.fwd_before_deg.is_nan() && record.inv_before_deg.is_nan() {
            Decision::Failed
        } else {
            Decision::Rejected
        };
        let why = if stale {
            format!(
                "stale (held-out forward {now:.3}° vs {threshold:.3}°, inverse {now_inv:.3}° vs {threshold_inv:.3}°)"
            )
        } else {
            format!("held-out forward {now:.3}°, inverse {now_inv:.3}°, adapting since the last swap")
        };
        record.message = format!("{why}: {}", notes.join("; "));
        JobResult {
            record,
            new_fwd,
            new_inv,
        }
    }
}

/// `tuned` ← θ₀ + α(θ − θ₀) with θ₀ = `base`, element by element: the fine-tune pulled back
/// towards the weights it started from (WiSE-FT, Wortsman et al. 2022). Both come from the same
/// network, so their parameter vectors have the same layout.
fn interpolate_towards(tuned: &mut [f32], base: &[f32], alpha: f32) {
    assert_eq!(tuned.len(), base.len(), "fine-tune and base of different networks");
    for (p, p0) in tuned.iter_mut().zip(base) {
        *p = p0 + alpha * (*p - p0);
    }
}

#[cfg(test)]
mod interpolation_tests {
    use super::interpolate_towards;

    #[test]
    fn interpolation_moves_a_fraction_of_the_way_from_the_base() {
        let base = [1.0f32, -2.0, 0.5, 0.0];
        let tuned = [3.0f32, -2.0, -0.5, 8.0];
        let mut quarter = tuned;
        interpolate_towards(&mut quarter, &base, 0.25);
        assert_eq!(quarter, [1.5, -2.0, 0.25, 2.0]);
        let mut whole = tuned;
        interpolate_towards(&mut whole, &base, 1.0);
        assert_eq!(whole, tuned);
    }
}
