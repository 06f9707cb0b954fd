//! The whole simulated pipeline as independent processes over iceoryx2: a 2,000-tick lockstep
//! run of configs/sim.toml (trajectory, compensator, actuator, plant, camera, estimator,
//! recorder), twice, with byte-identical logs; and replay of a log onto live services.

use crate::runtime_support;

use bowden_interfaces::{services, JointCommand};
use bowden_runtime::ports::{Message, PortContext};
use bowden_runtime::record::LogReader;
use bowden_runtime::replay::summarize;
use runtime_support::*;

#[test]
fn lockstep_sim_pipeline_2000_ticks_is_reproducible() {
    let dir = tempfile::tempdir().unwrap();
    let sim = sim_toml();
    let mut logs = Vec::new();
    for tag in ["a", "b"] {
        let (p, _guard_p) = guarded_prefix(&format!("pipe{tag}"));
        let log = dir.path().join(format!("{tag}.blog"));
        let out = run_ok(&[
            "run",
            sim.to_str().unwrap(),
            "--mode",
            "lockstep",
            "--ticks",
            "2000",
            "--prefix",
            &p,
            "--record",
            log.to_str().unwrap(),
            "--quiet",
        ]);
        let stdout = String::from_utf8_lossy(&out.stdout);
        for stage in [
            "trajectory",
            "compensator",
            "actuator",
            "plant",
            "camera",
            "estimator",
            "recorder",
        ] {
            assert!(
                stdout.contains(&format!("| {stage} | stopped | 2000 | 0 | 0 | 0 |")),
                "stage {stage} did not handle 2000 ticks cleanly:\n{stdout}"
            );
        }
        assert_clean(&p);
        logs.push(log);
    }

    // What the run did, from its log.
    let s = summarize(&logs[0]).unwrap();
    let count = |svc: &str| {
        s.services
            .iter()
            .find(|v| v.service == svc)
            .map(|v| (v.records, v.seq_gaps, v.last_tick))
    };
    for svc in [
        services::JOINT_TARGET,
        services::JOINT_COMMAND,
        services::MOTOR_COMMAND,
        services::PLANT_STATE,
    ] {
        assert_eq!(count(svc), Some((2000, 0, Some(1999))), "{svc}");
    }
    // 2 s of simulated time at 30 frames per second.
    let (frames, gaps, _) = count(services::JOINT_ESTIMATE).unwrap();
    assert!((60..=61).contains(&frames) && gaps == 0, "{frames} estimates");
    assert_eq!(count(services::MARKER_SET).unwrap().0, frames);
    assert!(
        s.estimate_valid_fraction.unwrap() > 0.9,
        "{:?}",
        s.estimate_valid_fraction
    );
    // The plant's hysteresis is there: the true angles lag the commands.
    assert!(
        s.plant_mean_abs_error_deg.iter().any(|&e| e > 1.0),
        "{:?}",
        s.plant_mean_abs_error_deg
    );
    // Every sample of tick k was produced for tick k (lockstep dataflow), in stage order.
    let r = LogReader::open(&logs[0]).unwrap();
    assert!(!r.rebuilt_index);
    let first_ticks: Vec<u64> = r.entries.iter().take(4).map(|e| e.tick).collect();
    assert_eq!(first_ticks, vec![0, 0, 0, 0]);

    // The same run twice: the same bytes.
    let a = std::fs::read(&logs[0]).unwrap();
    let b = std::fs::read(&logs[1]).unwrap();
    assert!(a.len() > 500_000, "log of {} bytes", a.len());
    assert!(a == b, "the two lockstep runs recorded different logs");
    let ia = std::fs::read(bowden_runtime::record::index_path(&logs[0])).unwrap();
    let ib = std::fs::read(bowden_runtime::record::index_path(&logs[1])).unwrap();
    assert!(ia == ib, "the two indexes differ");
}

#[test]
fn replay_republishes_the_recorded_samples() {
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard_p) = guarded_prefix("rec");
    let cfg = write_config(dir.path(), "chain.toml", &(control_chain(&p, "never")
        + "\n[[node]]\nname = \"recorder\"\n[node.params]\npath = \"unused\"\nservices = [\"bowden/joint_command\", \"bowden/plant_state\"]\n"));
    let log = dir.path().join("chain.blog");
    run_ok(&[
        "run",
        cfg.to_str().unwrap(),
        "--ticks",
        "300",
        "--record",
        log.to_str().unwrap(),
        "--quiet",
    ]);
    assert_clean(&p);

    let mut reader = LogReader::open(&log).unwrap();
    let mut buf = Vec::new();
    let recorded: Vec<JointCommand> = (0..reader.entries.len())
        .filter_map(|i| reader.sample::<JointCommand>(i, &mut buf).unwrap())
        .collect();
    assert_eq!(recorded.len(), 300);

    // Listen on a fresh prefix, replay the commands onto it at the recorded pace (1 ms apart):
    // the service's queue holds 64 samples, so the listener may be descheduled for 64 ms on a
    // loaded machine without losing one (at 10x it lost some under CI-like load).
    let (q, _guard_q) = guarded_prefix("rep");
    let received = {
        let ctx = PortContext::new("listener", &settings(&q)).unwrap();
        let mut input = ctx.input::<JointCommand>(services::JOINT_COMMAND, 64).unwrap();
        let mut child = bowden()
            .args([
                "replay",
                log.to_str().unwrap(),
                "--prefix",
                &q,
                "--services",
                services::JOINT_COMMAND,
                "--speed",
                "1",
            ])
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let mut got = Vec::new();
        loop {
            while let Some(c) = input.recv() {
                got.push(c);
            }
            if let Some(status) = child.try_wait().unwrap() {
                assert!(status.success(), "replay failed: {status}");
                while let Some(c) = input.recv() {
                    got.push(c);
                }
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let out = child.wait_with_output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.contains("replayed 300 samples"), "{text}");
        assert!(text.contains("| bowden/joint_command | 300 | 0..299 | 0 |"), "{text}");
        got
    };
    assert_eq!(received.len(), 300, "every recorded command arrives");
    for (a, b) in received.iter().zip(&recorded) {
        assert_eq!(
            a.as_bytes(),
            b.as_bytes(),
            "replayed samples keep their recorded bytes and headers"
        );
    }
    bowden_runtime::cleanup::remove_stale_nodes(&settings(&q)).unwrap();
    bowden_runtime::cleanup::remove_prefix_files(&settings(&q)).unwrap();
    assert_clean(&q);
}

#[test]
fn an_external_executable_replaces_a_node() {
    // The hardware-in-the-loop swap: the plant becomes an external process (here a shell that
    // checks the environment the launcher gives it, then runs bowden's own plant node from a
    // config of its own), started, supervised and stepped in lockstep like a built-in node.
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard_p) = guarded_prefix("hil");
    let plain = write_config(dir.path(), "plain.toml", &control_chain(&p, "never"));
    let script = format!(
        "test \"$BOWDEN_PREFIX\" = {p} && test \"$BOWDEN_MODE\" = lockstep && test \"$BOWDEN_NODE\" = plant && \
         exec {} node plant --config {} --quiet",
        bowden_exe(),
        plain.display()
    );
    let hil = control_chain(&p, "never").replace(
        "name = \"plant\"\n",
        &format!("name = \"plant\"\nexec = [\"/bin/sh\", \"-c\", {script:?}]\nreports_status = true\n"),
    );
    let cfg = write_config(dir.path(), "hil.toml", &hil);
    let out = run_ok(&["run", cfg.to_str().unwrap(), "--ticks", "300", "--quiet"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("plant [plant] external `/bin/sh -c"), "{err}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("| plant | stopped | 300 | 0 | 0 | 0 |"), "{stdout}");
    assert!(stdout.contains("| actuator | stopped | 300 | 0 | 0 | 0 |"), "{stdout}");
    assert_clean(&p);
}
