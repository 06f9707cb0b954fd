//! `configs/camera.toml`: intrinsics, pose, sensor noise and scene appearance, validated on
//! load with errors naming the file and the field.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::path::Path;

use crate::CameraError;
use bowden_interfaces::config::ConfigError;

/// Pinhole intrinsics of the colour-aligned RGBD stream. Pixel (u, v) with integer
/// coordinates is the centre of that pixel (OpenCV / librealsense convention):
/// u = fx·X/Z + cx, v = fy·Y/Z + cy.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    pub width_px: u32,
    pub height_px: u32,
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
}

impl Intrinsics {
    /// Pixels per frame.
    pub fn pixels(&self) -> usize {
        self.width_px as usize * self.height_px as usize
    }
    /// Projects a camera-frame point to pixel coordinates (None behind the camera).
    pub fn project(&self, p_cam_mm: &Point3<f64>) -> Option<(f64, f64)> {
        if p_cam_mm.z <= 0.0 {
            return None;
        }
        Some((
            self.fx_px * p_cam_mm.x / p_cam_mm.z + self.cx_px,
            self.fy_px * p_cam_mm.y / p_cam_mm.z + self.cy_px,
        ))
    }
    /// The camera-frame point seen at pixel (u, v) with depth Z = `depth_mm`.
    pub fn back_project(&self, u_px: f64, v_px: f64, depth_mm: f64) -> Point3<f64> {
        Point3::new(
            (u_px - self.cx_px) * depth_mm / self.fx_px,
            (v_px - self.cy_px) * depth_mm / self.fy_px,
            depth_mm,
        )
    }
}

/// Where the camera is: its optical centre and the point it looks at, in the robot base
/// frame. The camera frame is x right, y down, z forward (optical axis); `up_base_mm` fixes
/// the roll (image "up" is as close to it as the viewing direction allows).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PoseConfig {
    pub position_base_mm: [f64; 3],
    pub look_at_base_mm: [f64; 3],
    pub up_base: [f64; 3],
}

impl PoseConfig {
    /// T^base_cam: the camera's pose in the base frame (maps camera-frame points to base).
    pub fn camera_in_base(&self) -> Isometry3<f64> {
        let eye = Vector3::from(self.position_base_mm);
        let z = (Vector3::from(self.look_at_base_mm) - eye).normalize();
        let up = Vector3::from(self.up_base);
        let y = -(up - z * up.dot(&z)).normalize();
        let x = y.cross(&z);
        let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        Isometry3::from_parts(Translation3::from(eye), UnitQuaternion::from_rotation_matrix(&rot))
    }
}

/// Depth sensing: quantisation, range, noise and where a stereo sensor (D435-like) returns
/// no depth.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DepthConfig {
    /// Millimetres per depth count (RealSense default 1.0).
    pub unit_mm: f64,
    /// Closest and farthest depth the sensor reports; outside, 0 (no depth).
    pub min_mm: f64,
    pub max_mm: f64,
    /// Depth noise σ = noise_floor_mm + noise_coeff_per_mm · Z²: stereo depth error grows
    /// with the square of the distance (Z²·subpixel / (f·baseline)).
    pub noise_floor_mm: f64,
    pub noise_coeff_per_mm: f64,
    /// Distance between the stereo imagers (D435: 50 mm); sets the width of the occlusion
    /// shadow left of foreground objects.
    pub stereo_baseline_mm: f64,
    /// Model the stereo occlusion shadow (points the second imager cannot see get no depth).
    pub stereo_shadow: bool,
    /// Surfaces seen more obliquely than this (angle between normal and view ray) return no
    /// depth: the dark rim of a sphere's silhouette.
    pub silhouette_grazing_deg: f64,
    /// A depth jump larger than this between neighbouring pixels is an object edge...
    pub edge_jump_mm: f64,
    /// ...and the pixels within this many pixels of it on both sides return no depth.
    pub edge_invalid_px: u32,
    /// Probability that any pixel returns no depth (speckle dropout), 0..1.
    pub dropout_prob: f64,
}

/// Colour sensing and shading.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ColorConfig {
    /// Colour noise per channel: σ² = read_noise_dn² + shot_noise_gain_dn · value (in 8-bit DN).
    pub read_noise_dn: f64,
    pub shot_noise_gain_dn: f64,
    /// Lambertian shading: radiance = albedo · (ambient + diffuse · max(n·l, 0)) + specular.
    pub ambient: f64,
    pub diffuse: f64,
    /// Direction towards the (distant) light, in the camera frame (x right, y down, z forward).
    pub light_dir_cam: [f64; 3],
    /// Blinn–Phong highlight strength (0 = matte) and exponent.
    pub specular: f64,
    pub shininess: f64,
}

/// Colours (sRGB albedo) and sizes of what the camera sees.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AppearanceConfig {
    /// Marker colours: r0, r1, r2 red; b0, b1 blue; y0 yellow; g0 green (paper Fig. 8).
    pub red_rgb: [u8; 3],
    pub blue_rgb: [u8; 3],
    pub yellow_rgb: [u8; 3],
    pub green_rgb: [u8; 3],
    /// The flexure-hinge body (radius from the robot config).
    pub body_rgb: [u8; 3],
    /// The two jaws: capsules from the pivot along each jaw's z for `jaw_length_mm`.
    pub jaw_rgb: [u8; 3],
    pub jaw_radius_mm: f64,
    /// The proximal shaft the manipulator comes out of: a capsule of the body's radius from
    /// the base origin back along −x (0 = none).
    pub shaft_rgb: [u8; 3],
    pub shaft_length_mm: f64,
}

/// A textured plane behind the robot.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BackgroundConfig {
    /// A point on the plane and its normal, robot base frame.
    pub point_base_mm: [f64; 3],
    pub normal_base: [f64; 3],
    pub rgb: [u8; 3],
    /// Checkerboard square size on the plane, mm, and its relative albedo contrast (0..1).
    pub checker_mm: f64,
    pub checker_contrast: f64,
    /// Surface grain: cell size, mm, and relative albedo amplitude (0..1).
    pub grain_mm: f64,
    pub grain_contrast: f64,
}

/// Everything `configs/camera.toml` holds.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    pub intrinsics: Intrinsics,
    pub pose: PoseConfig,
    pub depth: DepthConfig,
    pub color: ColorConfig,
    pub appearance: AppearanceConfig,
    pub background: BackgroundConfig,
}

/// The shipped default, embedded at build time.
const DEFAULT_TOML: &str = include_str!("../../../configs/camera.toml");

impl CameraConfig {
    /// Reads and validates a camera file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CameraError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::io(path.display(), source))?;
        Self::parse(&text, path)
    }

    /// Parses and validates TOML text; `path` only names the source in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, CameraError> {
        let cfg: CameraConfig = toml::from_str(text).map_err(|e| ConfigError::parse(path.display(), e))?;
        cfg.validate(path)?;
        Ok(cfg)
    }

    /// The camera the repository ships (`configs/camera.toml`): a RealSense D435-like
    /// colour-aligned 640×480 stream looking at the paper's robot.
    pub fn paper_default() -> Self {
        Self::parse(DEFAULT_TOML, Path::new("configs/camera.toml")).expect("the shipped configs/camera.toml is valid")
    }

    /// Checks every field; the error names the first bad one.
    /// Long by design (over 120 lines): one check per field, in the file's order, so every
    /// rule of the schema is in one place beside its struct; each check is a few lines and
    /// shares nothing with the next, so helpers would only scatter the schema.
    // Long: one flat list of independent checks, each naming its field.
    pub fn validate(&self, path: &Path) -> Result<(), CameraError> {
        let bad =
            |field: &str, problem: String| CameraError::from(ConfigError::invalid(path.display(), field, problem));
        let k = &self.intrinsics;
        for (f, v) in [
            ("intrinsics.width_px", k.width_px),
            ("intrinsics.height_px", k.height_px),
        ] {
            if !(2..=8192).contains(&v) {
                return Err(bad(f, format!("must be 2..=8192, got {v}")));
            }
        }
        for (f, v) in [("intrinsics.fx_px", k.fx_px), ("intrinsics.fy_px", k.fy_px)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(f, format!("must be a positive number, got {v}")));
            }
        }
        for (f, v) in [("intrinsics.cx_px", k.cx_px), ("intrinsics.cy_px", k.cy_px)] {
            if !v.is_finite() {
                return Err(bad(f, format!("must be finite, got {v}")));
            }
        }
        let p = &self.pose;
        for (f, v) in [
            ("pose.position_base_mm", p.position_base_mm),
            ("pose.look_at_base_mm", p.look_at_base_mm),
            ("pose.up_base", p.up_base),
        ] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(bad(f, format!("must be finite, got {v:?}")));
            }
        }
        let view = Vector3::from(p.look_at_base_mm) - Vector3::from(p.position_base_mm);
        if view.norm() < 1e-6 {
            return Err(bad(
                "pose.look_at_base_mm",
                "must differ from pose.position_base_mm".into(),
            ));
        }
        let up = Vector3::from(p.up_base);
        if up.norm() < 1e-9 || view.normalize().cross(&up.normalize()).norm() < 1e-3 {
            return Err(bad(
                "pose.up_base",
                format!(
                    "must be non-zero and not parallel to the viewing direction, got {:?}",
                    p.up_base
                ),
            ));
        }
        let d = &self.depth;
        let positive = [
            ("depth.unit_mm", d.unit_mm),
            ("depth.max_mm", d.max_mm),
            ("depth.stereo_baseline_mm", d.stereo_baseline_mm),
            ("depth.edge_jump_mm", d.edge_jump_mm),
        ];
        for (f, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(f, format!("must be a positive number, got {v}")));
            }
        }
        let non_negative = [
            ("depth.min_mm", d.min_mm),
            ("depth.noise_floor_mm", d.noise_floor_mm),
            ("depth.noise_coeff_per_mm", d.noise_coeff_per_mm),
            ("color.read_noise_dn", self.color.read_noise_dn),
            ("color.shot_noise_gain_dn", self.color.shot_noise_gain_dn),
            ("color.ambient", self.color.ambient),
            ("color.diffuse", self.color.diffuse),
            ("color.specular", self.color.specular),
            ("appearance.shaft_length_mm", self.appearance.shaft_length_mm),
        ];
        for (f, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(f, format!("must be a number ≥ 0, got {v}")));
            }
        }
        if d.min_mm >= d.max_mm {
            return Err(bad(
                "depth.min_mm",
                format!("must be below depth.max_mm = {}, got {}", d.max_mm, d.min_mm),
            ));
        }
        if d.max_mm / d.unit_mm > u16::MAX as f64 {
            return Err(bad(
                "depth.max_mm",
                format!("{} mm does not fit 16 bits at depth.unit_mm = {}", d.max_mm, d.unit_mm),
            ));
        }
        if !(d.silhouette_grazing_deg.is_finite() && d.silhouette_grazing_deg > 0.0 && d.silhouette_grazing_deg <= 90.0)
        {
            return Err(bad(
                "depth.silhouette_grazing_deg",
                format!("must be in (0, 90], got {}", d.silhouette_grazing_deg),
            ));
        }
        if d.edge_invalid_px > 16 {
            return Err(bad(
                "depth.edge_invalid_px",
                format!("must be 0..=16, got {}", d.edge_invalid_px),
            ));
        }
        if !(d.dropout_prob.is_finite() && (0.0..=1.0).contains(&d.dropout_prob)) {
            return Err(bad(
                "depth.dropout_prob",
                format!("must be in [0, 1], got {}", d.dropout_prob),
            ));
        }
        let c = &self.color;
        let l = Vector3::from(c.light_dir_cam);
        if l.iter().any(|x| !x.is_finite()) || l.norm() < 1e-9 {
            return Err(bad(
                "color.light_dir_cam",
                format!("must be a finite non-zero vector, got {:?}", c.light_dir_cam),
            ));
        }
        if !(c.shininess.is_finite() && c.shininess >= 1.0) {
            return Err(bad("color.shininess", format!("must be ≥ 1, got {}", c.shininess)));
        }
        if !(self.appearance.jaw_radius_mm.is_finite() && self.appearance.jaw_radius_mm > 0.0) {
            return Err(bad(
                "appearance.jaw_radius_mm",
                format!("must be a positive number, got {}", self.appearance.jaw_radius_mm),
            ));
        }
        let b = &self.background;
        if b.point_base_mm.iter().any(|x| !x.is_finite()) {
            return Err(bad(
                "background.point_base_mm",
                format!("must be finite, got {:?}", b.point_base_mm),
            ));
        }
        let n = Vector3::from(b.normal_base);
        if n.iter().any(|x| !x.is_finite()) || n.norm() < 1e-9 {
            return Err(bad(
                "background.normal_base",
                format!("must be a finite non-zero vector, got {:?}", b.normal_base),
            ));
        }
        for (f, v) in [
            ("background.checker_mm", b.checker_mm),
            ("background.grain_mm", b.grain_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(f, format!("must be a positive number, got {v}")));
            }
        }
        for (f, v) in [
            ("background.checker_contrast", b.checker_contrast),
            ("background.grain_contrast", b.grain_contrast),
        ] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(bad(f, format!("must be in [0, 1], got {v}")));
            }
        }
        Ok(())
    }
}
