//! The estimator's settings: the `[hsv]` and `[estimator]` tables of `configs/markers.toml`
//! (the `[geometry]` table of the same file belongs to `bowden-kinematics`). Validated on
//! load; every error names the file and the field.

use serde::Deserialize;
use std::path::Path;

pub use bowden_interfaces::config::ConfigError;

/// One colour class in HSV space. Hue in degrees on [0, 360); when `h_min_deg > h_max_deg`
/// the range wraps through 0 (red). Saturation and value on [0, 1] (value = max(R,G,B)/255).
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HsvRange {
    pub h_min_deg: f64,
    pub h_max_deg: f64,
    pub s_min: f64,
    pub s_max: f64,
    pub v_min: f64,
    pub v_max: f64,
}

impl HsvRange {
    /// Whether an (h, s, v) triple lies in this range.
    #[inline]
    pub fn contains(&self, h_deg: f32, s: f32, v: f32) -> bool {
        let hue_ok = if self.h_min_deg <= self.h_max_deg {
            h_deg >= self.h_min_deg as f32 && h_deg <= self.h_max_deg as f32
        } else {
            h_deg >= self.h_min_deg as f32 || h_deg <= self.h_max_deg as f32
        };
        hue_ok && s >= self.s_min as f32 && s <= self.s_max as f32 && v >= self.v_min as f32 && v <= self.v_max as f32
    }
}

/// HSV ranges of the four marker colours (paper Fig. 8: red r0 r1 r2, blue b0 b1, yellow y0,
/// green g0).
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HsvConfig {
    pub red: HsvRange,
    pub blue: HsvRange,
    pub yellow: HsvRange,
    pub green: HsvRange,
}

impl HsvConfig {
    /// The ranges in [`crate::Colour`] order.
    pub fn ranges(&self) -> [HsvRange; 4] {
        [self.red, self.blue, self.yellow, self.green]
    }
}

/// Detection, fitting and gating parameters.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct EstimatorParams {
    /// Depth readings outside [depth_min_mm, depth_max_mm] are treated as missing.
    pub depth_min_mm: f64,
    pub depth_max_mm: f64,
    /// Connected components with fewer pixels are ignored (colour noise, specks).
    pub min_blob_pixels: u32,
    /// RANSAC hypotheses per sphere (3-point samples with the known radius).
    pub ransac_iterations: u32,
    /// A point is an inlier when its distance to the sphere surface is below this.
    pub ransac_inlier_mm: f64,
    /// Hypotheses are scored on at most this many points (evenly strided); the final
    /// inlier set and the least-squares refinement use every point.
    pub ransac_max_points: u32,
    /// The least-squares iterations of a sphere use at most this many of its depth points
    /// (evenly strided; a base sphere close to the camera has hundreds more than needed to
    /// converge); the final step and the statistics use every inlier.
    pub max_fit_points: u32,
    /// A sphere fit is accepted with at least this many inliers …
    pub min_inliers: u32,
    /// … making up at least this fraction of the blob's points with depth …
    pub min_inlier_fraction: f64,
    /// … and an RMS distance of inliers to the surface at most this.
    pub max_fit_rms_mm: f64,
    /// Silhouette step (see `sphere`): least edge points supporting the outline, largest
    /// arc concentration (0 = complete outline, 1 = a point), and how far (in the depth
    /// fit's lateral standard deviations, at least `silhouette_min_agreement_mm`) the
    /// outline's axis may lie from the depth fit's centre before the two count as
    /// disagreeing (the centre's covariance then grows by their difference).
    pub silhouette_min_edges: u32,
    pub silhouette_max_arc_concentration: f64,
    pub silhouette_agreement_sigmas: f64,
    pub silhouette_min_agreement_mm: f64,
    /// With a complete outline, a sphere needs only this many depth points (for its range).
    pub silhouette_min_depth_points: u32,
    /// Allowed systematic error of an outline's apparent radius, px (blur, thresholds):
    /// sets the range uncertainty of a jaw sphere known by its outline alone.
    pub silhouette_size_bias_px: f64,
    /// Seed of the RANSAC sampler (the same frame always gives the same answer).
    pub seed: u64,
    /// The three base centres are accepted when every pairwise distance is within this of
    /// the geometry's (catches a wrong blob taken for a base sphere).
    pub base_distance_tol_mm: f64,
    /// Largest RMS distance between the measured jaw centres and the fitted model (the
    /// jaw-pair model of eq. 8–10, and the joint-space fit), mm. Above it the jaw data are
    /// inconsistent and no joint is reported.
    pub jaw_fit_rms_max_mm: f64,
    /// Added in quadrature to every fitted centre's standard deviation (per axis) before
    /// the joint-space fit weighs the centres: the error no sphere fit sees (calibration,
    /// colour–depth registration, marker placement).
    pub centre_sigma_floor_mm: f64,
    /// A joint is reported only when its predicted standard deviation is at most this
    /// (an unobservable joint, e.g. q5 with the right jaw hidden, has an infinite one).
    pub joint_sigma_max_deg: f64,
    /// IK (`robot.ik`) tolerances: the IK gives the starting point of the joint-space fit,
    /// so it stops at the measurement's noise level rather than at machine precision.
    pub ik_tol_pos_mm: f64,
    pub ik_tol_rot_deg: f64,
    pub ik_max_iterations: u32,
    /// Physical angles may pass the command limits a little (hysteresis, slack); beyond
    /// the limits by more than this a joint is reported invalid.
    pub limit_margin_deg: f64,
    /// Refine the joints by least squares on the measured jaw centres (true, bowden's
    /// default) or stop at the paper's eq. 6–14 + IK (false).
    pub refine_joints: bool,
    /// Gauss–Newton iterations of the joint-space fit.
    pub refine_max_iterations: u32,
}

/// Everything the estimator reads from its config file.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct EstimatorConfig {
    pub hsv: HsvConfig,
    pub estimator: EstimatorParams,
}

impl EstimatorConfig {
    /// Reads the `[hsv]` and `[estimator]` tables of a markers file (other tables, e.g.
    /// `[geometry]`, are left to their readers).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            origin: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses the text of a markers file; `path` is only used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let parse_err = |message: String| ConfigError::Parse {
            origin: path.display().to_string(),
            message: message.replace('\n', " "),
        };
        let table: toml::Table = toml::from_str(text).map_err(|e| parse_err(e.to_string()))?;
        let mut mine = toml::Table::new();
        for key in ["hsv", "estimator"] {
            let value = table.get(key).cloned().ok_or_else(|| ConfigError::Invalid {
                origin: path.display().to_string(),
                field: key.into(),
                problem: "missing table".into(),
            })?;
            mine.insert(key.to_string(), value);
        }
        let cfg: EstimatorConfig = mine.try_into().map_err(|e: toml::de::Error| parse_err(e.to_string()))?;
        cfg.validate(path)?;
        Ok(cfg)
    }

    /// The settings the repository ships (`configs/markers.toml`, embedded at build time).
    pub fn paper_default() -> Self {
        Self::parse(
            include_str!("../../../configs/markers.toml"),
            Path::new("configs/markers.toml"),
        )
        .expect("the shipped configs/markers.toml [hsv]/[estimator] tables are valid")
    }

    /// Long by design (over 120 lines): one check per field, in the file's order, so every
    /// rule of the schema is in one place beside its struct; each check is a few lines and
    /// shares nothing with the next, so helpers would only scatter the schema.
    // Long: one flat list of independent checks, each naming its field.
    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |field: String, problem: String| ConfigError::Invalid {
            origin: path.display().to_string(),
            field,
            problem,
        };
        for (name, r) in ["red", "blue", "yellow", "green"].iter().zip(self.hsv.ranges()) {
            let f = |k: &str| format!("hsv.{name}.{k}");
            for (k, v) in [("h_min_deg", r.h_min_deg), ("h_max_deg", r.h_max_deg)] {
                if !(v.is_finite() && (0.0..=360.0).contains(&v)) {
                    return Err(bad(f(k), format!("must be in [0, 360], got {v}")));
                }
            }
            for (k, v) in [
                ("s_min", r.s_min),
                ("s_max", r.s_max),
                ("v_min", r.v_min),
                ("v_max", r.v_max),
            ] {
                if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                    return Err(bad(f(k), format!("must be in [0, 1], got {v}")));
                }
            }
            if r.s_min > r.s_max {
                return Err(bad(f("s_min"), format!("{} exceeds s_max {}", r.s_min, r.s_max)));
            }
            if r.v_min > r.v_max {
                return Err(bad(f("v_min"), format!("{} exceeds v_max {}", r.v_min, r.v_max)));
            }
            // A colour must exclude grey: with s_min = 0 the body and background would match.
            if r.s_min <= 0.0 {
                return Err(bad(
                    f("s_min"),
                    "must be > 0 (grey pixels would match every colour)".into(),
                ));
            }
        }
        let e = &self.estimator;
        let f = |k: &str| format!("estimator.{k}");
        let positive = [
            ("depth_max_mm", e.depth_max_mm),
            ("ransac_inlier_mm", e.ransac_inlier_mm),
            ("max_fit_rms_mm", e.max_fit_rms_mm),
            ("base_distance_tol_mm", e.base_distance_tol_mm),
            ("jaw_fit_rms_max_mm", e.jaw_fit_rms_max_mm),
            ("silhouette_agreement_sigmas", e.silhouette_agreement_sigmas),
            ("silhouette_min_agreement_mm", e.silhouette_min_agreement_mm),
            ("silhouette_size_bias_px", e.silhouette_size_bias_px),
            ("joint_sigma_max_deg", e.joint_sigma_max_deg),
            ("ik_tol_pos_mm", e.ik_tol_pos_mm),
            ("ik_tol_rot_deg", e.ik_tol_rot_deg),
        ];
        for (k, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(f(k), format!("must be a positive number, got {v}")));
            }
        }
        if !(e.depth_min_mm.is_finite() && e.depth_min_mm >= 0.0 && e.depth_min_mm < e.depth_max_mm) {
            return Err(bad(
                f("depth_min_mm"),
                format!(
                    "must be in [0, depth_max_mm = {}), got {}",
                    e.depth_max_mm, e.depth_min_mm
                ),
            ));
        }
        if !(e.centre_sigma_floor_mm.is_finite() && e.centre_sigma_floor_mm >= 0.0) {
            return Err(bad(
                f("centre_sigma_floor_mm"),
                format!("must be ≥ 0, got {}", e.centre_sigma_floor_mm),
            ));
        }
        if !(e.silhouette_max_arc_concentration.is_finite()
            && (0.0..=1.0).contains(&e.silhouette_max_arc_concentration))
        {
            return Err(bad(
                f("silhouette_max_arc_concentration"),
                format!("must be in [0, 1], got {}", e.silhouette_max_arc_concentration),
            ));
        }
        if e.silhouette_min_depth_points < 1 {
            return Err(bad(f("silhouette_min_depth_points"), "must be ≥ 1".into()));
        }
        if e.silhouette_min_edges < 3 {
            return Err(bad(
                f("silhouette_min_edges"),
                format!("must be ≥ 3, got {}", e.silhouette_min_edges),
            ));
        }
        if !(e.limit_margin_deg.is_finite() && e.limit_margin_deg >= 0.0) {
            return Err(bad(
                f("limit_margin_deg"),
                format!("must be ≥ 0, got {}", e.limit_margin_deg),
            ));
        }
        if !(e.min_inlier_fraction.is_finite() && (0.0..=1.0).contains(&e.min_inlier_fraction)) {
            return Err(bad(
                f("min_inlier_fraction"),
                format!("must be in [0, 1], got {}", e.min_inlier_fraction),
            ));
        }
        // A sphere with a known radius needs 3 points per hypothesis; fewer inliers cannot
        // distinguish a sphere from noise.
        if e.min_inliers < 4 {
            return Err(bad(f("min_inliers"), format!("must be ≥ 4, got {}", e.min_inliers)));
        }
        if e.min_blob_pixels < 1 {
            return Err(bad(f("min_blob_pixels"), "must be ≥ 1".into()));
        }
        for (k, v) in [
            ("ransac_iterations", e.ransac_iterations),
            ("ransac_max_points", e.ransac_max_points),
            ("max_fit_points", e.max_fit_points),
            ("ik_max_iterations", e.ik_max_iterations),
            ("refine_max_iterations", e.refine_max_iterations),
        ] {
            if v == 0 {
                return Err(bad(f(k), "must be ≥ 1".into()));
            }
        }
        if e.ransac_max_points < 3 {
            return Err(bad(f("ransac_max_points"), "must be ≥ 3".into()));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_config_is_valid() {
        let c = EstimatorConfig::paper_default();
        assert!(c.estimator.ransac_iterations > 0);
    }

    #[test]
    fn red_hue_wraps_through_zero() {
        let r = EstimatorConfig::paper_default().hsv.red;
        assert!(r.h_min_deg > r.h_max_deg, "red is expected to wrap");
        assert!(r.contains(0.0, 0.9, 0.8));
        assert!(r.contains(359.0, 0.9, 0.8));
        assert!(!r.contains(120.0, 0.9, 0.8));
        assert!(!r.contains(0.0, 0.01, 0.8), "grey is not red");
    }

    #[test]
    fn errors_name_file_and_field() {
        let text = include_str!("../../../configs/markers.toml");
        let p = Path::new("m.toml");
        let broken = text.replace("ransac_inlier_mm = ", "ransac_inlier_mm = -");
        let e = EstimatorConfig::parse(&broken, p).unwrap_err().to_string();
        assert!(e.contains("m.toml") && e.contains("estimator.ransac_inlier_mm"), "{e}");

        let unknown = text.replace("[estimator]", "[estimator]\nbogus_field = 1");
        let e = EstimatorConfig::parse(&unknown, p).unwrap_err().to_string();
        assert!(e.contains("bogus_field"), "{e}");

        let no_hsv = "[estimator]\nseed = 1\n";
        let e = EstimatorConfig::parse(no_hsv, p).unwrap_err().to_string();
        assert!(e.contains("`hsv`") && e.contains("missing"), "{e}");

        let e = EstimatorConfig::parse("this is [not toml", p).unwrap_err().to_string();
        assert!(e.contains("malformed TOML"), "{e}");

        let e = EstimatorConfig::load("/nonexistent/markers.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/markers.toml"), "{e}");
    }
}
