//! The actuator: joint command q_cmd → cable displacements Δw (eq. 5 with decoupling) for the
//! motors, behind the safety logic a real drive needs:
//!
//! - **validation**: a command with NaN/inf, the wrong joint count, or an impossible value
//!   (beyond ±`max_abs_deg`) is rejected and counted; the last safe command is held instead;
//! - **joint limits**: out-of-range commands are clamped (or rejected, by config);
//! - **rate limit**: no joint moves faster than `max_rate_deg_s` (time from the caller's clock,
//!   simulated in lockstep);
//! - **watchdog**: when no valid command arrived for `stale_after_ms`, hold the last safe command
//!   and flag a fault (once per stale episode); resume when commands come back (or, with
//!   `latch_on_stale`, only after a release);
//! - **e-stop latch**: `SafetyCommand::ESTOP` holds the last safe command until `RELEASE`;
//! - **robot-state monitor** ([`monitor`]): a robot state that is not finite, implausible,
//!   stale or missing holds the last safe command in the same step (`FaultHold`) until the
//!   configured resumption (a release, or N good states).
//!
//! [`Drive`] is the hardware interface (ros2_control's `write` side): the IPC drive that feeds
//! the simulated plant process and a real motor driver implement it alike, so they are
//! interchangeable. Nothing here allocates after construction.

pub mod monitor;

use bowden_interfaces::{fault, MotorCommand, PlantState, SafetyCommand, MAX_CABLES, MAX_JOINTS};
use bowden_kinematics::{Robot, N_CABLES, N_JOINTS};
use monitor::{MonitorConfig, StateFault, StateMonitor};
use serde::Deserialize;
use std::path::Path;

/// What to do with a command outside the joint limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OutOfRange {
    /// Clamp into the limits (and flag the output).
    #[default]
    Clamp,
    /// Reject the command (hold the last safe one).
    Reject,
}

/// A rate limit for every joint, or one per joint.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum Rate {
    All(f64),
    PerJoint(Vec<f64>),
}

/// `[node.params]` of the actuator stage.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorConfig {
    /// Watchdog: a command older than this is stale, ms.
    #[serde(default = "default_stale_ms")]
    pub stale_after_ms: f64,
    /// Largest joint speed, deg/s.
    #[serde(default = "default_rate")]
    pub max_rate_deg_s: Rate,
    #[serde(default)]
    pub out_of_range: OutOfRange,
    /// Any |q| above this is not a command but garbage: rejected even when clamping.
    #[serde(default = "default_max_abs")]
    pub max_abs_deg: f64,
    /// Stay in hold after a stale episode until a `RELEASE` safety command.
    #[serde(default)]
    pub latch_on_stale: bool,
    /// Configuration the motors are at before the first command, deg (zeros by default).
    #[serde(default)]
    pub initial_q_deg: Option<Vec<f64>>,
    /// The robot-state monitor's bounds and resumption (used when the robot reports a state).
    #[serde(default)]
    pub robot_state: MonitorConfig,
}

fn default_stale_ms() -> f64 {
    20.0
}
fn default_rate() -> Rate {
    Rate::All(400.0)
}
fn default_max_abs() -> f64 {
    360.0
}

impl Default for ActuatorConfig {
    fn default() -> Self {
        Self {
            stale_after_ms: default_stale_ms(),
            max_rate_deg_s: default_rate(),
            out_of_range: OutOfRange::Clamp,
            max_abs_deg: default_max_abs(),
            latch_on_stale: false,
            initial_q_deg: None,
            robot_state: MonitorConfig::default(),
        }
    }
}

/// A configuration that cannot be used; names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ActuatorError {
    #[error("{origin}: actuator field `{field}`: {problem}")]
    Invalid {
        origin: String,
        field: &'static str,
        problem: String,
    },
    #[error("{origin}: malformed actuator TOML: {message}")]
    Parse { origin: String, message: String },
    #[error("{origin}: cannot read: {message}")]
    Io { origin: String, message: String },
}

impl ActuatorConfig {
    /// Reads and validates a TOML file with the fields of [`ActuatorConfig`].
    pub fn load(path: &Path) -> Result<Self, ActuatorError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ActuatorError::Io {
            origin: origin.clone(),
            message: e.to_string(),
        })?;
        let c: Self = toml::from_str(&text).map_err(|e| ActuatorError::Parse {
            origin: origin.clone(),
            message: e.to_string().replace('\n', " "),
        })?;
        c.validate(&origin)?;
        Ok(c)
    }

    /// Checks every field; `origin` names the file (or stage) in errors.
    pub fn validate(&self, origin: &str) -> Result<(), ActuatorError> {
        let bad = |field, problem: String| ActuatorError::Invalid {
            origin: origin.to_string(),
            field,
            problem,
        };
        if !(self.stale_after_ms.is_finite() && self.stale_after_ms > 0.0) {
            return Err(bad(
                "stale_after_ms",
                format!("must be a positive number, got {}", self.stale_after_ms),
            ));
        }
        let rates: Vec<f64> = match &self.max_rate_deg_s {
            Rate::All(r) => vec![*r],
            Rate::PerJoint(v) => {
                if v.len() != N_JOINTS {
                    return Err(bad(
                        "max_rate_deg_s",
                        format!("needs {N_JOINTS} values, got {}", v.len()),
                    ));
                }
                v.clone()
            }
        };
        if let Some(r) = rates.iter().find(|r| !(r.is_finite() && **r > 0.0)) {
            return Err(bad("max_rate_deg_s", format!("must be positive numbers, got {r}")));
        }
        if !(self.max_abs_deg.is_finite() && self.max_abs_deg > 0.0) {
            return Err(bad(
                "max_abs_deg",
                format!("must be a positive number, got {}", self.max_abs_deg),
            ));
        }
        if let Err((field, problem)) = self.robot_state.validate() {
            return Err(bad(field, problem));
        }
        if let Some(q) = &self.initial_q_deg {
            if q.len() != N_JOINTS || !q.iter().all(|v| v.is_finite()) {
                return Err(bad(
                    "initial_q_deg",
                    format!("needs {N_JOINTS} finite values, got {q:?}"),
                ));
            }
        }
        Ok(())
    }

    fn rates(&self) -> [f64; N_JOINTS] {
        match &self.max_rate_deg_s {
            Rate::All(r) => [*r; N_JOINTS],
            Rate::PerJoint(v) => core::array::from_fn(|j| v[j]),
        }
    }
}

/// Why a command was not driven.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rejection {
    /// `n_joints` differs from the robot's.
    WrongJointCount {
        got: u32,
        expected: u32,
    },
    NotFinite {
        joint: usize,
    },
    /// |q| beyond `max_abs_deg`: not a plausible command.
    Impossible {
        joint: usize,
        value_deg: f64,
    },
    /// Outside the joint limits with `out_of_range = "reject"`.
    OutOfRange {
        joint: usize,
        value_deg: f64,
    },
    /// Ignored while the e-stop is latched (not counted as invalid).
    EStopLatched,
    /// Ignored while holding after a robot-state fault (not counted as invalid).
    FaultHold,
}

/// Operating state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ActuatorState {
    /// Driving commands.
    Running,
    /// Holding the last safe command because commands went stale.
    StaleHold,
    /// E-stop latched.
    EStop,
    /// Holding the last safe command because the robot's state cannot be trusted (see
    /// [`monitor`]); latched until the configured resumption.
    FaultHold,
}

/// Counters, for status samples and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ActuatorCounters {
    pub commands: u64,
    pub rejected_not_finite: u64,
    pub rejected_impossible: u64,
    pub rejected_joint_count: u64,
    pub rejected_out_of_range: u64,
    pub ignored_during_estop: u64,
    /// Outputs changed by a joint limit clamp.
    pub clamped: u64,
    /// Outputs changed by the rate limit.
    pub rate_limited: u64,
    /// Stale episodes (watchdog faults).
    pub stale_faults: u64,
    pub estops: u64,
    /// Commands ignored while holding after a robot-state fault.
    pub ignored_during_fault: u64,
    /// Times the actuator entered the fault hold.
    pub fault_holds: u64,
    /// Releases refused because the robot still reported no valid, fresh state.
    pub refused_releases: u64,
    /// Automatic resumptions after N good states.
    pub auto_resumes: u64,
}

impl ActuatorCounters {
    /// Invalid samples rejected.
    pub fn rejected(&self) -> u64 {
        self.rejected_not_finite + self.rejected_impossible + self.rejected_joint_count + self.rejected_out_of_range
    }
}

/// One drive setpoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActuatorOutput {
    pub q_cmd_deg: [f64; N_JOINTS],
    pub cable_disp_mm: [f64; N_CABLES],
    /// `MotorCommand::FLAG_*`.
    pub flags: u32,
}

impl ActuatorOutput {
    /// The sample for the drive (header left for the publisher to stamp).
    pub fn to_motor_command(&self) -> MotorCommand {
        let mut m = MotorCommand {
            n_cables: N_CABLES as u32,
            flags: self.flags,
            ..Default::default()
        };
        m.cable_disp_mm[..N_CABLES].copy_from_slice(&self.cable_disp_mm);
        m.q_cmd_deg[..N_JOINTS].copy_from_slice(&self.q_cmd_deg);
        m
    }
}

/// The result of handling one command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandResult {
    /// What to send to the drive now.
    pub output: ActuatorOutput,
    /// Set when the command was not driven (the output holds the last safe command).
    pub rejection: Option<Rejection>,
}

/// The actuator's state machine. See the crate documentation.
#[derive(Debug, Clone)]
pub struct Actuator {
    robot: Robot,
    out_of_range: OutOfRange,
    max_abs_deg: f64,
    latch_on_stale: bool,
    stale_after_ns: u64,
    rate_deg_per_ns: [f64; N_JOINTS],
    q_out: [f64; N_JOINTS],
    t_last_out_ns: Option<u64>,
    t_last_cmd_ns: Option<u64>,
    state: ActuatorState,
    counters: ActuatorCounters,
    monitor: Option<StateMonitor>,
    monitor_cfg: MonitorConfig,
    last_fault: u32,
}

const _: () = assert!(N_JOINTS <= MAX_JOINTS && N_CABLES <= MAX_CABLES);

impl Actuator {
    /// Validates `cfg` and starts holding the initial configuration.
    pub fn new(robot: &Robot, cfg: &ActuatorConfig, origin: &str) -> Result<Self, ActuatorError> {
        cfg.validate(origin)?;
        let q0: [f64; N_JOINTS] = match &cfg.initial_q_deg {
            Some(v) => core::array::from_fn(|j| v[j]),
            None => [0.0; N_JOINTS],
        };
        if let Err(e) = robot.check_command_limits(&q0) {
            return Err(ActuatorError::Invalid {
                origin: origin.to_string(),
                field: "initial_q_deg",
                problem: e.to_string(),
            });
        }
        Ok(Self {
            robot: robot.clone(),
            out_of_range: cfg.out_of_range,
            max_abs_deg: cfg.max_abs_deg,
            latch_on_stale: cfg.latch_on_stale,
            stale_after_ns: (cfg.stale_after_ms * 1e6) as u64,
            rate_deg_per_ns: cfg.rates().map(|r| r * 1e-9),
            q_out: q0,
            t_last_out_ns: None,
            t_last_cmd_ns: None,
            state: ActuatorState::Running,
            counters: ActuatorCounters::default(),
            monitor: None,
            monitor_cfg: cfg.robot_state.clone(),
            last_fault: fault::NONE,
        })
    }

    /// Watches the robot's reported state from now on ([`Actuator::observe_robot`],
    /// [`Actuator::supervise`]), with the configuration's `robot_state` bounds; the state is
    /// published every `state_period_ns`.
    pub fn monitor_robot_state(&mut self, state_period_ns: u64, origin: &str) -> Result<(), ActuatorError> {
        let m = StateMonitor::new(&self.robot, &self.monitor_cfg, state_period_ns).map_err(|(field, problem)| {
            ActuatorError::Invalid {
                origin: origin.to_string(),
                field,
                problem,
            }
        })?;
        self.monitor = Some(m);
        Ok(())
    }

    /// The robot-state monitor, when enabled.
    pub fn monitor(&self) -> Option<&StateMonitor> {
        self.monitor.as_ref()
    }

    /// The last fault detected (`bowden_interfaces::fault` code, 0 = none).
    pub fn last_fault(&self) -> u32 {
        self.last_fault
    }

    /// A state the robot reported: checked by the monitor; a bad one holds at once.
    pub fn observe_robot(&mut self, s: &PlantState) -> Option<StateFault> {
        let m = self.monitor.as_mut()?;
        let episodes = m.faults();
        let f = m.observe(s).err()?;
        let new_episode = m.faults() > episodes;
        self.enter_fault_hold(f.code, new_episode);
        Some(f)
    }

    /// Once per step before the command: the robot state's freshness, and the automatic
    /// resumption when configured. Returns the fault found now, if any.
    pub fn supervise(&mut self, t_now_ns: u64) -> Option<StateFault> {
        let m = self.monitor.as_mut()?;
        let episodes = m.faults();
        match m.check_age(t_now_ns) {
            Err(f) => {
                let new_episode = m.faults() > episodes;
                self.enter_fault_hold(f.code, new_episode);
                Some(f)
            }
            Ok(()) => {
                if self.state == ActuatorState::FaultHold && m.may_resume() {
                    self.counters.auto_resumes += 1;
                    self.resume_at(t_now_ns);
                }
                None
            }
        }
    }

    /// `new_episode`: this fault began a new stretch of untrusted state (its code is the one
    /// reported; later faults of the same stretch keep it).
    fn enter_fault_hold(&mut self, code: u32, new_episode: bool) {
        if new_episode {
            self.last_fault = code;
        }
        match self.state {
            ActuatorState::EStop | ActuatorState::FaultHold => {}
            ActuatorState::Running | ActuatorState::StaleHold => {
                self.counters.fault_holds += 1;
                self.state = ActuatorState::FaultHold;
            }
        }
    }

    fn resume_at(&mut self, t_now_ns: u64) {
        self.state = ActuatorState::Running;
        // The watchdog restarts from the resumption, not from the last command.
        if self.t_last_cmd_ns.is_some() {
            self.t_last_cmd_ns = Some(t_now_ns);
        }
    }

    pub fn state(&self) -> ActuatorState {
        self.state
    }

    pub fn counters(&self) -> ActuatorCounters {
        self.counters
    }

    /// The last command sent to the drive (the one a hold keeps).
    pub fn held_q_deg(&self) -> [f64; N_JOINTS] {
        self.q_out
    }

    fn output(&self, flags: u32) -> ActuatorOutput {
        ActuatorOutput {
            q_cmd_deg: self.q_out,
            cable_disp_mm: self.robot.cables().displacements_mm(&self.q_out),
            flags,
        }
    }

    fn hold_flags(&self) -> u32 {
        match self.state {
            ActuatorState::Running => 0,
            ActuatorState::StaleHold => MotorCommand::FLAG_HOLD,
            ActuatorState::EStop => MotorCommand::FLAG_HOLD | MotorCommand::FLAG_ESTOP,
            ActuatorState::FaultHold => MotorCommand::FLAG_HOLD | MotorCommand::FLAG_FAULT,
        }
    }

    fn hold(&mut self, t_now_ns: u64) -> ActuatorOutput {
        self.t_last_out_ns = Some(t_now_ns);
        self.output(self.hold_flags() | MotorCommand::FLAG_HOLD)
    }

    fn validate(&self, q: &[f64], n_joints: u32) -> Result<(), Rejection> {
        if n_joints as usize != N_JOINTS || q.len() < N_JOINTS {
            return Err(Rejection::WrongJointCount {
                got: n_joints,
                expected: N_JOINTS as u32,
            });
        }
        for (j, &v) in q[..N_JOINTS].iter().enumerate() {
            if !v.is_finite() {
                return Err(Rejection::NotFinite { joint: j + 1 });
            }
            if v.abs() > self.max_abs_deg {
                return Err(Rejection::Impossible {
                    joint: j + 1,
                    value_deg: v,
                });
            }
        }
        Ok(())
    }

    /// Handles a joint command that arrived at `t_now_ns` (`q_cmd_deg` holds at least the used
    /// entries; `n_joints` as sent). Always returns what to drive now.
    pub fn command(&mut self, q_cmd_deg: &[f64], n_joints: u32, t_now_ns: u64) -> CommandResult {
        if self.state == ActuatorState::EStop {
            self.counters.ignored_during_estop += 1;
            return CommandResult {
                output: self.hold(t_now_ns),
                rejection: Some(Rejection::EStopLatched),
            };
        }
        if self.state == ActuatorState::FaultHold {
            self.counters.ignored_during_fault += 1;
            return CommandResult {
                output: self.hold(t_now_ns),
                rejection: Some(Rejection::FaultHold),
            };
        }
        if let Err(r) = self.validate(q_cmd_deg, n_joints) {
            match r {
                Rejection::WrongJointCount { .. } => self.counters.rejected_joint_count += 1,
                Rejection::NotFinite { .. } => self.counters.rejected_not_finite += 1,
                _ => self.counters.rejected_impossible += 1,
            }
            return CommandResult {
                output: self.hold(t_now_ns),
                rejection: Some(r),
            };
        }
        let requested: [f64; N_JOINTS] = core::array::from_fn(|j| q_cmd_deg[j]);
        let mut flags = 0;
        let target = match self.robot.check_command_limits(&requested) {
            Ok(()) => requested,
            Err(_) if self.out_of_range == OutOfRange::Clamp => {
                self.counters.clamped += 1;
                flags |= MotorCommand::FLAG_CLAMPED;
                self.robot.clamp_command_to_limits(&requested)
            }
            Err(e) => {
                self.counters.rejected_out_of_range += 1;
                let (joint, value_deg) = match e {
                    bowden_kinematics::LimitError::OutOfRange { joint, value_deg, .. } => (joint, value_deg),
                    bowden_kinematics::LimitError::NotFinite { joint, value_deg } => (joint, value_deg),
                    bowden_kinematics::LimitError::JawsCross { opening_deg, .. } => (5, opening_deg),
                };
                return CommandResult {
                    output: self.hold(t_now_ns),
                    rejection: Some(Rejection::OutOfRange { joint, value_deg }),
                };
            }
        };
        self.counters.commands += 1;
        if self.state == ActuatorState::StaleHold && self.latch_on_stale {
            self.t_last_cmd_ns = Some(t_now_ns);
            return CommandResult {
                output: self.hold(t_now_ns),
                rejection: None,
            };
        }
        self.state = ActuatorState::Running;
        self.t_last_cmd_ns = Some(t_now_ns);
        // Rate limit from the last output; the first command may not move at all (dt = 0): a
        // motor cannot jump.
        let dt_ns = self.t_last_out_ns.map(|t| t_now_ns.saturating_sub(t)).unwrap_or(0) as f64;
        let mut limited = false;
        for ((q, &goal), &rate) in self.q_out.iter_mut().zip(&target).zip(&self.rate_deg_per_ns) {
            let max_step = rate * dt_ns;
            let d = goal - *q;
            if d.abs() > max_step {
                limited = true;
                *q += max_step.copysign(d);
            } else {
                *q = goal;
            }
        }
        if limited {
            self.counters.rate_limited += 1;
            flags |= MotorCommand::FLAG_CLAMPED;
        }
        self.t_last_out_ns = Some(t_now_ns);
        CommandResult {
            output: self.output(flags),
            rejection: None,
        }
    }

    /// No command at `t_now_ns`: checks the watchdog. Returns the hold setpoint to send while
    /// holding (stale or e-stop), `None` while the last command is still fresh (or none came yet).
    pub fn idle(&mut self, t_now_ns: u64) -> Option<ActuatorOutput> {
        match self.state {
            ActuatorState::EStop | ActuatorState::StaleHold | ActuatorState::FaultHold => Some(self.hold(t_now_ns)),
            ActuatorState::Running => {
                let last = self.t_last_cmd_ns?;
                if t_now_ns.saturating_sub(last) > self.stale_after_ns {
                    self.state = ActuatorState::StaleHold;
                    self.counters.stale_faults += 1;
                    self.last_fault = fault::INPUT_STALE;
                    Some(self.hold(t_now_ns))
                } else {
                    None
                }
            }
        }
    }

    /// Applies a safety command. Returns false for an unknown command value (counted as rejected).
    pub fn safety(&mut self, cmd: &SafetyCommand, t_now_ns: u64) -> bool {
        match cmd.command {
            SafetyCommand::ESTOP => {
                if self.state != ActuatorState::EStop {
                    self.counters.estops += 1;
                }
                self.state = ActuatorState::EStop;
                true
            }
            SafetyCommand::RELEASE => {
                // A person releases; the robot must still report valid, fresh states.
                let robot_ok = self.monitor.as_ref().is_none_or(|m| m.healthy());
                match self.state {
                    ActuatorState::Running => {}
                    ActuatorState::FaultHold if !robot_ok => self.counters.refused_releases += 1,
                    ActuatorState::EStop if !robot_ok => self.state = ActuatorState::FaultHold,
                    _ => self.resume_at(t_now_ns),
                }
                true
            }
            _ => {
                self.counters.rejected_impossible += 1;
                false
            }
        }
    }
}

/// A drive failed to take a setpoint.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("drive `{drive}`: {message}")]
pub struct DriveError {
    pub drive: String,
    pub message: String,
}

/// The motor side of the actuator (ros2_control's hardware interface, command half): the IPC
/// drive feeding the simulated plant process, a real motor driver, or an in-process simulation.
/// `write` is called from the control cycle: it must neither block nor allocate.
pub trait Drive {
    /// For logs and errors.
    fn name(&self) -> &str;

    /// Brings the hardware to a state where it accepts setpoints (enable amplifiers, home).
    fn activate(&mut self) -> Result<(), DriveError> {
        Ok(())
    }

    /// Sends one setpoint. `cmd.header` is stamped by the caller.
    fn write(&mut self, cmd: &MotorCommand) -> Result<(), DriveError>;

    /// Leaves the hardware holding safely (brakes, hold position) before the process exits.
    fn deactivate(&mut self) -> Result<(), DriveError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn act(cfg: ActuatorConfig) -> Actuator {
        Actuator::new(&Robot::paper_default(), &cfg, "test").expect("valid config")
    }

    #[test]
    fn drives_eq5_displacements_after_rate_limit() {
        let robot = Robot::paper_default();
        let mut a = act(ActuatorConfig::default());
        let q = [10.0, -5.0, 3.0, -2.0, 4.0];
        // 400 deg/s: 10 deg needs 25 ms.
        a.command(&q, 5, 0);
        let r = a.command(&q, 5, 100 * MS);
        assert_eq!(r.rejection, None);
        assert_eq!(r.output.q_cmd_deg, q);
        assert_eq!(r.output.cable_disp_mm, robot.cables().displacements_mm(&q));
        assert_eq!(r.output.flags, 0);
    }

    #[test]
    fn rate_limit_bounds_each_step() {
        let mut a = act(ActuatorConfig::default());
        a.command(&[0.0; 5], 5, 0);
        let r = a.command(&[50.0, 0.0, 0.0, 0.0, 0.0], 5, MS);
        assert!((r.output.q_cmd_deg[0] - 0.4).abs() < 1e-12, "{:?}", r.output.q_cmd_deg);
        assert_ne!(r.output.flags & MotorCommand::FLAG_CLAMPED, 0);
        assert_eq!(a.counters().rate_limited, 1);
    }

    #[test]
    fn nan_and_impossible_values_are_rejected_and_counted() {
        let mut a = act(ActuatorConfig::default());
        a.command(&[1.0, 0.0, 0.0, 0.0, 0.0], 5, 0);
        a.command(&[1.0, 0.0, 0.0, 0.0, 0.0], 5, 10 * MS);
        let r = a.command(&[f64::NAN, 0.0, 0.0, 0.0, 0.0], 5, 11 * MS);
        assert_eq!(r.rejection, Some(Rejection::NotFinite { joint: 1 }));
        assert_eq!(r.output.q_cmd_deg[0], 1.0, "holds the last safe command");
        assert_ne!(r.output.flags & MotorCommand::FLAG_HOLD, 0);
        let r = a.command(&[0.0, f64::INFINITY, 0.0, 0.0, 0.0], 5, 12 * MS);
        assert_eq!(r.rejection, Some(Rejection::NotFinite { joint: 2 }));
        let r = a.command(&[0.0, 0.0, 1e9, 0.0, 0.0], 5, 13 * MS);
        assert!(matches!(r.rejection, Some(Rejection::Impossible { joint: 3, .. })));
        let r = a.command(&[0.0; 5], 3, 14 * MS);
        assert!(matches!(r.rejection, Some(Rejection::WrongJointCount { got: 3, .. })));
        assert_eq!(a.counters().rejected(), 4);
        // And it goes on: a valid command is driven again.
        let r = a.command(&[1.0, 0.0, 0.0, 0.0, 0.0], 5, 15 * MS);
        assert_eq!(r.rejection, None);
    }

    #[test]
    fn out_of_range_clamps_or_rejects() {
        let mut a = act(ActuatorConfig::default());
        a.command(&[0.0; 5], 5, 0);
        let r = a.command(&[90.0, 0.0, 0.0, 0.0, 0.0], 5, 1000 * MS);
        assert_eq!(r.output.q_cmd_deg[0], 60.0);
        assert_ne!(r.output.flags & MotorCommand::FLAG_CLAMPED, 0);
        let mut b = act(ActuatorConfig {
            out_of_range: OutOfRange::Reject,
            ..Default::default()
        });
        b.command(&[0.0; 5], 5, 0);
        let r = b.command(&[90.0, 0.0, 0.0, 0.0, 0.0], 5, 1000 * MS);
        assert!(matches!(r.rejection, Some(Rejection::OutOfRange { joint: 1, .. })));
        assert_eq!(r.output.q_cmd_deg[0], 0.0);
        assert_eq!(b.counters().rejected_out_of_range, 1);
    }

    #[test]
    fn jaws_may_be_commanded_past_each_other_down_to_the_command_bound() {
        // The shipped robot lets a command overlap the jaws by 30° (its dead band keeps the
        // jaws themselves apart); beyond that the command is clamped or refused.
        let mut a = act(ActuatorConfig::default());
        a.command(&[0.0; 5], 5, 0);
        let crossed = [0.0, 0.0, 0.0, 10.0, -10.0];
        let r = a.command(&crossed, 5, 1000 * MS);
        assert_eq!(r.rejection, None);
        assert_eq!(r.output.q_cmd_deg, crossed);
        assert_eq!(r.output.flags & MotorCommand::FLAG_CLAMPED, 0);
        let r = a.command(&[0.0, 0.0, 0.0, 20.0, -20.0], 5, 2000 * MS);
        assert!((r.output.q_cmd_deg[4] - r.output.q_cmd_deg[3] + 30.0).abs() < 1e-9);
        assert_ne!(r.output.flags & MotorCommand::FLAG_CLAMPED, 0);
        let mut b = act(ActuatorConfig {
            out_of_range: OutOfRange::Reject,
            ..Default::default()
        });
        b.command(&[0.0; 5], 5, 0);
        let r = b.command(&[0.0, 0.0, 0.0, 20.0, -20.0], 5, 1000 * MS);
        assert!(matches!(r.rejection, Some(Rejection::OutOfRange { joint: 5, .. })));
    }

    #[test]
    fn watchdog_holds_then_resumes() {
        let mut a = act(ActuatorConfig::default()); // 20 ms
        assert_eq!(a.idle(0), None, "no command yet: nothing to hold");
        a.command(&[5.0, 0.0, 0.0, 0.0, 0.0], 5, 0);
        a.command(&[5.0, 0.0, 0.0, 0.0, 0.0], 5, 50 * MS);
        assert_eq!(a.idle(60 * MS), None);
        let h = a.idle(71 * MS).expect("stale: hold");
        assert_eq!(a.state(), ActuatorState::StaleHold);
        assert_eq!(h.q_cmd_deg[0], 5.0);
        assert_ne!(h.flags & MotorCommand::FLAG_HOLD, 0);
        assert!(a.idle(80 * MS).is_some(), "keeps sending the hold");
        assert_eq!(a.counters().stale_faults, 1, "one fault per episode");
        let r = a.command(&[6.0, 0.0, 0.0, 0.0, 0.0], 5, 90 * MS);
        assert_eq!(a.state(), ActuatorState::Running);
        assert_eq!(r.output.flags & MotorCommand::FLAG_HOLD, 0);
    }

    #[test]
    fn latched_stale_needs_release() {
        let mut a = act(ActuatorConfig {
            latch_on_stale: true,
            ..Default::default()
        });
        a.command(&[0.0; 5], 5, 0);
        a.idle(30 * MS).expect("stale");
        let r = a.command(&[1.0, 0.0, 0.0, 0.0, 0.0], 5, 31 * MS);
        assert_ne!(r.output.flags & MotorCommand::FLAG_HOLD, 0);
        let rel = SafetyCommand {
            command: SafetyCommand::RELEASE,
            ..Default::default()
        };
        assert!(a.safety(&rel, 32 * MS));
        let r = a.command(&[1.0, 0.0, 0.0, 0.0, 0.0], 5, 40 * MS);
        assert_eq!(r.output.flags & MotorCommand::FLAG_HOLD, 0);
    }

    #[test]
    fn estop_latches_until_release() {
        let mut a = act(ActuatorConfig::default());
        a.command(&[2.0, 0.0, 0.0, 0.0, 0.0], 5, 0);
        a.command(&[2.0, 0.0, 0.0, 0.0, 0.0], 5, 10 * MS);
        let stop = SafetyCommand {
            command: SafetyCommand::ESTOP,
            ..Default::default()
        };
        assert!(a.safety(&stop, 11 * MS));
        let r = a.command(&[30.0, 0.0, 0.0, 0.0, 0.0], 5, 12 * MS);
        assert_eq!(r.rejection, Some(Rejection::EStopLatched));
        assert_eq!(r.output.q_cmd_deg[0], 2.0);
        assert_ne!(r.output.flags & MotorCommand::FLAG_ESTOP, 0);
        assert!(a
            .idle(500 * MS)
            .is_some_and(|o| o.flags & MotorCommand::FLAG_ESTOP != 0));
        let bogus = SafetyCommand {
            command: 99,
            ..Default::default()
        };
        assert!(!a.safety(&bogus, 13 * MS));
        let rel = SafetyCommand {
            command: SafetyCommand::RELEASE,
            ..Default::default()
        };
        a.safety(&rel, 500 * MS + MS / 2);
        let r = a.command(&[30.0, 0.0, 0.0, 0.0, 0.0], 5, 501 * MS);
        assert_eq!(r.rejection, None);
        assert!((r.output.q_cmd_deg[0] - 2.4).abs() < 1e-9, "rate limited from the hold");
    }

    #[test]
    fn bad_config_names_the_field() {
        let e = Actuator::new(
            &Robot::paper_default(),
            &ActuatorConfig {
                stale_after_ms: -1.0,
                ..Default::default()
            },
            "sim.toml",
        )
        .unwrap_err();
        assert!(e.to_string().contains("stale_after_ms"), "{e}");
        let e = ActuatorConfig {
            max_rate_deg_s: Rate::PerJoint(vec![1.0, 2.0]),
            ..Default::default()
        }
        .validate("x")
        .unwrap_err();
        assert!(e.to_string().contains("max_rate_deg_s"), "{e}");
        let e: Result<ActuatorConfig, _> = toml::from_str("stale_after_ms = 5.0\nbogus = 1");
        assert!(e.is_err());
    }

    #[test]
    fn motor_command_layout() {
        let mut a = act(ActuatorConfig::default());
        let r = a.command(&[0.0; 5], 5, 0);
        let m = r.output.to_motor_command();
        assert_eq!(m.n_cables, 10);
        assert_eq!(&m.cable_disp_mm[..10], &r.output.cable_disp_mm);
        assert!(m.cable_disp_mm[10..].iter().all(|&v| v == 0.0));
    }
}
pub mod node;
pub mod serial;
