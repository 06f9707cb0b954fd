//! The robot-state monitor: the actuator watches the state the robot reports (the plant process
//! in simulation, a driver process on hardware) and holds safely when it cannot be trusted —
//! ros2_control's controller manager deactivating hardware on a read error, an IEC 61508 sensor
//! diagnostic going to a safe state. Every state is checked where the actuator consumes it:
//!
//! - **finite**: a NaN or infinite joint angle (a broken encoder, a diverged model);
//! - **plausible**: inside the robot's joint ranges widened by `range_margin_deg` (a reading far
//!   outside is a sensor or model fault, not a pose);
//! - **complete**: the robot file's joint count;
//! - **fresh**: the newest state is at most `max_age_ms` old (a silent or hung driver), timed on
//!   the actuator's clock (simulated in lockstep, so the decision is reproducible);
//! - **without gaps**: consecutive sequence numbers; a restarted publisher (its numbers start
//!   again) is a gap too, because states were lost while it was down.
//!
//! A violation is a fault: the bad state is counted by class, a fault *episode* begins (one per
//! stretch of untrusted states, with the code of what began it for the status sample), and the
//! actuator enters [`crate::ActuatorState::FaultHold`] in the same step. The episode ends with
//! the next valid, fresh state. Motion resumes only
//! explicitly ([`Resume`]): after a person's release (`bowden estop --release`), which is refused
//! while the robot still reports no valid state, or automatically after N good states in a row.
//! Nothing here allocates.

use bowden_interfaces::{fault, PlantState, MAX_JOINTS};
use bowden_kinematics::{LimitError, Robot, N_JOINTS};
use serde::Deserialize;

/// How motion resumes after a robot-state fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(
    untagged,
    expecting = "expected `resume = \"release\"` or `resume = { after_good = N }` (N ≥ 1)"
)]
pub enum Resume {
    /// Only by a person: a `SafetyCommand::RELEASE` (`bowden estop --release`).
    #[default]
    #[serde(with = "release_word")]
    Release,
    /// By itself, after this many consecutive good states (and while they stay fresh).
    AfterGood { after_good: u64 },
}

mod release_word {
    pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<(), D::Error> {
        let s = <String as serde::Deserialize>::deserialize(d)?;
        if s == "release" {
            Ok(())
        } else {
            Err(serde::de::Error::custom(format!("unknown resume `{s}`")))
        }
    }
}

/// `[node.params.robot_state]` of the actuator.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MonitorConfig {
    /// The newest robot state may be this old before it is a fault, ms. Default: 40 ms or 3
    /// periods of the state's producer, whichever is longer — 40 periods of the 1 kHz plant,
    /// which keeps a hung driver's detection under 50 ms; 300 ms for `evaluate`'s 10 Hz
    /// lockstep. It must be longer than one period of the producer.
    #[serde(default)]
    pub max_age_ms: Option<f64>,
    /// Joint angles beyond the ranges widened by this are implausible, deg.
    #[serde(default = "default_margin_deg")]
    pub range_margin_deg: f64,
    #[serde(default)]
    pub resume: Resume,
}

/// The shortest default age bound, ms.
pub const MIN_DEFAULT_MAX_AGE_MS: f64 = 40.0;
fn default_margin_deg() -> f64 {
    10.0
}

impl Default for MonitorConfig {
    fn default() -> Self {
        Self {
            max_age_ms: None,
            range_margin_deg: default_margin_deg(),
            resume: Resume::Release,
        }
    }
}

impl MonitorConfig {
    /// Checks every field; the error names it.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if let Some(a) = self.max_age_ms {
            if !(a.is_finite() && a > 0.0) {
                return Err(("robot_state.max_age_ms", format!("must be a positive number, got {a}")));
            }
        }
        if !(self.range_margin_deg.is_finite() && self.range_margin_deg >= 0.0) {
            return Err((
                "robot_state.range_margin_deg",
                format!("must be a non-negative number, got {}", self.range_margin_deg),
            ));
        }
        if self.resume == (Resume::AfterGood { after_good: 0 }) {
            return Err(("robot_state.resume", "after_good must be at least 1".into()));
        }
        Ok(())
    }
}

/// Faults by class, for status samples, summaries and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MonitorCounters {
    /// States received.
    pub states: u64,
    pub not_finite: u64,
    pub implausible: u64,
    pub joint_count: u64,
    /// Stale episodes (one per stretch without a fresh state).
    pub stale: u64,
    /// States missing between two received ones.
    pub missing: u64,
    /// Publisher restarts seen (sequence numbers started again).
    pub restarts: u64,
}

/// One fault the monitor found, with the time it was found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateFault {
    /// `bowden_interfaces::fault` code.
    pub code: u32,
    /// Joint (1-based) and value, for the value faults.
    pub joint: Option<(usize, f64)>,
}

/// See the module documentation.
#[derive(Debug, Clone)]
pub struct StateMonitor {
    robot: Robot,
    margin_deg: f64,
    max_age_ns: u64,
    resume: Resume,
    last_seq: Option<u64>,
    /// `t_origin_ns` of the newest state received.
    t_last_ns: Option<u64>,
    /// First check: the start of the wait for the first state.
    t_start_ns: Option<u64>,
    stale: bool,
    good_streak: u64,
    /// Inside a fault episode (since its first bad state, until a valid fresh one).
    in_episode: bool,
    episodes: u64,
    /// What began the last episode.
    episode_code: u32,
    counters: MonitorCounters,
}

impl StateMonitor {
    /// `state_period_ns`: how often the robot's state is published (the producer's period).
    /// Refuses an explicit age bound that a healthy producer cannot meet.
    pub fn new(robot: &Robot, cfg: &MonitorConfig, state_period_ns: u64) -> Result<Self, (&'static str, String)> {
        let max_age_ns = match cfg.max_age_ms {
            Some(ms) => {
                let ns = (ms * 1e6) as u64;
                if ns <= state_period_ns {
                    return Err((
                        "robot_state.max_age_ms",
                        format!(
                            "{ms} ms is not longer than the robot state's period ({} ms): every state would be stale",
                            state_period_ns as f64 / 1e6
                        ),
                    ));
                }
                ns
            }
            None => ((MIN_DEFAULT_MAX_AGE_MS * 1e6) as u64).max(3 * state_period_ns),
        };
        Ok(Self {
            robot: robot.clone(),
            margin_deg: cfg.range_margin_deg,
            max_age_ns,
            resume: cfg.resume,
            last_seq: None,
            t_last_ns: None,
            t_start_ns: None,
            stale: false,
            good_streak: 0,
            in_episode: false,
            episodes: 0,
            episode_code: fault::NONE,
            counters: MonitorCounters::default(),
        })
    }

    /// The age bound in use, ns.
    pub fn max_age_ns(&self) -> u64 {
        self.max_age_ns
    }

    pub fn counters(&self) -> MonitorCounters {
        self.counters
    }

    /// Fault episodes: stretches of untrusted robot state, however many bad states each held.
    pub fn faults(&self) -> u64 {
        self.episodes
    }

    /// States rejected (not finite, implausible, wrong joint count, after a gap).
    pub fn rejected(&self) -> u64 {
        let c = &self.counters;
        c.not_finite + c.implausible + c.joint_count
    }

    /// The code of what began the last fault episode (`fault::NONE` before any).
    pub fn episode_code(&self) -> u32 {
        self.episode_code
    }

    pub fn resume(&self) -> Resume {
        self.resume
    }

    /// Consecutive good states since the last fault.
    pub fn good_streak(&self) -> u64 {
        self.good_streak
    }

    /// The robot reports valid, fresh states now (what a release requires).
    pub fn healthy(&self) -> bool {
        self.good_streak > 0 && !self.stale
    }

    /// A state arrived: checks it. The newest state's time counts for freshness only when it
    /// is valid (a driver that keeps publishing NaN is not a live robot).
    pub fn observe(&mut self, s: &PlantState) -> Result<(), StateFault> {
        self.counters.states += 1;
        let seq = s.header.seq;
        let gap = match self.last_seq {
            Some(l) if seq == l.wrapping_add(1) => None,
            Some(l) if seq > l => {
                self.counters.missing += seq - l - 1;
                Some(())
            }
            Some(_) => {
                self.counters.restarts += 1;
                Some(())
            }
            None => None,
        };
        self.last_seq = Some(seq);
        // A gap is a fault about the states that were lost; the state itself is checked as
        // any other (a valid one is the first good state of the new stretch).
        let gap_fault = gap.map(|()| self.fail(fault::STATE_GAP, None));
        if s.n_joints as usize != N_JOINTS {
            self.counters.joint_count += 1;
            return Err(self.fail(fault::STATE_JOINT_COUNT, None));
        }
        let q: [f64; N_JOINTS] = core::array::from_fn(|j| s.q_phy_deg[j.min(MAX_JOINTS - 1)]);
        match self.robot.check_plausible(&q, self.margin_deg) {
            Ok(()) => {}
            Err(LimitError::NotFinite { joint, value_deg }) => {
                self.counters.not_finite += 1;
                return Err(self.fail(fault::STATE_NOT_FINITE, Some((joint, value_deg))));
            }
            Err(LimitError::OutOfRange { joint, value_deg, .. }) => {
                self.counters.implausible += 1;
                return Err(self.fail(fault::STATE_IMPLAUSIBLE, Some((joint, value_deg))));
            }
            Err(LimitError::JawsCross { opening_deg, .. }) => {
                self.counters.implausible += 1;
                return Err(self.fail(fault::STATE_IMPLAUSIBLE, Some((5, opening_deg))));
            }
        }
        self.t_last_ns = Some(
            self.t_last_ns
                .map_or(s.header.t_origin_ns, |t| t.max(s.header.t_origin_ns)),
        );
        self.stale = false;
        self.in_episode = false;
        self.good_streak += 1;
        gap_fault.map_or(Ok(()), Err)
    }

    /// Freshness at `t_now_ns` (the actuator's clock): a fault once per stale stretch; `Ok`
    /// while the newest valid state is young enough (or, before the first state, while the
    /// first wait is shorter than the bound).
    pub fn check_age(&mut self, t_now_ns: u64) -> Result<(), StateFault> {
        let since = *self.t_start_ns.get_or_insert(t_now_ns);
        let t_ref = self.t_last_ns.unwrap_or(since);
        if t_now_ns.saturating_sub(t_ref) <= self.max_age_ns {
            return Ok(());
        }
        if self.stale {
            // Still stale: reported once, the hold goes on.
            return Err(StateFault {
                code: fault::STATE_STALE,
                joint: None,
            });
        }
        self.stale = true;
        self.counters.stale += 1;
        Err(self.fail(fault::STATE_STALE, None))
    }

    fn fail(&mut self, code: u32, joint: Option<(usize, f64)>) -> StateFault {
        self.good_streak = 0;
        if !self.in_episode {
            self.in_episode = true;
            self.episodes += 1;
            self.episode_code = code;
        }
        StateFault { code, joint }
    }

    /// May motion resume by itself now?
    pub fn may_resume(&self) -> bool {
        match self.resume {
            Resume::Release => false,
            Resume::AfterGood { after_good } => !self.stale && self.good_streak >= after_good,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn state(seq: u64, t_ms: u64, q: [f64; 5]) -> PlantState {
        let mut s = PlantState {
            n_joints: 5,
            ..Default::default()
        };
        s.header.seq = seq;
        s.header.t_origin_ns = t_ms * MS;
        s.q_phy_deg[..5].copy_from_slice(&q);
        s
    }

    fn mon(resume: Resume) -> StateMonitor {
        StateMonitor::new(
            &Robot::paper_default(),
            &MonitorConfig {
                resume,
                ..Default::default()
            },
            MS,
        )
        .unwrap()
    }

    #[test]
    fn each_class_of_bad_state_is_a_counted_fault() {
        let mut m = mon(Resume::Release);
        assert!(m.observe(&state(0, 0, [1.0; 5])).is_ok());
        let f = m.observe(&state(1, 1, [f64::NAN, 0.0, 0.0, 0.0, 0.0])).unwrap_err();
        assert_eq!((f.code, f.joint.map(|j| j.0)), (fault::STATE_NOT_FINITE, Some(1)));
        let f = m.observe(&state(2, 2, [0.0, 0.0, 900.0, 0.0, 0.0])).unwrap_err();
        assert_eq!((f.code, f.joint), (fault::STATE_IMPLAUSIBLE, Some((3, 900.0))));
        // 65° on joint 1 (range ±60°) is inside the 10° margin: a pose, not a fault.
        assert!(m.observe(&state(3, 3, [65.0, 0.0, 0.0, 0.0, 0.0])).is_ok());
        let mut bad_count = state(4, 4, [0.0; 5]);
        bad_count.n_joints = 3;
        assert_eq!(m.observe(&bad_count).unwrap_err().code, fault::STATE_JOINT_COUNT);
        assert_eq!(m.observe(&state(9, 9, [0.0; 5])).unwrap_err().code, fault::STATE_GAP);
        assert_eq!(m.observe(&state(0, 10, [0.0; 5])).unwrap_err().code, fault::STATE_GAP);
        let c = m.counters();
        assert_eq!(
            (c.not_finite, c.implausible, c.joint_count, c.missing, c.restarts),
            (1, 1, 1, 4, 1)
        );
        // One episode from the NaN to the next valid state, one from the joint count to the
        // valid state after the gap, one for the restart.
        assert_eq!(m.faults(), 3);
        assert_eq!(m.episode_code(), fault::STATE_GAP);
        assert_eq!(m.good_streak(), 1, "the first state after a restart counts as good");
        assert_eq!(m.rejected(), 3);
    }

    #[test]
    fn stale_is_one_fault_per_stretch_and_clears_with_a_valid_state() {
        let mut m = mon(Resume::Release);
        // Before the first state: the bound runs from the first check.
        assert!(m.check_age(100 * MS).is_ok());
        assert!(m.check_age(140 * MS).is_ok());
        assert_eq!(m.check_age(141 * MS).unwrap_err().code, fault::STATE_STALE);
        assert!(m.check_age(150 * MS).is_err());
        assert_eq!(m.counters().stale, 1, "one episode");
        m.observe(&state(0, 150, [0.0; 5])).unwrap();
        assert!(m.check_age(151 * MS).is_ok());
        // NaN states do not keep the robot alive.
        for k in 1..=50 {
            let _ = m.observe(&state(k, 150 + k, [f64::NAN; 5]));
        }
        assert!(m.check_age(200 * MS).is_err());
        assert_eq!(m.counters().stale, 2);
    }

    #[test]
    fn resume_needs_n_good_states_or_a_release() {
        let mut m = mon(Resume::AfterGood { after_good: 3 });
        m.observe(&state(0, 0, [0.0; 5])).unwrap();
        m.observe(&state(1, 1, [f64::NAN; 5])).unwrap_err();
        assert!(!m.may_resume() && !m.healthy());
        m.observe(&state(2, 2, [0.0; 5])).unwrap();
        m.observe(&state(3, 3, [0.0; 5])).unwrap();
        assert!(!m.may_resume() && m.healthy());
        m.observe(&state(4, 4, [0.0; 5])).unwrap();
        assert!(m.may_resume());
        let mut r = mon(Resume::Release);
        for k in 0..100 {
            r.observe(&state(k, k, [0.0; 5])).unwrap();
        }
        assert!(!r.may_resume(), "release only: never by itself");
    }

    #[test]
    fn config_is_validated_and_parsed() {
        let c: MonitorConfig = toml::from_str("resume = { after_good = 5 }\nmax_age_ms = 10").unwrap();
        assert_eq!(c.resume, Resume::AfterGood { after_good: 5 });
        let robot = Robot::paper_default();
        // 10 ms against a 1 kHz state; refused against a 10 Hz one; the default follows the period.
        assert_eq!(StateMonitor::new(&robot, &c, MS).unwrap().max_age_ns(), 10 * MS);
        assert_eq!(
            StateMonitor::new(&robot, &c, 100 * MS).unwrap_err().0,
            "robot_state.max_age_ms"
        );
        let d = MonitorConfig::default();
        assert_eq!(StateMonitor::new(&robot, &d, MS).unwrap().max_age_ns(), 40 * MS);
        assert_eq!(StateMonitor::new(&robot, &d, 100 * MS).unwrap().max_age_ns(), 300 * MS);
        let c: MonitorConfig = toml::from_str("resume = \"release\"").unwrap();
        assert_eq!(c.resume, Resume::Release);
        assert!(toml::from_str::<MonitorConfig>("resume = \"auto\"").is_err());
        let bad = MonitorConfig {
            max_age_ms: Some(0.0),
            ..Default::default()
        };
        assert_eq!(bad.validate().unwrap_err().0, "robot_state.max_age_ms");
        let bad = MonitorConfig {
            resume: Resume::AfterGood { after_good: 0 },
            ..Default::default()
        };
        assert!(bad.validate().is_err());
    }
}
