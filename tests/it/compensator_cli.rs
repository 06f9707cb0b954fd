//! `bowden compensate` end to end: CSV in, CSV out, and clear errors for bad input.

use std::path::{Path, PathBuf};
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
    for mode in ["paper", "newton", "uncalibrated"] {
        let out = dir.path().join(format!("out-{mode}.csv"));
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

/// A smooth joint path of `n` waypoints inside the shipped robot's limits (and the shipped
/// models' training range): up to ~1.4° per joint between rows, as a CSV with the given header.
fn waypoints(n: usize, header: &str) -> String {
    let mut csv = format!("{header}\n");
    for k in 0..n {
        let t = k as f64 / (n - 1) as f64;
        let tau = std::f64::consts::TAU;
        let mut q = Vec::new();
        for (j, amp) in [18.0, 18.0, 13.0].into_iter().enumerate() {
            let j = j as f64;
            q.push(
                amp * (0.6 * (tau * (1.5 + 0.5 * j) * t + j).sin() + 0.4 * (tau * (3.1 + 0.3 * j) * t + 2.0 * j).sin()),
            );
        }
        let yaw = 5.0 * (tau * 2.0 * t).sin();
        let opening = 14.0 + 8.0 * (tau * 2.5 * t).sin();
        q.push(yaw - opening / 2.0);
        q.push(yaw + opening / 2.0);
        let fields: Vec<String> = q.iter().map(|v| format!("{v:.6}")).collect();
        csv += &format!("{},{}\n", k * 500_000_000, fields.join(","));
    }
    csv
}

/// Runs `compensate` (shipped config and models) and returns its predicted error: the mean
/// max|f(q_cmd) − q_desired| of its summary line.
fn predicted_error(targets: &Path, out: &Path, extra: &[&str]) -> f64 {
    let st = bowden()
        .arg("compensate")
        .arg("--targets")
        .arg(targets)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(st.status.success(), "{extra:?}: {err}");
    let at = err
        .find("q_desired| = ")
        .unwrap_or_else(|| panic!("no summary in {err}"))
        + "q_desired| = ".len();
    err[at..].split_whitespace().next().unwrap().parse().unwrap()
}

/// Largest change of any joint's command between consecutive rows of an output CSV.
fn largest_command_step(out: &Path) -> f64 {
    let text = std::fs::read_to_string(out).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let cols: Vec<usize> = (1..=5)
        .map(|c| header.iter().position(|h| *h == format!("q_cmd_{c}")).unwrap())
        .collect();
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            cols.iter().map(|&i| f[i].parse().unwrap()).collect()
        })
        .collect();
    rows.windows(2)
        .flat_map(|w| (0..5).map(move |c| (w[1][c] - w[0][c]).abs()))
        .fold(0.0, f64::max)
}

#[test]
fn compensate_treats_a_target_file_as_waypoints() {
    let dir = tempfile::tempdir().unwrap();
    let targets = dir.path().join("waypoints.csv");
    std::fs::write(&targets, waypoints(200, "t_ns,q1,q2,q3,q4,q5")).unwrap();
    let out = |name: &str| dir.path().join(format!("{name}.csv"));
    let uncalibrated = predicted_error(&targets, &out("uncalibrated"), &["--mode", "uncalibrated"]);
    let paper = predicted_error(&targets, &out("paper"), &["--mode", "paper"]);
    let newton = predicted_error(&targets, &out("newton"), &["--mode", "newton"]);
    assert!(
        paper < 0.6 * uncalibrated && newton < 0.6 * uncalibrated,
        "predicted error: paper {paper}, newton {newton}, uncalibrated {uncalibrated}"
    );
    // No output rate limit on waypoints: the commands move as far as the targets ask.
    assert!(largest_command_step(&out("paper")) > 1.0);
    // An explicit period makes the rows a timed stream under the controller's output limits:
    // the shipped 360°/s at 1 ms is 0.36° per row.
    let timed = predicted_error(&targets, &out("timed"), &["--mode", "paper", "--period-ns", "1000000"]);
    let step = largest_command_step(&out("timed"));
    assert!(step <= 0.36 + 1e-6, "rate limit at --period-ns 1000000: {step}");
    assert!(timed > paper, "rate-limited {timed} vs waypoints {paper}");
    // --period-ns 0 is the waypoint default, said explicitly.
    let zero = predicted_error(&targets, &out("zero"), &["--mode", "paper", "--period-ns", "0"]);
    assert_eq!(zero, paper);
}

/// The CSV without its wall-time column (the only one that varies between runs).
fn without_elapsed(out: &Path) -> String {
    std::fs::read_to_string(out)
        .unwrap()
        .lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string() + "\n")
        .collect()
}

#[test]
fn compensate_reads_named_columns_with_cols() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain.csv");
    let named = dir.path().join("named.csv");
    std::fs::write(&plain, waypoints(40, "t_ns,q1,q2,q3,q4,q5")).unwrap();
    // The joint columns under other names, one of them in a different place, and decoy q-columns.
    let text: String = waypoints(40, "t,a,pitch2,c,jaw_left,jaw_right")
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let decoy = if f[0] == "t" { "q1,q2" } else { "99,-99" };
            format!("{},{decoy},{},{},{},{},{}\n", f[2], f[0], f[1], f[3], f[4], f[5])
        })
        .collect();
    std::fs::write(&named, text).unwrap();
    let a = dir.path().join("a.csv");
    let b = dir.path().join("b.csv");
    predicted_error(&plain, &a, &["--mode", "paper"]);
    predicted_error(
        &named,
        &b,
        &["--mode", "paper", "--cols", "a, pitch2,c,jaw_left,jaw_right"],
    );
    assert_eq!(without_elapsed(&a), without_elapsed(&b));

    let st = bowden()
        .args(["compensate", "--mode", "uncalibrated", "--targets"])
        .arg(&named)
        .args(["--cols", "a,pitch2,nope,jaw_left,jaw_right"])
        .output()
        .unwrap();
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(
        err.contains("named.csv") && err.contains("\"nope\"") && err.contains("jaw_right"),
        "{err}"
    );
    let st = bowden()
        .args(["compensate", "--mode", "uncalibrated", "--targets"])
        .arg(&named)
        .args(["--cols", "a,pitch2,c"])
        .output()
        .unwrap();
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("--cols") && err.contains("5 joints"), "{err}");
}

#[test]
fn compensate_does_not_overwrite_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let targets = dir.path().join("targets.csv");
    std::fs::write(&targets, waypoints(10, "t_ns,q1,q2,q3,q4,q5")).unwrap();
    let out = dir.path().join("commands.csv");
    std::fs::write(&out, "keep me\n").unwrap();
    let run = |force: bool| {
        let mut c = bowden();
        c.args(["compensate", "--mode", "uncalibrated", "--targets"])
            .arg(&targets)
            .arg("--out")
            .arg(&out);
        if force {
            c.arg("--force");
        }
        c.output().unwrap()
    };
    let st = run(false);
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("commands.csv") && err.contains("--force"), "{err}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "keep me\n");
    let st = run(true);
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    assert!(std::fs::read_to_string(&out).unwrap().starts_with("step,q_des_1"));
}

#[test]
fn compensate_help_documents_every_output_column() {
    let dir = tempfile::tempdir().unwrap();
    let targets = dir.path().join("targets.csv");
    std::fs::write(&targets, waypoints(5, "t_ns,q1,q2,q3,q4,q5")).unwrap();
    let out = dir.path().join("out.csv");
    predicted_error(&targets, &out, &["--mode", "uncalibrated"]);
    let text = std::fs::read_to_string(&out).unwrap();
    let help = bowden().args(["compensate", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    for col in text.lines().next().unwrap().split(',') {
        // q_des_3 is documented as q_des_1..5.
        let doc = match col.rsplit_once('_') {
            Some((base, n)) if n.parse::<usize>().is_ok() => format!("{base}_1..5"),
            _ => col.to_string(),
        };
        assert!(
            help.contains(&format!("`{doc}`")),
            "--help does not document {col}: {help}"
        );
    }
    assert!(help.contains("--period-ns") && help.contains("--cols") && help.contains("--force"));
}

/// Every row the robot's limits change is counted per joint, on stderr and in the summary JSON,
/// and a file clamped on more than 1 % of its rows gets a warning (issue #42: never silent).
#[test]
fn compensate_counts_and_reports_every_clamp() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, q4_deg: &dyn Fn(usize) -> f64| {
        let targets = dir.path().join(format!("{name}.csv"));
        let mut csv = String::from("q1,q2,q3,q4,q5\n");
        for k in 0..10 {
            csv += &format!("1,2,3,{},0\n", q4_deg(k));
        }
        std::fs::write(&targets, csv).unwrap();
        let summary = dir.path().join(format!("{name}.json"));
        let out = bowden()
            .args(["compensate", "--mode", "uncalibrated", "--targets"])
            .arg(&targets)
            .arg("--out")
            .arg(dir.path().join(format!("{name}-out.csv")))
            .arg("--summary-json")
            .arg(&summary)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{stderr}");
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
        (stderr, json)
    };
    // The shipped robot's q4 limit is -44 deg: three of ten rows ask for -55.
    let (stderr, json) = run("clamped", &|k| if k % 3 == 0 && k > 0 { -55.0 } else { -10.0 });
    assert_eq!(json["joint_limited_rows"], 3, "{json}");
    assert_eq!(
        json["raised_rows_per_joint"],
        serde_json::json!([0, 0, 0, 3, 0]),
        "{json}"
    );
    assert_eq!(
        json["lowered_rows_per_joint"],
        serde_json::json!([0, 0, 0, 0, 0]),
        "{json}"
    );
    assert!(
        stderr.contains("changed 3 of 10 rows (30.0 %): q4 raised 3"),
        "{stderr}"
    );
    assert!(stderr.contains("warning: the joint limits of"), "{stderr}");
    // Inside the limits: counted as zero, no warning.
    let (stderr, json) = run("inside", &|_| -10.0);
    assert_eq!(json["joint_limited_rows"], 0, "{json}");
    assert!(stderr.contains("changed 0 of 10 rows (0.0 %)"), "{stderr}");
    assert!(!stderr.contains("warning:"), "{stderr}");
}
