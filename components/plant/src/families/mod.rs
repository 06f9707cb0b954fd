//! The hysteresis families beside the default capstan model (which lives in `plant.rs` and
//! `hysteresis.rs`): each module holds one family's instance parameters (config + seeded
//! variation), its evolving state (`Copy`, committed by the plant only when a step succeeds)
//! and its allocation-free update. The plant does the rest the same way for every family:
//! command checks and decoding, the residual coupling, gains and offsets, joint limits and jaw
//! contact, and the first-order settling.

pub mod bouc_wen;
pub mod lugre;
pub mod preisach;

use bowden_kinematics::{N_CABLES, N_JOINTS};
use nalgebra::Matrix5;

/// Joints that are bending segments (q1, q2: segment 1; q3: segment 2): cables crossing them
/// wrap the hinges by their bend. The jaws (q4, q5) are pulleys.
pub(crate) const BEND_JOINTS: usize = 3;

/// The instance parameters every family shares (the plant's, after the seeded variation).
pub(crate) struct Shared<'a> {
    /// L/(E·A) of each cable, mm/N.
    pub compliance_mm_per_n: &'a [f64; N_CABLES],
    /// μ_sheath·wrap of each cable.
    pub sheath_x: &'a [f64; N_CABLES],
    /// μ between cables and hinge holes.
    pub body_mu: f64,
    /// 1 where cable i crosses bending joint j.
    pub crosses: &'a [[f64; BEND_JOINTS]; N_CABLES],
    pub pairs: &'a [(usize, usize); N_JOINTS],
    pub pair_of: &'a [usize; N_CABLES],
    pub pair_sign: &'a [f64; N_CABLES],
    /// Cable displacements at the straight pose, mm.
    pub zero_mm: &'a [f64; N_CABLES],
    pub offset_rad: &'a [f64; N_JOINTS],
    /// J0⁻¹: joint angles (rad) per pair difference (mm) at the straight pose.
    pub jac_inv: Matrix5<f64>,
    /// ΔT (N per pair) = tension_matrix · q (rad): the joint stiffness through J0.
    pub tension_matrix: Matrix5<f64>,
    /// G·(I + C).
    pub joint_map: Matrix5<f64>,
}

/// What cable creep does to one antagonistic pair, the same way the capstan plant reasons:
/// the pair's creep s_a + s_b first relaxes its pre-tension (by creep / (c_a + c_b)); what the
/// pre-tension stretch c·T̄ cannot take up is free play (slack) of the pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PairCreep {
    /// Pre-tension lost by each cable of the pair, N.
    pub drop_n: f64,
    /// Remaining fraction of the pair's mean pre-tension, in [0, 1].
    pub tension_ratio: f64,
    /// Creep beyond the pre-tension stretch: free play of the pair difference (full width), mm.
    pub excess_mm: f64,
}

/// [`PairCreep`] of every pair for the slack `slack_mm`.
pub(crate) fn pair_creep(
    pairs: &[(usize, usize); N_JOINTS],
    compliance_mm_per_n: &[f64; N_CABLES],
    pretension_n: &[f64; N_CABLES],
    slack_mm: &[f64; N_CABLES],
) -> [PairCreep; N_JOINTS] {
    core::array::from_fn(|p| {
        let (a, b) = pairs[p];
        let creep = slack_mm[a] + slack_mm[b];
        let c = compliance_mm_per_n[a] + compliance_mm_per_n[b];
        let t_mean = 0.5 * (pretension_n[a] + pretension_n[b]);
        if creep <= 0.0 {
            return PairCreep {
                drop_n: 0.0,
                tension_ratio: 1.0,
                excess_mm: 0.0,
            };
        }
        let drop_n = creep / c;
        PairCreep {
            drop_n,
            tension_ratio: if t_mean > 0.0 {
                (1.0 - drop_n / t_mean).max(0.0)
            } else {
                0.0
            },
            excess_mm: (creep - c * t_mean).max(0.0),
        }
    })
}
