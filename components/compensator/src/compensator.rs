//! The compensation step: q_desired(t) → q_cmd(t), bounded in time and allocation-free.

use crate::config::{ConfigError, ControllerConfig, EvaluatorChoice, Mode, SafetyConfig};
use crate::history::History;
use crate::model::{Evaluator, Model, ModelError};
use crate::net::IncrementalNet;
use crate::prefix::{PrefixSync, PrefixWorker, PrefixWorkerOptions, FWD, INV};
use crate::refine::{newton_refine, paper_refine, NewtonParams, PaperParams, RefineResult, StopReason, WindowModel};
use bowden_interfaces::model::{Direction, Support, MAX_JOINTS};
use bowden_kinematics::{Robot, N_JOINTS};
use std::time::Instant;

/// Why a compensator cannot be built or switched.
#[derive(Debug, thiserror::Error)]
pub enum CompensatorError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("mode `{mode}` needs {which} model, but the config has no `{field}`")]
    MissingModel {
        mode: Mode,
        which: &'static str,
        field: &'static str,
    },
    #[error("{path}: {what}")]
    Mismatch { path: String, what: String },
}

/// A rejected target (the step holds the last command and counts it).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StepError {
    #[error("target has {found} joints, expected {expected}")]
    WrongLength { expected: usize, found: usize },
    #[error("target q{joint} = {value} deg is not finite")]
    NotFinite { joint: usize, value: f64 },
}

/// The result of one [`Compensator::step`]. Arrays hold `joints` used entries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutput {
    pub joints: usize,
    pub mode: Mode,
    pub q_desired_deg: [f64; MAX_JOINTS],
    /// The command to send (after rate and joint limits).
    pub q_cmd_deg: [f64; MAX_JOINTS],
    /// The refinement's result before the output limits.
    pub q_refined_deg: [f64; MAX_JOINTS],
    /// Forward-model prediction of the physical angles at `q_cmd_deg` (zeros without a
    /// forward model).
    pub q_predicted_deg: [f64; MAX_JOINTS],
    pub has_prediction: bool,
    /// max_j |q_predicted − q_desired| (NaN without a forward model).
    pub loss_max_abs_deg: f64,
    /// Refinement iterations.
    pub iterations: u32,
    /// Forward-model evaluations this step (refinement plus the prediction at q_cmd).
    pub forward_evals: u32,
    pub stop_reason: StopReason,
    /// Wall time of the step, ns (a measurement; it never changes the result unless a
    /// budget is set).
    pub elapsed_ns: u64,
    pub rate_limited: bool,
    pub joint_limited: bool,
    /// History entries appended after this step (0 most cycles at 1 kHz).
    pub history_appended: u32,
    /// Which candidate the safe refinement sent (`Refined` when `never_worse` is off).
    pub chosen: Chosen,
    /// A safety bound (support, step or drift guard) moved a candidate this step.
    pub safety_limited: bool,
    /// The vision-feedback correction added to the command this step
    /// ([`Compensator::step_with_correction`]; zeros otherwise).
    pub correction_deg: [f64; MAX_JOINTS],
    /// Joints (bit k = joint k) whose sent command sits at an upper bound: lowered by the
    /// joint limits, or at the top of the training data's command range. The feedback's
    /// anti-windup does not integrate a positive error there.
    pub upper_mask: u32,
    /// Likewise at a lower bound.
    pub lower_mask: u32,
    /// Joints (bit k = joint k) the robot's joint limits or jaw rule lowered this step
    /// (`joint_limited` says whether any did); counted by `bowden compensate` and reported.
    pub joint_limit_lowered_mask: u32,
    /// Likewise raised.
    pub joint_limit_raised_mask: u32,
    /// History entries the window prefixes this step ran on lag behind the history (the
    /// larger of the two models). Always 0 unless a prefix worker in
    /// [`PrefixSync::Newest`] mode had not finished the newest one
    /// ([`Compensator::start_prefix_worker`]).
    pub prefix_lag: u32,
}

/// The candidate a step sent (`[safety] never_worse`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Chosen {
    /// The refinement's result (always, when `never_worse` is off or no model runs).
    #[default]
    Refined,
    /// The refinement's start (the inverse model's estimate): the model rated the result worse.
    Start,
    /// The target unchanged: the model rated both worse than sending it as it is.
    Desired,
}

/// What the safe refinement did since the compensator was built (or reset).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SafetyCounts {
    pub steps: u64,
    /// Steps where a bound moved a candidate.
    pub limited: u64,
    /// Steps that sent the refinement's start instead of its result.
    pub start_chosen: u64,
    /// Steps that sent the target unchanged.
    pub desired_chosen: u64,
}

impl Default for StepOutput {
    fn default() -> Self {
        Self {
            joints: 0,
            mode: Mode::Uncalibrated,
            q_desired_deg: [0.0; MAX_JOINTS],
            q_cmd_deg: [0.0; MAX_JOINTS],
            q_refined_deg: [0.0; MAX_JOINTS],
            q_predicted_deg: [0.0; MAX_JOINTS],
            has_prediction: false,
            loss_max_abs_deg: f64::NAN,
            iterations: 0,
            forward_evals: 0,
            stop_reason: StopReason::None,
            elapsed_ns: 0,
            rate_limited: false,
            joint_limited: false,
            history_appended: 0,
            chosen: Chosen::Refined,
            safety_limited: false,
            correction_deg: [0.0; MAX_JOINTS],
            upper_mask: 0,
            lower_mask: 0,
            joint_limit_lowered_mask: 0,
            joint_limit_raised_mask: 0,
            prefix_lag: 0,
        }
    }
}

impl StepOutput {
    /// Copies the result into a `JointCommand` sample (the header is the caller's).
    pub fn fill_joint_command(&self, cmd: &mut bowden_interfaces::JointCommand) {
        cmd.n_joints = self.joints as u32;
        cmd.mode = self.mode.to_interface() as u32;
        cmd.q_cmd_deg = self.q_cmd_deg;
        cmd.q_desired_deg = self.q_desired_deg;
        cmd.q_predicted_deg = self.q_predicted_deg;
        cmd.iterations = self.iterations;
        cmd.stop_reason = self.stop_reason.code();
        cmd.compute_ns = self.elapsed_ns;
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Prefix {
    Valid,
    Shift,
    Full,
}

/// The compensator of one robot: models, histories, refinement settings, output limits.
pub struct Compensator {
    mode: Mode,
    j: usize,
    fwd: Option<Evaluator>,
    inv: Option<Evaluator>,
    fwd_l: usize,
    inv_l: usize,
    fwd_prefix: Prefix,
    inv_prefix: Prefix,
    history: History,
    paper: PaperParams,
    newton: NewtonParams,
    budget_ns: u64,
    robot: Robot,
    joint_limits: bool,
    rate_limit_deg_s: f64,
    period_ns: u64,
    last_sent: [f64; MAX_JOINTS],
    has_last: bool,
    rejected: u64,
    safety: SafetyConfig,
    support: Option<Support>,
    safety_counts: SafetyCounts,
    fwd_path: Option<String>,
    inv_path: Option<String>,
    /// Generation of the models in use: 0 = those loaded at start, then one per swap.
    generation: u64,
    evaluator_choice: EvaluatorChoice,
    /// Window prefixes computed off the cycle ([`Self::start_prefix_worker`]).
    worker: Option<PrefixWorker>,
}

/// Models made ready off the cycle (loaded, checked, evaluators sized) for
/// [`Compensator::swap_models`]. After the swap it holds the models that were replaced, to be
/// dropped off the cycle too.
pub struct PreparedModels {
    pub generation: u64,
    pub fwd: Option<Evaluator>,
    pub inv: Option<Evaluator>,
}

impl std::fmt::Debug for PreparedModels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PreparedModels")
            .field("generation", &self.generation)
            .field("fwd", &self.fwd.is_some())
            .field("inv", &self.inv.is_some())
            .finish()
    }
}

impl std::fmt::Debug for Compensator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Compensator")
            .field("mode", &self.mode)
            .field("joints", &self.j)
            .field("fwd", &self.fwd_path)
            .field("inv", &self.inv_path)
            .finish()
    }
}

/// Hands the worker the newest forward (sent) and inverse (desired) history windows of the
/// models it handles; returns both windows.
/// The tip pose of joint angles `q_deg` (the first [`N_JOINTS`] entries), by the robot's
/// forward kinematics (eq. (3)).
fn tip_pose(robot: &Robot, q_deg: &[f64]) -> bowden_kinematics::Pose {
    let mut a = [0.0f64; N_JOINTS];
    a.copy_from_slice(&q_deg[..N_JOINTS]);
    robot.fk(&a).ee
}

/// Position (mm) and orientation (deg) distance of the tip at `q_deg` from `target`, as the
/// evaluation measures them; NaN becomes +∞ (never admissible).
fn tip_distance(robot: &Robot, target: &bowden_kinematics::Pose, q_deg: &[f64]) -> (f64, f64) {
    let (pos, rot) = bowden_kinematics::pose_distance(target, &tip_pose(robot, q_deg));
    let finite = |v: f64| if v.is_nan() { f64::INFINITY } else { v };
    (finite(pos), finite(rot))
}

fn post_histories<'h>(w: &mut PrefixWorker, h: &'h History, fwd_l: usize, inv_l: usize) -> (&'h [f64], &'h [f64]) {
    let fh = h.sent_tail(fwd_l - 1);
    let ih = h.desired_tail(inv_l - 1);
    if w.handles(FWD) {
        w.post(FWD, fh);
    }
    if w.handles(INV) {
        w.post(INV, ih);
    }
    (fh, ih)
}

fn load_model(
    cfg: &ControllerConfig,
    field: &'static str,
    p: &std::path::Path,
    dir: Direction,
    j: usize,
) -> Result<(Model, String), CompensatorError> {
    let path = cfg.resolve_model_path(field, p)?;
    let opts = cfg.load_check.options();
    let m = Model::load_with(&path, &opts)?;
    let name = path.display().to_string();
    if m.metadata().direction != dir {
        return Err(CompensatorError::Mismatch {
            path: name,
            what: format!(
                "`{field}` must be a {dir} model, the file's metadata says direction = {}",
                m.metadata().direction
            ),
        });
    }
    if m.joints() != j {
        return Err(CompensatorError::Mismatch {
            path: name,
            what: format!("the model has {} joints, the robot {j}", m.joints()),
        });
    }
    Ok((m, name))
}

impl Compensator {
    /// Builds the compensator: loads and checks the models the config names (none are needed
    /// for `uncalibrated`), sizes every buffer. After this, [`Self::step`] never allocates.
    pub fn from_config(cfg: &ControllerConfig, robot: &Robot) -> Result<Self, CompensatorError> {
        cfg.validate()?;
        let j = N_JOINTS;
        let fwd = match &cfg.model_fwd {
            Some(p) => Some(load_model(cfg, "model_fwd", p, Direction::Forward, j)?),
            None => None,
        };
        let inv = match &cfg.model_inv {
            Some(p) => Some(load_model(cfg, "model_inv", p, Direction::Inverse, j)?),
            None => None,
        };
        Self::from_models(cfg, robot, fwd.map(|(m, _)| m), inv.map(|(m, _)| m))
    }

    /// Builds the compensator from already loaded models (the config's model paths are
    /// ignored).
    pub fn from_models(
        cfg: &ControllerConfig,
        robot: &Robot,
        fwd: Option<Model>,
        inv: Option<Model>,
    ) -> Result<Self, CompensatorError> {
        cfg.validate()?;
        let j = N_JOINTS;
        for (m, dir) in [(&fwd, Direction::Forward), (&inv, Direction::Inverse)] {
            if let Some(m) = m {
                if m.metadata().direction != dir || m.joints() != j {
                    return Err(CompensatorError::Mismatch {
                        path: m.path().to_string(),
                        what: format!(
                            "expected a {dir} model with {j} joints, found a {} model with {}",
                            m.metadata().direction,
                            m.joints()
                        ),
                    });
                }
            }
        }
        let evaluator = |m: &Model| match cfg.evaluator {
            EvaluatorChoice::Auto => m.evaluator(),
            EvaluatorChoice::Tract => Evaluator::Tract(Box::new(m.tract_evaluator())),
        };
        let fwd_l = fwd.as_ref().map(|m| m.seq_len()).unwrap_or(1);
        let inv_l = inv.as_ref().map(|m| m.seq_len()).unwrap_or(1);
        let rows = fwd_l.max(inv_l) - 1;
        let support = fwd.as_ref().and_then(|m| m.support().copied());
        let mut c = Self {
            mode: Mode::Uncalibrated,
            j,
            fwd_path: fwd.as_ref().map(|m| m.path().to_string()),
            inv_path: inv.as_ref().map(|m| m.path().to_string()),
            fwd: fwd.as_ref().map(evaluator),
            inv: inv.as_ref().map(evaluator),
            fwd_l,
            inv_l,
            fwd_prefix: Prefix::Full,
            inv_prefix: Prefix::Full,
            history: History::new(cfg.history_rule(), j, rows),
            paper: cfg.paper,
            newton: cfg.newton,
            budget_ns: cfg.budget.budget_ns,
            robot: robot.clone(),
            joint_limits: cfg.output.joint_limits,
            rate_limit_deg_s: cfg.output.rate_limit_deg_s,
            period_ns: cfg.output.period_ns,
            last_sent: [0.0; MAX_JOINTS],
            has_last: false,
            rejected: 0,
            safety: cfg.safety.clone(),
            support,
            safety_counts: SafetyCounts::default(),
            generation: 0,
            evaluator_choice: cfg.evaluator,
            worker: None,
        };
        c.set_mode(cfg.mode)?;
        Ok(c)
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Switches mode; refuses a mode whose models are not loaded.
    pub fn set_mode(&mut self, mode: Mode) -> Result<(), CompensatorError> {
        let (need_fwd, need_inv) = mode.needs_models(self.newton.init_from_inverse);
        if need_fwd && self.fwd.is_none() {
            return Err(CompensatorError::MissingModel {
                mode,
                which: "a forward",
                field: "model_fwd",
            });
        }
        if need_inv && self.inv.is_none() {
            return Err(CompensatorError::MissingModel {
                mode,
                which: "an inverse",
                field: "model_inv",
            });
        }
        self.mode = mode;
        Ok(())
    }

    pub fn joints(&self) -> usize {
        self.j
    }
    /// Targets rejected so far (wrong length, NaN/inf).
    pub fn rejected_inputs(&self) -> u64 {
        self.rejected
    }
    /// Whether each loaded model runs on the incremental evaluator.
    pub fn incremental(&self) -> (Option<bool>, Option<bool>) {
        (
            self.fwd.as_ref().map(|e| e.is_incremental()),
            self.inv.as_ref().map(|e| e.is_incremental()),
        )
    }
    /// Overrides the time budget (0 = none, for lockstep).
    pub fn set_budget_ns(&mut self, budget_ns: u64) {
        self.budget_ns = budget_ns;
    }
    /// Overrides the control period the rate limit assumes.
    pub fn set_period_ns(&mut self, period_ns: u64) {
        self.period_ns = period_ns;
    }
    pub fn history(&self) -> &History {
        &self.history
    }
    /// The training data's support the safe refinement uses (the forward model's metadata);
    /// `None` when the model file records none (then only the joint limits bound candidates).
    pub fn support(&self) -> Option<&Support> {
        self.support.as_ref()
    }
    pub fn safety(&self) -> &SafetyConfig {
        &self.safety
    }
    pub fn safety_counts(&self) -> SafetyCounts {
        self.safety_counts
    }

    /// One line on what the never-worse choice sent since the start (None when it is off): a
    /// high share of the target sent unchanged says the models do not fit this robot.
    pub fn safety_summary(&self) -> Option<String> {
        if !self.safety.never_worse {
            return None;
        }
        let c = self.safety_counts;
        Some(format!(
            "safe refinement{}: sent the refinement's result {}, its start {}, the target unchanged {}; \
             a bound moved a candidate in {} of {} steps",
            if self.safety.never_worse_tip {
                " (tip rating)"
            } else {
                ""
            },
            c.steps - c.start_chosen - c.desired_chosen,
            c.start_chosen,
            c.desired_chosen,
            c.limited,
            c.steps
        ))
    }

    /// The per-joint interval every candidate of this step must lie in: the training data's
    /// command range, a step from the forward model's newest history entry no larger than
    /// the data's largest, and the drift guard around `q_des` (docs/architecture.md, "Safe
    /// refinement"). Where the bounds do not meet (a target outside what the data covers),
    /// the joint is pinned to the target: the model knows nothing there.
    fn admissible(&self, q_des: &[f64], lo: &mut [f64], hi: &mut [f64]) {
        let j = self.j;
        for k in 0..j {
            lo[k] = f64::NEG_INFINITY;
            hi[k] = f64::INFINITY;
        }
        let Some(sup) = &self.support else {
            return;
        };
        let sf = &self.safety;
        if sf.support {
            let s = sf.support_scale;
            let newest = (self.fwd_l > 1).then(|| {
                let tail = self.history.sent_tail(self.fwd_l - 1);
                &tail[tail.len() - j..]
            });
            for k in 0..j {
                let c = 0.5 * (sup.cmd_min_deg[k] + sup.cmd_max_deg[k]);
                let h = 0.5 * (sup.cmd_max_deg[k] - sup.cmd_min_deg[k]) * s;
                lo[k] = lo[k].max(c - h);
                hi[k] = hi[k].min(c + h);
                if let Some(prev) = newest.filter(|_| sf.step_scale > 0.0) {
                    let d = sup.cmd_step_max_deg[k] * sf.step_scale;
                    lo[k] = lo[k].max(prev[k] - d);
                    hi[k] = hi[k].min(prev[k] + d);
                }
            }
        }
        if sf.correction_scale > 0.0 {
            for k in 0..j {
                let g = sup.gap_max_deg[k] * sf.correction_scale;
                lo[k] = lo[k].max(q_des[k] - g);
                hi[k] = hi[k].min(q_des[k] + g);
            }
        }
        for k in 0..j {
            if lo[k] > hi[k] {
                lo[k] = q_des[k];
                hi[k] = q_des[k];
            }
        }
    }

    /// Generation of the models in use (0 = those loaded at start; each swap sets its own).
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Sequence lengths (forward, inverse) a swapped-in model must have: the histories are
    /// sized for them. 0 where the direction is not loaded.
    pub fn seq_lens(&self) -> (usize, usize) {
        (
            self.fwd.as_ref().map_or(0, |_| self.fwd_l),
            self.inv.as_ref().map_or(0, |_| self.inv_l),
        )
    }

    /// How an accepted model is to be evaluated (the config's `evaluator`).
    pub fn evaluator_for(&self, m: &Model) -> Evaluator {
        match self.evaluator_choice {
            EvaluatorChoice::Auto => m.evaluator(),
            EvaluatorChoice::Tract => Evaluator::Tract(Box::new(m.tract_evaluator())),
        }
    }

    /// Exchanges the models in use with `next`'s at a cycle boundary: the evaluators move by
    /// value (no allocation, no deallocation: `next` then holds the replaced ones, for the
    /// caller to drop off the cycle). A direction `next` leaves `None` stays as it is. The
    /// histories carry over; the swapped models' window prefixes are recomputed by the next
    /// step (or [`Self::prepare`]). Refused, and nothing changed, when a model's sequence length
    /// or joints differ from those the histories were sized for, or a direction is not loaded.
    pub fn swap_models(&mut self, next: &mut PreparedModels) -> Result<(), CompensatorError> {
        let check = |e: &Option<Evaluator>, cur: &Option<Evaluator>, l: usize, dir: &str| {
            let Some(e) = e else { return Ok(()) };
            if cur.is_none() {
                return Err(format!("no {dir} model is loaded to be replaced"));
            }
            if e.seq_len() != l || e.joints() != self.j {
                return Err(format!(
                    "the new {dir} model has L = {} and {} joints, the running one L = {l} and {}",
                    e.seq_len(),
                    e.joints(),
                    self.j
                ));
            }
            Ok(())
        };
        check(&next.fwd, &self.fwd, self.fwd_l, "forward")
            .and_then(|_| check(&next.inv, &self.inv, self.inv_l, "inverse"))
            .map_err(|what| CompensatorError::Mismatch {
                path: format!("model generation {}", next.generation),
                what,
            })?;
        if next.fwd.is_some() {
            std::mem::swap(&mut self.fwd, &mut next.fwd);
            self.fwd_prefix = Prefix::Full;
            self.worker_swapped(FWD);
        }
        if next.inv.is_some() {
            std::mem::swap(&mut self.inv, &mut next.inv);
            self.inv_prefix = Prefix::Full;
            self.worker_swapped(INV);
        }
        std::mem::swap(&mut self.generation, &mut next.generation);
        Ok(())
    }

    /// Tells the prefix worker that model `m` was swapped: it rebuilds its evaluators of the
    /// new model off the cycle. A swapped-in model without an incremental evaluator leaves
    /// the worker and gets its prefixes in the step, as without a worker.
    fn worker_swapped(&mut self, m: usize) {
        let Some(w) = self.worker.as_mut() else { return };
        let e = if m == FWD { &self.fwd } else { &self.inv };
        match e {
            Some(Evaluator::Incremental(n)) => w.swapped(m, n.net_arc()),
            _ => w.release(m),
        }
    }

    /// Moves the window-prefix computation of every model with an incremental evaluator to a
    /// worker thread ([`crate::prefix`]): after a history step the cycle only posts the new
    /// history, and a later step adopts the finished prefix by exchanging two evaluators.
    /// `Wait` keeps the commands bit-identical to computing the prefix in the step (lockstep);
    /// `Newest` never blocks and may run a few steps on the previous window
    /// ([`StepOutput::prefix_lag`]). Allocates two more evaluators per model and the thread:
    /// call it at start-up, not on the cycle. Returns false (and starts nothing) when no model
    /// has an incremental evaluator. Replaces a worker started before.
    pub fn start_prefix_worker(&mut self, opts: PrefixWorkerOptions) -> std::io::Result<bool> {
        self.worker = None;
        // The active evaluators start from a complete prefix of the current history.
        self.sync_prefixes_in_step();
        let j = self.j;
        fn model(e: &Option<Evaluator>, l: usize, j: usize) -> Option<(&IncrementalNet, usize)> {
            match e {
                Some(Evaluator::Incremental(n)) => Some((&**n, (l - 1) * j)),
                _ => None,
            }
        }
        let models = [model(&self.fwd, self.fwd_l, j), model(&self.inv, self.inv_l, j)];
        if models.iter().all(|m| m.is_none()) {
            return Ok(false);
        }
        self.worker = Some(PrefixWorker::spawn(models, self.history.appended_total(), opts)?);
        Ok(true)
    }

    /// Stops the prefix worker (prefixes are computed in the step again, or in
    /// [`Self::prepare`]).
    pub fn stop_prefix_worker(&mut self) {
        if self.worker.take().is_some() {
            // The active evaluators may lag: recompute in full at the next step.
            self.fwd_prefix = Prefix::Full;
            self.inv_prefix = Prefix::Full;
        }
    }

    /// The prefix worker's mode, if one runs.
    pub fn prefix_worker(&self) -> Option<PrefixSync> {
        self.worker.as_ref().map(|w| w.sync_mode())
    }

    /// Blocks until the prefix worker finished the prefixes of the current history and
    /// adopts them, so the next step runs on them (tests and checks; never on the cycle).
    /// Without a worker, computes them now, like [`Self::prepare`].
    pub fn wait_prefixes(&mut self) {
        if let Some(w) = self.worker.as_mut() {
            if let Some(Evaluator::Incremental(n)) = self.fwd.as_mut() {
                w.wait_idle(FWD, n, self.history.sent_tail(self.fwd_l - 1));
            }
            if let Some(Evaluator::Incremental(n)) = self.inv.as_mut() {
                w.wait_idle(INV, n, self.history.desired_tail(self.inv_l - 1));
            }
        }
        self.sync_prefixes_in_step();
    }

    /// Forgets the histories (back to zero padding) and the last command.
    pub fn reset(&mut self) {
        self.history.reset();
        self.fwd_prefix = Prefix::Full;
        self.inv_prefix = Prefix::Full;
        if let Some(w) = self.worker.as_mut() {
            // The zero-padding prefix now (reset is not a cycle), in a new epoch whose keys
            // no result of the old history matches. Allocation-free.
            if w.handles(FWD) {
                if let Some(Evaluator::Incremental(n)) = self.fwd.as_mut() {
                    n.set_history(self.history.sent_tail(self.fwd_l - 1));
                }
            }
            if w.handles(INV) {
                if let Some(Evaluator::Incremental(n)) = self.inv.as_mut() {
                    n.set_history(self.history.desired_tail(self.inv_l - 1));
                }
            }
            w.restarted(self.history.appended_total());
        }
        self.has_last = false;
        self.last_sent = [0.0; MAX_JOINTS];
        self.safety_counts = SafetyCounts::default();
    }

    /// Does now the window-prefix work the next [`Self::step`] would otherwise start with
    /// (after a history entry was appended). A runtime can call it right after publishing
    /// the command, which takes that work off the target → command path; calling it is
    /// optional and never changes results. Allocation-free.
    ///
    /// With a prefix worker it hands the new history to the worker instead (a copy, and in
    /// `Newest` mode a `try_lock` that is retried at the next step if it fails), so the worker
    /// starts right after the command went out.
    pub fn prepare(&mut self) {
        if let Some(w) = self.worker.as_mut() {
            let (fh, ih) = post_histories(w, &self.history, self.fwd_l, self.inv_l);
            // A swapped-in model has no prefix yet, and the worker first builds its own
            // evaluators of it: compute it here, after the command went out, rather than at
            // the start of the next step.
            if let (true, Some(Evaluator::Incremental(n))) = (w.unusable(FWD), self.fwd.as_mut()) {
                w.sync(FWD, n, fh);
            }
            if let (true, Some(Evaluator::Incremental(n))) = (w.unusable(INV), self.inv.as_mut()) {
                w.sync(INV, n, ih);
            }
        }
        self.sync_prefixes_in_step();
    }

    /// True when the next step will first recompute (part of) a model's window prefix in the
    /// step (models handed to a prefix worker never are, after start-up).
    pub fn prefix_pending(&self) -> bool {
        let handled = |m| self.worker.as_ref().is_some_and(|w| w.handles(m));
        (self.fwd.is_some() && !handled(FWD) && self.fwd_prefix != Prefix::Valid)
            || (self.inv.is_some() && !handled(INV) && self.inv_prefix != Prefix::Valid)
    }

    /// Brings every model's prefix up to date for a step: through the worker where one
    /// handles the model, in place otherwise. Returns the prefix lag (see
    /// [`StepOutput::prefix_lag`]).
    fn sync_prefixes(&mut self) -> u32 {
        let mut lag = 0;
        if let Some(w) = self.worker.as_mut() {
            // Both requests go out before either result is waited for.
            let (fh, ih) = post_histories(w, &self.history, self.fwd_l, self.inv_l);
            if let (true, Some(Evaluator::Incremental(n))) = (w.handles(FWD), self.fwd.as_mut()) {
                lag = lag.max(w.sync(FWD, n, fh));
            }
            if let (true, Some(Evaluator::Incremental(n))) = (w.handles(INV), self.inv.as_mut()) {
                lag = lag.max(w.sync(INV, n, ih));
            }
        }
        self.sync_prefixes_in_step();
        lag
    }

    /// The prefixes of the models no worker handles, in place.
    fn sync_prefixes_in_step(&mut self) {
        let handled = |m| self.worker.as_ref().is_some_and(|w| w.handles(m));
        let (hf, hi) = (handled(FWD), handled(INV));
        if let (false, Some(f)) = (hf, &mut self.fwd) {
            let h = self.history.sent_tail(self.fwd_l - 1);
            match self.fwd_prefix {
                Prefix::Valid => {}
                Prefix::Shift => f.shift_history(h),
                Prefix::Full => f.set_history(h),
            }
            self.fwd_prefix = Prefix::Valid;
        }
        if let (false, Some(i)) = (hi, &mut self.inv) {
            let h = self.history.desired_tail(self.inv_l - 1);
            match self.inv_prefix {
                Prefix::Valid => {}
                Prefix::Shift => i.shift_history(h),
                Prefix::Full => i.set_history(h),
            }
            self.inv_prefix = Prefix::Valid;
        }
    }

    /// One compensation step. Allocation-free; its time is bounded by M (or the Newton
    /// evaluation cap) and the time budget. On a rejected target (`Err`), `out` holds the
    /// last command (or the target is not used at all) with `stop_reason = RejectedInput`,
    /// the histories are untouched, and the rejection is counted.
    pub fn step(&mut self, q_desired_deg: &[f64], out: &mut StepOutput) -> Result<(), StepError> {
        self.step_inner(q_desired_deg, None, out)
    }

    /// [`Self::step`] with `correction_deg` (one entry per joint, degrees) added to the
    /// feed-forward command before the output stage (rate limit, joint limits): the vision
    /// feedback's `apply = "command"`. The histories record the command actually sent, the
    /// correction included, as the forward model must see what the robot received; the
    /// prediction is at that command. A non-finite entry counts as 0. Allocation-free.
    pub fn step_with_correction(
        &mut self,
        q_desired_deg: &[f64],
        correction_deg: &[f64],
        out: &mut StepOutput,
    ) -> Result<(), StepError> {
        self.step_inner(q_desired_deg, Some(correction_deg), out)
    }

    // Long: the real-time step in the order it runs (checks, history, refinement, safe choice, output limits, prediction), allocation-free; its bytes are `bowden evaluate`'s, and a split would scatter that order across calls on the hot path.
    fn step_inner(
        &mut self,
        q_desired_deg: &[f64],
        correction: Option<&[f64]>,
        out: &mut StepOutput,
    ) -> Result<(), StepError> {
        let t0 = Instant::now();
        let j = self.j;
        out.joints = j;
        out.mode = self.mode;
        if let Err(e) = self.validate(q_desired_deg) {
            self.rejected += 1;
            out.q_cmd_deg = self.last_sent;
            out.q_refined_deg = self.last_sent;
            out.has_prediction = false;
            out.q_predicted_deg = [0.0; MAX_JOINTS];
            out.loss_max_abs_deg = f64::NAN;
            out.iterations = 0;
            out.forward_evals = 0;
            out.stop_reason = StopReason::RejectedInput;
            out.rate_limited = false;
            out.joint_limited = false;
            out.history_appended = 0;
            out.chosen = Chosen::Refined;
            out.safety_limited = false;
            out.correction_deg = [0.0; MAX_JOINTS];
            out.upper_mask = 0;
            out.lower_mask = 0;
            out.joint_limit_lowered_mask = 0;
            out.joint_limit_raised_mask = 0;
            out.prefix_lag = 0;
            out.elapsed_ns = t0.elapsed().as_nanos() as u64;
            return Err(e);
        }
        let q_des = &q_desired_deg[..j];
        out.q_desired_deg = [0.0; MAX_JOINTS];
        out.q_desired_deg[..j].copy_from_slice(q_des);
        out.prefix_lag = self.sync_prefixes();

        let budget = (self.budget_ns > 0).then_some((t0, self.budget_ns));
        let mut out_of_time = move || budget.is_some_and(|(s, b)| s.elapsed().as_nanos() as u64 >= b);
        let mut q = [0.0f64; MAX_JOINTS];
        let mut pred = [0.0f64; MAX_JOINTS];
        let mut res = RefineResult::default();
        // The admissible set of this step's candidates (all ±∞ without support or safety).
        let mut lo = [0.0f64; MAX_JOINTS];
        let mut hi = [0.0f64; MAX_JOINTS];
        self.admissible(q_des, &mut lo[..j], &mut hi[..j]);
        let mut limited = false;
        let robot = &self.robot;
        let limits = self.joint_limits;
        let mut project = |qv: &mut [f64]| {
            for k in 0..qv.len() {
                let v = qv[k].clamp(lo[k], hi[k]);
                limited |= v != qv[k];
                qv[k] = v;
            }
            if limits {
                let mut a = [0.0f64; N_JOINTS];
                a.copy_from_slice(&qv[..N_JOINTS]);
                qv[..N_JOINTS].copy_from_slice(&robot.clamp_command_to_limits(&a));
            }
        };
        let mut start = [0.0f64; MAX_JOINTS];
        match self.mode {
            Mode::Uncalibrated => q[..j].copy_from_slice(q_des),
            Mode::Paper => {
                // Algorithm 1, line 1: inverse model on the desired history + q_desired(t).
                let inv = self.inv.as_mut().expect("set_mode checked");
                inv.eval(q_des, &mut q[..j]);
                if q[..j].iter().any(|v| !v.is_finite()) {
                    q[..j].copy_from_slice(q_des);
                }
                project(&mut q[..j]);
                start = q;
                let fwd = self.fwd.as_mut().expect("set_mode checked");
                res = paper_refine(
                    fwd,
                    q_des,
                    &mut q[..j],
                    &self.paper,
                    &mut pred[..j],
                    &mut project,
                    &mut out_of_time,
                    &mut |_, _, _| {},
                );
            }
            Mode::Newton => {
                match (&mut self.inv, self.newton.init_from_inverse) {
                    (Some(inv), true) => {
                        inv.eval(q_des, &mut q[..j]);
                        if q[..j].iter().any(|v| !v.is_finite()) {
                            q[..j].copy_from_slice(q_des);
                        }
                    }
                    _ => q[..j].copy_from_slice(q_des),
                }
                project(&mut q[..j]);
                start = q;
                let fwd = self.fwd.as_mut().expect("set_mode checked");
                res = newton_refine(
                    fwd,
                    q_des,
                    &mut q[..j],
                    &self.newton,
                    &mut pred[..j],
                    &mut project,
                    &mut out_of_time,
                );
            }
        }
        // Never worse, by the model's own rating: the result must beat where the refinement
        // started, and sending the target unchanged. With `never_worse_tip`, a candidate must
        // also not move the predicted tip further from the target's pose than sending the target
        // unchanged would, in position and in orientation apart: the joint rating is a sum, and
        // a poor model can trade one joint for another in a way the tip pays for.
        let mut chosen = Chosen::Refined;
        if self.safety.never_worse && self.mode != Mode::Uncalibrated {
            if let Some(fwd) = &mut self.fwd {
                let cost = |p: &[f64]| -> f64 {
                    let c: f64 = (0..j).map(|k| (p[k] - q_des[k]) * (p[k] - q_des[k])).sum();
                    if c.is_nan() {
                        f64::INFINITY
                    } else {
                        c
                    }
                };
                if !res.pred_at_q {
                    fwd.eval(&q[..j], &mut pred[..j]);
                    res.evals += 1;
                    res.pred_at_q = true;
                }
                // The target as the output stage would send it, and the model's rating of it.
                let mut d = [0.0f64; MAX_JOINTS];
                d[..j].copy_from_slice(q_des);
                if self.joint_limits {
                    let mut a = [0.0f64; N_JOINTS];
                    a.copy_from_slice(&d[..N_JOINTS]);
                    d[..N_JOINTS].copy_from_slice(&self.robot.clamp_command_to_limits(&a));
                }
                let tip = self.safety.never_worse_tip && j == N_JOINTS;
                // The model's rating of the target sent unchanged: needed first with the tip
                // rating (it is the reference), otherwise only if it differs from the pick.
                let mut p_d = None;
                let tip_ref = if tip {
                    let mut p = pred;
                    if d[..j] != q[..j] {
                        fwd.eval(&d[..j], &mut p[..j]);
                        res.evals += 1;
                    }
                    p_d = Some(p);
                    let target = tip_pose(&self.robot, q_des);
                    let dist = tip_distance(&self.robot, &target, &p[..j]);
                    Some((target, dist))
                } else {
                    None
                };
                // Admissible: not rated further from the target's tip pose than the target sent
                // unchanged (always, without the tip rating).
                let robot = &self.robot;
                let admissible = |p: &[f64]| match &tip_ref {
                    None => true,
                    Some((target, (pos_d, rot_d))) => {
                        let (pos, rot) = tip_distance(robot, target, p);
                        pos <= *pos_d && rot <= *rot_d
                    }
                };
                let mut best = if admissible(&pred[..j]) {
                    cost(&pred[..j])
                } else {
                    f64::INFINITY
                };
                if q[..j] != start[..j] {
                    let mut p = [0.0f64; MAX_JOINTS];
                    fwd.eval(&start[..j], &mut p[..j]);
                    res.evals += 1;
                    let c = cost(&p[..j]);
                    if c < best && admissible(&p[..j]) {
                        best = c;
                        q = start;
                        pred = p;
                        chosen = Chosen::Start;
                    }
                }
                if d[..j] != q[..j] {
                    let p = match p_d {
                        Some(p) => p,
                        None => {
                            let mut p = [0.0f64; MAX_JOINTS];
                            fwd.eval(&d[..j], &mut p[..j]);
                            res.evals += 1;
                            p
                        }
                    };
                    // With the tip rating the target unchanged is the reference, so it is what
                    // is sent when nothing else is admissible.
                    if cost(&p[..j]) < best || (tip && best == f64::INFINITY) {
                        q = d;
                        pred = p;
                        chosen = Chosen::Desired;
                    }
                }
            }
        }
        self.safety_counts.steps += 1;
        self.safety_counts.limited += limited as u64;
        match chosen {
            Chosen::Refined => {}
            Chosen::Start => self.safety_counts.start_chosen += 1,
            Chosen::Desired => self.safety_counts.desired_chosen += 1,
        }
        out.chosen = chosen;
        out.safety_limited = limited;
        out.q_refined_deg = q;

        // Where the result sits at the training data's command range (not where a pin to an
        // uncovered target put it): the feedback's anti-windup.
        let (mut upper, mut lower) = (0u32, 0u32);
        if let (Some(sup), true, false) = (&self.support, self.safety.support, self.mode == Mode::Uncalibrated) {
            let s = self.safety.support_scale;
            for k in 0..j {
                let pinned = lo[k] == hi[k] && lo[k] == q_des[k];
                let c = 0.5 * (sup.cmd_min_deg[k] + sup.cmd_max_deg[k]);
                let h = 0.5 * (sup.cmd_max_deg[k] - sup.cmd_min_deg[k]) * s;
                if !pinned && q[k] >= c + h - 1e-9 {
                    upper |= 1 << k;
                }
                if !pinned && q[k] <= c - h + 1e-9 {
                    lower |= 1 << k;
                }
            }
        }

        // Output stage: the feedback's correction (when given), the rate limit against the
        // last command sent, then the joint limits.
        let mut cmd = q;
        out.correction_deg = [0.0; MAX_JOINTS];
        if let Some(corr) = correction {
            for k in 0..j.min(corr.len()) {
                let v = if corr[k].is_finite() { corr[k] } else { 0.0 };
                cmd[k] += v;
                out.correction_deg[k] = v;
            }
        }
        out.rate_limited = false;
        if self.rate_limit_deg_s > 0.0 && self.has_last {
            let max_d = self.rate_limit_deg_s * self.period_ns as f64 * 1e-9;
            for c in 0..j {
                let lo = self.last_sent[c] - max_d;
                let hi = self.last_sent[c] + max_d;
                let v = cmd[c].clamp(lo, hi);
                if v != cmd[c] {
                    out.rate_limited = true;
                }
                cmd[c] = v;
            }
        }
        out.joint_limited = false;
        out.joint_limit_lowered_mask = 0;
        out.joint_limit_raised_mask = 0;
        if self.joint_limits {
            let mut a = [0.0f64; N_JOINTS];
            a.copy_from_slice(&cmd[..N_JOINTS]);
            let clamped = self.robot.clamp_command_to_limits(&a);
            if clamped != a {
                out.joint_limited = true;
            }
            for k in 0..N_JOINTS {
                if clamped[k] < a[k] {
                    upper |= 1 << k;
                    out.joint_limit_lowered_mask |= 1 << k;
                } else if clamped[k] > a[k] {
                    lower |= 1 << k;
                    out.joint_limit_raised_mask |= 1 << k;
                }
            }
            cmd[..N_JOINTS].copy_from_slice(&clamped);
        }
        out.upper_mask = upper;
        out.lower_mask = lower;

        // The forward model's expectation for what is actually sent.
        let mut evals = res.evals;
        out.has_prediction = false;
        out.q_predicted_deg = [0.0; MAX_JOINTS];
        out.loss_max_abs_deg = f64::NAN;
        if let Some(fwd) = &mut self.fwd {
            if !(res.pred_at_q && cmd[..j] == q[..j]) {
                fwd.eval(&cmd[..j], &mut pred[..j]);
                evals += 1;
            }
            out.q_predicted_deg[..j].copy_from_slice(&pred[..j]);
            out.has_prediction = pred[..j].iter().all(|v| v.is_finite());
            out.loss_max_abs_deg = (0..j).map(|c| (pred[c] - q_des[c]).abs()).fold(0.0, f64::max);
        }

        let appended = self.history.record(q_des, &cmd[..j]);
        let mark = |p: &mut Prefix| {
            *p = match (appended, *p) {
                (0, p) => p,
                (1, Prefix::Valid) => Prefix::Shift,
                _ => Prefix::Full,
            }
        };
        mark(&mut self.fwd_prefix);
        mark(&mut self.inv_prefix);
        if let (Some(w), true) = (self.worker.as_mut(), appended > 0) {
            w.advanced(self.history.appended_total());
        }
        self.last_sent = cmd;
        self.has_last = true;

        out.q_cmd_deg = cmd;
        out.iterations = res.iterations;
        out.forward_evals = evals;
        out.stop_reason = res.stop;
        out.history_appended = appended as u32;
        out.elapsed_ns = t0.elapsed().as_nanos() as u64;
        Ok(())
    }

    fn validate(&self, q: &[f64]) -> Result<(), StepError> {
        if q.len() != self.j {
            return Err(StepError::WrongLength {
                expected: self.j,
                found: q.len(),
            });
        }
        if let Some((c, &v)) = q.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(StepError::NotFinite { joint: c + 1, value: v });
        }
        Ok(())
    }
}
