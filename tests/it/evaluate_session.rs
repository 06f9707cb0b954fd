//! `bowden evaluate --session`: a short tracking session through the real multi-process lockstep
//! pipeline on the slip scenario (configs/plant-slack-slip.toml with its slip moved to 60 s):
//! one pipeline per controller for the whole session (the plant's clock runs on), the
//! calibrated controllers lose gain after the slip, the report files are written, the same
//! command gives the same bytes, and nothing is left in shared memory.

use crate::cli_support;
use cli_support::{bowden, fails_with, ok, repo, shm_files, shm_leaked_since};
use std::collections::BTreeSet;
use std::path::Path;

fn session(plant: &Path, report: &Path) -> String {
    ok(&bowden(&[
        "evaluate",
        "--session",
        "2",
        "--window-s",
        "15",
        "--plant",
        &plant.display().to_string(),
        "--report",
        &report.display().to_string(),
    ]))
}

#[test]
fn a_session_through_a_slip_shows_the_lost_gain() {
    let shm_before = shm_files(&["bev"]);
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(repo().join("configs/plant-slack-slip.toml")).unwrap();
    assert!(text.contains("at_s = 120.0"));
    let plant = dir.path().join("plant-slip-60.toml");
    std::fs::write(&plant, text.replace("at_s = 120.0", "at_s = 60.0")).unwrap();

    let out = dir.path().join("a");
    let stdout = session(&plant, &out);
    assert!(
        stdout.contains("Tracking session through cable slack") && stdout.contains("w3 slips 0.5 mm at 60 s"),
        "{stdout}"
    );
    for f in ["session.md", "session.json", "session_error.svg", "session_gain.svg"] {
        let p = out.join(f);
        assert!(p.is_file() && std::fs::metadata(&p).unwrap().len() > 100, "{f} missing");
    }
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("session.json")).unwrap()).unwrap();

    // One run per controller, each ONE pipeline: the plant's clock advances 0.5 s per point from
    // the first point to the last, across every trajectory and lap.
    let runs = v["runs"].as_array().unwrap();
    let names: Vec<&str> = runs.iter().map(|r| r["controller"].as_str().unwrap()).collect();
    assert_eq!(names, ["uncalibrated", "paper", "newton"]);
    for r in runs {
        let pts = r["points"].as_array().unwrap();
        let t: Vec<f64> = pts.iter().map(|p| p["t_s"].as_f64().unwrap()).collect();
        assert!(t.len() > 200 && *t.last().unwrap() <= 120.0, "{} points", t.len());
        assert!(
            t.windows(2).all(|w| (w[1] - w[0] - 0.5).abs() < 1e-9),
            "the plant never restarts"
        );
        let laps: BTreeSet<u64> = pts.iter().map(|p| p["lap"].as_u64().unwrap()).collect();
        assert!(laps.len() >= 2, "the trajectories loop");
        let trajectories: BTreeSet<String> = pts.iter().map(|p| p["trajectory"].to_string()).collect();
        for name in ["\"random\"", "\"circle\"", "\"zigzag\"", "null"] {
            assert!(trajectories.contains(name), "{name} in {trajectories:?}");
        }
    }

    // Pure feed-forward loses gain after the slip: for both calibrated controllers every window
    // wholly after it is worse than any before it (truth), and the gain at the end is lower.
    let windows = v["summary"]["windows"].as_array().unwrap();
    let pos = |w: &serde_json::Value, c: &str| {
        w["cells"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["controller"] == c)
            .unwrap()["cell"]["task_truth"]["pos_mean_mm"]
            .as_f64()
            .unwrap()
    };
    let t_of = |w: &serde_json::Value, k: &str| w[k].as_f64().unwrap();
    for c in ["paper", "newton"] {
        let before = windows
            .iter()
            .filter(|w| t_of(w, "t_end_s") <= 60.0)
            .map(|w| pos(w, c))
            .fold(0.0, f64::max);
        let after: Vec<f64> = windows
            .iter()
            .filter(|w| t_of(w, "t_start_s") >= 60.0)
            .map(|w| pos(w, c))
            .collect();
        assert!(before > 0.0 && after.len() >= 3);
        assert!(
            after.iter().all(|&a| a > 1.5 * before),
            "{c}: before the slip ≤ {before:.2} mm, after {after:?}"
        );
        let s = v["summary"]["summary"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["controller"] == c)
            .unwrap();
        let (gb, ge) = (s["gain_before"].as_f64().unwrap(), s["gain_end"].as_f64().unwrap());
        assert!(
            gb > 0.6 && ge < gb - 0.1,
            "{c}: gain {gb:.3} before, {ge:.3} at the end"
        );
        assert!((s["gain_lost"].as_f64().unwrap() - (gb - ge)).abs() < 1e-12);
    }
    let md = std::fs::read_to_string(out.join("session.md")).unwrap();
    assert!(md.contains("| 4 | 60–75 (w3 slips 0.5 mm at 60 s) |"), "{md}");
    assert!(md.contains("gain lost") && md.contains("gain newton"), "{md}");

    // Deterministic: the same command gives the same bytes.
    let again = dir.path().join("b");
    session(&plant, &again);
    for f in ["session.json", "session.md"] {
        assert!(
            std::fs::read(out.join(f)).unwrap() == std::fs::read(again.join(f)).unwrap(),
            "{f} differs between two identical runs"
        );
    }

    // Nothing of the pipelines is left in shared memory.
    let leaked = shm_leaked_since(&shm_before, &["bev"]);
    assert!(leaked.is_empty(), "left in /dev/shm: {leaked:?}");
}

#[test]
fn bad_session_arguments_are_refused_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let report = dir.path().display().to_string();
    for (args, needle) in [
        (["--session", "0", "--window-s", "60"], "--session"),
        (["--session", "nan", "--window-s", "60"], "--session"),
        (["--session", "1", "--window-s", "0"], "--window-s"),
    ] {
        let mut a = vec!["evaluate", "--report", &report];
        a.extend(args);
        fails_with(&bowden(&a), &[needle]);
    }
    assert!(!dir.path().join("session.json").exists());
}
