//! The physical behaviour the model promises: dead band after reversal, growth with sheath
//! curvature and tension, coupling through the routing, settling, contact and limits, creep.

// Loops over joint indices read like the maths they check.
#![allow(clippy::needless_range_loop)]

use crate::common;

use bowden_kinematics::{Robot, N_JOINTS};
use bowden_plant::{characterize, CharacterizeOptions, Plant, PlantConfig};
use common::{commands, mean_abs_error, quasi_static_run, sweep};

fn with_wrap(wrap_deg: f64) -> PlantConfig {
    let mut c = PlantConfig::paper_default();
    c.sheath.wrap_deg = [wrap_deg; 10];
    c
}

#[test]
fn reversal_shows_a_dead_band_not_a_lag() {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    let cmds = sweep([0.0; 5], 0, 54.0, 3.0);
    let phy = quasi_static_run(&mut plant, &cmds);
    // At the top of the sweep (index 18, +54°) the command reverses; settled q1 must not move
    // for the next several 3° steps (a lag would follow at once, one sample later).
    let top = 18;
    assert_eq!(cmds[top][0], 54.0);
    assert!(phy[top][0] < 54.0 - 5.0, "q1 lags on the way up: {}", phy[top][0]);
    let held = (top + 1..cmds.len())
        .take_while(|&k| (phy[k][0] - phy[top][0]).abs() < 0.5)
        .count();
    assert!(held >= 3, "dead band after reversal: only {held} steps held");
    // Moving down, q1 is above the command; moving up, below: a loop, not a line.
    let k_down = cmds
        .iter()
        .enumerate()
        .position(|(k, q)| k > top && q[0] == 0.0)
        .unwrap();
    let k_up = cmds.iter().enumerate().rposition(|(_, q)| q[0] == 0.0).unwrap();
    assert!(
        phy[k_down][0] - phy[k_up][0] > 10.0,
        "loop width at 0: {} vs {}",
        phy[k_down][0],
        phy[k_up][0]
    );
}

#[test]
fn loops_change_with_sheath_curvature() {
    let robot = Robot::paper_default();
    let cmds = commands(&robot, 40, 3);
    let mut maes = Vec::new();
    let mut runs = Vec::new();
    for wrap in [60.0, 240.0, 480.0] {
        let mut plant = Plant::new(&robot, &with_wrap(wrap), 1);
        let phy = quasi_static_run(&mut plant, &cmds);
        maes.push(
            (0..N_JOINTS)
                .map(|j| mean_abs_error(&cmds, &phy, j))
                .collect::<Vec<_>>(),
        );
        runs.push(phy);
    }
    for j in 0..N_JOINTS {
        assert!(
            maes[0][j] < maes[1][j] && maes[1][j] < maes[2][j],
            "q{}: MAE must grow with wrap: {:?}",
            j + 1,
            maes.iter().map(|m| m[j]).collect::<Vec<_>>()
        );
    }
    // The loops themselves open up: in a sweep of q1, the angle reached at a zero command
    // coming down minus the one reached going up grows with the wrap (up to the default's wrap:
    // far beyond it the band outgrows the joint range and a sweep only traces minor loops).
    let sweep_cmds = sweep([0.0; 5], 0, 57.0, 3.0);
    let k_down = sweep_cmds.iter().position(|q| q[0] < -1.0).unwrap() - 1;
    let k_up = sweep_cmds.len() - 1 - 19;
    assert_eq!((sweep_cmds[k_down][0], sweep_cmds[k_up][0]), (0.0, 0.0));
    let opening: Vec<f64> = [60.0, 150.0, 240.0]
        .iter()
        .map(|&wrap| {
            let phy = quasi_static_run(&mut Plant::new(&robot, &with_wrap(wrap), 1), &sweep_cmds);
            phy[k_down][0] - phy[k_up][0]
        })
        .collect();
    assert!(
        opening[0] + 2.0 < opening[1] && opening[1] + 2.0 < opening[2],
        "q1 loop opening at 0 must grow with wrap: {opening:?}"
    );
    // In a q3 sweep the wrist departs further from its command the more the sheath is curved.
    let sweep3 = sweep([0.0; 5], 2, 42.0, 3.0);
    let dev: Vec<f64> = [60.0, 240.0, 480.0]
        .iter()
        .map(|&wrap| {
            let phy = quasi_static_run(&mut Plant::new(&robot, &with_wrap(wrap), 1), &sweep3);
            mean_abs_error(&sweep3, &phy, 2)
        })
        .collect();
    assert!(
        dev[0] + 2.0 < dev[1] && dev[1] + 2.0 < dev[2],
        "q3 sweep deviation: {dev:?}"
    );
    assert_ne!(runs[0], runs[1]);
}

#[test]
fn dead_band_grows_with_tension() {
    let robot = Robot::paper_default();
    let cmds = sweep([0.0; 5], 0, 45.0, 3.0);
    let mut hi = PlantConfig::paper_default();
    for t in hi.cables.pretension_n.iter_mut() {
        *t *= 1.5;
    }
    let base = quasi_static_run(&mut Plant::new(&robot, &PlantConfig::paper_default(), 1), &cmds);
    let tense = quasi_static_run(&mut Plant::new(&robot, &hi, 1), &cmds);
    assert!(mean_abs_error(&cmds, &tense, 0) > mean_abs_error(&cmds, &base, 0) + 2.0);
}

#[test]
fn segment1_motion_couples_into_the_distal_joints() {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    // Only q1 is commanded; q3 and the jaws are held at fixed commands.
    let base = [0.0, 0.0, 10.0, -10.0, 10.0];
    let phy = quasi_static_run(&mut plant, &sweep(base, 0, 45.0, 3.0));
    let range = |j: usize| {
        let v: Vec<f64> = phy.iter().map(|q| q[j]).collect();
        v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
    };
    assert!(range(2) > 2.0, "segment 2 moves with segment 1: range {}", range(2));
    // The same sweep with friction and coupling off leaves segment 2 where it was: the
    // coupling is the routing's (decoupled cables lag through their sheaths), not geometry.
    let mut ideal = PlantConfig::paper_default();
    ideal.sheath.friction_coefficient = 0.0;
    ideal.body.friction_coefficient = 0.0;
    ideal.joints.coupling = [[0.0; 5]; 5];
    ideal.joints.stiffness_nmm_per_rad = [0.0; 5];
    ideal.joints.offset_deg = [0.0; 5];
    let mut p2 = Plant::new(&robot, &ideal, 1);
    for q in sweep(base, 0, 45.0, 3.0) {
        p2.settle_joints(&q, 0.5, 0.01).unwrap();
        for j in 0..N_JOINTS {
            assert!(
                (p2.q_phy_deg()[j] - q[j]).abs() < 0.02,
                "ideal plant follows: {:?} vs {:?}",
                p2.q_phy_deg(),
                q
            );
        }
    }
}

#[test]
fn jaws_never_cross_and_joints_stay_in_limits() {
    let robot = Robot::paper_default();
    let lim = robot.config.limits.clone();
    let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 4);
    // Jaws commanded closed while the wrist and segment 1 move: friction drives them into each other.
    let mut cmds = sweep([0.0, 0.0, 0.0, 0.0, 0.0], 2, 44.0, 4.0);
    cmds.extend(sweep([0.0, 0.0, 0.0, 5.0, 5.0], 1, 60.0, 6.0));
    cmds.extend(commands(&robot, 30, 8));
    for q in &cmds {
        plant.step_joints(q, 0.02).unwrap();
        plant.settle_joints(q, 0.3, 0.01).unwrap();
        let p = plant.q_phy_deg();
        assert!(p[4] - p[3] >= lim.min_jaw_opening_deg - 1e-9, "jaws crossed: {p:?}");
        for j in 0..N_JOINTS {
            assert!(
                p[j] >= lim.q_min_deg[j] - 1e-9 && p[j] <= lim.q_max_deg[j] + 1e-9,
                "q{} = {}",
                j + 1,
                p[j]
            );
        }
    }
}

#[test]
fn settles_within_the_papers_pause() {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    plant
        .settle_joints(&[10.0, -5.0, 8.0, -10.0, 10.0], 1.0, 0.001)
        .unwrap();
    let start = plant.q_phy_deg();
    let target_cmd = [40.0, 20.0, -20.0, -30.0, 15.0];
    let w = robot.cables().displacements_mm(&target_cmd);
    let mut at_50ms = [0.0; 5];
    for k in 1..=500 {
        plant.step(&w, 0.001).unwrap();
        if k == 50 {
            at_50ms = plant.q_phy_deg();
        }
    }
    let qs = plant.q_quasi_static_deg();
    let end = plant.q_phy_deg();
    for j in 0..N_JOINTS {
        let jump = (qs[j] - start[j]).abs();
        // Within the 0.5 s pause the residual is below 0.5 % of the jump (6.25 time constants) …
        assert!(
            (end[j] - qs[j]).abs() <= 0.005 * jump + 1e-6,
            "q{}: {} vs {}",
            j + 1,
            end[j],
            qs[j]
        );
        // … but 50 ms in it is still clearly moving: the pause matters.
        if jump > 2.0 {
            assert!((at_50ms[j] - qs[j]).abs() > 0.3 * jump, "q{} settled too fast", j + 1);
        }
    }
    assert_eq!(plant.t_sim_ns(), 1_500_000_000);
    // Longer steps settle the same way (exact discretisation).
    let mut coarse = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    coarse
        .settle_joints(&[10.0, -5.0, 8.0, -10.0, 10.0], 1.0, 0.05)
        .unwrap();
    coarse.settle(&w, 0.5, 0.05).unwrap();
    for j in 0..N_JOINTS {
        assert!(
            (coarse.q_phy_deg()[j] - end[j]).abs() < 0.2,
            "dt independence q{}",
            j + 1
        );
    }
}

#[test]
fn settle_ends_exactly_at_the_duration() {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    plant.settle_joints(&[5.0; 5], 0.5, 0.03).unwrap();
    assert_eq!(plant.t_sim_ns(), 500_000_000);
    plant.settle_joints(&[5.0; 5], 0.0, 0.03).unwrap();
    assert_eq!(plant.t_sim_ns(), 500_000_000);
}

#[test]
fn creep_drifts_the_joints_under_a_constant_command() {
    let robot = Robot::paper_default();
    let mut cfg = PlantConfig::paper_default();
    // w1 creeps, its antagonist w2 does not: segment 1 pitch drifts negative.
    cfg.drift.rate_mm_per_hour[0] = 0.5;
    cfg.drift.max_mm = 0.3;
    let q = [20.0, 0.0, 0.0, -10.0, 10.0];
    let mut plant = Plant::new(&robot, &cfg, 1);
    let mut still = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    plant.settle_joints(&q, 1.0, 0.01).unwrap();
    still.settle_joints(&q, 1.0, 0.01).unwrap();
    let before = plant.q_phy_deg()[0];
    assert!((before - still.q_phy_deg()[0]).abs() < 0.05);
    // 40 min later (saturated at 0.3 mm): about 0.3 / (2·2 mm/rad) ≈ 4° of q1.
    plant.settle_joints(&q, 2400.0, 1.0).unwrap();
    still.settle_joints(&q, 2400.0, 1.0).unwrap();
    let drift = plant.q_phy_deg()[0] - before;
    assert!(drift < -2.0 && drift > -8.0, "drift {drift}");
    assert!((still.q_phy_deg()[0] - before).abs() < 0.05, "no creep without drift");
}

#[test]
fn truth_is_exact_and_state_sample_is_complete() {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    let q = [12.0, -7.0, 9.0, -4.0, 6.0];
    plant.settle_joints(&q, 0.5, 0.01).unwrap();
    let mut s = bowden_interfaces::PlantState::default();
    s.header.seq = 77;
    plant.fill_state(&mut s);
    assert_eq!(s.header.seq, 77, "the header is the publisher's");
    assert_eq!((s.n_joints, s.n_cables), (5, 10));
    assert_eq!(&s.q_phy_deg[..5], &plant.q_phy_deg());
    assert_eq!(&s.q_phy_deg[5..], &[0.0; 3]);
    for j in 0..5 {
        assert!((s.q_cmd_deg[j] - q[j]).abs() < 1e-9, "decoded command");
    }
    assert_eq!(&s.cable_tip_mm[..10], &plant.cable_tip_mm());
    assert_eq!(s.t_sim_ns, 500_000_000);
    // Reading twice gives the same: no noise in the truth.
    let mut s2 = bowden_interfaces::PlantState {
        header: s.header,
        ..Default::default()
    };
    plant.fill_state(&mut s2);
    assert_eq!(s, s2);
}

#[test]
fn second_robot_file_is_another_robot() {
    let robot = Robot::paper_default();
    let cfg2 = PlantConfig::load(concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs/plant-robot2.toml")).unwrap();
    assert_ne!(cfg2, PlantConfig::paper_default());
    let opts = CharacterizeOptions {
        n_configs: 30,
        ..Default::default()
    };
    let a = characterize(&robot, &PlantConfig::paper_default(), &opts, &mut |_, _| {}).unwrap();
    let b = characterize(&robot, &cfg2, &opts, &mut |_, _| {}).unwrap();
    for j in 0..N_JOINTS {
        assert!((a.joints[j].mae_deg - b.joints[j].mae_deg).abs() > 0.3, "q{}", j + 1);
        assert!(b.joints[j].loop_width_deg > 1.0, "robot 2 is hysteretic too");
    }
}
