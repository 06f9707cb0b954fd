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
