//! The conventions every subcommand follows (issue #14 item 2): `--json` prints JSON on stdout
//! and `--json-out FILE` writes it; enumerations are listed in `--help` and matched
//! case-insensitively; the common mistakes get a hint; an OS error's text is printed once.

use crate::cli_support;
use cli_support::{bowden, fails_with, ok};

fn help(args: &[&str]) -> String {
    ok(&bowden(&[args, &["--help"]].concat()))
}

#[test]
fn help_lists_every_enumeration_and_the_json_convention() {
    let train = help(&["train"]);
    for values in [
        "fnn, lstm, tcn, tcn-lstm",
        "forward, inverse",
        "relu-linear, relu-relu",
        "fused, candle",
        "vision, truth",
    ] {
        assert!(train.contains(values), "train --help lacks {values:?}:\n{train}");
    }
    let sweep = help(&["sweep"]);
    for opt in ["--data <DATA>", "--early-stop <EARLY_STOP>"] {
        let line = sweep
            .lines()
            .find(|l| l.trim_start().starts_with(opt))
            .unwrap_or_else(|| panic!("{opt:?} in {sweep}"));
        assert!(
            !line.trim_start()[opt.len()..].trim().is_empty(),
            "sweep {opt} has no help:\n{sweep}"
        );
    }
    assert!(help(&["collect"]).contains("paper, mixed"));
    assert!(help(&["evaluate"]).contains("uncalibrated, paper, newton"));
    for cmd in [
        &["evaluate"][..],
        &["run"],
        &["replay"],
        &["bench", "ipc"],
        &["bench", "cycle"],
    ] {
        let h = help(cmd);
        assert!(
            h.contains("--json ") || h.contains("--json\n"),
            "{cmd:?}: --json is a flag:\n{h}"
        );
        assert!(h.contains("--json-out <FILE>"), "{cmd:?}:\n{h}");
    }
}

#[test]
fn enumerations_are_case_insensitive_and_dataset_files_get_a_hint() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("dataset.csv");
    std::fs::write(&csv, "t_ns,q_cmd_1\n").unwrap();
    let csv_s = csv.display().to_string();
    // `--arch TCN --direction Forward` pass clap; the dataset file is then refused with a hint.
    let out = bowden(&[
        "train",
        "--arch",
        "TCN",
        "--direction",
        "Forward",
        "--phy-source",
        "TRUTH",
        "--data",
        &csv_s,
        "--out",
        &dir.path().join("m.onnx").display().to_string(),
    ]);
    fails_with(
        &out,
        &[
            "expected the dataset DIRECTORY (containing dataset.csv and manifest.json); you gave the file",
            &format!("use --data {}", dir.path().display()),
        ],
    );
    assert_eq!(String::from_utf8_lossy(&out.stderr).trim().lines().count(), 1);
    fails_with(
        &bowden(&["train", "--arch", "gru", "--direction", "forward"]),
        &["gru", "tcn-lstm"],
    );
    for args in [
        &[
            "tune",
            "--data",
            &csv_s,
            "--forward",
            "a.onnx",
            "--inverse",
            "b.onnx",
            "--out",
            "x.toml",
        ][..],
        &["stamp-support", "--data", &csv_s, "a.onnx"],
    ] {
        fails_with(&bowden(args), &["expected the dataset DIRECTORY"]);
    }
}

#[test]
fn an_os_error_is_printed_once() {
    let dir = tempfile::tempdir().unwrap();
    // A directory where a file is expected: the OS says "Is a directory (os error 21)".
    let out = bowden(&["fk", "--q", "0,0,0,0,0", "--config", &dir.path().display().to_string()]);
    fails_with(&out, &["os error 21"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.matches("os error 21").count(), 1, "{err}");
    // A file found nowhere names where it was looked for.
    let out = bowden(&["fk", "--q", "0,0,0,0,0", "--config", "configs/nope.toml"]);
    fails_with(
        &out,
        &["configs/nope.toml", "not found", "BOWDEN_HOME", "bowden shipped"],
    );
}

#[test]
fn outputs_are_kept_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let plot = dir.path().join("loops.svg").display().to_string();
    let run =
        |extra: &[&str]| bowden(&[&["plant", "characterize", "--samples", "3", "--plot", &plot][..], extra].concat());
    ok(&run(&[]));
    fails_with(&run(&[]), &[&plot, "exists", "--force", "--plot"]);
    ok(&run(&["--force"]));
}
