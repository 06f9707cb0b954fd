//! RGBD sources for bowden: a synthetic D435-like camera that renders the paper's robot and
//! its 7 coloured fiducial spheres (Park et al., RA-L 2024, §IV-A, Fig. 8), and a recorder /
//! replay source of frame sequences on disk, so recorded real-camera data drives the same
//! pipeline.
//!
//! ```no_run
//! use bowden_camera::{CameraConfig, SyntheticCamera};
//! use bowden_kinematics::{markers::MarkerGeometry, Robot};
//! let mut cam = SyntheticCamera::new(Robot::paper_default(), MarkerGeometry::paper_default(),
//!                                    CameraConfig::paper_default(), 7);
//! let px = (cam.width() * cam.height()) as usize;
//! let (mut rgb, mut depth_mm) = (vec![0u8; px * 3], vec![0u16; px]);
//! cam.render(&[10.0, -5.0, 20.0, -10.0, 15.0], 0, &mut rgb, &mut depth_mm).unwrap();
//! ```
//!
//! Conventions: camera frame x right, y down, z forward; pixel (u, v) with integer
//! coordinates is that pixel's centre; depth is the camera-frame Z in counts of
//! `depth.unit_mm` (1 mm by default), 0 = no depth.
//!
//! The scene: the 7 spheres where FK puts them (`MarkerGeometry::centres_base_mm`), the
//! flexure-hinge body as capsules along `Robot::centerline` (radius `module_radius_mm`), the
//! two jaws as thin capsules, the proximal shaft, and a textured backdrop plane. Colour is
//! Lambertian (plus a weak Blinn–Phong highlight) in linear light, encoded to sRGB.
//!
//! The sensor (`[depth]` and `[color]` of `configs/camera.toml`), modelled on a D435:
//! - depth quantised to `unit_mm`, noise σ = floor + coeff·Z² (stereo error grows with Z²);
//! - no depth where the surface is seen at grazing angles (the rim of every sphere), within
//!   `edge_invalid_px` of depth discontinuities, in the stereo occlusion shadow left of
//!   foreground objects (the second imager, `stereo_baseline_mm` to the right, cannot see
//!   there), outside [min_mm, max_mm], and at random with `dropout_prob`;
//! - colour noise σ² = read² + gain·value per channel.
//!
//! All noise comes from ChaCha8 seeded with the camera's seed on stream = frame index, a
//! fixed number of bits per pixel: frame k is the same bytes whatever was rendered before.

#![forbid(unsafe_code)]

pub mod bench;
pub mod camera;
pub mod config;
pub mod error;
pub mod node;
pub mod noise;
pub mod pngio;
pub mod record;
pub mod source;

pub use camera::{label, SyntheticCamera};
pub use config::{AppearanceConfig, BackgroundConfig, CameraConfig, ColorConfig, DepthConfig, Intrinsics, PoseConfig};
pub use error::CameraError;
pub use record::{FrameEntry, Recorder, RecordingIndex, ReplaySource, StreamInfo};
pub use source::{FrameSource, RecordedFrames};
