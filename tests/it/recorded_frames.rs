//! The vision loop on recorded frames (`[node.params] source = "recorded"` of the camera): a
//! lockstep run of configs/sim.toml records what its synthetic camera sends
//! (`record_to`); the same pipeline with the camera playing that directory back gives the
//! estimator the same frames, so every joint estimate is the same, bit for bit, and the
//! estimator's accuracy on recorded frames is the live one. A bad recording is refused on load,
//! naming the parameter and the file.

use crate::runtime_support::*;
use bowden_interfaces::{services, JointEstimate, PlantState};
use std::path::{Path, PathBuf};

const TICKS: u64 = 160;

/// configs/sim.toml at 10 ms ticks with the camera's parameters set.
fn pipeline(dir: &Path, name: &str, camera: &[(&str, toml::Value)]) -> PathBuf {
    let mut set = vec![("camera", "fps", toml::Value::Float(50.0))];
    for (k, v) in camera {
        set.push(("camera", k, v.clone()));
    }
    let out = dir.join(format!("{name}.toml"));
    bowden_evaluation::pipeline_variant(&sim_toml(), &set, &out).unwrap();
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    t["runtime"]
        .as_table_mut()
        .unwrap()
        .insert("period_us".into(), toml::Value::Integer(10_000));
    std::fs::write(&out, toml::to_string(&t).unwrap()).unwrap();
    out
}

/// Every tick's joint estimate (None where no frame was taken) and the truth of that tick.
fn run(file: &Path, tag: &str) -> Vec<(Option<JointEstimate>, PlantState)> {
    let (mut s, _guard) = lockstep_session(file, tag, &[services::JOINT_ESTIMATE, services::PLANT_STATE]);
    let mut v = Vec::new();
    for _ in 0..TICKS {
        let out = s.step().unwrap();
        assert!(out.events.is_empty(), "{:?}", out.events);
        v.push((
            out.get::<JointEstimate>(services::JOINT_ESTIMATE),
            out.get::<PlantState>(services::PLANT_STATE)
                .expect("a plant state every tick"),
        ));
    }
    s.shutdown().unwrap();
    v
}

fn rmse_deg(v: &[(Option<JointEstimate>, PlantState)]) -> (usize, f64) {
    let (mut n, mut se) = (0usize, 0.0);
    for (e, p) in v {
        if let Some(e) = e.filter(|e| e.quality == JointEstimate::QUALITY_VALID) {
            for j in 0..5 {
                se += (e.q_phy_deg[j] - p.q_phy_deg[j]).powi(2);
            }
            n += 1;
        }
    }
    (n, (se / (5 * n.max(1)) as f64).sqrt())
}

#[test]
fn the_vision_loop_on_recorded_frames_equals_the_live_one() {
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("frames");
    let live = run(
        &pipeline(
            dir.path(),
            "live",
            &[("record_to", toml::Value::String(frames.display().to_string()))],
        ),
        "rfl",
    );
    let index = std::fs::read_to_string(frames.join("index.json")).expect("the camera wrote its recording");
    assert!(index.contains("bowden-rgbd/1"), "{index}");
    let replayed = run(
        &pipeline(
            dir.path(),
            "replay",
            &[
                ("source", toml::Value::String("recorded".into())),
                ("frames", toml::Value::String(frames.display().to_string())),
            ],
        ),
        "rfr",
    );
    let (n_live, rmse_live) = rmse_deg(&live);
    let (n_rec, rmse_rec) = rmse_deg(&replayed);
    assert!(n_live >= 60, "{n_live} valid estimates live");
    assert!(rmse_live < 2.0, "live RMSE {rmse_live} deg");
    assert_eq!((n_rec, rmse_rec), (n_live, rmse_live), "accuracy on recorded frames");
    for (k, ((a, _), (b, _))) in live.iter().zip(&replayed).enumerate() {
        assert_eq!(a, b, "tick {k}: estimate from the recorded frame differs");
    }
}

#[test]
fn a_bad_recording_is_refused_naming_the_parameter_and_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nowhere");
    let file = pipeline(
        dir.path(),
        "bad",
        &[
            ("source", toml::Value::String("recorded".into())),
            ("frames", toml::Value::String(missing.display().to_string())),
        ],
    );
    // A standalone node creates iceoryx2's per-prefix management file: the guard removes it.
    let (p1, _g1) = guarded_prefix("rfb");
    let out = bowden()
        .args(["node", "camera", "--config"])
        .arg(&file)
        .args(["--mode", "lockstep", "--prefix", &p1])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("camera") && err.contains("nowhere") && err.contains("index.json"),
        "{err}"
    );
    let file = pipeline(
        dir.path(),
        "nodir",
        &[("source", toml::Value::String("recorded".into()))],
    );
    let (p2, _g2) = guarded_prefix("rfc");
    let out = bowden()
        .args(["node", "camera", "--config"])
        .arg(&file)
        .args(["--mode", "lockstep", "--prefix", &p2])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("params.frames"), "{err}");
}
