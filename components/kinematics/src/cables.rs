//! Eq. (5), the cable drive equation, for all ten cables, and its inverse.
//!
//! Eq. (5) gives the chord a cable at offset d/2 from the neutral axis spans across one
//! hinge of a segment of n hinges bent by θ in total:
//! Δw(θ, d) = (H·n/θ − d/2) · 2 · sin(θ / 2n).
//! A cable's displacement (mm pulled in, positive = shorter path) is the sum over every
//! hinge it crosses of (H − chord), plus, for forceps cables, the pulley travel r·q. A
//! cable that drives segment 2 or a jaw also runs through segment 1 (and 2), so its path
//! changes when those bend: adding those terms is the decoupling of w5/w6 (and w7–w10)
//! the paper applies for segment-1 bending.

use crate::config::RobotConfig;
use crate::{sinc, sinc_derivative, JointsDeg, N_CABLES, N_JOINTS};

/// Eq. (5) literally: the chord across one hinge, `theta_rad` = the segment's total bend,
/// `d_mm` = twice the cable's offset from the neutral axis, `n` hinges. Exact at θ = 0
/// (where it equals H).
#[inline]
pub fn eq5_hinge_chord_mm(theta_rad: f64, d_mm: f64, h_mm: f64, n: f64) -> f64 {
    let x = theta_rad / (2.0 * n);
    // (H·n/θ)·2·sin(θ/2n) = H·sinc(θ/2n); the d term has no singularity.
    h_mm * sinc(x) - d_mm * x.sin()
}

/// Displacement (pulled in) of a cable at offset `offset_mm` over a segment of `n` hinges
/// bent by `theta_rad`: n·(H − chord), and its derivative with respect to θ.
#[inline]
fn segment_pull(theta_rad: f64, offset_mm: f64, h_mm: f64, n: f64) -> (f64, f64) {
    let x = theta_rad / (2.0 * n);
    let pull = n * (h_mm - eq5_hinge_chord_mm(theta_rad, 2.0 * offset_mm, h_mm, n));
    // d/dθ: n · (−H·sinc'(x) + 2·off·cos x) · 1/(2n)
    let dpull = 0.5 * (-h_mm * sinc_derivative(x) + 2.0 * offset_mm * x.cos());
    (pull, dpull)
}

/// Which segments a cable crosses and how it ends.
#[derive(Debug, Clone, PartialEq)]
struct Routing {
    offset_pitch_mm: f64,
    offset_yaw_mm: f64,
    crosses_segment2: bool,
    /// (jaw joint index 3 or 4, signed pulley radius) for forceps cables.
    pulley: Option<(usize, f64)>,
}

/// The ten cables of a robot config.
#[derive(Debug, Clone, PartialEq)]
pub struct CableModel {
    h_mm: f64,
    n1: f64,
    n2: f64,
    routes: [Routing; N_CABLES],
    /// For each joint, the indices of its antagonistic pair (a, b).
    pairs: [(usize, usize); N_JOINTS],
    names: [String; N_CABLES],
}

/// The inverse did not find joint angles for the given displacements.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CableError {
    #[error("cable displacement w{cable} = {value_mm} mm is not finite")]
    NotFinite { cable: usize, value_mm: f64 },
    #[error(
        "cable displacements are inconsistent with any configuration (residual {residual_mm:.3e} mm on joint q{joint})"
    )]
    NoSolution { joint: usize, residual_mm: f64 },
}

impl CableModel {
    pub fn new(cfg: &RobotConfig) -> Self {
        let routes = core::array::from_fn(|i| {
            let c = &cfg.cables[i];
            Routing {
                offset_pitch_mm: c.offset_pitch_mm,
                offset_yaw_mm: c.offset_yaw_mm,
                crosses_segment2: c.joint >= 3,
                pulley: (c.joint >= 4).then(|| (c.joint - 1, c.pulley_sign * cfg.forceps.pulley_radius_mm)),
            }
        });
        let pairs = core::array::from_fn(|j| {
            let mut it = cfg
                .cables
                .iter()
                .enumerate()
                .filter(|(_, c)| c.joint == j + 1)
                .map(|(i, _)| i);
            let a = it.next().expect("validated: two cables per joint");
            let b = it.next().expect("validated: two cables per joint");
            (a, b)
        });
        Self {
            h_mm: cfg.hinge.h_mm,
            n1: cfg.segment1.modules as f64,
            n2: cfg.segment2.modules as f64,
            routes,
            pairs,
            names: core::array::from_fn(|i| cfg.cables[i].name.clone()),
        }
    }

    pub fn names(&self) -> &[String; N_CABLES] {
        &self.names
    }

    /// The antagonistic pair (cable indices) of each joint.
    pub fn pairs(&self) -> &[(usize, usize); N_JOINTS] {
        &self.pairs
    }

    /// Displacement of one cable and its gradient with respect to q (per rad).
    fn cable(&self, i: usize, q_rad: &[f64; N_JOINTS]) -> (f64, [f64; N_JOINTS]) {
        let r = &self.routes[i];
        let mut grad = [0.0; N_JOINTS];
        // Segment 1: n1 pitch hinges (q1) and n1 yaw hinges (q2).
        let (p1, d1) = segment_pull(q_rad[0], r.offset_pitch_mm, self.h_mm, self.n1);
        let (p2, d2) = segment_pull(q_rad[1], r.offset_yaw_mm, self.h_mm, self.n1);
        let mut w = p1 + p2;
        grad[0] += d1;
        grad[1] += d2;
        if r.crosses_segment2 {
            let (p3, d3) = segment_pull(q_rad[2], r.offset_pitch_mm, self.h_mm, self.n2);
            w += p3;
            grad[2] += d3;
        }
        if let Some((jaw, radius)) = r.pulley {
            w += radius * q_rad[jaw];
            grad[jaw] += radius;
        }
        (w, grad)
    }

    /// Eq. (5) with decoupling: cable displacements (mm, + = pulled in) for `q_deg`.
    pub fn displacements_mm(&self, q_deg: &JointsDeg) -> [f64; N_CABLES] {
        let q_rad = q_deg.map(f64::to_radians);
        core::array::from_fn(|i| self.cable(i, &q_rad).0)
    }

    /// Inverse of eq. (5): joint angles from cable displacements. Each joint is set by the
    /// differential displacement of its antagonistic pair (what a pair of tendons fixes;
    /// common-mode slack does not move a joint), solved by Newton on the 5×5 system.
    /// Exact for displacements produced by [`Self::displacements_mm`].
    pub fn joints_from_displacements(&self, w_mm: &[f64; N_CABLES]) -> Result<JointsDeg, CableError> {
        for (i, &v) in w_mm.iter().enumerate() {
            if !v.is_finite() {
                return Err(CableError::NotFinite {
                    cable: i + 1,
                    value_mm: v,
                });
            }
        }
        let target: [f64; N_JOINTS] = core::array::from_fn(|j| w_mm[self.pairs[j].0] - w_mm[self.pairs[j].1]);
        let mut q = [0.0f64; N_JOINTS];
        let mut res = [0.0; N_JOINTS];
        for _ in 0..50 {
            let mut jac = nalgebra::Matrix5::<f64>::zeros();
            for j in 0..N_JOINTS {
                let (a, b) = self.pairs[j];
                let (wa, ga) = self.cable(a, &q);
                let (wb, gb) = self.cable(b, &q);
                res[j] = wa - wb - target[j];
                for k in 0..N_JOINTS {
                    jac[(j, k)] = ga[k] - gb[k];
                }
            }
            if res.iter().all(|r| r.abs() < 1e-12) {
                return Ok(q.map(f64::to_degrees));
            }
            let Some(step) = jac.lu().solve(&nalgebra::Vector5::from(res)) else {
                break;
            };
            for k in 0..N_JOINTS {
                // Keep Newton inside ±π: beyond it eq. (5) is not one-to-one.
                q[k] = (q[k] - step[k]).clamp(-std::f64::consts::PI, std::f64::consts::PI);
            }
        }
        let (joint, worst) = res
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
            .map(|(j, r)| (j + 1, r.abs()))
            .unwrap_or((1, f64::NAN));
        if worst < 1e-9 {
            return Ok(q.map(f64::to_degrees));
        }
        Err(CableError::NoSolution {
            joint,
            residual_mm: worst,
        })
    }
}
