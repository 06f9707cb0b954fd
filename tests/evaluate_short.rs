//! A short evaluation through the real multi-process lockstep pipeline with the shipped
//! models: the calibrated controller must beat the uncalibrated one by a clear margin, and the
//! report files must be produced and parseable.

use std::process::Command;

#[test]
fn short_evaluation_calibrated_beats_uncalibrated() {
    let dir = tempfile::tempdir().unwrap();
    let (stdout, v) = evaluate(
        &["--controllers", "uncalibrated,paper,newton", "--max-points", "25"],
        dir.path(),
    );
    assert!(stdout.contains("Table V") && stdout.contains("Table VI"), "{stdout}");
    for f in ["report.md", "report.json", "path_circle.svg", "error_circle.svg"] {
        let p = dir.path().join(f);
        assert!(p.is_file() && std::fs::metadata(&p).unwrap().len() > 100, "{f} missing");
    }
    let cells = v["summary"]["cells"].as_array().unwrap();
    let pos = |ctrl: &str, by: &str| {
        cells.iter().find(|c| c["controller"] == ctrl).unwrap()[by]["pos_mean_mm"]
            .as_f64()
            .unwrap()
    };
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 6, "3 controllers × 2 repeats");
    // Both calibrated controllers beat the uncalibrated one by a clear margin, measured both
    // by vision and by the simulator's truth (measured with the shipped models: 7.40 mm →
    // 0.76 mm paper mode, 0.70 mm newton by vision; the models trained on eq. (16) alone
    // reached only 0.66× of uncalibrated, so this fails if the shipped models regress to them).
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
    // Calibrated points carry the forward model's prediction, uncalibrated ones none.
    for r in runs {
        let has = r["points"]
            .as_array()
            .unwrap()
            .iter()
            .all(|p| p["q_predicted_deg"].is_array());
        assert_eq!(has, r["controller"] != "uncalibrated", "{}", r["controller"]);
    }
}

/// `bowden evaluate` on the circle, 2 repeats, with `extra` arguments; stdout and report.json.
fn evaluate(extra: &[&str], dir: &std::path::Path) -> (String, serde_json::Value) {
    let out = Command::new(env!("CARGO_BIN_EXE_bowden"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["evaluate", "--trajectories", "circle", "--repeats", "2"])
        .args(extra)
        .arg("--report")
        .arg(dir)
        .output()
        .expect("bowden runs");
    assert!(
        out.status.success(),
        "evaluate failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    (String::from_utf8_lossy(&out.stdout).into_owned(), v)
}

fn evaluate_units(units: &str, dir: &std::path::Path) -> (String, serde_json::Value) {
    evaluate(
        &["--controllers", "uncalibrated", "--max-points", "6", "--units", units],
        dir,
    )
}

/// A plant file is one manufactured unit: repeats (other seeds) vary the camera's noise, not
/// the robot. `--units per-repeat` runs other units of the design instead.
#[test]
fn repeats_run_the_configured_unit_unless_asked_for_others() {
    // Column `key` of every point of run `r`.
    let col = |v: &serde_json::Value, r: usize, key: &str| -> Vec<serde_json::Value> {
        let points = v["runs"][r]["points"].as_array().unwrap();
        points.iter().map(|p| p[key].clone()).collect()
    };
    let truth = |v: &serde_json::Value, r: usize| col(v, r, "q_true_deg");
    let est = |v: &serde_json::Value, r: usize| col(v, r, "q_est_deg");
    let dir = tempfile::tempdir().unwrap();
    let (stdout, v) = evaluate_units("configured", dir.path());
    assert!(stdout.contains("(unit 2026)"), "{stdout}");
    assert_eq!(truth(&v, 0), truth(&v, 1), "the same robot under the same commands");
    assert_ne!(est(&v, 0), est(&v, 1), "the camera noise differs per repeat");
    let dir = tempfile::tempdir().unwrap();
    let (stdout, v) = evaluate_units("per-repeat", dir.path());
    assert!(stdout.contains("units 1000..=1001"), "{stdout}");
    assert_ne!(truth(&v, 0), truth(&v, 1), "two units of the design differ");
}
