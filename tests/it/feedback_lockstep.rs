//! The vision feedback through the real multi-process lockstep pipeline (configs/evaluate.toml:
//! compensator → actuator → plant → camera → estimator, with the estimator's `JointEstimate`
//! read back by the compensator), on the simulated default robot with its synthetic camera's
//! noise, ticks of 10 ms and the camera at 30 fps, points held 0.5 s as in `bowden evaluate`:
//!
//! - feedback (configs/controller-feedback-realtime.toml: the TCN pair, newton) tracks better
//!   than the same feed-forward without it, by truth, with a bounded error, and a run is the
//!   same bit for bit when repeated;
//! - with the markers lost (the estimator cannot see the blue base sphere, so every estimate is
//!   invalid) the commands are the feed-forward's, bit for bit, and the compensator's status
//!   counts the rejected estimates and the fallback.

use crate::runtime_support;
use bowden::registry::REGISTRY;

use bowden_interfaces::{services, JointCommand, JointTarget, PlantState};
use bowden_kinematics::{JointsDeg, Robot};
use bowden_runtime::config::{Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::session::{LockstepSession, SessionOptions};
use runtime_support::*;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// configs/evaluate.toml with 10 ms ticks, the camera at 30 fps, the compensator's config and
/// mode, and optionally the estimator's markers file.
fn pipeline(dir: &Path, name: &str, controller: &str, markers: Option<&Path>) -> PathBuf {
    let mut set = vec![
        ("compensator", "mode", toml::Value::String("newton".into())),
        (
            "compensator",
            "config",
            toml::Value::String(root().join(controller).display().to_string()),
        ),
        ("camera", "fps", toml::Value::Float(30.0)),
        // evaluate's per-tick rate limit at 100 ms ticks, per second at 10 ms ones.
        ("actuator", "max_rate_deg_s", toml::Value::Float(4000.0)),
    ];
    if let Some(m) = markers {
        set.push(("estimator", "markers", toml::Value::String(m.display().to_string())));
    }
    let out = dir.join(format!("{name}.toml"));
    bowden_evaluation::pipeline_variant(&root().join("configs/evaluate.toml"), &set, &out).unwrap();
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    t["runtime"]
        .as_table_mut()
        .unwrap()
        .insert("period_us".into(), toml::Value::Integer(10_000));
    std::fs::write(&out, toml::to_string(&t).unwrap()).unwrap();
    out
}

/// A controller config in `dir`: `src` with absolute model paths, the rate limit at evaluate's
/// per-tick value, and `[feedback]` as given (or removed).
fn controller(dir: &Path, src: &str, feedback: Option<bool>) -> PathBuf {
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(root().join(src)).unwrap()).unwrap();
    for key in ["model_fwd", "model_inv"] {
        if let Some(toml::Value::String(m)) = t.get_mut(key) {
            *m = root().join(m.as_str()).display().to_string();
        }
    }
    t["output"]
        .as_table_mut()
        .unwrap()
        .insert("rate_limit_deg_s".into(), toml::Value::Float(3600.0));
    match feedback {
        None => {
            t.remove("feedback");
        }
        Some(on) => {
            t["feedback"]
                .as_table_mut()
                .unwrap()
                .insert("enabled".into(), toml::Value::Boolean(on));
        }
    }
    let name = format!("controller-{}.toml", if feedback.is_some() { "fb" } else { "ff" });
    let p = dir.join(name);
    std::fs::write(&p, toml::to_string(&t).unwrap()).unwrap();
    p
}

struct Run {
    commands: Vec<JointCommand>,
    /// Truth at the last tick of each point.
    end_errors: Vec<f64>,
    /// Largest |q_desired − q_true| of any joint at any tick after the first point.
    max_error: f64,
    rejected: u64,
    faults: u64,
}

/// Home → a few points of the tuning circle, each held 0.5 s (50 ticks).
fn points() -> Vec<JointsDeg> {
    let robot = Robot::paper_default();
    let f = root().join("configs/trajectories/tuning/circle.toml");
    let spec = bowden_trajectory::task_space::TrajectorySpec::load(&f).unwrap();
    let path = spec.to_joint_space(&robot, &f).unwrap().q_deg;
    let mut v = bowden_trajectory::interpolate_eq16(&[[0.0; 5], path[0]]);
    v.extend_from_slice(&path[1..10]);
    v
}

fn run(pipeline_file: &Path, tag: &str) -> Run {
    let (prefix, _guard) = guarded_prefix(tag);
    let ov = Overrides {
        prefix: Some(prefix),
        seed: Some(1000),
        ..Default::default()
    };
    let cfg = PipelineConfig::load(pipeline_file, &ov, REGISTRY).unwrap();
    let mut opts = SessionOptions::new(LaunchOptions {
        quiet_children: true,
        ..LaunchOptions::with_exe(bowden_exe())
    });
    opts.taps = vec![services::JOINT_COMMAND.into(), services::PLANT_STATE.into()];
    opts.source = Some(services::JOINT_TARGET.into());
    let mut s = LockstepSession::start(&cfg, opts).unwrap();
    let pts = points();
    let (mut commands, mut end_errors, mut max_error) = (Vec::new(), Vec::new(), 0.0f64);
    s.step_with(JointTarget::from_deg(&[0.0; 5])).unwrap();
    for (i, q) in pts.iter().enumerate() {
        for t in 0..50 {
            let out = s.step_with(JointTarget::from_deg(q)).unwrap();
            assert!(out.events.is_empty(), "{:?}", out.events);
            commands.push(
                out.get::<JointCommand>(services::JOINT_COMMAND)
                    .expect("a command every tick"),
            );
            let truth = out
                .get::<PlantState>(services::PLANT_STATE)
                .expect("a plant state every tick")
                .q_phy_deg;
            let err = (0..5).map(|k| (q[k] - truth[k]).abs()).fold(0.0f64, f64::max);
            if i > 0 {
                max_error = max_error.max(err);
            }
            if t == 49 {
                end_errors.push((0..5).map(|k| (q[k] - truth[k]).abs()).sum::<f64>() / 5.0);
            }
        }
    }
    let report = s.shutdown().unwrap();
    let st = report.status("compensator").expect("the compensator's status");
    Run {
        commands,
        end_errors,
        max_error,
        rejected: st.rejected_samples,
        faults: st.faults,
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn feedback_in_lockstep_tracks_better_than_feed_forward_and_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let src = "configs/controller-feedback-realtime.toml";
    let ff = pipeline(
        dir.path(),
        "ff",
        controller(dir.path(), src, None).to_str().unwrap(),
        None,
    );
    let fb = pipeline(
        dir.path(),
        "fb",
        controller(dir.path(), src, Some(true)).to_str().unwrap(),
        None,
    );
    let a = run(&ff, "fbff");
    let b = run(&fb, "fbon");
    let c = run(&fb, "fbon2");
    // Lockstep: the same pipeline gives the same commands, bit for bit.
    assert_eq!(b.commands, c.commands, "feedback runs are deterministic");
    assert_eq!(b.end_errors, c.end_errors);
    // The feedback acted (the commands differ) and helped, by truth, at the end of the holds
    // (skipping the approach from home).
    assert_ne!(a.commands, b.commands);
    let n = points().len();
    let (e_ff, e_fb) = (mean(&a.end_errors[n - 9..]), mean(&b.end_errors[n - 9..]));
    eprintln!(
        "mean joint error at the end of the holds: feed-forward {e_ff:.3}°, feedback {e_fb:.3}°; \
         worst joint error {:.2}° vs {:.2}°",
        a.max_error, b.max_error
    );
    assert!(
        e_fb < 0.8 * e_ff,
        "feedback {e_fb:.3}° vs feed-forward {e_ff:.3}° mean joint error"
    );
    // Bounded: never worse than the feed-forward's worst plus the integrator's clamp (5°).
    assert!(b.max_error <= a.max_error + 5.0, "{} vs {}", b.max_error, a.max_error);
    assert_eq!(b.faults, 0, "no marker-loss fallback with the markers in view");
}

#[test]
fn feedback_with_markers_lost_falls_back_to_feed_forward() {
    let dir = tempfile::tempdir().unwrap();
    // The estimator looks for blue at a hue nothing has: the blue base sphere is never found,
    // so no frame gives a base frame and every estimate is invalid.
    let markers = std::fs::read_to_string(root().join("configs/markers.toml")).unwrap();
    let blind = markers.replacen(
        "[hsv.blue]\nh_min_deg = 200.0\nh_max_deg = 260.0",
        "[hsv.blue]\nh_min_deg = 280.0\nh_max_deg = 300.0",
        1,
    );
    assert_ne!(blind, markers, "configs/markers.toml changed: update this test");
    let blind_file = dir.path().join("markers-blind.toml");
    std::fs::write(&blind_file, blind).unwrap();
    let src = "configs/controller-feedback-realtime.toml";
    let ff = pipeline(
        dir.path(),
        "ff",
        controller(dir.path(), src, None).to_str().unwrap(),
        Some(&blind_file),
    );
    let fb = pipeline(
        dir.path(),
        "fb",
        controller(dir.path(), src, Some(true)).to_str().unwrap(),
        Some(&blind_file),
    );
    let a = run(&ff, "fblff");
    let b = run(&fb, "fblon");
    assert_eq!(a.commands, b.commands, "markers lost: pure feed-forward, bit for bit");
    assert_eq!(a.rejected, 0);
    // 30 fps for the run's ~5 s: every frame's estimate rejected and counted.
    let ticks = a.commands.len() as u64;
    assert!(
        b.rejected >= ticks / 4,
        "{} rejected estimates in {ticks} ticks",
        b.rejected
    );
    eprintln!(
        "markers lost: {} rejected estimates, {} fallback(s)",
        b.rejected, b.faults
    );
    assert_eq!(b.faults, 1, "one marker-loss fallback, counted as a fault");
}
