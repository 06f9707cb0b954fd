//! The e-stop protocol of a running pipeline, as `bowden estop` speaks it and any tool may: a
//! `SafetyCommand` (e-stop or release) on `bowden/safety`, a wake-up of its listeners, then the
//! named stage's `ComponentStatus` confirming the new state (`ESTOP`, or running again after a
//! release). The sample lives in the sender's shared memory, so the sender stays until the
//! confirmation or its time bound.

use crate::ports::{Input, IpcSettings, Output, PortContext, PortError, Wakeup};
use crate::stage::state;
use bowden_interfaces::{services, ComponentStatus, SafetyCommand};
use std::time::{Duration, Instant};

/// What to ask of the actuators.
#[derive(Debug, Clone, Copy, PartialEq, Eq, strum::Display)]
pub enum SafetyAction {
    #[strum(to_string = "e-stop")]
    Estop,
    #[strum(to_string = "release")]
    Release,
}

/// Why a safety command did not take effect.
#[derive(Debug, thiserror::Error)]
pub enum SafetyError {
    #[error(transparent)]
    Port(#[from] PortError),
    #[error("no actuator is listening on {service}")]
    NoListener { service: &'static str },
    #[error("stage `{stage}` did not confirm the {action} within {timeout_ms} ms")]
    NotConfirmed {
        stage: String,
        action: SafetyAction,
        timeout_ms: u64,
    },
}

/// A tool's connection to a pipeline's safety service and the stages' statuses.
pub struct SafetyLink {
    _ports: PortContext,
    statuses: Input<ComponentStatus>,
    out: Output<SafetyCommand>,
    wake: Wakeup,
}

impl SafetyLink {
    /// Opens the services of the pipeline under `settings` as iceoryx2 node `node_name`.
    pub fn open(node_name: &str, settings: &IpcSettings) -> Result<Self, SafetyError> {
        let ports = PortContext::new(node_name, settings)?;
        Ok(Self {
            statuses: ports.input::<ComponentStatus>(services::COMPONENT_STATUS, 256)?,
            out: ports.output::<SafetyCommand>(services::SAFETY)?,
            wake: ports.notifier(services::SAFETY)?,
            _ports: ports,
        })
    }

    /// Sends `action` and wakes the listeners; returns how many subscribers it reached (none is
    /// an error: nothing would stop).
    pub fn send(&mut self, action: SafetyAction) -> Result<usize, SafetyError> {
        let cmd = SafetyCommand {
            command: match action {
                SafetyAction::Estop => SafetyCommand::ESTOP,
                SafetyAction::Release => SafetyCommand::RELEASE,
            },
            ..Default::default()
        };
        let n = self.out.publish(0, crate::sys::monotonic_ns(), cmd)?;
        self.wake.notify()?;
        if n == 0 {
            return Err(SafetyError::NoListener {
                service: services::SAFETY,
            });
        }
        Ok(n)
    }

    /// Waits until stage `stage` reports the state `action` leads to (e-stop: `ESTOP`; release:
    /// running or degraded), at most `timeout`.
    pub fn confirm(&mut self, stage: &str, action: SafetyAction, timeout: Duration) -> Result<(), SafetyError> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(st) = self.statuses.recv() {
                if st.name() != stage {
                    continue;
                }
                let confirmed = match action {
                    SafetyAction::Release => st.state == state::RUNNING || st.state == state::DEGRADED,
                    SafetyAction::Estop => st.state == state::ESTOP,
                };
                if confirmed {
                    return Ok(());
                }
            }
            if Instant::now() >= deadline {
                return Err(SafetyError::NotConfirmed {
                    stage: stage.to_string(),
                    action,
                    timeout_ms: timeout.as_millis() as u64,
                });
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}
