//! `bowden-tuning`: the controller settings for a new robot, chosen by the tool from the robot's
//! own validation data — never by hand, never on the test paths (docs/architecture.md,
//! "Settings chosen by the tool").
//!
//! What is chosen, and from what:
//! - **the history step** (the joint-space distance the desired command must travel before
//!   the models' history advances): the grid of the training commands — the most frequent
//!   |Δq_cmd| between consecutive commands (3·√5° for eq. 16, also under `mixed`'s dither),
//!   the spacing the models learned one time step to be ([`command_spacing_deg`]);
//! - **the model pair** (one forward and one inverse among those trained, e.g. TCN and LSTM),
//!   **the mode** (Algorithm 1 or Gauss–Newton) and **newton's prior weight μ**: every
//!   combination is replayed on the validation stretch of the dataset — the path the robot
//!   actually made, its measured q_phy as the targets — through the real [`Compensator`] with
//!   the safe refinement on, exactly as it would run; the commands it sends are then rated by a
//!   forward model *other* than the one that chose them (a judge: a model's own rating is what
//!   its refinement minimised, so it flatters itself) — by the judge-only models when some are
//!   given (one yardstick for every candidate), else by the other forward models, or by the
//!   same one when only one was trained (the report says which). The lowest judged RMS error |f_judge(q_cmd) − q_desired|
//!   wins; when no candidate beats sending the targets unchanged, the mode is `uncalibrated`.
//!
//! Everything is deterministic (no time budget during the replay, fixed order, ties to the
//! first candidate): the same dataset and models give the same config bytes.

use bowden_compensator::config::HistoryRuleName;
use bowden_compensator::{
    Compensator, CompensatorError, ControllerConfig, Evaluator, Mode, Model, ModelError, SafetyConfig, StepOutput,
    WindowModel,
};
use bowden_kinematics::Robot;
use bowden_learning::arch::Direction as LearnDirection;
use bowden_learning::dataset::Dataset;
pub use bowden_learning::spacing::command_spacing_deg;
use bowden_learning::windows::{PhySource, SplitConfig, WindowSet};
use serde::Serialize;
use std::path::{Path, PathBuf};

pub const REPORT_FORMAT: &str = "bowden-tune-report/1";

/// Why settings could not be chosen.
#[derive(Debug, thiserror::Error)]
pub enum TuneError {
    #[error("{0}")]
    Model(#[from] ModelError),
    #[error("{0}")]
    Compensator(#[from] CompensatorError),
    #[error("{path}: expected a {want} model, the file's metadata says {found}")]
    Direction { path: String, want: String, found: String },
    #[error("no {0} model given")]
    NoModels(&'static str),
    #[error("the dataset cannot be split: {0}")]
    Split(String),
    #[error("the dataset has {found} validation samples with a valid estimate; tuning needs at least {need}")]
    TooFewSamples { found: usize, need: usize },
    #[error("base controller config: {0}")]
    BaseConfig(String),
    #[error("options: {0}")]
    Options(String),
}

/// What to try.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneOptions {
    /// The split the models were trained with (its validation part is what is replayed).
    pub split: SplitConfig,
    /// Validation steps replayed per candidate (after the warm-up), from the start of the
    /// validation stretch.
    pub max_steps: usize,
    /// Modes to consider besides `uncalibrated` (always the reference).
    pub modes: Vec<Mode>,
    /// Newton's prior weights to try; σ_f/σ_i (the MAP weight from the validation RMSEs) is
    /// added for every pair.
    pub prior_weights: Vec<f64>,
    /// Forward models used only to rate the candidates (e.g. an LSTM too slow for the 1 kHz
    /// cycle judging the TCN pair that will run in it).
    pub judges: Vec<PathBuf>,
}

impl Default for TuneOptions {
    fn default() -> Self {
        Self {
            split: SplitConfig::default(),
            max_steps: 1000,
            modes: vec![Mode::Paper, Mode::Newton],
            prior_weights: vec![0.0, 0.5, 1.0, 2.0],
            judges: Vec::new(),
        }
    }
}

/// One model's accuracy on the validation windows.
#[derive(Debug, Clone, Serialize)]
pub struct ModelScore {
    pub path: String,
    pub architecture: String,
    pub seq_len: usize,
    pub val_rmse_deg: f64,
    pub windows: usize,
}

/// One combination replayed.
#[derive(Debug, Clone, Serialize)]
pub struct Candidate {
    pub forward: usize,
    pub inverse: usize,
    pub mode: String,
    /// Newton's μ (None for Algorithm 1).
    pub prior_weight: Option<f64>,
    /// RMS over steps and joints of |f_judge(q_cmd) − q_desired|, deg: what decides.
    pub judged_rmse_deg: f64,
    /// The same by the candidate's own forward model (what its refinement minimised).
    pub self_rmse_deg: f64,
    /// Steps where the safe refinement sent the refinement's start / the target unchanged.
    pub start_chosen: u64,
    pub desired_chosen: u64,
    /// Steps where a safety bound moved a candidate.
    pub safety_limited: u64,
}

/// Everything `bowden tune` decided and why (`tune.json`).
#[derive(Debug, Clone, Serialize)]
pub struct TuneReport {
    pub format: String,
    pub samples: usize,
    pub validation_samples: usize,
    pub warmup_steps: usize,
    pub replayed_steps: usize,
    /// The training commands' grid step (see [`command_spacing_deg`]), deg.
    pub step_deg: f64,
    pub forward: Vec<ModelScore>,
    pub inverse: Vec<ModelScore>,
    /// Forward models that only judged (`TuneOptions::judges`).
    pub judge_only: Vec<ModelScore>,
    /// Which forward models judged each forward model's candidates: indices into `forward`,
    /// then `judge_only` (index `forward.len() + k`).
    pub judges: Vec<Vec<usize>>,
    /// The judged error of sending the targets unchanged (the bar every mode must beat).
    pub uncalibrated_judged_rmse_deg: Vec<f64>,
    pub candidates: Vec<Candidate>,
    /// Index into `candidates`; None = uncalibrated (nothing beat it).
    pub chosen: Option<usize>,
    pub chosen_mode: String,
    /// By how much the choice won (issue #43: a choice that wins by a hair on the validation
    /// stretch says little about other paths).
    pub margins: Margins,
}

/// The choice against its closest rivals, by judged RMSE (deg; positive: the choice is better).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Margins {
    /// The best candidate other than the chosen one (index into `candidates`).
    pub runner_up: Option<usize>,
    /// runner-up's judged RMSE − the choice's; with nothing chosen, the best candidate's
    /// judged RMSE − sending the targets unchanged (its judges' figure): how much it missed by.
    pub runner_up_margin_deg: Option<f64>,
    /// The best candidate of the other refinement mode (paper vs newton).
    pub other_mode: Option<usize>,
    pub other_mode_margin_deg: Option<f64>,
    /// Sending the targets unchanged (under the choice's judges) − the choice's judged RMSE.
    pub uncalibrated_margin_deg: Option<f64>,
}

impl TuneReport {
    /// One line: what was chosen and by how much it won against the runner-up, the best of the
    /// other mode and the targets unchanged (None without any candidate).
    pub fn margin_line(&self) -> Option<String> {
        let m = &self.margins;
        let name = |k: usize| {
            let c = &self.candidates[k];
            format!(
                "{}{} (forward {}, inverse {})",
                c.mode,
                c.prior_weight.map(|mu| format!(" μ {mu}")).unwrap_or_default(),
                c.forward,
                c.inverse
            )
        };
        let Some(k) = self.chosen else {
            let (b, d) = (m.runner_up?, m.runner_up_margin_deg?);
            return Some(format!(
                "chose uncalibrated: the best candidate, {}, was {d:+.3}° from beating the targets unchanged",
                name(b)
            ));
        };
        let judged = self.candidates[k].judged_rmse_deg;
        let rel = |d: f64| if judged > 0.0 { 100.0 * d / judged } else { f64::NAN };
        let mut line = format!("chose {}: judged RMSE {judged:.3}°", name(k));
        if let (Some(u), Some(d)) = (m.runner_up, m.runner_up_margin_deg) {
            line += &format!("; runner-up {} by {d:+.3}° ({:+.1} %)", name(u), rel(d));
        }
        if let (Some(o), Some(d)) = (m.other_mode, m.other_mode_margin_deg) {
            line += &format!("; best of the other mode {} by {d:+.3}° ({:+.1} %)", name(o), rel(d));
        }
        if let Some(d) = m.uncalibrated_margin_deg {
            line += &format!("; targets unchanged by {d:+.3}°");
        }
        Some(line)
    }
}

/// [`Margins`] of choice `chosen` among `candidates`; `uncal[f]`: the judged error of sending
/// the targets unchanged under forward model f's judges.
pub fn margins(candidates: &[Candidate], chosen: Option<usize>, uncal: &[f64]) -> Margins {
    let best_where = |keep: &dyn Fn(usize, &Candidate) -> bool| {
        candidates
            .iter()
            .enumerate()
            .filter(|(k, c)| c.judged_rmse_deg.is_finite() && keep(*k, c))
            .min_by(|a, b| a.1.judged_rmse_deg.total_cmp(&b.1.judged_rmse_deg))
            .map(|(k, _)| k)
    };
    let Some(ch) = chosen else {
        let best = best_where(&|_, _| true);
        return Margins {
            runner_up: best,
            runner_up_margin_deg: best
                .map(|b| candidates[b].judged_rmse_deg - uncal.get(candidates[b].forward).copied().unwrap_or(f64::NAN)),
            ..Margins::default()
        };
    };
    let c = &candidates[ch];
    let runner_up = best_where(&|k, _| k != ch);
    let other_mode = best_where(&|_, o| o.mode != c.mode);
    let margin = |k: Option<usize>| k.map(|k| candidates[k].judged_rmse_deg - c.judged_rmse_deg);
    Margins {
        runner_up,
        runner_up_margin_deg: margin(runner_up),
        other_mode,
        other_mode_margin_deg: margin(other_mode),
        uncalibrated_margin_deg: uncal.get(c.forward).map(|u| u - c.judged_rmse_deg),
    }
}

/// The chosen settings: the controller config (models named by the paths given) and the report.
pub struct TuneOutcome {
    pub config: ControllerConfig,
    pub report: TuneReport,
    pub model_fwd: PathBuf,
    pub model_inv: PathBuf,
}

/// Rolling history of the last `rows` inputs (zero-padded, oldest first), as the models see it.
struct Rolling {
    j: usize,
    rows: usize,
    buf: Vec<f64>,
}

impl Rolling {
    fn new(rows: usize, j: usize) -> Self {
        Self {
            j,
            rows,
            buf: vec![0.0; rows * j],
        }
    }
    fn push(&mut self, row: &[f64]) {
        if self.rows == 0 {
            return;
        }
        self.buf.drain(..self.j);
        self.buf.extend_from_slice(row);
    }
    /// The newest `n` rows (n ≤ rows).
    fn tail(&self, n: usize) -> &[f64] {
        &self.buf[(self.rows - n) * self.j..]
    }
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// A model's validation RMSE (deg) over the windows of `val` (skipping any with an invalid
/// estimate), at most `max` windows from the start of the stretch.
fn val_rmse(model: &Model, ds: &Dataset, val: &[usize], max: usize) -> (f64, usize) {
    let j = ds.joints;
    let l = model.seq_len();
    let forward = model.metadata().direction == bowden_learning::Direction::Forward;
    type Column = fn(&Dataset, usize) -> &[f64];
    let (input, target): (Column, Column) = if forward {
        (Dataset::cmd, Dataset::phy)
    } else {
        (Dataset::phy, Dataset::cmd)
    };
    let mut ev = model.evaluator();
    let mut hist = vec![0.0; (l - 1) * j];
    let mut out = vec![0.0; j];
    let (mut se, mut n) = (0.0, 0usize);
    for &t in val.iter().take(max) {
        let mut ok = finite(input(ds, t)) && finite(target(ds, t));
        for r in 0..l - 1 {
            let src = t as isize - (l as isize - 1) + r as isize;
            let row = &mut hist[r * j..(r + 1) * j];
            if src < 0 {
                row.fill(0.0);
            } else {
                let v = input(ds, src as usize);
                ok &= finite(v);
                row.copy_from_slice(v);
            }
        }
        if !ok {
            continue;
        }
        ev.set_history(&hist);
        ev.eval(input(ds, t), &mut out);
        se += out
            .iter()
            .zip(target(ds, t))
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>();
        n += 1;
    }
    (((se / (n * j).max(1) as f64).sqrt()), n)
}

struct Replay<'a> {
    ds: &'a Dataset,
    robot: &'a Robot,
    /// Indices replayed: warm-up context, then the scored validation steps.
    steps: Vec<usize>,
    warmup: usize,
}

struct ReplayResult {
    judged: Vec<f64>,
    self_rated: f64,
    start_chosen: u64,
    desired_chosen: u64,
    limited: u64,
}

impl Replay<'_> {
    /// Runs `cfg` with the models through the replay; rates what it sent with each judge.
    fn run(
        &self,
        cfg: &ControllerConfig,
        fwd: &Model,
        inv: &Model,
        judges: &[&Model],
    ) -> Result<ReplayResult, TuneError> {
        let j = self.ds.joints;
        let mut comp = Compensator::from_models(cfg, self.robot, Some(fwd.clone()), Some(inv.clone()))?;
        let rows = judges.iter().map(|m| m.seq_len() - 1).max().unwrap_or(0);
        let mut sent = Rolling::new(rows, j);
        let mut evs: Vec<Evaluator> = judges.iter().map(|m| m.evaluator()).collect();
        let mut pred = vec![0.0; j];
        let mut se = vec![0.0; judges.len()];
        let (mut se_self, mut n_self, mut n) = (0.0, 0usize, 0usize);
        let mut out = StepOutput::default();
        for (k, &t) in self.steps.iter().enumerate() {
            let q_des = self.ds.phy(t);
            if !finite(q_des) {
                continue;
            }
            // A rejected target cannot happen (checked finite); an error here is a bug upstream.
            if comp.step(q_des, &mut out).is_err() {
                continue;
            }
            let cmd = &out.q_cmd_deg[..j];
            if k >= self.warmup {
                for (e, (ev, m)) in evs.iter_mut().zip(judges).enumerate() {
                    ev.set_history(sent.tail(m.seq_len() - 1));
                    ev.eval(cmd, &mut pred);
                    se[e] += pred.iter().zip(q_des).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
                }
                n += 1;
                if out.has_prediction {
                    se_self += (0..j).map(|c| (out.q_predicted_deg[c] - q_des[c]).powi(2)).sum::<f64>();
                    n_self += 1;
                }
            }
            sent.push(cmd);
        }
        let c = comp.safety_counts();
        let rms = |s: f64, n: usize| if n == 0 { f64::NAN } else { (s / (n * j) as f64).sqrt() };
        Ok(ReplayResult {
            judged: se.iter().map(|&s| rms(s, n)).collect(),
            self_rated: rms(se_self, n_self),
            start_chosen: c.start_chosen,
            desired_chosen: c.desired_chosen,
            limited: c.limited,
        })
    }
}

/// Loads the candidates as the controller will (`base`'s `[load_check]`).
fn load(
    paths: &[PathBuf],
    want: bowden_learning::Direction,
    check: &bowden_compensator::LoadOptions,
) -> Result<Vec<Model>, TuneError> {
    paths
        .iter()
        .map(|p| {
            let m = Model::load_with(p, check)?;
            if m.metadata().direction != want {
                return Err(TuneError::Direction {
                    path: p.display().to_string(),
                    want: want.to_string(),
                    found: m.metadata().direction.to_string(),
                });
            }
            Ok(m)
        })
        .collect()
}

/// Chooses the settings (see the crate docs). `progress(done, total)` after every candidate.
// Long: the candidates are replayed and rated in one pass over the validation data; the loop body is the rating.
pub fn tune(
    ds: &Dataset,
    forward: &[PathBuf],
    inverse: &[PathBuf],
    base: &ControllerConfig,
    robot: &Robot,
    opts: &TuneOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<TuneOutcome, TuneError> {
    use bowden_learning::Direction as D;
    if forward.is_empty() {
        return Err(TuneError::NoModels("forward"));
    }
    if inverse.is_empty() {
        return Err(TuneError::NoModels("inverse"));
    }
    if opts.max_steps == 0 || opts.modes.contains(&Mode::Uncalibrated) {
        return Err(TuneError::Options(
            "max_steps must be ≥ 1 and modes must not list uncalibrated (it is always the reference)".into(),
        ));
    }
    if let Some(m) = opts.prior_weights.iter().find(|m| !(m.is_finite() && **m >= 0.0)) {
        return Err(TuneError::Options(format!("prior weight {m} must be finite and ≥ 0")));
    }
    base.validate().map_err(|e| TuneError::BaseConfig(e.to_string()))?;
    let fwd = load(forward, D::Forward, &base.load_check.options())?;
    let inv = load(inverse, D::Inverse, &base.load_check.options())?;
    let judge_models = load(&opts.judges, D::Forward, &base.load_check.options())?;

    let split = WindowSet::build(ds, LearnDirection::Forward, 1, opts.split, PhySource::Vision)
        .map_err(|e| TuneError::Split(e.to_string()))?;
    let step_deg = command_spacing_deg(ds, &split.train).ok_or(TuneError::TooFewSamples { found: 0, need: 2 })?;
    let valid_val = split.val.iter().filter(|&&t| ds.valid[t]).count();
    let need = 20;
    if valid_val < need {
        return Err(TuneError::TooFewSamples { found: valid_val, need });
    }

    let score = |m: &Model| {
        let (rmse, windows) = val_rmse(m, ds, &split.val, opts.max_steps);
        ModelScore {
            path: m.path().to_string(),
            architecture: m.metadata().architecture.to_string(),
            seq_len: m.seq_len(),
            val_rmse_deg: rmse,
            windows,
        }
    };
    let fwd_scores: Vec<ModelScore> = fwd.iter().map(score).collect();
    let judge_scores: Vec<ModelScore> = judge_models.iter().map(score).collect();
    let inv_scores: Vec<ModelScore> = inv.iter().map(score).collect();

    // The replay: the models' longest history as warm-up context before the validation stretch.
    let warm = fwd
        .iter()
        .chain(&inv)
        .chain(&judge_models)
        .map(|m| m.seq_len() - 1)
        .max()
        .unwrap_or(0);
    let v0 = split.val[0];
    let scored: Vec<usize> = split.val.iter().copied().take(opts.max_steps).collect();
    let steps: Vec<usize> = (v0.saturating_sub(warm)..v0).chain(scored.iter().copied()).collect();
    let replay = Replay {
        ds,
        robot,
        warmup: v0 - v0.saturating_sub(warm),
        steps,
    };
    // With judge-only models, they rate every candidate: one yardstick for all. Without, every
    // forward model but the candidate's own rates it. Cross-judging compares candidates rated by
    // different models, which favours the forward model whose judge is the most accurate: on
    // the second robot, the TCN forward's candidates (judged by the 0.9° LSTM) beat the LSTM
    // forward's (judged by the 3.3° TCN), and the chosen config tracked 5–9 points worse than
    // the LSTM pair it displaced.
    let raters: Vec<&Model> = fwd.iter().chain(&judge_models).collect();
    let judges: Vec<Vec<usize>> = (0..fwd.len())
        .map(|i| {
            if !judge_models.is_empty() {
                return (fwd.len()..raters.len()).collect();
            }
            let others: Vec<usize> = (0..raters.len()).filter(|&k| k != i).collect();
            if others.is_empty() {
                vec![i]
            } else {
                others
            }
        })
        .collect();

    let mut replay_cfg = base.clone();
    replay_cfg.budget.budget_ns = 0;
    replay_cfg.output.rate_limit_deg_s = 0.0;
    replay_cfg.history.rule = HistoryRuleName::EveryStep;
    // The base config's safeguards (the shipped ones are on); a base without `[safety]` gets
    // every safeguard on: a tuned controller always runs the safe refinement.
    let safety = if base.safety == SafetyConfig::default() {
        SafetyConfig::on()
    } else {
        base.safety.clone()
    };
    replay_cfg.safety = safety.clone();

    // The plan, in a fixed order.
    let mut plan: Vec<(usize, usize, Mode, Option<f64>)> = Vec::new();
    for (fi, fs) in fwd_scores.iter().enumerate() {
        for (ii, is) in inv_scores.iter().enumerate() {
            for &mode in &opts.modes {
                match mode {
                    Mode::Newton => {
                        let mut mus = opts.prior_weights.clone();
                        let map = fs.val_rmse_deg / is.val_rmse_deg;
                        if map.is_finite() {
                            mus.push((map * 1000.0).round() / 1000.0);
                        }
                        mus.sort_by(|a, b| a.total_cmp(b));
                        mus.dedup();
                        plan.extend(mus.into_iter().map(|mu| (fi, ii, mode, Some(mu))));
                    }
                    _ => plan.push((fi, ii, mode, None)),
                }
            }
        }
    }
    let total = plan.len() + fwd.len();
    let mut done = 0;

    // The bar: the targets sent unchanged, judged as each forward model's candidates are.
    let mut uncal = Vec::with_capacity(fwd.len());
    for fi in 0..fwd.len() {
        let mut cfg = replay_cfg.clone();
        cfg.mode = Mode::Uncalibrated;
        let js: Vec<&Model> = judges[fi].iter().map(|&k| raters[k]).collect();
        let r = replay.run(&cfg, &fwd[fi], &inv[0], &js)?;
        uncal.push(mean(&r.judged));
        done += 1;
        progress(done, total);
    }

    let mut candidates = Vec::with_capacity(plan.len());
    for &(fi, ii, mode, mu) in &plan {
        let mut cfg = replay_cfg.clone();
        cfg.mode = mode;
        if let Some(mu) = mu {
            cfg.newton.prior_weight = mu;
        }
        let js: Vec<&Model> = judges[fi].iter().map(|&k| raters[k]).collect();
        let r = replay.run(&cfg, &fwd[fi], &inv[ii], &js)?;
        candidates.push(Candidate {
            forward: fi,
            inverse: ii,
            mode: mode.as_str().to_string(),
            prior_weight: mu,
            judged_rmse_deg: mean(&r.judged),
            self_rmse_deg: r.self_rated,
            start_chosen: r.start_chosen,
            desired_chosen: r.desired_chosen,
            safety_limited: r.limited,
        });
        done += 1;
        progress(done, total);
    }

    // Lowest judged error; it must beat sending the targets unchanged under the same judges.
    let mut chosen: Option<usize> = None;
    for (k, c) in candidates.iter().enumerate() {
        let beats_uncal = c.judged_rmse_deg < uncal[c.forward];
        let better = chosen.is_none_or(|b| c.judged_rmse_deg < candidates[b].judged_rmse_deg);
        if c.judged_rmse_deg.is_finite() && beats_uncal && better {
            chosen = Some(k);
        }
    }

    let mut config = base.clone();
    config.history.rule = HistoryRuleName::Distance;
    config.history.step_deg = step_deg;
    config.safety = safety;
    let (fi, ii) = match chosen {
        Some(k) => {
            let c = &candidates[k];
            config.mode = Mode::parse(&c.mode).unwrap_or(Mode::Uncalibrated);
            if let Some(mu) = c.prior_weight {
                config.newton.prior_weight = mu;
            }
            (c.forward, c.inverse)
        }
        None => {
            config.mode = Mode::Uncalibrated;
            (0, 0)
        }
    };
    config.model_fwd = Some(forward[fi].clone());
    config.model_inv = Some(inverse[ii].clone());
    config.validate().map_err(|e| TuneError::BaseConfig(e.to_string()))?;
    let report = TuneReport {
        format: REPORT_FORMAT.into(),
        samples: ds.len(),
        validation_samples: split.val.len(),
        warmup_steps: replay.warmup,
        replayed_steps: scored.len(),
        step_deg,
        forward: fwd_scores,
        inverse: inv_scores,
        judge_only: judge_scores,
        judges,
        margins: margins(&candidates, chosen, &uncal),
        uncalibrated_judged_rmse_deg: uncal,
        candidates,
        chosen,
        chosen_mode: config.mode.as_str().to_string(),
    };
    Ok(TuneOutcome {
        config,
        report,
        model_fwd: forward[fi].clone(),
        model_inv: inverse[ii].clone(),
    })
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// The chosen settings as a controller config file: the base file's tables with the chosen
/// values written over them, `model_fwd`/`model_inv` as `fwd_name`/`inv_name` (paths as they
/// should appear in the file), and a header saying how every value was chosen.
pub fn config_toml(
    base_text: &str,
    outcome: &TuneOutcome,
    fwd_name: &str,
    inv_name: &str,
) -> Result<String, TuneError> {
    use toml::Value;
    let mut doc: toml::Table = toml::from_str(base_text).map_err(|e| TuneError::BaseConfig(e.to_string()))?;
    let c = &outcome.config;
    let r = &outcome.report;
    doc.insert("mode".into(), Value::String(c.mode.as_str().into()));
    doc.insert("model_fwd".into(), Value::String(fwd_name.into()));
    doc.insert("model_inv".into(), Value::String(inv_name.into()));
    let table = |doc: &mut toml::Table, name: &str| -> toml::Table {
        doc.get(name).and_then(|v| v.as_table()).cloned().unwrap_or_default()
    };
    let mut newton = table(&mut doc, "newton");
    newton.insert("prior_weight".into(), Value::Float(c.newton.prior_weight));
    doc.insert("newton".into(), Value::Table(newton));
    let mut history = table(&mut doc, "history");
    history.insert("rule".into(), Value::String("distance".into()));
    history.insert("step_deg".into(), Value::Float(c.history.step_deg));
    doc.insert("history".into(), Value::Table(history));
    let mut safety = toml::Table::new();
    safety.insert("support".into(), Value::Boolean(c.safety.support));
    safety.insert("support_scale".into(), Value::Float(c.safety.support_scale));
    safety.insert("step_scale".into(), Value::Float(c.safety.step_scale));
    safety.insert("never_worse".into(), Value::Boolean(c.safety.never_worse));
    if c.safety.never_worse_tip {
        // Written only when on, so configs tuned without it keep their bytes.
        safety.insert("never_worse_tip".into(), Value::Boolean(true));
    }
    safety.insert("correction_scale".into(), Value::Float(c.safety.correction_scale));
    doc.insert("safety".into(), Value::Table(safety));
    let body = toml::to_string(&doc).map_err(|e| TuneError::BaseConfig(e.to_string()))?;

    let mut head = String::new();
    head.push_str("# Controller settings chosen by `bowden tune` from the robot's validation data (never by hand,\n");
    head.push_str("# never on test paths; docs/architecture.md, \"Settings chosen by the tool\"). tune.json beside\n");
    head.push_str("# this file holds every candidate.\n#\n");
    head.push_str(&format!(
        "# history.step_deg = {:.4}: the grid of the training commands (most frequent |Δq_cmd|).\n",
        r.step_deg
    ));
    let line = |role: &str, k: usize, s: &ModelScore, tail: String| {
        format!(
            "# {role} #{k}: {} ({} L={}), validation RMSE {:.3}° {tail}\n",
            name_of(&s.path),
            s.architecture,
            s.seq_len,
            s.val_rmse_deg
        )
    };
    for (k, s) in r.forward.iter().enumerate() {
        head.push_str(&line("forward", k, s, format!("over {} windows", s.windows)));
    }
    for (k, s) in r.judge_only.iter().enumerate() {
        head.push_str(&line("judge", r.forward.len() + k, s, "(rates candidates only)".into()));
    }
    for (k, s) in r.inverse.iter().enumerate() {
        head.push_str(&line("inverse", k, s, format!("over {} windows", s.windows)));
    }
    head.push_str(&format!(
        "# Replayed {} validation steps (after {} of warm-up) per candidate, safe refinement on; the sent\n",
        r.replayed_steps, r.warmup_steps
    ));
    head.push_str("# commands rated by another forward model where one was trained (else by the same one):\n");
    for (k, u) in r.uncalibrated_judged_rmse_deg.iter().enumerate() {
        head.push_str(&format!(
            "#   targets unchanged, judged as forward #{k}'s candidates: {u:.3}°\n"
        ));
    }
    for (k, cand) in r.candidates.iter().enumerate() {
        let mark = if Some(k) == r.chosen { "  <- chosen" } else { "" };
        let mu = cand.prior_weight.map(|m| format!(" μ = {m}")).unwrap_or_default();
        head.push_str(&format!(
            "#   fwd #{} inv #{} {}{}: judged {:.3}° (own model {:.3}°){}\n",
            cand.forward, cand.inverse, cand.mode, mu, cand.judged_rmse_deg, cand.self_rmse_deg, mark
        ));
    }
    if r.chosen.is_none() {
        head.push_str("# No candidate beat sending the targets unchanged: mode = uncalibrated.\n");
    }
    head.push('\n');
    Ok(head + &body)
}

fn name_of(p: &str) -> String {
    Path::new(p)
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.to_string())
}

#[cfg(test)]
mod margin_tests {
    use super::*;

    fn cand(forward: usize, mode: &str, judged: f64) -> Candidate {
        Candidate {
            forward,
            inverse: 0,
            mode: mode.into(),
            prior_weight: None,
            judged_rmse_deg: judged,
            self_rmse_deg: judged,
            start_chosen: 0,
            desired_chosen: 0,
            safety_limited: 0,
        }
    }

    #[test]
    fn margins_name_the_runner_up_and_the_best_of_the_other_mode() {
        let c = [
            cand(0, "newton", 1.5),
            cand(0, "paper", 1.8),
            cand(1, "newton", 1.2),
            cand(1, "paper", f64::NAN),
        ];
        let m = margins(&c, Some(2), &[4.0, 3.0]);
        assert_eq!(m.runner_up, Some(0));
        assert!((m.runner_up_margin_deg.unwrap() - 0.3).abs() < 1e-12);
        assert_eq!(m.other_mode, Some(1), "the NaN candidate is no rival");
        assert!((m.other_mode_margin_deg.unwrap() - 0.6).abs() < 1e-12);
        assert!((m.uncalibrated_margin_deg.unwrap() - 1.8).abs() < 1e-12);
        // Nothing chosen: how far the best candidate was from beating the targets unchanged.
        let m = margins(&c, None, &[1.0, 1.0]);
        assert_eq!(m.runner_up, Some(2));
        assert!((m.runner_up_margin_deg.unwrap() - 0.2).abs() < 1e-12);
        assert_eq!(m.other_mode, None);
    }
}
