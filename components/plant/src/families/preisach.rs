//! `family = "preisach"`: joint-space friction lag of a population of stick–slip contacts,
//! classical Preisach hysteresis (a weighted grid of relay hysterons) with a non-uniform
//! density, gross sliding, and a rate-dependent delayed slip.
//!
//! Sources: F. Preisach, "Über die magnetische Nachwirkung" (Z. Physik 94, 1935) for the model;
//! I. D. Mayergoyz, "Mathematical Models of Hysteresis" (Springer, 1991) for its relay
//! formulation on the half plane α ≥ β, the staircase memory and the two properties that
//! characterise it (wiping-out and congruent minor loops); D. H. Everett's papers on hysteresis
//! (Trans. Faraday Soc., 1954–55) for the Everett function (the population of a region of the
//! plane), which sets the relay weights; G. Bertotti, "Hysteresis in Magnetism" (Academic Press,
//! 1998) for the factorised density in interaction and coercivity coordinates with a lognormal
//! coercivity distribution; M. W. Gutowski, "On the symmetry of a Preisach map" (2005,
//! cond-mat/0506176) for dropping the density's mirror symmetry; J. Swevers, F. Al-Bender,
//! C. Ganseman & T. Prajogo, "An integrated friction model structure with improved presliding
//! behavior" (IEEE Trans. Automatic Control 45, 2000) and F. Al-Bender, V. Lampaert & J.
//! Swevers (Tribology Letters 16, 2004) for friction as pre-sliding hysteresis with nonlocal
//! (Preisach-type) memory in the load that ends in gross sliding; C. Zener, "Elasticity and
//! Anelasticity of Metals" (1948) for the standard linear solid of the delayed slip; J. H.
//! Dieterich (J. Geophys. Res. 84, 1979) and T. Baumberger & C. Caroli ("Solid friction from
//! stick–slip down to pinning and aging", Adv. Phys. 55, 2006) for the creep of frictional
//! contacts loaded just below their threshold.
//!
//! # The contacts and the load they hold
//! Per joint k a population of stick–slip contacts between the cable and the turns of the coil
//! sheath or a hinge edge. The cable between the drive and the contacts stretches by the load u
//! they hold back (in degrees of joint command). A contact holds until the load rises past its
//! breakaway level α, then lets go forward, and holds again until the load falls below β ≤ α,
//! then lets go back: a Preisach relay γ_αβ ∈ {−1, +1} on the load, carrying a fixed share of
//! the joint's pre-sliding travel. Once the load reaches ±X every contact has let go and the
//! cable slides through them: the load stays at ±X while the command goes on. With c the
//! position the cable has slid to, at the end of each monotone change of the input v (a play
//! operator; the load is the matching stop operator)
//!
//!   c ← clamp(c, v − X, v + X),   u = v − c,   X = `lag_amplitude_deg` + `presliding_deg` (G + L).
//!
//! In the interaction/coercivity coordinates
//!
//!   h_c = (α − β)/2  (coercivity: half the contact's own dead band, its friction),
//!   h_u = (α + β)/2  (interaction: the load the contact rests at, neither way),
//!
//! the population density is factorised, μ = f_c(h_c)·f_u(h_u): f_c lognormal (median m,
//! log-sd s: friction levels are products of many positive factors) and f_u a split normal
//! with mode 0 and different widths σ₊ above and σ₋ below (contacts on the loaded side of the
//! sheath's loop hold more load one way than the other). A coercivity near X concentrates the
//! breakaway just before gross sliding: a sharp knee; σ₊ ≠ σ₋ makes the knees after an upward
//! and after a downward reversal different shapes (not point images of each other).
//!
//! # Output: a bounded friction lag
//! The joint is where the cable has slid to plus the pre-sliding travel the contacts have let
//! through:
//!
//!   q_h = c + L·(P − P₀),   lag ℓ = v − q_h = u − L·(P − P₀),
//!
//! P = Σ w_ij·s_ij ∈ [−1, 1] (below), L = `presliding_deg`, P₀ the output of the assembled state
//! (c = u = 0, the demagnetised staircase along α + β = 0: the robot is assembled straight and its
//! contacts settle around that pose), so the straight command gives q_h = 0 exactly. After a
//! reversal the load swings across; the joint stands where no contact lets go (dq/dv = 0),
//! moves briskly where the bulk does (dq/dv = L·dP/du), and once the load reaches ±X it follows
//! its command one to one, the lag fixed at ±G + L·P₀ (G = `lag_amplitude_deg`, the lag once
//! every contact slips): a flat stuck band, then unit slope, the knee set by the density.
//!
//! The lag lives on the load, not on the command. A Preisach output of the command has its
//! ascending branch below the descending one; a lag v − L·P of the command would put the rising
//! joint above the falling one (the joint leading its command after a reversal, and reversing
//! at once with it wherever no relay sits). Contacts that break away on the load they hold —
//! relative to where the cable last slid — make the lag change sign at every reversal, wherever
//! it happens, and never let the joint lead.
//!
//! # Bounds
//! With the cell update below, on a monotone excursion s_ij = max(s₀, r(u − α_i)) going up and
//! min(s₀, r(u − β_j)) going down, and r's slope 2/Δ is non-zero only within Δ/2 of the level:
//! at any load one row (α = a_i, all j ≤ i) moves going up, one column (β = a_j, all i ≥ j)
//! going down. So along any monotone input
//!
//!   0 ≤ dP/du ≤ b = (2/Δ)·max(max_i Σ_j≤i w_ij, max_j Σ_i≥j w_ij),
//!
//! attained on a sweep from saturation. Hence dq/dv ∈ [0, max(1, L·b)]: the joint never moves
//! against its input, whatever L; and with L·b ≤ 1, checked on load and again for each unit
//! (after its variation: [`BreakawayBoundError`]), it never outruns it either: the lag grows
//! in the direction of motion and stays within |ℓ − L·P₀| ≤ G (at u = ±X, P = ±1; and
//! ℓ(X) − ℓ(u) = (X − u) − L·(1 − P(u)) ≥ (1 − L·b)·(X − u) ≥ 0). The joint follows its command
//! over the whole range, joint limits and jaw contact being the plant's.
//!
//! # The grid
//! The half plane is cut to the triangle −X ≤ β ≤ α ≤ X on a [`LEVELS`] × [`LEVELS`] grid of
//! levels a_i = X·(−1 + (2i + 1)/LEVELS), spacing Δ = 2X/LEVELS: relay (i, j), i ≥ j, has
//! α = a_i, β = a_j ([`RELAYS`] per joint, a fixed array). Its weight w_ij is the population of
//! its cell, the square |α − a_i|, |β − a_j| ≤ Δ/2 (a diamond in (h_u, h_c); on the diagonal its
//! half with α ≥ β): an increment of the Everett function, integrated exactly in h_u (the split
//! normal's CDF) and in slices of h_c (the lognormal's CDF), then normalised to Σ w = 1 (the
//! density truncated to the grid: at u = ±X every relay has switched).
//!
//! A cell's population is carried by its relays spread evenly along the interaction direction
//! (α and β shifted together by ε ∈ [−Δ/2, Δ/2]). The mean state of those relays is exactly
//!
//!   s ← min(max(s, r(u − α)), r(u − β)),   r(z) = clamp(2z/Δ, −1, 1),
//!
//! for any monotone load excursion ending at u (the switched relays are always those with ε
//! below a bound, so the mean is the relays' fraction). So the output is continuous and
//! piecewise linear in the load, not a staircase, and the model is still a classical Preisach
//! model (its density is the weights smeared along those segments), with the wiping-out and
//! congruency properties; the stop operator before it has return-point memory too, so a minor
//! loop of the command that returns to its turning point leaves the state as it was. The
//! diagonal cells (α = β) are reversible: s = r(u − a_i).
//!
//! # Why joint space
//! The lag is the joint's (the contacts hold the joint back), and the capstan and LuGre families
//! already model friction per cable. Per antagonistic pair would be the alternative, but the
//! w5/w6 pair also carries segment 1's bend (eq. 5's decoupling term is as large as q3's own):
//! an operator on the pair difference would make q3 lag whenever segment 1 bends. And a
//! Preisach density is what one identifies from measured (q_cmd, q_phy) pairs, the paper's data
//! (Table IV, Fig. 9b): in degrees of the joint it reads directly as loop shape. Coupling
//! between joints is the plant's residual coupling matrix, shared by every family.
//!
//! # Delayed slip (rate dependence)
//! A contact loaded to just below its breakaway level does not hold it forever: its asperity
//! junctions in the polymer liner creep (Dieterich; Baumberger & Caroli), the solid-friction
//! counterpart of the thermally activated magnetic after-effect Preisach's 1935 paper is about.
//! Modelled in its simplest bounded form, one time constant: the contacts feel the command
//! through a standard linear solid (the sheath's liner), a share 1 − κ of a command change at
//! once and the rest κ relaxing in with τ. With the Maxwell-arm deflection e (deg of command),
//!
//!   de/dt = dx/dt − e/τ,   v = x − κ·e,
//!
//! the stop and the relays see v instead of the command x. Under a held command v → x
//! exponentially: while the cable slides the joint creeps on toward its command by the rest of
//! the change, exactly with τ; while the contacts hold it, by what they let go late (nothing
//! right after a reversal), and stops after a few τ. Faster commands leave more of the change
//! in the arm when the joint is read. Unlike the settling (`[dynamics]`, a linear lag of the
//! output), this relaxation switches relays (it is itself hysteretic); unlike `[drift]` (cable
//! creep over hours, away from the command) it is bounded and toward the command; unlike
//! LuGre's viscous and Stribeck terms it acts after the drive has stopped.
//!
//! The command is held over a step (zero-order hold, as for `lugre`): x jumps at its start, so
//! e jumps by Δx and then decays, e ← (e + Δx)·e^{−dt/τ}. v therefore moves monotonically from
//! its last value to v₀ = x − κ(e + Δx) and then monotonically to v₁ = x − κ·e·e^{−dt/τ}; the
//! stop and a relay update at the end of each monotone segment are exact, so a step is exact
//! for any dt. κ = 0 makes the model rate-independent.
//!
//! # Cable creep (`[drift]`)
//! As the `bouc-wen` family reasons: the pair's creep first relaxes its pre-tension, and the
//! contacts' friction scales with it: with the remaining fraction c every breakaway level, the
//! slide level and the pre-sliding travel scale by c (the grid is read at u/c, the stop clamps
//! at ±c·X, the output uses c·L; the bound L·b ≤ 1 is unchanged), so relays whose narrowed band
//! no longer holds them switch and a load beyond the new slide level slips: the joint springs
//! toward its command. Creep beyond the pre-tension stretch is free play, a play operator of
//! half its width (as a joint angle) on the command before the contacts; and the joint shifts
//! by −J₀⁻¹·(s_a − s_b).

use bowden_kinematics::{JointsDeg, N_JOINTS};
use nalgebra::Matrix5;

use crate::config::PreisachConfig;
use crate::hysteresis::play;

/// Threshold levels of each joint's grid.
pub const LEVELS: usize = 16;
/// Relays per joint: the triangle i ≥ j of the grid, diagonal included.
pub const RELAYS: usize = LEVELS * (LEVELS + 1) / 2;
/// Coercivity slices per cell when integrating its population.
const SLICES: usize = 16;

/// Packed index of relay (i, j), j ≤ i.
#[inline]
pub(crate) fn relay_index(i: usize, j: usize) -> usize {
    i * (i + 1) / 2 + j
}

/// A unit whose contacts would carry a joint faster than its command: the pre-sliding travel L
/// times the steepest breakaway rate b of the (varied) density exceeds 1 (see the module docs,
/// "Bounds").
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "joint q{} ([preisach] presliding_deg[{joint}]): presliding_deg {presliding_deg:.4} deg × steepest breakaway rate {rate_per_deg:.6} per deg = {product:.4} > 1 after the unit's variation: where the contacts let go the joint would outrun its command; lower presliding_deg or spread the contact density (coercivity_median_deg, coercivity_log_sd, interaction_sd_positive_deg, interaction_sd_negative_deg)",
    .joint + 1
)]
pub struct BreakawayBoundError {
    /// Joint index (0 = q1).
    pub joint: usize,
    /// L of this unit, deg.
    pub presliding_deg: f64,
    /// b of this unit's density, per deg of load.
    pub rate_per_deg: f64,
    /// L·b.
    pub product: f64,
}

/// Instance parameters (config + seeded variation).
#[derive(Debug, Clone)]
pub(crate) struct Params {
    /// Threshold levels a_i of each joint, deg of load: relay (i, j) switches up at a_i, down
    /// at a_j.
    level_deg: [[f64; LEVELS]; N_JOINTS],
    /// 2/Δ of each joint, per deg: a cell's relays switch over one level spacing.
    ramp_per_deg: [f64; N_JOINTS],
    /// Relay weights (Σ = 1 per joint), packed by [`relay_index`].
    weight: [[f64; RELAYS]; N_JOINTS],
    /// X = G + L of each joint: the load at which every contact has let go, deg.
    slide_deg: [f64; N_JOINTS],
    /// L of each joint, deg.
    presliding_deg: [f64; N_JOINTS],
    /// P of the assembled state, per joint: the straight command's output is the zero.
    zero_output: [f64; N_JOINTS],
    /// κ: the share of a command change the contacts feel only after the relaxation.
    relaxation_fraction: f64,
    /// τ of each joint's sheath, s.
    relaxation_time_s: [f64; N_JOINTS],
    /// J0⁻¹: joint angles (rad) per pair difference (mm), at the straight pose.
    pub jac_inv: Matrix5<f64>,
    /// Diagonal of J0, mm/rad.
    pub lever_mm: [f64; N_JOINTS],
}

/// The hysteretic state of every joint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct State {
    /// Mean state of each relay cell, in [−1, 1], packed by [`relay_index`].
    pub relay: [[f64; RELAYS]; N_JOINTS],
    /// The command after the free play, deg.
    pub input_deg: [f64; N_JOINTS],
    /// Maxwell-arm deflection e: the part of the command changes not yet felt, deg.
    pub arm_deg: [f64; N_JOINTS],
    /// c: where the cable has slid to through the contacts (the play of the input; the load
    /// they hold is u = v − c), deg.
    pub carrier_deg: [f64; N_JOINTS],
}

/// How cable creep changes each joint's contacts this step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Creep {
    /// Factor on every breakaway level, the slide level and the pre-sliding travel (remaining
    /// pre-tension fraction, in [0, 1]), per joint.
    pub width_scale: [f64; N_JOINTS],
    /// Half-width of the free play before the contacts (half the pair's slack as a joint
    /// angle), deg.
    pub play_deg: [f64; N_JOINTS],
}

impl Creep {
    /// No creep: the contacts are the file's.
    pub const NONE: Creep = Creep {
        width_scale: [1.0; N_JOINTS],
        play_deg: [0.0; N_JOINTS],
    };

    fn is_active(&self) -> bool {
        *self != Self::NONE
    }
}

/// What [`Params::advance`] did: the hysteretic angles and how many grid passes it took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Advance {
    /// q_h of each joint, deg.
    pub angle_deg: [f64; N_JOINTS],
    /// Relay-grid updates over all joints (0 when nothing moved).
    pub passes: u32,
}

/// The density's parameters for one joint (after the seeded variation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Density {
    /// X: the grid spans loads in [−X, X], deg.
    pub slide_deg: f64,
    /// Median of the lognormal coercivity, deg.
    pub coercivity_median_deg: f64,
    /// Standard deviation of ln h_c.
    pub coercivity_log_sd: f64,
    /// Widths of the split-normal interaction above and below its mode (0), deg.
    pub interaction_sd_positive_deg: f64,
    pub interaction_sd_negative_deg: f64,
}

impl Density {
    /// The file's nominal density of joint k.
    pub fn nominal(cfg: &PreisachConfig, k: usize) -> Self {
        Self {
            slide_deg: cfg.lag_amplitude_deg[k] + cfg.presliding_deg[k],
            coercivity_median_deg: cfg.coercivity_median_deg[k],
            coercivity_log_sd: cfg.coercivity_log_sd,
            interaction_sd_positive_deg: cfg.interaction_sd_positive_deg[k],
            interaction_sd_negative_deg: cfg.interaction_sd_negative_deg[k],
        }
    }
}

impl Params {
    /// `vary()` draws one seeded relative factor; the draws are per joint: the lag amplitude,
    /// the pre-sliding travel, the coercivity median, the two interaction widths, the
    /// relaxation time. Refuses a unit whose varied L·b exceeds 1 (the first such joint).
    pub fn new(
        cfg: &PreisachConfig,
        jac_inv: Matrix5<f64>,
        lever_mm: [f64; N_JOINTS],
        vary: &mut dyn FnMut() -> f64,
    ) -> Result<Self, BreakawayBoundError> {
        let mut level_deg = [[0.0; LEVELS]; N_JOINTS];
        let mut ramp_per_deg = [0.0; N_JOINTS];
        let mut weight = [[0.0; RELAYS]; N_JOINTS];
        let mut slide_deg = [0.0; N_JOINTS];
        let mut presliding_deg = [0.0; N_JOINTS];
        let mut relaxation_time_s = [0.0; N_JOINTS];
        for k in 0..N_JOINTS {
            let lag = cfg.lag_amplitude_deg[k] * vary();
            presliding_deg[k] = cfg.presliding_deg[k] * vary();
            slide_deg[k] = lag + presliding_deg[k];
            let density = Density {
                slide_deg: slide_deg[k],
                coercivity_median_deg: cfg.coercivity_median_deg[k] * vary(),
                coercivity_log_sd: cfg.coercivity_log_sd,
                interaction_sd_positive_deg: cfg.interaction_sd_positive_deg[k] * vary(),
                interaction_sd_negative_deg: cfg.interaction_sd_negative_deg[k] * vary(),
            };
            relaxation_time_s[k] = cfg.relaxation_time_s * vary();
            level_deg[k] = levels(slide_deg[k]);
            ramp_per_deg[k] = LEVELS as f64 / slide_deg[k];
            weight[k] = everett_weights(&density);
            let rate_per_deg = max_breakaway_rate(&weight[k], slide_deg[k]);
            let product = presliding_deg[k] * rate_per_deg;
            if product.is_nan() || product > 1.0 {
                return Err(BreakawayBoundError {
                    joint: k,
                    presliding_deg: presliding_deg[k],
                    rate_per_deg,
                    product,
                });
            }
        }
        let mut params = Self {
            level_deg,
            ramp_per_deg,
            weight,
            slide_deg,
            presliding_deg,
            zero_output: [0.0; N_JOINTS],
            relaxation_fraction: cfg.relaxation_fraction,
            relaxation_time_s,
            jac_inv,
            lever_mm,
        };
        let assembled = params.relaxed();
        params.zero_output = core::array::from_fn(|k| params.output(k, &assembled.relay[k]));
        Ok(params)
    }

    /// Assembled straight: no load, the relays in the demagnetised staircase along α + β = 0
    /// (centred below zero load up, above it down, the cells on the line half and half),
    /// nothing left in the arm. Consistent with u = 0: a first update there changes nothing.
    pub fn relaxed(&self) -> State {
        let mut relay = [[0.0; RELAYS]; N_JOINTS];
        for (k, grid) in relay.iter_mut().enumerate() {
            let a = &self.level_deg[k];
            for i in 0..LEVELS {
                for j in 0..=i {
                    let centre = 0.5 * (a[i] + a[j]);
                    grid[relay_index(i, j)] = (-centre * self.ramp_per_deg[k]).clamp(-1.0, 1.0);
                }
            }
        }
        State {
            relay,
            input_deg: [0.0; N_JOINTS],
            arm_deg: [0.0; N_JOINTS],
            carrier_deg: [0.0; N_JOINTS],
        }
    }

    /// P = Σ w·s of joint k's grid, in [−1, 1] (a fixed order: equal states give equal bits).
    #[inline]
    fn output(&self, k: usize, relay: &[f64; RELAYS]) -> f64 {
        self.weight[k].iter().zip(relay).map(|(w, s)| w * s).sum()
    }

    /// Moves joint k's relays as a monotone load excursion ending at `load_deg` does, every
    /// breakaway level scaled by `scale` (the grid read at load/scale; none left at 0).
    fn switch(&self, k: usize, relay: &mut [f64; RELAYS], load_deg: f64, scale: f64) {
        if scale <= 0.0 {
            return;
        }
        let u = if scale == 1.0 { load_deg } else { load_deg / scale };
        let a = &self.level_deg[k];
        let g = self.ramp_per_deg[k];
        // r(u − a_i) once per level serves as α for row i, β for column i.
        let r: [f64; LEVELS] = core::array::from_fn(|i| ((u - a[i]) * g).clamp(-1.0, 1.0));
        let mut n = 0;
        for (i, &up) in r.iter().enumerate() {
            for &down in &r[..=i] {
                relay[n] = relay[n].max(up).min(down);
                n += 1;
            }
        }
    }

    /// One step of `dt_s` under the held joint command `q_cmd_deg` (see the module docs):
    /// free play, the command change through the standard linear solid, the stop and the
    /// relays at the end of each monotone segment of the input, the output.
    pub fn advance(&self, st: &mut State, q_cmd_deg: &JointsDeg, dt_s: f64, creep: &Creep) -> Advance {
        let kappa = self.relaxation_fraction;
        // A band that changes (creep) must be applied even to an unchanged input.
        let band_moves = creep.is_active();
        let mut passes = 0;
        let mut angle_deg = [0.0; N_JOINTS];
        for (k, angle) in angle_deg.iter_mut().enumerate() {
            let x = play(st.input_deg[k], q_cmd_deg[k], creep.play_deg[k]);
            let dx = x - st.input_deg[k];
            let scale = creep.width_scale[k];
            let slide = scale * self.slide_deg[k];
            let relay = &mut st.relay[k];
            let mut carrier = st.carrier_deg[k];
            // The change reaches the contacts: 1 − κ of it at once, the rest stays in the arm.
            let arm = st.arm_deg[k] + dx;
            let v_start = x - kappa * arm;
            if dx != 0.0 || band_moves {
                // The load u = v − c, held within ±slide (beyond, the cable slides).
                carrier = carrier.clamp(v_start - slide, v_start + slide);
                self.switch(k, relay, v_start - carrier, scale);
                passes += 1;
            }
            // … and relaxes in over the step. (Without relaxation the arm is not kept: the state
            // is then the relays', the carrier's and the input's alone, as for a rate-independent
            // model.)
            let arm_end = if kappa > 0.0 {
                arm * (-dt_s / self.relaxation_time_s[k]).exp()
            } else {
                0.0
            };
            let v_end = x - kappa * arm_end;
            if v_end != v_start {
                carrier = carrier.clamp(v_end - slide, v_end + slide);
                self.switch(k, relay, v_end - carrier, scale);
                passes += 1;
            }
            st.input_deg[k] = x;
            st.arm_deg[k] = arm_end;
            st.carrier_deg[k] = carrier;
            let presliding = scale * self.presliding_deg[k];
            *angle = carrier + presliding * (self.output(k, relay) - self.zero_output[k]);
        }
        Advance { angle_deg, passes }
    }
}

/// b: the steepest rate dP/du at which a population with weights `w` on the grid ±`slide_deg`
/// lets go along a monotone load, per deg: (2/Δ)·(the heaviest row or column of the grid).
pub(crate) fn max_breakaway_rate(w: &[f64; RELAYS], slide_deg: f64) -> f64 {
    let mut rows = [0.0; LEVELS];
    let mut columns = [0.0; LEVELS];
    for i in 0..LEVELS {
        for j in 0..=i {
            let v = w[relay_index(i, j)];
            rows[i] += v;
            columns[j] += v;
        }
    }
    let heaviest = rows.iter().chain(&columns).fold(0.0f64, |m, &v| m.max(v));
    LEVELS as f64 / slide_deg * heaviest
}

/// b of the file's nominal density of joint k (what validation checks L against).
pub(crate) fn nominal_breakaway_rate(cfg: &PreisachConfig, k: usize) -> f64 {
    let d = Density::nominal(cfg, k);
    max_breakaway_rate(&everett_weights(&d), d.slide_deg)
}

/// The grid's levels a_i (deg) for loads ±`slide_deg`.
fn levels(slide_deg: f64) -> [f64; LEVELS] {
    core::array::from_fn(|i| slide_deg * (-1.0 + (2 * i + 1) as f64 / LEVELS as f64))
}

/// Relay weights of one joint: each cell's population under the density (an increment of the
/// Everett function), normalised to Σ = 1 over the grid. Packed by [`relay_index`].
///
/// In (h_u, h_c) a cell is the diamond |h_u − u₀| + |h_c − c₀| ≤ Δ/2 around its centre
/// (u₀, c₀) = ((a_i + a_j)/2, (a_i − a_j)/2); the diagonal cells keep their half with h_c ≥ 0.
/// Integrated in SLICES slices of h_c, each the lognormal's exact mass times the split normal's
/// exact mass over the diamond's width at the slice's middle.
pub(crate) fn everett_weights(d: &Density) -> [f64; RELAYS] {
    let a = levels(d.slide_deg);
    let delta = 2.0 * d.slide_deg / LEVELS as f64;
    let slice = delta / SLICES as f64;
    let mut w = [0.0; RELAYS];
    for i in 0..LEVELS {
        for j in 0..=i {
            let (u0, c0) = (0.5 * (a[i] + a[j]), 0.5 * (a[i] - a[j]));
            let mut mass = 0.0;
            for s in 0..SLICES {
                let c_lo = c0 - 0.5 * delta + s as f64 * slice;
                let c_hi = c_lo + slice;
                if c_hi <= 0.0 {
                    continue;
                }
                let m_c = lognormal_cdf(c_hi, d) - lognormal_cdf(c_lo, d);
                let half = 0.5 * delta - (0.5 * (c_lo + c_hi) - c0).abs();
                let m_u = split_normal_cdf(u0 + half, d) - split_normal_cdf(u0 - half, d);
                // The CDFs are approximations (≈1e-7): a difference must not go negative.
                mass += (m_c * m_u).max(0.0);
            }
            w[relay_index(i, j)] = mass;
        }
    }
    let total: f64 = w.iter().sum();
    // Validation keeps the median and widths inside the grid, so the population there is a
    // sizeable fraction of the whole and `total` is far from 0.
    w.map(|m| m / total)
}

/// P(h_c ≤ c) under the lognormal coercivity.
fn lognormal_cdf(c: f64, d: &Density) -> f64 {
    if c <= 0.0 {
        return 0.0;
    }
    normal_cdf((c / d.coercivity_median_deg).ln() / d.coercivity_log_sd)
}

/// P(h_u ≤ u) under the split normal (mode 0, σ₋ below, σ₊ above; continuous density).
fn split_normal_cdf(u: f64, d: &Density) -> f64 {
    let (sp, sn) = (d.interaction_sd_positive_deg, d.interaction_sd_negative_deg);
    let below = sn / (sn + sp);
    if u < 0.0 {
        2.0 * below * normal_cdf(u / sn)
    } else {
        below + 2.0 * (1.0 - below) * (normal_cdf(u / sp) - 0.5)
    }
}

/// Φ(z), the standard normal CDF.
fn normal_cdf(z: f64) -> f64 {
    0.5 * erfc(-z * core::f64::consts::FRAC_1_SQRT_2)
}

/// The complementary error function, fractional error < 1.2e-7 everywhere (the Chebyshev fit
/// of Numerical Recipes, 2nd ed., §6.2; the standard library has none).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98 + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// X = 20 + 5 = 25 deg, coercivities around 15 deg: L·b ≈ 0.5.
    fn config(kappa: f64) -> PreisachConfig {
        PreisachConfig {
            lag_amplitude_deg: [20.0; N_JOINTS],
            presliding_deg: [5.0; N_JOINTS],
            coercivity_median_deg: [15.0; N_JOINTS],
            coercivity_log_sd: 0.5,
            interaction_sd_positive_deg: [8.0; N_JOINTS],
            interaction_sd_negative_deg: [6.0; N_JOINTS],
            relaxation_fraction: kappa,
            relaxation_time_s: 0.25,
        }
    }

    fn params(kappa: f64) -> Params {
        Params::new(&config(kappa), Matrix5::identity(), [1.0; N_JOINTS], &mut || 1.0).unwrap()
    }

    /// b of joint 1.
    fn rate(p: &Params) -> f64 {
        max_breakaway_rate(&p.weight[0], p.slide_deg[0])
    }

    /// Joint 1 (index 0) driven through `path`, each command held `dt` (one step).
    fn drive(p: &Params, st: &mut State, path: &[f64], dt: f64) -> Vec<f64> {
        path.iter()
            .map(|&x| p.advance(st, &[x; N_JOINTS], dt, &Creep::NONE).angle_deg[0])
            .collect()
    }

    /// `from` → `to` in steps of `step` (both ends included).
    fn ramp(from: f64, to: f64, step: f64) -> Vec<f64> {
        let n = ((to - from).abs() / step).round() as usize;
        (0..=n).map(|i| from + (to - from) * i as f64 / n as f64).collect()
    }

    #[test]
    fn erfc_matches_reference_values() {
        // erfc to 10 digits (Abramowitz & Stegun, table 7.1).
        for (x, want) in [
            (0.0, 1.0),
            (0.5, 0.479_500_122_2),
            (1.0, 0.157_299_207_1),
            (2.0, 0.004_677_734_981),
            (-1.0, 1.842_700_792_9),
        ] {
            let got = erfc(x);
            assert!((got - want).abs() <= 1.2e-7 * want, "erfc({x}) = {got}, want {want}");
        }
    }

    #[test]
    fn weights_are_a_normalised_population_that_mirrors_the_density() {
        let d = Density {
            slide_deg: 60.0,
            coercivity_median_deg: 8.0,
            coercivity_log_sd: 0.5,
            interaction_sd_positive_deg: 15.0,
            interaction_sd_negative_deg: 15.0,
        };
        let w = everett_weights(&d);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(w.iter().all(|&v| v >= 0.0));
        // Symmetric density: cell (i, j) and its mirror (N−1−j, N−1−i) weigh the same.
        for i in 0..LEVELS {
            for j in 0..=i {
                let (a, b) = (w[relay_index(i, j)], w[relay_index(LEVELS - 1 - j, LEVELS - 1 - i)]);
                assert!((a - b).abs() < 1e-9, "({i}, {j}): {a} vs {b}");
            }
        }
        // Concentrated: the heaviest cell sits at h_u ≈ 0 with h_c within a cell of the median.
        let (n, _) = w
            .iter()
            .enumerate()
            .fold((0, 0.0), |m, (n, &v)| if v > m.1 { (n, v) } else { m });
        let i = (0..LEVELS).rev().find(|&i| relay_index(i, 0) <= n).unwrap();
        let j = n - relay_index(i, 0);
        let a = levels(60.0);
        assert!((0.5 * (a[i] + a[j])).abs() <= 3.75 + 1e-9, "heaviest cell ({i}, {j})");
        assert!(
            (0.5 * (a[i] - a[j]) - 8.0).abs() <= 3.75 + 1e-9,
            "heaviest cell ({i}, {j})"
        );
        // Skewed: more population above the mode than below.
        let skewed = everett_weights(&Density {
            interaction_sd_positive_deg: 25.0,
            ..d
        });
        let side = |sign: f64| -> f64 {
            (0..LEVELS)
                .flat_map(|i| (0..=i).map(move |j| (i, j)))
                .filter(|&(i, j)| sign * (a[i] + a[j]) > 1e-9)
                .map(|(i, j)| skewed[relay_index(i, j)])
                .sum()
        };
        let (above, below) = (side(1.0), side(-1.0));
        assert!(above > 1.3 * below, "above {above}, below {below}");
    }

    #[test]
    fn assembled_state_reads_zero_and_is_consistent_with_the_straight_command() {
        let p = params(0.0);
        let mut st = p.relaxed();
        let before = st;
        let out = p.advance(&mut st, &[0.0; N_JOINTS], 0.01, &Creep::NONE);
        assert_eq!(st, before, "no relay moves at the straight command");
        assert_eq!(out.passes, 0);
        assert!(out.angle_deg.iter().all(|&a| a == 0.0), "{:?}", out.angle_deg);
        // … also with the delayed slip, and after a minor excursion back to it (bit for bit).
        let p = params(0.35);
        let mut st = p.relaxed();
        assert_eq!(
            p.advance(&mut st, &[0.0; N_JOINTS], 0.01, &Creep::NONE).angle_deg,
            [0.0; N_JOINTS]
        );
        assert!(p.zero_output[0] != 0.0, "a skewed density is not demagnetised at P = 0");
    }

    #[test]
    fn the_lag_is_bounded_and_fixed_once_every_contact_slips() {
        let p = params(0.0);
        let (g, l, x) = (20.0, 5.0, 25.0);
        let p0 = p.zero_output[0];
        let mut st = p.relaxed();
        let mut path = ramp(0.0, 80.0, 0.5);
        path.extend(ramp(79.5, -80.0, 0.5));
        let q = drive(&p, &mut st, &path, 0.01);
        for (v, q) in path.iter().zip(&q) {
            let lag = v - q;
            assert!((lag - l * p0).abs() <= g + 1e-9, "lag {lag} at {v}");
        }
        // Going up from the straight pose the load reaches X at v = X: from there every contact
        // has let go, the lag is G + L·P₀ and the joint follows its command one to one.
        let top = path.iter().position(|&v| v == 80.0).unwrap();
        for k in 0..top {
            if path[k] >= x {
                assert!((path[k] - q[k] - (g + l * p0)).abs() < 1e-9, "{} → {}", path[k], q[k]);
            }
        }
        // Coming down from 80 the lag swings across in 2X = 50 of command, then is −G + L·P₀.
        for k in top..path.len() {
            if path[k] <= 80.0 - 2.0 * x {
                assert!((path[k] - q[k] - (-g + l * p0)).abs() < 1e-9, "{} → {}", path[k], q[k]);
            }
        }
        assert!(st.relay[0].iter().all(|&s| s <= -1.0 + 1e-12));
        // Right after the reversal the joint stands (no contact lets go near the slide level).
        assert!((q[top + 1] - q[top]).abs() < 0.01 * 0.5, "{} → {}", q[top], q[top + 1]);
    }

    #[test]
    fn the_breakaway_rate_bound_is_attained_and_never_exceeded() {
        // The file's skew and its mirror: the heaviest row, then the heaviest column, dominates.
        let mut mirrored = config(0.0);
        mirrored.interaction_sd_positive_deg = [6.0; N_JOINTS];
        mirrored.interaction_sd_negative_deg = [8.0; N_JOINTS];
        let mirrored = Params::new(&mirrored, Matrix5::identity(), [1.0; N_JOINTS], &mut || 1.0).unwrap();
        for p in [params(0.0), mirrored] {
            let x = p.slide_deg[0];
            let w = &p.weight[0];
            let row_max = (0..LEVELS)
                .map(|i| (0..=i).map(|j| w[relay_index(i, j)]).sum::<f64>())
                .fold(0.0f64, f64::max);
            let column_max = (0..LEVELS)
                .map(|j| (j..LEVELS).map(|i| w[relay_index(i, j)]).sum::<f64>())
                .fold(0.0f64, f64::max);
            assert!(
                (row_max - column_max).abs() > 0.01 * row_max,
                "{row_max} vs {column_max}"
            );
            let scale = LEVELS as f64 / x;
            assert_eq!(rate(&p), scale * row_max.max(column_max));
            // From negative saturation up, and from positive saturation down, in fine steps of
            // the load: the steepest dP/du is the heaviest row going up, the heaviest column
            // going down.
            let steepest = |from: f64, to: f64| {
                let mut st = p.relaxed();
                p.switch(0, &mut st.relay[0], from, 1.0);
                let mut last = p.output(0, &st.relay[0]);
                let mut max = 0.0f64;
                for u in ramp(from, to, 0.01) {
                    p.switch(0, &mut st.relay[0], u, 1.0);
                    let now = p.output(0, &st.relay[0]);
                    max = max.max((now - last).abs() / 0.01);
                    last = now;
                }
                max
            };
            let (up, down) = (steepest(-x, x), steepest(x, -x));
            assert!(
                (up - scale * row_max).abs() < 1e-6 * up,
                "up {up} vs rows {}",
                scale * row_max
            );
            assert!(
                (down - scale * column_max).abs() < 1e-6 * down,
                "down {down} vs columns {}",
                scale * column_max
            );
            // Along any history the rate stays below b: a seeded random walk of the load.
            let mut st = p.relaxed();
            let (mut u, mut last) = (0.0f64, p.output(0, &st.relay[0]));
            let mut seed = 0x2545_f491_4f6c_dd1du64;
            for _ in 0..20_000 {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let du = ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 6.0;
                let next = (u + du).clamp(-x, x);
                p.switch(0, &mut st.relay[0], next, 1.0);
                let now = p.output(0, &st.relay[0]);
                assert!((now - last).abs() <= rate(&p) * (next - u).abs() + 1e-12);
                assert!((now - last) * (next - u) >= 0.0, "P moves with the load");
                (u, last) = (next, now);
            }
        }
    }

    #[test]
    fn the_joint_never_moves_against_nor_outruns_its_input() {
        // A seeded random walk of the command in small and large steps, rate-independent.
        let walk = || {
            let mut seed = 0x9e37_79b9_7f4a_7c15u64;
            let mut v = 0.0f64;
            (0..20_000)
                .map(|_| {
                    seed ^= seed << 13;
                    seed ^= seed >> 7;
                    seed ^= seed << 17;
                    let r = (seed >> 11) as f64 / (1u64 << 53) as f64;
                    v = (v + (r - 0.5) * if seed.is_multiple_of(7) { 40.0 } else { 3.0 }).clamp(-70.0, 70.0);
                    v
                })
                .collect::<Vec<f64>>()
        };
        let path = walk();
        let outrun = |p: &Params| {
            let mut st = p.relaxed();
            let q = drive(p, &mut st, &path, 0.01);
            let mut worst = 0.0f64;
            for k in 1..path.len() {
                let (dv, dq) = (path[k] - path[k - 1], q[k] - q[k - 1]);
                assert!(dq * dv >= -1e-12, "step {k}: input {dv}, joint {dq}");
                if dv != 0.0 {
                    worst = worst.max(dq / dv);
                }
            }
            worst
        };
        let p = params(0.0);
        assert!(p.presliding_deg[0] * rate(&p) <= 1.0);
        let worst = outrun(&p);
        assert!(worst <= 1.0 + 1e-9, "dq/dv up to {worst}");
        // The bound is what keeps it from outrunning: three times the pre-sliding travel makes
        // the joint faster than its command where the contacts let go (but still not against).
        let mut steep = params(0.0);
        steep.presliding_deg[0] *= 3.0;
        assert!(steep.presliding_deg[0] * rate(&steep) > 1.2);
        let worst = outrun(&steep);
        assert!(worst > 1.2, "dq/dv up to {worst}");
    }

    #[test]
    fn a_unit_beyond_the_bound_is_refused_with_its_values() {
        // The second draw is joint 1's pre-sliding travel: 4 times the file's.
        let mut n = 0;
        let mut vary = || {
            n += 1;
            if n == 2 {
                4.0
            } else {
                1.0
            }
        };
        let e = Params::new(&config(0.0), Matrix5::identity(), [1.0; N_JOINTS], &mut vary).unwrap_err();
        assert_eq!(e.joint, 0);
        assert_eq!(e.presliding_deg, 20.0);
        // b of the varied density: X = 20 + 20.
        let varied = Density {
            slide_deg: 40.0,
            ..Density::nominal(&config(0.0), 0)
        };
        assert_eq!(e.rate_per_deg, max_breakaway_rate(&everett_weights(&varied), 40.0));
        assert_eq!(e.product, 20.0 * e.rate_per_deg);
        assert!(e.product > 1.0, "{e:?}");
        let msg = e.to_string();
        assert!(
            msg.contains("q1") && msg.contains("presliding_deg[0]") && msg.contains("coercivity_median_deg"),
            "{msg}"
        );
    }

    #[test]
    fn minor_loops_wipe_out_bit_for_bit() {
        let p = params(0.0);
        let mut st = p.relaxed();
        drive(&p, &mut st, &[10.0, 30.0, 50.0, 40.0, 20.0, 5.0], 0.01);
        let at_turn = st;
        // A minor loop inside the major one (peak 27 < 50), back to the turning point 5.
        drive(&p, &mut st, &[9.0, 18.0, 27.0, 21.0, 13.0, 7.0, 5.0], 0.01);
        assert_eq!(st, at_turn, "the minor loop is wiped out");
        // A larger excursion (past 50) is not: it wipes out the older maximum instead.
        drive(&p, &mut st, &[30.0, 55.0, 30.0, 5.0], 0.01);
        assert_ne!(st.relay, at_turn.relay);
    }

    #[test]
    fn held_command_relaxes_toward_the_static_output_with_tau() {
        let p = params(0.4);
        let stat = params(0.0);
        let (mut st, mut st_static) = (p.relaxed(), stat.relaxed());
        // Relaxed at 30 after −40: the cable slides (70 > 2X), the joint follows one to one;
        // then a jump to 34.
        drive(&p, &mut st, &[-40.0; 50], 0.1);
        drive(&p, &mut st, &[30.0; 50], 0.1);
        drive(&stat, &mut st_static, &[-40.0, 30.0], 0.1);
        let first = p.advance(&mut st, &[34.0; N_JOINTS], 1e-3, &Creep::NONE).angle_deg[0];
        let target = drive(&stat, &mut st_static, &[34.0], 1e-3)[0];
        assert!(
            target - first > 1.5,
            "the contacts feel 60 % at once: {first} vs {target}"
        );
        // Held: the output creeps toward the static one, exactly exponentially with τ = 0.25 s.
        let q = drive(&p, &mut st, &[34.0; 250], 1e-3);
        let at_tau = (q[249] - first) / (target - first);
        assert!(
            (at_tau - (1.0 - (-1.0f64).exp())).abs() < 1e-9,
            "fraction after τ: {at_tau}"
        );
        let end = *drive(&p, &mut st, &[34.0; 10_000], 1e-3).last().unwrap();
        assert!((end - target).abs() < 1e-9, "{end} vs {target}");
    }

    #[test]
    fn one_step_equals_many_for_the_relaxation() {
        let p = params(0.4);
        let (mut a, mut b) = (p.relaxed(), p.relaxed());
        let qa = p.advance(&mut a, &[40.0; N_JOINTS], 0.4, &Creep::NONE).angle_deg[0];
        let mut qb = p.advance(&mut b, &[40.0; N_JOINTS], 0.01, &Creep::NONE).angle_deg[0];
        for _ in 0..39 {
            qb = p.advance(&mut b, &[40.0; N_JOINTS], 0.01, &Creep::NONE).angle_deg[0];
        }
        assert!((qa - qb).abs() < 1e-9, "{qa} vs {qb}");
    }

    #[test]
    fn weaker_contacts_release_the_joint_toward_its_command() {
        let half = Creep {
            width_scale: [0.5; N_JOINTS],
            play_deg: [0.0; N_JOINTS],
        };
        let p = params(0.0);
        // Sliding (lag G + L·P₀ ≈ 20) and held by the contacts (after 30 of a 50 swing).
        for path in [&[10.0, 20.0, 30.0, 40.0][..], &[40.0, 10.0][..]] {
            let mut st = p.relaxed();
            let q = *drive(&p, &mut st, path, 0.01).last().unwrap();
            let cmd = *path.last().unwrap();
            let q_half = p.advance(&mut st, &[cmd; N_JOINTS], 0.01, &half).angle_deg[0];
            assert!((cmd - q_half).abs() < (cmd - q).abs() - 0.5, "{path:?}: {q} → {q_half}");
        }
        // No pre-tension left: no friction, the joint is at its command.
        let none = Creep {
            width_scale: [0.0; N_JOINTS],
            play_deg: [0.0; N_JOINTS],
        };
        let mut st = p.relaxed();
        drive(&p, &mut st, &[10.0, 20.0, 30.0], 0.01);
        assert_eq!(p.advance(&mut st, &[30.0; N_JOINTS], 0.01, &none).angle_deg[0], 30.0);
    }
}
