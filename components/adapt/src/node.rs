//! Adapt node: `JointCommand` + `JointEstimate` (read passively: the chain never waits for this
//! node) → `bowden_adapt::Adapter` → `ModelUpdate` when a fine-tuned model validated better.
//!
//! Rows are the last usable frame of each held target, paired with the command of its tick.
//! In lockstep a due check runs inside the tick (the whole pipeline waits for it, so runs
//! reproduce byte for byte); in real time it runs on a worker thread and the node goes on
//! draining its inputs. The estimate of tick k is paired with the command of tick k (the
//! command the plant held when the frame was taken); samples of tick k are read at tick k + 1,
//! when they are certainly complete.

use crate::{AdaptConfig, Adapter, Decision, JobResult, SwapRecord};
use bowden_compensator::ControllerConfig;
use bowden_interfaces::{fnv1a64, services, JointCommand, JointEstimate, ModelUpdate, MAX_JOINTS};
use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
use bowden_runtime::ports::{Input, Output};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use serde::Deserialize;
use std::collections::VecDeque;
use std::path::PathBuf;
use std::thread::JoinHandle;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Adaptation settings (configs/adapt.toml layout); the defaults when absent.
    #[serde(default)]
    config: Option<PathBuf>,
    /// Controller config whose models are adapted; by default the pipeline's compensator's.
    #[serde(default)]
    controller: Option<PathBuf>,
    /// Where generations, `state.json`, `rows.csv` and `adapt.jsonl` go (relative to the
    /// working directory). Default `out/adapt`.
    #[serde(default)]
    state_dir: Option<PathBuf>,
    /// Go on from the state saved in `state_dir` (default); `false` starts afresh.
    #[serde(default = "yes")]
    resume: bool,
    /// Swap drill for tests and benchmarks: every N ticks announce the models in use again as
    /// a new generation (same weights, so commands must not change), exercising the whole swap
    /// path. 0 = off.
    #[serde(default)]
    drill_every_ticks: u64,
}

fn yes() -> bool {
    true
}

struct AdaptStage {
    adapter: Adapter,
    commands: Input<JointCommand>,
    estimates: Input<JointEstimate>,
    out: Output<ModelUpdate>,
    /// Recent commands: (tick, angles), to pair each estimate with the command of its frame.
    recent: VecDeque<(u64, JointCommand)>,
    /// The newest usable frame of the target being held: (tick, command, estimate).
    held: Option<(u64, JointCommand, [f64; MAX_JOINTS])>,
    worker: Option<JoinHandle<JobResult>>,
    announce_at_start: bool,
    drill_every_ticks: u64,
    drill_generation: u64,
    rejected: u64,
    failed_checks: u64,
    unpaired: u64,
    name: String,
}

/// The `adapt` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "adapt",
    summary: "online adaptation: fine-tunes the models beside the chain and announces better ones",
    inputs: &[
        InputDecl::new(services::JOINT_COMMAND, Read::Feedback, 64),
        InputDecl::new(services::JOINT_ESTIMATE, Read::Feedback, 64),
    ],
    outputs: &[services::MODEL_UPDATE],
    schedule: Schedule {
        period_us: Some(20_000),
        ..Schedule::PERIODIC
    },
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    let cfg = match &p.config {
        Some(f) => AdaptConfig::load(&env.resolve(f)).map_err(|e| env.error(e))?,
        None => AdaptConfig::default(),
    };
    // The controller: given, or the pipeline compensator's `config`, or the shipped one.
    let controller = match &p.controller {
        Some(f) => Some(env.resolve(f)),
        None => env
            .pipeline
            .stages
            .iter()
            .find(|s| s.kind == "compensator")
            .and_then(|s| s.params.get("config"))
            .and_then(|v| v.as_str())
            .map(|f| env.resolve(std::path::Path::new(f))),
    };
    let ctl = match &controller {
        Some(f) => ControllerConfig::load(f).map_err(|e| env.error(e))?,
        None => ControllerConfig::shipped(),
    };
    let model = |field: &'static str, m: &Option<PathBuf>| -> Result<PathBuf, StageBuildError> {
        let m = m
            .as_ref()
            .ok_or_else(|| env.error(format!("the controller config names no `{field}` to adapt")))?;
        ctl.resolve_model_path(field, m).map_err(|e| env.error(e))
    };
    let fwd = model("model_fwd", &ctl.model_fwd)?;
    let inv = model("model_inv", &ctl.model_inv)?;
    let dir = p.state_dir.clone().unwrap_or_else(|| PathBuf::from("out/adapt"));
    // Absolute: the directory travels in `ModelUpdate` to another process.
    let dir = std::path::absolute(&dir).map_err(|e| env.error(format!("state_dir {}: {e}", dir.display())))?;
    let adapter = Adapter::open(cfg, &dir, &fwd, &inv, p.resume).map_err(|e| env.error(e))?;
    Ok(Box::new(AdaptStage {
        announce_at_start: adapter.current().is_some(),
        adapter,
        commands: env.input(services::JOINT_COMMAND)?,
        estimates: env.input(services::JOINT_ESTIMATE)?,
        out: env.output(services::MODEL_UPDATE)?,
        recent: VecDeque::with_capacity(128),
        held: None,
        worker: None,
        drill_every_ticks: p.drill_every_ticks,
        drill_generation: 0,
        rejected: 0,
        failed_checks: 0,
        unpaired: 0,
        name: env.spec.name.clone(),
    }))
}

impl AdaptStage {
    fn push_row(&mut self, tick: u64, c: &JointCommand, q_phy: &[f64; MAX_JOINTS]) {
        let j = self.adapter.joints();
        // The compensator's prediction, when its mode makes one (mode ≠ uncalibrated).
        let pred = (c.mode != 0).then_some(&c.q_predicted_deg[..j]);
        if let Err(why) = self.adapter.push(tick, &c.q_cmd_deg[..j], &q_phy[..j], pred) {
            eprintln!("{}: row refused: {why}", self.name);
        }
    }

    fn publish(&mut self, s: &SwapRecord, cx: &StepCx) -> Result<(), StageError> {
        let mut u = ModelUpdate {
            generation: s.generation,
            fwd_hash: s.fwd_hash,
            inv_hash: s.inv_hash,
            fwd_val_before_deg: s.fwd_before_deg,
            fwd_val_after_deg: s.fwd_after_deg,
            inv_val_before_deg: s.inv_before_deg,
            inv_val_after_deg: s.inv_after_deg,
            ..Default::default()
        };
        if !u.set_dir(&s.dir.display().to_string()) {
            eprintln!(
                "{}: generation {} not announced: its directory {} is longer than 255 bytes",
                self.name,
                s.generation,
                s.dir.display()
            );
            self.failed_checks += 1;
            return Ok(());
        }
        self.out.publish(cx.tick(), cx.clock_ns(), u)?;
        Ok(())
    }

    /// The generation in use announced with both files (after a restart, and for the drill).
    fn announce_whole(&mut self, generation: u64, cx: &StepCx) -> Result<(), StageError> {
        let Some(cur) = self.adapter.current().cloned() else {
            return Ok(());
        };
        let hash = |f: &str| std::fs::read(cur.dir.join(f)).map(|b| fnv1a64(&b)).unwrap_or(0);
        let s = SwapRecord {
            generation,
            fwd_hash: hash("fwd.onnx"),
            inv_hash: hash("inv.onnx"),
            ..cur
        };
        self.publish(&s, cx)
    }

    fn take_result(&mut self, r: JobResult, cx: &StepCx) -> Result<(), StageError> {
        let decision = r.record.decision;
        let message = r.record.message.clone();
        match self.adapter.apply(r, cx.tick()) {
            Ok(swap) => {
                eprintln!("{}: tick {}: check {:?}: {message}", self.name, cx.tick(), decision);
                if decision == Decision::Failed {
                    self.failed_checks += 1;
                }
                if let Some(s) = swap {
                    eprintln!(
                        "{}: generation {} written to {} and announced",
                        self.name,
                        s.generation,
                        s.dir.display()
                    );
                    self.publish(&s, cx)?;
                }
            }
            Err(e) => {
                self.failed_checks += 1;
                eprintln!(
                    "{}: tick {}: the check's result could not be kept: {e}",
                    self.name,
                    cx.tick()
                );
            }
        }
        Ok(())
    }
}

impl Stage for AdaptStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        if self.announce_at_start {
            self.announce_at_start = false;
            let g = self.adapter.generation();
            self.announce_whole(g, cx)?;
        }
        // Samples of earlier ticks only (`Read::Feedback`): this node is not ordered after the
        // chain.
        let mut active = false;
        while let Some(c) = self.commands.next(cx) {
            if self.recent.len() == self.recent.capacity() {
                self.recent.pop_front();
            }
            self.recent.push_back((c.header.tick, c));
        }
        let j = self.adapter.joints();
        while let Some(e) = self.estimates.next(cx) {
            active = true;
            let all = (1u32 << j) - 1;
            if e.quality != JointEstimate::QUALITY_VALID || e.n_joints as usize != j || e.joint_valid_mask & all != all
            {
                // Lost or partial markers: nothing to learn from this frame.
                self.rejected += 1;
                continue;
            }
            let Some((_, c)) = self.recent.iter().rev().find(|(t, _)| *t <= e.header.tick) else {
                self.unpaired += 1;
                continue;
            };
            // A row is the LAST frame of each held target (the most settled, as the dataset
            // measured after each command's pause): a frame replaces the held one while the
            // target stays, and a new target releases the held frame as a row. With one frame
            // per target, or a target that moves every cycle, every frame becomes a row.
            let c = *c;
            if let Some((ht, hc, hp)) = self.held.take() {
                if hc.q_desired_deg[..j] != c.q_desired_deg[..j] {
                    self.push_row(ht, &hc, &hp);
                }
            }
            self.held = Some((e.header.tick, c, e.q_phy_deg));
        }
        if let Some(w) = &self.worker {
            if w.is_finished() {
                let w = self.worker.take().expect("checked");
                match w.join() {
                    Ok(r) => self.take_result(r, cx)?,
                    Err(_) => {
                        self.failed_checks += 1;
                        eprintln!("{}: the fine-tuning thread panicked; the models in use stay", self.name);
                    }
                }
            }
        }
        if self.worker.is_none() && self.adapter.due() {
            let job = self.adapter.job();
            if cx.reproducible() {
                // The whole pipeline waits for the check, so the run reproduces byte for byte.
                let r = job.run();
                self.take_result(r, cx)?;
            } else {
                match std::thread::Builder::new()
                    .name("adapt-finetune".into())
                    .spawn(move || job.run())
                {
                    Ok(h) => self.worker = Some(h),
                    Err(e) => {
                        self.failed_checks += 1;
                        eprintln!("{}: could not start the fine-tuning thread: {e}", self.name);
                    }
                }
            }
            active = true;
        }
        if self.drill_every_ticks > 0 && cx.tick() > 0 && cx.tick().is_multiple_of(self.drill_every_ticks) {
            self.drill_generation += 1;
            let g = self.drill_generation;
            if self.adapter.current().is_some() {
                self.announce_whole(g, cx)?;
            } else {
                self.drill_base(g, cx)?;
            }
            active = true;
        }
        Ok(if active {
            StepReport {
                active: true,
                t_origin_ns: None,
            }
        } else {
            StepReport::IDLE
        })
    }

    fn counters(&self) -> StageCounters {
        StageCounters {
            rejected: self.rejected + self.adapter.rejected_rows(),
            faults: self.failed_checks,
            ..Default::default()
        }
    }

    fn summary(&self) -> Vec<String> {
        let mut v = vec![format!(
            "adapt: generation {}, {} rows in the window ({} skipped standing still, {} frames unusable, {} unpaired), reference {}",
            self.adapter.generation(),
            self.adapter.rows(),
            self.adapter.skipped_rows(),
            self.rejected + self.adapter.rejected_rows(),
            self.unpaired,
            self.adapter
                .reference_deg()
                .map_or("not yet measured".into(), |(f, i)| format!("forward {f:.3}°, inverse {i:.3}° held-out")),
        )];
        for s in self.adapter.swaps() {
            v.push(format!(
                "adapt: generation {} at tick {}: forward {:.3}° → {:.3}°, inverse {:.3}° → {:.3}° (held-out RMSE)",
                s.generation, s.tick, s.fwd_before_deg, s.fwd_after_deg, s.inv_before_deg, s.inv_after_deg
            ));
        }
        if self.drill_generation > 0 {
            v.push(format!(
                "adapt: swap drill announced {} generations",
                self.drill_generation
            ));
        }
        v
    }
}

impl AdaptStage {
    /// The drill without an adapted generation: the start models copied into the state
    /// directory once and announced from there.
    fn drill_base(&mut self, generation: u64, cx: &StepCx) -> Result<(), StageError> {
        let (fwd, inv) = self.adapter.model_files();
        let dir = self.adapter.state_dir().join("drill");
        let mut hashes = [0u64; 2];
        for (k, (src, name)) in [(fwd, "fwd.onnx"), (inv, "inv.onnx")].into_iter().enumerate() {
            let dst = dir.join(name);
            if !dst.exists() {
                let copied = std::fs::create_dir_all(&dir).and_then(|_| std::fs::copy(&src, &dst));
                if let Err(e) = copied {
                    eprintln!("{}: drill: {} → {}: {e}", self.name, src.display(), dst.display());
                    self.failed_checks += 1;
                    return Ok(());
                }
            }
            hashes[k] = std::fs::read(&dst).map(|b| fnv1a64(&b)).unwrap_or(0);
        }
        let s = SwapRecord {
            generation,
            tick: cx.tick(),
            dir,
            fwd_hash: hashes[0],
            inv_hash: hashes[1],
            fwd_before_deg: f64::NAN,
            fwd_after_deg: f64::NAN,
            inv_before_deg: f64::NAN,
            inv_after_deg: f64::NAN,
        };
        self.publish(&s, cx)
    }
}
