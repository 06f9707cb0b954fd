//! `configs/robot.toml`: geometry, joint limits and cable routing, validated on load.

use serde::Deserialize;
use std::path::Path;

use crate::N_JOINTS;

pub use bowden_interfaces::config::ConfigError;

/// Table I of the paper: the circular flexure hinge.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HingeConfig {
    /// Height between notches: h of eq. (1) and H of eq. (5).
    pub h_mm: f64,
    /// Thickness of the disk: l of eq. (1).
    pub l_mm: f64,
    pub round_radius_mm: f64,
    pub front_thickness_mm: f64,
    pub side_thickness_mm: f64,
    /// Outer radius of a module (the body's radius, used by the renderer as occluder).
    pub module_radius_mm: f64,
    /// Largest bend one hinge takes (FEA, §III-A). Joint limits beyond n·this are refused.
    pub max_hinge_bend_deg: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SegmentConfig {
    pub modules: u32,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ForcepsConfig {
    /// From the end of segment 2 to the jaw pivot, along the axis.
    pub wrist_length_mm: f64,
    /// Pivot to jaw tip (d_fcps of eq. 13).
    pub jaw_length_mm: f64,
    /// Jaw pulley radius: a forceps cable moves radius·angle.
    pub pulley_radius_mm: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LimitsConfig {
    pub q_min_deg: [f64; N_JOINTS],
    pub q_max_deg: [f64; N_JOINTS],
    /// Smallest physical jaw opening q5 − q4 (the jaws cannot pass through each other).
    /// Default 0.
    #[serde(default)]
    pub min_jaw_opening_deg: f64,
    /// Smallest *commanded* jaw opening q5_cmd − q4_cmd. A command is a drive position, not a
    /// jaw position: the cables' dead band keeps the physical jaws several degrees behind it,
    /// so a compensator must be able to command the jaws past each other (as a grasper does
    /// to grip), while contact stops the physical jaws at `min_jaw_opening_deg`. This bounds
    /// how far (the grip the drive may build). Default: `min_jaw_opening_deg` (no overlap).
    #[serde(default)]
    pub min_jaw_command_opening_deg: Option<f64>,
}

impl LimitsConfig {
    /// The commanded-opening bound in force (see `min_jaw_command_opening_deg`).
    pub fn jaw_command_opening_min_deg(&self) -> f64 {
        self.min_jaw_command_opening_deg.unwrap_or(self.min_jaw_opening_deg)
    }
}

/// One actuation cable: which joint it drives and where it runs through the modules.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CableConfig {
    pub name: String,
    /// 1-based joint this cable drives (1..=5).
    pub joint: usize,
    /// Offset from the neutral axis along the pitch bend direction, mm (positive = inside of
    /// a positive pitch bend).
    pub offset_pitch_mm: f64,
    /// Offset along the yaw bend direction, mm.
    pub offset_yaw_mm: f64,
    /// For forceps cables: +1 if pulling drives the jaw positive, −1 if negative.
    #[serde(default)]
    pub pulley_sign: f64,
}

/// The whole robot description.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    pub name: String,
    pub hinge: HingeConfig,
    pub segment1: SegmentConfig,
    pub segment2: SegmentConfig,
    pub forceps: ForcepsConfig,
    pub limits: LimitsConfig,
    pub cables: Vec<CableConfig>,
}

impl RobotConfig {
    /// Reads and validates a robot file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            origin: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses and validates TOML text; `path` is only used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let cfg: RobotConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            origin: path.display().to_string(),
            message: e.to_string().replace('\n', " "),
        })?;
        cfg.validate(path)?;
        Ok(cfg)
    }

    /// Long by design (over 120 lines): one check per field, in the file's order, so every
    /// rule of the schema is in one place beside its struct; each check is a few lines and
    /// shares nothing with the next, so helpers would only scatter the schema.
    // Long: one flat list of independent checks, each naming its field.
    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |field: &str, problem: String| ConfigError::Invalid {
            origin: path.display().to_string(),
            field: field.to_string(),
            problem,
        };
        let positive = [
            ("hinge.h_mm", self.hinge.h_mm),
            ("hinge.l_mm", self.hinge.l_mm),
            ("hinge.module_radius_mm", self.hinge.module_radius_mm),
            ("hinge.max_hinge_bend_deg", self.hinge.max_hinge_bend_deg),
            ("forceps.jaw_length_mm", self.forceps.jaw_length_mm),
            ("forceps.pulley_radius_mm", self.forceps.pulley_radius_mm),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(field, format!("must be a positive number, got {v}")));
            }
        }
        if !(self.forceps.wrist_length_mm.is_finite() && self.forceps.wrist_length_mm >= 0.0) {
            return Err(bad(
                "forceps.wrist_length_mm",
                format!("must be ≥ 0, got {}", self.forceps.wrist_length_mm),
            ));
        }
        for (field, seg) in [
            ("segment1.modules", &self.segment1),
            ("segment2.modules", &self.segment2),
        ] {
            if seg.modules == 0 || seg.modules > 200 {
                return Err(bad(field, format!("must be 1..=200, got {}", seg.modules)));
            }
        }
        for j in 0..N_JOINTS {
            let (lo, hi) = (self.limits.q_min_deg[j], self.limits.q_max_deg[j]);
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(bad(
                    &format!("limits.q_min_deg[{j}]/q_max_deg[{j}]"),
                    format!("need finite min < max, got {lo} .. {hi}"),
                ));
            }
            if lo.abs() >= 180.0 || hi.abs() >= 180.0 {
                return Err(bad(
                    &format!("limits (q{})", j + 1),
                    format!("must lie inside (-180, 180) deg, got {lo} .. {hi}"),
                ));
            }
        }
        // A segment cannot bend further than its hinges allow.
        let max_bend = |modules: u32| modules as f64 * self.hinge.max_hinge_bend_deg;
        for (j, modules) in [
            (0, self.segment1.modules),
            (1, self.segment1.modules),
            (2, self.segment2.modules),
        ] {
            let m = self.limits.q_min_deg[j].abs().max(self.limits.q_max_deg[j].abs());
            if m > max_bend(modules) + 1e-9 {
                return Err(bad(
                    &format!("limits (q{})", j + 1),
                    format!(
                        "{m} deg exceeds {modules} hinges × {} deg = {} deg",
                        self.hinge.max_hinge_bend_deg,
                        max_bend(modules)
                    ),
                ));
            }
        }
        if !self.limits.min_jaw_opening_deg.is_finite() {
            return Err(bad("limits.min_jaw_opening_deg", "must be finite".into()));
        }
        if let Some(c) = self.limits.min_jaw_command_opening_deg {
            if !c.is_finite() || c > self.limits.min_jaw_opening_deg {
                return Err(bad(
                    "limits.min_jaw_command_opening_deg",
                    format!(
                        "{c} deg: must be finite and at most min_jaw_opening_deg = {} deg \
                         (a command may overlap the jaws, the jaws themselves may not)",
                        self.limits.min_jaw_opening_deg
                    ),
                ));
            }
        }
        if self.cables.len() != 2 * N_JOINTS {
            return Err(bad(
                "cables",
                format!(
                    "need {} cables (an antagonistic pair per joint), got {}",
                    2 * N_JOINTS,
                    self.cables.len()
                ),
            ));
        }
        for j in 1..=N_JOINTS {
            let pair: Vec<&CableConfig> = self.cables.iter().filter(|c| c.joint == j).collect();
            if pair.len() != 2 {
                return Err(bad(
                    "cables",
                    format!("joint {j} needs exactly 2 cables, got {}", pair.len()),
                ));
            }
        }
        for (i, c) in self.cables.iter().enumerate() {
            let f = |name: &str| format!("cables[{i}] ({}).{name}", c.name);
            if !(1..=N_JOINTS).contains(&c.joint) {
                return Err(bad(&f("joint"), format!("must be 1..={N_JOINTS}, got {}", c.joint)));
            }
            for (name, v) in [
                ("offset_pitch_mm", c.offset_pitch_mm),
                ("offset_yaw_mm", c.offset_yaw_mm),
            ] {
                if !v.is_finite() || v.abs() >= self.hinge.module_radius_mm {
                    return Err(bad(
                        &f(name),
                        format!(
                            "must be finite and inside the module radius {} mm, got {v}",
                            self.hinge.module_radius_mm
                        ),
                    ));
                }
            }
            if c.joint >= 4 && c.pulley_sign.abs() != 1.0 {
                return Err(bad(
                    &f("pulley_sign"),
                    format!("forceps cables need ±1, got {}", c.pulley_sign),
                ));
            }
        }
        // Each pair must be antagonistic in its own bend direction, or the joint is not drivable.
        for j in 1..=N_JOINTS {
            let pair: Vec<&CableConfig> = self.cables.iter().filter(|c| c.joint == j).collect();
            let (a, b) = (pair[0], pair[1]);
            let lever = match j {
                1 | 3 => a.offset_pitch_mm - b.offset_pitch_mm,
                2 => a.offset_yaw_mm - b.offset_yaw_mm,
                _ => a.pulley_sign - b.pulley_sign,
            };
            if lever.abs() < 1e-6 {
                return Err(bad(
                    "cables",
                    format!(
                        "the pair of joint {j} ({}, {}) is not antagonistic: it cannot drive the joint",
                        a.name, b.name
                    ),
                ));
            }
        }
        Ok(())
    }
}
