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

/// The numbers inside the first `[...]` after `key` on `line`.
fn bracketed(line: &str, key: &str) -> Vec<String> {
    let rest = &line[line.find(key).unwrap_or_else(|| panic!("{key:?} in {line:?}")) + key.len()..];
    let open = rest.find('[').unwrap();
    let close = rest.find(']').unwrap();
    rest[open + 1..close].split_whitespace().map(str::to_string).collect()
}

fn json_q(out: &str) -> Vec<f64> {
    let v: serde_json::Value = serde_json::from_str(out).unwrap_or_else(|e| panic!("{e}: {out}"));
    v["q_deg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

#[test]
fn ik_round_trips_the_pose_fk_prints() {
    for q in [
        [20.0, -15.0, 10.0, -5.0, 15.0],
        [-41.3, 27.9, -33.1, -20.0, 35.5],
        [0.5, 0.0, -0.25, 3.0, 3.0],
    ] {
        let qs: Vec<String> = q.iter().map(|v| v.to_string()).collect();
        let (ok, out, err) = bowden(&["fk", "--q", &qs.join(",")]);
        assert!(ok, "{err}");
        // The end-effector row of the human-readable table, as a user copies it.
        let ee = out.lines().find(|l| l.starts_with("ee ")).expect("an ee row");
        let pos = bracketed(ee, "pos");
        let quat = bracketed(ee, "quat(w,x,y,z)");
        assert_eq!((pos.len(), quat.len()), (3, 4), "{ee}");
        let opening = (q[4] - q[3]).to_string();
        let args = [
            "ik",
            "--pos",
            &pos.join(","),
            "--quat",
            &quat.join(","),
            "--opening",
            &opening,
            "--json",
        ];
        let (ok, out, err) = bowden(&args);
        assert!(ok, "{args:?}: {err}\n{out}");
        assert!(!err.contains("normalised"), "fk's own quaternion needs no note: {err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["converged"], true, "{out}");
        assert!(v["residual_pos_mm"].as_f64().unwrap() < 1e-4, "{out}");
        let got = json_q(&out);
        for (g, want) in got.iter().zip(q) {
            assert!((g - want).abs() < 1e-3, "{q:?} → {ee} → {got:?}");
        }
        // The `ik` command fk prints as its last line round-trips too.
        let line = out_line_ik(&qs.join(","));
        let cmd: Vec<&str> = line.split_whitespace().skip(1).collect();
        let (ok, out, err) = bowden(&[&cmd[..], &["--json"]].concat());
        assert!(ok, "{line}: {err}");
        for (g, want) in json_q(&out).iter().zip(q) {
            assert!((g - want).abs() < 1e-3, "{line}: {out}");
        }
    }
}

/// fk's last line: the `bowden ik ...` command of the end-effector pose.
fn out_line_ik(q: &str) -> String {
    let (ok, out, err) = bowden(&["fk", "--q", q]);
    assert!(ok, "{err}");
    let last = out.lines().last().unwrap();
    let at = last
        .find("bowden ik ")
        .unwrap_or_else(|| panic!("no ik command in {last:?}"));
    last[at..].to_string()
}

#[test]
fn ik_takes_the_readme_example_and_says_it_normalised_the_quaternion() {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    let line = readme
        .lines()
        .find(|l| l.starts_with("bowden ik "))
        .expect("README shows `bowden ik`");
    let cmd: Vec<&str> = line.split('#').next().unwrap().split_whitespace().skip(1).collect();
    let quat = cmd[cmd.iter().position(|a| *a == "--quat").unwrap() + 1];
    let norm = quat
        .split(',')
        .map(|v| v.parse::<f64>().unwrap().powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(
        (norm - 1.0).abs() > 1e-4,
        "the README example shows a near-unit quaternion: {quat}"
    );
    let (ok, out, err) = bowden(&cmd);
    assert!(ok, "{line}: {err}\n{out}");
    assert!(
        err.contains("normalised") && err.contains(&format!("{norm:.6}")),
        "{err}"
    );
    assert!(out.contains("converged: residual") && !out.contains("NOT"), "{out}");
    let (ok, out, err) = bowden(&[&cmd[..], &["--json"]].concat());
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["converged"], true);
    assert!((v["quat_norm"].as_f64().unwrap() - norm).abs() < 1e-12);
    assert!(v["residual_pos_mm"].as_f64().unwrap() < 1e-3 && v["residual_rot_deg"].as_f64().unwrap() < 1e-3);
}

#[test]
fn ik_that_does_not_converge_shows_its_best_and_fails() {
    // The old README pose: its orientation is one the wrist cannot take at that position.
    let args = [
        "ik",
        "--pos",
        "40.1,-9.7,14.2",
        "--quat",
        "0.96,0.05,0.1,-0.2",
        "--opening",
        "20",
    ];
    let (ok, out, err) = bowden(&args);
    assert!(!ok, "an unreachable pose must fail: {out}");
    assert!(out.starts_with("NOT CONVERGED"), "{out}");
    for name in ["q1 =", "q2 =", "q3 =", "q4 =", "q5 =", "q_yaw ="] {
        assert!(out.contains(name), "{out}");
    }
    let res = out.lines().find(|l| l.contains("residual")).expect("a residual line");
    assert!(
        res.contains("NOT CONVERGED") && res.contains(" mm") && res.contains(" deg"),
        "{res}"
    );
    let err_lines: Vec<&str> = err.lines().filter(|l| !l.starts_with("note:")).collect();
    assert_eq!(err_lines.len(), 1, "{err}");
    assert!(
        err_lines[0].contains("did not converge") && err_lines[0].contains("mm"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    let (ok, out, _) = bowden(&[&args[..], &["--json"]].concat());
    assert!(!ok);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out}"));
    assert_eq!(v["converged"], false);
    assert!(v["residual_pos_mm"].as_f64().unwrap() > 1e-3, "{out}");
    assert!(v["residual_rot_deg"].as_f64().unwrap().is_finite());
    assert_eq!(json_q(&out).len(), 5);
}

#[test]
fn ik_refuses_what_is_not_nearly_a_unit_quaternion() {
    assert_one_line_error(
        &["ik", "--pos", "50,0,0", "--quat", "0.9,0,0,0"],
        &["norm 0.900000", "5 %"],
    );
    assert_one_line_error(&["ik", "--pos", "50,0,0", "--quat", "0,0,0,0"], &["zero quaternion"]);
    assert_one_line_error(
        &["ik", "--pos", "50,0,0", "--quat", "1,0,nan,0"],
        &["--quat[2]", "finite"],
    );
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
