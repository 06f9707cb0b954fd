//! Online adaptation and the hot model swap, with real processes in lockstep:
//! 1. a swap drill (the adapt node re-announcing the models in use every 10 ticks) makes 100
//!    swaps at 1 kHz with 0 allocations and 0 deadline faults in the compensator's cycle, and
//!    changes no command: the recorded commands are byte-identical to a run without swaps;
//! 2. a killed adapt node does not disturb the control chain;
//! 3. a slack session: with adaptation the error returns to its level before the slip, without
//!    it does not (`bowden evaluate --session --adapt`).

use crate::runtime_support;
use bowden::registry::REGISTRY;
use bowden_interfaces::{services, JointCommand, MotorCommand};

use bowden_runtime::config::{Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::session::{LockstepSession, SessionOptions};
use runtime_support::*;
use std::path::Path;
use std::time::Duration;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The control chain of the other runtime tests, with newton on the shipped TCN pair and an
/// adapt node.
fn chain_with_adapt(prefix: &str, state_dir: &Path, drill: u64, log: Option<&Path>) -> String {
    let controller = root().join("configs/controller.toml");
    let mut s = control_chain(prefix, "never")
        .replace("samples = 20\npause_s = 0.05", "samples = 30\npause_s = 0.02")
        .replace(
            "mode = \"uncalibrated\"",
            &format!("config = \"{}\"\nmode = \"newton\"", controller.display()),
        );
    s.push_str(&format!(
        r#"
[[node]]
name = "adapt"
on_loss = "continue"      # a helper: the chain goes on with the last good model
[node.params]
state_dir = "{state}"
resume = false
drill_every_ticks = {drill}
"#,
        state = state_dir.display(),
    ));
    if let Some(log) = log {
        s.push_str(&format!(
            r#"
[[node]]
name = "recorder"
[node.params]
path = "{}"
services = ["bowden/joint_command"]
"#,
            log.display()
        ));
    }
    s
}

/// `(process, system allocations, measured cycles)` from the executors' exit summaries.
fn audit(stderr: &str, process: &str) -> Option<(u64, u64)> {
    let mut current = None;
    for line in stderr.lines() {
        if let Some(rest) = line.strip_prefix('[') {
            current = rest.split(']').next().map(str::to_string);
        }
        if let Some(rest) = line
            .trim()
            .strip_prefix("allocations after 100 warm-up cycles: system ")
        {
            if current.as_deref() == Some(process) {
                let mut it = rest.split_whitespace();
                let sys: u64 = it.next()?.parse().ok()?;
                let cycles: u64 = it.nth(1)?.parse().ok()?;
                return Some((sys, cycles));
            }
        }
    }
    None
}

#[test]
fn a_swap_drill_of_100_swaps_changes_no_command_and_allocates_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let mut logs = Vec::new();
    for (tag, drill) in [("drill", 10u64), ("plain", 0)] {
        let (p, _guard) = guarded_prefix(&format!("swap{tag}"));
        let log = dir.path().join(format!("{tag}.blog"));
        let cfg = write_config(
            dir.path(),
            &format!("{tag}.toml"),
            &chain_with_adapt(&p, &dir.path().join(format!("state-{tag}")), drill, Some(&log)),
        );
        // 1,005 ticks at 1 kHz: announcements at ticks 10, 20, ..., 1000, each swapped in at the
        // next tick.
        let out = bowden()
            .args([
                "run",
                cfg.to_str().unwrap(),
                "--ticks",
                "1005",
                "--prefix",
                &p,
                "--record",
            ])
            .arg(&log)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{stdout}\n{stderr}");
        assert!(
            stdout.contains("| compensator | stopped | 1005 | 0 | 0 | 0 |"),
            "the compensator had misses, rejections or faults:\n{stdout}"
        );
        if drill > 0 {
            assert!(
                stderr.contains("model generation 100 in use; 100 swaps, 0 updates refused"),
                "{stderr}"
            );
        } else {
            assert!(stderr.contains("0 swaps, 0 updates refused"), "{stderr}");
        }
        let (sys, cycles) = audit(&stderr, "compensator").expect("the compensator's allocation audit");
        assert_eq!(sys, 0, "the compensator allocated in its cycle ({tag})");
        assert_eq!(cycles, 905);
        assert_clean(&p);
        logs.push(log);
    }
    let a = std::fs::read(&logs[0]).unwrap();
    let b = std::fs::read(&logs[1]).unwrap();
    assert!(a.len() > 100_000, "log of {} bytes", a.len());
    assert!(a == b, "swapping in the same weights changed the commands");
}

#[test]
fn a_killed_adapt_node_does_not_disturb_the_control_chain() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("adkill");
    let path = write_config(
        dir.path(),
        "chain.toml",
        &chain_with_adapt(&p, &dir.path().join("state"), 0, None),
    );
    let cfg = PipelineConfig::load(&path, &Overrides::default(), REGISTRY).unwrap();
    let mut opts = SessionOptions::new(LaunchOptions::with_exe(bowden_exe()));
    opts.launch.quiet_children = true;
    opts.taps = vec![services::JOINT_COMMAND.into(), services::MOTOR_COMMAND.into()];
    opts.stall_timeout = Some(Duration::from_secs(20));
    let mut s = LockstepSession::start(&cfg, opts).unwrap();
    for _ in 0..200 {
        assert!(s.step().unwrap().get::<JointCommand>(services::JOINT_COMMAND).is_some());
    }
    let pid = s.pids().iter().find(|(n, _)| n == "adapt").map(|(_, p)| *p).unwrap();
    // SAFETY: SIGKILL to a child process this test's session started.
    assert_eq!(unsafe { libc::kill(pid as i32, libc::SIGKILL) }, 0);
    let mut events = Vec::new();
    for k in 200..600 {
        let out = s.step().unwrap();
        events.extend(out.events.iter().cloned());
        assert!(
            out.get::<JointCommand>(services::JOINT_COMMAND).is_some(),
            "tick {k}: the compensator went on"
        );
        let m = out
            .get::<MotorCommand>(services::MOTOR_COMMAND)
            .expect("a motor command every tick");
        assert_eq!(
            m.flags & bowden_interfaces::MotorCommand::FLAG_HOLD,
            0,
            "tick {k}: no hold"
        );
    }
    assert!(
        events.iter().any(|e| e.contains("`adapt` exited (killed by signal 9)")),
        "{events:?}"
    );
    let report = s.shutdown().unwrap();
    for stage in ["compensator", "actuator", "plant"] {
        let st = report.status(stage).unwrap();
        assert_eq!(
            (st.cycles, st.faults, st.deadline_misses),
            (600, 0, 0),
            "{stage}: {st:?}"
        );
    }
    assert_clean(&p);
}

/// `(before, end)` tip position error by truth, mm, of a session report.
fn before_end(report: &Path) -> (f64, f64) {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(report.join("session.json")).unwrap()).unwrap();
    let s = &v["summary"]["summary"][0];
    (
        s["before"]["task_truth"]["pos_mean_mm"].as_f64().unwrap(),
        s["end"]["task_truth"]["pos_mean_mm"].as_f64().unwrap(),
    )
}

#[test]
fn adaptation_recovers_a_cable_slip_and_feed_forward_alone_does_not() {
    let dir = tempfile::tempdir().unwrap();
    // The shipped slip scenario, the slip at 60 s instead of 120 s to keep the test short.
    let plant = std::fs::read_to_string(root().join("configs/plant-slack-slip.toml"))
        .unwrap()
        .replace("at_s = 120.0", "at_s = 60.0");
    let plant = write_config(dir.path(), "plant-slip.toml", &plant);
    let run = |tag: &str, adapt: bool| {
        let report = dir.path().join(tag);
        let mut cmd = bowden();
        cmd.current_dir(root())
            .args(["evaluate", "--session", "4", "--controllers", "newton"])
            .args(["--controller-config", "configs/controller.toml"])
            .args(["--trajectories-dir", "configs/trajectories/tuning", "--plant"])
            .arg(&plant)
            .arg("--report")
            .arg(&report);
        if adapt {
            cmd.args(["--adapt", "configs/adapt.toml"]);
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        report
    };
    let ff = run("ff", false);
    let ad = run("adapt", true);
    let (b_ff, e_ff) = before_end(&ff);
    let (b_ad, e_ad) = before_end(&ad);
    // Identical until the first swap: the same plant, seed and controller.
    assert_eq!(b_ff, b_ad);
    assert!(
        e_ff > 1.5 * b_ff,
        "the slip should hurt feed-forward: {b_ff:.3} → {e_ff:.3} mm"
    );
    assert!(
        e_ad <= 1.1 * b_ad,
        "adaptation did not recover: {b_ad:.3} → {e_ad:.3} mm (feed-forward {e_ff:.3})"
    );
    // Every swap is logged with its held-out errors, and each one validated better.
    let log = std::fs::read_to_string(ad.join("adapt-newton/adapt.jsonl")).unwrap();
    let swaps: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|r| r["decision"] == "swapped")
        .collect();
    assert!(!swaps.is_empty(), "{log}");
    for r in &swaps {
        let (b, a) = (r["fwd_before_deg"].as_f64(), r["fwd_after_deg"].as_f64());
        let (bi, ai) = (r["inv_before_deg"].as_f64(), r["inv_after_deg"].as_f64());
        assert!(
            a.zip(b).is_some_and(|(a, b)| a < b) || ai.zip(bi).is_some_and(|(a, b)| a < b),
            "{r}"
        );
    }
    assert!(ad.join("adapt-newton/gen-0001/fwd.onnx").exists());
}
