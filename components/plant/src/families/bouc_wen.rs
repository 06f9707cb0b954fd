//! `family = "bouc-wen"`: joint-space, rate-independent, asymmetric Bouc–Wen hysteresis.
//!
//! Sources: R. Bouc, "Forced vibration of mechanical systems with hysteresis" (Proc. 4th Conf.
//! on Nonlinear Oscillation, Prague, 1967); Y.-K. Wen, "Method for random vibration of
//! hysteretic systems" (J. Eng. Mech. Div. ASCE 102(2), 1976); M. Ismail, F. Ikhouane and
//! J. Rodellar, "The hysteresis Bouc–Wen model, a survey" (Arch. Comput. Methods Eng. 16, 2009)
//! for the rate-independent form, the parameter classes and their stability; J. Song and
//! A. Der Kiureghian, "Generalized Bouc–Wen model for highly asymmetric hysteresis" (J. Eng.
//! Mech. 132(6), 2006) for the asymmetric extension.
//!
//! Per joint k the input x is the joint command decoded from the cable command (inverse of
//! eq. 5) and the hysteretic angle lags it by λ_k = W·ζ_k:
//!
//!   q_h = x − λ,   dζ = (dx / W)·(A − |ζ|ⁿ·(β·sgn(dx·ζ) + γ)),   A = 1, β + γ = 1.
//!
//! Written for λ: dλ/dx = 1 − |λ/W|ⁿ·(β·sgn(dx·λ) + γ), so dq_h/dx = |λ/W|ⁿ·(β·sgn(dx·λ) + γ).
//! Moving on (dx·λ > 0) λ saturates at |λ| = W where dq_h/dx = β + γ = 1: a lag of W. Right
//! after a reversal (dx·λ < 0, |λ| = W) dq_h/dx = γ − β, which is 0 for β = γ = ½: the joint
//! stands still while the command crosses the band (the backlash-like dead band of a friction
//! drive), λ runs through 0 linearly over a command change of W, and then dq_h/dx rises
//! smoothly back to 1 as |λ| → W (sharper for larger n). γ ≥ β keeps dq_h/dx ≥ 0 (a joint
//! never moves against its command); validation enforces it.
//!
//! Asymmetry: W is W_up while λ > 0 (lagging an increasing command) and W_down while λ < 0.
//! The switch happens where λ = 0, where |λ/W|ⁿ = 0 for either width, so the law stays
//! continuous. This is the asymmetry of Song & Der Kiureghian's generalised model in a simpler
//! form: there extra shape parameters multiply sign functions of dx, ζ and x; here the width
//! depends on sgn ζ, which keeps the dead band after a reversal exact on both sides.
//!
//! Both widths grow with the bend of the bending joints q1..q3 (cables crossing a bent segment
//! rub on its hinge edges, as the capstan family's wrap does): W = W₀·(1 + Σ_c w_kc·|q_h,c|),
//! |q_h,c| in rad, with q_h of the proximal joints taken along the integration path.
//!
//! Cable creep (`[drift]`), per antagonistic pair, reasoned as the capstan family does:
//! - the pair's creep first relaxes its pre-tension; sheath friction scales with tension
//!   (capstan), so both widths scale with the remaining fraction of the pair's pre-tension;
//! - creep beyond the pre-tension stretch is slack: a free play of that width in the pair
//!   difference, which lets the joint float by half of it either way: W_up and W_down both grow
//!   by ½·excess / J_kk (J the pair-difference Jacobian of eq. 5 at the straight pose, mm/rad);
//! - the distal ends sit s_a and s_b further out, so the joint is offset by −J⁻¹·(s_a − s_b).
//!
//! When a width shrinks (drift, a straightening segment) λ is clamped into the new band: the
//! friction can no longer hold the excess lag and the joint springs toward its command.
//!
//! Integration: the path from the previous command to the new one is a straight line in joint
//! space, cut into m equal sub-steps with m = max_k ⌈|Δx_k| / (0.05·W_min,k)⌉ (W_min,k the
//! narrowest band joint k can have under the present creep), each taken with the midpoint
//! rule. m depends only on the command change, never on dt: the model is rate-independent,
//! and one large command and the same command reached in small increments agree to the
//! integration error (≪ 0.1° for the shipped file).

use bowden_kinematics::{JointsDeg, N_JOINTS};
use nalgebra::Matrix5;

use crate::config::BoucWenConfig;

/// Sub-step length as a fraction of the narrowest band.
const STEP_FRACTION: f64 = 0.05;
/// Bands narrower than this (deg) count as none: λ = 0.
const MIN_WIDTH_DEG: f64 = 1e-3;
/// At most this many sub-steps per step (a full-range jump of the narrowest valid band needs
/// fewer; the clamp keeps λ bounded regardless).
const MAX_SUBSTEPS: usize = 20_000;

/// Instance parameters (config + seeded variation).
#[derive(Debug, Clone)]
pub(crate) struct Params {
    width_up_deg: [f64; N_JOINTS],
    width_down_deg: [f64; N_JOINTS],
    exponent: f64,
    beta: f64,
    gamma: f64,
    widening_per_rad: [[f64; 3]; N_JOINTS],
    /// q_e = elastic · q_h (rad): the stretch of the pairs under the joint stiffness.
    pub elastic: Matrix5<f64>,
    /// J0⁻¹: joint angles (rad) per pair difference (mm), at the straight pose.
    pub jac_inv: Matrix5<f64>,
    /// Diagonal of J0, mm/rad.
    pub lever_mm: [f64; N_JOINTS],
}

/// The hysteretic state: each joint's lag behind its command, deg.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct State {
    pub lag_deg: [f64; N_JOINTS],
}

impl State {
    pub fn relaxed() -> Self {
        Self {
            lag_deg: [0.0; N_JOINTS],
        }
    }
}

/// How creep changes each joint's band this step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Creep {
    /// Factor on both widths (remaining pre-tension fraction), per joint.
    pub width_scale: [f64; N_JOINTS],
    /// Added to both widths (half the pair's free play, as a joint angle), deg.
    pub extra_deg: [f64; N_JOINTS],
}

impl Creep {
    /// No creep: the band is the file's.
    pub const NONE: Creep = Creep {
        width_scale: [1.0; N_JOINTS],
        extra_deg: [0.0; N_JOINTS],
    };

    fn is_active(&self) -> bool {
        *self != Self::NONE
    }
}

impl Params {
    /// `vary()` draws one seeded relative factor; the draws are per joint: W_up, W_down, then
    /// the widening row.
    pub fn new(
        cfg: &BoucWenConfig,
        elastic: Matrix5<f64>,
        jac_inv: Matrix5<f64>,
        lever_mm: [f64; N_JOINTS],
        vary: &mut dyn FnMut() -> f64,
    ) -> Self {
        let mut width_up_deg = [0.0; N_JOINTS];
        let mut width_down_deg = [0.0; N_JOINTS];
        let mut widening_per_rad = [[0.0; 3]; N_JOINTS];
        for k in 0..N_JOINTS {
            width_up_deg[k] = cfg.width_up_deg[k] * vary();
            width_down_deg[k] = cfg.width_down_deg[k] * vary();
            let f = vary();
            widening_per_rad[k] = cfg.widening_per_rad[k].map(|w| w * f);
        }
        Self {
            width_up_deg,
            width_down_deg,
            exponent: cfg.exponent,
            beta: cfg.beta,
            gamma: cfg.gamma,
            widening_per_rad,
            elastic,
            jac_inv,
            lever_mm,
        }
    }

    /// The two widths of joint k (deg) at the bend `bend_rad` of q1..q3.
    #[inline]
    fn widths(&self, k: usize, bend_rad: &[f64; 3], creep: &Creep) -> (f64, f64) {
        let mut grow = 1.0;
        for (w, b) in self.widening_per_rad[k].iter().zip(bend_rad) {
            grow += w * b;
        }
        let s = creep.width_scale[k] * grow;
        (
            self.width_up_deg[k] * s + creep.extra_deg[k],
            self.width_down_deg[k] * s + creep.extra_deg[k],
        )
    }

    /// dλ for a command change `dx` (deg) at lag `lag` with the band (w_up, w_down).
    #[inline]
    fn dlag(&self, lag: f64, dx: f64, w_up: f64, w_down: f64) -> f64 {
        let w = if lag > 0.0 { w_up } else { w_down };
        if w < MIN_WIDTH_DEG {
            return dx;
        }
        let r = (lag / w).abs().powf(self.exponent);
        let s = if dx * lag > 0.0 {
            1.0
        } else if dx * lag < 0.0 {
            -1.0
        } else {
            0.0
        };
        dx * (1.0 - r * (self.beta * s + self.gamma))
    }

    /// Moves the lags along the straight command path `x0` → `x1` (deg). Returns the number
    /// of sub-steps taken (0 for a held command).
    // Per-joint loops index several arrays in step; they read like the maths.
    #[allow(clippy::needless_range_loop)]
    pub fn advance(&self, state: &mut State, x0: &JointsDeg, x1: &JointsDeg, creep: &Creep) -> u32 {
        let dx: [f64; N_JOINTS] = core::array::from_fn(|k| x1[k] - x0[k]);
        let mut m = 0usize;
        for k in 0..N_JOINTS {
            if dx[k] != 0.0 {
                let w_min =
                    self.width_up_deg[k].min(self.width_down_deg[k]) * creep.width_scale[k] + creep.extra_deg[k];
                let h = STEP_FRACTION * w_min.max(MIN_WIDTH_DEG);
                m = m.max((dx[k].abs() / h).ceil() as usize);
            }
        }
        let m = m.min(MAX_SUBSTEPS);
        let lag = &mut state.lag_deg;
        for s in 0..m {
            let t = s as f64 / m as f64;
            let bend: [f64; 3] = core::array::from_fn(|c| (x0[c] + t * dx[c] - lag[c]).abs().to_radians());
            for k in 0..N_JOINTS {
                let d = dx[k] / m as f64;
                if d == 0.0 {
                    continue;
                }
                let (wu, wd) = self.widths(k, &bend, creep);
                let mid = lag[k] + 0.5 * self.dlag(lag[k], d, wu, wd);
                lag[k] = (lag[k] + self.dlag(mid, d, wu, wd)).clamp(-wd, wu);
            }
        }
        // Creep narrows the band with time, also under a held command: the lag cannot exceed
        // it. (Without creep the sub-steps have clamped already, and a held command must
        // change nothing, however many steps it is held for.)
        if creep.is_active() {
            let bend: [f64; 3] = core::array::from_fn(|c| (x1[c] - lag[c]).abs().to_radians());
            for k in 0..N_JOINTS {
                let (wu, wd) = self.widths(k, &bend, creep);
                lag[k] = if wu.max(wd) < MIN_WIDTH_DEG {
                    0.0
                } else {
                    lag[k].clamp(-wd, wu)
                };
            }
        }
        m as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(n: f64, beta: f64) -> Params {
        let cfg = BoucWenConfig {
            width_up_deg: [10.0; N_JOINTS],
            width_down_deg: [6.0; N_JOINTS],
            exponent: n,
            beta,
            gamma: 1.0 - beta,
            widening_per_rad: [[0.0; 3]; N_JOINTS],
        };
        Params::new(
            &cfg,
            Matrix5::identity(),
            Matrix5::identity(),
            [1.0; N_JOINTS],
            &mut || 1.0,
        )
    }

    const NO_CREEP: Creep = Creep::NONE;

    fn walk(p: &Params, st: &mut State, from: f64, to: f64, step: f64) -> Vec<(f64, f64)> {
        let n = ((to - from).abs() / step).round() as usize;
        let mut out = Vec::new();
        for i in 1..=n {
            let a = from + (to - from) * (i - 1) as f64 / n as f64;
            let b = from + (to - from) * i as f64 / n as f64;
            p.advance(st, &[a; N_JOINTS], &[b; N_JOINTS], &NO_CREEP);
            out.push((b, b - st.lag_deg[0]));
        }
        out
    }

    #[test]
    fn saturates_at_the_asymmetric_widths_with_a_dead_band_after_reversal() {
        let p = params(4.0, 0.5);
        let mut st = State::relaxed();
        walk(&p, &mut st, 0.0, 60.0, 1.0);
        assert!((st.lag_deg[0] - 10.0).abs() < 0.05, "lag up {}", st.lag_deg[0]);
        // Reversal: the output stands still while the command comes back by ~W_up.
        let q_top = 60.0 - st.lag_deg[0];
        let down = walk(&p, &mut st, 60.0, 0.0, 0.5);
        for &(x, q) in down.iter().take_while(|(x, _)| *x >= 51.0) {
            assert!((q - q_top).abs() < 1e-9, "dead band at x = {x}: {q} vs {q_top}");
        }
        assert!((st.lag_deg[0] + 6.0).abs() < 0.05, "lag down {}", st.lag_deg[0]);
        // Monotone: the output never moves against the command.
        let up = walk(&p, &mut st, 0.0, 30.0, 0.7);
        assert!(up.windows(2).all(|w| w[1].1 >= w[0].1 - 1e-12));
    }

    #[test]
    fn one_jump_equals_many_small_steps() {
        let p = params(2.0, 0.5);
        let mut a = State::relaxed();
        let mut b = State::relaxed();
        p.advance(&mut a, &[0.0; N_JOINTS], &[25.0; N_JOINTS], &NO_CREEP);
        p.advance(&mut a, &[25.0; N_JOINTS], &[-13.0; N_JOINTS], &NO_CREEP);
        walk(&p, &mut b, 0.0, 25.0, 0.1);
        walk(&p, &mut b, 25.0, -13.0, 0.1);
        assert!((a.lag_deg[0] - b.lag_deg[0]).abs() < 0.02, "{:?} vs {:?}", a, b);
    }

    #[test]
    fn shrinking_band_clamps_the_lag() {
        let p = params(2.0, 0.5);
        let mut st = State::relaxed();
        walk(&p, &mut st, 0.0, 40.0, 1.0);
        let half = Creep {
            width_scale: [0.5; N_JOINTS],
            extra_deg: [0.0; N_JOINTS],
        };
        p.advance(&mut st, &[40.0; N_JOINTS], &[40.0; N_JOINTS], &half);
        assert!(st.lag_deg[0] <= 5.0 + 1e-12);
    }
}
