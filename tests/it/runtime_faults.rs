//! Faults with real processes: a node killed mid-run is detected and the actuator holds the last
//! safe command (lockstep and real time); a restart policy brings it back; a run SIGKILLed as a
//! whole leaves stale shared memory that the next run removes; the e-stop latches.

use crate::runtime_support;
use bowden::registry::REGISTRY;

use bowden_interfaces::{services, JointCommand, MotorCommand, SafetyCommand};
use bowden_runtime::config::{Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::session::{LockstepSession, Outcome, RealtimeSession, SessionError, SessionOptions};
use bowden_runtime::stage::state;
use runtime_support::*;
use std::time::Duration;

fn session(cfg_text: &str, dir: &std::path::Path) -> LockstepSession {
    let path = write_config(dir, "chain.toml", cfg_text);
    let cfg = PipelineConfig::load(&path, &Overrides::default(), REGISTRY).unwrap();
    let mut opts = SessionOptions::new(LaunchOptions::with_exe(bowden_exe()));
    opts.launch.quiet_children = true;
    opts.taps = vec![services::MOTOR_COMMAND.into(), services::JOINT_COMMAND.into()];
    opts.stall_timeout = Some(Duration::from_secs(20));
    LockstepSession::start(&cfg, opts).unwrap()
}

fn kill(pid: u32) {
    // SAFETY: SIGKILL to a child process this test's session started.
    assert_eq!(unsafe { libc::kill(pid as i32, libc::SIGKILL) }, 0);
}

fn pid_of(pids: &[(String, u32)], name: &str) -> u32 {
    pids.iter()
        .find(|(n, _)| n == name)
        .map(|(_, p)| *p)
        .expect("process exists")
}

#[test]
fn killed_compensator_without_restart_halts_the_run_with_an_estop() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard_p) = guarded_prefix("kill");
    let mut s = session(&control_chain(&p, "never"), dir.path());
    for _ in 0..300 {
        let out = s.step().unwrap();
        let m = out
            .get::<MotorCommand>(services::MOTOR_COMMAND)
            .expect("a motor command every tick");
        assert_eq!(m.flags & MotorCommand::FLAG_HOLD, 0);
    }
    kill(pid_of(&s.pids(), "compensator"));
    // Detected in the tick it happened (or the next): no restart left, so the launcher latches
    // the e-stop and halts rather than run on without a stage ("the others go on" is gone).
    let halted = (300..310u64).find_map(|_| match s.step() {
        Ok(_) => None,
        Err(SessionError::Halted { tick, reason }) => Some((tick, reason)),
        Err(e) => panic!("{e}"),
    });
    let (tick, reason) = halted.expect("halted");
    assert!(tick <= 301, "halted at tick {tick}");
    assert!(
        reason.contains("compensator") && reason.contains("lost for good"),
        "{reason}"
    );
    let report = s.shutdown().unwrap();
    assert!(
        report
            .events
            .iter()
            .any(|e| e.contains("`compensator` exited (killed by signal 9)") && e.contains("e-stop, run halted")),
        "{:?}",
        report.events
    );
    assert_eq!(report.outcome, Outcome::Unrecovered);
    assert_clean(&p);
}

#[test]
fn killed_compensator_is_restarted_and_commands_resume() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard_p) = guarded_prefix("rst");
    let mut s = session(&control_chain(&p, "on-failure"), dir.path());
    for _ in 0..100 {
        s.step().unwrap();
    }
    let old = pid_of(&s.pids(), "compensator");
    kill(old);
    let mut events = Vec::new();
    let mut resumed = 0;
    for _ in 0..100 {
        let out = s.step().unwrap();
        events.extend(out.events.iter().cloned());
        if out.get::<JointCommand>(services::JOINT_COMMAND).is_some() {
            resumed += 1;
        }
    }
    assert!(
        events.iter().any(|e| e.contains("restarting at the next tick")),
        "{events:?}"
    );
    assert!(
        events.iter().any(|e| e.contains("`compensator` restarted (restart 1)")),
        "{events:?}"
    );
    assert_ne!(pid_of(&s.pids(), "compensator"), old);
    assert!(
        resumed >= 95,
        "commands resumed after the restart ({resumed} of 100 ticks)"
    );
    let report = s.shutdown().unwrap();
    // The gap was shorter than the watchdog: no fault.
    assert_eq!(report.status("actuator").unwrap().faults, 0);
    assert_clean(&p);
}

/// Runs the pipeline until `bowden estop ARGS` (started in the background) has exited,
/// returning the motor command of the tick during which it exited.
fn step_while(s: &mut LockstepSession, p: &str, release: bool) -> MotorCommand {
    let mut args = vec!["estop", "--prefix", p];
    if release {
        args.push("--release");
    }
    let mut child = bowden()
        .args(&args)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    for _ in 0..5000 {
        let m = s.step().unwrap().get::<MotorCommand>(services::MOTOR_COMMAND).unwrap();
        if let Some(status) = child.try_wait().unwrap() {
            let out = child.wait_with_output().unwrap();
            assert!(status.success(), "{}", String::from_utf8_lossy(&out.stdout));
            assert!(String::from_utf8_lossy(&out.stdout).contains("confirmed by `actuator`"));
            return m;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    panic!("bowden estop did not finish");
}

#[test]
fn estop_latches_the_actuator() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard_p) = guarded_prefix("stop");
    let mut s = session(&control_chain(&p, "never"), dir.path());
    for _ in 0..50 {
        s.step().unwrap();
    }
    let m = step_while(&mut s, &p, false);
    assert_ne!(m.flags & MotorCommand::FLAG_ESTOP, 0);
    for _ in 0..50 {
        let k = s.step().unwrap().get::<MotorCommand>(services::MOTOR_COMMAND).unwrap();
        assert_ne!(k.flags & MotorCommand::FLAG_ESTOP, 0, "latched");
        assert_eq!(k.q_cmd_deg, m.q_cmd_deg, "holds while latched");
    }
    step_while(&mut s, &p, true);
    let after = s.step().unwrap().get::<MotorCommand>(services::MOTOR_COMMAND).unwrap();
    assert_eq!(after.flags & (MotorCommand::FLAG_ESTOP | MotorCommand::FLAG_HOLD), 0);
    let _ = (SafetyCommand::ESTOP, services::SAFETY);
    s.shutdown().unwrap();
    assert_clean(&p);
}

#[test]
fn realtime_kill_is_detected_and_watchdog_holds() {
    let (p, _guard_p) = guarded_prefix("rtk");
    let ov = Overrides {
        prefix: Some(p.clone()),
        ..Default::default()
    };
    let mut cfg = PipelineConfig::load(&sim_toml(), &ov, REGISTRY).unwrap();
    // The control chain only; no restart, so the hold lasts.
    cfg.stages
        .retain(|s| ["trajectory", "compensator", "actuator", "plant"].contains(&s.name.as_str()));
    cfg.processes
        .retain(|pr| ["trajectory", "compensator", "actuator", "plant"].contains(&pr.name.as_str()));
    for (i, pr) in cfg.processes.iter_mut().enumerate() {
        pr.stages = vec![i];
        pr.restart = bowden_runtime::config::RestartPolicy::Never;
    }
    let mut opts = SessionOptions::new(LaunchOptions::with_exe(bowden_exe()));
    opts.launch.quiet_children = true;
    let mut s = RealtimeSession::start(&cfg, opts).unwrap();
    s.run_for(Some(Duration::from_millis(700))).unwrap();
    kill(pid_of(&s.pids(), "compensator"));
    // Returns once the launcher halted the run (long before the 10 s).
    s.run_for(Some(Duration::from_secs(10))).unwrap();
    let report = s.shutdown().unwrap();
    assert!(
        report
            .events
            .iter()
            .any(|e| e.contains("`compensator` exited (killed by signal 9)") && e.contains("e-stop, run halted")),
        "{:?}",
        report.events
    );
    assert!(report.halted.is_some());
    assert!(
        report.faults.iter().any(|f| f.what.starts_with("e-stop confirmed")),
        "{:?}",
        report.faults
    );
    // The actuator took the launcher's e-stop before the run stopped.
    assert!(
        report.end_states.contains(&("actuator".to_string(), state::ESTOP)),
        "{:?}",
        report.end_states
    );
    assert_eq!(report.outcome, Outcome::Unrecovered);
    assert_clean(&p);
}

#[test]
fn stale_resources_of_a_killed_run_are_removed_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard_p) = guarded_prefix("stale");
    let cfg = write_config(dir.path(), "chain.toml", &control_chain(&p, "never"));
    // A run that never ends by itself, in its own process group so one SIGKILL takes it all.
    let mut child = {
        use std::os::unix::process::CommandExt;
        bowden()
            .args(["run", cfg.to_str().unwrap(), "--quiet"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .process_group(0)
            .spawn()
            .unwrap()
    };
    let t0 = std::time::Instant::now();
    while leftovers(&p).len() < 20 && t0.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: SIGKILL to the process group of the child this test started.
    assert_eq!(unsafe { libc::kill(-(child.id() as i32), libc::SIGKILL) }, 0);
    child.wait().unwrap();
    std::thread::sleep(Duration::from_millis(100));
    let stale = leftovers(&p);
    assert!(stale.len() >= 20, "the killed run left its shared memory: {stale:?}");

    let out = run_ok(&["run", cfg.to_str().unwrap(), "--ticks", "200", "--quiet"]);
    let err = String::from_utf8_lossy(&out.stderr);
    let removed: usize = err
        .lines()
        .find_map(|l| l.strip_prefix("launcher: removed stale iceoryx2 resources of "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no cleanup report in:\n{err}"));
    assert_eq!(removed, 5, "launcher + 4 nodes were dead:\n{err}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("| plant | stopped | 200 |"));
    assert_clean(&p);
}

#[test]
fn ctrl_c_stops_every_process_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard_p) = guarded_prefix("sigint");
    let cfg = write_config(
        dir.path(),
        "chain.toml",
        &control_chain(&p, "never").replace("mode = \"lockstep\"", "mode = \"realtime\""),
    );
    // As a terminal does: SIGINT to the whole foreground process group, once it runs.
    let mut child = {
        use std::os::unix::process::CommandExt;
        bowden()
            .args(["run", cfg.to_str().unwrap()])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .process_group(0)
            .spawn()
            .unwrap()
    };
    let (tx, rx) = std::sync::mpsc::channel();
    let err_pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        use std::io::BufRead;
        let mut all = String::new();
        for line in std::io::BufReader::new(err_pipe).lines().map_while(Result::ok) {
            if line.contains("process(es) ready") {
                let _ = tx.send(());
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    rx.recv_timeout(Duration::from_secs(30)).expect("the pipeline came up");
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: SIGINT to the process group of the child this test started.
    assert_eq!(unsafe { libc::kill(-(child.id() as i32), libc::SIGINT) }, 0);
    let out = child.wait_with_output().unwrap();
    let stderr = reader.join().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}\n{stdout}\n{stderr}", out.status);
    // Every stage stopped by itself (nobody had to be signalled again) and said so.
    for stage in ["trajectory", "compensator", "actuator", "plant"] {
        assert!(stdout.contains(&format!("| {stage} | stopped |")), "{stdout}");
        assert!(
            stderr.contains(&format!("[{stage}] exit summary (realtime)")),
            "{stderr}"
        );
    }
    assert!(!stdout.contains("did not exit in time"), "{stdout}");
    assert_clean(&p);
}

#[test]
fn a_bad_node_parameter_fails_start_up_clearly_and_cleanly() {
    // (what is replaced, by what, the stage, the field named in the error)
    let cases = [
        (
            "stale_after_ms = 20.0",
            "stale_after_ms = -1.0",
            "actuator",
            "stale_after_ms",
        ),
        (
            "name = \"plant\"\n[node.params]",
            "name = \"plant\"\n[node.params]\nunit = \"soon\"",
            "plant",
            "unit",
        ),
    ];
    for (i, (from, to, stage, field)) in cases.into_iter().enumerate() {
        let dir = tempfile::tempdir().unwrap();
        let (p, _guard_p) = guarded_prefix(&format!("badp{i}"));
        let text = control_chain(&p, "never");
        assert!(text.contains(from), "{from}");
        let cfg = write_config(dir.path(), "chain.toml", &text.replace(from, to));
        let out = bowden()
            .args(["run", cfg.to_str().unwrap(), "--ticks", "10"])
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        // The child names the file, the stage and the field; the launcher names the process.
        assert!(
            err.contains("chain.toml") && err.contains(&format!("`{stage}`")) && err.contains(field),
            "{err}"
        );
        assert!(
            err.contains(&format!("process `{stage}` exited during start-up (exit code 1)")),
            "{err}"
        );
        assert_clean(&p);
    }
}
