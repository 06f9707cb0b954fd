//! `family = "lugre"`: cable-space, rate-dependent LuGre friction on elastic cables.
//!
//! Sources: C. Canudas de Wit, H. Olsson, K. J. Åström and P. Lischinsky, "A new model for
//! control of systems with friction" (IEEE Trans. Autom. Control 40(3), 1995) for the friction
//! law; M. Kaneko et al. (1996; issue #12's reference; also their earlier papers on the
//! tendon-sheath drive of robot fingers) for the capstan relation along a sheath and the
//! "apparent tendon stiffness" and "equivalent backlash" of a tendon-sheath pair; T. N. Do,
//! T. Tjahjowidodo, M. W. S. Lau and S. J. Phee, "Dynamic friction-based force feedback for
//! tendon-sheath mechanism in NOTES system", and "Nonlinear friction modelling and
//! compensation control of hysteresis phenomena for a pair of tendon-sheath actuated surgical
//! robots" (Mech. Syst. Signal Process., 2015) for LuGre/Dahl-type tendon-sheath friction and
//! the backlash of a tendon-sheath pair (the free play below; Nagarajan's and Do et al.'s
//! backlash descriptions of tendon-sheath pairs).
//!
//! Each cable i is an elastic cable of stiffness k_i = E·A/L pulled at its proximal end by the
//! command u_i (zero-order hold: the drive reaches a new command within the step) and ending
//! in a massless slider x_i, its distal end, which rubs on the sheath with LuGre friction:
//!
//!   F = σ0·z + σ1·ż + σ2·v,   ż = v − σ0·|v|·z / g(v),   g(v) = Fc + (Fs − Fc)·e^{−(v/vs)²},
//!
//! and carries the load of the joints: the tension difference ΔT = L·(y − y0) of the pairs that
//! holds the joint angles against the joint stiffness (the capstan family's statics,
//! K·q = ½·J₀ᵀ·ΔT, linearised at the straight pose: L = 2·J₀⁻ᵀ·K·G(I + C)·J₀⁻¹, y the pair
//! differences the joints see), ½·ΔT on each cable of a pair, so holding a bend costs a
//! gain loss as in the capstan family. The Coulomb level is the capstan relation
//! Fc_i = T_i·(1 − e^{−μφ_i}) with T_i the cable's tension (pre-tension plus its share of ΔT) and
//! μφ_i = μ_sheath·wrap_i + μ_body·(bend of every segment the cable crosses), so the band
//! grows with curvature; Fs = stribeck_ratio·Fc. Tension and bend are re-evaluated every
//! sub-step from the present pair differences (joint angles linearised at the straight pose,
//! q − offset ≈ G(I + C)·J₀⁻¹·(y − y0)); the plant's joint angles themselves come from the exact
//! inverse of eq. 5 at the end of the step.
//!
//! Massless slider: k(u − x) − T_load = F. With R = k(u − x) − T_load − σ0·z, substituting ż:
//! v·(σ1 + σ2) − σ1·σ0·|v|·z/g = R. Since |σ0·z| ≤ g the left side is increasing in v, so
//! sgn v = sgn R and
//!
//!   v = R / (σ1 + σ2 − sgn(R)·σ1·σ0·z/g) = R / (σ1·ρ + σ2),   ρ = 1 − sgn(R)·σ0·z/g ∈ [0, 2],
//!
//! whose denominator is ≥ σ2 > 0. Integration: fixed sub-steps h ≤ 0.25 ms (the step split
//! evenly). Each is linearly implicit in the stiff part: the slider's own restoring stiffness
//! k + k_load + σ0·ρ (dR/dx along the motion) enters as v = R / (σ1·ρ + σ2 + h·(k + k_load +
//! σ0·ρ)), which is unconditionally stable and tends to the exact v as h → 0; then x += h·v and
//! the bristle state takes an implicit Euler step of its linear ODE, z ← (z + h·v) / (1 +
//! h·σ0·|v|/g), a convex combination of z and its sliding value sgn(v)·g/σ0 (so |σ0·z| ≤ g is
//! kept). When g drops below |σ0·z| (less tension, a straightened segment) the bristles slip:
//! z is clamped to ±g/σ0. g uses v of the previous sub-step. A 1 ms step and a 0.5 s settle
//! therefore take the same sub-steps per unit of time.
//!
//! Free play: the pair difference y that reaches the joint is a play (backlash) operator of the
//! difference of the distal ends: the joint stays while the slack of the pair's terminations is
//! taken up (free_play_mm, full width, per pair).
//!
//! Cable creep (`[drift]`), as the capstan family: the distal end sits s_i further out
//! (tip = x − s), the pair's pre-tension drops by (s_a + s_b)/(c_a + c_b) (lower friction), and
//! creep beyond the pre-tension stretch widens the pair's free play.

use bowden_kinematics::{N_CABLES, N_JOINTS};
use nalgebra::{Matrix5, Vector5};

use crate::config::LugreConfig;
use crate::families::{PairCreep, Shared, BEND_JOINTS};
use crate::hysteresis::play;

/// Longest internal sub-step, s.
pub const MAX_SUBSTEP_S: f64 = 2.5e-4;
/// Friction levels below this (N) count as none.
const MIN_FRICTION_N: f64 = 1e-12;

/// Instance parameters (config + seeded variation).
#[derive(Debug, Clone)]
pub(crate) struct Params {
    /// k_i = E·A/L, N/mm.
    stiffness_n_per_mm: [f64; N_CABLES],
    sigma0: [f64; N_CABLES],
    sigma1: [f64; N_CABLES],
    sigma2: [f64; N_CABLES],
    stribeck_ratio: f64,
    inv_vs: f64,
    /// Half the free play of each pair, mm.
    half_play_mm: [f64; N_JOINTS],
    /// ΔT (N per pair) = load · (y − y0) (mm).
    load: Matrix5<f64>,
    /// ∂(load on cable i)/∂x_i = ½·load[p][p] (≥ 0), N/mm.
    load_stiffness: [f64; N_CABLES],
    /// Joint angles relative to their offsets (rad) = angles · (y − y0) (mm), linearised.
    angles: Matrix5<f64>,
    offset_rad: [f64; N_JOINTS],
    /// e^{−μ_sheath·wrap_i}.
    sheath_decay: [f64; N_CABLES],
    body_mu: f64,
    /// Whether cable i crosses bending joint j (its wrap grows with |q_j|).
    crosses: [[bool; BEND_JOINTS]; N_CABLES],
    /// Pair differences at the straight pose, mm.
    y0: [f64; N_JOINTS],
    pairs: [(usize, usize); N_JOINTS],
    pair_of: [usize; N_CABLES],
    pair_sign: [f64; N_CABLES],
}

/// The friction state of every cable and pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct State {
    /// Distal end (slider) of each cable, before creep, mm.
    pub x_mm: [f64; N_CABLES],
    /// Bristle deflection, mm.
    pub z_mm: [f64; N_CABLES],
    /// Slider velocity of the last sub-step, mm/s.
    pub v_mm_per_s: [f64; N_CABLES],
    /// Pair differences after the free play (what the joints see), mm.
    pub y_mm: [f64; N_JOINTS],
}

/// Per step inputs that do not change within the step.
pub(crate) struct StepInput<'a> {
    pub u_mm: &'a [f64; N_CABLES],
    pub slack_mm: &'a [f64; N_CABLES],
    /// Pre-tension after creep, N.
    pub pretension_n: &'a [f64; N_CABLES],
    pub creep: &'a [PairCreep; N_JOINTS],
}

impl Params {
    /// `vary()` draws one seeded relative factor; the draws are per cable σ0 (σ1 with it: the
    /// bristles' time constant σ1/σ0 is the file's) then σ2, then per pair the free play.
    pub fn new(cfg: &LugreConfig, shared: &Shared, vary: &mut dyn FnMut() -> f64) -> Self {
        let mut sigma0 = [0.0; N_CABLES];
        let mut sigma1 = [0.0; N_CABLES];
        let mut sigma2 = [0.0; N_CABLES];
        for i in 0..N_CABLES {
            let f0 = vary();
            sigma0[i] = cfg.bristle_stiffness_n_per_mm * f0;
            sigma1[i] = cfg.bristle_damping_ns_per_mm * f0;
            sigma2[i] = cfg.viscous_ns_per_mm * vary();
        }
        let half_play_mm = core::array::from_fn(|p| 0.5 * cfg.free_play_mm[p] * vary());
        // ΔT = Tm·(q − offset), q − offset ≈ G(I + C)·J0⁻¹·(y − y0).
        let angles = shared.joint_map * shared.jac_inv;
        let load = shared.tension_matrix * angles;
        let (pairs, pair_of, zero) = (shared.pairs, shared.pair_of, shared.zero_mm);
        Self {
            stiffness_n_per_mm: shared.compliance_mm_per_n.map(|c| 1.0 / c),
            sigma0,
            sigma1,
            sigma2,
            stribeck_ratio: cfg.stribeck_ratio,
            inv_vs: 1.0 / cfg.stribeck_velocity_mm_per_s,
            half_play_mm,
            load,
            load_stiffness: core::array::from_fn(|i| (0.5 * load[(pair_of[i], pair_of[i])]).max(0.0)),
            angles,
            offset_rad: *shared.offset_rad,
            sheath_decay: shared.sheath_x.map(|x| (-x).exp()),
            body_mu: shared.body_mu,
            crosses: shared.crosses.map(|row| row.map(|c| c > 0.0)),
            y0: core::array::from_fn(|p| zero[pairs[p].0] - zero[pairs[p].1]),
            pairs: *pairs,
            pair_of: *pair_of,
            pair_sign: *shared.pair_sign,
        }
    }

    /// At rest at the straight pose.
    pub fn relaxed(&self, zero_mm: &[f64; N_CABLES]) -> State {
        State {
            x_mm: *zero_mm,
            z_mm: [0.0; N_CABLES],
            v_mm_per_s: [0.0; N_CABLES],
            y_mm: self.y0,
        }
    }

    /// Advances `state` by `dt_s` under the held command; returns the sub-steps taken and
    /// writes the distal cable tensions of the last one.
    pub fn advance(&self, state: &mut State, input: &StepInput, dt_s: f64, tension_n: &mut [f64; N_CABLES]) -> u32 {
        let n = (dt_s / MAX_SUBSTEP_S).ceil().max(1.0);
        let h = dt_s / n;
        let n = n as u32;
        for _ in 0..n {
            self.substep(state, input, h, tension_n);
        }
        // The pairs as the joints see the final distal ends.
        self.update_pairs(state, input);
        n
    }

    fn substep(&self, st: &mut State, inp: &StepInput, h: f64, tension_n: &mut [f64; N_CABLES]) {
        // The joints' load and bend, from what they see at the start of the sub-step (`y`, kept
        // consistent with the distal ends by `update_pairs`).
        self.update_pairs(st, inp);
        let dy = Vector5::from(core::array::from_fn(|p| st.y_mm[p] - self.y0[p]));
        let delta_t = self.load * dy;
        // The bend the cables wrap now: e^{−μ_body·|q_j|} per bending joint.
        let dq = self.angles * dy;
        let bend_decay: [f64; BEND_JOINTS] =
            core::array::from_fn(|j| (-self.body_mu * (dq[j] + self.offset_rad[j]).abs()).exp());
        for i in 0..N_CABLES {
            let t_load = 0.5 * self.pair_sign[i] * delta_t[self.pair_of[i]];
            let tension = (inp.pretension_n[i] + t_load).max(0.0);
            tension_n[i] = tension;
            // Capstan: Fc = T·(1 − e^{−μφ}), φ the sheath's wrap plus the crossed bends.
            let mut decay = self.sheath_decay[i];
            for (crosses, d) in self.crosses[i].iter().zip(&bend_decay) {
                if *crosses {
                    decay *= d;
                }
            }
            let fc = tension * (1.0 - decay);
            let s0 = self.sigma0[i];
            let r_v = st.v_mm_per_s[i] * self.inv_vs;
            let g = if r_v.abs() < 6.0 {
                fc + (self.stribeck_ratio - 1.0) * fc * (-(r_v * r_v)).exp()
            } else {
                fc
            };
            let k = self.stiffness_n_per_mm[i];
            if g <= MIN_FRICTION_N {
                // No friction: no bristles, only the viscous term.
                let v = (k * (inp.u_mm[i] - st.x_mm[i]) - t_load) / (self.sigma2[i] + h * (k + self.load_stiffness[i]));
                st.x_mm[i] += h * v;
                st.z_mm[i] = 0.0;
                st.v_mm_per_s[i] = v;
                continue;
            }
            // Bristles slip when the friction limit drops below what they hold.
            let z_max = g / s0;
            let z = st.z_mm[i].clamp(-z_max, z_max);
            let r = k * (inp.u_mm[i] - st.x_mm[i]) - t_load - s0 * z;
            let v = slider_velocity(
                r,
                s0 * z / g,
                s0,
                self.sigma1[i],
                self.sigma2[i],
                h * (k + self.load_stiffness[i]),
                h,
            );
            st.x_mm[i] += h * v;
            st.z_mm[i] = (z + h * v) / (1.0 + h * s0 * v.abs() / g);
            st.v_mm_per_s[i] = v;
        }
    }

    /// What the joints see: the distal pair differences (after creep) through the free play.
    /// Idempotent for unchanged distal ends.
    fn update_pairs(&self, st: &mut State, inp: &StepInput) {
        for (p, &(a, b)) in self.pairs.iter().enumerate() {
            let d = (st.x_mm[a] - inp.slack_mm[a]) - (st.x_mm[b] - inp.slack_mm[b]);
            let half = self.half_play_mm[p] + 0.5 * inp.creep[p].excess_mm;
            st.y_mm[p] = play(st.y_mm[p], d, half);
        }
    }

    /// Distal ends as the joints see them: after creep, with each pair's difference replaced by
    /// the one through its free play (the common mode is kept).
    pub fn tips_mm(&self, st: &State, slack_mm: &[f64; N_CABLES]) -> [f64; N_CABLES] {
        let mut tip: [f64; N_CABLES] = core::array::from_fn(|i| st.x_mm[i] - slack_mm[i]);
        for (p, &(a, b)) in self.pairs.iter().enumerate() {
            let shift = 0.5 * (st.y_mm[p] - (tip[a] - tip[b]));
            tip[a] += shift;
            tip[b] -= shift;
        }
        tip
    }
}

/// The massless slider's velocity for the net force R = k(u − x) − T_load − σ0·z and the
/// bristle load ratio ζ = σ0·z/g ∈ [−1, 1]: v = R / (σ1·ρ + σ2 + h_k + h·σ0·ρ) with
/// ρ = 1 − sgn(R)·ζ. `h_k` = h·(k + k_load) and `h` make it linearly implicit over a sub-step of
/// length h; h = 0 gives the exact v of the module docs.
#[inline]
fn slider_velocity(r: f64, zeta: f64, s0: f64, s1: f64, s2: f64, h_k: f64, h: f64) -> f64 {
    let sg = if r > 0.0 {
        1.0
    } else if r < 0.0 {
        -1.0
    } else {
        0.0
    };
    let rho = (1.0 - sg * zeta).clamp(0.0, 2.0);
    r / (s1 * rho + s2 + h_k + h * s0 * rho)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn massless_slider_velocity_balances_the_lugre_force() {
        let (s0, s1, s2, g) = (100.0, 0.2, 0.08, 2.0);
        for r in [-3.0, -0.5, -1e-6, 0.0, 1e-6, 0.7, 4.0] {
            for zeta in [-1.0, -0.6, 0.0, 0.3, 1.0] {
                let z = zeta * g / s0;
                let v = slider_velocity(r, zeta, s0, s1, s2, 0.0, 0.0);
                // σ0·z + σ1·ż + σ2·v = σ0·z + R, with ż = v − σ0·|v|·z/g.
                let z_dot = v - s0 * v.abs() * z / g;
                assert!((s1 * z_dot + s2 * v - r).abs() < 1e-12, "r {r} zeta {zeta}");
                assert!(v * r >= 0.0, "moves with the net force");
                assert!(v.abs() <= r.abs() / s2 + 1e-12, "denominator ≥ σ2");
            }
        }
    }

    #[test]
    fn implicit_substep_tends_to_the_exact_velocity() {
        let exact = slider_velocity(1.3, 0.4, 100.0, 0.2, 0.08, 0.0, 0.0);
        let coarse = slider_velocity(1.3, 0.4, 100.0, 0.2, 0.08, 4.8 * 2.5e-4, 2.5e-4);
        let fine = slider_velocity(1.3, 0.4, 100.0, 0.2, 0.08, 4.8 * 1e-7, 1e-7);
        assert!(coarse < fine && fine < exact);
        assert!((fine - exact).abs() < 1e-4 * exact);
    }
}
