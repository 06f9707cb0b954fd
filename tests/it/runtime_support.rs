//! Helpers shared by the `runtime_*` integration tests: the `bowden` binary, a unique iceoryx2
//! prefix per test, and the check that a test leaves nothing in shared memory.

#![allow(dead_code)]

use bowden_runtime::ports::IpcSettings;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn bowden_exe() -> &'static str {
    env!("CARGO_BIN_EXE_bowden")
}

pub fn bowden() -> Command {
    Command::new(bowden_exe())
}

/// A prefix no other test (or run) uses: `bwt<pid><tag>_`.
pub fn prefix(tag: &str) -> String {
    format!("bwt{}{tag}_", std::process::id())
}

pub fn sim_toml() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/sim.toml")
}

pub fn settings(prefix: &str) -> IpcSettings {
    IpcSettings {
        prefix: prefix.to_string(),
        namespace: String::new(),
    }
}

/// Files of `prefix` under /dev/shm and the iceoryx2 root directory.
pub fn leftovers(prefix: &str) -> Vec<PathBuf> {
    bowden_runtime::cleanup::prefix_files(&settings(prefix))
}

/// Removes a test prefix's resources when dropped, even when the test panics.
pub struct PrefixGuard(pub String);

impl Drop for PrefixGuard {
    fn drop(&mut self) {
        let _ = bowden_runtime::cleanup::remove_stale_nodes(&settings(&self.0));
        let _ = bowden_runtime::cleanup::remove_prefix_files(&settings(&self.0));
    }
}

/// A unique prefix and the guard that cleans it up.
pub fn guarded_prefix(tag: &str) -> (String, PrefixGuard) {
    let p = prefix(tag);
    (p.clone(), PrefixGuard(p))
}

pub fn assert_clean(prefix: &str) {
    let left = leftovers(prefix);
    assert!(left.is_empty(), "prefix `{prefix}` left files behind: {left:?}");
}

/// Runs `bowden args...`, panicking with its output if it fails.
pub fn run_ok(args: &[&str]) -> Output {
    let out = bowden().args(args).output().expect("bowden runs");
    if !out.status.success() {
        panic!(
            "bowden {args:?} failed ({}):\nstdout:\n{}\nstderr:\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    out
}

/// Writes a pipeline config into `dir` and returns its path.
pub fn write_config(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write config");
    p
}

/// The control chain (trajectory → compensator → actuator → plant) in lockstep, with the
/// compensator's restart policy given.
pub fn control_chain(prefix: &str, restart: &str) -> String {
    format!(
        r#"[runtime]
mode = "lockstep"
prefix = "{prefix}"
period_us = 1000
seed = 3

[[node]]
name = "trajectory"
[node.params]
source = "dataset"
samples = 20
pause_s = 0.05

[[node]]
name = "compensator"
restart = "{restart}"
[node.params]
mode = "uncalibrated"

[[node]]
name = "actuator"
[node.params]
stale_after_ms = 20.0

[[node]]
name = "plant"
[node.params]
"#
    )
}

/// A lockstep session of the pipeline file `file` (the `bowden` binary's kinds) under the test
/// prefix of `tag`, tapping `taps`; the guard removes the prefix's files when dropped.
pub fn lockstep_session(
    file: &Path,
    tag: &str,
    taps: &[&str],
) -> (bowden_runtime::session::LockstepSession, PrefixGuard) {
    use bowden_runtime::config::{Mode, Overrides, PipelineConfig};
    use bowden_runtime::launch::LaunchOptions;
    use bowden_runtime::session::{LockstepSession, SessionOptions};
    let (prefix, guard) = guarded_prefix(tag);
    let ov = Overrides {
        mode: Some(Mode::Lockstep),
        prefix: Some(prefix),
        ..Default::default()
    };
    let cfg = PipelineConfig::load(file, &ov, bowden::registry::REGISTRY).unwrap();
    let mut opts = SessionOptions::new(LaunchOptions {
        quiet_children: true,
        ..LaunchOptions::with_exe(bowden_exe())
    });
    opts.taps = taps.iter().map(|s| s.to_string()).collect();
    (LockstepSession::start(&cfg, opts).unwrap(), guard)
}
