//! The simulated manipulator: cable commands in, true joint angles out.
//!
//! Every family (`family` in the plant file) shares the command checks and decoding, the
//! per-unit variation of the drive (cable stiffness, pre-tension, sheath wrap, joint
//! stiffness: drawn first, in the same order for every family), the residual coupling, gains
//! and offsets, contact and limits, the first-order settling and creep's slack; the
//! `bouc-wen`, `lugre` and `preisach` families' own models are in [`crate::families`]. The
//! default, `capstan`, is described here.
//!
//! One step of the capstan family, for a command u (mm pulled in at the drive unit, eq. 5 of
//! q_cmd):
//! 1. every cable's distal end follows u through its sheath: a generalised Prandtl–Ishlinskii
//!    operator whose thresholds are the capstan dead band h = c·T·(cosh μφ − 1)/μφ of that
//!    cable, with φ = the sheath wrap plus the bend of every segment the cable crosses inside
//!    the manipulator, and T its present tension;
//! 2. the cable stretches elastically by its mean capstan stretch c·T·sinh(μφ)/μφ (relative
//!    to the straight pose), and sits out by its slack (`[drift]`: creep and slips) if any;
//! 3. the distal displacements go back through the inverse cable equation
//!    (`joints_from_displacements`: pair differences → joints), so segment-1 → segment-2 and
//!    wrist → forceps coupling comes from the routing (a distal cable's lag as segment 1 moves
//!    under it), then the residual coupling matrix, per-joint gains and offsets;
//! 4. tensions come from statics: holding joint angles q against the joint stiffness K takes
//!    pair tension differences ΔT with K·q = ½·J₀ᵀ·ΔT (virtual work, J₀ the pair-difference
//!    Jacobian of eq. 5 at the straight pose), so a bent segment 2 also loads the segment-1 pair.
//!
//! Tension and wrap depend on q, and q on them: the quasi-static state is the fixed point
//! q = Q(q), found each step by a preconditioned fixed-point iteration warm-started from the
//! previous one (1 iteration when nothing moved). The play state advances once per step, with
//! the converged thresholds. Contact keeps the jaws from crossing and the joints inside their
//! mechanical limits; the true angles then settle toward that state with a first-order lag.

use nalgebra::{Matrix5, Vector5};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use bowden_interfaces::PlantState;
use bowden_kinematics::cables::CableError;
use bowden_kinematics::{JointsDeg, Robot, N_CABLES, N_JOINTS};

use crate::config::{FamilyKind, PlantConfig, MAX_PLAYS, MAX_SLIPS};
use crate::families::{bouc_wen, lugre, pair_creep, preisach, Shared, BEND_JOINTS};
use crate::hysteresis::{capstan_half_width_mm, capstan_mean_stretch_mm, play, threshold_scales};

/// Fixed-point iterations per step at most, and the tolerance (rad) that stops them earlier.
const MAX_ITERATIONS: u32 = 12;
const TOLERANCE_RAD: f64 = 1e-7;
/// Longest accepted step, s (a step is exact for any dt; this only catches unit mistakes).
pub const MAX_DT_S: f64 = 60.0;

/// A command or step the plant refused. The plant's state is unchanged when one is returned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlantError {
    #[error("time step dt = {dt_s} s is invalid (need 0 < dt ≤ {MAX_DT_S} s)")]
    InvalidDt { dt_s: f64 },
    #[error("settle duration {duration_s} s is invalid (need a finite value ≥ 0)")]
    InvalidDuration { duration_s: f64 },
    #[error("cable command w{cable} = {value_mm} mm is not finite")]
    NonFiniteCommand { cable: usize, value_mm: f64 },
    #[error(
        "cable command w{cable} = {value_mm} mm is outside [{min_mm:.3}, {max_mm:.3}] mm (joint limits plus margin)"
    )]
    CommandOutOfRange {
        cable: usize,
        value_mm: f64,
        min_mm: f64,
        max_mm: f64,
    },
    #[error("cable command does not decode to joint angles: {0}")]
    UndecodableCommand(CableError),
    #[error("distal cable state does not decode to joint angles (plant parameters out of their physical range?): {0}")]
    UndecodableState(CableError),
}

/// Everything that evolves. Copy, so a step computes a new one and commits it at the end.
#[derive(Debug, Clone, Copy)]
struct State {
    /// Play outputs, per cable, per play (mm).
    z_mm: [[f64; MAX_PLAYS]; N_CABLES],
    /// Quasi-static equilibrium before contact and limits (rad): the warm start.
    q_eq_rad: [f64; N_JOINTS],
    /// Quasi-static state after contact and limits (deg).
    q_qs_deg: JointsDeg,
    /// True joint angles (deg).
    q_phy_deg: JointsDeg,
    /// Joint command decoded from the last cable command (deg).
    q_cmd_deg: JointsDeg,
    /// Last cable command (mm).
    u_mm: [f64; N_CABLES],
    /// Distal cable displacement (mm).
    tip_mm: [f64; N_CABLES],
    /// Distal cable tension (N).
    tension_n: [f64; N_CABLES],
    t_sim_ns: u64,
    iterations: u32,
    /// The state of the `bouc-wen`, `lugre` or `preisach` family (the capstan's is `z_mm`).
    family: FamilyState,
}

/// The evolving state of the selected family beyond what every family shares.
// Held by value: a step builds the next `State` on the stack and commits it whole, and boxing
// would allocate on the real-time path.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
enum FamilyState {
    Capstan,
    BoucWen(bouc_wen::State),
    Lugre(lugre::State),
    Preisach(preisach::State),
}

/// Instance parameters of the selected family beyond the shared ones (one per plant, by value
/// like the rest of its parameters).
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
enum Family {
    Capstan,
    BoucWen(bouc_wen::Params),
    Lugre(lugre::Params),
    Preisach(preisach::Params),
}

/// What every family's step starts from: the checked command and the time it advances to.
struct StepInput<'a> {
    cable_disp_mm: &'a [f64; N_CABLES],
    dt_s: f64,
    q_cmd_deg: JointsDeg,
    t_next_ns: u64,
    slack_mm: &'a [f64; N_CABLES],
}

/// What a family's step computed before contact, limits and settling (`Plant::finish`).
struct QuasiStatic {
    q_eq_rad: [f64; N_JOINTS],
    z_mm: [[f64; MAX_PLAYS]; N_CABLES],
    tip_mm: [f64; N_CABLES],
    tension_n: [f64; N_CABLES],
    iterations: u32,
    family: FamilyState,
}

/// The result of evaluating the quasi-static map once.
struct Eval {
    q_rad: [f64; N_JOINTS],
    z_mm: [[f64; MAX_PLAYS]; N_CABLES],
    tip_mm: [f64; N_CABLES],
    tension_n: [f64; N_CABLES],
}

/// The simulated tendon-sheath manipulator. See the module docs for the model.
#[derive(Debug, Clone)]
pub struct Plant {
    robot: Robot,
    config: PlantConfig,
    seed: u64,
    // Instance parameters (config + seeded variation).
    compliance_mm_per_n: [f64; N_CABLES],
    pretension_n: [f64; N_CABLES],
    sheath_x: [f64; N_CABLES],
    body_mu: f64,
    crosses: [[f64; BEND_JOINTS]; N_CABLES],
    pair_of: [usize; N_CABLES],
    pair_sign: [f64; N_CABLES],
    pairs: [(usize, usize); N_JOINTS],
    /// ΔT (N, per pair) = tension_matrix · q (rad).
    tension_matrix: Matrix5<f64>,
    /// Mean stretch at the straight pose: the reference the commands are relative to.
    stretch0_mm: [f64; N_CABLES],
    preconditioner: Matrix5<f64>,
    play_scale: [f64; MAX_PLAYS],
    plays: usize,
    /// G·(I + C).
    joint_map: Matrix5<f64>,
    offset_rad: [f64; N_JOINTS],
    tau_s: f64,
    drift_mm_per_s: [f64; N_CABLES],
    drift_max_mm: f64,
    /// Simulated time creep starts at, ns.
    drift_start_ns: u64,
    /// `[[drift.slip]]`: (time ns, cable index 0-based, mm); the first `n_slips` are used.
    slips: [(u64, usize, f64); MAX_SLIPS],
    n_slips: usize,
    u_min_mm: [f64; N_CABLES],
    u_max_mm: [f64; N_CABLES],
    family: Family,
    state: State,
    initial: State,
}

/// A plant that cannot be built from its config and unit. [`Plant::try_new`] returns it,
/// [`Plant::new`] panics with its message.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlantBuildError {
    #[error(
        "plant config `{name}` selects family \"{family}\" without its [{table}] table (validate the config first)"
    )]
    MissingTable {
        name: String,
        family: &'static str,
        table: &'static str,
    },
    #[error("plant config `{name}`, unit {unit}: {source}")]
    Preisach {
        name: String,
        unit: u64,
        #[source]
        source: preisach::BreakawayBoundError,
    },
}

/// The seeded manufacturing variation of unit `seed`: each call draws one relative factor
/// 1 + sd·n, n standard normal truncated at ±3σ.
fn unit_variation(seed: u64, sd: f64) -> impl FnMut() -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    move || {
        let n: f64 = rng.sample(StandardNormal);
        1.0 + sd * n.clamp(-3.0, 3.0)
    }
}

/// The drive's varied parameters, drawn first and in this order for every family.
struct Drive {
    compliance_mm_per_n: [f64; N_CABLES],
    pretension_n: [f64; N_CABLES],
    sheath_x: [f64; N_CABLES],
    stiffness: [f64; N_JOINTS],
}

fn draw_drive(config: &PlantConfig, vary: &mut dyn FnMut() -> f64) -> Drive {
    let mut compliance_mm_per_n = [0.0; N_CABLES];
    let mut pretension_n = [0.0; N_CABLES];
    let mut sheath_x = [0.0; N_CABLES];
    for i in 0..N_CABLES {
        let ea = config.cables.axial_stiffness_n[i] * vary();
        compliance_mm_per_n[i] = config.sheath.length_mm / ea;
        pretension_n[i] = config.cables.pretension_n[i] * vary();
        sheath_x[i] = config.sheath.friction_coefficient * config.sheath.wrap_deg[i].to_radians() * vary();
    }
    let stiffness = core::array::from_fn(|j| config.joints.stiffness_nmm_per_rad[j] * vary());
    Drive {
        compliance_mm_per_n,
        pretension_n,
        sheath_x,
        stiffness,
    }
}

/// Whether unit `unit` of a `preisach` plant keeps every joint's L·b ≤ 1 after its variation
/// (the same draws as [`Plant::try_new`]; for validating a file that names its unit). Ok for
/// other families.
pub(crate) fn preisach_unit(config: &PlantConfig, unit: u64) -> Result<(), preisach::BreakawayBoundError> {
    let Some(pc) = &config.preisach else {
        return Ok(());
    };
    let mut vary = unit_variation(unit, config.variation.relative_sd);
    draw_drive(config, &mut vary);
    preisach::Params::new(pc, Matrix5::zeros(), [0.0; N_JOINTS], &mut vary).map(|_| ())
}

impl Plant {
    /// A plant for `robot` with the parameters of `config`, varied per cable by the seeded
    /// manufacturing spread (`variation.relative_sd`). Same arguments → the same plant.
    ///
    /// # Panics
    /// Where [`Self::try_new`] returns an error: if `config` selects a family whose table is
    /// absent (a config that [`PlantConfig::validate`] refuses; every loaded config is
    /// validated), or if unit `seed` of a `preisach` plant has a joint whose contacts would
    /// outrun its command ([`preisach::BreakawayBoundError`]; validation checks the file's own
    /// unit, so a unit picked per run is the only way to get there).
    pub fn new(robot: &Robot, config: &PlantConfig, seed: u64) -> Plant {
        Self::try_new(robot, config, seed).unwrap_or_else(|e| panic!("{e}"))
    }

    /// [`Self::new`], with what it would panic on as an error.
    // Long: every derived parameter of one plant instance, in the order they depend on each other.
    pub fn try_new(robot: &Robot, config: &PlantConfig, seed: u64) -> Result<Plant, PlantBuildError> {
        let cables = robot.cables();
        let pairs = *cables.pairs();
        let mut vary = unit_variation(seed, config.variation.relative_sd);
        let Drive {
            compliance_mm_per_n,
            pretension_n,
            sheath_x,
            stiffness,
        } = draw_drive(config, &mut vary);

        // Pair-difference Jacobian of eq. (5) at the straight pose (mm/rad), by central differences.
        let delta_deg = 0.01;
        let mut jac = Matrix5::<f64>::zeros();
        let mut crosses = [[0.0; BEND_JOINTS]; N_CABLES];
        let zero = cables.displacements_mm(&[0.0; N_JOINTS]);
        for j in 0..N_JOINTS {
            let mut qp = [0.0; N_JOINTS];
            let mut qm = [0.0; N_JOINTS];
            qp[j] = delta_deg;
            qm[j] = -delta_deg;
            let (wp, wm) = (cables.displacements_mm(&qp), cables.displacements_mm(&qm));
            for (p, &(a, b)) in pairs.iter().enumerate() {
                jac[(p, j)] = ((wp[a] - wp[b]) - (wm[a] - wm[b])) / (2.0 * delta_deg.to_radians());
            }
            if j < BEND_JOINTS {
                // A cable crosses a segment iff its path length depends on that segment's bend.
                let mut q = [0.0; N_JOINTS];
                q[j] = 30.0;
                let w = cables.displacements_mm(&q);
                for i in 0..N_CABLES {
                    crosses[i][j] = if (w[i] - zero[i]).abs() > 1e-9 { 1.0 } else { 0.0 };
                }
            }
        }
        let mut pair_of = [0; N_CABLES];
        let mut pair_sign = [0.0; N_CABLES];
        for (p, &(a, b)) in pairs.iter().enumerate() {
            pair_of[a] = p;
            pair_of[b] = p;
            pair_sign[a] = 1.0;
            pair_sign[b] = -1.0;
        }
        // K·q = ½·J₀ᵀ·ΔT  ⇒  ΔT = 2·J₀⁻ᵀ·K·q. A robot config guarantees antagonistic pairs, so
        // J₀ is invertible; if it were not, the cables would carry no load-dependent tension.
        let k_diag = Matrix5::from_diagonal(&Vector5::from(stiffness));
        let tension_matrix = jac
            .transpose()
            .try_inverse()
            .map(|jti| 2.0 * jti * k_diag)
            .unwrap_or_else(Matrix5::zeros);

        let stretch0_mm: [f64; N_CABLES] =
            core::array::from_fn(|i| capstan_mean_stretch_mm(compliance_mm_per_n[i], pretension_n[i], sheath_x[i]));

        let j = &config.joints;
        let mut coupling = Matrix5::<f64>::identity();
        for r in 0..N_JOINTS {
            for c in 0..N_JOINTS {
                coupling[(r, c)] += j.coupling[r][c];
            }
        }
        let joint_map = Matrix5::from_diagonal(&Vector5::from(j.gain)) * coupling;

        // Linearised ∂Q/∂q through the stretch: −joint_map·J₀⁻¹·diag((c_a g_a + c_b g_b)/2)·Tm.
        // The fixed-point iteration is preconditioned by (I − ∂Q/∂q)⁻¹.
        let mut stretch_gain = Matrix5::<f64>::zeros();
        for (p, &(a, b)) in pairs.iter().enumerate() {
            let g = |i: usize| capstan_mean_stretch_mm(compliance_mm_per_n[i], 1.0, sheath_x[i]);
            stretch_gain[(p, p)] = 0.5 * (g(a) + g(b));
        }
        let preconditioner = jac
            .try_inverse()
            .and_then(|ji| (Matrix5::identity() + joint_map * ji * stretch_gain * tension_matrix).try_inverse())
            .unwrap_or_else(Matrix5::identity);

        // Families other than capstan carry no [hysteresis]: one play of unit scale, unused.
        let (plays, threshold_spread) = config
            .hysteresis
            .as_ref()
            .map_or((1, 0.0), |h| (h.plays, h.threshold_spread));
        let mut play_scale = [0.0; MAX_PLAYS];
        threshold_scales(plays, threshold_spread, &mut play_scale);

        // Displacement range the joint limits span. Eq. (5) is a sum of one term per joint, so
        // the range is the sum of each term's range over its joint's interval.
        let lim = &robot.config.limits;
        let mut u_min_mm = zero;
        let mut u_max_mm = zero;
        for jn in 0..N_JOINTS {
            let (lo, hi) = (lim.q_min_deg[jn], lim.q_max_deg[jn]);
            let n = 480;
            let mut term_min = [0.0f64; N_CABLES];
            let mut term_max = [0.0f64; N_CABLES];
            for s in 0..=n {
                let mut q = [0.0; N_JOINTS];
                q[jn] = lo + (hi - lo) * s as f64 / n as f64;
                let w = cables.displacements_mm(&q);
                for i in 0..N_CABLES {
                    let d = w[i] - zero[i];
                    term_min[i] = term_min[i].min(d);
                    term_max[i] = term_max[i].max(d);
                }
            }
            for i in 0..N_CABLES {
                u_min_mm[i] += term_min[i];
                u_max_mm[i] += term_max[i];
            }
        }
        for i in 0..N_CABLES {
            u_min_mm[i] -= config.command.margin_mm;
            u_max_mm[i] += config.command.margin_mm;
        }

        // The other families' parameters, drawn after the shared ones (so the capstan plant's
        // draws, and hence its instances, are what they always were).
        let jac_inv = jac.try_inverse().unwrap_or_else(Matrix5::zeros);
        let missing = |kind: FamilyKind| PlantBuildError::MissingTable {
            name: config.name.clone(),
            family: kind.as_str(),
            table: kind.table(),
        };
        let (family, family_state) = match config.family {
            FamilyKind::Capstan => {
                if config.hysteresis.is_none() {
                    return Err(missing(FamilyKind::Capstan));
                }
                (Family::Capstan, FamilyState::Capstan)
            }
            FamilyKind::BoucWen => {
                let Some(bw) = &config.bouc_wen else {
                    return Err(missing(FamilyKind::BoucWen));
                };
                // Stretch of the pairs under the joint stiffness: q_h = q_e + J0⁻¹·Cp·Tm·q_e.
                let mut cp = Matrix5::<f64>::zeros();
                for (p, &(a, b)) in pairs.iter().enumerate() {
                    cp[(p, p)] = 0.5 * (compliance_mm_per_n[a] + compliance_mm_per_n[b]);
                }
                let elastic = (Matrix5::identity() + jac_inv * cp * tension_matrix)
                    .try_inverse()
                    .unwrap_or_else(Matrix5::identity);
                let lever_mm = core::array::from_fn(|k| jac[(k, k)]);
                let params = bouc_wen::Params::new(bw, elastic, jac_inv, lever_mm, &mut vary);
                (
                    Family::BoucWen(params),
                    FamilyState::BoucWen(bouc_wen::State::relaxed()),
                )
            }
            FamilyKind::Lugre => {
                let Some(lg) = &config.lugre else {
                    return Err(missing(FamilyKind::Lugre));
                };
                let shared = Shared {
                    compliance_mm_per_n: &compliance_mm_per_n,
                    sheath_x: &sheath_x,
                    body_mu: config.body.friction_coefficient,
                    crosses: &crosses,
                    pairs: &pairs,
                    pair_of: &pair_of,
                    pair_sign: &pair_sign,
                    zero_mm: &zero,
                    offset_rad: &j.offset_deg.map(f64::to_radians),
                    jac_inv,
                    tension_matrix,
                    joint_map,
                };
                let params = lugre::Params::new(lg, &shared, &mut vary);
                let st = params.relaxed(&zero);
                (Family::Lugre(params), FamilyState::Lugre(st))
            }
            FamilyKind::Preisach => {
                let Some(pc) = &config.preisach else {
                    return Err(missing(FamilyKind::Preisach));
                };
                let lever_mm = core::array::from_fn(|k| jac[(k, k)]);
                let params = preisach::Params::new(pc, jac_inv, lever_mm, &mut vary).map_err(|source| {
                    PlantBuildError::Preisach {
                        name: config.name.clone(),
                        unit: seed,
                        source,
                    }
                })?;
                let st = params.relaxed();
                (Family::Preisach(params), FamilyState::Preisach(st))
            }
        };

        // Slips in a fixed array (validation bounds their number; extras are ignored).
        let mut slips = [(0u64, 0usize, 0.0f64); MAX_SLIPS];
        let n_slips = config.drift.slip.len().min(MAX_SLIPS);
        for (dst, sl) in slips.iter_mut().zip(&config.drift.slip) {
            *dst = (seconds_to_ns(sl.at_s), sl.cable.clamp(1, N_CABLES) - 1, sl.mm);
        }

        // Relaxed at the straight command: the joints sit at their zero offsets.
        let offset_rad = j.offset_deg.map(f64::to_radians);
        let q0 = robot.clamp_to_limits(&j.offset_deg);
        let initial = State {
            z_mm: [[0.0; MAX_PLAYS]; N_CABLES],
            q_eq_rad: offset_rad,
            q_qs_deg: q0,
            q_phy_deg: q0,
            q_cmd_deg: [0.0; N_JOINTS],
            u_mm: zero,
            tip_mm: zero,
            tension_n: pretension_n,
            t_sim_ns: 0,
            iterations: 0,
            family: family_state,
        };
        Ok(Plant {
            robot: robot.clone(),
            config: config.clone(),
            seed,
            compliance_mm_per_n,
            pretension_n,
            sheath_x,
            body_mu: config.body.friction_coefficient,
            crosses,
            pair_of,
            pair_sign,
            pairs,
            tension_matrix,
            stretch0_mm,
            preconditioner,
            play_scale,
            plays,
            joint_map,
            offset_rad,
            tau_s: config.dynamics.time_constant_s,
            drift_mm_per_s: config.drift.rate_mm_per_hour.map(|r| r / 3600.0),
            drift_max_mm: config.drift.max_mm,
            drift_start_ns: seconds_to_ns(config.drift.start_s),
            slips,
            n_slips,
            u_min_mm,
            u_max_mm,
            family,
            state: initial,
            initial,
        })
    }

    /// Advances the plant by `dt_s` under the cable command `cable_disp_mm` (mm pulled in at
    /// the drive, what `robot.cables().displacements_mm(q_cmd)` gives). Allocation-free.
    /// On error nothing changes.
    pub fn step(&mut self, cable_disp_mm: &[f64; N_CABLES], dt_s: f64) -> Result<(), PlantError> {
        if !(dt_s.is_finite() && dt_s > 0.0 && dt_s <= MAX_DT_S) {
            return Err(PlantError::InvalidDt { dt_s });
        }
        let q_cmd_deg = self.check_command(cable_disp_mm)?;
        let t_next_ns = self.state.t_sim_ns.saturating_add((dt_s * 1e9).round() as u64);
        let slack_mm = self.slack_mm(t_next_ns);
        let input = StepInput {
            cable_disp_mm,
            dt_s,
            q_cmd_deg,
            t_next_ns,
            slack_mm: &slack_mm,
        };
        let next = match (&self.family, &self.state.family) {
            (Family::BoucWen(p), FamilyState::BoucWen(st)) => self.next_bouc_wen(p, *st, &input),
            (Family::Lugre(p), FamilyState::Lugre(st)) => self.next_lugre(p, *st, &input),
            (Family::Preisach(p), FamilyState::Preisach(st)) => self.next_preisach(p, *st, &input),
            (Family::Capstan, _) => self.next_capstan(&input),
            _ => unreachable!("a plant's state is always of its own family"),
        }?;
        self.state = self.finish(&input, next);
        Ok(())
    }

    /// Contact, limits and settling after any family's quasi-static state: the new state.
    fn finish(&self, input: &StepInput, r: QuasiStatic) -> State {
        let (q_qs_deg, q_phy_deg) = self.settle_toward(&r.q_eq_rad, input.dt_s);
        State {
            z_mm: r.z_mm,
            q_eq_rad: r.q_eq_rad,
            q_qs_deg,
            q_phy_deg,
            q_cmd_deg: input.q_cmd_deg,
            u_mm: *input.cable_disp_mm,
            tip_mm: r.tip_mm,
            tension_n: r.tension_n,
            t_sim_ns: input.t_next_ns,
            iterations: r.iterations,
            family: r.family,
        }
    }

    /// The capstan family's step: the state after `dt_s` (nothing committed).
    fn next_capstan(&self, input: &StepInput) -> Result<QuasiStatic, PlantError> {
        let (cable_disp_mm, slack_mm) = (input.cable_disp_mm, input.slack_mm);
        // Quasi-static equilibrium q = Q(q), warm-started from the last one.
        let mut q = self.state.q_eq_rad;
        let mut eval = self.quasi_static(cable_disp_mm, &q, slack_mm)?;
        let mut iterations = 1;
        loop {
            let r = Vector5::from(q) - Vector5::from(eval.q_rad);
            if r.amax() < TOLERANCE_RAD || iterations >= MAX_ITERATIONS {
                break;
            }
            let step = self.preconditioner * r;
            for k in 0..N_JOINTS {
                // ±π bounds what eq. (5) can invert; the physical state is far inside.
                q[k] = (q[k] - step[k]).clamp(-core::f64::consts::PI, core::f64::consts::PI);
            }
            eval = self.quasi_static(cable_disp_mm, &q, slack_mm)?;
            iterations += 1;
        }

        Ok(QuasiStatic {
            q_eq_rad: eval.q_rad,
            z_mm: eval.z_mm,
            tip_mm: eval.tip_mm,
            tension_n: eval.tension_n,
            iterations,
            family: FamilyState::Capstan,
        })
    }

    /// The `bouc-wen` family's step (see [`crate::families::bouc_wen`]): joint command → lag per
    /// joint → creep offset → elastic stretch → coupling, gains, offsets.
    fn next_bouc_wen(
        &self,
        params: &bouc_wen::Params,
        mut bw: bouc_wen::State,
        input: &StepInput,
    ) -> Result<QuasiStatic, PlantError> {
        let (q_cmd_deg, slack_mm) = (input.q_cmd_deg, input.slack_mm);
        let creep = pair_creep(&self.pairs, &self.compliance_mm_per_n, &self.pretension_n, slack_mm);
        let band = bouc_wen::Creep {
            width_scale: creep.map(|c| c.tension_ratio),
            extra_deg: core::array::from_fn(|k| {
                let lever = params.lever_mm[k].abs();
                if lever > 0.0 {
                    (0.5 * creep[k].excess_mm / lever).to_degrees()
                } else {
                    0.0
                }
            }),
        };
        let substeps = params.advance(&mut bw, &self.state.q_cmd_deg, &q_cmd_deg, &band);
        // Creep moves the distal ends out: the joints shift by −J0⁻¹·(s_a − s_b).
        let ds = Vector5::from(core::array::from_fn(|p| {
            let (a, b) = self.pairs[p];
            slack_mm[a] - slack_mm[b]
        }));
        let shift = params.jac_inv * ds;
        let q_h = Vector5::from(core::array::from_fn(|k| {
            (q_cmd_deg[k] - bw.lag_deg[k]).to_radians() - shift[k]
        }));
        let q_e = params.elastic * q_h;
        let q_out = self.joint_map * q_e;
        let q_rad: [f64; N_JOINTS] = core::array::from_fn(|k| q_out[k] + self.offset_rad[k]);

        // What the cables do: their distal ends follow the stretched joints, their tensions
        // hold them against the joint stiffness.
        let q_e_deg: JointsDeg = core::array::from_fn(|k| q_e[k].to_degrees());
        let tip_mm = self.robot.cables().displacements_mm(&q_e_deg);
        let delta_t = self.tension_matrix * q_e;
        let tension_n = core::array::from_fn(|i| {
            let p = self.pair_of[i];
            (self.pretension_n[i] - creep[p].drop_n + self.pair_sign[i] * 0.5 * delta_t[p]).max(0.0)
        });

        Ok(QuasiStatic {
            q_eq_rad: q_rad,
            z_mm: self.state.z_mm,
            tip_mm,
            tension_n,
            iterations: substeps,
            family: FamilyState::BoucWen(bw),
        })
    }

    /// The `lugre` family's step (see [`crate::families::lugre`]): sub-stepped cable friction
    /// dynamics → distal ends, creep and free play → inverse cable equation → coupling, gains,
    /// offsets.
    fn next_lugre(
        &self,
        params: &lugre::Params,
        mut lg: lugre::State,
        input: &StepInput,
    ) -> Result<QuasiStatic, PlantError> {
        let (cable_disp_mm, dt_s, slack_mm) = (input.cable_disp_mm, input.dt_s, input.slack_mm);
        let creep = pair_creep(&self.pairs, &self.compliance_mm_per_n, &self.pretension_n, slack_mm);
        let pretension_n: [f64; N_CABLES] =
            core::array::from_fn(|i| (self.pretension_n[i] - creep[self.pair_of[i]].drop_n).max(0.0));
        let input = lugre::StepInput {
            u_mm: cable_disp_mm,
            slack_mm,
            pretension_n: &pretension_n,
            creep: &creep,
        };
        let mut tension_n = [0.0; N_CABLES];
        let substeps = params.advance(&mut lg, &input, dt_s, &mut tension_n);
        let tip_mm = params.tips_mm(&lg, slack_mm);
        let q_cables_deg = self
            .robot
            .cables()
            .joints_from_displacements(&tip_mm)
            .map_err(PlantError::UndecodableState)?;
        let q_out = self.joint_map * Vector5::from(q_cables_deg.map(f64::to_radians));
        let q_rad: [f64; N_JOINTS] = core::array::from_fn(|k| q_out[k] + self.offset_rad[k]);

        Ok(QuasiStatic {
            q_eq_rad: q_rad,
            z_mm: self.state.z_mm,
            tip_mm,
            tension_n,
            iterations: substeps,
            family: FamilyState::Lugre(lg),
        })
    }

    /// The `preisach` family's step (see [`crate::families::preisach`]): joint command → free
    /// play → delayed slip → contacts' load and relay grid per joint (a bounded lag) → creep
    /// offset → coupling, gains, offsets.
    fn next_preisach(
        &self,
        params: &preisach::Params,
        mut pr: preisach::State,
        input: &StepInput,
    ) -> Result<QuasiStatic, PlantError> {
        let (q_cmd_deg, slack_mm) = (input.q_cmd_deg, input.slack_mm);
        let creep = pair_creep(&self.pairs, &self.compliance_mm_per_n, &self.pretension_n, slack_mm);
        // As for bouc-wen: friction (every breakaway level, the slide level and the pre-sliding
        // travel) scales with the remaining pre-tension, and the pair's slack is free play of
        // half its width (as a joint angle) either way.
        let contacts = preisach::Creep {
            width_scale: creep.map(|c| c.tension_ratio),
            play_deg: core::array::from_fn(|k| {
                let lever = params.lever_mm[k].abs();
                if lever > 0.0 {
                    (0.5 * creep[k].excess_mm / lever).to_degrees()
                } else {
                    0.0
                }
            }),
        };
        let moved = params.advance(&mut pr, &q_cmd_deg, input.dt_s, &contacts);
        // Creep moves the distal ends out: the joints shift by −J0⁻¹·(s_a − s_b).
        let ds = Vector5::from(core::array::from_fn(|p| {
            let (a, b) = self.pairs[p];
            slack_mm[a] - slack_mm[b]
        }));
        let shift = params.jac_inv * ds;
        let q_h = Vector5::from(core::array::from_fn(|k| moved.angle_deg[k].to_radians() - shift[k]));
        let q_out = self.joint_map * q_h;
        let q_rad: [f64; N_JOINTS] = core::array::from_fn(|k| q_out[k] + self.offset_rad[k]);

        // What the cables do: their distal ends follow the joints, their tensions hold them
        // against the joint stiffness.
        let q_h_deg: JointsDeg = core::array::from_fn(|k| q_h[k].to_degrees());
        let tip_mm = self.robot.cables().displacements_mm(&q_h_deg);
        let delta_t = self.tension_matrix * q_h;
        let tension_n = core::array::from_fn(|i| {
            let p = self.pair_of[i];
            (self.pretension_n[i] - creep[p].drop_n + self.pair_sign[i] * 0.5 * delta_t[p]).max(0.0)
        });

        Ok(QuasiStatic {
            q_eq_rad: q_rad,
            z_mm: self.state.z_mm,
            tip_mm,
            tension_n,
            iterations: moved.passes,
            family: FamilyState::Preisach(pr),
        })
    }

    /// Joint limits and jaw contact on the quasi-static angles `q_eq_rad`, then the first-order
    /// settling of q_phy toward them over `dt_s`: (q_qs, q_phy), deg.
    fn settle_toward(&self, q_eq_rad: &[f64; N_JOINTS], dt_s: f64) -> (JointsDeg, JointsDeg) {
        let q_eq_deg = q_eq_rad.map(f64::to_degrees);
        let q_qs_deg = self.robot.clamp_to_limits(&q_eq_deg);
        // Exact discretisation of the first-order lag: any dt is stable.
        let alpha = 1.0 - (-dt_s / self.tau_s).exp();
        let mut q_phy_deg = self.state.q_phy_deg;
        for k in 0..N_JOINTS {
            q_phy_deg[k] += alpha * (q_qs_deg[k] - q_phy_deg[k]);
        }
        (q_qs_deg, q_phy_deg)
    }

    /// Holds `cable_disp_mm` for `duration_s` in steps of `dt_s` (the last one shortened to end
    /// exactly at `duration_s`). A bad command, dt or duration changes nothing.
    pub fn settle(&mut self, cable_disp_mm: &[f64; N_CABLES], duration_s: f64, dt_s: f64) -> Result<(), PlantError> {
        if !(duration_s.is_finite() && duration_s >= 0.0) {
            return Err(PlantError::InvalidDuration { duration_s });
        }
        if !(dt_s.is_finite() && dt_s > 0.0 && dt_s <= MAX_DT_S) {
            return Err(PlantError::InvalidDt { dt_s });
        }
        self.check_command(cable_disp_mm)?;
        let n = (duration_s / dt_s - 1e-9).ceil().max(0.0) as u64;
        for k in 0..n {
            let dt = if k + 1 == n {
                duration_s - (n - 1) as f64 * dt_s
            } else {
                dt_s
            };
            if dt > 0.0 {
                self.step(cable_disp_mm, dt)?;
            }
        }
        Ok(())
    }

    /// Convenience: [`Self::step`] with the cable displacements of a joint command (eq. 5).
    pub fn step_joints(&mut self, q_cmd_deg: &JointsDeg, dt_s: f64) -> Result<(), PlantError> {
        let w = self.robot.cables().displacements_mm(q_cmd_deg);
        self.step(&w, dt_s)
    }

    /// Convenience: [`Self::settle`] with the cable displacements of a joint command (eq. 5).
    pub fn settle_joints(&mut self, q_cmd_deg: &JointsDeg, duration_s: f64, dt_s: f64) -> Result<(), PlantError> {
        let w = self.robot.cables().displacements_mm(q_cmd_deg);
        self.settle(&w, duration_s, dt_s)
    }

    /// True physical joint angles q_phy (deg). Exact: measurement noise is the camera's.
    pub fn q_phy_deg(&self) -> JointsDeg {
        self.state.q_phy_deg
    }

    /// The joint command the present cable command encodes (inverse of eq. 5), deg.
    pub fn q_cmd_deg(&self) -> JointsDeg {
        self.state.q_cmd_deg
    }

    /// The state q_phy settles toward under the present command, deg.
    pub fn q_quasi_static_deg(&self) -> JointsDeg {
        self.state.q_qs_deg
    }

    /// Simulated time, ns (the sum of the steps taken since construction or reset).
    pub fn t_sim_ns(&self) -> u64 {
        self.state.t_sim_ns
    }

    /// Distal cable displacements after sheath friction, stretch and creep, mm.
    pub fn cable_tip_mm(&self) -> [f64; N_CABLES] {
        self.state.tip_mm
    }

    /// Distal cable tensions, N.
    pub fn cable_tension_n(&self) -> [f64; N_CABLES] {
        self.state.tension_n
    }

    /// The last cable command, mm.
    pub fn cable_command_mm(&self) -> [f64; N_CABLES] {
        self.state.u_mm
    }

    /// Accepted command range per cable (joint limits plus `command.margin_mm`), mm.
    pub fn command_range_mm(&self) -> ([f64; N_CABLES], [f64; N_CABLES]) {
        (self.u_min_mm, self.u_max_mm)
    }

    /// Fixed-point iterations the last step used (diagnostics and benchmarks); for `bouc-wen`
    /// its sub-steps, for `lugre` its friction sub-steps, for `preisach` its relay-grid passes
    /// over all joints (0 when nothing moved).
    pub fn last_iterations(&self) -> u32 {
        self.state.iterations
    }

    pub fn config(&self) -> &PlantConfig {
        &self.config
    }

    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Writes the truth into a [`PlantState`] sample. The header (seq, tick, t_origin_ns)
    /// belongs to the publisher and is left as it is; unused array entries are zeroed.
    pub fn fill_state(&self, out: &mut PlantState) {
        let s = &self.state;
        out.n_joints = N_JOINTS as u32;
        out.n_cables = N_CABLES as u32;
        out.t_sim_ns = s.t_sim_ns;
        out.q_phy_deg = Default::default();
        out.q_cmd_deg = Default::default();
        out.cable_tip_mm = Default::default();
        out.q_phy_deg[..N_JOINTS].copy_from_slice(&s.q_phy_deg);
        out.q_cmd_deg[..N_JOINTS].copy_from_slice(&s.q_cmd_deg);
        out.cable_tip_mm[..N_CABLES].copy_from_slice(&s.tip_mm);
    }

    /// Back to the straight, relaxed pose at t = 0 (same instance parameters).
    pub fn reset(&mut self) {
        self.state = self.initial;
    }

    /// Validates a cable command and decodes the joint command it encodes.
    fn check_command(&self, u: &[f64; N_CABLES]) -> Result<JointsDeg, PlantError> {
        for (i, &v) in u.iter().enumerate() {
            if !v.is_finite() {
                return Err(PlantError::NonFiniteCommand {
                    cable: i + 1,
                    value_mm: v,
                });
            }
            if v < self.u_min_mm[i] || v > self.u_max_mm[i] {
                return Err(PlantError::CommandOutOfRange {
                    cable: i + 1,
                    value_mm: v,
                    min_mm: self.u_min_mm[i],
                    max_mm: self.u_max_mm[i],
                });
            }
        }
        // A held command decodes as it did last step (the inverse is a Newton solve).
        if *u == self.state.u_mm {
            return Ok(self.state.q_cmd_deg);
        }
        self.robot
            .cables()
            .joints_from_displacements(u)
            .map_err(PlantError::UndecodableCommand)
    }

    /// Cable slack at time `t_ns`: creep since `drift.start_s` (saturating at `drift.max_mm`)
    /// plus every slip whose time has come. Allocation-free.
    fn slack_mm(&self, t_ns: u64) -> [f64; N_CABLES] {
        let t_s = t_ns.saturating_sub(self.drift_start_ns) as f64 * 1e-9;
        let mut slack: [f64; N_CABLES] =
            core::array::from_fn(|i| (self.drift_mm_per_s[i] * t_s).min(self.drift_max_mm));
        for &(at_ns, i, mm) in &self.slips[..self.n_slips] {
            if t_ns >= at_ns {
                slack[i] += mm;
            }
        }
        slack
    }

    /// The slack of every cable now (creep plus slips, `[drift]`), mm.
    pub fn cable_slack_mm(&self) -> [f64; N_CABLES] {
        self.slack_mm(self.state.t_sim_ns)
    }

    /// The quasi-static map Q: joint angles → tensions and wraps → plays (from the committed
    /// state) → stretch → inverse cable equation → coupling, gains, offsets.
    fn quasi_static(
        &self,
        u: &[f64; N_CABLES],
        q_rad: &[f64; N_JOINTS],
        slack_mm: &[f64; N_CABLES],
    ) -> Result<Eval, PlantError> {
        let delta_t = self.tension_matrix * Vector5::from(*q_rad);
        // Creep lowers a pair's common pre-tension; beyond what the pre-tension stretch can take
        // up it is free play (backlash) of the pair, shared by its two cables.
        let mut pretension = self.pretension_n;
        let mut backlash_mm = [0.0; N_CABLES];
        for &(a, b) in &self.pairs {
            let creep = slack_mm[a] + slack_mm[b];
            if creep > 0.0 {
                let c = self.compliance_mm_per_n[a] + self.compliance_mm_per_n[b];
                let drop_n = creep / c;
                for i in [a, b] {
                    pretension[i] = (pretension[i] - drop_n).max(0.0);
                }
                let excess = (creep - c * 0.5 * (self.pretension_n[a] + self.pretension_n[b])).max(0.0);
                backlash_mm[a] = 0.25 * excess;
                backlash_mm[b] = 0.25 * excess;
            }
        }
        let mut z_mm = self.state.z_mm;
        let mut tip_mm = [0.0; N_CABLES];
        let mut tension_n = [0.0; N_CABLES];
        for i in 0..N_CABLES {
            let t = (pretension[i] + self.pair_sign[i] * 0.5 * delta_t[self.pair_of[i]]).max(0.0);
            let mut wrap = 0.0;
            for (jn, &c) in self.crosses[i].iter().enumerate() {
                wrap += c * q_rad[jn].abs();
            }
            let x = self.sheath_x[i] + self.body_mu * wrap;
            let c = self.compliance_mm_per_n[i];
            let h = capstan_half_width_mm(c, t, x);
            let mut sum = 0.0;
            for (zk, scale) in z_mm[i].iter_mut().zip(&self.play_scale).take(self.plays) {
                *zk = play(*zk, u[i], h * scale + backlash_mm[i]);
                sum += *zk;
            }
            let stretch = capstan_mean_stretch_mm(c, t, x) - self.stretch0_mm[i];
            tip_mm[i] = sum / self.plays as f64 - stretch - slack_mm[i];
            tension_n[i] = t;
        }
        let q_cables_deg = self
            .robot
            .cables()
            .joints_from_displacements(&tip_mm)
            .map_err(PlantError::UndecodableState)?;
        let q_out = self.joint_map * Vector5::from(q_cables_deg.map(f64::to_radians));
        let q_rad = core::array::from_fn(|k| q_out[k] + self.offset_rad[k]);
        Ok(Eval {
            q_rad,
            z_mm,
            tip_mm,
            tension_n,
        })
    }
}

/// Seconds of simulated time as the plant's ns clock counts them (as a step of `dt_s` does).
fn seconds_to_ns(t_s: f64) -> u64 {
    (t_s.max(0.0) * 1e9).round() as u64
}
