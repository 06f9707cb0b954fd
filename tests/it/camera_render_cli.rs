//! `bowden render` writes a colour PNG, a 16-bit depth PNG and a false-colour preview that
//! decode to what the camera library renders; bad arguments fail with a one-line error.

use bowden_camera::pngio::{read_depth_png, read_rgb_png};
use bowden_camera::{CameraConfig, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use std::process::Command;

fn bowden() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_bowden"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

#[test]
fn render_writes_colour_depth_and_preview_equal_to_the_library() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("pose.png");
    let status = bowden()
        .args([
            "render",
            "--q",
            "20,-30,25,-20,15",
            "--seed",
            "3",
            "--frame",
            "2",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("run bowden");
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let stdout = String::from_utf8_lossy(&status.stdout);
    assert!(stdout.contains("r0") && stdout.contains("g0"), "{stdout}");

    let mut cam = SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        3,
    );
    let px = 640 * 480;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    cam.render(&[20.0, -30.0, 25.0, -20.0, 15.0], 2, &mut rgb, &mut depth)
        .expect("render");
    let (mut rgb_file, mut depth_file, mut vis) = (vec![0u8; px * 3], vec![0u16; px], vec![0u8; px * 3]);
    let mut scratch = Vec::new();
    read_rgb_png(&out, 640, 480, &mut rgb_file, &mut scratch).expect("colour");
    read_depth_png(
        &dir.path().join("pose_depth.png"),
        640,
        480,
        &mut depth_file,
        &mut scratch,
    )
    .expect("depth");
    read_rgb_png(&dir.path().join("pose_depth_vis.png"), 640, 480, &mut vis, &mut scratch).expect("preview");
    assert!(rgb_file == rgb, "colour PNG differs from the library render");
    assert!(depth_file == depth, "depth PNG differs from the library render");
    // The preview is black exactly where there is no depth.
    for (d, p) in depth.iter().zip(vis.chunks_exact(3)) {
        assert_eq!(*d == 0, p == [0, 0, 0]);
    }
}

#[test]
fn render_rejects_bad_arguments_in_one_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (args, needle) in [
        (vec!["render", "--q", "1,2,3"], "--q"),
        (vec!["render", "--q", "1,2,nan,4,5"], "--q"),
        (
            vec!["render", "--q", "0,0,0,0,0", "--config", "/nonexistent/camera.toml"],
            "/nonexistent/camera.toml",
        ),
    ] {
        let out = bowden()
            .args(&args)
            .arg("--out")
            .arg(dir.path().join("x.png"))
            .output()
            .expect("run");
        assert!(!out.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(needle) && err.trim().lines().count() == 1,
            "{args:?}: {err}"
        );
    }
}
