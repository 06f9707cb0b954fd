//! Actuator node: `JointCommand` → `bowden_actuator::Actuator` (limits, rate limit, watchdog,
//! e-stop) → `MotorCommand` through its [`Drive`]s, chosen in the pipeline file
//! (`[node.params] drive`): `"ipc"` (the default) publishes the setpoints on
//! `bowden/motor_command` for the plant process or an external motor-driver process;
//! `{ serial = "/dev/ttyUSB0" }` also writes them to a motor controller on a serial line
//! ([`crate::serial`]), and still publishes them (for the recorder, the estimator's IK start and
//! monitoring), after the controller took them.
//!
//! When the pipeline has a producer of `bowden/plant_state` (the simulated plant, or the robot's
//! driver process reporting its joint angles), the actuator reads it back (a feedback input,
//! never waited for) and holds on a state it cannot trust ([`crate::monitor`]).

use crate::serial::SerialLineDrive;
use crate::{Actuator, ActuatorConfig, ActuatorState, Drive, DriveError};
use bowden_interfaces::{services, JointCommand, MotorCommand, PlantState, SafetyCommand};
use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
use bowden_runtime::ports::{Input, Output};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use serde::Deserialize;

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

/// `[node.params] drive`: where setpoints go besides the IPC service.
#[derive(Debug, serde::Deserialize)]
#[serde(
    untagged,
    expecting = "expected `drive = \"ipc\"` or `drive = { serial = \"/dev/ttyUSB0\" }`"
)]
enum DriveParam {
    Name(DriveName),
    Serial { serial: std::path::PathBuf },
}

#[derive(Debug, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
enum DriveName {
    Ipc,
}

struct ActuatorStage {
    act: Actuator,
    commands: Input<JointCommand>,
    safety: Input<SafetyCommand>,
    /// The robot's reported state, when the pipeline has one.
    robot: Option<Input<PlantState>>,
    /// In write order: the hardware drive (if any), then the IPC drive.
    drives: Vec<Box<dyn Drive>>,
    last_tick: u64,
}

/// The `actuator` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "actuator",
    summary: "joint commands → motor setpoints through a drive (limits, rate limit, watchdog, e-stop)",
    inputs: &[
        InputDecl::new(services::JOINT_COMMAND, Read::Tick, 4),
        InputDecl::new(services::SAFETY, Read::Side, 8),
        // Deep enough for 64 ms of a 1 kHz driver: a late actuator step loses no state (a
        // lost one is a gap, and a gap is a fault).
        InputDecl::new(services::PLANT_STATE, Read::Feedback, 64),
    ],
    outputs: &[services::MOTOR_COMMAND],
    schedule: Schedule {
        wake_timeout_us: Some(5_000),
        deadline_us: Some(1_000),
        ..Schedule::EVENT
    },
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    // `drive` is the node's; every other parameter is the actuator's settings.
    let mut params = env.spec.params.clone();
    let drive_param = params.remove("drive");
    let bad = |what: &str, e: toml::de::Error| {
        env.error(format!(
            "{}: [node.params] of `{}`: {what}{}",
            env.pipeline.origin,
            env.spec.name,
            e.to_string().replace('\n', " ")
        ))
    };
    let cfg = ActuatorConfig::deserialize(toml::Value::Table(params)).map_err(|e| bad("", e))?;
    let drive_param = match drive_param {
        Some(v) => DriveParam::deserialize(v).map_err(|e| bad("drive: ", e))?,
        None => DriveParam::Name(DriveName::Ipc),
    };
    let robot = bowden_kinematics::Robot::load_or_paper(env.robot_file().as_deref()).map_err(|e| env.error(e))?;
    let origin = format!("{}: [node.params] of `{}`", env.pipeline.origin, env.spec.name);
    let mut act = Actuator::new(&robot, &cfg, &origin).map_err(|e| env.error(e))?;
    let robot_state = match env.pipeline.producer_of(services::PLANT_STATE) {
        Some(i) => {
            // How often the state comes: its producer's own period, never faster than a tick.
            let producer = &env.pipeline.stages[i];
            let own = env
                .pipeline
                .processes
                .iter()
                .find(|p| p.name == producer.process)
                .and_then(|p| match p.activation {
                    bowden_runtime::config::Activation::Periodic { period_ns, .. } => Some(period_ns),
                    bowden_runtime::config::Activation::Event { .. } => None,
                });
            let period_ns = own.unwrap_or(0).max(env.pipeline.period_ns());
            act.monitor_robot_state(period_ns, &origin).map_err(|e| env.error(e))?;
            Some(env.input(services::PLANT_STATE)?)
        }
        None => None,
    };
    let mut drives: Vec<Box<dyn Drive>> = Vec::with_capacity(2);
    if let DriveParam::Serial { serial } = &drive_param {
        drives.push(Box::new(
            SerialLineDrive::open(env.resolve(serial)).map_err(|e| env.error(e))?,
        ));
    }
    drives.push(Box::new(IpcDrive {
        out: env.output(services::MOTOR_COMMAND)?,
    }));
    for d in drives.iter_mut() {
        d.activate().map_err(|e| env.error(e))?;
    }
    Ok(Box::new(ActuatorStage {
        act,
        commands: env.input(services::JOINT_COMMAND)?,
        safety: env.input(services::SAFETY)?,
        robot: robot_state,
        drives,
        last_tick: 0,
    }))
}

impl ActuatorStage {
    fn send(&mut self, mut m: MotorCommand, tick: u64, origin: u64) -> Result<(), StageError> {
        m.header.tick = tick;
        m.header.t_origin_ns = origin;
        for d in self.drives.iter_mut() {
            d.write(&m).map_err(|e| StageError::Fatal {
                stage: "actuator".into(),
                message: e.to_string(),
            })?;
        }
        Ok(())
    }
}

impl Stage for ActuatorStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        let now = cx.clock_ns();
        while let Some(s) = self.safety.next(cx) {
            self.act.safety(&s, now);
        }
        // The robot's state before the command: a fault found now holds in this very step.
        if let Some(robot) = self.robot.as_mut() {
            while let Some(s) = robot.next(cx) {
                self.act.observe_robot(&s);
            }
            self.act.supervise(now);
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
            rejected: c.rejected() + self.act.monitor().map_or(0, |m| m.rejected()),
            faults: c.stale_faults + self.act.monitor().map_or(0, |m| m.faults()),
            degraded: self.act.state() == ActuatorState::StaleHold,
            estop: self.act.state() == ActuatorState::EStop,
            fault_hold: self.act.state() == ActuatorState::FaultHold,
            last_fault: self.act.last_fault(),
        }
    }

    fn finish(&mut self) -> Result<(), StageError> {
        // Every drive is told to hold, even when one of them fails; the first error is kept.
        let mut first = None;
        for d in self.drives.iter_mut() {
            if let Err(e) = d.deactivate() {
                first.get_or_insert(StageError::Fatal {
                    stage: "actuator".into(),
                    message: e.to_string(),
                });
            }
        }
        first.map_or(Ok(()), Err)
    }

    fn summary(&self) -> Vec<String> {
        let c = self.act.counters();
        let mut v = vec![format!(
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
        )];
        if let Some(m) = self.act.monitor() {
            let r = m.counters();
            v.push(format!(
                "actuator: robot states {}, faults {} (not finite {}, out of range {}, joint count {}, stale {}, missing {}, publisher restarts {}), fault holds {}, commands ignored in fault hold {}, releases refused {}, automatic resumptions {}, last fault: {}",
                r.states,
                m.faults(),
                r.not_finite,
                r.implausible,
                r.joint_count,
                r.stale,
                r.missing,
                r.restarts,
                c.fault_holds,
                c.ignored_during_fault,
                c.refused_releases,
                c.auto_resumes,
                bowden_interfaces::fault::name(self.act.last_fault())
            ));
        }
        v
    }
}
