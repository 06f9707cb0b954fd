//! `bowden bench transfer --quick` end to end on one capstan unit: every step of a user's
//! workflow runs as a subprocess, the report files are written with numbers for every
//! (trajectory, controller), a rerun resumes (every step skipped), a removed stamp reruns only
//! its step, bad configs name the field, and no shared memory is left behind.

use crate::cli_support;
use cli_support::{bowden, fails_with, ok, repo, shm_files, shm_leaked_since, transfer_recipe};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The config of the test: one held-out unit of the default capstan family. `bowden tune` is
/// used when this bowden has it.
fn config(dir: &Path, recipe_extra: &str, family_extra: &str) -> PathBuf {
    let tune = bowden(&["tune", "--help"]).status.success();
    let r = repo();
    let text = format!(
        r#"{recipe}
{recipe_extra}
[[family]]
name = "capstan"
plant = "{plant}"
tuning_units = [2026]
heldout_units = [4242]
{family_extra}
"#,
        recipe = transfer_recipe(tune),
        plant = r.join("configs/plant.toml").display(),
    );
    let p = dir.join("transfer.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn steps(v: &serde_json::Value) -> Vec<(String, String)> {
    v["units"][0]["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["step"].as_str().unwrap().to_string(),
                s["status"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

#[test]
// Long: one scenario end to end (run, resume, report, merge); its steps depend on each other's files.
fn quick_transfer_runs_resumes_and_reports() {
    let shm_before = shm_files(&["bcol", "bev"]);
    let tmp = tempfile::tempdir().unwrap();
    // A second family whose plant file the simulator refuses: its unit fails at `collect`, the
    // bench goes on with the other, reports the failure and exits non-zero.
    let plant = std::fs::read_to_string(repo().join("configs/plant.toml")).unwrap();
    assert!(plant.contains("\nplays = 6\n"));
    std::fs::write(
        tmp.path().join("plant-broken.toml"),
        plant.replace("\nplays = 6\n", "\nplays = \"six\"\n"),
    )
    .unwrap();
    // An LSTM forward model trained only to judge tune's candidates (`tune --judge`), and the
    // tuned controller evaluated a second time with vision feedback.
    let extra = format!(
        "judge_archs = [\"lstm\"]\n[recipe.feedback]\nconfig = \"{}\"\ncamera_fps = 10.0",
        repo().join("configs/controller-feedback.toml").display()
    );
    let cfg = config(
        tmp.path(),
        &extra,
        "[[family]]\nname = \"broken\"\nplant = \"plant-broken.toml\"\nheldout_units = [1]\n",
    );
    let out = tmp.path().join("out");
    let (cfg_s, out_s) = (cfg.display().to_string(), out.display().to_string());
    let all = bowden(&["bench", "transfer", "--config", &cfg_s, "--out", &out_s, "--quick"]);
    fails_with(&all, &["1 of 2 unit(s) failed", "broken/unit-1 at collect", "plays"]);
    let stdout = String::from_utf8_lossy(&all.stdout).into_owned();
    assert!(
        stdout.contains("| broken | 1 | — | — | **failed** at step `collect`"),
        "{stdout}"
    );
    assert!(
        stdout.contains("## Failures") && stdout.contains("expected usize"),
        "{stdout}"
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("transfer.json")).unwrap()).unwrap();
    let broken = &v["units"][1];
    assert_eq!(
        (broken["family"].as_str(), broken["status"].as_str()),
        (Some("broken"), Some("failed"))
    );
    assert_eq!(broken["failure"]["step"], "collect");
    assert!(!broken["failure"]["log_tail"].as_array().unwrap().is_empty());
    assert!(!out.join("units/broken/unit-1/collect.done").exists());
    // From here on the good family only.
    let args = [
        "bench",
        "transfer",
        "--config",
        &cfg_s,
        "--out",
        &out_s,
        "--quick",
        "--families",
        "capstan",
    ];
    assert!(stdout.contains("# Transfer to unseen units"), "{stdout}");
    assert!(
        stdout.contains("Held-out units") && stdout.contains("capstan 4242"),
        "{stdout}"
    );
    assert!(
        stdout.contains("Tuning units") && stdout.contains("capstan 2026"),
        "{stdout}"
    );
    for f in ["transfer.md", "transfer.json", "transfer.svg"] {
        let p = out.join(f);
        assert!(p.is_file() && std::fs::metadata(&p).unwrap().len() > 200, "{f} missing");
    }
    let svg = std::fs::read_to_string(out.join("transfer.svg")).unwrap();
    assert!(svg.contains("capstan (1 unit)"), "family label in the plot");
    assert_eq!(v["quick"], true);
    let units = v["units"].as_array().unwrap();
    assert_eq!(units.len(), 2, "the held-out units run by default, not the tuning one");
    let u = &units[0];
    assert_eq!(
        (u["family"].as_str(), u["unit"].as_u64()),
        (Some("capstan"), Some(4242))
    );
    assert_eq!(
        (u["role"].as_str(), u["status"].as_str()),
        (Some("held-out"), Some("ok")),
        "{u}"
    );
    // The unit's plant file is the family's with the unit set.
    let unit_dir = out.join("units/capstan/unit-4242");
    let plant: toml::Table = toml::from_str(&std::fs::read_to_string(unit_dir.join("plant.toml")).unwrap()).unwrap();
    assert_eq!(plant["variation"]["unit"].as_integer(), Some(4242));
    // A number for every trajectory × calibrated controller × metric.
    let rows = u["rows"].as_array().unwrap();
    for t in ["random", "circle", "zigzag"] {
        for c in ["paper", "newton", "paper+fb", "newton+fb"] {
            let row = rows
                .iter()
                .find(|r| r["trajectory"] == t && r["controller"] == c)
                .unwrap_or_else(|| panic!("no row {t}/{c}"));
            for m in [
                "position_vision",
                "position_truth",
                "orientation_vision",
                "orientation_truth",
                "joint_vision",
                "joint_truth",
            ] {
                for part in ["error", "uncalibrated", "reduction_pct"] {
                    assert!(
                        row[part][m].as_f64().is_some_and(f64::is_finite),
                        "{t}/{c} {part}.{m}: {row}"
                    );
                }
                assert!(
                    row["uncalibrated"][m].as_f64().unwrap() > 0.0,
                    "{t}/{c} uncalibrated {m}"
                );
            }
        }
    }
    let first = steps(&v);
    let names: Vec<&str> = first.iter().map(|(s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        [
            "collect",
            "train-tcn-forward",
            "train-tcn-inverse",
            "train-lstm-forward",
            "tune",
            "evaluate",
            "feedback",
            "evaluate-feedback"
        ]
    );
    // The feedback controller is the tuned one plus the [feedback] table, evaluated with frames
    // during each held point.
    let fb: toml::Table =
        toml::from_str(&std::fs::read_to_string(unit_dir.join("controller-feedback.toml")).unwrap()).unwrap();
    let tuned: toml::Table =
        toml::from_str(&std::fs::read_to_string(unit_dir.join("controller.toml")).unwrap()).unwrap();
    assert_eq!(fb["feedback"]["enabled"].as_bool(), Some(true));
    assert_eq!(
        (fb["mode"].clone(), fb["model_fwd"].clone()),
        (tuned["mode"].clone(), tuned["model_fwd"].clone())
    );
    let eval_fb = std::fs::read_to_string(unit_dir.join("evaluate-feedback.done")).unwrap();
    assert!(
        eval_fb.contains("--camera-fps") && eval_fb.contains("controller-feedback.toml"),
        "{eval_fb}"
    );
    assert!(
        stdout.contains("## Goals (held-out)") && stdout.contains("| newton+fb |"),
        "{stdout}"
    );
    // The judge rates candidates only: tune gets it with --judge, never as a controller model.
    let tune_stamp = std::fs::read_to_string(unit_dir.join("tune.done")).unwrap();
    assert!(
        tune_stamp.contains("--judge") && tune_stamp.contains("lstm_forward_L10.onnx"),
        "{tune_stamp}"
    );
    let controller = std::fs::read_to_string(unit_dir.join("controller.toml")).unwrap();
    assert!(controller.contains("judge #1: lstm_forward_L10.onnx"), "{controller}");
    // tune quotes its chosen models' validation RMSE by train's definition: the number in the
    // model's training report (#42 item 3).
    let tune_log = std::fs::read_to_string(unit_dir.join("logs/tune.log")).unwrap();
    let fwd_model = tuned["model_fwd"].as_str().unwrap();
    let fwd_report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(unit_dir.join(fwd_model).with_extension("report.json")).unwrap())
            .unwrap();
    let quoted = format!(
        "validation RMSE {:.3}°",
        fwd_report["best_val_rmse_deg"].as_f64().unwrap()
    );
    assert!(
        tune_log
            .lines()
            .any(|l| l.starts_with("forward ") && l.contains(&quoted) && l.contains("by train's definition")),
        "{quoted} in:\n{tune_log}"
    );
    // ... and the margin its choice won by, in the log and in tune.json (#43 item 3).
    let tune_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(unit_dir.join("controller.tune.json")).unwrap()).unwrap();
    let margins = &tune_json["margins"];
    if tune_json["chosen"].is_u64() {
        let runner_up = margins["runner_up_margin_deg"].as_f64().unwrap();
        assert!(runner_up.is_finite(), "{margins}");
        assert!(
            tune_log
                .lines()
                .any(|l| l.starts_with("chose ") && l.contains("runner-up")),
            "{tune_log}"
        );
    } else {
        assert!(
            tune_log.lines().any(|l| l.starts_with("chose uncalibrated")),
            "{tune_log}"
        );
    }
    assert!(!controller.contains("model_fwd = \"models/lstm"), "{controller}");
    assert!(first.iter().all(|(_, st)| st == "ran"), "{first:?}");
    for (s, _) in &first {
        assert!(unit_dir.join(format!("{s}.done")).is_file(), "{s}.done");
        assert!(unit_dir.join("logs").join(format!("{s}.log")).is_file(), "{s}.log");
    }
    assert!(v["timing"][0]["collect"]["seconds"].as_f64().unwrap() > 0.0);

    // A rerun (of the good family) resumes: every step skipped, quickly.
    let t0 = Instant::now();
    let stdout2 = ok(&bowden(&args));
    assert!(!stdout2.contains("| broken | 1 |"), "{stdout2}");
    let dt = t0.elapsed().as_secs_f64();
    let v2: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("transfer.json")).unwrap()).unwrap();
    assert!(steps(&v2).iter().all(|(_, st)| st == "skipped"), "{:?}", steps(&v2));
    assert!(dt < 20.0, "a resumed run took {dt:.1} s");
    assert_eq!(
        v2["units"][0]["rows"], v["units"][0]["rows"],
        "same results from the same files"
    );
    assert!(stdout2.contains("8 step(s) *"), "{stdout2}");

    // An unfinished step (no stamp) reruns, with what depends on it; the rest is kept.
    std::fs::remove_file(unit_dir.join("tune.done")).unwrap();
    ok(&bowden(&args));
    let v3: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("transfer.json")).unwrap()).unwrap();
    let st: Vec<String> = steps(&v3).into_iter().map(|(_, s)| s).collect();
    assert_eq!(
        st,
        ["skipped", "skipped", "skipped", "skipped", "ran", "ran", "ran", "ran"]
    );

    // Nothing of the pipelines is left in shared memory.
    let leaked = shm_leaked_since(&shm_before, &["bcol", "bev"]);
    assert!(leaked.is_empty(), "left in /dev/shm: {leaked:?}");
}

#[test]
fn bad_configs_name_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out").display().to_string();
    let run = |cfg: &Path| {
        bowden(&[
            "bench",
            "transfer",
            "--config",
            &cfg.display().to_string(),
            "--out",
            &out,
        ])
    };
    // Wrong value.
    let cfg = config(tmp.path(), "", "");
    let text = std::fs::read_to_string(&cfg).unwrap();
    std::fs::write(&cfg, text.replace("samples = 3000", "samples = 1")).unwrap();
    fails_with(&run(&cfg), &["transfer.toml", "recipe.samples"]);
    // Misspelt key.
    std::fs::write(&cfg, text.replace("samples = 3000", "sampels = 3000")).unwrap();
    fails_with(&run(&cfg), &["transfer.toml", "sampels"]);
    // Unknown controller, unknown architecture, a held-out unit that is also a tuning unit.
    std::fs::write(&cfg, text.replace("\"paper\", \"newton\"", "\"paper\", \"pid\"")).unwrap();
    fails_with(&run(&cfg), &["recipe.controllers", "pid"]);
    std::fs::write(&cfg, text.replace("[\"tcn\"]", "[\"tcn\", \"gru\"]")).unwrap();
    fails_with(&run(&cfg), &["recipe.archs[1]"]);
    std::fs::write(&cfg, text.replace("heldout_units = [4242]", "heldout_units = [2026]")).unwrap();
    fails_with(&run(&cfg), &["family[0].heldout_units", "2026"]);
    // A missing plant file, named before anything runs.
    let cfg = config(
        tmp.path(),
        "",
        "[[family]]\nname = \"ghost\"\nplant = \"configs/plant-ghost.toml\"\nheldout_units = [1]\n",
    );
    fails_with(&run(&cfg), &["family[1] (ghost).plant", "plant-ghost.toml"]);
    // An unknown family on the command line.
    let out2 = bowden(&[
        "bench",
        "transfer",
        "--config",
        &cfg.display().to_string(),
        "--families",
        "nope",
        "--out",
        &out,
    ]);
    fails_with(&out2, &["--families", "nope", "capstan"]);
    assert!(!Path::new(&out).join("units").exists(), "nothing ran");
}

/// `[recipe.closed_loop]` and `recipe.trajectory_sets` (issue #12): a second collection round
/// under the first round's controller, whose models the evaluation then uses, and a second set
/// of paths reported as controllers `…@NAME`.
#[test]
fn quick_transfer_with_a_closed_loop_round_and_a_second_path_set() {
    let shm_before = shm_files(&["bcol", "bev"]);
    let tmp = tempfile::tempdir().unwrap();
    let extra = format!(
        "trajectory_sets = {{ large = \"{}\" }}\n[recipe.closed_loop]\nsamples = 40\nexcitation = \"paper\"",
        repo().join("configs/trajectories/large").display()
    );
    let cfg = config(tmp.path(), &extra, "");
    let out = tmp.path().join("out");
    let (cfg_s, out_s) = (cfg.display().to_string(), out.display().to_string());
    let args = ["bench", "transfer", "--config", &cfg_s, "--out", &out_s, "--quick"];
    let stdout = ok(&bowden(&args));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("transfer.json")).unwrap()).unwrap();
    let names: Vec<String> = steps(&v).into_iter().map(|(s, _)| s).collect();
    assert_eq!(
        names,
        [
            "collect",
            "train-tcn-forward",
            "train-tcn-inverse",
            "tune",
            "collect-closed-loop",
            "train-tcn-forward-closed-loop",
            "train-tcn-inverse-closed-loop",
            "tune-closed-loop",
            "evaluate",
            "evaluate-large",
        ]
    );
    let unit_dir = out.join("units/capstan/unit-4242");
    // The second round ran under the first round's controller and added to its data; the
    // evaluations use the controller tuned on the whole.
    let collect2 = std::fs::read_to_string(unit_dir.join("collect-closed-loop.done")).unwrap();
    assert!(
        collect2.contains("--controller-config") && collect2.contains("unit-4242/controller.toml"),
        "{collect2}"
    );
    assert!(collect2.contains("--extend"), "{collect2}");
    let first = bowden_learning::dataset::Dataset::read_dir(&unit_dir.join("data"))
        .unwrap()
        .0;
    let whole = bowden_learning::dataset::Dataset::read_dir(&unit_dir.join("data-closed-loop"))
        .unwrap()
        .0;
    assert!(whole.len() > first.len(), "{} rows after {}", whole.len(), first.len());
    for step in ["evaluate", "evaluate-large"] {
        let stamp = std::fs::read_to_string(unit_dir.join(format!("{step}.done"))).unwrap();
        assert!(stamp.contains("controller-closed-loop.toml"), "{step}: {stamp}");
        assert_eq!(
            stamp.contains("--trajectories-dir"),
            step == "evaluate-large",
            "{stamp}"
        );
    }
    // Rows of both sets for every path and controller, and the set's own goal lines.
    let rows = v["units"][0]["rows"].as_array().unwrap();
    for t in ["random", "circle", "zigzag"] {
        for c in ["paper", "newton", "paper@large", "newton@large"] {
            assert!(
                rows.iter().any(|r| r["trajectory"] == t && r["controller"] == c),
                "no row {t}/{c}"
            );
        }
    }
    // The large paths are larger: the uncalibrated robot misses them by more.
    let unc = |c: &str| {
        rows.iter()
            .filter(|r| r["controller"] == c)
            .map(|r| r["uncalibrated"]["position_truth"].as_f64().unwrap())
            .sum::<f64>()
    };
    assert!(
        unc("newton@large") > unc("newton"),
        "{} vs {}",
        unc("newton@large"),
        unc("newton")
    );
    assert!(stdout.contains("| newton@large |"), "{stdout}");
    assert!(stdout.contains("4b. a second round under that controller"), "{stdout}");
    assert!(stdout.contains("reported as controllers `…@large`"), "{stdout}");
    assert!(shm_leaked_since(&shm_before, &["bcol", "bev"]).is_empty());

    // Bad values name the field.
    let text = std::fs::read_to_string(&cfg).unwrap();
    std::fs::write(&cfg, text.replace("samples = 40", "samples = 1")).unwrap();
    fails_with(&bowden(&args), &["recipe.closed_loop.samples"]);
    std::fs::write(&cfg, text.replace("excitation = \"paper\"", "excitation = \"chirp\"")).unwrap();
    // Refused while parsing, at the key's line and column, with the accepted names.
    fails_with(
        &bowden(&args),
        &[
            "transfer.toml",
            "line 16",
            "excitation = \"chirp\"",
            "expected `paper` or `mixed`",
        ],
    );
    std::fs::write(
        &cfg,
        text.replace("configs/trajectories/large", "configs/trajectories/huge"),
    )
    .unwrap();
    fails_with(&bowden(&args), &["recipe.trajectory_sets.large", "huge"]);
}
