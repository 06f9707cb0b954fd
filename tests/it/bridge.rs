//! Two machines on one: the shipped split configs run as two `bowden run`s with different
//! iceoryx2 prefixes, joined only by their Zenoh bridges on loopback. The camera and the
//! estimator run on the "vision PC" side, fed with the plant state from the "control PC" side,
//! and their joint estimates come back to the control side, headers intact.

use crate::runtime_support;

use bowden_interfaces::{JointEstimate, PlantState};
use bowden_runtime::record::LogReader;
use runtime_support::*;
use std::collections::BTreeMap;
use std::process::Stdio;

fn shipped(name: &str, port: u16) -> String {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("configs")
        .join(name);
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains(":7447\"]"), "{name} names port 7447");
    text.replace("tcp/0.0.0.0:7447", &format!("tcp/127.0.0.1:{port}"))
        .replace("tcp/127.0.0.1:7447", &format!("tcp/127.0.0.1:{port}"))
}

#[test]
fn the_sim_loop_runs_across_two_pipelines_joined_by_the_bridge() {
    let (pv, _gv) = guarded_prefix("brV");
    let (pc, _gc) = guarded_prefix("brC");
    let dir = tempfile::tempdir().unwrap();
    let port = bowden_bridge::free_loopback_port().unwrap();
    let vision = write_config(dir.path(), "split-vision.toml", &shipped("split-vision.toml", port));
    let control = write_config(dir.path(), "split-control.toml", &shipped("split-control.toml", port));
    let log = dir.path().join("control.blog");

    // The vision side outlives the control side: it must see its peer go and still end on time.
    let vision_run = bowden()
        .args(["run", vision.to_str().unwrap(), "--prefix", &pv, "--seconds", "7"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let control_out = bowden()
        .args(["run", control.to_str().unwrap(), "--prefix", &pc, "--seconds", "5"])
        .args(["--record", log.to_str().unwrap()])
        .output()
        .unwrap();
    let vision_out = vision_run.wait_with_output().unwrap();
    let (cerr, verr) = (
        String::from_utf8_lossy(&control_out.stderr).to_string(),
        String::from_utf8_lossy(&vision_out.stderr).to_string(),
    );
    assert!(control_out.status.success(), "control side failed:\n{cerr}");
    // The vision side outlives the control side by 2 s: it loses its peer and with it the
    // robot's state, and its outcome says so (exit code 4, the faults listed) rather than pass
    // for a clean run.
    let vout = String::from_utf8_lossy(&vision_out.stdout).to_string();
    assert_eq!(vision_out.status.code(), Some(4), "vision side:\n{vout}\n{verr}");
    assert!(
        vout.contains("fault: ") && vout.contains("outcome: fault not recovered"),
        "{vout}"
    );
    assert!(cerr.contains("bridge: peer") && cerr.contains("connected"), "{cerr}");
    assert!(
        verr.contains("bridge: fault: peer") && verr.contains("lost"),
        "the vision side reported its lost peer:\n{verr}"
    );

    // The control side recorded the plant's truth and the estimates that came back.
    let mut r = LogReader::open(&log).unwrap();
    let mut buf = Vec::new();
    let mut truth: BTreeMap<u64, [f64; 5]> = BTreeMap::new();
    let mut estimates = Vec::new();
    for i in 0..r.entries.len() {
        if let Some(s) = r.sample::<PlantState>(i, &mut buf).unwrap() {
            truth.insert(s.header.tick, core::array::from_fn(|j| s.q_phy_deg[j]));
        } else if let Some(e) = r.sample::<JointEstimate>(i, &mut buf).unwrap() {
            estimates.push(e);
        }
    }
    assert!(truth.len() > 1000, "{} plant states recorded", truth.len());
    assert!(
        estimates.len() >= 15,
        "{} estimates came back over the bridge (30 fps for ~4 s)\n{cerr}\n{verr}",
        estimates.len()
    );
    // Each estimate carries the tick of the plant state the camera rendered (the header crossed
    // the bridge twice unchanged) and agrees with it.
    let mut errs = Vec::new();
    for e in &estimates {
        assert_eq!(e.n_joints, 5);
        let q = truth
            .get(&e.header.tick)
            .unwrap_or_else(|| panic!("estimate of tick {} has no plant state of that tick", e.header.tick));
        if e.joint_valid_mask == 0b11111 {
            errs.push((0..5).map(|j| (e.q_phy_deg[j] - q[j]).abs()).sum::<f64>() / 5.0);
        }
    }
    assert!(
        errs.len() * 2 >= estimates.len(),
        "{} of {} estimates valid",
        errs.len(),
        estimates.len()
    );
    errs.sort_by(f64::total_cmp);
    let median = errs[errs.len() / 2];
    assert!(median < 2.0, "median joint error of the remote estimates {median:.2}°");
    assert_clean(&pv);
    assert_clean(&pc);
}

#[test]
fn a_bridge_in_lockstep_is_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let text = shipped("split-vision.toml", 7447).replace("mode = \"realtime\"", "mode = \"lockstep\"");
    let cfg = write_config(dir.path(), "v.toml", &text);
    let (p, _g) = guarded_prefix("brL");
    let out = bowden()
        .args(["run", cfg.to_str().unwrap(), "--prefix", &p, "--ticks", "10"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("node[2] (bridge).kind") && err.contains("lockstep cannot span it"),
        "{err}"
    );
    assert_clean(&p);
}

#[test]
fn bench_bridge_measures_every_stream_and_frames_arrive_intact() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bridge.json");
    run_ok(&[
        "bench",
        "bridge",
        "--samples",
        "60",
        "--rate-hz",
        "500",
        "--frames",
        "6",
        "--ipc-samples",
        "100",
        "--json-out",
        json.to_str().unwrap(),
    ]);
    let rows: Vec<serde_json::Value> = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let paths: Vec<&str> = rows.iter().map(|r| r["path"].as_str().unwrap()).collect();
    assert_eq!(rows.len(), 9, "{paths:?}");
    // The export in the producer's process: the importing bridge alone delivers, to a consumer
    // woken by the event and to one polling its subscriber.
    for p in [
        "bridge, import side only: export",
        "bridge, import side only, read by polling",
    ] {
        assert!(paths.iter().any(|x| x.starts_with(p)), "{p}: {paths:?}");
    }
    // The machine's own hop under the network rows: TCP loses nothing.
    let tcp = rows
        .iter()
        .find(|r| r["path"].as_str().unwrap().starts_with("plain TCP"))
        .unwrap();
    assert_eq!(tcp["delivered"].as_u64(), Some(60), "{tcp}");
    for r in &rows {
        let (sent, delivered) = (r["sent"].as_u64().unwrap(), r["delivered"].as_u64().unwrap());
        assert_eq!(r["corrupt"].as_u64().unwrap(), 0, "{r}");
        // Zenoh drops rather than blocks when its queue is full: a loaded machine may lose a
        // few, but most arrive, and every one that arrives is measured.
        assert!(delivered * 2 >= sent && delivered <= sent, "{r}");
        assert_eq!(r["one_way"]["count"].as_u64().unwrap(), delivered, "{r}");
        assert!(r["one_way"]["p50_ns"].as_u64().unwrap() > 0, "{r}");
    }
    let frames = rows
        .iter()
        .find(|r| {
            r["stream"].as_str().unwrap().starts_with("RGBD") && r["path"].as_str().unwrap().starts_with("bridge")
        })
        .unwrap();
    assert!(frames["p50_first_quarter_ns"].as_u64().is_some(), "{frames}");
    assert!(std::fs::read_dir("/dev/shm").unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .starts_with("bwbr")));
}

/// The names of a process's threads (Zenoh names its runtime threads `<runtime>-<n>`).
fn thread_names(pid: u32) -> Vec<String> {
    let Ok(dir) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return Vec::new();
    };
    dir.filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
        .map(|s| s.trim().to_string())
        .collect()
}

/// The Zenoh runtime threads of a `bowden bench bridge-peer` started with `zenoh_runtime` as
/// its ZENOH_RUNTIME (None: unset), once its session is open (it then waits for a peer that
/// never comes, and is killed).
fn zenoh_threads_of_a_bridge_process(zenoh_runtime: Option<&str>) -> Vec<String> {
    let port = bowden_bridge::free_loopback_port().unwrap();
    let mut cmd = bowden();
    cmd.args(["bench", "bridge-peer", "--connect"])
        .arg(format!("tcp/127.0.0.1:{port}"))
        .args(["--count", "1", "--low-latency", "true"])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    match zenoh_runtime {
        Some(v) => cmd.env("ZENOH_RUNTIME", v),
        None => cmd.env_remove("ZENOH_RUNTIME"),
    };
    let mut child = cmd.spawn().unwrap();
    let is_zenoh = |n: &String| ["app-", "acc-", "tx-", "rx-", "net-"].iter().any(|p| n.starts_with(p));
    let t0 = std::time::Instant::now();
    let mut names = Vec::new();
    // The session is open once Zenoh's threads exist; give the rest of start-up a moment.
    while t0.elapsed() < std::time::Duration::from_secs(15) {
        names = thread_names(child.id());
        if names.iter().any(is_zenoh) {
            std::thread::sleep(std::time::Duration::from_millis(300));
            names = thread_names(child.id());
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let _ = child.kill();
    let _ = child.wait();
    let mut z: Vec<String> = names.into_iter().filter(is_zenoh).collect();
    z.sort();
    z
}

#[test]
fn bowden_runs_zenoh_on_one_runtime_unless_the_user_says_otherwise() {
    // Unset: every Zenoh runtime handed over to one single-worker runtime (one reactor, so a
    // socket's reader is woken once, not twice).
    let ours = zenoh_threads_of_a_bridge_process(None);
    assert!(!ours.is_empty(), "no Zenoh threads seen");
    assert!(
        ours.iter().all(|n| n.starts_with("app-")),
        "bowden's layout runs everything on the app runtime: {ours:?}"
    );
    // The user's setting wins: Zenoh's own default ("()") starts runtimes of its own beside
    // app (net at once; rx, tx once a link is up).
    let theirs = zenoh_threads_of_a_bridge_process(Some("()"));
    assert!(
        theirs.iter().any(|n| !n.starts_with("app-")),
        "Zenoh's default layout has threads of other runtimes: {theirs:?}"
    );
}

#[test]
fn an_invalid_zenoh_runtime_is_an_error_naming_it_not_a_crash() {
    // Zenoh panics when it parses a ZENOH_RUNTIME it cannot read; the bridge stage turns that
    // into its build error, naming the variable and its value.
    let (p, _g) = guarded_prefix("brZ");
    let dir = tempfile::tempdir().unwrap();
    let port = bowden_bridge::free_loopback_port().unwrap();
    let cfg = write_config(
        dir.path(),
        "bridge.toml",
        &format!(
            "[runtime]\nmode = \"realtime\"\nperiod_us = 1000\n\n[[node]]\nname = \"bridge\"\n\
             [node.params]\nlisten = [\"tcp/127.0.0.1:{port}\"]\nexport = [\"bowden/joint_estimate\"]\n"
        ),
    );
    let out = bowden()
        .args(["run", cfg.to_str().unwrap(), "--prefix", &p, "--seconds", "1"])
        .env("ZENOH_RUNTIME", "not ron")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("is ZENOH_RUNTIME valid?") && err.contains("`not ron`"),
        "{err}"
    );
}
