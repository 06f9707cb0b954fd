//! `bowden compensate` end to end: CSV in, CSV out, and clear errors for bad input.

use std::path::PathBuf;
use std::process::Command;

fn bowden() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_bowden"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("tests/fixtures/pytorch/{name}.onnx"))
}

#[test]
fn compensate_writes_one_row_per_target() {
    let dir = tempfile::tempdir().unwrap();
    let targets = dir.path().join("targets.csv");
    let mut csv = String::from("t_ns,q1,q2,q3,q4,q5\n");
    for k in 0..30 {
        let s = k as f64;
        csv += &format!(
            "{},{},{},{},{},{}\n",
            k * 1000,
            0.5 * s,
            -0.3 * s,
            0.2 * s,
            -0.1 * s,
            0.4 * s
        );
    }
    std::fs::write(&targets, csv).unwrap();
    let out = dir.path().join("out.csv");
    for mode in ["paper", "newton", "uncalibrated"] {
        let st = bowden()
            .args(["compensate", "--mode", mode, "--targets"])
            .arg(&targets)
            .arg("--model-fwd")
            .arg(fixture("tcn-linear2_forward_L80_J5_s0"))
            .arg("--model-inv")
            .arg(fixture("tcn-linear2_inverse_L80_J5_s0"))
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(st.status.success(), "{mode}: {}", String::from_utf8_lossy(&st.stderr));
        let text = std::fs::read_to_string(&out).unwrap();
        let mut lines = text.lines();
        let header = lines.next().unwrap();
        assert!(header.starts_with("step,q_des_1") && header.contains("q_cmd_5") && header.contains("q_pred_1"));
        let rows: Vec<&str> = lines.collect();
        assert_eq!(rows.len(), 30, "{mode}");
        let stop_col = header.split(',').position(|h| h == "stop_reason").unwrap();
        let want = if mode == "uncalibrated" { "none" } else { "" };
        for r in rows {
            let f: Vec<&str> = r.split(',').collect();
            if !want.is_empty() {
                assert_eq!(f[stop_col], want);
            }
        }
    }
}

#[test]
fn compensate_reports_bad_targets_with_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let targets = dir.path().join("bad.csv");
    std::fs::write(&targets, "q1,q2,q3,q4,q5\n1,2,3,4,5\n1,2,x,4,5\n").unwrap();
    let st = bowden()
        .args(["compensate", "--mode", "uncalibrated", "--targets"])
        .arg(&targets)
        .output()
        .unwrap();
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(
        err.contains("bad.csv:3") && err.contains("q3") && err.contains("\"x\""),
        "{err}"
    );
    let st = bowden()
        .args(["compensate", "--targets"])
        .arg(&targets)
        .args(["--model-fwd", "/nonexistent/f.onnx"])
        .output()
        .unwrap();
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("/nonexistent/f.onnx"), "{err}");
}
