//! camera.toml: the shipped default is valid and D435-like; bad files are refused naming
//! the file and the field.

use bowden_camera::{CameraConfig, CameraError};
use bowden_interfaces::config::ConfigError;
use std::path::Path;

const SHIPPED: &str = include_str!("../../../../configs/camera.toml");

fn parse(text: &str) -> Result<CameraConfig, CameraError> {
    CameraConfig::parse(text, Path::new("test/camera.toml"))
}

#[test]
fn shipped_default_is_a_d435_at_640x480() {
    let c = CameraConfig::paper_default();
    let k = c.intrinsics;
    assert_eq!((k.width_px, k.height_px), (640, 480));
    assert!((k.fx_px - 615.0).abs() < 20.0 && (k.fy_px - 615.0).abs() < 20.0);
    assert_eq!((k.cx_px, k.cy_px), (320.0, 240.0));
    assert_eq!(c.depth.unit_mm, 1.0);
    assert_eq!(c.depth.stereo_baseline_mm, 50.0);
    let loaded = CameraConfig::load(concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs/camera.toml")).expect("load");
    assert_eq!(loaded, c);
}

fn expect_field(text: &str, field: &str) {
    match parse(text) {
        Err(e @ CameraError::Config(ConfigError::Invalid { .. })) => {
            let msg = e.to_string();
            assert!(msg.contains("test/camera.toml") && msg.contains(field), "{msg}");
        }
        other => panic!("expected an error on {field}, got {other:?}"),
    }
}

#[test]
fn bad_values_name_the_field() {
    let cases = [
        ("fx_px = 615.0", "fx_px = -615.0", "intrinsics.fx_px"),
        ("fx_px = 615.0", "fx_px = nan", "intrinsics.fx_px"),
        ("width_px = 640", "width_px = 0", "intrinsics.width_px"),
        ("up_base = [0.0, 0.0, 1.0]", "up_base = [0.0, 0.0, 0.0]", "pose.up_base"),
        ("unit_mm = 1.0", "unit_mm = 0.0", "depth.unit_mm"),
        ("min_mm = 135.0", "min_mm = 5000.0", "depth.min_mm"),
        ("max_mm = 3000.0", "max_mm = 70000.0", "depth.max_mm"),
        ("dropout_prob = 0.002", "dropout_prob = 1.5", "depth.dropout_prob"),
        (
            "silhouette_grazing_deg = 72.0",
            "silhouette_grazing_deg = 120.0",
            "depth.silhouette_grazing_deg",
        ),
        ("shininess = 24.0", "shininess = 0.0", "color.shininess"),
        (
            "jaw_radius_mm = 0.7",
            "jaw_radius_mm = -1.0",
            "appearance.jaw_radius_mm",
        ),
        (
            "normal_base = [0.433, 0.75, 0.5]",
            "normal_base = [0.0, 0.0, 0.0]",
            "background.normal_base",
        ),
        (
            "checker_contrast = 0.12",
            "checker_contrast = 2.0",
            "background.checker_contrast",
        ),
    ];
    for (from, to, field) in cases {
        assert!(SHIPPED.contains(from), "{from} not in the shipped file");
        expect_field(&SHIPPED.replacen(from, to, 1), field);
    }
    // Looking at the camera's own position.
    let mut c = CameraConfig::paper_default();
    c.pose.look_at_base_mm = c.pose.position_base_mm;
    assert!(
        matches!(c.validate(Path::new("x.toml")), Err(CameraError::Config(ConfigError::Invalid { field, .. })) if field == "pose.look_at_base_mm")
    );
}

#[test]
fn malformed_or_unknown_keys_and_missing_files_are_refused() {
    let unknown = SHIPPED.replacen("fx_px = 615.0", "fx_px = 615.0\nfocal = 3.0", 1);
    match parse(&unknown) {
        Err(e @ CameraError::Config(ConfigError::Parse { .. })) => assert!(e.to_string().contains("focal"), "{e}"),
        other => panic!("{other:?}"),
    }
    let missing = SHIPPED.replacen("fy_px = 615.0", "", 1);
    assert!(matches!(
        parse(&missing),
        Err(CameraError::Config(ConfigError::Parse { .. }))
    ));
    assert!(matches!(
        parse("[intrinsics"),
        Err(CameraError::Config(ConfigError::Parse { .. }))
    ));
    match CameraConfig::load("/nonexistent/camera.toml") {
        Err(e @ CameraError::Config(ConfigError::Io { .. })) => {
            assert!(e.to_string().contains("/nonexistent/camera.toml"))
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_camera_from_an_invalid_in_memory_config_is_refused() {
    use bowden_camera::SyntheticCamera;
    use bowden_kinematics::{markers::MarkerGeometry, Robot};
    let mut c = CameraConfig::paper_default();
    c.intrinsics.width_px = 0;
    match SyntheticCamera::try_new(Robot::paper_default(), MarkerGeometry::paper_default(), c, 0) {
        Err(CameraError::Config(ConfigError::Invalid { field, .. })) => assert_eq!(field, "intrinsics.width_px"),
        other => panic!("{:?}", other.map(|_| ())),
    }
}
