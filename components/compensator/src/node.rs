//! Compensator node: `JointTarget` → `bowden_compensator::Compensator::step` → `JointCommand`.
//!
//! With `[feedback] enabled = true` in the controller config (and a calibrated mode, or
//! `in_uncalibrated`), the node also reads the estimator's `JointEstimate` stream as a passive
//! input (neither waited for nor woken by, like the estimator's IK hint): every estimate that
//! arrived up to this cycle is checked by `bowden_compensator::Feedback`, which keeps the
//! desired angles of recent ticks to compare each frame with what was wanted when it was taken,
//! and the resulting correction shapes the target or is added to the command
//! (docs/architecture.md, "Vision feedback"). In lockstep the estimate of tick k is read at
//! tick k + 1 (the estimator runs after the compensator within a tick), deterministically.

use crate::{
    ApplyTo, Compensator, ControllerConfig, Dither, Feedback, Loaded, LoaderSettings, Mode, ModelLoader, PrefixSync,
    PrefixWorkerOptions, StepOutput,
};
use bowden_interfaces::{services, JointCommand, JointEstimate, JointTarget, ModelUpdate, MAX_JOINTS};
use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
use bowden_runtime::ports::{Input, Output};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use serde::Deserialize;
use std::path::PathBuf;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Controller config (configs/controller.toml layout); the shipped one when absent.
    #[serde(default)]
    config: Option<PathBuf>,
    /// Overrides the config's mode: uncalibrated | paper | newton.
    #[serde(default)]
    mode: Option<String>,
    /// Compute the window prefixes on a worker thread, off the cycle. Real time: default
    /// true, the step never waits for it (it runs on the newest complete prefix). Lockstep:
    /// default false; true waits for the worker, with commands bit-identical to the prefixes
    /// computed in the step (a check of the real-time path's arithmetic).
    #[serde(default)]
    prefix_worker: Option<bool>,
}

/// The vision-feedback path of the node.
struct FeedbackPath {
    fb: Feedback,
    estimates: Input<JointEstimate>,
    apply: ApplyTo,
}

/// The hot-swap path of the node: present when the pipeline has a stage announcing
/// `ModelUpdate`s (an `adapt` node).
struct SwapPath {
    updates: Input<ModelUpdate>,
    loader: ModelLoader,
    /// Updates handed to the loader and not answered yet.
    pending: u32,
    swapped: u64,
    refused: u64,
}

/// Lockstep waits this long for the loader's answer before counting a fault.
const LOCKSTEP_LOAD_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(120);

struct CompensatorStage {
    comp: Compensator,
    swap: Option<SwapPath>,
    /// `[dither]`: an offset added to the command, for online adaptation's data.
    dither: Option<Dither>,
    input: Input<JointTarget>,
    out: Output<JointCommand>,
    step_out: StepOutput,
    bad_size: u64,
    /// Commands the robot's joint limits or jaw rule changed, and per joint how often they
    /// lowered / raised it: never silent (the summary says how many, issue #42).
    limited_commands: u64,
    limit_lowered: [u64; MAX_JOINTS],
    limit_raised: [u64; MAX_JOINTS],
    feedback: Option<FeedbackPath>,
    /// `[feedback]` is enabled but not applied in this mode (uncalibrated).
    feedback_idle: bool,
}

/// The `compensator` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "compensator",
    summary: "targets → calibrated joint commands (Algorithm 1; optional vision feedback and model hot swap)",
    inputs: &[
        InputDecl::new(services::JOINT_TARGET, Read::Tick, 4),
        InputDecl::new(services::JOINT_ESTIMATE, Read::Feedback, 8),
        InputDecl::new(services::MODEL_UPDATE, Read::Feedback, 8),
    ],
    outputs: &[services::JOINT_COMMAND],
    schedule: Schedule {
        deadline_us: Some(500),
        ..Schedule::EVENT
    },
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    let robot = bowden_kinematics::Robot::load_or_paper(env.robot_file().as_deref()).map_err(|e| env.error(e))?;
    let mut cfg = match &p.config {
        Some(path) => ControllerConfig::load(env.resolve(path)).map_err(|e| env.error(e))?,
        None => ControllerConfig::shipped(),
    };
    if let Some(m) = &p.mode {
        // Set before loading so a mode without models needs no model file.
        cfg.mode = Mode::parse(m)
            .ok_or_else(|| env.error(format!("params.mode `{m}`: expected uncalibrated, paper or newton")))?;
    }
    // Load only the models the mode uses: `uncalibrated` runs without any model file.
    let (needs_fwd, needs_inv) = cfg.mode.needs_models(cfg.newton.init_from_inverse);
    if !needs_fwd {
        cfg.model_fwd = None;
    }
    if !needs_inv {
        cfg.model_inv = None;
    }
    let mut comp = Compensator::from_config(&cfg, &robot).map_err(|e| env.error(e))?;
    comp.set_period_ns(env.pipeline.period_ns());
    if env.reproducible() {
        // A time budget would make results depend on the machine's speed.
        comp.set_budget_ns(0);
    }
    if cfg.mode != Mode::Uncalibrated && p.prefix_worker.unwrap_or(!env.reproducible()) {
        // The worker inherits this thread's placement (the process's real-time settings are
        // applied after the stages are built): it moves to the CPUs the process is not pinned
        // to, where it cannot delay the cycle, and stays under SCHED_OTHER.
        let pinned: Vec<usize> = env
            .pipeline
            .processes
            .iter()
            .find(|pr| pr.stages.iter().any(|&i| env.pipeline.stages[i].name == env.spec.name))
            .and_then(|pr| pr.rt.as_ref())
            .map(|rt| rt.cpus.clone())
            .unwrap_or_default();
        let n_cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let others: Vec<usize> = (0..n_cpus).filter(|c| !pinned.contains(c)).collect();
        let on_start: Option<Box<dyn FnOnce() + Send>> = (!pinned.is_empty() && !others.is_empty()).then(|| {
            Box::new(move || {
                let _ = bowden_runtime::rt::pin_to_cpus(&others);
            }) as Box<dyn FnOnce() + Send>
        });
        comp.start_prefix_worker(PrefixWorkerOptions {
            sync: if env.reproducible() {
                PrefixSync::Wait
            } else {
                PrefixSync::Newest
            },
            name: format!("{}-prefix", env.spec.name),
            on_start,
        })
        .map_err(|e| env.error(format!("prefix worker thread: {e}")))?;
    }
    let fb_cfg = &cfg.feedback;
    let applied = fb_cfg.enabled && (cfg.mode != Mode::Uncalibrated || fb_cfg.in_uncalibrated);
    let feedback = if applied {
        Some(FeedbackPath {
            fb: Feedback::new(fb_cfg, comp.joints(), env.pipeline.period_ns()),
            estimates: env.input(services::JOINT_ESTIMATE)?,
            apply: fb_cfg.apply,
        })
    } else {
        None
    };
    let announced = env.produced(services::MODEL_UPDATE);
    let swap = if announced && cfg.mode != Mode::Uncalibrated {
        let settings = LoaderSettings::for_compensator(&comp, &cfg, &env.spec.name, true);
        Some(SwapPath {
            updates: env.input(services::MODEL_UPDATE)?,
            loader: ModelLoader::spawn(settings).map_err(|e| env.error(format!("model loader thread: {e}")))?,
            pending: 0,
            swapped: 0,
            refused: 0,
        })
    } else {
        None
    };
    let dither = (cfg.dither.enabled && cfg.mode != Mode::Uncalibrated)
        .then(|| Dither::new(&cfg.dither, &robot, cfg.history.step_deg));
    Ok(Box::new(CompensatorStage {
        comp,
        swap,
        dither,
        input: env.input(services::JOINT_TARGET)?,
        out: env.output(services::JOINT_COMMAND)?,
        step_out: StepOutput::default(),
        bad_size: 0,
        limited_commands: 0,
        limit_lowered: [0; MAX_JOINTS],
        limit_raised: [0; MAX_JOINTS],
        feedback,
        feedback_idle: fb_cfg.enabled && !applied,
    }))
}

impl CompensatorStage {
    /// At the cycle boundary (after the command went out): hands new announcements to the
    /// loader and swaps in whatever it has ready. Real time: never waits. Lockstep: waits for
    /// the loader's answer, so the swap happens at the tick after the announcement whatever
    /// the machine's speed. Allocation-free on this thread.
    fn swap_models(&mut self, cx: &StepCx) {
        let Some(sp) = self.swap.as_mut() else { return };
        // Announcements of earlier ticks only (`Read::Feedback`): `adapt` is not ordered before us.
        while let Some(u) = sp.updates.next(cx) {
            if sp.loader.request(&u) {
                sp.pending += 1;
            } else {
                sp.refused += 1;
            }
        }
        while sp.pending > 0 {
            let answer = if cx.reproducible() {
                sp.loader.take_blocking(LOCKSTEP_LOAD_TIMEOUT)
            } else {
                sp.loader.try_take()
            };
            let Some(answer) = answer else {
                if cx.reproducible() {
                    // The loader did not answer in time: count it and go on with the models in use.
                    sp.pending = 0;
                    sp.refused += 1;
                }
                break;
            };
            sp.pending -= 1;
            match answer {
                Loaded::Ready(mut next) => {
                    match self.comp.swap_models(&mut next) {
                        Ok(()) => sp.swapped += 1,
                        Err(_) => sp.refused += 1,
                    }
                    // `next` now holds the replaced models (or the refused ones): freed off the cycle.
                    sp.loader.retire(next);
                }
                Loaded::Refused { .. } => sp.refused += 1,
            }
        }
    }

    /// One step with the vision feedback: reads the estimates that arrived, updates the
    /// correction and applies it. `Err` = a rejected target (counted by the compensator).
    fn step_with_feedback(&mut self, t: &JointTarget, n: usize, cx: &StepCx) -> Result<(), ()> {
        let Some(fp) = self.feedback.as_mut() else {
            return Err(());
        };
        let q = &t.q_desired_deg[..n];
        let now = cx.clock_ns();
        let usable = n == self.comp.joints() && q.iter().all(|v| v.is_finite());
        if usable {
            fp.fb.begin(t.header.tick, q, now);
        }
        // Every estimate of the ticks before, in arrival order (`Read::Feedback`; real time:
        // whatever arrived since the last cycle).
        while let Some(e) = fp.estimates.next(cx) {
            fp.fb.observe(&e, now);
        }
        if !usable {
            // Rejected and counted by the compensator, which holds its last command.
            return self.comp.step(q, &mut self.step_out).map_err(|_| ());
        }
        let mut u = [0.0f64; MAX_JOINTS];
        u[..n].copy_from_slice(fp.fb.update(now));
        if let Some(d) = self.dither.as_mut() {
            for (v, o) in u[..n].iter_mut().zip(d.update(q)) {
                *v += o;
            }
        }
        let r = if u[..n].iter().all(|&v| v == 0.0) {
            // No correction (yet, or markers lost): the feed-forward exactly as without feedback.
            self.comp.step(q, &mut self.step_out)
        } else {
            match fp.apply {
                ApplyTo::Command => self.comp.step_with_correction(q, &u[..n], &mut self.step_out),
                ApplyTo::Target => {
                    let mut shaped = [0.0f64; MAX_JOINTS];
                    for k in 0..n {
                        shaped[k] = q[k] + u[k];
                    }
                    let r = self.comp.step(&shaped[..n], &mut self.step_out);
                    // The command carries the real target; the correction is reported beside it.
                    self.step_out.q_desired_deg[..n].copy_from_slice(q);
                    self.step_out.correction_deg[..n].copy_from_slice(&u[..n]);
                    r
                }
            }
        };
        fp.fb.note_bounds(self.step_out.upper_mask, self.step_out.lower_mask);
        r.map_err(|_| ())
    }
}

impl Stage for CompensatorStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        let Some(t) = self.input.next(cx) else {
            return Ok(StepReport::IDLE);
        };
        let n = t.n_joints as usize;
        if n == 0 || n > MAX_JOINTS {
            self.bad_size += 1;
            return Ok(StepReport::IDLE);
        }
        // A rejected target (NaN, wrong length) is counted by the compensator; nothing is sent,
        // so the actuator's watchdog sees the gap.
        let ok = if self.feedback.is_some() {
            self.step_with_feedback(&t, n, cx).is_ok()
        } else if let Some(d) = self.dither.as_mut() {
            let q = &t.q_desired_deg[..n];
            let mut off = [0.0f64; MAX_JOINTS];
            let o = d.update(q);
            off[..o.len()].copy_from_slice(o);
            self.comp.step_with_correction(q, &off[..n], &mut self.step_out).is_ok()
        } else {
            self.comp.step(&t.q_desired_deg[..n], &mut self.step_out).is_ok()
        };
        if !ok {
            return Ok(StepReport::IDLE);
        }
        if self.step_out.joint_limited {
            self.limited_commands += 1;
            for k in 0..n {
                self.limit_lowered[k] += u64::from(self.step_out.joint_limit_lowered_mask >> k & 1);
                self.limit_raised[k] += u64::from(self.step_out.joint_limit_raised_mask >> k & 1);
            }
        }
        let mut cmd = JointCommand::default();
        self.step_out.fill_joint_command(&mut cmd);
        if cx.reproducible() {
            // The compute time is the machine's, not the run's: kept out of reproducible bytes.
            cmd.compute_ns = 0;
        }
        self.out.publish(t.header.tick, t.header.t_origin_ns, cmd)?;
        self.swap_models(cx);
        // The next window prefix (after a history step or a swap) now, off the target → command
        // path of the next cycle (results are the same either way).
        self.comp.prepare();
        Ok(StepReport::published(t.header.t_origin_ns))
    }

    fn counters(&self) -> StageCounters {
        let fb = self.feedback.as_ref().map(|f| (f.fb.counts(), f.fb.lost()));
        StageCounters {
            // Unusable estimates (invalid, partial, NaN, outliers) count as rejected samples;
            // marker-loss fallbacks as faults, and the node is degraded while markers are lost.
            rejected: self.comp.rejected_inputs() + self.bad_size + fb.map_or(0, |(c, _)| c.rejected()),
            // A refused model update (bad file, failed load check, loader timeout) is a fault:
            // the models in use stay.
            faults: fb.map_or(0, |(c, _)| c.loss_episodes) + self.swap.as_ref().map_or(0, |s| s.refused),
            degraded: fb.is_some_and(|(_, lost)| lost),
            ..Default::default()
        }
    }

    fn summary(&self) -> Vec<String> {
        let mut by_joint = String::new();
        for k in 0..self.comp.joints() {
            for (what, n) in [("lowered", self.limit_lowered[k]), ("raised", self.limit_raised[k])] {
                if n > 0 {
                    by_joint += &format!("{}q{} {what} {n}", if by_joint.is_empty() { ": " } else { ", " }, k + 1);
                }
            }
        }
        let mut v = vec![format!(
            "compensator: mode {}, rejected targets {}, commands changed by the joint limits {}{by_joint}",
            self.comp.mode(),
            self.comp.rejected_inputs() + self.bad_size,
            self.limited_commands
        )];
        if let Some(line) = self.comp.safety_summary() {
            v.push(line);
        }
        if let Some(d) = &self.dither {
            let (draws, scaled, max_tip) = d.counts();
            v.push(format!(
                "dither: {draws} offsets drawn, {scaled} scaled down to the tip bound, largest tip displacement {max_tip:.3} mm"
            ));
        }
        if let Some(sp) = &self.swap {
            v.push(format!(
                "compensator: model generation {} in use; {} swaps, {} updates refused",
                self.comp.generation(),
                sp.swapped,
                sp.refused
            ));
        }
        if let Some(f) = &self.feedback {
            v.push(f.fb.summary());
        } else if self.feedback_idle {
            v.push(
                "feedback: enabled in the config, not applied in uncalibrated mode (in_uncalibrated = false)".into(),
            );
        }
        v
    }
}
