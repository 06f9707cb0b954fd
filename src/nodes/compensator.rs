//! Compensator node: `JointTarget` → `bowden_compensator::Compensator::step` → `JointCommand`.

use bowden_compensator::{Compensator, ControllerConfig, Mode, StepOutput};
use bowden_interfaces::{services, JointCommand, JointTarget, MAX_JOINTS};
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
}

struct CompensatorStage {
    comp: Compensator,
    input: Input<JointTarget>,
    out: Output<JointCommand>,
    step_out: StepOutput,
    bad_size: u64,
}

pub fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    let robot = super::robot(env)?;
    let mut cfg = match &p.config {
        Some(path) => ControllerConfig::load(super::resolve(env, path)).map_err(|e| env.error(e))?,
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
    if env.lockstep() {
        // A time budget would make results depend on the machine's speed.
        comp.set_budget_ns(0);
    }
    Ok(Box::new(CompensatorStage {
        comp,
        input: env.ports.input(services::JOINT_TARGET, 4)?,
        out: env.ports.output(services::JOINT_COMMAND)?,
        step_out: StepOutput::default(),
        bad_size: 0,
    }))
}

impl Stage for CompensatorStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        let Some(t) = self.input.take(cx.lockstep, cx.tick) else {
            return Ok(StepReport::IDLE);
        };
        let n = t.n_joints as usize;
        if n == 0 || n > MAX_JOINTS {
            self.bad_size += 1;
            return Ok(StepReport::IDLE);
        }
        // A rejected target (NaN, wrong length) is counted by the compensator; nothing is sent,
        // so the actuator's watchdog sees the gap.
        if self.comp.step(&t.q_desired_deg[..n], &mut self.step_out).is_err() {
            return Ok(StepReport::IDLE);
        }
        let mut cmd = JointCommand::default();
        self.step_out.fill_joint_command(&mut cmd);
        if cx.lockstep {
            cmd.compute_ns = 0;
        }
        self.out.publish(t.header.tick, t.header.t_origin_ns, cmd)?;
        Ok(StepReport::published(t.header.t_origin_ns))
    }

    fn counters(&self) -> StageCounters {
        StageCounters {
            rejected: self.comp.rejected_inputs() + self.bad_size,
            ..Default::default()
        }
    }

    fn summary(&self) -> Vec<String> {
        vec![format!(
            "compensator: mode {}, rejected targets {}",
            self.comp.mode(),
            self.comp.rejected_inputs() + self.bad_size
        )]
    }
}
