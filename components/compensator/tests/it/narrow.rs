//! The compiled narrow trial (every TCN fixture and the shipped TCN pair) returns the node
//! walk's bits: outputs and Jacobians over shifted windows of a real trajectory.

use crate::common;
use bowden_compensator::bench::random_trajectory;
use bowden_compensator::Model;
use bowden_kinematics::Robot;
use std::path::PathBuf;

#[test]
fn narrow_plan_reproduces_the_node_walk_on_every_tcn_model() {
    let shipped = |f: &str| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models").join(f);
    let mut models: Vec<(String, PathBuf)> = common::ALL
        .iter()
        .filter(|n| n.starts_with("tcn") && !n.starts_with("tcn-lstm"))
        .map(|n| (n.to_string(), common::fixture(n)))
        .collect();
    for f in ["tcn_forward_L80.onnx", "tcn_inverse_L80.onnx"] {
        models.push((f.to_string(), shipped(f)));
    }
    assert!(models.len() >= 3, "{models:?}");
    let robot = Robot::paper_default();
    let traj = random_trajectory(&robot, 400, 3.0 * 5f64.sqrt(), 9);
    let bits = |v: &[f64]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
    for (name, path) in models {
        let m = Model::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut narrow = m.incremental().expect("recognised");
        assert!(narrow.is_narrow(), "{name}: a TCN with J = 5 must get the narrow plan");
        let mut walk = m.incremental().expect("recognised").into_generic();
        let (l, j) = (narrow.seq_len(), narrow.joints());
        let mut hist: Vec<f64> = traj[..l - 1].iter().flatten().copied().collect();
        narrow.set_history(&hist);
        walk.set_history(&hist);
        for (k, q) in traj[l - 1..].iter().enumerate().take(200) {
            let last: Vec<f64> = q.iter().map(|v| v + 0.37 * (k % 7) as f64 - 1.0).collect();
            let (mut ya, mut yb) = (vec![0.0; j], vec![0.0; j]);
            let (mut ja, mut jb) = (vec![0.0; j * j], vec![0.0; j * j]);
            narrow.eval(&last, &mut ya);
            walk.eval(&last, &mut yb);
            assert_eq!(bits(&ya), bits(&yb), "{name} point {k}: eval");
            narrow.eval_jacobian(&last, &mut ya, &mut ja);
            walk.eval_jacobian(&last, &mut yb, &mut jb);
            assert_eq!(bits(&ya), bits(&yb), "{name} point {k}: eval_jacobian value");
            assert_eq!(bits(&ja), bits(&jb), "{name} point {k}: jacobian");
            hist.copy_within(j.., 0);
            hist[(l - 2) * j..].copy_from_slice(q);
            narrow.shift_history(&hist);
            walk.shift_history(&hist);
        }
    }
}
