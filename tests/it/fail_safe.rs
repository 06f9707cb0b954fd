//! Fail safe (#41): robot-side faults hold the robot in the tick they are detected, motion
//! resumes only as configured, a process lost for good halts the run with an e-stop, and the
//! run's outcome (its exit code) tells the truth. Lockstep, so every figure is exact: the
//! control chain at 1 kHz with the plant's fault injection (`[node.params] fault`).

use crate::runtime_support::*;
use bowden::registry::REGISTRY;
use bowden_interfaces::{fault, services, MotorCommand, PlantState};
use bowden_runtime::config::{Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::session::{LockstepSession, Outcome, SessionError, SessionOptions};
use bowden_runtime::stage::state;
use std::time::Duration;

const FAULT_TICK: u64 = 200;

fn start(cfg_text: &str, dir: &std::path::Path) -> LockstepSession {
    // A shared machine can pause a tick for seconds: no stall halts these runs by accident.
    start_with_stall(cfg_text, dir, Some(Duration::from_secs(20)))
}

/// [`start`] with the session's stall bound: `None` keeps the config's `stall_timeout_ms`.
fn start_with_stall(cfg_text: &str, dir: &std::path::Path, stall: Option<Duration>) -> LockstepSession {
    let path = write_config(dir, "chain.toml", cfg_text);
    let cfg = PipelineConfig::load(&path, &Overrides::default(), REGISTRY).unwrap();
    let mut opts = SessionOptions::new(LaunchOptions::with_exe(bowden_exe()));
    opts.launch.quiet_children = true;
    opts.taps = vec![services::MOTOR_COMMAND.into(), services::PLANT_STATE.into()];
    opts.stall_timeout = stall;
    LockstepSession::start(&cfg, opts).unwrap()
}

/// The control chain with the plant's fault injection from `FAULT_TICK` on (the plant's time
/// after its step k is (k + 1) ms).
fn faulty_chain(prefix: &str, kind: &str) -> String {
    format!(
        "{}fault = {{ kind = \"{kind}\", after_s = {} }}\n",
        control_chain(prefix, "never"),
        (FAULT_TICK + 1) as f64 / 1000.0
    )
}

fn bad(p: &PlantState) -> bool {
    p.q_phy_deg[..5].iter().any(|v| !v.is_finite() || v.abs() > 100.0)
}

#[test]
fn robot_faults_hold_the_robot_in_the_tick_they_are_detected() {
    let dir = tempfile::tempdir().unwrap();
    for (kind, tag) in [("nan", "fs1"), ("out-of-range", "fs2"), ("silent", "fs3")] {
        let (p, _guard) = guarded_prefix(tag);
        let mut s = start(&faulty_chain(&p, kind), dir.path());
        let (mut last_good_state, mut first_bad_state, mut hold_at) = (None, None, None);
        let mut held_q = None;
        for k in 0..400u64 {
            let out = s.step().unwrap();
            assert!(out.events.is_empty(), "{kind}: {:?}", out.events);
            match out.get::<PlantState>(services::PLANT_STATE) {
                Some(ps) if bad(&ps) => {
                    first_bad_state.get_or_insert(k);
                }
                Some(_) => last_good_state = Some(k),
                None => {}
            }
            let m = out
                .get::<MotorCommand>(services::MOTOR_COMMAND)
                .expect("a motor command every tick");
            if m.flags & MotorCommand::FLAG_FAULT != 0 {
                assert_ne!(m.flags & MotorCommand::FLAG_HOLD, 0, "{kind}: a fault hold is a hold");
                hold_at.get_or_insert(k);
                // No motion after the detection: every later command is the same hold.
                assert_eq!(*held_q.get_or_insert(m.q_cmd_deg), m.q_cmd_deg, "{kind}: tick {k}");
            } else {
                assert!(hold_at.is_none(), "{kind}: tick {k}: motion resumed without a release");
            }
        }
        let hold_at = hold_at.unwrap_or_else(|| panic!("{kind}: the actuator never held"));
        let last_good = last_good_state.unwrap();
        match kind {
            // The actuator reads tick k's state in its step of tick k + 1: that very step holds.
            "silent" => {
                assert_eq!(first_bad_state, None);
                assert_eq!(last_good, FAULT_TICK - 1, "the plant's last state");
                // 40 ms default bound: the first step whose newest state is older than 40 ms.
                assert_eq!(hold_at, last_good + 41, "{kind}");
            }
            _ => {
                assert_eq!(first_bad_state, Some(FAULT_TICK), "{kind}");
                assert_eq!(hold_at, FAULT_TICK + 1, "{kind}");
            }
        }
        let report = s.shutdown().unwrap();
        let act = report.status("actuator").unwrap();
        let code = match kind {
            "nan" => fault::STATE_NOT_FINITE,
            "out-of-range" => fault::STATE_IMPLAUSIBLE,
            _ => fault::STATE_STALE,
        };
        assert_eq!((act.last_fault, act.faults), (code, 1), "{kind}: one episode");
        assert_eq!(
            report.outcome,
            Outcome::Unrecovered,
            "{kind}: {}",
            report.format_summary()
        );
        assert_eq!(report.outcome.exit_code(), 4);
        let hold = report
            .faults
            .iter()
            .find(|f| f.source == "actuator" && f.what.starts_with("safe hold"))
            .unwrap_or_else(|| panic!("{kind}: {:?}", report.faults));
        assert_eq!(hold.tick, Some(hold_at), "{kind}: reported at the tick it happened");
        assert!(hold.what.contains(fault::name(code)), "{hold}");
        assert!(report.end_states.contains(&("actuator".into(), state::FAULT)));
        assert_clean(&p);
    }
}

#[test]
fn a_clean_run_is_clean() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs4");
    let mut s = start(&control_chain(&p, "never"), dir.path());
    for _ in 0..300 {
        s.step().unwrap();
    }
    let report = s.shutdown().unwrap();
    assert!(report.faults.is_empty(), "{:?}", report.faults);
    assert_eq!(report.outcome, Outcome::Clean);
    assert_eq!(report.outcome.exit_code(), 0);
    assert_clean(&p);
}

/// A killed driver is restarted: the actuator holds from the lost state on, and motion resumes
/// only after the configured number of good states from the new instance.
#[test]
fn a_restarted_driver_must_report_good_states_before_motion_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs5");
    let text = control_chain(&p, "never")
        .replace(
            "stale_after_ms = 20.0\n",
            "stale_after_ms = 20.0\nrobot_state = { resume = { after_good = 50 } }\n",
        )
        .replace("name = \"plant\"\n", "name = \"plant\"\nrestart = \"on-failure\"\n");
    let log = dir.path().join("run.blog");
    let text = format!(
        "{text}\n[[node]]\nname = \"recorder\"\n[node.params]\npath = \"{}\"\nservices = [\"bowden/plant_state\"]\n",
        log.display()
    );
    let mut s = start(&text, dir.path());
    for _ in 0..FAULT_TICK {
        s.step().unwrap();
    }
    let plant = s.pids().into_iter().find(|(n, _)| n == "plant").unwrap().1;
    // SAFETY: SIGKILL to a child this test's session started.
    assert_eq!(unsafe { libc::kill(plant as i32, libc::SIGKILL) }, 0);
    let (mut hold_from, mut resumed_at, mut first_new_state) = (None, None, None);
    let mut events = Vec::new();
    for k in FAULT_TICK..FAULT_TICK + 200 {
        let out = s.step().unwrap();
        events.extend(out.events.iter().cloned());
        if let Some(ps) = out.get::<PlantState>(services::PLANT_STATE) {
            if ps.header.seq == 0 {
                first_new_state.get_or_insert(k);
            }
        }
        let m = out.get::<MotorCommand>(services::MOTOR_COMMAND).unwrap();
        if m.flags & MotorCommand::FLAG_FAULT != 0 {
            hold_from.get_or_insert(k);
        } else if hold_from.is_some() {
            resumed_at.get_or_insert(k);
        }
    }
    assert!(events.iter().any(|e| e.contains("`plant` restarted")), "{events:?}");
    let hold_from = hold_from.expect("held while the driver was away");
    let first_new = first_new_state.expect("the new plant reported");
    let resumed = resumed_at.expect("motion resumed");
    assert!(
        hold_from <= first_new + 1,
        "held by the first state of the new instance"
    );
    // States of ticks first_new .. first_new + 49 are read in the steps after them.
    assert_eq!(resumed, first_new + 50, "resumed after 50 good states, not before");
    let report = s.shutdown().unwrap();
    assert_eq!(report.outcome, Outcome::Recovered, "{}", report.format_summary());
    assert_eq!(report.outcome.exit_code(), 3);
    let act = report.status("actuator").unwrap();
    assert_eq!(act.last_fault, fault::STATE_GAP, "a restart is a gap: states were lost");
    assert!(
        report.faults.iter().any(|f| f.what.starts_with("running again")),
        "{:?}",
        report.faults
    );
    // The recording does not hide the restart: `replay --summary` counts it.
    let summary = bowden_runtime::replay::summarize(&log).unwrap();
    let ps = summary
        .services
        .iter()
        .find(|v| v.service == services::PLANT_STATE)
        .unwrap();
    assert_eq!(ps.publisher_restarts, 1, "{}", summary.to_markdown());
    assert_clean(&p);
}

#[test]
fn a_process_lost_for_good_halts_the_run_with_an_estop() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs6");
    let mut s = start(&control_chain(&p, "never"), dir.path());
    for _ in 0..100 {
        s.step().unwrap();
    }
    let plant = s.pids().into_iter().find(|(n, _)| n == "plant").unwrap().1;
    // SAFETY: SIGKILL to a child this test's session started.
    assert_eq!(unsafe { libc::kill(plant as i32, libc::SIGKILL) }, 0);
    let halted = (0..50).find_map(|_| match s.step() {
        Ok(_) => None,
        Err(SessionError::Halted { tick, reason }) => Some((tick, reason)),
        Err(e) => panic!("{e}"),
    });
    let (tick, reason) = halted.expect("the run halted");
    assert!(
        reason.contains("process plant") && reason.contains("lost for good"),
        "{reason}"
    );
    assert!(tick <= 101, "halted at tick {tick}");
    assert!(matches!(s.step(), Err(SessionError::Halted { .. })), "stays halted");
    let report = s.shutdown().unwrap();
    assert_eq!(report.outcome, Outcome::Unrecovered);
    assert!(report.halted.is_some());
    assert!(
        report.faults.iter().any(|f| f.what.contains("e-stop sent")),
        "{:?}",
        report.faults
    );
    assert_clean(&p);
}

/// `bowden run` exits with the outcome's code and lists the faults with their times.
#[test]
fn bowden_run_exits_non_zero_after_a_fault_and_zero_after_a_clean_run() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs7");
    let faulty = write_config(dir.path(), "faulty.toml", &faulty_chain(&p, "nan"));
    let out = bowden()
        .args(["run", faulty.to_str().unwrap(), "--ticks", "300", "--quiet"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(4),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("fault: t 0.201 s (tick 201): actuator: safe hold: robot state not finite"),
        "{text}"
    );
    assert!(text.contains("outcome: fault not recovered (exit code 4)"), "{text}");
    let clean = write_config(dir.path(), "clean.toml", &control_chain(&p, "never"));
    let out = bowden()
        .args(["run", clean.to_str().unwrap(), "--ticks", "100", "--quiet"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("outcome: clean (exit code 0)"));
    assert_clean(&p);
}

/// Security (#41 item 6): while a pipeline runs, every shared-memory file of its prefix is
/// private to the deploying user — including iceoryx2's management file, which it creates
/// with mode 0666 — and a prefix with a file of another user (a squatter) is refused before
/// anything opens it.
#[test]
fn shared_memory_is_private_and_a_squatted_prefix_is_refused() {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs8");
    let mut s = start(&control_chain(&p, "never"), dir.path());
    s.step().unwrap();
    let files = bowden_runtime::cleanup::prefix_files(&settings(&p));
    assert!(
        files.iter().any(|f| f.to_string_lossy().ends_with("global_mgmt")),
        "{files:?}"
    );
    for f in &files {
        let mode = std::fs::metadata(f).unwrap().mode() & 0o777;
        assert_eq!(mode & 0o077, 0, "{}: mode {mode:o}", f.display());
    }
    s.shutdown().unwrap();
    assert_clean(&p);

    // A file of the prefix that another user owns. Only root can make one here; as another
    // user, the check is the same code path, shown by the owner comparison.
    let shm = std::path::Path::new("/dev/shm").join(format!("{p}squatted_node.0_10_0.global_mgmt"));
    std::fs::write(&shm, b"").unwrap();
    std::fs::set_permissions(&shm, std::fs::Permissions::from_mode(0o666)).unwrap();
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    if root {
        let c = std::ffi::CString::new(shm.to_str().unwrap()).unwrap();
        // SAFETY: chown of a file this test created, to `nobody`.
        assert_eq!(unsafe { libc::chown(c.as_ptr(), 65534, 65534) }, 0);
        let path = write_config(dir.path(), "chain2.toml", &control_chain(&p, "never"));
        let cfg = PipelineConfig::load(&path, &Overrides::default(), REGISTRY).unwrap();
        let opts = SessionOptions::new(LaunchOptions::with_exe(bowden_exe()));
        let err = LockstepSession::start(&cfg, opts).err().expect("refused");
        let text = err.to_string();
        assert!(text.contains("owned by uid 65534") && text.contains(&p), "{text}");
        // `bowden estop` refuses it the same way, at once.
        let out = bowden()
            .args(["estop", "--prefix", &p, "--timeout-ms", "200"])
            .output()
            .unwrap();
        assert!(!out.status.success());
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("owned by uid 65534"),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    } else {
        // Our own file with mode 0666 is made private instead.
        assert_eq!(bowden_runtime::cleanup::secure_prefix_files(&settings(&p)).unwrap(), 1);
    }
    std::fs::remove_file(&shm).unwrap();
    assert_clean(&p);
}

fn signal(pid: u32, sig: i32) {
    // SAFETY: a signal to a child process this test's session started.
    assert_eq!(unsafe { libc::kill(pid as i32, sig) }, 0);
}

fn pid(s: &[(String, u32)], name: &str) -> u32 {
    s.iter().find(|(n, _)| n == name).map(|(_, p)| *p).unwrap()
}

/// Lockstep: a process that stops making progress (SIGSTOP: alive, silent) halts the run after
/// `stall_timeout_ms`, with the e-stop and a report, not an error without one.
#[test]
fn a_hung_process_halts_a_lockstep_run_within_the_stall_bound() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs9");
    let text = control_chain(&p, "never").replace("seed = 3\n", "seed = 3\nstall_timeout_ms = 300\n");
    // The config's bound, not the other tests' 20 s override.
    let mut s = start_with_stall(&text, dir.path(), None);
    for _ in 0..50 {
        s.step().unwrap();
    }
    let plant = pid(&s.pids(), "plant");
    signal(plant, libc::SIGSTOP);
    let err = s.step().expect_err("the tick cannot complete");
    signal(plant, libc::SIGCONT);
    match err {
        SessionError::Halted { tick, reason } => {
            assert_eq!(tick, 50);
            assert!(reason.contains("no progress") && reason.contains("plant"), "{reason}");
            // The bound that halted it is the config's 300 ms (what the reason reports waiting,
            // at most a few polls more), not a default of seconds.
            let waited_ms: u64 = reason
                .split("no progress for ")
                .nth(1)
                .and_then(|r| r.split(" ms").next())
                .and_then(|n| n.parse().ok())
                .unwrap_or_else(|| panic!("no wait in: {reason}"));
            assert!((300..5_000).contains(&waited_ms), "{reason}");
        }
        e => panic!("{e}"),
    }
    let report = s.shutdown().unwrap();
    assert_eq!(report.outcome, Outcome::Unrecovered);
    assert!(
        report
            .faults
            .iter()
            .any(|f| f.what.contains("(hung?)") && f.what.contains("e-stop sent")),
        "{:?}",
        report.faults
    );
    assert_clean(&p);
}

/// Real time: a stage that stops reporting (SIGSTOP) is found by the launcher within
/// `liveness_ms`; it latches the e-stop and halts the run. The actuator's own watchdog holds
/// even sooner (the compensator's commands stop).
#[test]
fn a_silent_stage_halts_a_realtime_run_with_an_estop() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs10");
    let text = control_chain(&p, "never").replace(
        "mode = \"lockstep\"\n",
        "mode = \"realtime\"\nstatus_period_ms = 50\nliveness_ms = 250\n",
    );
    let path = write_config(dir.path(), "rt.toml", &text);
    let cfg = PipelineConfig::load(&path, &Overrides::default(), REGISTRY).unwrap();
    let mut opts = SessionOptions::new(LaunchOptions::with_exe(bowden_exe()));
    opts.launch.quiet_children = true;
    let mut s = bowden_runtime::session::RealtimeSession::start(&cfg, opts).unwrap();
    s.run_for(Some(Duration::from_millis(500))).unwrap();
    let comp = pid(&s.pids(), "compensator");
    signal(comp, libc::SIGSTOP);
    // Returns when the launcher halts (the 20 s are a bound, not a wait).
    s.run_for(Some(Duration::from_secs(20))).unwrap();
    signal(comp, libc::SIGCONT);
    let report = s.shutdown().unwrap();
    let halted = report.halted.clone().expect("halted");
    assert!(
        halted.contains("stage compensator") && halted.contains("no status for"),
        "{halted}"
    );
    assert!(
        report.faults.iter().any(|f| f.what.starts_with("e-stop confirmed")),
        "{:?}",
        report.faults
    );
    assert_eq!(report.outcome, Outcome::Unrecovered);
    assert_clean(&p);
}

/// `bowden bench faults` runs the real-time fault table end to end: each fault is detected by
/// the right detector and every run exits with the unrecovered code. (The figures are in
/// docs/results/faults; nothing here is timed.)
#[test]
fn bench_faults_detects_every_injected_fault() {
    let out = bowden()
        .args([
            "bench",
            "faults",
            "--runs",
            "1",
            "--cases",
            "nan,hung,lost",
            "--fault-at-s",
            "0.5",
            "--after-s",
            "0.5",
            "--json",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}\n{}", String::from_utf8_lossy(&out.stderr));
    let rows: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 3);
    for r in rows {
        let run = &r["runs"][0];
        let by = run["detected_by"]
            .as_str()
            .unwrap_or_else(|| panic!("not detected: {r}"));
        let want = if r["case"] == "lost" { "launcher" } else { "actuator" };
        assert!(by.starts_with(want), "{r}");
        assert!(run["detection_ms"].as_f64().unwrap() >= -2.0, "{r}");
        assert_eq!(run["exit_code"], 4, "{r}");
    }
    assert!(
        rows[2]["runs"][0]["reaction_ms"].as_f64().is_some(),
        "the e-stop was confirmed"
    );
}

/// The management-file attack of #41 as another user (needs root here, to act as `nobody`;
/// elsewhere it says so and passes): emptying the prefix's iceoryx2 files fails, and
/// `bowden estop` still latches and is confirmed.
#[test]
fn another_user_cannot_empty_the_pipeline_files_and_the_estop_still_works() {
    use std::os::unix::process::CommandExt;
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("another_user_cannot_empty_…: not root, cannot act as another user here");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("fs11");
    let text = control_chain(&p, "never").replace("mode = \"lockstep\"\n", "mode = \"realtime\"\n");
    let path = write_config(dir.path(), "rt.toml", &text);
    let cfg = PipelineConfig::load(&path, &Overrides::default(), REGISTRY).unwrap();
    let mut opts = SessionOptions::new(LaunchOptions::with_exe(bowden_exe()));
    opts.launch.quiet_children = true;
    let mut s = bowden_runtime::session::RealtimeSession::start(&cfg, opts).unwrap();
    s.run_for(Some(Duration::from_millis(300))).unwrap();
    let files = bowden_runtime::cleanup::prefix_files(&settings(&p));
    let mgmt = files
        .iter()
        .find(|f| f.to_string_lossy().ends_with("global_mgmt"))
        .expect("the management file");
    {
        let f = mgmt;
        let attack = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!(": > '{}'", f.display()))
            .uid(65534)
            .gid(65534)
            .output()
            .unwrap();
        assert!(
            !attack.status.success(),
            "another user emptied {}: {}",
            f.display(),
            String::from_utf8_lossy(&attack.stderr)
        );
    }
    let t0 = std::time::Instant::now();
    let out = bowden()
        .args(["estop", "--prefix", &p, "--timeout-ms", "2000"])
        .output()
        .unwrap();
    let took = t0.elapsed();
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("confirmed by `actuator`"));
    eprintln!(
        "estop after the attack: confirmed in {:.0} ms (process start included)",
        took.as_secs_f64() * 1e3
    );
    s.run_for(Some(Duration::from_millis(50))).unwrap();
    let report = s.shutdown().unwrap();
    assert_eq!(report.outcome, Outcome::EStop, "{}", report.format_summary());
    assert_clean(&p);
}
