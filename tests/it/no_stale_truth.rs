//! No stale truth (#41, item 2): when the simulated robot starts reporting NaN, impossible
//! angles, or nothing at all (fault injection of the plant node, `[node.params] fault`), the
//! camera stops rendering its last good pose, so no joint estimate after the fault is marked
//! valid: a frozen robot is never measured as healthy. Lockstep, configs/sim.toml at 10 ms
//! ticks, the camera at 50 fps.

use crate::runtime_support::*;
use bowden_interfaces::{services, JointEstimate};
use std::path::Path;

const FAULT_AT_S: f64 = 1.0;

/// Valid estimates before the fault, and after `FAULT_AT_S + grace_s` (by frame time).
fn run(dir: &Path, kind: &str, tag: &str) -> (usize, usize, Vec<String>) {
    let mut fault = toml::Table::new();
    fault.insert("kind".into(), toml::Value::String(kind.into()));
    fault.insert("after_s".into(), toml::Value::Float(FAULT_AT_S));
    let file = dir.join(format!("{kind}.toml"));
    bowden_evaluation::pipeline_variant(
        &sim_toml(),
        &[
            ("camera", "fps", toml::Value::Float(50.0)),
            ("plant", "fault", toml::Value::Table(fault)),
        ],
        &file,
    )
    .unwrap();
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    t["runtime"]
        .as_table_mut()
        .unwrap()
        .insert("period_us".into(), toml::Value::Integer(10_000));
    std::fs::write(&file, toml::to_string(&t).unwrap()).unwrap();
    let (mut s, _guard) = lockstep_session(&file, tag, &[services::JOINT_ESTIMATE]);
    // The camera may still send frames of states taken before the fault for up to its
    // max_state_age_ms (100 ms by default): a frame's time is when it was exposed.
    let grace_ns = ((FAULT_AT_S + 0.1) * 1e9) as u64 + 10_000_000;
    let (mut before, mut after) = (0, 0);
    for _ in 0..250 {
        let out = s.step().unwrap();
        assert!(out.events.is_empty(), "{:?}", out.events);
        if let Some(e) = out.get::<JointEstimate>(services::JOINT_ESTIMATE) {
            if e.quality == JointEstimate::QUALITY_VALID {
                if e.header.t_origin_ns < (FAULT_AT_S * 1e9) as u64 {
                    before += 1;
                } else if e.header.t_origin_ns > grace_ns {
                    after += 1;
                }
            }
        }
    }
    let report = s.shutdown().unwrap();
    let summary = report.format_summary().lines().map(str::to_string).collect();
    (before, after, summary)
}

#[test]
fn a_faulty_robot_is_never_measured_as_healthy() {
    let dir = tempfile::tempdir().unwrap();
    for (kind, tag) in [("nan", "nst1"), ("out-of-range", "nst2"), ("silent", "nst3")] {
        let (before, after, summary) = run(dir.path(), kind, tag);
        assert!(before >= 40, "{kind}: {before} valid estimates before the fault");
        assert_eq!(
            after, 0,
            "{kind}: valid estimates of a robot that stopped reporting its state"
        );
        let camera = summary
            .iter()
            .find(|l| l.starts_with("| camera |"))
            .cloned()
            .unwrap_or_else(|| panic!("{kind}: no camera row in {summary:?}"));
        // | camera | state | cycles | misses | rejected | faults | ...
        let cols: Vec<&str> = camera.split('|').map(str::trim).collect();
        let (rejected, faults): (u64, u64) = (cols[5].parse().unwrap(), cols[6].parse().unwrap());
        match kind {
            "silent" => assert!(faults > 0, "{kind}: skipped frames counted as faults: {camera}"),
            _ => assert!(rejected > 0, "{kind}: rejected states counted: {camera}"),
        }
    }
}
