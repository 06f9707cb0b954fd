//! Every controller config shipped in `configs/` loads with the models it names: the contract is
//! accepted, both models run on the exact incremental evaluator (checked against tract at load),
//! and a short compensated path gives finite commands inside the command limits. A config pointing
//! at a missing or mismatched model fails here, not in a user's first `bowden evaluate`.

use bowden_compensator::{Compensator, ControllerConfig, Mode, StepOutput};
use bowden_kinematics::Robot;
use std::path::Path;

#[test]
fn shipped_controller_configs_load_their_models_and_compensate() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let robot = Robot::load(root.join("configs/robot.toml")).unwrap();
    let mut seen = 0;
    for name in ["controller.toml", "controller-accurate.toml", "controller-robot2.toml"] {
        let path = root.join("configs").join(name);
        let cfg = ControllerConfig::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut comp = Compensator::from_config(&cfg, &robot).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(
            comp.incremental(),
            (Some(true), Some(true)),
            "{name}: both models incremental"
        );
        // Every shipped controller runs the safe refinement, with the forward model's
        // training-data support recorded in its metadata (else the support and drift bounds
        // would silently be off).
        let sf = comp.safety();
        assert!(
            sf.support && sf.never_worse && sf.correction_scale > 0.0,
            "{name}: {sf:?}"
        );
        let sup = comp
            .support()
            .unwrap_or_else(|| panic!("{name}: the forward model records no training-data support"));
        for k in 0..5 {
            assert!(
                sup.cmd_min_deg[k] < sup.cmd_max_deg[k] && sup.cmd_step_max_deg[k] > 0.0 && sup.gap_max_deg[k] > 0.0
            );
        }
        for mode in [Mode::Paper, Mode::Newton] {
            comp.set_mode(mode).unwrap();
            comp.reset();
            let mut out = StepOutput::default();
            // A small loop, one dataset step (3·√5°) per target, as the evaluation trajectories.
            for k in 0..12 {
                let a = k as f64 * 0.9;
                let q = [12.0 * a.cos(), 12.0 * a.sin(), 6.0 * a.sin(), -8.0, 8.0];
                comp.step(&q, &mut out)
                    .unwrap_or_else(|e| panic!("{name} {mode:?} step {k}: {e}"));
                assert!(out.q_cmd_deg[..5].iter().all(|v| v.is_finite()), "{name} {mode:?}");
                // Command limits: the jaws may be commanded past each other, down to the bound.
                robot
                    .check_command_limits(&out.q_cmd_deg[..5].try_into().unwrap())
                    .unwrap_or_else(|e| panic!("{name} {mode:?} step {k}: {e}"));
            }
        }
        seen += 1;
    }
    assert_eq!(seen, 3);
}

/// `bowden train` (bowden-learning) writes the support props the compensator reads: the two
/// crates share the contract's key names (`bowden_interfaces::model`) but not the code that
/// writes and reads them, so a written model is loaded here, end to end.
#[test]
fn the_support_train_writes_is_the_support_the_compensator_reads() {
    let ds = bowden_learning::synthetic::hysteretic_dataset(400, 5, 3);
    let w = bowden_learning::WindowSet::build(
        &ds,
        bowden_learning::Direction::Forward,
        10,
        bowden_learning::SplitConfig::default(),
        bowden_learning::PhySource::Vision,
    )
    .unwrap();
    let cfg = bowden_learning::TrainConfig::paper(
        bowden_learning::Architecture::Fnn,
        bowden_learning::Direction::Forward,
        10,
        1,
        0,
    );
    let m = bowden_learning::train(&w, &cfg, None).unwrap().model;
    let want = m.support.clone().expect("train records the support");
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("m.onnx");
    m.save(&p).unwrap();
    let loaded = bowden_compensator::Model::load(&p).unwrap();
    let got = loaded.support().expect("the compensator reads it");
    for k in 0..5 {
        assert_eq!(got.cmd_min_deg[k], want.cmd_min_deg[k]);
        assert_eq!(got.cmd_max_deg[k], want.cmd_max_deg[k]);
        assert_eq!(got.cmd_step_max_deg[k], want.cmd_step_max_deg[k]);
        assert_eq!(got.gap_max_deg[k], want.gap_max_deg[k]);
    }
}
