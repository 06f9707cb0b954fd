//! The vision feedback in closed loop, deterministic and in process: a 1 kHz compensator
//! (target shaping and command correction) on a toy robot with per-joint backlash, an offset
//! the feed-forward does not know and an 80 ms settling lag, seen by a 30 fps camera with
//! latency, Gaussian noise, NaN and invalid frames; and the controller config's `[feedback]`
//! table. The simulated robot and the real pipeline are exercised by the root crate's
//! `tests/it/feedback_lockstep.rs`.

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
    /// The desired angles at t ms.
    targets: fn(u64) -> [f64; J],
    /// At this time (ms) the robot's offset of one joint changes by this much (a cable slip).
    slip: Option<(u64, usize, f64)>,
    /// The robot's backlash half-width (deg), its offsets (None: the toy's), and the camera's
    /// frame interval (ms).
    band_deg: f64,
    offsets: Option<[f64; J]>,
    frame_every_ms: u64,
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
    robot.band = sc.band_deg;
    if let Some(o) = sc.offsets {
        robot.offset = o;
    }
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
        let q = (sc.targets)(k);
        if let Some((t_ms, joint, deg)) = sc.slip {
            if k == t_ms {
                robot.offset[joint] += deg;
            }
        }
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
        if k.is_multiple_of(sc.frame_every_ms) && k < sc.frames_until_ms {
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
        targets: target,
        slip: None,
        band_deg: 2.0,
        offsets: None,
        frame_every_ms: 33,
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
        targets: target,
        slip: None,
        band_deg: 2.0,
        offsets: None,
        frame_every_ms: 33,
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
        targets: target,
        slip: None,
        band_deg: 2.0,
        offsets: None,
        frame_every_ms: 33,
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

/// Held points at the paper's pace: a new target every 500 ms, each within ±10° of the
/// middle of the range, deterministic.
/// 60 s of points held 0.5 s (`targets`), a 10 fps camera 66 ms late with 0.3° noise, and the
/// toy robot with backlash `band_deg`, `offsets` (None: its own) and `slip`.
fn paper_pace(
    targets: fn(u64) -> [f64; J],
    slip: Option<(u64, usize, f64)>,
    band_deg: f64,
    offsets: Option<[f64; J]>,
) -> Scenario {
    Scenario {
        targets,
        slip,
        band_deg,
        offsets,
        frame_every_ms: 100,
        latency_ms: 66,
        noise_deg: 0.3,
        nan_every: 0,
        invalid_every: 0,
        frames_until_ms: u64::MAX,
        seconds: 60,
    }
}

/// The `[feedback]` table of configs/controller-feedback.toml.
fn shipped_feedback() -> FeedbackConfig {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    ControllerConfig::load(root.join("configs/controller-feedback.toml"))
        .unwrap()
        .feedback
}

/// Mean error over [from_ms, to_ms) without the first 100 ms of every 500 ms hold.
fn held_error(err: &[f64], from_ms: usize, to_ms: usize) -> f64 {
    let v: Vec<f64> = (from_ms..to_ms).filter(|t| t % 500 >= 100).map(|t| err[t]).collect();
    mean(&v)
}

fn held_points(t_ms: u64) -> [f64; J] {
    held_points_within(t_ms, 10.0)
}

/// The same within ±3°: steps of the dataset's size, after which the robot's lag has
/// settled 100 ms into a hold.
fn near_held_points(t_ms: u64) -> [f64; J] {
    held_points_within(t_ms, 3.0)
}

fn held_points_within(t_ms: u64, half_range_deg: f64) -> [f64; J] {
    let p = t_ms / 500;
    core::array::from_fn(|j| {
        let h = (p.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (j as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9)) >> 40;
        ((h % 2001) as f64 / 1000.0 - 1.0) * half_range_deg
    })
}

#[test]
fn the_slow_correction_learns_a_slip_that_every_jump_forgets() {
    // A cable slips at 10 s: joint 5 of the toy robot (no backlash here: what the feed-forward
    // leaves is its offsets) sits 4° lower from then on. The camera runs at 10 fps, so the local
    // correction has 4 frames per held point, and it is forgotten at every jump
    // (keep_on_jump = 0, as shipped): at every new point the error starts again from the
    // offset. The slow correction learns it once.
    let sc = paper_pace(near_held_points, Some((10_000, 4, 4.0)), 0.0, None);
    // The shipped [feedback] (configs/controller-feedback.toml), and the same without `b`.
    let slow = shipped_feedback();
    assert!(slow.bias_gain > 0.0 && slow.keep_on_jump == 0.0);
    let local = FeedbackConfig {
        bias_gain: 0.0,
        ..slow.clone()
    };
    let (a, b) = (run(Some(&local), &sc, 5), run(Some(&slow), &sc, 5));
    // The error once the robot's 80 ms lag has passed (100–500 ms into each hold), and before
    // the first frame of the point has been integrated (100–200 ms: what the feed-forward and b
    // leave at a new point).
    let late = |o: &Outcome| held_error(&o.err, 40_000, 60_000);
    let fresh = |o: &Outcome| {
        let v: Vec<f64> = (40_000..60_000usize)
            .filter(|t| (100..200).contains(&(t % 500)))
            .map(|t| o.err[t])
            .collect();
        mean(&v)
    };
    // Measured: 0.98° → 0.60° over the holds, 1.70° → 1.02° at new points.
    for (what, f) in [("holds", &late as &dyn Fn(&Outcome) -> f64), ("new points", &fresh)] {
        assert!(
            f(&b) < 0.75 * f(&a),
            "{what}: slow correction {:.3}° vs local only {:.3}°",
            f(&b),
            f(&a)
        );
    }
    // What it learned: every offset down to the dead band, never beyond it (b stops once the
    // mean need left is inside the band: measured b = [1.60, −0.60, 0.08, 1.08, 1.51] for
    // offsets d = [3, −2, 1.5, 2.5, 3] with the shipped 2° band); the slip on joint 5 (its
    // offset −1° → +3°) turned its b positive. Nothing without it.
    let band = slow.bias_deadband_deg;
    let d = [3.0, -2.0, 1.5, 2.5, 3.0];
    for (k, (&bk, dk)) in b.fb.slow_correction().iter().zip(d).enumerate() {
        assert!(
            bk * dk >= 0.0 && bk.abs() <= dk.abs() + band,
            "joint {k}: b {bk} for offset {dk}"
        );
    }
    assert!(b.fb.slow_correction()[4] > 1.0, "{:?}", b.fb.slow_correction());
    assert!(a.fb.slow_correction().iter().all(|&v| v == 0.0));
    // Bounded and converged: the last 20 s no worse than the 20 s before.
    assert!(held_error(&b.err, 40_000, 60_000) <= held_error(&b.err, 20_000, 40_000) * 1.25 + 0.05);
    assert!(b.u_max <= slow.integrator_max_deg + slow.bias_max_deg + 1e-12);
}

#[test]
fn the_most_eager_slow_correction_stays_bounded_with_delay_and_noise() {
    // The most eager slow correction the loader accepts (b takes every new point's whole
    // error: bias_gain 1, no average, no dead band) on top of the shipped local gain, with
    // 0–150 ms latency, 0.5° noise, NaN and invalid frames, and a slip: nothing grows.
    for latency_ms in [0, 66, 150] {
        let sc = Scenario {
            targets: held_points,
            slip: Some((10_000, 1, -3.0)),
            band_deg: 2.0,
            offsets: None,
            frame_every_ms: 33,
            latency_ms,
            noise_deg: 0.5,
            nan_every: 7,
            invalid_every: 11,
            frames_until_ms: u64::MAX,
            seconds: 60,
        };
        let cfg = FeedbackConfig {
            bias_gain: 1.0,
            bias_window: 1,
            bias_deadband_deg: 0.0,
            ..fb_cfg(ApplyTo::Target, 0.8)
        };
        cfg.check().unwrap();
        let o = run(Some(&cfg), &sc, 6);
        let ff = run(None, &sc, 6);
        let what = format!("latency {latency_ms} ms");
        let (mid, late) = (held_error(&o.err, 20_000, 40_000), held_error(&o.err, 40_000, 60_000));
        assert!(
            late.is_finite() && late <= mid * 1.25 + 0.05,
            "{what}: grows {mid} → {late}"
        );
        let ff_late = held_error(&ff.err, 40_000, 60_000);
        assert!(late < ff_late, "{what}: {late} vs feed-forward {ff_late}");
        assert!(o.u_max <= cfg.integrator_max_deg + cfg.bias_max_deg + 1e-12, "{what}");
    }
}

#[test]
fn the_slow_correction_leaves_a_zero_mean_residual_alone() {
    // No offset, no slip: what the feed-forward leaves is the backlash, whose sign follows the
    // direction each point is approached from. Its mean over new points stays inside the dead
    // band, so b never moves and the commands are those of the local correction alone, bit
    // for bit.
    let sc = paper_pace(held_points, None, 0.6, Some([0.0; J]));
    let slow = shipped_feedback();
    let local = FeedbackConfig {
        bias_gain: 0.0,
        ..slow.clone()
    };
    let (a, b) = (run(Some(&local), &sc, 8), run(Some(&slow), &sc, 8));
    assert!(
        b.fb.slow_correction().iter().all(|&v| v == 0.0),
        "{:?}",
        b.fb.slow_correction()
    );
    assert_eq!(a.cmd, b.cmd);
    // Without the dead band and the average (b learning every new point's error) it does move.
    let eager = FeedbackConfig {
        bias_window: 1,
        bias_deadband_deg: 0.0,
        ..slow.clone()
    };
    let c = run(Some(&eager), &sc, 8);
    assert!(c.fb.slow_correction().iter().any(|&v| v != 0.0));
    assert_ne!(a.cmd, c.cmd);
}
