//! Renders a configuration to PNGs (colour, 16-bit depth, false-colour depth, labels) for
//! eyeballing: `cargo run -p bowden-camera --example camera_look -- OUT_PREFIX q1 q2 q3 q4 q5`.

use bowden_camera::pngio::{depth_preview, write_depth_png, write_rgb_png};
use bowden_camera::{label, CameraConfig, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let prefix = args.first().cloned().unwrap_or_else(|| "/tmp/cam".into());
    let mut q = [0.0; 5];
    for (j, a) in args.iter().skip(1).take(5).enumerate() {
        q[j] = a.parse()?;
    }
    let mut cam = SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        1,
    );
    let (w, h) = (cam.width(), cam.height());
    let px = (w * h) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    cam.render(&q, 0, &mut rgb, &mut depth)?;
    write_rgb_png(&PathBuf::from(format!("{prefix}.png")), w, h, &rgb)?;
    write_depth_png(
        &PathBuf::from(format!("{prefix}_depth.png")),
        w,
        h,
        &depth,
        &mut Vec::new(),
    )?;
    write_rgb_png(
        &PathBuf::from(format!("{prefix}_depth_vis.png")),
        w,
        h,
        &depth_preview(&depth),
    )?;
    // A ×4 nearest-neighbour zoom on the jaw markers, colour and depth preview side by side.
    let c = cam.marker_centres_cam_mm(&q)[3];
    if let Some((cu, cv)) = cam.intrinsics().project(&c) {
        let (zw, zh, s) = (48usize, 48usize, 4usize);
        let u0 = (cu as isize - zw as isize / 2).clamp(0, w as isize - zw as isize) as usize;
        let v0 = (cv as isize - zh as isize / 2).clamp(0, h as isize - zh as isize) as usize;
        let vis = depth_preview(&depth);
        let mut zoom = vec![0u8; zw * s * 2 * zh * s * 3];
        let zrow = zw * s * 2;
        for y in 0..zh * s {
            for x in 0..zw * s {
                let src = ((v0 + y / s) * w as usize + u0 + x / s) * 3;
                zoom[(y * zrow + x) * 3..][..3].copy_from_slice(&rgb[src..src + 3]);
                zoom[(y * zrow + zw * s + x) * 3..][..3].copy_from_slice(&vis[src..src + 3]);
            }
        }
        write_rgb_png(
            &PathBuf::from(format!("{prefix}_zoom.png")),
            (zw * s * 2) as u32,
            (zh * s) as u32,
            &zoom,
        )?;
    }
    let mut counts = [0usize; 13];
    let mut valid = [0usize; 13];
    for (i, &l) in cam.labels().iter().enumerate() {
        let k = (l & label::WHAT_MASK) as usize;
        counts[k] += 1;
        if depth[i] > 0 {
            valid[k] += 1;
        }
    }
    println!("pixels per label: {counts:?}\nwith depth:       {valid:?}");
    for (i, c) in cam.marker_centres_cam_mm(&q).iter().enumerate() {
        println!(
            "marker {i}: cam {:.1} {:.1} {:.1} -> px {:?}",
            c.x,
            c.y,
            c.z,
            cam.intrinsics().project(c)
        );
    }
    Ok(())
}
