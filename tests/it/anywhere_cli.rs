//! The main commands run from an empty directory, as an installed binary does (issue #14
//! item 1): the shipped configs and models come from the copy built into the binary
//! (extracted to the cache, here a temporary one), the node processes of `collect`, `evaluate`
//! and `run` read the same files, outputs go under the working directory, and nothing is left
//! in shared memory.

use crate::cli_support;
use cli_support::{shm_files, shm_leaked_since};
use std::path::Path;
use std::process::{Command, Output};

/// `bowden ARGS` in `cwd`, with the built-in copy extracted under `cache` and no $BOWDEN_HOME.
fn bowden_in(cwd: &Path, cache: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bowden"))
        .current_dir(cwd)
        .env("XDG_CACHE_HOME", cache)
        .env_remove("BOWDEN_HOME")
        .args(args)
        .output()
        .expect("bowden runs")
}

fn ok(args: &[&str], out: &Output) -> String {
    assert!(
        out.status.success(),
        "bowden {args:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_main_commands_run_from_an_empty_directory() {
    let shm_before = shm_files(&["bev", "bcol", "bwany"]);
    let tmp = tempfile::tempdir().unwrap();
    let (cwd, cache) = (tmp.path().join("work"), tmp.path().join("cache"));
    std::fs::create_dir_all(&cwd).unwrap();
    let run = |args: &[&str]| ok(args, &bowden_in(&cwd, &cache, args));

    let fk = run(&["fk", "--q", "20,-15,10,-5,15"]);
    assert!(fk.contains("back through ik"), "{fk}");
    let plant = run(&[
        "plant",
        "characterize",
        "--samples",
        "20",
        "--config",
        "configs/plant-lugre.toml",
    ]);
    assert!(plant.contains("| q1 |"), "{plant}");
    assert!(cwd.join("plant_loops.svg").is_file());
    let est = run(&["estimator", "eval", "--frames", "5"]);
    assert!(est.contains("detection"), "{est}");

    run(&["collect", "--samples", "5", "--out", "data"]);
    let manifest = std::fs::read_to_string(cwd.join("data/manifest.json")).unwrap();
    assert!(cwd.join("data/dataset.csv").is_file(), "{manifest}");
    let again = bowden_in(&cwd, &cache, &["collect", "--samples", "5", "--out", "data"]);
    assert!(!again.status.success());
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(err.contains("data/dataset.csv") && err.contains("--force"), "{err}");

    let eval = run(&[
        "evaluate",
        "--max-points",
        "5",
        "--repeats",
        "1",
        "--trajectories",
        "circle",
        "--json",
        "--json-out",
        "summary.json",
    ]);
    let v: serde_json::Value = serde_json::from_str(&eval).expect("--json: the summary on stdout");
    assert!(v["cells"].as_array().is_some_and(|c| c.len() == 3), "{v}");
    assert!(cwd.join("summary.json").is_file());
    let report = std::fs::read_to_string(cwd.join("out/evaluate/report.md")).unwrap();
    assert!(
        report.contains("pipeline configs/evaluate.toml (built-in)")
            && report.contains("controller configs/controller-accurate.toml (built-in)"),
        "{report}"
    );
    // The shipped models ran: the calibrated controllers beat the uncalibrated one.
    let by = |ctrl: &str| {
        v["cells"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["controller"] == ctrl)
            .unwrap()["task_truth"]["pos_mean_mm"]
            .as_f64()
            .unwrap()
    };
    assert!(by("newton") < by("uncalibrated"), "{v}");

    // `run`'s default pipeline, and its node processes, from the same copy.
    let prefix = format!("bwany{}_", std::process::id());
    let out = bowden_in(
        &cwd,
        &cache,
        &[
            "run", "--mode", "lockstep", "--ticks", "20", "--prefix", &prefix, "--quiet", "--json",
        ],
    );
    let text = ok(&["run"], &out);
    let v: serde_json::Value = serde_json::from_str(&text).expect("run --json");
    assert_eq!(v["ticks"], 20, "{v}");

    // A shipped trajectory as a target file, and the transfer benchmark's shipped config.
    run(&[
        "trajectory",
        "export",
        "--file",
        "configs/trajectories/large/circle.toml",
        "--out",
        "circle.csv",
    ]);
    assert!(cwd.join("circle.csv").is_file());
    let transfer = bowden_in(
        &cwd,
        &cache,
        &[
            "bench",
            "transfer",
            "--quick",
            "--units",
            "Tuning",
            "--families",
            "robot2-capstan",
            "--out",
            "tr",
        ],
    );
    ok(&["bench", "transfer"], &transfer);
    assert!(cwd.join("tr/transfer.json").is_file() && cwd.join("tr/units/robot2-capstan/unit-79/eval").is_dir());

    // Everything the run wrote is under the working directory; the cache holds the copy.
    assert!(cache.join("bowden").is_dir());
    let leaked = shm_leaked_since(&shm_before, &["bev", "bcol", "bwany"]);
    assert!(leaked.is_empty(), "left in /dev/shm: {leaked:?}");
}

#[test]
fn bowden_home_comes_before_the_built_in_copy() {
    let tmp = tempfile::tempdir().unwrap();
    let (cwd, cache, home) = (tmp.path().join("w"), tmp.path().join("c"), tmp.path().join("home"));
    std::fs::create_dir_all(&cwd).unwrap();
    let out = bowden_in(&cwd, &cache, &["shipped", "--extract", &home.display().to_string()]);
    ok(&["shipped"], &out);
    let robot = home.join("configs/robot.toml");
    let text = std::fs::read_to_string(&robot).unwrap();
    let name = text
        .lines()
        .find(|l| l.starts_with("name"))
        .expect("a name line")
        .to_string();
    std::fs::write(&robot, text.replacen(&name, "name = \"home-robot\"", 1)).unwrap();
    let fk = |home: Option<&Path>| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_bowden"));
        c.current_dir(&cwd)
            .env("XDG_CACHE_HOME", &cache)
            .env_remove("BOWDEN_HOME");
        if let Some(h) = home {
            c.env("BOWDEN_HOME", h);
        }
        let out = c.args(["fk", "--q", "0,0,0,0,0"]).output().unwrap();
        ok(&["fk"], &out)
    };
    assert!(fk(Some(&home)).contains("home-robot"));
    assert!(!fk(None).contains("home-robot"));
    // An extracted copy is not overwritten without --force.
    let out = bowden_in(&cwd, &cache, &["shipped", "--extract", &home.display().to_string()]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--force"));
    let listing = ok(&["shipped"], &bowden_in(&cwd, &cache, &["shipped"]));
    assert!(listing.contains("configs/robot.toml") && listing.contains("models/tcn_forward_L80.onnx"));
}
