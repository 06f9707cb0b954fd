//! `bowden import`, `bowden train`, `bowden sweep` from the command line: files written,
//! reports consistent, errors named, sweeps resumable.

use crate::cli_support;
use cli_support::{bowden, fails_with, ok};
use std::path::Path;
use std::process::Output;

use bowden_learning::npy::write_npy_f64;
use bowden_learning::synthetic::hysteretic_dataset;

fn synthetic_dir(dir: &Path, n: usize) -> String {
    hysteretic_dataset(n, 5, 11)
        .write_dir(dir, "synthetic", Some(11), None, serde_json::Value::Null)
        .unwrap();
    dir.display().to_string()
}

#[test]
fn import_csv_and_npy_with_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let csv = tmp.path().join("log.csv");
    std::fs::write(&csv, "t,c1,c2,m1,m2\n0,1,2,1.1,2.1\n5,2,3,2.1,3.2\n").unwrap();
    let out_dir = tmp.path().join("ds");
    let (csv_s, out_s) = (csv.display().to_string(), out_dir.display().to_string());
    let stdout = ok(&bowden(&[
        "import",
        "--csv",
        &csv_s,
        "--cmd-cols",
        "c1,c2",
        "--phy-cols",
        "m1,m2",
        "--time-col",
        "t",
        "--out",
        &out_s,
    ]));
    assert!(stdout.contains("2 samples (2 valid), 2 joints"), "{stdout}");
    assert!(out_dir.join("manifest.json").exists() && out_dir.join("dataset.csv").exists());
    // The dataset is kept unless --force.
    fails_with(
        &bowden(&["import", "--csv", &csv_s, "--out", &out_s]),
        &["dataset.csv", "exists", "--force"],
    );

    fails_with(
        &bowden(&[
            "import",
            "--csv",
            &csv_s,
            "--cmd-cols",
            "c1,nope",
            "--phy-cols",
            "m1,m2",
            "--out",
            &out_s,
            "--force",
        ]),
        &["log.csv", "nope"],
    );

    let (c, p) = (tmp.path().join("cmd.npy"), tmp.path().join("phy.npy"));
    write_npy_f64(&c, 3, 5, &[0.0; 15]).unwrap();
    write_npy_f64(&p, 3, 4, &[0.0; 12]).unwrap();
    let (c_s, p_s) = (c.display().to_string(), p.display().to_string());
    fails_with(
        &bowden(&[
            "import",
            "--npy-cmd",
            &c_s,
            "--npy-phy",
            &p_s,
            "--out",
            &out_s,
            "--force",
        ]),
        &["phy.npy", "(3, 4)"],
    );
    write_npy_f64(&p, 3, 5, &[0.1; 15]).unwrap();
    let stdout = ok(&bowden(&[
        "import",
        "--npy-cmd",
        &c_s,
        "--npy-phy",
        &p_s,
        "--unit",
        "rad",
        "--joints",
        "1,3",
        "--out",
        &out_s,
        "--force",
    ]));
    assert!(stdout.contains("3 samples (3 valid), 2 joints"), "{stdout}");
}

/// `bowden train --arch tcn --direction forward --data DATA --out OUT`, then `extra`.
fn train_tcn_forward(data: &str, out: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "train",
        "--arch",
        "tcn",
        "--direction",
        "forward",
        "--data",
        data,
        "--out",
        out,
    ];
    args.extend_from_slice(extra);
    bowden(&args)
}

#[test]
fn train_writes_model_report_and_plot() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synthetic_dir(&tmp.path().join("data"), 1500);
    let model = tmp.path().join("models/tcn_forward.onnx");
    let model_s = model.display().to_string();
    let stdout = ok(&train_tcn_forward(
        &data,
        &model_s,
        &["--seq-len", "16", "--epochs", "3", "--seed", "1"],
    ));
    assert!(stdout.contains("validation RMSE"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("models/tcn_forward.report.json")).unwrap())
            .unwrap();
    // L = 16: eq. (20) gives 3 blocks of two 5→5 convolutions (k = 3): 3 × 2 × 80.
    assert_eq!(report["params"], 480);
    assert_eq!(report["tcn_blocks"], 3);
    let best = report["best_val_rmse_deg"].as_f64().unwrap();
    let identity = report["identity_val_rmse_deg"].as_f64().unwrap();
    assert!(best < identity, "model {best} vs identity {identity}");
    assert!(report["export"]["max_abs_diff_deg"].as_f64().unwrap() <= 1e-4);
    assert_eq!(report["epochs"].as_array().unwrap().len(), 3);
    let svg = std::fs::read_to_string(tmp.path().join("models/tcn_forward.loss.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("validation"));
    let meta = bowden_learning::onnx::read_metadata(&model).unwrap();
    let get = |k: &str| meta.iter().find(|(mk, _)| mk == k).map(|(_, v)| v.as_str());
    assert_eq!(get("direction"), Some("forward"));
    assert_eq!(get("seq_len"), Some("16"));
    assert_eq!(get("tcn_block"), Some("relu-linear"));
    // `--decimation auto` (the default): the synthetic data walk eq. (16)'s one step, so the
    // histories are decimated, and the report says why.
    assert!(stdout.contains("decimation auto → 4"), "{stdout}");
    assert_eq!(report["config"]["decimation"], 4);
    assert_eq!(report["decimation_auto"]["decimation"], 4);
    assert_eq!(report["decimation_auto"]["larger_fraction"], 0.0);
    // A number is used as given, and nothing is chosen.
    let literal = tmp.path().join("models/tcn_forward_d1.onnx");
    let stdout = ok(&train_tcn_forward(
        &data,
        &literal.display().to_string(),
        &["--seq-len", "16", "--epochs", "1", "--decimation", "1"],
    ));
    assert!(!stdout.contains("decimation auto"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("models/tcn_forward_d1.report.json")).unwrap())
            .unwrap();
    assert!(report["config"].get("decimation").is_none() && report.get("decimation_auto").is_none());
    fails_with(
        &train_tcn_forward(&data, &model_s, &["--decimation", "0", "--force"]),
        &["--decimation", "auto"],
    );

    fails_with(
        &bowden(&[
            "train",
            "--arch",
            "gru",
            "--direction",
            "forward",
            "--data",
            &data,
            "--out",
            &model_s,
        ]),
        &["--arch", "gru"],
    );
    // The model is kept unless --force.
    fails_with(
        &train_tcn_forward(&data, &model_s, &[]),
        &["tcn_forward.onnx", "exists", "--force"],
    );
    let missing = tmp.path().join("nothing").display().to_string();
    fails_with(
        &train_tcn_forward(&missing, &model_s, &["--force"]),
        &["nothing", "manifest.json"],
    );
}

#[test]
fn auto_decimation_refuses_data_without_a_step() {
    // A log whose commands never move: no grid to decide from. The error names the dataset
    // and the flag, and writes nothing.
    let tmp = tempfile::tempdir().unwrap();
    let mut ds = hysteretic_dataset(400, 5, 3);
    ds.q_cmd_deg.iter_mut().for_each(|q| *q = 10.0);
    let dir = tmp.path().join("held");
    ds.write_dir(&dir, "synthetic", Some(3), None, serde_json::Value::Null)
        .unwrap();
    let model = tmp.path().join("m.onnx");
    fails_with(
        &train_tcn_forward(
            &dir.display().to_string(),
            &model.display().to_string(),
            &["--seq-len", "8", "--epochs", "1"],
        ),
        &["held", "--decimation auto", "give a number"],
    );
    assert!(!model.exists());
}

#[test]
fn sweep_summarises_and_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synthetic_dir(&tmp.path().join("data"), 900);
    let out = tmp.path().join("sweep").display().to_string();
    let args = [
        "sweep",
        "--archs",
        "tcn,fnn",
        "--seq-lens",
        "8,12",
        "--seeds",
        "2",
        "--directions",
        "forward,inverse",
        "--tcn-blocks",
        "relu-linear",
        "--epochs",
        "2",
        "--data",
        &data,
        "--out",
        &out,
        "--jobs",
        "2",
    ];
    let first = ok(&bowden(&args));
    assert!(first.contains("16 runs, 0 reused"), "{first}");
    let md = std::fs::read_to_string(tmp.path().join("sweep/sweep.md")).unwrap();
    assert!(
        md.contains("## forward") && md.contains("## inverse") && md.contains("tcn (relu-linear)"),
        "{md}"
    );
    assert!(md.contains("| identity |"), "{md}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("sweep/sweep.json")).unwrap()).unwrap();
    let groups = summary["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 8); // 2 models × 2 L × 2 directions
    assert!(groups.iter().all(|g| g["n"] == 2));
    assert!(std::fs::read_to_string(tmp.path().join("sweep/sweep.svg"))
        .unwrap()
        .starts_with("<svg"));
    // Rerun: nothing is trained again, the same table comes out.
    let second = ok(&bowden(&args));
    assert!(second.contains("16 runs, 16 reused"), "{second}");
    assert_eq!(md, std::fs::read_to_string(tmp.path().join("sweep/sweep.md")).unwrap());
}

/// `bench train --pytorch`: PyTorch's epoch is timed by the given interpreter in the same
/// run (here a stand-in that answers like the script), the ratio is taken against it, a bf16
/// run also asks for autocast's epoch, and an interpreter that is missing or has no torch is
/// named. `train --precision bf16` records the precision in the report.
#[test]
fn bench_train_times_pytorch_in_the_same_run_and_train_records_bf16() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let write_exe = |name: &str, body: &str| {
        let p = tmp.path().join(name);
        std::fs::write(&p, body).unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
        p.display().to_string()
    };
    let fake = write_exe(
        "fake-python",
        "#!/bin/sh\ncase \"$*\" in\n  *--bf16*) echo 'lstm epoch 0: 2 s'; echo '{\"median_seconds\": 2.0}';;\n  \
         *) echo '{\"median_seconds\": 3.5}';;\nesac\n",
    );
    let stdout = ok(&bowden(&[
        "bench",
        "train",
        "--arch",
        "lstm",
        "--windows",
        "64",
        "--seq-len",
        "12",
        "--epochs",
        "1",
        "--precision",
        "bf16",
        "--pytorch",
        &fake,
        "--json",
    ]));
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let r = &v[0];
    assert_eq!(r["options"]["precision"], "bf16");
    assert_eq!(r["pytorch_measured"], true);
    assert_eq!(r["pytorch_seconds"], 3.5);
    assert_eq!(r["pytorch_bf16_seconds"], 2.0);
    let median = r["median_seconds"].as_f64().unwrap();
    assert!((r["speedup_vs_pytorch"].as_f64().unwrap() - 3.5 / median).abs() < 1e-9);
    assert!((r["speedup_vs_pytorch_bf16"].as_f64().unwrap() - 2.0 / median).abs() < 1e-9);

    let no_torch = write_exe(
        "python-without-torch",
        "#!/bin/sh\necho \"ModuleNotFoundError: No module named 'torch'\" >&2\nexit 1\n",
    );
    let bench = |python: &str| {
        bowden(&[
            "bench",
            "train",
            "--arch",
            "tcn",
            "--windows",
            "32",
            "--seq-len",
            "12",
            "--epochs",
            "1",
            "--pytorch",
            python,
        ])
    };
    fails_with(&bench(&no_torch), &["--pytorch", "No module named 'torch'"]);
    let missing = tmp.path().join("no-such-python").display().to_string();
    fails_with(&bench(&missing), &["--pytorch", "no-such-python"]);

    let data = synthetic_dir(&tmp.path().join("data"), 400);
    let model = tmp.path().join("lstm.onnx").display().to_string();
    let train = |precision: &str| {
        ok(&bowden(&[
            "train",
            "--arch",
            "lstm",
            "--direction",
            "forward",
            "--seq-len",
            "8",
            "--epochs",
            "1",
            "--data",
            &data,
            "--out",
            &model,
            "--force",
            "--precision",
            precision,
        ]))
    };
    let report = || -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("lstm.report.json")).unwrap()).unwrap()
    };
    train("bf16");
    assert_eq!(report()["config"]["precision"], "bf16");
    // f32 is the default and is not written, so reports read as before the option existed.
    train("f32");
    assert!(report()["config"].get("precision").is_none());
    fails_with(
        &bowden(&[
            "train",
            "--arch",
            "lstm",
            "--direction",
            "forward",
            "--data",
            &data,
            "--out",
            &model,
            "--precision",
            "f16",
        ]),
        &["--precision", "f16"],
    );
}

/// `bowden score` (#42 item 3) reproduces `train`'s validation RMSE to the last bit, forward
/// and inverse, on the windows of each model's training report (here a two-block split and the
/// decimation `auto` chose), and reports MAE and identity beside it, with a plot.
#[test]
fn score_reproduces_train_validation_rmse_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synthetic_dir(&tmp.path().join("data"), 1500);
    let dir = tmp.path().join("m");
    let (fwd, inv) = (dir.join("fwd.onnx"), dir.join("inv.onnx"));
    let (fwd_s, inv_s) = (fwd.display().to_string(), inv.display().to_string());
    let split = ["--seq-len", "16", "--epochs", "2", "--seed", "3", "--val-blocks", "2"];
    ok(&train_tcn_forward(&data, &fwd_s, &split));
    let mut args = vec![
        "train",
        "--arch",
        "tcn",
        "--direction",
        "inverse",
        "--data",
        &data,
        "--out",
        &inv_s,
    ];
    args.extend_from_slice(&split);
    ok(&bowden(&args));
    let plots = tmp.path().join("plots").display().to_string();
    let out = ok(&bowden(&[
        "score", "--json", "--data", &data, &fwd_s, &inv_s, "--plots", &plots,
    ]));
    let scores: serde_json::Value = serde_json::from_str(&out).unwrap();
    for (i, (m, stem)) in [(&fwd, "fwd"), (&inv, "inv")].into_iter().enumerate() {
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(m.with_extension("report.json")).unwrap()).unwrap();
        let s = &scores[i];
        assert_eq!(s["rmse_deg"], report["best_val_rmse_deg"], "{m:?}: {s}");
        assert_eq!(s["rmse_per_joint_deg"], report["best_val_rmse_per_joint_deg"]);
        assert_eq!(s["identity_rmse_deg"], report["identity_val_rmse_deg"]);
        assert_eq!(s["windows"], report["data"]["val_windows"]);
        assert_eq!(s["settings"]["decimation"], report["config"]["decimation"]);
        assert_eq!(s["settings"]["split"]["val_blocks"], 2);
        let (mae, rmse) = (s["mae_deg"].as_f64().unwrap(), s["rmse_deg"].as_f64().unwrap());
        assert!(mae > 0.0 && mae <= rmse, "MAE ≤ RMSE: {mae} {rmse}");
        let svg = std::fs::read_to_string(Path::new(&plots).join(format!("{stem}.score.svg"))).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("measured"));
    }
    assert_eq!(scores[1]["direction"], "inverse");
    // Other windows, other figures: the report's settings are what made them equal.
    let out = ok(&bowden(&[
        "score",
        "--json",
        "--ignore-report",
        "--data",
        &data,
        &fwd_s,
    ]));
    let other: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(other[0]["settings"]["from"], "given");
    assert_ne!(other[0]["rmse_deg"], scores[0]["rmse_deg"]);
}
