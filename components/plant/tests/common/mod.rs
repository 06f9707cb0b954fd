// Shared helpers; included with `mod common;` by the test files that need them.
#![allow(dead_code)]

use bowden_interfaces::PlantState;
use bowden_kinematics::{JointsDeg, Robot};
use bowden_plant::Plant;

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
