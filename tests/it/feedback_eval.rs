//! Measurements of the vision feedback (docs/architecture.md, "Vision feedback") through the
//! real multi-process lockstep pipeline, with the camera at a real frame rate. Ignored by
//! default (minutes each); run one with `--ignored --nocapture`:
//!
//! ```sh
//! cargo test --release --test it feedback_eval:: -- --ignored --nocapture paper_pace_camera_30fps
//! cargo test --release --test it feedback_eval:: -- --ignored --nocapture khz_camera_30fps
//! ```
//!
//! `bowden evaluate` runs the camera at one frame per held point (`camera_fps_for`), on the
//! point's last tick: the feedback there sees each point once, after it was measured. These
//! harnesses run the same pipeline (configs/evaluate.toml) with a shorter tick so the camera can
//! run at 30 fps:
//!
//! - `paper_pace_camera_30fps`: the unseen trajectories at the paper's pace (every point held
//!   0.5 s and measured on its last tick, exactly as `bowden evaluate` does, through
//!   `bowden_evaluation::run_trajectory`), ticks of 10 ms, camera 30 fps;
//! - `khz_camera_30fps`: the same paths resampled 0.06° apart and played one point per 1 ms
//!   tick (60°/s), camera 30 fps; every tick is scored by truth, every frame by vision.
//!
//! Each compares the feed-forward config (`FB_FF_CONFIG`) with the feedback config
//! (`FB_CONFIG`) — the same models, `[feedback]` on — for the modes in `FB_MODES`, and prints
//! Table V/VI (controllers `<mode>` = feed-forward, `<mode>-fb` = with feedback). Environment:
//! `FB_TRAJ_DIR` (default configs/trajectories; configs/trajectories/tuning to choose settings),
//! `FB_TRAJECTORIES` (random,circle,zigzag), `FB_REPEATS` (1), `FB_MAX_POINTS`, `FB_PLANT`.

use bowden::registry::REGISTRY;
use bowden_evaluation::report::{markdown, summarise, write_report};
use bowden_evaluation::{pipeline_variant, run_trajectory, EvalSettings, PointRecord, RunRecord, RunSpec};
use bowden_interfaces::{services, JointCommand, JointEstimate, JointTarget, PlantState};
use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use bowden_runtime::config::{Overrides, PipelineConfig};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::session::{LockstepSession, SessionOptions};
use bowden_trajectory::task_space::TrajectorySpec;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn env_or(key: &str, default: &str) -> String {
    std::env::var(key).unwrap_or_else(|_| default.to_string())
}

fn abs(p: &str) -> PathBuf {
    let p = PathBuf::from(p);
    if p.is_absolute() {
        p
    } else {
        root().join(p)
    }
}

struct Setup {
    robot: Robot,
    ff: PathBuf,
    fb: PathBuf,
    /// The configs as named (`ff`/`fb` may be adjusted copies).
    names: (String, String),
    modes: Vec<String>,
    paths: Vec<(String, PathBuf, TrajectorySpec)>,
    repeats: u32,
    max_points: Option<usize>,
    plant: Option<PathBuf>,
}

fn setup(default_ff: &str, default_fb: &str) -> Setup {
    let robot = Robot::paper_default();
    let dir = abs(&env_or("FB_TRAJ_DIR", "configs/trajectories"));
    let paths = env_or("FB_TRAJECTORIES", "random,circle,zigzag")
        .split(',')
        .map(|n| {
            let file = dir.join(format!("{n}.toml"));
            let spec = TrajectorySpec::load(&file).unwrap();
            (n.to_string(), file, spec)
        })
        .collect();
    let (ff, fb) = (env_or("FB_FF_CONFIG", default_ff), env_or("FB_CONFIG", default_fb));
    Setup {
        robot,
        ff: abs(&ff),
        fb: abs(&fb),
        names: (ff, fb),
        modes: env_or("FB_MODES", "newton,paper")
            .split(',')
            .map(String::from)
            .collect(),
        paths,
        repeats: env_or("FB_REPEATS", "1").parse().unwrap(),
        max_points: std::env::var("FB_MAX_POINTS").ok().map(|v| v.parse().unwrap()),
        plant: std::env::var("FB_PLANT").ok().map(|p| abs(&p)),
    }
}

/// configs/evaluate.toml with the compensator's config and mode, the camera's rate, the plant
/// file and the tick set.
#[allow(clippy::too_many_arguments)]
fn pipeline(
    dir: &Path,
    s: &Setup,
    label: &str,
    config: &Path,
    mode: &str,
    period_us: u64,
    fps: f64,
    act_rate: Option<f64>,
) -> PathBuf {
    let mut set = vec![
        ("compensator", "mode", toml::Value::String(mode.into())),
        (
            "compensator",
            "config",
            toml::Value::String(config.display().to_string()),
        ),
        ("camera", "fps", toml::Value::Float(fps)),
    ];
    if let Some(p) = &s.plant {
        set.push(("plant", "config", toml::Value::String(p.display().to_string())));
    }
    // The actuator's rate limit is per second, so a shorter tick lets it ramp a point's jump
    // over several ticks where a 100 ms tick passes it at once; each joint ramps on its own,
    // the cables (each driven by several joints) then take another path through the sheaths'
    // hysteresis than in `bowden evaluate` (and in the models' data). `FB_ACTUATOR_RATE`
    // sets it (the paper-pace harness keeps evaluate's per-tick limit).
    let act_rate = std::env::var("FB_ACTUATOR_RATE")
        .ok()
        .map(|r| r.parse().unwrap())
        .or(act_rate);
    if let Some(r) = act_rate {
        set.push(("actuator", "max_rate_deg_s", toml::Value::Float(r)));
    }
    let out = dir.join(format!("pipeline-{label}.toml"));
    pipeline_variant(&root().join("configs/evaluate.toml"), &set, &out).unwrap();
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    t["runtime"]
        .as_table_mut()
        .unwrap()
        .insert("period_us".into(), toml::Value::Integer(period_us as i64));
    std::fs::write(&out, toml::to_string(&t).unwrap()).unwrap();
    out
}

/// (label, controller config, mode): uncalibrated, then each mode without and with feedback.
fn variants(s: &Setup) -> Vec<(String, PathBuf, String)> {
    let mut v = vec![("uncalibrated".to_string(), s.ff.clone(), "uncalibrated".to_string())];
    let skip_ff = std::env::var("FB_SKIP_FF").is_ok();
    for m in &s.modes {
        if !skip_ff {
            v.push((m.clone(), s.ff.clone(), m.clone()));
        }
        v.push((format!("{m}-fb"), s.fb.clone(), m.clone()));
    }
    v
}

fn launch() -> LaunchOptions {
    LaunchOptions {
        quiet_children: true,
        ..LaunchOptions::with_exe(env!("CARGO_BIN_EXE_bowden"))
    }
}

fn header(s: &Setup, what: &str) -> String {
    format!(
        "{what}; feed-forward {} vs feedback {}; plant {}; {} repeat(s)",
        s.names.0,
        s.names.1,
        s.plant
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "configs/plant.toml".into()),
        s.repeats
    )
}

/// Home → the first point at the dataset step, the first point itself excluded (as
/// `bowden evaluate` approaches).
fn approach(first: &JointsDeg) -> Vec<JointsDeg> {
    let mut path = bowden_trajectory::interpolate_eq16(&[[0.0; 5], *first]);
    path.retain(|p| p != first);
    path
}

/// A copy of controller config `src` in `dir` with absolute model paths and the compensator's
/// rate limit scaled by `scale`.
fn scaled_rate(src: &Path, dir: &Path, scale: f64) -> PathBuf {
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(src).unwrap()).unwrap();
    for key in ["model_fwd", "model_inv"] {
        if let Some(toml::Value::String(m)) = t.get_mut(key) {
            if Path::new(m.as_str()).is_relative() {
                *m = root().join(m.as_str()).display().to_string();
            }
        }
    }
    let out = t["output"].as_table_mut().unwrap();
    let r = out["rate_limit_deg_s"].as_float().unwrap();
    out.insert("rate_limit_deg_s".into(), toml::Value::Float(r * scale));
    let name = src.file_name().unwrap().to_string_lossy().into_owned();
    let p = dir.join(format!("rate-{name}"));
    std::fs::write(&p, toml::to_string(&t).unwrap()).unwrap();
    p
}

#[test]
#[ignore = "minutes: a measurement, run with --ignored --nocapture"]
fn paper_pace_camera_30fps() {
    let mut s = setup("configs/controller-accurate.toml", "configs/controller-feedback.toml");
    let dir = tempfile::tempdir().unwrap();
    let period_us = env_or("FB_PERIOD_US", "10000").parse::<u64>().unwrap();
    // The compensator's rate limit is per tick (rate × tick): at 100 ms ticks (`bowden
    // evaluate`) it never clips a point's first command, at 10 ms it would, and the models'
    // sent-command history would record the clipped command. Both configs keep evaluate's
    // per-tick limit, so the feed-forward runs as it does in `bowden evaluate`.
    let scale = 100_000.0 / period_us as f64;
    s.ff = scaled_rate(&s.ff, dir.path(), scale);
    s.fb = scaled_rate(&s.fb, dir.path(), scale);
    let act_rate = Some(400.0 * scale);
    let fps: f64 = env_or("FB_FPS", "30").parse().unwrap();
    let settle_ticks = (500_000 / period_us) as u32;
    let settings = EvalSettings {
        settle_ticks,
        repeats: s.repeats,
        seed0: 1000,
        work_dir: dir.path().to_path_buf(),
        prefix_stem: format!("fbe{}_", std::process::id()),
        launch: launch(),
        kinds: REGISTRY,
    };
    let mut runs = Vec::new();
    for (label, cfg, mode) in variants(&s) {
        let file = pipeline(dir.path(), &s, &label, &cfg, &mode, period_us, fps, act_rate);
        for (name, path, spec) in &s.paths {
            let mut t = spec.to_joint_space(&s.robot, path).unwrap();
            if let Some(n) = s.max_points {
                t.q_deg.truncate(n.max(1));
            }
            let appr = approach(&t.q_deg[0]);
            for r in 0..s.repeats {
                let spec = RunSpec {
                    pipeline_file: &file,
                    name,
                    controller: &label,
                    repeat: r,
                    approach: &appr,
                    q_path: &t.q_deg,
                };
                runs.push(run_trajectory(&spec, &settings, &mut || {}).unwrap());
            }
        }
    }
    let h = header(
        &s,
        &format!(
            "paper's pace: points held 0.5 s ({settle_ticks} ticks of {} ms), measured on the last tick; camera {fps} fps",
            period_us as f64 / 1000.0
        ),
    );
    finish(&s, &runs, &h);
}

/// Prints Table V/VI; with `FB_REPORT=DIR` also writes report.md, report.json and the plots.
fn finish(s: &Setup, runs: &[RunRecord], header: &str) {
    let summary = summarise(&s.robot, runs);
    if let Ok(dir) = std::env::var("FB_REPORT") {
        write_report(&s.robot, runs, &summary, header, Path::new(&dir)).unwrap();
    }
    print!("{}", markdown(&summary, header));
}

#[test]
#[ignore = "minutes: a measurement, run with --ignored --nocapture"]
fn khz_camera_30fps() {
    let s = setup("configs/controller.toml", "configs/controller-feedback-realtime.toml");
    let dir = tempfile::tempdir().unwrap();
    let fps: f64 = env_or("FB_FPS", "30").parse().unwrap();
    let step_deg: f64 = env_or("FB_STEP_DEG", "0.06").parse().unwrap();
    let mut runs = Vec::new();
    for (label, cfg, mode) in variants(&s) {
        let file = pipeline(dir.path(), &s, &label, &cfg, &mode, 1000, fps, None);
        for (name, path, spec) in &s.paths {
            let mut fine = spec.to_joint_space_with_step(&s.robot, path, step_deg).unwrap().q_deg;
            if let Some(n) = s.max_points {
                fine.truncate(n.max(1));
            }
            // Home → start at the same speed, then 0.5 s at the start, unscored.
            let mut lead: Vec<JointsDeg> =
                bowden_trajectory::task_space::resample_by_chord(&[[0.0; 5], fine[0]], step_deg);
            lead.extend(std::iter::repeat_n(fine[0], 500));
            for r in 0..s.repeats {
                runs.push(run_fine(&file, name, &label, r, 1000 + u64::from(r), &lead, &fine));
            }
        }
    }
    let h = header(
        &s,
        &format!(
            "1 kHz: paths {step_deg}° apart, one per 1 ms tick ({:.0}°/s), every tick scored by truth, every frame by vision; camera {fps} fps",
            step_deg * 1000.0
        ),
    );
    finish(&s, &runs, &h);
}

/// One fine path through the lockstep pipeline, one point per tick; every tick is a point
/// (truth), with the estimate of that tick when a frame was taken (vision).
fn run_fine(
    pipeline_file: &Path,
    name: &str,
    label: &str,
    repeat: u32,
    seed: u64,
    lead: &[JointsDeg],
    path: &[JointsDeg],
) -> RunRecord {
    let ov = Overrides {
        prefix: Some(format!("fbk{}_{}_{}_{}_", std::process::id(), name, label, repeat)),
        seed: Some(seed),
        ..Default::default()
    };
    let cfg = PipelineConfig::load(pipeline_file, &ov, REGISTRY).unwrap();
    let mut opts = SessionOptions::new(launch());
    opts.taps = vec![
        services::JOINT_COMMAND.into(),
        services::PLANT_STATE.into(),
        services::JOINT_ESTIMATE.into(),
    ];
    opts.source = Some(services::JOINT_TARGET.into());
    let mut sess = LockstepSession::start(&cfg, opts).unwrap();
    for q in lead {
        let out = sess.step_with(JointTarget::from_deg(q)).unwrap();
        assert!(out.events.is_empty(), "{:?}", out.events);
    }
    let take = |a: &[f64; 8]| -> JointsDeg { core::array::from_fn(|j| a[j]) };
    let (mut points, mut invalid) = (Vec::with_capacity(path.len()), 0);
    let mut last_cmd = None;
    for q in path {
        let out = sess.step_with(JointTarget::from_deg(q)).unwrap();
        assert!(out.events.is_empty(), "{:?}", out.events);
        last_cmd = out.get::<JointCommand>(services::JOINT_COMMAND).or(last_cmd);
        let (cmd, state) = (
            last_cmd.expect("a command"),
            out.get::<PlantState>(services::PLANT_STATE).expect("a plant state"),
        );
        let (q_est, ee_est) = match out.get::<JointEstimate>(services::JOINT_ESTIMATE) {
            Some(e) if e.quality == bowden_interfaces::JointEstimate::QUALITY_VALID => {
                (Some(take(&e.q_phy_deg)), Some((e.ee_pos_base_mm, e.ee_quat_base_wxyz)))
            }
            Some(_) => {
                invalid += 1;
                (None, None)
            }
            None => (None, None),
        };
        points.push(PointRecord {
            q_desired_deg: *q,
            q_cmd_deg: take(&cmd.q_cmd_deg),
            q_true_deg: take(&state.q_phy_deg),
            q_est_deg: q_est,
            ee_est,
            q_predicted_deg: None,
            refine_iterations: cmd.iterations,
            t_sim_ns: state.t_sim_ns,
        });
    }
    let ticks = sess.ticks_done();
    let report = sess.shutdown().unwrap();
    if std::env::var("FB_VERBOSE").is_ok() {
        if let Some(st) = report.status("compensator") {
            eprintln!(
                "{name}/{label}: compensator rejected {} faults {} state {}",
                st.rejected_samples, st.faults, st.state
            );
        }
    }
    debug_assert!(points.iter().all(|p: &PointRecord| p.q_true_deg.len() == N_JOINTS));
    RunRecord {
        trajectory: name.into(),
        controller: label.into(),
        repeat,
        seed,
        points,
        invalid_estimates: invalid,
        ticks,
    }
}
