//! Actuator node: `JointCommand` → `bowden_actuator::Actuator` (limits, rate limit, watchdog,
//! e-stop) → `MotorCommand` through a [`Drive`]: here the IPC drive that feeds the plant process
//! or an external motor-driver process alike.

use crate::{Actuator, ActuatorConfig, ActuatorState, Drive, DriveError};
use bowden_interfaces::{services, JointCommand, MotorCommand, SafetyCommand};
use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
use bowden_runtime::ports::{Input, Output};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};

/// Publishes setpoints on `bowden/motor_command` for whichever process drives the motors.
pub struct IpcDrive {
    out: Output<MotorCommand>,
}

impl Drive for IpcDrive {
    fn name(&self) -> &str {
        self.out.service()
    }

    fn write(&mut self, cmd: &MotorCommand) -> Result<(), DriveError> {
        self.out
            .publish(cmd.header.tick, cmd.header.t_origin_ns, *cmd)
            .map(|_| ())
            .map_err(|e| DriveError {
                drive: self.out.service().to_string(),
                message: e.to_string(),
            })
    }
}

struct ActuatorStage {
    act: Actuator,
    commands: Input<JointCommand>,
    safety: Input<SafetyCommand>,
    drive: Box<dyn Drive>,
    last_tick: u64,
}

/// The `actuator` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "actuator",
    summary: "joint commands → motor setpoints through a drive (limits, rate limit, watchdog, e-stop)",
    inputs: &[
        InputDecl::new(services::JOINT_COMMAND, Read::Tick, 4),
        InputDecl::new(services::SAFETY, Read::Side, 8),
    ],
    outputs: &[services::MOTOR_COMMAND],
    schedule: Schedule {
        periodic: false,
        period_us: None,
        wake_timeout_us: Some(5_000),
        deadline_us: Some(1_000),
    },
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let cfg: ActuatorConfig = env.params()?;
    let robot = bowden_kinematics::Robot::load_or_paper(env.robot_file().as_deref()).map_err(|e| env.error(e))?;
    let origin = format!("{}: [node.params] of `{}`", env.pipeline.origin, env.spec.name);
    let act = Actuator::new(&robot, &cfg, &origin).map_err(|e| env.error(e))?;
    let mut drive: Box<dyn Drive> = Box::new(IpcDrive {
        out: env.output(services::MOTOR_COMMAND)?,
    });
    drive.activate().map_err(|e| env.error(e))?;
    Ok(Box::new(ActuatorStage {
        act,
        commands: env.input(services::JOINT_COMMAND)?,
        safety: env.input(services::SAFETY)?,
        drive,
        last_tick: 0,
    }))
}

impl ActuatorStage {
    fn send(&mut self, mut m: MotorCommand, tick: u64, origin: u64) -> Result<(), StageError> {
        m.header.tick = tick;
        m.header.t_origin_ns = origin;
        self.drive.write(&m).map_err(|e| StageError::Fatal {
            stage: "actuator".into(),
            message: e.to_string(),
        })
    }
}

impl Stage for ActuatorStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        let now = cx.clock_ns();
        while let Some(s) = self.safety.next(cx) {
            self.act.safety(&s, now);
        }
        if let Some(c) = self.commands.next(cx) {
            self.last_tick = c.header.tick;
            let r = self.act.command(&c.q_cmd_deg, c.n_joints, now);
            self.send(r.output.to_motor_command(), c.header.tick, c.header.t_origin_ns)?;
            return Ok(StepReport::published(c.header.t_origin_ns));
        }
        // No command this activation: the watchdog decides whether to (keep) hold(ing).
        match self.act.idle(now) {
            Some(hold) => {
                self.send(hold.to_motor_command(), cx.out_tick(self.last_tick), now)?;
                Ok(StepReport {
                    active: true,
                    t_origin_ns: None,
                })
            }
            None => Ok(StepReport::IDLE),
        }
    }

    fn counters(&self) -> StageCounters {
        let c = self.act.counters();
        StageCounters {
            rejected: c.rejected(),
            faults: c.stale_faults,
            degraded: self.act.state() == ActuatorState::StaleHold,
            estop: self.act.state() == ActuatorState::EStop,
        }
    }

    fn finish(&mut self) -> Result<(), StageError> {
        self.drive.deactivate().map_err(|e| StageError::Fatal {
            stage: "actuator".into(),
            message: e.to_string(),
        })
    }

    fn summary(&self) -> Vec<String> {
        let c = self.act.counters();
        vec![format!(
            "actuator: state {:?}, commands {}, rejected {} (nan {}, impossible {}, joints {}, range {}), clamped {}, rate-limited {}, stale faults {}, e-stops {}",
            self.act.state(),
            c.commands,
            c.rejected(),
            c.rejected_not_finite,
            c.rejected_impossible,
            c.rejected_joint_count,
            c.rejected_out_of_range,
            c.clamped,
            c.rate_limited,
            c.stale_faults,
            c.estops
        )]
    }
}
