//! The kinematics commands as a user runs them: answers, and one-line errors with a
//! non-zero exit for bad input (never a panic).

use std::process::Command;

fn bowden(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_bowden"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("bowden runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn assert_one_line_error(args: &[&str], must_contain: &[&str]) {
    let (ok, _, err) = bowden(args);
    assert!(!ok, "{args:?} should fail");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    let line = err.trim();
    assert_eq!(line.lines().count(), 1, "{args:?}: not one line: {err}");
    for m in must_contain {
        assert!(line.contains(m), "{args:?}: {line:?} does not name {m:?}");
    }
}

#[test]
fn fk_json_at_zero_is_straight() {
    let (ok, out, err) = bowden(&["fk", "--q", "0,0,0,0,0", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let pos = v["ee"]["pos_mm"].as_array().unwrap();
    assert!(pos[0].as_f64().unwrap() > 40.0);
    assert!(pos[1].as_f64().unwrap().abs() < 1e-9 && pos[2].as_f64().unwrap().abs() < 1e-9);
}

#[test]
fn ik_inverts_fk_from_the_command_line() {
    let (ok, out, err) = bowden(&["fk", "--q", "20,-15,10,-5,15", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let p: Vec<String> = v["ee"]["pos_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.to_string())
        .collect();
    let q: Vec<String> = v["ee"]["quat_wxyz"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.to_string())
        .collect();
    let (ok, out, err) = bowden(&[
        "ik",
        "--pos",
        &p.join(","),
        "--quat",
        &q.join(","),
        "--opening",
        "20",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let got: Vec<f64> = v["q_deg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    for (g, want) in got.iter().zip([20.0, -15.0, 10.0, -5.0, 15.0]) {
        assert!((g - want).abs() < 1e-6, "{got:?}");
    }
}

#[test]
fn cables_round_trip_from_the_command_line() {
    let (ok, out, err) = bowden(&["cables", "--q", "30,-20,10,-10,25", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let w: Vec<String> = v["cable_disp_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.to_string())
        .collect();
    assert_eq!(w.len(), 10);
    let (ok, out, err) = bowden(&["cables", "--w", &w.join(","), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let q: Vec<f64> = v["q_deg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert!((q[0] - 30.0).abs() < 1e-9 && (q[4] - 25.0).abs() < 1e-9, "{q:?}");
}

#[test]
fn bad_input_gives_one_line_errors() {
    assert_one_line_error(&["fk", "--q", "0,0,99,0,0"], &["q3", "99", "limits"]);
    assert_one_line_error(&["fk", "--q", "0,nan,0,0,0"], &["--q[1]", "finite"]);
    assert_one_line_error(&["fk", "--q", "0,0,0"], &["--q", "5"]);
    assert_one_line_error(
        &["fk", "--q", "0,0,0,0,0", "--config", "/nonexistent/robot.toml"],
        &["/nonexistent/robot.toml"],
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("robot.toml");
    std::fs::write(&bad, "name = [").unwrap();
    assert_one_line_error(
        &["fk", "--q", "0,0,0,0,0", "--config", bad.to_str().unwrap()],
        &["robot.toml", "malformed"],
    );
    let text = std::fs::read_to_string("configs/robot.toml")
        .unwrap()
        .replace("modules = 11", "modules = 0");
    std::fs::write(&bad, text).unwrap();
    assert_one_line_error(
        &["cables", "--q", "0,0,0,0,0", "--config", bad.to_str().unwrap()],
        &["segment1.modules"],
    );
    assert_one_line_error(&["ik", "--pos", "500,0,0", "--quat", "1,0,0,0"], &["did not converge"]);
    assert_one_line_error(&["ik", "--pos", "50,0,0", "--quat", "2,0,0,0"], &["unit quaternion"]);
}
