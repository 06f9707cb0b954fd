//! The simulated manipulator: cable commands in, true joint angles out.
//!
//! One step, for a command u (mm pulled in at the drive unit, eq. 5 of q_cmd):
//! 1. every cable's distal end follows u through its sheath: a generalised Prandtl–Ishlinskii
//!    operator whose thresholds are the capstan dead band h = c·T·(cosh μφ − 1)/μφ of that
//!    cable, with φ = the sheath wrap plus the bend of every segment the cable crosses inside
//!    the manipulator, and T its present tension;
//! 2. the cable stretches elastically by its mean capstan stretch c·T·sinh(μφ)/μφ (relative
//!    to the straight pose), and creeps by its slack if drift is on;
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

use crate::config::{PlantConfig, MAX_PLAYS};
use crate::hysteresis::{capstan_half_width_mm, capstan_mean_stretch_mm, play, threshold_scales};

/// Joints that are bending segments (q1, q2: segment 1; q3: segment 2): cables crossing them
/// wrap the hinges by their bend. The jaws (q4, q5) are pulleys.
const BEND_JOINTS: usize = 3;
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
    u_min_mm: [f64; N_CABLES],
    u_max_mm: [f64; N_CABLES],
    state: State,
    initial: State,
}

impl Plant {
    /// A plant for `robot` with the parameters of `config`, varied per cable by the seeded
    /// manufacturing spread (`variation.relative_sd`). Same arguments → the same plant.
    pub fn new(robot: &Robot, config: &PlantConfig, seed: u64) -> Plant {
        let cables = robot.cables();
        let pairs = *cables.pairs();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let sd = config.variation.relative_sd;
        let mut vary = move || {
            let n: f64 = rng.sample(StandardNormal);
            1.0 + sd * n.clamp(-3.0, 3.0)
        };

        let mut compliance_mm_per_n = [0.0; N_CABLES];
        let mut pretension_n = [0.0; N_CABLES];
        let mut sheath_x = [0.0; N_CABLES];
        for i in 0..N_CABLES {
            let ea = config.cables.axial_stiffness_n[i] * vary();
            compliance_mm_per_n[i] = config.sheath.length_mm / ea;
            pretension_n[i] = config.cables.pretension_n[i] * vary();
            sheath_x[i] = config.sheath.friction_coefficient * config.sheath.wrap_deg[i].to_radians() * vary();
        }
        let stiffness: [f64; N_JOINTS] = core::array::from_fn(|j| config.joints.stiffness_nmm_per_rad[j] * vary());

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

        let mut play_scale = [0.0; MAX_PLAYS];
        threshold_scales(
            config.hysteresis.plays,
            config.hysteresis.threshold_spread,
            &mut play_scale,
        );

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
        };
        Plant {
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
            plays: config.hysteresis.plays,
            joint_map,
            offset_rad,
            tau_s: config.dynamics.time_constant_s,
            drift_mm_per_s: config.drift.rate_mm_per_hour.map(|r| r / 3600.0),
            drift_max_mm: config.drift.max_mm,
            u_min_mm,
            u_max_mm,
            state: initial,
            initial,
        }
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

        // Quasi-static equilibrium q = Q(q), warm-started from the last one.
        let mut q = self.state.q_eq_rad;
        let mut eval = self.quasi_static(cable_disp_mm, &q, &slack_mm)?;
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
            eval = self.quasi_static(cable_disp_mm, &q, &slack_mm)?;
            iterations += 1;
        }

        let q_eq_deg = eval.q_rad.map(f64::to_degrees);
        let q_qs_deg = self.robot.clamp_to_limits(&q_eq_deg);
        // Exact discretisation of the first-order lag: any dt is stable.
        let alpha = 1.0 - (-dt_s / self.tau_s).exp();
        let mut q_phy_deg = self.state.q_phy_deg;
        for k in 0..N_JOINTS {
            q_phy_deg[k] += alpha * (q_qs_deg[k] - q_phy_deg[k]);
        }

        self.state = State {
            z_mm: eval.z_mm,
            q_eq_rad: eval.q_rad,
            q_qs_deg,
            q_phy_deg,
            q_cmd_deg,
            u_mm: *cable_disp_mm,
            tip_mm: eval.tip_mm,
            tension_n: eval.tension_n,
            t_sim_ns: t_next_ns,
            iterations,
        };
        Ok(())
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

    /// Fixed-point iterations the last step used (diagnostics and benchmarks).
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

    /// Cable creep at time `t_ns`.
    fn slack_mm(&self, t_ns: u64) -> [f64; N_CABLES] {
        let t_s = t_ns as f64 * 1e-9;
        core::array::from_fn(|i| (self.drift_mm_per_s[i] * t_s).min(self.drift_max_mm))
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
