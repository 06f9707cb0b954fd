//! Shared helpers of the estimator's tests: the synthetic camera and the paper's estimator.

#![allow(dead_code)]

use bowden_camera::{CameraConfig, SyntheticCamera};
use bowden_estimator::{Estimator, EstimatorConfig};
use bowden_interfaces::{RgbdFrameHeader, N_MARKERS};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_kinematics::{JointsDeg, Robot};
use nalgebra::Point3;

pub fn camera(seed: u64) -> SyntheticCamera {
    SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        seed,
    )
}

pub fn estimator() -> Estimator {
    Estimator::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        EstimatorConfig::paper_default(),
    )
}

/// A rendered frame and its truth.
pub struct Frame {
    pub header: RgbdFrameHeader,
    pub rgb: Vec<u8>,
    pub depth: Vec<u16>,
    pub truth: [Point3<f64>; N_MARKERS],
}

pub fn render(cam: &mut SyntheticCamera, q: &JointsDeg, index: u64) -> Frame {
    let px = (cam.width() * cam.height()) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    cam.render(q, index, &mut rgb, &mut depth).expect("render");
    Frame {
        header: cam.header(index, index, 0),
        rgb,
        depth,
        truth: cam.marker_centres_cam_mm(q),
    }
}

/// A configuration in which the default camera sees all seven spheres whole.
pub const Q_ALL_VISIBLE: JointsDeg = [10.0, -15.0, 20.0, -20.0, 20.0];

/// Background-grey paint over every pixel the renderer labelled as marker `m` (the depth
/// stays): the sphere is there in depth but no longer has its colour.
pub fn paint_out_marker(frame: &mut Frame, labels: &[u8], m: usize) {
    use bowden_camera::label;
    for (i, l) in labels.iter().enumerate() {
        if l & label::WHAT_MASK == label::marker(m) {
            frame.rgb[3 * i..3 * i + 3].copy_from_slice(&[118, 118, 122]);
        }
    }
}

/// Indices of the pixels labelled as marker `m`.
pub fn marker_pixels(labels: &[u8], m: usize) -> Vec<usize> {
    use bowden_camera::label;
    labels
        .iter()
        .enumerate()
        .filter(|(_, l)| *l & label::WHAT_MASK == label::marker(m))
        .map(|(i, _)| i)
        .collect()
}

/// Outputs as text (`{:?}`), so that NaN fields compare equal to NaN.
pub fn fingerprint(ms: &bowden_interfaces::MarkerSet, je: &bowden_interfaces::JointEstimate) -> String {
    format!("{ms:?}{je:?}")
}
