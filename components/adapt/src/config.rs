//! `[adapt]`: the settings of online adaptation (configs/adapt.toml), validated on load.

use bowden_interfaces::config::ConfigError;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Settings of the `adapt` node. Defaults are those of configs/adapt.toml.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptConfig {
    /// Rows a fine-tune and its validation use: the newest this many.
    pub window_rows: usize,
    /// Rows gathered between two staleness checks.
    pub check_every_rows: usize,
    /// Newest fraction of the window held out: never trained on, used to rate the models in
    /// use and the fine-tuned ones.
    pub holdout_fraction: f64,
    /// Last fraction of the training part used for early stopping of the fine-tune.
    pub early_stop_fraction: f64,
    /// Stale when the held-out error of the forward model in use exceeds this × the reference.
    pub stale_factor: f64,
    /// ... and this absolute error, deg (noise alone never triggers a fine-tune).
    pub stale_min_deg: f64,
    /// A fine-tuned model replaces the one in use only when its held-out error is lower by at
    /// least this fraction.
    pub min_gain: f64,
    /// A new row is kept only if its command moved at least this far (max over joints, deg)
    /// from the previous kept row's.
    pub min_step_deg: f64,
    /// Fine-tuning: epochs, early-stopping patience, learning rate, batch size, seed.
    pub epochs: usize,
    pub patience: usize,
    pub lr: f64,
    pub batch_size: usize,
    pub seed: u64,
    /// Weight λ of the fine-tune's pull λ·‖θ − θ₀‖² towards the weights in use (L2-SP; 0 =
    /// none): the new rows come from the robot's own closed loop, along the commands the
    /// compensator sends, and without it a fine-tune is free to change the model everywhere
    /// else, where the refinement then searches.
    pub anchor: f64,
    /// Weight-space interpolation of the fine-tune (WiSE-FT, Wortsman et al. 2022): the
    /// candidate is θ₀ + α(θ_ft − θ₀) from the re-centred model θ₀; 1 = the fine-tune itself.
    pub interpolate: f64,
    /// Which models are fine-tuned: "forward", "inverse" or both.
    pub directions: Vec<String>,
}

impl Default for AdaptConfig {
    fn default() -> Self {
        Self {
            window_rows: 200,
            check_every_rows: 40,
            holdout_fraction: 0.25,
            early_stop_fraction: 0.2,
            stale_factor: 1.3,
            stale_min_deg: 0.5,
            min_gain: 0.05,
            min_step_deg: 0.05,
            epochs: 40,
            patience: 8,
            lr: 3e-4,
            batch_size: 16,
            seed: 1,
            anchor: 0.0,
            interpolate: 1.0,
            directions: vec!["forward".into(), "inverse".into()],
        }
    }
}

impl AdaptConfig {
    /// Reads and validates a TOML file whose `[adapt]` table (or whole body) holds the settings.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::io(path.display(), e))?;
        Self::from_toml(&text, path.display())
    }

    /// Parses and validates TOML text; `origin` only names the source in errors.
    pub fn from_toml(text: &str, origin: impl std::fmt::Display) -> Result<Self, ConfigError> {
        let origin = origin.to_string();
        let v: toml::Table = toml::from_str(text).map_err(|e| ConfigError::parse(&origin, e))?;
        let table = match v.get("adapt") {
            Some(toml::Value::Table(t)) => t.clone(),
            Some(_) => return Err(ConfigError::invalid(&origin, "adapt", "must be a table")),
            None => v,
        };
        let c: AdaptConfig = table
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::parse(&origin, e))?;
        c.validate(&origin)?;
        Ok(c)
    }

    /// Checks every field; the error names the first bad one (`origin` names the source).
    pub fn validate(&self, origin: impl std::fmt::Display) -> Result<(), ConfigError> {
        let bad = |name: &str, problem: String| Err(ConfigError::invalid(&origin, format!("adapt.{name}"), problem));
        for (name, v) in [
            ("holdout_fraction", self.holdout_fraction),
            ("early_stop_fraction", self.early_stop_fraction),
            ("min_gain", self.min_gain),
        ] {
            if !(v > 0.0 && v < 1.0) {
                return bad(name, format!("{v}: must be in (0, 1)"));
            }
        }
        if self.window_rows < 20 {
            return bad("window_rows", format!("{}: at least 20", self.window_rows));
        }
        if self.check_every_rows == 0 {
            return bad("check_every_rows", "must be at least 1".into());
        }
        if !(self.stale_factor >= 1.0 && self.stale_factor.is_finite()) {
            return bad("stale_factor", format!("{}: must be ≥ 1", self.stale_factor));
        }
        for (n, v) in [
            ("stale_min_deg", self.stale_min_deg),
            ("min_step_deg", self.min_step_deg),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return bad(n, format!("{v}: must be ≥ 0"));
            }
        }
        for (n, v) in [
            ("epochs", self.epochs),
            ("batch_size", self.batch_size),
            ("patience", self.patience),
        ] {
            if v == 0 {
                return bad(n, "must be at least 1".into());
            }
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return bad("lr", format!("{}: must be positive", self.lr));
        }
        if !(self.anchor >= 0.0 && self.anchor.is_finite()) {
            return bad("anchor", format!("{}: must be ≥ 0", self.anchor));
        }
        if !(self.interpolate > 0.0 && self.interpolate <= 1.0) {
            return bad("interpolate", format!("{}: must be in (0, 1]", self.interpolate));
        }
        if self.directions.is_empty() {
            return bad("directions", "name forward, inverse or both".into());
        }
        for d in &self.directions {
            if d != "forward" && d != "inverse" {
                return bad("directions", format!("`{d}` is not forward or inverse"));
            }
        }
        Ok(())
    }

    pub fn adapts(&self, forward: bool) -> bool {
        self.directions
            .iter()
            .any(|d| d == if forward { "forward" } else { "inverse" })
    }
}
