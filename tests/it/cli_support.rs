//! Running the `bowden` binary from integration tests: the repository root as the working
//! directory, and the two outcomes every CLI test checks.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `bowden ARGS` from the repository root.
pub fn bowden(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bowden"))
        .current_dir(repo())
        .args(args)
        .output()
        .expect("run bowden")
}

/// The stdout of a run that must succeed (else its stderr and stdout in the panic).
pub fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "bowden failed: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A run that must fail with a clear error mentioning every needle, and no panic.
pub fn fails_with(out: &Output, needles: &[&str]) {
    assert!(!out.status.success(), "expected a failure");
    let err = String::from_utf8_lossy(&out.stderr);
    for n in needles {
        assert!(err.contains(n), "stderr {err:?} does not mention {n:?}");
    }
    assert!(!err.contains("panicked"), "{err}");
}

/// The `seed` and `[recipe]` of a `bench transfer` config the tests share (the quick recipe over
/// the three test paths, from the shipped TCN controller), without a trailing newline.
pub fn transfer_recipe(tune: bool) -> String {
    format!(
        r#"seed = 7
[recipe]
samples = 3000
excitation = "mixed"
archs = ["tcn"]
epochs = 100
seq_len = 80
repeats = 3
trajectories = ["random", "circle", "zigzag"]
controllers = ["uncalibrated", "paper", "newton"]
tune = {tune}
base_controller = "{base}""#,
        base = repo().join("configs/controller.toml").display(),
    )
}

/// The iceoryx2 files in /dev/shm whose names start with one of `prefixes` (the pipelines of
/// `bowden` subcommands: `bev<pid>_…` of evaluate, `bcol<pid>_…` of collect, …).
pub fn shm_files(prefixes: &[&str]) -> std::collections::BTreeSet<String> {
    std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| prefixes.iter().any(|p| n.starts_with(p)))
                .collect()
        })
        .unwrap_or_default()
}

/// Files of `prefixes` that appeared since `before` and whose owner (the pid after the prefix)
/// has exited: what a finished run left behind. Files of a process still running — another
/// run on the same machine — are not counted.
pub fn shm_leaked_since(before: &std::collections::BTreeSet<String>, prefixes: &[&str]) -> Vec<String> {
    shm_files(prefixes)
        .difference(before)
        .filter(|n| {
            let rest = prefixes.iter().find_map(|p| n.strip_prefix(p)).unwrap_or(n.as_str());
            let pid: String = rest.chars().take_while(char::is_ascii_digit).collect();
            pid.is_empty() || !std::path::Path::new("/proc").join(&pid).exists()
        })
        .cloned()
        .collect()
}
