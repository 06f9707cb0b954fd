//! Safe refinement (docs/architecture.md, "Safe refinement") on deliberately poor models: the
//! PyTorch fixtures are untrained networks, so the refinement chases whatever they predict.
//! Checked here against independent evaluations of the same models:
//! - never worse: the forward model never rates the sent command worse than the target sent
//!   unchanged; with the tip rating, neither the predicted tip position nor orientation;
//! - support: every sent command inside the training data's command range, and within the
//!   largest training step of the newest history entry;
//! - drift guard: |q_cmd − q_desired| stays within the data's largest gap over a long run, where
//!   without the guard the same models walk the commands away;
//! - support metadata that is partial or malformed is refused naming the key.

use crate::common;
use bowden_compensator::bench::random_trajectory;
use bowden_compensator::config::HistoryRuleName;
use bowden_compensator::{Chosen, Compensator, ControllerConfig, Mode, Model, SafetyConfig, StepOutput, WindowModel};
use bowden_kinematics::Robot;
use common::with_props;

use common::{supported, GAP, RANGE, STEP};

fn cfg(mode: Mode, safety: SafetyConfig) -> ControllerConfig {
    let mut c = ControllerConfig::shipped();
    c.mode = mode;
    c.budget.budget_ns = 0;
    c.output.rate_limit_deg_s = 0.0;
    c.history.rule = HistoryRuleName::EveryStep;
    // Newton free to roam: the poor model's optimum is far from the data.
    c.newton.prior_weight = 0.0;
    c.newton.max_evals = 8;
    c.safety = safety;
    c
}

fn targets() -> Vec<[f64; 5]> {
    random_trajectory(&Robot::paper_default(), 300, 3.0 * 5f64.sqrt(), 17)
}

/// Steps `comp` through `targets()` and, for every step, evaluates an independent evaluator of
/// `fwd` on the same sent history at the sent command and at the target as the output stage
/// would send it; `check(q_desired, sent, prediction at sent, prediction at the target, out)`.
fn judged_run(
    comp: &mut Compensator,
    fwd: &Model,
    robot: &Robot,
    mut check: impl FnMut(&[f64; 5], &[f64; 5], &[f64; 5], &[f64; 5], &StepOutput),
) {
    let mut judge = fwd.evaluator();
    let mut sent_hist = vec![0.0; 79 * 5];
    let mut out = StepOutput::default();
    let (mut p_sent, mut p_des) = ([0.0; 5], [0.0; 5]);
    for q_d in targets() {
        comp.step(&q_d, &mut out).unwrap();
        let sent: [f64; 5] = core::array::from_fn(|k| out.q_cmd_deg[k]);
        let des = robot.clamp_command_to_limits(&q_d);
        judge.set_history(&sent_hist);
        judge.eval(&sent, &mut p_sent);
        judge.eval(&des, &mut p_des);
        check(&q_d, &sent, &p_sent, &p_des, &out);
        sent_hist.copy_within(5.., 0);
        sent_hist[78 * 5..].copy_from_slice(&sent);
    }
}

#[test]
fn the_sent_command_is_never_rated_worse_than_the_target_unchanged() {
    let robot = Robot::paper_default();
    let fwd = Model::load(common::fixture("tcn_forward_L80_J5_s0")).unwrap();
    let inv = Model::load(common::fixture("tcn_inverse_L80_J5_s0")).unwrap();
    let safety = SafetyConfig {
        never_worse: true,
        ..SafetyConfig::default()
    };
    for mode in [Mode::Paper, Mode::Newton] {
        let mut comp =
            Compensator::from_models(&cfg(mode, safety.clone()), &robot, Some(fwd.clone()), Some(inv.clone())).unwrap();
        // An independent evaluation of the same forward model on the same sent history.
        let mut chosen = [0u32; 3];
        judged_run(&mut comp, &fwd, &robot, |q_d, sent, p_sent, p_des, out| {
            let cost = |p: &[f64; 5]| (0..5).map(|k| (p[k] - q_d[k]).powi(2)).sum::<f64>();
            assert!(
                cost(p_sent) <= cost(p_des) * (1.0 + 1e-9) + 1e-12,
                "{mode}: sent {sent:?} rated {:.4} worse than the target {:.4}",
                cost(p_sent),
                cost(p_des)
            );
            chosen[out.chosen as usize] += 1;
        });
        eprintln!("{mode}: refined / start / target chosen {chosen:?}");
        let counts = comp.safety_counts();
        assert_eq!(counts.steps, 300);
        assert_eq!(
            (counts.start_chosen, counts.desired_chosen),
            (u64::from(chosen[1]), u64::from(chosen[2]))
        );
        // The line the compensator node and `bowden compensate` print at the end.
        let line = comp.safety_summary().expect("never_worse is on");
        assert!(
            line.contains(&format!(
                "result {}, its start {}, the target unchanged {};",
                chosen[0], chosen[1], chosen[2]
            )) && line.ends_with("of 300 steps"),
            "{line}"
        );
        // Newton minimises the model's own rating, so its result is sent where the model trusts
        // it; Algorithm 1's α = 0.001 barely moves the untrained inverse's estimate, which an
        // untrained forward model rates worse than the target itself.
        if mode == Mode::Newton {
            assert!(
                chosen[0] > 0,
                "{mode}: the refinement's result is sent where it is better"
            );
        }
    }
    let _ = Chosen::Refined;
}

/// The tip pose's distance (position mm, orientation °) from `target` at predicted angles `p`,
/// as the evaluation measures it.
fn tip_distance(robot: &Robot, target: &[f64; 5], p: &[f64; 5]) -> (f64, f64) {
    bowden_kinematics::pose_distance(&robot.fk(target).ee, &robot.fk(p).ee)
}

/// The joint rating is a sum: a poor model can trade joints so that the sum improves while the
/// tip it predicts moves away in position or orientation (held-out Bouc–Wen units with the
/// paper's protocol did exactly that, by truth). With `never_worse_tip` that is never sent.
/// Checked against an independent evaluation of the same model; without the tip rating the
/// same run must send such commands, or the test would show nothing. With the untrained FNN forward
/// fixture they do (82 of 300 paper steps, 48 of 300 newton steps; the untrained TCN's
/// predictions never trade joints so).
#[test]
fn with_the_tip_rating_the_predicted_tip_is_never_further_than_the_target_unchanged() {
    let robot = Robot::paper_default();
    let fwd = Model::load(common::fixture("fnn_forward_L80_J5_s0")).unwrap();
    let inv = Model::load(common::fixture("tcn_inverse_L80_J5_s0")).unwrap();
    for mode in [Mode::Paper, Mode::Newton] {
        let mut worse = [0u32; 2];
        let mut chosen_tip = [0u32; 3];
        for tip in [false, true] {
            let safety = SafetyConfig {
                never_worse: true,
                never_worse_tip: tip,
                ..SafetyConfig::default()
            };
            let mut comp =
                Compensator::from_models(&cfg(mode, safety), &robot, Some(fwd.clone()), Some(inv.clone())).unwrap();
            judged_run(&mut comp, &fwd, &robot, |q_d, sent, p_sent, p_des, out| {
                let (pos_s, rot_s) = tip_distance(&robot, q_d, p_sent);
                let (pos_d, rot_d) = tip_distance(&robot, q_d, p_des);
                let further = pos_s > pos_d * (1.0 + 1e-9) + 1e-9 || rot_s > rot_d * (1.0 + 1e-9) + 1e-9;
                worse[tip as usize] += further as u32;
                if tip {
                    assert!(
                        !further,
                        "{mode}: sent {sent:?}, predicted tip {pos_s:.3} mm / {rot_s:.3}° from the target, \
                         the target unchanged {pos_d:.3} mm / {rot_d:.3}°"
                    );
                    chosen_tip[out.chosen as usize] += 1;
                }
            });
        }
        eprintln!("{mode}: predicted tip further than the target's, joint rating / tip rating: {worse:?}; refined / start / target with the tip rating: {chosen_tip:?}");
        assert!(
            worse[0] > 0,
            "{mode}: the joint rating alone never sent a tip-worse command: the test shows nothing"
        );
        // The tip rating picks among the candidates, it does not stop the refinement.
        assert!(chosen_tip[0] > 0, "{mode}: the refinement's result was never sent");
    }
}

#[test]
fn candidates_stay_inside_the_support_and_the_drift_guard_holds() {
    let robot = Robot::paper_default();
    let fwd = supported("tcn_forward_L80_J5_s0");
    let inv = Model::load(common::fixture("tcn_inverse_L80_J5_s0")).unwrap();
    assert!(fwd.support().is_some());
    // Slow targets inside the support, long enough for drift through the sent history to show.
    let ts: Vec<[f64; 5]> = targets()
        .into_iter()
        .map(|q| core::array::from_fn(|k| (q[k] * 0.3).clamp(-RANGE + 2.0, RANGE - 2.0)))
        .collect();
    for mode in [Mode::Paper, Mode::Newton] {
        let mut worst_gap = [0.0f64; 2];
        let strict = SafetyConfig {
            step_scale: 1.0,
            ..SafetyConfig::on()
        };
        for (run, safety) in [strict, SafetyConfig::default()].into_iter().enumerate() {
            let mut comp =
                Compensator::from_models(&cfg(mode, safety.clone()), &robot, Some(fwd.clone()), Some(inv.clone()))
                    .unwrap();
            let mut out = StepOutput::default();
            let mut prev: Option<[f64; 5]> = None;
            for q_d in &ts {
                comp.step(q_d, &mut out).unwrap();
                for k in 0..5 {
                    let c = out.q_cmd_deg[k];
                    worst_gap[run] = worst_gap[run].max((c - q_d[k]).abs());
                    if safety.support {
                        assert!(c.abs() <= RANGE + 1e-9, "{mode}: q{} = {c} outside the support", k + 1);
                        assert!(
                            (c - q_d[k]).abs() <= GAP + 1e-9,
                            "{mode}: q{} = {c} is {:.2}° from the target (guard {GAP})",
                            k + 1,
                            (c - q_d[k]).abs()
                        );
                        if let Some(p) = prev {
                            // One history entry per step (every_step): the newest entry is the
                            // last command sent.
                            assert!(
                                (c - p[k]).abs() <= STEP + 1e-9,
                                "{mode}: step {:.2}° > {STEP}",
                                c - p[k]
                            );
                        }
                    }
                }
                prev = Some(core::array::from_fn(|k| out.q_cmd_deg[k]));
            }
            if safety.support {
                assert!(comp.safety_counts().limited > 0, "{mode}: the bounds were active");
            }
        }
        eprintln!(
            "{mode}: largest |q_cmd − q_desired| with safety {:.2}°, without {:.2}°",
            worst_gap[0], worst_gap[1]
        );
        assert!(
            worst_gap[1] > GAP,
            "{mode}: the poor model must walk the commands away without the guard ({:.2}°), or this test proves nothing",
            worst_gap[1]
        );
    }
}

#[test]
fn partial_or_malformed_support_metadata_is_refused_by_key() {
    let e = with_props("tcn_forward_L80_J5_s0", &[("support_cmd_min_deg", "1,2,3,4,5")])
        .map(|_| ())
        .map_err(|e| e.to_string())
        .expect_err("partial support refused");
    assert!(e.contains("support_cmd_max_deg"), "{e}");
    let e = with_props(
        "tcn_forward_L80_J5_s0",
        &[
            ("support_cmd_min_deg", "1,2,3,4"),
            ("support_cmd_max_deg", "1,2,3,4,5"),
            ("support_cmd_step_max_deg", "1,2,3,4,5"),
            ("support_gap_max_deg", "1,2,3,4,5"),
        ],
    )
    .map(|_| ())
    .map_err(|e| e.to_string())
    .expect_err("wrong length refused");
    assert!(e.contains("support_cmd_min_deg"), "{e}");
    let e = with_props(
        "tcn_forward_L80_J5_s0",
        &[
            ("support_cmd_min_deg", "1,2,3,4,5"),
            ("support_cmd_max_deg", "1,2,3,4,5"),
            ("support_cmd_step_max_deg", "1,2,NaN,4,5"),
            ("support_gap_max_deg", "1,2,3,4,5"),
        ],
    )
    .map(|_| ())
    .map_err(|e| e.to_string())
    .expect_err("NaN refused");
    assert!(e.contains("support_cmd_step_max_deg"), "{e}");
}
