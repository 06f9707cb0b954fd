//! Two machines on one: the shipped split configs run as two `bowden run`s with different
//! iceoryx2 prefixes, joined only by their Zenoh bridges on loopback. The camera and the
//! estimator run on the "vision PC" side, fed with the plant state from the "control PC" side,
//! and their joint estimates come back to the control side, headers intact.

mod runtime_support;

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
    assert!(vision_out.status.success(), "vision side failed:\n{verr}");
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
        err.contains("node[0] (bridge).kind") && err.contains("lockstep cannot span it"),
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
    assert_eq!(rows.len(), 7, "{paths:?}");
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
