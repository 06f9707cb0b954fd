//! The window prefixes computed off the cycle (`Compensator::start_prefix_worker`) against the
//! prefixes computed in the step, on the shipped controllers (TCN pair, accurate TCN + LSTM
//! pair):
//!
//! - `Wait` mode (lockstep) gives bit-identical step outputs, through history steps of one and
//!   of several entries, fine paths, a reset, a rejected target and hot model swaps;
//! - `Newest` mode (real time) gives bit-identical outputs whenever it runs on a complete
//!   prefix (after `wait_prefixes`), and reports its lag otherwise;
//! - the shipped models' incremental evaluators agree with tract within 1e-4 deg.
//!
//! No timing is asserted here: speed is claimed by `bowden bench compensate` percentiles.

use bowden_compensator::bench::random_trajectory;
use bowden_compensator::{
    Compensator, ControllerConfig, LoadOptions, Mode, Model, PrefixSync, PrefixWorkerOptions, PreparedModels,
    StepOutput,
};
use bowden_kinematics::Robot;
use std::path::Path;

fn config(name: &str) -> ControllerConfig {
    ControllerConfig::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs").join(name)).unwrap()
}

fn model(cfg: &ControllerConfig, field: &'static str) -> Model {
    let p = match field {
        "model_fwd" => cfg.model_fwd.clone(),
        _ => cfg.model_inv.clone(),
    }
    .unwrap();
    Model::load(cfg.resolve_model_path(field, &p).unwrap()).unwrap()
}

fn shipped_model(file: &str) -> Model {
    Model::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("models").join(file)).unwrap()
}

fn opts(sync: PrefixSync) -> PrefixWorkerOptions {
    PrefixWorkerOptions {
        sync,
        name: "prefix-test".into(),
        on_start: None,
    }
}

/// Dataset-rate steps (one entry each), a coarse path (several interpolated entries per
/// step), then a fine one (an entry every ~100 steps).
fn targets(robot: &Robot) -> Vec<[f64; 5]> {
    let step = 3.0 * 5f64.sqrt();
    let mut t = random_trajectory(robot, 120, step, 21);
    t.extend(random_trajectory(robot, 40, 3.5 * step, 22));
    t.extend(random_trajectory(robot, 600, 0.06, 23));
    t
}

/// Every field but the wall time, bit for bit.
fn same(a: &StepOutput, b: &StepOutput, what: &str) {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.q_cmd_deg), bits(&b.q_cmd_deg), "{what}: q_cmd");
    assert_eq!(bits(&a.q_refined_deg), bits(&b.q_refined_deg), "{what}: q_refined");
    assert_eq!(
        bits(&a.q_predicted_deg),
        bits(&b.q_predicted_deg),
        "{what}: q_predicted"
    );
    assert_eq!(
        a.loss_max_abs_deg.to_bits(),
        b.loss_max_abs_deg.to_bits(),
        "{what}: loss"
    );
    assert_eq!(
        (
            a.iterations,
            a.forward_evals,
            a.stop_reason,
            a.chosen,
            a.history_appended
        ),
        (
            b.iterations,
            b.forward_evals,
            b.stop_reason,
            b.chosen,
            b.history_appended
        ),
        "{what}: refinement"
    );
    assert_eq!(
        (
            a.rate_limited,
            a.joint_limited,
            a.safety_limited,
            a.upper_mask,
            a.lower_mask
        ),
        (
            b.rate_limited,
            b.joint_limited,
            b.safety_limited,
            b.upper_mask,
            b.lower_mask
        ),
        "{what}: limits"
    );
    assert_eq!(b.prefix_lag, 0, "{what}: a complete prefix");
}

/// Runs `reference` (prefixes in the step) and `other` in lockstep over `targets`, with a
/// reset and a rejected target half-way; `before_step` runs on `other` before each step.
fn lockstep(
    reference: &mut Compensator,
    other: &mut Compensator,
    targets: &[[f64; 5]],
    what: &str,
    before_step: &mut dyn FnMut(&mut Compensator),
) -> u64 {
    let (mut a, mut b) = (StepOutput::default(), StepOutput::default());
    let mut appended = 0;
    for (i, t) in targets.iter().enumerate() {
        if i == targets.len() / 3 {
            reference.reset();
            other.reset();
            assert!(reference.step(&[f64::NAN; 5], &mut a).is_err());
            assert!(other.step(&[f64::NAN; 5], &mut b).is_err());
        }
        before_step(other);
        reference.step(t, &mut a).unwrap();
        other.step(t, &mut b).unwrap();
        same(&a, &b, &format!("{what} step {i}"));
        appended += a.history_appended as u64;
        // As the node does: the prefix work right after the command went out.
        reference.prepare();
        other.prepare();
    }
    appended
}

#[test]
fn off_cycle_prefix_is_bit_identical_to_in_step_in_lockstep() {
    let robot = Robot::paper_default();
    let targets = targets(&robot);
    for name in ["controller.toml", "controller-accurate.toml"] {
        let base = config(name);
        let (fwd, inv) = (model(&base, "model_fwd"), model(&base, "model_inv"));
        for mode in [Mode::Paper, Mode::Newton] {
            let mut c = base.clone();
            c.mode = mode;
            c.budget.budget_ns = 0;
            let build = || Compensator::from_models(&c, &robot, Some(fwd.clone()), Some(inv.clone())).unwrap();
            let mut reference = build();

            let mut waiting = build();
            assert!(waiting.start_prefix_worker(opts(PrefixSync::Wait)).unwrap());
            assert_eq!(waiting.prefix_worker(), Some(PrefixSync::Wait));
            let appended = lockstep(
                &mut reference,
                &mut waiting,
                &targets,
                &format!("{name} {mode} wait"),
                &mut |_| {},
            );
            assert!(appended > 200, "the history moved ({appended} entries)");

            // Newest (real time) on a complete prefix: the same bits.
            let mut reference = build();
            let mut newest = build();
            assert!(newest.start_prefix_worker(opts(PrefixSync::Newest)).unwrap());
            lockstep(
                &mut reference,
                &mut newest,
                &targets,
                &format!("{name} {mode} newest"),
                &mut |c| c.wait_prefixes(),
            );
        }
    }
}

#[test]
fn newest_mode_reports_its_lag_and_catches_up() {
    let robot = Robot::paper_default();
    let base = config("controller-accurate.toml");
    let mut c = base.clone();
    c.budget.budget_ns = 0;
    let mut comp = Compensator::from_models(
        &c,
        &robot,
        Some(model(&base, "model_fwd")),
        Some(model(&base, "model_inv")),
    )
    .unwrap();
    assert!(comp.start_prefix_worker(opts(PrefixSync::Newest)).unwrap());
    assert!(!comp.prefix_pending(), "the step never computes a handled prefix");
    // Dataset-rate targets back to back: far faster than the LSTM prefix (≈ 2 ms), so the
    // steps run on older prefixes and say so.
    let targets = random_trajectory(&robot, 400, 3.0 * 5f64.sqrt(), 5);
    let mut out = StepOutput::default();
    let (mut lagged, mut max_lag) = (0u32, 0u32);
    for t in &targets {
        comp.step(t, &mut out).unwrap();
        assert!(out.q_cmd_deg[..5].iter().all(|v| v.is_finite()));
        lagged += (out.prefix_lag > 0) as u32;
        max_lag = max_lag.max(out.prefix_lag);
        comp.prepare();
    }
    assert!(lagged > 0, "back-to-back dataset steps outrun the worker");
    assert!(max_lag as usize <= targets.len());
    comp.wait_prefixes();
    comp.step(&targets[0], &mut out).unwrap();
    assert_eq!(
        out.prefix_lag, 0,
        "after wait_prefixes the step runs on the newest prefix"
    );
}

#[test]
fn swaps_restart_the_worker_with_the_new_models() {
    let robot = Robot::paper_default();
    let base = config("controller-accurate.toml");
    let mut c = base.clone();
    c.budget.budget_ns = 0;
    c.mode = Mode::Newton;
    let (fwd, inv) = (model(&base, "model_fwd"), model(&base, "model_inv"));
    // Other models of the same L and joints, as an adaptation generation would be.
    let (fwd2, inv2) = (
        shipped_model("lstm_forward_L80.onnx"),
        shipped_model("tcn_inverse_L80.onnx"),
    );
    let targets = targets(&robot);
    for sync in [PrefixSync::Wait, PrefixSync::Newest] {
        let build = || Compensator::from_models(&c, &robot, Some(fwd.clone()), Some(inv.clone())).unwrap();
        let mut reference = build();
        let mut other = build();
        assert!(other.start_prefix_worker(opts(sync)).unwrap());
        let (mut a, mut b) = (StepOutput::default(), StepOutput::default());
        for (i, t) in targets.iter().enumerate() {
            // Swap both models, then only the inverse back, then the forward back.
            let next = match i {
                100 => Some((Some(&fwd2), Some(&inv2), 1)),
                300 => Some((None, Some(&inv), 2)),
                500 => Some((Some(&fwd), None, 3)),
                _ => None,
            };
            if let Some((f, v, generation)) = next {
                for comp in [&mut reference, &mut other] {
                    let mut p = PreparedModels {
                        generation,
                        fwd: f.map(|m| comp.evaluator_for(m)),
                        inv: v.map(|m| comp.evaluator_for(m)),
                    };
                    comp.swap_models(&mut p).unwrap();
                    assert_eq!(comp.generation(), generation);
                }
            }
            if sync == PrefixSync::Newest {
                other.wait_prefixes();
            }
            reference.step(t, &mut a).unwrap();
            other.step(t, &mut b).unwrap();
            same(&a, &b, &format!("{sync:?} step {i}"));
            reference.prepare();
            other.prepare();
        }
    }
}

/// The load check every model passes before it runs (8 seeded random windows, some with
/// left zero padding, tolerance 1e-4 deg), on the shipped models, plus a second seed.
#[test]
fn shipped_incremental_evaluators_match_tract_within_1e_4_deg() {
    for seed in [LoadOptions::default().seed, 7] {
        check_shipped(&LoadOptions {
            seed,
            ..LoadOptions::default()
        });
    }
}

fn check_shipped(opts: &LoadOptions) {
    assert_eq!(opts.tolerance_deg, 1e-4);
    for file in [
        "tcn_forward_L80.onnx",
        "tcn_inverse_L80.onnx",
        "lstm_forward_L80.onnx",
        "lstm_inverse_L80.onnx",
    ] {
        let m = Model::load_with(Path::new(env!("CARGO_MANIFEST_DIR")).join("models").join(file), opts)
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        let d = m.load_check_max_abs_diff_deg().expect("incremental");
        assert!(d <= 1e-4, "{file}: {d:e} deg");
    }
}
