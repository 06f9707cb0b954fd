//! Kinematics of the paper's flexure-hinge continuum manipulator (Park et al., RA-L 2024,
//! §III): eq. (1) hinge length, eq. (2) modified-DH transforms (Table II) chained per
//! module, per segment and through the forceps to the end-effector (eq. 3), a damped
//! Newton–Raphson inverse kinematics (eq. 4), and the cable drive equation (5) with the
//! decoupling of the distal cables, plus its inverse.
//!
//! Frames: the manipulator axis is the base x axis; q1 (segment-1 pitch) and q3
//! (segment-2 pitch) bend in the base x–z plane, q2 (segment-1 yaw) in the x–y plane; the
//! jaws rotate about the distal z axis. Jaw and end-effector frames follow the paper's
//! marker convention (eq. 8–12): x = jaw rotation axis, z = along the jaw, y = z × x.
//!
//! Joint vectors are `[f64; 5]` in degrees at the API; radians inside.

pub mod cables;
pub mod config;
pub mod fk;
pub mod ik;
pub mod markers;

pub use cables::CableModel;
pub use config::{ConfigError, RobotConfig};
pub use fk::{dh_transform, hinge_length_tr, pose_distance, FkResult, Pose};
pub use ik::{IkError, IkOptions, IkSolution};

/// Number of joints of this manipulator: q1..q5.
pub const N_JOINTS: usize = 5;
/// Number of actuation cables w1..w10.
pub const N_CABLES: usize = 10;
/// Joint names for reports.
pub const JOINT_NAMES: [&str; N_JOINTS] = ["q1", "q2", "q3", "q4", "q5"];

/// A joint configuration in degrees: q1..q5.
pub type JointsDeg = [f64; N_JOINTS];

/// A joint value outside what the robot can do.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LimitError {
    #[error("q{joint} = {value_deg} deg is not a finite number")]
    NotFinite { joint: usize, value_deg: f64 },
    #[error("q{joint} = {value_deg} deg is outside the joint limits [{min_deg}, {max_deg}]")]
    OutOfRange {
        joint: usize,
        value_deg: f64,
        min_deg: f64,
        max_deg: f64,
    },
    #[error("jaw opening q5 − q4 = {opening_deg} deg is below the minimum {min_deg} deg (the jaws would cross)")]
    JawsCross { opening_deg: f64, min_deg: f64 },
}

/// The manipulator: its configuration and the models computed from it.
#[derive(Debug, Clone)]
pub struct Robot {
    pub config: RobotConfig,
    cables: CableModel,
}

impl Robot {
    pub fn new(config: RobotConfig) -> Self {
        let cables = CableModel::new(&config);
        Self { config, cables }
    }

    /// Loads `configs/robot.toml` (or another robot file).
    pub fn load(path: impl AsRef<std::path::Path>) -> Result<Self, ConfigError> {
        Ok(Self::new(RobotConfig::load(path)?))
    }

    /// The robot file `path`, or the shipped robot when there is none (a pipeline's
    /// `[runtime] robot`).
    pub fn load_or_paper(path: Option<&std::path::Path>) -> Result<Self, ConfigError> {
        match path {
            Some(p) => Self::load(p),
            None => Ok(Self::paper_default()),
        }
    }

    /// The robot the repository ships (`configs/robot.toml`, embedded at build time), so
    /// tests and tools run without a path.
    pub fn paper_default() -> Self {
        let text = include_str!("../../../configs/robot.toml");
        Self::new(
            RobotConfig::parse(text, std::path::Path::new("configs/robot.toml"))
                .expect("the shipped configs/robot.toml is valid"),
        )
    }

    pub fn cables(&self) -> &CableModel {
        &self.cables
    }

    /// Checks a physical joint vector against finiteness, joint limits and jaw crossing.
    pub fn check_limits(&self, q_deg: &JointsDeg) -> Result<(), LimitError> {
        self.check_with_opening(q_deg, self.config.limits.min_jaw_opening_deg)
    }

    /// Checks that a *measured* or simulated joint vector is physically plausible: finite and
    /// inside the joint ranges widened by `margin_deg` on each side (a joint overshoots its
    /// nominal range a little; a reading far outside it is a sensor or model fault, not a pose).
    pub fn check_plausible(&self, q_deg: &JointsDeg, margin_deg: f64) -> Result<(), LimitError> {
        let lim = &self.config.limits;
        for (j, &v) in q_deg.iter().enumerate() {
            if !v.is_finite() {
                return Err(LimitError::NotFinite {
                    joint: j + 1,
                    value_deg: v,
                });
            }
            let (lo, hi) = (lim.q_min_deg[j] - margin_deg, lim.q_max_deg[j] + margin_deg);
            if v < lo || v > hi {
                return Err(LimitError::OutOfRange {
                    joint: j + 1,
                    value_deg: v,
                    min_deg: lo,
                    max_deg: hi,
                });
            }
        }
        Ok(())
    }

    /// Checks a joint *command* (a drive position): the joint ranges as [`Self::check_limits`],
    /// the jaw opening against the commanded bound `min_jaw_command_opening_deg`.
    pub fn check_command_limits(&self, q_cmd_deg: &JointsDeg) -> Result<(), LimitError> {
        self.check_with_opening(q_cmd_deg, self.config.limits.jaw_command_opening_min_deg())
    }

    fn check_with_opening(&self, q_deg: &JointsDeg, min_opening_deg: f64) -> Result<(), LimitError> {
        let lim = &self.config.limits;
        for (j, &v) in q_deg.iter().enumerate() {
            if !v.is_finite() {
                return Err(LimitError::NotFinite {
                    joint: j + 1,
                    value_deg: v,
                });
            }
            if v < lim.q_min_deg[j] || v > lim.q_max_deg[j] {
                return Err(LimitError::OutOfRange {
                    joint: j + 1,
                    value_deg: v,
                    min_deg: lim.q_min_deg[j],
                    max_deg: lim.q_max_deg[j],
                });
            }
        }
        let opening = q_deg[4] - q_deg[3];
        if opening < min_opening_deg {
            return Err(LimitError::JawsCross {
                opening_deg: opening,
                min_deg: min_opening_deg,
            });
        }
        Ok(())
    }

    /// Clamps a physical joint vector into the limits (and opens crossed jaws symmetrically).
    pub fn clamp_to_limits(&self, q_deg: &JointsDeg) -> JointsDeg {
        self.clamp_with_opening(q_deg, self.config.limits.min_jaw_opening_deg)
    }

    /// Clamps a joint command into the command limits (see [`Self::check_command_limits`]).
    pub fn clamp_command_to_limits(&self, q_cmd_deg: &JointsDeg) -> JointsDeg {
        self.clamp_with_opening(q_cmd_deg, self.config.limits.jaw_command_opening_min_deg())
    }

    fn clamp_with_opening(&self, q_deg: &JointsDeg, min_opening_deg: f64) -> JointsDeg {
        let lim = &self.config.limits;
        let mut q = *q_deg;
        for ((v, lo), hi) in q.iter_mut().zip(&lim.q_min_deg).zip(&lim.q_max_deg) {
            *v = v.clamp(*lo, *hi);
        }
        let opening = q[4] - q[3];
        if opening < min_opening_deg {
            let mid = 0.5 * (q[3] + q[4]);
            let half = 0.5 * min_opening_deg;
            q[3] = (mid - half).clamp(lim.q_min_deg[3], lim.q_max_deg[3]);
            q[4] = (mid + half).clamp(lim.q_min_deg[4], lim.q_max_deg[4]);
        }
        q
    }

    /// Length of the straight manipulator from base to jaw tip (all joints zero), mm.
    pub fn straight_length_mm(&self) -> f64 {
        let c = &self.config;
        let hinge = c.hinge.l_mm + c.hinge.h_mm; // eq. (1) at θ = 0
        let seg1 = 2.0 * c.segment1.modules as f64 * hinge;
        let seg2 = c.segment2.modules as f64 * hinge;
        seg1 + seg2 + c.forceps.wrist_length_mm + c.forceps.jaw_length_mm
    }
}

/// sin(x)/x with its exact limit at 0 (Taylor series near 0, so no cancellation or NaN).
#[inline]
pub fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        let x2 = x * x;
        1.0 - x2 / 6.0 + x2 * x2 / 120.0
    } else {
        x.sin() / x
    }
}

/// d/dx sinc(x), exact at 0.
#[inline]
pub fn sinc_derivative(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        let x2 = x * x;
        -x / 3.0 + x * x2 / 30.0
    } else {
        (x * x.cos() - x.sin()) / (x * x)
    }
}
