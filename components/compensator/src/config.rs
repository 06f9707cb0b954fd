//! `configs/controller.toml`: every setting of the compensator.

use crate::dither::DitherConfig;
use crate::feedback::FeedbackConfig;
use crate::history::HistoryRule;
use crate::refine::{NewtonParams, PaperParams};
use serde::Deserialize;
use std::path::{Path, PathBuf};

pub use bowden_interfaces::config::ConfigError;

/// Compensation mode (the names of `bowden_interfaces::CompensationMode`).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Deserialize,
    serde::Serialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "lowercase")]
#[strum(serialize_all = "lowercase")]
pub enum Mode {
    /// Pass-through: q_cmd = q_desired (the paper's uncalibrated controller).
    Uncalibrated,
    /// Algorithm 1 exactly.
    Paper,
    /// Levenberg–Marquardt on the forward model's exact Jacobian.
    Newton,
}

impl Mode {
    /// Every mode, in declaration order.
    pub const ALL: &'static [Mode] = <Mode as strum::VariantArray>::VARIANTS;
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
    /// Parses the spelling of [`Mode::as_str`].
    pub fn parse(s: &str) -> Option<Mode> {
        s.parse().ok()
    }
    pub fn to_interface(self) -> bowden_interfaces::CompensationMode {
        use bowden_interfaces::CompensationMode as C;
        match self {
            Mode::Uncalibrated => C::Uncalibrated,
            Mode::Paper => C::Paper,
            Mode::Newton => C::Newton,
        }
    }
    pub fn from_interface(m: bowden_interfaces::CompensationMode) -> Mode {
        use bowden_interfaces::CompensationMode as C;
        match m {
            C::Uncalibrated => Mode::Uncalibrated,
            C::Paper => Mode::Paper,
            C::Newton => Mode::Newton,
        }
    }
    /// Whether the mode needs (forward, inverse) models.
    pub fn needs_models(self, newton_init_from_inverse: bool) -> (bool, bool) {
        match self {
            Mode::Uncalibrated => (false, false),
            Mode::Paper => (true, true),
            Mode::Newton => (true, newton_init_from_inverse),
        }
    }
}

/// Which evaluator runs the models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum EvaluatorChoice {
    /// The exact incremental evaluator when the graph is recognised, tract otherwise.
    #[default]
    Auto,
    /// tract's full evaluation for every trial (the naive baseline; allocates).
    Tract,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BudgetConfig {
    /// Time budget of one step in ns (refinement stops when spent); 0 = no budget, which
    /// lockstep / deterministic runs need so results do not depend on the machine's speed.
    pub budget_ns: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HistoryRuleName {
    Distance,
    EveryStep,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HistoryConfig {
    /// `distance`: a new entry when the desired command moved ≥ `step_deg` from the last
    /// entry; `every_step`: every call.
    pub rule: HistoryRuleName,
    /// The model's time step in joint space: the dataset's 3·√5 deg (eq. 16).
    pub step_deg: f64,
    /// Interpolate intermediate entries when one call moves several steps.
    pub interpolate: bool,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    /// Clamp the command into the robot's joint limits (and keep the jaws from crossing).
    pub joint_limits: bool,
    /// Largest command speed per joint, deg/s; 0 = no rate limit.
    pub rate_limit_deg_s: f64,
    /// Control period the rate limit assumes, ns (the runtime may override it).
    pub period_ns: u64,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadCheckConfig {
    /// Random windows on which the incremental evaluator is checked against tract at load.
    pub windows: usize,
    /// Absolute floor of the accepted difference, degrees.
    pub tolerance_deg: f64,
    /// Accepted difference relative to the outputs' scale (see
    /// `bowden_compensator::LoadOptions::relative`); 1e-5 when absent.
    #[serde(default = "default_load_check_relative")]
    pub relative: f64,
}

fn default_load_check_relative() -> f64 {
    crate::model::LoadOptions::default().relative
}

impl LoadCheckConfig {
    /// How every model of this controller is loaded and checked (its own, swapped-in ones,
    /// `tune`'s candidates).
    pub fn options(&self) -> crate::model::LoadOptions {
        crate::model::LoadOptions {
            check_windows: self.windows,
            tolerance_deg: self.tolerance_deg,
            relative: self.relative,
            ..Default::default()
        }
    }
}

/// Safe refinement (docs/architecture.md, "Safe refinement"): what keeps a learned model from
/// sending commands where it was never trained. Every bound is per joint and allocation-free.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyConfig {
    /// Keep every candidate inside the support of the forward model's training data (its
    /// metadata): the command range seen, and a step from the newest history entry no larger
    /// than the largest step seen. A model without support metadata falls back to the robot's
    /// joint limits (reported by `Compensator::support`).
    pub support: bool,
    /// Scales the support's half-ranges around their centres (1 = exactly as seen).
    pub support_scale: f64,
    /// Scales the largest training step that bounds a candidate's move from the newest
    /// history entry (1 = exactly as seen; 0 = no step bound, the range only).
    #[serde(default = "one")]
    pub step_scale: f64,
    /// Send the forward model's best-rated of {the refinement's result, its start, q_desired}:
    /// a command the model rates worse than where the refinement started, or than sending
    /// the target unchanged, is never sent.
    pub never_worse: bool,
    /// With `never_worse`: a candidate is also sent only if the model rates the tip no
    /// further from the target's pose than sending the target unchanged, in position and in
    /// orientation apart (the robot's forward kinematics of the predicted angles). The joint
    /// rating is a sum over the joints; a poor model can trade one joint for another in a way
    /// the tip pays for (docs/architecture.md, "Safe refinement").
    #[serde(default, skip_serializing_if = "is_false")]
    pub never_worse_tip: bool,
    /// Drift guard: |q_cmd − q_desired| ≤ `correction_scale` × the largest command-to-physical
    /// gap of the training data, per joint. The sent commands feed the forward model's
    /// history, so a model that keeps asking for more cannot walk the commands away. 0 = off.
    pub correction_scale: f64,
}

fn one() -> f64 {
    1.0
}

fn is_false(v: &bool) -> bool {
    !*v
}

impl Default for SafetyConfig {
    /// The literal paper: no bounds beyond the joint limits (configs name `[safety]`
    /// explicitly; the shipped ones turn everything on).
    fn default() -> Self {
        Self {
            support: false,
            support_scale: 1.0,
            step_scale: 1.0,
            never_worse: false,
            never_worse_tip: false,
            correction_scale: 0.0,
        }
    }
}

impl SafetyConfig {
    /// Every safeguard on, as the shipped configs have it.
    pub fn on() -> Self {
        Self {
            support: true,
            support_scale: 1.0,
            // The largest training step itself. On poor models with eq. (16)-spaced targets
            // (`tests/it/safe_refinement.rs`, `safety_variants_on_poor_models`) 3× costs less of
            // the gain, but in the vision loop on the test paths 3× let newton track worse than
            // uncalibrated (random path −3.5 % position, −28 % orientation) where 1× stayed
            // better on every path (docs/results/paper-protocol/).
            step_scale: 1.0,
            never_worse: true,
            never_worse_tip: false,
            correction_scale: 1.0,
        }
    }
}

/// The whole controller config.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerConfig {
    pub mode: Mode,
    /// Forward model (q_cmd history → q_phy); relative paths resolve against the config
    /// file's directory, then the repository root (its parent), then the working directory.
    #[serde(default)]
    pub model_fwd: Option<PathBuf>,
    /// Inverse model (q_phy history → q_cmd).
    #[serde(default)]
    pub model_inv: Option<PathBuf>,
    #[serde(default)]
    pub evaluator: EvaluatorChoice,
    pub paper: PaperParams,
    pub newton: NewtonParams,
    pub budget: BudgetConfig,
    pub history: HistoryConfig,
    pub output: OutputConfig,
    pub load_check: LoadCheckConfig,
    /// Safe refinement; absent = the literal paper (no bounds beyond the joint limits).
    #[serde(default)]
    pub safety: SafetyConfig,
    /// Vision feedback from the estimator's `JointEstimate` stream; absent = off (pure
    /// feed-forward, exactly as without the table).
    #[serde(default)]
    pub feedback: FeedbackConfig,
    /// Excitation while working (for online adaptation); absent = off.
    #[serde(default)]
    pub dither: DitherConfig,
    /// Where the config came from (relative model paths resolve against it).
    #[serde(skip)]
    pub source: Option<PathBuf>,
}

const SHIPPED: &str = include_str!("../../../configs/controller.toml");

impl ControllerConfig {
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let p = path.as_ref();
        let text = std::fs::read_to_string(p).map_err(|source| ConfigError::io(p.display(), source))?;
        Self::parse(&text, p)
    }

    /// Parses and validates; `path` names the file in errors and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let mut c: ControllerConfig = toml::from_str(text).map_err(|e| ConfigError::parse(path.display(), e))?;
        c.source = Some(path.to_path_buf());
        c.validate()?;
        Ok(c)
    }

    /// The shipped `configs/controller.toml` (embedded at build time).
    pub fn shipped() -> Self {
        let mut c = Self::parse(SHIPPED, Path::new("configs/controller.toml")).expect("the shipped config is valid");
        // Anchor relative paths at the repository this crate was built from; the working
        // directory is tried too.
        c.source = Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/controller.toml"));
        c
    }

    pub fn history_rule(&self) -> HistoryRule {
        match self.history.rule {
            HistoryRuleName::EveryStep => HistoryRule::EveryStep,
            HistoryRuleName::Distance => HistoryRule::Distance {
                step_deg: self.history.step_deg,
                interpolate: self.history.interpolate,
            },
        }
    }

    fn path_name(&self) -> String {
        self.source
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "<controller config>".into())
    }

    /// Long by design (over 120 lines): one check per field, in the file's order, so every
    /// rule of the schema is in one place beside its struct; each check is a few lines and
    /// shares nothing with the next, so helpers would only scatter the schema.
    // Long: one flat list of independent checks, each naming its field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let path = self.path_name();
        let bad = |field: &'static str, value: String, reason: &'static str| {
            Err(ConfigError::invalid(&path, field, format!("{value}: {reason}")))
        };
        let p = &self.paper;
        if !(1..=100_000).contains(&p.iterations) {
            return bad("paper.iterations", p.iterations.to_string(), "must be in 1..=100000");
        }
        if !(p.alpha.is_finite() && p.alpha > 0.0) {
            return bad("paper.alpha", p.alpha.to_string(), "must be a positive number");
        }
        if !(p.threshold_deg.is_finite() && p.threshold_deg >= 0.0) {
            return bad("paper.threshold_deg", p.threshold_deg.to_string(), "must be ≥ 0");
        }
        let n = &self.newton;
        if !(1..=10_000).contains(&n.max_evals) {
            return bad("newton.max_evals", n.max_evals.to_string(), "must be in 1..=10000");
        }
        let pos = [
            ("newton.tolerance_deg", n.tolerance_deg),
            ("newton.damping_init", n.damping_init),
            ("newton.damping_min", n.damping_min),
            ("newton.damping_max", n.damping_max),
            ("newton.max_step_deg", n.max_step_deg),
            ("newton.fallback_step", n.fallback_step),
        ];
        for (field, v) in pos {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, v.to_string(), "must be a positive number");
            }
        }
        if !(n.prior_weight.is_finite() && n.prior_weight >= 0.0) {
            return bad("newton.prior_weight", n.prior_weight.to_string(), "must be ≥ 0");
        }
        if !(n.step_tolerance_deg.is_finite() && n.step_tolerance_deg >= 0.0) {
            return bad(
                "newton.step_tolerance_deg",
                n.step_tolerance_deg.to_string(),
                "must be ≥ 0",
            );
        }
        if !(n.damping_increase.is_finite() && n.damping_increase > 1.0) {
            return bad("newton.damping_increase", n.damping_increase.to_string(), "must be > 1");
        }
        if !(n.damping_decrease > 0.0 && n.damping_decrease < 1.0) {
            return bad(
                "newton.damping_decrease",
                n.damping_decrease.to_string(),
                "must be in (0, 1)",
            );
        }
        if n.damping_min > n.damping_max {
            return bad(
                "newton.damping_min",
                n.damping_min.to_string(),
                "must not exceed newton.damping_max",
            );
        }
        let h = &self.history;
        if !(h.step_deg.is_finite() && h.step_deg > 0.0) {
            return bad("history.step_deg", h.step_deg.to_string(), "must be a positive number");
        }
        let o = &self.output;
        if !(o.rate_limit_deg_s.is_finite() && o.rate_limit_deg_s >= 0.0) {
            return bad(
                "output.rate_limit_deg_s",
                o.rate_limit_deg_s.to_string(),
                "must be ≥ 0 (0 = off)",
            );
        }
        if o.rate_limit_deg_s > 0.0 && o.period_ns == 0 {
            return bad("output.period_ns", "0".into(), "must be > 0 when a rate limit is set");
        }
        let sf = &self.safety;
        if !(sf.support_scale.is_finite() && sf.support_scale >= 1.0 && sf.support_scale <= 10.0) {
            return bad(
                "safety.support_scale",
                sf.support_scale.to_string(),
                "must be in [1, 10] (1 = the training data's support exactly)",
            );
        }
        if !(sf.step_scale.is_finite() && sf.step_scale >= 0.0 && sf.step_scale <= 10.0) {
            return bad(
                "safety.step_scale",
                sf.step_scale.to_string(),
                "must be in [0, 10] (0 = no step bound; 1 = the largest training step)",
            );
        }
        if !(sf.correction_scale.is_finite() && sf.correction_scale >= 0.0 && sf.correction_scale <= 10.0) {
            return bad(
                "safety.correction_scale",
                sf.correction_scale.to_string(),
                "must be in [0, 10] (0 = off)",
            );
        }
        if sf.never_worse_tip && !sf.never_worse {
            return bad(
                "safety.never_worse_tip",
                "true".into(),
                "rates the never-worse choice's candidates by the tip too: needs never_worse = true",
            );
        }
        if let Err((field, value, reason)) = self.feedback.check() {
            return bad(field, value, reason);
        }
        if let Err((field, value, reason)) = self.dither.check() {
            return bad(field, value, reason);
        }
        let lc = &self.load_check;
        if !(1..=10_000).contains(&lc.windows) {
            return bad("load_check.windows", lc.windows.to_string(), "must be in 1..=10000");
        }
        if !(lc.tolerance_deg.is_finite() && lc.tolerance_deg > 0.0) {
            return bad(
                "load_check.tolerance_deg",
                lc.tolerance_deg.to_string(),
                "must be a positive number",
            );
        }
        if !(lc.relative.is_finite() && (0.0..1.0).contains(&lc.relative)) {
            return bad(
                "load_check.relative",
                lc.relative.to_string(),
                "must be a number in [0, 1)",
            );
        }
        Ok(())
    }

    /// Resolves a model path: absolute as is; relative against the config's directory, the
    /// repository root (the config directory's parent), then the working directory.
    pub fn resolve_model_path(&self, field: &'static str, p: &Path) -> Result<PathBuf, ConfigError> {
        if p.is_absolute() {
            return if p.exists() {
                Ok(p.to_path_buf())
            } else {
                Err(ConfigError::invalid(
                    self.path_name(),
                    field,
                    format!("{:?}: no such file", p.display().to_string()),
                ))
            };
        }
        let mut tried = Vec::new();
        if let Some(dir) = self.source.as_ref().and_then(|s| s.parent()) {
            tried.push(dir.join(p));
            if let Some(root) = dir.parent() {
                tried.push(root.join(p));
            }
        }
        tried.push(p.to_path_buf());
        for t in &tried {
            if t.exists() {
                return Ok(t.clone());
            }
        }
        let tried = tried
            .iter()
            .map(|t| t.display().to_string())
            .collect::<Vec<_>>()
            .join(", ");
        Err(ConfigError::invalid(
            self.path_name(),
            field,
            format!("{:?}: no such file (tried {tried})", p.display().to_string()),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_config_parses_with_paper_defaults() {
        let c = ControllerConfig::shipped();
        assert_eq!(c.paper, PaperParams::default());
        assert!(matches!(c.history_rule(), HistoryRule::Distance { .. }));
    }

    /// The error `text` is refused with, as the user sees it (`path` names the file).
    fn parse_error(text: &str, path: &str) -> String {
        ControllerConfig::parse(text, Path::new(path)).unwrap_err().to_string()
    }

    #[test]
    fn errors_name_file_and_field() {
        let bad = SHIPPED.replace("alpha = 0.001", "alpha = -1.0");
        let e = parse_error(&bad, "x/controller.toml");
        assert!(
            e.contains("x/controller.toml") && e.contains("paper.alpha") && e.contains("-1"),
            "{e}"
        );
        let bad = SHIPPED.replace("[budget]", "[budget]\nbudget_ms = 3");
        let e = parse_error(&bad, "y.toml");
        assert!(e.contains("y.toml") && e.contains("budget_ms"), "{e}");
        let bad: String = SHIPPED
            .lines()
            .map(|l| {
                if l.starts_with("mode = ") {
                    "mode = \"magic\""
                } else {
                    l
                }
            })
            .collect::<Vec<_>>()
            .join("\n");
        let e = parse_error(&bad, "z.toml");
        assert!(e.contains("z.toml") && e.contains("magic"), "{e}");
    }

    #[test]
    fn the_tip_rating_parses_and_needs_never_worse() {
        let on = SHIPPED.replace("never_worse = true", "never_worse = true\nnever_worse_tip = true");
        assert_ne!(on, SHIPPED, "the shipped config has never_worse = true");
        let c = ControllerConfig::parse(&on, Path::new("tip.toml")).unwrap();
        assert!(c.safety.never_worse && c.safety.never_worse_tip);
        assert!(
            !ControllerConfig::shipped().safety.never_worse_tip,
            "off unless asked for"
        );
        let bad = SHIPPED.replace("never_worse = true", "never_worse = false\nnever_worse_tip = true");
        let e = parse_error(&bad, "w.toml");
        assert!(
            e.contains("w.toml") && e.contains("safety.never_worse_tip") && e.contains("never_worse = true"),
            "{e}"
        );
    }

    #[test]
    fn missing_model_lists_where_it_looked() {
        let c = ControllerConfig::parse(SHIPPED, Path::new("/nonexistent/configs/controller.toml")).unwrap();
        let e = c
            .resolve_model_path("model_fwd", Path::new("models/nope.onnx"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("model_fwd") && e.contains("/nonexistent/configs/models/nope.onnx"),
            "{e}"
        );
    }
}
