//! A short evaluation through the real multi-process lockstep pipeline with the shipped
//! models: the calibrated controller must beat the uncalibrated one by a clear margin, and the
//! report files must be produced and parseable.

use std::process::Command;

#[test]
fn short_evaluation_calibrated_beats_uncalibrated() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_bowden"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args([
            "evaluate",
            "--trajectories",
            "circle",
            "--controllers",
            "uncalibrated,paper,newton",
            "--repeats",
            "2",
            "--max-points",
            "25",
            "--report",
        ])
        .arg(dir.path())
        .output()
        .expect("bowden runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "evaluate failed: {stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("Table V") && stdout.contains("Table VI"), "{stdout}");
    for f in ["report.md", "report.json", "path_circle.svg", "error_circle.svg"] {
        let p = dir.path().join(f);
        assert!(p.is_file() && std::fs::metadata(&p).unwrap().len() > 100, "{f} missing");
    }
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.path().join("report.json")).unwrap()).unwrap();
    let cells = v["summary"]["cells"].as_array().unwrap();
    let pos = |ctrl: &str, by: &str| {
        cells.iter().find(|c| c["controller"] == ctrl).unwrap()[by]["pos_mean_mm"]
            .as_f64()
            .unwrap()
    };
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 6, "3 controllers × 2 repeats");
    // Both calibrated controllers beat the uncalibrated one by a clear margin, measured both
    // by vision and by the simulator's truth (measured with the shipped models: 7.48 mm →
    // 0.77 mm paper mode, 0.74 mm newton; the models trained on eq. (16) alone reached only
    // 0.66× of uncalibrated, so this fails if the shipped models regress to them).
    for by in ["task_truth", "task_vision"] {
        let u = pos("uncalibrated", by);
        for ctrl in ["paper", "newton"] {
            let c = pos(ctrl, by);
            assert!(c < 0.3 * u, "{by}: {ctrl} {c:.2} mm vs uncalibrated {u:.2} mm");
        }
    }
    // Repeats differ (their own seeds) but the same seed gives the same run: checked by the
    // runtime's determinism tests; here the two repeats must not be byte-identical.
    assert_ne!(runs[0]["points"], runs[1]["points"]);
}
