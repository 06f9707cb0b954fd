// Shared helpers; included with `mod common;` by the test files that need them.
#![allow(dead_code)]

use bowden_interfaces::PlantState;
use bowden_kinematics::{JointsDeg, Robot};
use bowden_plant::characterize::{TARGET_MAE_DEG, TARGET_SD_DEG};
use bowden_plant::{characterize, Characterization, CharacterizeOptions, Plant, PlantConfig};

/// Bytes of everything the plant exposes: equal bytes = equal state.
pub fn state_bytes(p: &Plant) -> Vec<u8> {
    let mut s = PlantState::default();
    p.fill_state(&mut s);
    let mut out = Vec::new();
    out.extend(s.t_sim_ns.to_le_bytes());
    for v in s.q_phy_deg.iter().chain(&s.q_cmd_deg).chain(&s.cable_tip_mm) {
        out.extend(v.to_le_bytes());
    }
    for v in p
        .q_quasi_static_deg()
        .iter()
        .chain(&p.cable_tension_n())
        .chain(&p.cable_command_mm())
    {
        out.extend(v.to_le_bytes());
    }
    out
}

/// A seeded eq. (16) command sequence.
pub fn commands(robot: &Robot, n_configs: usize, seed: u64) -> Vec<JointsDeg> {
    bowden_trajectory::dataset_commands(robot, n_configs, seed)
}

/// Sweep of one joint 0 → +a → −a → +a in `step` increments, others at `base`.
pub fn sweep(base: JointsDeg, joint: usize, amplitude_deg: f64, step_deg: f64) -> Vec<JointsDeg> {
    let n = (amplitude_deg / step_deg).round() as i64;
    let mut vals = Vec::new();
    vals.extend((0..=n).map(|k| k as f64 * step_deg));
    vals.extend((-n..n).rev().map(|k| k as f64 * step_deg));
    vals.extend((-n + 1..=n).map(|k| k as f64 * step_deg));
    vals.into_iter()
        .map(|v| {
            let mut q = base;
            q[joint] += v;
            q
        })
        .collect()
}

pub fn quasi_static_run(plant: &mut Plant, cmds: &[[f64; 5]]) -> Vec<[f64; 5]> {
    cmds.iter()
        .map(|q| {
            plant.settle_joints(q, 0.5, 0.01).unwrap();
            plant.q_phy_deg()
        })
        .collect()
}

pub fn mean_abs_error(cmds: &[[f64; 5]], phy: &[[f64; 5]], j: usize) -> f64 {
    cmds.iter().zip(phy).map(|(c, p)| (p[j] - c[j]).abs()).sum::<f64>() / cmds.len() as f64
}

/// Table IV's magnitudes on a seeded 150-configuration characterization (MAE 10–16°, SD
/// 7–11° on every joint) with history-dependent loops: a loop width and a residual no offset,
/// gain or lag explains, both > 3°.
pub fn lands_in_the_papers_range(config: &PlantConfig) -> Characterization {
    let robot = Robot::paper_default();
    let options = CharacterizeOptions {
        n_configs: 150,
        dataset_seed: 2,
        plant_seed: 2,
        pause_s: 0.5,
        dt_s: 0.01,
    };
    let mut calls = 0;
    let r = characterize(&robot, config, &options, &mut |_, _| calls += 1).unwrap();
    assert_eq!(calls, r.n_commands, "progress reported once per command");
    eprintln!("{}", r.markdown_table());
    for j in &r.joints {
        assert!(
            (TARGET_MAE_DEG.0..=TARGET_MAE_DEG.1).contains(&j.mae_deg),
            "{}: {} MAE {:.2} outside {:?}",
            config.name,
            j.joint,
            j.mae_deg,
            TARGET_MAE_DEG
        );
        assert!(
            (TARGET_SD_DEG.0..=TARGET_SD_DEG.1).contains(&j.sd_abs_deg),
            "{}: {} SD {:.2} outside {:?}",
            config.name,
            j.joint,
            j.sd_abs_deg,
            TARGET_SD_DEG
        );
        assert!(
            j.loop_width_deg > 3.0,
            "{}: {} loop width {:.2}",
            config.name,
            j.joint,
            j.loop_width_deg
        );
        assert!(
            j.lag_residual_deg > 3.0,
            "{}: {} lag residual {:.2}",
            config.name,
            j.joint,
            j.lag_residual_deg
        );
    }
    assert!(r.in_paper_range);
    r
}
