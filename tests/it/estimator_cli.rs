//! `bowden estimate --frames DIR` on a recording made with the camera's recorder, and
//! `bowden estimator eval`, end to end through the binary; bad inputs give one-line errors
//! naming what is wrong.

use bowden_camera::{CameraConfig, Recorder, StreamInfo, SyntheticCamera};
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use std::process::Command;

fn bowden() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bowden"))
}

#[test]
fn estimate_on_a_recording() {
    let dir = tempfile::tempdir().unwrap();
    let rec_dir = dir.path().join("rec");
    let mut cam = SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        3,
    );
    let configs = [
        [10.0, -15.0, 20.0, -20.0, 20.0],
        [-25.0, 20.0, 10.0, -5.0, 30.0],
        [40.0, 0.0, -30.0, -35.0, 0.0],
    ];
    let px = (cam.width() * cam.height()) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let mut rec = Recorder::create(&rec_dir, StreamInfo::from_header(&cam.header(0, 0, 0))).unwrap();
    for (i, q) in configs.iter().enumerate() {
        cam.render(q, i as u64, &mut rgb, &mut depth).unwrap();
        rec.record(&cam.header(i as u64, i as u64, 1000 * i as u64).header, &rgb, &depth)
            .unwrap();
    }
    rec.finish().unwrap();

    let out = bowden()
        .args(["estimate", "--json", "--frames"])
        .arg(&rec_dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let records: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let records = records.as_array().unwrap();
    assert_eq!(records.len(), configs.len());
    for (r, q) in records.iter().zip(&configs) {
        assert_eq!(r["quality"], "valid", "{r}");
        for k in 0..5 {
            let est = r["q_phy_deg"][k].as_f64().unwrap();
            assert!((est - q[k]).abs() < 1.5, "q{} = {est} for truth {}", k + 1, q[k]);
        }
        assert_eq!(r["markers"].as_array().unwrap().len(), 7);
    }
    assert_eq!(records[2]["seq"], 2);
    assert_eq!(records[2]["t_origin_ns"], 2000);

    // The table form, with a hint.
    let out = bowden()
        .args(["estimate", "--hint", "0,0,0,-10,10", "--frames"])
        .arg(&rec_dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("3 frames: 3 valid, 0 partial, 0 invalid"), "{text}");
}

#[test]
fn eval_reports_against_the_goals() {
    let dir = tempfile::tempdir().unwrap();
    let out = bowden()
        .args([
            "estimator",
            "eval",
            "--frames",
            "25",
            "--seed",
            "5",
            "--json",
            "--check",
            "--out",
        ])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rep: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    assert_eq!(rep["options"]["frames"], 25);
    assert!(rep["detection_rate"].as_f64().unwrap() >= 0.99);
    assert!(rep["centre_error_rms_mm"].as_f64().unwrap() <= 0.5);
    for k in 0..5 {
        assert!(
            rep["joint_error_rms_deg"][k].as_f64().unwrap() <= 1.0,
            "{}",
            rep["joint_error_rms_deg"]
        );
    }
    assert!(rep["time_p50_us"].as_f64().unwrap() > 0.0);
    for f in ["eval.json", "eval.md", "eval.svg"] {
        let p = dir.path().join(f);
        assert!(
            std::fs::metadata(&p).map(|m| m.len() > 100).unwrap_or(false),
            "{} missing",
            p.display()
        );
    }
    let svg = std::fs::read_to_string(dir.path().join("eval.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("q5"));
}

#[test]
fn bad_inputs_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    // No recording there.
    let missing = dir.path().join("nothing");
    let out = bowden().args(["estimate", "--frames"]).arg(&missing).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("index.json") && err.lines().count() == 1, "{err}");

    // A markers file whose [estimator] table is broken.
    let text = std::fs::read_to_string("configs/markers.toml").unwrap();
    let bad = dir.path().join("markers.toml");
    std::fs::write(&bad, text.replace("ransac_iterations = 48", "ransac_iterations = 0")).unwrap();
    let out = bowden()
        .args(["estimator", "eval", "--frames", "1", "--markers"])
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("markers.toml") && err.contains("estimator.ransac_iterations"),
        "{err}"
    );

    let out = bowden()
        .args(["estimate", "--hint", "1,2,3", "--frames"])
        .arg(&missing)
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("--hint"));
}
