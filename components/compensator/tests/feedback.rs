//! The vision feedback in closed loop, deterministic and in process: a 1 kHz compensator
//! (target shaping and command correction) on a toy robot with per-joint backlash, an offset
//! the feed-forward does not know and an 80 ms settling lag, seen by a 30 fps camera with
//! latency, Gaussian noise, NaN and invalid frames; and the controller config's `[feedback]`
//! table. The simulated robot and the real pipeline are exercised by the root crate's
//! `tests/feedback_lockstep.rs`.

// Joint loops index several parallel arrays with one variable, as in the crate itself.
#![allow(clippy::needless_range_loop)]

use bowden_compensator::{ApplyTo, Compensator, ControllerConfig, Feedback, FeedbackConfig, Mode, StepOutput};
use bowden_interfaces::JointEstimate;
use bowden_kinematics::Robot;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use std::path::Path;

const MS: u64 = 1_000_000;
const J: usize = 5;

/// Per joint: a play operator of half-width `band` on the command, minus `offset`, then a
/// first-order lag of 80 ms: a dead band the uncalibrated command does not cross and a bias.
struct ToyRobot {
    play: [f64; J],
    q: [f64; J],
    band: f64,
    offset: [f64; J],
}

impl ToyRobot {
    fn new() -> Self {
        Self {
            play: [0.0; J],
            q: [0.0; J],
            band: 2.0,
            offset: [3.0, -2.0, 1.5, 2.5, -1.0],
        }
    }
    fn step(&mut self, cmd: &[f64]) {
        let a = 1.0 - (-1.0f64 / 80.0).exp();
        for k in 0..J {
            self.play[k] = self.play[k].clamp(cmd[k] - self.band, cmd[k] + self.band);
            let qs = self.play[k] - self.offset[k];
            self.q[k] += a * (qs - self.q[k]);
        }
    }
}

fn compensator() -> Compensator {
    let mut cfg = ControllerConfig::shipped();
    cfg.mode = Mode::Uncalibrated;
    cfg.model_fwd = None;
    cfg.model_inv = None;
    let mut c = Compensator::from_config(&cfg, &Robot::paper_default()).unwrap();
    c.set_budget_ns(0);
    c
}

fn target(t_ms: u64) -> [f64; J] {
    // Holds and slow sweeps, well inside the joint limits; periodic in 12 s.
    let s = t_ms as f64 * 1e-3;
    let slow = (2.0 * std::f64::consts::PI * s / 6.0).sin();
    let hold = ((t_ms / 4000) % 3) as f64 * 4.0 - 4.0; // jumps at 4, 8, 12 s
    [
        10.0 * slow + hold,
        -8.0 * slow,
        5.0 + hold,
        -10.0 + 3.0 * slow,
        10.0 - 3.0 * slow,
    ]
}

struct Scenario {
    latency_ms: u64,
    noise_deg: f64,
    /// Every n-th frame carries a NaN, every m-th is invalid (0 = never).
    nan_every: u64,
    invalid_every: u64,
    /// No frame after this time (markers lost), ms.
    frames_until_ms: u64,
    seconds: u64,
}

struct Outcome {
    /// |q_desired − q_phy| per ms, mean over joints.
    err: Vec<f64>,
    /// Largest |u| seen at any step.
    u_max: f64,
    cmd: Vec<[f64; J]>,
    fb: Feedback,
}

/// Runs the loop; `cfg = None` is the feed-forward alone.
fn run(cfg: Option<&FeedbackConfig>, sc: &Scenario, seed: u64) -> Outcome {
    let mut comp = compensator();
    let mut fb = Feedback::new(cfg.unwrap_or(&FeedbackConfig::default()), J, MS);
    let mut robot = ToyRobot::new();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut gauss = move || {
        // Box–Muller.
        let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-12), rng.random());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    };
    let mut in_flight: VecDeque<(u64, JointEstimate)> = VecDeque::new();
    let mut out = StepOutput::default();
    let (mut err, mut cmds, mut u_max) = (Vec::new(), Vec::new(), 0.0f64);
    let mut frame = 0u64;
    for k in 0..sc.seconds * 1000 {
        let now = k * MS;
        let q = target(k);
        let mut u = [0.0; J];
        if let Some(c) = cfg {
            fb.begin(k, &q, now);
            while in_flight.front().is_some_and(|(arrive, _)| *arrive <= now) {
                let (_, e) = in_flight.pop_front().unwrap();
                fb.observe(&e, now);
            }
            u.copy_from_slice(fb.update(now));
            let shaped: [f64; J] = core::array::from_fn(|j| q[j] + u[j]);
            match c.apply {
                ApplyTo::Target => comp.step(&shaped, &mut out).unwrap(),
                ApplyTo::Command => comp.step_with_correction(&q, &u, &mut out).unwrap(),
            }
            fb.note_bounds(out.upper_mask, out.lower_mask);
        } else {
            comp.step(&q, &mut out).unwrap();
        }
        u_max = u.iter().fold(u_max, |m, v| m.max(v.abs()));
        let cmd: [f64; J] = core::array::from_fn(|j| out.q_cmd_deg[j]);
        robot.step(&cmd);
        cmds.push(cmd);
        err.push((0..J).map(|j| (q[j] - robot.q[j]).abs()).sum::<f64>() / J as f64);
        // The camera: 30 fps, the robot after this tick's command.
        if k.is_multiple_of(33) && k < sc.frames_until_ms {
            frame += 1;
            let mut e = JointEstimate {
                n_joints: J as u32,
                quality: JointEstimate::QUALITY_VALID,
                joint_valid_mask: 0b11111,
                ..Default::default()
            };
            e.header.tick = k;
            e.header.t_origin_ns = now;
            for j in 0..J {
                e.q_phy_deg[j] = robot.q[j] + sc.noise_deg * gauss();
            }
            if sc.nan_every > 0 && frame.is_multiple_of(sc.nan_every) {
                e.q_phy_deg[frame as usize % J] = f64::NAN;
            }
            if sc.invalid_every > 0 && frame.is_multiple_of(sc.invalid_every) {
                e.quality = JointEstimate::QUALITY_INVALID;
            }
            in_flight.push_back((now + sc.latency_ms * MS, e));
        }
    }
    Outcome {
        err,
        u_max,
        cmd: cmds,
        fb,
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn fb_cfg(apply: ApplyTo, gain: f64) -> FeedbackConfig {
    FeedbackConfig {
        enabled: true,
        apply,
        gain,
        ..FeedbackConfig::default()
    }
}

#[test]
fn feedback_with_delay_and_noise_stays_bounded_and_beats_feed_forward() {
    let base = Scenario {
        latency_ms: 0,
        noise_deg: 0.5,
        nan_every: 7,
        invalid_every: 11,
        frames_until_ms: u64::MAX,
        seconds: 30,
    };
    let ff = run(None, &base, 1);
    let ff_err = mean(&ff.err[10_000..]);
    assert!(ff_err > 2.0, "the toy robot's offset and dead band: {ff_err}");
    // Camera latency from none to 4.5 frames; the shipped gain and near the bound of "any
    // settling" (gain < 1); both ways of applying the correction.
    for latency_ms in [0, 33, 66, 100, 150] {
        for (apply, gain) in [(ApplyTo::Target, 0.5), (ApplyTo::Target, 0.95), (ApplyTo::Command, 0.5)] {
            let cfg = fb_cfg(apply, gain);
            let sc = Scenario { latency_ms, ..base };
            let o = run(Some(&cfg), &sc, 1);
            let what = format!("latency {latency_ms} ms, {apply:?}, gain {gain}");
            // Bounded: the integrator within its clamp, the error never beyond the
            // feed-forward's worst plus the clamp.
            assert!(o.u_max <= cfg.integrator_max_deg + 1e-12, "{what}: |u| {}", o.u_max);
            let ff_max = ff.err.iter().fold(0.0f64, |m, &e| m.max(e));
            let fb_max = o.err.iter().fold(0.0f64, |m, &e| m.max(e));
            assert!(
                fb_max <= ff_max + cfg.integrator_max_deg,
                "{what}: max error {fb_max} vs {ff_max}"
            );
            // Not diverging: the last period of the (12 s periodic) targets no worse than the
            // one before.
            let (mid, late) = (mean(&o.err[6_000..18_000]), mean(&o.err[18_000..]));
            assert!(late <= mid * 1.25 + 0.05, "{what}: error grows {mid} → {late}");
            // And better than the feed-forward alone, down towards the noise.
            let fb_err = mean(&o.err[10_000..]);
            assert!(fb_err < 0.5 * ff_err, "{what}: {fb_err:.3} vs feed-forward {ff_err:.3}");
            // Every NaN and invalid frame was rejected and counted; none was integrated.
            let c = o.fb.counts();
            assert!(c.not_finite > 50 && c.invalid > 30, "{what}: {c:?}");
            assert!(c.updates > 100, "{what}: {c:?}");
            assert_eq!(c.loss_episodes, 0, "{what}");
        }
    }
}

#[test]
fn a_delayed_integrator_rings_above_the_documented_bound() {
    // What the capture-time test prevents: the same loop fed every frame's error regardless
    // of when it was captured is a delayed integrator, z^(d+1) − z^d + k·g, unstable for
    // k·g ≥ 2·sin(π / (2(2d + 1))). The pure recursion, d = 4 frames (≈ 130 ms at 30 fps):
    let bound = 2.0 * (std::f64::consts::PI / 18.0).sin();
    let ring = |k: f64| {
        let d = 4;
        let mut u = vec![0.0f64; d + 1];
        for _ in 0..3000 {
            let e = 1.0 - u[u.len() - 1 - d];
            let next = u[u.len() - 1] + k * e;
            u.push(next);
        }
        u[u.len() - 50..].iter().fold(0.0f64, |m, v| m.max((v - 1.0).abs()))
    };
    assert!(ring(0.8 * bound) < 1e-3, "converges below the bound");
    assert!(ring(1.2 * bound) > 1.0, "rings above it");
    // With the gate (the real loop, 150 ms latency), a gain of 0.95 > bound converges.
    assert!(0.95 > bound);
}

#[test]
fn markers_lost_falls_back_to_feed_forward() {
    let base = Scenario {
        latency_ms: 66,
        noise_deg: 0.3,
        nan_every: 0,
        invalid_every: 0,
        frames_until_ms: 9_000,
        seconds: 12,
    };
    let ff = run(None, &base, 3);
    for apply in [ApplyTo::Target, ApplyTo::Command] {
        let cfg = fb_cfg(apply, 0.5);
        let o = run(Some(&cfg), &base, 3);
        // The correction worked while frames came...
        assert!(mean(&o.err[8_500..9_000]) < 0.5 * mean(&ff.err[8_500..9_000]));
        // ... was held within the timeout, then dropped: after the last frame (captured at
        // 8.976 s) plus the 1 s timeout and the rate limit's ramp, the command is the
        // feed-forward's, bit for bit (no target jump between 8 and 12 s resets it earlier).
        assert!(o.fb.lost(), "{apply:?}");
        assert_eq!(o.fb.counts().loss_episodes, 1);
        let back = 9_976 + 50;
        assert_ne!(
            o.cmd[9_900], ff.cmd[9_900],
            "{apply:?}: still corrected within the timeout"
        );
        assert_eq!(&o.cmd[back..], &ff.cmd[back..], "{apply:?}: pure feed-forward after it");
    }
}

#[test]
fn markers_never_seen_leave_the_feed_forward_untouched() {
    let sc = Scenario {
        latency_ms: 0,
        noise_deg: 0.0,
        nan_every: 0,
        invalid_every: 1, // every frame invalid
        frames_until_ms: u64::MAX,
        seconds: 3,
    };
    let ff = run(None, &sc, 4);
    let o = run(Some(&fb_cfg(ApplyTo::Target, 0.5)), &sc, 4);
    assert_eq!(o.cmd, ff.cmd);
    assert!(o.fb.counts().invalid > 80);
    assert_eq!(o.fb.counts().updates, 0);
    assert!(o.fb.lost());
}

#[test]
fn the_feedback_table_is_validated_on_load_and_off_by_default() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let shipped = std::fs::read_to_string(root.join("configs/controller.toml")).unwrap();
    let c = ControllerConfig::parse(&shipped, Path::new("configs/controller.toml")).unwrap();
    assert!(!c.feedback.enabled, "absent = off");
    for f in [
        "configs/controller-feedback.toml",
        "configs/controller-feedback-realtime.toml",
    ] {
        let c = ControllerConfig::load(root.join(f)).unwrap();
        assert!(c.feedback.enabled, "{f}");
        assert!(c.feedback.gain < 1.0, "{f}: stable however little a frame has settled");
    }
    let with = |table: &str| format!("{shipped}\n[feedback]\n{table}\n");
    let e = ControllerConfig::parse(&with("enabled = true\ngain = 2.5"), Path::new("x.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("x.toml") && e.contains("feedback.gain") && e.contains("2.5"),
        "{e}"
    );
    let e = ControllerConfig::parse(&with("enabled = true\nloss_timeout_ms = -1"), Path::new("y.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("feedback.loss_timeout_ms"), "{e}");
    let e = ControllerConfig::parse(&with("enabled = true\ngian = 0.5"), Path::new("z.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("gian"), "unknown keys are refused: {e}");
    let e = ControllerConfig::parse(&with("apply = \"elsewhere\""), Path::new("w.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("elsewhere"), "{e}");
}
