//! Where the 7 fiducial spheres sit on the robot (`[geometry]` of `configs/markers.toml`):
//! shared by the renderer (to draw them) and the estimator (to invert eq. 6–14).

use nalgebra::{Point3, Vector3};
use serde::Deserialize;
use std::path::Path;

use crate::config::ConfigError;
use crate::fk::FkResult;
use bowden_interfaces::N_MARKERS;

/// Marker positions: base spheres in the base frame, jaw spheres in their jaw frame, mm.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MarkerGeometry {
    pub base_radius_mm: f64,
    pub jaw_radius_mm: f64,
    pub r0_base_mm: [f64; 3],
    pub r1_base_mm: [f64; 3],
    pub b0_base_mm: [f64; 3],
    pub r2_left_mm: [f64; 3],
    pub b1_left_mm: [f64; 3],
    pub y0_right_mm: [f64; 3],
    pub g0_right_mm: [f64; 3],
}

#[derive(Deserialize)]
struct File {
    geometry: MarkerGeometry,
}

impl MarkerGeometry {
    /// Reads the `[geometry]` table of a markers file (other tables are ignored here).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            origin: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| ConfigError::Parse {
            origin: path.display().to_string(),
            message: e.to_string().replace('\n', " "),
        })?;
        let geometry = table.get("geometry").cloned().ok_or_else(|| ConfigError::Invalid {
            origin: path.display().to_string(),
            field: "geometry".into(),
            problem: "missing table".into(),
        })?;
        let file: File = toml::Table::from_iter([("geometry".to_string(), geometry)])
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Parse {
                origin: path.display().to_string(),
                message: e.to_string().replace('\n', " "),
            })?;
        let g = file.geometry;
        let bad = |field: &str, problem: String| ConfigError::Invalid {
            origin: path.display().to_string(),
            field: format!("geometry.{field}"),
            problem,
        };
        for (f, r) in [("base_radius_mm", g.base_radius_mm), ("jaw_radius_mm", g.jaw_radius_mm)] {
            if !(r.is_finite() && r > 0.0) {
                return Err(bad(f, format!("must be positive, got {r}")));
            }
        }
        for (f, v) in g.named() {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(bad(f, "must be finite".into()));
            }
        }
        // Eq. (7) needs r0→r1 ⟂ r1→b0 to give an orthonormal base frame.
        let y = Vector3::from(g.r1_base_mm) - Vector3::from(g.r0_base_mm);
        let z = Vector3::from(g.b0_base_mm) - Vector3::from(g.r1_base_mm);
        if y.norm() < 1e-6 || z.norm() < 1e-6 || (y.normalize().dot(&z.normalize())).abs() > 1e-6 {
            return Err(bad(
                "r0/r1/b0_base_mm",
                "r0→r1 and r1→b0 must be non-zero and perpendicular (eq. 7)".into(),
            ));
        }
        Ok(g)
    }

    /// The geometry the repository ships (`configs/markers.toml`, embedded at build time).
    pub fn paper_default() -> Self {
        Self::parse(
            include_str!("../../../configs/markers.toml"),
            Path::new("configs/markers.toml"),
        )
        .expect("the shipped configs/markers.toml is valid")
    }

    fn named(&self) -> [(&'static str, [f64; 3]); N_MARKERS] {
        [
            ("r0_base_mm", self.r0_base_mm),
            ("r1_base_mm", self.r1_base_mm),
            ("b0_base_mm", self.b0_base_mm),
            ("r2_left_mm", self.r2_left_mm),
            ("b1_left_mm", self.b1_left_mm),
            ("y0_right_mm", self.y0_right_mm),
            ("g0_right_mm", self.g0_right_mm),
        ]
    }

    /// Radius of each marker, indexed like `bowden_interfaces::marker`.
    pub fn radii_mm(&self) -> [f64; N_MARKERS] {
        let (b, j) = (self.base_radius_mm, self.jaw_radius_mm);
        [b, b, b, j, j, j, j]
    }

    /// Centres of the 7 spheres in the robot base frame for a configuration's FK.
    pub fn centres_base_mm(&self, fk: &FkResult) -> [Point3<f64>; N_MARKERS] {
        let p = |v: [f64; 3]| Point3::from(v);
        [
            p(self.r0_base_mm),
            p(self.r1_base_mm),
            p(self.b0_base_mm),
            fk.jaw_left * p(self.r2_left_mm),
            fk.jaw_left * p(self.b1_left_mm),
            fk.jaw_right * p(self.y0_right_mm),
            fk.jaw_right * p(self.g0_right_mm),
        ]
    }

    /// L_base of eq. (7): from the midpoint of r0 and r1 to the robot base origin, in the
    /// base frame.
    pub fn l_base_mm(&self) -> Vector3<f64> {
        -(Vector3::from(self.r0_base_mm) + Vector3::from(self.r1_base_mm)) * 0.5
    }
}
