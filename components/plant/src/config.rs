//! `configs/plant.toml`: the physical parameters of the simulated tendon-sheath drive,
//! validated on load. A second robot (another sheath routing, other cables) is another file.
//!
//! The top-level `family` key picks the hysteresis model (see [`FamilyKind`]); each family has
//! its own table (`[hysteresis]` for `capstan`, `[bouc_wen]`, `[lugre]`, `[preisach]`),
//! required when that family is selected and refused otherwise. The other tables describe the
//! drive and the joints and are shared: every family reads `[joints]`, `[cables]`,
//! `[dynamics]`, `[drift]`, `[variation]` and `[command]`; `[sheath]` and `[body]` set the
//! friction of the cable-space families (`bouc-wen` and `preisach` read only
//! `sheath.length_mm`, for the cables' compliance).

use serde::{Deserialize, Serialize};
use std::path::Path;

use bowden_kinematics::{N_CABLES, N_JOINTS};

use crate::families::preisach;

/// Largest number of play operators per cable (the state is a fixed array: no allocation).
pub const MAX_PLAYS: usize = 16;

pub use bowden_interfaces::config::ConfigError;

/// The sheath every cable runs through between the drive unit and the manipulator base.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SheathConfig {
    /// Length of cable and sheath, mm (2.5 m in the paper).
    pub length_mm: f64,
    /// Total wrap angle of each cable's sheath (the integral of its curvature along the
    /// routing), deg. This is the "sheath curvature" the dead band grows with.
    pub wrap_deg: [f64; N_CABLES],
    /// Coulomb friction coefficient μ between cable and sheath liner (capstan: e^{μφ}).
    pub friction_coefficient: f64,
}

/// Friction inside the manipulator: a cable crossing a bent segment wraps the hinge edges by
/// that segment's bend angle, so the friction of distal cables grows with proximal bending.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BodyConfig {
    /// μ between cable and the hinge holes.
    pub friction_coefficient: f64,
}

/// The ten actuation cables.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CablesConfig {
    /// Axial stiffness E·A of each cable in series with its sheath's compression, N.
    pub axial_stiffness_n: [f64; N_CABLES],
    /// Pre-tension of each cable at the straight pose, N.
    pub pretension_n: [f64; N_CABLES],
}

/// Joint-space properties of the manipulator.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JointsConfig {
    /// Elastic restoring stiffness of each joint (flexure hinges in series; jaw return), N·mm/rad.
    /// Holding a bend takes a tension difference in the cable pairs, which stretches them.
    pub stiffness_nmm_per_rad: [f64; N_JOINTS],
    /// Per-joint gain on the angle decoded from the distal cable ends.
    pub gain: [f64; N_JOINTS],
    /// Per-joint zero offset, deg.
    pub offset_deg: [f64; N_JOINTS],
    /// Residual coupling not explained by the cable routing: q = (I + C)·q_cables, C with a
    /// zero diagonal (row = affected joint, column = source joint).
    pub coupling: [[f64; N_JOINTS]; N_JOINTS],
}

/// Which hysteresis model the plant simulates (`family = "…"` at the top of the plant file).
#[derive(
    Debug,
    Clone,
    Copy,
    Default,
    Deserialize,
    Serialize,
    PartialEq,
    Eq,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum FamilyKind {
    /// Cable space, rate-independent: capstan dead band + generalised Prandtl–Ishlinskii plays
    /// per cable (`[hysteresis]`). The default: files without `family` are this.
    #[default]
    Capstan,
    /// Joint space, rate-independent: an asymmetric Bouc–Wen lag per joint (`[bouc_wen]`).
    BoucWen,
    /// Cable space, rate-dependent: LuGre friction on an elastic cable per cable (`[lugre]`).
    Lugre,
    /// Joint space, rate-dependent: a bounded friction lag per joint from a classical Preisach
    /// relay grid on the contacts' load (lognormal × split-normal density), gross sliding and a
    /// delayed slip (`[preisach]`).
    Preisach,
}

impl FamilyKind {
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }

    /// The family's own table in a plant file.
    pub fn table(self) -> &'static str {
        match self {
            FamilyKind::Capstan => "hysteresis",
            FamilyKind::BoucWen => "bouc_wen",
            FamilyKind::Lugre => "lugre",
            FamilyKind::Preisach => "preisach",
        }
    }
}

/// `[bouc_wen]`: a rate-independent Bouc–Wen lag per joint, in joint space (see
/// `families::bouc_wen`). The input x is the joint command decoded from the cable command; the
/// output lags it by λ = W·ζ: q_h = x − λ, dζ = (dx/W)·(1 − |ζ|ⁿ·(β·sgn(dx·ζ) + γ)).
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BoucWenConfig {
    /// Saturated lag W of each joint behind an increasing command (ζ > 0), deg.
    pub width_up_deg: [f64; N_JOINTS],
    /// Saturated lag W of each joint behind a decreasing command (ζ < 0), deg.
    pub width_down_deg: [f64; N_JOINTS],
    /// Sharpness n of the transition from the dead band to the saturated lag (1 = rounded).
    pub exponent: f64,
    /// β and γ of the Bouc–Wen law, A = 1. β + γ = 1 makes the saturated lag exactly W;
    /// γ − β ≥ 0 is the slope dq/dx right after a reversal (0: a backlash-like dead band).
    pub beta: f64,
    pub gamma: f64,
    /// Relative widening of each joint's W per rad of bend of q1, q2, q3 (row = joint whose
    /// band widens, column = bending joint): cables crossing a bent segment rub on its hinges.
    pub widening_per_rad: [[f64; 3]; N_JOINTS],
}

/// `[lugre]`: LuGre friction (Canudas de Wit et al. 1995) between each cable and its sheath,
/// lumped at the cable's distal end (see `families::lugre`). Friction levels come from the
/// capstan relation Fc = T·(1 − e^{−μφ}) with `[sheath]`, `[body]` and the cable tension.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LugreConfig {
    /// σ0: stiffness of the bristles (pre-sliding displacement ≈ Fc/σ0), N/mm.
    pub bristle_stiffness_n_per_mm: f64,
    /// σ1: micro-damping of the bristles, N·s/mm.
    pub bristle_damping_ns_per_mm: f64,
    /// σ2: viscous friction, N·s/mm. > 0: it is what bounds the massless slider's speed.
    pub viscous_ns_per_mm: f64,
    /// Fs/Fc: static (breakaway) over Coulomb friction, ≥ 1.
    pub stribeck_ratio: f64,
    /// vs: Stribeck velocity, mm/s.
    pub stribeck_velocity_mm_per_s: f64,
    /// Free play (backlash) of each cable pair at its distal termination, mm of pair difference
    /// (full width), per joint.
    pub free_play_mm: [f64; N_JOINTS],
}

/// `[preisach]`: a friction lag per joint, in joint space (see `families::preisach`): a
/// population of stick–slip contacts, each a Preisach relay γ_αβ (α ≥ β) on the load the
/// contacts hold back, on a 16 × 16 triangular grid spanning loads of ±X, X =
/// `lag_amplitude_deg` + `presliding_deg`, weighted by a density that is lognormal in the
/// coercivity h_c = (α − β)/2 and split-normal in the interaction h_u = (α + β)/2. At a load of
/// ±X every contact has let go and the cable slides through (a play of half-width X); the joint
/// is where the cable has slid to plus the pre-sliding travel L·(Σ w·γ − its assembled value):
/// it lags its command by at most `lag_amplitude_deg` (plus L times the assembled offset) and
/// follows it over its whole range. The contacts feel the command through a standard linear
/// solid: a share `relaxation_fraction` of every change arrives only with the time constant
/// `relaxation_time_s` (delayed slip).
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PreisachConfig {
    /// G: the lag once every contact slips (the joint behind a command that has moved on by
    /// more than 2X in one direction), deg.
    pub lag_amplitude_deg: [f64; N_JOINTS],
    /// L: half the joint's travel while its contacts let go (the rest of a reversal's 2X of
    /// command it stands), deg. Validation requires L·b ≤ 1, b the density's steepest
    /// breakaway rate per deg of load, so that the joint never outruns its command.
    pub presliding_deg: [f64; N_JOINTS],
    /// Median of the lognormal coercivity (half a contact's own dead band), deg of load.
    pub coercivity_median_deg: [f64; N_JOINTS],
    /// Standard deviation of ln(coercivity): the spread of the friction levels.
    pub coercivity_log_sd: f64,
    /// Width of the interaction density above its mode (zero load), deg.
    pub interaction_sd_positive_deg: [f64; N_JOINTS],
    /// Width of the interaction density below its mode, deg (≠ the positive one: skewed,
    /// asymmetric branches).
    pub interaction_sd_negative_deg: [f64; N_JOINTS],
    /// κ: share of a command change the contacts feel only after the relaxation, in [0, 1)
    /// (0: rate-independent).
    pub relaxation_fraction: f64,
    /// τ of the relaxation (the sheath liner's standard linear solid), s.
    pub relaxation_time_s: f64,
}

/// Rate-independent hysteresis per cable: a generalised Prandtl–Ishlinskii operator.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HysteresisConfig {
    /// Number of play operators per cable (1 = a pure backlash), 1..=16.
    pub plays: usize,
    /// Relative spread of the play thresholds around the capstan half-width h: thresholds are
    /// uniform in h·[1 − s, 1 + s] (friction is not uniform along a real sheath, so the distal
    /// end starts to follow gradually after a reversal). 0 ≤ s < 1.
    pub threshold_spread: f64,
}

#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DynamicsConfig {
    /// Time constant of the first-order settling toward the quasi-static state, s.
    pub time_constant_s: f64,
}

/// Largest number of `[[drift.slip]]` entries (the plant holds them in a fixed array).
pub const MAX_SLIPS: usize = 16;

/// Cable slack for adaptation scenarios: a slow creep of every cable and sudden slips of single
/// cables. All rates zero and no slips = off.
///
/// The slack of cable i at simulated time t is
/// `min(rate_i · max(t − start_s, 0), max_mm) + Σ mm over the slips of cable i with at_s ≤ t`:
/// its distal end sits that much further out, and the pair's pre-tension drops with it (each
/// family's docs say what else follows).
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DriftConfig {
    /// Creep rate of each cable, mm per hour of simulated time.
    pub rate_mm_per_hour: [f64; N_CABLES],
    /// Creep saturates at this length, mm (slips come on top).
    pub max_mm: f64,
    /// Simulated time at which creep starts, s (absent = 0: from the start).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub start_s: f64,
    /// `[[drift.slip]]`: sudden slips, each a step of one cable's slack (absent = none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub slip: Vec<SlipConfig>,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// `[[drift.slip]]`: one cable slips at its termination by `mm` at simulated time `at_s` (a step
/// of its slack that stays).
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SlipConfig {
    /// When, s of simulated time (the first step that ends at or after it applies the slip).
    pub at_s: f64,
    /// Which cable, 1-based as the robot's w1..w10 (configs/robot.toml's cable order).
    pub cable: usize,
    /// How far its distal end slips out, mm.
    pub mm: f64,
}

impl DriftConfig {
    /// Whether any creep or slip is configured.
    pub fn is_active(&self) -> bool {
        self.creeps() || !self.slip.is_empty()
    }

    fn creeps(&self) -> bool {
        self.max_mm > 0.0 && self.rate_mm_per_hour.iter().any(|&r| r > 0.0)
    }

    /// Simulated time at which slack first appears (creep start or the earliest slip), s; None
    /// without any.
    pub fn onset_s(&self) -> Option<f64> {
        let creep = self.creeps().then_some(self.start_s);
        self.slip.iter().map(|s| s.at_s).chain(creep).reduce(f64::min)
    }

    /// What this drift does, for reports: the moments to mark (what, simulated time s) and
    /// one line ("creep w1 6 mm/h from 120 s, up to 2 mm (reached at 1320 s); w3 slips ...").
    /// `cable_name(i)` names cable i (0-based).
    pub fn describe(&self, cable_name: impl Fn(usize) -> String) -> (Vec<(String, f64)>, String) {
        let mut marks = Vec::new();
        let mut parts = Vec::new();
        let creeping: Vec<usize> = (0..self.rate_mm_per_hour.len())
            .filter(|&i| self.rate_mm_per_hour[i] > 0.0 && self.max_mm > 0.0)
            .collect();
        if !creeping.is_empty() {
            let rates: Vec<String> = creeping
                .iter()
                .map(|&i| format!("{} {} mm/h", cable_name(i), self.rate_mm_per_hour[i]))
                .collect();
            let fastest = creeping.iter().map(|&i| self.rate_mm_per_hour[i]).fold(0.0, f64::max);
            let full_s = self.start_s + 3600.0 * self.max_mm / fastest;
            parts.push(format!(
                "creep {} from {:.0} s, up to {} mm (reached at {:.0} s)",
                rates.join(", "),
                self.start_s,
                self.max_mm,
                full_s
            ));
            marks.push((format!("creep starts ({:.0} s)", self.start_s), self.start_s));
            marks.push((format!("creep reaches {} mm ({full_s:.0} s)", self.max_mm), full_s));
        }
        for sl in &self.slip {
            let what = format!("{} slips {} mm at {:.0} s", cable_name(sl.cable - 1), sl.mm, sl.at_s);
            marks.push((what.clone(), sl.at_s));
            parts.push(what);
        }
        let description = if parts.is_empty() {
            "no creep, no slip".into()
        } else {
            parts.join("; ")
        };
        (marks, description)
    }
}

/// Seeded manufacturing variation: every plant instance (seed) is a slightly different robot.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VariationConfig {
    /// Relative standard deviation (truncated at ±3σ) applied to each cable's stiffness,
    /// pre-tension and sheath wrap and to each joint's stiffness, and to the family's own
    /// parameters (`bouc-wen`: each joint's two widths and its widening; `lugre`: each cable's
    /// bristle stiffness and damping and viscous friction, each pair's free play; `preisach`:
    /// each joint's lag amplitude, pre-sliding travel, coercivity median, two interaction widths
    /// and relaxation time).
    pub relative_sd: f64,
    /// Which manufactured unit this file describes: the seed of its variation. A robot is one
    /// unit: its dataset is collected on it and its controller evaluated on it, whatever the
    /// run's seed (which then varies only the noise). Absent: every run's seed picks its own
    /// unit (a different robot each run).
    #[serde(default)]
    pub unit: Option<u64>,
}

impl VariationConfig {
    /// The unit a run with seed `run_seed` simulates.
    pub fn unit_for_run(&self, run_seed: u64) -> u64 {
        self.unit.unwrap_or(run_seed)
    }
}

/// Checks on incoming cable commands.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CommandConfig {
    /// A command may exceed the displacement range the joint limits span by this much, mm.
    pub margin_mm: f64,
}

/// The whole plant description.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlantConfig {
    pub name: String,
    /// The hysteresis model; absent = `capstan`.
    #[serde(default)]
    pub family: FamilyKind,
    pub sheath: SheathConfig,
    pub body: BodyConfig,
    pub cables: CablesConfig,
    pub joints: JointsConfig,
    /// `[hysteresis]`: the `capstan` family's plays (required for it, refused for the others).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hysteresis: Option<HysteresisConfig>,
    /// `[bouc_wen]`: required when `family = "bouc-wen"`, refused otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bouc_wen: Option<BoucWenConfig>,
    /// `[lugre]`: required when `family = "lugre"`, refused otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lugre: Option<LugreConfig>,
    /// `[preisach]`: required when `family = "preisach"`, refused otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preisach: Option<PreisachConfig>,
    pub dynamics: DynamicsConfig,
    pub drift: DriftConfig,
    pub variation: VariationConfig,
    pub command: CommandConfig,
}

impl PlantConfig {
    /// Reads and validates a plant file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            origin: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// `path` when given, else the shipped plant ([`Self::paper_default`]).
    pub fn load_or_shipped(path: Option<&Path>) -> Result<Self, ConfigError> {
        path.map_or_else(|| Ok(Self::paper_default()), Self::load)
    }

    /// The plant the repository ships (`configs/plant.toml`, embedded at build time).
    pub fn paper_default() -> Self {
        Self::parse(
            include_str!("../../../configs/plant.toml"),
            Path::new("configs/plant.toml"),
        )
        .expect("the shipped configs/plant.toml is valid")
    }

    /// Parses and validates TOML text; `path` is only used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let cfg: PlantConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            origin: path.display().to_string(),
            message: e.to_string().replace('\n', " "),
        })?;
        cfg.validate(path)?;
        Ok(cfg)
    }

    /// Checks every field; the error names the first bad one.
    /// Long by design (over 120 lines): one check per field, in the file's order, so every
    /// rule of the schema is in one place beside its struct; each check is a few lines and
    /// shares nothing with the next, so helpers would only scatter the schema.
    // Long: one flat list of independent checks, each naming its field.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |field: String, problem: String| ConfigError::Invalid {
            origin: path.display().to_string(),
            field,
            problem,
        };
        let check = |field: String, v: f64, ok: bool, want: &str| {
            if v.is_finite() && ok {
                Ok(())
            } else {
                Err(bad(field, format!("must be {want}, got {v}")))
            }
        };
        let s = &self.sheath;
        check("sheath.length_mm".into(), s.length_mm, s.length_mm > 0.0, "> 0")?;
        check(
            "sheath.friction_coefficient".into(),
            s.friction_coefficient,
            (0.0..=2.0).contains(&s.friction_coefficient),
            "in [0, 2]",
        )?;
        for (i, &w) in s.wrap_deg.iter().enumerate() {
            check(
                format!("sheath.wrap_deg[{i}]"),
                w,
                (0.0..=3600.0).contains(&w),
                "in [0, 3600] deg",
            )?;
        }
        let mu_b = self.body.friction_coefficient;
        check(
            "body.friction_coefficient".into(),
            mu_b,
            (0.0..=2.0).contains(&mu_b),
            "in [0, 2]",
        )?;
        for i in 0..N_CABLES {
            let ea = self.cables.axial_stiffness_n[i];
            check(format!("cables.axial_stiffness_n[{i}]"), ea, ea > 0.0, "> 0 N")?;
            let t0 = self.cables.pretension_n[i];
            check(format!("cables.pretension_n[{i}]"), t0, t0 >= 0.0, "≥ 0 N")?;
            let r = self.drift.rate_mm_per_hour[i];
            check(format!("drift.rate_mm_per_hour[{i}]"), r, r >= 0.0, "≥ 0 mm/h")?;
        }
        let j = &self.joints;
        for k in 0..N_JOINTS {
            let st = j.stiffness_nmm_per_rad[k];
            check(
                format!("joints.stiffness_nmm_per_rad[{k}]"),
                st,
                st >= 0.0,
                "≥ 0 N·mm/rad",
            )?;
            let g = j.gain[k];
            check(format!("joints.gain[{k}]"), g, g > 0.1 && g < 10.0, "in (0.1, 10)")?;
            let o = j.offset_deg[k];
            check(format!("joints.offset_deg[{k}]"), o, o.abs() <= 45.0, "within ±45 deg")?;
            for c in 0..N_JOINTS {
                let v = j.coupling[k][c];
                if k == c {
                    if v != 0.0 {
                        return Err(bad(
                            format!("joints.coupling[{k}][{c}]"),
                            format!("the diagonal must be 0 (a joint's own scale is joints.gain), got {v}"),
                        ));
                    }
                } else {
                    check(format!("joints.coupling[{k}][{c}]"), v, v.abs() < 1.0, "within (−1, 1)")?;
                }
            }
        }
        if let Some(h) = &self.hysteresis {
            if !(1..=MAX_PLAYS).contains(&h.plays) {
                return Err(bad(
                    "hysteresis.plays".into(),
                    format!("must be 1..={MAX_PLAYS}, got {}", h.plays),
                ));
            }
            check(
                "hysteresis.threshold_spread".into(),
                h.threshold_spread,
                (0.0..1.0).contains(&h.threshold_spread),
                "in [0, 1)",
            )?;
        }
        let tau = self.dynamics.time_constant_s;
        check(
            "dynamics.time_constant_s".into(),
            tau,
            tau > 0.0 && tau <= 60.0,
            "in (0, 60] s",
        )?;
        let m = self.drift.max_mm;
        check("drift.max_mm".into(), m, m >= 0.0, "≥ 0 mm")?;
        let st = self.drift.start_s;
        check("drift.start_s".into(), st, (0.0..=1e7).contains(&st), "in [0, 1e7] s")?;
        if self.drift.slip.len() > MAX_SLIPS {
            return Err(bad(
                "drift.slip".into(),
                format!("at most {MAX_SLIPS} slips, got {}", self.drift.slip.len()),
            ));
        }
        for (k, sl) in self.drift.slip.iter().enumerate() {
            check(
                format!("drift.slip[{k}].at_s"),
                sl.at_s,
                (0.0..=1e7).contains(&sl.at_s),
                "in [0, 1e7] s",
            )?;
            if !(1..=N_CABLES).contains(&sl.cable) {
                return Err(bad(
                    format!("drift.slip[{k}].cable"),
                    format!("must be 1..={N_CABLES} (w1..w{N_CABLES}), got {}", sl.cable),
                ));
            }
            check(
                format!("drift.slip[{k}].mm"),
                sl.mm,
                sl.mm > 0.0 && sl.mm <= 5.0,
                "in (0, 5] mm",
            )?;
        }
        let v = self.variation.relative_sd;
        check(
            "variation.relative_sd".into(),
            v,
            (0.0..0.3).contains(&v),
            "in [0, 0.3)",
        )?;
        let cm = self.command.margin_mm;
        check("command.margin_mm".into(), cm, cm >= 0.0, "≥ 0 mm")?;
        self.validate_family(path)
    }

    /// The selected family's table is present and valid; the other families' are absent.
    /// Long by design (over 120 lines): one check per field, in the file's order, so every
    /// rule of the schema is in one place beside its struct; each check is a few lines and
    /// shares nothing with the next, so helpers would only scatter the schema.
    // Long: one flat list of independent checks per family table, each naming its field.
    fn validate_family(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |field: String, problem: String| ConfigError::Invalid {
            origin: path.display().to_string(),
            field,
            problem,
        };
        let check = |field: String, v: f64, ok: bool, want: &str| {
            if v.is_finite() && ok {
                Ok(())
            } else {
                Err(bad(field, format!("must be {want}, got {v}")))
            }
        };
        let family = self.family;
        let present = [
            (FamilyKind::Capstan, self.hysteresis.is_some()),
            (FamilyKind::BoucWen, self.bouc_wen.is_some()),
            (FamilyKind::Lugre, self.lugre.is_some()),
            (FamilyKind::Preisach, self.preisach.is_some()),
        ];
        for (kind, is_present) in present {
            if kind == family && !is_present {
                return Err(bad(
                    kind.table().into(),
                    format!(
                        "the [{}] table is required when family = \"{}\"",
                        kind.table(),
                        kind.as_str()
                    ),
                ));
            }
            if kind != family && is_present {
                return Err(bad(
                    kind.table().into(),
                    format!(
                        "the [{}] table belongs to family \"{}\" but this file selects family = \"{}\"; remove the table or change `family`",
                        kind.table(),
                        kind.as_str(),
                        family.as_str()
                    ),
                ));
            }
        }
        if let Some(b) = &self.bouc_wen {
            for k in 0..N_JOINTS {
                for (name, w) in [
                    ("width_up_deg", b.width_up_deg[k]),
                    ("width_down_deg", b.width_down_deg[k]),
                ] {
                    check(
                        format!("bouc_wen.{name}[{k}]"),
                        w,
                        (0.01..=90.0).contains(&w),
                        "in [0.01, 90] deg",
                    )?;
                }
                for c in 0..3 {
                    let v = b.widening_per_rad[k][c];
                    check(
                        format!("bouc_wen.widening_per_rad[{k}][{c}]"),
                        v,
                        (0.0..=10.0).contains(&v),
                        "in [0, 10] per rad",
                    )?;
                }
            }
            check(
                "bouc_wen.exponent".into(),
                b.exponent,
                (1.0..=20.0).contains(&b.exponent),
                "in [1, 20]",
            )?;
            check("bouc_wen.beta".into(), b.beta, b.beta >= 0.0, "≥ 0")?;
            check(
                "bouc_wen.gamma".into(),
                b.gamma,
                b.gamma >= b.beta,
                "≥ bouc_wen.beta (otherwise the joint moves against its command after a reversal)",
            )?;
            let sum = b.beta + b.gamma;
            if (sum - 1.0).abs() > 1e-9 {
                return Err(bad(
                    "bouc_wen.gamma".into(),
                    format!(
                        "beta + gamma must be 1 (A = 1, so that the saturated lag is the width), got {} + {} = {sum}",
                        b.beta, b.gamma
                    ),
                ));
            }
        }
        if let Some(l) = &self.lugre {
            check(
                "lugre.bristle_stiffness_n_per_mm".into(),
                l.bristle_stiffness_n_per_mm,
                l.bristle_stiffness_n_per_mm > 0.0 && l.bristle_stiffness_n_per_mm <= 1e6,
                "in (0, 1e6] N/mm",
            )?;
            check(
                "lugre.bristle_damping_ns_per_mm".into(),
                l.bristle_damping_ns_per_mm,
                l.bristle_damping_ns_per_mm >= 0.0 && l.bristle_damping_ns_per_mm <= 1e3,
                "in [0, 1e3] N·s/mm",
            )?;
            check(
                "lugre.viscous_ns_per_mm".into(),
                l.viscous_ns_per_mm,
                l.viscous_ns_per_mm >= 1e-4 && l.viscous_ns_per_mm <= 1e3,
                "in [1e-4, 1e3] N·s/mm (the massless slider needs viscous friction)",
            )?;
            check(
                "lugre.stribeck_ratio".into(),
                l.stribeck_ratio,
                (1.0..=5.0).contains(&l.stribeck_ratio),
                "in [1, 5]",
            )?;
            check(
                "lugre.stribeck_velocity_mm_per_s".into(),
                l.stribeck_velocity_mm_per_s,
                l.stribeck_velocity_mm_per_s > 0.0 && l.stribeck_velocity_mm_per_s <= 1e4,
                "in (0, 1e4] mm/s",
            )?;
            for (k, &b) in l.free_play_mm.iter().enumerate() {
                check(
                    format!("lugre.free_play_mm[{k}]"),
                    b,
                    (0.0..=10.0).contains(&b),
                    "in [0, 10] mm",
                )?;
            }
        }
        if let Some(p) = &self.preisach {
            for k in 0..N_JOINTS {
                let g = p.lag_amplitude_deg[k];
                check(
                    format!("preisach.lag_amplitude_deg[{k}]"),
                    g,
                    (0.1..=90.0).contains(&g),
                    "in [0.1, 90] deg",
                )?;
                let l = p.presliding_deg[k];
                check(
                    format!("preisach.presliding_deg[{k}]"),
                    l,
                    l > 0.0 && l <= 90.0,
                    "in (0, 90] deg",
                )?;
                // The density must live on the grid (loads in ±X): a median contact whose own
                // loop (2·h_c) does not fit, or an interaction wider than the range, would put
                // most of the population where no load reaches it.
                let x = g + l;
                let m = p.coercivity_median_deg[k];
                check(
                    format!("preisach.coercivity_median_deg[{k}]"),
                    m,
                    m >= 0.01 && m <= x,
                    &format!(
                        "in [0.01, X = preisach.lag_amplitude_deg[{k}] + presliding_deg[{k}] = {x}] deg (the median contact's loop must fit in the grid)"
                    ),
                )?;
                for (name, sd) in [
                    ("interaction_sd_positive_deg", p.interaction_sd_positive_deg[k]),
                    ("interaction_sd_negative_deg", p.interaction_sd_negative_deg[k]),
                ] {
                    check(
                        format!("preisach.{name}[{k}]"),
                        sd,
                        sd >= 0.1 && sd <= x,
                        &format!("in [0.1, X = preisach.lag_amplitude_deg[{k}] + presliding_deg[{k}] = {x}] deg (a wider density lies mostly outside the grid)"),
                    )?;
                }
            }
            check(
                "preisach.coercivity_log_sd".into(),
                p.coercivity_log_sd,
                (0.05..=2.0).contains(&p.coercivity_log_sd),
                "in [0.05, 2] (the lognormal's spread of ln h_c)",
            )?;
            check(
                "preisach.relaxation_fraction".into(),
                p.relaxation_fraction,
                (0.0..1.0).contains(&p.relaxation_fraction),
                "in [0, 1) (0 = rate-independent; 1 would leave the contacts nothing at once)",
            )?;
            check(
                "preisach.relaxation_time_s".into(),
                p.relaxation_time_s,
                p.relaxation_time_s > 0.0 && p.relaxation_time_s <= 60.0,
                "in (0, 60] s",
            )?;
            // Never faster than the command: L·b ≤ 1 for the file's density, and for the unit
            // the file names (its varied density; a unit picked per run is checked when its
            // plant is built, `Plant::try_new`).
            for k in 0..N_JOINTS {
                let l = p.presliding_deg[k];
                let b = preisach::nominal_breakaway_rate(p, k);
                if (l * b).is_nan() || l * b > 1.0 {
                    return Err(bad(
                        format!("preisach.presliding_deg[{k}]"),
                        format!(
                            "must be at most 1/b = {:.4} deg, got {l}: L·b = {:.4} > 1, b = {b:.6} per deg the steepest breakaway rate of the contact density (preisach.coercivity_median_deg, coercivity_log_sd, interaction_sd_positive_deg, interaction_sd_negative_deg), so that the joint never outruns its command where its contacts let go; lower presliding_deg[{k}] or spread the density",
                            1.0 / b,
                            l * b
                        ),
                    ));
                }
            }
            if let Some(unit) = self.variation.unit {
                if let Err(e) = crate::plant::preisach_unit(self, unit) {
                    return Err(bad(
                        format!("preisach.presliding_deg[{}]", e.joint),
                        format!("unit {unit} (variation.unit): {e}"),
                    ));
                }
            }
        }
        Ok(())
    }
}
